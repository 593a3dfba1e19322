//! Import of real robot recordings into the dataset format.
//!
//! The layout (documented in `docs/dataset.md`):
//!
//! ```text
//! <recordings>/
//!   recordings.json             optional: the robot's layout, {"cameras": ["left", "right"],
//!                               "image_size": 64, "joints": [...], "torques": [...],
//!                               "extra": [...]}; every field optional, the paper's robot
//!                               by default (see [`RecordingLayout`])
//!   <sequence>/                 every sub-folder holding a meta.json is one sequence
//!     meta.json                 {"task": "wiping", "split": "learn" | "test",
//!                                "bed_height_mm": 650, "subtasks": ["reaching", ...]}
//!     left/  000000.png ...     frames of each camera, PNG or JPEG, any size; ordered by
//!     right/ 000000.jpg ...     the number in the file name, which must run without gaps
//!     proprio.csv               header, then one row per frame with a column for every
//!                               channel the layout names (by default left_q1..left_q7,
//!                               right_q1..right_q7 in rad, left_tau1..right_tau7 in N m),
//!                               optionally `subtask` (an index into meta.json's subtasks);
//!                               other columns (e.g. a timestamp) are ignored
//! ```
//!
//! Frames are centre-cropped to a square and area-resampled to the dataset's image size.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::resample::square_area_resample;
use crate::{Channels, Dataset, Result, Sequence, SequenceInfo, Split, format_err, io_err};

/// A recording's `meta.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecordingMeta {
    pub task: String,
    pub split: Split,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bed_height_mm: Option<f64>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub subtasks: Vec<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed: Option<u64>,
}

/// What a robot's recordings hold: camera folders, the square image size to import at, and
/// the proprioceptive channels (the CSV columns) by name. On disk, `recordings.json` at the
/// root of a recordings folder ([`LayoutFile`]).
#[derive(Clone, Debug, PartialEq)]
pub struct RecordingLayout {
    /// Camera folder names, in the order the model sees them.
    pub cameras: Vec<String>,
    /// Square image size after centre crop and area resampling.
    pub image_size: usize,
    /// Joint angles, torques and extra channels: the CSV columns, in the model's order.
    pub channels: Channels,
}

/// `recordings.json`: every field optional. Without any channel list the channels are the
/// paper's robot's; with one, the lists not given are empty (a robot without torque
/// sensing lists only `joints`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LayoutFile {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cameras: Option<Vec<String>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub image_size: Option<usize>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub joints: Option<Vec<String>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub torques: Option<Vec<String>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub extra: Option<Vec<String>>,
}

impl From<LayoutFile> for RecordingLayout {
    fn from(f: LayoutFile) -> Self {
        let paper = Self::default();
        let channels = if f.joints.is_none() && f.torques.is_none() && f.extra.is_none() {
            paper.channels
        } else {
            Channels {
                joints: f.joints.unwrap_or_default(),
                torques: f.torques.unwrap_or_default(),
                extra: f.extra.unwrap_or_default(),
            }
        };
        Self {
            cameras: f.cameras.unwrap_or(paper.cameras),
            image_size: f.image_size.unwrap_or(paper.image_size),
            channels,
        }
    }
}

impl From<&RecordingLayout> for LayoutFile {
    fn from(l: &RecordingLayout) -> Self {
        Self {
            cameras: Some(l.cameras.clone()),
            image_size: Some(l.image_size),
            joints: Some(l.channels.joints.clone()),
            torques: Some(l.channels.torques.clone()),
            extra: Some(l.channels.extra.clone()),
        }
    }
}

impl Default for RecordingLayout {
    /// The paper's robot: two cameras at 64x64, two 7-joint arms with torques.
    fn default() -> Self {
        Self {
            cameras: vec!["left".into(), "right".into()],
            image_size: 64,
            channels: Channels::paper(),
        }
    }
}

impl RecordingLayout {
    /// The paper's channels with these cameras and image size.
    pub fn paper(cameras: &[String], image_size: usize) -> Self {
        Self {
            cameras: cameras.to_vec(),
            image_size,
            channels: Channels::paper(),
        }
    }

