//! The closed loop end to end on a small untrained network: deterministic episodes written
//! as datasets, the baselines, perturbations reaching the network, and clear errors.
#![allow(clippy::unwrap_used)] // test code: a failed unwrap is a failed run

use std::sync::Arc;

use caresim::{DatasetSpec, Revision, Task, simulate_proprioception};
use pvrnn_core::config::{ModuleConfig, VisionLayout};
use pvrnn_core::cpu::CpuBackend;
use pvrnn_core::infer::InferenceSettings;
use pvrnn_core::{Model, ModelConfig, Observed};
use pvrnn_dataset::{Dataset, proprio_ranges};
use pvrnn_drive::{Controller, Drive, DriveSpec, Episode, Occlusion, Push, VisionDrop};

/// A small network with caresim's senses: two 64x64 cameras (16, 32, 64), 14 joints and
/// 14 torques scaled by the learning trials' ranges.
fn network() -> Arc<Model<f32>> {
    let mut c = ModelConfig::default();
    let m = |d, z, fast, slow| ModuleConfig {
        d,
        z,
        tau: [fast, slow],
    };
    c.executive = m(4, 2, 4.0, 8.0);
    c.associative = m(4, 2, 2.0, 4.0);
    c.exteroceptive = m(4, 2, 1.5, 2.0);
    c.proprioceptive = m(4, 2, 1.0, 2.0);
    c.exteroceptive_readout.hidden = vec![4];
    c.proprioceptive_readout.hidden = vec![4];
    c.vision = VisionLayout {
        cameras: 2,
        channels: 3,
        resolutions: vec![16, 32, 64],
    };
    c.proprio_dims = 28;
    let learning: Vec<_> = DatasetSpec::default()
        .trials()
        .iter()
        .filter(|t| t.split == pvrnn_dataset::Split::Learn)
        .take(2)
        .map(simulate_proprioception)
        .collect();
    c.normalisation = Some(proprio_ranges(&learning.iter().collect::<Vec<_>>()));
    Arc::new(Model::init(c, 1, 4, 7).unwrap())
}

/// Few updates on a short window: the loop, not the inference, is under test.
fn settings(model: &Model<f32>) -> InferenceSettings {
    let mut s = InferenceSettings::from_config(&model.config, 3);
    s.window = 4;
    s.iterations = 2;
    s.observed = Observed {
        vision_levels: 1,
        proprio: true,
    };
    s
}

fn drive(spec: DriveSpec, model: &Arc<Model<f32>>) -> Episode {
    let network = spec.controller.uses_network().then(|| {
        (
            model.clone(),
            settings(model),
            &CpuBackend as &dyn pvrnn_core::backend::Backend<f32>,
        )
    });
    let mut steps = 0;
    let episode = Drive::start(spec, network)
        .unwrap()
        .finish(&mut |done, len| {
            assert!(done <= len);
            steps = done;
        })
        .unwrap();
    assert_eq!(steps, episode.sequence.len());
    episode
}

fn spec(task: Task, controller: Controller) -> DriveSpec {
    let mut s = DriveSpec::new(task, 650, 0, Revision::R2);
    s.controller = controller;
    s
}

