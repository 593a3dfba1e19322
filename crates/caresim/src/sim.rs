//! Running a trial: inverse kinematics, towel, torques and both cameras, step by step.

use glam::{DAffine3, DVec3};
use pvrnn_dataset::{Sequence, SequenceInfo, Split};

use crate::arm::DOF;
use crate::body::Mannequin;
use crate::cloth::Cloth;
use crate::render::{self, Camera, Frame, Material};
use crate::revision::Revision;
use crate::scene::{self, Robot};
use crate::shapes::{Mesh, Shape};
use crate::task::{Plan, Script, SimRng, Task, Variation};

/// Camera image size and supersampling.
pub const IMAGE_SIZE: usize = 64;
pub const SUPERSAMPLE: usize = 4;
/// Seconds per step (caresim's clock, the towel's too).
pub const STEP_SECONDS: f64 = 0.1;
const TOWEL_SIZE: f64 = 0.30;
const TOWEL_PARTICLES: usize = 11;
/// Sensor noise (std) of joint angles (rad) and torques (N m).
const JOINT_NOISE: f64 = 2e-4;
const TORQUE_NOISE: f64 = 0.05;
/// Revision 2: where loads act, from the palm's centre along the hand's x axis (m).
const PALM_CONTACT: f64 = 0.04;
/// A commanded hand acts on the scene (load, lift, grasp) only this close to where the
/// script puts it (m): three times the scripted inverse kinematics' largest error.
pub const CONTACT_TOLERANCE: f64 = 0.03;
/// An unsupported upper body sinks back by this factor of its lift each step.
pub const LIFT_RELAX: f64 = 0.8;

/// Which trial to simulate.
#[derive(Clone, Debug, PartialEq)]
pub struct TrialSpec {
    pub task: Task,
    pub bed_height_mm: u32,
    pub split: Split,
    /// Trial number within its task, height and split.
    pub index: usize,
    pub seed: u64,
    /// The task's variability factor (1 = the default benchmark; see
    /// [`crate::variability`]).
    pub variability: f64,
    /// Which edition of the benchmark.
    pub revision: Revision,
}

impl TrialSpec {
    pub fn name(&self) -> String {
        format!(
            "{}_{}mm_{}{}",
            self.task.name(),
            self.bed_height_mm,
            self.split.name(),
            self.index
        )
    }
}

/// A step's state besides the recorded signals (for tests and diagnostics).
#[derive(Clone, Debug)]
pub struct StepRecord {
    pub plan: Plan,
    /// Joint angles and torques without sensor noise (left arm, right arm).
    pub q: [[f64; DOF]; 2],
    pub torques: [[f64; DOF]; 2],
    pub ik_position_error: [f64; 2],
    pub tcp: [DAffine3; 2],
    pub towel_centroid: Option<DVec3>,
    pub towel_grip_error: Option<f64>,
    /// The upper body's lift after the step (rad): the script's where the left hand is
    /// in place, sinking back where it is not ([`LIFT_RELAX`]).
    pub lift: f64,
}

/// One trial in progress.
#[derive(Debug)]
pub struct Simulation {
    pub spec: TrialSpec,
    pub robot: Robot,
    pub body: Mannequin,
    pub script: Script,
    pub towel: Option<Cloth>,
    pub bed_top: f64,
    pub q: [[f64; DOF]; 2],
    /// The sensor noise's scale (1 = a recording's: joints 2e-4 rad, torques 0.05 N m);
    /// the same draws, scaled, so 3 gives the recording's noise times 3.
    pub sensor_noise: f64,
    step: usize,
    noise: SimRng,
    lift: f64,
    body_cache: Option<(f64, Vec<(Mesh, Material)>)>,
}

impl Simulation {
    pub fn new(spec: TrialSpec) -> Self {
        Self::with_robot(spec, Robot::default())
    }

