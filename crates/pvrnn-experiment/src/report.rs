//! Reports rebuilt from the result files alone: per trial -> per network (mean over trials,
//! then over test sequences) -> mean ± SE over networks, the paper's statistics, figures.
//! The scale is stamped on every table and figure title.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Result;
use pvrnn_core::{AblationMode, ModelConfig, ModuleId};
use pvrnn_eval::gate::Gate;
use pvrnn_eval::plots::{Bar, bar_chart, write_png};
use pvrnn_eval::report::sig;
use rand::{RngExt, SeedableRng};
use serde::Serialize;
use serde_json::{Value, json};

use crate::occlusion::OcclusionScores;
use crate::plan::{Experiment, JobKind, Plan, VISION_CONDITIONS};
use crate::run::{InferResult, Stop, TrainResult, read_infer_result, read_train_result};
use crate::stats::{self, Blocked2, Contrast, Effect, mean_se};

/// Steps on either side of a subtask boundary that count as "near" it.
pub const BOUNDARY_HALF_WIDTH: usize = 3;
/// Permutations of the boundary test.
pub const PERMUTATIONS: usize = 2000;

struct Results {
    /// The experiment's folder.
    dir: PathBuf,
    trains: Vec<TrainResult>,
    /// The inference runs every analysis uses.
    infers: Vec<(InferResult, Option<Vec<Vec<f32>>>)>,
    /// Each inference result's file, by job name.
    paths: BTreeMap<String, PathBuf>,
    /// Inference runs that diverged beyond repair: left out of every analysis, listed.
    diverged: Vec<InferResult>,
    done: usize,
    total: usize,
}

fn collect(plan: &Plan, dir: &Path) -> Result<Results> {
    let mut r = Results {
        dir: dir.to_path_buf(),
        trains: Vec::new(),
        infers: Vec::new(),
        paths: BTreeMap::new(),
        diverged: Vec::new(),
        done: 0,
        total: plan.jobs.len(),
    };
    for job in &plan.jobs {
        if !plan.is_done(dir, job.id) {
            continue;
        }
        r.done += 1;
        let path = plan.result_path(dir, job.id);
        match job.kind {
            JobKind::Train { .. } => r.trains.push(read_train_result(&path)?),
            JobKind::Infer { .. } => {
                let (result, maps) = read_infer_result(&path)?;
                r.paths.insert(result.job.clone(), path.clone());
                if result.diverged.is_some() {
                    r.diverged.push(result);
                } else {
                    r.infers.push((result, maps));
                }
            }
        }
    }
    Ok(r)
}

/// Per network: the mean over test sequences of the mean over trials of `value`, for the
/// results `keep` selects.
fn per_network(
    infers: &[(InferResult, Option<Vec<Vec<f32>>>)],
    keep: &dyn Fn(&InferResult) -> bool,
    value: &dyn Fn(&InferResult) -> Option<f64>,
) -> BTreeMap<usize, f64> {
    let mut by_seq: BTreeMap<(usize, String), Vec<f64>> = BTreeMap::new();
    for (r, _) in infers {
        if let Some(v) = value(r).filter(|v| keep(r) && v.is_finite()) {
            by_seq
                .entry((r.network, r.sequence.clone()))
                .or_default()
                .push(v);
        }
    }
    let mut by_net: BTreeMap<usize, Vec<f64>> = BTreeMap::new();
    for ((net, _), trials) in by_seq {
        by_net.entry(net).or_default().push(mean_se(&trials).0);
    }
    by_net
        .into_iter()
        .map(|(n, seqs)| (n, mean_se(&seqs).0))
        .collect()
}

fn mean_se_text(values: &[f64]) -> String {
    if values.is_empty() {
        return "–".into();
    }
    match mean_se(values) {
        (m, Some(se)) => format!("{} ± {}", sig(m), sig(se)),
        (m, None) => sig(m),
    }
}

fn bar(label: &str, values: &[f64]) -> Bar {
    let (mean, se) = mean_se(values);
    Bar {
        label: label.into(),
        mean: if values.is_empty() { f64::NAN } else { mean },
        se,
    }
}

fn p_text(p: Option<f64>) -> String {
    p.map_or("–".into(), |p| {
        if p < 1e-4 {
            "< 0.0001".into()
        } else {
            format!("{p:.4}")
        }
    })
}

fn effects_table(out: &mut String, effects: &[Effect]) {
    out.push_str("| effect | F | df | p | partial η² |\n|---|---|---|---|---|\n");
    for e in effects {
        let _ = writeln!(
            out,
            "| {} | {} | {}, {} | {} | {} |",
            e.effect,
            sig(e.f),
            e.df1,
            e.df2,
            p_text(e.p),
            sig(e.partial_eta_squared)
        );
    }
}

fn contrasts_table(out: &mut String, contrasts: &[Contrast]) {
    out.push_str("| contrast | rank difference | t | df | p | p (Holm) | Cohen's d (pooled SD; for paired levels, pairing ignored) | raw difference [95% CI] |\n|---|---|---|---|---|---|---|---|\n");
    for c in contrasts {
        let _ = writeln!(
            out,
            "| {} vs {} | {} | {} | {} | {} | {} | {} | {} |",
            c.a,
            c.b,
            sig(c.rank_difference),
            sig(c.t),
            c.df,
            p_text(c.p),
            p_text(c.p_holm),
            sig(c.cohen_d),
            difference_text(c.difference.as_ref()),
        );
    }
}

/// "m [lo, hi]", or "–" without one.
fn difference_text(d: Option<&stats::Difference>) -> String {
    d.map_or("–".into(), |d| {
        format!("{} [{}, {}]", sig(d.mean), sig(d.ci95[0]), sig(d.ci95[1]))
    })
}

