use std::path::{Path, PathBuf};

use anyhow::Result;
use pvrnn_core::{Model, io};
use pvrnn_dataset::{Dataset, Selection, Split, proprio_ranges};

use crate::util;

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Example:\n  pvrnn init --dataset caresim/ --out m.safetensors --seed 1\n  pvrnn init --config my.toml --sequences 18 --steps 300 --out m.safetensors"
)]
pub struct Args {
    /// TOML configuration (fields left out keep the paper's values; see `pvrnn config`).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Number of training sequences S.
    #[arg(long, required_unless_present = "dataset")]
    sequences: Option<usize>,
    /// Steps per sequence T.
    #[arg(long, required_unless_present = "dataset")]
    steps: Option<usize>,
    /// Fit the model to a dataset folder: its cameras, image size (the largest vision
    /// level, keeping the configuration's number of levels) and proprioceptive channels,
    /// its learning split's S and longest T, and store its proprioception ranges.
    #[arg(long, conflicts_with_all = ["sequences", "steps"])]
    dataset: Option<PathBuf>,
    /// Seed of the weight initialisation and the fixed recurrent biases.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// The model file to write (safetensors).
    #[arg(long)]
    out: PathBuf,
}

pub fn run(a: Args) -> Result<()> {
    let mut config = util::load_config(a.config.as_deref())?;
    let (sequences, steps) = match &a.dataset {
        Some(dir) => {
            let dataset = Dataset::open(dir)?;
            let learn = dataset.select(&Selection::Split(Split::Learn))?;
            let fitted = pvrnn_dataset::inputs::fit_config(&config, &dataset.manifest)?;
            if fitted.vision != config.vision || fitted.proprio_dims != config.proprio_dims {
                eprintln!(
                    "fitted to the dataset: {} camera(s) at {:?} pixels, {} proprioceptive dimensions",
                    fitted.vision.cameras, fitted.vision.resolutions, fitted.proprio_dims
                );
            }
            config = fitted;
            config.normalisation = Some(proprio_ranges(&learn));
            (
                learn.len(),
                learn.iter().map(|s| s.len()).max().unwrap_or(0),
            )
        }
        None => (
            a.sequences.expect("clap requires it"),
            a.steps.expect("clap requires it"),
        ),
    };
    let model = Model::<f32>::init(config, sequences, steps, a.seed)?;
    io::save_model(&a.out, &model)?;
    eprintln!(
        "wrote {} ({sequences} sequences x {steps} steps, seed {})",
        a.out.display(),
        a.seed
    );
    Ok(())
}

pub fn print_config(model: Option<&Path>) -> Result<()> {
    let config = match model {
        Some(p) => io::load_model(p)?.config,
        None => pvrnn_core::ModelConfig::default(),
    };
    print!("{}", util::config_to_toml(&config));
    Ok(())
}
