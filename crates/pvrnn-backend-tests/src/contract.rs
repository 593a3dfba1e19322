//! What every backend's loaded model promises besides `evaluate`, checked against
//! `evaluate` itself and against the definitions: the prior's pre-activations of a state,
//! the free prior rollout that initialises a model, and the read-outs the explorer and
//! compact runs use.

use pvrnn_core::backend::{Backend, FullOutputs, Grads, Posterior, Request, Window};
use pvrnn_core::config::ModuleId;
use pvrnn_core::{Ablation, Modality, Model, Observed, Real};

use crate::fixtures::{random_observations, tiny_config, tiny_model, uniform};
use crate::{Shared, SuiteReal};

fn close<T: SuiteReal>(a: &[T], b: &[f64], what: &str) {
    assert_eq!(a.len(), b.len(), "{what}: lengths");
    for (i, (x, y)) in a.iter().zip(b).enumerate() {
        let x = x.to_f64();
        assert!(
            (x - y).abs() <= T::rounding_tolerance(*y),
            "{what}[{i}]: {x} vs {y}"
        );
    }
}

fn to_f64<T: Real>(v: &[T]) -> Vec<f64> {
    v.iter().map(|x| x.to_f64()).collect()
}

pub fn prior_preactivations_are_the_prior_layers_of_the_state<T: SuiteReal>(backend: &Shared<T>) {
    let mut config = tiny_config();
    config.prior_bias = true;
    let mut model = tiny_model(config.clone(), 1, 3, 4);
    for (name, t, _) in model.params.named_mut() {
        if name.contains("b_prior") {
            let v = uniform(t.len(), 3, -0.5, 0.5);
            t.data_mut().copy_from_slice(&v);
        }
    }
    // The definition in f64 on the values the backend sees.
    let model = model.cast::<T>().cast::<f64>();
    let d: Vec<Vec<T>> = ModuleId::ALL
        .iter()
        .map(|id| {
            uniform(config.module(*id).d, 10 + id.index() as u64, -1.0, 1.0)
                .into_iter()
                .map(T::from_f64)
                .collect()
        })
        .collect();
    let loaded = backend.load(&model.params.cast::<T>(), &config);
    let (mu, sigma) = loaded.prior_preactivations(std::array::from_fn(|m| d[m].as_slice()));
    for m in 0..4 {
        let p = &model.params.modules[m];
        let dm = to_f64(&d[m]);
        let by_definition = |w: &pvrnn_core::Tensor<f64>, b: Option<&pvrnn_core::Tensor<f64>>| {
            let cols = w.shape()[1];
            (0..w.shape()[0])
                .map(|j| {
                    b.map_or(0.0, |b| b.data()[j])
                        + (0..cols)
                            .map(|k| w.data()[j * cols + k] * dm[k])
                            .sum::<f64>()
                })
                .collect::<Vec<f64>>()
        };
        close(
            &mu[m],
            &by_definition(&p.w_prior_mu, p.b_prior_mu.as_ref()),
            "mu",
        );
        close(
            &sigma[m],
            &by_definition(&p.w_prior_sigma, p.b_prior_sigma.as_ref()),
            "sigma",
        );
    }
}

pub fn the_prior_rollout_and_the_readouts_agree_with_evaluate<T: SuiteReal>(backend: &Shared<T>) {
    let config = tiny_config();
    let model = tiny_model(config.clone(), 1, 6, 9).cast::<T>();
    let len = 6;
    let data = random_observations::<T>(&config, 1, len, 2);
    let zeros: Vec<Vec<T>> = ModuleId::ALL
        .iter()
        .map(|id| vec![T::ZERO; len * config.module(*id).z])
        .collect();
    let window = Window {
        len,
        h0: None,
        posterior: Posterior::Prior,
        eps: std::array::from_fn(|m| zeros[m].as_slice()),
        targets: Modality::ALL.map(|mo| (0..len).map(|t| data.step(mo, 0, t)).collect()),
    };
    let request = Request {
        observed: Observed::all(&config),
        ablation: Ablation::none(),
        grads: Grads::None,
        full_outputs: FullOutputs::AllSteps,
        resident_targets: None,
    };
    let loaded = backend.load(&model.params, &config);
    let result = loaded
        .evaluate(&[window], &request)
        .unwrap()
        .windows
        .remove(0);
    // The rollout is the prior's pre-activations of the mean path from zero.
    let (a_mu, a_sigma) = loaded.prior_rollout(len);
    for m in 0..4 {
        let trace = &result.trace.modules[m];
        close(&a_mu[m], &to_f64(&trace.pre_mu_p), "rollout a_mu");
        close(&a_sigma[m], &to_f64(&trace.log_sigma_p), "rollout a_sigma");
    }
    // A read-out of the stored d is the full output evaluate computed.
    for modality in Modality::ALL {
        let d = &result.trace.modules[modality.module().index()].d;
        close(
            &loaded.readout(modality, d, len).unwrap(),
            &to_f64(&result.outputs[modality.index()]),
            modality.name(),
        );
    }
    // A model initialised on this backend starts every sequence on that rollout.
    let fresh = Model::<T>::init_on(backend, config.clone(), 2, len, 9).unwrap();
    let (start_mu, start_sigma) = backend.load(&fresh.params, &config).prior_rollout(len);
    for m in 0..4 {
        for s in 0..2 {
            close(
                fresh.adaptive.a_mu[m].sub(&[s]),
                &to_f64(&start_mu[m]),
                "init a_mu",
            );
            close(
                fresh.adaptive.a_sigma[m].sub(&[s]),
                &to_f64(&start_sigma[m]),
                "init a_sigma",
            );
        }
    }
}
