//! The experiments end to end at smoke scale on a small synthetic dataset: planning,
//! running, interruption and resume, reports, cluster scripts.

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};

use pvrnn_experiment::run::{Event, Interrupted, Selection, read_infer_result, read_train_result};
use pvrnn_experiment::{Experiment, JobKind, Plan, Scale, report, slurm};

/// The CPU backend, shared as the runner takes it.
fn cpu() -> std::sync::Arc<dyn pvrnn_core::backend::Backend<f32>> {
    std::sync::Arc::new(pvrnn_core::cpu::CpuBackend)
}

fn dataset(dir: &Path) {
    pvrnn_dataset::synthetic::caresim_like(&[590, 650, 710], 3, 1, 30)
        .unwrap()
        .write(dir)
        .unwrap();
}

#[test]
fn robustness_runs_resumes_after_interruption_and_reports() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    dataset(&data);
    let out = tmp.path().join("robustness");
    let plan = Plan::new(Experiment::Robustness, Scale::Smoke, &data, None, None).unwrap();
    plan.save(&out).unwrap();
    // 2 networks; 2 tasks x 1 test sequence x 6 conditions x 2 trials each.
    assert_eq!(plan.jobs.len(), 2 + 2 * 2 * 6 * 2);
    assert!(
        plan.check_matches(Experiment::Robustness, Scale::Paper)
            .is_err()
    );

    // Stop during the first training: its checkpoint is written at the iteration reached.
    let stop = AtomicBool::new(false);
    let events = |e: Event<'_>| {
        if let Event::Training { done: 7, .. } = e {
            stop.store(true, Ordering::SeqCst);
        }
    };
    let e = pvrnn_experiment::run::run(&out, &cpu(), "cpu", 1, Selection::All, &stop, &events)
        .unwrap_err();
    assert!(e.downcast_ref::<Interrupted>().is_some(), "{e:#}");
    let checkpoint = plan.checkpoint_path(&out, 0);
    let file = pvrnn_core::io::TensorFile::open(&checkpoint).unwrap();
    assert_eq!(pvrnn_core::io::checkpoint_iteration(&file), Some(7));
    assert!(!plan.is_done(&out, 0));

    // Running network 0 resumes its training and does its inference runs, nothing else.
    let go = AtomicBool::new(false);
    let e = pvrnn_experiment::run::run(&out, &cpu(), "cpu", 1, Selection::Network(2), &go, &|_| {})
        .unwrap_err();
    assert!(e.to_string().contains("networks 0..1"), "{e:#}");
    pvrnn_experiment::run::run(&out, &cpu(), "cpu", 2, Selection::Network(0), &go, &|_| {})
        .unwrap();
    let of_network_0 = Selection::Network(0).jobs(&plan);
    assert_eq!(of_network_0.len(), 1 + 2 * 6 * 2);
    for (i, job) in plan.jobs.iter().enumerate() {
        assert_eq!(
            plan.is_done(&out, i),
            job.network() == 0,
            "job {}",
            job.name
        );
    }

    // Running again does everything else, two jobs at a time.
    pvrnn_experiment::run::run(&out, &cpu(), "cpu", 2, Selection::All, &go, &|_| {}).unwrap();
    assert!((0..plan.jobs.len()).all(|i| plan.is_done(&out, i)));
    let trained = read_train_result(&plan.result_path(&out, 0)).unwrap();
    assert_eq!(
        trained.backend.as_deref(),
        Some("cpu"),
        "what trained it is recorded"
    );
    assert_eq!(trained.iterations, 20);
    let log = std::fs::read_to_string(checkpoint.with_extension("log.csv")).unwrap();
    let iterations: Vec<u64> = log
        .lines()
        .skip(1)
        .map(|l| l.split(',').next().unwrap().parse().unwrap())
        .collect();
    assert_eq!(
        iterations,
        (0..20).collect::<Vec<_>>(),
        "one log row per iteration"
    );

    let dir = report::write(&out).unwrap();
    let md = std::fs::read_to_string(dir.join("report.md")).unwrap();
    assert!(
        md.contains("smoke scale") && md.contains("Two-way ART ANOVA"),
        "{md}"
    );
    assert!(
        md.contains("observed"),
        "the report names the accuracy normalisation"
    );
    assert!(dir.join("robustness.png").is_file());
    let svg = std::fs::read_to_string(dir.join("robustness.svg")).unwrap();
    assert!(
        svg.starts_with("<svg") && svg.contains("proprio on"),
        "{svg}"
    );
    // Tidy tables of every run and training, for re-checking elsewhere.
    let mut trials = csv::Reader::from_path(dir.join("trials.csv")).unwrap();
    let header = trials.headers().unwrap().clone();
    assert_eq!(
        &header.iter().take(3).collect::<Vec<_>>(),
        &["scale", "job", "network"]
    );
    let column = |name: &str| header.iter().position(|h| h == name).unwrap();
    let (error, condition) = (column("error_vision64"), column("condition"));
    assert!(header.iter().any(|h| h == "sigma_p_executive"));
    let rows: Vec<csv::StringRecord> = trials.records().map(Result::unwrap).collect();
    assert_eq!(
        rows.len(),
        2 * 6 * 2 * 2,
        "networks x conditions x sequences x trials"
    );
    assert!(
        rows.iter()
            .all(|r| r.len() == header.len() && &r[0] == "smoke")
    );
    assert!(rows.iter().all(|r| r[error].parse::<f64>().unwrap() > 0.0));
    // A condition holds a comma and survives quoting.
    assert!(
        rows.iter()
            .any(|r| &r[condition] == "vision 16, proprio off")
    );
    let trainings = std::fs::read_to_string(dir.join("trainings.csv")).unwrap();
    assert_eq!(trainings.lines().count(), 3, "{trainings}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["scale"], "smoke");
    assert_eq!(
        summary["results"]["art"]["effects"]
            .as_array()
            .unwrap()
            .len(),
        3
    );
    // Every cell has both networks.
    for row in summary["results"]["cells"].as_array().unwrap() {
        for cell in row.as_array().unwrap() {
            assert_eq!(cell.as_object().unwrap().len(), 2);
        }
    }

    // One job for a cluster task: a done job is skipped; cluster scripts cover the rest.
    pvrnn_experiment::run::run(&out, &cpu(), "cpu", 1, Selection::Job(5), &go, &|_| {
        panic!("job 5 is done")
    })
    .unwrap();
    std::fs::remove_file(plan.result_path(&out, 9)).unwrap();
    let submit = slurm::emit(
        &out,
        &slurm::SlurmOptions {
            pvrnn: "/opt/pvrnn".into(),
            train_time: "10:00:00".into(),
            infer_time: "01:00:00".into(),
            cpus: 4,
            backend: "cpu".into(),
            extra: vec!["--partition=cpu".into()],
        },
    )
    .unwrap();
    let script = std::fs::read_to_string(&submit).unwrap();
    assert!(
        script.contains("--array=9 infer.sbatch") && !script.contains("train.sbatch"),
        "{script}"
    );
    let infer = std::fs::read_to_string(out.join("slurm/infer.sbatch")).unwrap();
    assert!(infer.contains("--job \"$SLURM_ARRAY_TASK_ID\"") && infer.contains("--partition=cpu"));
}

