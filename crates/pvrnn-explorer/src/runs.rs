//! Inference runs as the explorer keeps them: per condition, compact (the states that
//! reproduce every prediction), computed live in slices so the interface never freezes,
//! and cached.

use std::collections::{HashMap, HashSet, VecDeque};
use std::sync::Arc;

use pvrnn_core::config::{ModelConfig, ModuleId};
use pvrnn_core::infer::{InferenceSettings, Run};
use pvrnn_core::{Ablation, AblationMode, Modality, Model, NoiseMode, Observations, Observed};

pub use crate::engine::Finished;
use crate::engine::{CompactStep, Engine, Event, ModuleStates};
use serde::{Deserialize, Serialize};
use web_time::{Duration, Instant};

/// Everything an inference run depends on besides the model and the sequence.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct Condition {
    /// Lowest vision levels observed (0 = none).
    pub vision_levels: u8,
    pub proprio: bool,
    /// Modules whose z is set to 0.
    pub ablation: [bool; 4],
    /// When the ablation applies (readout: re-read the standard inference; inference: z = 0
    /// throughout). Meaningless without an ablation: [`Condition::canonical`] resets it.
    #[serde(default)]
    pub ablation_mode: AblationMode,
    /// H.
    pub window: u16,
    pub iterations: u16,
    /// The inference learning rate's bits: exact (a rate such as 0.0905 must not round to
    /// another), and hashable so conditions can be keys. See [`Condition::lr`].
    pub lr_bits: u64,
    pub seed: u32,
}

impl Condition {
    /// The model's configured inference, everything observed, no ablation, seed 0.
    pub fn standard(config: &ModelConfig) -> Self {
        Self {
            vision_levels: config.vision.resolutions.len() as u8,
            proprio: true,
            ablation: [false; 4],
            ablation_mode: AblationMode::default(),
            window: config.inference.window as u16,
            iterations: config.inference.iterations as u16,
            lr_bits: config.inference.optimizer.lr.to_bits(),
            seed: 0,
        }
    }

    pub fn settings(&self, config: &ModelConfig) -> InferenceSettings {
        let mut s = InferenceSettings::from_config(config, self.seed as u64);
        s.observed = Observed {
            vision_levels: self.vision_levels as usize,
            proprio: self.proprio,
        };
        s.ablation = Ablation(self.ablation);
        s.ablation_mode = self.ablation_mode;
        s.window = (self.window as usize).max(1);
        s.iterations = self.iterations as usize;
        s.optimizer.lr = self.lr();
        s.canonical()
    }

    /// The same condition with the ablation mode reset when nothing is ablated, so one
    /// run has one key.
    pub fn canonical(self) -> Self {
        if self.ablation.iter().any(|&a| a) {
            self
        } else {
            Self {
                ablation_mode: AblationMode::default(),
                ..self
            }
        }
    }

    /// The condition a run was computed under, if it is one the explorer can express.
    pub fn of(settings: &InferenceSettings, config: &ModelConfig) -> Option<Self> {
        let seed = match settings.noise {
            NoiseMode::Sampled { seed } => u32::try_from(seed).ok()?,
            NoiseMode::Zero => return None,
        };
        let c = Self {
            vision_levels: settings.observed.vision_levels as u8,
            proprio: settings.observed.proprio,
            ablation: settings.ablation.0,
            ablation_mode: settings.ablation_mode,
            window: settings.window as u16,
            iterations: settings.iterations as u16,
            lr_bits: settings.optimizer.lr.to_bits(),
            seed,
        };
        (c.settings(config) == settings.clone().canonical()).then_some(c.canonical())
    }

    /// The inference learning rate.
    pub fn lr(&self) -> f64 {
        f64::from_bits(self.lr_bits)
    }

    pub fn set_lr(&mut self, lr: f64) {
        self.lr_bits = lr.to_bits();
    }

    /// The same condition (and ablation mode) with exactly one module ablated.
    pub fn ablating(&self, module: ModuleId) -> Self {
        let mut c = *self;
        c.ablation = [false; 4];
        c.ablation[module.index()] = true;
        c
    }

    pub fn without_ablation(&self) -> Self {
        Self {
            ablation: [false; 4],
            ..*self
        }
        .canonical()
    }
}

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
        trace.proprio_recon = loaded.readout(Modality::Proprioceptive, &trace.modules[p].d, steps);
        trace.proprio_prior =
            loaded.readout(Modality::Proprioceptive, &trace.modules[p].prior_d, steps);
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

