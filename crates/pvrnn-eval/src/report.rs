//! From an [`Evaluation`] to figures (per trial, then per sequence the mean of its trials,
//! then mean ± SE over the scope's sequences), and the report files: `summary.json`, `summary.md`, `per_sequence.csv`,
//! `per_step.csv`.

use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::Path;

use serde::Serialize;

use crate::evaluate::{Evaluation, Series, Source, Target};
use crate::groups::Group;
use crate::metrics::{Sse, StepErrors};
use crate::{Result, write_file};

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

/// Where the report comes from (for its header).
#[derive(Clone, Debug, Serialize)]
pub struct ReportMeta {
    pub model: String,
    /// Training iteration of the model, when its file says.
    pub model_iteration: Option<u64>,
    pub dataset: String,
    pub split: String,
    /// Wall-clock seconds the inference runs took, and on how many worker threads.
    pub seconds: f64,
    pub threads: usize,
    /// Where the arithmetic ran: `cpu`, or `wgpu on` and the adapter (`--backend`).
    pub backend: String,
    /// The machine (`machine::describe`), e.g. `AMD EPYC (AVX2), 2 cores, 2 threads`.
    pub machine: String,
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

fn find<'a>(
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
fn is_summary_group(g: &Group) -> bool {
    !g.is_vision() || !g.name.contains('_')
}

/// `summary.json`'s shape.
#[derive(Serialize)]
struct Summary<'a> {
    format: &'static str,
    meta: &'a ReportMeta,
    condition: Condition,
    trials: usize,
    change_threshold_levels: f64,
    groups: &'a [Group],
    sequences: Vec<&'a crate::evaluate::SequenceMeta>,
    figures: &'a [Figure],
    comparisons: &'a [Comparison],
    /// Steps whose online inference diverged and was restarted at a reduced rate (their
    /// errors are in the figures, at that rate).
    restarts: Vec<SequenceRow<'a, crate::evaluate::Restart>>,
    /// Trials whose online inference diverged beyond repair (left out of the figures; a
    /// sequence none of whose trials finished is left out with its baselines).
    failures: Vec<SequenceRow<'a, crate::evaluate::Failure>>,
}

/// One entry of a per-sequence list (a restart, a failure), named by its sequence.
#[derive(Serialize)]
struct SequenceRow<'a, T> {
    sequence: &'a str,
    #[serde(flatten)]
    entry: &'a T,
}

