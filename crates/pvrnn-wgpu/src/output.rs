//! The read-outs' output layers on the GPU: weights uploaded once per loaded model, inputs
//! and targets streamed per call in chunks of rows that fit WebGPU's binding limits.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use pvrnn_core::Modality;
use pvrnn_core::backend::{OutputLayer, OutputLoss};
use pvrnn_core::deferred::Deferred;
use pvrnn_core::params::Params;
use wgpu::util::DeviceExt;

use crate::gpu::{Gpu, Kernels, ResidentKey};
use crate::learner::ResidentLayer;
use crate::pool::PooledBuffer;
use crate::readback::read_back;

/// Threads per workgroup of every kernel; rows per workgroup of `loss_rows.wgsl`, columns
/// per workgroup of `loss_columns.wgsl`.
const WORKGROUP: usize = 64;
/// Columns per tile of `loss_rows.wgsl` (its splits are whole tiles).
const TILE_COLUMNS: usize = 32;
/// Rows per workgroup of `predict.wgsl`.
const PREDICT_ROWS: usize = 4;

/// How a call is cut into work: column splits of the row pass (each with its own split-K
/// partial) and chunks of rows (each binding at most `max_chunk_bytes`). Results do not
/// depend on it beyond f32 summation order; tests shrink it to run every path on small
/// shapes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Tiling {
    /// Workgroups the row pass aims for per chunk: enough to fill a large GPU (the rows
    /// alone give 85 workgroups of 64 at the paper's 5,400), few enough that the split-K
    /// partials stay small.
    pub target_workgroups: usize,
    /// At most this many column splits: the reduce pass adds a row's partials one after
    /// another, so with few rows (online inference's 30, which would otherwise get one
    /// split per 32-column tile: 1,008) it becomes the slow part, and with too few the row
    /// pass runs out of parallelism. 256 was the fastest cap for inference's window on an
    /// H200 and leaves learning's paper-scale chunks (112 splits) as they were
    /// (docs/gpu.md has the measurements).
    pub max_splits: usize,
    /// Largest buffer a chunk binds (the device's binding limit applies too).
    pub max_chunk_bytes: usize,
}

impl Default for Tiling {
    fn default() -> Self {
        Self {
            target_workgroups: 1024,
            max_splits: 256,
            // Below WebGPU's default 128 MiB per binding.
            max_chunk_bytes: 64 << 20,
        }
    }
}
/// Hidden widths whose registers (two rows of width/4 vec4s per thread) the kernels are
/// written for.
const MAX_HIDDEN: usize = 64;

/// Hidden width in vec4s: rows of weights and activations are zero-padded to it.
pub(crate) fn vec4s(hidden: usize) -> usize {
    hidden.div_ceil(4)
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct RowsParams {
    rows: u32,
    k: u32,
    cols_per_split: u32,
    scale: f32,
    row_offset: u32,
    _pad: [u32; 3],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct ColumnsParams {
    rows: u32,
    k: u32,
    scale: f32,
    row_offset: u32,
    accumulate: u32,
    _pad: [u32; 3],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct ReduceParams {
    rows: u32,
    splits: u32,
    row_offset: u32,
    _pad: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct PredictParams {
    rows: u32,
    dims: u32,
    _pad: [u32; 2],
}

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
                kernels: gpu.kernels(vec4s(hidden)),
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
                    self.gpu
                        .device
                        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                            label: Some("resident targets"),
                            contents: bytemuck::cast_slice(&packed(rows, key.columns)),
                            usage: wgpu::BufferUsages::STORAGE,
                        })
                })
                .collect()
        })
    }

    fn chunk_limit(&self) -> usize {
        (self.gpu.limits().max_storage_buffer_binding_size as usize)
            .min(self.tiling.max_chunk_bytes)
    }

    fn layer(&self, modality: Modality) -> Option<&Layer> {
        self.layers[modality.index()].as_ref()
    }
}

/// Whether the kernels hold an output layer of this shape.
pub(crate) fn fits(dims: usize, hidden: usize) -> bool {
    hidden > 0 && hidden <= MAX_HIDDEN && dims > 0
}

/// The first `k` values of each row, contiguous.
fn packed(rows: &[&[f32]], k: usize) -> Vec<f32> {
    let mut out = Vec::with_capacity(rows.len() * k);
    for row in rows {
        out.extend_from_slice(&row[..k]);
    }
    out
}

/// Rows of `width` values zero-padded to whole vec4s (the kernels' layout).
pub(crate) fn pad_rows(data: &[f32], width: usize) -> Vec<f32> {
    let padded = 4 * vec4s(width);
    let mut out = vec![0f32; data.len() / width.max(1) * padded];
    for (src, dst) in data.chunks_exact(width).zip(out.chunks_exact_mut(padded)) {
        dst[..width].copy_from_slice(src);
    }
    out
}

/// The inverse of [`pad_rows`].
pub(crate) fn unpad_rows(data: &[f32], width: usize) -> Vec<f32> {
    let padded = 4 * vec4s(width);
    let mut out = Vec::with_capacity(data.len() / padded * width);
    for row in data.chunks_exact(padded) {
        out.extend_from_slice(&row[..width]);
    }
    out
}

