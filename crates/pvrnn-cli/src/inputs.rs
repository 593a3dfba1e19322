//! `--inputs`: an inputs safetensors file or a dataset folder.

use std::path::Path;

use anyhow::{Context, Result};
use pvrnn_core::{Model, Observations, io};
use pvrnn_dataset::{Dataset, Selection, Split};

/// Model inputs and, for dataset folders, the names of the chosen sequences.
pub struct Inputs {
    pub observations: Observations<f32>,
    pub names: Option<Vec<String>>,
}

/// Reads `path`: a safetensors inputs file as is, or a dataset folder's `split` sequences
/// (default `default_split`) scaled with the model's normalisation. A model without one
/// gets the dataset's learning-split ranges (the spec's rule), and a note says so.
pub fn load(
    path: &Path,
    split: Option<&str>,
    default_split: Split,
    model: &mut Model<f32>,
) -> Result<Inputs> {
    if !path.is_dir() {
        if let Some(s) = split {
            anyhow::bail!(
                "--split {s} applies to dataset folders, and {} is a file",
                path.display()
            );
        }
        return Ok(Inputs {
            observations: io::load_observations(path)?,
            names: None,
        });
    }
    let dataset = Dataset::open(path)?;
    let selection = parse_split(split, default_split)?;
    ensure_normalisation(model, &dataset, path)?;
    let sequences = dataset.select(&selection)?;
    let observations = dataset
        .observations(&sequences, &model.config)
        .with_context(|| format!("{} does not fit the model", path.display()))?;
    Ok(Inputs {
        observations,
        names: Some(sequences.iter().map(|s| s.info.name.clone()).collect()),
    })
}

/// `--split`: learn, test or all (default `default_split`).
pub fn parse_split(split: Option<&str>, default_split: Split) -> Result<Selection> {
    match split {
        Some(s) => {
            Selection::parse(s).with_context(|| format!("--split {s}: expected learn, test or all"))
        }
        None => Ok(Selection::Split(default_split)),
    }
}

/// A model without proprioception ranges gets the dataset's learning-split ranges (the
/// spec's rule), and a note says so.
pub fn ensure_normalisation(model: &mut Model<f32>, dataset: &Dataset, path: &Path) -> Result<()> {
    if pvrnn_dataset::inputs::ensure_normalisation(&mut model.config, dataset)? {
        eprintln!(
            "note: the model has no proprioception ranges; using {}'s learning split",
            path.display()
        );
    }
    Ok(())
}
