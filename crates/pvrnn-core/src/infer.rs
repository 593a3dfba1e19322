//! Online inference by error regression (eq. 18): weights fixed, the adaptive variables of a
//! sliding window of the last H steps are updated to minimise the window's free energy.
//!
//! At each new step t (spec, "Online inference"):
//! - the window is steps max(1, t-H+1)..t; it grows while t < H;
//! - the newest step's a starts at the prior's pre-activation from d_{t-1}; older window
//!   steps keep their a (warm start);
//! - `iterations` RAdam updates of all window a's, fresh eps each iteration, moments reset
//!   at each new step;
//! - the state entering the window is held fixed; a final pass recomputes the window, and
//!   the state after its oldest step is held for the next step once the window is full.
//!
//! A step can be run in slices ([`OnlineInference::begin_step`],
//! [`OnlineInference::iterate`], [`OnlineInference::finish_step`]) so an interactive front
//! end can spread the work over frames.

use std::sync::Arc;

use serde::{Deserialize, Serialize};

use crate::backend::{Backend, FullOutputs, Grads, LoadedModel, Posterior, Request, Trace, Window};
use crate::config::{Modality, ModelConfig, ModuleId, RAdamConfig, validate_radam};
use crate::data::{Ablation, AblationMode, Observations, Observed};
use crate::error::{Error, Result};
use crate::free_energy::FreeEnergy;
use crate::noise::{NoiseMode, Stream};
use crate::optim::RAdam;
use crate::params::Model;
use crate::{Real, Tensor};

/// Everything that determines an inference run besides the model and the data.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct InferenceSettings {
    /// H.
    pub window: usize,
    pub iterations: usize,
    pub optimizer: RAdamConfig,
    pub reset_moments_each_step: bool,
    pub observed: Observed,
    pub ablation: Ablation,
    /// When the ablation applies; files written before the modes existed ablated during
    /// inference.
    #[serde(default = "AblationMode::legacy")]
    pub ablation_mode: AblationMode,
    pub noise: NoiseMode,
}

impl InferenceSettings {
    /// The model's configured defaults, everything observed, no ablation.
    pub fn from_config(config: &ModelConfig, seed: u64) -> Self {
        Self {
            window: config.inference.window,
            iterations: config.inference.iterations,
            optimizer: config.inference.optimizer.clone(),
            reset_moments_each_step: config.inference.reset_moments_each_step,
            observed: Observed::all(config),
            ablation: Ablation::none(),
            ablation_mode: AblationMode::default(),
            noise: NoiseMode::Sampled { seed },
        }
    }

    /// The same settings with the ablation mode reset when nothing is ablated (the mode
    /// then changes nothing), so equal runs compare equal.
    pub fn canonical(mut self) -> Self {
        if self.ablation.is_none() {
            self.ablation_mode = AblationMode::default();
        }
        self
    }

    /// The ablation in force during the inference iterations.
    pub fn inference_ablation(&self) -> Ablation {
        match self.ablation_mode {
            AblationMode::Inference => self.ablation,
            AblationMode::Readout => Ablation::none(),
        }
    }

    /// The ablation applied only when the final pass is read out again.
    fn readout_only_ablation(&self) -> Option<Ablation> {
        (self.ablation_mode == AblationMode::Readout && !self.ablation.is_none())
            .then_some(self.ablation)
    }

    pub fn validate(&self, config: &ModelConfig) -> Result<()> {
        if self.window == 0 {
            return Err(Error::InvalidArgument(
                "the inference window H must be at least 1".into(),
            ));
        }
        if self.observed.vision_levels > config.vision.resolutions.len() {
            return Err(Error::InvalidArgument(format!(
                "{} vision levels observed, but the model has {}",
                self.observed.vision_levels,
                config.vision.resolutions.len()
            )));
        }
        validate_radam("inference optimizer", &self.optimizer)
    }
}

/// One module's distributions and states, row-major `[steps, width]`: at one step
/// (`steps = 1`, in a [`StepOutput`]) or stacked over a whole run (in a [`Run`], and in the
/// explorer's traces and worker messages). Widths: z for the four distributions, d for `d`
/// and `prior_d`. The one type every consumer of module states shares.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ModuleStates<T> {
    pub mu_p: Vec<T>,
    pub sigma_p: Vec<T>,
    pub mu_q: Vec<T>,
    pub sigma_q: Vec<T>,
    pub d: Vec<T>,
    /// d in the one-step-ahead prior step (x^_{t+1} is the read-out of these).
    pub prior_d: Vec<T>,
}

