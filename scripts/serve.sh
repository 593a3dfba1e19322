#!/usr/bin/env bash
# The quick start: installs what is missing for the web build (scripts/setup.sh serve: the
# wasm32 target, wasm-bindgen-cli, trunk; no root, no browser), builds the explorer as a web
# site on the bundled default model, and serves it at http://127.0.0.1:${PORT:-8080}/.
# (The desktop app instead: cargo run --release -p pvrnn-explorer)
set -euo pipefail
cd "$(dirname "$0")/.."
./scripts/setup.sh serve
export PATH="$PWD/web/node_modules/.bin:$PATH"
page=web/index.html
if ! [ -x web/node_modules/.bin/wasm-opt ]; then
    # No npm, so no binaryen: serve the module unoptimised (larger, same behaviour).
    echo "note: npm is not installed, so the site is served without wasm-opt (a larger download);" >&2
    echo "      install Node.js and npm for the optimised build" >&2
    page=web/.index-without-wasm-opt.html
    sed 's/data-wasm-opt="[0-9a-z]*"/data-wasm-opt="0"/' web/index.html > "$page"
fi
exec trunk serve "$page" --release --address 127.0.0.1 --port "${PORT:-8080}"
