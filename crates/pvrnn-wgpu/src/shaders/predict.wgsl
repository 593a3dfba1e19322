// x^ = tanh(W h + b) for every dimension: the explorer's images and a run's reconstructions.
// Thread t of workgroup (x, y) computes column 64 x + t of rows 4 y .. 4 y + 3, with the
// rows' hidden activations staged in workgroup memory.

const HV: u32 = {{HV}}u;  // hidden width in vec4s (zero-padded)
const RB: u32 = 4u;       // rows per workgroup

struct Params {
    rows: u32,
    dims: u32,
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> x: array<vec4<f32>>;  // [rows, HV]
@group(0) @binding(2) var<storage, read> w: array<vec4<f32>>;  // [dims, HV]
@group(0) @binding(3) var<storage, read> b: array<f32>;        // [dims]
@group(0) @binding(4) var<storage, read_write> out: array<f32>;  // [rows, dims]

var<workgroup> x_rows: array<vec4<f32>, {{RB_HV}}>;

@compute @workgroup_size(64)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) t: u32) {
    let r0 = wg.y * RB;
    for (var i = t; i < RB * HV; i += 64u) {
        let r = r0 + i / HV;
        var v = vec4<f32>(0.0);
        if (r < p.rows) {
            v = x[r * HV + i % HV];
        }
        x_rows[i] = v;
    }
    workgroupBarrier();
    let col = wg.x * 64u + t;
    if (col >= p.dims) {
        return;
    }
    //#unroll r 4
    var acc{r} = vec4<f32>(0.0);
    //#end
    //#unroll i HV
    let w{i} = w[col * HV + {i}u];
    //#unroll r 4
    acc{r} = fma(w{i}, x_rows[{r}u * HV + {i}u], acc{r});
    //#end
    //#end
    //#unroll r 4
    if (r0 + {r}u < p.rows) {
        let a = (acc{r}.x + acc{r}.y) + (acc{r}.z + acc{r}.w) + b[col];
        out[(r0 + {r}u) * p.dims + col] = tanh(clamp(a, -15.0, 15.0));
    }
    //#end
}
