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

fn hierarchy(r: &Value) -> Vec<Finding> {
    let boundary = &r["executive_boundary"];
    let difference = mean_of(&boundary["near_minus_elsewhere_per_network"]);
    // The verdict is the test across networks, the unit every other finding is tested
    // over; the permutation test (within runs, so over repeated trials of the same
    // networks) is printed beside it.
    let p = num(&boundary["difference"]["p"]);
    let mut out = vec![finding(
        "The executive module's latent state changes most at subtask boundaries (Figs 2A, 3A)",
        "described from single runs, no test",
        match difference {
            Some(d) => format!(
                // No `|` in the text: it would split the Markdown table's cell.
                "mean absolute Δμ_q near − elsewhere (steps t ≥ H) = {d:.3e}; across networks, two-sided one-sample t: {}; within runs, two-sided permutation: {}",
                p_text(p),
                p_text(num(&boundary["p"]))
            ),
            None => "no run with a subtask boundary".into(),
        },
        verdict(p, true, difference.is_none_or(|d| d > 0.0)),
    )
    .with_effect(effect_text(&boundary["difference"]))];
    let matched = &r["executive_boundary_matched"];
    if !matched.is_null() {
        let difference = mean_of(&matched["near_minus_elsewhere_per_network"]);
        let p = num(&matched["difference"]["p"]);
        out.push(
            finding(
                "The executive module's latent state changes most at subtask boundaries, onset kept, within its time constant (Figs 2A, 3A)",
                "described from single runs, no test",
                match difference {
                    Some(d) => format!(
                        "mean absolute Δμ_q within ±{} steps − elsewhere (steps t ≥ 1) = {d:.3e}; across networks, two-sided one-sample t: {}; within runs, two-sided permutation: {}",
                        matched["half_width"],
                        p_text(p),
                        p_text(num(&matched["p"]))
                    ),
                    None => "no run with a subtask boundary".into(),
                },
                verdict(p, true, difference.is_none_or(|d| d > 0.0)),
            )
            .with_effect(effect_text(&matched["difference"])),
        );
    }
    if r["occlusion"].is_null() {
        out.push(
            finding(
                "Body parts hidden by the arms are inferred (Fig 3B)",
                "shown in pictures, not measured",
                "no robot-free renders in the data".into(),
                (None, "not testable here".into()),
            )
            .on_vision(),
        );
        return out;
    }
    for (label, what) in [
        (
            "reconstruction, everything observed",
            "the reconstruction (everything observed)",
        ),
        (
            "reconstruction, 16x16 + proprioception observed",
            "the reconstruction from the 16x16 input",
        ),
        (
            "prior prediction, everything observed",
            "the one-step prior prediction",
        ),
    ] {
        let test = &r["occlusion"]["relative"][label];
        let d = &test["difference"];
        let p = num(&d["p"]);
        let closer = num(&d["mean"]).is_none_or(|m| m < 0.0);
        out.push(
            finding(
                &format!(
                    "Body parts hidden by the arms are inferred (Fig 3B): {what} is closer to the hidden body than the observed frame"
                ),
                "shown in pictures, not measured",
                match num(&d["mean"]) {
                    Some(m) => format!(
                        "d(model, body) − d(observed, body) = {m:.3e}, one-sample t, {}",
                        p_text(p)
                    ),
                    None => "–".into(),
                },
                if test["per_network"].as_array().is_none_or(Vec::is_empty) {
                    (None, "not recorded in these runs (written before relative scores were kept)".into())
                } else {
                    verdict(p, true, closer)
                },
            )
            .with_effect(effect_text(d))
            .on_vision(),
        );
    }
    if let Some(against) = r["occlusion"]["against_baselines"].as_object() {
        out.push(against_baselines_finding(against).on_vision());
    }
    out
}

/// Fig 3B against what needs no model (pre-specified 2026-12-06): the reconstruction must be
/// closer to the hidden body than both observation-only baselines. Significantly farther
/// than either disagrees; significantly closer than both agrees; anything else undecided.
fn against_baselines_finding(against: &serde_json::Map<String, Value>) -> Finding {
    let tests: Vec<(&String, Option<f64>, Option<f64>)> = against
        .iter()
        .map(|(k, v)| (k, num(&v["difference"]["mean"]), num(&v["difference"]["p"])))
        .collect();
    let ours = tests
        .iter()
        .map(|(k, m, p)| match m {
            Some(m) => format!("model − {k} = {m:.3e}, one-sample t, {}", p_text(*p)),
            None => format!("model − {k}: –"),
        })
        .collect::<Vec<_>>()
        .join("; ");
    let significant = |p: &Option<f64>| p.is_some_and(|p| p < ALPHA);
    let verdict = if tests.iter().any(|(_, m, _)| m.is_none()) {
        (None, "no test: too few complete networks".to_string())
    } else if tests
        .iter()
        .any(|(_, m, p)| m.is_some_and(|m| m > 0.0) && significant(p))
    {
        (
            Some(false),
            "an observation-only baseline is closer to the hidden body than the reconstruction"
                .to_string(),
        )
    } else if tests
        .iter()
        .all(|(_, m, p)| m.is_some_and(|m| m < 0.0) && significant(p))
    {
        (Some(true), String::new())
    } else {
        (
            None,
            "undecided: not closer than every observation-only baseline, not significantly farther"
                .to_string(),
        )
    };
    let strongest = against
        .values()
        .max_by(|a, b| {
            let m = |v: &Value| num(&v["difference"]["mean"]).unwrap_or(f64::NEG_INFINITY);
            m(a).total_cmp(&m(b))
        })
        .map_or(Value::Null, |v| v["difference"].clone());
    finding(
        "Body parts hidden by the arms are inferred (Fig 3B): the reconstruction (everything observed) is closer to the hidden body than the observation-only baselines (the mean image, each pixel's last unhidden observation)",
        "shown in pictures, not measured",
        ours,
        verdict,
    )
    .with_effect(effect_text(&strongest))
}

