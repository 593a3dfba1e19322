//! safetensors files: models (spec tensor names, configuration as JSON metadata `config`),
//! checkpoints (a model plus optimiser state), gradients (`grad.` prefix), inputs
//! (`x_extero`, `x_proprio`) and inference runs.
//!
//! Every reader checks the header, dtypes, shapes and values and names the file and tensor
//! in its error; files are written to a temporary name and renamed, so an interrupted write
//! never leaves a half-written file under the real name.

use std::borrow::Cow;
use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use safetensors::tensor::{Metadata, TensorInfo};
use safetensors::{Dtype, SafeTensorError, View};
use serde::{Deserialize, Serialize};

use crate::config::{Modality, ModelConfig, ModuleId};
use crate::data::Observations;
use crate::error::{Error, Result};
use crate::free_energy::{FreeEnergy, Gradients};
use crate::infer::{InferenceSettings, ModuleStates, Run};
use crate::noise::NoiseMode;
use crate::optim::RAdam;
use crate::params::{Adaptive, Model, Params, Role};
use crate::train::{Trainer, trainable_names};
use crate::{Real, Tensor};

/// Identifies what kind of file a safetensors file is (metadata key `format`).
pub const MODEL_FORMAT: &str = "pvrnn-model/1";
pub const CHECKPOINT_FORMAT: &str = "pvrnn-checkpoint/1";
pub const RUN_FORMAT: &str = "pvrnn-inference/1";
const OPTIMIZER_PREFIX: &str = "radam.";
/// A model file's metadata key for the training iteration it was taken at
/// ([`save_model_at`]; a checkpoint keeps it in its learning state).
const TRAINED_ITERATIONS: &str = "trained_iterations";

/// A parsed safetensors file held in memory.
#[derive(Debug)]
pub struct TensorFile {
    what: String,
    bytes: Vec<u8>,
    data_start: usize,
    tensors: HashMap<String, TensorInfo>,
    metadata: HashMap<String, String>,
}

fn describe(e: SafeTensorError) -> String {
    match e {
        SafeTensorError::MetadataIncompleteBuffer | SafeTensorError::InvalidOffset(_) => {
            format!("the file is truncated or its header does not match its size ({e})")
        }
        SafeTensorError::HeaderTooSmall | SafeTensorError::HeaderTooLarge => {
            format!("the header is missing or corrupt ({e})")
        }
        other => other.to_string(),
    }
}

impl TensorFile {
    pub fn open(path: &Path) -> Result<Self> {
        let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        Self::from_bytes(bytes, path.display().to_string())
    }

    /// Parses a file already in memory (e.g. fetched in the browser); `what` names it in errors.
    pub fn from_bytes(bytes: Vec<u8>, what: impl Into<String>) -> Result<Self> {
        let what = what.into();
        let format_err = |detail: String| Error::Format {
            what: what.clone(),
            detail,
        };
        let (header_len, metadata): (usize, Metadata) =
            safetensors::SafeTensors::read_metadata(&bytes).map_err(|e| format_err(describe(e)))?;
        let data_start = 8 + header_len;
        let tensors: HashMap<String, TensorInfo> = metadata
            .tensors()
            .into_iter()
            .map(|(name, info)| (name, info.clone()))
            .collect();
        let meta = metadata.metadata().clone().unwrap_or_default();
        Ok(Self {
            what,
            bytes,
            data_start,
            tensors,
            metadata: meta,
        })
    }

