#!/usr/bin/env bash
# The glTF export checked by a real consumer (issue 28): export a stage-2 run, render two test
# views with Blender's Cycles from the exported cameras, render the same views with `i2sdf edit`
# (empty spec: the unedited recovered scene) and compare both with the test images (PSNR on the
# 8-bit sRGB images).
#   docs/experiments/export_blender.sh RUN ROOM OUT [SPP]
# ROOM: the dataset whose test views are scored (the exact room for a capture's run). Needs
# `blender` (Debian's 3.4 with python3-numpy), python3 with numpy and Pillow; optionally the
# Khronos validator (`npm install gltf-validator`, run from OUT/node_modules).
set -euo pipefail
RUN=$1 ROOM=$2 OUT=$3 SPP=${4:-512}
BIN=${I2SDF:-target/release/i2sdf}
mkdir -p "$OUT"
"$BIN" export --run "$RUN" --data "$ROOM" --out "$OUT/room.glb" --force
: > "$OUT/empty.toml"
for v in 0 1; do
  "$BIN" edit --run "$RUN" --data "$ROOM" --spec "$OUT/empty.toml" --out "$OUT/edit_$v" --view $v --force
done
python3 - "$ROOM" "$OUT" "$SPP" "$BIN" <<'PY'
import json, os, subprocess, sys
import numpy as np
from PIL import Image
room, out, spp, binary = sys.argv[1:5]
frames = [f for f in json.load(open(os.path.join(room, 'transforms.json')))['frames'] if f.get('split') == 'test']
load = lambda p: np.asarray(Image.open(p).convert('RGB'), dtype=np.float64) / 255
psnr = lambda a, b: -10 * np.log10(((a - b) ** 2).mean())
for v in (0, 1):
    name = os.path.splitext(os.path.basename(frames[v]['file_path']))[0]
    png = os.path.join(out, f'blender_{name}.png')
    subprocess.run(['blender', '-b', '--factory-startup', '--python', 'scripts/blender_render.py', '--',
                    '--scene', os.path.join(out, 'room.glb'), '--camera', f'test_{name}', '--out', png,
                    '--spp', spp], check=True, stdout=subprocess.DEVNULL)
    test = load(os.path.join(room, frames[v]['file_path']))
    edit = load(os.path.join(out, f'edit_{v}', f'{name}.png'))
    blend = load(png)
    print(f'{name}: Blender vs test {psnr(blend, test):.2f} dB, Blender vs i2sdf edit {psnr(blend, edit):.2f} dB, '
          f'i2sdf edit vs test {psnr(edit, test):.2f} dB')
PY
