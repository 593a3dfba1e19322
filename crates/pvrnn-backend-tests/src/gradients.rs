//! Exact gradients: a backend's analytic gradients against central finite differences of
//! the free energy, computed in f64 on the CPU for the same values rounded to the
//! backend's precision, on small models with every structural feature.

use pvrnn_core::backend::{Backend, FullOutputs, Grads, Posterior, Request, Window, WindowResult};
use pvrnn_core::config::{AccuracyNormalisation, ModelConfig, ModuleId};
use pvrnn_core::cpu::CpuBackend;
use pvrnn_core::free_energy::{NoiseDraw, free_energy};
use pvrnn_core::params::{Params, Role};
use pvrnn_core::{Ablation, Modality, Model, NoiseMode, Observations, Observed, Real};

use crate::fixtures::{random_observations, tiny_config, tiny_model, uniform};
use crate::{Shared, SuiteReal, rounded};

/// The finite-difference step.
const H: f64 = 1e-5;

/// F of `model` on `data` in f64 on the CPU: the reference.
fn reference_value(model: &Model<f64>, data: &Observations<f64>, noise: NoiseDraw) -> f64 {
    free_energy(&CpuBackend, model, data, noise, false)
        .unwrap()
        .0
        .total
}

fn entry<'a>(model: &'a mut Model<f64>, name: &str, i: usize) -> &'a mut f64 {
    for (n, t, _) in model.params.named_mut() {
        if n == name {
            return &mut t.data_mut()[i];
        }
    }
    for (n, t) in model.adaptive.named_mut() {
        if n == name {
            return &mut t.data_mut()[i];
        }
    }
    panic!("no tensor {name}")
}

/// Checks up to `per_tensor` entries of every trainable tensor (and its largest gradient),
/// and the free energy itself.
fn check_all<T: SuiteReal>(
    backend: &dyn Backend<T>,
    model: Model<f64>,
    data: &Observations<f64>,
    noise: NoiseDraw,
    per_tensor: usize,
) {
    // The values the backend sees, exactly, so that only arithmetic separates the two.
    let mut model = model.cast::<T>().cast::<f64>();
    let data = data.cast::<T>().cast::<f64>();
    let (energy, grads) =
        free_energy(backend, &model.cast::<T>(), &data.cast::<T>(), noise, true).unwrap();
    let reference = reference_value(&model, &data, noise);
    assert!(
        (energy.total - reference).abs() <= T::rounding_tolerance(reference) * 10.0,
        "free energy {} against the f64 reference {reference}",
        energy.total
    );
    let grads = grads.unwrap();
    let mut tensors: Vec<(String, Vec<f64>)> = grads
        .params
        .named()
        .into_iter()
        .filter(|(_, _, role)| *role == Role::Trainable)
        .map(|(n, t, _)| (n, t.data().iter().map(|v| v.to_f64()).collect()))
        .collect();
    tensors.extend(
        grads
            .adaptive
            .named()
            .into_iter()
            .map(|(n, t)| (n, t.data().iter().map(|v| v.to_f64()).collect())),
    );
    assert!(tensors.len() >= 30, "every trainable tensor is listed");
    let mut failures = Vec::new();
    for (name, g) in &tensors {
        // Entries spread over the tensor, plus the largest gradient.
        let mut picks: Vec<usize> = (0..per_tensor).map(|k| k * g.len() / per_tensor).collect();
        let largest = (0..g.len())
            .max_by(|&a, &b| g[a].abs().total_cmp(&g[b].abs()))
            .unwrap();
        picks.push(largest);
        picks.dedup();
        let mut nonzero = 0;
        for &i in &picks {
            let orig = *entry(&mut model, name, i);
            *entry(&mut model, name, i) = orig + H;
            let plus = reference_value(&model, &data, noise);
            *entry(&mut model, name, i) = orig - H;
            let minus = reference_value(&model, &data, noise);
            *entry(&mut model, name, i) = orig;
            let numeric = (plus - minus) / (2.0 * H);
            if (numeric - g[i]).abs() > T::gradient_tolerance(numeric) {
                failures.push(format!(
                    "{name}[{i}]: analytic {:.10e} numeric {:.10e}",
                    g[i], numeric
                ));
            }
            if g[i].abs() > 1e-6 {
                nonzero += 1;
            }
        }
        assert!(
            nonzero > 0,
            "{name}: every checked gradient is ~0, the check proves nothing"
        );
    }
    assert!(
        failures.is_empty(),
        "gradient mismatches:\n{}",
        failures.join("\n")
    );
}

