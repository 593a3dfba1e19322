//! The CPU backend: faer for the large products, hand-written kernels for the recurrence,
//! rayon across sequences and output-column groups (sequential on wasm).

mod readout;
mod recurrent;

use crate::Real;
use crate::backend::{
    Backend, BatchResult, ErrorRegression, FullOutputs, Grads, LoadedModel, ModuleWeightGrads,
    OutputLayer, Posterior, Recurrence, RecurrenceGrads, RecurrencePass, RegressionRequest,
    RegressionResult, Request, Trace, Window, WindowResult,
};
use crate::config::{Modality, ModelConfig, ModuleId};
use crate::data::Ablation;
use crate::parallel;
use crate::params::Params;

/// Runs the model on the CPU.
#[derive(Clone, Copy, Debug, Default)]
pub struct CpuBackend;

impl<T: Real> Backend<T> for CpuBackend {
    fn load(&self, params: &Params<T>, config: &ModelConfig) -> Box<dyn LoadedModel<T>> {
        Box::new(CpuModel::new(params, config, Offload::default()))
    }
}

/// Parts of the model's arithmetic computed elsewhere (a GPU's, loaded with the same
/// weights); whatever is `None`, or declines a call, runs on the CPU.
#[derive(Debug)]
pub struct Offload<T: Real> {
    pub output_layer: Option<Box<dyn OutputLayer<T>>>,
    pub recurrence: Option<Box<dyn Recurrence<T>>>,
    /// Online inference's updates, several at once ([`LoadedModel::regress`]).
    pub regression: Option<Box<dyn ErrorRegression<T>>>,
}

impl<T: Real> Default for Offload<T> {
    fn default() -> Self {
        Self {
            output_layer: None,
            recurrence: None,
            regression: None,
        }
    }
}

impl CpuBackend {
    /// Loads the weights with some of the work computed elsewhere (see [`Offload`]): how a
    /// backend that accelerates part of the model builds its model, the rest (learning's
    /// bookkeeping, and what it does not take) staying here.
    pub fn load_with<T: Real>(
        params: &Params<T>,
        config: &ModelConfig,
        offload: Offload<T>,
    ) -> Box<dyn LoadedModel<T>> {
        Box::new(CpuModel::new(params, config, offload))
    }
}

/// Weights in the CPU kernels' layouts.
#[derive(Debug)]
struct CpuModel<T> {
    params: Params<T>,
    config: ModelConfig,
    prepared: recurrent::Prepared<T>,
    /// Output weights transposed, per modality, made on first use by online inference.
    out_t: [std::sync::OnceLock<Vec<T>>; 2],
    /// Computes the output layers elsewhere when set (see [`OutputLayer`]).
    output_layer: Option<Box<dyn OutputLayer<T>>>,
    /// Computes the recurrence elsewhere when set (see [`Recurrence`]).
    recurrence: Option<Box<dyn Recurrence<T>>>,
    /// Runs online inference's updates elsewhere when set (see [`ErrorRegression`]).
    regression: Option<Box<dyn ErrorRegression<T>>>,
}

impl<T: Real> CpuModel<T> {
    fn new(params: &Params<T>, config: &ModelConfig, offload: Offload<T>) -> Self {
        Self {
            prepared: recurrent::Prepared::new(params, config),
            params: params.clone(),
            config: config.clone(),
            out_t: Default::default(),
            output_layer: offload.output_layer,
            recurrence: offload.recurrence,
            regression: offload.regression,
        }
    }

