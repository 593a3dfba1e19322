//! A tiny model and dataset for the explorer's tests.
#![allow(dead_code)]

use pvrnn_core::config::{ModuleConfig, VisionLayout};
use pvrnn_core::{Model, ModelConfig};
use pvrnn_dataset::{Dataset, Sequence, SequenceInfo, Split};
use pvrnn_explorer::Bundle;

pub fn config() -> ModelConfig {
    let mut c = ModelConfig::default();
    let m = |d, z| ModuleConfig {
        d,
        z,
        tau: [2.0, 4.0],
    };
    c.executive = m(6, 3);
    c.associative = m(6, 3);
    c.exteroceptive = m(8, 4);
    c.proprioceptive = m(6, 3);
    c.exteroceptive_readout.hidden = vec![8, 10];
    c.proprioceptive_readout.hidden = vec![8];
    c.vision = VisionLayout {
        cameras: 2,
        channels: 3,
        resolutions: vec![4, 8],
    };
    c.inference.window = 4;
    c.inference.iterations = 3;
    c
}

pub fn sequence(name: &str, task: &str, split: Split, t: usize, seed: u32) -> Sequence {
    Sequence {
        info: SequenceInfo {
            name: name.into(),
            file: format!("{name}.safetensors"),
            task: task.into(),
            bed_height_mm: Some(650.0),
            split,
            seed: Some(seed as u64),
            length: t,
            subtasks: vec!["first".into(), "second".into()],
        },
        cameras: 2,
        image_size: 8,
        images: (0..t * 2 * 8 * 8 * 3)
            .map(|i| ((i as u32 * 37 + seed * 11) % 256) as u8)
            .collect(),
        joints: (0..t * 14)
            .map(|i| (i as f32 * 0.05 + seed as f32).sin())
            .collect(),
        torques: (0..t * 14).map(|i| (i as f32 * 0.07).cos() * 3.0).collect(),
        subtask: (0..t).map(|i| (i * 2 / t) as u32).collect(),
        extra: Vec::new(),
        images_without_robot: None,
    }
}

pub fn dataset() -> Dataset {
    Dataset::new(
        "test",
        vec!["left".into(), "right".into()],
        8,
        vec![
            sequence("reach_learn", "repositioning", Split::Learn, 12, 1),
            sequence("reach_test", "repositioning", Split::Test, 10, 2),
            sequence("wipe_test", "wiping", Split::Test, 9, 3),
        ],
    )
    .unwrap()
}

pub fn model() -> Model<f32> {
    Model::<f32>::init(config(), 1, 12, 5).unwrap()
}

pub fn bundle() -> Bundle {
    Bundle::new("tiny".into(), model(), dataset()).unwrap()
}

/// A robot that is not the paper's: three cameras (head, left_wrist, right_wrist), 3 joints,
/// 2 torques and 1 extra channel.
pub fn three_camera_bundle() -> Bundle {
    use pvrnn_dataset::Channels;
    let channels = Channels {
        joints: vec!["base_yaw".into(), "shoulder".into(), "elbow".into()],
        torques: vec!["shoulder_tau".into(), "elbow_tau".into()],
        extra: vec!["grip_mm".into()],
    };
    let robot = |name: &str, split, t: usize, seed: u32| {
        let mut s = sequence(name, "handover", split, t, seed);
        // Not caresim: no bed.
        s.info.bed_height_mm = None;
        s.cameras = 3;
        s.images = (0..t * 3 * 8 * 8 * 3)
            .map(|i| ((i as u32 * 29 + seed) % 256) as u8)
            .collect();
        s.joints = (0..t * 3).map(|i| (i as f32 * 0.1).sin()).collect();
        s.torques = (0..t * 2).map(|i| (i as f32 * 0.2).cos()).collect();
        s.extra = (0..t).map(|i| i as f32 * 0.5).collect();
        s
    };
    let dataset = Dataset::with_channels(
        "three cameras",
        ["head", "left_wrist", "right_wrist"]
            .iter()
            .map(|c| c.to_string())
            .collect(),
        8,
        channels,
        vec![
            robot("learn", Split::Learn, 10, 1),
            robot("test", Split::Test, 8, 2),
        ],
    )
    .unwrap();
    let mut config = config();
    config.vision.cameras = 3;
    config.proprio_dims = 6;
    let model = Model::<f32>::init(config, 1, 10, 3).unwrap();
    Bundle::new("three cameras".into(), model, dataset).unwrap()
}

/// The labels a robot's bundle must show, and those only the paper's robot has.
pub const THREE_CAMERA_LABELS: [&str; 10] = [
    "head camera",
    "left_wrist camera",
    "right_wrist camera",
    "contours and contributions (right_wrist camera, 8x8)",
    "step t = 0: head camera at 8x8",
    "joint angles (rad); one colour per channel",
    "torques (N m); one colour per channel",
    "extra channels: grip_mm (their own units)",
    "base_yaw",
    "elbow_tau",
];
pub const PAPER_ONLY_LABELS: [&str; 4] = ["left camera", "right camera", "left arm", "warm"];

/// A tiny network with caresim's senses (two 64x64 cameras, 14 joints and 14 torques) and
/// one simulated caresim test trial (revision 1): enough for the Drive window.
pub fn caresim_bundle() -> Bundle {
    let mut c = config();
    c.vision.resolutions = vec![16, 32, 64];
    let spec = caresim::DatasetSpec::default()
        .trials()
        .into_iter()
        .find(|t| t.split == Split::Test)
        .unwrap();
    let (sequence, _) = caresim::simulate(&spec);
    let dataset = Dataset::new(
        "caresim",
        vec!["left".into(), "right".into()],
        caresim::IMAGE_SIZE,
        vec![sequence],
    )
    .unwrap();
    c.normalisation = Some(pvrnn_dataset::proprio_ranges(&[&dataset.sequences[0]]));
    let model = Model::<f32>::init(c, 1, 12, 5).unwrap();
    Bundle::new("tiny caresim".into(), model, dataset).unwrap()
}
