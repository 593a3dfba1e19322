//! The recurrence on the GPU: forward and back-propagation through time with one
//! workgroup per window (`shaders/recurrence_forward.wgsl`, `recurrence_backward.wgsl`;
//! a window's steps depend on each other, so dispatching per step would cost a submission
//! per step), and the weight gradients with one thread per weight and window, their
//! partial sums added in window order (`recurrence_weights.wgsl`,
//! `recurrence_weights_reduce.wgsl`). The forward record stays on the device for the backward
//! pass; the states come back once (the read-outs on the CPU need them).

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use pvrnn_core::ModelConfig;
use pvrnn_core::assembled::{ModuleWeightGrads, Recurrence, RecurrenceGrads, RecurrencePass};
use pvrnn_core::backend::{ModuleTrace, Posterior, Trace, Window};
use pvrnn_core::config::ModuleId;
use pvrnn_core::cpu::CpuRecurrence;
use pvrnn_core::data::Ablation;
use pvrnn_core::params::{ModuleParams, Params};

use crate::encode::{Recorder, bind, dispatch};
use crate::gpu::{Gpu, RecurrenceKernels};
use crate::output::Tiling;
use crate::pool::PooledBuffer;
use crate::readback::read_back;
use pvrnn_core::deferred::Deferred;

/// Units per module the kernels' workgroup arrays hold (`MAX_UNITS` in the WGSL).
const MAX_UNITS: usize = 128;
/// Threads per workgroup of the weight-gradient kernel.
const WEIGHTS_WORKGROUP: usize = 64;
/// Where the window table starts, and its words per window (see
/// `shaders/recurrence_common.wgsl`).
const TABLE_WINDOWS: usize = std::mem::size_of::<Table>() / 4;
const WINDOW_WORDS: usize = std::mem::size_of::<TableWindow>() / 4;

/// The recurrence kernels' table (`Table` in `shaders/recurrence_common.wgsl`, field for
/// field), followed by one [`TableWindow`] per window.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Table {
    windows: u32,
    /// 1 if module m is ablated.
    ablated: [u32; 4],
    strides: Strides32,
    /// Module m's offset within a step of the read-out gradients.
    grad_d_at: [u32; 4],
    pad: [u32; 2],
    modules: [TableModule; 4],
}

/// [`Strides`] as the kernels read them.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Strides32 {
    record: u32,
    input: u32,
    init: u32,
    grad_d: u32,
    back: u32,
}

/// A module in the kernels' table (`Module` in the WGSL): sizes, weight offsets, offsets
/// within a step (see [`ModuleLayout`]).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct TableModule {
    d: u32,
    z: u32,
    /// 4 = none.
    parent: u32,
    parent_d: u32,
    w_prior: u32,
    b_prior: u32,
    w_dd: u32,
    w_dz: u32,
    w_dh: u32,
    bias: u32,
    inv_tau: u32,
    decay: u32,
    record: u32,
    input: u32,
    init: u32,
    back: u32,
}

