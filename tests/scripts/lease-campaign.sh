#!/usr/bin/env bash
# scripts/lease-campaign.sh on scratch copies, with a stand-in for the runner: the loan's
# deadline stops the runner with SIGTERM, what finished comes back in results.tgz, the
# network of a finished training whose inference runs did not all run comes back to where
# its runs read it, and the training that had run furthest without finishing comes back in
# parts and is put back in training/in-flight/ on the other machine, byte for byte, for
# experiments.sh to resume; where what a loan returns has no room for it, the summary says
# it is lost.
set -euo pipefail
scripts=$(realpath "$(dirname "$0")/../../scripts")
work=$(mktemp -d /tmp/pvrnn-lease.XXXXXX)
trap 'rm -rf "$work"' EXIT
fail() { echo "lease-campaign test: $*" >&2; exit 1; }

# The machine lent: a checkout with the plan, and a runner that finishes one training,
# leaves two in flight (network 1 further than network 2) and waits to be stopped.
lent=$work/lent
mkdir -p "$lent/scripts" "$lent/docs/results/converged/interference/results"
cp "$scripts/experiments.sh" "$scripts/lease-campaign.sh" "$scripts/gpu-host.sh" "$lent/scripts/"
# Network 0 finished; one of its two inference runs ran.
cat > "$lent/docs/results/converged/interference/plan.json" <<EOF
{
  "dataset": "$lent/data/caresim-robotfree",
  "jobs": [
    {"id": 0, "name": "train-repositioning-plus3-net0", "kind": "train"},
    {"id": 1, "name": "train-repositioning-plus3-net1", "kind": "train"},
    {"id": 2, "name": "infer-repositioning-plus3-net0-a", "kind": "infer", "train_job": 0},
    {"id": 3, "name": "infer-repositioning-plus3-net0-b", "kind": "infer", "train_job": 0}
  ]
}
EOF
cat > "$work/pvrnn" <<'EOF'
#!/usr/bin/env bash
shift 2 # --threads N
case "$1" in
simulate) out=${*: -1}; mkdir -p "$out"; echo '{}' > "$out/dataset.json" ;;
experiment)
    echo "$*" > runner-args.txt
    n=training/converged-interference r=docs/results/converged/interference/results
    mkdir -p "$n"
    for net in 0 1 2; do
        stem=$n/converged-train-repositioning-plus3-net$net
        printf 'iteration,total\n0,1.0\n%d,0.5\n' $((300 - 100 * (net == 2) + 200 * (net == 0))) > "$stem.log.csv"
        echo "validations of $net" > "$stem.validation.csv"
        head -c $((2500000 + net)) /dev/urandom > "$stem.safetensors"
        echo "best of $net" > "$stem.best.safetensors"
    done
    echo '{"job": "train-repositioning-plus3-net0", "iterations": 500, "network_iteration": 300}' \
        > "$r/train-repositioning-plus3-net0.json"
    echo run > "$r/infer-repositioning-plus3-net0-a.safetensors"
    trap 'echo "interrupted: checkpoints written"; exit 130' TERM
    sleep 120 &
    wait
    ;;
esac
EOF
chmod +x "$work/pvrnn"

(cd "$lent" && PART_MB=1 BACKEND=cpu GPU_RECURRENCE= scripts/lease-campaign.sh "$work/pvrnn" \
    "$work/out" 3 > "$work/lease.log" 2>&1) || fail "the loan's script failed: $(cat "$work/lease.log")"
grep -q -- "--scale converged .*--cohort 2" "$lent/runner-args.txt" ||
    fail "the runner was not asked for the converged plan in cohorts: $(cat "$lent/runner-args.txt")"
grep -q "exit status 124" "$work/out/summary.txt" || fail "not stopped at the deadline: $(cat "$work/out/summary.txt")"
grep -q "^  train-repositioning-plus3-net0$" "$work/out/summary.txt" ||
    fail "the finished training is not listed: $(cat "$work/out/summary.txt")"
