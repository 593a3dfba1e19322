//! The dataset format shared by the caresim benchmark and real robot recordings.
//!
//! A dataset is a folder:
//!
//! ```text
//! dataset.json                      manifest (format, image size, cameras, channel names, sequences)
//! <name>.safetensors                one file per sequence:
//!     images   u8  [T, cameras, S, S, 3]   8-bit RGB, row-major, pixel-interleaved
//!     joints   f32 [T, J]                  rad, the manifest's `joints` in order (the paper's
//!                                          robot: left arm joints 1-7, right arm joints 1-7)
//!     torques  f32 [T, K]                  N m, the manifest's `torques` (absent when K = 0)
//!     extra    f32 [T, E]                  any other channels, the manifest's `extra`
//!                                          (absent when E = 0)
//!     subtask  i64 [T]                     index into the sequence's `subtasks` names
//!   metadata `sequence`: the sequence's manifest entry as JSON (the file describes itself)
//! previews/<name>.png, .gif        optional contact sheet and animation
//! ```
//!
//! [`Dataset::observations`] turns sequences into model inputs exactly as the model spec's
//! "Data layout" says (see [`inputs`]). `docs/dataset.md` documents the format for users.
//!
//! - This module: the manifest ([`Manifest`]), a sequence in memory ([`Sequence`]), a whole
//!   dataset ([`Dataset`]), and a robot's proprioceptive channels by name ([`Channels`],
//!   [`ProprioLayout`]).
//! - [`inputs`]: from a dataset to model inputs (the resolution pyramid, normalisation, the
//!   learning split's ranges for models without their own).
//! - [`import`]: real robot recordings (frames and a proprioception CSV) into the format;
//!   [`resample`]: camera frames of any size to the dataset's square images.
//! - [`preview`]: a contact sheet (PNG) and an animation (GIF) of a sequence.
//! - [`bundle`]: the bundle manifest, `bundle.json`, that `pvrnn bundle` writes and the
//!   explorer reads; [`card`]: the model card inside it.
//! - [`synthetic`]: a small caresim-shaped dataset for tests.

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

pub use inputs::{Selection, proprio_noise_std, proprio_ranges};

/// Manifest format identifier.
pub const FORMAT: &str = "pvrnn-dataset/1";
pub const MANIFEST: &str = "dataset.json";
/// How many proprioceptive channels of each kind a robot has. The model's proprioceptive
/// vector is the joint angles, then the torques, then the extra channels, in the order the
/// dataset manifest names them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ProprioLayout {
    pub joints: usize,
    pub torques: usize,
    pub extra: usize,
}

impl ProprioLayout {
    /// The paper's robot: two 7-joint arms, a torque sensor in every joint.
    pub const PAPER: Self = Self {
        joints: 14,
        torques: 14,
        extra: 0,
    };

    /// Proprioceptive dimensions per step (the model's `proprio_dims`).
    pub fn dims(&self) -> usize {
        self.joints + self.torques + self.extra
    }

    /// Where the joint angles, torques and extra channels sit in the proprioceptive vector.
    pub fn ranges(&self) -> [std::ops::Range<usize>; 3] {
        let (j, k) = (self.joints, self.joints + self.torques);
        [0..j, j..k, k..self.dims()]
    }
}

/// The proprioceptive channels of a robot, by name: the columns `pvrnn import` reads and
/// the names a dataset manifest declares.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Channels {
    /// Joint angles, rad.
    pub joints: Vec<String>,
    /// Joint torques, N m (empty for a robot without torque sensing).
    #[serde(default)]
    pub torques: Vec<String>,
    /// Any other channels (a gripper's opening, a force sensor), in their own units.
    #[serde(default)]
    pub extra: Vec<String>,
}

