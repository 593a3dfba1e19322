//! An experiment's manifest (`plan.json`): its design at one scale and its independent jobs
//! (trainings, then inference runs that read the trained networks). Every job writes one
//! result file atomically; a job is done when its result file exists.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail, ensure};
use pvrnn_dataset::{Dataset, Split};
use serde::{Deserialize, Serialize};

mod design;
mod jobs;

pub use design::Design;
use jobs::{
    Jobs, TASKS, check_reuse, inference_jobs, interference_trainings, names_of, names_of_split,
    resolve_validation, shared_trainings,
};

pub const FORMAT: &str = "pvrnn-experiment/1";

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Experiment {
    /// Figs 2-3: contribution maps per module; the executive module's latent change near
    /// subtask boundaries.
    Hierarchy,
    /// Fig 4: prior sigma and its change per module and task.
    Uncertainty,
    /// Fig 5: vision 64 / 32+16 / 16 x proprioception on / off.
    Robustness,
    /// Fig 6: one task's 9 sequences plus 0 / 3 / 6 / 9 of the other.
    Interference,
}

impl Experiment {
    pub const ALL: [Experiment; 4] = [
        Experiment::Hierarchy,
        Experiment::Uncertainty,
        Experiment::Robustness,
        Experiment::Interference,
    ];
    pub fn name(self) -> &'static str {
        match self {
            Experiment::Hierarchy => "hierarchy",
            Experiment::Uncertainty => "uncertainty",
            Experiment::Robustness => "robustness",
            Experiment::Interference => "interference",
        }
    }
    pub fn parse(text: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|e| e.name() == text)
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Scale {
    /// End to end in minutes on 2 cores: tiny trainings on truncated sequences. Tests the
    /// machinery; its numbers mean nothing.
    Smoke,
    /// The largest design that fits about 12 hours of 2-core training in total.
    Reduced,
    /// The paper's 5 networks per condition, each trained until it converges (the
    /// validation-best checkpoint, or a flat free energy) within a cap.
    Converged,
    /// The paper's design: 5 networks x 100,000 iterations, 5 trials per test sequence.
    Paper,
}

impl Scale {
    pub fn name(self) -> &'static str {
        match self {
            Scale::Smoke => "smoke",
            Scale::Reduced => "reduced",
            Scale::Converged => "converged",
            Scale::Paper => "paper",
        }
    }
    pub fn parse(text: &str) -> Option<Self> {
        [Scale::Smoke, Scale::Reduced, Scale::Converged, Scale::Paper]
            .into_iter()
            .find(|s| s.name() == text)
    }
}

/// What a job computes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum JobKind {
    /// Learning one network on `sequences` (names in the dataset's learning split).
    Train {
        network: usize,
        /// Training condition, e.g. `all 18` or `repositioning 9 + wiping 3`.
        condition: String,
        sequences: Vec<String>,
        seed: u64,
        iterations: u64,
        /// A trained checkpoint used instead of training (same seed, data and
        /// iterations), copied in when the job runs.
        reuse: Option<PathBuf>,
    },
    /// Online inference of one test sequence by one trained network under one condition.
    Infer {
        network: usize,
        /// The training job whose network this reads.
        train_job: usize,
        /// Training condition of that network (interference) or `all 18`.
        training: String,
        sequence: String,
        task: String,
        trial: usize,
        /// Vision levels observed (lowest first) and proprioception.
        vision_levels: usize,
        proprio: bool,
        /// Also the `readout` ablation of each module (contribution maps).
        maps: bool,
    },
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Job {
    pub id: usize,
    pub name: String,
    #[serde(flatten)]
    pub kind: JobKind,
    /// Jobs that must be done first.
    pub after: Vec<usize>,
}

