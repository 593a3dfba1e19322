//! The paper's findings set beside ours: every report ends with a table of what the paper
//! found (its numbers, from the figures' captions and the text), what this run found, and
//! whether they agree, read from the report's own results (`summary.json`'s `results`).
//!
//! "Agrees" means the same direction and the same verdict at p < 0.05 (a difference the
//! paper found significant is significant here too). The paper's two "no difference"
//! claims (Figs 4A, 6A) agree only when the difference test is not significant and an
//! equivalence test puts the difference inside a stated margin. A direction is judged on
//! the mean errors; where the aligned ranks a rank test uses point the other way, the
//! verdict is "undecided", as is Fig 5B's rise when its means and ranks run in different
//! orders (a rise neither shows is a disagreement).
//! A same-direction result that is not significant is not blamed on power by default:
//! every finding states its effect with the 95% confidence interval and the smallest
//! effect the design could detect (80% power, from the observed variance), and where the
//! paper gives a statistic, the verdict tests whether one effect fits both studies
//! ([`crate::compatibility`]): if they differ it disagrees, if one fits both it is
//! undecided (too small a design to tell).
//! Every verdict needs networks that pass the validity gate ([`gated`]); on networks that
//! lose to a baseline without dynamics a finding is "not testable on these networks".

use serde::Serialize;
use serde_json::Value;

use crate::compatibility::{Compatibility, OurStatistic, PaperStatistic};
use crate::plan::Experiment;

mod hierarchy;
mod interference;
mod robustness;
mod uncertainty;

use hierarchy::hierarchy;
use interference::interference;
use robustness::robustness;
use uncertainty::uncertainty;

/// One finding: the paper's, ours, and whether they agree (None: not testable here).
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Finding {
    pub finding: String,
    pub paper: String,
    pub ours: String,
    /// Our effect: the difference with its 95% CI, Cohen's d and the detectable difference.
    pub effect: String,
    pub agrees: Option<bool>,
    /// Why they disagree or cannot be compared, when they do not simply agree.
    pub note: String,
    /// What the validity gate must find the networks have learned for a verdict.
    #[serde(rename = "gate_needs")]
    pub needs: GateNeed,
}

/// The measures of the validity gate a finding depends on: what it measures.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum GateNeed {
    /// The finding measures the reconstructed images (Figs 3B, 5B).
    Vision,
    /// The finding measures the whole network: latent states, pooled errors (Figs 2-4, 6).
    VisionAndProprioception,
}

impl GateNeed {
    fn words(self) -> &'static str {
        match self {
            GateNeed::Vision => "vision measure",
            GateNeed::VisionAndProprioception => "vision and proprioception measures",
        }
    }
}

const ALPHA: f64 = 0.05;

/// The key of the interference results' asymmetry test (beside the directions' keys).
pub const ASYMMETRY: &str = "asymmetry";

fn num(v: &Value) -> Option<f64> {
    v.as_f64()
}

fn p_text(p: Option<f64>) -> String {
    match p {
        Some(p) if p < 0.001 => "p < 0.001".into(),
        Some(p) => format!("p = {p:.3}"),
        None => "p = –".into(),
    }
}

/// An ART ANOVA's F (every F set beside the paper's is one) as "ART F(df1, df2) = f, p".
fn f_text(effect: &Value) -> String {
    match (num(&effect["f"]), num(&effect["df1"]), num(&effect["df2"])) {
        (Some(f), Some(a), Some(b)) => {
            format!("ART F({a}, {b}) = {f:.2}, {}", p_text(num(&effect["p"])))
        }
        _ => "not computed (too few networks)".into(),
    }
}

fn t_text(t: &Value) -> String {
    match (num(&t["t"]), num(&t["df"])) {
        (Some(v), Some(df)) => format!("t({df}) = {v:.2}, {}", p_text(num(&t["p"]))),
        _ => "not computed (too few networks)".into(),
    }
}

