//! Inference runs as the explorer keeps them: per condition, compact (the states that
//! reproduce every prediction), computed live in slices so the interface never freezes,
//! and cached.

use std::collections::{HashMap, HashSet, VecDeque};
use std::sync::Arc;

use pvrnn_core::config::{ModelConfig, ModuleId};
use pvrnn_core::infer::Run;
use pvrnn_core::{Modality, Model, Observations};
use web_time::{Duration, Instant};

use crate::condition::RunKey;
use crate::driving::{DriveEvent, DriveProgress, DriveRequest, EPISODE_SO_FAR};
pub use crate::engine::Finished;
use crate::engine::{CompactStep, Event, ModuleStates};
use crate::executor::Executor;

/// A run in progress or complete: what the views need, growing step by step.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RunTrace {
    pub steps: usize,
    /// Latent and recurrent sizes per module.
    pub z: [usize; 4],
    pub d: [usize; 4],
    /// Every module's states, row-major `[steps, width]`.
    pub modules: [ModuleStates; 4],
    /// Window free energy per step.
    pub free_energy: Vec<f32>,
    /// Mean squared reconstruction error of all dimensions (vision, proprioception).
    pub recon_error: Vec<[f32; 2]>,
    /// Predicted proprioception (model units): posterior reconstruction and one-step prior
    /// prediction, `[steps, dims]`.
    pub proprio_recon: Vec<f32>,
    pub proprio_prior: Vec<f32>,
}

impl RunTrace {
    pub fn new(config: &ModelConfig) -> Self {
        Self {
            z: ModuleId::ALL.map(|id| config.module(id).z),
            d: ModuleId::ALL.map(|id| config.module(id).d),
            ..Self::default()
        }
    }

    pub fn push(&mut self, step: &CompactStep) {
        for (trace, s) in self.modules.iter_mut().zip(&step.modules) {
            trace.extend(s);
        }
        self.free_energy.push(step.free_energy);
        self.recon_error.push(step.recon_error);
        self.proprio_recon.extend_from_slice(&step.proprio_recon);
        self.proprio_prior.extend_from_slice(&step.proprio_prior);
        self.steps += 1;
    }

    /// A stored (compact) run; proprioceptive predictions are re-read out from `d` by
    /// `loaded` (the model's weights on a backend).
    pub fn from_run(
        run: &Run<f32>,
        config: &ModelConfig,
        loaded: &dyn pvrnn_core::backend::LoadedModel<f32>,
    ) -> Self {
        let mut trace = Self::new(config);
        let steps = run.steps();
        trace.modules = run.modules.clone();
        trace.free_energy = run.free_energy.iter().map(|f| f.total as f32).collect();
        trace.recon_error = run
            .recon_error
            .iter()
            .map(|e| e.map(|v| v as f32))
            .collect();
        let p = ModuleId::Proprioceptive.index();
        let proprio = Modality::Proprioceptive;
        trace.proprio_recon = host_read_out(loaded, proprio, &trace.modules[p].d, steps);
        trace.proprio_prior = host_read_out(loaded, proprio, &trace.modules[p].prior_d, steps);
        trace.steps = steps;
        trace
    }

    /// One module's `d` at step t (or its prior-step d).
    pub fn d_at(&self, module: ModuleId, t: usize, prior: bool) -> &[f32] {
        let m = module.index();
        let w = self.d[m];
        let v = if prior {
            &self.modules[m].prior_d
        } else {
            &self.modules[m].d
        };
        &v[t * w..(t + 1) * w]
    }
}

/// A cached run and whether it is finished.
#[derive(Clone, Debug)]
pub struct Entry {
    pub trace: RunTrace,
    pub complete: bool,
    pub error: Option<String>,
}

/// How soon the window redraws after an off-thread result arrives (web worker, desktop
/// thread): often enough to watch a run grow, rarely enough that drawing does not take the
/// core the inference needs (measured: `pvrnn-explorer --bench-live`).
pub const REPAINT_EVERY: Duration = Duration::from_millis(100);

/// Gives a sequence's inputs by name.
pub type ObservationSource<'a> = dyn FnMut(&str) -> Result<Arc<Observations<f32>>, String> + 'a;

/// All runs: cached, being computed, or waiting.
#[derive(Default)]
pub struct RunStore {
    entries: HashMap<RunKey, Entry>,
    queue: VecDeque<RunKey>,
    /// The run being looked at: it takes over from any other.
    urgent: Option<RunKey>,
    /// Live runs finished since the last `take_finished`.
    finished: Vec<Finished>,
    executor: Box<dyn Executor>,
    /// The model the executor has, the sequences it has, and what it is computing.
    executor_model: Option<Arc<Model<f32>>>,
    provided: HashSet<String>,
    running: Option<(RunKey, usize)>,
    /// What the user should know about how runs are computed (e.g. a failed worker).
    notes: Vec<String>,
}

