//! The recurrent part (eqs. 2-10, 16) over one window: forward, and back-propagation
//! through time by hand.
//!
//! Modules are evaluated top-down within a step (a child reads its parent's d_t), and
//! differentiated bottom-up (a child's gradient reaches its parent's d_t before the parent is
//! processed). Products are in axpy form with pre-transposed weights (see `kernels`).

use faer::{Accum, MatMut, MatRef, Par};

use crate::Real;
use crate::assembled::ModuleWeightGrads;
use crate::backend::{ModuleTrace, Posterior, Trace, Window};
use crate::config::{ModelConfig, ModuleId};
use crate::data::Ablation;
use crate::kernels::{gemv_padded, pad_rows, padded, simd, transpose_padded};
use crate::params::Params;

/// One module's weights laid out for the kernels: rows padded to the vector width, transposed
/// copies for the forward products, row-major originals for the backward ones.
#[derive(Debug)]
pub(crate) struct PreparedModule<T> {
    d: usize,
    z: usize,
    /// `d` and `z` padded to the vector width.
    pd: usize,
    pz: usize,
    parent: Option<usize>,
    /// Forward, `[inputs, padded outputs]`: W_prior^T as `[d, 2 pz]` (mean block, then
    /// log-sigma block), W_dd^T `[d, pd]`, W_dz^T `[z, pd]`, W_dh^T `[d_parent, pd]`.
    wt_prior: Vec<T>,
    wt_dd: Vec<T>,
    wt_dz: Vec<T>,
    wt_dh: Vec<T>,
    /// `[2 pz]` prior biases (zeros without `prior_bias`) and `[pd]` recurrent bias.
    b_prior: Vec<T>,
    bias: Vec<T>,
    /// Backward, `[outputs, padded inputs]`: W_dd `[d, pd]`, W_dz `[d, pz]`,
    /// W_dh `[d, pd_parent]`, W_prior `[2z, pd]` (mean rows, then log-sigma rows).
    w_dd: Vec<T>,
    w_dz: Vec<T>,
    w_dh: Vec<T>,
    w_prior: Vec<T>,
    inv_tau: Vec<T>,
    /// 1 - 1/tau
    decay: Vec<T>,
}

#[derive(Debug)]
pub(crate) struct Prepared<T> {
    pub(crate) modules: [PreparedModule<T>; 4],
    /// W / z per module: the weight of a unit's KL in F.
    pub(crate) kl_scale: [T; 4],
    /// B of `log_sigma_bound` (log sigma = B tanh(pre-activation / B)), if the model has one.
    pub(crate) log_sigma_bound: Option<T>,
}

