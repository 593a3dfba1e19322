// Copies a strided block of values between two buffers: for b < blocks, r < rows, c < width,
//   dst[dst_offset + b dst_block + r dst_row + c] = src[src_offset + b src_block + r src_row + c].
// How the device-resident learning iteration moves values between the layouts of its
// kernels without a round trip: adaptive variables and eps into the recurrence's inputs,
// module states out of its record into the read-outs, their gradients back, d F / d a out
// to the adaptive variables' gradients, and (width 1) the recurrent matrices transposed
// for the forward kernel. One thread per value.

struct Params {
    blocks: u32,
    rows: u32,
    width: u32,
    groups_x: u32,     // workgroups per row of the dispatch grid
    src_offset: u32,
    src_block: u32,
    src_row: u32,
    _pad0: u32,
    dst_offset: u32,
    dst_block: u32,
    dst_row: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> src: array<f32>;
@group(0) @binding(2) var<storage, read_write> dst: array<f32>;

@compute @workgroup_size(64)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) t: u32) {
    let i = (wg.y * p.groups_x + wg.x) * 64u + t;
    let per_block = p.rows * p.width;
    if (i >= p.blocks * per_block) {
        return;
    }
    let b = i / per_block;
    let r = (i % per_block) / p.width;
    let c = i % p.width;
    dst[p.dst_offset + b * p.dst_block + r * p.dst_row + c] =
        src[p.src_offset + b * p.src_block + r * p.src_row + c];
}
