//! GPU compute for the scalable PV-RNN through wgpu (Vulkan, Metal, DX12, and WebGPU in the
//! browser).
//!
//! [`WgpuBackend`] implements pvrnn-core's [`Backend`] for `f32` the way the CPU backend
//! does: it assembles a loaded model ([`pvrnn_core::assembled::AssembledModel`], the
//! backend-neutral driver) from its own pieces. [`GpuReadout`] runs both read-outs' output
//! layers on the GPU (`tanh(W h + b)` into every dimension, fused with its loss and both
//! backward products: `shaders/loss_rows.wgsl` and `shaders/loss_columns.wgsl`; most of a
//! learning iteration's arithmetic, docs/gpu.md), and their hidden layers on the CPU's
//! read-out. With [`WgpuBackend::with_recurrence_on_gpu`], [`GpuRecurrence`] runs the
//! recurrence forward and backward with its weight gradients (`shaders/recurrence_*.wgsl`,
//! one workgroup per window) for learning and the free energy; online inference keeps the
//! recurrence on the CPU ([`Backend::load_for_inference`]: it is bound by round trips,
//! and on an H200 the GPU's recurrence made it slower, docs/gpu.md). What a GPU piece does not take (shapes its
//! kernels do not hold, calls too small to pay for a transfer) it hands to the CPU's piece
//! with the same weights, through that piece's public methods. In learning, [`GpuLearner`]
//! (pvrnn-core's [`Learner`] seam) keeps both read-outs' weights, biases and RAdam moments
//! on the GPU for the whole run, runs their hidden layers there too (`shaders/dense_*.wgsl`)
//! and updates them there (`shaders/radam.wgsl`); with the recurrence on the GPU it keeps
//! everything and runs a whole learning iteration in one submission (`iteration/`),
//! reading back only the free-energy terms. In the browser (wasm32, wgpu's `webgpu`
//! feature) the same pieces run on WebGPU and their read-backs are awaited
//! ([`WgpuBackend::open`], [`pvrnn_core::deferred`]).
//!
//! Results match the CPU backend to f32 summation order (the tests in `tests/` check the
//! free energy and every gradient against it on a CPU Vulkan device, and in headless
//! Chromium on SwiftShader's WebGPU adapter).
//!
//! Modules (the design and every kernel: the crate's README.md):
//! - `gpu`: the device, its queue, the compiled kernels (one set per hidden width), the
//!   targets kept on the device between calls.
//! - `output`: the read-outs' output layers ([`GpuOutputLayer`]) and how a call is cut
//!   into work ([`Tiling`], [`OutputKernels`]); `readout`: both read-outs as one piece
//!   ([`GpuReadout`]).
//! - This file: the backend and what a user chooses of it ([`WgpuOptions`], the `pvrnn`
//!   command's `--gpu-recurrence`, `--weights-on-host`, `--wgpu-checks` and `bench
//!   --profile-kernels`). No environment variable changes what it computes; wgpu's own
//!   `WGPU_ADAPTER_NAME` and `WGPU_BACKEND` choose the adapter.
//! - `recurrence`: the recurrence forward and backward, one workgroup per window
//!   ([`GpuRecurrence`]).
//! - `learner`: learning with the read-outs resident ([`GpuLearner`]); `resident`: a
//!   learner's tensors on the device; `iteration`: a whole learning iteration on the
//!   device, and a cohort of runs sharing one stack.
//! - `copy`: moving values between the kernels' layouts; `encode`: bind groups, dispatches
//!   and their replay; `pool`: reused buffers; `readback`: read-backs as futures.
//! - `template`: the kernels' sources expanded before compilation (shape constants,
//!   unrolled blocks, variants).
//! - `timing`, `kernel_names`: the device's own time per part and per kernel while
//!   profiling.

/// A kernel's source as the crate embeds it: `src/shaders/NAME` with its comments blanked
/// (`build.rs`), for a smaller web site.
macro_rules! shader {
    ($name:literal) => {
        include_str!(concat!(env!("OUT_DIR"), "/shaders/", $name))
    };
}

mod copy;
mod encode;
mod gpu;
mod iteration;
mod kernel_names;
mod learner;
mod output;
mod pool;
mod readback;
mod readout;
mod recurrence;
mod resident;
mod template;
mod timing;

use std::sync::Arc;

