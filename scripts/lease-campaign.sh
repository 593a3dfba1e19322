#!/usr/bin/env bash
# A short loan of a GPU machine spent on the converged interference campaign
# (docs/results/experiments.md): train the plan's next networks there for at most SECONDS,
# then pack what came of it into a few files small enough to bring back, and unpack them
# here.
#
#   scripts/lease-campaign.sh PVRNN_BINARY OUT_DIR SECONDS   # on the GPU machine
#   scripts/lease-campaign.sh --unpack DIR                   # here, with what came back
#
# On the GPU machine it runs `scripts/experiments.sh interference` at the converged scale
# with BACKEND=wgpu, GPU_RECURRENCE=1 and COHORT networks of a condition trained together
# (default 2), all the machine's threads, and stops it with SIGTERM at the deadline (the
# runner then writes every training's checkpoint). A training kept in training/in-flight/
# is resumed there first (experiments.sh restores it), so a session stops its own training
# here and keeps it (`scripts/experiments.sh keep`) before the loan, or both would train it.
# OUT_DIR gets:
#   results.tgz        the plan's results and report, and every training's log and
#                      validations (finished trainings are complete in these)
#   networks.tgz.NN    the networks of trainings that finished during the loan but whose
#                      inference runs did not all run before the deadline: their results
#                      say they are done, so without the network their runs could not run
#                      anywhere else (a best network is 9.5 MB at paper scale)
#   in-flight.tgz.NN   the training that had run furthest without finishing, as
#                      `scripts/experiments.sh keep` keeps it (checkpoint 28 MB, best
#                      network 9.5 MB), if it fits after those networks
#   summary.txt        what finished, what came back, what did not, and the runner's last
#                      lines
# The archives come in parts of at most PART_MB MiB (default 15), and all of OUT_DIR within
# BACK_MB MiB (default 60) and BACK_FILES files (default 8): what a loan here returns (8
# files of 16 MiB, 64 MiB together). Choose COHORT and SECONDS so that the trainings and
# their inference runs finish (a cohort of 3 at 12 sequences trained 12,000 iterations in
# 329 s on an H200, then each inference run took 13-15 s).
# --unpack puts the results back (and clears training/in-flight/ if the loan finished the
# training kept there) and the training in flight into training/in-flight/, from where the
# next `scripts/experiments.sh` run here resumes it (it replaces a checkpoint of
# the same training here only if that is older: the loan's, resumed from it, is newer).
#
# The committed plan names its data and networks by absolute paths (under /work/main);
# where the checkout is elsewhere and nothing is at that path, it is made a link to the
# checkout (the data is simulated there if missing, as experiments.sh does). On a host with the NVIDIA driver but no Vulkan loader, the loader's
# Debian packages in .gl/ are unpacked first (docs/gpu.md), as scripts/gpu-measure.sh does.
set -euo pipefail
cd "$(dirname "$0")/.."

results=docs/results/converged/interference
networks=training/converged-interference
kept=training/in-flight

if [ "${1:-}" = --unpack ]; then
    from=${2:?usage: scripts/lease-campaign.sh --unpack DIR}
    tar -xzf "$from/results.tgz"
    # A training kept here that the loan finished is not resumed again.
    if [ -f "$kept/stem.txt" ]; then
        job=$(basename "$(cat "$kept/stem.txt")")
        if [ -f "$results/results/${job#converged-}.json" ]; then
            rm -rf "$kept"
            echo "the kept training ${job#converged-} finished during the loan: $kept/ cleared" >&2
        fi
    fi
    if compgen -G "$from/networks.tgz.*" >/dev/null; then
        echo "networks back for their inference runs (scripts/experiments.sh runs them):" >&2
        cat "$from"/networks.tgz.* | tar -xvzf - | sed 's/^/  /' >&2
    fi
    if compgen -G "$from/in-flight.tgz.*" >/dev/null; then
        rm -rf "$kept"
        cat "$from"/in-flight.tgz.* | tar -xzf -
        stem=$(cat "$kept/stem.txt")
        if [ -f "$stem.safetensors" ] && [ "$stem.safetensors" -nt "$kept/checkpoint.safetensors" ]; then
            echo "$stem.safetensors here is newer than the loan's; left as it is" >&2
        else
            rm -f "$stem.safetensors" # experiments.sh restores the kept one in its place
        fi
        echo "in flight: $stem (log to iteration $(tail -n 1 "$kept/log.csv" | cut -d, -f1)); scripts/experiments.sh resumes it" >&2
    fi
    cat "$from/summary.txt" >&2
    exit 0
fi

bin=$(realpath "${1:?usage: scripts/lease-campaign.sh PVRNN_BINARY OUT_DIR SECONDS}")
out=${2:?usage: scripts/lease-campaign.sh PVRNN_BINARY OUT_DIR SECONDS}
seconds=${3:?usage: scripts/lease-campaign.sh PVRNN_BINARY OUT_DIR SECONDS}
mkdir -p "$out"

