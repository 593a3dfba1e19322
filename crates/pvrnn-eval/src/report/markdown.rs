//! `summary.md`: the report's opening (scale, compute, condition, stability, definitions),
//! then tables of the model beside its baselines per scope, sequence and camera.

use std::fmt::Write as _;

use super::comparisons::{Comparison, is_summary_group};
use super::condition::{Condition, ReportMeta};
use super::figures::{Figure, Pixels, find, scopes};
use super::summary::sequence_rows;
use crate::evaluate::{Evaluation, Source, Target};
use crate::groups::Group;

/// A number with four significant digits.
pub fn sig(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let decimals = (3 - v.abs().log10().floor() as i32).max(0) as usize;
    format!("{v:.decimals$}")
}

fn cell(f: Option<&Figure>) -> String {
    match f {
        None => "—".into(),
        Some(f) => match f.se {
            Some(se) => format!("{} ± {}", sig(f.mean), sig(se)),
            None => sig(f.mean),
        },
    }
}

pub(super) fn markdown(
    eval: &Evaluation,
    meta: &ReportMeta,
    condition: &Condition,
    figures: &[Figure],
    comparisons: &[Comparison],
) -> String {
    let mut md = String::new();
    preamble(&mut md, eval, meta, condition);
    let top = format!("v{}", eval.resolutions.last().copied().unwrap_or(0));
    let _ = writeln!(
        md,
        "## The model against the baselines ({top}, the highest resolution)\n"
    );
    ratio_table(
        &mut md,
        comparisons.iter().filter(|c| c.group == top).collect(),
    );
    let _ = writeln!(md);

    for (scope, _) in scopes(eval)
        .into_iter()
        .filter(|(s, _)| !s.starts_with("sequence:"))
    {
        let _ = writeln!(
            md,
            "## {}\n",
            if scope == "all" {
                "All sequences".to_string()
            } else {
                scope.replace("task:", "Task: ")
            }
        );
        for pixels in Pixels::ALL {
            if pixels == Pixels::Changing {
                let _ = writeln!(md, "\nChanging pixels only:\n");
            }
            comparison_header(&mut md, "group");
            for group in eval.groups.iter().filter(|g| is_summary_group(g)) {
                if pixels == Pixels::Changing && !group.is_vision() {
                    continue;
                }
                comparison_row(&mut md, &group_label(group), |t, s| {
                    find(figures, &scope, t, s, &group.name, pixels)
                });
            }
        }
        let _ = writeln!(md);
    }

    let _ = writeln!(md, "## Per sequence ({top}, all pixels)\n");
    comparison_header(&mut md, "sequence");
    for s in &eval.sequences {
        let scope = format!("sequence:{}", s.meta.name);
        comparison_row(&mut md, &s.meta.name, |t, src| {
            find(figures, &scope, t, src, &top, Pixels::All)
        });
    }
    let _ = writeln!(md, "\n## Per camera (all sequences, all pixels)\n");
    comparison_header(&mut md, "group");
    for group in eval.groups.iter().filter(|g| !is_summary_group(g)) {
        comparison_row(&mut md, &group_label(group), |t, s| {
            find(figures, "all", t, s, &group.name, Pixels::All)
        });
    }
    let _ = writeln!(
        md,
        "\nFiles: `summary.json` (every figure and comparison), `per_sequence.csv` (every trial value), \
         `per_step.csv` (every step), `plots/` (error over time, actual vs predicted images)."
    );
    md
}

/// The report's opening: scale, compute, condition, stability, failures, and how the
/// errors and baselines are defined.
fn preamble(md: &mut String, eval: &Evaluation, meta: &ReportMeta, condition: &Condition) {
    let iteration = meta
        .model_iteration
        .map_or("unknown".to_string(), |i| i.to_string());
    let seqs = eval.sequences.len();
    let trials = eval.settings.trials;
    let _ = writeln!(md, "# Evaluation of `{}`\n", meta.model);
    let _ = writeln!(
        md,
        "- **Scale**: one network (training iteration {iteration}); {seqs} sequences of the `{}` split of `{}` x {}.",
        meta.split,
        meta.dataset,
        match (condition.seed, trials) {
            (None, _) => format!("{trials} inference trial(s) without noise (eps = 0)"),
            (Some(seed), 1) => format!("1 inference trial (noise seed {seed})"),
            (Some(seed), n) => format!(
                "{n} inference trials (noise seeds {seed}..{})",
                seed + n as u64 - 1
            ),
        }
    );
    let _ = writeln!(
        md,
        "- **Compute**: {:.0} s of online inference on {} worker thread{}, backend {}; {}.",
        meta.seconds,
        meta.threads,
        if meta.threads == 1 { "" } else { "s" },
        meta.backend,
        meta.machine
    );
    let _ = writeln!(
        md,
        "- **Condition**: {}; window H = {}, {} iterations per step, lr {}.",
        condition.label(),
        condition.window,
        condition.iterations,
        condition.lr
    );
    stability(md, eval, trials);
    let _ = writeln!(
        md,
        "- **Errors**: mean squared error in the model's normalised units (inputs in [-0.9, 0.9]). \
         Per trial pooled over steps and dimensions; per sequence the mean of its trials; then mean ± standard \
         error over sequences (trials of one sequence share its data and are not counted as samples). \
         *recon*: the posterior reconstruction of the current step x_t (all dimensions, observed or not); \
         *next*: the one-step prior prediction of x_(t+1). Groups marked * were not observed."
    );
    let _ = writeln!(
        md,
        "- **Baselines** (deterministic; mean over sequences): *upsample*: bilinear upsampling of the highest observed resolution; \
         *upsample_detail*: that plus the fine detail of the mean learning image (the mean image minus its own upsampling from the observed resolution); \
         *nearest*: the learning-split frame whose observed inputs are closest (each modality's mean squared distance over its observed dimensions, summed), whole; \
         *previous*: the current step's true input as the prediction of the next (it sees dimensions the model may not); \
         *mean*: the mean learning-split input. *won*: the sequences on which the model (mean of its trials) beats the baseline."
    );
    let _ = writeln!(
        md,
        "- **Changing pixels**: a pixel whose channels move by more than {} of 255 levels since the previous frame.\n",
        eval.settings.change_threshold
    );
}

