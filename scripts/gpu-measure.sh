#!/usr/bin/env bash
# Times the wgpu backend on a machine with a GPU, every variant alternated in one call so
# that the figures compare (docs/gpu.md reports them only when they come from one call).
#
#   scripts/gpu-measure.sh [--quick] PVRNN_BINARY OUT_DIR
#
# Writes OUT_DIR/<variant>-round<R>.jsonl (one `pvrnn bench --json --profile` object per
# line) and OUT_DIR/summary.txt (mean seconds per training iteration and inference steps
# per second per variant), and prints the summary. Variants, each with all the host's
# threads and with 2:
#   cpu          the CPU backend
#   wgpu         the wgpu backend as it ships (read-outs and their optimiser resident)
#   host-weights `--weights-on-host`: weights uploaded and updated on the host every
#                iteration (the path before the resident learner)
#   whole        `--gpu-recurrence`: the recurrence on the GPU too, the whole learning
#                iteration there (recurrent weights and adaptive variables resident, one
#                submission, only the free-energy terms read back); training only (online
#                inference keeps the recurrence on the CPU: it would time `wgpu` again)
#   whole-N      `--gpu-recurrence --networks N` (N = 5, the paper's networks per
#                condition; NETWORKS overrides): N networks trained together, one
#                recurrence dispatch for all of them; training only
#   whole-kernels, whole-N-kernels
#                `whole` and `whole-N` with every dispatch timed apart
#                (`--profile-kernels`): the summary's device table then lists each
#                kernel's milliseconds per iteration ("kernel <label>"); a pass per
#                dispatch adds to the totals, so these time where, not how fast
#   whole-N-checked, whole-N-unchecked
#                `whole-N` with wgpu's runtime checks in every kernel (`--wgpu-checks all`)
#                and in none (`--wgpu-checks none`); the default checks every kernel but
#                the output layers' main passes (fused and blocked)
# (The variants of the switches deleted on 2026-12-06, which lost their measurements or
# were never timed, are in docs/gpu.md, "What was tried, measured and deleted".)
#   torch-eager, torch-graph
#                the same model in PyTorch on the same GPU (scripts/torch-reference.py),
#                eager and with the whole iteration captured in a CUDA graph; training
#                only, where python3 imports torch with CUDA
#   base-whole, base-whole-N, base-whole-kernels
#                `whole`, `whole-N` and `whole-kernels` run with another build, the
#                binary BASELINE names (set BASELINE to run them): two builds compared in
#                one call, alternated, without a switch in the code
# ITERATIONS=N and INFER_STEPS=N replace the training iterations and inference steps per
# bench (10 and 20; 3 and 5 with --quick); TORCH_ITERATIONS=N the PyTorch peer's (eager
# PyTorch took about 2 s per paper-scale iteration on an H200: 5 keep it under a minute).
# THREADS="16" replaces the thread counts (default: all the host's, and 2); VARIANTS="wgpu
# whole-5 torch-graph ..." runs only the variants it names (a lease too short for all).
# `--quick` runs one round of 3 training iterations (a smoke check of the set-up); the
# default is two rounds of 10 training iterations and 20 inference steps each (not yet
# run on a GPU: time it with --quick first). BENCH_ARGS adds options to every bench
# (`BENCH_ARGS="--sequences 2 --steps 40 --only train"` checks the script on a CPU
# Vulkan device in a few minutes).
#
# OUTPUT_BENCH=PATH (the output-layer kernel benchmark, built with `cargo bench -p
# pvrnn-wgpu --bench output_layer --no-run`) also times the output layer's kernels alone,
# fused and blocked, at the paper's shapes: OUT_DIR/output-layer.txt. OVERLAP_BENCH=PATH
# (`cargo bench -p pvrnn-wgpu --bench overlap --no-run`; lease-tree.sh pack --tests packs
# it) also runs the overlap probe: whether the device runs two dispatches with no barrier
# between them at once (OUT_DIR/overlap.txt).
#
# On a bare host whose image has the NVIDIA driver but no Vulkan loader: put the Debian
# packages of the loader in .gl/ (`apt-get download libvulkan1`, plus what it needs) and
# this script unpacks them first; VK_DRIVER_FILES is pointed at NVIDIA's ICD when it is
# where the lent machines keep it.
set -euo pipefail

