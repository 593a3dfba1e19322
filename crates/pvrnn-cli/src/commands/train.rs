use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{Context, Result, bail};
use pvrnn_core::train::Trainer;
use pvrnn_core::{FreeEnergy, NoiseMode, io};

use crate::{inputs, util};
use pvrnn_dataset::Split;
use pvrnn_eval::training_log::TrainingLog;
use pvrnn_eval::validation;

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Example:\n  pvrnn train --model m.safetensors --inputs caresim/ --out run.safetensors --iterations 100000 --checkpoint-every 200 --keep-every 10000\n  pvrnn train --resume --inputs caresim/ --out run.safetensors --iterations 100000"
)]
pub struct Args {
    /// Model to start from (from `pvrnn init`); not needed with --resume.
    #[arg(long, required_unless_present = "resume")]
    model: Option<PathBuf>,
    /// Training inputs: a safetensors file (`x_extero`, `x_proprio`, optional `lengths`) or
    /// a dataset folder (its learning split; the model stores the proprioception ranges).
    #[arg(long)]
    inputs: PathBuf,
    /// Dataset split: learn (default), test or all.
    #[arg(long)]
    split: Option<String>,
    /// The run's checkpoint: written every --checkpoint-every iterations and at the end;
    /// it is also a model file. A CSV log goes next to it (`run.safetensors` -> `run.log.csv`).
    #[arg(long)]
    out: PathBuf,
    /// Total iterations, counted from the start of the run also with --resume (default: the
    /// configuration's `train.iterations`, the paper's 100,000).
    #[arg(long)]
    iterations: Option<u64>,
    /// Write the checkpoint every this many iterations (it is overwritten).
    #[arg(long, default_value_t = 100)]
    checkpoint_every: u64,
    /// Also keep a copy of the checkpoint every this many iterations, as
    /// `<out stem>.iter<N>.safetensors` beside --out (for evaluating a run as it goes).
    #[arg(long)]
    keep_every: Option<u64>,
    /// Seed of the noise draws.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// eps = 0 (deterministic learning; for debugging).
    #[arg(long)]
    zero_noise: bool,
    /// Learning rate of weights and adaptive variables (default: the model's configuration, the paper's 0.001).
    #[arg(long)]
    lr: Option<f64>,
    /// Continue the run saved in --out.
    #[arg(long)]
    resume: bool,
    /// Replace an existing --out instead of refusing.
    #[arg(long)]
    overwrite: bool,
    /// Held-out sequences for early stopping: a dataset folder none of whose sequences the
    /// run learns from (e.g. `pvrnn simulate --seed 1`). Every --validate-every iterations
    /// the run is scored on all of them (online inference with the lowest vision resolution
    /// and proprioception observed, one trial: the error of the highest resolution's
    /// reconstruction; diverged trials count first), the scores go to `<out
    /// stem>.validation.csv`, and the best checkpoint so far is kept as `<out
    /// stem>.best.safetensors`.
    #[arg(long)]
    validate: Option<PathBuf>,
    /// Validate every this many iterations (with --validate).
    #[arg(long, default_value_t = 5000, requires = "validate")]
    validate_every: u64,
    /// Stop early once this many validations in a row have not beaten the best one (with
    /// --validate; the best checkpoint is kept, the run's checkpoint stays resumable).
    #[arg(long, requires = "validate")]
    patience: Option<usize>,
    #[command(flatten)]
    backend: util::BackendArgs,
}

pub use pvrnn_eval::training_log::path_for as log_path;

/// Where `--keep-every` keeps the checkpoint of `iteration`: `run.safetensors` ->
/// `run.iter10000.safetensors`.
pub fn kept_path(out: &Path, iteration: u64) -> PathBuf {
    sibling(out, &format!("iter{iteration}.safetensors"))
}

/// `run.safetensors` -> `run.<suffix>` beside it.
fn sibling(out: &Path, suffix: &str) -> PathBuf {
    let stem = out
        .file_stem()
        .map_or_else(String::new, |s| s.to_string_lossy().into_owned());
    out.with_file_name(format!("{stem}.{suffix}"))
}

/// Where `--validate` keeps its scores and the best checkpoint.
pub fn validation_paths(out: &Path) -> (PathBuf, PathBuf) {
    (
        sibling(out, "validation.csv"),
        sibling(out, "best.safetensors"),
    )
}

/// Early stopping's state: the held-out data, the scores so far (of iterations up to the
/// checkpoint's: a resumed run forgets the rest) and the paths.
struct Validation {
    dataset: pvrnn_dataset::Dataset,
    every: u64,
    patience: Option<usize>,
    rows: Vec<validation::ValidationRow>,
    log: PathBuf,
    best: PathBuf,
}

