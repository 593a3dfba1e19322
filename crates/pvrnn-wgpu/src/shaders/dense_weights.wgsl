// A hidden read-out layer's weight gradients, first pass: partial sums over a range of
// rows. For weight (j, i) and rows [s R, (s + 1) R): sum g_pre[r, j] x[r, i], and for the
// bias (i = fan_in) sum g_pre[r, j], with g_pre = g_y (1 - y^2). One thread per weight and
// range: 5,400 rows in ranges of 256 give a 50 x 41 layer 45,000 threads instead of 2,050
// each walking every row. `dense_weights_reduce.wgsl` adds the ranges in order (split-K:
// portable WGSL has no float atomics), so results do not depend on scheduling.

struct Params {
    rows: u32,
    fan_in: u32,
    fan_out: u32,
    x_stride: u32,
    y_stride: u32,
    rows_per_split: u32,
    groups_x: u32,
    splits: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> x: array<f32>;              // [rows, x_stride]
@group(0) @binding(2) var<storage, read> y: array<f32>;              // [rows, y_stride]
@group(0) @binding(3) var<storage, read> g_y: array<f32>;            // [rows, y_stride]
@group(0) @binding(4) var<storage, read_write> partial: array<f32>;  // [splits, fan_out * (fan_in + 1)]

@compute @workgroup_size(64)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) t: u32) {
    let idx = (wg.y * p.groups_x + wg.x) * 64u + t;
    let per_split = p.fan_out * (p.fan_in + 1u);
    let s = idx / per_split;
    let e = idx % per_split;
    if (s >= p.splits) {
        return;
    }
    let j = e / (p.fan_in + 1u);
    let i = e % (p.fan_in + 1u);
    let start = s * p.rows_per_split;
    let end = min(start + p.rows_per_split, p.rows);
    var acc = 0.0;
    for (var r = start; r < end; r++) {
        let a = y[r * p.y_stride + j];
        let g = g_y[r * p.y_stride + j] * (1.0 - a * a);
        if (i < p.fan_in) {
            acc = fma(g, x[r * p.x_stride + i], acc);
        } else {
            acc += g;
        }
    }
    partial[idx] = acc;
}
