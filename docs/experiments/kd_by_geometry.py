"""Where a run's Kd and roughness error lies on the test views: on surfaces the training views
do not see, on pixels where the reconstruction's surface is not the true one (so Kd is compared
across two surfaces), or on the true surface; the last split by the true material (matte,
sheen, glossy).

For each test pixel: the training views that see its GT surface point as in kd_observed.py
(none, one, two or more); "on the surface" when the rendered z-depth agrees with the GT z-depth
within 2 % (both finite). Prints each group's share of the pixels, its Kd PSNR (linear, clipped
to [0, 1], emitter-mask pixels left out as `eval` does), its share of the squared error, the Kd
PSNR of the whole set if the group's error were that of the seen on-surface pixels, and its
roughness L1 (mean and share of the sum). Where the reconstruction's surface lies in front of
the true one, how many training views see its point as empty space (over 5 cm in front of their
GT depth, no depth edge within 2 px: `Room.free_space_views`), i.e. whether the data contradict
it. Then fills of the pixels no training view sees: the mean of their true Kd per view (the best a
constant guess can do); the same fill as a method could make it, where no training view's depth
map sees the reconstructed point, by the mean prediction of the seen pixels (and halfway to it);
and the mean predicted Kd of the test pixels seen by two or more views within R with the same GT
normal (what the nearest observed surface would give; needs scipy).

    python3 docs/experiments/kd_by_geometry.py ROOM RENDERED [FIGURE.png]
RENDERED: `i2sdf render --run RUN --out RENDERED --split test --what albedo,depth,roughness`.
FIGURE.png: per test view (the first three), the GT Kd | the predicted Kd | where the
reconstruction's surface is in front of the true one (green) or behind it (magenta) | what one
training view sees (yellow) and what none does (red).
Needs numpy, OpenEXR, Pillow.
"""
import os, sys
import numpy as np
from PIL import Image

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from kd_observed import Room, exr, frame_name

room, rendered = Room(sys.argv[1]), sys.argv[2]
tiles = []
cols = {k: [] for k in ("gt", "pred", "views", "own_views", "on", "ks", "rough", "fill", "point", "normal")}
phantom_free = []
for f in room.test:
    z, pw = room.points(f)
    seen = room.views_seeing(pw)
    name = frame_name(f)
    gt = np.clip(exr(f"{room.dir}/{f['albedo_file_path']}"), 0, 1)
    pr = np.clip(exr(f"{rendered}/albedo/{name}.exr"), 0, 1)
    zp = exr(f"{rendered}/depth/{name}.exr")
    ks = exr(f"{room.dir}/{f['specular_file_path']}")
    ks = ks.mean(-1) if ks.ndim == 3 else ks
    rg = exr(f"{room.dir}/{f['roughness_file_path']}")
    rp = exr(f"{rendered}/roughness/{name}.exr")
    rg, rp = (r[..., 0] if r.ndim == 3 else r for r in (rg, rp))
    keep = room.scored(f, z)
    on = np.isfinite(zp) & (np.abs(zp - z) < 0.02 * z)
    # The reconstruction's surface points in front of the true ones: do the training views say
    # that space is empty?
    # (The reconstruction's point on a pixel's ray: the camera centre plus the GT point's offset
    # from it scaled by the ratio of the z-depths.)
    ahead = keep & ~on & np.isfinite(zp) & (zp < z)
    centre = np.array(f["transform_matrix"])[:3, 3]
    ahead_pts = centre + (pw[ahead][:, :3] - centre) * (zp[ahead] / z[ahead])[:, None]
    phantom_free.append(room.free_space_views(ahead_pts))
    if len(tiles) < 3:
        geo, vis = gt.copy(), gt.copy()
        front = np.isfinite(zp) & (zp < z)
        geo[~on & front] = [0, 1, 0]
        geo[~on & ~front] = [1, 0, 1]
        vis[seen == 1] = [1, 1, 0]
        vis[seen == 0] = [1, 0, 0]
        tiles.append(np.concatenate([gt, pr, geo, vis], 1))
    # What no training view sees, filled by its true mean in this view.
    fill = pr.copy()
    unseen = keep & (seen == 0)
    if unseen.any():
        fill[unseen] = gt[unseen].mean(0)
    # What a method can know of it: how many training views see the *reconstructed* point (by
    # their depth maps, an input), the GT point where the render has no surface.
    own = room.views_seeing(room.points(f, np.where(np.isfinite(zp), zp, z))[1])
    for k, a in (("gt", gt), ("pred", pr), ("views", seen), ("own_views", own), ("on", on), ("ks", ks), ("fill", fill)):
        cols[k].append(a[keep])
    cols["rough"].append(np.abs(rp - rg)[keep])
    cols["point"].append(pw[..., :3][keep])
    cols["normal"].append(exr(f"{room.dir}/{f['normal_file_path']}")[keep])
