//! Interference (Fig 6): each primary task's error as the other task's data is added, per
//! direction, and the asymmetry between directions.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

use anyhow::Result;
use pvrnn_core::ModelConfig;
use pvrnn_eval::plots::{Bar, bar_chart};
use pvrnn_eval::report::sig;
use serde_json::{Value, json};

use super::{
    EQUIVALENCE_MARGIN, Results, bar, contrasts_table, effects_table, mean_se_text, p_text,
    per_network,
};
use crate::plan::{Experiment, JobKind, Plan};
use crate::run::InferResult;
use crate::stats::{self, mean_se};

/// Dimensions per vision resolution (keyed as the run's errors are) and in all, with
/// proprioception: the paper's pooled error is the mean over all sensory dimensions.
fn sensory_dimensions() -> (Vec<(String, f64)>, f64) {
    let config = ModelConfig::default();
    let layout = &config.vision;
    let vision: Vec<(String, f64)> = (0..layout.resolutions.len())
        .map(|l| {
            (
                format!("vision{}", layout.resolutions[l]),
                (layout.level_offset(l + 1) - layout.level_offset(l)) as f64,
            )
        })
        .collect();
    let all = vision.iter().map(|(_, d)| d).sum::<f64>() + config.proprio_dims as f64;
    (vision, all)
}

/// The paper's pooled error of a run: its squared errors averaged over every sensory
/// dimension (every vision resolution and proprioception).
fn pooled_error(x: &InferResult) -> Option<f64> {
    let (vision, all) = sensory_dimensions();
    let proprio_dims = ModelConfig::default().proprio_dims as f64;
    let mut sum = x.errors.get("proprio")? * proprio_dims;
    for (key, dims) in &vision {
        sum += x.errors.get(key)? * dims;
    }
    Some(sum / all)
}

/// The table of the difference most added − none per measure (independent networks),
/// with its 95% CI and the detectable difference, and the equivalence test of "no change"
/// (Fig 6A) against ±`EQUIVALENCE_MARGIN` of the none condition's mean; both as JSON.
fn most_minus_none(
    names: &[&str],
    per_measure: &[Vec<Vec<f64>>],
    md: &mut String,
) -> (
    serde_json::Map<String, Value>,
    serde_json::Map<String, Value>,
) {
    let mut differences = serde_json::Map::new();
    let mut equivalences = serde_json::Map::new();
    md.push_str(
        "| measure | most added − none | 95% CI | d | detectable | equivalence margin | 90% CI | TOST p | equivalent |\n|---|---|---|---|---|---|---|---|---|\n",
    );
    for (name, groups) in names.iter().zip(per_measure) {
        let (d, e) = match (groups.first(), groups.last()) {
            (Some(none), Some(most)) if groups.len() > 1 => (
                stats::difference(most, none, false),
                stats::equivalence(
                    most,
                    none,
                    EQUIVALENCE_MARGIN * mean_se(none).0.abs(),
                    false,
                ),
            ),
            _ => (None, None),
        };
        let equivalence_cells = e.as_ref().map_or("| | | |".to_string(), |e| {
            format!(
                "±{} | [{}, {}] | {} | {} |",
                sig(e.margin),
                sig(e.ci90[0]),
                sig(e.ci90[1]),
                p_text(e.p),
                if e.equivalent { "yes" } else { "no" }
            )
        });
        match &d {
            Some(d) => {
                let _ = writeln!(
                    md,
                    "| {name} | {} | [{}, {}] | {} | ±{} | {equivalence_cells}",
                    sig(d.mean),
                    sig(d.ci95[0]),
                    sig(d.ci95[1]),
                    sig(d.cohen_d),
                    sig(d.detectable)
                );
            }
            None => {
                let _ = writeln!(md, "| {name} | – | | | | {equivalence_cells}");
            }
        }
        differences.insert(name.to_string(), json!(d));
        equivalences.insert(name.to_string(), json!(e));
    }
    (differences, equivalences)
}

/// The primary task of an interference training condition or of a job that reads one
/// (`repositioning 9 + wiping 3` → `repositioning`).
fn primary_of<'a>(plan: &'a Plan, job: &crate::plan::Job) -> Option<&'a str> {
    let condition = match &job.kind {
        JobKind::Train { condition, .. } => condition,
        JobKind::Infer { training, .. } => training,
    };
    plan.design
        .primary_tasks
        .iter()
        .find(|p| condition.starts_with(p.as_str()))
        .map(String::as_str)
}