/// Which run: a sequence (by name) under a condition.
#[derive(Clone, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct RunKey {
    pub sequence: String,
    pub condition: Condition,
}

/// How soon the window redraws after an off-thread result arrives (web worker, desktop
/// thread): often enough to watch a run grow, rarely enough that drawing does not take the
/// core the inference needs (measured: `pvrnn-explorer --bench-live`).
pub const REPAINT_EVERY: Duration = Duration::from_millis(100);

/// Where runs are computed. The store only sends commands and reads [`Event`]s, so it does
/// not depend on how (or on which thread) a result was computed.
#[derive(Debug)]
pub enum Executor {
    /// In slices between frames, on the calling thread.
    Inline(Box<Engine>),
    /// In a Web Worker, beside the page's thread.
    #[cfg(target_arch = "wasm32")]
    Worker(crate::worker::WorkerClient),
    /// On a background thread, beside the window's (desktop).
    #[cfg(not(target_arch = "wasm32"))]
    Thread(crate::thread::ThreadClient),
}

impl Default for Executor {
    fn default() -> Self {
        Self::Inline(Box::default())
    }
}

impl Executor {
    fn set_model(&mut self, model: &Arc<Model<f32>>) {
        match self {
            Self::Inline(e) => e.set_model(model.clone()),
            #[cfg(target_arch = "wasm32")]
            Self::Worker(w) => w.set_model(model),
            #[cfg(not(target_arch = "wasm32"))]
            Self::Thread(t) => t.set_model(model),
        }
    }

    fn add_observations(&mut self, name: &str, observations: Arc<Observations<f32>>) {
        match self {
            Self::Inline(e) => e.add_observations(name.to_string(), observations),
            #[cfg(target_arch = "wasm32")]
            Self::Worker(w) => w.add_observations(name, &observations),
            #[cfg(not(target_arch = "wasm32"))]
            Self::Thread(t) => t.add_observations(name, observations),
        }
    }

    fn run(&mut self, key: &RunKey) {
        match self {
            Self::Inline(e) => e.run(key.clone()),
            #[cfg(target_arch = "wasm32")]
            Self::Worker(w) => w.run(key),
            #[cfg(not(target_arch = "wasm32"))]
            Self::Thread(t) => t.run(key),
        }
    }

    /// Computes for up to `budget` (inline) or collects what arrived (worker, thread).
    fn poll(&mut self, budget: Duration) -> Vec<Event> {
        match self {
            Self::Inline(e) => e.work(budget),
            #[cfg(target_arch = "wasm32")]
            Self::Worker(w) => w.take_events(),
            #[cfg(not(target_arch = "wasm32"))]
            Self::Thread(t) => t.take_events(),
        }
    }

    /// Why the executor cannot go on (a worker that failed), if it cannot.
    fn broken(&mut self) -> Option<String> {
        match self {
            Self::Inline(_) => None,
            #[cfg(target_arch = "wasm32")]
            Self::Worker(w) => w.failure(),
            #[cfg(not(target_arch = "wasm32"))]
            Self::Thread(t) => t.failure(),
        }
    }

    /// Where a worker computes, once it said (`None`: the executor's own default label).
    fn compute_label(&self) -> Option<String> {
        match self {
            #[cfg(target_arch = "wasm32")]
            Self::Worker(w) => w.compute(),
            _ => None,
        }
    }

    pub fn is_inline(&self) -> bool {
        matches!(self, Self::Inline(_))
    }
}

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
    executor: Executor,
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
    pub fn set_executor(&mut self, executor: Executor) {
        self.executor = executor;
        self.restart_executor();
    }

    pub fn with_executor(executor: Executor) -> Self {
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

    /// Asks for a run; an `urgent` one (the run being looked at) interrupts any other.
    pub fn request(&mut self, key: RunKey, urgent: bool) {
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
        if let Some(reason) = self.executor.broken() {
            // Computing in the page is slower, but it works everywhere.
            self.executor = Executor::default();
            self.restart_executor();
            note_fallback(&reason);
            self.notes.push(format!(
                "live runs compute in the page: the worker failed ({reason})"
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
    crate::web::log(&format!(
        "computing in the page instead of a worker: {reason}"
    ));
    #[cfg(not(target_arch = "wasm32"))]
    let _ = reason;
}
