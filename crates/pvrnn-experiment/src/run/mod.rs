//! Running an experiment's jobs: trainings (resumable from their checkpoint, which is
//! written every `checkpoint_every` iterations and on interruption) and inference runs
//! (each scored into one result file). Jobs whose result exists are skipped, so running
//! again continues where a killed run stopped.

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use anyhow::{Result, anyhow, ensure};
use pvrnn_core::backend::Backend;
use pvrnn_dataset::{Dataset, Sequence};

use crate::plan::{Job, JobKind, Plan};

mod inference;
mod results;
mod training;

use inference::infer;
pub use inference::job_settings;
pub use results::{
    Diverged, InferResult, Stop, TrainResult, convergence, counted, last_tenth_change,
    network_path, read_infer_result, read_phase_maps, read_train_result,
};
use training::train;

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

#[cfg(test)]
mod tests {
    use pvrnn_eval::validation::ValidationRow;

    use super::training::machines_of;
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
