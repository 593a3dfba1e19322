//! Where everything lives in the recurrence kernels' buffers ([`RecurrenceLayout`]): each
//! module's shapes and offsets into the packed weights and within a step of each buffer,
//! the per-step strides, the windows' table entries and inputs, and the workgroup width.

use pvrnn_core::ModelConfig;
use pvrnn_core::backend::{Posterior, Window};
use pvrnn_core::config::ModuleId;
use pvrnn_core::params::{ModuleParams, Params};

use crate::gpu::Gpu;

/// A window's table entry: steps, then where its inputs, record, read-out gradients and
/// backward record start, whether its posterior is the prior, and where its network's
/// weights start: `[steps, inputs, record, prior, grad_d, back, weights]`.
pub(crate) type WindowEntry = [usize; 7];

/// The forward record's z-long rows per module and step.
const RECORD_ROWS: usize = 9;

/// One module's shapes and offsets: into the weights, and within a step of each buffer.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct ModuleLayout {
    pub(crate) d: usize,
    pub(crate) z: usize,
    pub(crate) parent: Option<usize>,
    pub(crate) parent_d: usize,
    pub(crate) w_prior: usize,
    pub(crate) b_prior: usize,
    pub(crate) w_dd: usize,
    pub(crate) w_dz: usize,
    pub(crate) w_dh: usize,
    pub(crate) bias: usize,
    pub(crate) inv_tau: usize,
    pub(crate) decay: usize,
    /// Offsets within a step of the forward record, the inputs, the initial states, the
    /// backward record and the read-out gradients.
    pub(crate) record: usize,
    pub(crate) input: usize,
    pub(crate) init: usize,
    pub(crate) back: usize,
    pub(crate) grad_d: usize,
}

/// Per-step (per-window for `init`) sizes of the buffers.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Strides {
    pub(crate) record: usize,
    pub(crate) input: usize,
    pub(crate) init: usize,
    pub(crate) grad_d: usize,
    pub(crate) back: usize,
}

/// Where everything lives in the recurrence kernels' buffers: the modules' shapes and
/// offsets, the per-step strides, and the packed weights' size.
#[derive(Clone, Debug)]
pub(crate) struct RecurrenceLayout {
    pub(super) modules: [ModuleLayout; 4],
    pub(super) strides: Strides,
    pub(super) weight_floats: usize,
    pub(super) kl_scale: [f32; 4],
    /// The model bounds its log sigmas (`log_sigma_bound`), which the kernels do not
    /// implement: every call then stays on the CPU.
    pub(super) bounded_log_sigma: bool,
}

impl RecurrenceLayout {
    /// The layout of `config`'s modules and `params`' weights packed in it.
    pub(crate) fn new(params: &Params<f32>, config: &ModelConfig) -> (Self, Vec<f32>) {
        let mut modules = [ModuleLayout::default(); 4];
        let mut strides = Strides::default();
        let mut weights = Vec::new();
        for id in ModuleId::ALL {
            let m = id.index();
            let p = &params.modules[m];
            let (d, z) = (config.module(id).d, config.module(id).z);
            let parent = id.parent().map(ModuleId::index);
            let parent_d = id.parent().map_or(0, |pid| config.module(pid).d);
            let mut layout = ModuleLayout {
                d,
                z,
                parent,
                parent_d,
                record: strides.record,
                input: strides.input,
                init: strides.init,
                back: strides.back,
                grad_d: strides.grad_d,
                ..Default::default()
            };
            // Each tensor's offset, then its values (a pair is one block: mean, log sigma).
            let mut push = |offset: &mut usize, parts: &[&[f32]]| {
                *offset = weights.len();
                for part in parts {
                    weights.extend_from_slice(part);
                }
            };
            let zeros = vec![0f32; z];
            let bias_or_zeros = |b: &Option<pvrnn_core::Tensor<f32>>| {
                b.as_ref().map_or(zeros.clone(), |b| b.data().to_vec())
            };
            push(
                &mut layout.w_prior,
                &[p.w_prior_mu.data(), p.w_prior_sigma.data()],
            );
            push(
                &mut layout.b_prior,
                &[
                    &bias_or_zeros(&p.b_prior_mu),
                    &bias_or_zeros(&p.b_prior_sigma),
                ],
            );
            push(&mut layout.w_dd, &[p.w_dd.data()]);
            push(&mut layout.w_dz, &[p.w_dz.data()]);
            push(
                &mut layout.w_dh,
                &[p.w_dh.as_ref().map_or(&[][..], |w| w.data())],
            );
            push(&mut layout.bias, &[p.bias.data()]);
            // As the CPU backend computes them, so both use the same f32 values.
            let inv_tau: Vec<f32> = p.tau.data().iter().map(|&t| 1.0 / t).collect();
            let decay: Vec<f32> = p.tau.data().iter().map(|&t| 1.0 - 1.0 / t).collect();
            push(&mut layout.inv_tau, &[&inv_tau]);
            push(&mut layout.decay, &[&decay]);
            strides.record += 2 * d + RECORD_ROWS * z;
            strides.input += 3 * z;
            strides.init += 2 * d;
            strides.back += 4 * z + d;
            strides.grad_d += d;
            modules[m] = layout;
        }
        let kl_scale =
            ModuleId::ALL.map(|id| (config.kl_weight / config.module(id).z as f64) as f32);
        let layout = Self {
            modules,
            strides,
            weight_floats: weights.len(),
            kl_scale,
            bounded_log_sigma: config.log_sigma_bound.is_some(),
        };
        (layout, weights)
    }

