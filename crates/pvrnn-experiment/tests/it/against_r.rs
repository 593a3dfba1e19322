//! The experiments' statistics against an independent implementation: R's `lm`, `anova`,
//! `pt`, `p.adjust` and `t.test` (`tests/art.R`, base R only) on the same designs, with
//! ties, block effects, main effects and an interaction. Needs `Rscript` (Debian's
//! `r-base-core`, which `scripts/setup.sh` installs); without it the test says so and
//! passes, unless `PVRNN_REQUIRE_R=1` (set by `scripts/test.sh`).

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

use pvrnn_experiment::stats::{Blocked2, art_one_way, art_two_way, paired_t};

/// A seeded pseudo-random value in [0, 1) (a fixed design, no RNG crate needed).
fn noise(i: u64) -> f64 {
    let x = i.wrapping_mul(0x9E37_79B9_7F4A_7C15).rotate_left(17) ^ 0x2545_F491_4F6C_DD1D;
    (x.wrapping_mul(0xBF58_476D_1CE4_E5B9) >> 11) as f64 / (1u64 << 53) as f64
}

/// 5 networks x vision (3 levels) x proprioception (2 levels): vision and proprioception
/// effects, an interaction, block effects, and values rounded so that some tie.
fn two_way() -> Blocked2 {
    let mut y = Vec::new();
    for k in 0..5 {
        let mut rows = Vec::new();
        for i in 0..3 {
            let mut row = Vec::new();
            for j in 0..2 {
                let v = 1.0 + 0.6 * i as f64 + 0.4 * j as f64 * i as f64 + 0.3 * k as f64
                    - 0.2 * j as f64
                    + noise((k * 6 + i * 2 + j) as u64);
                row.push((v * 4.0).round() / 4.0);
            }
            rows.push(row);
        }
        y.push(rows);
    }
    Blocked2 {
        y,
        a_levels: vec!["v0".into(), "v1".into(), "v2".into()],
        b_levels: vec!["p0".into(), "p1".into()],
    }
}

fn one_way() -> (Vec<String>, Vec<Vec<f64>>) {
    let labels = vec!["g0".into(), "g1".into(), "g2".into(), "g3".into()];
    let groups = (0..4)
        .map(|g| {
            (0..5)
                .map(|n| ((g as f64 * 0.5 + 2.0 * noise(100 + g * 5 + n)) * 4.0).round() / 4.0)
                .collect()
        })
        .collect();
    (labels, groups)
}

fn paired() -> (Vec<f64>, Vec<f64>) {
    let x: Vec<f64> = (0..5).map(|n| 1.0 + noise(200 + n)).collect();
    let y = x
        .iter()
        .enumerate()
        .map(|(n, v)| v - 0.3 + 0.4 * noise(300 + n as u64))
        .collect();
    (x, y)
}

fn write_csvs(dir: &Path) {
    let design = two_way();
    let mut csv = String::from("block,a,b,y\n");
    for (k, block) in design.y.iter().enumerate() {
        for (i, row) in block.iter().enumerate() {
            for (j, v) in row.iter().enumerate() {
                csv += &format!(
                    "n{k},{},{},{v:.17}\n",
                    design.a_levels[i], design.b_levels[j]
                );
            }
        }
    }
    std::fs::write(dir.join("two_way.csv"), csv).unwrap();
    let (labels, groups) = one_way();
    let mut csv = String::from("group,y\n");
    for (label, g) in labels.iter().zip(&groups) {
        for v in g {
            csv += &format!("{label},{v:.17}\n");
        }
    }
    std::fs::write(dir.join("one_way.csv"), csv).unwrap();
    let (x, y) = paired();
    let mut csv = String::from("x,y\n");
    for (a, b) in x.iter().zip(&y) {
        csv += &format!("{a:.17},{b:.17}\n");
    }
    std::fs::write(dir.join("paired.csv"), csv).unwrap();
}

/// R's numbers, or `None` when there is no R (and it is not required).
fn r_results(dir: &Path) -> Option<BTreeMap<String, f64>> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/art.R");
    let out = match Command::new("Rscript").arg(&script).arg(dir).output() {
        Ok(out) => out,
        Err(e) => {
            assert!(
                std::env::var("PVRNN_REQUIRE_R").is_err(),
                "Rscript is required (PVRNN_REQUIRE_R) but cannot run: {e}"
            );
            eprintln!("skipped: no Rscript ({e}); `apt-get install r-base-core` to run it");
            return None;
        }
    };
    assert!(
        out.status.success(),
        "Rscript failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).unwrap();
    Some(
        text.lines()
            .filter_map(|l| {
                let mut w = l.split_whitespace();
                Some((w.next()?.to_string(), w.next()?.parse().ok()?))
            })
            .collect(),
    )
}

fn close(what: &str, ours: f64, theirs: f64) {
    let tol = 1e-9 * theirs.abs().max(1e-12) + 1e-12;
    assert!(
        (ours - theirs).abs() <= tol.max(1e-9 * ours.abs()),
        "{what}: ours {ours}, R {theirs}"
    );
}

#[test]
fn art_anova_contrasts_and_t_tests_match_r() {
    let dir = tempfile::tempdir().unwrap();
    write_csvs(dir.path());
    let Some(r) = r_results(dir.path()) else {
        return;
    };
    let get = |key: &str| *r.get(key).unwrap_or_else(|| panic!("R printed no {key}"));

    let art = art_two_way(&two_way()).unwrap();
    for (effect, key) in art.effects.iter().zip(["a", "b", "a:b"]) {
        close(
            &format!("F of {key}"),
            effect.f,
            get(&format!("two_way.F.{key}")),
        );
        close(
            &format!("p of {key}"),
            effect.p.unwrap(),
            get(&format!("two_way.p.{key}")),
        );
        close(
            &format!("df2 of {key}"),
            effect.df2,
            get(&format!("two_way.df2.{key}")),
        );
        close(
            &format!("partial eta squared of {key}"),
            effect.partial_eta_squared,
            get(&format!("two_way.eta.{key}")),
        );
    }
    // The design has effects to find, so the comparison is not of zeros.
    assert!(art.effects[0].p.unwrap() < 0.01, "{:?}", art.effects[0]);
    for c in &art.a_contrasts {
        let key = format!("two_way.contrast_a.{}-{}", c.a, c.b);
        close(&format!("{key} t"), c.t, get(&format!("{key}.t")));
        close(
            &format!("{key} Holm p"),
            c.p_holm.unwrap(),
            get(&format!("{key}.p_holm")),
        );
    }
    // The cell contrasts' error term is the combined factor's ANOVA on ranks.
    let c = &art.cell_contrasts[0];
    let se = c.rank_difference / c.t;
    close(
        "cell contrast MSE",
        se * se / (2.0 / 5.0),
        get("two_way.cells.mse"),
    );

    let (labels, groups) = one_way();
    let one = art_one_way(&labels, &groups).unwrap();
    close("one-way F", one.effect.f, get("one_way.F"));
    close("one-way p", one.effect.p.unwrap(), get("one_way.p"));
    for c in &one.contrasts {
        let key = format!("one_way.contrast.{}-{}", c.a, c.b);
        close(&format!("{key} t"), c.t, get(&format!("{key}.t")));
        close(
            &format!("{key} Holm p"),
            c.p_holm.unwrap(),
            get(&format!("{key}.p_holm")),
        );
    }

    let (x, y) = paired();
    let t = paired_t(&x, &y).unwrap();
    close("paired t", t.t, get("paired.t"));
    close("paired p", t.p.unwrap(), get("paired.p"));
}
