//! Checkpoints: a model (loadable wherever a model is) plus RAdam's moments and the learning
//! state in its metadata, to continue a learning run where it stopped.

use std::borrow::Cow;
use std::path::Path;

use serde::{Deserialize, Serialize};

use super::model::{model_from_file, model_metadata, model_tensors};
use super::tensor_file::TensorFile;
use super::write::{OutTensor, save};
use super::{CHECKPOINT_FORMAT, OPTIMIZER_PREFIX, TRAINED_ITERATIONS};
use crate::Real;
use crate::error::{Error, Result};
use crate::free_energy::FreeEnergy;
use crate::noise::NoiseMode;
use crate::optim::RAdam;
use crate::params::Role;
use crate::train::{Trainer, trainable_names};

/// Learning state stored in a checkpoint's metadata.
#[derive(Clone, Debug, Serialize, Deserialize)]
struct TrainingState {
    iteration: u64,
    optimizer_step: u64,
    noise: NoiseMode,
    last_free_energy: Option<FreeEnergy>,
}

/// Saves a learning run: the model (loadable as a model) plus optimiser moments.
pub fn save_checkpoint<T: Real>(
    path: &Path,
    trainer: &mut Trainer<T>,
    last: Option<FreeEnergy>,
) -> Result<()> {
    let (iteration, noise) = (trainer.iteration, trainer.noise);
    // The device's tensors brought to the host, then checked: a device that failed would
    // have given values that mean nothing, and the last checkpoint must stay.
    trainer.state();
    trainer.check_device()?;
    let (model, optimizer) = trainer.state();
    let mut tensors = model_tensors(model, false);
    for ((name, m), v) in trainable_names(model)
        .into_iter()
        .zip(&optimizer.m)
        .zip(&optimizer.v)
    {
        let f = |x: &Vec<T>| {
            OutTensor::F32(
                vec![x.len()],
                Cow::Owned(x.iter().map(|v| v.to_f32()).collect()),
            )
        };
        tensors.insert(format!("{OPTIMIZER_PREFIX}m.{name}"), f(m));
        tensors.insert(format!("{OPTIMIZER_PREFIX}v.{name}"), f(v));
    }
    let mut meta = model_metadata(&model.config, CHECKPOINT_FORMAT);
    let state = TrainingState {
        iteration,
        optimizer_step: optimizer.step,
        noise,
        last_free_energy: last,
    };
    meta.insert(
        "training".into(),
        serde_json::to_string(&state).expect("serialisable"),
    );
    save(path, &tensors, meta)
}

/// Whether a file is a checkpoint (has learning state).
pub fn is_checkpoint(file: &TensorFile) -> bool {
    file.metadata("training").is_some()
}

/// The training iteration a checkpoint was written at, or a model saved with
/// [`save_model_at`](super::save_model_at) was taken at (`None` for a plain model file or unreadable learning
/// state).
pub fn checkpoint_iteration(file: &TensorFile) -> Option<u64> {
    match file.metadata("training") {
        Some(text) => serde_json::from_str::<TrainingState>(text)
            .ok()
            .map(|state| state.iteration),
        None => file.metadata(TRAINED_ITERATIONS)?.parse().ok(),
    }
}

/// Restores a learning run from a checkpoint, to continue on `backend`.
pub fn load_checkpoint_on(
    path: &Path,
    backend: Box<dyn crate::backend::Backend<f32>>,
) -> Result<Trainer<f32>> {
    Ok(load_checkpoint(path)?.with_backend(backend))
}

/// Restores a learning run from a checkpoint (on the CPU backend; see
/// [`load_checkpoint_on`]).
pub fn load_checkpoint(path: &Path) -> Result<Trainer<f32>> {
    checkpoint_from_file(&TensorFile::open(path)?)
}

/// A learning run from a checkpoint file's bytes (`what` names it in errors).
pub fn checkpoint_from_bytes(bytes: Vec<u8>, what: &str) -> Result<Trainer<f32>> {
    checkpoint_from_file(&TensorFile::from_bytes(bytes, what)?)
}

fn checkpoint_from_file(file: &TensorFile) -> Result<Trainer<f32>> {
    let model = model_from_file(file)?;
    let state: TrainingState = file
        .metadata("training")
        .ok_or_else(|| Error::Format {
            what: file.what().into(),
            detail: "no `training` metadata: a model, not a checkpoint (start a new run from it instead)".into(),
        })
        .and_then(|s| {
            serde_json::from_str(s).map_err(|e| Error::Format {
                what: file.what().into(),
                detail: format!("bad `training` metadata: {e}"),
            })
        })?;
    let names = trainable_names(&model);
    let sizes: Vec<usize> = {
        let mut v: Vec<usize> = model
            .params
            .named()
            .into_iter()
            .filter(|x| x.2 == Role::Trainable)
            .map(|x| x.1.len())
            .collect();
        v.extend(model.adaptive.named().into_iter().map(|x| x.1.len()));
        v
    };
    let mut optimizer = RAdam::new(model.config.train.optimizer.clone(), &sizes);
    optimizer.step = state.optimizer_step;
    for (i, (name, &n)) in names.iter().zip(&sizes).enumerate() {
        optimizer.m[i] = file
            .f32(&format!("{OPTIMIZER_PREFIX}m.{name}"), Some(&[n]))?
            .into_data();
        optimizer.v[i] = file
            .f32(&format!("{OPTIMIZER_PREFIX}v.{name}"), Some(&[n]))?
            .into_data();
    }
    Trainer::resume(model, optimizer, state.iteration, state.noise)
}