/// The jobs of one direction of the interference experiment: its trainings and their
/// inference runs.
fn direction_jobs(plan: &Plan, primary: &str) -> Vec<usize> {
    plan.jobs
        .iter()
        .filter(|j| primary_of(plan, j) == Some(primary))
        .map(|j| j.id)
        .collect()
}

/// The network job `id` belongs to, once its training and every inference run of it are
/// done: its name (`network 2 (wiping 9 + repositioning 6)`). The runner asks after each
/// job it finishes and rebuilds the report when one is named, so that a long campaign's
/// report always holds what is done.
pub fn network_completed_by(plan: &Plan, dir: &Path, id: usize) -> Option<String> {
    let train = match &plan.jobs.get(id)?.kind {
        JobKind::Train { .. } => id,
        JobKind::Infer { train_job, .. } => *train_job,
    };
    let JobKind::Train {
        network, condition, ..
    } = &plan.jobs.get(train)?.kind
    else {
        return None;
    };
    let runs = plan
        .jobs
        .iter()
        .filter(|j| matches!(j.kind, JobKind::Infer { train_job, .. } if train_job == train));
    (plan.is_done(dir, train) && runs.into_iter().all(|j| plan.is_done(dir, j.id)))
        .then(|| format!("network {network} ({condition})"))
}

/// The part of the design job `id` belongs to whose analysis runs before the whole plan
/// is done (an interference direction of a two-direction plan), once every training and
/// inference run of it is done: its name (`the repositioning direction`). The runner asks
/// after each job it finishes and rebuilds the report when a part is named.
pub fn completed_by(plan: &Plan, dir: &Path, id: usize) -> Option<String> {
    if plan.experiment != Experiment::Interference || plan.design.primary_tasks.len() < 2 {
        return None;
    }
    let primary = primary_of(plan, plan.jobs.get(id)?)?;
    direction_jobs(plan, primary)
        .iter()
        .all(|&j| plan.is_done(dir, j))
        .then(|| format!("the {primary} direction"))
}

/// A direction's conditions in plan order, and how many networks each plans (the
/// design, not what is done so far).
fn planned_conditions(plan: &Plan, primary: &str) -> (Vec<String>, BTreeMap<String, usize>) {
    let mut conditions: Vec<String> = Vec::new();
    let mut planned: BTreeMap<String, usize> = BTreeMap::new();
    for job in &plan.jobs {
        if let JobKind::Train { condition, .. } = &job.kind
            && primary_of(plan, job) == Some(primary)
        {
            if !conditions.contains(condition) {
                conditions.push(condition.clone());
            }
            *planned.entry(condition.clone()).or_default() += 1;
        }
    }
    (conditions, planned)
}

/// A complete direction's tests, per measure: most added − none with the equivalence
/// test, and the one-way ART ANOVA with its contrasts; into the report and `direction`.
fn direction_tests(
    names: &[&str],
    conditions: &[String],
    per_measure: &[Vec<Vec<f64>>],
    direction: &mut Value,
    md: &mut String,
) -> Result<()> {
    let mut tests = serde_json::Map::new();
    let (differences, equivalences) = most_minus_none(names, per_measure, md);
    md.push('\n');
    for (name, groups) in names.iter().zip(per_measure) {
        match stats::art_one_way(conditions, groups) {
            Some(a) => {
                let _ = writeln!(md, "{name}:\n");
                effects_table(md, std::slice::from_ref(&a.effect));
                md.push('\n');
                contrasts_table(md, &a.contrasts);
                md.push('\n');
                tests.insert(name.to_string(), serde_json::to_value(&a)?);
            }
            None => {
                let _ = writeln!(
                    md,
                    "{name}: too few networks per condition for the ANOVA.\n"
                );
            }
        }
    }
    direction["art"] = Value::Object(tests);
    direction["most_minus_none"] = Value::Object(differences);
    direction["equivalence"] = Value::Object(equivalences);
    Ok(())
}

