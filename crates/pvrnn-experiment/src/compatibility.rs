//! Whether a result in the paper's direction that is not significant here still excludes
//! the paper's effect (a disagreement) or is too imprecise to tell (the design too small):
//! the plan's rule for such results (docs/experiments.md, "Verdicts").
//!
//! The paper reports test statistics, not effects in our units, so the two are compared as
//! the noncentrality of the test: the paper's statistic estimates its noncentrality (δ = t,
//! λ = df1 F; where it reports only a p, the smallest |t| that p allows), which is scaled to
//! our number of networks per condition (δ grows with √n, λ with n) and set against the
//! 95% confidence interval of ours, found by inverting the noncentral t or F distribution
//! at our statistic (Steiger & Fouladi 1997). Rank statistics (ART, ART-C) are compared
//! with the paper's, which are rank statistics too.

use statrs::distribution::{ContinuousCDF, Normal, StudentsT};
use statrs::function::beta::beta_reg;
use statrs::function::gamma::ln_gamma;

/// Each side's tail of the 95% interval.
const TAIL: f64 = 0.025;

/// P(T ≤ t) for the noncentral t distribution with `df` degrees of freedom and
/// noncentrality `delta` (the Poisson-mixture series of Lenth 1989, AS 243).
pub fn noncentral_t_cdf(t: f64, df: f64, delta: f64) -> f64 {
    if t < 0.0 {
        return 1.0 - noncentral_t_cdf(-t, df, -delta);
    }
    let normal = Normal::standard();
    let y = t * t / (t * t + df);
    let half = delta * delta / 2.0;
    let mut sum = 0.0;
    if half > 0.0 {
        // Terms around the Poisson weight's mode carry the sum; walk out from it both ways
        // until the weights no longer count.
        let mode = half.floor();
        let term = |j: f64| {
            let log_weight = j * half.ln() - half;
            let p = (log_weight - ln_gamma(j + 1.0)).exp();
            let q = delta.signum()
                * (log_weight + delta.abs().ln() - 0.5 * 2f64.ln() - ln_gamma(j + 1.5)).exp();
            p * beta_reg(j + 0.5, df / 2.0, y) + q * beta_reg(j + 1.0, df / 2.0, y)
        };
        let mut j = mode;
        loop {
            let x = term(j);
            sum += x;
            if (j > mode + 10.0 && x.abs() < 1e-16) || j > mode + 10_000.0 {
                break;
            }
            j += 1.0;
        }
        let mut j = mode - 1.0;
        while j >= 0.0 {
            let x = term(j);
            sum += x;
            if j < mode - 10.0 && x.abs() < 1e-16 {
                break;
            }
            j -= 1.0;
        }
    } else {
        sum = beta_reg(0.5, df / 2.0, y);
    }
    (normal.cdf(-delta) + 0.5 * sum).clamp(0.0, 1.0)
}

/// P(F ≤ f) for the noncentral F distribution with `df1`, `df2` degrees of freedom and
/// noncentrality `lambda` (a Poisson mixture of beta distributions).
pub fn noncentral_f_cdf(f: f64, df1: f64, df2: f64, lambda: f64) -> f64 {
    if f <= 0.0 {
        return 0.0;
    }
    let x = df1 * f / (df1 * f + df2);
    let half = lambda / 2.0;
    if half <= 0.0 {
        return beta_reg(df1 / 2.0, df2 / 2.0, x);
    }
    let mode = half.floor();
    let term = |j: f64| {
        (j * half.ln() - half - ln_gamma(j + 1.0)).exp() * beta_reg(df1 / 2.0 + j, df2 / 2.0, x)
    };
    let mut sum = 0.0;
    let mut j = mode;
    loop {
        let x = term(j);
        sum += x;
        if (j > mode + 10.0 && x < 1e-16) || j > mode + 10_000.0 {
            break;
        }
        j += 1.0;
    }
    let mut j = mode - 1.0;
    while j >= 0.0 {
        let x = term(j);
        sum += x;
        if j < mode - 10.0 && x < 1e-16 {
            break;
        }
        j -= 1.0;
    }
    sum.clamp(0.0, 1.0)
}

/// The `x` at which the decreasing function `cdf` equals `target`, between `lo` and the
/// first of `hi`, 2 `hi`, 4 `hi`, ... below it.
fn solve_decreasing(cdf: impl Fn(f64) -> f64, target: f64, mut lo: f64, mut hi: f64) -> f64 {
    let mut step = hi - lo;
    while cdf(hi) > target && step < 1e6 {
        lo = hi;
        step *= 2.0;
        hi += step;
    }
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if cdf(mid) > target {
            lo = mid;
        } else {
            hi = mid;
        }
        if hi - lo < 1e-10 * (1.0 + hi.abs()) {
            break;
        }
    }
    0.5 * (lo + hi)
}

