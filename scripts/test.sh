#!/usr/bin/env bash
# Runs every test: formatting, lints, native tests of all crates, the core's tests compiled
# to WebAssembly under Node, the explorer's browser glue in headless Chromium, and the web
# site itself: built with Trunk, served on 127.0.0.1, opened in headless Chromium (it must
# load, draw, and compute a live run in its worker). CI (.ci/run) runs exactly this.
set -euo pipefail
cd "$(dirname "$0")/.."
./scripts/setup.sh
# A one-off build keeps nothing for a next one: incremental caches only fill the disk.
export CARGO_INCREMENTAL=${CARGO_INCREMENTAL:-0}

start=$SECONDS
step() { printf '\n== [%dm%02ds] %s\n' $(((SECONDS - start) / 60)) $(((SECONDS - start) % 60)) "$*" >&2; }

# Runs a browser test (built beforehand) under a time limit, and once more if it ran out: CI
# once saw chromedriver never bring up the browser, and the run hung until CI's own limit.
in_browser() {
    local limit=$1 attempt rc
    shift
    for attempt in 1 2; do
        rc=0
        timeout --kill-after=10 "$limit" "$@" || rc=$?
        [ "$rc" -eq 124 ] || [ "$rc" -eq 137 ] || return "$rc"
        echo "no result within $limit s (attempt $attempt of 2): stopping the browser" >&2
        pkill -f chromedriver || true
        pkill -f 'chromium.*--headless' || true
    done
    return 1
}

step "cargo fmt --check"
cargo fmt --all -- --check

step "cargo clippy"
cargo clippy --workspace --all-targets -- -D warnings

# (also the check that the dataset crate and the simulator compile for WebAssembly)
step "cargo clippy for WebAssembly (the explorer's web code, the core's wasm kernels, WebGPU)"
# One invocation: apart, the GPU crate's features differ and faer, web-sys and wgpu were
# checked twice. Every target but the GPU crate's benchmarks (native only; the only ones).
cargo clippy -p pvrnn-explorer -p pvrnn-core -p pvrnn-backend-tests -p pvrnn-dataset -p caresim \
    -p pvrnn-wgpu --target wasm32-unknown-unknown --lib --bins --tests --examples -- -D warnings

step "cargo doc with warnings denied"
RUSTDOCFLAGS="-D warnings" cargo doc --workspace --no-deps

step "native tests (the walkthrough apart, below, in a virtual display)"
PVRNN_REQUIRE_PYTHON=1 PVRNN_REQUIRE_R=1 cargo test --workspace -- --skip the_walkthrough_runs_as_written

step "the GPU overlap probe runs, its outputs checked (lavapipe: nothing overlaps there)"
cargo test -p pvrnn-wgpu --bench overlap -- --quick

step "the committed experiments' statistics recomputed apart from the Rust code (Python: numpy, scipy)"
python3 scripts/recheck-experiments.py docs/results/converged docs/results
python3 scripts/recheck-interference.py docs/results/converged/interference/report/trials.csv
python3 scripts/recheck-interference.py docs/results/interference/report/trials.csv --networks 3

step "the walkthrough as written, its explorer step in a virtual display (Xvfb)"
PVRNN_REQUIRE_PYTHON=1 PVRNN_EXPLORER_BIN="$PWD/target/debug/pvrnn-explorer" \
    timeout 900 xvfb-run -a -s "-screen 0 1440x920x24" cargo test -p pvrnn-cli --test it walkthrough::

step "an experiment's Slurm job arrays on a real one-node Slurm (munge, slurmctld, slurmd)"
timeout 900 tests/slurm/run.sh target/debug/pvrnn

step "a campaign's training in flight kept for a fresh machine and put back (scripts/experiments.sh keep); interference in plan order"
tests/scripts/in-flight.sh

step "a GPU loan spent on the campaign: stopped at its deadline, packed, brought back (scripts/lease-campaign.sh)"
tests/scripts/lease-campaign.sh

step "a checkout packed for a GPU call and put back (scripts/lease-tree.sh)"
tests/scripts/lease-tree.sh

step "caresim writes the same bytes on aarch64 (cross-compiled, run under QEMU): the golden sequence's SHA-256"
CARGO_TARGET_AARCH64_UNKNOWN_LINUX_GNU_LINKER=aarch64-linux-gnu-gcc \
CARGO_TARGET_AARCH64_UNKNOWN_LINUX_GNU_RUNNER="qemu-aarch64 -L /usr/aarch64-linux-gnu" \
    cargo test --profile cross-golden --target aarch64-unknown-linux-gnu -p caresim --test benchmark \
    golden_