impl std::fmt::Debug for RunStore {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RunStore")
            .field("runs", &self.entries.len())
            .field("queued", &self.queue.len())
            .field("computing", &self.computing())
            .field("inline", &self.executor.is_inline())
            .finish()
    }
}

impl RunStore {
    /// Notes since the last call, for the status line.
    /// Where live runs compute when the executor knows better than the app (a worker that
    /// chose WebGPU or the CPU).
    pub fn compute_label(&self) -> Option<String> {
        self.executor.compute_label()
    }

    pub fn take_notes(&mut self) -> Vec<String> {
        std::mem::take(&mut self.notes)
    }

    /// Computes with `executor` from now on; runs part way through start again there.
    pub fn set_executor(&mut self, executor: Box<dyn Executor>) {
        self.executor = executor;
        self.restart_executor();
    }

    pub fn with_executor(executor: Box<dyn Executor>) -> Self {
        Self {
            executor,
            ..Self::default()
        }
    }

    pub fn insert_complete(&mut self, key: RunKey, trace: RunTrace) {
        self.entries.insert(
            key,
            Entry {
                trace,
                complete: true,
                error: None,
            },
        );
    }

    pub fn get(&self, key: &RunKey) -> Option<&Entry> {
        self.entries.get(key)
    }

    /// Forgets every run of a sequence (the episode being driven, which grows).
    pub fn forget_sequence(&mut self, name: &str) {
        self.entries.retain(|k, _| k.sequence != name);
        self.queue.retain(|k| k.sequence != name);
    }

    /// Asks for a run; an `urgent` one (the run being looked at) interrupts any other.
    pub fn request(&mut self, key: RunKey, urgent: bool) {
        // The episode being driven has the one run the drive infers; none is computed from
        // its recording, which grows (ablated or other conditions wait for its end).
        if key.sequence == EPISODE_SO_FAR {
            return;
        }
        let done = self.entries.get(&key).is_some_and(|e| e.complete);
        if urgent {
            self.urgent = (!done).then(|| key.clone());
        }
        let running = self.computing() == Some(&key);
        if done || running || (!urgent && self.queue.contains(&key)) {
            return;
        }
        self.queue.retain(|k| *k != key);
        if urgent {
            self.queue.push_front(key);
        } else {
            self.queue.push_back(key);
        }
    }

    /// Nothing computing or waiting.
    pub fn idle(&self) -> bool {
        self.running.is_none() && self.queue.is_empty()
    }

    pub fn computing(&self) -> Option<&RunKey> {
        self.running.as_ref().map(|(k, _)| k)
    }

    /// Steps done and total of the run being computed.
    pub fn progress(&self) -> Option<(usize, usize)> {
        let (key, total) = self.running.as_ref()?;
        Some((self.entries.get(key).map_or(0, |e| e.trace.steps), *total))
    }

    pub fn waiting(&self) -> usize {
        self.queue.len()
    }

    /// Whether runs are computed on this thread.
    pub fn computes_inline(&self) -> bool {
        self.executor.is_inline()
    }

    /// Live runs finished since last asked.
    pub fn take_finished(&mut self) -> Vec<Finished> {
        std::mem::take(&mut self.finished)
    }

    /// Forgets every run (a new model or dataset); the executor stays.
    pub fn clear(&mut self) {
        let executor = std::mem::take(&mut self.executor);
        *self = Self::with_executor(executor);
    }

    /// Runs what is asked for and takes in results, computing for up to `budget` when inline.
    /// `observations(name)` gives a sequence's inputs. Returns whether anything happened.
    pub fn work(
        &mut self,
        model: &Arc<Model<f32>>,
        budget: Duration,
        observations: &mut ObservationSource<'_>,
    ) -> bool {
        let start = Instant::now();
        self.ready_executor(model);
        let mut worked = false;
        loop {
            self.dispatch(model, observations);
            let left = budget.saturating_sub(start.elapsed());
            let events = self.executor.poll(left);
            worked |= !events.is_empty();
            for event in events {
                self.take_event(event);
            }
            if !self.executor.is_inline() || self.idle() || start.elapsed() >= budget {
                break;
            }
        }
        // Hand the executor its next run at once rather than a frame later.
        self.dispatch(model, observations);
        worked || (self.executor.is_inline() && self.running.is_some())
    }

    /// Applies the Drive window's request where runs are computed (so in the web worker
    /// when there is one), after the executor has `model`.
    pub fn drive(&mut self, model: &Arc<Model<f32>>, request: DriveRequest) -> Result<(), String> {
        self.ready_executor(model);
        self.executor.drive(model, request)
    }

    /// The episode in progress, as last heard of.
    pub fn drive_progress(&self) -> Option<DriveProgress> {
        self.executor.drive_progress()
    }

    /// Whether an episode advances only while frames are drawn (not in a worker).
    pub fn drives_here(&self) -> bool {
        self.executor.drives_here()
    }

