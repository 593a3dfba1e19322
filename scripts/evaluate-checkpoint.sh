#!/usr/bin/env bash
# Evaluates one training checkpoint of the campaign (docs/results/campaign-100k.md) on the test
# split under the three standard conditions, keeps each report's summary in
# docs/results/evals/iter<N>/<condition>/ and rebuilds the error-vs-iterations table
# docs/results/progress.md from every evaluation kept there.
#
#   scripts/evaluate-checkpoint.sh CHECKPOINT DATASET [TRIALS] [THREADS]
#
# The full reports (per-step CSV, plots) stay in $EVAL_SCRATCH (default /tmp/pvrnn-evals).
set -euo pipefail
cd "$(dirname "$0")/.."

checkpoint=${1:?usage: scripts/evaluate-checkpoint.sh CHECKPOINT DATASET [TRIALS] [THREADS]}
dataset=${2:?usage: scripts/evaluate-checkpoint.sh CHECKPOINT DATASET [TRIALS] [THREADS]}
trials=${3:-2}
threads=${4:-2}
scratch=${EVAL_SCRATCH:-/tmp/pvrnn-evals}
pvrnn=${PVRNN:-target/release/pvrnn}
[ -x "$pvrnn" ] || cargo build --release -p pvrnn-cli

# condition folder | evaluate flags
conditions=(
    "all|--vision all --proprio on"
    "16+proprio|--vision 16 --proprio on"
    "16|--vision 16 --proprio off"
)
for entry in "${conditions[@]}"; do
    name=${entry%%|*}
    flags=${entry#*|}
    out="$scratch/$name"
    echo "== $checkpoint, $name ($trials trials)" >&2
    start=$(date +%s)
    # shellcheck disable=SC2086 # the flags are words
    "$pvrnn" --threads "$threads" evaluate --model "$checkpoint" --inputs "$dataset" \
        $flags --trials "$trials" --out "$out"
    echo "   took $(( $(date +%s) - start )) s" >&2
    # The checkpoint's training iteration (recorded in the summary) names the folder.
    iteration=$(grep -o '"model_iteration": *[0-9]*' "$out/summary.json" | grep -o '[0-9]*$')
    keep="docs/results/evals/iter$iteration/$name"
    mkdir -p "$keep"
    cp "$out/summary.json" "$out/summary.md" "$keep/"
done

"$pvrnn" report table docs/results/evals/iter*/* --out docs/results/progress.md
echo "docs/results/progress.md updated" >&2