/// Agreement of a test with the paper's verdict `significant` (and, when the paper's effect
/// has a direction, `direction_ok`): (agrees, note).
fn verdict(p: Option<f64>, significant: bool, direction_ok: bool) -> (Option<bool>, String) {
    let Some(p) = p else {
        return (None, "no test: too few complete networks".into());
    };
    match (significant, p < ALPHA, direction_ok) {
        (_, true, false) => (Some(false), "the opposite direction, significant".into()),
        (_, false, false) => (
            Some(false),
            "the opposite direction (not significant)".into(),
        ),
        (true, true, true) | (false, false, true) => (Some(true), String::new()),
        (true, false, true) => (
            Some(false),
            "same direction, not significant here (the paper gives no statistic to set our interval against)"
                .into(),
        ),
        (false, true, true) => (Some(false), "significant here, not in the paper".into()),
    }
}

/// [`verdict`] for a claim the paper found significant and reports a statistic for
/// (`against`: our result set against the paper's, [`crate::compatibility`]): a
/// same-direction result that is not significant disagrees when the two studies' effects
/// differ and is undecided (too small a design) when one effect fits both.
fn verdict_against(
    p: Option<f64>,
    direction_ok: bool,
    against: Option<Compatibility>,
) -> (Option<bool>, String) {
    match (p, against) {
        (Some(p), Some(c)) if p >= ALPHA && direction_ok => {
            if c.differs {
                (
                    Some(false),
                    format!(
                        "same direction, not significant, and smaller than the paper's effect beyond both studies' uncertainty ({})",
                        c.text
                    ),
                )
            } else {
                (
                    None,
                    format!(
                        "undecided: same direction, not significant, and one effect fits both studies ({}): too small a design to tell",
                        c.text
                    ),
                )
            }
        }
        (Some(p), None) if p >= ALPHA && direction_ok => (
            Some(false),
            "same direction, not significant here (our statistic is missing, so it is not set against the paper's)".into(),
        ),
        _ => verdict(p, true, direction_ok),
    }
}

/// Our t or F as JSON (`{"t", "df"}` or `{"f", "df1", "df2"}`); a t negated when
/// `negate` (so that the paper's direction is positive).
fn our_t(v: &Value, negate: bool) -> Option<OurStatistic> {
    let t = num(&v["t"])?;
    Some(OurStatistic::T {
        t: if negate { -t } else { t },
        df: num(&v["df"])?,
    })
}

fn our_f(v: &Value) -> Option<OurStatistic> {
    Some(OurStatistic::F {
        f: num(&v["f"])?,
        df1: num(&v["df1"])?,
        df2: num(&v["df2"])?,
    })
}

/// The paper's statistic against ours at `networks` networks per condition.
fn against(
    paper: PaperStatistic,
    ours: Option<OurStatistic>,
    networks: usize,
) -> Option<Compatibility> {
    crate::compatibility::compare(paper, ours?, networks as f64)
}

fn finding(
    finding: &str,
    paper: &str,
    ours: String,
    (agrees, note): (Option<bool>, String),
) -> Finding {
    Finding {
        finding: finding.into(),
        paper: paper.into(),
        ours,
        effect: "–".into(),
        agrees,
        note,
        needs: GateNeed::VisionAndProprioception,
    }
}

/// A [`crate::stats::Difference`] (as JSON) as "Δ = m [lo, hi], d = x; detectable ±y".
fn effect_text(d: &Value) -> String {
    match (
        num(&d["mean"]),
        num(&d["ci95"][0]),
        num(&d["ci95"][1]),
        num(&d["detectable"]),
    ) {
        (Some(m), Some(lo), Some(hi), Some(det)) => format!(
            "Δ = {m:.3e} [{lo:.3e}, {hi:.3e}], {} = {:.2}; detectable ±{det:.3e}",
            // d_z: the mean of paired differences over their SD; d: over the pooled SD.
            if d["paired"] == true { "d_z" } else { "d" },
            num(&d["cohen_d"]).unwrap_or(f64::NAN)
        ),
        _ => "– (too few networks)".into(),
    }
}

