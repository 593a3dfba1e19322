//! Camera frames of any size to the dataset's square images: centre crop to a square, then
//! area resampling (each output pixel is the exact average of the source area it covers).

use image::RgbImage;

/// Centre-crops `img` to a square and area-resamples it to `size` x `size`; RGB bytes.
pub fn square_area_resample(img: &RgbImage, size: usize) -> Vec<u8> {
    let (w, h) = (img.width() as usize, img.height() as usize);
    let side = w.min(h);
    let (x0, y0) = ((w - side) / 2, (h - side) / 2);
    let src = img.as_raw();
    // Horizontal pass over the crop rows, then vertical, in f64 channel sums.
    let weights = area_weights(side, size);
    let mut rows = vec![0f64; side * size * 3];
    for y in 0..side {
        let row = &src[((y0 + y) * w + x0) * 3..((y0 + y) * w + x0 + side) * 3];
        for (ox, taps) in weights.iter().enumerate() {
            for &(sx, wgt) in taps {
                for c in 0..3 {
                    rows[(y * size + ox) * 3 + c] += wgt * row[sx * 3 + c] as f64;
                }
            }
        }
    }
    let mut out = vec![0u8; size * size * 3];
    for (oy, taps) in weights.iter().enumerate() {
        for ox in 0..size {
            for c in 0..3 {
                let v: f64 = taps
                    .iter()
                    .map(|&(sy, wgt)| wgt * rows[(sy * size + ox) * 3 + c])
                    .sum();
                out[(oy * size + ox) * 3 + c] = v.round().clamp(0.0, 255.0) as u8;
            }
        }
    }
    out
}

/// For each output index, the source indices it covers with their weights (summing to 1).
fn area_weights(src: usize, dst: usize) -> Vec<Vec<(usize, f64)>> {
    let scale = src as f64 / dst as f64;
    (0..dst)
        .map(|o| {
            let (a, b) = (o as f64 * scale, (o + 1) as f64 * scale);
            let mut taps = Vec::new();
            let mut s = a.floor() as usize;
            while (s as f64) < b && s < src {
                let cover = (b.min((s + 1) as f64) - a.max(s as f64)).max(0.0);
                if cover > 0.0 {
                    taps.push((s, cover / scale));
                }
                s += 1;
            }
            taps
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identity_at_the_same_size_and_exact_averages_when_shrinking() {
        let img = RgbImage::from_fn(4, 4, |x, y| image::Rgb([(x * 10) as u8, (y * 20) as u8, 7]));
        assert_eq!(square_area_resample(&img, 4), img.as_raw().clone());
        let half = square_area_resample(&img, 2);
        // Pixel (0, 0) averages x in {0, 1}, y in {0, 1}: red (0 + 10) / 2 = 5, green 10.
        assert_eq!(&half[..3], &[5, 10, 7]);
    }

    #[test]
    fn crops_the_centre_of_wide_frames() {
        // 6x2: a 2-pixel-wide centre (x = 2, 3) of value 200, sides 0.
        let img = RgbImage::from_fn(6, 2, |x, _| {
            if (2..4).contains(&x) {
                image::Rgb([200; 3])
            } else {
                image::Rgb([0; 3])
            }
        });
        assert!(square_area_resample(&img, 2).iter().all(|&v| v == 200));
        // Non-integer ratios keep the mean.
        let img = RgbImage::from_fn(5, 5, |x, y| image::Rgb([((x + y) * 20) as u8; 3]));
        let out = square_area_resample(&img, 3);
        let mean_in: f64 = img.as_raw().iter().map(|&v| v as f64).sum::<f64>() / 75.0;
        let mean_out: f64 = out.iter().map(|&v| v as f64).sum::<f64>() / 27.0;
        assert!((mean_in - mean_out).abs() < 1.0, "{mean_in} {mean_out}");
    }
}
