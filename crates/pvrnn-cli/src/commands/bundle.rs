//! `pvrnn bundle`: a model, a dataset split, precomputed runs under the standard conditions
//! and the model's card, packaged for the explorer.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, Result, bail};
use pvrnn_core::infer::{InferenceSettings, Run};
use pvrnn_core::io::{self, StateStorage, TensorFile};
use pvrnn_core::run_sequence;
use pvrnn_core::{Modality, Model, ModuleId, Observations, Observed};
use pvrnn_dataset::card::ModelCard;
use pvrnn_dataset::{Dataset, Split};
use rayon::prelude::*;

use pvrnn_dataset::bundle::{BUNDLE_MANIFEST, BundleManifest};

use crate::commands::train::log_path;
use crate::{inputs, util};

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Example:\n  pvrnn bundle --model training/caresim-seed0.safetensors --dataset caresim/ --out models/default \\\n    --evaluation docs/results/evals/iter30000/all --machine \"AMD EPYC 7B13, 2 threads\""
)]
pub struct Args {
    /// A trained model (or checkpoint).
    #[arg(long)]
    model: PathBuf,
    /// The dataset folder whose sequences the bundle shows.
    #[arg(long)]
    dataset: PathBuf,
    /// Bundle folder to write.
    #[arg(long)]
    out: PathBuf,
    /// Which sequences: test (default), learn or all.
    #[arg(long, default_value = "test")]
    split: String,
    /// One line saying what the bundle is (shown by the explorer).
    #[arg(long, default_value = "")]
    description: String,
    /// Seed of the precomputed runs' noise.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Conditions to precompute, as VISION/PROPRIO (vision: all, none, `low` for the lowest
    /// resolution alone, or the lowest resolutions such as 16 or 32+16; proprioception: on
    /// or off). The default is the explorer's four standard conditions.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "all/on,low/on,low/off,none/on"
    )]
    conditions: Vec<String>,
    /// Store the weights as f32 instead of f16 (f16 halves the download; the bundle
    /// measures and reports what the rounding changes).
    #[arg(long)]
    f32_weights: bool,
    /// Mantissa bits (of f16's 10) kept for the runs' per-step states: fewer bits compress
    /// much better; the bundle measures and reports what the rounding changes.
    #[arg(long, default_value_t = 6, value_parser = clap::value_parser!(u32).range(1..=10))]
    state_bits: u32,
    /// `pvrnn evaluate` reports of this model (folders with a summary.json) for the card.
    #[arg(long)]
    evaluation: Vec<PathBuf>,
    /// The training log for the card (default: beside the model, `run.safetensors` -> `run.log.csv`, when it exists).
    #[arg(long)]
    training_log: Option<PathBuf>,
    /// The machine the model was trained on, for the card (e.g. "AMD EPYC 7B13, 2 threads").
    #[arg(long)]
    machine: Option<String>,
    /// The training data in words, for the card (default: the dataset's source and its
    /// learning split's size).
    #[arg(long)]
    training_data: Option<String>,
}

/// One VISION/PROPRIO condition and its runs file's name.
fn parse_condition(text: &str, model: &Model<f32>) -> Result<(Observed, String)> {
    let Some((vision, proprio)) = text.split_once('/') else {
        bail!("--conditions: `{text}` is not VISION/PROPRIO (e.g. 16/on)");
    };
    // `low`: the lowest resolution, so the default fits any model's pyramid.
    let lowest = model
        .config
        .vision
        .resolutions
        .first()
        .map(|r| r.to_string());
    let vision = match (vision, &lowest) {
        ("low", Some(r)) => r.as_str(),
        _ => vision,
    };
    let observed = Observed {
        vision_levels: Observed::parse_vision(vision, &model.config)?,
        proprio: util::on_off(proprio)
            .map_err(|e| anyhow::anyhow!("--conditions `{text}`: {e}"))?,
    };
    Ok((observed, format!("runs-{vision}-{proprio}.safetensors")))
}

/// Every sequence's run under one condition.
fn runs_of(
    model: &Arc<Model<f32>>,
    settings: &InferenceSettings,
    data: &Observations<f32>,
    what: &str,
) -> Result<Vec<Run<f32>>> {
    let total: usize = data.lengths().iter().sum();
    let bar = util::progress(total as u64, what);
    // Sequences in parallel: one run's window is too small to keep two cores busy alone.
    let runs = (0..data.sequences())
        .into_par_iter()
        .map(|s| {
            run_sequence(
                model.clone(),
                settings.clone(),
                data,
                s,
                false,
                &mut |step, _| {
                    bar.set_message(format!(
                        "sequence {s}, window F {:.4}",
                        step.window_free_energy.total
                    ));
                    bar.inc(1);
                },
            )
        })
        .collect::<pvrnn_core::Result<Vec<_>>>()?;
    bar.finish();
    Ok(runs)
}