/// Rebuilds `DIR/report/` (report.md, summary.json, figures) from the results. One at a
/// time in a process: jobs finishing together may each complete a part of the design.
pub fn write(dir: &Path) -> Result<PathBuf> {
    static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let _guard = ONE_AT_A_TIME
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    let plan = Plan::load(dir)?;
    let results = collect(&plan, dir)?;
    let out_dir = dir.join("report");
    let built_from = jobs_done_in_report(&out_dir);
    anyhow::ensure!(
        built_from <= results.done,
        "{}: the report there was built from {built_from} finished jobs, and only {} have \
         their result files here: the others' files are missing (a clean clone of this \
         repository keeps only the reports of docs/results, not the per-trial inference \
         outputs; docs/results/README.md says how to regenerate them); the report is left \
         as it is (delete report/summary.json to build it from fewer)",
        dir.display(),
        results.done
    );
    std::fs::create_dir_all(&out_dir)?;
    let stamp = format!("{} scale", plan.scale.name());
    let mut md = String::new();
    let _ = writeln!(md, "# Experiment: {} ({stamp})\n", plan.experiment.name());
    design_header(&plan, &results, &mut md);
    learning_curves(&plan, &results.trains, &mut md);
    md.push('\n');
    let mut summary = json!({
        "format": "pvrnn-experiment-report/1",
        "experiment": plan.experiment.name(),
        "scale": plan.scale.name(),
        "design": plan.design,
        "jobs_done": results.done,
        "jobs_total": results.total,
        "trainings": results.trains,
        "diverged": results.diverged,
    });
    let body = match plan.experiment {
        Experiment::Hierarchy => hierarchy(&plan, &results, &out_dir, &stamp, &mut md)?,
        Experiment::Uncertainty => uncertainty(&results, &out_dir, &stamp, &mut md)?,
        Experiment::Robustness => robustness(&results, &out_dir, &stamp, &mut md)?,
        Experiment::Interference => interference(&plan, &results, &out_dir, &stamp, &mut md)?,
    };
    let gates = network_gates(&results.trains);
    let count = |pass: fn(&Gate) -> bool| {
        gates
            .iter()
            .filter(|g| g.as_ref().is_some_and(pass))
            .count()
    };
    let gate_summary = crate::paper::GateSummary {
        passing: count(Gate::passes),
        passing_vision: count(Gate::passes_vision),
        networks: gates.len(),
    };
    let findings = crate::paper::gated(
        crate::paper::findings(plan.experiment, &body),
        &gate_summary,
    );
    md.push_str(&crate::paper::markdown(
        &findings,
        &stamp,
        &coverage(&plan, &results),
    ));
    summary["results"] = body;
    summary["gate"] = serde_json::to_value(&gate_summary)?;
    summary["paper"] = serde_json::to_value(&findings)?;
    let scale = plan.scale.name();
    pvrnn_core::io::write_atomic(
        &out_dir.join("trials.csv"),
        trials_csv(
            scale,
            &results
                .infers
                .iter()
                .map(|(r, _)| r)
                .chain(&results.diverged)
                .collect::<Vec<_>>(),
        )
        .as_bytes(),
    )?;
    pvrnn_core::io::write_atomic(
        &out_dir.join("trainings.csv"),
        trainings_csv(
            scale,
            &results.trains,
            &gates,
            plan.design.flat_change.unwrap_or(FLAT_CHANGE),
        )
        .as_bytes(),
    )?;
    md.push_str("## Data

Every inference run (one row per network, test sequence, condition and trial; errors in model units) is in `trials.csv`, every training in `trainings.csv`: tidy tables for re-checking the statistics elsewhere (e.g. `read.csv` in R).
");
    pvrnn_core::io::write_atomic(&out_dir.join("report.md"), md.as_bytes())?;
    pvrnn_core::io::write_atomic(
        &out_dir.join("summary.json"),
        serde_json::to_string_pretty(&summary)?.as_bytes(),
    )?;
    Ok(out_dir)
}

/// How much of the design the results cover: networks, or for interference (one network
/// per training) trainings of the design's.
fn coverage(plan: &Plan, results: &Results) -> String {
    let covered = results
        .infers
        .iter()
        .map(|(x, _)| (x.training.as_str(), x.network))
        .collect::<std::collections::BTreeSet<_>>()
        .len();
    if plan.experiment == Experiment::Interference {
        let planned = plan
            .jobs
            .iter()
            .filter(|j| matches!(j.kind, JobKind::Train { .. }))
            .count();
        format!(
            "{covered} of the design's {planned} trainings, {} networks per condition",
            plan.design.networks
        )
    } else {
        format!(
            "{covered} of the design's {} networks",
            plan.design.networks
        )
    }
}

/// The report's opening: the design at its scale, and what is missing or diverged.
fn design_header(plan: &Plan, results: &Results, md: &mut String) {
    let d = &plan.design;
    let _ = writeln!(
        md,
        "Scale **{}**: {}. Networks: {}, learning iterations: {}, trials per test sequence: {}, inference window: {}, updates per step: {}, test steps: {}. Estimated training time: {:.1} h on 2 cores. Proprioception ranges: {}. Dataset: `{}` ({}).\n",
        plan.scale.name(),
        d.note,
        d.networks,
        d.train_iterations,
        d.trials,
        d.inference_window
            .map_or("model's (30)".into(), |v| v.to_string()),
        d.inference_iterations
            .map_or("model's (50)".into(), |v| v.to_string()),
        d.test_steps
            .map_or("whole sequences".into(), |v| format!("first {v}")),
        d.estimated_training_hours,
        plan.ranges_from,
        plan.dataset.display(),
        if plan.dataset_source.is_empty() {
            "source not recorded"
        } else {
            &plan.dataset_source
        }
    );
    if results.done < results.total {
        let _ = writeln!(
            md,
            "**Partial**: {} of {} jobs done; the numbers below use the finished ones.\n",
            results.done, results.total
        );
    }
    if !results.diverged.is_empty() {
        let listed: Vec<String> = results
            .diverged
            .iter()
            .map(|x| {
                format!(
                    "network {} on `{}` ({}, trial {}) at step {}",
                    x.network,
                    x.sequence,
                    x.condition,
                    x.trial,
                    x.diverged.as_ref().map_or(0, |d| d.step)
                )
            })
            .collect();
        let _ = writeln!(
            md,
            "**Diverged**: online inference diverged beyond repair in {} of {} inference runs, which every analysis below leaves out: {}.\n",
            results.diverged.len(),
            results.diverged.len() + results.infers.len(),
            listed.join("; ")
        );
    }
}

/// The convergence criterion applied to every network: the relative change of the mean
/// free energy over the last tenth of its iterations must be under 1% (or, under a design
/// with a validation rule, the rule stopped it).
pub const FLAT_CHANGE: f64 = 0.01;

/// The learning-curves table: per network the iterations reached, the last-tenth change,
/// why it stopped, the iteration of the network used, and whether it converged.
fn learning_curves(plan: &Plan, trains: &[TrainResult], md: &mut String) {
    let flat = plan.design.flat_change.unwrap_or(FLAT_CHANGE);
    let rule = match plan.design.validate_every {
        Some(every) => format!(
            "trained until {} validations in a row (every {every} iterations, on `{}`{}) did not beat the best one, or the free energy changed by less than {:.0}% over the last tenth of the iterations; at most {} iterations",
            plan.design.patience.unwrap_or(0),
            plan.validation_dataset
                .as_deref()
                .map_or("?".into(), |p| p.display().to_string()),
            plan.design
                .select_from
                .map_or(String::new(), |from| format!(
                    "; those before iteration {from} do not count"
                )),
            flat * 100.0,
            plan.design.train_iterations
        ),
        None => format!(
            "a fixed {} iterations; a network counts as converged when its free energy changed by less than {:.0}% over the last tenth",
            plan.design.train_iterations,
            flat * 100.0
        ),
    };
    let _ = writeln!(
        md,
        "## Learning curves\n\nConvergence: {rule}. *Final F*: the free energy at the last iteration trained (not at the network used). *Last-tenth change*: the relative change of the mean free energy from the second-to-last to the last tenth of the iterations (negative = still falling).\n\n| network | training | iterations | network used | final F | last-tenth change | stopped | converged | time |\n|---|---|---|---|---|---|---|---|---|"
    );
    for t in trains {
        let stopped = match t.stop {
            Some(Stop::ValidationBest) => "validation best".to_string(),
            Some(Stop::Flat) => "flat".to_string(),
            Some(Stop::Cap) => "cap".to_string(),
            None => "fixed iterations".to_string(),
        };
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} | {} | {stopped} | {} | {} |",
            t.network,
            t.condition,
            t.iterations,
            t.network_iteration.unwrap_or(t.iterations),
            t.final_free_energy.map_or("–".into(), sig),
            t.last_tenth_change
                .map_or("–".into(), |c| format!("{:+.2}%", c * 100.0)),
            if t.converged(flat) { "yes" } else { "**no**" },
            match &t.reused {
                Some(p) => format!("reused `{p}`"),
                None => {
                    let on = t.machines.join("; then ");
                    match (&t.backend, on.is_empty()) {
                        (Some(b), false) => format!("{:.0} s ({b}; on {on})", t.seconds),
                        (Some(b), true) => format!("{:.0} s ({b})", t.seconds),
                        (None, _) => format!("{:.0} s", t.seconds),
                    }
                }
            }
        );
    }
    let unconverged = trains.iter().filter(|t| !t.converged(flat)).count();
    if unconverged > 0 {
        let _ = writeln!(
            md,
            "\n**Not converged**: {unconverged} of {} networks; their results stand at the iterations reached.",
            trains.len()
        );
    }
    md.push('\n');
}

/// A CSV field: quoted when it holds a comma, a quote or a line break.
fn csv_field(text: &str) -> String {
    if text.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", text.replace('"', "\"\""))
    } else {
        text.to_string()
    }
}

/// A number for the CSVs: full precision, empty when missing or not finite.
fn csv_number(v: Option<f64>) -> String {
    v.filter(|v| v.is_finite())
        .map_or_else(String::new, |v| v.to_string())
}

/// One row per inference run: what it ran and every score it recorded.
/// One row per inference run; a run that diverged has its step in `diverged_at_step` and
/// no scores (they would cover only the steps before it).
fn trials_csv(scale: &str, runs: &[&InferResult]) -> String {
    let modules: Vec<String> = module_names()
        .iter()
        .map(|m| m.to_lowercase().replace(' ', "_"))
        .collect();
    let error_keys: std::collections::BTreeSet<&String> =
        runs.iter().flat_map(|r| r.errors.keys()).collect();
    let mut header: Vec<String> = [
        "scale",
        "job",
        "network",
        "training",
        "sequence",
        "task",
        "condition",
        "trial",
        "steps",
        "diverged_at_step",
    ]
    .map(String::from)
    .to_vec();
    header.extend(error_keys.iter().map(|k| format!("error_{k}")));
    for prefix in ["sigma_p", "sigma_p_change", "map_mean"] {
        header.extend(modules.iter().map(|m| format!("{prefix}_{m}")));
    }
    header.push("backend".into());
    let mut out = header.join(",") + "\n";
    for r in runs {
        let diverged = r.diverged.as_ref().map(|d| d.step.to_string());
        let mut row: Vec<String> = [
            scale,
            &r.job,
            &r.network.to_string(),
            &r.training,
            &r.sequence,
            &r.task,
            &r.condition,
            &r.trial.to_string(),
            &r.steps.to_string(),
            diverged.as_deref().unwrap_or(""),
        ]
        .iter()
        .map(|f| csv_field(f))
        .collect();
        if diverged.is_some() {
            let scores = error_keys.len() + 3 * modules.len();
            row.extend(std::iter::repeat_n(String::new(), scores));
            row.push(csv_field(r.backend.as_deref().unwrap_or("")));
            out += &(row.join(",") + "\n");
            continue;
        }
        row.extend(
            error_keys
                .iter()
                .map(|k| csv_number(r.errors.get(*k).copied())),
        );
        row.extend(r.sigma_p.iter().map(|v| csv_number(Some(*v))));
        row.extend(r.sigma_p_change.iter().map(|v| csv_number(Some(*v))));
        row.extend((0..4).map(|m| csv_number(r.map_means.map(|v| v[m]))));
        row.push(csv_field(r.backend.as_deref().unwrap_or("")));
        out += &(row.join(",") + "\n");
    }
    out
}

/// One row per training.
/// Each training's validity gate: the validation of the network used (`None`: the training
/// has no validation at that iteration, so nothing held out says what it learned).
/// How many finished jobs the report in `out_dir` was built from (0 where there is none).
fn jobs_done_in_report(out_dir: &Path) -> usize {
    std::fs::read_to_string(out_dir.join("summary.json"))
        .ok()
        .and_then(|text| serde_json::from_str::<Value>(&text).ok())
        .and_then(|summary| summary["jobs_done"].as_u64())
        .map_or(0, |n| n as usize)
}

fn network_gates(trains: &[TrainResult]) -> Vec<Option<Gate>> {
    trains.iter().map(TrainResult::gate).collect()
}

/// What a gate's log lacks, as `measure: name name; ...` (empty when complete).
fn not_recorded(gate: &Gate) -> String {
    gate.checks
        .iter()
        .filter(|c| !c.missing.is_empty())
        .map(|c| format!("{}: {}", c.measure, c.missing.join(" ")))
        .collect::<Vec<_>>()
        .join("; ")
}