pub(crate) fn bind(
    gpu: &Gpu,
    pipeline: &wgpu::ComputePipeline,
    buffers: &[&wgpu::Buffer],
) -> wgpu::BindGroup {
    let entries: Vec<wgpu::BindGroupEntry<'_>> = buffers
        .iter()
        .enumerate()
        .map(|(i, b)| wgpu::BindGroupEntry {
            binding: i as u32,
            resource: b.as_entire_binding(),
        })
        .collect();
    gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: None,
        layout: &pipeline.get_bind_group_layout(0),
        entries: &entries,
    })
}

pub(crate) fn dispatch(
    encoder: &mut wgpu::CommandEncoder,
    pipeline: &wgpu::ComputePipeline,
    group: &wgpu::BindGroup,
    x: u32,
    y: u32,
) {
    let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor::default());
    pass.set_pipeline(pipeline);
    pass.set_bind_group(0, group, &[]);
    pass.dispatch_workgroups(x, y, 1);
}

impl OutputLayer<f32> for GpuOutputLayer {
    fn loss<'a>(
        &'a self,
        modality: Modality,
        input: &[f32],
        n: usize,
        k: usize,
        divisor: usize,
        targets: &[&[f32]],
        resident: Option<u64>,
        weight_grads: bool,
    ) -> Option<Deferred<'a, OutputLoss<f32>>> {
        let layer = self.layer(modality)?;
        if n == 0 || k == 0 {
            return None;
        }
        let gpu = &*self.gpu;
        let (hl, hv) = (layer.hidden, vec4s(layer.hidden));
        let limit = self.chunk_limit();
        let max_groups = gpu.limits().max_compute_workgroups_per_dimension as usize;
        // Rows per chunk: the chunk's targets fit one binding.
        let chunk = (limit / (4 * k)).max(1).min(n);
        // Column splits: enough workgroups to fill the GPU, partials within one binding.
        let tiles = k.div_ceil(TILE_COLUMNS);
        let row_blocks = chunk.div_ceil(WORKGROUP);
        let splits = self
            .tiling
            .target_workgroups
            .div_ceil(row_blocks)
            .min(limit / (16 * hv * chunk))
            .min(max_groups)
            .min(self.tiling.max_splits)
            .clamp(1, tiles);
        let cols_per_split = tiles.div_ceil(splits) * TILE_COLUMNS;
        let splits = k.div_ceil(cols_per_split);
        let scale = (1.0 / divisor as f64) as f32;

        let encode_phase = pvrnn_core::profile::phase("    GPU: upload and encode");
        let x = gpu.upload("hidden", &pad_rows(input, hl));
        let resident = resident.map(|observations| {
            let key = ResidentKey {
                observations,
                rows: n,
                columns: k,
                chunk_rows: chunk,
            };
            self.resident_targets(modality, key, targets)
        });
        // Every element the read-back returns is written by a kernel first.
        let part_in = gpu.scratch(
            "partial d input",
            splits * chunk * 4 * hv,
            wgpu::BufferUsages::empty(),
        );
        let part_loss = gpu.scratch("partial loss", splits * chunk, wgpu::BufferUsages::empty());
        // A learner's layer keeps its weight gradients for its update; others read them back.
        let learner = layer.resident().filter(|_| weight_grads);
        let read_grads = weight_grads && learner.is_none();
        let gw_scratch = gpu.scratch(
            "d W",
            if read_grads { k * 4 * hv } else { 1 },
            wgpu::BufferUsages::COPY_SRC,
        );
        let gb_scratch = gpu.scratch(
            "d b",
            if read_grads { k } else { 1 },
            wgpu::BufferUsages::COPY_SRC,
        );
        let (gw, gb): (&wgpu::Buffer, &wgpu::Buffer) = match learner {
            Some(r) => {
                r.gradient_rows(k);
                (&r.grad_w, &r.grad_b)
            }
            None => (&gw_scratch, &gb_scratch),
        };
        let grad_in = gpu.scratch("d input", n * 4 * hv, wgpu::BufferUsages::COPY_SRC);
        let row_loss = gpu.scratch("row loss", n, wgpu::BufferUsages::COPY_SRC);

        // Every chunk in one submission; streamed targets and parameters get buffers per
        // chunk, written before the submission runs and kept from the pool until it has.
        let mut in_flight: Vec<PooledBuffer> = Vec::new();
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        let mut start = 0;
        while start < n {
            let rows = chunk.min(n - start);
            let streamed = resident
                .is_none()
                .then(|| gpu.upload("targets", &packed(&targets[start..start + rows], k)));
            let y: &wgpu::Buffer = match (&resident, &streamed) {
                (Some(chunks), _) => &chunks[start / chunk],
                (None, Some(buffer)) => buffer,
                (None, None) => unreachable!("targets are resident or streamed"),
            };
            let rows_params = gpu.uniform(&RowsParams {
                rows: rows as u32,
                k: k as u32,
                cols_per_split: cols_per_split as u32,
                scale,
                row_offset: start as u32,
                _pad: [0; 3],
            });
            let rows_group = bind(
                gpu,
                &layer.kernels.loss_rows,
                &[
                    &rows_params,
                    &x,
                    layer.weight(),
                    layer.bias(),
                    y,
                    &part_in,
                    &part_loss,
                ],
            );
            dispatch(
                &mut encoder,
                &layer.kernels.loss_rows,
                &rows_group,
                rows.div_ceil(WORKGROUP) as u32,
                splits as u32,
            );
            let reduce_params = gpu.uniform(&ReduceParams {
                rows: rows as u32,
                splits: splits as u32,
                row_offset: start as u32,
                _pad: 0,
            });
            let reduce_group = bind(
                gpu,
                &layer.kernels.reduce,
                &[&reduce_params, &part_in, &part_loss, &grad_in, &row_loss],
            );
            dispatch(
                &mut encoder,
                &layer.kernels.reduce,
                &reduce_group,
                (rows * hv).div_ceil(WORKGROUP) as u32,
                1,
            );
            if weight_grads {
                let columns_params = gpu.uniform(&ColumnsParams {
                    rows: rows as u32,
                    k: k as u32,
                    scale,
                    row_offset: start as u32,
                    accumulate: (start > 0) as u32,
                    _pad: [0; 3],
                });
                let columns_group = bind(
                    gpu,
                    &layer.kernels.loss_columns,
                    &[&columns_params, &x, layer.weight(), layer.bias(), y, gw, gb],
                );
                dispatch(
                    &mut encoder,
                    &layer.kernels.loss_columns,
                    &columns_group,
                    k.div_ceil(WORKGROUP) as u32,
                    1,
                );
                in_flight.push(columns_params);
            }
            in_flight.extend(streamed);
            in_flight.push(rows_params);
            in_flight.push(reduce_params);
            start += rows;
        }

        let mut sources: Vec<(&wgpu::Buffer, usize)> = vec![(&grad_in, n * 4 * hv), (&row_loss, n)];
        if read_grads {
            sources.push((gw, k * 4 * hv));
            sources.push((gb, k));
        }
        let pending = read_back(gpu, encoder, &sources);
        drop(encode_phase);
        let (has_bias, half_over_divisor) = (layer.has_bias, 0.5 / divisor as f64);
        // The buffers the submission uses stay out of the pool until it has run.
        let used = (
            in_flight, x, part_in, part_loss, gw_scratch, gb_scratch, grad_in, row_loss, resident,
        );
        Some(Box::pin(async move {
            let wait_phase = pvrnn_core::profile::phase("    GPU: run and read back");
            let mut results = pending.await.into_iter();
            drop(used);
            drop(wait_phase);
            let grad_in = unpad_rows(&results.next().unwrap_or_default(), hl);
            let row_loss = results
                .next()
                .unwrap_or_default()
                .into_iter()
                .map(|s| s as f64 * half_over_divisor)
                .collect();
            let grad_w = results.next().map(|g| unpad_rows(&g, hl));
            let grad_b = results.next().filter(|_| has_bias);
            OutputLoss {
                row_loss,
                grad_in,
                grad_w,
                grad_b,
            }
        }))
    }

    fn predict<'a>(
        &'a self,
        modality: Modality,
        input: &[f32],
        n: usize,
    ) -> Option<Deferred<'a, Vec<f32>>> {
        let layer = self.layer(modality)?;
        if n == 0 {
            return Some(pvrnn_core::deferred::ready(Vec::new()));
        }
        let gpu = &*self.gpu;
        let (hl, dims) = (layer.hidden, layer.dims);
        let limit = self.chunk_limit();
        let chunk = (limit / (4 * dims))
            .max(1)
            .min(n)
            .min(PREDICT_ROWS * gpu.limits().max_compute_workgroups_per_dimension as usize);
        let input = pad_rows(input, hl);
        let padded = input.len() / n;
        Some(Box::pin(async move {
            let mut prediction = Vec::with_capacity(n * dims);
            let mut start = 0;
            while start < n {
                let rows = chunk.min(n - start);
                let x = gpu.upload("hidden", &input[start * padded..(start + rows) * padded]);
                let out = gpu.scratch("prediction", rows * dims, wgpu::BufferUsages::COPY_SRC);
                let params = gpu.uniform(&PredictParams {
                    rows: rows as u32,
                    dims: dims as u32,
                    _pad: [0; 2],
                });
                let group = bind(
                    gpu,
                    &layer.kernels.predict,
                    &[&params, &x, layer.weight(), layer.bias(), &out],
                );
                let mut encoder = gpu.device.create_command_encoder(&Default::default());
                dispatch(
                    &mut encoder,
                    &layer.kernels.predict,
                    &group,
                    dims.div_ceil(WORKGROUP) as u32,
                    rows.div_ceil(PREDICT_ROWS) as u32,
                );
                let part = read_back(gpu, encoder, &[(&out, rows * dims)]).await;
                prediction.extend(part.into_iter().flatten());
                start += rows;
            }
            prediction
        }))
    }
}
