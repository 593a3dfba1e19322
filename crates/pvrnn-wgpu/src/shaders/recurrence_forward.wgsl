// The recurrence forward over whole windows, one workgroup per window (eqs. 2-10, 16): the
// steps depend on each other, so a window stays in one workgroup and its states in
// workgroup memory. A step is five phases between barriers, each over every module's
// units at once where the modules do not depend on each other: the priors and the
// recurrent part of u (from d_{t-1}); posteriors, z and KL; u += W_dz z, which finishes
// the top module's step; then, one depth at a time, the top-down input from the parent's
// d_t and the state update. Every sum is `cpu::recurrent::forward`'s, in its order.
//
// The loops are latency-bound (a few dozen dependent multiply-adds per thread and phase),
// so the weights come transposed (`weights_t`: each matrix column-major, at the offsets
// the table gives) to make a warp's loads one coalesced read, and LOADS loads are issued
// before their multiply-adds, which keep the CPU's order (`dot_d_prev`, `dot_zs`:
// `recurrence_dot.wgsl`).

@group(0) @binding(0) var<storage, read> table: Table;
@group(0) @binding(1) var<storage, read> weights_t: array<f32>;
@group(0) @binding(2) var<storage, read> inputs: array<f32>;
@group(0) @binding(3) var<storage, read_write> record: array<f32>;

// Per module (MAX_UNITS each): d_{t-1} (d_t once the module's step is done) and h_{t-1};
// the prior pre-activations (mean, then log sigma: 2 MAX_UNITS each), u and z.
var<workgroup> d_prev: array<f32, 512>;
var<workgroup> h_prev: array<f32, 512>;
var<workgroup> prior: array<f32, 1024>;
var<workgroup> u: array<f32, 512>;
var<workgroup> zs: array<f32, 512>;
var<workgroup> steps: u32;

