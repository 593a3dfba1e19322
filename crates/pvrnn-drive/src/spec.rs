//! What an episode is ([`DriveSpec`]): the trial, who drives ([`Controller`]), how fast the
//! joints may move, and what is done to the robot on the way ([`Perturbations`]).

use caresim::env::SpeedLimit;
use caresim::{DatasetSpec, Revision, Task, TrialSpec, Variability};
use pvrnn_dataset::Split;
use serde::Serialize;

use crate::{Error, Result};

/// Who sends the joint commands.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Controller {
    /// The network, closed loop: each step's observation updates its latent states by
    /// online inference, and its prediction of the next step's joint angles is the
    /// command.
    #[default]
    Network,
    /// The network's own prior generation, open loop: the same commands, but nothing the
    /// environment returns is fed back (no observation, no inference updates).
    Prior,
    /// The mean joint trajectory of the task's learning trials at this bed height (3 per
    /// height), resampled to the episode's length and replayed without looking; a bed
    /// height between learned ones interpolates their means.
    MeanTrajectory,
}

impl Controller {
    pub const ALL: [Controller; 3] = [
        Controller::Network,
        Controller::Prior,
        Controller::MeanTrajectory,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Controller::Network => "network",
            Controller::Prior => "prior",
            Controller::MeanTrajectory => "mean-trajectory",
        }
    }

    pub fn parse(text: &str) -> Result<Self> {
        Self::ALL
            .into_iter()
            .find(|c| c.name() == text)
            .ok_or_else(|| {
                Error::Invalid(format!(
                    "unknown controller `{text}` (network, prior, mean-trajectory)"
                ))
            })
    }

    /// Whether the controller runs the network.
    pub fn uses_network(self) -> bool {
        self != Controller::MeanTrajectory
    }
}

/// An arm displaced mid-task: shoved during the step into `step`, it lands `radians` off
/// (every joint) from where it was sent, and the network sees it there; the next
/// command moves it on.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Push {
    /// Before this step is taken (1 or later).
    pub step: usize,
    /// 0 left, 1 right.
    pub arm: usize,
    /// Every joint of the arm turned by this much (rad; clamped to the joints' limits).
    pub radians: f64,
}

impl Push {
    /// `STEP:ARM:RAD`, e.g. `120:left:0.2`.
    pub fn parse(text: &str) -> Result<Self> {
        let bad = || {
            Error::Invalid(format!(
                "push `{text}`: expected STEP:ARM:RADIANS, e.g. 120:left:0.2 (ARM left or right)"
            ))
        };
        let [step, arm, radians] = split3(text).ok_or_else(bad)?;
        let push = Self {
            step: step.parse().map_err(|_| bad())?,
            arm: arm_index(arm).ok_or_else(bad)?,
            radians: radians.parse().map_err(|_| bad())?,
        };
        if push.step == 0 || !push.radians.is_finite() {
            return Err(bad());
        }
        Ok(push)
    }
}

/// A camera that sees nothing for a while: its image is mid-grey (128) in what the network
/// is given and in the episode's recording.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct Occlusion {
    /// 0 left, 1 right.
    pub camera: usize,
    pub from: usize,
    pub steps: usize,
}

impl Occlusion {
    /// `CAMERA:FROM:STEPS`, e.g. `left:100:30`.
    pub fn parse(text: &str) -> Result<Self> {
        let bad = || {
            Error::Invalid(format!(
                "occlusion `{text}`: expected CAMERA:FROM:STEPS, e.g. left:100:30 (CAMERA left or right)"
            ))
        };
        let [camera, from, steps] = split3(text).ok_or_else(bad)?;
        Ok(Self {
            camera: arm_index(camera).ok_or_else(bad)?,
            from: from.parse().map_err(|_| bad())?,
            steps: steps.parse().map_err(|_| bad())?,
        })
    }

    pub fn covers(&self, step: usize) -> bool {
        (self.from..self.from.saturating_add(self.steps)).contains(&step)
    }
}

/// The network's vision cut mid-task: from step `from` on it observes only the lowest
/// `levels` vision resolutions (0: no vision; 1: 16x16 for the paper's layout). The
/// robot's cameras still record everything; the inference reads its window again without
/// the dropped levels from there on, as a branch of a run does.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct VisionDrop {
    pub from: usize,
    pub levels: usize,
}

impl VisionDrop {
    /// `FROM:LEVELS`, e.g. `120:1` (16x16 only from step 120) or `120:0` (no vision).
    pub fn parse(text: &str) -> Result<Self> {
        let bad = || {
            Error::Invalid(format!(
                "vision drop `{text}`: expected FROM:LEVELS, e.g. 120:1 (the lowest LEVELS vision resolutions observed from step FROM on; 0 none)"
            ))
        };
        let (from, levels) = text.split_once(':').ok_or_else(bad)?;
        Ok(Self {
            from: from.parse().map_err(|_| bad())?,
            levels: levels.parse().map_err(|_| bad())?,
        })
    }
}

