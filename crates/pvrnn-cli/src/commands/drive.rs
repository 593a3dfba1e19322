//! `pvrnn drive`: the network drives caresim's robot in closed loop (or a baseline does);
//! the episode as a dataset folder with the network's run and `drive.json`.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result};
use caresim::Task;
use pvrnn_core::io;
use pvrnn_drive::spec::{parse_speed_limit, speed_limit_text};
use pvrnn_drive::{Controller, Drive, DriveSpec, Occlusion, Perturbations, Push, VisionDrop};

use crate::condition::ConditionArgs;
use crate::util;

#[derive(clap::Args, Debug)]
#[command(after_help = "Example:\n  \
    pvrnn drive --model models/default --task repositioning --bed-height 650 --vision 16 --proprio on --out drive/\n  \
    pvrnn drive --model models/default --task wiping --bed-height 620 --push 120:right:0.2 --out pushed/\n  \
    pvrnn drive --controller mean-trajectory --task wiping --bed-height 650 --out mean/")]
pub struct Args {
    /// The network that drives: a model file, or a bundle folder (its model.safetensors).
    /// Not needed by `--controller mean-trajectory`.
    #[arg(long)]
    model: Option<PathBuf>,
    /// repositioning or wiping.
    #[arg(long)]
    task: String,
    /// The bed's height in mm (learned: 590, 650, 710; any other is a height the network
    /// never saw).
    #[arg(long, default_value_t = 650)]
    bed_height: u32,
    /// caresim's edition (1: what the shipped model learned; 2: every joint moved).
    #[arg(long, default_value = "1", value_parser = caresim::Revision::parse)]
    revision: caresim::Revision,
    /// Who drives: network (closed loop), prior (the network's prior generation, open
    /// loop) or mean-trajectory (the learning trials' mean joint angles, open loop).
    #[arg(long, default_value = "network")]
    controller: String,
    /// How fast the joints may move: scripted (2 rad a step, as the scripted trials) or
    /// panda (the Franka Panda's joint speeds, 0.22-0.26 rad a step).
    #[arg(long, default_value = "scripted")]
    speed_limit: String,
    /// The sensor noise's scale (1 = a recording's; 3 = proprioceptive noise x3).
    #[arg(long, default_value_t = 1.0)]
    sensor_noise: f64,
    /// Push an arm before a step: STEP:ARM:RADIANS (every joint of the arm turned), e.g.
    /// 120:left:0.2.
    #[arg(long)]
    push: Option<String>,
    /// Occlude a camera: CAMERA:FROM:STEPS (the camera shows mid-grey), e.g. left:100:30.
    #[arg(long)]
    occlude: Option<String>,
    /// Drop the network's vision mid-task: FROM:LEVELS, from step FROM on it observes only
    /// the lowest LEVELS resolutions (0: none), e.g. 120:1 (16x16 only).
    #[arg(long)]
    drop_vision: Option<String>,
    /// Folder to write the episode to (dataset.json, its sequence, runs.safetensors,
    /// drive.json).
    #[arg(long)]
    out: PathBuf,
    /// What the network observes and how it infers; `--seed` also picks the trial: the
    /// test trial of caresim's dataset of that seed at this bed height.
    #[command(flatten)]
    condition: ConditionArgs,
    #[command(flatten)]
    backend: util::BackendArgs,
}

/// A model file, or a bundle folder's.
fn model_path(path: &Path) -> PathBuf {
    if path.is_dir() {
        path.join("model.safetensors")
    } else {
        path.to_path_buf()
    }
}

pub fn run(a: Args) -> Result<()> {
    let task = Task::parse(&a.task)
        .with_context(|| format!("unknown task `{}` (tasks: repositioning, wiping)", a.task))?;
    let mut spec = DriveSpec::new(task, a.bed_height, a.condition.seed, a.revision);
    spec.controller = Controller::parse(&a.controller)?;
    spec.speed_limit = parse_speed_limit(&a.speed_limit)?;
    spec.perturbations = Perturbations {
        sensor_noise: a.sensor_noise,
        push: a.push.as_deref().map(Push::parse).transpose()?,
        occlusion: a.occlude.as_deref().map(Occlusion::parse).transpose()?,
        vision_drop: a
            .drop_vision
            .as_deref()
            .map(VisionDrop::parse)
            .transpose()?,
    };
    let (backend, _) = a.backend.open_for_inference("drive")?;
    let model = match (&a.model, spec.controller.uses_network()) {
        (Some(path), true) => {
            let path = model_path(path);
            let model = io::load_model(&path)
                .with_context(|| format!("{}: cannot load the model", path.display()))?;
            pvrnn_drive::check_model(&model.config)
                .with_context(|| format!("{} cannot drive caresim's robot", path.display()))?;
            Some(Arc::new(model))
        }
        (None, true) => anyhow::bail!(
            "the {} controller needs --model (only mean-trajectory drives without a network)",
            spec.controller.name()
        ),
        (_, false) => None,
    };
    let settings = model
        .as_ref()
        .map(|m| a.condition.settings(&m.config))
        .transpose()?;
    let network = model
        .clone()
        .zip(settings)
        .map(|(m, s)| (m, s, backend.as_ref()));
    let drive = Drive::start(spec, network)?;
    let trial = drive.trial().name();
    let bar = util::progress(drive.len() as u64, "drive");
    bar.set_message(trial.clone());
    let started = Instant::now();
    let episode = drive.finish(&mut |done, _| bar.set_position(done as u64))?;
    let seconds = started.elapsed().as_secs_f64();
    bar.finish();
    let steps = episode.sequence.len();
    let per_second = steps as f64 / seconds.max(1e-9);
    let condition = match (&model, &episode.run) {
        (Some(m), Some(run)) if run.settings.iterations == 0 && !run.settings.observed.proprio => {
            format!(
                "prior generation: nothing observed, no updates, H {}",
                run.settings.window
            )
        }
        (Some(m), Some(run)) => {
            let s = &run.settings;
            format!(
                "vision {}, proprio {}, H {}, {} iterations",
                s.observed.vision_label(&m.config),
                if s.observed.proprio { "on" } else { "off" },
                s.window,
                s.iterations
            )
        }
        _ => "no network".into(),
    };
    let extra = serde_json::json!({
        "model": a.model.as_ref().map(|p| p.display().to_string()),
        "condition": condition,
        "seconds": seconds,
        "steps_per_second": per_second,
        "threads": rayon::current_num_threads(),
    });
    episode.write(&a.out, model.as_ref().map(|m| &m.config), extra)?;
    eprintln!(
        "{trial} driven by the {} controller ({condition}; speed limit {}): {steps} steps in {seconds:.1} s, {per_second:.1} steps/s on {} threads",
        episode.spec.controller.name(),
        speed_limit_text(episode.spec.speed_limit),
        rayon::current_num_threads()
    );
    eprintln!("episode:       {}", episode.outcome.summary());
    eprintln!("demonstration: {}", episode.demonstration.summary());
    eprintln!("wrote {}", a.out.display());
    Ok(())
}