#[test]
fn hierarchy_and_uncertainty_report_maps_and_task_tests() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    dataset(&data);
    for experiment in [Experiment::Hierarchy, Experiment::Uncertainty] {
        let out = tmp.path().join(experiment.name());
        Plan::new(experiment, Scale::Smoke, &data, None, None)
            .unwrap()
            .save(&out)
            .unwrap();
        pvrnn_experiment::run::run(
            &out,
            &cpu(),
            "cpu",
            1,
            Selection::All,
            &AtomicBool::new(false),
            &|_| {},
        )
        .unwrap();
        let dir = report::write(&out).unwrap();
        let summary: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap())
                .unwrap();
        // Every report ends with the paper's findings beside ours.
        let md = std::fs::read_to_string(dir.join("report.md")).unwrap();
        let findings = summary["paper"].as_array().unwrap();
        assert!(
            md.contains("## Compared with the paper") && findings.len() >= 2,
            "{md}"
        );
        assert!(
            findings
                .iter()
                .all(|f| !f["ours"].as_str().unwrap().is_empty())
        );
        match experiment {
            Experiment::Hierarchy => {
                assert!(dir.join("contribution_maps.png").is_file());
                assert_eq!(summary["results"]["ablation_mode"], "readout");
                let c = &summary["results"]["contribution_per_network"];
                // The proprioceptive module feeds no image; the exteroceptive one does.
                assert!(
                    c["proprioceptive"]
                        .as_array()
                        .unwrap()
                        .iter()
                        .all(|v| v == 0.0)
                );
                assert!(
                    c["exteroceptive"]
                        .as_array()
                        .unwrap()
                        .iter()
                        .all(|v| v.as_f64().unwrap() > 0.0)
                );
                // When each module contributes: per task and subtask phase, with a labelled
                // picture; the exteroceptive module contributes in every phase.
                let over_time = &summary["results"]["contribution_over_time"];
                for task in ["repositioning", "wiping"] {
                    // Smoke scale runs the first 10 steps: the first subtask, named from the data.
                    assert_eq!(
                        over_time[task]["phases"],
                        serde_json::json!(["reaching"]),
                        "{over_time}"
                    );
                    let ext = over_time[task]["per_network"]["exteroceptive"]
                        .as_array()
                        .unwrap();
                    assert!(ext.iter().all(|phase| {
                        phase
                            .as_array()
                            .unwrap()
                            .iter()
                            .all(|v| v.as_f64().unwrap() > 0.0)
                    }));
                    assert!(
                        dir.join(format!("contributions_over_time_{task}.png"))
                            .is_file()
                    );
                }
                // Occlusion relative to the observed frame, also from the 16x16 input and the
                // prior prediction (the synthetic test sequences have robot-free renders).
                let relative = &summary["results"]["occlusion"]["relative"];
                for row in [
                    "reconstruction, everything observed",
                    "prior prediction, everything observed",
                    "reconstruction, 16x16 + proprioception observed",
                ] {
                    assert_eq!(
                        relative[row]["per_network"].as_array().unwrap().len(),
                        2,
                        "{row}: {relative}"
                    );
                }
                // The boundary test leaves out the warm-up (steps t < H) and is two-sided.
                let boundary = &summary["results"]["executive_boundary"];
                assert_eq!(boundary["from_step"], 4);
                assert_eq!(boundary["two_sided"], true);
            }
            _ => {
                let comparisons = summary["results"]["comparisons"].as_array().unwrap();
                assert_eq!(comparisons.len(), 10);
                assert!(comparisons.iter().all(|c| c["paired_t"]["df"] == 1.0));
                assert!(dir.join("sigma_p.png").is_file());
            }
        }
    }
}

