//! PNG pictures: each sequence's error over time with its subtask bar, actual vs predicted
//! images, and training curves; bar charts also as SVG. Text uses an embedded font, so
//! pictures look the same on every machine.

use std::path::Path;
use std::sync::Once;

use image::{ImageFormat, RgbImage};
use plotters::coord::Shift;
use plotters::prelude::*;
use pvrnn_core::config::Normalisation;

use crate::evaluate::{Evaluation, SequenceResult, Source, Target};
use crate::metrics::StepErrors;
use crate::report::sig;
use crate::{Error, Result, write_file};

const FONT: &str = "sans-serif";
const MODEL: RGBColor = RGBColor(31, 119, 180);
const UPSAMPLE: RGBColor = RGBColor(255, 127, 14);
const PREVIOUS: RGBColor = RGBColor(44, 160, 44);
const MEAN: RGBColor = RGBColor(127, 127, 127);
const SUBTASK_COLOURS: [RGBColor; 6] = [
    RGBColor(141, 211, 199),
    RGBColor(255, 255, 179),
    RGBColor(190, 186, 218),
    RGBColor(251, 128, 114),
    RGBColor(128, 177, 211),
    RGBColor(253, 180, 98),
];

fn ensure_font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        plotters::style::register_font(FONT, FontStyle::Normal, epaint_default_fonts::HACK_REGULAR)
            .unwrap_or_else(|_| panic!("the embedded font parses"));
    });
}

fn plot_err(e: impl std::fmt::Display) -> Error {
    Error::Invalid(format!("drawing a plot: {e}"))
}

/// Draws into a `width x height` white picture and writes it as PNG.
fn draw_png(
    path: &Path,
    (width, height): (u32, u32),
    draw: impl FnOnce(&DrawingArea<BitMapBackend<'_>, Shift>) -> Result<()>,
) -> Result<()> {
    ensure_font();
    let mut buf = vec![255u8; (width * height * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (width, height)).into_drawing_area();
        draw(&root)?;
        root.present().map_err(plot_err)?;
    }
    png(
        path,
        RgbImage::from_raw(width, height, buf).expect("buffer of the right size"),
    )
}

fn png(path: &Path, image: RgbImage) -> Result<()> {
    let mut bytes = std::io::Cursor::new(Vec::new());
    image
        .write_to(&mut bytes, ImageFormat::Png)
        .map_err(|e| Error::Invalid(format!("{}: cannot encode PNG: {e}", path.display())))?;
    write_file(path, &bytes.into_inner())
}

/// An axis tick: four significant digits without trailing zeros (`2000`, `10`, `0.015`).
fn tick(v: f64) -> String {
    let text = sig(v);
    if text.contains('.') {
        text.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        text
    }
}

/// One line of a chart.
struct Line {
    label: String,
    colour: RGBColor,
    dashed: bool,
    /// A dot at every point: sparse measurements (one validation is otherwise invisible).
    markers: bool,
    points: Vec<(f64, f64)>,
}

/// A chart of lines with a log-scaled y axis.
fn line_chart(
    area: &DrawingArea<BitMapBackend<'_>, Shift>,
    title: &str,
    x_label: &str,
    y_label: &str,
    x_max: f64,
    lines: &[Line],
) -> Result<()> {
    let positive = lines
        .iter()
        .flat_map(|l| l.points.iter().map(|p| p.1))
        .filter(|v| *v > 0.0 && v.is_finite());
    let (lo, hi) = positive.fold((f64::MAX, f64::MIN), |(a, b), v| (a.min(v), b.max(v)));
    let (lo, hi) = if lo > hi {
        (1e-4, 1.0)
    } else {
        (lo / 1.5, hi * 1.5)
    };
    let mut chart = ChartBuilder::on(area)
        .caption(title, (FONT, 18))
        .margin(8)
        // Room for the last x tick's label (e.g. 100000), centred on the right edge.
        .margin_right(28)
        .x_label_area_size(32)
        .y_label_area_size(64)
        .build_cartesian_2d(0f64..x_max.max(1.0), (lo..hi).log_scale())
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .x_desc(x_label)
        .y_desc(y_label)
        .label_style((FONT, 13))
        .x_label_formatter(&|v| tick(*v))
        .y_label_formatter(&|v| tick(*v))
        .draw()
        .map_err(plot_err)?;
    for line in lines {
        let colour = line.colour;
        if line.markers {
            let dots = line
                .points
                .iter()
                .map(|&(x, y)| Circle::new((x, y.max(lo)), 4, colour.filled()));
            chart.draw_series(dots).map_err(plot_err)?;
        }
        let points = line.points.iter().map(|&(x, y)| (x, y.max(lo)));
        let series = if line.dashed {
            chart.draw_series(DashedLineSeries::new(points, 6, 4, colour.stroke_width(2)))
        } else {
            chart.draw_series(LineSeries::new(points, colour.stroke_width(2)))
        }
        .map_err(plot_err)?;
        series
            .label(line.label.clone())
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 18, y)], colour.stroke_width(3)));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font((FONT, 13))
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(plot_err)?;
    Ok(())
}

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

