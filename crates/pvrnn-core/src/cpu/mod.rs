//! The CPU backend: faer for the large products, hand-written kernels for the recurrence,
//! rayon across sequences and output-column groups (sequential on wasm).
//!
//! Its pieces ([`CpuRecurrence`], [`CpuReadout`]) are public: the driver
//! ([`crate::assembled`]) runs them for [`CpuBackend`], and another backend may hand them
//! what it does not compute itself.

mod readout;
mod recurrent;

use std::sync::Arc;

use crate::Real;
use crate::assembled::{
    AssembledModel, DenseGrads, ModuleWeightGrads, OutputLoss, Parts, Readout, ReadoutBatch,
    ReadoutLoss, ReadoutWeightGrads, Recurrence, RecurrenceGrads, RecurrencePass, add,
};
use crate::backend::{Backend, LoadedModel, Trace, Window};
use crate::config::{Modality, ModelConfig};
use crate::data::Ablation;
use crate::deferred::{Deferred, ready};
use crate::parallel;
use crate::params::Params;

/// Runs the model on the CPU.
#[derive(Clone, Copy, Debug, Default)]
pub struct CpuBackend;

impl<T: Real> Backend<T> for CpuBackend {
    fn load(&self, params: &Params<T>, config: &ModelConfig) -> Box<dyn LoadedModel<T>> {
        let params = Arc::new(params.clone());
        let parts = Parts {
            recurrence: Box::new(CpuRecurrence::new(&params, config)),
            readout: Box::new(CpuReadout::new(params.clone())),
            device: None,
        };
        Box::new(AssembledModel::new(params, config, parts))
    }
}

/// The recurrence on the CPU: the weights laid out for its kernels (`recurrent`), windows
/// in parallel.
#[derive(Debug)]
pub struct CpuRecurrence<T> {
    prepared: recurrent::Prepared<T>,
}

impl<T: Real> CpuRecurrence<T> {
    pub fn new(params: &Params<T>, config: &ModelConfig) -> Self {
        Self {
            prepared: recurrent::Prepared::new(params, config),
        }
    }
}

impl<T: Real> Recurrence<T> for CpuRecurrence<T> {
    fn forward<'a>(
        &'a self,
        windows: &[Window<'_, T>],
        ablation: &Ablation,
    ) -> Deferred<'a, Box<dyn RecurrencePass<T> + 'a>> {
        ready(
            Box::new(CpuPass::forward(&self.prepared, windows, *ablation))
                as Box<dyn RecurrencePass<T> + 'a>,
        )
    }
}

/// Both read-outs on the CPU. Its steps are public so that a backend that runs the output
/// layer elsewhere can run the hidden layers here.
#[derive(Debug)]
pub struct CpuReadout<T> {
    params: Arc<Params<T>>,
    /// Output weights transposed, per modality, made on first use by online inference.
    out_t: [std::sync::OnceLock<Vec<T>>; 2],
}

impl<T: Real> CpuReadout<T> {
    pub fn new(params: Arc<Params<T>>) -> Self {
        Self {
            params,
            out_t: Default::default(),
        }
    }

    /// Activations of every hidden layer of `modality`'s read-out for the module states `d`
    /// (`[n, d]`), bottom first, each `[n, width]`.
    pub fn hidden_forward(&self, modality: Modality, d: &[T], n: usize) -> Vec<Vec<T>> {
        let _phase = crate::profile::phase("  read-out hidden layers");
        readout::hidden_forward(&self.params.readouts[modality.index()], d, n)
    }

    /// Back through the hidden layers from d F / d (top activation): d F / d `d` and, if
    /// asked, each hidden layer's gradients. `acts` from [`Self::hidden_forward`].
    pub fn hidden_backward(
        &self,
        modality: Modality,
        d: &[T],
        n: usize,
        acts: &[Vec<T>],
        grad_top: Vec<T>,
        weight_grads: bool,
    ) -> (Vec<T>, Vec<DenseGrads<T>>) {
        let _phase = crate::profile::phase("  read-out hidden layers");
        let r = &self.params.readouts[modality.index()];
        readout::hidden_backward(r, d, n, acts, grad_top, weight_grads)
    }

