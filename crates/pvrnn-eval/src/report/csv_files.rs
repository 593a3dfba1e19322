//! The report's CSV files: `per_sequence.csv` (every trial value) and `per_step.csv` (every
//! step's errors).

use super::figures::{TrialValue, applicable};
use crate::Result;
use crate::evaluate::{Evaluation, Series};
use crate::metrics::Sse;

fn csv_bytes(rows: impl FnOnce(&mut csv::Writer<Vec<u8>>) -> csv::Result<()>) -> Result<Vec<u8>> {
    let mut w = csv::Writer::from_writer(Vec::new());
    rows(&mut w)?;
    w.into_inner()
        .map_err(|e| crate::Error::Invalid(e.to_string()))
}

pub(super) fn per_sequence_csv(eval: &Evaluation, values: &[TrialValue]) -> Result<Vec<u8>> {
    csv_bytes(|w| {
        w.write_record([
            "sequence",
            "task",
            "bed_height_mm",
            "trial",
            "target",
            "source",
            "group",
            "observed",
            "pixels",
            "mse",
            "values",
        ])?;
        for v in values {
            let seq = &eval.sequences[v.sequence].meta;
            let group = &eval.groups[v.group];
            w.write_record([
                seq.name.clone(),
                seq.task.clone(),
                seq.bed_height_mm.map_or(String::new(), |h| h.to_string()),
                v.trial.map_or(String::new(), |t| t.to_string()),
                v.target.name().into(),
                v.source.name().into(),
                group.name.clone(),
                group.observed.to_string(),
                v.pixels.name().into(),
                format!("{:e}", v.mse),
                v.values.to_string(),
            ])?;
        }
        Ok(())
    })
}

pub(super) fn per_step_csv(eval: &Evaluation) -> Result<Vec<u8>> {
    csv_bytes(|w| {
        let mut header: Vec<String> = ["sequence", "trial", "source", "target", "t", "subtask"]
            .map(String::from)
            .to_vec();
        for g in &eval.groups {
            header.push(g.name.clone());
        }
        for g in eval.groups.iter().filter(|g| g.is_vision()) {
            header.push(format!("{}_changing", g.name));
        }
        w.write_record(&header)?;
        for seq in &eval.sequences {
            for series in &seq.series {
                write_series(w, eval, &seq.meta, series)?;
            }
        }
        Ok(())
    })
}

fn write_series(
    w: &mut csv::Writer<Vec<u8>>,
    eval: &Evaluation,
    meta: &crate::evaluate::SequenceMeta,
    series: &Series,
) -> csv::Result<()> {
    let mse = |s: Sse| s.mse().map_or(String::new(), |v| format!("{v:e}"));
    for (t, step) in series.steps.iter().enumerate() {
        let Some(e) = step else { continue };
        let subtask = meta
            .subtask
            .get(t)
            .and_then(|&i| meta.subtask_names.get(i as usize))
            .cloned()
            .unwrap_or_default();
        let mut row = vec![
            meta.name.clone(),
            series.trial.map_or(String::new(), |k| k.to_string()),
            series.source.name().into(),
            series.target.name().into(),
            t.to_string(),
            subtask,
        ];
        for (g, group) in eval.groups.iter().enumerate() {
            row.push(if applicable(series.source, series.target, group) {
                mse(e.all[g])
            } else {
                String::new()
            });
        }
        for (g, group) in eval
            .groups
            .iter()
            .enumerate()
            .filter(|(_, g)| g.is_vision())
        {
            row.push(if applicable(series.source, series.target, group) {
                mse(e.changing[g])
            } else {
                String::new()
            });
        }
        w.write_record(&row)?;
    }
    Ok(())
}
