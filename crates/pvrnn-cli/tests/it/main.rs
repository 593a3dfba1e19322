//! The `pvrnn` command line's integration tests.
//! One binary, a module per file, so the crate's tests link once; one file's tests:
//! `cargo test -p pvrnn-cli --test it MODULE::`.
#![allow(clippy::unwrap_used)] // test code: a failed unwrap is a failed run

mod cli;
mod layering;
mod readme;
mod walkthrough;
