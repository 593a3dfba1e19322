//! `evaluate` end to end on a small model and dataset: the model's errors agree with the
//! core's own reconstruction error, the baselines equal their definitions, and the report
//! files and the progress table come out.
#![allow(clippy::unwrap_used)] // test code: a failed unwrap is a failed run

use std::path::Path;
use std::sync::Arc;

use pvrnn_core::config::{ModuleConfig, VisionLayout};
use pvrnn_core::infer::InferenceSettings;
use pvrnn_core::run_sequence;
use pvrnn_core::{Modality, Model, ModelConfig, Observed};
use pvrnn_dataset::{Dataset, Selection, Sequence, SequenceInfo, Split, proprio_ranges};
use pvrnn_eval::report::{self, Pixels};
use pvrnn_eval::{EvalSettings, Evaluation, ReportMeta, Source, Target, evaluate, plots, progress};

const T: usize = 10;

/// A sequence whose left camera shows a bright pixel moving one place per step (the right
/// camera is static), with smooth proprioception.
fn sequence(name: &str, task: &str, split: Split, phase: usize) -> Sequence {
    let mut images = vec![40u8; T * 2 * 4 * 4 * 3];
    for t in 0..T {
        let pixel = (t + phase) % 16;
        let at = (t * 2 * 16 + pixel) * 3;
        images[at..at + 3].copy_from_slice(&[250, 200, 10]);
    }
    Sequence {
        info: SequenceInfo {
            name: name.into(),
            file: format!("{name}.safetensors"),
            task: task.into(),
            bed_height_mm: Some(650.0),
            split,
            seed: None,
            length: T,
            subtasks: vec!["reach".into(), "wipe".into()],
        },
        cameras: 2,
        image_size: 4,
        images,
        joints: (0..T * 14)
            .map(|i| (i as f32 * 0.1 + phase as f32).sin())
            .collect(),
        torques: (0..T * 14)
            .map(|i| (i as f32 * 0.05).cos() * (1 + phase) as f32)
            .collect(),
        subtask: (0..T).map(|t| (t * 2 / T) as u32).collect(),
        extra: Vec::new(),
        images_without_robot: None,
    }
}

fn dataset() -> Dataset {
    let seqs = vec![
        sequence("r_learn0", "repositioning", Split::Learn, 0),
        sequence("r_learn1", "repositioning", Split::Learn, 3),
        sequence("w_learn0", "wiping", Split::Learn, 5),
        sequence("r_test0", "repositioning", Split::Test, 1),
        sequence("w_test0", "wiping", Split::Test, 7),
    ];
    Dataset::new("test", vec!["left".into(), "right".into()], 4, seqs).unwrap()
}

fn model(ds: &Dataset) -> Model<f32> {
    let mut c = ModelConfig::default();
    let m = |d, z, tau: [f64; 2]| ModuleConfig { d, z, tau };
    c.executive = m(6, 2, c.executive.tau);
    c.associative = m(6, 2, c.associative.tau);
    c.exteroceptive = m(6, 3, c.exteroceptive.tau);
    c.proprioceptive = m(6, 2, c.proprioceptive.tau);
    c.exteroceptive_readout.hidden = vec![6, 8];
    c.proprioceptive_readout.hidden = vec![6];
    c.vision = VisionLayout {
        cameras: 2,
        channels: 3,
        resolutions: vec![2, 4],
    };
    c.inference.window = 4;
    c.inference.iterations = 3;
    c.normalisation = Some(proprio_ranges(&ds.split(Some(Split::Learn))));
    Model::init(c, 3, T, 7).unwrap()
}

fn settings(model: &Model<f32>, vision_levels: usize, trials: usize) -> EvalSettings {
    let mut inference = InferenceSettings::from_config(&model.config, 11);
    inference.observed = Observed {
        vision_levels,
        proprio: true,
    };
    EvalSettings {
        inference,
        trials,
        change_threshold: 8.0,
        image_columns: 4,
        nearest_neighbour: true,
    }
}

