//! `pvrnn`: the command-line face of the scalable PV-RNN.
//!
//! - This file: the subcommands and their dispatch.
//! - `commands`: one file per subcommand (`init` also serves `config`), each with its
//!   arguments and its `run`.
//! - `condition`: the inference condition flags `infer` and `evaluate` share.
//! - `inputs`: `--inputs`, an inputs file or a dataset folder.
//! - `util`: the thread pool, configuration files, progress bars, and the backend the
//!   flags choose (`--backend`, `--gpu-recurrence`, `--weights-on-host`).

mod commands;
mod condition;
mod inputs;
mod util;

use std::path::PathBuf;

use clap::{Parser, Subcommand};

#[derive(Parser, Debug)]
#[command(
    name = "pvrnn",
    version,
    about = "Scalable PV-RNN: learning and online inference for visuo-proprioceptive sequences"
)]
struct Cli {
    /// Worker threads (default: all cores).
    #[arg(long, global = true)]
    threads: Option<usize>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Create a freshly initialised model for S sequences of T steps.
    Init(commands::init::Args),
    /// Print a configuration as TOML: the paper's defaults, or a model's own (fields:
    /// docs/config.md).
    #[command(
        after_help = "Example:\n  pvrnn config > my.toml\n  pvrnn config --model run.safetensors"
    )]
    Config {
        /// Print this model's configuration instead of the defaults.
        #[arg(long)]
        model: Option<PathBuf>,
    },
    /// Free energy of a model on its training inputs, as JSON; optionally its gradients.
    FreeEnergy(commands::free_energy::Args),
    /// Learn: full-batch RAdam with checkpoints and resume.
    Train(commands::train::Args),
    /// Online inference (sliding-window error regression) on each sequence of the inputs.
    Infer(commands::infer::Args),
    /// Score online inference on a dataset split against baselines; a report with tables and plots.
    Evaluate(commands::evaluate::Args),
    /// Run one of the paper's experiments (plan, resumable jobs, statistics, report; Slurm).
    Experiment(commands::experiment::Args),
    /// Learning curves from a training log; error against iterations from several evaluations.
    #[command(subcommand)]
    Report(commands::report::Command),
    /// Time learning and online inference at the paper's scale on random data.
    Bench(commands::bench::Args),
    /// Write the caresim benchmark (repositioning and wiping) as a dataset folder.
    Simulate(commands::simulate::Args),
    /// Import real robot recordings (frames and a proprioception CSV) as a dataset folder.
    Import(commands::import::Args),
    /// Package a model, a dataset split and precomputed runs for the explorer.
    Bundle(commands::bundle::Args),
    /// Let the network drive caresim's robot in closed loop (or a baseline open loop); the
    /// episode as a dataset folder, scored by the pre-specified success criteria.
    Drive(commands::drive::Args),
}

fn main() {
    let cli = Cli::parse();
    if let Err(e) = util::set_threads(cli.threads) {
        eprintln!("error: {e:#}");
        std::process::exit(2);
    }
    let result = match cli.command {
        Command::Init(a) => commands::init::run(a),
        Command::Config { model } => commands::init::print_config(model.as_deref()),
        Command::FreeEnergy(a) => commands::free_energy::run(a),
        Command::Train(a) => commands::train::run(a),
        Command::Infer(a) => commands::infer::run(a),
        Command::Evaluate(a) => commands::evaluate::run(a),
        Command::Experiment(a) => commands::experiment::run(a),
        Command::Report(c) => commands::report::run(c),
        Command::Bench(a) => commands::bench::run(a),
        Command::Simulate(a) => commands::simulate::run(a),
        Command::Import(a) => commands::import::run(a),
        Command::Bundle(a) => commands::bundle::run(a),
        Command::Drive(a) => commands::drive::run(a),
    };
    if let Err(e) = result {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

#[cfg(test)]
mod tests {
    use clap::CommandFactory;

    /// Every command ends its help with an example, and every flag says what it is.
    #[test]
    fn every_command_has_an_example_and_every_flag_a_help() {
        let mut missing = Vec::new();
        let root = super::Cli::command();
        let mut commands: Vec<clap::Command> = root.get_subcommands().cloned().collect();
        while let Some(c) = commands.pop() {
            if c.has_subcommands() {
                commands.extend(c.get_subcommands().cloned());
                continue;
            }
            let example = c
                .get_after_help()
                .is_some_and(|h| h.to_string().starts_with("Example"));
            if !example {
                missing.push(format!("{}: no example", c.get_name()));
            }
            for arg in c.get_arguments() {
                let id = arg.get_id().as_str();
                if id == "help" || id == "version" {
                    continue;
                }
                if arg
                    .get_help()
                    .is_none_or(|h| h.to_string().trim().is_empty())
                {
                    missing.push(format!("{} --{id}: no help", c.get_name()));
                }
            }
        }
        assert!(missing.is_empty(), "{missing:#?}");
    }
}
