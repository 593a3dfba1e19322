//! From an [`Evaluation`] to figures: each trial's error pooled over steps and dimensions,
//! then per sequence the mean of its trials, then mean ± SE over each scope's sequences.

use std::collections::HashMap;

use serde::Serialize;

use crate::evaluate::{Evaluation, Source, Target};
use crate::groups::Group;
use crate::metrics::{Sse, StepErrors};

/// Over which values of a group an error is taken.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Pixels {
    All,
    /// Only the pixels that changed since the previous frame (vision).
    Changing,
}

impl Pixels {
    pub const ALL: [Pixels; 2] = [Pixels::All, Pixels::Changing];
    pub fn name(self) -> &'static str {
        match self {
            Pixels::All => "all",
            Pixels::Changing => "changing",
        }
    }
}

/// One trial's (or one deterministic baseline's) error on one sequence.
#[derive(Clone, Debug, Serialize)]
pub struct TrialValue {
    pub sequence: usize,
    pub trial: Option<usize>,
    pub source: Source,
    pub target: Target,
    pub group: usize,
    pub pixels: Pixels,
    pub mse: f64,
    pub values: u64,
}

/// One figure of the report: the mean (± SE) of the trial values in a scope.
#[derive(Clone, Debug, Serialize)]
pub struct Figure {
    /// `all`, `task:<task>` or `sequence:<name>`.
    pub scope: String,
    pub target: Target,
    pub source: Source,
    pub group: String,
    pub pixels: Pixels,
    pub mean: f64,
    /// Standard error over the scope's sequences (model only): a sequence's trials share
    /// its data, so they are averaged first rather than counted as samples.
    pub se: Option<f64>,
    /// Sequences averaged (each the mean of its trials).
    pub n: usize,
}

/// Whether a source's figure means something for a target and group: the previous step
/// only predicts the next one; upsampling only reconstructs unobserved vision levels.
pub fn applicable(source: Source, target: Target, group: &Group) -> bool {
    match source {
        Source::Model | Source::Mean => true,
        Source::Previous => target == Target::Next,
        Source::Upsample | Source::UpsampleDetail => {
            target == Target::Recon && group.is_vision() && !group.observed
        }
        Source::Nearest => target == Target::Recon,
    }
}

fn pooled(steps: &[Option<StepErrors>], group: usize, pixels: Pixels) -> Sse {
    let mut total = Sse::default();
    for e in steps.iter().flatten() {
        total.add(match pixels {
            Pixels::All => e.all[group],
            Pixels::Changing => e.changing[group],
        });
    }
    total
}

/// Every trial value of the evaluation (pooled over steps and dimensions).
pub fn trial_values(eval: &Evaluation) -> Vec<TrialValue> {
    let mut out = Vec::new();
    for (s, seq) in eval.sequences.iter().enumerate() {
        if seq.excluded() {
            continue;
        }
        for series in &seq.series {
            for (g, group) in eval.groups.iter().enumerate() {
                if !applicable(series.source, series.target, group) {
                    continue;
                }
                for pixels in Pixels::ALL {
                    if pixels == Pixels::Changing && !group.is_vision() {
                        continue;
                    }
                    let sse = pooled(&series.steps, g, pixels);
                    if let Some(mse) = sse.mse() {
                        out.push(TrialValue {
                            sequence: s,
                            trial: series.trial,
                            source: series.source,
                            target: series.target,
                            group: g,
                            pixels,
                            mse,
                            values: sse.count,
                        });
                    }
                }
            }
        }
    }
    out
}

/// The scopes of a report: all sequences, each task, each sequence.
pub fn scopes(eval: &Evaluation) -> Vec<(String, Vec<usize>)> {
    let mut out = vec![("all".to_string(), (0..eval.sequences.len()).collect())];
    let mut tasks: Vec<&str> = Vec::new();
    for s in &eval.sequences {
        if !tasks.contains(&s.meta.task.as_str()) {
            tasks.push(&s.meta.task);
        }
    }
    for task in tasks {
        let members = (0..eval.sequences.len())
            .filter(|&i| eval.sequences[i].meta.task == task)
            .collect();
        out.push((format!("task:{task}"), members));
    }
    for (i, s) in eval.sequences.iter().enumerate() {
        out.push((format!("sequence:{}", s.meta.name), vec![i]));
    }
    out
}

/// Mean and standard error (sample standard deviation / sqrt(n); `None` for n < 2).
pub fn mean_se(values: &[f64]) -> (f64, Option<f64>) {
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    if values.len() < 2 {
        return (mean, None);
    }
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, Some((var / n).sqrt()))
}

/// What a figure or a comparison is of: (source, target, group index, pixels).
type Quantity = (Source, Target, usize, Pixels);

/// Per quantity and sequence, the mean of that sequence's trial values (a deterministic
/// baseline has one value).
pub fn sequence_means(values: &[TrialValue]) -> HashMap<(Quantity, usize), f64> {
    let mut sums: HashMap<(Quantity, usize), (f64, usize)> = HashMap::new();
    for v in values {
        let e = sums
            .entry(((v.source, v.target, v.group, v.pixels), v.sequence))
            .or_default();
        e.0 += v.mse;
        e.1 += 1;
    }
    sums.into_iter()
        .map(|(k, (sum, n))| (k, sum / n as f64))
        .collect()
}

/// Every figure of every scope: mean ± SE over the scope's sequences of each sequence's
/// trial mean.
pub fn figures(eval: &Evaluation, values: &[TrialValue]) -> Vec<Figure> {
    let means = sequence_means(values);
    let mut out = Vec::new();
    for (scope, members) in scopes(eval) {
        for target in Target::ALL {
            for source in Source::ALL {
                for (g, group) in eval.groups.iter().enumerate() {
                    for pixels in Pixels::ALL {
                        let v: Vec<f64> = members
                            .iter()
                            .filter_map(|&s| means.get(&((source, target, g, pixels), s)).copied())
                            .collect();
                        if v.is_empty() {
                            continue;
                        }
                        let (mean, se) = mean_se(&v);
                        out.push(Figure {
                            scope: scope.clone(),
                            target,
                            source,
                            group: group.name.clone(),
                            pixels,
                            mean,
                            se: if source == Source::Model { se } else { None },
                            n: v.len(),
                        });
                    }
                }
            }
        }
    }
    out
}

pub(super) fn find<'a>(
    figures: &'a [Figure],
    scope: &str,
    target: Target,
    source: Source,
    group: &str,
    pixels: Pixels,
) -> Option<&'a Figure> {
    figures.iter().find(|f| {
        f.scope == scope
            && f.target == target
            && f.source == source
            && f.group == group
            && f.pixels == pixels
    })
}
