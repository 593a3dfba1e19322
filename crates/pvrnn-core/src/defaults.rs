//! The one place the core chooses a backend for a caller that names none: the CPU.
//!
//! Every function here is a shorthand for its `_on` / `with_backend` form with
//! [`CpuBackend`]; the rest of the core takes the backend it is given.

use std::sync::Arc;

use crate::Real;
use crate::config::ModelConfig;
use crate::cpu::CpuBackend;
use crate::data::Observations;
use crate::error::Result;
use crate::infer::{InferenceSettings, OnlineInference, Run, StepOutput, run_sequence_on};
use crate::noise::NoiseMode;
use crate::optim::RAdam;
use crate::params::Model;
use crate::train::Trainer;

impl<T: Real> Model<T> {
    /// A fresh model for `sequences` training sequences of `steps` steps
    /// ([`Model::init_on`] the CPU).
    pub fn init(config: ModelConfig, sequences: usize, steps: usize, seed: u64) -> Result<Self> {
        Self::init_on(&CpuBackend, config, sequences, steps, seed)
    }
}

impl<T: Real> Trainer<T> {
    /// A new run with fresh optimiser moments ([`Trainer::new_on`] the CPU; another
    /// backend with [`Trainer::with_backend`]).
    pub fn new(model: Model<T>, noise: NoiseMode) -> Self {
        Self::new_on(Box::new(CpuBackend), model, noise)
    }

    /// Continues a run from saved state ([`Trainer::resume_on`] the CPU).
    pub fn resume(
        model: Model<T>,
        optimizer: RAdam<T>,
        iteration: u64,
        noise: NoiseMode,
    ) -> Result<Self> {
        Self::resume_on(Box::new(CpuBackend), model, optimizer, iteration, noise)
    }
}

impl<T: Real> OnlineInference<T> {
    /// Online inference on the CPU ([`OnlineInference::with_backend`]).
    pub fn new(model: Arc<Model<T>>, settings: InferenceSettings) -> Result<Self> {
        Self::with_backend(model, settings, &CpuBackend)
    }
}

/// [`run_sequence_on`] the CPU.
pub fn run_sequence<T: Real>(
    model: Arc<Model<T>>,
    settings: InferenceSettings,
    data: &Observations<T>,
    s: usize,
    keep_outputs: bool,
    progress: &mut dyn FnMut(&StepOutput<T>, usize),
) -> Result<Run<T>> {
    run_sequence_on(
        &CpuBackend,
        model,
        settings,
        data,
        s,
        keep_outputs,
        progress,
    )
}
