//! The inference condition flags `infer` and `evaluate` share.

use anyhow::Result;
use pvrnn_core::infer::{Condition, InferenceSettings};
use pvrnn_core::{ModelConfig, NoiseMode};

use crate::util;

#[derive(clap::Args, Debug, Clone)]
pub struct ConditionArgs {
    /// Vision observed: all, none, or the lowest resolutions, e.g. 16 or 32+16.
    #[arg(long, default_value = "all")]
    pub vision: String,
    /// Proprioception observed: on or off.
    #[arg(long, default_value = "on", value_parser = util::on_off, action = clap::ArgAction::Set)]
    pub proprio: bool,
    /// Modules whose z is set to 0 (comma-separated: executive, associative, exteroceptive, proprioceptive).
    #[arg(long, default_value = "none")]
    pub ablate: String,
    /// When --ablate applies: `readout` (inference runs as standard, then each step's final
    /// pass is read out again with z = 0: the paper's contribution maps) or `inference`
    /// (z = 0 during every inference iteration, so other modules may compensate).
    #[arg(long, default_value = "readout", value_parser = ["readout", "inference"])]
    pub ablation_mode: String,
    /// Window length H (default: the model's configuration, 30).
    #[arg(long)]
    pub window: Option<usize>,
    /// Updates per step (default: the model's configuration, 50).
    #[arg(long)]
    pub iterations: Option<usize>,
    /// Learning rate of the window's adaptive variables (default: the model's configuration, 1.0).
    #[arg(long)]
    pub lr: Option<f64>,
    /// Seed of the noise draws (0 to 4294967295).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// No noise: z = mu (eps = 0) instead of a seeded sample (for debugging).
    #[arg(long)]
    pub zero_noise: bool,
}

impl ConditionArgs {
    /// The condition these flags state for a model (the core's one condition type).
    pub fn condition(&self, config: &ModelConfig) -> Result<Condition> {
        Ok(Condition::parse(
            config,
            &self.vision,
            self.proprio,
            &self.ablate,
            &self.ablation_mode,
            (self.window, self.iterations, self.lr),
            self.seed,
        )?)
    }

    /// The inference settings these flags give for a model.
    pub fn settings(&self, config: &ModelConfig) -> Result<InferenceSettings> {
        let mut settings = self.condition(config)?.settings(config);
        if self.zero_noise {
            settings.noise = NoiseMode::Zero;
        }
        settings.validate(config)?;
        Ok(settings.canonical())
    }
}
