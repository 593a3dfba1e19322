//! The findings' verdicts on hand-made results.

use super::hierarchy::against_baselines_finding;
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
    let agrees = |equivalent: bool, p: f64| findings(Experiment::Interference, &r(equivalent, p));
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
