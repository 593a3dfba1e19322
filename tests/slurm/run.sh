#!/usr/bin/env bash
# `pvrnn experiment --emit slurm` on a real Slurm: starts a single-node cluster on this
# machine (munge, slurmctld and slurmd, started directly: no systemd), plans a smoke-scale
# experiment, submits its job arrays with the emitted submit.sh, waits for them and checks
# the report. Needs root and Debian's slurm-wlm and munge (scripts/setup.sh installs them).
#
#   tests/slurm/run.sh [PVRNN]      PVRNN: the pvrnn executable (default target/release/pvrnn)
set -euo pipefail
cd "$(dirname "$0")/../.."
pvrnn=$(realpath "${1:-target/release/pvrnn}")
[ -x "$pvrnn" ] || { echo "no pvrnn executable at $pvrnn" >&2; exit 1; }
for tool in munged slurmctld slurmd sbatch squeue sacct scontrol; do
    command -v "$tool" >/dev/null || { echo "$tool is missing: apt-get install slurm-wlm munge" >&2; exit 1; }
done

work=$(mktemp -d /tmp/pvrnn-slurm.XXXXXX)
chmod 755 "$work"
conf="$work/slurm.conf"
export SLURM_CONF="$conf"
pids=()
cleanup() {
    scancel --user=root >/dev/null 2>&1 || true
    for pid in "${pids[@]}"; do kill "$pid" 2>/dev/null || true; done
    sleep 1
    for pid in "${pids[@]}"; do kill -9 "$pid" 2>/dev/null || true; done
    # Keep the folder when asked (PVRNN_KEEP_SLURM=1) or when the test failed.
    if [ "${PVRNN_KEEP_SLURM:-0}" = 1 ] || [ "${passed:-0}" != 1 ]; then
        echo "slurm test folder kept: $work" >&2
    else
        rm -rf "$work"
    fi
}
trap cleanup EXIT

# munge authenticates Slurm's daemons and commands to each other: a private key and socket.
# (The socket's folder must be open to all, the key's to munge alone.)
mkdir -p "$work/munge" "$work/munge-key"
chown munge: "$work/munge" "$work/munge-key"
chmod 755 "$work/munge"
chmod 700 "$work/munge-key"
dd if=/dev/urandom of="$work/munge-key/munge.key" bs=1024 count=1 status=none
chown munge: "$work/munge-key/munge.key"
chmod 400 "$work/munge-key/munge.key"
runuser -u munge -- munged --key-file="$work/munge-key/munge.key" \
    --socket="$work/munge/socket" --pid-file="$work/munge/munged.pid" \
    --log-file="$work/munge/munged.log" --seed-file="$work/munge/seed"
pids+=("$(cat "$work/munge/munged.pid")")

node=$(slurmd -C | head -1)
node_name=$(echo "$node" | sed -E 's/NodeName=([^ ]+).*/\1/')
mkdir -p "$work/state" "$work/spool" "$work/log"
cat >"$conf" <<EOF
ClusterName=pvrnn-test
SlurmctldHost=$node_name
SlurmUser=root
AuthType=auth/munge
AuthInfo=socket=$work/munge/socket
CredType=cred/munge
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
SchedulerType=sched/backfill
SwitchType=switch/none
MpiDefault=none
ReturnToService=2
StateSaveLocation=$work/state
SlurmdSpoolDir=$work/spool
SlurmctldPidFile=$work/slurmctld.pid
SlurmdPidFile=$work/slurmd.pid
SlurmctldLogFile=$work/log/slurmctld.log
SlurmdLogFile=$work/log/slurmd.log
SlurmctldPort=16817
SlurmdPort=16818
JobCompType=jobcomp/none
AccountingStorageType=accounting_storage/none
JobAcctGatherType=jobacct_gather/none
MaxArraySize=1000
$node
PartitionName=test Nodes=$node_name Default=YES MaxTime=INFINITE State=UP
EOF
slurmctld -f "$conf"
slurmd -f "$conf"
for _ in $(seq 60); do
    [ -f "$work/slurmctld.pid" ] && [ -f "$work/slurmd.pid" ] && sinfo -h -o '%t' 2>/dev/null | grep -qE '^(idle|mix|alloc)' && break
    sleep 1
done
pids+=("$(cat "$work/slurmctld.pid")" "$(cat "$work/slurmd.pid")")
sinfo -h -o '%t' | grep -qE '^(idle|mix|alloc)' || {
    echo "the node did not come up:" >&2
    sinfo >&2 || true
    tail -20 "$work/log/slurmctld.log" "$work/log/slurmd.log" >&2
    exit 1
}
echo "slurm is up: $(sinfo -h -o '%P %D nodes, %c CPUs, %t')" >&2

# A small benchmark and a smoke-scale experiment, planned for the cluster.
"$pvrnn" simulate --out "$work/data" --heights 650 --learn-per-height 1 \
    --test-per-height 1 --no-previews 2>/dev/null
"$pvrnn" experiment robustness --scale smoke --dataset "$work/data" --out "$work/exp" \
    --emit slurm --slurm-pvrnn "$pvrnn" --slurm-cpus 1 \
    --slurm-train-time 00:10:00 --slurm-infer-time 00:10:00
[ -x "$work/exp/slurm/submit.sh" ] || chmod +x "$work/exp/slurm/submit.sh"
"$work/exp/slurm/submit.sh"
echo "submitted: $(squeue -h | wc -l) tasks queued or running" >&2

# Every task (trainings, inference runs, the report) leaves the queue; none may fail.
for _ in $(seq 600); do
    [ -z "$(squeue -h)" ] && break
    sleep 1
done
if [ -n "$(squeue -h)" ]; then
    echo "jobs still queued after 10 minutes:" >&2
    squeue >&2
    exit 1
fi
report="$work/exp/report/report.md"
if ! grep -q "# Experiment: robustness (smoke scale)" "$report" 2>/dev/null; then
    echo "no report at $report; task outputs:" >&2
    tail -n 20 "$work"/exp/slurm/*.out >&2 || true
    exit 1
fi
if grep -l -iE "error|panicked" "$work"/exp/slurm/*.out >/dev/null 2>&1; then
    echo "a task reported an error:" >&2
    grep -iE -H "error|panicked" "$work"/exp/slurm/*.out >&2
    exit 1
fi
tasks=$(ls "$work"/exp/slurm/*.out | wc -l)
results=$(ls "$work"/exp/results | wc -l)
echo "slurm: $tasks array tasks ran, $results result files, report written" >&2
passed=1
