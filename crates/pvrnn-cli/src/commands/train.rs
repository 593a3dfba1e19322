use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{Context, Result, bail};
use pvrnn_core::train::Trainer;
use pvrnn_core::{FreeEnergy, NoiseMode, io};

use crate::{inputs, util};
use pvrnn_dataset::Split;
use pvrnn_eval::early_stopping::{EarlyStopping, StoppingRule};
use pvrnn_eval::training_log::TrainingLog;
use pvrnn_eval::validation;

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Example:\n  pvrnn train --model m.safetensors --inputs caresim/ --out run.safetensors --iterations 100000 --checkpoint-every 200 --keep-every 10000\n  pvrnn train --resume --inputs caresim/ --out run.safetensors --iterations 100000\n  pvrnn train --model m0.safetensors --out run0.safetensors --model m1.safetensors --out run1.safetensors --inputs caresim/ --backend wgpu --gpu-recurrence"
)]
pub struct Args {
    /// Model to start from (from `pvrnn init`); not needed with --resume. Given several
    /// times (with as many --out, in the same order), the networks train together: every
    /// iteration of all of them is queued before the host waits for any, and with
    /// `--backend wgpu --gpu-recurrence` their recurrences run in one dispatch (docs/gpu.md).
    /// Network k draws its noise with seed --seed + k; each result is the one it gets alone.
    #[arg(long, required_unless_present = "resume")]
    model: Vec<PathBuf>,
    /// Training inputs: a safetensors file (`x_extero`, `x_proprio`, optional `lengths`) or
    /// a dataset folder (its learning split; the model stores the proprioception ranges).
    #[arg(long)]
    inputs: PathBuf,
    /// Dataset split: learn (default), test or all.
    #[arg(long)]
    split: Option<String>,
    /// The run's checkpoint: written every --checkpoint-every iterations and at the end;
    /// it is also a model file. A CSV log goes next to it (`run.safetensors` -> `run.log.csv`).
    /// One per network (see --model; with --resume, every run to continue).
    #[arg(long, required = true)]
    out: Vec<PathBuf>,
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
    /// Seed of the noise draws (network k of several: this + k).
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

/// Early stopping (`pvrnn_eval::early_stopping`, the experiments' type too) with the
/// command's messages; the best network is kept as a whole checkpoint.
struct Validation {
    stopping: EarlyStopping,
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
        let (log, best) = validation_paths(out);
        let rule = StoppingRule {
            every,
            patience,
            select_from: 0,
        };
        let stopping = EarlyStopping::open(dataset, rule, log, best, trainer.iteration)?;
        Ok(Self { stopping })
    }

    /// The best row, when --patience validations since have not beaten it.
    fn stalled(&self) -> Option<&validation::ValidationRow> {
        self.stopping.stalled()
    }

    /// Scores the trainer's model; keeps its checkpoint when it is the best so far.
    fn run(
        &mut self,
        trainer: &mut Trainer<f32>,
        last: Option<FreeEnergy>,
        bar: &util::Progress,
    ) -> Result<()> {
        bar.set_message("validating".into());
        let (row, is_best) = self.stopping.score(
            Arc::new(trainer.model().clone()),
            trainer.backend(),
            trainer.iteration,
        )?;
        bar.println(format!(
            "validation at iteration {}: reconstruction error {:.5} ({} of {} trials diverged, {:.0} s){}",
            row.iteration,
            row.recon_vision_top,
            row.failed_trials,
            row.trials,
            row.seconds,
            if is_best {
                format!("; best so far, kept {}", self.stopping.best_path().display())
            } else {
                String::new()
            }
        ));
        if is_best {
            io::save_checkpoint(self.stopping.best_path(), trainer, last)?;
        }
        self.stopping.record(row)?;
        Ok(())
    }
}

/// One network's run: its trainer, checkpoint, log and early stopping.
struct Run {
    out: PathBuf,
    log: PathBuf,
    log_file: TrainingLog,
    trainer: Trainer<f32>,
    validation: Option<Validation>,
    last: Option<FreeEnergy>,
    /// Why it stopped before the last iteration (early stopping), once it has.
    stopped: Option<String>,
}

