// The recurrent weights' gradients, second pass: each weight's partial sums, one per window
// (`recurrence_weights.wgsl` with PARTIALS = 1), added in window order into the network's
// gradients, one thread per weight.

struct ReduceParams {
    first_part: u32,
    parts: u32,
    total: u32,
    base: u32,
}

@group(0) @binding(0) var<storage, read> partial_sums: array<f32>;
@group(0) @binding(1) var<storage, read_write> grads: array<f32>;
@group(0) @binding(2) var<uniform> p: ReduceParams;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let g = id.x;
    if (g >= p.total) {
        return;
    }
    var acc = 0.0;
    for (var s = p.first_part; s < p.first_part + p.parts; s++) {
        acc += partial_sums[s * p.total + g];
    }
    grads[p.base + g] = acc;
}
