//! Online inference over one sequence ([`OnlineInference`]): its state, what it reports after
//! each step ([`StepOutput`]), and beginning a step with its observation.

use std::sync::Arc;

use super::settings::InferenceSettings;
use super::states::ModuleStates;
use crate::Real;
use crate::backend::{Backend, LoadedModel};
use crate::config::{Modality, ModuleId};
use crate::data::Ablation;
use crate::error::{Error, Result};
use crate::free_energy::FreeEnergy;
use crate::optim::RAdam;
use crate::params::Model;

/// What online inference reports after step t. With a `readout` ablation, the read-outs,
/// the module states and the prior prediction come from the ablated re-read of the final
/// pass, and the free-energy terms from the standard pass that inference optimised.
#[derive(Clone, Debug, PartialEq)]
pub struct StepOutput<T> {
    /// 0-based index of the step.
    pub t: usize,
    /// Posterior reconstruction x^_t of all dimensions, per modality.
    pub recon: [Vec<T>; 2],
    /// One-step-ahead prior prediction x^_{t+1}, per modality.
    pub prior_next: [Vec<T>; 2],
    /// Each module's states at step t, with `prior_d` the d of the prior step that
    /// `prior_next` is the read-out of.
    pub modules: [ModuleStates<T>; 4],
    /// Mean squared error of `recon` against the whole observation (observed and
    /// unobserved dimensions), per modality, in model units.
    pub recon_error: [f64; 2],
    /// Free energy of the window after the updates (final pass).
    pub window_free_energy: FreeEnergy,
    /// The newest step's accuracy terms (observed dimensions), per modality.
    pub step_accuracy: [f64; 2],
    /// The reconstruction re-read with each of [`OnlineInference::set_readout_ablations`]'s
    /// ablations (in that order), per modality.
    pub ablated_recon: Vec<[Vec<T>; 2]>,
    /// How often this step's updates diverged and were restarted from the step's start at
    /// half the rate (0 almost always; see [`MAX_RATE_HALVINGS`]). The step's result is
    /// then that of a rate of `lr / 2^rate_halvings`.
    pub rate_halvings: u32,
}

/// How often a diverged step is restarted at half the rate before online inference gives
/// up with an error. `lr / 2^30` is in effect no update: the step then keeps the prior it
/// started from. Restarts are cheap (a diverging rate fails within a few updates); a
/// trained network needed 24 on a test step whose prior sigma had grown to 6,000
/// (docs/results/campaign-100k.md, 80,000 iterations).
pub const MAX_RATE_HALVINGS: u32 = 30;

#[derive(Debug)]
pub(super) struct Pending<T> {
    pub(super) iterations_done: usize,
    /// The adaptive variables and the optimiser as `begin_step` left them: a step whose
    /// window diverges (a non-finite free energy or gradient) restarts from here.
    pub(super) start: ([Vec<T>; 4], [Vec<T>; 4], RAdam<T>),
    pub(super) rate_halvings: u32,
    /// Diverged `MAX_RATE_HALVINGS + 1` times: `finish_step` reports the error.
    pub(super) gave_up: bool,
}

/// Online inference over one sequence, one step at a time.
#[derive(Debug)]
pub struct OnlineInference<T: Real> {
    pub(super) model: Arc<Model<T>>,
    pub(super) settings: InferenceSettings,
    pub(super) loaded: Box<dyn LoadedModel<T>>,
    /// h entering the window; `None` = zeros (the window still starts at step 1).
    pub(super) held_h: Option<[Vec<T>; 4]>,
    /// Window adaptive variables per module, `[len, z]`.
    pub(super) a_mu: [Vec<T>; 4],
    pub(super) a_sigma: [Vec<T>; 4],
    /// Observed part of each window step's input, per modality.
    pub(super) observations: [Vec<Vec<T>>; 2],
    /// Names the window's targets for the backend (`Request::resident_targets`): the same
    /// for every pass of a step, new whenever `observations` changes.
    pub(super) targets_id: u64,
    /// The newest step's whole observation (for its reconstruction error).
    pub(super) latest: [Vec<T>; 2],
    /// State after the newest finished step.
    pub(super) last_h: [Vec<T>; 4],
    pub(super) last_d: [Vec<T>; 4],
    pub(super) steps_done: usize,
    pub(super) optimizer: RAdam<T>,
    pub(super) pending: Option<Pending<T>>,
    /// Extra read-outs of every step's final pass (contribution maps in one run).
    pub(super) readout_ablations: Vec<Ablation>,
}

