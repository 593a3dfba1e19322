//! The core's integration tests (also run as WebAssembly under Node).
//! One binary, a module per file, so the crate's tests link once; one file's tests:
//! `cargo test -p pvrnn-core --test it MODULE::`.
#![allow(clippy::unwrap_used)] // test code: a failed unwrap is a failed run

mod config_docs;
mod files;
mod learning;

// The backend suite's fixtures, shared by path (a dev-dependency on it would point up).
#[allow(dead_code)]
#[path = "../../../pvrnn-backend-tests/src/fixtures.rs"]
mod fixtures;
