//! The experiments' integration tests.
//! One binary, a module per file, so the crate's tests link once; one file's tests:
//! `cargo test -p pvrnn-experiment --test it MODULE::`.
#![allow(clippy::unwrap_used)] // test code: a failed unwrap is a failed run

mod against_r;
mod against_references;
mod campaign_docs;
mod experiments;
