#!/usr/bin/env bash
# Installs what a fresh machine lacks. Idempotent: each step is skipped when already done.
# Versions are pinned: wasm-bindgen must equal the crate in Cargo.lock, and trunk 0.22 needs a
# newer rustc than the workspace's 1.95 (README, Install).
#
#   scripts/setup.sh serve   what building and serving the site needs: the wasm32 target,
#                            wasm-bindgen-cli and trunk (rustup and cargo only: no root, no
#                            browser), and binaryen's wasm-opt from npm when npm is there
#   scripts/setup.sh [test]  also what the tests need: Node.js, npm, headless Chromium and
#                            chromedriver (apt-get: root on Debian/Ubuntu) and the npm tools
set -euo pipefail
cd "$(dirname "$0")/.."
mode=${1:-test}
case "$mode" in serve | test) ;; *) echo "usage: scripts/setup.sh [serve|test]" >&2; exit 2 ;; esac

WASM_BINDGEN_VERSION=0.2.130

step() { printf '\n== %s\n' "$*" >&2; }

if ! rustup target list --installed | grep -q '^wasm32-unknown-unknown$'; then
    step "adding the wasm32-unknown-unknown target"
    rustup target add wasm32-unknown-unknown
fi

# A minimal rustup profile has neither; test.sh checks formatting and runs clippy.
for component in rustfmt clippy; do
    if [ "$mode" = test ] && ! rustup component list --installed | grep -q "^$component-"; then
        step "adding the Rust component $component"
        rustup component add "$component"
    fi
done

if ! wasm-bindgen-test-runner --version 2>/dev/null | grep -q "$WASM_BINDGEN_VERSION"; then
    step "installing wasm-bindgen-cli $WASM_BINDGEN_VERSION (about 2 minutes)"
    # Without --locked: its lock file wants a crate version this registry lacks.
    cargo install wasm-bindgen-cli --version "$WASM_BINDGEN_VERSION"
fi

if [ "$mode" = test ] && ! command -v xvfb-run >/dev/null 2>&1; then
    step "installing Xvfb and Mesa (the desktop app's smoke test draws in a virtual display)"
    apt-get update -qq && apt-get install -y -qq xvfb xauth libgl1-mesa-dri
fi

if [ "$mode" = test ] && ! ls /usr/share/vulkan/icd.d/lvp_icd*.json >/dev/null 2>&1; then
    step "installing Mesa's CPU Vulkan driver, lavapipe (the snapshot tests render with wgpu)"
    apt-get update -qq && apt-get install -y -qq mesa-vulkan-drivers
fi

if ! trunk --version 2>/dev/null | grep -q "0.21.14"; then
    step "installing trunk 0.21.14 (about 7 minutes; 0.22 needs a newer rustc)"
    cargo install trunk --version 0.21.14 --locked
fi

if [ "$mode" = serve ]; then
    # wasm-opt shrinks the site; serving works without it (scripts/serve.sh says so).
    if command -v npm >/dev/null 2>&1 && ! [ -x web/node_modules/.bin/wasm-opt ]; then
        step "installing the web tools (binaryen 132) into web/node_modules"
        (cd web && npm ci --no-audit --no-fund)
    fi
    exit 0
fi

if ! command -v qemu-aarch64 >/dev/null 2>&1 || ! command -v aarch64-linux-gnu-gcc >/dev/null 2>&1; then
    step "installing QEMU's user-mode aarch64 emulator and an aarch64 linker (caresim's bytes are checked on aarch64)"
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
        qemu-user gcc-aarch64-linux-gnu libc6-dev-arm64-cross
fi
if ! rustup target list --installed | grep -q '^aarch64-unknown-linux-gnu$'; then
    step "adding the aarch64-unknown-linux-gnu target"
    rustup target add aarch64-unknown-linux-gnu
fi

if ! command -v node >/dev/null 2>&1; then
    step "installing Node.js (runs the wasm tests)"
    apt-get update -qq && apt-get install -y -qq nodejs
fi

if ! command -v npm >/dev/null 2>&1; then
    step "installing npm (wasm-opt and the browser test's driver come from npm)"
    apt-get update -qq && apt-get install -y -qq npm
fi

if ! command -v chromium >/dev/null 2>&1 || ! command -v chromedriver >/dev/null 2>&1; then
    step "installing headless Chromium and chromedriver (web tests)"
    apt-get update -qq && apt-get install -y -qq chromium chromium-driver
fi

if ! command -v slurmctld >/dev/null 2>&1 || ! command -v munged >/dev/null 2>&1; then
    step "installing Slurm and munge (the experiments' cluster scripts run on a one-node Slurm)"
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends slurm-wlm munge
fi

if ! command -v Rscript >/dev/null 2>&1; then
    step "installing R (base R checks the experiments' statistics: ART ANOVA, contrasts, t-tests)"
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends r-base-core
fi

if ! python3 -c "import safetensors, numpy, scipy" 2>/dev/null; then
    step "installing the Python packages the walkthrough's snippet (safetensors, numpy) and the statistics' rechecks (scipy) use"
    if ! python3 -m pip --version >/dev/null 2>&1; then
        apt-get update -qq && apt-get install -y -qq python3-pip
    fi
    # A distribution's own Python (Debian 12 and later, PEP 668) refuses installs outside a
    # virtual environment; there the packages go to the user's site-packages, which
    # leaves the system's packages alone.
    python3 -m pip install --quiet safetensors numpy scipy 2>/dev/null ||
        python3 -m pip install --quiet --no-warn-script-location --user --break-system-packages safetensors numpy scipy
fi

if ! [ -x web/node_modules/.bin/wasm-opt ] || ! [ -d web/node_modules/playwright-core ]; then
    step "installing the web tools (binaryen 132, playwright-core) into web/node_modules"
    (cd web && npm ci --no-audit --no-fund)
fi
