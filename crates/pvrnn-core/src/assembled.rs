//! The backend-neutral driver: a loaded model assembled from a backend's pieces.
//!
//! [`AssembledModel`] implements [`LoadedModel`] once, for every backend. An evaluation runs
//! the recurrence forward over a batch of windows ([`Recurrence`]), then each modality's
//! read-out and its loss on the observed dimensions ([`Readout`]), then the way back through
//! time ([`RecurrencePass::backward`]), and sums the gradients into the model's tensors.
//! A backend supplies the pieces ([`Parts`]): the CPU its kernels ([`crate::cpu`]), the GPU
//! its shaders (the `pvrnn-wgpu` crate), which hand shapes they do not take to the CPU's
//! pieces through these same traits. Pieces answer with [`Deferred`] results, so that one
//! code path serves a backend whose results arrive through the browser's event loop.

use std::sync::Arc;

use crate::backend::{
    BatchResult, FullOutputs, Grads, LoadedModel, Posterior, Request, Trace, Window, WindowResult,
};
use crate::config::{Modality, ModelConfig, ModuleId};
use crate::data::Ablation;
use crate::deferred::Deferred;
use crate::params::Params;
use crate::{Real, Result};

/// Gradients of one module's recurrent weights, summed over a batch's windows and steps
/// (row-major, the parameters' shapes). `w_dh` is empty for the top module.
#[derive(Clone, Debug)]
pub struct ModuleWeightGrads<T> {
    pub w_dd: Vec<T>,
    pub w_dz: Vec<T>,
    pub w_dh: Vec<T>,
    pub w_prior_mu: Vec<T>,
    pub w_prior_sigma: Vec<T>,
    pub b_prior_mu: Vec<T>,
    pub b_prior_sigma: Vec<T>,
}

/// What back-propagation through the recurrence returns for a batch.
#[derive(Clone, Debug)]
pub struct RecurrenceGrads<T> {
    /// Per window, d F / d a_mu and d F / d a_sigma per module, `[len, z]`.
    pub a_mu: Vec<[Vec<T>; 4]>,
    pub a_sigma: Vec<[Vec<T>; 4]>,
    /// Per module, summed over the windows in their order (when weight gradients were asked).
    pub weights: Option<[ModuleWeightGrads<T>; 4]>,
}

/// The recurrence: the modules' MTRNN updates, priors, posteriors and KL terms over a batch
/// of windows, with the weights given when the piece was made.
pub trait Recurrence<T: Real>: Send + Sync + std::fmt::Debug {
    /// Runs every window forward. The windows are read before this returns; the states may
    /// come later ([`Deferred`]: WebGPU's arrive through the browser's event loop).
    fn forward<'a>(
        &'a self,
        windows: &[Window<'_, T>],
        ablation: &Ablation,
    ) -> Deferred<'a, Box<dyn RecurrencePass<T> + 'a>>;

    /// The prior's pre-activations along a free-running rollout from the sequence start
    /// with eps = 0 (the mean path), `[steps, z]` per module. A synchronous call (model
    /// initialisation): the default runs [`Self::forward`] and waits, which a piece whose
    /// results need the browser's event loop must not do (it computes this elsewhere).
    fn prior_rollout(&self, config: &ModelConfig, steps: usize) -> ([Vec<T>; 4], [Vec<T>; 4]) {
        let zeros = prior_rollout_eps(config, steps);
        let window = prior_rollout_window(&zeros, steps);
        let pass = crate::deferred::now(self.forward(&[window], &Ablation::none()));
        rollout_of(pass)
    }
}

/// eps = 0 for every module over `steps` steps: the mean path of a prior rollout.
pub fn prior_rollout_eps<T: Real>(config: &ModelConfig, steps: usize) -> [Vec<T>; 4] {
    ModuleId::ALL.map(|id| vec![T::ZERO; steps * config.module(id).z])
}

/// The window of a prior rollout from the sequence start, with `eps` from
/// [`prior_rollout_eps`].
pub fn prior_rollout_window<T: Real>(eps: &[Vec<T>; 4], steps: usize) -> Window<'_, T> {
    Window {
        len: steps,
        h0: None,
        posterior: Posterior::Prior,
        eps: std::array::from_fn(|m| eps[m].as_slice()),
        targets: [Vec::new(), Vec::new()],
    }
}

/// A prior rollout's adaptive variables (a = the prior's pre-activations) from its pass.
pub fn rollout_of<T: Real>(pass: Box<dyn RecurrencePass<T> + '_>) -> ([Vec<T>; 4], [Vec<T>; 4]) {
    let trace = pass.into_traces().into_iter().next();
    let modules = trace.map(|t| t.modules).unwrap_or_default();
    (
        std::array::from_fn(|m| modules[m].pre_mu_p.clone()),
        std::array::from_fn(|m| modules[m].log_sigma_p.clone()),
    )
}

