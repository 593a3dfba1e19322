//! Inference runs as the explorer keeps them: per condition, compact (the states that
//! reproduce every prediction), computed live in slices so the interface never freezes,
//! and cached.

use std::collections::{HashMap, VecDeque};
use std::sync::Arc;

use pvrnn_core::config::{ModelConfig, ModuleId};
use pvrnn_core::cpu::readout;
use pvrnn_core::infer::{InferenceSettings, OnlineInference, Run, StepOutput};
use pvrnn_core::{Ablation, Modality, Model, NoiseMode, Observations, Observed};
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
    /// H.
    pub window: u16,
    pub iterations: u16,
    /// Inference learning rate in thousandths (an integer so conditions can be keys).
    pub lr_milli: u32,
    pub seed: u32,
}

impl Condition {
    /// The model's configured inference, everything observed, no ablation, seed 0.
    pub fn standard(config: &ModelConfig) -> Self {
        Self {
            vision_levels: config.vision.resolutions.len() as u8,
            proprio: true,
            ablation: [false; 4],
            window: config.inference.window as u16,
            iterations: config.inference.iterations as u16,
            lr_milli: (config.inference.optimizer.lr * 1000.0).round() as u32,
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
        s.window = (self.window as usize).max(1);
        s.iterations = self.iterations as usize;
        s.optimizer.lr = (self.lr_milli.max(1) as f64) / 1000.0;
        s
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
            window: settings.window as u16,
            iterations: settings.iterations as u16,
            lr_milli: (settings.optimizer.lr * 1000.0).round() as u32,
            seed,
        };
        (c.settings(config) == *settings).then_some(c)
    }

    /// The same condition with exactly one module ablated.
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
    }
}

/// One module's per-step states, row-major `[steps, width]`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ModuleTrace {
    pub mu_p: Vec<f32>,
    pub sigma_p: Vec<f32>,
    pub mu_q: Vec<f32>,
    pub sigma_q: Vec<f32>,
    pub d: Vec<f32>,
    pub prior_d: Vec<f32>,
}

/// A run in progress or complete: what the views need, growing step by step.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RunTrace {
    pub steps: usize,
    /// Latent and recurrent sizes per module.
    pub z: [usize; 4],
    pub d: [usize; 4],
    pub modules: [ModuleTrace; 4],
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

    pub fn push(&mut self, out: &StepOutput<f32>) {
        for (m, trace) in self.modules.iter_mut().enumerate() {
            let s = &out.modules[m];
            trace.mu_p.extend_from_slice(&s.mu_p);
            trace.sigma_p.extend_from_slice(&s.sigma_p);
            trace.mu_q.extend_from_slice(&s.mu_q);
            trace.sigma_q.extend_from_slice(&s.sigma_q);
            trace.d.extend_from_slice(&s.d);
            trace.prior_d.extend_from_slice(&out.prior_d[m]);
        }
        self.free_energy.push(out.window_free_energy.total as f32);
        self.recon_error.push(out.recon_error.map(|e| e as f32));
        self.proprio_recon.extend_from_slice(&out.recon[1]);
        self.proprio_prior.extend_from_slice(&out.prior_next[1]);
        self.steps += 1;
    }

    /// A stored (compact) run; proprioceptive predictions are re-read out from `d`.
    pub fn from_run(run: &Run<f32>, model: &Model<f32>) -> Self {
        let mut trace = Self::new(&model.config);
        let steps = run.steps();
        for (m, t) in trace.modules.iter_mut().enumerate() {
            let r = &run.modules[m];
            t.mu_p = r.mu_p.data().to_vec();
            t.sigma_p = r.sigma_p.data().to_vec();
            t.mu_q = r.mu_q.data().to_vec();
            t.sigma_q = r.sigma_q.data().to_vec();
            t.d = r.d.data().to_vec();
            t.prior_d = r.prior_d.data().to_vec();
        }
        trace.free_energy = run.free_energy.iter().map(|f| f.total as f32).collect();
        trace.recon_error = run.recon_error.iter().map(|e| e.map(|v| v as f32)).collect();
        let p = ModuleId::Proprioceptive.index();
        trace.proprio_recon = readout(&model.params, Modality::Proprioceptive, &trace.modules[p].d, steps);
        trace.proprio_prior = readout(&model.params, Modality::Proprioceptive, &trace.modules[p].prior_d, steps);
        trace.steps = steps;
        trace
    }

    /// One module's `d` at step t (or its prior-step d).
    pub fn d_at(&self, module: ModuleId, t: usize, prior: bool) -> &[f32] {
        let m = module.index();
        let w = self.d[m];
        let v = if prior { &self.modules[m].prior_d } else { &self.modules[m].d };
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
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct RunKey {
    pub sequence: String,
    pub condition: Condition,
}

/// Online inference of one sequence under one condition, advanced a slice at a time.
struct Job {
    key: RunKey,
    inference: OnlineInference<f32>,
    observations: Arc<Observations<f32>>,
    next: usize,
    /// Wall time spent computing (slices only, not the frames in between).
    busy: Duration,
    started: Instant,
}

/// A finished live run: how many steps, computing time, and wall time.
#[derive(Clone, Debug, PartialEq)]
pub struct Finished {
    pub key: RunKey,
    pub steps: usize,
    pub busy: Duration,
    pub wall: Duration,
}

/// Updates per slice before the clock is checked.
const CHUNK: usize = 5;

/// All runs: cached, being computed, or waiting.
#[derive(Default)]
pub struct RunStore {
    entries: HashMap<RunKey, Entry>,
    queue: VecDeque<RunKey>,
    job: Option<Job>,
    /// Jobs interrupted by a more urgent run, resumed when their turn comes again.
    paused: HashMap<RunKey, Job>,
    /// The run being looked at: it takes over from any other job.
    urgent: Option<RunKey>,
    /// Live runs finished since the last `take_finished`.
    finished: Vec<Finished>,
}

impl std::fmt::Debug for RunStore {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RunStore")
            .field("runs", &self.entries.len())
            .field("queued", &self.queue.len())
            .field("computing", &self.job.as_ref().map(|j| &j.key))
            .finish()
    }
}

