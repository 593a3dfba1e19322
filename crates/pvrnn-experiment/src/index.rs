//! The results' index (`docs/results/index.md`), generated from the result files alone:
//! every experiment folder (its `plan.json`, `results/train-*.json` and
//! `report/summary.json`) with its scale, data, jobs, trainings and the validity gate, the
//! readings of its findings, and every training's validation log (`*.validation.csv`).
//! Nothing in it is typed by hand, so it cannot drift from the files; a test regenerates
//! the committed index and compares.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use pvrnn_eval::gate::{Gate, GateVerdict};
use pvrnn_eval::report::sig;
use pvrnn_eval::validation;
use serde_json::Value;

use crate::plan::{JobKind, Plan};
use crate::run::{TrainResult, read_train_result};

/// The index of every experiment folder and validation log under `root`, as markdown; paths
/// are written relative to `root` (the index lives there).
pub fn index(root: &Path) -> Result<String> {
    let mut plans = Vec::new();
    let mut logs = Vec::new();
    walk(root, &mut plans, &mut logs)?;
    let mut md = String::from(
        "# The results: an index\n\n\
         Generated from the result files by `pvrnn report index docs/results --out \
         docs/results/index.md`, never edited by hand (a test regenerates it and compares). \
         What the results mean: [experiments.md](experiments.md) (the paper's experiments) \
         and [README.md](README.md) (the shipped model's quality). A network's gate \
         (docs/experiments.md, \"The validity gate\") is read from its held-out validation \
         at the iteration used: `pass`, `fail`, `incomplete` (a baseline it needs was not \
         recorded) or `not gated` (no held-out validation). Errors are mean squared errors \
         in model units on the held-out data (caresim seed 1 where the data is caresim).\n\n\
         ## Experiments\n\n\
         | folder | experiment | scale | data | jobs done | trainings | gate: pass / fail / incomplete (vision passes) | findings: agree / disagree / undecided / not testable |\n\
         |---|---|---|---|---|---|---|---|\n",
    );
    let mut experiments = Vec::new();
    for dir in &plans {
        experiments.push(Folder::read(dir)?);
    }
    for (dir, e) in plans.iter().zip(&experiments) {
        let name = relative(root, dir);
        let _ = writeln!(
            md,
            "| [{name}]({name}/report/report.md) | {} | {} | {} | {} | {} | {} | {} |",
            e.plan.experiment.name(),
            e.plan.scale.name(),
            cell(&e.plan.dataset_source),
            e.jobs_done(),
            e.trains.len(),
            e.gate_counts(),
            e.reading_counts(),
        );
    }
    for (dir, e) in plans.iter().zip(&experiments) {
        let _ = write!(md, "\n## {}\n\n", relative(root, dir));
        e.trainings_table(&mut md);
        e.findings_table(&mut md);
    }
    md.push_str(
        "\n## Validation logs of trainings outside the experiments\n\n\
         Each `pvrnn train --validate` log: its best validation (the network kept) and the \
         gate on it.\n\n\
         | log | validations | last iteration | best at | held-out vision (strongest baseline) | gate |\n\
         |---|---|---|---|---|---|\n",
    );
    for path in &logs {
        let rows = validation::read_log(path)?;
        let Some(best) = validation::best(&rows) else {
            continue;
        };
        let gate = Gate::of(best);
        let _ = writeln!(
            md,
            "| [{name}]({name}) | {} | {} | {} | {} | {} |",
            rows.len(),
            rows.last().map_or(0, |r| r.iteration),
            best.iteration,
            vision_against_baseline(&gate),
            gate.verdict.name(),
            name = relative(root, path),
        );
    }
    Ok(md)
}

/// Experiment folders (holding `plan.json`) and validation logs under `dir`, sorted by path.
fn walk(dir: &Path, plans: &mut Vec<PathBuf>, logs: &mut Vec<PathBuf>) -> Result<()> {
    let mut entries = std::fs::read_dir(dir)
        .with_context(|| format!("{}: cannot list the folder", dir.display()))?
        .map(|e| e.map(|e| e.path()))
        .collect::<std::io::Result<Vec<_>>>()?;
    entries.sort();
    if entries
        .iter()
        .any(|p| p.file_name().is_some_and(|n| n == "plan.json"))
    {
        plans.push(dir.to_path_buf());
    }
    let experiment = plans.last().is_some_and(|p| p == dir);
    for path in entries {
        if path.is_dir() {
            walk(&path, plans, logs)?;
        } else if !experiment // its trainings' validations are in its own table
            && path
            .file_name()
            .and_then(|n| n.to_str())
            .is_some_and(|n| n.ends_with("validation.csv") || n.starts_with("validation-"))
            && path.extension().is_some_and(|e| e == "csv")
        {
            logs.push(path);
        }
    }
    Ok(())
}

fn relative(root: &Path, path: &Path) -> String {
    path.strip_prefix(root)
        .unwrap_or(path)
        .to_string_lossy()
        .replace('\\', "/")
}

/// A table cell: no `|` or line break from the text breaks the row.
fn cell(text: &str) -> String {
    text.replace('|', "/").replace('\n', " ")
}

/// One experiment folder's files.
struct Folder {
    plan: Plan,
    trains: Vec<TrainResult>,
    /// `report/summary.json`, where the report was built.
    summary: Option<Value>,
}

