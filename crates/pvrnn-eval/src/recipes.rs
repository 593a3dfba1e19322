//! The recipe search's table (`pvrnn report recipes`): per recipe, the checkpoint chosen on
//! held-out validation sequences and its validation errors, built from the files the search
//! leaves in each recipe's folder, so the published table is regenerated rather than typed.
//!
//! A recipe folder may hold:
//! - `run.validation.csv` (`pvrnn train --validate`): its best row is the chosen checkpoint,
//!   with the 16x16 + proprioception error and the diverged trials;
//! - `run.log.csv`: the training's wall time up to that checkpoint;
//! - `val-16/summary.json`: a `pvrnn evaluate` of the chosen checkpoint on the validation
//!   sequences with 16x16 + proprioception observed (replaces the log's figures: a recipe
//!   that only changes inference, e.g. its learning rate, has no training of its own);
//! - `val-all/summary.json`: the same with everything observed;
//! - `machine.txt`: where it ran, one line (otherwise the machines the validation log names).

use std::fmt::Write as _;
use std::path::Path;

use pvrnn_dataset::card::thousands;

use crate::progress::Summary;
use crate::report::sig;
use crate::training_log;
use crate::validation::{self, ValidationRow};
use crate::{Error, Result};

/// One validation condition's headline: the model's error of the unobserved (or, with
/// everything observed, observed) top resolution and the trials that diverged.
#[derive(Clone, Debug, PartialEq)]
pub struct Scored {
    /// Mean squared error of the top resolution's reconstruction over the finished trials.
    pub error: f64,
    /// Bilinear upsampling's error on the same sequences, where the condition has it.
    pub upsample: Option<f64>,
    pub failed_trials: usize,
    pub trials: usize,
}

/// One row of the table.
#[derive(Clone, Debug, PartialEq)]
pub struct RecipeRow {
    pub name: String,
    /// The chosen checkpoint's training iteration.
    pub iteration: Option<u64>,
    /// The last validated iteration (how far the run went).
    pub last_validated: Option<u64>,
    pub vision16: Option<Scored>,
    pub all: Option<Scored>,
    /// Training wall time to the chosen checkpoint, seconds.
    pub seconds: Option<f64>,
    pub machine: Option<String>,
    /// Every validation of the run: (iteration, error, diverged trials).
    pub curve: Vec<(u64, f64, usize)>,
}

fn read(path: &Path) -> Result<Option<String>> {
    match std::fs::read_to_string(path) {
        Ok(text) => Ok(Some(text)),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(Error::File {
            path: path.display().to_string(),
            detail: e.to_string(),
        }),
    }
}

/// The headline of a `pvrnn evaluate` summary and its model's iteration.
fn scored_summary(path: &Path) -> Result<Option<(Scored, Option<u64>)>> {
    let Some(text) = read(path)? else {
        return Ok(None);
    };
    let what = path.display().to_string();
    let summary = Summary::parse(&text, &what)?;
    let row = crate::progress::read_summary(&text, &what).ok();
    let top = summary
        .top_group()
        .ok_or_else(|| summary.bad("no vision groups"))?;
    let error = summary
        .figure("recon", &top, "model", "all")
        .map(|f| f.0)
        .ok_or_else(|| summary.bad(&format!("no model figure for {top}")))?;
    Ok(Some((
        Scored {
            error,
            upsample: summary
                .figure("recon", &top, "upsample", "all")
                .map(|f| f.0),
            failed_trials: row.as_ref().map_or(0, |r| r.failed_trials),
            trials: row.as_ref().map_or(0, |r| r.total_trials),
        },
        row.map(|r| r.iteration),
    )))
}