impl Finding {
    fn with_effect(mut self, effect: String) -> Self {
        self.effect = effect;
        self
    }

    /// A finding about the reconstructed images only.
    fn on_vision(mut self) -> Self {
        self.needs = GateNeed::Vision;
        self
    }
}

/// Per-network values of a JSON map {network: value}, in network order.
fn by_network(v: &Value) -> std::collections::BTreeMap<String, f64> {
    v.as_object()
        .map(|m| {
            m.iter()
                .filter_map(|(k, v)| Some((k.clone(), num(v)?)))
                .collect()
        })
        .unwrap_or_default()
}

/// The paired difference a − b over the networks both maps hold, as JSON.
fn paired_difference(a: &Value, b: &Value) -> Value {
    let (a, b) = (by_network(a), by_network(b));
    let keys: Vec<&String> = a.keys().filter(|k| b.contains_key(*k)).collect();
    let av: Vec<f64> = keys.iter().map(|k| a[*k]).collect();
    let bv: Vec<f64> = keys.iter().map(|k| b[*k]).collect();
    serde_json::to_value(crate::stats::difference(&av, &bv, true)).unwrap_or(Value::Null)
}

/// Mean of a JSON map's (or array's) numbers.
fn mean_of(v: &Value) -> Option<f64> {
    let values: Vec<f64> = match v {
        Value::Object(m) => m.values().filter_map(num).collect(),
        Value::Array(a) => a.iter().filter_map(num).collect(),
        _ => Vec::new(),
    };
    (!values.is_empty()).then(|| values.iter().sum::<f64>() / values.len() as f64)
}

/// The findings of `experiment` beside the paper's, from the report's `results`.
pub fn findings(experiment: Experiment, results: &Value) -> Vec<Finding> {
    match experiment {
        Experiment::Hierarchy => hierarchy(results),
        Experiment::Uncertainty => uncertainty(results),
        Experiment::Robustness => robustness(results)
            .into_iter()
            .map(Finding::on_vision)
            .collect(),
        Experiment::Interference => interference(results),
    }
}

/// Findings of a direction not yet complete: no statistic, no effect, no verdict.
fn untested(findings: &mut [Finding], note: &str) {
    for f in findings {
        f.ours = "not tested: the direction is not complete".into();
        f.effect = "–".into();
        f.agrees = None;
        f.note = note.into();
    }
}

/// How many of a report's networks pass the validity gate ([`pvrnn_eval::gate`]): on
/// every measure, and on vision alone.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct GateSummary {
    pub passing: usize,
    pub passing_vision: usize,
    pub networks: usize,
}

impl GateSummary {
    /// Every network passes what `need` asks.
    pub fn all_pass(&self, need: GateNeed) -> bool {
        self.networks > 0 && self.passing_for(need) == self.networks
    }

    fn passing_for(&self, need: GateNeed) -> usize {
        match need {
            GateNeed::Vision => self.passing_vision,
            GateNeed::VisionAndProprioception => self.passing,
        }
    }
}

/// A finding is drawn only from networks that pass the validity gate on what it measures:
/// while any of the report's networks does not (or was not gated), the finding keeps our
/// statistics for the record but has no verdict, "not testable on these networks"
/// (docs/experiments.md, "The validity gate").
pub fn gated(findings: Vec<Finding>, gate: &GateSummary) -> Vec<Finding> {
    findings
        .into_iter()
        .map(|f| {
            if gate.all_pass(f.needs) {
                return f;
            }
            Finding {
                agrees: None,
                note: format!(
                    "not testable on these networks: {} of {} pass the validity gate's {} (trainings.csv){}",
                    gate.passing_for(f.needs),
                    gate.networks,
                    f.needs.words(),
                    if f.note.is_empty() {
                        String::new()
                    } else {
                        format!("; without the gate: {}", f.note)
                    }
                ),
                ..f
            }
        })
        .collect()
}

