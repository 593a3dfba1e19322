//! The dimension groups errors are reported for: each vision resolution (both cameras and
//! each camera alone), joint angles, torques.

use std::ops::Range;

use pvrnn_core::config::VisionLayout;
use pvrnn_core::{Modality, ModelConfig, Observed};
use pvrnn_dataset::ProprioLayout;
use serde::Serialize;

/// A named set of input dimensions of one modality.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Group {
    /// e.g. `v64`, `v64_left`, `joints`.
    pub name: String,
    pub modality: Modality,
    /// Vision level (index into the resolutions), for vision groups.
    pub level: Option<usize>,
    /// Whether the model observed these dimensions under the evaluated condition.
    pub observed: bool,
    #[serde(skip)]
    pub dims: Range<usize>,
}

impl Group {
    pub fn is_vision(&self) -> bool {
        self.modality == Modality::Exteroceptive
    }
}

/// The groups of a model with the dataset's camera names and proprioception layout
/// (joint angles, then torques, then extra channels), under `observed`.
pub fn groups(
    config: &ModelConfig,
    cameras: &[String],
    proprio: ProprioLayout,
    observed: &Observed,
) -> Vec<Group> {
    let layout: &VisionLayout = &config.vision;
    let mut out = Vec::new();
    for (level, &r) in layout.resolutions.iter().enumerate() {
        let seen = level < observed.vision_levels;
        let start = layout.level_offset(level);
        out.push(Group {
            name: format!("v{r}"),
            modality: Modality::Exteroceptive,
            level: Some(level),
            observed: seen,
            dims: start..start + layout.level_dims(level),
        });
        let image = layout.channels * r * r;
        for (camera, name) in cameras.iter().enumerate().take(layout.cameras) {
            let at = layout.image_offset(level, camera);
            out.push(Group {
                name: format!("v{r}_{name}"),
                modality: Modality::Exteroceptive,
                level: Some(level),
                observed: seen,
                dims: at..at + image,
            });
        }
    }
    for (name, dims) in ["joints", "torques", "extra"]
        .into_iter()
        .zip(proprio.ranges())
    {
        if !dims.is_empty() {
            out.push(Group {
                name: name.into(),
                modality: Modality::Proprioceptive,
                level: None,
                observed: observed.proprio,
                dims,
            });
        }
    }
    out
}
