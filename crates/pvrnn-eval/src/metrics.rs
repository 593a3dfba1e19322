//! Squared errors per group, over all dimensions or only over the pixels that change
//! between consecutive frames, and the bilinear upsampling the resolution baseline uses.
//! The model and every baseline are scored by [`score`], one code path for all.

use pvrnn_core::Modality;
use pvrnn_core::config::VisionLayout;
use serde::Serialize;

use crate::groups::Group;

/// A sum of squared errors and how many values it sums.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Sse {
    pub sum: f64,
    pub count: u64,
}

impl Sse {
    pub fn add(&mut self, other: Sse) {
        self.sum += other.sum;
        self.count += other.count;
    }

    /// Mean squared error; `None` when no value was counted.
    pub fn mse(&self) -> Option<f64> {
        (self.count > 0).then(|| self.sum / self.count as f64)
    }
}

/// The errors of one prediction of one step, per group (in [`crate::groups`] order).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StepErrors {
    /// Over every dimension of the group.
    pub all: Vec<Sse>,
    /// Over the dimensions of pixels that changed (vision groups only; empty otherwise).
    pub changing: Vec<Sse>,
}

impl StepErrors {
    pub fn zeros(groups: usize) -> Self {
        Self {
            all: vec![Sse::default(); groups],
            changing: vec![Sse::default(); groups],
        }
    }

    pub fn add(&mut self, other: &StepErrors) {
        for (a, b) in self.all.iter_mut().zip(&other.all) {
            a.add(*b);
        }
        for (a, b) in self.changing.iter_mut().zip(&other.changing) {
            a.add(*b);
        }
    }
}

/// Scores `prediction` against `truth` (per modality, full-length vectors in model
/// units). `changed` flags the vision dimensions whose pixel changed; without it the
/// changing-pixel errors stay empty.
pub fn score(
    groups: &[Group],
    prediction: [&[f32]; 2],
    truth: [&[f32]; 2],
    changed: Option<&[bool]>,
) -> StepErrors {
    let mut out = StepErrors::zeros(groups.len());
    for (g, group) in groups.iter().enumerate() {
        let m = group.modality.index();
        let (p, x) = (
            &prediction[m][group.dims.clone()],
            &truth[m][group.dims.clone()],
        );
        let mut all = Sse::default();
        let mut changing = Sse::default();
        let flags = changed
            .filter(|_| group.modality == Modality::Exteroceptive)
            .map(|c| &c[group.dims.clone()]);
        for (i, (&pi, &xi)) in p.iter().zip(x).enumerate() {
            let e = (pi as f64 - xi as f64).powi(2);
            all.sum += e;
            all.count += 1;
            if flags.is_some_and(|f| f[i]) {
                changing.sum += e;
                changing.count += 1;
            }
        }
        out.all[g] = all;
        out.changing[g] = changing;
    }
    out
}

/// Flags each vision dimension whose pixel (any channel) differs between `from` and `to`
/// by more than `threshold` model units.
pub fn change_mask(layout: &VisionLayout, from: &[f32], to: &[f32], threshold: f32) -> Vec<bool> {
    let c = layout.channels;
    let mut mask = vec![false; layout.dims()];
    for (pixel, flags) in mask.chunks_exact_mut(c).enumerate() {
        let range = pixel * c..(pixel + 1) * c;
        let changed = from[range.clone()]
            .iter()
            .zip(&to[range])
            .any(|(a, b)| (a - b).abs() > threshold);
        flags.fill(changed);
    }
    mask
}

/// Bilinear upsampling of a `[r, r, channels]` image to `[size, size, channels]`, pixel
/// centres aligned (as `align_corners = false` in PyTorch) and edges clamped.
pub fn upsample_bilinear(image: &[f32], r: usize, channels: usize, size: usize) -> Vec<f32> {
    let scale = r as f64 / size as f64;
    let coords: Vec<(usize, usize, f32)> = (0..size)
        .map(|o| {
            let s = ((o as f64 + 0.5) * scale - 0.5).clamp(0.0, (r - 1) as f64);
            let lo = s.floor() as usize;
            (lo, (lo + 1).min(r - 1), (s - lo as f64) as f32)
        })
        .collect();
    let mut out = vec![0f32; size * size * channels];
    for (y, &(y0, y1, wy)) in coords.iter().enumerate() {
        for (x, &(x0, x1, wx)) in coords.iter().enumerate() {
            for ch in 0..channels {
                let at = |yy: usize, xx: usize| image[(yy * r + xx) * channels + ch];
                let top = at(y0, x0) * (1.0 - wx) + at(y0, x1) * wx;
                let bottom = at(y1, x0) * (1.0 - wx) + at(y1, x1) * wx;
                out[(y * size + x) * channels + ch] = top * (1.0 - wy) + bottom * wy;
            }
        }
    }
    out
}