#[test]
fn the_closed_loop_is_deterministic_and_its_episode_is_a_dataset() {
    let model = network();
    let a = drive(spec(Task::Wiping, Controller::Network), &model);
    let b = drive(spec(Task::Wiping, Controller::Network), &model);
    assert_eq!(a.commands, b.commands, "same seed, same episode");
    assert!(a.sequence.images == b.sequence.images);
    assert_eq!(a.commands.len() + 1, a.sequence.len());
    assert_eq!(a.sequence.info.name, "wiping_650mm_test0");
    // The network's commands are its predictions: the arms moved where it said.
    let last = a.sequence.len() - 1;
    let moved: f64 = (0..14)
        .map(|j| (a.sequence.joints[last * 14 + j] - a.sequence.joints[j]).abs() as f64)
        .sum();
    assert!(moved > 1e-3, "an untrained network still moves the arms");
    // Its folder: a dataset the loader reads, the network's run, the outcome.
    let dir = tempfile::tempdir().unwrap();
    a.write(
        dir.path(),
        Some(&model.config),
        serde_json::json!({"note": 1}),
    )
    .unwrap();
    let dataset = Dataset::open(dir.path()).unwrap();
    assert_eq!(dataset.sequences.len(), 1);
    assert_eq!(dataset.sequences[0].joints, a.sequence.joints);
    let file = pvrnn_core::io::TensorFile::open(&dir.path().join("runs.safetensors")).unwrap();
    let runs = pvrnn_core::io::load_runs(&file, &model.config).unwrap();
    assert_eq!(runs[0].run.steps(), a.sequence.len());
    assert_eq!(runs[0].name.as_deref(), Some("wiping_650mm_test0"));
    let summary: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("drive.json")).unwrap()).unwrap();
    assert_eq!(summary["trial"], "wiping_650mm_test0");
    assert_eq!(summary["spec"]["controller"], "network");
    assert_eq!(summary["note"], 1);
    assert_eq!(summary["demonstration"]["success"], true);
    assert_eq!(
        summary["outcome"]["success"].as_bool(),
        Some(a.outcome.success)
    );
}

#[test]
fn perturbations_reach_the_network_but_not_its_open_loop_prior() {
    let model = network();
    let mut pushed = spec(Task::Repositioning, Controller::Network);
    pushed.perturbations.push = Some(Push {
        step: 20,
        arm: 0,
        radians: 0.3,
    });
    pushed.perturbations.occlusion = Some(Occlusion {
        camera: 1,
        from: 5,
        steps: 10,
    });
    let plain = drive(spec(Task::Repositioning, Controller::Network), &model);
    let perturbed = drive(pushed.clone(), &model);
    // Equal until the network sees the occluded camera (step 5), apart after.
    assert_eq!(plain.commands[..5], perturbed.commands[..5]);
    assert_ne!(plain.commands[5], perturbed.commands[5]);
    // The push moved the left arm before step 20: its joints are off the command there.
    let q = |e: &Episode, t: usize| e.sequence.joints[t * 14] as f64;
    assert!((q(&perturbed, 20) - perturbed.commands[19][0]).abs() > 0.1);
    // The occluded camera shows mid-grey in the recording, in those steps only.
    let frame = 64 * 64 * 3;
    let image = |e: &Episode, t: usize, cam: usize| {
        e.sequence.images[(t * 2 + cam) * frame..(t * 2 + cam + 1) * frame].to_vec()
    };
    assert!(image(&perturbed, 5, 1).iter().all(|&v| v == 128));
    assert!(image(&perturbed, 14, 1).iter().all(|&v| v == 128));
    assert!(image(&perturbed, 15, 1).iter().any(|&v| v != 128));
    assert_eq!(image(&perturbed, 5, 0), image(&plain, 5, 0));
    // The prior observes nothing: the same commands however the robot is perturbed.
    pushed.controller = Controller::Prior;
    let prior = drive(spec(Task::Repositioning, Controller::Prior), &model);
    let prior_pushed = drive(pushed, &model);
    assert_eq!(prior.commands, prior_pushed.commands);
    assert_ne!(prior.commands, plain.commands);
}

#[test]
fn the_mean_learning_trajectory_stays_near_the_demonstration() {
    let model = network();
    let mean = drive(
        spec(Task::Repositioning, Controller::MeanTrajectory),
        &model,
    );
    assert!(mean.run.is_none());
    let held = drive(spec(Task::Repositioning, Controller::Network), &model);
    assert!(
        mean.outcome.joint_distance < 0.15
            && mean.outcome.joint_distance < held.outcome.joint_distance,
        "mean trajectory {} rad, untrained network {} rad",
        mean.outcome.joint_distance,
        held.outcome.joint_distance
    );
    // A height between the learned ones interpolates their means by height.
    let at = |h: u32| {
        let mut s = spec(Task::Repositioning, Controller::MeanTrajectory);
        s.bed_height_mm = h;
        pvrnn_drive::baseline::mean_trajectory(&s, 200).unwrap()
    };
    let (low, mid, high) = (at(590), at(620), at(650));
    for t in [0, 77, 199] {
        for j in 0..14 {
            let expected = 0.5 * low[t][j] + 0.5 * high[t][j];
            assert!((mid[t][j] - expected).abs() < 1e-12, "step {t} joint {j}");
        }
    }
}

