//! The condition of an inference run in a few exact, hashable fields ([`Condition`]): what
//! is observed, what is ablated and when, the window, updates, rate and noise seed. The
//! one condition type from the core to the command line and the explorer: each states
//! its condition as one, and [`Condition::settings`] gives the [`InferenceSettings`] it
//! means for a model.

use serde::{Deserialize, Serialize};

use crate::config::{ModelConfig, ModuleId};
use crate::data::{Ablation, AblationMode, Observed};
use crate::error::{Error, Result};
use crate::infer::InferenceSettings;
use crate::noise::NoiseMode;

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
        Self {
            ablation_mode: Ablation(self.ablation).canonical_mode(self.ablation_mode),
            ..self
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

    /// The condition given by the command line's words: vision `all`, `none` or the lowest
    /// resolutions (`16`, `32+16`); ablated modules (`none`, `executive,proprioceptive`);
    /// the ablation mode (`readout`, `inference`); the window, updates and rate where
    /// given (else the model's configuration); the noise seed.
    pub fn parse(
        config: &ModelConfig,
        vision: &str,
        proprio: bool,
        ablate: &str,
        ablation_mode: &str,
        (window, iterations, lr): (Option<usize>, Option<usize>, Option<f64>),
        seed: u64,
    ) -> Result<Self> {
        let narrow = |what: &str, value: usize| {
            u16::try_from(value)
                .map_err(|_| Error::InvalidArgument(format!("{what} {value} is more than 65535")))
        };
        let mut c = Self::standard(config);
        c.vision_levels = Observed::parse_vision(vision, config)? as u8;
        c.proprio = proprio;
        c.ablation = Ablation::parse(ablate)?.0;
        c.ablation_mode = AblationMode::parse(ablation_mode)?;
        if let Some(h) = window {
            if h == 0 {
                return Err(Error::InvalidArgument(
                    "the inference window H must be at least 1".into(),
                ));
            }
            c.window = narrow("the window", h)?;
        }
        if let Some(n) = iterations {
            c.iterations = narrow("the updates per step", n)?;
        }
        if let Some(lr) = lr {
            c.set_lr(lr);
        }
        c.seed = u32::try_from(seed).map_err(|_| {
            Error::InvalidArgument(format!("the noise seed {seed} is more than 4294967295"))
        })?;
        Ok(c.canonical())
    }

    pub fn without_ablation(&self) -> Self {
        Self {
            ablation: [false; 4],
            ..*self
        }
        .canonical()
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)] // test code: a failed unwrap is a failed test

    use super::*;

    #[test]
    fn the_command_lines_words_give_the_condition_and_its_settings() {
        let config = ModelConfig::default();
        let c = Condition::parse(
            &config,
            "16",
            false,
            "executive",
            "inference",
            (Some(20), None, Some(0.5)),
            7,
        )
        .unwrap();
        assert_eq!(
            (c.vision_levels, c.proprio, c.window, c.seed),
            (1, false, 20, 7)
        );
        assert_eq!(c.ablation, [true, false, false, false]);
        assert_eq!(c.iterations as usize, config.inference.iterations);
        let settings = c.settings(&config);
        assert_eq!(settings.optimizer.lr, 0.5);
        assert_eq!(settings.ablation_mode, AblationMode::Inference);
        // The settings name the condition back.
        assert_eq!(Condition::of(&settings, &config), Some(c));
        // Nothing ablated: the mode is the default, so one run has one key.
        let plain = Condition::parse(
            &config,
            "all",
            true,
            "none",
            "inference",
            (None, None, None),
            0,
        )
        .unwrap();
        assert_eq!(plain, Condition::standard(&config));
    }

    #[test]
    fn words_out_of_range_are_errors_that_say_so() {
        let config = ModelConfig::default();
        let parse = |vision: &str, ablate: &str, window: Option<usize>, seed: u64| {
            Condition::parse(
                &config,
                vision,
                true,
                ablate,
                "readout",
                (window, None, None),
                seed,
            )
            .unwrap_err()
            .to_string()
        };
        assert!(parse("all", "none", Some(0), 0).contains("at least 1"));
        assert!(parse("all", "none", Some(70_000), 0).contains("more than 65535"));
        assert!(parse("all", "none", None, 1 << 33).contains("seed"));
        assert!(parse("all", "cortex", None, 0).contains("cortex"));
        assert!(parse("8", "none", None, 0).contains('8'));
    }
}
