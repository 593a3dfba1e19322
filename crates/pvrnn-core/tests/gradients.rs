//! Exact gradients, proven by central finite differences in f64 on small models.
//!
//! Tolerance: |numeric - analytic| <= 1e-7 + 1e-5 |analytic|. With h = 1e-5 the truncation
//! error of a central difference is ~h^2 * F''' ~ 1e-10 and rounding ~1e-16 * F / h ~ 1e-10,
//! so a wrong term (even a missing factor 1/tau or a sign) fails by orders of magnitude.
#![allow(clippy::unwrap_used)] // test code: a failed unwrap is a failed run

mod common;

#[cfg(target_arch = "wasm32")]
use wasm_bindgen_test::wasm_bindgen_test as test;

use common::{random_observations, tiny_config, tiny_model, uniform};
use pvrnn_core::backend::{Backend, FullOutputs, Grads, Posterior, Request, Window};
use pvrnn_core::config::{AccuracyNormalisation, ModelConfig, ModuleId};
use pvrnn_core::free_energy::{NoiseDraw, free_energy};
use pvrnn_core::params::Role;
use pvrnn_core::{Ablation, Model, NoiseMode, Observations, Observed};

const H: f64 = 1e-5;

fn tolerance(analytic: f64) -> f64 {
    1e-7 + 1e-5 * analytic.abs()
}

