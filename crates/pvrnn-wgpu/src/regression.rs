//! Online inference's updates of a window on the GPU, all of a call's updates in one
//! submission (pvrnn-core's [`ErrorRegression`]): per update the recurrence forward, each
//! observed read-out (hidden layers, output layer's loss, back to d F / d d) from the
//! module states in the recurrence's record, the recurrence backward, and
//! `shaders/regression_update.wgsl`, which checks the update's terms are finite, applies
//! RAdam to the adaptive variables where the recurrence reads them and writes the next
//! update's eps beside them. One read-back at the end: the adaptive variables, the moments
//! and a flag per update. Without it every update is two or three round trips (the
//! recurrence's states, the read-outs' gradients, d F / d a), 50 times per step: the
//! latency that bounds online inference on a GPU (docs/gpu.md).
//!
//! The same natively and in the browser: the result is [`Deferred`], so WebGPU's read-back
//! arrives through the worker's event loop. The weights go up at the first call of a loaded
//! model, not at load: learning loads a model every iteration and never calls it.

use std::sync::{Arc, OnceLock};

use bytemuck::{Pod, Zeroable};
use pvrnn_core::assembled::ErrorRegression;
use pvrnn_core::backend::{RegressionRequest, RegressionResult, Window};
use pvrnn_core::deferred::Deferred;
use pvrnn_core::optim::RAdamStep;
use pvrnn_core::params::Params;
use pvrnn_core::{Modality, ModelConfig};

use crate::encode::{DispatchList, bind, grid};
use crate::gpu::Gpu;
use crate::iteration::{RecordRows, encode_readout_of_record};
use crate::output::EncodedReadout;
use crate::output::{GpuOutputLayer, Tiling};
use crate::pool::PooledBuffer;
use crate::readback::read_back;
use crate::recurrence::{GpuRecurrence, ModuleLayout, RecurrenceLayout, Strides};
use crate::resident::ResidentLayer;

/// One update's uniform (`Params` in `shaders/regression_update.wgsl`, field for field):
/// its index, the threads, and its RAdam scalars ([`RAdamStep`]).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct UpdateParams {
    update: u32,
    count: u32,
    groups_x: u32,
    /// 1: the rectified step, 0: the plain one.
    rectified: u32,
    beta1: f32,
    beta2: f32,
    one_minus_beta1: f32,
    one_minus_beta2: f32,
    weight_decay: f32,
    eps: f32,
    sqrt_bias2: f32,
    /// The rectified or the plain step size.
    lr: f32,
}

impl UpdateParams {
    fn new(update: usize, count: usize, groups_x: u32, step: &RAdamStep) -> Self {
        Self {
            update: update as u32,
            count: count as u32,
            groups_x,
            rectified: step.rectified.is_some() as u32,
            beta1: step.beta1 as f32,
            beta2: step.beta2 as f32,
            one_minus_beta1: (1.0 - step.beta1) as f32,
            one_minus_beta2: (1.0 - step.beta2) as f32,
            weight_decay: step.weight_decay as f32,
            eps: step.eps as f32,
            sqrt_bias2: step.sqrt_bias2 as f32,
            lr: step.rectified.unwrap_or(step.plain) as f32,
        }
    }
}

/// The window's layout as the update kernel reads it (`RegressionTable` in the WGSL, field
/// for field), followed in its buffer by every update's eps, `[updates, len, sum_z]`.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct RegressionTable {
    len: u32,
    sum_z: u32,
    init_stride: u32,
    input_stride: u32,
    back_stride: u32,
    record_stride: u32,
    updates: u32,
    /// 1 where the modality is observed (its row losses are bound).
    extero_rows: u32,
    proprio_rows: u32,
    pad: [u32; 7],
    modules: [UpdateModule; 4],
}

/// A module in [`RegressionTable`]: its z, its units' offset among a step's, its offsets
/// within a step of the inputs and of the backward record, the row of its KL terms in the
/// forward record.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct UpdateModule {
    z: u32,
    offset: u32,
    input: u32,
    back: u32,
    kl_row: u32,
    pad: [u32; 3],
}

