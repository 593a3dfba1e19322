//! Did an episode do the task? The success criteria of docs/closed-loop.md (pre-specified
//! 2026-12-06), read from the environment's state, never from images: [`Outcome::assess`]
//! scores an episode's step records against the scripted demonstration of the same trial
//! ([`demonstration`]).
//!
//! - Repositioning: the neck reached (the left hand within [`CONTACT_TOLERANCE`] of the
//!   neck, the script's left-hand target at the end of reaching, while reaching or
//!   holding, and the upper body supported later), the
//!   upper body lifted to at least [`LIFT_SHARE`] of the demonstration's largest lift, no
//!   hand below the mattress's top over the bed.
//! - Wiping: the towel grasped, at least [`COVERAGE_SHARE`] of the demonstration's wiped
//!   path covered ([`NEAR`]), the towel released on the body (grasped before, not held at
//!   the end, and at least
//!   [`ON_BODY_SHARE`] of its particles within [`NEAR`] of the mannequin's surface; the
//!   first wording, the centroid's height above the surface below it, failed half the
//!   scripted demonstrations, since a draped towel's centroid lies inside the body's
//!   curve or beside it: revised 2026-12-06 before any network drove).
//!
//! Beside success: the root mean square distance of the noise-free joint angles from the
//! demonstration's (rad).

use serde::Serialize;

use crate::scene::{BED_FAR, BED_HALF_LENGTH, BED_NEAR};
use crate::sim::{CONTACT_TOLERANCE, Simulation, StepRecord, TrialSpec};
use crate::task::Task;

/// The demonstration's largest lift that an episode must reach.
pub const LIFT_SHARE: f64 = 0.8;
/// The share of the demonstration's wiped path an episode must cover.
pub const COVERAGE_SHARE: f64 = 0.6;
/// "Near" for the towel: covered path points, and a released towel's particles to the
/// body's surface (m).
pub const NEAR: f64 = 0.05;
/// The share of a released towel's particles that must lie near the body ("released on
/// the body").
pub const ON_BODY_SHARE: f64 = 0.5;

/// The subtasks of the criteria (indices into [`Task::subtasks`]).
const REACHING: u32 = 0;
const HOLDING: u32 = 1;
const WIPING: u32 = 1;

/// The scripted run of `spec` (no rendering): the simulation at its end and every step's
/// record.
pub fn demonstration(spec: &TrialSpec) -> (Simulation, Vec<StepRecord>) {
    let mut sim = Simulation::new(spec.clone());
    let records = (0..sim.len()).map(|_| sim.step()).collect();
    (sim, records)
}

/// Each criterion of one episode, and whether all hold.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Outcome {
    pub task: String,
    pub success: bool,
    /// Each criterion by name, in the order docs/closed-loop.md states them.
    pub criteria: Vec<(String, bool)>,
    /// The quantities behind them (name, value, what it is compared with).
    pub measures: Vec<Measure>,
    /// Root mean square over steps and the 14 joints of the noise-free joint angles'
    /// difference from the demonstration (rad), over the steps both have.
    pub joint_distance: f64,
    /// How far the joints travelled (the sum over steps and joints of each step's move,
    /// noise-free) as a share of the demonstration's: 0 for arms held still.
    pub joint_path_share: f64,
}

/// One quantity behind a criterion.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Measure {
    pub name: String,
    pub value: f64,
    /// What it is compared with (a threshold, or the demonstration's value).
    pub against: f64,
}

impl Outcome {
    /// Scores `episode` (its step records; `sim` the environment's simulation at its end)
    /// against the demonstration `demo` of the same trial.
    pub fn assess(sim: &Simulation, episode: &[StepRecord], demo: &[StepRecord]) -> Self {
        let task = sim.spec.task;
        let (criteria, measures) = match task {
            Task::Repositioning => repositioning(sim, episode, demo),
            Task::Wiping => wiping(sim, episode, demo),
        };
        Self {
            task: task.name().into(),
            success: criteria.iter().all(|(_, ok)| *ok),
            criteria,
            measures,
            joint_distance: joint_distance(episode, demo),
            joint_path_share: joint_path(episode) / joint_path(demo).max(f64::MIN_POSITIVE),
        }
    }

    /// One line: success and each criterion.
    pub fn summary(&self) -> String {
        let parts: Vec<String> = self
            .criteria
            .iter()
            .map(|(name, ok)| format!("{name} {}", if *ok { "yes" } else { "no" }))
            .collect();
        format!(
            "{}: {} ({}); joints {:.3} rad from the demonstration, {:.0}% of its joint path",
            self.task,
            if self.success { "success" } else { "failure" },
            parts.join(", "),
            self.joint_distance,
            100.0 * self.joint_path_share
        )
    }
}

type Scored = (Vec<(String, bool)>, Vec<Measure>);

fn measure(name: &str, value: f64, against: f64) -> Measure {
    Measure {
        name: name.into(),
        value,
        against,
    }
}

fn largest_lift(records: &[StepRecord]) -> f64 {
    records.iter().map(|r| r.lift).fold(0.0, f64::max)
}