fn trainings_csv(scale: &str, trains: &[TrainResult], gates: &[Option<Gate>], flat: f64) -> String {
    let mut out = String::from(
        "scale,job,network,training,sequences,iterations,final_free_energy,seconds,last_tenth_change,reused,backend,stop,network_iteration,converged,machines,held_out_vision,vision_baseline,vision_baseline_error,held_out_joints_next,joints_baseline_error,held_out_torques_next,torques_baseline_error,held_out_diverged,not_recorded,gate,gate_detail\n",
    );
    for (t, gate) in trains.iter().zip(gates) {
        let check = |measure: &str| {
            gate.as_ref()
                .and_then(|g| g.checks.iter().find(|c| c.measure == measure))
        };
        let model = |measure: &str| csv_number(check(measure).and_then(|c| c.model));
        let baseline = |measure: &str| {
            csv_number(
                check(measure)
                    .map(|c| c.baseline_error)
                    .filter(|e| e.is_finite()),
            )
        };
        let row = [
            csv_field(scale),
            csv_field(&t.job),
            t.network.to_string(),
            csv_field(&t.condition),
            t.sequences.to_string(),
            t.iterations.to_string(),
            csv_number(t.final_free_energy),
            csv_number(Some(t.seconds)),
            csv_number(t.last_tenth_change),
            csv_field(t.reused.as_deref().unwrap_or("")),
            csv_field(t.backend.as_deref().unwrap_or("")),
            t.stop.map_or(String::new(), |s| {
                serde_json::to_value(s)
                    .ok()
                    .and_then(|v| v.as_str().map(str::to_string))
                    .unwrap_or_default()
            }),
            t.network_iteration.map_or(String::new(), |n| n.to_string()),
            t.converged(flat).to_string(),
            csv_field(&t.machines.join("; then ")),
            model("vision"),
            csv_field(check("vision").map_or("", |c| c.baseline)),
            baseline("vision"),
            model("joints"),
            baseline("joints"),
            model("torques"),
            baseline("torques"),
            gate.as_ref()
                .map_or(String::new(), |g| g.failed_trials.to_string()),
            csv_field(&gate.as_ref().map_or(String::new(), not_recorded)),
            csv_field(gate.as_ref().map_or("not gated", |g| g.verdict.name())),
            csv_field(&gate.as_ref().map_or(
                "no held-out validation of the network used".into(),
                Gate::describe,
            )),
        ];
        out += &(row.join(",") + "\n");
    }
    out
}

fn module_names() -> Vec<String> {
    ModuleId::ALL.iter().map(|m| m.name().to_string()).collect()
}

/// The everything-observed runs (the hierarchy's maps and boundary analyses use only them).
fn everything_observed(x: &InferResult) -> bool {
    x.condition == Plan::condition_label(VISION_CONDITIONS[0].1, true)
}

/// The subtask names of `task` in the plan's dataset (when it is there to read), else
/// "subtask k".
fn subtask_names(plan: &Plan, task: &str, count: usize) -> Vec<String> {
    let names: Option<Vec<String>> =
        pvrnn_dataset::Dataset::open(&plan.dataset)
            .ok()
            .and_then(|d| {
                d.manifest
                    .sequences
                    .iter()
                    .find(|s| s.task == task)
                    .map(|s| s.subtasks.clone())
            });
    (0..count)
        .map(|k| {
            names
                .as_ref()
                .and_then(|n| n.get(k).cloned())
                .unwrap_or_else(|| format!("subtask {}", k + 1))
        })
        .collect()
}

fn hierarchy(plan: &Plan, r: &Results, out: &Path, stamp: &str, md: &mut String) -> Result<Value> {
    let mode = AblationMode::Readout;
    let observed: Vec<(InferResult, Option<Vec<Vec<f32>>>)> = r
        .infers
        .iter()
        .filter(|(x, _)| everything_observed(x))
        .cloned()
        .collect();
    let _ = writeln!(
        md,
        "## Contribution maps ({stamp})\n\nPer module: the mean |standard − ablated| reconstruction of the top-resolution images, with the module's z = 0 (`{}` ablation: inference runs as standard, then each step is read out again). Everything observed. Mean ± SE over networks (each the mean over test sequences of the mean over trials).\n",
        mode.name()
    );
    md.push_str("| module | mean contribution |\n|---|---|\n");
    let mut contributions = BTreeMap::new();
    for (m, name) in module_names().iter().enumerate() {
        let nets: Vec<f64> = per_network(&observed, &|_| true, &|x| x.map_means.map(|v| v[m]))
            .into_values()
            .collect();
        let _ = writeln!(md, "| {name} | {} |", mean_se_text(&nets));
        contributions.insert(name.clone(), nets);
    }
    // The maps: averaged over every result (a balanced design weighs networks equally).
    let maps: Vec<&Vec<Vec<f32>>> = observed.iter().filter_map(|(_, m)| m.as_ref()).collect();
    if let Some(first) = maps.first() {
        let width = first[0].len();
        let mut mean = vec![vec![0f64; width]; 4];
        for m in &maps {
            for (acc, v) in mean.iter_mut().zip(m.iter()) {
                for (a, b) in acc.iter_mut().zip(v) {
                    *a += *b as f64 / maps.len() as f64;
                }
            }
        }
        let path = out.join("contribution_maps.png");
        write_maps(&path, &mean)?;
        let _ = writeln!(
            md,
            "\n![contribution maps]({}): one row per module (executive, associative, exteroceptive, proprioceptive), left and right camera; brightness = mean |standard − ablated| per pixel, one scale for all.\n",
            path.file_name()
                .map_or(String::new(), |f| f.to_string_lossy().into_owned())
        );
    }
    let over_time = time_resolved(plan, r, out, stamp, md)?;
    // The executive module near subtask boundaries.
    let window = plan
        .design
        .inference_window
        .unwrap_or(ModelConfig::default().inference.window);
    let (per_net, observed_difference, p) = boundary_test(&observed, window, BOUNDARY_HALF_WIDTH);
    let _ = writeln!(
        md,
        "## Executive latent change near subtask boundaries ({stamp})\n\nMean |Δμ_q| of the executive module per step, within ±{BOUNDARY_HALF_WIDTH} steps of a subtask boundary minus elsewhere; per network, then over networks. Boundaries: the onset of the first subtask (step 0, as the paper counts it) and every change of subtask. Only steps t ≥ H = {window} count: before the inference window is full online inference warms up and the posterior moves more everywhere, which would confound the comparison (so the onset's own neighbourhood, inside the warm-up, drops out at H = {window}). Permutation test: each run's analysed series circularly shifted against its labels, {PERMUTATIONS} permutations, two-sided.\n"
    );
    let nets: Vec<f64> = per_net.values().copied().collect();
    let across = stats::difference(&nets, &vec![0.0; nets.len()], true);
    match observed_difference {
        Some(_) => {
            // Networks are the units the verdict is tested over; the permutation test
            // shuffles within runs, so it speaks for these networks only.
            let _ = writeln!(
                md,
                "Near − elsewhere: {} (over networks); across networks, two-sided one-sample t: p = {} (the verdict's test); within runs, permutation p = {}.\n",
                mean_se_text(&nets),
                p_text(across.as_ref().and_then(|d| d.p)),
                p_text(p)
            );
        }
        None => md.push_str(
            "No test run has a subtask boundary with steps on both sides: nothing to test.\n\n",
        ),
    }
    let matched = matched_boundary_test(&observed, md);
    let occlusion = occlusion_section(r, stamp, md);
    Ok(json!({
        "ablation_mode": mode.name(),
        "contribution_per_network": contributions,
        "contribution_over_time": over_time,
        "occlusion": occlusion,
        "executive_boundary": {
            "half_width": BOUNDARY_HALF_WIDTH,
            "from_step": window,
            "two_sided": true,
            "near_minus_elsewhere_per_network": per_net,
            "difference": across,
            "permutations": PERMUTATIONS,
            "p": p,
        },
        "executive_boundary_matched": matched,
    }))
}

/// The executive module's time constants, the paper's: the half-width of the matched
/// boundary test is the slower one.
fn executive_half_width() -> usize {
    let tau = ModelConfig::default().executive.tau;
    tau[0].max(tau[1]).round() as usize
}

/// The boundary test with the paper's reading of its figures (pre-specified 2026-12-06,
/// beside the one above): "near" spans the executive's slower time constant on either side
/// of a boundary, and the onset at step 0 is kept (every step from 1 counts, the warm-up
/// included, as in the paper's figures).
fn matched_boundary_test(
    observed: &[(InferResult, Option<Vec<Vec<f32>>>)],
    md: &mut String,
) -> Value {
    let half_width = executive_half_width();
    let (per_net, difference, p) = boundary_test(observed, 0, half_width);
    let nets: Vec<f64> = per_net.values().copied().collect();
    let across = stats::difference(&nets, &vec![0.0; nets.len()], true);
    if difference.is_some() {
        let _ = writeln!(
            md,
            "With a window matched to the executive's slower time constant (±{half_width} steps) and the onset kept (every step from 1, the warm-up included, as the paper's figures show it): near − elsewhere {} (over networks); across networks, two-sided one-sample t: p = {}; within runs, permutation p = {}.\n",
            mean_se_text(&nets),
            p_text(across.as_ref().and_then(|d| d.p)),
            p_text(p)
        );
    }
    json!({
        "half_width": half_width,
        "from_step": 1,
        "two_sided": true,
        "near_minus_elsewhere_per_network": per_net,
        "difference": across,
        "permutations": PERMUTATIONS,
        "p": p,
    })
}

