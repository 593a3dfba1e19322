use std::path::{Path, PathBuf};

use anyhow::Result;
use pvrnn_core::{Model, io};

use crate::util;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// TOML configuration (fields left out keep the paper's values; see `pvrnn config`).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Number of training sequences S.
    #[arg(long)]
    sequences: usize,
    /// Steps per sequence T.
    #[arg(long)]
    steps: usize,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    #[arg(long)]
    out: PathBuf,
}

pub fn run(a: Args) -> Result<()> {
    let config = util::load_config(a.config.as_deref())?;
    let model = Model::<f32>::init(config, a.sequences, a.steps, a.seed)?;
    io::save_model(&a.out, &model)?;
    eprintln!(
        "wrote {} ({} sequences x {} steps, seed {})",
        a.out.display(),
        a.sequences,
        a.steps,
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