    /// The recurrence forward over `windows`, where the offloaded one takes it (awaited:
    /// see [`crate::deferred`]), else here.
    async fn recurrence_forward<'a>(
        &'a self,
        windows: &[Window<'_, T>],
        ablation: &Ablation,
    ) -> Box<dyn RecurrencePass<T> + 'a> {
        let _phase = crate::profile::phase("  recurrence forward");
        match self
            .recurrence
            .as_ref()
            .and_then(|r| r.forward(windows, ablation))
        {
            Some(pending) => pending.await,
            None => Box::new(CpuPass::forward(&self.prepared, windows, *ablation)),
        }
    }

    /// The read-out's hidden activations for the module states `d` (`[n, d]`), bottom
    /// first: from the offloaded layer where its hidden weights live there (a learner's,
    /// when `ask_device`: then only the top layer's), else computed here.
    async fn hidden_activations(
        &self,
        modality: Modality,
        d: &[T],
        n: usize,
        ask_device: bool,
    ) -> Vec<Vec<T>> {
        let on_device = ask_device
            .then_some(self.output_layer.as_ref())
            .flatten()
            .and_then(|o| o.hidden_top(modality, d, n));
        match on_device {
            Some(top) => vec![top.await],
            None => {
                let _phase = crate::profile::phase("  read-out hidden layers");
                readout::hidden_forward(&self.params.readouts[modality.index()], d, n)
            }
        }
    }

    fn out_t(&self, mi: usize) -> &[T] {
        self.out_t[mi].get_or_init(|| {
            let w = &self.params.readouts[mi].out.weight;
            let (rows, cols) = (w.shape()[0], w.shape()[1]);
            let mut t = vec![T::ZERO; rows * cols];
            for r in 0..rows {
                for c in 0..cols {
                    t[c * rows + r] = w.data()[r * cols + c];
                }
            }
            t
        })
    }
}

impl<T: Real> LoadedModel<T> for CpuModel<T> {
    fn evaluate(&self, windows: &[Window<'_, T>], request: &Request) -> BatchResult<T> {
        crate::deferred::now(evaluate(self, windows, request))
    }

    fn evaluate_async<'a>(
        &'a self,
        windows: &'a [Window<'a, T>],
        request: &'a Request,
    ) -> crate::deferred::Deferred<'a, BatchResult<T>> {
        Box::pin(evaluate(self, windows, request))
    }

    fn prior_preactivations(&self, d: [&[T]; 4]) -> ([Vec<T>; 4], [Vec<T>; 4]) {
        prior_preactivations(&self.params, d)
    }

    fn prior_rollout(&self, steps: usize) -> ([Vec<T>; 4], [Vec<T>; 4]) {
        prior_rollout(self, steps)
    }

    fn regress<'a>(
        &'a self,
        request: &RegressionRequest<'_, T>,
    ) -> Option<crate::deferred::Deferred<'a, RegressionResult<T>>> {
        self.regression
            .as_ref()?
            .regress(&self.params, &self.config, request)
    }

    fn regresses(&self) -> bool {
        self.regression.is_some()
    }

    fn readout(&self, modality: Modality, d: &[T], n: usize) -> Vec<T> {
        let r = &self.params.readouts[modality.index()];
        let acts = crate::deferred::now(self.hidden_activations(modality, d, n, true));
        let top: &[T] = acts.last().map(Vec::as_slice).unwrap_or(d);
        match self
            .output_layer
            .as_ref()
            .and_then(|o| o.predict(modality, top, n))
        {
            Some(prediction) => crate::deferred::now(prediction),
            None => readout::output_predict(&r.out, None, top, n),
        }
    }
}

