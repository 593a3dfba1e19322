//! What the explorer shows: a model, a dataset, and runs computed in advance.
//!
//! A bundle folder (written by `pvrnn bundle`) holds `bundle.json` (with the model's card),
//! the model, the dataset (manifest and sequence files) and one runs file per precomputed
//! condition. The same pieces can come from a folder on disk, from files downloaded in the
//! browser, or from files a user drops.

use std::collections::HashMap;
use std::sync::Arc;

use pvrnn_core::backend::{Backend, LoadedModel};
use pvrnn_core::cpu::CpuBackend;
use pvrnn_core::io::{self, TensorFile};
use pvrnn_core::{Model, Observations};
use pvrnn_dataset::Dataset;
use pvrnn_dataset::card::ModelCard;
use pvrnn_dataset::inputs::{check_layout, ensure_normalisation};

use crate::condition::{Condition, RunKey};
use crate::runs::RunTrace;

pub use pvrnn_dataset::bundle::{BUNDLE_FORMAT, BUNDLE_MANIFEST, BundleManifest};

/// A model with the dataset it is explored on.
pub struct Bundle {
    pub description: String,
    /// The model's card, when the bundle has one.
    pub card: Option<ModelCard>,
    pub model: Arc<Model<f32>>,
    /// The model's weights on the backend that reads images and proprioception out of
    /// stored states.
    pub loaded: Arc<dyn LoadedModel<f32>>,
    pub dataset: Dataset,
    /// Runs computed in advance (e.g. by `pvrnn bundle`).
    pub precomputed: Vec<(RunKey, RunTrace)>,
    /// What loading it left out and why (shown in the status line).
    pub notes: Vec<String>,
    observations: HashMap<String, Arc<Observations<f32>>>,
}

impl std::fmt::Debug for Bundle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Bundle")
            .field("description", &self.description)
            .field("sequences", &self.dataset.sequences.len())
            .field("precomputed", &self.precomputed.len())
            .finish()
    }
}

impl Bundle {
    /// Checks that the model and the dataset fit together; a model without proprioception
    /// ranges gets the dataset's learning split's.
    pub fn new(
        description: String,
        mut model: Model<f32>,
        dataset: Dataset,
    ) -> Result<Self, String> {
        if dataset.sequences.is_empty() {
            return Err("the dataset holds no sequences".into());
        }
        check_layout(&dataset.manifest, &model.config.vision)
            .map_err(|e| format!("the model does not fit the dataset: {e}"))?;
        let layout = dataset.manifest.proprio_layout();
        if model.config.proprio_dims != layout.dims() {
            return Err(format!(
                "the model does not fit the dataset: it has {} proprioceptive dimensions, the data {} ({} joint angles, {} torques, {} extra channels)",
                model.config.proprio_dims,
                layout.dims(),
                layout.joints,
                layout.torques,
                layout.extra
            ));
        }
        ensure_normalisation(&mut model.config, &dataset).map_err(|e| e.to_string())?;
        Ok(Self {
            description,
            card: None,
            loaded: Arc::from(CpuBackend.load(&model.params, &model.config)),
            model: Arc::new(model),
            dataset,
            precomputed: Vec::new(),
            notes: Vec::new(),
            observations: HashMap::new(),
        })
    }

