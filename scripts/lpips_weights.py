#!/usr/bin/env python3
"""Write the LPIPS weights that `i2sdf eval --lpips-weights FILE.safetensors` reads: the `lpips`
package's v0.1 AlexNet metric, i.e. torchvision's ImageNet-pretrained AlexNet `features` (the
backbone) and the linear heads the package ships (lpips/weights/v0.1/alex.pth).

It only works where torchvision can download its pretrained AlexNet weights (about 233 MB, of
which the 2.5 M parameters of `features` are kept: a ~10 MB file), on the first run, into torch's
cache: i2sdf neither ships nor downloads them. Needs torch, torchvision, lpips and safetensors
(`pip install torch torchvision lpips safetensors`).

The file holds f32 tensors with the package's state-dict names:
    net.slice1.0.weight  [64, 3, 11, 11]   net.slice1.0.bias  [64]
    net.slice2.3.weight  [192, 64, 5, 5]   net.slice2.3.bias  [192]
    net.slice3.6.weight  [384, 192, 3, 3]  net.slice3.6.bias  [384]
    net.slice4.8.weight  [256, 384, 3, 3]  net.slice4.8.bias  [256]
    net.slice5.10.weight [256, 256, 3, 3]  net.slice5.10.bias [256]
    lin0.model.1.weight .. lin4.model.1.weight  [1, C, 1, 1]  (C = 64, 192, 384, 256, 256)

usage: lpips_weights.py OUT.safetensors [--check A.png B.png]

--check prints the package's LPIPS of two images of the same size (RGB, read with Pillow) to
compare with i2sdf's. --random-backbone (for testing this script without the download) keeps a
randomly initialised backbone: the file is then NOT the metric.
"""
import argparse

import numpy as np
import torch
import lpips
from safetensors.numpy import save_file

NAMES = [f"net.{s}.{k}" for s in ("slice1.0", "slice2.3", "slice3.6", "slice4.8", "slice5.10") for k in ("weight", "bias")]
NAMES += [f"lin{l}.model.1.weight" for l in range(5)]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", help="the safetensors file to write")
    ap.add_argument("--check", nargs=2, metavar=("A", "B"), help="print the package's LPIPS of two images")
    ap.add_argument("--random-backbone", action="store_true", help="testing only: no download, not the metric")
    args = ap.parse_args()
    model = lpips.LPIPS(net="alex", version="0.1", pretrained=True, pnet_rand=args.random_backbone, verbose=False)
    model.eval()
    state = model.state_dict()
    tensors = {}
    for name in NAMES:
        t = state[name].detach().to(torch.float32).contiguous().numpy()
        tensors[name] = np.ascontiguousarray(t)
    for l in range(5):
        head = tensors[f"lin{l}.model.1.weight"]
        assert (head >= 0).all(), f"lin{l}: negative head weights (not the package's v0.1 heads?)"
    meta = {"format": "lpips v0.1 alex", "random_backbone": str(args.random_backbone).lower()}
    save_file(tensors, args.out, metadata=meta)
    count = sum(v.size for v in tensors.values())
    print(f"wrote {args.out}: {len(tensors)} tensors, {count} values")
    if args.check:
        from PIL import Image

        def load(p):
            a = np.asarray(Image.open(p).convert("RGB"), dtype=np.float32) / 255.0
            return torch.from_numpy(a).permute(2, 0, 1)[None]

        with torch.no_grad():
            d = model(load(args.check[0]), load(args.check[1]), normalize=True)
        print(f"LPIPS {args.check[0]} {args.check[1]}: {d.item():.6f}")


if __name__ == "__main__":
    main()
