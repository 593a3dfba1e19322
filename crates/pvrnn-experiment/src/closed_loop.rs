//! The closed loop's statistics over networks, as pre-specified in docs/closed-loop.md
//! ("Statistics", 2026-12-06): the unit is the network. Per task, condition and
//! controller, each network's success rate over its episodes, and their mean over
//! networks with its standard error and a 95% interval; then the network in closed loop
//! against each open-loop baseline, paired by network: the difference of success rates
//! and of the joint distance from the demonstration (two-sided paired t, mean difference
//! with its 95% interval, d_z).
//!
//! Episodes come from `pvrnn drive` folders (`pvrnn_drive::table::Row`), each labelled
//! with the network that drove it (for the baselines: the network whose run of the table
//! produced it; the mean trajectory is the same for every network, so its "difference"
//! is the network's rate against that one value). And the success table's figure.

use std::collections::BTreeMap;

use pvrnn_drive::table::{Row, Summary};
use pvrnn_eval::plots::{Bar, bar_chart};

use crate::stats::{Difference, difference, mean_ci95};

/// The controller that closes the loop, and the baselines it is compared with.
const CLOSED_LOOP: &str = "network";
const BASELINES: [&str; 2] = ["prior", "mean-trajectory"];

/// Per network: the success rate and the mean joint distance over its episodes.
#[derive(Clone, Debug, PartialEq)]
pub struct NetworkScore {
    pub network: String,
    pub episodes: usize,
    pub success_rate: f64,
    pub joint_distance: f64,
}

/// Task, condition and controller.
type Cell = (String, String, String);

/// Each cell's scores, one per network, networks in name order.
pub fn scores(rows: &[(String, Row)]) -> BTreeMap<Cell, Vec<NetworkScore>> {
    let mut episodes: BTreeMap<Cell, BTreeMap<&str, Vec<&Row>>> = BTreeMap::new();
    for (network, row) in rows {
        let cell = (
            row.task.clone(),
            row.condition.clone(),
            row.controller.clone(),
        );
        episodes
            .entry(cell)
            .or_default()
            .entry(network)
            .or_default()
            .push(row);
    }
    episodes
        .into_iter()
        .map(|(cell, networks)| {
            let scores = networks
                .into_iter()
                .map(|(network, rows)| {
                    let n = rows.len() as f64;
                    NetworkScore {
                        network: network.to_string(),
                        episodes: rows.len(),
                        success_rate: rows.iter().filter(|r| r.success).count() as f64 / n,
                        joint_distance: rows.iter().map(|r| r.joint_distance).sum::<f64>() / n,
                    }
                })
                .collect();
            (cell, scores)
        })
        .collect()
}

/// The closed loop against one baseline in one task and condition, over the networks that
/// ran both.
#[derive(Clone, Debug)]
pub struct Comparison {
    pub task: String,
    pub condition: String,
    pub baseline: &'static str,
    pub networks: usize,
    /// Success rate, network − baseline (`None` with fewer than 2 networks).
    pub success: Option<Difference>,
    /// Joint distance from the demonstration (rad), network − baseline.
    pub joint_distance: Option<Difference>,
}

/// Every comparison the data allows: the network against each baseline, paired by network.
pub fn comparisons(scores: &BTreeMap<Cell, Vec<NetworkScore>>) -> Vec<Comparison> {
    let mut out = Vec::new();
    for ((task, condition, controller), closed) in scores {
        if controller != CLOSED_LOOP {
            continue;
        }
        for baseline in BASELINES {
            let key = (task.clone(), condition.clone(), baseline.to_string());
            let Some(open) = scores.get(&key) else {
                continue;
            };
            let pairs: Vec<(&NetworkScore, &NetworkScore)> = closed
                .iter()
                .filter_map(|c| Some((c, open.iter().find(|o| o.network == c.network)?)))
                .collect();
            let paired = |f: fn(&NetworkScore) -> f64| {
                let (a, b): (Vec<f64>, Vec<f64>) = pairs.iter().map(|(c, o)| (f(c), f(o))).unzip();
                difference(&a, &b, true)
            };
            out.push(Comparison {
                task: task.clone(),
                condition: condition.clone(),
                baseline,
                networks: pairs.len(),
                success: paired(|s| s.success_rate),
                joint_distance: paired(|s| s.joint_distance),
            });
        }
    }
    out
}