#[test]
fn interference_adds_the_same_sequences_per_bed_height_for_every_network() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    dataset(&data);
    let plan = Plan::new(Experiment::Interference, Scale::Paper, &data, None, None).unwrap();
    let trains: Vec<(&str, &Vec<String>)> = plan
        .jobs
        .iter()
        .filter_map(|j| match &j.kind {
            JobKind::Train {
                condition,
                sequences,
                ..
            } => Some((condition.as_str(), sequences)),
            _ => None,
        })
        .collect();
    // 2 primary tasks x 4 conditions x 5 networks.
    assert_eq!(trains.len(), 40);
    let plus3: Vec<&Vec<String>> = trains
        .iter()
        .filter(|(c, _)| *c == "repositioning 9 + wiping 3")
        .map(|t| t.1)
        .collect();
    assert_eq!(plus3.len(), 5);
    assert!(plus3.iter().all(|s| *s == plus3[0]));
    let added: Vec<&String> = plus3[0]
        .iter()
        .filter(|s| s.starts_with("wiping"))
        .collect();
    assert_eq!(
        added,
        [
            "wiping_590mm_learn0",
            "wiping_650mm_learn0",
            "wiping_710mm_learn0"
        ]
    );
    assert!(
        trains
            .iter()
            .any(|(c, s)| *c == "wiping 9 + repositioning 9" && s.len() == 18)
    );
    // A checkpoint to reuse must match the design's training.
    assert!(
        Plan::new(
            Experiment::Interference,
            Scale::Reduced,
            &data,
            Some(Path::new("x")),
            None
        )
        .is_err()
    );
}

