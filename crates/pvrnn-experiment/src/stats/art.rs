//! ANOVA of a blocked two-factor design (and the split-plot and between-subjects layouts
//! checked against ARTool), the aligned rank transform for each effect, one-way ART
//! between networks, and ART-C contrasts.

use super::{Difference, difference, f_p_value, holm, mean_se, ranks, t_p_value, t_statistic};
use serde::Serialize;

/// One effect's F test.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Effect {
    pub effect: String,
    pub f: f64,
    pub df1: f64,
    pub df2: f64,
    pub p: Option<f64>,
    /// SS_effect / (SS_effect + SS_error) of the ranked, aligned data.
    pub partial_eta_squared: f64,
}

/// A pairwise contrast (ART-C).
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Contrast {
    pub a: String,
    pub b: String,
    /// Mean rank of `a` minus mean rank of `b` (aligned ranks).
    pub rank_difference: f64,
    pub t: f64,
    pub df: f64,
    pub p: Option<f64>,
    /// Holm-adjusted within the family of contrasts reported together.
    pub p_holm: Option<f64>,
    /// Cohen's d of the raw values (a - b over their pooled SD).
    pub cohen_d: f64,
    /// The raw difference a − b with its 95% CI: over networks, paired in a design blocked
    /// by network (each network's mean of the level), independent between groups.
    pub difference: Option<Difference>,
}

/// Values of a blocked two-factor design: `y[block][i][j]`, one value per block and cell.
#[derive(Clone, Debug)]
pub struct Blocked2 {
    pub y: Vec<Vec<Vec<f64>>>,
    pub a_levels: Vec<String>,
    pub b_levels: Vec<String>,
}

/// The two-way ART ANOVA with its contrasts.
#[derive(Clone, Debug, Serialize)]
pub struct ArtTwoWay {
    pub blocks: usize,
    pub effects: Vec<Effect>,
    /// Pairwise contrasts of the first factor's levels, Holm-adjusted together.
    pub a_contrasts: Vec<Contrast>,
    /// Pairwise contrasts of the second factor's levels.
    pub b_contrasts: Vec<Contrast>,
    /// Pairwise contrasts of all cells, Holm-adjusted together.
    pub cell_contrasts: Vec<Contrast>,
}

/// How the units `y[k][i][j]` of a balanced two-factor design (factors A with levels i, B
/// with levels j) relate to its cells; it decides each effect's error term.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Layout {
    /// Block k (a network) sees every cell once: the randomised complete block design, whose
    /// F tests are those of the random-intercept model. Every effect is tested against the
    /// residual after blocks. The experiments' design.
    Blocked,
    /// Block (i, k) belongs to level i of A and sees every level of B once (a split plot,
    /// e.g. trays within moisture levels): A is tested against blocks within A, B and A:B
    /// against the within-block residual.
    SplitPlot,
    /// k counts independent replicates of each cell (completely randomised): every effect
    /// is tested against the within-cell error.
    Between,
}

struct Anova2 {
    ss: [f64; 3],
    df: [f64; 3],
    /// Each effect's error: sum of squares and degrees of freedom.
    error: [(f64, f64); 3],
    a_means: Vec<f64>,
    b_means: Vec<f64>,
    cell_means: Vec<Vec<f64>>,
}

impl Anova2 {
    fn effect(&self, e: usize, name: &str) -> Effect {
        let (ss_error, df_error) = self.error[e];
        effect(name, self.ss[e], self.df[e], ss_error, df_error)
    }

    /// Mean square and degrees of freedom of effect `e`'s error.
    fn error_ms(&self, e: usize) -> (f64, f64) {
        let (ss, df) = self.error[e];
        (ss / df, df)
    }
}

