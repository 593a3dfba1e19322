//! Model inputs (normalised observations) and the conditions under which they are observed.

use serde::{Deserialize, Serialize};

use crate::config::{Modality, ModelConfig, ModuleId};
use crate::error::{Error, Result};
use crate::{Real, Tensor};

/// Normalised observations of S sequences: `extero [S, T, vision dims]`,
/// `proprio [S, T, proprio dims]`, and each sequence's length (<= T; steps beyond it are
/// padding and ignored).
#[derive(Clone, Debug)]
pub struct Observations<T> {
    extero: Tensor<T>,
    proprio: Tensor<T>,
    lengths: Vec<usize>,
    /// Names this content (see [`Observations::id`]); a clone shares it.
    id: u64,
}

impl<T: PartialEq> PartialEq for Observations<T> {
    fn eq(&self, other: &Self) -> bool {
        self.extero == other.extero
            && self.proprio == other.proprio
            && self.lengths == other.lengths
    }
}

/// A fresh id (an [`Observations::id`], or any other promise that the same id names the
/// same targets: `Request::resident_targets`).
pub(crate) fn next_id() -> u64 {
    static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);
    NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
}

impl<T: Real> Observations<T> {
    /// Checks shapes, lengths and that every value is finite.
    pub fn new(extero: Tensor<T>, proprio: Tensor<T>, lengths: Option<Vec<usize>>) -> Result<Self> {
        for (name, t) in [("x_extero", &extero), ("x_proprio", &proprio)] {
            if t.shape().len() != 3 || t.shape()[0] == 0 || t.shape()[1] == 0 {
                return Err(Error::Shape {
                    what: "inputs".into(),
                    name: name.into(),
                    found: t.shape().to_vec(),
                    expected: "[sequences, steps, dims] with sequences, steps >= 1".into(),
                });
            }
            if let Some((flat, value)) = t.first_non_finite() {
                return Err(Error::NonFinite {
                    what: "inputs".into(),
                    name: name.into(),
                    index: t.unravel(flat),
                    value: value.to_f64(),
                });
            }
        }
        let (s, steps) = (extero.shape()[0], extero.shape()[1]);
        if proprio.shape()[..2] != extero.shape()[..2] {
            return Err(Error::Mismatch(format!(
                "inputs: x_extero is {:?} but x_proprio is {:?}; both need the same [sequences, steps]",
                extero.shape(),
                proprio.shape()
            )));
        }
        let lengths = lengths.unwrap_or_else(|| vec![steps; s]);
        if lengths.len() != s || lengths.iter().any(|&l| l == 0 || l > steps) {
            return Err(Error::Mismatch(format!(
                "inputs: lengths {lengths:?} must give 1..={steps} steps for each of {s} sequences"
            )));
        }
        Ok(Self {
            extero,
            proprio,
            lengths,
            id: next_id(),
        })
    }

    /// Identifies this content for the process's lifetime: observations are immutable, so
    /// two with the same id hold the same values (a clone keeps the id; every other
    /// constructor makes a new one). A GPU backend keeps learning targets resident under it.
    pub fn id(&self) -> u64 {
        self.id
    }

    pub fn sequences(&self) -> usize {
        self.extero.shape()[0]
    }
    /// Padded length T.
    pub fn steps(&self) -> usize {
        self.extero.shape()[1]
    }
    pub fn lengths(&self) -> &[usize] {
        &self.lengths
    }
    pub fn dims(&self, modality: Modality) -> usize {
        self.tensor(modality).shape()[2]
    }
    pub fn tensor(&self, modality: Modality) -> &Tensor<T> {
        match modality {
            Modality::Exteroceptive => &self.extero,
            Modality::Proprioceptive => &self.proprio,
        }
    }
    /// One step's observation of one modality.
    pub fn step(&self, modality: Modality, sequence: usize, t: usize) -> &[T] {
        self.tensor(modality).sub(&[sequence, t])
    }

    /// Fails with a message naming both sizes if these inputs do not fit the model.
    pub fn check_fits(&self, config: &ModelConfig) -> Result<()> {
        for modality in Modality::ALL {
            let (got, want) = (self.dims(modality), config.modality_dims(modality));
            if got != want {
                return Err(Error::Mismatch(format!(
                    "inputs: {} has {got} dimensions per step but the model expects {want}{}",
                    match modality {
                        Modality::Exteroceptive => "x_extero",
                        Modality::Proprioceptive => "x_proprio",
                    },
                    match modality {
                        Modality::Exteroceptive => format!(
                            " ({} cameras x {} channels at resolutions {:?})",
                            config.vision.cameras,
                            config.vision.channels,
                            config.vision.resolutions
                        ),
                        Modality::Proprioceptive => String::new(),
                    }
                )));
            }
        }
        Ok(())
    }