    /// Reads `recordings.json` from a recordings folder; the paper's layout if there is
    /// none.
    pub fn of_recordings(from: &Path) -> Result<Self> {
        let path = from.join(LAYOUT);
        if !path.is_file() {
            return Ok(Self::default());
        }
        let text = std::fs::read_to_string(&path).map_err(|e| io_err(&path, e))?;
        let file: LayoutFile = serde_json::from_str(&text)
            .map_err(|e| format_err(path.display(), format!("invalid: {e}")))?;
        let layout = Self::from(file);
        layout.validate(&path.display().to_string())?;
        Ok(layout)
    }

    /// At least one camera, an image size of at least 2, valid channel names.
    pub fn validate(&self, what: &str) -> Result<()> {
        if self.cameras.is_empty() {
            return Err(format_err(what, "names no camera"));
        }
        if self.image_size < 2 {
            return Err(format_err(what, "the image size must be at least 2"));
        }
        self.channels.validate(what)
    }
}

pub const META: &str = "meta.json";
/// The optional layout file at the root of a recordings folder.
pub const LAYOUT: &str = "recordings.json";
pub const PROPRIO_CSV: &str = "proprio.csv";
const IMAGE_EXTENSIONS: [&str; 3] = ["png", "jpg", "jpeg"];

/// Imports every recording under `from` (sub-folders with a `meta.json`, in name order),
/// calling `progress(done, total, name)` before each.
pub fn import_recordings(
    from: &Path,
    layout: &RecordingLayout,
    progress: &mut dyn FnMut(usize, usize, &str),
) -> Result<Dataset> {
    layout.validate("the recording layout")?;
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(from)
        .map_err(|e| io_err(from, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.join(META).is_file())
        .collect();
    dirs.sort();
    if dirs.is_empty() {
        return Err(format_err(
            from.display(),
            format!("no recordings: no sub-folder holds a {META}"),
        ));
    }
    let mut sequences = Vec::with_capacity(dirs.len());
    for (done, dir) in dirs.iter().enumerate() {
        let name = dir
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        progress(done, dirs.len(), &name);
        sequences.push(import_sequence(dir, &name, layout)?);
    }
    Dataset::with_channels(
        &format!("imported from {}", from.display()),
        layout.cameras.clone(),
        layout.image_size,
        layout.channels.clone(),
        sequences,
    )
}

/// Imports one recording folder.
pub fn import_sequence(dir: &Path, name: &str, layout: &RecordingLayout) -> Result<Sequence> {
    let (cameras, image_size) = (&layout.cameras, layout.image_size);
    let meta_path = dir.join(META);
    let text = std::fs::read_to_string(&meta_path).map_err(|e| io_err(&meta_path, e))?;
    let meta: RecordingMeta = serde_json::from_str(&text)
        .map_err(|e| format_err(meta_path.display(), format!("invalid: {e}")))?;

    let mut frame_lists = Vec::with_capacity(cameras.len());
    for cam in cameras {
        frame_lists.push(list_frames(&dir.join(cam))?);
    }
    let n = frame_lists[0].len();
    for (cam, list) in cameras.iter().zip(&frame_lists) {
        if list.len() != n {
            return Err(format_err(
                dir.join(cam).display(),
                format!(
                    "{} frames, but {} has {n}",
                    list.len(),
                    dir.join(&cameras[0]).display()
                ),
            ));
        }
    }
    let ([joints, torques, extra], subtask) = read_proprio(
        &dir.join(PROPRIO_CSV),
        &layout.channels,
        n,
        meta.subtasks.len(),
    )?;

    let mut images = vec![0u8; n * cameras.len() * image_size * image_size * 3];
    let frame_bytes = image_size * image_size * 3;
    for t in 0..n {
        for (c, list) in frame_lists.iter().enumerate() {
            let path = &list[t];
            let img = image::open(path)
                .map_err(|e| format_err(path.display(), format!("cannot read the image: {e}")))?
                .to_rgb8();
            let start = (t * cameras.len() + c) * frame_bytes;
            images[start..start + frame_bytes]
                .copy_from_slice(&square_area_resample(&img, image_size));
        }
    }
    let seq = Sequence {
        info: SequenceInfo {
            name: name.to_string(),
            file: format!("{}.safetensors", crate::file_stem(name)),
            task: meta.task,
            bed_height_mm: meta.bed_height_mm,
            split: meta.split,
            seed: meta.seed,
            length: n,
            subtasks: meta.subtasks,
        },
        cameras: cameras.len(),
        image_size,
        images,
        joints,
        torques,
        extra,
        subtask,
        images_without_robot: None,
    };
    seq.validate(&dir.display().to_string(), layout.channels.layout())?;
    Ok(seq)
}

/// Image files of one camera folder, ordered by frame number; gaps and duplicates are errors.
fn list_frames(dir: &Path) -> Result<Vec<PathBuf>> {
    let entries = std::fs::read_dir(dir).map_err(|e| io_err(dir, e))?;
    let mut frames: Vec<(u64, PathBuf)> = Vec::new();
    for entry in entries {
        let path = entry.map_err(|e| io_err(dir, e))?.path();
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase())
            .unwrap_or_default();
        if !IMAGE_EXTENSIONS.contains(&ext.as_str()) {
            continue;
        }
        let stem = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let digits: String = stem
            .chars()
            .rev()
            .skip_while(|c| !c.is_ascii_digit())
            .take_while(|c| c.is_ascii_digit())
            .collect::<Vec<_>>()
            .into_iter()
            .rev()
            .collect();
        let index: u64 = digits
            .parse()
            .map_err(|_| format_err(path.display(), "the file name holds no frame number"))?;
        frames.push((index, path));
    }
    if frames.is_empty() {
        return Err(format_err(dir.display(), "no PNG or JPEG frames"));
    }
    frames.sort();
    for pair in frames.windows(2) {
        if pair[0].0 == pair[1].0 {
            return Err(format_err(
                dir.display(),
                format!(
                    "frame {} appears twice ({} and {})",
                    pair[0].0,
                    pair[0].1.display(),
                    pair[1].1.display()
                ),
            ));
        }
        if pair[1].0 != pair[0].0 + 1 {
            return Err(format_err(
                dir.display(),
                format!(
                    "frame {} is missing (between {} and {})",
                    pair[0].0 + 1,
                    pair[0].1.display(),
                    pair[1].1.display()
                ),
            ));
        }
    }
    Ok(frames.into_iter().map(|(_, p)| p).collect())
}

