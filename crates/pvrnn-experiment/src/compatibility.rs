//! Whether a result in the paper's direction that is not significant here contradicts the
//! paper's (a disagreement) or is too imprecise to tell (the design too small): the plan's
//! rule for such results (docs/experiments.md, "Verdicts").
//!
//! The paper reports test statistics, not effects in our units, so the two studies are
//! compared through the noncentrality of their tests, which grows with the networks per
//! condition n (δ = θ √n for a t, λ = θ n for an F, θ the effect per network). The paper's
//! estimate is itself uncertain (5 networks), so "differs" is a test, not our interval
//! against the paper's point: the likelihood-ratio test of one θ for both studies (χ², 1
//! df), each study's statistic by its noncentral t or F density (where the paper gives only
//! p, the probability of a t at least as large as that p allows). Beside it, our
//! noncentrality's 95% interval (the noncentral distribution inverted at our statistic,
//! Steiger & Fouladi 1997) and the paper's estimate scaled to our networks. Rank statistics
//! (ART, ART-C) are compared with the paper's, which it reports as ART's.

use statrs::distribution::{ContinuousCDF, Normal, StudentsT};
use statrs::function::beta::beta_reg;
use statrs::function::gamma::ln_gamma;

/// Each side's tail of the 95% interval.
const TAIL: f64 = 0.025;

/// Σ_j term(j) over j = 0, 1, ..., walking out from `mode` both ways until the terms no
/// longer count: the Poisson mixtures below put their weight around the Poisson mean.
fn sum_around(mode: f64, term: impl Fn(f64) -> f64) -> f64 {
    let mut sum = 0.0;
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
    sum
}

/// ln of the Poisson weight of `j` with mean `half`.
fn ln_poisson(j: f64, half: f64) -> f64 {
    j * half.ln() - half - ln_gamma(j + 1.0)
}

/// P(T ≤ t) for the noncentral t distribution with `df` degrees of freedom and
/// noncentrality `delta` (the Poisson-mixture series of Lenth 1989, AS 243).
pub fn noncentral_t_cdf(t: f64, df: f64, delta: f64) -> f64 {
    if t < 0.0 {
        return 1.0 - noncentral_t_cdf(-t, df, -delta);
    }
    let y = t * t / (t * t + df);
    let half = delta * delta / 2.0;
    let sum = if half > 0.0 {
        sum_around(half.floor(), |j| {
            let q = delta.signum()
                * (ln_poisson(j, half) + ln_gamma(j + 1.0) + delta.abs().ln()
                    - 0.5 * 2f64.ln()
                    - ln_gamma(j + 1.5))
                .exp();
            ln_poisson(j, half).exp() * beta_reg(j + 0.5, df / 2.0, y)
                + q * beta_reg(j + 1.0, df / 2.0, y)
        })
    } else {
        beta_reg(0.5, df / 2.0, y)
    };
    (Normal::standard().cdf(-delta) + 0.5 * sum).clamp(0.0, 1.0)
}

/// The noncentral t density: ν/t (F_{ν+2}(t √(1 + 2/ν)) − F_ν(t)) away from 0, a central
/// difference of the distribution function next to it.
pub fn noncentral_t_pdf(t: f64, df: f64, delta: f64) -> f64 {
    let density = if t.abs() > 1e-3 {
        df / t
            * (noncentral_t_cdf(t * (1.0 + 2.0 / df).sqrt(), df + 2.0, delta)
                - noncentral_t_cdf(t, df, delta))
    } else {
        let h = 1e-4;
        (noncentral_t_cdf(t + h, df, delta) - noncentral_t_cdf(t - h, df, delta)) / (2.0 * h)
    };
    density.max(0.0)
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
    sum_around(half.floor(), |j| {
        ln_poisson(j, half).exp() * beta_reg(df1 / 2.0 + j, df2 / 2.0, x)
    })
    .clamp(0.0, 1.0)
}

