//! A step's updates: passes over the window and RAdam updates of its adaptive variables, run
//! in slices; a window that diverges restarts the step at half the rate.

use super::online::{MAX_RATE_HALVINGS, OnlineInference};
use crate::Real;
use crate::backend::{FullOutputs, Grads, Posterior, Request, Window};
use crate::data::Ablation;
use crate::error::Result;
use crate::noise::Stream;

impl<T: Real> OnlineInference<T> {
    pub(super) async fn window_pass(
        &self,
        eps: &[Vec<T>; 4],
        ablation: Ablation,
        grads: Grads,
        full: FullOutputs,
    ) -> Result<crate::backend::WindowResult<T>> {
        let window = self.window(std::array::from_fn(|m| eps[m].as_slice()));
        let request = Request {
            observed: self.settings.observed,
            ablation,
            grads,
            full_outputs: full,
            resident_targets: Some(self.targets_id),
        };
        let mut result = self
            .loaded
            .evaluate_async(std::slice::from_ref(&window), &request)
            .await?;
        Ok(result.windows.pop().expect("one window"))
    }

    /// The window as it stands: its held state, its adaptive variables, its targets.
    fn window<'a>(&'a self, eps: [&'a [T]; 4]) -> Window<'a, T> {
        Window {
            len: self.window_len(),
            h0: self
                .held_h
                .as_ref()
                .map(|h| std::array::from_fn(|m| h[m].as_slice())),
            posterior: Posterior::Adaptive {
                a_mu: std::array::from_fn(|m| self.a_mu[m].as_slice()),
                a_sigma: std::array::from_fn(|m| self.a_sigma[m].as_slice()),
            },
            eps,
            targets: std::array::from_fn(|i| {
                self.observations[i].iter().map(Vec::as_slice).collect()
            }),
        }
    }

    pub(super) fn eps(&self, stream: Stream, tags: &[u64], len: usize) -> [Vec<T>; 4] {
        std::array::from_fn(|m| {
            let mut e = vec![T::ZERO; len * self.z(m)];
            let mut key = tags.to_vec();
            key.push(m as u64);
            self.settings.noise.fill(stream, &key, &mut e);
            e
        })
    }

    /// Runs up to `max` of the step's remaining updates; returns how many are left. Fails
    /// where the backend's device failed.
    pub fn iterate(&mut self, max: usize) -> Result<usize> {
        crate::parallel::in_pool(|| crate::deferred::now(self.iterate_here(max)))
    }

    /// [`Self::iterate`] on a backend whose results arrive through the browser's event loop
    /// (WebGPU; see [`crate::deferred`]). The same updates, in the same order.
    pub async fn iterate_async(&mut self, max: usize) -> Result<usize> {
        self.iterate_here(max).await
    }

    pub(super) async fn iterate_here(&mut self, max: usize) -> Result<usize> {
        let t = self.steps_done as u64;
        let mut ran = 0;
        while ran < max {
            let Some(pending) = self.pending.as_ref() else {
                return Ok(0);
            };
            let done = pending.iterations_done;
            if done >= self.settings.iterations {
                break;
            }
            let eps = self.eps(Stream::InferIteration, &[t, done as u64], self.window_len());
            let ablation = self.settings.inference_ablation();
            let result = self
                .window_pass(&eps, ablation, Grads::Adaptive, FullOutputs::None)
                .await?;
            let (Some(g_mu), Some(g_sigma)) = (result.grad_a_mu, result.grad_a_sigma) else {
                unreachable!("adaptive gradients requested")
            };
            ran += 1;
            let finite = result.accuracy.iter().flatten().all(|v| v.is_finite())
                && result
                    .trace
                    .modules
                    .iter()
                    .all(|m| m.kl.iter().all(|v| v.is_finite()))
                && g_mu
                    .iter()
                    .chain(g_sigma.iter())
                    .all(|g| g.iter().all(|v| v.is_finite()));
            if !finite {
                self.restart_step_at_half_rate();
                continue;
            }
            let grads: Vec<&[T]> = g_mu
                .iter()
                .chain(g_sigma.iter())
                .map(Vec::as_slice)
                .collect();
            let (mu, sigma) = (&mut self.a_mu, &mut self.a_sigma);
            let mut params: Vec<&mut [T]> = mu
                .iter_mut()
                .chain(sigma.iter_mut())
                .map(Vec::as_mut_slice)
                .collect();
            self.optimizer.update(&mut params, &grads);
            if let Some(pending) = self.pending.as_mut() {
                pending.iterations_done += 1;
            }
        }
        Ok(self.iterations_left())
    }

    /// The step's window diverged: back to the step's start with half the rate (the same
    /// noise draws again), or, after [`MAX_RATE_HALVINGS`] halvings, give up and let
    /// `finish_step` report it.
    fn restart_step_at_half_rate(&mut self) {
        let Some(pending) = self.pending.as_mut() else {
            return;
        };
        if pending.rate_halvings >= MAX_RATE_HALVINGS {
            pending.gave_up = true;
            pending.iterations_done = self.settings.iterations;
            return;
        }
        pending.rate_halvings += 1;
        pending.iterations_done = 0;
        let (a_mu, a_sigma, optimizer) = &pending.start;
        self.a_mu = a_mu.clone();
        self.a_sigma = a_sigma.clone();
        self.optimizer = optimizer.clone();
        self.optimizer.config.lr =
            self.settings.optimizer.lr / 2f64.powi(pending.rate_halvings as i32);
    }
}
