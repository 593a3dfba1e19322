//! Hierarchy's findings (Figs 2-3): the executive boundary tests, contributions by phase,
//! hidden body parts (against the observed frame and the observation-only baselines).

use super::{ALPHA, Finding, effect_text, finding, mean_of, num, p_text, verdict};
use serde_json::Value;

pub(super) fn hierarchy(r: &Value) -> Vec<Finding> {
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
pub(super) fn against_baselines_finding(against: &serde_json::Map<String, Value>) -> Finding {
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