use pvrnn_core::ModelConfig;
use pvrnn_core::assembled::{AssembledModel, Parts, Recurrence};
use pvrnn_core::backend::{Backend, Learner, LoadedModel};
use pvrnn_core::cpu::CpuRecurrence;
use pvrnn_core::optim::RAdam;
use pvrnn_core::params::{Model, Params};

#[cfg(not(target_arch = "wasm32"))]
pub use gpu::probe_now;
pub use gpu::{BlockedDepth, Gpu, GpuError, RuntimeChecks, probe};
pub use learner::GpuLearner;
pub use output::{GpuOutputLayer, OutputKernels, Tiling};
pub use readout::GpuReadout;
pub use recurrence::GpuRecurrence;

/// What a user chooses of the wgpu backend; the defaults are what ships. Each non-default
/// value is either one that won a measurement for some work (`recurrence_on_gpu`, for
/// learning) or a way to compare, check or profile (docs/gpu.md, "Settings", says which
/// measurement each stands on). How a call is cut into work is [`Tiling`], which only tests
/// and benchmarks change.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct WgpuOptions {
    /// Learning and the free energy run the recurrence on the GPU too (`--gpu-recurrence`;
    /// see [`WgpuBackend::with_recurrence_on_gpu`]).
    pub recurrence_on_gpu: bool,
    /// Learning uploads the weights and reads their gradients back every iteration,
    /// updating them on the CPU (`--weights-on-host`; see
    /// [`WgpuBackend::with_resident_learning`]): to time the two paths on one machine.
    pub weights_on_host: bool,
    /// Which kernels keep wgpu's runtime checks (`--wgpu-checks`).
    pub checks: RuntimeChecks,
    /// While profiling (`pvrnn bench --profile --profile-kernels`), each dispatch of a
    /// whole iteration on the device runs in a timed pass of its own, so that the profile
    /// lists each kernel's device time (`device: kernel <label>`) as well as each part's.
    /// Off by default: a pass per dispatch lets the device drain between them, which adds
    /// to the parts' times.
    pub profile_kernels: bool,
}

/// The model's arithmetic with the output layers on a GPU (see the crate docs).
#[derive(Clone, Debug)]
pub struct WgpuBackend {
    gpu: Arc<Gpu>,
    tiling: Tiling,
    options: WgpuOptions,
}

impl WgpuBackend {
    /// Opens the first suitable adapter (high performance preferred; `WGPU_ADAPTER_NAME`
    /// and `WGPU_BACKEND` choose another) with the default options. Fails with a message a
    /// user can act on when the machine has none.
    #[cfg(not(target_arch = "wasm32"))]
    pub fn new() -> Result<Self, GpuError> {
        Self::new_with(WgpuOptions::default())
    }

    /// [`Self::new`] with `options`.
    #[cfg(not(target_arch = "wasm32"))]
    pub fn new_with(options: WgpuOptions) -> Result<Self, GpuError> {
        Ok(Self::on(Arc::new(Gpu::new(options.checks)?), options))
    }

    /// [`Self::new`] without blocking (the browser's WebGPU; see [`Gpu::open`]).
    pub async fn open() -> Result<Self, GpuError> {
        let options = WgpuOptions::default();
        Ok(Self::on(
            Arc::new(Gpu::open(options.checks).await?),
            options,
        ))
    }

    fn on(gpu: Arc<Gpu>, options: WgpuOptions) -> Self {
        Self {
            gpu,
            tiling: Tiling::default(),
            options,
        }
    }

    /// The options it was opened with, as the builders below left them.
    pub fn options(&self) -> WgpuOptions {
        self.options
    }

    /// Runs the recurrence (forward, back-propagation through time and its weight
    /// gradients) on the GPU too, instead of the CPU: a learning iteration then runs there
    /// whole ([`GpuLearner`]). A learning option: online inference keeps the recurrence on
    /// the CPU whatever this says ([`Backend::load_for_inference`]). Off by default: on an
    /// H200 it made learning faster (0.0256 against 0.0299 s per paper-scale iteration),
    /// and online inference, when it ran there too, slower (21 against 35 steps/s with
    /// 16x16 and proprioception; docs/gpu.md).
    pub fn with_recurrence_on_gpu(mut self, on: bool) -> Self {
        self.options.recurrence_on_gpu = on;
        self
    }

