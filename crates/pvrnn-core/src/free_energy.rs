//! The free energy of a model on its training sequences (eq. 17) and its exact gradient.

use crate::Real;
use crate::backend::{Backend, FullOutputs, Grads, Posterior, Request, Window};
use crate::config::{Modality, ModelConfig, ModuleId};
use crate::data::{Ablation, Observations, Observed};
use crate::error::{Error, Result};
use crate::noise::{NoiseMode, Stream};
use crate::params::{Adaptive, Model, Params};
pub use crate::terms::{AccuracyTerms, ComplexityTerms, FreeEnergy};

/// d F / d every trainable tensor (fixed tensors hold zeros).
#[derive(Clone, Debug, PartialEq)]
pub struct Gradients<T> {
    pub params: Params<T>,
    pub adaptive: Adaptive<T>,
}

/// Which eps a full-data evaluation uses.
#[derive(Clone, Copy, Debug)]
pub struct NoiseDraw {
    pub mode: NoiseMode,
    pub(crate) stream: Stream,
    pub(crate) iteration: u64,
}

impl NoiseDraw {
    /// The draw of an evaluation (`pvrnn free-energy`).
    pub fn evaluation(mode: NoiseMode) -> Self {
        Self {
            mode,
            stream: Stream::Evaluate,
            iteration: 0,
        }
    }

    /// The draw of learning iteration `iteration`.
    pub fn training(mode: NoiseMode, iteration: u64) -> Self {
        Self {
            mode,
            stream: Stream::Train,
            iteration,
        }
    }
}

/// Fails unless the model's adaptive variables cover the data's sequences and steps.
pub fn check_model_fits_data<T: Real>(model: &Model<T>, data: &Observations<T>) -> Result<()> {
    data.check_fits(&model.config)?;
    let (s, t) = (model.adaptive.sequences(), model.adaptive.steps());
    if s != data.sequences() || t < data.steps() {
        return Err(Error::Mismatch(format!(
            "the model holds adaptive variables for {s} sequences of {t} steps, but the inputs have {} sequences of {} steps (create the model for this data with `pvrnn init --sequences {} --steps {}`)",
            data.sequences(),
            data.steps(),
            data.sequences(),
            data.steps()
        )));
    }
    Ok(())
}

/// Free energy of the model on its training data, with gradients if asked.
pub fn free_energy<T: Real>(
    backend: &dyn Backend<T>,
    model: &Model<T>,
    data: &Observations<T>,
    noise: NoiseDraw,
    with_gradients: bool,
) -> Result<(FreeEnergy, Option<Gradients<T>>)> {
    crate::deferred::now(free_energy_async(
        backend,
        model,
        data,
        noise,
        with_gradients,
    ))
}

/// [`free_energy`] on a backend whose results arrive through the browser's event loop
/// (WebGPU; see [`crate::deferred`]): the same evaluation, awaited.
pub async fn free_energy_async<T: Real>(
    backend: &dyn Backend<T>,
    model: &Model<T>,
    data: &Observations<T>,
    noise: NoiseDraw,
    with_gradients: bool,
) -> Result<(FreeEnergy, Option<Gradients<T>>)> {
    check_model_fits_data(model, data)?;
    let config = &model.config;
    let sequences = data.sequences();
    let eps = window_eps(config, data.lengths(), noise);
    let observed = Observed::all(config);
    let windows: Vec<Window<'_, T>> = (0..sequences)
        .map(|s| {
            let len = data.lengths()[s];
            Window {
                len,
                h0: None,
                posterior: Posterior::Adaptive {
                    a_mu: std::array::from_fn(|m| {
                        &model.adaptive.a_mu[m].sub(&[s])[..len * config.module(ModuleId::ALL[m]).z]
                    }),
                    a_sigma: std::array::from_fn(|m| {
                        &model.adaptive.a_sigma[m].sub(&[s])
                            [..len * config.module(ModuleId::ALL[m]).z]
                    }),
                },
                eps: std::array::from_fn(|m| eps[s][m].as_slice()),
                targets: Modality::ALL
                    .map(|modality| (0..len).map(|t| data.step(modality, s, t)).collect()),
            }
        })
        .collect();
    let request = Request {
        observed,
        ablation: Ablation::none(),
        grads: if with_gradients {
            Grads::All
        } else {
            Grads::None
        },
        full_outputs: FullOutputs::None,
        // Every sequence from its first step, in order.
        resident_targets: Some(data.id()),
    };
    let loaded = {
        let _phase = crate::profile::phase("load weights");
        backend.load(&model.params, config)
    };
    let result = {
        let _phase = crate::profile::phase("evaluate");
        loaded.evaluate_async(&windows, &request).await?
    };
    let _phase = crate::profile::phase("collect gradients");

    let mut accuracy = [0.0; 2];
    let mut complexity = [0.0; 4];
    for w in &result.windows {
        for (sum, per_step) in accuracy.iter_mut().zip(&w.accuracy) {
            *sum += per_step.iter().sum::<f64>();
        }
        for (sum, m) in complexity.iter_mut().zip(&w.trace.modules) {
            *sum += m.kl.iter().sum::<f64>();
        }
    }
    let report = FreeEnergy::from_terms(accuracy, complexity, config.kl_weight);

    let gradients = if with_gradients {
        let mut adaptive =
            Adaptive::zeros(config, model.adaptive.sequences(), model.adaptive.steps());
        for (s, w) in result.windows.iter().enumerate() {
            let (Some(g_mu), Some(g_sigma)) = (&w.grad_a_mu, &w.grad_a_sigma) else {
                unreachable!("gradients were requested")
            };
            for m in 0..4 {
                adaptive.a_mu[m].sub_mut(&[s])[..g_mu[m].len()].copy_from_slice(&g_mu[m]);
                adaptive.a_sigma[m].sub_mut(&[s])[..g_sigma[m].len()].copy_from_slice(&g_sigma[m]);
            }
        }
        Some(Gradients {
            params: result.grad_params.expect("gradients were requested"),
            adaptive,
        })
    } else {
        None
    };
    Ok((report, gradients))
}

/// eps of every training sequence of the given lengths, per sequence and module `[len, z]`:
/// what [`free_energy`] draws, for a backend that evaluates learning on its own
/// ([`crate::backend::Learner::free_energy`]).
pub fn window_eps<T: Real>(
    config: &ModelConfig,
    lengths: &[usize],
    noise: NoiseDraw,
) -> Vec<[Vec<T>; 4]> {
    let _phase = crate::profile::phase("noise");
    crate::parallel::map(lengths.len(), |s| {
        sequence_eps(config, lengths[s], noise, s as u64)
    })
}

/// eps of one training sequence, per module `[len, z]`.
fn sequence_eps<T: Real>(
    config: &ModelConfig,
    len: usize,
    noise: NoiseDraw,
    sequence: u64,
) -> [Vec<T>; 4] {
    ModuleId::ALL.map(|id| {
        let mut e = vec![T::ZERO; len * config.module(id).z];
        noise.mode.fill(
            noise.stream,
            &[noise.iteration, sequence, id.index() as u64],
            &mut e,
        );
        e
    })
}
