#!/usr/bin/env python3
"""A dataset folder whose learning split comes from one dataset and whose test split is
every sequence of one task in another, linked, not copied: `pvrnn evaluate --split test`
on it scores a model on the second dataset's sequences against baselines (mean image,
upsampling with the mean image's detail, nearest frame) taken from the first one's
learning split, the model's own training data, instead of the scored dataset's.

    scripts/baseline-dataset.py LEARN_DATASET SCORED_DATASET TASK OUT

Example (the interference campaign's validation set, wiping, with the baselines of the
networks' training data; docs/results/experiments.md):

    scripts/baseline-dataset.py data/caresim-robotfree data/caresim-seed1 wiping /tmp/fair
    pvrnn --threads 1 evaluate --model NETWORK --inputs /tmp/fair --split test \
        --vision 16 --proprio on --trials 1 --seed 0 --out /tmp/fair-eval
"""
import json
import pathlib
import sys


def main() -> None:
    if len(sys.argv) != 5:
        sys.exit(__doc__)
    learn, scored, task, out = sys.argv[1:]
    learn, scored, out = (pathlib.Path(p).resolve() for p in (learn, scored, out))
    out.mkdir(parents=True, exist_ok=True)
    manifests = [json.loads((d / "dataset.json").read_text()) for d in (learn, scored)]
    sequences = []
    for prefix, folder, manifest, keep, split in (
        ("learn_", learn, manifests[0], lambda s: s["split"] == "learn", "learn"),
        ("scored_", scored, manifests[1], lambda s: True, "test"),
    ):
        for s in manifest["sequences"]:
            if s["task"] != task or not keep(s):
                continue
            linked = {**s, "name": prefix + s["name"], "file": prefix + s["file"], "split": split}
            link = out / linked["file"]
            if not link.exists():
                link.symlink_to(folder / s["file"])
            sequences.append(linked)
    if not any(s["split"] == "learn" for s in sequences):
        sys.exit(f"{learn}: no learning sequence of task `{task}`")
    if not any(s["split"] == "test" for s in sequences):
        sys.exit(f"{scored}: no sequence of task `{task}`")
    manifest = {**manifests[1], "sequences": sequences}
    manifest["source"] = f"learning split: {manifests[0].get('source')}; scored: {manifests[1].get('source')}, task {task}"
    (out / "dataset.json").write_text(json.dumps(manifest, indent=1) + "\n")
    print(f"{out}: {sum(s['split'] == 'learn' for s in sequences)} learning, "
          f"{sum(s['split'] == 'test' for s in sequences)} scored sequences")


main()
