//! Learning with the read-outs resident on the GPU (pvrnn-core's [`Learner`]): their
//! weights, biases and RAdam moments, hidden layers included, are uploaded once per run.
//! Every iteration a read-out takes the module states, runs its hidden layers and output
//! layer forward and back (`GpuOutputLayer::readout_loss`), leaves every weight gradient
//! in the learner's buffers and returns dF/dd; `radam.wgsl` then updates the weights where
//! they are. At the paper's scale that is 1.6 M of the model's 1.7 M weights, so an
//! iteration no longer uploads 6.5 MB of weights nor reads 6.5 MB of gradients back, and
//! the host's RAdam covers only the rest. The recurrence and the KL terms stay where
//! [`WgpuBackend`] puts them; with the recurrence on the GPU, the learner keeps the
//! recurrent weights and the adaptive variables too and runs the whole iteration
//! ([`DeviceIteration`]). A learner's loaded models serve learning's evaluation only:
//! the host's copies of the resident weights are stale until downloaded.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use bytemuck::{Pod, Zeroable};
use pvrnn_core::ModelConfig;
use pvrnn_core::backend::{Backend, Learner, LoadedModel};
use pvrnn_core::optim::{RAdam, RAdamStep};
use pvrnn_core::params::{Model, Params, Role};
use wgpu::util::DeviceExt;

