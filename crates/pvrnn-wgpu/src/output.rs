//! The read-outs' output layers on the GPU: weights uploaded once per loaded model, inputs
//! and targets streamed per call in chunks of rows that fit WebGPU's binding limits.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use pvrnn_core::Modality;
use pvrnn_core::backend::{OutputLayer, OutputLoss};
use pvrnn_core::params::Params;
use wgpu::util::DeviceExt;

use crate::gpu::{Gpu, Kernels, ResidentKey};

/// Columns per tile and threads per workgroup of `output_loss.wgsl`.
const TILE_COLUMNS: usize = 32;
const WORKGROUP: usize = 64;

/// How a call is cut into work: column groups (workgroups, each with its own split-K
/// partial) and chunks of rows (one submission each). Results do not depend on it beyond
/// f32 summation order; tests shrink it to run every path on small shapes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Tiling {
    /// Column groups per chunk at most: enough to fill a large GPU, few enough that the
    /// split-K partials stay small.
    pub max_groups: usize,
    /// Largest buffer a chunk binds (the device's binding limit applies too).
    pub max_chunk_bytes: usize,
}

impl Default for Tiling {
    fn default() -> Self {
        Self {
            max_groups: 256,
            // Below WebGPU's default 128 MiB per binding.
            max_chunk_bytes: 64 << 20,
        }
    }
}
/// Hidden widths the kernels' workgroup memory holds within WebGPU's default 16 KiB.
const MAX_HIDDEN: usize = 64;

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct LossParams {
    rows: u32,
    k: u32,
    tiles_per_group: u32,
    weight_grads: u32,
    scale: f32,
    row_offset: u32,
    _pad: [u32; 2],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct ReduceParams {
    rows: u32,
    groups: u32,
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
    weight: wgpu::Buffer,
    bias: wgpu::Buffer,
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
        let layers = std::array::from_fn(|mi| {
            let out = &params.readouts[mi].out;
            let (dims, hidden) = (out.weight.shape()[0], out.weight.shape()[1]);
            if hidden == 0 || hidden > MAX_HIDDEN || dims == 0 {
                return None;
            }
            let zeros = vec![0f32; dims];
            let bias = out.bias.as_ref().map_or(zeros.as_slice(), |b| b.data());
            Some(Layer {
                kernels: gpu.kernels(hidden),
                hidden,
                dims,
                has_bias: out.bias.is_some(),
                weight: storage(&gpu, "output weight", out.weight.data()),
                bias: storage(&gpu, "output bias", bias),
            })
        });
        Self {
            gpu,
            tiling,
            layers,
        }
    }

    /// The targets of `key` on the device, uploaded on first use (one buffer per chunk of
    /// rows) and kept until another run's replace them.
    fn resident_targets(
        &self,
        modality: Modality,
        key: ResidentKey,
        targets: &[&[f32]],
    ) -> Arc<Vec<wgpu::Buffer>> {
        let mut resident = self.gpu.resident.lock().unwrap_or_else(|e| e.into_inner());
        let slot = &mut resident[modality.index()];
        if let Some((k, chunks)) = slot.as_ref()
            && *k == key
        {
            return chunks.clone();
        }
        // Free the old run's targets before allocating the new ones.
        *slot = None;
        let chunks: Vec<wgpu::Buffer> = targets
            .chunks(key.chunk_rows)
            .map(|rows| storage(&self.gpu, "resident targets", &packed(rows, key.columns)))
            .collect();
        let chunks = Arc::new(chunks);
        *slot = Some((key, chunks.clone()));
        chunks
    }

    fn chunk_limit(&self) -> usize {
        (self.gpu.limits().max_storage_buffer_binding_size as usize)
            .min(self.tiling.max_chunk_bytes)
    }

    fn layer(&self, modality: Modality) -> Option<&Layer> {
        self.layers[modality.index()].as_ref()
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

fn storage(gpu: &Gpu, label: &str, data: &[f32]) -> wgpu::Buffer {
    // A binding may not be empty.
    let data: &[f32] = if data.is_empty() { &[0.0] } else { data };
    gpu.device
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents: bytemuck::cast_slice(data),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        })
}

fn uniform<P: Pod>(gpu: &Gpu, params: &P) -> wgpu::Buffer {
    gpu.device
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("params"),
            contents: bytemuck::bytes_of(params),
            usage: wgpu::BufferUsages::UNIFORM,
        })
}

