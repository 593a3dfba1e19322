// The output layer's forward product and error, register-blocked (`OutputKernels::Blocked`,
// the first of its three products): x^ = tanh(W h + b) for a 64 x 64 tile of (rows,
// columns) per workgroup, the error gradient g = (x^ - x)(1 - x^2) / divisor written out for
// the other two products (`blocked_input_grad.wgsl`, `blocked_weight_grad.wgsl`), and each
// row's squared error summed over the workgroup's column split.
//
// Thread (ty, tx) of the 16 x 16 workgroup owns rows ty + 16 i and columns tx + 16 j
// (i, j < 4): sixteen dot products, kept as vec4 partial sums (acc{i}{j}) over the hidden
// width, which is walked in chunks of KC vec4s staged in workgroup memory (transposed, so
// that consecutive threads read consecutive vec4s). Each chunk step loads 4 + 4 vec4s for
// 64 multiply-adds, against one vec4 for 4 in `loss_rows.wgsl`.
//
// Workgroup memory: 2 * KC * 64 * 16 + 64 * 17 * 4 bytes = 12.4 KiB, within WebGPU's
// default 16 KiB; 256 invocations, WebGPU's default maximum.

const HV: u32 = {{HV}}u;  // hidden width in vec4s (zero-padded)
const BM: u32 = 64u;      // rows per workgroup
const BN: u32 = 64u;      // columns per tile
const KC: u32 = 4u;       // vec4s of the hidden width per staged chunk
const LS: u32 = 17u;      // row stride of the loss tile (odd: no bank conflicts)

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
@group(0) @binding(4) var<storage, read> y: array<f32>;                // [rows, k]
@group(0) @binding(5) var<storage, read_write> g: array<f32>;          // [rows, k]
@group(0) @binding(6) var<storage, read_write> part_loss: array<f32>;  // [splits, rows]

var<workgroup> x_tile: array<vec4<f32>, 256>;  // [KC, BM]
var<workgroup> w_tile: array<vec4<f32>, 256>;  // [KC, BN]
var<workgroup> loss_tile: array<f32, 1088>;    // [BM, LS]

@compute @workgroup_size(256)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) t: u32) {
    let split = wg.y;
    let r0 = wg.x * BM;
    let tx = t % 16u;
    let ty = t / 16u;
    // The staging thread's place: chunk vec4 `kk` of row (or column) `lane`.
    let lane = t / KC;
    let kk = t % KC;
    let stage_row = r0 + lane;

    //#unroll i 4
    var loss{i} = 0.0;
    //#end

    let c_begin = split * p.cols_per_split;
    let c_end = min(p.k, c_begin + p.cols_per_split);
    for (var c0 = c_begin; c0 < c_end; c0 += BN) {
        //#unroll i 4
        //#unroll j 4
        var acc{i}{j} = vec4<f32>(0.0);
        //#end
        //#end
        let stage_col = c0 + lane;
        for (var k0 = 0u; k0 < HV; k0 += KC) {
            let h = k0 + kk;
            var xv = vec4<f32>(0.0);
            if (stage_row < p.rows && h < HV) {
                xv = x[(p.row_offset + stage_row) * HV + h];
            }
            x_tile[kk * BM + lane] = xv;
            var wv = vec4<f32>(0.0);
            if (stage_col < c_end && h < HV) {
                wv = w[stage_col * HV + h];
            }
            w_tile[kk * BN + lane] = wv;
            workgroupBarrier();
            // The last chunk may run past the hidden width (13 vec4s at the paper's
            // scale): its zero padding is skipped, not multiplied.
            //#unroll q 4
            if (k0 + {q}u < HV) {
            //#unroll i 4
            let a{i} = x_tile[{q}u * BM + ty + 16u * {i}u];
            //#end
            //#unroll j 4
            let b{j} = w_tile[{q}u * BN + tx + 16u * {j}u];
            //#end
            //#unroll i 4
            //#unroll j 4
            acc{i}{j} = fma(a{i}, b{j}, acc{i}{j});
            //#end
            //#end
            }
            //#end
            workgroupBarrier();
        }
        // The epilogue: consecutive threads (tx) read and write consecutive columns.
        //#unroll j 4
        let col{j} = c0 + tx + 16u * {j}u;
        let live_c{j} = col{j} < c_end;
        let bias{j} = b[select(0u, col{j}, live_c{j})];
        //#end
        //#unroll i 4
        let row{i} = r0 + ty + 16u * {i}u;
        if (row{i} < p.rows) {
            let at{i} = row{i} * p.k;
            //#unroll j 4
            if (live_c{j}) {
                let yhat = tanh_safe(sum4(acc{i}{j}) + bias{j});
                let e = yhat - y[at{i} + col{j}];
                loss{i} += e * e;
                g[at{i} + col{j}] = p.scale * e * (1.0 - yhat * yhat);
            }
            //#end
        }
        //#end
    }

    // Each row's loss: its 16 threads' sums, added in order.
    //#unroll i 4
    loss_tile[(ty + 16u * {i}u) * LS + tx] = loss{i};
    //#end
    workgroupBarrier();
    if (t < BM && r0 + t < p.rows) {
        var l = 0.0;
        for (var s = 0u; s < 16u; s++) {
            l += loss_tile[t * LS + s];
        }
        part_loss[split * p.rows + r0 + t] = l;
    }
}