    pub fn what(&self) -> &str {
        &self.what
    }
    pub fn metadata(&self, key: &str) -> Option<&str> {
        self.metadata.get(key).map(String::as_str)
    }
    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.tensors.keys().map(String::as_str)
    }
    pub fn contains(&self, name: &str) -> bool {
        self.tensors.contains_key(name)
    }
    pub fn shape(&self, name: &str) -> Option<&[usize]> {
        self.tensors.get(name).map(|i| i.shape.as_slice())
    }

    fn info(&self, name: &str) -> Result<&TensorInfo> {
        self.tensors.get(name).ok_or_else(|| Error::MissingTensor {
            what: self.what.clone(),
            name: name.into(),
        })
    }

    /// A tensor's shape and raw bytes, after checking its dtype is one of `dtypes` and its
    /// shape is `shape` (`None` = any).
    fn checked(
        &self,
        name: &str,
        dtypes: &[Dtype],
        expected: &'static str,
        shape: Option<&[usize]>,
    ) -> Result<(&TensorInfo, &[u8])> {
        let info = self.info(name)?;
        if !dtypes.contains(&info.dtype) {
            return Err(Error::Dtype {
                what: self.what.clone(),
                name: name.into(),
                found: format!("{:?}", info.dtype),
                expected,
            });
        }
        if let Some(shape) = shape
            && info.shape != shape
        {
            return Err(Error::Shape {
                what: self.what.clone(),
                name: name.into(),
                found: info.shape.clone(),
                expected: format!("{shape:?}"),
            });
        }
        let (a, b) = info.data_offsets;
        Ok((info, &self.bytes[self.data_start + a..self.data_start + b]))
    }

    /// An f32 tensor (F16 is widened), checked for shape (`None` = any) and finiteness.
    pub fn f32(&self, name: &str, shape: Option<&[usize]>) -> Result<Tensor<f32>> {
        let (info, raw) = self.checked(name, &[Dtype::F32, Dtype::F16], "F32", shape)?;
        let data: Vec<f32> = if info.dtype == Dtype::F16 {
            raw.chunks_exact(2)
                .map(|c| half::f16::from_le_bytes([c[0], c[1]]).to_f32())
                .collect()
        } else {
            raw.chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect()
        };
        let tensor = Tensor::from_vec(&info.shape, data).map_err(|_| Error::Format {
            what: self.what.clone(),
            detail: format!(
                "tensor `{name}` has {} bytes for shape {:?}",
                raw.len(),
                info.shape
            ),
        })?;
        if let Some((flat, value)) = tensor.first_non_finite() {
            return Err(Error::NonFinite {
                what: self.what.clone(),
                name: name.into(),
                index: tensor.unravel(flat),
                value: value as f64,
            });
        }
        Ok(tensor)
    }

    /// A U8 tensor (8-bit images), checked for shape (`None` = any); returns shape and bytes.
    pub fn u8(&self, name: &str, shape: Option<&[usize]>) -> Result<(Vec<usize>, Vec<u8>)> {
        let (info, raw) = self.checked(name, &[Dtype::U8], "U8", shape)?;
        Ok((info.shape.clone(), raw.to_vec()))
    }

    /// An integer tensor (I64 or I32) as `usize`s.
    pub fn indices(&self, name: &str) -> Result<Vec<usize>> {
        let (info, raw) = self.checked(name, &[Dtype::I64, Dtype::I32], "I64 or I32", None)?;
        // I64 or I32, as checked.
        let values: Vec<i64> = if info.dtype == Dtype::I64 {
            raw.chunks_exact(8)
                .map(|c| i64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]))
                .collect()
        } else {
            raw.chunks_exact(4)
                .map(|c| i32::from_le_bytes([c[0], c[1], c[2], c[3]]) as i64)
                .collect()
        };
        values
            .into_iter()
            .map(|v| {
                usize::try_from(v).map_err(|_| Error::Format {
                    what: self.what.clone(),
                    detail: format!("`{name}` holds the negative value {v}"),
                })
            })
            .collect()
    }
}

/// A tensor to write: f32 values (or f16, half the size), i64 indices or u8 bytes (images).
#[derive(Debug)]
pub enum OutTensor<'a> {
    F32(Vec<usize>, Cow<'a, [f32]>),
    F16(Vec<usize>, Vec<half::f16>),
    I64(Vec<usize>, Vec<i64>),
    U8(Vec<usize>, Cow<'a, [u8]>),
}

impl OutTensor<'_> {
    pub fn f32<T: Real>(t: &Tensor<T>) -> OutTensor<'static> {
        OutTensor::F32(
            t.shape().to_vec(),
            Cow::Owned(t.data().iter().map(|v| v.to_f32()).collect()),
        )
    }

    /// The tensor rounded to f16 (to nearest).
    pub fn f16<T: Real>(t: &Tensor<T>) -> OutTensor<'static> {
        OutTensor::F16(
            t.shape().to_vec(),
            t.data()
                .iter()
                .map(|v| half::f16::from_f32(v.to_f32()))
                .collect(),
        )
    }
}

fn f32_bytes(v: &[f32]) -> Cow<'_, [u8]> {
    if cfg!(target_endian = "little") {
        Cow::Borrowed(bytemuck::cast_slice(v))
    } else {
        Cow::Owned(v.iter().flat_map(|x| x.to_le_bytes()).collect())
    }
}

