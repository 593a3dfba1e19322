#!/usr/bin/env bash
# The mean learning trajectory (open loop, no network) on the test trials of caresim
# revision 2, seeds 0-4, both tasks, the learned bed heights and 620 / 680 mm, at the
# scripts' joint speeds and at the Franka Panda's; then the table and figure here.
#
#   docs/results/closed-loop/mean-trajectory/run.sh [OUT]   (default runs/drive-speed)
set -euo pipefail
cd "$(dirname "$0")/../../../.."
out=${1:-runs/drive-speed}
pvrnn=${PVRNN:-target/release/pvrnn}
[ -x "$pvrnn" ] || cargo build --release -p pvrnn-cli
for limit in scripted panda; do
    for seed in 0 1 2 3 4; do
        for task in repositioning wiping; do
            for height in 590 650 710 620 680; do
                episode=$out/$limit/$task-$height-seed$seed
                [ -f "$episode/drive.json" ] && continue
                "$pvrnn" --threads 1 drive --controller mean-trajectory --revision 2 \
                    --task "$task" --bed-height "$height" --seed "$seed" --speed-limit "$limit" \
                    --out "$episode" 2>&1 | grep -E "^(episode|error)" | sed "s|^|$episode: |"
            done
        done
    done
done
here=docs/results/closed-loop/mean-trajectory
"$pvrnn" report drive "$out" --out "$here/table.md" --figure "$here/success.png"