/// Contribution per module and subtask phase (per task): a table of means ± SE over
/// networks and a labelled picture of the maps, averaged over trials and test sequences.
fn time_resolved(
    plan: &Plan,
    r: &Results,
    out: &Path,
    stamp: &str,
    md: &mut String,
) -> Result<Value> {
    let _ = writeln!(
        md,
        "## Contributions over time ({stamp})\n\nThe paper's claim is *when* each module contributes. Per subtask phase, the mean |standard − ablated| of the module's read-out (as above), averaged over the phase's steps, then trials and test sequences; mean ± SE over networks.\n"
    );
    let with_phases: Vec<&(InferResult, Option<Vec<Vec<f32>>>)> = r
        .infers
        .iter()
        .filter(|(x, _)| everything_observed(x) && x.phase_map_means.is_some())
        .collect();
    if with_phases.is_empty() {
        md.push_str(
            "Not recorded in these runs (results written before per-phase maps were kept).\n\n",
        );
        return Ok(Value::Null);
    }
    let mut summary = serde_json::Map::new();
    let tasks: std::collections::BTreeSet<&str> =
        with_phases.iter().map(|(x, _)| x.task.as_str()).collect();
    for task in tasks {
        let phases = with_phases
            .iter()
            .filter(|(x, _)| x.task == task)
            .filter_map(|(x, _)| x.phase_map_means.as_ref().map(Vec::len))
            .max()
            .unwrap_or(0);
        let names = subtask_names(plan, task, phases);
        let networks = per_network(
            &r.infers,
            &|x| x.task == task && x.phase_map_means.is_some(),
            &|_| Some(0.0),
        )
        .len();
        let _ = writeln!(
            md,
            "**{task}** ({networks} network{})\n\n| module | {} |\n|---|{}",
            if networks == 1 { "" } else { "s" },
            names.join(" | "),
            "---|".repeat(phases)
        );
        let mut rows = serde_json::Map::new();
        for (m, module) in module_names().iter().enumerate() {
            let mut cells = Vec::new();
            let mut values = Vec::new();
            for k in 0..phases {
                let nets: Vec<f64> = per_network(
                    &r.infers,
                    &|x| everything_observed(x) && x.task == task,
                    &|x| {
                        x.phase_map_means
                            .as_ref()
                            .and_then(|p| p.get(k).copied().flatten())
                            .map(|v| v[m])
                    },
                )
                .into_values()
                .collect();
                cells.push(mean_se_text(&nets));
                values.push(nets);
            }
            let _ = writeln!(md, "| {module} | {} |", cells.join(" | "));
            rows.insert(module.clone(), json!(values));
        }
        summary.insert(
            task.to_string(),
            json!({"phases": names, "per_network": rows}),
        );
        phase_picture(r, &with_phases, task, &names, out, stamp, md)?;
    }
    Ok(Value::Object(summary))
}

/// The per-phase picture of one task: per module (rows) and phase (columns), the maps of
/// the first camera averaged over the runs that have the phase.
fn phase_picture(
    r: &Results,
    with_phases: &[&(InferResult, Option<Vec<Vec<f32>>>)],
    task: &str,
    names: &[String],
    out: &Path,
    stamp: &str,
    md: &mut String,
) -> Result<()> {
    let phases = names.len();
    let mut sums: Vec<Vec<Vec<f64>>> = Vec::new();
    // Runs that have each phase (a run that ends early lacks the later ones).
    let mut per_phase = vec![0usize; phases];
    let mut count = 0usize;
    for (x, _) in with_phases.iter().filter(|(x, _)| x.task == task) {
        let path = r.paths.get(&x.job);
        let Some(maps) = path.and_then(|p| crate::run::read_phase_maps(p).ok().flatten()) else {
            continue;
        };
        if sums.is_empty() {
            sums = vec![vec![Vec::new(); phases]; 4];
        }
        for (k, phase) in maps.iter().enumerate().take(phases) {
            if x.phase_steps.get(k).copied().unwrap_or(0) == 0 {
                continue;
            }
            per_phase[k] += 1;
            for (m, map) in phase.iter().enumerate() {
                let acc = &mut sums[m][k];
                if acc.is_empty() {
                    *acc = vec![0.0; map.len()];
                }
                for (a, v) in acc.iter_mut().zip(map) {
                    *a += *v as f64;
                }
            }
        }
        count += 1;
    }
    if count > 0 {
        let pixels = sums.iter().flatten().map(Vec::len).max().unwrap_or(0);
        // The first camera: the map holds the cameras one after the other.
        let side = ((pixels / 2) as f64).sqrt() as usize;
        let cells: Vec<Vec<Vec<f64>>> = sums
            .iter()
            .map(|phases| {
                phases
                    .iter()
                    .zip(&per_phase)
                    .map(|(m, &runs)| {
                        m.iter()
                            .take(side * side)
                            .map(|v| v / runs.max(1) as f64)
                            .collect()
                    })
                    .collect()
            })
            .collect();
        let file = format!("contributions_over_time_{task}.png");
        pvrnn_eval::plots::labelled_maps(
            &out.join(&file),
            &format!(
                "{task}: contribution per module and subtask, camera 0 ({stamp}, {count} runs)"
            ),
            &module_names(),
            names,
            &cells,
            side,
        )?;
        let _ = writeln!(
            md,
            "\n![{task}: contributions over time]({file}): rows = modules, columns = subtask phases; brightness = mean |standard − ablated| per pixel, one scale for the picture.\n"
        );
    } else {
        md.push('\n');
    }
    Ok(())
}

/// Body parts the arms hide, scored against the robot-free renders relative to the
/// observed frame, for the reconstruction with everything observed, the reconstruction
/// from the 16x16 input, and the one-step prior prediction.
fn occlusion_section(r: &Results, stamp: &str, md: &mut String) -> Value {
    let _ = writeln!(
        md,
        "## Occlusion: what the model makes of hidden body parts ({stamp})\n"
    );
    if r.infers.iter().all(|(x, _)| x.occlusion.is_none()) {
        md.push_str(
            "The test sequences have no robot-free renders: simulate the dataset with `pvrnn simulate --robot-free` to score occlusion.\n\n",
        );
        return Value::Null;
    }
    let _ = writeln!(
        md,
        "On top-resolution pixels the arms hide (observed and robot-free image differ by more than {} in a channel, model units). The score is relative to the observed frame: d(model, body) − d(observed, body), MSE against the robot-free image; 0 = as far from the body as the camera's image (e.g. drawing the arm it sees), negative = more of the hidden body than the camera showed. Per network (mean over trials, then test sequences), then mean ± SE over networks; two-sided one-sample t-tests of the relative score against 0, with the 95% CI and the smallest difference the design detects (80% power).\n",
        crate::occlusion::HIDDEN_THRESHOLD
    );
    type Pick = fn(&OcclusionScores) -> Option<f64>;
    let sixteen = Plan::condition_label(VISION_CONDITIONS[2].1, true);
    let rows: [(&str, bool, Pick); 4] = [
        ("reconstruction, everything observed", true, |o| {
            o.model_relative()
        }),
        ("prior prediction, everything observed", true, |o| {
            o.prior_relative()
        }),
        (
            "reconstruction, 16x16 + proprioception observed",
            false,
            |o| o.model_relative(),
        ),
        (
            "prior prediction, 16x16 + proprioception observed",
            false,
            |o| o.prior_relative(),
        ),
    ];
    md.push_str("| scored | relative score (model − observed) | 95% CI | d_z | p | detectable |\n|---|---|---|---|---|---|\n");
    let mut tests = serde_json::Map::new();
    for (label, all, pick) in rows {
        let nets: Vec<f64> = per_network(
            &r.infers,
            &|x| {
                if all {
                    everything_observed(x)
                } else {
                    x.condition == sixteen
                }
            },
            &|x| x.occlusion.as_ref().and_then(pick),
        )
        .into_values()
        .collect();
        let diff = stats::difference(&nets, &vec![0.0; nets.len()], true);
        match &diff {
            Some(d) => {
                let _ = writeln!(
                    md,
                    "| {label} | {} | [{}, {}] | {} | {} | ±{} |",
                    mean_se_text(&nets),
                    sig(d.ci95[0]),
                    sig(d.ci95[1]),
                    sig(d.cohen_d),
                    p_text(d.p),
                    sig(d.detectable)
                );
            }
            None => {
                let _ = writeln!(
                    md,
                    "| {label} | {} | – (fewer than 2 networks) | | | |",
                    mean_se_text(&nets)
                );
            }
        }
        tests.insert(
            label.to_string(),
            json!({"per_network": nets, "difference": diff}),
        );
    }
    // The observation-only baselines, for scale.
    type Abs = fn(&OcclusionScores) -> f64;
    let absolute: [(&str, Abs); 5] = [
        ("model vs hidden body", |o| o.model),
        ("observed frame vs hidden body", |o| {
            o.observed.unwrap_or(f64::NAN)
        }),
        ("mean image vs hidden body", |o| o.mean_image),
        ("last seen vs hidden body", |o| o.last_seen),
        ("share of values hidden", |o| o.hidden_share),
    ];
    md.push_str("\nAbsolute errors on the hidden pixels, everything observed (mean ± SE over networks):\n\n| measure | mean ± SE |\n|---|---|\n");
    let mut absolute_json = serde_json::Map::new();
    for (label, pick) in absolute {
        let nets = per_network(&r.infers, &everything_observed, &|x| {
            x.occlusion.as_ref().map(pick)
        });
        let values: Vec<f64> = nets.values().copied().collect();
        let _ = writeln!(md, "| {label} | {} |", mean_se_text(&values));
        absolute_json.insert(label.to_string(), json!(nets));
    }
    md.push('\n');
    let against = against_observation_baselines(r, md);
    json!({
        "threshold": crate::occlusion::HIDDEN_THRESHOLD,
        "relative": tests,
        "absolute": absolute_json,
        "against_baselines": against,
    })
}

