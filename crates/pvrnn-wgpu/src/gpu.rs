//! The device, its queue, and the compiled kernels (one set per hidden width).

use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock};

use crate::pool::{BufferPool, PooledBuffer};

/// Why no GPU could be used.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    #[error(
        "no GPU adapter found ({0}); install a Vulkan, Metal or DX12 driver (on Debian, \
         `mesa-vulkan-drivers` gives the CPU's lavapipe device) or use `--backend cpu`"
    )]
    NoAdapter(String),
    #[error("the GPU adapter {adapter} refused a device: {reason}")]
    NoDevice { adapter: String, reason: String },
    #[error("waiting for the GPU adapter {adapter} failed: {reason}")]
    Wait { adapter: String, reason: String },
}

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

/// Which kernels keep wgpu's runtime checks (bounds, loop bounding, integer division)
/// natively (`WgpuOptions::checks`, `pvrnn --wgpu-checks`); the browser's WebGPU checks
/// every kernel regardless.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum RuntimeChecks {
    /// Every kernel but the audited output-layer ones (`Gpu::audited_pipeline`), whose
    /// checks cost them a fourth of their time on an H200 (docs/gpu.md).
    #[default]
    Audited,
    /// Every kernel: to rule the unchecked ones out when a result looks wrong.
    All,
    /// No kernel: to measure what the checks cost.
    None,
}

impl std::str::FromStr for RuntimeChecks {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim() {
            "audited" => Ok(Self::Audited),
            "all" => Ok(Self::All),
            "none" => Ok(Self::None),
            other => Err(format!(
                "unknown runtime checks {other:?}: `audited`, `all` or `none`"
            )),
        }
    }
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

/// The recurrence's kernels (shapes come from a table at run time, so one set per workgroup
/// width serves every model).
#[derive(Debug)]
pub(crate) struct RecurrenceKernels {
    pub(crate) forward: wgpu::ComputePipeline,
    pub(crate) backward: wgpu::ComputePipeline,
    /// The weight gradients, one thread per weight over all of a network's windows: where
    /// the partial sums below do not fit one binding or dispatch.
    pub(crate) weights: wgpu::ComputePipeline,
    /// The weight gradients' partial sums, one thread per weight and window.
    pub(crate) weight_partials: wgpu::ComputePipeline,
    /// The partial sums added in window order.
    pub(crate) weights_reduce: wgpu::ComputePipeline,
}

/// Loads the recurrence kernels issue before their multiply-adds in each dot product
/// (`shaders/recurrence_dot.wgsl`), forward and backward: a step's phases are chains of
/// dependent loads. On an H200 (2026-12-01) the backward took 2.70 ms an iteration at 30
/// (one round trip per 30-long sum) against 3.03 at 8, the forward 1.44 ms at 8 against
/// 1.93 at 30; 4 loads both ways (the kernels before 2026-11-28) were slower still.
const RECURRENCE_LOADS: [usize; 2] = [8, 30];

/// The recurrence kernels' compiled shape: threads per workgroup, a step's loads issued at
/// its start.
type RecurrenceShape = (u32, bool);

/// The hidden read-out layers' kernels (shapes are parameters, so one set serves every
/// layer).
#[derive(Debug)]
pub(crate) struct DenseKernels {
    pub(crate) forward: wgpu::ComputePipeline,
    pub(crate) backward: wgpu::ComputePipeline,
    pub(crate) weights: wgpu::ComputePipeline,
    pub(crate) weights_reduce: wgpu::ComputePipeline,
}

/// Learning targets kept on the device: which observations, and how they were cut.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct ResidentKey {
    pub(crate) observations: u64,
    pub(crate) rows: usize,
    pub(crate) columns: usize,
    pub(crate) chunk_rows: usize,
}

/// Targets kept on the device, for every run that used them lately: several trainings or
/// inference runs may share one GPU (`pvrnn experiment --jobs N --backend wgpu`), and one
/// slot per modality would re-upload each run's targets whenever another ran in between.
#[derive(Debug, Default)]
pub(crate) struct ResidentTargets {
    entries: Vec<ResidentEntry>,
    /// Look-ups so far: the clock that says which entries are stale.
    clock: u64,
    uploads: u64,
}

#[derive(Debug)]
struct ResidentEntry {
    modality: usize,
    key: ResidentKey,
    chunks: Arc<Vec<wgpu::Buffer>>,
    /// The look-up clock and the time at its last use.
    last_used: u64,
    last_used_at: web_time::Instant,
}