pub fn run(a: Args) -> Result<()> {
    check_args(&a)?;
    let (backend, backend_name) = a.backend.open()?;
    let backend: Arc<dyn pvrnn_core::backend::Backend<f32>> = Arc::from(backend);
    if a.backend.backend != util::BackendKind::Cpu {
        eprintln!("backend: {backend_name}");
    }
    let mut trainers = Vec::with_capacity(a.out.len());
    for k in 0..a.out.len() {
        trainers.push(open_trainer(&a, k)?.with_backend(Box::new(backend.clone())));
    }
    let data = load_data(&a, &mut trainers)?;
    let total = a
        .iterations
        .unwrap_or(trainers[0].config().train.iterations);
    let mut runs = Vec::with_capacity(trainers.len());
    for (k, trainer) in trainers.into_iter().enumerate() {
        runs.push(open_run(&a, &a.out[k], trainer)?);
    }
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
    bar.set_position(runs.iter().map(|r| r.trainer.iteration).min().unwrap_or(0));
    for run in &mut runs {
        if let Some(v) = run.validation.as_mut()
            && v.stopping.missed(run.trainer.iteration)
        {
            v.run(&mut run.trainer, None, &bar)?;
        }
    }
    loop {
        for run in &mut runs {
            check_stalled(&a, run, total)?;
        }
        let mut active: Vec<&mut Run> = runs
            .iter_mut()
            .filter(|r| r.stopped.is_none() && r.trainer.iteration < total)
            .collect();
        if active.is_empty() {
            break;
        }
        let before: Vec<u64> = active.iter().map(|r| r.trainer.iteration).collect();
        // One dataset for all, or each network's own (another normalisation).
        let data_of: Vec<&pvrnn_core::Observations<f32>> = active
            .iter()
            .map(|r| &*data[runs_index(&a, &r.out).min(data.len() - 1)])
            .collect();
        let reports = {
            let mut trainers: Vec<&mut Trainer<f32>> =
                active.iter_mut().map(|r| &mut r.trainer).collect();
            pvrnn_core::train::step_together(&mut trainers, &data_of)?
        };
        let stop = interrupted.load(Ordering::SeqCst);
        for ((run, it), report) in active.into_iter().zip(before).zip(reports) {
            let report = report.with_context(|| run.out.display().to_string())?;
            after_step(&a, run, it, report, total, stop, &bar)?;
        }
        bar.set_position(runs.iter().map(|r| r.trainer.iteration).min().unwrap_or(0));
        if stop {
            bar.abandon();
            for run in &runs {
                eprintln!(
                    "interrupted: checkpoint at iteration {} written to {}; continue with --resume",
                    run.trainer.iteration,
                    run.out.display()
                );
            }
            std::process::exit(130);
        }
    }
    bar.finish();
    runs.into_iter().try_for_each(|run| match run.stopped {
        Some(why) => {
            eprintln!("{why}");
            Ok(())
        }
        None => finished(&run.out, &run.log, run.trainer.iteration, run.last),
    })
}

/// The arguments' combinations a run cannot take.
fn check_args(a: &Args) -> Result<()> {
    anyhow::ensure!(
        a.resume || a.model.len() == a.out.len(),
        "{} --model but {} --out: give one --out per network, in the same order",
        a.model.len(),
        a.out.len()
    );
    anyhow::ensure!(
        a.checkpoint_every >= 1,
        "--checkpoint-every must be at least 1"
    );
    anyhow::ensure!(a.keep_every != Some(0), "--keep-every must be at least 1");
    let mut outs: Vec<&PathBuf> = a.out.iter().collect();
    outs.sort();
    outs.dedup();
    anyhow::ensure!(
        outs.len() == a.out.len(),
        "every network needs its own --out"
    );
    Ok(())
}

/// Which network `out` is (its place among --out).
fn runs_index(a: &Args, out: &Path) -> usize {
    a.out.iter().position(|o| o == out).unwrap_or(0)
}

/// The training data, loaded once when every network reads it the same way (the same
/// configuration after the dataset's ranges), else once per network.
fn load_data(
    a: &Args,
    trainers: &mut [Trainer<f32>],
) -> Result<Vec<Arc<pvrnn_core::Observations<f32>>>> {
    let had_ranges: Vec<bool> = trainers
        .iter_mut()
        .map(|t| t.config().normalisation.is_some())
        .collect();
    let first = inputs::load(
        &a.inputs,
        a.split.as_deref(),
        Split::Learn,
        trainers[0].state_mut().0,
    )?
    .observations;
    let first_config = trainers[0].config().clone();
    let mut data = vec![Arc::new(first)];
    let mut shared = true;
    for (k, trainer) in trainers.iter_mut().enumerate().skip(1) {
        // Without ranges of its own a network takes the dataset's, as the first did.
        if !had_ranges[k] && !had_ranges[0] {
            trainer.state_mut().0.config.normalisation = first_config.normalisation.clone();
        }
        shared &= *trainer.config() == first_config;
    }
    if !shared {
        for trainer in trainers.iter_mut().skip(1) {
            let own = inputs::load(
                &a.inputs,
                a.split.as_deref(),
                Split::Learn,
                trainer.state_mut().0,
            )?;
            data.push(Arc::new(own.observations));
        }
    }
    for (k, trainer) in trainers.iter_mut().enumerate() {
        if let Some(lr) = a.lr {
            set_lr(trainer, lr)?;
        }
        pvrnn_core::free_energy::check_model_fits_data(
            trainer.model(),
            &data[k.min(data.len() - 1)],
        )?;
    }
    Ok(data)
}