fn anova2(y: &[Vec<Vec<f64>>], layout: Layout) -> Anova2 {
    let (n, a, b) = (y.len(), y[0].len(), y[0][0].len());
    let all: Vec<f64> = y.iter().flatten().flatten().copied().collect();
    let grand = all.iter().sum::<f64>() / all.len() as f64;
    let block_means: Vec<f64> = y
        .iter()
        .map(|blk| blk.iter().flatten().sum::<f64>() / (a * b) as f64)
        .collect();
    let cell_means: Vec<Vec<f64>> = (0..a)
        .map(|i| {
            (0..b)
                .map(|j| y.iter().map(|blk| blk[i][j]).sum::<f64>() / n as f64)
                .collect()
        })
        .collect();
    let a_means: Vec<f64> = cell_means
        .iter()
        .map(|r| r.iter().sum::<f64>() / b as f64)
        .collect();
    let b_means: Vec<f64> = (0..b)
        .map(|j| cell_means.iter().map(|r| r[j]).sum::<f64>() / a as f64)
        .collect();
    let ss_total: f64 = all.iter().map(|v| (v - grand).powi(2)).sum();
    let ss_block = (a * b) as f64 * block_means.iter().map(|m| (m - grand).powi(2)).sum::<f64>();
    let ss_a = (n * b) as f64 * a_means.iter().map(|m| (m - grand).powi(2)).sum::<f64>();
    let ss_b = (n * a) as f64 * b_means.iter().map(|m| (m - grand).powi(2)).sum::<f64>();
    let mut ss_ab = 0.0;
    for i in 0..a {
        for j in 0..b {
            ss_ab += (cell_means[i][j] - a_means[i] - b_means[j] + grand).powi(2);
        }
    }
    ss_ab *= n as f64;
    let (nf, af, bf) = (n as f64, a as f64, b as f64);
    let error = match layout {
        Layout::Blocked => {
            let e = (
                (ss_total - ss_block - ss_a - ss_b - ss_ab).max(0.0),
                (nf - 1.0) * (af * bf - 1.0),
            );
            [e; 3]
        }
        Layout::SplitPlot => {
            // Blocks within A: each block's mean about its level of A.
            let ss_blocks_in_a = bf
                * (0..a)
                    .flat_map(|i| (0..n).map(move |k| (i, k)))
                    .map(|(i, k)| (y[k][i].iter().sum::<f64>() / bf - a_means[i]).powi(2))
                    .sum::<f64>();
            let whole = (ss_blocks_in_a, af * (nf - 1.0));
            let within = (
                (ss_total - ss_a - ss_blocks_in_a - ss_b - ss_ab).max(0.0),
                af * (nf - 1.0) * (bf - 1.0),
            );
            [whole, within, within]
        }
        Layout::Between => {
            let e = (
                (ss_total - ss_a - ss_b - ss_ab).max(0.0),
                af * bf * (nf - 1.0),
            );
            [e; 3]
        }
    };
    Anova2 {
        ss: [ss_a, ss_b, ss_ab],
        df: [af - 1.0, bf - 1.0, (af - 1.0) * (bf - 1.0)],
        error,
        a_means,
        b_means,
        cell_means,
    }
}

pub(super) fn effect(name: &str, ss: f64, df: f64, ss_error: f64, df_error: f64) -> Effect {
    let ms_error = ss_error / df_error;
    let f = if ms_error > 0.0 {
        (ss / df) / ms_error
    } else if ss > 0.0 {
        f64::INFINITY
    } else {
        0.0
    };
    Effect {
        effect: name.to_string(),
        f,
        df1: df,
        df2: df_error,
        p: f_p_value(f, df, df_error),
        partial_eta_squared: if ss + ss_error > 0.0 {
            ss / (ss + ss_error)
        } else {
            0.0
        },
    }
}

pub(super) fn cohen_d(a: &[f64], b: &[f64]) -> f64 {
    let var = |v: &[f64]| {
        let (m, _) = mean_se(v);
        v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len().max(2) - 1) as f64
    };
    let pooled = (((a.len() - 1) as f64 * var(a) + (b.len() - 1) as f64 * var(b))
        / ((a.len() + b.len()).max(3) - 2) as f64)
        .sqrt();
    let diff = mean_se(a).0 - mean_se(b).0;
    if pooled > 0.0 { diff / pooled } else { 0.0 }
}

/// The raw values of the levels compared: `values[i]` for Cohen's d; `units[i]`, one per
/// network (in block order when `paired`), for the difference and its interval.
pub(super) struct Raw<'a> {
    values: &'a [Vec<f64>],
    units: &'a [Vec<f64>],
    paired: bool,
}

/// Pairwise contrasts of `means` (mean ranks) with `count` values each, error `ms`, `df`,
/// Holm-adjusted together.
pub(super) fn pairwise(
    labels: &[String],
    means: &[f64],
    count: &[usize],
    ms: f64,
    df: f64,
    raw: &Raw<'_>,
) -> Vec<Contrast> {
    let mut out = Vec::new();
    for i in 0..means.len() {
        for j in i + 1..means.len() {
            let diff = means[i] - means[j];
            let se = (ms * (1.0 / count[i] as f64 + 1.0 / count[j] as f64)).sqrt();
            let t = t_statistic(diff, se);
            out.push(Contrast {
                a: labels[i].clone(),
                b: labels[j].clone(),
                rank_difference: diff,
                t,
                df,
                p: t_p_value(t, df),
                p_holm: None,
                cohen_d: cohen_d(&raw.values[i], &raw.values[j]),
                difference: difference(&raw.units[i], &raw.units[j], raw.paired),
            });
        }
    }
    let ps: Vec<f64> = out.iter().map(|c| c.p.unwrap_or(1.0)).collect();
    for (c, adjusted) in out.iter_mut().zip(holm(&ps)) {
        c.p_holm = c.p.map(|_| adjusted);
    }
    out
}