impl View for &OutTensor<'_> {
    fn dtype(&self) -> Dtype {
        match self {
            OutTensor::F32(..) => Dtype::F32,
            OutTensor::F16(..) => Dtype::F16,
            OutTensor::I64(..) => Dtype::I64,
            OutTensor::U8(..) => Dtype::U8,
        }
    }
    fn shape(&self) -> &[usize] {
        match self {
            OutTensor::F32(s, _)
            | OutTensor::F16(s, _)
            | OutTensor::I64(s, _)
            | OutTensor::U8(s, _) => s,
        }
    }
    fn data(&self) -> Cow<'_, [u8]> {
        match self {
            OutTensor::F32(_, v) => f32_bytes(v),
            OutTensor::F16(_, v) => Cow::Owned(v.iter().flat_map(|x| x.to_le_bytes()).collect()),
            OutTensor::I64(_, v) => Cow::Owned(v.iter().flat_map(|x| x.to_le_bytes()).collect()),
            OutTensor::U8(_, v) => Cow::Borrowed(v),
        }
    }
    fn data_len(&self) -> usize {
        match self {
            OutTensor::F32(_, v) => v.len() * 4,
            OutTensor::F16(_, v) => v.len() * 2,
            OutTensor::I64(_, v) => v.len() * 8,
            OutTensor::U8(_, v) => v.len(),
        }
    }
}

/// Serialises tensors and metadata to bytes. The header is canonical (keys sorted), so the
/// same tensors and metadata always give the same bytes.
pub fn to_bytes(
    tensors: &BTreeMap<String, OutTensor<'_>>,
    metadata: HashMap<String, String>,
) -> Result<Vec<u8>> {
    let bytes =
        safetensors::serialize(tensors.iter().map(|(k, v)| (k.as_str(), v)), Some(metadata))
            .map_err(|e| Error::Format {
                what: "serialising".into(),
                detail: e.to_string(),
            })?;
    Ok(canonical_header(bytes))
}

/// Rewrites a safetensors header with its JSON keys sorted (safetensors writes its metadata
/// map in hash order, which differs between runs). Data offsets are relative to the data
/// section, so only the header and its length change.
fn canonical_header(bytes: Vec<u8>) -> Vec<u8> {
    let n = u64::from_le_bytes(bytes[..8].try_into().expect("8-byte length")) as usize;
    let header: serde_json::Value =
        serde_json::from_slice(&bytes[8..8 + n]).expect("safetensors wrote valid JSON");
    // serde_json's map is ordered by key (no preserve_order feature).
    let mut json = serde_json::to_vec(&header).expect("serialisable");
    while !json.len().is_multiple_of(8) {
        json.push(b' ');
    }
    let mut out = Vec::with_capacity(8 + json.len() + bytes.len() - 8 - n);
    out.extend_from_slice(&(json.len() as u64).to_le_bytes());
    out.extend_from_slice(&json);
    out.extend_from_slice(&bytes[8 + n..]);
    out
}

/// Writes bytes to `path` atomically: a temporary file in the same folder, synced, renamed.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    use std::io::Write;
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = path
        .file_name()
        .ok_or_else(|| Error::InvalidArgument(format!("{}: not a file path", path.display())))?;
    let tmp = dir.join(format!(
        ".{}.{}.tmp",
        name.to_string_lossy(),
        std::process::id()
    ));
    let result = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    result.map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        Error::io(path, e)
    })
}

fn save(
    path: &Path,
    tensors: &BTreeMap<String, OutTensor<'_>>,
    metadata: HashMap<String, String>,
) -> Result<()> {
    write_atomic(path, &to_bytes(tensors, metadata)?)
}

fn model_tensors<T: Real>(model: &Model<T>, half: bool) -> BTreeMap<String, OutTensor<'static>> {
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

fn model_metadata(config: &ModelConfig, format: &str) -> HashMap<String, String> {
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
/// [`checkpoint_iteration`]): a trained network for inference without the optimiser
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
/// [`save_model_at`] was taken at (`None` for a plain model file or unreadable learning
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

/// A run's per-step tensors (without the sequence axis): file name, `[steps, width]` data
/// and width.
fn run_tensors<'a, T: Real>(
    config: &ModelConfig,
    run: &'a Run<T>,
) -> Vec<(String, &'a [T], usize)> {
    let mut v = Vec::new();
    for modality in Modality::ALL {
        let width = config.modality_dims(modality);
        if let Some(recon) = &run.recon {
            v.push((
                format!("recon.{}", modality.name()),
                recon[modality.index()].data(),
                width,
            ));
        }
        if let Some(prior) = &run.prior_next {
            v.push((
                format!("prior.{}", modality.name()),
                prior[modality.index()].data(),
                width,
            ));
        }
    }
    for id in ModuleId::ALL {
        let m = &run.modules[id.index()];
        let widths = ModuleStates::<T>::widths(config.module(id).z, config.module(id).d);
        for ((field, data), width) in ModuleStates::<T>::FIELDS.iter().zip(m.fields()).zip(widths) {
            v.push((format!("{}.{field}", id.name()), data.as_slice(), width));
        }
    }
    v
}