/// `evaluate` on the CPU over the test split.
fn evaluate_test(
    ds: &Dataset,
    model: &Arc<Model<f32>>,
    settings: &EvalSettings,
) -> pvrnn_eval::Result<Evaluation> {
    evaluate(
        model.clone(),
        &pvrnn_core::cpu::CpuBackend,
        ds,
        &Selection::Split(Split::Test),
        settings,
        &|| {},
    )
}

/// A report header for a model at training `iteration`.
fn meta(iteration: u64) -> ReportMeta {
    ReportMeta {
        model: "m.safetensors".into(),
        model_iteration: Some(iteration),
        dataset: "ds".into(),
        split: "test".into(),
        seconds: 1.0,
        threads: 1,
        backend: "cpu".into(),
        machine: "a test machine".into(),
    }
}

/// Writes the report (and, with `plots`, the pictures) into `dir`; returns `summary.md`.
fn report_md(eval: &Evaluation, meta: &ReportMeta, dir: &Path, plots: bool) -> String {
    pvrnn_eval::write_report(eval, meta, dir).unwrap();
    if plots {
        plots::write_plots(eval, &dir.join("plots")).unwrap();
    }
    std::fs::read_to_string(dir.join("summary.md")).unwrap()
}

#[test]
fn errors_match_the_core_and_baselines_match_their_definitions() {
    let ds = dataset();
    let model = Arc::new(model(&ds));
    let test = Selection::Split(Split::Test);
    let eval = evaluate_test(&ds, &model, &settings(&model, 1, 2)).unwrap();
    let names: Vec<&str> = eval.groups.iter().map(|g| g.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "v2", "v2_left", "v2_right", "v4", "v4_left", "v4_right", "joints", "torques"
        ]
    );
    assert!(eval.groups[0].observed && !eval.groups[3].observed && eval.groups[6].observed);

    // The model's reconstruction errors, pooled over both levels, are the core's own
    // per-step reconstruction error of trial 0.
    let data = ds
        .observations(&ds.select(&test).unwrap(), &model.config)
        .unwrap();
    let run = run_sequence(
        model.clone(),
        settings(&model, 1, 1).inference,
        &data,
        1,
        false,
        &mut |_, _| {},
    )
    .unwrap();
    let seq = &eval.sequences[1];
    assert_eq!(seq.meta.name, "w_test0");
    let recon0 = seq
        .series
        .iter()
        .find(|s| s.source == Source::Model && s.target == Target::Recon && s.trial == Some(0))
        .unwrap();
    for t in 0..T {
        let e = recon0.steps[t].as_ref().unwrap();
        let (sum, count) = [0, 3].iter().fold((0.0, 0), |(s, c), &g| {
            (s + e.all[g].sum, c + e.all[g].count)
        });
        let mse = sum / count as f64;
        assert!(
            (mse - run.recon_error[t][0]).abs() <= 1e-6 * mse.max(1e-6),
            "step {t}: {mse} vs {}",
            run.recon_error[t][0]
        );
        let (psum, pcount) =
            (6..8).fold((0.0, 0), |(s, c), g| (s + e.all[g].sum, c + e.all[g].count));
        assert!((psum / pcount as f64 - run.recon_error[t][1]).abs() < 1e-6);
    }
    // A second trial uses other noise, so its errors differ.
    let recon1 = seq
        .series
        .iter()
        .find(|s| s.source == Source::Model && s.target == Target::Recon && s.trial == Some(1))
        .unwrap();
    assert_ne!(recon0.steps[5], recon1.steps[5]);

    // The previous-frame baseline: step t's input as the prediction of t + 1.
    let previous = seq
        .series
        .iter()
        .find(|s| s.source == Source::Previous)
        .unwrap();
    let x = |t: usize| data.step(Modality::Exteroceptive, 1, t);
    let layout = &model.config.vision;
    let v4 = layout.level_offset(1)..layout.dims();
    let n4 = v4.len() as f64;
    let expect: f64 = v4
        .clone()
        .map(|d| (x(3)[d] as f64 - x(4)[d] as f64).powi(2))
        .sum::<f64>()
        / n4;
    let got = previous.steps[3].as_ref().unwrap().all[3].mse().unwrap();
    assert!((got - expect).abs() < 1e-9, "{got} vs {expect}");
    assert!(previous.steps[T - 1].is_none(), "no step after the last");
    // Only the left camera moves: its changing pixels are the two lit places (the old
    // and the new), the right camera has none.
    let e = previous.steps[3].as_ref().unwrap();
    assert_eq!(e.changing[4].count, 2 * 3);
    assert_eq!(e.changing[5].count, 0);
    assert!((e.changing[4].mse().unwrap() - e.all[4].sum / 6.0).abs() < 1e-9);

    // The mean baseline: the mean learning input.
    let mean = pvrnn_eval::baselines::learning_mean(&ds, &model).unwrap();
    let mean_recon = seq
        .series
        .iter()
        .find(|s| s.source == Source::Mean && s.target == Target::Recon)
        .unwrap();
    let expect: f64 = v4
        .clone()
        .map(|d| (mean[0][d] as f64 - x(2)[d] as f64).powi(2))
        .sum::<f64>()
        / n4;
    assert!((mean_recon.steps[2].as_ref().unwrap().all[3].mse().unwrap() - expect).abs() < 1e-9);

    // Upsampling plus the mean image's detail: upsampled 2x2 + (mean 4x4 - upsampled mean 2x2).
    let baseline = |source: Source| {
        seq.series
            .iter()
            .find(|s| s.source == source && s.target == Target::Recon)
            .unwrap()
    };
    let v2 = |v: &[f32], camera: usize| {
        let at = layout.image_offset(0, camera);
        v[at..at + 12].to_vec()
    };
    let mut detailed = vec![0f32; layout.dims()];
    for camera in 0..2 {
        let up = pvrnn_eval::metrics::upsample_bilinear(&v2(x(2), camera), 2, 3, 4);
        let up_mean = pvrnn_eval::metrics::upsample_bilinear(&v2(&mean[0], camera), 2, 3, 4);
        let at = layout.image_offset(1, camera);
        for i in 0..48 {
            detailed[at + i] = up[i] + mean[0][at + i] - up_mean[i];
        }
    }
    let expect: f64 = v4
        .clone()
        .map(|d| (detailed[d] as f64 - x(2)[d] as f64).powi(2))
        .sum::<f64>()
        / n4;
    let got = baseline(Source::UpsampleDetail).steps[2]
        .as_ref()
        .unwrap()
        .all[3]
        .mse()
        .unwrap();
    assert!((got - expect).abs() < 1e-9, "{got} vs {expect}");

    // The nearest neighbour: over every learning frame, the smallest distance over the
    // observed inputs (2x2 vision and proprioception, each divided by its dimensions); its
    // whole 4x4 image is the reconstruction.
    let learn = ds.select(&Selection::Split(Split::Learn)).unwrap();
    let reference = ds.observations(&learn, &model.config).unwrap();
    let p = |data: &pvrnn_core::Observations<f32>, s: usize, t: usize| {
        data.step(Modality::Proprioceptive, s, t).to_vec()
    };
    let distance = |a: &[f32], b: &[f32]| {
        a.iter()
            .zip(b)
            .map(|(x, y)| (*x as f64 - *y as f64).powi(2))
            .sum::<f64>()
            / a.len() as f64
    };
    let observed = layout.observed_dims(1);
    for t in [0, 4, 9] {
        let (l, u) = (0..learn.len())
            .flat_map(|l| (0..T).map(move |u| (l, u)))
            .min_by(|&(l1, u1), &(l2, u2)| {
                let d = |l: usize, u: usize| {
                    distance(
                        &x(t)[..observed],
                        &reference.step(Modality::Exteroceptive, l, u)[..observed],
                    ) + distance(&p(&data, 1, t), &p(&reference, l, u))
                };
                d(l1, u1).total_cmp(&d(l2, u2))
            })
            .unwrap();
        let frame = reference.step(Modality::Exteroceptive, l, u);
        let expect: f64 = v4
            .clone()
            .map(|d| (frame[d] as f64 - x(t)[d] as f64).powi(2))
            .sum::<f64>()
            / n4;
        let got = baseline(Source::Nearest).steps[t].as_ref().unwrap().all[3]
            .mse()
            .unwrap();
        assert!((got - expect).abs() < 1e-9, "step {t}: {got} vs {expect}");
        let joints = baseline(Source::Nearest).steps[t].as_ref().unwrap().all[6]
            .mse()
            .unwrap();
        let expect = (0..14)
            .map(|d| (p(&reference, l, u)[d] as f64 - p(&data, 1, t)[d] as f64).powi(2))
            .sum::<f64>()
            / 14.0;
        assert!((joints - expect).abs() < 1e-9);
    }

    // Upsampling only when some levels are observed and some not.
    assert!(seq.series.iter().any(|s| s.source == Source::Upsample));
    let all = evaluate_test(&ds, &model, &settings(&model, 2, 1)).unwrap();
    assert!(
        all.sequences
            .iter()
            .all(|s| s.series.iter().all(|x| x.source != Source::Upsample))
    );

    // Figures: a sequence's trials are averaged first, then mean ± SE over sequences.
    let values = report::trial_values(&eval);
    let figures = report::figures(&eval, &values);
    let sequence_mean = |s: usize| {
        let v: Vec<f64> = values
            .iter()
            .filter(|v| {
                v.sequence == s
                    && v.source == Source::Model
                    && v.target == Target::Recon
                    && v.group == 3
                    && v.pixels == Pixels::All
            })
            .map(|v| v.mse)
            .collect();
        assert_eq!(v.len(), 2, "two trials");
        v.iter().sum::<f64>() / 2.0
    };
    let (m0, m1) = (sequence_mean(0), sequence_mean(1));
    let model_v4 = figures
        .iter()
        .find(|f| {
            f.scope == "all"
                && f.source == Source::Model
                && f.target == Target::Recon
                && f.group == "v4"
                && f.pixels == Pixels::All
        })
        .unwrap();
    assert_eq!(model_v4.n, 2);
    assert!((model_v4.mean - (m0 + m1) / 2.0).abs() < 1e-12);
    // The SE of two values is half their distance.
    assert!((model_v4.se.unwrap() - (m0 - m1).abs() / 2.0).abs() < 1e-12);
    let up = figures
        .iter()
        .find(|f| {
            f.scope == "task:wiping"
                && f.source == Source::Upsample
                && f.group == "v4"
                && f.pixels == Pixels::All
        })
        .unwrap();
    assert_eq!(up.n, 1);
    // No upsampling figure for the observed level, no previous-frame reconstruction.
    assert!(
        !figures
            .iter()
            .any(|f| f.source == Source::Upsample && f.group == "v2")
    );
    assert!(
        !figures
            .iter()
            .any(|f| f.source == Source::Previous && f.target == Target::Recon)
    );
    let comparisons = report::comparisons(&eval, &values, &figures);
    let c = comparisons
        .iter()
        .find(|c| {
            c.scope == "all"
                && c.group == "v4"
                && c.baseline == Source::Upsample
                && c.pixels == Pixels::All
        })
        .unwrap();
    assert_eq!(c.model_better, c.model < c.baseline_value);
    assert!((c.ratio - model_v4.mean / c.baseline_value).abs() < 1e-12);
    // Wins: the sequences whose trial mean is below the baseline's value there.
    let up_of = |s: usize| {
        values
            .iter()
            .find(|v| {
                v.sequence == s
                    && v.source == Source::Upsample
                    && v.group == 3
                    && v.pixels == Pixels::All
            })
            .unwrap()
            .mse
    };
    assert_eq!(c.sequences, 2);
    assert_eq!(
        c.wins,
        usize::from(m0 < up_of(0)) + usize::from(m1 < up_of(1))
    );
    for baseline in [Source::UpsampleDetail, Source::Nearest, Source::Mean] {
        assert!(
            comparisons
                .iter()
                .any(|c| c.scope == "all" && c.group == "v4" && c.baseline == baseline),
            "{baseline:?}"
        );
    }
}

