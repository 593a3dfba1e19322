#!/usr/bin/env bash
# Device call 2 (2026-11-28): the output layer's cuts and wgpu's runtime checks, kernels
# alone, then whole learning iterations (1 and 5 networks, --gpu-recurrence) with the
# fastest cut against the default, alternated, in the same call. Results tarred into $OUT.
set -uo pipefail
if [ -d /usr/local/nvidia ]; then
  for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig
  export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
fi
m=/tmp/m2; mkdir -p $m; cd "$(dirname "$0")/.."
date -u > $m/date.txt; nvidia-smi -L >> $m/date.txt 2>&1
timeout 60 gpu-run/output_layer > $m/kernels-checked.txt 2>&1
PVRNN_WGPU_UNCHECKED=1 timeout 40 gpu-run/output_layer learning > $m/kernels-unchecked.txt 2>&1
cat $m/kernels-checked.txt $m/kernels-unchecked.txt
# The fastest cut of learning's full batch (checked): "learning, C MiB, S col ranges, W wg".
best=$(grep -E '^learning, [0-9]+ MiB' $m/kernels-checked.txt | sed -E 's/^learning, ([0-9]+) MiB, ([0-9]+) col ranges, ([0-9]+) wg.*: +([0-9.]+) ms per call.*/\4 \1 \2 \3/' | sort -n | head -1)
echo "best cut (ms chunk_mb column_splits workgroups): $best" | tee -a $m/date.txt
read -r _ chunk splits wg <<<"$best"
bench() { # name, env..., then -- and bench args
  local name=$1; shift
  timeout 40 env "$@" gpu-run/pvrnn --threads 16 bench --json --profile --only train --train-iterations 30 \
    --backend wgpu --gpu-recurrence ${NETS:+--networks $NETS} >> $m/$name.jsonl 2>> $m/log.txt || echo "FAILED $name" | tee -a $m/log.txt
}
for round in 1; do
  NETS=5 bench whole-5-default X=1
  NETS=5 bench whole-5-best PVRNN_WGPU_CHUNK_MB=$chunk PVRNN_WGPU_COLUMN_SPLITS=$splits PVRNN_WGPU_WORKGROUPS=$wg
  NETS=5 bench whole-5-best-unchecked PVRNN_WGPU_CHUNK_MB=$chunk PVRNN_WGPU_COLUMN_SPLITS=$splits PVRNN_WGPU_WORKGROUPS=$wg PVRNN_WGPU_UNCHECKED=1
  NETS= bench whole-default X=1
  NETS= bench whole-best PVRNN_WGPU_CHUNK_MB=$chunk PVRNN_WGPU_COLUMN_SPLITS=$splits PVRNN_WGPU_WORKGROUPS=$wg
done
python3 - $m <<'PY' | tee $m/summary.txt
import json, pathlib, statistics, sys
for f in sorted(pathlib.Path(sys.argv[1]).glob("*.jsonl")):
    rs = [json.loads(l) for l in f.read_text().splitlines() if l.strip()]
    print(f"{f.stem:28} s/iter {[round(r['train_iter_s'], 4) for r in rs]} "
          f"net-iter/s {[round(r['network_iterations_per_s'], 1) for r in rs]} "
          f"GPU MB {[round(r.get('gpu_buffer_mb') or 0) for r in rs]} F {[r['train_free_energy'][-1] if isinstance(r.get('train_free_energy'), list) else r.get('train_free_energy') for r in rs][:1]}")
PY
date -u >> $m/date.txt
tar czf $OUT/m2.tgz -C /tmp m2
