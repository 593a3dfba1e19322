//! The statistics of the paper's figures: paired t-tests, Holm's correction, the aligned
//! rank transform (ART) ANOVA for a two-factor design blocked by network (and, to check it
//! against ARTool's reference values, split-plot and between-subjects layouts) and for one
//! between-networks factor, and ART-C contrasts. (The boundary permutation test lives in
//! `report/hierarchy.rs`.)
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

mod art;

pub use art::{
    ArtOneWay, ArtTwoWay, Blocked2, Contrast, Effect, Layout, anova, art_anova, art_one_way,
    art_two_way,
};

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

/// The mean's 95% t interval (`None` for fewer than two values).
pub fn mean_ci95(values: &[f64]) -> Option<[f64; 2]> {
    let (mean, se) = mean_se(values);
    let t975 = t_quantile(1.0 - ALPHA / 2.0, values.len() as f64 - 1.0)?;
    let se = se?;
    Some([mean - t975 * se, mean + t975 * se])
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

#[cfg(test)]
mod tests;