fn difference_text(d: &Option<Difference>, digits: usize) -> String {
    match d {
        Some(d) => format!(
            "{:+.digits$} [{:+.digits$}, {:+.digits$}], p {}, d_z {:.2}",
            d.mean,
            d.ci95[0],
            d.ci95[1],
            d.p.map_or("–".into(), |p| format!("{p:.4}")),
            d.cohen_d
        ),
        None => "– (fewer than 2 networks)".into(),
    }
}

/// The two tables as Markdown: success over networks per cell, then the comparisons.
pub fn markdown(rows: &[(String, Row)]) -> String {
    let scores = scores(rows);
    let mut out = String::from(
        "Over networks (the unit; docs/closed-loop.md, \"Statistics\"): each network's success rate over its episodes, their mean ± SE over networks and its 95% t interval.\n\n\
         | task | condition | controller | networks | episodes | success rate (mean ± se over networks) | 95% interval | per network |\n|---|---|---|---|---|---|---|---|\n",
    );
    for ((task, condition, controller), s) in &scores {
        let rates: Vec<f64> = s.iter().map(|s| s.success_rate).collect();
        let (mean, se) = crate::stats::mean_se(&rates);
        let interval = mean_ci95(&rates).map_or("–".into(), |[low, high]| {
            format!("{:.2}-{:.2}", low.max(0.0), high.min(1.0))
        });
        let each: Vec<String> = s
            .iter()
            .map(|s| format!("{} {:.2}", s.network, s.success_rate))
            .collect();
        out += &format!(
            "| {task} | {condition} | {controller} | {} | {} | {mean:.2} ± {} | {interval} | {} |\n",
            s.len(),
            s.iter().map(|s| s.episodes).sum::<usize>(),
            se.map_or("–".into(), |se| format!("{se:.2}")),
            each.join("; ")
        );
    }
    out += "\nThe closed loop against each open-loop baseline, paired by network (two-sided paired t; mean difference network − baseline [95% interval]). A comparison is a finding only for networks that pass the validity gate (docs/experiments.md); for any other it is reported as measured and is not testable.\n\n\
            | task | condition | baseline | networks | success rate difference | joint distance difference (rad) |\n|---|---|---|---|---|---|\n";
    for c in comparisons(&scores) {
        out += &format!(
            "| {} | {} | {} | {} | {} | {} |\n",
            c.task,
            c.condition,
            c.baseline,
            c.networks,
            difference_text(&c.success, 2),
            difference_text(&c.joint_distance, 3)
        );
    }
    out
}

