//! Running an experiment's jobs: trainings (resumable from their checkpoint, which is
//! written every `checkpoint_every` iterations and on interruption) and inference runs
//! (each scored into one result file). Jobs whose result exists are skipped, so running
//! again continues where a killed run stopped.

use std::collections::{BTreeMap, HashMap};

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use anyhow::{Context, Result, anyhow, bail, ensure};
use pvrnn_core::backend::Backend;
use pvrnn_core::infer::{InferenceSettings, OnlineInference};
use pvrnn_core::io::{self, OutTensor, TensorFile};
use pvrnn_core::train::Trainer;
use pvrnn_core::{Ablation, Model, ModelConfig, ModuleId, NoiseMode, Observed};
use pvrnn_dataset::{Dataset, Sequence, proprio_ranges};
use serde::{Deserialize, Serialize};

use pvrnn_eval::training_log::{self, TrainingLog};
use pvrnn_eval::validation::{self, ValidationRow};

use crate::occlusion::{OcclusionScorer, OcclusionScores};
use crate::plan::{Design, Job, JobKind, Plan};

/// What a running experiment reports.
#[derive(Debug)]
pub enum Event<'a> {
    Started {
        id: usize,
        name: &'a str,
    },
    /// A training's progress: iterations done of total, and the last free energy.
    Training {
        id: usize,
        done: u64,
        total: u64,
        free_energy: f64,
    },
    /// An inference run's progress: steps done of total.
    Inferring {
        id: usize,
        done: usize,
        total: usize,
    },
    Finished {
        id: usize,
        name: &'a str,
        seconds: f64,
    },
    /// An inference run diverged beyond repair at `step`: recorded, the report leaves it out.
    Diverged {
        id: usize,
        name: &'a str,
        step: usize,
    },
    /// Job `id` completed `part` of the design whose analysis runs before the whole plan
    /// is done (an interference direction, [`crate::report::completed_by`]), or else a
    /// network: its training and inference runs ([`crate::report::network_completed_by`]):
    /// the report was rebuilt (its `report.md`), or could not be (why). Sent by
    /// [`crate::reporting::run_with`].
    Reported {
        id: usize,
        part: &'a str,
        report: std::result::Result<&'a Path, &'a str>,
    },
}

/// Stopped on request (Ctrl-C, SIGTERM); checkpoints are written.
#[derive(Debug)]
pub struct Interrupted;

impl std::fmt::Display for Interrupted {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "interrupted; running the same command again resumes")
    }
}
impl std::error::Error for Interrupted {}

/// The result of a training job.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct TrainResult {
    pub job: String,
    pub network: usize,
    pub condition: String,
    pub sequences: usize,
    pub iterations: u64,
    pub final_free_energy: Option<f64>,
    /// Training seconds (summed over resumed runs; 0 for a reused checkpoint).
    pub seconds: f64,
    /// Relative change of the mean free energy between the second-to-last and the last
    /// tenth of the iterations: how flat the learning curve ended.
    pub last_tenth_change: Option<f64>,
    pub reused: Option<String>,
    /// What computed it: the backend and threads (`cpu, 2 threads`, `wgpu on NVIDIA H200
    /// (Vulkan), 2 threads`); absent in results written before it was recorded (all cpu).
    #[serde(default)]
    pub backend: Option<String>,
    /// Why training stopped, under a design with a convergence rule (absent: it trained
    /// the design's fixed iterations).
    #[serde(default)]
    pub stop: Option<Stop>,
    /// The iteration of the network the inference runs read (the best-validated
    /// checkpoint's, or `iterations`).
    #[serde(default)]
    pub network_iteration: Option<u64>,
    /// The validations of the convergence rule, in order.
    #[serde(default)]
    pub validations: Vec<ValidationRow>,
    /// Where it ran, as `pvrnn_eval::machine::describe` names a machine (its CPU, cores and
    /// threads; `backend` names a GPU): each validation's machine, then the one it finished
    /// on, in order, a stretch on one machine named once. Empty in results written before
    /// 2026-12-01 (their validations' rows name theirs) and for reused checkpoints.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub machines: Vec<String>,
}

/// Why a training under a convergence rule stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Stop {
    /// `patience` validations in a row did not beat the best: the best checkpoint is the
    /// network.
    ValidationBest,
    /// The free energy changed by less than `flat_change` over the last tenth.
    Flat,
    /// The cap was reached first: not converged (the best checkpoint is the network).
    Cap,
}

impl Stop {
    pub fn converged(self) -> bool {
        self != Stop::Cap
    }
}

impl TrainResult {
    /// The validity gate on the held-out validation of the network the inference runs
    /// read (`None`: no validation of it was recorded).
    pub fn gate(&self) -> Option<pvrnn_eval::gate::Gate> {
        let used = self.network_iteration.unwrap_or(self.iterations);
        self.validations
            .iter()
            .find(|v| v.iteration == used)
            .map(pvrnn_eval::gate::Gate::of)
    }

    /// Whether the network counts as converged: it stopped by the convergence rule, or
    /// (trained a fixed number of iterations) its free energy ended flat by `flat_change`.
    pub fn converged(&self, flat_change: f64) -> bool {
        match self.stop {
            Some(stop) => stop.converged(),
            None => self
                .last_tenth_change
                .is_some_and(|c| c.abs() < flat_change),
        }
    }
}

/// The validations `design`'s convergence rule counts: those from `Design::select_from`
/// on (`rows` in the order they ran).
pub fn counted<'r>(design: &Design, rows: &'r [ValidationRow]) -> &'r [ValidationRow] {
    rows_from(rows, design.select_from.unwrap_or(0))
}

/// The validations of `rows` (in the order they ran) at iteration `from` or later.
fn rows_from(rows: &[ValidationRow], from: u64) -> &[ValidationRow] {
    &rows[rows.partition_point(|r| r.iteration < from)..]
}

/// The convergence rule of `design`, checked at a validation (or the cap): `totals` is
/// the free energy per iteration so far, `rows` the validations so far.
pub fn convergence(
    design: &Design,
    totals: &[f64],
    rows: &[ValidationRow],
    iteration: u64,
) -> Option<Stop> {
    if design
        .patience
        .is_some_and(|p| validation::stalled(counted(design, rows), p).is_some())
    {
        return Some(Stop::ValidationBest);
    }
    if let Some(flat) = design.flat_change
        && last_tenth_change(totals).is_some_and(|c| c.abs() < flat)
    {
        return Some(Stop::Flat);
    }
    (iteration >= design.train_iterations).then_some(Stop::Cap)
}

/// The result of an inference job (metadata `result` of its safetensors file; contribution
/// maps as the f16 tensor `maps` [4 modules, top-level vision dims]).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct InferResult {
    pub job: String,
    pub network: usize,
    pub training: String,
    pub sequence: String,
    pub task: String,
    pub trial: usize,
    pub condition: String,
    pub steps: usize,
    /// Mean over steps of the reconstruction's MSE (model units, all dimensions of the
    /// group, observed or not): `vision<r>` per resolution, `joints`, `torques`,
    /// `proprio`.
    pub errors: BTreeMap<String, f64>,
    /// Per module: the mean prior sigma and the mean |change of prior sigma| between steps.
    pub sigma_p: [f64; 4],
    pub sigma_p_change: [f64; 4],
    /// Per step t >= 1: mean |mu_q(t) - mu_q(t-1)| of the executive module.
    pub executive_change: Vec<f64>,
    /// Subtask index per step.
    pub subtask: Vec<u32>,
    /// Per module: the mean |standard - ablated| of the top-resolution images (readout
    /// ablation), when maps were asked for.
    pub map_means: Option<[f64; 4]>,
    /// Steps per subtask phase, and per phase each module's mean contribution (maps runs;
    /// the per-phase maps, averaged over colour channels, are the f16 tensor `phase_maps`
    /// [phases, 4 modules, cameras x r x r]). Absent in results written before.
    #[serde(default)]
    pub phase_steps: Vec<usize>,
    #[serde(default)]
    pub phase_map_means: Option<Vec<Option<[f64; 4]>>>,
    /// Hidden body parts scored against the robot-free renders (runs on data that has
    /// them).
    #[serde(default)]
    pub occlusion: Option<OcclusionScores>,
    /// Set when online inference diverged beyond repair (`pvrnn_core::Error::Numerical`):
    /// the run stopped there, every figure above covers only the `steps` before it, and
    /// the report leaves the run out.
    #[serde(default)]
    pub diverged: Option<Diverged>,
    /// What computed it (as [`TrainResult::backend`]).
    #[serde(default)]
    pub backend: Option<String>,
}

