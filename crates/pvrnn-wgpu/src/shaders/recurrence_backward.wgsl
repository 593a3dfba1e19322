// Back-propagation through time over whole windows, one workgroup per window, in the
// reverse order of the forward kernel (steps backwards, modules bottom-up, so a child's
// gradient reaches its parent's d_t first), with the sums of `cpu::recurrent::backward`.
// Writes dF/da per step and, for the weight-gradient kernel, dF/du and dF/d prior.
// Its threads own columns of the weight matrices, so their loads are coalesced as stored;
// four are issued before their four multiply-adds (the sums keep the CPU's order).

@group(0) @binding(0) var<storage, read> table: Table;
@group(0) @binding(1) var<storage, read> weights: array<f32>;
@group(0) @binding(2) var<storage, read> record: array<f32>;
@group(0) @binding(3) var<storage, read> grad_d: array<f32>;
@group(0) @binding(4) var<storage, read_write> back: array<f32>;
@group(0) @binding(5) var<uniform> p: BackwardParams;

struct BackwardParams {
    kl_scale: vec4<f32>,
}

// dF/dd_t and dF/dd_{t-1} (being summed) and dF/dh_{t+1}, per module.
var<workgroup> gd_cur: array<f32, 512>;
var<workgroup> gd_prev: array<f32, 512>;
var<workgroup> gh_next: array<f32, 512>;
var<workgroup> gu: array<f32, 128>;
var<workgroup> gz: array<f32, 128>;
var<workgroup> gprior: array<f32, 256>;
var<workgroup> steps: u32;

