//! The open-loop baseline that needs no network: the mean joint trajectory of the task's
//! learning trials ([`mean_trajectory`]).

use caresim::{BED_HEIGHTS_MM, simulate_proprioception};
use pvrnn_dataset::Split;

use crate::spec::DriveSpec;
use crate::{Error, Result};

/// Learning trials per task and bed height (the paper's 3).
pub const LEARNING_TRIALS: usize = 3;

/// The mean of the recorded joint angles (14 per step) of `spec`'s task's learning trials
/// at its bed height in its caresim dataset, each trial resampled (linearly, over its
/// normalised time) to `steps`. A bed height between the learned ones (590, 650, 710 mm)
/// interpolates the two neighbours' means by height; one outside them takes the nearest.
pub fn mean_trajectory(spec: &DriveSpec, steps: usize) -> Result<Vec<[f64; 14]>> {
    if steps == 0 {
        return Err(Error::Invalid("an episode of 0 steps".into()));
    }
    let h = spec.bed_height_mm;
    let learned = BED_HEIGHTS_MM;
    let (below, above) = match learned.iter().position(|&l| l >= h) {
        Some(0) => (learned[0], learned[0]),
        Some(i) if learned[i] == h => (h, h),
        Some(i) => (learned[i - 1], learned[i]),
        None => (learned[2], learned[2]),
    };
    let at = |height: u32| -> Vec<[f64; 14]> {
        let trials: Vec<_> = spec
            .dataset(vec![height], LEARNING_TRIALS, 0)
            .trials()
            .into_iter()
            .filter(|t| t.split == Split::Learn)
            .collect();
        let mut mean = vec![[0.0; 14]; steps];
        for trial in &trials {
            let seq = simulate_proprioception(trial);
            for (t, row) in mean.iter_mut().enumerate() {
                let joints = resampled(&seq.joints, seq.len(), t, steps);
                for (m, j) in row.iter_mut().zip(joints) {
                    *m += j / trials.len() as f64;
                }
            }
        }
        mean
    };
    let low = at(below);
    if below == above {
        return Ok(low);
    }
    let high = at(above);
    let w = (h - below) as f64 / (above - below) as f64;
    Ok(low
        .iter()
        .zip(&high)
        .map(|(a, b)| std::array::from_fn(|j| a[j] * (1.0 - w) + b[j] * w))
        .collect())
}

/// A recording's 14 joint angles at step `t` of `steps`, the recording (`len` steps)
/// stretched to that length.
fn resampled(joints: &[f32], len: usize, t: usize, steps: usize) -> [f64; 14] {
    let x = if steps > 1 {
        t as f64 * (len - 1) as f64 / (steps - 1) as f64
    } else {
        0.0
    };
    let i = (x.floor() as usize).min(len - 1);
    let k = (i + 1).min(len - 1);
    let f = x - i as f64;
    std::array::from_fn(|j| joints[i * 14 + j] as f64 * (1.0 - f) + joints[k * 14 + j] as f64 * f)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resampling_keeps_the_ends_and_interpolates_between() {
        let joints: Vec<f32> = (0..3).flat_map(|t| [t as f32 * 2.0; 14]).collect();
        assert_eq!(resampled(&joints, 3, 0, 5)[3], 0.0);
        assert_eq!(resampled(&joints, 3, 4, 5)[3], 4.0);
        assert_eq!(resampled(&joints, 3, 1, 5)[0], 1.0);
    }
}
