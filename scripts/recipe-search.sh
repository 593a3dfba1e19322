#!/usr/bin/env bash
# One training of the recipe search (docs/results/README.md, "Recipe search"): the paper's
# configuration or a named departure from it, trained on caresim seed 0 and scored on the
# held-out caresim seed 1 every VALIDATE_EVERY iterations; stops at ITERATIONS or when
# PATIENCE validations in a row did not beat the best. Run it again to resume.
#
#   scripts/recipe-search.sh WORKDIR RECIPE [ITERATIONS]
#
# RECIPE: paper | data-x3 (3x the learning sequences: 9 per task and bed height, new
# seeds; the paper's 18 among them) | any training/recipes/NAME.toml (w-half, w-double,
# log-sigma-bound, ...). Writes WORKDIR/RECIPE/run.safetensors (revision 2:
# WORKDIR/r2-RECIPE/; resumable), its log,
# run.validation.csv, run.best.safetensors (the validation-best checkpoint) and
# run.iter<N>.safetensors every VALIDATE_EVERY iterations. Environment: THREADS (default
# 1: two recipes train side by side on two cores), VALIDATE_EVERY (2000), PATIENCE (none),
# BACKEND (cpu; `wgpu` on a GPU machine), PVRNN (the binary; default target/release/pvrnn),
# REVISION (caresim's, 1 or 2; default 1: docs/caresim.md, "Revisions"; revision 2's data
# goes to WORKDIR/data/r2-*), TASKS (one task, `repositioning` or `wiping`: learned and
# validated on that task's sequences only; runs and data get the task in their names, e.g.
# WORKDIR/r2-wiping-paper/ and WORKDIR/data/r2-wiping-seed1/).
set -euo pipefail
cd "$(dirname "$0")/.."

usage="usage: scripts/recipe-search.sh WORKDIR RECIPE [ITERATIONS]"
work=${1:?$usage}
recipe=${2:?$usage}
iterations=${3:-40000}
pvrnn=${PVRNN:-target/release/pvrnn}
[ -x "$pvrnn" ] || cargo build --release -p pvrnn-cli
every=${VALIDATE_EVERY:-2000}

revision=${REVISION:-1}
case "$revision" in
1) prefix=caresim ;;
2) prefix=r2 ;;
*) echo "REVISION must be 1 or 2, not $revision" >&2; exit 2 ;;
esac
tasks=()
case "${TASKS:-}" in
"") ;;
repositioning | wiping) prefix=$prefix-$TASKS tasks=(--tasks "$TASKS") ;;
*) echo "TASKS must be repositioning or wiping, not $TASKS" >&2; exit 2 ;;
esac
data=$work/data/$prefix
config=()
case "$recipe" in
paper) ;;
data-x3) data=$work/data/$prefix-x3 ;;
*)
    toml=training/recipes/$recipe.toml
    [ -f "$toml" ] || { echo "no recipe $recipe (no $toml)" >&2; exit 2; }
    config=(--config "$toml")
    ;;
esac

simulate() { # folder, extra flags
    [ -f "$1/dataset.json" ] ||
        "$pvrnn" simulate --out "$1" --no-previews --revision "$revision" "${tasks[@]}" "${@:2}"
}
simulate "$work/data/$prefix" --seed 0
simulate "$work/data/$prefix-seed1" --seed 1
[ "$recipe" = data-x3 ] && simulate "$data" --seed 0 --learn-per-height 9

run=$work/$recipe
[ "$revision" = 1 ] || run=$work/r2-$recipe
[ -z "${TASKS:-}" ] || run=$work/$prefix-$recipe
mkdir -p "$run"
flags=(--inputs "$data" --out "$run/run.safetensors" --iterations "$iterations"
    --checkpoint-every 500 --keep-every "$every"
    --validate "$work/data/$prefix-seed1" --validate-every "$every")
[ -n "${PATIENCE:-}" ] && flags+=(--patience "$PATIENCE")
[ -n "${BACKEND:-}" ] && flags+=(--backend "$BACKEND")
if [ -f "$run/run.safetensors" ]; then
    exec "$pvrnn" --threads "${THREADS:-1}" train --resume "${flags[@]}"
fi
"$pvrnn" init --dataset "$data" --seed 0 "${config[@]}" --out "$run/init.safetensors"
exec "$pvrnn" --threads "${THREADS:-1}" train --model "$run/init.safetensors" "${flags[@]}"
