//! The model against each applicable baseline ([`Comparison`]): the ratio of their figures
//! and the sequences the model wins.

use serde::Serialize;

use super::figures::{Figure, Pixels, TrialValue, find, scopes, sequence_means};
use crate::evaluate::{Evaluation, Source, Target};
use crate::groups::Group;

/// The model against one baseline in one scope: `ratio` = model / baseline (below 1: the
/// model is better).
#[derive(Clone, Debug, Serialize)]
pub struct Comparison {
    pub scope: String,
    pub target: Target,
    pub group: String,
    pub pixels: Pixels,
    pub baseline: Source,
    pub model: f64,
    pub model_se: Option<f64>,
    pub baseline_value: f64,
    pub ratio: f64,
    pub model_better: bool,
    /// Sequences of the scope on which the model (the mean of its trials) is better than
    /// the baseline, and how many sequences both were scored on.
    pub wins: usize,
    pub sequences: usize,
}

/// The model against each applicable baseline, for every level and proprioception group
/// (not per camera) in the `all` and per-task scopes, with the sequences it wins.
pub fn comparisons(
    eval: &Evaluation,
    values: &[TrialValue],
    figures: &[Figure],
) -> Vec<Comparison> {
    let means = sequence_means(values);
    let mut out = Vec::new();
    let scopes: Vec<(String, Vec<usize>)> = scopes(eval)
        .into_iter()
        .filter(|s| !s.0.starts_with("sequence:"))
        .collect();
    for (scope, members) in &scopes {
        for (g, group) in eval
            .groups
            .iter()
            .enumerate()
            .filter(|(_, g)| is_summary_group(g))
        {
            for target in Target::ALL {
                for pixels in Pixels::ALL {
                    let Some(model) =
                        find(figures, scope, target, Source::Model, &group.name, pixels)
                    else {
                        continue;
                    };
                    for baseline in Source::BASELINES {
                        if let Some(b) = find(figures, scope, target, baseline, &group.name, pixels)
                        {
                            let ratio = model.mean / b.mean;
                            let pairs: Vec<(f64, f64)> = members
                                .iter()
                                .filter_map(|&s| {
                                    Some((
                                        *means.get(&((Source::Model, target, g, pixels), s))?,
                                        *means.get(&((baseline, target, g, pixels), s))?,
                                    ))
                                })
                                .collect();
                            out.push(Comparison {
                                scope: scope.clone(),
                                target,
                                group: group.name.clone(),
                                pixels,
                                baseline,
                                model: model.mean,
                                model_se: model.se,
                                baseline_value: b.mean,
                                ratio,
                                model_better: model.mean < b.mean,
                                wins: pairs.iter().filter(|(m, b)| m < b).count(),
                                sequences: pairs.len(),
                            });
                        }
                    }
                }
            }
        }
    }
    out
}

/// Level groups (both cameras) and proprioception groups: the ones the tables show.
pub(super) fn is_summary_group(g: &Group) -> bool {
    !g.is_vision() || !g.name.contains('_')
}
