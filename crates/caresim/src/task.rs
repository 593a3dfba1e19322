//! The two caregiving tasks as scripted, teleoperation-like hand trajectories, with the
//! per-trial variability of the paper: mannequin posture, subtask timing, towel position,
//! wiping pattern (stroke count, direction, amplitude, drift, pressure), and hand jitter.
//! Wiping varies more than repositioning.

use glam::{DMat3, DVec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::arm::{GRAVITY, IkTarget};
use crate::body::{Landmarks, Mannequin, Posture, UPPER_COM, UPPER_MASS};
use crate::math::{cos, ln, sin};
use crate::revision::Revision;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Task {
    Repositioning,
    Wiping,
}

impl Task {
    pub const ALL: [Task; 2] = [Task::Repositioning, Task::Wiping];

    pub fn name(self) -> &'static str {
        match self {
            Task::Repositioning => "repositioning",
            Task::Wiping => "wiping",
        }
    }

    pub fn parse(text: &str) -> Option<Task> {
        Self::ALL.into_iter().find(|t| t.name() == text)
    }

    pub fn subtasks(self) -> [&'static str; 3] {
        match self {
            Task::Repositioning => ["reaching", "holding", "lifting"],
            Task::Wiping => ["reaching", "wiping", "releasing"],
        }
    }

    /// Nominal subtask durations (steps) and their relative spread (std of a factor).
    fn timing(self) -> ([f64; 3], f64) {
        match self {
            Task::Repositioning => ([80.0, 120.0, 100.0], 0.06),
            Task::Wiping => ([70.0, 160.0, 70.0], 0.18),
        }
    }
}

/// A seeded source of the trial's random choices.
#[derive(Debug)]
pub(crate) struct SimRng(ChaCha8Rng);

impl SimRng {
    pub(crate) fn new(seed: u64) -> Self {
        Self(ChaCha8Rng::seed_from_u64(seed))
    }
    pub(crate) fn uniform(&mut self) -> f64 {
        (self.0.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    pub(crate) fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.uniform()
    }
    pub(crate) fn normal(&mut self) -> f64 {
        let u1 = 1.0 - self.uniform();
        let u2 = self.uniform();
        (-2.0 * ln(u1)).sqrt() * cos(std::f64::consts::TAU * u2)
    }
}

/// A trial's random choices with their spread around the centre scaled by the task's
/// variability factor. Each choice takes the same draws whatever the factor, so the rest of
/// the trial stays in step; a factor of exactly 1 gives the unscaled values bit for bit.
struct Spread<'a> {
    rng: &'a mut SimRng,
    factor: f64,
}

impl Spread<'_> {
    fn uniform(&mut self) -> f64 {
        let u = self.rng.uniform();
        if self.factor == 1.0 {
            u
        } else {
            0.5 + self.factor * (u - 0.5)
        }
    }
    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.uniform()
    }
    fn normal(&mut self) -> f64 {
        self.factor * self.rng.normal()
    }
}

/// Smooth, low-frequency hand wobble, like a teleoperator's.
#[derive(Clone, Debug)]
struct Jitter {
    amplitude: f64,
    freq: [f64; 3],
    phase: [[f64; 3]; 3],
}

impl Jitter {
    fn new(rng: &mut SimRng, amplitude: f64) -> Self {
        Self {
            amplitude,
            freq: std::array::from_fn(|_| rng.range(0.004, 0.03)),
            phase: std::array::from_fn(|_| {
                std::array::from_fn(|_| rng.range(0.0, std::f64::consts::TAU))
            }),
        }
    }
    fn at(&self, t: f64) -> DVec3 {
        let axis = |a: usize| {
            (0..3)
                .map(|k| sin(std::f64::consts::TAU * self.freq[k] * t + self.phase[a][k]))
                .sum::<f64>()
                / 3f64.sqrt()
        };
        DVec3::new(axis(0), axis(1), axis(2)) * self.amplitude
    }
}

/// A trial's wiping pattern.
#[derive(Clone, Debug, PartialEq)]
pub struct WipePattern {
    pub strokes: usize,
    pub amplitude: f64,
    /// Angle of the strokes from the body axis (rad).
    pub angle: f64,
    /// Sideways drift over the whole wiping phase (m).
    pub drift: f64,
    /// Pressing force (N).
    pub press: f64,
    /// Towel centre offsets (along the body, across it) from the belly (m), and its yaw.
    pub towel_offset: [f64; 2],
    pub towel_yaw: f64,
}