/// Each interference direction is tested only on its complete design: with network 0
/// alone the report gives descriptive means and no test; the job that finishes a direction
/// is the one `report::completed_by` names (the front end then writes the report); and a
/// complete direction has its ANOVA, every Holm contrast with its raw difference and
/// interval, and the "no change" claim (Fig 6A) tested as equivalence. Meanwhile each
/// network's last job rebuilds the report (`report::network_completed_by`), once, and the
/// report then counts that network as done.
#[test]
fn an_interference_direction_is_tested_once_complete() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    // Sequences of 12 steps: 16 trainings and 32 inference runs, as short as they go.
    pvrnn_dataset::synthetic::caresim_like(&[590, 650, 710], 3, 1, 12)
        .unwrap()
        .write(&data)
        .unwrap();
    let out = tmp.path().join("interference");
    let plan = Plan::new(Experiment::Interference, Scale::Smoke, &data, None, None).unwrap();
    plan.save(&out).unwrap();
    assert_eq!(plan.design.primary_tasks, ["repositioning", "wiping"]);
    let go = AtomicBool::new(false);
    // (job, direction completed, whether its report then held that direction's tests)
    let completed = std::sync::Mutex::new(Vec::new());
    // (job, network completed, that network's inference runs in the report then)
    let networks = std::sync::Mutex::new(Vec::new());
    let events = |e: Event<'_>| {
        if let Event::Reported { id, part, report } = e {
            let md = std::fs::read_to_string(report.unwrap()).unwrap();
            if part.starts_with("network ") {
                // The trials' job names end in the network's: `...-net0-<sequence>-...`.
                let JobKind::Infer { train_job, .. } = plan.jobs[id].kind else {
                    panic!("{part}: a network is finished by an inference run")
                };
                let net = plan.jobs[train_job].name.replace("train-", "infer-");
                let trials = std::fs::read_to_string(out.join("report/trials.csv"))
                    .unwrap()
                    .lines()
                    .filter(|l| l.split(',').nth(1).unwrap().starts_with(&format!("{net}-")))
                    .count();
                networks
                    .lock()
                    .unwrap()
                    .push((id, part.to_string(), trials));
                return;
            }
            let primary = part.split(' ').nth(1).unwrap().to_string();
            let tested = !md.contains(&format!("### Primary task: {primary}\n\n**No test yet**"));
            completed
                .lock()
                .unwrap()
                .push((id, part.to_string(), tested));
        }
    };
    let workers = pvrnn_experiment::run::Workers { jobs: 2, cohort: 1 };
    let run = |selection| {
        pvrnn_experiment::reporting::run_with(&out, &cpu(), "cpu", workers, selection, &go, &events)
    };
    run(Selection::Network(0)).unwrap();
    assert!(completed.lock().unwrap().is_empty(), "{completed:?}");
    // Every training says where it ran.
    let trainings = std::fs::read_to_string(out.join("report/trainings.csv")).unwrap();
    let mut lines = trainings.lines();
    let header = lines.next().unwrap();
    assert!(
        header.contains(",machines,") && header.ends_with(",gate,gate_detail"),
        "{trainings}"
    );
    // Every training says where it ran; smoke trainings have no held-out validation, so
    // the validity gate cannot judge them (their findings are not testable).
    let here = pvrnn_eval::machine::here();
    assert!(
        lines.all(|l| l.contains(&format!(",\"{here}\",")) && l.contains(",not gated,")),
        "{trainings}"
    );
    // Network 0 of each of the 8 conditions, each once, by its last job, with all of that
    // network's inference runs in the report it rebuilt.
    {
        let mut networks = networks.lock().unwrap();
        assert_eq!(networks.len(), 8, "{networks:?}");
        let mut parts: Vec<&str> = networks.iter().map(|n| n.1.as_str()).collect();
        parts.sort_unstable();
        parts.dedup();
        assert_eq!(parts.len(), 8, "{parts:?}");
        for (id, part, trials) in networks.iter() {
            assert!(part.starts_with("network 0 ("), "{part}");
            let JobKind::Infer { train_job, .. } = plan.jobs[*id].kind else {
                unreachable!()
            };
            let runs = plan
                .jobs
                .iter()
                .filter(|j| matches!(j.kind, JobKind::Infer { train_job: t, .. } if t == train_job))
                .count();
            assert!(
                runs > 0 && *trials == runs,
                "{part}: {trials} of {runs} runs reported"
            );
            assert_eq!(
                report::network_completed_by(&plan, &out, *id).as_deref(),
                Some(part.as_str())
            );
        }
        networks.clear();
    }
    let dir = report::write(&out).unwrap();
    let md = std::fs::read_to_string(dir.join("report.md")).unwrap();
    assert_eq!(
        md.matches("**No test yet**: 4 of this direction's 8 trainings")
            .count(),
        2,
        "{md}"
    );
    assert!(
        md.contains("| 1 of 2 |") && !md.contains("| condition |"),
        "{md}"
    );
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap();
    let repositioning = &summary["results"]["repositioning"];
    assert_eq!(repositioning["complete"], false);
    assert!(repositioning["art"].is_null() && repositioning["equivalence"].is_null());
    let findings = summary["paper"].as_array().unwrap();
    assert!(
        findings.iter().all(|f| f["agrees"].is_null()
            && f["note"]
                .as_str()
                .unwrap()
                .contains("without the gate: no test yet")),
        "{findings:?}"
    );
    assert!(
        md.contains("(8 of the design's 16 trainings, 2 networks per condition)"),
        "{md}"
    );

    run(Selection::All).unwrap();
    // Network 1 of each condition, but the two whose last job completed a direction: that
    // names the direction instead.
    let networks = networks.into_inner().unwrap();
    assert_eq!(networks.len(), 6, "{networks:?}");
    assert!(
        networks.iter().all(|n| n.1.starts_with("network 1 (")),
        "{networks:?}"
    );
    let completed = completed.into_inner().unwrap();
    let names: Vec<&str> = completed.iter().map(|(_, part, _)| part.as_str()).collect();
    assert_eq!(
        names,
        ["the repositioning direction", "the wiping direction"]
    );
    // Each is reported once, after a job of its own direction, with its tests.
    for (id, part, tested) in &completed {
        let JobKind::Infer { training, .. } = &plan.jobs[*id].kind else {
            panic!("an inference run ends a direction")
        };
        let primary = training.split(' ').next().unwrap();
        assert_eq!(part, &format!("the {primary} direction"));
        assert!(tested, "{part}: its report has no tests");
    }
    assert!(
        report::completed_by(&plan, &out, 0).is_some(),
        "named once all is done"
    );
    let dir = report::write(&out).unwrap();
    let md = std::fs::read_to_string(dir.join("report.md")).unwrap();
    assert!(!md.contains("No test yet"), "{md}");
    assert_eq!(
        md.matches("| condition |").count(),
        8,
        "4 measures x 2 directions: {md}"
    );
    assert!(
        md.contains("raw difference [95% CI]") && md.contains("| equivalence margin |"),
        "{md}"
    );
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap();
    for primary in ["repositioning", "wiping"] {
        let direction = &summary["results"][primary];
        assert_eq!(direction["complete"], true);
        let tost = &direction["equivalence"]["pooled"];
        let none = direction["per_network"][0][0].as_array().unwrap();
        let none_mean = none.iter().map(|v| v.as_f64().unwrap()).sum::<f64>() / none.len() as f64;
        assert!(
            (tost["margin"].as_f64().unwrap() - 0.1 * none_mean).abs() <= 1e-12 * none_mean,
            "the margin is ±10% of the none condition's mean: {tost}"
        );
        let contrasts = direction["art"]["pooled"]["contrasts"].as_array().unwrap();
        assert_eq!(contrasts.len(), 6);
        assert!(
            contrasts.iter().all(|c| c["difference"]["ci95"].is_array()),
            "{contrasts:?}"
        );
    }
    // The asymmetry of the two directions, once both are complete: every measure's
    // difference of log ratios with its interval.
    let asymmetry = &summary["results"]["asymmetry"];
    assert_eq!(asymmetry["first"], "repositioning");
    for measure in ["pooled", "vision", "proprioception", "equal weight"] {
        let t = &asymmetry["measures"][measure];
        assert!(
            t["p"].is_f64() && t["ci95"].is_array(),
            "{measure}: {asymmetry}"
        );
    }
    assert!(
        md.contains("### Asymmetry: does the other task's data change wiping's error"),
        "{md}"
    );
    let findings = summary["paper"].as_array().unwrap();
    assert_eq!(
        findings.len(),
        7,
        "Fig 6A, 6B, its 4 Holm contrasts and the asymmetry: {findings:?}"
    );
    assert!(
        findings[6]["ours"].as_str().unwrap().contains("Welch t("),
        "{findings:?}"
    );
    assert!(
        findings[0]["ours"]
            .as_str()
            .unwrap()
            .starts_with("TOST: difference"),
        "{findings:?}"
    );
    assert!(
        findings
            .iter()
            .all(|f| f["effect"].as_str().unwrap().contains("detectable")),
        "an effect with its interval beside every p: {findings:?}"
    );
    assert!(
        md.contains("(16 of the design's 16 trainings, 2 networks per condition)"),
        "{md}"
    );
}