impl<T: Real> Prepared<T> {
    pub(crate) fn new(params: &Params<T>, config: &ModelConfig) -> Self {
        let modules = ModuleId::ALL.map(|id| {
            let p = &params.modules[id.index()];
            let (d, z) = (config.module(id).d, config.module(id).z);
            let (pd, pz) = (padded(d), padded(z));
            let parent = id.parent();
            let parent_d = parent.map_or(0, |pid| config.module(pid).d);
            let mut wt_prior = vec![T::ZERO; d * 2 * pz];
            let t_mu = transpose_padded(p.w_prior_mu.data(), z, d, pz);
            let t_sigma = transpose_padded(p.w_prior_sigma.data(), z, d, pz);
            for i in 0..d {
                wt_prior[i * 2 * pz..i * 2 * pz + pz].copy_from_slice(&t_mu[i * pz..(i + 1) * pz]);
                wt_prior[i * 2 * pz + pz..(i + 1) * 2 * pz]
                    .copy_from_slice(&t_sigma[i * pz..(i + 1) * pz]);
            }
            let mut b_prior = vec![T::ZERO; 2 * pz];
            if let (Some(bm), Some(bs)) = (&p.b_prior_mu, &p.b_prior_sigma) {
                b_prior[..z].copy_from_slice(bm.data());
                b_prior[pz..pz + z].copy_from_slice(bs.data());
            }
            let mut bias = vec![T::ZERO; pd];
            bias[..d].copy_from_slice(p.bias.data());
            let mut w_prior = pad_rows(p.w_prior_mu.data(), z, d, pd);
            w_prior.extend(pad_rows(p.w_prior_sigma.data(), z, d, pd));
            let (wt_dh, w_dh) = match &p.w_dh {
                Some(w) => (
                    transpose_padded(w.data(), d, parent_d, pd),
                    pad_rows(w.data(), d, parent_d, padded(parent_d)),
                ),
                None => (Vec::new(), Vec::new()),
            };
            PreparedModule {
                d,
                z,
                pd,
                pz,
                parent: parent.map(ModuleId::index),
                wt_prior,
                wt_dd: transpose_padded(p.w_dd.data(), d, d, pd),
                wt_dz: transpose_padded(p.w_dz.data(), d, z, pd),
                wt_dh,
                b_prior,
                bias,
                w_dd: pad_rows(p.w_dd.data(), d, d, pd),
                w_dz: pad_rows(p.w_dz.data(), d, z, pz),
                w_dh,
                w_prior,
                inv_tau: p.tau.data().iter().map(|&t| T::ONE / t).collect(),
                decay: p.tau.data().iter().map(|&t| T::ONE - T::ONE / t).collect(),
            }
        });
        let kl_scale =
            ModuleId::ALL.map(|id| T::from_f64(config.kl_weight / config.module(id).z as f64));
        Self {
            modules,
            kl_scale,
            log_sigma_bound: config.log_sigma_bound.map(T::from_f64),
        }
    }
}

#[inline(always)] // inside the kernels' SIMD dispatch: `tanh` needs its FMA
fn empty_trace<T: Real>(p: &PreparedModule<T>, len: usize, h0: Option<&[T]>) -> ModuleTrace<T> {
    let h0 = h0.map(<[T]>::to_vec).unwrap_or_else(|| vec![T::ZERO; p.d]);
    let d0 = h0.iter().map(|&h| h.tanh()).collect();
    ModuleTrace {
        h0,
        d0,
        h: vec![T::ZERO; len * p.d],
        d: vec![T::ZERO; len * p.d],
        mu_p: vec![T::ZERO; len * p.z],
        pre_mu_p: vec![T::ZERO; len * p.z],
        log_sigma_p: vec![T::ZERO; len * p.z],
        inv_var_p: vec![T::ZERO; len * p.z],
        mu_q: vec![T::ZERO; len * p.z],
        log_sigma_q: vec![T::ZERO; len * p.z],
        sigma_q: vec![T::ZERO; len * p.z],
        z: vec![T::ZERO; len * p.z],
        kl: vec![0.0; len],
    }
}

/// `out` = the log sigmas of `pre` (pre-activations): themselves, or B tanh(pre / B) under
/// a bound B (a departure from the paper: sigma stays within [e^-B, e^B]).
#[inline(always)] // inside the kernels' SIMD dispatch: `tanh` needs its FMA
fn bounded_log_sigma<T: Real>(out: &mut Vec<T>, pre: &[T], bound: Option<T>) {
    out.clear();
    match bound {
        None => out.extend_from_slice(pre),
        Some(b) => {
            let inv = T::ONE / b;
            out.extend(pre.iter().map(|&x| b * (x * inv).tanh()));
        }
    }
}

/// Runs a window forward; returns every state.
pub(crate) fn forward<T: Real>(
    p: &Prepared<T>,
    w: &Window<'_, T>,
    ablation: &Ablation,
) -> Trace<T> {
    simd(
        #[inline(always)]
        || forward_impl(p, w, ablation),
    )
}