    pub fn cast<U: Real>(&self) -> Observations<U> {
        Observations {
            extero: self.extero.cast(),
            proprio: self.proprio.cast(),
            lengths: self.lengths.clone(),
            id: next_id(),
        }
    }

    /// The sub-set of sequences `which`, in that order.
    pub fn select(&self, which: &[usize]) -> Result<Self> {
        let pick = |t: &Tensor<T>| -> Result<Tensor<T>> {
            let mut data = Vec::with_capacity(which.len() * t.shape()[1] * t.shape()[2]);
            for &s in which {
                if s >= t.shape()[0] {
                    return Err(Error::InvalidArgument(format!(
                        "sequence {s} does not exist (the inputs hold {})",
                        t.shape()[0]
                    )));
                }
                data.extend_from_slice(t.sub(&[s]));
            }
            Tensor::from_vec(&[which.len(), t.shape()[1], t.shape()[2]], data)
        };
        Ok(Self {
            extero: pick(&self.extero)?,
            proprio: pick(&self.proprio)?,
            lengths: which.iter().map(|&s| self.lengths[s]).collect(),
            id: next_id(),
        })
    }
}

/// Which sensory dimensions enter the free energy.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct Observed {
    /// How many of the lowest vision resolutions are observed: 0 = none, 1 = 16x16 only,
    /// 2 = 32+16, 3 = all (for the default layout).
    pub vision_levels: usize,
    pub proprio: bool,
}

impl Observed {
    pub fn all(config: &ModelConfig) -> Self {
        Self {
            vision_levels: config.vision.resolutions.len(),
            proprio: true,
        }
    }

    /// Observed leading dimensions of a modality (its observed rows of the output layer).
    pub fn dims(&self, config: &ModelConfig, modality: Modality) -> usize {
        match modality {
            Modality::Exteroceptive => config.vision.observed_dims(self.vision_levels),
            Modality::Proprioceptive => {
                if self.proprio {
                    config.proprio_dims
                } else {
                    0
                }
            }
        }
    }

    /// Parses the vision part: `all`, `none`, or the resolutions observed, e.g. `16`,
    /// `32+16`, `64+32+16` (the lowest levels must be included).
    pub fn parse_vision(text: &str, config: &ModelConfig) -> Result<usize> {
        let res = &config.vision.resolutions;
        let text = text.trim();
        match text {
            "all" => return Ok(res.len()),
            "none" | "0" => return Ok(0),
            _ => {}
        }
        let mut given: Vec<usize> = Vec::new();
        for part in text.split('+') {
            let r: usize = part.trim().parse().map_err(|_| {
                Error::InvalidArgument(format!(
                    "vision condition `{text}`: expected all, none, or resolutions like 32+16"
                ))
            })?;
            given.push(r);
        }
        given.sort_unstable();
        given.dedup();
        // The observed set must be the lowest k levels; a single number means "up to it".
        let levels = if given.len() == 1 {
            res.iter().position(|&r| r == given[0]).map(|p| p + 1)
        } else if given[..] == res[..given.len().min(res.len())] {
            Some(given.len())
        } else {
            None
        };
        levels.ok_or_else(|| {
            Error::InvalidArgument(format!(
                "vision condition `{text}`: the model's resolutions are {res:?}; observe all, none, or the lowest ones (e.g. {})",
                res.iter().take(2).rev().map(|r| r.to_string()).collect::<Vec<_>>().join("+")
            ))
        })
    }

    /// Human-readable vision condition, e.g. `32+16`.
    pub fn vision_label(&self, config: &ModelConfig) -> String {
        if self.vision_levels == 0 {
            return "none".into();
        }
        config.vision.resolutions[..self.vision_levels]
            .iter()
            .rev()
            .map(|r| r.to_string())
            .collect::<Vec<_>>()
            .join("+")
    }
}

