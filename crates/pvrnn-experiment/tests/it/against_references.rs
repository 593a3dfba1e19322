//! The statistics against published reference values: textbook examples for the ANOVA and
//! the paired t-test (at the end), and the ART against ARTool's own: the F tests that
//! ARTool's test suite (`tests/testthat/test.anova.art.R` in mjskay/ARTool) expects for the
//! example data of
//! Higgins, Blair & Tashtoush (1990), which it ships as `Higgins1990Table1` and
//! `Higgins1990Table5`. ARTool prints F to 4 decimals; ours must agree to that.
//!
//! The data, as plain values (ARTool keeps them in binary .RData files):
//! - Table 1: the `Higgins1990-Table1.csv` distributed with the original ARTool (also in the
//!   CRAN package ART's tests): a 3 x 3 between-subjects design, 4 subjects per cell.
//! - Table 5: Milliken & Johnson's peat-pot dry matter (nlme's `Wheat`), truncated to one
//!   decimal, which is ARTool's copy (its README prints the first ten values: 3.3 4.3 4.5
//!   5.8 4.0 4.1 6.5 7.3 1.9 3.8). Moisture varies between trays (3 per level), fertilizer
//!   within trays: a split plot.
//!
//! Both data sets have aligned responses that are equal in exact arithmetic; the reference
//! values need them ranked as ties (`stats::ranks`).

use pvrnn_experiment::stats::{Effect, Layout, art_anova};

/// `y[k][i][j]` from values listed with k fastest, then j, then i (the tables' order: for
/// each level of A, each level of B, its units).
fn table(values: &[f64], a: usize, b: usize, n: usize) -> Vec<Vec<Vec<f64>>> {
    assert_eq!(values.len(), a * b * n);
    (0..n)
        .map(|k| {
            (0..a)
                .map(|i| (0..b).map(|j| values[(i * b + j) * n + k]).collect())
                .collect()
        })
        .collect()
}

fn check(effects: &[Effect], expected: &[(&str, f64, f64, f64)]) {
    assert_eq!(effects.len(), expected.len(), "{effects:?}");
    for (e, &(name, f, df1, df2)) in effects.iter().zip(expected) {
        assert_eq!(e.effect, name);
        assert!((e.f - f).abs() < 5e-5, "{name}: F = {:.6}, ARTool {f}", e.f);
        assert_eq!((e.df1, e.df2), (df1, df2), "{name}");
    }
}

/// Higgins et al.'s Table 1: Row (A) x Column (B), 4 subjects per cell, in the file's
/// order: row 1 column 1's four responses, row 1 column 2's, ...
#[rustfmt::skip]
const TABLE_1: [f64; 36] = [
    11.5, 10.1, 9.9, 10.6,   9.0, 7.4, 8.8, 8.8,    3.8, 6.3, 4.9, 5.3,
    9.9, 9.8, 9.3, 9.1,      9.3, 7.4, 7.7, 7.9,    4.1, 6.3, 5.5, 5.4,
    13.9, 16.0, 14.2, 15.2,  13.0, 13.4, 11.2, 12.8, 9.6, 9.6, 11.0, 13.4,
];

#[test]
fn higgins_1990_table_1_between_subjects() {
    let y = table(&TABLE_1, 3, 3, 4);
    let effects = art_anova(&y, Layout::Between).unwrap();
    // art(Response ~ Row * Column): Row F(2, 27) = 29.9925, Column 77.8668, Row:Column
    // F(4, 27) = 0.6417.
    check(
        &effects,
        &[
            ("A", 29.9925, 2.0, 27.0),
            ("B", 77.8668, 2.0, 27.0),
            ("A:B", 0.6417, 4.0, 27.0),
        ],
    );
    assert!((effects[2].p.unwrap() - 0.6374).abs() < 5e-5);
}