/// One code path for every output layer: awaits only where the layer computes elsewhere
/// (see [`crate::deferred`]).
async fn evaluate<T: Real>(
    model: &CpuModel<T>,
    windows: &[Window<'_, T>],
    req: &Request,
) -> BatchResult<T> {
    let (params, config) = (&model.params, &model.config);
    let pass = model.recurrence_forward(windows, &req.ablation).await;
    let traces = pass.traces();
    let mut offsets = Vec::with_capacity(windows.len() + 1);
    let mut total = 0;
    offsets.push(total);
    for w in windows {
        total += w.len;
        offsets.push(total);
    }
    let n = offsets[windows.len()];
    let want_grads = req.grads != Grads::None;
    let all_grads = req.grads == Grads::All;
    let mut grad_params = all_grads.then(|| params.zeros_like());
    let mut accuracy: [Vec<f64>; 2] = [vec![0.0; n], vec![0.0; n]];
    let mut grad_d: [Option<Vec<T>>; 2] = [None, None];
    let mut outputs: [Vec<Vec<T>>; 2] = [
        vec![Vec::new(); windows.len()],
        vec![Vec::new(); windows.len()],
    ];

    for modality in Modality::ALL {
        let mi = modality.index();
        let module = modality.module();
        let k = req.observed.dims(config, modality);
        if k == 0 && req.full_outputs == FullOutputs::None {
            continue;
        }
        let d = config.module(module).d;
        let mut input = Vec::with_capacity(n * d);
        for tr in traces {
            input.extend_from_slice(&tr.modules[module.index()].d);
        }
        let r = &params.readouts[mi];
        let targets: Vec<&[T]> = if k > 0 {
            windows
                .iter()
                .flat_map(|w| w.targets[mi].iter().copied())
                .collect()
        } else {
            Vec::new()
        };
        if k > 0 {
            assert_eq!(
                targets.len(),
                n,
                "one {} target row per step",
                modality.name()
            );
        }
        let divisor = config
            .accuracy_normalisation
            .divisor(k, config.modality_dims(modality));
        // The whole read-out elsewhere, where its hidden layers live there too (a learner's).
        let offload = model.output_layer.as_ref();
        let whole = (k > 0).then_some(offload).flatten().and_then(|o| {
            o.readout_loss(
                modality,
                &input,
                n,
                k,
                divisor,
                &targets,
                req.resident_targets,
                all_grads,
            )
        });
        let whole_done = whole.is_some();
        if let Some(loss) = whole {
            let loss = loss.await;
            accuracy[mi] = loss.row_loss;
            if want_grads {
                grad_d[mi] = Some(loss.grad_d);
            }
            if req.full_outputs == FullOutputs::None {
                continue;
            }
        }
        // The top activations for the host's loss or the full read-outs: where the hidden
        // weights live (a learner's device, whose read-out then handled the loss, or which
        // is not observed), else here.
        let acts = model
            .hidden_activations(modality, &input, n, whole_done || k == 0)
            .await;
        let top: &[T] = acts.last().map(Vec::as_slice).unwrap_or(&input);
        let hl = top.len() / n.max(1);

        if k > 0 && !whole_done {
            // In wasm faer's product runs at half the speed of the small-row kernels; natively
            // faer is as fast at 16x16 and much faster at full vision.
            let small = cfg!(target_arch = "wasm32") && n <= readout::SMALL_ROWS && !all_grads;
            let out_t = small.then(|| model.out_t(mi));
            let output_phase = crate::profile::phase("  read-out output layer");
            let offloaded = model.output_layer.as_ref().and_then(|o| {
                o.loss(
                    modality,
                    top,
                    n,
                    k,
                    divisor,
                    &targets,
                    req.resident_targets,
                    all_grads,
                )
            });
            let loss = match offloaded {
                Some(loss) => loss.await,
                None => {
                    readout::output_loss(&r.out, out_t, top, n, k, divisor, &targets, all_grads)
                }
            };
            drop(output_phase);
            accuracy[mi] = loss.row_loss;
            if want_grads {
                let _phase = crate::profile::phase("  read-out hidden layers");
                let (g_input, layer_grads) =
                    readout::hidden_backward(r, &input, n, &acts, loss.grad_in, all_grads);
                grad_d[mi] = Some(g_input);
                if let Some(g) = grad_params.as_mut() {
                    let gr = &mut g.readouts[mi];
                    for (layer, lg) in gr.hidden.iter_mut().zip(layer_grads) {
                        layer.weight.data_mut().copy_from_slice(&lg.weight);
                        if let (Some(b), Some(gb)) = (layer.bias.as_mut(), lg.bias) {
                            b.data_mut().copy_from_slice(&gb);
                        }
                    }
                    // Unobserved rows of the output layer get no gradient.
                    if let Some(gw) = loss.grad_w {
                        gr.out.weight.data_mut()[..k * hl].copy_from_slice(&gw);
                    }
                    if let (Some(b), Some(gb)) = (gr.out.bias.as_mut(), loss.grad_b) {
                        b.data_mut()[..k].copy_from_slice(&gb);
                    }
                }
            }
        }

        if req.full_outputs != FullOutputs::None {
            let mut rows = Vec::new();
            let mut per_window = Vec::with_capacity(windows.len());
            for (i, w) in windows.iter().enumerate() {
                let range = match req.full_outputs {
                    FullOutputs::LastStep => offsets[i] + w.len - 1..offsets[i] + w.len,
                    _ => offsets[i]..offsets[i + 1],
                };
                per_window.push(range.len());
                for row in range {
                    rows.extend_from_slice(&top[row * hl..(row + 1) * hl]);
                }
            }
            let n_rows = rows.len() / hl.max(1);
            let small = cfg!(target_arch = "wasm32") && n_rows <= readout::SMALL_ROWS;
            let offloaded = model
                .output_layer
                .as_ref()
                .and_then(|o| o.predict(modality, &rows, n_rows));
            let pred = match offloaded {
                Some(prediction) => prediction.await,
                None => {
                    readout::output_predict(&r.out, small.then(|| model.out_t(mi)), &rows, n_rows)
                }
            };
            let dims = config.modality_dims(modality);
            let mut start = 0;
            for (i, count) in per_window.into_iter().enumerate() {
                outputs[mi][i] = pred[start * dims..(start + count) * dims].to_vec();
                start += count;
            }
        }
    }

    let backward_phase = crate::profile::phase("  recurrence backward");
    let grads = if want_grads {
        let from_readout: Vec<[Option<&[T]>; 4]> = (0..windows.len())
            .map(|i| {
                let rows = offsets[i]..offsets[i + 1];
                let mut per_module: [Option<&[T]>; 4] = [None; 4];
                for modality in Modality::ALL {
                    if let Some(g) = &grad_d[modality.index()] {
                        let d = config.module(modality.module()).d;
                        per_module[modality.module().index()] =
                            Some(&g[rows.start * d..rows.end * d]);
                    }
                }
                per_module
            })
            .collect();
        Some(pass.backward(&from_readout, all_grads).await)
    } else {
        None
    };
    drop(backward_phase);

    let _phase = crate::profile::phase("  collect results");
    let mut adaptive_grads = None;
    if let Some(g) = grads {
        if let (Some(gp), Some(wg)) = (grad_params.as_mut(), g.weights) {
            for (m, wg) in wg.into_iter().enumerate() {
                let mp = &mut gp.modules[m];
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
        adaptive_grads = Some(g.a_mu.into_iter().zip(g.a_sigma));
    }
    let mut results = Vec::with_capacity(windows.len());
    for (i, (trace, outs)) in pass
        .into_traces()
        .into_iter()
        .zip(transpose_outputs(outputs))
        .enumerate()
    {
        let rows = offsets[i]..offsets[i + 1];
        let (grad_a_mu, grad_a_sigma) = match adaptive_grads.as_mut().and_then(Iterator::next) {
            Some((a_mu, a_sigma)) => (Some(a_mu), Some(a_sigma)),
            None => (None, None),
        };
        results.push(WindowResult {
            trace,
            accuracy: [
                accuracy[0][rows.clone()].to_vec(),
                accuracy[1][rows].to_vec(),
            ],
            grad_a_mu,
            grad_a_sigma,
            outputs: outs,
        });
    }
    BatchResult {
        windows: results,
        grad_params,
    }
}

fn transpose_outputs<T>(outputs: [Vec<Vec<T>>; 2]) -> impl Iterator<Item = [Vec<T>; 2]> {
    let [e, p] = outputs;
    e.into_iter().zip(p).map(|(e, p)| [e, p])
}

fn add<T: Real>(acc: &mut [T], v: &[T]) {
    for (a, &b) in acc.iter_mut().zip(v) {
        *a += b;
    }
}

/// The CPU's recurrence: windows in parallel (`cpu::recurrent`), weight gradients summed
/// in window order.
#[derive(Debug)]
struct CpuPass<'a, T> {
    prepared: &'a recurrent::Prepared<T>,
    ablation: Ablation,
    traces: Vec<Trace<T>>,
}

impl<'a, T: Real> CpuPass<'a, T> {
    fn forward(
        prepared: &'a recurrent::Prepared<T>,
        windows: &[Window<'_, T>],
        ablation: Ablation,
    ) -> Self {
        let traces = parallel::map(windows.len(), |i| {
            recurrent::forward(prepared, &windows[i], &ablation)
        });
        Self {
            prepared,
            ablation,
            traces,
        }
    }
}

impl<T: Real> RecurrencePass<T> for CpuPass<'_, T> {
    fn traces(&self) -> &[Trace<T>] {
        &self.traces
    }

    fn backward<'s>(
        &'s self,
        grad_d: &[[Option<&[T]>; 4]],
        weight_grads: bool,
    ) -> crate::deferred::Deferred<'s, RecurrenceGrads<T>> {
        let per_window = parallel::map(self.traces.len(), |i| {
            recurrent::backward(
                self.prepared,
                &self.traces[i],
                grad_d[i],
                &self.ablation,
                weight_grads,
            )
        });
        let mut sum: Option<[ModuleWeightGrads<T>; 4]> = None;
        let (mut a_mu, mut a_sigma) = (Vec::new(), Vec::new());
        for g in per_window {
            a_mu.push(g.a_mu);
            a_sigma.push(g.a_sigma);
            let Some(w) = g.weights else { continue };
            match sum.as_mut() {
                None => sum = Some(w),
                Some(sum) => {
                    for (s, w) in sum.iter_mut().zip(&w) {
                        add(&mut s.w_dd, &w.w_dd);
                        add(&mut s.w_dz, &w.w_dz);
                        add(&mut s.w_dh, &w.w_dh);
                        add(&mut s.w_prior_mu, &w.w_prior_mu);
                        add(&mut s.w_prior_sigma, &w.w_prior_sigma);
                        add(&mut s.b_prior_mu, &w.b_prior_mu);
                        add(&mut s.b_prior_sigma, &w.b_prior_sigma);
                    }
                }
            }
        }
        crate::deferred::ready(RecurrenceGrads {
            a_mu,
            a_sigma,
            weights: sum,
        })
    }

    fn into_traces(self: Box<Self>) -> Vec<Trace<T>> {
        self.traces
    }
}