/// A network's log and early stopping, opened at its trainer's iteration.
fn open_run(a: &Args, out: &Path, trainer: Trainer<f32>) -> Result<Run> {
    let log = log_path(out);
    let log_file = TrainingLog::resume(&log, trainer.iteration)?;
    let validation = a
        .validate
        .as_deref()
        .map(|dir| Validation::open(dir, a.validate_every, a.patience, out, &trainer))
        .transpose()?;
    Ok(Run {
        out: out.to_path_buf(),
        log,
        log_file,
        trainer,
        validation,
        last: None,
        stopped: None,
    })
}

/// Early stopping: once --patience validations have not beaten the best, a run short of
/// `total` iterations stops (its checkpoint written) and says why.
fn check_stalled(a: &Args, run: &mut Run, total: u64) -> Result<()> {
    // A run at its last iteration has finished, whatever its validations say.
    if run.stopped.is_some() || run.trainer.iteration >= total {
        return Ok(());
    }
    let Some(best) = run.validation.as_ref().and_then(Validation::stalled) else {
        return Ok(());
    };
    let why = format!(
        "stopped early at iteration {}: {} validations since iteration {} (error {:.5}, kept as {}) did not beat it",
        run.trainer.iteration,
        a.patience.unwrap_or(0),
        best.iteration,
        best.recon_vision_top,
        validation_paths(&run.out).1.display()
    );
    if run.last.is_some() {
        run.log_file.flush()?;
        io::save_checkpoint(&run.out, &mut run.trainer, run.last)?;
    }
    run.stopped = Some(why);
    Ok(())
}

/// After one iteration of `run` (from iteration `it`): the log, the progress line, a
/// checkpoint when due (or when stopping), a kept copy, a validation when due.
fn after_step(
    a: &Args,
    run: &mut Run,
    it: u64,
    report: FreeEnergy,
    total: u64,
    stop: bool,
    bar: &util::Progress,
) -> Result<()> {
    let trainer = &mut run.trainer;
    if run.last.is_none() && runs_index(a, &run.out) == 0 {
        say_what_is_resident(trainer, bar);
    }
    run.log_file.append(it, &report)?;
    run.last = Some(report);
    bar.set_message(format!("F {:.4}", report.total));
    let keep = a
        .keep_every
        .is_some_and(|k| trainer.iteration.is_multiple_of(k));
    if trainer.iteration.is_multiple_of(a.checkpoint_every)
        || trainer.iteration == total
        || stop
        || keep
    {
        run.log_file.flush()?;
        io::save_checkpoint(&run.out, trainer, run.last)?;
    }
    if keep {
        let kept = kept_path(&run.out, trainer.iteration);
        io::save_checkpoint(&kept, trainer, run.last)?;
        bar.println(format!("kept {}", kept.display()));
    }
    if let Some(v) = run.validation.as_mut()
        && !stop
        && v.stopping.due(trainer.iteration)
    {
        v.run(trainer, run.last, bar)?;
        bar.set_message(format!("F {:.4}", report.total));
    }
    Ok(())
}

/// After the first iteration: which tensors the backend keeps on its device.
fn say_what_is_resident(trainer: &Trainer<f32>, bar: &util::Progress) {
    let resident = trainer.resident_tensors().len();
    if resident == 0 {
        return;
    }
    let all = trainer.trainable_tensors();
    bar.println(if resident == all {
        format!("on the GPU for the whole run: all {all} trainable tensors, so each iteration runs there whole")
    } else {
        format!("on the GPU for the whole run: {resident} of {all} trainable tensors (the rest updated on the CPU)")
    });
}

/// Network `k`'s run to continue (`--resume`), or a new one from its `--model`.
fn open_trainer(a: &Args, k: usize) -> Result<Trainer<f32>> {
    let out = &a.out[k];
    if a.resume {
        let t = io::load_checkpoint(out).with_context(|| "cannot resume".to_string())?;
        eprintln!("resuming {} at iteration {}", out.display(), t.iteration);
        return Ok(t);
    }
    if out.exists() && !a.overwrite {
        bail!(
            "{} exists: pass --resume to continue that run or --overwrite to start over",
            out.display()
        );
    }
    let model = io::load_model(&a.model[k])?;
    let noise = if a.zero_noise {
        NoiseMode::Zero
    } else {
        NoiseMode::Sampled {
            seed: a.seed + k as u64,
        }
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
