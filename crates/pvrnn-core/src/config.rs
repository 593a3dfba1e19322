//! The model configuration. Defaults are the paper's; every point `docs/model.md` marks as
//! \[decided\] is a field here, so a user can change it in a TOML file.
//!
//! The configuration travels inside every model file as JSON (safetensors metadata `config`).

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// The four modules, in the top-down order they are evaluated at every step.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ModuleId {
    Executive,
    Associative,
    Exteroceptive,
    Proprioceptive,
}

impl ModuleId {
    /// Top-down order: parents before children.
    pub const ALL: [ModuleId; 4] = [
        ModuleId::Executive,
        ModuleId::Associative,
        ModuleId::Exteroceptive,
        ModuleId::Proprioceptive,
    ];

    pub fn index(self) -> usize {
        self as usize
    }

    /// Tensor-name prefix and display name.
    pub fn name(self) -> &'static str {
        match self {
            ModuleId::Executive => "executive",
            ModuleId::Associative => "associative",
            ModuleId::Exteroceptive => "exteroceptive",
            ModuleId::Proprioceptive => "proprioceptive",
        }
    }

    /// The module whose d_t feeds this one top-down.
    pub fn parent(self) -> Option<ModuleId> {
        match self {
            ModuleId::Executive => None,
            ModuleId::Associative => Some(ModuleId::Executive),
            ModuleId::Exteroceptive | ModuleId::Proprioceptive => Some(ModuleId::Associative),
        }
    }

    pub fn from_name(name: &str) -> Option<ModuleId> {
        Self::ALL.into_iter().find(|m| m.name() == name)
    }
}

/// The two sensory modalities, each read out from the level-1 module of the same name.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Modality {
    Exteroceptive,
    Proprioceptive,
}

impl Modality {
    pub const ALL: [Modality; 2] = [Modality::Exteroceptive, Modality::Proprioceptive];

    pub fn index(self) -> usize {
        self as usize
    }
    pub fn name(self) -> &'static str {
        match self {
            Modality::Exteroceptive => "exteroceptive",
            Modality::Proprioceptive => "proprioceptive",
        }
    }
    /// The module whose d_t the read-out maps to predictions.
    pub fn module(self) -> ModuleId {
        match self {
            Modality::Exteroceptive => ModuleId::Exteroceptive,
            Modality::Proprioceptive => ModuleId::Proprioceptive,
        }
    }
}

/// Sizes and time constants of one module.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModuleConfig {
    /// Recurrent (deterministic) units.
    pub d: usize,
    /// Latent (stochastic) units.
    pub z: usize,
    /// Time constants `[fast, slow]`, each for half of the units (see `tau_order`).
    pub tau: [f64; 2],
}

/// A feed-forward read-out: tanh hidden layers, then a tanh output layer.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReadoutConfig {
    /// Hidden layer widths, bottom (module side) first.
    pub hidden: Vec<usize>,
    /// \[decided\] Hidden layers have a trainable bias.
    pub hidden_bias: bool,
    /// \[decided\] The output layer has no bias (eq. 13).
    pub output_bias: bool,
}

/// Layout of the exteroceptive vector: for each resolution (ascending), each camera's
/// row-major, pixel-interleaved image.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VisionLayout {
    /// Cameras, in the dataset's order (`pvrnn init --dataset` sets it from the dataset).
    pub cameras: usize,
    /// Colour channels per pixel: 3 (RGB) for every dataset this project reads.
    pub channels: usize,
    /// Square image sizes, ascending; each lower level is a 2x2 box average of the next.
    pub resolutions: Vec<usize>,
}

impl VisionLayout {
    /// Length of one level (all cameras) in the exteroceptive vector.
    pub fn level_dims(&self, level: usize) -> usize {
        let r = self.resolutions[level];
        self.cameras * self.channels * r * r
    }

    /// Offset of `level` in the exteroceptive vector.
    pub fn level_offset(&self, level: usize) -> usize {
        (0..level).map(|l| self.level_dims(l)).sum()
    }

    /// Offset of one camera's image at one level.
    pub fn image_offset(&self, level: usize, camera: usize) -> usize {
        let r = self.resolutions[level];
        self.level_offset(level) + camera * self.channels * r * r
    }

    pub fn dims(&self) -> usize {
        self.level_offset(self.resolutions.len())
    }

    /// Number of leading dimensions observed when the lowest `levels` resolutions are given.
    pub fn observed_dims(&self, levels: usize) -> usize {
        self.level_offset(levels.min(self.resolutions.len()))
    }
}

