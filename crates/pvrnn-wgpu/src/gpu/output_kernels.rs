//! The output layer's kernels, compiled per hidden width in vec4s ([`Kernels`]): the fused
//! row and column passes, the reduction and the predictions, with the row pass's shape
//! ([`RowPass`]), and the register-blocked products ([`BlockedKernels`]) at the depth the
//! adapter allows ([`BlockedDepth`]).

use std::sync::{Arc, OnceLock};

use super::Gpu;

/// Kernels compiled for one hidden width in vec4s (a constant of the WGSL source, so rows
/// live in registers and tiles are fixed-size arrays in workgroup memory).
#[derive(Debug)]
pub(crate) struct Kernels {
    hv: usize,
    /// Rows per workgroup of `loss_rows`.
    pub(crate) row_pass_rows: usize,
    pub(crate) loss_rows: wgpu::ComputePipeline,
    pub(crate) loss_columns: wgpu::ComputePipeline,
    pub(crate) reduce: wgpu::ComputePipeline,
    pub(crate) predict: wgpu::ComputePipeline,
    /// The register-blocked output-layer kernels (`OutputKernels::Blocked`), deep and
    /// shallow ([`BlockedDepth`]), for widths with and without a padding lane to sum the
    /// biases in (`blocked_weight_grad.wgsl`), and with the error gradients read and
    /// written as scalars or as vec4s (`Tiling::vector_io`), compiled on first use.
    blocked: [[[OnceLock<BlockedKernels>; 2]; 2]; 2],
}

/// Rows per workgroup of the fused row pass (`loss_rows.wgsl`, one per thread) where the
/// adapter's workgroup memory holds them, and its columns per step: on an H200 (2026-11-28)
/// 64 and 2 were within the spread of the fastest of the 12 shapes measured (32, 64 or 128
/// rows; 1, 2, 4 or 8 columns per step), and 4 and 8 per step slower everywhere.
const ROW_PASS_ROWS: usize = 64;
const ROW_PASS_STEP: usize = 2;

/// What the output layer's kernels are compiled for: the hidden width in vec4s, and the
/// row pass's rows per workgroup ([`RowPass::new`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub(crate) struct RowPass {
    pub(crate) hv: usize,
    pub(crate) rows: usize,
}

impl RowPass {
    /// [`ROW_PASS_ROWS`] halved until the kernel's workgroup memory fits `workgroup_bytes`
    /// (the device's limit), at least 32 (the tile's biases are loaded by its first 32
    /// threads): WebGPU's default 16 KiB holds 64 rows at the paper's width, 32 at 64
    /// hidden units.
    pub(crate) fn new(hv: usize, workgroup_bytes: usize) -> Self {
        // loss_rows.wgsl: the weight tile, the target tile (33 floats a row), the biases.
        let bytes = |rows: usize| 32 * hv * 16 + rows * 33 * 4 + 32 * 4;
        let mut rows = ROW_PASS_ROWS;
        while rows > 32 && bytes(rows) > workgroup_bytes {
            rows /= 2;
        }
        Self { hv, rows }
    }
}

/// The register-blocked output layer's kernels for one hidden width: the forward product
/// with the error gradient written out, then the input and weight gradients from it.
#[derive(Debug)]
pub(crate) struct BlockedKernels {
    pub(crate) forward: wgpu::ComputePipeline,
    pub(crate) input_grad: wgpu::ComputePipeline,
    pub(crate) weight_grad: wgpu::ComputePipeline,
    pub(crate) weight_reduce: wgpu::ComputePipeline,
}

/// How deep the register-blocked kernels' staged tiles are, each double-buffered: `Deep`
/// stages 4 vec4s of the hidden width per chunk of the forward product and 16 columns
/// (rows) per tile of the gradient products, in 32 KiB of workgroup memory (native
/// adapters: NVIDIA's Vulkan driver offers 48 KiB, lavapipe 32); `Shallow` half that, in
/// WebGPU's default 16 KiB. The adapter's limit chooses unless `Tiling::blocked_depth` asks
/// for the shallower (tests, to run the shallow kernels on any adapter).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BlockedDepth {
    Deep,
    Shallow,
}

impl BlockedDepth {
    /// The deepest `limits` allow.
    pub fn for_limits(limits: &wgpu::Limits) -> Self {
        if limits.max_compute_workgroup_storage_size >= 32 << 10 {
            Self::Deep
        } else {
            Self::Shallow
        }
    }

    /// vec4s of the hidden width per staged chunk of `blocked_forward.wgsl`.
    fn forward_vec4s(self) -> usize {
        match self {
            Self::Deep => 4,
            Self::Shallow => 2,
        }
    }

    /// Columns (rows) per staged tile of `blocked_input_grad.wgsl` (`blocked_weight_grad.wgsl`).
    fn tile(self) -> usize {
        match self {
            Self::Deep => 16,
            Self::Shallow => 8,
        }
    }
}

impl Gpu {
    /// The kernels for a hidden width of `hv` vec4s and the row pass's rows, compiled on
    /// first use.
    pub(crate) fn kernels(&self, row_pass: RowPass) -> Arc<Kernels> {
        let mut cache = self.kernels.lock().unwrap_or_else(|e| e.into_inner());
        cache
            .entry(row_pass)
            .or_insert_with(|| Arc::new(self.compile(row_pass)))
            .clone()
    }

