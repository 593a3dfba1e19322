#!/usr/bin/env bash
# Runs the paper's four experiments at reduced scale into docs/results/<experiment>/,
# network by network, so that a run cut short (a session's end, a reboot) leaves complete
# networks and resumes where it stopped (docs/experiments.md):
#
#   scripts/reduced-experiments.sh                 # everything not done yet
#   scripts/reduced-experiments.sh shared 1        # only network 1 of the shared experiments
#   scripts/reduced-experiments.sh interference 2  # only network 2 of interference
#
# hierarchy, uncertainty and robustness share their 3 networks (training/reduced-networks/,
# trained once, by whichever experiment comes first); interference trains its own 12 there.
# The data is caresim seed 0 with robot-free renders (data/caresim-robotfree, made here if
# missing: its learning sequences are byte for byte those of `pvrnn simulate`). Each step
# ends with the experiment's report rebuilt from what is done. THREADS (default 2) sets the
# worker threads, JOBS (default 1) the jobs run at once, BACKEND (cpu or wgpu; default cpu)
# what computes, PVRNN the executable (default target/release/pvrnn). On a GPU machine:
#
#   BACKEND=wgpu JOBS=4 THREADS=16 scripts/reduced-experiments.sh interference 1
set -euo pipefail
cd "$(dirname "$0")/.."

threads=${THREADS:-2}
jobs=${JOBS:-1}
backend=${BACKEND:-cpu}
data=data/caresim-robotfree
networks=training/reduced-networks
if [ -z "${PVRNN:-}" ]; then
    # Always from the current sources: a stale binary could plan another design.
    cargo build --release --bin pvrnn
fi
pvrnn=${PVRNN:-target/release/pvrnn}
[ -f "$data/dataset.json" ] ||
    "$pvrnn" --threads "$threads" simulate --robot-free --no-previews --out "$data"

# One network of one experiment: its trainings (or the shared ones, already trained), then
# its inference runs, then the report.
run() {
    local experiment=$1 network=$2 out=docs/results/$1
    local args=(--scale reduced --out "$out" --network "$network" --jobs "$jobs" --backend "$backend")
    [ -f "$out/plan.json" ] || args+=(--dataset "$data" --networks "$networks")
    echo "== $experiment, network $network ($(date -u +%H:%M:%S))" >&2
    local start
    start=$(date +%s)
    "$pvrnn" --threads "$threads" experiment "$experiment" "${args[@]}"
    echo "   $experiment network $network took $(( $(date +%s) - start )) s" >&2
}

which=${1:-all}
only=${2:-}
networks_of() { if [ -n "$only" ]; then echo "$only"; else echo 0 1 2; fi; }
if [ "$which" = all ] || [ "$which" = shared ]; then
    for network in $(networks_of); do
        for experiment in hierarchy uncertainty robustness; do
            run "$experiment" "$network"
        done
    done
fi
if [ "$which" = all ] || [ "$which" = interference ]; then
    for network in $(networks_of); do
        run interference "$network"
    done
fi