/// What each modality's accuracy term is divided by when only part of it is observed
/// (spec, \[decided\] "Accuracy under partial observation").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AccuracyNormalisation {
    /// The number of observed dimensions (the spec's default): every observed condition
    /// weighs its accuracy like full observation does.
    #[default]
    Observed,
    /// The modality's full dimension: fewer observed pixels weigh less against the
    /// complexity terms.
    Full,
}

impl AccuracyNormalisation {
    pub fn name(self) -> &'static str {
        match self {
            AccuracyNormalisation::Observed => "observed",
            AccuracyNormalisation::Full => "full",
        }
    }

    /// The divisor of a modality's summed squared error: `observed` of `dims` dimensions.
    pub fn divisor(self, observed: usize, dims: usize) -> usize {
        match self {
            AccuracyNormalisation::Observed => observed,
            AccuracyNormalisation::Full => dims,
        }
    }
}

/// Which half of a module's units gets the smaller time constant.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TauOrder {
    /// \[decided\] The first half of a module's units gets the smaller (faster) tau.
    FastFirst,
    /// The first half gets the larger (slower) tau.
    SlowFirst,
}

/// How the adaptive variables a start before learning.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PosteriorInit {
    /// \[decided\] a = the prior's pre-activations of a first forward pass (mean path, eps = 0).
    Prior,
    /// a = 0: posterior N(0, 1).
    Zero,
}

/// Rectified Adam (Liu et al. 2020), as in PyTorch's `RAdam`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RAdamConfig {
    /// Learning rate (step size).
    pub lr: f64,
    /// Decay of the first-moment (mean gradient) estimate.
    pub beta1: f64,
    /// Decay of the second-moment (squared gradient) estimate.
    pub beta2: f64,
    /// Added to the second moment's square root in the denominator.
    pub eps: f64,
    /// \[decided\] The adaptive (rectified) step is used once rho_t exceeds this (PyTorch: 5).
    pub rectify_threshold: f64,
    /// \[decided\] L2 penalty added to the gradient; 0 = none.
    pub weight_decay: f64,
}

/// Learning settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainConfig {
    /// The optimiser of weights and adaptive variables during learning.
    pub optimizer: RAdamConfig,
    /// The paper's run length.
    pub iterations: u64,
}

/// Online inference (error regression) settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InferenceConfig {
    /// H: steps in the sliding window.
    pub window: usize,
    /// Updates of the window's adaptive variables per step.
    pub iterations: usize,
    /// \[decided\] RAdam with lr 1.0 ...
    pub optimizer: RAdamConfig,
    /// \[decided\] ... and moments reset at every new step.
    pub reset_moments_each_step: bool,
}

/// Proprioception scaling to [-0.9, 0.9] by the learning set's per-dimension range.
/// Vision is always `v / 255 * 1.8 - 0.9`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Normalisation {
    /// Per proprioceptive dimension: the learning split's minimum (recorded units).
    pub proprio_min: Vec<f64>,
    /// Per proprioceptive dimension: the learning split's maximum (recorded units).
    pub proprio_max: Vec<f64>,
}

impl Normalisation {
    /// Raw proprioceptive value of dimension `i` to model units (a constant dimension maps to 0).
    pub fn proprio_to_model(&self, i: usize, v: f64) -> f64 {
        let (lo, hi) = (self.proprio_min[i], self.proprio_max[i]);
        if hi > lo {
            (v - lo) / (hi - lo) * 1.8 - 0.9
        } else {
            0.0
        }
    }

    /// Model units back to raw proprioceptive units.
    pub fn proprio_from_model(&self, i: usize, v: f64) -> f64 {
        let (lo, hi) = (self.proprio_min[i], self.proprio_max[i]);
        if hi > lo {
            (v + 0.9) / 1.8 * (hi - lo) + lo
        } else {
            lo
        }
    }

    /// A spread (a standard deviation) of dimension `i` in raw units, in model units.
    pub fn noise_to_model(&self, i: usize, spread: f64) -> f64 {
        let (lo, hi) = (self.proprio_min[i], self.proprio_max[i]);
        if hi > lo {
            spread / (hi - lo) * 1.8
        } else {
            0.0
        }
    }

    /// An 8-bit channel value to model units.
    pub fn vision_to_model(v: f64) -> f64 {
        v / 255.0 * 1.8 - 0.9
    }

    /// Model units back to an 8-bit channel value.
    pub fn vision_from_model(v: f64) -> u8 {
        ((v + 0.9) / 1.8 * 255.0).round().clamp(0.0, 255.0) as u8
    }
}

