#!/usr/bin/env python3
"""Independent re-computation of the interference experiment's statistics from the
tidy trials.csv written by `pvrnn experiment interference` (report.md, "Multitask
interference").

Usage:
    python3 scripts/recheck-interference.py TRIALS_CSV [--summary SUMMARY_JSON] [--networks 5]

Definitions (from report.md / docs/experiments.md, re-implemented here):
  * measures per trial:
      pooled         = MSE over all sensory dims: dims-weighted mean of error_vision16,
                       error_vision32, error_vision64 (2 cameras x 3 channels x r^2 each:
                       1536, 6144, 24576) and error_proprio (28 dims) -> 32284 dims
      vision         = error_vision64
      proprioception = error_proprio
      equal weight   = (error_vision64 + error_proprio) / 2
  * per network: mean over test sequences of the mean over trials (diverged runs,
    i.e. rows with diverged_at_step set / empty errors, are left out)
  * per direction (primary task), conditions = 0/3/6/9 of the other task added,
    independent groups of networks:
      - one-way ART ANOVA = one-way ANOVA of the ranks of all networks' values
      - ART-C contrasts: mean-rank differences, t with the ANOVA's within MS and df,
        Holm-adjusted over the 6 pairs; Cohen's d (pooled SD) and the raw difference
        with its 95% CI (Student t, pooled variance)
      - most added - none: difference, 95% CI, Cohen's d, detectable
        = (t_.975 + t_.80) * SE (df = n1+n2-2)
      - TOST of most added vs none against +-10% of none's mean: 90% CI and the larger
        one-sided p; equivalent when p < 0.05
  * asymmetry (both directions complete): per direction the log ratio of the
    geometric means (most added / none); Welch t of second's (wiping) minus first's
    (repositioning) log ratio over the four groups' variances, Welch-Satterthwaite df,
    95% CI, detectable.
"""
import argparse
import csv
import json
import math
import os
import re
import sys
from collections import defaultdict

import numpy as np
from scipy import stats
from scipy.optimize import brentq

import recheck_gate  # scripts/recheck_gate.py

ALPHA, POWER, MARGIN = 0.05, 0.80, 0.10
CAMERAS, CHANNELS, RESOLUTIONS, PROPRIO_DIMS = 2, 3, (16, 32, 64), 28
MEASURES = ["pooled", "vision", "proprioception", "equal weight"]
DIRECTIONS = ["repositioning", "wiping"]  # plan order: first, second


def dims():
    vis = {r: CAMERAS * CHANNELS * r * r for r in RESOLUTIONS}
    return vis, sum(vis.values()) + PROPRIO_DIMS


def measures_of(row):
    """The four measures of one trial row, or None when it has no scores."""
    try:
        v = {r: float(row[f"error_vision{r}"]) for r in RESOLUTIONS}
        p = float(row["error_proprio"])
    except (KeyError, ValueError):
        return None
    vis, total = dims()
    pooled = (sum(v[r] * vis[r] for r in RESOLUTIONS) + p * PROPRIO_DIMS) / total
    top = v[RESOLUTIONS[-1]]
    out = {"pooled": pooled, "vision": top, "proprioception": p,
           "equal weight": (top + p) / 2}
    return out if all(math.isfinite(x) for x in out.values()) else None


def parse_training(label):
    """'repositioning 9 + wiping 3' -> ('repositioning', 3)."""
    m = re.fullmatch(r"\s*(\S+)\s+\d+\s*\+\s*\S+\s+(\d+)\s*", label)
    if not m:
        raise ValueError(f"unexpected training label {label!r}")
    return m.group(1), int(m.group(2))


def sig(x, n=4):
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "nan"
    return f"{x:.{n}g}" if abs(x) >= 1e-3 or x == 0 else f"{x:.{n - 1}e}"


def pfmt(p):
    return "< 0.0001" if p < 1e-4 else f"{p:.4f}"


# ---------------------------------------------------------------- data