/// Every sequence's entries of one list, in sequence order.
fn sequence_rows<T>(
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

/// The inference condition, in the CLI's terms.
#[derive(Clone, Debug, Serialize)]
pub struct Condition {
    pub vision: String,
    pub proprio: bool,
    pub ablation: Vec<String>,
    /// `readout` or `inference` (meaningful only with an ablation).
    pub ablation_mode: String,
    pub window: usize,
    pub iterations: usize,
    pub lr: f64,
    pub seed: Option<u64>,
}

impl Condition {
    pub fn of(eval: &Evaluation) -> Self {
        let s = &eval.settings.inference;
        let res = &eval.resolutions;
        let vision = match s.observed.vision_levels {
            0 => "none".to_string(),
            n if n >= res.len() => "all".to_string(),
            n => res[..n]
                .iter()
                .rev()
                .map(|r| r.to_string())
                .collect::<Vec<_>>()
                .join("+"),
        };
        Self {
            vision,
            proprio: s.observed.proprio,
            ablation: pvrnn_core::ModuleId::ALL
                .iter()
                .filter(|m| s.ablation.contains(**m))
                .map(|m| m.name().to_string())
                .collect(),
            ablation_mode: s.ablation_mode.name().to_string(),
            window: s.window,
            iterations: s.iterations,
            lr: s.optimizer.lr,
            seed: match s.noise {
                pvrnn_core::NoiseMode::Sampled { seed } => Some(seed),
                pvrnn_core::NoiseMode::Zero => None,
            },
        }
    }

    /// e.g. `vision 16, proprioception on, no ablation`.
    pub fn label(&self) -> String {
        format!(
            "vision {}, proprioception {}, {}",
            self.vision,
            if self.proprio { "on" } else { "off" },
            if self.ablation.is_empty() {
                "no ablation".to_string()
            } else {
                format!(
                    "{} ablated ({} mode)",
                    self.ablation.join("+"),
                    self.ablation_mode
                )
            }
        )
    }
}

/// A number with four significant digits.
pub fn sig(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let decimals = (3 - v.abs().log10().floor() as i32).max(0) as usize;
    format!("{v:.decimals$}")
}

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

fn cell(f: Option<&Figure>) -> String {
    match f {
        None => "—".into(),
        Some(f) => match f.se {
            Some(se) => format!("{} ± {}", sig(f.mean), sig(se)),
            None => sig(f.mean),
        },
    }
}

fn markdown(
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

fn csv_bytes(rows: impl FnOnce(&mut csv::Writer<Vec<u8>>) -> csv::Result<()>) -> Result<Vec<u8>> {
    let mut w = csv::Writer::from_writer(Vec::new());
    rows(&mut w)?;
    w.into_inner()
        .map_err(|e| crate::Error::Invalid(e.to_string()))
}

fn per_sequence_csv(eval: &Evaluation, values: &[TrialValue]) -> Result<Vec<u8>> {
    csv_bytes(|w| {
        w.write_record([
            "sequence",
            "task",
            "bed_height_mm",
            "trial",
            "target",
            "source",
            "group",
            "observed",
            "pixels",
            "mse",
            "values",
        ])?;
        for v in values {
            let seq = &eval.sequences[v.sequence].meta;
            let group = &eval.groups[v.group];
            w.write_record([
                seq.name.clone(),
                seq.task.clone(),
                seq.bed_height_mm.map_or(String::new(), |h| h.to_string()),
                v.trial.map_or(String::new(), |t| t.to_string()),
                v.target.name().into(),
                v.source.name().into(),
                group.name.clone(),
                group.observed.to_string(),
                v.pixels.name().into(),
                format!("{:e}", v.mse),
                v.values.to_string(),
            ])?;
        }
        Ok(())
    })
}

fn per_step_csv(eval: &Evaluation) -> Result<Vec<u8>> {
    csv_bytes(|w| {
        let mut header: Vec<String> = ["sequence", "trial", "source", "target", "t", "subtask"]
            .map(String::from)
            .to_vec();
        for g in &eval.groups {
            header.push(g.name.clone());
        }
        for g in eval.groups.iter().filter(|g| g.is_vision()) {
            header.push(format!("{}_changing", g.name));
        }
        w.write_record(&header)?;
        for seq in &eval.sequences {
            for series in &seq.series {
                write_series(w, eval, &seq.meta, series)?;
            }
        }
        Ok(())
    })
}

fn write_series(
    w: &mut csv::Writer<Vec<u8>>,
    eval: &Evaluation,
    meta: &crate::evaluate::SequenceMeta,
    series: &Series,
) -> csv::Result<()> {
    let mse = |s: Sse| s.mse().map_or(String::new(), |v| format!("{v:e}"));
    for (t, step) in series.steps.iter().enumerate() {
        let Some(e) = step else { continue };
        let subtask = meta
            .subtask
            .get(t)
            .and_then(|&i| meta.subtask_names.get(i as usize))
            .cloned()
            .unwrap_or_default();
        let mut row = vec![
            meta.name.clone(),
            series.trial.map_or(String::new(), |k| k.to_string()),
            series.source.name().into(),
            series.target.name().into(),
            t.to_string(),
            subtask,
        ];
        for (g, group) in eval.groups.iter().enumerate() {
            row.push(if applicable(series.source, series.target, group) {
                mse(e.all[g])
            } else {
                String::new()
            });
        }
        for (g, group) in eval
            .groups
            .iter()
            .enumerate()
            .filter(|(_, g)| g.is_vision())
        {
            row.push(if applicable(series.source, series.target, group) {
                mse(e.changing[g])
            } else {
                String::new()
            });
        }
        w.write_record(&row)?;
    }
    Ok(())
}
