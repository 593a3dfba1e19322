// The output layer's input gradient from the error gradient (`OutputKernels::Blocked`, the
// second of its three products): d h = g W over a column split for 128 rows per workgroup,
// one partial per split (`reduce.wgsl` adds them in order, as for `loss_rows.wgsl`).
//
// Thread (ry, h) of the 16 x HV workgroup owns vec4 h of the width for eight rows: 4 ry + i
// and 64 + 4 ry + i (i < 4), eight vec4 accumulators (`a*`, `b*`). The split's columns are
// walked in tiles of KT staged in workgroup memory: the error gradients transposed (a vec4
// is four consecutive rows of one column), the weights as they lie. Per column, 3 vec4
// loads for 32 multiply-adds.
//
// Double-buffered as `blocked_forward.wgsl`: the next tile is loaded into registers before
// the arithmetic and stored into the other buffer after it, one barrier per tile. KT = 16
// (24 KiB of workgroup memory at HV = 16) where the adapter allows 32 KiB, else 8.
//
// VEC_IO = 1 (k a multiple of 4) reads the error gradients as vec4s, as
// `blocked_forward.wgsl` writes them.
//
// Compiled without wgpu's runtime checks (`Gpu::audited_pipeline`): every index is in
// bounds by construction. Device memory: rows below p.rows, columns below c_end <= p.k,
// splits below the grid's y the host sized part_in for; loads outside are skipped (zeros),
// stores outside are skipped. Workgroup memory: below 2 BUF (buffer offsets 0 or BUF, row
// quads below 32, columns below KT, h below HV).

const HV: u32 = {{HV}}u;       // hidden width in vec4s (zero-padded)
const KT: u32 = {{KT}}u;       // columns per tile
const NT: u32 = 16u * HV;      // threads
const BM: u32 = 128u;          // rows per workgroup
const GH: u32 = KT * 32u;      // vec4s of error gradients per buffer
const BUF: u32 = GH + KT * HV; // one buffer: error gradients, then weights
const QUADS: u32 = KT / 4u;    // column quads per row quad

struct Params {
    rows: u32,            // rows in this chunk
    k: u32,               // observed columns
    cols_per_split: u32,  // a multiple of KT
    _pad0: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> w: array<vec4<f32>>;             // [dims, HV]
//#if VEC_IO
@group(0) @binding(2) var<storage, read> g: array<vec4<f32>>;             // [rows, k / 4]
//#else
@group(0) @binding(2) var<storage, read> g: array<f32>;                   // [rows, k]
//#end
@group(0) @binding(3) var<storage, read_write> part_in: array<vec4<f32>>; // [splits, rows, HV]

var<workgroup> stage: array<vec4<f32>, {{STAGE}}>;  // 2 BUF

// One staged 4 x 4 block of error gradients, transposed: v{f} holds column 4 c4 + f of
// rows 4 m4 .. 4 m4 + 3.
struct Block {
    v0: vec4<f32>,
    v1: vec4<f32>,
    v2: vec4<f32>,
    v3: vec4<f32>,
}

// Block `i` (row quad i / QUADS, column quad i % QUADS: four threads read a row's 16
// consecutive columns) of the tile at c0; zeros past the rows, c_end or the 32 QUADS
// blocks.
fn load_block(i: u32, r0: u32, c0: u32, c_end: u32) -> Block {
    var v0 = vec4<f32>(0.0);
    var v1 = vec4<f32>(0.0);
    var v2 = vec4<f32>(0.0);
    var v3 = vec4<f32>(0.0);
    if (i < 32u * QUADS) {
        let row = r0 + 4u * (i / QUADS);
        let col = c0 + 4u * (i % QUADS);
        //#unroll e 4
        if (row + {e}u < p.rows) {
            let at = (row + {e}u) * p.k + col;
//#if VEC_IO
            // k and c_end multiples of 4: the four columns are all in or all out.
            if (col < c_end) {
                let q = g[at / 4u];
                v0[{e}] = q.x;
                v1[{e}] = q.y;
                v2[{e}] = q.z;
                v3[{e}] = q.w;
            }
//#else
            if (col < c_end) { v0[{e}] = g[at]; }
            if (col + 1u < c_end) { v1[{e}] = g[at + 1u]; }
            if (col + 2u < c_end) { v2[{e}] = g[at + 2u]; }
            if (col + 3u < c_end) { v3[{e}] = g[at + 3u]; }
//#end
        }
        //#end
    }
    return Block(v0, v1, v2, v3);
}

fn store_block(i: u32, buffer: u32, block: Block) {
    if (i < 32u * QUADS) {
        let at = buffer + 4u * (i % QUADS) * 32u + i / QUADS;
        stage[at] = block.v0;
        stage[at + 32u] = block.v1;
        stage[at + 64u] = block.v2;
        stage[at + 96u] = block.v3;
    }
}

// The weights of the tile at c0 for thread t: column t / HV, vec4 t % HV (zeros past c_end;
// threads at or past KT HV stage nothing).
fn load_weights(t: u32, c0: u32, c_end: u32) -> vec4<f32> {
    let col = c0 + t / HV;
    var v = vec4<f32>(0.0);
    if (t < KT * HV && col < c_end) {
        v = w[col * HV + t % HV];
    }
    return v;
}

@compute @workgroup_size({{NT}})
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) t: u32) {
    let split = wg.y;
    let r0 = wg.x * BM;
    let h = t % HV;
    let ry = t / HV;

    //#unroll i 4
    var a{i} = vec4<f32>(0.0);
    var b{i} = vec4<f32>(0.0);
    //#end

    let c_begin = split * p.cols_per_split;
    let c_end = min(p.k, c_begin + p.cols_per_split);
    let tiles = (c_end - c_begin + KT - 1u) / KT;
    //#unroll s {{LOADS}}
    var block{s} = load_block(t + {s}u * NT, r0, c_begin, c_end);
    store_block(t + {s}u * NT, 0u, block{s});
    //#end
    var weights = load_weights(t, c_begin, c_end);
    if (t < KT * HV) {
        stage[GH + t] = weights;
    }
    workgroupBarrier();
    for (var tile = 0u; tile < tiles; tile++) {
        let more = tile + 1u < tiles;
        let next = c_begin + (tile + 1u) * KT;
        if (more) {
            //#unroll s {{LOADS}}
            block{s} = load_block(t + {s}u * NT, r0, next, c_end);
            //#end
            weights = load_weights(t, next, c_end);
        }
        let base = (tile % 2u) * BUF;
        //#unroll c KT
        {
            let ga = stage[base + {c}u * 32u + ry];
            let gb = stage[base + {c}u * 32u + 16u + ry];
            let wv = stage[base + GH + {c}u * HV + h];
            //#unroll i 4
            a{i} = fma(vec4<f32>(ga[{i}]), wv, a{i});
            b{i} = fma(vec4<f32>(gb[{i}]), wv, b{i});
            //#end
        }
        //#end
        if (more) {
            let other = ((tile + 1u) % 2u) * BUF;
            //#unroll s {{LOADS}}
            store_block(t + {s}u * NT, other, block{s});
            //#end
            if (t < KT * HV) {
                stage[other + GH + t] = weights;
            }
        }
        workgroupBarrier();
    }

    //#unroll i 4
    {
        let row_a = r0 + 4u * ry + {i}u;
        if (row_a < p.rows) {
            part_in[(split * p.rows + row_a) * HV + h] = a{i};
        }
        let row_b = row_a + 64u;
        if (row_b < p.rows) {
            part_in[(split * p.rows + row_b) * HV + h] = b{i};
        }
    }
    //#end
}
