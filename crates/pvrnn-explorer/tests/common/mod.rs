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