/// Per-step scalars of a run, with their file names.
fn run_scalars<T: Real>(run: &Run<T>) -> Vec<(String, Vec<f64>)> {
    let mut v = vec![(
        "free_energy.total".to_string(),
        run.free_energy
            .iter()
            .map(|f| f.total)
            .collect::<Vec<f64>>(),
    )];
    for modality in Modality::ALL {
        let (n, i) = (modality.name(), modality.index());
        v.push((
            format!("free_energy.accuracy.{n}"),
            run.free_energy
                .iter()
                .map(|f| {
                    if i == 0 {
                        f.accuracy.exteroceptive
                    } else {
                        f.accuracy.proprioceptive
                    }
                })
                .collect(),
        ));
        v.push((
            format!("step_accuracy.{n}"),
            run.step_accuracy.iter().map(|a| a[i]).collect(),
        ));
        v.push((
            format!("recon_error.{n}"),
            run.recon_error.iter().map(|a| a[i]).collect(),
        ));
    }
    for id in ModuleId::ALL {
        v.push((
            format!("free_energy.complexity.{}", id.name()),
            run.free_energy
                .iter()
                .map(|f| f.complexity_of(id))
                .collect(),
        ));
    }
    v
}

/// Writes inference runs of several sequences, stacked `[S, T_max, ...]` (shorter runs are
/// zero-padded; `lengths` gives each run's steps): per-module states, per-step free-energy
/// terms and errors, and the full read-outs `recon.*` / `prior.*` when the runs kept them.
pub fn save_runs<T: Real>(
    path: &Path,
    config: &ModelConfig,
    runs: &[Run<T>],
    sequence_ids: &[usize],
    sequence_names: Option<&[String]>,
) -> Result<()> {
    write_atomic(
        path,
        &runs_to_bytes(
            config,
            runs,
            sequence_ids,
            sequence_names,
            StateStorage::F32,
        )?,
    )
}

/// How a runs file stores the per-step states (the per-step scalars stay f32).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StateStorage {
    F32,
    /// f16: half the size, about 3 significant digits.
    F16,
    /// f16 rounded to nearest with only this many of its 10 mantissa bits (the rest zero):
    /// the same dtype for readers, but far more compressible (gzip), for states that are
    /// drawn rather than computed with. 6 bits keep the relative error within about 2^-7 = 0.8%.
    F16Mantissa(u32),
}

impl StateStorage {
    /// The value a reader gets back for `v`.
    pub fn round_trip(self, v: f32) -> f32 {
        match self {
            StateStorage::F32 => v,
            _ => self.to_f16(v).to_f32(),
        }
    }

    /// `v` as an f16 (F32 storage writes f32 and does not use this).
    pub fn to_f16(self, v: f32) -> half::f16 {
        let h = half::f16::from_f32(v);
        match self {
            StateStorage::F16Mantissa(bits) if bits < 10 && h.is_finite() => {
                let drop = 10 - bits;
                let raw = h.to_bits();
                // Round half up on the magnitude; a carry into the exponent is still the
                // nearest value (and saturates to infinity only beyond f16's range).
                let rounded =
                    (raw & 0x7fff).saturating_add(1 << (drop - 1)) & !((1u16 << drop) - 1);
                half::f16::from_bits((raw & 0x8000) | rounded.min(0x7c00))
            }
            _ => h,
        }
    }
}

