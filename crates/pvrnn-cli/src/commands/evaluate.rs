//! `pvrnn evaluate`: online inference on every sequence of a dataset split under one
//! condition, N noise trials each, scored against baselines; a report folder.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{Result, bail};
use pvrnn_core::io::{self, TensorFile};
use pvrnn_dataset::{Dataset, Split};
use pvrnn_eval::report::{self, Pixels};
use pvrnn_eval::{EvalSettings, ReportMeta, plots};

use crate::condition::ConditionArgs;
use crate::{inputs, util};

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Example:\n  pvrnn evaluate --model training/caresim-seed0.safetensors --inputs caresim/ --vision 16 --proprio on --trials 5 --out eval/p16/"
)]
pub struct Args {
    /// A trained model or checkpoint (a checkpoint also gives the report its iteration).
    #[arg(long)]
    model: PathBuf,
    /// A dataset folder (subtask labels, tasks, and its learning split for the mean baseline).
    #[arg(long)]
    inputs: PathBuf,
    /// Dataset split to evaluate: test (default), learn or all.
    #[arg(long)]
    split: Option<String>,
    #[command(flatten)]
    condition: ConditionArgs,
    /// Inference trials per sequence (noise seeds --seed, --seed + 1, ...); the paper uses 5.
    #[arg(long, default_value_t = 5)]
    trials: usize,
    /// A pixel counts as changing when a channel moves by more than this many 8-bit levels
    /// (0-255) from the previous frame.
    #[arg(long, default_value_t = 8.0)]
    change_threshold: f64,
    /// Report folder: summary.json, summary.md, per_sequence.csv, per_step.csv, plots/.
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    backend: util::BackendArgs,
}

pub fn run(a: Args) -> Result<()> {
    if !a.inputs.is_dir() {
        bail!(
            "{}: evaluate needs a dataset folder (subtask labels, tasks and the learning split's mean), not an inputs file",
            a.inputs.display()
        );
    }
    anyhow::ensure!(a.trials >= 1, "--trials must be at least 1");
    anyhow::ensure!(
        a.change_threshold.is_finite() && (0.0..255.0).contains(&a.change_threshold),
        "--change-threshold must be in [0, 255) levels"
    );
    let (backend, backend_name) = a.backend.open_for_inference("evaluate")?;
    if a.backend.backend != util::BackendKind::Cpu {
        eprintln!("backend: {backend_name}");
    }
    let file = TensorFile::open(&a.model)?;
    let mut model = io::model_from_file(&file)?;
    let iteration = io::checkpoint_iteration(&file);
    drop(file);
    let dataset = Dataset::open(&a.inputs)?;
    inputs::ensure_normalisation(&mut model, &dataset, &a.inputs)?;
    let selection = inputs::parse_split(a.split.as_deref(), Split::Test)?;
    let settings = EvalSettings {
        inference: a.condition.settings(&model.config)?,
        trials: a.trials,
        change_threshold: a.change_threshold,
        image_columns: 8,
        nearest_neighbour: true,
    };
    let steps: usize = dataset.select(&selection)?.iter().map(|s| s.len()).sum();
    let bar = util::progress((steps * a.trials) as u64, "evaluate");
    let started = std::time::Instant::now();
    let evaluation = pvrnn_eval::evaluate(
        Arc::new(model),
        backend.as_ref(),
        &dataset,
        &selection,
        &settings,
        &|| bar.inc(1),
    )?;
    bar.finish();
    let meta = ReportMeta {
        model: a.model.display().to_string(),
        model_iteration: iteration,
        dataset: a.inputs.display().to_string(),
        split: a.split.unwrap_or_else(|| "test".into()),
        seconds: started.elapsed().as_secs_f64(),
        threads: rayon::current_num_threads(),
        backend: backend_name,
        machine: pvrnn_eval::machine::describe(rayon::current_num_threads()),
    };
    pvrnn_eval::write_report(&evaluation, &meta, &a.out)?;
    plots::write_plots(&evaluation, &a.out.join("plots"))?;

    // The headline: the model against each baseline on the highest resolution.
    let values = report::trial_values(&evaluation);
    let figures = report::figures(&evaluation, &values);
    let top = format!("v{}", evaluation.resolutions.last().copied().unwrap_or(0));
    for c in report::comparisons(&evaluation, &values, &figures)
        .iter()
        .filter(|c| c.group == top && c.pixels == Pixels::All && !c.scope.starts_with("sequence:"))
    {
        eprintln!(
            "{:<22} {:<5} {top}: model {} vs {:<8} {}  ({}: x{:.3})",
            c.scope,
            c.target.name(),
            report::sig(c.model),
            c.baseline.name(),
            report::sig(c.baseline_value),
            if c.model_better { "better" } else { "worse" },
            c.ratio
        );
    }
    eprintln!(
        "wrote {} (summary.md, summary.json, CSVs, plots/)",
        a.out.display()
    );
    let failures: Vec<String> = evaluation
        .sequences
        .iter()
        .flat_map(|s| {
            s.failures
                .iter()
                .map(move |f| format!("`{}` trial {} at step {}", s.meta.name, f.trial, f.step))
        })
        .collect();
    if evaluation.sequences.iter().all(|s| s.excluded()) {
        bail!(
            "online inference diverged in every trial ({}); the report has no figures. Try a smaller --lr",
            failures.join(", ")
        );
    }
    if !failures.is_empty() {
        eprintln!(
            "warning: online inference diverged beyond repair in {} trial(s), left out of the figures \
             (see summary.md): {}",
            failures.len(),
            failures.join(", ")
        );
    }
    Ok(())
}
