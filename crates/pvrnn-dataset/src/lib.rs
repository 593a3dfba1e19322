//! The dataset format shared by the caresim benchmark and real robot recordings.
//!
//! A dataset is a folder:
//!
//! ```text
//! dataset.json                      manifest (format, image size, cameras, channel names, sequences)
//! <name>.safetensors                one file per sequence:
//!     images   u8  [T, cameras, S, S, 3]   8-bit RGB, row-major, pixel-interleaved
//!     joints   f32 [T, 14]                 rad: left arm joints 1-7, right arm joints 1-7
//!     torques  f32 [T, 14]                 N m: same order
//!     subtask  i64 [T]                     index into the sequence's `subtasks` names
//!   metadata `sequence`: the sequence's manifest entry as JSON (the file describes itself)
//! previews/<name>.png, .gif        optional contact sheet and animation
//! ```
//!
//! [`Dataset::observations`] turns sequences into model inputs exactly as the model spec's
//! "Data layout" says (see [`inputs`]). `docs/dataset.md` documents the format for users.

pub mod bundle;
pub mod card;
pub mod import;
pub mod inputs;
pub mod preview;
pub mod resample;
pub mod synthetic;

use std::borrow::Cow;
use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use pvrnn_core::io::{self, OutTensor, TensorFile};
use serde::{Deserialize, Serialize};

pub use inputs::{Selection, proprio_ranges};

/// Manifest format identifier.
pub const FORMAT: &str = "pvrnn-dataset/1";
pub const MANIFEST: &str = "dataset.json";
/// Joint angles per step (two 7-joint arms); as many torques follow them.
pub const JOINTS: usize = 14;
/// Joint angles and torques per step.
pub const PROPRIO_DIMS: usize = 2 * JOINTS;

/// Names of the 14 joints, left arm then right arm.
pub fn joint_names() -> Vec<String> {
    ["left", "right"]
        .iter()
        .flat_map(|arm| (1..=7).map(move |j| format!("{arm}_q{j}")))
        .collect()
}

/// Names of the 14 torques, same order as the joints.
pub fn torque_names() -> Vec<String> {
    ["left", "right"]
        .iter()
        .flat_map(|arm| (1..=7).map(move |j| format!("{arm}_tau{j}")))
        .collect()
}

/// Everything that can go wrong reading or writing datasets and recordings.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("{path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    /// A file that is not what it should be; `what` names it.
    #[error("{what}: {detail}")]
    Format { what: String, detail: String },
    #[error(transparent)]
    Core(#[from] pvrnn_core::Error),
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

pub(crate) fn io_err(path: &Path, source: std::io::Error) -> Error {
    Error::Io {
        path: path.display().to_string(),
        source,
    }
}

pub(crate) fn format_err(what: impl std::fmt::Display, detail: impl Into<String>) -> Error {
    Error::Format {
        what: what.to_string(),
        detail: detail.into(),
    }
}

/// Learning or test sequence.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Split {
    Learn,
    Test,
}

impl Split {
    pub fn name(self) -> &'static str {
        match self {
            Split::Learn => "learn",
            Split::Test => "test",
        }
    }
}

/// A sequence's manifest entry.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SequenceInfo {
    pub name: String,
    /// File name inside the dataset folder.
    pub file: String,
    /// e.g. `repositioning`, `wiping`.
    pub task: String,
    #[serde(default)]
    pub bed_height_mm: Option<f64>,
    pub split: Split,
    /// The simulation seed (absent for real recordings).
    #[serde(default)]
    pub seed: Option<u64>,
    pub length: usize,
    /// Names of the subtasks the per-step `subtask` labels index.
    #[serde(default)]
    pub subtasks: Vec<String>,
}

/// The dataset manifest, `dataset.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    pub format: String,
    /// Square image size of every camera.
    pub image_size: usize,
    pub cameras: Vec<String>,
    pub joints: Vec<String>,
    pub torques: Vec<String>,
    /// Free text: where the data comes from.
    #[serde(default)]
    pub source: String,
    pub sequences: Vec<SequenceInfo>,
}

/// One recorded (or simulated) sequence in memory.
#[derive(Clone, Debug, PartialEq)]
pub struct Sequence {
    pub info: SequenceInfo,
    pub cameras: usize,
    pub image_size: usize,
    /// `[T, cameras, S, S, 3]`
    pub images: Vec<u8>,
    /// `[T, 14]` rad
    pub joints: Vec<f32>,
    /// `[T, 14]` N m
    pub torques: Vec<f32>,
    /// `[T]`
    pub subtask: Vec<u32>,
    /// `[T, cameras, S, S, 3]`: the same frames rendered without the robot, where a
    /// simulator can (caresim's `--robot-free`), so that what the arms hide can be scored.
    pub images_without_robot: Option<Vec<u8>>,
}

