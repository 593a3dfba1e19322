//! Where runs are computed. The run store only sends commands and reads [`Event`]s, so it
//! does not depend on how (or on which thread) a result was computed: in slices between
//! frames on the calling thread ([`Inline`]), on a background thread beside the desktop
//! window (`thread::ThreadClient`), or in a Web Worker beside the page
//! (`worker::WorkerClient`). The Drive window's episode goes where runs go: the page or
//! the desktop window steps it between frames ([`LocalDrive`]), the web worker between its
//! ticks.

use std::sync::Arc;

use pvrnn_core::{Model, Observations};
use web_time::Duration;

use crate::condition::RunKey;
use crate::driving::{DriveEvent, DriveProgress, DriveRequest, LocalDrive};
use crate::engine::{Engine, Event};

pub trait Executor: std::fmt::Debug {
    fn set_model(&mut self, model: &Arc<Model<f32>>);

    fn add_observations(&mut self, name: &str, observations: Arc<Observations<f32>>);

    /// Starts computing `key` (dropping the run it was computing, which stays paused).
    fn run(&mut self, key: &RunKey);

    /// Computes for up to `budget` (inline) or collects what arrived (thread, worker).
    fn poll(&mut self, budget: Duration) -> Vec<Event>;

    /// Why the executor cannot go on (a worker that failed), if it cannot.
    fn broken(&mut self) -> Option<String> {
        None
    }

    /// Where it computes, once it said (`None`: the app's own label).
    fn compute_label(&self) -> Option<String> {
        None
    }

    /// Whether it computes on the calling thread (then only while polled).
    fn is_inline(&self) -> bool {
        false
    }

    /// Applies the Drive window's request; `model` is the open network, which the executor
    /// already has ([`Self::set_model`]).
    fn drive(&mut self, model: &Arc<Model<f32>>, request: DriveRequest) -> Result<(), String>;

    /// The episode in progress, as last heard of.
    fn drive_progress(&self) -> Option<DriveProgress>;

    /// Steps the episode for up to `budget` (stepped on the calling thread) or collects
    /// what arrived (worker).
    fn poll_drive(&mut self, budget: Duration) -> Vec<DriveEvent>;

    /// Whether an episode advances only while polled (then the window must keep drawing
    /// frames while it drives); a worker's progress repaints the page when it arrives.
    fn drives_here(&self) -> bool {
        true
    }
}

/// Computes in slices between frames, on the calling thread.
#[derive(Debug, Default)]
pub struct Inline {
    engine: Box<Engine>,
    drive: LocalDrive,
}

impl Executor for Inline {
    fn set_model(&mut self, model: &Arc<Model<f32>>) {
        self.engine.set_model(model.clone());
    }

    fn add_observations(&mut self, name: &str, observations: Arc<Observations<f32>>) {
        self.engine.add_observations(name.to_string(), observations);
    }

    fn run(&mut self, key: &RunKey) {
        self.engine.run(key.clone());
    }

    fn poll(&mut self, budget: Duration) -> Vec<Event> {
        self.engine.work(budget)
    }

    fn is_inline(&self) -> bool {
        true
    }

    fn drive(&mut self, model: &Arc<Model<f32>>, request: DriveRequest) -> Result<(), String> {
        self.drive.request(Some(model), request)
    }

    fn drive_progress(&self) -> Option<DriveProgress> {
        self.drive.progress()
    }

    fn poll_drive(&mut self, budget: Duration) -> Vec<DriveEvent> {
        self.drive.step_for(budget).into_iter().collect()
    }
}

/// Computing inline until an app hands the store a thread or a worker.
impl Default for Box<dyn Executor> {
    fn default() -> Self {
        Box::<Inline>::default()
    }
}