/// The adaptive variables of a free prior rollout from the zero state (mean path, eps = 0):
/// a = the prior's pre-activations at every step. Per module `[steps, z]`.
fn prior_rollout<T: Real>(model: &CpuModel<T>, steps: usize) -> ([Vec<T>; 4], [Vec<T>; 4]) {
    let zeros: [Vec<T>; 4] =
        ModuleId::ALL.map(|id| vec![T::ZERO; steps * model.config.module(id).z]);
    let window = Window {
        len: steps,
        h0: None,
        posterior: Posterior::Prior,
        eps: std::array::from_fn(|m| zeros[m].as_slice()),
        targets: [Vec::new(), Vec::new()],
    };
    let windows = std::slice::from_ref(&window);
    // Natively on the offloaded recurrence if any (its results are ready at once); in the
    // browser here, because this synchronous call (model initialisation) cannot wait on
    // the event loop that WebGPU's read-backs need.
    #[cfg(not(target_arch = "wasm32"))]
    let pass = crate::deferred::now(model.recurrence_forward(windows, &Ablation::none()));
    #[cfg(target_arch = "wasm32")]
    let pass = Box::new(CpuPass::forward(&model.prepared, windows, Ablation::none()));
    let trace = pass.into_traces().into_iter().next();
    let modules = trace.map(|t| t.modules).unwrap_or_default();
    (
        std::array::from_fn(|m| modules[m].pre_mu_p.clone()),
        std::array::from_fn(|m| modules[m].log_sigma_p.clone()),
    )
}

/// The prior's pre-activations `(W_prior_mu d + b, W_prior_sigma d + b)` of every module
/// for the state `d` (per module): the initial a of a new inference step.
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
