#!/usr/bin/env python3
"""Kd and roughness error of one or more runs' test views, by the true material class of each
pixel (Ks to 1 %, ρ to 0.05): which materials a change of stage 2 moves ("A specular lobe chosen
per material segment" in docs/results.md).

Usage: materials_by_class.py ROOM MAPS [MAPS ...]
  ROOM: the dataset (`material/NNNN_{kd,ks,roughness}.exr`, `mask/NNNN.png`);
  MAPS: `i2sdf render --run RUN --out MAPS --split test --what albedo,specular,roughness`.
Per class (the 16 with the largest roughness L1 in the first MAPS): its share of the pixels, and
for each MAPS its share of Kd's squared error (× 1000, over all pixels), of the roughness L1,
and its mean fitted ρ and Ks; then each MAPS' Kd PSNR and roughness L1. Emitter pixels (the
mask) are left out. Needs numpy, Pillow and OpenEXR.
"""
import sys
from pathlib import Path

import numpy as np
from exr_maps import gray, read
from PIL import Image

room, runs = sys.argv[1], sys.argv[2:]
names = sorted(p.stem for p in Path(runs[0], "roughness").glob("*.exr"))
res = {}  # (class, run) -> [pixels, Kd squared error, roughness L1, Σρ, ΣKs]
for r, maps in enumerate(runs):
    for n in names:
        kd, ks = read(f"{room}/material/{n}_kd.exr"), gray(read(f"{room}/material/{n}_ks.exr"))
        rho = gray(read(f"{room}/material/{n}_roughness.exr"))
        mask = np.asarray(Image.open(f"{room}/mask/{n}.png"))
        ok = (mask[..., 0] if mask.ndim == 3 else mask) < 128
        p_kd, p_ks = read(f"{maps}/albedo/{n}.exr"), gray(read(f"{maps}/specular/{n}.exr"))
        p_rho = gray(read(f"{maps}/roughness/{n}.exr"))
        cls = np.round(ks * 100).astype(int) * 100 + np.round(rho * 20).astype(int)
        for c in np.unique(cls[ok]):
            s = ok & (cls == c)
            e = res.setdefault((c, r), [0, 0.0, 0.0, 0.0, 0.0])
            e[0] += s.sum()
            e[1] += ((p_kd[s] - kd[s]) ** 2).sum() / 3
            e[2] += np.abs(p_rho[s] - rho[s]).sum()
            e[3] += p_rho[s].sum()
            e[4] += p_ks[s].sum()
n = sum(v[0] for (c, r), v in res.items() if r == 0)
classes = sorted({c for c, _ in res}, key=lambda c: -res.get((c, 0), [0, 0, 0])[2])
print(f"{n} px; class (true Ks, ρ): pixels | per run: Kd SE share ×1000, roughness L1 share, mean ρ, mean Ks")
for c in classes[:16]:
    line = f"Ks {c // 100:3d} % ρ {c % 100 / 20:.2f}: {res[(c, 0)][0] / n * 100:5.1f} % |"
    for r in range(len(runs)):
        v = res.get((c, r))
        if v:
            line += f" {v[1] / n * 1e3:.3f} {v[2] / n:.4f} {v[3] / v[0]:.2f} {v[4] / v[0]:.3f} |"
    print(line)
for r, maps in enumerate(runs):
    se = sum(v[1] for (c, m), v in res.items() if m == r)
    rl = sum(v[2] for (c, m), v in res.items() if m == r)
    print(f"{maps}: Kd PSNR {-10 * np.log10(se / n):.2f}, roughness L1 {rl / n:.4f}")
