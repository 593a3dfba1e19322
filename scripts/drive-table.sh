#!/usr/bin/env bash
# The closed loop's success table (docs/closed-loop.md): one network drives caresim's robot
# on the test trials of caresim seeds SEEDS (default 0), both tasks, the learned bed heights
# (590, 650, 710 mm) and two it never learned (620, 680), beside the two open-loop
# baselines (the network's prior, the mean learning trajectory); then 16x16 vision, sensor
# noise x3, a push (0.2 rad on every joint of the working arm at step 100) and the left camera
# occluded for 30 steps from step 100, at 650 mm. Every episode is a folder under OUT;
# the table is OUT/table.md and its figure OUT/success.png (`pvrnn report drive`). Episodes
# already written are kept.
#
#   scripts/drive-table.sh MODEL REVISION OUT [SEEDS]
#
# Environment: PVRNN (the binary; default target/release/pvrnn), THREADS (default 1).
set -euo pipefail
cd "$(dirname "$0")/.."
usage="usage: scripts/drive-table.sh MODEL REVISION OUT [SEEDS, e.g. \"0 1 2\"]"
model=${1:?$usage}
revision=${2:?$usage}
out=${3:?$usage}
seeds=${4:-0}
pvrnn=${PVRNN:-target/release/pvrnn}
[ -x "$pvrnn" ] || cargo build --release -p pvrnn-cli

episode() { # folder, flags
    [ -f "$out/$1/drive.json" ] && return
    "$pvrnn" --threads "${THREADS:-1}" drive --model "$model" --revision "$revision" \
        --out "$out/$1" "${@:2}" 2>&1 | grep --line-buffered -E "^(episode|error)" | sed "s|^|$1: |"
}
for seed in $seeds; do
    for task in repositioning wiping; do
        for height in 590 650 710 620 680; do
            for controller in network prior mean-trajectory; do
                episode "$controller/$task-$height-seed$seed" --task "$task" --bed-height "$height" \
                    --seed "$seed" --controller "$controller"
            done
        done
        at=(--task "$task" --bed-height 650 --seed "$seed")
        arm=left # the arm that does the task's work
        [ "$task" = wiping ] && arm=right
        episode "perturbed/vision16-$task-seed$seed" "${at[@]}" --vision 16
        episode "perturbed/noise3-$task-seed$seed" "${at[@]}" --sensor-noise 3
        episode "perturbed/push-$task-seed$seed" "${at[@]}" --push "100:$arm:0.2"
        episode "perturbed/occluded-$task-seed$seed" "${at[@]}" --occlude left:100:30
    done
done
"$pvrnn" report drive "$out" --out "$out/table.md" --figure "$out/success.png"
cat "$out/table.md"
