//! Uncertainty (Fig 4): prior sigma between tasks (tested as equivalence) and its change
//! over time.

use std::fmt::Write as _;
use std::path::Path;

use anyhow::Result;
use pvrnn_core::{ModelConfig, ModuleId};
use pvrnn_eval::plots::bar_chart;
use pvrnn_eval::report::sig;
use serde::Serialize;
use serde_json::{Value, json};

use super::{Results, bar, mean_se_text, module_names, p_text, per_network};
use crate::run::InferResult;
use crate::stats::{self, mean_se};

#[derive(Serialize)]
struct TaskComparison {
    module: String,
    measure: String,
    repositioning: Vec<f64>,
    wiping: Vec<f64>,
    paired_t: Option<stats::PairedT>,
    /// Repositioning − wiping with its 95% CI and the detectable difference.
    difference: Option<stats::Difference>,
    /// Prior sigma only: the equivalence test of "no difference between tasks".
    equivalence: Option<stats::Equivalence>,
}

/// The equivalence margin of a "no difference" claim, relative to the level compared:
/// Fig 4A's (±10% of the mean prior sigma of the two tasks, fixed before the converged runs) and
/// Fig 6A's (±10% of the none-added condition's mean error; the same rule, fixed on
/// 2026-11-29 before either interference direction was complete, docs/experiments.md).
pub const EQUIVALENCE_MARGIN: f64 = 0.10;

pub(super) fn uncertainty(r: &Results, out: &Path, stamp: &str, md: &mut String) -> Result<Value> {
    let _ = writeln!(
        md,
        "## Prior uncertainty per module and task ({stamp})\n\nMean prior σ and mean |Δσ_p| between steps, everything observed; per network, then mean ± SE over networks; paired t-tests (repositioning vs wiping) across networks.\n"
    );
    md.push_str("| module | measure | repositioning | wiping | t | df | p | d_z |\n|---|---|---|---|---|---|---|---|\n");
    let mut comparisons = Vec::new();
    for (label, measure) in [
        ("prior sigma", 0),
        ("mean absolute change of prior sigma", 1),
    ] {
        let mut groups = Vec::new();
        // The four modules, then all of them (the paper's "All": every latent unit alike,
        // so modules weigh by their z units; the experiments train the default sizes).
        let units = ModuleId::ALL.map(|id| ModelConfig::default().module(id).z as f64);
        let mut names = module_names();
        names.push("all modules".into());
        for (m, name) in names.iter().enumerate() {
            let value = |x: &InferResult| {
                let v = if measure == 0 {
                    x.sigma_p
                } else {
                    x.sigma_p_change
                };
                if m < 4 {
                    v[m]
                } else {
                    v.iter().zip(&units).map(|(a, w)| a * w).sum::<f64>()
                        / units.iter().sum::<f64>()
                }
            };
            let of = |task: &'static str| {
                per_network(&r.infers, &|x| x.task == task, &|x| Some(value(x)))
            };
            let (a, b) = (of("repositioning"), of("wiping"));
            let paired: Vec<usize> = a.keys().filter(|k| b.contains_key(k)).copied().collect();
            let av: Vec<f64> = paired.iter().map(|k| a[k]).collect();
            let bv: Vec<f64> = paired.iter().map(|k| b[k]).collect();
            let t = stats::paired_t(&av, &bv);
            let level = (mean_se(&av).0 + mean_se(&bv).0) / 2.0;
            let equivalence = (measure == 0)
                .then(|| stats::equivalence(&av, &bv, EQUIVALENCE_MARGIN * level.abs(), true))
                .flatten();
            let _ = writeln!(
                md,
                "| {name} | {label} | {} | {} | {} | {} | {} | {} |",
                mean_se_text(&av),
                mean_se_text(&bv),
                t.as_ref().map_or("–".into(), |t| sig(t.t)),
                t.as_ref().map_or("–".into(), |t| t.df.to_string()),
                p_text(t.as_ref().and_then(|t| t.p)),
                t.as_ref().map_or("–".into(), |t| sig(t.cohen_dz)),
            );
            groups.push((
                name.clone(),
                vec![bar("repositioning", &av), bar("wiping", &bv)],
            ));
            let difference = stats::difference(&av, &bv, true);
            comparisons.push(TaskComparison {
                module: name.clone(),
                measure: label.into(),
                repositioning: av,
                difference,
                wiping: bv,
                paired_t: t,
                equivalence,
            });
        }
        let file = if measure == 0 {
            "sigma_p.png"
        } else {
            "sigma_p_change.png"
        };
        bar_chart(
            &out.join(file),
            &format!("{label} per module ({stamp})"),
            label,
            &["repositioning".into(), "wiping".into()],
            &groups,
        )?;
        let _ = writeln!(md, "\n![{label}]({file})\n");
        if measure == 0 {
            md.push_str("| module | measure | repositioning | wiping | t | df | p | d_z |\n|---|---|---|---|---|---|---|---|\n");
        }
    }
    let _ = writeln!(
        md,
        "### Is there no difference between the tasks? (Fig 4A, equivalence)\n\nThe paper reads a non-significant t-test as \"no difference\"; here that claim is tested as an equivalence: two one-sided tests (TOST) of repositioning − wiping against a margin of ±{:.0}% of the two tasks' mean prior σ, fixed before the converged runs (the reduced-scale results were re-analysed with it afterwards). Equivalent when the 90% CI lies inside the margin (p < 0.05).\n\n| module | difference | 90% CI | margin | TOST p | equivalent |\n|---|---|---|---|---|---|",
        EQUIVALENCE_MARGIN * 100.0
    );
    for c in comparisons.iter().filter(|c| c.measure == "prior sigma") {
        match &c.equivalence {
            Some(e) => {
                let _ = writeln!(
                    md,
                    "| {} | {} | [{}, {}] | ±{} | {} | {} |",
                    c.module,
                    sig(e.mean),
                    sig(e.ci90[0]),
                    sig(e.ci90[1]),
                    sig(e.margin),
                    p_text(e.p),
                    if e.equivalent { "yes" } else { "not shown" }
                );
            }
            None => {
                let _ = writeln!(md, "| {} | – (fewer than 2 networks) | | | | |", c.module);
            }
        }
    }
    md.push('\n');
    Ok(json!({ "comparisons": comparisons, "equivalence_margin": EQUIVALENCE_MARGIN }))
}