@compute @workgroup_size(128)
fn main(@builtin(workgroup_id) wg_id: vec3<u32>, @builtin(local_invocation_index) lid: u32) {
    let win = window_at(wg_id.x);
    if (lid == 0u) {
        steps = win.len;
    }
    for (var i = lid; i < 4u * MAX_UNITS; i += WG) {
        gd_cur[i] = 0.0;
        gd_prev[i] = 0.0;
        gh_next[i] = 0.0;
    }
    let len = workgroupUniformLoad(&steps);
    let rec_stride = table.strides.rec;
    let grad_stride = table.strides.grad_d;
    let back_stride = table.strides.back;
    for (var step = 0u; step < len; step++) {
        let t = len - 1u - step;
        let rec_t = win.rec + t * rec_stride;
        let back_t = win.back + t * back_stride;
        for (var mm = 0u; mm < 4u; mm++) {
            let m = 3u - mm;
            let md = module_in(m, win.weights);
            let dp = m * MAX_UNITS;
            let c = p.kl_scale[m];
            // Phase 1: dF/dh_t and dF/du_t.
            for (var i = lid; i < md.d; i += WG) {
                let g = gd_cur[dp + i] + grad_d[win.grad_d + t * grad_stride + table.grad_d_at[m] + i];
                let d_t = record[rec_t + rec_d(md) + i];
                let gh = fma(g, 1.0 - d_t * d_t, weights[md.decay + i] * gh_next[dp + i]);
                gh_next[dp + i] = gh;
                let g_u = gh * weights[md.inv_tau + i];
                gu[i] = g_u;
                back[back_t + md.back + 2u * md.z + i] = g_u;
            }
            workgroupBarrier();
            // Phase 2: W_dd^T gu into dF/dd_{t-1}, W_dz^T gu into dF/dz, W_dh^T gu into the
            // parent's dF/dd_t.
            for (var o = lid; o < md.d + md.z + md.parent_d; o += WG) {
                if (o < md.d) {
                    var acc = gd_prev[dp + o];
                    var i = 0u;
                    for (; i + 4u <= md.d; i += 4u) {
                        //#unroll K 4
                        let w{K} = weights[md.w_dd + (i + {K}u) * md.d + o];
                        //#end
                        //#unroll K 4
                        acc = fma(gu[i + {K}u], w{K}, acc);
                        //#end
                    }
                    for (; i < md.d; i++) {
                        acc = fma(gu[i], weights[md.w_dd + i * md.d + o], acc);
                    }
                    gd_prev[dp + o] = acc;
                } else if (o < md.d + md.z) {
                    let j = o - md.d;
                    var acc = 0.0;
                    if (table.ablated[m] == 0u) {
                        var i = 0u;
                        for (; i + 4u <= md.d; i += 4u) {
                            //#unroll K 4
                            let w{K} = weights[md.w_dz + (i + {K}u) * md.z + j];
                            //#end
                            //#unroll K 4
                            acc = fma(gu[i + {K}u], w{K}, acc);
                            //#end
                        }
                        for (; i < md.d; i++) {
                            acc = fma(gu[i], weights[md.w_dz + i * md.z + j], acc);
                        }
                    }
                    gz[j] = acc;
                } else {
                    let k = o - md.d - md.z;
                    let pp = md.parent * MAX_UNITS;
                    var acc = gd_cur[pp + k];
                    var i = 0u;
                    for (; i + 4u <= md.d; i += 4u) {
                        //#unroll K 4
                        let w{K} = weights[md.w_dh + (i + {K}u) * md.parent_d + k];
                        //#end
                        //#unroll K 4
                        acc = fma(gu[i + {K}u], w{K}, acc);
                        //#end
                    }
                    for (; i < md.d; i++) {
                        acc = fma(gu[i], weights[md.w_dh + i * md.parent_d + k], acc);
                    }
                    gd_cur[pp + k] = acc;
                }
            }
            workgroupBarrier();
            // Phase 3: the posterior (through z and the KL term) and the prior (through KL).
            for (var j = lid; j < md.z; j += WG) {
                let mu_p = record[rec_t + rec_row(md, MU_P) + j];
                let mu_q = record[rec_t + rec_row(md, MU_Q) + j];
                let ivp = record[rec_t + rec_row(md, INV_VAR_P) + j];
                let ls_q = record[rec_t + rec_row(md, LOG_SIGMA_Q) + j];
                let ls_p = record[rec_t + rec_row(md, LOG_SIGMA_P) + j];
                let z = record[rec_t + rec_row(md, Z) + j];
                let var_ratio = exp(2.0 * (ls_q - ls_p));
                let diff = mu_q - mu_p;
                let g_mu_q = gz[j] + c * diff * ivp;
                let g_ls_q = gz[j] * (z - mu_q) + c * (var_ratio - 1.0);
                let g_mu_p = -c * diff * ivp * (1.0 - mu_p * mu_p);
                let g_ls_p = c * (1.0 - diff * diff * ivp - var_ratio);
                gprior[j] = g_mu_p;
                gprior[md.z + j] = g_ls_p;
                back[back_t + md.back + j] = g_mu_q * (1.0 - mu_q * mu_q);
                back[back_t + md.back + md.z + j] = g_ls_q;
                back[back_t + md.back + 2u * md.z + md.d + j] = g_mu_p;
                back[back_t + md.back + 3u * md.z + md.d + j] = g_ls_p;
            }
            workgroupBarrier();
            // Phase 4: W_prior^T gprior into dF/dd_{t-1}.
            for (var o = lid; o < md.d; o += WG) {
                var acc = gd_prev[dp + o];
                var j = 0u;
                for (; j + 4u <= 2u * md.z; j += 4u) {
                    //#unroll K 4
                    let w{K} = weights[md.w_prior + (j + {K}u) * md.d + o];
                    //#end
                    //#unroll K 4
                    acc = fma(gprior[j + {K}u], w{K}, acc);
                    //#end
                }
                for (; j < 2u * md.z; j++) {
                    acc = fma(gprior[j], weights[md.w_prior + j * md.d + o], acc);
                }
                gd_prev[dp + o] = acc;
            }
            workgroupBarrier();
        }
        // dF/dd_{t-1} becomes the current one; what reaches d_0 is dropped.
        for (var i = lid; i < 4u * MAX_UNITS; i += WG) {
            gd_cur[i] = gd_prev[i];
            gd_prev[i] = 0.0;
        }
        workgroupBarrier();
    }
}
