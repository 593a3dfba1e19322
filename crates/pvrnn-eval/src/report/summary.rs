//! `summary.json`'s shape: the report's header, condition, groups, sequences, every figure
//! and comparison, and the steps and trials whose inference diverged.

use serde::Serialize;

use super::comparisons::Comparison;
use super::condition::{Condition, ReportMeta};
use super::figures::Figure;
use crate::evaluate::Evaluation;
use crate::groups::Group;

/// `summary.json`'s shape.
#[derive(Serialize)]
pub(super) struct Summary<'a> {
    pub(super) format: &'static str,
    pub(super) meta: &'a ReportMeta,
    pub(super) condition: Condition,
    pub(super) trials: usize,
    pub(super) change_threshold_levels: f64,
    pub(super) groups: &'a [Group],
    pub(super) sequences: Vec<&'a crate::evaluate::SequenceMeta>,
    pub(super) figures: &'a [Figure],
    pub(super) comparisons: &'a [Comparison],
    /// Steps whose online inference diverged and was restarted at a reduced rate (their
    /// errors are in the figures, at that rate).
    pub(super) restarts: Vec<SequenceRow<'a, crate::evaluate::Restart>>,
    /// Trials whose online inference diverged beyond repair (left out of the figures; a
    /// sequence none of whose trials finished is left out with its baselines).
    pub(super) failures: Vec<SequenceRow<'a, crate::evaluate::Failure>>,
}

/// One entry of a per-sequence list (a restart, a failure), named by its sequence.
#[derive(Serialize)]
pub(super) struct SequenceRow<'a, T> {
    pub(super) sequence: &'a str,
    #[serde(flatten)]
    pub(super) entry: &'a T,
}

/// Every sequence's entries of one list, in sequence order.
pub(super) fn sequence_rows<T>(
    eval: &Evaluation,
    list: impl Fn(&crate::evaluate::SequenceResult) -> &Vec<T>,
) -> Vec<SequenceRow<'_, T>> {
    eval.sequences
        .iter()
        .flat_map(|s| {
            list(s).iter().map(|entry| SequenceRow {
                sequence: &s.meta.name,
                entry,
            })
        })
        .collect()
}