impl ResidentTargets {
    /// An entry is freed once unused both for this many look-ups (of any run) and for
    /// [`Self::STALE_AFTER`]: a run that ended, an inference step's window a second after
    /// its step. Both, because look-ups alone would let a fast run (an online inference
    /// looks up about 2 x 50 times per step) evict a slow one's data between its
    /// iterations, and time alone would drop a lone slow run's data (a learning
    /// iteration on a CPU adapter takes seconds) when nothing else needs the room.
    const STALE_AFTER_LOOKUPS: u64 = 64;
    const STALE_AFTER: std::time::Duration = std::time::Duration::from_secs(1);
    /// At most this many entries (a run has one per modality on the GPU) stay, the least
    /// recently used going first.
    const MAX_ENTRIES: usize = 64;

    /// The targets under `key`, made by `upload` if they are not on the device.
    pub(crate) fn get_or_upload(
        &mut self,
        modality: usize,
        key: ResidentKey,
        upload: impl FnOnce() -> Vec<wgpu::Buffer>,
    ) -> Arc<Vec<wgpu::Buffer>> {
        self.clock += 1;
        let (now, now_at) = (self.clock, web_time::Instant::now());
        self.entries.retain(|e| {
            now - e.last_used <= Self::STALE_AFTER_LOOKUPS
                || now_at.duration_since(e.last_used_at) <= Self::STALE_AFTER
        });
        if let Some(e) = self
            .entries
            .iter_mut()
            .find(|e| e.modality == modality && e.key == key)
        {
            e.last_used = now;
            e.last_used_at = now_at;
            return e.chunks.clone();
        }
        while self.entries.len() >= Self::MAX_ENTRIES {
            let oldest = (0..self.entries.len())
                .min_by_key(|&i| self.entries[i].last_used)
                .unwrap_or(0);
            self.entries.swap_remove(oldest);
        }
        self.uploads += 1;
        let chunks = Arc::new(upload());
        self.entries.push(ResidentEntry {
            modality,
            key,
            chunks: chunks.clone(),
            last_used: now,
            last_used_at: now_at,
        });
        chunks
    }
}

/// An open GPU: device, queue and kernels, shared by every model loaded on it.
#[derive(Debug)]
pub struct Gpu {
    pub(crate) device: wgpu::Device,
    pub(crate) queue: wgpu::Queue,
    info: wgpu::AdapterInfo,
    kernels: Mutex<HashMap<RowPass, Arc<Kernels>>>,
    /// By (threads per workgroup, early loads); a few at most (a linear search: a map of
    /// its own costs the web site's download more than it saves).
    recurrence_kernels: Mutex<Vec<(RecurrenceShape, Arc<RecurrenceKernels>)>>,
    radam_kernel: OnceLock<Arc<wgpu::ComputePipeline>>,
    finite_check_kernel: OnceLock<Arc<wgpu::ComputePipeline>>,
    copy_kernel: OnceLock<Arc<wgpu::ComputePipeline>>,
    dense_kernels: OnceLock<Arc<DenseKernels>>,
    /// Targets kept on the device (learning's data, uploaded once per run; an inference
    /// step's window, once per step).
    pub(crate) resident: Mutex<ResidentTargets>,
    pool: Arc<BufferPool>,
    read_backs: AtomicU64,
    /// Runs' parts of learning iterations encoded (not replayed) so far.
    iterations_encoded: AtomicU64,
    /// Submissions' recurrence parts encoded (not replayed) so far.
    recurrence_parts_encoded: AtomicU64,
    /// Which kernels keep wgpu's runtime checks (see [`RuntimeChecks`]).
    checks: RuntimeChecks,
    /// Every kernel's label, for the profile's time per kernel.
    pub(crate) kernel_names: crate::kernel_names::KernelNames,
    /// The device's first failure outside an [`Gpu::allocating`] scope (see
    /// [`Gpu::failure`]).
    failed: Arc<Mutex<Option<String>>>,
}

impl Gpu {
    /// Opens an adapter and a device with the adapter's own limits (larger buffers than
    /// WebGPU's defaults where the hardware allows them), its kernels checked as `checks`
    /// says.
    #[cfg(not(target_arch = "wasm32"))]
    pub fn new(checks: RuntimeChecks) -> Result<Self, GpuError> {
        pollster::block_on(Self::open(checks))
    }