fn uncertainty(r: &Value) -> Vec<Finding> {
    let pick = |measure: &str| {
        r["comparisons"]
            .as_array()
            .and_then(|c| {
                c.iter()
                    .find(|x| x["module"] == "all modules" && x["measure"] == measure)
            })
            .cloned()
            .unwrap_or(Value::Null)
    };
    let level = pick("prior sigma");
    let change = pick("mean absolute change of prior sigma");
    let tost = &level["equivalence"];
    let (agrees, note) = no_difference_verdict(
        tost,
        num(&level["paired_t"]["p"]),
        "the tasks differ (paired t significant)",
        "by less than the equivalence margin",
    );
    vec![
        finding(
            "Mean prior σ (all modules) does not differ between repositioning and wiping (Fig 4A): tested as equivalence",
            "t(4) = 1.67, p = 0.17 (n.s., read as no difference)",
            match tost_text(tost) {
                Some(t) => format!("{t}; paired {}", t_text(&level["paired_t"])),
                None => t_text(&level["paired_t"]),
            },
            (agrees, note),
        )
        .with_effect(effect_text(&level["difference"])),
        finding(
            "Prior σ changes less over time in repositioning than in wiping (Fig 4B)",
            "t(4) = −8.15, p = 0.0012",
            t_text(&change["paired_t"]),
            verdict_against(
                num(&change["paired_t"]["p"]),
                num(&change["paired_t"]["t"]).is_none_or(|t| t < 0.0),
                against(
                    PaperStatistic::T { t: 8.15, df: 4.0 },
                    // Repositioning − wiping: the paper's direction is negative.
                    our_t(&change["paired_t"], true),
                    num(&change["paired_t"]["n"]).unwrap_or(0.0) as usize,
                ),
            ),
        )
        .with_effect(effect_text(&change["difference"])),
    ]
}

fn robustness(r: &Value) -> Vec<Finding> {
    let effects = &r["art"]["effects"];
    // cells[vision][proprio] = {network: error}; vision 64, 32+16, 16; proprio on, off.
    let cell = |v: usize, p: usize| mean_of(&r["cells"][v][p]);
    let by_vision: Vec<Option<f64>> = (0..3)
        .map(|v| Some((cell(v, 0)? + cell(v, 1)?) / 2.0))
        .collect();
    let networks = by_network(&r["cells"][0][0]).len();
    let paper_f = |f: f64, df1: f64| PaperStatistic::F { f, df1, df2: 20.0 };
    let resolution_verdict = resolution_verdict(
        num(&effects[0]["p"]),
        Order::of(&by_vision),
        Order::of_ranks(&r["art"]["a_contrasts"]),
        against(paper_f(105.57, 2.0), our_f(&effects[0]), networks),
    );
    let on: Option<f64> = (0..3).map(|v| cell(v, 0)).sum::<Option<f64>>();
    let off: Option<f64> = (0..3).map(|v| cell(v, 1)).sum::<Option<f64>>();
    let helps = match (on, off) {
        (Some(a), Some(b)) => a < b,
        _ => true,
    };
    // What proprioception saves (off − on) at 64 (all) and at 16x16: the paper's
    // interaction is that it saves more at the low resolution.
    let saving = |v: usize| Some(cell(v, 1)? - cell(v, 0)?);
    let (saving_64, saving_16) = (saving(0), saving(2));
    let more_at_low = match (saving_64, saving_16) {
        (Some(high), Some(low)) => low > high,
        _ => true,
    };
    let fmt = |v: Option<f64>| v.map_or("–".into(), |v| format!("{v:.3e}"));
    let (simple_p, simple_t) = simple_effect(r);
    // Paired differences over networks: 16 vs 64 (vision, proprio on), off vs on (16x16),
    // and the interaction (saving at 16 − saving at 64).
    let cells = &r["cells"];
    let saving_by_network = |v: usize| -> Value {
        let (on, off) = (by_network(&cells[v][0]), by_network(&cells[v][1]));
        Value::Object(
            on.iter()
                .filter_map(|(k, a)| Some((k.clone(), serde_json::json!(off.get(k)? - a))))
                .collect(),
        )
    };
    let simple_helps = match (cell(2, 0), cell(2, 1)) {
        (Some(a), Some(b)) => a < b,
        _ => true,
    };
    vec![
        finding(
            "The 64x64 error rises as the observed resolution drops (Fig 5B)",
            "F(2, 20) = 105.57, p < 0.001",
            format!(
                "{}; mean error 64 / 32+16 / 16: {}",
                f_text(&effects[0]),
                by_vision
                    .iter()
                    .map(|v| v.map_or("–".into(), |v| format!("{v:.3e}")))
                    .collect::<Vec<_>>()
                    .join(" / ")
            ),
            resolution_verdict,
        )
        .with_effect(format!("16 − 64 (proprio on): {}", effect_text(&paired_difference(&cells[2][0], &cells[0][0])))),
        finding(
            "Proprioception lowers the error (Fig 5B)",
            "F(1, 20) = 46.09, p < 0.001",
            format!(
                "{}; mean error on / off: {} / {}",
                f_text(&effects[1]),
                fmt(on.map(|v| v / 3.0)),
                fmt(off.map(|v| v / 3.0))
            ),
            verdict_against(
                num(&effects[1]["p"]),
                helps,
                against(paper_f(46.09, 1.0), our_f(&effects[1]), networks),
            ),
        )
        .with_effect(format!("off − on at 64: {}", effect_text(&paired_difference(&cells[0][1], &cells[0][0])))),
        finding(
            "Resolution and proprioception interact: proprioception helps most at low resolution (Fig 5B)",
            "F(2, 20) = 13.57, p < 0.001",
            format!(
                "{}; error saved by proprioception (off − on) at 64 / 16: {} / {}",
                f_text(&effects[2]),
                fmt(saving_64),
                fmt(saving_16)
            ),
            verdict_against(
                num(&effects[2]["p"]),
                more_at_low,
                against(paper_f(13.57, 2.0), our_f(&effects[2]), networks),
            ),
        )
        .with_effect(format!(
            "saving at 16 − saving at 64: {}",
            effect_text(&paired_difference(&saving_by_network(2), &saving_by_network(0)))
        )),
        finding(
            "With 16x16 vision only, proprioception still lowers the error (simple effect)",
            "p = 0.034",
            format!(
                "ART-C cell contrast 16 / on vs 16 / off, Holm over all 15 cell pairs: {}",
                p_text(simple_p)
            ),
            verdict_against(
                simple_p,
                simple_helps,
                // The largest p that prints as 0.034; its df assumed from the paper's
                // F(·, 20) (5 networks, 6 cells).
                against(PaperStatistic::P { p: 0.0345, df: 20.0 }, simple_t, networks),
            ),
        )
        .with_effect(format!("off − on at 16: {}", effect_text(&paired_difference(&cells[2][1], &cells[2][0])))),
    ]
}

