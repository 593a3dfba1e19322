//! The compute side of the explorer: online inference of one run at a time, advanced in
//! slices, reporting each finished step as a [`CompactStep`]. It knows nothing of egui or of
//! the browser, so the same engine runs inline between frames (desktop, tests) and inside a
//! Web Worker (web), where the page only sees the messages.

use std::collections::{HashMap, VecDeque};
use std::sync::Arc;

use pvrnn_core::backend::Backend;
use pvrnn_core::config::{ModelConfig, ModuleId};
use pvrnn_core::infer::{InferenceState, OnlineInference, StepOutput};
use pvrnn_core::{Modality, Model, Observations};
use web_time::{Duration, Instant};

use crate::condition::RunKey;

/// One module's states at one step, or (in a `RunTrace`) at every step so far: the core's
/// type, shared by the engine, the worker's messages and the views.
pub type ModuleStates = pvrnn_core::infer::ModuleStates<f32>;

/// What the views keep of one inference step: the latent states, from which every image is
/// read out on demand, plus the few numbers that would cost a read-out to recompute.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CompactStep {
    pub modules: [ModuleStates; 4],
    /// Free energy of the inference window.
    pub free_energy: f32,
    /// Mean squared reconstruction error (vision, proprioception).
    pub recon_error: [f32; 2],
    /// Proprioception reconstructed and predicted one step ahead (model units).
    pub proprio_recon: Vec<f32>,
    pub proprio_prior: Vec<f32>,
}

/// Sizes that fix the layout of a [`CompactStep`] as a flat list of numbers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StepLayout {
    pub z: [usize; 4],
    pub d: [usize; 4],
    pub proprio: usize,
}

impl StepLayout {
    pub fn of(config: &ModelConfig) -> Self {
        Self {
            z: ModuleId::ALL.map(|id| config.module(id).z),
            d: ModuleId::ALL.map(|id| config.module(id).d),
            proprio: config.proprio_dims,
        }
    }

