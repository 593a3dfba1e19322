//! The statistics of the paper's figures: paired t-tests, Holm's correction, the aligned
//! rank transform (ART) ANOVA for a two-factor design blocked by network (and, to check it
//! against ARTool's reference values, split-plot and between-subjects layouts) and for one
//! between-networks factor, and ART-C contrasts. (The boundary permutation test lives in
//! `report.rs`.)
//!
//! ART (Wobbrock et al. 2011): for each effect, the responses are aligned (residuals of the
//! full factorial cell means plus that effect's estimate), ranked, and analysed by the
//! ordinary ANOVA of the design, of which only that effect's F test is read. ART-C (Elkin
//! et al. 2021): pairwise contrasts on the responses aligned and ranked for the factor the
//! contrast compares (for cells: for the combined factor, i.e. the ranks of the raw data).
//! Networks are the blocks (random intercepts): with one value per network and cell the
//! mixed model's F tests are those of the randomised complete block ANOVA used here.

use serde::Serialize;
use statrs::distribution::{ContinuousCDF, FisherSnedecor, StudentsT};

/// Mean and standard error (None for fewer than two values).
pub fn mean_se(values: &[f64]) -> (f64, Option<f64>) {
    pvrnn_eval::report::mean_se(values)
}

/// A difference over its standard error; with no spread, 0 for no difference and an
/// infinite t for any other.
fn t_statistic(difference: f64, se: f64) -> f64 {
    if se > 0.0 {
        difference / se
    } else if difference == 0.0 {
        0.0
    } else {
        f64::INFINITY.copysign(difference)
    }
}

/// Two-sided p-value of a t statistic.
pub fn t_p_value(t: f64, df: f64) -> Option<f64> {
    if df.is_nan() || df <= 0.0 || t.is_nan() {
        return None;
    }
    if t.is_infinite() {
        return Some(0.0);
    }
    let dist = StudentsT::new(0.0, 1.0, df).ok()?;
    Some((2.0 * dist.sf(t.abs())).min(1.0))
}

/// Upper-tail p-value of an F statistic.
pub fn f_p_value(f: f64, df1: f64, df2: f64) -> Option<f64> {
    if df1.is_nan() || df2.is_nan() || df1 <= 0.0 || df2 <= 0.0 || f.is_nan() {
        return None;
    }
    if f.is_infinite() {
        return Some(0.0);
    }
    let dist = FisherSnedecor::new(df1, df2).ok()?;
    Some(dist.sf(f.max(0.0)))
}

/// A paired t-test of `a` against `b` (same networks, same order).
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct PairedT {
    pub n: usize,
    pub mean_difference: f64,
    pub t: f64,
    pub df: f64,
    pub p: Option<f64>,
    /// Cohen's d_z: mean difference / SD of the differences.
    pub cohen_dz: f64,
}

pub fn paired_t(a: &[f64], b: &[f64]) -> Option<PairedT> {
    if a.len() != b.len() || a.len() < 2 {
        return None;
    }
    let d: Vec<f64> = a.iter().zip(b).map(|(x, y)| x - y).collect();
    let n = d.len() as f64;
    let mean = d.iter().sum::<f64>() / n;
    let sd = (d.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    let t = t_statistic(mean, sd / n.sqrt());
    Some(PairedT {
        n: d.len(),
        mean_difference: mean,
        t,
        df: n - 1.0,
        p: t_p_value(t, n - 1.0),
        cohen_dz: if sd > 0.0 { mean / sd } else { 0.0 },
    })
}

/// Two-sided significance level of every test, and the power the detectable effect is
/// computed for.
pub const ALPHA: f64 = 0.05;
pub const POWER: f64 = 0.8;

/// A difference of means (a − b), with its 95% confidence interval, Cohen's d, and the
/// smallest difference this design detects with 80% power in a two-sided test at 0.05,
/// computed from the observed variance: (t_{0.975} + t_{0.8}) x SE, df as the t-test's.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Difference {
    pub paired: bool,
    pub n: [usize; 2],
    pub mean: f64,
    pub ci95: [f64; 2],
    /// d_z (paired: mean / SD of the differences) or d (independent: pooled SD).
    pub cohen_d: f64,
    pub detectable: f64,
    pub p: Option<f64>,
}