/// The whole model configuration.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ModelConfig {
    /// The top module: slowest time constants, no parent.
    pub executive: ModuleConfig,
    /// Below the executive; the parent of both sensory modules.
    pub associative: ModuleConfig,
    /// The vision module; its d is read out into images.
    pub exteroceptive: ModuleConfig,
    /// The proprioception module; its d is read out into joint angles and other channels.
    pub proprioceptive: ModuleConfig,
    /// From the exteroceptive module's d to the vision vector.
    pub exteroceptive_readout: ReadoutConfig,
    /// From the proprioceptive module's d to the proprioceptive vector.
    pub proprioceptive_readout: ReadoutConfig,
    /// Cameras and resolutions of the vision vector.
    pub vision: VisionLayout,
    /// Proprioceptive dimensions: the dataset's joint angles, then torques, then extra
    /// channels (the paper's robot: 14 + 14 + 0; `pvrnn init --dataset` sets it).
    pub proprio_dims: usize,
    /// W: weight of every module's complexity term.
    pub kl_weight: f64,
    /// \[decided\] Divisor of each modality's accuracy under partial observation.
    pub accuracy_normalisation: AccuracyNormalisation,
    /// \[decided\] The prior has no bias (eqs. 5-6).
    pub prior_bias: bool,
    /// \[decided\] The first half of a module's units gets the smaller tau.
    pub tau_order: TauOrder,
    /// \[decided\] Fixed recurrent bias ~ N(0, variance), variance (not std) 10.
    pub recurrent_bias_variance: f64,
    /// Gain of Xavier-normal weight initialisation.
    pub xavier_gain: f64,
    /// \[decided\] Initial adaptive variables.
    pub posterior_init: PosteriorInit,
    /// Not in the paper (off by default): bound every log sigma, prior's and posterior's,
    /// softly to (-B, B) as B tanh(pre-activation / B), so that a prior's sigma cannot
    /// explode on states learning never visited. A departure; results say when it is on.
    pub log_sigma_bound: Option<f64>,
    /// Learning.
    pub train: TrainConfig,
    /// Online inference (error regression).
    pub inference: InferenceConfig,
    /// Set when a model is trained on a dataset folder; absent for pre-normalised inputs.
    pub normalisation: Option<Normalisation>,
}

impl Default for ModelConfig {
    fn default() -> Self {
        let module = |d, z, fast, slow| ModuleConfig {
            d,
            z,
            tau: [fast, slow],
        };
        Self {
            executive: module(30, 30, 8.0, 16.0),
            associative: module(30, 30, 4.0, 8.0),
            exteroceptive: module(30, 40, 2.0, 4.0),
            proprioceptive: module(30, 30, 2.0, 4.0),
            exteroceptive_readout: ReadoutConfig {
                hidden: vec![40, 50],
                hidden_bias: true,
                output_bias: false,
            },
            proprioceptive_readout: ReadoutConfig {
                hidden: vec![40],
                hidden_bias: true,
                output_bias: false,
            },
            vision: VisionLayout {
                cameras: 2,
                channels: 3,
                resolutions: vec![16, 32, 64],
            },
            proprio_dims: 28,
            kl_weight: 0.005,
            accuracy_normalisation: AccuracyNormalisation::Observed,
            prior_bias: false,
            tau_order: TauOrder::FastFirst,
            recurrent_bias_variance: 10.0,
            xavier_gain: 1.0,
            posterior_init: PosteriorInit::Prior,
            log_sigma_bound: None,
            train: TrainConfig {
                optimizer: RAdamConfig {
                    lr: 0.001,
                    beta1: 0.9,
                    beta2: 0.999,
                    eps: 1e-8,
                    rectify_threshold: 4.0,
                    weight_decay: 0.0,
                },
                iterations: 100_000,
            },
            inference: InferenceConfig {
                window: 30,
                iterations: 50,
                optimizer: RAdamConfig {
                    lr: 1.0,
                    beta1: 0.9,
                    beta2: 0.999,
                    eps: 1e-8,
                    rectify_threshold: 4.0,
                    weight_decay: 0.0,
                },
                reset_moments_each_step: true,
            },
            normalisation: None,
        }
    }
}

impl ModelConfig {
    pub fn module(&self, id: ModuleId) -> &ModuleConfig {
        match id {
            ModuleId::Executive => &self.executive,
            ModuleId::Associative => &self.associative,
            ModuleId::Exteroceptive => &self.exteroceptive,
            ModuleId::Proprioceptive => &self.proprioceptive,
        }
    }