    /// Numbers in one encoded step.
    pub fn len(&self) -> usize {
        (0..4).map(|m| 4 * self.z[m] + 2 * self.d[m]).sum::<usize>() + 3 + 2 * self.proprio
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

impl CompactStep {
    pub fn from_output(out: &StepOutput<f32>) -> Self {
        Self {
            modules: out.modules.clone(),
            free_energy: out.window_free_energy.total as f32,
            recon_error: out.recon_error.map(|e| e as f32),
            proprio_recon: out.recon[1].clone(),
            proprio_prior: out.prior_next[1].clone(),
        }
    }

    /// Flat encoding, for messages between threads.
    pub fn to_f32s(&self) -> Vec<f32> {
        let mut v = Vec::new();
        for m in &self.modules {
            for part in m.fields() {
                v.extend_from_slice(part);
            }
        }
        v.push(self.free_energy);
        v.extend_from_slice(&self.recon_error);
        v.extend_from_slice(&self.proprio_recon);
        v.extend_from_slice(&self.proprio_prior);
        v
    }

    /// Decodes [`Self::to_f32s`]; a length that does not fit the layout is an error.
    pub fn from_f32s(v: &[f32], layout: &StepLayout) -> Result<Self, String> {
        if v.len() != layout.len() {
            return Err(format!(
                "a step message has {} numbers, the model needs {}",
                v.len(),
                layout.len()
            ));
        }
        let mut rest = v;
        let mut take = |n: usize| {
            let (head, tail) = rest.split_at(n);
            rest = tail;
            head.to_vec()
        };
        let modules = std::array::from_fn(|m| {
            let mut states = ModuleStates::default();
            let widths = ModuleStates::widths(layout.z[m], layout.d[m]);
            for (field, width) in states.fields_mut().into_iter().zip(widths) {
                *field = take(width);
            }
            states
        });
        let free_energy = take(1)[0];
        let e = take(2);
        Ok(Self {
            modules,
            free_energy,
            recon_error: [e[0], e[1]],
            proprio_recon: take(layout.proprio),
            proprio_prior: take(layout.proprio),
        })
    }
}

/// A live run that finished: steps, computing time, and wall time since it started.
#[derive(Clone, Debug, PartialEq)]
pub struct Finished {
    pub key: RunKey,
    pub steps: usize,
    pub busy: Duration,
    pub wall: Duration,
    /// Steps that were not computed but replayed (a branch's shared past, known from its
    /// run): `steps - replayed` were computed in `busy`.
    pub replayed: usize,
}

/// What the engine reports.
#[derive(Clone, Debug, PartialEq)]
pub enum Event {
    /// The next step of a run (steps of one run always arrive in order).
    Step(RunKey, Box<CompactStep>),
    Done(Finished),
    Failed(RunKey, String),
}

/// Online inference of one sequence under one condition, advanced a slice at a time.
struct Job {
    key: RunKey,
    inference: OnlineInference<f32>,
    observations: Arc<Observations<f32>>,
    next: usize,
    /// Time spent computing (slices only, not the pauses in between).
    busy: Duration,
    started: Instant,
    /// A branch still to take: at this step, continue under these settings.
    switch: Option<(usize, pvrnn_core::infer::InferenceSettings)>,
    /// Steps already known (a branch's shared past), reported before any computed one.
    replay: VecDeque<CompactStep>,
    /// How many steps were replayed.
    replayed: usize,
    /// What the job learns of its base run (the run itself, or a branch's past), so that
    /// later branches of it start where they leave it instead of recomputing its past.
    history: History,
    backend: Option<Arc<dyn Backend<f32>>>,
}

impl Job {
    /// Whether the job is computing its base run (the run itself, or a branch's past
    /// before it switches), whose history later branches continue from.
    fn records_its_base(&self) -> bool {
        self.key.then.is_none() || self.switch.is_some()
    }
}

/// The steps of a run and the inference state before each: `states[t]` is the state
/// before step t, so a branch at t continues from it. A few kilobytes a step.
#[derive(Clone, Debug, Default)]
struct History {
    steps: Vec<CompactStep>,
    states: Vec<InferenceState<f32>>,
}

/// Runs whose histories are kept (the oldest is forgotten first).
const HISTORIES: usize = 8;

/// Inference iterations per slice before the clock is checked.
const CHUNK: usize = 5;

/// Runs one inference job at a time; a job switched away from is paused, not lost.
#[derive(Default)]
pub struct Engine {
    model: Option<Arc<Model<f32>>>,
    observations: HashMap<String, Arc<Observations<f32>>>,
    current: Option<Job>,
    paused: HashMap<RunKey, Job>,
    /// Failures found when a run was asked for, reported by the next `work`.
    failures: Vec<Event>,
    /// Where runs compute; `None`: the CPU backend.
    backend: Option<Arc<dyn Backend<f32>>>,
    /// Histories of base runs computed here (by key, without a branch), newest last.
    histories: VecDeque<(RunKey, History)>,
}

impl std::fmt::Debug for Engine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Engine")
            .field("sequences", &self.observations.len())
            .field("running", &self.running())
            .field("paused", &self.paused.len())
            .finish()
    }
}

impl Engine {
    /// An engine whose runs compute on `backend` (a GPU's, on the desktop).
    pub fn on(backend: Arc<dyn Backend<f32>>) -> Self {
        Self {
            backend: Some(backend),
            ..Self::default()
        }
    }

    /// A new model: every job and sequence is forgotten.
    pub fn set_model(&mut self, model: Arc<Model<f32>>) {
        *self = Self {
            model: Some(model),
            backend: self.backend.take(),
            ..Self::default()
        };
    }

    /// The model runs are computed with, once set.
    pub fn model(&self) -> Option<&Arc<Model<f32>>> {
        self.model.as_ref()
    }