#[inline(always)]
fn forward_impl<T: Real>(p: &Prepared<T>, w: &Window<'_, T>, ablation: &Ablation) -> Trace<T> {
    let len = w.len;
    let mut modules: [ModuleTrace<T>; 4] =
        std::array::from_fn(|m| empty_trace(&p.modules[m], len, w.h0.map(|h| h[m])));
    let mut prior = Vec::new();
    let mut kl_terms = Vec::new();
    // The log sigmas the step uses: the pre-activations, or bounded (`log_sigma_bound`).
    let mut ls_p_buf = Vec::new();
    let mut ls_q_buf = Vec::new();
    let mut u = Vec::new();
    let half = T::from_f64(0.5);
    let two = T::from_f64(2.0);
    for t in 0..len {
        for m in 0..4 {
            let pm = &p.modules[m];
            let (d, z) = (pm.d, pm.z);
            let (above, rest) = modules.split_at_mut(m);
            let tr = &mut rest[0];
            let parent_d = pm
                .parent
                .map(|pi| &above[pi].d[t * above[pi].d0.len()..][..above[pi].d0.len()]);

            // Prior from d_{t-1}.
            let (d_before, d_now) = tr.d.split_at_mut(t * d);
            let d_prev: &[T] = if t == 0 {
                &tr.d0
            } else {
                &d_before[(t - 1) * d..]
            };
            let pz = pm.pz;
            prior.clear();
            prior.extend_from_slice(&pm.b_prior);
            gemv_padded(&mut prior, &pm.wt_prior, d_prev, 2 * pz);

            // Posterior, sample, KL: element-wise passes that vectorise.
            let row = t * z..(t + 1) * z;
            let (a_mu, a_sigma): (&[T], &[T]) = match w.posterior {
                Posterior::Adaptive { a_mu, a_sigma } => {
                    (&a_mu[m][row.clone()], &a_sigma[m][row.clone()])
                }
                Posterior::Prior => (&prior[..z], &prior[pz..pz + z]),
            };
            let eps = &w.eps[m][row.clone()];
            let ablated = ablation.0[m];
            kl_terms.clear();
            kl_terms.resize(z, T::ZERO);
            bounded_log_sigma(&mut ls_p_buf, &prior[pz..pz + z], p.log_sigma_bound);
            bounded_log_sigma(&mut ls_q_buf, &a_sigma[..z], p.log_sigma_bound);
            // Every slice is exactly z long, so the loop has no bounds checks and vectorises.
            let (pre, ls_p) = (&prior[..z], &ls_p_buf[..z]);
            let (a_mu, a_sigma, eps) = (&a_mu[..z], &ls_q_buf[..z], &eps[..z]);
            let pre_out = &mut tr.pre_mu_p[row.clone()];
            let mu_p_out = &mut tr.mu_p[row.clone()];
            let ls_p_out = &mut tr.log_sigma_p[row.clone()];
            let ivp_out = &mut tr.inv_var_p[row.clone()];
            let mu_q_out = &mut tr.mu_q[row.clone()];
            let ls_q_out = &mut tr.log_sigma_q[row.clone()];
            let sigma_q_out = &mut tr.sigma_q[row.clone()];
            let z_out = &mut tr.z[row.clone()];
            let kl_out = &mut kl_terms[..z];
            for j in 0..z {
                let mu_p = pre[j].tanh();
                let mu_q = a_mu[j].tanh();
                let sigma_q = a_sigma[j].exp();
                let inv_var_p = (-two * ls_p[j]).exp();
                let diff = mu_p - mu_q;
                // sigma_q^2 / sigma_p^2 from the logs: as a product of exponentials it is
                // inf * 0 = NaN once both log sigmas pass ~44 (f32), which a trained
                // network's prior reaches on unfamiliar states.
                let var_ratio = (two * (a_sigma[j] - ls_p[j])).exp();
                kl_out[j] =
                    ls_p[j] - a_sigma[j] + half * (diff * diff * inv_var_p + var_ratio) - half;
                pre_out[j] = pre[j];
                mu_p_out[j] = mu_p;
                ls_p_out[j] = ls_p[j];
                ivp_out[j] = inv_var_p;
                mu_q_out[j] = mu_q;
                ls_q_out[j] = a_sigma[j];
                sigma_q_out[j] = sigma_q;
                z_out[j] = if ablated {
                    T::ZERO
                } else {
                    mu_q + sigma_q * eps[j]
                };
            }
            tr.kl[t] = kl_terms.iter().map(|k| k.to_f64()).sum::<f64>() / z as f64;

            // MTRNN update.
            u.clear();
            u.extend_from_slice(&pm.bias);
            gemv_padded(&mut u, &pm.wt_dd, d_prev, pm.pd);
            gemv_padded(&mut u, &pm.wt_dz, &tr.z[row], pm.pd);
            if let Some(dp) = parent_d {
                gemv_padded(&mut u, &pm.wt_dh, dp, pm.pd);
            }
            let (h_before, h_now) = tr.h.split_at_mut(t * d);
            let h_prev: &[T] = if t == 0 {
                &tr.h0
            } else {
                &h_before[(t - 1) * d..]
            };
            let (decay, inv_tau, h_prev, u) =
                (&pm.decay[..d], &pm.inv_tau[..d], &h_prev[..d], &u[..d]);
            let (h_now, d_now) = (&mut h_now[..d], &mut d_now[..d]);
            for i in 0..d {
                let h = decay[i].madd(h_prev[i], inv_tau[i] * u[i]);
                h_now[i] = h;
                d_now[i] = h.tanh();
            }
        }
    }
    Trace { len, modules }
}

