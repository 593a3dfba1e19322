//! From an [`Evaluation`] to figures (per trial, then per sequence the mean of its trials,
//! then mean ± SE over the scope's sequences), and the report files: `summary.json`, `summary.md`, `per_sequence.csv`,
//! `per_step.csv`.
//!
//! One job per file:
//! - `figures.rs`: trial values and figures, per scope ([`trial_values`], [`figures`],
//!   [`mean_se`]).
//! - `comparisons.rs`: the model against each baseline ([`comparisons`]).
//! - `condition.rs`: where the report comes from and the inference condition
//!   ([`ReportMeta`], [`Condition`]).
//! - `summary.rs`: `summary.json`'s shape.
//! - `markdown.rs`: `summary.md` ([`sig`] writes its numbers).
//! - `csv_files.rs`: `per_sequence.csv` and `per_step.csv`.
//!
//! [`write_report`] writes them all.

mod comparisons;
mod condition;
mod csv_files;
mod figures;
mod markdown;
mod summary;

use std::path::Path;

use crate::evaluate::Evaluation;
use crate::{Result, write_file};
use csv_files::{per_sequence_csv, per_step_csv};
use markdown::markdown;
use summary::{Summary, sequence_rows};

pub use comparisons::{Comparison, comparisons};
pub use condition::{Condition, ReportMeta};
pub use figures::{
    Figure, Pixels, TrialValue, applicable, figures, mean_se, scopes, sequence_means, trial_values,
};
pub use markdown::sig;

/// Writes `summary.json`, `summary.md`, `per_sequence.csv` and `per_step.csv` into `dir`.
pub fn write_report(eval: &Evaluation, meta: &ReportMeta, dir: &Path) -> Result<()> {
    let values = trial_values(eval);
    let figures = figures(eval, &values);
    let comparisons = comparisons(eval, &values, &figures);
    let condition = Condition::of(eval);
    let summary = Summary {
        format: "pvrnn-evaluation/1",
        meta,
        condition: condition.clone(),
        trials: eval.settings.trials,
        change_threshold_levels: eval.settings.change_threshold,
        groups: &eval.groups,
        sequences: eval.sequences.iter().map(|s| &s.meta).collect(),
        figures: &figures,
        comparisons: &comparisons,
        restarts: sequence_rows(eval, |s| &s.restarts),
        failures: sequence_rows(eval, |s| &s.failures),
    };
    write_file(
        &dir.join("summary.json"),
        serde_json::to_string_pretty(&summary)
            .expect("serialisable")
            .as_bytes(),
    )?;
    write_file(
        &dir.join("summary.md"),
        markdown(eval, meta, &condition, &figures, &comparisons).as_bytes(),
    )?;
    write_file(
        &dir.join("per_sequence.csv"),
        &per_sequence_csv(eval, &values)?,
    )?;
    write_file(&dir.join("per_step.csv"), &per_step_csv(eval)?)?;
    Ok(())
}
