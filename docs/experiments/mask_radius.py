#!/usr/bin/env python3
"""The radius a light's emitter-mask pieces give it, against the truth, for the rim correction of
clipped pieces (`CLIPPED_RIM_PX` in crates/train/src/stage2/emitter_triangulation.rs).

Each whole piece (not touching the frame) whose centroid ray passes within 12 cm of the light's
true centre is a disc of the piece's solid angle (the sum of its pixels' own, through the
capture's OPENCV lens), shrunk by the rim correction c (pixels) as `disc_angle` does, at the
centre's depth along that ray. Printed: the median radius for c = 0, 0.25, 0.5. The cameras are
the true poses (`poses_true.json`), the masks those a run found (`RUN/emitter_masks/`, one per
training frame in order).

Usage: mask_radius.py CAPTURE RUN X,Y,Z   (the light's true centre, world metres; the built-in
rooms' bulb: `floor_lamp_bulb` in CAPTURE/scene.toml)
Needs numpy, scipy, pillow.
"""
import json
import sys

import numpy as np
from PIL import Image
from scipy import ndimage

cap, run = sys.argv[1], sys.argv[2]
centre = np.array([float(x) for x in sys.argv[3].split(",")])
d = json.load(open(f"{cap}/transforms.json"))
true_poses = json.load(open(f"{cap}/poses_true.json"))["transform_matrix"]
fx, fy, cx, cy, w, h = d["fl_x"], d["fl_y"], d["cx"], d["cy"], d["w"], d["h"]
k1, k2, p1, p2 = (d.get(k, 0.0) for k in ("k1", "k2", "p1", "p2"))


def undistort(xd, yd):
    x, y = xd.copy(), yd.copy()
    for _ in range(20):
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2 * r2
        dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        x, y = (xd - dx) / radial, (yd - dy) / radial
    return x, y


def directions(u, v):
    """Unit camera-space directions (x right, y down, z forward) of image points (u, v)."""
    x, y = undistort((u - cx) / fx, (v - cy) / fy)
    dirs = np.stack([x, y, np.ones_like(x)], -1)
    return dirs / np.linalg.norm(dirs, axis=-1, keepdims=True)


radii = {0.0: [], 0.25: [], 0.5: []}
train = [f for f in d["frames"] if f["split"] == "train"]
for i, frame in enumerate(train):
    mask = np.array(Image.open(f"{run}/emitter_masks/{i:04d}.png"))
    mask = (mask[..., 0] if mask.ndim == 3 else mask) > 127
    c2w = np.array(true_poses[frame["file_path"]])
    origin, rot = c2w[:3, 3], c2w[:3, :3]
    labels, count = ndimage.label(mask)
    for label in range(1, count + 1):
        ys, xs = np.nonzero(labels == label)
        if xs.min() == 0 or ys.min() == 0 or xs.max() == w - 1 or ys.max() == h - 1:
            continue
        u, v = xs + 0.5, ys + 0.5
        solid_angle = np.linalg.norm(
            np.cross(directions(u + 0.5, v) - directions(u - 0.5, v), directions(u, v + 0.5) - directions(u, v - 0.5)),
            axis=-1,
        ).sum()
        dc = directions(np.array([u.mean()]), np.array([v.mean()]))[0]
        ray = rot @ np.array([dc[0], -dc[1], -dc[2]])  # OpenGL camera axes
        to_centre = centre - origin
        depth = to_centre @ ray
        if depth <= 0 or np.linalg.norm(to_centre - depth * ray) > 0.12:
            continue
        r_px = np.sqrt(len(xs) / np.pi)
        angle = np.sqrt(solid_angle / np.pi)
        for c in radii:
            radii[c].append(angle * max(r_px - c, 0.5) / r_px * depth)
for c, rs in radii.items():
    print(f"rim {c:.2f} px: {len(rs)} pieces, median radius {np.median(rs):.4f} m")