#[test]
fn reports_plots_and_the_progress_table_are_written() {
    let ds = dataset();
    let model = Arc::new(model(&ds));
    let eval = evaluate_test(&ds, &model, &settings(&model, 1, 2)).unwrap();
    // Pictures of the first trial that finished: here trial 0.
    assert!(
        eval.sequences
            .iter()
            .all(|s| s.images.trial == 0 && s.images.steps.len() == 4)
    );
    let dir = tempfile::tempdir().unwrap();
    let mut meta = ReportMeta {
        model: "m.safetensors".into(),
        model_iteration: Some(1000),
        dataset: "ds".into(),
        split: "test".into(),
        seconds: 1.5,
        threads: 2,
        backend: "cpu".into(),
        machine: "a test machine".into(),
    };
    let md = report_md(&eval, &meta, dir.path(), true);
    assert!(
        md.contains("2 sequences") && md.contains("2 inference trials"),
        "{md}"
    );
    assert!(md.contains("| v4* |") && md.contains("upsample"), "{md}");
    let per_step = std::fs::read_to_string(dir.path().join("per_step.csv")).unwrap();
    // Model: 2 sequences x 2 trials x (T recon + T - 1 next); baselines: mean (T + T - 1),
    // previous (T - 1), upsample, upsample_detail and nearest (T each) per sequence.
    assert_eq!(
        per_step.lines().count(),
        1 + 2 * 2 * (2 * T - 1) + 2 * (6 * T - 2)
    );
    assert!(
        per_step
            .lines()
            .next()
            .unwrap()
            .ends_with("v4_right_changing")
    );
    for name in ["error_r_test0.png", "images_w_test0.png"] {
        let img = image::open(dir.path().join("plots").join(name))
            .unwrap()
            .to_rgb8();
        // Something was drawn: the picture is not one colour.
        let first = *img.get_pixel(0, 0);
        assert!(img.pixels().any(|p| *p != first), "{name} is blank");
    }

    // Progress: two evaluations of the same condition give a table with the change.
    let text = std::fs::read_to_string(dir.path().join("summary.json")).unwrap();
    let a = progress::read_summary(&text, "a").unwrap();
    assert_eq!(a.iteration, 1000);
    assert_eq!(a.condition, "vision 2, proprioception on");
    let mut b = a.clone();
    b.iteration = 2000;
    b.model = a.model.iter().map(|v| v.map(|x| x * 0.9)).collect();
    assert!((progress::max_relative_change(&a, &b).unwrap() - 0.1).abs() < 1e-9);
    let table = progress::markdown(&[b, a]);
    assert!(
        table.contains("| 1000 |") && table.contains("| 2000 |") && table.contains("10.0%"),
        "{table}"
    );
    assert!(table.find("| 1000 |") < table.find("| 2000 |"));
    assert!(table.contains("best baseline"));
    meta.model_iteration = None;
    pvrnn_eval::write_report(&eval, &meta, dir.path()).unwrap();
    let text = std::fs::read_to_string(dir.path().join("summary.json")).unwrap();
    let e = progress::read_summary(&text, "b").unwrap_err().to_string();
    assert!(e.contains("iteration"), "{e}");
    assert!(progress::read_summary("{}", "c").is_err());
}

