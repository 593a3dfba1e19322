//! A run continued from its own state is the same run, and a branch (the state continued
//! under another observation) shares every step before it: what the explorer's "branch at
//! t" relies on, and the closed loop's vision drop taken in place (`reobserve`), on every
//! backend.

use std::sync::Arc;

use pvrnn_core::infer::{InferenceSettings, InferenceState, OnlineInference, StepOutput};
use pvrnn_core::{Modality, Model, Observations, Observed, Real};

use crate::fixtures::{learning_config, sine_observations};
use crate::{Shared, SuiteReal};

/// The window inputs `state` needs, from the sequence.
fn window_inputs<'a, T: Real>(
    data: &'a Observations<T>,
    state: &InferenceState<T>,
) -> Vec<(&'a [T], &'a [T])> {
    let end = state.steps_done();
    (end - state.window_len()..end)
        .map(|t| {
            (
                data.step(Modality::Exteroceptive, 0, t),
                data.step(Modality::Proprioceptive, 0, t),
            )
        })
        .collect()
}

fn steps<T: Real>(
    inference: &mut OnlineInference<T>,
    data: &Observations<T>,
    range: std::ops::Range<usize>,
) -> Vec<StepOutput<T>> {
    range
        .map(|t| {
            inference
                .step(
                    data.step(Modality::Exteroceptive, 0, t),
                    data.step(Modality::Proprioceptive, 0, t),
                )
                .unwrap()
        })
        .collect()
}

pub fn a_run_continued_from_its_state_is_the_same_run_and_a_branch_shares_its_past<T: SuiteReal>(
    backend: &Shared<T>,
) {
    let config = learning_config();
    let data = sine_observations::<T>(&config, 1, 12);
    let model = Arc::new(Model::<T>::init_on(backend.as_ref(), config.clone(), 1, 12, 2).unwrap());
    let mut settings = InferenceSettings::from_config(&config, 3);
    settings.window = 4;
    settings.iterations = 3;
    // Moments carried across steps, so that the state's optimiser matters too.
    settings.reset_moments_each_step = false;
    let open = |settings: &InferenceSettings| {
        OnlineInference::with_backend(model.clone(), settings.clone(), backend.as_ref()).unwrap()
    };
    let whole = steps(&mut open(&settings), &data, 0..12);

    // Past the warm-up (the window full and sliding), and inside it.
    for at in [2, 7] {
        let mut first = open(&settings);
        let before = steps(&mut first, &data, 0..at);
        assert_eq!(before, whole[..at], "the same settings, the same steps");
        let state = first.state().unwrap();
        assert_eq!(state.steps_done(), at);
        // A full window slides as its step finishes: H - 1 steps wait for the next.
        assert_eq!(state.window_len(), at.min(3));

        let mut continued = open(&settings);
        continued
            .continue_from(state.clone(), &window_inputs(&data, &state))
            .unwrap();
        assert_eq!(
            steps(&mut continued, &data, at..12),
            whole[at..],
            "continued at {at}: not the run it continues"
        );

        // The branch: proprioception off from `at`. The same past, another future.
        let mut blind = settings.clone();
        blind.observed = Observed {
            proprio: false,
            ..blind.observed
        };
        let mut branch = open(&blind);
        branch
            .continue_from(state.clone(), &window_inputs(&data, &state))
            .unwrap();
        let after = steps(&mut branch, &data, at..12);
        assert_eq!(after[0].t, at);
        assert_ne!(
            after[0].recon[1], whole[at].recon[1],
            "branch at {at}: its observation made no difference"
        );
        assert!(after.iter().all(|s| s.window_free_energy.total.is_finite()));

        // The same branch taken in place (`reobserve`: the closed loop's vision drop).
        let mut in_place = open(&settings);
        steps(&mut in_place, &data, 0..at);
        let observed = blind.observed;
        in_place
            .reobserve(observed, &window_inputs(&data, &state))
            .unwrap();
        assert_eq!(in_place.settings().observed, observed);
        assert_eq!(
            steps(&mut in_place, &data, at..12),
            after,
            "reobserved at {at}: not the branch"
        );
    }
    // A reobservation the model cannot have is refused, and changes nothing.
    let mut unchanged = open(&settings);
    steps(&mut unchanged, &data, 0..3);
    let state = unchanged.state().unwrap();
    let too_many = Observed {
        vision_levels: config.vision.resolutions.len() + 1,
        ..settings.observed
    };
    assert!(
        unchanged
            .reobserve(too_many, &window_inputs(&data, &state))
            .is_err()
    );
    assert_eq!(unchanged.settings().observed, settings.observed);
    assert_eq!(steps(&mut unchanged, &data, 3..12), whole[3..]);

    // Misuse is an error, not a wrong run.
    let mut first = open(&settings);
    steps(&mut first, &data, 0..5);
    let state = first.state().unwrap();
    let inputs = window_inputs(&data, &state);
    let err = open(&settings)
        .continue_from(state.clone(), &inputs[1..])
        .unwrap_err();
    assert!(
        err.to_string().contains("inputs of the window's 3 steps"),
        "{err}"
    );
    let mut short = settings.clone();
    short.window = 2;
    let err = open(&short).continue_from(state, &inputs).unwrap_err();
    assert!(err.to_string().contains("H = 2"), "{err}");
    first
        .begin_step(
            data.step(Modality::Exteroceptive, 0, 5),
            data.step(Modality::Proprioceptive, 0, 5),
        )
        .unwrap();
    assert!(first.state().is_err(), "a state inside a step");
}
