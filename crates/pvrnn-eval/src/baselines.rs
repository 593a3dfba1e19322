//! What the baselines take from the learning split: its mean input, the fine detail of its
//! mean image, and, for the nearest-neighbour baseline, the learning frame whose observed
//! inputs are closest to each evaluated step's.

use pvrnn_core::config::VisionLayout;
use pvrnn_core::{Modality, Model, Observations, Observed};
use pvrnn_dataset::{Dataset, Selection, Sequence, Split};
use rayon::prelude::*;

use crate::Result;
use crate::metrics::upsampled_vision;

/// Mean normalised input (vision, proprioception) over every step of the learning split.
pub fn learning_mean(dataset: &Dataset, model: &Model<f32>) -> Result<[Vec<f32>; 2]> {
    let learn = dataset.select(&Selection::Split(Split::Learn))?;
    let config = &model.config;
    let mut sums = [
        vec![0f64; config.vision.dims()],
        vec![0f64; config.proprio_dims],
    ];
    let mut steps = 0usize;
    for seq in learn {
        let obs = dataset.observations(&[seq], config)?;
        for t in 0..seq.len() {
            for m in Modality::ALL {
                for (s, &v) in sums[m.index()].iter_mut().zip(obs.step(m, 0, t)) {
                    *s += v as f64;
                }
            }
        }
        steps += seq.len();
    }
    Ok(sums.map(|s| s.into_iter().map(|v| (v / steps as f64) as f32).collect()))
}

/// The fine detail of the mean image: at each level above the `observed_levels` ones, the
/// mean image minus its own bilinear upsampling from the highest observed level (zero at
/// the observed levels). Added to the upsampled observation it gives the
/// *upsample + mean detail* baseline. `None` when no level or every level is observed.
pub fn mean_detail(
    layout: &VisionLayout,
    mean_vision: &[f32],
    observed_levels: usize,
) -> Option<Vec<f32>> {
    let upsampled = upsampled_vision(layout, mean_vision, observed_levels)?;
    Some(
        mean_vision
            .iter()
            .zip(&upsampled)
            .map(|(m, u)| m - u)
            .collect(),
    )
}

/// The *upsample + mean detail* reconstruction of one step's vision.
pub fn upsampled_with_detail(
    layout: &VisionLayout,
    x: &[f32],
    observed_levels: usize,
    detail: &[f32],
) -> Option<Vec<f32>> {
    let mut up = upsampled_vision(layout, x, observed_levels)?;
    for (u, d) in up.iter_mut().zip(detail) {
        *u += d;
    }
    Some(up)
}

/// A learning frame: (index of the sequence in the learning split, step).
pub type Frame = (usize, usize);

/// The observed part of an input that the nearest-neighbour search compares: the leading
/// `vision` dimensions (the observed levels, lowest resolution first in the layout) and,
/// when observed, all of proprioception. Distances weight each modality by one over its
/// compared dimensions, as the free energy weights accuracy, so that 28 joint values are
/// not drowned by 1,536 pixels.
#[derive(Clone, Copy, Debug)]
struct Key {
    vision: usize,
    proprio: usize,
}

impl Key {
    fn of(layout: &VisionLayout, proprio_dims: usize, observed: &Observed) -> Option<Self> {
        let key = Key {
            vision: layout.observed_dims(observed.vision_levels),
            proprio: if observed.proprio { proprio_dims } else { 0 },
        };
        (key.vision + key.proprio > 0).then_some(key)
    }

    fn distance(&self, a: [&[f32]; 2], b: [&[f32]; 2]) -> f32 {
        let mut d = 0.0;
        if self.vision > 0 {
            d += squared_distance(&a[0][..self.vision], &b[0][..self.vision]) / self.vision as f32;
        }
        if self.proprio > 0 {
            d += squared_distance(&a[1][..self.proprio], &b[1][..self.proprio])
                / self.proprio as f32;
        }
        d
    }
}

/// Evaluated steps compared with one reference frame together (`NearestFrames::search`);
/// the tests' 10-step sequences span two blocks.
const NEAREST_BLOCK: usize = 8;

/// Squared Euclidean distance, in eight independent sums so that it vectorises.
fn squared_distance(a: &[f32], b: &[f32]) -> f32 {
    let mut acc = [0f32; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for k in 0..8 {
            let e = x[k] - y[k];
            acc[k] += e * e;
        }
    }
    let tail: f32 = ra.iter().zip(rb).map(|(x, y)| (x - y) * (x - y)).sum();
    acc.iter().sum::<f32>() + tail
}

/// For every step of every evaluated sequence, the learning frame whose observed inputs
/// are closest (`None` where nothing is observed, or for padding steps). A learning
/// sequence that is itself evaluated (`--split learn` or `all`) is never its own
/// neighbour: the baseline must not copy the answer.
#[derive(Clone, Debug)]
pub struct NearestFrames {
    /// `[evaluated sequence][step]`.
    pub frames: Vec<Vec<Option<Frame>>>,
}

