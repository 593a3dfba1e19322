#!/usr/bin/env bash
# Runs the paper's four experiments at one scale (SCALE: reduced, the default, converged, or
# paper: the paper's protocol, 100,000 iterations, a GPU job) on one caresim revision
# (REVISION: 1, the default, or 2: docs/caresim.md, "Revisions"), network by network, so
# that a run cut short (a session's end, a reboot) leaves complete networks and resumes
# where it stopped (docs/experiments.md):
#
#   scripts/experiments.sh                              # reduced: everything not done yet
#   scripts/experiments.sh shared 1                     # network 1 of the shared experiments
#   scripts/experiments.sh interference 2               # network 2 of interference
#   SCALE=converged scripts/experiments.sh shared 0     # converged scale, network 0
#   SCALE=converged scripts/experiments.sh interference # converged interference, plan order
#   REVISION=2 SCALE=converged scripts/experiments.sh shared 0   # the same on revision 2
#
# Revision 1's reduced results go to docs/results/<experiment>/, converged ones to
# docs/results/converged/<experiment>/; revision 2's to docs/results/r2/<scale>/<experiment>/,
# with data/r2-robotfree, data/r2-seed1 and training/r2-<scale>-networks/ (interference:
# training/r2-<scale>-interference/). At the paper scale (fixed 100,000 iterations) the
# networks are validated once at the end on seed 1 for the validity gate. hierarchy,
# uncertainty and robustness share their networks (training/<scale>-networks/, trained
# once, by whichever experiment comes first); interference trains its own (reduced: in the
# same folder; converged: training/converged-interference/). The data is caresim seed 0
# with robot-free renders (data/caresim-robotfree, made here if missing: its learning
# sequences are byte for byte those of `pvrnn simulate`); the converged and paper scales
# validate on caresim seed 1 (data/caresim-seed1, made here if missing). Each step
# ends with the experiment's report rebuilt from what is done. THREADS (default 2) sets the
# worker threads, JOBS (default 1) the jobs run at once, BACKEND (cpu or wgpu; default cpu)
# what computes, PVRNN the executable (default target/release/pvrnn). COHORT=N (without a
# network number) runs every network's jobs at once, training a condition's networks N
# together (`--cohort`; with BACKEND=wgpu add GPU_RECURRENCE=1 for one recurrence dispatch
# for all of them). On a GPU machine:
#
#   BACKEND=wgpu JOBS=4 THREADS=16 scripts/experiments.sh interference 1
#   SCALE=converged BACKEND=wgpu GPU_RECURRENCE=1 COHORT=5 JOBS=2 THREADS=16 \
#       scripts/experiments.sh interference
#
# A converged training takes hours, longer than a session on a fresh machine keeps its
# files. `scripts/experiments.sh keep` copies the training in flight (the newest checkpoint
# under training/converged-*/, with its best network and logs) into training/in-flight/,
# one path per file, to commit; every run here first puts it back where its training
# resumes from it, unless that checkpoint is already there.
set -euo pipefail
cd "$(dirname "$0")/.."

kept=training/in-flight
if [ "${1:-}" = keep ]; then
    checkpoint=$(ls -t training/*converged-*/*.safetensors training/*paper-*/*.safetensors 2>/dev/null |
        grep -v '\.best\.safetensors$' | head -n 1 || true)
    [ -n "$checkpoint" ] || { echo "no converged training has a checkpoint" >&2; exit 1; }
    stem=${checkpoint%.safetensors}
    mkdir -p "$kept"
    # In this order while the training runs: the best network and the validations before
    # the checkpoint (one validated after them is validated again on resume), the training
    # log after it (flushed before each checkpoint, it covers the checkpoint's iterations).
    for part in best.safetensors validation.csv checkpoint log.csv; do
        source=$stem.$part target=$kept/$part
        [ "$part" != checkpoint ] || source=$checkpoint target=$kept/checkpoint.safetensors
        if [ -f "$source" ]; then cp "$source" "$target"; else rm -f "$target"; fi
    done
    echo "$stem" > "$kept/stem.txt"
    echo "kept $stem in $kept/ (its log reaches iteration $(tail -n 1 "$stem.log.csv" | cut -d, -f1); it resumes from its last checkpoint); commit it" >&2
    exit 0
