#!/usr/bin/env bash
# Device call 1 of 2026-11-30/12-01 (issue 34): the wgpu suites on the H200 (the vec4,
# bias-lane and early-load kernels were tested on lavapipe only), then the prepared
# measurement: every variant alternated over two rounds, 30 iterations each.
set -uo pipefail
m=$OUT/m1; mkdir -p $m; cp lease/plan1.sh $m/
for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig
export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
date -u > $m/date.txt; nvidia-smi --query-gpu=name,driver_version --format=csv >> $m/date.txt
for t in suite-wgpu agrees-with-cpu device-times; do
  timeout 120 lease/$t > $m/$t.txt 2>&1; echo "$t rc $?" >> $m/date.txt; grep "test result" $m/$t.txt
done
date -u >> $m/date.txt
VARIANTS="whole whole-waited whole-kernels whole-late whole-scalar-io whole-chunk128 whole-loads30 whole-5 whole-5-waited whole-5-kernels whole-5-late whole-5-scalar-io cpu torch-graph" \
  CHUNKS=128 LOADS=30 KERNEL_WORKGROUPS="" THREADS=16 ITERATIONS=30 \
  timeout 330 scripts/gpu-measure.sh lease/pvrnn $m/measure > $m/measure.txt 2>&1
echo "measure rc $?" >> $m/date.txt
date -u >> $m/date.txt
cat $m/date.txt; cat $m/measure/summary.txt 2>/dev/null || tail -20 $m/measure.txt
cd $OUT && tar czf m1.tgz m1 && rm -rf m1
