//! The network drives the robot: closed-loop online inference in caresim (issue 70;
//! docs/closed-loop.md).
//!
//! At each step the environment's observation (both cameras, noisy joints and torques)
//! updates the network's latent states by online inference, and the network's prediction
//! of the next step's joint angles is the command the arms move toward. The episode is
//! recorded in the dataset format, so it can be evaluated, bundled and explored like a
//! recording, and scored by caresim's pre-specified success criteria
//! ([`caresim::outcome`]).
//!
//! - [`spec`]: what an episode is ([`DriveSpec`]): the trial, who drives ([`Controller`]:
//!   the network closed loop, or a baseline), the joints' speed limit and the
//!   perturbations ([`Perturbations`]: sensor noise, a push, an occluded camera).
//! - [`drive`]: the loop, one step at a time ([`Drive`]), and what it leaves ([`Episode`]).
//! - [`baseline`]: the mean learning trajectory, replayed open loop.
//! - [`output`]: an episode's folder (the dataset, the network's run, `drive.json`).
//! - [`table`]: the success table of many episodes (`pvrnn report drive`).

pub mod baseline;
pub mod drive;
pub mod output;
pub mod spec;
pub mod table;

pub use drive::{Drive, DriveStep, Episode, Network, check_model};
pub use spec::{Controller, DriveSpec, Occlusion, Perturbations, Push, VisionDrop};

/// What can go wrong driving.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A spec, model or command that cannot drive, and why.
    #[error("{0}")]
    Invalid(String),
    #[error(transparent)]
    Step(#[from] caresim::env::StepError),
    #[error(transparent)]
    Core(#[from] pvrnn_core::Error),
    #[error(transparent)]
    Dataset(#[from] pvrnn_dataset::Error),
}

pub type Result<T, E = Error> = std::result::Result<T, E>;
