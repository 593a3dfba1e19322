//! Runs an evaluation: online inference (exactly `pvrnn infer`) on every sequence of a
//! split, several noise trials each, every step scored against the truth; the baselines of
//! each sequence scored by the same code.

use std::sync::Arc;

use pvrnn_core::backend::Backend;
use pvrnn_core::infer::{InferenceSettings, OnlineInference};
use pvrnn_core::{Modality, Model, ModelConfig, Observations};
use pvrnn_dataset::{Dataset, Selection, Sequence};
use rayon::prelude::*;
use serde::Serialize;

use crate::baselines::{NearestFrames, learning_mean, mean_detail, upsampled_with_detail};
use crate::groups::{Group, groups};
use crate::metrics::{StepErrors, change_mask, score, upsampled_vision};
use crate::{Error, Result};

/// What is predicted.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, PartialOrd, Ord)]
#[serde(rename_all = "lowercase")]
pub enum Target {
    /// x_t: the posterior reconstruction of the current step (all dimensions, observed or not).
    Recon,
    /// x_{t+1}: the one-step prior prediction made at step t.
    Next,
}

/// Who predicts it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, PartialOrd, Ord)]
#[serde(rename_all = "lowercase")]
pub enum Source {
    Model,
    /// The current step as the prediction of the next one (true values, also of
    /// dimensions the model does not observe).
    Previous,
    /// The mean learning-split input (image and posture).
    Mean,
    /// Bilinear upsampling of the highest observed resolution to the unobserved ones.
    Upsample,
    /// Upsampling plus the fine detail of the mean learning image (that image minus its
    /// own upsampling from the highest observed resolution): what a network that only
    /// memorised the average scene would add to upsampling.
    #[serde(rename = "upsample_detail")]
    UpsampleDetail,
    /// The learning frame whose observed inputs are closest (each modality's squared
    /// distance over its observed dimensions, divided by their number), whole.
    Nearest,
}

impl Target {
    pub const ALL: [Target; 2] = [Target::Recon, Target::Next];
    pub fn name(self) -> &'static str {
        match self {
            Target::Recon => "recon",
            Target::Next => "next",
        }
    }
}

impl Source {
    pub const ALL: [Source; 6] = [
        Source::Model,
        Source::Previous,
        Source::Mean,
        Source::Upsample,
        Source::UpsampleDetail,
        Source::Nearest,
    ];
    /// Every source but the model, in the order reports list them.
    pub const BASELINES: [Source; 5] = [
        Source::Upsample,
        Source::UpsampleDetail,
        Source::Nearest,
        Source::Previous,
        Source::Mean,
    ];
    pub fn name(self) -> &'static str {
        match self {
            Source::Model => "model",
            Source::Previous => "previous",
            Source::Mean => "mean",
            Source::Upsample => "upsample",
            Source::UpsampleDetail => "upsample_detail",
            Source::Nearest => "nearest",
        }
    }
}

/// Everything an evaluation depends on besides the model and the data.
#[derive(Clone, Debug)]
pub struct EvalSettings {
    /// The inference condition; trial k uses noise seed `seed + k`.
    pub inference: InferenceSettings,
    pub trials: usize,
    /// A pixel "changes" when a channel moves by more than this many 8-bit levels.
    pub change_threshold: f64,
    /// Time steps shown in each sequence's picture of actual vs predicted images.
    pub image_columns: usize,
    /// Whether to search the learning split for each step's nearest neighbour (the
    /// `nearest` baseline; early stopping's validation skips it).
    pub nearest_neighbour: bool,
}

/// One sequence's identity as the report shows it.
#[derive(Clone, Debug, Serialize)]
pub struct SequenceMeta {
    pub name: String,
    pub task: String,
    pub bed_height_mm: Option<f64>,
    pub length: usize,
    /// Per step, an index into `subtask_names`.
    #[serde(skip)]
    pub subtask: Vec<u32>,
    pub subtask_names: Vec<String>,
}

