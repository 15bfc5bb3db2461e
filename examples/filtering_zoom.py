"""The zoom-out of a scene with planes as one strip of frames per method (004 Fig. 4 / 8 in motion).

    python examples/filtering_zoom.py SCENE.toml -o zoom_out                # zooms 1,2,4,8,16,32
    python examples/filtering_zoom.py /work/bench/filtering/scales.toml -o zoom_out --zoom 1,4,16 --gt-spp 256
    python examples/filtering_zoom.py grazing/dunes.toml -o zoom_aniso --max-anisotropy 16   # anisotropic footprints

Writes OUT/METHOD.png for every method (gmm_aligned, gmm_unaligned, toksvig, lean, fixed, ground_truth):
the frames at each zoom side by side, each cropped to the plane's bounding box and scaled to the same
height so the surface stays readable as it shrinks (nearest-neighbour, so pixels stay pixels), with a
common exposure taken from the ground truth; and OUT/all.png stacking the strips.  The scene files of the
benchmark come from ``examples/filtering_scenes.py``.
"""
from __future__ import annotations

from warpbw.entry import interrupt_in_one_line

interrupt_in_one_line(__name__)   # first: a Ctrl-C while the imports below load says one line, no traceback

import math
import sys
from pathlib import Path

import numpy as np

from warpbw.cli_common import OneLineParser, check_output_dir, check_overwrite, init_warp, run_command
from warpbw.errors import INT32_MAX

TILE = 160          # height of a frame in the strip, pixels


def crop(img, cov):
    rows = np.flatnonzero(cov.any(1))
    cols = np.flatnonzero(cov.any(0))
    if rows.size == 0:
        return img
    return img[rows[0]:rows[-1] + 1, cols[0]:cols[-1] + 1]


def main(argv=None) -> int:
    ap = OneLineParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", help="scene file with planes")
    ap.add_argument("-o", "--output", default="zoom_out",
                    help="output directory for METHOD.png, one strip per method, and all.png (default ./zoom_out)")
    ap.add_argument("--zoom", default="1,2,4,8,16,32", help="zoom factors (default 1,2,4,8,16,32)")
    ap.add_argument("--gt-spp", type=int, default=256, help="ground-truth rays per pixel, 64 to 2^31-1 (default 256)")
    ap.add_argument("--max-anisotropy", type=int, default=1, metavar="N",
                    help="filter with up to N probes along each footprint's major axis (default 1: isotropic, 004; "
                    "see warpbw render --help)")
    ap.add_argument("--force", action="store_true", help="overwrite existing strips in the output directory")
    args = ap.parse_args(argv)
    try:
        zooms = [float(z) for z in args.zoom.split(",")]
    except ValueError:
        zooms = []
    if not zooms or not all(z > 0 and math.isfinite(z) for z in zooms):
        ap.error(f"--zoom {args.zoom!r}: expected comma-separated positive numbers, e.g. 1,2,4,8")
    twice = sorted({z for z in zooms if zooms.count(z) > 1})
    if twice:   # each zoom is one frame of the strip: a repeat would only render it again
        ap.error(f"--zoom {args.zoom!r}: expected distinct values, got {', '.join(f'{z:g}' for z in twice)} more "
                 "than once")

    from PIL import Image

    init_warp("cpu")           # Warp's no-CUDA-driver line kept off stderr
    from warpbw.errors import WarpbwError
    from warpbw.filtering import (ALL_METHODS, MAX_ANISOTROPY, MIN_GT_SPP, prepare_filtering, render_filtering,
                                  zoomed_camera)
    from warpbw.io.exr import linear_to_srgb
    from warpbw.io.staged import staged_outputs
    from warpbw.scene import PlaneObject, load_scene

    if not MIN_GT_SPP <= args.gt_spp <= INT32_MAX:   # the shading kernels count rays in int32
        ap.error(f"--gt-spp {args.gt_spp}: expected from {MIN_GT_SPP} to {INT32_MAX} rays per pixel")
    if not 1 <= args.max_anisotropy <= MAX_ANISOTROPY:
        ap.error(f"--max-anisotropy {args.max_anisotropy}: expected an integer from 1 to {MAX_ANISOTROPY}")
    scene = load_scene(args.scene)
    if not any(isinstance(o, PlaneObject) for o in scene.objects):
        raise WarpbwError(f"{args.scene}: no [[object]] is a plane (expected a scene with planes, "
                          "e.g. from examples/filtering_scenes.py)")
    out = Path(args.output)
    check_output_dir(out, "-o")
    check_overwrite([out / f"{m}.png" for m in ALL_METHODS] + [out / "all.png"], args.force)
    out.mkdir(parents=True, exist_ok=True)
    prep = prepare_filtering(scene, ALL_METHODS, progress=True)
    frames = {m: [] for m in ALL_METHODS}
    for z in zooms:
        cam = zoomed_camera(scene.camera, z)
        for m in ALL_METHODS:
            r = render_filtering(scene, m, spp=args.gt_spp, prepared=prep, camera=cam,
                                 max_anisotropy=args.max_anisotropy)
            frames[m].append(crop(r.image, r.coverage))
    # one exposure for everything: the ground truth's 99th percentile maps to white
    white = float(np.percentile(np.concatenate([f.reshape(-1, 3) for f in frames["ground_truth"]]), 99)) or 1.0
    strips = {}   # by method, written with the grid at the end
    for m in ALL_METHODS:
        tiles = []
        for f in frames[m]:
            # sRGB codes rounded, as write_png's (truncated, every code was half a step dark and 255 only at 1)
            rgb = np.round(np.clip(linear_to_srgb(np.clip(f / white, 0, 1)), 0, 1) * 255).astype(np.uint8)
            im = Image.fromarray(rgb)
            w = max(1, round(im.width * TILE / im.height))
            tiles.append(im.resize((w, TILE), Image.NEAREST))
        strip = Image.new("RGB", (sum(t.width for t in tiles) + 4 * (len(tiles) - 1), TILE))
        x = 0
        for t in tiles:
            strip.paste(t, (x, 0))
            x += t.width + 4
        strips[m] = strip
    grid = Image.new("RGB", (max(s.width for s in strips.values()), len(strips) * (TILE + 4)))
    for i, s in enumerate(strips.values()):
        grid.paste(s, (0, i * (TILE + 4)))
    pngs = {m: out / f"{m}.png" for m in strips}
    # every strip and the grid, or none
    with staged_outputs([*pngs.values(), out / "all.png"], force=args.force) as at:
        for m, p in pngs.items():
            strips[m].save(at[p])
        grid.save(at[out / "all.png"])
    for p in pngs.values():
        print(f"wrote {p}")
    print(f"wrote {out / 'all.png'} (rows: {', '.join(ALL_METHODS)}; columns: zoom {args.zoom})")
    return 0


if __name__ == "__main__":
    sys.exit(run_command("filtering_zoom.py", lambda _: main(), None))
