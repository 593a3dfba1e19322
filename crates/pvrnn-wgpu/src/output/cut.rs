//! How a loss call is cut: chunks of rows whose targets and partials fit one binding, column
//! splits (row ranges for the blocked weight gradient) that fill the GPU, and the buffers
//! and scratch a chunk reads and writes.

use crate::pool::PooledBuffer;

use super::GpuOutputLayer;
use super::tiling::{BLOCKED_TILE, BLOCKED_WEIGHT_ROWS, OutputKernels, TILE_COLUMNS};

/// How a loss call is cut into chunks of rows and column splits (see
/// [`GpuOutputLayer::encode_loss`]).
#[derive(Clone, Copy, Debug)]
pub(super) struct LossCut {
    /// `Fused` or `Blocked` (the tiling's choice for the call's rows).
    pub(super) kernels: OutputKernels,
    pub(super) chunk: usize,
    pub(super) splits: usize,
    pub(super) cols_per_split: usize,
}

/// One chunk's rows: the first, how many, the observed columns, 1 / divisor.
#[derive(Clone, Copy, Debug)]
pub(super) struct ChunkRows {
    pub(super) start: usize,
    pub(super) rows: usize,
    pub(super) k: usize,
    pub(super) scale: f32,
}

/// The buffers a loss call's chunks read and write.
pub(super) struct LossBuffers<'b> {
    /// The top hidden activations and the chunk's targets.
    pub(super) x: &'b wgpu::Buffer,
    pub(super) y: &'b wgpu::Buffer,
    /// The row pass's per-split partials, reduced into `grad_in` and `row_loss`.
    pub(super) part_in: &'b wgpu::Buffer,
    pub(super) part_loss: &'b wgpu::Buffer,
    pub(super) grad_in: &'b wgpu::Buffer,
    pub(super) row_loss: &'b wgpu::Buffer,
    /// Where the column pass accumulates d W and d b.
    pub(super) gw: &'b wgpu::Buffer,
    pub(super) gb: &'b wgpu::Buffer,
    /// The blocked kernels' scratch, with `OutputKernels::Blocked`.
    pub(super) blocked: Option<&'b BlockedScratch>,
}

/// What `OutputKernels::Blocked` keeps between its products: a chunk's error gradient
/// `[rows, k]`, and the weight gradient's partial sums per row range `[splits, k, 4 hv]`
/// and `[splits, k]` (when weight gradients are asked for).
pub(super) struct BlockedScratch {
    pub(super) g: PooledBuffer,
    pub(super) part_w: Option<(PooledBuffer, PooledBuffer)>,
}

impl GpuOutputLayer {
    /// How a loss call is cut: rows per chunk (the chunk's targets fit one binding), and
    /// column splits (enough workgroups to fill the GPU, partials within one binding).
    pub(super) fn loss_cut(&self, n: usize, k: usize, hv: usize) -> LossCut {
        let limit = self.chunk_limit();
        let max_groups = self.gpu.limits().max_compute_workgroups_per_dimension as usize;
        let mut chunk = (limit / (4 * k)).max(1).min(n);
        let kernels = self.tiling.output_kernels.for_rows(n);
        // The blocked kernels' workgroups take 128 rows: a chunk of whole blocks wastes none
        // (520 rows per chunk at the paper's scale would leave a fifth of the forward
        // product's threads idle).
        let blocked = kernels == OutputKernels::Blocked;
        if blocked && chunk < n && chunk > BLOCKED_TILE {
            chunk -= chunk % BLOCKED_TILE;
        }
        // Column splits: enough workgroups to fill the GPU, partials within one binding.
        let (tile_columns, row_blocks) = if blocked {
            (BLOCKED_TILE, chunk.div_ceil(BLOCKED_TILE))
        } else {
            let rows = self.tiling.row_pass(hv, &self.gpu).rows;
            (TILE_COLUMNS, chunk.div_ceil(rows))
        };
        let tiles = k.div_ceil(tile_columns);
        let splits = self
            .tiling
            .target_workgroups
            .div_ceil(row_blocks)
            .min(limit / (16 * hv * chunk))
            .min(max_groups)
            .min(self.tiling.max_splits)
            .clamp(1, tiles);
        let cols_per_split = tiles.div_ceil(splits) * tile_columns;
        let splits = k.div_ceil(cols_per_split);
        LossCut {
            kernels,
            chunk,
            splits,
            cols_per_split,
        }
    }

    /// The scratch of the blocked kernels for a call cut as `cut` (none for the fused).
    pub(super) fn blocked_scratch(
        &self,
        cut: LossCut,
        k: usize,
        hv: usize,
        weight_grads: bool,
    ) -> Option<BlockedScratch> {
        if cut.kernels != OutputKernels::Blocked {
            return None;
        }
        let usage = wgpu::BufferUsages::empty();
        let part_w = weight_grads.then(|| {
            // A shorter last chunk has no more ranges.
            let splits = self.weight_splits_at_most(cut.chunk, k, hv);
            (
                self.gpu.scratch("partial d W", splits * k * 4 * hv, usage),
                self.gpu.scratch("partial d b", splits * k, usage),
            )
        });
        Some(BlockedScratch {
            g: self.gpu.scratch("error gradient", cut.chunk * k, usage),
            part_w,
        })
    }

    /// How `blocked_weight_grad.wgsl` cuts `rows` rows into ranges (each with its own
    /// partial d W): the ranges and the rows per range.
    pub(super) fn weight_cut(&self, rows: usize, k: usize, hv: usize) -> (usize, usize) {
        let rows_per_split = rows
            .div_ceil(self.weight_splits_at_most(rows, k, hv))
            .next_multiple_of(BLOCKED_WEIGHT_ROWS);
        (rows.div_ceil(rows_per_split), rows_per_split)
    }

    /// At most this many row ranges for `rows` rows (never more for fewer rows): enough
    /// workgroups to fill the GPU, partials within one binding.
    fn weight_splits_at_most(&self, rows: usize, k: usize, hv: usize) -> usize {
        let column_blocks = k.div_ceil(BLOCKED_TILE);
        self.tiling
            .target_workgroups
            .div_ceil(column_blocks)
            .min(self.chunk_limit() / (16 * hv * k))
            .min(self.gpu.limits().max_compute_workgroups_per_dimension as usize)
            .clamp(1, rows.div_ceil(BLOCKED_WEIGHT_ROWS))
    }
}