pub fn learning_gradients_match_finite_differences<T: SuiteReal>(backend: &dyn Backend<T>) {
    let config = tiny_config();
    let model = tiny_model(config.clone(), 2, 6, 3);
    let data = random_observations(&config, 2, 6, 11);
    check_all(
        backend,
        model,
        &data,
        NoiseDraw::training(NoiseMode::Sampled { seed: 5 }, 0),
        4,
    );
}

pub fn gradients_with_optional_biases_and_slow_first_taus<T: SuiteReal>(backend: &Shared<T>) {
    let mut config = tiny_config();
    config.prior_bias = true;
    config.exteroceptive_readout.output_bias = true;
    config.proprioceptive_readout.hidden_bias = false;
    config.tau_order = pvrnn_core::config::TauOrder::SlowFirst;
    let mut model = tiny_model(config.clone(), 2, 5, 8);
    // Biases start at zero; move them so their gradients are generic.
    for (name, t, _) in model.params.named_mut() {
        if name.contains("b_prior") || name.ends_with("out.bias") {
            let v = uniform(t.len(), name.len() as u64, -0.3, 0.3);
            t.data_mut().copy_from_slice(&v);
        }
    }
    let data = random_observations(&config, 2, 5, 12);
    check_all(
        backend,
        model,
        &data,
        NoiseDraw::training(NoiseMode::Sampled { seed: 9 }, 4),
        3,
    );
}

pub fn gradients_with_a_log_sigma_bound<T: SuiteReal>(backend: &dyn Backend<T>) {
    let mut config = tiny_config();
    // Small enough that many log sigmas sit on the tanh's curve, not its linear middle.
    config.log_sigma_bound = Some(0.4);
    let mut model = tiny_model(config.clone(), 2, 5, 13);
    for (name, t) in model.adaptive.named_mut() {
        if name.ends_with("a_sigma") {
            let v = uniform(t.len(), name.len() as u64, -1.5, 1.5);
            t.data_mut().copy_from_slice(&v);
        }
    }
    let data = random_observations::<f64>(&config, 2, 5, 14);
    let noise = NoiseDraw::training(NoiseMode::Sampled { seed: 3 }, 1);
    // The bound changes F on this backend: it is in the arithmetic, not only in the
    // configuration.
    let mut unbounded = model.clone();
    unbounded.config.log_sigma_bound = None;
    let value = |m: &Model<f64>| {
        free_energy(backend, &m.cast::<T>(), &data.cast::<T>(), noise, false)
            .unwrap()
            .0
            .total
    };
    let (f, f_free) = (value(&model), value(&unbounded));
    assert!((f - f_free).abs() > 1e-3 * f.abs(), "{f} vs {f_free}");
    check_all(backend, model, &data, noise, 3);
}

pub fn gradients_with_unequal_sequence_lengths_and_zero_noise<T: SuiteReal>(backend: &Shared<T>) {
    let config = tiny_config();
    let model = tiny_model(config.clone(), 3, 6, 21);
    let full = random_observations::<f64>(&config, 3, 6, 4);
    let data = Observations::new(
        full.tensor(Modality::Exteroceptive).clone(),
        full.tensor(Modality::Proprioceptive).clone(),
        Some(vec![6, 3, 5]),
    )
    .unwrap();
    check_all(
        backend,
        model,
        &data,
        NoiseDraw::training(NoiseMode::Zero, 0),
        3,
    );
}

/// One inference window's inputs, in f64 (rounded to the backend's precision).
struct WindowInputs {
    len: usize,
    held: Vec<Vec<f64>>,
    a_mu: Vec<Vec<f64>>,
    a_sigma: Vec<Vec<f64>>,
    eps: Vec<Vec<f64>>,
    data: Observations<f64>,
}

/// What one window is asked for.
#[derive(Clone, Copy, Debug)]
struct WindowQuery {
    observed: Observed,
    ablation: Ablation,
    grads: Grads,
}

fn adaptive_entry(inputs: &mut WindowInputs, sigma: bool, m: usize, i: usize) -> &mut f64 {
    if sigma {
        &mut inputs.a_sigma[m][i]
    } else {
        &mut inputs.a_mu[m][i]
    }
}

