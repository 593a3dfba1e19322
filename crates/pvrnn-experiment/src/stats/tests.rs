//! The statistics against values computed by hand and by R.

use super::*;

#[test]
fn relative_change_difference_matches_a_hand_computation() {
    // Logs: first before {0, 0.2}, after {0.1, 0.3}: ratio 0.1; second before {1, 1.2},
    // after {1.5, 1.9}: ratio 0.6. Difference 0.5. Group variances of the logs 0.02,
    // 0.02, 0.02, 0.08; of the means (n = 2) 0.01 x 3 + 0.04: SE sqrt(0.07).
    let e = |logs: [f64; 2]| logs.map(f64::exp).to_vec();
    let d = relative_change_difference(
        [&e([0.0, 0.2]), &e([0.1, 0.3])],
        [&e([1.0, 1.2]), &e([1.5, 1.9])],
    )
    .unwrap();
    assert!((d.log_ratio[0] - 0.1).abs() < 1e-12 && (d.log_ratio[1] - 0.6).abs() < 1e-12);
    assert!((d.difference - 0.5).abs() < 1e-12, "{d:?}");
    let se = 0.07f64.sqrt();
    assert!((d.t - 0.5 / se).abs() < 1e-9, "{d:?}");
    // Welch-Satterthwaite: 0.07² / (3 x 0.01² + 0.04²) = 0.0049 / 0.0019.
    assert!((d.df - 0.0049 / 0.0019).abs() < 1e-9, "{d:?}");
    assert!((d.change[1] - (0.6f64.exp() - 1.0)).abs() < 1e-12);
    // A non-positive error has no log: no test.
    assert!(
        relative_change_difference([&[1.0, 0.0], &[1.0, 2.0]], [&[1.0, 2.0], &[1.0, 2.0]])
            .is_none()
    );
}

#[test]
fn paired_t_matches_a_hand_computation() {
    // Differences 1, 2, 3, 4: mean 2.5, SD 1.2910, t = 3.873 with 3 df, p = 0.0305.
    let t = paired_t(&[2.0, 4.0, 6.0, 8.0], &[1.0, 2.0, 3.0, 4.0]).unwrap();
    assert!((t.t - 3.872983).abs() < 1e-5, "{t:?}");
    assert!((t.p.unwrap() - 0.030466).abs() < 1e-4, "{t:?}");
    assert_eq!(t.df, 3.0);
}

#[test]
fn differences_and_equivalence_match_hand_computations() {
    // Paired: differences 1, 2, 3: mean 2, SD 1, SE 1/sqrt(3), df 2, t_0.975 = 4.3027.
    let d = difference(&[2.0, 4.0, 6.0], &[1.0, 2.0, 3.0], true).unwrap();
    assert!((d.mean - 2.0).abs() < 1e-12 && (d.cohen_d - 2.0).abs() < 1e-12);
    let half = 4.302_652_7 / 3f64.sqrt();
    assert!((d.ci95[0] - (2.0 - half)).abs() < 1e-5, "{d:?}");
    // t_0.8 with 2 df = 1.060660.
    assert!((d.detectable - (4.302_652_7 + 1.060_660_2) / 3f64.sqrt()).abs() < 1e-5);
    // Independent: means 2 and 5, both SD 1: pooled SD 1, SE sqrt(2/3), df 4.
    let i = difference(&[1.0, 2.0, 3.0], &[4.0, 5.0, 6.0], false).unwrap();
    assert!((i.mean + 3.0).abs() < 1e-12 && (i.cohen_d + 3.0).abs() < 1e-12);
    assert!((i.ci95[1] - (-3.0 + 2.776_445 * (2.0f64 / 3.0).sqrt())).abs() < 1e-5);
    // TOST: mean difference 2, SE 1/sqrt(3), t_0.95(2) = 2.919986.
    let e = equivalence(&[2.0, 4.0, 6.0], &[1.0, 2.0, 3.0], 5.0, true).unwrap();
    assert!((e.ci90[1] - (2.0 + 2.919_986 / 3f64.sqrt())).abs() < 1e-5);
    assert!(e.equivalent, "CI90 [1.3, 3.7] inside ±5: {e:?}");
    assert!(
        !equivalence(&[2.0, 4.0, 6.0], &[1.0, 2.0, 3.0], 2.5, true)
            .unwrap()
            .equivalent
    );
    assert!(equivalence(&[1.0], &[1.0], 1.0, true).is_none());
    // Independent groups: mean difference −3, pooled SD 1, SE sqrt(2/3), df 4,
    // t_0.95(4) = 2.131847: 90% CI [−4.741, −1.259].
    let e = equivalence(&[1.0, 2.0, 3.0], &[4.0, 5.0, 6.0], 5.0, false).unwrap();
    assert!(
        (e.ci90[0] - (-3.0 - 2.131_847 * (2.0f64 / 3.0).sqrt())).abs() < 1e-5,
        "{e:?}"
    );
    assert!(e.equivalent && !e.paired && e.n == [3, 3], "{e:?}");
    assert!(
        !equivalence(&[1.0, 2.0, 3.0], &[4.0, 5.0, 6.0], 4.0, false)
            .unwrap()
            .equivalent
    );
    // Independent groups need not be of one size, nor the same networks.
    assert!(equivalence(&[1.0, 2.0], &[4.0, 5.0, 6.0], 5.0, false).is_some());
}

