//! Finishing a step: the final pass over the window, the step's outputs (read-outs, module
//! states, errors, the prior prediction of the next step), and sliding a full window.

use super::online::{OnlineInference, StepOutput};
use super::states::ModuleStates;
use crate::Real;
use crate::backend::{FullOutputs, Grads, Posterior, Request, Trace, Window};
use crate::config::{ModelConfig, ModuleId};
use crate::data::{Ablation, Observed};
use crate::error::{Error, Result};
use crate::free_energy::FreeEnergy;
use crate::noise::Stream;

impl<T: Real> OnlineInference<T> {
    /// Final pass over the window and the outputs of the step; slides the window.
    pub fn finish_step(&mut self) -> Result<StepOutput<T>> {
        if self.pending.is_none() {
            return Err(Error::InvalidArgument(
                "finish_step called without begin_step".into(),
            ));
        }
        crate::parallel::in_pool(|| {
            crate::deferred::now(async {
                self.iterate_here(usize::MAX).await?;
                self.finish_here().await
            })
        })
    }

    /// [`Self::finish_step`] on a backend whose results arrive through the browser's event
    /// loop (see [`Self::iterate_async`]).
    pub async fn finish_step_async(&mut self) -> Result<StepOutput<T>> {
        if self.pending.is_none() {
            return Err(Error::InvalidArgument(
                "finish_step called without begin_step".into(),
            ));
        }
        self.iterate_here(usize::MAX).await?;
        self.finish_here().await
    }

    async fn finish_here(&mut self) -> Result<StepOutput<T>> {
        let t = self.steps_done;
        let len = self.window_len();
        let config = self.model.config.clone();
        let eps = self.eps(Stream::InferFinal, &[t as u64], len);
        let ablation = self.settings.inference_ablation();
        let result = self
            .window_pass(&eps, ablation, Grads::None, FullOutputs::LastStep)
            .await?;
        let trace = &result.trace;
        let mut ablated_recon: Vec<[Vec<T>; 2]> = Vec::with_capacity(self.readout_ablations.len());
        for a in &self.readout_ablations {
            let pass = self
                .window_pass(&eps, *a, Grads::None, FullOutputs::LastStep)
                .await?;
            ablated_recon.push(pass.outputs);
        }
        // A `readout` ablation: the same pass re-read with z = 0; what the step reports.
        let readout = match self.settings.readout_only_ablation() {
            Some(a) => Some(
                self.window_pass(&eps, a, Grads::None, FullOutputs::LastStep)
                    .await?,
            ),
            None => None,
        };
        let reported = readout.as_ref().unwrap_or(&result);

        let mut accuracy = [0.0; 2];
        for (sum, per_step) in accuracy.iter_mut().zip(&result.accuracy) {
            *sum = per_step.iter().sum();
        }
        let complexity: [f64; 4] = std::array::from_fn(|m| trace.modules[m].kl.iter().sum());
        let window_free_energy = FreeEnergy::from_terms(accuracy, complexity, config.kl_weight);
        let (rate_halvings, gave_up) = self
            .pending
            .as_ref()
            .map_or((0, false), |p| (p.rate_halvings, p.gave_up));
        if gave_up || !window_free_energy.total.is_finite() {
            return Err(Error::Numerical(format!(
                "online inference diverged at step {t} (window free energy {:.4e}; restarted \
                 {rate_halvings} times at half the rate); try a smaller inference lr",
                window_free_energy.total
            )));
        }
        // A halved rate is for the step that needed it; the next step starts at the rate set.
        self.optimizer.config.lr = self.settings.optimizer.lr;
        let step_accuracy = [result.accuracy[0][len - 1], result.accuracy[1][len - 1]];
        let mut modules = last_step_states(&reported.trace, &config);
        let last_state = |tr: &Trace<T>, field: fn(&crate::backend::ModuleTrace<T>) -> &Vec<T>| {
            std::array::from_fn::<Vec<T>, 4, _>(|m| {
                let d = config.module(ModuleId::ALL[m]).d;
                field(&tr.modules[m])[(len - 1) * d..len * d].to_vec()
            })
        };
        // Inference continues from the standard pass ...
        self.last_h = last_state(trace, |m| &m.h);
        self.last_d = last_state(trace, |m| &m.d);
        // ... and the prior prediction starts from the state the step reports.
        let (prior_next, prior_d) = match &readout {
            Some(r) => {
                self.prior_prediction(
                    t,
                    &last_state(&r.trace, |m| &m.h),
                    &last_state(&r.trace, |m| &m.d),
                    self.settings.ablation,
                )
                .await?
            }
            None => {
                self.prior_prediction(t, &self.last_h, &self.last_d, ablation)
                    .await?
            }
        };
        for (states, d) in modules.iter_mut().zip(prior_d) {
            states.prior_d = d;
        }
        let recon = reported.outputs.clone();
        let recon_error: [f64; 2] = std::array::from_fn(|i| {
            let n = recon[i].len().max(1) as f64;
            recon[i]
                .iter()
                .zip(&self.latest[i])
                .map(|(a, b)| (*a - *b).to_f64().powi(2))
                .sum::<f64>()
                / n
        });

        if len == self.settings.window {
            self.slide(trace);
        }
        self.pending = None;
        self.steps_done += 1;
        Ok(StepOutput {
            t,
            recon,
            prior_next,
            modules,
            recon_error,
            window_free_energy,
            step_accuracy,
            ablated_recon,
            rate_halvings,
        })
    }

