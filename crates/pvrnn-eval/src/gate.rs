//! The validity gate: a network enters a finding only if, on held-out data, it beats the
//! strongest baseline of what the finding measures (docs/experiments.md, "The validity
//! gate", pre-specified 2026-12-06). A network that loses to a baseline without dynamics
//! has not learned what the paper's figures measure, so a finding drawn from it cannot
//! tell a non-replication from a flaw of ours.
//!
//! The gate reads the validation of the network used (the convergence rule's best
//! checkpoint), scored on the held-out dataset (caresim seed 1) at the paper's Fig. 5
//! question, the lowest vision resolution and proprioception observed:
//! - **vision**: the reconstruction of the highest resolution against bilinear upsampling,
//!   upsampling plus the mean image's detail, the nearest learning frame and the mean
//!   learning image;
//! - **proprioception** (joint angles; torques, where the robot has them): the one-step
//!   prediction against the previous value and the mean learning input.
//!
//! It passes when the network beats the strongest (lowest-error) baseline on every measure
//! and no trial diverged. A baseline a log did not record leaves the gate `incomplete`, never
//! a pass; a loss to a recorded baseline is a `fail` whatever is missing.

use serde::Serialize;

use crate::validation::ValidationRow;

/// One measure: the network's held-out error against the strongest recorded baseline.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct GateCheck {
    /// `vision`, `joints` or `torques`.
    pub measure: &'static str,
    /// The network's held-out error (`None`: not recorded).
    pub model: Option<f64>,
    /// The strongest baseline's name (e.g. `upsample_detail`) and error.
    pub baseline: &'static str,
    pub baseline_error: f64,
    /// What of this measure the log lacks: `model`, or baselines' names.
    pub missing: Vec<&'static str>,
}

impl GateCheck {
    /// The network is worse than (or as bad as) a recorded baseline.
    pub fn lost(&self) -> bool {
        self.model.is_some_and(|m| m >= self.baseline_error)
    }
}

/// The gate's verdict on one network.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum GateVerdict {
    Pass,
    Fail,
    /// Every recorded baseline beaten, but one the gate needs was not recorded.
    Incomplete,
}

impl GateVerdict {
    pub fn name(self) -> &'static str {
        match self {
            GateVerdict::Pass => "pass",
            GateVerdict::Fail => "fail",
            GateVerdict::Incomplete => "incomplete",
        }
    }
}

/// The gate on one validation.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Gate {
    pub verdict: GateVerdict,
    pub checks: Vec<GateCheck>,
    /// Trials whose online inference diverged (any fails the gate).
    pub failed_trials: usize,
}

impl Gate {
    /// The gate of the network whose held-out scores are `row`.
    pub fn of(row: &ValidationRow) -> Gate {
        let mut checks = vec![check(
            "vision",
            Some(row.recon_vision_top),
            &[
                ("upsample_detail", row.upsample_detail),
                ("nearest", row.nearest),
                ("upsample", row.upsample),
                ("mean", row.mean),
            ],
        )];
        // A robot without torque sensors has no torque measure (recon_torques absent).
        if row.recon_joints.is_some() {
            checks.push(check(
                "joints",
                row.next_joints,
                &[("previous", row.previous_joints), ("mean", row.mean_joints)],
            ));
        }
        if row.recon_torques.is_some() {
            checks.push(check(
                "torques",
                row.next_torques,
                &[
                    ("previous", row.previous_torques),
                    ("mean", row.mean_torques),
                ],
            ));
        }
        let lost = row.failed_trials > 0 || checks.iter().any(GateCheck::lost);
        let verdict = if lost {
            GateVerdict::Fail
        } else if checks.iter().any(|c| !c.missing.is_empty()) {
            GateVerdict::Incomplete
        } else {
            GateVerdict::Pass
        };
        Gate {
            verdict,
            checks,
            failed_trials: row.failed_trials,
        }
    }

    pub fn passes(&self) -> bool {
        self.verdict == GateVerdict::Pass
    }

    /// Passes on the vision measure alone (what a finding about images needs).
    pub fn passes_vision(&self) -> bool {
        self.failed_trials == 0
            && self
                .checks
                .iter()
                .find(|c| c.measure == "vision")
                .is_some_and(|c| !c.lost() && c.missing.is_empty())
    }

    /// One line: each measure as `vision 0.00627 vs upsample_detail 0.00607 (lost)`.
    pub fn describe(&self) -> String {
        let mut parts: Vec<String> = self
            .checks
            .iter()
            .map(|c| {
                if c.model.is_none() && !c.baseline_error.is_finite() {
                    return format!("{} not recorded", c.measure);
                }
                let model = c.model.map_or("not recorded".into(), |m| format!("{m:.5}"));
                let outcome = match (c.model, c.lost()) {
                    (None, _) => "unknown",
                    (Some(_), true) => "lost",
                    (Some(_), false) => "beaten",
                };
                let mut text = format!(
                    "{} {model} vs {} {:.5} ({outcome})",
                    c.measure, c.baseline, c.baseline_error,
                );
                if !c.missing.is_empty() {
                    text += &format!(", {} not recorded", c.missing.join(" and "));
                }
                text
            })
            .collect();
        if self.failed_trials > 0 {
            parts.push(format!("{} trials diverged", self.failed_trials));
        }
        parts.join("; ")
    }
}