/// The simple effect of proprioception at 16x16 (the ART-C contrast of the cells 16 / on
/// and 16 / off): its Holm p and its t in the paper's direction (lower with it on).
fn simple_effect(r: &Value) -> (Option<f64>, Option<OurStatistic>) {
    let simple = r["art"]["cell_contrasts"].as_array().and_then(|c| {
        c.iter().find(|x| {
            let (a, b) = (x["a"].as_str().unwrap_or(""), x["b"].as_str().unwrap_or(""));
            a.starts_with("16 /") && b.starts_with("16 /")
        })
    });
    (
        simple.and_then(|x| num(&x["p_holm"])),
        simple.and_then(|x| our_t(x, x["a"].as_str().is_some_and(|a| a.ends_with("on")))),
    )
}

/// Resolution levels 64 / 32+16 / 16 in the order of [`robustness`]'s means.
const RESOLUTIONS: [&str; 3] = ["64 (all)", "32+16", "16"];

/// How errors by resolution (64, 32+16, 16) run as the resolution drops.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Order {
    Rising,
    Falling,
    /// Neither; the level with the lowest error.
    Lowest(&'static str),
}

impl Order {
    fn from_levels(v: [f64; 3]) -> Self {
        if v[0] <= v[1] && v[1] <= v[2] {
            Order::Rising
        } else if v[0] >= v[1] && v[1] >= v[2] {
            Order::Falling
        } else {
            let lowest = (0..3).min_by(|&a, &b| v[a].total_cmp(&v[b])).unwrap_or(0);
            Order::Lowest(RESOLUTIONS[lowest])
        }
    }

    /// The order of the mean errors; `None` when one is unknown.
    fn of(by_vision: &[Option<f64>]) -> Option<Self> {
        Some(Self::from_levels([
            by_vision[0]?,
            by_vision[1]?,
            by_vision[2]?,
        ]))
    }

    /// The order of the aligned ranks the ANOVA tests, from the vision contrasts
    /// (64 − 32+16, 64 − 16 and 32+16 − 16 in mean rank).
    fn of_ranks(contrasts: &Value) -> Option<Self> {
        let c = contrasts.as_array()?;
        let first = num(&c.first()?["rank_difference"])?;
        let second = num(&c.get(1)?["rank_difference"])?;
        // Mean ranks relative to 64's: 0, −(64 − 32+16), −(64 − 16).
        Some(Self::from_levels([0.0, -first, -second]))
    }
}

