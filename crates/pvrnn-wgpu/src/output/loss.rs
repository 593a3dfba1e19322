//! The output layer's loss encoded for a call, chunk by chunk: the targets resident or
//! streamed, the row pass (fused, or the blocked kernels' first two products), the splits'
//! partials reduced, and the weight gradients (the fused column pass, or the blocked third
//! product).

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use pvrnn_core::Modality;

use crate::encode::{Recorder, WORKGROUP, bind, dispatch, vec4s};
use crate::gpu::ResidentKey;
use crate::pool::PooledBuffer;

use super::cut::{BlockedScratch, ChunkRows, LossBuffers, LossCut};
use super::{GpuOutputLayer, Layer, packed};

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

/// The output layer's loss encoded on the device (see [`GpuOutputLayer::encode_loss`]): the
/// buffers that hold its results, and those the submission uses until it has run.
pub(super) struct EncodedLoss {
    /// d F / d input, `[n, 4 hv]` (padded rows), and the row losses, `[n]` (sums of squared
    /// errors times 1 / divisor).
    pub(super) grad_in: PooledBuffer,
    pub(super) row_loss: PooledBuffer,
    /// d W `[k, 4 hv]` and d b `[k]`, when they are to be read back.
    pub(super) grads: Option<(PooledBuffer, PooledBuffer)>,
    pub(super) in_flight: Vec<PooledBuffer>,
    pub(super) resident_targets: Option<Arc<Vec<wgpu::Buffer>>>,
}