/// The window's free energy on `backend` in `U`, and its results.
fn window_energy<U: Real>(
    backend: &dyn Backend<U>,
    params: &Params<f64>,
    config: &ModelConfig,
    inputs: &WindowInputs,
    query: WindowQuery,
) -> (f64, WindowResult<U>) {
    let cast = |v: &[Vec<f64>]| -> Vec<Vec<U>> {
        v.iter()
            .map(|x| x.iter().map(|&y| U::from_f64(y)).collect())
            .collect()
    };
    let (held, a_mu, a_sigma, eps) = (
        cast(&inputs.held),
        cast(&inputs.a_mu),
        cast(&inputs.a_sigma),
        cast(&inputs.eps),
    );
    let data = inputs.data.cast::<U>();
    let len = inputs.len;
    let window = Window {
        len,
        h0: Some(std::array::from_fn(|m| held[m].as_slice())),
        posterior: Posterior::Adaptive {
            a_mu: std::array::from_fn(|m| a_mu[m].as_slice()),
            a_sigma: std::array::from_fn(|m| a_sigma[m].as_slice()),
        },
        eps: std::array::from_fn(|m| eps[m].as_slice()),
        targets: Modality::ALL.map(|mo| (0..len).map(|t| data.step(mo, 0, t)).collect()),
    };
    let request = Request {
        observed: query.observed,
        ablation: query.ablation,
        grads: query.grads,
        full_outputs: FullOutputs::None,
        resident_targets: None,
    };
    let r = backend
        .load(&params.cast::<U>(), config)
        .evaluate(&[window], &request)
        .unwrap()
        .windows
        .remove(0);
    let f: f64 = r.accuracy.iter().flatten().sum::<f64>()
        + config.kl_weight
            * r.trace
                .modules
                .iter()
                .map(|m| m.kl.iter().sum::<f64>())
                .sum::<f64>();
    (f, r)
}

/// The inference path: a window entering from a held (non-zero) state, partial
/// observation, an ablated module, adaptive-variable gradients only.
pub fn inference_window_gradients_match_finite_differences<T: SuiteReal>(backend: &Shared<T>) {
    let config: ModelConfig = tiny_config();
    let model = tiny_model(config.clone(), 1, 1, 2);
    let params = model.params.cast::<T>().cast::<f64>();
    let len = 5;
    let per_module = |seed: u64, lo: f64, hi: f64, width: &dyn Fn(ModuleId) -> usize| {
        ModuleId::ALL
            .iter()
            .map(|id| rounded::<T>(&uniform(width(*id), seed + id.index() as u64, lo, hi)))
            .collect::<Vec<_>>()
    };
    let d = |id: ModuleId| config.module(id).d;
    let z = |id: ModuleId| len * config.module(id).z;
    let mut inputs = WindowInputs {
        len,
        held: per_module(70, -1.5, 1.5, &d),
        a_mu: per_module(80, -0.7, 0.7, &z),
        a_sigma: per_module(90, -1.0, 0.0, &z),
        eps: per_module(60, -1.5, 1.5, &z),
        data: random_observations::<T>(&config, 1, len, 33).cast::<f64>(),
    };
    for (observed, ablation, normalisation) in [
        (
            Observed {
                vision_levels: 1,
                proprio: false,
            },
            Ablation::of(&[ModuleId::Associative]),
            AccuracyNormalisation::Observed,
        ),
        (
            Observed {
                vision_levels: 2,
                proprio: true,
            },
            Ablation::of(&[ModuleId::Exteroceptive]),
            AccuracyNormalisation::Observed,
        ),
        (
            Observed {
                vision_levels: 1,
                proprio: true,
            },
            Ablation::none(),
            AccuracyNormalisation::Full,
        ),
        (
            Observed {
                vision_levels: 0,
                proprio: true,
            },
            Ablation::none(),
            AccuracyNormalisation::Observed,
        ),
    ] {
        let mut config = config.clone();
        config.accuracy_normalisation = normalisation;
        let query = |grads| WindowQuery {
            observed,
            ablation,
            grads,
        };
        let (_, r) = window_energy(backend, &params, &config, &inputs, query(Grads::Adaptive));
        let (g_mu, g_sigma) = (r.grad_a_mu.unwrap(), r.grad_a_sigma.unwrap());
        for m in 0..4 {
            for i in 0..inputs.a_mu[m].len() {
                for (which, grad) in [(0, g_mu[m][i]), (1, g_sigma[m][i])] {
                    let grad = grad.to_f64();
                    let sigma = which == 1;
                    let orig = *adaptive_entry(&mut inputs, sigma, m, i);
                    *adaptive_entry(&mut inputs, sigma, m, i) = orig + H;
                    let plus = window_energy::<f64>(
                        &CpuBackend,
                        &params,
                        &config,
                        &inputs,
                        query(Grads::None),
                    )
                    .0;
                    *adaptive_entry(&mut inputs, sigma, m, i) = orig - H;
                    let minus = window_energy::<f64>(
                        &CpuBackend,
                        &params,
                        &config,
                        &inputs,
                        query(Grads::None),
                    )
                    .0;
                    *adaptive_entry(&mut inputs, sigma, m, i) = orig;
                    let numeric = (plus - minus) / (2.0 * H);
                    assert!(
                        (numeric - grad).abs() <= T::gradient_tolerance(numeric),
                        "{observed:?} {ablation:?} {normalisation:?} module {m} {} [{i}]: analytic {grad:e} numeric {numeric:e}",
                        if which == 0 { "a_mu" } else { "a_sigma" }
                    );
                }
            }
        }
    }
}