/// Where and how an inference run diverged beyond repair.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Diverged {
    pub step: usize,
    pub message: String,
}

/// Datasets and trained networks shared by the jobs of one process.
#[derive(Default)]
struct Cache {
    dataset: Mutex<Option<Arc<Dataset>>>,
}

impl Cache {
    fn dataset(&self, dir: &Path) -> Result<Arc<Dataset>> {
        let mut slot = self.dataset.lock().map_err(|_| anyhow!("a job panicked"))?;
        if let Some(d) = slot.as_ref() {
            return Ok(d.clone());
        }
        let d = Arc::new(Dataset::open(dir)?);
        *slot = Some(d.clone());
        Ok(d)
    }
}

/// A sequence cut to its first `steps` steps.
fn truncated(seq: &Sequence, steps: Option<usize>) -> Sequence {
    let Some(steps) = steps.filter(|&s| s < seq.len()) else {
        return seq.clone();
    };
    let mut s = seq.clone();
    let per_step = |len: usize| len / seq.len().max(1);
    s.images.truncate(steps * per_step(seq.images.len()));
    if let Some(hidden) = s.images_without_robot.as_mut() {
        hidden.truncate(steps * per_step(seq.images.len()));
    }
    s.joints.truncate(steps * per_step(seq.joints.len()));
    s.torques.truncate(steps * per_step(seq.torques.len()));
    s.extra.truncate(steps * per_step(seq.extra.len()));
    s.subtask.truncate(steps);
    s.info.length = steps;
    s
}

fn sequences<'a>(dataset: &'a Dataset, names: &[String]) -> Result<Vec<&'a Sequence>> {
    names
        .iter()
        .map(|n| {
            dataset.by_name(n).ok_or_else(|| {
                anyhow!("the dataset has no sequence `{n}` (the plan was made for another dataset)")
            })
        })
        .collect()
}

/// Which of a plan's jobs a run does.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Selection {
    /// Every job not done yet.
    All,
    /// This one job (a cluster array task); its dependencies must be done.
    Job(usize),
    /// One network's jobs: each training, then its inference runs. Finishing networks one
    /// by one gives complete results early, and splits a run across sessions or machines.
    Network(usize),
}

impl Selection {
    fn includes(self, plan: &Plan, id: usize) -> bool {
        match self {
            Selection::All => true,
            Selection::Job(k) => k == id,
            Selection::Network(k) => plan.jobs[id].network() == k,
        }
    }

    /// The jobs of `plan` this selection covers.
    pub fn jobs(self, plan: &Plan) -> Vec<usize> {
        (0..plan.jobs.len())
            .filter(|&i| self.includes(plan, i))
            .collect()
    }
}

/// The next ready job of `selection` (its dependencies done; `state` holds which jobs are
/// done and which taken), with up to `cohort - 1` more ready trainings of its sequences;
/// marks them taken.
fn take_next(
    plan: &Plan,
    state: &Mutex<(Vec<bool>, Vec<bool>)>,
    selection: Selection,
    cohort: usize,
) -> Option<Vec<usize>> {
    let mut s = state.lock().ok()?;
    let (done, taken) = &mut *s;
    let ready = |i: usize| {
        selection.includes(plan, i)
            && !done[i]
            && !taken[i]
            && plan.jobs[i].after.iter().all(|&a| done[a])
    };
    let id = first_ready(&plan.jobs, ready)?;
    let mut ids = vec![id];
    ids.extend(
        (id + 1..plan.jobs.len())
            .filter(|&i| ready(i) && same_training(plan, id, i))
            .take(cohort.max(1) - 1),
    );
    for &i in &ids {
        taken[i] = true;
    }
    Some(ids)
}

/// The first ready job, an inference run before any training: a trained network's runs
/// follow it at once, so its results are complete (and can be committed without the
/// network) while the next training has not started; an interrupted campaign loses only
/// the trainings under way.
fn first_ready(jobs: &[Job], ready: impl Fn(usize) -> bool) -> Option<usize> {
    let infer = |i: &usize| matches!(jobs[*i].kind, JobKind::Infer { .. });
    let mut candidates = (0..jobs.len()).filter(|&i| ready(i));
    let first = candidates.next()?;
    if infer(&first) {
        return Some(first);
    }
    Some(candidates.find(infer).unwrap_or(first))
}

/// Whether `selection` names a network or a job of `plan`, and a job's dependencies are
/// done.
fn check_selection(plan: &Plan, dir: &Path, selection: Selection) -> Result<()> {
    if let Selection::Network(k) = selection {
        let networks = plan.jobs.iter().map(|j| j.network() + 1).max().unwrap_or(0);
        ensure!(
            k < networks,
            "--network {k}: the plan has networks 0..{}",
            networks.saturating_sub(1)
        );
    }
    if let Selection::Job(id) = selection {
        ensure!(
            id < plan.jobs.len(),
            "--job {id}: the plan has jobs 0..{}",
            plan.jobs.len().saturating_sub(1)
        );
        let missing: Vec<usize> = plan.jobs[id]
            .after
            .iter()
            .copied()
            .filter(|&a| !plan.is_done(dir, a))
            .collect();
        ensure!(
            missing.is_empty(),
            "job {id} needs jobs {missing:?} done first"
        );
    }
    Ok(())
}

/// How a run spreads its jobs: `jobs` at a time, and up to `cohort` trainings of the same
/// sequences (an experiment condition's networks) trained together in one of them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Workers {
    pub jobs: usize,
    pub cohort: usize,
}

