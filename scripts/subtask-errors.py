#!/usr/bin/env python3
"""Where a model wins and loses: its 64x64 reconstruction error against the baselines per
task and subtask, over all pixels and over the changing ones, from a `pvrnn evaluate`
report's per_step.csv (docs/results/README.md, "Where it loses").

    python3 scripts/subtask-errors.py EVAL_DIR [BASELINE ...]

BASELINE defaults to upsample and upsample_detail. Each cell is the mean over the
subtask's steps (and, for the model, its trials) of the per-step error; "x" is model /
baseline. Steps are pooled over the task's sequences, so this table describes where the
error is, not a test: the per-sequence statistics are in the report's summary.md.
"""
import csv
import sys
from collections import defaultdict


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    folder = sys.argv[1]
    baselines = sys.argv[2:] or ["upsample", "upsample_detail"]
    sums = defaultdict(lambda: [0.0, 0])  # (source, task, subtask, column) -> [sum, n]
    steps = defaultdict(set)  # (task, subtask) -> {(sequence, t)}
    order = []
    with open(f"{folder}/per_step.csv", newline="") as f:
        for row in csv.DictReader(f):
            if row["target"] != "recon":
                continue
            task = row["sequence"].split("_")[0]
            key = (task, row["subtask"])
            if key not in order:
                order.append(key)
            steps[key].add((row["sequence"], row["t"]))
            for column in ["v64", "v64_changing"]:
                if row[column]:
                    cell = sums[(row["source"], *key, column)]
                    cell[0] += float(row[column])
                    cell[1] += 1

    def mean(source, key, column):
        total, n = sums.get((source, *key, column), (0.0, 0))
        return total / n if n else None

    header = "| task | subtask | steps | pixels | model | " + " | ".join(baselines) + " |"
    print(header)
    print("|" + "---|" * (5 + len(baselines)))
    for key in order:
        for column, label in [("v64", "all"), ("v64_changing", "changing")]:
            model = mean("model", key, column)
            if model is None:
                continue
            cells = []
            for b in baselines:
                value = mean(b, key, column)
                cells.append("—" if value is None else f"{value:.4f} (x{model / value:.2f})")
            print(f"| {key[0]} | {key[1]} | {len(steps[key])} | {label} | {model:.4f} | "
                  + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
