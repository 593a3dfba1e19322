//! The CPU backend: faer for the large products, hand-written kernels for the recurrence,
//! rayon across sequences and output-column groups (sequential on wasm).

mod readout;
mod recurrent;

use crate::Real;
use crate::backend::{
    Backend, BatchResult, FullOutputs, Grads, LoadedModel, OutputLayer, Posterior, Request, Window,
    WindowResult,
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
        Box::new(CpuModel::new(params, config, None))
    }
}

impl CpuBackend {
    /// Loads the weights with the read-outs' output layers computed by `output_layer` (a
    /// GPU's, loaded with the same weights) and everything else on the CPU: how a backend
    /// that accelerates only the dominant product builds its model.
    pub fn load_with_output_layer<T: Real>(
        params: &Params<T>,
        config: &ModelConfig,
        output_layer: Box<dyn OutputLayer<T>>,
    ) -> Box<dyn LoadedModel<T>> {
        Box::new(CpuModel::new(params, config, Some(output_layer)))
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
}

impl<T: Real> CpuModel<T> {
    fn new(
        params: &Params<T>,
        config: &ModelConfig,
        output_layer: Option<Box<dyn OutputLayer<T>>>,
    ) -> Self {
        Self {
            prepared: recurrent::Prepared::new(params, config),
            params: params.clone(),
            config: config.clone(),
            out_t: Default::default(),
            output_layer,
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
        evaluate(self, windows, request)
    }

    fn prior_preactivations(&self, d: [&[T]; 4]) -> ([Vec<T>; 4], [Vec<T>; 4]) {
        prior_preactivations(&self.params, d)
    }

    fn prior_rollout(&self, steps: usize) -> ([Vec<T>; 4], [Vec<T>; 4]) {
        let r = prior_rollout(&self.prepared, &self.config, steps);
        (r.a_mu, r.a_sigma)
    }

    fn readout(&self, modality: Modality, d: &[T], n: usize) -> Vec<T> {
        let r = &self.params.readouts[modality.index()];
        let acts = readout::hidden_forward(r, d, n);
        let top: &[T] = acts.last().map(Vec::as_slice).unwrap_or(d);
        self.output_layer
            .as_ref()
            .and_then(|o| o.predict(modality, top, n))
            .unwrap_or_else(|| readout::output_predict(&r.out, None, top, n))
    }
}

fn evaluate<T: Real>(
    model: &CpuModel<T>,
    windows: &[Window<'_, T>],
    req: &Request,
) -> BatchResult<T> {
    let (params, config, prepared) = (&model.params, &model.config, &model.prepared);
    let forward_phase = crate::profile::phase("  recurrence forward");
    let traces = parallel::map(windows.len(), |i| {
        recurrent::forward(prepared, &windows[i], &req.ablation)
    });
    drop(forward_phase);
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
        for tr in &traces {
            input.extend_from_slice(&tr.modules[module.index()].d);
        }
        let r = &params.readouts[mi];
        let hidden_phase = crate::profile::phase("  read-out hidden layers");
        let acts = readout::hidden_forward(r, &input, n);
        drop(hidden_phase);
        let top: &[T] = acts.last().map(Vec::as_slice).unwrap_or(&input);
        let hl = top.len() / n.max(1);

        if k > 0 {
            let targets: Vec<&[T]> = windows
                .iter()
                .flat_map(|w| w.targets[mi].iter().copied())
                .collect();
            assert_eq!(
                targets.len(),
                n,
                "one {} target row per step",
                modality.name()
            );
            // In wasm faer's product runs at half the speed of the small-row kernels; natively
            // faer is as fast at 16x16 and much faster at full vision.
            let small = cfg!(target_arch = "wasm32") && n <= readout::SMALL_ROWS && !all_grads;
            let out_t = small.then(|| model.out_t(mi));
            let divisor = config
                .accuracy_normalisation
                .divisor(k, config.modality_dims(modality));
            let output_phase = crate::profile::phase("  read-out output layer");
            let loss = model
                .output_layer
                .as_ref()
                .and_then(|o| {
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
                })
                .unwrap_or_else(|| {
                    readout::output_loss(&r.out, out_t, top, n, k, divisor, &targets, all_grads)
                });
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
            let pred = model
                .output_layer
                .as_ref()
                .and_then(|o| o.predict(modality, &rows, n_rows))
                .unwrap_or_else(|| {
                    readout::output_predict(&r.out, small.then(|| model.out_t(mi)), &rows, n_rows)
                });
            let dims = config.modality_dims(modality);
            let mut start = 0;
            for (i, count) in per_window.into_iter().enumerate() {
                outputs[mi][i] = pred[start * dims..(start + count) * dims].to_vec();
                start += count;
            }
        }
    }

    let backward_phase = crate::profile::phase("  recurrence backward");
    let window_grads = want_grads.then(|| {
        parallel::map(windows.len(), |i| {
            let rows = offsets[i]..offsets[i + 1];
            let mut from_readout: [Option<&[T]>; 4] = [None; 4];
            for modality in Modality::ALL {
                if let Some(g) = &grad_d[modality.index()] {
                    let d = config.module(modality.module()).d;
                    from_readout[modality.module().index()] =
                        Some(&g[rows.start * d..rows.end * d]);
                }
            }
            recurrent::backward(prepared, &traces[i], from_readout, &req.ablation, all_grads)
        })
    });

    drop(backward_phase);
    let _phase = crate::profile::phase("  collect results");
    let mut results = Vec::with_capacity(windows.len());
    let mut window_grads = window_grads.map(Vec::into_iter);
    for (i, (trace, outs)) in traces
        .into_iter()
        .zip(transpose_outputs(outputs))
        .enumerate()
    {
        let rows = offsets[i]..offsets[i + 1];
        let (grad_a_mu, grad_a_sigma) = match window_grads.as_mut().and_then(Iterator::next) {
            Some(g) => {
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
                (Some(g.a_mu), Some(g.a_sigma))
            }
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

/// The adaptive variables of a free prior rollout from the zero state (mean path, eps = 0):
/// a = the prior's pre-activations at every step. Per module `[steps, z]`.
#[derive(Debug)]
pub(crate) struct PriorRollout<T> {
    pub(crate) a_mu: [Vec<T>; 4],
    pub(crate) a_sigma: [Vec<T>; 4],
}

fn prior_rollout<T: Real>(
    prepared: &recurrent::Prepared<T>,
    config: &ModelConfig,
    steps: usize,
) -> PriorRollout<T> {
    let zeros: [Vec<T>; 4] = ModuleId::ALL.map(|id| vec![T::ZERO; steps * config.module(id).z]);
    let window = Window {
        len: steps,
        h0: None,
        posterior: Posterior::Prior,
        eps: std::array::from_fn(|m| zeros[m].as_slice()),
        targets: [Vec::new(), Vec::new()],
    };
    let modules = recurrent::forward(prepared, &window, &Ablation::none()).modules;
    PriorRollout {
        a_mu: std::array::from_fn(|m| modules[m].pre_mu_p.clone()),
        a_sigma: std::array::from_fn(|m| modules[m].log_sigma_p.clone()),
    }
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
