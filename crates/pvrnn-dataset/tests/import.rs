//! Importing real recordings: the layout round trip, and an error naming the file (and the
//! line) for every kind of bad input.
#![allow(clippy::unwrap_used)] // test code: a failed unwrap is a failed run

use std::path::Path;

use image::RgbImage;
use pvrnn_dataset::import::{RecordingLayout, import_recordings, import_sequence, write_recording};
use pvrnn_dataset::{Sequence, SequenceInfo, Split};

/// The paper's robot at 8x8 pixels.
fn layout() -> RecordingLayout {
    RecordingLayout::paper(&["left".into(), "right".into()], 8)
}

fn sequence(t: usize) -> Sequence {
    Sequence {
        info: SequenceInfo {
            name: "demo".into(),
            file: "demo.safetensors".into(),
            task: "wiping".into(),
            bed_height_mm: Some(650.0),
            split: Split::Test,
            seed: None,
            length: t,
            subtasks: vec!["reaching".into(), "wiping".into(), "releasing".into()],
        },
        cameras: 2,
        image_size: 8,
        images: (0..t * 2 * 8 * 8 * 3)
            .map(|i| (i * 7 % 251) as u8)
            .collect(),
        joints: (0..t * 14).map(|i| (i as f32 * 0.013).sin()).collect(),
        torques: (0..t * 14)
            .map(|i| (i as f32 * 0.031).cos() * 4.5)
            .collect(),
        subtask: (0..t).map(|i| (i * 3 / t) as u32).collect(),
        extra: Vec::new(),
        images_without_robot: None,
    }
}

fn recording(dir: &Path, t: usize) -> Sequence {
    let seq = sequence(t);
    write_recording(&seq, &layout(), dir).unwrap();
    seq
}

fn import_err(dir: &Path) -> String {
    import_sequence(dir, "demo", &layout())
        .unwrap_err()
        .to_string()
}

#[test]
fn round_trip_through_the_recordings_layout() {
    let dir = tempfile::tempdir().unwrap();
    let seq = recording(dir.path(), 6);
    let back = import_sequence(dir.path(), "demo", &layout()).unwrap();
    assert_eq!(back, seq);
    // Any frame size is centre-cropped and area-resampled: 16x24 -> 8x8.
    let big = RgbImage::from_fn(24, 16, |x, y| {
        image::Rgb([(x * 10) as u8, (y * 10) as u8, 99])
    });
    big.save(dir.path().join("left/000002.png")).unwrap();
    let resized = import_sequence(dir.path(), "demo", &layout()).unwrap();
    let px = &resized.image(2, 0)[..3];
    // Output pixel (0, 0) averages the crop's x in 4..6, y in 0..2: red (40 + 50) / 2, green 5.
    assert_eq!(px, &[45, 5, 99]);
}

#[test]
fn a_folder_of_recordings_becomes_a_dataset() {
    let root = tempfile::tempdir().unwrap();
    recording(&root.path().join("b_second"), 4);
    recording(&root.path().join("a_first"), 5);
    std::fs::create_dir(root.path().join("notes")).unwrap();
    let ds = import_recordings(root.path(), &layout(), &mut |_, _, _| {}).unwrap();
    let names: Vec<&str> = ds.sequences.iter().map(|s| s.info.name.as_str()).collect();
    assert_eq!(names, ["a_first", "b_second"]);
    let e = import_recordings(&root.path().join("notes"), &layout(), &mut |_, _, _| {})
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("notes") && e.contains("no sub-folder holds a meta.json"),
        "{e}"
    );
}

#[test]
fn missing_frame_is_named() {
    let dir = tempfile::tempdir().unwrap();
    recording(dir.path(), 6);
    std::fs::remove_file(dir.path().join("right/000003.png")).unwrap();
    let e = import_err(dir.path());
    assert!(
        e.contains("right") && e.contains("frame 3 is missing"),
        "{e}"
    );
}

#[test]
fn frame_count_mismatches_are_named() {
    let dir = tempfile::tempdir().unwrap();
    recording(dir.path(), 6);
    std::fs::remove_file(dir.path().join("right/000005.png")).unwrap();
    let e = import_err(dir.path());
    assert!(
        e.contains("right: 5 frames") && e.contains("left has 6"),
        "{e}"
    );
    // Frames agree with each other but not with the CSV.
    std::fs::remove_file(dir.path().join("left/000005.png")).unwrap();
    let e = import_err(dir.path());
    assert!(
        e.contains("proprio.csv") && e.contains("6 rows, but there are 5 frames"),
        "{e}"
    );
}