grep -q "plus3-net1 at iteration 300" "$work/out/summary.txt" ||
    fail "network 1 (iteration 300) is the furthest in flight: $(cat "$work/out/summary.txt")"
parts=$(ls "$work/out"/in-flight.tgz.* | wc -l)
[ "$parts" -ge 3 ] || fail "a 2.5 MB checkpoint in parts of 1 MiB came back in $parts parts"
for f in "$work/out"/*; do
    [ "$(stat -c %s "$f")" -le $((1 << 20)) ] || [[ "$f" != *in-flight* ]] || fail "$f is over PART_MB"
done

# Back here: a checkout without the trainings; the results and the kept training come back.
here=$work/here
mkdir -p "$here/scripts"
cp "$scripts/experiments.sh" "$scripts/lease-campaign.sh" "$here/scripts/"
(cd "$here" && scripts/lease-campaign.sh --unpack "$work/out" > "$work/unpack.log" 2>&1) ||
    fail "--unpack failed: $(cat "$work/unpack.log")"
stem=training/converged-interference/converged-train-repositioning-plus3-net1
[ "$(cat "$here/training/in-flight/stem.txt")" = "$stem" ] || fail "kept $(cat "$here/training/in-flight/stem.txt")"
cmp -s "$here/training/in-flight/checkpoint.safetensors" "$lent/$stem.safetensors" ||
    fail "the checkpoint came back changed"
cmp -s "$here/training/in-flight/best.safetensors" "$lent/$stem.best.safetensors" ||
    fail "the best network came back changed"
[ -f "$here/docs/results/converged/interference/results/train-repositioning-plus3-net0.json" ] ||
    fail "the finished training's result did not come back"
cmp -s "$here/$stem.validation.csv" "$lent/$stem.validation.csv" || fail "the validations did not come back"
owed=training/converged-interference/converged-train-repositioning-plus3-net0.best.safetensors
cmp -s "$here/$owed" "$lent/$owed" || fail "network 0, whose inference runs did not all run, did not come back"
[ ! -e "$here/${owed%.best.safetensors}.safetensors" ] || fail "network 0's checkpoint came back too"

# A loan returning fewer files: network 0 comes back, the training in flight has no room
# left and the summary says it is lost.
rm -rf "$lent/training" "$lent/runner-args.txt"
(cd "$lent" && PART_MB=1 BACK_FILES=5 BACKEND=cpu GPU_RECURRENCE= scripts/lease-campaign.sh \
    "$work/pvrnn" "$work/small" 3 > "$work/small.log" 2>&1) || fail "the small loan failed: $(cat "$work/small.log")"
compgen -G "$work/small/networks.tgz.*" >/dev/null || fail "network 0 did not come back in the small loan"
! compgen -G "$work/small/in-flight.tgz.*" >/dev/null || fail "the training in flight came back without room"
grep -q "^LOST (no room after the networks above): the training in flight" "$work/small/summary.txt" ||
    fail "the summary does not say the training in flight is lost: $(cat "$work/small/summary.txt")"
# A loan that finished the training kept here and left none in flight: the kept one is
# cleared, not resumed again.
again=$work/again
mkdir -p "$again/scripts" "$again/training/in-flight" "$work/finished"
cp "$scripts/experiments.sh" "$scripts/lease-campaign.sh" "$again/scripts/"
cp "$work/out/results.tgz" "$work/out/summary.txt" "$work/finished/"
echo training/converged-interference/converged-train-repositioning-plus3-net0 > "$again/training/in-flight/stem.txt"
(cd "$again" && scripts/lease-campaign.sh --unpack "$work/finished" > "$work/again.log" 2>&1) ||
    fail "--unpack without a training in flight failed: $(cat "$work/again.log")"
[ ! -e "$again/training/in-flight" ] || fail "the finished training is still kept: $(cat "$work/again.log")"
echo "lease-campaign test: passed"
