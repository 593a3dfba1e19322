//! `pvrnn bundle`: a model, a dataset split and precomputed runs, packaged for the explorer.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{Context, Result};
use pvrnn_core::infer::{InferenceSettings, run_sequence};
use pvrnn_core::io;
use pvrnn_dataset::{Dataset, Selection, Split, proprio_ranges};
use serde::Serialize;

use crate::util;

/// `bundle.json`: what the explorer opens.
#[derive(Serialize)]
struct BundleManifest {
    format: &'static str,
    description: String,
    model: &'static str,
    dataset: &'static str,
    runs: &'static str,
}

#[derive(clap::Args, Debug)]
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
}

pub fn run(a: Args) -> Result<()> {
    let mut model = io::load_model(&a.model)?;
    let dataset = Dataset::open(&a.dataset)?;
    if model.config.normalisation.is_none() {
        let learn = dataset.select(&Selection::Split(Split::Learn))?;
        model.config.normalisation = Some(proprio_ranges(&learn));
    }
    let selection = Selection::parse(&a.split)
        .with_context(|| format!("--split {}: expected learn, test or all", a.split))?;
    let sequences: Vec<_> = dataset.select(&selection)?.into_iter().cloned().collect();
    let subset = Dataset::new(
        &dataset.manifest.source,
        dataset.manifest.cameras.clone(),
        dataset.manifest.image_size,
        sequences,
    )?;
    let refs: Vec<_> = subset.sequences.iter().collect();
    let data = subset.observations(&refs, &model.config)?;

    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("{}: cannot create", a.out.display()))?;
    let model = Arc::new(model.weights_only());
    io::save_model(&a.out.join("model.safetensors"), &model)?;
    subset.write(&a.out)?;

    let settings = InferenceSettings::from_config(&model.config, a.seed);
    let total: usize = data.lengths().iter().sum();
    let bar = util::progress(total as u64, "runs");
    let mut runs = Vec::new();
    let mut before = 0u64;
    for s in 0..data.sequences() {
        let run = run_sequence(
            model.clone(),
            settings.clone(),
            &data,
            s,
            false,
            &mut |done, _| bar.set_position(before + done as u64),
        )?;
        before += run.steps() as u64;
        runs.push(run);
    }
    bar.finish();
    let names: Vec<String> = subset
        .sequences
        .iter()
        .map(|s| s.info.name.clone())
        .collect();
    let ids: Vec<usize> = (0..names.len()).collect();
    // f16 states: the explorer only draws them, and the bundle has to download quickly.
    let bytes = io::runs_to_bytes(&model.config, &runs, &ids, Some(&names), true)?;
    io::write_atomic(&a.out.join("runs.safetensors"), &bytes)?;
    let manifest = BundleManifest {
        format: "pvrnn-bundle/1",
        description: a.description,
        model: "model.safetensors",
        dataset: pvrnn_dataset::MANIFEST,
        runs: "runs.safetensors",
    };
    io::write_atomic(
        &a.out.join("bundle.json"),
        serde_json::to_string_pretty(&manifest)?.as_bytes(),
    )?;
    eprintln!(
        "wrote {} ({} sequences with precomputed runs)",
        a.out.display(),
        names.len()
    );
    Ok(())
}
