//! An episode's folder: `dataset.json` and the episode's sequence (a one-sequence dataset,
//! split test), `runs.safetensors` (the network's inference, as `pvrnn infer --compact`
//! writes it) and `drive.json` (the spec, the outcome beside the demonstration's, the
//! commands, and what the caller adds, such as the speed).

use std::path::Path;

use pvrnn_core::config::ModelConfig;
use pvrnn_core::io;
use pvrnn_dataset::Dataset;
use serde::Serialize;

use crate::drive::Episode;
use crate::spec::speed_limit_text;
use crate::{Error, Result};

/// The name of an episode's summary file.
pub const SUMMARY: &str = "drive.json";
/// The name of the network's run file.
pub const RUNS: &str = "runs.safetensors";

#[derive(Serialize)]
struct Summary<'a> {
    format: &'static str,
    trial: String,
    steps: usize,
    spec: &'a crate::spec::DriveSpec,
    speed_limit: &'static str,
    outcome: &'a caresim::outcome::Outcome,
    demonstration: &'a caresim::outcome::Outcome,
    commands: &'a [[f64; 14]],
    #[serde(flatten)]
    extra: serde_json::Value,
}

impl Episode {
    /// Writes the episode's folder (created if missing); `config` is the driving network's
    /// (for its run file), `extra` more fields for `drive.json` (an object).
    pub fn write(
        &self,
        dir: &Path,
        config: Option<&ModelConfig>,
        extra: serde_json::Value,
    ) -> Result<()> {
        let dataset = Dataset::new(
            &format!("caresim drive ({} controller)", self.spec.controller.name()),
            vec!["left".into(), "right".into()],
            caresim::IMAGE_SIZE,
            vec![self.sequence.clone()],
        )?;
        dataset.write(dir)?;
        if let (Some(run), Some(config)) = (&self.run, config) {
            io::save_runs(
                &dir.join(RUNS),
                config,
                std::slice::from_ref(run),
                &[0],
                Some(std::slice::from_ref(&self.sequence.info.name)),
            )?;
        }
        let summary = Summary {
            format: "pvrnn-drive/1",
            trial: self.trial.name(),
            steps: self.sequence.len(),
            spec: &self.spec,
            speed_limit: speed_limit_text(self.spec.speed_limit),
            outcome: &self.outcome,
            demonstration: &self.demonstration,
            commands: &self.commands,
            extra,
        };
        let json = serde_json::to_string_pretty(&summary)
            .map_err(|e| Error::Invalid(format!("drive.json: {e}")))?;
        let path = dir.join(SUMMARY);
        std::fs::write(&path, json + "\n").map_err(|source| {
            Error::Dataset(pvrnn_dataset::Error::Io {
                path: path.display().to_string(),
                source,
            })
        })
    }
}