/// A batch run forward: its states, and what back-propagation needs of them (a GPU keeps
/// them on the device, so the backward pass uploads only the read-outs' gradients).
pub trait RecurrencePass<T: Real>: Send + std::fmt::Debug {
    /// Every window's states, in the windows' order.
    fn traces(&self) -> &[Trace<T>];

    /// Back-propagation through time. `grad_d[w][m]` is d F / d d_t of module m from its
    /// read-out in window w (`[len, d]`), if the module has an observed read-out. `grad_d`
    /// is read before this returns; the gradients may come later.
    fn backward<'s>(
        &'s self,
        grad_d: &[[Option<&[T]>; 4]],
        weight_grads: bool,
    ) -> Deferred<'s, RecurrenceGrads<T>>;

    /// The states, given up.
    fn into_traces(self: Box<Self>) -> Vec<Trace<T>>;
}

/// The output layer's results for `n` rows (`x^ = tanh(W h + b)`, fused with its loss):
/// what the CPU's and the GPU's output-layer kernels return.
#[derive(Clone, Debug)]
pub struct OutputLoss<T> {
    /// Per row: (1/divisor) * sum over the first k dimensions of 1/2 (x - x^)^2.
    pub row_loss: Vec<f64>,
    /// d F / d input (the top hidden activation), `[n, hidden]`.
    pub grad_in: Vec<T>,
    /// d F / d W for the first k rows of W, `[k, hidden]` (when weight gradients were asked).
    pub grad_w: Option<Vec<T>>,
    /// d F / d b for the first k dimensions (when weight gradients were asked and b exists).
    pub grad_b: Option<Vec<T>>,
}

/// Gradients of one dense layer, the layer's shapes.
#[derive(Clone, Debug)]
pub struct DenseGrads<T> {
    pub weight: Vec<T>,
    pub bias: Option<Vec<T>>,
}

/// A read-out's weight gradients for one batch.
#[derive(Clone, Debug)]
pub struct ReadoutWeightGrads<T> {
    /// Per hidden layer, bottom first.
    pub hidden: Vec<DenseGrads<T>>,
    /// The output layer's first k rows (the observed dimensions; the others get none):
    /// weight `[k, hidden]`, bias `[k]`. `None` where a device keeps them for its learner.
    pub output: Option<DenseGrads<T>>,
}

/// One modality's read-out over a batch's rows, and its loss on the observed dimensions.
#[derive(Clone, Copy, Debug)]
pub struct ReadoutBatch<'r, T> {
    pub modality: Modality,
    /// The module states feeding the read-out, `[n, d]`.
    pub d: &'r [T],
    pub n: usize,
    /// The observed dimensions: the first `k` of the modality.
    pub k: usize,
    /// Each row's summed squared error is divided by this (k, or the modality's dimension).
    pub divisor: usize,
    /// One target row per row of `d`, each at least `k` long.
    pub targets: &'r [&'r [T]],
    /// As [`Request::resident_targets`]: the targets may be kept on a device across calls.
    pub resident_targets: Option<u64>,
    /// Whether to compute the read-out's weight gradients.
    pub weight_grads: bool,
}

/// What [`Readout::loss`] returns.
#[derive(Clone, Debug)]
pub struct ReadoutLoss<T> {
    /// Per row, as [`OutputLoss::row_loss`].
    pub row_loss: Vec<f64>,
    /// d F / d the module states `d` that feed the read-out, `[n, d]`.
    pub grad_d: Vec<T>,
    /// With [`ReadoutBatch::weight_grads`]; `None` from a piece that keeps them on its
    /// device for its learner ([`crate::backend::Learner`]).
    pub weight_grads: Option<ReadoutWeightGrads<T>>,
}

/// Both modalities' read-outs (hidden layers, then the output layer into every dimension),
/// with the weights given when the piece was made.
pub trait Readout<T: Real>: Send + Sync + std::fmt::Debug {
    /// Forward through the read-out, the loss on the observed dimensions, and back to the
    /// module states. The batch is read before this returns; the result may come later.
    fn loss<'a>(&'a self, batch: &ReadoutBatch<'_, T>) -> Deferred<'a, ReadoutLoss<T>>;

    /// Predictions of every dimension of `modality`, `[n, dims]`, for the module states `d`
    /// (`[n, d]`). `d` is read before this returns.
    fn predict<'a>(&'a self, modality: Modality, d: &[T], n: usize) -> Deferred<'a, Vec<T>>;
}