/// Steps whose online inference diverged and was restarted at a halved rate are listed in
/// `summary.md` and `summary.json` (here provoked by rates far above the paper's 1.0; the
/// smallest power of two that makes some step restart).
#[test]
fn restarted_steps_are_reported() {
    let ds = dataset();
    let model = Arc::new(model(&ds));
    let meta = meta(1);
    let run = |lr: f64| {
        let mut s = settings(&model, 2, 1);
        s.inference.optimizer.lr = lr;
        evaluate_test(&ds, &model, &s)
    };
    let eval = (0..60)
        .find_map(|e| match run(2f64.powi(e)) {
            Ok(eval) if eval.sequences.iter().any(|s| !s.restarts.is_empty()) => Some(eval),
            _ => None,
        })
        .expect("some rate makes a step restart");
    let restarts: usize = eval.sequences.iter().map(|s| s.restarts.len()).sum();
    let dir = tempfile::tempdir().unwrap();
    let md = report_md(&eval, &meta, dir.path(), false);
    assert!(
        md.contains(&format!("diverged in {restarts} step(s)")) && md.contains("(lr / 2^"),
        "{md}"
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("summary.json")).unwrap())
            .unwrap();
    let listed = json["restarts"].as_array().unwrap();
    assert_eq!(listed.len(), restarts);
    assert!(listed[0]["rate_halvings"].as_u64().unwrap() >= 1, "{json}");
    assert!(listed[0]["sequence"].is_string(), "{json}");

    // At the paper's rate nothing restarts, and the report says so.
    let calm = run(1.0).unwrap();
    assert!(calm.sequences.iter().all(|s| s.restarts.is_empty()));
    let md = report_md(&calm, &meta, dir.path(), false);
    assert!(md.contains("no step's online inference diverged"), "{md}");
}

