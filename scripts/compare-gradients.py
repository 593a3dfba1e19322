#!/usr/bin/env python3
"""Compares two gradient files of `pvrnn free-energy --grads` (for example the CPU and the
wgpu backend on the same model and data): per tensor, max |a - b| / max |a|.

    scripts/compare-gradients.py cpu.safetensors gpu.safetensors [--tolerance 1e-4]

Needs numpy. Exits 1 when a tensor differs by more than the tolerance."""
import argparse
import json
import struct
import sys

import numpy as np

DTYPES = {"F32": np.float32, "F64": np.float64, "F16": np.float16}


def read(path):
    with open(path, "rb") as f:
        raw = f.read()
    n = struct.unpack("<Q", raw[:8])[0]
    header = json.loads(raw[8:8 + n])
    header.pop("__metadata__", None)
    data = raw[8 + n:]
    return {
        name: np.frombuffer(data[v["data_offsets"][0]:v["data_offsets"][1]],
                            dtype=DTYPES[v["dtype"]]).reshape(v["shape"])
        for name, v in header.items()
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("a")
    ap.add_argument("b")
    ap.add_argument("--tolerance", type=float, default=1e-4)
    args = ap.parse_args()
    a, b = read(args.a), read(args.b)
    if a.keys() != b.keys():
        sys.exit(f"the files hold different tensors: {sorted(a.keys() ^ b.keys())}")
    worst = 0.0
    for name in sorted(a):
        x, y = a[name].astype(np.float64), b[name].astype(np.float64)
        if x.shape != y.shape:
            sys.exit(f"{name}: shapes {x.shape} and {y.shape} differ")
        d = np.abs(x - y).max(initial=0.0) / max(np.abs(x).max(initial=0.0), 1e-30)
        worst = max(worst, d)
        print(f"{name:60s} {d:.2e}")
    print(f"worst: {worst:.2e} (tolerance {args.tolerance:g})")
    sys.exit(0 if worst <= args.tolerance else 1)


if __name__ == "__main__":
    main()
