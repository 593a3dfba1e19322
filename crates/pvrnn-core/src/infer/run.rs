//! Whole runs: one sequence's inference stacked over steps ([`Run`]), and running online
//! inference over every step of a sequence ([`run_sequence_on`]).

use std::sync::Arc;

use super::online::{OnlineInference, StepOutput};
use super::settings::InferenceSettings;
use super::states::ModuleStates;
use crate::backend::Backend;
use crate::config::Modality;
use crate::data::Observations;
use crate::error::{Error, Result};
use crate::free_energy::FreeEnergy;
use crate::params::Model;
use crate::{Real, Tensor};

/// A whole inference run of one sequence, stacked over steps.
#[derive(Clone, Debug, PartialEq)]
pub struct Run<T> {
    pub settings: InferenceSettings,
    /// Per modality `[steps, dims]`: reconstructions and one-step prior predictions of all
    /// dimensions. `None` in compact runs: they are the read-outs of `d` and `prior_d`
    /// ([`crate::backend::LoadedModel::readout`]), so a compact run can still show them.
    pub recon: Option<[Tensor<T>; 2]>,
    pub prior_next: Option<[Tensor<T>; 2]>,
    /// Per module, stacked over steps.
    pub modules: [ModuleStates<T>; 4],
    /// Per step: window free energy, the newest step's accuracy terms, and its
    /// reconstruction error (all dimensions) per modality.
    pub free_energy: Vec<FreeEnergy>,
    pub step_accuracy: Vec<[f64; 2]>,
    pub recon_error: Vec<[f64; 2]>,
}

impl<T: Real> Run<T> {
    pub fn steps(&self) -> usize {
        self.free_energy.len()
    }

    /// Stacks per-step outputs; `keep_outputs` keeps the full read-outs (large: two
    /// vision vectors per step).
    pub fn from_steps(
        settings: InferenceSettings,
        steps: &[StepOutput<T>],
        keep_outputs: bool,
    ) -> Self {
        let n = steps.len();
        let stack = |f: &dyn Fn(&StepOutput<T>) -> &[T]| -> Tensor<T> {
            let w = steps.first().map_or(0, |s| f(s).len());
            let mut data = Vec::with_capacity(n * w);
            for s in steps {
                data.extend_from_slice(f(s));
            }
            Tensor::from_vec(&[n, w], data).expect("every step has the same sizes")
        };
        Self {
            recon: keep_outputs.then(|| std::array::from_fn(|i| stack(&|s| &s.recon[i]))),
            prior_next: keep_outputs.then(|| std::array::from_fn(|i| stack(&|s| &s.prior_next[i]))),
            modules: std::array::from_fn(|m| {
                ModuleStates::stack(steps.iter().map(|s| &s.modules[m]))
            }),
            free_energy: steps.iter().map(|s| s.window_free_energy).collect(),
            step_accuracy: steps.iter().map(|s| s.step_accuracy).collect(),
            recon_error: steps.iter().map(|s| s.recon_error).collect(),
            settings,
        }
    }
}

/// Runs online inference over sequence `s` of `data` (all of its steps) on `backend`,
/// calling `progress(step, length)` after each step with its output (`step.t + 1` steps
/// are done) and the sequence's length; `keep_outputs` as in [`Run::from_steps`]
/// ([`crate::defaults::run_sequence`]: on the CPU).
pub fn run_sequence_on<T: Real>(
    backend: &dyn Backend<T>,
    model: Arc<Model<T>>,
    settings: InferenceSettings,
    data: &Observations<T>,
    s: usize,
    keep_outputs: bool,
    progress: &mut dyn FnMut(&StepOutput<T>, usize),
) -> Result<Run<T>> {
    data.check_fits(&model.config)?;
    if s >= data.sequences() {
        return Err(Error::InvalidArgument(format!(
            "sequence {s} does not exist (the inputs hold {})",
            data.sequences()
        )));
    }
    let mut inference = OnlineInference::with_backend(model, settings.clone(), backend)?;
    let len = data.lengths()[s];
    let mut steps = Vec::with_capacity(len);
    for t in 0..len {
        let step = inference.step(
            data.step(Modality::Exteroceptive, s, t),
            data.step(Modality::Proprioceptive, s, t),
        )?;
        progress(&step, len);
        steps.push(step);
    }
    Ok(Run::from_steps(settings, &steps, keep_outputs))
}
