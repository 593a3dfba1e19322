//! caresim as an environment: a trial that a controller drives, step by step, instead of
//! its script.
//!
//! [`Environment::reset`] starts a trial (task, bed height, seed, variability, revision:
//! a [`TrialSpec`]) and returns its first observation: the arms settled into the task's
//! start posture, as the scripted trial's first step. Each [`Environment::step`] takes 14
//! joint commands (left arm, then right, rad), moves each joint toward its command as a
//! position-controlled arm would (at most a stated speed, [`SpeedLimit`]; commands beyond
//! a joint's limits stop at the limit), lets the
//! scene respond (the script's loads, the upper body's lift and the towel's grasp act
//! where the hand is where the script has it: [`crate::sim::CONTACT_TOLERANCE`]) and
//! returns the next observation: both cameras, the joint angles and torques with the same
//! sensor noise as a recording, the subtask the script is in. Replaying a scripted trial's
//! own joint angles gives its dataset sequence back byte for byte. Seeded like the rest of
//! caresim: the same trial and commands give the same episode.

use pvrnn_dataset::Sequence;

use crate::arm::{DOF, Q_MAX, Q_MIN};
use crate::sim::{IMAGE_SIZE, STEP_SECONDS, SUPERSAMPLE, Simulation, StepRecord, TrialSpec};

/// The Franka Panda's joint speed limits (rad/s), the arm caresim's kinematics are.
pub const MAX_JOINT_SPEED: [f64; DOF] = [2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61];
/// The scripted trials' envelope (rad per step): their arms move up to 1.84 rad in one
/// step (the left wrist turns over as the hand slides under the back, in every
/// repositioning trial: `cargo run --release -p caresim --example joint_speeds`), about 7x
/// what a Panda can; a replay reproduces them under this limit.
pub const SCRIPTED_MAX_STEP: f64 = 2.0;

/// How fast the environment's joints may move.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum SpeedLimit {
    /// [`SCRIPTED_MAX_STEP`] per step for every joint: what the scripted trials do, so a
    /// replay gives their recordings back.
    #[default]
    Scripted,
    /// The Franka Panda's limits ([`MAX_JOINT_SPEED`]): 0.22-0.26 rad per step.
    Panda,
}

impl SpeedLimit {
    /// Each joint's largest move in one step (rad).
    pub fn max_step(self) -> [f64; DOF] {
        match self {
            SpeedLimit::Scripted => [SCRIPTED_MAX_STEP; DOF],
            SpeedLimit::Panda => MAX_JOINT_SPEED.map(|v| v * STEP_SECONDS),
        }
    }
}

/// What the robot senses after a step.
#[derive(Clone, Debug)]
pub struct Observation {
    /// Steps taken (1 after the reset).
    pub step: usize,
    /// Both cameras' 64x64 RGB images (left, then right), as a dataset stores them.
    pub images: Vec<u8>,
    /// Joint angles (rad) and torques (N m) with sensor noise: left arm, then right.
    pub joints: [f32; 14],
    pub torques: [f32; 14],
    /// The subtask the script is in at this step.
    pub subtask: u32,
    /// The state behind it (noise-free joints and torques, hands, towel).
    pub record: StepRecord,
}

/// Why a step was refused.
#[derive(Clone, Debug, PartialEq)]
pub enum StepError {
    /// A command is NaN or infinite.
    NotFinite { joint: usize, value: f64 },
    /// The episode has taken all its steps.
    Over { steps: usize },
    /// A perturbation that cannot be applied (what, and why).
    BadPerturbation(String),
}

impl std::fmt::Display for StepError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            StepError::NotFinite { joint, value } => write!(
                f,
                "joint command {joint} ({} arm, joint {}) is {value}: a command must be a finite angle in radians",
                if *joint < DOF { "left" } else { "right" },
                joint % DOF + 1
            ),
            StepError::Over { steps } => {
                write!(f, "the episode is over: it has taken all its {steps} steps")
            }
            StepError::BadPerturbation(why) => write!(f, "{why}"),
        }
    }
}

impl std::error::Error for StepError {}

/// One trial driven by joint commands.
#[derive(Debug)]
pub struct Environment {
    sim: Simulation,
    max_step: [f64; DOF],
}

impl Environment {
    /// Starts `spec`'s trial under the scripted trials' speed limit; its first observation.
    pub fn reset(spec: TrialSpec) -> (Self, Observation) {
        Self::reset_with(spec, SpeedLimit::default())
    }