#[test]
fn bad_csv_rows_are_named_with_their_line() {
    let dir = tempfile::tempdir().unwrap();
    recording(dir.path(), 6);
    let csv_path = dir.path().join("proprio.csv");
    let text = std::fs::read_to_string(&csv_path).unwrap();
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    let mut fields: Vec<&str> = lines[3].split(',').collect();
    fields[1] = "abc";
    lines[3] = fields.join(",");
    std::fs::write(&csv_path, lines.join("\n")).unwrap();
    let e = import_err(dir.path());
    assert!(
        e.contains("proprio.csv: line 4: column `left_q2`: `abc` is not a number"),
        "{e}"
    );

    let short = text
        .lines()
        .enumerate()
        .map(|(i, l)| if i == 2 { "1,2,3" } else { l })
        .collect::<Vec<_>>()
        .join("\n");
    std::fs::write(&csv_path, short).unwrap();
    let e = import_err(dir.path());
    assert!(e.contains("proprio.csv") && e.contains("line 3"), "{e}");

    let no_column = text.replacen("right_tau4", "right_tau_4", 1);
    std::fs::write(&csv_path, no_column).unwrap();
    let e = import_err(dir.path());
    assert!(
        e.contains("line 1: the header has no column `right_tau4`"),
        "{e}"
    );

    let nan = text
        .lines()
        .enumerate()
        .map(|(i, l)| {
            if i == 5 {
                l.replacen(',', ",NaN,", 1)
            } else {
                l.to_string()
            }
        })
        .collect::<Vec<_>>();
    let nan: Vec<String> = nan
        .into_iter()
        .map(|l| l.split(',').take(29).collect::<Vec<_>>().join(","))
        .collect();
    std::fs::write(&csv_path, nan.join("\n")).unwrap();
    let e = import_err(dir.path());
    assert!(e.contains("line 6") && e.contains("NaN"), "{e}");

    let bad_label = text
        .lines()
        .enumerate()
        .map(|(i, l)| {
            if i == 2 {
                format!("{},7", l.rsplit_once(',').unwrap().0)
            } else {
                l.to_string()
            }
        })
        .collect::<Vec<_>>();
    std::fs::write(&csv_path, bad_label.join("\n")).unwrap();
    let e = import_err(dir.path());
    assert!(
        e.contains("line 3: subtask 7, but meta.json names only 3 subtasks"),
        "{e}"
    );
}

#[test]
fn unreadable_images_and_bad_meta_are_named() {
    let dir = tempfile::tempdir().unwrap();
    recording(dir.path(), 4);
    std::fs::write(dir.path().join("left/000002.png"), b"not a png").unwrap();
    let e = import_err(dir.path());
    assert!(
        e.contains("left/000002.png") && e.contains("cannot read the image"),
        "{e}"
    );

    std::fs::write(
        dir.path().join("meta.json"),
        "{\"task\": \"wiping\", \"split\": \"later\"}",
    )
    .unwrap();
    let e = import_err(dir.path());
    assert!(e.contains("meta.json") && e.contains("later"), "{e}");

    std::fs::remove_dir_all(dir.path().join("right")).unwrap();
    std::fs::write(
        dir.path().join("meta.json"),
        "{\"task\": \"wiping\", \"split\": \"learn\"}",
    )
    .unwrap();
    let e = import_err(dir.path());
    assert!(e.contains("right") && e.contains("No such file"), "{e}");
}

/// Any robot: the channels recordings.json names are the CSV columns read, in its order;
/// a column it names that the CSV lacks, a name given twice and no channels at all are
/// errors naming the file.
#[test]
fn a_robot_layout_names_the_columns() {
    use pvrnn_dataset::import::{LAYOUT, RecordingLayout, write_layout};
    use pvrnn_dataset::{Channels, Dataset, ProprioLayout};
    let root = tempfile::tempdir().unwrap();
    let layout = RecordingLayout {
        cameras: vec!["wrist".into()],
        image_size: 8,
        channels: Channels {
            joints: (1..=6).map(|j| format!("q{j}")).collect(),
            torques: Vec::new(),
            extra: vec!["gripper".into()],
        },
    };
    let mut seq = sequence(5);
    seq.cameras = 1;
    seq.images.truncate(5 * 8 * 8 * 3);
    seq.joints = (0..5 * 6).map(|i| i as f32 * 0.1).collect();
    seq.torques = Vec::new();
    seq.extra = vec![0.08, 0.08, 0.05, 0.02, 0.01];
    write_recording(&seq, &layout, &root.path().join("t1")).unwrap();
    write_layout(&layout, root.path()).unwrap();
    let read = RecordingLayout::of_recordings(root.path()).unwrap();
    assert_eq!(read, layout);
    let ds = import_recordings(root.path(), &read, &mut |_, _, _| {}).unwrap();
    assert_eq!(
        ds.manifest.proprio_layout(),
        ProprioLayout {
            joints: 6,
            torques: 0,
            extra: 1
        }
    );
    assert_eq!(
        ds.sequences[0].proprio(2)[6],
        0.05,
        "the gripper comes last"
    );
    assert_eq!(ds.sequences[0].proprio(2)[0], 1.2);
    // Written and read back: the torque tensor is absent, the channels stay.
    let out = tempfile::tempdir().unwrap();
    ds.write(out.path()).unwrap();
    assert_eq!(Dataset::open(out.path()).unwrap(), ds);
    // Only a joints list: no torques (not the paper's 14).
    std::fs::write(root.path().join(LAYOUT), r#"{"joints": ["q1"]}"#).unwrap();
    let only = RecordingLayout::of_recordings(root.path()).unwrap();
    assert_eq!(only.channels.layout().dims(), 1);
    assert_eq!(
        only.cameras,
        ["left", "right"],
        "the other fields keep the defaults"
    );
    // A column the CSV lacks.
    std::fs::write(
        root.path().join(LAYOUT),
        r#"{"cameras": ["wrist"], "image_size": 8, "joints": ["q1", "elbow"]}"#,
    )
    .unwrap();
    let layout = RecordingLayout::of_recordings(root.path()).unwrap();
    let e = import_recordings(root.path(), &layout, &mut |_, _, _| {})
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("proprio.csv")
            && e.contains("no column `elbow`")
            && e.contains("recordings.json"),
        "{e}"
    );
    for (text, says) in [
        (r#"{"joints": ["q1", "q1"]}"#, "`q1` appears twice"),
        (r#"{"joints": []}"#, "names no proprioceptive channel"),
        (r#"{"joint": ["q1"]}"#, "unknown field"),
    ] {
        std::fs::write(root.path().join(LAYOUT), text).unwrap();
        let e = RecordingLayout::of_recordings(root.path())
            .unwrap_err()
            .to_string();
        assert!(e.contains(LAYOUT) && e.contains(says), "{text}: {e}");
    }
}
