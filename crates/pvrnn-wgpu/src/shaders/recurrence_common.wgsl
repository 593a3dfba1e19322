// Shared by the recurrence kernels: the layout table written by `recurrence.rs`.
//
// table (u32):
//   [1 + m]        1 if module m is ablated (z = 0)
//   [5..10)        strides: forward record per step, inputs per step, initial states per
//                  window, read-out gradients per step, backward record per step
//   [10 + m]       module m's offset within a step of the read-out gradients
//   [16 + 16 m ..] module m: d, z, parent (4 = none), parent's d, then offsets into the
//                  weights: W_prior (2z x d: mean rows, then log-sigma rows), b_prior (2z),
//                  W_dd (d x d), W_dz (d x z), W_dh (d x parent's d), bias (d), 1/tau (d),
//                  1 - 1/tau (d); then the module's offset within a step of the forward
//                  record, of the inputs, of the initial states, and of the backward record
//   [80 + 8 w ..]  window w: steps, inputs offset, forward record offset, posterior is the
//                  prior (1) or adaptive (0), read-out gradients offset, backward record
//                  offset
//
// Per window and step, module m's forward record holds h (d), d (d), then z-long rows:
// the prior mean's pre-activation, the prior mean, log sigma_p, 1/sigma_p^2, the posterior
// mean, log sigma_q, sigma_q, z, and the per-unit KL terms. Its inputs hold a_mu, a_sigma
// and eps (z each); its initial states h0 then d0 (d each). The backward record holds
// dF/da_mu, dF/da_sigma (z each), dF/du (d) and dF/d prior pre-activations (2z).

const MAX_UNITS: u32 = 128u;
const WG: u32 = 128u;

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

fn module_at(m: u32) -> Module {
    let b = 16u + 16u * m;
    return Module(table[b], table[b + 1u], table[b + 2u], table[b + 3u], table[b + 4u],
        table[b + 5u], table[b + 6u], table[b + 7u], table[b + 8u], table[b + 9u], table[b + 10u],
        table[b + 11u], table[b + 12u], table[b + 13u], table[b + 14u], table[b + 15u]);
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

const REC_STRIDE: u32 = 5u;
const IN_STRIDE: u32 = 6u;
const INIT_STRIDE: u32 = 7u;
const GRAD_D_STRIDE: u32 = 8u;
const BACK_STRIDE: u32 = 9u;

struct WindowInfo {
    len: u32,
    inp: u32,
    rec: u32,
    prior: u32,
    grad_d: u32,
    back: u32,
}

fn window_at(w: u32) -> WindowInfo {
    let b = 80u + 8u * w;
    return WindowInfo(table[b], table[b + 1u], table[b + 2u], table[b + 3u], table[b + 4u],
        table[b + 5u]);
}

// tanh that saturates instead of returning NaN: some drivers compute it from exponentials
// that overflow for |x| above about 44; beyond 15 it rounds to +-1 in f32 anyway.
fn tanh_sat(x: f32) -> f32 {
    return tanh(clamp(x, -15.0, 15.0));
}
