//! The scalable PV-RNN explorer: open a trained model with its dataset, scrub time, change
//! the conditions of online inference (ablations, vision resolution, proprioception, H,
//! iterations, lr, seed) and watch the latent states and predicted images follow. Runs are
//! computed live in slices between frames and cached per condition; runs computed in
//! advance (a bundle from `pvrnn bundle`) show at once. Desktop (eframe) and web (Trunk).

pub mod about;
pub mod app;
#[cfg(target_arch = "wasm32")]
pub mod browser;
pub mod bundle;
pub mod condition;
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

pub use app::ExplorerApp;
pub use bundle::Bundle;
pub use condition::Condition;
pub use state::ViewState;
