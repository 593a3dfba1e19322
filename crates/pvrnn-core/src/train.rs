//! Learning (eq. 17): full-batch RAdam on every weight and every training sequence's
//! adaptive variables.

use crate::Real;
use crate::backend::Backend;
use crate::cpu::CpuBackend;
use crate::data::Observations;
use crate::error::{Error, Result};
use crate::free_energy::{FreeEnergy, NoiseDraw, free_energy};
use crate::noise::NoiseMode;
use crate::optim::RAdam;
use crate::params::{Model, Role};

/// A learning run: the model, its optimiser state and how far it got.
#[derive(Debug)]
pub struct Trainer<T: Real> {
    pub model: Model<T>,
    pub optimizer: RAdam<T>,
    /// Completed iterations.
    pub iteration: u64,
    pub noise: NoiseMode,
    backend: Box<dyn Backend<T>>,
}

/// Names of the tensors the optimiser updates, in its order.
pub fn trainable_names<T: Real>(model: &Model<T>) -> Vec<String> {
    let mut names: Vec<String> = model
        .params
        .named()
        .into_iter()
        .filter(|(_, _, role)| *role == Role::Trainable)
        .map(|(n, _, _)| n)
        .collect();
    names.extend(model.adaptive.named().into_iter().map(|(n, _)| n));
    names
}

fn trainable_sizes<T: Real>(model: &Model<T>) -> Vec<usize> {
    let mut sizes: Vec<usize> = model
        .params
        .named()
        .into_iter()
        .filter(|(_, _, role)| *role == Role::Trainable)
        .map(|(_, t, _)| t.len())
        .collect();
    sizes.extend(model.adaptive.named().into_iter().map(|(_, t)| t.len()));
    sizes
}

impl<T: Real> Trainer<T> {
    /// A new run with fresh optimiser moments.
    pub fn new(model: Model<T>, noise: NoiseMode) -> Self {
        let optimizer = RAdam::new(
            model.config.train.optimizer.clone(),
            &trainable_sizes(&model),
        );
        Self {
            model,
            optimizer,
            iteration: 0,
            noise,
            backend: Box::new(CpuBackend),
        }
    }

    /// Continues a run from saved state.
    pub fn resume(
        model: Model<T>,
        optimizer: RAdam<T>,
        iteration: u64,
        noise: NoiseMode,
    ) -> Result<Self> {
        let sizes = trainable_sizes(&model);
        let fits = optimizer.m.len() == sizes.len()
            && optimizer.v.len() == sizes.len()
            && optimizer
                .m
                .iter()
                .zip(&optimizer.v)
                .zip(&sizes)
                .all(|((m, v), &n)| m.len() == n && v.len() == n);
        if !fits {
            return Err(Error::Mismatch(
                "the optimiser state does not match the model's tensors".into(),
            ));
        }
        Ok(Self {
            model,
            optimizer,
            iteration,
            noise,
            backend: Box::new(CpuBackend),
        })
    }

    /// Replaces the arithmetic backend.
    pub fn with_backend(mut self, backend: Box<dyn Backend<T>>) -> Self {
        self.backend = backend;
        self
    }

    /// The arithmetic the trainer runs on (also for scoring its model as it goes).
    pub fn backend(&self) -> &dyn Backend<T> {
        self.backend.as_ref()
    }

    /// One full-batch iteration; returns the free energy at which the gradient was taken.
    pub fn step(&mut self, data: &Observations<T>) -> Result<FreeEnergy> {
        crate::parallel::in_pool(|| self.step_here(data))
    }

    fn step_here(&mut self, data: &Observations<T>) -> Result<FreeEnergy> {
        let draw = NoiseDraw::training(self.noise, self.iteration);
        let (report, grads) = free_energy(self.backend.as_ref(), &self.model, data, draw, true)?;
        let grads = grads.expect("gradients requested");
        if !report.total.is_finite() {
            return Err(Error::Numerical(format!(
                "the free energy became {} at iteration {}: learning diverged (try a smaller train.optimizer.lr)",
                report.total, self.iteration
            )));
        }
        let mut grad_slices: Vec<&[T]> = grads
            .params
            .named()
            .into_iter()
            .filter(|(_, _, role)| *role == Role::Trainable)
            .map(|(_, t, _)| t.data())
            .collect();
        grad_slices.extend(grads.adaptive.named().into_iter().map(|(_, t)| t.data()));
        let mut param_slices: Vec<&mut [T]> = Vec::new();
        for (_, t, role) in self.model.params.named_mut() {
            if role == Role::Trainable {
                param_slices.push(t.data_mut());
            }
        }
        for (_, t) in self.model.adaptive.named_mut() {
            param_slices.push(t.data_mut());
        }
        self.optimizer.update(&mut param_slices, &grad_slices);
        self.iteration += 1;
        Ok(report)
    }
}