/// Experiments sharing a networks folder compute each inference run once: uncertainty's
/// runs are hierarchy's (everything observed; the maps are read out after each step), taken
/// from `<networks>/runs/`, and they are exactly what uncertainty computes on its own.
#[test]
fn shared_networks_compute_each_run_once() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    dataset(&data);
    let networks = tmp.path().join("networks");
    let go = AtomicBool::new(false);
    let mut plans = Vec::new();
    for (experiment, name, shared) in [
        (Experiment::Hierarchy, "hierarchy", true),
        (Experiment::Uncertainty, "uncertainty", true),
        (Experiment::Uncertainty, "uncertainty-alone", false),
    ] {
        let out = tmp.path().join(name);
        let mut plan = Plan::new(experiment, Scale::Smoke, &data, None, None).unwrap();
        if shared {
            plan.claim_networks_dir(&networks).unwrap();
        }
        plan.save(&out).unwrap();
        let inferred = std::sync::atomic::AtomicUsize::new(0);
        let events = |e: Event<'_>| {
            if let Event::Inferring { done: 1, .. } = e {
                inferred.fetch_add(1, Ordering::SeqCst);
            }
        };
        pvrnn_experiment::run::run(&out, &cpu(), "cpu", 1, Selection::All, &go, &events).unwrap();
        let runs = plan
            .jobs
            .iter()
            .filter(|j| matches!(j.kind, JobKind::Infer { .. }))
            .count();
        let expected = if name == "uncertainty" { 0 } else { runs };
        assert_eq!(inferred.into_inner(), expected, "{name}");
        plans.push((out, plan));
    }
    let (shared_dir, shared) = &plans[1];
    let (alone_dir, alone) = &plans[2];
    for (a, b) in shared.jobs.iter().zip(&alone.jobs) {
        if !matches!(a.kind, JobKind::Infer { .. }) {
            continue;
        }
        let (x, maps) = read_infer_result(&shared.result_path(shared_dir, a.id)).unwrap();
        let (y, _) = read_infer_result(&alone.result_path(alone_dir, b.id)).unwrap();
        assert!(maps.is_none() && x.map_means.is_none());
        assert_eq!(x.job, a.name);
        assert_eq!(
            (&x.errors, x.sigma_p, x.sigma_p_change, &x.executive_change),
            (&y.errors, y.sigma_p, y.sigma_p_change, &y.executive_change),
            "{}",
            a.name
        );
    }
    assert!(networks.join("runs").is_dir());
}

/// The convergence rule: validation-best first, then a flat free energy, then the cap.
#[test]
fn convergence_rule_stops_at_the_validation_best_a_flat_curve_or_the_cap() {
    use pvrnn_eval::validation::ValidationRow;
    use pvrnn_experiment::run::{Stop, convergence};
    let mut design = pvrnn_experiment::Design::of(Experiment::Hierarchy, Scale::Converged);
    assert_eq!(
        (
            design.validate_every,
            design.patience,
            design.flat_change,
            design.select_from
        ),
        (Some(2_000), Some(2), Some(0.01), Some(8_000))
    );
    design.train_iterations = 100;
    design.select_from = None;
    let row = |iteration, error| ValidationRow {
        iteration,
        failed_trials: 0,
        trials: 4,
        recon_vision_top: error,
        recon_joints: None,
        recon_torques: None,
        seconds: 1.0,
        upsample: None,
        upsample_detail: None,
        mean: None,
        machine: None,
        ..Default::default()
    };
    let falling: Vec<f64> = (0..60).map(|i| 100.0 - i as f64).collect();
    let flat = vec![50.0; 60];
    let improving = [row(20, 0.3), row(40, 0.2), row(60, 0.1)];
    let turned = [row(20, 0.3), row(40, 0.1), row(60, 0.2), row(80, 0.15)];
    assert_eq!(convergence(&design, &falling, &improving, 60), None);
    assert_eq!(convergence(&design, &falling, &turned[..3], 60), None);
    assert_eq!(
        convergence(&design, &falling, &turned, 80),
        Some(Stop::ValidationBest)
    );
    assert_eq!(
        convergence(&design, &flat, &improving, 60),
        Some(Stop::Flat)
    );
    assert_eq!(
        convergence(&design, &falling, &improving, 100),
        Some(Stop::Cap)
    );
    // Validations before `select_from` do not count: an early best neither stops the run
    // nor is its network.
    let early = [row(20, 0.1), row(40, 0.3), row(60, 0.35), row(80, 0.36)];
    assert_eq!(
        convergence(&design, &falling, &early[..3], 60),
        Some(Stop::ValidationBest)
    );
    design.select_from = Some(40);
    assert_eq!(convergence(&design, &falling, &early[..3], 60), None);
    assert_eq!(
        convergence(&design, &falling, &early, 80),
        Some(Stop::ValidationBest)
    );
    let counted = pvrnn_experiment::run::counted(&design, &early);
    assert_eq!(
        pvrnn_eval::validation::best(counted).map(|r| r.iteration),
        Some(40)
    );
}

