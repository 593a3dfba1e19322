//! The seam between the model's bookkeeping (learning loop, sliding window, optimiser, I/O)
//! and the arithmetic.
//!
//! A [`Backend`] turns parameters into a [`LoadedModel`] (the CPU backend lays weights out
//! for its kernels; the GPU backend uploads them). Everything expensive then happens in
//! one call: [`LoadedModel::evaluate`] runs a batch of windows (whole sequences in learning,
//! the sliding window in inference) forward, computes the free energy on the observed
//! dimensions, and optionally back-propagates through time. Both backends build their
//! loaded model the same way: [`crate::assembled::AssembledModel`], the backend-neutral
//! driver, over the pieces each supplies (its recurrence and its read-outs). The CPU's
//! are in [`crate::cpu`], the GPU's in the `pvrnn-wgpu` crate; nothing above these traits
//! knows which runs.

use crate::Real;
use crate::config::{Modality, ModelConfig};
use crate::data::{Ablation, Observations, Observed};
use crate::deferred::Deferred;
use crate::error::Result;
use crate::optim::{RAdam, RAdamStep};
use crate::params::{Model, Params};
use crate::terms::FreeEnergy;

/// Where the adaptive variables of a window come from.
#[derive(Clone, Copy, Debug)]
pub enum Posterior<'a, T> {
    /// `a_mu`, `a_sigma` per module, each `[len, z]` row-major.
    Adaptive {
        a_mu: [&'a [T]; 4],
        a_sigma: [&'a [T]; 4],
    },
    /// The posterior equals the prior at every step (a = the prior's pre-activations):
    /// free generation, and the initial value of a.
    Prior,
}

/// One window: consecutive steps of one sequence.
#[derive(Clone, Debug)]
pub struct Window<'a, T> {
    pub len: usize,
    /// Internal state h entering the window, per module; `None` = zeros (sequence start).
    pub h0: Option<[&'a [T]; 4]>,
    pub posterior: Posterior<'a, T>,
    /// eps per module, `[len, z]`.
    pub eps: [&'a [T]; 4],
    /// Per modality, one target row per step (at least the observed dimensions long);
    /// may be empty for a modality that is not observed.
    pub targets: [Vec<&'a [T]>; 2],
}

/// What gradients to compute.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Grads {
    None,
    /// Only the adaptive variables (online inference).
    Adaptive,
    /// Adaptive variables and every weight (learning).
    All,
}

/// For which steps to compute the read-outs of *all* dimensions (observed or not).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FullOutputs {
    None,
    LastStep,
    AllSteps,
}

#[derive(Clone, Copy, Debug)]
pub struct Request {
    pub observed: Observed,
    pub ablation: Ablation,
    pub grads: Grads,
    pub full_outputs: FullOutputs,
    /// A promise about the targets: every call with the same id has the same windows'
    /// target rows, so a backend may keep them on its device across calls instead of
    /// uploading them each time. Learning's full batch passes its data's
    /// [`crate::Observations::id`]; online inference a fresh id per step's window (its 50
    /// updates see the same targets).
    pub resident_targets: Option<u64>,
}

/// Per-step states of one module over a window, row-major `[len, dim]`.
#[derive(Clone, Debug, Default)]
pub struct ModuleTrace<T> {
    /// State entering the window, `[d]`.
    pub h0: Vec<T>,
    pub d0: Vec<T>,
    pub h: Vec<T>,
    pub d: Vec<T>,
    /// Prior mean, its pre-activation, and log sigma.
    pub mu_p: Vec<T>,
    pub pre_mu_p: Vec<T>,
    pub log_sigma_p: Vec<T>,
    /// 1 / sigma_p^2, kept for the backward pass.
    pub inv_var_p: Vec<T>,
    /// Posterior mean, log sigma and sigma.
    pub mu_q: Vec<T>,
    pub log_sigma_q: Vec<T>,
    pub sigma_q: Vec<T>,
    pub z: Vec<T>,
    /// Per step: KL[q || p] / z (the complexity term before W).
    pub kl: Vec<f64>,
}

#[derive(Clone, Debug)]
pub struct Trace<T> {
    pub len: usize,
    pub modules: [ModuleTrace<T>; 4],
}

/// Results for one window.
#[derive(Clone, Debug)]
pub struct WindowResult<T> {
    pub trace: Trace<T>,
    /// Per modality, per step: (1 / observed dims) * sum 1/2 (x - x^)^2; zeros if unobserved.
    pub accuracy: [Vec<f64>; 2],
    /// d F / d a_mu and d F / d a_sigma per module, `[len, z]` (when gradients were requested).
    pub grad_a_mu: Option<[Vec<T>; 4]>,
    pub grad_a_sigma: Option<[Vec<T>; 4]>,
    /// Per modality, all-dimension read-outs of the requested steps, `[steps, dims]`.
    pub outputs: [Vec<T>; 2],
}

#[derive(Clone, Debug)]
pub struct BatchResult<T> {
    pub windows: Vec<WindowResult<T>>,
    /// d F / d every weight (fixed tensors are zero), with `Grads::All`.
    pub grad_params: Option<Params<T>>,
}

/// An implementation of the model's arithmetic.
pub trait Backend<T: Real>: Send + Sync + std::fmt::Debug {
    /// Prepares a set of weights for evaluation. Weights are fixed for the loaded model's
    /// lifetime: learning loads once per iteration, inference once per run.
    fn load(&self, params: &Params<T>, config: &ModelConfig) -> Box<dyn LoadedModel<T>>;

    /// [`Self::load`] for online inference ([`crate::infer::OnlineInference`]), where a
    /// backend may put the work elsewhere than for learning: inference evaluates one short
    /// window at a time, many times per step, so it is bound by round trips where learning
    /// is bound by arithmetic. The default is [`Self::load`].
    fn load_for_inference(
        &self,
        params: &Params<T>,
        config: &ModelConfig,
    ) -> Box<dyn LoadedModel<T>> {
        self.load(params, config)
    }

    /// A learning run's weights kept on the backend's device between iterations (see
    /// [`Learner`]), starting from `model` and `optimizer`; `None` (the default, and the
    /// CPU's answer) loads the weights every iteration and updates them on the host.
    fn learner(&self, model: &Model<T>, optimizer: &RAdam<T>) -> Option<Box<dyn Learner<T>>> {
        let _ = (model, optimizer);
        None
    }

    /// Learners for several runs trained together (a cohort, [`crate::train::step_together`]):
    /// a device may lay them out side by side so that one dispatch computes all of them.
    /// The default makes each alone ([`Self::learner`]). Fails where the device's memory
    /// does not hold them all ([`crate::Error::Device`]).
    fn learners(
        &self,
        runs: &[(&Model<T>, &RAdam<T>)],
    ) -> Result<Vec<Option<Box<dyn Learner<T>>>>> {
        Ok(runs
            .iter()
            .map(|(model, optimizer)| self.learner(model, optimizer))
            .collect())
    }
}

/// A shared backend is a backend (one GPU serving several trainings and inference runs).
impl<T: Real> Backend<T> for std::sync::Arc<dyn Backend<T>> {
    fn load(&self, params: &Params<T>, config: &ModelConfig) -> Box<dyn LoadedModel<T>> {
        (**self).load(params, config)
    }

    fn load_for_inference(
        &self,
        params: &Params<T>,
        config: &ModelConfig,
    ) -> Box<dyn LoadedModel<T>> {
        (**self).load_for_inference(params, config)
    }

    fn learner(&self, model: &Model<T>, optimizer: &RAdam<T>) -> Option<Box<dyn Learner<T>>> {
        (**self).learner(model, optimizer)
    }

    fn learners(
        &self,
        runs: &[(&Model<T>, &RAdam<T>)],
    ) -> Result<Vec<Option<Box<dyn Learner<T>>>>> {
        (**self).learners(runs)
    }
}

/// Learning with some trainable tensors and their optimiser moments resident on a device:
/// uploaded once, their gradients computed and their RAdam update applied there, so that an
/// iteration moves neither those weights up nor their gradients back (at the paper's scale
/// the vision output layer: 1.6 M of the model's 1.7 M weights). [`crate::train::Trainer`]
/// drives it: it evaluates through the learner (a [`Backend`] whose loaded models use the
/// device's copies of the resident tensors and leave their gradients there), calls
/// [`Self::update`] with the step's scalars, updates the other tensors on the host, and
/// downloads the resident ones before anything reads the model or the optimiser.
pub trait Learner<T: Real>: Backend<T> {
    /// The resident tensors, as indices into [`crate::train::trainable_names`]' order. The
    /// host's copies of them (values and moments) are stale until [`Self::download`], and a
    /// loaded model's gradient for them is not computed on the host (it reads zero).
    fn resident(&self) -> &[usize];

    /// Queues one RAdam step of the resident tensors on the device, with the gradients of
    /// the last evaluation with weight gradients (zero for a tensor it did not reach, as on
    /// the host). Models loaded afterwards see the new values.
    fn update(&self, step: &RAdamStep);

    /// Copies resident tensor `index` (one of [`Self::resident`]) and its two moments from
    /// the device into the host's slices.
    fn download(&self, index: usize, value: &mut [T], m: &mut [T], v: &mut [T]);

    /// The device's first failure (out of memory, a lost device), after which what
    /// [`Self::download`] gives means nothing. `None` (the default): it has not failed.
    fn failure(&self) -> Option<crate::Error> {
        None
    }

    /// Whether this learner keeps every trainable tensor on its device and evaluates a
    /// learning iteration there whole ([`Self::free_energy`] then always answers).
    fn runs_whole_iterations(&self) -> bool {
        false
    }

    /// A whole learning evaluation on the device, for a learner that keeps every trainable
    /// tensor there, the adaptive variables and the recurrence included: the free energy
    /// of the device's model on `data` (all of it observed, no ablation, as
    /// [`crate::free_energy::free_energy`]), with every gradient left on the device for
    /// [`Self::update`], so that only the free-energy terms come back. `eps` per sequence
    /// and module, `[len, z]` ([`crate::free_energy::window_eps`]). `None` (the default):
    /// the trainer evaluates through [`Backend::load`] and updates the tensors that are not
    /// resident on the host. A learner that [`Self::runs_whole_iterations`] must answer.
    fn free_energy(
        &self,
        data: &Observations<T>,
        eps: &[[Vec<T>; 4]],
    ) -> Option<Result<FreeEnergy>> {
        let _ = (data, eps);
        None
    }

    /// [`Self::free_energy`] started now and finished when the result is awaited: a learner
    /// on a device queues the iteration and returns, so that several learning runs on one
    /// device (a cohort, [`crate::train::step_together`]) are all queued before the host
    /// waits for the first. The default computes it at once.
    fn begin_free_energy<'a>(
        &'a self,
        data: &'a Observations<T>,
        eps: &'a [[Vec<T>; 4]],
    ) -> Option<Deferred<'a, Result<FreeEnergy>>> {
        self.free_energy(data, eps).map(crate::deferred::ready)
    }

    /// Whether [`Self::update`] is skipped on the device when the evaluation queued before
    /// it gave a free energy that is not finite (the trainer then downloads the learner's
    /// tensors, as they were, and makes a new one). Such a learner lets the trainer queue an
    /// iteration's update, and the next iteration's evaluation ([`Self::queue_free_energy`]),
    /// before it has read the free energy back, so that the device never waits for the
    /// host. The default: no, the trainer checks first.
    fn guards_updates(&self) -> bool {
        false
    }

    /// Queues the evaluation [`Self::begin_free_energy`] would begin for `data` and `eps`,
    /// for the next call of it with the same `data` and `eps` to take (any other call drops
    /// it); it starts at [`Self::submit_queued`]. The default queues nothing.
    fn queue_free_energy(&self, data: &Observations<T>, eps: &[[Vec<T>; 4]]) -> Result<()> {
        let _ = (data, eps);
        Ok(())
    }

    /// Starts on the device, without waiting, what is queued there: begun and queued
    /// evaluations (of every run sharing it, a cohort's in one submission). Awaiting an
    /// evaluation starts it too. The default has nothing to start.
    fn submit_queued(&self) {}
}