impl<T: Copy> ModuleStates<T> {
    /// The field names as they appear in files (`<module>.<field>`), in a fixed order.
    pub const FIELDS: [&'static str; 6] = ["mu_p", "sigma_p", "mu_q", "sigma_q", "d", "prior_d"];

    /// The fields in [`Self::FIELDS`] order.
    pub fn fields(&self) -> [&Vec<T>; 6] {
        [
            &self.mu_p,
            &self.sigma_p,
            &self.mu_q,
            &self.sigma_q,
            &self.d,
            &self.prior_d,
        ]
    }

    /// The fields in [`Self::FIELDS`] order, mutable.
    pub fn fields_mut(&mut self) -> [&mut Vec<T>; 6] {
        [
            &mut self.mu_p,
            &mut self.sigma_p,
            &mut self.mu_q,
            &mut self.sigma_q,
            &mut self.d,
            &mut self.prior_d,
        ]
    }

    /// Widths of the fields in [`Self::FIELDS`] order, for a module of these sizes.
    pub fn widths(z: usize, d: usize) -> [usize; 6] {
        [z, z, z, z, d, d]
    }

    /// Appends `other`'s steps.
    pub fn extend(&mut self, other: &Self) {
        for (mine, theirs) in self.fields_mut().into_iter().zip(other.fields()) {
            mine.extend_from_slice(theirs);
        }
    }

    /// Stacks the states of consecutive steps.
    pub fn stack<'a>(steps: impl IntoIterator<Item = &'a Self>) -> Self
    where
        T: 'a,
    {
        let mut all = Self {
            mu_p: Vec::new(),
            sigma_p: Vec::new(),
            mu_q: Vec::new(),
            sigma_q: Vec::new(),
            d: Vec::new(),
            prior_d: Vec::new(),
        };
        for s in steps {
            all.extend(s);
        }
        all
    }
}

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
struct Pending<T> {
    iterations_done: usize,
    /// The adaptive variables and the optimiser as `begin_step` left them: a step whose
    /// window diverges (a non-finite free energy or gradient) restarts from here.
    start: ([Vec<T>; 4], [Vec<T>; 4], RAdam<T>),
    rate_halvings: u32,
    /// Diverged `MAX_RATE_HALVINGS + 1` times: `finish_step` reports the error.
    gave_up: bool,
}

/// Online inference over one sequence, one step at a time.
#[derive(Debug)]
pub struct OnlineInference<T: Real> {
    model: Arc<Model<T>>,
    settings: InferenceSettings,
    loaded: Box<dyn LoadedModel<T>>,
    /// h entering the window; `None` = zeros (the window still starts at step 1).
    held_h: Option<[Vec<T>; 4]>,
    /// Window adaptive variables per module, `[len, z]`.
    a_mu: [Vec<T>; 4],
    a_sigma: [Vec<T>; 4],
    /// Observed part of each window step's input, per modality.
    observations: [Vec<Vec<T>>; 2],
    /// Names the window's targets for the backend (`Request::resident_targets`): the same
    /// for every pass of a step, new whenever `observations` changes.
    targets_id: u64,
    /// The newest step's whole observation (for its reconstruction error).
    latest: [Vec<T>; 2],
    /// State after the newest finished step.
    last_h: [Vec<T>; 4],
    last_d: [Vec<T>; 4],
    steps_done: usize,
    optimizer: RAdam<T>,
    pending: Option<Pending<T>>,
    /// Extra read-outs of every step's final pass (contribution maps in one run).
    readout_ablations: Vec<Ablation>,
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

