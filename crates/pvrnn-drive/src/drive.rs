//! The closed loop, one step at a time ([`Drive`]), and what an episode leaves
//! ([`Episode`]).
//!
//! Step t: the environment's observation of step t (cameras, noisy joints and torques;
//! perturbed as the spec says) goes into the network's online inference, whose one-step
//! prediction of the joint angles at t+1 is the command the environment moves the arms
//! toward. Without a network (the mean-trajectory baseline) the command is the baseline's.
//! A vision drop (`VisionDrop`) switches the inference to fewer vision levels at its step,
//! as a branch of a run does (`OnlineInference::reobserve`).

use std::sync::Arc;

use caresim::env::{Environment, Observation};
use caresim::outcome::{Outcome, demonstration};
use caresim::{StepRecord, TrialSpec};
use pvrnn_core::backend::Backend;
use pvrnn_core::config::ModelConfig;
use pvrnn_core::data::Observed;
use pvrnn_core::infer::{InferenceSettings, OnlineInference, Run, StepOutput};
use pvrnn_core::params::Model;
use pvrnn_dataset::Sequence;
use pvrnn_dataset::inputs::step_vision_vector;

use crate::baseline::mean_trajectory;
use crate::spec::{Controller, DriveSpec};
use crate::{Error, Result};

/// The joint angles are the first 14 proprioceptive dimensions (left arm, then right).
const JOINTS: usize = 14;
/// What an occluded camera shows.
const OCCLUDED: u8 = 128;

/// Checks that a network can drive caresim's robot: two 64x64 cameras at the top of its
/// vision pyramid, 14 joint angles and 14 torques, and the proprioceptive ranges to read
/// its predictions in radians.
pub fn check_model(config: &ModelConfig) -> Result<()> {
    let vision = &config.vision;
    if vision.cameras != 2 || vision.resolutions.last() != Some(&caresim::IMAGE_SIZE) {
        return Err(Error::Invalid(format!(
            "the model sees {} camera(s) at {:?}; caresim's robot has 2 cameras of {s}x{s}, so the model's highest resolution must be {s}",
            vision.cameras,
            vision.resolutions,
            s = caresim::IMAGE_SIZE
        )));
    }
    if config.proprio_dims != 2 * JOINTS {
        return Err(Error::Invalid(format!(
            "the model has {} proprioceptive dimensions; caresim's robot has 28 (14 joint angles, 14 torques)",
            config.proprio_dims
        )));
    }
    if config.normalisation.is_none() {
        return Err(Error::Invalid(
            "the model has no proprioception ranges, so its predictions cannot be read as joint angles; train it on a dataset first".into(),
        ));
    }
    Ok(())
}

/// The network that drives: the model, its inference settings (H, iterations, rate,
/// what is observed, the noise seed) and the backend it runs on.
pub type Network<'a> = (Arc<Model<f32>>, InferenceSettings, &'a dyn Backend<f32>);

/// One step's report.
#[derive(Clone, Debug)]
pub struct DriveStep {
    /// The observation of this step (as the network was given it).
    pub observation: Observation,
    /// The network's inference of this step (none for the mean-trajectory baseline).
    pub network: Option<StepOutput<f32>>,
    /// The command sent for the next step (none at the last step).
    pub command: Option<[f64; 14]>,
}

/// An episode in progress.
pub struct Drive {
    spec: DriveSpec,
    trial: TrialSpec,
    env: Environment,
    inference: Option<OnlineInference<f32>>,
    /// The settings the inference started with (the run's: a vision drop is in the spec).
    start_settings: Option<InferenceSettings>,
    /// The mean-trajectory baseline's commands.
    planned: Option<Vec<[f64; 14]>>,
    /// The observation the next `step` takes in.
    next: Option<Observation>,
    observations: Vec<Observation>,
    outputs: Vec<StepOutput<f32>>,
    commands: Vec<[f64; 14]>,
}

impl std::fmt::Debug for Drive {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Drive")
            .field("spec", &self.spec)
            .field("steps_done", &self.steps_done())
            .finish_non_exhaustive()
    }
}

impl Drive {
    /// Resets the environment to `spec`'s trial with the `network` that drives (the
    /// mean-trajectory baseline needs none).
    pub fn start(spec: DriveSpec, network: Option<Network<'_>>) -> Result<Self> {
        let trial = spec.trial()?;
        let p = spec.perturbations;
        if p.vision_drop.is_some() && spec.controller != Controller::Network {
            return Err(Error::Invalid(format!(
                "a vision drop needs the network in closed loop; the {} controller observes no vision",
                spec.controller.name()
            )));
        }
        let (mut env, first) = Environment::reset_with(trial.clone(), spec.speed_limit);
        env.set_sensor_noise(p.sensor_noise)?;
        let inference = match (spec.controller.uses_network(), network) {
            (false, _) => None,
            (true, None) => {
                return Err(Error::Invalid(format!(
                    "the {} controller needs a model",
                    spec.controller.name()
                )));
            }
            (true, Some((model, mut settings, backend))) => {
                check_model(&model.config)?;
                if spec.controller == Controller::Prior {
                    // Nothing observed and no updates: each step's posterior is its prior.
                    settings.observed = Observed {
                        vision_levels: 0,
                        proprio: false,
                    };
                    settings.iterations = 0;
                }
                Some(OnlineInference::with_backend(model, settings, backend)?)
            }
        };
        let start_settings = inference.as_ref().map(|i| i.settings().clone());
        let planned = (spec.controller == Controller::MeanTrajectory)
            .then(|| mean_trajectory(&spec, env.len()))
            .transpose()?;
        let mut drive = Self {
            spec,
            trial,
            env,
            inference,
            start_settings,
            planned,
            next: None,
            observations: Vec::new(),
            outputs: Vec::new(),
            commands: Vec::new(),
        };
        drive.next = Some(drive.perceived(first));
        Ok(drive)
    }

