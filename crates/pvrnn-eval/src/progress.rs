//! Error against training iterations: one table per condition from several evaluations'
//! `summary.json` files of the same run, with the largest relative change between
//! consecutive evaluations (the campaign's convergence test).

use std::collections::BTreeMap;
use std::fmt::Write as _;

use pvrnn_dataset::card::{CardEvaluation, CardRow};
use serde_json::Value;

use crate::report::sig;
use crate::{Error, Result};

/// The errors each row shows: (target, group), all sequences, all pixels.
pub const COLUMNS: [(&str, &str); 7] = [
    ("recon", "v16"),
    ("recon", "v64"),
    ("recon", "joints"),
    ("recon", "torques"),
    ("next", "v64"),
    ("next", "joints"),
    ("next", "torques"),
];

/// One evaluation, as read back from its `summary.json`.
#[derive(Clone, Debug)]
pub struct Evaluated {
    pub iteration: u64,
    pub condition: String,
    /// Per column: the model's mean (None where the group is missing).
    pub model: Vec<Option<f64>>,
    /// Per column: the best applicable baseline and its name.
    pub best_baseline: Vec<Option<(f64, String)>>,
    /// Trials whose online inference diverged beyond repair (left out of its figures), and
    /// how many trials it ran in all.
    pub failed_trials: usize,
    pub total_trials: usize,
    /// Sequences none of whose trials finished (left out of every figure, baselines too).
    pub excluded_sequences: usize,
}

fn field<'a>(v: &'a Value, path: &[&str]) -> Option<&'a Value> {
    path.iter().try_fold(v, |v, k| v.get(k))
}

/// A parsed `summary.json` and a way to name it in errors.
pub(crate) struct Summary<'a> {
    v: Value,
    what: &'a str,
}

impl<'a> Summary<'a> {
    pub(crate) fn parse(text: &str, what: &'a str) -> Result<Self> {
        let s = Summary {
            v: Value::Null,
            what,
        };
        let v: Value = serde_json::from_str(text).map_err(|e| s.bad(&format!("not JSON: {e}")))?;
        if v.get("format").and_then(Value::as_str) != Some("pvrnn-evaluation/1") {
            return Err(s.bad("not a `pvrnn evaluate` summary (format pvrnn-evaluation/1)"));
        }
        Ok(Summary { v, what })
    }

    pub(crate) fn bad(&self, detail: &str) -> Error {
        Error::File {
            path: self.what.to_string(),
            detail: detail.to_string(),
        }
    }

    /// The mean (and SE) of one figure over all sequences.
    pub(crate) fn figure(
        &self,
        target: &str,
        group: &str,
        source: &str,
        pixels: &str,
    ) -> Option<(f64, Option<f64>)> {
        self.v.get("figures")?.as_array()?.iter().find_map(|f| {
            let is = |k: &str, want: &str| f.get(k).and_then(Value::as_str) == Some(want);
            (is("scope", "all")
                && is("target", target)
                && is("group", group)
                && is("source", source)
                && is("pixels", pixels))
            .then(|| {
                Some((
                    f.get("mean")?.as_f64()?,
                    f.get("se").and_then(Value::as_f64),
                ))
            })
            .flatten()
        })
    }

    /// The highest-resolution vision group (both cameras), e.g. `v64`.
    pub(crate) fn top_group(&self) -> Option<String> {
        self.v
            .get("groups")?
            .as_array()?
            .iter()
            .filter_map(|g| g.get("name")?.as_str())
            .filter_map(|n| Some((n.strip_prefix('v')?.parse::<u32>().ok()?, n)))
            .max()
            .map(|(_, n)| n.to_string())
    }

    /// E.g. "vision 16, proprioception on".
    pub(crate) fn condition(&self) -> Result<String> {
        let c = self
            .v
            .get("condition")
            .ok_or_else(|| self.bad("no condition"))?;
        Ok(format!(
            "vision {}, proprioception {}{}",
            c.get("vision").and_then(Value::as_str).unwrap_or("?"),
            if c.get("proprio").and_then(Value::as_bool).unwrap_or(false) {
                "on"
            } else {
                "off"
            },
            match c.get("ablation").and_then(Value::as_array) {
                Some(a) if !a.is_empty() => format!(
                    ", {} ablated",
                    a.iter()
                        .filter_map(Value::as_str)
                        .collect::<Vec<_>>()
                        .join("+")
                ),
                _ => String::new(),
            }
        ))
    }
}

/// Reads one `summary.json` (text); `what` names it in errors.
pub fn read_summary(text: &str, what: &str) -> Result<Evaluated> {
    let summary = Summary::parse(text, what)?;
    let v = &summary.v;
    let iteration = field(v, &["meta", "model_iteration"])
        .and_then(Value::as_u64)
        .ok_or_else(|| {
            summary.bad(
                "the evaluated model does not say its training iteration (evaluate a checkpoint)",
            )
        })?;
    let condition = summary.condition()?;
    if v.get("figures").and_then(Value::as_array).is_none() {
        return Err(summary.bad("no figures"));
    }
    let find = |target: &str, group: &str, source: &str| {
        summary.figure(target, group, source, "all").map(|f| f.0)
    };
    let model = COLUMNS.iter().map(|(t, g)| find(t, g, "model")).collect();
    let best_baseline = COLUMNS
        .iter()
        .map(|(t, g)| {
            crate::Source::BASELINES
                .map(crate::Source::name)
                .iter()
                .filter_map(|s| find(t, g, s).map(|v| (v, s.to_string())))
                .min_by(|a, b| a.0.total_cmp(&b.0))
        })
        .collect();
    let failures: Vec<&str> = v
        .get("failures")
        .and_then(Value::as_array)
        .map_or(Vec::new(), |f| {
            f.iter()
                .filter_map(|f| f.get("sequence").and_then(Value::as_str))
                .collect()
        });
    let trials = v.get("trials").and_then(Value::as_u64).unwrap_or(0) as usize;
    let total_trials = v
        .get("sequences")
        .and_then(Value::as_array)
        .map_or(0, Vec::len)
        * trials;
    let mut per_sequence: BTreeMap<&str, usize> = BTreeMap::new();
    for name in &failures {
        *per_sequence.entry(name).or_default() += 1;
    }
    let excluded_sequences = per_sequence.values().filter(|&&n| n >= trials).count();
    Ok(Evaluated {
        iteration,
        condition,
        model,
        best_baseline,
        failed_trials: failures.len(),
        total_trials,
        excluded_sequences,
    })
}