fn zeroed(gpu: &Gpu, label: &str, floats: usize, extra: wgpu::BufferUsages) -> wgpu::Buffer {
    gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: (floats.max(1) * 4) as u64,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST | extra,
        mapped_at_creation: false,
    })
}

fn bind(gpu: &Gpu, pipeline: &wgpu::ComputePipeline, buffers: &[&wgpu::Buffer]) -> wgpu::BindGroup {
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

fn dispatch(
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

/// Copies `sources` (each `floats` long) into one mappable buffer, waits, and reads them.
fn read_back(
    gpu: &Gpu,
    mut encoder: wgpu::CommandEncoder,
    sources: &[(&wgpu::Buffer, usize)],
) -> Vec<Vec<f32>> {
    let total: usize = sources.iter().map(|&(_, n)| n).sum();
    let staging = gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("read back"),
        size: (total.max(1) * 4) as u64,
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut offset = 0;
    for &(buffer, n) in sources {
        if n > 0 {
            encoder.copy_buffer_to_buffer(buffer, 0, &staging, (offset * 4) as u64, (n * 4) as u64);
        }
        offset += n;
    }
    gpu.queue.submit([encoder.finish()]);
    let slice = staging.slice(..);
    slice.map_async(wgpu::MapMode::Read, |r| {
        if let Err(e) = r {
            panic!("reading results back from the GPU failed: {e}");
        }
    });
    if let Err(e) = gpu.device.poll(wgpu::PollType::wait_indefinitely()) {
        panic!("waiting for the GPU failed: {e}");
    }
    let view = match slice.get_mapped_range() {
        Ok(v) => v,
        Err(e) => panic!("reading results back from the GPU failed: {e}"),
    };
    let all: &[f32] = bytemuck::cast_slice(&view);
    let mut out = Vec::with_capacity(sources.len());
    let mut offset = 0;
    for &(_, n) in sources {
        out.push(all[offset..offset + n].to_vec());
        offset += n;
    }
    out
}

impl OutputLayer<f32> for GpuOutputLayer {
    fn loss(
        &self,
        modality: Modality,
        input: &[f32],
        n: usize,
        k: usize,
        divisor: usize,
        targets: &[&[f32]],
        resident: Option<u64>,
        weight_grads: bool,
    ) -> Option<OutputLoss<f32>> {
        let layer = self.layer(modality)?;
        if n == 0 || k == 0 {
            return None;
        }
        let gpu = &*self.gpu;
        let hl = layer.hidden;
        let limit = self.chunk_limit();
        let tiles = k.div_ceil(TILE_COLUMNS);
        let tiles_per_group = tiles.div_ceil(self.tiling.max_groups.max(1));
        let groups = tiles.div_ceil(tiles_per_group);
        // Rows per chunk: the chunk's targets and its split-K partials each fit one binding.
        let chunk = (limit / (4 * k.max(groups * hl)))
            .max(1)
            .min(n)
            .min(gpu.limits().max_compute_workgroups_per_dimension as usize);

        let x = storage(gpu, "hidden", input);
        let resident = resident.map(|observations| {
            let key = ResidentKey {
                observations,
                rows: n,
                columns: k,
                chunk_rows: chunk,
            };
            self.resident_targets(modality, key, targets)
        });
        // Without resident targets, one buffer refilled for every chunk.
        let streamed = resident
            .is_none()
            .then(|| zeroed(gpu, "targets", chunk * k, wgpu::BufferUsages::empty()));
        let part_in = zeroed(
            gpu,
            "partial d input",
            groups * chunk * hl,
            wgpu::BufferUsages::empty(),
        );
        let part_loss = zeroed(
            gpu,
            "partial loss",
            groups * chunk,
            wgpu::BufferUsages::empty(),
        );
        let wg_floats = if weight_grads { k * hl } else { 1 };
        let gw = zeroed(gpu, "d W", wg_floats, wgpu::BufferUsages::COPY_SRC);
        let gb = zeroed(
            gpu,
            "d b",
            if weight_grads { k } else { 1 },
            wgpu::BufferUsages::COPY_SRC,
        );
        let grad_in = zeroed(gpu, "d input", n * hl, wgpu::BufferUsages::COPY_SRC);
        let row_loss = zeroed(gpu, "row loss", n, wgpu::BufferUsages::COPY_SRC);

        let mut start = 0;
        while start < n {
            let rows = chunk.min(n - start);
            let y = match (&resident, &streamed) {
                (Some(chunks), _) => &chunks[start / chunk],
                (None, Some(buffer)) => {
                    gpu.queue.write_buffer(
                        buffer,
                        0,
                        bytemuck::cast_slice(&packed(&targets[start..start + rows], k)),
                    );
                    buffer
                }
                (None, None) => unreachable!("targets are resident or streamed"),
            };
            let loss_params = uniform(
                gpu,
                &LossParams {
                    rows: rows as u32,
                    k: k as u32,
                    tiles_per_group: tiles_per_group as u32,
                    weight_grads: weight_grads as u32,
                    scale: (1.0 / divisor as f64) as f32,
                    row_offset: start as u32,
                    _pad: [0; 2],
                },
            );
            let reduce_params = uniform(
                gpu,
                &ReduceParams {
                    rows: rows as u32,
                    groups: groups as u32,
                    row_offset: start as u32,
                    _pad: 0,
                },
            );
            let loss_group = bind(
                gpu,
                &layer.kernels.output_loss,
                &[
                    &loss_params,
                    &x,
                    &layer.weight,
                    &layer.bias,
                    y,
                    &part_in,
                    &part_loss,
                    &gw,
                    &gb,
                ],
            );
            let reduce_group = bind(
                gpu,
                &layer.kernels.reduce,
                &[&reduce_params, &part_in, &part_loss, &grad_in, &row_loss],
            );
            let mut encoder = gpu.device.create_command_encoder(&Default::default());
            encoder.clear_buffer(&part_in, 0, None);
            encoder.clear_buffer(&part_loss, 0, None);
            dispatch(
                &mut encoder,
                &layer.kernels.output_loss,
                &loss_group,
                groups as u32,
                1,
            );
            let reduce_groups = (rows * hl).div_ceil(WORKGROUP) as u32;
            dispatch(
                &mut encoder,
                &layer.kernels.reduce,
                &reduce_group,
                reduce_groups,
                1,
            );
            gpu.queue.submit([encoder.finish()]);
            start += rows;
        }

        let encoder = gpu.device.create_command_encoder(&Default::default());
        let mut sources = vec![(&grad_in, n * hl), (&row_loss, n)];
        if weight_grads {
            sources.push((&gw, k * hl));
            sources.push((&gb, k));
        }
        let mut results = read_back(gpu, encoder, &sources).into_iter();
        let grad_in = results.next().unwrap_or_default();
        let half_over_divisor = 0.5 / divisor as f64;
        let row_loss = results
            .next()
            .unwrap_or_default()
            .into_iter()
            .map(|s| s as f64 * half_over_divisor)
            .collect();
        let grad_w = results.next();
        let grad_b = results.next().filter(|_| layer.has_bias);
        Some(OutputLoss {
            row_loss,
            grad_in,
            grad_w,
            grad_b,
        })
    }

    fn predict(&self, modality: Modality, input: &[f32], n: usize) -> Option<Vec<f32>> {
        let layer = self.layer(modality)?;
        if n == 0 {
            return Some(Vec::new());
        }
        let gpu = &*self.gpu;
        let (hl, dims) = (layer.hidden, layer.dims);
        let limit = self.chunk_limit();
        let chunk = (limit / (4 * dims))
            .max(1)
            .min(n)
            .min(gpu.limits().max_compute_workgroups_per_dimension as usize);
        let mut prediction = Vec::with_capacity(n * dims);
        let mut start = 0;
        while start < n {
            let rows = chunk.min(n - start);
            let x = storage(gpu, "hidden", &input[start * hl..(start + rows) * hl]);
            let out = zeroed(gpu, "prediction", rows * dims, wgpu::BufferUsages::COPY_SRC);
            let params = uniform(
                gpu,
                &PredictParams {
                    rows: rows as u32,
                    dims: dims as u32,
                    _pad: [0; 2],
                },
            );
            let group = bind(
                gpu,
                &layer.kernels.predict,
                &[&params, &x, &layer.weight, &layer.bias, &out],
            );
            let mut encoder = gpu.device.create_command_encoder(&Default::default());
            dispatch(
                &mut encoder,
                &layer.kernels.predict,
                &group,
                dims.div_ceil(WORKGROUP) as u32,
                rows as u32,
            );
            let part = read_back(gpu, encoder, &[(&out, rows * dims)]);
            prediction.extend(part.into_iter().flatten());
            start += rows;
        }
        Some(prediction)
    }
}