fn split3(text: &str) -> Option<[&str; 3]> {
    let parts: Vec<&str> = text.split(':').collect();
    parts.try_into().ok()
}

fn arm_index(text: &str) -> Option<usize> {
    match text {
        "left" | "0" => Some(0),
        "right" | "1" => Some(1),
        _ => None,
    }
}

/// What is done to the robot during an episode.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Perturbations {
    /// The sensor noise's scale (1 = a recording's; 3 = "proprioceptive noise x3").
    pub sensor_noise: f64,
    pub push: Option<Push>,
    pub occlusion: Option<Occlusion>,
    pub vision_drop: Option<VisionDrop>,
}

impl Default for Perturbations {
    fn default() -> Self {
        Self {
            sensor_noise: 1.0,
            push: None,
            occlusion: None,
            vision_drop: None,
        }
    }
}

/// One episode: everything it depends on besides the network.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct DriveSpec {
    pub task: Task,
    pub bed_height_mm: u32,
    /// The caresim dataset seed whose test trial this is (seed 0: the benchmark's test
    /// split; other seeds: more trials of the same kind).
    pub seed: u64,
    #[serde(serialize_with = "revision_number")]
    pub revision: Revision,
    pub controller: Controller,
    #[serde(serialize_with = "speed_limit_name")]
    pub speed_limit: SpeedLimit,
    pub perturbations: Perturbations,
}

fn revision_number<S: serde::Serializer>(
    r: &Revision,
    s: S,
) -> std::result::Result<S::Ok, S::Error> {
    s.serialize_u32(r.number())
}

fn speed_limit_name<S: serde::Serializer>(
    l: &SpeedLimit,
    s: S,
) -> std::result::Result<S::Ok, S::Error> {
    s.serialize_str(speed_limit_text(*l))
}

/// `scripted` or `panda`.
pub fn speed_limit_text(limit: SpeedLimit) -> &'static str {
    match limit {
        SpeedLimit::Scripted => "scripted",
        SpeedLimit::Panda => "panda",
    }
}

pub fn parse_speed_limit(text: &str) -> Result<SpeedLimit> {
    match text {
        "scripted" => Ok(SpeedLimit::Scripted),
        "panda" => Ok(SpeedLimit::Panda),
        _ => Err(Error::Invalid(format!(
            "unknown speed limit `{text}` (scripted: the scripted trials' 2 rad a step; panda: the Franka Panda's joint speeds)"
        ))),
    }
}

impl DriveSpec {
    /// The task's test trial at this bed height in caresim `seed`'s dataset (the paper's
    /// variability), the network driving, no perturbation.
    pub fn new(task: Task, bed_height_mm: u32, seed: u64, revision: Revision) -> Self {
        Self {
            task,
            bed_height_mm,
            seed,
            revision,
            controller: Controller::default(),
            speed_limit: SpeedLimit::default(),
            perturbations: Perturbations::default(),
        }
    }

    /// The caresim dataset this episode's trial belongs to, with `learn` learning trials
    /// per height at `heights`.
    pub fn dataset(&self, heights: Vec<u32>, learn: usize, test: usize) -> DatasetSpec {
        DatasetSpec {
            seed: self.seed,
            tasks: vec![self.task],
            bed_heights_mm: heights,
            learn_per_height: learn,
            test_per_height: test,
            variability: Variability::PAPER,
            revision: self.revision,
        }
    }

    /// The trial driven: the test trial of this task and bed height (a bed height the
    /// benchmark never learned is a trial of its own, seeded the same way).
    pub fn trial(&self) -> Result<TrialSpec> {
        if !(300..=1200).contains(&self.bed_height_mm) {
            return Err(Error::Invalid(format!(
                "bed height {} mm: it must be between 300 and 1200",
                self.bed_height_mm
            )));
        }
        self.dataset(vec![self.bed_height_mm], 0, 1)
            .trials()
            .into_iter()
            .find(|t| t.split == Split::Test)
            .ok_or_else(|| Error::Invalid("no test trial".into()))
    }
}