fi
if [ -f "$kept/stem.txt" ]; then
    stem=$(cat "$kept/stem.txt")
    if [ ! -f "$stem.safetensors" ]; then
        mkdir -p "$(dirname "$stem")"
        for part in best.safetensors log.csv validation.csv; do
            [ ! -f "$kept/$part" ] || cp "$kept/$part" "$stem.$part"
        done
        cp "$kept/checkpoint.safetensors" "$stem.safetensors"
        echo "resuming $stem from $kept/" >&2
    fi
fi

which=${1:-all}
only=${2:-}
# `--cohort` trains a condition's networks together, so pvrnn refuses it beside `--network`.
if [ -n "${COHORT:-}" ] && { [ -n "$only" ] || [ "$which" != interference ]; }; then
    echo "COHORT=$COHORT trains a condition's networks together: use it with \`interference\` and no network number" >&2
    exit 2
fi

threads=${THREADS:-2}
jobs=${JOBS:-1}
backend=${BACKEND:-cpu}
scale=${SCALE:-reduced}
revision=${REVISION:-1}
case "$revision" in
1) data=data/caresim-robotfree validation=data/caresim-seed1 prefix="" ;;
2) data=data/r2-robotfree validation=data/r2-seed1 prefix=r2- ;;
*) echo "REVISION must be 1 or 2, not $revision" >&2; exit 2 ;;
esac
case "$scale" in
reduced) results=docs/results count=3 ;;
converged) results=docs/results/converged count=5 ;;
paper) results=docs/results/paper count=5 ;;
*) echo "SCALE must be reduced, converged or paper, not $scale" >&2; exit 2 ;;
esac
[ "$revision" = 1 ] || results=docs/results/r2/$scale
if [ -z "${PVRNN:-}" ]; then
    # Always from the current sources: a stale binary could plan another design.
    cargo build --release --bin pvrnn
fi
pvrnn=${PVRNN:-target/release/pvrnn}
validated=true
[ "$scale" != reduced ] || validated=false
[ -f "$data/dataset.json" ] ||
    "$pvrnn" --threads "$threads" simulate --revision "$revision" --robot-free --no-previews --out "$data"
[ "$validated" = false ] || [ -f "$validation/dataset.json" ] ||
    "$pvrnn" --threads "$threads" simulate --revision "$revision" --seed 1 --no-previews --out "$validation"

# One network of one experiment: its trainings (or the shared ones, already trained), then
# its inference runs, then the report.
run() {
    local experiment=$1 network=$2 out=$results/$1
    local networks=training/$prefix$scale-networks
    [ "$experiment" != interference ] || [ "$scale" = reduced ] ||
        networks=training/$prefix$scale-interference
    local args=(--scale "$scale" --out "$out" --jobs "$jobs" --backend "$backend")
    if [ -n "$network" ]; then args+=(--network "$network"); fi
    if [ -n "${COHORT:-}" ]; then args+=(--cohort "$COHORT"); fi
    if [ -n "${GPU_RECURRENCE:-}" ]; then args+=(--gpu-recurrence); fi
    [ -f "$out/plan.json" ] || args+=(--dataset "$data" --networks "$networks")
    [ -f "$out/plan.json" ] || [ "$validated" = false ] || args+=(--validate "$validation")
    echo "== $experiment, network ${network:-all} ($(date -u +%H:%M:%S))" >&2
    local start
    start=$(date +%s)
    "$pvrnn" --threads "$threads" experiment "$experiment" "${args[@]}"
    echo "   $experiment network ${network:-all} took $(( $(date +%s) - start )) s" >&2
}

networks_of() { if [ -n "$only" ]; then echo "$only"; else seq 0 $((count - 1)); fi; }
if [ "$which" = all ] || [ "$which" = shared ]; then
    for network in $(networks_of); do
        for experiment in hierarchy uncertainty robustness; do
            run "$experiment" "$network"
        done
    done
fi
if [ "$which" = all ] || [ "$which" = interference ]; then
    if [ -z "$only" ] && { [ -n "${COHORT:-}" ] || [ "$scale" != reduced ]; }; then
        # Plan order: a condition's networks one after another (or together with COHORT),
        # so that a direction's trainings, which its test needs, finish first.
        run interference ""
    else
        for network in $(networks_of); do
            run interference "$network"
        done
    fi
fi
