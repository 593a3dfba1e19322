// Shared by the recurrence kernels: the layout table written by `recurrence/table.rs`
// (`Table`, `TableModule` and `TableWindow` there are these structs, field for field).
//
// Module m's weights in `weights` start at its offsets: W_prior (2z x d: mean rows, then
// log-sigma rows), b_prior (2z), W_dd (d x d), W_dz (d x z), W_dh (d x parent's d), bias
// (d), 1/tau (d), 1 - 1/tau (d).
//
// Per window and step, module m's forward record holds h (d), d (d), then z-long rows:
// the prior mean's pre-activation, the prior mean, log sigma_p, 1/sigma_p^2, the posterior
// mean, log sigma_q, sigma_q, z, and the per-unit KL terms. Its inputs hold a_mu, a_sigma
// and eps (z each); its initial states h0 then d0 (d each). The backward record holds
// dF/da_mu, dF/da_sigma (z each), dF/du (d) and dF/d prior pre-activations (2z).

const MAX_UNITS: u32 = 128u;
// Threads per window's workgroup (`RecurrenceLayout::threads`): one per item of a step's
// widest phase where the adapter allows, so that no thread walks two dot products in turn.
const WG: u32 = {{WG}}u;
// 1: a step's loads issued at its start where the width allows (`Tiling::recurrence_early_loads`).
const EARLY: u32 = {{EARLY}}u;

// A module: its sizes (parent 4 = none), its offsets into the weights, and its offsets
// within a step of the forward record, the inputs, the initial states and the backward
// record.
struct Module {
    d: u32,
    z: u32,
    parent: u32,
    parent_d: u32,
    w_prior: u32,
    b_prior: u32,
    w_dd: u32,
    w_dz: u32,
    w_dh: u32,
    bias: u32,
    inv_tau: u32,
    decay: u32,
    rec: u32,
    inp: u32,
    init: u32,
    back: u32,
}

// Per step (per window for `init`): the forward record, the inputs, the initial states,
// the read-out gradients, the backward record.
struct Strides {
    rec: u32,
    inp: u32,
    init: u32,
    grad_d: u32,
    back: u32,
}

// A window: its steps, and where its inputs, forward record, read-out gradients and
// backward record start; `prior` 1 if its posterior is the prior; `weights` where its
// network's weights start (several networks' windows run in one dispatch: a cohort).
struct WindowInfo {
    len: u32,
    inp: u32,
    rec: u32,
    prior: u32,
    grad_d: u32,
    back: u32,
    weights: u32,
    pad1: u32,
}

struct Table {
    windows_count: u32,
    // 1 if module m is ablated (z = 0).
    ablated: array<u32, 4>,
    strides: Strides,
    // Module m's offset within a step of the read-out gradients.
    grad_d_at: array<u32, 4>,
    pad: array<u32, 2>,
    modules: array<Module, 4>,
    windows: array<WindowInfo>,
}

fn module_at(m: u32) -> Module {
    return table.modules[m];
}

// Module m with its weight offsets in the network whose weights start at `base`.
fn module_in(m: u32, base: u32) -> Module {
    var md = table.modules[m];
    md.w_prior += base;
    md.b_prior += base;
    md.w_dd += base;
    md.w_dz += base;
    md.w_dh += base;
    md.bias += base;
    md.inv_tau += base;
    md.decay += base;
    return md;
}

// Offsets of the forward record's rows within a module's part of a step.
fn rec_h(md: Module) -> u32 { return md.rec; }
fn rec_d(md: Module) -> u32 { return md.rec + md.d; }
fn rec_row(md: Module, k: u32) -> u32 { return md.rec + 2u * md.d + k * md.z; }
const PRE_MU_P: u32 = 0u;
const MU_P: u32 = 1u;
const LOG_SIGMA_P: u32 = 2u;
const INV_VAR_P: u32 = 3u;
const MU_Q: u32 = 4u;
const LOG_SIGMA_Q: u32 = 5u;
const SIGMA_Q: u32 = 6u;
const Z: u32 = 7u;
const KL: u32 = 8u;

// Items handed out over every module at once: each module m has `sizes[m]` (its units, or
// its outputs of a phase), one after another; item k is (module, index within it).
fn split(k: u32, sizes: vec4<u32>) -> vec2<u32> {
    var i = k;
    var m = 0u;
    for (; m < 3u && i >= sizes[m]; m++) {
        i -= sizes[m];
    }
    return vec2<u32>(m, i);
}

fn total(sizes: vec4<u32>) -> u32 {
    return sizes.x + sizes.y + sizes.z + sizes.w;
}

// Every module's d and z.
fn units_d() -> vec4<u32> {
    return vec4<u32>(table.modules[0].d, table.modules[1].d, table.modules[2].d, table.modules[3].d);
}

fn units_z() -> vec4<u32> {
    return vec4<u32>(table.modules[0].z, table.modules[1].z, table.modules[2].z, table.modules[3].z);
}

// Each module's depth below the top (0: no parent) and how many depths there are, set by
// a window's first thread (`set_depths`) for the kernels that take a step's phases one
// depth at a time.
var<workgroup> depth: array<u32, 4>;
var<workgroup> depths: u32;

// The modules come top-down (a parent before its children), so the parent's depth is
// known when its child's is set.
fn set_depths() {
    var deepest = 0u;
    for (var m = 0u; m < 4u; m++) {
        let parent = table.modules[m].parent;
        depth[m] = 0u;
        if (parent < 4u) {
            depth[m] = depth[parent] + 1u;
        }
        deepest = max(deepest, depth[m]);
    }
    depths = deepest + 1u;
}

fn window_at(w: u32) -> WindowInfo {
    return table.windows[w];
}

// tanh that saturates instead of returning NaN: some drivers compute it from exponentials
// that overflow for |x| above about 44; beyond 15 it rounds to +-1 in f32 anyway.
fn tanh_sat(x: f32) -> f32 {
    return tanh(clamp(x, -15.0, 15.0));
}