def load(path):
    rows = list(csv.DictReader(open(path, newline="")))
    # direction -> added -> label, and network -> list of (sequence, trial, measures|None)
    data = defaultdict(lambda: defaultdict(lambda: defaultdict(list)))
    labels = {}
    seqs = defaultdict(set)
    trials = defaultdict(set)
    for r in rows:
        primary, added = parse_training(r["training"])
        if r["task"] != primary:
            continue  # only the primary task's test sequences
        labels[(primary, added)] = r["training"]
        seqs[primary].add(r["sequence"])
        trials[primary].add(r["trial"])
        m = None if r.get("diverged_at_step") else measures_of(r)
        data[primary][added][int(r["network"])].append((r["sequence"], r["trial"], m))
    return data, labels, seqs, trials


def per_network(runs):
    """Mean over sequences of the mean over trials, per measure."""
    out = {}
    for name in MEASURES:
        by_seq = defaultdict(list)
        for seq, _, m in runs:
            if m is not None:
                by_seq[seq].append(m[name])
        out[name] = float(np.mean([np.mean(v) for v in by_seq.values()])) if by_seq else float("nan")
    return out


def trainings_done(trials_path):
    path = os.path.join(os.path.dirname(os.path.abspath(trials_path)), "trainings.csv")
    if not os.path.exists(path):
        return None
    done = defaultdict(int)
    for r in csv.DictReader(open(path, newline="")):
        done[parse_training(r["training"])] += 1
    return done


# ---------------------------------------------------------------- statistics

def holm(p):
    p = np.asarray(p, float)
    order = np.argsort(p, kind="stable")
    m = len(p)
    adj = np.empty(m)
    run = 0.0
    for k, i in enumerate(order):
        run = max(run, min(1.0, (m - k) * p[i]))
        adj[i] = run
    return adj


def pooled_sd(a, b):
    return math.sqrt(((len(a) - 1) * np.var(a, ddof=1) + (len(b) - 1) * np.var(b, ddof=1))
                     / (len(a) + len(b) - 2))


def two_group(a, b):
    """a - b, independent groups (Student t)."""
    a, b = np.asarray(a), np.asarray(b)
    res = stats.ttest_ind(a, b, equal_var=True)
    df = len(a) + len(b) - 2
    sd = pooled_sd(a, b)
    se = sd * math.sqrt(1 / len(a) + 1 / len(b))
    ci = res.confidence_interval(1 - ALPHA)
    diff = a.mean() - b.mean()
    detectable = (stats.t.ppf(1 - ALPHA / 2, df) + stats.t.ppf(POWER, df)) * se
    # For comparison only: the exact difference with 80% power (noncentral t).
    tc = stats.t.ppf(1 - ALPHA / 2, df)
    def power(nc):
        # The lower tail is negligible at large nc, where scipy's nct.cdf can give NaN
        # at few degrees of freedom (3 networks per group).
        lower = stats.nct.cdf(-tc, df, nc)
        return stats.nct.sf(tc, df, nc) + (lower if math.isfinite(lower) else 0.0) - POWER
    exact = brentq(power, 0.1, 10.0) * se
    return dict(diff=diff, ci=(ci.low, ci.high), d=diff / sd, t=res.statistic, p=res.pvalue,
                df=df, se=se, detectable=detectable, detectable_exact=exact)


def tost(a, b, margin):
    a, b = np.asarray(a), np.asarray(b)
    lo = stats.ttest_ind(a + margin, b, alternative="greater").pvalue  # H0: diff <= -margin
    hi = stats.ttest_ind(a - margin, b, alternative="less").pvalue     # H0: diff >= +margin
    ci = stats.ttest_ind(a, b).confidence_interval(1 - 2 * ALPHA)
    p = max(lo, hi)
    return dict(margin=margin, ci90=(ci.low, ci.high), p=p, equivalent=p < ALPHA)


