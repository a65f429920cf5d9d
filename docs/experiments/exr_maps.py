"""Reading the datasets' EXR maps for the scripts here (numpy and OpenEXR)."""
import numpy as np
import OpenEXR


def read(path):
    """An EXR image as float32: H×W×3 (RGB) or H×W (one channel)."""
    with OpenEXR.File(str(path)) as f:
        ch = f.channels()
        if "RGB" in ch:
            return ch["RGB"].pixels.astype(np.float32)
        if "Y" in ch:
            return ch["Y"].pixels.astype(np.float32)
        return np.stack([ch[c].pixels for c in "RGB" if c in ch], -1).astype(np.float32)


def gray(a):
    """The mean over channels of an RGB map; a one-channel map as it is."""
    return a.mean(-1) if a.ndim == 3 else a