/// A window in the kernels' table (`WindowInfo` in the WGSL).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct TableWindow {
    steps: u32,
    inputs: u32,
    record: u32,
    /// 1 if the window's posterior is the prior.
    prior: u32,
    grad_d: u32,
    back: u32,
    /// Where the window's network's weights start (a cohort's networks in one dispatch).
    weights: u32,
    pad: u32,
}

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

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct BackwardParams {
    kl_scale: [f32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct WeightsParams {
    first_window: u32,
    windows: u32,
    total: u32,
    base: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct ReduceParams {
    first_part: u32,
    parts: u32,
    total: u32,
    base: u32,
}

/// Where everything lives in the recurrence kernels' buffers: the modules' shapes and
/// offsets, the per-step strides, and the packed weights' size.
#[derive(Clone, Debug)]
pub(crate) struct RecurrenceLayout {
    modules: [ModuleLayout; 4],
    strides: Strides,
    weight_floats: usize,
    kl_scale: [f32; 4],
    /// The model bounds its log sigmas (`log_sigma_bound`), which the kernels do not
    /// implement: every call then stays on the CPU.
    bounded_log_sigma: bool,
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

/// The recurrent weights of one loaded model, uploaded.
#[derive(Debug)]
pub struct GpuRecurrence {
    gpu: Arc<Gpu>,
    pub(crate) kernels: Arc<RecurrenceKernels>,
    pub(crate) layout: RecurrenceLayout,
    pub(crate) weights: PooledBuffer,
    /// The same values with every matrix transposed (same offsets), for the forward
    /// kernel: its threads own output rows, so this layout makes their loads coalesced.
    pub(crate) weights_t: PooledBuffer,
    /// The CPU's recurrence with the same weights, for the windows the kernels do not hold.
    cpu: CpuRecurrence<f32>,
}

impl GpuRecurrence {
    /// Uploads the modules' weights. A module wider than the kernels hold leaves every
    /// call to the CPU.
    pub fn upload(
        gpu: Arc<Gpu>,
        tiling: Tiling,
        params: &Params<f32>,
        config: &ModelConfig,
    ) -> Self {
        let (layout, weights) = RecurrenceLayout::new(params, config);
        let weights_t = layout.transposed(&weights);
        Self {
            kernels: gpu.recurrence_kernels(
                layout.threads(&gpu, tiling.recurrence_threads),
                tiling.recurrence_early_loads,
            ),
            weights: gpu.upload("recurrent weights", &weights),
            weights_t: gpu.upload("recurrent weights, transposed", &weights_t),
            gpu,
            layout,
            cpu: CpuRecurrence::new(params, config),
        }
    }
}

impl RecurrenceLayout {
    /// The table the kernels read (`Table` in `shaders/recurrence_common.wgsl`): modules,
    /// strides, ablation, then `windows` as (steps, inputs, record, prior posterior,
    /// read-out gradients, backward record) offsets.
    fn table(&self, ablation: &Ablation, windows: &[WindowEntry]) -> Vec<u32> {
        let s = &self.strides;
        let word = |v: usize| v as u32;
        let header = Table {
            windows: word(windows.len()),
            ablated: ablation.0.map(u32::from),
            strides: Strides32 {
                record: word(s.record),
                input: word(s.input),
                init: word(s.init),
                grad_d: word(s.grad_d),
                back: word(s.back),
            },
            grad_d_at: std::array::from_fn(|m| word(self.modules[m].grad_d)),
            pad: [0; 2],
            modules: std::array::from_fn(|m| {
                let ml = &self.modules[m];
                TableModule {
                    d: word(ml.d),
                    z: word(ml.z),
                    parent: word(ml.parent.unwrap_or(4)),
                    parent_d: word(ml.parent_d),
                    w_prior: word(ml.w_prior),
                    b_prior: word(ml.b_prior),
                    w_dd: word(ml.w_dd),
                    w_dz: word(ml.w_dz),
                    w_dh: word(ml.w_dh),
                    bias: word(ml.bias),
                    inv_tau: word(ml.inv_tau),
                    decay: word(ml.decay),
                    record: word(ml.record),
                    input: word(ml.input),
                    init: word(ml.init),
                    back: word(ml.back),
                }
            }),
        };
        let mut t: Vec<u32> = bytemuck::cast_slice(bytemuck::bytes_of(&header)).to_vec();
        for w in windows {
            let entry = TableWindow {
                steps: word(w[0]),
                inputs: word(w[1]),
                record: word(w[2]),
                prior: word(w[3]),
                grad_d: word(w[4]),
                back: word(w[5]),
                weights: word(w[6]),
                pad: 0,
            };
            t.extend_from_slice(bytemuck::cast_slice(bytemuck::bytes_of(&entry)));
        }
        t
    }

    /// Whether the kernels hold these shapes: module widths within the workgroup arrays,
    /// windows within one dispatch, buffers within one binding.
    pub(crate) fn fits(&self, gpu: &Gpu, windows: usize, steps: usize) -> bool {
        let limits = gpu.limits();
        let binding = limits.max_storage_buffer_binding_size as usize;
        let s = self.strides;
        let largest = (steps * s.record.max(s.back).max(s.input) + windows * s.init)
            .max(TABLE_WINDOWS + WINDOW_WORDS * windows);
        !self.bounded_log_sigma
            && self
                .modules
                .iter()
                .all(|m| m.d <= MAX_UNITS && m.z <= MAX_UNITS)
            && windows > 0
            && windows <= limits.max_compute_workgroups_per_dimension as usize
            && 4 * largest <= binding
            && self.weight_floats.div_ceil(WEIGHTS_WORKGROUP)
                <= limits.max_compute_workgroups_per_dimension as usize
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

    /// The windows' table, uploaded.
    pub(crate) fn upload_table(
        &self,
        gpu: &Gpu,
        ablation: &Ablation,
        entries: &[WindowEntry],
    ) -> PooledBuffer {
        gpu.upload("recurrence table", &self.table(ablation, entries))
    }

    /// Encodes the forward pass of the table's windows: `record` gets every step's states.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn encode_forward(
        &self,
        gpu: &Gpu,
        kernels: &RecurrenceKernels,
        encoder: &mut dyn Recorder,
        table: &wgpu::Buffer,
        weights_t: &wgpu::Buffer,
        inputs: &wgpu::Buffer,
        record: &wgpu::Buffer,
        windows: usize,
    ) {
        let group = bind(gpu, &kernels.forward, &[table, weights_t, inputs, record]);
        dispatch(encoder, &kernels.forward, &group, windows as u32, 1);
    }

    /// Encodes back-propagation through the table's windows from the read-outs' d F / d d
    /// in `grad_d`: `back` gets every step's gradients (d F / d a among them). Returns the
    /// uniform it used, to keep until the submission has run.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn encode_backward(
        &self,
        gpu: &Gpu,
        kernels: &RecurrenceKernels,
        encoder: &mut dyn Recorder,
        table: &wgpu::Buffer,
        weights: &wgpu::Buffer,
        record: &wgpu::Buffer,
        grad_d: &wgpu::Buffer,
        back: &wgpu::Buffer,
        windows: usize,
    ) -> PooledBuffer {
        let params = gpu.uniform(&BackwardParams {
            kl_scale: self.kl_scale,
        });
        let group = bind(
            gpu,
            &kernels.backward,
            &[table, weights, record, grad_d, back, &params],
        );
        dispatch(encoder, &kernels.backward, &group, windows as u32, 1);
        params
    }

    /// Encodes the weight gradients of each network in `networks` (its windows of the
    /// table, and where its gradients start in `grads`, the packed weights' layout). Where
    /// the partial sums fit one binding and the dispatch grid: one dispatch of a partial
    /// sum per window for all the networks' windows, then one reduce per network in window
    /// order; else one dispatch per network, a thread per weight over all its windows
    /// (which leaves a large GPU mostly idle: on an H200, 2026-11-30, the weight gradients
    /// took 3.05 ms that way against 0.40 per window, one network). Returns the buffers to
    /// keep until the submission has run.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn encode_weight_grads(
        &self,
        gpu: &Gpu,
        kernels: &RecurrenceKernels,
        encoder: &mut dyn Recorder,
        buffers: WeightGradBuffers<'_>,
        networks: &[(std::ops::Range<usize>, usize)],
    ) -> Vec<PooledBuffer> {
        let WeightGradBuffers {
            table,
            inputs,
            record,
            back,
            grads,
        } = buffers;
        let total = self.weight_floats;
        let groups = total.div_ceil(WEIGHTS_WORKGROUP) as u32;
        let first = networks.iter().map(|(w, _)| w.start).min().unwrap_or(0);
        let end = networks.iter().map(|(w, _)| w.end).max().unwrap_or(0);
        let limits = gpu.limits();
        let partials = end > first
            && 4 * (end - first) * total <= limits.max_storage_buffer_binding_size as usize
            && end - first <= limits.max_compute_workgroups_per_dimension as usize;
        let mut keep = Vec::new();
        if !partials {
            for (windows, base) in networks {
                let params = gpu.uniform(&WeightsParams {
                    first_window: windows.start as u32,
                    windows: windows.len() as u32,
                    total: total as u32,
                    base: *base as u32,
                });
                let group = bind(
                    gpu,
                    &kernels.weights,
                    &[table, inputs, record, back, grads, &params],
                );
                dispatch(encoder, &kernels.weights, &group, groups, 1);
                keep.push(params);
            }
            return keep;
        }
        let partial = gpu.scratch(
            "recurrent weight gradients, per window",
            (end - first) * total,
            wgpu::BufferUsages::empty(),
        );
        let params = gpu.uniform(&WeightsParams {
            first_window: first as u32,
            windows: (end - first) as u32,
            total: total as u32,
            base: 0,
        });
        let group = bind(
            gpu,
            &kernels.weight_partials,
            &[table, inputs, record, back, &partial, &params],
        );
        dispatch(
            encoder,
            &kernels.weight_partials,
            &group,
            groups,
            (end - first) as u32,
        );
        keep.push(params);
        for (windows, base) in networks {
            let params = gpu.uniform(&ReduceParams {
                first_part: (windows.start - first) as u32,
                parts: windows.len() as u32,
                total: total as u32,
                base: *base as u32,
            });
            let group = bind(gpu, &kernels.weights_reduce, &[&partial, grads, &params]);
            dispatch(encoder, &kernels.weights_reduce, &group, groups, 1);
            keep.push(params);
        }
        keep.push(partial);
        keep
    }
}

/// The buffers the recurrent weight gradients read and write (see
/// [`RecurrenceLayout::encode_weight_grads`]).
pub(crate) struct WeightGradBuffers<'a> {
    pub(crate) table: &'a wgpu::Buffer,
    pub(crate) inputs: &'a wgpu::Buffer,
    pub(crate) record: &'a wgpu::Buffer,
    pub(crate) back: &'a wgpu::Buffer,
    pub(crate) grads: &'a wgpu::Buffer,
}

/// On the GPU where its kernels hold the windows, else on the CPU's recurrence.
impl Recurrence<f32> for GpuRecurrence {
    fn forward<'a>(
        &'a self,
        windows: &[Window<'_, f32>],
        ablation: &Ablation,
    ) -> Deferred<'a, Box<dyn RecurrencePass<f32> + 'a>> {
        match self.forward_on_gpu(windows, ablation) {
            Some(pass) => pass,
            None => self.cpu.forward(windows, ablation),
        }
    }

    /// In the browser on the CPU: this synchronous call (model initialisation) cannot wait
    /// on the event loop that WebGPU's read-backs need.
    #[cfg(target_arch = "wasm32")]
    fn prior_rollout(&self, config: &ModelConfig, steps: usize) -> ([Vec<f32>; 4], [Vec<f32>; 4]) {
        self.cpu.prior_rollout(config, steps)
    }
}

impl GpuRecurrence {
    /// The windows forward on the GPU; `None` for shapes its kernels do not hold.
    pub fn forward_on_gpu<'a>(
        &'a self,
        windows: &[Window<'_, f32>],
        ablation: &Ablation,
    ) -> Option<Deferred<'a, Box<dyn RecurrencePass<f32> + 'a>>> {
        let layout = &self.layout;
        let steps: usize = windows.iter().map(|w| w.len).sum();
        if !layout.fits(&self.gpu, windows.len(), steps) || windows.iter().any(|w| w.len == 0) {
            return None;
        }
        let s = layout.strides;
        let entries = layout.entries(
            windows
                .iter()
                .map(|w| (w.len, matches!(w.posterior, Posterior::Prior))),
        );
        let (inputs, initial) = layout.pack_inputs(windows);
        let gpu = &*self.gpu;
        let table = layout.upload_table(gpu, ablation, &entries);
        let input_buffer = gpu.upload("recurrence inputs", &inputs);
        let record = gpu.scratch(
            "recurrence record",
            steps * s.record,
            wgpu::BufferUsages::COPY_SRC,
        );
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        layout.encode_forward(
            gpu,
            &self.kernels,
            &mut encoder,
            &table,
            &self.weights_t,
            &input_buffer,
            &record,
            windows.len(),
        );
        let pending = read_back(gpu, encoder, &[(&record, steps * s.record)]);
        Some(Box::pin(async move {
            let values = pending.await.pop().unwrap_or_default();
            let traces = entries
                .iter()
                .zip(initial)
                .map(|(entry, init)| {
                    let (len, at) = (entry[0], entry[2]);
                    let mut init = init.into_iter();
                    let modules = std::array::from_fn(|m| {
                        let (h0, d0) = init.next().unwrap_or_default();
                        self.unpack_trace(&values[at..], len, m, h0, d0)
                    });
                    Trace { len, modules }
                })
                .collect();
            Box::new(GpuPass {
                recurrence: self,
                table,
                inputs: input_buffer,
                record,
                traces,
                entries,
                steps,
            }) as Box<dyn RecurrencePass<f32> + 'a>
        }))
    }
}
impl GpuRecurrence {
    /// Module m's states over a window from its forward record.
    fn unpack_trace(
        &self,
        record: &[f32],
        len: usize,
        m: usize,
        h0: Vec<f32>,
        d0: Vec<f32>,
    ) -> ModuleTrace<f32> {
        let ml = self.layout.modules[m];
        let (d, z) = (ml.d, ml.z);
        let stride = self.layout.strides.record;
        let gather = |offset: usize, width: usize| {
            let mut out = Vec::with_capacity(len * width);
            for t in 0..len {
                let at = t * stride + ml.record + offset;
                out.extend_from_slice(&record[at..at + width]);
            }
            out
        };
        let row = |k: usize| gather(2 * d + k * z, z);
        let kl_terms = row(8);
        ModuleTrace {
            h0,
            d0,
            h: gather(0, d),
            d: gather(d, d),
            pre_mu_p: row(0),
            mu_p: row(1),
            log_sigma_p: row(2),
            inv_var_p: row(3),
            mu_q: row(4),
            log_sigma_q: row(5),
            sigma_q: row(6),
            z: row(7),
            // As the CPU backend: the units' terms summed in f64, divided by z.
            kl: kl_terms
                .chunks_exact(z.max(1))
                .map(|k| k.iter().map(|&v| v as f64).sum::<f64>() / z as f64)
                .collect(),
        }
    }
}

/// A batch run forward on the GPU: the record and inputs stay on the device.
#[derive(Debug)]
struct GpuPass<'a> {
    recurrence: &'a GpuRecurrence,
    table: PooledBuffer,
    inputs: PooledBuffer,
    record: PooledBuffer,
    traces: Vec<Trace<f32>>,
    /// The windows' table entries (steps, offsets).
    entries: Vec<WindowEntry>,
    steps: usize,
}