    /// The weight matrices as (offset, rows, columns): the forward kernel reads them
    /// transposed (its threads own output rows, so that layout makes their loads coalesced).
    pub(crate) fn matrices(&self) -> Vec<(usize, usize, usize)> {
        self.modules
            .iter()
            .flat_map(|ml| {
                [
                    (ml.w_prior, 2 * ml.z, ml.d),
                    (ml.w_dd, ml.d, ml.d),
                    (ml.w_dz, ml.d, ml.z),
                    (ml.w_dh, ml.d, ml.parent_d),
                ]
            })
            .filter(|&(_, rows, cols)| rows * cols > 0)
            .collect()
    }

    /// `weights` with every matrix transposed in place (same offsets).
    pub(crate) fn transposed(&self, weights: &[f32]) -> Vec<f32> {
        let mut weights_t = weights.to_vec();
        for (at, rows, cols) in self.matrices() {
            for r in 0..rows {
                for c in 0..cols {
                    weights_t[at + c * rows + r] = weights[at + r * cols + c];
                }
            }
        }
        weights_t
    }

    /// Module `m`'s trainable tensors (of `p`, its parameters) with their offsets in the
    /// packed weights (the bias and the time constants are fixed; a missing prior bias's
    /// slots stay zero).
    pub(crate) fn trainable<'p>(
        &self,
        m: usize,
        p: &'p ModuleParams<f32>,
    ) -> Vec<(&'p pvrnn_core::Tensor<f32>, usize)> {
        let ml = self.modules[m];
        let half = ml.z * ml.d;
        let mut out = vec![
            (&p.w_dd, ml.w_dd),
            (&p.w_dz, ml.w_dz),
            (&p.w_prior_mu, ml.w_prior),
            (&p.w_prior_sigma, ml.w_prior + half),
        ];
        out.extend(p.w_dh.as_ref().map(|w| (w, ml.w_dh)));
        out.extend(p.b_prior_mu.as_ref().map(|b| (b, ml.b_prior)));
        out.extend(p.b_prior_sigma.as_ref().map(|b| (b, ml.b_prior + ml.z)));
        out
    }
}