impl GpuOutputLayer {
    /// Encodes the fused loss of `layer` for `n` rows of top hidden activations in `x`
    /// (`[n, 4 hv]`, padded rows), with the weight gradients when `weight_grads` (into a
    /// learner's buffers if the layer is resident, else into buffers to read back).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn encode_loss(
        &self,
        encoder: &mut dyn Recorder,
        layer: &Layer,
        modality: Modality,
        x: &wgpu::Buffer,
        n: usize,
        k: usize,
        divisor: usize,
        targets: &[&[f32]],
        resident: Option<u64>,
        weight_grads: bool,
    ) -> EncodedLoss {
        let gpu = &*self.gpu;
        let hv = vec4s(layer.hidden);
        let cut = self.loss_cut(n, k, hv);
        let chunk = cut.chunk;
        let splits = cut.splits;
        let scale = (1.0 / divisor as f64) as f32;

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
        let grads = (weight_grads && learner.is_none()).then(|| {
            (
                gpu.scratch("d W", k * 4 * hv, wgpu::BufferUsages::COPY_SRC),
                gpu.scratch("d b", k, wgpu::BufferUsages::COPY_SRC),
            )
        });
        let (gw, gb): (&wgpu::Buffer, &wgpu::Buffer) = match (learner, &grads) {
            (Some(r), _) => {
                r.gradient_rows(k);
                (&r.grad_w, &r.grad_b)
            }
            (None, Some((gw, gb))) => (gw, gb),
            // No weight gradients: the column pass does not run.
            (None, None) => (&part_in, &part_loss),
        };
        let grad_in = gpu.scratch("d input", n * 4 * hv, wgpu::BufferUsages::COPY_SRC);
        let row_loss = gpu.scratch("row loss", n, wgpu::BufferUsages::COPY_SRC);
        let blocked = self.blocked_scratch(cut, k, hv, weight_grads);

        // Every chunk in one submission; streamed targets and parameters get buffers per
        // chunk, written before the submission runs and kept from the pool until it has.
        let mut in_flight: Vec<PooledBuffer> = Vec::new();
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
            let buffers = LossBuffers {
                x,
                y,
                part_in: &part_in,
                part_loss: &part_loss,
                grad_in: &grad_in,
                row_loss: &row_loss,
                gw,
                gb,
                blocked: blocked.as_ref(),
            };
            let chunk_rows = ChunkRows {
                start,
                rows,
                k,
                scale,
            };
            let params =
                self.encode_loss_chunk(encoder, layer, &buffers, chunk_rows, cut, weight_grads);
            in_flight.extend(streamed);
            in_flight.extend(params);
            start += rows;
        }
        in_flight.push(part_in);
        in_flight.push(part_loss);
        if let Some(BlockedScratch { g, part_w }) = blocked {
            in_flight.push(g);
            in_flight.extend(part_w.into_iter().flat_map(|(w, b)| [w, b]));
        }
        EncodedLoss {
            grad_in,
            row_loss,
            grads,
            in_flight,
            resident_targets: resident,
        }
    }

    /// One chunk of rows of a loss call: the row pass (forward, error, partial d input),
    /// its reduction, and with `weight_grads` the column pass. Returns the chunk's parameter buffers, to keep until the submission has run.
    #[allow(clippy::too_many_arguments)]
    fn encode_loss_chunk(
        &self,
        encoder: &mut dyn Recorder,
        layer: &Layer,
        b: &LossBuffers<'_>,
        chunk: ChunkRows,
        cut: LossCut,
        weight_grads: bool,
    ) -> Vec<PooledBuffer> {
        let gpu = &*self.gpu;
        let hv = vec4s(layer.hidden);
        let ChunkRows {
            start,
            rows,
            k,
            scale,
        } = chunk;
        let mut params = Vec::new();
        let rows_params = gpu.uniform(&RowsParams {
            rows: rows as u32,
            k: k as u32,
            cols_per_split: cut.cols_per_split as u32,
            scale,
            row_offset: start as u32,
            _pad: [0; 3],
        });
        match b.blocked {
            None => {
                let group = bind(
                    gpu,
                    &layer.kernels.loss_rows,
                    &[
                        &rows_params,
                        b.x,
                        layer.weight(),
                        layer.bias(),
                        b.y,
                        b.part_in,
                        b.part_loss,
                    ],
                );
                let row_blocks = rows.div_ceil(layer.kernels.row_pass_rows) as u32;
                let kernel = &layer.kernels.loss_rows;
                dispatch(encoder, kernel, &group, row_blocks, cut.splits as u32);
            }
            Some(scratch) => {
                let input_params =
                    self.encode_blocked_rows(encoder, layer, b, scratch, &rows_params, chunk, cut);
                params.push(input_params);
            }
        }
        let reduce_params = gpu.uniform(&ReduceParams {
            rows: rows as u32,
            splits: cut.splits as u32,
            row_offset: start as u32,
            _pad: 0,
        });
        let reduce_group = bind(
            gpu,
            &layer.kernels.reduce,
            &[
                &reduce_params,
                b.part_in,
                b.part_loss,
                b.grad_in,
                b.row_loss,
            ],
        );
        dispatch(
            encoder,
            &layer.kernels.reduce,
            &reduce_group,
            (rows * hv).div_ceil(WORKGROUP) as u32,
            1,
        );
        if weight_grads {
            match b.blocked {
                None => params.push(self.encode_columns(encoder, layer, b, chunk)),
                Some(scratch) => {
                    params.extend(self.encode_blocked_weights(encoder, layer, b, scratch, chunk));
                }
            }
        }
        params.push(rows_params);
        params.push(reduce_params);
        params
    }

    /// `loss_columns.wgsl` for one chunk: d W and d b, the forward product recomputed.
    /// Returns its parameters, to keep until the submission has run.
    fn encode_columns(
        &self,
        encoder: &mut dyn Recorder,
        layer: &Layer,
        b: &LossBuffers<'_>,
        chunk: ChunkRows,
    ) -> PooledBuffer {
        let gpu = &*self.gpu;
        let columns_params = gpu.uniform(&ColumnsParams {
            rows: chunk.rows as u32,
            k: chunk.k as u32,
            scale: chunk.scale,
            row_offset: chunk.start as u32,
            accumulate: (chunk.start > 0) as u32,
            _pad: [0; 3],
        });
        let columns_group = bind(
            gpu,
            &layer.kernels.loss_columns,
            &[
                &columns_params,
                b.x,
                layer.weight(),
                layer.bias(),
                b.y,
                b.gw,
                b.gb,
            ],
        );
        dispatch(
            encoder,
            &layer.kernels.loss_columns,
            &columns_group,
            chunk.k.div_ceil(WORKGROUP) as u32,
            1,
        );
        columns_params
    }
}