/// Reads one recipe folder (see the module's documentation).
pub fn read_recipe(name: &str, dir: &Path) -> Result<RecipeRow> {
    let log = dir.join("run.validation.csv");
    let rows: Vec<ValidationRow> = validation::read_log(&log)?;
    let best = validation::best(&rows);
    let mut row = RecipeRow {
        name: name.to_string(),
        iteration: best.map(|b| b.iteration),
        last_validated: rows.last().map(|r| r.iteration),
        vision16: best.map(|b| Scored {
            error: b.recon_vision_top,
            upsample: b.upsample,
            failed_trials: b.failed_trials,
            trials: b.trials,
        }),
        all: None,
        seconds: None,
        curve: rows
            .iter()
            .map(|r| (r.iteration, r.recon_vision_top, r.failed_trials))
            .collect(),
        machine: match read(&dir.join("machine.txt"))? {
            Some(m) => Some(m.trim().to_string()),
            None => machines(&rows, best.map(|b| b.iteration)),
        },
    };
    if let Some((scored, iteration)) = scored_summary(&dir.join("val-16/summary.json"))? {
        row.vision16 = Some(scored);
        row.iteration = row.iteration.or(iteration);
    }
    if let Some((scored, iteration)) = scored_summary(&dir.join("val-all/summary.json"))? {
        row.all = Some(scored);
        row.iteration = row.iteration.or(iteration);
    }
    row.seconds = row
        .iteration
        .and_then(|i| training_log::seconds_at(&dir.join("run.log.csv"), i));
    if row.vision16.is_none() && row.all.is_none() {
        return Err(Error::File {
            path: dir.display().to_string(),
            detail: "no run.validation.csv, val-16/summary.json or val-all/summary.json in it"
                .into(),
        });
    }
    Ok(row)
}

/// The machines the validation log names up to the chosen iteration, in order of first
/// appearance (a run resumed elsewhere names several).
fn machines(rows: &[ValidationRow], upto: Option<u64>) -> Option<String> {
    let mut seen: Vec<&str> = Vec::new();
    for r in rows
        .iter()
        .filter(|r| upto.is_none_or(|u| r.iteration <= u))
    {
        if let Some(m) = r.machine.as_deref()
            && !seen.contains(&m)
        {
            seen.push(m);
        }
    }
    (!seen.is_empty()).then(|| seen.join("; "))
}

/// The table: a row per recipe, the best 16x16 + proprioception error in bold; then, where
/// runs were validated, their errors at equal iterations (a recipe that is ahead only
/// because it trained longer shows here).
pub fn markdown(rows: &[RecipeRow]) -> String {
    let mut md = chosen_table(rows);
    let curves: Vec<&RecipeRow> = rows.iter().filter(|r| !r.curve.is_empty()).collect();
    if curves.is_empty() {
        return md;
    }
    let mut iterations: Vec<u64> = curves
        .iter()
        .flat_map(|r| r.curve.iter().map(|c| c.0))
        .collect();
    iterations.sort_unstable();
    iterations.dedup();
    md.push_str("\nThe 64x64 error from 16x16 + proprioception at every validated iteration:\n\n| iteration |");
    for r in &curves {
        let _ = write!(md, " {} |", r.name);
    }
    md.push_str("\n|---|");
    md.push_str(&"---|".repeat(curves.len()));
    for it in iterations {
        let _ = write!(md, "\n| {} |", thousands(it));
        for r in &curves {
            let cell = match r.curve.iter().find(|c| c.0 == it) {
                Some((_, e, 0)) => sig(*e),
                Some((_, e, failed)) => format!("{} ({failed} diverged)", sig(*e)),
                None => String::new(),
            };
            let _ = write!(md, " {cell} |");
        }
    }
    md.push('\n');
    md
}

