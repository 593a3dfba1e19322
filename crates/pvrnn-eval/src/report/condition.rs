//! The report's header: where it comes from ([`ReportMeta`]) and the inference condition in
//! the CLI's terms ([`Condition`]).

use serde::Serialize;

use crate::evaluate::Evaluation;

/// Where the report comes from (for its header).
#[derive(Clone, Debug, Serialize)]
pub struct ReportMeta {
    pub model: String,
    /// Training iteration of the model, when its file says.
    pub model_iteration: Option<u64>,
    pub dataset: String,
    pub split: String,
    /// Wall-clock seconds the inference runs took, and on how many worker threads.
    pub seconds: f64,
    pub threads: usize,
    /// Where the arithmetic ran: `cpu`, or `wgpu on` and the adapter (`--backend`).
    pub backend: String,
    /// The machine (`machine::describe`), e.g. `AMD EPYC (AVX2), 2 cores, 2 threads`.
    pub machine: String,
}

/// The inference condition, in the CLI's terms.
#[derive(Clone, Debug, Serialize)]
pub struct Condition {
    pub vision: String,
    pub proprio: bool,
    pub ablation: Vec<String>,
    /// `readout` or `inference` (meaningful only with an ablation).
    pub ablation_mode: String,
    pub window: usize,
    pub iterations: usize,
    pub lr: f64,
    pub seed: Option<u64>,
}

impl Condition {
    pub fn of(eval: &Evaluation) -> Self {
        let s = &eval.settings.inference;
        let res = &eval.resolutions;
        let vision = match s.observed.vision_levels {
            0 => "none".to_string(),
            n if n >= res.len() => "all".to_string(),
            n => res[..n]
                .iter()
                .rev()
                .map(|r| r.to_string())
                .collect::<Vec<_>>()
                .join("+"),
        };
        Self {
            vision,
            proprio: s.observed.proprio,
            ablation: pvrnn_core::ModuleId::ALL
                .iter()
                .filter(|m| s.ablation.contains(**m))
                .map(|m| m.name().to_string())
                .collect(),
            ablation_mode: s.ablation_mode.name().to_string(),
            window: s.window,
            iterations: s.iterations,
            lr: s.optimizer.lr,
            seed: match s.noise {
                pvrnn_core::NoiseMode::Sampled { seed } => Some(seed),
                pvrnn_core::NoiseMode::Zero => None,
            },
        }
    }

    /// e.g. `vision 16, proprioception on, no ablation`.
    pub fn label(&self) -> String {
        format!(
            "vision {}, proprioception {}, {}",
            self.vision,
            if self.proprio { "on" } else { "off" },
            if self.ablation.is_empty() {
                "no ablation".to_string()
            } else {
                format!(
                    "{} ablated ({} mode)",
                    self.ablation.join("+"),
                    self.ablation_mode
                )
            }
        )
    }
}