/// Vision reconstruction MSE of a run of `data`'s first sequence, read out from its states
/// `d` as a reader gets them back from `storage`.
/// What the rounded states change: the vision read-out of the first run's d, with the
/// states as stored against exact, as the card states it.
fn states_note(
    shipped: &Model<f32>,
    first: &Run<f32>,
    one: &Observations<f32>,
    bits: u32,
    name: &str,
) -> Result<String> {
    let exact = stored_state_vision_error(shipped, first, one, StateStorage::F32)?;
    let rounded = stored_state_vision_error(shipped, first, one, StateStorage::F16Mantissa(bits))?;
    Ok(format!(
        "per-step states as f16 with {bits} of 10 mantissa bits (changes the vision reconstruction error read out of {name}'s states by {:+.3}%)",
        (rounded / exact - 1.0) * 100.0
    ))
}

fn stored_state_vision_error(
    model: &Model<f32>,
    run: &Run<f32>,
    data: &Observations<f32>,
    storage: StateStorage,
) -> Result<f64> {
    let d: Vec<f32> = run.modules[ModuleId::Exteroceptive.index()]
        .d
        .iter()
        .map(|&v| storage.round_trip(v))
        .collect();
    let steps = run.steps();
    let loaded = pvrnn_core::backend::Backend::load(
        &pvrnn_core::cpu::CpuBackend,
        &model.params,
        &model.config,
    );
    let recon = loaded.readout(Modality::Exteroceptive, &d, steps)?;
    let dims = data.dims(Modality::Exteroceptive);
    let sum: f64 = (0..steps)
        .flat_map(|t| {
            recon[t * dims..(t + 1) * dims]
                .iter()
                .zip(data.step(Modality::Exteroceptive, 0, t))
        })
        .map(|(a, b)| (f64::from(*a) - f64::from(*b)).powi(2))
        .sum();
    Ok(sum / (steps * dims) as f64)
}

fn mean_recon_error(run: &Run<f32>, modality: usize) -> f64 {
    run.recon_error.iter().map(|e| e[modality]).sum::<f64>() / run.steps().max(1) as f64
}

/// (iteration, free energy, seconds) of the log row at `iteration` (or the last before it).
fn training_row(log: &Path, iteration: Option<u64>) -> Result<Option<(f64, f64)>> {
    let text = std::fs::read_to_string(log)
        .with_context(|| format!("{}: cannot read the training log", log.display()))?;
    let mut found = None;
    for line in text.lines().skip(1) {
        let cells: Vec<&str> = line.split(',').collect();
        let (Some(i), Some(total), Some(seconds)) = (
            cells.first().and_then(|c| c.parse::<u64>().ok()),
            cells.get(1).and_then(|c| c.parse::<f64>().ok()),
            cells.last().and_then(|c| c.parse::<f64>().ok()),
        ) else {
            bail!("{}: `{line}` is not a training log row", log.display());
        };
        if iteration.is_some_and(|want| i > want) {
            break;
        }
        found = Some((total, seconds));
    }
    Ok(found)
}

pub fn run(a: Args) -> Result<()> {
    let file = TensorFile::open(&a.model)?;
    let mut model = io::model_from_file(&file)?;
    let iteration = io::checkpoint_iteration(&file);
    drop(file);
    let dataset = Dataset::open(&a.dataset)?;
    inputs::ensure_normalisation(&mut model, &dataset, &a.dataset)?;
    let conditions: Vec<(Observed, String)> = a
        .conditions
        .iter()
        .map(|c| parse_condition(c, &model))
        .collect::<Result<_>>()?;
    let selection = inputs::parse_split(Some(&a.split), Split::Test)?;
    let sequences: Vec<_> = dataset.select(&selection)?.into_iter().cloned().collect();
    let subset = dataset.subset(sequences)?;
    let refs: Vec<_> = subset.sequences.iter().collect();
    let data = subset.observations(&refs, &model.config)?;
    let learning = dataset
        .select(&pvrnn_dataset::Selection::Split(Split::Learn))
        .map_or(0, |s| s.len());

    // Inference needs the weights only: the learning sequences' adaptive variables (A) do
    // not take part in online inference on new sequences.
    let full = Arc::new(model.weights_only());
    let (model_bytes, weights) = if a.f32_weights {
        (io::model_to_bytes(&*full)?, "f32".to_string())
    } else {
        (io::model_to_bytes_f16(&*full)?, String::new())
    };
    // The runs are computed with exactly the weights that ship.
    let shipped = Arc::new(io::model_from_bytes(
        model_bytes.clone(),
        "the bundled model",
    )?);
    let mut settings = InferenceSettings::from_config(&shipped.config, a.seed);

    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("{}: cannot create", a.out.display()))?;
    io::write_atomic(&a.out.join("model.safetensors"), &model_bytes)?;
    subset.write(&a.out)?;
    let names: Vec<String> = subset
        .sequences
        .iter()
        .map(|s| s.info.name.clone())
        .collect();
    let ids: Vec<usize> = (0..names.len()).collect();
    let storage = StateStorage::F16Mantissa(a.state_bits);
    let mut run_files = Vec::new();
    let mut first_runs = None;
    for (observed, file) in &conditions {
        settings.observed = *observed;
        let runs = runs_of(&shipped, &settings, &data, file)?;
        // Rounded f16 states: the explorer draws them and reads images out of `d`, and the
        // bundle has to download quickly.
        let bytes = io::runs_to_bytes(&shipped.config, &runs, &ids, Some(&names), storage)?;
        io::write_atomic(&a.out.join(file), &bytes)?;
        run_files.push(file.clone());
        first_runs.get_or_insert(runs);
    }

    let weights = if weights.is_empty() {
        let first = &first_runs.as_ref().expect("at least one condition")[0];
        f16_note(
            &full,
            first,
            &mut settings,
            conditions[0].0,
            &data,
            &names[0],
        )?
    } else {
        weights
    };
    eprintln!("weights: {weights}");
    let first = &first_runs.as_ref().expect("at least one condition")[0];
    let states = states_note(
        &shipped,
        first,
        &data.select(&[0])?,
        a.state_bits,
        &names[0],
    )?;
    eprintln!("runs: {states}");

    let card = model_card(
        &a,
        &model,
        &dataset,
        iteration,
        learning,
        format!("{weights}; {states}"),
    )?;
    write_card_readme(&a, &card, &run_files)?;
    let manifest = BundleManifest::new(
        a.description,
        "model.safetensors".into(),
        pvrnn_dataset::MANIFEST.into(),
        run_files,
        Some(card),
    );
    io::write_atomic(&a.out.join(BUNDLE_MANIFEST), manifest.to_json().as_bytes())?;
    eprintln!(
        "wrote {} ({} sequences, {} precomputed conditions)",
        a.out.display(),
        names.len(),
        conditions.len()
    );
    Ok(())
}

