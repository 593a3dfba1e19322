//! A model's card: how it was trained and how it scores against the baselines. `pvrnn
//! bundle` writes it into `bundle.json` (and as `README.md`), the explorer shows it.

use std::fmt::Write as _;

use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ModelCard {
    /// Training iterations of the shipped weights.
    pub iteration: Option<u64>,
    /// Wall-clock seconds of training up to that iteration (all resumes together).
    pub training_seconds: Option<f64>,
    /// Where it was trained (CPU, cores, threads).
    pub training_machine: Option<String>,
    /// The training data, in words.
    pub training_data: String,
    /// Free energy (total, per training sequence and step summed as in the log) at that
    /// iteration, from the training log.
    pub free_energy: Option<f64>,
    /// How the weights are stored and what that costs, as measured.
    pub weights: String,
    /// The model's settings that depart from the paper's configuration
    /// (`ModelConfig::departures_from_paper`); empty: the paper's configuration.
    #[serde(default)]
    pub departures: Vec<String>,
    /// Evaluations of these weights, one per condition.
    #[serde(default)]
    pub evaluations: Vec<CardEvaluation>,
}

/// One `pvrnn evaluate` report, condensed.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CardEvaluation {
    /// E.g. "vision 16, proprioception on".
    pub condition: String,
    pub sequences: usize,
    pub trials: usize,
    pub rows: Vec<CardRow>,
}

/// The model's mean error (± SE over sequences, each the mean of its trials) and the
/// baselines' on one group.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CardRow {
    /// `recon` (posterior reconstruction of x_t) or `next` (prior prediction of x_t+1).
    pub target: String,
    /// E.g. `v64`, `joints`.
    pub group: String,
    /// `all` or `changing` (pixels that change from the previous frame).
    pub pixels: String,
    /// Whether the group was observed in this condition.
    pub observed: bool,
    pub model: f64,
    pub model_se: Option<f64>,
    /// (baseline, value): `upsample`, `upsample_detail`, `nearest`, `previous`, `mean`.
    pub baselines: Vec<(String, f64)>,
}

impl ModelCard {
    /// The training line, e.g. "30,000 iterations, 6.1 h on AMD EPYC (2 threads)".
    pub fn training_summary(&self) -> String {
        let mut s = match self.iteration {
            Some(i) => format!("{} iterations", thousands(i)),
            None => "unknown iterations".into(),
        };
        if let Some(sec) = self.training_seconds {
            let _ = write!(s, ", {:.1} h", sec / 3600.0);
        }
        if let Some(m) = &self.training_machine {
            let _ = write!(s, " on {m}");
        }
        s
    }

    /// The card as Markdown (the bundle's README.md).
    pub fn markdown(&self, title: &str) -> String {
        let mut md = format!("# {title}\n\n");
        let _ = writeln!(md, "- **Training**: {}.", self.training_summary());
        let _ = writeln!(md, "- **Data**: {}.", self.training_data);
        if let Some(f) = self.free_energy {
            let _ = writeln!(md, "- **Free energy** at that iteration: {f:.1}.");
        }
        if self.departures.is_empty() {
            let _ = writeln!(md, "- **Configuration**: the paper's.");
        } else {
            let _ = writeln!(
                md,
                "- **Configuration**: the paper's except (departures from the paper): {}.",
                self.departures
                    .iter()
                    .map(|d| format!("`{d}`"))
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        }
        let _ = writeln!(md, "- **Weights**: {}.", self.weights);
        for e in &self.evaluations {
            let _ = writeln!(
                md,
                "\n## {} ({} test sequences x {} trials)\n\nMean squared error in model units (mean ± SE over sequences, each the mean of its trials; baselines are deterministic). * = not observed.\n",
                e.condition, e.sequences, e.trials
            );
            let _ = writeln!(md, "| target | group | pixels | model | baselines |");
            let _ = writeln!(md, "|---|---|---|---|---|");
            for r in &e.rows {
                let _ = writeln!(
                    md,
                    "| {} | {}{} | {} | {} | {} |",
                    r.target,
                    r.group,
                    if r.observed { "" } else { "*" },
                    r.pixels,
                    r.model_text(),
                    r.baselines_text()
                );
            }
        }
        md
    }
}

impl CardRow {
    pub fn model_text(&self) -> String {
        match self.model_se {
            Some(se) => format!("{} ± {}", sig4(self.model), sig4(se)),
            None => sig4(self.model),
        }
    }

    pub fn baselines_text(&self) -> String {
        self.baselines
            .iter()
            .map(|(name, v)| format!("{name} {}", sig4(*v)))
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// Four significant digits.
fn sig4(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let digits = (3 - v.abs().log10().floor() as i32).max(0) as usize;
    format!("{v:.digits$}")
}

/// An integer with thousands separators (`12000` -> `12,000`), as the cards and tables print
/// iterations.
pub fn thousands(n: u64) -> String {
    let s = n.to_string();
    let mut out = String::new();
    for (i, c) in s.chars().enumerate() {
        if i > 0 && (s.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(c);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_card_reads_as_markdown_and_round_trips_through_json() {
        let card = ModelCard {
            iteration: Some(30_000),
            training_seconds: Some(7200.0),
            training_machine: Some("AMD EPYC, 2 threads".into()),
            training_data: "caresim seed 0".into(),
            free_energy: Some(1234.5),
            weights: "f16".into(),
            departures: vec!["kl_weight: 0.01 (paper: 0.005)".into()],
            evaluations: vec![CardEvaluation {
                condition: "vision 16, proprioception on".into(),
                sequences: 6,
                trials: 5,
                rows: vec![CardRow {
                    target: "recon".into(),
                    group: "v64".into(),
                    pixels: "all".into(),
                    observed: false,
                    model: 0.012346,
                    model_se: Some(0.00012),
                    baselines: vec![("upsample".into(), 0.0095)],
                }],
            }],
        };
        assert_eq!(
            card.training_summary(),
            "30,000 iterations, 2.0 h on AMD EPYC, 2 threads"
        );
        let md = card.markdown("m");
        assert!(
            md.contains("| recon | v64* | all | 0.01235 ± 0.0001200 | upsample 0.009500 |"),
            "{md}"
        );
        assert!(
            md.contains(
                "the paper's except (departures from the paper): `kl_weight: 0.01 (paper: 0.005)`"
            ),
            "{md}"
        );
        let paper = ModelCard::default().markdown("m");
        assert!(paper.contains("**Configuration**: the paper's."), "{paper}");
        let back: ModelCard = serde_json::from_str(&serde_json::to_string(&card).unwrap()).unwrap();
        assert_eq!(back, card);
    }
}