/// Everything random about a trial, drawn from its seed.
#[derive(Clone, Debug)]
pub struct Variation {
    pub durations: [usize; 3],
    pub posture: Posture,
    pub lift_max: f64,
    pub wipe: Option<WipePattern>,
    /// How far this operator twists the wrists, as a factor on the scripted twists
    /// (revision 2 only; drawn from a stream of its own, so revision 1's draws stay).
    pub wrist_gain: f64,
    jitter: [Jitter; 2],
}

impl Variation {
    /// The trial of `seed`, its spread scaled by `variability` (see [`crate::variability`]).
    pub fn draw(task: Task, seed: u64, variability: f64) -> Self {
        let mut raw_rng = SimRng::new(seed);
        let mut rng = Spread {
            rng: &mut raw_rng,
            factor: variability,
        };
        // Each subtask's share varies by `spread`; the whole trial stays near 300 steps
        // (+-10%), like the paper's sequences.
        let (nominal, spread) = task.timing();
        let raw = nominal.map(|d| {
            d * (1.0 + spread * rng.normal()).clamp(1.0 - 2.0 * spread, 1.0 + 2.0 * spread)
        });
        let total = 300.0 * (1.0 + 0.04 * rng.normal()).clamp(0.9, 1.1);
        let sum: f64 = raw.iter().sum();
        let durations = raw.map(|d| (d * total / sum).round() as usize);
        let posture = Posture {
            offset: [rng.range(-0.025, 0.025), rng.range(-0.04, 0.04)],
            yaw: rng.range(-0.04, 0.04),
            head_yaw: rng.range(-0.25, 0.25),
            arm_spread: [rng.range(-0.03, 0.05), rng.range(-0.03, 0.05)],
            leg_spread: rng.range(-0.02, 0.06),
        };
        let lift_max = rng.range(0.85, 1.0);
        let wipe = (task == Task::Wiping).then(|| WipePattern {
            strokes: 2 + (rng.uniform() * 4.0) as usize,
            amplitude: rng.range(0.08, 0.22),
            angle: rng.range(-0.6, 0.6),
            drift: rng.range(-0.06, 0.06),
            press: rng.range(6.0, 12.0),
            towel_offset: [rng.range(-0.08, 0.12), rng.range(-0.05, 0.04)],
            towel_yaw: rng.range(-0.5, 0.5),
        });
        // Jitter's size scales; its frequencies and phases are not a spread.
        let amplitude = variability * if task == Task::Wiping { 0.006 } else { 0.003 };
        let jitter = [
            Jitter::new(&mut raw_rng, amplitude),
            Jitter::new(&mut raw_rng, amplitude),
        ];
        let mut wrist_rng = SimRng::new(seed ^ 0x0057_215E_7715);
        let wrist_gain = Spread {
            rng: &mut wrist_rng,
            factor: variability,
        }
        .range(0.75, 1.25);
        Self {
            durations,
            posture,
            lift_max,
            wipe,
            wrist_gain,
            jitter,
        }
    }