    /// [`Self::new`] without blocking: the only way in the browser, where the adapter and
    /// the device arrive through the event loop.
    pub async fn open(checks: RuntimeChecks) -> Result<Self, GpuError> {
        let adapter = adapter().await?;
        let info = adapter.get_info();
        let (device, queue) = adapter
            .request_device(&wgpu::DeviceDescriptor {
                label: Some("pvrnn"),
                required_limits: adapter.limits(),
                // For the profile's device times (`timing.rs`, native only), where the
                // adapter has them.
                required_features: if cfg!(target_arch = "wasm32") {
                    wgpu::Features::empty()
                } else {
                    adapter.features() & wgpu::Features::TIMESTAMP_QUERY
                },
                ..Default::default()
            })
            .await
            .map_err(|e| GpuError::NoDevice {
                adapter: info.name.clone(),
                reason: e.to_string(),
            })?;
        let failed = Arc::new(Mutex::new(None));
        device.on_uncaptured_error(Arc::new(failure_recorder(describe(&info), failed.clone())));
        Ok(Self {
            device,
            queue,
            info,
            kernels: Mutex::new(HashMap::new()),
            recurrence_kernels: Mutex::default(),
            radam_kernel: OnceLock::new(),
            finite_check_kernel: OnceLock::new(),
            copy_kernel: OnceLock::new(),
            dense_kernels: OnceLock::new(),
            resident: Mutex::new(ResidentTargets::default()),
            pool: Arc::default(),
            read_backs: AtomicU64::new(0),
            iterations_encoded: AtomicU64::new(0),
            recurrence_parts_encoded: AtomicU64::new(0),
            checks,
            kernel_names: Default::default(),
            failed,
        })
    }

    /// The device's first failure, if it has failed: running out of memory (or an internal
    /// error) in work that no checked allocation scope covers, such as a read-out's call
    /// on whatever thread evaluates, or a read-back that could not be made. From then on
    /// the device's results mean nothing: loaded models report this instead of them
    /// ([`pvrnn_core::assembled::DeviceHealth`]), and so do learners and checkpoints.
    pub fn failure(&self) -> Option<pvrnn_core::Error> {
        let failed = self.failed.lock().unwrap_or_else(|e| e.into_inner());
        failed.clone().map(pvrnn_core::Error::Device)
    }

    /// The slot [`Self::failure`] reads, for a read-back to record a failure in.
    pub(crate) fn failure_slot(&self) -> Arc<Mutex<Option<String>>> {
        self.failed.clone()
    }

    /// Runs `make`, work that allocates device memory, with running out of memory caught:
    /// an [`pvrnn_core::Error::Device`] saying what could not be done (`what`) on which
    /// adapter, instead of wgpu's uncaptured-error panic. A failed allocation leaves invalid
    /// buffers that the rest of `make` then touches: those validation errors are caught too
    /// (the inner scope). Every allocation of a learning run passes here: the resident
    /// buffers when its learners are made, the targets and scratch of its first iteration.
    pub(crate) fn allocating<T>(
        &self,
        what: impl FnOnce() -> String,
        make: impl FnOnce() -> T,
    ) -> pvrnn_core::Result<T> {
        let out_of_memory = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let invalid = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let made = make();
        let invalid = pvrnn_core::deferred::now(invalid.pop());
        let out_of_memory = pvrnn_core::deferred::now(out_of_memory.pop());
        let failed =
            |error: &wgpu::Error| format!("{} could not {} ({error})", self.describe(), what());
        match (out_of_memory, invalid) {
            (None, None) => Ok(made),
            (Some(error), _) => Err(pvrnn_core::Error::Device(format!(
                "{}: out of memory; train fewer networks at once (`--cohort` / `--networks`; docs/gpu.md gives the memory per network)",
                failed(&error)
            ))),
            (None, Some(error)) => Err(pvrnn_core::Error::Device(failed(&error))),
        }
    }

    /// "name (driver, API)".
    pub fn describe(&self) -> String {
        describe(&self.info)
    }

    /// Whether the adapter is a CPU implementation (lavapipe, SwiftShader, WARP): correct,
    /// but slower than the CPU backend, so not chosen unless asked for.
    pub fn is_cpu(&self) -> bool {
        is_cpu(&self.info)
    }

    /// Results read back from the device so far: how a caller (a test, a status line) sees
    /// that work really ran here.
    pub fn read_backs(&self) -> u64 {
        self.read_backs.load(Ordering::Relaxed)
    }

    /// Resident target sets uploaded so far (each modality's count separately): how a test
    /// sees that runs sharing the GPU keep their data there.
    pub fn resident_uploads(&self) -> u64 {
        self.resident.lock().map_or(0, |r| r.uploads)
    }