/// One source's errors for one target over a sequence's steps (`None` where undefined,
/// e.g. the step after the last).
#[derive(Clone, Debug)]
pub struct Series {
    pub source: Source,
    pub target: Target,
    /// The noise trial (model series only).
    pub trial: Option<usize>,
    pub steps: Vec<Option<StepErrors>>,
}

/// Vision vectors of a few steps of one trial (the first that finished), for pictures.
#[derive(Clone, Debug, Default)]
pub struct ImageSamples {
    /// The trial they come from.
    pub trial: usize,
    pub steps: Vec<usize>,
    pub actual: Vec<Vec<f32>>,
    pub recon: Vec<Vec<f32>>,
    /// The prior prediction of the step, made one step before (none at the first step).
    pub predicted: Vec<Option<Vec<f32>>>,
    /// The upsampling baseline's reconstruction (when the condition has one).
    pub upsampled: Vec<Option<Vec<f32>>>,
}

#[derive(Clone, Debug)]
pub struct SequenceResult {
    pub meta: SequenceMeta,
    pub series: Vec<Series>,
    pub images: ImageSamples,
    /// Steps whose online inference diverged and was restarted at a reduced rate.
    pub restarts: Vec<Restart>,
    /// Trials whose online inference diverged beyond repair: they have no model series.
    pub failures: Vec<Failure>,
}

impl SequenceResult {
    /// Whether no trial of the sequence finished: the sequence then leaves every figure,
    /// baselines included, so the model and the baselines are scored on the same sequences.
    pub fn excluded(&self) -> bool {
        !self.series.iter().any(|s| s.source == Source::Model)
    }
}

/// A step of one trial that online inference restarted at `lr / 2^rate_halvings` after its
/// window diverged (`pvrnn_core::infer::StepOutput::rate_halvings`).
#[derive(Clone, Debug, Serialize)]
pub struct Restart {
    pub trial: usize,
    pub step: usize,
    pub rate_halvings: u32,
}

/// A trial that stopped because online inference diverged even at the smallest rate
/// (`pvrnn_core::Error::Numerical`). Its steps are left out of every figure; the other
/// trials go on.
#[derive(Clone, Debug, Serialize)]
pub struct Failure {
    pub trial: usize,
    /// The step that could not be computed.
    pub step: usize,
    pub message: String,
}

/// What one trial's run gives: its series, pictures and restarts, or how it failed.
enum TrialRun {
    Finished([Series; 2], Box<ImageSamples>, Vec<Restart>),
    Failed(Failure),
}

/// A finished evaluation.
#[derive(Clone, Debug)]
pub struct Evaluation {
    pub settings: EvalSettings,
    pub groups: Vec<Group>,
    pub sequences: Vec<SequenceResult>,
    /// Vision resolutions, ascending, and camera names (for pictures).
    pub resolutions: Vec<usize>,
    pub cameras: Vec<String>,
}

/// Per step, the vision dimensions that changed from the previous step (none at t = 0).
type ChangeMasks = Vec<Option<Vec<bool>>>;

/// What the baselines need: the model's layout, the groups scored, the mean learning
/// input, the change threshold, the observed vision levels and the mean image's detail.
struct Baselines<'a> {
    config: &'a pvrnn_core::ModelConfig,
    groups: &'a [Group],
    mean: [&'a [f32]; 2],
    threshold: f32,
    vision_levels: usize,
    detail: Option<&'a [f32]>,
}