impl Sequence {
    pub fn len(&self) -> usize {
        self.info.length
    }
    pub fn is_empty(&self) -> bool {
        self.info.length == 0
    }
    /// One camera's image at step t, `[S, S, 3]`.
    pub fn image(&self, t: usize, camera: usize) -> &[u8] {
        let n = self.image_size * self.image_size * 3;
        let start = (t * self.cameras + camera) * n;
        &self.images[start..start + n]
    }
    /// Joint angles (14) then torques (14) at step t: the raw proprioceptive vector.
    pub fn proprio(&self, t: usize) -> [f32; PROPRIO_DIMS] {
        let mut v = [0.0; PROPRIO_DIMS];
        v[..14].copy_from_slice(&self.joints[t * 14..(t + 1) * 14]);
        v[14..].copy_from_slice(&self.torques[t * 14..(t + 1) * 14]);
        v
    }

    /// The same sequence seen without the robot (its robot-free renders as the images), if
    /// it has them.
    pub fn without_robot(&self) -> Option<Sequence> {
        let images = self.images_without_robot.clone()?;
        Some(Sequence {
            info: self.info.clone(),
            cameras: self.cameras,
            image_size: self.image_size,
            images,
            joints: self.joints.clone(),
            torques: self.torques.clone(),
            subtask: self.subtask.clone(),
            images_without_robot: None,
        })
    }

    /// Checks sizes and values; `what` names the sequence in errors.
    pub fn validate(&self, what: &str) -> Result<()> {
        let t = self.info.length;
        let expect = |name: &str, got: usize, want: usize| {
            if got == want {
                Ok(())
            } else {
                Err(format_err(
                    what,
                    format!("{name} has {got} values, expected {want} for {t} steps"),
                ))
            }
        };
        expect(
            "images",
            self.images.len(),
            t * self.cameras * self.image_size * self.image_size * 3,
        )?;
        expect("joints", self.joints.len(), t * 14)?;
        expect("torques", self.torques.len(), t * 14)?;
        expect("subtask", self.subtask.len(), t)?;
        if let Some(hidden) = &self.images_without_robot {
            expect(
                "images_without_robot",
                hidden.len(),
                self.images.len() / t.max(1) * t,
            )?;
        }
        if t == 0 {
            return Err(format_err(what, "the sequence has no steps"));
        }
        for (name, v) in [("joints", &self.joints), ("torques", &self.torques)] {
            if let Some(i) = v.iter().position(|x| !x.is_finite()) {
                return Err(format_err(
                    what,
                    format!(
                        "{name} holds a non-finite value at step {}, channel {}",
                        i / 14,
                        i % 14
                    ),
                ));
            }
        }
        if !self.info.subtasks.is_empty()
            && let Some(&bad) = self
                .subtask
                .iter()
                .find(|&&s| s as usize >= self.info.subtasks.len())
        {
            return Err(format_err(
                what,
                format!(
                    "subtask label {bad} but only {} subtasks are named",
                    self.info.subtasks.len()
                ),
            ));
        }
        Ok(())
    }

    /// The sequence as a safetensors file (self-describing: its info is the metadata).
    pub fn to_bytes(&self) -> Result<Vec<u8>> {
        let t = self.info.length;
        let s = self.image_size;
        let mut tensors = BTreeMap::new();
        tensors.insert(
            "images".to_string(),
            OutTensor::U8(vec![t, self.cameras, s, s, 3], Cow::Borrowed(&self.images)),
        );
        tensors.insert(
            "joints".to_string(),
            OutTensor::F32(vec![t, 14], Cow::Borrowed(&self.joints)),
        );
        tensors.insert(
            "torques".to_string(),
            OutTensor::F32(vec![t, 14], Cow::Borrowed(&self.torques)),
        );
        tensors.insert(
            "subtask".to_string(),
            OutTensor::I64(vec![t], self.subtask.iter().map(|&x| x as i64).collect()),
        );
        if let Some(hidden) = &self.images_without_robot {
            tensors.insert(
                "images_without_robot".to_string(),
                OutTensor::U8(vec![t, self.cameras, s, s, 3], Cow::Borrowed(hidden)),
            );
        }
        let meta = HashMap::from([
            ("format".to_string(), format!("{FORMAT}/sequence")),
            (
                "sequence".to_string(),
                serde_json::to_string(&self.info).expect("serialisable"),
            ),
        ]);
        Ok(io::to_bytes(&tensors, meta)?)
    }

