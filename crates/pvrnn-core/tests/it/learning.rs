//! Online inference's window, seeds, ablations and guards on a briefly trained model (CPU).
//! That learning lowers the free energy and inference tracks the sequence on every backend
//! is the backend suite's (crates/pvrnn-backend-tests).

use crate::fixtures;

#[cfg(target_arch = "wasm32")]
use wasm_bindgen_test::wasm_bindgen_test as test;

use std::sync::Arc;

use fixtures::{learning_config, sine_observations};
use pvrnn_core::infer::{InferenceSettings, OnlineInference};
use pvrnn_core::run_sequence;
use pvrnn_core::train::Trainer;
use pvrnn_core::{Ablation, AblationMode, Modality, Model, ModuleId, NoiseMode, Observations};

fn trained(iterations: usize) -> (Trainer<f32>, Observations<f32>, f64, f64) {
    let config = learning_config();
    let data = sine_observations::<f32>(&config, 2, 48);
    let model = Model::<f32>::init(config, 2, 48, 1).unwrap();
    let mut trainer = Trainer::new(model, NoiseMode::Sampled { seed: 1 });
    let first = trainer.step(&data).unwrap().total;
    let mut last = first;
    for _ in 1..iterations {
        last = trainer.step(&data).unwrap().total;
    }
    (trainer, data, first, last)
}

#[test]
fn window_grows_then_slides() {
    let config = learning_config();
    let data = sine_observations::<f32>(&config, 1, 12);
    let model = Arc::new(Model::<f32>::init(config.clone(), 1, 12, 2).unwrap());
    let mut settings = InferenceSettings::from_config(&config, 1);
    settings.window = 5;
    settings.iterations = 3;
    let mut inf = OnlineInference::new(model, settings).unwrap();
    for t in 0..12 {
        inf.begin_step(
            data.step(Modality::Exteroceptive, 0, t),
            data.step(Modality::Proprioceptive, 0, t),
        )
        .unwrap();
        assert_eq!(inf.window_len(), (t + 1).min(5));
        assert_eq!(inf.iterations_left(), 3);
        assert_eq!(inf.iterate(2).unwrap(), 1);
        let out = inf.finish_step().unwrap();
        assert_eq!(out.t, t);
        assert_eq!(out.recon[0].len(), config.vision.dims());
        assert_eq!(
            out.modules[ModuleId::Exteroceptive.index()].mu_q.len(),
            config.exteroceptive.z
        );
        assert!(
            out.modules
                .iter()
                .all(|m| m.sigma_p.iter().all(|&s| s > 0.0))
        );
    }
    assert_eq!(inf.steps_done(), 12);
}

#[test]
fn same_seed_same_result_and_zero_noise_ignores_seed() {
    let config = learning_config();
    let data = sine_observations::<f32>(&config, 2, 10);
    let run = |noise: NoiseMode| {
        let model = Model::<f32>::init(config.clone(), 2, 10, 4).unwrap();
        let mut t = Trainer::new(model, noise);
        let reports: Vec<f64> = (0..3).map(|_| t.step(&data).unwrap().total).collect();
        (reports, t.into_model())
    };
    let (a, ma) = run(NoiseMode::Sampled { seed: 1 });
    let (b, mb) = run(NoiseMode::Sampled { seed: 1 });
    let (c, _) = run(NoiseMode::Sampled { seed: 2 });
    assert_eq!(a, b);
    assert_eq!(ma, mb);
    assert_ne!(a[1], c[1]);
    let (z1, _) = run(NoiseMode::Zero);
    let (z2, _) = run(NoiseMode::Zero);
    assert_eq!(z1, z2);

    let model = Arc::new(ma);
    let infer = |seed| {
        let mut s = InferenceSettings::from_config(&config, seed);
        s.window = 4;
        s.iterations = 5;
        run_sequence(model.clone(), s, &data, 1, true, &mut |_, _| {}).unwrap()
    };
    assert_eq!(infer(7), infer(7));
    assert_ne!(infer(7).recon.unwrap()[0], infer(8).recon.unwrap()[0]);
}

#[test]
fn ablating_a_module_changes_the_prediction() {
    let (trainer, data, _, _) = trained(60);
    let model = Arc::new(trainer.into_model());
    let run = |ablation, mode| {
        let mut s = InferenceSettings::from_config(&model.config, 3);
        s.window = 6;
        s.iterations = 5;
        s.noise = NoiseMode::Zero;
        s.ablation = ablation;
        s.ablation_mode = mode;
        run_sequence(model.clone(), s, &data, 0, true, &mut |_, _| {}).unwrap()
    };
    let standard = run(Ablation::none(), AblationMode::Readout);
    for id in ModuleId::ALL {
        let ablated = run(Ablation::of(&[id]), AblationMode::Inference);
        let diff: f32 = standard.recon.as_ref().unwrap()[0]
            .data()
            .iter()
            .zip(ablated.recon.as_ref().unwrap()[0].data())
            .map(|(a, b)| (a - b).abs())
            .sum();
        assert!(diff > 1e-3, "ablating {} changed nothing", id.name());
    }
}