/// A learning dataset in `dir`/data and a held-out one (one sequence per task) in
/// `dir`/held-out.
fn learning_and_held_out(dir: &Path) -> (std::path::PathBuf, std::path::PathBuf) {
    let data = dir.join("data");
    dataset(&data);
    let held_out = dir.join("held-out");
    pvrnn_dataset::synthetic::caresim_like(&[650], 1, 0, 6)
        .unwrap()
        .write(&held_out)
        .unwrap();
    (data, held_out)
}

/// `experiment`'s smoke plan on `data` under the convergence rule at a test's scale: a
/// validation on `held_out` every 4 iterations, patience 1, no flat-curve stop.
fn validated_smoke_plan(experiment: Experiment, data: &Path, held_out: &Path) -> Plan {
    let mut plan = Plan::new(experiment, Scale::Smoke, data, None, Some(held_out)).unwrap();
    plan.design.validate_every = Some(4);
    plan.design.patience = Some(1);
    plan.design.flat_change = Some(1e-12);
    plan
}

/// A training under a validation rule validates, keeps its best checkpoint, stops by the
/// rule, and its inference runs read the network the rule chose.
#[test]
fn a_converged_design_validates_and_reads_the_network_it_chose() {
    let tmp = tempfile::tempdir().unwrap();
    let (data, held_out) = learning_and_held_out(tmp.path());
    assert!(
        Plan::new(Experiment::Hierarchy, Scale::Converged, &data, None, None)
            .unwrap_err()
            .to_string()
            .contains("--validate")
    );
    assert!(
        Plan::new(
            Experiment::Hierarchy,
            Scale::Smoke,
            &data,
            None,
            Some(&data)
        )
        .is_err()
    );
    let plan = validated_smoke_plan(Experiment::Hierarchy, &data, &held_out);
    // The cap: the smoke design's 20 iterations.
    let out = tmp.path().join("hierarchy");
    plan.save(&out).unwrap();
    let go = AtomicBool::new(false);
    pvrnn_experiment::run::run(&out, &cpu(), "cpu", 1, Selection::Job(0), &go, &|_| {}).unwrap();
    let trained = read_train_result(&plan.result_path(&out, 0)).unwrap();
    let iterations: Vec<u64> = trained.validations.iter().map(|r| r.iteration).collect();
    assert_eq!(
        iterations,
        (1..=iterations.len() as u64)
            .map(|k| 4 * k)
            .collect::<Vec<_>>()
    );
    let best = pvrnn_eval::validation::best(&trained.validations).unwrap();
    let path = pvrnn_experiment::run::network_path(&plan, &out, 0).unwrap();
    match trained.stop {
        Some(pvrnn_experiment::run::Stop::ValidationBest) => {
            // One validation after the best did not beat it.
            assert_eq!(trained.iterations, best.iteration + 4);
            assert_eq!(trained.network_iteration, Some(best.iteration));
            assert_eq!(path, plan.best_path(&out, 0));
        }
        Some(pvrnn_experiment::run::Stop::Cap) => {
            assert_eq!(trained.iterations, 20);
            assert_eq!(trained.network_iteration, Some(best.iteration));
            assert!(iterations.iter().all(|&i| i <= 20));
        }
        other => panic!("stopped by {other:?}"),
    }
    // Every validation records the validity gate's baselines beside the network's errors;
    // a 20-iteration network has not learned, so the gate fails it and the report says so.
    for r in &trained.validations {
        assert!(
            [r.nearest, r.next_joints, r.next_torques, r.previous_joints]
                .iter()
                .chain([&r.previous_torques, &r.mean_joints, &r.mean_torques])
                .all(|v| v.is_some_and(f64::is_finite)),
            "{r:?}"
        );
    }
    let gate = pvrnn_eval::gate::Gate::of(best);
    assert_eq!(
        gate.verdict,
        pvrnn_eval::gate::GateVerdict::Fail,
        "{}",
        gate.describe()
    );
    pvrnn_experiment::report::write(&out).unwrap();
    let trainings = std::fs::read_to_string(out.join("report/trainings.csv")).unwrap();
    let row = trainings.lines().nth(1).unwrap();
    assert!(
        row.contains(",fail,vision ") && row.contains("(lost)"),
        "{trainings}"
    );
    let summary = std::fs::read_to_string(out.join("report/summary.json")).unwrap();
    assert!(
        summary.contains("not testable on these networks: 0 of 1 pass the validity gate's"),
        "{summary}"
    );
    let file = pvrnn_core::io::TensorFile::open(&path).unwrap();
    assert_eq!(
        pvrnn_core::io::checkpoint_iteration(&file),
        trained.network_iteration
    );
    // The best network is kept without optimiser moments (a third of a checkpoint).
    let best_file = pvrnn_core::io::TensorFile::open(&plan.best_path(&out, 0)).unwrap();
    assert!(!pvrnn_core::io::is_checkpoint(&best_file));
    assert!(plan.validation_log_path(&out, 0).is_file());
    // A network file of another iteration than the result names (stale) is refused.
    let kept = std::fs::read(&path).unwrap();
    let model = pvrnn_core::io::load_model(&path).unwrap();
    let other = trained.network_iteration.unwrap() + 1;
    pvrnn_core::io::save_model_at(&path, &model, other).unwrap();
    let e = pvrnn_experiment::run::network_path(&plan, &out, 0).unwrap_err();
    assert!(
        e.to_string().contains(&format!("iteration {other}")) && e.to_string().contains("stale"),
        "{e:#}"
    );
    std::fs::write(&path, kept).unwrap();
    assert_eq!(
        pvrnn_experiment::run::network_path(&plan, &out, 0).unwrap(),
        path
    );
    // Learning all 18 sequences, the network is validated on both tasks' held-out ones;
    // an interference network that learns one task only, on that task's.
    assert_eq!(trained.validations[0].trials, 2);
    let mut single = Plan::new(
        Experiment::Interference,
        Scale::Smoke,
        &data,
        None,
        Some(&held_out),
    )
    .unwrap();
    single.design.validate_every = Some(10);
    single.design.patience = Some(1);
    let out = tmp.path().join("interference");
    single.save(&out).unwrap();
    let JobKind::Train { condition, .. } = &single.jobs[0].kind else {
        panic!("a training first")
    };
    assert!(condition.ends_with(" 0"), "{condition}");
    pvrnn_experiment::run::run(&out, &cpu(), "cpu", 1, Selection::Job(0), &go, &|_| {}).unwrap();
    let trained = read_train_result(&single.result_path(&out, 0)).unwrap();
    assert_eq!(
        trained.validations[0].trials, 1,
        "{:?}",
        trained.validations
    );
    // Learning both tasks (the other task's sequences added), an interference network is
    // still validated on its primary task only: the one its inference runs are scored on.
    let mixed = single
        .jobs
        .iter()
        .position(
            |j| matches!(&j.kind, JobKind::Train { condition, .. } if !condition.ends_with(" 0")),
        )
        .expect("a condition with the other task added");
    pvrnn_experiment::run::run(&out, &cpu(), "cpu", 1, Selection::Job(mixed), &go, &|_| {})
        .unwrap();
    let trained = read_train_result(&single.result_path(&out, mixed)).unwrap();
    assert_eq!(
        trained.validations[0].trials, 1,
        "{:?}",
        trained.validations
    );
}

