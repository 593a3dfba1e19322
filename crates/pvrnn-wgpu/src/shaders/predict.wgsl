// x^ = tanh(W h + b) for every dimension: the explorer's images and a run's reconstructions.
// Workgroup (x, y) computes 64 columns of row y.

const HL: u32 = {{HL}}u;

struct Params {
    rows: u32,
    dims: u32,
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> x: array<f32>;    // [rows, HL]
@group(0) @binding(2) var<storage, read> w: array<f32>;    // [dims, HL]
@group(0) @binding(3) var<storage, read> b: array<f32>;    // [dims]
@group(0) @binding(4) var<storage, read_write> out: array<f32>;  // [rows, dims]

var<workgroup> x_row: array<f32, HL>;

@compute @workgroup_size(64)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) t: u32) {
    let row = wg.y;
    for (var h = t; h < HL; h += 64u) {
        x_row[h] = x[row * HL + h];
    }
    workgroupBarrier();
    let col = wg.x * 64u + t;
    if (col >= p.dims) {
        return;
    }
    var a = b[col];
    for (var h = 0u; h < HL; h++) {
        a += x_row[h] * w[col * HL + h];
    }
    out[row * p.dims + col] = tanh(a);
}