/// The report's stability and failure lines: steps that restarted at a halved rate, and
/// trials that diverged beyond repair (left out, with what that excludes).
fn stability(md: &mut String, eval: &Evaluation, trials: usize) {
    let restarts = sequence_rows(eval, |s| &s.restarts);
    if restarts.is_empty() {
        let _ = writeln!(md, "- **Stability**: no step's online inference diverged.");
    } else {
        let listed: Vec<String> = restarts
            .iter()
            .map(|r| {
                format!(
                    "`{}` trial {} step {} (lr / 2^{})",
                    r.sequence, r.entry.trial, r.entry.step, r.entry.rate_halvings
                )
            })
            .collect();
        let _ = writeln!(
            md,
            "- **Stability**: online inference diverged in {} step(s) and restarted each from the \
             step's start at a halved rate until it did not: {}. Those steps' errors are in the \
             tables, at that rate.",
            restarts.len(),
            listed.join(", ")
        );
    }
    let failures = sequence_rows(eval, |s| &s.failures);
    if !failures.is_empty() {
        let listed: Vec<String> = failures
            .iter()
            .map(|f| {
                format!(
                    "`{}` trial {} at step {}",
                    f.sequence, f.entry.trial, f.entry.step
                )
            })
            .collect();
        let excluded: Vec<String> = eval
            .sequences
            .iter()
            .filter(|s| s.excluded())
            .map(|s| format!("`{}`", s.meta.name))
            .collect();
        let _ = writeln!(
            md,
            "- **Failures**: online inference diverged beyond repair (even at lr / 2^{}) in {} of {} \
             trials: {}. Those trials are left out of every figure{}. First message: {}",
            pvrnn_core::infer::MAX_RATE_HALVINGS,
            failures.len(),
            eval.sequences.len() * trials,
            listed.join(", "),
            if excluded.is_empty() {
                String::new()
            } else {
                format!(
                    "; {} had no trial that finished and {} left out with {} baselines, so the \
                     model and the baselines are scored on the same sequences",
                    excluded.join(", "),
                    if excluded.len() == 1 { "is" } else { "are" },
                    if excluded.len() == 1 { "its" } else { "their" },
                )
            },
            failures[0].entry.message
        );
    }
}

/// The model beside each baseline: one row per comparison.
fn ratio_table(md: &mut String, rows: Vec<&Comparison>) {
    let _ = writeln!(
        md,
        "| scope | target | group | pixels | baseline | model | baseline value | model / baseline | won |"
    );
    let _ = writeln!(md, "|---|---|---|---|---|---|---|---|---|");
    for c in rows {
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} | {} | {} | **{:.3}** {} | {} of {} |",
            c.scope,
            c.target.name(),
            c.group,
            c.pixels.name(),
            c.baseline.name(),
            match c.model_se {
                Some(se) => format!("{} ± {}", sig(c.model), sig(se)),
                None => sig(c.model),
            },
            sig(c.baseline_value),
            c.ratio,
            if c.model_better { "better" } else { "worse" },
            c.wins,
            c.sequences
        );
    }
}

/// The header of a table of the model beside its baselines, one row per `first` column.
fn comparison_header(md: &mut String, first: &str) {
    let _ = writeln!(
        md,
        "| {first} | recon: model | upsample | upsample_detail | nearest | mean | next: model | previous | mean |"
    );
    let _ = writeln!(md, "|---|---|---|---|---|---|---|---|---|");
}

/// One row of that table; `figure` finds the mean (± SE) of a target and source.
fn comparison_row<'a>(
    md: &mut String,
    label: &str,
    figure: impl Fn(Target, Source) -> Option<&'a Figure>,
) {
    let _ = writeln!(
        md,
        "| {label} | {} | {} | {} | {} | {} | {} | {} | {} |",
        cell(figure(Target::Recon, Source::Model)),
        cell(figure(Target::Recon, Source::Upsample)),
        cell(figure(Target::Recon, Source::UpsampleDetail)),
        cell(figure(Target::Recon, Source::Nearest)),
        cell(figure(Target::Recon, Source::Mean)),
        cell(figure(Target::Next, Source::Model)),
        cell(figure(Target::Next, Source::Previous)),
        cell(figure(Target::Next, Source::Mean)),
    );
}

/// A group's name, starred when it was not observed.
fn group_label(group: &Group) -> String {
    format!("{}{}", group.name, if group.observed { "" } else { "*" })
}