def art_one_way(groups):
    """One-way ART (= ANOVA of ranks) with ART-C pairwise contrasts, Holm-adjusted."""
    allv = np.concatenate(groups)
    ranks = stats.rankdata(allv)  # average ranks for exact ties
    sizes = [len(g) for g in groups]
    rg = np.split(ranks, np.cumsum(sizes)[:-1])
    f = stats.f_oneway(*rg)
    k, n = len(groups), len(allv)
    df1, df2 = k - 1, n - k
    means = [g.mean() for g in rg]
    ss_w = sum(((g - g.mean()) ** 2).sum() for g in rg)
    ss_b = sum(len(g) * (g.mean() - ranks.mean()) ** 2 for g in rg)
    ms_w = ss_w / df2
    contrasts = []
    for i in range(k):
        for j in range(i + 1, k):
            rd = means[i] - means[j]
            t = rd / math.sqrt(ms_w * (1 / sizes[i] + 1 / sizes[j]))
            p = 2 * stats.t.sf(abs(t), df2)
            raw = two_group(groups[i], groups[j])
            contrasts.append(dict(i=i, j=j, rank_diff=rd, t=t, p=p, d=raw["d"],
                                  diff=raw["diff"], ci=raw["ci"]))
    for c, adj in zip(contrasts, holm([c["p"] for c in contrasts])):
        c["p_holm"] = adj
    return dict(F=f.statistic, df=(df1, df2), p=f.pvalue, eta2=ss_b / (ss_b + ss_w),
                contrasts=contrasts)


def asymmetry(first, second):
    """first/second: (none, most) arrays. Welch t of second's log ratio - first's."""
    groups = [np.log(np.asarray(g)) for g in (*first, *second)]
    v = [g.var(ddof=1) / len(g) for g in groups]
    lr = [groups[1].mean() - groups[0].mean(), groups[3].mean() - groups[2].mean()]
    diff = lr[1] - lr[0]
    var = sum(v)
    se = math.sqrt(var)
    df = var ** 2 / sum(vi ** 2 / (len(g) - 1) for vi, g in zip(v, groups))
    t = diff / se
    tq = stats.t.ppf(1 - ALPHA / 2, df)
    return dict(log_ratio=lr, change=[math.expm1(x) for x in lr], diff=diff,
                ci=(diff - tq * se, diff + tq * se), t=t, df=df,
                p=2 * stats.t.sf(abs(t), df),
                detectable=(tq + stats.t.ppf(POWER, df)) * se)


# ---------------------------------------------------------------- comparison with summary.json

class Checker:
    def __init__(self, summary):
        self.s = summary["results"] if summary else None
        self.worst = 0.0
        self.count = 0
        self.bad = []

    def get(self, path):
        node = self.s
        for k in path:
            if node is None:
                return None
            try:
                node = node[k]
            except (KeyError, IndexError, TypeError):
                return None
        return node

    def check(self, path, ours):
        if self.s is None:
            return
        ref = self.get(path)
        if ref is None:
            return
        if isinstance(ref, bool):
            ok = ref == ours
            rel = 0.0 if ok else 1.0
        else:
            ref = float(ref)
            rel = abs(ours - ref) / max(abs(ref), 1e-300) if ref != ours else 0.0
            # p-values far below 1e-4 are printed as "< 0.0001"; compare absolutely there
            if path[-1] in ("p", "p_holm") and max(abs(ref), abs(ours)) < 1e-4:
                rel = min(rel, abs(ours - ref) * 1e4)
        self.count += 1
        self.worst = max(self.worst, rel)
        if rel > 1e-6:
            self.bad.append(("/".join(map(str, path)), ours, ref, rel))

    def report(self):
        if self.s is None:
            return
        print(f"\n== comparison with summary.json: {self.count} values compared, "
              f"largest relative difference {self.worst:.2e}")
        for p, o, r, rel in self.bad:
            print(f"   MISMATCH {p}: ours {o!r} vs summary {r!r} (rel {rel:.2e})")
        if not self.bad:
            print("   all agree to within 1e-6 (relative)")
        return not self.bad


# ---------------------------------------------------------------- main