#[derive(Debug)]
pub(crate) struct WindowGrads<T> {
    pub(crate) a_mu: [Vec<T>; 4],
    pub(crate) a_sigma: [Vec<T>; 4],
    pub(crate) weights: Option<[ModuleWeightGrads<T>; 4]>,
}

/// Back-propagation through the window. `grad_d[m]` is d F / d d_t from the read-out of
/// module m (`[len, d]`), if it has an observed read-out.
pub(crate) fn backward<T: Real>(
    p: &Prepared<T>,
    tr: &Trace<T>,
    grad_d: [Option<&[T]>; 4],
    ablation: &Ablation,
    weight_grads: bool,
) -> WindowGrads<T> {
    simd(
        #[inline(always)]
        || backward_impl(p, tr, grad_d, ablation, weight_grads),
    )
}

#[inline(always)]
fn backward_impl<T: Real>(
    p: &Prepared<T>,
    tr: &Trace<T>,
    grad_d: [Option<&[T]>; 4],
    ablation: &Ablation,
    weight_grads: bool,
) -> WindowGrads<T> {
    let len = tr.len;
    let dims = |m: usize| (p.modules[m].d, p.modules[m].z);
    let mut gd_cur: [Vec<T>; 4] = std::array::from_fn(|m| vec![T::ZERO; p.modules[m].pd]);
    let mut gd_prev: [Vec<T>; 4] = std::array::from_fn(|m| vec![T::ZERO; p.modules[m].pd]);
    let mut gh_next: [Vec<T>; 4] = std::array::from_fn(|m| vec![T::ZERO; dims(m).0]);
    let mut ga_mu: [Vec<T>; 4] = std::array::from_fn(|m| vec![T::ZERO; len * dims(m).1]);
    let mut ga_sigma: [Vec<T>; 4] = std::array::from_fn(|m| vec![T::ZERO; len * dims(m).1]);
    // Per-step pre-activation gradients, kept for the weight gradients.
    let mut gu_all: [Vec<T>; 4] = std::array::from_fn(|m| {
        if weight_grads {
            vec![T::ZERO; len * dims(m).0]
        } else {
            Vec::new()
        }
    });
    let mut gprior_all: [Vec<T>; 4] = std::array::from_fn(|m| {
        if weight_grads {
            vec![T::ZERO; len * 2 * dims(m).1]
        } else {
            Vec::new()
        }
    });
    let mut gz = Vec::new();
    let mut gprior = Vec::new();
    let mut gu = Vec::new();

    for t in (0..len).rev() {
        for m in (0..4).rev() {
            let pm = &p.modules[m];
            let mt = &tr.modules[m];
            let (d, z) = (pm.d, pm.z);
            let c = p.kl_scale[m];

            // d F / d h_t, then the pre-activation u_t = h-update input.
            let d_t = &mt.d[t * d..(t + 1) * d];
            let from_readout = grad_d[m].map(|g| &g[t * d..(t + 1) * d]);
            gu.clear();
            gu.resize(d, T::ZERO);
            let gd = &mut gd_cur[m][..d];
            if let Some(r) = from_readout {
                for (g, &r) in gd.iter_mut().zip(r) {
                    *g += r;
                }
            }
            let (decay, inv_tau, gh_next, gu) = (
                &pm.decay[..d],
                &pm.inv_tau[..d],
                &mut gh_next[m][..d],
                &mut gu[..d],
            );
            for i in 0..d {
                let gh = gd[i].madd(T::ONE - d_t[i] * d_t[i], decay[i] * gh_next[i]);
                gh_next[i] = gh;
                gu[i] = gh * inv_tau[i];
            }
            gemv_padded(&mut gd_prev[m], &pm.w_dd, gu, pm.pd);
            gz.clear();
            gz.resize(pm.pz, T::ZERO);
            if !ablation.0[m] {
                gemv_padded(&mut gz, &pm.w_dz, gu, pm.pz);
            }
            if let Some(pi) = pm.parent {
                let stride = p.modules[pi].pd;
                gemv_padded(&mut gd_cur[pi], &pm.w_dh, gu, stride);
            }

            // Posterior (through z and KL) and prior (through KL).
            gprior.clear();
            gprior.resize(2 * z, T::ZERO);
            let row = t * z..(t + 1) * z;
            latent_grads(
                mt,
                row.clone(),
                &gz[..z],
                c,
                p.log_sigma_bound,
                &mut ga_mu[m][row.clone()],
                &mut ga_sigma[m][row],
                &mut gprior,
            );
            gemv_padded(&mut gd_prev[m], &pm.w_prior, &gprior, pm.pd);
            if weight_grads {
                gu_all[m][t * d..(t + 1) * d].copy_from_slice(gu);
                gprior_all[m][t * 2 * z..(t + 1) * 2 * z].copy_from_slice(&gprior);
            }
        }
        // Gradients w.r.t. d_{t-1} become the current ones; those reaching d_0 (the held or
        // zero initial state) are dropped.
        for m in 0..4 {
            std::mem::swap(&mut gd_cur[m], &mut gd_prev[m]);
            gd_prev[m].fill(T::ZERO);
        }
    }

    let weights = weight_grads.then(|| {
        std::array::from_fn(|m| {
            module_weight_grads(&p.modules[m], tr, m, &gu_all[m], &gprior_all[m])
        })
    });
    WindowGrads {
        a_mu: ga_mu,
        a_sigma: ga_sigma,
        weights,
    }
}