impl Validation {
    fn open(
        dir: &Path,
        every: u64,
        patience: Option<usize>,
        out: &Path,
        trainer: &Trainer<f32>,
    ) -> Result<Self> {
        anyhow::ensure!(every >= 1, "--validate-every must be at least 1");
        anyhow::ensure!(patience != Some(0), "--patience must be at least 1");
        let dataset = pvrnn_dataset::Dataset::open(dir)
            .with_context(|| format!("--validate {}", dir.display()))?;
        // Now rather than at the first validation, hours into the run.
        let config = trainer.config();
        pvrnn_dataset::inputs::check_layout(&dataset.manifest, &config.vision)
            .and_then(|()| pvrnn_dataset::inputs::check_proprio(&dataset.manifest, config))
            .with_context(|| format!("--validate {}: the model does not fit it", dir.display()))?;
        let iteration = trainer.iteration;
        let (log, best) = validation_paths(out);
        let mut rows = validation::read_log(&log)?;
        rows.retain(|r| r.iteration <= iteration);
        Ok(Self {
            dataset,
            every,
            patience,
            rows,
            log,
            best,
        })
    }

    /// The best row, when --patience validations since have not beaten it.
    fn stalled(&self) -> Option<&validation::ValidationRow> {
        validation::stalled(&self.rows, self.patience?)
    }

    /// Whether the checkpoint's own iteration is due a validation that is not in the log
    /// (the run stopped during it).
    fn missed(&self, iteration: u64) -> bool {
        iteration > 0
            && iteration.is_multiple_of(self.every)
            && self.rows.last().map(|r| r.iteration) != Some(iteration)
    }

    /// Scores the trainer's model; keeps its checkpoint when it is the best so far.
    fn run(
        &mut self,
        trainer: &mut Trainer<f32>,
        last: Option<FreeEnergy>,
        bar: &util::Progress,
    ) -> Result<()> {
        bar.set_message("validating".into());
        let row = validation::validate(
            Arc::new(trainer.model().clone()),
            trainer.backend(),
            &self.dataset,
            trainer.iteration,
        )?;
        let is_best = validation::best(&self.rows).is_none_or(|b| row.better_than(b));
        bar.println(format!(
            "validation at iteration {}: reconstruction error {:.5} ({} of {} trials diverged, {:.0} s){}",
            row.iteration,
            row.recon_vision_top,
            row.failed_trials,
            row.trials,
            row.seconds,
            if is_best {
                format!("; best so far, kept {}", self.best.display())
            } else {
                String::new()
            }
        ));
        if is_best {
            io::save_checkpoint(&self.best, trainer, last)?;
        }
        self.rows.push(row);
        validation::write_log(&self.log, &self.rows)?;
        Ok(())
    }
}