impl<T: Real> OnlineInference<T> {
    pub fn with_backend(
        model: Arc<Model<T>>,
        settings: InferenceSettings,
        backend: &dyn Backend<T>,
    ) -> Result<Self> {
        settings.validate(&model.config)?;
        let config = &model.config;
        let zeros_d = ModuleId::ALL.map(|id| vec![T::ZERO; config.module(id).d]);
        let optimizer = RAdam::new(settings.optimizer.clone(), &[0; 8]);
        Ok(Self {
            held_h: None,
            a_mu: Default::default(),
            a_sigma: Default::default(),
            observations: Default::default(),
            targets_id: crate::data::next_id(),
            latest: Default::default(),
            last_h: zeros_d.clone(),
            last_d: zeros_d,
            steps_done: 0,
            optimizer,
            pending: None,
            readout_ablations: Vec::new(),
            loaded: backend.load_for_inference(&model.params, config),
            model,
            settings,
        })
    }

    pub fn settings(&self) -> &InferenceSettings {
        &self.settings
    }

    /// Also re-reads every step's final pass with each of these ablations (one extra pass
    /// each, no effect on the inference): `StepOutput::ablated_recon`. This is how one run
    /// gives every module's `readout` contribution map.
    pub fn set_readout_ablations(&mut self, ablations: Vec<Ablation>) {
        self.readout_ablations = ablations;
    }
    pub fn model(&self) -> &Arc<Model<T>> {
        &self.model
    }
    /// Steps finished so far.
    pub fn steps_done(&self) -> usize {
        self.steps_done
    }
    /// Current window length.
    pub fn window_len(&self) -> usize {
        self.observations[0].len()
    }
    /// A step has begun and is not finished yet.
    pub fn in_step(&self) -> bool {
        self.pending.is_some()
    }

    /// Iterations still to run for the step in progress (0 when none is in progress).
    pub fn iterations_left(&self) -> usize {
        self.pending
            .as_ref()
            .map_or(0, |p| self.settings.iterations - p.iterations_done)
    }

    pub(super) fn z(&self, m: usize) -> usize {
        self.model.config.module(ModuleId::ALL[m]).z
    }

    /// Starts step t with its observation (full-length vectors; only the observed
    /// dimensions are read).
    pub fn begin_step(&mut self, x_extero: &[T], x_proprio: &[T]) -> Result<()> {
        if self.pending.is_some() {
            return Err(Error::InvalidArgument(
                "begin_step called before the previous step was finished".into(),
            ));
        }
        let config = &self.model.config;
        let mut observed_rows: [Vec<T>; 2] = Default::default();
        for (modality, x) in Modality::ALL.into_iter().zip([x_extero, x_proprio]) {
            let dims = config.modality_dims(modality);
            if x.len() != dims {
                return Err(Error::Mismatch(format!(
                    "step {}: {} observation has {} values, the model expects {dims}",
                    self.steps_done,
                    modality.name(),
                    x.len()
                )));
            }
            let k = self.settings.observed.dims(config, modality);
            if let Some(i) = x[..k].iter().position(|v| !v.is_finite()) {
                return Err(Error::NonFinite {
                    what: format!("step {} observation", self.steps_done),
                    name: modality.name().into(),
                    index: vec![i],
                    value: x[i].to_f64(),
                });
            }
            observed_rows[modality.index()] = x[..k].to_vec();
        }
        // The newest step's a = prior pre-activations from d_{t-1}.
        let (pre_mu, pre_sigma) = self
            .loaded
            .prior_preactivations(std::array::from_fn(|m| self.last_d[m].as_slice()));
        for m in 0..4 {
            self.a_mu[m].extend_from_slice(&pre_mu[m]);
            self.a_sigma[m].extend_from_slice(&pre_sigma[m]);
        }
        for (rows, row) in self.observations.iter_mut().zip(observed_rows) {
            rows.push(row);
        }
        self.targets_id = crate::data::next_id();
        self.latest = [x_extero.to_vec(), x_proprio.to_vec()];
        let sizes: Vec<usize> = (0..8).map(|i| self.a_mu[i % 4].len()).collect();
        if self.settings.reset_moments_each_step || self.steps_done == 0 {
            self.optimizer = RAdam::new(self.settings.optimizer.clone(), &sizes);
        } else {
            // Keep the moments of the steps still in the window; the new step's start at 0.
            for (i, &n) in sizes.iter().enumerate() {
                self.optimizer.m[i].resize(n, T::ZERO);
                self.optimizer.v[i].resize(n, T::ZERO);
            }
        }
        self.pending = Some(Pending {
            iterations_done: 0,
            start: (
                self.a_mu.clone(),
                self.a_sigma.clone(),
                self.optimizer.clone(),
            ),
            rate_halvings: 0,
            gave_up: false,
        });
        Ok(())
    }
}