/// `readout` ablation leaves the inference as it is (same free energy at every step) and
/// changes only what is read out; `inference` ablation changes the inference itself. The
/// extra read-outs of one standard run equal the `readout` runs, module by module.
#[test]
fn readout_ablation_rereads_the_standard_inference() {
    let (trainer, data, _, _) = trained(60);
    let model = Arc::new(trainer.into_model());
    let settings = |ablation, mode| {
        let mut s = InferenceSettings::from_config(&model.config, 5);
        s.window = 4;
        s.iterations = 4;
        s.ablation = ablation;
        s.ablation_mode = mode;
        s
    };
    let run = |ablation, mode| {
        run_sequence(
            model.clone(),
            settings(ablation, mode),
            &data,
            1,
            true,
            &mut |_, _| {},
        )
        .unwrap()
    };
    let standard = run(Ablation::none(), AblationMode::Readout);
    // One standard run with every module's read-out ablation.
    let mut inference = OnlineInference::new(
        model.clone(),
        settings(Ablation::none(), AblationMode::Readout),
    )
    .unwrap();
    let singles: Vec<Ablation> = ModuleId::ALL
        .iter()
        .map(|id| Ablation::of(&[*id]))
        .collect();
    inference.set_readout_ablations(singles.clone());
    let steps: Vec<_> = (0..data.lengths()[1])
        .map(|t| {
            inference
                .step(
                    data.step(Modality::Exteroceptive, 1, t),
                    data.step(Modality::Proprioceptive, 1, t),
                )
                .unwrap()
        })
        .collect();
    for (i, ablation) in singles.into_iter().enumerate() {
        let readout = run(ablation, AblationMode::Readout);
        let during = run(ablation, AblationMode::Inference);
        assert_eq!(readout.free_energy, standard.free_energy, "{ablation:?}");
        assert_ne!(during.free_energy, standard.free_energy, "{ablation:?}");
        let recon = readout.recon.as_ref().unwrap();
        // A module feeds only its own read-out and the modules below it.
        assert!(
            recon != standard.recon.as_ref().unwrap(),
            "{ablation:?} changed no read-out"
        );
        for (t, step) in steps.iter().enumerate() {
            let w = recon[0].shape()[1];
            assert_eq!(
                step.ablated_recon[i][0],
                recon[0].data()[t * w..(t + 1) * w],
                "{ablation:?} step {t}"
            );
            let w = recon[1].shape()[1];
            assert_eq!(
                step.ablated_recon[i][1],
                recon[1].data()[t * w..(t + 1) * w],
                "{ablation:?} step {t}"
            );
            assert_eq!(step.window_free_energy, standard.free_energy[t]);
        }
    }
    // Files from before the two modes ablated during inference.
    let mut json = serde_json::to_value(settings(
        Ablation::of(&[ModuleId::Executive]),
        AblationMode::Readout,
    ))
    .unwrap();
    json.as_object_mut().unwrap().remove("ablation_mode");
    let old: InferenceSettings = serde_json::from_value(json).unwrap();
    assert_eq!(old.ablation_mode, AblationMode::Inference);
    let plain = settings(Ablation::none(), AblationMode::Inference).canonical();
    assert_eq!(plain.ablation_mode, AblationMode::Readout);
}

/// A step whose window diverges (here: a rate so large that a sigma overflows) restarts
/// from the step's start at half the rate. Its result is then exactly that of a run at the
/// halved rate, it says so, and a rate that still diverges after `MAX_RATE_HALVINGS`
/// halvings is an error that says how often it was restarted.
#[test]
fn a_diverging_step_restarts_at_half_the_rate() {
    use pvrnn_core::infer::MAX_RATE_HALVINGS;
    let config = learning_config();
    let data = sine_observations::<f32>(&config, 1, 4);
    let model = Arc::new(Model::<f32>::init(config.clone(), 1, 4, 2).unwrap());
    let first_step = |lr: f64| {
        let mut s = InferenceSettings::from_config(&config, 3);
        s.window = 4;
        s.iterations = 20;
        s.optimizer.lr = lr;
        let mut inf = OnlineInference::new(model.clone(), s).unwrap();
        inf.step(
            data.step(Modality::Exteroceptive, 0, 0),
            data.step(Modality::Proprioceptive, 0, 0),
        )
    };
    // The smallest power of two that diverges: half of it does not.
    let (exponent, restarted) = (0..80)
        .find_map(|e| match first_step(2f64.powi(e)) {
            Ok(out) if out.rate_halvings > 0 => Some((e, out)),
            _ => None,
        })
        .expect("some rate diverges");
    assert_eq!(restarted.rate_halvings, 1);
    let halved = first_step(2f64.powi(exponent - 1)).unwrap();
    assert_eq!(halved.rate_halvings, 0);
    assert_eq!(restarted.recon, halved.recon);
    assert_eq!(restarted.window_free_energy, halved.window_free_energy);
    assert!(restarted.window_free_energy.total.is_finite());

    let hopeless = (exponent..exponent + 40)
        .find_map(|e| first_step(2f64.powi(e)).err())
        .expect("a large enough rate diverges at every halving");
    let message = hopeless.to_string();
    assert!(
        message.contains("diverged")
            && message.contains(&format!("restarted {MAX_RATE_HALVINGS} times")),
        "{message}"
    );
}

#[test]
fn bad_steps_are_rejected() {
    let config = learning_config();
    let model = Arc::new(Model::<f32>::init(config.clone(), 1, 4, 2).unwrap());
    let mut inf = OnlineInference::new(model, InferenceSettings::from_config(&config, 1)).unwrap();
    let dv = config.vision.dims();
    let e = inf
        .begin_step(&vec![0.0; dv - 1], &[0.0; 4])
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("exteroceptive") && e.contains(&format!("{}", dv - 1)),
        "{e}"
    );
    let mut x = vec![0.0; dv];
    x[2] = f32::NAN;
    let e = inf.begin_step(&x, &[0.0; 4]).unwrap_err().to_string();
    assert!(e.contains("non-finite"), "{e}");
    assert!(inf.finish_step().is_err());
}
