//! Robustness (Fig 5): reconstruction error by observed resolution and proprioception
//! (aligned rank transform ANOVA, contrasts).

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

use anyhow::Result;
use pvrnn_eval::plots::bar_chart;
use serde_json::{Value, json};

use super::{Results, bar, contrasts_table, effects_table, mean_se_text, per_network};
use crate::plan::{Plan, VISION_CONDITIONS};
use crate::stats::{self, Blocked2};

pub(super) fn robustness(r: &Results, out: &Path, stamp: &str, md: &mut String) -> Result<Value> {
    let top = r
        .infers
        .first()
        .and_then(|(x, _)| {
            x.errors
                .keys()
                .filter_map(|k| k.strip_prefix("vision")?.parse::<usize>().ok())
                .max()
        })
        .unwrap_or(64);
    let key = format!("vision{top}");
    let _ = writeln!(
        md,
        "## Reconstruction error of the {top}x{top} images under degraded input ({stamp})\n\nMSE (model units) of the posterior reconstruction of the full-resolution images, observed or not; per network, then mean ± SE over networks. The accuracy term divides each modality's error by its *observed* dimensions (the spec's default; configuration field `accuracy_normalisation`).\n"
    );
    let vision: Vec<String> = VISION_CONDITIONS.iter().map(|c| c.0.to_string()).collect();
    let proprio = ["on".to_string(), "off".to_string()];
    let mut cells: Vec<Vec<BTreeMap<usize, f64>>> = Vec::new();
    md.push_str("| vision | proprio on | proprio off |\n|---|---|---|\n");
    let mut groups = Vec::new();
    for (label, levels) in VISION_CONDITIONS {
        let mut row = Vec::new();
        let mut bars = Vec::new();
        for p in [true, false] {
            let nets = per_network(
                &r.infers,
                &|x| x.condition == Plan::condition_label(levels, p),
                &|x| x.errors.get(&key).copied(),
            );
            bars.push(bar(
                if p { "proprio on" } else { "proprio off" },
                &nets.values().copied().collect::<Vec<_>>(),
            ));
            row.push(nets);
        }
        let _ = writeln!(
            md,
            "| {label} | {} | {} |",
            mean_se_text(&row[0].values().copied().collect::<Vec<_>>()),
            mean_se_text(&row[1].values().copied().collect::<Vec<_>>())
        );
        groups.push((format!("vision {label}"), bars));
        cells.push(row);
    }
    bar_chart(
        &out.join("robustness.png"),
        &format!("{top}x{top} reconstruction error ({stamp})"),
        "MSE",
        &["proprio on".into(), "proprio off".into()],
        &groups,
    )?;
    md.push_str("\n![robustness](robustness.png)\n\n");
    // Networks with every cell.
    let networks: Vec<usize> = cells[0][0]
        .keys()
        .filter(|n| {
            cells
                .iter()
                .all(|row| row.iter().all(|c| c.contains_key(n)))
        })
        .copied()
        .collect();
    let design = Blocked2 {
        y: networks
            .iter()
            .map(|n| {
                cells
                    .iter()
                    .map(|row| row.iter().map(|c| c[n]).collect())
                    .collect()
            })
            .collect(),
        a_levels: vision.clone(),
        b_levels: proprio.iter().map(|p| format!("proprio {p}")).collect(),
    };
    let art = stats::art_two_way(&design);
    match &art {
        Some(a) => {
            let _ = writeln!(
                md,
                "### Two-way ART ANOVA (vision × proprioception, network as block, {} networks)\n",
                a.blocks
            );
            let mut effects = a.effects.clone();
            for (e, name) in
                effects
                    .iter_mut()
                    .zip(["vision", "proprioception", "vision × proprioception"])
            {
                e.effect = name.into();
            }
            effects_table(md, &effects);
            md.push_str("\n### ART-C contrasts (Holm within each family)\n\nRaw difference: over networks, paired (each network's mean of the level or cell), with its 95% CI.\n\nVision levels:\n\n");
            contrasts_table(md, &a.a_contrasts);
            md.push_str("\nCells:\n\n");
            contrasts_table(md, &a.cell_contrasts);
            md.push('\n');
        }
        None => md.push_str("Too few complete networks (at least 2) for the ANOVA.\n\n"),
    }
    Ok(json!({
        "error": key,
        "accuracy_normalisation": "observed",
        "cells": cells,
        "art": art,
    }))
}