/// The noncentral F density: given the Poisson count j, F is (df1 + 2j) / df1 times a
/// central F(df1 + 2j, df2).
pub fn noncentral_f_pdf(f: f64, df1: f64, df2: f64, lambda: f64) -> f64 {
    if f <= 0.0 {
        return 0.0;
    }
    // ln of the central F(a, b) density at y.
    let ln_central = |y: f64, a: f64, b: f64| {
        0.5 * a * (a / b).ln() + (0.5 * a - 1.0) * y.ln()
            - 0.5 * (a + b) * (1.0 + a * y / b).ln()
            - (ln_gamma(a / 2.0) + ln_gamma(b / 2.0) - ln_gamma((a + b) / 2.0))
    };
    let term = |j: f64, half: f64| {
        let a = df1 + 2.0 * j;
        let ln_weight = if half > 0.0 { ln_poisson(j, half) } else { 0.0 };
        (ln_weight + (df1 / a).ln() + ln_central(f * df1 / a, a, df2)).exp()
    };
    let half = lambda / 2.0;
    if half <= 0.0 {
        return term(0.0, 0.0);
    }
    sum_around(half.floor(), |j| term(j, half))
}

/// The `x` at which the decreasing function `cdf` equals `target`, from a bracket
/// `[lo, hi]` widened (doubling steps) until it holds it.
fn solve_decreasing(cdf: impl Fn(f64) -> f64, target: f64, mut lo: f64, mut hi: f64) -> f64 {
    let mut step = (hi - lo).max(1.0);
    while cdf(lo) < target && step < 1e6 {
        hi = lo;
        lo -= step;
        step *= 2.0;
    }
    while cdf(hi) > target && step < 1e6 {
        lo = hi;
        hi += step;
        step *= 2.0;
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

/// What the paper reports for a claim, as the statistic of its test, oriented so that its
/// direction is positive.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PaperStatistic {
    /// A t test (or a contrast's t) with its degrees of freedom.
    T { t: f64, df: f64 },
    /// An F test.
    F { f: f64, df1: f64, df2: f64 },
    /// Only a two-sided p of a t test with `df` degrees of freedom (assumed from the
    /// paper's design): the paper's t is at least the one that p gives. Pass the largest
    /// p the printed one rounds from (0.034 → 0.0345); an adjusted p (Holm) is at least
    /// the unadjusted one, so the bound holds for it too.
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

/// Our result against the paper's.
#[derive(Clone, Debug, PartialEq)]
pub struct Compatibility {
    /// Whether the two studies' effects differ (the likelihood-ratio test of one effect
    /// for both rejects at 0.05).
    pub differs: bool,
    /// E.g. "one effect for both studies: likelihood ratio χ²(1) = 3.77, p = 0.052; our
    /// noncentrality δ: 95% CI [−0.28, 4.68], the paper's estimate 8.15 at our 5 networks".
    pub text: String,
}

/// The log-likelihood of one study's statistic as a function of the effect per network θ,
/// the noncentrality being δ = θ √n (t) or λ = θ n (F) at its `n` networks per condition.
#[derive(Clone, Copy, Debug)]
enum Observed {
    T {
        t: f64,
        df: f64,
        n: f64,
    },
    F {
        f: f64,
        df1: f64,
        df2: f64,
        n: f64,
    },
    /// A t of at least `t` (a p alone).
    TAtLeast {
        t: f64,
        df: f64,
        n: f64,
    },
}

impl Observed {
    fn log_likelihood(self, theta: f64) -> f64 {
        let p = match self {
            Observed::T { t, df, n } => noncentral_t_pdf(t, df, theta * n.sqrt()),
            Observed::F { f, df1, df2, n } => noncentral_f_pdf(f, df1, df2, theta * n),
            Observed::TAtLeast { t, df, n } => 1.0 - noncentral_t_cdf(t, df, theta * n.sqrt()),
        };
        p.max(1e-300).ln()
    }

    /// The effect per network its own statistic suggests (to place the search).
    fn estimate(self) -> f64 {
        match self {
            Observed::T { t, n, .. } | Observed::TAtLeast { t, n, .. } => t / n.sqrt(),
            Observed::F { f, df1, n, .. } => df1 * f / n,
        }
    }
}

/// The largest value of `f` over `[lo, hi]`: a grid, then golden-section search around
/// the best point of it (the likelihoods here are smooth and single-peaked).
fn maximum(f: impl Fn(f64) -> f64, lo: f64, hi: f64) -> f64 {
    const POINTS: usize = 400;
    let step = (hi - lo) / POINTS as f64;
    let (best, best_value) = (0..=POINTS)
        .map(|i| lo + step * i as f64)
        .map(|x| (x, f(x)))
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .unwrap_or((lo, f(lo)));
    let (mut a, mut b) = ((best - step).max(lo), (best + step).min(hi));
    let ratio = (5f64.sqrt() - 1.0) / 2.0;
    for _ in 0..80 {
        let (c, d) = (b - ratio * (b - a), a + ratio * (b - a));
        if f(c) > f(d) {
            b = d;
        } else {
            a = c;
        }
    }
    best_value.max(f(0.5 * (a + b)))
}

/// The likelihood-ratio test of one effect per network for both studies (χ² with 1 df):
/// twice the log-likelihood each study reaches with its own effect, less what they reach
/// with a shared one.
fn one_effect_test(ours: Observed, paper: Observed) -> (f64, f64) {
    let (a, b) = (ours.estimate(), paper.estimate());
    let f_test = matches!(ours, Observed::F { .. });
    let spread = 10.0 + 2.0 * a.abs().max(b.abs());
    let (lo, hi) = if f_test {
        (0.0, spread)
    } else {
        (a.min(b) - spread, a.max(b) + spread)
    };
    // A p alone is most likely with an effect as large as can be: its supremum is 1.
    let paper_alone = match paper {
        Observed::TAtLeast { .. } => 0.0,
        _ => maximum(|x| paper.log_likelihood(x), lo, hi),
    };
    let apart = maximum(|x| ours.log_likelihood(x), lo, hi) + paper_alone;
    let together = maximum(|x| ours.log_likelihood(x) + paper.log_likelihood(x), lo, hi);
    let statistic = (2.0 * (apart - together)).max(0.0);
    let p = statrs::distribution::ChiSquared::new(1.0).map_or(f64::NAN, |chi| chi.sf(statistic));
    (statistic, p)
}

/// Our result (at `networks` networks per condition) against the paper's: whether the two
/// studies' effects differ, with our noncentrality's 95% interval beside the paper's
/// estimate scaled to our networks; `None` when the two are not the same kind of test or a
/// value is missing.
pub fn compare(paper: PaperStatistic, ours: OurStatistic, networks: f64) -> Option<Compatibility> {
    if networks.is_nan() || networks <= 0.0 {
        return None;
    }
    let scale = networks / PAPER_NETWORKS;
    let (mine, theirs, name, paper_value, bound, ci) = match (paper, ours) {
        (PaperStatistic::T { t, df: paper_df }, OurStatistic::T { t: ours, df }) => (
            Observed::T {
                t: ours,
                df,
                n: networks,
            },
            Observed::T {
                t,
                df: paper_df,
                n: PAPER_NETWORKS,
            },
            "δ",
            t * scale.sqrt(),
            false,
            t_noncentrality_ci(ours, df)?,
        ),
        (PaperStatistic::P { p, df: paper_df }, OurStatistic::T { t: ours, df }) => {
            let smallest = StudentsT::new(0.0, 1.0, paper_df)
                .ok()?
                .inverse_cdf(1.0 - p / 2.0);
            (
                Observed::T {
                    t: ours,
                    df,
                    n: networks,
                },
                Observed::TAtLeast {
                    t: smallest,
                    df: paper_df,
                    n: PAPER_NETWORKS,
                },
                "δ",
                smallest * scale.sqrt(),
                true,
                t_noncentrality_ci(ours, df)?,
            )
        }
        (
            PaperStatistic::F { f, df1, df2 },
            OurStatistic::F {
                f: ours,
                df1: d1,
                df2: d2,
            },
        ) => (
            Observed::F {
                f: ours,
                df1: d1,
                df2: d2,
                n: networks,
            },
            Observed::F {
                f,
                df1,
                df2,
                n: PAPER_NETWORKS,
            },
            "λ",
            df1 * f * scale,
            false,
            f_noncentrality_ci(ours, d1, d2)?,
        ),
        _ => return None,
    };
    if !ci.iter().all(|c| c.is_finite()) {
        return None;
    }
    let (statistic, p) = one_effect_test(mine, theirs);
    Some(Compatibility {
        differs: p < TAIL * 2.0,
        text: format!(
            "one effect for both studies: likelihood ratio χ²(1) = {statistic:.2}, {}; our noncentrality {name}: 95% CI [{:.2}, {:.2}], the paper's {}{paper_value:.2} at our {networks} networks",
            if p < 0.001 {
                "p < 0.001".to_string()
            } else {
                format!("p = {p:.3}")
            },
            ci[0],
            ci[1],
            if bound { "at least " } else { "estimate " }
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
    fn the_densities_match_scipy() {
        for (t, df, delta, want) in [
            (2.28, 4.0, 1.5, 0.232_260_038_849_539_64),
            (-0.7, 2.0, 0.9, 0.092_927_900_377_099_55),
            (0.0005, 20.0, 1.0, 0.239_087_142_161_970_55),
            (8.15, 4.0, 6.0, 0.094_021_537_768_062_62),
        ] {
            let got = noncentral_t_pdf(t, df, delta);
            assert!(
                (got - want).abs() < 1e-7 * want.max(1.0),
                "t {t} δ {delta}: {got} vs {want}"
            );
        }
        for (f, df1, df2, lambda, want) in [
            (0.39, 1.0, 20.0, 5.0, 0.093_171_279_245_644_46),
            (0.0077, 2.0, 20.0, 3.0, 0.224_067_496_412_293_76),
            (19.16, 3.0, 16.0, 40.0, 0.036_798_606_166_266_82),
            (1.5, 2.0, 20.0, 0.0, 0.214_943_222_714_665_84),
        ] {
            let got = noncentral_f_pdf(f, df1, df2, lambda);
            assert!(
                (got - want).abs() < 1e-9,
                "F {f} λ {lambda}: {got} vs {want}"
            );
        }
    }

    // Reference likelihood-ratio statistics: R's dt / df / pt with ncp, maximised with
    // optimize() over the effect per network (R warns that dt's ncp series may lose
    // precision, hence the tolerance).
    #[test]
    fn the_one_effect_test_matches_r() {
        let t = |t: f64, df: f64| OurStatistic::T { t, df };
        let f = |f: f64, df1: f64, df2: f64| OurStatistic::F { f, df1, df2 };
        for (paper, ours, networks, chi2, differs) in [
            // Fig 4B: our t(4) = 2.28 against the paper's 8.15 (5 networks each).
            (
                PaperStatistic::T { t: 8.15, df: 4.0 },
                t(2.28, 4.0),
                5.0,
                3.768_180_9,
                false,
            ),
            // Three networks, t(2) = 1.79.
            (
                PaperStatistic::T { t: 8.15, df: 4.0 },
                t(1.79, 2.0),
                3.0,
                3.056_743_1,
                false,
            ),
            // Fig 5B's proprioception: F(1, 20) = 0.39 against 46.09.
            (
                PaperStatistic::F {
                    f: 46.09,
                    df1: 1.0,
                    df2: 20.0,
                },
                f(0.39, 1.0, 20.0),
                5.0,
                13.645_729,
                true,
            ),
            (
                PaperStatistic::F {
                    f: 19.16,
                    df1: 3.0,
                    df2: 16.0,
                },
                f(4.0, 3.0, 16.0),
                5.0,
                4.339_292,
                true,
            ),
            // A p alone (the t at least the one p = 0.0345 gives on 20 df).
            (
                PaperStatistic::P {
                    p: 0.0345,
                    df: 20.0,
                },
                t(0.312, 20.0),
                5.0,
                4.228_563,
                true,
            ),
            (
                PaperStatistic::P { p: 0.001, df: 16.0 },
                t(1.0, 16.0),
                5.0,
                6.428_111,
                true,
            ),
        ] {
            let c = compare(paper, ours, networks).unwrap();
            let got: f64 = c.text["one effect for both studies: likelihood ratio χ²(1) = ".len()..]
                .split(',')
                .next()
                .unwrap()
                .parse()
                .unwrap();
            assert!(
                (got - chi2).abs() < 0.01,
                "{paper:?} {ours:?}: {} vs {chi2}",
                c.text
            );
            assert_eq!(c.differs, differs, "{}", c.text);
        }
        // Beside the test: our interval and the paper's estimate at our networks.
        let c = compare(PaperStatistic::T { t: 8.15, df: 4.0 }, t(1.79, 2.0), 3.0).unwrap();
        assert!(
            c.text
                .contains("95% CI [-0.86, 4.24], the paper's estimate 6.31 at our 3 networks"),
            "{}",
            c.text
        );
        let bound = PaperStatistic::P {
            p: 0.0345,
            df: 20.0,
        };
        assert!(
            compare(bound, t(0.1, 20.0), 5.0)
                .unwrap()
                .text
                .contains("at least 2.27")
        );
        // Different kinds of test are not compared.
        assert!(compare(bound, f(1.0, 1.0, 20.0), 5.0).is_none());
    }
}
