//! Rectified Adam (Liu et al. 2020), following PyTorch's `torch.optim.RAdam` except that the
//! rectification threshold on rho_t is a setting (the spec decides 4; PyTorch uses 5).

use crate::Real;
use crate::config::RAdamConfig;

/// RAdam moments for a list of tensors (flat slices), in a fixed order.
#[derive(Clone, Debug, PartialEq)]
pub struct RAdam<T> {
    pub config: RAdamConfig,
    /// Updates taken since the last reset.
    pub step: u64,
    pub m: Vec<Vec<T>>,
    pub v: Vec<Vec<T>>,
}

impl<T: Real> RAdam<T> {
    pub fn new(config: RAdamConfig, sizes: &[usize]) -> Self {
        Self {
            config,
            step: 0,
            m: sizes.iter().map(|&n| vec![T::ZERO; n]).collect(),
            v: sizes.iter().map(|&n| vec![T::ZERO; n]).collect(),
        }
    }

    /// Forgets the moments (inference does this at every new step).
    pub fn reset(&mut self) {
        self.step = 0;
        for m in self.m.iter_mut().chain(self.v.iter_mut()) {
            m.fill(T::ZERO);
        }
    }

    /// One update of every tensor; `params[i]` and `grads[i]` match the sizes given to `new`.
    pub fn update(&mut self, params: &mut [&mut [T]], grads: &[&[T]]) {
        assert_eq!(params.len(), self.m.len());
        assert_eq!(grads.len(), self.m.len());
        let step = self.begin_step();
        for (i, (p, g)) in params.iter_mut().zip(grads).enumerate() {
            self.apply(&step, i, p, g);
        }
    }

    /// Counts one more update and returns its scalars: [`Self::update`] in two parts, so that
    /// a learner may apply the same step to tensors it keeps elsewhere (on a GPU) and the
    /// host applies it to the rest with [`Self::apply`].
    pub fn begin_step(&mut self) -> RAdamStep {
        self.step += 1;
        let c = &self.config;
        let t = self.step as f64;
        let bias1 = 1.0 - c.beta1.powf(t);
        let bias2 = 1.0 - c.beta2.powf(t);
        let rho_inf = 2.0 / (1.0 - c.beta2) - 1.0;
        let rho_t = rho_inf - 2.0 * t * c.beta2.powf(t) / bias2;
        // With rectification: p -= lr * m_hat * r * sqrt(bias2) / (sqrt(v) + eps);
        // without: p -= lr * m_hat (momentum SGD while the variance estimate is unreliable).
        let rect = (rho_t > c.rectify_threshold).then(|| {
            ((rho_t - 4.0) * (rho_t - 2.0) * rho_inf / ((rho_inf - 4.0) * (rho_inf - 2.0) * rho_t))
                .sqrt()
        });
        RAdamStep {
            beta1: c.beta1,
            beta2: c.beta2,
            weight_decay: c.weight_decay,
            eps: c.eps,
            sqrt_bias2: bias2.sqrt(),
            plain: c.lr / bias1,
            rectified: rect.map(|r| c.lr / bias1 * r),
        }
    }

    /// Applies `step` (from [`Self::begin_step`]) to tensor `i`.
    pub fn apply(&mut self, step: &RAdamStep, i: usize, p: &mut [T], g: &[T]) {
        let s = Step {
            b1: T::from_f64(step.beta1),
            b2: T::from_f64(step.beta2),
            one_b1: T::from_f64(1.0 - step.beta1),
            one_b2: T::from_f64(1.0 - step.beta2),
            wd: T::from_f64(step.weight_decay),
            eps: T::from_f64(step.eps),
            sqrt_bias2: T::from_f64(step.sqrt_bias2),
            plain: T::from_f64(step.plain),
            rectified: step.rectified.map(T::from_f64),
        };
        let _phase = crate::profile::phase("optimiser (RAdam)");
        let (m, v) = (&mut self.m[i], &mut self.v[i]);
        let n = p.len();
        crate::parallel::for_each_chunk4(p, &mut m[..n], &mut v[..n], &g[..n], |p, m, v, g| {
            crate::kernels::simd(
                #[inline(always)]
                || update_tensor(&s, p, m, v, g),
            )
        });
    }
}

