//! The read-outs' output layers on the GPU: weights uploaded once per loaded model, inputs
//! and targets streamed per call in chunks of rows that fit WebGPU's binding limits.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use pvrnn_core::Modality;
use pvrnn_core::assembled::{OutputLoss, ReadoutLoss};
use pvrnn_core::deferred::Deferred;
use pvrnn_core::params::Params;

use crate::encode::{
    Recorder, WORKGROUP, bind, dispatch, fits, grid, pad_rows, row_losses, unpad_rows, vec4s,
};
use crate::gpu::{BlockedDepth, Gpu, Kernels, ResidentKey, RowPass};
use crate::pool::PooledBuffer;
use crate::readback::read_back;
use crate::resident::ResidentLayer;

/// Columns per tile of `loss_rows.wgsl` (its splits are whole tiles).
const TILE_COLUMNS: usize = 32;
/// Rows and columns per workgroup of `blocked_forward.wgsl` (its splits are whole tiles of
/// columns), rows per workgroup of `blocked_input_grad.wgsl` and columns per workgroup of
/// `blocked_weight_grad.wgsl`: 16 x 16 threads of 8 x 8 outputs.
const BLOCKED_TILE: usize = 128;
/// The row ranges of `blocked_weight_grad.wgsl` are whole tiles of this many rows (its
/// tile is 16 or 8 rows deep, `BlockedDepth`).
const BLOCKED_WEIGHT_ROWS: usize = 16;

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

