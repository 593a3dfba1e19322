//! Everything that determines an inference run besides the model and the data
//! ([`InferenceSettings`]): the window, the updates and their optimiser, what is observed,
//! what is ablated and when, and the noise.

use serde::{Deserialize, Serialize};

use crate::config::{ModelConfig, RAdamConfig, validate_radam};
use crate::data::{Ablation, AblationMode, Observed};
use crate::error::{Error, Result};
use crate::noise::NoiseMode;

/// Everything that determines an inference run besides the model and the data.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct InferenceSettings {
    /// H.
    pub window: usize,
    pub iterations: usize,
    pub optimizer: RAdamConfig,
    pub reset_moments_each_step: bool,
    pub observed: Observed,
    pub ablation: Ablation,
    /// When the ablation applies; files written before the modes existed ablated during
    /// inference.
    #[serde(default = "AblationMode::legacy")]
    pub ablation_mode: AblationMode,
    pub noise: NoiseMode,
}

impl InferenceSettings {
    /// The model's configured defaults, everything observed, no ablation.
    pub fn from_config(config: &ModelConfig, seed: u64) -> Self {
        Self {
            window: config.inference.window,
            iterations: config.inference.iterations,
            optimizer: config.inference.optimizer.clone(),
            reset_moments_each_step: config.inference.reset_moments_each_step,
            observed: Observed::all(config),
            ablation: Ablation::none(),
            ablation_mode: AblationMode::default(),
            noise: NoiseMode::Sampled { seed },
        }
    }

    /// The same settings with the ablation mode reset when nothing is ablated (the mode
    /// then changes nothing), so equal runs compare equal.
    pub fn canonical(mut self) -> Self {
        self.ablation_mode = self.ablation.canonical_mode(self.ablation_mode);
        self
    }

    /// The ablation in force during the inference iterations.
    pub fn inference_ablation(&self) -> Ablation {
        match self.ablation_mode {
            AblationMode::Inference => self.ablation,
            AblationMode::Readout => Ablation::none(),
        }
    }

    /// The ablation applied only when the final pass is read out again.
    pub(super) fn readout_only_ablation(&self) -> Option<Ablation> {
        (self.ablation_mode == AblationMode::Readout && !self.ablation.is_none())
            .then_some(self.ablation)
    }

    pub fn validate(&self, config: &ModelConfig) -> Result<()> {
        if self.window == 0 {
            return Err(Error::InvalidArgument(
                "the inference window H must be at least 1".into(),
            ));
        }
        if self.observed.vision_levels > config.vision.resolutions.len() {
            return Err(Error::InvalidArgument(format!(
                "{} vision levels observed, but the model has {}",
                self.observed.vision_levels,
                config.vision.resolutions.len()
            )));
        }
        validate_radam("inference optimizer", &self.optimizer)
    }
}