quick=0
if [ "${1:-}" = "--quick" ]; then
    quick=1
    shift
fi
bin=${1:?usage: scripts/gpu-measure.sh [--quick] PVRNN_BINARY OUT_DIR}
out=${2:?usage: scripts/gpu-measure.sh [--quick] PVRNN_BINARY OUT_DIR}
mkdir -p "$out"

# shellcheck source=scripts/gpu-host.sh
source "$(dirname "$0")/gpu-host.sh"

if [ "$quick" = 1 ]; then
    rounds=1 iterations=3 steps=5
else
    rounds=2 iterations=10 steps=20
fi
iterations=${ITERATIONS:-$iterations} steps=${INFER_STEPS:-$steps}
all=$(nproc)
thread_counts=$all
if [ "$all" != 2 ]; then thread_counts="$all 2"; fi
thread_counts=${THREADS:-$thread_counts}

# The whole-iteration variants time learning alone (BENCH_ARGS may already choose a part).
train_only="--only train"
if [[ " ${BENCH_ARGS:-} " == *" --only "* ]]; then train_only=""; fi

wanted() { [ -z "${VARIANTS:-}" ] || [[ " $VARIANTS " == *" $1 "* ]]; }

bench() {
    local variant=$1 threads=$2 round=$3
    shift 3
    wanted "$variant" || return 0
    local file="$out/$variant-$threads-threads-round$round.jsonl"
    # shellcheck disable=SC2086 # BENCH_ARGS is a list of options
    if ! "$bin" --threads "$threads" bench --json --profile \
        --train-iterations "$iterations" --infer-steps "$steps" ${BENCH_ARGS:-} "$@" \
        >>"$file" 2>>"$out/log.txt"; then
        echo "FAILED: $variant, $threads threads, round $round (see $out/log.txt)" | tee -a "$out/log.txt"
    fi
}

"$bin" --version | tee "$out/version.txt"
for round in $(seq "$rounds"); do
    for threads in $thread_counts; do
        bench wgpu "$threads" "$round" --backend wgpu
        bench host-weights "$threads" "$round" --backend wgpu --weights-on-host
        bench whole "$threads" "$round" --backend wgpu --gpu-recurrence $train_only
        if [ -n "${BASELINE:-}" ]; then
            # bench runs "$bin": here the other build.
            bin=$BASELINE bench base-whole "$threads" "$round" --backend wgpu \
                --gpu-recurrence $train_only
            bin=$BASELINE bench "base-whole-${NETWORKS:-5}" "$threads" "$round" \
                --backend wgpu --gpu-recurrence --networks "${NETWORKS:-5}" $train_only
            bin=$BASELINE bench base-whole-kernels "$threads" "$round" --backend wgpu \
                --gpu-recurrence --profile-kernels $train_only
        fi
        bench "whole-${NETWORKS:-5}" "$threads" "$round" --backend wgpu --gpu-recurrence \
            --networks "${NETWORKS:-5}" $train_only
        bench whole-kernels "$threads" "$round" --backend wgpu --gpu-recurrence \
            --profile-kernels $train_only
        bench "whole-${NETWORKS:-5}-kernels" "$threads" "$round" --backend wgpu \
            --gpu-recurrence --profile-kernels --networks "${NETWORKS:-5}" $train_only
        for checks in all none; do
            name=$([ "$checks" = all ] && echo checked || echo unchecked)
            bench "whole-${NETWORKS:-5}-$name" "$threads" "$round" --backend wgpu \
                --gpu-recurrence --wgpu-checks "$checks" --networks "${NETWORKS:-5}" $train_only
        done
        bench cpu "$threads" "$round" --backend cpu
    done
    if python3 -c 'import torch, sys; sys.exit(not torch.cuda.is_available())' 2>/dev/null; then
        for mode in eager graph; do
            wanted "torch-$mode" || continue
            # shellcheck disable=SC2086 # BENCH_ARGS is a list of options
            python3 scripts/torch-reference.py time --mode "$mode" \
                --iterations "${TORCH_ITERATIONS:-$iterations}" \
                $(echo " ${BENCH_ARGS:-}" | grep -oE -- '--(sequences|steps) [0-9]+' | tr '\n' ' ') \
                >>"$out/torch-$mode-round$round.jsonl" 2>>"$out/log.txt" ||
                echo "FAILED: torch $mode, round $round (see $out/log.txt)" | tee -a "$out/log.txt"
        done
    fi