    /// Device memory held by buffers now, in bytes, as wgpu's allocation counter gives it
    /// (the resident weights, data and moments, and the pool's reusable buffers); `None`
    /// where the platform does not count (WebGPU).
    pub fn buffer_memory(&self) -> Option<u64> {
        let bytes = self.device.get_internal_counters().hal.buffer_memory.read();
        (bytes > 0).then_some(bytes as u64)
    }

    /// Whether the device has timestamp queries (the profile's device times, `timing.rs`).
    pub fn has_timestamps(&self) -> bool {
        self.device
            .features()
            .contains(wgpu::Features::TIMESTAMP_QUERY)
    }

    /// Waits until the device has run everything submitted so far, and with it every
    /// callback of a mapping (the profile's device times arrive in those).
    #[cfg(not(target_arch = "wasm32"))]
    pub fn wait_idle(&self) -> Result<(), GpuError> {
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map(drop)
            .map_err(|e| GpuError::Wait {
                adapter: self.info.name.clone(),
                reason: e.to_string(),
            })
    }

    /// A run's part of a whole learning iteration on the device encoded so far, not
    /// replayed: how a test sees that iterations replay.
    pub fn iterations_encoded(&self) -> u64 {
        self.iterations_encoded.load(Ordering::Relaxed)
    }

    pub(crate) fn count_iteration_encoded(&self) {
        self.iterations_encoded.fetch_add(1, Ordering::Relaxed);
    }

    /// A submission's recurrence part (the windows' table, the recurrence's dispatches and
    /// the weight gradients of its runs) encoded so far, not replayed.
    pub fn recurrence_parts_encoded(&self) -> u64 {
        self.recurrence_parts_encoded.load(Ordering::Relaxed)
    }

    pub(crate) fn count_recurrence_part_encoded(&self) {
        self.recurrence_parts_encoded
            .fetch_add(1, Ordering::Relaxed);
    }

    pub(crate) fn count_read_back(&self) {
        self.read_backs.fetch_add(1, Ordering::Relaxed);
    }

    pub(crate) fn limits(&self) -> wgpu::Limits {
        self.device.limits()
    }

    /// A storage buffer holding `data` (written at the next submission), from the pool:
    /// f32 values, or 32-bit words (tables of shapes and offsets).
    pub(crate) fn upload<P: bytemuck::Pod>(&self, label: &str, data: &[P]) -> PooledBuffer {
        let words = std::mem::size_of_val(data).div_ceil(4);
        let buffer = self.scratch(label, words, wgpu::BufferUsages::empty());
        if !data.is_empty() {
            self.queue
                .write_buffer(&buffer, 0, bytemuck::cast_slice(data));
        }
        buffer
    }

    /// A long-lived buffer (not pooled) holding `data`, written at the next submission.
    /// Not `create_buffer_init`: when the device is out of memory that maps an invalid
    /// buffer and panics inside wgpu, where this leaves an error for [`Gpu::allocating`]'s
    /// scope to report.
    pub(crate) fn filled<P: bytemuck::Pod>(
        &self,
        label: &str,
        data: &[P],
        usage: wgpu::BufferUsages,
    ) -> wgpu::Buffer {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        let buffer = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: (bytes.len() as u64).next_multiple_of(wgpu::COPY_BUFFER_ALIGNMENT),
            usage: usage | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        if !bytes.is_empty() {
            self.queue.write_buffer(&buffer, 0, bytes);
        }
        buffer
    }

    /// A storage buffer of `floats` values whose contents are undefined (the pool's last
    /// user's): for results the kernels write before anything reads them.
    pub(crate) fn scratch(
        &self,
        label: &str,
        floats: usize,
        extra: wgpu::BufferUsages,
    ) -> PooledBuffer {
        self.pool.take(
            &self.device,
            label,
            4 * floats as u64,
            wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST | extra,
        )
    }

    /// A uniform buffer holding `params`.
    pub(crate) fn uniform<P: bytemuck::Pod>(&self, params: &P) -> PooledBuffer {
        let bytes = bytemuck::bytes_of(params);
        let buffer = self.pool.take(
            &self.device,
            "params",
            bytes.len() as u64,
            wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        );
        self.queue.write_buffer(&buffer, 0, bytes);
        buffer
    }

    /// A mappable buffer of `floats` values for reading results back.
    pub(crate) fn staging(&self, floats: usize) -> PooledBuffer {
        self.pool.take(
            &self.device,
            "read back",
            4 * floats as u64,
            wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        )
    }

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