pub fn run(a: Args) -> Result<()> {
    let (backend, backend_name) = a.backend.open()?;
    let mut trainer = open_trainer(&a)?.with_backend(backend);
    if a.backend.backend != util::BackendKind::Cpu {
        eprintln!("backend: {backend_name}");
    }
    let data = inputs::load(
        &a.inputs,
        a.split.as_deref(),
        Split::Learn,
        trainer.state_mut().0,
    )?
    .observations;
    if let Some(lr) = a.lr {
        set_lr(&mut trainer, lr)?;
    }
    pvrnn_core::free_energy::check_model_fits_data(trainer.model(), &data)?;
    anyhow::ensure!(
        a.checkpoint_every >= 1,
        "--checkpoint-every must be at least 1"
    );
    anyhow::ensure!(a.keep_every != Some(0), "--keep-every must be at least 1");
    let total = a.iterations.unwrap_or(trainer.config().train.iterations);
    let log = log_path(&a.out);
    let mut log_file = TrainingLog::resume(&log, trainer.iteration)?;
    let mut validation = a
        .validate
        .as_deref()
        .map(|dir| Validation::open(dir, a.validate_every, a.patience, &a.out, &trainer))
        .transpose()?;
    if let Some(dir) = &a.validate
        && std::fs::canonicalize(dir).ok() == std::fs::canonicalize(&a.inputs).ok()
    {
        eprintln!(
            "warning: --validate {} is the training data: early stopping needs sequences the run does not learn from",
            dir.display()
        );
    }

    let interrupted = Arc::new(AtomicBool::new(false));
    {
        let flag = interrupted.clone();
        ctrlc::set_handler(move || flag.store(true, Ordering::SeqCst))
            .context("cannot install the Ctrl-C / SIGTERM handler")?;
    }

    let bar = util::progress(total, "train");
    bar.set_position(trainer.iteration);
    let mut last: Option<FreeEnergy> = None;
    if let Some(v) = validation.as_mut()
        && v.missed(trainer.iteration)
    {
        v.run(&mut trainer, None, &bar)?;
    }
    while trainer.iteration < total {
        if let Some(best) = validation.as_ref().and_then(Validation::stalled) {
            bar.abandon();
            if last.is_some() {
                log_file.flush()?;
                io::save_checkpoint(&a.out, &mut trainer, last)?;
            }
            eprintln!(
                "stopped early at iteration {}: {} validations since iteration {} (error {:.5}, kept as {}) did not beat it",
                trainer.iteration,
                a.patience.unwrap_or(0),
                best.iteration,
                best.recon_vision_top,
                validation_paths(&a.out).1.display()
            );
            return Ok(());
        }
        let it = trainer.iteration;
        let report = trainer.step(&data)?;
        let resident = last.is_none().then(|| trainer.resident_tensors().len());
        if let Some(resident) = resident.filter(|&r| r > 0) {
            let all = trainer.trainable_tensors();
            bar.println(if resident == all {
                format!("on the GPU for the whole run: all {all} trainable tensors, so each iteration runs there whole")
            } else {
                format!("on the GPU for the whole run: {resident} of {all} trainable tensors (the rest updated on the CPU)")
            });
        }
        log_file.append(it, &report)?;
        last = Some(report);
        bar.set_position(trainer.iteration);
        bar.set_message(format!("F {:.4}", report.total));
        let stop = interrupted.load(Ordering::SeqCst);
        let keep = a.keep_every.is_some_and(|k| trainer.iteration % k == 0);
        if trainer.iteration % a.checkpoint_every == 0 || trainer.iteration == total || stop || keep
        {
            log_file.flush()?;
            io::save_checkpoint(&a.out, &mut trainer, last)?;
        }
        if keep {
            let kept = kept_path(&a.out, trainer.iteration);
            io::save_checkpoint(&kept, &mut trainer, last)?;
            bar.println(format!("kept {}", kept.display()));
        }
        if let Some(v) = validation.as_mut()
            && !stop
            && trainer.iteration.is_multiple_of(v.every)
        {
            v.run(&mut trainer, last, &bar)?;
            bar.set_message(format!("F {:.4}", report.total));
        }
        if stop {
            bar.abandon();
            eprintln!(
                "interrupted: checkpoint at iteration {} written to {}; continue with --resume",
                trainer.iteration,
                a.out.display()
            );
            std::process::exit(130);
        }
    }
    bar.finish();
    finished(&a.out, &log, trainer.iteration, last)
}

/// The run to continue (`--resume`), or a new one from `--model`.
fn open_trainer(a: &Args) -> Result<Trainer<f32>> {
    if a.resume {
        let t = io::load_checkpoint(&a.out).with_context(|| "cannot resume".to_string())?;
        eprintln!("resuming {} at iteration {}", a.out.display(), t.iteration);
        return Ok(t);
    }
    if a.out.exists() && !a.overwrite {
        bail!(
            "{} exists: pass --resume to continue that run or --overwrite to start over",
            a.out.display()
        );
    }
    let model = io::load_model(a.model.as_deref().expect("clap requires --model"))?;
    let noise = if a.zero_noise {
        NoiseMode::Zero
    } else {
        NoiseMode::Sampled { seed: a.seed }
    };
    Ok(Trainer::new(model, noise))
}

/// `--lr`: the learning rate of the model's configuration and of its optimiser.
fn set_lr(trainer: &mut Trainer<f32>, lr: f64) -> Result<()> {
    anyhow::ensure!(lr > 0.0 && lr.is_finite(), "--lr must be positive");
    let (model, optimizer) = trainer.state_mut();
    model.config.train.optimizer.lr = lr;
    optimizer.config.lr = lr;
    Ok(())
}

/// The end of a run: what was written, and the last iteration's free energy on stdout.
fn finished(out: &Path, log: &Path, iteration: u64, last: Option<FreeEnergy>) -> Result<()> {
    if last.is_none() {
        // Nothing to do (already at the requested iteration); keep the file as it is.
        eprintln!("{} is already at iteration {iteration}", out.display());
    } else {
        eprintln!(
            "wrote {} (iteration {iteration}), log {}",
            out.display(),
            log.display()
        );
    }
    if let Some(report) = last {
        println!("{}", serde_json::to_string(&report)?);
    }
    Ok(())
}
