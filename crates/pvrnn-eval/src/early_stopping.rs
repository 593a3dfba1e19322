//! Early stopping on held-out data: the one type behind `pvrnn train --validate` and the
//! experiments' convergence rule (pvrnn-experiment's training jobs). It knows when a
//! validation is due, keeps the validations so far in their log (a resumed run forgets
//! those after its checkpoint), says whether a new one is the best, and whether the run
//! has turned. What the best network is saved as is the caller's: `pvrnn train` keeps a
//! whole checkpoint, an experiment only the model.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use pvrnn_core::Model;
use pvrnn_core::backend::Backend;
use pvrnn_dataset::Dataset;

use crate::Result;
use crate::validation::{self, ValidationRow};

/// When to validate and when to stop.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StoppingRule {
    /// Validate every this many iterations (0 counts as 1).
    pub every: u64,
    /// Stop once this many validations in a row have not beaten the best (`None`: the
    /// validations are recorded and the best kept, but they never stop the run).
    pub patience: Option<usize>,
    /// The first iteration whose validation may be the best: earlier ones are recorded,
    /// not counted.
    pub select_from: u64,
}

/// A training run's early stopping: the held-out data, the rule, the validations so far
/// and where the log and the best network go.
#[derive(Debug)]
pub struct EarlyStopping {
    dataset: Dataset,
    rule: StoppingRule,
    rows: Vec<ValidationRow>,
    log: PathBuf,
    best: PathBuf,
}

impl EarlyStopping {
    /// Opens the log at `log` (a missing file is an empty log) for a run at `iteration`:
    /// validations of later iterations (written before the run was resumed from an older
    /// checkpoint) are forgotten.
    pub fn open(
        dataset: Dataset,
        rule: StoppingRule,
        log: PathBuf,
        best: PathBuf,
        iteration: u64,
    ) -> Result<Self> {
        let mut rows = validation::read_log(&log)?;
        rows.retain(|r| r.iteration <= iteration);
        Ok(Self {
            dataset,
            rule: StoppingRule {
                every: rule.every.max(1),
                ..rule
            },
            rows,
            log,
            best,
        })
    }

    pub fn rule(&self) -> StoppingRule {
        self.rule
    }

    /// Where the best network is kept.
    pub fn best_path(&self) -> &Path {
        &self.best
    }

    /// The validations so far, in the order they ran.
    pub fn rows(&self) -> &[ValidationRow] {
        &self.rows
    }

    /// The validations, given up (the run is over).
    pub fn into_rows(self) -> Vec<ValidationRow> {
        self.rows
    }

    /// A validation is due after `iteration`.
    pub fn due(&self, iteration: u64) -> bool {
        iteration > 0 && iteration.is_multiple_of(self.rule.every)
    }

    /// The checkpoint's own iteration is due a validation the log lacks (the run stopped
    /// during it).
    pub fn missed(&self, iteration: u64) -> bool {
        self.due(iteration) && self.rows.last().map(|r| r.iteration) != Some(iteration)
    }

    /// The validations that may be the best (from `select_from` on).
    fn counted(&self) -> &[ValidationRow] {
        let from = self.rule.select_from;
        &self.rows[self.rows.partition_point(|r| r.iteration < from)..]
    }

    /// The best counted validation, when `patience` validations since have not beaten it:
    /// the run has turned.
    pub fn stalled(&self) -> Option<&ValidationRow> {
        validation::stalled(self.counted(), self.rule.patience?)
    }

    /// Scores `model` at `iteration` on the held-out data; `true` when it is the best so
    /// far (the caller keeps it at [`Self::best_path`], then [`Self::record`]s the row:
    /// in that order, a log never names a best that was not kept).
    pub fn score(
        &self,
        model: Arc<Model<f32>>,
        backend: &dyn Backend<f32>,
        iteration: u64,
    ) -> Result<(ValidationRow, bool)> {
        let row = validation::validate(model, backend, &self.dataset, iteration)?;
        let best = iteration >= self.rule.select_from
            && validation::best(self.counted()).is_none_or(|b| row.better_than(b));
        Ok((row, best))
    }

    /// Adds a validation to the log (rewritten atomically).
    pub fn record(&mut self, row: ValidationRow) -> Result<()> {
        self.rows.push(row);
        validation::write_log(&self.log, &self.rows)
    }
}
