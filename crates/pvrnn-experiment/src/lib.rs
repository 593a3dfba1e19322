//! The paper's experiments as plans of independent, resumable jobs.
//!
//! - [`plan`]: experiments, scales and their designs; the manifest `plan.json` of jobs.
//! - [`run`]: running jobs (trainings resume from their checkpoints; inference runs write
//!   one result file each, atomically).
//! - [`occlusion`]: scoring what the model makes of body parts the arms hide.
//! - [`stats`]: paired t-tests, Holm, aligned rank transform ANOVA and ART-C contrasts.
//! - [`report`]: figures, statistics and `report.md` / `summary.json` from the results alone.
//! - [`index`]: the results' index (`docs/results/index.md`) generated from their files.
//! - [`paper`]: the paper's findings beside ours (the table every report ends with).
//! - [`compatibility`]: whether a non-significant result and the paper's differ (one effect
//!   for both studies, tested).
//! - [`reporting`]: running jobs with the report rebuilt when a part of the design (an
//!   interference direction) is complete.
//! - [`slurm`]: the same plan as Slurm job arrays.
//! - [`closed_loop`]: the closed loop's statistics over networks and its success figure
//!   (`pvrnn report drive --networks --figure`).

pub mod closed_loop;
pub mod compatibility;
pub mod index;
pub mod occlusion;
pub mod paper;
pub mod plan;
pub mod report;
pub mod reporting;
pub mod run;
pub mod slurm;
pub mod stats;

pub use plan::{Design, Experiment, Job, JobKind, Plan, Scale};
