// The output layer's forward product and error, register-blocked (`OutputKernels::Blocked`,
// the first of its three products): x^ = tanh(W h + b) for a 128 x 128 tile of (rows,
// columns) per workgroup, the error gradient g = (x^ - x)(1 - x^2) / divisor written out for
// the other two products (`blocked_input_grad.wgsl`, `blocked_weight_grad.wgsl`), and each
// row's squared error summed over the workgroup's column split.
//
// Thread (ty, tx) of the 16 x 16 workgroup owns an 8 x 8 block: rows 4 ty + i and
// 64 + 4 ty + i, columns 4 tx + j and 64 + 4 tx + j (i, j < 4), as 16 vec4 accumulators
// (`lo*`: the low four columns, `hi*`: the high; `*_a`: the low four rows, `*_b`: the high).
// The hidden width is walked one scalar k at a time from workgroup memory, where it is
// staged transposed in chunks of KC vec4s: per k, 4 vec4 loads (two of rows, two of
// columns; consecutive threads read consecutive vec4s) for 64 multiply-adds.
//
// Double-buffered: while a chunk is multiplied, each staging thread already holds the next
// chunk's 4 x 4 block in registers (loaded before the arithmetic, stored into the other
// buffer after it), so one barrier per chunk and the device-memory latency under the
// arithmetic. The chunks of all the split's tiles are one loop, so a tile's first chunk
// loads under the previous tile's last chunk and epilogue. A last chunk that runs past the
// width (13 vec4s at the paper's scale, 4 per chunk) multiplies only its TAIL scalars,
// unrolled apart from the whole chunks, so the inner loop has no branch. KC = 4 (32 KiB of workgroup memory) on adapters that allow it, else 2
// (16 KiB, WebGPU's default); chosen by the host from the adapter's limits.
//
// With VEC_IO = 1 (the host's choice where the row length k is a multiple of 4, as every
// caresim layout's is) the targets and the error gradient are read and written as vec4s of
// four consecutive columns, one access where there were four; the arithmetic is the same.
//
// Compiled without wgpu's runtime checks (`Gpu::audited_pipeline`): every index is in
// bounds by construction. Device memory: rows below p.rows (x: p.row_offset + row, the host
// bound the chunk's rows), columns below c_end <= p.k, vec4s of the width below HV; loads
// outside are skipped (zeros), stores outside are skipped. Workgroup memory: stage indices
// are at most 2 BUF - 1 (buffer offsets 0 or BUF, lanes below 32, q below KS).

const HV: u32 = {{HV}}u;       // hidden width in vec4s (zero-padded)
const KC: u32 = {{KC}}u;       // vec4s of the width per staged chunk
const KS: u32 = {{KS}}u;       // scalars of the width per staged chunk (4 KC)
const FULL: u32 = {{FULL}}u;   // whole chunks of the width (HV / KC)
const TAIL: u32 = {{TAIL}}u;   // scalars of the width in a last, partial chunk (0: none)
const CHUNKS: u32 = {{CHUNKS}}u; // chunks per tile: FULL, and one more if TAIL > 0
const CL: u32 = {{CL}}u;       // column quads per tile: 32
const BM: u32 = 128u;          // rows per workgroup
const BN: u32 = 4u * CL;       // columns per tile: 128
const RH: u32 = KS * 32u;      // vec4s of the rows' chunk
const BUF: u32 = RH + KS * CL; // one buffer: the rows' chunk, then the columns'

