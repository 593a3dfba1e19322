//! caresim: a seeded synthetic stand-in for the paper's robot recordings
//! (its specification: `docs/caresim.md`).
//!
//! A dual-arm humanoid (two arms with the Franka Panda's 7-DOF kinematics hanging from its
//! shoulders, a binocular camera pair in its head) stands at a bed at 590, 650 or 710 mm
//! with a supine mannequin of the paper's dimensions, and performs
//!
//! - **repositioning**: reach the left hand to the neck; slide it under the upper back
//!   while the right hand holds the legs; lift the upper body towards sitting;
//! - **wiping**: reach a towel lying on the mannequin and grasp it; wipe the body surface
//!   in strokes that follow its curvature; release the towel and withdraw.
//!
//! Per step it records 14 joint angles (inverse kinematics of the scripted hand targets),
//! 14 joint torques (gravity load plus the hand's external load through the Jacobian
//! transpose, plus sensor noise), two 64x64 RGB camera images (z-buffered, shaded,
//! supersampled), and the subtask label. Same seed, same bytes.
//!
//! Modules: [`arm`] kinematics and torques, [`body`] the mannequin, [`cloth`] the towel,
//! [`shapes`] primitives and meshes, [`render`] the rasteriser, [`scene`] robot, bed, room
//! and cameras, [`task`] the scripted tasks and their variability, [`sim`] running a trial,
//! [`env`](mod@env) a trial driven by joint commands instead of its script (closed loop),
//! [`outcome`] whether such an episode did the task (the pre-specified success criteria),
//! [`revision`] which edition of the benchmark (revision 2 moves every joint).

pub mod arm;
pub mod body;
pub mod cloth;
pub mod env;
mod math;
pub mod outcome;
pub mod render;
pub mod revision;
pub mod scene;
pub mod shapes;
pub mod sim;
pub mod task;
pub mod variability;

pub use revision::Revision;
pub use sim::{
    IMAGE_SIZE, Simulation, StepRecord, TrialSpec, simulate, simulate_proprioception, simulate_with,
};
pub use task::Task;
pub use variability::Variability;

use pvrnn_dataset::Split;

/// The paper's three bed heights (mm).
pub const BED_HEIGHTS_MM: [u32; 3] = [590, 650, 710];

/// Which trials make a dataset. The default is the paper's: per task, 3 learning and 1
/// test sequence per bed height (9 + 3 per task, 24 in all).
#[derive(Clone, Debug, PartialEq)]
pub struct DatasetSpec {
    pub seed: u64,
    pub tasks: Vec<Task>,
    pub bed_heights_mm: Vec<u32>,
    pub learn_per_height: usize,
    pub test_per_height: usize,
    pub variability: Variability,
    /// Which edition of the benchmark ([`Revision`]).
    pub revision: Revision,
}

impl Default for DatasetSpec {
    fn default() -> Self {
        Self {
            seed: 0,
            tasks: Task::ALL.to_vec(),
            bed_heights_mm: BED_HEIGHTS_MM.to_vec(),
            learn_per_height: 3,
            test_per_height: 1,
            variability: Variability::PAPER,
            revision: Revision::default(),
        }
    }
}

fn mix(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

impl DatasetSpec {
    /// Every trial, in dataset order: by task, learning before test, by height, by index.
    /// Each trial's seed depends only on the dataset seed and the trial's identity.
    pub fn trials(&self) -> Vec<TrialSpec> {
        let mut out = Vec::new();
        for &task in &self.tasks {
            for (split, count) in [
                (Split::Learn, self.learn_per_height),
                (Split::Test, self.test_per_height),
            ] {
                for &height in &self.bed_heights_mm {
                    for index in 0..count {
                        let key = [task as u64, height as u64, split as u64, index as u64];
                        let seed = key.iter().fold(mix(self.seed), |acc, &k| mix(acc ^ mix(k)));
                        out.push(TrialSpec {
                            task,
                            bed_height_mm: height,
                            split,
                            index,
                            seed,
                            variability: self.variability.of(task),
                            revision: self.revision,
                        });
                    }
                }
            }
        }
        out
    }
}