/// The model's reconstruction (everything observed) on the hidden pixels against each
/// observation-only baseline (pre-specified 2026-12-06): d(model, body) − d(baseline, body)
/// per network, two-sided one-sample t. Inferring the hidden body means beating what needs
/// no model: the mean learning image and each pixel's last unhidden observation.
fn against_observation_baselines(r: &Results, md: &mut String) -> Value {
    type Pick = fn(&OcclusionScores) -> f64;
    let baselines: [(&str, Pick); 2] = [
        ("mean image", |o| o.model - o.mean_image),
        ("last seen", |o| o.model - o.last_seen),
    ];
    md.push_str("Against the observation-only baselines (reconstruction, everything observed; d(model, body) − d(baseline, body), negative = the model closer to the hidden body):\n\n| baseline | model − baseline | 95% CI | d_z | p |\n|---|---|---|---|---|\n");
    let mut out = serde_json::Map::new();
    for (label, pick) in baselines {
        let nets: Vec<f64> = per_network(&r.infers, &everything_observed, &|x| {
            x.occlusion.as_ref().map(pick)
        })
        .into_values()
        .collect();
        let diff = stats::difference(&nets, &vec![0.0; nets.len()], true);
        let _ = match &diff {
            Some(d) => writeln!(
                md,
                "| {label} | {} | [{}, {}] | {} | {} |",
                mean_se_text(&nets),
                sig(d.ci95[0]),
                sig(d.ci95[1]),
                sig(d.cohen_d),
                p_text(d.p)
            ),
            None => writeln!(md, "| {label} | {} | – | | |", mean_se_text(&nets)),
        };
        out.insert(
            label.to_string(),
            json!({"per_network": nets, "difference": diff}),
        );
    }
    md.push('\n');
    Value::Object(out)
}

/// Writes the four modules' maps (rows) for each camera (columns) as one PNG.
fn write_maps(path: &Path, maps: &[Vec<f64>]) -> Result<()> {
    // Top-resolution layout: cameras x (r x r x 3).
    let per_pixel: Vec<Vec<f64>> = maps
        .iter()
        .map(|m| m.chunks(3).map(|c| c.iter().sum::<f64>() / 3.0).collect())
        .collect();
    let pixels = per_pixel[0].len();
    let (cameras, r) = [2usize, 1]
        .into_iter()
        .find_map(|c| {
            let side = ((pixels / c) as f64).sqrt().round() as usize;
            (side * side * c == pixels).then_some((c, side))
        })
        .unwrap_or((1, 1));
    let max = per_pixel
        .iter()
        .flatten()
        .fold(0.0f64, |a, b| a.max(*b))
        .max(1e-12);
    let scale = 3;
    let gap = 4;
    let width = cameras * (r * scale + gap);
    let height = 4 * (r * scale + gap);
    let mut rgb = vec![255u8; width * height * 3];
    for (m, map) in per_pixel.iter().enumerate() {
        for c in 0..cameras {
            for y in 0..r * scale {
                for x in 0..r * scale {
                    let v = map[c * r * r + (y / scale) * r + x / scale] / max;
                    // Brighter = more influence, as the paper's Figs 2B and 3B.
                    let level = (255.0 * v.clamp(0.0, 1.0)) as u8;
                    let px = c * (r * scale + gap) + x;
                    let py = m * (r * scale + gap) + y;
                    let i = (py * width + px) * 3;
                    rgb[i..i + 3].copy_from_slice(&[level, level, level]);
                }
            }
        }
    }
    write_png(path, width as u32, height as u32, rgb)?;
    Ok(())
}

/// Near-minus-elsewhere executive change per network, its mean over networks, and the
/// two-sided permutation p-value. Boundaries: the onset of the first subtask (step 0) and
/// every change of subtask label; "near" is within `half_width` steps of one. Only steps
/// `t >= window` count (at least step 1, the first change): before the inference window is
/// full, online inference is still warming up and the posterior moves more everywhere (the
/// onset's neighbourhood then lies in the warm-up and drops out; `window` 0 keeps it).
fn boundary_test(
    infers: &[(InferResult, Option<Vec<Vec<f32>>>)],
    window: usize,
    half_width: usize,
) -> (BTreeMap<usize, f64>, Option<f64>, Option<f64>) {
    // Per run: the analysed changes (step t >= max(window, 1); index t-1 of the series) and
    // their near-boundary mask.
    let runs: Vec<(&InferResult, Vec<f64>, Vec<bool>)> = infers
        .iter()
        .map(|(r, _)| {
            let steps = r.subtask.len();
            let boundaries: Vec<usize> = std::iter::once(0)
                .chain((1..steps).filter(|&t| r.subtask[t] != r.subtask[t - 1]))
                .collect();
            let first = window.max(1);
            let near = |t: usize| boundaries.iter().any(|&b| t.abs_diff(b) <= half_width);
            let values: Vec<f64> = (first..steps)
                .filter_map(|t| r.executive_change.get(t - 1).copied())
                .collect();
            let mask: Vec<bool> = (first..first + values.len()).map(near).collect();
            (r, values, mask)
        })
        .filter(|(r, values, mask)| {
            r.executive_change.len() + 1 == r.subtask.len()
                && mask.iter().any(|&m| m)
                && mask.iter().any(|&m| !m)
                && !values.is_empty()
        })
        .collect();
    if runs.is_empty() {
        return (BTreeMap::new(), None, None);
    }
    let statistic = |shift: &dyn Fn(usize) -> usize| -> (BTreeMap<usize, f64>, f64) {
        let mut by_seq: BTreeMap<(usize, String), Vec<f64>> = BTreeMap::new();
        for (i, (r, values, mask)) in runs.iter().enumerate() {
            let n = mask.len();
            let s = shift(i) % n;
            let (mut near, mut far) = (Vec::new(), Vec::new());
            for (t, v) in values.iter().enumerate() {
                if mask[(t + s) % n] {
                    near.push(*v)
                } else {
                    far.push(*v)
                }
            }
            by_seq
                .entry((r.network, r.sequence.clone()))
                .or_default()
                .push(mean_se(&near).0 - mean_se(&far).0);
        }
        let mut by_net: BTreeMap<usize, Vec<f64>> = BTreeMap::new();
        for ((net, _), v) in by_seq {
            by_net.entry(net).or_default().push(mean_se(&v).0);
        }
        let nets: BTreeMap<usize, f64> = by_net
            .into_iter()
            .map(|(n, v)| (n, mean_se(&v).0))
            .collect();
        let overall = mean_se(&nets.values().copied().collect::<Vec<_>>()).0;
        (nets, overall)
    };
    let (per_net, observed) = statistic(&|_| 0);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x5eed);
    let (mut above, mut below) = (0usize, 0usize);
    for _ in 0..PERMUTATIONS {
        let shifts: Vec<usize> = runs
            .iter()
            .map(|(_, _, m)| rng.random_range(1..m.len().max(2)))
            .collect();
        let permuted = statistic(&|i| shifts[i]).1;
        above += usize::from(permuted >= observed);
        below += usize::from(permuted <= observed);
    }
    // Two-sided: twice the smaller one-sided p (the shift null need not be symmetric).
    let one_sided = |k: usize| (1 + k) as f64 / (1 + PERMUTATIONS) as f64;
    let p = (2.0 * one_sided(above).min(one_sided(below))).min(1.0);
    (per_net, Some(observed), Some(p))
}

#[derive(Serialize)]
struct TaskComparison {
    module: String,
    measure: String,
    repositioning: Vec<f64>,
    wiping: Vec<f64>,
    paired_t: Option<stats::PairedT>,
    /// Repositioning − wiping with its 95% CI and the detectable difference.
    difference: Option<stats::Difference>,
    /// Prior sigma only: the equivalence test of "no difference between tasks".
    equivalence: Option<stats::Equivalence>,
}

/// The equivalence margin of a "no difference" claim, relative to the level compared:
/// Fig 4A's (±10% of the mean prior sigma of the two tasks, fixed before the converged runs) and
/// Fig 6A's (±10% of the none-added condition's mean error; the same rule, fixed on
/// 2026-11-29 before either interference direction was complete, docs/experiments.md).
pub const EQUIVALENCE_MARGIN: f64 = 0.10;