/// A loaded model's error regression on the GPU; its weights go up at the first call.
#[derive(Debug)]
pub(crate) struct GpuRegression {
    gpu: Arc<Gpu>,
    tiling: Tiling,
    uploaded: OnceLock<Option<Uploaded>>,
}

/// The weights on the device: the recurrence's, and both read-outs whole.
#[derive(Debug)]
struct Uploaded {
    recurrence: GpuRecurrence,
    readouts: GpuOutputLayer,
}

impl GpuRegression {
    pub(crate) fn new(gpu: Arc<Gpu>, tiling: Tiling) -> Self {
        Self {
            gpu,
            tiling,
            uploaded: OnceLock::new(),
        }
    }

    fn uploaded(&self, params: &Params<f32>, config: &ModelConfig) -> Option<&Uploaded> {
        self.uploaded
            .get_or_init(|| {
                let layers: [Option<Arc<ResidentLayer>>; 2] = std::array::from_fn(|mi| {
                    ResidentLayer::frozen(&self.gpu, params, mi).map(Arc::new)
                });
                Some(Uploaded {
                    recurrence: GpuRecurrence::upload(self.gpu.clone(), params, config),
                    readouts: GpuOutputLayer::with_resident(
                        self.gpu.clone(),
                        self.tiling,
                        params,
                        &layers,
                    ),
                })
            })
            .as_ref()
    }
}

impl ErrorRegression<f32> for GpuRegression {
    fn regress<'a>(
        &'a self,
        params: &'a Params<f32>,
        config: &'a ModelConfig,
        request: &RegressionRequest<'_, f32>,
    ) -> Option<Deferred<'a, RegressionResult<f32>>> {
        let updates = request.steps.len();
        let w = &request.window;
        if !matches!(w.posterior, pvrnn_core::backend::Posterior::Adaptive { .. })
            || updates == 0
            || w.len == 0
            || request.eps.len() != updates
            || request.m.len() != 8
            || request.v.len() != 8
        {
            return None;
        }
        let up = self.uploaded(params, config)?;
        let layout = &up.recurrence.layout;
        let observed: Vec<(Modality, usize)> = Modality::ALL
            .into_iter()
            .map(|modality| (modality, request.observed.dims(config, modality)))
            .filter(|&(_, k)| k > 0)
            .collect();
        // The update kernel's table (every update's eps) within one binding.
        let sum_z: usize = layout.modules().iter().map(|m| m.z).sum();
        let table_bytes = std::mem::size_of::<RegressionTable>() + 4 * updates * w.len * sum_z;
        if !layout.fits(&self.gpu, 1, w.len)
            || table_bytes > self.gpu.limits().max_storage_buffer_binding_size as usize
            || observed
                .iter()
                .any(|&(modality, _)| !up.readouts.has_whole_readout(modality))
        {
            return None;
        }
        Some(run(&self.gpu, up, config, request, &observed))
    }
}

/// The updates of `request` on the device (see the module docs): encoded and submitted
/// now, read back when awaited.
fn run<'a>(
    gpu: &'a Gpu,
    up: &Uploaded,
    config: &ModelConfig,
    request: &RegressionRequest<'_, f32>,
    observed: &[(Modality, usize)],
) -> Deferred<'a, RegressionResult<f32>> {
    let phase = pvrnn_core::profile::phase("  error regression on the device");
    let encode_phase = pvrnn_core::profile::phase("    upload and encode");
    let updates = request.steps.len();
    let len = request.window.len;
    let layout = &up.recurrence.layout;
    let modules = *layout.modules();
    let s = layout.strides();
    let zs: [usize; 4] = std::array::from_fn(|m| modules[m].z);
    let b = Buffers::upload(gpu, layout, request, observed, &zs);
    // Everything the submission uses stays out of the pool until it has run: a buffer
    // taken again meanwhile would get its new contents (written through the queue) before
    // the submission's first command.
    let mut keep: Vec<PooledBuffer> = Vec::new();
    let mut encoder = gpu.device.create_command_encoder(&Default::default());
    encoder.clear_buffer(&b.flags, 0, None);
    // Modules without an observed read-out get no gradient from one.
    encoder.clear_buffer(&b.grad_d, 0, None);
    let (update, readouts) = record_update(
        gpu,
        up,
        config,
        request,
        observed,
        &b,
        &mut encoder,
        &mut keep,
    );
    encode_updates(
        gpu,
        request,
        &b,
        &update,
        &readouts,
        &mut encoder,
        &mut keep,
    );
    drop(encode_phase);
    let run_phase = pvrnn_core::profile::phase("    run and read back");
    let pending = read_back(
        gpu,
        encoder,
        &[
            (&b.inputs, b.inputs_len),
            (&b.moments, b.moments_len),
            (&b.flags, updates),
        ],
    );
    let used = (keep, readouts, b);
    Box::pin(async move {
        let results = pending.await;
        drop(run_phase);
        drop(used);
        let result = unpack(results, &zs, &modules, s, len);
        drop(phase);
        result
    })
}

