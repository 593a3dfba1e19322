//! `pvrnn report`: learning curves from a training log, validation curves of one or more
//! runs, and the error-against-iterations table from several evaluations of one run.

use std::path::PathBuf;

use anyhow::{Context, Result};
use pvrnn_eval::{plots, progress, validation};

#[derive(clap::Subcommand, Debug)]
pub enum Command {
    /// Learning curves (every free-energy term against the iteration) from a training log.
    #[command(
        after_help = "Example:\n  pvrnn report curves --log training/caresim-seed0.log.csv --out docs/results/curves.png"
    )]
    Curves {
        /// A `pvrnn train` log (`run.safetensors` -> `run.log.csv`).
        #[arg(long)]
        log: PathBuf,
        /// PNG to write.
        #[arg(long)]
        out: PathBuf,
        /// Title of the plot (default: the log's file name).
        #[arg(long)]
        title: Option<String>,
    },
    /// Validation curves: the held-out error `pvrnn train --validate` recorded against the
    /// iteration, for one or more runs (e.g. recipes compared), with the baselines.
    #[command(
        after_help = "Example:\n  pvrnn report validation paper=runs/paper.validation.csv data3x=runs/data3x.validation.csv --out docs/results/validation.png"
    )]
    Validation {
        /// Runs as NAME=FILE: a label and a `<run>.validation.csv`.
        #[arg(required = true)]
        runs: Vec<String>,
        /// PNG to write.
        #[arg(long)]
        out: PathBuf,
        /// Title of the plot.
        #[arg(
            long,
            default_value = "validation: reconstruction error of the unobserved top resolution"
        )]
        title: String,
    },
    /// Error against training iterations: one Markdown table per condition from the
    /// `summary.json` of several `pvrnn evaluate` runs on checkpoints of one training run.
    #[command(
        after_help = "Example:\n  pvrnn report table eval/iter*/*/ --out docs/results/progress.md"
    )]
    Table {
        /// Evaluation folders (each holding a summary.json) or summary.json files.
        #[arg(required = true)]
        evaluations: Vec<PathBuf>,
        /// Write the tables here instead of printing them.
        #[arg(long)]
        out: Option<PathBuf>,
    },
}

pub fn run(command: Command) -> Result<()> {
    match command {
        Command::Curves { log, out, title } => {
            let text = std::fs::read_to_string(&log)
                .with_context(|| format!("{}: cannot read the training log", log.display()))?;
            let title = title.unwrap_or_else(|| format!("learning curves: {}", log.display()));
            plots::training_curves(&text, &title, &out)
                .with_context(|| format!("{}", log.display()))?;
            eprintln!("wrote {}", out.display());
        }
        Command::Validation { runs, out, title } => {
            let mut read = Vec::new();
            for run in &runs {
                let (name, file) = run.split_once('=').with_context(|| {
                    format!("`{run}`: name each run as NAME=FILE (e.g. paper=run.validation.csv)")
                })?;
                let rows = validation::read_log(std::path::Path::new(file))?;
                anyhow::ensure!(!rows.is_empty(), "{file}: no validations in it");
                read.push((name.to_string(), rows));
            }
            plots::validation_curves(&read, &title, &out)?;
            eprintln!("wrote {}", out.display());
        }
        Command::Table { evaluations, out } => {
            let mut read = Vec::new();
            for path in evaluations {
                let file = if path.is_dir() {
                    path.join("summary.json")
                } else {
                    path
                };
                let text = std::fs::read_to_string(&file)
                    .with_context(|| format!("{}: cannot read", file.display()))?;
                read.push(progress::read_summary(&text, &file.display().to_string())?);
            }
            let md = progress::markdown(&read);
            match out {
                Some(path) => {
                    pvrnn_core::io::write_atomic(&path, md.as_bytes())?;
                    eprintln!("wrote {}", path.display());
                }
                None => print!("{md}"),
            }
        }
    }
    Ok(())
}