impl RunStore {
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
        let running = self.job.as_ref().is_some_and(|j| j.key == key);
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
        self.job.is_none() && self.queue.is_empty() && self.paused.is_empty()
    }

    pub fn computing(&self) -> Option<&RunKey> {
        self.job.as_ref().map(|j| &j.key)
    }

    /// Steps done and total of the run being computed.
    pub fn progress(&self) -> Option<(usize, usize)> {
        self.job.as_ref().map(|j| (j.next, j.observations.lengths()[0]))
    }

    pub fn waiting(&self) -> usize {
        self.queue.len()
    }

    /// Live runs finished since last asked.
    pub fn take_finished(&mut self) -> Vec<Finished> {
        std::mem::take(&mut self.finished)
    }

    /// Forgets every run (a new model or dataset).
    pub fn clear(&mut self) {
        *self = Self::default();
    }

    /// Computes for about `budget`; `observations(name)` gives a sequence's inputs.
    /// Returns whether any work was done.
    pub fn work(
        &mut self,
        model: &Arc<Model<f32>>,
        budget: Duration,
        observations: &mut dyn FnMut(&str) -> Result<Arc<Observations<f32>>, String>,
    ) -> bool {
        let start = Instant::now();
        let mut worked = false;
        // The run being looked at takes over: pause whatever else is computing.
        if let (Some(urgent), Some(job)) = (&self.urgent, &self.job) {
            if job.key != *urgent {
                let job = self.job.take().expect("checked");
                self.queue.push_back(job.key.clone());
                self.paused.insert(job.key.clone(), job);
            }
        }
        while start.elapsed() < budget {
            if self.job.is_none() {
                let Some(key) = self.queue.pop_front() else { break };
                if let Some(job) = self.paused.remove(&key) {
                    self.job = Some(job);
                    continue;
                }
                match self.start(model, key.clone(), observations) {
                    Ok(job) => {
                        self.entries.insert(
                            key,
                            Entry {
                                trace: RunTrace::new(&model.config),
                                complete: false,
                                error: None,
                            },
                        );
                        self.job = Some(job);
                    }
                    Err(e) => {
                        self.entries.insert(
                            key,
                            Entry {
                                trace: RunTrace::new(&model.config),
                                complete: true,
                                error: Some(e),
                            },
                        );
                        continue;
                    }
                }
            }
            worked = true;
            let job = self.job.as_mut().expect("started above");
            let entry = self.entries.get_mut(&job.key).expect("inserted when started");
            let slice = Instant::now();
            let result = Self::advance(job, entry);
            job.busy += slice.elapsed();
            match result {
                Ok(true) => {
                    entry.complete = true;
                    if self.urgent.as_ref() == Some(&job.key) {
                        self.urgent = None;
                    }
                    self.finished.push(Finished {
                        key: job.key.clone(),
                        steps: job.next,
                        busy: job.busy,
                        wall: job.started.elapsed(),
                    });
                    self.job = None;
                }
                Ok(false) => {}
                Err(e) => {
                    entry.complete = true;
                    entry.error = Some(e);
                    self.job = None;
                }
            }
        }
        worked
    }

    fn start(
        &self,
        model: &Arc<Model<f32>>,
        key: RunKey,
        observations: &mut dyn FnMut(&str) -> Result<Arc<Observations<f32>>, String>,
    ) -> Result<Job, String> {
        let obs = observations(&key.sequence)?;
        let settings = key.condition.settings(&model.config);
        let inference = OnlineInference::new(model.clone(), settings).map_err(|e| e.to_string())?;
        Ok(Job {
            key,
            inference,
            observations: obs,
            next: 0,
            busy: Duration::ZERO,
            started: Instant::now(),
        })
    }

    /// A few updates of the job; `Ok(true)` when the sequence is done.
    fn advance(job: &mut Job, entry: &mut Entry) -> Result<bool, String> {
        let len = job.observations.lengths()[0];
        if job.next >= len {
            return Ok(true);
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
        if inf.iterate(CHUNK) == 0 {
            let out = inf.finish_step().map_err(|e| e.to_string())?;
            entry.trace.push(&out);
            job.next += 1;
        }
        Ok(job.next >= len)
    }
}
