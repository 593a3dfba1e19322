//! `pvrnn report`: learning curves from a training log, validation curves of one or more
//! runs, the error-against-iterations table from several evaluations of one run, the
//! index of a results folder, and the closed loop's success table and figure.

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
    /// The recipe search's table: per recipe, the checkpoint chosen on validation data and
    /// its validation errors (16x16 + proprioception; everything observed), diverged
    /// trials, training time and machine, from the files in each recipe's folder
    /// (run.validation.csv, run.log.csv, val-16/ and val-all/ evaluations, machine.txt).
    #[command(
        after_help = "Example:\n  pvrnn report recipes paper=docs/results/recipes/paper w-double=docs/results/recipes/w-double --out docs/results/recipes.md"
    )]
    Recipes {
        /// Recipes as NAME=FOLDER.
        #[arg(required = true)]
        recipes: Vec<String>,
        /// Write the table here instead of printing it.
        #[arg(long)]
        out: Option<PathBuf>,
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
    /// The index of a results folder, generated from its files: every experiment folder
    /// (plan.json, results/train-*.json, report/summary.json) with its trainings, the
    /// validity gate and its findings' readings, and every validation log.
    #[command(
        after_help = "Example:\n  pvrnn report index docs/results --out docs/results/index.md\n  pvrnn report index docs/results --out docs/results/index.md --check"
    )]
    Index {
        /// The results folder.
        root: PathBuf,
        /// Write the index here instead of printing it.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Only check that --out holds what would be written (exit status 1 if not).
        #[arg(long, requires = "out")]
        check: bool,
    },
    /// The closed loop's success table: every `pvrnn drive` episode folder under a
    /// directory, by task, condition and controller, with intervals.
    #[command(after_help = "Example:
  scripts/drive-table.sh models/default 1 runs/drive
  pvrnn report drive runs/drive --out runs/drive/table.md --figure runs/drive/success.png
  pvrnn report drive runs/drive-networks --networks --out table.md   # runs/drive-networks/net0/ ...")]
    Drive {
        /// A folder holding episode folders (each with a drive.json), at any depth.
        root: PathBuf,
        /// Write the table here instead of printing it.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Also draw the success rates as a PNG (and an SVG beside it): one group of bars
        /// per task and condition, one bar per controller, whiskers the 95% Wilson interval.
        #[arg(long)]
        figure: Option<PathBuf>,
        /// Each folder directly under ROOT holds one network's episodes (e.g. one
        /// `scripts/drive-table.sh` run each): also the statistics over networks, the unit
        /// (success rate mean ± SE over networks; the closed loop against each baseline,
        /// paired by network).
        #[arg(long)]
        networks: bool,
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
                let (name, file) = named(run)?;
                let rows = validation::read_log(std::path::Path::new(file))?;
                anyhow::ensure!(!rows.is_empty(), "{file}: no validations in it");
                read.push((name.to_string(), rows));
            }
            plots::validation_curves(&read, &title, &out)?;
            eprintln!("wrote {}", out.display());
        }
        Command::Recipes { recipes, out } => {
            let mut rows = Vec::new();
            for recipe in &recipes {
                let (name, dir) = named(recipe)?;
                rows.push(pvrnn_eval::recipes::read_recipe(
                    name,
                    std::path::Path::new(dir),
                )?);
            }
            write_or_print(out, &pvrnn_eval::recipes::markdown(&rows))?;
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
            write_or_print(out, &progress::markdown(&read))?;
        }
        Command::Index { root, out, check } => {
            let index = pvrnn_experiment::index::index(&root)?;
            match out {
                Some(out) if check => {
                    let written = std::fs::read_to_string(&out).unwrap_or_default();
                    anyhow::ensure!(
                        written == index,
                        "{} is not the index of {} as its files are now: run `pvrnn report index {} --out {}`",
                        out.display(),
                        root.display(),
                        root.display(),
                        out.display()
                    );
                    eprintln!("{} is up to date", out.display());
                }
                out => write_or_print(out, &index)?,
            }
        }
        Command::Drive {
            root,
            out,
            figure,
            networks,
        } => {
            let rows = pvrnn_drive::table::episodes(&root)?;
            let mut table = pvrnn_drive::table::markdown(&rows);
            if networks {
                let labelled: Vec<(String, pvrnn_drive::table::Row)> = rows
                    .iter()
                    .map(|r| (network_of(&root, &r.folder), r.clone()))
                    .collect();
                table = format!(
                    "{}\nEvery episode (each network's pooled):\n\n{table}",
                    pvrnn_experiment::closed_loop::markdown(&labelled)
                );
            }
            write_or_print(out, &table)?;
            if let Some(path) = figure {
                pvrnn_experiment::closed_loop::success_figure(
                    &pvrnn_drive::table::summarise(&rows),
                    &path,
                )?;
                eprintln!("wrote {} (and .svg)", path.display());
            }
        }
    }
    Ok(())
}

/// `NAME=PATH` -> (NAME, PATH).
fn named(arg: &str) -> Result<(&str, &str)> {
    arg.split_once('=')
        .filter(|(name, path)| !name.is_empty() && !path.is_empty())
        .with_context(|| {
            format!(
                "`{arg}`: name each run as NAME=FILE or NAME=FOLDER (e.g. paper=run.validation.csv)"
            )
        })
}

fn write_or_print(out: Option<PathBuf>, md: &str) -> Result<()> {
    match out {
        Some(path) => {
            pvrnn_core::io::write_atomic(&path, md.as_bytes())?;
            eprintln!("wrote {}", path.display());
        }
        None => print!("{md}"),
    }
    Ok(())
}

/// The folder directly under `root` that holds an episode: its network.
fn network_of(root: &std::path::Path, episode: &std::path::Path) -> String {
    episode
        .strip_prefix(root)
        .ok()
        .and_then(|p| p.components().next())
        .map_or_else(String::new, |c| {
            c.as_os_str().to_string_lossy().into_owned()
        })
}
