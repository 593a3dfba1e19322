//! Building a plan's jobs: the trainings of each condition (shared networks or
//! interference's data conditions) and the inference runs that read them.

use std::path::{Path, PathBuf};

use super::{Design, Experiment, Job, JobKind, Scale, VISION_CONDITIONS};
use anyhow::{Context, Result, bail, ensure};
use pvrnn_dataset::{Dataset, Split};

/// The two tasks of a caresim-style dataset.
pub(super) const TASKS: [&str; 2] = ["repositioning", "wiping"];

/// The names of `task`'s sequences in `split`, in the dataset's order.
pub(super) fn names_of(dataset: &Dataset, task: &str, split: Split) -> Vec<String> {
    dataset
        .manifest
        .sequences
        .iter()
        .filter(|s| s.task == task && s.split == split)
        .map(|s| s.name.clone())
        .collect()
}

/// The names of every sequence in `split`, in the dataset's order.
pub(super) fn names_of_split(dataset: &Dataset, split: Split) -> Vec<String> {
    dataset
        .manifest
        .sequences
        .iter()
        .filter(|s| s.split == split)
        .map(|s| s.name.clone())
        .collect()
}

/// The held-out dataset of a design with a convergence rule (required there, never the
/// learning data).
pub(super) fn resolve_validation(
    design: &Design,
    scale: Scale,
    validation: Option<&Path>,
    dataset_dir: &Path,
) -> Result<Option<PathBuf>> {
    match (design.validate_every, validation) {
        (Some(_), None) => bail!(
            "the {} scale trains each network until its validation error stops improving: pass --validate with a held-out caresim dataset (`pvrnn simulate --seed 1`)",
            scale.name()
        ),
        (_, Some(dir)) => {
            Dataset::open(dir).with_context(|| format!("--validate {}", dir.display()))?;
            let dir = std::fs::canonicalize(dir)?;
            ensure!(
                dir != std::fs::canonicalize(dataset_dir)?,
                "--validate {}: the learning data itself; the convergence rule needs sequences the networks do not learn from",
                dir.display()
            );
            Ok(Some(dir))
        }
        (None, None) => Ok(None),
    }
}

/// A checkpoint reused as network 0 must be of the design's training.
pub(super) fn check_reuse(
    experiment: Experiment,
    scale: Scale,
    design: &Design,
    path: &Path,
) -> Result<()> {
    ensure!(
        experiment != Experiment::Interference,
        "--reuse: the interference experiment trains on subsets; there is nothing to reuse"
    );
    let file = pvrnn_core::io::TensorFile::open(path)?;
    let iteration = pvrnn_core::io::checkpoint_iteration(&file);
    ensure!(
        iteration == Some(design.train_iterations),
        "--reuse {}: a checkpoint at iteration {:?}, the {} design trains {} iterations",
        path.display(),
        iteration,
        scale.name(),
        design.train_iterations
    );
    Ok(())
}

/// The plan's jobs as they are added (a job's id is its index).
pub(super) struct Jobs(pub(super) Vec<Job>);

impl Jobs {
    fn push(&mut self, name: String, kind: JobKind, after: Vec<usize>) -> usize {
        let id = self.0.len();
        self.0.push(Job {
            id,
            name,
            kind,
            after,
        });
        id
    }
}

/// A planned training: its job, network, condition, primary task (interference) and the
/// name its inference jobs carry.
pub(super) struct Training {
    job: usize,
    network: usize,
    condition: String,
    primary: Option<String>,
    name: String,
}

/// Interference: per primary task and number of the other task's sequences added, one
/// training per network.
pub(super) fn interference_trainings(
    jobs: &mut Jobs,
    design: &Design,
    dataset: &Dataset,
) -> Result<Vec<Training>> {
    let mut trainings = Vec::new();
    for primary in &design.primary_tasks {
        let other = TASKS
            .iter()
            .find(|t| *t != primary)
            .expect("two tasks")
            .to_string();
        let kept = names_of(dataset, primary, Split::Learn);
        let extra = added_sequences(dataset, &other, &design.added)?;
        for (&k, added) in design.added.iter().zip(extra) {
            let condition = format!("{primary} {} + {other} {k}", kept.len());
            for network in 0..design.networks {
                let mut sequences = kept.clone();
                sequences.extend(added.iter().cloned());
                let name = format!("{primary}-plus{k}-net{network}");
                let job = jobs.push(
                    format!("train-{name}"),
                    JobKind::Train {
                        network,
                        condition: condition.clone(),
                        sequences,
                        seed: network as u64,
                        iterations: design.train_iterations,
                        reuse: None,
                    },
                    Vec::new(),
                );
                trainings.push(Training {
                    job,
                    network,
                    condition: condition.clone(),
                    primary: Some(primary.clone()),
                    name,
                });
            }
        }
    }
    Ok(trainings)
}

