//! The report's tidy tables: `trials.csv` (one row per inference run) and `trainings.csv`
//! (one row per training, with the validity gate on the network used).

use std::path::Path;

use pvrnn_eval::gate::Gate;
use serde_json::Value;

use super::module_names;
use crate::run::{InferResult, TrainResult};

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
pub(super) fn trials_csv(scale: &str, runs: &[&InferResult]) -> String {
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
pub(super) fn jobs_done_in_report(out_dir: &Path) -> usize {
    std::fs::read_to_string(out_dir.join("summary.json"))
        .ok()
        .and_then(|text| serde_json::from_str::<Value>(&text).ok())
        .and_then(|summary| summary["jobs_done"].as_u64())
        .map_or(0, |n| n as usize)
}

pub(super) fn network_gates(trains: &[TrainResult]) -> Vec<Option<Gate>> {
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

pub(super) fn trainings_csv(
    scale: &str,
    trains: &[TrainResult],
    gates: &[Option<Gate>],
    flat: f64,
) -> String {
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
