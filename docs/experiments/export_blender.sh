#!/usr/bin/env bash
# The glTF export checked by a real consumer (issue 28): export a stage-2 run (textures, and
# vertex colours), render two test views with Blender's Cycles from the exported cameras, render
# the same views with `i2sdf edit` (empty spec: the unedited recovered scene) and compare them
# with each other and with the test images (PSNR on the 8-bit sRGB images; the mean linear
# brightness against `edit`'s over the pixels that are not emitters).
#   docs/experiments/export_blender.sh RUN ROOM OUT [SPP]
# ROOM: the dataset whose test views are scored (the exact room for a capture's run).
# Blender variants: "imported" (the scene as Blender 3.4's importer builds it: Principled BSDF),
# "exact" (--diffuse lambert --specular gltf: the file's BRDF as glTF states it), "lights" (the
# punctual lights of --lights alone). Needs `blender` (Debian's 3.4 with python3-numpy), python3
# with numpy and Pillow.
set -euo pipefail
RUN=$1 ROOM=$2 OUT=$3 SPP=${4:-512}
BIN=${I2SDF:-target/release/i2sdf}
mkdir -p "$OUT"
"$BIN" export --run "$RUN" --data "$ROOM" --out "$OUT/room.glb" --lights --force
"$BIN" export --run "$RUN" --data "$ROOM" --out "$OUT/room_vc.glb" --texture-size 0 --force
: > "$OUT/empty.toml"
for v in 0 1; do
  "$BIN" edit --run "$RUN" --data "$ROOM" --spec "$OUT/empty.toml" --out "$OUT/edit_$v" --view $v --force
done
# Blender from the shell: a Python interpreter of pyenv's would hand Blender's embedded Python
# its own environment, without Debian's numpy
NAMES=$(python3 -c "import json,os,sys; fs=[f for f in json.load(open(sys.argv[1]))['frames'] if f.get('split')=='test']; print(' '.join(os.path.splitext(os.path.basename(f['file_path']))[0] for f in fs[:2]))" "$ROOM/transforms.json")
render() { # NAME LABEL SCENE [ARGS...]
  local name=$1 label=$2 scene=$3; shift 3
  blender -b --factory-startup --python scripts/blender_render.py -- --scene "$OUT/$scene" \
    --camera "test_$name" --out "$OUT/blender_${name}_$label.png" --spp "$SPP" "$@" > "$OUT/blender_${name}_$label.log" 2>&1
  grep -q "^Saved:" "$OUT/blender_${name}_$label.log" || { echo "Blender failed: $OUT/blender_${name}_$label.log" >&2; exit 1; }
}
for name in $NAMES; do
  render "$name" textures_imported room.glb
  render "$name" textures_exact room.glb --diffuse lambert --specular gltf
  render "$name" vertex_colours_imported room_vc.glb
  render "$name" vertex_colours_exact room_vc.glb --diffuse lambert --specular gltf
  render "$name" textures_lights_only room.glb --lighting lights
done
python3 - "$ROOM" "$OUT" <<'PY'
import json, os, sys
import numpy as np
from PIL import Image
room, out = sys.argv[1:3]
frames = [f for f in json.load(open(os.path.join(room, 'transforms.json')))['frames'] if f.get('split') == 'test']
load = lambda p: np.asarray(Image.open(p).convert('RGB'), dtype=np.float64) / 255
linear = lambda x: np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)
psnr = lambda a, b: -10 * np.log10(((a - b) ** 2).mean())
variants = ['textures_imported', 'textures_exact', 'vertex_colours_imported', 'vertex_colours_exact',
            'textures_lights_only']
print('| view | Blender variant | vs test image | vs `i2sdf edit` | brightness / edit\'s |')
print('|---|---|---|---|---|')
for v in (0, 1):
    name = os.path.splitext(os.path.basename(frames[v]['file_path']))[0]
    test = load(os.path.join(room, frames[v]['file_path']))
    edit = load(os.path.join(out, f'edit_{v}', f'{name}.png'))
    for label in variants:
        b = load(os.path.join(out, f'blender_{name}_{label}.png'))
        keep = (b.max(-1) < 0.98) & (edit.max(-1) < 0.98)
        ratio = linear(b)[keep].mean() / linear(edit)[keep].mean()
        print(f'| {name} | {label.replace("_", " ")} | {psnr(b, test):.2f} | {psnr(b, edit):.2f} | {ratio:.3f} |')
    print(f'| {name} | (`i2sdf edit` itself) | {psnr(edit, test):.2f} | | |')
PY
