//! What a run is: a sequence (by name) under a condition of online inference (the core's
//! [`Condition`]), and a branch of it. Shared by the run store, the engines that compute
//! runs, and the bundles that carry them.

pub use pvrnn_core::infer::Condition;
use serde::{Deserialize, Serialize};

/// Which run: a sequence (by name) under a condition, and, for a branch, the condition it
/// continues under from a step on.
#[derive(Clone, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct RunKey {
    pub sequence: String,
    pub condition: Condition,
    /// A branch: the steps before `then.at` are the run under `condition`, the steps from
    /// it on are inferred under `then.condition`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub then: Option<Switch>,
}

/// Where a branch leaves its run, and the condition it continues under.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct Switch {
    pub at: u32,
    pub condition: Condition,
}

impl RunKey {
    pub fn new(sequence: impl Into<String>, condition: Condition) -> Self {
        Self {
            sequence: sequence.into(),
            condition,
            then: None,
        }
    }

    /// The run a branch leaves (the key itself when it is not a branch).
    pub fn base(&self) -> Self {
        Self {
            then: None,
            ..self.clone()
        }
    }

    /// The branch of this run at step `at` under `condition` (whose window is the run's:
    /// the state a branch continues from holds the run's window). A branch of a branch
    /// leaves the same base run.
    pub fn branched(&self, at: usize, condition: Condition) -> Self {
        Self {
            then: Some(Switch {
                at: at as u32,
                condition: Condition {
                    window: self.condition.window,
                    ..condition
                }
                .canonical(),
            }),
            ..self.base()
        }
    }

    /// The condition in force at step t.
    pub fn condition_at(&self, t: usize) -> &Condition {
        match &self.then {
            Some(s) if t >= s.at as usize => &s.condition,
            _ => &self.condition,
        }
    }
}