/// Rows: actual, reconstruction, prediction made one step earlier, upsampling baseline
/// (when there is one); columns: evenly spaced steps; the first camera at the top resolution.
fn write_image_grid(eval: &Evaluation, seq: &SequenceResult, path: &Path) -> Result<()> {
    let images = &seq.images;
    let level = eval.resolutions.len() - 1;
    let r = eval.resolutions[level];
    let layout = pvrnn_core::config::VisionLayout {
        cameras: eval.cameras.len(),
        channels: 3,
        resolutions: eval.resolutions.clone(),
    };
    let offset = layout.image_offset(level, 0);
    let scale = (128 / r).max(1) as u32;
    let cell = r as u32 * scale;
    let (label_w, head_h, gap) = (150u32, 24u32, 4u32);
    let mut rows: Vec<(&str, Vec<Option<&[f32]>>)> = vec![
        (
            "actual",
            images.actual.iter().map(|v| Some(v.as_slice())).collect(),
        ),
        (
            "reconstruction",
            images.recon.iter().map(|v| Some(v.as_slice())).collect(),
        ),
        (
            "prediction (t-1)",
            images.predicted.iter().map(|v| v.as_deref()).collect(),
        ),
    ];
    if images.upsampled.iter().any(Option::is_some) {
        rows.push((
            "bilinear upsampling",
            images.upsampled.iter().map(|v| v.as_deref()).collect(),
        ));
    }
    let cols = images.steps.len() as u32;
    let width = label_w + cols * (cell + gap);
    let height = head_h + rows.len() as u32 * (cell + gap) + 22;
    let mut picture = RgbImage::from_pixel(width, height, image::Rgb([255, 255, 255]));
    for (row, (_, cells)) in rows.iter().enumerate() {
        for (col, v) in cells.iter().enumerate() {
            let Some(v) = v else { continue };
            let (x0, y0) = (
                label_w + col as u32 * (cell + gap),
                head_h + row as u32 * (cell + gap),
            );
            for y in 0..cell {
                for x in 0..cell {
                    let p = offset + (((y / scale) as usize) * r + (x / scale) as usize) * 3;
                    let rgb = [0, 1, 2].map(|c| Normalisation::vision_from_model(v[p + c] as f64));
                    picture.put_pixel(x0 + x, y0 + y, image::Rgb(rgb));
                }
            }
        }
    }
    ensure_font();
    let mut buf = picture.into_raw();
    {
        let root = BitMapBackend::with_buffer(&mut buf, (width, height)).into_drawing_area();
        for (row, (name, _)) in rows.iter().enumerate() {
            let y = (head_h + row as u32 * (cell + gap) + cell / 2) as i32 - 8;
            root.draw(&Text::new(name.to_string(), (6, y), (FONT, 15)))
                .map_err(plot_err)?;
        }
        for (col, t) in images.steps.iter().enumerate() {
            let x = (label_w + col as u32 * (cell + gap)) as i32 + 4;
            root.draw(&Text::new(format!("t = {t}"), (x, 4), (FONT, 14)))
                .map_err(plot_err)?;
        }
        let note = format!(
            "{} ({}), camera {}, {}x{}; trial {}",
            seq.meta.name,
            crate::report::Condition::of(eval).label(),
            eval.cameras.first().map_or("0", |c| c.as_str()),
            r,
            r,
            images.trial
        );
        root.draw(&Text::new(note, (6, height as i32 - 20), (FONT, 13)))
            .map_err(plot_err)?;
        root.present().map_err(plot_err)?;
    }
    png(
        path,
        RgbImage::from_raw(width, height, buf).expect("buffer of the right size"),
    )
}

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

