//! What a run is: a sequence (by name) under a condition of online inference. Shared by
//! the run store, the engines that compute runs, and the bundles that carry them.

use pvrnn_core::config::{ModelConfig, ModuleId};
use pvrnn_core::infer::InferenceSettings;
use pvrnn_core::{Ablation, AblationMode, NoiseMode, Observed};
use serde::{Deserialize, Serialize};

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

/// Which run: a sequence (by name) under a condition, and, for a branch, the condition it
/// continues under from a step on.
#[derive(Clone, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct RunKey {
    pub sequence: String,
    pub condition: Condition,
    /// A branch: the steps before `then.at` are the run under `condition`, the steps from
    /// it on are inferred under `then.condition`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub then: Option<Switch>,
}

/// Where a branch leaves its run, and the condition it continues under.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct Switch {
    pub at: u32,
    pub condition: Condition,
}

impl RunKey {
    pub fn new(sequence: impl Into<String>, condition: Condition) -> Self {
        Self {
            sequence: sequence.into(),
            condition,
            then: None,
        }
    }

    /// The run a branch leaves (the key itself when it is not a branch).
    pub fn base(&self) -> Self {
        Self {
            then: None,
            ..self.clone()
        }
    }

    /// The branch of this run at step `at` under `condition` (whose window is the run's:
    /// the state a branch continues from holds the run's window). A branch of a branch
    /// leaves the same base run.
    pub fn branched(&self, at: usize, condition: Condition) -> Self {
        Self {
            then: Some(Switch {
                at: at as u32,
                condition: Condition {
                    window: self.condition.window,
                    ..condition
                }
                .canonical(),
            }),
            ..self.base()
        }
    }

    /// The condition in force at step t.
    pub fn condition_at(&self, t: usize) -> &Condition {
        match &self.then {
            Some(s) if t >= s.at as usize => &s.condition,
            _ => &self.condition,
        }
    }
}
