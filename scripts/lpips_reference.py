#!/usr/bin/env python3
"""Reference values for i2sdf's LPIPS test (crates/eval/tests/lpips.rs), from the `lpips` package
itself: its AlexNet v0.1 model with the linear heads it ships, and a backbone whose weights are set
from a deterministic formula (so no 10 MB backbone is downloaded or committed; the Rust test builds
the same weights from the same formula).

The formula (all integer arithmetic on u32, wrapping, then exact floating point):

    hash(x)   = lowbias32: x ^= x >> 16; x *= 0x7feb352d; x ^= x >> 15; x *= 0x846ca68b; x ^= x >> 16
    unit(s,i) = (hash((i + 0x9E3779B9 * s) mod 2^32) >> 8) / 2^24 * 2 - 1        (in [-1, 1), exact)
    conv l (0-based) weight, flat index i of PyTorch's [out][in][kh][kw]:
              f32( unit(2l + 1, i) * sqrt(6 / (in * kh * kw)) )                     (f64 product)
    conv l bias[o] = f32( 0.1 * unit(2l + 2, o) )

and the test images (H×W×3, values in f64 then rounded to f32):

    v(y, x, c) = clamp(0.5 + 0.35 sin(freq (1 + 0.3 c) x + 0.17 y + phase + 0.5 c)
                       + noise * unit(100 + seed, (y W + x) 3 + c), 0, 1)

The model runs in float64 (the weights and images are the f32 values above), so the printed
distances are the f32 inputs' exact LPIPS to ~1e-12; `normalize=True` maps [0, 1] to [-1, 1].

usage: lpips_reference.py [--heads crates/eval/tests/fixtures/lpips_alex_v0.1_heads.safetensors]

With --heads it also writes the package's linear heads (lin0..lin4, 1152 values, BSD-2-Clause
like the package) as the f32 safetensors fixture the test reads. Needs torch, torchvision, lpips,
safetensors, numpy; downloads nothing (pnet_rand=True skips torchvision's pretrained backbone).
"""
import argparse
import math

import numpy as np
import torch
import lpips
from safetensors.numpy import save_file

# (name, in, out, kernel) of the backbone's convolutions in the package's state dict.
CONVS = [
    ("net.slice1.0", 3, 64, 11),
    ("net.slice2.3", 64, 192, 5),
    ("net.slice3.6", 192, 384, 3),
    ("net.slice4.8", 384, 256, 3),
    ("net.slice5.10", 256, 256, 3),
]

# (width, height, (phase, freq, seed, noise) of image a, the same of image b)
PAIRS = [
    (64, 48, (0.0, 0.21, 1, 0.10), (0.6, 0.21, 2, 0.10)),
    (64, 48, (1.0, 0.13, 3, 0.05), (1.0, 0.13, 4, 0.05)),
    (70, 50, (0.3, 0.31, 5, 0.10), (0.3, 0.11, 6, 0.10)),
    (131, 97, (2.0, 0.07, 7, 0.02), (2.2, 0.08, 8, 0.20)),
]

M32 = 0xFFFFFFFF


def hash32(x):
    x &= M32
    x ^= x >> 16
    x = (x * 0x7FEB352D) & M32
    x ^= x >> 15
    x = (x * 0x846CA68B) & M32
    x ^= x >> 16
    return x


def unit(stream, i):
    h = hash32(i + 0x9E3779B9 * stream)
    return (h >> 8) / float(1 << 24) * 2.0 - 1.0


def backbone(l, cin, cout, k):
    s = math.sqrt(6.0 / (cin * k * k))
    n = cout * cin * k * k
    w = np.array([unit(2 * l + 1, i) * s for i in range(n)], dtype=np.float64).astype(np.float32)
    b = np.array([0.1 * unit(2 * l + 2, o) for o in range(cout)], dtype=np.float64).astype(np.float32)
    return w.reshape(cout, cin, k, k), b


def image(w, h, phase, freq, seed, noise):
    img = np.empty((h, w, 3), dtype=np.float32)
    for y in range(h):
        for x in range(w):
            for c in range(3):
                v = 0.5 + 0.35 * math.sin(freq * (1.0 + 0.3 * c) * x + 0.17 * y + phase + 0.5 * c)
                v += noise * unit(100 + seed, (y * w + x) * 3 + c)
                img[y, x, c] = min(max(v, 0.0), 1.0)
    return img


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--heads", help="write the package's linear heads here (safetensors)")
    args = ap.parse_args()
    model = lpips.LPIPS(net="alex", version="0.1", pnet_rand=True, pretrained=True, verbose=False)
    state = model.state_dict()
    for l, (name, cin, cout, k) in enumerate(CONVS):
        w, b = backbone(l, cin, cout, k)
        assert state[name + ".weight"].shape == w.shape, name
        state[name + ".weight"] = torch.from_numpy(w)
        state[name + ".bias"] = torch.from_numpy(b)
    model.load_state_dict(state)
    model = model.double().eval()
    heads = {f"lin{l}.model.1.weight": state[f"lin{l}.model.1.weight"].numpy().astype(np.float32) for l in range(5)}
    assert sum(v.size for v in heads.values()) == 1152
    if args.heads:
        save_file(heads, args.heads)
    with torch.no_grad():
        for w, h, pa, pb in PAIRS:
            a, b = image(w, h, *pa), image(w, h, *pb)
            ta = torch.from_numpy(a.astype(np.float64)).permute(2, 0, 1)[None]
            tb = torch.from_numpy(b.astype(np.float64)).permute(2, 0, 1)[None]
            d, layers = model(ta, tb, retPerLayer=True, normalize=True)
            per = ", ".join(f"{x.item():.10f}" for x in layers)
            print(f"{w}x{h} {pa} {pb}: {d.item():.10f}  layers [{per}]")


if __name__ == "__main__":
    main()