    pub fn spec(&self) -> &DriveSpec {
        &self.spec
    }
    pub fn trial(&self) -> &TrialSpec {
        &self.trial
    }
    /// The episode's length in steps.
    pub fn len(&self) -> usize {
        self.env.len()
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Steps whose observation has been taken in.
    pub fn steps_done(&self) -> usize {
        self.observations.len()
    }
    pub fn is_over(&self) -> bool {
        self.next.is_none()
    }
    /// The environment (its scene, for rendering and inspection).
    pub fn environment(&self) -> &Environment {
        &self.env
    }

    /// The network's inference of each step taken so far (none for the mean trajectory).
    pub fn outputs(&self) -> &[StepOutput<f32>] {
        &self.outputs
    }

    /// The latest observation taken in (none before the first step).
    pub fn latest(&self) -> Option<&Observation> {
        self.observations.last()
    }

    /// Pushes arm `arm` by `radians` (every joint) in the next step, as if a person shoved
    /// it now; the spec records it (a push at that step), so the episode can be replayed.
    /// Replaces an earlier push.
    pub fn push_now(&mut self, arm: usize, radians: f64) -> Result<()> {
        if arm > 1 || !radians.is_finite() {
            return Err(Error::Invalid(format!(
                "push: arm {arm} by {radians} rad (arm 0 or 1, a finite angle)"
            )));
        }
        self.spec.perturbations.push = Some(crate::spec::Push {
            step: self.observations.len() + 1,
            arm,
            radians,
        });
        Ok(())
    }

    /// Occludes camera `camera` for `steps` steps from the next one on (the spec records
    /// it). Replaces an earlier occlusion.
    pub fn occlude_now(&mut self, camera: usize, steps: usize) -> Result<()> {
        if camera > 1 {
            return Err(Error::Invalid(format!(
                "occlusion: camera {camera} does not exist (0 left, 1 right)"
            )));
        }
        self.spec.perturbations.occlusion = Some(crate::spec::Occlusion {
            camera,
            from: self.observations.len() + 1,
            steps,
        });
        Ok(())
    }

    /// From the next step on, the network observes only the lowest `levels` vision
    /// resolutions (0: none); the spec records it. Replaces an earlier drop that has not
    /// happened yet. Only a network that observes vision can lose it.
    pub fn drop_vision_now(&mut self, levels: usize) -> Result<()> {
        let Some(inference) = &self.inference else {
            return Err(Error::Invalid(format!(
                "the {} controller has no vision to drop",
                self.spec.controller.name()
            )));
        };
        let observed = inference.settings().observed.vision_levels;
        if levels >= observed {
            return Err(Error::Invalid(format!(
                "vision drop to {levels} levels: the network observes {observed} now"
            )));
        }
        self.spec.perturbations.vision_drop = Some(crate::spec::VisionDrop {
            from: self.observations.len(),
            levels,
        });
        Ok(())
    }

    /// The network's inputs for an observation: the vision pyramid, and the joints and
    /// torques in model units.
    fn network_inputs(config: &ModelConfig, o: &Observation) -> (Vec<f32>, Vec<f32>) {
        let mut extero = vec![0f32; config.vision.dims()];
        step_vision_vector(&o.images, 2, &config.vision, &mut extero);
        let norm = config.normalisation.as_ref().expect("checked at the start");
        let proprio = o
            .joints
            .iter()
            .chain(&o.torques)
            .enumerate()
            .map(|(d, &v)| norm.proprio_to_model(d, v as f64) as f32)
            .collect();
        (extero, proprio)
    }

    /// Switches the inference to the spec's vision drop when step `t` is its first.
    fn apply_vision_drop(&mut self, t: usize) -> Result<()> {
        let (Some(drop), Some(inference)) =
            (self.spec.perturbations.vision_drop, self.inference.as_mut())
        else {
            return Ok(());
        };
        if drop.from != t || inference.settings().observed.vision_levels == drop.levels {
            return Ok(());
        }
        let config = &inference.model().config;
        let window = inference.window_len();
        let inputs: Vec<(Vec<f32>, Vec<f32>)> = self.observations[t - window..t]
            .iter()
            .map(|o| Self::network_inputs(config, o))
            .collect();
        let slices: Vec<(&[f32], &[f32])> = inputs
            .iter()
            .map(|(e, p)| (e.as_slice(), p.as_slice()))
            .collect();
        let observed = Observed {
            vision_levels: drop.levels,
            ..inference.settings().observed
        };
        inference.reobserve(observed, &slices)?;
        Ok(())
    }

    /// The observation as the robot's sensors give it to the network: a camera occluded
    /// in this step shows mid-grey.
    fn perceived(&self, mut o: Observation) -> Observation {
        if let Some(occ) = self.spec.perturbations.occlusion
            && occ.covers(o.step - 1)
        {
            let frame = o.images.len() / 2;
            o.images[occ.camera * frame..(occ.camera + 1) * frame].fill(OCCLUDED);
        }
        o
    }

    /// Takes in the next observation, sends the next command; `None` once the episode is
    /// over.
    pub fn step(&mut self) -> Result<Option<DriveStep>> {
        let Some(observation) = self.next.take() else {
            return Ok(None);
        };
        let t = self.observations.len();
        self.apply_vision_drop(t)?;
        let network = match self.inference.as_mut() {
            Some(inference) => {
                let (extero, proprio) =
                    Self::network_inputs(&inference.model().config, &observation);
                Some(inference.step(&extero, &proprio)?)
            }
            None => None,
        };
        let last = t + 1 >= self.env.len();
        let command = if last {
            None
        } else {
            Some(self.command(t, network.as_ref())?)
        };
        if let Some(c) = command {
            let mut moved_to = c;
            if let Some(push) = self.spec.perturbations.push
                && push.step == t + 1
            {
                // Shoved during the step: the arm lands displaced from where it was sent
                // (at any speed limit), and the network sees it there.
                self.env.push(push.arm, &[push.radians; 7])?;
                for q in &mut moved_to[push.arm * 7..push.arm * 7 + 7] {
                    *q += push.radians;
                }
            }
            let o = self.env.step(&moved_to)?;
            self.next = Some(self.perceived(o));
            self.commands.push(c);
        }
        self.observations.push(observation.clone());
        if let Some(n) = &network {
            self.outputs.push(n.clone());
        }
        Ok(Some(DriveStep {
            observation,
            network,
            command,
        }))
    }

    /// The command for step t + 1: the network's predicted joint angles in radians, or
    /// the baseline's.
    fn command(&self, t: usize, network: Option<&StepOutput<f32>>) -> Result<[f64; 14]> {
        if let Some(planned) = &self.planned {
            return Ok(planned[t + 1]);
        }
        let (out, inference) = network
            .zip(self.inference.as_ref())
            .ok_or_else(|| Error::Invalid("no network output to command from".into()))?;
        let norm = inference
            .model()
            .config
            .normalisation
            .as_ref()
            .expect("checked at the start");
        let mut command = [0.0; 14];
        for (j, c) in command.iter_mut().enumerate() {
            let v = out.prior_next[1][j] as f64;
            if !v.is_finite() {
                return Err(Error::Invalid(format!(
                    "step {t}: the network's prediction of joint {j} is {v}; no command can be sent"
                )));
            }
            *c = norm.proprio_from_model(j, v);
        }
        Ok(command)
    }

    /// Runs the episode to its end, calling `progress(steps done, length)` after each step.
    pub fn finish(mut self, progress: &mut dyn FnMut(usize, usize)) -> Result<Episode> {
        let len = self.len();
        while self.step()?.is_some() {
            progress(self.steps_done(), len);
        }
        Ok(self.episode())
    }

    /// What the robot has sensed so far, as a dataset sequence (one step per step done).
    pub fn sequence_so_far(&self) -> Sequence {
        caresim::env::episode_sequence(&self.trial, &self.observations)
    }

    /// The network's inference so far (none for the mean-trajectory baseline).
    pub fn run_so_far(&self) -> Option<Run<f32>> {
        self.start_settings
            .as_ref()
            .map(|s| Run::from_steps(s.clone(), &self.outputs, false))
    }

    /// What the episode leaves so far: the recording, the network's run, the outcome
    /// (judged against the scripted demonstration, which is simulated for it).
    pub fn episode(&self) -> Episode {
        let records: Vec<StepRecord> = self.observations.iter().map(|o| o.record.clone()).collect();
        let (demo_sim, demo) = demonstration(&self.trial);
        Episode {
            spec: self.spec.clone(),
            trial: self.trial.clone(),
            sequence: self.sequence_so_far(),
            run: self.run_so_far(),
            outcome: Outcome::assess(self.env.simulation(), &records, &demo),
            demonstration: Outcome::assess(&demo_sim, &demo, &demo),
            commands: self.commands.clone(),
        }
    }
}

/// A finished (or stopped) episode.
#[derive(Clone, Debug)]
pub struct Episode {
    pub spec: DriveSpec,
    pub trial: TrialSpec,
    /// What the robot sensed, as a dataset sequence.
    pub sequence: Sequence,
    /// The network's inference over the episode (compact: no read-outs).
    pub run: Option<Run<f32>>,
    pub outcome: Outcome,
    /// The scripted demonstration's own outcome, for comparison.
    pub demonstration: Outcome,
    /// The commands sent (one fewer than the steps).
    pub commands: Vec<[f64; 14]>,
}
