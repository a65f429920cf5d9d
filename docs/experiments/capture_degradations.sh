#!/usr/bin/env bash
# Issue 24's capture figures (docs/results.md, "Your own room"): each phone-capture degradation
# alone on the small living room, the COLMAP import against transforms.json, and the default
# room's full capture through both stages. Usage, from the repository root after
# `cargo build --release`:
#   docs/experiments/capture_degradations.sh WORK_DIR [small|poses|colmap|full]...
# COLMAP needs a Python with pycolmap, numpy and pillow as $PYCOLMAP_PYTHON.
set -euo pipefail
I=${I2SDF:-$PWD/target/release/i2sdf}
HERE=$(cd "$(dirname "$0")" && pwd)
W=$1; shift
mkdir -p "$W"; cd "$W"
S="--width 80 --height 60 --views 24 --spp 32 --seed 1"
QUICK_S2="--set stage2.iterations=400 --set stage2.cache_pixels=32768 --set stage2.cache_samples=64 --set stage2.bake_resolution=128"

synth() { [ -f "$1/transforms.json" ] || "$I" synth --out "$1" "${@:2}" > "$1.synth.log" 2>&1; }
summary() { # RUN: the eval figures as one JSON line
  python3 - "$1" <<'PY'
import json, sys
r = json.load(open(sys.argv[1] + ".eval.json")); g = r["geometry"]; m = g.get("mesh") or {}
print(json.dumps({"run": sys.argv[1], "psnr": r["novel_view"]["psnr"], "F": m.get("fscore"),
  "thin2": (g.get("thin_objects") or {}).get("recall_2cm"), "depth_l1": g.get("depth_l1"),
  "normal": g.get("normal_angular_l1"), "poses": r.get("poses"), "rerender": r["rerender"].get("psnr"),
  "kd": r["material"].get("albedo_psnr"), "emitters": r["emitters"]}))
PY
}
stage1() { # DATA RUN SCORE_AGAINST [--set ...]: 800 iterations of stage 1, eval at mesh 256
  rm -rf "$2"
  "$I" train --data "$1" --out "$2" --stage geometry --quiet --set train.iterations=800 "${@:4}"
  "$I" eval --run "$2" --data "$3" --out "$2.eval.json" --mesh-resolution 256 --force > /dev/null
  summary "$2"
}
stage2() { # DATA RUN: the quick demo's stage 2 on a copy of a stage-1 run, eval against exact
  rm -rf "$2_s2"; cp -r "$2" "$2_s2"
  "$I" train --data "$1" --out "$2_s2" --stage material --quiet $QUICK_S2
  "$I" eval --run "$2_s2" --data exact --out "$2_s2.eval.json" --mesh-resolution 256 --spp 16 --bounces 4 --force > /dev/null
  summary "$2_s2"
}

pose_rows() {
  for d in pose05 pose2; do
    stage1 $d r_${d}_off exact --set pose.correction=off
    stage1 $d r_${d}_on exact
  done
  stage1 exact r_exact_on exact --set pose.correction=on
}

for what in "$@"; do case $what in
small)
  synth exact $S; synth jpeg $S --jpeg-quality 90; synth lens $S --lens opencv
  synth dhalf $S --depth-grid 2; synth dnoise $S --depth-noise sigma; synth nonormal $S --no-normals
  synth nomask $S --no-masks; synth pose05 $S --pose-noise 0.5,0.3; synth pose2 $S --pose-noise 2,1
  for d in exact jpeg lens dhalf dnoise nonormal nomask; do stage1 $d r_$d exact; done
  pose_rows
  stage2 exact r_exact; stage2 nomask r_nomask ;;
poses) # the pose rows alone: without and with the correction (on by default where poses are
  # not declared exact, as in these two), and the correction forced on for the exact room
  synth exact $S; synth pose05 $S --pose-noise 0.5,0.3; synth pose2 $S --pose-noise 2,1
  pose_rows ;;
colmap)
  synth cexact $S --depth-grid 1 --no-normals --no-hdr
  "${PYCOLMAP_PYTHON:-python3}" "$HERE/colmap_from_synth.py" cexact colmap_bin colmap_txt
  "$I" check --data colmap_bin | grep scale; "$I" check --data colmap_txt | grep scale
  stage1 cexact r_cexact cexact; stage1 colmap_bin r_colmap_bin colmap_bin ;;
full)
  synth room; synth capture --capture
  rm -rf full_run; "$I" train --data capture --out full_run --quiet
  "$I" eval --run full_run --data room --out full_run.eval.json --force > /dev/null; summary full_run ;;
*) echo "unknown part $what (small, poses, colmap, full)"; exit 2 ;;
esac; done
