//! The explorer's native integration tests (the browser's are `tests/web.rs`).
//! One binary, a module per file, so the crate's tests link once; one file's tests:
//! `cargo test -p pvrnn-explorer --test it MODULE::`.
#![allow(clippy::unwrap_used)] // test code: a failed unwrap is a failed run
#![cfg(not(target_arch = "wasm32"))]

mod docs;
mod driving;
mod findings;
mod mutations;
mod ui;

// Shared with the browser's tests (`tests/web.rs`).
#[path = "../common/mod.rs"]
mod common;
