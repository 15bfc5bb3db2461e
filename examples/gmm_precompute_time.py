"""Time the GMM mipmap precompute (004 Sec. 4.1) of the three procedural test surfaces at 512x512.

Issue 4's aim: a 512x512 height field with 4 components in under 60 s on 2 cores (004 reports about
5 minutes on a 2.8 GHz Pentium IV).  Run: ``nice -n 10 python examples/gmm_precompute_time.py [SIZE]``.
"""
from __future__ import annotations

import sys
import time

from precompute.gmm_mipmap import build_gmm_mipmap
from precompute.surfaces import SURFACES

SIZE = 512           # issue 4 acceptance: "a 512x512 height field with 4 components"
COMPONENTS = 4


def main(size: int = SIZE) -> None:
    for name in ("dunes", "hemispherical_scales", "carved_disk"):
        h = SURFACES[name](size)
        t0 = time.perf_counter()
        mip = build_gmm_mipmap(h, components=COMPONENTS, progress=False)
        dt = time.perf_counter() - t0
        print(f"{name:22s} {size}x{size}, {COMPONENTS} components, {len(mip.levels)} levels: {dt:6.1f} s")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else SIZE)
