//! A learner's tensors on the device ([`ResidentLayer`]: a read-out's weights, biases,
//! RAdam moments and gradients), shared by the learner, the output layer that computes
//! with them, and the whole-iteration learner.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use pvrnn_core::optim::RAdam;
use pvrnn_core::params::Params;

use crate::encode::{fits, pad_rows};
use crate::gpu::Gpu;

/// One read-out (its hidden layers and its output layer) kept on the device for a learning
/// run, in the kernels' layout (rows of the output weight zero-padded to whole vec4s; the
/// padding stays zero through every update).
#[derive(Debug)]
pub(crate) struct ResidentLayer {
    pub(crate) weight: wgpu::Buffer,
    /// `[dims]`; zeros (and never updated) for a layer without a bias.
    pub(crate) bias: wgpu::Buffer,
    pub(crate) grad_w: wgpu::Buffer,
    pub(crate) grad_b: wgpu::Buffer,
    /// The hidden layers, bottom (module side) first.
    pub(crate) hidden: Vec<ResidentDense>,
    /// Width of the module's states `d`, the read-out's input.
    pub(crate) input_width: usize,
    /// The output layer's fan-in (the top hidden width).
    pub(crate) hidden_width: usize,
    /// Every trainable tensor of the read-out, with its moments and gradient.
    pub(crate) tensors: Vec<ResidentTensor>,
    /// Rows of `grad_w` written by the last evaluation with weight gradients (the observed
    /// dimensions; 0: none); the update treats the others as zero, and then resets it.
    pub(crate) rows_with_gradient: AtomicUsize,
    /// Whether the hidden layers' gradients were written since the last update (only a
    /// whole read-out on the device writes them); if not, the update treats them as zero.
    pub(crate) hidden_gradients: AtomicBool,
}

/// A hidden read-out layer on the device, `y = tanh(W x + b)`.
#[derive(Debug)]
pub(crate) struct ResidentDense {
    pub(crate) weight: wgpu::Buffer,
    /// `[fan_out]`; zeros for a layer without a bias.
    pub(crate) bias: wgpu::Buffer,
    pub(crate) grad_w: wgpu::Buffer,
    pub(crate) grad_b: wgpu::Buffer,
    pub(crate) fan_in: usize,
    pub(crate) fan_out: usize,
    pub(crate) has_bias: bool,
}

/// One trainable tensor's buffers (shared with [`ResidentLayer`]'s handles, or with the
/// packed recurrent weights of [`DeviceIteration`]).
#[derive(Debug)]
pub(crate) struct ResidentTensor {
    /// Its index in the trainer's order (`pvrnn_core::train::trainable_names`).
    pub(crate) index: usize,
    pub(crate) value: wgpu::Buffer,
    pub(crate) moments: [wgpu::Buffer; 2],
    pub(crate) grad: wgpu::Buffer,
    /// Floats in the device's layout.
    pub(crate) len: usize,
    /// Where it starts in its buffers (value, moments and gradient share the layout).
    pub(crate) offset: usize,
    pub(crate) part: Part,
}

/// Which gradient rows an evaluation writes: the output layer's observed rows only, a
/// hidden layer's whole tensor when a whole read-out ran on the device, the recurrence's
/// and the adaptive variables' every time (only the device evaluates them).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Part {
    OutputWeight,
    OutputBias,
    Hidden,
    Whole,
}

impl ResidentLayer {
    /// Records that the gradients now hold the first `k` rows of the output layer's (and
    /// all of the hidden layers').
    pub(crate) fn gradient_rows(&self, k: usize) {
        self.rows_with_gradient.store(k, Ordering::SeqCst);
    }

    /// Records that the hidden layers' gradients are this evaluation's.
    pub(crate) fn hidden_gradients_written(&self) {
        self.hidden_gradients.store(true, Ordering::SeqCst);
    }

