//! The wgpu backend's native integration tests (the browser's are `tests/webgpu.rs`; the
//! profile's device times are `tests/device_times.rs`, in a process of their own).
//! One binary, a module per file, so the crate's tests link once; one file's tests:
//! `cargo test -p pvrnn-wgpu --test it MODULE::`.
#![allow(clippy::unwrap_used)] // test code: a failed unwrap is a failed run
#![cfg(not(target_arch = "wasm32"))]

mod agrees_with_cpu;
mod documented;

// Shared with the browser's and the device-time tests.
#[path = "../common/mod.rs"]
mod common;