    /// The output layer's fused loss on the batch's observed dimensions for the top hidden
    /// activations `top` (`[n, hidden]`).
    pub fn output_loss(&self, batch: &ReadoutBatch<'_, T>, top: &[T]) -> OutputLoss<T> {
        let _phase = crate::profile::phase("  read-out output layer");
        let mi = batch.modality.index();
        // In wasm faer's product runs at half the speed of the small-row kernels; natively
        // faer is as fast at 16x16 and much faster at full vision.
        let small =
            cfg!(target_arch = "wasm32") && batch.n <= readout::SMALL_ROWS && !batch.weight_grads;
        readout::output_loss(
            &self.params.readouts[mi].out,
            small.then(|| self.out_t(mi)),
            top,
            batch.n,
            batch.k,
            batch.divisor,
            batch.targets,
            batch.weight_grads,
        )
    }

    /// Predictions of every dimension of `modality` for the top hidden activations `top`.
    pub fn output_predict(&self, modality: Modality, top: &[T], n: usize) -> Vec<T> {
        let mi = modality.index();
        let small = cfg!(target_arch = "wasm32") && n <= readout::SMALL_ROWS;
        readout::output_predict(
            &self.params.readouts[mi].out,
            small.then(|| self.out_t(mi)),
            top,
            n,
        )
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

/// The read-out's loss from its steps: the hidden layers' activations `acts` (bottom first)
/// for the module states `d` (`[n, d]`), the output layer's `loss`, and the way back to the
/// module states. How the CPU composes them, and how a backend that computes the output
/// layer elsewhere finishes its loss here.
pub fn readout_loss_from<T: Real>(
    cpu: &CpuReadout<T>,
    modality: Modality,
    d: &[T],
    n: usize,
    acts: &[Vec<T>],
    loss: OutputLoss<T>,
    weight_grads: bool,
) -> ReadoutLoss<T> {
    let (grad_d, hidden) = cpu.hidden_backward(modality, d, n, acts, loss.grad_in, weight_grads);
    let weight_grads = weight_grads.then(|| ReadoutWeightGrads {
        hidden,
        output: loss.grad_w.map(|weight| DenseGrads {
            weight,
            bias: loss.grad_b,
        }),
    });
    ReadoutLoss {
        row_loss: loss.row_loss,
        grad_d,
        weight_grads,
    }
}

impl<T: Real> Readout<T> for CpuReadout<T> {
    fn loss<'a>(&'a self, batch: &ReadoutBatch<'_, T>) -> Deferred<'a, ReadoutLoss<T>> {
        let acts = self.hidden_forward(batch.modality, batch.d, batch.n);
        let top = acts.last().map(Vec::as_slice).unwrap_or(batch.d);
        let loss = self.output_loss(batch, top);
        let (modality, d, n) = (batch.modality, batch.d, batch.n);
        ready(readout_loss_from(
            self,
            modality,
            d,
            n,
            &acts,
            loss,
            batch.weight_grads,
        ))
    }

    fn predict<'a>(&'a self, modality: Modality, d: &[T], n: usize) -> Deferred<'a, Vec<T>> {
        let acts = self.hidden_forward(modality, d, n);
        let top = acts.last().map(Vec::as_slice).unwrap_or(d);
        ready(self.output_predict(modality, top, n))
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
    ) -> Deferred<'s, RecurrenceGrads<T>> {
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
        ready(RecurrenceGrads {
            a_mu,
            a_sigma,
            weights: sum,
        })
    }

    fn into_traces(self: Box<Self>) -> Vec<Trace<T>> {
        self.traces
    }
}
