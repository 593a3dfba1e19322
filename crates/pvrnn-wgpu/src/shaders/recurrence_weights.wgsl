// The recurrent weights' gradients, summing outer-product terms over windows and steps in
// a fixed order, so no float atomics are needed and results do not depend on scheduling.
// With PARTIALS = 0, one thread per weight (the weights buffer's layout) walks every
// window of its network and writes the sum to grads[base + g]. With PARTIALS = 1, one
// thread per weight and window (workgroup row y: window first_window + y) walks that
// window's steps and writes its partial sum to grads[y * total + g], which
// `recurrence_weights_reduce.wgsl` adds in window order: 18 times the threads and an
// eighteenth of the chain at the paper's batch (one thread per weight left a large GPU
// mostly idle on 5,400 dependent steps).
//   W_prior[j][i] += gprior_j d_{t-1,i}    b_prior[j] += gprior_j
//   W_dd[r][i]    += gu_r d_{t-1,i}        W_dz[r][j] += gu_r z_j
//   W_dh[r][k]    += gu_r d_parent,t,k     (the bias and time constants are fixed: 0)

@group(0) @binding(0) var<storage, read> table: Table;
@group(0) @binding(1) var<storage, read> inputs: array<f32>;
@group(0) @binding(2) var<storage, read> record: array<f32>;
@group(0) @binding(3) var<storage, read> back: array<f32>;
@group(0) @binding(4) var<storage, read_write> grads: array<f32>;
@group(0) @binding(5) var<uniform> p: WeightsParams;

// The windows first_window .. first_window + windows (one network's with PARTIALS = 0,
// its weights' gradients written from `base` on; any with PARTIALS = 1, a partial per
// window from 0 on).
struct WeightsParams {
    first_window: u32,
    windows: u32,
    total: u32,
    base: u32,
}

// d_{t-1} of module md, unit i, in window win (d_0 from the inputs' initial states).
fn d_before(win: WindowInfo, md: Module, t: u32, i: u32) -> f32 {
    if (t == 0u) {
        return inputs[win.inp + md.init + md.d + i];
    }
    return record[win.rec + (t - 1u) * table.strides.rec + rec_d(md) + i];
}

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let g = id.x;
    if (g >= p.total) {
        return;
    }
    // Which module and tensor: the modules' blocks are contiguous, W_prior first.
    var m = 0u;
    for (var k = 1u; k < 4u; k++) {
        if (g >= module_at(k).w_prior) {
            m = k;
        }
    }
    let md = module_at(m);
    let rec_stride = table.strides.rec;
    let back_stride = table.strides.back;
    var first = p.first_window;
    var window_end = p.first_window + p.windows;
    var write_at = p.base + g;
    if ({{PARTIALS}}u == 1u) {
        first = p.first_window + id.y;
        window_end = first + 1u;
        write_at = id.y * p.total + g;
    }
    var acc = 0.0;
    for (var w = first; w < window_end; w++) {
        let win = window_at(w);
        for (var t = 0u; t < win.len; t++) {
            let back_t = win.back + t * back_stride + md.back;
            let rec_t = win.rec + t * rec_stride;
            if (g < md.b_prior) {
                let e = g - md.w_prior;
                let j = e / md.d;
                let i = e % md.d;
                acc = fma(back[back_t + 2u * md.z + md.d + j], d_before(win, md, t, i), acc);
            } else if (g < md.w_dd) {
                acc += back[back_t + 2u * md.z + md.d + (g - md.b_prior)];
            } else if (g < md.w_dz) {
                let e = g - md.w_dd;
                acc = fma(back[back_t + 2u * md.z + e / md.d], d_before(win, md, t, e % md.d), acc);
            } else if (g < md.w_dh) {
                let e = g - md.w_dz;
                let z = record[rec_t + rec_row(md, Z) + e % md.z];
                acc = fma(back[back_t + 2u * md.z + e / md.z], z, acc);
            } else if (g < md.bias) {
                let e = g - md.w_dh;
                let parent = module_at(md.parent);
                let dp = record[rec_t + rec_d(parent) + e % md.parent_d];
                acc = fma(back[back_t + 2u * md.z + e / md.parent_d], dp, acc);
            }
        }
    }
    grads[write_at] = acc;
}
