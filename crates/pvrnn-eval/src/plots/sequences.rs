//! Each evaluated sequence's errors over time: the top resolution's reconstruction and
//! prediction and proprioception's prediction beside their baselines, over the subtask bar
//! (`plots/error_<sequence>.png`), with its images beside them.

use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;

use super::canvas::{FONT, MEAN, MODEL, PREVIOUS, SUBTASK_COLOURS, UPSAMPLE, draw_png, plot_err};
use super::images::write_image_grid;
use super::lines::{Line, line_chart};
use crate::Result;
use crate::evaluate::{Evaluation, SequenceResult, Source, Target};
use crate::metrics::StepErrors;

/// Per-step MSE of `group` averaged over the series of `source` and `target` (over trials).
fn step_curve(
    seq: &SequenceResult,
    source: Source,
    target: Target,
    group: usize,
) -> Vec<(f64, f64)> {
    let chosen: Vec<&Vec<Option<StepErrors>>> = seq
        .series
        .iter()
        .filter(|s| s.source == source && s.target == target)
        .map(|s| &s.steps)
        .collect();
    let Some(first) = chosen.first() else {
        return Vec::new();
    };
    (0..first.len())
        .filter_map(|t| {
            let v: Vec<f64> = chosen
                .iter()
                .filter_map(|steps| steps[t].as_ref().and_then(|e| e.all[group].mse()))
                .collect();
            // A prediction of step t + 1 is drawn at t + 1.
            let at = if target == Target::Next { t + 1 } else { t } as f64;
            (!v.is_empty()).then(|| (at, v.iter().sum::<f64>() / v.len() as f64))
        })
        .collect()
}

/// The subtask bar under the charts, with the subtask names.
fn subtask_bar(area: &DrawingArea<BitMapBackend<'_>, Shift>, seq: &SequenceResult) -> Result<()> {
    let (w, _) = area.dim_in_pixel();
    let len = seq.meta.length.max(1);
    // The charts' plotting area starts after the y label area and margin.
    let (left, right) = (72i32, w as i32 - 8);
    let x = |t: usize| left + ((right - left) as f64 * t as f64 / len as f64) as i32;
    for t in 0..len {
        let label = seq.meta.subtask.get(t).copied().unwrap_or(0) as usize;
        let colour = SUBTASK_COLOURS[label % SUBTASK_COLOURS.len()];
        area.draw(&Rectangle::new(
            [(x(t), 4), (x(t + 1) + 1, 24)],
            colour.filled(),
        ))
        .map_err(plot_err)?;
    }
    let mut at = left;
    for (i, name) in seq.meta.subtask_names.iter().enumerate() {
        let colour = SUBTASK_COLOURS[i % SUBTASK_COLOURS.len()];
        area.draw(&Rectangle::new([(at, 32), (at + 14, 46)], colour.filled()))
            .map_err(plot_err)?;
        area.draw(&Text::new(name.clone(), (at + 18, 32), (FONT, 14)))
            .map_err(plot_err)?;
        at += 30 + 8 * name.len() as i32;
    }
    area.draw(&Text::new("subtask".to_string(), (4, 8), (FONT, 13)))
        .map_err(plot_err)?;
    Ok(())
}

