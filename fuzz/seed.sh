#!/usr/bin/env bash
# Writes a seed corpus for every fuzz target (fuzz/corpus/<target>/): small valid files of
# each format, so that libFuzzer starts from inputs that get past the first checks instead of
# from empty bytes. Needs a `pvrnn` binary (argument 1, default target/release/pvrnn) and
# Python with numpy and safetensors. Then, for example:
#   cd fuzz && cargo +nightly fuzz run model -- -max_total_time=60
set -euo pipefail
cd "$(dirname "$0")/.."
pvrnn=$(realpath "${1:-target/release/pvrnn}")
corpus=fuzz/corpus
scratch=$(mktemp -d)
trap 'rm -rf "$scratch"' EXIT

# A tiny model (modules of 3 units, one camera, 2x2 and 4x4 images), its inputs, a 2-iteration
# checkpoint and a runs file.
"$pvrnn" config | python3 -c '
import re, sys
s = sys.stdin.read()
s = re.sub(r"^d = \d+", "d = 3", s, flags=re.M)
s = re.sub(r"^z = \d+", "z = 2", s, flags=re.M)
s = re.sub(r"hidden = \[[^\]]*\]", "hidden = [3]", s)
s = s.replace("cameras = 2", "cameras = 1")
s = re.sub(r"resolutions = \[[^\]]*\]", "resolutions = [2, 4]", s)
print(s)' >"$scratch/small.toml"
python3 -c '
import sys, numpy as np
from safetensors.numpy import save_file
r = np.random.default_rng(0)
x = lambda d: r.uniform(-0.9, 0.9, (2, 3, d)).astype(np.float32)
save_file({"x_extero": x(60), "x_proprio": x(28)}, sys.argv[1])' "$scratch/inputs.safetensors"
"$pvrnn" init --config "$scratch/small.toml" --sequences 2 --steps 3 --out "$scratch/model.safetensors" >/dev/null 2>&1
"$pvrnn" --threads 1 train --model "$scratch/model.safetensors" --inputs "$scratch/inputs.safetensors" \
    --out "$scratch/checkpoint.safetensors" --iterations 2 --checkpoint-every 1 >/dev/null 2>&1
"$pvrnn" --threads 1 infer --model "$scratch/checkpoint.safetensors" --inputs "$scratch/inputs.safetensors" \
    --out "$scratch/runs.safetensors" --window 2 --iterations 1 >/dev/null 2>&1

mkdir -p "$corpus"/{model,checkpoint,tensors,dataset_manifest,bundle_manifest,recording,url_hash}
cp "$scratch/model.safetensors" "$corpus/model/"
cp "$scratch/checkpoint.safetensors" "$corpus/checkpoint/"
cp "$scratch/checkpoint.safetensors" "$corpus/model/"
cp "$scratch/inputs.safetensors" "$scratch/runs.safetensors" "$corpus/tensors/"
cp models/default/dataset.json "$corpus/dataset_manifest/"
cp models/default/bundle.json "$corpus/bundle_manifest/"
printf '%s' 'seq=only&t=3&vision=1&proprio=0&ablate=1000&ablation=inference&lr=0.5' >"$corpus/url_hash/view"

# A recording as the recording target reads it: meta.json, 0xFF 0xFE, proprio.csv (the
# paper's two arms: 14 joints, 14 torques), 0xFF 0xFE, one 8x8 camera frame (PNG).
python3 -c '
import sys, zlib, struct, json
meta = json.dumps({"task": "wiping", "split": "learn", "subtasks": ["reaching", "wiping"]}).encode()
names = [f"{a}_{k}{j}" for k in ("q", "tau") for a in ("left", "right") for j in range(1, 8)]
rows = ["time_s," + ",".join(names) + ",subtask"]
for t in range(3):
    rows.append(f"{t / 10:.2f}," + ",".join(f"{0.01 * (t + j):.3f}" for j in range(len(names))) + f",{t // 2}")
csv = ("\n".join(rows) + "\n").encode()
def chunk(kind, data):
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
raw = b"".join(b"\x00" + bytes([128, 64, 32] * 8) for _ in range(8))
png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 8, 8, 8, 2, 0, 0, 0)) \
    + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")
open(sys.argv[1], "wb").write(meta + b"\xff\xfe" + csv + b"\xff\xfe" + png)' "$corpus/recording/paper-arms"

for target in "$corpus"/*; do
    echo "$(basename "$target"): $(ls "$target" | wc -l) seed file(s)"
done
