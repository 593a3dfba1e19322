#!/usr/bin/env bash
# Device call 1 (2026-11-28): scripts/gpu-measure.sh on the lent GPU, 16 threads only,
# 30 training iterations and 20 inference steps per bench, two rounds, the output-layer
# kernels alone, nvidia-smi's memory read every 200 ms. Everything tarred into $OUT.
set -uo pipefail
if [ -d /usr/local/nvidia ]; then
  for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig
  export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
fi
m=/tmp/m; mkdir -p $m
date -u > $m/date.txt
nvidia-smi > $m/nvidia-smi.txt 2>&1
nproc >> $m/date.txt; lscpu | grep -i "model name" >> $m/date.txt
(nvidia-smi --query-gpu=timestamp,memory.used,utilization.gpu,clocks.sm --format=csv -lms 200 > $m/smi.csv 2>&1 &)
timeout 90 gpu-run/output_layer > $m/output-layer.txt 2>&1
THREADS=$(nproc) ITERATIONS=${ITERATIONS:-30} \
  timeout ${BUDGET:-420} scripts/gpu-measure.sh gpu-run/pvrnn $m/measure 2>&1 | tee $m/stdout.txt
pkill nvidia-smi
date -u >> $m/date.txt
tar czf $OUT/measure.tgz -C /tmp m
cp $m/measure/summary.txt $OUT/ 2>/dev/null || true