/// The device buffers of one call's updates.
struct Buffers {
    /// The recurrence's table for the window.
    table: PooledBuffer,
    /// The inputs as the first update reads them (its eps in the eps slots), and their
    /// length; updated in place.
    inputs: PooledBuffer,
    inputs_len: usize,
    /// The moments ([`pack_moments`]), updated in place.
    moments: PooledBuffer,
    moments_len: usize,
    /// The update kernel's table ([`regression_table`]).
    meta: PooledBuffer,
    /// Per update, 1 if it was not finite.
    flags: PooledBuffer,
    record: PooledBuffer,
    back: PooledBuffer,
    grad_d: PooledBuffer,
    /// Bound where a modality is not observed (its flag in `meta` says not to read it).
    no_rows: PooledBuffer,
}

impl Buffers {
    fn upload(
        gpu: &Gpu,
        layout: &RecurrenceLayout,
        request: &RegressionRequest<'_, f32>,
        observed: &[(Modality, usize)],
        zs: &[usize; 4],
    ) -> Self {
        let len = request.window.len;
        let s = layout.strides();
        let z_offset: [usize; 4] = std::array::from_fn(|m| zs[..m].iter().sum());
        let first = Window {
            eps: std::array::from_fn(|m| request.eps[0][m].as_slice()),
            ..request.window.clone()
        };
        let (inputs, _) = layout.pack_inputs(std::slice::from_ref(&first));
        let entries = layout.entries(std::iter::once((len, false)));
        let moments = pack_moments(request, zs, &z_offset);
        let scratch = |label, values| gpu.scratch(label, values, wgpu::BufferUsages::empty());
        Self {
            table: layout.upload_table(gpu, &request.ablation, &entries),
            inputs: readable(gpu, "regression inputs", &inputs),
            inputs_len: inputs.len(),
            moments: readable(gpu, "regression moments", &moments),
            moments_len: moments.len(),
            meta: gpu.upload(
                "regression table",
                &regression_table(layout, request, observed, zs, &z_offset),
            ),
            flags: gpu.scratch(
                "regression flags",
                request.steps.len(),
                wgpu::BufferUsages::COPY_SRC,
            ),
            record: scratch("recurrence record", len * s.record),
            back: scratch("recurrence backward", len * s.back),
            grad_d: scratch("read-out gradients", len * s.grad_d),
            no_rows: scratch("no row losses", 1),
        }
    }
}

/// One update's work, recorded once: every update runs the same dispatches on the same
/// buffers, so their bind groups are made once and replayed (each bind group and compute
/// pass costs the host tens of microseconds; an update is some 17 dispatches). The
/// recurrence forward, the observed read-outs (returned, for their row losses), the
/// recurrence backward.
fn record_update(
    gpu: &Gpu,
    up: &Uploaded,
    config: &ModelConfig,
    request: &RegressionRequest<'_, f32>,
    observed: &[(Modality, usize)],
    b: &Buffers,
    encoder: &mut wgpu::CommandEncoder,
    keep: &mut Vec<PooledBuffer>,
) -> (DispatchList, Vec<(Modality, EncodedReadout)>) {
    let recurrence = &up.recurrence;
    let layout = &recurrence.layout;
    let len = request.window.len;
    let mut update = DispatchList::default();
    layout.encode_forward(
        gpu,
        &recurrence.kernels,
        &mut update,
        &b.table,
        &recurrence.weights_t,
        &b.inputs,
        &b.record,
        1,
    );
    let mut readouts = Vec::with_capacity(observed.len());
    for &(modality, k) in observed {
        let (readout, _) = encode_readout_of_record(
            gpu,
            &up.readouts,
            config,
            layout,
            encoder,
            &mut update,
            RecordRows {
                record: &b.record,
                grad_d: &b.grad_d,
                first: 0,
                rows: len,
            },
            modality,
            k,
            &request.window.targets[modality.index()],
            request.resident_targets,
            false,
            keep,
        )
        .expect("the read-out is on the device (checked before)");
        readouts.push((modality, readout));
    }
    keep.push(layout.encode_backward(
        gpu,
        &recurrence.kernels,
        &mut update,
        &b.table,
        &recurrence.weights,
        &b.record,
        &b.grad_d,
        &b.back,
        1,
    ));
    (update, readouts)
}