step "core tests and the CPU backend's suite as WebAssembly under Node"
cargo test -p pvrnn-core -p pvrnn-backend-tests --target wasm32-unknown-unknown

step "WebGPU in a browser worker (SwiftShader's adapter): online inference agrees with the CPU"
# SwiftShader is slow: the runner's default 20 s for the whole run is not enough.
cargo test -p pvrnn-wgpu --target wasm32-unknown-unknown --test webgpu --no-run
WASM_BINDGEN_TEST_TIMEOUT=300 \
WASM_BINDGEN_TEST_WEBDRIVER_JSON="$PWD/tests/web/webgpu-webdriver.json" CHROMEDRIVER="$(command -v chromedriver)" \
    in_browser 420 cargo test -p pvrnn-wgpu --target wasm32-unknown-unknown --test webgpu

step "the explorer's web entry and browser glue in headless Chromium"
cargo test -p pvrnn-explorer --target wasm32-unknown-unknown --no-run
WASM_BINDGEN_TEST_WEBDRIVER_JSON="$PWD/tests/web/webdriver.json" CHROMEDRIVER="$(command -v chromedriver)" \
    in_browser 300 cargo test -p pvrnn-explorer --target wasm32-unknown-unknown

step "the desktop app in a virtual display (Xvfb): opens, computes a run live, saves a picture; with each renderer; drives the robot from the address"
mkdir -p target
# glow (Mesa's OpenGL) and wgpu (lavapipe where there is no GPU) by name; auto takes glow
# where the only Vulkan device is a CPU, wgpu on a GPU.
for renderer in auto glow wgpu; do
    rm -f target/desktop-smoke.png
    timeout 300 xvfb-run -a -s "-screen 0 1440x920x24" target/debug/pvrnn-explorer \
        --view 'seq=repositioning_590mm_test0&vision=1&ablate=1000' --renderer "$renderer" \
        --screenshot target/desktop-smoke.png 2>&1 | tee target/desktop-smoke.log
    want="drawing: $renderer"
    if [ "$renderer" = auto ]; then want="drawing: (glow|wgpu)"; fi
    grep -Eq "saved target/desktop-smoke.png \($want" target/desktop-smoke.log ||
        { echo "--renderer $renderer: the picture was not drawn by $want" >&2; exit 1; }
    python3 - <<'PY'
import struct
png = open("target/desktop-smoke.png", "rb").read()
assert png[:8] == b"\x89PNG\r\n\x1a\n", "not a PNG"
width, height = struct.unpack(">II", png[16:24])
assert (width, height) == (1440, 920), (width, height)
assert len(png) > 100_000, f"{len(png)} bytes: a blank window?"
print(f"desktop window: {width}x{height}, {len(png)} bytes")
PY
done
# The Drive window in the desktop's frame loop: the address's drive (a push at step 40) is
# driven to its end before the picture (stepped between frames, which must keep coming).
timeout 400 xvfb-run -a -s "-screen 0 1440x920x24" target/debug/pvrnn-explorer \
    --view 'drive=repositioning%3A650%3A0%3A1%3Anetwork%3Bpush%3D40%3Aleft%3A0.2&vision=1&proprio=1&maps=0' \
    --renderer glow --screenshot target/desktop-drive.png 2>&1 | tee target/desktop-drive.log
grep -q 'drive: Info("repositioning: ' target/desktop-drive.log ||
    { echo "the desktop app did not drive the address's episode to its end" >&2; exit 1; }

step "the web site: trunk build --release"
PATH="$PWD/web/node_modules/.bin:$PATH" trunk build --release

step "the web site's sizes against their record (web/sizes.json)"
python3 scripts/site-sizes.py

step "the web site in headless Chromium"
port=${PVRNN_TEST_PORT:-8765}
python3 -m http.server "$port" --bind 127.0.0.1 --directory dist >/dev/null 2>&1 &
server=$!
trap 'kill $server 2>/dev/null || true' EXIT
for _ in $(seq 50); do
    (exec 3<>"/dev/tcp/127.0.0.1/$port") 2>/dev/null && break
    sleep 0.2
done
mkdir -p target
in_browser 900 node tests/web/smoke.mjs "http://127.0.0.1:$port/index.html" target/web-smoke.png --live-seconds 240 --webgpu

step "all tests passed"
