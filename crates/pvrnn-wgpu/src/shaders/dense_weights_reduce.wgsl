// A hidden read-out layer's weight gradients, second pass: each weight's (and bias's)
// partial sums added in range order (see `dense_weights.wgsl`), one thread per value.

struct Params {
    fan_in: u32,
    fan_out: u32,
    splits: u32,
    has_bias: u32,
    groups_x: u32,   // workgroups per row of the dispatch grid
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> partial: array<f32>;   // [splits, fan_out * (fan_in + 1)]
@group(0) @binding(2) var<storage, read_write> g_w: array<f32>; // [fan_out, fan_in]
@group(0) @binding(3) var<storage, read_write> g_b: array<f32>; // [fan_out]

@compute @workgroup_size(64)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) t: u32) {
    let per_split = p.fan_out * (p.fan_in + 1u);
    let e = (wg.y * p.groups_x + wg.x) * 64u + t;
    if (e >= per_split) {
        return;
    }
    var acc = 0.0;
    for (var s = 0u; s < p.splits; s++) {
        acc += partial[s * per_split + e];
    }
    let j = e / (p.fan_in + 1u);
    let i = e % (p.fan_in + 1u);
    if (i < p.fan_in) {
        g_w[j * p.fan_in + i] = acc;
    } else if (p.has_bias != 0u) {
        g_b[j] = acc;
    }
}
