//! The success table of many episodes ([`episodes`] reads them, [`markdown`] writes it):
//! every episode folder under a directory (its `drive.json`), grouped by controller and condition (what was done to the robot,
//! and whether the bed height was learned), with the success count, a 95% Wilson interval
//! over episodes, each criterion's count, and the mean joint distance from the
//! demonstration with its standard error over episodes.
//!
//! Episodes of one network are not independent units for a claim about networks
//! (docs/closed-loop.md, "Statistics": the unit is the network); this table reports what
//! was run, as measured.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use crate::output::SUMMARY;
use crate::{Error, Result};

/// The bed heights the benchmark learns (mm).
const LEARNED: [u64; 3] = [590, 650, 710];

/// One episode as its `drive.json` states it.
#[derive(Clone, Debug, PartialEq)]
pub struct Row {
    pub folder: PathBuf,
    pub task: String,
    pub controller: String,
    pub condition: String,
    pub success: bool,
    pub criteria: Vec<(String, bool)>,
    pub joint_distance: f64,
    /// The joint path travelled as a share of the demonstration's.
    pub joint_path_share: f64,
}

fn field<'a>(
    v: &'a serde_json::Value,
    path: &[&str],
    file: &Path,
) -> Result<&'a serde_json::Value> {
    path.iter()
        .try_fold(v, |v, k| v.get(k))
        .ok_or_else(|| Error::Invalid(format!("{}: no field {}", file.display(), path.join("."))))
}

impl Row {
    /// Reads an episode folder's `drive.json`.
    pub fn read(folder: &Path) -> Result<Self> {
        let file = folder.join(SUMMARY);
        let text = std::fs::read_to_string(&file)
            .map_err(|e| Error::Invalid(format!("{}: {e}", file.display())))?;
        let v: serde_json::Value = serde_json::from_str(&text)
            .map_err(|e| Error::Invalid(format!("{}: not JSON: {e}", file.display())))?;
        let text_of = |path: &[&str]| -> Result<String> {
            Ok(field(&v, path, &file)?
                .as_str()
                .unwrap_or_default()
                .to_string())
        };
        let spec = field(&v, &["spec"], &file)?;
        let p = field(spec, &["perturbations"], &file)?;
        let mut condition = Vec::new();
        let height = field(spec, &["bed_height_mm"], &file)?
            .as_u64()
            .unwrap_or(0);
        if !LEARNED.contains(&height) {
            condition.push("unlearned bed height".to_string());
        }
        if let Some(label) = v.get("condition").and_then(|c| c.as_str())
            && label.starts_with("vision 16,")
        {
            condition.push("16x16 vision".into());
        }
        let noise = p
            .get("sensor_noise")
            .and_then(|n| n.as_f64())
            .unwrap_or(1.0);
        if noise != 1.0 {
            condition.push(format!("sensor noise x{noise}"));
        }
        if !p.get("push").is_none_or(|x| x.is_null()) {
            condition.push("push".into());
        }
        if !p.get("occlusion").is_none_or(|x| x.is_null()) {
            condition.push("camera occluded".into());
        }
        if let Some(levels) = p
            .get("vision_drop")
            .and_then(|x| x.get("levels"))
            .and_then(|x| x.as_u64())
        {
            condition.push(format!("vision dropped to {levels} levels mid-task"));
        }
        if v.get("speed_limit").and_then(|l| l.as_str()) == Some("panda") {
            condition.push("Panda's joint speeds".into());
        }
        let outcome = field(&v, &["outcome"], &file)?;
        let criteria = field(outcome, &["criteria"], &file)?
            .as_array()
            .map(|a| {
                a.iter()
                    .filter_map(|c| Some((c.get(0)?.as_str()?.to_string(), c.get(1)?.as_bool()?)))
                    .collect()
            })
            .unwrap_or_default();
        Ok(Self {
            folder: folder.to_path_buf(),
            task: text_of(&["outcome", "task"])?,
            controller: text_of(&["spec", "controller"])?,
            condition: if condition.is_empty() {
                "as learned".into()
            } else {
                condition.join(", ")
            },
            success: field(outcome, &["success"], &file)?
                .as_bool()
                .unwrap_or(false),
            criteria,
            joint_distance: field(outcome, &["joint_distance"], &file)?
                .as_f64()
                .unwrap_or(f64::NAN),
            joint_path_share: field(outcome, &["joint_path_share"], &file)?
                .as_f64()
                .unwrap_or(f64::NAN),
        })
    }
}

/// Every episode under a directory (folders holding a `drive.json`, at any depth), in
/// path order.
pub fn episodes(root: &Path) -> Result<Vec<Row>> {
    let mut found = Vec::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        if dir.join(SUMMARY).is_file() {
            found.push(dir.clone());
        }
        let entries = std::fs::read_dir(&dir)
            .map_err(|e| Error::Invalid(format!("{}: {e}", dir.display())))?;
        for entry in entries.flatten() {
            if entry.file_type().is_ok_and(|t| t.is_dir()) {
                stack.push(entry.path());
            }
        }
    }
    found.sort();
    if found.is_empty() {
        return Err(Error::Invalid(format!(
            "{}: no episode folders (none holds a {SUMMARY})",
            root.display()
        )));
    }
    found.iter().map(|f| Row::read(f)).collect()
}

