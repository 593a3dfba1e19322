//! Robustness's findings (Fig 5B): resolution, proprioception and their interaction, with
//! the verdicts on orders of means and ranks.

use serde_json::Value;

use super::{
    ALPHA, Finding, against, by_network, effect_text, f_text, finding, mean_of, num, our_f, our_t,
    p_text, paired_difference, verdict, verdict_against,
};
use crate::compatibility::{Compatibility, OurStatistic, PaperStatistic};

pub(super) fn robustness(r: &Value) -> Vec<Finding> {
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