impl RecurrencePass<f32> for GpuPass<'_> {
    fn traces(&self) -> &[Trace<f32>] {
        &self.traces
    }

    fn backward<'s>(
        &'s self,
        grad_d: &[[Option<&[f32]>; 4]],
        weight_grads: bool,
    ) -> Deferred<'s, RecurrenceGrads<f32>> {
        let r = self.recurrence;
        let gpu = &*r.gpu;
        let layout = &r.layout;
        let s = layout.strides;
        let mut from_readout = vec![0f32; self.steps * s.grad_d];
        for (entry, per_module) in self.entries.iter().zip(grad_d) {
            for (m, g) in per_module.iter().enumerate() {
                let Some(g) = g else { continue };
                let d = layout.modules[m].d;
                for t in 0..entry[0] {
                    let at = entry[4] + t * s.grad_d + layout.modules[m].grad_d;
                    from_readout[at..at + d].copy_from_slice(&g[t * d..(t + 1) * d]);
                }
            }
        }
        let grad_d = gpu.upload("read-out gradients", &from_readout);
        let back = gpu.scratch(
            "recurrence backward",
            self.steps * s.back,
            wgpu::BufferUsages::COPY_SRC,
        );
        let windows = self.entries.len();
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        let backward_params = layout.encode_backward(
            gpu,
            &r.kernels,
            &mut encoder,
            &self.table,
            &r.weights,
            &self.record,
            &grad_d,
            &back,
            windows,
        );
        let grads = gpu.scratch(
            "recurrent weight gradients",
            if weight_grads {
                layout.weight_floats
            } else {
                1
            },
            wgpu::BufferUsages::COPY_SRC,
        );
        let weights_params = weight_grads.then(|| {
            let buffers = WeightGradBuffers {
                table: &self.table,
                inputs: &self.inputs,
                record: &self.record,
                back: &back,
                grads: &grads,
            };
            layout.encode_weight_grads(gpu, &r.kernels, &mut encoder, buffers, &[(0..windows, 0)])
        });
        let mut sources = vec![(&*back, self.steps * s.back)];
        if weight_grads {
            sources.push((&*grads, layout.weight_floats));
        }
        let pending = read_back(gpu, encoder, &sources);
        // The submission's buffers stay out of the pool until it has run.
        let used = (grad_d, back, grads, backward_params, weights_params);
        Box::pin(async move {
            let results = pending.await;
            drop(used);
            self.unpack_grads(results)
        })
    }

    fn into_traces(self: Box<Self>) -> Vec<Trace<f32>> {
        self.traces
    }
}

