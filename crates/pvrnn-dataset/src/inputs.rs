//! From a dataset to model inputs, exactly as `docs/model.md` "Data layout" says:
//!
//! - vision: for each resolution ascending (16, 32, 64), for each camera (left, right), the
//!   image row-major and pixel-interleaved; the 32x32 and 16x16 images are 2x2 box averages
//!   of the level above; values `v / 255 * 1.8 - 0.9`;
//! - proprioception: the joint angles, then the torques, then any extra channels, in the
//!   order the manifest names them (the paper's robot: joints 1-7 left, 1-7 right, torques
//!   likewise), each scaled to [-0.9, 0.9] by the learning split's min and max (stored in
//!   the model; a constant dimension maps to 0).

use pvrnn_core::config::{ModelConfig, Normalisation, VisionLayout};
use pvrnn_core::{Observations, Tensor};

use crate::{Dataset, Manifest, Result, Sequence, Split, format_err};

/// Which of a dataset's sequences to use.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Selection {
    Split(Split),
    All,
}

impl Selection {
    pub fn parse(text: &str) -> Option<Self> {
        match text {
            "learn" => Some(Selection::Split(Split::Learn)),
            "test" => Some(Selection::Split(Split::Test)),
            "all" => Some(Selection::All),
            _ => None,
        }
    }
    fn split(&self) -> Option<Split> {
        match self {
            Selection::Split(s) => Some(*s),
            Selection::All => None,
        }
    }
}

/// Per-dimension min and max of the raw proprioception over `sequences` (which share one
/// channel layout, as a dataset's do).
pub fn proprio_ranges(sequences: &[&Sequence]) -> Normalisation {
    let dims = sequences.first().map_or(0, |s| s.proprio_layout().dims());
    let mut lo = vec![f64::INFINITY; dims];
    let mut hi = vec![f64::NEG_INFINITY; dims];
    for s in sequences {
        for t in 0..s.len() {
            for (i, v) in s.proprio(t).into_iter().enumerate() {
                lo[i] = lo[i].min(v as f64);
                hi[i] = hi[i].max(v as f64);
            }
        }
    }
    Normalisation {
        proprio_min: lo,
        proprio_max: hi,
    }
}

/// Per proprioceptive dimension, the sensor noise's standard deviation estimated from the
/// recordings (raw units): the standard deviation of step-to-step differences over sqrt 2,
/// pooled over `sequences`. Motion between steps adds to the differences, so on a moving
/// channel this overestimates the noise; on a channel that only carries noise it is the
/// noise.
pub fn proprio_noise_std(sequences: &[&Sequence]) -> Vec<f64> {
    let dims = sequences.first().map_or(0, |s| s.proprio_layout().dims());
    let (mut sum, mut sum_sq, mut count) = (vec![0.0; dims], vec![0.0; dims], 0usize);
    for s in sequences {
        let mut previous: Option<Vec<f32>> = None;
        for t in 0..s.len() {
            let row = s.proprio(t);
            if let Some(p) = &previous {
                for i in 0..dims {
                    let d = (row[i] - p[i]) as f64;
                    sum[i] += d;
                    sum_sq[i] += d * d;
                }
                count += 1;
            }
            previous = Some(row);
        }
    }
    (0..dims)
        .map(|i| {
            if count < 2 {
                return 0.0;
            }
            let n = count as f64;
            let variance = (sum_sq[i] - sum[i] * sum[i] / n) / (n - 1.0);
            (variance.max(0.0) / 2.0).sqrt()
        })
        .collect()
}

/// Fails with a message naming both sides unless the model's vision layout is this
/// dataset's pyramid.
pub fn check_layout(manifest: &Manifest, layout: &VisionLayout) -> Result<()> {
    let res = &layout.resolutions;
    let top = *res.last().expect("validated non-empty");
    let halves = res.windows(2).all(|w| w[0] * 2 == w[1]);
    if layout.cameras != manifest.cameras.len()
        || layout.channels != 3
        || top != manifest.image_size
        || !halves
    {
        return Err(format_err(
            "dataset",
            format!(
                "its {} cameras of {}x{} RGB images do not fit the model's vision layout ({} cameras x {} channels at {:?}); \
                 the model needs the dataset's camera count, 3 channels, the image size as its largest resolution and each lower one half the next",
                manifest.cameras.len(),
                manifest.image_size,
                manifest.image_size,
                layout.cameras,
                layout.channels,
                res
            ),
        ));
    }
    Ok(())
}