fn uncertainty(r: &Results, out: &Path, stamp: &str, md: &mut String) -> Result<Value> {
    let _ = writeln!(
        md,
        "## Prior uncertainty per module and task ({stamp})\n\nMean prior σ and mean |Δσ_p| between steps, everything observed; per network, then mean ± SE over networks; paired t-tests (repositioning vs wiping) across networks.\n"
    );
    md.push_str("| module | measure | repositioning | wiping | t | df | p | d_z |\n|---|---|---|---|---|---|---|---|\n");
    let mut comparisons = Vec::new();
    for (label, measure) in [
        ("prior sigma", 0),
        ("mean absolute change of prior sigma", 1),
    ] {
        let mut groups = Vec::new();
        // The four modules, then all of them (the paper's "All": every latent unit alike,
        // so modules weigh by their z units; the experiments train the default sizes).
        let units = ModuleId::ALL.map(|id| ModelConfig::default().module(id).z as f64);
        let mut names = module_names();
        names.push("all modules".into());
        for (m, name) in names.iter().enumerate() {
            let value = |x: &InferResult| {
                let v = if measure == 0 {
                    x.sigma_p
                } else {
                    x.sigma_p_change
                };
                if m < 4 {
                    v[m]
                } else {
                    v.iter().zip(&units).map(|(a, w)| a * w).sum::<f64>()
                        / units.iter().sum::<f64>()
                }
            };
            let of = |task: &'static str| {
                per_network(&r.infers, &|x| x.task == task, &|x| Some(value(x)))
            };
            let (a, b) = (of("repositioning"), of("wiping"));
            let paired: Vec<usize> = a.keys().filter(|k| b.contains_key(k)).copied().collect();
            let av: Vec<f64> = paired.iter().map(|k| a[k]).collect();
            let bv: Vec<f64> = paired.iter().map(|k| b[k]).collect();
            let t = stats::paired_t(&av, &bv);
            let level = (mean_se(&av).0 + mean_se(&bv).0) / 2.0;
            let equivalence = (measure == 0)
                .then(|| stats::equivalence(&av, &bv, EQUIVALENCE_MARGIN * level.abs(), true))
                .flatten();
            let _ = writeln!(
                md,
                "| {name} | {label} | {} | {} | {} | {} | {} | {} |",
                mean_se_text(&av),
                mean_se_text(&bv),
                t.as_ref().map_or("–".into(), |t| sig(t.t)),
                t.as_ref().map_or("–".into(), |t| t.df.to_string()),
                p_text(t.as_ref().and_then(|t| t.p)),
                t.as_ref().map_or("–".into(), |t| sig(t.cohen_dz)),
            );
            groups.push((
                name.clone(),
                vec![bar("repositioning", &av), bar("wiping", &bv)],
            ));
            let difference = stats::difference(&av, &bv, true);
            comparisons.push(TaskComparison {
                module: name.clone(),
                measure: label.into(),
                repositioning: av,
                difference,
                wiping: bv,
                paired_t: t,
                equivalence,
            });
        }
        let file = if measure == 0 {
            "sigma_p.png"
        } else {
            "sigma_p_change.png"
        };
        bar_chart(
            &out.join(file),
            &format!("{label} per module ({stamp})"),
            label,
            &["repositioning".into(), "wiping".into()],
            &groups,
        )?;
        let _ = writeln!(md, "\n![{label}]({file})\n");
        if measure == 0 {
            md.push_str("| module | measure | repositioning | wiping | t | df | p | d_z |\n|---|---|---|---|---|---|---|---|\n");
        }
    }
    let _ = writeln!(
        md,
        "### Is there no difference between the tasks? (Fig 4A, equivalence)\n\nThe paper reads a non-significant t-test as \"no difference\"; here that claim is tested as an equivalence: two one-sided tests (TOST) of repositioning − wiping against a margin of ±{:.0}% of the two tasks' mean prior σ, fixed before the converged runs (the reduced-scale results were re-analysed with it afterwards). Equivalent when the 90% CI lies inside the margin (p < 0.05).\n\n| module | difference | 90% CI | margin | TOST p | equivalent |\n|---|---|---|---|---|---|",
        EQUIVALENCE_MARGIN * 100.0
    );
    for c in comparisons.iter().filter(|c| c.measure == "prior sigma") {
        match &c.equivalence {
            Some(e) => {
                let _ = writeln!(
                    md,
                    "| {} | {} | [{}, {}] | ±{} | {} | {} |",
                    c.module,
                    sig(e.mean),
                    sig(e.ci90[0]),
                    sig(e.ci90[1]),
                    sig(e.margin),
                    p_text(e.p),
                    if e.equivalent { "yes" } else { "not shown" }
                );
            }
            None => {
                let _ = writeln!(md, "| {} | – (fewer than 2 networks) | | | | |", c.module);
            }
        }
    }
    md.push('\n');
    Ok(json!({ "comparisons": comparisons, "equivalence_margin": EQUIVALENCE_MARGIN }))
}

fn robustness(r: &Results, out: &Path, stamp: &str, md: &mut String) -> Result<Value> {
    let top = r
        .infers
        .first()
        .and_then(|(x, _)| {
            x.errors
                .keys()
                .filter_map(|k| k.strip_prefix("vision")?.parse::<usize>().ok())
                .max()
        })
        .unwrap_or(64);
    let key = format!("vision{top}");
    let _ = writeln!(
        md,
        "## Reconstruction error of the {top}x{top} images under degraded input ({stamp})\n\nMSE (model units) of the posterior reconstruction of the full-resolution images, observed or not; per network, then mean ± SE over networks. The accuracy term divides each modality's error by its *observed* dimensions (the spec's default; configuration field `accuracy_normalisation`).\n"
    );
    let vision: Vec<String> = VISION_CONDITIONS.iter().map(|c| c.0.to_string()).collect();
    let proprio = ["on".to_string(), "off".to_string()];
    let mut cells: Vec<Vec<BTreeMap<usize, f64>>> = Vec::new();
    md.push_str("| vision | proprio on | proprio off |\n|---|---|---|\n");
    let mut groups = Vec::new();
    for (label, levels) in VISION_CONDITIONS {
        let mut row = Vec::new();
        let mut bars = Vec::new();
        for p in [true, false] {
            let nets = per_network(
                &r.infers,
                &|x| x.condition == Plan::condition_label(levels, p),
                &|x| x.errors.get(&key).copied(),
            );
            bars.push(bar(
                if p { "proprio on" } else { "proprio off" },
                &nets.values().copied().collect::<Vec<_>>(),
            ));
            row.push(nets);
        }
        let _ = writeln!(
            md,
            "| {label} | {} | {} |",
            mean_se_text(&row[0].values().copied().collect::<Vec<_>>()),
            mean_se_text(&row[1].values().copied().collect::<Vec<_>>())
        );
        groups.push((format!("vision {label}"), bars));
        cells.push(row);
    }
    bar_chart(
        &out.join("robustness.png"),
        &format!("{top}x{top} reconstruction error ({stamp})"),
        "MSE",
        &["proprio on".into(), "proprio off".into()],
        &groups,
    )?;
    md.push_str("\n![robustness](robustness.png)\n\n");
    // Networks with every cell.
    let networks: Vec<usize> = cells[0][0]
        .keys()
        .filter(|n| {
            cells
                .iter()
                .all(|row| row.iter().all(|c| c.contains_key(n)))
        })
        .copied()
        .collect();
    let design = Blocked2 {
        y: networks
            .iter()
            .map(|n| {
                cells
                    .iter()
                    .map(|row| row.iter().map(|c| c[n]).collect())
                    .collect()
            })
            .collect(),
        a_levels: vision.clone(),
        b_levels: proprio.iter().map(|p| format!("proprio {p}")).collect(),
    };
    let art = stats::art_two_way(&design);
    match &art {
        Some(a) => {
            let _ = writeln!(
                md,
                "### Two-way ART ANOVA (vision × proprioception, network as block, {} networks)\n",
                a.blocks
            );
            let mut effects = a.effects.clone();
            for (e, name) in
                effects
                    .iter_mut()
                    .zip(["vision", "proprioception", "vision × proprioception"])
            {
                e.effect = name.into();
            }
            effects_table(md, &effects);
            md.push_str("\n### ART-C contrasts (Holm within each family)\n\nRaw difference: over networks, paired (each network's mean of the level or cell), with its 95% CI.\n\nVision levels:\n\n");
            contrasts_table(md, &a.a_contrasts);
            md.push_str("\nCells:\n\n");
            contrasts_table(md, &a.cell_contrasts);
            md.push('\n');
        }
        None => md.push_str("Too few complete networks (at least 2) for the ANOVA.\n\n"),
    }
    Ok(json!({
        "error": key,
        "accuracy_normalisation": "observed",
        "cells": cells,
        "art": art,
    }))
}

/// Dimensions per vision resolution (keyed as the run's errors are) and in all, with
/// proprioception: the paper's pooled error is the mean over all sensory dimensions.
fn sensory_dimensions() -> (Vec<(String, f64)>, f64) {
    let config = ModelConfig::default();
    let layout = &config.vision;
    let vision: Vec<(String, f64)> = (0..layout.resolutions.len())
        .map(|l| {
            (
                format!("vision{}", layout.resolutions[l]),
                (layout.level_offset(l + 1) - layout.level_offset(l)) as f64,
            )
        })
        .collect();
    let all = vision.iter().map(|(_, d)| d).sum::<f64>() + config.proprio_dims as f64;
    (vision, all)
}

/// The paper's pooled error of a run: its squared errors averaged over every sensory
/// dimension (every vision resolution and proprioception).
fn pooled_error(x: &InferResult) -> Option<f64> {
    let (vision, all) = sensory_dimensions();
    let proprio_dims = ModelConfig::default().proprio_dims as f64;
    let mut sum = x.errors.get("proprio")? * proprio_dims;
    for (key, dims) in &vision {
        sum += x.errors.get(key)? * dims;
    }
    Some(sum / all)
}