/// One module's step of back-propagation through its latent variables: from d F / d z
/// (`gz`) and the KL term (weighted by `c`) to d F / d the adaptive variables a_mu,
/// a_sigma of the posterior (`ga_mu`, `ga_sigma`) and d F / d the prior's
/// pre-activations (`gprior`: mean, then log sigma).
#[inline(always)] // inside the kernels' SIMD dispatch: `exp` needs its FMA
fn latent_grads<T: Real>(
    mt: &ModuleTrace<T>,
    row: std::ops::Range<usize>,
    gz: &[T],
    c: T,
    log_sigma_bound: Option<T>,
    ga_mu: &mut [T],
    ga_sigma: &mut [T],
    gprior: &mut [T],
) {
    let z = gz.len();
    let (g_mu_p, g_ls_p) = gprior.split_at_mut(z);
    let (g_mu_p, g_ls_p) = (&mut g_mu_p[..z], &mut g_ls_p[..z]);
    let (mu_p, mu_q, ivp) = (
        &mt.mu_p[row.clone()],
        &mt.mu_q[row.clone()],
        &mt.inv_var_p[row.clone()],
    );
    let (ls_q, ls_p) = (&mt.log_sigma_q[row.clone()], &mt.log_sigma_p[row.clone()]);
    let zz = &mt.z[row];
    let two = T::from_f64(2.0);
    // d log sigma / d pre-activation: 1, or 1 - (log sigma / B)^2 under a bound.
    let inv_bound = log_sigma_bound.map_or(T::ZERO, |b| T::ONE / b);
    for j in 0..z {
        // sigma_q^2 / sigma_p^2, from the logs as in the forward pass.
        let var_ratio = (two * (ls_q[j] - ls_p[j])).exp();
        let diff = mu_q[j] - mu_p[j];
        let g_mu_q = gz[j] + c * diff * ivp[j];
        // z - mu_q = sigma_q * eps is d z / d log sigma_q.
        let g_ls_q = gz[j] * (zz[j] - mu_q[j]) + c * (var_ratio - T::ONE);
        let (bq, bp) = (ls_q[j] * inv_bound, ls_p[j] * inv_bound);
        ga_mu[j] = g_mu_q * (T::ONE - mu_q[j] * mu_q[j]);
        ga_sigma[j] = g_ls_q * (T::ONE - bq * bq);
        g_mu_p[j] = -c * diff * ivp[j] * (T::ONE - mu_p[j] * mu_p[j]);
        g_ls_p[j] = c * (T::ONE - diff * diff * ivp[j] - var_ratio) * (T::ONE - bp * bp);
    }
}

