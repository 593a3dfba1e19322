//! Files a user drops on the window: a bundle, a model, a dataset, runs, in any mix.

use std::collections::BTreeMap;

use pvrnn_core::io::{self, TensorFile};
use pvrnn_dataset::Dataset;

use crate::bundle::{BUNDLE_MANIFEST, Bundle};

/// A dropped file: its name, and its bytes or why they could not be read.
pub type DroppedFile = (String, Result<Vec<u8>, String>);

/// Reads dropped files natively; a dropped folder contributes the files directly in it.
#[cfg(not(target_arch = "wasm32"))]
pub fn read_dropped(dropped: &[eframe::egui::DroppedFileHandle]) -> Vec<DroppedFile> {
    let mut out = Vec::new();
    for f in dropped {
        let path = f.path();
        if path.is_dir() {
            read_folder(path, &mut out);
        } else {
            out.push((file_name(path), f.bytes()));
        }
    }
    out
}

/// Reads files and folders by path (a file dialog's choice), as [`read_dropped`] does.
#[cfg(not(target_arch = "wasm32"))]
pub fn read_paths(paths: &[std::path::PathBuf]) -> Vec<DroppedFile> {
    let mut out = Vec::new();
    for path in paths {
        if path.is_dir() {
            read_folder(path, &mut out);
        } else {
            out.push((
                file_name(path),
                std::fs::read(path).map_err(|e| format!("{}: {e}", path.display())),
            ));
        }
    }
    out
}

/// The files directly in a folder (not its sub-folders), sorted by name.
#[cfg(not(target_arch = "wasm32"))]
fn read_folder(folder: &std::path::Path, out: &mut Vec<DroppedFile>) {
    let Ok(entries) = std::fs::read_dir(folder) else {
        out.push((
            folder.display().to_string(),
            Err("cannot read the folder".into()),
        ));
        return;
    };
    let mut files: Vec<std::path::PathBuf> = entries
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.is_file())
        .collect();
    files.sort();
    for p in files {
        let bytes = std::fs::read(&p).map_err(|e| format!("{}: {e}", p.display()));
        out.push((file_name(&p), bytes));
    }
}

#[cfg(not(target_arch = "wasm32"))]
fn file_name(path: &std::path::Path) -> String {
    path.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// What a dropped safetensors file is.
fn kind(file: &TensorFile) -> &'static str {
    match file.metadata("format") {
        Some(io::MODEL_FORMAT) | Some(io::CHECKPOINT_FORMAT) => "model",
        Some(io::RUN_FORMAT) => "runs",
        _ if file.metadata("sequence").is_some() => "sequence",
        _ if file.metadata("config").is_some() => "model",
        _ => "unknown",
    }
}

/// Builds what to show from dropped files, keeping the parts of `current` they do not
/// replace. Every message names the file that does not fit.
pub fn assemble(files: Vec<DroppedFile>, current: Option<&Bundle>) -> Result<Bundle, String> {
    // Sorted by name, so what is read and what an error names never depend on hash order.
    let mut bytes: BTreeMap<String, Vec<u8>> = BTreeMap::new();
    for (name, data) in files {
        bytes.insert(name.clone(), data.map_err(|e| format!("{name}: {e}"))?);
    }
    if bytes.contains_key(BUNDLE_MANIFEST) {
        return Bundle::from_files(&bytes.into_iter().collect());
    }
    let mut model: Option<(String, _)> = None;
    let mut runs = Vec::new();
    for (name, data) in &bytes {
        if name.ends_with(".safetensors") {
            let file =
                TensorFile::from_bytes(data.clone(), name.as_str()).map_err(|e| e.to_string())?;
            match kind(&file) {
                "model" => {
                    if let Some((first, _)) = &model {
                        return Err(format!(
                            "{first} and {name} are both models: drop one model at a time"
                        ));
                    }
                    let m = io::model_from_file(&file).map_err(|e| e.to_string())?;
                    model = Some((name.clone(), m));
                }
                "runs" => runs.push(name.clone()),
                "sequence" => {}
                _ => {
                    return Err(format!(
                        "{name}: neither a model, a run file, nor a dataset sequence"
                    ));
                }
            }
        }
    }
    let dataset = match bytes.get(pvrnn_dataset::MANIFEST) {
        Some(json) => {
            let json = String::from_utf8(json.clone())
                .map_err(|_| "dataset.json is not text".to_string())?;
            Dataset::from_parts(&json, |file| {
                bytes.get(file).cloned().ok_or_else(|| pvrnn_dataset::Error::Format {
                    what: file.into(),
                    detail: "dataset.json lists it, but it was not dropped (drop the whole dataset folder)".into(),
                })
            })
            .map_err(|e| e.to_string())?
        }
        None => current
            .map(|b| b.dataset.clone())
            .ok_or("drop a dataset folder (dataset.json and its sequence files) too")?,
    };
    let model = match model {
        Some((_, m)) => m,
        None => current
            .map(|b| (*b.model).clone())
            .ok_or("drop a model file (.safetensors) too")?,
    };
    let description = current
        .filter(|_| bytes.is_empty())
        .map(|b| b.description.clone())
        .unwrap_or_else(|| "dropped files".into());
    let mut bundle = Bundle::new(description, model, dataset)?;
    for name in runs {
        bundle.add_runs(bytes[&name].clone(), &name)?;
    }
    Ok(bundle)
}