/// [`save_runs`] into bytes; `storage` chooses how the per-step states are stored (f16:
/// half the size, about three significant digits: enough for viewing, e.g. the explorer's
/// precomputed runs).
pub fn runs_to_bytes<T: Real>(
    config: &ModelConfig,
    runs: &[Run<T>],
    sequence_ids: &[usize],
    sequence_names: Option<&[String]>,
    storage: StateStorage,
) -> Result<Vec<u8>> {
    let Some(first) = runs.first() else {
        return Err(Error::InvalidArgument("no inference runs to save".into()));
    };
    let s = runs.len();
    let t_max = runs.iter().map(Run::steps).max().unwrap_or(0);
    let mut tensors = BTreeMap::new();
    let layout = run_tensors(config, first);
    for (k, (name, _, width)) in layout.iter().enumerate() {
        let width = *width;
        let mut data = vec![0f32; s * t_max * width];
        for (i, run) in runs.iter().enumerate() {
            let (other, t, _) = &run_tensors(config, run)[k];
            if other != name || t.len() != run.steps() * width {
                return Err(Error::InvalidArgument(format!(
                    "run {i} does not match the first run's layout at {name} ({} numbers for {} steps of width {width})",
                    t.len(),
                    run.steps()
                )));
            }
            for (dst, src) in data[i * t_max * width..].iter_mut().zip(t.iter()) {
                *dst = src.to_f32();
            }
        }
        let tensor = if storage == StateStorage::F32 {
            OutTensor::F32(vec![s, t_max, width], Cow::Owned(data))
        } else {
            OutTensor::F16(
                vec![s, t_max, width],
                data.iter().map(|&v| storage.to_f16(v)).collect(),
            )
        };
        tensors.insert(name.clone(), tensor);
    }
    let scalar_names: Vec<String> = run_scalars(first).into_iter().map(|(n, _)| n).collect();
    for (k, name) in scalar_names.into_iter().enumerate() {
        let mut data = vec![0f32; s * t_max];
        for (i, run) in runs.iter().enumerate() {
            for (t, v) in run_scalars(run)[k].1.iter().enumerate() {
                data[i * t_max + t] = *v as f32;
            }
        }
        tensors.insert(name, OutTensor::F32(vec![s, t_max], Cow::Owned(data)));
    }
    tensors.insert(
        "lengths".into(),
        OutTensor::I64(vec![s], runs.iter().map(|r| r.steps() as i64).collect()),
    );
    tensors.insert(
        "sequence".into(),
        OutTensor::I64(vec![s], sequence_ids.iter().map(|&i| i as i64).collect()),
    );
    let mut meta = model_metadata(config, RUN_FORMAT);
    meta.insert(
        "settings".into(),
        serde_json::to_string(&first.settings).expect("serialisable"),
    );
    if let Some(names) = sequence_names {
        meta.insert(
            "sequence_names".into(),
            serde_json::to_string(names).expect("serialisable"),
        );
    }
    to_bytes(&tensors, meta)
}

/// A run read from a file, with the sequence it belongs to.
#[derive(Clone, Debug, PartialEq)]
pub struct LoadedRun {
    /// Index of the sequence in the inputs it was run on.
    pub sequence: usize,
    /// Its name, for runs on a dataset.
    pub name: Option<String>,
    pub run: Run<f32>,
}