/// The table of the difference most added − none per measure (independent networks),
/// with its 95% CI and the detectable difference, and the equivalence test of "no change"
/// (Fig 6A) against ±`EQUIVALENCE_MARGIN` of the none condition's mean; both as JSON.
fn most_minus_none(
    names: &[&str],
    per_measure: &[Vec<Vec<f64>>],
    md: &mut String,
) -> (
    serde_json::Map<String, Value>,
    serde_json::Map<String, Value>,
) {
    let mut differences = serde_json::Map::new();
    let mut equivalences = serde_json::Map::new();
    md.push_str(
        "| measure | most added − none | 95% CI | d | detectable | equivalence margin | 90% CI | TOST p | equivalent |\n|---|---|---|---|---|---|---|---|---|\n",
    );
    for (name, groups) in names.iter().zip(per_measure) {
        let (d, e) = match (groups.first(), groups.last()) {
            (Some(none), Some(most)) if groups.len() > 1 => (
                stats::difference(most, none, false),
                stats::equivalence(
                    most,
                    none,
                    EQUIVALENCE_MARGIN * mean_se(none).0.abs(),
                    false,
                ),
            ),
            _ => (None, None),
        };
        let equivalence_cells = e.as_ref().map_or("| | | |".to_string(), |e| {
            format!(
                "±{} | [{}, {}] | {} | {} |",
                sig(e.margin),
                sig(e.ci90[0]),
                sig(e.ci90[1]),
                p_text(e.p),
                if e.equivalent { "yes" } else { "no" }
            )
        });
        match &d {
            Some(d) => {
                let _ = writeln!(
                    md,
                    "| {name} | {} | [{}, {}] | {} | ±{} | {equivalence_cells}",
                    sig(d.mean),
                    sig(d.ci95[0]),
                    sig(d.ci95[1]),
                    sig(d.cohen_d),
                    sig(d.detectable)
                );
            }
            None => {
                let _ = writeln!(md, "| {name} | – | | | | {equivalence_cells}");
            }
        }
        differences.insert(name.to_string(), json!(d));
        equivalences.insert(name.to_string(), json!(e));
    }
    (differences, equivalences)
}

/// The primary task of an interference training condition or of a job that reads one
/// (`repositioning 9 + wiping 3` → `repositioning`).
fn primary_of<'a>(plan: &'a Plan, job: &crate::plan::Job) -> Option<&'a str> {
    let condition = match &job.kind {
        JobKind::Train { condition, .. } => condition,
        JobKind::Infer { training, .. } => training,
    };
    plan.design
        .primary_tasks
        .iter()
        .find(|p| condition.starts_with(p.as_str()))
        .map(String::as_str)
}

/// The jobs of one direction of the interference experiment: its trainings and their
/// inference runs.
fn direction_jobs(plan: &Plan, primary: &str) -> Vec<usize> {
    plan.jobs
        .iter()
        .filter(|j| primary_of(plan, j) == Some(primary))
        .map(|j| j.id)
        .collect()
}

/// The network job `id` belongs to, once its training and every inference run of it are
/// done: its name (`network 2 (wiping 9 + repositioning 6)`). The runner asks after each
/// job it finishes and rebuilds the report when one is named, so that a long campaign's
/// report always holds what is done.
pub fn network_completed_by(plan: &Plan, dir: &Path, id: usize) -> Option<String> {
    let train = match &plan.jobs.get(id)?.kind {
        JobKind::Train { .. } => id,
        JobKind::Infer { train_job, .. } => *train_job,
    };
    let JobKind::Train {
        network, condition, ..
    } = &plan.jobs.get(train)?.kind
    else {
        return None;
    };
    let runs = plan
        .jobs
        .iter()
        .filter(|j| matches!(j.kind, JobKind::Infer { train_job, .. } if train_job == train));
    (plan.is_done(dir, train) && runs.into_iter().all(|j| plan.is_done(dir, j.id)))
        .then(|| format!("network {network} ({condition})"))
}

/// The part of the design job `id` belongs to whose analysis runs before the whole plan
/// is done (an interference direction of a two-direction plan), once every training and
/// inference run of it is done: its name (`the repositioning direction`). The runner asks
/// after each job it finishes and rebuilds the report when a part is named.
pub fn completed_by(plan: &Plan, dir: &Path, id: usize) -> Option<String> {
    if plan.experiment != Experiment::Interference || plan.design.primary_tasks.len() < 2 {
        return None;
    }
    let primary = primary_of(plan, plan.jobs.get(id)?)?;
    direction_jobs(plan, primary)
        .iter()
        .all(|&j| plan.is_done(dir, j))
        .then(|| format!("the {primary} direction"))
}

/// A direction's conditions in plan order, and how many networks each plans (the
/// design, not what is done so far).
fn planned_conditions(plan: &Plan, primary: &str) -> (Vec<String>, BTreeMap<String, usize>) {
    let mut conditions: Vec<String> = Vec::new();
    let mut planned: BTreeMap<String, usize> = BTreeMap::new();
    for job in &plan.jobs {
        if let JobKind::Train { condition, .. } = &job.kind
            && primary_of(plan, job) == Some(primary)
        {
            if !conditions.contains(condition) {
                conditions.push(condition.clone());
            }
            *planned.entry(condition.clone()).or_default() += 1;
        }
    }
    (conditions, planned)
}

/// A complete direction's tests, per measure: most added − none with the equivalence
/// test, and the one-way ART ANOVA with its contrasts; into the report and `direction`.
fn direction_tests(
    names: &[&str],
    conditions: &[String],
    per_measure: &[Vec<Vec<f64>>],
    direction: &mut Value,
    md: &mut String,
) -> Result<()> {
    let mut tests = serde_json::Map::new();
    let (differences, equivalences) = most_minus_none(names, per_measure, md);
    md.push('\n');
    for (name, groups) in names.iter().zip(per_measure) {
        match stats::art_one_way(conditions, groups) {
            Some(a) => {
                let _ = writeln!(md, "{name}:\n");
                effects_table(md, std::slice::from_ref(&a.effect));
                md.push('\n');
                contrasts_table(md, &a.contrasts);
                md.push('\n');
                tests.insert(name.to_string(), serde_json::to_value(&a)?);
            }
            None => {
                let _ = writeln!(
                    md,
                    "{name}: too few networks per condition for the ANOVA.\n"
                );
            }
        }
    }
    direction["art"] = Value::Object(tests);
    direction["most_minus_none"] = Value::Object(differences);
    direction["equivalence"] = Value::Object(equivalences);
    Ok(())
}

fn interference(
    plan: &Plan,
    r: &Results,
    out: &Path,
    stamp: &str,
    md: &mut String,
) -> Result<Value> {
    let top = ModelConfig::default()
        .vision
        .resolutions
        .last()
        .copied()
        .unwrap_or(64);
    let all_dims = sensory_dimensions().1;
    let pooled = pooled_error;
    type Measure<'a> = (&'a str, &'a dyn Fn(&InferResult) -> Option<f64>);
    // Pre-specified: the paper's pooled error first (the test the findings read), then
    // each modality and the equal-weight mean beside it.
    let measures: [Measure<'_>; 4] = [
        ("pooled", &pooled),
        ("vision", &|x| {
            x.errors.get(&format!("vision{top}")).copied()
        }),
        ("proprioception", &|x| x.errors.get("proprio").copied()),
        ("equal weight", &|x| {
            Some((x.errors.get(&format!("vision{top}"))? + x.errors.get("proprio")?) / 2.0)
        }),
    ];
    let _ = writeln!(
        md,
        "## Multitask interference ({stamp})\n\nEach primary task's 9 learning sequences plus 0 / 3 / 6 / 9 of the other task's (3 = one per bed height, 6 = two), one normalisation for all; errors of the primary task's test sequences (reconstruction MSE, everything observed). Measures, named before the converged runs (the reduced-scale results were re-analysed with them afterwards): **pooled** = the paper's, the mean squared error over all {all_dims} sensory dimensions (every vision resolution and proprioception; vision dominates by dimension count); beside it vision (the {top}x{top} images), proprioception, and the equal-weight mean of the two. Per network, mean ± SE over networks; one-way ART ANOVA over the conditions (independent groups, as the paper's one-way ANOVA: each condition's network k starts from seed k but learns other data, and the pre-specified analysis does not pair networks by seed, which is conservative if same-seed networks err alike), Holm-corrected ART-C contrasts, Cohen's d and the raw difference with its 95% CI; the difference most added − none with its 95% CI and the smallest difference the design detects (80% power, two-sided t-test from the observed variance); and \"no change\" (Fig 6A) tested as equivalence of most added and none: two one-sided tests against ±{:.0}% of the none condition's mean, equivalent when the 90% CI lies inside. A direction is tested only when every training and inference run of its plan is done.\n",
        EQUIVALENCE_MARGIN * 100.0
    );
    let mut json_out = serde_json::Map::new();
    for primary in &plan.design.primary_tasks {
        let (conditions, planned) = planned_conditions(plan, primary);
        let jobs = direction_jobs(plan, primary);
        let jobs_done = jobs.iter().filter(|&&j| plan.is_done(&r.dir, j)).count();
        let complete = !jobs.is_empty() && jobs_done == jobs.len();
        let trainings_done = r
            .trains
            .iter()
            .filter(|t| t.condition.starts_with(primary.as_str()))
            .count();
        let trainings_planned: usize = planned.values().sum();
        let _ = writeln!(md, "### Primary task: {primary}\n");
        if !complete {
            let _ = writeln!(
                md,
                "**No test yet**: {trainings_done} of this direction's {trainings_planned} trainings and {jobs_done} of its {} jobs are done. The tests run on the complete design only; the means below are descriptive.\n",
                jobs.len()
            );
        }
        md.push_str("| training | networks | pooled | vision | proprioception | equal weight |\n|---|---|---|---|---|---|\n");
        let mut per_measure: Vec<Vec<Vec<f64>>> = vec![Vec::new(); measures.len()];
        for c in &conditions {
            let done = r.trains.iter().filter(|t| &t.condition == c).count();
            let mut row = format!("| {c} | {done} of {} |", planned[c]);
            for (k, (_, f)) in measures.iter().enumerate() {
                let nets: Vec<f64> = per_network(&r.infers, &|x| &x.training == c, *f)
                    .into_values()
                    .collect();
                let _ = write!(row, " {} |", mean_se_text(&nets));
                per_measure[k].push(nets);
            }
            md.push_str(&row);
            md.push('\n');
        }
        let groups: Vec<(String, Vec<Bar>)> = measures
            .iter()
            .enumerate()
            .map(|(k, (name, _))| {
                (
                    name.to_string(),
                    conditions
                        .iter()
                        .zip(&per_measure[k])
                        .map(|(c, v)| bar(c, v))
                        .collect(),
                )
            })
            .collect();
        let file = format!("interference_{primary}.png");
        let title = if complete {
            format!("{primary}: error by training condition ({stamp})")
        } else {
            format!(
                "{primary}: error by training condition ({stamp}; {trainings_done} of {trainings_planned} trainings, no test yet)"
            )
        };
        bar_chart(&out.join(&file), &title, "MSE", &conditions, &groups)?;
        let _ = writeln!(md, "\n![{primary}]({file})\n");
        let mut direction = json!({
            "conditions": conditions,
            "measures": measures.iter().map(|(n, _)| *n).collect::<Vec<_>>(),
            "per_network": per_measure,
            "complete": complete,
            "trainings_done": trainings_done,
            "trainings_planned": trainings_planned,
            "jobs_done": jobs_done,
            "jobs_planned": jobs.len(),
        });
        if complete {
            let names: Vec<&str> = measures.iter().map(|(n, _)| *n).collect();
            direction_tests(&names, &conditions, &per_measure, &mut direction, md)?;
        }
        json_out.insert(primary.clone(), direction);
    }
    if let Some(asymmetry) = asymmetry(&plan.design.primary_tasks, &json_out, md) {
        json_out.insert(crate::paper::ASYMMETRY.into(), asymmetry);
    }
    Ok(Value::Object(json_out))
}

