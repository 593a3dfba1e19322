// A hidden read-out layer forward: y[r, j] = tanh(sum_i x[r, i] W[j, i] + b[j]) for every
// row, one thread per output value. Columns of y from `fan_out` up to `y_stride` are zero
// padding (the top layer's rows are whole vec4s for the output layer's kernels).

struct Params {
    rows: u32,
    fan_in: u32,
    fan_out: u32,
    x_stride: u32,   // floats per row of x
    y_stride: u32,   // floats per row of y (at least fan_out)
    has_bias: u32,
    groups_x: u32,   // workgroups per row of the dispatch grid
    _pad: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> x: array<f32>;        // [rows, x_stride]
@group(0) @binding(2) var<storage, read> w: array<f32>;        // [fan_out, fan_in]
@group(0) @binding(3) var<storage, read> b: array<f32>;        // [fan_out]
@group(0) @binding(4) var<storage, read_write> y: array<f32>;  // [rows, y_stride]

@compute @workgroup_size(64)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) t: u32) {
    let idx = (wg.y * p.groups_x + wg.x) * 64u + t;
    let r = idx / p.y_stride;
    let j = idx % p.y_stride;
    if (r >= p.rows) {
        return;
    }
    if (j >= p.fan_out) {
        y[idx] = 0.0;
        return;
    }
    var acc = 0.0;
    for (var i = 0u; i < p.fan_in; i++) {
        acc = fma(x[r * p.x_stride + i], w[j * p.fan_in + i], acc);
    }
    if (p.has_bias != 0u) {
        acc += b[j];
    }
    y[idx] = tanh(clamp(acc, -15.0, 15.0));
}