    fn z(&self, m: usize) -> usize {
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

    async fn window_pass(
        &self,
        eps: &[Vec<T>; 4],
        ablation: Ablation,
        grads: Grads,
        full: FullOutputs,
    ) -> Result<crate::backend::WindowResult<T>> {
        let window = self.window(std::array::from_fn(|m| eps[m].as_slice()));
        let request = Request {
            observed: self.settings.observed,
            ablation,
            grads,
            full_outputs: full,
            resident_targets: Some(self.targets_id),
        };
        let mut result = self
            .loaded
            .evaluate_async(std::slice::from_ref(&window), &request)
            .await?;
        Ok(result.windows.pop().expect("one window"))
    }

    /// The window as it stands: its held state, its adaptive variables, its targets.
    fn window<'a>(&'a self, eps: [&'a [T]; 4]) -> Window<'a, T> {
        Window {
            len: self.window_len(),
            h0: self
                .held_h
                .as_ref()
                .map(|h| std::array::from_fn(|m| h[m].as_slice())),
            posterior: Posterior::Adaptive {
                a_mu: std::array::from_fn(|m| self.a_mu[m].as_slice()),
                a_sigma: std::array::from_fn(|m| self.a_sigma[m].as_slice()),
            },
            eps,
            targets: std::array::from_fn(|i| {
                self.observations[i].iter().map(Vec::as_slice).collect()
            }),
        }
    }

    fn eps(&self, stream: Stream, tags: &[u64], len: usize) -> [Vec<T>; 4] {
        std::array::from_fn(|m| {
            let mut e = vec![T::ZERO; len * self.z(m)];
            let mut key = tags.to_vec();
            key.push(m as u64);
            self.settings.noise.fill(stream, &key, &mut e);
            e
        })
    }

    /// Runs up to `max` of the step's remaining updates; returns how many are left. Fails
    /// where the backend's device failed.
    pub fn iterate(&mut self, max: usize) -> Result<usize> {
        crate::parallel::in_pool(|| crate::deferred::now(self.iterate_here(max)))
    }

    /// [`Self::iterate`] on a backend whose results arrive through the browser's event loop
    /// (WebGPU; see [`crate::deferred`]). The same updates, in the same order.
    pub async fn iterate_async(&mut self, max: usize) -> Result<usize> {
        self.iterate_here(max).await
    }

    async fn iterate_here(&mut self, max: usize) -> Result<usize> {
        let t = self.steps_done as u64;
        let mut ran = 0;
        while ran < max {
            let Some(pending) = self.pending.as_ref() else {
                return Ok(0);
            };
            let done = pending.iterations_done;
            if done >= self.settings.iterations {
                break;
            }
            let eps = self.eps(Stream::InferIteration, &[t, done as u64], self.window_len());
            let ablation = self.settings.inference_ablation();
            let result = self
                .window_pass(&eps, ablation, Grads::Adaptive, FullOutputs::None)
                .await?;
            let (Some(g_mu), Some(g_sigma)) = (result.grad_a_mu, result.grad_a_sigma) else {
                unreachable!("adaptive gradients requested")
            };
            ran += 1;
            let finite = result.accuracy.iter().flatten().all(|v| v.is_finite())
                && result
                    .trace
                    .modules
                    .iter()
                    .all(|m| m.kl.iter().all(|v| v.is_finite()))
                && g_mu
                    .iter()
                    .chain(g_sigma.iter())
                    .all(|g| g.iter().all(|v| v.is_finite()));
            if !finite {
                self.restart_step_at_half_rate();
                continue;
            }
            let grads: Vec<&[T]> = g_mu
                .iter()
                .chain(g_sigma.iter())
                .map(Vec::as_slice)
                .collect();
            let (mu, sigma) = (&mut self.a_mu, &mut self.a_sigma);
            let mut params: Vec<&mut [T]> = mu
                .iter_mut()
                .chain(sigma.iter_mut())
                .map(Vec::as_mut_slice)
                .collect();
            self.optimizer.update(&mut params, &grads);
            if let Some(pending) = self.pending.as_mut() {
                pending.iterations_done += 1;
            }
        }
        Ok(self.iterations_left())
    }

    /// The step's window diverged: back to the step's start with half the rate (the same
    /// noise draws again), or, after [`MAX_RATE_HALVINGS`] halvings, give up and let
    /// `finish_step` report it.
    fn restart_step_at_half_rate(&mut self) {
        let Some(pending) = self.pending.as_mut() else {
            return;
        };
        if pending.rate_halvings >= MAX_RATE_HALVINGS {
            pending.gave_up = true;
            pending.iterations_done = self.settings.iterations;
            return;
        }
        pending.rate_halvings += 1;
        pending.iterations_done = 0;
        let (a_mu, a_sigma, optimizer) = &pending.start;
        self.a_mu = a_mu.clone();
        self.a_sigma = a_sigma.clone();
        self.optimizer = optimizer.clone();
        self.optimizer.config.lr =
            self.settings.optimizer.lr / 2f64.powi(pending.rate_halvings as i32);
    }

    /// Final pass over the window and the outputs of the step; slides the window.
    pub fn finish_step(&mut self) -> Result<StepOutput<T>> {
        if self.pending.is_none() {
            return Err(Error::InvalidArgument(
                "finish_step called without begin_step".into(),
            ));
        }
        crate::parallel::in_pool(|| {
            crate::deferred::now(async {
                self.iterate_here(usize::MAX).await?;
                self.finish_here().await
            })
        })
    }

    /// [`Self::finish_step`] on a backend whose results arrive through the browser's event
    /// loop (see [`Self::iterate_async`]).
    pub async fn finish_step_async(&mut self) -> Result<StepOutput<T>> {
        if self.pending.is_none() {
            return Err(Error::InvalidArgument(
                "finish_step called without begin_step".into(),
            ));
        }
        self.iterate_here(usize::MAX).await?;
        self.finish_here().await
    }

    async fn finish_here(&mut self) -> Result<StepOutput<T>> {
        let t = self.steps_done;
        let len = self.window_len();
        let config = self.model.config.clone();
        let eps = self.eps(Stream::InferFinal, &[t as u64], len);
        let ablation = self.settings.inference_ablation();
        let result = self
            .window_pass(&eps, ablation, Grads::None, FullOutputs::LastStep)
            .await?;
        let trace = &result.trace;
        let mut ablated_recon: Vec<[Vec<T>; 2]> = Vec::with_capacity(self.readout_ablations.len());
        for a in &self.readout_ablations {
            let pass = self
                .window_pass(&eps, *a, Grads::None, FullOutputs::LastStep)
                .await?;
            ablated_recon.push(pass.outputs);
        }
        // A `readout` ablation: the same pass re-read with z = 0; what the step reports.
        let readout = match self.settings.readout_only_ablation() {
            Some(a) => Some(
                self.window_pass(&eps, a, Grads::None, FullOutputs::LastStep)
                    .await?,
            ),
            None => None,
        };
        let reported = readout.as_ref().unwrap_or(&result);

        let mut accuracy = [0.0; 2];
        for (sum, per_step) in accuracy.iter_mut().zip(&result.accuracy) {
            *sum = per_step.iter().sum();
        }
        let complexity: [f64; 4] = std::array::from_fn(|m| trace.modules[m].kl.iter().sum());
        let window_free_energy = FreeEnergy::from_terms(accuracy, complexity, config.kl_weight);
        let (rate_halvings, gave_up) = self
            .pending
            .as_ref()
            .map_or((0, false), |p| (p.rate_halvings, p.gave_up));
        if gave_up || !window_free_energy.total.is_finite() {
            return Err(Error::Numerical(format!(
                "online inference diverged at step {t} (window free energy {:.4e}; restarted \
                 {rate_halvings} times at half the rate); try a smaller inference lr",
                window_free_energy.total
            )));
        }
        // A halved rate is for the step that needed it; the next step starts at the rate set.
        self.optimizer.config.lr = self.settings.optimizer.lr;
        let step_accuracy = [result.accuracy[0][len - 1], result.accuracy[1][len - 1]];
        let mut modules = last_step_states(&reported.trace, &config);
        let last_state = |tr: &Trace<T>, field: fn(&crate::backend::ModuleTrace<T>) -> &Vec<T>| {
            std::array::from_fn::<Vec<T>, 4, _>(|m| {
                let d = config.module(ModuleId::ALL[m]).d;
                field(&tr.modules[m])[(len - 1) * d..len * d].to_vec()
            })
        };
        // Inference continues from the standard pass ...
        self.last_h = last_state(trace, |m| &m.h);
        self.last_d = last_state(trace, |m| &m.d);
        // ... and the prior prediction starts from the state the step reports.
        let (prior_next, prior_d) = match &readout {
            Some(r) => {
                self.prior_prediction(
                    t,
                    &last_state(&r.trace, |m| &m.h),
                    &last_state(&r.trace, |m| &m.d),
                    self.settings.ablation,
                )
                .await?
            }
            None => {
                self.prior_prediction(t, &self.last_h, &self.last_d, ablation)
                    .await?
            }
        };
        for (states, d) in modules.iter_mut().zip(prior_d) {
            states.prior_d = d;
        }
        let recon = reported.outputs.clone();
        let recon_error: [f64; 2] = std::array::from_fn(|i| {
            let n = recon[i].len().max(1) as f64;
            recon[i]
                .iter()
                .zip(&self.latest[i])
                .map(|(a, b)| (*a - *b).to_f64().powi(2))
                .sum::<f64>()
                / n
        });

        if len == self.settings.window {
            self.slide(trace);
        }
        self.pending = None;
        self.steps_done += 1;
        Ok(StepOutput {
            t,
            recon,
            prior_next,
            modules,
            recon_error,
            window_free_energy,
            step_accuracy,
            ablated_recon,
            rate_halvings,
        })
    }

    /// Slides the full window: the state after its oldest step (from the step's standard
    /// pass, `trace`) is held, and that step's adaptive variables, moments and
    /// observations leave the window.
    fn slide(&mut self, trace: &Trace<T>) {
        let config = &self.model.config;
        self.held_h = Some(std::array::from_fn(|m| {
            let d = config.module(ModuleId::ALL[m]).d;
            trace.modules[m].h[..d].to_vec()
        }));
        for m in 0..4 {
            let z = self.z(m);
            self.a_mu[m].drain(..z);
            self.a_sigma[m].drain(..z);
            for opt_i in [m, m + 4] {
                self.optimizer.m[opt_i].drain(..z);
                self.optimizer.v[opt_i].drain(..z);
            }
        }
        for rows in &mut self.observations {
            rows.remove(0);
        }
        self.targets_id = crate::data::next_id();
    }

    /// x^_{t+1} from the prior: one generation step from the state after step t with
    /// z = mu_p + sigma_p * eps; also the modules' d in that step.
    async fn prior_prediction(
        &self,
        t: usize,
        last_h: &[Vec<T>; 4],
        last_d: &[Vec<T>; 4],
        ablation: Ablation,
    ) -> Result<([Vec<T>; 2], [Vec<T>; 4])> {
        let (pre_mu, pre_sigma) = self
            .loaded
            .prior_preactivations(std::array::from_fn(|m| last_d[m].as_slice()));
        let eps = self.eps(Stream::InferPrior, &[t as u64], 1);
        let window = Window {
            len: 1,
            h0: Some(std::array::from_fn(|m| last_h[m].as_slice())),
            posterior: Posterior::Adaptive {
                a_mu: std::array::from_fn(|m| pre_mu[m].as_slice()),
                a_sigma: std::array::from_fn(|m| pre_sigma[m].as_slice()),
            },
            eps: std::array::from_fn(|m| eps[m].as_slice()),
            targets: [Vec::new(), Vec::new()],
        };
        let request = Request {
            observed: Observed {
                vision_levels: 0,
                proprio: false,
            },
            ablation,
            grads: Grads::None,
            full_outputs: FullOutputs::LastStep,
            resident_targets: None,
        };
        let mut result = self
            .loaded
            .evaluate_async(std::slice::from_ref(&window), &request)
            .await?;
        let w = result.windows.pop().expect("one window");
        let [a, b, c, d] = w.trace.modules;
        Ok((w.outputs, [a.d, b.d, c.d, d.d]))
    }

    /// begin + all iterations + finish.
    pub fn step(&mut self, x_extero: &[T], x_proprio: &[T]) -> Result<StepOutput<T>> {
        self.begin_step(x_extero, x_proprio)?;
        self.finish_step()
    }
}

/// Where an online inference stands between two steps: everything it carries from one step
/// to the next except the model, the settings and the window's inputs (the caller has those
/// and passes them back to [`OnlineInference::continue_from`]). Taken at step t and
/// continued under other settings, it branches a run: the steps before t are shared, the
/// steps from t on are inferred under the new condition.
#[derive(Clone, Debug, PartialEq)]
pub struct InferenceState<T> {
    held_h: Option<[Vec<T>; 4]>,
    a_mu: [Vec<T>; 4],
    a_sigma: [Vec<T>; 4],
    last_h: [Vec<T>; 4],
    last_d: [Vec<T>; 4],
    optimizer: RAdam<T>,
    steps_done: usize,
    window_len: usize,
}

impl<T> InferenceState<T> {
    /// Steps finished when the state was taken: the next step is this one.
    pub fn steps_done(&self) -> usize {
        self.steps_done
    }

    /// Steps in the window (the inputs [`OnlineInference::continue_from`] needs: the
    /// `window_len` steps before [`Self::steps_done`]).
    pub fn window_len(&self) -> usize {
        self.window_len
    }
}

impl<T: Real> OnlineInference<T> {
    /// The state between two steps (an error inside a step).
    pub fn state(&self) -> Result<InferenceState<T>> {
        if self.in_step() {
            return Err(Error::InvalidArgument(
                "the inference state is taken between steps, not inside one".into(),
            ));
        }
        Ok(InferenceState {
            held_h: self.held_h.clone(),
            a_mu: self.a_mu.clone(),
            a_sigma: self.a_sigma.clone(),
            last_h: self.last_h.clone(),
            last_d: self.last_d.clone(),
            optimizer: self.optimizer.clone(),
            steps_done: self.steps_done,
            window_len: self.window_len(),
        })
    }

    /// Continues from `state` under this inference's settings: the next step is
    /// `state.steps_done()`. `window_inputs` are the whole observations (exteroceptive,
    /// proprioceptive) of the window's steps, oldest first; they are read under these
    /// settings' observation, since one window has one observation condition (a branch that
    /// drops vision at t infers its whole window without it). The optimiser keeps its
    /// moments and takes these settings' rate.
    pub fn continue_from(
        &mut self,
        state: InferenceState<T>,
        window_inputs: &[(&[T], &[T])],
    ) -> Result<()> {
        if self.in_step() {
            return Err(Error::InvalidArgument(
                "continue_from called inside a step".into(),
            ));
        }
        if state.window_len > self.settings.window {
            return Err(Error::InvalidArgument(format!(
                "the state's window holds {} steps, more than this inference's H = {}",
                state.window_len, self.settings.window
            )));
        }
        if window_inputs.len() != state.window_len {
            return Err(Error::Mismatch(format!(
                "continuing needs the inputs of the window's {} steps, got {}",
                state.window_len,
                window_inputs.len()
            )));
        }
        let config = &self.model.config;
        for m in 0..4 {
            let id = ModuleId::ALL[m];
            let (z, d) = (config.module(id).z, config.module(id).d);
            let fits = state.a_mu[m].len() == state.window_len * z
                && state.a_sigma[m].len() == state.window_len * z
                && state.last_d[m].len() == d
                && state.last_h[m].len() == d
                && state.held_h.as_ref().is_none_or(|h| h[m].len() == d);
            if !fits {
                return Err(Error::Mismatch(format!(
                    "the inference state does not fit this model's {} module (z = {z}, d = {d})",
                    id.name()
                )));
            }
        }
        let first = state.steps_done - state.window_len;
        let mut rows: [Vec<Vec<T>>; 2] = Default::default();
        for (i, (x_extero, x_proprio)) in window_inputs.iter().enumerate() {
            for (modality, x) in Modality::ALL.into_iter().zip([*x_extero, *x_proprio]) {
                let dims = config.modality_dims(modality);
                let k = self.settings.observed.dims(config, modality);
                let bad = x.len() != dims || x[..k].iter().any(|v| !v.is_finite());
                if bad {
                    return Err(Error::Mismatch(format!(
                        "step {}: the {} input has {} values (the model expects {dims}) or \
                         a non-finite observed value",
                        first + i,
                        modality.name(),
                        x.len()
                    )));
                }
                rows[modality.index()].push(x[..k].to_vec());
            }
        }
        self.latest = window_inputs
            .last()
            .map(|(e, p)| [e.to_vec(), p.to_vec()])
            .unwrap_or_default();
        self.observations = rows;
        self.held_h = state.held_h;
        self.a_mu = state.a_mu;
        self.a_sigma = state.a_sigma;
        self.last_h = state.last_h;
        self.last_d = state.last_d;
        self.optimizer = state.optimizer;
        self.optimizer.config = self.settings.optimizer.clone();
        self.steps_done = state.steps_done;
        self.targets_id = crate::data::next_id();
        Ok(())
    }
}

/// Module states at the window's newest step; `prior_d` is filled in by the caller.
fn last_step_states<T: Real>(trace: &Trace<T>, config: &ModelConfig) -> [ModuleStates<T>; 4] {
    let t = trace.len - 1;
    std::array::from_fn(|m| {
        let id = ModuleId::ALL[m];
        let (d, z) = (config.module(id).d, config.module(id).z);
        let mt = &trace.modules[m];
        let row = |v: &[T], w: usize| v[t * w..(t + 1) * w].to_vec();
        ModuleStates {
            mu_p: row(&mt.mu_p, z),
            sigma_p: mt.log_sigma_p[t * z..(t + 1) * z]
                .iter()
                .map(|x| x.exp())
                .collect(),
            mu_q: row(&mt.mu_q, z),
            sigma_q: row(&mt.sigma_q, z),
            d: row(&mt.d, d),
            prior_d: Vec::new(),
        }
    })
}

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
