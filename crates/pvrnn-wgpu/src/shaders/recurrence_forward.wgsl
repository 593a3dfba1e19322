// The recurrence forward over whole windows, one workgroup per window (eqs. 2-10, 16): the
// steps depend on each other, so a window stays in one workgroup and its states in
// workgroup memory; each module's step is three phases between barriers (prior and the
// recurrent part of u; posterior, z and KL; the rest of u and the state update). Modules
// run top-down within a step, as `cpu::recurrent::forward`, with the same order of sums.
//
// The loops are latency-bound (a few dozen dependent multiply-adds per thread and phase),
// so the weights come transposed (`weights_t`: each matrix column-major, at the offsets
// the table gives) to make a warp's loads one coalesced read, and four loads are issued
// before their four multiply-adds, which keep the CPU's order.

@group(0) @binding(0) var<storage, read> table: Table;
@group(0) @binding(1) var<storage, read> weights_t: array<f32>;
@group(0) @binding(2) var<storage, read> inputs: array<f32>;
@group(0) @binding(3) var<storage, read_write> record: array<f32>;

// d_{t-1} (d_t once a module's step is done) and h_{t-1} per module.
var<workgroup> d_prev: array<f32, 512>;
var<workgroup> h_prev: array<f32, 512>;
// The current module's prior pre-activations (mean, then log sigma), u and z.
var<workgroup> prior: array<f32, 256>;
var<workgroup> u: array<f32, 128>;
var<workgroup> zs: array<f32, 128>;
var<workgroup> steps: u32;

@compute @workgroup_size(128)
fn main(@builtin(workgroup_id) wg_id: vec3<u32>, @builtin(local_invocation_index) lid: u32) {
    let win = window_at(wg_id.x);
    if (lid == 0u) {
        steps = win.len;
    }
    for (var m = 0u; m < 4u; m++) {
        let md = module_at(m);
        for (var i = lid; i < md.d; i += WG) {
            let at = win.inp + md.init;
            h_prev[m * MAX_UNITS + i] = inputs[at + i];
            d_prev[m * MAX_UNITS + i] = inputs[at + md.d + i];
        }
    }
    let len = workgroupUniformLoad(&steps);
    let rec_stride = table.strides.rec;
    let in_stride = table.strides.inp;
    let init_stride = table.strides.init;
    for (var t = 0u; t < len; t++) {
        let rec_t = win.rec + t * rec_stride;
        let in_t = win.inp + init_stride + t * in_stride;
        for (var m = 0u; m < 4u; m++) {
            let md = module_in(m, win.weights);
            let dp = m * MAX_UNITS;
            // Phase A: the prior from d_{t-1} (2z outputs) and bias + W_dd d_{t-1} (d outputs).
            for (var o = lid; o < 2u * md.z + md.d; o += WG) {
                // Output o's weights: column o of a (d x rows) matrix at `at`.
                var acc: f32;
                var at: u32;
                var rows: u32;
                var col: u32;
                if (o < 2u * md.z) {
                    acc = weights_t[md.b_prior + o];
                    at = md.w_prior;
                    rows = 2u * md.z;
                    col = o;
                } else {
                    col = o - 2u * md.z;
                    acc = weights_t[md.bias + col];
                    at = md.w_dd;
                    rows = md.d;
                }
                var i = 0u;
                for (; i + 4u <= md.d; i += 4u) {
                    //#unroll K 4
                    let w{K} = weights_t[at + (i + {K}u) * rows + col];
                    //#end
                    //#unroll K 4
                    acc = fma(w{K}, d_prev[dp + i + {K}u], acc);
                    //#end
                }
                for (; i < md.d; i++) {
                    acc = fma(weights_t[at + i * rows + col], d_prev[dp + i], acc);
                }
                if (o < 2u * md.z) {
                    prior[o] = acc;
                } else {
                    u[col] = acc;
                }
            }
            workgroupBarrier();
            // Phase B: posterior, sample and KL, per unit.
            for (var j = lid; j < md.z; j += WG) {
                let pre = prior[j];
                let ls_p = prior[md.z + j];
                var a_mu = pre;
                var a_sigma = ls_p;
                let at = in_t + md.inp;
                if (win.prior == 0u) {
                    a_mu = inputs[at + j];
                    a_sigma = inputs[at + md.z + j];
                }
                let eps = inputs[at + 2u * md.z + j];
                let mu_p = tanh_sat(pre);
                let mu_q = tanh_sat(a_mu);
                let sigma_q = exp(a_sigma);
                let inv_var_p = exp(-2.0 * ls_p);
                let diff = mu_p - mu_q;
                // sigma_q^2 / sigma_p^2 from the logs (a product of exponentials overflows).
                let var_ratio = exp(2.0 * (a_sigma - ls_p));
                let kl = ls_p - a_sigma + 0.5 * (diff * diff * inv_var_p + var_ratio) - 0.5;
                var z = fma(sigma_q, eps, mu_q);
                if (table.ablated[m] != 0u) {
                    z = 0.0;
                }
                zs[j] = z;
                record[rec_t + rec_row(md, PRE_MU_P) + j] = pre;
                record[rec_t + rec_row(md, MU_P) + j] = mu_p;
                record[rec_t + rec_row(md, LOG_SIGMA_P) + j] = ls_p;
                record[rec_t + rec_row(md, INV_VAR_P) + j] = inv_var_p;
                record[rec_t + rec_row(md, MU_Q) + j] = mu_q;
                record[rec_t + rec_row(md, LOG_SIGMA_Q) + j] = a_sigma;
                record[rec_t + rec_row(md, SIGMA_Q) + j] = sigma_q;
                record[rec_t + rec_row(md, Z) + j] = z;
                record[rec_t + rec_row(md, KL) + j] = kl;
            }
            workgroupBarrier();
            // Phase C: u += W_dz z + W_dh d_parent,t; the leaky update.
            for (var r = lid; r < md.d; r += WG) {
                var acc = u[r];
                var j = 0u;
                for (; j + 4u <= md.z; j += 4u) {
                    //#unroll K 4
                    let w{K} = weights_t[md.w_dz + (j + {K}u) * md.d + r];
                    //#end
                    //#unroll K 4
                    acc = fma(w{K}, zs[j + {K}u], acc);
                    //#end
                }
                for (; j < md.z; j++) {
                    acc = fma(weights_t[md.w_dz + j * md.d + r], zs[j], acc);
                }
                if (md.parent < 4u) {
                    let pp = md.parent * MAX_UNITS;
                    var k = 0u;
                    for (; k + 4u <= md.parent_d; k += 4u) {
                        //#unroll K 4
                        let w{K} = weights_t[md.w_dh + (k + {K}u) * md.d + r];
                        //#end
                        //#unroll K 4
                        acc = fma(w{K}, d_prev[pp + k + {K}u], acc);
                        //#end
                    }
                    for (; k < md.parent_d; k++) {
                        acc = fma(weights_t[md.w_dh + k * md.d + r], d_prev[pp + k], acc);
                    }
                }
                let h = fma(weights_t[md.decay + r], h_prev[dp + r], weights_t[md.inv_tau + r] * acc);
                let d = tanh_sat(h);
                h_prev[dp + r] = h;
                d_prev[dp + r] = d;
                record[rec_t + rec_h(md) + r] = h;
                record[rec_t + rec_d(md) + r] = d;
            }
            workgroupBarrier();
        }
    }
}
