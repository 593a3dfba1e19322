//! Evaluation of a trained scalable PV-RNN: online inference (exactly `pvrnn infer`) on
//! every sequence of a dataset split under one condition, several noise trials each; errors
//! per modality group (each vision resolution and camera, joint angles, torques), for the
//! reconstruction of the current step and the prediction of the next, over all pixels and
//! over the pixels that change; the same errors of honest baselines (previous step, mean
//! learning input, bilinear upsampling), computed by the same code; and a report.
//!
//! - [`groups`]: which dimensions a figure covers.
//! - [`metrics`]: squared errors (one function for model and baselines), change masks,
//!   upsampling.
//! - [`evaluate`](mod@evaluate): the runs.
//! - [`report`]: aggregation (per trial, then mean ± SE) and the JSON, Markdown and CSV files.
//! - [`plots`]: PNG pictures (error over time with the subtask bar; actual vs predicted
//!   images), and training curves from a training log.
//! - [`gate`]: the validity gate: does a network beat the strongest baseline on held-out data?
//! - [`machine`]: where a result was computed, in words.
//! - [`progress`]: error against training iterations, from several evaluations.
//! - [`recipes`]: the recipe search's table, from each recipe's validation files.
//! - [`training_log`]: the per-iteration CSV log every training writes beside its checkpoint.
//! - [`validation`]: one validation: a training run scored on held-out sequences, and its log.
//! - [`early_stopping`]: when to validate, which network is best, when the run has turned:
//!   the one type behind `pvrnn train --validate` and the experiments' convergence rule.

pub mod baselines;
pub mod early_stopping;
pub mod evaluate;
pub mod gate;
pub mod groups;
pub mod machine;
pub mod metrics;
pub mod plots;
pub mod progress;
pub mod recipes;
pub mod report;
pub mod training_log;
pub mod validation;

use std::path::Path;

pub use evaluate::{EvalSettings, Evaluation, Source, Target, evaluate};
pub use report::{ReportMeta, write_report};

#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error(transparent)]
    Core(#[from] pvrnn_core::Error),
    #[error(transparent)]
    Dataset(#[from] pvrnn_dataset::Error),
    #[error("{0}")]
    Invalid(String),
    #[error("{path}: {detail}")]
    File { path: String, detail: String },
    #[error(transparent)]
    Csv(#[from] csv::Error),
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Writes a file atomically (temporary file, then rename), creating its folder.
pub(crate) fn write_file(path: &Path, bytes: &[u8]) -> Result<()> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|e| Error::File {
            path: dir.display().to_string(),
            detail: format!("cannot create: {e}"),
        })?;
    }
    pvrnn_core::io::write_atomic(path, bytes)?;
    Ok(())
}