/// One bar of [`bar_chart`]: a mean and its standard error (whiskers), if known.
#[derive(Clone, Debug)]
pub struct Bar {
    pub label: String,
    pub mean: f64,
    pub se: Option<f64>,
}

/// Bars in groups (e.g. one group per module, one bar per task) with ±SE whiskers; a linear
/// y axis from 0. `series` names the bars of each group in order (the legend). Written as
/// PNG to `path` and as SVG beside it (same name, `.svg`: scalable, for papers).
pub fn bar_chart(
    path: &Path,
    title: &str,
    y_label: &str,
    series: &[String],
    groups: &[(String, Vec<Bar>)],
) -> Result<()> {
    let per_group = groups.iter().map(|g| g.1.len()).max().unwrap_or(0).max(1);
    let width = (160 + groups.len() * (per_group * 44 + 40)).clamp(480, 1600) as u32;
    let size = (width, 420);
    draw_png(path, size, |root| {
        draw_bars(root, title, y_label, series, groups)
    })?;
    draw_svg(&path.with_extension("svg"), size, |root| {
        draw_bars(root, title, y_label, series, groups)
    })
}

/// Draws into a `width x height` white SVG picture and writes it.
fn draw_svg(
    path: &Path,
    (width, height): (u32, u32),
    draw: impl FnOnce(&DrawingArea<SVGBackend<'_>, Shift>) -> Result<()>,
) -> Result<()> {
    ensure_font();
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (width, height)).into_drawing_area();
        root.fill(&WHITE).map_err(plot_err)?;
        draw(&root)?;
        root.present().map_err(plot_err)?;
    }
    write_file(path, svg.as_bytes())
}

