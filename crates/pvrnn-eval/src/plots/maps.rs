//! A grid of grey maps with a label on every row and column, on one scale.

use std::path::Path;

use plotters::prelude::*;

use super::canvas::{FONT, draw_png, plot_err};
use crate::Result;

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
