//! Learning on a backend lowers the free energy, and online inference on it with the
//! learned weights tracks the sequence.

use std::sync::Arc;

use pvrnn_core::infer::{InferenceSettings, run_sequence_on};
use pvrnn_core::train::{Trainer, step_together};
use pvrnn_core::{Modality, Model, NoiseMode, Observations, Observed, Real};

use crate::fixtures::{learning_config, sine_observations};
use crate::{Shared, SuiteReal};

/// Mean squared error of a modality's predictions against the data, over steps and dims.
fn mse<T: Real>(pred: &[T], data: &Observations<T>, modality: Modality, s: usize) -> f64 {
    let dims = data.dims(modality);
    let mut sum = 0.0;
    for (t, row) in pred.chunks_exact(dims).enumerate() {
        for (p, x) in row.iter().zip(data.step(modality, s, t)) {
            sum += (p.to_f64() - x.to_f64()).powi(2);
        }
    }
    sum / pred.len() as f64
}

/// `iterations` of learning on `backend`: the trainer, its data, and the first and last
/// free energy.
fn trained_on<T: Real>(
    backend: &Shared<T>,
    iterations: usize,
) -> (Trainer<T>, Observations<T>, f64, f64) {
    let config = learning_config();
    let data = sine_observations::<T>(&config, 2, 48);
    let model = Model::<T>::init_on(backend.as_ref(), config, 2, 48, 1).unwrap();
    let mut trainer = Trainer::new_on(
        Box::new(backend.clone()),
        model,
        NoiseMode::Sampled { seed: 1 },
    );
    let first = trainer.step(&data).unwrap().total;
    let mut last = first;
    for _ in 1..iterations {
        last = trainer.step(&data).unwrap().total;
    }
    (trainer, data, first, last)
}

/// Learning on `backend`, then online inference on it.
pub fn learning_lowers_free_energy_and_online_inference_tracks_the_sequence<T: SuiteReal>(
    backend: &Shared<T>,
) {
    let (trainer, data, first, last) = trained_on(backend, 400);
    let inference = backend.as_ref();
    assert!(last < 0.2 * first, "free energy {first} -> {last}");

    let model = Arc::new(trainer.into_model());
    let mut settings = InferenceSettings::from_config(&model.config, 3);
    settings.window = 8;
    settings.iterations = 20;
    let run = run_sequence_on(
        inference,
        model.clone(),
        settings.clone(),
        &data,
        0,
        true,
        &mut |_, _| {},
    )
    .unwrap();
    let baseline = 0.36 / 2.0; // mean of (0.6 sin)^2: the error of predicting 0
    let vision = mse(
        run.recon.as_ref().unwrap()[0].data(),
        &data,
        Modality::Exteroceptive,
        0,
    );
    let proprio = mse(
        run.recon.as_ref().unwrap()[1].data(),
        &data,
        Modality::Proprioceptive,
        0,
    );
    assert!(
        vision < 0.1 * baseline,
        "vision reconstruction MSE {vision}"
    );
    assert!(
        proprio < 0.1 * baseline,
        "proprio reconstruction MSE {proprio}"
    );

    // Vision unobserved above the lowest level: the model still predicts it from 1x1 + proprio.
    let mut partial = settings.clone();
    partial.observed = Observed {
        vision_levels: 1,
        proprio: true,
    };
    let run_partial = run_sequence_on(
        inference,
        model.clone(),
        partial,
        &data,
        0,
        true,
        &mut |_, _| {},
    )
    .unwrap();
    let hidden_part = model.config.vision.observed_dims(1);
    let dims = model.config.vision.dims();
    let mut err = 0.0;
    let mut n = 0;
    for t in 0..data.lengths()[0] {
        let pred = &run_partial.recon.as_ref().unwrap()[0].data()[t * dims..(t + 1) * dims];
        for i in hidden_part..dims {
            err +=
                (pred[i].to_f64() - data.step(Modality::Exteroceptive, 0, t)[i].to_f64()).powi(2);
            n += 1;
        }
    }
    assert!(
        err / (n as f64) < 0.25 * baseline,
        "unobserved-resolution MSE {}",
        err / n as f64
    );

    // The prior's one-step prediction is also better than chance.
    let steps = data.lengths()[0];
    let dv = model.config.vision.dims();
    let prior = &run.prior_next.as_ref().unwrap()[0].data()[..(steps - 1) * dv];
    let mut perr = 0.0;
    for t in 0..steps - 1 {
        for (p, x) in
            prior[t * dv..(t + 1) * dv]
                .iter()
                .zip(data.step(Modality::Exteroceptive, 0, t + 1))
        {
            perr += (p.to_f64() - x.to_f64()).powi(2);
        }
    }
    let perr = perr / prior.len() as f64;
    assert!(
        perr < 0.5 * baseline,
        "one-step prior prediction MSE {perr}"
    );
}