/// The findings as a Markdown section; `coverage` says how much of the design the results
/// cover ("5 of the design's 5 networks").
pub fn markdown(findings: &[Finding], stamp: &str, coverage: &str) -> String {
    let mut md = format!(
        "## Compared with the paper ({stamp})\n\nThe paper's numbers (5 networks x 100,000 iterations, 5 trials) beside this run's ({coverage}). A verdict needs every network to pass the validity gate (on held-out data it beats the strongest baseline of vision and of proprioception; trainings.csv); otherwise the finding is not testable on these networks and its verdict without the gate is printed for the record only. Agrees = same direction and same verdict at p < 0.05 (a \"no difference\" or \"no change\", Figs 4A and 6A: no significant difference and equivalence within the stated margin). Directions are judged on the mean errors; where the aligned ranks a rank test uses point the other way, the verdict is undecided. A result in the paper's direction that is not significant disagrees when the two studies' effects differ (a likelihood-ratio test of one effect per network for both, from the paper's t or F, or the smallest t its p allows) and is undecided when one effect fits both; our noncentrality's 95% interval and the paper's estimate at our networks are printed beside it. Effect: our difference with its 95% CI, Cohen's d (d_z for paired differences), and the smallest difference this design detects with 80% power (two-sided, 0.05, from the observed variance).\n\n| finding | paper | ours | effect | agrees |\n|---|---|---|---|---|\n"
    );
    for f in findings {
        debug_assert!(!format!("{}{}{}", f.finding, f.paper, f.ours).contains('|'));
        let agrees = match f.agrees {
            Some(true) => "yes".to_string(),
            Some(false) => format!("no: {}", f.note),
            None => format!("–: {}", f.note),
        };
        md.push_str(&format!(
            "| {} | {} | {} | {} | {agrees} |\n",
            f.finding, f.paper, f.ours, f.effect
        ));
    }
    md.push('\n');
    md
}

/// The verdict on a "no difference" claim (Figs 4A and 6A), one rule for both (amended
/// 2026-12-06, docs/experiments.md): equivalence within the margin (TOST JSON `tost`) agrees,
/// with a significant difference test (`p`: the paired t or the omnibus ANOVA) stated
/// beside it (`inside`: a difference smaller than the margin the claim allows); without
/// equivalence, a significant difference disagrees; neither is undecided. `differ` says
/// what a significant test means.
fn no_difference_verdict(
    tost: &Value,
    p: Option<f64>,
    differ: &str,
    inside: &str,
) -> (Option<bool>, String) {
    let equivalent = tost["equivalent"].as_bool();
    match (p, equivalent) {
        (Some(p), Some(true)) if p < ALPHA => (
            Some(true),
            format!("equivalent within the margin; {differ}, but {inside}"),
        ),
        (_, Some(true)) => (Some(true), String::new()),
        (Some(p), _) if p < ALPHA => (Some(false), differ.into()),
        (_, Some(false)) => (
            None,
            "undecided: neither a difference nor equivalence within the margin is shown".into(),
        ),
        (_, None) => (None, "no test: too few complete networks".into()),
    }
}

/// A TOST result as "TOST: difference m, 90% CI [lo, hi] vs margin ±x, p".
fn tost_text(tost: &Value) -> Option<String> {
    Some(format!(
        "TOST: difference {:.3e}, 90% CI [{:.3e}, {:.3e}] vs margin ±{:.3e}, {}",
        num(&tost["mean"])?,
        num(&tost["ci90"][0])?,
        num(&tost["ci90"][1])?,
        num(&tost["margin"])?,
        p_text(num(&tost["p"]))
    ))
}

#[cfg(test)]
mod tests;