    /// Slides the full window: the state after its oldest step (from the step's standard
    /// pass, `trace`) is held, and that step's adaptive variables, moments and
    /// observations leave the window.
    fn slide(&mut self, trace: &Trace<T>) {
        let config = &self.model.config;
        self.held_h = Some(std::array::from_fn(|m| {
            let d = config.module(ModuleId::ALL[m]).d;
            trace.modules[m].h[..d].to_vec()
        }));
        for m in 0..4 {
            let z = self.z(m);
            self.a_mu[m].drain(..z);
            self.a_sigma[m].drain(..z);
            for opt_i in [m, m + 4] {
                self.optimizer.m[opt_i].drain(..z);
                self.optimizer.v[opt_i].drain(..z);
            }
        }
        for rows in &mut self.observations {
            rows.remove(0);
        }
        self.targets_id = crate::data::next_id();
    }

    /// x^_{t+1} from the prior: one generation step from the state after step t with
    /// z = mu_p + sigma_p * eps; also the modules' d in that step.
    async fn prior_prediction(
        &self,
        t: usize,
        last_h: &[Vec<T>; 4],
        last_d: &[Vec<T>; 4],
        ablation: Ablation,
    ) -> Result<([Vec<T>; 2], [Vec<T>; 4])> {
        let (pre_mu, pre_sigma) = self
            .loaded
            .prior_preactivations(std::array::from_fn(|m| last_d[m].as_slice()));
        let eps = self.eps(Stream::InferPrior, &[t as u64], 1);
        let window = Window {
            len: 1,
            h0: Some(std::array::from_fn(|m| last_h[m].as_slice())),
            posterior: Posterior::Adaptive {
                a_mu: std::array::from_fn(|m| pre_mu[m].as_slice()),
                a_sigma: std::array::from_fn(|m| pre_sigma[m].as_slice()),
            },
            eps: std::array::from_fn(|m| eps[m].as_slice()),
            targets: [Vec::new(), Vec::new()],
        };
        let request = Request {
            observed: Observed {
                vision_levels: 0,
                proprio: false,
            },
            ablation,
            grads: Grads::None,
            full_outputs: FullOutputs::LastStep,
            resident_targets: None,
        };
        let mut result = self
            .loaded
            .evaluate_async(std::slice::from_ref(&window), &request)
            .await?;
        let w = result.windows.pop().expect("one window");
        let [a, b, c, d] = w.trace.modules;
        Ok((w.outputs, [a.d, b.d, c.d, d.d]))
    }

    /// begin + all iterations + finish.
    pub fn step(&mut self, x_extero: &[T], x_proprio: &[T]) -> Result<StepOutput<T>> {
        self.begin_step(x_extero, x_proprio)?;
        self.finish_step()
    }
}

/// Module states at the window's newest step; `prior_d` is filled in by the caller.
fn last_step_states<T: Real>(trace: &Trace<T>, config: &ModelConfig) -> [ModuleStates<T>; 4] {
    let t = trace.len - 1;
    std::array::from_fn(|m| {
        let id = ModuleId::ALL[m];
        let (d, z) = (config.module(id).d, config.module(id).z);
        let mt = &trace.modules[m];
        let row = |v: &[T], w: usize| v[t * w..(t + 1) * w].to_vec();
        ModuleStates {
            mu_p: row(&mt.mu_p, z),
            sigma_p: mt.log_sigma_p[t * z..(t + 1) * z]
                .iter()
                .map(|x| x.exp())
                .collect(),
            mu_q: row(&mt.mu_q, z),
            sigma_q: row(&mt.sigma_q, z),
            d: row(&mt.d, d),
            prior_d: Vec::new(),
        }
    })
}