    /// Starts `spec`'s trial with its joints limited to `limit`; its first observation.
    pub fn reset_with(spec: TrialSpec, limit: SpeedLimit) -> (Self, Observation) {
        let mut sim = Simulation::new(spec);
        let record = sim.step();
        let mut env = Self {
            sim,
            max_step: limit.max_step(),
        };
        let first = env.observe(record);
        (env, first)
    }

    /// The episode's length in steps (the scripted trial's).
    pub fn len(&self) -> usize {
        self.sim.len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Steps taken so far (the reset's included).
    pub fn steps_taken(&self) -> usize {
        self.sim.steps_taken()
    }

    /// The simulation behind the episode (the scene, for inspection and rendering).
    pub fn simulation(&self) -> &Simulation {
        &self.sim
    }

    /// Moves the arms toward `commands` (14 joint angles, left arm then right, rad) for
    /// one step; the next observation. Commands beyond a joint's limits are clamped to
    /// them; a NaN or infinite one is refused.
    pub fn step(&mut self, commands: &[f64; 14]) -> Result<Observation, StepError> {
        if self.steps_taken() >= self.len() {
            return Err(StepError::Over { steps: self.len() });
        }
        if let Some((joint, &value)) = commands.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(StepError::NotFinite { joint, value });
        }
        let mut target = [[0.0; DOF]; 2];
        for arm in 0..2 {
            for j in 0..DOF {
                target[arm][j] = commands[arm * DOF + j].clamp(Q_MIN[j], Q_MAX[j]);
            }
        }
        let record = self.sim.step_commanded(&target, &self.max_step);
        Ok(self.observe(record))
    }

    /// Scales the sensor noise of the observations from the next step on (1 = a
    /// recording's; 3 = the robustness test's "proprioceptive noise x3").
    pub fn set_sensor_noise(&mut self, factor: f64) -> Result<(), StepError> {
        if !(factor.is_finite() && factor >= 0.0) {
            return Err(StepError::BadPerturbation(format!(
                "sensor noise factor {factor}: it must be a finite number of at least 0"
            )));
        }
        self.sim.sensor_noise = factor;
        Ok(())
    }

    /// Pushes arm `arm` (0 left, 1 right): its joints displaced by `delta` (rad) at once,
    /// as a hand shoving the arm would (clamped to the joints' limits); the next step
    /// moves on from there toward its commands.
    pub fn push(&mut self, arm: usize, delta: &[f64; DOF]) -> Result<(), StepError> {
        if arm > 1 {
            return Err(StepError::BadPerturbation(format!(
                "push: arm {arm} does not exist (0 left, 1 right)"
            )));
        }
        if let Some(v) = delta.iter().find(|v| !v.is_finite()) {
            return Err(StepError::BadPerturbation(format!(
                "push: a displacement of {v} rad; it must be finite"
            )));
        }
        for (j, d) in delta.iter().enumerate() {
            self.sim.q[arm][j] = (self.sim.q[arm][j] + d).clamp(Q_MIN[j], Q_MAX[j]);
        }
        Ok(())
    }

    fn observe(&mut self, record: StepRecord) -> Observation {
        let mut images = Vec::with_capacity(2 * IMAGE_SIZE * IMAGE_SIZE * 3);
        for camera in 0..2 {
            images.extend(self.sim.render(camera, true, IMAGE_SIZE, SUPERSAMPLE).rgb);
        }
        let (joints, torques) = self.sim.sensors(&record);
        Observation {
            step: self.steps_taken(),
            images,
            joints,
            torques,
            subtask: record.plan.subtask,
            record,
        }
    }
}

/// An episode's observations as a dataset sequence (the trial's name and information),
/// so that it can be evaluated, bundled and explored like a recording.
pub fn episode_sequence(spec: &TrialSpec, observations: &[Observation]) -> Sequence {
    let mut seq = Sequence {
        info: crate::sim::sequence_info(spec, observations.len()),
        cameras: 2,
        image_size: IMAGE_SIZE,
        images: Vec::new(),
        joints: Vec::new(),
        torques: Vec::new(),
        subtask: Vec::new(),
        extra: Vec::new(),
        images_without_robot: None,
    };
    for o in observations {
        seq.images.extend_from_slice(&o.images);
        seq.joints.extend(o.joints);
        seq.torques.extend(o.torques);
        seq.subtask.push(o.subtask);
    }
    seq
}
