#!/usr/bin/env bash
# Device call 1 of 2026-11-30 (docs/results/gpu/notes.md entry 9): the blocked output-layer
# kernels alone (deep and shallow against the fused), then scripts/gpu-measure.sh at 16
# threads, 30 iterations, two rounds of: whole, whole-blocked, whole-rec128, whole-5,
# whole-5-blocked, whole-5-encoded, whole-5-rec128, torch-graph. Everything tarred to $OUT.
set -uo pipefail
for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig
m=/tmp/m; mkdir -p $m
icd=$(ls /usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json /usr/share/vulkan/icd.d/nvidia_icd.json /etc/vulkan/icd.d/nvidia_icd.json 2>/dev/null | head -1)
[ -n "$icd" ] && export VK_DRIVER_FILES=$icd
export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
{ echo "icd: $icd"; ldconfig -p | grep -i "vulkan\|GLX_nvidia\|GLdispatch"; find / -name "nvidia_icd*.json" -not -path "/proc/*" 2>/dev/null; } > $m/vulkan.txt 2>&1
cat $m/vulkan.txt
cp gpu-run/plan.sh $m/
date -u > $m/date.txt
nvidia-smi > $m/nvidia-smi.txt 2>&1
nproc >> $m/date.txt; lscpu | grep -i "model name" >> $m/date.txt
(nvidia-smi --query-gpu=timestamp,memory.used,utilization.gpu,clocks.sm --format=csv -lms 500 > $m/smi.csv 2>&1 &)
echo "output layer start $(date -u +%T)" >> $m/date.txt
timeout 120 gpu-run/output_layer > $m/output-layer.txt 2>&1
cat $m/output-layer.txt
if grep -q "^no GPU" $m/output-layer.txt; then tar czf $OUT/measure.tgz -C /tmp m; exit 1; fi
echo "measure start $(date -u +%T)" >> $m/date.txt
THREADS=16 ITERATIONS=30 VARIANTS="whole whole-blocked whole-rec128 whole-5 whole-5-blocked whole-5-encoded whole-5-rec128 torch-graph" \
  timeout ${BUDGET:-380} scripts/gpu-measure.sh gpu-run/pvrnn $m/measure > $m/stdout.txt 2>&1
cat $m/stdout.txt | tail -60
pkill nvidia-smi
date -u >> $m/date.txt
cat $m/date.txt
tar czf $OUT/measure.tgz -C /tmp m
cp $m/measure/summary.txt $OUT/ 2>/dev/null || true
