//! Writes `tests/data/one-arm/`: a small set of recordings of a robot that is not the
//! paper's: one 6-joint arm without torque sensing, a gripper channel, one wrist camera
//! with 160x120 frames (imported at 128x128). The walkthrough (`docs/walkthrough.md`) and
//! its test use it; it stands in for a user's own robot.
//!
//!     cargo run -p pvrnn-dataset --example one_arm_recordings [-- OUT_DIR]
//!
//! Deterministic: the same files every time.
#![allow(clippy::unwrap_used)] // a generator run by hand: a failure should stop it loudly

use std::f32::consts::PI;
use std::path::PathBuf;

use image::{Rgb, RgbImage};
use pvrnn_dataset::import::{LayoutFile, META, PROPRIO_CSV, RecordingMeta};
use pvrnn_dataset::{Split, import};

const WIDTH: u32 = 160;
const HEIGHT: u32 = 120;
const STEPS: usize = 24;

fn main() {
    let out = std::env::args()
        .nth(1)
        .map_or_else(|| PathBuf::from("tests/data/one-arm"), PathBuf::from);
    let joints: Vec<String> = (1..=6).map(|j| format!("q{j}")).collect();
    let layout = LayoutFile {
        cameras: Some(vec!["wrist".into()]),
        image_size: Some(128),
        joints: Some(joints.clone()),
        torques: None,
        extra: Some(vec!["gripper".into()]),
    };
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(
        out.join(import::LAYOUT),
        serde_json::to_string_pretty(&layout).unwrap() + "\n",
    )
    .unwrap();
    // Two learning trials and one test trial of a "reach and grasp" task.
    for (name, split, phase) in [
        ("trial_1", Split::Learn, 0.0f32),
        ("trial_2", Split::Learn, 0.35),
        ("trial_3", Split::Test, 0.18),
    ] {
        let dir = out.join(name);
        std::fs::create_dir_all(dir.join("wrist")).unwrap();
        let meta = RecordingMeta {
            task: "reach-grasp".into(),
            split,
            bed_height_mm: None,
            subtasks: vec!["reach".into(), "grasp".into()],
            seed: None,
        };
        std::fs::write(
            dir.join(META),
            serde_json::to_string_pretty(&meta).unwrap() + "\n",
        )
        .unwrap();
        let mut csv = String::from("time_s,");
        csv.push_str(&joints.join(","));
        csv.push_str(",gripper,subtask\n");
        for t in 0..STEPS {
            let s = t as f32 / (STEPS - 1) as f32;
            // The arm swings out, then the gripper closes.
            let q: Vec<f32> = (0..6)
                .map(|j| 0.6 * (PI * s + phase + j as f32 * 0.4).sin() / (1.0 + j as f32 * 0.3))
                .collect();
            let grasp = s > 0.6;
            let gripper = if grasp { 0.01 } else { 0.08 };
            csv.push_str(&format!("{:.2},", t as f32 * 0.1));
            for v in &q {
                csv.push_str(&format!("{v:.5},"));
            }
            csv.push_str(&format!("{gripper},{}\n", u8::from(grasp)));
            frame(&q, gripper, phase)
                .save(dir.join("wrist").join(format!("frame_{t:04}.png")))
                .unwrap();
        }
        std::fs::write(dir.join(PROPRIO_CSV), csv).unwrap();
    }
    eprintln!("wrote {}", out.display());
}

/// What the wrist camera sees: a table, an object whose place depends on the trial, and the
/// gripper's jaws, opened by `gripper` and swung by the first two joints.
fn frame(q: &[f32], gripper: f32, phase: f32) -> RgbImage {
    let (w, h) = (WIDTH as f32, HEIGHT as f32);
    let cx = w * 0.5 + q[0] * 50.0;
    let cy = h * 0.55 + q[1] * 30.0;
    let ox = w * (0.35 + phase);
    let oy = h * 0.6;
    let jaw = gripper * 300.0;
    RgbImage::from_fn(WIDTH, HEIGHT, |x, y| {
        let (x, y) = (x as f32, y as f32);
        let object = (x - ox).powi(2) + (y - oy).powi(2) < 14.0f32.powi(2);
        let left_jaw = (x - (cx - jaw)).abs() < 4.0 && (y - cy).abs() < 18.0;
        let right_jaw = (x - (cx + jaw)).abs() < 4.0 && (y - cy).abs() < 18.0;
        if left_jaw || right_jaw {
            Rgb([70, 70, 80])
        } else if object {
            Rgb([200, 60, 40])
        } else if y > h * 0.3 {
            Rgb([180, 160, 120])
        } else {
            Rgb([220, 225, 230])
        }
    })
}
