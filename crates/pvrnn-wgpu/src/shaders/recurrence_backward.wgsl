// Back-propagation through time over whole windows, one workgroup per window, in the
// reverse order of the forward kernel: steps backwards and, within a step, one depth at a
// time from the bottom (a child's gradient reaches its parent's d_t before the parent's
// turn): dF/dh_t and dF/du_t, then W_dd^T and W_dz^T of dF/du into the module's own
// dF/dd_{t-1} and dF/dz, and W_dh^T into the parent's dF/dd_t. Then, every module at
// once, the posterior and the prior (through z and the KL term), and W_prior^T of the
// prior's gradient into dF/dd_{t-1}. Every sum is `cpu::recurrent::backward`'s, in its
// order (a parent sums its children's contributions from the last module first, as the
// CPU visits them). Writes dF/da per step and, for the weight-gradient kernel, dF/du and
// dF/d prior.
// Its threads own columns of the weight matrices, so their loads are coalesced as stored;
// LOADS are issued before their multiply-adds (`dot_gu`, `dot_gprior`:
// `recurrence_dot.wgsl`; the sums keep the CPU's order).

@group(0) @binding(0) var<storage, read> table: Table;
@group(0) @binding(1) var<storage, read> weights: array<f32>;
@group(0) @binding(2) var<storage, read> record: array<f32>;
@group(0) @binding(3) var<storage, read> grad_d: array<f32>;
@group(0) @binding(4) var<storage, read_write> back: array<f32>;
@group(0) @binding(5) var<uniform> p: BackwardParams;

struct BackwardParams {
    kl_scale: vec4<f32>,
}

// Per module (MAX_UNITS each): dF/dd_t, dF/dd_{t-1} (being summed), dF/dh_{t+1}, dF/du
// and dF/dz; dF/d prior (2 MAX_UNITS each).
var<workgroup> gd_cur: array<f32, 512>;
var<workgroup> gd_prev: array<f32, 512>;
var<workgroup> gh_next: array<f32, 512>;
var<workgroup> gu: array<f32, 512>;
var<workgroup> gz: array<f32, 512>;
var<workgroup> gprior: array<f32, 1024>;
var<workgroup> steps: u32;

