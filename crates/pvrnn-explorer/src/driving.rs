//! Where the Drive window's episode is stepped (`pvrnn_drive`): what the window asks
//! ([`DriveRequest`]), what it shows while the robot acts ([`DriveProgress`]) and what a
//! finished episode leaves ([`FinishedDrive`]). [`LocalDrive`] steps an episode on the
//! thread that calls it: the page or the desktop window between frames, or the web worker
//! between its ticks (`worker`); the executors (`executor::Executor`) say which. No egui.

use std::sync::Arc;

use pvrnn_core::Model;
use pvrnn_core::config::ModelConfig;
use pvrnn_core::infer::Run;
use pvrnn_core::io::{self, StateStorage, TensorFile};
use pvrnn_dataset::{ProprioLayout, Sequence, SequenceInfo};
use pvrnn_drive::{Drive, DriveSpec, Episode};
use serde::{Deserialize, Serialize};
use web_time::{Duration, Instant};

use crate::condition::Condition;

/// How far a push turns every joint of the arm (rad).
pub const PUSH_RADIANS: f64 = 0.2;
/// How long a camera stays covered (steps).
pub const OCCLUSION_STEPS: usize = 30;
/// Numbers per step in [`DriveProgress::live`].
pub const LIVE_PER_STEP: usize = 6;
/// The name the episode being driven has in the open data while it runs (the finished
/// episode gets its own, `state::drive_episode_name`).
pub const EPISODE_SO_FAR: &str = "drive in progress";
/// How often the episode so far ([`EpisodeSoFar`]) is taken while the robot acts: the
/// main panels follow it at this rate without copying the whole recording every step.
pub const SO_FAR_EVERY: Duration = Duration::from_millis(500);

/// What the Drive window asks of wherever the episode is stepped.
#[derive(Clone, Debug, PartialEq)]
pub enum DriveRequest {
    /// Reset the trial and let the spec's controller act, under `condition` (the network's
    /// inference: what it observes, H, iterations, rate, noise seed).
    Start {
        spec: Box<DriveSpec>,
        condition: Condition,
    },
    /// Turn every joint of an arm (0 left, 1 right) by [`PUSH_RADIANS`] before the next step.
    Push(usize),
    /// Cover a camera (0 left, 1 right) for [`OCCLUSION_STEPS`] steps from the next one.
    Occlude(usize),
    /// From the next step on, the network observes only the lowest this many vision
    /// resolutions (0: none).
    DropVision(usize),
    /// Abandon the episode.
    Stop,
}

/// An episode in progress, as the window shows it.
#[derive(Clone, Debug, PartialEq)]
pub struct DriveProgress {
    /// The drive so far (the perturbations made while it acts included).
    pub spec: DriveSpec,
    pub condition: Condition,
    /// caresim's name of the trial.
    pub trial: String,
    pub steps_done: usize,
    /// The episode's length (0 until the environment said).
    pub len: usize,
    /// The latest step and both cameras as the network was given them (64x64 RGB each).
    pub cameras: Option<(usize, Vec<u8>)>,
    /// How the network copes, per step taken ([`LIVE_PER_STEP`] numbers each; empty
    /// without a network): its reconstruction's mean squared error against everything the
    /// robot sensed (vision, proprioception; model units), then each module's KL in the
    /// inference window (executive, associative, exteroceptive, proprioceptive).
    pub live: Vec<f32>,
    /// The episode so far, for the main panels (refreshed at most every
    /// [`SO_FAR_EVERY`]; none before the first step).
    pub so_far: Option<Arc<EpisodeSoFar>>,
}

/// A finished episode, as the page keeps it.
#[derive(Clone, Debug, PartialEq)]
pub struct FinishedDrive {
    /// The drive as it happened (perturbations included): one text, one episode.
    pub spec: DriveSpec,
    pub condition: Condition,
    /// What the robot sensed, as a dataset sequence.
    pub sequence: Sequence,
    /// The network's inference over the episode (none for the mean trajectory).
    pub run: Option<Run<f32>>,
    /// The outcome in words (`Outcome::summary`).
    pub summary: String,
    /// Whether the scripted demonstration of the same trial succeeded.
    pub demonstration_success: bool,
}

impl FinishedDrive {
    pub fn new(episode: Episode, condition: Condition) -> Self {
        Self {
            summary: episode.outcome.summary(),
            demonstration_success: episode.demonstration.success,
            spec: episode.spec,
            condition,
            sequence: episode.sequence,
            run: episode.run,
        }
    }
}

/// An episode (finished or so far) as the web worker sends it to the page: the sequence as
/// the dataset's file, the network's run as `pvrnn infer` writes it (in f32: the page shows
/// what was computed), the rest as JSON ([`FinishedDrive::to_parts`],
/// [`EpisodeSoFar::to_parts`]).
#[derive(Clone, Debug, PartialEq)]
pub struct EpisodeParts {
    pub header: String,
    pub sequence: Vec<u8>,
    pub run: Option<Vec<u8>>,
}