    fn compile(&self, row_pass: RowPass) -> Kernels {
        let RowPass { hv, rows } = row_pass;
        let step = ROW_PASS_STEP;
        // Tile sizes in vec4s: 32 columns (loss_rows), 32 rows (loss_columns), 4 rows
        // (predict) of hv each; loss_rows' rows per workgroup and columns per step, and its
        // target tile (rows x 33 floats).
        let constants = [
            ("HV", hv),
            ("CT_HV", 32 * hv),
            ("RT_HV", 32 * hv),
            ("RB_HV", 4 * hv),
            ("RT", rows),
            ("CS", step),
            ("RT_YS", rows * 33),
        ];
        let source = |text: &str| output_source(text, &constants);
        Kernels {
            hv,
            row_pass_rows: rows,
            loss_rows: self.audited_pipeline("loss_rows", source(shader!("loss_rows.wgsl"))),
            loss_columns: self
                .audited_pipeline("loss_columns", source(shader!("loss_columns.wgsl"))),
            reduce: self.pipeline("reduce", source(shader!("reduce.wgsl"))),
            predict: self.pipeline("predict", source(shader!("predict.wgsl"))),
            blocked: Default::default(),
        }
    }

    /// The register-blocked kernels of `kernels`' width in vec4s (`hidden` units) with
    /// tiles `depth` deep (at most what the adapter's workgroup memory holds), the targets
    /// and error gradients as vec4s where `vector_io` (rows of a multiple of 4 columns),
    /// compiled on first use.
    pub(crate) fn blocked_kernels<'k>(
        &self,
        kernels: &'k Kernels,
        depth: BlockedDepth,
        hidden: usize,
        vector_io: bool,
    ) -> &'k BlockedKernels {
        let depth = match BlockedDepth::for_limits(&self.limits()) {
            BlockedDepth::Shallow => BlockedDepth::Shallow,
            BlockedDepth::Deep => depth,
        };
        let bias_lane = usize::from(!hidden.is_multiple_of(4));
        let vec_io = usize::from(vector_io);
        kernels.blocked[depth as usize][bias_lane][vec_io].get_or_init(|| {
            let hv = kernels.hv;
            let (kc, kt) = (depth.forward_vec4s(), depth.tile());
            let threads = 16 * hv;
            // The forward product's column quads per tile: 8 columns per thread.
            let cl = 32;
            let forward = [
                ("HV", hv),
                ("KC", kc),
                ("KS", 4 * kc),
                ("FULL", hv / kc),
                ("TAIL", 4 * (hv % kc)),
                ("CHUNKS", hv.div_ceil(kc)),
                ("CL", cl),
                // Two buffers of a chunk's rows (32 quads) and columns, at least the 512
                // vec4s of the row losses' reduction.
                ("STAGE", (2 * 4 * kc * (32 + cl)).max(512)),
                ("VEC_IO", vec_io),
            ];
            // The input and weight gradients: two buffers of 32 kt error-gradient vec4s and
            // kt hv weight (activation) vec4s; each thread loads a fixed number of the
            // error gradients' 4 x 4 blocks (input) or vec4s (weights).
            let gradient = |loads: usize| {
                [
                    ("HV", hv),
                    ("KT", kt),
                    ("NT", threads),
                    ("STAGE", 2 * (32 * kt + kt * hv)),
                    ("LOADS", loads),
                    ("BIAS_LANE", bias_lane),
                    ("VEC_IO", vec_io),
                ]
            };
            BlockedKernels {
                forward: self.audited_pipeline(
                    "blocked forward",
                    output_source(shader!("blocked_forward.wgsl"), &forward),
                ),
                input_grad: self.audited_pipeline(
                    "blocked input gradient",
                    output_source(
                        shader!("blocked_input_grad.wgsl"),
                        &gradient((8 * kt).div_ceil(threads)),
                    ),
                ),
                weight_grad: self.audited_pipeline(
                    "blocked weight gradient",
                    output_source(
                        shader!("blocked_weight_grad.wgsl"),
                        &gradient((32 * kt).div_ceil(threads)),
                    ),
                ),
                weight_reduce: self.pipeline(
                    "blocked weight reduce",
                    output_source(shader!("blocked_weight_reduce.wgsl"), &[("HV", hv)]),
                ),
            }
        })
    }
}

/// An output-layer kernel's source, expanded, after the helpers they share.
fn output_source(text: &str, constants: &[(&str, usize)]) -> String {
    let common = shader!("output_common.wgsl");
    crate::template::expand(&format!("{common}\n{text}"), constants)
}

#[cfg(all(test, not(target_arch = "wasm32")))]
mod tests {
    use super::*;

    /// The row pass's rows fit the workgroup memory: 64 at the paper's width (13 vec4s)
    /// within WebGPU's default 16 KiB, 32 at 64 hidden units.
    #[test]
    fn the_row_pass_rows_fit_the_workgroup_memory() {
        let rows = |hv, bytes| RowPass::new(hv, bytes).rows;
        assert_eq!(rows(13, 16 << 10), 64);
        assert_eq!(rows(13, 48 << 10), 64);
        assert_eq!(rows(16, 16 << 10), 32);
        assert_eq!(rows(16, 48 << 10), 64);
    }
}