@compute @workgroup_size({{WG}})
fn main(@builtin(workgroup_id) wg_id: vec3<u32>, @builtin(local_invocation_index) lid: u32) {
    let win = window_at(wg_id.x);
    if (lid == 0u) {
        steps = win.len;
        set_depths();
    }
    for (var i = lid; i < 4u * MAX_UNITS; i += WG) {
        gd_cur[i] = 0.0;
        gd_prev[i] = 0.0;
        gh_next[i] = 0.0;
    }
    // (Each load is also a barrier: `depth` is visible to every thread after it.)
    let len = workgroupUniformLoad(&steps);
    let levels = workgroupUniformLoad(&depths);
    let ds = units_d();
    let zs_n = units_z();
    // Phase 2's outputs per module: its own dF/dd_{t-1} (d) and dF/dz (z), then its part
    // of its children's W_dh^T sums (its own d).
    let outputs_2 = 2u * ds + zs_n;
    let rec_stride = table.strides.rec;
    let grad_stride = table.strides.grad_d;
    let back_stride = table.strides.back;
    // Where the workgroup is as wide as phases 1 and 3 (the default width: one thread per
    // item of the widest phase), each thread has at most one item of each, and it loads a
    // step's values from the forward record and the read-outs' gradients at the step's
    // start: one wait for device memory per step, under the phases before their use,
    // instead of one per depth in phase 1 and one more in phase 3. The same values.
    let ahead = EARLY == 1u && total(ds) <= WG && total(zs_n) <= WG;
    let mine = early_items(lid, ds, zs_n);
    for (var step = 0u; step < len; step++) {
        let t = len - 1u - step;
        let rec_t = win.rec + t * rec_stride;
        let back_t = win.back + t * back_stride;
        var early = Early();
        if (ahead) {
            early = load_early(mine, win.grad_d + t * grad_stride, rec_t);
        }
        for (var up = 0u; up < levels; up++) {
            let level = levels - 1u - up;
            // Phase 1, the modules at this depth: dF/dh_t and dF/du_t.
            for (var k = lid; k < total(ds); k += WG) {
                let mi = split(k, ds);
                let m = mi.x;
                if (depth[m] != level) {
                    continue;
                }
                let i = mi.y;
                let md = module_in(m, win.weights);
                let dp = m * MAX_UNITS;
                var from_readouts = early.grad_d;
                var d_t = early.d;
                if (!ahead) {
                    from_readouts = grad_d[win.grad_d + t * grad_stride + table.grad_d_at[m] + i];
                    d_t = record[rec_t + rec_d(md) + i];
                }
                let g = gd_cur[dp + i] + from_readouts;
                let gh = fma(g, 1.0 - d_t * d_t, weights[md.decay + i] * gh_next[dp + i]);
                gh_next[dp + i] = gh;
                let g_u = gh * weights[md.inv_tau + i];
                gu[dp + i] = g_u;
                back[back_t + md.back + 2u * md.z + i] = g_u;
            }
            workgroupBarrier();
            // Phase 2: the modules at this depth, W_dd^T gu into their dF/dd_{t-1} and W_dz^T
            // gu into dF/dz; their parents (one depth up), W_dh^T gu into dF/dd_t.
            for (var k = lid; k < total(outputs_2); k += WG) {
                let mo = split(k, outputs_2);
                let m = mo.x;
                let o = mo.y;
                let md = module_in(m, win.weights);
                let dp = m * MAX_UNITS;
                if (o < md.d + md.z) {
                    if (depth[m] != level) {
                        continue;
                    }
                    if (o < md.d) {
                        let acc = dot_gu(gd_prev[dp + o], md.w_dd + o, md.d, dp, md.d);
                        gd_prev[dp + o] = acc;
                    } else {
                        let j = o - md.d;
                        var acc = 0.0;
                        if (table.ablated[m] == 0u) {
                            acc = dot_gu(0.0, md.w_dz + j, md.z, dp, md.d);
                        }
                        gz[dp + j] = acc;
                    }
                } else {
                    // Unit k2 of module m as a parent: its children at this depth, the last
                    // module first.
                    if (depth[m] + 1u != level) {
                        continue;
                    }
                    let k2 = o - md.d - md.z;
                    var acc = gd_cur[dp + k2];
                    for (var cc = 0u; cc < 4u; cc++) {
                        let c = 3u - cc;
                        let cd = module_in(c, win.weights);
                        if (cd.parent != m) {
                            continue;
                        }
                        let cp = c * MAX_UNITS;
                        acc = dot_gu(acc, cd.w_dh + k2, cd.parent_d, cp, cd.d);
                    }
                    gd_cur[dp + k2] = acc;
                }
            }
            workgroupBarrier();
        }
        // Phase 3, every module: the posterior (through z and the KL term) and the prior
        // (through KL).
        for (var k = lid; k < total(zs_n); k += WG) {
            let mj = split(k, zs_n);
            let m = mj.x;
            let j = mj.y;
            let md = module_at(m);
            let dp = m * MAX_UNITS;
            let c = p.kl_scale[m];
            var r = early.kl;
            if (!ahead) {
                r = kl_record(md, rec_t, j);
            }
            let mu_p = r.mu_p;
            let mu_q = r.mu_q;
            let ivp = r.inv_var_p;
            let ls_q = r.log_sigma_q;
            let ls_p = r.log_sigma_p;
            let z = r.z;
            let var_ratio = exp(2.0 * (ls_q - ls_p));
            let diff = mu_q - mu_p;
            let g_mu_q = gz[dp + j] + c * diff * ivp;
            let g_ls_q = gz[dp + j] * (z - mu_q) + c * (var_ratio - 1.0);
            let g_mu_p = -c * diff * ivp * (1.0 - mu_p * mu_p);
            let g_ls_p = c * (1.0 - diff * diff * ivp - var_ratio);
            gprior[2u * dp + j] = g_mu_p;
            gprior[2u * dp + md.z + j] = g_ls_p;
            back[back_t + md.back + j] = g_mu_q * (1.0 - mu_q * mu_q);
            back[back_t + md.back + md.z + j] = g_ls_q;
            back[back_t + md.back + 2u * md.z + md.d + j] = g_mu_p;
            back[back_t + md.back + 3u * md.z + md.d + j] = g_ls_p;
        }
        workgroupBarrier();
        // Phase 4, every module: W_prior^T gprior into dF/dd_{t-1}, which becomes the
        // current one (dF/dd_t is spent); what reaches d_0 is dropped.
        for (var k = lid; k < total(ds); k += WG) {
            let mo = split(k, ds);
            let m = mo.x;
            let o = mo.y;
            let md = module_in(m, win.weights);
            let dp = m * MAX_UNITS;
            let acc = dot_gprior(gd_prev[dp + o], md.w_prior + o, md.d, 2u * dp, 2u * md.z);
            gd_cur[dp + o] = acc;
            gd_prev[dp + o] = 0.0;
        }
        workgroupBarrier();
    }
}

