// The output layer's weight gradient from the error gradient (`OutputKernels::Blocked`, the
// third of its three products): d W = g^T h and d b = the column sums of g, for 128 columns
// per workgroup over a range of rows, one partial per range (`blocked_weight_reduce.wgsl`
// adds them in order).
//
// Thread (cy, h) of the 16 x HV workgroup owns vec4 h of the width for eight columns:
// 4 cy + j and 64 + 4 cy + j (j < 4), eight vec4 accumulators (`a*`, `b*`), and the
// columns' bias sums (below: in the padding lane where there is one, else every thread
// adds them and the h = 0 ones write them). The range's rows
// are walked in tiles of KT staged in workgroup memory: error gradients as they lie (a
// vec4 is four consecutive columns of one row; consecutive threads read consecutive
// columns), hidden activations likewise. Per row, 3 vec4 loads for 32 multiply-adds, and
// the forward product is not recomputed.
//
// Double-buffered as `blocked_forward.wgsl`. KT = 16 where the adapter allows 32 KiB of
// workgroup memory, else 8.
//
// VEC_IO = 1 (k a multiple of 4) reads the error gradients as vec4s, as
// `blocked_forward.wgsl` writes them.
//
// Where the width leaves its last lane as padding (BIAS_LANE = 1: hidden widths not a
// multiple of 4, such as the paper's 50), the bias sums ride in it: that lane is staged as
// 1 instead of 0, so the last vec4's accumulators add g times 1 there, the same sums in
// the same order as adding g (an fma by 1 rounds once, as an add does), without a thread's
// two extra vec4 adds per row (a fifth of its arithmetic). Its part_w lane is written as
// the zero it was.
//
// Compiled without wgpu's runtime checks (`Gpu::audited_pipeline`): every index is in
// bounds by construction. Device memory: rows below r_end <= p.rows (x: p.row_offset + row),
// columns below p.k, ranges below the grid's y the host sized part_w and part_b for; loads
// outside are skipped (zeros), stores outside are skipped. Workgroup memory: below 2 BUF.

const HV: u32 = {{HV}}u;       // hidden width in vec4s (zero-padded)
const KT: u32 = {{KT}}u;       // rows per tile
const NT: u32 = 16u * HV;      // threads
const BN: u32 = 128u;          // columns per workgroup
const GH: u32 = KT * 32u;      // vec4s of error gradients per buffer
const BUF: u32 = GH + KT * HV; // one buffer: error gradients, then activations
const BIAS_LANE: bool = {{BIAS_LANE}}u == 1u; // the bias sums in the width's padding lane