/// Joint angles, torques and extra channels `[frames, n]` each, and the subtask labels.
type Proprio = ([Vec<f32>; 3], Vec<u32>);

/// Reads `proprio.csv`: `frames` rows with a column for every named channel and an
/// optional subtask column.
fn read_proprio(
    path: &Path,
    channels: &Channels,
    frames: usize,
    subtasks: usize,
) -> Result<Proprio> {
    let what = path.display().to_string();
    let mut reader = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .from_path(path)
        .map_err(|e| format_err(&what, csv_detail(&e)))?;
    let headers = reader
        .headers()
        .map_err(|e| format_err(&what, csv_detail(&e)))?
        .clone();
    let column = |name: &str| headers.iter().position(|h| h == name);
    let kinds = [&channels.joints, &channels.torques, &channels.extra];
    let mut cols: [Vec<usize>; 3] = Default::default();
    for (names, cols) in kinds.iter().zip(&mut cols) {
        for name in names.iter() {
            cols.push(column(name).ok_or_else(|| {
                format_err(
                    &what,
                    format!(
                        "line 1: the header has no column `{name}` (the layout names {}; \
                         put the robot's channel names in recordings.json)",
                        describe(channels)
                    ),
                )
            })?);
        }
    }
    let subtask_col = column("subtask");
    let mut values: [Vec<f32>; 3] = Default::default();
    let mut labels = Vec::new();
    let mut rows = 0;
    for record in reader.records() {
        let record = record.map_err(|e| format_err(&what, csv_detail(&e)))?;
        let line = record.position().map_or(0, |p| p.line());
        let field = |col: usize, name: &str| -> Result<f32> {
            let text = record.get(col).unwrap_or("");
            let v: f32 = text.parse().map_err(|_| {
                format_err(
                    &what,
                    format!("line {line}: column `{name}`: `{text}` is not a number"),
                )
            })?;
            if !v.is_finite() {
                return Err(format_err(
                    &what,
                    format!("line {line}: column `{name}`: `{text}` is not finite"),
                ));
            }
            Ok(v)
        };
        for ((cols, names), out) in cols.iter().zip(kinds).zip(&mut values) {
            for (col, name) in cols.iter().zip(names.iter()) {
                out.push(field(*col, name)?);
            }
        }
        labels.push(match subtask_col {
            Some(col) => {
                let text = record.get(col).unwrap_or("");
                let v: u32 = text.parse().map_err(|_| {
                    format_err(
                        &what,
                        format!("line {line}: column `subtask`: `{text}` is not a subtask index"),
                    )
                })?;
                if subtasks > 0 && v as usize >= subtasks {
                    return Err(format_err(
                        &what,
                        format!(
                            "line {line}: subtask {v}, but meta.json names only {subtasks} subtasks"
                        ),
                    ));
                }
                v
            }
            None => 0,
        });
        rows += 1;
    }
    if rows != frames {
        return Err(format_err(
            &what,
            format!("{rows} rows, but there are {frames} frames per camera"),
        ));
    }
    Ok((values, labels))
}