/// The rows a model card shows: each resolution, joints and torques, for the
/// reconstruction and the next-step prediction, over all pixels and (for vision) over the
/// changing ones.
pub fn card_evaluation(text: &str, what: &str) -> Result<CardEvaluation> {
    let summary = Summary::parse(text, what)?;
    let v = &summary.v;
    let groups: Vec<(String, bool)> = v
        .get("groups")
        .and_then(Value::as_array)
        .ok_or_else(|| summary.bad("no groups"))?
        .iter()
        .filter_map(|g| {
            Some((
                g.get("name")?.as_str()?.to_string(),
                g.get("observed")?.as_bool()?,
            ))
        })
        // Whole levels and modalities; per-camera groups stay in the full report.
        .filter(|(name, _)| !name.contains('_'))
        .collect();
    let mut rows = Vec::new();
    for target in ["recon", "next"] {
        for pixels in ["all", "changing"] {
            for (group, observed) in &groups {
                let Some((model, model_se)) = summary.figure(target, group, "model", pixels) else {
                    continue;
                };
                let baselines = crate::Source::BASELINES
                    .map(crate::Source::name)
                    .iter()
                    .filter_map(|b| {
                        summary
                            .figure(target, group, b, pixels)
                            .map(|f| (b.to_string(), f.0))
                    })
                    .collect();
                rows.push(CardRow {
                    target: target.into(),
                    group: group.clone(),
                    pixels: pixels.into(),
                    observed: *observed,
                    model,
                    model_se,
                    baselines,
                });
            }
        }
    }
    Ok(CardEvaluation {
        condition: summary.condition()?,
        sequences: v
            .get("sequences")
            .and_then(Value::as_array)
            .map_or(0, Vec::len),
        trials: v.get("trials").and_then(Value::as_u64).unwrap_or(0) as usize,
        rows,
    })
}

/// The largest relative change of any column between two evaluations.
pub fn max_relative_change(a: &Evaluated, b: &Evaluated) -> Option<f64> {
    a.model
        .iter()
        .zip(&b.model)
        .filter_map(|(x, y)| Some(((y.as_ref()? - x.as_ref()?) / x.as_ref()?).abs()))
        .reduce(f64::max)
}

/// One Markdown table per condition: a row per iteration, the largest change from the
/// previous row, and the best baseline of each column.
pub fn markdown(evaluations: &[Evaluated]) -> String {
    let mut by_condition: BTreeMap<&str, Vec<&Evaluated>> = BTreeMap::new();
    for e in evaluations {
        by_condition.entry(&e.condition).or_default().push(e);
    }
    let mut md = String::new();
    for (condition, mut rows) in by_condition {
        rows.sort_by_key(|e| e.iteration);
        let _ = writeln!(md, "### {condition}\n");
        let head: Vec<String> = COLUMNS.iter().map(|(t, g)| format!("{t} {g}")).collect();
        let _ = writeln!(md, "| iteration | {} | largest change |", head.join(" | "));
        let _ = writeln!(md, "|---|{}---|", "---|".repeat(COLUMNS.len()));
        for (i, e) in rows.iter().enumerate() {
            let cells: Vec<String> = e.model.iter().map(|v| v.map_or("—".into(), sig)).collect();
            let change = i
                .checked_sub(1)
                .and_then(|p| max_relative_change(rows[p], e))
                .map_or("—".into(), |c| format!("{:.1}%", c * 100.0));
            let iteration = match (e.failed_trials, e.excluded_sequences) {
                (0, _) => e.iteration.to_string(),
                (n, 0) => format!(
                    "{} ({n} of {} trials diverged, left out)",
                    e.iteration, e.total_trials
                ),
                (n, k) => format!(
                    "{} ({n} of {} trials diverged, left out; {k} sequence(s) left out with them)",
                    e.iteration, e.total_trials
                ),
            };
            let _ = writeln!(md, "| {iteration} | {} | {change} |", cells.join(" | "));
        }
        // Baselines over every sequence: a row that left sequences out scores them on fewer.
        let complete = rows.iter().rev().find(|e| e.failed_trials == 0);
        if let Some(last) = complete.or(rows.last()) {
            let cells: Vec<String> = last
                .best_baseline
                .iter()
                .map(|b| {
                    b.as_ref()
                        .map_or("—".into(), |(v, s)| format!("{} ({s})", sig(*v)))
                })
                .collect();
            let _ = writeln!(md, "| best baseline | {} | |", cells.join(" | "));
        }
        let _ = writeln!(md);
    }
    md
}