#[test]
fn holm_adjusts_step_down() {
    let adjusted = holm(&[0.01, 0.04, 0.03]);
    for (a, e) in adjusted.iter().zip([0.03, 0.06, 0.06]) {
        assert!((a - e).abs() < 1e-12, "{adjusted:?}");
    }
    assert_eq!(holm(&[0.5, 0.9]), vec![1.0, 1.0]);
}

#[test]
fn ties_get_average_ranks() {
    assert_eq!(ranks(&[3.0, 1.0, 3.0, 2.0]), vec![3.5, 1.0, 3.5, 2.0]);
}

#[test]
fn f_p_value_matches_tables() {
    // F(2, 10) = 4.10 is the 5% critical value.
    assert!((f_p_value(4.1028, 2.0, 10.0).unwrap() - 0.05).abs() < 1e-3);
}

/// A design with a strong effect of A and a block effect only: ART finds A, not B or
/// A:B, and the contrasts order the levels.
#[test]
fn art_two_way_finds_the_effect_that_is_there() {
    use rand::{RngExt, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    let mut y = Vec::new();
    for k in 0..6 {
        let block = k as f64 * 0.37;
        let mut rows = Vec::new();
        for i in 0..3 {
            let mut row = Vec::new();
            for j in 0..2 {
                // A: 0, 5, 10; seeded uniform noise; B and A:B: none.
                let _ = j;
                let noise: f64 = rng.random_range(-0.5..0.5);
                row.push(i as f64 * 5.0 + block + noise);
            }
            rows.push(row);
        }
        y.push(rows);
    }
    let design = Blocked2 {
        y,
        a_levels: vec!["a0".into(), "a1".into(), "a2".into()],
        b_levels: vec!["b0".into(), "b1".into()],
    };
    let art = art_two_way(&design).unwrap();
    assert_eq!(art.effects.len(), 3);
    assert!(art.effects[0].p.unwrap() < 1e-6, "{:?}", art.effects[0]);
    assert!(art.effects[1].p.unwrap() > 0.05, "{:?}", art.effects[1]);
    assert!(art.effects[2].p.unwrap() > 0.05, "{:?}", art.effects[2]);
    assert_eq!(art.effects[0].df1, 2.0);
    assert_eq!(art.effects[0].df2, 25.0);
    assert_eq!(art.a_contrasts.len(), 3);
    assert!(
        art.a_contrasts
            .iter()
            .all(|c| c.rank_difference < 0.0 && c.p_holm.unwrap() < 0.01)
    );
    assert_eq!(art.cell_contrasts.len(), 15);
    // Raw differences: paired over the 6 networks, each network's mean of the level
    // (over B) for A's contrasts, its cell value for the cells'.
    let level_mean = |k: usize, i: usize| design.y[k][i].iter().sum::<f64>() / 2.0;
    let by_network: Vec<f64> = (0..6)
        .map(|k| level_mean(k, 0) - level_mean(k, 1))
        .collect();
    let a01 = art.a_contrasts[0].difference.as_ref().unwrap();
    assert!(a01.paired && a01.n == [6, 6], "{a01:?}");
    assert!(
        (a01.mean - by_network.iter().sum::<f64>() / 6.0).abs() < 1e-12,
        "{a01:?}"
    );
    let expected = difference(&by_network, &[0.0; 6], true).unwrap();
    assert!(
        (a01.ci95[0] - expected.ci95[0]).abs() < 1e-12,
        "{a01:?} {expected:?}"
    );
    let cell = art.cell_contrasts[0].difference.as_ref().unwrap();
    let cells: Vec<f64> = (0..6)
        .map(|k| design.y[k][0][0] - design.y[k][0][1])
        .collect();
    assert!(
        (cell.mean - cells.iter().sum::<f64>() / 6.0).abs() < 1e-12,
        "{cell:?}"
    );
}

#[test]
fn one_way_art_is_the_anova_of_ranks() {
    let labels: Vec<String> = ["x", "y", "z"].map(String::from).to_vec();
    let groups = vec![
        vec![1.0, 2.0, 3.0],
        vec![4.0, 5.0, 6.0],
        vec![7.0, 8.0, 9.0],
    ];
    let art = art_one_way(&labels, &groups).unwrap();
    // Ranks = values: SS_between = 3 * (9 + 0 + 9) = 54, SS_within = 6, F = 27 / 1 = 27.
    assert!((art.effect.f - 27.0).abs() < 1e-9, "{:?}", art.effect);
    assert_eq!((art.effect.df1, art.effect.df2), (2.0, 6.0));
    assert!((art.effect.partial_eta_squared - 0.9).abs() < 1e-12);
    assert_eq!(art.contrasts.len(), 3);
    // x vs z: difference -6, SE sqrt(1 * 2/3).
    let xz = &art.contrasts[1];
    assert!((xz.t + 6.0 / (2.0f64 / 3.0).sqrt()).abs() < 1e-9, "{xz:?}");
    assert!(art_one_way(&labels[..1], &groups[..1]).is_none());
}