/// Runs the selected jobs not done yet, `parallel` at a time, in dependency order.
///
/// `backend_name` says what computes (`cpu, 2 threads`); every result records it.
pub fn run(
    dir: &Path,
    backend: &Arc<dyn Backend<f32>>,
    backend_name: &str,
    parallel: usize,
    selection: Selection,
    stop: &AtomicBool,
    events: &(dyn Fn(Event<'_>) + Sync),
) -> Result<()> {
    let workers = Workers {
        jobs: parallel,
        cohort: 1,
    };
    run_with(dir, backend, backend_name, workers, selection, stop, events)
}

/// [`run`] with trainings in cohorts ([`Workers`]).
pub fn run_with(
    dir: &Path,
    backend: &Arc<dyn Backend<f32>>,
    backend_name: &str,
    workers: Workers,
    selection: Selection,
    stop: &AtomicBool,
    events: &(dyn Fn(Event<'_>) + Sync),
) -> Result<()> {
    let parallel = workers.jobs;
    let plan = Plan::load(dir)?;
    let cache = Cache::default();
    check_selection(&plan, dir, selection)?;
    if let Selection::Job(id) = selection {
        if !plan.is_done(dir, id) {
            run_jobs(
                &plan,
                dir,
                backend,
                backend_name,
                &[id],
                &cache,
                stop,
                events,
            )?;
        }
        return Ok(());
    }
    let state: Mutex<(Vec<bool>, Vec<bool>)> = Mutex::new((
        (0..plan.jobs.len()).map(|i| plan.is_done(dir, i)).collect(),
        vec![false; plan.jobs.len()],
    ));
    let failure: Mutex<Option<anyhow::Error>> = Mutex::new(None);
    let next = || take_next(&plan, &state, selection, workers.cohort);
    std::thread::scope(|scope| {
        for _ in 0..parallel.max(1) {
            scope.spawn(|| {
                loop {
                    if stop.load(Ordering::SeqCst)
                        || failure.lock().map(|f| f.is_some()).unwrap_or(true)
                    {
                        return;
                    }
                    let Some(ids) = next() else {
                        // Nothing ready: finished, or waiting on jobs other workers run.
                        let pending = state
                            .lock()
                            .map(|s| s.1.iter().zip(&s.0).any(|(t, d)| *t && !d))
                            .unwrap_or(false);
                        if !pending {
                            return;
                        }
                        std::thread::sleep(std::time::Duration::from_millis(50));
                        continue;
                    };
                    match run_jobs(
                        &plan,
                        dir,
                        backend,
                        backend_name,
                        &ids,
                        &cache,
                        stop,
                        events,
                    ) {
                        Ok(()) => {
                            if let Ok(mut s) = state.lock() {
                                for &id in &ids {
                                    s.0[id] = true;
                                }
                            }
                        }
                        Err(e) => {
                            let names: Vec<String> = ids
                                .iter()
                                .map(|&id| format!("{id} ({})", plan.jobs[id].name))
                                .collect();
                            if let Ok(mut f) = failure.lock() {
                                f.get_or_insert(e.context(format!("job {}", names.join(", "))));
                            }
                            if let Ok(mut s) = state.lock() {
                                for &id in &ids {
                                    s.1[id] = false;
                                }
                            }
                            return;
                        }
                    }
                }
            });
        }
    });
    if let Some(e) = failure
        .into_inner()
        .map_err(|_| anyhow!("a job panicked"))?
    {
        return Err(e);
    }
    if stop.load(Ordering::SeqCst) {
        return Err(Interrupted.into());
    }
    Ok(())
}

/// Runs jobs `ids`: one job, or several trainings of the same sequences trained together
/// (a cohort, [`train`]).
#[allow(clippy::too_many_arguments)]
fn run_jobs(
    plan: &Plan,
    dir: &Path,
    backend: &Arc<dyn Backend<f32>>,
    backend_name: &str,
    ids: &[usize],
    cache: &Cache,
    stop: &AtomicBool,
    events: &(dyn Fn(Event<'_>) + Sync),
) -> Result<()> {
    for &id in ids {
        events(Event::Started {
            id,
            name: &plan.jobs[id].name,
        });
    }
    let start = Instant::now();
    match &plan.jobs[ids[0]].kind {
        JobKind::Train { .. } => train(plan, dir, backend, backend_name, ids, cache, stop, events)?,
        JobKind::Infer { .. } => {
            for &id in ids {
                infer(plan, dir, backend, backend_name, id, cache, events)?;
            }
        }
    }
    for &id in ids {
        events(Event::Finished {
            id,
            name: &plan.jobs[id].name,
            seconds: start.elapsed().as_secs_f64(),
        });
    }
    Ok(())
}

/// Whether jobs `a` and `b` can train together: trainings of the same sequences, neither
/// reused from another's checkpoint.
fn same_training(plan: &Plan, a: usize, b: usize) -> bool {
    match (&plan.jobs[a].kind, &plan.jobs[b].kind) {
        (
            JobKind::Train {
                sequences: sa,
                reuse: None,
                ..
            },
            JobKind::Train {
                sequences: sb,
                reuse: None,
                ..
            },
        ) => sa == sb,
        _ => false,
    }
}

pub use pvrnn_eval::training_log::path_for as log_path;

/// Relative change of the mean of the last tenth of `values` against the tenth before.
pub fn last_tenth_change(values: &[f64]) -> Option<f64> {
    let tenth = values.len() / 10;
    if tenth == 0 {
        return None;
    }
    let n = values.len();
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let before = mean(&values[n - 2 * tenth..n - tenth]);
    let last = mean(&values[n - tenth..]);
    (before != 0.0).then(|| (last - before) / before.abs())
}

/// One training job in progress: its trainer, log, convergence rule and where it stops.
struct TrainingRun<'p> {
    plan: &'p Plan,
    dir: &'p Path,
    id: usize,
    iterations: u64,
    checkpoint: std::path::PathBuf,
    log: std::path::PathBuf,
    trainer: Trainer<f32>,
    log_file: TrainingLog,
    rule: Option<ConvergenceRule>,
    stop_reason: Option<Stop>,
    /// Whether the run reached its stop (the cap, or the convergence rule's).
    done: bool,
}

impl<'p> TrainingRun<'p> {
    /// Opens job `id` (a training that is not reused) at its checkpoint, or fresh, with its
    /// data (`data`: the job's sequences as the dataset gives them).
    fn open(
        plan: &'p Plan,
        dir: &'p Path,
        id: usize,
        backend: &Arc<dyn Backend<f32>>,
        dataset: &Dataset,
        chosen: &[Sequence],
    ) -> Result<Self> {
        let JobKind::Train {
            seed, iterations, ..
        } = &plan.jobs[id].kind
        else {
            unreachable!("a training job")
        };
        let checkpoint = plan.checkpoint_path(dir, id);
        let log = log_path(&checkpoint);
        let mut trainer = open_trainer(&checkpoint, dataset, chosen, *seed)?
            .with_backend(Box::new(backend.clone()));
        let log_file = TrainingLog::resume(&log, trainer.iteration)?;
        let mut rule = ConvergenceRule::open(
            plan,
            dir,
            id,
            (trainer.iteration, *iterations),
            &scored_tasks(plan, id, chosen),
        )?;
        if let Some(rule) = rule.as_mut()
            && rule.missed(trainer.iteration)
        {
            rule.validate(backend, &mut trainer)?;
        }
        let mut run = Self {
            plan,
            dir,
            id,
            iterations: *iterations,
            checkpoint,
            log,
            trainer,
            log_file,
            rule,
            stop_reason: None,
            done: false,
        };
        run.check_stop();
        Ok(run)
    }

    /// Whether the run stops before its next iteration (its cap, or the convergence rule).
    fn check_stop(&mut self) {
        if let Some(rule) = &self.rule {
            self.stop_reason = rule.check(&self.plan.design, &self.log, self.trainer.iteration);
        }
        self.done = self.stop_reason.is_some() || self.trainer.iteration >= self.iterations;
    }

    /// After an iteration that gave `report`: the log and the progress event.
    fn record(
        &mut self,
        it: u64,
        report: pvrnn_core::FreeEnergy,
        events: &(dyn Fn(Event<'_>) + Sync),
    ) -> Result<()> {
        self.log_file.append(it, &report)?;
        events(Event::Training {
            id: self.id,
            done: self.trainer.iteration,
            total: self.iterations,
            free_energy: report.total,
        });
        Ok(())
    }

    /// Then a checkpoint when one is due (or the run is `stopping`: interrupted), a
    /// validation when due, and whether the run goes on.
    fn checkpoint_and_validate(
        &mut self,
        report: pvrnn_core::FreeEnergy,
        backend: &Arc<dyn Backend<f32>>,
        stopping: bool,
    ) -> Result<()> {
        let validating = self.validating(stopping);
        let trainer = &mut self.trainer;
        if trainer
            .iteration
            .is_multiple_of(self.plan.design.checkpoint_every.max(1))
            || trainer.iteration == self.iterations
            || stopping
            || validating
        {
            self.log_file.flush()?;
            io::save_checkpoint(&self.checkpoint, trainer, Some(report))?;
        }
        if stopping {
            return Ok(());
        }
        if validating && let Some(rule) = self.rule.as_mut() {
            rule.validate(backend, trainer)?;
        }
        self.check_stop();
        Ok(())
    }

    /// Whether the run validates after this iteration (not when it is `stopping`).
    fn validating(&self, stopping: bool) -> bool {
        self.rule
            .as_ref()
            .is_some_and(|r| r.due(self.trainer.iteration))
            && !stopping
    }

    /// Writes the job's result (the run has stopped).
    fn finish(self, backend_name: &str) -> Result<()> {
        let job = &self.plan.jobs[self.id];
        let JobKind::Train {
            network,
            condition,
            sequences: names,
            ..
        } = &job.kind
        else {
            unreachable!("a training job")
        };
        let iteration = self.trainer.iteration;
        let mut stop_reason = self.stop_reason;
        if let Some(rule) = &self.rule
            && rule.stops
            && stop_reason.is_none()
        {
            // The job's iterations are the cap (the design's, when the plan was made).
            stop_reason = rule
                .check(&self.plan.design, &self.log, iteration)
                .or(Some(Stop::Cap));
        }
        let totals = training_log::totals(&self.log, iteration);
        let seconds = training_log::seconds(&self.log).unwrap_or(0.0);
        let validations = self.rule.map(|r| r.rows).unwrap_or_default();
        // The network: the best-validated checkpoint unless the free energy went flat first.
        let counted = counted(&self.plan.design, &validations);
        let network_iteration = match (stop_reason, validation::best(counted)) {
            (Some(Stop::ValidationBest | Stop::Cap), Some(best)) => best.iteration,
            _ => iteration,
        };
        write_train_result(
            self.plan,
            self.dir,
            self.id,
            TrainResult {
                job: job.name.clone(),
                network: *network,
                condition: condition.clone(),
                sequences: names.len(),
                iterations: iteration,
                final_free_energy: totals.last().copied(),
                seconds,
                last_tenth_change: last_tenth_change(&totals),
                reused: None,
                backend: Some(backend_name.to_string()),
                stop: stop_reason,
                network_iteration: Some(network_iteration),
                machines: machines_of(&validations, pvrnn_eval::machine::here()),
                validations,
            },
        )
    }
}

/// The machines of `validations` and then `last`, in order, each run of one machine once.
fn machines_of(validations: &[ValidationRow], last: String) -> Vec<String> {
    let mut machines: Vec<String> = Vec::new();
    let each = validations.iter().filter_map(|v| v.machine.clone());
    for machine in each.chain(std::iter::once(last)) {
        if machines.last() != Some(&machine) {
            machines.push(machine);
        }
    }
    machines
}

/// Training jobs `ids` (trainings of the same sequences, not reused: a cohort of seeds)
/// trained together, every iteration of all of them queued on the device before the host
/// waits for any (`pvrnn_core::train::step_together`); each stops by its own rule and the
/// others go on. A cohort of one is a training alone.
#[allow(clippy::too_many_arguments)]
fn train(
    plan: &Plan,
    dir: &Path,
    backend: &Arc<dyn Backend<f32>>,
    backend_name: &str,
    ids: &[usize],
    cache: &Cache,
    stop: &AtomicBool,
    events: &(dyn Fn(Event<'_>) + Sync),
) -> Result<()> {
    let Some(JobKind::Train {
        sequences: names,
        reuse,
        ..
    }) = ids.first().map(|&id| &plan.jobs[id].kind)
    else {
        unreachable!("training jobs")
    };
    for &id in ids {
        let checkpoint = plan.checkpoint_path(dir, id);
        std::fs::create_dir_all(checkpoint.parent().expect("a folder"))
            .with_context(|| format!("cannot create {}", checkpoint.display()))?;
    }
    let dataset = cache.dataset(&plan.dataset)?;
    let chosen: Vec<Sequence> = sequences(&dataset, names)?
        .into_iter()
        .map(|s| truncated(s, plan.design.train_steps))
        .collect();
    if let Some(source) = reuse {
        let tasks = scored_tasks(plan, ids[0], &chosen);
        return train_reused(plan, dir, ids[0], source, backend, &tasks);
    }
    let chosen_refs: Vec<&Sequence> = chosen.iter().collect();
    let mut runs = ids
        .iter()
        .map(|&id| TrainingRun::open(plan, dir, id, backend, &dataset, &chosen))
        .collect::<Result<Vec<_>>>()?;
    // One copy of the data for the cohort: its members learn the same sequences, and the
    // device keeps one copy of its targets.
    let data = dataset.observations(&chosen_refs, runs[0].trainer.config())?;
    for run in &mut runs {
        pvrnn_core::free_energy::check_model_fits_data(run.trainer.model(), &data)?;
    }
    // A run's result is written as soon as it stops; the others go on.
    let mut runs: Vec<Option<TrainingRun<'_>>> = runs.into_iter().map(Some).collect();
    loop {
        for slot in &mut runs {
            if slot.as_ref().is_some_and(|r| r.done)
                && let Some(run) = slot.take()
            {
                run.finish(backend_name)?;
            }
        }
        let mut active: Vec<&mut TrainingRun<'_>> = runs.iter_mut().flatten().collect();
        if active.is_empty() {
            return Ok(());
        }
        let before: Vec<u64> = active.iter().map(|r| r.trainer.iteration).collect();
        let reports = {
            let mut trainers: Vec<&mut Trainer<f32>> =
                active.iter_mut().map(|r| &mut r.trainer).collect();
            pvrnn_core::train::step_together(&mut trainers, &vec![&data; before.len()])?
        };
        // Every member's iteration is logged, then (the interruption flag read once for
        // all of them) checkpointed when due or interrupted, before an error (or the
        // interruption) ends the cohort.
        let mut failed = None;
        let mut recorded = Vec::with_capacity(active.len());
        for ((run, it), report) in active.into_iter().zip(before).zip(reports) {
            match report
                .with_context(|| format!("job {}", run.id))
                .and_then(|report| run.record(it, report, events).map(|()| report))
            {
                Ok(report) => recorded.push((run, report)),
                Err(e) => {
                    failed.get_or_insert(e);
                }
            }
        }
        let stopping = stop.load(Ordering::SeqCst);
        let outcomes = checkpoint_and_validate_side_by_side(recorded, backend, stopping);
        for outcome in outcomes {
            if let Err(e) = outcome {
                failed.get_or_insert(e);
            }
        }
        if stopping {
            failed.get_or_insert(Interrupted.into());
        }
        if let Some(e) = failed {
            return Err(e);
        }
    }
}

/// A cohort's members checkpoint and validate side by side: a validation is online
/// inference, latency-bound (round trips on a GPU), and the members reach theirs at the
/// same iteration. Each member's results are its own, as one after another. Threads only
/// then: most iterations validate nothing.
fn checkpoint_and_validate_side_by_side(
    recorded: Vec<(&mut TrainingRun<'_>, pvrnn_core::FreeEnergy)>,
    backend: &Arc<dyn Backend<f32>>,
    stopping: bool,
) -> Vec<Result<()>> {
    let validations = recorded
        .iter()
        .filter(|(run, _)| run.validating(stopping))
        .count();
    if validations > 1 {
        std::thread::scope(|scope| {
            let members: Vec<_> = recorded
                .into_iter()
                .map(|(run, report)| {
                    scope.spawn(move || run.checkpoint_and_validate(report, backend, stopping))
                })
                .collect();
            members
                .into_iter()
                .map(|m| {
                    m.join()
                        .unwrap_or_else(|panic| std::panic::resume_unwind(panic))
                })
                .collect()
        })
    } else {
        recorded
            .into_iter()
            .map(|(run, report)| run.checkpoint_and_validate(report, backend, stopping))
            .collect()
    }
}

/// The tasks training `id` is validated on: those its inference runs are scored on, of the
/// tasks it learns (all it learns where no run reads it). An interference network is so
/// validated on its primary task only: stopped on the error the experiment compares, not
/// on a few added sequences of the other task, which stop improving early (validated on
/// both, repositioning + 3 wiping sequences stopped at 8,000 iterations and used 4,000,
/// against 14,000 / 10,000 for repositioning alone: the comparison would be of training
/// lengths, not of interference).
fn scored_tasks<'a>(
    plan: &'a Plan,
    id: usize,
    chosen: &'a [Sequence],
) -> std::collections::BTreeSet<&'a str> {
    let learned: std::collections::BTreeSet<&str> =
        chosen.iter().map(|s| s.info.task.as_str()).collect();
    let scored: std::collections::BTreeSet<&str> = plan
        .jobs
        .iter()
        .filter_map(|j| match &j.kind {
            JobKind::Infer {
                train_job, task, ..
            } if *train_job == id => Some(task.as_str()),
            _ => None,
        })
        .filter(|t| learned.contains(t))
        .collect();
    if scored.is_empty() { learned } else { scored }
}

/// The plan's held-out dataset, its sequences of `tasks` only (`None` when the plan names
/// none).
fn held_out(plan: &Plan, tasks: &std::collections::BTreeSet<&str>) -> Result<Option<Dataset>> {
    let Some(data) = plan.validation_dataset.as_ref() else {
        return Ok(None);
    };
    let mut dataset =
        Dataset::open(data).with_context(|| format!("validation dataset {}", data.display()))?;
    dataset
        .manifest
        .sequences
        .retain(|s| tasks.contains(s.task.as_str()));
    dataset
        .sequences
        .retain(|s| tasks.contains(s.info.task.as_str()));
    ensure!(
        !dataset.sequences.is_empty(),
        "validation dataset {}: no sequence of the tasks the network learns ({})",
        data.display(),
        tasks.iter().copied().collect::<Vec<_>>().join(", ")
    );
    Ok(Some(dataset))
}

/// The convergence rule's state during one training: the held-out data, the validations
/// so far (up to the checkpoint's iteration: a resumed run forgets later ones) and where
/// the log and the best checkpoint go.
struct ConvergenceRule {
    dataset: Dataset,
    every: u64,
    /// Whether the rule stops the training (a convergence rule); without one, a design
    /// with held-out data validates its network once, at its last iteration, for the
    /// validity gate.
    stops: bool,
    /// `Design::select_from`: the first iteration whose validation may be the network.
    select_from: u64,
    rows: Vec<ValidationRow>,
    log: std::path::PathBuf,
    best: std::path::PathBuf,
}

impl ConvergenceRule {
    /// `tasks`: the tasks the network is validated on ([`scored_tasks`]); `last`: the
    /// training's last iteration.
    fn open(
        plan: &Plan,
        dir: &Path,
        id: usize,
        (iteration, last): (u64, u64),
        tasks: &std::collections::BTreeSet<&str>,
    ) -> Result<Option<Self>> {
        ensure!(
            plan.design.validate_every.is_none() || plan.validation_dataset.is_some(),
            "the {} design validates its networks, but the plan names no validation dataset",
            plan.scale.name()
        );
        let Some(dataset) = held_out(plan, tasks)? else {
            return Ok(None);
        };
        let (every, stops) = match plan.design.validate_every {
            Some(every) => (every, true),
            None => (last, false),
        };
        let log = plan.validation_log_path(dir, id);
        let mut rows = validation::read_log(&log)?;
        rows.retain(|r| r.iteration <= iteration);
        Ok(Some(Self {
            dataset,
            every: every.max(1),
            stops,
            select_from: plan.design.select_from.unwrap_or(0),
            rows,
            log,
            best: plan.best_path(dir, id),
        }))
    }

    fn due(&self, iteration: u64) -> bool {
        iteration > 0 && iteration.is_multiple_of(self.every)
    }

    /// The checkpoint's own iteration is due a validation the log lacks (stopped during it).
    fn missed(&self, iteration: u64) -> bool {
        self.due(iteration) && self.rows.last().map(|r| r.iteration) != Some(iteration)
    }

    fn check(&self, design: &Design, log: &Path, iteration: u64) -> Option<Stop> {
        if !self.stops || (!self.due(iteration) && iteration < design.train_iterations) {
            return None;
        }
        convergence(
            design,
            &training_log::totals(log, iteration),
            &self.rows,
            iteration,
        )
    }

    /// Validates the network; the best so far is kept as a model (inference reads it; the
    /// run resumes from its own checkpoint), a third of a checkpoint's size.
    fn validate(
        &mut self,
        backend: &Arc<dyn Backend<f32>>,
        trainer: &mut Trainer<f32>,
    ) -> Result<()> {
        let iteration = trainer.iteration;
        let model = Arc::new(trainer.model().clone());
        let row = validation::validate(model.clone(), backend.as_ref(), &self.dataset, iteration)?;
        let counted = rows_from(&self.rows, self.select_from);
        if iteration >= self.select_from
            && validation::best(counted).is_none_or(|b| row.better_than(b))
        {
            io::save_model_at(&self.best, &model, iteration)?;
        }
        self.rows.push(row);
        validation::write_log(&self.log, &self.rows)?;
        Ok(())
    }
}

/// The training's checkpoint to resume, or a new network for `chosen` (the paper's
/// configuration, normalised by all learning sequences of the dataset).
fn open_trainer(
    checkpoint: &Path,
    dataset: &Dataset,
    chosen: &[Sequence],
    seed: u64,
) -> Result<Trainer<f32>> {
    if checkpoint.is_file() {
        return io::load_checkpoint(checkpoint)
            .with_context(|| format!("{}: cannot resume", checkpoint.display()));
    }
    let mut config = ModelConfig::default();
    // One normalisation for every training condition: all learning sequences.
    let all_learn = dataset.split(Some(pvrnn_dataset::Split::Learn));
    config.normalisation = Some(proprio_ranges(&all_learn));
    let steps = chosen.iter().map(Sequence::len).max().unwrap_or(0);
    let model = Model::<f32>::init(config, chosen.len(), steps, seed)?;
    Ok(Trainer::new(model, NoiseMode::Sampled { seed }))
}

/// A training job whose network is a kept checkpoint of the same training: copied in, its
/// result read from the log it came with.
/// A reused network is validated once on the plan's held-out data, if it names any, so that
/// the validity gate can judge it.
fn train_reused(
    plan: &Plan,
    dir: &Path,
    id: usize,
    source: &Path,
    backend: &Arc<dyn Backend<f32>>,
    tasks: &std::collections::BTreeSet<&str>,
) -> Result<()> {
    let job = &plan.jobs[id];
    let JobKind::Train {
        network,
        condition,
        sequences: names,
        iterations,
        ..
    } = &job.kind
    else {
        unreachable!("a training job")
    };
    let checkpoint = plan.checkpoint_path(dir, id);
    let bytes = std::fs::read(source)
        .with_context(|| format!("{}: cannot read the reused checkpoint", source.display()))?;
    let file = TensorFile::from_bytes(bytes.clone(), source.display().to_string())?;
    ensure!(
        io::checkpoint_iteration(&file) == Some(*iterations),
        "{}: not a checkpoint at iteration {iterations}",
        source.display()
    );
    io::write_atomic(&checkpoint, &bytes)?;
    // The campaign's log: beside the checkpoint, or of the run a kept copy came from.
    let stem = source
        .file_stem()
        .map_or(String::new(), |s| s.to_string_lossy().into_owned());
    let run_stem = stem.split(".iter").next().unwrap_or(&stem).to_string();
    let totals = [
        log_path(source),
        source.with_file_name(format!("{run_stem}.log.csv")),
    ]
    .iter()
    .map(|p| training_log::totals(p, *iterations))
    .find(|t| !t.is_empty())
    .unwrap_or_default();
    let validations = match held_out(plan, tasks)? {
        Some(data) => {
            let model = Arc::new(io::load_model(&checkpoint)?);
            vec![validation::validate(
                model,
                backend.as_ref(),
                &data,
                *iterations,
            )?]
        }
        None => Vec::new(),
    };
    write_train_result(
        plan,
        dir,
        id,
        TrainResult {
            job: job.name.clone(),
            network: *network,
            condition: condition.clone(),
            sequences: names.len(),
            iterations: *iterations,
            final_free_energy: totals.last().copied(),
            seconds: 0.0,
            last_tenth_change: last_tenth_change(&totals),
            reused: Some(source.display().to_string()),
            backend: None,
            stop: None,
            network_iteration: Some(*iterations),
            machines: validations
                .iter()
                .filter_map(|v| v.machine.clone())
                .collect(),
            validations,
        },
    )
}

/// The trained network a training job's inference runs read: its best-validated
/// checkpoint when the convergence rule chose it, else the final checkpoint. A file that
/// holds the network of another iteration than the training's result names (a stale best
/// network left beside a checkpoint resumed from before it) is an error, not a silent
/// substitute.
pub fn network_path(plan: &Plan, dir: &Path, train_job: usize) -> Result<std::path::PathBuf> {
    let trained = read_train_result(&plan.result_path(dir, train_job))?;
    let used = trained.network_iteration.unwrap_or(trained.iterations);
    let path = if used != trained.iterations {
        plan.best_path(dir, train_job)
    } else {
        plan.checkpoint_path(dir, train_job)
    };
    let file = io::TensorFile::open(&path)
        .with_context(|| format!("{}: the trained network of job {train_job}", path.display()))?;
    if let Some(held) = io::checkpoint_iteration(&file)
        && held != used
    {
        bail!(
            "{} holds the network of iteration {held}, but job {train_job}'s result ({}) uses iteration {used}: the file is stale; train the job again (remove its result and checkpoints)",
            path.display(),
            plan.result_path(dir, train_job).display()
        );
    }
    Ok(path)
}

fn write_train_result(plan: &Plan, dir: &Path, id: usize, result: TrainResult) -> Result<()> {
    let path = plan.result_path(dir, id);
    std::fs::create_dir_all(path.parent().expect("a folder"))?;
    io::write_atomic(&path, serde_json::to_string_pretty(&result)?.as_bytes())?;
    Ok(())
}

/// The inference settings of a job under the design.
pub fn job_settings(
    design: &Design,
    config: &ModelConfig,
    trial: usize,
    vision_levels: usize,
    proprio: bool,
) -> InferenceSettings {
    let mut s = InferenceSettings::from_config(config, trial as u64);
    if let Some(h) = design.inference_window {
        s.window = h;
    }
    if let Some(n) = design.inference_iterations {
        s.iterations = n;
    }
    s.observed = Observed {
        vision_levels: vision_levels.min(config.vision.resolutions.len()),
        proprio,
    };
    s
}

fn mse(a: &[f32], b: &[f32]) -> f64 {
    let n = a.len().max(1) as f64;
    a.iter()
        .zip(b)
        .map(|(x, y)| ((x - y) as f64).powi(2))
        .sum::<f64>()
        / n
}

fn infer(
    plan: &Plan,
    dir: &Path,
    backend: &Arc<dyn Backend<f32>>,
    backend_name: &str,
    id: usize,
    cache: &Cache,
    events: &(dyn Fn(Event<'_>) + Sync),
) -> Result<()> {
    let job = &plan.jobs[id];
    let JobKind::Infer {
        network,
        train_job,
        training,
        sequence,
        task,
        trial,
        vision_levels,
        proprio,
        maps,
    } = &job.kind
    else {
        unreachable!("an inference job")
    };
    let shared = SharedRun::of(plan, dir, job)?;
    if !*maps && let Some(mut result) = shared.as_ref().and_then(SharedRun::read) {
        // The same run, done by another experiment: its scores, under this job's name.
        result.job = job.name.clone();
        result.map_means = None;
        result.phase_map_means = None;
        return write_infer_result(plan, dir, id, &result, None, shared.as_ref());
    }
    let model = Arc::new(io::load_model(&network_path(plan, dir, *train_job)?)?);
    let config = model.config.clone();
    let dataset = cache.dataset(&plan.dataset)?;
    let seq = truncated(
        sequences(&dataset, std::slice::from_ref(sequence))?[0],
        plan.design.test_steps,
    );
    let data = dataset.observations(&[&seq], &config)?;
    let settings = job_settings(&plan.design, &config, *trial, *vision_levels, *proprio);
    let mut inference = OnlineInference::with_backend(model.clone(), settings, backend.as_ref())?;
    if *maps {
        inference
            .set_readout_ablations(ModuleId::ALL.iter().map(|m| Ablation::of(&[*m])).collect());
    }
    let mut scores = RunScores::new(&config, *maps);
    let top = scores.top;
    let mut occlusion = occlusion_scorer(&seq, &dataset, &model, top)?;
    let mut prior_top: Option<Vec<f32>> = None;
    let mut steps = seq.len();
    let mut diverged = None;
    for t in 0..seq.len() {
        let x = data.step(pvrnn_core::Modality::Exteroceptive, 0, t);
        let p = data.step(pvrnn_core::Modality::Proprioceptive, 0, t);
        let out = match inference.step(x, p) {
            Ok(out) => out,
            // Not the job's failure: the network's, recorded so the report can say so.
            Err(pvrnn_core::Error::Numerical(message)) => {
                events(Event::Diverged {
                    id,
                    name: &job.name,
                    step: t,
                });
                diverged = Some(Diverged { step: t, message });
                steps = t;
                break;
            }
            Err(e) => return Err(e.into()),
        };
        if let Some((truth, scorer)) = occlusion.as_mut() {
            let truth = truth.step(pvrnn_core::Modality::Exteroceptive, 0, t);
            scorer.step(
                &x[top.0..top.1],
                &truth[top.0..top.1],
                &out.recon[0][top.0..top.1],
                prior_top.as_deref(),
            );
        }
        prior_top = Some(out.prior_next[0][top.0..top.1].to_vec());
        let phase = seq.subtask.get(t).copied().unwrap_or(0) as usize;
        scores.step(&config, &out, x, p, phase);
        events(Event::Inferring {
            id,
            done: t + 1,
            total: steps,
        });
    }
    let finished = scores.finish(steps);
    let result = InferResult {
        job: job.name.clone(),
        network: *network,
        training: training.clone(),
        sequence: sequence.clone(),
        task: task.clone(),
        trial: *trial,
        condition: Plan::condition_label(*vision_levels, *proprio),
        steps,
        errors: finished.errors,
        sigma_p: finished.sigma_p,
        sigma_p_change: finished.sigma_p_change,
        executive_change: finished.executive_change,
        subtask: seq.subtask[..steps].to_vec(),
        map_means: finished.map_means,
        phase_steps: finished.phase_steps,
        phase_map_means: finished.phase_map_means,
        occlusion: occlusion.and_then(|(_, scorer)| scorer.finish()),
        diverged,
        backend: Some(backend_name.to_string()),
    };
    let maps = maps.then_some((finished.maps.as_slice(), finished.phase_maps.as_slice()));
    write_infer_result(plan, dir, id, &result, maps, shared.as_ref())
}

/// Occlusion: the run's robot-free inputs and the scorer, where the data has them.
fn occlusion_scorer(
    seq: &Sequence,
    dataset: &Dataset,
    model: &Model<f32>,
    top: (usize, usize),
) -> Result<Option<(pvrnn_core::Observations<f32>, OcclusionScorer)>> {
    let Some(hidden) = seq.without_robot() else {
        return Ok(None);
    };
    let truth = dataset.observations(&[&hidden], &model.config)?;
    let mean = pvrnn_eval::baselines::learning_mean(dataset, model)?;
    Ok(Some((
        truth,
        OcclusionScorer::new(mean[0][top.0..top.1].to_vec()),
    )))
}

/// What an inference run accumulates step by step, apart from occlusion: the
/// reconstruction errors, prior sigma and its change, the executive module's latent
/// change, and (runs with maps) each module's contribution, over the run and per phase.
struct RunScores {
    /// The top resolution's range of the vision dimensions.
    top: (usize, usize),
    maps: bool,
    errors: BTreeMap<String, f64>,
    sigma: [f64; 4],
    sigma_change: [f64; 4],
    executive_change: Vec<f64>,
    /// The previous step's prior sigma per module and executive mu_q.
    previous: Option<([Vec<f32>; 4], Vec<f32>)>,
    map_sums: Vec<Vec<f64>>,
    /// Per subtask phase: its steps, and each module's map averaged over colour channels.
    phase_sums: Vec<(usize, Vec<Vec<f64>>)>,
}

/// A run's scores, averaged over its steps.
struct FinishedScores {
    errors: BTreeMap<String, f64>,
    sigma_p: [f64; 4],
    sigma_p_change: [f64; 4],
    executive_change: Vec<f64>,
    map_means: Option<[f64; 4]>,
    phase_steps: Vec<usize>,
    phase_map_means: Option<Vec<Option<[f64; 4]>>>,
    /// The maps themselves: [module][value] and [phase][module][pixel].
    maps: Vec<Vec<f32>>,
    phase_maps: Vec<Vec<Vec<f32>>>,
}

fn mean_abs_difference(a: &[f32], b: &[f32]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(a, b)| (a - b).abs() as f64)
        .sum::<f64>()
        / a.len().max(1) as f64
}

impl RunScores {
    fn new(config: &ModelConfig, maps: bool) -> Self {
        let layout = &config.vision;
        let levels = layout.resolutions.len();
        let top = (layout.level_offset(levels - 1), layout.level_offset(levels));
        Self {
            top,
            maps,
            errors: BTreeMap::new(),
            sigma: [0.0; 4],
            sigma_change: [0.0; 4],
            executive_change: Vec::new(),
            previous: None,
            map_sums: vec![vec![0f64; top.1 - top.0]; if maps { 4 } else { 0 }],
            phase_sums: Vec::new(),
        }
    }

    fn step(
        &mut self,
        config: &ModelConfig,
        out: &pvrnn_core::infer::StepOutput<f32>,
        x: &[f32],
        p: &[f32],
        phase: usize,
    ) {
        let layout = &config.vision;
        let joints = config.proprio_dims / 2;
        for level in 0..layout.resolutions.len() {
            let (a, b) = (layout.level_offset(level), layout.level_offset(level + 1));
            *self
                .errors
                .entry(format!("vision{}", layout.resolutions[level]))
                .or_default() += mse(&out.recon[0][a..b], &x[a..b]);
        }
        let errors = &mut self.errors;
        *errors.entry("joints".into()).or_default() += mse(&out.recon[1][..joints], &p[..joints]);
        *errors.entry("torques".into()).or_default() += mse(&out.recon[1][joints..], &p[joints..]);
        *errors.entry("proprio".into()).or_default() += mse(&out.recon[1], p);
        for (m, module) in out.modules.iter().enumerate() {
            let n = module.sigma_p.len().max(1) as f64;
            self.sigma[m] += module.sigma_p.iter().map(|v| *v as f64).sum::<f64>() / n;
            if let Some((prev_sigma, _)) = &self.previous {
                self.sigma_change[m] += mean_abs_difference(&module.sigma_p, &prev_sigma[m]);
            }
        }
        let exec = &out.modules[ModuleId::Executive.index()].mu_q;
        if let Some((_, prev_exec)) = &self.previous {
            self.executive_change
                .push(mean_abs_difference(exec, prev_exec));
        }
        self.previous = Some((
            std::array::from_fn(|m| out.modules[m].sigma_p.clone()),
            exec.clone(),
        ));
        self.add_maps(out, phase);
    }

    /// Each module's |standard - ablated| top-resolution read-out, over the run and in the
    /// step's subtask phase.
    fn add_maps(&mut self, out: &pvrnn_core::infer::StepOutput<f32>, phase: usize) {
        if !self.maps {
            return;
        }
        let (a0, a1) = self.top;
        if self.phase_sums.len() <= phase {
            let pixels = (a1 - a0) / 3;
            self.phase_sums
                .resize_with(phase + 1, || (0, vec![vec![0f64; pixels]; 4]));
        }
        let (steps_in_phase, phase_sums) = &mut self.phase_sums[phase];
        *steps_in_phase += 1;
        let standard = &out.recon[0][a0..a1];
        for (m, ablated) in out.ablated_recon.iter().enumerate() {
            let ablated = &ablated[0][a0..a1];
            for ((sum, a), b) in self.map_sums[m].iter_mut().zip(ablated).zip(standard) {
                *sum += (a - b).abs() as f64;
            }
            for (sum, (a, b)) in phase_sums[m]
                .iter_mut()
                .zip(ablated.chunks(3).zip(standard.chunks(3)))
            {
                *sum += mean_abs_difference(a, b);
            }
        }
    }

    fn finish(self, steps: usize) -> FinishedScores {
        let n = steps.max(1) as f64;
        let changes = steps.saturating_sub(1).max(1) as f64;
        let maps: Vec<Vec<f32>> = self
            .map_sums
            .iter()
            .map(|m| m.iter().map(|v| (v / n) as f32).collect())
            .collect();
        let phase_maps: Vec<Vec<Vec<f32>>> = self
            .phase_sums
            .iter()
            .map(|(k, sums)| {
                sums.iter()
                    .map(|m| m.iter().map(|v| (v / (*k).max(1) as f64) as f32).collect())
                    .collect()
            })
            .collect();
        let mean = |v: &[f32]| v.iter().map(|v| *v as f64).sum::<f64>() / v.len().max(1) as f64;
        FinishedScores {
            errors: self.errors.into_iter().map(|(k, v)| (k, v / n)).collect(),
            sigma_p: self.sigma.map(|v| v / n),
            sigma_p_change: self.sigma_change.map(|v| v / changes),
            executive_change: self.executive_change,
            map_means: self.maps.then(|| std::array::from_fn(|m| mean(&maps[m]))),
            phase_steps: self.phase_sums.iter().map(|(k, _)| *k).collect(),
            // A label that never occurs: no steps, no contribution (not 0).
            phase_map_means: self.maps.then(|| {
                phase_maps
                    .iter()
                    .zip(&self.phase_sums)
                    .map(|(p, (k, _))| (*k > 0).then(|| std::array::from_fn(|m| mean(&p[m]))))
                    .collect()
            }),
            maps,
            phase_maps,
        }
    }
}

/// An inference run's contribution maps: time-averaged [module][value], and per phase
/// [phase][module][pixel].
type MapsToWrite<'a> = (&'a [Vec<f32>], &'a [Vec<Vec<f32>>]);

/// Writes an inference job's result file (and, when the run is shared, the shared copy).
fn write_infer_result(
    plan: &Plan,
    dir: &Path,
    id: usize,
    result: &InferResult,
    maps: Option<MapsToWrite<'_>>,
    shared: Option<&SharedRun>,
) -> Result<()> {
    let mut tensors = BTreeMap::new();
    // f16: pictures need no more, and it halves the results a run commits.
    let f16 = |v: Vec<f32>| -> Vec<half::f16> { v.into_iter().map(half::f16::from_f32).collect() };
    if let Some((maps, phases)) = maps {
        let width = maps.first().map_or(0, Vec::len);
        tensors.insert(
            "maps".to_string(),
            OutTensor::F16(vec![4, width], f16(maps.concat())),
        );
        if !phases.is_empty() {
            let width = phases[0].first().map_or(0, Vec::len);
            let rows = phases.iter().flatten().cloned().collect::<Vec<_>>();
            tensors.insert(
                "phase_maps".to_string(),
                OutTensor::F16(vec![phases.len(), 4, width], f16(rows.concat())),
            );
        }
    }
    let mut metadata = HashMap::from([
        (
            "format".to_string(),
            "pvrnn-experiment-result/1".to_string(),
        ),
        ("result".to_string(), serde_json::to_string(result)?),
    ]);
    if let Some(shared) = shared {
        metadata.insert("network".to_string(), shared.network.clone());
    }
    let bytes = io::to_bytes(&tensors, metadata)?;
    let path = plan.result_path(dir, id);
    std::fs::create_dir_all(path.parent().expect("a folder"))?;
    io::write_atomic(&path, &bytes)?;
    if let Some(shared) = shared
        && !shared.path.is_file()
    {
        std::fs::create_dir_all(shared.path.parent().expect("a folder"))?;
        io::write_atomic(&shared.path, &bytes)?;
    }
    Ok(())
}

/// Part of a kept run's identity: runs kept before occlusion was scored relative to the
/// observed frame (and on the prior) in every run are not reused.
const SCORES_VERSION: &str = "; scores 2";

/// An inference run as experiments sharing a networks folder see it. The same network,
/// test sequence, trial (noise seed), observed modalities and inference settings give the
/// same run in every experiment (hierarchy's runs with everything observed are
/// uncertainty's, and robustness's "64 (all), proprioception on" ones: the contribution
/// maps are read out after each step and change nothing), so it is computed once and kept
/// in `<networks>/runs/`; a job without maps takes it from there.
struct SharedRun {
    path: std::path::PathBuf,
    /// The trained network's identity (its iterations and final free energy): a network
    /// trained again after a run was kept does not reuse that run.
    network: String,
}

impl SharedRun {
    fn of(plan: &Plan, dir: &Path, job: &crate::plan::Job) -> Result<Option<Self>> {
        let (
            Some(networks),
            JobKind::Infer {
                train_job,
                sequence,
                trial,
                vision_levels,
                proprio,
                ..
            },
        ) = (&plan.networks_dir, &job.kind)
        else {
            return Ok(None);
        };
        let checkpoint = plan.checkpoint_path(dir, *train_job);
        let Some(stem) = checkpoint.file_stem() else {
            return Ok(None);
        };
        let trained = read_train_result(&plan.result_path(dir, *train_job))?;
        let d = &plan.design;
        let setting = |v: Option<usize>| v.map_or("model".to_string(), |v| v.to_string());
        let name = format!(
            "{sequence}-trial{trial}-vision{vision_levels}-proprio{}-window{}-updates{}-steps{}.safetensors",
            if *proprio { "on" } else { "off" },
            setting(d.inference_window),
            setting(d.inference_iterations),
            setting(d.test_steps),
        );
        Ok(Some(Self {
            path: networks.join("runs").join(stem).join(name),
            network: match trained.network_iteration {
                Some(n) if n != trained.iterations => format!(
                    "{} iterations (network of iteration {n}), final free energy {:?}",
                    trained.iterations, trained.final_free_energy
                ),
                _ => format!(
                    "{} iterations, final free energy {:?}",
                    trained.iterations, trained.final_free_energy
                ),
            } + SCORES_VERSION,
        }))
    }

    /// The kept run, if there is one of this network.
    fn read(&self) -> Option<InferResult> {
        let file = TensorFile::open(&self.path).ok()?;
        if file.metadata("network") != Some(self.network.as_str()) {
            return None;
        }
        read_infer_result(&self.path).ok().map(|(result, _)| result)
    }
}

/// Reads an inference job's result (and its maps, if any).
pub fn read_infer_result(path: &Path) -> Result<(InferResult, Option<Vec<Vec<f32>>>)> {
    let file = TensorFile::open(path)?;
    let result: InferResult = file
        .metadata("result")
        .and_then(|t| serde_json::from_str(t).ok())
        .ok_or_else(|| {
            anyhow!(
                "{}: not an experiment result (no valid `result` metadata)",
                path.display()
            )
        })?;
    let maps = if file.contains("maps") {
        let t = file.f32("maps", None)?;
        let shape = t.shape().to_vec();
        if shape.len() != 2 || shape[0] != 4 {
            bail!(
                "{}: `maps` has shape {shape:?}, expected [4, n]",
                path.display()
            );
        }
        Some(t.data().chunks(shape[1]).map(<[f32]>::to_vec).collect())
    } else {
        None
    };
    Ok((result, maps))
}

/// Reads an inference result's per-phase contribution maps (indexed `[phase][module][pixel]`,
/// averaged over colour channels), if it has them.
pub fn read_phase_maps(path: &Path) -> Result<Option<Vec<Vec<Vec<f32>>>>> {
    let file = TensorFile::open(path)?;
    if !file.contains("phase_maps") {
        return Ok(None);
    }
    let t = file.f32("phase_maps", None)?;
    let shape = t.shape().to_vec();
    if shape.len() != 3 || shape[1] != 4 {
        bail!(
            "{}: `phase_maps` has shape {shape:?}, expected [phases, 4, n]",
            path.display()
        );
    }
    Ok(Some(
        t.data()
            .chunks(4 * shape[2])
            .map(|p| p.chunks(shape[2]).map(<[f32]>::to_vec).collect())
            .collect(),
    ))
}

/// Reads a training job's result.
pub fn read_train_result(path: &Path) -> Result<TrainResult> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    serde_json::from_str(&text)
        .with_context(|| format!("{}: not a training result", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn train(id: usize) -> Job {
        Job {
            id,
            name: format!("train-{id}"),
            kind: JobKind::Train {
                network: id,
                condition: "all 1".into(),
                sequences: vec!["a".into()],
                seed: id as u64,
                iterations: 1,
                reuse: None,
            },
            after: vec![],
        }
    }

    fn infer(id: usize, train_job: usize) -> Job {
        Job {
            id,
            name: format!("infer-{id}"),
            kind: JobKind::Infer {
                network: train_job,
                train_job,
                training: "all 1".into(),
                sequence: "a".into(),
                task: "wiping".into(),
                trial: 0,
                vision_levels: 3,
                proprio: true,
                maps: false,
            },
            after: vec![train_job],
        }
    }

    #[test]
    fn a_trained_networks_inference_runs_before_the_next_training() {
        // Plans list trainings first: 0 and 1 train, 2 and 3 read network 0, 4 network 1.
        let jobs = vec![train(0), train(1), infer(2, 0), infer(3, 0), infer(4, 1)];
        let next = |done: &[usize], taken: &[usize]| {
            first_ready(&jobs, |i| {
                !done.contains(&i)
                    && !taken.contains(&i)
                    && jobs[i].after.iter().all(|a| done.contains(a))
            })
        };
        assert_eq!(next(&[], &[]), Some(0));
        assert_eq!(
            next(&[], &[0]),
            Some(1),
            "nothing to infer yet: the next training"
        );
        assert_eq!(
            next(&[0], &[]),
            Some(2),
            "network 0 is trained: its runs first"
        );
        assert_eq!(next(&[0, 2], &[]), Some(3));
        assert_eq!(next(&[0, 2, 3], &[]), Some(1));
        assert_eq!(next(&[0, 1, 2, 3], &[]), Some(4));
        assert_eq!(next(&[0, 1, 2, 3, 4], &[]), None);
    }

    #[test]
    fn a_trainings_machines_are_its_validations_then_the_last_each_stretch_once() {
        let row = |iteration: u64, machine: Option<&str>| ValidationRow {
            iteration,
            failed_trials: 0,
            trials: 1,
            recon_vision_top: 0.01,
            recon_joints: None,
            recon_torques: None,
            seconds: 1.0,
            upsample: None,
            upsample_detail: None,
            mean: None,
            machine: machine.map(str::to_string),
            ..Default::default()
        };
        let rows = [
            row(2000, Some("A")),
            row(4000, Some("A")),
            row(6000, None),
            row(8000, Some("B")),
        ];
        assert_eq!(machines_of(&rows, "A".into()), ["A", "B", "A"]);
        assert_eq!(machines_of(&rows, "B".into()), ["A", "B"]);
        assert_eq!(machines_of(&[], "C".into()), ["C"]);
    }
}