/// Sums of outer products over the window, as small matrix products.
fn module_weight_grads<T: Real>(
    pm: &PreparedModule<T>,
    tr: &Trace<T>,
    m: usize,
    gu: &[T],
    gprior: &[T],
) -> ModuleWeightGrads<T> {
    let (d, z, len) = (pm.d, pm.z, tr.len);
    let mt = &tr.modules[m];
    // d_{t-1} for every step of the window.
    let mut d_prev = Vec::with_capacity(len * d);
    d_prev.extend_from_slice(&mt.d0);
    d_prev.extend_from_slice(&mt.d[..(len - 1) * d]);
    let gu_t = MatRef::from_row_major_slice(gu, len, d).transpose();
    let gprior_m = MatRef::from_row_major_slice(gprior, len, 2 * z);
    let outer = |lhs_t: MatRef<'_, T>, rhs: &[T], cols: usize| {
        let mut out = vec![T::ZERO; lhs_t.nrows() * cols];
        faer::linalg::matmul::matmul(
            MatMut::from_row_major_slice_mut(&mut out, lhs_t.nrows(), cols),
            Accum::Replace,
            lhs_t,
            MatRef::from_row_major_slice(rhs, len, cols),
            T::ONE,
            Par::Seq,
        );
        out
    };
    let w_dh = match pm.parent {
        Some(pi) => outer(gu_t, &tr.modules[pi].d, tr.modules[pi].d0.len()),
        None => Vec::new(),
    };
    let col_sum = |range: std::ops::Range<usize>| {
        let mut s = vec![T::ZERO; range.len()];
        for t in 0..len {
            for (acc, &g) in s
                .iter_mut()
                .zip(&gprior[t * 2 * z + range.start..t * 2 * z + range.end])
            {
                *acc += g;
            }
        }
        s
    };
    ModuleWeightGrads {
        w_dd: outer(gu_t, &d_prev, d),
        w_dz: outer(gu_t, &mt.z, z),
        w_dh,
        w_prior_mu: outer(gprior_m.subcols(0, z).transpose(), &d_prev, d),
        w_prior_sigma: outer(gprior_m.subcols(z, z).transpose(), &d_prev, d),
        b_prior_mu: col_sum(0..z),
        b_prior_sigma: col_sum(z..2 * z),
    }
}