struct Params {
    rows: u32,            // rows in this chunk
    k: u32,               // observed columns (the targets' row length)
    cols_per_split: u32,  // a multiple of BN
    scale: f32,           // 1 / divisor
    row_offset: u32,      // first row of this chunk in `x`
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> x: array<vec4<f32>>;          // [all rows, HV]
@group(0) @binding(2) var<storage, read> w: array<vec4<f32>>;          // [dims, HV]
@group(0) @binding(3) var<storage, read> b: array<f32>;                // [dims]
//#if VEC_IO
@group(0) @binding(4) var<storage, read> y: array<vec4<f32>>;          // [rows, k / 4]
@group(0) @binding(5) var<storage, read_write> g: array<vec4<f32>>;    // [rows, k / 4]
//#else
@group(0) @binding(4) var<storage, read> y: array<f32>;                // [rows, k]
@group(0) @binding(5) var<storage, read_write> g: array<f32>;          // [rows, k]
//#end
@group(0) @binding(6) var<storage, read_write> part_loss: array<f32>;  // [splits, rows]

// Two buffers of [KS, 32] vec4s of rows then [KS, CL] of columns (vec4 = four consecutive
// rows or columns at one k); after the last tile, the row losses' reduction (512 vec4s).
var<workgroup> stage: array<vec4<f32>, {{STAGE}}>;

// A staging thread's 4 x 4 block of one chunk, transposed: v{c} holds k = 4 kk + c of its
// four rows (or columns).
struct Block {
    v0: vec4<f32>,
    v1: vec4<f32>,
    v2: vec4<f32>,
    v3: vec4<f32>,
}

// A staging thread's lane and vec4 of the chunk: threads below 32 KC stage rows, the next
// CL KC columns, the others nothing.
fn lane_of(t: u32) -> u32 {
    return select((t - 32u * KC) % CL, t % 32u, t < 32u * KC);
}

fn vec4_of(t: u32) -> u32 {
    return select((t - 32u * KC) / CL, t / 32u, t < 32u * KC);
}

// The block of chunk `chunk` for rows (or columns) 4 lane .. 4 lane + 3 (zeros past the
// width, the rows, c_end, and for threads that stage nothing, never stored).
fn load_block(t: u32, r0: u32, c0: u32, c_end: u32, chunk: u32) -> Block {
    let lane = lane_of(t);
    let h = chunk * KC + vec4_of(t);
    var v0 = vec4<f32>(0.0);
    var v1 = vec4<f32>(0.0);
    var v2 = vec4<f32>(0.0);
    var v3 = vec4<f32>(0.0);
    if (h < HV) {
        if (t < 32u * KC) {
            let row = r0 + 4u * lane;
            let at = (p.row_offset + row) * HV + h;
            if (row < p.rows) { v0 = x[at]; }
            if (row + 1u < p.rows) { v1 = x[at + HV]; }
            if (row + 2u < p.rows) { v2 = x[at + 2u * HV]; }
            if (row + 3u < p.rows) { v3 = x[at + 3u * HV]; }
        } else if (t < (32u + CL) * KC) {
            let col = c0 + 4u * lane;
            let at = col * HV + h;
            if (col < c_end) { v0 = w[at]; }
            if (col + 1u < c_end) { v1 = w[at + HV]; }
            if (col + 2u < c_end) { v2 = w[at + 2u * HV]; }
            if (col + 3u < c_end) { v3 = w[at + 3u * HV]; }
        }
    }
    return Block(
        vec4<f32>(v0.x, v1.x, v2.x, v3.x),
        vec4<f32>(v0.y, v1.y, v2.y, v3.y),
        vec4<f32>(v0.z, v1.z, v2.z, v3.z),
        vec4<f32>(v0.w, v1.w, v2.w, v3.w),
    );
}

fn store_block(t: u32, buffer: u32, block: Block) {
    let lane = lane_of(t);
    let q = 4u * vec4_of(t);
    if (t < 32u * KC) {
        let at = buffer + q * 32u + lane;
        stage[at] = block.v0;
        stage[at + 32u] = block.v1;
        stage[at + 64u] = block.v2;
        stage[at + 96u] = block.v3;
    } else if (t < (32u + CL) * KC) {
        let at = buffer + RH + q * CL + lane;
        stage[at] = block.v0;
        stage[at + CL] = block.v1;
        stage[at + 2u * CL] = block.v2;
        stage[at + 3u * CL] = block.v3;
    }
}

// The biases of four columns from `col` (zeros at or past c_end).
fn biases(col: u32, c_end: u32) -> vec4<f32> {
    var v = vec4<f32>(0.0);
    //#unroll j 4
    if (col + {j}u < c_end) {
        v[{j}] = b[col + {j}u];
    }
    //#end
    return v;
}

// The targets of four columns from `col` of one row (zeros at or past c_end and past the
// chunk's rows). The epilogue loads a row pair's four vec4s of targets before it writes
// any of their errors, so that four loads wait on device memory once, not each in turn
// after the previous error's arithmetic. (Not for aliasing: SPIR-V lets a driver assume
// that two bindings without the Aliased decoration, which naga never emits, do not
// overlap.)
fn targets(row: u32, col: u32, c_end: u32) -> vec4<f32> {
    var wanted = vec4<f32>(0.0);
//#if VEC_IO
    // k and c_end are multiples of 4, col too: the four columns are all in or all out.
    if (row < p.rows && col < c_end) {
        wanted = y[(row * p.k + col) / 4u];
    }
//#else
    if (row < p.rows) {
        let at = row * p.k + col;
        //#unroll j 4
        if (col + {j}u < c_end) {
            wanted[{j}] = y[at + {j}u];
        }
        //#end
    }
//#end
    return wanted;
}

// The error of four columns from `col` of one row, given their forward products `acc`,
// biases `bias` and targets `wanted`: the error gradient written, the squared error
// returned (columns at or past c_end and rows past the chunk skipped).
fn emit(row: u32, col: u32, c_end: u32, acc: vec4<f32>, bias: vec4<f32>, wanted: vec4<f32>) -> f32 {
    var loss = 0.0;
//#if VEC_IO
    if (row < p.rows && col < c_end) {
        var grad = vec4<f32>(0.0);
        //#unroll j 4
        {
            let yhat = tanh_safe(acc[{j}] + bias[{j}]);
            let e = yhat - wanted[{j}];
            loss += e * e;
            grad[{j}] = p.scale * e * (1.0 - yhat * yhat);
        }
        //#end
        g[(row * p.k + col) / 4u] = grad;
    }
//#else
    if (row < p.rows) {
        let at = row * p.k + col;
        //#unroll j 4
        if (col + {j}u < c_end) {
            let yhat = tanh_safe(acc[{j}] + bias[{j}]);
            let e = yhat - wanted[{j}];
            loss += e * e;
            g[at + {j}u] = p.scale * e * (1.0 - yhat * yhat);
        }
        //#end
    }
//#end
    return loss;
}

@compute @workgroup_size(256)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) t: u32) {
    let split = wg.y;
    let r0 = wg.x * BM;
    let tx = t % 16u;
    let ty = t / 16u;

    //#unroll i 4
    var loss_a{i} = 0.0;
    var loss_b{i} = 0.0;
    //#end

    let c_begin = split * p.cols_per_split;
    let c_end = min(p.k, c_begin + p.cols_per_split);
    let tiles = select(0u, (c_end - c_begin + BN - 1u) / BN, c_end > c_begin);
    // One loop over every tile's chunks, so that the next tile's first chunk is loaded
    // under this tile's last chunk and epilogue, as the chunks within a tile are.
    let steps = tiles * CHUNKS;
    //#unroll i 4
    var lo_a{i} = vec4<f32>(0.0);
    var lo_b{i} = vec4<f32>(0.0);
    var hi_a{i} = vec4<f32>(0.0);
    var hi_b{i} = vec4<f32>(0.0);
    //#end
    var block = load_block(t, r0, c_begin, c_end, 0u);
    store_block(t, 0u, block);
    workgroupBarrier();
    for (var step = 0u; step < steps; step++) {
        let chunk = step % CHUNKS;
        let c0 = c_begin + (step / CHUNKS) * BN;
        let more = step + 1u < steps;
        if (more) {
            let next = step + 1u;
            block = load_block(t, r0, c_begin + (next / CHUNKS) * BN, c_end, next % CHUNKS);
        }
        let xb = (step % 2u) * BUF;
        let wb = xb + RH;
        if (chunk < FULL) {
            //#unroll q KS
            {
                let ra = stage[xb + {q}u * 32u + ty];
                let rb = stage[xb + {q}u * 32u + 16u + ty];
                let cl = stage[wb + {q}u * CL + tx];
                let ch = stage[wb + {q}u * CL + 16u + tx];
                //#unroll i 4
                lo_a{i} = fma(vec4<f32>(ra[{i}]), cl, lo_a{i});
                lo_b{i} = fma(vec4<f32>(rb[{i}]), cl, lo_b{i});
                hi_a{i} = fma(vec4<f32>(ra[{i}]), ch, hi_a{i});
                hi_b{i} = fma(vec4<f32>(rb[{i}]), ch, hi_b{i});
                //#end
            }
            //#end
        } else {
            // The last chunk when the width is not a whole number of chunks (13 vec4s at
            // the paper's scale): only its TAIL scalars, so its zero padding is not
            // multiplied.
            //#unroll q TAIL
            {
                let ra = stage[xb + {q}u * 32u + ty];
                let rb = stage[xb + {q}u * 32u + 16u + ty];
                let cl = stage[wb + {q}u * CL + tx];
                let ch = stage[wb + {q}u * CL + 16u + tx];
                //#unroll i 4
                lo_a{i} = fma(vec4<f32>(ra[{i}]), cl, lo_a{i});
                lo_b{i} = fma(vec4<f32>(rb[{i}]), cl, lo_b{i});
                hi_a{i} = fma(vec4<f32>(ra[{i}]), ch, hi_a{i});
                hi_b{i} = fma(vec4<f32>(rb[{i}]), ch, hi_b{i});
                //#end
            }
            //#end
        }
        if (chunk + 1u == CHUNKS) {
            // The tile's errors, each row's low columns then its high ones, a row pair's
            // targets first (`targets`); then its accumulators start again at zero.
            let col_lo = c0 + 4u * tx;
            let bias_lo = biases(col_lo, c_end);
            let col_hi = col_lo + 64u;
            let bias_hi = biases(col_hi, c_end);
            //#unroll i 4
            {
                let row_a = r0 + 4u * ty + {i}u;
                let row_b = row_a + 64u;
                let y_alo = targets(row_a, col_lo, c_end);
                let y_blo = targets(row_b, col_lo, c_end);
                let y_ahi = targets(row_a, col_hi, c_end);
                let y_bhi = targets(row_b, col_hi, c_end);
                loss_a{i} += emit(row_a, col_lo, c_end, lo_a{i}, bias_lo, y_alo);
                loss_a{i} += emit(row_a, col_hi, c_end, hi_a{i}, bias_hi, y_ahi);
                loss_b{i} += emit(row_b, col_lo, c_end, lo_b{i}, bias_lo, y_blo);
                loss_b{i} += emit(row_b, col_hi, c_end, hi_b{i}, bias_hi, y_bhi);
                hi_a{i} = vec4<f32>(0.0);
                hi_b{i} = vec4<f32>(0.0);
                lo_a{i} = vec4<f32>(0.0);
                lo_b{i} = vec4<f32>(0.0);
            }
            //#end
        }
        if (more) {
            store_block(t, ((step + 1u) % 2u) * BUF, block);
        }
        workgroupBarrier();
    }

    // Each row's loss: its 16 threads' sums (one per tx), added in order. Row quad m
    // (rows 4 m .. 4 m + 3) of thread tx sits at stage[32 tx + m]: quads ty and 16 + ty.
    stage[32u * tx + ty] = vec4<f32>(loss_a0, loss_a1, loss_a2, loss_a3);
    stage[32u * tx + 16u + ty] = vec4<f32>(loss_b0, loss_b1, loss_b2, loss_b3);
    workgroupBarrier();
    if (t < 32u) {
        var l = vec4<f32>(0.0);
        for (var s = 0u; s < 16u; s++) {
            l += stage[32u * s + t];
        }
        let row = r0 + 4u * t;
        let at = split * p.rows + row;
        //#unroll i 4
        if (row + {i}u < p.rows) {
            part_loss[at + {i}u] = l[{i}];
        }
        //#end
    }
}