/// A device whose queued work can fail after the call that queued it has returned (out of
/// memory, a lost device). Once it has failed, its pieces answer with values of the right
/// shapes that mean nothing; the loaded model reports [`Self::failure`] instead of them.
pub trait DeviceHealth: Send + Sync + std::fmt::Debug {
    /// The device's first failure, if it has failed.
    fn failure(&self) -> Option<crate::Error>;
}

/// The pieces a backend assembles a loaded model from.
#[derive(Debug)]
pub struct Parts<T: Real> {
    pub recurrence: Box<dyn Recurrence<T>>,
    pub readout: Box<dyn Readout<T>>,
    /// Where the pieces compute on a device that can fail ([`DeviceHealth`]); `None` on
    /// the host.
    pub device: Option<Arc<dyn DeviceHealth>>,
}

/// A loaded model: one set of weights and the pieces that compute with them.
#[derive(Debug)]
pub struct AssembledModel<T: Real> {
    params: Arc<Params<T>>,
    config: ModelConfig,
    parts: Parts<T>,
}

impl<T: Real> AssembledModel<T> {
    /// `parts` must have been made with the same weights.
    pub fn new(params: Arc<Params<T>>, config: &ModelConfig, parts: Parts<T>) -> Self {
        Self {
            params,
            config: config.clone(),
            parts,
        }
    }

    /// `value`, unless the pieces' device has failed (then what they computed means nothing).
    fn checked<V>(&self, value: V) -> Result<V> {
        match self.parts.device.as_ref().and_then(|d| d.failure()) {
            Some(failure) => Err(failure),
            None => Ok(value),
        }
    }
}

impl<T: Real> LoadedModel<T> for AssembledModel<T> {
    fn evaluate(&self, windows: &[Window<'_, T>], request: &Request) -> Result<BatchResult<T>> {
        crate::deferred::now(evaluate(self, windows, request))
    }

    fn evaluate_async<'a>(
        &'a self,
        windows: &'a [Window<'a, T>],
        request: &'a Request,
    ) -> Deferred<'a, Result<BatchResult<T>>> {
        Box::pin(evaluate(self, windows, request))
    }

    fn prior_preactivations(&self, d: [&[T]; 4]) -> ([Vec<T>; 4], [Vec<T>; 4]) {
        prior_preactivations(&self.params, d)
    }

    fn prior_rollout(&self, steps: usize) -> ([Vec<T>; 4], [Vec<T>; 4]) {
        self.parts.recurrence.prior_rollout(&self.config, steps)
    }

    fn readout(&self, modality: Modality, d: &[T], n: usize) -> Result<Vec<T>> {
        self.checked(())?;
        let prediction = crate::deferred::now(self.parts.readout.predict(modality, d, n));
        self.checked(prediction)
    }
}

/// Where each window's steps sit among a batch's rows.
struct Rows {
    offsets: Vec<usize>,
}

