//! A learner's whole read-out encoded on the device: its hidden layers forward from the
//! module states (`shaders/dense_*.wgsl`), the output layer's loss, and the way back to
//! d F / d d with every weight gradient into the learner's buffers.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use pvrnn_core::Modality;

use crate::encode::{Recorder, bind, dispatch, grid, vec4s};
use crate::pool::PooledBuffer;
use crate::resident::ResidentLayer;

use super::GpuOutputLayer;
use super::loss::EncodedLoss;

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct DenseParams {
    rows: u32,
    fan_in: u32,
    fan_out: u32,
    x_stride: u32,
    y_stride: u32,
    has_bias: u32,
    groups_x: u32,
    _pad: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct DenseWeightsParams {
    rows: u32,
    fan_in: u32,
    fan_out: u32,
    x_stride: u32,
    y_stride: u32,
    rows_per_split: u32,
    groups_x: u32,
    splits: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct DenseReduceParams {
    fan_in: u32,
    fan_out: u32,
    splits: u32,
    has_bias: u32,
    groups_x: u32,
    _pad: [u32; 3],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct DenseBackParams {
    rows: u32,
    fan_in: u32,
    fan_out: u32,
    y_stride: u32,
    gx_stride: u32,
    groups_x: u32,
    _pad: [u32; 2],
}

/// A learner's whole read-out encoded on the device (see [`GpuOutputLayer::encode_readout`]).
#[derive(Debug)]
pub(crate) struct EncodedReadout {
    /// d F / d the module states, `[n, grad_stride]` (the first `d` values of each row).
    pub(crate) grad_d: PooledBuffer,
    pub(crate) grad_stride: usize,
    /// The row losses' sums of squared errors (times 1 / divisor), `[n]`.
    pub(crate) row_loss: PooledBuffer,
    /// What the submission uses, kept from the pool until it has run.
    _keep: Vec<PooledBuffer>,
    _targets: Option<Arc<Vec<wgpu::Buffer>>>,
}

impl GpuOutputLayer {
    /// Encodes a learner's whole read-out of `modality` from the module states in `input`:
    /// `[n, input width]` for a read-out with hidden layers, else `[n, 4 hv]` (the output
    /// layer's padded rows, padding zero). The hidden layers forward, the output layer's
    /// loss, and back to d F / d d, every weight gradient into the learner's buffers (when
    /// `weight_grads`). `None` unless the read-out is a learner's.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn encode_readout(
        &self,
        encoder: &mut dyn Recorder,
        modality: Modality,
        input: &wgpu::Buffer,
        n: usize,
        k: usize,
        divisor: usize,
        targets: &[&[f32]],
        resident: Option<u64>,
        weight_grads: bool,
    ) -> Option<EncodedReadout> {
        let layer = self.layer(modality)?;
        let readout = layer.resident()?;
        let mut keep = Vec::new();
        let acts = self.encode_hidden_forward(encoder, readout, input, n, &mut keep);
        let top: &wgpu::Buffer = acts.last().map_or(input, |(a, _)| a);
        let encoded = self.encode_loss(
            encoder,
            layer,
            modality,
            top,
            n,
            k,
            divisor,
            targets,
            resident,
            weight_grads,
        );
        let EncodedLoss {
            grad_in,
            row_loss,
            grads: _,
            in_flight,
            resident_targets,
        } = encoded;
        keep.extend(in_flight);
        let (grad_d, grad_stride) = if readout.hidden.is_empty() {
            (grad_in, 4 * vec4s(layer.hidden))
        } else {
            let grad_d = self.encode_hidden_backward(
                encoder,
                readout,
                input,
                &acts,
                grad_in,
                n,
                weight_grads,
                &mut keep,
            );
            if weight_grads {
                readout.hidden_gradients_written();
            }
            (grad_d, readout.input_width)
        };
        keep.extend(acts.into_iter().map(|(a, _)| a));
        Some(EncodedReadout {
            grad_d,
            grad_stride,
            row_loss,
            _keep: keep,
            _targets: resident_targets,
        })
    }

    /// Encodes the hidden layers of a learner's read-out, forward from the module states in
    /// `d` (`[n, input width]`): every layer's activations, the top one in padded rows for
    /// the output layer's kernels. Returns them bottom first.
    pub(super) fn encode_hidden_forward(
        &self,
        encoder: &mut dyn Recorder,
        readout: &ResidentLayer,
        d: &wgpu::Buffer,
        n: usize,
        in_flight: &mut Vec<PooledBuffer>,
    ) -> Vec<(PooledBuffer, usize)> {
        let gpu = &*self.gpu;
        let kernels = gpu.dense_kernels();
        let mut acts: Vec<(PooledBuffer, usize)> = Vec::with_capacity(readout.hidden.len());
        for (l, layer) in readout.hidden.iter().enumerate() {
            let top = l + 1 == readout.hidden.len();
            let y_stride = if top {
                4 * vec4s(layer.fan_out)
            } else {
                layer.fan_out
            };
            let (x, x_stride) = match acts.last() {
                Some((a, stride)) => (&**a, *stride),
                None => (d, readout.input_width),
            };
            // COPY_SRC: `hidden_top` reads the top layer back.
            let y = gpu.scratch(
                "hidden activations",
                n * y_stride,
                wgpu::BufferUsages::COPY_SRC,
            );
            let (groups_x, groups_y) = grid(gpu, n * y_stride);
            let params = gpu.uniform(&DenseParams {
                rows: n as u32,
                fan_in: layer.fan_in as u32,
                fan_out: layer.fan_out as u32,
                x_stride: x_stride as u32,
                y_stride: y_stride as u32,
                has_bias: layer.has_bias as u32,
                groups_x,
                _pad: 0,
            });
            let group = bind(
                gpu,
                &kernels.forward,
                &[&params, x, &layer.weight, &layer.bias, &y],
            );
            dispatch(encoder, &kernels.forward, &group, groups_x, groups_y);
            in_flight.push(params);
            acts.push((y, y_stride));
        }
        acts
    }

    /// Encodes the way back through a learner's hidden layers from `grad_top` (d F / d the
    /// top activations, padded rows): the weight gradients into the learner's buffers (when
    /// `weight_grads`) and d F / d d, `[n, input width]`, which it returns.
    #[allow(clippy::too_many_arguments)]
    fn encode_hidden_backward(
        &self,
        encoder: &mut dyn Recorder,
        readout: &ResidentLayer,
        d: &wgpu::Buffer,
        acts: &[(PooledBuffer, usize)],
        grad_top: PooledBuffer,
        n: usize,
        weight_grads: bool,
        in_flight: &mut Vec<PooledBuffer>,
    ) -> PooledBuffer {
        let gpu = &*self.gpu;
        let kernels = gpu.dense_kernels();
        let mut grad = grad_top;
        for (l, layer) in readout.hidden.iter().enumerate().rev() {
            let (y, y_stride) = (&acts[l].0, acts[l].1);
            let (x, x_stride): (&wgpu::Buffer, usize) = match l {
                0 => (d, readout.input_width),
                _ => (&acts[l - 1].0, acts[l - 1].1),
            };
            if weight_grads {
                // Split-K over rows, then the ranges added in order.
                let values = layer.fan_out * (layer.fan_in + 1);
                let rows_per_split = self.tiling.weight_rows_per_split.max(1);
                let splits = n.div_ceil(rows_per_split);
                let partial =
                    gpu.scratch("d W partials", splits * values, wgpu::BufferUsages::empty());
                let (groups_x, groups_y) = grid(gpu, splits * values);
                let params = gpu.uniform(&DenseWeightsParams {
                    rows: n as u32,
                    fan_in: layer.fan_in as u32,
                    fan_out: layer.fan_out as u32,
                    x_stride: x_stride as u32,
                    y_stride: y_stride as u32,
                    rows_per_split: rows_per_split as u32,
                    groups_x,
                    splits: splits as u32,
                });
                let group = bind(gpu, &kernels.weights, &[&params, x, y, &grad, &partial]);
                dispatch(encoder, &kernels.weights, &group, groups_x, groups_y);
                let (reduce_x, reduce_y) = grid(gpu, values);
                let reduce_params = gpu.uniform(&DenseReduceParams {
                    fan_in: layer.fan_in as u32,
                    fan_out: layer.fan_out as u32,
                    splits: splits as u32,
                    has_bias: layer.has_bias as u32,
                    groups_x: reduce_x,
                    _pad: [0; 3],
                });
                let group = bind(
                    gpu,
                    &kernels.weights_reduce,
                    &[&reduce_params, &partial, &layer.grad_w, &layer.grad_b],
                );
                dispatch(encoder, &kernels.weights_reduce, &group, reduce_x, reduce_y);
                in_flight.extend([params, reduce_params, partial]);
            }
            let grad_x = gpu.scratch("d hidden input", n * x_stride, wgpu::BufferUsages::COPY_SRC);
            let (groups_x, groups_y) = grid(gpu, n * x_stride);
            let params = gpu.uniform(&DenseBackParams {
                rows: n as u32,
                fan_in: layer.fan_in as u32,
                fan_out: layer.fan_out as u32,
                y_stride: y_stride as u32,
                gx_stride: x_stride as u32,
                groups_x,
                _pad: [0; 2],
            });
            let group = bind(
                gpu,
                &kernels.backward,
                &[&params, &grad, y, &layer.weight, &grad_x],
            );
            dispatch(encoder, &kernels.backward, &group, groups_x, groups_y);
            in_flight.push(params);
            in_flight.push(std::mem::replace(&mut grad, grad_x));
        }
        grad
    }
}