/// `plan` saved in `dir`/alone and `dir`/together, its jobs 0 and 1 (a condition's first
/// two networks) trained one by one in the first.
fn trained_alone(plan: &Plan, dir: &Path) -> (std::path::PathBuf, std::path::PathBuf) {
    let (alone, together) = (dir.join("alone"), dir.join("together"));
    plan.save(&alone).unwrap();
    plan.save(&together).unwrap();
    let go = AtomicBool::new(false);
    for id in [0, 1] {
        pvrnn_experiment::run::run(&alone, &cpu(), "cpu", 1, Selection::Job(id), &go, &|_| {})
            .unwrap();
    }
    (alone, together)
}

/// A cohort's members validate side by side: the validations, the networks chosen and the
/// stopping iterations are those of each network trained alone.
#[test]
fn a_cohort_validates_as_its_networks_validate_alone() {
    let tmp = tempfile::tempdir().unwrap();
    let (data, held_out) = learning_and_held_out(tmp.path());
    let plan = validated_smoke_plan(Experiment::Robustness, &data, &held_out);
    let (alone, together) = trained_alone(&plan, tmp.path());
    let go = AtomicBool::new(false);
    let started = std::sync::Mutex::new(Vec::new());
    let events = |e: Event<'_>| {
        if let Event::Started { id, .. } = e {
            started.lock().unwrap().push(id);
        }
    };
    let workers = pvrnn_experiment::run::Workers { jobs: 1, cohort: 2 };
    pvrnn_experiment::run::run_with(
        &together,
        &cpu(),
        "cpu",
        workers,
        Selection::All,
        &go,
        &events,
    )
    .unwrap();
    assert_eq!(started.lock().unwrap()[..2], [0, 1], "one cohort of both");
    for id in [0, 1] {
        let (a, b) = (
            read_train_result(&plan.result_path(&alone, id)).unwrap(),
            read_train_result(&plan.result_path(&together, id)).unwrap(),
        );
        assert!(!a.validations.is_empty(), "job {id} validated");
        // Both ran here, validations and all: one machine, named as validations name it.
        let here = [pvrnn_eval::machine::here()];
        assert_eq!(
            (&a.machines[..], &b.machines[..]),
            (&here[..], &here[..]),
            "job {id}"
        );
        let scores = |r: &pvrnn_experiment::run::TrainResult| {
            r.validations
                .iter()
                .map(|v| (v.iteration, v.failed_trials, v.recon_vision_top.to_bits()))
                .collect::<Vec<_>>()
        };
        assert_eq!(scores(&a), scores(&b), "job {id}: its validations");
        assert_eq!(
            (a.iterations, a.network_iteration, a.stop),
            (b.iterations, b.network_iteration, b.stop),
            "job {id}"
        );
        assert_eq!(
            a.final_free_energy.map(f64::to_bits),
            b.final_free_energy.map(f64::to_bits),
            "job {id}: the same network"
        );
    }
}

