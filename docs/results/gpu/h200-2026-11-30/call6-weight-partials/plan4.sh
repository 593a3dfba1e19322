#!/usr/bin/env bash
# Device call 6 of 2026-11-30: the recurrent weight gradients as a partial sum per window
# and a reduce (the new default) against one thread per weight over every window
# (PVRNN_WGPU_RECURRENCE_WEIGHTS=serial, the path before). The wgpu suites, agrees_with_cpu
# and device_times on the H200 first; then whole learning iterations of 1 and 5 networks,
# both ways, alternated twice, with the device's time per part.
set -uo pipefail
for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig
export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
m=/tmp/m4; rm -rf $m; mkdir -p $m; cp gpu-run/plan4.sh $m/
date -u > $m/date.txt
for t in suite-wgpu agrees-with-cpu device-times; do
  timeout 100 gpu-run/$t > $m/$t.txt 2>&1; echo "$t rc $?" >> $m/date.txt; grep "test result" $m/$t.txt
done
b() { local name=$1; shift; env "$@" gpu-run/pvrnn --threads 16 bench --json --profile --backend wgpu --gpu-recurrence --only train --train-iterations 30 $NET >> $m/$name.jsonl 2>>$m/log.txt || echo "FAILED $name"; }
for round in 1 2; do
  NET=""; b whole X=1; b whole-serial PVRNN_WGPU_RECURRENCE_WEIGHTS=serial
  NET="--networks 5"; b whole-5 X=1; b whole-5-serial PVRNN_WGPU_RECURRENCE_WEIGHTS=serial
done
date -u >> $m/date.txt
python3 - $m <<'PY'
import json,pathlib,sys,statistics
for f in sorted(pathlib.Path(sys.argv[1]).glob('*.jsonl')):
    rs=[json.loads(l) for l in f.read_text().splitlines() if l.strip()]
    t=[r['train_iter_s'] for r in rs]
    fe=rs[-1].get('train_free_energy'); fe=fe[-1] if isinstance(fe,list) else fe
    print(f"{f.stem:16} s/iter {' '.join(f'{x:.4f}' for x in t)}  net-it/s {statistics.mean(r.get('networks',1)/r['train_iter_s'] for r in rs):.1f}  F {fe}  MB {rs[-1].get('gpu_buffer_mb')}")
    d={}
    for r in rs:
        for part in r.get('profile') or []:
            if part.get('part')!='train': continue
            for p in part['phases']:
                if p['phase'].startswith('device: '): d.setdefault(p['phase'][8:],[]).append(p['ms'])
    print('    '+'; '.join(f"{k[:28]} {statistics.mean(v):.2f}" for k,v in d.items()))
PY
cat $m/date.txt
tar czf $OUT/m4.tgz -C /tmp m4
