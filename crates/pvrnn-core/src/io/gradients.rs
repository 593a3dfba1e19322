//! Gradient files: d F / d every trainable tensor, each under its name with a `grad.` prefix.

use std::collections::BTreeMap;
use std::path::Path;

use super::model::model_metadata;
use super::write::{OutTensor, save};
use crate::Real;
use crate::config::ModelConfig;
use crate::error::Result;
use crate::free_energy::Gradients;
use crate::params::Role;

/// Writes d F / d every trainable tensor as `grad.<name>`.
pub fn save_gradients<T: Real>(
    path: &Path,
    grads: &Gradients<T>,
    config: &ModelConfig,
) -> Result<()> {
    let mut tensors = BTreeMap::new();
    for (name, t, role) in grads.params.named() {
        if role == Role::Trainable {
            tensors.insert(format!("grad.{name}"), OutTensor::f32(t));
        }
    }
    for (name, t) in grads.adaptive.named() {
        tensors.insert(format!("grad.{name}"), OutTensor::f32(t));
    }
    save(path, &tensors, model_metadata(config, "pvrnn-gradients/1"))
}
