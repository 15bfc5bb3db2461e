"""Write the reflectance-filtering benchmark scenes of issue 4 (the three procedural test surfaces of
``precompute.surfaces`` on a plane under a directional light), then optionally bench them.

    python examples/filtering_scenes.py --out /work/bench/filtering             # write scenes + height maps
    python examples/filtering_scenes.py --out /work/bench/filtering --run       # and run bench-filtering on each

=====================  ====================  ======  =======================================
scene                  surface               tiling  like
=====================  ====================  ======  =======================================
scales                 hemispherical_scales  4       004 Fig. 8 (armour)
carved_disk            carved_disk           1       004 Fig. 4 / 7 (carved silver disk)
dunes                  dunes                 2       004 Fig. 1 (sand dunes)
=====================  ====================  ======  =======================================

Each height field is written as a one-channel EXR (``--size`` texels square, default 256).  The camera
sits at ``DISTANCE`` from the plane's centre, 60 degrees above it, so that at zoom 1 a pixel covers
about one texel of a tiling-4 map at the default resolution; ``warpbw bench-filtering`` moves it away by
each zoom factor.  The light mirrors the view about the normal, so the highlight sits mid-image.
``--run`` writes NAME.json and NAME.png beside each scene and prints the tables.
"""
from __future__ import annotations

import argparse
import math
import subprocess
import sys
from pathlib import Path

import numpy as np

# scene name -> (surface generator name, tiling, material)
SCENES = {
    "scales": ("hemispherical_scales", 4, {"roughness": 0.08, "f0": [0.9, 0.75, 0.4], "diffuse": [0.05, 0.04, 0.02]}),
    "carved_disk": ("carved_disk", 1, {"roughness": 0.06, "f0": [0.95, 0.93, 0.88], "diffuse": [0.02, 0.02, 0.02]}),
    "dunes": ("dunes", 2, {"roughness": 0.15, "f0": [0.04, 0.04, 0.04], "diffuse": [0.7, 0.55, 0.35]}),
}
DISTANCE = 0.35           # camera distance at zoom 1 (plane units; the plane is 2 units wide)
ELEVATION_DEG = 60.0      # camera elevation above the plane
FOV_DEG = 40.0
RESOLUTION = (128, 96)

SCENE = """\
# issue 4 benchmark scene: {surface} ({size}x{size}) on a plane, tiled {tiling}x (examples/filtering_scenes.py)
[camera]
position = [0.0, {cy:.6f}, {cz:.6f}]
look_at = [0.0, 0.0, 0.0]
fov = {fov}
resolution = [{w}, {h}]

[[light]]
type = "directional"
direction = [0.15, {ly:.6f}, {lz:.6f}]
radiance = [3.0, 3.0, 3.0]

[[object]]
shape = "plane"
center = [0.0, 0.0, 0.0]
size = 2.0
material = "m"

[material.m]
type = "cook-torrance"
roughness = {roughness}
f0 = {f0}
diffuse = {diffuse}
normal_map = "{name}.exr"
normal_map_kind = "height"
normal_map_scale = 1.0
tiling = {tiling}
"""


def write_scenes(out: Path, size: int, resolution=RESOLUTION) -> list:
    from precompute.surfaces import SURFACES
    from warpbw.io.exr import write_exr

    out.mkdir(parents=True, exist_ok=True)
    el = math.radians(ELEVATION_DEG)
    paths = []
    for name, (surface, tiling, mat) in SCENES.items():
        h = SURFACES[surface](size)
        write_exr(out / f"{name}.exr", h.astype(np.float32)[..., None], channels=["Y"])
        text = SCENE.format(surface=surface, size=size, tiling=tiling, cy=DISTANCE * math.sin(el),
                            cz=DISTANCE * math.cos(el), fov=FOV_DEG, w=resolution[0], h=resolution[1],
                            ly=math.sin(el), lz=-math.cos(el), name=name, **mat)
        p = out / f"{name}.toml"
        p.write_text(text)
        paths.append(p)
        print(f"wrote {p} and {name}.exr ({surface}, {size}x{size}, tiling {tiling})")
    return paths


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="bench_filtering", help="directory for the scenes (default ./bench_filtering)")
    ap.add_argument("--size", type=int, default=256, help="height-field size in texels (default 256)")
    ap.add_argument("--run", action="store_true", help="run warpbw bench-filtering on each scene")
    ap.add_argument("--zoom", default="1,2,4,8,16,32", help="zoom factors for --run")
    ap.add_argument("--gt-spp", default="1024", help="ground-truth rays per pixel for --run")
    ap.add_argument("--force", action="store_true", help="overwrite existing results")
    args = ap.parse_args(argv)
    out = Path(args.out)
    paths = write_scenes(out, args.size)
    if args.run:
        for p in paths:
            cmd = [sys.executable, "-m", "warpbw.cli", "bench-filtering", str(p), "--zoom", args.zoom,
                   "--gt-spp", args.gt_spp, "--json", str(p.with_suffix(".json")), "--plot",
                   str(p.with_suffix(".png"))] + (["--force"] if args.force else [])
            print("$", " ".join(cmd), flush=True)
            r = subprocess.run(cmd)
            if r.returncode:
                return r.returncode
    return 0


if __name__ == "__main__":
    sys.exit(main())