#[test]
fn higgins_1990_table_5_split_plot() {
    // Moisture m1..m4 (A) x fertilizer f1..f4 (B); trays t1..t12, three per moisture level.
    // Listed tray by tray (f1..f4 within each tray).
    #[rustfmt::skip]
    let by_tray = [
        3.3, 4.3, 4.5, 5.8,   4.0, 4.1, 6.5, 7.3,   1.9, 3.8, 4.4, 5.1,
        5.0, 7.9, 10.7, 13.5, 5.9, 8.5, 10.3, 13.9, 6.9, 7.0, 10.9, 15.2,
        6.5, 10.7, 12.2, 15.7, 8.2, 8.9, 13.4, 14.9, 5.2, 8.6, 11.1, 15.6,
        6.8, 9.0, 10.3, 12.5, 6.4, 6.0, 10.7, 12.5, 4.0, 3.8, 9.4, 10.2,
    ];
    // y[k][i][j]: tray k of moisture level i, fertilizer j.
    let y: Vec<Vec<Vec<f64>>> = (0..3)
        .map(|k| {
            (0..4)
                .map(|i| (0..4).map(|j| by_tray[(i * 3 + k) * 4 + j]).collect())
                .collect()
        })
        .collect();
    let effects = art_anova(&y, Layout::SplitPlot).unwrap();
    // art(DryMatter ~ Moisture * Fertilizer + Error(Tray)): Moisture F(3, 8) = 23.8326
    // (tested against trays), Fertilizer F(3, 24) = 122.4017, interaction F(9, 24) = 5.1180.
    check(
        &effects,
        &[
            ("A", 23.8326, 3.0, 8.0),
            ("B", 122.4017, 3.0, 24.0),
            ("A:B", 5.1180, 9.0, 24.0),
        ],
    );
}

#[test]
fn ties_split_by_rounding_would_move_the_f_values() {
    // The same Table 1 with one response nudged far beyond rounding: the ranks, and so the
    // F values, change (the comparison above is not insensitive to the data).
    let mut response = TABLE_1.to_vec();
    response[6] += 1e-6;
    let effects = art_anova(&table(&response, 3, 3, 4), Layout::Between).unwrap();
    assert!((effects[1].f - 77.8668).abs() > 1e-3, "{:?}", effects[1]);
}

/// The ANOVA engine itself against a textbook: Montgomery, *Design and Analysis of
/// Experiments*, Example 5.1 (battery life, 3 materials x 3 temperatures, 4 replicates):
/// material F(2, 27) = 7.91, temperature 28.97, interaction F(4, 27) = 3.56.
#[test]
fn two_way_anova_matches_montgomery_example_5_1() {
    use pvrnn_experiment::stats::anova;
    #[rustfmt::skip]
    let life = [
        130.0, 155.0, 74.0, 180.0,   34.0, 40.0, 80.0, 75.0,     20.0, 70.0, 82.0, 58.0,
        150.0, 188.0, 159.0, 126.0,  136.0, 122.0, 106.0, 115.0, 25.0, 70.0, 58.0, 45.0,
        138.0, 110.0, 168.0, 160.0,  174.0, 120.0, 150.0, 139.0, 96.0, 104.0, 82.0, 60.0,
    ];
    let effects = anova(&table(&life, 3, 3, 4), Layout::Between);
    for (e, (f, df1)) in effects.iter().zip([(7.91, 2.0), (28.97, 2.0), (3.56, 4.0)]) {
        assert!(
            (e.f - f).abs() < 5e-3,
            "{}: F = {:.4}, textbook {f}",
            e.effect,
            e.f
        );
        assert_eq!((e.df1, e.df2), (df1, 27.0));
    }
}

/// The paired t-test against Student's sleep data (Cushny & Peebles; R's `sleep`): extra
/// hours of sleep under two drugs for the same 10 patients, t(9) = -4.0621, p = 0.002833.
#[test]
fn paired_t_matches_students_sleep_data() {
    use pvrnn_experiment::stats::paired_t;
    let drug1 = [0.7, -1.6, -0.2, -1.2, -0.1, 3.4, 3.7, 0.8, 0.0, 2.0];
    let drug2 = [1.9, 0.8, 1.1, 0.1, -0.1, 4.4, 5.5, 1.6, 4.6, 3.4];
    let t = paired_t(&drug1, &drug2).unwrap();
    assert!((t.t + 4.0621).abs() < 5e-5, "{t:?}");
    assert_eq!(t.df, 9.0);
    assert!((t.p.unwrap() - 0.002833).abs() < 5e-7, "{t:?}");
}
