//! Early stopping: a training run scored on held-out sequences as it goes, so that the
//! checkpoint that generalises best can be kept (the caresim campaign's network overfits
//! its 18 learning sequences from 10,000 iterations on; docs/results).
//!
//! One validation is `pvrnn evaluate` on every sequence of the held-out dataset under the
//! paper's Fig. 5 question: the lowest vision resolution and proprioception observed, one
//! noise trial (seed 0). Its score is the reconstruction error of the highest (unobserved)
//! resolution; a trial whose inference diverges beyond repair counts against the
//! checkpoint before any error does. Each validation also records the baselines of the
//! validity gate ([`crate::gate`]): whether the network beats what needs no learning.

use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use pvrnn_core::backend::Backend;
use pvrnn_core::infer::InferenceSettings;
use pvrnn_core::{Model, Observed};
use pvrnn_dataset::{Dataset, Selection};
use serde::{Deserialize, Serialize};

use crate::evaluate::{EvalSettings, Source, Target, evaluate};
use crate::report::{Pixels, figures, trial_values};
use crate::{Error, Result, write_file};

/// One validation of a training run (a row of `<run>.validation.csv`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ValidationRow {
    pub iteration: u64,
    /// Trials whose online inference diverged beyond repair (left out of the errors).
    pub failed_trials: usize,
    pub trials: usize,
    /// Mean squared reconstruction error of the highest vision resolution (not observed),
    /// over the finished trials; infinite when none finished.
    pub recon_vision_top: f64,
    /// The same for the observed joint angles and torques (absent without them).
    pub recon_joints: Option<f64>,
    pub recon_torques: Option<f64>,
    /// Wall-clock seconds the validation took.
    pub seconds: f64,
    /// The baselines' errors on the same finished sequences (the same for every row while
    /// no trial diverges): bilinear upsampling, upsampling plus the mean image's detail,
    /// the mean learning image. Absent in logs written before they were recorded.
    #[serde(default)]
    pub upsample: Option<f64>,
    #[serde(default)]
    pub upsample_detail: Option<f64>,
    #[serde(default)]
    pub mean: Option<f64>,
    /// Where it ran (`machine::describe`): the training between two validations ran there
    /// too. Absent in older logs.
    #[serde(default)]
    pub machine: Option<String>,
    /// The validity gate's other baselines (docs/experiments.md, "The validity gate"),
    /// absent in logs written before 2026-12-06. Vision: the nearest learning frame (the
    /// held-out dataset's learning frame whose observed inputs are closest, never the
    /// sequence's own).
    #[serde(default)]
    pub nearest: Option<f64>,
    /// Proprioception: the model's one-step prediction of the joint angles and torques, the
    /// previous value's and the mean learning input's errors for it.
    #[serde(default)]
    pub next_joints: Option<f64>,
    #[serde(default)]
    pub next_torques: Option<f64>,
    #[serde(default)]
    pub previous_joints: Option<f64>,
    #[serde(default)]
    pub previous_torques: Option<f64>,
    #[serde(default)]
    pub mean_joints: Option<f64>,
    #[serde(default)]
    pub mean_torques: Option<f64>,
}

impl ValidationRow {
    /// Fewer diverged trials first, then the lower vision error.
    pub fn better_than(&self, other: &ValidationRow) -> bool {
        (self.failed_trials, self.recon_vision_top) < (other.failed_trials, other.recon_vision_top)
    }
}

/// The best row of `rows` (the first of equals), if any.
pub fn best(rows: &[ValidationRow]) -> Option<&ValidationRow> {
    rows.iter()
        .fold(None, |best: Option<&ValidationRow>, row| match best {
            Some(b) if !row.better_than(b) => Some(b),
            _ => Some(row),
        })
}

/// Early stopping's rule: the best row, when `patience` validations have come after it
/// without beating it (the run has turned; training on only overfits further).
pub fn stalled(rows: &[ValidationRow], patience: usize) -> Option<&ValidationRow> {
    let best = best(rows)?;
    let after = rows.iter().filter(|r| r.iteration > best.iteration).count();
    (patience > 0 && after >= patience).then_some(best)
}

