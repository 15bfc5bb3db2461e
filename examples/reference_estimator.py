"""Reference estimator example (002 Eq. 2), stage by stage at the kernel level: G-buffer, materials,
environment, then N BRDF-importance samples per pixel, with and without MIS.

    python examples/reference_estimator.py [--probe ../shared/data/envmaps/studio.exr] [--spp 64] [--runs 3]
        [--out ref_out] [--json OUT.json] [--plot OUT.png] [--force]

Two analytic spheres (Lambert and GGX) and one NPF sphere under a light probe (the procedural sky when
the default probe is absent; the NPF sphere is left out when the default NPF table is).  Prints time
per stage (assets, G-buffer, each estimator) and throughput (the G-buffer's and each estimator's time the median
of ``--runs`` frames after a warm-up frame, DESIGN.md's measurement protocol; fewer than 3 warn, as ``warpbw
bench``'s; until session 75 the G-buffer was not timed); writes ref_bis.exr / ref_mis.exr and PNGs.  ``--json`` /
``--plot`` (as ``warpbw bench``'s: the one not given goes beside the other; an existing file is kept without
``--force``, refused before any work) write the record (the settings, device and threads, ``gbuffer_time_s``, and
per estimator every figure printed) and its plot (each estimator's time and throughput).
"""
from warpbw.entry import interrupt_in_one_line

interrupt_in_one_line(__name__)   # first: a Ctrl-C while the imports below load says one line, no traceback

import argparse
import statistics
import sys
import time
from pathlib import Path

from warpbw import brdf as B
from warpbw.cli_common import (PROTOCOL_RUNS, RUNS_MAX, OneLineParser, check_output_dir, check_overwrite,
                               check_record_outputs, few_runs_warning, init_warp, run_command, write_record)
from warpbw.envmap import envmap_from_array, load_envmap, procedural_sky
from warpbw.errors import INT32_MAX, check_count
from warpbw.gbuffer import SphereSpec, build_geometry, make_camera, render_gbuffer
from warpbw.io.exr import write_exr, write_png
from warpbw.io.shared_data import shared_data_dir
from warpbw.io.staged import staged_outputs
from warpbw.scene import MAX_RESOLUTION
from warpbw.launch import default_threads
from warpbw.shading import shade_reference

OUTPUTS = ("ref_bis.exr", "ref_bis.png", "ref_mis.exr", "ref_mis.png")


