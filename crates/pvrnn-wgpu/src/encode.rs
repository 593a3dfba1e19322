//! What every kernel's host side shares: bind groups, dispatches recorded straight into
//! an encoder or into a list to replay, the grid of a flat kernel, and the kernels' row
//! layout (rows zero-padded to whole vec4s).

use crate::gpu::Gpu;

/// Threads per workgroup of every kernel; rows per workgroup of `loss_rows.wgsl`, columns
/// per workgroup of `loss_columns.wgsl`.
pub(crate) const WORKGROUP: usize = 64;

/// Hidden widths whose registers (two rows of width/4 vec4s per thread) the kernels are
/// written for.
pub(crate) const MAX_HIDDEN: usize = 64;

/// Hidden width in vec4s: rows of weights and activations are zero-padded to it.
pub(crate) fn vec4s(hidden: usize) -> usize {
    hidden.div_ceil(4)
}

/// Whether the kernels hold an output layer of this shape.
pub(crate) fn fits(dims: usize, hidden: usize) -> bool {
    hidden > 0 && hidden <= MAX_HIDDEN && dims > 0
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

/// Where kernels' dispatches go: straight into a command encoder (a compute pass each), or
/// into a [`DispatchList`] to replay, the same dispatches many times over (online
/// inference's updates: bind groups and passes cost the host more than the small kernels).
pub(crate) trait Recorder {
    fn record(&mut self, pipeline: &wgpu::ComputePipeline, group: &wgpu::BindGroup, x: u32, y: u32);
}

impl Recorder for wgpu::CommandEncoder {
    fn record(
        &mut self,
        pipeline: &wgpu::ComputePipeline,
        group: &wgpu::BindGroup,
        x: u32,
        y: u32,
    ) {
        let mut pass = self.begin_compute_pass(&wgpu::ComputePassDescriptor::default());
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, group, &[]);
        pass.dispatch_workgroups(x, y, 1);
    }
}

/// Dispatches recorded once and replayed into compute passes (see [`Recorder`]).
#[derive(Debug, Default)]
pub(crate) struct DispatchList {
    dispatches: Vec<(wgpu::ComputePipeline, wgpu::BindGroup, u32, u32)>,
}

impl Recorder for DispatchList {
    fn record(
        &mut self,
        pipeline: &wgpu::ComputePipeline,
        group: &wgpu::BindGroup,
        x: u32,
        y: u32,
    ) {
        self.dispatches
            .push((pipeline.clone(), group.clone(), x, y));
    }
}

impl DispatchList {
    /// Every recorded dispatch, in order, into `pass` (wgpu orders each after the ones
    /// whose results it reads).
    pub(crate) fn replay(&self, pass: &mut wgpu::ComputePass<'_>) {
        for (pipeline, group, x, y) in &self.dispatches {
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, group, &[]);
            pass.dispatch_workgroups(*x, *y, 1);
        }
    }

    /// The recorded dispatches' kernels, in order.
    pub(crate) fn kernels(&self) -> impl Iterator<Item = &wgpu::ComputePipeline> {
        self.dispatches.iter().map(|(pipeline, ..)| pipeline)
    }

    /// How many dispatches are recorded.
    pub(crate) fn len(&self) -> usize {
        self.dispatches.len()
    }

    /// Recorded dispatch `index` alone into `pass` (for timing each apart).
    pub(crate) fn replay_one(&self, index: usize, pass: &mut wgpu::ComputePass<'_>) {
        if let Some((pipeline, group, x, y)) = self.dispatches.get(index) {
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, group, &[]);
            pass.dispatch_workgroups(*x, *y, 1);
        }
    }
}

pub(crate) fn dispatch(
    recorder: &mut (impl Recorder + ?Sized),
    pipeline: &wgpu::ComputePipeline,
    group: &wgpu::BindGroup,
    x: u32,
    y: u32,
) {
    recorder.record(pipeline, group, x, y);
}

/// The row losses, 1/2 (1 / divisor) sum (x - x^)^2 as `OutputLoss::row_loss`, from the
/// kernels' per-row sums of squared errors.
pub(crate) fn row_losses(sums: Vec<f32>, divisor: usize) -> Vec<f64> {
    let half_over_divisor = 0.5 / divisor as f64;
    sums.into_iter()
        .map(|s| s as f64 * half_over_divisor)
        .collect()
}

/// A 2-D grid of 64-thread workgroups covering `threads` (a kernel's flat index is
/// `(wg.y * groups_x + wg.x) * 64 + t`).
pub(crate) fn grid(gpu: &Gpu, threads: usize) -> (u32, u32) {
    let groups = threads.div_ceil(WORKGROUP).max(1);
    let max = gpu.limits().max_compute_workgroups_per_dimension as usize;
    let x = groups.min(max);
    (x as u32, groups.div_ceil(x) as u32)
}
