#!/usr/bin/env python3
"""Roughness L1 of a run's test views grouped by the true (roughness, Ks) of each pixel: which
materials the error comes from ("Where the roughness error is" in docs/results.md).

Usage: roughness_by_material.py ROOM MAPS
  ROOM: the dataset (`material/NNNN_{roughness,ks}.exr`, `mask/NNNN.png`);
  MAPS: `i2sdf render --run RUN --out MAPS --split test --what roughness,specular`.
Pixels of emitters (the mask) are left out. Needs numpy, Pillow and OpenEXR.
"""
import sys

import numpy as np
from exr_maps import gray, read
from PIL import Image


room, maps = sys.argv[1], sys.argv[2]
names = sorted(p.stem for p in __import__("pathlib").Path(maps, "roughness").glob("*.exr"))
g_rho, p_rho, g_ks, p_ks = [], [], [], []
for n in names:
    g = gray(read(f"{room}/material/{n}_roughness.exr"))
    p = gray(read(f"{maps}/roughness/{n}.exr"))
    ks = gray(read(f"{room}/material/{n}_ks.exr"))
    pks = gray(read(f"{maps}/specular/{n}.exr"))
    mask = np.asarray(Image.open(f"{room}/mask/{n}.png"))
    mask = mask[..., 0] if mask.ndim == 3 else mask
    ok = (mask < 128) & np.isfinite(p) & (g > 0)
    g_rho.append(g[ok]), p_rho.append(p[ok]), g_ks.append(ks[ok]), p_ks.append(pks[ok])
G, P, K, PK = (np.concatenate(v) for v in (g_rho, p_rho, g_ks, p_ks))
err = np.abs(G - P)
print(f"roughness L1 {err.mean():.4f} over {len(G)} pixels")
print("true rho / Ks | share of pixels | predicted rho / Ks | L1 | share of the L1")
for gv in np.unique(np.round(G, 2)):
    for kv in np.unique(np.round(K[np.round(G, 2) == gv], 2)):
        s = (np.round(G, 2) == gv) & (np.round(K, 2) == kv)
        if s.sum() < 200:
            continue
        print(
            f"{gv:.2f} / {kv:.2f} | {s.mean():.3f} | {P[s].mean():.2f} / {PK[s].mean():.3f} | "
            f"{err[s].mean():.3f} | {err[s].sum() / err.sum():.3f}"
        )