impl DriveSpec {
    /// The spec in one line, as an address or a file name can hold it:
    /// `TASK:HEIGHT:SEED:REVISION:CONTROLLER`, then `;noise=F`, `;push=STEP:ARM:RAD`,
    /// `;occlude=CAMERA:FROM:STEPS`, `;vision=FROM:LEVELS`, `;limit=panda` where they differ
    /// from the defaults.
    /// [`DriveSpec::parse_text`] reads it back.
    pub fn to_text(&self) -> String {
        let arm = |i: usize| if i == 0 { "left" } else { "right" };
        let mut text = format!(
            "{}:{}:{}:{}:{}",
            self.task.name(),
            self.bed_height_mm,
            self.seed,
            self.revision.number(),
            self.controller.name()
        );
        let p = &self.perturbations;
        if p.sensor_noise != 1.0 {
            text += &format!(";noise={}", p.sensor_noise);
        }
        if let Some(push) = p.push {
            text += &format!(";push={}:{}:{}", push.step, arm(push.arm), push.radians);
        }
        if let Some(o) = p.occlusion {
            text += &format!(";occlude={}:{}:{}", arm(o.camera), o.from, o.steps);
        }
        if let Some(v) = p.vision_drop {
            text += &format!(";vision={}:{}", v.from, v.levels);
        }
        if self.speed_limit != SpeedLimit::default() {
            text += &format!(";limit={}", speed_limit_text(self.speed_limit));
        }
        text
    }

    /// Reads [`DriveSpec::to_text`]'s form.
    pub fn parse_text(text: &str) -> Result<Self> {
        let bad = |why: &str| {
            Error::Invalid(format!(
                "drive `{text}`: {why} (expected TASK:HEIGHT:SEED:REVISION:CONTROLLER[;noise=F][;push=STEP:ARM:RAD][;occlude=CAMERA:FROM:STEPS][;vision=FROM:LEVELS][;limit=panda])"
            ))
        };
        let mut parts = text.split(';');
        let head: Vec<&str> = parts.next().unwrap_or("").split(':').collect();
        let [task, height, seed, revision, controller] = head[..] else {
            return Err(bad("five fields first"));
        };
        let task = Task::parse(task).ok_or_else(|| bad("unknown task"))?;
        let height = height
            .parse()
            .map_err(|_| bad("the bed height is not a number"))?;
        let seed = seed.parse().map_err(|_| bad("the seed is not a number"))?;
        let revision = Revision::parse(revision).map_err(|e| bad(&e))?;
        let mut spec = DriveSpec::new(task, height, seed, revision);
        spec.controller = Controller::parse(controller)?;
        for part in parts {
            let (key, value) = part
                .split_once('=')
                .ok_or_else(|| bad("KEY=VALUE after `;`"))?;
            let p = &mut spec.perturbations;
            match key {
                "noise" => {
                    p.sensor_noise = value
                        .parse()
                        .ok()
                        .filter(|v: &f64| v.is_finite() && *v >= 0.0)
                        .ok_or_else(|| bad("the noise factor must be a number of at least 0"))?
                }
                "push" => p.push = Some(Push::parse(value)?),
                "occlude" => p.occlusion = Some(Occlusion::parse(value)?),
                "vision" => p.vision_drop = Some(VisionDrop::parse(value)?),
                "limit" => spec.speed_limit = parse_speed_limit(value)?,
                _ => return Err(bad(&format!("unknown key `{key}`"))),
            }
        }
        spec.trial()?;
        Ok(spec)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_text_form_reads_back_and_names_what_is_wrong() {
        let mut spec = DriveSpec::new(Task::Wiping, 620, 3, Revision::R2);
        assert_eq!(spec.to_text(), "wiping:620:3:2:network");
        spec.controller = Controller::Prior;
        spec.speed_limit = SpeedLimit::Panda;
        spec.perturbations = Perturbations {
            sensor_noise: 3.0,
            push: Some(Push {
                step: 100,
                arm: 1,
                radians: -0.25,
            }),
            occlusion: Some(Occlusion {
                camera: 0,
                from: 40,
                steps: 30,
            }),
            vision_drop: Some(VisionDrop {
                from: 150,
                levels: 1,
            }),
        };
        let text = spec.to_text();
        assert_eq!(
            text,
            "wiping:620:3:2:prior;noise=3;push=100:right:-0.25;occlude=left:40:30;vision=150:1;limit=panda"
        );
        assert_eq!(DriveSpec::parse_text(&text).unwrap(), spec);
        for (bad, says) in [
            ("wiping:620:3:2", "five fields"),
            ("cooking:620:3:2:network", "unknown task"),
            ("wiping:20:3:2:network", "between 300 and 1200"),
            ("wiping:620:3:2:network;noise=-1", "at least 0"),
            ("wiping:620:3:2:network;wind=3", "unknown key `wind`"),
            ("wiping:620:3:2:network;vision=150", "expected FROM:LEVELS"),
        ] {
            let e = DriveSpec::parse_text(bad).unwrap_err().to_string();
            assert!(e.contains(says), "{bad}: {e}");
        }
    }
}