/// The 95% confidence interval of the noncentrality δ behind an observed t with `df`
/// degrees of freedom.
pub fn t_noncentrality_ci(t: f64, df: f64) -> Option<[f64; 2]> {
    if !t.is_finite() || !df.is_finite() || df <= 0.0 {
        return None;
    }
    let cdf = |delta: f64| noncentral_t_cdf(t, df, delta);
    let width = 10.0 + t.abs();
    Some([
        solve_decreasing(cdf, 1.0 - TAIL, t - width, t),
        solve_decreasing(cdf, TAIL, t, t + width),
    ])
}

/// The 95% confidence interval of the noncentrality λ behind an observed F (0 where even
/// λ = 0 puts the observation inside a tail).
pub fn f_noncentrality_ci(f: f64, df1: f64, df2: f64) -> Option<[f64; 2]> {
    if !f.is_finite() || f < 0.0 || df1 <= 0.0 || df2 <= 0.0 {
        return None;
    }
    let cdf = |lambda: f64| noncentral_f_cdf(f, df1, df2, lambda);
    let at_zero = cdf(0.0);
    let start = 10.0 + 2.0 * df1 * f;
    let lower = if at_zero > 1.0 - TAIL {
        solve_decreasing(cdf, 1.0 - TAIL, 0.0, start)
    } else {
        0.0
    };
    let upper = if at_zero > TAIL {
        solve_decreasing(cdf, TAIL, 0.0, start)
    } else {
        0.0
    };
    Some([lower, upper])
}

/// What the paper reports for a claim, as the statistic of its test.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PaperStatistic {
    /// A t test (or a contrast's t) with its degrees of freedom.
    T { t: f64, df: f64 },
    /// An F test.
    F { f: f64, df1: f64, df2: f64 },
    /// Only a two-sided p of a t test with `df` degrees of freedom (perhaps adjusted for
    /// multiple comparisons, which only makes the unadjusted p smaller): its effect is at
    /// least the |t| that p gives.
    P { p: f64, df: f64 },
}

/// The paper's networks per condition (Figs 4-6: "5 independently trained networks").
pub const PAPER_NETWORKS: f64 = 5.0;

/// Our statistic for the same claim; a t is oriented so that the paper's direction is
/// positive.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum OurStatistic {
    T { t: f64, df: f64 },
    F { f: f64, df1: f64, df2: f64 },
}

/// The paper's effect set against our interval.
#[derive(Clone, Debug, PartialEq)]
pub struct Compatibility {
    /// Whether our 95% interval lies below the paper's effect (the smallest it can be, for
    /// a p alone).
    pub excluded: bool,
    /// E.g. "noncentrality δ: ours 95% CI [−0.42, 5.31], the paper's 8.15 at 5 networks".
    pub text: String,
}

