//! How much the trials of a task differ from each other, as a setting, and as a measurement.
//!
//! The paper explains its uncertainty and interference results (Figs 4 and 6) by wiping
//! varying more than repositioning. caresim builds that difference in; a control with
//! *matched* variability tests the explanation instead: if the tasks still differ when
//! their trials vary equally, variability was not the (whole) reason.
//!
//! A task's variability is a factor on the spread of every random choice of its trials
//! around the centre of its range (posture, subtask timing, lift height, towel placement,
//! wiping pattern, hand jitter). 1 is the default benchmark; 0 makes every trial of a task
//! nominal apart from its bed height and sensor noise. A trial keeps its seed whatever the
//! factor, so the same trial under two settings is the same draw, shrunk or stretched.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::sim::{Simulation, TrialSpec};
use crate::task::Task;

/// Per-task variability factors.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Variability {
    pub repositioning: f64,
    pub wiping: f64,
}

impl Default for Variability {
    fn default() -> Self {
        Self::PAPER
    }
}

impl Variability {
    /// The default benchmark: wiping varies more than repositioning, as in the paper.
    pub const PAPER: Self = Self {
        repositioning: 1.0,
        wiping: 1.0,
    };

    /// Both tasks with the same measured trajectory spread ([`trajectory_spread`] of the
    /// working hand over the 9 learning trials of seed 0): wiping shrunk to repositioning's.
    /// Calibrated by bisection (`cargo run --release -p caresim --example calibrate_variability`);
    /// the test `matched_variability_equalises_the_trajectory_spread` holds it to within 10%.
    pub const MATCHED: Self = Self {
        repositioning: 1.0,
        wiping: MATCHED_WIPING,
    };

    /// The factor of `task`.
    pub fn of(self, task: Task) -> f64 {
        match task {
            Task::Repositioning => self.repositioning,
            Task::Wiping => self.wiping,
        }
    }

    /// `paper`, `matched`, or factors such as `repositioning=1,wiping=0.5` (a task left out
    /// keeps 1).
    pub fn parse(text: &str) -> Result<Self, String> {
        match text.trim() {
            "paper" => return Ok(Self::PAPER),
            "matched" => return Ok(Self::MATCHED),
            _ => {}
        }
        let mut out = Self::PAPER;
        for part in text.split(',') {
            let (task, value) = part.split_once('=').ok_or_else(|| {
                format!(
                    "variability `{text}`: expected `paper`, `matched` or \
                     `repositioning=F,wiping=F`"
                )
            })?;
            let task = Task::parse(task.trim())
                .ok_or_else(|| format!("variability `{text}`: unknown task `{}`", task.trim()))?;
            let value: f64 = value
                .trim()
                .parse()
                .map_err(|_| format!("variability `{text}`: `{value}` is not a number"))?;
            if !(0.0..=2.0).contains(&value) {
                return Err(format!(
                    "variability `{text}`: factors go from 0 (every trial nominal) to 2, got {value}"
                ));
            }
            match task {
                Task::Repositioning => out.repositioning = value,
                Task::Wiping => out.wiping = value,
            }
        }
        Ok(out)
    }

    /// A name for people and manifests: `paper`, `matched`, or the factors.
    pub fn describe(self) -> String {
        if self == Self::PAPER {
            "paper".into()
        } else if self == Self::MATCHED {
            format!(
                "matched (repositioning={}, wiping={})",
                self.repositioning, self.wiping
            )
        } else {
            format!(
                "repositioning={}, wiping={}",
                self.repositioning, self.wiping
            )
        }
    }
}

/// Wiping's factor in [`Variability::MATCHED`].
const MATCHED_WIPING: f64 = 0.1;

/// The hand that does a task's work: the left lifts the upper body, the right wipes.
pub fn working_hand(task: Task) -> usize {
    match task {
        Task::Repositioning => 0,
        Task::Wiping => 1,
    }
}

/// Positions of a trial's working hand at `points` instants of normalised time (kinematics
/// only, nothing rendered).
fn hand_path(spec: &TrialSpec, points: usize) -> Vec<DVec3> {
    let hand = working_hand(spec.task);
    let mut sim = Simulation::new(spec.clone());
    let path: Vec<DVec3> = (0..sim.len())
        .map(|_| sim.step().tcp[hand].translation)
        .collect();
    (0..points)
        .map(|i| path[i * (path.len() - 1) / (points - 1).max(1)])
        .collect()
}

/// Trajectory spread (m) of a set of trials of one task: the across-trial standard
/// deviation of the working hand's position at 100 instants of normalised time, averaged
/// over time, within each bed height (the designed condition is not variability), then
/// averaged over heights.
pub fn trajectory_spread(trials: &[TrialSpec]) -> f64 {
    const POINTS: usize = 100;
    let mut heights: Vec<u32> = trials.iter().map(|t| t.bed_height_mm).collect();
    heights.sort_unstable();
    heights.dedup();
    let per_height: Vec<f64> = heights
        .iter()
        .map(|&h| {
            let paths: Vec<Vec<DVec3>> = trials
                .iter()
                .filter(|t| t.bed_height_mm == h)
                .map(|t| hand_path(t, POINTS))
                .collect();
            let n = paths.len() as f64;
            (0..POINTS)
                .map(|k| {
                    let mean = paths.iter().map(|p| p[k]).sum::<DVec3>() / n;
                    (paths
                        .iter()
                        .map(|p| (p[k] - mean).length_squared())
                        .sum::<f64>()
                        / n)
                        .sqrt()
                })
                .sum::<f64>()
                / POINTS as f64
        })
        .collect();
    per_height.iter().sum::<f64>() / per_height.len().max(1) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_presets_and_factors_and_rejects_the_rest() {
        assert_eq!(Variability::parse("paper"), Ok(Variability::PAPER));
        assert_eq!(Variability::parse("matched"), Ok(Variability::MATCHED));
        assert_eq!(
            Variability::parse("wiping=0.5"),
            Ok(Variability {
                repositioning: 1.0,
                wiping: 0.5
            })
        );
        assert_eq!(
            Variability::parse(" repositioning = 1.5 , wiping=0 "),
            Ok(Variability {
                repositioning: 1.5,
                wiping: 0.0
            })
        );
        for bad in [
            "",
            "wiping",
            "wiping=x",
            "cooking=1",
            "wiping=-1",
            "wiping=3",
        ] {
            let err = Variability::parse(bad).expect_err(bad);
            assert!(err.contains("variability"), "{bad}: {err}");
        }
        assert_eq!(Variability::PAPER.describe(), "paper");
        assert!(Variability::MATCHED.describe().starts_with("matched"));
    }
}
