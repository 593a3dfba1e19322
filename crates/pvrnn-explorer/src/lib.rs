//! The scalable PV-RNN explorer: open a trained model with its dataset, scrub time, change
//! the conditions of online inference (ablations, vision resolution, proprioception, H,
//! iterations, lr, seed) and watch the latent states and predicted images follow. Runs are
//! computed live in slices between frames and cached per condition; runs computed in
//! advance (a bundle from `pvrnn bundle`) show at once. Desktop (eframe) and web (Trunk).
//!
//! Modules, from the leaves up:
//! - `condition`: what a run depends on (`Condition`) and which run a view names (`RunKey`:
//!   a sequence and a condition, and for a branch the step it leaves the run at); the leaf
//!   every other module shares.
//! - `bundle`: a model, its test sequences and precomputed runs (`Bundle`), from a folder,
//!   downloaded bytes or dropped files; `drop`: assembling dropped or chosen files.
//! - `engine`: online inference of one run at a time in slices (`Engine`), reporting each
//!   step as a `CompactStep`; it keeps each step's inference state, so a branch continues
//!   from its run's state. No egui, no browser.
//! - `executor`: where runs are computed (`Executor`): `Inline` in slices of the frame
//!   budget, `thread` (desktop) and `worker` (web) beside the window; `driving`: the Drive
//!   window's episode (`LocalDrive` steps it: the window between frames, or the worker).
//! - `runs`: the runs a view needs, cached and queued (`RunStore`, `RunTrace`).
//! - `state`: everything a view is (`ViewState`), as the URL hash or `--view`, kept within
//!   what the bundle can show.
//! - `images`: predicted images read out from `d` on demand, contours, contribution maps.
//! - `findings`: the paper's claims beside ours, each a row of `docs/results/experiments.md`.
//! - `about`: the "About this model" window (the model card).
//! - `app`: the window (`ExplorerApp`): its state and logic in `app/mod.rs`, one file per
//!   panel (`controls`, `status`, `time_panel`, `images_panel`, `traces`, `summaries`,
//!   `compare`, `branch`, `second`, `contributions`, `findings_panel`, `tour`, `drive`: the
//!   network driving caresim's robot, `pvrnn_drive`), `export`
//!   (CSV of a run, PNG of the window) and `bench` (frames drawn headless and timed).
//! - `web`, `browser` (wasm32): the web entry and the browser glue the app, the store and
//!   the worker share.
//!
//! How a change of condition becomes a picture: the view names a `RunKey`. A cached run
//! shows at once; otherwise `RunStore::request` queues it as urgent, the executor pauses
//! what it was computing and runs it, and each finished step arrives as a `CompactStep`.
//! Runs keep latent states only; images are read out from `d` for the frame shown
//! (`LoadedModel::readout`), so a 300-step run costs about 1 MB instead of about 80 MB.

pub mod about;
pub mod app;
#[cfg(target_arch = "wasm32")]
pub mod browser;
pub mod bundle;
pub mod condition;
pub mod driving;
pub mod drop;
pub mod engine;
pub mod executor;
pub mod findings;
pub mod images;
pub mod runs;
pub mod state;
#[cfg(not(target_arch = "wasm32"))]
pub mod thread;
#[cfg(target_arch = "wasm32")]
pub mod web;
#[cfg(target_arch = "wasm32")]
pub mod worker;

pub use app::{ExplorerApp, TourTarget};
pub use bundle::Bundle;
pub use condition::Condition;
pub use state::ViewState;
