//! The read-outs' output layers on the GPU: weights uploaded once per loaded model, inputs
//! and targets streamed per call in chunks of rows that fit WebGPU's binding limits.
//!
//! Files:
//! - This file: [`GpuOutputLayer`], its layers' weights (uploaded, or a learner's resident
//!   ones) and the targets it keeps on the device.
//! - `tiling.rs`: how a call is cut into work ([`Tiling`]) and which kernels run
//!   ([`OutputKernels`]).
//! - `cut.rs`: a loss call's chunks of rows and column splits, and the buffers a chunk uses.
//! - `loss.rs`: the loss encoded chunk by chunk: the fused row and column passes, the
//!   splits' partials reduced.
//! - `blocked.rs`: the register-blocked kernels' three products for a chunk.
//! - `hidden.rs`: a learner's whole read-out: its hidden layers forward and back around the
//!   output layer's loss.
//! - `calls.rs`: the calls a read-out makes (the loss, the whole read-out's loss, the top
//!   hidden activations, predictions), each read back as a future.

mod blocked;
mod calls;
mod cut;
mod hidden;
mod loss;
mod tiling;

use std::sync::Arc;

use pvrnn_core::Modality;
use pvrnn_core::params::Params;

use crate::encode::{fits, pad_rows, vec4s};
use crate::gpu::{Gpu, Kernels, ResidentKey};
use crate::pool::PooledBuffer;
use crate::resident::ResidentLayer;

pub(crate) use hidden::EncodedReadout;
pub use tiling::{OutputKernels, Tiling};

/// One modality's output layer on the GPU.
#[derive(Debug)]
struct Layer {
    kernels: Arc<Kernels>,
    hidden: usize,
    dims: usize,
    has_bias: bool,
    weights: Weights,
}

/// Where a layer's weights come from.
#[derive(Debug)]
enum Weights {
    /// Uploaded for this loaded model.
    Uploaded {
        weight: PooledBuffer,
        bias: PooledBuffer,
    },
    /// A learner's, kept on the device across iterations; weight gradients go to its
    /// buffers instead of coming back.
    Resident(Arc<ResidentLayer>),
}

impl Layer {
    fn weight(&self) -> &wgpu::Buffer {
        match &self.weights {
            Weights::Uploaded { weight, .. } => weight,
            Weights::Resident(r) => &r.weight,
        }
    }

    fn bias(&self) -> &wgpu::Buffer {
        match &self.weights {
            Weights::Uploaded { bias, .. } => bias,
            Weights::Resident(r) => &r.bias,
        }
    }

    fn resident(&self) -> Option<&ResidentLayer> {
        match &self.weights {
            Weights::Uploaded { .. } => None,
            Weights::Resident(r) => Some(r),
        }
    }
}

/// The output layers of both read-outs, uploaded to a GPU.
#[derive(Debug)]
pub struct GpuOutputLayer {
    gpu: Arc<Gpu>,
    tiling: Tiling,
    layers: [Option<Layer>; 2],
}

impl GpuOutputLayer {
    /// Uploads both output layers' weights. A layer wider than the kernels hold stays on
    /// the CPU (every call for it returns `None`).
    pub fn upload(gpu: Arc<Gpu>, tiling: Tiling, params: &Params<f32>) -> Self {
        Self::with_resident(gpu, tiling, params, &[None, None])
    }

    /// [`Self::upload`], except that the layers in `resident` are a learner's, already on
    /// the device (their weights in `params` are not read).
    pub(crate) fn with_resident(
        gpu: Arc<Gpu>,
        tiling: Tiling,
        params: &Params<f32>,
        resident: &[Option<Arc<ResidentLayer>>; 2],
    ) -> Self {
        let layers = std::array::from_fn(|mi| {
            let out = &params.readouts[mi].out;
            let (dims, hidden) = (out.weight.shape()[0], out.weight.shape()[1]);
            if !fits(dims, hidden) {
                return None;
            }
            let weights = match &resident[mi] {
                Some(r) => Weights::Resident(r.clone()),
                None => {
                    let zeros = vec![0f32; dims];
                    let bias = out.bias.as_ref().map_or(zeros.as_slice(), |b| b.data());
                    Weights::Uploaded {
                        weight: gpu.upload("output weight", &pad_rows(out.weight.data(), hidden)),
                        bias: gpu.upload("output bias", bias),
                    }
                }
            };
            Some(Layer {
                kernels: gpu.kernels(tiling.row_pass(vec4s(hidden), &gpu)),
                hidden,
                dims,
                has_bias: out.bias.is_some(),
                weights,
            })
        });
        Self {
            gpu,
            tiling,
            layers,
        }
    }

    /// The targets of `key` on the device, uploaded on first use (one buffer per chunk of
    /// rows) and kept while their run goes on (`ResidentTargets`).
    fn resident_targets(
        &self,
        modality: Modality,
        key: ResidentKey,
        targets: &[&[f32]],
    ) -> Arc<Vec<wgpu::Buffer>> {
        let mut resident = self.gpu.resident.lock().unwrap_or_else(|e| e.into_inner());
        resident.get_or_upload(modality.index(), key, || {
            targets
                .chunks(key.chunk_rows)
                .map(|rows| {
                    // Long-lived (not pooled): they stay while their run uses them.
                    self.gpu.filled(
                        "resident targets",
                        &packed(rows, key.columns),
                        wgpu::BufferUsages::STORAGE,
                    )
                })
                .collect()
        })
    }

    /// What an evaluation with weight gradients records on each resident read-out for the
    /// learner's next update: the output layer's rows with a gradient and whether the
    /// hidden layers' gradients were written (`None` for a layer that is not resident).
    pub(crate) fn learner_marks(&self) -> [Option<(usize, bool)>; 2] {
        std::array::from_fn(|mi| {
            let r = self.layers[mi].as_ref()?.resident()?;
            Some((
                r.rows_with_gradient
                    .load(std::sync::atomic::Ordering::SeqCst),
                r.hidden_gradients.load(std::sync::atomic::Ordering::SeqCst),
            ))
        })
    }

    /// Records `marks` (from [`Self::learner_marks`]) again, for an evaluation replayed
    /// without encoding.
    pub(crate) fn set_learner_marks(&self, marks: [Option<(usize, bool)>; 2]) {
        for (layer, mark) in self.layers.iter().zip(marks) {
            let (Some(r), Some((rows, hidden))) = (layer.as_ref().and_then(Layer::resident), mark)
            else {
                continue;
            };
            r.gradient_rows(rows);
            if hidden {
                r.hidden_gradients_written();
            }
        }
    }

    fn chunk_limit(&self) -> usize {
        (self.gpu.limits().max_storage_buffer_binding_size as usize)
            .min(self.tiling.max_chunk_bytes)
    }

    fn layer(&self, modality: Modality) -> Option<&Layer> {
        self.layers[modality.index()].as_ref()
    }

    /// Whether a call of `outputs` output values (rows x columns) is too little work to pay
    /// for a round trip ([`Tiling::min_work`]); never for a learner's resident layer.
    fn too_small(&self, layer: &Layer, outputs: usize) -> bool {
        layer.resident().is_none() && outputs * layer.hidden < self.tiling.min_work
    }
}

/// The first `k` values of each row, contiguous.
fn packed(rows: &[&[f32]], k: usize) -> Vec<f32> {
    let mut out = Vec::with_capacity(rows.len() * k);
    for row in rows {
        out.extend_from_slice(&row[..k]);
    }
    out
}