impl GpuPass<'_> {
    /// The backward pass's read-back: d F / d a per window, and the weights' gradients
    /// when they were asked for.
    fn unpack_grads(&self, results: Vec<Vec<f32>>) -> RecurrenceGrads<f32> {
        let layout = &self.recurrence.layout;
        let s = layout.strides;
        let mut results = results.into_iter();
        let back = results.next().unwrap_or_default();
        let (mut a_mu, mut a_sigma) = (Vec::new(), Vec::new());
        for entry in &self.entries {
            let (len, at) = (entry[0], entry[5]);
            let gather = |m: usize, offset: usize| {
                let z = layout.modules[m].z;
                let mut out = Vec::with_capacity(len * z);
                for t in 0..len {
                    let i = at + t * s.back + layout.modules[m].back + offset * z;
                    out.extend_from_slice(&back[i..i + z]);
                }
                out
            };
            a_mu.push(std::array::from_fn(|m| gather(m, 0)));
            a_sigma.push(std::array::from_fn(|m| gather(m, 1)));
        }
        let weights = results.next().map(|g| {
            std::array::from_fn(|m| {
                let ml = layout.modules[m];
                let (d, z) = (ml.d, ml.z);
                let take = |at: usize, n: usize| g[at..at + n].to_vec();
                ModuleWeightGrads {
                    w_prior_mu: take(ml.w_prior, z * d),
                    w_prior_sigma: take(ml.w_prior + z * d, z * d),
                    b_prior_mu: take(ml.b_prior, z),
                    b_prior_sigma: take(ml.b_prior + z, z),
                    w_dd: take(ml.w_dd, d * d),
                    w_dz: take(ml.w_dz, d * z),
                    w_dh: take(ml.w_dh, d * ml.parent_d),
                }
            })
        });
        RecurrenceGrads {
            a_mu,
            a_sigma,
            weights,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The WGSL structs have no padding of their own (every field a u32 or an array of
    /// them), so the kernels read these at the same word offsets as the Rust structs give.
    #[test]
    fn the_table_s_rust_structs_have_the_wgsl_layout() {
        assert_eq!(std::mem::size_of::<TableModule>(), 16 * 4);
        assert_eq!(std::mem::size_of::<TableWindow>(), 8 * 4);
        // windows count, 4 ablated, 5 strides, 4 offsets, 2 pad, then 4 modules.
        assert_eq!(std::mem::size_of::<Table>(), (16 + 4 * 16) * 4);
        let common = shader!("recurrence_common.wgsl");
        for name in ["struct Table {", "struct Module {", "struct WindowInfo {"] {
            assert!(common.contains(name), "{name} is gone from the WGSL");
        }
    }
}
