#!/usr/bin/env bash
# Scores checkpoints of one training run on held-out validation sequences, to choose the
# one to ship without looking at the test split (docs/results/campaign-100k.md, "Choosing the
# shipped checkpoint"). Validation data: another caresim seed, whose every sequence (both
# splits) is new to the network:
#
#   pvrnn simulate --out caresim-seed1 --seed 1
#   scripts/validate-checkpoints.sh caresim-seed1 OUTDIR CHECKPOINT...
#
# Each checkpoint gets `pvrnn evaluate --split all --vision 16 --proprio on --trials 1`
# (the issue's headline condition) into OUTDIR/<checkpoint file stem>/; the headline lines
# of every evaluation are printed at the end. THREADS (default 2) sets the worker threads.
set -euo pipefail
cd "$(dirname "$0")/.."

usage="usage: scripts/validate-checkpoints.sh VALIDATION_DATASET OUTDIR CHECKPOINT..."
dataset=${1:?$usage}
outdir=${2:?$usage}
shift 2
[ $# -ge 1 ] || { echo "$usage" >&2; exit 2; }
pvrnn=${PVRNN:-target/release/pvrnn}
[ -x "$pvrnn" ] || cargo build --release -p pvrnn-cli
mkdir -p "$outdir"

for checkpoint in "$@"; do
    name=$(basename "$checkpoint" .safetensors)
    # A bundle's weights are all called model.safetensors: name them by their folder.
    [ "$name" = model ] && name=$(basename "$(dirname "$checkpoint")")
    echo "== $checkpoint" >&2
    start=$(date +%s)
    "$pvrnn" --threads "${THREADS:-2}" evaluate --model "$checkpoint" --inputs "$dataset" \
        --split all --vision 16 --proprio on --trials 1 --out "$outdir/$name" 2>&1 |
        tee "$outdir/$name.log" >&2
    echo "   took $(( $(date +%s) - start )) s" >&2
done

echo >&2
for checkpoint in "$@"; do
    name=$(basename "$checkpoint" .safetensors)
    [ "$name" = model ] && name=$(basename "$(dirname "$checkpoint")")
    echo "$checkpoint:"
    grep -E '^(all|task:).* recon .*(upsample|mean)|^warning' "$outdir/$name.log" || true
done