fn chosen_table(rows: &[RecipeRow]) -> String {
    let best = rows
        .iter()
        .filter_map(|r| r.vision16.as_ref())
        .filter(|s| s.failed_trials == 0)
        .map(|s| s.error)
        .fold(f64::INFINITY, f64::min);
    let mut md = String::from(
        "| recipe | chosen iteration (validated to) | 64x64 from 16x16 + proprio (x upsampling) | 64x64, everything observed | diverged trials (16 / all) | training to the chosen iteration | where |\n|---|---|---|---|---|---|---|\n",
    );
    let dash = || "—".to_string();
    for r in rows {
        let v16 = r.vision16.as_ref().map_or_else(dash, |s| {
            let text = match s.upsample {
                Some(u) => format!("{} (x{:.2})", sig(s.error), s.error / u),
                None => sig(s.error),
            };
            if s.error == best {
                format!("**{text}**")
            } else {
                text
            }
        });
        let all = r.all.as_ref().map_or_else(dash, |s| sig(s.error));
        let diverged = |s: &Option<Scored>| {
            s.as_ref()
                .map_or_else(dash, |s| format!("{} of {}", s.failed_trials, s.trials))
        };
        let _ = writeln!(
            md,
            "| {} | {}{} | {v16} | {all} | {} / {} | {} | {} |",
            r.name,
            r.iteration.map_or_else(dash, thousands),
            r.last_validated
                .map_or_else(String::new, |l| format!(" ({})", thousands(l))),
            diverged(&r.vision16),
            diverged(&r.all),
            r.seconds
                .map_or_else(dash, |s| format!("{:.1} h", s / 3600.0)),
            r.machine.clone().unwrap_or_else(dash),
        );
    }
    md
}

#[cfg(test)]
mod tests {
    use super::*;

    fn validation_row(iteration: u64, error: f64) -> ValidationRow {
        ValidationRow {
            iteration,
            failed_trials: 0,
            trials: 24,
            recon_vision_top: error,
            recon_joints: None,
            recon_torques: None,
            seconds: 60.0,
            upsample: Some(0.0094),
            upsample_detail: None,
            mean: None,
            machine: Some("AMD EPYC (AVX2), 2 cores, 1 thread".into()),
            ..Default::default()
        }
    }

    #[test]
    fn a_run_folder_gives_its_best_checkpoint_and_the_time_to_it() {
        let dir = tempfile::tempdir().unwrap();
        let run = dir.path().join("paper");
        std::fs::create_dir_all(&run).unwrap();
        validation::write_log(
            &run.join("run.validation.csv"),
            &[
                validation_row(2000, 0.0068),
                validation_row(4000, 0.0063),
                validation_row(6000, 0.0065),
            ],
        )
        .unwrap();
        let mut log = String::from(training_log::HEADER);
        for it in 0..6000u64 {
            let _ = write!(log, "\n{it},1,1,1,1,1,1,1,{}", (it + 1) as f64 * 0.5);
        }
        std::fs::write(run.join("run.log.csv"), log).unwrap();
        // Where it ran comes from the validation log, unless machine.txt says otherwise.
        let row = read_recipe("paper", &run).unwrap();
        assert_eq!(
            row.machine.as_deref(),
            Some("AMD EPYC (AVX2), 2 cores, 1 thread")
        );
        std::fs::write(run.join("machine.txt"), "AMD EPYC, 1 thread\n").unwrap();
        let row = read_recipe("paper", &run).unwrap();
        assert_eq!(row.iteration, Some(4000));
        assert_eq!(row.last_validated, Some(6000));
        assert_eq!(row.seconds, Some(2000.0));
        assert_eq!(row.vision16.as_ref().unwrap().error, 0.0063);
        assert!(row.all.is_none());
        let md = markdown(&[row]);
        assert!(
            md.contains("| paper | 4,000 (6,000) | **0.006300 (x0.67)** | — | 0 of 24 / — | 0.6 h | AMD EPYC, 1 thread |"),
            "{md}"
        );
        assert!(
            md.contains("| iteration | paper |\n|---|---|\n| 2,000 | 0.006800 |\n| 4,000 | 0.006300 |\n| 6,000 | 0.006500 |\n"),
            "{md}"
        );
        let e = read_recipe("empty", dir.path()).unwrap_err().to_string();
        assert!(e.contains("no run.validation.csv"), "{e}");
    }
}
