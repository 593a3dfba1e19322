//! Model files: a model's weights and adaptive variables under the spec's tensor names and
//! its configuration as JSON metadata (`config`), written in f32 or f16 and read back as
//! f32 after every tensor is checked.

use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use super::tensor_file::TensorFile;
use super::write::{OutTensor, save, to_bytes};
use super::{MODEL_FORMAT, OPTIMIZER_PREFIX, TRAINED_ITERATIONS};
use crate::Real;
use crate::config::{ModelConfig, ModuleId};
use crate::error::{Error, Result};
use crate::params::{Adaptive, Model, Params};

pub(super) fn model_tensors<T: Real>(
    model: &Model<T>,
    half: bool,
) -> BTreeMap<String, OutTensor<'static>> {
    let store = if half { OutTensor::f16 } else { OutTensor::f32 };
    let mut out = BTreeMap::new();
    for (name, t, _) in model.params.named() {
        out.insert(name, store(t));
    }
    for (name, t) in model.adaptive.named() {
        out.insert(name, store(t));
    }
    out
}

pub(super) fn model_metadata(config: &ModelConfig, format: &str) -> HashMap<String, String> {
    HashMap::from([
        ("config".to_string(), config.to_json()),
        ("format".to_string(), format.to_string()),
    ])
}

/// A model as safetensors bytes.
pub fn model_to_bytes<T: Real>(model: &Model<T>) -> Result<Vec<u8>> {
    to_bytes(
        &model_tensors(model, false),
        model_metadata(&model.config, MODEL_FORMAT),
    )
}

/// [`model_to_bytes`] with every tensor rounded to f16: half the size, for shipping a
/// model whose measured error from the rounding is negligible (loading widens to f32).
pub fn model_to_bytes_f16<T: Real>(model: &Model<T>) -> Result<Vec<u8>> {
    to_bytes(
        &model_tensors(model, true),
        model_metadata(&model.config, MODEL_FORMAT),
    )
}

pub fn save_model<T: Real>(path: &Path, model: &Model<T>) -> Result<()> {
    save(
        path,
        &model_tensors(model, false),
        model_metadata(&model.config, MODEL_FORMAT),
    )
}

/// [`save_model`] recording the training iteration the network was taken at (read back by
/// [`checkpoint_iteration`](super::checkpoint_iteration)): a trained network for inference without the optimiser
/// moments a checkpoint carries, a third of its size.
pub fn save_model_at<T: Real>(path: &Path, model: &Model<T>, iteration: u64) -> Result<()> {
    let mut meta = model_metadata(&model.config, MODEL_FORMAT);
    meta.insert(TRAINED_ITERATIONS.into(), iteration.to_string());
    save(path, &model_tensors(model, false), meta)
}

pub fn load_model(path: &Path) -> Result<Model<f32>> {
    model_from_file(&TensorFile::open(path)?)
}

pub fn model_from_bytes(bytes: Vec<u8>, what: &str) -> Result<Model<f32>> {
    model_from_file(&TensorFile::from_bytes(bytes, what)?)
}

/// Reads and checks a model (also accepts a checkpoint, ignoring its optimiser state).
pub fn model_from_file(file: &TensorFile) -> Result<Model<f32>> {
    let config_json = file.metadata("config").ok_or_else(|| Error::Format {
        what: file.what().into(),
        detail: "no `config` metadata: not a pvrnn model file".into(),
    })?;
    let config = ModelConfig::from_json(config_json).map_err(|e| Error::Format {
        what: file.what().into(),
        detail: format!("its configuration is invalid: {e}"),
    })?;
    let mut params = Params::<f32>::zeros(&config);
    let mut expected: Vec<String> = Vec::new();
    for (name, t, _) in params.named_mut() {
        let shape = t.shape().to_vec();
        *t = file.f32(&name, Some(&shape))?;
        expected.push(name);
    }
    // The adaptive variables fix S and T; every module must agree.
    let a0 = format!("{}.a_mu", ModuleId::Executive.name());
    let (s, steps) = match file.shape(&a0) {
        Some(&[s, t, _]) => (s, t),
        Some(other) => {
            return Err(Error::Shape {
                what: file.what().into(),
                name: a0,
                found: other.to_vec(),
                expected: "[sequences, steps, z]".into(),
            });
        }
        None => {
            return Err(Error::MissingTensor {
                what: file.what().into(),
                name: a0,
            });
        }
    };
    let mut adaptive = Adaptive::zeros(&config, s, steps);
    for (name, t) in adaptive.named_mut() {
        let shape = t.shape().to_vec();
        *t = file.f32(&name, Some(&shape))?;
        expected.push(name);
    }
    for name in file.names() {
        if !expected.iter().any(|e| e == name) && !name.starts_with(OPTIMIZER_PREFIX) {
            return Err(Error::UnexpectedTensor {
                what: file.what().into(),
                name: name.into(),
            });
        }
    }
    Ok(Model {
        config,
        params,
        adaptive,
    })
}