/// Reads runs written by [`save_runs`].
pub fn load_runs(file: &TensorFile, config: &ModelConfig) -> Result<Vec<LoadedRun>> {
    let bad = |detail: &str| Error::Format {
        what: file.what().into(),
        detail: detail.into(),
    };
    let settings: InferenceSettings = file
        .metadata("settings")
        .and_then(|s| serde_json::from_str::<InferenceSettings>(s).ok())
        .map(InferenceSettings::canonical)
        .ok_or_else(|| bad("no valid `settings` metadata: not a pvrnn inference file"))?;
    let names: Option<Vec<String>> = match file.metadata("sequence_names") {
        Some(text) => {
            Some(serde_json::from_str(text).map_err(|_| bad("invalid `sequence_names` metadata"))?)
        }
        None => None,
    };
    let lengths = file.indices("lengths")?;
    let ids = file.indices("sequence")?;
    let s = lengths.len();
    if ids.len() != s || names.as_ref().is_some_and(|n| n.len() != s) {
        return Err(bad(
            "`lengths`, `sequence` and `sequence_names` disagree on the number of runs",
        ));
    }
    let t_max = lengths.iter().copied().max().unwrap_or(0);
    let read = |name: &str, width: usize| file.f32(name, Some(&[s, t_max, width]));
    let cut = |t: &Tensor<f32>, i: usize, len: usize| -> Tensor<f32> {
        let width = t.shape()[2];
        Tensor::from_vec(&[len, width], t.sub(&[i])[..len * width].to_vec()).expect("sized")
    };
    let optional = |prefix: &str| -> Result<Option<Vec<Tensor<f32>>>> {
        if !file.contains(&format!("{prefix}.exteroceptive")) {
            return Ok(None);
        }
        Modality::ALL
            .iter()
            .map(|m| read(&format!("{prefix}.{}", m.name()), config.modality_dims(*m)))
            .collect::<Result<Vec<_>>>()
            .map(Some)
    };
    let recon = optional("recon")?;
    let prior = optional("prior")?;
    let mut module_tensors = Vec::new();
    for id in ModuleId::ALL {
        let (d, z) = (config.module(id).d, config.module(id).z);
        let n = id.name();
        module_tensors.push([
            read(&format!("{n}.mu_p"), z)?,
            read(&format!("{n}.sigma_p"), z)?,
            read(&format!("{n}.mu_q"), z)?,
            read(&format!("{n}.sigma_q"), z)?,
            read(&format!("{n}.d"), d)?,
            read(&format!("{n}.prior_d"), d)?,
        ]);
    }
    let scalar = |name: &str| file.f32(name, Some(&[s, t_max]));
    let total = scalar("free_energy.total")?;
    let per_modality = |prefix: &str| -> Result<Vec<Tensor<f32>>> {
        Modality::ALL
            .iter()
            .map(|m| scalar(&format!("{prefix}.{}", m.name())))
            .collect()
    };
    let fe_acc = per_modality("free_energy.accuracy")?;
    let step_acc = per_modality("step_accuracy")?;
    let recon_err = per_modality("recon_error")?;
    let cx: Vec<Tensor<f32>> = ModuleId::ALL
        .iter()
        .map(|m| scalar(&format!("free_energy.complexity.{}", m.name())))
        .collect::<Result<_>>()?;
    let mut runs = Vec::with_capacity(s);
    for i in 0..s {
        let len = lengths[i];
        let at = |x: &Tensor<f32>, t: usize| x.data()[i * t_max + t] as f64;
        let pair = |x: &[Tensor<f32>], t: usize| [at(&x[0], t), at(&x[1], t)];
        let free_energy = (0..len)
            .map(|t| {
                let mut fe = FreeEnergy::from_terms(
                    pair(&fe_acc, t),
                    std::array::from_fn(|m| at(&cx[m], t)),
                    config.kl_weight,
                );
                // The stored total, not one recomputed from f32-rounded terms.
                fe.total = at(&total, t);
                fe
            })
            .collect();
        let both = |x: &Option<Vec<Tensor<f32>>>| {
            x.as_ref().map(|v| [cut(&v[0], i, len), cut(&v[1], i, len)])
        };
        runs.push(LoadedRun {
            sequence: ids[i],
            name: names.as_ref().map(|n| n[i].clone()),
            run: Run {
                settings: settings.clone(),
                recon: both(&recon),
                prior_next: both(&prior),
                modules: std::array::from_fn(|m| {
                    let [a, b, c, d, e, f] = &module_tensors[m];
                    let cut = |x: &Tensor<f32>| cut(x, i, len).into_data();
                    ModuleStates {
                        mu_p: cut(a),
                        sigma_p: cut(b),
                        mu_q: cut(c),
                        sigma_q: cut(d),
                        d: cut(e),
                        prior_d: cut(f),
                    }
                }),
                free_energy,
                step_accuracy: (0..len).map(|t| pair(&step_acc, t)).collect(),
                recon_error: (0..len).map(|t| pair(&recon_err, t)).collect(),
            },
        });
    }
    Ok(runs)
}

#[cfg(test)]
mod storage_tests {
    use super::StateStorage;

    #[test]
    fn a_shortened_mantissa_rounds_to_nearest_and_zeroes_the_dropped_bits() {
        let six = StateStorage::F16Mantissa(6);
        for i in 0..20_000 {
            let v = ((i as f32) * 0.7317).sin() * 3.0 + (i as f32 * 1e-4);
            let stored = six.to_f16(v);
            assert_eq!(stored.to_bits() & 0b1111, 0, "{v}");
            let err = (stored.to_f32() - v).abs();
            // Half an ulp of a 6-bit mantissa after f16's own rounding (half an ulp of 10
            // bits), plus f16's absolute precision near zero.
            assert!(
                err <= v.abs() * (2f32.powi(-7) + 2f32.powi(-11)) + 1e-7,
                "{v} -> {stored}"
            );
        }
        // Rounding up carries into the exponent: 1.99 -> 2.
        assert_eq!(six.to_f16(1.999).to_f32(), 2.0);
        assert_eq!(six.to_f16(-1.999).to_f32(), -2.0);
        assert_eq!(StateStorage::F16.to_f16(0.1), half::f16::from_f32(0.1));
    }
}