fn repositioning(sim: &Simulation, episode: &[StepRecord], demo: &[StepRecord]) -> Scored {
    // The neck: the script's left-hand target at the end of reaching.
    let neck = demo
        .iter()
        .rev()
        .find(|r| r.plan.subtask == REACHING)
        .map(|r| r.plan.hands[0].position);
    // The left hand's distance from it while reaching or holding.
    let near_neck: Vec<(usize, f64)> = episode
        .iter()
        .enumerate()
        .filter(|(_, r)| matches!(r.plan.subtask, REACHING | HOLDING))
        .filter_map(|(t, r)| Some((t, (r.tcp[0].translation - neck?).length())))
        .collect();
    let closest = near_neck
        .iter()
        .map(|&(_, e)| e)
        .fold(f64::INFINITY, f64::min);
    let first_reach = near_neck
        .iter()
        .find(|&&(_, e)| e < CONTACT_TOLERANCE)
        .map(|&(t, _)| t);
    let supported_later = first_reach.is_some_and(|t| episode[t..].iter().any(|r| r.lift > 0.0));
    let (lift, demo_lift) = (largest_lift(episode), largest_lift(demo));
    let lowest = lowest_over_bed(sim, episode);
    (
        vec![
            ("neck reached".into(), supported_later),
            ("upper body lifted".into(), lift >= LIFT_SHARE * demo_lift),
            ("no collision with the bed".into(), lowest >= 0.0),
        ],
        vec![
            measure(
                "closest left hand to the neck while reaching or holding (m)",
                closest,
                CONTACT_TOLERANCE,
            ),
            measure("largest lift (rad)", lift, demo_lift),
            measure(
                "lowest hand above the mattress over the bed (m)",
                lowest,
                0.0,
            ),
        ],
    )
}

/// The lowest height of a hand's tool point above the mattress's top while over the bed
/// (m; negative: below it; infinite: never over the bed).
fn lowest_over_bed(sim: &Simulation, episode: &[StepRecord]) -> f64 {
    episode
        .iter()
        .flat_map(|r| r.tcp.iter().map(|tcp| tcp.translation))
        .filter(|p| (BED_NEAR..=BED_FAR).contains(&p.x) && p.y.abs() <= BED_HALF_LENGTH)
        .map(|p| p.z - sim.bed_top)
        .fold(f64::INFINITY, f64::min)
}

fn wiping(sim: &Simulation, episode: &[StepRecord], demo: &[StepRecord]) -> Scored {
    let grasped = episode.iter().any(|r| r.towel_grip_error.is_some());
    // The demonstration's wiped path, and the towel's places while the episode held it.
    let path: Vec<_> = demo
        .iter()
        .filter(|r| r.plan.subtask == WIPING)
        .filter_map(|r| r.towel_centroid)
        .collect();
    let held: Vec<_> = episode
        .iter()
        .filter(|r| r.towel_grip_error.is_some())
        .filter_map(|r| r.towel_centroid)
        .collect();
    let covered = path
        .iter()
        .filter(|p| held.iter().any(|h| (*h - **p).length() <= NEAR))
        .count();
    let coverage = if path.is_empty() {
        0.0
    } else {
        covered as f64 / path.len() as f64
    };
    let last = episode.last();
    let released = last.is_some_and(|r| r.towel_grip_error.is_none());
    let resting = towel_on_body(sim);
    (
        vec![
            ("towel grasped".into(), grasped),
            ("wiped path covered".into(), coverage >= COVERAGE_SHARE),
            (
                "towel released on the body".into(),
                grasped && released && resting >= ON_BODY_SHARE,
            ),
        ],
        vec![
            measure(
                "share of the demonstration's wiped path covered",
                coverage,
                COVERAGE_SHARE,
            ),
            measure(
                "share of the towel within 5 cm of the body at the end",
                resting,
                ON_BODY_SHARE,
            ),
        ],
    )
}

/// The share of the towel's particles within [`NEAR`] of the mannequin's surface now.
fn towel_on_body(sim: &Simulation) -> f64 {
    let Some(towel) = sim.towel.as_ref() else {
        return 0.0;
    };
    let shapes = sim.body.shapes(sim.lift());
    let near = towel
        .pos
        .iter()
        .filter(|p| crate::shapes::union_sdf(&shapes, **p) <= NEAR)
        .count();
    near as f64 / towel.pos.len().max(1) as f64
}

/// The sum over steps and joints of each step's move (rad).
pub fn joint_path(records: &[StepRecord]) -> f64 {
    records
        .windows(2)
        .map(|w| {
            (0..2)
                .flat_map(|arm| (0..7).map(move |j| (w[1].q[arm][j] - w[0].q[arm][j]).abs()))
                .sum::<f64>()
        })
        .sum()
}

/// Root mean square of the noise-free joint angles' difference over the steps both have.
pub fn joint_distance(episode: &[StepRecord], demo: &[StepRecord]) -> f64 {
    let steps = episode.len().min(demo.len());
    if steps == 0 {
        return f64::NAN;
    }
    let sum: f64 = episode
        .iter()
        .zip(demo)
        .flat_map(|(a, b)| {
            (0..2).flat_map(move |arm| {
                (0..7).map(move |j| {
                    let d = a.q[arm][j] - b.q[arm][j];
                    d * d
                })
            })
        })
        .sum();
    (sum / (steps * 14) as f64).sqrt()
}