    /// The recurrence's kernels with `threads` per window's workgroup
    /// (`RecurrenceLayout::threads`), [`RECURRENCE_LOADS`] in flight per dot product and a
    /// step's loads issued at its start where the width allows (`early`,
    /// `Tiling::recurrence_early_loads`), compiled on first use.
    pub(crate) fn recurrence_kernels(&self, threads: u32, early: bool) -> Arc<RecurrenceKernels> {
        let [forward_loads, backward_loads] = RECURRENCE_LOADS;
        let mut compiled = self
            .recurrence_kernels
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        let shape = (threads, early);
        if let Some((_, kernels)) = compiled.iter().find(|(key, _)| *key == shape) {
            return kernels.clone();
        }
        let kernels = {
            let common = shader!("recurrence_common.wgsl");
            let weights = shader!("recurrence_weights.wgsl");
            // A kernel's source: the common part, its own, and its dot products
            // (`recurrence_dot.wgsl` once per function name, weights and values); PARTIALS
            // picks the weight-gradient kernel's form (1: a partial sum per window).
            let source = |text: &str, dots: &[[&str; 3]], partials: usize, loads: usize| {
                let mut full = format!("{common}\n{text}");
                for [name, weights, values] in dots {
                    let dot = shader!("recurrence_dot.wgsl");
                    full.push('\n');
                    full.push_str(
                        &dot.replace("DOT", name)
                            .replace("WEIGHTS", weights)
                            .replace("VALUES", values),
                    );
                }
                crate::template::expand(
                    &full,
                    &[
                        ("WG", threads as usize),
                        ("LOADS", loads),
                        ("PARTIALS", partials),
                        ("EARLY", usize::from(early)),
                    ],
                )
            };
            Arc::new(RecurrenceKernels {
                forward: self.pipeline(
                    "recurrence forward",
                    source(
                        shader!("recurrence_forward.wgsl"),
                        &[
                            ["dot_d_prev", "weights_t", "d_prev"],
                            ["dot_zs", "weights_t", "zs"],
                        ],
                        0,
                        forward_loads,
                    ),
                ),
                backward: self.pipeline(
                    "recurrence backward",
                    source(
                        shader!("recurrence_backward.wgsl"),
                        &[
                            ["dot_gu", "weights", "gu"],
                            ["dot_gprior", "weights", "gprior"],
                        ],
                        0,
                        backward_loads,
                    ),
                ),
                // No dot products: LOADS is unused there.
                weights: self.pipeline("recurrence weights", source(weights, &[], 0, 1)),
                weight_partials: self
                    .pipeline("recurrence weight partials", source(weights, &[], 1, 1)),
                weights_reduce: self.pipeline(
                    "recurrence weights reduce",
                    shader!("recurrence_weights_reduce.wgsl").into(),
                ),
            })
        };
        compiled.push((shape, kernels.clone()));
        kernels
    }

    /// The RAdam update of a resident tensor (`shaders/radam.wgsl`), compiled on first use.
    pub(crate) fn radam_kernel(&self) -> Arc<wgpu::ComputePipeline> {
        self.compiled_once(&self.radam_kernel, "radam", shader!("radam.wgsl"))
    }

    /// The divergence mark of a learning run (`shaders/finite_check.wgsl`), compiled on
    /// first use.
    pub(crate) fn finite_check_kernel(&self) -> Arc<wgpu::ComputePipeline> {
        let source = shader!("finite_check.wgsl");
        self.compiled_once(&self.finite_check_kernel, "finite check", source)
    }

    /// The strided copy between layouts (`shaders/strided_copy.wgsl`), compiled on first use.
    pub(crate) fn copy_kernel(&self) -> Arc<wgpu::ComputePipeline> {
        let source = shader!("strided_copy.wgsl");
        self.compiled_once(&self.copy_kernel, "strided copy", source)
    }

    /// A one-kernel shader kept in `cell`, compiled at its first use.
    fn compiled_once(
        &self,
        cell: &OnceLock<Arc<wgpu::ComputePipeline>>,
        label: &'static str,
        source: &str,
    ) -> Arc<wgpu::ComputePipeline> {
        cell.get_or_init(|| Arc::new(self.pipeline(label, source.into())))
            .clone()
    }

