//! The recurrence kernels' dispatches: forward and backward over the table's windows (a
//! workgroup each), the weight gradients (partial sums per window reduced in window order,
//! or a thread per weight over all windows), and whether the kernels hold a shape.

use bytemuck::{Pod, Zeroable};

use crate::encode::{Recorder, bind, dispatch};
use crate::gpu::{Gpu, RecurrenceKernels};
use crate::pool::PooledBuffer;

use super::layout::RecurrenceLayout;
use super::table::{TABLE_WINDOWS, WINDOW_WORDS};

/// Units per module the kernels' workgroup arrays hold (`MAX_UNITS` in the WGSL).
const MAX_UNITS: usize = 128;

/// Threads per workgroup of the weight-gradient kernel.
const WEIGHTS_WORKGROUP: usize = 64;

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

impl RecurrenceLayout {
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
