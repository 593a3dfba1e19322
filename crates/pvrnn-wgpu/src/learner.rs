//! Learning with the output layers resident on the GPU (pvrnn-core's [`Learner`]): their
//! weights, biases and RAdam moments are uploaded once per run; every iteration the row and
//! column passes leave the weight gradients in the learner's buffers and `radam.wgsl`
//! updates the weights where they are. At the paper's scale that is 1.6 M of the model's
//! 1.7 M weights, so an iteration no longer uploads 6.5 MB of weights nor reads 6.5 MB of
//! gradients back, and the host's RAdam covers only the rest. The recurrence, the hidden
//! read-out layers and the KL terms stay where [`WgpuBackend`] puts them.

use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

use bytemuck::{Pod, Zeroable};
use pvrnn_core::ModelConfig;
use pvrnn_core::backend::{Backend, Learner, LoadedModel};
use pvrnn_core::optim::{RAdam, RAdamStep};
use pvrnn_core::params::{Model, Params, Role};
use wgpu::util::DeviceExt;

use crate::WgpuBackend;
use crate::gpu::Gpu;
use crate::output::{bind, dispatch, fits, pad_rows, unpad_rows, vec4s};
use crate::readback::read_back;

/// Threads per workgroup of `radam.wgsl`.
const WORKGROUP: usize = 64;

/// One output layer kept on the device for a learning run, in the kernels' layout (rows of
/// the weight zero-padded to whole vec4s; the padding stays zero through every update).
#[derive(Debug)]
pub(crate) struct ResidentLayer {
    pub(crate) weight: wgpu::Buffer,
    /// `[dims]`; zeros (and never updated) for a layer without a bias.
    pub(crate) bias: wgpu::Buffer,
    pub(crate) grad_w: wgpu::Buffer,
    pub(crate) grad_b: wgpu::Buffer,
    moments_w: [wgpu::Buffer; 2],
    moments_b: Option<[wgpu::Buffer; 2]>,
    hidden: usize,
    dims: usize,
    /// The tensors' indices in the trainer's order (`pvrnn_core::train::trainable_names`).
    weight_index: usize,
    bias_index: Option<usize>,
    /// Rows of `grad_w` written by the last evaluation with weight gradients (the observed
    /// dimensions); the update treats the others as zero, and then resets it.
    rows_with_gradient: AtomicUsize,
}

impl ResidentLayer {
    /// Records that `grad_w` and `grad_b` now hold the gradient of the first `k` rows.
    pub(crate) fn gradient_rows(&self, k: usize) {
        self.rows_with_gradient.store(k, Ordering::SeqCst);
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
}

/// A learning run on [`WgpuBackend`] with its output layers resident (see the module docs).
#[derive(Debug)]
pub struct GpuLearner {
    backend: WgpuBackend,
    layers: [Option<Arc<ResidentLayer>>; 2],
    resident: Vec<usize>,
}

impl GpuLearner {
    /// Uploads the output layers of `model` that the kernels hold, with their moments from
    /// `optimizer`; `None` if there is none to keep.
    pub(crate) fn new(
        backend: &WgpuBackend,
        model: &Model<f32>,
        optimizer: &RAdam<f32>,
    ) -> Option<Self> {
        let index_of = trainable_indices(&model.params);
        let gpu = backend.gpu();
        let layers: [Option<Arc<ResidentLayer>>; 2] = std::array::from_fn(|mi| {
            let out = &model.params.readouts[mi].out;
            let (dims, hidden) = (out.weight.shape()[0], out.weight.shape()[1]);
            let weight_index = index_of(&out.weight)?;
            if !fits(dims, hidden) {
                return None;
            }
            let bias_index = out.bias.as_ref().and_then(&index_of);
            let padded = |values: &[f32]| pad_rows(values, hidden);
            let buffer = |label: &str, values: &[f32]| resident_buffer(gpu, label, values);
            let zeros = vec![0f32; dims];
            // A fixed bias is read, never updated; a missing one is zero.
            let bias = out.bias.as_ref().map_or(zeros.as_slice(), |b| b.data());
            Some(Arc::new(ResidentLayer {
                weight: buffer("resident output weight", &padded(out.weight.data())),
                bias: buffer("resident output bias", bias),
                grad_w: buffer("resident d W", &vec![0f32; dims * 4 * vec4s(hidden)]),
                grad_b: buffer("resident d b", &zeros),
                moments_w: [
                    buffer("resident m of W", &padded(&optimizer.m[weight_index])),
                    buffer("resident v of W", &padded(&optimizer.v[weight_index])),
                ],
                moments_b: bias_index.map(|i| {
                    [
                        buffer("resident m of b", &optimizer.m[i]),
                        buffer("resident v of b", &optimizer.v[i]),
                    ]
                }),
                hidden,
                dims,
                weight_index,
                bias_index,
                rows_with_gradient: AtomicUsize::new(0),
            }))
        });
        let resident: Vec<usize> = layers
            .iter()
            .flatten()
            .flat_map(|l| std::iter::once(l.weight_index).chain(l.bias_index))
            .collect();
        (!resident.is_empty()).then(|| Self {
            backend: backend.clone(),
            layers,
            resident,
        })
    }