    pub fn readout(&self, modality: Modality) -> &ReadoutConfig {
        match modality {
            Modality::Exteroceptive => &self.exteroceptive_readout,
            Modality::Proprioceptive => &self.proprioceptive_readout,
        }
    }

    /// Output dimensions of a modality.
    pub fn modality_dims(&self, modality: Modality) -> usize {
        match modality {
            Modality::Exteroceptive => self.vision.dims(),
            Modality::Proprioceptive => self.proprio_dims,
        }
    }

    /// Per-unit time constants of a module.
    pub fn taus(&self, id: ModuleId) -> Vec<f64> {
        let m = self.module(id);
        let (first, second) = match self.tau_order {
            TauOrder::FastFirst => (m.tau[0], m.tau[1]),
            TauOrder::SlowFirst => (m.tau[1], m.tau[0]),
        };
        (0..m.d)
            .map(|i| if i < m.d / 2 { first } else { second })
            .collect()
    }

    /// Checks every size, rate and constant; the message names the offending field.
    pub fn validate(&self) -> Result<()> {
        let bad = |msg: String| Err(Error::Config(msg));
        for id in ModuleId::ALL {
            let m = self.module(id);
            let name = id.name();
            if m.d == 0 || m.z == 0 {
                return bad(format!(
                    "{name}: d and z must be at least 1 (got d = {}, z = {})",
                    m.d, m.z
                ));
            }
            for tau in m.tau {
                if !(tau >= 1.0 && tau.is_finite()) {
                    return bad(format!(
                        "{name}.tau: time constants must be finite and >= 1 (got {tau})"
                    ));
                }
            }
        }
        for modality in Modality::ALL {
            let r = self.readout(modality);
            if r.hidden.contains(&0) {
                return bad(format!(
                    "{}_readout.hidden: layer widths must be >= 1",
                    modality.name()
                ));
            }
        }
        let v = &self.vision;
        if v.cameras == 0 || v.channels == 0 || v.resolutions.is_empty() {
            return bad("vision: cameras, channels and resolutions must be non-empty".into());
        }
        if v.resolutions.windows(2).any(|w| w[0] >= w[1]) || v.resolutions[0] == 0 {
            return bad(format!(
                "vision.resolutions must be positive and ascending (got {:?})",
                v.resolutions
            ));
        }
        if self.proprio_dims == 0 {
            return bad("proprio_dims must be at least 1".into());
        }
        if !(self.kl_weight >= 0.0 && self.kl_weight.is_finite()) {
            return bad(format!(
                "kl_weight must be finite and >= 0 (got {})",
                self.kl_weight
            ));
        }
        if let Some(b) = self.log_sigma_bound
            && !(b > 0.0 && b.is_finite())
        {
            return bad(format!("log_sigma_bound must be finite and > 0 (got {b})"));
        }
        if !(self.recurrent_bias_variance >= 0.0 && self.recurrent_bias_variance.is_finite()) {
            return bad("recurrent_bias_variance must be finite and >= 0".into());
        }
        if !(self.xavier_gain > 0.0 && self.xavier_gain.is_finite()) {
            return bad("xavier_gain must be finite and > 0".into());
        }
        validate_radam("train.optimizer", &self.train.optimizer)?;
        validate_radam("inference.optimizer", &self.inference.optimizer)?;
        if self.inference.window == 0 {
            return bad("inference.window must be at least 1".into());
        }
        if let Some(n) = &self.normalisation {
            if n.proprio_min.len() != self.proprio_dims || n.proprio_max.len() != self.proprio_dims
            {
                return bad(format!(
                    "normalisation: proprio_min/max need {} values (got {} and {})",
                    self.proprio_dims,
                    n.proprio_min.len(),
                    n.proprio_max.len()
                ));
            }
            if n.proprio_min
                .iter()
                .chain(&n.proprio_max)
                .any(|v| !v.is_finite())
            {
                return bad("normalisation: ranges must be finite".into());
            }
        }
        Ok(())
    }