pub(super) fn interference(
    plan: &Plan,
    r: &Results,
    out: &Path,
    stamp: &str,
    md: &mut String,
) -> Result<Value> {
    let top = ModelConfig::default()
        .vision
        .resolutions
        .last()
        .copied()
        .unwrap_or(64);
    let all_dims = sensory_dimensions().1;
    let pooled = pooled_error;
    type Measure<'a> = (&'a str, &'a dyn Fn(&InferResult) -> Option<f64>);
    // Pre-specified: the paper's pooled error first (the test the findings read), then
    // each modality and the equal-weight mean beside it.
    let measures: [Measure<'_>; 4] = [
        ("pooled", &pooled),
        ("vision", &|x| {
            x.errors.get(&format!("vision{top}")).copied()
        }),
        ("proprioception", &|x| x.errors.get("proprio").copied()),
        ("equal weight", &|x| {
            Some((x.errors.get(&format!("vision{top}"))? + x.errors.get("proprio")?) / 2.0)
        }),
    ];
    let _ = writeln!(
        md,
        "## Multitask interference ({stamp})\n\nEach primary task's 9 learning sequences plus 0 / 3 / 6 / 9 of the other task's (3 = one per bed height, 6 = two), one normalisation for all; errors of the primary task's test sequences (reconstruction MSE, everything observed). Measures, named before the converged runs (the reduced-scale results were re-analysed with them afterwards): **pooled** = the paper's, the mean squared error over all {all_dims} sensory dimensions (every vision resolution and proprioception; vision dominates by dimension count); beside it vision (the {top}x{top} images), proprioception, and the equal-weight mean of the two. Per network, mean ± SE over networks; one-way ART ANOVA over the conditions (independent groups, as the paper's one-way ANOVA: each condition's network k starts from seed k but learns other data, and the pre-specified analysis does not pair networks by seed, which is conservative if same-seed networks err alike), Holm-corrected ART-C contrasts, Cohen's d and the raw difference with its 95% CI; the difference most added − none with its 95% CI and the smallest difference the design detects (80% power, two-sided t-test from the observed variance); and \"no change\" (Fig 6A) tested as equivalence of most added and none: two one-sided tests against ±{:.0}% of the none condition's mean, equivalent when the 90% CI lies inside. A direction is tested only when every training and inference run of its plan is done.\n",
        EQUIVALENCE_MARGIN * 100.0
    );
    let mut json_out = serde_json::Map::new();
    for primary in &plan.design.primary_tasks {
        let (conditions, planned) = planned_conditions(plan, primary);
        let jobs = direction_jobs(plan, primary);
        let jobs_done = jobs.iter().filter(|&&j| plan.is_done(&r.dir, j)).count();
        let complete = !jobs.is_empty() && jobs_done == jobs.len();
        let trainings_done = r
            .trains
            .iter()
            .filter(|t| t.condition.starts_with(primary.as_str()))
            .count();
        let trainings_planned: usize = planned.values().sum();
        let _ = writeln!(md, "### Primary task: {primary}\n");
        if !complete {
            let _ = writeln!(
                md,
                "**No test yet**: {trainings_done} of this direction's {trainings_planned} trainings and {jobs_done} of its {} jobs are done. The tests run on the complete design only; the means below are descriptive.\n",
                jobs.len()
            );
        }
        md.push_str("| training | networks | pooled | vision | proprioception | equal weight |\n|---|---|---|---|---|---|\n");
        let mut per_measure: Vec<Vec<Vec<f64>>> = vec![Vec::new(); measures.len()];
        for c in &conditions {
            let done = r.trains.iter().filter(|t| &t.condition == c).count();
            let mut row = format!("| {c} | {done} of {} |", planned[c]);
            for (k, (_, f)) in measures.iter().enumerate() {
                let nets: Vec<f64> = per_network(&r.infers, &|x| &x.training == c, *f)
                    .into_values()
                    .collect();
                let _ = write!(row, " {} |", mean_se_text(&nets));
                per_measure[k].push(nets);
            }
            md.push_str(&row);
            md.push('\n');
        }
        let groups: Vec<(String, Vec<Bar>)> = measures
            .iter()
            .enumerate()
            .map(|(k, (name, _))| {
                (
                    name.to_string(),
                    conditions
                        .iter()
                        .zip(&per_measure[k])
                        .map(|(c, v)| bar(c, v))
                        .collect(),
                )
            })
            .collect();
        let file = format!("interference_{primary}.png");
        let title = if complete {
            format!("{primary}: error by training condition ({stamp})")
        } else {
            format!(
                "{primary}: error by training condition ({stamp}; {trainings_done} of {trainings_planned} trainings, no test yet)"
            )
        };
        bar_chart(&out.join(&file), &title, "MSE", &conditions, &groups)?;
        let _ = writeln!(md, "\n![{primary}]({file})\n");
        let mut direction = json!({
            "conditions": conditions,
            "measures": measures.iter().map(|(n, _)| *n).collect::<Vec<_>>(),
            "per_network": per_measure,
            "complete": complete,
            "trainings_done": trainings_done,
            "trainings_planned": trainings_planned,
            "jobs_done": jobs_done,
            "jobs_planned": jobs.len(),
        });
        if complete {
            let names: Vec<&str> = measures.iter().map(|(n, _)| *n).collect();
            direction_tests(&names, &conditions, &per_measure, &mut direction, md)?;
        }
        json_out.insert(primary.clone(), direction);
    }
    if let Some(asymmetry) = asymmetry(&plan.design.primary_tasks, &json_out, md) {
        json_out.insert(crate::paper::ASYMMETRY.into(), asymmetry);
    }
    Ok(Value::Object(json_out))
}