fn value(
    backend: &dyn Backend<f64>,
    model: &Model<f64>,
    data: &Observations<f64>,
    noise: NoiseDraw,
) -> f64 {
    free_energy(backend, model, data, noise, false)
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

/// Checks up to `per_tensor` entries of every trainable tensor; returns how many entries
/// with a clearly non-zero gradient were checked per tensor.
fn check_all(
    backend: &dyn Backend<f64>,
    mut model: Model<f64>,
    data: &Observations<f64>,
    noise: NoiseDraw,
    per_tensor: usize,
) {
    let (_, grads) = free_energy(backend, &model, data, noise, true).unwrap();
    let grads = grads.unwrap();
    let mut tensors: Vec<(String, Vec<f64>)> = grads
        .params
        .named()
        .into_iter()
        .filter(|(_, _, role)| *role == Role::Trainable)
        .map(|(n, t, _)| (n, t.data().to_vec()))
        .collect();
    tensors.extend(
        grads
            .adaptive
            .named()
            .into_iter()
            .map(|(n, t)| (n, t.data().to_vec())),
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
            let plus = value(backend, &model, data, noise);
            *entry(&mut model, name, i) = orig - H;
            let minus = value(backend, &model, data, noise);
            *entry(&mut model, name, i) = orig;
            let numeric = (plus - minus) / (2.0 * H);
            if (numeric - g[i]).abs() > tolerance(g[i]) {
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

#[test]
fn learning_gradients_match_finite_differences() {
    common::for_each_backend(|backend: &dyn Backend<f64>| {
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
    });
}

#[test]
fn gradients_with_optional_biases_and_slow_first_taus() {
    common::for_each_backend(|backend: &dyn Backend<f64>| {
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
    });
}

#[test]
fn gradients_with_a_log_sigma_bound() {
    common::for_each_backend(|backend: &dyn Backend<f64>| {
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
        let data = random_observations(&config, 2, 5, 14);
        let noise = NoiseDraw::training(NoiseMode::Sampled { seed: 3 }, 1);
        // The bound changes F: it is in the arithmetic, not only in the configuration.
        let mut unbounded = model.clone();
        unbounded.config.log_sigma_bound = None;
        let (f, f_free) = (
            value(backend, &model, &data, noise),
            value(backend, &unbounded, &data, noise),
        );
        assert!((f - f_free).abs() > 1e-3 * f.abs(), "{f} vs {f_free}");
        check_all(backend, model, &data, noise, 3);
    });
}

#[test]
fn gradients_with_unequal_sequence_lengths_and_zero_noise() {
    common::for_each_backend(|backend: &dyn Backend<f64>| {
        let config = tiny_config();
        let model = tiny_model(config.clone(), 3, 6, 21);
        let full = random_observations::<f64>(&config, 3, 6, 4);
        let data = Observations::new(
            full.tensor(pvrnn_core::Modality::Exteroceptive).clone(),
            full.tensor(pvrnn_core::Modality::Proprioceptive).clone(),
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
    });
}

/// The inference path: a window entering from a held (non-zero) state, partial
/// observation, an ablated module, adaptive-variable gradients only.
#[test]
fn inference_window_gradients_match_finite_differences() {
    common::for_each_backend(|backend: &dyn Backend<f64>| {
        let config: ModelConfig = tiny_config();
        let model = tiny_model(config.clone(), 1, 1, 2);
        let len = 5;
        let data = random_observations::<f64>(&config, 1, len, 33);
        let held: Vec<Vec<f64>> = ModuleId::ALL
            .iter()
            .map(|id| uniform(config.module(*id).d, 70 + id.index() as u64, -1.5, 1.5))
            .collect();
        let mut a_mu: Vec<Vec<f64>> = ModuleId::ALL
            .iter()
            .map(|id| {
                uniform(
                    len * config.module(*id).z,
                    80 + id.index() as u64,
                    -0.7,
                    0.7,
                )
            })
            .collect();
        let mut a_sigma: Vec<Vec<f64>> = ModuleId::ALL
            .iter()
            .map(|id| {
                uniform(
                    len * config.module(*id).z,
                    90 + id.index() as u64,
                    -1.0,
                    0.0,
                )
            })
            .collect();
        let eps: Vec<Vec<f64>> = ModuleId::ALL
            .iter()
            .map(|id| {
                uniform(
                    len * config.module(*id).z,
                    60 + id.index() as u64,
                    -1.5,
                    1.5,
                )
            })
            .collect();

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
            let evaluate = |a_mu: &[Vec<f64>], a_sigma: &[Vec<f64>], grads: Grads| {
                let window = Window {
                    len,
                    h0: Some(std::array::from_fn(|m| held[m].as_slice())),
                    posterior: Posterior::Adaptive {
                        a_mu: std::array::from_fn(|m| a_mu[m].as_slice()),
                        a_sigma: std::array::from_fn(|m| a_sigma[m].as_slice()),
                    },
                    eps: std::array::from_fn(|m| eps[m].as_slice()),
                    targets: pvrnn_core::Modality::ALL
                        .map(|mo| (0..len).map(|t| data.step(mo, 0, t)).collect()),
                };
                let request = Request {
                    observed,
                    ablation,
                    grads,
                    full_outputs: FullOutputs::None,
                    resident_targets: None,
                };
                let r = backend
                    .load(&model.params, &config)
                    .evaluate(&[window], &request)
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
            };
            let (_, r) = evaluate(&a_mu, &a_sigma, Grads::Adaptive);
            let (g_mu, g_sigma) = (r.grad_a_mu.unwrap(), r.grad_a_sigma.unwrap());
            for m in 0..4 {
                for i in 0..a_mu[m].len() {
                    for (which, grad) in [(0, g_mu[m][i]), (1, g_sigma[m][i])] {
                        let target = if which == 0 { &mut a_mu } else { &mut a_sigma };
                        let orig = target[m][i];
                        target[m][i] = orig + H;
                        let plus = evaluate(&a_mu, &a_sigma, Grads::None).0;
                        let target = if which == 0 { &mut a_mu } else { &mut a_sigma };
                        target[m][i] = orig - H;
                        let minus = evaluate(&a_mu, &a_sigma, Grads::None).0;
                        let target = if which == 0 { &mut a_mu } else { &mut a_sigma };
                        target[m][i] = orig;
                        let numeric = (plus - minus) / (2.0 * H);
                        assert!(
                            (numeric - grad).abs() <= tolerance(grad),
                            "{observed:?} {ablation:?} {normalisation:?} module {m} {} [{i}]: analytic {grad:e} numeric {numeric:e}",
                            if which == 0 { "a_mu" } else { "a_sigma" }
                        );
                    }
                }
            }
        }
    });
}

/// Unobserved output rows take no part in the free energy, so their weights get no gradient.
#[test]
fn unobserved_outputs_get_no_weight_gradient() {
    common::for_each_backend(|backend: &dyn Backend<f64>| {
        let config = tiny_config();
        let model = tiny_model(config.clone(), 1, 4, 6);
        let data = random_observations::<f64>(&config, 1, 4, 7);
        let eps: Vec<Vec<f64>> = ModuleId::ALL
            .iter()
            .map(|id| vec![0.0; 4 * config.module(*id).z])
            .collect();
        let window = Window {
            len: 4,
            h0: None,
            posterior: Posterior::Adaptive {
                a_mu: std::array::from_fn(|m| model.adaptive.a_mu[m].data()),
                a_sigma: std::array::from_fn(|m| model.adaptive.a_sigma[m].data()),
            },
            eps: std::array::from_fn(|m| eps[m].as_slice()),
            targets: pvrnn_core::Modality::ALL
                .map(|mo| (0..4).map(|t| data.step(mo, 0, t)).collect()),
        };
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
            .evaluate(&[window], &request);
        let g = r.grad_params.unwrap();
        let w = g.readouts[0].out.weight.data();
        let hidden = g.readouts[0].out.weight.shape()[1];
        let observed_rows = config.vision.observed_dims(1);
        assert!(w[..observed_rows * hidden].iter().any(|&v| v != 0.0));
        assert!(w[observed_rows * hidden..].iter().all(|&v| v == 0.0));
    });
}

/// `accuracy_normalisation = "full"` divides the vision error by all 32,256-style dimensions
/// instead of the observed ones: the same sum, scaled by observed / full.
#[test]
fn full_accuracy_normalisation_scales_by_the_observed_fraction() {
    common::for_each_backend(|backend: &dyn Backend<f64>| {
        let config = tiny_config();
        let model = tiny_model(config.clone(), 1, 3, 6);
        let data = random_observations::<f64>(&config, 1, 3, 8);
        let eps: Vec<Vec<f64>> = ModuleId::ALL
            .iter()
            .map(|id| vec![0.0; 3 * config.module(*id).z])
            .collect();
        let observed = Observed {
            vision_levels: 1,
            proprio: true,
        };
        let accuracy = |normalisation| {
            let mut config = config.clone();
            config.accuracy_normalisation = normalisation;
            let window = Window {
                len: 3,
                h0: None,
                posterior: Posterior::Adaptive {
                    a_mu: std::array::from_fn(|m| model.adaptive.a_mu[m].data()),
                    a_sigma: std::array::from_fn(|m| model.adaptive.a_sigma[m].data()),
                },
                eps: std::array::from_fn(|m| eps[m].as_slice()),
                targets: pvrnn_core::Modality::ALL
                    .map(|mo| (0..3).map(|t| data.step(mo, 0, t)).collect()),
            };
            let request = Request {
                observed,
                ablation: Ablation::none(),
                grads: Grads::None,
                full_outputs: FullOutputs::None,
                resident_targets: None,
            };
            let mut r = backend
                .load(&model.params, &config)
                .evaluate(&[window], &request);
            r.windows.remove(0).accuracy
        };
        let by_observed = accuracy(AccuracyNormalisation::Observed);
        let by_full = accuracy(AccuracyNormalisation::Full);
        let fraction = config.vision.observed_dims(1) as f64
            / config.modality_dims(pvrnn_core::Modality::Exteroceptive) as f64;
        for t in 0..3 {
            let expected = by_observed[0][t] * fraction;
            assert!(
                (by_full[0][t] - expected).abs() <= 1e-12 * expected.abs(),
                "step {t}"
            );
            // Proprioception is fully observed: both divisors are the same.
            assert_eq!(by_full[1][t], by_observed[1][t]);
        }
        assert!(fraction < 1.0);
    });
}
