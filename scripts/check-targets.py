#!/usr/bin/env python3
"""Checks a model against the shipping targets of docs/results/README.md ("Targets"),
pre-specified before the model was chosen, from three `pvrnn evaluate` reports on the
same sequences (2 trials each):

    python3 scripts/check-targets.py EVAL_16_PROPRIO EVAL_ALL EVAL_16_NO_PROPRIO

Each report folder holds `summary.json`, whose per-sequence figures average each sequence's
trials; the unit of every statistic is the sequence. Ratios are geometric means over sequences with a
95% t-interval, and a two-sided paired t-test on the log ratios (H0: ratio 1); n is small
(6 test sequences), so the intervals are wide and are the thing to read.
"""
import json
import math
import statistics
import sys
from collections import defaultdict

# Two-sided 95% quantiles of Student's t (df 1..30); larger df use the normal's.
T975 = [12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179,
        2.160, 2.145, 2.131, 2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064,
        2.060, 2.056, 2.052, 2.048, 2.045, 2.042]


def t_two_sided_p(t, df):
    """P(|T| > |t|) for Student's t with df degrees of freedom (regularised incomplete beta
    by its continued fraction, Numerical Recipes' betacf)."""
    x = df / (df + t * t)
    a, b = df / 2, 0.5

    def betacf(a, b, x):
        tiny = 1e-300
        qab, qap, qam = a + b, a + 1, a - 1
        c, d = 1.0, 1 - qab * x / qap
        d = 1 / (d if abs(d) > tiny else tiny)
        h = d
        for m in range(1, 300):
            m2 = 2 * m
            for aa in (m * (b - m) * x / ((qam + m2) * (a + m2)),
                       -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2))):
                d = 1 + aa * d
                d = 1 / (d if abs(d) > tiny else tiny)
                c = 1 + aa / c
                c = c if abs(c) > tiny else tiny
                h *= d * c
            if abs(d * c - 1) < 1e-13:
                break
        return h

    lbeta = math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b)
    front = math.exp(lbeta + a * math.log(x) + b * math.log(1 - x))
    if x < (a + 1) / (a + b + 2):
        return front * betacf(a, b, x) / a
    return 1 - front * betacf(b, a, 1 - x) / b


def read(folder):
    """{(target, source, group, pixels): {sequence: its mean over trials}} from the report's
    per-sequence figures, and each sequence's task."""
    summary = json.load(open(f"{folder}/summary.json"))
    tasks = {s["name"]: s["task"] for s in summary["sequences"]}
    means = defaultdict(dict)
    for f in summary["figures"]:
        if f["scope"].startswith("sequence:"):
            key = (f["target"], f["source"], f["group"], f["pixels"])
            means[key][f["scope"].split(":", 1)[1]] = f["mean"]
    return means, tasks


def ratio_stats(a, b):
    """Geometric-mean ratio a/b over the sequences both have, its 95% CI and paired p."""
    seqs = sorted(set(a) & set(b))
    logs = [math.log(a[s] / b[s]) for s in seqs]
    n = len(logs)
    mean = statistics.fmean(logs)
    if n < 2:
        return math.exp(mean), None, None, n
    se = statistics.stdev(logs) / math.sqrt(n)
    q = T975[n - 2] if n - 1 <= len(T975) else 1.96
    p = t_two_sided_p(mean / se, n - 1) if se > 0 else 0.0
    return math.exp(mean), (math.exp(mean - q * se), math.exp(mean + q * se)), p, n


def describe(a, b):
    r, ci, p, n = ratio_stats(a, b)
    if ci is None:
        return f"x{r:.3f} (n = {n})"
    return f"x{r:.3f} [95% CI {ci[0]:.3f}, {ci[1]:.3f}], paired t on log ratios p = {p:.3g}, n = {n}"


def main():
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    v16, tasks = read(sys.argv[1])
    vall, _ = read(sys.argv[2])
    v16off, _ = read(sys.argv[3])
    top = "v64"
    model = lambda m, target="recon", pixels="all": m[(target, "model", top, pixels)]
    base = lambda m, source, target="recon", pixels="all": m[(target, source, top, pixels)]
    lines = []

    def verdict(name, ok, detail):
        lines.append((name, ok))
        print(f"- **{name}**: {'met' if ok else 'MISSED'}. {detail}")

    m16, up = model(v16), base(v16, "upsample")
    overall = statistics.fmean(m16.values()) / statistics.fmean(up.values())
    worst = max(m16[s] / up[s] for s in m16)
    verdict(
        "T1 64x64 from 16x16 + proprioception at most 0.5x bilinear upsampling overall, below 1.0x on every sequence",
        overall <= 0.5 and worst < 1.0,
        f"overall x{overall:.3f} (means over sequences); per sequence "
        + ", ".join(f"{s} x{m16[s] / up[s]:.3f}" for s in sorted(m16))
        + f"; geometric mean {describe(m16, up)}.",
    )
    for source in ["upsample_detail", "nearest"]:
        if ("recon", source, top, "all") not in v16:
            print(f"- T2 ({source}): not in this report (written before that baseline existed)")
            continue
        b = base(v16, source)
        per_task = {}
        for task in sorted(set(tasks.values())):
            seqs = [s for s in m16 if tasks[s] == task]
            per_task[task] = (statistics.fmean(m16[s] for s in seqs), statistics.fmean(b[s] for s in seqs))
        verdict(
            f"T2 better than {source} on both tasks (16x16 + proprioception)",
            all(m < bb for m, bb in per_task.values()),
            "; ".join(f"{t}: model {m:.5f} vs {bb:.5f} (x{m / bb:.3f})" for t, (m, bb) in per_task.items())
            + f"; wins {sum(m16[s] < b[s] for s in m16)} of {len(m16)} sequences; all sequences {describe(m16, b)}.",
        )
    mall = model(vall)
    r_all = statistics.fmean(mall.values()) / statistics.fmean(m16.values())
    verdict(
        "T3 everything observed at least 15% better than 16x16 + proprioception",
        r_all <= 0.85,
        f"x{r_all:.3f} (means over sequences); {describe(mall, m16)}.",
    )
    moff = model(v16off)
    wins = sum(m16[s] < moff[s] for s in m16)
    verdict(
        "T4 proprioception on better than off at 16x16 on at least 5 of 6 sequences",
        wins >= 5,
        f"on better on {wins} of {len(m16)}; on / off {describe(m16, moff)}.",
    )
    nxt = model(vall, "next", "changing")
    prev = base(vall, "previous", "next", "changing")
    r_next = statistics.fmean(nxt.values()) / statistics.fmean(prev.values())
    verdict(
        "T6 one-step prediction with everything observed better than the previous frame on changing pixels",
        r_next < 1.0,
        f"x{r_next:.3f} (means over sequences); {describe(nxt, prev)}.",
    )
    failures = {
        name: len(json.load(open(f"{folder}/summary.json")).get("failures", []))
        for name, folder in zip(["16x16 + proprioception", "everything", "16x16 alone"], sys.argv[1:])
    }
    verdict(
        "T5 no diverged trial",
        not any(failures.values()),
        "; ".join(f"{name}: {n} trial(s) diverged beyond repair" for name, n in failures.items()) + ".",
    )
    print(f"\n{sum(ok for _, ok in lines)} of {len(lines)} checks met.")


if __name__ == "__main__":
    main()