    /// Reads a sequence file; `info` is the manifest's entry, checked against the file.
    pub fn from_bytes(
        bytes: Vec<u8>,
        what: &str,
        info: &SequenceInfo,
        cameras: usize,
        image_size: usize,
    ) -> Result<Self> {
        let file = TensorFile::from_bytes(bytes, what)?;
        let t = info.length;
        let shape = [t, cameras, image_size, image_size, 3];
        let (_, images) = file.u8("images", Some(&shape))?;
        let images_without_robot = if file.contains("images_without_robot") {
            Some(file.u8("images_without_robot", Some(&shape))?.1)
        } else {
            None
        };
        let joints = file.f32("joints", Some(&[t, 14]))?.into_data();
        let torques = file.f32("torques", Some(&[t, 14]))?.into_data();
        let subtask: Vec<u32> = file
            .indices("subtask")?
            .into_iter()
            .map(|s| s as u32)
            .collect();
        let seq = Sequence {
            info: info.clone(),
            cameras,
            image_size,
            images,
            joints,
            torques,
            subtask,
            images_without_robot,
        };
        seq.validate(what)?;
        Ok(seq)
    }
}

/// A dataset in memory.
#[derive(Clone, Debug, PartialEq)]
pub struct Dataset {
    pub manifest: Manifest,
    pub sequences: Vec<Sequence>,
}

impl Dataset {
    /// A dataset of `sequences`, which must share camera count and image size.
    pub fn new(
        source: &str,
        cameras: Vec<String>,
        image_size: usize,
        sequences: Vec<Sequence>,
    ) -> Result<Self> {
        for s in &sequences {
            if s.cameras != cameras.len() || s.image_size != image_size {
                return Err(format_err(
                    &s.info.name,
                    format!(
                        "{} cameras of {}x{} but the dataset has {} of {image_size}x{image_size}",
                        s.cameras,
                        s.image_size,
                        s.image_size,
                        cameras.len()
                    ),
                ));
            }
            s.validate(&s.info.name)?;
        }
        let manifest = Manifest {
            format: FORMAT.into(),
            image_size,
            cameras,
            joints: joint_names(),
            torques: torque_names(),
            source: source.into(),
            sequences: sequences.iter().map(|s| s.info.clone()).collect(),
        };
        Ok(Self {
            manifest,
            sequences,
        })
    }

    /// Reads `dataset.json` and every sequence file of a dataset folder.
    pub fn open(dir: &Path) -> Result<Self> {
        let manifest_path = dir.join(MANIFEST);
        let text =
            std::fs::read_to_string(&manifest_path).map_err(|e| io_err(&manifest_path, e))?;
        let manifest = parse_manifest(&text, &manifest_path.display().to_string())?;
        Self::with_sequences(manifest, |info| {
            let path = dir.join(&info.file);
            let bytes = std::fs::read(&path).map_err(|e| io_err(&path, e))?;
            Ok((bytes, path.display().to_string()))
        })
    }

    /// Builds a dataset from a manifest and a way to fetch each sequence file's bytes (for
    /// the browser, where files are downloaded).
    pub fn from_parts(
        manifest_json: &str,
        mut fetch: impl FnMut(&str) -> Result<Vec<u8>>,
    ) -> Result<Self> {
        let manifest = parse_manifest(manifest_json, MANIFEST)?;
        Self::with_sequences(manifest, |info| Ok((fetch(&info.file)?, info.file.clone())))
    }

    /// Loads every sequence of `manifest`; `read` gives a file's bytes and the name its
    /// errors should carry.
    fn with_sequences(
        manifest: Manifest,
        mut read: impl FnMut(&SequenceInfo) -> Result<(Vec<u8>, String)>,
    ) -> Result<Self> {
        let mut sequences = Vec::with_capacity(manifest.sequences.len());
        for info in &manifest.sequences {
            let (bytes, name) = read(info)?;
            sequences.push(Sequence::from_bytes(
                bytes,
                &name,
                info,
                manifest.cameras.len(),
                manifest.image_size,
            )?);
        }
        Ok(Self {
            manifest,
            sequences,
        })
    }

    /// Writes the dataset (sequence files first, the manifest last, each atomically).
    pub fn write(&self, dir: &Path) -> Result<()> {
        std::fs::create_dir_all(dir).map_err(|e| io_err(dir, e))?;
        for s in &self.sequences {
            io::write_atomic(&dir.join(&s.info.file), &s.to_bytes()?)?;
        }
        let json = serde_json::to_string_pretty(&self.manifest).expect("serialisable");
        io::write_atomic(&dir.join(MANIFEST), json.as_bytes())?;
        Ok(())
    }

    /// Sequences of one split (or all), in manifest order.
    pub fn split(&self, split: Option<Split>) -> Vec<&Sequence> {
        self.sequences
            .iter()
            .filter(|s| split.is_none_or(|sp| s.info.split == sp))
            .collect()
    }

    pub fn by_name(&self, name: &str) -> Option<&Sequence> {
        self.sequences.iter().find(|s| s.info.name == name)
    }
}