fn t_quantile(q: f64, df: f64) -> Option<f64> {
    Some(StudentsT::new(0.0, 1.0, df).ok()?.inverse_cdf(q))
}

/// The mean difference `a` − `b` with the SD it is scaled by (of the differences when
/// paired, pooled when independent), its standard error and degrees of freedom.
fn spread(a: &[f64], b: &[f64], paired: bool) -> Option<(f64, f64, f64, f64)> {
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let var = |v: &[f64]| {
        let m = mean(v);
        v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() as f64 - 1.0)
    };
    if paired {
        if a.len() != b.len() || a.len() < 2 {
            return None;
        }
        let d: Vec<f64> = a.iter().zip(b).map(|(x, y)| x - y).collect();
        let n = d.len() as f64;
        let sd = var(&d).sqrt();
        Some((mean(&d), sd, sd / n.sqrt(), n - 1.0))
    } else {
        if a.len() < 2 || b.len() < 2 {
            return None;
        }
        let (na, nb) = (a.len() as f64, b.len() as f64);
        let pooled = (((na - 1.0) * var(a) + (nb - 1.0) * var(b)) / (na + nb - 2.0)).sqrt();
        Some((
            mean(a) - mean(b),
            pooled,
            pooled * (1.0 / na + 1.0 / nb).sqrt(),
            na + nb - 2.0,
        ))
    }
}

/// `a` − `b`: paired (same networks, same order) or independent groups.
pub fn difference(a: &[f64], b: &[f64], paired: bool) -> Option<Difference> {
    let (diff, sd, se, df) = spread(a, b, paired)?;
    let t975 = t_quantile(1.0 - ALPHA / 2.0, df)?;
    let t80 = t_quantile(POWER, df)?;
    let t = t_statistic(diff, se);
    Some(Difference {
        paired,
        n: [a.len(), b.len()],
        mean: diff,
        ci95: [diff - t975 * se, diff + t975 * se],
        cohen_d: if sd > 0.0 { diff / sd } else { 0.0 },
        detectable: (t975 + t80) * se,
        p: t_p_value(t, df),
    })
}

/// Two one-sided tests (TOST) of the difference a − b (paired, or independent groups)
/// against the equivalence margin ±`margin`: equivalent when both one-sided tests reject
/// at 0.05, i.e. the 90% confidence interval lies inside the margin.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Equivalence {
    pub paired: bool,
    pub n: [usize; 2],
    pub margin: f64,
    pub mean: f64,
    pub ci90: [f64; 2],
    /// The larger of the two one-sided p-values.
    pub p: Option<f64>,
    pub equivalent: bool,
}

pub fn equivalence(a: &[f64], b: &[f64], margin: f64, paired: bool) -> Option<Equivalence> {
    if margin.is_nan() || margin <= 0.0 {
        return None;
    }
    let (mean, _, se, df) = spread(a, b, paired)?;
    let dist = StudentsT::new(0.0, 1.0, df).ok()?;
    let t95 = dist.inverse_cdf(1.0 - ALPHA);
    let (p_lower, p_upper) = if se > 0.0 {
        (
            dist.sf((mean + margin) / se),
            dist.cdf((mean - margin) / se),
        )
    } else {
        let inside = mean.abs() < margin;
        (
            if inside { 0.0 } else { 1.0 },
            if inside { 0.0 } else { 1.0 },
        )
    };
    let p = p_lower.max(p_upper);
    Some(Equivalence {
        paired,
        n: [a.len(), b.len()],
        margin,
        mean,
        ci90: [mean - t95 * se, mean + t95 * se],
        p: Some(p),
        equivalent: p < ALPHA,
    })
}

/// Whether a change is larger in one design than in another (an interaction of two
/// independent 2-group comparisons): the change of each is the log ratio of its groups'
/// geometric means (`after` over `before`, so changes of tasks whose errors differ in size
/// compare as relative ones), and the test is Welch's t of the difference of the two log
/// ratios over the four groups' variances (two-sided, Welch-Satterthwaite df).
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct RelativeChangeDifference {
    /// Each design's log ratio, first and second.
    pub log_ratio: [f64; 2],
    /// Each design's change as a fraction (exp(log ratio) − 1).
    pub change: [f64; 2],
    /// Second − first log ratio, with its 95% CI.
    pub difference: f64,
    pub ci95: [f64; 2],
    pub t: f64,
    pub df: f64,
    pub p: Option<f64>,
    /// The smallest difference of log ratios this design detects (80% power, two-sided,
    /// 0.05): (t₀.₉₇₅ + t₀.₈) x SE.
    pub detectable: f64,
}