/// A fresh learning run of the suite's learning fixture with `seed` (weights and noise).
fn fresh_run<T: Real>(backend: &Shared<T>, seed: u64) -> (Trainer<T>, Observations<T>) {
    let config = learning_config();
    let data = sine_observations::<T>(&config, 2, 48);
    let model = Model::<T>::init_on(backend.as_ref(), config, 2, 48, seed).unwrap();
    let trainer = Trainer::new_on(
        Box::new(backend.clone()),
        model,
        NoiseMode::Sampled { seed },
    );
    (trainer, data)
}

/// Every value of a run's model, parameters then adaptive variables, as bits.
fn model_bits<T: Real>(trainer: &mut Trainer<T>) -> Vec<u64> {
    let model = trainer.model();
    let params = model.params.named().into_iter().map(|(_, t, _)| t.data());
    let adaptive = model.adaptive.named().into_iter().map(|(_, t)| t.data());
    params
        .chain(adaptive)
        .flat_map(|values| values.iter().map(|v| v.to_f64().to_bits()))
        .collect()
}

/// A run's noise changed between iterations takes effect at the next one, though the
/// trainer drew that iteration's eps ahead while its device ran the last one: the run
/// equals one whose learner was made afresh after the change, and differs from one whose
/// noise stayed.
pub fn a_changed_noise_takes_effect_at_the_next_iteration<T: SuiteReal>(backend: &Shared<T>) {
    let changed = NoiseMode::Sampled { seed: 9 };
    let second = |trainer: &mut Trainer<T>, data: &Observations<T>| {
        let total = trainer.step(data).unwrap().total.to_bits();
        (total, model_bits(trainer))
    };
    // Changed in place, the first iteration stepped as a cohort of one.
    let (mut run, data) = fresh_run(backend, 1);
    step_together(&mut [&mut run], &[&data]).unwrap()[0]
        .as_ref()
        .unwrap();
    run.noise = changed;
    let in_place = second(&mut run, &data);
    // Changed after the learner was dropped (`state_mut`).
    let (mut run, data) = fresh_run(backend, 1);
    run.step(&data).unwrap();
    run.state_mut();
    run.noise = changed;
    let afresh = second(&mut run, &data);
    assert!(
        in_place == afresh,
        "the noise changed in place was not the noise of the next iteration"
    );
    let (mut run, data) = fresh_run(backend, 1);
    run.step(&data).unwrap();
    let unchanged = second(&mut run, &data);
    assert_ne!(
        in_place.0, unchanged.0,
        "the changed noise should change the free energy"
    );
}

/// Three runs (seeds 1-3) stepped together (`step_together`, a cohort; on a device that
/// lays them out side by side, one dispatch for all), then runs 1 and 3 without run 2 (a
/// member that stopped), give each run's free energies and weights bit for bit as the run
/// stepped alone.
pub fn learning_runs_stepped_together_equal_each_run_alone<T: SuiteReal>(backend: &Shared<T>) {
    const ITERATIONS: usize = 3;
    // Runs 1 and 3 take one more iteration than run 2.
    let iterations = |k: usize| ITERATIONS + usize::from(k != 1);
    let mut alone = Vec::new();
    for (k, seed) in (1..=3).enumerate() {
        let (mut trainer, data) = fresh_run(backend, seed);
        let totals: Vec<u64> = (0..iterations(k))
            .map(|_| trainer.step(&data).unwrap().total.to_bits())
            .collect();
        alone.push((totals, model_bits(&mut trainer)));
    }
    let (mut runs, data): (Vec<Trainer<T>>, Vec<Observations<T>>) =
        (1..=3).map(|seed| fresh_run(backend, seed)).unzip();
    let data_refs: Vec<&Observations<T>> = data.iter().collect();
    let mut together = vec![Vec::new(); 3];
    for _ in 0..ITERATIONS {
        let mut members: Vec<&mut Trainer<T>> = runs.iter_mut().collect();
        let reports = step_together(&mut members, &data_refs).unwrap();
        for (totals, report) in together.iter_mut().zip(reports) {
            totals.push(report.unwrap().total.to_bits());
        }
    }
    {
        let (first, rest) = runs.split_at_mut(1);
        let mut members = vec![&mut first[0], &mut rest[1]];
        let reports = step_together(&mut members, &[data_refs[0], data_refs[2]]).unwrap();
        for (k, report) in [0, 2].into_iter().zip(reports) {
            together[k].push(report.unwrap().total.to_bits());
        }
    }
    for (k, ((totals, bits), (run, together))) in
        alone.iter().zip(runs.iter_mut().zip(&together)).enumerate()
    {
        assert_eq!(totals, together, "run {k}: free energies stepped together");
        assert_eq!(run.iteration, iterations(k) as u64);
        assert!(
            *bits == model_bits(run),
            "run {k}: weights stepped together differ from the run alone"
        );
    }
    // One dataset per run, or a clear error.
    let mut members: Vec<&mut Trainer<T>> = runs.iter_mut().collect();
    let error = step_together(&mut members, &data_refs[..2]).unwrap_err();
    assert!(
        error.to_string().contains("3 learning runs but 2 datasets"),
        "{error}"
    );
}

