#!/usr/bin/env python3
"""The ceiling of a k-wide image decoder on a caresim dataset (docs/results/README.md).

The paper's vision read-out ends in a linear layer from 50 hidden units to the 32,256
pixel values (then tanh): whatever the network infers, its 64x64 images lie near a
50-dimensional subspace. The best such subspace for the learning frames is their principal
components; giving each test frame its best code in it (its projection) bounds what any
50-wide decoder can reconstruct, however good the inference. Printed for k = 50, 100, 200,
400 over all 64x64 values and over the changing pixels (a channel moving by more than 8 of
255 levels since the previous frame), beside copying the previous frame and the mean image.
Errors in the model's units (v / 255 * 1.8 - 0.9), pooled over the test frames after each
sequence's first.

    python3 scripts/decoder-ceiling.py DATASET_DIR
"""
import json
import sys

import numpy as np
from safetensors.numpy import load_file


def frames(dataset, manifest, split):
    out = []
    for s in manifest["sequences"]:
        if s["split"] == split:
            images = load_file(f"{dataset}/{s['file']}")["images"]  # [T, cameras, S, S, 3]
            x = images.astype(np.float32) / 255 * 1.8 - 0.9
            out.append(x.reshape(x.shape[0], -1))
    return out


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    dataset = sys.argv[1]
    manifest = json.load(open(f"{dataset}/dataset.json"))
    learn = np.concatenate(frames(dataset, manifest, "learn"))
    test = frames(dataset, manifest, "test")
    threshold = 8 / 255 * 1.8
    target = np.concatenate([x[1:] for x in test])
    previous = np.concatenate([x[:-1] for x in test])
    moved = np.concatenate(
        [
            np.repeat(
                (np.abs(x[1:] - x[:-1]).reshape(x.shape[0] - 1, -1, 3).max(2) > threshold), 3, axis=1
            )
            for x in test
        ]
    )
    mean = learn.mean(0)
    centred = learn - mean
    # Principal directions from the (frames x frames) Gram matrix: cheaper than an SVD of
    # the (frames x pixels) one.
    w, v = np.linalg.eigh((centred @ centred.T).astype(np.float64))
    order = np.argsort(w)[::-1]
    w, v = w[order], v[:, order]

    def line(name, prediction):
        e = (prediction - target) ** 2
        print(f"{name:42s} all {e.mean():.5f}   changing {e[moved].mean():.5f}", flush=True)

    print(f"{len(learn)} learning frames, {len(target)} test frames, 64x64 x {manifest['cameras'].__len__()} cameras")
    line("previous frame", previous)
    line("mean learning image", np.broadcast_to(mean, target.shape))
    for k in [50, 100, 200, 400]:
        basis = ((centred.T @ v[:, :k]) / np.sqrt(w[:k])).astype(np.float32)
        line(f"best {k}-dimensional code (PCA of learning)", (target - mean) @ basis @ basis.T + mean)


if __name__ == "__main__":
    main()
