//! The device's own time per part of a submission, while profiling is on (`pvrnn bench
//! --profile`): each part runs in its own compute pass with a timestamp at its start and
//! end (wgpu's `TIMESTAMP_QUERY`), and the differences are added to the profile as
//! "device: ..." phases when the device has run them. The host's phases say how long the
//! host waited; these say which kernels the device spent that time in.
//!
//! Off (and the parts in one pass, as without profiling) where the device has no
//! timestamps, and in the browser (profiling is native only; leaving the queries out keeps
//! the site's download as it was). A pass boundary lets the driver drain the work before it, so the parts add
//! up to a little more than the one pass they replace.

use crate::gpu::Gpu;

/// A submission's timed passes: the profile's phases each adds its time to (a part, and
/// with `WgpuOptions::profile_kernels` its kernel too), the queries, and where they are
/// resolved.
#[cfg(not(target_arch = "wasm32"))]
pub(crate) struct PassTimes {
    names: Vec<Vec<&'static str>>,
    queries: wgpu::QuerySet,
    resolved: wgpu::Buffer,
    staging: wgpu::Buffer,
}

#[cfg(not(target_arch = "wasm32"))]
impl PassTimes {
    /// Queries for `names` (one part each, in the order their passes will be begun);
    /// `None` unless profiling is on and `gpu` has timestamps.
    pub(crate) fn new(gpu: &Gpu, names: &[&'static str]) -> Option<Self> {
        Self::adding_to(gpu, names.iter().map(|&name| vec![name]).collect())
    }

    /// Queries for one pass per entry of `names`, each pass's time added to every phase
    /// its entry names; `None` unless profiling is on and `gpu` has timestamps.
    pub(crate) fn adding_to(gpu: &Gpu, names: Vec<Vec<&'static str>>) -> Option<Self> {
        if !pvrnn_core::profile::enabled() || !gpu.has_timestamps() || names.is_empty() {
            return None;
        }
        let count = 2 * names.len() as u32;
        let bytes = u64::from(count) * 8;
        let buffer = |label, usage| {
            gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: bytes,
                usage,
                mapped_at_creation: false,
            })
        };
        Some(Self {
            names,
            queries: gpu.device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("pass timestamps"),
                ty: wgpu::QueryType::Timestamp,
                count,
            }),
            resolved: buffer(
                "pass timestamps, resolved",
                wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
            ),
            staging: buffer(
                "pass timestamps, read back",
                wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            ),
        })
    }

    /// The timestamp writes of part `part`'s pass.
    pub(crate) fn writes(&self, part: usize) -> wgpu::ComputePassTimestampWrites<'_> {
        wgpu::ComputePassTimestampWrites {
            query_set: &self.queries,
            beginning_of_pass_write_index: Some(2 * part as u32),
            end_of_pass_write_index: Some(2 * part as u32 + 1),
        }
    }

    /// Resolves the timestamps after every part's pass in `encoder`; once that is
    /// submitted, [`Self::collect`] adds them to the profile.
    pub(crate) fn resolve(&self, encoder: &mut wgpu::CommandEncoder) {
        let count = 2 * self.names.len() as u32;
        encoder.resolve_query_set(&self.queries, 0..count, &self.resolved, 0);
        encoder.copy_buffer_to_buffer(&self.resolved, 0, &self.staging, 0, u64::from(count) * 8);
    }

    /// Adds each part's device time to the profile when the submitted work has run (at a
    /// later wait for the device: the next read-back, or [`Gpu::wait_idle`]).
    pub(crate) fn collect(self, gpu: &Gpu) {
        let period_ns = f64::from(gpu.queue.get_timestamp_period());
        let Self { names, staging, .. } = self;
        let mapped = staging.clone();
        staging
            .slice(..)
            .map_async(wgpu::MapMode::Read, move |result| {
                if result.is_err() {
                    return;
                }
                // A failed mapping loses this sample of the profile, nothing else.
                if let Ok(bytes) = mapped.slice(..).get_mapped_range() {
                    let ticks: Vec<u64> = bytes
                        .chunks_exact(8)
                        .map(|b| {
                            let mut word = [0u8; 8];
                            word.copy_from_slice(b);
                            u64::from_le_bytes(word)
                        })
                        .collect();
                    for (phases, pair) in names.iter().zip(ticks.chunks_exact(2)) {
                        let seconds = pair[1].saturating_sub(pair[0]) as f64 * period_ns * 1e-9;
                        for name in phases {
                            pvrnn_core::profile::add(name, seconds);
                        }
                    }
                }
                mapped.unmap();
            });
    }
}

/// In the browser: never made (profiling is native only).
#[cfg(target_arch = "wasm32")]
pub(crate) enum PassTimes {}

#[cfg(target_arch = "wasm32")]
impl PassTimes {
    pub(crate) fn new(_gpu: &Gpu, _names: &[&'static str]) -> Option<Self> {
        None
    }

    pub(crate) fn adding_to(_gpu: &Gpu, _names: Vec<Vec<&'static str>>) -> Option<Self> {
        None
    }

    pub(crate) fn writes(&self, _part: usize) -> wgpu::ComputePassTimestampWrites<'_> {
        match *self {}
    }

    pub(crate) fn resolve(&self, _encoder: &mut wgpu::CommandEncoder) {
        match *self {}
    }

    pub(crate) fn collect(self, _gpu: &Gpu) {
        match self {}
    }
}

/// Begins part `part`'s compute pass: timed when `times` is `Some`.
pub(crate) fn begin_pass<'e>(
    encoder: &'e mut wgpu::CommandEncoder,
    times: Option<&PassTimes>,
    part: usize,
) -> wgpu::ComputePass<'e> {
    encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
        label: None,
        timestamp_writes: times.map(|t| t.writes(part)),
    })
}