    /// The hidden read-out layers' kernels, compiled on first use.
    pub(crate) fn dense_kernels(&self) -> Arc<DenseKernels> {
        self.dense_kernels
            .get_or_init(|| {
                Arc::new(DenseKernels {
                    forward: self.pipeline("dense forward", shader!("dense_forward.wgsl").into()),
                    backward: self
                        .pipeline("dense backward", shader!("dense_backward.wgsl").into()),
                    weights: self.pipeline("dense weights", shader!("dense_weights.wgsl").into()),
                    weights_reduce: self.pipeline(
                        "dense weights reduce",
                        shader!("dense_weights_reduce.wgsl").into(),
                    ),
                })
            })
            .clone()
    }

    /// `source` compiled with wgpu's runtime checks (bounds, loop bounding, division),
    /// unless [`RuntimeChecks::None`].
    fn pipeline(&self, label: &'static str, source: String) -> wgpu::ComputePipeline {
        self.compile_pipeline(label, source, self.checks == RuntimeChecks::None)
    }

    /// `source` compiled without wgpu's runtime checks, unless [`RuntimeChecks::All`]:
    /// for the output-layer kernels only (fused and blocked), whose every index is bounded by the shapes
    /// the host sized their buffers with (see their sources). The checks cost them a fourth
    /// of their time on an H200 (docs/gpu.md).
    fn audited_pipeline(&self, label: &'static str, source: String) -> wgpu::ComputePipeline {
        self.compile_pipeline(label, source, self.checks != RuntimeChecks::All)
    }

    #[allow(unsafe_code)] // trusted shader modules: see the SAFETY note
    fn compile_pipeline(
        &self,
        label: &'static str,
        source: String,
        unchecked: bool,
    ) -> wgpu::ComputePipeline {
        let descriptor = wgpu::ShaderModuleDescriptor {
            label: Some(label),
            source: wgpu::ShaderSource::Wgsl(source.into()),
        };
        let module = if unchecked {
            // SAFETY: by default only the output-layer kernels (`audited_pipeline`):
            // every index they form is bounded by the row, column and split counts the host
            // sized their buffers and dispatches with (dead threads read index 0 and write
            // nothing; tile indices stay below the tile sizes, which are multiples of the
            // steps), their loops are bounded by uniform counts and their divisors are
            // nonzero constants. Every kernel only with `RuntimeChecks::None`, which is for
            // measuring what the checks cost. The browser's WebGPU checks regardless.
            unsafe {
                self.device.create_shader_module_trusted(
                    descriptor,
                    wgpu::ShaderRuntimeChecks::unchecked(),
                )
            }
        } else {
            self.device.create_shader_module(descriptor)
        };
        let pipeline = self
            .device
            .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(label),
                layout: None,
                module: &module,
                entry_point: Some("main"),
                compilation_options: Default::default(),
                cache: None,
            });
        self.kernel_names.register(&pipeline, label);
        pipeline
    }
}

/// An output-layer kernel's source, expanded, after the helpers they share.
fn output_source(text: &str, constants: &[(&str, usize)]) -> String {
    let common = shader!("output_common.wgsl");
    crate::template::expand(&format!("{common}\n{text}"), constants)
}

/// The adapter [`Gpu::open`] takes: Vulkan, Metal, DX12 (and WebGPU) unless `WGPU_BACKEND`
/// says otherwise (OpenGL has no use for compute here, and probing it through EGL beside
/// eframe's own GL context panics inside wgpu-hal: BadAccess in make_current, seen under
/// Xvfb); `WGPU_ADAPTER_NAME` picks one by name.
async fn adapter() -> Result<wgpu::Adapter, GpuError> {
    let mut descriptor = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
    descriptor.backends = wgpu::Backends::from_env().unwrap_or(wgpu::Backends::PRIMARY);
    let instance = wgpu::Instance::new(descriptor);
    wgpu::util::initialize_adapter_from_env_or_default(&instance, None)
        .await
        .map_err(|e| GpuError::NoAdapter(e.to_string()))
}

/// What [`Gpu::open`] would open, without opening a device: a cheap look at the machine
/// (the explorer picks its renderer with it) as `(its description, whether it is a CPU
/// implementation)`.
pub async fn probe() -> Result<(String, bool), GpuError> {
    let info = adapter().await?.get_info();
    Ok((describe(&info), is_cpu(&info)))
}

/// [`probe`], blocking.
#[cfg(not(target_arch = "wasm32"))]
pub fn probe_now() -> Result<(String, bool), GpuError> {
    pollster::block_on(probe())
}

fn is_cpu(info: &wgpu::AdapterInfo) -> bool {
    info.device_type == wgpu::DeviceType::Cpu
}