/// The paper's effect (at `networks` networks per condition, ours) against our 95%
/// interval; `None` when the two are not the same kind of test or a value is missing.
pub fn compare(paper: PaperStatistic, ours: OurStatistic, networks: f64) -> Option<Compatibility> {
    if networks.is_nan() || networks <= 0.0 {
        return None;
    }
    let scale = networks / PAPER_NETWORKS;
    let (name, paper_value, bound, ci) = match (paper, ours) {
        (PaperStatistic::T { t, .. }, OurStatistic::T { t: ours, df }) => (
            "δ",
            t.abs() * scale.sqrt(),
            false,
            t_noncentrality_ci(ours, df)?,
        ),
        (PaperStatistic::P { p, df: paper_df }, OurStatistic::T { t: ours, df }) => {
            let smallest = StudentsT::new(0.0, 1.0, paper_df)
                .ok()?
                .inverse_cdf(1.0 - p / 2.0);
            (
                "δ",
                smallest * scale.sqrt(),
                true,
                t_noncentrality_ci(ours, df)?,
            )
        }
        (
            PaperStatistic::F { f, df1, .. },
            OurStatistic::F {
                f: ours,
                df1: d1,
                df2: d2,
            },
        ) => (
            "λ",
            df1 * f * scale,
            false,
            f_noncentrality_ci(ours, d1, d2)?,
        ),
        _ => return None,
    };
    Some(Compatibility {
        excluded: ci[1] < paper_value,
        text: format!(
            "noncentrality {name}: ours 95% CI [{:.2}, {:.2}], the paper's {}{paper_value:.2} at {networks} networks",
            ci[0],
            ci[1],
            if bound { "at least " } else { "" }
        ),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    // Reference values: SciPy's stats.nct / ncf; R's pt / pf with ncp agree to 1e-10.
    #[test]
    fn the_noncentral_distributions_match_scipy() {
        for (t, df, delta, want) in [
            (2.0, 4.0, 1.0, 0.764_567_453_824_324_3),
            (-1.5, 2.0, 0.7, 0.044_039_704_499_232_61),
            (0.5, 20.0, 3.0, 0.006_236_991_303_444_414),
            (3.0, 16.0, 8.0, 5.146_034_289_473_735e-6),
        ] {
            let got = noncentral_t_cdf(t, df, delta);
            assert!(
                (got - want).abs() < 1e-9,
                "t {t} df {df} δ {delta}: {got} vs {want}"
            );
        }
        for (f, df1, df2, lambda, want) in [
            (0.39, 1.0, 20.0, 5.0, 0.051_270_302_257_176_735),
            (2.5, 3.0, 16.0, 12.0, 0.162_649_182_512_337_93),
            (105.57, 2.0, 20.0, 150.0, 0.793_731_703_937_613),
        ] {
            let got = noncentral_f_cdf(f, df1, df2, lambda);
            assert!(
                (got - want).abs() < 1e-9,
                "F {f} λ {lambda}: {got} vs {want}"
            );
        }
        // No noncentrality: the central distributions.
        let central = StudentsT::new(0.0, 1.0, 4.0).unwrap();
        assert!((noncentral_t_cdf(-1.3, 4.0, 0.0) - central.cdf(-1.3)).abs() < 1e-12);
    }

    #[test]
    fn the_intervals_put_the_observation_at_each_tail() {
        let [lo, hi] = t_noncentrality_ci(2.28, 4.0).unwrap();
        assert!((noncentral_t_cdf(2.28, 4.0, lo) - 0.975).abs() < 1e-8);
        assert!((noncentral_t_cdf(2.28, 4.0, hi) - 0.025).abs() < 1e-8);
        assert!(lo < 2.28 && 2.28 < hi);
        let [lo, hi] = f_noncentrality_ci(19.16, 3.0, 16.0).unwrap();
        assert!((noncentral_f_cdf(19.16, 3.0, 16.0, lo) - 0.975).abs() < 1e-8);
        assert!((noncentral_f_cdf(19.16, 3.0, 16.0, hi) - 0.025).abs() < 1e-8);
        // An F too small even for no effect: the interval is [0, 0].
        assert_eq!(f_noncentrality_ci(0.001, 2.0, 20.0).unwrap(), [0.0, 0.0]);
        // Small but ordinary: the lower end is 0, the upper above it.
        let [lo, hi] = f_noncentrality_ci(0.39, 1.0, 20.0).unwrap();
        assert_eq!(lo, 0.0);
        assert!((noncentral_f_cdf(0.39, 1.0, 20.0, hi) - 0.025).abs() < 1e-8);
    }

    #[test]
    fn a_wide_interval_holds_the_paper_and_a_narrow_one_excludes_it() {
        let paper = PaperStatistic::T { t: -8.15, df: 4.0 };
        // Five networks, t = 2.28 in the paper's direction: δ at most about 5.
        let narrow = compare(paper, OurStatistic::T { t: 2.28, df: 4.0 }, 5.0).unwrap();
        assert!(narrow.excluded, "{narrow:?}");
        // Three networks, t = 1.79 on 2 df: δ up to 4.24, below the paper's 6.31 at 3
        // networks, but above a paper's t of 4.0 (3.10 at 3 networks).
        let three = OurStatistic::T { t: 1.79, df: 2.0 };
        assert!(compare(paper, three, 3.0).unwrap().excluded);
        let smaller = PaperStatistic::T { t: 4.0, df: 4.0 };
        let wide = compare(smaller, three, 3.0).unwrap();
        assert!(!wide.excluded, "{wide:?}");
        assert!(wide.text.contains("[-0.86, 4.24]"), "{wide:?}");
        // A p alone bounds the paper's effect from below.
        let bound = PaperStatistic::P { p: 0.034, df: 20.0 };
        let c = compare(bound, OurStatistic::T { t: 0.1, df: 20.0 }, 5.0).unwrap();
        assert!(c.text.contains("at least 2.28"), "{c:?}");
        // Different kinds of test are not compared.
        assert!(
            compare(
                bound,
                OurStatistic::F {
                    f: 1.0,
                    df1: 1.0,
                    df2: 20.0
                },
                5.0
            )
            .is_none()
        );
    }
}
