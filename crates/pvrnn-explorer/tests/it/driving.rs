//! Where the Drive window's episode is stepped (`pvrnn_explorer::driving`): requests,
//! progress, and a finished episode through the bytes the web worker sends the page.

use std::sync::Arc;

use pvrnn_drive::{Controller, DriveSpec};
use pvrnn_explorer::Condition;
use pvrnn_explorer::driving::{
    DriveEvent, DriveRequest, EpisodeSoFar, FinishedDrive, LocalDrive, SO_FAR_EVERY,
};
use web_time::Duration;

use super::common;

fn spec(controller: Controller) -> DriveSpec {
    let mut spec = DriveSpec::new(caresim::Task::Repositioning, 650, 0, caresim::Revision::R1);
    spec.controller = controller;
    spec
}

#[test]
fn an_episode_is_stepped_perturbed_and_survives_the_trip_to_the_page() {
    let bundle = common::caresim_bundle();
    let model = bundle.model.clone();
    let condition = Condition::standard(&model.config);
    let mut local = LocalDrive::default();
    // Perturbations without an episode change nothing; a start without a model is refused.
    local.request(None, DriveRequest::Push(0)).unwrap();
    let start = DriveRequest::Start {
        spec: Box::new(spec(Controller::Network)),
        condition,
    };
    assert!(local.request(None, start.clone()).is_err());
    assert!(local.progress().is_none());
    local.request(Some(&model), start).unwrap();
    let progress = local.progress().unwrap();
    assert_eq!(progress.steps_done, 0);
    assert!(progress.len > 10, "{}", progress.len);
    assert_eq!(progress.trial, "repositioning_650mm_test0");
    // One step at least, even without time for it.
    assert!(local.step_for(Duration::ZERO).is_none());
    assert_eq!(local.progress().unwrap().steps_done, 1);
    // The episode so far, for the main panels: taken at once after the first step.
    let first = local
        .progress()
        .unwrap()
        .so_far
        .expect("the episode so far");
    assert_eq!(first.steps(), 1);
    assert_eq!(first.run.as_ref().unwrap().steps(), 1);
    let (step, cameras) = local.progress().unwrap().cameras.unwrap();
    assert_eq!(step, 1);
    // How the network copes, per step: its errors and each module's KL, all finite.
    let live = local.progress().unwrap().live;
    assert_eq!(live.len(), pvrnn_explorer::driving::LIVE_PER_STEP);
    assert!(
        live.iter().all(|v| v.is_finite()) && live[0] > 0.0,
        "{live:?}"
    );
    assert_eq!(
        cameras.len(),
        2 * caresim::IMAGE_SIZE * caresim::IMAGE_SIZE * 3
    );
    // A push is recorded in the drive's spec; a camera that does not exist is refused.
    local.request(None, DriveRequest::Push(1)).unwrap();
    assert!(
        local
            .progress()
            .unwrap()
            .spec
            .to_text()
            .contains(";push=2:right:0.2")
    );
    let err = local.request(None, DriveRequest::Occlude(2)).unwrap_err();
    assert!(err.contains("camera 2"), "{err}");
    // Taken again once grown and its interval passed, not every step.
    assert!(local.step_for(Duration::ZERO).is_none());
    assert_eq!(local.progress().unwrap().so_far.unwrap().steps(), 1);
    assert!(
        local
            .step_for(SO_FAR_EVERY + Duration::from_millis(50))
            .is_none()
    );
    let progress_then = local.progress().unwrap();
    let so_far = progress_then.so_far.clone().unwrap();
    assert_eq!(so_far.steps(), progress_then.steps_done);
    assert!(so_far.steps() > 2, "{}", so_far.steps());
    // Through the worker's bytes, and back.
    let parts = so_far.to_parts(&model.config).unwrap();
    let back = EpisodeSoFar::from_parts(parts.clone(), Some(&model.config)).unwrap();
    assert_eq!(back.sequence, so_far.sequence);
    assert_eq!(
        back.run.as_ref().unwrap().modules,
        so_far.run.as_ref().unwrap().modules
    );
    let err = EpisodeSoFar::from_parts(parts, None).unwrap_err();
    assert!(
        err.contains("episode so far") && err.contains("without its model"),
        "{err}"
    );
    let finished = match local.step_for(Duration::from_secs(600)) {
        Some(DriveEvent::Finished(f)) => *f,
        other => panic!("the episode did not finish: {other:?}"),
    };
    assert!(
        local.progress().is_none(),
        "a finished episode is no longer in progress"
    );
    assert_eq!(finished.sequence.len(), progress.len);
    assert_eq!(finished.run.as_ref().unwrap().steps(), progress.len);
    // What the panels showed while it ran is the start of the episode, exactly.
    let n = so_far.steps();
    assert_eq!(
        so_far.sequence.joints,
        finished.sequence.joints[..so_far.sequence.joints.len()]
    );
    assert!(so_far.sequence.images[..] == finished.sequence.images[..so_far.sequence.images.len()]);
    let run = finished.run.as_ref().unwrap();
    for (m, states) in so_far.run.as_ref().unwrap().modules.iter().enumerate() {
        let width = states.mu_q.len() / n;
        assert_eq!(
            states.mu_q[..],
            run.modules[m].mu_q[..n * width],
            "module {m}'s mu"
        );
    }
    assert!(
        finished.summary.starts_with("repositioning: "),
        "{}",
        finished.summary
    );
    // The bytes the worker sends: the same episode, run included, on the page.
    let parts = finished.to_parts(&model.config).unwrap();
    let back = FinishedDrive::from_parts(parts.clone(), Some(&model.config)).unwrap();
    let (run, back_run) = (finished.run.as_ref().unwrap(), back.run.as_ref().unwrap());
    assert_eq!(back_run.settings, run.settings);
    assert_eq!(back_run.modules, run.modules, "the latent states, exactly");
    // Per-step scalars travel as f32 (as the explorer keeps them).
    let totals = |r: &pvrnn_core::infer::Run<f32>| -> Vec<f32> {
        r.free_energy.iter().map(|f| f.total as f32).collect()
    };
    assert_eq!(totals(back_run), totals(run));
    let without_run = |f: &FinishedDrive| FinishedDrive {
        run: None,
        ..f.clone()
    };
    assert_eq!(without_run(&back), without_run(&finished));
    // A run cannot be read without its model, nor a truncated sequence at all.
    let err = FinishedDrive::from_parts(parts.clone(), None).unwrap_err();
    assert!(err.contains("without its model"), "{err}");
    let mut cut = parts;
    cut.sequence.truncate(cut.sequence.len() / 2);
    assert!(FinishedDrive::from_parts(cut, Some(&model.config)).is_err());
}

#[test]
fn a_stopped_episode_leaves_nothing_and_the_mean_trajectory_needs_no_network() {
    let model = Arc::new(common::model());
    let condition = Condition::standard(&model.config);
    let mut local = LocalDrive::default();
    // A network that cannot drive caresim's robot (one 8x8 camera) is refused with why.
    let err = local
        .request(
            Some(&model),
            DriveRequest::Start {
                spec: Box::new(spec(Controller::Network)),
                condition,
            },
        )
        .unwrap_err();
    assert!(err.contains("camera"), "{err}");
    local
        .request(
            Some(&model),
            DriveRequest::Start {
                spec: Box::new(spec(Controller::MeanTrajectory)),
                condition,
            },
        )
        .unwrap();
    assert!(local.step_for(Duration::ZERO).is_none());
    assert!(
        local.progress().unwrap().live.is_empty(),
        "no network, nothing to plot"
    );
    local.request(None, DriveRequest::Stop).unwrap();
    assert!(local.progress().is_none());
    assert!(local.step_for(Duration::ZERO).is_none());
}