/// The model card: the training's iteration, time, machine, data and final free energy
/// (from its log, where there is one), the weights' note, departures from the paper and
/// the evaluations cited.
fn model_card(
    a: &Args,
    model: &Model<f32>,
    dataset: &Dataset,
    iteration: Option<u64>,
    learning: usize,
    weights: String,
) -> Result<ModelCard> {
    let log = a.training_log.clone().unwrap_or_else(|| log_path(&a.model));
    let trained = if a.training_log.is_some() || log.is_file() {
        training_row(&log, iteration)?
    } else {
        None
    };
    let evaluations = card_evaluations(&a.evaluation)?;
    let card = ModelCard {
        iteration,
        training_seconds: trained.map(|t| t.1),
        training_machine: a.machine.clone(),
        training_data: a.training_data.clone().unwrap_or_else(|| {
            format!(
                "{} ({learning} learning sequences)",
                dataset.manifest.source
            )
        }),
        free_energy: trained.map(|t| t.0),
        weights,
        departures: model.config.departures_from_paper(),
        evaluations,
    };
    Ok(card)
}

/// What f16 weights change: `sequence`'s run under the first condition (`f16_run`, with
/// the shipped weights) against the same run with the f32 weights of `full`.
fn f16_note(
    full: &Arc<Model<f32>>,
    f16_run: &Run<f32>,
    settings: &mut InferenceSettings,
    observed: Observed,
    data: &Observations<f32>,
    sequence: &str,
) -> Result<String> {
    settings.observed = observed;
    let first_sequence = data.select(&[0])?;
    let f32_run = runs_of(full, settings, &first_sequence, "f16 check")?.remove(0);
    let change =
        |m: usize| (mean_recon_error(f16_run, m) / mean_recon_error(&f32_run, m) - 1.0) * 100.0;
    Ok(format!(
        "f16 (rounding the weights changes the mean reconstruction error of {sequence} by {:+.2}% (vision) and {:+.2}% (proprioception), measured on one run)",
        change(0),
        change(1)
    ))
}

/// The evaluations the card cites (`--evaluation`: report folders or summary files).
fn card_evaluations(paths: &[PathBuf]) -> Result<Vec<pvrnn_dataset::card::CardEvaluation>> {
    let mut evaluations = Vec::new();
    for dir in paths {
        let path = if dir.is_dir() {
            dir.join("summary.json")
        } else {
            dir.clone()
        };
        let text = std::fs::read_to_string(&path)
            .with_context(|| format!("{}: cannot read", path.display()))?;
        evaluations.push(pvrnn_eval::progress::card_evaluation(
            &text,
            &path.display().to_string(),
        )?);
    }
    Ok(evaluations)
}

/// The bundle's README.md: the model card and how to open the bundle.
fn write_card_readme(a: &Args, card: &ModelCard, run_files: &[String]) -> Result<()> {
    let title = if a.description.is_empty() {
        "PV-RNN model".to_string()
    } else {
        a.description.clone()
    };
    let mut readme = card.markdown(&title);
    readme.push_str(&format!(
        "\nPrecomputed runs (seed {}): {}.\n\nWritten by `pvrnn bundle`; open with `pvrnn-explorer --bundle {}`.\n",
        a.seed,
        run_files.join(", "),
        a.out.display()
    ));
    io::write_atomic(&a.out.join("README.md"), readme.as_bytes())?;
    Ok(())
}
