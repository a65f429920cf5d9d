#!/usr/bin/env python3
"""The share of a surface's radiance that is its specular lobe: a room rendered twice, as it is
(ROOM) and with that surface's Ks set to 0 in its scene.toml (`i2sdf synth --scene EDITED.toml
--seed S --out NOKS`, the same seed and cameras), compared over the surface's pixels in every
view's HDR image. The surface's pixels are those whose true (Ks, roughness) are KS and RHO (the
floor of the built-in rooms: 0.04 and 0.5).

Usage: sheen_share.py ROOM NOKS [KS RHO]   (needs numpy and OpenEXR)
"""
import sys
from pathlib import Path

import numpy as np
from exr_maps import gray, read


room, noks = Path(sys.argv[1]), Path(sys.argv[2])
ks_value, rho_value = (float(sys.argv[3]), float(sys.argv[4])) if len(sys.argv) > 4 else (0.04, 0.5)
shares = []
for hdr in sorted((room / "hdr").glob("*.exr")):
    n = hdr.stem
    ks = gray(read(room / "material" / f"{n}_ks.exr"))
    rho = gray(read(room / "material" / f"{n}_roughness.exr"))
    surface = (np.abs(ks - ks_value) < 1e-3) & (np.abs(rho - rho_value) < 1e-3)
    if not surface.any():
        continue
    with_lobe, without = gray(read(hdr))[surface], gray(read(noks / "hdr" / f"{n}.exr"))[surface]
    shares.append((with_lobe - without) / np.maximum(without, 1e-4))
q = np.concatenate(shares)
p50, p90, p99 = np.percentile(q, [50, 90, 99])
print(f"{len(q)} pixels: specular share mean {q.mean():.3f}, median {p50:.3f}, p90 {p90:.3f}, p99 {p99:.3f}")
