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


def vision_passes(row):
    """The vision measure alone (what a finding about images needs)."""
    m, b = _num(row.get("held_out_vision")), _num(row.get("vision_baseline_error"))
    missing = any(part.strip().startswith("vision:") for part in row.get("not_recorded", "").split(";"))
    return ((_num(row.get("held_out_diverged")) or 0) == 0 and m is not None and b is not None
            and m < b and not missing)


def recheck(path, summary):
    """Recomputes every network's gate from trainings.csv; returns ({need: every network
    passes it}, mismatches), needs as summary.json's findings name them (`gate_needs`)."""
    rows = list(csv.DictReader(open(path, newline="")))
    bad = []
    if rows and "gate" not in rows[0]:
        return {}, [f"{path}: no gate column (a report written before the gate)"]
    for r in rows:
        ours = gate_of(r)
        if ours != r["gate"]:
            bad.append(f"{r['job']}: gate {r['gate']!r} in trainings.csv, {ours!r} recomputed")
    passing = sum(gate_of(r) == "pass" for r in rows)
    passing_vision = sum(vision_passes(r) for r in rows)
    ref = summary.get("gate") or {}
    ours = {"passing": passing, "passing_vision": passing_vision, "networks": len(rows)}
    if {k: ref.get(k) for k in ours} != ours:
        bad.append(f"summary gate {ref} against {ours} recomputed from trainings.csv")
    print(f"  validity gate: {passing} of {len(rows)} networks pass, {passing_vision} on vision "
          "(recomputed from trainings.csv)")
    every = bool(rows)
    return {"vision_and_proprioception": every and passing == len(rows),
            "vision": every and passing_vision == len(rows)}, bad