    /// Uploads read-out `mi` of `params` for learning: each tensor with its moments (from
    /// `optimizer`, at the tensor's index in its order) and a gradient; `None` if the
    /// kernels do not hold it or one of its tensors is not trainable.
    pub(crate) fn upload(
        gpu: &Gpu,
        params: &Params<f32>,
        (optimizer, index_of): (&RAdam<f32>, &TensorIndex<'_>),
        mi: usize,
    ) -> Option<Self> {
        let readout = &params.readouts[mi];
        let out = &readout.out;
        let (dims, hidden_width) = (out.weight.shape()[0], out.weight.shape()[1]);
        if !fits(dims, hidden_width) {
            return None;
        }
        let mut tensors = Vec::new();
        // The value's buffer, and the tensor with its moments and gradient (in `layout`).
        let mut add = |tensor: &pvrnn_core::Tensor<f32>,
                       part: Part,
                       layout: &dyn Fn(&[f32]) -> Vec<f32>|
         -> Option<(wgpu::Buffer, wgpu::Buffer)> {
            let value = layout(tensor.data());
            let index = index_of(tensor)?;
            let len = value.len();
            let buffer = |label: &str, values: &[f32]| resident_buffer(gpu, label, values);
            let t = ResidentTensor {
                index,
                value: buffer("resident tensor", &value),
                moments: [
                    buffer("resident m", &layout(&optimizer.m[index])),
                    buffer("resident v", &layout(&optimizer.v[index])),
                ],
                grad: buffer("resident gradient", &vec![0f32; len]),
                len,
                offset: 0,
                part,
            };
            let handles = (t.value.clone(), t.grad.clone());
            tensors.push(t);
            Some(handles)
        };
        let plain = |v: &[f32]| v.to_vec();
        let mut hidden = Vec::new();
        for layer in &readout.hidden {
            let (fan_out, fan_in) = (layer.weight.shape()[0], layer.weight.shape()[1]);
            let (weight, grad_w) = add(&layer.weight, Part::Hidden, &plain)?;
            let (bias, grad_b) = match &layer.bias {
                Some(b) => add(b, Part::Hidden, &plain)?,
                None => (
                    resident_buffer(gpu, "no bias", &vec![0f32; fan_out]),
                    resident_buffer(gpu, "no bias gradient", &vec![0f32; fan_out]),
                ),
            };
            hidden.push(ResidentDense {
                weight,
                bias,
                grad_w,
                grad_b,
                fan_in,
                fan_out,
                has_bias: layer.bias.is_some(),
            });
        }
        let padded = |v: &[f32]| pad_rows(v, hidden_width);
        let (weight, grad_w) = add(&out.weight, Part::OutputWeight, &padded)?;
        let (bias, grad_b) = match &out.bias {
            Some(b) => add(b, Part::OutputBias, &plain)?,
            None => (
                resident_buffer(gpu, "no bias", &vec![0f32; dims]),
                resident_buffer(gpu, "no bias gradient", &vec![0f32; dims]),
            ),
        };
        let input_width = readout
            .hidden
            .first()
            .map_or(hidden_width, |l| l.weight.shape()[1]);
        Some(Self {
            weight,
            bias,
            grad_w,
            grad_b,
            hidden,
            input_width,
            hidden_width,
            tensors,
            rows_with_gradient: AtomicUsize::new(0),
            hidden_gradients: AtomicBool::new(false),
        })
    }
}

/// A tensor's index in the trainer's order of trainable tensors, `None` for a fixed one
/// (see [`trainable_indices`]).
pub(crate) type TensorIndex<'a> = dyn Fn(&pvrnn_core::Tensor<f32>) -> Option<usize> + 'a;

/// A long-lived storage buffer (not pooled: it lives as long as its learner).
pub(crate) fn resident_buffer(gpu: &Gpu, label: &str, values: &[f32]) -> wgpu::Buffer {
    let values: &[f32] = if values.is_empty() { &[0.0] } else { values };
    gpu.filled(
        label,
        values,
        wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
    )
}