/// The channel names of a layout, shortened for a message.
fn describe(channels: &Channels) -> String {
    let short = |v: &[String]| match v {
        [] => "none".to_string(),
        [one] => one.clone(),
        [first, .., last] => format!("{first}..{last}"),
    };
    format!(
        "joints {}, torques {}, extra {}",
        short(&channels.joints),
        short(&channels.torques),
        short(&channels.extra)
    )
}

fn csv_detail(e: &csv::Error) -> String {
    match e.position() {
        Some(p) => format!("line {}: {e}", p.line()),
        None => e.to_string(),
    }
}

/// Writes a dataset sequence in the recordings layout (PNG frames, proprio.csv, meta.json):
/// a template for real data, and the other half of the import round trip. The CSV's
/// columns are `layout`'s channel names; `recordings.json` is the caller's to write
/// ([`write_layout`]).
pub fn write_recording(seq: &Sequence, layout: &RecordingLayout, dir: &Path) -> Result<()> {
    let cameras = &layout.cameras;
    for (c, cam) in cameras.iter().enumerate() {
        let cam_dir = dir.join(cam);
        std::fs::create_dir_all(&cam_dir).map_err(|e| io_err(&cam_dir, e))?;
        for t in 0..seq.len() {
            let path = cam_dir.join(format!("{t:06}.png"));
            let s = seq.image_size as u32;
            image::save_buffer(&path, seq.image(t, c), s, s, image::ExtendedColorType::Rgb8)
                .map_err(|e| format_err(path.display(), format!("cannot write: {e}")))?;
        }
    }
    let mut csv = String::new();
    let mut header: Vec<String> = layout.channels.names().cloned().collect();
    header.push("subtask".into());
    csv.push_str(&header.join(","));
    csv.push('\n');
    for t in 0..seq.len() {
        let p = seq.proprio(t);
        let mut row: Vec<String> = p.iter().map(|v| v.to_string()).collect();
        row.push(seq.subtask[t].to_string());
        csv.push_str(&row.join(","));
        csv.push('\n');
    }
    let csv_path = dir.join(PROPRIO_CSV);
    std::fs::write(&csv_path, csv).map_err(|e| io_err(&csv_path, e))?;
    let meta = RecordingMeta {
        task: seq.info.task.clone(),
        split: seq.info.split,
        bed_height_mm: seq.info.bed_height_mm,
        subtasks: seq.info.subtasks.clone(),
        seed: seq.info.seed,
    };
    let meta_path = dir.join(META);
    std::fs::write(
        &meta_path,
        serde_json::to_string_pretty(&meta).expect("serialisable"),
    )
    .map_err(|e| io_err(&meta_path, e))?;
    Ok(())
}

/// Writes `recordings.json` into a recordings folder.
pub fn write_layout(layout: &RecordingLayout, from: &Path) -> Result<()> {
    std::fs::create_dir_all(from).map_err(|e| io_err(from, e))?;
    let path = from.join(LAYOUT);
    std::fs::write(
        &path,
        serde_json::to_string_pretty(&LayoutFile::from(layout)).expect("serialisable"),
    )
    .map_err(|e| io_err(&path, e))
}
