use std::path::PathBuf;

use anyhow::Result;
use pvrnn_core::free_energy::{NoiseDraw, free_energy};
use pvrnn_core::{NoiseMode, io};
use pvrnn_dataset::Split;

use crate::{inputs, util};

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Example:\n  pvrnn free-energy --model run.safetensors --inputs caresim/ --zero-noise\n  pvrnn free-energy --model m.safetensors --inputs x.safetensors --grads g.safetensors\n  pvrnn free-energy --model m.safetensors --inputs caresim/ --backend wgpu"
)]
pub struct Args {
    /// The model (or checkpoint) to evaluate.
    #[arg(long)]
    model: PathBuf,
    /// safetensors with `x_extero` [S, T, vision dims] and `x_proprio` [S, T, 28] (f32,
    /// normalised), or a dataset folder.
    #[arg(long)]
    inputs: PathBuf,
    /// Dataset split: learn (default), test or all.
    #[arg(long)]
    split: Option<String>,
    /// eps = 0 instead of seeded noise.
    #[arg(long)]
    zero_noise: bool,
    /// Seed of the noise draw.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Also write dF/d(every trainable tensor) here, named `grad.<tensor>`.
    #[arg(long)]
    grads: Option<PathBuf>,
    #[command(flatten)]
    backend: util::BackendArgs,
}

pub fn run(a: Args) -> Result<()> {
    let (backend, backend_name) = a.backend.open()?;
    if a.backend.backend != util::BackendKind::Cpu {
        eprintln!("backend: {backend_name}");
    }
    let mut model = io::load_model(&a.model)?;
    let data = inputs::load(&a.inputs, a.split.as_deref(), Split::Learn, &mut model)?.observations;
    let mode = if a.zero_noise {
        NoiseMode::Zero
    } else {
        NoiseMode::Sampled { seed: a.seed }
    };
    let (report, grads) = free_energy(
        backend.as_ref(),
        &model,
        &data,
        NoiseDraw::evaluation(mode),
        a.grads.is_some(),
    )?;
    if let (Some(path), Some(grads)) = (&a.grads, grads) {
        io::save_gradients(path, &grads, &model.config)?;
    }
    println!("{}", serde_json::to_string(&report)?);
    Ok(())
}