    /// Adds runs from a runs file. Runs that cannot be shown (an unknown sequence, a
    /// condition the explorer cannot express, a length that differs from the sequence's) are
    /// skipped, and a note says which and why.
    pub fn add_runs(&mut self, bytes: Vec<u8>, what: &str) -> Result<usize, String> {
        let file = TensorFile::from_bytes(bytes, what).map_err(|e| e.to_string())?;
        let runs = io::load_runs(&file, &self.model.config).map_err(|e| e.to_string())?;
        let mut added = 0;
        let mut skipped = Vec::new();
        for (index, loaded) in runs.into_iter().enumerate() {
            let name = loaded.name.clone().or_else(|| {
                self.dataset
                    .sequences
                    .get(loaded.sequence)
                    .map(|s| s.info.name.clone())
            });
            let Some(name) = name else {
                skipped.push(format!(
                    "run {index}: sequence {} is not in the data",
                    loaded.sequence
                ));
                continue;
            };
            let Some(seq) = self.dataset.by_name(&name) else {
                skipped.push(format!("run {index}: no sequence `{name}` in the data"));
                continue;
            };
            let Some(condition) = Condition::of(&loaded.run.settings, &self.model.config) else {
                skipped.push(format!(
                    "run {index} ({name}): its settings (e.g. noise off) are not a condition the explorer can show"
                ));
                continue;
            };
            if seq.len() != loaded.run.steps() {
                skipped.push(format!(
                    "run {index} ({name}): {} steps, the sequence has {}",
                    loaded.run.steps(),
                    seq.len()
                ));
                continue;
            }
            let trace = RunTrace::from_run(&loaded.run, &self.model.config, self.loaded.as_ref());
            self.precomputed.push((RunKey::new(name, condition), trace));
            added += 1;
        }
        if !skipped.is_empty() {
            self.notes.push(format!(
                "{what}: {} of {} runs skipped: {}",
                skipped.len(),
                skipped.len() + added,
                skipped.join("; ")
            ));
        }
        Ok(added)
    }

    /// A bundle from its files' bytes, by file name (as downloaded or dropped).
    pub fn from_files(files: &HashMap<String, Vec<u8>>) -> Result<Self, String> {
        let get = |name: &str| {
            files
                .get(name)
                .cloned()
                .ok_or_else(|| format!("{name} is missing"))
        };
        let manifest = BundleManifest::parse(&get(BUNDLE_MANIFEST)?, BUNDLE_MANIFEST)
            .map_err(|e| e.to_string())?;
        let model = io::model_from_bytes(get(&manifest.model)?, &manifest.model)
            .map_err(|e| e.to_string())?;
        let dataset_json = String::from_utf8(get(&manifest.dataset)?)
            .map_err(|_| format!("{} is not text", manifest.dataset))?;
        let dataset = Dataset::from_parts(&dataset_json, |name| {
            files
                .get(name)
                .cloned()
                .ok_or_else(|| pvrnn_dataset::Error::Format {
                    what: name.into(),
                    detail: "missing from the bundle".into(),
                })
        })
        .map_err(|e| e.to_string())?;
        let mut bundle = Self::new(manifest.description, model, dataset)?;
        bundle.card = manifest.card;
        for runs in &manifest.runs {
            bundle.add_runs(get(runs)?, runs)?;
        }
        Ok(bundle)
    }

    /// The files a bundle manifest names, in download order.
    pub fn files_of(manifest: &BundleManifest, dataset_json: &str) -> Result<Vec<String>, String> {
        let dataset: pvrnn_dataset::Manifest = serde_json::from_str(dataset_json)
            .map_err(|e| format!("{}: not a dataset manifest: {e}", manifest.dataset))?;
        let mut files = vec![manifest.model.clone()];
        files.extend(dataset.sequences.iter().map(|s| s.file.clone()));
        files.extend(manifest.runs.iter().cloned());
        Ok(files)
    }

    /// The files the first view needs, of those [`Self::files_of`] lists: the model, the
    /// sequence `wanted` (a view's, if the dataset has it; else the first), and the first
    /// runs file (the model's standard condition, as `pvrnn bundle` writes it).
    pub fn first_files(
        manifest: &BundleManifest,
        dataset_json: &str,
        wanted: Option<&str>,
    ) -> Result<Vec<String>, String> {
        let dataset: pvrnn_dataset::Manifest = serde_json::from_str(dataset_json)
            .map_err(|e| format!("{}: not a dataset manifest: {e}", manifest.dataset))?;
        let sequence = dataset
            .sequences
            .iter()
            .find(|s| Some(s.name.as_str()) == wanted)
            .or(dataset.sequences.first())
            .ok_or_else(|| format!("{}: no sequences", manifest.dataset))?;
        let mut files = vec![manifest.model.clone(), sequence.file.clone()];
        files.extend(manifest.runs.first().cloned());
        Ok(files)
    }