fn draw_bars<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    title: &str,
    y_label: &str,
    series: &[String],
    groups: &[(String, Vec<Bar>)],
) -> Result<()> {
    const COLOURS: [RGBColor; 6] = [
        MODEL,
        UPSAMPLE,
        PREVIOUS,
        MEAN,
        SUBTASK_COLOURS[3],
        SUBTASK_COLOURS[4],
    ];
    let per_group = groups.iter().map(|g| g.1.len()).max().unwrap_or(0).max(1);
    let top = groups
        .iter()
        .flat_map(|g| g.1.iter().map(|b| b.mean + b.se.unwrap_or(0.0)))
        .filter(|v| v.is_finite())
        .fold(0.0f64, f64::max);
    let top = if top > 0.0 { top * 1.15 } else { 1.0 };
    {
        let mut chart = ChartBuilder::on(root)
            .caption(title, (FONT, 17))
            .margin(10)
            .x_label_area_size(34)
            .y_label_area_size(70)
            .build_cartesian_2d(0f64..groups.len().max(1) as f64, 0f64..top)
            .map_err(plot_err)?;
        chart
            .configure_mesh()
            .disable_x_mesh()
            .x_labels(groups.len().max(1) * 2 + 1)
            .x_label_formatter(&|x| {
                let i = (*x - 0.5).round();
                if (x - 0.5 - i).abs() < 1e-6 && i >= 0.0 {
                    groups
                        .get(i as usize)
                        .map_or(String::new(), |g| g.0.clone())
                } else {
                    String::new()
                }
            })
            .y_desc(y_label)
            .label_style((FONT, 13))
            .y_label_formatter(&|v| tick(*v))
            .draw()
            .map_err(plot_err)?;
        let slot = 0.8 / per_group as f64;
        for (k, name) in series.iter().enumerate().take(per_group) {
            let colour = COLOURS[k % COLOURS.len()];
            let mut rects = Vec::new();
            let mut whiskers = Vec::new();
            for (g, (_, bars)) in groups.iter().enumerate() {
                let Some(bar) = bars.get(k) else { continue };
                if !bar.mean.is_finite() {
                    continue;
                }
                let x0 = g as f64 + 0.1 + k as f64 * slot;
                rects.push(Rectangle::new(
                    [(x0, 0.0), (x0 + slot * 0.9, bar.mean)],
                    colour.filled(),
                ));
                if let Some(se) = bar.se.filter(|s| s.is_finite()) {
                    let xm = x0 + slot * 0.45;
                    whiskers.push(PathElement::new(
                        [(xm, (bar.mean - se).max(0.0)), (xm, bar.mean + se)],
                        BLACK.stroke_width(2),
                    ));
                }
            }
            chart
                .draw_series(rects)
                .map_err(plot_err)?
                .label(name.clone())
                .legend(move |(x, y)| {
                    Rectangle::new([(x, y - 5), (x + 14, y + 5)], colour.filled())
                });
            chart.draw_series(whiskers).map_err(plot_err)?;
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font((FONT, 13))
            .position(SeriesLabelPosition::UpperRight)
            .draw()
            .map_err(plot_err)?;
    }
    Ok(())
}

/// Writes an RGB picture (`width x height`, 8-bit, row-major) as PNG.
pub fn write_png(path: &Path, width: u32, height: u32, rgb: Vec<u8>) -> Result<()> {
    let image = RgbImage::from_raw(width, height, rgb)
        .ok_or_else(|| Error::Invalid(format!("{}: picture of the wrong size", path.display())))?;
    png(path, image)
}

/// A grid of grey maps with a label on every row and column: `cells[row][column]` is a
/// `side x side` map, drawn on one scale (white = the grid's largest value), `title` above.
pub fn labelled_maps(
    path: &Path,
    title: &str,
    rows: &[String],
    columns: &[String],
    cells: &[Vec<Vec<f64>>],
    side: usize,
) -> Result<()> {
    let scale = 2u32;
    let cell = side as u32 * scale;
    let (label_w, head_h, gap) = (150u32, 52u32, 6u32);
    // Wide enough for the title (about 7.7 px per character at 14 px).
    let width =
        (label_w + columns.len() as u32 * (cell + gap)).max(title.chars().count() as u32 * 8 + 12);
    let height = head_h + rows.len() as u32 * (cell + gap) + 4;
    let max = cells
        .iter()
        .flatten()
        .flatten()
        .fold(0.0f64, |a, b| a.max(*b))
        .max(1e-12);
    draw_png(path, (width, height), |root| {
        root.draw(&Text::new(title.to_string(), (6, 4), (FONT, 14)))
            .map_err(plot_err)?;
        for (c, label) in columns.iter().enumerate() {
            let x = (label_w + c as u32 * (cell + gap)) as i32;
            root.draw(&Text::new(label.clone(), (x, 28), (FONT, 12)))
                .map_err(plot_err)?;
        }
        for (r, label) in rows.iter().enumerate() {
            let y0 = head_h + r as u32 * (cell + gap);
            root.draw(&Text::new(
                label.clone(),
                (6, (y0 + cell / 2) as i32 - 7),
                (FONT, 13),
            ))
            .map_err(plot_err)?;
            for (c, map) in cells.get(r).into_iter().flatten().enumerate() {
                let x0 = label_w + c as u32 * (cell + gap);
                for y in 0..cell {
                    for x in 0..cell {
                        let i = (y / scale) as usize * side + (x / scale) as usize;
                        let v = map.get(i).copied().unwrap_or(0.0) / max;
                        let level = (255.0 * v.clamp(0.0, 1.0)) as u8;
                        root.draw_pixel(
                            ((x0 + x) as i32, (y0 + y) as i32),
                            &RGBColor(level, level, level),
                        )
                        .map_err(plot_err)?;
                    }
                }
            }
        }
        Ok(())
    })
}
