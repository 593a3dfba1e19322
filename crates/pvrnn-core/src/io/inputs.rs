//! Input files: a model's observations (`x_extero`, `x_proprio` and optional `lengths`),
//! read and checked, or written.

use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use super::tensor_file::TensorFile;
use super::write::{OutTensor, save};
use crate::Real;
use crate::config::Modality;
use crate::data::Observations;
use crate::error::{Error, Result};

/// Reads `x_extero [S, T, vision]`, `x_proprio [S, T, 28]` and optional `lengths [S]`.
pub fn load_observations(path: &Path) -> Result<Observations<f32>> {
    observations_from_file(&TensorFile::open(path)?)
}

pub fn observations_from_file(file: &TensorFile) -> Result<Observations<f32>> {
    let extero = file.f32("x_extero", None)?;
    let proprio = file.f32("x_proprio", None)?;
    let lengths = if file.contains("lengths") {
        Some(file.indices("lengths")?)
    } else {
        None
    };
    Observations::new(extero, proprio, lengths).map_err(|e| match e {
        Error::Shape {
            name,
            found,
            expected,
            ..
        } => Error::Shape {
            what: file.what().into(),
            name,
            found,
            expected,
        },
        Error::Mismatch(m) => Error::Mismatch(format!("{}: {m}", file.what())),
        other => other,
    })
}

pub fn save_observations<T: Real>(path: &Path, obs: &Observations<T>) -> Result<()> {
    let mut tensors = BTreeMap::new();
    tensors.insert(
        "x_extero".into(),
        OutTensor::f32(obs.tensor(Modality::Exteroceptive)),
    );
    tensors.insert(
        "x_proprio".into(),
        OutTensor::f32(obs.tensor(Modality::Proprioceptive)),
    );
    tensors.insert(
        "lengths".into(),
        OutTensor::I64(
            vec![obs.sequences()],
            obs.lengths().iter().map(|&l| l as i64).collect(),
        ),
    );
    save(
        path,
        &tensors,
        HashMap::from([("format".into(), "pvrnn-inputs/1".into())]),
    )
}