/// What a sequence's file does not say of it.
#[derive(Serialize, Deserialize)]
struct RecordingHeader {
    info: SequenceInfo,
    cameras: usize,
    image_size: usize,
    /// Joint angles, torques, other channels.
    layout: [usize; 3],
}

/// What a finished episode's files do not say.
#[derive(Serialize, Deserialize)]
struct FinishedHeader {
    spec: String,
    condition: Condition,
    summary: String,
    demonstration_success: bool,
    #[serde(flatten)]
    recording: RecordingHeader,
}

/// A recording and its run as bytes; `config` is the driving network's (for the run's
/// file), `header` makes the JSON part from what the sequence's file does not say.
fn encode<H: Serialize>(
    sequence: &Sequence,
    run: Option<&Run<f32>>,
    config: &ModelConfig,
    header: impl FnOnce(RecordingHeader) -> H,
) -> Result<EpisodeParts, String> {
    let layout = sequence.proprio_layout();
    let recording = RecordingHeader {
        info: sequence.info.clone(),
        cameras: sequence.cameras,
        image_size: sequence.image_size,
        layout: [layout.joints, layout.torques, layout.extra],
    };
    let name = std::slice::from_ref(&sequence.info.name);
    let run = run
        .map(|run| {
            let runs = std::slice::from_ref(run);
            io::runs_to_bytes(config, runs, &[0], Some(name), StateStorage::F32)
        })
        .transpose()
        .map_err(|e| e.to_string())?;
    Ok(EpisodeParts {
        header: serde_json::to_string(&header(recording)).map_err(|e| e.to_string())?,
        sequence: sequence.to_bytes().map_err(|e| e.to_string())?,
        run,
    })
}

/// Reads [`encode`] back; `config` is the open network's (to read the run).
fn decode(
    header: RecordingHeader,
    sequence: Vec<u8>,
    run: Option<Vec<u8>>,
    config: Option<&ModelConfig>,
    what: &str,
) -> Result<(Sequence, Option<Run<f32>>), String> {
    let [joints, torques, extra] = header.layout;
    let sequence = Sequence::from_bytes(
        sequence,
        &format!("{what}'s sequence"),
        &header.info,
        header.cameras,
        header.image_size,
        ProprioLayout {
            joints,
            torques,
            extra,
        },
    )
    .map_err(|e| e.to_string())?;
    let run = match run {
        None => None,
        Some(bytes) => {
            let config = config.ok_or_else(|| format!("{what}'s run arrived without its model"))?;
            let file = TensorFile::from_bytes(bytes, format!("{what}'s run"))
                .map_err(|e| e.to_string())?;
            let mut runs = io::load_runs(&file, config).map_err(|e| e.to_string())?;
            if runs.len() != 1 {
                return Err(format!("{what}'s run file holds {} runs", runs.len()));
            }
            Some(runs.remove(0).run)
        }
    };
    Ok((sequence, run))
}

impl FinishedDrive {
    /// The episode as bytes; `config` is the driving network's (for its run's file).
    pub fn to_parts(&self, config: &ModelConfig) -> Result<EpisodeParts, String> {
        encode(&self.sequence, self.run.as_ref(), config, |recording| {
            FinishedHeader {
                spec: self.spec.to_text(),
                condition: self.condition,
                summary: self.summary.clone(),
                demonstration_success: self.demonstration_success,
                recording,
            }
        })
    }

    /// Reads [`Self::to_parts`] back; `config` is the open network's (to read the run).
    pub fn from_parts(parts: EpisodeParts, config: Option<&ModelConfig>) -> Result<Self, String> {
        let header: FinishedHeader = serde_json::from_str(&parts.header)
            .map_err(|e| format!("a finished episode's description: {e}"))?;
        let (sequence, run) = decode(
            header.recording,
            parts.sequence,
            parts.run,
            config,
            "the finished episode",
        )?;
        Ok(Self {
            spec: DriveSpec::parse_text(&header.spec).map_err(|e| e.to_string())?,
            condition: header.condition,
            sequence,
            run,
            summary: header.summary,
            demonstration_success: header.demonstration_success,
        })
    }
}

/// The episode so far, which the main panels show while the robot acts: their traces,
/// images and errors grow with it (taken at most every [`SO_FAR_EVERY`]).
#[derive(Clone, Debug, PartialEq)]
pub struct EpisodeSoFar {
    /// What the robot has sensed, one step per step done.
    pub sequence: Sequence,
    /// The network's inference over those steps (none for the mean trajectory).
    pub run: Option<Run<f32>>,
}

impl EpisodeSoFar {
    pub fn steps(&self) -> usize {
        self.sequence.len()
    }

    /// As bytes; `config` is the driving network's.
    pub fn to_parts(&self, config: &ModelConfig) -> Result<EpisodeParts, String> {
        encode(&self.sequence, self.run.as_ref(), config, |recording| {
            recording
        })
    }

    /// Reads [`Self::to_parts`] back; `config` is the open network's.
    pub fn from_parts(parts: EpisodeParts, config: Option<&ModelConfig>) -> Result<Self, String> {
        let header: RecordingHeader = serde_json::from_str(&parts.header)
            .map_err(|e| format!("the episode so far's description: {e}"))?;
        let (sequence, run) = decode(
            header,
            parts.sequence,
            parts.run,
            config,
            "the episode so far",
        )?;
        Ok(Self { sequence, run })
    }
}

