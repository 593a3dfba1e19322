//! Each evaluated sequence's actual vs predicted images (`plots/images_<sequence>.png`):
//! the actual frame, the reconstruction, the prediction made a step earlier and the
//! upsampling baseline, at evenly spaced steps.

use std::path::Path;

use image::RgbImage;
use plotters::prelude::*;
use pvrnn_core::config::Normalisation;

use super::canvas::{FONT, ensure_font, plot_err, png};
use crate::Result;
use crate::evaluate::{Evaluation, SequenceResult};

/// Rows: actual, reconstruction, prediction made one step earlier, upsampling baseline
/// (when there is one); columns: evenly spaced steps; the first camera at the top resolution.
pub(super) fn write_image_grid(eval: &Evaluation, seq: &SequenceResult, path: &Path) -> Result<()> {
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
