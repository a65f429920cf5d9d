#!/usr/bin/env bash
# Issue 27's baseline rows (docs/results.md, "Scored like the paper"): the defaults, VolSDF-D and
# the MonoSDF-like configuration at 2000 stage-1 iterations, each scored with `eval --split both`.
# Usage, from the repository root after `cargo build --release`:
#   docs/experiments/baseline_rows.sh WORK_DIR [SEED]      (SEED: synth's --seed, default 0)
set -u
I=${I2SDF:-$PWD/target/release/i2sdf}; C=$PWD/configs; SEED=${2:-0}
mkdir -p "$1"; cd "$1"
$I bench --json > bench_before.json 2>/dev/null
[ -f room/transforms.json ] || /usr/bin/time -f "synth %e s" $I synth --out room --seed $SEED > synth.log 2>&1
for row in defaults volsdf_d monosdf_like; do
  cfg=""; [ $row != defaults ] && cfg="--config $C/$row.toml"
  rm -rf r_$row
  /usr/bin/time -f "$row train %e s" $I train --data room --out r_$row $cfg --set train.iterations=2000 --stage geometry --quiet > r_$row.train.log 2>&1
  /usr/bin/time -f "$row eval %e s" $I eval --run r_$row --split both --mesh-resolution 512 --out r_$row.eval.json --force > r_$row.eval.log 2>&1
done
$I bench --json > bench_after.json 2>/dev/null
echo finished