    /// Every setting that differs from the paper's configuration (`ModelConfig::default()`),
    /// as `path: value (paper: value)`, e.g. `kl_weight: 0.01 (paper: 0.005)`. What is
    /// fitted to a dataset (its cameras and resolutions, proprioceptive channels and ranges)
    /// and the planned iteration count are not departures. A model card lists these, so a
    /// recipe is stated where the model is.
    pub fn departures_from_paper(&self) -> Vec<String> {
        fn flatten(prefix: &str, v: &serde_json::Value, out: &mut Vec<(String, String)>) {
            match v {
                serde_json::Value::Object(map) => {
                    for (k, v) in map {
                        let path = if prefix.is_empty() {
                            k.clone()
                        } else {
                            format!("{prefix}.{k}")
                        };
                        flatten(&path, v, out);
                    }
                }
                other => out.push((prefix.to_string(), other.to_string())),
            }
        }
        let fitted = [
            "vision",
            "proprio_dims",
            "normalisation",
            "train.iterations",
        ];
        let values = |c: &ModelConfig| {
            let mut out = Vec::new();
            flatten("", &serde_json::to_value(c).expect("serialises"), &mut out);
            out.retain(|(path, _)| {
                !fitted
                    .iter()
                    .any(|f| path == f || path.starts_with(&format!("{f}.")))
            });
            out
        };
        let paper: std::collections::BTreeMap<String, String> =
            values(&ModelConfig::default()).into_iter().collect();
        let mut out: Vec<String> = values(self)
            .into_iter()
            .filter(|(path, v)| paper.get(path) != Some(v))
            .map(|(path, v)| match paper.get(&path) {
                Some(p) => format!("{path}: {v} (paper: {p})"),
                None => format!("{path}: {v}"),
            })
            .collect();
        out.sort();
        out
    }

    /// The configuration as the JSON stored in model files.
    pub fn to_json(&self) -> String {
        serde_json::to_string(self).expect("configuration serialises")
    }

    pub fn from_json(text: &str) -> Result<Self> {
        let config: Self =
            serde_json::from_str(text).map_err(|e| Error::Config(format!("bad JSON: {e}")))?;
        config.validate()?;
        Ok(config)
    }
}

pub(crate) fn validate_radam(name: &str, o: &RAdamConfig) -> Result<()> {
    let ok = o.lr > 0.0
        && o.lr.is_finite()
        && (0.0..1.0).contains(&o.beta1)
        && (0.0..1.0).contains(&o.beta2)
        && o.eps > 0.0
        && o.rectify_threshold.is_finite()
        && o.weight_decay >= 0.0
        && o.weight_decay.is_finite();
    if ok {
        Ok(())
    } else {
        Err(Error::Config(format!(
            "{name}: need lr > 0, 0 <= beta < 1, eps > 0, finite rectify_threshold, weight_decay >= 0 (got {o:?})"
        )))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    #[cfg(target_arch = "wasm32")]
    use wasm_bindgen_test::wasm_bindgen_test as test;

    #[test]
    fn defaults_are_the_papers() {
        let c = ModelConfig::default();
        c.validate().unwrap();
        assert_eq!(c.vision.dims(), 32_256);
        assert_eq!(c.vision.observed_dims(1), 1536);
        assert_eq!(c.vision.observed_dims(2), 1536 + 6144);
        assert_eq!(c.taus(ModuleId::Executive)[0], 8.0);
        assert_eq!(c.taus(ModuleId::Executive)[29], 16.0);
        assert_eq!(c.exteroceptive.z, 40);
    }

    #[test]
    fn json_round_trip() {
        let c = ModelConfig::default();
        assert_eq!(ModelConfig::from_json(&c.to_json()).unwrap(), c);
    }

    #[test]
    fn departures_name_what_differs_from_the_paper_but_not_what_a_dataset_fits() {
        let mut c = ModelConfig::default();
        assert!(c.departures_from_paper().is_empty());
        c.vision.resolutions = vec![8, 16];
        c.proprio_dims = 9;
        c.train.iterations = 40_000;
        c.normalisation = Some(Normalisation {
            proprio_min: vec![0.0; 9],
            proprio_max: vec![1.0; 9],
        });
        assert!(c.departures_from_paper().is_empty());
        c.kl_weight = 0.01;
        c.log_sigma_bound = Some(5.0);
        c.exteroceptive_readout.hidden = vec![40, 200];
        c.inference.optimizer.lr = 0.5;
        assert_eq!(
            c.departures_from_paper(),
            [
                "exteroceptive_readout.hidden: [40,200] (paper: [40,50])",
                "inference.optimizer.lr: 0.5 (paper: 1.0)",
                "kl_weight: 0.01 (paper: 0.005)",
                "log_sigma_bound: 5.0 (paper: null)",
            ]
        );
    }

    #[test]
    fn bad_values_are_named() {
        let mut c = ModelConfig::default();
        c.associative.tau = [0.5, 8.0];
        let e = c.validate().unwrap_err().to_string();
        assert!(e.contains("associative.tau"), "{e}");
        let mut c = ModelConfig::default();
        c.vision.resolutions = vec![32, 16];
        assert!(c.validate().unwrap_err().to_string().contains("ascending"));
    }
}