/// Fig 5B's "the error rises as the resolution drops": the paper's order in both the mean
/// errors and the ranks the test uses (or in the means where no ranks are recorded); the
/// two disagreeing leave it undecided.
fn resolution_verdict(
    p: Option<f64>,
    means: Option<Order>,
    ranks: Option<Order>,
    against: Option<Compatibility>,
) -> (Option<bool>, String) {
    let significance = if p.is_some_and(|p| p < ALPHA) {
        "significant"
    } else {
        "not significant"
    };
    match (means, ranks) {
        (None, _) => verdict_against(p, true, against),
        (Some(m), None) => resolution_verdict(p, Some(m), Some(m), against),
        (Some(m), Some(r)) if r == m => match m {
            Order::Rising => verdict_against(p, true, against),
            Order::Falling => verdict(p, true, false),
            Order::Lowest(level) => (
                Some(false),
                format!(
                    "the error does not rise monotonically as the resolution drops (lowest with {level}; ANOVA {significance})"
                ),
            ),
        },
        (Some(m), Some(r)) if m == Order::Rising || r == Order::Rising => (
            None,
            format!(
                "undecided (ANOVA {significance}): the {} rise as the resolution drops, the {} do not{}",
                if r == Order::Rising {
                    "aligned ranks the test uses"
                } else {
                    "mean errors"
                },
                if r == Order::Rising {
                    "mean errors"
                } else {
                    "aligned ranks"
                },
                match (m, r) {
                    (Order::Lowest(level), _) | (_, Order::Lowest(level)) =>
                        format!(" (lowest with {level})"),
                    _ => String::new(),
                }
            ),
        ),
        (Some(_), Some(_)) => (
            Some(false),
            format!(
                "neither the mean errors nor the ranks rise monotonically as the resolution drops (ANOVA {significance})"
            ),
        ),
    }
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

fn interference(r: &Value) -> Vec<Finding> {
    let mut out = Vec::new();
    let Some(primaries) = r.as_object() else {
        return out;
    };
    for (primary, v) in primaries {
        if primary == ASYMMETRY {
            continue;
        }
        let mut findings = if primary == "repositioning" {
            vec![no_change_finding(v)]
        } else {
            let mut f = vec![rise_finding(v)];
            f.extend(holm_findings(v));
            f
        };
        // A direction is tested on its complete design only (reports from before this
        // field was written had every direction complete): until then its findings say
        // so, with no statistic and no effect from the partial data.
        if v["complete"] == false {
            untested(
                &mut findings,
                &format!(
                    "no test yet: {} of the direction's {} trainings and {} of its {} jobs done",
                    v["trainings_done"], v["trainings_planned"], v["jobs_done"], v["jobs_planned"]
                ),
            );
        }
        out.extend(findings);
    }
    if primaries.contains_key("wiping") && primaries.contains_key("repositioning") {
        out.push(asymmetry_finding(&r[ASYMMETRY]));
    }
    out
}

/// Fig 6 read as one claim: adding repositioning data changes wiping's error by more than
/// adding wiping data changes repositioning's (the difference of the two directions' log
/// ratios of none → 9 added, pooled error).
fn asymmetry_finding(a: &Value) -> Finding {
    let t = &a["measures"]["pooled"];
    // Wiping's log ratio − repositioning's: the paper's asymmetry is positive.
    let sign = if a["second"] == "wiping" { 1.0 } else { -1.0 };
    let difference = num(&t["difference"]).map(|d| sign * d);
    let p = num(&t["p"]);
    let (ours, effect, verdict) = match (a.is_null(), difference) {
        (true, _) => (
            "not tested yet: both directions must be complete".to_string(),
            "–".to_string(),
            (
                None,
                "no test yet: both directions must be complete".to_string(),
            ),
        ),
        (false, None) => (
            "–".into(),
            "–".into(),
            (None, "no test: too few complete networks".into()),
        ),
        (false, Some(d)) => {
            let change = |i: usize| num(&t["change"][i]).map_or(f64::NAN, |c| 100.0 * c);
            let (reposition, wipe) = if sign > 0.0 {
                (change(0), change(1))
            } else {
                (change(1), change(0))
            };
            let ci = [num(&t["ci95"][0]), num(&t["ci95"][1])].map(|c| c.map(|c| sign * c));
            let (lo, hi) = match ci {
                [Some(a), Some(b)] => (a.min(b), a.max(b)),
                _ => (f64::NAN, f64::NAN),
            };
            (
                format!(
                    "pooled error, none → 9 added: wiping {wipe:+.1}%, repositioning {reposition:+.1}%; Welch t({:.1}) = {:.2}, {}",
                    num(&t["df"]).unwrap_or(f64::NAN),
                    sign * num(&t["t"]).unwrap_or(f64::NAN),
                    p_text(p)
                ),
                format!(
                    "wiping's − repositioning's log ratio: {d:.3e} [{lo:.3e}, {hi:.3e}]; detectable ±{:.3e}",
                    num(&t["detectable"]).unwrap_or(f64::NAN)
                ),
                verdict(p, true, d > 0.0),
            )
        }
    };
    Finding {
        finding: "The interference is asymmetric: adding repositioning data raises wiping's error by a larger factor than adding wiping data raises repositioning's (Fig 6A against 6B)".into(),
        paper: "described from the two ANOVAs (F(3, 16) = 19.16 against 0.62), not tested".into(),
        ours,
        effect,
        agrees: verdict.0,
        note: verdict.1,
        needs: GateNeed::VisionAndProprioception,
    }
}

/// Fig 6A: "did not affect" is a claim of no change, tested as equivalence of the most
/// added and none, beside the omnibus test.
fn no_change_finding(v: &Value) -> Finding {
    let effect = &v["art"]["pooled"]["effect"];
    let tost = &v["equivalence"]["pooled"];
    let ours = match tost_text(tost) {
        Some(t) => format!("{t}; {}", f_text(effect)),
        None => f_text(effect),
    };
    // Fig 4A's rule: "no change" needs equivalence within the margin, and then agrees
    // whatever the ANOVA says (stated beside it); without equivalence a change the ANOVA
    // finds disagrees.
    let verdict = no_difference_verdict(
        tost,
        num(&effect["p"]),
        "adding wiping changes repositioning's error (ANOVA significant)",
        "9 added against none lies within the equivalence margin",
    );
    finding(
        "Adding wiping data does not change repositioning's error (Fig 6A): tested as equivalence of 9 added and none",
        "F(3, 16) = 0.62, p = 0.61 (n.s., read as no change)",
        ours,
        verdict,
    )
    .with_effect(format!(
        "9 added − none, pooled: {}",
        effect_text(&v["most_minus_none"]["pooled"])
    ))
}

/// Fig 6B: wiping's errors rise with added repositioning data.
fn rise_finding(v: &Value) -> Finding {
    let effect = &v["art"]["pooled"]["effect"];
    let means: Vec<Option<f64>> = v["per_network"][0]
        .as_array()
        .map(|c| c.iter().map(mean_of).collect())
        .unwrap_or_default();
    let rising = means
        .first()
        .copied()
        .flatten()
        .zip(means.last().copied().flatten());
    // The ranks of none against the most added (the last condition).
    let most = v["conditions"]
        .as_array()
        .and_then(|c| c.last())
        .map_or(String::new(), |x| added(x.as_str().unwrap_or("")));
    let ranks = lower_in_ranks(pooled_contrast(v, "0", &most), "0");
    finding(
        "Adding repositioning data raises wiping's error (Fig 6B)",
        "F(3, 16) = 19.16, p < 0.001",
        format!(
            "{}; pooled error with 0 / 3 / 6 / 9 added: {}",
            f_text(effect),
            means
                .iter()
                .map(|m| m.map_or("–".into(), |m| format!("{m:.3e}")))
                .collect::<Vec<_>>()
                .join(" / ")
        ),
        directed_verdict(
            num(&effect["p"]),
            rising.is_none_or(|(first, last)| first < last),
            ranks,
            against(
                PaperStatistic::F {
                    f: 19.16,
                    df1: 3.0,
                    df2: 16.0,
                },
                our_f(effect),
                networks_per_condition(v),
            ),
        ),
    )
    .with_effect(format!(
        "9 added − none, pooled: {}",
        effect_text(&v["most_minus_none"]["pooled"])
    ))
}

/// The pooled ART-C contrast of the conditions adding `few` and `many` sequences.
fn pooled_contrast<'a>(v: &'a Value, few: &str, many: &str) -> Option<&'a Value> {
    v["art"]["pooled"]["contrasts"]
        .as_array()?
        .iter()
        .find(|x| {
            let (a, b) = (
                added(x["a"].as_str().unwrap_or("")),
                added(x["b"].as_str().unwrap_or("")),
            );
            (a == few && b == many) || (a == many && b == few)
        })
}