/// Scores `model` (at training `iteration`) on every sequence of `dataset`.
pub fn validate(
    model: Arc<Model<f32>>,
    backend: &dyn Backend<f32>,
    dataset: &Dataset,
    iteration: u64,
) -> Result<ValidationRow> {
    let started = Instant::now();
    let config = &model.config;
    let mut inference = InferenceSettings::from_config(config, 0);
    inference.observed = Observed {
        vision_levels: 1,
        proprio: true,
    };
    let settings = EvalSettings {
        inference,
        trials: 1,
        change_threshold: 8.0,
        image_columns: 1,
        nearest_neighbour: true,
    };
    let eval = evaluate(model, backend, dataset, &Selection::All, &settings, &|| {})?;
    let figures = figures(&eval, &trial_values(&eval));
    let figure_of = |target: Target, source: Source, group: &str| {
        figures
            .iter()
            .find(|f| {
                f.scope == "all"
                    && f.target == target
                    && f.source == source
                    && f.group == group
                    && f.pixels == Pixels::All
            })
            .map(|f| f.mean)
    };
    let figure = |source: Source, group: &str| figure_of(Target::Recon, source, group);
    let next = |source: Source, group: &str| figure_of(Target::Next, source, group);
    let recon = |group: &str| figure(Source::Model, group);
    let top = format!("v{}", eval.resolutions.last().copied().unwrap_or(0));
    Ok(ValidationRow {
        iteration,
        failed_trials: eval.sequences.iter().map(|s| s.failures.len()).sum(),
        trials: eval.sequences.len(),
        recon_vision_top: recon(&top).unwrap_or(f64::INFINITY),
        recon_joints: recon("joints"),
        recon_torques: recon("torques"),
        seconds: started.elapsed().as_secs_f64(),
        upsample: figure(Source::Upsample, &top),
        upsample_detail: figure(Source::UpsampleDetail, &top),
        mean: figure(Source::Mean, &top),
        machine: Some(crate::machine::here()),
        nearest: figure(Source::Nearest, &top),
        next_joints: next(Source::Model, "joints"),
        next_torques: next(Source::Model, "torques"),
        previous_joints: next(Source::Previous, "joints"),
        previous_torques: next(Source::Previous, "torques"),
        mean_joints: next(Source::Mean, "joints"),
        mean_torques: next(Source::Mean, "torques"),
    })
}

/// Reads a validation log; a missing file is an empty log.
pub fn read_log(path: &Path) -> Result<Vec<ValidationRow>> {
    if !path.exists() {
        return Ok(Vec::new());
    }
    let bad = |e: csv::Error| Error::File {
        path: path.display().to_string(),
        detail: format!("not a validation log: {e}"),
    };
    csv::Reader::from_path(path)
        .map_err(bad)?
        .deserialize()
        .collect::<std::result::Result<_, _>>()
        .map_err(bad)
}

/// Writes a validation log (atomically: it is small and rewritten whole).
pub fn write_log(path: &Path, rows: &[ValidationRow]) -> Result<()> {
    let mut w = csv::Writer::from_writer(Vec::new());
    for row in rows {
        w.serialize(row)?;
    }
    let bytes = w.into_inner().map_err(|e| Error::File {
        path: path.display().to_string(),
        detail: e.to_string(),
    })?;
    write_file(path, &bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(iteration: u64, failed_trials: usize, error: f64) -> ValidationRow {
        ValidationRow {
            iteration,
            failed_trials,
            trials: 4,
            recon_vision_top: error,
            recon_joints: (failed_trials < 4).then_some(0.5),
            recon_torques: None,
            seconds: 1.5,
            upsample: Some(0.009),
            upsample_detail: None,
            mean: Some(0.015),
            machine: Some("AMD EPYC (AVX2), 2 cores, 1 thread".into()),
            ..Default::default()
        }
    }

    #[test]
    fn fewer_diverged_trials_win_before_a_lower_error() {
        let rows = [
            row(10, 1, 0.001),
            row(20, 0, 0.009),
            row(30, 0, 0.004),
            row(40, 0, 0.004),
            row(50, 4, f64::INFINITY),
        ];
        assert_eq!(best(&rows).unwrap().iteration, 30);
        assert!(row(1, 0, 0.5).better_than(&row(2, 1, 0.1)));
        assert!(!row(1, 4, f64::INFINITY).better_than(&row(2, 3, 0.1)));
        assert!(best(&[]).is_none());
        // Patience 2: stop once two validations after the best (30) did not beat it.
        assert!(stalled(&rows[..4], 2).is_none());
        assert_eq!(stalled(&rows, 2).map(|r| r.iteration), Some(30));
        assert!(stalled(&rows, 3).is_none() && stalled(&rows, 0).is_none());
        assert!(stalled(&[], 1).is_none());
    }

    #[test]
    fn the_log_round_trips_and_names_a_bad_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run.validation.csv");
        assert!(read_log(&path).unwrap().is_empty());
        let rows = vec![row(10, 0, 0.004), row(20, 4, f64::INFINITY)];
        write_log(&path, &rows).unwrap();
        assert_eq!(read_log(&path).unwrap(), rows);
        // A log written before the baselines were recorded still reads.
        std::fs::write(
            &path,
            "iteration,failed_trials,trials,recon_vision_top,recon_joints,recon_torques,seconds\n\
             2000,0,24,0.0068,0.017,0.024,110.2\n",
        )
        .unwrap();
        let old = read_log(&path).unwrap();
        assert_eq!((old[0].iteration, old[0].upsample), (2000, None));
        std::fs::write(&path, "iteration,failed_trials\nten,0\n").unwrap();
        let e = read_log(&path).unwrap_err().to_string();
        assert!(
            e.contains("run.validation.csv") && e.contains("not a validation log"),
            "{e}"
        );
    }
}
