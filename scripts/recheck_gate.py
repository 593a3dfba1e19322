"""The validity gate rechecked from a report's trainings.csv, apart from the Rust code
(crates/pvrnn-eval/src/gate.rs; docs/experiments.md, "The validity gate").

A network passes when, on held-out data, it beats the strongest recorded baseline of every
measure (vision: held_out_vision < vision_baseline_error; joint angles and torques: the
one-step prediction < its baseline's error), no trial diverged and nothing was left
unrecorded; a loss to a recorded baseline (or a diverged trial) fails; otherwise it is
incomplete. A network without a held-out validation is "not gated". A report's findings
have verdicts only when every network passes.
"""
import csv
import math

MEASURES = [("held_out_vision", "vision_baseline_error"),
            ("held_out_joints_next", "joints_baseline_error"),
            ("held_out_torques_next", "torques_baseline_error")]


def _num(s):
    v = float(s) if s not in (None, "") else math.nan
    return v if math.isfinite(v) else None


def gate_of(row):
    if row.get("gate") == "not gated" and not row.get("held_out_vision"):
        return "not gated"
    lost = (_num(row.get("held_out_diverged")) or 0) > 0
    for model, baseline in MEASURES:
        m, b = _num(row.get(model)), _num(row.get(baseline))
        if m is not None and b is not None and m >= b:
            lost = True
    if lost:
        return "fail"
    return "incomplete" if row.get("not_recorded") else "pass"


def recheck(path, summary):
    """Recomputes every network's gate from trainings.csv; returns (all pass, mismatches)."""
    rows = list(csv.DictReader(open(path, newline="")))
    bad = []
    if rows and "gate" not in rows[0]:
        return False, [f"{path}: no gate column (a report written before the gate)"]
    for r in rows:
        ours = gate_of(r)
        if ours != r["gate"]:
            bad.append(f"{r['job']}: gate {r['gate']!r} in trainings.csv, {ours!r} recomputed")
    passing = sum(gate_of(r) == "pass" for r in rows)
    ref = summary.get("gate") or {}
    if (ref.get("passing"), ref.get("networks")) != (passing, len(rows)):
        bad.append(f"summary gate {ref} against {passing} of {len(rows)} passing in trainings.csv")
    print(f"  validity gate: {passing} of {len(rows)} networks pass (recomputed from trainings.csv)")
    return bool(rows) and passing == len(rows), bad