impl Job {
    /// The network the job trains or reads.
    pub fn network(&self) -> usize {
        match self.kind {
            JobKind::Train { network, .. } | JobKind::Infer { network, .. } => network,
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Plan {
    pub format: String,
    pub experiment: Experiment,
    pub scale: Scale,
    pub design: Design,
    /// The dataset folder (absolute).
    pub dataset: PathBuf,
    /// The dataset's own description (e.g. `caresim (seed 0, variability matched ...)`).
    #[serde(default)]
    pub dataset_source: String,
    /// Proprioception ranges of all 18 learning sequences: one normalisation for every
    /// training condition, so networks trained on subsets stay comparable.
    pub ranges_from: String,
    /// Where the trained networks go (absolute); None = `DIR/networks`. Experiments at the
    /// same scale that name the same folder share their networks (hierarchy, uncertainty
    /// and robustness train the same ones): a network trained by one is reused by the next.
    #[serde(default)]
    pub networks_dir: Option<PathBuf>,
    /// The held-out dataset of the convergence rule (absolute; designs with one).
    #[serde(default)]
    pub validation_dataset: Option<PathBuf>,
    pub jobs: Vec<Job>,
}

/// Vision conditions of the robustness experiment: (label, levels observed).
pub const VISION_CONDITIONS: [(&str, usize); 3] = [("64 (all)", 3), ("32+16", 2), ("16", 1)];

impl Plan {
    pub fn path(dir: &Path) -> PathBuf {
        dir.join("plan.json")
    }

    /// Where job `id` writes its result.
    pub fn result_path(&self, dir: &Path, id: usize) -> PathBuf {
        let job = &self.jobs[id];
        match job.kind {
            JobKind::Train { .. } => dir.join("results").join(format!("{}.json", job.name)),
            JobKind::Infer { .. } => dir
                .join("results")
                .join(format!("{}.safetensors", job.name)),
        }
    }

    /// A training job's running checkpoint (the trained network once the job is done).
    /// The scale is part of the name, so a shared folder never mixes scales.
    pub fn checkpoint_path(&self, dir: &Path, id: usize) -> PathBuf {
        self.networks_dir
            .clone()
            .unwrap_or_else(|| dir.join("networks"))
            .join(format!(
                "{}-{}.safetensors",
                self.scale.name(),
                self.jobs[id].name
            ))
    }

    /// Makes `networks` this plan's networks folder. A shared folder remembers the data its
    /// networks learned (`data.json`: the dataset's source and learning sequences), so a
    /// plan on other data (another seed or variability setting) cannot reuse them.
    pub fn claim_networks_dir(&mut self, networks: &Path) -> Result<()> {
        std::fs::create_dir_all(networks)
            .with_context(|| format!("cannot create {}", networks.display()))?;
        let networks = std::fs::canonicalize(networks)?;
        let dataset = Dataset::open(&self.dataset)?;
        let learned: Vec<serde_json::Value> = dataset
            .manifest
            .sequences
            .iter()
            .filter(|s| s.split == Split::Learn)
            .map(|s| serde_json::json!({"name": s.name, "seed": s.seed, "length": s.length}))
            .collect();
        let claim = serde_json::json!({
            "dataset": dataset.manifest.source,
            "learning_sequences": learned,
        });
        let path = networks.join("data.json");
        match std::fs::read_to_string(&path) {
            Ok(text) => {
                let held: serde_json::Value = serde_json::from_str(&text)
                    .with_context(|| format!("{}: not valid JSON", path.display()))?;
                ensure!(
                    held == claim,
                    "{}: its networks learned other data (dataset `{}`) than {} (dataset `{}`); use another --networks folder",
                    networks.display(),
                    held["dataset"].as_str().unwrap_or("?"),
                    self.dataset.display(),
                    dataset.manifest.source
                );
            }
            Err(_) => pvrnn_core::io::write_atomic(
                &path,
                serde_json::to_string_pretty(&claim)?.as_bytes(),
            )?,
        }
        self.networks_dir = Some(networks);
        Ok(())
    }

    /// A training job's best-validated network (designs with a convergence rule): a model
    /// file recording its iteration, without the optimiser state of a checkpoint.
    pub fn best_path(&self, dir: &Path, id: usize) -> PathBuf {
        self.checkpoint_path(dir, id)
            .with_extension("best.safetensors")
    }

    /// A training job's validation log (designs with a convergence rule).
    pub fn validation_log_path(&self, dir: &Path, id: usize) -> PathBuf {
        self.checkpoint_path(dir, id)
            .with_extension("validation.csv")
    }

    pub fn is_done(&self, dir: &Path, id: usize) -> bool {
        self.result_path(dir, id).is_file()
    }

    pub fn load(dir: &Path) -> Result<Self> {
        let path = Self::path(dir);
        let text = std::fs::read_to_string(&path)
            .with_context(|| format!("{}: cannot read the experiment's plan", path.display()))?;
        let plan: Plan = serde_json::from_str(&text)
            .with_context(|| format!("{}: not a valid experiment plan", path.display()))?;
        ensure!(
            plan.format == FORMAT,
            "{}: format `{}`, expected `{FORMAT}`",
            path.display(),
            plan.format
        );
        for job in &plan.jobs {
            ensure!(
                job.after.iter().all(|&a| a < job.id) && plan.jobs[job.id].id == job.id,
                "{}: job {} has invalid dependencies",
                path.display(),
                job.id
            );
        }
        Ok(plan)
    }

    pub fn save(&self, dir: &Path) -> Result<()> {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
        let text = serde_json::to_string_pretty(self)?;
        pvrnn_core::io::write_atomic(&Self::path(dir), text.as_bytes())?;
        Ok(())
    }

    /// Plans `experiment` at `scale` on a caresim-style dataset (tasks `repositioning` and
    /// `wiping`, 9 learning and some test sequences each).
    pub fn new(
        experiment: Experiment,
        scale: Scale,
        dataset_dir: &Path,
        reuse: Option<&Path>,
        validation: Option<&Path>,
    ) -> Result<Self> {
        let dataset = Dataset::open(dataset_dir)?;
        let design = Design::of(experiment, scale);
        let validation_dataset = resolve_validation(&design, scale, validation, dataset_dir)?;
        let dataset_dir = std::fs::canonicalize(dataset_dir)
            .with_context(|| format!("cannot resolve {}", dataset_dir.display()))?;
        for task in TASKS {
            ensure!(
                !names_of(&dataset, task, Split::Learn).is_empty()
                    && !names_of(&dataset, task, Split::Test).is_empty(),
                "{}: the experiments need learning and test sequences of the task `{task}` (a caresim dataset)",
                dataset_dir.display()
            );
        }
        if let Some(path) = reuse {
            check_reuse(experiment, scale, &design, path)?;
        }
        let mut jobs = Jobs(Vec::new());
        let trainings = if experiment == Experiment::Interference {
            interference_trainings(&mut jobs, &design, &dataset)?
        } else {
            shared_trainings(&mut jobs, &design, &dataset, reuse)?
        };
        inference_jobs(&mut jobs, &design, experiment, &trainings, &dataset);
        let learned = names_of_split(&dataset, Split::Learn).len();
        Ok(Plan {
            format: FORMAT.into(),
            experiment,
            scale,
            design,
            dataset: dataset_dir,
            ranges_from: format!("all {learned} learning sequences of the dataset"),
            dataset_source: dataset.manifest.source.clone(),
            networks_dir: None,
            validation_dataset,
            jobs: jobs.0,
        })
    }

    /// The label of a robustness condition.
    pub fn condition_label(vision_levels: usize, proprio: bool) -> String {
        let vision = VISION_CONDITIONS
            .iter()
            .find(|c| c.1 == vision_levels)
            .map_or_else(|| format!("{vision_levels} levels"), |c| c.0.to_string());
        format!(
            "vision {vision}, proprio {}",
            if proprio { "on" } else { "off" }
        )
    }

    /// Checks that an existing plan is the one asked for: results of different
    /// experiments or scales are never mixed.
    pub fn check_matches(&self, experiment: Experiment, scale: Scale) -> Result<()> {
        if self.experiment != experiment || self.scale != scale {
            bail!(
                "the folder holds the {} experiment at {} scale, not {} at {}: use another --out",
                self.experiment.name(),
                self.scale.name(),
                experiment.name(),
                scale.name()
            );
        }
        Ok(())
    }
}