impl Baselines<'_> {
    /// Sequence `s`'s change masks (masks[t]: from t-1 to t) and the baselines' series.
    fn of_sequence(&self, data: &Observations<f32>, s: usize) -> (ChangeMasks, Vec<Series>) {
        let len = data.lengths()[s];
        let x = |t: usize| {
            [
                data.step(Modality::Exteroceptive, s, t),
                data.step(Modality::Proprioceptive, s, t),
            ]
        };
        let masks: ChangeMasks = (0..len)
            .map(|t| {
                (t > 0)
                    .then(|| change_mask(&self.config.vision, x(t - 1)[0], x(t)[0], self.threshold))
            })
            .collect();
        let mut series = Vec::new();
        series.push(Series {
            source: Source::Mean,
            target: Target::Recon,
            trial: None,
            steps: (0..len)
                .map(|t| Some(score(self.groups, self.mean, x(t), masks[t].as_deref())))
                .collect(),
        });
        series.push(Series {
            source: Source::Mean,
            target: Target::Next,
            trial: None,
            steps: (0..len)
                .map(|t| {
                    (t + 1 < len)
                        .then(|| score(self.groups, self.mean, x(t + 1), masks[t + 1].as_deref()))
                })
                .collect(),
        });
        series.push(Series {
            source: Source::Previous,
            target: Target::Next,
            trial: None,
            steps: (0..len)
                .map(|t| {
                    (t + 1 < len)
                        .then(|| score(self.groups, x(t), x(t + 1), masks[t + 1].as_deref()))
                })
                .collect(),
        });
        // The upsampling baselines: the observed levels' images upsampled to every level
        // (plus the mean image's detail), proprioception as observed.
        let upsampled = |source: Source, up: &dyn Fn(&[f32]) -> Option<Vec<f32>>| Series {
            source,
            target: Target::Recon,
            trial: None,
            steps: (0..len)
                .map(|t| {
                    let up = up(x(t)[0]).expect("some levels observed, some not");
                    Some(score(
                        self.groups,
                        [&up, x(t)[1]],
                        x(t),
                        masks[t].as_deref(),
                    ))
                })
                .collect(),
        };
        let layout = &self.config.vision;
        if self.vision_levels > 0 && self.vision_levels < layout.resolutions.len() {
            series.push(upsampled(Source::Upsample, &|v| {
                upsampled_vision(layout, v, self.vision_levels)
            }));
        }
        if let Some(detail) = self.detail {
            series.push(upsampled(Source::UpsampleDetail, &|v| {
                upsampled_with_detail(layout, v, self.vision_levels, detail)
            }));
        }
        (masks, series)
    }
}

/// Evaluates `model` on `selection` of `dataset`, running inference on `backend`.
/// `progress` is called with each finished inference step.
pub fn evaluate(
    model: Arc<Model<f32>>,
    backend: &dyn Backend<f32>,
    dataset: &Dataset,
    selection: &Selection,
    settings: &EvalSettings,
    progress: &(dyn Fn() + Sync),
) -> Result<Evaluation> {
    let config = &model.config;
    if settings.trials == 0 {
        return Err(Error::Invalid("at least one trial is needed".into()));
    }
    settings.inference.validate(config)?;
    let manifest = &dataset.manifest;
    pvrnn_dataset::inputs::check_proprio(manifest, config)?;
    let sequences = dataset.select(selection)?;
    let data = dataset.observations(&sequences, config)?;
    data.check_fits(config)?;
    let mean = learning_mean(dataset, &model)?;
    let groups = groups(
        config,
        &manifest.cameras,
        manifest.proprio_layout(),
        &settings.inference.observed,
    );
    let threshold = (settings.change_threshold / 255.0 * 1.8) as f32;
    let vision_levels = settings.inference.observed.vision_levels;
    let detail = mean_detail(&config.vision, &mean[0], vision_levels);

    // Per sequence: change masks (masks[t]: from t-1 to t) and the baselines' series.
    let baselines = Baselines {
        config,
        groups: &groups,
        mean: [mean[0].as_slice(), mean[1].as_slice()],
        threshold,
        vision_levels,
        detail: detail.as_deref(),
    };
    let mut prepared: Vec<(ChangeMasks, Vec<Series>)> = (0..sequences.len())
        .into_par_iter()
        .map(|s| baselines.of_sequence(&data, s))
        .collect();
    if settings.nearest_neighbour {
        add_nearest_frames(
            dataset,
            &model,
            &sequences,
            &data,
            settings,
            &groups,
            &mut prepared,
        )?;
    }

    let jobs: Vec<(usize, usize)> = (0..sequences.len())
        .flat_map(|s| (0..settings.trials).map(move |k| (s, k)))
        .collect();
    let runs: Vec<(usize, TrialRun)> = jobs
        .par_iter()
        .map(|&(s, trial)| {
            run_trial(
                &model,
                backend,
                &data,
                s,
                trial,
                settings,
                &groups,
                &prepared[s].0,
                progress,
            )
            .map(|run| (s, run))
            // Name the run that failed so it can be rerun.
            .map_err(|e| {
                Error::Invalid(format!(
                    "sequence `{}`, trial {trial}: {e}",
                    sequences[s].info.name
                ))
            })
        })
        .collect::<Result<_>>()?;

    let results = sequence_results(&sequences, prepared, runs, &data, config, vision_levels);
    Ok(Evaluation {
        settings: settings.clone(),
        groups,
        sequences: results,
        resolutions: config.vision.resolutions.clone(),
        cameras: manifest.cameras.clone(),
    })
}

