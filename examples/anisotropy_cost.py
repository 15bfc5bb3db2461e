"""Frame time of anisotropic footprints against isotropic ones (``--max-anisotropy``, warpbw.filtering).

    python examples/anisotropy_cost.py bench/filtering/*.toml bench/graze20/*.toml [--size 512x384] [--runs 5]

For each scene with planes (those of ``examples/filtering_scenes.py``), at each zoom and for the filtered
methods gmm_aligned, toksvig and lean (``METHODS``), the median kernel time of ``--runs`` frames with one
isotropic probe (004) and with up to ``--aniso`` probes along each footprint's major axis, rendered alternately
so that the machine's load falls on both alike, and their ratio.  Compare the times only as that ratio: the
machine is shared.
"""
from __future__ import annotations

import math
import statistics
import sys
from dataclasses import replace

from warpbw.cli_common import OneLineParser, init_warp, run_command
from warpbw.scene import MAX_RESOLUTION

METHODS = ("gmm_aligned", "toksvig", "lean")


def main(argv=None) -> int:
    ap = OneLineParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenes", nargs="+", help="scene files with planes")
    ap.add_argument("--zoom", default="1,8,32", help="zoom factors (default 1,8,32)")
    ap.add_argument("--size", default="512x384", help="frame size WxH (default 512x384)")
    ap.add_argument("--runs", type=int, default=5, help="timed frames per setting (median; default 5)")
    ap.add_argument("--aniso", type=int, default=16, help="most probes of the anisotropic setting (default 16)")
    args = ap.parse_args(argv)
    try:
        w, h = (int(v) for v in args.size.lower().split("x"))
        zooms = [float(z) for z in args.zoom.split(",")]
    except ValueError:
        ap.error(f"--size {args.size!r} / --zoom {args.zoom!r}: expected WxH and comma-separated numbers")
    if w < 1 or h < 1 or args.runs < 1 or not zooms or min(zooms) <= 0:
        ap.error("expected a positive --size, --runs and --zoom")
    if w > MAX_RESOLUTION or h > MAX_RESOLUTION:
        ap.error(f"--size {args.size}: expected at most {MAX_RESOLUTION} pixels per side")
    if not all(math.isfinite(z) for z in zooms):   # nan passed the check above, and inf failed only after the work
        ap.error(f"--zoom {args.zoom!r}: expected comma-separated positive numbers, e.g. 1,8,32")

    init_warp("cpu")
    from warpbw.filtering import MAX_ANISOTROPY, prepare_filtering, render_filtering, zoomed_camera
    from warpbw.scene import load_scene

    if not 2 <= args.aniso <= MAX_ANISOTROPY:
        ap.error(f"--aniso {args.aniso}: expected an integer from 2 to {MAX_ANISOTROPY}")
    for path in args.scenes:
        scene = load_scene(path)
        scene = replace(scene, camera=replace(scene.camera, width=w, height=h))
        prep = prepare_filtering(scene, METHODS, progress=True)
        print(f"{path}: {w}x{h}, isotropic / up to {args.aniso} probes, ms (ratio)", flush=True)
        print(f"{'zoom':>6}" + "".join(f"{m:>26}" for m in METHODS))
        for z in zooms:
            cam = zoomed_camera(scene.camera, z)
            cells = []
            for m in METHODS:
                times = {1: [], args.aniso: []}
                for a in times:                       # warm-up: compile, touch the mipmaps
                    render_filtering(scene, m, prepared=prep, camera=cam, max_anisotropy=a)
                for _ in range(args.runs):
                    for a in times:
                        times[a].append(render_filtering(scene, m, prepared=prep, camera=cam, max_anisotropy=a).time_s)
                t1, ta = (statistics.median(times[a]) * 1e3 for a in times)
                cells.append(f"{t1:7.1f} / {ta:7.1f} ({ta / t1:4.2f}x)")
            print(f"{z:>6g}" + "".join(f"{c:>26}" for c in cells), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(run_command("anisotropy_cost", lambda _: main(), None))