use crate::WgpuBackend;
use crate::gpu::Gpu;
use crate::iteration::DeviceIteration;
use crate::output::{
    DispatchList, Recorder, bind, dispatch, fits, grid, pad_rows, unpad_rows, vec4s,
};
use crate::readback::read_back;

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
    tensors: Vec<ResidentTensor>,
    /// Rows of `grad_w` written by the last evaluation with weight gradients (the observed
    /// dimensions; 0: none); the update treats the others as zero, and then resets it.
    rows_with_gradient: AtomicUsize,
    /// Whether the hidden layers' gradients were written since the last update (only a
    /// whole read-out on the device writes them); if not, the update treats them as zero.
    hidden_gradients: AtomicBool,
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

    /// Uploads read-out `mi` of `params` for inference: its weights only, no moments and no
    /// gradients (the hidden layers on the device for online inference's updates); `None`
    /// if the kernels do not hold it.
    pub(crate) fn frozen(gpu: &Gpu, params: &Params<f32>, mi: usize) -> Option<Self> {
        Self::upload(gpu, params, None, mi)
    }

    /// Uploads read-out `mi` of `params`, for learning (`learning`: the optimiser, whose
    /// moments go up too, and each tensor's index in its order) or not; `None` if the
    /// kernels do not hold it or, in learning, one of its tensors is not trainable.
    fn upload(
        gpu: &Gpu,
        params: &Params<f32>,
        learning: Option<(&RAdam<f32>, &TensorIndex<'_>)>,
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
            let Some((optimizer, index_of)) = learning else {
                // Never written: kernels that compute no weight gradient do not bind it.
                let no_gradient = resident_buffer(gpu, "no gradient", &[0.0]);
                return Some((resident_buffer(gpu, "frozen tensor", &value), no_gradient));
            };
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

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct RAdamParams {
    count: u32,
    live: u32,
    groups_x: u32,
    rectified: u32,
    b1: f32,
    b2: f32,
    one_b1: f32,
    one_b2: f32,
    wd: f32,
    eps: f32,
    sqrt_bias2: f32,
    lr: f32,
    offset: u32,
    _pad: [u32; 3],
}

/// A learning run on [`WgpuBackend`] with its read-outs resident (see the module docs), and
/// with the recurrence on the GPU ([`WgpuBackend::with_recurrence_on_gpu`]) everything
/// else too (`iteration.rs`).
#[derive(Debug)]
pub struct GpuLearner {
    backend: WgpuBackend,
    layers: [Option<Arc<ResidentLayer>>; 2],
    /// The recurrence and the adaptive variables, when the whole iteration runs here.
    iteration: Option<DeviceIteration>,
    /// Their tensors (ranges of the packed recurrent weights, the adaptive variables).
    more: Vec<ResidentTensor>,
    resident: Vec<usize>,
}

impl GpuLearner {
    /// Uploads the read-outs of `model` that the kernels hold, with their moments from
    /// `optimizer`; `None` if there is none to keep.
    pub(crate) fn new(
        backend: &WgpuBackend,
        model: &Model<f32>,
        optimizer: &RAdam<f32>,
    ) -> Option<Self> {
        let index_of = trainable_indices(&model.params);
        let layers: [Option<Arc<ResidentLayer>>; 2] = std::array::from_fn(|mi| {
            ResidentLayer::upload(
                backend.gpu(),
                &model.params,
                Some((optimizer, &index_of)),
                mi,
            )
            .map(Arc::new)
        });
        let mut more = Vec::new();
        let iteration = backend
            .recurrence_on_gpu()
            .then(|| {
                DeviceIteration::new(
                    backend.gpu(),
                    backend.tiling(),
                    model,
                    optimizer,
                    &layers,
                    &index_of,
                    &mut more,
                )
            })
            .flatten();
        let resident: Vec<usize> = layers
            .iter()
            .flatten()
            .flat_map(|l| l.tensors.iter().map(|t| t.index))
            .chain(more.iter().map(|t| t.index))
            .collect();
        (!resident.is_empty()).then(|| Self {
            backend: backend.clone(),
            layers,
            iteration,
            more,
            resident,
        })
    }

    fn gpu(&self) -> &Gpu {
        self.backend.gpu()
    }

    /// Encodes one RAdam step of `t`: its first `live` elements with their gradient, the
    /// rest without.
    fn encode_update(
        &self,
        encoder: &mut dyn Recorder,
        step: &RAdamStep,
        t: &ResidentTensor,
        live: usize,
        keep: &mut Vec<crate::pool::PooledBuffer>,
    ) {
        let gpu = self.gpu();
        let count = t.len;
        let (groups_x, groups_y) = grid(gpu, count);
        let params = gpu.uniform(&RAdamParams {
            count: count as u32,
            live: live as u32,
            groups_x,
            rectified: step.rectified.is_some() as u32,
            b1: step.beta1 as f32,
            b2: step.beta2 as f32,
            one_b1: (1.0 - step.beta1) as f32,
            one_b2: (1.0 - step.beta2) as f32,
            wd: step.weight_decay as f32,
            eps: step.eps as f32,
            sqrt_bias2: step.sqrt_bias2 as f32,
            lr: step.rectified.unwrap_or(step.plain) as f32,
            offset: t.offset as u32,
            _pad: [0; 3],
        });
        let kernel = gpu.radam_kernel();
        let group = bind(
            gpu,
            &kernel,
            &[&params, &t.value, &t.moments[0], &t.moments[1], &t.grad],
        );
        dispatch(encoder, &kernel, &group, groups_x, groups_y);
        keep.push(params);
    }
}

/// A tensor's index in the trainer's order of trainable tensors, `None` for a fixed one
/// (see [`trainable_indices`]).
pub(crate) type TensorIndex<'a> = dyn Fn(&pvrnn_core::Tensor<f32>) -> Option<usize> + 'a;

/// A long-lived storage buffer (not pooled: it lives as long as its learner).
pub(crate) fn resident_buffer(gpu: &Gpu, label: &str, values: &[f32]) -> wgpu::Buffer {
    let values: &[f32] = if values.is_empty() { &[0.0] } else { values };
    gpu.device
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents: bytemuck::cast_slice(values),
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
        })
}

/// A function giving a tensor's index in the trainer's order of trainable tensors (the
/// parameters that are `Role::Trainable`, in `Params::named` order, then the adaptive
/// variables), or `None` for a fixed one.
fn trainable_indices(params: &Params<f32>) -> impl Fn(&pvrnn_core::Tensor<f32>) -> Option<usize> {
    let addresses: Vec<*const pvrnn_core::Tensor<f32>> = params
        .named()
        .into_iter()
        .filter(|(_, _, role)| *role == Role::Trainable)
        .map(|(_, t, _)| t as *const _)
        .collect();
    move |tensor| addresses.iter().position(|&a| std::ptr::eq(a, tensor))
}

