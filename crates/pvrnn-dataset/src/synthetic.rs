//! A small caresim-shaped dataset of smooth synthetic signals (two tasks, bed heights,
//! learning and test splits, subtask labels), for tests that need a dataset in seconds
//! rather than a simulation.

use crate::{Dataset, Result, Sequence, SequenceInfo, Split, file_stem};

/// `learn_per_height` learning and `test_per_height` test sequences of `steps` steps for
/// each task (`repositioning`, `wiping`) and bed height; two 64x64 cameras; three subtasks
/// of equal length. In the test sequences a dark bar (the "arm") sweeps across the images,
/// and their robot-free renders are the images without it.
pub fn caresim_like(
    heights_mm: &[u32],
    learn_per_height: usize,
    test_per_height: usize,
    steps: usize,
) -> Result<Dataset> {
    let size = 64;
    let mut sequences = Vec::new();
    for (k, task) in ["repositioning", "wiping"].into_iter().enumerate() {
        for &height in heights_mm {
            for (split, count) in [
                (Split::Learn, learn_per_height),
                (Split::Test, test_per_height),
            ] {
                for i in 0..count {
                    let name = format!("{task}_{height}mm_{}{i}", split.name());
                    // A phase per sequence so no two are alike.
                    let phase =
                        (k * 7 + height as usize / 10 + i * 3 + (split == Split::Test) as usize)
                            as f32
                            * 0.37;
                    let mut images = Vec::with_capacity(steps * 2 * size * size * 3);
                    let test = split == Split::Test;
                    let mut without_robot = test.then(|| Vec::with_capacity(images.capacity()));
                    for t in 0..steps {
                        let s = t as f32 / steps as f32;
                        for camera in 0..2 {
                            for y in 0..size {
                                for x in 0..size {
                                    for c in 0..3 {
                                        let v = 0.5
                                            + 0.4
                                                * ((x as f32 * 0.11 + y as f32 * 0.07 + c as f32)
                                                    * (1.0 + k as f32)
                                                    + 6.0 * s
                                                    + phase
                                                    + camera as f32)
                                                    .sin();
                                        let body = (v * 255.0) as u8;
                                        let arm = x + 12 >= 8 + 40 * t / steps.max(1)
                                            && x < 8 + 40 * t / steps.max(1)
                                            && y < 40;
                                        if let Some(hidden) = without_robot.as_mut() {
                                            hidden.push(body);
                                            images.push(if arm { 30 } else { body });
                                        } else {
                                            images.push(body);
                                        }
                                    }
                                }
                            }
                        }
                    }
                    let joints: Vec<f32> = (0..steps * 14)
                        .map(|j| ((j / 14) as f32 * 0.1 + (j % 14) as f32 + phase).sin() * 0.8)
                        .collect();
                    let torques: Vec<f32> = (0..steps * 14)
                        .map(|j| {
                            ((j / 14) as f32 * 0.05 + (j % 14) as f32 * 0.3 + phase).cos() * 5.0
                        })
                        .collect();
                    sequences.push(Sequence {
                        info: SequenceInfo {
                            file: format!("{}.safetensors", file_stem(&name)),
                            name,
                            task: task.into(),
                            bed_height_mm: Some(height as f64),
                            split,
                            seed: None,
                            length: steps,
                            subtasks: vec!["reaching".into(), "holding".into(), "moving".into()],
                        },
                        cameras: 2,
                        image_size: size,
                        images,
                        joints,
                        torques,
                        subtask: (0..steps).map(|t| (3 * t / steps.max(1)) as u32).collect(),
                        extra: Vec::new(),
                        images_without_robot: without_robot,
                    });
                }
            }
        }
    }
    Dataset::new(
        "synthetic (tests)",
        vec!["left".into(), "right".into()],
        size,
        sequences,
    )
}
