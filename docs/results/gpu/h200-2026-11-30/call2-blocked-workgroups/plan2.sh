#!/usr/bin/env bash
# Device call 2 of 2026-11-30: the blocked kernels at a workgroup target of 256 (the
# output-layer benchmark's fastest blocked case in call 1) in whole iterations of 1, 5
# and 10 networks, alternated with the defaults over two rounds.
set -uo pipefail
for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig
export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
m=/tmp/m2; mkdir -p $m; cp gpu-run/plan2.sh $m/
b() { local name=$1; shift; env "$@" gpu-run/pvrnn --threads 16 bench --json --profile --backend wgpu --gpu-recurrence --only train --train-iterations 30 $NET >> $m/$name.jsonl 2>>$m/log.txt || echo "FAILED $name"; }
for round in 1 2; do
  NET=""; b whole X=1; b whole-blocked PVRNN_WGPU_OUTPUT_KERNELS=blocked; b whole-blocked-wg256 PVRNN_WGPU_OUTPUT_KERNELS=blocked PVRNN_WGPU_WORKGROUPS=256; b whole-wg256 PVRNN_WGPU_WORKGROUPS=256
  NET="--networks 5"; b whole-5 X=1; b whole-5-blocked PVRNN_WGPU_OUTPUT_KERNELS=blocked; b whole-5-blocked-wg256 PVRNN_WGPU_OUTPUT_KERNELS=blocked PVRNN_WGPU_WORKGROUPS=256
done
NET="--networks 10"; b whole-10-blocked-wg256 PVRNN_WGPU_OUTPUT_KERNELS=blocked PVRNN_WGPU_WORKGROUPS=256; b whole-10 X=1
python3 - $m <<'PY'
import json,pathlib,sys,statistics
for f in sorted(pathlib.Path(sys.argv[1]).glob('*.jsonl')):
    rs=[json.loads(l) for l in f.read_text().splitlines() if l.strip()]
    t=[r['train_iter_s'] for r in rs]
    print(f"{f.stem:28} s/iter {' '.join(f'{x:.4f}' for x in t)}  net-it/s {statistics.mean(r.get('networks',1)/r['train_iter_s'] for r in rs):.1f}  F {rs[-1].get('train_free_energy')}  MB {rs[-1].get('gpu_buffer_mb')}")
PY
tar czf $OUT/m2.tgz -C /tmp m2