/// A window over `model`'s first sequence with zero eps, for the two checks below.
fn plain_window<'a, T: Real>(
    model: &'a Model<T>,
    data: &'a Observations<T>,
    eps: &'a [Vec<T>],
    len: usize,
) -> Window<'a, T> {
    Window {
        len,
        h0: None,
        posterior: Posterior::Adaptive {
            a_mu: std::array::from_fn(|m| model.adaptive.a_mu[m].data()),
            a_sigma: std::array::from_fn(|m| model.adaptive.a_sigma[m].data()),
        },
        eps: std::array::from_fn(|m| eps[m].as_slice()),
        targets: Modality::ALL.map(|mo| (0..len).map(|t| data.step(mo, 0, t)).collect()),
    }
}

fn zero_eps<T: Real>(config: &ModelConfig, len: usize) -> Vec<Vec<T>> {
    ModuleId::ALL
        .iter()
        .map(|id| vec![T::ZERO; len * config.module(*id).z])
        .collect()
}

/// Unobserved output rows take no part in the free energy, so their weights get no gradient.
pub fn unobserved_outputs_get_no_weight_gradient<T: SuiteReal>(backend: &dyn Backend<T>) {
    let config = tiny_config();
    let model = tiny_model(config.clone(), 1, 4, 6).cast::<T>();
    let data = random_observations::<T>(&config, 1, 4, 7);
    let eps = zero_eps::<T>(&config, 4);
    let request = Request {
        observed: Observed {
            vision_levels: 1,
            proprio: true,
        },
        ablation: Ablation::none(),
        grads: Grads::All,
        full_outputs: FullOutputs::None,
        resident_targets: None,
    };
    let r = backend
        .load(&model.params, &config)
        .evaluate(&[plain_window(&model, &data, &eps, 4)], &request)
        .unwrap();
    let g = r.grad_params.unwrap();
    let w = g.readouts[0].out.weight.data();
    let hidden = g.readouts[0].out.weight.shape()[1];
    let observed_rows = config.vision.observed_dims(1);
    assert!(w[..observed_rows * hidden].iter().any(|&v| v != T::ZERO));
    assert!(w[observed_rows * hidden..].iter().all(|&v| v == T::ZERO));
}

/// `accuracy_normalisation = "full"` divides the vision error by all of the modality's
/// dimensions instead of the observed ones: the same sum, scaled by observed / full.
pub fn full_accuracy_normalisation_scales_by_the_observed_fraction<T: SuiteReal>(
    backend: &Shared<T>,
) {
    let config = tiny_config();
    let model = tiny_model(config.clone(), 1, 3, 6).cast::<T>();
    let data = random_observations::<T>(&config, 1, 3, 8);
    let eps = zero_eps::<T>(&config, 3);
    let accuracy = |normalisation| {
        let mut config = config.clone();
        config.accuracy_normalisation = normalisation;
        let request = Request {
            observed: Observed {
                vision_levels: 1,
                proprio: true,
            },
            ablation: Ablation::none(),
            grads: Grads::None,
            full_outputs: FullOutputs::None,
            resident_targets: None,
        };
        let mut r = backend
            .load(&model.params, &config)
            .evaluate(&[plain_window(&model, &data, &eps, 3)], &request)
            .unwrap();
        r.windows.remove(0).accuracy
    };
    let by_observed = accuracy(AccuracyNormalisation::Observed);
    let by_full = accuracy(AccuracyNormalisation::Full);
    let fraction = config.vision.observed_dims(1) as f64
        / config.modality_dims(Modality::Exteroceptive) as f64;
    for t in 0..3 {
        let expected = by_observed[0][t] * fraction;
        assert!(
            (by_full[0][t] - expected).abs() <= T::rounding_tolerance(expected),
            "step {t}: {} against {expected}",
            by_full[0][t]
        );
        // Proprioception is fully observed: both divisors are the same.
        assert_eq!(by_full[1][t], by_observed[1][t]);
    }
    assert!(fraction < 1.0);
}
