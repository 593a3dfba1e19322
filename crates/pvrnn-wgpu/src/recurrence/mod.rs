//! The recurrence on the GPU: forward and back-propagation through time with one
//! workgroup per window (`shaders/recurrence_forward.wgsl`, `recurrence_backward.wgsl`;
//! a window's steps depend on each other, so dispatching per step would cost a submission
//! per step), and the weight gradients with one thread per weight and window, their
//! partial sums added in window order (`recurrence_weights.wgsl`,
//! `recurrence_weights_reduce.wgsl`). The forward record stays on the device for the backward
//! pass; the states come back once (the read-outs on the CPU need them).
//!
//! Files:
//! - This file: a loaded model's recurrent weights on the device ([`GpuRecurrence`]).
//! - `layout.rs`: where everything lives in the kernels' buffers ([`RecurrenceLayout`]):
//!   the modules' shapes and offsets, the weights packed, the windows' entries and inputs.
//! - `table.rs`: the table of shapes and offsets the kernels read, field for field as the
//!   WGSL declares it.
//! - `dispatch.rs`: the forward, backward and weight-gradient dispatches, and whether the
//!   kernels hold a shape.
//! - `pass.rs`: the model's recurrence forward and backward on the device, the results
//!   read back into the core's traces and gradients.

mod dispatch;
mod layout;
mod pass;
mod table;

use std::sync::Arc;

use pvrnn_core::ModelConfig;
use pvrnn_core::cpu::CpuRecurrence;
use pvrnn_core::params::Params;

use crate::gpu::{Gpu, RecurrenceKernels};
use crate::output::Tiling;
use crate::pool::PooledBuffer;

pub(crate) use dispatch::WeightGradBuffers;
pub(crate) use layout::{RecurrenceLayout, WindowEntry};

/// The recurrent weights of one loaded model, uploaded.
#[derive(Debug)]
pub struct GpuRecurrence {
    gpu: Arc<Gpu>,
    pub(crate) kernels: Arc<RecurrenceKernels>,
    pub(crate) layout: RecurrenceLayout,
    pub(crate) weights: PooledBuffer,
    /// The same values with every matrix transposed (same offsets), for the forward
    /// kernel: its threads own output rows, so this layout makes their loads coalesced.
    pub(crate) weights_t: PooledBuffer,
    /// The CPU's recurrence with the same weights, for the windows the kernels do not hold.
    cpu: CpuRecurrence<f32>,
}

impl GpuRecurrence {
    /// Uploads the modules' weights. A module wider than the kernels hold leaves every
    /// call to the CPU.
    pub fn upload(
        gpu: Arc<Gpu>,
        tiling: Tiling,
        params: &Params<f32>,
        config: &ModelConfig,
    ) -> Self {
        let (layout, weights) = RecurrenceLayout::new(params, config);
        let weights_t = layout.transposed(&weights);
        Self {
            kernels: gpu.recurrence_kernels(
                layout.threads(&gpu, tiling.recurrence_threads),
                tiling.recurrence_early_loads,
            ),
            weights: gpu.upload("recurrent weights", &weights),
            weights_t: gpu.upload("recurrent weights, transposed", &weights_t),
            gpu,
            layout,
            cpu: CpuRecurrence::new(params, config),
        }
    }
}
