//! The device, its queue, and the compiled kernels (one set per hidden width).
//!
//! Files:
//! - This file: [`Gpu`], what it holds and what it counts.
//! - `adapter.rs`: opening an adapter and a device ([`Gpu::open`]), and looking at the
//!   machine's without opening one ([`probe`]).
//! - `failure.rs`: the device's failures: allocations checked in a scope
//!   ([`Gpu::allocating`]), and the first failure no scope caught ([`Gpu::failure`]).
//! - `buffers.rs`: buffers from the pool (uploads, scratch, uniforms, read-backs) and
//!   long-lived ones.
//! - `targets.rs`: the targets kept on the device between calls ([`ResidentTargets`]).
//! - `pipelines.rs`: a kernel's source compiled into a pipeline, with or without wgpu's
//!   runtime checks ([`RuntimeChecks`]), and the kernels of one shape for every model.
//! - `output_kernels.rs`: the output layer's kernels, compiled per hidden width ([`Kernels`],
//!   [`BlockedKernels`]).
//! - `recurrence_kernels.rs`: the recurrence's kernels, compiled per workgroup width
//!   ([`RecurrenceKernels`]).

mod adapter;
mod buffers;
mod failure;
mod output_kernels;
mod pipelines;
mod recurrence_kernels;
mod targets;

use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock};

use crate::pool::BufferPool;

#[cfg(not(target_arch = "wasm32"))]
pub use adapter::probe_now;
pub use adapter::{GpuError, probe};
pub(crate) use failure::record_failure;
pub use output_kernels::BlockedDepth;
pub(crate) use output_kernels::{BlockedKernels, Kernels, RowPass};
pub use pipelines::RuntimeChecks;
pub(crate) use recurrence_kernels::RecurrenceKernels;
pub(crate) use targets::{ResidentKey, ResidentTargets};

use adapter::{describe, is_cpu};
use pipelines::DenseKernels;
use recurrence_kernels::RecurrenceShape;

/// An open GPU: device, queue and kernels, shared by every model loaded on it.
#[derive(Debug)]
pub struct Gpu {
    pub(crate) device: wgpu::Device,
    pub(crate) queue: wgpu::Queue,
    info: wgpu::AdapterInfo,
    kernels: Mutex<HashMap<RowPass, Arc<Kernels>>>,
    /// By (threads per workgroup, early loads); a few at most (a linear search: a map of
    /// its own costs the web site's download more than it saves).
    recurrence_kernels: Mutex<Vec<(RecurrenceShape, Arc<RecurrenceKernels>)>>,
    radam_kernel: OnceLock<Arc<wgpu::ComputePipeline>>,
    finite_check_kernel: OnceLock<Arc<wgpu::ComputePipeline>>,
    copy_kernel: OnceLock<Arc<wgpu::ComputePipeline>>,
    dense_kernels: OnceLock<Arc<DenseKernels>>,
    /// Targets kept on the device (learning's data, uploaded once per run; an inference
    /// step's window, once per step).
    pub(crate) resident: Mutex<ResidentTargets>,
    pool: Arc<BufferPool>,
    read_backs: AtomicU64,
    /// Runs' parts of learning iterations encoded (not replayed) so far.
    iterations_encoded: AtomicU64,
    /// Submissions' recurrence parts encoded (not replayed) so far.
    recurrence_parts_encoded: AtomicU64,
    /// Which kernels keep wgpu's runtime checks (see [`RuntimeChecks`]).
    checks: RuntimeChecks,
    /// Every kernel's label, for the profile's time per kernel.
    pub(crate) kernel_names: crate::kernel_names::KernelNames,
    /// The device's first failure outside an [`Gpu::allocating`] scope (see
    /// [`Gpu::failure`]).
    failed: Arc<Mutex<Option<String>>>,
}

impl Gpu {
    /// "name (driver, API)".
    pub fn describe(&self) -> String {
        describe(&self.info)
    }

    /// Whether the adapter is a CPU implementation (lavapipe, SwiftShader, WARP): correct,
    /// but slower than the CPU backend, so not chosen unless asked for.
    pub fn is_cpu(&self) -> bool {
        is_cpu(&self.info)
    }

    /// Results read back from the device so far: how a caller (a test, a status line) sees
    /// that work really ran here.
    pub fn read_backs(&self) -> u64 {
        self.read_backs.load(Ordering::Relaxed)
    }

    /// Resident target sets uploaded so far (each modality's count separately): how a test
    /// sees that runs sharing the GPU keep their data there.
    pub fn resident_uploads(&self) -> u64 {
        self.resident.lock().map_or(0, |r| r.uploads)
    }

    /// Device memory held by buffers now, in bytes, as wgpu's allocation counter gives it
    /// (the resident weights, data and moments, and the pool's reusable buffers); `None`
    /// where the platform does not count (WebGPU).
    pub fn buffer_memory(&self) -> Option<u64> {
        let bytes = self.device.get_internal_counters().hal.buffer_memory.read();
        (bytes > 0).then_some(bytes as u64)
    }

    /// Whether the device has timestamp queries (the profile's device times, `timing.rs`).
    pub fn has_timestamps(&self) -> bool {
        self.device
            .features()
            .contains(wgpu::Features::TIMESTAMP_QUERY)
    }

    /// Waits until the device has run everything submitted so far, and with it every
    /// callback of a mapping (the profile's device times arrive in those).
    #[cfg(not(target_arch = "wasm32"))]
    pub fn wait_idle(&self) -> Result<(), GpuError> {
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map(drop)
            .map_err(|e| GpuError::Wait {
                adapter: self.info.name.clone(),
                reason: e.to_string(),
            })
    }

    /// A run's part of a whole learning iteration on the device encoded so far, not
    /// replayed: how a test sees that iterations replay.
    pub fn iterations_encoded(&self) -> u64 {
        self.iterations_encoded.load(Ordering::Relaxed)
    }

    pub(crate) fn count_iteration_encoded(&self) {
        self.iterations_encoded.fetch_add(1, Ordering::Relaxed);
    }

    /// A submission's recurrence part (the windows' table, the recurrence's dispatches and
    /// the weight gradients of its runs) encoded so far, not replayed.
    pub fn recurrence_parts_encoded(&self) -> u64 {
        self.recurrence_parts_encoded.load(Ordering::Relaxed)
    }

    pub(crate) fn count_recurrence_part_encoded(&self) {
        self.recurrence_parts_encoded
            .fetch_add(1, Ordering::Relaxed);
    }

    pub(crate) fn count_read_back(&self) {
        self.read_backs.fetch_add(1, Ordering::Relaxed);
    }

    pub(crate) fn limits(&self) -> wgpu::Limits {
        self.device.limits()
    }
}
