//! Inference jobs: online inference on a test sequence under a condition, scored (errors,
//! sigma, contribution maps, occlusion) into one result file; runs shared across
//! experiments computed once.

use std::collections::{BTreeMap, HashMap};

use std::path::Path;
use std::sync::Arc;

use anyhow::Result;
use pvrnn_core::backend::Backend;
use pvrnn_core::infer::{InferenceSettings, OnlineInference};
use pvrnn_core::io::{self, OutTensor, TensorFile};
use pvrnn_core::{Ablation, Model, ModelConfig, ModuleId, Observed};
use pvrnn_dataset::{Dataset, Sequence};

use super::{
    Cache, Diverged, Event, InferResult, network_path, read_infer_result, read_train_result,
    sequences, truncated,
};
use crate::occlusion::OcclusionScorer;
use crate::plan::{Design, JobKind, Plan};

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

pub(super) fn infer(
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
