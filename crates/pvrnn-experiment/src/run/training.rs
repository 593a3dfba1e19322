//! Training jobs: resumable from their checkpoint, validated on held-out data under the
//! design's convergence rule (early stopping), or reusing a checkpoint.

use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{Context, Result, ensure};
use pvrnn_core::backend::Backend;
use pvrnn_core::io::{self, TensorFile};
use pvrnn_core::train::Trainer;
use pvrnn_core::{Model, ModelConfig, NoiseMode};
use pvrnn_dataset::{Dataset, Sequence, proprio_ranges};

use pvrnn_eval::training_log::{self, TrainingLog};
use pvrnn_eval::validation::{self, ValidationRow};

use super::results::write_train_result;
use super::{
    Cache, Event, Interrupted, Stop, TrainResult, convergence, counted, last_tenth_change,
    log_path, sequences, truncated,
};
use crate::plan::{Design, JobKind, Plan};
use pvrnn_eval::early_stopping::{EarlyStopping, StoppingRule};

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
            .is_some_and(|r| r.stopping.due(self.trainer.iteration))
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
        let validations = self
            .rule
            .map(|r| r.stopping.into_rows())
            .unwrap_or_default();
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
pub(super) fn machines_of(validations: &[ValidationRow], last: String) -> Vec<String> {
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
pub(super) fn train(
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

/// The convergence rule's state during one training: early stopping on the held-out data
/// (the same type as `pvrnn train --validate`'s), and whether it stops the run.
struct ConvergenceRule {
    stopping: EarlyStopping,
    /// Whether the rule stops the training (a convergence rule); without one, a design
    /// with held-out data validates its network once, at its last iteration, for the
    /// validity gate.
    stops: bool,
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
        let rule = StoppingRule {
            every,
            patience: plan.design.patience.filter(|_| stops),
            select_from: plan.design.select_from.unwrap_or(0),
        };
        let stopping = EarlyStopping::open(
            dataset,
            rule,
            plan.validation_log_path(dir, id),
            plan.best_path(dir, id),
            iteration,
        )?;
        Ok(Some(Self { stopping, stops }))
    }

    fn missed(&self, iteration: u64) -> bool {
        self.stopping.missed(iteration)
    }

    fn check(&self, design: &Design, log: &Path, iteration: u64) -> Option<Stop> {
        if !self.stops || (!self.stopping.due(iteration) && iteration < design.train_iterations) {
            return None;
        }
        convergence(
            design,
            &training_log::totals(log, iteration),
            self.stopping.rows(),
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
        let (row, best) = self
            .stopping
            .score(model.clone(), backend.as_ref(), iteration)?;
        if best {
            io::save_model_at(self.stopping.best_path(), &model, iteration)?;
        }
        self.stopping.record(row)?;
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