fn reshape(values: &[f64], n: usize, a: usize, b: usize) -> Vec<Vec<Vec<f64>>> {
    (0..n)
        .map(|k| {
            (0..a)
                .map(|i| (0..b).map(|j| values[(k * a + i) * b + j]).collect())
                .collect()
        })
        .collect()
}

/// The ART F tests of a balanced two-factor design `y[k][i][j]` under `layout`: for each
/// effect (A, B, A:B) the responses are aligned with the full-factorial cell means, ranked
/// (average ties) and analysed by the layout's ANOVA, of which only that effect's F test is
/// read. Also returns each effect's ANOVA of its aligned ranks (for contrasts). None for a
/// design too small to test (fewer than 2 units per cell or 2 levels of A) or ragged.
fn art_aligned(y: &[Vec<Vec<f64>>], layout: Layout) -> Option<(Vec<Effect>, Vec<Anova2>)> {
    let n = y.len();
    let a = y.first()?.len();
    let b = y.first()?.first()?.len();
    if n < 2
        || a < 2
        || b < 1
        || y.iter()
            .any(|blk| blk.len() != a || blk.iter().any(|r| r.len() != b))
    {
        return None;
    }
    let raw = anova2(y, layout);
    let grand = raw.a_means.iter().sum::<f64>() / a as f64;
    let flat = |f: &dyn Fn(usize, usize, usize) -> f64| -> Vec<f64> {
        let mut v = Vec::with_capacity(n * a * b);
        for k in 0..n {
            for i in 0..a {
                for j in 0..b {
                    v.push(f(k, i, j));
                }
            }
        }
        v
    };
    let residual = |k: usize, i: usize, j: usize| y[k][i][j] - raw.cell_means[i][j];
    let aligned: [Vec<f64>; 3] = [
        flat(&|k, i, j| residual(k, i, j) + raw.a_means[i] - grand),
        flat(&|k, i, j| residual(k, i, j) + raw.b_means[j] - grand),
        flat(&|k, i, j| {
            residual(k, i, j) + raw.cell_means[i][j] - raw.a_means[i] - raw.b_means[j] + grand
        }),
    ];
    let names = ["A", "B", "A:B"];
    let mut effects = Vec::new();
    let mut ranked = Vec::new();
    for (e, values) in aligned.iter().enumerate() {
        let an = anova2(&reshape(&ranks(values), n, a, b), layout);
        if b > 1 || e == 0 {
            effects.push(an.effect(e, names[e]));
        }
        ranked.push(an);
    }
    Some((effects, ranked))
}

/// The ordinary (parametric) two-factor ANOVA of `y[k][i][j]` under `layout`: the F tests
/// of A, B and A:B, the engine the ART runs on its aligned ranks.
pub fn anova(y: &[Vec<Vec<f64>>], layout: Layout) -> Vec<Effect> {
    let an = anova2(y, layout);
    ["A", "B", "A:B"]
        .iter()
        .enumerate()
        .map(|(e, name)| an.effect(e, name))
        .collect()
}

/// The two-factor ART ANOVA under any [`Layout`]: the F tests of A, B and A:B (B and A:B
/// only when B has two levels or more), named "A", "B", "A:B".
pub fn art_anova(y: &[Vec<Vec<f64>>], layout: Layout) -> Option<Vec<Effect>> {
    art_aligned(y, layout).map(|(effects, _)| effects)
}