fn parse_manifest(text: &str, what: &str) -> Result<Manifest> {
    let manifest: Manifest = serde_json::from_str(text)
        .map_err(|e| format_err(what, format!("not a valid dataset manifest: {e}")))?;
    if manifest.format != FORMAT {
        return Err(format_err(
            what,
            format!("format `{}`, expected `{FORMAT}`", manifest.format),
        ));
    }
    if manifest.joints.len() != 14 || manifest.torques.len() != 14 {
        return Err(format_err(what, "needs 14 joint and 14 torque names"));
    }
    if manifest.cameras.is_empty() || manifest.image_size == 0 {
        return Err(format_err(
            what,
            "needs at least one camera and a non-zero image size",
        ));
    }
    let mut names = std::collections::HashSet::new();
    for s in &manifest.sequences {
        if !names.insert(&s.name) {
            return Err(format_err(
                what,
                format!("sequence name `{}` appears twice", s.name),
            ));
        }
    }
    Ok(manifest)
}

/// A file name for a sequence: lower-case letters, digits, `-` and `_` only.
pub fn file_stem(name: &str) -> String {
    name.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c.to_ascii_lowercase()
            } else {
                '_'
            }
        })
        .collect()
}

/// The folder of a dataset path's previews.
pub fn previews_dir(dataset: &Path) -> PathBuf {
    dataset.join("previews")
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(crate) fn sequence(name: &str, split: Split, t: usize, seed: u8) -> Sequence {
        Sequence {
            info: SequenceInfo {
                name: name.into(),
                file: format!("{}.safetensors", file_stem(name)),
                task: "repositioning".into(),
                bed_height_mm: Some(650.0),
                split,
                seed: Some(seed as u64),
                length: t,
                subtasks: vec!["a".into(), "b".into()],
            },
            cameras: 2,
            image_size: 4,
            images: (0..t * 2 * 4 * 4 * 3)
                .map(|i| (i as u8).wrapping_mul(seed))
                .collect(),
            joints: (0..t * 14)
                .map(|i| (i as f32 * 0.01 + seed as f32).sin())
                .collect(),
            torques: (0..t * 14)
                .map(|i| (i as f32 * 0.02).cos() * seed as f32)
                .collect(),
            subtask: (0..t).map(|i| (i * 2 / t) as u32).collect(),
            images_without_robot: None,
        }
    }

    #[test]
    fn write_and_open_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let ds = Dataset::new(
            "test",
            vec!["left".into(), "right".into()],
            4,
            vec![
                sequence("A 1", Split::Learn, 5, 3),
                sequence("b", Split::Test, 7, 5),
            ],
        )
        .unwrap();
        ds.write(dir.path()).unwrap();
        let back = Dataset::open(dir.path()).unwrap();
        assert_eq!(back, ds);
        assert_eq!(back.split(Some(Split::Test)).len(), 1);
        assert_eq!(back.sequences[0].info.file, "a_1.safetensors");
    }

    #[test]
    fn bad_files_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let ds = Dataset::new(
            "t",
            vec!["l".into(), "r".into()],
            4,
            vec![sequence("s", Split::Learn, 5, 3)],
        )
        .unwrap();
        ds.write(dir.path()).unwrap();
        // A sequence file that does not match the manifest's length.
        let mut m = ds.manifest.clone();
        m.sequences[0].length = 6;
        std::fs::write(
            dir.path().join(MANIFEST),
            serde_json::to_string(&m).unwrap(),
        )
        .unwrap();
        let e = Dataset::open(dir.path()).unwrap_err().to_string();
        assert!(
            e.contains("s.safetensors") && e.contains("images") && e.contains("[6, 2, 4, 4, 3]"),
            "{e}"
        );
        // A missing sequence file.
        std::fs::remove_file(dir.path().join("s.safetensors")).unwrap();
        let e = Dataset::open(dir.path()).unwrap_err().to_string();
        assert!(
            e.contains("s.safetensors") && e.contains("No such file"),
            "{e}"
        );
        // A broken manifest.
        std::fs::write(dir.path().join(MANIFEST), "{\"format\": 3}").unwrap();
        let e = Dataset::open(dir.path()).unwrap_err().to_string();
        assert!(
            e.contains("dataset.json") && e.contains("not a valid dataset manifest"),
            "{e}"
        );
        // No manifest at all.
        let e = Dataset::open(&dir.path().join("nowhere"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("dataset.json"), "{e}");
    }

    #[test]
    fn non_finite_proprioception_is_rejected() {
        let mut s = sequence("s", Split::Learn, 3, 1);
        s.torques[17] = f32::NAN;
        let e = s.validate("s").unwrap_err().to_string();
        assert!(
            e.contains("torques") && e.contains("step 1, channel 3"),
            "{e}"
        );
    }
}
