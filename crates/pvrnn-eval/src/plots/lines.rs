//! A chart of lines ([`Line`]) on a log-scaled y axis, with a legend: the error curves and
//! the training and validation curves.

use plotters::coord::Shift;
use plotters::prelude::*;

use super::canvas::{FONT, plot_err, tick};
use crate::Result;

/// One line of a chart.
pub(super) struct Line {
    pub(super) label: String,
    pub(super) colour: RGBColor,
    pub(super) dashed: bool,
    /// A dot at every point: sparse measurements (one validation is otherwise invisible).
    pub(super) markers: bool,
    pub(super) points: Vec<(f64, f64)>,
}

/// A chart of lines with a log-scaled y axis.
pub(super) fn line_chart(
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