done

if [ -n "${OUTPUT_BENCH:-}" ]; then
    # Fused and blocked alternate within the run (the benchmark's own order).
    "$OUTPUT_BENCH" | tee "$out/output-layer.txt" ||
        echo "FAILED: the output-layer benchmark (see above)" | tee -a "$out/log.txt"
fi

if [ -n "${OVERLAP_BENCH:-}" ]; then
    "$OVERLAP_BENCH" | tee "$out/overlap.txt" ||
        echo "FAILED: the overlap probe (see above)" | tee -a "$out/log.txt"
fi

python3 - "$out" <<'EOF' | tee "$out/summary.txt"
import json, pathlib, statistics, sys
rows = {}
for f in sorted(pathlib.Path(sys.argv[1]).glob("*.jsonl")):
    variant = f.stem.rsplit("-round", 1)[0]
    for line in f.read_text().splitlines():
        if line.strip():
            rows.setdefault(variant, []).append(json.loads(line))
def mean(xs):
    xs = [x for x in xs if x is not None]
    return f"{statistics.mean(xs):.4f}" if xs else "-"
print(f"{'variant':36} {'train s/iter':>12} {'net-iter/s':>10} {'p16 steps/s':>12} "
      f"{'full steps/s':>12} {'GPU MB':>8}  backend")
for variant, rs in sorted(rows.items()):
    rate = [r.get('networks', 1) / r['train_iter_s'] for r in rs if r.get('train_iter_s')]
    print(f"{variant:36} {mean([r.get('train_iter_s') for r in rs]):>12} {mean(rate):>10} "
          f"{mean([r.get('infer_p16_steps_per_s') for r in rs]):>12} "
          f"{mean([r.get('infer_full_steps_per_s') for r in rs]):>12} "
          f"{mean([r.get('gpu_buffer_mb') or r.get('peak_gpu_mb') for r in rs]):>8}  "
          f"{rs[0].get('backend')}")
# The device's own time per part of a training iteration (`--profile` with
# `--gpu-recurrence`: timestamp queries), mean over rounds, where the variant has them.
device = {}
for variant, rs in sorted(rows.items()):
    for r in rs:
        for part in r.get('profile') or []:
            if part.get('part') != 'train':
                continue
            for p in part['phases']:
                if p['phase'].startswith('device: '):
                    runs = device.setdefault(variant, {}).setdefault(p['phase'][8:], [])
                    runs.append((p['ms'], p.get('times', 1.0)))
if device:
    print()
    print("device ms per training iteration (timestamp queries)")
    for variant, phases in device.items():
        # Kernels ("kernel <label>", --profile-kernels) are inside the parts.
        ms = {k: statistics.mean(m for m, _ in v) for k, v in phases.items()}
        total = sum(m for k, m in ms.items() if not k.startswith('kernel '))
        print(f"{variant:36} total {total:9.3f}")
        for phase, v in phases.items():
            # A kernel's dispatches per iteration (--profile-kernels).
            times = statistics.mean(t for _, t in v)
            count = f"  x{times:g}" if phase.startswith('kernel ') else ""
            print(f"    {phase:70} {ms[phase]:9.3f}{count}")
EOF
