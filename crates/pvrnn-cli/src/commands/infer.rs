use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{Context, Result};
use pvrnn_core::infer::run_sequence_on;
use pvrnn_core::io;

use crate::condition::ConditionArgs;
use crate::{inputs, util};
use pvrnn_dataset::Split;

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Example:\n  pvrnn infer --model run.safetensors --inputs caresim/ --out runs.safetensors --vision 16 --proprio on\n  pvrnn infer --model run.safetensors --inputs caresim/ --out abl.safetensors --ablate executive --ablation-mode readout"
)]
pub struct Args {
    /// The trained model (or a training checkpoint).
    #[arg(long)]
    model: PathBuf,
    /// Inputs: a safetensors file (`x_extero`, `x_proprio`, optional `lengths`, normalised)
    /// or a dataset folder (its test split unless --split says otherwise).
    #[arg(long)]
    inputs: PathBuf,
    /// Dataset split: test (default), learn or all.
    #[arg(long)]
    split: Option<String>,
    /// Per-step outputs of every sequence: reconstructions `recon.*`, one-step prior
    /// predictions `prior.*`, `<module>.{mu_p,sigma_p,mu_q,sigma_q,d}`, free energy terms.
    #[arg(long)]
    out: PathBuf,
    /// Which sequences (comma-separated indices); default all.
    #[arg(long, value_delimiter = ',')]
    sequences: Option<Vec<usize>>,
    #[command(flatten)]
    condition: ConditionArgs,
    /// Leave out the full read-outs (`recon.*`, `prior.*`: two vision vectors per step);
    /// they are the read-outs of the stored `d` and `prior_d`.
    #[arg(long)]
    compact: bool,
    #[command(flatten)]
    backend: util::BackendArgs,
}

pub fn run(a: Args) -> Result<()> {
    let (backend, backend_name) = a.backend.open_for_inference("infer")?;
    if a.backend.backend != util::BackendKind::Cpu {
        eprintln!("backend: {backend_name}");
    }
    let mut model = io::load_model(&a.model)?;
    let inputs = inputs::load(&a.inputs, a.split.as_deref(), Split::Test, &mut model)?;
    let (data, names) = (inputs.observations, inputs.names);
    let model = Arc::new(model);
    data.check_fits(&model.config)?;
    let config = &model.config;
    let settings = a.condition.settings(config)?;
    let which: Vec<usize> = a
        .sequences
        .unwrap_or_else(|| (0..data.sequences()).collect());
    let total: usize = which
        .iter()
        .map(|&s| data.lengths().get(s).copied().unwrap_or(0))
        .sum();
    let bar = util::progress(total as u64, "infer");
    let mut runs = Vec::with_capacity(which.len());
    let mut done_before = 0u64;
    for &s in &which {
        bar.set_message(format!("sequence {s}"));
        let run = run_sequence_on(
            backend.as_ref(),
            model.clone(),
            settings.clone(),
            &data,
            s,
            !a.compact,
            &mut |step, _| {
                if step.rate_halvings > 0 {
                    bar.println(format!(
                        "sequence {s}, step {}: the window diverged; restarted at lr / 2^{}",
                        step.t, step.rate_halvings
                    ));
                }
                bar.set_message(format!(
                    "sequence {s}, window F {:.4}",
                    step.window_free_energy.total
                ));
                bar.set_position(done_before + step.t as u64 + 1);
            },
        )
        .with_context(|| format!("sequence {s}"))?;
        done_before += run.steps() as u64;
        runs.push(run);
    }
    bar.finish();
    let chosen_names = names.map(|n| {
        which
            .iter()
            .filter_map(|&s| n.get(s).cloned())
            .collect::<Vec<_>>()
    });
    io::save_runs(&a.out, config, &runs, &which, chosen_names.as_deref())?;
    let mean_fe: f64 = runs
        .iter()
        .flat_map(|r| r.free_energy.iter().map(|f| f.total))
        .sum::<f64>()
        / total.max(1) as f64;
    eprintln!(
        "wrote {} ({} sequences, {} steps; vision {}, proprio {}, mean window free energy {:.5})",
        a.out.display(),
        runs.len(),
        total,
        settings.observed.vision_label(config),
        if settings.observed.proprio {
            "on"
        } else {
            "off"
        },
        mean_fe
    );
    Ok(())
}
