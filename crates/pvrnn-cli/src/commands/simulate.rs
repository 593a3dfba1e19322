//! `pvrnn simulate`: the caresim benchmark as a dataset folder, with previews.

use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};

use anyhow::{Context, Result};
use caresim::{DatasetSpec, Task};
use pvrnn_dataset::{Dataset, preview, previews_dir};
use rayon::prelude::*;

use crate::util;

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Example:\n  pvrnn simulate --out caresim/\n  pvrnn simulate --out caresim-matched/ --variability matched --robot-free"
)]
pub struct Args {
    /// Dataset folder to write.
    #[arg(long)]
    out: PathBuf,
    /// Seed of every random choice (postures, timing, towel, wiping pattern, sensor noise):
    /// the same seed writes the same bytes.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Learning sequences per task and bed height (paper: 3).
    #[arg(long, default_value_t = 3)]
    learn_per_height: usize,
    /// Test sequences per task and bed height (paper: 1).
    #[arg(long, default_value_t = 1)]
    test_per_height: usize,
    /// Tasks (comma-separated): repositioning, wiping.
    #[arg(long, value_delimiter = ',', default_values_t = ["repositioning".to_string(), "wiping".to_string()])]
    tasks: Vec<String>,
    /// Bed heights in mm (paper: 590, 650, 710).
    #[arg(long, value_delimiter = ',', default_values_t = caresim::BED_HEIGHTS_MM)]
    heights: Vec<u32>,
    /// How much trials of a task differ: `paper` (wiping varies more than repositioning),
    /// `matched` (wiping shrunk to repositioning's trajectory spread: the control for the
    /// uncertainty and interference experiments), or factors such as
    /// `repositioning=1,wiping=0.5` (0 = every trial nominal, 1 = paper, at most 2).
    #[arg(long, default_value = "paper", value_parser = caresim::Variability::parse)]
    variability: caresim::Variability,
    /// Which edition of the benchmark: 1 (the November 2026 benchmark the shipped model
    /// learned: the wrists never turn, three torques carry only noise) or 2 (every joint
    /// moved and every torque loaded; docs/caresim.md, "Revisions").
    #[arg(long, default_value = "1", value_parser = caresim::Revision::parse)]
    revision: caresim::Revision,
    /// Also render every test frame without the robot (stored as `images_without_robot` in
    /// the test sequences' files), so that the hierarchy experiment can score what the
    /// model makes of body parts the arms hide. About a quarter more simulation time.
    #[arg(long)]
    robot_free: bool,
    /// Skip the contact sheets and animations.
    #[arg(long)]
    no_previews: bool,
}

pub fn run(a: Args) -> Result<()> {
    let tasks = a
        .tasks
        .iter()
        .map(|t| {
            Task::parse(t)
                .with_context(|| format!("unknown task `{t}` (tasks: repositioning, wiping)"))
        })
        .collect::<Result<Vec<_>>>()?;
    anyhow::ensure!(
        !a.heights.is_empty() && a.heights.iter().all(|&h| (300..=1200).contains(&h)),
        "--heights must be bed heights in mm between 300 and 1200"
    );
    let spec = DatasetSpec {
        seed: a.seed,
        tasks,
        bed_heights_mm: a.heights.clone(),
        learn_per_height: a.learn_per_height,
        test_per_height: a.test_per_height,
        variability: a.variability,
        revision: a.revision,
    };
    let trials = spec.trials();
    anyhow::ensure!(
        !trials.is_empty(),
        "nothing to simulate: every count is zero"
    );
    let bar = util::progress(trials.len() as u64, "simulate");
    let done = AtomicU64::new(0);
    let sequences: Vec<_> = trials
        .par_iter()
        .map(|trial| {
            let robot_free = a.robot_free && trial.split == pvrnn_dataset::Split::Test;
            let (seq, _) = caresim::simulate_with(trial, robot_free);
            bar.set_position(done.fetch_add(1, Ordering::Relaxed) + 1);
            seq
        })
        .collect();
    bar.finish();
    let source = source_text(a.seed, a.variability, a.revision);
    let dataset = Dataset::new(
        &source,
        vec!["left".into(), "right".into()],
        caresim::IMAGE_SIZE,
        sequences,
    )?;
    dataset.write(&a.out)?;
    if !a.no_previews {
        let dir = previews_dir(&a.out);
        std::fs::create_dir_all(&dir)
            .with_context(|| format!("{}: cannot create", dir.display()))?;
        dataset
            .sequences
            .par_iter()
            .try_for_each(|s| -> Result<()> {
                let stem = pvrnn_dataset::file_stem(&s.info.name);
                preview::write_contact_sheet(s, &dir.join(format!("{stem}.png")))?;
                preview::write_animation(s, &dir.join(format!("{stem}.gif")), 2, 10)?;
                Ok(())
            })?;
    }
    let steps: usize = dataset.sequences.iter().map(|s| s.len()).sum();
    eprintln!(
        "wrote {} ({} sequences, {steps} steps{})",
        a.out.display(),
        dataset.sequences.len(),
        if a.no_previews {
            ""
        } else {
            ", previews in previews/"
        }
    );
    Ok(())
}

/// The dataset's source: the revision-1 paper benchmark keeps the text of the trained
/// models' data (`caresim (seed 0)`); anything else names its settings.
fn source_text(
    seed: u64,
    variability: caresim::Variability,
    revision: caresim::Revision,
) -> String {
    let mut settings = vec![format!("seed {seed}")];
    if variability != caresim::Variability::PAPER {
        settings.push(format!("variability {}", variability.describe()));
    }
    let name = match revision {
        caresim::Revision::R1 => "caresim".to_string(),
        other => format!("caresim revision {other}"),
    };
    format!("{name} ({})", settings.join(", "))
}