/// The two-way ART ANOVA (factors A and B, blocks = networks) and its ART-C contrasts.
pub fn art_two_way(design: &Blocked2) -> Option<ArtTwoWay> {
    let y = &design.y;
    let n = y.len();
    let a = design.a_levels.len();
    let b = design.b_levels.len();
    if y.first()
        .is_none_or(|blk| blk.len() != a || blk.iter().any(|r| r.len() != b))
    {
        return None;
    }
    let (effects, ranked) = art_aligned(y, Layout::Blocked)?;
    let raw_a: Vec<Vec<f64>> = (0..a)
        .map(|i| y.iter().flat_map(|blk| blk[i].iter().copied()).collect())
        .collect();
    let raw_b: Vec<Vec<f64>> = (0..b)
        .map(|j| {
            y.iter()
                .flat_map(|blk| blk.iter().map(move |r| r[j]))
                .collect()
        })
        .collect();
    // Each network's mean of a level, for the paired differences.
    let block_means = |level: &dyn Fn(&[Vec<f64>]) -> Vec<f64>| -> Vec<Vec<f64>> {
        let per_block: Vec<Vec<f64>> = y.iter().map(|blk| level(blk)).collect();
        let levels = per_block.first().map_or(0, Vec::len);
        (0..levels)
            .map(|l| per_block.iter().map(|m| m[l]).collect())
            .collect()
    };
    let units_a = block_means(&|blk| blk.iter().map(|r| mean_se(r).0).collect());
    let units_b = block_means(&|blk| {
        (0..b)
            .map(|j| blk.iter().map(|r| r[j]).sum::<f64>() / a as f64)
            .collect()
    });
    let (ms_a, df_a) = ranked[0].error_ms(0);
    let a_contrasts = pairwise(
        &design.a_levels,
        &ranked[0].a_means,
        &vec![n * b; a],
        ms_a,
        df_a,
        &Raw {
            values: &raw_a,
            units: &units_a,
            paired: true,
        },
    );
    let b_contrasts = if b > 1 {
        let (ms_b, df_b) = ranked[1].error_ms(1);
        pairwise(
            &design.b_levels,
            &ranked[1].b_means,
            &vec![n * a; b],
            ms_b,
            df_b,
            &Raw {
                values: &raw_b,
                units: &units_b,
                paired: true,
            },
        )
    } else {
        Vec::new()
    };
    // Cells: the combined factor's alignment is the raw data less a constant.
    let cells = a * b;
    let cell_ranks = reshape(&ranks(&y.concat().concat()), n, 1, cells);
    let cell_values: Vec<Vec<Vec<f64>>> = cell_ranks
        .iter()
        .map(|blk| blk[0].iter().map(|v| vec![*v]).collect())
        .collect();
    let cell_anova = anova2(&cell_values, Layout::Blocked);
    let cell_labels: Vec<String> = (0..a)
        .flat_map(|i| (0..b).map(move |j| (i, j)))
        .map(|(i, j)| format!("{} / {}", design.a_levels[i], design.b_levels[j]))
        .collect();
    let raw_cells: Vec<Vec<f64>> = (0..a)
        .flat_map(|i| (0..b).map(move |j| (i, j)))
        .map(|(i, j)| y.iter().map(|blk| blk[i][j]).collect())
        .collect();
    let cell_contrasts = if b > 1 {
        let (ms_cells, df_cells) = cell_anova.error_ms(0);
        pairwise(
            &cell_labels,
            &cell_anova.a_means,
            &vec![n; cells],
            ms_cells,
            df_cells,
            &Raw {
                values: &raw_cells,
                units: &raw_cells,
                paired: true,
            },
        )
    } else {
        Vec::new()
    };
    Some(ArtTwoWay {
        blocks: n,
        effects,
        a_contrasts,
        b_contrasts,
        cell_contrasts,
    })
}

/// The one-way ART ANOVA between independent groups (e.g. networks trained under
/// different conditions): for one factor the alignment is the identity, so this is the
/// ANOVA of the ranks; pairwise ART-C contrasts Holm-adjusted together.
#[derive(Clone, Debug, Serialize)]
pub struct ArtOneWay {
    pub effect: Effect,
    pub contrasts: Vec<Contrast>,
}

pub fn art_one_way(labels: &[String], groups: &[Vec<f64>]) -> Option<ArtOneWay> {
    let k = groups.len();
    let total: usize = groups.iter().map(Vec::len).sum();
    if k < 2 || groups.iter().any(Vec::is_empty) || total <= k {
        return None;
    }
    let all: Vec<f64> = groups.iter().flatten().copied().collect();
    let r = ranks(&all);
    let mut start = 0;
    let mut rank_groups = Vec::new();
    for g in groups {
        rank_groups.push(r[start..start + g.len()].to_vec());
        start += g.len();
    }
    let grand = r.iter().sum::<f64>() / total as f64;
    let means: Vec<f64> = rank_groups.iter().map(|g| mean_se(g).0).collect();
    let ss_between: f64 = rank_groups
        .iter()
        .zip(&means)
        .map(|(g, m)| g.len() as f64 * (m - grand).powi(2))
        .sum();
    let ss_within: f64 = rank_groups
        .iter()
        .zip(&means)
        .map(|(g, m)| g.iter().map(|v| (v - m).powi(2)).sum::<f64>())
        .sum();
    let (df1, df2) = ((k - 1) as f64, (total - k) as f64);
    let mut effect = effect("condition", ss_between, df1, ss_within, df2);
    // One factor: partial eta squared is eta squared.
    effect.partial_eta_squared = if ss_between + ss_within > 0.0 {
        ss_between / (ss_between + ss_within)
    } else {
        0.0
    };
    let counts: Vec<usize> = groups.iter().map(Vec::len).collect();
    let raw = Raw {
        values: groups,
        units: groups,
        paired: false,
    };
    let contrasts = pairwise(labels, &means, &counts, ss_within / df2, df2, &raw);
    Some(ArtOneWay { effect, contrasts })
}
