//! Interference's findings (Fig 6): no change for repositioning, the rise for wiping,
//! Holm-corrected contrasts and the asymmetry between directions.

use serde_json::Value;

use super::{
    ASYMMETRY, Finding, GateNeed, against, effect_text, f_text, finding, mean_of,
    no_difference_verdict, num, our_f, our_t, p_text, tost_text, untested, verdict,
    verdict_against,
};
use crate::compatibility::{Compatibility, PaperStatistic};

pub(super) fn interference(r: &Value) -> Vec<Finding> {
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
pub(super) fn added(label: &str) -> String {
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
