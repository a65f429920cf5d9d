#!/usr/bin/env bash
# Issue 27, item 6 (docs/results.md, "The paper's scale"): the default room at the paper's
# resolution, 640×480 with 200 views, trained with the defaults (stage 1) and scored; peak memory
# (GNU time's maximum resident set), the run log's per-iteration times and eval's time, with
# `i2sdf bench` before and after. The synthesis is 4 paths per pixel to fit a session (the test
# images are noisier than the default room's 128: their PSNR is not comparable; depth, normals
# and the mesh are exact).
# Usage, from the repository root after `cargo build --release`:
#   docs/experiments/paper_scale.sh WORK_DIR [ITERATIONS]      (default 5000, the defaults')
set -u
I=${I2SDF:-$PWD/target/release/i2sdf}; IT=${2:-5000}
mkdir -p "$1"; cd "$1"
$I bench --json > bench_before.json 2>/dev/null
[ -f room640/transforms.json ] || /usr/bin/time -f "synth %e s, peak %M KB" \
  $I synth --out room640 --width 640 --height 480 --views 200 --spp 4 > synth640.log 2>&1
rm -rf r640
/usr/bin/time -f "train %e s, peak %M KB" $I train --data room640 --out r640 --stage geometry \
  --set train.iterations=$IT --quiet > r640.train.log 2>&1
/usr/bin/time -f "eval %e s, peak %M KB" $I eval --run r640 --mesh-resolution 512 \
  --out r640.eval.json --force > r640.eval.log 2>&1
$I bench --json > bench_after.json 2>/dev/null
# Mean per-iteration times of the run log after the first 50 iterations.
python3 - <<'EOF'
import json
rows = [json.loads(l) for l in open("r640/log.jsonl")]
rows = [r for r in rows if r.get("stage") == "stage1" and r["iteration"] >= 50]
for k in ("ms_sampling", "ms_forward", "ms_backward"):
    print(k, round(sum(r[k] for r in rows) / len(rows), 1))
t = rows[-1]["time_s"] - rows[0]["time_s"]
print("s per iteration", round(t / (rows[-1]["iteration"] - rows[0]["iteration"]), 3))
EOF
echo finished