    /// Steps the episode for up to `budget` when it is stepped here, or collects what the
    /// worker sent.
    pub fn poll_drive(&mut self, budget: Duration) -> Vec<DriveEvent> {
        self.executor.poll_drive(budget)
    }

    /// An executor that works (the page's own when the worker failed) and has `model`.
    fn ready_executor(&mut self, model: &Arc<Model<f32>>) {
        if let Some(reason) = self.executor.broken() {
            let driving = self.executor.drive_progress().is_some();
            // Computing in the page is slower, but it works everywhere.
            self.executor = Box::default();
            self.restart_executor();
            note_fallback(&reason);
            self.notes.push(format!(
                "live runs compute in the page: the worker failed ({reason}){}",
                if driving {
                    "; the episode it was driving is lost"
                } else {
                    ""
                }
            ));
        }
        if !self
            .executor_model
            .as_ref()
            .is_some_and(|m| Arc::ptr_eq(m, model))
        {
            self.restart_executor();
            self.executor.set_model(model);
            self.executor_model = Some(model.clone());
        }
    }

    /// A fresh executor state: runs it was part way through start again.
    fn restart_executor(&mut self) {
        self.entries.retain(|_, e| e.complete);
        if let Some((key, _)) = self.running.take() {
            self.queue.push_front(key);
        }
        self.provided.clear();
        self.executor_model = None;
    }

    /// Makes the executor run the urgent run, or else the next waiting one.
    fn dispatch(&mut self, model: &Arc<Model<f32>>, observations: &mut ObservationSource<'_>) {
        let complete = |s: &Self, k: &RunKey| s.entries.get(k).is_some_and(|e| e.complete);
        if let Some(u) = &self.urgent
            && complete(self, u)
        {
            self.urgent = None;
        }
        let want = match (&self.urgent, &self.running) {
            (Some(u), Some((r, _))) if u != r => {
                // Paused, not lost: the executor keeps its state and the key waits its turn.
                let (r, _) = self.running.take().expect("matched");
                self.queue.push_back(r);
                u.clone()
            }
            (_, Some(_)) => return,
            (Some(u), None) => u.clone(),
            (None, None) => loop {
                let Some(k) = self.queue.pop_front() else {
                    return;
                };
                if !complete(self, &k) {
                    break k;
                }
            },
        };
        self.queue.retain(|k| *k != want);
        let obs = match observations(&want.sequence) {
            Ok(o) => o,
            Err(e) => {
                self.fail(&want, e);
                return;
            }
        };
        if let Err(e) = obs.check_fits(&model.config) {
            self.fail(&want, e.to_string());
            return;
        }
        if self.provided.insert(want.sequence.clone()) {
            self.executor.add_observations(&want.sequence, obs.clone());
        }
        self.entries.entry(want.clone()).or_insert_with(|| Entry {
            trace: RunTrace::new(&model.config),
            complete: false,
            error: None,
        });
        self.executor.run(&want);
        self.running = Some((want, obs.lengths()[0]));
    }

    fn fail(&mut self, key: &RunKey, error: String) {
        let entry = self.entries.entry(key.clone()).or_insert_with(|| Entry {
            trace: RunTrace::default(),
            complete: true,
            error: None,
        });
        entry.complete = true;
        entry.error = Some(error);
        if self.urgent.as_ref() == Some(key) {
            self.urgent = None;
        }
        if self.computing() == Some(key) {
            self.running = None;
        }
    }

    fn take_event(&mut self, event: Event) {
        match event {
            Event::Step(key, step) => {
                if let Some(e) = self.entries.get_mut(&key).filter(|e| !e.complete) {
                    e.trace.push(&step);
                }
            }
            Event::Done(f) => {
                if let Some(e) = self.entries.get_mut(&f.key) {
                    e.complete = true;
                }
                if self.urgent.as_ref() == Some(&f.key) {
                    self.urgent = None;
                }
                if self.computing() == Some(&f.key) {
                    self.running = None;
                }
                self.finished.push(f);
            }
            Event::Failed(key, e) => self.fail(&key, e),
        }
    }
}

/// Says (in the browser console) why runs are computed in the page rather than a worker.
fn note_fallback(reason: &str) {
    #[cfg(target_arch = "wasm32")]
    eframe::web_sys::console::log_1(
        &format!("computing in the page instead of a worker: {reason}").into(),
    );
    #[cfg(not(target_arch = "wasm32"))]
    let _ = reason;
}

/// The read-out of `n` module states `d` into every dimension of `modality`, for a model
/// loaded on the host: the explorer loads every bundle on the CPU backend (`Bundle::loaded`),
/// whose read-outs cannot fail (only a device's can,
/// [`pvrnn_core::backend::LoadedModel::readout`]).
pub fn host_read_out(
    loaded: &dyn pvrnn_core::backend::LoadedModel<f32>,
    modality: Modality,
    d: &[f32],
    n: usize,
) -> Vec<f32> {
    loaded
        .readout(modality, d, n)
        .unwrap_or_else(|e| unreachable!("a read-out on the host failed: {e}"))
}