impl Channels {
    /// The paper's robot: `left_q1..left_q7, right_q1..right_q7`, then
    /// `left_tau1..right_tau7`.
    pub fn paper() -> Self {
        let names = |kind: &str| -> Vec<String> {
            ["left", "right"]
                .iter()
                .flat_map(|arm| (1..=7).map(move |j| format!("{arm}_{kind}{j}")))
                .collect()
        };
        Self {
            joints: names("q"),
            torques: names("tau"),
            extra: Vec::new(),
        }
    }

    pub fn layout(&self) -> ProprioLayout {
        ProprioLayout {
            joints: self.joints.len(),
            torques: self.torques.len(),
            extra: self.extra.len(),
        }
    }

    /// Every channel name, in the proprioceptive vector's order.
    pub fn names(&self) -> impl Iterator<Item = &String> {
        self.joints.iter().chain(&self.torques).chain(&self.extra)
    }

    /// At least one channel, no name twice, none empty; `what` names the file in errors.
    pub fn validate(&self, what: &str) -> Result<()> {
        if self.layout().dims() == 0 {
            return Err(format_err(
                what,
                "names no proprioceptive channel (joints, torques or extra)",
            ));
        }
        let mut seen = std::collections::HashSet::new();
        for name in self.names() {
            if name.trim().is_empty() {
                return Err(format_err(
                    what,
                    "a proprioceptive channel has an empty name",
                ));
            }
            if !seen.insert(name) {
                return Err(format_err(
                    what,
                    format!("the channel name `{name}` appears twice"),
                ));
            }
        }
        Ok(())
    }
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
    /// Joint-angle channels (rad), in the order of the proprioceptive vector.
    pub joints: Vec<String>,
    /// Torque channels (N m); may be empty.
    pub torques: Vec<String>,
    /// Other proprioceptive channels, after the torques; absent when there are none.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub extra: Vec<String>,
    /// Free text: where the data comes from.
    #[serde(default)]
    pub source: String,
    pub sequences: Vec<SequenceInfo>,
}

impl Manifest {
    /// The proprioceptive channels the dataset declares.
    pub fn channels(&self) -> Channels {
        Channels {
            joints: self.joints.clone(),
            torques: self.torques.clone(),
            extra: self.extra.clone(),
        }
    }

    pub fn proprio_layout(&self) -> ProprioLayout {
        self.channels().layout()
    }
}

/// One recorded (or simulated) sequence in memory.
#[derive(Clone, Debug, PartialEq)]
pub struct Sequence {
    pub info: SequenceInfo,
    pub cameras: usize,
    pub image_size: usize,
    /// `[T, cameras, S, S, 3]`
    pub images: Vec<u8>,
    /// `[T, J]` rad
    pub joints: Vec<f32>,
    /// `[T, K]` N m (empty without torque sensing)
    pub torques: Vec<f32>,
    /// `[T, E]` other channels (usually empty)
    pub extra: Vec<f32>,
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
    /// Channels of each kind, from the data's sizes (checked against the manifest by
    /// [`Self::validate`]).
    pub fn proprio_layout(&self) -> ProprioLayout {
        let t = self.info.length.max(1);
        ProprioLayout {
            joints: self.joints.len() / t,
            torques: self.torques.len() / t,
            extra: self.extra.len() / t,
        }
    }

