//! How a call is cut into work ([`Tiling`]: chunks, splits, the small-call threshold, the
//! kernels' variants) and which output kernels run ([`OutputKernels`]), with the tile shapes
//! of the kernels that the cut follows.

use crate::gpu::{BlockedDepth, Gpu, RowPass};

/// Columns per tile of `loss_rows.wgsl` (its splits are whole tiles).
pub(super) const TILE_COLUMNS: usize = 32;

/// Rows and columns per workgroup of `blocked_forward.wgsl` (its splits are whole tiles of
/// columns), rows per workgroup of `blocked_input_grad.wgsl` and columns per workgroup of
/// `blocked_weight_grad.wgsl`: 16 x 16 threads of 8 x 8 outputs.
pub(super) const BLOCKED_TILE: usize = 128;

/// The row ranges of `blocked_weight_grad.wgsl` are whole tiles of this many rows (its
/// tile is 16 or 8 rows deep, `BlockedDepth`).
pub(super) const BLOCKED_WEIGHT_ROWS: usize = 16;

/// Which kernels compute an output layer's loss and gradients. Both give the CPU's results
/// to f32 summation order; which is faster is a GPU's question (docs/gpu.md).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum OutputKernels {
    /// `Blocked` for a call of at least one whole block of rows (`BLOCKED_TILE`, 128:
    /// learning's batches), `Fused` for fewer (online inference's 30-row window). On an
    /// H200 (2026-11-30) the blocked kernels took a paper-scale learning iteration from
    /// 0.0185 to 0.0164 s and five networks' from 0.071 to 0.061 s, while the fused took
    /// inference's window in 0.22 ms against 0.27 (docs/gpu.md).
    #[default]
    Auto,
    /// A fused pass by rows (forward product, error, input gradient; each thread one row
    /// against broadcast weights) and, with weight gradients, a pass by columns that
    /// recomputes the forward product.
    Fused,
    /// Three register-blocked products with the error gradient written out between them:
    /// the forward product in 8 x 8 blocks of (rows, columns) per thread, then the input
    /// and the weight gradients eight rows (columns) by one vec4 of the width per thread,
    /// their tiles double-buffered in workgroup memory and as deep as the adapter allows
    /// (`BlockedDepth`). 16 (forward) and 10.7 multiply-adds per workgroup-memory load
    /// against `Fused`'s 4, and no recomputed product, for a [rows x columns] error
    /// gradient in device memory (one chunk of rows, at most `Tiling::max_chunk_bytes`).
    Blocked,
}

impl OutputKernels {
    /// The kernels a call of `rows` rows runs: `Fused` or `Blocked`, never `Auto`.
    pub fn for_rows(self, rows: usize) -> Self {
        match self {
            Self::Auto if rows >= BLOCKED_TILE => Self::Blocked,
            Self::Auto => Self::Fused,
            chosen => chosen,
        }
    }
}