    pub fn add_observations(&mut self, name: String, observations: Arc<Observations<f32>>) {
        self.observations.insert(name, observations);
    }

    pub fn has_observations(&self, name: &str) -> bool {
        self.observations.contains_key(name)
    }

    pub fn running(&self) -> Option<&RunKey> {
        self.current.as_ref().map(|j| &j.key)
    }

    /// Steps done and total of the running job.
    pub fn progress(&self) -> Option<(usize, usize)> {
        self.current
            .as_ref()
            .map(|j| (j.next, j.observations.lengths()[0]))
    }

    /// Makes `key` the running job: the current one is paused, and `key` resumes where it
    /// stopped or starts.
    pub fn run(&mut self, key: RunKey) {
        if self.running() == Some(&key) {
            return;
        }
        if let Some(job) = self.current.take() {
            self.paused.insert(job.key.clone(), job);
        }
        if let Some(job) = self.paused.remove(&key) {
            self.current = Some(job);
            return;
        }
        match self.start(&key) {
            Ok(job) => self.current = Some(job),
            Err(e) => self.failures.push(Event::Failed(key, e)),
        }
    }

    fn start(&self, key: &RunKey) -> Result<Job, String> {
        let model = self.model.as_ref().ok_or("no model is loaded")?;
        let observations = self
            .observations
            .get(&key.sequence)
            .ok_or_else(|| format!("no observations of sequence `{}`", key.sequence))?
            .clone();
        let open = |settings| open(model, settings, self.backend.as_ref());
        let mut job = Job {
            key: key.clone(),
            inference: open(key.condition.settings(&model.config))?,
            observations,
            next: 0,
            busy: Duration::ZERO,
            started: Instant::now(),
            switch: None,
            replay: VecDeque::new(),
            replayed: 0,
            history: History::default(),
            backend: self.backend.clone(),
        };
        let Some(then) = &key.then else {
            return Ok(job);
        };
        let at = then.at as usize;
        let len = job.observations.lengths()[0];
        if at >= len {
            return Err(format!(
                "a branch at step {at}, but `{}` has {len} steps",
                key.sequence
            ));
        }
        let settings = then.condition.settings(&model.config);
        let base = key.base();
        let known = self
            .history(&base)
            .or_else(|| self.paused.get(&base).map(|j| &j.history))
            .filter(|h| h.states.len() > at && h.steps.len() >= at);
        match known {
            // The base run's state at `at` is known: the branch starts there.
            Some(h) => {
                job.inference = open(settings)?;
                let state = h.states[at].clone();
                continue_at(&mut job.inference, state, &job.observations)?;
                job.replay = h.steps[..at].iter().cloned().collect();
                job.replayed = at;
                job.next = at;
            }
            // Otherwise it computes the base run's past first (and keeps its history).
            None => job.switch = Some((at, settings)),
        }
        Ok(job)
    }

    fn history(&self, key: &RunKey) -> Option<&History> {
        self.histories
            .iter()
            .rev()
            .find(|(k, _)| k == key)
            .map(|(_, h)| h)
    }

    /// Keeps what a finished (or stopped) job learned of its base run, unless a longer
    /// history of that run is kept already.
    fn keep_history(&mut self, job: &mut Job) {
        let history = std::mem::take(&mut job.history);
        if history.states.is_empty() {
            return;
        }
        let key = job.key.base();
        if self
            .history(&key)
            .is_some_and(|h| h.states.len() >= history.states.len())
        {
            return;
        }
        self.histories.retain(|(k, _)| *k != key);
        self.histories.push_back((key, history));
        while self.histories.len() > HISTORIES {
            self.histories.pop_front();
        }
    }

    /// Computes the running job for about `budget` (at least one slice) and reports what
    /// happened.
    pub fn work(&mut self, budget: Duration) -> Vec<Event> {
        pvrnn_core::deferred::now(self.work_async(budget))
    }