fn describe(i: &wgpu::AdapterInfo) -> String {
    // Browsers may withhold the adapter's name.
    let name = if i.name.trim().is_empty() {
        "unnamed adapter"
    } else {
        i.name.as_str()
    };
    let driver = [i.driver.as_str(), i.driver_info.as_str()]
        .into_iter()
        .filter(|s| !s.is_empty())
        .collect::<Vec<_>>()
        .join(" ");
    if driver.is_empty() {
        format!("{name} ({:?})", i.backend)
    } else {
        format!("{name} ({driver}, {:?})", i.backend)
    }
}

/// wgpu's handler of the errors no scope caught. Running out of memory (or an internal
/// error) is recorded as the device's failure ([`Gpu::failure`]), not wgpu's default panic;
/// the validation errors that follow it (work binding the buffers it left invalid) are its
/// consequence. A validation error with no failure before it is a kernel or a binding this
/// crate got wrong: a bug, which panics as wgpu's default handler does.
fn failure_recorder(
    adapter: String,
    failed: Arc<Mutex<Option<String>>>,
) -> impl Fn(wgpu::Error) + Send + Sync + 'static {
    move |error| {
        let already = failed.lock().map_or(true, |f| f.is_some());
        match error {
            wgpu::Error::Validation { .. } if !already => panic!("wgpu error: {error}"),
            wgpu::Error::OutOfMemory { .. } => record_failure(
                &failed,
                format!(
                    "{adapter}: out of memory ({error}); evaluate or train fewer networks at \
                     once, or use `--backend cpu` (docs/gpu.md gives the memory per network)"
                ),
            ),
            _ => record_failure(&failed, format!("{adapter}: {error}")),
        }
    }
}

/// Keeps the first failure only: those after it are its consequences.
pub(crate) fn record_failure(failed: &Mutex<Option<String>>, why: String) {
    let mut failed = failed.lock().unwrap_or_else(|e| e.into_inner());
    if failed.is_none() {
        *failed = Some(why);
    }
}

impl pvrnn_core::assembled::DeviceHealth for Gpu {
    fn failure(&self) -> Option<pvrnn_core::Error> {
        Gpu::failure(self)
    }
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

