// Marks a learning run as diverged when one of its free-energy terms (KL terms, row
// losses) is not finite, NaN or infinite (every exponent bit set), which is when the host
// finds the summed free energy not finite: the run's RAdam updates (`radam.wgsl`) read
// the mark and skip, so that an update queued before the host has read the free energy
// back never applies a diverged iteration's gradients. Each evaluation clears the mark
// first (`DeviceIteration::clear`). One thread per term.

struct Params {
    count: u32,     // terms
    groups_x: u32,  // workgroups per row of the dispatch grid
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> terms: array<f32>;
@group(0) @binding(2) var<storage, read_write> diverged: array<atomic<u32>>;

@compute @workgroup_size(64)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) t: u32) {
    let e = (wg.y * p.groups_x + wg.x) * 64u + t;
    if (e >= p.count) {
        return;
    }
    if ((bitcast<u32>(terms[e]) & 0x7f800000u) == 0x7f800000u) {
        atomicOr(&diverged[0], 1u);
    }
}