/// The model's error against the lowest of the recorded baselines.
fn check(
    measure: &'static str,
    model: Option<f64>,
    baselines: &[(&'static str, Option<f64>)],
) -> GateCheck {
    let (baseline, baseline_error) = baselines
        .iter()
        .filter_map(|(name, e)| Some((*name, (*e)?)))
        .fold(("none recorded", f64::INFINITY), |best, b| {
            if b.1 < best.1 { b } else { best }
        });
    let mut missing: Vec<&'static str> = Vec::new();
    if model.is_none() {
        missing.push("model");
    }
    missing.extend(
        baselines
            .iter()
            .filter(|(_, e)| e.is_none())
            .map(|(name, _)| *name),
    );
    GateCheck {
        measure,
        model,
        baseline,
        baseline_error,
        missing,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn complete(vision: f64, joints: f64) -> ValidationRow {
        ValidationRow {
            iteration: 8000,
            trials: 24,
            recon_vision_top: vision,
            recon_joints: Some(0.003),
            recon_torques: Some(0.004),
            upsample: Some(0.0094),
            upsample_detail: Some(0.0061),
            mean: Some(0.0138),
            nearest: Some(0.0075),
            next_joints: Some(joints),
            next_torques: Some(0.020),
            previous_joints: Some(0.0157),
            previous_torques: Some(0.0286),
            mean_joints: Some(0.17),
            mean_torques: Some(0.15),
            ..Default::default()
        }
    }

    #[test]
    fn a_network_passes_only_by_beating_the_strongest_baseline_of_every_measure() {
        let pass = Gate::of(&complete(0.0050, 0.0140));
        assert_eq!(pass.verdict, GateVerdict::Pass, "{}", pass.describe());
        assert_eq!(pass.checks[0].baseline, "upsample_detail");
        assert_eq!(pass.checks[1].baseline, "previous");
        // Vision between upsampling + detail (0.0061) and the nearest frame (0.0075): fail.
        let vision = Gate::of(&complete(0.0063, 0.0140));
        assert_eq!(vision.verdict, GateVerdict::Fail);
        assert!(
            vision
                .describe()
                .contains("vision 0.00630 vs upsample_detail 0.00610 (lost)")
        );
        // Joints predicted worse than copying the previous value: fail, but vision passes.
        let joints = Gate::of(&complete(0.0050, 0.0160));
        assert_eq!(joints.verdict, GateVerdict::Fail);
        assert!(joints.passes_vision() && !vision.passes_vision());
        // A diverged trial fails whatever the errors.
        let diverged = ValidationRow {
            failed_trials: 1,
            ..complete(0.0050, 0.0140)
        };
        assert_eq!(Gate::of(&diverged).verdict, GateVerdict::Fail);
    }

    #[test]
    fn a_log_without_the_gates_baselines_never_passes() {
        // Written before 2026-12-06: vision baselines but upsampling's only, no prediction.
        let old = ValidationRow {
            nearest: None,
            next_joints: None,
            next_torques: None,
            previous_joints: None,
            previous_torques: None,
            mean_joints: None,
            mean_torques: None,
            ..complete(0.0050, 0.0140)
        };
        let gate = Gate::of(&old);
        // Vision beats every recorded baseline; the prediction was not recorded.
        assert_eq!(gate.verdict, GateVerdict::Incomplete, "{}", gate.describe());
        assert!(
            gate.describe()
                .ends_with("; joints not recorded; torques not recorded")
        );
        // A loss on what was recorded fails, whatever is missing (the November networks).
        let lost = ValidationRow {
            recon_vision_top: 0.0063,
            ..old
        };
        assert_eq!(Gate::of(&lost).verdict, GateVerdict::Fail);
        // With the prediction recorded but the nearest frame missing: incomplete.
        let partial = ValidationRow {
            nearest: None,
            ..complete(0.0050, 0.0140)
        };
        let gate = Gate::of(&partial);
        assert_eq!(gate.verdict, GateVerdict::Incomplete, "{}", gate.describe());
        assert!(gate.describe().contains("nearest not recorded"));
        // A robot without torque sensors is judged on vision and joints only.
        let no_torques = ValidationRow {
            recon_torques: None,
            next_torques: None,
            previous_torques: None,
            mean_torques: None,
            ..complete(0.0050, 0.0140)
        };
        assert_eq!(Gate::of(&no_torques).checks.len(), 2);
        assert!(Gate::of(&no_torques).passes());
    }
}
