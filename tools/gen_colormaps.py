"""Generate kernels/render/scene/colormaps.npz from matplotlib (run once; the .npz is committed).

    python tools/gen_colormaps.py [--out kernels/render/scene/colormaps.npz]

The names are kernels/colormap_names.py's. Each table is 256 x 3 float32, sRGB-encoded in [0, 1],
exactly matplotlib's ``colormaps[name].resampled(256)(arange(256))[:, :3]``. The tables are data, never typed by hand.
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
from kernels.colormap_names import MATPLOTLIB  # noqa: E402  (our name -> matplotlib's)

N = 256


def tables() -> dict:
    import matplotlib

    out = {}
    for ours, mpl in MATPLOTLIB.items():
        cmap = matplotlib.colormaps[mpl].resampled(N)
        out[ours] = np.asarray(cmap(np.arange(N))[:, :3], dtype=np.float32)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", default=os.path.join(ROOT, "kernels", "render", "scene", "colormaps.npz"))
    args = ap.parse_args(argv)
    import matplotlib

    t = tables()
    t["_source"] = np.array(f"matplotlib {matplotlib.__version__}")
    np.savez_compressed(args.out, **t)
    print(f"wrote {len(MATPLOTLIB)} colormaps ({N} entries, sRGB) to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
