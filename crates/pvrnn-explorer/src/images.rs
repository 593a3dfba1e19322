//! Pictures from vision vectors: camera images at every resolution, contours of the actual
//! image, and ablation contribution maps (grayscale |standard - ablated|, Fig. 2B / 3B).

use pvrnn_core::config::{Normalisation, VisionLayout};

/// A square RGB image.
#[derive(Clone, Debug, PartialEq)]
pub struct Rgb {
    pub size: usize,
    pub pixels: Vec<u8>,
}

impl Rgb {
    pub fn to_color_image(&self) -> eframe::egui::ColorImage {
        eframe::egui::ColorImage::from_rgb([self.size, self.size], &self.pixels)
    }
}

/// One camera's image at one level of a vision vector (model units to 8-bit RGB).
pub fn camera_image(layout: &VisionLayout, vision: &[f32], level: usize, camera: usize) -> Rgb {
    let r = layout.resolutions[level];
    let off = layout.image_offset(level, camera);
    let channels = layout.channels;
    let mut pixels = Vec::with_capacity(r * r * 3);
    for p in 0..r * r {
        let px = &vision[off + p * channels..off + (p + 1) * channels];
        let c = |i: usize| Normalisation::vision_from_model(px[i.min(channels - 1)] as f64);
        pixels.extend_from_slice(&[c(0), c(1), c(2)]);
    }
    Rgb { size: r, pixels }
}

/// Edges of an image (Sobel gradient magnitude of its brightness): white on black.
pub fn contours(img: &Rgb) -> Rgb {
    let n = img.size;
    let lum = |x: isize, y: isize| -> f32 {
        let (x, y) = (
            x.clamp(0, n as isize - 1) as usize,
            y.clamp(0, n as isize - 1) as usize,
        );
        let p = &img.pixels[(y * n + x) * 3..(y * n + x) * 3 + 3];
        0.299 * p[0] as f32 + 0.587 * p[1] as f32 + 0.114 * p[2] as f32
    };
    let mut pixels = Vec::with_capacity(n * n * 3);
    for y in 0..n as isize {
        for x in 0..n as isize {
            let gx = lum(x + 1, y - 1) + 2.0 * lum(x + 1, y) + lum(x + 1, y + 1)
                - lum(x - 1, y - 1)
                - 2.0 * lum(x - 1, y)
                - lum(x - 1, y + 1);
            let gy = lum(x - 1, y + 1) + 2.0 * lum(x, y + 1) + lum(x + 1, y + 1)
                - lum(x - 1, y - 1)
                - 2.0 * lum(x, y - 1)
                - lum(x + 1, y - 1);
            let v = ((gx * gx + gy * gy).sqrt() * 0.5).min(255.0) as u8;
            pixels.extend_from_slice(&[v, v, v]);
        }
    }
    Rgb { size: n, pixels }
}

/// Grayscale |a - b| of one camera's image at one level, averaged over channels; `gain`
/// maps a difference of the full range to `gain` x white.
pub fn contribution(
    layout: &VisionLayout,
    a: &[f32],
    b: &[f32],
    level: usize,
    camera: usize,
    gain: f32,
) -> Rgb {
    let r = layout.resolutions[level];
    gray(&pixel_differences(layout, a, b, level, camera), r, gain)
}

/// |a - b| per pixel of one camera's image at one level, averaged over channels (model
/// units), row-major.
pub fn pixel_differences(
    layout: &VisionLayout,
    a: &[f32],
    b: &[f32],
    level: usize,
    camera: usize,
) -> Vec<f32> {
    let r = layout.resolutions[level];
    let off = layout.image_offset(level, camera);
    let ch = layout.channels;
    (0..r * r)
        .map(|p| {
            let range = off + p * ch..off + (p + 1) * ch;
            a[range.clone()]
                .iter()
                .zip(&b[range])
                .map(|(x, y)| (x - y).abs())
                .sum::<f32>()
                / ch as f32
        })
        .collect()
}

/// A grayscale picture of per-pixel differences in model units; `gain` maps a difference
/// of the full range to `gain` x white.
pub fn gray(differences: &[f32], size: usize, gain: f32) -> Rgb {
    let mut pixels = Vec::with_capacity(size * size * 3);
    for &diff in differences {
        // Model units span 1.8.
        let v = (diff / 1.8 * gain * 255.0).min(255.0) as u8;
        pixels.extend_from_slice(&[v, v, v]);
    }
    Rgb { size, pixels }
}

/// Draws the bright pixels of `edges` over `img` in a highlight colour.
pub fn overlay(img: &Rgb, edges: &Rgb, threshold: u8) -> Rgb {
    let mut out = img.clone();
    if edges.size != img.size {
        return out;
    }
    for (px, e) in out
        .pixels
        .chunks_exact_mut(3)
        .zip(edges.pixels.chunks_exact(3))
    {
        if e[0] > threshold {
            px.copy_from_slice(&[255, 214, 0]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn layout() -> VisionLayout {
        VisionLayout {
            cameras: 2,
            channels: 3,
            resolutions: vec![2, 4],
        }
    }

    #[test]
    fn camera_images_come_from_their_slice_of_the_vector() {
        let l = layout();
        let mut v = vec![-0.9f32; l.dims()];
        // Level 1, right camera, pixel (1, 2), green = white.
        v[l.image_offset(1, 1) + (4 + 2) * 3 + 1] = 0.9;
        let img = camera_image(&l, &v, 1, 1);
        assert_eq!(img.size, 4);
        assert_eq!(&img.pixels[(4 + 2) * 3..(4 + 2) * 3 + 3], &[0, 255, 0]);
        assert!(camera_image(&l, &v, 1, 0).pixels.iter().all(|&p| p == 0));
    }

    #[test]
    fn contributions_and_contours() {
        let l = layout();
        let a = vec![0.0f32; l.dims()];
        let mut b = a.clone();
        b[l.image_offset(0, 0)] = 0.9; // red channel of pixel 0: mean |diff| 0.3
        let c = contribution(&l, &a, &b, 0, 0, 1.0);
        assert_eq!(c.pixels[0], (0.3 / 1.8 * 255.0) as u8);
        assert_eq!(c.pixels[3], 0);
        let half = Rgb {
            size: 4,
            pixels: (0..16)
                .flat_map(|i| if i % 4 < 2 { [0u8; 3] } else { [255u8; 3] })
                .collect(),
        };
        let e = contours(&half);
        // The vertical edge between columns 1 and 2 is bright, the flat corners dark.
        assert!(e.pixels[(4 + 1) * 3] > 100 && e.pixels[(4 + 2) * 3] > 100);
        assert_eq!(e.pixels[0], 0);
    }
}