    /// [`Self::work`] where GPU results arrive through the browser's event loop (WebGPU in
    /// the worker): the same slices, awaited.
    pub async fn work_async(&mut self, budget: Duration) -> Vec<Event> {
        let mut events = std::mem::take(&mut self.failures);
        let start = Instant::now();
        let mut first = true;
        while let Some(job) = self.current.as_mut() {
            if !std::mem::take(&mut first) && start.elapsed() >= budget {
                break;
            }
            for step in job.replay.drain(..) {
                events.push(Event::Step(job.key.clone(), Box::new(step)));
            }
            let slice = Instant::now();
            let result = advance(job).await;
            job.busy += slice.elapsed();
            match result {
                Ok(step) => {
                    if let Some(step) = step {
                        events.push(Event::Step(job.key.clone(), Box::new(step)));
                    }
                    if job.next >= job.observations.lengths()[0] {
                        events.push(Event::Done(Finished {
                            key: job.key.clone(),
                            steps: job.next,
                            busy: job.busy,
                            wall: job.started.elapsed(),
                            replayed: job.replayed,
                        }));
                        if let Some(mut job) = self.current.take() {
                            self.keep_history(&mut job);
                        }
                    }
                }
                Err(e) => {
                    events.push(Event::Failed(job.key.clone(), e));
                    self.current = None;
                }
            }
        }
        events
    }
}

/// An online inference of `model` on `backend` (the CPU's when `None`).
fn open(
    model: &Arc<Model<f32>>,
    settings: pvrnn_core::infer::InferenceSettings,
    backend: Option<&Arc<dyn Backend<f32>>>,
) -> Result<OnlineInference<f32>, String> {
    match backend {
        Some(backend) => OnlineInference::with_backend(model.clone(), settings, backend.as_ref()),
        None => OnlineInference::new(model.clone(), settings),
    }
    .map_err(|e| e.to_string())
}

/// Continues `inference` from `state`, with the window's inputs from the sequence.
fn continue_at(
    inference: &mut OnlineInference<f32>,
    state: InferenceState<f32>,
    observations: &Observations<f32>,
) -> Result<(), String> {
    let end = state.steps_done();
    let inputs: Vec<(&[f32], &[f32])> = (end - state.window_len()..end)
        .map(|t| {
            (
                observations.step(Modality::Exteroceptive, 0, t),
                observations.step(Modality::Proprioceptive, 0, t),
            )
        })
        .collect();
    inference
        .continue_from(state, &inputs)
        .map_err(|e| e.to_string())
}

/// Before step t: a base run records its state; a branch due here switches to its
/// condition.
fn before_step(job: &mut Job) -> Result<(), String> {
    let t = job.next;
    if job.records_its_base() && job.history.states.len() == t {
        let state = job.inference.state().map_err(|e| e.to_string())?;
        job.history.states.push(state);
    }
    if let Some((at, settings)) = job.switch.take_if(|(at, _)| *at == t) {
        debug_assert_eq!(at, t);
        let state = job.inference.state().map_err(|e| e.to_string())?;
        let model = job.inference.model().clone();
        job.inference = open(&model, settings, job.backend.as_ref())?;
        continue_at(&mut job.inference, state, &job.observations)?;
    }
    Ok(())
}