/// A run's model, optimiser step count and iteration count: what a diverged iteration
/// must leave as it was.
fn run_state<T: Real>(trainer: &mut Trainer<T>) -> (Vec<u64>, u64, u64) {
    let bits = model_bits(trainer);
    (bits, trainer.state().1.step, trainer.iteration)
}

/// A learning iteration whose free energy is not finite (after a step at a learning rate
/// far too large) fails, naming the divergence, and leaves the run as it was before it:
/// model, optimiser and iteration count; on a device that queued the iteration's update
/// before it read the free energy back (`Learner::guards_updates`), the update was skipped
/// there. So does the next attempt. In a cohort (on a device that lays it out side by
/// side, its runs in one submission), the other run goes on as it would alone.
pub fn a_diverging_iteration_leaves_the_run_as_it_was<T: SuiteReal>(backend: &Shared<T>) {
    // Finite at the first iteration (the weights are fine), not after its update.
    let ruinous = || {
        let mut config = learning_config();
        config.train.optimizer.lr = 1e200;
        let data = sine_observations::<T>(&config, 2, 48);
        let model = Model::<T>::init_on(backend.as_ref(), config, 2, 48, 1).unwrap();
        let run = Trainer::new_on(
            Box::new(backend.clone()),
            model,
            NoiseMode::Sampled { seed: 1 },
        );
        (run, data)
    };
    let diverges = |report: Result<_, pvrnn_core::Error>| match report {
        Err(pvrnn_core::Error::Numerical(message)) => {
            assert!(message.contains("learning diverged"), "{message}");
        }
        other => panic!("expected the divergence, got {other:?}"),
    };
    let (mut run, data) = ruinous();
    run.step(&data).unwrap();
    let before = run_state(&mut run);
    for _ in 0..2 {
        diverges(run.step(&data));
        assert!(
            run_state(&mut run) == before,
            "a diverged iteration changed the run"
        );
    }
    // Stepped together with a run that learns on (on a device that lays a cohort out side
    // by side, one submission for both at the first step): the other run's data are
    // sane, this one's past its float type's square root, so that its free energy is
    // infinite from the start.
    let (mut alone, other_data) = fresh_run(backend, 2);
    for _ in 0..3 {
        alone.step(&other_data).unwrap();
    }
    let (mut run, data) = fresh_run(backend, 1);
    let data = past_the_squares_range(&data);
    let (mut other, _) = fresh_run(backend, 2);
    let before = run_state(&mut run);
    for _ in 0..3 {
        let mut reports =
            step_together(&mut [&mut run, &mut other], &[&data, &other_data]).unwrap();
        reports.pop().unwrap().unwrap();
        diverges(reports.pop().unwrap());
        assert!(
            run_state(&mut run) == before,
            "a diverged iteration in a cohort changed the run"
        );
    }
    assert!(
        run_state(&mut other) == run_state(&mut alone),
        "the other run of the cohort differs from the run alone"
    );
}

/// `data` scaled by the largest power of 1e10 that `T` holds: finite, but its squares are
/// not.
fn past_the_squares_range<T: Real>(data: &Observations<T>) -> Observations<T> {
    let mut scale = 1e300;
    while !T::from_f64(scale).is_finite() {
        scale /= 1e10;
    }
    let scaled = |modality| {
        let t: &pvrnn_core::Tensor<T> = data.tensor(modality);
        let values = t
            .data()
            .iter()
            .map(|v| T::from_f64(v.to_f64() * scale))
            .collect();
        pvrnn_core::Tensor::from_vec(t.shape(), values).unwrap()
    };
    Observations::new(
        scaled(Modality::Exteroceptive),
        scaled(Modality::Proprioceptive),
        None,
    )
    .unwrap()
}