impl RecurrenceLayout {
    /// Threads per window's workgroup of the forward and backward kernels: `wanted`
    /// (`Tiling::recurrence_threads`, tests), else one per item of a step's widest phase (the
    /// forward's priors and recurrent sums, 2z + d per module; the backward's W_dd^T, W_dz^T
    /// and W_dh^T sums, 2d + z), in whole 64-thread groups, at most what the adapter allows.
    /// A step's phases are chains of dependent loads, so a thread walking three dot
    /// products in turn (the paper's 380 items on 128 threads) takes three times as long
    /// as three threads walking one each; the sums are the same either way (each is one
    /// thread's, in the CPU's order).
    pub(crate) fn threads(&self, gpu: &Gpu, wanted: Option<usize>) -> u32 {
        let sum = |item: fn(&ModuleLayout) -> usize| self.modules.iter().map(item).sum::<usize>();
        let widest = sum(|m| 2 * m.z + m.d).max(sum(|m| 2 * m.d + m.z));
        let limits = gpu.limits();
        let allowed = (limits.max_compute_invocations_per_workgroup)
            .min(limits.max_compute_workgroup_size_x) as usize;
        let threads = wanted.unwrap_or_else(|| widest.div_ceil(64) * 64);
        threads.clamp(32, allowed.max(32)) as u32
    }

    /// The packed weights' length.
    pub(crate) fn weight_floats(&self) -> usize {
        self.weight_floats
    }

    /// Whether `other` lays out the same shapes (so that one dispatch runs both networks'
    /// windows): the same modules, weights and KL weights.
    pub(crate) fn same_shape(&self, other: &Self) -> bool {
        let shape = |l: &Self| {
            let modules: Vec<[usize; 4]> = l
                .modules
                .iter()
                .map(|m| [m.d, m.z, m.parent.unwrap_or(4), m.w_prior])
                .collect();
            (modules, l.weight_floats, l.kl_scale, l.bounded_log_sigma)
        };
        shape(self) == shape(other)
    }

    pub(crate) fn modules(&self) -> &[ModuleLayout; 4] {
        &self.modules
    }

    pub(crate) fn strides(&self) -> Strides {
        self.strides
    }

    /// The table entries of windows of these lengths, in order (see [`Self::table`]): each
    /// window's inputs (its initial states, then its steps) follow the last one's, its
    /// records and gradients continue the last one's steps.
    pub(crate) fn entries(&self, windows: impl Iterator<Item = (usize, bool)>) -> Vec<WindowEntry> {
        let s = self.strides;
        let (mut before, mut input_at) = (0, 0);
        windows
            .map(|(len, prior)| {
                let entry = [
                    len,
                    input_at,
                    before * s.record,
                    prior as usize,
                    before * s.grad_d,
                    before * s.back,
                    0,
                ];
                before += len;
                input_at += s.init + len * s.input;
                entry
            })
            .collect()
    }

    /// The recurrence's inputs for `windows` (see [`Self::entries`]), and each window's
    /// initial states (h0, d0) per module: d0 = tanh(h0) computed here as the CPU backend
    /// does, a = 0 for `Posterior::Prior`.
    #[allow(clippy::type_complexity)]
    pub(crate) fn pack_inputs(
        &self,
        windows: &[Window<'_, f32>],
    ) -> (Vec<f32>, Vec<[(Vec<f32>, Vec<f32>); 4]>) {
        let s = self.strides;
        let steps: usize = windows.iter().map(|w| w.len).sum();
        let mut inputs = Vec::with_capacity(windows.len() * s.init + steps * s.input);
        let mut initial = Vec::with_capacity(windows.len());
        for w in windows {
            let mut init: [(Vec<f32>, Vec<f32>); 4] = Default::default();
            for (m, ml) in self.modules.iter().enumerate() {
                let h0 =
                    w.h0.map_or_else(|| vec![0.0; ml.d], |h| h[m][..ml.d].to_vec());
                let d0: Vec<f32> = h0.iter().map(|h| h.tanh()).collect();
                inputs.extend_from_slice(&h0);
                inputs.extend_from_slice(&d0);
                init[m] = (h0, d0);
            }
            for t in 0..w.len {
                for (m, ml) in self.modules.iter().enumerate() {
                    let row = t * ml.z..(t + 1) * ml.z;
                    match w.posterior {
                        Posterior::Adaptive { a_mu, a_sigma } => {
                            inputs.extend_from_slice(&a_mu[m][row.clone()]);
                            inputs.extend_from_slice(&a_sigma[m][row.clone()]);
                        }
                        Posterior::Prior => inputs.resize(inputs.len() + 2 * ml.z, 0.0),
                    }
                    inputs.extend_from_slice(&w.eps[m][row]);
                }
            }
            initial.push(init);
        }
        (inputs, initial)
    }
}