impl Rows {
    fn new<T>(windows: &[Window<'_, T>]) -> Self {
        let mut offsets = Vec::with_capacity(windows.len() + 1);
        offsets.push(0);
        for w in windows {
            offsets.push(offsets[offsets.len() - 1] + w.len);
        }
        Self { offsets }
    }

    fn total(&self) -> usize {
        self.offsets[self.offsets.len() - 1]
    }

    fn of(&self, window: usize) -> std::ops::Range<usize> {
        self.offsets[window]..self.offsets[window + 1]
    }

    /// The rows whose all-dimension read-outs `full` asks for, per window.
    fn full(&self, window: usize, full: FullOutputs) -> std::ops::Range<usize> {
        let rows = self.of(window);
        match full {
            FullOutputs::LastStep => rows.end.saturating_sub(1).max(rows.start)..rows.end,
            _ => rows,
        }
    }
}

/// One modality's results over a batch.
struct ModalityResults<T> {
    /// Per row.
    accuracy: Vec<f64>,
    /// d F / d the module states, `[rows, d]`, when gradients were asked and it is observed.
    grad_d: Option<Vec<T>>,
    /// Per window, the all-dimension read-outs asked for.
    outputs: Vec<Vec<T>>,
}

/// One code path for every backend: awaits only where a piece computes elsewhere (see
/// [`crate::deferred`]). Fails where the pieces' device has failed: before (it would
/// answer with nothing meaningful), after the read-outs, and at the end.
async fn evaluate<T: Real>(
    model: &AssembledModel<T>,
    windows: &[Window<'_, T>],
    req: &Request,
) -> Result<BatchResult<T>> {
    model.checked(())?;
    let pass = {
        let _phase = crate::profile::phase("  recurrence forward");
        model.parts.recurrence.forward(windows, &req.ablation).await
    };
    let rows = Rows::new(windows);
    let mut grad_params = (req.grads == Grads::All).then(|| model.params.zeros_like());
    let [vision, proprioception] = Modality::ALL;
    let traces = pass.traces();
    let vision = modality_results(model, vision, traces, windows, req, &rows, &mut grad_params);
    let vision = vision.await;
    let proprioception = modality_results(
        model,
        proprioception,
        traces,
        windows,
        req,
        &rows,
        &mut grad_params,
    );
    let per_modality = [vision, proprioception.await];
    // A device that failed in the read-outs: the way back would compute with nothing.
    model.checked(())?;

    let backward_phase = crate::profile::phase("  recurrence backward");
    let grads = if req.grads != Grads::None {
        let from_readout: Vec<[Option<&[T]>; 4]> = (0..windows.len())
            .map(|i| readout_grads_of_window(&model.config, &per_modality, rows.of(i)))
            .collect();
        Some(pass.backward(&from_readout, req.grads == Grads::All).await)
    } else {
        None
    };
    drop(backward_phase);

    let _phase = crate::profile::phase("  collect results");
    let mut adaptive_grads = None;
    if let Some(g) = grads {
        if let (Some(gp), Some(wg)) = (grad_params.as_mut(), g.weights) {
            add_recurrent_grads(gp, wg);
        }
        adaptive_grads = Some(g.a_mu.into_iter().zip(g.a_sigma));
    }
    let [vision, proprioception] = per_modality;
    let mut outputs = vision.outputs.into_iter().zip(proprioception.outputs);
    let mut results = Vec::with_capacity(windows.len());
    for (i, trace) in pass.into_traces().into_iter().enumerate() {
        let window_rows = rows.of(i);
        let (grad_a_mu, grad_a_sigma) = match adaptive_grads.as_mut().and_then(Iterator::next) {
            Some((a_mu, a_sigma)) => (Some(a_mu), Some(a_sigma)),
            None => (None, None),
        };
        let (e, p) = outputs.next().unwrap_or_default();
        results.push(WindowResult {
            trace,
            accuracy: [
                vision.accuracy[window_rows.clone()].to_vec(),
                proprioception.accuracy[window_rows].to_vec(),
            ],
            grad_a_mu,
            grad_a_sigma,
            outputs: [e, p],
        });
    }
    model.checked(BatchResult {
        windows: results,
        grad_params,
    })
}

/// One modality's read-out over the batch: its loss where it is observed (weight gradients
/// into `grad_params`), and the all-dimension read-outs the request asks for.
async fn modality_results<T: Real>(
    model: &AssembledModel<T>,
    modality: Modality,
    traces: &[Trace<T>],
    windows: &[Window<'_, T>],
    req: &Request,
    rows: &Rows,
    grad_params: &mut Option<Params<T>>,
) -> ModalityResults<T> {
    let config = &model.config;
    let n = rows.total();
    let mut results = ModalityResults {
        accuracy: vec![0.0; n],
        grad_d: None,
        outputs: vec![Vec::new(); windows.len()],
    };
    let k = req.observed.dims(config, modality);
    if k == 0 && req.full_outputs == FullOutputs::None {
        return results;
    }
    let module = modality.module();
    let width = config.module(module).d;
    let mut d = Vec::with_capacity(n * width);
    for trace in traces {
        d.extend_from_slice(&trace.modules[module.index()].d);
    }
    if k > 0 {
        let targets: Vec<&[T]> = windows
            .iter()
            .flat_map(|w| w.targets[modality.index()].iter().copied())
            .collect();
        assert_eq!(
            targets.len(),
            n,
            "one {} target row per step",
            modality.name()
        );
        let batch = ReadoutBatch {
            modality,
            d: &d,
            n,
            k,
            divisor: config
                .accuracy_normalisation
                .divisor(k, config.modality_dims(modality)),
            targets: &targets,
            resident_targets: req.resident_targets,
            weight_grads: req.grads == Grads::All,
        };
        let loss = model.parts.readout.loss(&batch).await;
        results.accuracy = loss.row_loss;
        if req.grads != Grads::None {
            results.grad_d = Some(loss.grad_d);
        }
        if let (Some(gp), Some(wg)) = (grad_params.as_mut(), loss.weight_grads) {
            set_readout_grads(gp, modality, k, wg);
        }
    }
    if req.full_outputs != FullOutputs::None {
        let mut selected = Vec::new();
        let mut counts = Vec::with_capacity(windows.len());
        for i in 0..windows.len() {
            let range = rows.full(i, req.full_outputs);
            counts.push(range.len());
            selected.extend_from_slice(&d[range.start * width..range.end * width]);
        }
        let n_rows = selected.len() / width.max(1);
        let prediction = model
            .parts
            .readout
            .predict(modality, &selected, n_rows)
            .await;
        let dims = config.modality_dims(modality);
        let mut start = 0;
        for (i, count) in counts.into_iter().enumerate() {
            results.outputs[i] = prediction[start * dims..(start + count) * dims].to_vec();
            start += count;
        }
    }
    results
}

/// d F / d d per module from the read-outs, for one window's rows.
fn readout_grads_of_window<'g, T: Real>(
    config: &ModelConfig,
    per_modality: &'g [ModalityResults<T>; 2],
    rows: std::ops::Range<usize>,
) -> [Option<&'g [T]>; 4] {
    let mut per_module: [Option<&[T]>; 4] = [None; 4];
    for modality in Modality::ALL {
        if let Some(g) = &per_modality[modality.index()].grad_d {
            let d = config.module(modality.module()).d;
            per_module[modality.module().index()] = Some(&g[rows.start * d..rows.end * d]);
        }
    }
    per_module
}

/// A read-out's weight gradients into the model's tensors (the output layer's unobserved
/// rows get none).
fn set_readout_grads<T: Real>(
    grads: &mut Params<T>,
    modality: Modality,
    k: usize,
    weights: ReadoutWeightGrads<T>,
) {
    let readout = &mut grads.readouts[modality.index()];
    for (layer, g) in readout.hidden.iter_mut().zip(weights.hidden) {
        layer.weight.data_mut().copy_from_slice(&g.weight);
        if let (Some(b), Some(gb)) = (layer.bias.as_mut(), g.bias) {
            b.data_mut().copy_from_slice(&gb);
        }
    }
    let Some(output) = weights.output else {
        return;
    };
    let hidden = readout.out.weight.shape()[1];
    readout.out.weight.data_mut()[..k * hidden].copy_from_slice(&output.weight);
    if let (Some(b), Some(gb)) = (readout.out.bias.as_mut(), output.bias) {
        b.data_mut()[..k].copy_from_slice(&gb);
    }
}

fn add_recurrent_grads<T: Real>(grads: &mut Params<T>, weights: [ModuleWeightGrads<T>; 4]) {
    for (m, wg) in weights.into_iter().enumerate() {
        let mp = &mut grads.modules[m];
        add(mp.w_dd.data_mut(), &wg.w_dd);
        add(mp.w_dz.data_mut(), &wg.w_dz);
        if let Some(w) = mp.w_dh.as_mut() {
            add(w.data_mut(), &wg.w_dh);
        }
        add(mp.w_prior_mu.data_mut(), &wg.w_prior_mu);
        add(mp.w_prior_sigma.data_mut(), &wg.w_prior_sigma);
        if let Some(b) = mp.b_prior_mu.as_mut() {
            add(b.data_mut(), &wg.b_prior_mu);
        }
        if let Some(b) = mp.b_prior_sigma.as_mut() {
            add(b.data_mut(), &wg.b_prior_sigma);
        }
    }
}

/// `acc += v`, element by element.
pub fn add<T: Real>(acc: &mut [T], v: &[T]) {
    for (a, &b) in acc.iter_mut().zip(v) {
        *a += b;
    }
}

/// The prior's pre-activations `(W_prior_mu d + b, W_prior_sigma d + b)` of every module
/// for the state `d` (per module): the initial a of a new inference step. A few small
/// products, on the host for every backend.
fn prior_preactivations<T: Real>(params: &Params<T>, d: [&[T]; 4]) -> ([Vec<T>; 4], [Vec<T>; 4]) {
    let product = |w: &crate::Tensor<T>, b: Option<&crate::Tensor<T>>, x: &[T]| -> Vec<T> {
        let cols = w.shape()[1];
        w.data()
            .chunks_exact(cols)
            .enumerate()
            .map(|(j, row)| {
                let mut s = b.map_or(T::ZERO, |b| b.data()[j]);
                for (&wi, &xi) in row.iter().zip(x) {
                    s += wi * xi;
                }
                s
            })
            .collect()
    };
    let mu = std::array::from_fn(|m| {
        let p = &params.modules[m];
        product(&p.w_prior_mu, p.b_prior_mu.as_ref(), d[m])
    });
    let sigma = std::array::from_fn(|m| {
        let p = &params.modules[m];
        product(&p.w_prior_sigma, p.b_prior_sigma.as_ref(), d[m])
    });
    (mu, sigma)
}