    /// An out-of-memory no scope catches (a read-out's call on whatever thread evaluates)
    /// is the device's failure: wgpu's handler records it instead of panicking, the
    /// validation errors it causes are taken as its consequence, and every later
    /// evaluation, learning step and checkpoint on the device fails naming it. A real one
    /// is provoked in the CLI's tests (`a_read_out_the_device_memory_cannot_hold_is_a_clear_error`).
    #[test]
    fn a_failure_no_scope_catches_fails_every_later_evaluation_and_checkpoint() {
        use pvrnn_core::backend::Backend;
        use pvrnn_core::config::{ModuleConfig, VisionLayout};
        use pvrnn_core::free_energy::{NoiseDraw, free_energy};
        use pvrnn_core::noise::NoiseMode;
        use pvrnn_core::{Model, ModelConfig, Observations, Tensor, train::Trainer};

        let gpu = match Gpu::new(RuntimeChecks::default()) {
            Ok(gpu) => Arc::new(gpu),
            Err(e) if std::env::var_os("PVRNN_SKIP_WGPU").is_some() => {
                eprintln!("skipped (PVRNN_SKIP_WGPU): {e}");
                return;
            }
            Err(e) => panic!("{e}"),
        };
        let backend = crate::WgpuBackend::on(gpu.clone(), crate::WgpuOptions::default());
        let mut config = ModelConfig::default();
        let module = |d, z| ModuleConfig {
            d,
            z,
            tau: [2.0, 4.0],
        };
        config.executive = module(4, 2);
        config.associative = module(4, 2);
        config.exteroceptive = module(6, 3);
        config.proprioceptive = module(4, 2);
        config.exteroceptive_readout.hidden = vec![8];
        config.proprioceptive_readout.hidden = vec![6];
        config.vision = VisionLayout {
            cameras: 1,
            channels: 3,
            resolutions: vec![4],
        };
        config.proprio_dims = 4;
        let (sequences, steps) = (2, 5);
        let (vision, proprio) = (config.vision.dims(), config.proprio_dims);
        let data: Observations<f32> = Observations::new(
            Tensor::from_vec(
                &[sequences, steps, vision],
                vec![0.1; sequences * steps * vision],
            )
            .unwrap(),
            Tensor::from_vec(
                &[sequences, steps, proprio],
                vec![-0.2; sequences * steps * proprio],
            )
            .unwrap(),
            None,
        )
        .unwrap();
        let model = Model::init_on(&backend, config, sequences, steps, 7).unwrap();
        let noise = NoiseDraw::evaluation(NoiseMode::Zero);
        assert!(free_energy(&backend, &model, &data, noise, true).is_ok());
        let mut trainer =
            Trainer::new_on(Box::new(backend.clone()), model.clone(), NoiseMode::Zero);
        trainer.step(&data).unwrap();
        let checkpoint = std::env::temp_dir().join(format!(
            "pvrnn-device-failure-{}.safetensors",
            std::process::id()
        ));
        pvrnn_core::io::save_checkpoint(&checkpoint, &mut trainer, None).unwrap();
        let before = std::fs::read(&checkpoint).unwrap();

        let handler = failure_recorder(gpu.describe(), gpu.failure_slot());
        let source = || Box::new(std::io::Error::other("no memory left")) as wgpu::ErrorSource;
        handler(wgpu::Error::OutOfMemory { source: source() });
        // Work binding what the failure left invalid: its consequence, not a panic.
        handler(wgpu::Error::Validation {
            source: source(),
            description: "a buffer is invalid".into(),
        });
        let failure = gpu.failure().expect("the failure is recorded").to_string();
        assert!(
            failure.contains("out of memory") && failure.contains(&gpu.describe()),
            "{failure}"
        );
        let names_it = |result: pvrnn_core::Result<()>, what: &str| match result {
            Err(e) => assert_eq!(e.to_string(), failure, "{what}"),
            Ok(()) => panic!("{what} succeeded on a failed device"),
        };
        names_it(
            free_energy(&backend, &model, &data, noise, true).map(|_| ()),
            "an evaluation",
        );
        let loaded = backend.load(&model.params, &model.config);
        names_it(
            loaded
                .readout(pvrnn_core::Modality::Proprioceptive, &[0.0; 4], 1)
                .map(|_| ()),
            "a read-out",
        );
        names_it(trainer.step(&data).map(|_| ()), "a learning step");
        names_it(
            pvrnn_core::io::save_checkpoint(&checkpoint, &mut trainer, None),
            "a checkpoint",
        );
        assert_eq!(
            std::fs::read(&checkpoint).unwrap(),
            before,
            "the last checkpoint stays"
        );
        std::fs::remove_file(&checkpoint).ok();

        // A validation error with no failure before it is a bug in this crate: it panics,
        // as wgpu's own handler does.
        let fresh = failure_recorder(gpu.describe(), Arc::default());
        let bug = std::panic::catch_unwind(|| {
            fresh(wgpu::Error::Validation {
                source: source(),
                description: "a kernel got wrong".into(),
            })
        });
        assert!(bug.is_err());
    }

    /// A buffer over the device's size limit stands in for one that does not fit its
    /// memory (lavapipe allocates host memory, which a test cannot exhaust): both leave an
    /// invalid buffer whose later uses fail validation too.
    #[test]
    fn allocations_the_device_refuses_are_an_error_naming_what_failed() {
        let gpu = match Gpu::new(RuntimeChecks::default()) {
            Ok(gpu) => gpu,
            Err(e) if std::env::var_os("PVRNN_SKIP_WGPU").is_some() => {
                eprintln!("skipped (PVRNN_SKIP_WGPU): {e}");
                return;
            }
            Err(e) => panic!("{e}"),
        };
        let small = gpu.allocating(
            || "make a small buffer".into(),
            || gpu.scratch("small", 16, wgpu::BufferUsages::empty()),
        );
        assert!(small.is_ok());
        let too_large = gpu.device.limits().max_buffer_size.saturating_add(4);
        let refused = gpu.allocating(
            || "make a buffer too large".into(),
            || {
                let buffer = gpu.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("too large"),
                    size: too_large,
                    usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                });
                gpu.queue.write_buffer(&buffer, 0, &[0; 4]);
                buffer
            },
        );
        match refused {
            Err(pvrnn_core::Error::Device(message)) => {
                assert!(
                    message.contains("could not make a buffer too large")
                        && message.contains(&gpu.describe()),
                    "{message}"
                );
            }
            other => panic!("expected a device error, got {other:?}"),
        }
        // The device is still usable.
        let after = gpu.allocating(
            || "make a small buffer".into(),
            || gpu.scratch("small", 16, wgpu::BufferUsages::empty()),
        );
        assert!(after.is_ok());
    }
}