/// 95% Wilson score interval of `k` successes in `n`.
pub fn wilson(k: usize, n: usize) -> (f64, f64) {
    if n == 0 {
        return (0.0, 1.0);
    }
    let (z, n, p) = (1.959_963_984_540_054, n as f64, k as f64 / n as f64);
    let centre = (p + z * z / (2.0 * n)) / (1.0 + z * z / n);
    let half = z / (1.0 + z * z / n) * (p * (1.0 - p) / n + z * z / (4.0 * n * n)).sqrt();
    ((centre - half).max(0.0), (centre + half).min(1.0))
}

/// One row of the table: the episodes of one task, condition and controller.
#[derive(Clone, Debug, PartialEq)]
pub struct Summary {
    pub task: String,
    pub condition: String,
    pub controller: String,
    pub episodes: usize,
    pub successes: usize,
    /// The success rate's 95% Wilson interval over episodes.
    pub interval: (f64, f64),
    /// Each criterion with the number of episodes that met it.
    pub criteria_met: Vec<(String, usize)>,
    /// The joint distance from the demonstration: mean and standard error over episodes
    /// (`None` for one episode).
    pub joint_distance: (f64, Option<f64>),
    /// The joint path as a share of the demonstration's, mean over episodes.
    pub joint_path_share: f64,
}

impl Summary {
    pub fn success_rate(&self) -> f64 {
        self.successes as f64 / self.episodes.max(1) as f64
    }
}

/// The episodes grouped by task, condition and controller, in that order.
pub fn summarise(rows: &[Row]) -> Vec<Summary> {
    let mut groups: BTreeMap<(String, String, String), Vec<&Row>> = BTreeMap::new();
    for r in rows {
        groups
            .entry((r.task.clone(), r.condition.clone(), r.controller.clone()))
            .or_default()
            .push(r);
    }
    groups
        .into_iter()
        .map(|((task, condition, controller), group)| {
            let n = group.len();
            let k = group.iter().filter(|r| r.success).count();
            let criteria_met = group[0]
                .criteria
                .iter()
                .enumerate()
                .map(|(i, (name, _))| {
                    let met = group
                        .iter()
                        .filter(|r| r.criteria.get(i).is_some_and(|c| c.1))
                        .count();
                    (name.clone(), met)
                })
                .collect();
            let d: Vec<f64> = group.iter().map(|r| r.joint_distance).collect();
            let mean = d.iter().sum::<f64>() / n as f64;
            // One episode: no spread to estimate.
            let se = (n > 1).then(|| {
                let ss: f64 = d.iter().map(|x| (x - mean) * (x - mean)).sum();
                (ss / (n - 1) as f64 / n as f64).sqrt()
            });
            Summary {
                task,
                condition,
                controller,
                episodes: n,
                successes: k,
                interval: wilson(k, n),
                criteria_met,
                joint_distance: (mean, se),
                joint_path_share: group.iter().map(|r| r.joint_path_share).sum::<f64>() / n as f64,
            }
        })
        .collect()
}

/// The table, as Markdown: one row per task, condition and controller.
pub fn markdown(rows: &[Row]) -> String {
    let mut out = String::from(
        "| task | condition | controller | episodes | success | 95% interval | each criterion met | joint distance (rad, mean ± se) | joint path (share of the demonstration's, mean) |\n|---|---|---|---|---|---|---|---|---|\n",
    );
    for g in summarise(rows) {
        let (n, k, (lo, hi)) = (g.episodes, g.successes, g.interval);
        let each: Vec<String> = g
            .criteria_met
            .iter()
            .map(|(name, met)| format!("{name} {met}/{n}"))
            .collect();
        let (mean, se) = g.joint_distance;
        let se = se.map_or("–".into(), |se| format!("{se:.3}"));
        out += &format!(
            "| {} | {} | {} | {n} | {k}/{n} | {lo:.2}-{hi:.2} | {} | {mean:.3} ± {se} | {:.0}% |\n",
            g.task,
            g.condition,
            g.controller,
            each.join("; "),
            100.0 * g.joint_path_share
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wilson_matches_its_textbook_values() {
        // 0 of 10: [0, 0.2775]; 5 of 10: [0.2366, 0.7634] (Wilson 1927 / Newcombe 1998).
        let (lo, hi) = wilson(0, 10);
        assert!(lo == 0.0 && (hi - 0.2775).abs() < 1e-4, "{hi}");
        let (lo, hi) = wilson(5, 10);
        assert!((lo - 0.2366).abs() < 1e-4 && (hi - 0.7634).abs() < 1e-4);
    }
}