/// The nearest learning frame's series (a baseline: the learning frame whose inputs are
/// closest to the observed ones), when the dataset has learning sequences to search.
fn add_nearest_frames(
    dataset: &Dataset,
    model: &Model<f32>,
    sequences: &[&Sequence],
    data: &Observations<f32>,
    settings: &EvalSettings,
    groups: &[Group],
    prepared: &mut [(ChangeMasks, Vec<Series>)],
) -> Result<()> {
    let Some(nearest) = NearestFrames::search(
        dataset,
        model,
        sequences,
        data,
        &settings.inference.observed,
    )?
    else {
        return Ok(());
    };
    let mut steps: Vec<Vec<Option<StepErrors>>> =
        data.lengths().iter().map(|&len| vec![None; len]).collect();
    nearest.for_each(dataset, model, |s, t, frame| {
        let truth = [
            data.step(Modality::Exteroceptive, s, t),
            data.step(Modality::Proprioceptive, s, t),
        ];
        steps[s][t] = Some(score(groups, frame, truth, prepared[s].0[t].as_deref()));
    })?;
    for ((_, series), steps) in prepared.iter_mut().zip(steps) {
        series.push(Series {
            source: Source::Nearest,
            target: Target::Recon,
            trial: None,
            steps,
        });
    }
    Ok(())
}

/// Per sequence: its description, the baselines' series and every finished trial's, the
/// first finished trial's pictures (with the baselines' beside them), restarts and
/// failures.
fn sequence_results(
    sequences: &[&Sequence],
    prepared: Vec<(ChangeMasks, Vec<Series>)>,
    runs: Vec<(usize, TrialRun)>,
    data: &Observations<f32>,
    config: &ModelConfig,
    vision_levels: usize,
) -> Vec<SequenceResult> {
    let mut results: Vec<SequenceResult> = sequences
        .iter()
        .zip(prepared)
        .map(|(seq, (_, baselines))| SequenceResult {
            meta: SequenceMeta {
                name: seq.info.name.clone(),
                task: seq.info.task.clone(),
                bed_height_mm: seq.info.bed_height_mm,
                length: seq.len(),
                subtask: seq.subtask.clone(),
                subtask_names: seq.info.subtasks.clone(),
            },
            series: baselines,
            images: ImageSamples::default(),
            restarts: Vec::new(),
            failures: Vec::new(),
        })
        .collect();
    for (s, run) in runs {
        match run {
            TrialRun::Finished(series, images, restarts) => {
                results[s].series.extend(series);
                results[s].restarts.extend(restarts);
                // Jobs come in trial order: the first finished trial shows its pictures.
                if results[s].images.steps.is_empty() {
                    results[s].images = *images;
                }
            }
            TrialRun::Failed(failure) => results[s].failures.push(failure),
        }
    }
    for (s, r) in results.iter_mut().enumerate() {
        fill_baseline_images(&mut r.images, data, s, config, vision_levels);
    }
    results
}