    pub fn with_robot(spec: TrialSpec, robot: Robot) -> Self {
        let variation = Variation::draw(spec.task, spec.seed, spec.variability);
        let bed_top = spec.bed_height_mm as f64 / 1000.0;
        let body = Mannequin::new(scene::HIPS, bed_top, variation.posture);
        let towel = variation.wipe.as_ref().map(|w| {
            let lm = body.landmarks();
            let across = DVec3::Z.cross(lm.along);
            let shapes = body.shapes(0.0);
            let mut centre = lm.belly + lm.along * w.towel_offset[0] + across * w.towel_offset[1];
            // Laid down just above the body, then left to drape.
            centre.z =
                crate::shapes::surface_height(&shapes, centre.x, centre.y, bed_top + 0.6, bed_top)
                    .unwrap_or(bed_top)
                    + 0.02;
            let mut towel = Cloth::new(
                centre,
                w.towel_yaw + body.posture.yaw,
                TOWEL_SIZE,
                TOWEL_PARTICLES,
            );
            for _ in 0..20 {
                towel.step(STEP_SECONDS, 8, &shapes, bed_top, None);
            }
            towel
        });
        let grasp = towel.as_ref().map(Cloth::grasp_point);
        let script = Script::new(spec.task, variation, &body, bed_top, grasp, spec.revision);
        let mut q = robot.rest;
        // Settle into the first targets from the rest posture.
        let first = script.at(0, &body);
        for arm in 0..2 {
            robot.arms[arm].solve_ik(&mut q[arm], &first.hands[arm], &robot.rest[arm]);
        }
        Self {
            noise: SimRng::new(spec.seed ^ 0x5EED_0F5E_0015),
            spec,
            robot,
            body,
            script,
            towel,
            bed_top,
            q,
            sensor_noise: 1.0,
            step: 0,
            lift: 0.0,
            body_cache: None,
        }
    }