struct Params {
    rows: u32,            // rows in this chunk
    k: u32,               // observed columns
    rows_per_split: u32,  // a multiple of KT
    row_offset: u32,      // first row of this chunk in `x`
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> x: array<vec4<f32>>;            // [all rows, HV]
//#if VEC_IO
@group(0) @binding(2) var<storage, read> g: array<vec4<f32>>;            // [rows, k / 4]
//#else
@group(0) @binding(2) var<storage, read> g: array<f32>;                  // [rows, k]
//#end
@group(0) @binding(3) var<storage, read_write> part_w: array<vec4<f32>>; // [splits, k, HV]
@group(0) @binding(4) var<storage, read_write> part_b: array<f32>;       // [splits, k]

var<workgroup> stage: array<vec4<f32>, {{STAGE}}>;  // 2 BUF

// Error gradients `i` of the tile at r0 (row i / 32, columns 4 (i % 32) ..): zeros past
// r_end, p.k or the tile's 32 KT vec4s.
fn load_gradients(i: u32, r0: u32, r_end: u32, c0: u32) -> vec4<f32> {
    var v = vec4<f32>(0.0);
    let row = r0 + i / 32u;
    if (i < 32u * KT && row < r_end) {
        let col = c0 + 4u * (i % 32u);
        let at = row * p.k + col;
//#if VEC_IO
        // k a multiple of 4: the four columns are all in or all out.
        if (col < p.k) { v = g[at / 4u]; }
//#else
        if (col < p.k) { v.x = g[at]; }
        if (col + 1u < p.k) { v.y = g[at + 1u]; }
        if (col + 2u < p.k) { v.z = g[at + 2u]; }
        if (col + 3u < p.k) { v.w = g[at + 3u]; }
//#end
    }
    return v;
}

// The activations of the tile at r0 for thread t: row t / HV, vec4 t % HV (zeros past
// r_end; threads at or past KT HV stage nothing).
fn load_activations(t: u32, r0: u32, r_end: u32) -> vec4<f32> {
    let row = r0 + t / HV;
    var v = vec4<f32>(0.0);
    if (t < KT * HV && row < r_end) {
        v = x[(p.row_offset + row) * HV + t % HV];
        if (BIAS_LANE && t % HV == HV - 1u) {
            v.w = 1.0;
        }
    }
    return v;
}

fn store(t: u32, buffer: u32, activations: vec4<f32>) {
    if (t < KT * HV) {
        stage[buffer + GH + t] = activations;
    }
}

@compute @workgroup_size({{NT}})
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) t: u32) {
    let split = wg.y;
    let c0 = wg.x * BN;
    let h = t % HV;
    let cy = t / HV;

    //#unroll j 4
    var a{j} = vec4<f32>(0.0);
    var b{j} = vec4<f32>(0.0);
    //#end
    var bias_a = vec4<f32>(0.0);
    var bias_b = vec4<f32>(0.0);

    let r_begin = split * p.rows_per_split;
    let r_end = min(p.rows, r_begin + p.rows_per_split);
    let tiles = (r_end - r_begin + KT - 1u) / KT;
    //#unroll s {{LOADS}}
    var grads{s} = load_gradients(t + {s}u * NT, r_begin, r_end, c0);
    if (t + {s}u * NT < GH) {
        stage[t + {s}u * NT] = grads{s};
    }
    //#end
    var activations = load_activations(t, r_begin, r_end);
    store(t, 0u, activations);
    workgroupBarrier();
    for (var tile = 0u; tile < tiles; tile++) {
        let more = tile + 1u < tiles;
        let next = r_begin + (tile + 1u) * KT;
        if (more) {
            //#unroll s {{LOADS}}
            grads{s} = load_gradients(t + {s}u * NT, next, r_end, c0);
            //#end
            activations = load_activations(t, next, r_end);
        }
        let base = (tile % 2u) * BUF;
        //#unroll r KT
        {
            let ga = stage[base + {r}u * 32u + cy];
            let gb = stage[base + {r}u * 32u + 16u + cy];
            let xv = stage[base + GH + {r}u * HV + h];
            if (!BIAS_LANE) {
                bias_a += ga;
                bias_b += gb;
            }
            //#unroll j 4
            a{j} = fma(vec4<f32>(ga[{j}]), xv, a{j});
            b{j} = fma(vec4<f32>(gb[{j}]), xv, b{j});
            //#end
        }
        //#end
        if (more) {
            let other = ((tile + 1u) % 2u) * BUF;
            //#unroll s {{LOADS}}
            if (t + {s}u * NT < GH) {
                stage[other + t + {s}u * NT] = grads{s};
            }
            //#end
            store(t, other, activations);
        }
        workgroupBarrier();
    }

    //#unroll j 4
    {
        let col_a = c0 + 4u * cy + {j}u;
        if (col_a < p.k) {
            store_column(split, col_a, h, a{j}, bias_a[{j}]);
        }
        let col_b = col_a + 64u;
        if (col_b < p.k) {
            store_column(split, col_b, h, b{j}, bias_b[{j}]);
        }
    }
    //#end
}

// Thread h's vec4 of column `col`'s weight gradient, and the column's bias sum from the
// thread that holds it: the padding lane's (BIAS_LANE), else h = 0's `bias`.
fn store_column(split: u32, col: u32, h: u32, sums: vec4<f32>, bias: f32) {
    var w = sums;
    if (BIAS_LANE) {
        if (h == HV - 1u) {
            part_b[split * p.k + col] = w.w;
            w.w = 0.0;
        }
    } else if (h == 0u) {
        part_b[split * p.k + col] = bias;
    }
    part_w[(split * p.k + col) * HV + h] = w;
}
