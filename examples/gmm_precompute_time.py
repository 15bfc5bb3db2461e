"""Time the GMM mipmap precompute (004 Sec. 4.1) of the three procedural test surfaces at 512x512.

Issue 4's aim: a 512x512 height field with 4 components in under 60 s on 2 cores (004 reports about
5 minutes on a 2.8 GHz Pentium IV).  Run: ``nice -n 10 python examples/gmm_precompute_time.py [--size N]
[--components K] [--runs 3] [--json OUT.json] [--plot OUT.png] [--force]``.

Each surface's time is the median of ``--runs`` builds (DESIGN.md, measurement protocol: at least 3; fewer are
timed, with its warning), after one untimed build of a small map (the first build pays for imports).
``--json`` / ``--plot`` (as ``warpbw bench``'s: the one not given goes beside the other; an existing file is kept
without ``--force``, refused before any work) write the record (the settings, the CPU count, each surface's
median ``time_s``, its runs and levels, the aim) and the plot of the seconds per surface against the 60 s aim.
"""
from __future__ import annotations

from warpbw.entry import interrupt_in_one_line

interrupt_in_one_line(__name__)   # first: a Ctrl-C while the imports below load says one line, no traceback

import os
import statistics
import sys
import time
from pathlib import Path

from precompute.gmm_mipmap import DEFAULT_COMPONENTS, MAX_COMPONENTS, build_gmm_mipmap
from precompute.surfaces import MAX_SURFACE_SIZE, MIN_SURFACE_SIZE, SURFACES
from warpbw.cli_common import (PROTOCOL_RUNS, RUNS_MAX, OneLineParser, check_record_outputs, few_runs_warning,
                               run_command, write_record)

SIZE = 512           # issue 4 acceptance: "a 512x512 height field with 4 components"
AIM_S = 60.0         # issue 4 acceptance: "... in under 60 s on 2 cores"
SURFACE_NAMES = ("dunes", "hemispherical_scales", "carved_disk")


def write_plot(record: dict, path) -> None:
    """Seconds per surface (the median as a bar, each run as a dot) against the aim."""
    from matplotlib.figure import Figure

    names = list(record["time_s"])
    fig = Figure(figsize=(6, 4))   # not pyplot's: nothing to close, the caller's backend kept
    ax = fig.subplots()
    ax.bar(range(len(names)), [record["time_s"][n] for n in names], color="C0", alpha=0.7, label="median")
    for i, n in enumerate(names):
        runs = record["time_runs_s"][n]
        ax.plot([i] * len(runs), runs, "k.", label="runs" if i == 0 else None)
    ax.axhline(record["aim_time_s"], color="C3", ls="--", label=f"aim: {record['aim_time_s']:g} s")
    ax.set_xticks(range(len(names)), names)
    ax.set_ylabel("GMM mipmap precompute (s)")
    ax.set_title(f"{record['size']}x{record['size']}, {record['components']} components, "
                 f"{record['cpu_count']} CPUs, median of {record['runs']}", fontsize=10)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv=None) -> int:
    ap = OneLineParser(description="Wall time of the GMM mipmap precompute (warpbw-precompute gmm) "
                       "of each procedural test surface (issue 4's aim: 512x512, 4 components, "
                       "under 60 s on 2 cores).")
    ap.add_argument("--size", type=int, default=SIZE, help=f"height-field side in texels (default {SIZE})")
    ap.add_argument("--components", type=int, default=DEFAULT_COMPONENTS,
                    help=f"Gaussians per texel (default {DEFAULT_COMPONENTS})")
    ap.add_argument("--runs", type=int, default=PROTOCOL_RUNS,
                    help=f"timed builds per surface (median; default {PROTOCOL_RUNS})")
    ap.add_argument("--json", type=Path, help="write the record here (JSON); without it, beside --plot as OUT.json")
    ap.add_argument("--plot", type=Path, help="write the plot here (PNG): seconds per surface against the aim; "
                    "without it, beside --json as OUT.png")
    ap.add_argument("--force", action="store_true", help="overwrite --json and --plot")
    args = ap.parse_args(argv)
    if not MIN_SURFACE_SIZE <= args.size <= MAX_SURFACE_SIZE:   # the scales need more than 2 texels per spacing
        ap.error(f"--size {args.size}: expected an integer from {MIN_SURFACE_SIZE} to {MAX_SURFACE_SIZE}")
    if not 1 <= args.components <= MAX_COMPONENTS:
        ap.error(f"--components {args.components}: expected an integer from 1 to {MAX_COMPONENTS}")
    if not 1 <= args.runs <= RUNS_MAX:
        ap.error(f"--runs {args.runs}: expected an integer from 1 to {RUNS_MAX} (the timed runs of one point)")
    json_path, plot_path = check_record_outputs(args.json, args.plot, args.force)
    # warm-up, untimed: the first build imports and sets up what the others reuse (1.5 s of a 17x17 map's 1.6 s)
    build_gmm_mipmap(SURFACES[SURFACE_NAMES[0]](MIN_SURFACE_SIZE), components=args.components, progress=False)
    runs, levels = {}, {}
    for name in SURFACE_NAMES:
        h = SURFACES[name](args.size)
        runs[name] = []
        for _ in range(args.runs):
            t0 = time.perf_counter()
            mip = build_gmm_mipmap(h, components=args.components, progress=False)
            runs[name].append(time.perf_counter() - t0)
        levels[name] = len(mip.levels)
        print(f"{name:22s} {args.size}x{args.size}, {args.components} components, {levels[name]} levels: "
              f"{statistics.median(runs[name]):6.1f} s")
    if json_path is not None:
        record = {"size": args.size, "components": args.components, "runs": args.runs, "cpu_count": os.cpu_count(),
                  "aim_time_s": AIM_S, "time_s": {n: statistics.median(r) for n, r in runs.items()},
                  "time_runs_s": runs, "levels": levels}
        write_record(json_path, plot_path, record, write_plot, force=args.force)
    warning = few_runs_warning(args.runs)
    if warning is not None:
        print(f"gmm_precompute_time.py: warning: {warning}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(run_command("gmm_precompute_time.py", lambda _: main(), None))
