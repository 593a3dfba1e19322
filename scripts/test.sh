#!/usr/bin/env bash
# Runs every test: formatting, lints, native tests of all crates, and the core's tests
# compiled to WebAssembly under Node. CI (.ci/run) runs exactly this.
set -euo pipefail
cd "$(dirname "$0")/.."
./scripts/setup.sh

step() { printf '\n== %s\n' "$*" >&2; }

step "cargo fmt --check"
cargo fmt --all -- --check

step "cargo clippy"
cargo clippy --workspace --all-targets -- -D warnings

step "native tests"
cargo test --workspace

step "core tests as WebAssembly under Node"
cargo test -p pvrnn-core --target wasm32-unknown-unknown

step "the dataset crate and the simulator build for WebAssembly"
cargo build -p pvrnn-dataset -p caresim --target wasm32-unknown-unknown

echo "all tests passed" >&2