// What phase 3 reads of a unit's step from the forward record.
struct KlRecord {
    mu_p: f32,
    mu_q: f32,
    inv_var_p: f32,
    log_sigma_q: f32,
    log_sigma_p: f32,
    z: f32,
}

fn kl_record(md: Module, rec_t: u32, j: u32) -> KlRecord {
    return kl_record_at(rec_t + rec_row(md, 0u) + j, md.z);
}

// `kl_record` from unit j's first row in the step's record (`at`) and the rows' length.
fn kl_record_at(at: u32, z: u32) -> KlRecord {
    return KlRecord(
        record[at + MU_P * z],
        record[at + MU_Q * z],
        record[at + INV_VAR_P * z],
        record[at + LOG_SIGMA_Q * z],
        record[at + LOG_SIGMA_P * z],
        record[at + Z * z],
    );
}

// Where a thread's loads of a step read, the same every step (`ahead`): for its phase-1
// item (unit i of module m, item `lid` of the d units) dF/dd_t's offset in a step of the
// read-outs' gradients and d_t's in a step of the record; for its phase-3 item (unit j of
// module m, item `lid` of the z units) its first row's offset in the record and the rows'
// length. Found once per window, not per step.
struct EarlyItems {
    has_d: bool,
    grad_d: u32,
    d: u32,
    has_z: bool,
    kl: u32,
    z: u32,
}

fn early_items(lid: u32, ds: vec4<u32>, zs_n: vec4<u32>) -> EarlyItems {
    var mine = EarlyItems();
    if (lid < total(ds)) {
        let mi = split(lid, ds);
        mine.has_d = true;
        mine.grad_d = table.grad_d_at[mi.x] + mi.y;
        mine.d = rec_d(module_at(mi.x)) + mi.y;
    }
    if (lid < total(zs_n)) {
        let mj = split(lid, zs_n);
        let md = module_at(mj.x);
        mine.has_z = true;
        mine.kl = rec_row(md, 0u) + mj.y;
        mine.z = md.z;
    }
    return mine;
}

// A thread's loads of a step, issued at its start (`ahead`): the read-outs' dF/dd_t and
// d_t of its phase-1 item, what `kl_record` reads of its phase-3 item (zeros where it has
// none); `grad_t` and `rec_t` are the step's offsets.
struct Early {
    grad_d: f32,
    d: f32,
    kl: KlRecord,
}

fn load_early(mine: EarlyItems, grad_t: u32, rec_t: u32) -> Early {
    var early = Early();
    if (mine.has_d) {
        early.grad_d = grad_d[grad_t + mine.grad_d];
        early.d = record[rec_t + mine.d];
    }
    if (mine.has_z) {
        early.kl = kl_record_at(rec_t + mine.kl, mine.z);
    }
    return early;
}
