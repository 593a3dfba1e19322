//! Online inference by error regression (eq. 18): weights fixed, the adaptive variables of a
//! sliding window of the last H steps are updated to minimise the window's free energy.
//!
//! At each new step t (spec, "Online inference"):
//! - the window is steps max(1, t-H+1)..t; it grows while t < H;
//! - the newest step's a starts at the prior's pre-activation from d_{t-1}; older window
//!   steps keep their a (warm start);
//! - `iterations` RAdam updates of all window a's, fresh eps each iteration, moments reset
//!   at each new step;
//! - the state entering the window is held fixed; a final pass recomputes the window, and
//!   the state after its oldest step is held for the next step once the window is full.
//!
//! A step can be run in slices ([`OnlineInference::begin_step`],
//! [`OnlineInference::iterate`], [`OnlineInference::finish_step`]) so an interactive front
//! end can spread the work over frames.
//!
//! One job per file:
//! - `settings.rs`: what determines a run besides the model and the data
//!   ([`InferenceSettings`]).
//! - `condition.rs`: the same in a few exact, hashable fields ([`Condition`]): the one
//!   condition type of the command line and the explorer.
//! - `states.rs`: one module's distributions and states over steps ([`ModuleStates`]).
//! - `online.rs`: the online inference of one sequence ([`OnlineInference`]), what a step
//!   reports ([`StepOutput`]), and beginning a step.
//! - `iterate.rs`: a step's updates of the window's adaptive variables, restarted at half
//!   the rate where they diverge ([`MAX_RATE_HALVINGS`]).
//! - `finish.rs`: a step's final pass, its outputs and the prior prediction; sliding the
//!   window.
//! - `branch.rs`: the state between two steps ([`InferenceState`]), to continue a run under
//!   other settings.
//! - `run.rs`: a whole run of one sequence, stacked over steps ([`Run`],
//!   [`run_sequence_on`]).

mod branch;
mod condition;
mod finish;
mod iterate;
mod online;
mod run;
mod settings;
mod states;

pub use branch::InferenceState;
pub use condition::Condition;
pub use online::{MAX_RATE_HALVINGS, OnlineInference, StepOutput};
pub use run::{Run, run_sequence_on};
pub use settings::InferenceSettings;
pub use states::ModuleStates;