/// The asymmetry of the two directions (pre-specified 2026-11-30, before the second
/// direction's first training): whether the most added data changes the second primary
/// task's error by a different factor than the first's, per measure
/// ([`stats::relative_change_difference`] of none → most added); once both directions are
/// complete.
fn asymmetry(
    primaries: &[String],
    directions: &serde_json::Map<String, Value>,
    md: &mut String,
) -> Option<Value> {
    let [first, second] = primaries else {
        return None;
    };
    let (a, b) = (directions.get(first)?, directions.get(second)?);
    if a["complete"] != true || b["complete"] != true {
        return None;
    }
    // A direction's none and most-added groups of measure k.
    let ends = |d: &Value, k: usize| -> Option<[Vec<f64>; 2]> {
        let groups = d["per_network"][k].as_array()?;
        let values = |g: &Value| -> Vec<f64> {
            g.as_array()
                .map_or(Vec::new(), |v| v.iter().filter_map(Value::as_f64).collect())
        };
        Some([values(groups.first()?), values(groups.last()?)])
    };
    let _ = writeln!(
        md,
        "### Asymmetry: does the other task's data change {second}'s error by a different factor than {first}'s?

Pre-specified on 2026-11-30, before the converged campaign's second direction began (docs/experiments.md): each direction's change from none to the most added is the ratio of the two conditions' geometric-mean errors; the test is Welch's t of the difference of the log ratios ({second}'s − {first}'s; two-sided, 95% CI, and the smallest difference the design detects with 80% power). The paper's asymmetry (Fig 6: wiping's error rises with repositioning data added, repositioning's does not change with wiping data added) is wiping's log ratio above repositioning's.

| measure | {first}: change | {second}: change | difference of log ratios [95% CI] | t | df | p | detectable |\n|---|---|---|---|---|---|---|---|"
    );
    let mut tests = serde_json::Map::new();
    let names = a["measures"].as_array()?;
    for (k, name) in names.iter().enumerate() {
        let name = name.as_str()?;
        let ([a0, a1], [b0, b1]) = (ends(a, k)?, ends(b, k)?);
        let test = stats::relative_change_difference([&a0, &a1], [&b0, &b1]);
        match &test {
            Some(t) => {
                let _ = writeln!(
                    md,
                    "| {name} | {:+.1}% | {:+.1}% | {} [{}, {}] | {:.2} | {:.1} | {} | ±{} |",
                    100.0 * t.change[0],
                    100.0 * t.change[1],
                    sig(t.difference),
                    sig(t.ci95[0]),
                    sig(t.ci95[1]),
                    t.t,
                    t.df,
                    p_text(t.p),
                    sig(t.detectable)
                );
            }
            None => {
                let _ = writeln!(md, "| {name} | – | – | – | | | | |");
            }
        }
        tests.insert(name.to_string(), json!(test));
    }
    md.push('\n');
    Some(json!({"first": first, "second": second, "measures": tests}))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run_with(
        network: usize,
        sequence: &str,
        near_bump: f64,
    ) -> (InferResult, Option<Vec<Vec<f32>>>) {
        let steps = 60;
        let subtask: Vec<u32> = (0..steps).map(|t| (t / 20) as u32).collect();
        let executive_change = (1..steps)
            .map(|t: usize| {
                let near = [20usize, 40]
                    .iter()
                    .any(|b| t.abs_diff(*b) <= BOUNDARY_HALF_WIDTH);
                0.1 + 0.01 * ((t * 7919) % 13) as f64 + if near { near_bump } else { 0.0 }
            })
            .collect();
        (
            InferResult {
                job: String::new(),
                network,
                training: "all 18".into(),
                sequence: sequence.into(),
                task: "wiping".into(),
                trial: 0,
                condition: String::new(),
                steps,
                errors: BTreeMap::new(),
                sigma_p: [1.0; 4],
                sigma_p_change: [0.0; 4],
                executive_change,
                subtask,
                map_means: None,
                phase_steps: Vec::new(),
                phase_map_means: None,
                occlusion: None,
                diverged: None,
                backend: None,
            },
            None,
        )
    }

    #[test]
    fn the_matched_boundary_test_spans_the_executives_slower_time_constant_and_keeps_the_onset() {
        assert_eq!(
            executive_half_width(),
            16,
            "the paper's executive tau 8 and 16"
        );
        // A change that lasts 10 steps after each boundary, the onset's included: the
        // matched window (±16 from step 1) holds all of it, ±3 from t >= 10 a little.
        let runs: Vec<_> = (0..3)
            .flat_map(|n| [run_with(n, "a", 0.0), run_with(n, "b", 0.0)])
            .map(|(mut r, m)| {
                for (i, v) in r.executive_change.iter_mut().enumerate() {
                    let t = i + 1;
                    if [0usize, 20, 40].iter().any(|&b| t >= b && t < b + 10) {
                        *v += 0.2;
                    }
                }
                (r, m)
            })
            .collect();
        let (_, narrow, _) = boundary_test(&runs, 10, BOUNDARY_HALF_WIDTH);
        let mut md = String::new();
        let matched = matched_boundary_test(&runs, &mut md);
        assert_eq!(
            (
                matched["half_width"].as_u64(),
                matched["from_step"].as_u64()
            ),
            (Some(16), Some(1))
        );
        let wide = mean_se(
            &matched["near_minus_elsewhere_per_network"]
                .as_object()
                .unwrap()
                .values()
                .map(|v| v.as_f64().unwrap())
                .collect::<Vec<_>>(),
        )
        .0;
        assert!(
            wide > 0.05 && narrow.unwrap() < wide,
            "{wide} vs {narrow:?}"
        );
        assert!(md.contains("±16 steps"), "{md}");
    }

    #[test]
    fn boundary_test_detects_change_at_subtask_boundaries_only_when_there_is_some() {
        let bumped: Vec<_> = (0..3)
            .flat_map(|n| [run_with(n, "a", 0.2), run_with(n, "b", 0.2)])
            .collect();
        let (per_net, observed, p) = boundary_test(&bumped, 10, BOUNDARY_HALF_WIDTH);
        assert_eq!(per_net.len(), 3);
        assert!((observed.unwrap() - 0.2).abs() < 0.05, "{observed:?}");
        assert!(p.unwrap() < 0.01, "{p:?}");
        let flat: Vec<_> = (0..3)
            .flat_map(|n| [run_with(n, "a", 0.0), run_with(n, "b", 0.0)])
            .collect();
        let (_, _, p) = boundary_test(&flat, 10, BOUNDARY_HALF_WIDTH);
        assert!(p.unwrap() > 0.05, "{p:?}");
        // A warm-up (large changes before the window is full) is left out; counted, it
        // moves the statistic (the old test's confound).
        let warm: Vec<_> = flat
            .iter()
            .map(|(r, m)| {
                let mut r = r.clone();
                for v in &mut r.executive_change[..9] {
                    *v += 1.0;
                }
                (r, m.clone())
            })
            .collect();
        let (_, with_warm_up, _) = boundary_test(&warm, 10, BOUNDARY_HALF_WIDTH);
        let (_, without, _) = boundary_test(&flat, 10, BOUNDARY_HALF_WIDTH);
        assert_eq!(with_warm_up, without);
        let (_, counted, _) = boundary_test(&warm, 0, BOUNDARY_HALF_WIDTH);
        let (_, flat_all, _) = boundary_test(&flat, 0, BOUNDARY_HALF_WIDTH);
        assert!(
            (counted.unwrap() - flat_all.unwrap()).abs() > 0.01,
            "{counted:?}"
        );
    }
}