/// When an ablated module's z is 0 (spec, "Conditions a user can set at inference").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AblationMode {
    /// Inference runs as standard; the final pass of each step is then read out again with
    /// the module's z = 0 (same a's, eps and held state). The paper's contribution maps
    /// (Figs 2B, 3B): what the module adds to the prediction the network actually made.
    #[default]
    Readout,
    /// z = 0 during every inference iteration too, so the other modules may compensate.
    Inference,
}

impl AblationMode {
    pub fn name(self) -> &'static str {
        match self {
            AblationMode::Readout => "readout",
            AblationMode::Inference => "inference",
        }
    }

    pub fn parse(text: &str) -> Result<Self> {
        match text {
            "readout" => Ok(AblationMode::Readout),
            "inference" => Ok(AblationMode::Inference),
            other => Err(Error::InvalidArgument(format!(
                "unknown ablation mode `{other}` (readout or inference)"
            ))),
        }
    }

    /// Runs written before the two modes existed ablated during inference.
    pub fn legacy() -> Self {
        AblationMode::Inference
    }
}

/// Modules whose latent z is set to 0 when generating.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct Ablation(pub [bool; 4]);

impl Ablation {
    pub fn none() -> Self {
        Self([false; 4])
    }
    pub fn of(modules: &[ModuleId]) -> Self {
        let mut a = [false; 4];
        for m in modules {
            a[m.index()] = true;
        }
        Self(a)
    }
    pub fn contains(&self, id: ModuleId) -> bool {
        self.0[id.index()]
    }
    pub fn is_none(&self) -> bool {
        !self.0.iter().any(|&a| a)
    }
    /// The ablation mode a condition with this ablation states: `mode`, or the default
    /// when nothing is ablated (the mode then changes nothing), so that equal runs compare
    /// equal.
    pub fn canonical_mode(&self, mode: AblationMode) -> AblationMode {
        if self.is_none() {
            AblationMode::default()
        } else {
            mode
        }
    }
    /// e.g. `executive+proprioceptive`, or `none`.
    pub fn label(&self) -> String {
        let names: Vec<&str> = ModuleId::ALL
            .iter()
            .filter(|id| self.contains(**id))
            .map(|id| id.name())
            .collect();
        if names.is_empty() {
            "none".into()
        } else {
            names.join("+")
        }
    }
    /// Parses a comma-separated list of module names (or `none`).
    pub fn parse(text: &str) -> Result<Self> {
        let mut a = [false; 4];
        for name in text
            .split(',')
            .map(str::trim)
            .filter(|s| !s.is_empty() && *s != "none")
        {
            let id = ModuleId::from_name(name).ok_or_else(|| {
                Error::InvalidArgument(format!(
                    "unknown module `{name}` (modules: executive, associative, exteroceptive, proprioceptive)"
                ))
            })?;
            a[id.index()] = true;
        }
        Ok(Self(a))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    #[cfg(target_arch = "wasm32")]
    use wasm_bindgen_test::wasm_bindgen_test as test;

    #[test]
    fn vision_conditions_parse() {
        let c = ModelConfig::default();
        assert_eq!(Observed::parse_vision("all", &c).unwrap(), 3);
        assert_eq!(Observed::parse_vision("none", &c).unwrap(), 0);
        assert_eq!(Observed::parse_vision("16", &c).unwrap(), 1);
        assert_eq!(Observed::parse_vision("32+16", &c).unwrap(), 2);
        assert_eq!(Observed::parse_vision("16+32+64", &c).unwrap(), 3);
        assert!(Observed::parse_vision("64+32", &c).is_err());
        assert!(Observed::parse_vision("twelve", &c).is_err());
        let o = Observed {
            vision_levels: 2,
            proprio: true,
        };
        assert_eq!(o.vision_label(&c), "32+16");
        assert_eq!(o.dims(&c, Modality::Exteroceptive), 7680);
    }

    #[test]
    fn nan_inputs_are_rejected_with_position() {
        let mut x = Tensor::<f32>::zeros(&[2, 3, 4]);
        x.data_mut()[13] = f32::NAN;
        let p = Tensor::<f32>::zeros(&[2, 3, 1]);
        let e = Observations::new(x, p, None).unwrap_err().to_string();
        assert!(e.contains("x_extero") && e.contains("[1, 0, 1]"), "{e}");
    }

    #[test]
    fn ablation_parses_module_names() {
        let a = Ablation::parse("executive, proprioceptive").unwrap();
        assert!(a.contains(ModuleId::Executive) && !a.contains(ModuleId::Associative));
        assert!(Ablation::parse("cortex").is_err());
    }
}