/// [`RelativeChangeDifference`] of the change from `first[0]` to `first[1]` and that from
/// `second[0]` to `second[1]` (each group one value per network, all positive).
pub fn relative_change_difference(
    first: [&[f64]; 2],
    second: [&[f64]; 2],
) -> Option<RelativeChangeDifference> {
    let groups = [first[0], first[1], second[0], second[1]];
    if groups
        .iter()
        .any(|g| g.len() < 2 || g.iter().any(|&x| x.is_nan() || x <= 0.0))
    {
        return None;
    }
    // Mean of the logs and the variance of that mean, per group.
    let moments: Vec<(f64, f64, f64)> = groups
        .iter()
        .map(|g| {
            let logs: Vec<f64> = g.iter().map(|x| x.ln()).collect();
            let (mean, se) = mean_se(&logs);
            (mean, se.unwrap_or(0.0).powi(2), g.len() as f64)
        })
        .collect();
    let log_ratio = [moments[1].0 - moments[0].0, moments[3].0 - moments[2].0];
    let difference = log_ratio[1] - log_ratio[0];
    let variance: f64 = moments.iter().map(|m| m.1).sum();
    let se = variance.sqrt();
    let df = variance.powi(2)
        / moments
            .iter()
            .map(|(_, v, n)| v.powi(2) / (n - 1.0))
            .sum::<f64>();
    let df = if df.is_finite() {
        df
    } else {
        moments.iter().map(|m| m.2 - 1.0).sum()
    };
    let t975 = t_quantile(1.0 - ALPHA / 2.0, df)?;
    let t80 = t_quantile(POWER, df)?;
    let t = t_statistic(difference, se);
    Some(RelativeChangeDifference {
        log_ratio,
        change: log_ratio.map(|l| l.exp() - 1.0),
        difference,
        ci95: [difference - t975 * se, difference + t975 * se],
        t,
        df,
        p: t_p_value(t, df),
        detectable: (t975 + t80) * se,
    })
}

/// Holm's step-down adjustment of a family of p-values (same order as given).
pub fn holm(p: &[f64]) -> Vec<f64> {
    let m = p.len();
    let mut order: Vec<usize> = (0..m).collect();
    order.sort_by(|&i, &j| p[i].total_cmp(&p[j]));
    let mut adjusted = vec![0.0; m];
    let mut running = 0.0f64;
    for (rank, &i) in order.iter().enumerate() {
        running = running.max(((m - rank) as f64 * p[i]).min(1.0));
        adjusted[i] = running;
    }
    adjusted
}

/// Ranks 1..n with ties given their average rank. Values within 1e-10 of the largest
/// magnitude of each other are ties: aligned responses that are equal in exact arithmetic
/// differ by rounding, and splitting those ties changes the F values (ARTool's reference
/// values for Higgins et al.'s data need them tied).
pub fn ranks(values: &[f64]) -> Vec<f64> {
    let mut order: Vec<usize> = (0..values.len()).collect();
    order.sort_by(|&i, &j| values[i].total_cmp(&values[j]));
    let scale = values.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let tolerance = 1e-10 * scale;
    let mut out = vec![0.0; values.len()];
    let mut start = 0;
    while start < order.len() {
        let mut end = start + 1;
        while end < order.len() && values[order[end]] - values[order[end - 1]] <= tolerance {
            end += 1;
        }
        let average = (start + end + 1) as f64 / 2.0;
        for &i in &order[start..end] {
            out[i] = average;
        }
        start = end;
    }
    out
}

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

fn effect(name: &str, ss: f64, df: f64, ss_error: f64, df_error: f64) -> Effect {
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

fn cohen_d(a: &[f64], b: &[f64]) -> f64 {
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
struct Raw<'a> {
    values: &'a [Vec<f64>],
    units: &'a [Vec<f64>],
    paired: bool,
}

/// Pairwise contrasts of `means` (mean ranks) with `count` values each, error `ms`, `df`,
/// Holm-adjusted together.
fn pairwise(
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

#[cfg(test)]
mod tests {
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
}
