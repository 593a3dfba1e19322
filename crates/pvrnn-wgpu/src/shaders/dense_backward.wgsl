// A hidden read-out layer backward, to its input: g_x[r, i] = sum_j g_pre[r, j] W[j, i]
// with g_pre = g_y (1 - y^2) (y = tanh of the pre-activation), one thread per input value.
// Columns of g_x from `fan_in` up to `gx_stride` are zero padding.

struct Params {
    rows: u32,
    fan_in: u32,
    fan_out: u32,
    y_stride: u32,    // floats per row of y and g_y
    gx_stride: u32,   // floats per row of g_x (at least fan_in)
    groups_x: u32,
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> g_y: array<f32>;       // [rows, y_stride]
@group(0) @binding(2) var<storage, read> y: array<f32>;         // [rows, y_stride]
@group(0) @binding(3) var<storage, read> w: array<f32>;         // [fan_out, fan_in]
@group(0) @binding(4) var<storage, read_write> g_x: array<f32>; // [rows, gx_stride]

@compute @workgroup_size(64)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) t: u32) {
    let idx = (wg.y * p.groups_x + wg.x) * 64u + t;
    let r = idx / p.gx_stride;
    let i = idx % p.gx_stride;
    if (r >= p.rows) {
        return;
    }
    if (i >= p.fan_in) {
        g_x[idx] = 0.0;
        return;
    }
    var acc = 0.0;
    for (var j = 0u; j < p.fan_out; j++) {
        let a = y[r * p.y_stride + j];
        let g = g_y[r * p.y_stride + j] * (1.0 - a * a);
        acc = fma(g, w[j * p.fan_in + i], acc);
    }
    g_x[idx] = acc;
}