# shellcheck source=scripts/gpu-host.sh
source scripts/gpu-host.sh
# The checkout the plan was made in: two folders above its dataset's.
planned=$(sed -nE 's/^ *"dataset": *"(.*)",?$/\1/p' "$results/plan.json" 2>/dev/null | head -n 1)
root=$(dirname "$(dirname "${planned:-.}")")
if [ -n "$planned" ] && [ "$(realpath "$root" 2>/dev/null || true)" != "$(pwd -P)" ]; then
    if [ -e "$root" ]; then
        echo "the plan's paths are under $root, another checkout: its data and networks are used" >&2
    else
        mkdir -p "$(dirname "$root")"
        ln -s "$(pwd -P)" "$root"
    fi
fi
before=$(ls "$results"/results/train-*.json 2>/dev/null || true)

start=$(date +%s)
status=0
# timeout signals the runner's whole process group: the runner checkpoints and stops.
SCALE=converged BACKEND=${BACKEND:-wgpu} GPU_RECURRENCE=${GPU_RECURRENCE-1} \
    COHORT=${COHORT:-2} JOBS=1 THREADS=${THREADS:-$(nproc)} PVRNN=$bin \
    timeout -s TERM -k 300 "$seconds" scripts/experiments.sh interference \
    >"$out/runner.log" 2>&1 || status=$?
elapsed=$(($(date +%s) - start))

shopt -s nullglob
tar -czf "$out/results.tgz" "$results" "$networks"/*.log.csv "$networks"/*.validation.csv
{
    echo "loan: ${elapsed} s of ${seconds}, runner exit status ${status} (124: stopped at the deadline)"
    echo "trainings finished during the loan:"
    ls "$results"/results/train-*.json 2>/dev/null | grep -vxF -e "${before:-/}" |
        sed -E 's|.*/(train-.*)\.json$|  \1|' || echo "  none"

} >"$out/summary.txt"

# Room for the archives: what a loan returns, less the files beside them (results.tgz,
# runner.log, summary.txt), in bytes and in files.
part=$((${PART_MB:-15} * 1048576))
size() { cat "$@" | wc -c; }
parts_of() { echo $((($1 + part - 1) / part)); }
bytes_left=$((${BACK_MB:-60} * 1048576 - $(size "$out/results.tgz" "$out/runner.log") - 65536))
files_left=$((${BACK_FILES:-8} - 3))
fits() { [ "$1" -le "$bytes_left" ] && [ "$(parts_of "$1")" -le "$files_left" ]; }

# Finished trainings whose inference runs did not all run: the network the runs read (the
# best one where the rule chose it, else the final checkpoint), in plan order.
owed=$(python3 - "$results" "$networks" <<'EOF'
import json, pathlib, sys
results, networks = map(pathlib.Path, sys.argv[1:])
jobs = json.loads((results / "plan.json").read_text())["jobs"]
for job in (j for j in jobs if j["kind"] == "train"):
    done = results / "results" / f"{job['name']}.json"
    runs = [j for j in jobs if j["kind"] == "infer" and j["train_job"] == job["id"]]
    if not done.exists() or all(
        (results / "results" / f"{r['name']}.safetensors").exists() for r in runs
    ):
        continue
    result = json.loads(done.read_text())
    used = result.get("network_iteration") or result["iterations"]
    stem = networks / f"converged-{job['name']}"
    print(f"{stem}.best.safetensors" if used != result["iterations"] else f"{stem}.safetensors")
EOF
)
back=() bytes=0
for network in $owed; do
    with=$((bytes + $(size "$network")))
    if fits "$with"; then
        back+=("$network") bytes=$with
        echo "network back for its inference runs: $network" >>"$out/summary.txt"
    else
        echo "LOST (no room to bring it back): $network, whose inference runs did not all run" >>"$out/summary.txt"
    fi
done
if [ ${#back[@]} -gt 0 ]; then
    tar -czf - "${back[@]}" | split -b "$part" -d - "$out/networks.tgz."
    bytes=$(size "$out"/networks.tgz.*)
    bytes_left=$((bytes_left - bytes)) files_left=$((files_left - $(parts_of "$bytes")))
fi

# The furthest unfinished training: the one whose log reaches the highest iteration among
# those with a checkpoint and no result.
furthest="" furthest_iteration=-1
for checkpoint in "$networks"/*.safetensors; do
    case "$checkpoint" in *.best.safetensors) continue ;; esac
    stem=${checkpoint%.safetensors}
    job=${stem##*/converged-}
    [ ! -f "$results/results/$job.json" ] || continue
    iteration=$(tail -n 1 "$stem.log.csv" 2>/dev/null | cut -d, -f1)
    [[ "$iteration" =~ ^[0-9]+$ ]] || continue
    if [ "$iteration" -gt "$furthest_iteration" ]; then
        furthest=$stem furthest_iteration=$iteration
    fi
done
if [ -n "$furthest" ]; then
    # keep takes the newest checkpoint: make it this one.
    touch "$furthest.safetensors"
    scripts/experiments.sh keep 2>>"$out/summary.txt"
    if fits "$(du -sb "$kept" | cut -f1)"; then
        tar -czf - "$kept" | split -b "$part" -d - "$out/in-flight.tgz."
        echo "in flight: $furthest at iteration $furthest_iteration (in-flight.tgz.*)" >>"$out/summary.txt"
    else
        echo "LOST (no room after the networks above): the training in flight, $furthest at iteration $furthest_iteration" >>"$out/summary.txt"
    fi
fi
echo "runner's last lines:" >>"$out/summary.txt"
tail -n 5 "$out/runner.log" >>"$out/summary.txt"
cat "$out/summary.txt"