impl Backend<f32> for GpuLearner {
    /// A model whose read-outs are the learner's. When the learner runs whole iterations,
    /// the recurrent weights and adaptive variables it keeps are not in such a model (it
    /// takes them from `params` and the windows, the host's stale copies): learning then
    /// evaluates through [`Learner::free_energy`] only, as `Trainer` does.
    fn load(&self, params: &Params<f32>, config: &ModelConfig) -> Box<dyn LoadedModel<f32>> {
        self.backend.load_with_layers(params, config, &self.layers)
    }
}

impl Learner<f32> for GpuLearner {
    fn resident(&self) -> &[usize] {
        &self.resident
    }

    fn update(&self, step: &RAdamStep) {
        let gpu = self.gpu();
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        let mut keep = Vec::new();
        // Every tensor's update in one compute pass.
        let mut work = DispatchList::default();
        for layer in self.layers.iter().flatten() {
            let k = layer.rows_with_gradient.swap(0, Ordering::SeqCst);
            let hidden = layer.hidden_gradients.swap(false, Ordering::SeqCst);
            for t in &layer.tensors {
                let live = match t.part {
                    Part::OutputWeight => k * 4 * vec4s(layer.hidden_width),
                    Part::OutputBias => k,
                    Part::Hidden if hidden => t.len,
                    Part::Hidden => 0,
                    Part::Whole => t.len,
                };
                self.encode_update(&mut work, step, t, live, &mut keep);
            }
        }
        for t in &self.more {
            self.encode_update(&mut work, step, t, t.len, &mut keep);
        }
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor::default());
            work.replay(&mut pass);
        }
        if let Some(iteration) = &self.iteration {
            iteration.encode_transposes(gpu, &mut encoder, &mut keep);
        }
        // Queued, not waited for: the next iteration's submissions run after it. The
        // uniforms may go back to the pool at once: a later user writes them through the
        // queue, which orders that write after this submission.
        gpu.queue.submit([encoder.finish()]);
        drop(keep);
    }

    fn download(&self, index: usize, value: &mut [f32], m: &mut [f32], v: &mut [f32]) {
        let found = self
            .layers
            .iter()
            .flatten()
            .find_map(|l| {
                l.tensors
                    .iter()
                    .find(|t| t.index == index)
                    .map(|t| (Some(l.hidden_width), t))
            })
            .or_else(|| {
                self.more
                    .iter()
                    .find(|t| t.index == index)
                    .map(|t| (None, t))
            });
        let Some((layer_width, t)) = found else {
            panic!("tensor {index} is not resident on this learner");
        };
        let gpu = self.gpu();
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        // The tensor's range of its three buffers (a packed buffer holds others too).
        let len = t.len;
        let part = gpu.scratch("download", 3 * len, wgpu::BufferUsages::COPY_SRC);
        let [mb, vb] = &t.moments;
        for (k, buffer) in [&t.value, mb, vb].into_iter().enumerate() {
            encoder.copy_buffer_to_buffer(
                buffer,
                (4 * t.offset) as u64,
                &part,
                (4 * k * len) as u64,
                (4 * len) as u64,
            );
        }
        let results = pvrnn_core::deferred::now(read_back(gpu, encoder, &[(&part, 3 * len)]));
        drop(part);
        let values = results.into_iter().next().unwrap_or_default();
        for (dst, src) in [value, m, v]
            .into_iter()
            .zip(values.chunks_exact(len.max(1)))
        {
            match layer_width {
                Some(width) if t.part == Part::OutputWeight => {
                    dst.copy_from_slice(&unpad_rows(src, width));
                }
                _ => dst.copy_from_slice(src),
            }
        }
    }

    fn runs_whole_iterations(&self) -> bool {
        self.iteration.is_some()
    }

    fn free_energy(
        &self,
        data: &pvrnn_core::Observations<f32>,
        eps: &[[Vec<f32>; 4]],
    ) -> Option<pvrnn_core::Result<pvrnn_core::FreeEnergy>> {
        let iteration = self.iteration.as_ref()?;
        Some(iteration.free_energy(self.gpu(), data, eps))
    }
}
