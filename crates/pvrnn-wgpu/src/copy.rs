//! Moving values between the kernels' layouts on the device (`shaders/strided_copy.wgsl`),
//! so that a learning iteration that keeps everything there never reshapes on the host.

use bytemuck::{Pod, Zeroable};

use crate::encode::{Recorder, bind, dispatch, grid};
use crate::gpu::Gpu;
use crate::pool::PooledBuffer;

/// Where values sit in a buffer: the first one, and the steps between blocks and rows.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Strided {
    pub(crate) offset: usize,
    pub(crate) block: usize,
    pub(crate) row: usize,
}

impl Strided {
    /// Rows `row` apart from `offset` (one block).
    pub(crate) fn rows(offset: usize, row: usize) -> Self {
        Self {
            offset,
            block: 0,
            row,
        }
    }
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct CopyParams {
    blocks: u32,
    rows: u32,
    width: u32,
    groups_x: u32,
    src_offset: u32,
    src_block: u32,
    src_row: u32,
    _pad0: u32,
    dst_offset: u32,
    dst_block: u32,
    dst_row: u32,
    _pad1: u32,
}

/// Encodes `blocks` x `rows` rows of `width` values from `src` (at `from`) to `dst` (at
/// `to`); the uniform it uses goes into `keep` until the submission has run.
#[allow(clippy::too_many_arguments)]
pub(crate) fn encode_copy(
    gpu: &Gpu,
    encoder: &mut dyn Recorder,
    src: &wgpu::Buffer,
    from: Strided,
    dst: &wgpu::Buffer,
    to: Strided,
    [blocks, rows, width]: [usize; 3],
    keep: &mut Vec<PooledBuffer>,
) {
    let count = blocks * rows * width;
    if count == 0 {
        return;
    }
    let kernel = gpu.copy_kernel();
    let (groups_x, groups_y) = grid(gpu, count);
    let params = gpu.uniform(&CopyParams {
        blocks: blocks as u32,
        rows: rows as u32,
        width: width as u32,
        groups_x,
        src_offset: from.offset as u32,
        src_block: from.block as u32,
        src_row: from.row as u32,
        _pad0: 0,
        dst_offset: to.offset as u32,
        dst_block: to.block as u32,
        dst_row: to.row as u32,
        _pad1: 0,
    });
    let group = bind(gpu, &kernel, &[&params, src, dst]);
    dispatch(encoder, &kernel, &group, groups_x, groups_y);
    keep.push(params);
}