/// The resolution baseline's vision vector: the observed levels as observed, each higher
/// level bilinearly upsampled from the highest observed one. `None` when no level or every
/// level is observed.
pub fn upsampled_vision(
    layout: &VisionLayout,
    x: &[f32],
    observed_levels: usize,
) -> Option<Vec<f32>> {
    let levels = layout.resolutions.len();
    if observed_levels == 0 || observed_levels >= levels {
        return None;
    }
    let top = observed_levels - 1;
    let r = layout.resolutions[top];
    let mut out = x.to_vec();
    for level in observed_levels..levels {
        let size = layout.resolutions[level];
        for camera in 0..layout.cameras {
            let from = layout.image_offset(top, camera);
            let image = &x[from..from + r * r * layout.channels];
            let up = upsample_bilinear(image, r, layout.channels, size);
            let to = layout.image_offset(level, camera);
            out[to..to + up.len()].copy_from_slice(&up);
        }
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::groups::groups;
    use pvrnn_core::{ModelConfig, Observed};

    fn layout() -> VisionLayout {
        VisionLayout {
            cameras: 2,
            channels: 3,
            resolutions: vec![2, 4],
        }
    }

    #[test]
    fn bilinear_upsampling_keeps_constants_and_interpolates_ramps() {
        let flat = vec![0.25f32; 2 * 2 * 3];
        assert!(upsample_bilinear(&flat, 2, 3, 8).iter().all(|&v| v == 0.25));
        // A horizontal ramp 0, 1 over 2 pixels: output centres at x = 0.5..3.5 of 4 map to
        // source -0.25, 0.25, 0.75, 1.25 -> clamped 0, 0.25, 0.75, 1.
        let ramp = [0.0f32, 1.0, 0.0, 1.0];
        let up = upsample_bilinear(&ramp, 2, 1, 4);
        assert_eq!(&up[..4], &[0.0, 0.25, 0.75, 1.0]);
        assert_eq!(&up[12..], &[0.0, 0.25, 0.75, 1.0]);
    }

    #[test]
    fn the_upsampling_baseline_fills_only_unobserved_levels() {
        let l = layout();
        let x: Vec<f32> = (0..l.dims()).map(|i| i as f32 * 0.01).collect();
        assert!(upsampled_vision(&l, &x, 0).is_none());
        assert!(upsampled_vision(&l, &x, 2).is_none());
        let up = upsampled_vision(&l, &x, 1).unwrap();
        assert_eq!(&up[..l.level_dims(0)], &x[..l.level_dims(0)]);
        let right = l.image_offset(0, 1);
        let expect = upsample_bilinear(&x[right..right + 12], 2, 3, 4);
        let at = l.image_offset(1, 1);
        assert_eq!(&up[at..at + 48], &expect[..]);
    }

    #[test]
    fn scores_pool_squared_errors_per_group_and_over_changing_pixels() {
        let mut config = ModelConfig::default();
        config.vision = layout();
        let cams = ["left".to_string(), "right".to_string()];
        let gs = groups(
            &config,
            &cams,
            pvrnn_dataset::ProprioLayout::PAPER,
            &Observed::all(&config),
        );
        let names: Vec<&str> = gs.iter().map(|g| g.name.as_str()).collect();
        assert_eq!(
            names,
            [
                "v2", "v2_left", "v2_right", "v4", "v4_left", "v4_right", "joints", "torques"
            ]
        );
        let dv = config.vision.dims();
        let truth_v = vec![0.0f32; dv];
        let mut pred_v = vec![0.0f32; dv];
        // One pixel of the 4x4 right image is off by 0.5 in its green channel.
        let px = config.vision.image_offset(1, 1) + 5 * 3;
        pred_v[px + 1] = 0.5;
        let truth_p = vec![0.1f32; 28];
        let mut pred_p = truth_p.clone();
        pred_p[20] = 0.4;
        let mut changed = vec![false; dv];
        changed[px..px + 3].fill(true);
        let e = score(
            &gs,
            [&pred_v, &pred_p],
            [&truth_v, &truth_p],
            Some(&changed),
        );
        let v4 = &e.all[3];
        assert_eq!(v4.count, 96);
        assert!((v4.mse().unwrap() - 0.25 / 96.0).abs() < 1e-12);
        assert_eq!(e.changing[5].count, 3);
        assert!((e.changing[5].mse().unwrap() - 0.25 / 3.0).abs() < 1e-12);
        assert_eq!(e.changing[4].mse(), None);
        assert_eq!(e.all[6].mse(), Some(0.0));
        assert!((e.all[7].mse().unwrap() - 0.09 / 14.0).abs() < 1e-9);
        assert_eq!(e.changing[7].count, 0);
        // The change mask flags all channels of a pixel when any channel moves enough.
        let mut moved = truth_v.clone();
        moved[px + 2] = 0.2;
        let mask = change_mask(&config.vision, &truth_v, &moved, 0.1);
        assert_eq!(mask.iter().filter(|&&m| m).count(), 3);
        assert!(mask[px] && mask[px + 1] && mask[px + 2]);
        assert!(
            change_mask(&config.vision, &truth_v, &moved, 0.3)
                .iter()
                .all(|&m| !m)
        );
    }
}
