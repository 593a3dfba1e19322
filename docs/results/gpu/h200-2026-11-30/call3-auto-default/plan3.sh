#!/usr/bin/env bash
# Device call 3 of 2026-11-30: the build that makes the blocked kernels the default for
# learning's calls (OutputKernels::Auto, workgroup target 256). The wgpu backend suites
# and agrees_with_cpu on the H200, then whole iterations of 1 and 5 networks as shipped
# against the fused kernels at the old target (the default before), alternated twice,
# and one `wgpu` bench with online inference as shipped.
set -uo pipefail
for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig
export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
m=/tmp/m3; rm -rf $m; mkdir -p $m; cp gpu-run/plan3.sh $m/
date -u > $m/date.txt
timeout 100 gpu-run/suite-wgpu > $m/suite-wgpu.txt 2>&1; echo "suite rc $?" >> $m/date.txt
timeout 100 gpu-run/agrees-with-cpu > $m/agrees-with-cpu.txt 2>&1; echo "agrees rc $?" >> $m/date.txt
tail -3 $m/suite-wgpu.txt $m/agrees-with-cpu.txt; grep -h "FAILED\|panicked" $m/*.txt | head
date -u >> $m/date.txt
b() { local name=$1; shift; env "$@" gpu-run/pvrnn --threads 16 bench --json --profile --backend wgpu --gpu-recurrence --only train --train-iterations 30 $NET >> $m/$name.jsonl 2>>$m/log.txt || echo "FAILED $name"; }
for round in 1 2; do
  NET=""; b whole X=1; b whole-fused-1024 PVRNN_WGPU_OUTPUT_KERNELS=fused PVRNN_WGPU_WORKGROUPS=1024
  NET="--networks 5"; b whole-5 X=1; b whole-5-fused-1024 PVRNN_WGPU_OUTPUT_KERNELS=fused PVRNN_WGPU_WORKGROUPS=1024
done
timeout 90 gpu-run/pvrnn --threads 16 bench --json --backend wgpu --train-iterations 10 --infer-steps 20 >> $m/wgpu.jsonl 2>>$m/log.txt || echo "FAILED wgpu"
date -u >> $m/date.txt
python3 - $m <<'PY'
import json,pathlib,sys,statistics
for f in sorted(pathlib.Path(sys.argv[1]).glob('*.jsonl')):
    rs=[json.loads(l) for l in f.read_text().splitlines() if l.strip()]
    t=[r['train_iter_s'] for r in rs]
    print(f"{f.stem:20} s/iter {' '.join(f'{x:.4f}' for x in t)}  net-it/s {statistics.mean(r.get('networks',1)/r['train_iter_s'] for r in rs):.1f}  F {rs[-1].get('train_free_energy')[-1] if isinstance(rs[-1].get('train_free_energy'),list) else rs[-1].get('train_free_energy')}  MB {rs[-1].get('gpu_buffer_mb')}  infer {rs[-1].get('infer_p16_steps_per_s')} {rs[-1].get('infer_full_steps_per_s')}  {rs[-1].get('backend')}")
PY
cat $m/date.txt
tar czf $OUT/m3.tgz -C /tmp m3
