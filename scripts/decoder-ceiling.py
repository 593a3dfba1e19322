#!/usr/bin/env python3
"""What a k-wide image decoder can draw on a caresim dataset (docs/results/README.md).

The paper's vision read-out ends in a linear layer from 50 hidden units to the 32,256
pixel values, then tanh: before the tanh, whatever the network infers, its 64x64 images lie
in a 50-dimensional affine subspace. Three figures per width k (50, 100, 200, 400), over
all 64x64 values and over the changing pixels (a channel moving by more than 8 of 255
levels since the previous frame), beside copying the previous frame and the mean image:

- *the test frames' own best k-dimensional code* (their principal components): no image set
  in a k-dimensional affine subspace reconstructs the test frames better. A bound for a
  linear output layer; the paper's tanh bends the subspace into a curved k-dimensional
  surface, which can come closer, so for the paper's read-out it is an approximation;
- *the learning frames' best k-dimensional code* (the test frames projected on the learning
  frames' principal components): what PCA of the learning data reconstructs. It is not a
  bound on a decoder (a network need not draw with the learning frames' principal
  components), and it falls as the learning data grows: printed for 1, 2, ... learning
  sequences per task and bed height (6, 12, 18 on the paper's dataset);
- `--fig6a`: the repositioning test frames on the principal components of the learning
  frames of repositioning's 9 sequences plus 0 / 3 / 6 / 9 of wiping's (the interference
  experiment's conditions: 3 = one per bed height, 6 = two), at k = 50, 100, 200: how much
  of Fig 6A's rise with no training at all a fixed-width linear code shows.

Errors in the model's units (v / 255 * 1.8 - 0.9), pooled over the test frames after each
sequence's first.

    python3 scripts/decoder-ceiling.py DATASET_DIR [--fig6a]
"""
import json
import sys

import numpy as np
from safetensors.numpy import load_file

WIDTHS = [50, 100, 200, 400]


def frames(dataset, manifest, keep):
    out = []
    for s in manifest["sequences"]:
        if keep(s):
            images = load_file(f"{dataset}/{s['file']}")["images"]  # [T, cameras, S, S, 3]
            x = images.astype(np.float32) / 255 * 1.8 - 0.9
            out.append(x.reshape(x.shape[0], -1))
    return out


class Codes:
    """Principal components of a set of frames, from the (frames x frames) Gram matrix:
    cheaper than an SVD of the (frames x pixels) one."""

    def __init__(self, frames):
        self.mean = frames.mean(0)
        centred = frames - self.mean
        w, v = np.linalg.eigh((centred @ centred.T).astype(np.float64))
        order = np.argsort(w)[::-1]
        self.w, self.v, self.centred = w[order], v[:, order], centred

    def project(self, x, k):
        k = min(k, int((self.w > 1e-9 * self.w[0]).sum()))
        basis = ((self.centred.T @ self.v[:, :k]) / np.sqrt(self.w[:k])).astype(np.float32)
        return (x - self.mean) @ basis @ basis.T + self.mean


def scorer(test):
    threshold = 8 / 255 * 1.8
    target = np.concatenate([x[1:] for x in test])
    moved = np.concatenate(
        [
            np.repeat(
                (np.abs(x[1:] - x[:-1]).reshape(x.shape[0] - 1, -1, 3).max(2) > threshold), 3, axis=1
            )
            for x in test
        ]
    )

    def line(name, prediction):
        e = (prediction - target) ** 2
        print(f"{name:60s} all {e.mean():.5f}   changing {e[moved].mean():.5f}", flush=True)
        return e.mean()

    return target, line


def ceilings(dataset, manifest):
    learn = frames(dataset, manifest, lambda s: s["split"] == "learn")
    test = frames(dataset, manifest, lambda s: s["split"] == "test")
    target, line = scorer(test)
    print(f"{sum(len(x) for x in learn)} learning frames in {len(learn)} sequences, "
          f"{len(target)} test frames, 64x64 x {len(manifest['cameras'])} cameras")
    line("previous frame", np.concatenate([x[:-1] for x in test]))
    everything = np.concatenate(learn)
    line("mean learning image", np.broadcast_to(everything.mean(0), target.shape))
    own = Codes(target)
    for k in WIDTHS:
        line(f"test frames' own best {k}-dim code (bound, linear output)", own.project(target, k))
    del own
    learn_specs = [s for s in manifest["sequences"] if s["split"] == "learn"]
    cells = len({(s["task"], s.get("bed_height_mm")) for s in learn_specs})
    for per_cell in range(1, len(learn_specs) // cells + 1):
        names = balanced(manifest, per_cell)
        chosen = [x for s, x in zip(learn_specs, learn) if s["name"] in names]
        codes = Codes(np.concatenate(chosen))
        for k in WIDTHS:
            line(f"learning PCA, {len(chosen)} sequences, k = {k}", codes.project(target, k))


def balanced(manifest, per_height, task=None):
    """The first `per_height` learning sequences of every task (or `task`) and bed height."""
    chosen, seen = set(), {}
    for s in manifest["sequences"]:
        if s["split"] == "learn" and task in (None, s["task"]):
            cell = (s["task"], s.get("bed_height_mm"))
            if seen.get(cell, 0) < per_height:
                chosen.add(s["name"])
                seen[cell] = seen.get(cell, 0) + 1
    return chosen


def fig6a(dataset, manifest):
    def pick(task, per_height):
        return balanced(manifest, per_height, task)

    repositioning = pick("repositioning", 3)
    test = frames(dataset, manifest, lambda s: s["split"] == "test" and s["task"] == "repositioning")
    target, line = scorer(test)
    print(f"\nFig 6A without training: repositioning's {len(target)} test frames")
    for k in [50, 100, 200]:
        errors = []
        for added in [0, 1, 2, 3]:
            names = repositioning | pick("wiping", added)
            codes = Codes(np.concatenate(frames(dataset, manifest, lambda s: s["name"] in names)))
            errors.append(line(f"k = {k}, repositioning 9 + wiping {3 * added}", codes.project(target, k)))
        print(f"{'':60s} 0 -> 9 added: {100 * (errors[-1] / errors[0] - 1):+.1f}%")


def main():
    args = sys.argv[1:]
    if not args or len(args) > 2 or (len(args) == 2 and args[1] != "--fig6a"):
        sys.exit(__doc__)
    dataset = args[0]
    manifest = json.load(open(f"{dataset}/dataset.json"))
    ceilings(dataset, manifest)
    if "--fig6a" in args:
        fig6a(dataset, manifest)


if __name__ == "__main__":
    main()
