#!/usr/bin/env bash
# Device call 3 (2026-11-28): the row pass's shapes (rows per workgroup x columns per
# step) and one chunk against the default, kernels alone, checked and unchecked; then whole
# learning iterations (1 and 5 networks, --gpu-recurrence) with the fastest shape against
# the default, alternated over two rounds in the same call. Results tarred into $OUT.
set -uo pipefail
if [ -d /usr/local/nvidia ]; then
  for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig
  export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
fi
m=/tmp/m3; mkdir -p $m; cd "$(dirname "$0")/.."
date -u > $m/date.txt; nvidia-smi -L >> $m/date.txt 2>&1
timeout 70 gpu-run/output_layer > $m/kernels-checked.txt 2>&1
PVRNN_WGPU_UNCHECKED=1 timeout 50 gpu-run/output_layer learning > $m/kernels-unchecked.txt 2>&1
cat $m/kernels-checked.txt $m/kernels-unchecked.txt
best=$(grep -E '^learning, row pass' $m/kernels-checked.txt | sed -E 's/^learning, row pass ([0-9]+) rows, ([0-9]+) per step.*: +([0-9.]+) ms per call.*/\3 \1 \2/' | sort -n | head -1)
ms() { grep -E "^$1 " $m/kernels-checked.txt | sed -E 's/.*: +([0-9.]+) ms per call.*/\1/'; }
chunk=64; if python3 -c "import sys; sys.exit(not float('$(ms 'learning, one chunk')') < 0.95*float('$(ms 'learning, full batch')'))"; then chunk=768; fi
echo "best row pass (ms rows step): $best; chunk MiB: $chunk" | tee -a $m/date.txt
read -r _ rows step <<<"$best"
B="PVRNN_WGPU_ROW_PASS_ROWS=$rows PVRNN_WGPU_ROW_PASS_STEP=$step PVRNN_WGPU_CHUNK_MB=$chunk"
bench() { local name=$1; shift
  timeout 40 env "$@" gpu-run/pvrnn --threads 16 bench --json --profile --only train --train-iterations 30 \
    --backend wgpu --gpu-recurrence ${NETS:+--networks $NETS} >> $m/$name.jsonl 2>> $m/log.txt || echo "FAILED $name" | tee -a $m/log.txt
}
for round in 1 2; do
  NETS=5 bench whole-5-default X=1
  NETS=5 bench whole-5-best $B
  NETS=5 bench whole-5-best-unchecked $B PVRNN_WGPU_UNCHECKED=1
  NETS= bench whole-default X=1
  NETS= bench whole-best $B
  NETS= bench whole-best-unchecked $B PVRNN_WGPU_UNCHECKED=1
done
NETS=16 bench whole-16-best $B
python3 - $m <<'PY' | tee $m/summary.txt
import json, pathlib, sys
for f in sorted(pathlib.Path(sys.argv[1]).glob("*.jsonl")):
    rs = [json.loads(l) for l in f.read_text().splitlines() if l.strip()]
    fe = rs[0].get('train_free_energy')
    print(f"{f.stem:26} s/iter {[round(r['train_iter_s'], 4) for r in rs]} "
          f"net-iter/s {[round(r['network_iterations_per_s'], 1) for r in rs]} "
          f"GPU MB {[round(r.get('gpu_buffer_mb') or 0) for r in rs]} F {fe[-1] if isinstance(fe, list) else fe}")
PY
date -u >> $m/date.txt
tar czf $OUT/m3.tgz -C /tmp m3
