//! Uncertainty's findings (Fig 4): mean prior sigma between tasks (equivalence) and its
//! change over time.

use serde_json::Value;

use super::{
    Finding, against, effect_text, finding, no_difference_verdict, num, our_t, t_text, tost_text,
    verdict_against,
};
use crate::compatibility::PaperStatistic;

pub(super) fn uncertainty(r: &Value) -> Vec<Finding> {
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