    pub fn len(&self) -> usize {
        self.durations.iter().sum()
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Friction (coefficient 0.5) against a hand moving along `path` at step `t` while
/// `normal` newtons press on it: horizontal, opposite the hand's horizontal motion.
fn sliding_friction(path: &Path, t: f64, normal: f64) -> DVec3 {
    let velocity = (path.at(t + 0.5).0 - path.at(t - 0.5).0).with_z(0.0);
    if velocity.length() > 1e-6 && normal > 0.0 {
        -velocity.normalize() * 0.5 * normal
    } else {
        DVec3::ZERO
    }
}

/// Minimum-jerk blend 0 -> 1.
fn min_jerk(x: f64) -> f64 {
    let x = x.clamp(0.0, 1.0);
    x * x * x * (10.0 - 15.0 * x + 6.0 * x * x)
}

/// A hand path through keyframes (step, position, finger direction), min-jerk between them.
#[derive(Clone, Debug, Default)]
struct Path {
    keys: Vec<(f64, DVec3, DVec3)>,
}

impl Path {
    fn key(mut self, t: f64, p: DVec3, fingers: DVec3) -> Self {
        self.keys.push((t, p, fingers.normalize()));
        self
    }
    fn at(&self, t: f64) -> (DVec3, DVec3) {
        let k = &self.keys;
        if t <= k[0].0 {
            return (k[0].1, k[0].2);
        }
        for w in k.windows(2) {
            if t <= w[1].0 {
                let s = min_jerk((t - w[0].0) / (w[1].0 - w[0].0).max(1e-9));
                return (w[0].1.lerp(w[1].1, s), w[0].2.lerp(w[1].2, s).normalize());
            }
        }
        let last = k.last().expect("a path has keys");
        (last.1, last.2)
    }
}

/// What the script asks for at one step.
#[derive(Clone, Copy, Debug)]
pub struct Plan {
    pub subtask: u32,
    /// Left hand, right hand.
    pub hands: [IkTarget; 2],
    /// Lift of the mannequin's upper body (rad).
    pub lift: f64,
    /// Force the environment applies to each hand (N).
    pub forces: [DVec3; 2],
    /// The right hand holds the towel.
    pub grasping: bool,
}

/// Home positions of the hands: in front of the robot's hips.
pub const HOME: [DVec3; 2] = [DVec3::new(0.30, 0.30, 0.93), DVec3::new(0.30, -0.30, 0.93)];
const HOME_FINGERS: DVec3 = DVec3::new(1.0, 0.0, -1.0);
const DIRECTION_WEIGHT: f64 = 0.12;

/// A trial's script: hand paths, lift and loads for every step.
#[derive(Clone, Debug)]
pub struct Script {
    pub task: Task,
    pub variation: Variation,
    bounds: [f64; 3],
    left: Path,
    right: Path,
    landmarks: Landmarks,
    /// Body-frame point under the back the left hand holds while lifting.
    back_local: DVec3,
    wipe_start: DVec3,
    /// Stroke direction and sideways direction (horizontal units).
    wipe_dirs: (DVec3, DVec3),
    surface: Vec<crate::shapes::Shape>,
    bed_top: f64,
    revision: Revision,
}

impl Script {
    /// `grasp` is where the towel's grasp point lies (wiping).
    pub fn new(
        task: Task,
        variation: Variation,
        body: &Mannequin,
        bed_top: f64,
        grasp: Option<DVec3>,
        revision: Revision,
    ) -> Self {
        let [d0, d1, d2] = variation.durations.map(|d| d as f64);
        let (t1, t2) = (d0, d0 + d1);
        let lm = body.landmarks();
        let x = DVec3::X;
        let z = DVec3::Z;
        let home = |i: usize| Path::default().key(0.0, HOME[i], HOME_FINGERS);
        let (left, right, wipe_start) = match task {
            Task::Repositioning => {
                let under = x * 0.01 + z * 0.03;
                let left = home(0)
                    .key(0.15 * d0, HOME[0], HOME_FINGERS)
                    .key(
                        0.6 * d0,
                        lm.under_neck - x * 0.16 + z * 0.14,
                        DVec3::new(1.0, 0.0, -0.5),
                    )
                    .key(
                        0.85 * d0,
                        lm.under_neck - x * 0.07 + z * 0.04,
                        DVec3::new(1.0, 0.0, -0.15),
                    )
                    .key(t1, lm.under_neck + under, DVec3::new(1.0, 0.0, -0.1))
                    .key(
                        t1 + 0.5 * d1,
                        lm.under_back + under,
                        DVec3::new(1.0, 0.0, -0.1),
                    );
                let right = home(1)
                    .key(t1 + 0.35 * d1, HOME[1], HOME_FINGERS)
                    .key(
                        t1 + 0.7 * d1,
                        lm.near_knee - x * 0.08 + z * 0.13,
                        DVec3::new(0.8, 0.0, -0.6),
                    )
                    .key(
                        t1 + 0.9 * d1,
                        lm.near_knee + z * 0.025,
                        DVec3::new(0.6, 0.0, -0.8),
                    );
                (left, right, DVec3::ZERO)
            }
            Task::Wiping => {
                let g = grasp.expect("wiping needs the towel's grasp point");
                let down = DVec3::new(0.45, 0.0, -0.9);
                let right = home(1)
                    .key(0.1 * d0, HOME[1], HOME_FINGERS)
                    .key(0.65 * d0, g + z * 0.12, down)
                    .key(0.9 * d0, g + z * 0.012, down);
                (home(0), right, g + z * 0.012)
            }
        };
        let angle = variation.wipe.as_ref().map_or(0.0, |w| w.angle);
        let along = (DMat3::from_rotation_z(angle) * lm.along)
            .with_z(0.0)
            .normalize();
        let across = z.cross(along);
        Self {
            task,
            bounds: [t1, t2, t2 + d2],
            left,
            right,
            back_local: body.to_local(lm.under_back) + z * 0.03,
            landmarks: lm,
            wipe_start,
            wipe_dirs: (along, across),
            surface: body.shapes(0.0),
            bed_top,
            variation,
            revision,
        }
    }

    pub fn len(&self) -> usize {
        self.variation.len()
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    fn subtask(&self, t: f64) -> u32 {
        if t < self.bounds[0] {
            0
        } else if t < self.bounds[1] {
            1
        } else {
            2
        }
    }

    /// The plan of step `t`.
    pub fn at(&self, step: usize, body: &Mannequin) -> Plan {
        let t = step as f64;
        let [t1, t2, t3] = self.bounds;
        let (d1, d2) = (t2 - t1, t3 - t2);
        let subtask = self.subtask(t);
        let target = |(p, f): (DVec3, DVec3), hand: usize| IkTarget {
            position: p + self.variation.jitter[hand].at(t),
            fingers: f,
            direction_weight: DIRECTION_WEIGHT,
            wrist_twist: (self.revision == Revision::R2).then(|| self.wrist_twist(t, hand)),
        };
        let mut left = self.left.at(t);
        let mut right = self.right.at(t);
        let mut lift = 0.0;
        let mut forces = [DVec3::ZERO; 2];
        let mut grasping = false;
        match self.task {
            Task::Repositioning => {
                // Weight resting on the hand under the neck, then under the back.
                if t >= 0.85 * self.variation.durations[0] as f64 {
                    forces[0] = DVec3::new(0.0, 0.0, -4.0);
                }
                if t >= t1 + 0.5 * d1 {
                    forces[0] = DVec3::new(0.0, 0.0, -8.0);
                }
                if t >= t1 + 0.9 * d1 {
                    forces[1] = DVec3::new(0.0, 0.0, 6.0);
                }
                if self.revision == Revision::R2 && t < t1 + 0.5 * d1 {
                    // Sliding under the neck and back: the body's weight on the palm resists.
                    forces[0] += sliding_friction(&self.left, t, -forces[0].z);
                }
                if t >= t2 {
                    let tau = (t - t2) / d2;
                    lift = self.variation.lift_max * min_jerk((tau - 0.08) / 0.8);
                    let hand = body.upper_point(self.back_local, lift);
                    left = (
                        hand + DVec3::X * 0.01,
                        (DMat3::from_axis_angle(self.landmarks.pivot_axis, lift)
                            * DVec3::new(1.0, 0.0, -0.1))
                        .normalize(),
                    );
                    // Holding the upper body: its weight's moment about the hips over the
                    // lever to the hand, taken over from the bed as it lifts off.
                    let lever = (self.back_local - DVec3::new(0.0, 0.0, 0.1)).length();
                    let full = UPPER_MASS * GRAVITY * UPPER_COM * cos(lift) / lever;
                    let support = 8.0 + (full - 8.0) * min_jerk(tau / 0.3);
                    forces[0] = match self.revision {
                        Revision::R1 => DVec3::new(0.0, 0.0, -support),
                        // The back presses along its own normal, which tilts with the lift.
                        Revision::R2 => {
                            DMat3::from_axis_angle(self.landmarks.pivot_axis, lift)
                                * DVec3::new(0.0, 0.0, -support)
                        }
                    };
                    forces[1] = DVec3::new(0.0, 0.0, 6.0 + 6.0 * tau);
                }
            }
            Task::Wiping => {
                let w = self.variation.wipe.as_ref().expect("wiping pattern");
                grasping = t >= 0.9 * self.variation.durations[0] as f64 && t < t2 + 0.12 * d2;
                if grasping {
                    forces[1] = DVec3::new(0.0, 0.0, 2.0);
                }
                if (t1..t2).contains(&t) {
                    let s = (t - t1) / d1;
                    let (along, across) = self.wipe_dirs;
                    let stroke =
                        |s: f64| 0.5 * (1.0 - cos(std::f64::consts::TAU * w.strokes as f64 * s));
                    let flat = |s: f64| {
                        self.wipe_start
                            + along * (w.amplitude * stroke(s))
                            + across * (w.drift * min_jerk(s))
                    };
                    let pos = self.on_surface(flat(s));
                    let velocity = (flat(s + 1e-3) - flat(s - 1e-3)).with_z(0.0);
                    let friction = if velocity.length() > 1e-9 {
                        -velocity.normalize() * 0.5 * w.press
                    } else {
                        DVec3::ZERO
                    };
                    right = (pos, DVec3::new(0.45, 0.0, -0.9) + along * 0.1);
                    forces[1] = DVec3::new(0.0, 0.0, w.press) + friction;
                }
                if t >= t2 {
                    let tau = (t - t2) / d2;
                    let end = self.right_wipe_end();
                    let up = end + DVec3::Z * 0.12;
                    let (p, f) = if tau < 0.45 {
                        (
                            end.lerp(up, min_jerk((tau - 0.12) / 0.33)),
                            DVec3::new(0.45, 0.0, -0.9),
                        )
                    } else {
                        (
                            up.lerp(HOME[1], min_jerk((tau - 0.45) / 0.5)),
                            HOME_FINGERS.normalize().lerp(
                                DVec3::new(0.45, 0.0, -0.9),
                                1.0 - min_jerk((tau - 0.45) / 0.5),
                            ),
                        )
                    };
                    right = (p, f.normalize());
                }
            }
        }
        Plan {
            subtask,
            hands: [target(left, 0), target(right, 1)],
            lift,
            forces,
            grasping,
        }
    }

    /// Revision 2: how far the operator has turned hand `hand`'s wrist from rest at step
    /// `t` (rad): the palm turns up to slide under the neck and back and eases as the body
    /// rises; the knee hand turns the other way; the towel hand turns to pinch the towel,
    /// rolls with every stroke and turns back once it lets go.
    fn wrist_twist(&self, t: f64, hand: usize) -> f64 {
        let [t1, t2, t3] = self.bounds;
        let d0 = t1;
        let (d1, d2) = (t2 - t1, t3 - t2);
        let ramp = |from: f64, to: f64| min_jerk((t - from) / (to - from).max(1e-9));
        let g = self.variation.wrist_gain;
        match (self.task, hand) {
            (Task::Repositioning, 0) => {
                let under = 1.0 * ramp(0.15 * d0, 0.85 * d0);
                g * (under - 0.5 * ramp(t2, t2 + 0.8 * d2))
            }
            (Task::Repositioning, _) => {
                let knee = -0.7 * ramp(t1 + 0.35 * d1, t1 + 0.9 * d1);
                g * (knee + 0.2 * ramp(t2, t3))
            }
            (Task::Wiping, 1) => {
                let w = self.variation.wipe.as_ref().expect("wiping pattern");
                let pinch = g * 0.6 + 0.4 * w.angle;
                let roll = if (t1..t2).contains(&t) {
                    let s = (t - t1) / d1;
                    0.35 * g * sin(std::f64::consts::TAU * w.strokes as f64 * s)
                } else {
                    0.0
                };
                pinch * (ramp(0.1 * d0, 0.9 * d0) - ramp(t2 + 0.12 * d2, t2 + 0.6 * d2)) + roll
            }
            (Task::Wiping, _) => 0.0,
        }
    }

    /// Where the wiping phase ends.
    fn right_wipe_end(&self) -> DVec3 {
        let w = self.variation.wipe.as_ref().expect("wiping pattern");
        let (_, across) = self.wipe_dirs;
        self.on_surface(self.wipe_start + across * w.drift)
    }

    /// The towel-holding hand's position over `p`: on the body's (or the mattress's)
    /// surface below it, plus the towel's thickness and the hand's clearance.
    fn on_surface(&self, p: DVec3) -> DVec3 {
        let height = crate::shapes::surface_height(
            &self.surface,
            p.x,
            p.y,
            self.bed_top + 0.6,
            self.bed_top,
        )
        .unwrap_or(self.bed_top);
        DVec3::new(p.x, p.y, height + 0.022)
    }
}
