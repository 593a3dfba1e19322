//! The training log, one CSV row per iteration beside the checkpoint (`run.safetensors` ->
//! `run.log.csv`): the free energy's terms and the run's wall time. Written by `pvrnn train`
//! and by the experiments' trainings alike; read by the training-curve plots, the model card
//! and the experiment reports.

use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use pvrnn_core::FreeEnergy;

use crate::{Error, Result};

/// The columns. `seconds`: wall time of the run so far, summed over resumed runs.
pub const HEADER: &str = "iteration,total,accuracy_exteroceptive,accuracy_proprioceptive,complexity_executive,complexity_associative,complexity_exteroceptive,complexity_proprioceptive,seconds";

/// The log beside a checkpoint.
pub fn path_for(checkpoint: &Path) -> PathBuf {
    checkpoint.with_extension("log.csv")
}

fn file_err(path: &Path, e: std::io::Error) -> Error {
    Error::File {
        path: path.display().to_string(),
        detail: e.to_string(),
    }
}

/// An open log that rows are appended to.
#[derive(Debug)]
pub struct TrainingLog {
    file: File,
    path: PathBuf,
    seconds_before: f64,
    start: Instant,
}

impl TrainingLog {
    /// Opens the log of a run that continues at `iteration`: keeps the rows of earlier
    /// iterations (later rows were not checkpointed, and will be run again), and continues
    /// the clock from the last kept row.
    pub fn resume(path: &Path, iteration: u64) -> Result<Self> {
        let mut kept = String::from(HEADER);
        kept.push('\n');
        let mut seconds_before = 0.0;
        if let Ok(text) = std::fs::read_to_string(path) {
            for line in text.lines().skip(1) {
                let it: Option<u64> = line.split(',').next().and_then(|s| s.parse().ok());
                if it.is_some_and(|i| i < iteration) {
                    kept.push_str(line);
                    kept.push('\n');
                    seconds_before = line
                        .rsplit(',')
                        .next()
                        .and_then(|s| s.parse().ok())
                        .unwrap_or(seconds_before);
                }
            }
        }
        crate::write_file(path, kept.as_bytes())?;
        let file = std::fs::OpenOptions::new()
            .append(true)
            .open(path)
            .map_err(|e| file_err(path, e))?;
        Ok(Self {
            file,
            path: path.to_path_buf(),
            seconds_before,
            start: Instant::now(),
        })
    }

    /// Wall time of the run so far, over all its resumptions (s).
    pub fn seconds(&self) -> f64 {
        self.seconds_before + self.start.elapsed().as_secs_f64()
    }

    /// The row of `iteration` (the iteration the report's step started at).
    pub fn append(&mut self, iteration: u64, report: &FreeEnergy) -> Result<()> {
        let seconds = self.seconds();
        writeln!(
            self.file,
            "{iteration},{},{},{},{},{},{},{},{seconds:.3}",
            report.total,
            report.accuracy.exteroceptive,
            report.accuracy.proprioceptive,
            report.complexity.executive,
            report.complexity.associative,
            report.complexity.exteroceptive,
            report.complexity.proprioceptive,
        )
        .map_err(|e| file_err(&self.path, e))
    }

    /// Writes buffered rows (with every checkpoint, so the log covers what it covers).
    pub fn flush(&mut self) -> Result<()> {
        self.file.flush().map_err(|e| file_err(&self.path, e))
    }
}

/// The free energy per iteration of a log, for iterations before `iterations`; empty when
/// the log is missing. Reads the first two columns, so older three-column logs
/// (`iteration,total,seconds`) read too.
pub fn totals(path: &Path, iterations: u64) -> Vec<f64> {
    let Ok(text) = std::fs::read_to_string(path) else {
        return Vec::new();
    };
    text.lines()
        .skip(1)
        .filter_map(|line| {
            let mut fields = line.split(',');
            let it: u64 = fields.next()?.parse().ok()?;
            let total: f64 = fields.next()?.parse().ok()?;
            (it < iterations).then_some(total)
        })
        .collect()
}

/// The last row's wall time (s), if any.
pub fn seconds(path: &Path) -> Option<f64> {
    let text = std::fs::read_to_string(path).ok()?;
    text.lines()
        .skip(1)
        .last()
        .and_then(|l| l.rsplit(',').next()?.parse().ok())
}

/// The wall time (s) a run had taken when it reached `iteration` (the row of iteration
/// `iteration - 1`, the last one before that checkpoint), if the log has it.
pub fn seconds_at(path: &Path, iteration: u64) -> Option<f64> {
    let text = std::fs::read_to_string(path).ok()?;
    text.lines().skip(1).find_map(|line| {
        let it: u64 = line.split(',').next()?.parse().ok()?;
        (it + 1 == iteration)
            .then(|| line.rsplit(',').next()?.parse().ok())
            .flatten()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resuming_drops_rows_past_the_checkpoint_and_keeps_the_clock() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run.log.csv");
        let report = FreeEnergy {
            total: 2.5,
            ..FreeEnergy::default()
        };
        let mut log = TrainingLog::resume(&path, 0).unwrap();
        for it in 0..4 {
            log.append(it, &report).unwrap();
        }
        log.flush().unwrap();
        drop(log);
        // Fake a longer first run: rows 0-3 at 10 s each.
        let text = std::fs::read_to_string(&path).unwrap();
        let rows: Vec<String> = text
            .lines()
            .enumerate()
            .map(|(i, l)| {
                if i == 0 {
                    l.to_string()
                } else {
                    let (head, _) = l.rsplit_once(',').unwrap();
                    format!("{head},{}.000", 10 * i)
                }
            })
            .collect();
        std::fs::write(&path, rows.join("\n") + "\n").unwrap();
        // The checkpoint was at iteration 2: rows 2 and 3 go, the clock resumes at 20 s.
        let mut log = TrainingLog::resume(&path, 2).unwrap();
        assert!(log.seconds() >= 20.0 && log.seconds() < 21.0);
        log.append(2, &report).unwrap();
        log.flush().unwrap();
        assert_eq!(totals(&path, 10), vec![2.5, 2.5, 2.5]);
        assert_eq!(totals(&path, 1), vec![2.5]);
        assert!(seconds(&path).unwrap() >= 20.0);
        // Iteration 2 was reached after row 1 (20 s); nothing logged reaches 5.
        assert_eq!(seconds_at(&path, 2), Some(20.0));
        assert_eq!(seconds_at(&path, 5), None);
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.starts_with(HEADER));
        assert_eq!(text.lines().count(), 4);
        assert!(totals(&dir.path().join("missing.csv"), 10).is_empty());
    }
}