    /// Whether the recurrence runs on the GPU (see [`Self::with_recurrence_on_gpu`]).
    pub fn recurrence_on_gpu(&self) -> bool {
        self.options.recurrence_on_gpu
    }

    /// Whether learning keeps the output layers' weights and RAdam moments on the GPU
    /// between iterations ([`GpuLearner`]; on by default natively). Off, every iteration
    /// uploads the weights and reads their gradients back, and RAdam runs on the CPU: the
    /// way to compare the two on one machine.
    pub fn with_resident_learning(mut self, on: bool) -> Self {
        self.options.weights_on_host = !on;
        self
    }

    /// Whether learning keeps weights on the GPU (see [`Self::with_resident_learning`]).
    pub fn resident_learning(&self) -> bool {
        !self.options.weights_on_host && !cfg!(target_arch = "wasm32")
    }

    /// Each dispatch of a whole iteration on the device timed apart while profiling
    /// ([`WgpuOptions::profile_kernels`]).
    pub fn with_kernel_profile(mut self, on: bool) -> Self {
        self.options.profile_kernels = on;
        self
    }

    /// Loads `params` with the output layers in `resident` taken from a learner's buffers.
    fn load_with_layers(
        &self,
        params: &Params<f32>,
        config: &ModelConfig,
        resident: &[Option<Arc<resident::ResidentLayer>>; 2],
        recurrence_on_gpu: bool,
    ) -> Box<dyn LoadedModel<f32>> {
        let layer = GpuOutputLayer::with_resident(self.gpu.clone(), self.tiling, params, resident);
        let recurrence: Box<dyn Recurrence<f32>> = if recurrence_on_gpu {
            Box::new(GpuRecurrence::upload(
                self.gpu.clone(),
                self.tiling,
                params,
                config,
            ))
        } else {
            Box::new(CpuRecurrence::new(params, config))
        };
        let params = Arc::new(params.clone());
        let parts = Parts {
            recurrence,
            readout: Box::new(GpuReadout::new(layer, params.clone())),
            device: Some(self.gpu.clone()),
        };
        Box::new(AssembledModel::new(params, config, parts))
    }

    /// How the work is cut (tiles, chunks, the small-call threshold).
    pub fn tiling(&self) -> Tiling {
        self.tiling
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
        self.load_with_layers(params, config, &[None, None], self.recurrence_on_gpu())
    }

    /// The output layers on the GPU, the recurrence always on the CPU: online inference
    /// evaluates one short window at a time, and the GPU's recurrence (one workgroup per
    /// window, a round trip per pass) made it slower on an H200 (docs/gpu.md).
    fn load_for_inference(
        &self,
        params: &Params<f32>,
        config: &ModelConfig,
    ) -> Box<dyn LoadedModel<f32>> {
        self.load_with_layers(params, config, &[None, None], false)
    }

    /// Natively, a [`GpuLearner`] (unless [`Self::with_resident_learning`] turned it off).
    /// Not in the browser: bringing its weights back blocks on a read-back there.
    fn learner(&self, model: &Model<f32>, optimizer: &RAdam<f32>) -> Option<Box<dyn Learner<f32>>> {
        if !self.resident_learning() {
            return None;
        }
        GpuLearner::new(self, model, optimizer).map(|l| Box::new(l) as Box<dyn Learner<f32>>)
    }

    /// With the recurrence on the GPU, runs of one shape share a stack: one forward and one
    /// backward dispatch compute every window of all of them (`iteration/`). Fails
    /// naming the cohort's size when the device runs out of memory making their buffers.
    fn learners(
        &self,
        runs: &[(&Model<f32>, &RAdam<f32>)],
    ) -> pvrnn_core::Result<Vec<Option<Box<dyn Learner<f32>>>>> {
        if !self.resident_learning() {
            // No learner here (the browser): nothing to allocate.
            return Ok(runs.iter().map(|_| None).collect());
        }
        let what = || match runs.len() {
            1 => "make the buffers of a network's training".to_string(),
            n => format!("make the buffers of {n} networks trained together"),
        };
        self.gpu
            .allocating(what, || match GpuLearner::cohort(self, runs) {
                Some(learners) => learners
                    .into_iter()
                    .map(|l| Some(Box::new(l) as Box<dyn Learner<f32>>))
                    .collect(),
                None => runs
                    .iter()
                    .map(|(model, optimizer)| self.learner(model, optimizer))
                    .collect(),
            })
    }
}