/// Steps shown in pictures: `n` evenly spaced over `len`.
fn image_steps(len: usize, n: usize) -> Vec<usize> {
    if n <= 1 || len <= 1 {
        return vec![0];
    }
    let mut v: Vec<usize> = (0..n).map(|i| i * (len - 1) / (n - 1)).collect();
    v.dedup();
    v
}

fn run_trial(
    model: &Arc<Model<f32>>,
    backend: &dyn Backend<f32>,
    data: &Observations<f32>,
    s: usize,
    trial: usize,
    settings: &EvalSettings,
    groups: &[Group],
    masks: &[Option<Vec<bool>>],
    progress: &(dyn Fn() + Sync),
) -> Result<TrialRun> {
    let mut inference_settings: InferenceSettings = settings.inference.clone();
    inference_settings.noise = match inference_settings.noise {
        pvrnn_core::NoiseMode::Sampled { seed } => pvrnn_core::NoiseMode::Sampled {
            seed: seed.wrapping_add(trial as u64),
        },
        zero => zero,
    };
    let mut inference = OnlineInference::with_backend(model.clone(), inference_settings, backend)?;
    let len = data.lengths()[s];
    let x = |t: usize| {
        [
            data.step(Modality::Exteroceptive, s, t),
            data.step(Modality::Proprioceptive, s, t),
        ]
    };
    let mut recon = Vec::with_capacity(len);
    let mut next = Vec::with_capacity(len);
    let shown = image_steps(len, settings.image_columns);
    let mut images = ImageSamples {
        trial,
        ..ImageSamples::default()
    };
    let mut last_prior: Option<Vec<f32>> = None;
    let mut restarts = Vec::new();
    for t in 0..len {
        let out = match inference.step(x(t)[0], x(t)[1]) {
            Ok(out) => out,
            Err(pvrnn_core::Error::Numerical(message)) => {
                (t..len).for_each(|_| progress());
                return Ok(TrialRun::Failed(Failure {
                    trial,
                    step: t,
                    message,
                }));
            }
            Err(e) => return Err(e.into()),
        };
        if out.rate_halvings > 0 {
            restarts.push(Restart {
                trial,
                step: t,
                rate_halvings: out.rate_halvings,
            });
        }
        recon.push(Some(score(
            groups,
            [&out.recon[0], &out.recon[1]],
            x(t),
            masks[t].as_deref(),
        )));
        next.push((t + 1 < len).then(|| {
            score(
                groups,
                [&out.prior_next[0], &out.prior_next[1]],
                x(t + 1),
                masks[t + 1].as_deref(),
            )
        }));
        if shown.contains(&t) {
            images.steps.push(t);
            images.actual.push(x(t)[0].to_vec());
            images.recon.push(out.recon[0].clone());
            images.predicted.push(last_prior.take());
        }
        last_prior = Some(out.prior_next[0].clone());
        progress();
    }
    let series = |target, steps| Series {
        source: Source::Model,
        target,
        trial: Some(trial),
        steps,
    };
    Ok(TrialRun::Finished(
        [series(Target::Recon, recon), series(Target::Next, next)],
        Box::new(images),
        restarts,
    ))
}

fn fill_baseline_images(
    images: &mut ImageSamples,
    data: &Observations<f32>,
    s: usize,
    config: &pvrnn_core::ModelConfig,
    vision_levels: usize,
) {
    images.upsampled = images
        .steps
        .iter()
        .map(|&t| {
            upsampled_vision(
                &config.vision,
                data.step(Modality::Exteroceptive, s, t),
                vision_levels,
            )
        })
        .collect();
}