/// One sequence's errors over time: the top resolution's reconstruction and prediction,
/// and proprioception's prediction, each beside its baselines, over the subtask bar.
fn error_chart(
    eval: &Evaluation,
    seq: &SequenceResult,
    path: &Path,
    top_g: usize,
    (joints, torques): (Option<usize>, Option<usize>),
) -> Result<()> {
    let top = &eval.groups[top_g].name;
    let x_max = seq.meta.length as f64;
    let top_observed = eval.groups[top_g].observed;
    let trials = eval.settings.trials - seq.failures.len();
    let failed = match seq.failures.len() {
        0 => String::new(),
        n => format!("; {n} diverged"),
    };
    let seen = if top_observed {
        "observed"
    } else {
        "not observed"
    };
    draw_png(path, (1100, 980), |root| {
        let (charts, bar) = root.split_vertically(920);
        let parts = charts.split_evenly((3, 1));
        line_chart(
            &parts[0],
            &format!(
                "{}: {top} reconstruction of x_t ({seen}, mean of {trials} trials{failed})",
                seq.meta.name
            ),
            "step",
            "MSE",
            x_max,
            &reconstruction_lines(seq, top_g, top_observed),
        )?;
        line_chart(
            &parts[1],
            &format!("{top} prediction of x_(t+1)"),
            "step",
            "MSE",
            x_max,
            &[
                step_line(
                    seq,
                    "model (prior)",
                    MODEL,
                    false,
                    Source::Model,
                    Target::Next,
                    top_g,
                ),
                step_line(
                    seq,
                    "previous frame",
                    PREVIOUS,
                    false,
                    Source::Previous,
                    Target::Next,
                    top_g,
                ),
                step_line(
                    seq,
                    "mean learning image",
                    MEAN,
                    true,
                    Source::Mean,
                    Target::Next,
                    top_g,
                ),
            ],
        )?;
        line_chart(
            &parts[2],
            "proprioception: prediction of x_(t+1)",
            "step",
            "MSE",
            x_max,
            &proprioception_lines(seq, joints, torques),
        )?;
        subtask_bar(&bar, seq)
    })?;
    Ok(())
}

/// One series of a sequence's per-step errors as a line.
fn step_line(
    seq: &SequenceResult,
    label: &str,
    colour: RGBColor,
    dashed: bool,
    source: Source,
    target: Target,
    g: usize,
) -> Line {
    Line {
        label: label.to_string(),
        colour,
        dashed,
        markers: false,
        points: step_curve(seq, source, target, g),
    }
}

/// The top resolution's reconstruction: the model, bilinear upsampling where that
/// resolution is not observed, the mean learning image.
fn reconstruction_lines(seq: &SequenceResult, top_g: usize, top_observed: bool) -> Vec<Line> {
    let mut lines = vec![
        step_line(
            seq,
            "model",
            MODEL,
            false,
            Source::Model,
            Target::Recon,
            top_g,
        ),
        step_line(
            seq,
            "mean learning image",
            MEAN,
            true,
            Source::Mean,
            Target::Recon,
            top_g,
        ),
    ];
    if !top_observed {
        let upsampling = step_line(
            seq,
            "bilinear upsampling",
            UPSAMPLE,
            false,
            Source::Upsample,
            Target::Recon,
            top_g,
        );
        lines.insert(1, upsampling);
    }
    lines
}

/// The one-step predictions of joints and torques (dashed), against the previous step.
fn proprioception_lines(
    seq: &SequenceResult,
    joints: Option<usize>,
    torques: Option<usize>,
) -> Vec<Line> {
    let mut lines = Vec::new();
    for (name, g) in [("joints", joints), ("torques", torques)] {
        if let Some(g) = g {
            let dashed = name == "torques";
            let model = format!("{name}: model");
            let previous = format!("{name}: previous step");
            lines.push(step_line(
                seq,
                &model,
                MODEL,
                dashed,
                Source::Model,
                Target::Next,
                g,
            ));
            lines.push(step_line(
                seq,
                &previous,
                PREVIOUS,
                dashed,
                Source::Previous,
                Target::Next,
                g,
            ));
        }
    }
    lines
}

/// `plots/error_<sequence>.png` and `plots/images_<sequence>.png` for every sequence.
pub fn write_plots(eval: &Evaluation, dir: &Path) -> Result<()> {
    let top_level = eval.resolutions.len() - 1;
    let group_index = |name: &str| eval.groups.iter().position(|g| g.name == name);
    let top = format!("v{}", eval.resolutions[top_level]);
    let top_g = group_index(&top).expect("the top level has a group");
    let (joints, torques) = (group_index("joints"), group_index("torques"));
    for seq in &eval.sequences {
        let stem = pvrnn_dataset::file_stem(&seq.meta.name);
        error_chart(
            eval,
            seq,
            &dir.join(format!("error_{stem}.png")),
            top_g,
            (joints, torques),
        )?;
        // Pictures come from the first trial that finished; none when every one diverged.
        if !seq.images.steps.is_empty() {
            write_image_grid(eval, seq, &dir.join(format!("images_{stem}.png")))?;
        }
    }
    Ok(())
}
