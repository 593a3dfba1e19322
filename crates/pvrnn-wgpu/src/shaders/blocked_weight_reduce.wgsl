// Adds the row ranges' partial weight gradients of `blocked_weight_grad.wgsl` in range
// order (results do not depend on scheduling) into d W and d b; a later chunk of rows adds
// to what the earlier ones wrote (`accumulate`). One thread per vec4 of d W.

const HV: u32 = {{HV}}u;

struct Params {
    k: u32,
    splits: u32,
    accumulate: u32,  // 0: the first chunk writes, later ones add
    _pad: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> part_w: array<vec4<f32>>;   // [splits, k, HV]
@group(0) @binding(2) var<storage, read> part_b: array<f32>;         // [splits, k]
@group(0) @binding(3) var<storage, read_write> gw: array<vec4<f32>>; // [k, HV]
@group(0) @binding(4) var<storage, read_write> gb: array<f32>;       // [k]

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = id.y * groups.x * 64u + id.x;
    if (i >= p.k * HV) {
        return;
    }
    let stride = p.k * HV;
    var a = vec4<f32>(0.0);
    for (var s = 0u; s < p.splits; s++) {
        a += part_w[s * stride + i];
    }
    if (p.accumulate != 0u) {
        a += gw[i];
    }
    gw[i] = a;
    if (i % HV == 0u) {
        let c = i / HV;
        var b = 0.0;
        for (var s = 0u; s < p.splits; s++) {
            b += part_b[s * p.k + c];
        }
        if (p.accumulate != 0u) {
            b += gb[c];
        }
        gb[c] = b;
    }
}
