//! Branching a run: the state of an online inference between two steps
//! ([`InferenceState`]), and continuing from it under other settings.

use super::online::OnlineInference;
use crate::Real;
use crate::config::{Modality, ModuleId};
use crate::error::{Error, Result};
use crate::optim::RAdam;

/// Where an online inference stands between two steps: everything it carries from one step
/// to the next except the model, the settings and the window's inputs (the caller has those
/// and passes them back to [`OnlineInference::continue_from`]). Taken at step t and
/// continued under other settings, it branches a run: the steps before t are shared, the
/// steps from t on are inferred under the new condition.
#[derive(Clone, Debug, PartialEq)]
pub struct InferenceState<T> {
    held_h: Option<[Vec<T>; 4]>,
    a_mu: [Vec<T>; 4],
    a_sigma: [Vec<T>; 4],
    last_h: [Vec<T>; 4],
    last_d: [Vec<T>; 4],
    optimizer: RAdam<T>,
    steps_done: usize,
    window_len: usize,
}

impl<T> InferenceState<T> {
    /// Steps finished when the state was taken: the next step is this one.
    pub fn steps_done(&self) -> usize {
        self.steps_done
    }

    /// Steps in the window (the inputs [`OnlineInference::continue_from`] needs: the
    /// `window_len` steps before [`Self::steps_done`]).
    pub fn window_len(&self) -> usize {
        self.window_len
    }
}

impl<T: Real> OnlineInference<T> {
    /// The state between two steps (an error inside a step).
    pub fn state(&self) -> Result<InferenceState<T>> {
        if self.in_step() {
            return Err(Error::InvalidArgument(
                "the inference state is taken between steps, not inside one".into(),
            ));
        }
        Ok(InferenceState {
            held_h: self.held_h.clone(),
            a_mu: self.a_mu.clone(),
            a_sigma: self.a_sigma.clone(),
            last_h: self.last_h.clone(),
            last_d: self.last_d.clone(),
            optimizer: self.optimizer.clone(),
            steps_done: self.steps_done,
            window_len: self.window_len(),
        })
    }

    /// Goes on under another observation from the next step on, as a branch of itself
    /// ([`Self::continue_from`] its own state): the window's steps are read again under
    /// `observed`, whose settings are checked against the model first. `window_inputs` as
    /// for [`Self::continue_from`]. On an error nothing changed.
    pub fn reobserve(
        &mut self,
        observed: crate::data::Observed,
        window_inputs: &[(&[T], &[T])],
    ) -> Result<()> {
        let state = self.state()?;
        let mut settings = self.settings.clone();
        settings.observed = observed;
        settings.validate(&self.model.config)?;
        let before = std::mem::replace(&mut self.settings, settings);
        let result = self.continue_from(state, window_inputs);
        if result.is_err() {
            self.settings = before;
        }
        result
    }

    /// Continues from `state` under this inference's settings: the next step is
    /// `state.steps_done()`. `window_inputs` are the whole observations (exteroceptive,
    /// proprioceptive) of the window's steps, oldest first; they are read under these
    /// settings' observation, since one window has one observation condition (a branch that
    /// drops vision at t infers its whole window without it). The optimiser keeps its
    /// moments and takes these settings' rate.
    pub fn continue_from(
        &mut self,
        state: InferenceState<T>,
        window_inputs: &[(&[T], &[T])],
    ) -> Result<()> {
        if self.in_step() {
            return Err(Error::InvalidArgument(
                "continue_from called inside a step".into(),
            ));
        }
        if state.window_len > self.settings.window {
            return Err(Error::InvalidArgument(format!(
                "the state's window holds {} steps, more than this inference's H = {}",
                state.window_len, self.settings.window
            )));
        }
        if window_inputs.len() != state.window_len {
            return Err(Error::Mismatch(format!(
                "continuing needs the inputs of the window's {} steps, got {}",
                state.window_len,
                window_inputs.len()
            )));
        }
        let config = &self.model.config;
        for m in 0..4 {
            let id = ModuleId::ALL[m];
            let (z, d) = (config.module(id).z, config.module(id).d);
            let fits = state.a_mu[m].len() == state.window_len * z
                && state.a_sigma[m].len() == state.window_len * z
                && state.last_d[m].len() == d
                && state.last_h[m].len() == d
                && state.held_h.as_ref().is_none_or(|h| h[m].len() == d);
            if !fits {
                return Err(Error::Mismatch(format!(
                    "the inference state does not fit this model's {} module (z = {z}, d = {d})",
                    id.name()
                )));
            }
        }
        let first = state.steps_done - state.window_len;
        let mut rows: [Vec<Vec<T>>; 2] = Default::default();
        for (i, (x_extero, x_proprio)) in window_inputs.iter().enumerate() {
            for (modality, x) in Modality::ALL.into_iter().zip([*x_extero, *x_proprio]) {
                let dims = config.modality_dims(modality);
                let k = self.settings.observed.dims(config, modality);
                let bad = x.len() != dims || x[..k].iter().any(|v| !v.is_finite());
                if bad {
                    return Err(Error::Mismatch(format!(
                        "step {}: the {} input has {} values (the model expects {dims}) or \
                         a non-finite observed value",
                        first + i,
                        modality.name(),
                        x.len()
                    )));
                }
                rows[modality.index()].push(x[..k].to_vec());
            }
        }
        self.latest = window_inputs
            .last()
            .map(|(e, p)| [e.to_vec(), p.to_vec()])
            .unwrap_or_default();
        self.observations = rows;
        self.held_h = state.held_h;
        self.a_mu = state.a_mu;
        self.a_sigma = state.a_sigma;
        self.last_h = state.last_h;
        self.last_d = state.last_d;
        self.optimizer = state.optimizer;
        self.optimizer.config = self.settings.optimizer.clone();
        self.steps_done = state.steps_done;
        self.targets_id = crate::data::next_id();
        Ok(())
    }
}
