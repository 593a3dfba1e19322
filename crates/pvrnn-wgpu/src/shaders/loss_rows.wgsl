// The fused output layer of a read-out, by rows: x^ = tanh(W h + b), its squared error
// against the targets, the error gradient g = (x^ - x)(1 - x^2) / divisor, and the input
// gradient d h = g W, so the [rows x k] prediction never exists.
//
// Thread t of a workgroup owns one row: its hidden activations (xr*) and its input gradient
// (gx*) stay in registers, HV vec4s each (the source is unrolled before compilation, see
// template.rs), and it walks the workgroup's range of columns in tiles of CT whose weights
// and targets are staged in workgroup memory (weights read by every thread at the same
// address: a broadcast). Column ranges ("splits") make the grid large enough to fill a GPU;
// each split writes its own partial input gradient and row loss, and `reduce.wgsl` adds the
// splits in order (split-K without float atomics, which portable WGSL lacks). The weight
// gradient is `loss_columns.wgsl`'s, which recomputes the forward product by columns: one
// more product, but no [columns x rows] partials.
//
// Compiled without wgpu's runtime checks (`Gpu::audited_pipeline`), so every index must
// stay in bounds by construction: rows below p.rows (dead threads read row 0, write
// nothing), columns below c_end <= p.k, splits below the grid's y the host sized part_in
// and part_loss for; tile indices below CT * HV, RT * YS and CT (c + j < CT: CS divides CT).
//
// Workgroup memory: CT * HV * 16 + RT * YS * 4 + CT * 4 bytes = 15.3 KiB at HV = 13 and
// RT = 64, within WebGPU's default 16 KiB (at HV = 16 the host takes RT = 32 there).

const HV: u32 = {{HV}}u;  // hidden width in vec4s (zero-padded)
const RT: u32 = {{RT}}u;  // rows per workgroup (one per thread; 64, or 32 where the workgroup memory is small)
const CS: u32 = {{CS}}u;  // columns per step of the inner loop (2)
const CT: u32 = 32u;      // columns per tile
const YS: u32 = 33u;      // row stride of the target tile (odd: no bank conflicts)

struct Params {
    rows: u32,            // rows in this chunk
    k: u32,               // observed columns (the targets' row length)
    cols_per_split: u32,  // a multiple of CT
    scale: f32,           // 1 / divisor
    row_offset: u32,      // first row of this chunk in `x`
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> x: array<vec4<f32>>;             // [all rows, HV]
@group(0) @binding(2) var<storage, read> w: array<vec4<f32>>;             // [dims, HV]
@group(0) @binding(3) var<storage, read> b: array<f32>;                   // [dims]
@group(0) @binding(4) var<storage, read> y: array<f32>;                   // [rows, k]
@group(0) @binding(5) var<storage, read_write> part_in: array<vec4<f32>>; // [splits, rows, HV]
@group(0) @binding(6) var<storage, read_write> part_loss: array<f32>;     // [splits, rows]

var<workgroup> w_tile: array<vec4<f32>, {{CT_HV}}>;
var<workgroup> y_tile: array<f32, {{RT_YS}}>;  // RT * YS
var<workgroup> b_tile: array<f32, 32>;    // CT

@compute @workgroup_size({{RT}})
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) t: u32) {
    let split = wg.y;
    let r0 = wg.x * RT;
    let row = r0 + t;
    let live = row < p.rows;
    // A dead thread reads row 0 (always present) and writes nothing.
    let base = (p.row_offset + select(0u, row, live)) * HV;

    //#unroll i HV
    let xr{i} = x[base + {i}u];
    var gx{i} = vec4<f32>(0.0);
    //#end
    var loss = 0.0;

    let c_begin = split * p.cols_per_split;
    let c_end = min(p.k, c_begin + p.cols_per_split);
    for (var c0 = c_begin; c0 < c_end; c0 += CT) {
        let n = min(CT, c_end - c0);
        for (var i = t; i < CT * HV; i += RT) {
            let c = c0 + i / HV;
            var v = vec4<f32>(0.0);
            if (c < c_end) {
                v = w[c * HV + i % HV];
            }
            w_tile[i] = v;
        }
        if (t < CT) {
            var v = 0.0;
            if (t < n) {
                v = b[c0 + t];
            }
            b_tile[t] = v;
        }
        // Targets: consecutive threads read consecutive columns of a row.
        for (var i = t; i < RT * CT; i += RT) {
            let rr = i / CT;
            let cc = i % CT;
            var v = 0.0;
            if (r0 + rr < p.rows && cc < n) {
                v = y[(r0 + rr) * p.k + c0 + cc];
            }
            y_tile[rr * YS + cc] = v;
        }
        workgroupBarrier();

        // CS columns at a time (the tile's unused columns are zeros: g = 0 there, and the
        // error is masked): CS independent dot products in flight.
        for (var c = 0u; c < n; c += CS) {
            //#unroll j CS
            var a{j} = vec4<f32>(0.0);
            //#end
            //#unroll i HV
            //#unroll j CS
            a{j} = fma(xr{i}, w_tile[(c + {j}u) * HV + {i}u], a{j});
            //#end
            //#end
            var step_loss = 0.0;
            //#unroll j CS
            let yhat{j} = tanh_safe(sum4(a{j}) + b_tile[c + {j}u]);
            // Column c + j may lie past the tile's end (n not a multiple of CS).
            let e{j} = select(0.0, yhat{j} - y_tile[t * YS + c + {j}u], c + {j}u < n);
            step_loss += e{j} * e{j};
            let g{j} = vec4<f32>(p.scale * e{j} * (1.0 - yhat{j} * yhat{j}));
            //#end
            loss += step_loss;
            //#unroll i HV
            //#unroll j CS
            gx{i} = fma(g{j}, w_tile[(c + {j}u) * HV + {i}u], gx{i});
            //#end
            //#end
        }
        workgroupBarrier();
    }

    if (live) {
        let at = split * p.rows + row;
        //#unroll i HV
        part_in[at * HV + {i}u] = gx{i};
        //#end
        part_loss[at] = loss;
    }
}