#[test]
fn what_cannot_drive_is_refused_with_the_reason() {
    let model = network();
    let mut wrong = (*model).clone();
    wrong.config.vision.resolutions = vec![8, 16, 32];
    let e = Drive::start(
        spec(Task::Wiping, Controller::Network),
        Some((Arc::new(wrong), settings(&model), &CpuBackend)),
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("highest resolution must be 64"), "{e}");
    let e = Drive::start(spec(Task::Wiping, Controller::Prior), None)
        .unwrap_err()
        .to_string();
    assert!(e.contains("the prior controller needs a model"), "{e}");
    let mut low = spec(Task::Wiping, Controller::MeanTrajectory);
    low.bed_height_mm = 20;
    let e = Drive::start(low, None).unwrap_err().to_string();
    assert!(e.contains("between 300 and 1200"), "{e}");
    let mut noisy = spec(Task::Wiping, Controller::MeanTrajectory);
    noisy.perturbations.sensor_noise = f64::NAN;
    let e = Drive::start(noisy, None).unwrap_err().to_string();
    assert!(e.contains("sensor noise factor NaN"), "{e}");
    for (bad, says) in [
        (Push::parse("0:left:0.2").map(|_| ()), "STEP:ARM:RADIANS"),
        (Push::parse("10:middle:0.2").map(|_| ()), "STEP:ARM:RADIANS"),
        (Occlusion::parse("left:10").map(|_| ()), "CAMERA:FROM:STEPS"),
        (
            Controller::parse("autopilot").map(|_| ()),
            "unknown controller",
        ),
    ] {
        let e = bad.unwrap_err().to_string();
        assert!(e.contains(says), "{e}");
    }
}

#[test]
fn vision_dropped_mid_task_reaches_the_network_from_its_step_and_replays_from_the_spec() {
    let model = network();
    let network = || {
        Some((
            model.clone(),
            settings(&model),
            &CpuBackend as &dyn pvrnn_core::backend::Backend<f32>,
        ))
    };
    let plain = drive(spec(Task::Repositioning, Controller::Network), &model);
    // Dropped live, as the explorer's Drive window does it, after 30 steps.
    let mut live = Drive::start(spec(Task::Repositioning, Controller::Network), network()).unwrap();
    for _ in 0..30 {
        live.step().unwrap();
    }
    let err = live.drop_vision_now(1).unwrap_err().to_string();
    assert!(err.contains("observes 1 now"), "{err}");
    live.drop_vision_now(0).unwrap();
    let live = live.finish(&mut |_, _| {}).unwrap();
    assert_eq!(
        live.spec.perturbations.vision_drop,
        Some(VisionDrop {
            from: 30,
            levels: 0
        })
    );
    assert!(
        live.spec.to_text().ends_with(";vision=30:0"),
        "{}",
        live.spec.to_text()
    );
    // The same until the network infers step 30 without vision; apart from there.
    assert_eq!(plain.commands[..30], live.commands[..30]);
    assert_ne!(plain.commands[30], live.commands[30]);
    // The cameras still record, and the run keeps the condition it started under.
    assert!(live.sequence.images.iter().any(|&v| v != 128));
    assert_eq!(
        live.run.as_ref().unwrap().settings.observed.vision_levels,
        1
    );
    // The spec's text replays the episode.
    let replay = drive(DriveSpec::parse_text(&live.spec.to_text()).unwrap(), &model);
    assert_eq!(replay.commands, live.commands);
    // Without a network there is no vision to drop.
    let mut mean =
        Drive::start(spec(Task::Repositioning, Controller::MeanTrajectory), None).unwrap();
    assert!(mean.drop_vision_now(0).is_err());
}