/// Every update into one compute pass: the recorded work, then the update kernel, which
/// alone differs between updates (its uniform: the index and the RAdam scalars).
fn encode_updates(
    gpu: &Gpu,
    request: &RegressionRequest<'_, f32>,
    b: &Buffers,
    update: &DispatchList,
    readouts: &[(Modality, EncodedReadout)],
    encoder: &mut wgpu::CommandEncoder,
    keep: &mut Vec<PooledBuffer>,
) {
    let count = b.moments_len / 4;
    let kernel = gpu.regression_kernel();
    let (groups_x, groups_y) = grid(gpu, count);
    let rows = |modality: Modality| -> &wgpu::Buffer {
        readouts
            .iter()
            .find(|(o, _)| *o == modality)
            .map_or(&b.no_rows, |(_, r)| &r.row_loss)
    };
    let groups: Vec<wgpu::BindGroup> = request
        .steps
        .iter()
        .enumerate()
        .map(|(u, step)| {
            let params = gpu.uniform(&UpdateParams::new(u, count, groups_x, step));
            let group = bind(
                gpu,
                &kernel,
                &[
                    &params,
                    &b.meta,
                    &b.back,
                    &b.record,
                    rows(Modality::Exteroceptive),
                    rows(Modality::Proprioceptive),
                    &b.inputs,
                    &b.moments,
                    &b.flags,
                ],
            );
            keep.push(params);
            group
        })
        .collect();
    let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor::default());
    for group in &groups {
        update.replay(&mut pass);
        pass.set_pipeline(&kernel);
        pass.set_bind_group(0, group, &[]);
        pass.dispatch_workgroups(groups_x, groups_y, 1);
    }
}

/// The moments in the update kernel's layout: m then v, a_mu then a_sigma, per step the
/// modules' units side by side.
fn pack_moments(
    request: &RegressionRequest<'_, f32>,
    zs: &[usize; 4],
    z_offset: &[usize; 4],
) -> Vec<f32> {
    let len = request.window.len;
    let sum_z: usize = zs.iter().sum();
    let count = len * sum_z;
    let mut moments = vec![0f32; 4 * count];
    for (which, tensors) in [request.m, request.v].into_iter().enumerate() {
        for k in 0..2 {
            for (m, &z) in zs.iter().enumerate() {
                let tensor = &tensors[4 * k + m];
                for t in 0..len {
                    let at = (2 * which + k) * count + t * sum_z + z_offset[m];
                    moments[at..at + z].copy_from_slice(&tensor[t * z..(t + 1) * z]);
                }
            }
        }
    }
    moments
}