/// Weights ready for evaluation on one backend. Everything the model computes goes through
/// these methods, so a model, a learning run, online inference and the explorer's read-outs
/// run on whichever backend loaded the weights.
pub trait LoadedModel<T: Real>: Send + Sync + std::fmt::Debug {
    /// Forward pass, free energy and (optionally) back-propagation through time for a batch
    /// of windows. The free energy is F = sum_steps [accuracy terms + W * complexity terms].
    /// Fails where the device computing it failed ([`crate::Error::Device`]: out of memory,
    /// a lost device), never with results that mean nothing.
    fn evaluate(&self, windows: &[Window<'_, T>], request: &Request) -> Result<BatchResult<T>>;

    /// [`Self::evaluate`] for a backend whose results arrive through an event loop
    /// (WebGPU in the browser, see [`crate::deferred`]); the others finish it at once.
    fn evaluate_async<'a>(
        &'a self,
        windows: &'a [Window<'a, T>],
        request: &'a Request,
    ) -> Deferred<'a, Result<BatchResult<T>>> {
        crate::deferred::ready(self.evaluate(windows, request))
    }

    /// The prior's pre-activations `(W_prior_mu d + b, W_prior_sigma d + b)` of every
    /// module for the states `d` (one per module): the initial a of a new inference step.
    fn prior_preactivations(&self, d: [&[T]; 4]) -> ([Vec<T>; 4], [Vec<T>; 4]);

    /// The prior's pre-activations along a free-running rollout from the sequence start
    /// with eps = 0 (the mean path), `[steps, z]` per module: the initial adaptive variables
    /// of `posterior_init = "prior"`.
    fn prior_rollout(&self, steps: usize) -> ([Vec<T>; 4], [Vec<T>; 4]);

    /// The read-out of `n` module states `d` (`[n, d]` row-major) into predictions of every
    /// dimension of `modality` (`[n, dims]`): how a compact run's images and
    /// proprioception are reconstructed. Fails as [`Self::evaluate`].
    fn readout(&self, modality: Modality, d: &[T], n: usize) -> Result<Vec<T>>;
}