/// Fails with a message naming both sides unless the model's proprioception is this
/// dataset's channels.
pub fn check_proprio(manifest: &Manifest, config: &ModelConfig) -> Result<()> {
    let layout = manifest.proprio_layout();
    if layout.dims() != config.proprio_dims {
        return Err(format_err(
            "dataset",
            format!(
                "its {} proprioceptive channels ({} joint angles, {} torques, {} extra) do not fit the model's {} proprioceptive dimensions; \
                 create the model for this dataset with `pvrnn init --dataset`",
                layout.dims(),
                layout.joints,
                layout.torques,
                layout.extra,
                config.proprio_dims
            ),
        ));
    }
    if let Some(norm) = &config.normalisation
        && norm.proprio_min.len() != layout.dims()
    {
        return Err(format_err(
            "model",
            format!(
                "its proprioception ranges have {} dimensions, the dataset {}",
                norm.proprio_min.len(),
                layout.dims()
            ),
        ));
    }
    Ok(())
}

/// The configuration `config` adapted to a dataset: its cameras, its image size as the
/// largest resolution (keeping the number of levels, each half the next) and its
/// proprioceptive channels. Fails when the image size does not halve that often.
pub fn fit_config(config: &ModelConfig, manifest: &Manifest) -> Result<ModelConfig> {
    let mut fitted = config.clone();
    let levels = config.vision.resolutions.len().max(1);
    let top = manifest.image_size;
    if !top.is_multiple_of(1 << (levels - 1)) || top >> (levels - 1) == 0 {
        return Err(format_err(
            "dataset",
            format!(
                "its {top}x{top} images cannot be halved {} times for the model's {levels} vision levels; \
                 import with an --image-size divisible by {}",
                levels - 1,
                1 << (levels - 1)
            ),
        ));
    }
    fitted.vision.cameras = manifest.cameras.len();
    fitted.vision.resolutions = (0..levels).rev().map(|l| top >> l).collect();
    fitted.proprio_dims = manifest.proprio_layout().dims();
    Ok(fitted)
}

/// A model without proprioception ranges gets the dataset's learning split's (the spec's
/// rule; every reader of a model and a dataset applies it here). Returns whether it did.
pub fn ensure_normalisation(config: &mut ModelConfig, dataset: &Dataset) -> Result<bool> {
    if config.normalisation.is_some() {
        return Ok(false);
    }
    let learn = dataset.split(Some(Split::Learn));
    if learn.is_empty() {
        return Err(format_err(
            "model",
            "has no proprioception ranges, and the dataset has no learning sequences to take them from",
        ));
    }
    config.normalisation = Some(proprio_ranges(&learn));
    Ok(true)
}

/// Writes one step's vision vector (all levels, all cameras) into `out`.
pub fn vision_vector(seq: &Sequence, t: usize, layout: &VisionLayout, out: &mut [f32]) {
    let frame = seq.image(t, 0).len();
    let step = &seq.images[t * seq.cameras * frame..(t + 1) * seq.cameras * frame];
    step_vision_vector(step, seq.cameras, layout, out);
}

/// [`vision_vector`] of one step's images as a sequence stores them (`[cameras, S, S, 3]`,
/// S the layout's highest resolution), e.g. a robot's cameras as they come.
pub fn step_vision_vector(images: &[u8], cameras: usize, layout: &VisionLayout, out: &mut [f32]) {
    if cameras == 0 || images.is_empty() {
        return;
    }
    let levels = layout.resolutions.len();
    let frame = images.len() / cameras;
    let mut level_images: Vec<Vec<f32>> = images
        .chunks_exact(frame)
        .map(|img| img.iter().map(|&v| v as f32).collect())
        .collect();
    // Highest level first, each lower one the 2x2 box average of the one above.
    for level in (0..levels).rev() {
        let r = layout.resolutions[level];
        for (cam, img) in level_images.iter_mut().enumerate() {
            if level + 1 < levels {
                *img = box_average(img, r * 2);
            }
            let off = layout.image_offset(level, cam);
            for (o, &v) in out[off..off + r * r * 3].iter_mut().zip(img.iter()) {
                *o = Normalisation::vision_to_model(v as f64) as f32;
            }
        }
    }
}

/// 2x2 box average of a `[size, size, 3]` image.
pub fn box_average(img: &[f32], size: usize) -> Vec<f32> {
    let half = size / 2;
    let mut out = vec![0f32; half * half * 3];
    for y in 0..half {
        for x in 0..half {
            for c in 0..3 {
                let at = |yy: usize, xx: usize| img[(yy * size + xx) * 3 + c];
                out[(y * half + x) * 3 + c] = (at(2 * y, 2 * x)
                    + at(2 * y, 2 * x + 1)
                    + at(2 * y + 1, 2 * x)
                    + at(2 * y + 1, 2 * x + 1))
                    * 0.25;
            }
        }
    }
    out
}

impl Dataset {
    /// The sequences of a selection, in manifest order; an error if there are none.
    pub fn select(&self, selection: &Selection) -> Result<Vec<&Sequence>> {
        let seqs = self.split(selection.split());
        if seqs.is_empty() {
            return Err(format_err(
                "dataset",
                format!(
                    "has no {} sequences",
                    selection.split().map_or("", |s| s.name())
                ),
            ));
        }
        Ok(seqs)
    }