/// A few updates of the job, and the step if it finished one.
async fn advance(job: &mut Job) -> Result<Option<CompactStep>, String> {
    if !job.inference.in_step() {
        before_step(job)?;
    }
    let inf = &mut job.inference;
    if !inf.in_step() {
        let t = job.next;
        inf.begin_step(
            job.observations.step(Modality::Exteroceptive, 0, t),
            job.observations.step(Modality::Proprioceptive, 0, t),
        )
        .map_err(|e| e.to_string())?;
    }
    // Natively the synchronous calls, which run in the thread pool (a GPU's read-backs
    // wait in place there); in the browser the awaited ones (WebGPU's arrive through the
    // event loop; there is no pool).
    #[cfg(not(target_arch = "wasm32"))]
    let left = inf.iterate(CHUNK);
    #[cfg(target_arch = "wasm32")]
    let left = inf.iterate_async(CHUNK).await;
    let left = left.map_err(|e| e.to_string())?;
    if left > 0 {
        return Ok(None);
    }
    #[cfg(not(target_arch = "wasm32"))]
    let out = inf.finish_step();
    #[cfg(target_arch = "wasm32")]
    let out = inf.finish_step_async().await;
    let out = out.map_err(|e| e.to_string())?;
    let step = CompactStep::from_output(&out);
    if job.records_its_base() && job.history.steps.len() == job.next {
        job.history.steps.push(step.clone());
    }
    job.next += 1;
    Ok(Some(step))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::condition::Condition;
    use pvrnn_core::Tensor;
    use pvrnn_core::config::{ModuleConfig, VisionLayout};

    fn setup() -> (Arc<Model<f32>>, Arc<Observations<f32>>) {
        let mut config = ModelConfig::default();
        let m = |d, z| ModuleConfig {
            d,
            z,
            tau: [2.0, 4.0],
        };
        config.executive = m(6, 3);
        config.associative = m(6, 3);
        config.exteroceptive = m(8, 4);
        config.proprioceptive = m(6, 3);
        config.exteroceptive_readout.hidden = vec![8];
        config.proprioceptive_readout.hidden = vec![8];
        config.vision = VisionLayout {
            cameras: 1,
            channels: 3,
            resolutions: vec![4],
        };
        config.inference.iterations = 3;
        config.inference.window = 4;
        let model = Model::<f32>::init(config.clone(), 1, 9, 7).expect("model");
        let steps = 9;
        let ext = config.vision.dims();
        let extero: Vec<f32> = (0..steps * ext)
            .map(|i| ((i * 37) % 100) as f32 / 60.0 - 0.8)
            .collect();
        let proprio: Vec<f32> = (0..steps * config.proprio_dims)
            .map(|i| ((i * 11) % 50) as f32 / 40.0 - 0.6)
            .collect();
        let obs = Observations::new(
            Tensor::from_vec(&[1, steps, ext], extero).expect("extero"),
            Tensor::from_vec(&[1, steps, config.proprio_dims], proprio).expect("proprio"),
            None,
        )
        .expect("observations");
        (Arc::new(model), Arc::new(obs))
    }

    fn steps_of(events: &[Event], key: &RunKey) -> Vec<CompactStep> {
        events
            .iter()
            .filter_map(|e| match e {
                Event::Step(k, s) if k == key => Some((**s).clone()),
                _ => None,
            })
            .collect()
    }

    fn run_to_end(engine: &mut Engine) -> Vec<Event> {
        let mut events = Vec::new();
        while engine.running().is_some() {
            events.extend(engine.work(Duration::from_millis(50)));
        }
        events
    }

    #[test]
    fn a_paused_run_resumes_to_the_same_result() {
        let (model, obs) = setup();
        let standard = Condition::standard(&model.config);
        let a = RunKey::new("s", standard);
        let b = RunKey::new(
            "s",
            Condition {
                seed: 5,
                ..standard
            },
        );

        let mut engine = Engine::default();
        engine.set_model(model.clone());
        engine.add_observations("s".into(), obs.clone());
        engine.run(a.clone());
        let whole = run_to_end(&mut engine);
        assert_eq!(steps_of(&whole, &a).len(), 9);
        assert!(matches!(whole.last(), Some(Event::Done(f)) if f.key == a && f.steps == 9));

        // Interrupt a after a few steps, run b to the end, then resume a.
        let mut engine = Engine::default();
        engine.set_model(model);
        engine.add_observations("s".into(), obs);
        engine.run(a.clone());
        let mut events = Vec::new();
        while steps_of(&events, &a).len() < 3 {
            events.extend(engine.work(Duration::ZERO));
        }
        engine.run(b.clone());
        events.extend(run_to_end(&mut engine));
        engine.run(a.clone());
        events.extend(run_to_end(&mut engine));
        assert_eq!(
            steps_of(&events, &a),
            steps_of(&whole, &a),
            "resumed run differs"
        );
        assert_eq!(steps_of(&events, &b).len(), 9);
        assert_ne!(
            steps_of(&events, &b),
            steps_of(&whole, &a),
            "seed must matter"
        );
    }

    #[test]
    fn a_branch_shares_the_steps_before_it_whether_its_past_is_known_or_recomputed() {
        let (model, obs) = setup();
        let standard = Condition::standard(&model.config);
        let base = RunKey::new("s", standard);
        let blind = Condition {
            vision_levels: 0,
            ..standard
        };
        let branch = base.branched(5, blind);
        let fresh = || {
            let mut engine = Engine::default();
            engine.set_model(model.clone());
            engine.add_observations("s".into(), obs.clone());
            engine
        };
        // Recomputed: a fresh engine knows nothing of the base run.
        let mut engine = fresh();
        engine.run(branch.clone());
        let recomputed = steps_of(&run_to_end(&mut engine), &branch);
        // Known: the base run was computed here first.
        let mut engine = fresh();
        engine.run(base.clone());
        let whole = steps_of(&run_to_end(&mut engine), &base);
        engine.run(branch.clone());
        // The shared past arrives at once (one slice computes at most one step).
        let mut events = engine.work(Duration::ZERO);
        assert!(steps_of(&events, &branch).len() >= 5, "{events:?}");
        events.extend(run_to_end(&mut engine));
        let known = steps_of(&events, &branch);
        let Some(Event::Done(done)) = events.last() else {
            panic!("{events:?}")
        };
        assert_eq!(recomputed.len(), 9);
        assert_eq!(known, recomputed, "the two ways to a branch differ");
        assert_eq!(recomputed[..5], whole[..5], "the shared past differs");
        assert_ne!(
            recomputed[5], whole[5],
            "the branch's condition changed nothing"
        );
        assert_eq!(done.steps, 9);
        // A branch past the sequence's end is an error, not a run.
        let mut engine = fresh();
        let late = base.branched(9, blind);
        engine.run(late.clone());
        let events = engine.work(Duration::from_millis(10));
        assert!(
            matches!(&events[..], [Event::Failed(k, e)] if *k == late && e.contains("9 steps")),
            "{events:?}"
        );
    }

    #[test]
    fn steps_survive_the_flat_encoding() {
        let (model, obs) = setup();
        let key = RunKey::new("s", Condition::standard(&model.config));
        let layout = StepLayout::of(&model.config);
        let mut engine = Engine::default();
        engine.set_model(model);
        engine.add_observations("s".into(), obs);
        engine.run(key.clone());
        let steps = steps_of(&run_to_end(&mut engine), &key);
        for s in &steps {
            let flat = s.to_f32s();
            assert_eq!(flat.len(), layout.len());
            assert_eq!(&CompactStep::from_f32s(&flat, &layout).expect("decodes"), s);
        }
        let err = CompactStep::from_f32s(&steps[0].to_f32s()[1..], &layout).unwrap_err();
        assert!(err.contains("numbers"), "{err}");
    }

    #[test]
    fn missing_inputs_are_reported_not_panicked() {
        let (model, _) = setup();
        let key = RunKey::new("nowhere", Condition::standard(&model.config));
        let mut engine = Engine::default();
        engine.set_model(model);
        engine.run(key.clone());
        let events = engine.work(Duration::from_millis(10));
        assert!(
            matches!(&events[..], [Event::Failed(k, e)] if *k == key && e.contains("nowhere")),
            "{events:?}"
        );
        assert!(engine.running().is_none());
    }
}