/// A trial whose online inference diverges beyond repair does not stop the evaluation: it
/// is listed and left out of the figures, and a sequence with no finished trial leaves
/// every figure with its baselines, so the model and the baselines stay comparable.
#[test]
fn diverged_trials_are_left_out_and_reported() {
    let ds = dataset();
    let meta = meta(3000);
    let dir = tempfile::tempdir().unwrap();

    // A proprioceptive prior whose log sigma is 1000 x the state: infinite or zero sigmas
    // from the first step with a state on, in every trial.
    let mut broken = model(&ds);
    broken.params.modules[3]
        .w_prior_sigma
        .data_mut()
        .fill(1000.0);
    let broken = Arc::new(broken);
    let eval = evaluate_test(&ds, &broken, &settings(&broken, 1, 2)).unwrap();
    for seq in &eval.sequences {
        assert_eq!(seq.failures.len(), 2, "{}", seq.meta.name);
        assert!(seq.excluded());
        assert!(
            seq.failures[0].message.contains("diverged"),
            "{:?}",
            seq.failures
        );
    }
    assert!(report::trial_values(&eval).is_empty());
    let md = report_md(&eval, &meta, dir.path(), true);
    assert!(md.contains("in 4 of 4 trials"), "{md}");

    // One of two sequences without a finished trial: its baselines leave the figures too.
    let model = Arc::new(model(&ds));
    let mut eval = evaluate_test(&ds, &model, &settings(&model, 1, 2)).unwrap();
    let lost = &mut eval.sequences[0];
    lost.series.retain(|s| s.source != Source::Model);
    lost.images = Default::default();
    lost.failures = (0..2)
        .map(|trial| pvrnn_eval::evaluate::Failure {
            trial,
            step: 4,
            message: "online inference diverged at step 4".into(),
        })
        .collect();
    let values = report::trial_values(&eval);
    assert!(values.iter().all(|v| v.sequence == 1));
    let figures = report::figures(&eval, &values);
    let n = |source| {
        figures
            .iter()
            .find(|f| f.scope == "all" && f.source == source && f.group == "v4")
            .unwrap()
            .n
    };
    // One sequence left, its two trials averaged into one value.
    assert_eq!((n(Source::Model), n(Source::Upsample)), (1, 1));
    let md = report_md(&eval, &meta, dir.path(), true);
    assert!(
        md.contains("in 2 of 4 trials") && md.contains("`r_test0` had no trial that finished"),
        "{md}"
    );
    let text = std::fs::read_to_string(dir.path().join("summary.json")).unwrap();
    let json: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert_eq!(json["failures"].as_array().unwrap().len(), 2);
    assert_eq!(json["failures"][0]["sequence"], "r_test0");
    let row = progress::read_summary(&text, "summary.json").unwrap();
    assert_eq!(
        (row.failed_trials, row.total_trials, row.excluded_sequences),
        (2, 4, 1)
    );
    let table = progress::markdown(std::slice::from_ref(&row));
    assert!(
        table.contains(
            "| 3000 (2 of 4 trials diverged, left out; 1 sequence(s) left out with them) |"
        ),
        "{table}"
    );
    // The best-baseline line comes from the last row over every sequence.
    let mut complete = row.clone();
    complete.iteration = 2000;
    complete.failed_trials = 0;
    for b in complete.best_baseline.iter_mut().flatten() {
        b.0 = 123.0;
    }
    let table = progress::markdown(&[complete, row]);
    let baseline_line = table
        .lines()
        .find(|l| l.starts_with("| best baseline"))
        .unwrap();
    assert!(baseline_line.contains("123.0"), "{table}");
}