    pub fn len(&self) -> usize {
        self.script.len()
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Advances one step as scripted (the arms follow the script's hand targets by
    /// inverse kinematics); returns its state.
    pub fn step(&mut self) -> StepRecord {
        self.advance(None)
    }

    /// Advances one step with the arms moved toward `commanded` joint angles instead
    /// ([`crate::env`]): each joint by at most `max_step` (rad), exactly onto its command
    /// when that is within reach. The scene responds as the script has it only where the
    /// hand is: a load, the upper body's lift (left hand) and the towel's grasp (right
    /// hand) act when that hand is within [`CONTACT_TOLERANCE`] of the script's target;
    /// an unsupported upper body sinks back ([`LIFT_RELAX`] a step).
    pub(crate) fn step_commanded(
        &mut self,
        commanded: &[[f64; DOF]; 2],
        max_step: &[f64; DOF],
    ) -> StepRecord {
        self.advance(Some((commanded, max_step)))
    }

    fn advance(&mut self, commanded: Option<(&[[f64; DOF]; 2], &[f64; DOF])>) -> StepRecord {
        let plan = self.script.at(self.step, &self.body);
        let mut ik_err = [0.0; 2];
        match commanded {
            None => {
                for arm in 0..2 {
                    ik_err[arm] = self.robot.arms[arm]
                        .solve_ik(&mut self.q[arm], &plan.hands[arm], &self.robot.rest[arm])
                        .position_error;
                }
            }
            Some((target, max_step)) => {
                for arm in 0..2 {
                    for j in 0..DOF {
                        let (q, to) = (self.q[arm][j], target[arm][j]);
                        // Onto the command itself when it is within reach (q + (to - q)
                        // need not round to `to`).
                        self.q[arm][j] = if (to - q).abs() <= max_step[j] {
                            to
                        } else {
                            q + max_step[j].copysign(to - q)
                        };
                    }
                }
            }
        }
        let tcp = [0, 1].map(|a| self.robot.arms[a].fk(&self.q[a]).tcp);
        // Where the script's contacts act: always when it moves the arms itself.
        let in_place = match commanded {
            None => [true; 2],
            Some(_) => [0, 1].map(|a| {
                let off = (tcp[a].translation - plan.hands[a].position).length();
                ik_err[a] = off;
                off < CONTACT_TOLERANCE
            }),
        };
        self.lift = if in_place[0] {
            plan.lift
        } else {
            self.lift * LIFT_RELAX
        };
        if let Some(towel) = self.towel.as_mut() {
            if plan.grasping && in_place[1] && !towel.is_grasped() {
                towel.grasp(&tcp[1], 0.04);
            } else if !plan.grasping && towel.is_grasped() {
                towel.release();
            }
            let mut colliders = self.body.shapes(0.0);
            if !towel.is_grasped() {
                colliders.push(scene::hand_shape(&tcp[1]));
            }
            towel.step(
                STEP_SECONDS,
                8,
                &colliders,
                self.bed_top,
                towel.is_grasped().then_some(&tcp[1]),
            );
        }
        let contact = match self.spec.revision {
            Revision::R1 => 0.0,
            Revision::R2 => PALM_CONTACT,
        };
        let forces = [0, 1].map(|a| {
            if in_place[a] {
                plan.forces[a]
            } else {
                DVec3::ZERO
            }
        });
        let torques =
            [0, 1].map(|a| self.robot.arms[a].static_torques_at(&self.q[a], forces[a], contact));
        self.step += 1;
        StepRecord {
            plan,
            q: self.q,
            torques,
            ik_position_error: ik_err,
            tcp,
            towel_centroid: self.towel.as_ref().map(Cloth::centroid),
            towel_grip_error: self
                .towel
                .as_ref()
                .filter(|t| t.is_grasped())
                .map(|t| t.grip_error(&tcp[1])),
            lift: self.lift,
        }
    }

    /// Steps taken so far.
    pub fn steps_taken(&self) -> usize {
        self.step
    }

    /// The upper body's lift now (rad).
    pub fn lift(&self) -> f64 {
        self.lift
    }

    /// Renders camera `camera` (0 left, 1 right) in the current state.
    pub fn render(
        &mut self,
        camera: usize,
        with_robot: bool,
        size: usize,
        supersample: usize,
    ) -> Frame {
        let cam: Camera = self.robot.cameras[camera];
        self.render_from(&cam, with_robot, size, supersample)
    }

    /// Renders the current state from any camera (e.g. an overview for people).
    pub fn render_from(
        &mut self,
        cam: &Camera,
        with_robot: bool,
        size: usize,
        supersample: usize,
    ) -> Frame {
        let stale = self
            .body_cache
            .as_ref()
            .is_none_or(|(lift, _)| (lift - self.lift).abs() > 1e-9);
        if stale {
            let head = match self.body.parts(0.0)[5].shape {
                Shape::Ellipsoid { c, .. } => c,
                _ => self.body.origin,
            };
            let mut meshes = scene::room_meshes(self.bed_top, head);
            meshes.extend(scene::body_meshes(&self.body, self.lift));
            self.body_cache = Some((self.lift, meshes));
        }
        let mut items: Vec<(&Mesh, Material)> = Vec::new();
        let cached = &self.body_cache.as_ref().expect("filled above").1;
        items.extend(cached.iter().map(|(m, mat)| (m, *mat)));
        let robot = if with_robot {
            self.robot.meshes(&self.q)
        } else {
            Vec::new()
        };
        items.extend(robot.iter().map(|(m, mat)| (m, *mat)));
        let towel = self
            .towel
            .as_ref()
            .map(|t| (t.mesh(), scene::towel_material()));
        if let Some((m, mat)) = &towel {
            items.push((m, *mat));
        }
        render::render(&items, cam, size, supersample, scene::BACKGROUND)
    }

    /// Noisy sensor readings of a step: 14 joint angles, 14 torques (left arm, then right).
    pub(crate) fn sensors(&mut self, record: &StepRecord) -> ([f32; 14], [f32; 14]) {
        let mut joints = [0f32; 14];
        let mut torques = [0f32; 14];
        for arm in 0..2 {
            for j in 0..DOF {
                // x 1.0 is exact: a recording's bytes do not change.
                joints[arm * DOF + j] = (record.q[arm][j]
                    + JOINT_NOISE * self.sensor_noise * self.noise.normal())
                    as f32;
                torques[arm * DOF + j] = (record.torques[arm][j]
                    + TORQUE_NOISE * self.sensor_noise * self.noise.normal())
                    as f32;
            }
        }
        (joints, torques)
    }
}

/// A trial's proprioception alone: a sequence with no cameras whose joint angles, torques
/// and subtasks are those [`simulate`] records, bytes and noise included (the sensor noise
/// is drawn only for proprioception), at a small part of its cost: no frame is rendered.
pub fn simulate_proprioception(spec: &TrialSpec) -> Sequence {
    let mut sim = Simulation::new(spec.clone());
    let t = sim.len();
    let (mut joints, mut torques) = (Vec::with_capacity(t * 14), Vec::with_capacity(t * 14));
    let mut subtask = Vec::with_capacity(t);
    for _ in 0..t {
        let record = sim.step();
        let (j, tq) = sim.sensors(&record);
        joints.extend(j);
        torques.extend(tq);
        subtask.push(record.plan.subtask);
    }
    Sequence {
        info: sequence_info(spec, t),
        cameras: 0,
        image_size: 0,
        images: Vec::new(),
        joints,
        torques,
        subtask,
        extra: Vec::new(),
        images_without_robot: None,
    }
}

pub(crate) fn sequence_info(spec: &TrialSpec, length: usize) -> SequenceInfo {
    let name = spec.name();
    SequenceInfo {
        file: format!("{name}.safetensors"),
        name,
        task: spec.task.name().into(),
        bed_height_mm: Some(spec.bed_height_mm as f64),
        split: spec.split,
        seed: Some(spec.seed),
        length,
        subtasks: spec.task.subtasks().iter().map(|s| s.to_string()).collect(),
    }
}

/// Simulates a whole trial into a dataset sequence, with each step's state.
pub fn simulate(spec: &TrialSpec) -> (Sequence, Vec<StepRecord>) {
    simulate_with(spec, false)
}

/// [`simulate`], and with `robot_free` each frame rendered also without the robot (the
/// ground truth of what the arms hide; the rendering with the robot is unchanged).
pub fn simulate_with(spec: &TrialSpec, robot_free: bool) -> (Sequence, Vec<StepRecord>) {
    let mut sim = Simulation::new(spec.clone());
    let t = sim.len();
    let frame = IMAGE_SIZE * IMAGE_SIZE * 3;
    let mut images = Vec::with_capacity(t * 2 * frame);
    let mut joints = Vec::with_capacity(t * 14);
    let mut torques = Vec::with_capacity(t * 14);
    let mut subtask = Vec::with_capacity(t);
    let mut records = Vec::with_capacity(t);
    let mut without_robot = robot_free.then(|| Vec::with_capacity(t * 2 * frame));
    for _ in 0..t {
        let record = sim.step();
        for cam in 0..2 {
            images.extend(sim.render(cam, true, IMAGE_SIZE, SUPERSAMPLE).rgb);
        }
        if let Some(hidden) = without_robot.as_mut() {
            for cam in 0..2 {
                hidden.extend(sim.render(cam, false, IMAGE_SIZE, SUPERSAMPLE).rgb);
            }
        }
        let (j, tq) = sim.sensors(&record);
        joints.extend(j);
        torques.extend(tq);
        subtask.push(record.plan.subtask);
        records.push(record);
    }
    let seq = Sequence {
        info: sequence_info(spec, t),
        cameras: 2,
        image_size: IMAGE_SIZE,
        images,
        joints,
        torques,
        subtask,
        extra: Vec::new(),
        images_without_robot: without_robot,
    };
    (seq, records)
}
