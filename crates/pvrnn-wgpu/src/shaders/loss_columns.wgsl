// The output layer's weight gradient, by columns: d W = g^T h and d b = sum over rows of g,
// with g = (x^ - x)(1 - x^2) / divisor recomputed from the forward product (see
// `loss_rows.wgsl`, which computes the loss and the input gradient).
//
// Thread t owns one column: its weights (wc*) and its weight gradient (gw*) stay in
// registers, HV vec4s each (unrolled, see template.rs), and it walks every row of the chunk
// in tiles of RT rows whose hidden activations are staged in workgroup memory (a broadcast:
// every thread reads the same address). Consecutive threads read consecutive targets of a
// row. A column belongs to one workgroup, so d W needs no atomics; chunks of rows
// accumulate in order (`accumulate`).
//
// Compiled without wgpu's runtime checks (`Gpu::audited_pipeline`), so every index must
// stay in bounds by construction: columns below p.k (dead threads read column 0, write
// nothing), rows below p.rows (row r + 1 only when r + 1 < n), tile indices below RT * HV
// (RT even, so r + 1 < RT).
//
// Workgroup memory: RT * HV * 16 bytes = 6.5 KiB at HV = 13.

const HV: u32 = {{HV}}u;  // hidden width in vec4s (zero-padded)
const CW: u32 = 64u;      // columns per workgroup (one per thread)
const RT: u32 = 32u;      // rows per tile

struct Params {
    rows: u32,        // rows in this chunk
    k: u32,           // observed columns
    scale: f32,       // 1 / divisor
    row_offset: u32,  // first row of this chunk in `x`
    accumulate: u32,  // 0: the first chunk writes, later ones add
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> x: array<vec4<f32>>;        // [all rows, HV]
@group(0) @binding(2) var<storage, read> w: array<vec4<f32>>;        // [dims, HV]
@group(0) @binding(3) var<storage, read> b: array<f32>;              // [dims]
@group(0) @binding(4) var<storage, read> y: array<f32>;              // [rows, k]
@group(0) @binding(5) var<storage, read_write> gw: array<vec4<f32>>; // [k, HV]
@group(0) @binding(6) var<storage, read_write> gb: array<f32>;       // [k]

var<workgroup> x_tile: array<vec4<f32>, {{RT_HV}}>;

@compute @workgroup_size(64)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) t: u32) {
    let col = wg.x * CW + t;
    let live = col < p.k;
    // A dead thread reads column 0 (always present) and writes nothing.
    let c = select(0u, col, live);

    //#unroll i HV
    let wc{i} = w[c * HV + {i}u];
    var gw{i} = vec4<f32>(0.0);
    //#end
    let bias = b[c];
    var acc_b = 0.0;

    for (var r0 = 0u; r0 < p.rows; r0 += RT) {
        let n = min(RT, p.rows - r0);
        for (var i = t; i < RT * HV; i += CW) {
            let r = r0 + i / HV;
            var v = vec4<f32>(0.0);
            if (r < p.rows) {
                v = x[(p.row_offset + r) * HV + i % HV];
            }
            x_tile[i] = v;
        }
        workgroupBarrier();
        // Two rows at a time: two independent dot products in flight. Row r + 1 may lie
        // past the chunk (odd n): its g is masked to 0.
        for (var r = 0u; r < n; r += 2u) {
            let x0 = r * HV;
            let x1 = x0 + HV;
            var a0 = vec4<f32>(0.0);
            var a1 = vec4<f32>(0.0);
            //#unroll i HV
            a0 = fma(wc{i}, x_tile[x0 + {i}u], a0);
            a1 = fma(wc{i}, x_tile[x1 + {i}u], a1);
            //#end
            let yhat0 = tanh_safe(sum4(a0) + bias);
            let yhat1 = tanh_safe(sum4(a1) + bias);
            let more = r + 1u < n;
            let e0 = yhat0 - y[(r0 + r) * p.k + c];
            let e1 = select(0.0, yhat1 - y[(r0 + select(r, r + 1u, more)) * p.k + c], more);
            let g0 = p.scale * e0 * (1.0 - yhat0 * yhat0);
            let g1 = p.scale * e1 * (1.0 - yhat1 * yhat1);
            acc_b += g0 + g1;
            let v0 = vec4<f32>(g0);
            let v1 = vec4<f32>(g1);
            //#unroll i HV
            gw{i} = fma(v1, x_tile[x1 + {i}u], fma(v0, x_tile[x0 + {i}u], gw{i}));
            //#end
        }
        workgroupBarrier();
    }

    if (live) {
        if (p.accumulate != 0u) {
            //#unroll i HV
            gw{i} += gw[col * HV + {i}u];
            //#end
            acc_b += gb[col];
        }
        //#unroll i HV
        gw[col * HV + {i}u] = gw{i};
        //#end
        gb[col] = acc_b;
    }
}
