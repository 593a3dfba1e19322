//! Bar charts: bars in groups with ±SE whiskers on a linear axis from 0, written as PNG and
//! as SVG beside it.

use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;

use super::canvas::{
    FONT, MEAN, MODEL, PREVIOUS, SUBTASK_COLOURS, UPSAMPLE, draw_png, draw_svg, plot_err, tick,
};
use crate::Result;

/// One bar of [`bar_chart`]: a mean and its standard error (whiskers), if known.
#[derive(Clone, Debug)]
pub struct Bar {
    pub label: String,
    pub mean: f64,
    pub se: Option<f64>,
    /// Whiskers from `low` to `high` instead of ±SE (an asymmetric interval, e.g. a
    /// proportion's Wilson interval).
    pub interval: Option<(f64, f64)>,
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
    // Wide enough for the bars and for the longest group label (about 8 px a character).
    let label = groups
        .iter()
        .map(|g| g.0.chars().count())
        .max()
        .unwrap_or(0)
        * 8
        + 12;
    let width = (160 + groups.len() * (per_group * 44 + 40).max(label)).clamp(480, 1600) as u32;
    let size = (width, 420);
    draw_png(path, size, |root| {
        draw_bars(root, title, y_label, series, groups)
    })?;
    draw_svg(&path.with_extension("svg"), size, |root| {
        draw_bars(root, title, y_label, series, groups)
    })
}

/// A bar's whisker: its interval, or ±SE; `None` if neither is known and finite.
fn whisker(bar: &Bar) -> Option<(f64, f64)> {
    bar.interval
        .or_else(|| bar.se.map(|se| (bar.mean - se, bar.mean + se)))
        .filter(|(low, high)| low.is_finite() && high.is_finite())
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
        .flat_map(|g| g.1.iter().map(|b| whisker(b).map_or(b.mean, |w| w.1)))
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
                if let Some((low, high)) = whisker(bar) {
                    let xm = x0 + slot * 0.45;
                    whiskers.push(PathElement::new(
                        [(xm, low.max(0.0)), (xm, high)],
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