def write_plot(record: dict, path) -> None:
    """Each estimator's frame time (the median as a bar, each run as a dot) and its throughput."""
    from matplotlib.figure import Figure

    names = list(record["estimators"])
    est = [record["estimators"][n] for n in names]
    fig = Figure(figsize=(9, 3.8))   # not pyplot's: nothing to close, the caller's backend kept
    ax, ax2 = fig.subplots(1, 2)
    ax.bar(names, [e["time_s"] for e in est], color="C0", alpha=0.7, label=f"median of {record['runs']}")
    for i, e in enumerate(est):
        ax.plot([i] * len(e["time_runs_s"]), e["time_runs_s"], "k.", label="runs" if i == 0 else None)
    ax.set_ylabel("shading time (s)")
    ax.legend(fontsize=8)
    ax2.bar(names, [e["evaluations_per_s"] / 1e6 for e in est], color="C1")
    ax2.set_ylabel("M evaluations / s")
    w, h = record["resolution"]
    fig.suptitle(f"reference estimator: {w}x{h}, {record['spp']} spp, {record['environment']}; "
                 f"{record['device']}, {record['threads']} threads", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main():
    here = Path(__file__).resolve().parent
    data = shared_data_dir(here.parent)
    ap = OneLineParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    default_probe, default_npf = data / "envmaps" / "studio.exr", data / "brdf" / "npf.bin"
    ap.add_argument("--probe", help=f"lat-long EXR light probe (default {default_probe}; the procedural sky "
                                    "when it is absent)")
    ap.add_argument("--npf", help=f"NPF table (default {default_npf}; no NPF sphere when it is absent)")
    ap.add_argument("--material", default="gold-metallic-paint", help="NPF material of the NPF sphere (default "
                    "gold-metallic-paint)")
    ap.add_argument("--spp", type=int, default=64, help="samples per pixel (default 64)")
    ap.add_argument("--runs", type=int, default=PROTOCOL_RUNS,
                    help=f"timed frames per estimator (median; default {PROTOCOL_RUNS})")
    ap.add_argument("--resolution", type=int, nargs=2, default=[384, 160], metavar=("W", "H"),
                    help="image size in pixels (default 384 160)")
    ap.add_argument("--device", default="cpu", help="Warp device (default cpu; cuda where there is one)")
    ap.add_argument("--out", default="ref_out", help="output folder (default ref_out)")
    ap.add_argument("--json", help="write the record here (JSON); without it, beside --plot as OUT.json")
    ap.add_argument("--plot", help="write the plot here (PNG): each estimator's time and throughput; without it, "
                    "beside --json as OUT.png")
    ap.add_argument("--force", action="store_true", help="overwrite existing outputs in --out, and --json / --plot")
    args = ap.parse_args()
    dev = args.device
    w, h = args.resolution
    if not (1 <= w <= MAX_RESOLUTION and 1 <= h <= MAX_RESOLUTION):
        ap.error(f"--resolution {w} {h}: expected a width and a height of at least 1 pixel and at most "
                 f"{MAX_RESOLUTION}")
    check_count(args.spp, "--spp", 1, INT32_MAX)   # the shading kernel counts samples in int32
    check_count(args.runs, "--runs", 1, RUNS_MAX)   # the timed runs of one point
    for flag, given in (("--probe", args.probe), ("--npf", args.npf)):
        if given is not None and not Path(given).is_file():
            ap.error(f"{flag} {given}: no such file")
    probe = Path(args.probe) if args.probe is not None else default_probe
    npf = Path(args.npf) if args.npf is not None else default_npf
    out = Path(args.out)
    check_output_dir(out, "--out")   # named by its option (they were refused as "-o OUT/NAME")
    check_overwrite([out / n for n in OUTPUTS], args.force, "--out")
    json_path, plot_path = check_record_outputs(args.json, args.plot, args.force, inputs=[probe, npf])
    init_warp(dev)             # --device checked; Warp's no-CUDA-driver line kept off stderr

    t0 = time.perf_counter()
    env = load_envmap(probe, device=dev) if probe.is_file() else \
        envmap_from_array(procedural_sky(512, 256), name="procedural sky", device=dev)
    specs = [B.MaterialSpec("lambert", B.LAMBERT, albedo=(0.7, 0.7, 0.7)),
             B.MaterialSpec("ggx", B.GGX, alpha=0.15, specular=(0.95, 0.95, 0.95))]
    spheres = [SphereSpec((-1.3, 0, 0), 0.6, 0), SphereSpec((0, 0, 0), 0.6, 1)]
    if npf.is_file():
        from warpbw.io.npf import npf_eval, read_npf
        from warpbw.sampling import build_sampler_table

        m = read_npf(npf, args.material)
        specs.append(B.MaterialSpec(m.name, B.NPF, npf=B.pack_npf_curves(m.rho_d, m.rho_s, m.D, m.G1, m.F),
                                    linear=True, sampler=build_sampler_table(lambda a, b: npf_eval(m, a, b))))
        spheres.append(SphereSpec((1.3, 0, 0), 0.6, 2))
    mats = B.build_material_table(specs, device=dev)
    geo = build_geometry(spheres, [], device=dev)
    cam = make_camera((0, 0.4, 4.5), (0, 0, 0), (0, 1, 0), 45.0, w, h)
    t_assets = time.perf_counter() - t0
    print(f"assets: {t_assets:.2f} s ({env.name}, materials {', '.join(mats.names)})")
    record = {"resolution": [w, h], "spp": args.spp, "runs": args.runs, "environment": env.name,
              "materials": list(mats.names), "device": dev, "threads": default_threads(dev),
              "assets_time_s": t_assets, "estimators": {}}

    gb = render_gbuffer(cam, geo, device=dev)   # warm-up (compiles); then timed as the estimators are
    g_times = []
    for _ in range(args.runs):
        t0 = time.perf_counter()
        gb = render_gbuffer(cam, geo, device=dev)
        g_times.append(time.perf_counter() - t0)
    record["gbuffer_time_s"] = statistics.median(g_times)
    print(f"G-buffer: {record['gbuffer_time_s'] * 1e3:.1f} ms")
    images = {}   # name -> image, written together at the end
    for mis in (False, True):
        shade_reference(gb, mats, env.data, 1, mis=mis, device=dev)      # warm-up (compiles)
        times = []
        for _ in range(args.runs):
            t0 = time.perf_counter()
            res = shade_reference(gb, mats, env.data, args.spp, seed=1, mis=mis, device=dev)
            times.append(time.perf_counter() - t0)
        dt = statistics.median(times)
        evals = res.samples * (2 if mis else 1)
        img = res.radiance.numpy().reshape(h, w, 3)
        name = "ref_mis" if mis else "ref_bis"
        images[name] = img
        mean = img[gb.coverage].mean(0).round(4)
        print(f"{name}: {args.spp} spp over {res.pixels_shaded} pixels in {dt:.2f} s "
              f"({evals / dt / 1e6:.2f} M evaluations/s), non-finite samples {res.non_finite}; "
              f"mean radiance {mean}")
        record["estimators"][name] = {"mis": mis, "pixels_shaded": int(res.pixels_shaded), "time_s": dt,
                                      "time_runs_s": times, "evaluations": int(evals),
                                      "evaluations_per_s": evals / dt, "non_finite_samples": int(res.non_finite),
                                      "mean_radiance": [float(v) for v in img[gb.coverage].mean(0)]}
    # all four, or none: an error leaves the old set
    with staged_outputs([out / n for n in OUTPUTS], force=args.force) as at:
        for name, img in images.items():
            write_exr(at[out / f"{name}.exr"], img)
            write_png(at[out / f"{name}.png"], img)
    print(f"wrote {out}/ref_bis.exr, ref_mis.exr and PNGs")
    if json_path is not None:
        write_record(json_path, plot_path, record, write_plot, force=args.force)
    warning = few_runs_warning(args.runs)
    if warning is not None:
        print(f"reference_estimator.py: warning: {warning}", file=sys.stderr)


if __name__ == "__main__":
    sys.exit(run_command("reference_estimator.py", lambda _: main(), None))