/// A condition's networks trained together (a cohort of 2) give the results and the
/// checkpoints they get trained one by one, are checkpointed together when interrupted,
/// and resume.
#[test]
fn networks_of_one_condition_train_together_as_they_train_alone() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    dataset(&data);
    let plan = Plan::new(Experiment::Robustness, Scale::Smoke, &data, None, None).unwrap();
    let (alone, together) = trained_alone(&plan, tmp.path());
    let go = AtomicBool::new(false);
    let workers = pvrnn_experiment::run::Workers { jobs: 1, cohort: 2 };
    // Interrupted at iteration 7 of network 0: both are checkpointed there.
    let stop = AtomicBool::new(false);
    let started = std::sync::Mutex::new(Vec::new());
    let events = |e: Event<'_>| match e {
        Event::Started { id, .. } => started.lock().unwrap().push(id),
        Event::Training { id: 0, done: 7, .. } => stop.store(true, Ordering::SeqCst),
        _ => {}
    };
    let e = pvrnn_experiment::run::run_with(
        &together,
        &cpu(),
        "cpu",
        workers,
        Selection::All,
        &stop,
        &events,
    )
    .unwrap_err();
    assert!(e.downcast_ref::<Interrupted>().is_some(), "{e:#}");
    assert_eq!(*started.lock().unwrap(), vec![0, 1], "one cohort of both");
    for id in [0, 1] {
        let file = pvrnn_core::io::TensorFile::open(&plan.checkpoint_path(&together, id)).unwrap();
        assert_eq!(
            pvrnn_core::io::checkpoint_iteration(&file),
            Some(7),
            "job {id}"
        );
    }
    pvrnn_experiment::run::run_with(
        &together,
        &cpu(),
        "cpu",
        workers,
        Selection::All,
        &go,
        &|_| {},
    )
    .unwrap();
    for id in [0, 1] {
        let (a, b) = (
            read_train_result(&plan.result_path(&alone, id)).unwrap(),
            read_train_result(&plan.result_path(&together, id)).unwrap(),
        );
        assert_eq!(a.iterations, b.iterations, "job {id}");
        assert_eq!(
            a.final_free_energy.map(f64::to_bits),
            b.final_free_energy.map(f64::to_bits),
            "job {id}: the same network"
        );
        let weights = |dir: &Path| {
            let model = pvrnn_core::io::load_checkpoint(&plan.checkpoint_path(dir, id))
                .unwrap()
                .into_model();
            model
                .params
                .named()
                .into_iter()
                .map(|(_, t, _)| t.data().to_vec())
                .collect::<Vec<_>>()
        };
        assert!(
            weights(&alone) == weights(&together),
            "job {id}: the same weights"
        );
    }
}

/// A fixed-iteration design (the paper's protocol) given held-out data validates its network
/// once, at its last iteration, so that the validity gate can judge it, and is not stopped
/// early; a reused checkpoint is validated the same way.
#[test]
fn a_fixed_design_with_held_out_data_validates_its_network_once_for_the_gate() {
    let tmp = tempfile::tempdir().unwrap();
    let (data, held_out) = learning_and_held_out(tmp.path());
    let plan = Plan::new(
        Experiment::Robustness,
        Scale::Smoke,
        &data,
        None,
        Some(&held_out),
    )
    .unwrap();
    assert!(plan.design.validate_every.is_none());
    let out = tmp.path().join("robustness");
    plan.save(&out).unwrap();
    let go = AtomicBool::new(false);
    pvrnn_experiment::run::run(&out, &cpu(), "cpu", 1, Selection::Job(0), &go, &|_| {}).unwrap();
    let trained = read_train_result(&plan.result_path(&out, 0)).unwrap();
    let JobKind::Train { iterations, .. } = plan.jobs[0].kind else {
        panic!("a training first")
    };
    assert_eq!((trained.iterations, trained.stop), (iterations, None));
    let validated: Vec<u64> = trained.validations.iter().map(|v| v.iteration).collect();
    assert_eq!(validated, [iterations]);
    assert_eq!(trained.network_iteration, Some(iterations));
    assert!(trained.validations[0].nearest.is_some());
    // The same network reused as network 0 of another plan: validated too.
    let checkpoint = plan.checkpoint_path(&out, 0);
    let again = Plan::new(
        Experiment::Robustness,
        Scale::Smoke,
        &data,
        Some(&checkpoint),
        Some(&held_out),
    )
    .unwrap();
    let out = tmp.path().join("reused");
    again.save(&out).unwrap();
    pvrnn_experiment::run::run(&out, &cpu(), "cpu", 1, Selection::Job(0), &go, &|_| {}).unwrap();
    let reused = read_train_result(&again.result_path(&out, 0)).unwrap();
    assert!(reused.reused.is_some());
    assert_eq!(
        reused
            .validations
            .iter()
            .map(|v| v.iteration)
            .collect::<Vec<_>>(),
        [iterations]
    );
    assert_eq!(
        reused.validations[0].recon_vision_top, trained.validations[0].recon_vision_top,
        "the same network, the same held-out score"
    );
}
