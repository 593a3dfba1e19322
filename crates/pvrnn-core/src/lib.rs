//! The scalable PV-RNN (Idei et al., "Scalable predictive processing framework for multitask
//! caregiving robots"): a hierarchical predictive-coding variational RNN over vision and
//! proprioception.
//!
//! - [`config`]: the model configuration (paper defaults, every open point a field).
//! - [`params`]: weights and adaptive variables with the spec's tensor names; [`Model`].
//! - [`data`]: model inputs ([`Observations`]), which dimensions count ([`Observed`]) and
//!   ablations.
//! - [`free_energy`]: F, its terms, and exact gradients ([`free_energy::free_energy`]);
//!   [`terms`]: the value and its accuracy and complexity terms ([`FreeEnergy`]).
//! - [`train`]: full-batch RAdam learning ([`train::Trainer`]), several runs stepped
//!   together; [`optim`]: RAdam.
//! - [`infer`]: online inference over a sliding window ([`infer::OnlineInference`]), whole
//!   runs, and a run's state between two steps, to continue it under other settings.
//! - [`io`]: safetensors files for models, checkpoints, gradients, inputs and runs.
//! - [`backend`]: the arithmetic interface; everything costly is one call,
//!   [`backend::LoadedModel::evaluate`]. [`assembled`]: the backend-neutral driver over a
//!   backend's pieces; [`cpu`] supplies the CPU's pieces (the `pvrnn-wgpu` crate the GPU's).
//! - [`deferred`]: results that arrive later, so one `async` driver serves the CPU, a native
//!   GPU and WebGPU in the browser.
//! - [`defaults`]: the one place a default backend (the CPU) is chosen.
//! - [`noise`]: seeded ChaCha8 streams keyed by purpose, iteration and sequence.
//! - `kernels` and [`real`]: SIMD dispatch, padded small matrix-vector products, vectorised
//!   element-wise maths; [`Real`] is `f32` or `f64`. `parallel`: rayon natively, a plain loop on
//!   wasm, pieces that do not depend on the thread count.
//! - [`tensor`]: the owned n-dimensional array; [`error`]: the one error type;
//!   [`profile`]: wall-clock seconds per named phase (`pvrnn bench --profile`).
//!
//! The crate has no GUI or OS dependency beyond files in [`io`] and compiles to
//! `wasm32-unknown-unknown`.

pub mod assembled;
pub mod backend;
pub mod config;
pub mod cpu;
pub mod data;
pub mod defaults;
pub mod deferred;
pub mod error;
pub mod free_energy;
pub mod infer;
pub mod io;
mod kernels;
pub mod noise;
pub mod optim;
mod parallel;
pub mod params;
pub mod profile;
pub mod real;
pub mod tensor;
pub mod terms;
pub mod train;

pub use config::{Modality, ModelConfig, ModuleId};
pub use data::{Ablation, AblationMode, Observations, Observed};
pub use defaults::run_sequence;
pub use error::{Error, Result};
pub use free_energy::FreeEnergy;
pub use noise::NoiseMode;
pub use params::Model;
pub use real::Real;
pub use tensor::Tensor;
