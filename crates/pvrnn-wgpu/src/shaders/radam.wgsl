// One RAdam update of a tensor resident on the device (pvrnn-core's `RAdam::apply`, in the
// same order of operations): g' = g + wd p; m = b1 m + (1 - b1) g'; v = b2 v + (1 - b2) g'^2;
// p -= lr m sqrt(bias2) / (sqrt(v) + eps) when rectified, else p -= lr m. Elements from
// `live` on have no gradient this step (rows of the output layer that were not observed):
// g = 0 there, as on the host. The tensor may be one range of packed buffers (the recurrent
// weights: value, moments and gradient share the layout). Nothing changes when the run's
// divergence mark is set (`finite_check.wgsl`): the evaluation before this update gave a
// free energy that was not finite, which the host had not read back when it queued the
// update. One thread per element.

struct Params {
    count: u32,       // elements of the tensor
    live: u32,        // elements with a gradient (the first rows)
    groups_x: u32,    // workgroups per row of the dispatch grid
    rectified: u32,   // 1: the rectified update, 0: momentum only
    b1: f32,
    b2: f32,
    one_b1: f32,
    one_b2: f32,
    wd: f32,
    eps: f32,
    sqrt_bias2: f32,
    lr: f32,          // lr / bias1, times the rectification term when rectified
    offset: u32,      // where the tensor starts in its buffers (a packed buffer holds several)
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read_write> value: array<f32>;
@group(0) @binding(2) var<storage, read_write> m: array<f32>;
@group(0) @binding(3) var<storage, read_write> v: array<f32>;
@group(0) @binding(4) var<storage, read> grad: array<f32>;
@group(0) @binding(5) var<storage, read> diverged: array<u32>;

@compute @workgroup_size(64)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) t: u32) {
    let e = (wg.y * p.groups_x + wg.x) * 64u + t;
    if (e >= p.count || diverged[0] != 0u) {
        return;
    }
    let i = p.offset + e;
    var g = 0.0;
    if (e < p.live) {
        g = grad[i];
    }
    let x = value[i];
    let gd = fma(p.wd, x, g);
    let mi = fma(p.b1, m[i], p.one_b1 * gd);
    let vi = fma(p.b2, v[i], p.one_b2 * gd * gd);
    m[i] = mi;
    v[i] = vi;
    if (p.rectified != 0u) {
        value[i] = x - p.lr * mi * p.sqrt_bias2 / (sqrt(vi) + p.eps);
    } else {
        value[i] = x - p.lr * mi;
    }
}
