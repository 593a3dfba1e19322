// The fused output layer of a read-out: x^ = tanh(W h + b), its squared error against the
// targets, the error gradient g = (x^ - x)(1 - x^2) / divisor, and both backward products
// (d input = g W, d W = g^T h), tile by tile, so the [rows x k] prediction never exists.
//
// One workgroup owns a range of column tiles (TC columns each) and walks every row of the
// chunk in sub-tiles of TR rows. Because it owns its columns, it accumulates d W and d b
// for them without atomics (across chunks, in later submissions). The input gradient sums
// over columns, which several workgroups share: each writes its own partial (split-K) and
// `reduce.wgsl` adds them in a fixed order.
//
// HL (the hidden width) is substituted before compilation, so the tiles are fixed-size
// arrays in workgroup memory: (TC + TR) * HL + TR * TC + WG floats, 11.9 KiB at HL = 50,
// within WebGPU's default 16 KiB.

const HL: u32 = {{HL}}u;
const HALF: u32 = {{HALF}}u;
const TR: u32 = 16u;
const TC: u32 = 32u;
const WG: u32 = 64u;

struct Params {
    rows: u32,            // rows in this chunk
    k: u32,               // observed columns (the targets' row length)
    tiles_per_group: u32, // column tiles per workgroup
    weight_grads: u32,    // 1: accumulate d W and d b
    scale: f32,           // 1 / divisor
    row_offset: u32,      // first row of this chunk in `x`
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> x: array<f32>;               // [all rows, HL]
@group(0) @binding(2) var<storage, read> w: array<f32>;               // [dims, HL]
@group(0) @binding(3) var<storage, read> b: array<f32>;               // [dims]
@group(0) @binding(4) var<storage, read> y: array<f32>;               // [rows, k]
@group(0) @binding(5) var<storage, read_write> part_in: array<f32>;   // [groups, rows, HL]
@group(0) @binding(6) var<storage, read_write> part_loss: array<f32>; // [groups, rows]
@group(0) @binding(7) var<storage, read_write> gw: array<f32>;        // [k, HL]
@group(0) @binding(8) var<storage, read_write> gb: array<f32>;        // [k]

var<workgroup> w_tile: array<f32, {{TC_HL}}>;
var<workgroup> x_tile: array<f32, {{TR_HL}}>;
var<workgroup> g_tile: array<f32, 512>;  // TR * TC
var<workgroup> sq: array<f32, 64>;       // WG

@compute @workgroup_size(64)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) t: u32) {
    let group = wg.x;
    // Forward: thread t computes row t / 4, columns (t % 4) * 8 .. + 8 of the tile.
    let fr = t / 4u;
    let fc = (t % 4u) * 8u;
    // d W: thread t owns column t / 2, hidden units (t % 2) * HALF .. + HALF.
    let wc = t / 2u;
    let wh = (t % 2u) * HALF;
    for (var ti = 0u; ti < p.tiles_per_group; ti++) {
        let c0 = (group * p.tiles_per_group + ti) * TC;
        if (c0 >= p.k) {
            break;
        }
        for (var i = t; i < TC * HL; i += WG) {
            let c = c0 + i / HL;
            var v = 0.0;
            if (c < p.k) {
                v = w[c * HL + i % HL];
            }
            w_tile[i] = v;
        }
        var acc_w: array<f32, HALF>;
        for (var j = 0u; j < HALF; j++) {
            acc_w[j] = 0.0;
        }
        var acc_b = 0.0;
        workgroupBarrier();
        for (var r0 = 0u; r0 < p.rows; r0 += TR) {
            for (var i = t; i < TR * HL; i += WG) {
                let r = r0 + i / HL;
                var v = 0.0;
                if (r < p.rows) {
                    v = x[(p.row_offset + r) * HL + i % HL];
                }
                x_tile[i] = v;
            }
            workgroupBarrier();

            var s = 0.0;
            let row = r0 + fr;
            for (var j = 0u; j < 8u; j++) {
                let c = fc + j;
                let col = c0 + c;
                var g = 0.0;
                if (col < p.k && row < p.rows) {
                    var a = b[col];
                    for (var h = 0u; h < HL; h++) {
                        a += x_tile[fr * HL + h] * w_tile[c * HL + h];
                    }
                    let yhat = tanh(a);
                    let e = yhat - y[row * p.k + col];
                    s += e * e;
                    g = p.scale * e * (1.0 - yhat * yhat);
                }
                g_tile[fr * TC + c] = g;
            }
            sq[t] = s;
            workgroupBarrier();

            if (t < TR && r0 + t < p.rows) {
                let at = p.rows * group + r0 + t;
                part_loss[at] += (sq[4u * t] + sq[4u * t + 1u]) + (sq[4u * t + 2u] + sq[4u * t + 3u]);
            }
            if (p.weight_grads != 0u) {
                for (var rr = 0u; rr < TR; rr++) {
                    let g = g_tile[rr * TC + wc];
                    acc_b += g;
                    for (var j = 0u; j < HALF; j++) {
                        let h = wh + j;
                        if (h < HL) {
                            acc_w[j] += g * x_tile[rr * HL + h];
                        }
                    }
                }
            }
            for (var o = t; o < TR * HL; o += WG) {
                let rr = o / HL;
                let h = o % HL;
                if (r0 + rr < p.rows) {
                    var a = 0.0;
                    for (var c = 0u; c < TC; c++) {
                        a += g_tile[rr * TC + c] * w_tile[c * HL + h];
                    }
                    part_in[(p.rows * group + r0 + rr) * HL + h] += a;
                }
            }
            workgroupBarrier();
        }
        if (p.weight_grads != 0u) {
            let col = c0 + wc;
            if (col < p.k) {
                for (var j = 0u; j < HALF; j++) {
                    let h = wh + j;
                    if (h < HL) {
                        gw[col * HL + h] += acc_w[j];
                    }
                }
                if (t % 2u == 0u) {
                    gb[col] += acc_b;
                }
            }
        }
        workgroupBarrier();
    }
}