/// The success table as bars (`pvrnn report drive --figure`): a group per task and
/// condition, a bar per controller, whiskers the 95% Wilson interval; PNG and SVG.
pub fn success_figure(summaries: &[Summary], path: &std::path::Path) -> anyhow::Result<()> {
    let mut controllers: Vec<String> = summaries.iter().map(|s| s.controller.clone()).collect();
    // The closed loop first, then its baselines.
    let order = |c: &String| {
        ["network", "prior", "mean-trajectory"]
            .iter()
            .position(|k| k == c)
    };
    controllers.sort_by_key(|c| (order(c).unwrap_or(usize::MAX), c.clone()));
    controllers.dedup();
    let mut groups: Vec<(String, Vec<Bar>)> = Vec::new();
    for s in summaries {
        let initial: String = s
            .task
            .chars()
            .take(1)
            .flat_map(char::to_uppercase)
            .collect();
        let label = format!("{initial}: {}", short_condition(&s.condition));
        if groups.last().is_none_or(|g| g.0 != label) {
            let empty = controllers.iter().map(|c| Bar {
                label: c.clone(),
                mean: f64::NAN, // a controller not run under this condition: no bar
                se: None,
                interval: None,
            });
            groups.push((label, empty.collect()));
        }
        let k = controllers
            .iter()
            .position(|c| *c == s.controller)
            .unwrap_or(0);
        let bars = &mut groups.last_mut().expect("pushed above").1;
        bars[k].mean = s.success_rate();
        bars[k].interval = Some(s.interval);
    }
    let episodes: usize = summaries.iter().map(|s| s.episodes).sum();
    bar_chart(
        path,
        &format!(
            "closed loop in caresim: success rate ({episodes} episodes; R repositioning, W wiping)"
        ),
        "success rate (95% Wilson interval)",
        &controllers,
        &groups,
    )?;
    Ok(())
}

/// A condition's words short enough for an axis label.
fn short_condition(condition: &str) -> String {
    condition
        .replace("as learned", "learned")
        .replace("unlearned bed height", "new height")
        .replace("16x16 vision", "16x16")
        .replace("sensor noise x", "noise x")
        .replace("camera occluded", "occluded")
        .replace("Panda's joint speeds", "Panda")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(task: &str, controller: &str, success: bool, distance: f64) -> Row {
        Row {
            folder: "x".into(),
            task: task.into(),
            controller: controller.into(),
            condition: "as learned".into(),
            success,
            criteria: vec![("grasped".into(), success)],
            joint_distance: distance,
            joint_path_share: 1.0,
        }
    }

    #[test]
    fn networks_are_the_unit_and_pairs_are_by_network() {
        // Three networks, two episodes each per controller: the network succeeds in
        // 2/2, 1/2, 2/2 episodes, its prior in none; the mean trajectory in 1/2 for all.
        let mut rows = Vec::new();
        for (k, wins) in [2, 1, 2].into_iter().enumerate() {
            let net = format!("net{k}");
            for e in 0..2 {
                rows.push((net.clone(), row("wiping", "network", e < wins, 0.1)));
                rows.push((
                    net.clone(),
                    row("wiping", "prior", false, 0.3 + 0.01 * k as f64),
                ));
                rows.push((net.clone(), row("wiping", "mean-trajectory", e == 0, 0.2)));
            }
        }
        let scores = scores(&rows);
        let network = &scores[&("wiping".into(), "as learned".into(), "network".into())];
        let rates: Vec<f64> = network.iter().map(|s| s.success_rate).collect();
        assert_eq!(rates, [1.0, 0.5, 1.0]);
        let c = comparisons(&scores);
        assert_eq!(c.len(), 2);
        let prior = c.iter().find(|c| c.baseline == "prior").unwrap();
        assert_eq!(prior.networks, 3);
        let d = prior.success.as_ref().unwrap();
        // Differences 1, 0.5, 1: mean 5/6.
        assert!((d.mean - 5.0 / 6.0).abs() < 1e-12, "{}", d.mean);
        assert!(d.ci95[0] < d.mean && d.mean < d.ci95[1] && d.p.unwrap() < 0.05);
        let distance = prior.joint_distance.as_ref().unwrap();
        assert!((distance.mean - (0.1 - 0.31)).abs() < 1e-12);
        let table = markdown(&rows);
        assert!(
            table.contains("| wiping | as learned | network | 3 | 6 | 0.83 ± 0.17 |"),
            "{table}"
        );
        assert!(
            table.contains("| wiping | as learned | prior | 3 | +0.83 ["),
            "{table}"
        );
        // One network: no test, said so.
        let one: Vec<_> = rows.into_iter().filter(|(n, _)| n == "net0").collect();
        assert!(markdown(&one).contains("– (fewer than 2 networks)"));
    }
}