/// Whether the aligned ranks of `contrast` put the condition adding `few` below the other;
/// `None` when they tie or no contrast is recorded.
fn lower_in_ranks(contrast: Option<&Value>, few: &str) -> Option<bool> {
    let x = contrast?;
    let d = num(&x["rank_difference"])?;
    if d == 0.0 {
        return None;
    }
    Some(if added(x["a"].as_str().unwrap_or("")) == few {
        d < 0.0
    } else {
        d > 0.0
    })
}

/// The verdict on a directed claim judged on the mean errors (`lower`: the paper's
/// direction), undecided when the aligned ranks the test uses point the other way.
fn directed_verdict(
    p: Option<f64>,
    lower: bool,
    ranks: Option<bool>,
    against: Option<Compatibility>,
) -> (Option<bool>, String) {
    match ranks {
        Some(ranks) if ranks != lower && p.is_some() => (
            None,
            "undecided: the mean errors and the aligned ranks the test uses point different ways"
                .into(),
        ),
        _ => verdict_against(p, lower, against),
    }
}

/// The networks per condition of an interference direction (the smallest group).
fn networks_per_condition(v: &Value) -> usize {
    v["per_network"][0]
        .as_array()
        .and_then(|c| c.iter().filter_map(|g| g.as_array().map(Vec::len)).min())
        .unwrap_or(0)
}

/// The number of sequences a condition adds (`wiping 9 + repositioning 3` → `3`).
fn added(label: &str) -> String {
    label.rsplit(' ').next().unwrap_or("").to_string()
}