impl NearestFrames {
    /// Searches the learning split of `dataset` for `evaluated` (whose inputs are `data`).
    pub fn search(
        dataset: &Dataset,
        model: &Model<f32>,
        evaluated: &[&Sequence],
        data: &Observations<f32>,
        observed: &Observed,
    ) -> Result<Option<Self>> {
        let config = &model.config;
        let Some(key) = Key::of(&config.vision, config.proprio_dims, observed) else {
            return Ok(None);
        };
        let learn = dataset.select(&Selection::Split(Split::Learn))?;
        let mut best: Vec<Vec<(f32, Option<Frame>)>> = data
            .lengths()
            .iter()
            .map(|&len| vec![(f32::INFINITY, None); len])
            .collect();
        for (l, seq) in learn.iter().enumerate() {
            let reference = dataset.observations(&[seq], config)?;
            let frame = |u: usize| {
                [
                    reference.step(Modality::Exteroceptive, 0, u),
                    reference.step(Modality::Proprioceptive, 0, u),
                ]
            };
            best.par_iter_mut().enumerate().for_each(|(s, steps)| {
                if evaluated[s].info.name == seq.info.name {
                    return;
                }
                // A block of evaluated steps against each reference frame in turn, so that
                // a reference frame is read from memory once per block, not once per step
                // (with 64x64 observed, a sequence's frames are ~40 MB: more than a cache).
                for (b, block) in steps.chunks_mut(NEAREST_BLOCK).enumerate() {
                    let x: Vec<[&[f32]; 2]> = (0..block.len())
                        .map(|i| {
                            let t = b * NEAREST_BLOCK + i;
                            [
                                data.step(Modality::Exteroceptive, s, t),
                                data.step(Modality::Proprioceptive, s, t),
                            ]
                        })
                        .collect();
                    for u in 0..seq.len() {
                        let reference = frame(u);
                        for (slot, x) in block.iter_mut().zip(&x) {
                            let d = key.distance(*x, reference);
                            if d < slot.0 {
                                *slot = (d, Some((l, u)));
                            }
                        }
                    }
                }
            });
        }
        Ok(Some(Self {
            frames: best
                .into_iter()
                .map(|steps| steps.into_iter().map(|(_, f)| f).collect())
                .collect(),
        }))
    }

    /// Calls `visit(s, t, frame inputs)` for every evaluated step with a neighbour, loading
    /// each learning sequence once.
    pub fn for_each(
        &self,
        dataset: &Dataset,
        model: &Model<f32>,
        mut visit: impl FnMut(usize, usize, [&[f32]; 2]),
    ) -> Result<()> {
        let learn = dataset.select(&Selection::Split(Split::Learn))?;
        for (l, seq) in learn.iter().enumerate() {
            let wanted: Vec<(usize, usize, usize)> = self
                .frames
                .iter()
                .enumerate()
                .flat_map(|(s, steps)| {
                    steps.iter().enumerate().filter_map(move |(t, f)| match f {
                        Some((fl, u)) if *fl == l => Some((s, t, *u)),
                        _ => None,
                    })
                })
                .collect();
            if wanted.is_empty() {
                continue;
            }
            let reference = dataset.observations(&[seq], &model.config)?;
            for (s, t, u) in wanted {
                visit(
                    s,
                    t,
                    [
                        reference.step(Modality::Exteroceptive, 0, u),
                        reference.step(Modality::Proprioceptive, 0, u),
                    ],
                );
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::upsample_bilinear;

    fn layout() -> VisionLayout {
        VisionLayout {
            cameras: 1,
            channels: 1,
            resolutions: vec![2, 4],
        }
    }

    #[test]
    fn the_detail_is_what_upsampling_the_mean_misses_and_only_above_the_observed_levels() {
        let l = layout();
        // A 2x2 level (4 values) then a 4x4 level with a checkerboard on top of a ramp.
        let mut mean = vec![0.1, 0.2, 0.3, 0.4];
        let fine: Vec<f32> = (0..16)
            .map(|i| 0.05 * (i % 4) as f32 + if (i / 4 + i % 4) % 2 == 0 { 0.2 } else { -0.2 })
            .collect();
        mean.extend(&fine);
        let detail = mean_detail(&l, &mean, 1).unwrap();
        assert!(detail[..4].iter().all(|&d| d == 0.0));
        let up = upsample_bilinear(&mean[..4], 2, 1, 4);
        for i in 0..16 {
            assert!((detail[4 + i] - (fine[i] - up[i])).abs() < 1e-7);
        }
        // The mean itself is reconstructed exactly from its own coarse level.
        let rebuilt = upsampled_with_detail(&l, &mean, 1, &detail).unwrap();
        for (a, b) in rebuilt.iter().zip(&mean) {
            assert!((a - b).abs() < 1e-6);
        }
        assert!(mean_detail(&l, &mean, 0).is_none() && mean_detail(&l, &mean, 2).is_none());
    }

    #[test]
    fn distances_weight_each_modality_by_its_compared_dimensions() {
        let key = Key {
            vision: 4,
            proprio: 2,
        };
        let a = ([0.0f32; 6], [0.0f32; 2]);
        let b = ([1.0f32, 1.0, 1.0, 1.0, 9.0, 9.0], [0.5f32, 0.5]);
        // Vision: 4 / 4 (the unobserved last two ignored); proprioception: 0.5 / 2.
        let d = key.distance([&a.0, &a.1], [&b.0, &b.1]);
        assert!((d - 1.25).abs() < 1e-6, "{d}");
        let long_a: Vec<f32> = (0..37).map(|i| i as f32 * 0.1).collect();
        let long_b: Vec<f32> = (0..37).map(|i| (i as f32 * 0.1).sin()).collect();
        let naive: f32 = long_a
            .iter()
            .zip(&long_b)
            .map(|(x, y)| (x - y) * (x - y))
            .sum();
        assert!((squared_distance(&long_a, &long_b) - naive).abs() < 1e-3 * naive);
    }
}
