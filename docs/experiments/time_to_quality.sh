#!/usr/bin/env bash
# Time-to-quality curve of stage 1 (issue 26): one stage-1 run with snapshots at 1, 2, 3, 5 and
# 7 minutes of wall time (train.snapshot_seconds), stopped after the last one; each snapshot
# scored by `eval` against the room; `i2sdf bench` before and after. Prints a Markdown table and
# writes WORK/NAME.curve.csv.
#
#   docs/experiments/time_to_quality.sh ROOM WORK NAME [--set KEY=VALUE ...]
#
# Two configurations compared as a pair: run them one after the other on the same machine
# (nothing else on the cores), e.g. NAME=defaults, then NAME=grid with --set
# sampling.occupancy_resolution=64. A run that ends before the last snapshot is also scored at
# its end (the row "end", at the stage's own wall time).
set -euo pipefail
ROOM=$1 WORK=$2 NAME=$3
shift 3
I=${I2SDF:-$(dirname "$0")/../../target/release/i2sdf}
TIMES=(60 120 180 300 420)
RUN=$WORK/$NAME
mkdir -p "$WORK"
[ -e "$RUN" ] && { echo "$RUN exists: give another NAME or remove it" >&2; exit 2; }
"$I" bench --json > "$RUN.bench_before.json"
list=$(IFS=,; echo "${TIMES[*]}")
"$I" train --data "$ROOM" --out "$RUN" --stage geometry --quiet \
  --set "train.snapshot_seconds=[$list]" "$@" > "$RUN.train.log" 2>&1 &
pid=$!
last=$(printf "%s/snapshots/stage1-%05ds/run.json" "$RUN" "${TIMES[-1]}")
while kill -0 $pid 2>/dev/null && [ ! -f "$last" ]; do sleep 5; done
kill $pid 2>/dev/null || true
wait $pid 2>/dev/null || true
"$I" bench --json > "$RUN.bench_after.json"
echo "seconds,iteration,psnr,ssim,fscore,thin_2cm,thin_5cm,depth_l1" > "$RUN.curve.csv"
ended=""
[ -f "$last" ] || ended=end
for t in "${TIMES[@]}" $ended; do
  if [ "$t" = end ]; then
    snap=$RUN
  else
    snap=$(printf "%s/snapshots/stage1-%05ds" "$RUN" "$t")
  fi
  [ -f "$snap/run.json" ] || continue
  "$I" eval --run "$snap" --data "$ROOM" --out "$snap.eval.json" --mesh-resolution 256 --force > /dev/null 2>&1
  python3 - "$snap" "$t" >> "$RUN.curve.csv" <<'PY'
import json, sys
snap, t = sys.argv[1], sys.argv[2]
r = json.load(open(snap + ".eval.json")); g = r["geometry"]; m = g.get("mesh") or {}
th = g.get("thin_objects") or {}
stage = json.load(open(snap + "/run.json"))["stage1"]
it = stage["iterations"]
if t == "end":
    t = f"{stage['seconds']:.0f}"
print(",".join(str(x) for x in [t, it, r["novel_view"]["psnr"], r["novel_view"]["ssim"], m.get("fscore"),
      th.get("recall_2cm"), th.get("recall_5cm"), g.get("depth_l1")]))
PY
done
python3 - "$RUN" <<'PY'
import csv, json, sys
run = sys.argv[1]
b0, b1 = (json.load(open(f"{run}.bench_{w}.json")) for w in ("before", "after"))
print(f"{run}: bench before {b0['iteration_ms']:.1f} ms (median {b0['iteration_ms_median']:.1f}), "
      f"after {b1['iteration_ms']:.1f} ms (median {b1['iteration_ms_median']:.1f})")
print("| minutes | iteration | test PSNR | F @ 5 cm | thin @ 2 cm | thin @ 5 cm |")
print("|---|---|---|---|---|---|")
f = lambda v, d: "" if v in ("", "None") else f"{float(v):.{d}f}"
for row in csv.DictReader(open(f"{run}.curve.csv")):
    print(f"| {int(row['seconds']) / 60:.3g} | {row['iteration']} | {f(row['psnr'], 2)} | {f(row['fscore'], 3)} "
          f"| {f(row['thin_2cm'], 2)} | {f(row['thin_5cm'], 2)} |")
PY