def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("trials_csv")
    ap.add_argument("--summary", help="summary.json to compare every number against "
                    "(default: the one beside trials.csv, if any; 'none' to skip)")
    ap.add_argument("--networks", type=int, default=5, help="networks per condition (design)")
    ap.add_argument("--conditions", default="0,3,6,9", help="sequences added (design)")
    args = ap.parse_args()
    design_added = [int(x) for x in args.conditions.split(",")]

    spath = args.summary
    if spath is None:
        cand = os.path.join(os.path.dirname(os.path.abspath(args.trials_csv)), "summary.json")
        spath = cand if os.path.exists(cand) else None
    summary = json.load(open(spath)) if spath and spath != "none" else None
    chk = Checker(summary)

    data, labels, seqs, trials = load(args.trials_csv)
    trained = trainings_done(args.trials_csv)
    vis, total = dims()
    print(f"pooled = dims-weighted MSE over {total} dims "
          f"(vision16 {vis[16]}, vision32 {vis[32]}, vision64 {vis[64]}, proprio {PROPRIO_DIMS})")

    ends = {}
    for primary in DIRECTIONS:
        print(f"\n################ primary task: {primary}")
        expected_runs = len(seqs[primary]) * len(trials[primary])
        groups = {m: [] for m in MEASURES}
        complete = True
        cond_labels = []
        for added in design_added:
            label = labels.get((primary, added), f"{primary} 9 + ? {added}")
            cond_labels.append(label)
            nets = data[primary].get(added, {})
            full = [n for n, runs in nets.items() if len(runs) >= expected_runs]
            partial = [n for n, runs in nets.items() if len(runs) < expected_runs]
            if len(full) < args.networks:
                complete = False
            values = {n: per_network(runs) for n, runs in sorted(nets.items())}
            tr = "" if trained is None else f", {trained.get((primary, added), 0)} trained"
            flag = f"  [partial networks: {partial}]" if partial else ""
            print(f"\n{label}: {len(full)} of {args.networks} networks with all "
                  f"{expected_runs} runs{tr}{flag}")
            k = design_added.index(added)
            for m in MEASURES:
                v = np.array([values[n][m] for n in sorted(values)])
                groups[m].append(v)
                for idx, x in enumerate(v):
                    chk.check([primary, "per_network", MEASURES.index(m), k, idx], x)
                se = v.std(ddof=1) / math.sqrt(len(v)) if len(v) > 1 else float("nan")
                print(f"  {m:15s} nets " + " ".join(f"{x:.6g}" for x in v)
                      + f"   mean {sig(v.mean() if len(v) else float('nan'))} ± {sig(se)}")
        if not complete:
            print(f"\n!! {primary} direction INCOMPLETE: no tests (descriptive means only)")
            continue
        ends[primary] = {m: (groups[m][0], groups[m][-1]) for m in MEASURES}

        print(f"\n-- tests ({cond_labels[-1]} vs {cond_labels[0]}; ART over the {len(design_added)} conditions)")
        for m in MEASURES:
            g = groups[m]
            none, most = g[0], g[-1]
            art = art_one_way(g)
            eff = two_group(most, none)
            eq = tost(most, none, MARGIN * abs(none.mean()))
            print(f"\n[{m}]")
            print(f"  ART F({art['df'][0]}, {art['df'][1]}) = {art['F']:.4g}, p = {art['p']:.4g}"
                  f", eta^2 = {art['eta2']:.4g}")
            base = [primary, "art", m]
            chk.check(base + ["effect", "f"], art["F"])
            chk.check(base + ["effect", "p"], art["p"])
            chk.check(base + ["effect", "partial_eta_squared"], art["eta2"])
            for ci, c in enumerate(art["contrasts"]):
                print(f"    {design_added[c['i']]} vs {design_added[c['j']]}: rank diff {c['rank_diff']:+.3f}"
                      f", t = {c['t']:.4g}, p = {pfmt(c['p'])}, p(Holm) = {pfmt(c['p_holm'])}"
                      f", d = {c['d']:.4g}, raw {sig(c['diff'])} [{sig(c['ci'][0])}, {sig(c['ci'][1])}]")
                cb = base + ["contrasts", ci]
                for key, val in [("rank_difference", c["rank_diff"]), ("t", c["t"]), ("p", c["p"]),
                                 ("p_holm", c["p_holm"]), ("cohen_d", c["d"])]:
                    chk.check(cb + [key], val)
                chk.check(cb + ["difference", "mean"], c["diff"])
                chk.check(cb + ["difference", "ci95", 0], c["ci"][0])
                chk.check(cb + ["difference", "ci95", 1], c["ci"][1])
            print(f"  effect {design_added[-1]} added - none = {sig(eff['diff'])} "
                  f"[{sig(eff['ci'][0])}, {sig(eff['ci'][1])}] (95%), d = {eff['d']:.4g}, "
                  f"Student t({eff['df']}) = {eff['t']:.4g}, p = {pfmt(eff['p'])}")
            print(f"  detectable (80% power, (t.975+t.80)xSE) = ±{sig(eff['detectable'])}"
                  f"   [exact noncentral-t: ±{sig(eff['detectable_exact'])}]")
            print(f"  TOST vs ±{sig(eq['margin'])}: 90% CI [{sig(eq['ci90'][0])}, {sig(eq['ci90'][1])}]"
                  f", p = {eq['p']:.4g} -> {'EQUIVALENT' if eq['equivalent'] else 'not equivalent'}")
            mb = [primary, "most_minus_none", m]
            for key, val in [("mean", eff["diff"]), ("cohen_d", eff["d"]),
                             ("detectable", eff["detectable"]), ("p", eff["p"])]:
                chk.check(mb + [key], val)
            chk.check(mb + ["ci95", 0], eff["ci"][0])
            chk.check(mb + ["ci95", 1], eff["ci"][1])
            qb = [primary, "equivalence", m]
            for key, val in [("margin", eq["margin"]), ("p", eq["p"]), ("equivalent", eq["equivalent"])]:
                chk.check(qb + [key], val)
            chk.check(qb + ["ci90", 0], eq["ci90"][0])
            chk.check(qb + ["ci90", 1], eq["ci90"][1])

    print(f"\n################ asymmetry ({DIRECTIONS[1]}'s log ratio - {DIRECTIONS[0]}'s, none -> {design_added[-1]} added)")
    if not all(d in ends for d in DIRECTIONS):
        missing = [d for d in DIRECTIONS if d not in ends]
        print(f"!! not tested: direction(s) {missing} incomplete")
    else:
        for m in MEASURES:
            a = asymmetry(ends[DIRECTIONS[0]][m], ends[DIRECTIONS[1]][m])
            print(f"  [{m}] change {DIRECTIONS[0]} {100 * a['change'][0]:+.2f}%, "
                  f"{DIRECTIONS[1]} {100 * a['change'][1]:+.2f}%; difference of log ratios "
                  f"{a['diff']:.4g} [{a['ci'][0]:.4g}, {a['ci'][1]:.4g}], Welch t = {a['t']:.4g}, "
                  f"df = {a['df']:.4g}, p = {pfmt(a['p'])}, detectable ±{a['detectable']:.4g}")
            ab = ["asymmetry", "measures", m]
            for key, val in [("difference", a["diff"]), ("t", a["t"]), ("df", a["df"]),
                             ("p", a["p"]), ("detectable", a["detectable"])]:
                chk.check(ab + [key], val)
            for i in (0, 1):
                chk.check(ab + ["log_ratio", i], a["log_ratio"][i])
                chk.check(ab + ["ci95", i], a["ci"][i])
        if summary is not None and chk.get(["asymmetry"]) is None:
            print("  (summary.json has no asymmetry result to compare with)")
    gate_bad = []
    trainings = os.path.join(os.path.dirname(os.path.abspath(args.trials_csv)), "trainings.csv")
    if summary is not None and os.path.exists(trainings):
        _, gate_bad = recheck_gate.recheck(trainings, summary)
        for b in gate_bad:
            print(f"  MISMATCH (validity gate) {b}")
    if chk.report() is False or gate_bad:
        sys.exit(1)


if __name__ == "__main__":
    main()