/// The update kernel's table ([`RegressionTable`]) and every update's eps after it, as
/// 32-bit words.
fn regression_table(
    layout: &RecurrenceLayout,
    request: &RegressionRequest<'_, f32>,
    observed: &[(Modality, usize)],
    zs: &[usize; 4],
    z_offset: &[usize; 4],
) -> Vec<u32> {
    let len = request.window.len;
    let modules = layout.modules();
    let s = layout.strides();
    let sum_z: usize = zs.iter().sum();
    let has_rows = |modality: Modality| observed.iter().any(|&(o, _)| o == modality) as u32;
    let table = RegressionTable {
        len: len as u32,
        sum_z: sum_z as u32,
        init_stride: s.init as u32,
        input_stride: s.input as u32,
        back_stride: s.back as u32,
        record_stride: s.record as u32,
        updates: request.steps.len() as u32,
        extero_rows: has_rows(Modality::Exteroceptive),
        proprio_rows: has_rows(Modality::Proprioceptive),
        pad: [0; 7],
        modules: std::array::from_fn(|m| {
            let ml = &modules[m];
            UpdateModule {
                z: ml.z as u32,
                offset: z_offset[m] as u32,
                input: ml.input as u32,
                back: ml.back as u32,
                kl_row: (ml.record + 2 * ml.d + 8 * ml.z) as u32,
                pad: [0; 3],
            }
        }),
    };
    let mut words: Vec<u32> = bytemuck::cast_slice(bytemuck::bytes_of(&table)).to_vec();
    words.reserve(request.eps.len() * len * sum_z);
    for eps in request.eps {
        for t in 0..len {
            for (m, &z) in zs.iter().enumerate() {
                words.extend(eps[m][t * z..(t + 1) * z].iter().map(|v| v.to_bits()));
            }
        }
    }
    words
}

/// The adaptive variables and moments from the read-back (see [`run`]).
fn unpack(
    results: Vec<Vec<f32>>,
    zs: &[usize; 4],
    modules: &[ModuleLayout; 4],
    s: Strides,
    len: usize,
) -> RegressionResult<f32> {
    let sum_z: usize = zs.iter().sum();
    let count = len * sum_z;
    let z_offset: [usize; 4] = std::array::from_fn(|m| zs[..m].iter().sum());
    let mut results = results.into_iter();
    let (inputs, moments, flags) = (
        results.next().unwrap_or_default(),
        results.next().unwrap_or_default(),
        results.next().unwrap_or_default(),
    );
    let first_non_finite = flags.iter().position(|f| f.to_bits() != 0);
    // The adaptive variables from the inputs' a slots, the moments back per tensor.
    let a = |k: usize, m: usize| {
        let (z, ml) = (zs[m], modules[m]);
        let mut out = Vec::with_capacity(len * z);
        for t in 0..len {
            let at = s.init + t * s.input + ml.input + k * z;
            out.extend_from_slice(&inputs[at..at + z]);
        }
        out
    };
    let moment = |which: usize, i: usize| {
        let (k, m) = (i / 4, i % 4);
        let z = zs[m];
        let mut out = Vec::with_capacity(len * z);
        for t in 0..len {
            let at = (2 * which + k) * count + t * sum_z + z_offset[m];
            out.extend_from_slice(&moments[at..at + z]);
        }
        out
    };
    RegressionResult {
        a_mu: std::array::from_fn(|m| a(0, m)),
        a_sigma: std::array::from_fn(|m| a(1, m)),
        m: (0..8).map(|i| moment(0, i)).collect(),
        v: (0..8).map(|i| moment(1, i)).collect(),
        first_non_finite,
    }
}

/// A storage buffer holding `values` that can also be read back.
fn readable(gpu: &Gpu, label: &str, values: &[f32]) -> PooledBuffer {
    let buffer = gpu.scratch(label, values.len().max(1), wgpu::BufferUsages::COPY_SRC);
    if !values.is_empty() {
        gpu.queue
            .write_buffer(&buffer, 0, bytemuck::cast_slice(values));
    }
    buffer
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every field a 4-byte scalar or an array of them: no padding on either side, so the
    /// kernel reads the Rust structs at the same offsets (the uniform's size a multiple of
    /// 16 bytes, as uniforms need).
    #[test]
    fn the_update_kernel_s_structs_have_the_wgsl_layout() {
        assert_eq!(std::mem::size_of::<UpdateModule>(), 8 * 4);
        assert_eq!(std::mem::size_of::<RegressionTable>(), 48 * 4);
        assert_eq!(std::mem::size_of::<UpdateParams>(), 12 * 4);
        let wgsl = include_str!("shaders/regression_update.wgsl");
        for name in [
            "struct Params {",
            "struct UpdateModule {",
            "struct RegressionTable {",
        ] {
            assert!(wgsl.contains(name), "{name} is gone from the WGSL");
        }
    }
}
