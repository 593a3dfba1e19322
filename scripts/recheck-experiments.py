#!/usr/bin/env python3
"""Independent re-computation of the robustness, uncertainty and hierarchy experiments'
statistics from their tidy trials.csv, compared with their summary.json (numpy + scipy,
written apart from the Rust code; definitions from docs/experiments.md and the reports).

Usage:
    python3 scripts/recheck-experiments.py docs/results/converged [docs/results ...]
A path is a report folder (trials.csv + summary.json), a folder holding report/, or one
holding robustness/, uncertainty/, hierarchy/. Exit status 1 when any figure disagrees.

Definitions re-implemented (alpha 0.05, power 0.80):
  * per network: mean over test sequences of the mean over trials; rows with
    diverged_at_step set (or an empty value) left out; networks in numeric order.
  * paired difference a - b over networks: mean, 95% CI (t, n-1 df), d_z = mean / SD of
    the differences, two-sided paired-t p, detectable = (t_.975 + t_.80) x SE.
  * robustness: error_vision<top> (64x64 MSE, all pixels) in six cells, vision {64 (all),
    32+16, 16} x proprio {on, off}, over both tasks' sequences; networks are blocks.
    - two-way ART: per effect, values aligned (value - cell mean + the effect's estimate:
      A_i - grand, B_j - grand, cell_ij - A_i - B_j + grand), ranked (average ranks;
      values within 1e-10 x max|value| tie, as ARTool), then the randomised complete block
      ANOVA (blocks + A + B + A:B; error df (n-1)(ab-1)), fitted by least squares with
      sum-to-zero coding; that effect's F, p, partial eta^2 = SS / (SS + SS_error).
    - ART-C: a factor's levels compared on the ranks aligned for it (mean-rank difference,
      t on that ANOVA's error MS and df); cells on the ranks of the raw values in the
      blocks + cells ANOVA; Holm within each family (vision 3, proprio 1, cells 15).
      Cohen's d of the raw values pooled over networks (pooled SD); the raw difference
      paired over networks' level (cell) means.
  * uncertainty: prior sigma and mean |change of prior sigma| per module, and "all
    modules" = the mean weighted by z units (30, 30, 40, 30: the default model);
    repositioning vs wiping paired over networks; for prior sigma the TOST of the paired
    difference against +-10% of the two tasks' mean (90% CI, larger one-sided p,
    equivalent when p < 0.05).
  * summary.json "paper" (texts printed to 2-4 digits, checked to those digits): its
    means, effects, and the likelihood-ratio test of one effect per network for both
    studies (chi^2, 1 df): each study's statistic by its noncentral t or F density,
    delta = theta sqrt(n) or lambda = theta n (n networks; the paper 5); a paper "p only"
    (0.034 -> 0.0345, df 20) as P(T >= the t that p gives); LR = 2 x (each study's own
    best log-likelihood - the best shared one). Beside it our noncentrality's 95% CI (the
    noncentral cdf inverted at our statistic) and the paper's scaled to our n (t sqrt(n/5),
    df1 F n/5). Verdicts: opposite direction disagrees; same and significant agrees; same,
    not significant: disagrees when the LR p < 0.05, else undecided (null). Fig 4A:
    equivalence agrees, else a significant paired t disagrees, else undecided. Not
    re-derived: Fig 5B's resolution-order verdict (means and aligned-rank orders).
  * hierarchy: the per-network mean contribution per module = map_mean_<module> of the
    everything-observed runs. Not in trials.csv, so skipped: contributions per subtask
    phase (per-step maps), the executive boundary test (per-step mu_q, subtask labels)
    and the occlusion scores (hidden-pixel errors). For boundary and occlusion only the
    one-sample t against 0 is re-checked from summary.json's own per-network values,
    counted apart as "internal".
"""
import argparse, csv, json, math, os, re, sys  # noqa: E401
from collections import defaultdict

import numpy as np
from scipy import stats
from scipy.optimize import brentq, minimize_scalar

import recheck_gate  # scripts/recheck_gate.py

ALPHA, POWER, MARGIN, TIE = 0.05, 0.80, 0.10, 1e-10
MODULES = ["executive", "associative", "exteroceptive", "proprioceptive"]
Z_UNITS = {"executive": 30, "associative": 30, "exteroceptive": 40, "proprioceptive": 30}
VISION = ["64 (all)", "32+16", "16"]
PROPRIO = ["on", "off"]
PAPER_NETWORKS = 5.0
EVERYTHING = "vision 64 (all), proprio on"


