#!/usr/bin/env bash
# The quick start: installs what is missing (scripts/setup.sh), builds the explorer as a web
# site on the bundled default model, and serves it at http://127.0.0.1:${PORT:-8080}/.
# (The desktop app instead: cargo run --release -p pvrnn-explorer)
set -euo pipefail
cd "$(dirname "$0")/.."
./scripts/setup.sh
export PATH="$PWD/web/node_modules/.bin:$PATH"
exec trunk serve --release --address 127.0.0.1 --port "${PORT:-8080}"
