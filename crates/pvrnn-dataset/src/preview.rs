//! Pictures of a sequence for a person to look at: a contact sheet (PNG) of evenly spaced
//! frames of every camera with a subtask colour bar, and an animation (GIF).

use std::path::Path;

use image::codecs::gif::{GifEncoder, Repeat};
use image::{Delay, Frame, Rgb, RgbImage, RgbaImage};

use crate::{Result, Sequence, format_err, io_err};

/// Colours of the subtask bar (cycled).
const SUBTASK_COLOURS: [[u8; 3]; 4] = [[66, 133, 244], [244, 160, 0], [15, 157, 88], [219, 68, 55]];

/// Copies one camera frame into `img` at (x, y), magnified `scale` times.
fn blit(img: &mut RgbImage, frame: &[u8], size: usize, x: u32, y: u32, scale: u32) {
    for py in 0..size {
        for px in 0..size {
            let i = (py * size + px) * 3;
            let c = Rgb([frame[i], frame[i + 1], frame[i + 2]]);
            for dy in 0..scale {
                for dx in 0..scale {
                    img.put_pixel(x + px as u32 * scale + dx, y + py as u32 * scale + dy, c);
                }
            }
        }
    }
}

/// A contact sheet: `columns` evenly spaced steps (first to last), one row per camera,
/// frames magnified `scale` times, a bar under each column in the colour of its subtask.
pub fn contact_sheet(seq: &Sequence, columns: usize, scale: u32) -> RgbImage {
    let size = seq.image_size;
    let cell = size as u32 * scale;
    let gap = 2 * scale;
    let bar = 3 * scale;
    let columns = columns.clamp(1, seq.len());
    let width = columns as u32 * (cell + gap) + gap;
    let height = seq.cameras as u32 * (cell + gap) + bar + 2 * gap;
    let mut img = RgbImage::from_pixel(width, height, Rgb([24, 24, 28]));
    for col in 0..columns {
        let t = if columns == 1 {
            0
        } else {
            col * (seq.len() - 1) / (columns - 1)
        };
        let x = gap + col as u32 * (cell + gap);
        for cam in 0..seq.cameras {
            blit(
                &mut img,
                seq.image(t, cam),
                size,
                x,
                gap + cam as u32 * (cell + gap),
                scale,
            );
        }
        let colour = Rgb(SUBTASK_COLOURS[seq.subtask[t] as usize % SUBTASK_COLOURS.len()]);
        let y0 = gap + seq.cameras as u32 * (cell + gap);
        for y in y0..y0 + bar {
            for xx in x..x + cell {
                img.put_pixel(xx, y, colour);
            }
        }
    }
    img
}

/// Writes the contact sheet as PNG.
pub fn write_contact_sheet(seq: &Sequence, path: &Path) -> Result<()> {
    contact_sheet(seq, 10, 2).save(path).map_err(|e| {
        format_err(
            path.display(),
            format!("cannot write the contact sheet: {e}"),
        )
    })
}

/// Writes an animation of every `stride`-th step (cameras side by side, magnified 2x,
/// played at `fps`).
pub fn write_animation(seq: &Sequence, path: &Path, stride: usize, fps: u32) -> Result<()> {
    let size = seq.image_size;
    let scale = 2;
    let (w, h) = (
        seq.cameras as u32 * size as u32 * scale,
        size as u32 * scale,
    );
    let file = std::fs::File::create(path).map_err(|e| io_err(path, e))?;
    let mut encoder = GifEncoder::new_with_speed(std::io::BufWriter::new(file), 30);
    let err = |e: image::ImageError| {
        format_err(path.display(), format!("cannot write the animation: {e}"))
    };
    encoder.set_repeat(Repeat::Infinite).map_err(err)?;
    let delay = Delay::from_numer_denom_ms(1000, fps.max(1));
    for t in (0..seq.len()).step_by(stride.max(1)) {
        let mut rgb = RgbImage::new(w, h);
        for cam in 0..seq.cameras {
            blit(
                &mut rgb,
                seq.image(t, cam),
                size,
                cam as u32 * size as u32 * scale,
                0,
                scale,
            );
        }
        let rgba = RgbaImage::from_fn(w, h, |x, y| {
            let p = rgb.get_pixel(x, y);
            image::Rgba([p[0], p[1], p[2], 255])
        });
        encoder
            .encode_frame(Frame::from_parts(rgba, 0, 0, delay))
            .map_err(err)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tests::sequence;

    #[test]
    fn sheet_and_animation_are_written() {
        let dir = tempfile::tempdir().unwrap();
        let seq = sequence("s", crate::Split::Learn, 12, 3);
        let sheet = contact_sheet(&seq, 5, 2);
        assert_eq!(sheet.width(), 5 * (8 + 4) + 4);
        write_contact_sheet(&seq, &dir.path().join("s.png")).unwrap();
        write_animation(&seq, &dir.path().join("s.gif"), 2, 10).unwrap();
        let gif = std::fs::read(dir.path().join("s.gif")).unwrap();
        assert_eq!(&gif[..3], b"GIF");
        let png = image::open(dir.path().join("s.png")).unwrap();
        assert_eq!(png.width(), contact_sheet(&seq, 10, 2).width());
    }
}
