//! What a model makes of body parts the robot's arms hide. On data with robot-free renders
//! (`pvrnn simulate --robot-free`), a top-resolution pixel is *hidden* at a step when the
//! observed image and the robot-free one differ there; on hidden pixels the model's
//! reconstruction is scored against the robot-free truth, beside two baselines that use only
//! what was observed: the mean learning image, and each pixel's last unhidden observation.
//! The model is scored *relative to the observed frame* (its error minus the observed
//! frame's: below 0 when it shows more of the body than the camera did), so that a
//! reconstruction that faithfully copies the arm it sees scores 0, not a failure; and on
//! the one-step prior prediction, which no observation of its step has shaped.

use serde::{Deserialize, Serialize};

/// A pixel is hidden when a channel differs by more than this between the observed and the
/// robot-free image (model units, where 255 grey levels span 1.8: about 7 levels, above
/// anti-aliasing noise at the robot's edges).
pub const HIDDEN_THRESHOLD: f32 = 0.05;

/// Mean squared errors (model units) over every hidden value of a run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct OcclusionScores {
    /// Share of the top-resolution values hidden, over all steps.
    pub hidden_share: f64,
    /// The model's reconstruction against the robot-free truth.
    pub model: f64,
    /// The mean learning image against the robot-free truth.
    pub mean_image: f64,
    /// Each pixel's last unhidden observation (the mean image before its first) against
    /// the robot-free truth.
    pub last_seen: f64,
    /// The model's reconstruction against what was observed (the robot itself): small when
    /// the model draws the arm rather than the body behind it.
    pub model_vs_observed: f64,
    /// The observed frame (the arm) against the robot-free truth: the reference of the
    /// relative scores. Absent in results written before it was recorded.
    #[serde(default)]
    pub observed: Option<f64>,
    /// The one-step prior prediction (made at the step before, before this step's
    /// observation) against the robot-free truth, on the pixels hidden at its step.
    #[serde(default)]
    pub prior: Option<f64>,
    /// The observed frame against the truth on the pixels the prior is scored on: the
    /// prior's reference.
    #[serde(default)]
    pub observed_where_prior: Option<f64>,
}

impl OcclusionScores {
    /// d(model, body) - d(observed, body): negative when the reconstruction shows more of
    /// the hidden body than the camera did.
    pub fn model_relative(&self) -> Option<f64> {
        self.observed.map(|o| self.model - o)
    }

    /// The same for the prior prediction.
    pub fn prior_relative(&self) -> Option<f64> {
        Some(self.prior? - self.observed_where_prior?)
    }
}

/// Accumulates [`OcclusionScores`] step by step.
#[derive(Debug)]
pub struct OcclusionScorer {
    mean_image: Vec<f32>,
    last_seen: Vec<f32>,
    /// Squared errors: model, mean image, last seen, model vs observed, observed, prior,
    /// and observed on the pixels the prior is scored on.
    sums: [f64; 7],
    hidden: usize,
    /// Hidden values the prior prediction was scored on (all but the first step's).
    prior_scored: usize,
    total: usize,
}

impl OcclusionScorer {
    /// `mean_image`: the mean learning image at the top resolution (cameras x r x r x 3).
    pub fn new(mean_image: Vec<f32>) -> Self {
        Self {
            last_seen: mean_image.clone(),
            mean_image,
            sums: [0.0; 7],
            hidden: 0,
            prior_scored: 0,
            total: 0,
        }
    }

    /// One step's top-resolution images: observed, robot-free, the model's reconstruction,
    /// and the prior prediction of this step made at the step before (None at the first).
    pub fn step(&mut self, observed: &[f32], truth: &[f32], recon: &[f32], prior: Option<&[f32]>) {
        let prior_chunks = prior.map(|p| p.chunks(3));
        let mut prior_chunks = prior_chunks.into_iter().flatten();
        let pixels = observed
            .chunks(3)
            .zip(truth.chunks(3))
            .zip(recon.chunks(3))
            .zip(self.mean_image.chunks(3))
            .zip(self.last_seen.chunks_mut(3));
        for ((((obs, truth), recon), mean), last) in pixels {
            let prior = prior_chunks.next();
            self.total += obs.len();
            let hidden = obs
                .iter()
                .zip(truth)
                .any(|(a, b)| (a - b).abs() > HIDDEN_THRESHOLD);
            if !hidden {
                last.copy_from_slice(obs);
                continue;
            }
            self.hidden += obs.len();
            for c in 0..obs.len() {
                let sq = |a: f32, b: f32| ((a - b) as f64).powi(2);
                self.sums[0] += sq(recon[c], truth[c]);
                self.sums[1] += sq(mean[c], truth[c]);
                self.sums[2] += sq(last[c], truth[c]);
                self.sums[3] += sq(recon[c], obs[c]);
                self.sums[4] += sq(obs[c], truth[c]);
                if let Some(prior) = prior {
                    self.sums[5] += sq(prior[c], truth[c]);
                    self.sums[6] += sq(obs[c], truth[c]);
                }
            }
            if prior.is_some() {
                self.prior_scored += obs.len();
            }
        }
    }