/// The asymmetry of the two directions (pre-specified 2026-11-30, before the second
/// direction's first training): whether the most added data changes the second primary
/// task's error by a different factor than the first's, per measure
/// ([`stats::relative_change_difference`] of none → most added); once both directions are
/// complete.
fn asymmetry(
    primaries: &[String],
    directions: &serde_json::Map<String, Value>,
    md: &mut String,
) -> Option<Value> {
    let [first, second] = primaries else {
        return None;
    };
    let (a, b) = (directions.get(first)?, directions.get(second)?);
    if a["complete"] != true || b["complete"] != true {
        return None;
    }
    // A direction's none and most-added groups of measure k.
    let ends = |d: &Value, k: usize| -> Option<[Vec<f64>; 2]> {
        let groups = d["per_network"][k].as_array()?;
        let values = |g: &Value| -> Vec<f64> {
            g.as_array()
                .map_or(Vec::new(), |v| v.iter().filter_map(Value::as_f64).collect())
        };
        Some([values(groups.first()?), values(groups.last()?)])
    };
    let _ = writeln!(
        md,
        "### Asymmetry: does the other task's data change {second}'s error by a different factor than {first}'s?

Pre-specified on 2026-11-30, before the converged campaign's second direction began (docs/experiments.md): each direction's change from none to the most added is the ratio of the two conditions' geometric-mean errors; the test is Welch's t of the difference of the log ratios ({second}'s − {first}'s; two-sided, 95% CI, and the smallest difference the design detects with 80% power). The paper's asymmetry (Fig 6: wiping's error rises with repositioning data added, repositioning's does not change with wiping data added) is wiping's log ratio above repositioning's.

| measure | {first}: change | {second}: change | difference of log ratios [95% CI] | t | df | p | detectable |\n|---|---|---|---|---|---|---|---|"
    );
    let mut tests = serde_json::Map::new();
    let names = a["measures"].as_array()?;
    for (k, name) in names.iter().enumerate() {
        let name = name.as_str()?;
        let ([a0, a1], [b0, b1]) = (ends(a, k)?, ends(b, k)?);
        let test = stats::relative_change_difference([&a0, &a1], [&b0, &b1]);
        match &test {
            Some(t) => {
                let _ = writeln!(
                    md,
                    "| {name} | {:+.1}% | {:+.1}% | {} [{}, {}] | {:.2} | {:.1} | {} | ±{} |",
                    100.0 * t.change[0],
                    100.0 * t.change[1],
                    sig(t.difference),
                    sig(t.ci95[0]),
                    sig(t.ci95[1]),
                    t.t,
                    t.df,
                    p_text(t.p),
                    sig(t.detectable)
                );
            }
            None => {
                let _ = writeln!(md, "| {name} | – | – | – | | | | |");
            }
        }
        tests.insert(name.to_string(), json!(test));
    }
    md.push('\n');
    Some(json!({"first": first, "second": second, "measures": tests}))
}