c = {k: np.concatenate(v) for k, v in cols.items()}
e = ((c["gt"] - c["pred"]) ** 2).mean(-1)
views, on, ks, rough = c["views"], c["on"], c["ks"], c["rough"]
s = views >= 2
psnr = lambda x: 10 * np.log10(1 / x.mean())
print(f"pixels {len(e)}: Kd PSNR {psnr(e):.2f} dB, roughness L1 {rough.mean():.3f}")
ref = e[s & on].mean()
groups = [
    ("seen by no training view", views == 0),
    ("seen by one training view, on the surface", (views == 1) & on),
    ("seen by one training view, surface elsewhere", (views == 1) & ~on),
    ("seen, reconstructed surface elsewhere (z off > 2 %)", s & ~on),
    ("seen, on the surface, matte (GT Ks < 0.015)", s & on & (ks < 0.015)),
    ("seen, on the surface, sheen (0.015-0.2)", s & on & (ks >= 0.015) & (ks <= 0.2)),
    ("seen, on the surface, glossy (> 0.2)", s & on & (ks > 0.2)),
]
print(f"{'group':<52} {'pixels':>6} {'Kd PSNR':>7} {'error':>6} {'all if as seen':>14} {'rough L1':>8} {'share':>6}")
for name, sel in groups:
    if not sel.any():
        continue
    alt = e.copy()
    alt[sel] = ref
    print(
        f"{name:<52} {sel.mean()*100:5.1f}% {psnr(e[sel]):7.2f} {e[sel].sum()/e.sum()*100:5.1f}% "
        f"{psnr(alt):14.2f} {rough[sel].mean():8.3f} {rough[sel].sum()/rough.sum()*100:5.1f}%"
    )
pf = np.concatenate(phantom_free)
if len(pf):
    shares = " / ".join(f"{x * 100:.0f} %" for x in ((pf == 0).mean(), (pf == 1).mean(), (pf == 2).mean(), (pf >= 3).mean()))
    print(f"reconstructed surface in front of the true one ({len(pf)} px): in the free space of 0 / 1 / 2 / >= 3 training views {shares}")
print(f"no training view's pixels filled by their true mean per view: {psnr(((c['gt'] - c['fill']) ** 2).mean(-1)):.2f} dB")
# The same fill as a method could do it: where no training view sees the reconstructed point,
# the mean prediction of the pixels two or more views see (and halfway towards it).
own = c["own_views"] == 0
for a in (1.0, 0.5):
    fill = c["pred"].copy()
    fill[own] += a * (c["pred"][c["own_views"] >= 2].mean(0) - fill[own])
    print(
        f"reconstructed point seen by no training view ({own.mean()*100:.1f} % of the pixels, {(views[own] == 0).mean()*100:.0f} % of them "
        f"truly unseen) {'filled by' if a == 1 else 'moved halfway to'} the seen mean: {psnr(((c['gt'] - fill) ** 2).mean(-1)):.2f} dB"
    )
try:
    from scipy.spatial import cKDTree
except ImportError:
    cKDTree = None
if cKDTree is not None:
    src, dst = np.where(s)[0], np.where(views == 0)[0]
    tree = cKDTree(c["point"][src])
    for r in (0.1, 0.2, 0.4, 0.8):
        fill = c["pred"].copy()
        for j, nb in zip(dst, tree.query_ball_point(c["point"][dst], r)):
            nb = src[nb]
            nb = nb[c["normal"][nb] @ c["normal"][j] > 0.9]
            if len(nb):
                fill[j] = c["pred"][nb].mean(0)
        print(f"  ... filled by the seen pixels' prediction within {r*100:.0f} cm (same normal): {psnr(((c['gt'] - fill) ** 2).mean(-1)):.2f} dB")
if len(sys.argv) > 3:
    img = np.clip(np.concatenate(tiles, 0), 0, 1) ** (1 / 2.2)
    Image.fromarray((img * 255).astype(np.uint8)).save(sys.argv[3])
