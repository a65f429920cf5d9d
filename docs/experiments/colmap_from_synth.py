"""Turns a room written by `i2sdf synth` (with `--depth-grid 1`: 16-bit millimetre PNG depth)
into a COLMAP dataset, the way a user's SfM reconstruction of the same captures would look: the
poses moved by an arbitrary similarity (COLMAP's frame and scale are its own), 3D points with
their tracks (back-projected depth pixels, observed in every view whose depth agrees), written by
COLMAP's own code (pycolmap) in the binary and the text layout.

    python -m venv venv && venv/bin/pip install pycolmap numpy pillow
    venv/bin/python colmap_from_synth.py ROOM OUT_BIN OUT_TXT

Each OUT gets sparse/0 (binary or text), images/, depth/, masks/ (the room's emitter masks) and
train.txt / test.txt (the room's split). Used for the COLMAP figures of docs/results.md; i2sdf
itself never runs Python.
"""

import json
import os
import shutil
import sys

import numpy as np
import pycolmap
from PIL import Image

SCALE = 0.23  # COLMAP's arbitrary scale: model units per metre
N_POINTS = 3000
GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])


def main(room, out_bin, out_txt):
    tj = json.load(open(os.path.join(room, "transforms.json")))
    w, h = tj["w"], tj["h"]
    fx, fy, cx, cy = tj["fl_x"], tj["fl_y"], tj["cx"], tj["cy"]
    rng = np.random.default_rng(5)
    # The similarity from the room's frame to the "SfM" frame: x' = s R x + t.
    a = 0.7
    rot = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]) @ np.array(
        [[1, 0, 0], [0, np.cos(0.3), -np.sin(0.3)], [0, np.sin(0.3), np.cos(0.3)]]
    )
    trans = np.array([0.4, -1.1, 2.0])

    frames = tj["frames"]
    views = []
    for f in frames:
        c2w = np.array(f["transform_matrix"]) @ GL_TO_CV  # OpenCV axes
        depth = np.asarray(Image.open(os.path.join(room, f["depth_file_path"])), dtype=np.float64)
        depth *= tj.get("depth_unit_scale_factor", 0.001)
        views.append((f, c2w, depth))

    # 3D points: depth pixels of random views, back-projected (metres, room frame), then tracked
    # in every view where they project inside the image with depth within 1 %.
    k = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    points = []
    while len(points) < N_POINTS:
        v = rng.integers(len(views))
        _, c2w, depth = views[v]
        px, py = rng.integers(w), rng.integers(h)
        z = depth[py, px]
        if z <= 0:
            continue
        x_cam = np.linalg.inv(k) @ np.array([px + 0.5, py + 0.5, 1.0]) * z
        x = c2w[:3, :3] @ x_cam + c2w[:3, 3]
        track = []
        for j, (_, c2w_j, depth_j) in enumerate(views):
            xc = c2w_j[:3, :3].T @ (x - c2w_j[:3, 3])
            if xc[2] <= 1e-3:
                continue
            u = k @ xc / xc[2]
            ui, vi = int(np.floor(u[0])), int(np.floor(u[1]))
            if 0 <= ui < w and 0 <= vi < h and depth_j[vi, ui] > 0 and abs(depth_j[vi, ui] - xc[2]) < 0.01 * xc[2]:
                track.append((j, u[:2]))
        if len(track) >= 2:
            points.append((x, track))

    rec = pycolmap.Reconstruction()
    cam = pycolmap.Camera.create_from_model_name(1, "PINHOLE", 1.0, w, h)
    cam.params = np.array([fx, fy, cx, cy])
    rec.add_camera_with_trivial_rig(cam)
    xys = {j: [] for j in range(len(views))}
    tracks = []
    for x, track in points:
        t = []
        for j, uv in track:
            t.append((j + 1, len(xys[j])))
            xys[j].append(uv)
        tracks.append(t)
    names = []
    for i, (f, c2w, _) in enumerate(views):
        # The camera in the SfM frame: centre s R c + t, rotation R R_c2w.
        r_c2w = rot @ c2w[:3, :3]
        centre = SCALE * rot @ c2w[:3, 3] + trans
        r_w2c = r_c2w.T
        name = os.path.basename(f["file_path"])
        names.append(name)
        image = pycolmap.Image(image_id=i + 1, name=name, camera_id=1)
        image.points2D = pycolmap.Point2DList([pycolmap.Point2D(np.asarray(uv)) for uv in xys[i]])
        rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(pycolmap.Rotation3d(r_w2c), -r_w2c @ centre))
    for (x, _), t in zip(points, tracks):
        track = pycolmap.Track()
        for image_id, idx in t:
            track.add_element(image_id, idx)
        rec.add_point3D(SCALE * rot @ x + trans, track, np.array([128, 128, 128], dtype=np.uint8))

    for out, write in ((out_bin, rec.write_binary), (out_txt, rec.write_text)):
        if os.path.exists(out):
            shutil.rmtree(out)
        os.makedirs(os.path.join(out, "sparse", "0"))
        write(os.path.join(out, "sparse", "0"))
        for sub in ("images", "depth", "masks"):
            os.makedirs(os.path.join(out, sub))
        for f in frames:
            stem = os.path.splitext(os.path.basename(f["file_path"]))[0]
            shutil.copy(os.path.join(room, f["file_path"]), os.path.join(out, "images", os.path.basename(f["file_path"])))
            shutil.copy(os.path.join(room, f["depth_file_path"]), os.path.join(out, "depth", stem + ".png"))
            if "emitter_mask_path" in f:
                shutil.copy(os.path.join(room, f["emitter_mask_path"]), os.path.join(out, "masks", stem + ".png"))
        for split in ("train", "test"):
            with open(os.path.join(out, split + ".txt"), "w") as fh:
                for f, name in zip(frames, names):
                    if f["split"] == split:
                        fh.write(name + "\n")
    print(f"{len(views)} images, {len(points)} points, scale {SCALE} model units per metre")


if __name__ == "__main__":
    main(*sys.argv[1:4])