/// How a call is cut into work: column splits of the row pass (each with its own split-K
/// partial) and chunks of rows (each binding at most `max_chunk_bytes`), and which of the
/// kernels' equivalent paths run. Results do not depend on it beyond f32 summation order;
/// the defaults are what ships, and only tests and benchmarks change it
/// ([`crate::WgpuBackend::with_tiling`]): to run every path on small shapes, and each
/// kernel's paths against each other.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Tiling {
    /// Workgroups a chunk's passes aim for (the row pass's and the blocked input
    /// gradient's column splits, the blocked weight gradient's row ranges): enough to fill
    /// a large GPU, few enough that the split-K partials stay small. 256: on an H200
    /// (2026-11-30) the blocked learning call took 9.9 ms at 256 against 18.1 at 1,024
    /// and 10.7 at 4,096, and whole iterations with the fused kernels were alike at 256
    /// and 1,024 (0.0189 and 0.0185 s).
    pub target_workgroups: usize,
    /// At most this many column splits: the reduce pass adds a row's partials one after
    /// another, so with few rows (online inference's 30, which would otherwise get one
    /// split per 32-column tile: 1,008) it becomes the slow part, and with too few the row
    /// pass runs out of parallelism. 256 was the fastest cap for inference's window on an
    /// H200 and leaves learning's paper-scale chunks (112 splits) as they were
    /// (docs/results/gpu/README.md, "2026-11-26: H200, several calls").
    pub max_splits: usize,
    /// Largest buffer a chunk binds (the device's binding limit applies too).
    pub max_chunk_bytes: usize,
    /// Rows per partial sum of a hidden read-out layer's weight gradient
    /// (`dense_weights.wgsl`, a learner's read-outs): 5,400 rows in ranges of 256 give a
    /// 50 x 41 layer 45,000 threads.
    pub weight_rows_per_split: usize,
    /// Calls whose forward product has fewer multiply-adds than this (rows x columns x
    /// hidden width) stay on the CPU, where they take less than the GPU's round trip (a
    /// fixed 0.2-0.3 ms per call on an H200). Online inference makes such calls 50 times a
    /// step: proprioception (30 x 28 x 40 = 34 k) and 16x16 vision (30 x 1,536 x 50 = 2.3 M),
    /// where 2 CPU threads measured 53.6 steps/s against 25.5 on the GPU (H200, 2026-11-26:
    /// docs/results/gpu/README.md, "2026-11-26: H200, several calls"; every call on the GPU
    /// lost again on 2026-11-28, 28.1 against 35.4 steps/s).
    /// Everything observed (48 M) and learning (87 M and more) stay on the GPU. A learner's
    /// resident layers always run on the GPU (their weights live there). Tests set 0 to
    /// run their small shapes on the GPU.
    pub min_work: usize,
    /// The output layer's kernels: by default each call's by its rows
    /// ([`OutputKernels::Auto`]); tests and benchmarks force either set.
    pub output_kernels: OutputKernels,
    /// How deep the blocked kernels' tiles are; `None`: as deep as the adapter allows
    /// (tests force the shallow tiles that WebGPU's default limits get).
    pub blocked_depth: Option<BlockedDepth>,
    /// Threads per window's workgroup of the recurrence kernels; `None`: one per item of a
    /// step's widest phase, as the adapter allows (384 at the paper's shapes, where 128, the
    /// width before 2026-11-28, made an iteration 0.0208 s against 0.0188 on an H200).
    /// Narrower widths are what an adapter with fewer invocations per workgroup gets
    /// (WebGPU's default 256); tests force them.
    pub recurrence_threads: Option<usize>,
    /// The blocked output kernels read the targets and read and write the error gradient
    /// as vec4s of four consecutive columns where a row's observed columns are a multiple
    /// of 4 (every caresim layout's): a fourth of the accesses, each four times as wide;
    /// the same arithmetic. Off: one value at a time (the kernels before 2026-11-30's
    /// fourth session; on an H200 the read-outs took 5.48 ms an iteration that way against 4.96,
    /// docs/gpu.md). Only tests turn it off (the scalar path serves k not a multiple of 4).
    pub vector_io: bool,
    /// Where a window's workgroup is as wide as the recurrence's per-unit phases (the
    /// default width), each thread issues a step's loads from device memory (the forward's
    /// inputs; the backward's record and read-out gradients) at the step's start, so that
    /// their latency passes under the phases before their use: one wait per step where the
    /// backward had one per depth and one more. The same values. Off: loaded where they
    /// are used (the kernels before 2026-11-30's fourth session, and the path of narrower
    /// widths; on an H200 about as fast, docs/gpu.md). Only tests turn it off.
    pub recurrence_early_loads: bool,
}

impl Tiling {
    /// The row pass's shape for a hidden width of `hv` vec4s on `gpu`.
    pub(crate) fn row_pass(&self, hv: usize, gpu: &Gpu) -> RowPass {
        let workgroup_bytes = gpu.limits().max_compute_workgroup_storage_size as usize;
        RowPass::new(hv, workgroup_bytes)
    }
}

impl Default for Tiling {
    fn default() -> Self {
        Self {
            target_workgroups: 256,
            max_splits: 256,
            // WebGPU's default 128 MiB per binding. On an H200 (2026-12-01) 128 MiB took a
            // paper-scale iteration from 0.0103 to 0.0100 s against 64 (fewer, deeper
            // dispatches), for 66 MB more per network.
            max_chunk_bytes: 128 << 20,
            weight_rows_per_split: 256,
            min_work: 4 << 20,
            output_kernels: OutputKernels::Auto,
            blocked_depth: None,
            recurrence_threads: None,
            vector_io: true,
            recurrence_early_loads: true,
        }
    }
}
