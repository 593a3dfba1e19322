//! `OutputKernels::Blocked` for one chunk of rows: the forward product with the error
//! gradient written out, the input gradient's partials from it, and the weight gradient's
//! partials per range of rows added into the layer's.

use bytemuck::{Pod, Zeroable};

use crate::encode::{Recorder, bind, dispatch, grid, vec4s};
use crate::gpu::BlockedDepth;
use crate::pool::PooledBuffer;

use super::cut::{BlockedScratch, ChunkRows, LossBuffers, LossCut};
use super::tiling::BLOCKED_TILE;
use super::{GpuOutputLayer, Layer};

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct BlockedInputParams {
    rows: u32,
    k: u32,
    cols_per_split: u32,
    _pad: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct BlockedWeightParams {
    rows: u32,
    k: u32,
    rows_per_split: u32,
    row_offset: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct BlockedReduceParams {
    k: u32,
    splits: u32,
    accumulate: u32,
    _pad: u32,
}

impl GpuOutputLayer {
    /// The blocked kernels of `layer`'s width at the depth the tiling asks for, for rows of
    /// `k` observed columns (read as vec4s where `k` is a multiple of 4 and the tiling
    /// allows it).
    fn blocked_kernels<'l>(&self, layer: &'l Layer, k: usize) -> &'l crate::gpu::BlockedKernels {
        let depth = self.tiling.blocked_depth.unwrap_or(BlockedDepth::Deep);
        let vector_io = self.tiling.vector_io && k.is_multiple_of(4);
        self.gpu
            .blocked_kernels(&layer.kernels, depth, layer.hidden, vector_io)
    }

    /// `OutputKernels::Blocked`'s first two products for one chunk: the forward product
    /// with the error gradient written to `scratch.g` and the row losses' partials, then
    /// the input gradient's partials from it (both per column split, as `loss_rows.wgsl`'s).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn encode_blocked_rows(
        &self,
        encoder: &mut dyn Recorder,
        layer: &Layer,
        b: &LossBuffers<'_>,
        scratch: &BlockedScratch,
        rows_params: &wgpu::Buffer,
        chunk: ChunkRows,
        cut: LossCut,
    ) -> PooledBuffer {
        let gpu = &*self.gpu;
        let kernels = self.blocked_kernels(layer, chunk.k);
        let splits = cut.splits as u32;
        let forward = bind(
            gpu,
            &kernels.forward,
            &[
                rows_params,
                b.x,
                layer.weight(),
                layer.bias(),
                b.y,
                &scratch.g,
                b.part_loss,
            ],
        );
        let row_blocks = chunk.rows.div_ceil(BLOCKED_TILE) as u32;
        dispatch(encoder, &kernels.forward, &forward, row_blocks, splits);
        let input_params = gpu.uniform(&BlockedInputParams {
            rows: chunk.rows as u32,
            k: chunk.k as u32,
            cols_per_split: cut.cols_per_split as u32,
            _pad: 0,
        });
        let input = bind(
            gpu,
            &kernels.input_grad,
            &[&input_params, layer.weight(), &scratch.g, b.part_in],
        );
        let row_blocks = chunk.rows.div_ceil(BLOCKED_TILE) as u32;
        dispatch(encoder, &kernels.input_grad, &input, row_blocks, splits);
        input_params
    }

    /// `OutputKernels::Blocked`'s third product for one chunk: d W and d b from the error
    /// gradient, per range of rows, then the ranges added into `b.gw`, `b.gb` (after the
    /// earlier chunks'). Returns the parameters, to keep until the submission has run.
    pub(super) fn encode_blocked_weights(
        &self,
        encoder: &mut dyn Recorder,
        layer: &Layer,
        b: &LossBuffers<'_>,
        scratch: &BlockedScratch,
        chunk: ChunkRows,
    ) -> [PooledBuffer; 2] {
        let gpu = &*self.gpu;
        let kernels = self.blocked_kernels(layer, chunk.k);
        let hv = vec4s(layer.hidden);
        let Some((part_w, part_b)) = &scratch.part_w else {
            unreachable!("weight gradients asked for: their partials were made")
        };
        let (splits, rows_per_split) = self.weight_cut(chunk.rows, chunk.k, hv);
        let weight_params = gpu.uniform(&BlockedWeightParams {
            rows: chunk.rows as u32,
            k: chunk.k as u32,
            rows_per_split: rows_per_split as u32,
            row_offset: chunk.start as u32,
        });
        let weights = bind(
            gpu,
            &kernels.weight_grad,
            &[&weight_params, b.x, &scratch.g, part_w, part_b],
        );
        let column_blocks = chunk.k.div_ceil(BLOCKED_TILE) as u32;
        let reduce_params = gpu.uniform(&BlockedReduceParams {
            k: chunk.k as u32,
            splits: splits as u32,
            accumulate: (chunk.start > 0) as u32,
            _pad: 0,
        });
        let reduce = bind(
            gpu,
            &kernels.weight_reduce,
            &[&reduce_params, part_w, part_b, b.gw, b.gb],
        );
        let (groups_x, groups_y) = grid(gpu, chunk.k * hv);
        let (product, splits) = (&kernels.weight_grad, splits as u32);
        dispatch(encoder, product, &weights, column_blocks, splits);
        let sum = &kernels.weight_reduce;
        dispatch(encoder, sum, &reduce, groups_x, groups_y);
        [weight_params, reduce_params]
    }
}