# ---------------------------------------------------------------- data

def load(path):
    rows = list(csv.DictReader(open(path, newline="")))
    ok = [r for r in rows if not r.get("diverged_at_step")]
    return ok, len(rows) - len(ok)


def num(s):
    """A CSV field as a finite float, else None (empty: no score)."""
    v = float(s) if s not in (None, "") else math.nan
    return v if math.isfinite(v) else None


def per_network(rows, keep, value):
    """{network: mean over sequences of the mean over trials of value(row)}."""
    acc = defaultdict(lambda: defaultdict(list))
    for r in rows:
        v = value(r) if keep(r) else None
        if v is not None:
            acc[int(r["network"])][r["sequence"]].append(v)
    return {n: float(np.mean([np.mean(t) for t in seqs.values()]))
            for n, seqs in sorted(acc.items())}


# ---------------------------------------------------------------- statistics

def paired(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    res = stats.ttest_rel(a, b)
    ci = res.confidence_interval(1 - ALPHA)
    d = a - b
    n, sd = len(d), d.std(ddof=1)
    se = sd / math.sqrt(n)
    det = (stats.t.ppf(1 - ALPHA / 2, n - 1) + stats.t.ppf(POWER, n - 1)) * se
    return dict(mean=d.mean(), ci95=[ci.low, ci.high], cohen_d=d.mean() / sd, detectable=det,
                p=res.pvalue, t=res.statistic, df=n - 1, n=[len(a), len(b)])


def tost_paired(a, b, margin):
    d = np.asarray(a, float) - np.asarray(b, float)
    lo = stats.ttest_1samp(d, -margin, alternative="greater").pvalue  # H0: diff <= -margin
    hi = stats.ttest_1samp(d, margin, alternative="less").pvalue      # H0: diff >= +margin
    ci = stats.ttest_1samp(d, 0.0).confidence_interval(1 - 2 * ALPHA)
    p = max(lo, hi)
    return dict(margin=margin, mean=d.mean(), ci90=[ci.low, ci.high], p=p,
                equivalent=bool(p < ALPHA), n=[len(d), len(d)])


def cohen_d(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    sp = math.sqrt(((len(a) - 1) * a.var(ddof=1) + (len(b) - 1) * b.var(ddof=1))
                   / (len(a) + len(b) - 2))
    return (a.mean() - b.mean()) / sp


def holm(p):
    p = np.asarray(p, float)
    out, run = np.empty(len(p)), 0.0
    for k, i in enumerate(np.argsort(p, kind="stable")):
        run = max(run, min(1.0, (len(p) - k) * p[i]))
        out[i] = run
    return out


def ranks(v):
    """Average ranks; neighbours within TIE x max|v| of each other are one tie group."""
    v = np.asarray(v, float)
    order, tol = np.argsort(v, kind="stable"), TIE * np.abs(v).max()
    out, start = np.empty(len(v)), 0
    while start < len(v):
        end = start + 1
        while end < len(v) and v[order[end]] - v[order[end - 1]] <= tol:
            end += 1
        out[order[start:end]] = (start + 1 + end) / 2
        start = end
    return out


def sum_coding(levels, k):
    """Sum-to-zero columns of a factor with k levels (level k-1 = -1 in every column)."""
    levels = np.asarray(levels)
    x = (levels[:, None] == np.arange(k - 1)).astype(float)
    x[levels == k - 1] = -1.0
    return x


def blocked_anova(y, terms):
    """Least-squares ANOVA of y (flat) with an intercept and the given terms
    {name: columns}; each term's SS = the RSS rise when its columns are dropped."""
    def rss(cols):
        X = np.column_stack([np.ones(len(y))] + cols)
        beta, *_ = np.linalg.lstsq(X, y, rcond=None)
        return float(((y - X @ beta) ** 2).sum())
    full = rss(list(terms.values()))
    df_err = len(y) - 1 - sum(c.shape[1] for c in terms.values())
    out = {name: (rss([c for m, c in terms.items() if m != name]) - full, cols.shape[1])
           for name, cols in terms.items()}
    return out, full, df_err


def design_terms(n, a, b):
    k, i, j = np.meshgrid(range(n), range(a), range(b), indexing="ij")
    k, i, j = k.ravel(), i.ravel(), j.ravel()
    A, B = sum_coding(i, a), sum_coding(j, b)
    AB = np.column_stack([A[:, p] * B[:, q] for p in range(a - 1) for q in range(b - 1)])
    return {"block": sum_coding(k, n), "A": A, "B": B, "A:B": AB}, i, j


def rank_contrasts(r, group, labels, ms, df):
    """ART-C: pairwise mean-rank differences of the groups, t on the error MS, Holm."""
    out = []
    for x in range(len(labels)):
        for z in range(x + 1, len(labels)):
            rx, rz = r[group == x], r[group == z]
            diff = rx.mean() - rz.mean()
            t = diff / math.sqrt(ms * (1 / len(rx) + 1 / len(rz)))
            out.append(dict(i=x, j=z, a=labels[x], b=labels[z], rank_difference=diff, t=t,
                            df=df, p=2 * stats.t.sf(abs(t), df)))
    for c, adj in zip(out, holm([c["p"] for c in out])):
        c["p_holm"] = adj
    return out


def art_two_way(y):
    """y[k, i, j]: network k, vision i, proprioception j."""
    n, a, b = y.shape
    terms, i, j = design_terms(n, a, b)
    flat = y.ravel()
    cell = y.mean(axis=0)
    am, bm, g = cell.mean(axis=1), cell.mean(axis=0), cell.mean()
    resid = flat - cell[i, j]
    aligned = {"A": resid + am[i] - g, "B": resid + bm[j] - g,
               "A:B": resid + cell[i, j] - am[i] - bm[j] + g}
    effects, fams = [], {}
    for name, values in aligned.items():
        r = ranks(values)
        ss, ss_err, df_err = blocked_anova(r, terms)
        s, df = ss[name]
        f = (s / df) / (ss_err / df_err)
        effects.append(dict(effect=name, f=f, df1=df, df2=df_err, p=stats.f.sf(f, df, df_err),
                            partial_eta_squared=s / (s + ss_err)))
        if name in ("A", "B"):
            lv, labels = (i, VISION) if name == "A" else (j, [f"proprio {p}" for p in PROPRIO])
            fams[name] = rank_contrasts(r, lv, labels, ss_err / df_err, df_err)
    # Cells: ranks of the raw values, blocks + cells (one combined factor).
    c = i * b + j
    labels = [f"{VISION[x]} / proprio {PROPRIO[z]}" for x in range(a) for z in range(b)]
    r = ranks(flat)
    _, ss_err, df_err = blocked_anova(r, {"block": terms["block"], "cell": sum_coding(c, a * b)})
    fams["cells"] = rank_contrasts(r, c, labels, ss_err / df_err, df_err)
    # Raw effects: values pooled for d, per-network means paired for the difference.
    unit = {"A": [y[:, x, :].mean(axis=1) for x in range(a)],
            "B": [y[:, :, z].mean(axis=1) for z in range(b)],
            "cells": [y[:, x, z] for x in range(a) for z in range(b)]}
    pooled = {"A": [y[:, x, :].ravel() for x in range(a)],
              "B": [y[:, :, z].ravel() for z in range(b)], "cells": unit["cells"]}
    for fam, cs in fams.items():
        for ct in cs:
            ct["cohen_d"] = cohen_d(pooled[fam][ct["i"]], pooled[fam][ct["j"]])
            ct["difference"] = paired(unit[fam][ct["i"]], unit[fam][ct["j"]])
    exact_ties = sum(len(x) - len(np.unique(x)) for x in aligned.values())
    tol_ties = sum(len(x) - len(np.unique(ranks(x))) for x in aligned.values())
    return effects, fams, (exact_ties, tol_ties)


# ---------------------------------------------------------------- against the paper

def loglik(obs, theta):
    """ln density of a study's statistic at effect per network theta (vectorised)."""
    s, df, n = obs["stat"], obs["df"], obs["n"]
    p = {"t": lambda: stats.nct.pdf(s, df, theta * math.sqrt(n)),
         "t_at_least": lambda: stats.nct.sf(s, df, theta * math.sqrt(n)),
         "F": lambda: stats.ncf.pdf(s, df[0], df[1], theta * n)}[obs["kind"]]()
    return np.log(np.maximum(p, 1e-300))


def best(fun, lo, hi):
    """Maximum of a smooth single-peaked function: fine grid, then bounded Brent."""
    x = np.linspace(lo, hi, 4001)
    k = int(np.argmax(fun(x)))
    r = minimize_scalar(lambda t: -fun(t), bounds=(x[max(k - 1, 0)], x[min(k + 1, len(x) - 1)]),
                        method="bounded", options={"xatol": 1e-12})
    return max(fun(x[k]), -r.fun)


def paper_comparison(ours, paper, n):
    """LR test of one effect per network for both studies, our noncentrality's 95% CI,
    and the paper's noncentrality scaled to our n networks."""
    est = [o["df"][0] * o["stat"] / o["n"] if o["kind"] == "F" else o["stat"] / math.sqrt(o["n"])
           for o in (ours, paper)]
    spread = 10 + 2 * max(map(abs, est))  # a range wide enough to hold every maximum
    lo, hi = (0.0, spread) if ours["kind"] == "F" else (min(est) - spread, max(est) + spread)
    # A "p only" paper statistic is most likely with an unbounded effect: its supremum is 1.
    alone = 0.0 if paper["kind"] == "t_at_least" else best(lambda t: loglik(paper, t), lo, hi)
    apart = best(lambda t: loglik(ours, t), lo, hi) + alone
    lr = max(0.0, 2 * (apart - best(lambda t: loglik(ours, t) + loglik(paper, t), lo, hi)))
    s, df = ours["stat"], ours["df"]
    if ours["kind"] == "t":  # the cdf falls as delta rises: invert it at each tail
        g, w = (lambda d, q: stats.nct.cdf(s, df, d) - q), 10 + abs(s)
        ci = [brentq(g, s - w, s + w, args=(q,), xtol=1e-12) for q in (1 - ALPHA / 2, ALPHA / 2)]
    else:                    # lambda >= 0: 0 where even lambda = 0 puts F inside the tail
        g, ci = (lambda lam, q: stats.ncf.cdf(s, df[0], df[1], lam) - q), []
        for q in (1 - ALPHA / 2, ALPHA / 2):
            hi = 10 + 2 * df[0] * s
            while g(hi, q) > 0:
                hi *= 2
            ci.append(0.0 if g(0.0, q) <= 0 else brentq(g, 0.0, hi, args=(q,), xtol=1e-12))
    scale = n / PAPER_NETWORKS
    at_n = (paper["df"][0] * paper["stat"] * scale if paper["kind"] == "F"
            else paper["stat"] * math.sqrt(scale))
    return dict(lr=lr, p=stats.chi2.sf(lr, 1), ci=ci, paper_at_n=at_n)


# ---------------------------------------------------------------- comparison with summary.json

NUM = r"(-?\d+(?:\.\d+)?(?:e-?\d+)?)"
PTXT = r"(p < 0\.001|p = \d\.\d+)"


class Checker:
    """Compares our figures with summary.json: counts them by kind, keeps the mismatches."""

    def __init__(self, summary, rel, abs_, gated=None):
        self.s, self.rel, self.abs = summary, rel, abs_
        self.gated = gated  # {gate need: every network passes it}; None: no gate
        self.count, self.worst, self.bad, self.seen = defaultdict(int), 0.0, [], set()

    def get(self, path):
        node = self.s
        for k in path:
            try:
                node = node[k]
            except (KeyError, IndexError, TypeError):
                return None
        return node

    def _record(self, path, kind, ok, ours, ref, rel=math.inf):
        self.seen.add(tuple(map(str, path)))
        self.count[kind] += 1
        if not ok:
            self.bad.append((kind, "/".join(map(str, path)), ours, ref, rel))

    def num(self, path, ours, kind="trials.csv"):
        """One figure, to the tolerance; a missing or non-numeric field is a mismatch."""
        ref = self.get(path)
        if not isinstance(ref, (int, float)):
            return self._record(path, kind, False, ours, ref)
        d = abs(float(ours) - float(ref))
        rel = d / abs(ref) if ref else (0.0 if d == 0 else math.inf)
        self.worst = max(self.worst, rel if ref else 0.0)
        self._record(path, kind, d <= self.rel * max(abs(ref), abs(ours)) or d <= self.abs,
                     ours, ref, rel)

    def tree(self, path, ours, kind="trials.csv"):
        """Every number (or bool) of a nested dict / list of ours against the same paths."""
        items = ours.items() if isinstance(ours, dict) else \
            enumerate(ours) if isinstance(ours, (list, tuple)) else None
        if items is None:
            return self.num(path, ours, kind)
        for k, v in items:
            self.tree(path + [k], v, kind)

    def text(self, k, field):
        return (self.get(["paper", k]) or {}).get(field) or ""

    def label(self, path, ours, kind="labels"):
        """Equality of a label (or, counted under its kind, a verdict). A verdict needs every
        network to pass the validity gate: otherwise there is none (null)."""
        if kind == "paper verdict" and self.gated is not None:
            need = self.get(list(path[:-1]) + ["gate_needs"])
            if not self.gated.get(need, False):
                ours = None
        ref = self.get(path)
        self._record(path, kind, ref == ours, ours, ref)

    def printed(self, path, token, ours):
        """A figure printed in a text (token: as printed, or None when the text did not
        match): agrees when ours rounds to it; "p < 0.001" when ours is below."""
        if token is None:
            ok, token = False, "(text not found)"
        elif token.startswith("p"):
            ok = ours < 0.001 if "<" in token else self._rounds(token[4:], ours)
        else:
            ok = self._rounds(token, ours)
        self._record(path, "paper text, printed digits", ok, ours, token)

    @staticmethod
    def _rounds(token, ours):
        m = re.fullmatch(r"-?\d+(?:\.(\d+))?(?:e(-?\d+))?", token)
        half = 0.5 * 10.0 ** (int(m.group(2) or 0) - len(m.group(1) or ""))
        return abs(float(token) - ours) <= half * (1 + 1e-6) + 1e-12

    def not_compared(self, node, path=("results",)):
        """Numeric leaves under summary["results"] that no check compared."""
        node = self.get(list(path)) if node is None else node
        if isinstance(node, (dict, list)):
            items = node.items() if isinstance(node, dict) else enumerate(node)
            return [p for k, v in items for p in self.not_compared(v, path + (str(k),))]
        return ["/".join(path)] if isinstance(node, (int, float)) and path not in self.seen else []


def check_effect_text(chk, path, text, d):
    """effect_text: "Δ = m [lo, hi], d_z = x; detectable ±y" (3-digit e / 2 decimals)."""
    m = re.search(rf"Δ = {NUM} \[{NUM}, {NUM}\], d(?:_z)? = {NUM}; detectable ±{NUM}", text)
    for k, v in enumerate([d["mean"], d["ci95"][0], d["ci95"][1], d["cohen_d"], d["detectable"]]):
        chk.printed(path, m and m.group(k + 1), v)


def check_lr_note(chk, path, note, ours, paper, n):
    r = paper_comparison(ours, paper, n)
    m = re.search(rf"likelihood ratio χ²\(1\) = {NUM}, {PTXT}; our noncentrality [δλ]: 95% CI "
                  rf"\[{NUM}, {NUM}\], the paper's (?:at least |estimate ){NUM} at our (\d+) networks",
                  note)
    for k, v in enumerate([r["lr"], r["p"], r["ci"][0], r["ci"][1], r["paper_at_n"], n]):
        chk.printed(path + ["note"], m and m.group(k + 1), v)
    print(f"    LR one effect for both: chi2(1) = {r['lr']:.4f}, p = {r['p']:.4f}; "
          f"noncentrality 95% CI [{r['ci'][0]:.4f}, {r['ci'][1]:.4f}], paper at n: {r['paper_at_n']:.4f}")
    return r["p"]


def check_verdict(chk, path, p, direction_ok, lr):
    """A claim the paper found significant: the opposite direction disagrees; same direction
    and significant agrees; same direction, not significant: lr() (the LR test's p) < 0.05
    disagrees, else undecided (null)."""
    expected = False if not direction_ok else True if p < ALPHA else (False if lr() < ALPHA else None)
    chk.label(path + ["agrees"], expected, "paper verdict")


def search(pattern, text):
    m = re.search(pattern, text)
    return (lambda k: m.group(k)) if m else (lambda k: None)


def diff_fields(d):
    """A paired difference as summary.json writes it (stats::Difference)."""
    return {k: d[k] for k in ("mean", "ci95", "cohen_d", "detectable", "p", "n")} | {"paired": True}


# ---------------------------------------------------------------- experiments

def robustness(rows, chk):
    top = max(int(c[12:]) for c in rows[0] if c.startswith("error_vision"))
    chk.label(["results", "error"], f"vision{top}")
    cells = [[per_network(rows, lambda r, v=v, p=p: r["condition"] == f"vision {v}, proprio {p}",
                          lambda r: num(r[f"error_vision{top}"])) for p in PROPRIO] for v in VISION]
    nets = sorted(set.intersection(*[set(c) for row in cells for c in row]))
    chk.tree(["results", "cells"], [[{str(k): v for k, v in c.items()} for c in row] for row in cells])
    y = np.array([[[cells[x][z][k] for z in range(2)] for x in range(3)] for k in nets])
    effects, fams, ties = art_two_way(y)
    print(f"  cells (mean over {len(nets)} networks; rows 64, 32+16, 16; on, off): "
          + "; ".join(f"{y[:, x, 0].mean():.6g}, {y[:, x, 1].mean():.6g}" for x in range(3)))
    print(f"  tied aligned values: {ties[0]} exact, {ties[1]} with the 1e-10 tolerance")
    art = ["results", "art"]
    chk.num(art + ["blocks"], len(nets))
    for e, eff in enumerate(effects):
        print(f"  ART {eff['effect']:3s}: F({eff['df1']}, {eff['df2']}) = {eff['f']:.6g}, "
              f"p = {eff['p']:.6g}, partial eta^2 = {eff['partial_eta_squared']:.6g}")
        chk.label(art + ["effects", e, "effect"], eff["effect"])
        chk.tree(art + ["effects", e], {k: v for k, v in eff.items() if k != "effect"})
    for fam, key in (("A", "a_contrasts"), ("B", "b_contrasts"), ("cells", "cell_contrasts")):
        for k, ct in enumerate(fams[fam]):
            chk.label(art + [key, k, "a"], ct["a"])
            chk.label(art + [key, k, "b"], ct["b"])
            fields = ("rank_difference", "t", "df", "p", "p_holm", "cohen_d")
            chk.tree(art + [key, k], {f: ct[f] for f in fields}
                     | {"difference": diff_fields(ct["difference"])})
    # The paper table (printed digits), from our own figures.
    cm = y.mean(axis=0)                                 # cell means over networks
    by_v, on, off = cm.mean(axis=1), cm[:, 0].mean(), cm[:, 1].mean()
    save = y[:, :, 1] - y[:, :, 0]                      # off - on per network and vision
    F = r"ART F\((\d+), (\d+)\) = " + NUM + ", " + PTXT
    findings = [  # effect index, trailing numbers, effect difference
        (0, list(by_v), paired(y[:, 2, 0], y[:, 0, 0])),
        (1, [on, off], paired(y[:, 0, 1], y[:, 0, 0])),
        (2, [save[:, 0].mean(), save[:, 2].mean()], paired(save[:, 2], save[:, 0])),
    ]
    for k, (e, tail, diff) in enumerate(findings):
        g = search(F + r"; [^:]+: " + " / ".join([NUM] * len(tail)) + "$", chk.text(k, "ours"))
        for m, v in enumerate([effects[e][f] for f in ("df1", "df2", "f", "p")] + tail):
            chk.printed(["paper", k, "ours"], g(m + 1), v)
        check_effect_text(chk, ["paper", k, "effect"], chk.text(k, "effect"), diff)
    simple = next(c for c in fams["cells"] if c["a"].startswith("16 /") and c["b"].startswith("16 /"))
    chk.printed(["paper", 3, "ours"], search(PTXT + "$", chk.text(3, "ours"))(1), simple["p_holm"])
    check_effect_text(chk, ["paper", 3, "effect"], chk.text(3, "effect"), paired(y[:, 2, 1], y[:, 2, 0]))
    # Same direction and not significant: set against the paper's statistic.
    n = len(nets)
    paper_f = [(1, 46.09, 1, on < off),                                 # Fig 5B: F(1, 20)
               (2, 13.57, 2, save[:, 2].mean() > save[:, 0].mean())]   # F(2, 20)
    for k, f, df1, direction in paper_f:
        eff = effects[k]
        ours = {"kind": "F", "stat": eff["f"], "df": (eff["df1"], eff["df2"]), "n": n}
        paper = {"kind": "F", "stat": f, "df": (df1, 20), "n": PAPER_NETWORKS}
        check_verdict(chk, ["paper", k], eff["p"], direction, lambda k=k, ours=ours, paper=paper:
                      check_lr_note(chk, ["paper", k], chk.text(k, "note"), ours, paper, n))
    t = -simple["t"] if simple["a"].endswith("on") else simple["t"]  # paper's direction > 0
    t20 = stats.t.ppf(1 - 0.0345 / 2, 20)  # the smallest t that p = 0.034 (< 0.0345) allows
    check_verdict(chk, ["paper", 3], simple["p_holm"], cm[2, 0] < cm[2, 1], lambda: check_lr_note(
        chk, ["paper", 3], chk.text(3, "note"),
        {"kind": "t", "stat": t, "df": simple["df"], "n": n},
        {"kind": "t_at_least", "stat": t20, "df": 20, "n": PAPER_NETWORKS}, n))


def uncertainty(rows, chk):
    weights = np.array([Z_UNITS[m] for m in MODULES], float)
    chk.num(["results", "equivalence_margin"], MARGIN)
    ours, k = {}, 0
    for label, prefix in (("prior sigma", "sigma_p"),
                          ("mean absolute change of prior sigma", "sigma_p_change")):
        for module in MODULES + ["all modules"]:
            def value(r):
                v = [num(r[f"{prefix}_{m}"]) for m in MODULES]
                if None in v:
                    return None
                return v[MODULES.index(module)] if module in MODULES else float(v @ weights / weights.sum())
            rep = per_network(rows, lambda r: r["task"] == "repositioning", value)
            wip = per_network(rows, lambda r: r["task"] == "wiping", value)
            nets = [n for n in rep if n in wip]
            a, b = np.array([rep[n] for n in nets]), np.array([wip[n] for n in nets])
            d = paired(a, b)
            e = tost_paired(a, b, MARGIN * abs((a.mean() + b.mean()) / 2)) if prefix == "sigma_p" else None
            base = ["results", "comparisons", k]
            chk.label(base + ["module"], module)
            chk.label(base + ["measure"], label)
            chk.tree(base, {"repositioning": list(a), "wiping": list(b), "difference": diff_fields(d),
                            "paired_t": {"n": len(nets), "mean_difference": d["mean"], "t": d["t"],
                                         "df": d["df"], "p": d["p"], "cohen_dz": d["cohen_d"]}})
            if e:
                chk.tree(base + ["equivalence"], e | {"paired": True})
            else:
                chk.label(base + ["equivalence"], None)
            print(f"  {label[:14]:14s} {module:14s} rep {a.mean():.6g} wip {b.mean():.6g}: "
                  f"t({d['df']}) = {d['t']:.5g}, p = {d['p']:.4g}, d_z = {d['cohen_d']:.4g}"
                  + (f"; TOST ±{e['margin']:.4g}: p = {e['p']:.3g}" if e else ""))
            ours[(prefix, module)], k = (d, e), k + 1
    # The paper table (printed digits): Fig 4A (TOST, paired t), Fig 4B (paired t of the change).
    d, e = ours[("sigma_p", "all modules")]
    g = search(rf"TOST: difference {NUM}, 90% CI \[{NUM}, {NUM}\] vs margin ±{NUM}, {PTXT}; "
               rf"paired t\((\d+)\) = {NUM}, {PTXT}", chk.text(0, "ours"))
    for m, v in enumerate([e["mean"], *e["ci90"], e["margin"], e["p"], d["df"], d["t"], d["p"]]):
        chk.printed(["paper", 0, "ours"], g(m + 1), v)
    check_effect_text(chk, ["paper", 0, "effect"], chk.text(0, "effect"), d)
    # Fig 4A's rule (amended 2026-12-06): equivalence within the margin agrees, else a
    # significant paired t disagrees, else undecided.
    chk.label(["paper", 0, "agrees"], True if e["equivalent"] else (False if d["p"] < ALPHA else None),
              "paper verdict")
    d, _ = ours[("sigma_p_change", "all modules")]
    g = search(rf"^t\((\d+)\) = {NUM}, {PTXT}$", chk.text(1, "ours"))
    for m, v in enumerate([d["df"], d["t"], d["p"]]):
        chk.printed(["paper", 1, "ours"], g(m + 1), v)
    check_effect_text(chk, ["paper", 1, "effect"], chk.text(1, "effect"), d)
    n = d["n"][0]  # the paper's direction: repositioning lower (t < 0)
    check_verdict(chk, ["paper", 1], d["p"], d["t"] < 0, lambda: check_lr_note(
        chk, ["paper", 1], chk.text(1, "note"), {"kind": "t", "stat": -d["t"], "df": d["df"], "n": n},
        {"kind": "t", "stat": 8.15, "df": 4, "n": PAPER_NETWORKS}, n))


def hierarchy(rows, chk):
    for m in MODULES:
        nets = per_network(rows, lambda r: r["condition"] == EVERYTHING, lambda r: num(r[f"map_mean_{m}"]))
        chk.tree(["results", "contribution_per_network", m], list(nets.values()))
        print(f"  contribution {m:14s}: mean {np.mean(list(nets.values())):.6g} over {len(nets)} networks")
    # Internal: the tests from summary.json's own per-network values (inputs not re-derived).
    tests = [(["results", "executive_boundary"], "near_minus_elsewhere_per_network"),
             (["results", "executive_boundary_matched"], "near_minus_elsewhere_per_network")]
    for group in ("relative", "against_baselines"):
        for name in chk.get(["results", "occlusion", group]) or {}:
            tests.append((["results", "occlusion", group, name], "per_network"))
    for base, key in tests:
        vals = chk.get(base + [key])
        vals = list(vals.values()) if isinstance(vals, dict) else vals
        if not vals or len(vals) < 2 or chk.get(base + ["difference"]) is None:
            continue
        chk.tree(base + ["difference"], diff_fields(paired(vals, np.zeros(len(vals)))), "internal")
    print("  not recomputable from trials.csv: contribution_over_time, executive_boundary "
          "(per-network values, permutation p), occlusion scores")


# ---------------------------------------------------------------- main

def report_dirs(path):
    for cand in (path, os.path.join(path, "report")):
        if all(os.path.exists(os.path.join(cand, f)) for f in ("trials.csv", "summary.json")):
            return [cand]
    found = []
    for e in ("robustness", "uncertainty", "hierarchy"):
        found += report_dirs(os.path.join(path, e)) if os.path.isdir(os.path.join(path, e)) else []
    return found


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("paths", nargs="+", help="report folder(s), or folders holding them")
    ap.add_argument("--rel", type=float, default=1e-9, help="relative tolerance (default 1e-9)")
    ap.add_argument("--abs", type=float, default=1e-15, help="absolute tolerance (default 1e-15)")
    args = ap.parse_args()
    dirs = [d for p in args.paths for d in report_dirs(p)]
    if not dirs:
        sys.exit(f"no report folder (trials.csv + summary.json) under {args.paths}")
    table, failed = [], False
    for d in dirs:
        summary = json.load(open(os.path.join(d, "summary.json")))
        exp = summary.get("experiment")
        if exp not in ("robustness", "uncertainty", "hierarchy"):
            print(f"\n{d}: experiment {exp!r} is not checked here (interference: recheck-interference.py)")
            continue
        rows, diverged = load(os.path.join(d, "trials.csv"))
        print(f"\n################ {exp} ({summary.get('scale')} scale): {d}")
        print(f"  {len(rows)} runs with scores, {diverged} diverged (left out); "
              f"summary lists {len(summary.get('diverged', []))} diverged")
        gated, gate_bad = recheck_gate.recheck(os.path.join(d, "trainings.csv"), summary)
        chk = Checker(summary, args.rel, args.abs, gated)
        for b in gate_bad:
            chk._record(["gate"], "validity gate", False, b, "trainings.csv")
        {"robustness": robustness, "uncertainty": uncertainty, "hierarchy": hierarchy}[exp](rows, chk)
        left = chk.not_compared(None)
        figures = sum(chk.count.values()) - chk.count.get("labels", 0)
        bad = sum(1 for b in chk.bad if b[0] != "labels")
        print(f"  == compared: " + ", ".join(f"{v} {k}" for k, v in chk.count.items())
              + f"; largest relative difference (exact figures) {chk.worst:.2e}")
        if left:  # grouped by their first three path components
            groups = sorted({"/".join(p.split("/")[:3]) for p in left})
            print("  numeric fields of results not compared: " + ", ".join(
                f"{g} ({sum(p.startswith(g + '/') or p == g for p in left)})" for g in groups))
        for kind, p, o, r, rel in chk.bad:
            o = float(o) if isinstance(o, (np.floating, np.integer)) else o
            print(f"  MISMATCH ({kind}) {p}: ours {o!r} vs summary {r!r} (rel {rel:.2e})")
        failed |= bool(chk.bad)
        table.append((exp, summary.get("scale"), figures, figures - bad, chk.worst))
    if not table:
        sys.exit("nothing checked: no robustness, uncertainty or hierarchy report among the paths")
    print("\n== experiment / scale: figures compared, agreeing, largest relative difference")
    for exp, scale, total, ok, worst in table:
        print(f"   {exp:12s} {scale:10s} {total:5d} {ok:5d}   {worst:.2e}")
    print("   all agree" if not failed else "   DISAGREEMENTS above")
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
