// The output layer's input gradient from the error gradient (`OutputKernels::Blocked`, the
// second of its three products): d h = g W over a column split, one partial per split
// (`reduce.wgsl` adds them in order, as for `loss_rows.wgsl`).
//
// Thread t owns two rows, r0 + t and r0 + t + 64, their gradients in registers (gx{i},
// gy{i}: HV vec4s each, unrolled). The split's columns are walked in tiles of CT whose
// weights (a broadcast: every thread reads the same address) and error gradients are staged
// in workgroup memory; each weight vec4 serves both rows, 8 multiply-adds per load against
// 4 in `loss_rows.wgsl`.
//
// Workgroup memory: CT * HV * 16 + 2 * 64 * GS * 4 bytes = 12 KiB at HV = 13.

const HV: u32 = {{HV}}u;  // hidden width in vec4s (zero-padded)
const RT: u32 = 128u;     // rows per workgroup (two per thread)
const CT: u32 = 16u;      // columns per tile
const GS: u32 = 17u;      // row stride of the gradient tile (odd: no bank conflicts)

struct Params {
    rows: u32,            // rows in this chunk
    k: u32,               // observed columns
    cols_per_split: u32,  // a multiple of CT
    _pad0: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> w: array<vec4<f32>>;             // [dims, HV]
@group(0) @binding(2) var<storage, read> g: array<f32>;                   // [rows, k]
@group(0) @binding(3) var<storage, read_write> part_in: array<vec4<f32>>; // [splits, rows, HV]

var<workgroup> w_tile: array<vec4<f32>, {{CT16_HV}}>;
var<workgroup> g_tile: array<f32, 2176>;  // RT * GS

@compute @workgroup_size(64)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) t: u32) {
    let split = wg.y;
    let r0 = wg.x * RT;

    //#unroll i HV
    var gx{i} = vec4<f32>(0.0);
    var gy{i} = vec4<f32>(0.0);
    //#end

    let c_begin = split * p.cols_per_split;
    let c_end = min(p.k, c_begin + p.cols_per_split);
    for (var c0 = c_begin; c0 < c_end; c0 += CT) {
        let n = min(CT, c_end - c0);
        for (var i = t; i < CT * HV; i += 64u) {
            let c = c0 + i / HV;
            var v = vec4<f32>(0.0);
            if (c < c_end) {
                v = w[c * HV + i % HV];
            }
            w_tile[i] = v;
        }
        // Error gradients: consecutive threads read consecutive columns of a row; columns
        // past the split (and rows past the chunk) are zeros.
        for (var i = t; i < RT * CT; i += 64u) {
            let rr = i / CT;
            let cc = i % CT;
            var v = 0.0;
            if (r0 + rr < p.rows && cc < n) {
                v = g[(r0 + rr) * p.k + c0 + cc];
            }
            g_tile[rr * GS + cc] = v;
        }
        workgroupBarrier();
        for (var c = 0u; c < CT; c++) {
            let g0 = vec4<f32>(g_tile[t * GS + c]);
            let g1 = vec4<f32>(g_tile[(t + 64u) * GS + c]);
            let base = c * HV;
            //#unroll i HV
            {
                let wv = w_tile[base + {i}u];
                gx{i} = fma(g0, wv, gx{i});
                gy{i} = fma(g1, wv, gy{i});
            }
            //#end
        }
        workgroupBarrier();
    }

    let row_x = r0 + t;
    if (row_x < p.rows) {
        let at = (split * p.rows + row_x) * HV;
        //#unroll i HV
        part_in[at + {i}u] = gx{i};
        //#end
    }
    let row_y = row_x + 64u;
    if (row_y < p.rows) {
        let at = (split * p.rows + row_y) * HV;
        //#unroll i HV
        part_in[at + {i}u] = gy{i};
        //#end
    }
}
