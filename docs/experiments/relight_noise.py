#!/usr/bin/env python3
"""How much of a relit set's PSNR is Monte Carlo noise: two renders of the same views with
different seeds (`i2sdf edit ... --seed 0 --out A`, `--seed 1 --out B`), scored against the truth.

For renders a, b with independent noise of variance s2 each and truth g,
  E[mse(a, g)]           = bias2 + s2          (what eval reports at this spp)
  E[mse(a, b)]           = 2 s2
  E[mse((a+b)/2, g)]     = bias2 + s2 / 2
so bias2 = mse((a+b)/2, g) - mse(a, b) / 4 is the error of the same scene at infinite spp, and
bias2 + s2 / k that of k times the paths. (The truth's own noise is part of bias2.)

Usage: relight_noise.py A B TRUTH  (folders of NNNN.png; TRUTH e.g. ROOM/relight/SET)
"""
import sys
from pathlib import Path

import numpy as np
from PIL import Image


def load(p):
    return np.asarray(Image.open(p).convert("RGB")).astype(np.float64) / 255.0


def psnr(mse):
    # The estimate of the bias can come out at or under 0 where noise is all the error.
    return float("inf") if mse <= 0.0 else 10.0 * np.log10(1.0 / mse)


def main():
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    a_dir, b_dir, truth_dir = map(Path, sys.argv[1:4])
    rows = []
    for a_path in sorted(a_dir.glob("*.png")):
        a, b, g = load(a_path), load(b_dir / a_path.name), load(truth_dir / a_path.name)
        one = np.mean((a - g) ** 2)
        noise = np.mean((a - b) ** 2) / 2.0
        bias = np.mean(((a + b) / 2.0 - g) ** 2) - noise / 2.0
        rows.append((a_path.stem, psnr(one), psnr(noise), psnr(bias + noise / 4.0), psnr(bias)))
    print("view   this spp   noise alone   4x spp   infinite spp  (PSNR, dB)")
    for r in rows:
        print(f"{r[0]}  {r[1]:8.2f}  {r[2]:11.2f}  {r[3]:7.2f}  {r[4]:12.2f}")
    means = np.mean([r[1:] for r in rows], axis=0)
    print(f"mean  {means[0]:8.2f}  {means[1]:11.2f}  {means[2]:7.2f}  {means[3]:12.2f}")


if __name__ == "__main__":
    main()