/// Hierarchy, uncertainty and robustness: one training per network on every learning
/// sequence (network 0 may reuse a checkpoint).
pub(super) fn shared_trainings(
    jobs: &mut Jobs,
    design: &Design,
    dataset: &Dataset,
    reuse: Option<&Path>,
) -> Result<Vec<Training>> {
    let all = names_of_split(dataset, Split::Learn);
    let condition = format!("all {}", all.len());
    let mut trainings = Vec::new();
    for network in 0..design.networks {
        let reuse = match reuse.filter(|_| network == 0) {
            Some(p) => Some(
                std::fs::canonicalize(p)
                    .with_context(|| format!("cannot resolve {}", p.display()))?,
            ),
            None => None,
        };
        let job = jobs.push(
            format!("train-net{network}"),
            JobKind::Train {
                network,
                condition: condition.clone(),
                sequences: all.clone(),
                seed: network as u64,
                iterations: design.train_iterations,
                reuse,
            },
            Vec::new(),
        );
        trainings.push(Training {
            job,
            network,
            condition: condition.clone(),
            primary: None,
            name: format!("net{network}"),
        });
    }
    Ok(trainings)
}

/// The observation conditions an experiment's inference runs: (label, vision levels
/// observed, proprioception).
fn observed_conditions(experiment: Experiment) -> Vec<(String, usize, bool)> {
    match experiment {
        Experiment::Robustness => VISION_CONDITIONS
            .iter()
            .flat_map(|&(label, levels)| {
                [true, false].map(|p| {
                    (
                        format!("vision {label}, proprio {}", if p { "on" } else { "off" }),
                        levels,
                        p,
                    )
                })
            })
            .collect(),
        // Occlusion (Fig. 3B) is scored also where the top resolution is not observed,
        // so the reconstruction cannot copy the arm it sees: the 16x16 input
        // (robustness's "vision 16, proprio on" run, shared with it).
        Experiment::Hierarchy => vec![
            ("everything observed".to_string(), 3, true),
            ("vision 16, proprio on".to_string(), 1, true),
        ],
        _ => vec![("everything observed".to_string(), 3, true)],
    }
}

/// One inference job per training, test sequence of its tasks, condition and trial.
pub(super) fn inference_jobs(
    jobs: &mut Jobs,
    design: &Design,
    experiment: Experiment,
    trainings: &[Training],
    dataset: &Dataset,
) {
    let conditions = observed_conditions(experiment);
    // Contribution maps: hierarchy's everything-observed runs.
    let maps_of = |c: usize| experiment == Experiment::Hierarchy && c == 0;
    for t in trainings {
        let test_tasks: Vec<&str> = match &t.primary {
            Some(p) => vec![p.as_str()],
            None => TASKS.to_vec(),
        };
        for task in test_tasks {
            let mut tests = names_of(dataset, task, Split::Test);
            if let Some(k) = design.test_sequences_per_task {
                tests.truncate(k);
            }
            for sequence in tests {
                for (c, (_, levels, proprio)) in conditions.iter().enumerate() {
                    for trial in 0..design.trials {
                        jobs.push(
                            format!("infer-{}-{sequence}-c{c}-trial{trial}", t.name),
                            JobKind::Infer {
                                network: t.network,
                                train_job: t.job,
                                training: t.condition.clone(),
                                sequence: sequence.clone(),
                                task: task.to_string(),
                                trial,
                                vision_levels: *levels,
                                proprio: *proprio,
                                maps: maps_of(c),
                            },
                            vec![t.job],
                        );
                    }
                }
            }
        }
    }
}

/// The other task's learning sequences added for each count: `k / 3` per bed height (3 = one
/// per height, 6 = two per height), the same for every network. Heights in order, the
/// sequences of a height in name order.
fn added_sequences(dataset: &Dataset, task: &str, counts: &[usize]) -> Result<Vec<Vec<String>>> {
    let mut by_height: std::collections::BTreeMap<i64, Vec<String>> = Default::default();
    for s in &dataset.manifest.sequences {
        if s.task == task && s.split == Split::Learn {
            let height = s.bed_height_mm.map_or(0, |h| h.round() as i64);
            by_height.entry(height).or_default().push(s.name.clone());
        }
    }
    for names in by_height.values_mut() {
        names.sort();
    }
    let heights = by_height.len().max(1);
    counts
        .iter()
        .map(|&k| {
            ensure!(
                k % heights == 0,
                "cannot add {k} {task} sequences evenly over {heights} bed heights"
            );
            let per = k / heights;
            let mut out = Vec::new();
            for names in by_height.values() {
                ensure!(
                    names.len() >= per,
                    "only {} {task} learning sequences at one bed height; {per} needed",
                    names.len()
                );
                out.extend(names[..per].iter().cloned());
            }
            Ok(out)
        })
        .collect()
}