    /// The scores, or None when nothing was hidden.
    pub fn finish(self) -> Option<OcclusionScores> {
        if self.hidden == 0 {
            return None;
        }
        let n = self.hidden as f64;
        Some(OcclusionScores {
            hidden_share: n / self.total as f64,
            model: self.sums[0] / n,
            mean_image: self.sums[1] / n,
            last_seen: self.sums[2] / n,
            model_vs_observed: self.sums[3] / n,
            observed: Some(self.sums[4] / n),
            prior: (self.prior_scored > 0).then(|| self.sums[5] / self.prior_scored as f64),
            observed_where_prior: (self.prior_scored > 0)
                .then(|| self.sums[6] / self.prior_scored as f64),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scores_only_hidden_pixels_against_the_truth_and_remembers_the_last_sight() {
        // Two pixels of one channel triple each; the body is 0.2 then 0.3 everywhere.
        let mut scorer = OcclusionScorer::new(vec![0.0; 6]);
        // Step 0: nothing hidden; the model is perfect.
        scorer.step(&[0.2; 6], &[0.2; 6], &[0.2; 6], None);
        // Step 1: the arm (0.9) hides pixel 1, whose body moved to 0.3 behind it; the model
        // draws the arm there.
        let observed = [0.2, 0.2, 0.2, 0.9, 0.9, 0.9];
        let truth = [0.2, 0.2, 0.2, 0.3, 0.3, 0.3];
        // The prior (made before the step) half-expected the body: 0.25 there.
        let prior = [0.2, 0.2, 0.2, 0.25, 0.25, 0.25];
        scorer.step(&observed, &truth, &observed, Some(&prior));
        // A difference under the threshold is not hidden.
        scorer.step(
            &[0.2; 6],
            &[0.2 + HIDDEN_THRESHOLD * 0.5; 6],
            &[0.2; 6],
            Some(&[0.2; 6]),
        );
        let s = scorer.finish().expect("something was hidden");
        let close = |a: f64, b: f64| (a - b).abs() < 1e-6;
        assert!(close(s.hidden_share, 3.0 / 18.0), "{s:?}");
        assert!(close(s.model, 0.36), "arm drawn over the body: {s:?}");
        assert!(close(s.model_vs_observed, 0.0), "{s:?}");
        // Relative to the observed frame, copying the arm scores 0, not a failure.
        assert!(close(s.observed.unwrap(), 0.36), "{s:?}");
        assert!(close(s.model_relative().unwrap(), 0.0), "{s:?}");
        assert!(close(s.prior.unwrap(), 0.0025), "{s:?}");
        // The prior's reference: the observed frame on the pixels the prior is scored on.
        assert!(close(s.observed_where_prior.unwrap(), 0.36), "{s:?}");
        assert!(close(s.prior_relative().unwrap(), 0.0025 - 0.36), "{s:?}");
        // Hidden at the first step (no prior yet) and later: each score keeps its pixels.
        let mut two = OcclusionScorer::new(vec![0.0; 3]);
        two.step(&[0.9; 3], &[0.2; 3], &[0.9; 3], None);
        two.step(&[0.5; 3], &[0.2; 3], &[0.5; 3], Some(&[0.2; 3]));
        let t = two.finish().unwrap();
        assert!(close(t.observed.unwrap(), (0.49 + 0.09) / 2.0), "{t:?}");
        assert!(close(t.observed_where_prior.unwrap(), 0.09), "{t:?}");
        assert!(close(t.prior_relative().unwrap(), -0.09), "{t:?}");
        assert!(close(s.mean_image, 0.09), "{s:?}");
        assert!(close(s.last_seen, 0.01), "last seen 0.2, truth 0.3: {s:?}");
        assert!(OcclusionScorer::new(vec![0.0; 3]).finish().is_none());
    }
}
