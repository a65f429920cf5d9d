#!/usr/bin/env python3
"""Convert an i2sdf native dataset (e.g. `i2sdf synth` output) into the two formats other tools
write, as an independent cross-check of i2sdf's loaders (numpy + OpenEXR only, no i2sdf code):

  --to nerfstudio : transforms.json with .npy float32 depth (z-depth, H×W) and normals (H×W×3),
                    nerfstudio's train_filenames / test_filenames instead of per-frame splits
  --to paper      : the I²-SDF release layout (VolSDF/IDR): cameras_normalize.npz with
                    world_mat_i = K·W2C, scale_mat_i, val_mat_i; image/, depth/, normal/
                    (OpenCV camera-space normals), light_mask/, val/; integer-pixel ray convention

usage: convert_native.py SRC DST --to nerfstudio|paper
"""
import argparse, json, os, shutil
import numpy as np
import OpenEXR


def read_exr(path):
    with OpenEXR.File(path) as f:
        ch = f.channels()
        if "RGB" in ch:
            return np.asarray(ch["RGB"].pixels, dtype=np.float32)
        for name in ("Y", "R", "Z"):
            if name in ch:
                return np.asarray(ch[name].pixels, dtype=np.float32)
        return np.asarray(next(iter(ch.values())).pixels, dtype=np.float32)


def write_exr(path, arr):
    arr = np.ascontiguousarray(arr.astype(np.float32))
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    chans = {"RGB": arr} if arr.ndim == 3 else {"Y": arr}
    with OpenEXR.File(header, chans) as f:
        f.write(path)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("src"); ap.add_argument("dst"); ap.add_argument("--to", required=True, choices=["nerfstudio", "paper"])
    a = ap.parse_args()
    meta = json.load(open(os.path.join(a.src, "transforms.json")))
    frames = meta["frames"]
    os.makedirs(a.dst, exist_ok=True)
    gl_to_cv = np.diag([1.0, -1.0, -1.0, 1.0])

    if a.to == "nerfstudio":
        out = {k: meta[k] for k in ("fl_x", "fl_y", "cx", "cy", "w", "h")}
        out["camera_model"] = "OPENCV"
        out["frames"], out["train_filenames"], out["test_filenames"] = [], [], []
        for d in ("images", "depth", "normals"):
            os.makedirs(os.path.join(a.dst, d), exist_ok=True)
        for i, f in enumerate(frames):
            name = f"frame_{i:05d}"
            shutil.copy(os.path.join(a.src, f["file_path"]), os.path.join(a.dst, "images", name + ".png"))
            np.save(os.path.join(a.dst, "depth", name + ".npy"), read_exr(os.path.join(a.src, f["depth_file_path"])))
            np.save(os.path.join(a.dst, "normals", name + ".npy"), read_exr(os.path.join(a.src, f["normal_file_path"])))
            fp = f"images/{name}.png"
            out["frames"].append({"file_path": fp, "transform_matrix": f["transform_matrix"],
                                  "depth_file_path": f"depth/{name}.npy", "normal_file_path": f"normals/{name}.npy"})
            (out["train_filenames"] if f["split"] == "train" else out["test_filenames"]).append(fp)
        json.dump(out, open(os.path.join(a.dst, "transforms.json"), "w"), indent=1)
        return

    # The paper's release: K with the integer-pixel convention (principal point − ½), P = K·W2C.
    fx, fy, cx, cy = meta["fl_x"], meta["fl_y"], meta["cx"] - 0.5, meta["cy"] - 0.5
    K = np.array([[fx, 0, cx, 0], [0, fy, cy, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    # A VolSDF normalization: centre and radius of the camera centres, enlarged (only recorded).
    centres = np.array([np.array(f["transform_matrix"])[:3, 3] for f in frames])
    c = centres.mean(0); r = np.linalg.norm(centres - c, axis=1).max() * 3.0 + 1e-6
    scale = np.eye(4); scale[:3, :3] *= r; scale[:3, 3] = c
    mats = {}
    for d in ("image", "depth", "normal", "light_mask", "val"):
        os.makedirs(os.path.join(a.dst, d), exist_ok=True)
    train = [f for f in frames if f["split"] == "train"]
    test = [f for f in frames if f["split"] == "test"]
    for i, f in enumerate(train):
        c2w = np.array(f["transform_matrix"]) @ gl_to_cv
        mats[f"world_mat_{i}"] = K @ np.linalg.inv(c2w)
        mats[f"scale_mat_{i}"] = scale
        shutil.copy(os.path.join(a.src, f["file_path"]), os.path.join(a.dst, "image", f"{i:04d}.png"))
        shutil.copy(os.path.join(a.src, f["emitter_mask_path"]), os.path.join(a.dst, "light_mask", f"{i:04d}.png"))
        depth = read_exr(os.path.join(a.src, f["depth_file_path"]))
        write_exr(os.path.join(a.dst, "depth", f"{i:04d}.exr"), np.stack([depth] * 3, -1))
        n_world = read_exr(os.path.join(a.src, f["normal_file_path"]))
        n_cam = n_world @ c2w[:3, :3]  # row vectors: n_cam = Rᵀ n_world
        write_exr(os.path.join(a.dst, "normal", f"{i:04d}.exr"), n_cam)
    for i, f in enumerate(test):
        c2w = np.array(f["transform_matrix"]) @ gl_to_cv
        mats[f"val_mat_{i}"] = K @ np.linalg.inv(c2w)
        shutil.copy(os.path.join(a.src, f["file_path"]), os.path.join(a.dst, "val", f"{i:04d}.png"))
    np.savez(os.path.join(a.dst, "cameras_normalize.npz"), **mats)


if __name__ == "__main__":
    main()
