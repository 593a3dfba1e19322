//! Reports rebuilt from the result files alone: per trial -> per network (mean over trials,
//! then over test sequences) -> mean ± SE over networks, the paper's statistics, figures.
//! The scale is stamped on every table and figure title.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Result;
use pvrnn_core::ModuleId;
use pvrnn_eval::gate::Gate;
use pvrnn_eval::plots::Bar;
use pvrnn_eval::report::sig;
use serde_json::json;

use crate::plan::{Experiment, JobKind, Plan, VISION_CONDITIONS};
use crate::run::{InferResult, Stop, TrainResult, read_infer_result, read_train_result};
use crate::stats::{self, Contrast, Effect, mean_se};

mod hierarchy;
mod interference;
mod robustness;
mod tables;
mod uncertainty;

use hierarchy::hierarchy;
use interference::interference;
pub use interference::{completed_by, network_completed_by};
use robustness::robustness;
use tables::{jobs_done_in_report, network_gates, trainings_csv, trials_csv};
pub use uncertainty::EQUIVALENCE_MARGIN;
use uncertainty::uncertainty;

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
        interval: None,
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

fn module_names() -> Vec<String> {
    ModuleId::ALL.iter().map(|m| m.name().to_string()).collect()
}

/// The everything-observed runs (the hierarchy's maps and boundary analyses use only them).
fn everything_observed(x: &InferResult) -> bool {
    x.condition == Plan::condition_label(VISION_CONDITIONS[0].1, true)
}
