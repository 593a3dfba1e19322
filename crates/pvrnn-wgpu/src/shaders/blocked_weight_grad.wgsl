// The output layer's weight gradient from the error gradient (`OutputKernels::Blocked`, the
// third of its three products): d W = g^T h and d b = the column sums of g, over a range of
// rows, one partial per range (`blocked_weight_reduce.wgsl` adds them in order).
//
// Thread t owns two columns, c0 + t and c0 + t + 64, their gradients in registers (gx{i},
// gy{i}: HV vec4s each, unrolled), and walks its range's rows in tiles of RT whose hidden
// activations are staged in workgroup memory (a broadcast). Each activation vec4 serves
// both columns, 8 multiply-adds per load against 4 in `loss_columns.wgsl`, and the forward
// product is not recomputed. Consecutive threads read consecutive error gradients of a row.
//
// Workgroup memory: RT * HV * 16 bytes = 6.5 KiB at HV = 13.

const HV: u32 = {{HV}}u;  // hidden width in vec4s (zero-padded)
const CW: u32 = 128u;     // columns per workgroup (two per thread)
const RT: u32 = 32u;      // rows per tile

struct Params {
    rows: u32,            // rows in this chunk
    k: u32,               // observed columns
    rows_per_split: u32,  // a multiple of RT
    row_offset: u32,      // first row of this chunk in `x`
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> x: array<vec4<f32>>;          // [all rows, HV]
@group(0) @binding(2) var<storage, read> g: array<f32>;                // [rows, k]
@group(0) @binding(3) var<storage, read_write> part_w: array<vec4<f32>>; // [splits, k, HV]
@group(0) @binding(4) var<storage, read_write> part_b: array<f32>;     // [splits, k]

var<workgroup> x_tile: array<vec4<f32>, {{RT_HV}}>;

@compute @workgroup_size(64)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) t: u32) {
    let split = wg.y;
    let col_x = wg.x * CW + t;
    let col_y = col_x + 64u;
    let live_x = col_x < p.k;
    let live_y = col_y < p.k;
    // A dead thread reads column 0 (always present) and writes nothing.
    let cx = select(0u, col_x, live_x);
    let cy = select(0u, col_y, live_y);

    //#unroll i HV
    var gx{i} = vec4<f32>(0.0);
    var gy{i} = vec4<f32>(0.0);
    //#end
    var bx = 0.0;
    var by = 0.0;

    let r_begin = split * p.rows_per_split;
    let r_end = min(p.rows, r_begin + p.rows_per_split);
    for (var r0 = r_begin; r0 < r_end; r0 += RT) {
        let n = min(RT, r_end - r0);
        for (var i = t; i < RT * HV; i += 64u) {
            let r = r0 + i / HV;
            var v = vec4<f32>(0.0);
            if (r < r_end) {
                v = x[(p.row_offset + r) * HV + i % HV];
            }
            x_tile[i] = v;
        }
        workgroupBarrier();
        for (var r = 0u; r < n; r++) {
            let at = (r0 + r) * p.k;
            let s0 = select(0.0, g[at + cx], live_x);
            let s1 = select(0.0, g[at + cy], live_y);
            bx += s0;
            by += s1;
            let g0 = vec4<f32>(s0);
            let g1 = vec4<f32>(s1);
            let base = r * HV;
            //#unroll i HV
            {
                let xv = x_tile[base + {i}u];
                gx{i} = fma(g0, xv, gx{i});
                gy{i} = fma(g1, xv, gy{i});
            }
            //#end
        }
        workgroupBarrier();
    }

    if (live_x) {
        let at = split * p.k + col_x;
        //#unroll i HV
        part_w[at * HV + {i}u] = gx{i};
        //#end
        part_b[at] = bx;
    }
    if (live_y) {
        let at = split * p.k + col_y;
        //#unroll i HV
        part_w[at * HV + {i}u] = gy{i};
        //#end
        part_b[at] = by;
    }
}
