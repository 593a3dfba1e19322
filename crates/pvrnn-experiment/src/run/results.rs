//! The jobs' result files: a training's `train-*.json` (with its validations and why it
//! stopped), an inference run's safetensors, and where a trained network is.

use std::collections::BTreeMap;

use std::path::Path;

use anyhow::{Context, Result, anyhow, bail};
use pvrnn_core::io::{self, TensorFile};
use serde::{Deserialize, Serialize};

use pvrnn_eval::validation::{self, ValidationRow};

use crate::occlusion::OcclusionScores;
use crate::plan::{Design, Plan};

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

pub(super) fn write_train_result(
    plan: &Plan,
    dir: &Path,
    id: usize,
    result: TrainResult,
) -> Result<()> {
    let path = plan.result_path(dir, id);
    std::fs::create_dir_all(path.parent().expect("a folder"))?;
    io::write_atomic(&path, serde_json::to_string_pretty(&result)?.as_bytes())?;
    Ok(())
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