/// The scalars of one RAdam update, the same for every tensor (see [`RAdam::begin_step`]):
/// with `g' = g + weight_decay * p`, `m = beta1 m + (1 - beta1) g'`, `v = beta2 v + (1 -
/// beta2) g'^2`, then `p -= rectified * m * sqrt_bias2 / (sqrt(v) + eps)` when rectified,
/// else `p -= plain * m`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RAdamStep {
    pub beta1: f64,
    pub beta2: f64,
    pub weight_decay: f64,
    pub eps: f64,
    pub sqrt_bias2: f64,
    pub plain: f64,
    pub rectified: Option<f64>,
}

/// The scalars of one RAdam step.
#[derive(Clone, Copy, Debug)]
struct Step<T> {
    b1: T,
    b2: T,
    one_b1: T,
    one_b2: T,
    wd: T,
    eps: T,
    sqrt_bias2: T,
    plain: T,
    rectified: Option<T>,
}

// Slice arguments (not captured variables) tell the compiler the four arrays do not alias,
// which it needs to vectorise.
#[inline(always)]
fn update_tensor<T: Real>(s: &Step<T>, p: &mut [T], m: &mut [T], v: &mut [T], g: &[T]) {
    let n = p.len();
    let (m, v, g) = (&mut m[..n], &mut v[..n], &g[..n]);
    for j in 0..n {
        let gj = s.wd.madd(p[j], g[j]);
        m[j] = s.b1.madd(m[j], s.one_b1 * gj);
        v[j] = s.b2.madd(v[j], s.one_b2 * gj * gj);
    }
    match s.rectified {
        Some(r) => {
            for j in 0..n {
                p[j] -= r * m[j] * s.sqrt_bias2 / (v[j].sqrt() + s.eps);
            }
        }
        None => {
            for j in 0..n {
                p[j] -= s.plain * m[j];
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::ModelConfig;
    #[cfg(target_arch = "wasm32")]
    use wasm_bindgen_test::wasm_bindgen_test as test;

    /// While rho_t <= 4 (the first steps with beta2 = 0.999) an update is momentum SGD with
    /// bias correction, checked here in closed form.
    #[test]
    fn first_steps_are_bias_corrected_momentum() {
        let mut cfg = ModelConfig::default().train.optimizer;
        cfg.lr = 0.1;
        let mut opt = RAdam::<f64>::new(cfg.clone(), &[1]);
        let mut p = [1.0f64];
        let g1 = 2.0 * p[0];
        opt.update(&mut [&mut p], &[&[g1]]);
        // m = 0.1 g, m_hat = g
        assert!((p[0] - (1.0 - 0.1 * g1)).abs() < 1e-12);
        let g2 = 2.0 * p[0];
        let m2 = 0.9 * 0.1 * g1 + 0.1 * g2;
        let expect = p[0] - 0.1 * m2 / (1.0 - 0.81);
        opt.update(&mut [&mut p], &[&[g2]]);
        assert!((p[0] - expect).abs() < 1e-12);
    }

    #[test]
    fn rectified_phase_descends_and_reset_forgets() {
        let mut cfg = ModelConfig::default().train.optimizer;
        cfg.lr = 0.05;
        let mut opt = RAdam::<f64>::new(cfg, &[2]);
        let mut p = [1.0f64, -2.0];
        for _ in 0..600 {
            let g = [2.0 * p[0], 2.0 * p[1]];
            opt.update(&mut [&mut p], &[&g]);
        }
        assert!(p[0].abs() < 0.05 && p[1].abs() < 0.05, "{p:?}");
        opt.reset();
        assert_eq!(opt.step, 0);
        assert!(opt.m[0].iter().all(|&v| v == 0.0));
    }
}