/// Rows per workgroup of `predict.wgsl`.
const PREDICT_ROWS: usize = 4;

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
struct DenseParams {
    rows: u32,
    fan_in: u32,
    fan_out: u32,
    x_stride: u32,
    y_stride: u32,
    has_bias: u32,
    groups_x: u32,
    _pad: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct DenseWeightsParams {
    rows: u32,
    fan_in: u32,
    fan_out: u32,
    x_stride: u32,
    y_stride: u32,
    rows_per_split: u32,
    groups_x: u32,
    splits: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct DenseReduceParams {
    fan_in: u32,
    fan_out: u32,
    splits: u32,
    has_bias: u32,
    groups_x: u32,
    _pad: [u32; 3],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct DenseBackParams {
    rows: u32,
    fan_in: u32,
    fan_out: u32,
    y_stride: u32,
    gx_stride: u32,
    groups_x: u32,
    _pad: [u32; 2],
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

/// How a loss call is cut into chunks of rows and column splits (see
/// [`GpuOutputLayer::encode_loss`]).
#[derive(Clone, Copy, Debug)]
struct LossCut {
    /// `Fused` or `Blocked` (the tiling's choice for the call's rows).
    kernels: OutputKernels,
    chunk: usize,
    splits: usize,
    cols_per_split: usize,
}

/// One chunk's rows: the first, how many, the observed columns, 1 / divisor.
#[derive(Clone, Copy, Debug)]
struct ChunkRows {
    start: usize,
    rows: usize,
    k: usize,
    scale: f32,
}

/// The buffers a loss call's chunks read and write.
struct LossBuffers<'b> {
    /// The top hidden activations and the chunk's targets.
    x: &'b wgpu::Buffer,
    y: &'b wgpu::Buffer,
    /// The row pass's per-split partials, reduced into `grad_in` and `row_loss`.
    part_in: &'b wgpu::Buffer,
    part_loss: &'b wgpu::Buffer,
    grad_in: &'b wgpu::Buffer,
    row_loss: &'b wgpu::Buffer,
    /// Where the column pass accumulates d W and d b.
    gw: &'b wgpu::Buffer,
    gb: &'b wgpu::Buffer,
    /// The blocked kernels' scratch, with `OutputKernels::Blocked`.
    blocked: Option<&'b BlockedScratch>,
}

/// What `OutputKernels::Blocked` keeps between its products: a chunk's error gradient
/// `[rows, k]`, and the weight gradient's partial sums per row range `[splits, k, 4 hv]`
/// and `[splits, k]` (when weight gradients are asked for).
struct BlockedScratch {
    g: PooledBuffer,
    part_w: Option<(PooledBuffer, PooledBuffer)>,
}

/// The output layer's loss encoded on the device (see [`GpuOutputLayer::encode_loss`]): the
/// buffers that hold its results, and those the submission uses until it has run.
struct EncodedLoss {
    /// d F / d input, `[n, 4 hv]` (padded rows), and the row losses, `[n]` (sums of squared
    /// errors times 1 / divisor).
    grad_in: PooledBuffer,
    row_loss: PooledBuffer,
    /// d W `[k, 4 hv]` and d b `[k]`, when they are to be read back.
    grads: Option<(PooledBuffer, PooledBuffer)>,
    in_flight: Vec<PooledBuffer>,
    resident_targets: Option<Arc<Vec<wgpu::Buffer>>>,
}

/// A learner's whole read-out encoded on the device (see [`GpuOutputLayer::encode_readout`]).
#[derive(Debug)]
pub(crate) struct EncodedReadout {
    /// d F / d the module states, `[n, grad_stride]` (the first `d` values of each row).
    pub(crate) grad_d: PooledBuffer,
    pub(crate) grad_stride: usize,
    /// The row losses' sums of squared errors (times 1 / divisor), `[n]`.
    pub(crate) row_loss: PooledBuffer,
    /// What the submission uses, kept from the pool until it has run.
    _keep: Vec<PooledBuffer>,
    _targets: Option<Arc<Vec<wgpu::Buffer>>>,
}

impl GpuOutputLayer {
    /// Encodes the fused loss of `layer` for `n` rows of top hidden activations in `x`
    /// (`[n, 4 hv]`, padded rows), with the weight gradients when `weight_grads` (into a
    /// learner's buffers if the layer is resident, else into buffers to read back).
    #[allow(clippy::too_many_arguments)]
    fn encode_loss(
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

    /// The blocked kernels of `layer`'s width at the depth the tiling asks for, for rows of
    /// `k` observed columns (read as vec4s where `k` is a multiple of 4 and the tiling
    /// allows it).
    fn blocked_kernels<'l>(&self, layer: &'l Layer, k: usize) -> &'l crate::gpu::BlockedKernels {
        let depth = self.tiling.blocked_depth.unwrap_or(BlockedDepth::Deep);
        let vector_io = self.tiling.vector_io && k.is_multiple_of(4);
        self.gpu
            .blocked_kernels(&layer.kernels, depth, layer.hidden, vector_io)
    }

    /// How a loss call is cut: rows per chunk (the chunk's targets fit one binding), and
    /// column splits (enough workgroups to fill the GPU, partials within one binding).
    fn loss_cut(&self, n: usize, k: usize, hv: usize) -> LossCut {
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
    fn blocked_scratch(
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
    fn weight_cut(&self, rows: usize, k: usize, hv: usize) -> (usize, usize) {
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

    /// `OutputKernels::Blocked`'s first two products for one chunk: the forward product
    /// with the error gradient written to `scratch.g` and the row losses' partials, then
    /// the input gradient's partials from it (both per column split, as `loss_rows.wgsl`'s).
    #[allow(clippy::too_many_arguments)]
    fn encode_blocked_rows(
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
    fn encode_blocked_weights(
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

    /// Encodes a learner's whole read-out of `modality` from the module states in `input`:
    /// `[n, input width]` for a read-out with hidden layers, else `[n, 4 hv]` (the output
    /// layer's padded rows, padding zero). The hidden layers forward, the output layer's
    /// loss, and back to d F / d d, every weight gradient into the learner's buffers (when
    /// `weight_grads`). `None` unless the read-out is a learner's.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn encode_readout(
        &self,
        encoder: &mut dyn Recorder,
        modality: Modality,
        input: &wgpu::Buffer,
        n: usize,
        k: usize,
        divisor: usize,
        targets: &[&[f32]],
        resident: Option<u64>,
        weight_grads: bool,
    ) -> Option<EncodedReadout> {
        let layer = self.layer(modality)?;
        let readout = layer.resident()?;
        let mut keep = Vec::new();
        let acts = self.encode_hidden_forward(encoder, readout, input, n, &mut keep);
        let top: &wgpu::Buffer = acts.last().map_or(input, |(a, _)| a);
        let encoded = self.encode_loss(
            encoder,
            layer,
            modality,
            top,
            n,
            k,
            divisor,
            targets,
            resident,
            weight_grads,
        );
        let EncodedLoss {
            grad_in,
            row_loss,
            grads: _,
            in_flight,
            resident_targets,
        } = encoded;
        keep.extend(in_flight);
        let (grad_d, grad_stride) = if readout.hidden.is_empty() {
            (grad_in, 4 * vec4s(layer.hidden))
        } else {
            let grad_d = self.encode_hidden_backward(
                encoder,
                readout,
                input,
                &acts,
                grad_in,
                n,
                weight_grads,
                &mut keep,
            );
            if weight_grads {
                readout.hidden_gradients_written();
            }
            (grad_d, readout.input_width)
        };
        keep.extend(acts.into_iter().map(|(a, _)| a));
        Some(EncodedReadout {
            grad_d,
            grad_stride,
            row_loss,
            _keep: keep,
            _targets: resident_targets,
        })
    }

    /// Encodes the hidden layers of a learner's read-out, forward from the module states in
    /// `d` (`[n, input width]`): every layer's activations, the top one in padded rows for
    /// the output layer's kernels. Returns them bottom first.
    fn encode_hidden_forward(
        &self,
        encoder: &mut dyn Recorder,
        readout: &ResidentLayer,
        d: &wgpu::Buffer,
        n: usize,
        in_flight: &mut Vec<PooledBuffer>,
    ) -> Vec<(PooledBuffer, usize)> {
        let gpu = &*self.gpu;
        let kernels = gpu.dense_kernels();
        let mut acts: Vec<(PooledBuffer, usize)> = Vec::with_capacity(readout.hidden.len());
        for (l, layer) in readout.hidden.iter().enumerate() {
            let top = l + 1 == readout.hidden.len();
            let y_stride = if top {
                4 * vec4s(layer.fan_out)
            } else {
                layer.fan_out
            };
            let (x, x_stride) = match acts.last() {
                Some((a, stride)) => (&**a, *stride),
                None => (d, readout.input_width),
            };
            // COPY_SRC: `hidden_top` reads the top layer back.
            let y = gpu.scratch(
                "hidden activations",
                n * y_stride,
                wgpu::BufferUsages::COPY_SRC,
            );
            let (groups_x, groups_y) = grid(gpu, n * y_stride);
            let params = gpu.uniform(&DenseParams {
                rows: n as u32,
                fan_in: layer.fan_in as u32,
                fan_out: layer.fan_out as u32,
                x_stride: x_stride as u32,
                y_stride: y_stride as u32,
                has_bias: layer.has_bias as u32,
                groups_x,
                _pad: 0,
            });
            let group = bind(
                gpu,
                &kernels.forward,
                &[&params, x, &layer.weight, &layer.bias, &y],
            );
            dispatch(encoder, &kernels.forward, &group, groups_x, groups_y);
            in_flight.push(params);
            acts.push((y, y_stride));
        }
        acts
    }

    /// Encodes the way back through a learner's hidden layers from `grad_top` (d F / d the
    /// top activations, padded rows): the weight gradients into the learner's buffers (when
    /// `weight_grads`) and d F / d d, `[n, input width]`, which it returns.
    #[allow(clippy::too_many_arguments)]
    fn encode_hidden_backward(
        &self,
        encoder: &mut dyn Recorder,
        readout: &ResidentLayer,
        d: &wgpu::Buffer,
        acts: &[(PooledBuffer, usize)],
        grad_top: PooledBuffer,
        n: usize,
        weight_grads: bool,
        in_flight: &mut Vec<PooledBuffer>,
    ) -> PooledBuffer {
        let gpu = &*self.gpu;
        let kernels = gpu.dense_kernels();
        let mut grad = grad_top;
        for (l, layer) in readout.hidden.iter().enumerate().rev() {
            let (y, y_stride) = (&acts[l].0, acts[l].1);
            let (x, x_stride): (&wgpu::Buffer, usize) = match l {
                0 => (d, readout.input_width),
                _ => (&acts[l - 1].0, acts[l - 1].1),
            };
            if weight_grads {
                // Split-K over rows, then the ranges added in order.
                let values = layer.fan_out * (layer.fan_in + 1);
                let rows_per_split = self.tiling.weight_rows_per_split.max(1);
                let splits = n.div_ceil(rows_per_split);
                let partial =
                    gpu.scratch("d W partials", splits * values, wgpu::BufferUsages::empty());
                let (groups_x, groups_y) = grid(gpu, splits * values);
                let params = gpu.uniform(&DenseWeightsParams {
                    rows: n as u32,
                    fan_in: layer.fan_in as u32,
                    fan_out: layer.fan_out as u32,
                    x_stride: x_stride as u32,
                    y_stride: y_stride as u32,
                    rows_per_split: rows_per_split as u32,
                    groups_x,
                    splits: splits as u32,
                });
                let group = bind(gpu, &kernels.weights, &[&params, x, y, &grad, &partial]);
                dispatch(encoder, &kernels.weights, &group, groups_x, groups_y);
                let (reduce_x, reduce_y) = grid(gpu, values);
                let reduce_params = gpu.uniform(&DenseReduceParams {
                    fan_in: layer.fan_in as u32,
                    fan_out: layer.fan_out as u32,
                    splits: splits as u32,
                    has_bias: layer.has_bias as u32,
                    groups_x: reduce_x,
                    _pad: [0; 3],
                });
                let group = bind(
                    gpu,
                    &kernels.weights_reduce,
                    &[&reduce_params, &partial, &layer.grad_w, &layer.grad_b],
                );
                dispatch(encoder, &kernels.weights_reduce, &group, reduce_x, reduce_y);
                in_flight.extend([params, reduce_params, partial]);
            }
            let grad_x = gpu.scratch("d hidden input", n * x_stride, wgpu::BufferUsages::COPY_SRC);
            let (groups_x, groups_y) = grid(gpu, n * x_stride);
            let params = gpu.uniform(&DenseBackParams {
                rows: n as u32,
                fan_in: layer.fan_in as u32,
                fan_out: layer.fan_out as u32,
                y_stride: y_stride as u32,
                gx_stride: x_stride as u32,
                groups_x,
                _pad: [0; 2],
            });
            let group = bind(
                gpu,
                &kernels.backward,
                &[&params, &grad, y, &layer.weight, &grad_x],
            );
            dispatch(encoder, &kernels.backward, &group, groups_x, groups_y);
            in_flight.push(params);
            in_flight.push(std::mem::replace(&mut grad, grad_x));
        }
        grad
    }
}

/// The output layer's pieces, each declining (`None`) what the GPU does not take; the
/// results are read back before the futures finish ([`Deferred`]: a native GPU's at once,
/// WebGPU's through the browser's event loop). Inputs are read before a call returns.
impl GpuOutputLayer {
    /// The fused loss of the first `k` dimensions for the top hidden activations `input`
    /// (`[n, hidden]`): forward, error, d F / d input, and d F / d W and b when
    /// `weight_grads` (left on the device for a resident layer). `None` for calls too small
    /// to pay for a transfer.
    #[allow(clippy::too_many_arguments)]
    pub fn loss<'a>(
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
        if n == 0 || k == 0 || self.too_small(layer, n * k) {
            return None;
        }
        let gpu = &*self.gpu;
        let (hl, hv) = (layer.hidden, vec4s(layer.hidden));
        let encode_phase = pvrnn_core::profile::phase("    GPU: upload and encode");
        let x = gpu.upload("hidden", &pad_rows(input, hl));
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        let encoded = self.encode_loss(
            &mut encoder,
            layer,
            modality,
            &x,
            n,
            k,
            divisor,
            targets,
            resident,
            weight_grads,
        );
        let mut sources: Vec<(&wgpu::Buffer, usize)> =
            vec![(&encoded.grad_in, n * 4 * hv), (&encoded.row_loss, n)];
        if let Some((gw, gb)) = &encoded.grads {
            sources.push((gw, k * 4 * hv));
            sources.push((gb, k));
        }
        let pending = read_back(gpu, encoder, &sources);
        drop(encode_phase);
        let has_bias = layer.has_bias;
        // The buffers the submission uses stay out of the pool until it has run.
        let used = (x, encoded);
        Some(Box::pin(async move {
            let wait_phase = pvrnn_core::profile::phase("    GPU: run and read back");
            let mut results = pending.await.into_iter();
            drop(used);
            drop(wait_phase);
            let grad_in = unpad_rows(&results.next().unwrap_or_default(), hl);
            let row_loss = row_losses(results.next().unwrap_or_default(), divisor);
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

    /// Only for a learner's read-outs (their hidden layers' weights are on the device):
    /// the hidden layers, the output layer's loss and the way back to the module states in
    /// one submission, reading back d F / d d and the row losses.
    #[allow(clippy::too_many_arguments)]
    pub fn readout_loss<'a>(
        &'a self,
        modality: Modality,
        d: &[f32],
        n: usize,
        k: usize,
        divisor: usize,
        targets: &[&[f32]],
        resident: Option<u64>,
        weight_grads: bool,
    ) -> Option<Deferred<'a, ReadoutLoss<f32>>> {
        let layer = self.layer(modality)?;
        let readout = layer.resident()?;
        if k == 0 || readout.hidden.is_empty() {
            return None;
        }
        let width = readout.input_width;
        if n == 0 {
            return Some(pvrnn_core::deferred::ready(ReadoutLoss {
                row_loss: Vec::new(),
                grad_d: Vec::new(),
                weight_grads: None,
            }));
        }
        let gpu = &*self.gpu;
        // Until the results are in (the CPU's read-out phases do not run).
        let readout_phase = pvrnn_core::profile::phase("  read-out, hidden and output layers");
        let encode_phase = pvrnn_core::profile::phase("    GPU: upload and encode");
        let input = gpu.upload("module states", d);
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        let encoded = self.encode_readout(
            &mut encoder,
            modality,
            &input,
            n,
            k,
            divisor,
            targets,
            resident,
            weight_grads,
        )?;
        let pending = read_back(
            gpu,
            encoder,
            &[(&encoded.grad_d, n * width), (&encoded.row_loss, n)],
        );
        drop(encode_phase);
        let used = (input, encoded);
        Some(Box::pin(async move {
            let wait_phase = pvrnn_core::profile::phase("    GPU: run and read back");
            let mut results = pending.await.into_iter();
            drop(used);
            drop(wait_phase);
            let grad_d = results.next().unwrap_or_default();
            let row_loss = row_losses(results.next().unwrap_or_default(), divisor);
            drop(readout_phase);
            // The weight gradients stay on the device for the learner's update.
            ReadoutLoss {
                row_loss,
                grad_d,
                weight_grads: None,
            }
        }))
    }

    /// For a learner's read-outs, whose hidden weights live on the device (see
    /// [`Self::readout_loss`]): their hidden layers forward, the top activations read back.
    pub fn hidden_top<'a>(
        &'a self,
        modality: Modality,
        d: &[f32],
        n: usize,
    ) -> Option<Deferred<'a, Vec<f32>>> {
        let layer = self.layer(modality)?;
        let readout = layer.resident()?;
        if readout.hidden.is_empty() {
            return None;
        }
        if n == 0 {
            return Some(pvrnn_core::deferred::ready(Vec::new()));
        }
        let gpu = &*self.gpu;
        let input = gpu.upload("module states", d);
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        let mut in_flight = Vec::new();
        let acts = self.encode_hidden_forward(&mut encoder, readout, &input, n, &mut in_flight);
        let (top, stride) = acts.last().expect("hidden layers");
        let pending = read_back(gpu, encoder, &[(top, n * stride)]);
        let hl = layer.hidden;
        let used = (input, acts, in_flight);
        Some(Box::pin(async move {
            let top = pending.await.into_iter().next().unwrap_or_default();
            drop(used);
            unpad_rows(&top, hl)
        }))
    }

    /// Predictions of every dimension, `[n, dims]`, for the top hidden activations
    /// `input` (`[n, hidden]`); `None` for calls too small to pay for a transfer.
    pub fn predict<'a>(
        &'a self,
        modality: Modality,
        input: &[f32],
        n: usize,
    ) -> Option<Deferred<'a, Vec<f32>>> {
        let layer = self.layer(modality)?;
        if n == 0 {
            return Some(pvrnn_core::deferred::ready(Vec::new()));
        }
        if self.too_small(layer, n * layer.dims) {
            return None;
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
