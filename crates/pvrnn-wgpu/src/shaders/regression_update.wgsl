// One of online inference's updates of the window's adaptive variables, on the device so
// that a step's updates run in one submission: after the recurrence backward has written
// d F / d a into `back`, one thread per (step, module unit) checks that this update's
// terms are finite (its gradients, its KL term, and for the step's first unit the
// read-outs' row losses), applies RAdam to a_mu and a_sigma where the recurrence reads
// them (the inputs' a slots), and writes the next update's eps into the eps slot.
//
// `p` is the update's: its index, the threads, and its RAdam scalars; `table` the
// window's layout and every update's eps (`RegressionTable` and `UpdateParams` in
// `regression.rs` are these structs, field for field). `moments`: m then v, each a_mu then
// a_sigma, `[len, sum_z]`.

struct Params {
    update: u32,
    count: u32,       // len x sum_z threads
    groups_x: u32,    // workgroups per row of the dispatch grid
    rectified: u32,   // 1: the rectified step (lr x r / (sqrt(v) + eps)), 0: plain (lr)
    beta1: f32,
    beta2: f32,
    one_minus_beta1: f32,
    one_minus_beta2: f32,
    weight_decay: f32,
    eps: f32,
    sqrt_bias2: f32,
    lr: f32,          // the rectified or the plain step size
}

// A module: its z, its units' offset among a step's, its offsets within a step of the
// inputs and the backward record, and the row of its KL terms within the forward record.
struct UpdateModule {
    z: u32,
    offset: u32,
    input: u32,
    back: u32,
    kl_row: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

struct RegressionTable {
    len: u32,
    sum_z: u32,
    init_stride: u32,
    input_stride: u32,
    back_stride: u32,
    record_stride: u32,
    updates: u32,
    extero_rows: u32,   // 1 if the row losses of vision are bound (it is observed)
    proprio_rows: u32,
    pad: array<u32, 7>,
    modules: array<UpdateModule, 4>,
    eps: array<f32>,    // [updates, len, sum_z]
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> table: RegressionTable;
@group(0) @binding(2) var<storage, read> back: array<f32>;
@group(0) @binding(3) var<storage, read> record: array<f32>;
@group(0) @binding(4) var<storage, read> rows_e: array<f32>;
@group(0) @binding(5) var<storage, read> rows_p: array<f32>;
@group(0) @binding(6) var<storage, read_write> inputs: array<f32>;
@group(0) @binding(7) var<storage, read_write> moments: array<f32>;
@group(0) @binding(8) var<storage, read_write> flags: array<u32>;

// Infinite or NaN, by the exponent bits (WGSL may assume arithmetic never produces them,
// so comparisons cannot be trusted to find them).
fn bad(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7f800000u) == 0x7f800000u;
}

// RAdam on one value (pvrnn-core's `RAdam::apply`, as `radam.wgsl`); `at` its input slot,
// `mo` its index in the first moment.
fn radam(at: u32, mo: u32, g: f32) {
    let x = inputs[at];
    let gd = fma(p.weight_decay, x, g);
    let mi = fma(p.beta1, moments[mo], p.one_minus_beta1 * gd);
    let vo = mo + 2u * p.count;
    let vi = fma(p.beta2, moments[vo], p.one_minus_beta2 * gd * gd);
    moments[mo] = mi;
    moments[vo] = vi;
    if (p.rectified != 0u) {
        inputs[at] = x - p.lr * mi * p.sqrt_bias2 / (sqrt(vi) + p.eps);
    } else {
        inputs[at] = x - p.lr * mi;
    }
}

@compute @workgroup_size(64)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) t: u32) {
    let i = (wg.y * p.groups_x + wg.x) * 64u + t;
    if (i >= p.count) {
        return;
    }
    let sum_z = table.sum_z;
    let step = i / sum_z;
    let c = i % sum_z;
    var m = 0u;
    for (var k = 1u; k < 4u; k++) {
        if (c >= table.modules[k].offset) {
            m = k;
        }
    }
    let md = table.modules[m];
    let z = md.z;
    let j = c - md.offset;
    let back_at = step * table.back_stride + md.back + j;
    let g_mu = back[back_at];
    let g_sigma = back[back_at + z];
    var diverged = bad(g_mu) || bad(g_sigma) || bad(record[step * table.record_stride + md.kl_row + j]);
    if (c == 0u) {
        diverged = diverged || (table.extero_rows != 0u && bad(rows_e[step]))
            || (table.proprio_rows != 0u && bad(rows_p[step]));
    }
    if (diverged) {
        flags[p.update] = 1u;
    }
    let at = table.init_stride + step * table.input_stride + md.input + j;
    radam(at, i, g_mu);
    radam(at + z, p.count + i, g_sigma);
    if (p.update + 1u < table.updates) {
        inputs[at + 2u * z] = table.eps[(p.update + 1u) * p.count + i];
    }
}
