"""Kd PSNR of a run's test views split by how many training views see each pixel's surface.

For each test pixel the ground-truth surface point (GT z-depth, pinhole, OpenGL camera axes as in
transforms.json) is projected into every training view; a view sees it where the point lands in
its image and its GT depth there agrees within 2 %. Prints the Kd PSNR (linear, clipped to [0, 1],
emitter-mask pixels left out as `eval` does) over all pixels and over those seen by at least
1, 2 and 3 training views, and the share of the squared error on pixels seen by fewer than 2.

    python3 docs/experiments/kd_observed.py ROOM RENDERED
RENDERED: `i2sdf render --run RUN --out RENDERED --split test --what albedo`.
Needs numpy, OpenEXR, Pillow. `kd_by_geometry.py` uses its helpers.
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


class Room:
    """A native dataset's cameras, its training views' GT depth, and its test frames."""

    def __init__(self, room):
        self.dir = room
        t = json.load(open(f"{room}/transforms.json"))
        self.fx, self.fy, self.cx, self.cy, self.w, self.h = t["fl_x"], t["fl_y"], t["cx"], t["cy"], t["w"], t["h"]
        train = [f for f in t["frames"] if f["split"] == "train"]
        self.test = [f for f in t["frames"] if f["split"] == "test"]
        self.tdepth = [exr(f"{room}/{f['depth_file_path']}") for f in train]
        self.tw2c = [np.linalg.inv(np.array(f["transform_matrix"])) for f in train]
        self.u, self.v = np.meshgrid(np.arange(self.w) + 0.5, np.arange(self.h) + 0.5)

    def points(self, f, z=None):
        """The GT z-depth of test frame `f` (or the z-depth `z` given) and its pixels' world points
        (h × w × 4). OpenGL camera: x right, y up, looking down -z; z-depth along the optical axis."""
        if z is None:
            z = exr(f"{self.dir}/{f['depth_file_path']}")
        pc = np.stack([(self.u - self.cx) / self.fx * z, -(self.v - self.cy) / self.fy * z, -z, np.ones_like(z)], -1)
        return z, pc @ np.array(f["transform_matrix"]).T

    def project(self, p, w2c):
        """Homogeneous world points `p` (… × 4) in a training view: their z-depth, whether they
        land in its image in front of it, and the pixel they land in (column, row)."""
        q = p @ w2c.T
        zq = -q[..., 2]
        ok = zq > 1e-3
        uq = np.where(ok, q[..., 0] / np.maximum(zq, 1e-3) * self.fx + self.cx, -1)
        vq = np.where(ok, -q[..., 1] / np.maximum(zq, 1e-3) * self.fy + self.cy, -1)
        inb = ok & (uq >= 0) & (vq >= 0) & (uq < self.w) & (vq < self.h)
        return zq, inb, np.clip(uq.astype(int), 0, self.w - 1), np.clip(vq.astype(int), 0, self.h - 1)

    def views_seeing(self, pw):
        """How many training views see each world point (lands in the image, GT depth within 2 %)."""
        seen = np.zeros(pw.shape[:-1], int)
        for d, m in zip(self.tdepth, self.tw2c):
            zq, inb, xi, yi = self.project(pw, m)
            seen += inb & (np.abs(d[yi, xi] - zq) < 0.02 * zq)
        return seen

    def free_space_views(self, pts, margin=0.05, edge=2):
        """How many training views see each world point (n × 3) as empty: it lies over `margin`
        in front of the GT depth of the pixel it lands in, and of every pixel within `edge` of
        it (so that a point a pixel beside a depth edge does not count)."""
        if getattr(self, "_near_edge", None) != edge:
            # Each training view's least depth within `edge` pixels, made once per `edge`.
            self._near_edge, self._near = edge, []
            for d in self.tdepth:
                near = d.copy()
                for dy in range(-edge, edge + 1):
                    for dx in range(-edge, edge + 1):
                        near = np.minimum(near, np.roll(np.roll(d, dy, 0), dx, 1))
                self._near.append(near)
        count = np.zeros(len(pts), int)
        p = np.concatenate([pts, np.ones((len(pts), 1))], 1)
        for near, m in zip(self._near, self.tw2c):
            zq, inb, xi, yi = self.project(p, m)
            count += inb & (zq < near[yi, xi] - margin)
        return count

    def scored(self, f, z):
        """The pixels `eval` scores: not an emitter by the GT mask, a finite GT surface."""
        mask = np.asarray(Image.open(f"{self.dir}/{f['emitter_mask_path']}").convert("L")) > 127
        return ~mask & (z > 0)


def frame_name(f):
    return f["file_path"].split("/")[-1].split(".")[0]


if __name__ == "__main__":
    room, rendered = Room(sys.argv[1]), sys.argv[2]
    err_all, seen_all = [], []
    for f in room.test:
        z, pw = room.points(f)
        seen = room.views_seeing(pw)
        gt = np.clip(exr(f"{room.dir}/{f['albedo_file_path']}"), 0, 1)
        pr = np.clip(exr(f"{rendered}/albedo/{frame_name(f)}.exr"), 0, 1)
        keep = room.scored(f, z)
        err_all.append(((gt - pr) ** 2).mean(-1)[keep])
        seen_all.append(seen[keep])
    e, s = np.concatenate(err_all), np.concatenate(seen_all)
    psnr = lambda x: 10 * np.log10(1 / x.mean())
    print(f"pixels {len(e)}: Kd PSNR {psnr(e):.2f} dB")
    for k in (1, 2, 3):
        sel = s >= k
        print(f"  seen by >= {k} training views: {sel.mean() * 100:.1f} % of pixels, Kd PSNR {psnr(e[sel]):.2f} dB")
    print(f"  share of the squared error on pixels seen by < 2 views: {e[s < 2].sum() / e.sum() * 100:.1f} %")