impl Folder {
    fn read(dir: &Path) -> Result<Folder> {
        let plan = Plan::load(dir)?;
        let mut trains = Vec::new();
        for job in &plan.jobs {
            if matches!(job.kind, JobKind::Train { .. }) && plan.is_done(dir, job.id) {
                trains.push(read_train_result(&plan.result_path(dir, job.id))?);
            }
        }
        let summary_path = dir.join("report/summary.json");
        let summary = if summary_path.is_file() {
            let text = std::fs::read_to_string(&summary_path)
                .with_context(|| format!("{}: cannot read", summary_path.display()))?;
            Some(
                serde_json::from_str(&text)
                    .with_context(|| format!("{}: not JSON", summary_path.display()))?,
            )
        } else {
            None
        };
        Ok(Folder {
            plan,
            trains,
            summary,
        })
    }

    /// "done of total" as the report counted them (the per-trial inference files are not
    /// kept in git, so the report's count is the record).
    fn jobs_done(&self) -> String {
        let field = |name: &str| {
            self.summary
                .as_ref()
                .and_then(|s| s[name].as_u64())
                .map_or("?".to_string(), |n| n.to_string())
        };
        format!("{} of {}", field("jobs_done"), self.plan.jobs.len())
    }

    fn gates(&self) -> Vec<Option<Gate>> {
        self.trains.iter().map(TrainResult::gate).collect()
    }

    fn gate_counts(&self) -> String {
        let gates: Vec<Gate> = self.gates().into_iter().flatten().collect();
        if gates.is_empty() {
            return "not gated".into();
        }
        let count = |verdict: GateVerdict| gates.iter().filter(|g| g.verdict == verdict).count();
        format!(
            "{} / {} / {} ({})",
            count(GateVerdict::Pass),
            count(GateVerdict::Fail),
            count(GateVerdict::Incomplete),
            gates.iter().filter(|g| g.passes_vision()).count(),
        )
    }

    fn findings(&self) -> Vec<&Value> {
        self.summary
            .as_ref()
            .and_then(|s| s["paper"].as_array())
            .map(|a| a.iter().collect())
            .unwrap_or_default()
    }

    fn reading_counts(&self) -> String {
        let findings = self.findings();
        if findings.is_empty() {
            return "no report".into();
        }
        let count = |reading: &str| {
            findings
                .iter()
                .filter(|f| self::reading(f) == reading)
                .count()
        };
        format!(
            "{} / {} / {} / {}",
            count("agrees"),
            count("disagrees"),
            count("undecided"),
            count("not testable")
        )
    }

    fn trainings_table(&self, md: &mut String) {
        if self.trains.is_empty() {
            md.push_str("No training finished.\n");
            return;
        }
        md.push_str(
            "| training | iterations | stopped | network used | held-out vision (strongest baseline) | gate | free energy's last-tenth change | training time | where it ran |\n\
             |---|---|---|---|---|---|---|---|---|\n",
        );
        for (t, gate) in self.trains.iter().zip(self.gates()) {
            let stopped = match (&t.reused, t.stop) {
                (Some(from), _) => format!("reused ({})", cell(from)),
                (None, Some(stop)) => serde_json::to_value(stop)
                    .ok()
                    .and_then(|v| v.as_str().map(str::to_string))
                    .unwrap_or_default(),
                (None, None) => "fixed iterations".into(),
            };
            let time = if t.reused.is_some() {
                "–".to_string()
            } else {
                format!("{:.0} s", t.seconds)
            };
            let place = if t.machines.is_empty() {
                t.backend.clone().unwrap_or_default()
            } else {
                t.machines.join("; then ")
            };
            let _ = writeln!(
                md,
                "| {}, net {} | {} | {stopped} | {} | {} | {} | {} | {time} | {} |",
                cell(&t.condition),
                t.network,
                t.iterations,
                t.network_iteration.unwrap_or(t.iterations),
                gate.as_ref().map_or("–".into(), vision_against_baseline),
                gate.as_ref().map_or("not gated", |g| g.verdict.name()),
                t.last_tenth_change
                    .map_or("–".into(), |c| format!("{:+.1}%", 100.0 * c)),
                cell(&place),
            );
        }
    }

    fn findings_table(&self, md: &mut String) {
        let findings = self.findings();
        if findings.is_empty() {
            return;
        }
        md.push_str("\n| finding (paper) | reading | why |\n|---|---|---|\n");
        for f in findings {
            let _ = writeln!(
                md,
                "| {} | {} | {} |",
                cell(f["finding"].as_str().unwrap_or("")),
                reading(f),
                cell(f["note"].as_str().unwrap_or("")),
            );
        }
    }
}

/// A finding's reading as its report gives it.
fn reading(finding: &Value) -> &'static str {
    match finding["agrees"].as_bool() {
        Some(true) => "agrees",
        Some(false) => "disagrees",
        None if finding["note"]
            .as_str()
            .is_some_and(|n| n.starts_with("not testable")) =>
        {
            "not testable"
        }
        None => "undecided",
    }
}

/// `0.006221 (upsample_detail 0.006068)`.
fn vision_against_baseline(gate: &Gate) -> String {
    let Some(vision) = gate.checks.iter().find(|c| c.measure == "vision") else {
        return "–".into();
    };
    let model = vision.model.map_or("not recorded".into(), sig);
    if vision.baseline_error.is_finite() {
        format!(
            "{model} ({} {})",
            vision.baseline,
            sig(vision.baseline_error)
        )
    } else {
        format!("{model} (no baseline recorded)")
    }
}