@compute @workgroup_size({{WG}})
fn main(@builtin(workgroup_id) wg_id: vec3<u32>, @builtin(local_invocation_index) lid: u32) {
    let win = window_at(wg_id.x);
    if (lid == 0u) {
        steps = win.len;
        set_depths();
    }
    for (var m = 0u; m < 4u; m++) {
        let md = module_at(m);
        for (var i = lid; i < md.d; i += WG) {
            let at = win.inp + md.init;
            h_prev[m * MAX_UNITS + i] = inputs[at + i];
            d_prev[m * MAX_UNITS + i] = inputs[at + md.d + i];
        }
    }
    // (Each load is also a barrier: `depth` is visible to every thread after it.)
    let len = workgroupUniformLoad(&steps);
    let levels = workgroupUniformLoad(&depths);
    let ds = units_d();
    let zs_n = units_z();
    let outputs_a = 2u * zs_n + ds;
    let rec_stride = table.strides.rec;
    let in_stride = table.strides.inp;
    let init_stride = table.strides.init;
    // Where the workgroup is as wide as phase B (the default width), each thread has at
    // most one unit of it and loads that unit's inputs of a step (the adaptive variables,
    // eps) at the step's start, so that device memory's latency passes under phase A
    // instead of opening phase B. The same values.
    let ahead = EARLY == 1u && total(zs_n) <= WG;
    // This thread's unit of phase B where `ahead`: its inputs' offset in a step and the
    // rows' length, found once per window, not per step.
    var mine = vec2<u32>(0u, 0u);
    let has_unit = lid < total(zs_n);
    if (has_unit) {
        let mj = split(lid, zs_n);
        let md = module_at(mj.x);
        mine = vec2<u32>(md.inp + mj.y, md.z);
    }
    for (var t = 0u; t < len; t++) {
        let rec_t = win.rec + t * rec_stride;
        let in_t = win.inp + init_stride + t * in_stride;
        var early = StepInputs();
        if (ahead && has_unit) {
            early = step_inputs_at(win, in_t + mine.x, mine.y);
        }
        // Phase A, every module: the prior from d_{t-1} (2z outputs) and bias + W_dd d_{t-1}
        // (d outputs).
        for (var k = lid; k < total(outputs_a); k += WG) {
            let mo = split(k, outputs_a);
            let m = mo.x;
            let o = mo.y;
            let md = module_in(m, win.weights);
            let dp = m * MAX_UNITS;
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
            acc = dot_d_prev(acc, at + col, rows, dp, md.d);
            if (o < 2u * md.z) {
                prior[2u * dp + o] = acc;
            } else {
                u[dp + col] = acc;
            }
        }
        workgroupBarrier();
        // Phase B, every module: posterior, sample and KL, per unit.
        for (var k = lid; k < total(zs_n); k += WG) {
            let mj = split(k, zs_n);
            let m = mj.x;
            let j = mj.y;
            let md = module_at(m);
            let dp = m * MAX_UNITS;
            let pre = prior[2u * dp + j];
            let ls_p = prior[2u * dp + md.z + j];
            var given = early;
            if (!ahead) {
                given = step_inputs(md, win, in_t, j);
            }
            var a_mu = pre;
            var a_sigma = ls_p;
            if (win.prior == 0u) {
                a_mu = given.a_mu;
                a_sigma = given.a_sigma;
            }
            let eps = given.eps;
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
            zs[dp + j] = z;
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
        // Phase C, every module: u += W_dz z; a module without a parent takes its step here.
        for (var k = lid; k < total(ds); k += WG) {
            let mr = split(k, ds);
            let m = mr.x;
            let r = mr.y;
            let md = module_in(m, win.weights);
            let dp = m * MAX_UNITS;
            var acc = u[dp + r];
            acc = dot_zs(acc, md.w_dz + r, md.d, dp, md.z);
            if (md.parent < 4u) {
                u[dp + r] = acc;
            } else {
                take_step(md, dp + r, r, rec_t, acc);
            }
        }
        workgroupBarrier();
        // Then one depth at a time (a module's parent has taken its step): u += W_dh
        // d_parent,t, and the step.
        for (var level = 1u; level < levels; level++) {
            for (var k = lid; k < total(ds); k += WG) {
                let mr = split(k, ds);
                let m = mr.x;
                if (depth[m] != level) {
                    continue;
                }
                let r = mr.y;
                let md = module_in(m, win.weights);
                let dp = m * MAX_UNITS;
                var acc = u[dp + r];
                let pp = md.parent * MAX_UNITS;
                acc = dot_d_prev(acc, md.w_dh + r, md.d, pp, md.parent_d);
                take_step(md, dp + r, r, rec_t, acc);
            }
            workgroupBarrier();
        }
    }
}

// The leaky update of unit r (at `at` in the workgroup arrays) from its total input `acc`.
fn take_step(md: Module, at: u32, r: u32, rec_t: u32, acc: f32) {
    let h = fma(weights_t[md.decay + r], h_prev[at], weights_t[md.inv_tau + r] * acc);
    let d = tanh_sat(h);
    h_prev[at] = h;
    d_prev[at] = d;
    record[rec_t + rec_h(md) + r] = h;
    record[rec_t + rec_d(md) + r] = d;
}

// Unit j's inputs of a step: its adaptive variables (read only where the window has a
// posterior; zeros otherwise) and eps.
struct StepInputs {
    a_mu: f32,
    a_sigma: f32,
    eps: f32,
}

fn step_inputs(md: Module, win: WindowInfo, in_t: u32, j: u32) -> StepInputs {
    return step_inputs_at(win, in_t + md.inp + j, md.z);
}

// `step_inputs` from the unit's offset in the step's inputs (`at`) and the rows' length.
fn step_inputs_at(win: WindowInfo, at: u32, z: u32) -> StepInputs {
    var given = StepInputs();
    if (win.prior == 0u) {
        given.a_mu = inputs[at];
        given.a_sigma = inputs[at + z];
    }
    given.eps = inputs[at + 2u * z];
    return given;
}