    /// The bundle as far as `files` hold it: the sequences and runs files that arrived
    /// (the first view, while the rest downloads); runs of sequences still on their way
    /// are left for the whole bundle, without a note.
    pub fn from_part_of_files(files: &HashMap<String, Vec<u8>>) -> Result<Self, String> {
        let manifest_bytes = files
            .get(BUNDLE_MANIFEST)
            .ok_or_else(|| format!("{BUNDLE_MANIFEST} is missing"))?;
        let mut manifest =
            BundleManifest::parse(manifest_bytes, BUNDLE_MANIFEST).map_err(|e| e.to_string())?;
        let dataset_bytes = files
            .get(&manifest.dataset)
            .ok_or_else(|| format!("{} is missing", manifest.dataset))?;
        let mut dataset: serde_json::Value = serde_json::from_slice(dataset_bytes)
            .map_err(|e| format!("{}: not JSON: {e}", manifest.dataset))?;
        if let Some(serde_json::Value::Array(sequences)) = dataset.get_mut("sequences") {
            sequences.retain(|s| {
                s.get("file")
                    .and_then(|f| f.as_str())
                    .is_some_and(|f| files.contains_key(f))
            });
        }
        manifest.runs.retain(|r| files.contains_key(r));
        let mut part = files.clone();
        part.insert(
            manifest.dataset.clone(),
            serde_json::to_vec(&dataset).map_err(|e| e.to_string())?,
        );
        part.insert(
            BUNDLE_MANIFEST.into(),
            serde_json::to_vec(&manifest).map_err(|e| e.to_string())?,
        );
        let mut bundle = Self::from_files(&part)?;
        bundle.notes.clear();
        Ok(bundle)
    }

    /// Opens a bundle folder, or a dataset folder with a model file beside it.
    #[cfg(not(target_arch = "wasm32"))]
    pub fn open_dir(dir: &std::path::Path) -> Result<Self, String> {
        let read = |name: &str| {
            std::fs::read(dir.join(name)).map_err(|e| format!("{}: {e}", dir.join(name).display()))
        };
        let manifest_path = dir.join(BUNDLE_MANIFEST);
        if !manifest_path.is_file() {
            return Err(format!(
                "{}: not a bundle folder (no {BUNDLE_MANIFEST}); make one with `pvrnn bundle`",
                dir.display()
            ));
        }
        let manifest = BundleManifest::parse(
            &read(BUNDLE_MANIFEST)?,
            &manifest_path.display().to_string(),
        )
        .map_err(|e| e.to_string())?;
        let model = io::load_model(&dir.join(&manifest.model)).map_err(|e| e.to_string())?;
        let dataset = Dataset::open(dir).map_err(|e| e.to_string())?;
        let mut bundle = Self::new(manifest.description.clone(), model, dataset)?;
        bundle.card = manifest.card;
        for runs in &manifest.runs {
            let path = dir.join(runs);
            bundle.add_runs(read(runs)?, &path.display().to_string())?;
        }
        Ok(bundle)
    }

    /// Adds a sequence (a driven episode) to the data, replacing one of the same name.
    pub fn replace_sequence(&mut self, sequence: pvrnn_dataset::Sequence) {
        self.remove_sequence(&sequence.info.name.clone());
        self.dataset.manifest.sequences.push(sequence.info.clone());
        self.dataset.sequences.push(sequence);
    }

    /// Takes a sequence (the episode being driven, when it ends) out of the data.
    pub fn remove_sequence(&mut self, name: &str) {
        self.observations.remove(name);
        self.dataset.sequences.retain(|s| s.info.name != name);
        self.dataset.manifest.sequences.retain(|s| s.name != name);
    }

    /// A sequence's model inputs (computed once, shared by its runs).
    pub fn observations(&mut self, name: &str) -> Result<Arc<Observations<f32>>, String> {
        if let Some(o) = self.observations.get(name) {
            return Ok(o.clone());
        }
        let seq = self
            .dataset
            .by_name(name)
            .ok_or_else(|| format!("no sequence `{name}`"))?;
        let obs = Arc::new(
            self.dataset
                .observations(&[seq], &self.model.config)
                .map_err(|e| e.to_string())?,
        );
        self.observations.insert(name.to_string(), obs.clone());
        Ok(obs)
    }
}
