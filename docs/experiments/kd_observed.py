"""Kd PSNR of a run's test views split by how many training views see each pixel's surface.

For each test pixel the ground-truth surface point (GT z-depth, pinhole, OpenGL camera axes as in
transforms.json) is projected into every training view; a view sees it where the point lands in
its image and its GT depth there agrees within 2 %. Prints the Kd PSNR (linear, clipped to [0, 1],
emitter-mask pixels left out as `eval` does) over all pixels and over those seen by at least
1, 2 and 3 training views, and the share of the squared error on pixels seen by fewer than 2.

    python3 docs/experiments/kd_observed.py ROOM RENDERED
RENDERED: `i2sdf render --run RUN --out RENDERED --split test --what albedo`.
Needs numpy, OpenEXR, Pillow.
"""
import json, sys
import numpy as np
import OpenEXR
from PIL import Image


def exr(path):
    ch = OpenEXR.File(path).channels()
    if "RGB" in ch:
        return np.asarray(ch["RGB"].pixels, dtype=np.float64)
    if all(c in ch for c in "RGB"):
        return np.stack([np.asarray(ch[c].pixels, dtype=np.float64) for c in "RGB"], -1)
    a = np.asarray(next(iter(ch.values())).pixels, dtype=np.float64)
    return a[..., 0] if a.ndim == 3 else a


room, rendered = sys.argv[1], sys.argv[2]
t = json.load(open(f"{room}/transforms.json"))
fx, fy, cx, cy, w, h = t["fl_x"], t["fl_y"], t["cx"], t["cy"], t["w"], t["h"]
train = [f for f in t["frames"] if f["split"] == "train"]
test = [f for f in t["frames"] if f["split"] == "test"]
tdepth = [exr(f"{room}/{f['depth_file_path']}") for f in train]
tw2c = [np.linalg.inv(np.array(f["transform_matrix"])) for f in train]
u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
err_all, seen_all = [], []
for f in test:
    z = exr(f"{room}/{f['depth_file_path']}")
    c2w = np.array(f["transform_matrix"])
    # OpenGL camera: x right, y up, looking down -z; z-depth along the optical axis.
    pc = np.stack([(u - cx) / fx * z, -(v - cy) / fy * z, -z, np.ones_like(z)], -1)
    pw = pc @ c2w.T
    seen = np.zeros(z.shape, int)
    for d, m in zip(tdepth, tw2c):
        q = pw @ m.T
        zq = -q[..., 2]
        ok = zq > 1e-3
        uq = np.where(ok, q[..., 0] / np.maximum(zq, 1e-3) * fx + cx, -1)
        vq = np.where(ok, -q[..., 1] / np.maximum(zq, 1e-3) * fy + cy, -1)
        inb = ok & (uq >= 0) & (vq >= 0) & (uq < w) & (vq < h)
        xi = np.clip(uq.astype(int), 0, w - 1)
        yi = np.clip(vq.astype(int), 0, h - 1)
        dz = d[yi, xi]
        seen += inb & (np.abs(dz - zq) < 0.02 * zq)
    gt = np.clip(exr(f"{room}/{f['albedo_file_path']}"), 0, 1)
    name = f["file_path"].split("/")[-1].split(".")[0]
    pr = np.clip(exr(f"{rendered}/albedo/{name}.exr"), 0, 1)
    mask = np.asarray(Image.open(f"{room}/{f['emitter_mask_path']}").convert("L")) > 127
    keep = ~mask & (z > 0)
    err_all.append(((gt - pr) ** 2).mean(-1)[keep])
    seen_all.append(seen[keep])
e, s = np.concatenate(err_all), np.concatenate(seen_all)
psnr = lambda x: 10 * np.log10(1 / x.mean())
print(f"pixels {len(e)}: Kd PSNR {psnr(e):.2f} dB")
for k in (1, 2, 3):
    sel = s >= k
    print(f"  seen by >= {k} training views: {sel.mean() * 100:.1f} % of pixels, Kd PSNR {psnr(e[sel]):.2f} dB")
print(f"  share of the squared error on pixels seen by < 2 views: {e[s < 2].sum() / e.sum() * 100:.1f} %")
