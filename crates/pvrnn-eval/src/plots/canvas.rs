//! What every figure shares: the embedded font (pictures look the same on every machine),
//! the colours, drawing into a white PNG or SVG canvas and writing it, and axis ticks.

use std::path::Path;
use std::sync::Once;

use image::{ImageFormat, RgbImage};
use plotters::coord::Shift;
use plotters::prelude::*;

use crate::report::sig;
use crate::{Error, Result, write_file};

pub(super) const FONT: &str = "sans-serif";
pub(super) const MODEL: RGBColor = RGBColor(31, 119, 180);
pub(super) const UPSAMPLE: RGBColor = RGBColor(255, 127, 14);
pub(super) const PREVIOUS: RGBColor = RGBColor(44, 160, 44);
pub(super) const MEAN: RGBColor = RGBColor(127, 127, 127);
pub(super) const SUBTASK_COLOURS: [RGBColor; 6] = [
    RGBColor(141, 211, 199),
    RGBColor(255, 255, 179),
    RGBColor(190, 186, 218),
    RGBColor(251, 128, 114),
    RGBColor(128, 177, 211),
    RGBColor(253, 180, 98),
];

pub(super) fn ensure_font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        plotters::style::register_font(FONT, FontStyle::Normal, epaint_default_fonts::HACK_REGULAR)
            .unwrap_or_else(|_| panic!("the embedded font parses"));
    });
}

pub(super) fn plot_err(e: impl std::fmt::Display) -> Error {
    Error::Invalid(format!("drawing a plot: {e}"))
}

/// Draws into a `width x height` white picture and writes it as PNG.
pub(super) fn draw_png(
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

pub(super) fn png(path: &Path, image: RgbImage) -> Result<()> {
    let mut bytes = std::io::Cursor::new(Vec::new());
    image
        .write_to(&mut bytes, ImageFormat::Png)
        .map_err(|e| Error::Invalid(format!("{}: cannot encode PNG: {e}", path.display())))?;
    write_file(path, &bytes.into_inner())
}

/// An axis tick: four significant digits without trailing zeros (`2000`, `10`, `0.015`).
pub(super) fn tick(v: f64) -> String {
    let text = sig(v);
    if text.contains('.') {
        text.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        text
    }
}

/// Draws into a `width x height` white SVG picture and writes it.
pub(super) fn draw_svg(
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

/// Writes an RGB picture (`width x height`, 8-bit, row-major) as PNG.
pub fn write_png(path: &Path, width: u32, height: u32, rgb: Vec<u8>) -> Result<()> {
    let image = RgbImage::from_raw(width, height, rgb)
        .ok_or_else(|| Error::Invalid(format!("{}: picture of the wrong size", path.display())))?;
    png(path, image)
}