    fn gpu(&self) -> &Gpu {
        self.backend.gpu()
    }

    /// Encodes one RAdam step of `count` elements, the first `live` of which have a gradient.
    #[allow(clippy::too_many_arguments)]
    fn encode_update(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        step: &RAdamStep,
        count: usize,
        live: usize,
        value: &wgpu::Buffer,
        moments: &[wgpu::Buffer; 2],
        grad: &wgpu::Buffer,
        keep: &mut Vec<crate::pool::PooledBuffer>,
    ) {
        let gpu = self.gpu();
        let groups = count.div_ceil(WORKGROUP);
        let max = gpu.limits().max_compute_workgroups_per_dimension as usize;
        let groups_x = groups.clamp(1, max);
        let params = gpu.uniform(&RAdamParams {
            count: count as u32,
            live: live as u32,
            groups_x: groups_x as u32,
            rectified: step.rectified.is_some() as u32,
            b1: step.beta1 as f32,
            b2: step.beta2 as f32,
            one_b1: (1.0 - step.beta1) as f32,
            one_b2: (1.0 - step.beta2) as f32,
            wd: step.weight_decay as f32,
            eps: step.eps as f32,
            sqrt_bias2: step.sqrt_bias2 as f32,
            lr: step.rectified.unwrap_or(step.plain) as f32,
        });
        let kernel = gpu.radam_kernel();
        let group = bind(
            gpu,
            &kernel,
            &[&params, value, &moments[0], &moments[1], grad],
        );
        dispatch(
            encoder,
            &kernel,
            &group,
            groups_x as u32,
            groups.div_ceil(groups_x) as u32,
        );
        keep.push(params);
    }
}

/// A long-lived storage buffer (not pooled: it lives as long as its learner).
fn resident_buffer(gpu: &Gpu, label: &str, values: &[f32]) -> wgpu::Buffer {
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
        for layer in self.layers.iter().flatten() {
            let k = layer.rows_with_gradient.swap(0, Ordering::SeqCst);
            let width = 4 * vec4s(layer.hidden);
            self.encode_update(
                &mut encoder,
                step,
                layer.dims * width,
                k * width,
                &layer.weight,
                &layer.moments_w,
                &layer.grad_w,
                &mut keep,
            );
            if let Some(moments) = &layer.moments_b {
                self.encode_update(
                    &mut encoder,
                    step,
                    layer.dims,
                    k,
                    &layer.bias,
                    moments,
                    &layer.grad_b,
                    &mut keep,
                );
            }
        }
        // Queued, not waited for: the next iteration's submissions run after it.
        gpu.queue.submit([encoder.finish()]);
        drop(keep);
    }

    fn download(&self, index: usize, value: &mut [f32], m: &mut [f32], v: &mut [f32]) {
        let Some((layer, is_weight)) = self.layers.iter().flatten().find_map(|l| {
            if l.weight_index == index {
                Some((l, true))
            } else if l.bias_index == Some(index) {
                Some((l, false))
            } else {
                None
            }
        }) else {
            panic!("tensor {index} is not resident on this learner");
        };
        let gpu = self.gpu();
        let (buffers, floats) = if is_weight {
            let [mw, vw] = &layer.moments_w;
            (
                [&layer.weight, mw, vw],
                layer.dims * 4 * vec4s(layer.hidden),
            )
        } else {
            let [mb, vb] = layer
                .moments_b
                .as_ref()
                .expect("a resident bias has moments");
            ([&layer.bias, mb, vb], layer.dims)
        };
        let encoder = gpu.device.create_command_encoder(&Default::default());
        let sources: Vec<(&wgpu::Buffer, usize)> = buffers.iter().map(|&b| (b, floats)).collect();
        let results = pvrnn_core::deferred::now(read_back(gpu, encoder, &sources));
        for (dst, src) in [value, m, v].into_iter().zip(results) {
            let src = if is_weight {
                unpad_rows(&src, layer.hidden)
            } else {
                src
            };
            dst.copy_from_slice(&src);
        }
    }
}
