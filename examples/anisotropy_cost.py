"""Frame time of anisotropic footprints against isotropic ones (``--max-anisotropy``, warpbw.filtering).

    python examples/anisotropy_cost.py bench/filtering/*.toml bench/graze20/*.toml [--size 512x384] [--runs 5]
        [--json OUT.json] [--plot OUT.png] [--force]

For each scene with planes (those of ``examples/filtering_scenes.py``), at each zoom and for the filtered
methods gmm_aligned, toksvig and lean (``METHODS``), the median kernel time of ``--runs`` frames with one
isotropic probe (004) and with up to ``--aniso`` probes along each footprint's major axis, rendered alternately
so that the machine's load falls on both alike, and their ratio.  Compare the times only as that ratio: the
machine is shared.

``--json`` / ``--plot`` (as ``warpbw bench``'s: the one not given goes beside the other; an existing file is kept
without ``--force``, refused before any work) write the record of the run (DESIGN.md, measurement protocol): the
settings, the device and threads, and per scene, zoom and method the two median times (``isotropic_time_s``,
``anisotropic_time_s``) and their ``ratio``; and the plot of that ratio against zoom, one line per method and scene.
Fewer than 3 ``--runs`` are timed, with the protocol's warning.
"""
from __future__ import annotations

from warpbw.entry import interrupt_in_one_line

interrupt_in_one_line(__name__)   # first: a Ctrl-C while the imports below load says one line, no traceback

import math
import statistics
import sys
from dataclasses import replace
from pathlib import Path

from warpbw.cli_common import (RUNS_MAX, OneLineParser, check_record_outputs, few_runs_warning, init_warp, run_command,
                               write_record)
from warpbw.scene import MAX_RESOLUTION

METHODS = ("gmm_aligned", "toksvig", "lean")


def _scene_name(path: str) -> str:
    """A scene's folder and name (bench/filtering/scales.toml and bench/graze20/scales.toml are both "scales")."""
    return "/".join(Path(path).with_suffix("").parts[-2:])


def write_plot(record: dict, path) -> None:
    """The anisotropic frame's time over the isotropic one's against zoom, one line per scene and method."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7, 4.5))   # not pyplot's: nothing to close, the caller's backend kept
    ax = fig.subplots()
    for i, sc in enumerate(record["scenes"]):
        rows = sorted(sc["zooms"], key=lambda r: r["zoom"])   # along the zoom (--zoom 4,1,2 drew 4 -> 1 -> 2)
        for j, m in enumerate(record["methods"]):
            ax.plot([r["zoom"] for r in rows], [r["methods"][m]["ratio"] for r in rows],
                    "os^"[j % 3] + "-", color=f"C{i % 10}", label=f"{_scene_name(sc['scene'])}: {m}")
    ax.axhline(1.0, color="k", lw=0.8, ls="--")
    ax.set_xscale("log", base=2)
    ax.set_xlabel("zoom (camera distance factor)")
    ax.set_ylabel(f"frame time, up to {record['aniso']} probes / 1 probe")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    w, h = record["size"]
    ax.set_title(f"cost of anisotropic footprints: {w}x{h}, median of {record['runs']} frames", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv=None) -> int:
    ap = OneLineParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenes", nargs="+", help="scene files with planes")
    ap.add_argument("--zoom", default="1,8,32", help="zoom factors (default 1,8,32)")
    ap.add_argument("--size", default="512x384", help="frame size WxH (default 512x384)")
    ap.add_argument("--runs", type=int, default=5, help="timed frames per setting (median; default 5)")
    ap.add_argument("--aniso", type=int, default=16, help="most probes of the anisotropic setting (default 16)")
    ap.add_argument("--json", help="write the record here (JSON); without it, beside --plot as OUT.json")
    ap.add_argument("--plot", help="write the plot here (PNG): the time ratio against zoom, one line per method and "
                    "scene; without it, beside --json as OUT.png")
    ap.add_argument("--force", action="store_true", help="overwrite --json and --plot")
    args = ap.parse_args(argv)
    try:
        w, h = (int(v) for v in args.size.lower().split("x"))
        zooms = [float(z) for z in args.zoom.split(",")]
    except ValueError:
        ap.error(f"--size {args.size!r} / --zoom {args.zoom!r}: expected WxH and comma-separated numbers")
    if w < 1 or h < 1 or args.runs < 1 or not zooms or min(zooms) <= 0:
        ap.error("expected a positive --size, --runs and --zoom")
    if args.runs > RUNS_MAX:
        ap.error(f"--runs {args.runs}: expected at most {RUNS_MAX} (the timed runs of one point)")
    if w > MAX_RESOLUTION or h > MAX_RESOLUTION:
        ap.error(f"--size {args.size}: expected at most {MAX_RESOLUTION} pixels per side")
    if not all(math.isfinite(z) for z in zooms):   # nan passed the check above, and inf failed only after the work
        ap.error(f"--zoom {args.zoom!r}: expected comma-separated positive numbers, e.g. 1,8,32")
    json_path, plot_path = check_record_outputs(args.json, args.plot, args.force, inputs=args.scenes)

    init_warp("cpu")
    from warpbw.filtering import MAX_ANISOTROPY, prepare_filtering, render_filtering, zoomed_camera
    from warpbw.scene import load_scene
    from warpbw.launch import default_threads

    if not 2 <= args.aniso <= MAX_ANISOTROPY:
        ap.error(f"--aniso {args.aniso}: expected an integer from 2 to {MAX_ANISOTROPY}")
    record = {"size": [w, h], "zooms": zooms, "runs": args.runs, "aniso": args.aniso, "methods": list(METHODS),
              "device": "cpu", "threads": default_threads("cpu"), "scenes": []}
    for path in args.scenes:
        scene = load_scene(path)
        scene = replace(scene, camera=replace(scene.camera, width=w, height=h))
        prep = prepare_filtering(scene, METHODS, progress=True)
        print(f"{path}: {w}x{h}, isotropic / up to {args.aniso} probes, ms (ratio)", flush=True)
        print(f"{'zoom':>6}" + "".join(f"{m:>26}" for m in METHODS))
        rows = []
        record["scenes"].append({"scene": str(path), "zooms": rows})
        for z in zooms:
            cam = zoomed_camera(scene.camera, z)
            cells = []
            rows.append({"zoom": z, "methods": {}})
            for m in METHODS:
                times = {1: [], args.aniso: []}
                for a in times:                       # warm-up: compile, touch the mipmaps
                    render_filtering(scene, m, prepared=prep, camera=cam, max_anisotropy=a)
                for _ in range(args.runs):
                    for a in times:
                        times[a].append(render_filtering(scene, m, prepared=prep, camera=cam, max_anisotropy=a).time_s)
                s1, sa = (statistics.median(times[a]) for a in times)
                t1, ta = s1 * 1e3, sa * 1e3
                cells.append(f"{t1:7.1f} / {ta:7.1f} ({ta / t1:4.2f}x)")
                rows[-1]["methods"][m] = {"isotropic_time_s": s1, "anisotropic_time_s": sa, "ratio": ta / t1}
            print(f"{z:>6g}" + "".join(f"{c:>26}" for c in cells), flush=True)
    if json_path is not None:
        write_record(json_path, plot_path, record, write_plot, force=args.force)
    warning = few_runs_warning(args.runs)
    if warning is not None:
        print(f"anisotropy_cost.py: warning: {warning}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(run_command("anisotropy_cost.py", lambda _: main(), None))
