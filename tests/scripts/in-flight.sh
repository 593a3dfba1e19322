#!/usr/bin/env bash
# `scripts/experiments.sh keep` and the restore every run of it begins with, on a scratch
# copy of the script: keep copies the newest converged training's checkpoint (not a newer
# best network of another one) with its best network and logs into training/in-flight/;
# on a machine without them, a run puts them back under their own names, and a training
# whose checkpoint is there is left alone; the converged interference campaign runs in its
# plan's order. (The runner's resume itself is tested in crates/pvrnn-experiment.)
set -euo pipefail
script=$(realpath "$(dirname "$0")/../../scripts/experiments.sh")
work=$(mktemp -d /tmp/pvrnn-in-flight.XXXXXX)
trap 'rm -rf "$work"' EXIT
mkdir -p "$work/scripts" "$work/training/converged-interference" "$work/training/converged-networks"
cp "$script" "$work/scripts/"
cd "$work"
fail() { echo "in-flight test: $*" >&2; exit 1; }

older=training/converged-networks/converged-train-net0
stem=training/converged-interference/converged-train-repositioning-plus3-net2
echo older > "$older.safetensors"
sleep 1
echo checkpoint > "$stem.safetensors"
echo best > "$stem.best.safetensors"
printf 'iteration,total\n0,1.0\n500,0.5\n' > "$stem.log.csv"
echo validations > "$stem.validation.csv"
sleep 1
echo other > training/converged-networks/converged-train-net1.best.safetensors

scripts/experiments.sh keep 2> keep.log || fail "keep failed: $(cat keep.log)"
grep -q "iteration 500" keep.log || fail "keep did not name the iteration: $(cat keep.log)"
[ "$(cat training/in-flight/stem.txt)" = "$stem" ] || fail "kept $(cat training/in-flight/stem.txt), not $stem"
for part in checkpoint.safetensors:safetensors best.safetensors:best.safetensors \
    log.csv:log.csv validation.csv:validation.csv; do
    cmp -s "training/in-flight/${part%%:*}" "$stem.${part#*:}" || fail "training/in-flight/${part%%:*} differs"
done

# A fresh machine: the kept training is put back (the run then fails at the missing
# executable, after the restore).
rm -rf training/converged-interference
PVRNN=/bin/false scripts/experiments.sh interference 2 2> run.log && fail "the run should stop at /bin/false"
grep -q "resuming $stem" run.log || fail "no restore: $(cat run.log)"
for part in safetensors best.safetensors log.csv validation.csv; do
    [ -f "$stem.$part" ] || fail "$stem.$part was not put back"
done
[ "$(cat "$stem.safetensors")" = checkpoint ] || fail "the checkpoint put back is not the kept one"

# A training further along here than what was kept is not overwritten.
echo later > "$stem.safetensors"
PVRNN=/bin/false scripts/experiments.sh interference 2 2> run.log || true
[ "$(cat "$stem.safetensors")" = later ] || fail "a checkpoint already here was overwritten"
grep -q resuming run.log && fail "restored over an existing checkpoint"
# The converged interference campaign without a network number runs in the plan's order
# (no --network: a condition's networks before the next condition), every other call
# network by network.
mkdir -p data/caresim-robotfree data/caresim-seed1 docs/results/converged/interference
touch data/caresim-robotfree/dataset.json data/caresim-seed1/dataset.json \
    docs/results/converged/interference/plan.json
printf '#!/bin/sh\necho "$@" >> %s/calls.txt\n' "$work" > record && chmod +x record
SCALE=converged PVRNN=./record scripts/experiments.sh interference 2> run.log || fail "$(cat run.log)"
[ "$(grep -c ' experiment interference ' calls.txt)" = 1 ] || fail "not one plan-order run: $(cat calls.txt)"
grep -q -- --network calls.txt && fail "the plan-order run named a network: $(cat calls.txt)"
rm calls.txt
SCALE=converged PVRNN=./record scripts/experiments.sh shared 2> run.log || fail "$(cat run.log)"
[ "$(grep -c -- '--network' calls.txt)" = 15 ] || fail "shared: not network by network: $(cat calls.txt)"
rm calls.txt
# COHORT with a network number, or for the shared networks, is refused before pvrnn runs.
for call in "interference 1" "shared"; do
    # shellcheck disable=SC2086 # the call is a list of words
    SCALE=converged COHORT=5 PVRNN=./record scripts/experiments.sh $call 2> run.log &&
        fail "COHORT=5 $call should be refused"
    grep -q "no network number" run.log || fail "COHORT=5 $call: $(cat run.log)"
    [ ! -f calls.txt ] || fail "COHORT=5 $call ran pvrnn: $(cat calls.txt)"
done
echo "in-flight keep and restore, interference in plan order, COHORT's refusals: ok" >&2