/// Fig 6B's Holm contrasts the paper reports, each with the raw difference of the
/// conditions' per-network pooled errors (independent groups) beside its p.
fn holm_findings(v: &Value) -> Vec<Finding> {
    // A condition's per-network pooled errors, by how many sequences it adds.
    let group = |count: &str| -> Vec<f64> {
        let index = v["conditions"].as_array().and_then(|c| {
            c.iter()
                .position(|x| added(x.as_str().unwrap_or("")) == count)
        });
        index
            .and_then(|i| v["per_network"][0].get(i)?.as_array().cloned())
            .map(|values| values.iter().filter_map(num).collect())
            .unwrap_or_default()
    };
    let mut out = Vec::new();
    for (few, many, paper_p, p_value) in [
        // The largest p each printed one allows; df 16 assumed from the paper's F(3, 16).
        ("0", "6", "p < 0.001", 0.001),
        ("0", "9", "p < 0.001", 0.001),
        ("3", "6", "p = 0.0033", 0.003_35),
        ("3", "9", "p = 0.0033", 0.003_35),
    ] {
        let contrast = pooled_contrast(v, few, many);
        let p = contrast.and_then(|x| num(&x["p_holm"]));
        let difference =
            serde_json::to_value(crate::stats::difference(&group(many), &group(few), false))
                .unwrap_or(Value::Null);
        // The direction is the printed effect's (mean errors, many − few > 0: lower with
        // fewer), unless the aligned ranks the test uses point the other way.
        let lower = num(&difference["mean"]).is_none_or(|d| d > 0.0);
        // The contrast's t in the paper's direction (lower with fewer added): the rank
        // difference is a − b.
        let t = contrast.and_then(|x| our_t(x, added(x["a"].as_str().unwrap_or("")) == few));
        let (agrees, note) = directed_verdict(
            p,
            lower,
            lower_in_ranks(contrast, few),
            against(
                PaperStatistic::P {
                    p: p_value,
                    df: 16.0,
                },
                t,
                networks_per_condition(v),
            ),
        );
        out.push(
            finding(
                &format!("Wiping's error is lower with {few} than with {many} repositioning sequences added (Fig 6B, Holm)"),
                paper_p,
                format!("ART-C, Holm over the 6 pairs: {}", p_text(p)),
                (agrees, note),
            )
            .with_effect(format!("{many} added − {few}, pooled: {}", effect_text(&difference))),
        );
    }
    out
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

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn the_hidden_body_must_be_drawn_better_than_what_needs_no_model() {
        let against = |mean: f64, p_mean: f64, last: f64, p_last: f64| {
            let d = |m: f64, p: f64| json!({"difference": {"mean": m, "p": p, "ci95": [m - 0.01, m + 0.01], "cohen_d": 1.0, "detectable": 0.02, "paired": true}});
            json!({"mean image": d(mean, p_mean), "last seen": d(last, p_last)})
                .as_object()
                .unwrap()
                .clone()
        };
        assert_eq!(
            against_baselines_finding(&against(-0.02, 0.01, -0.01, 0.02)).agrees,
            Some(true)
        );
        // The November networks: farther from the body than the last unhidden frame.
        let f = against_baselines_finding(&against(0.026, 0.001, 0.036, 0.001));
        assert_eq!(f.agrees, Some(false));
        assert!(f.effect.starts_with("Δ = 3.600e-2"), "{}", f.effect);
        assert!(
            f.ours.contains("model − last seen = 3.600e-2"),
            "{}",
            f.ours
        );
        assert_eq!(
            against_baselines_finding(&against(-0.02, 0.01, -0.01, 0.3)).agrees,
            None
        );
    }

    #[test]
    fn a_verdict_needs_every_network_to_pass_the_gate() {
        let f = vec![
            finding("claim", "p", "ours".into(), (Some(false), "why".into())),
            finding("images", "p", "ours".into(), (Some(true), String::new())).on_vision(),
        ];
        let gate = |passing, passing_vision| GateSummary {
            passing,
            passing_vision,
            networks: 5,
        };
        assert_eq!(gated(f.clone(), &gate(5, 5)), f);
        let g = gated(f.clone(), &gate(4, 5));
        assert_eq!(g[0].agrees, None);
        assert_eq!(
            g[0].note,
            "not testable on these networks: 4 of 5 pass the validity gate's vision and proprioception measures (trainings.csv); without the gate: why"
        );
        assert_eq!(g[0].ours, "ours", "the statistics stay for the record");
        // A finding about images needs the vision measure only.
        assert_eq!(g[1], f[1]);
        let g = gated(f.clone(), &gate(0, 4));
        assert_eq!(g[1].agrees, None);
        assert!(g[1].note.starts_with(
            "not testable on these networks: 4 of 5 pass the validity gate's vision measure"
        ));
        let none = GateSummary {
            passing: 0,
            passing_vision: 0,
            networks: 0,
        };
        assert_eq!(gated(f, &none)[1].agrees, None);
    }

    #[test]
    fn verdicts_follow_direction_then_significance() {
        assert_eq!(verdict(Some(0.01), true, true).0, Some(true));
        assert_eq!(verdict(Some(0.20), false, true).0, Some(true));
        assert_eq!(verdict(Some(0.20), true, true).0, Some(false));
        // Not blamed on power by default: the effect's interval says what was shown.
        let note = verdict(Some(0.20), true, true).1;
        assert!(
            !note.contains("power") && note.contains("interval"),
            "{note}"
        );
        assert_eq!(verdict(Some(0.01), true, false).0, Some(false));
        assert_eq!(verdict(None, true, true).0, None);
    }

    #[test]
    fn uncertainty_reads_the_all_modules_tests() {
        let tost = |equivalent: bool| {
            json!({"mean": 0.01, "ci90": [-0.02, 0.04], "margin": 0.05,
            "p": if equivalent { 0.01 } else { 0.2 }, "equivalent": equivalent})
        };
        let r = |equivalent: bool, p: f64| {
            json!({"comparisons": [
                {"module": "all modules", "measure": "prior sigma",
                 "paired_t": {"t": 0.5, "df": 2.0, "p": p}, "equivalence": tost(equivalent),
                 "difference": {"mean": 0.01, "ci95": [-0.03, 0.05], "cohen_d": 0.3, "detectable": 0.08}},
                {"module": "all modules", "measure": "mean absolute change of prior sigma",
                 "paired_t": {"t": 5.0, "df": 2.0, "p": 0.04}},
            ]})
        };
        let f = findings(Experiment::Uncertainty, &r(true, 0.66));
        assert_eq!(f.len(), 2);
        // "No difference" holds only as equivalence within the margin.
        assert_eq!(f[0].agrees, Some(true));
        assert!(
            f[0].ours.contains("TOST") && f[0].ours.contains("t(2) = 0.50, p = 0.660"),
            "{}",
            f[0].ours
        );
        assert!(
            f[0].effect.contains("detectable ±8.000e-2"),
            "{}",
            f[0].effect
        );
        let undecided = findings(Experiment::Uncertainty, &r(false, 0.66));
        assert_eq!(undecided[0].agrees, None, "{:?}", undecided[0]);
        assert!(undecided[0].note.contains("undecided"));
        assert_eq!(
            findings(Experiment::Uncertainty, &r(false, 0.01))[0].agrees,
            Some(false)
        );
        // Fig 6A's rule too (amended 2026-12-06): equivalence within the margin agrees, a
        // significant difference stated beside it.
        let inside = findings(Experiment::Uncertainty, &r(true, 0.01));
        assert_eq!(inside[0].agrees, Some(true), "{:?}", inside[0]);
        assert!(
            inside[0]
                .note
                .starts_with("equivalent within the margin; the tasks differ")
        );
        assert!(inside[0].note.contains("less than the equivalence margin"));
        // Significant, but wiping's change is the smaller: the opposite of the paper.
        assert_eq!(f[1].agrees, Some(false));
        assert!(f[1].note.contains("opposite"));
    }

    #[test]
    fn robustness_directions_come_from_the_cells() {
        // cells[vision][proprio on, off] per network. Proprioception lowers the error on
        // average, but saves more at 64 (0.3) than at 16 (0.1): the interaction runs the
        // other way from the paper's.
        let cells = |on: f64, off: f64| json!([{"0": on, "1": on}, {"0": off, "1": off}]);
        let effect = |p: f64| json!({"f": 9.0, "df1": 2, "df2": 5, "p": p});
        let r = json!({
            "cells": [cells(1.0, 1.3), cells(1.5, 1.6), cells(2.0, 2.1)],
            "art": {"effects": [effect(0.01), effect(0.01), effect(0.01)], "cell_contrasts": []},
        });
        let f = robustness(&r);
        assert_eq!(f[0].agrees, Some(true), "{:?}", f[0]);
        assert_eq!(f[1].agrees, Some(true), "{:?}", f[1]);
        assert!(f[1].ours.contains("1.500e0 / 1.667e0"), "{}", f[1].ours);
        assert_eq!(f[2].agrees, Some(false), "{:?}", f[2]);
        assert!(f[2].note.contains("opposite direction"), "{}", f[2].note);
        assert!(f[2].ours.contains("3.000e-1 / 1.000e-1"), "{}", f[2].ours);

        // Lowest at 32+16: significant, but neither the paper's order nor its opposite.
        let r = json!({
            "cells": [cells(1.5, 1.5), cells(1.0, 1.0), cells(2.0, 2.0)],
            "art": {"effects": [effect(0.01), effect(0.5), effect(0.5)], "cell_contrasts": []},
        });
        let f = robustness(&r);
        assert_eq!(f[0].agrees, Some(false), "{:?}", f[0]);
        assert!(
            f[0].note.contains("not rise monotonically") && f[0].note.contains("lowest with 32+16"),
            "{}",
            f[0].note
        );
        assert!(!f[0].note.contains("opposite"), "{}", f[0].note);

        // The same means, but ranks that rise (an outlier lifts the 64 mean): undecided.
        let rank = |d: f64| json!({"rank_difference": d});
        let mut with_ranks = r.clone();
        with_ranks["art"]["a_contrasts"] = json!([rank(-3.5), rank(-11.2), rank(-7.7)]);
        let f = robustness(&with_ranks);
        assert_eq!(f[0].agrees, None, "{:?}", f[0]);
        assert!(
            f[0].note
                .starts_with("undecided (ANOVA significant): the aligned ranks the test uses rise")
                && f[0].note.contains("lowest with 32+16"),
            "{}",
            f[0].note
        );
    }

    #[test]
    fn the_boundary_verdict_is_the_test_across_networks() {
        // Significant within runs (permutation), not across networks: the verdict follows
        // the networks, and both p values are printed.
        let r = json!({"executive_boundary": {
            "near_minus_elsewhere_per_network": {"0": -0.002, "1": -0.004, "2": 0.002},
            "p": 0.046,
            "difference": {"mean": -0.00133, "ci95": [-0.01, 0.007], "cohen_d": -0.5,
                "detectable": 0.011, "p": 0.45, "paired": true},
        }, "occlusion": null});
        let f = findings(Experiment::Hierarchy, &r);
        assert_eq!(f[0].agrees, Some(false), "{:?}", f[0]);
        assert_eq!(f[0].note, "the opposite direction (not significant)");
        assert!(
            f[0].ours.contains("one-sample t: p = 0.450")
                && f[0].ours.contains("permutation: p = 0.046"),
            "{}",
            f[0].ours
        );
        assert!(f[0].effect.contains("d_z = -0.50"), "{}", f[0].effect);
    }

    #[test]
    fn interference_reads_the_pooled_contrasts() {
        let label = |k: &str| format!("wiping 9 + repositioning {k}");
        let contrast = |a: &str, b: &str, d: f64, p: f64| json!({"a": label(a), "b": label(b), "rank_difference": d, "p_holm": p});
        let r = json!({"wiping": {
            "conditions": [label("0"), label("3"), label("6"), label("9")],
            "per_network": [[[1.0, 1.2], [2.0, 2.2], [3.0, 3.2], [4.0, 4.2]], [], [], []],
            "complete": true,
            "art": {"pooled": {
                "effect": {"f": 9.0, "df1": 3.0, "df2": 8.0, "p": 0.006},
                "contrasts": [
                    contrast("0", "6", -5.0, 0.01),
                    contrast("0", "9", -6.0, 0.20),
                    contrast("3", "6", 2.0, 0.01),
                    contrast("3", "9", -4.0, 0.04),
                ],
            }},
        }});
        let f = findings(Experiment::Interference, &r);
        assert_eq!(f.len(), 5);
        assert_eq!(f[0].agrees, Some(true), "{:?}", f[0]);
        assert!(f[0].ours.contains("1.100e0 / 2.100e0"), "{}", f[0].ours);
        assert_eq!(f[1].agrees, Some(true));
        assert_eq!(f[2].agrees, Some(false));
        // 3 vs 6: the ranks put 3 above 6, the means (2.1 against 3.1) below: undecided.
        assert_eq!(f[3].agrees, None, "{:?}", f[3]);
        assert!(f[3].note.contains("different ways"), "{}", f[3].note);
        assert_eq!(f[4].agrees, Some(true));
        // Tied ranks do not contradict the means.
        let mut tied = r.clone();
        tied["wiping"]["art"]["pooled"]["contrasts"][2] = contrast("3", "6", 0.0, 0.01);
        assert_eq!(
            findings(Experiment::Interference, &tied)[3].agrees,
            Some(true)
        );
        // The rise itself: means rise from none to 9 added, but ranks of 0 vs 9 say the
        // other way: undecided.
        let mut against = r.clone();
        against["wiping"]["art"]["pooled"]["contrasts"][1] = contrast("0", "9", 6.0, 0.20);
        let f = findings(Experiment::Interference, &against);
        assert_eq!(f[0].agrees, None, "{:?}", f[0]);
        assert!(f[0].note.contains("different ways"), "{}", f[0].note);
        // Every Holm contrast has its raw difference with its interval beside its p:
        // 6 added − 0 = 2 (independent groups, SD 0.1414 each).
        assert!(
            f[1].effect
                .starts_with("6 added − 0, pooled: Δ = 2.000e0 ["),
            "{}",
            f[1].effect
        );
        assert!(
            f[1..].iter().all(|x| x.effect.contains("detectable")),
            "{f:?}"
        );

        // An incomplete direction is not tested, whatever its partial numbers say.
        let mut partial = r.clone();
        partial["wiping"]["complete"] = json!(false);
        partial["wiping"]["trainings_done"] = json!(7);
        partial["wiping"]["trainings_planned"] = json!(20);
        partial["wiping"]["jobs_done"] = json!(49);
        partial["wiping"]["jobs_planned"] = json!(140);
        let f = findings(Experiment::Interference, &partial);
        assert!(
            f.iter().all(|x| x.agrees.is_none() && x.effect == "–"),
            "{f:?}"
        );
        assert!(
            f[0].note.contains("7 of the direction's 20"),
            "{}",
            f[0].note
        );
    }

    #[test]
    fn a_non_significant_result_is_set_against_the_papers_effect() {
        let change = |t: f64, p: f64| {
            json!({"comparisons": [
                {"module": "all modules", "measure": "mean absolute change of prior sigma",
                 "paired_t": {"t": t, "df": 2.0, "p": p, "n": 3}},
            ]})
        };
        // Fig 4B, repositioning − wiping (the paper: t(4) = −8.15 at 5 networks).
        // t(2) = −0.20 at 3 networks: one effect for both studies is rejected (R: χ² 7.53,
        // p = 0.006): the two differ.
        let f = &findings(Experiment::Uncertainty, &change(-0.2, 0.86))[1];
        assert_eq!(f.agrees, Some(false), "{f:?}");
        assert!(
            f.note.contains("beyond both studies' uncertainty") && f.note.contains("χ²(1) = 7.53"),
            "{}",
            f.note
        );
        // t(2) = −1.79 (p = 0.215): one effect fits both (χ² 3.06, p = 0.080): undecided,
        // though our interval, δ up to 4.24, lies below the paper's estimate (6.31 at 3).
        let f = &findings(Experiment::Uncertainty, &change(-1.79, 0.215))[1];
        assert_eq!(f.agrees, None, "{f:?}");
        assert!(
            f.note.contains("too small a design")
                && f.note
                    .contains("[-0.86, 4.24], the paper's estimate 6.31 at our 3 networks"),
            "{}",
            f.note
        );
        // The opposite direction is not set against anything.
        let f = &findings(Experiment::Uncertainty, &change(1.79, 0.215))[1];
        assert!(f.note.contains("opposite"), "{}", f.note);

        // Fig 6B's Holm contrasts report only p: the paper's effect is at least the t that
        // p allows (4.01 on 16 df for p < 0.001, δ 4.01 at 5 networks).
        let label = |k: &str| format!("wiping 9 + repositioning {k}");
        let contrast = |a: &str, b: &str, t: f64| json!({"a": label(a), "b": label(b), "rank_difference": t, "t": t, "df": 16.0, "p_holm": 0.5});
        let group = |m: f64| json!([m, m + 0.1, m + 0.2, m + 0.3, m + 0.4]);
        let r = |t_0_6: f64| {
            json!({"wiping": {
                "conditions": [label("0"), label("3"), label("6"), label("9")],
                "per_network": [[group(1.0), group(1.1), group(1.2), group(1.3)]],
                "complete": true,
                "art": {"pooled": {
                    "effect": {"f": 1.0, "df1": 3.0, "df2": 16.0, "p": 0.4},
                    "contrasts": [contrast("0", "6", t_0_6), contrast("0", "9", -1.0),
                        contrast("3", "6", -1.0), contrast("3", "9", -1.0)],
                }},
            }})
        };
        // t = −1.0 (0 below 6 in ranks) against a t of at least 4.01: the two differ
        // (R: χ² 6.43, p = 0.011).
        let f = findings(Experiment::Interference, &r(-1.0));
        assert_eq!(f[1].agrees, Some(false), "{:?}", f[1]);
        assert!(
            f[1].note
                .contains("the paper's at least 4.01 at our 5 networks"),
            "{}",
            f[1].note
        );
        // t = −3.0: one effect fits both (χ² 2.03, p = 0.15): undecided.
        let f = findings(Experiment::Interference, &r(-3.0));
        assert_eq!(f[1].agrees, None, "{:?}", f[1]);
        // The rise's F(3, 16) = 1.0 against the paper's 19.16: they differ (χ² 10.3).
        assert_eq!(f[0].agrees, Some(false), "{:?}", f[0]);
        assert!(f[0].note.contains("λ"), "{}", f[0].note);
    }

    #[test]
    fn the_asymmetry_is_read_from_both_directions() {
        let direction = json!({"complete": true});
        let test = |difference: f64, p: f64| {
            json!({"log_ratio": [0.0, difference], "change": [0.0, difference.exp() - 1.0],
                "difference": difference, "ci95": [difference - 0.1, difference + 0.1],
                "t": difference / 0.05, "df": 7.5, "p": p, "detectable": 0.14})
        };
        let r = |asymmetry: Value| json!({"repositioning": direction, "wiping": direction, "asymmetry": asymmetry});
        let last = |r: &Value| findings(Experiment::Interference, r).pop().unwrap();
        // Not yet tested: no asymmetry in the results.
        let f = last(&json!({"repositioning": direction, "wiping": direction}));
        assert!(
            f.finding.contains("asymmetric") && f.agrees.is_none(),
            "{f:?}"
        );
        // Wiping's error rises by 20% more (log ratio 0.18), significantly: agrees.
        let ordered = |a: Value| {
            r(json!({"first": "repositioning", "second": "wiping", "measures": {"pooled": a}}))
        };
        let f = last(&ordered(test(0.18, 0.01)));
        assert_eq!(f.agrees, Some(true), "{f:?}");
        assert!(
            f.ours.contains("wiping +19.7%, repositioning +0.0%"),
            "{}",
            f.ours
        );
        assert!(
            f.effect
                .starts_with("wiping's − repositioning's log ratio: 1.800e-1"),
            "{}",
            f.effect
        );
        // The same numbers with the directions the other way round: repositioning's rise.
        let swapped = r(json!({"first": "wiping", "second": "repositioning",
            "measures": {"pooled": test(0.18, 0.01)}}));
        let f = last(&swapped);
        assert_eq!(f.agrees, Some(false), "{f:?}");
        assert!(f.note.contains("opposite"), "{}", f.note);
        assert!(
            f.effect.contains("-1.800e-1 [-2.800e-1, -8.000e-2]"),
            "{}",
            f.effect
        );
        // Every other finding of the directions is still there, the asymmetry last.
        assert_eq!(
            findings(Experiment::Interference, &ordered(test(0.18, 0.01))).len(),
            7
        );
    }

    #[test]
    fn repositioning_no_change_is_tested_as_equivalence() {
        let r = |equivalent: bool, p: f64| {
            json!({"repositioning": {
                "complete": true,
                "art": {"pooled": {"effect": {"f": 1.0, "df1": 3.0, "df2": 16.0, "p": p}}},
                "equivalence": {"pooled": {"mean": 1e-5, "ci90": [-2e-5, 4e-5], "margin": 3e-4,
                    "p": if equivalent { 0.01 } else { 0.3 }, "equivalent": equivalent}},
            }})
        };
        let agrees =
            |equivalent: bool, p: f64| findings(Experiment::Interference, &r(equivalent, p));
        let f = agrees(true, 0.6);
        assert_eq!(f[0].agrees, Some(true), "{:?}", f[0]);
        assert!(
            f[0].ours.starts_with("TOST: difference 1.000e-5"),
            "{}",
            f[0].ours
        );
        // Not significant is not enough: without equivalence it is undecided.
        let f = agrees(false, 0.6);
        assert_eq!(f[0].agrees, None, "{:?}", f[0]);
        assert!(f[0].note.contains("undecided"), "{}", f[0].note);
        assert_eq!(agrees(false, 0.01)[0].agrees, Some(false));
        // A change the ANOVA finds within the margin agrees, the change stated beside it;
        // without a TOST it disagrees.
        let f = agrees(true, 0.01);
        assert_eq!(f[0].agrees, Some(true), "{:?}", f[0]);
        assert!(f[0].note.contains("ANOVA significant"), "{}", f[0].note);
        assert!(
            f[0].note.contains("9 added against none lies within"),
            "{}",
            f[0].note
        );
        let mut no_tost = r(true, 0.01);
        no_tost["repositioning"]["equivalence"] = json!({});
        let f = findings(Experiment::Interference, &no_tost);
        assert_eq!(f[0].agrees, Some(false), "{:?}", f[0]);
    }
}