/// What happened to the episode since last asked.
#[derive(Clone, Debug, PartialEq)]
pub enum DriveEvent {
    Finished(Box<FinishedDrive>),
    /// The episode stopped (a model that cannot drive, a step that failed), and why.
    Failed(String),
}

/// Steps an episode on the calling thread.
#[derive(Default)]
pub struct LocalDrive {
    driving: Option<(Drive, Condition)>,
    /// The episode so far as last taken, and when.
    so_far: Option<(Arc<EpisodeSoFar>, Instant)>,
}

impl std::fmt::Debug for LocalDrive {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let steps = self.driving.as_ref().map(|(d, _)| d.steps_done());
        f.debug_struct("LocalDrive").field("steps", &steps).finish()
    }
}

impl LocalDrive {
    /// Applies a request; `model` is the open network (needed to start).
    pub fn request(
        &mut self,
        model: Option<&Arc<Model<f32>>>,
        request: DriveRequest,
    ) -> Result<(), String> {
        let drive = self.driving.as_mut().map(|(d, _)| d);
        match request {
            DriveRequest::Start { spec, condition } => {
                let model = model.ok_or("no network is open")?;
                self.driving = None;
                let settings = condition.settings(&model.config);
                let backend = pvrnn_core::cpu::CpuBackend;
                let network = spec.controller.uses_network().then(|| {
                    (
                        model.clone(),
                        settings,
                        &backend as &dyn pvrnn_core::backend::Backend<f32>,
                    )
                });
                let drive = Drive::start(*spec, network).map_err(|e| e.to_string())?;
                self.driving = Some((drive, condition));
                self.so_far = None;
                Ok(())
            }
            DriveRequest::Push(arm) => drive.map_or(Ok(()), |d| {
                d.push_now(arm, PUSH_RADIANS).map_err(|e| e.to_string())
            }),
            DriveRequest::Occlude(camera) => drive.map_or(Ok(()), |d| {
                d.occlude_now(camera, OCCLUSION_STEPS)
                    .map_err(|e| e.to_string())
            }),
            DriveRequest::DropVision(levels) => drive.map_or(Ok(()), |d| {
                d.drop_vision_now(levels).map_err(|e| e.to_string())
            }),
            DriveRequest::Stop => {
                self.driving = None;
                self.so_far = None;
                Ok(())
            }
        }
    }

    pub fn is_driving(&self) -> bool {
        self.driving.is_some()
    }

    /// The episode in progress.
    pub fn progress(&self) -> Option<DriveProgress> {
        let (drive, condition) = self.driving.as_ref()?;
        Some(DriveProgress {
            spec: drive.spec().clone(),
            condition: *condition,
            trial: drive.trial().name(),
            steps_done: drive.steps_done(),
            len: drive.len(),
            cameras: drive.latest().map(|o| (o.step, o.images.clone())),
            live: drive
                .outputs()
                .iter()
                .flat_map(|o| {
                    let kl = o.window_free_energy.complexity;
                    [
                        o.recon_error[0],
                        o.recon_error[1],
                        kl.executive,
                        kl.associative,
                        kl.exteroceptive,
                        kl.proprioceptive,
                    ]
                    .map(|v| v as f32)
                })
                .collect(),
            so_far: self.so_far.as_ref().map(|(s, _)| s.clone()),
        })
    }

    /// Takes the episode so far when it has grown and [`SO_FAR_EVERY`] has passed (at
    /// once after the first step).
    fn take_so_far(&mut self) {
        let Some((drive, _)) = &self.driving else {
            return;
        };
        let due = match &self.so_far {
            None => drive.steps_done() > 0,
            Some((s, at)) => s.steps() < drive.steps_done() && at.elapsed() >= SO_FAR_EVERY,
        };
        if due {
            let so_far = EpisodeSoFar {
                sequence: drive.sequence_so_far(),
                run: drive.run_so_far(),
            };
            self.so_far = Some((Arc::new(so_far), Instant::now()));
        }
    }

    /// Steps the episode for up to `budget` (at least one step); the event when it ended.
    pub fn step_for(&mut self, budget: Duration) -> Option<DriveEvent> {
        let (drive, _) = self.driving.as_mut()?;
        let started = Instant::now();
        loop {
            match drive.step() {
                Ok(Some(_)) if drive.is_over() => break,
                Ok(Some(_)) if started.elapsed() < budget => {}
                Ok(Some(_)) => {
                    self.take_so_far();
                    return None;
                }
                Ok(None) => break,
                Err(e) => {
                    self.driving = None;
                    self.so_far = None;
                    return Some(DriveEvent::Failed(e.to_string()));
                }
            }
        }
        let (drive, condition) = self.driving.take()?;
        self.so_far = None;
        Some(DriveEvent::Finished(Box::new(FinishedDrive::new(
            drive.episode(),
            condition,
        ))))
    }
}
