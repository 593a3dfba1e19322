//! GPU compute for the scalable PV-RNN through wgpu (Vulkan, Metal, DX12; WebGPU later).
//!
//! [`WgpuBackend`] implements pvrnn-core's [`Backend`] for `f32`. What runs on the GPU
//! today is the read-outs' output layer (`tanh(W h + b)` into every dimension, fused with
//! its loss and both backward products: `shaders/loss_rows.wgsl` and
//! `shaders/loss_columns.wgsl`), which is about 97% of a learning iteration's arithmetic
//! (docs/gpu.md). The recurrence, the hidden read-out
//! layers, the KL terms and the optimiser stay on the CPU backend, which calls this crate
//! through [`pvrnn_core::backend::OutputLayer`]. Those move over next (issue 12); the
//! seam does not change when they do.
//!
//! Results match the CPU backend to f32 summation order (the tests in `tests/` check the
//! free energy and every gradient against it on a CPU Vulkan device).

mod gpu;
mod output;
mod pool;
mod template;

use std::sync::Arc;

use pvrnn_core::ModelConfig;
use pvrnn_core::backend::{Backend, LoadedModel};
use pvrnn_core::cpu::CpuBackend;
use pvrnn_core::params::Params;

pub use gpu::{Gpu, GpuError};
pub use output::{GpuOutputLayer, Tiling};

/// The model's arithmetic with the output layers on a GPU (see the crate docs).
#[derive(Clone, Debug)]
pub struct WgpuBackend {
    gpu: Arc<Gpu>,
    tiling: Tiling,
}

impl WgpuBackend {
    /// Opens the first suitable adapter (high performance preferred; `WGPU_ADAPTER_NAME`
    /// and `WGPU_BACKEND` choose another). Fails with a message a user can act on when the
    /// machine has none.
    pub fn new() -> Result<Self, GpuError> {
        Ok(Self {
            gpu: Arc::new(Gpu::new()?),
            tiling: Tiling::default(),
        })
    }

    /// The same GPU with another cut of the work (tests use small tiles and chunks).
    pub fn with_tiling(mut self, tiling: Tiling) -> Self {
        self.tiling = tiling;
        self
    }

    /// The adapter in words: name, driver and API (for `pvrnn bench` and status lines).
    pub fn adapter_name(&self) -> String {
        self.gpu.describe()
    }

    pub fn gpu(&self) -> &Arc<Gpu> {
        &self.gpu
    }
}

impl Backend<f32> for WgpuBackend {
    fn load(&self, params: &Params<f32>, config: &ModelConfig) -> Box<dyn LoadedModel<f32>> {
        let layer = GpuOutputLayer::upload(self.gpu.clone(), self.tiling, params);
        CpuBackend::load_with_output_layer(params, config, Box::new(layer))
    }
}