    /// Joint angles, then torques, then extra channels at step t: the raw proprioceptive
    /// vector.
    pub fn proprio(&self, t: usize) -> Vec<f32> {
        let l = self.proprio_layout();
        let row = |v: &[f32], n: usize| v[t * n..(t + 1) * n].to_vec();
        let mut out = row(&self.joints, l.joints);
        out.extend(row(&self.torques, l.torques));
        out.extend(row(&self.extra, l.extra));
        out
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
            extra: self.extra.clone(),
            subtask: self.subtask.clone(),
            images_without_robot: None,
        })
    }

    /// Checks sizes and values against a channel layout; `what` names the sequence in
    /// errors.
    pub fn validate(&self, what: &str, layout: ProprioLayout) -> Result<()> {
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
        expect("joints", self.joints.len(), t * layout.joints)?;
        expect("torques", self.torques.len(), t * layout.torques)?;
        expect("extra", self.extra.len(), t * layout.extra)?;
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
        for (name, v, n) in [
            ("joints", &self.joints, layout.joints),
            ("torques", &self.torques, layout.torques),
            ("extra", &self.extra, layout.extra),
        ] {
            if let Some(i) = v.iter().position(|x| !x.is_finite()) {
                return Err(format_err(
                    what,
                    format!(
                        "{name} holds a non-finite value at step {}, channel {}",
                        i / n,
                        i % n
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
        let layout = self.proprio_layout();
        // Joint angles always (a robot's only channels may be joints); the others only when
        // the robot has them, so the paper's files stay as they were.
        for (name, data, n) in [
            ("joints", &self.joints, layout.joints),
            ("torques", &self.torques, layout.torques),
            ("extra", &self.extra, layout.extra),
        ] {
            if n > 0 || name == "joints" {
                tensors.insert(
                    name.to_string(),
                    OutTensor::F32(vec![t, n], Cow::Borrowed(data)),
                );
            }
        }
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

    /// Reads a sequence file; `info` is the manifest's entry and `layout` its channels,
    /// both checked against the file.
    pub fn from_bytes(
        bytes: Vec<u8>,
        what: &str,
        info: &SequenceInfo,
        cameras: usize,
        image_size: usize,
        layout: ProprioLayout,
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
        let channels = |name: &str, n: usize| -> Result<Vec<f32>> {
            if n == 0 && !file.contains(name) {
                return Ok(Vec::new());
            }
            Ok(file.f32(name, Some(&[t, n]))?.into_data())
        };
        let joints = channels("joints", layout.joints)?;
        let torques = channels("torques", layout.torques)?;
        let extra = channels("extra", layout.extra)?;
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
            extra,
            subtask,
            images_without_robot,
        };
        seq.validate(what, layout)?;
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
    /// A dataset of the paper's robot (two 7-joint arms with torques): `sequences` must
    /// share camera count and image size.
    pub fn new(
        source: &str,
        cameras: Vec<String>,
        image_size: usize,
        sequences: Vec<Sequence>,
    ) -> Result<Self> {
        Self::with_channels(source, cameras, image_size, Channels::paper(), sequences)
    }

    /// A dataset of any robot: `sequences` must share camera count and image size and
    /// carry the named channels.
    pub fn with_channels(
        source: &str,
        cameras: Vec<String>,
        image_size: usize,
        channels: Channels,
        sequences: Vec<Sequence>,
    ) -> Result<Self> {
        channels.validate("the dataset's channels")?;
        let layout = channels.layout();
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
            s.validate(&s.info.name, layout)?;
        }
        let manifest = Manifest {
            format: FORMAT.into(),
            image_size,
            cameras,
            joints: channels.joints,
            torques: channels.torques,
            extra: channels.extra,
            source: source.into(),
            sequences: sequences.iter().map(|s| s.info.clone()).collect(),
        };
        Ok(Self {
            manifest,
            sequences,
        })
    }

    /// A dataset of some of this one's sequences (or others of the same robot): the same
    /// source, cameras, image size and channels.
    pub fn subset(&self, sequences: Vec<Sequence>) -> Result<Self> {
        let m = &self.manifest;
        Self::with_channels(
            &m.source,
            m.cameras.clone(),
            m.image_size,
            m.channels(),
            sequences,
        )
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
        let layout = manifest.proprio_layout();
        for info in &manifest.sequences {
            let (bytes, name) = read(info)?;
            sequences.push(Sequence::from_bytes(
                bytes,
                &name,
                info,
                manifest.cameras.len(),
                manifest.image_size,
                layout,
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
    manifest.channels().validate(what)?;
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
            extra: Vec::new(),
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
        let e = s
            .validate("s", ProprioLayout::PAPER)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("torques") && e.contains("step 1, channel 3"),
            "{e}"
        );
    }
}
