//! Training curves: every free-energy term of a training log against the iteration, and
//! validation runs' held-out error against the iteration beside the baselines.

use std::path::Path;

use plotters::prelude::*;

use super::canvas::{MEAN, MODEL, PREVIOUS, UPSAMPLE, draw_png};
use super::lines::{Line, line_chart};
use crate::report::sig;
use crate::{Error, Result};

/// Learning curves from a training log (`pvrnn train`'s `<out>.log.csv`): every
/// free-energy term against the iteration, log-scaled, averaged in bins of iterations.
pub fn training_curves(log: &str, title: &str, path: &Path) -> Result<()> {
    let mut lines = log.lines();
    let header: Vec<&str> = lines
        .next()
        .ok_or_else(|| Error::Invalid("the training log is empty".into()))?
        .split(',')
        .collect();
    let column = |name: &str| {
        header
            .iter()
            .position(|h| *h == name)
            .ok_or_else(|| Error::Invalid(format!("the training log has no `{name}` column")))
    };
    let iteration = column("iteration")?;
    let terms = [
        ("total", MODEL),
        ("accuracy_exteroceptive", UPSAMPLE),
        ("accuracy_proprioceptive", PREVIOUS),
        ("complexity_executive", RGBColor(214, 39, 40)),
        ("complexity_associative", RGBColor(148, 103, 189)),
        ("complexity_exteroceptive", RGBColor(140, 86, 75)),
        ("complexity_proprioceptive", RGBColor(227, 119, 194)),
    ];
    let columns: Vec<usize> = terms
        .iter()
        .map(|(n, _)| column(n))
        .collect::<Result<_>>()?;
    let mut rows: Vec<(f64, Vec<f64>)> = Vec::new();
    for (i, line) in lines.enumerate() {
        let f: Vec<&str> = line.split(',').collect();
        let num = |c: usize| -> Result<f64> {
            f.get(c).and_then(|v| v.parse().ok()).ok_or_else(|| {
                Error::Invalid(format!(
                    "training log line {}: not a number in column {}",
                    i + 2,
                    c + 1
                ))
            })
        };
        rows.push((
            num(iteration)?,
            columns.iter().map(|&c| num(c)).collect::<Result<_>>()?,
        ));
    }
    if rows.is_empty() {
        return Err(Error::Invalid("the training log has no rows".into()));
    }
    let bins = 600.min(rows.len());
    let per_bin = rows.len().div_ceil(bins);
    let binned: Vec<(f64, Vec<f64>)> = rows
        .chunks(per_bin)
        .map(|chunk| {
            let n = chunk.len() as f64;
            let it = chunk.iter().map(|r| r.0).sum::<f64>() / n;
            let values = (0..terms.len())
                .map(|k| chunk.iter().map(|r| r.1[k]).sum::<f64>() / n)
                .collect();
            (it, values)
        })
        .collect();
    let x_max = rows.last().map_or(1.0, |r| r.0 + 1.0);
    let lines: Vec<Line> = terms
        .iter()
        .enumerate()
        .map(|(k, (name, colour))| Line {
            label: name.to_string(),
            colour: *colour,
            dashed: name.starts_with("complexity"),
            markers: false,
            points: binned.iter().map(|(it, v)| (*it, v[k])).collect(),
        })
        .collect();
    draw_png(path, (1100, 600), |root| {
        line_chart(
            root,
            title,
            "iteration",
            "summed over sequences and steps (complexity before W)",
            x_max,
            &lines,
        )
    })
}

/// Validation curves (`pvrnn train --validate`'s logs): each run's held-out error of the
/// unobserved top resolution against the iteration, its best point marked in the legend,
/// and the first run's baselines as dashed levels.
pub fn validation_curves(
    runs: &[(String, Vec<crate::validation::ValidationRow>)],
    title: &str,
    path: &Path,
) -> Result<()> {
    const RUNS: [RGBColor; 6] = [
        MODEL,
        RGBColor(214, 39, 40),
        RGBColor(148, 103, 189),
        RGBColor(140, 86, 75),
        RGBColor(227, 119, 194),
        RGBColor(23, 190, 207),
    ];
    let x_max = runs
        .iter()
        .flat_map(|(_, rows)| rows.iter().map(|r| r.iteration as f64))
        .fold(1.0, f64::max);
    let mut lines: Vec<Line> = runs
        .iter()
        .enumerate()
        .map(|(k, (name, rows))| {
            let best = crate::validation::best(rows);
            Line {
                label: match best {
                    Some(b) => format!(
                        "{name} (best {} at {}{})",
                        sig(b.recon_vision_top),
                        b.iteration,
                        if b.failed_trials > 0 {
                            format!(", {} diverged", b.failed_trials)
                        } else {
                            String::new()
                        }
                    ),
                    None => name.clone(),
                },
                colour: RUNS[k % RUNS.len()],
                dashed: false,
                markers: true,
                // A validation whose every trial diverged has no error to draw.
                points: rows
                    .iter()
                    .filter(|r| r.recon_vision_top.is_finite())
                    .map(|r| (r.iteration as f64, r.recon_vision_top))
                    .collect(),
            }
        })
        .collect();
    if let Some((_, rows)) = runs.first() {
        let level =
            |get: fn(&crate::validation::ValidationRow) -> Option<f64>| rows.iter().find_map(get);
        for (name, value, colour) in [
            ("upsampling", level(|r| r.upsample), UPSAMPLE),
            (
                "upsampling + mean detail",
                level(|r| r.upsample_detail),
                PREVIOUS,
            ),
            ("mean image", level(|r| r.mean), MEAN),
        ] {
            if let Some(v) = value {
                lines.push(Line {
                    label: format!("{name} ({})", sig(v)),
                    colour,
                    dashed: true,
                    markers: false,
                    points: vec![(0.0, v), (x_max, v)],
                });
            }
        }
    }
    draw_png(path, (1100, 600), |root| {
        line_chart(
            root,
            title,
            "iteration",
            "mean squared error (model units)",
            x_max,
            &lines,
        )
    })
}