    /// Model inputs for `sequences`, scaled with the model's stored normalisation.
    pub fn observations(
        &self,
        sequences: &[&Sequence],
        config: &ModelConfig,
    ) -> Result<Observations<f32>> {
        check_layout(&self.manifest, &config.vision)?;
        check_proprio(&self.manifest, config)?;
        let norm = config.normalisation.as_ref().ok_or_else(|| {
            format_err(
                "model",
                "has no proprioception ranges; create it with `pvrnn init --dataset` or train it on a dataset first",
            )
        })?;
        let steps = sequences.iter().map(|s| s.len()).max().unwrap_or(0);
        let (s_count, dv) = (sequences.len(), config.vision.dims());
        let mut extero = vec![0f32; s_count * steps * dv];
        let dp = config.proprio_dims;
        let mut proprio = vec![0f32; s_count * steps * dp];
        for (i, seq) in sequences.iter().enumerate() {
            for t in 0..seq.len() {
                let row = (i * steps + t) * dv;
                vision_vector(seq, t, &config.vision, &mut extero[row..row + dv]);
                let prow = (i * steps + t) * dp;
                for (d, v) in seq.proprio(t).into_iter().enumerate() {
                    proprio[prow + d] = norm.proprio_to_model(d, v as f64) as f32;
                }
            }
        }
        Ok(Observations::new(
            Tensor::from_vec(&[s_count, steps, dv], extero)?,
            Tensor::from_vec(&[s_count, steps, dp], proprio)?,
            Some(sequences.iter().map(|s| s.len()).collect()),
        )?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tests::sequence;

    #[test]
    fn pyramid_layout_and_scaling_follow_the_spec() {
        let seq = sequence("s", Split::Learn, 2, 7);
        let layout = VisionLayout {
            cameras: 2,
            channels: 3,
            resolutions: vec![1, 2, 4],
        };
        let mut out = vec![0f32; layout.dims()];
        vision_vector(&seq, 1, &layout, &mut out);
        let scale = |v: f64| (v / 255.0 * 1.8 - 0.9) as f32;
        // Level 2 (4x4), right camera, pixel (1, 2), green channel: the raw value.
        let raw = seq.image(1, 1)[(4 + 2) * 3 + 1] as f64;
        assert!((out[layout.image_offset(2, 1) + (4 + 2) * 3 + 1] - scale(raw)).abs() < 1e-6);
        // Level 0 (1x1), left camera, red: the mean of all 16 pixels.
        let mean: f64 = (0..16).map(|p| seq.image(1, 0)[p * 3] as f64).sum::<f64>() / 16.0;
        assert!((out[0] - scale(mean)).abs() < 1e-5);
        // Level 1 (2x2), left, pixel (1, 0), blue: mean of the 2x2 block at rows 2-3, cols 0-1.
        let block: f64 = [(2, 0), (2, 1), (3, 0), (3, 1)]
            .iter()
            .map(|&(y, x)| seq.image(1, 0)[(y * 4 + x) * 3 + 2] as f64)
            .sum::<f64>()
            / 4.0;
        assert!((out[layout.image_offset(1, 0) + 2 * 3 + 2] - scale(block)).abs() < 1e-5);
    }

    #[test]
    fn proprioception_is_scaled_by_the_learning_ranges() {
        let learn = sequence("a", Split::Learn, 6, 2);
        let test = sequence("b", Split::Test, 4, 9);
        let ds = Dataset::new("t", vec!["l".into(), "r".into()], 4, vec![learn, test]).unwrap();
        let mut config = ModelConfig::default();
        config.vision.resolutions = vec![1, 2, 4];
        config.normalisation = Some(proprio_ranges(&ds.split(Some(Split::Learn))));
        let learn_obs = ds
            .observations(&ds.split(Some(Split::Learn)), &config)
            .unwrap();
        let p = learn_obs
            .tensor(pvrnn_core::Modality::Proprioceptive)
            .data();
        let (lo, hi) = p
            .iter()
            .fold((f32::MAX, f32::MIN), |(a, b), &v| (a.min(v), b.max(v)));
        assert!(
            (lo + 0.9).abs() < 1e-5 && (hi - 0.9).abs() < 1e-5,
            "{lo} {hi}"
        );
        // Test data is scaled by the same ranges (so it can leave [-0.9, 0.9]).
        let all = ds.observations(&ds.split(None), &config).unwrap();
        assert_eq!(all.lengths(), &[6, 4]);
        config.normalisation = None;
        let e = ds
            .observations(&ds.split(None), &config)
            .unwrap_err()
            .to_string();
        assert!(e.contains("proprioception ranges"), "{e}");
        config.vision.resolutions = vec![16, 32, 64];
        config.normalisation = Some(proprio_ranges(&ds.split(None)));
        let e = ds
            .observations(&ds.split(None), &config)
            .unwrap_err()
            .to_string();
        assert!(e.contains("4x4") && e.contains("[16, 32, 64]"), "{e}");
    }
}
