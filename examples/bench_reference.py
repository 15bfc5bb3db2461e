"""Benchmark of the forward reference: G-buffer time, shading throughput, error against spp.

    python examples/bench_reference.py [--material gold-metallic-paint] [--probe forest.exr]
        [--resolution 512 512] [--spp 16,32,64,128,256,512,1024] [--gt-spp 16384] [--runs 3] [--out bench_out]
        [--force]

Scene: the Stanford bunny (../shared/data/meshes/bunny.obj) with a MERL material written from the NPF
fit by ``warpbw-precompute npf-to-merl``, under a light probe of ../shared/data/envmaps.

Protocol (../shared/DESIGN.md): times are medians of ``--runs`` runs (default 3; fewer warn, as ``warpbw bench``'s)
after a warm-up frame; the ground truth is the MIS reference at ``--gt-spp``, the mean of independently seeded
4096-spp chunks (2048 for an odd multiple of 4096, so that half of them hold half the samples; each cached),
accepted when the PSNR of a render at the sweep's largest ``--spp`` (1024 by default) against its first half and
against the whole differ by < 0.5 dB (else it says so).
Writes bench_out/bench_reference.json, a plot bench_out/bench_reference.png (error against time,
one curve per estimator), PNG previews, the MERL file (kept as a cache, stamped beside it as
``precompute.npf_to_merl`` says; converted again where the stamp is missing or stale), and the ground truth's
chunks as EXR (``warpbw.bench.ground_truth``'s cache, by scene hash, seed and ``GT_VERSION``); an earlier run's
records are kept unless ``--force`` (``--check-only`` updates them by design).

``--check-only`` redoes the ground truth and its check alone, keeping the sweep of an earlier run's JSON: the
check renders at that sweep's largest spp, and the options that describe the scene (``--material``, ``--probe``,
``--rotation``, ``--resolution``, and ``--spp`` where given) must be the ones the sweep was run with.
"""
from __future__ import annotations

from warpbw.entry import interrupt_in_one_line

interrupt_in_one_line(__name__)   # first: a Ctrl-C while the imports below load says one line, no traceback

import argparse
import json
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from warpbw.cli import check_command_options
from warpbw.bench import GT_CHUNK_SPP
from warpbw.cli_common import OneLineParser, check_overwrite, few_runs_warning, init_warp, run_command
from warpbw.errors import WarpbwError
from warpbw.io.shared_data import shared_data_dir
from warpbw.scene import MAX_RESOLUTION, toml_escape

HERE = Path(__file__).resolve().parent
DATA = shared_data_dir(HERE.parent)

SCENE = """
[camera]
position = [0.0, 0.35, 4.6]
look_at = [0.0, 0.0, 0.0]
fov = 35.0
resolution = [{w}, {h}]
[environment]
file = "{probe}"
rotation = {rotation}
[[object]]
mesh = "{mesh}"
material = "m"
[material.m]
type = "merl"
file = "{merl}"
"""
DEFAULT_SPP = "16,32,64,128,256,512,1024"
MATERIAL_NOTE = " (NPF -> MERL)"    # how the record names the material: converted from its NPF fit


def earlier_sweep(path: Path, material: str, probe: str, rotation: float, resolution, spp) -> tuple:
    """(methods, spps) of the run ``--check-only`` keeps: the records of ``path`` and the spp they were taken at.
    Refused, naming the option to pass, where this command describes another scene or (``spp``: a list, or None
    where ``--spp`` is not given) another sweep; a file that is not such a record is refused too."""
    try:
        record = json.loads(path.read_text())
        scene, methods = record["scene"], record["methods"]
        spps = sorted({int(r["spp"]) for recs in methods.values() for r in recs})
        if not methods.get("brdf_is"):
            raise ValueError("no BRDF-sampling records")
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
        why = f"no field {exc}" if isinstance(exc, KeyError) else str(exc)
        raise WarpbwError(f"--check-only: {path} is not the records of a bench_reference run ({why}); run without "
                          f"--check-only to make them") from None
    # "rotation_deg" is written since session 55: an earlier record was made at the default rotation, 0
    was = {"--material": str(scene.get("material", "")).removesuffix(MATERIAL_NOTE), "--probe": scene.get("probe"),
           "--rotation": scene.get("rotation_deg", 0.0), "--resolution": scene.get("resolution"), "--spp": spps}
    now = {"--material": material, "--probe": probe, "--rotation": rotation, "--resolution": list(resolution),
           "--spp": spps if spp is None else spp}
    for option in was:
        if was[option] != now[option]:
            then = _as_typed(option, was[option])
            raise WarpbwError(f"--check-only: {path} holds a sweep run with {option} {then}, not "
                              f"{_as_typed(option, now[option])}; pass {option} {then}")
    return methods, spps


def _as_typed(option: str, value) -> str:
    """``value`` of ``option`` as it is typed on the command line: --spp 16,64; --resolution 512 512."""
    if isinstance(value, list):
        return (",", " ")[option == "--resolution"].join(map(str, value))
    return f"{value:g}" if isinstance(value, float) else str(value)


def timed_render(prep, spp, seed, mis, runs):
    """(the last run's result, the median of the runs' wall times, the last run's stats with each stage time of
    ``stats["time_s"]`` the median over the runs, as the protocol's times are, and ``samples_per_second`` the samples
    over that median shading time; both were the last run's)."""
    from warpbw.pipeline import render_reference

    times, stages, res = [], [], None
    for r in range(runs):
        t0 = time.perf_counter()
        res = render_reference(prep, spp=spp, seed=seed + r, mis=mis)
        times.append(time.perf_counter() - t0)
        stages.append(res.stats["time_s"])
    stats = {**res.stats, "time_s": {k: statistics.median(s[k] for s in stages) for k in stages[-1]}}
    sps, last, median = res.stats.get("samples_per_second"), stages[-1]["shading"], stats["time_s"]["shading"]
    if sps is not None and median > 0:   # every run shades the same samples
        stats["samples_per_second"] = sps * last / median
    return res, statistics.median(times), stats


def main():
    ap = OneLineParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--material", default="gold-metallic-paint",
                    help="NPF material of ../shared/data/brdf/npf.bin, written as MERL (default gold-metallic-paint)")
    ap.add_argument("--probe", default="forest.exr", help="light probe in ../shared/data/envmaps (default forest.exr)")
    ap.add_argument("--rotation", type=float, default=0.0, help="the probe's rotation about +Y, degrees (default 0)")
    ap.add_argument("--resolution", type=int, nargs=2, default=[512, 512], metavar=("W", "H"),
                    help="image size in pixels (default 512 512)")
    ap.add_argument("--spp", help=f"comma-separated samples per pixel (default {DEFAULT_SPP}; with --check-only, "
                                  "those of the earlier sweep)")
    ap.add_argument("--gt-spp", type=int, default=16384,
                    help=f"ground-truth spp (a multiple of {GT_CHUNK_SPP}, at least two chunks)")
    ap.add_argument("--runs", type=int, default=3, help="timed runs per point (median)")
    ap.add_argument("--out", default="bench_out",
                    help="folder for the records, previews, the MERL file and the ground truth's cached chunks "
                    "(default bench_out)")
    ap.add_argument("--check-only", action="store_true",
                    help="redo only the ground-truth check, keeping the sweep of an earlier run's JSON")
    ap.add_argument("--force", action="store_true", help="overwrite an earlier run's records and previews")
    args = ap.parse_args()
    # the options warpbw bench also has mean the same here: its parsers check them, before any work
    spp_text = DEFAULT_SPP if args.spp is None else args.spp
    check_command_options("bench", {"--spp": spp_text, "--runs": str(args.runs)})
    if args.gt_spp % GT_CHUNK_SPP or args.gt_spp < 2 * GT_CHUNK_SPP:
        ap.error(f"--gt-spp {args.gt_spp}: expected a multiple of {GT_CHUNK_SPP} of at least {2 * GT_CHUNK_SPP} "
                 f"(the mean of cached chunks of at most {GT_CHUNK_SPP} spp, checked against its first half)")
    if not all(1 <= r <= MAX_RESOLUTION for r in args.resolution):
        ap.error(f"--resolution {args.resolution[0]} {args.resolution[1]}: expected a width and a height from 1 "
                 f"to {MAX_RESOLUTION}")
    if not math.isfinite(args.rotation):
        ap.error(f"--rotation {args.rotation}: expected a finite angle in degrees")
    out = Path(args.out)
    spps = sorted({int(s) for s in spp_text.split(",") if s.strip()})
    if not args.check_only:
        check_overwrite([out / "bench_reference.json", out / "bench_reference.png", out / "ground_truth.png"]
                        + [out / f"{m}_{spps[-1]}spp.png" for m in ("brdf_is", "mis")], args.force, "--out")
    elif not (out / "bench_reference.json").is_file():
        ap.error(f"--check-only: {out / 'bench_reference.json'} not found (an earlier run's records are needed)")
    else:   # the sweep kept, and the spp it was taken at (the check's, and the plot's 1/spp line)
        kept, spps = earlier_sweep(out / "bench_reference.json", args.material, args.probe, args.rotation,
                                   args.resolution, None if args.spp is None else spps)

    import warp as wp

    init_warp("cpu")           # Warp's no-CUDA-driver line kept off stderr
    from precompute.npf_to_merl import npf_to_merl, tabulation_is_current, write_tabulation_stamp
    from warpbw.io.exr import write_png
    from warpbw.io.npf import read_npf
    from warpbw.io.staged import staged_outputs
    from warpbw.metrics import mse, psnr, relmse
    from warpbw.pipeline import prepare_scene, render_reference
    from warpbw.scene import parse_scene

    merl, table = out / f"{args.material}.binary", DATA / "brdf" / "npf.bin"
    # the MERL file from the NPF fit (warpbw-precompute npf-to-merl), kept in OUT as a cache: used as it is while its
    # stamp says the current tabulation of this table wrote it, else converted again (bench_scenes.py does the same;
    # a file of session 68's tabulation was used as it was)
    current = tabulation_is_current(merl, table, args.material)
    if not current:   # --material checked first
        try:
            read_npf(table, args.material)
        except WarpbwError as exc:
            raise WarpbwError(f"--material {args.material}: {exc}") from None
        if args.check_only and merl.exists():   # the kept sweep measured that file's material
            raise WarpbwError(f"--check-only: {merl} is not the current tabulation of {args.material} (its stamp "
                              f"{merl.name}.tabulation says otherwise or is missing), so the kept sweep measured "
                              "another material; run without --check-only")
    if not (DATA / "envmaps" / args.probe).is_file():
        ap.error(f"--probe {args.probe}: no such probe in {DATA / 'envmaps'}")
    if not current:
        out.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        npf_to_merl(table, args.material, merl, force=True)   # OUT's own cache entry, stale or missing
        write_tabulation_stamp(merl, table, args.material)
        print(f"wrote {merl} (MERL .binary from the NPF fit, {time.perf_counter() - t0:.1f} s)")
    out.mkdir(parents=True, exist_ok=True)
    w, h = args.resolution
    probe, mesh = DATA / "envmaps" / args.probe, DATA / "meshes" / "bunny.obj"
    scene = parse_scene(SCENE.format(w=w, h=h, probe=toml_escape(str(probe), f"--probe {args.probe}"),
                                     rotation=args.rotation, mesh=toml_escape(str(mesh), str(mesh)),
                                     merl=toml_escape(str(merl.resolve()), f"--out {out}")),
                        base_dir=out, source="bench_reference")
    t0 = time.perf_counter()
    prep = prepare_scene(scene, progress=True)
    t_prep = time.perf_counter() - t0
    print(f"assets loaded in {t_prep:.2f} s: {prep.timings}")

    # warm-up frames compile every kernel variant
    render_reference(prep, spp=1, seed=0, mis=False)
    render_reference(prep, spp=1, seed=0, mis=True)

    # G-buffer alone
    from warpbw.gbuffer import render_gbuffer

    gb_times = []
    for _ in range(5):
        t0 = time.perf_counter()
        render_gbuffer(prep.camera, prep.geometry, curvature=False)
        wp.synchronize()
        gb_times.append(time.perf_counter() - t0)
    gbuffer_ms = statistics.median(gb_times) * 1e3

    # ground truth: the mean of independently seeded MIS chunks (warpbw.bench.ground_truth_chunks), every chunk cached
    # (warpbw.bench.ground_truth: by scene hash, seed and GT_VERSION, so raising --gt-spp only renders the missing
    # ones and a chunk of an older estimator is never read)
    from warpbw.bench import ground_truth

    truth = ground_truth(prep, args.gt_spp, out, progress=True)
    gt, gt_half, gt_spp, n_chunks, gt_time = truth.image, truth.half, truth.spp, truth.chunks, truth.render_time_s
    previews = {out / "ground_truth.png": gt}   # written with the records at the end
    print(f"ground truth {gt_spp} spp ({n_chunks} chunks; {gt_time:.1f} s rendering the missing ones)")
    cov = render_reference(prep, spp=1, seed=0).coverage

    records = {"brdf_is": [], "mis": []}
    for method, mis in () if args.check_only else (("brdf_is", False), ("mis", True)):
        for spp in spps:
            res, t, stats = timed_render(prep, spp, 10 + spp, mis, args.runs)
            rec = {"spp": spp, "time_s": t, "shading_s": stats["time_s"]["shading"],
                   "gbuffer_s": stats["time_s"]["gbuffer"],
                   "psnr_db": psnr(res.image, gt, cov), "relmse": relmse(res.image, gt, cov),
                   "samples_per_s": stats["samples_per_second"] * (2 if mis else 1),
                   "non_finite_samples": stats["non_finite_samples"]}
            records[method].append(rec)
            print(f"{method:8s} {spp:5d} spp  {t:7.3f} s  PSNR {rec['psnr_db']:6.2f} dB  relMSE {rec['relmse']:.3e}  "
                  f"{rec['samples_per_s'] / 1e6:.2f} M evals/s")
            if spp == max(spps):
                previews[out / f"{method}_{spp}spp.png"] = res.image
    top = max(spps)
    if args.check_only:
        records = kept
    best = render_reference(prep, spp=top, seed=77, mis=True).image
    # with one peak for both (the full ground truth's): PSNR takes its peak from the reference, and the
    # brightest covered pixel of an HDR reference is itself noisy, which would blur the check
    d_psnr = abs(10.0 * math.log10(mse(best, gt_half, cov) / mse(best, gt, cov)))
    converged = d_psnr < 0.5
    print(f"ground-truth check: PSNR of a {top}-spp MIS render against GT/2 vs GT differs by {d_psnr:.3f} dB "
          f"({'< 0.5 dB: converged' if converged else '>= 0.5 dB: NOT converged, raise --gt-spp'})")
    record = {"scene": {"mesh": "bunny.obj", "material": args.material + MATERIAL_NOTE, "probe": args.probe,
                        "rotation_deg": args.rotation, "resolution": [w, h], "covered_pixels": int(cov.sum())},
              "machine": {"cpu_count": __import__("os").cpu_count(), "device": "cpu"},
              # the timed runs per point: --check-only keeps the earlier sweep, and the count it was timed with
              "runs": (json.loads((out / "bench_reference.json").read_text()).get("runs") if args.check_only
                       else args.runs),
              "asset_load_s": t_prep, "gbuffer_ms": gbuffer_ms,
              "ground_truth_spp": gt_spp, "ground_truth_render_time_s": gt_time,
              "ground_truth_doubling_delta_db": d_psnr, "ground_truth_converged": converged,
              "methods": records}
    json_path, plot_path = out / "bench_reference.json", out / "bench_reference.png"

    from matplotlib.figure import Figure

    fig = Figure(figsize=(10, 4))   # not pyplot's: nothing to close, the caller's backend kept
    ax = fig.subplots(1, 2)
    for method, recs in records.items():
        ax[0].plot([r["time_s"] for r in recs], [r["psnr_db"] for r in recs], "o-", label=method)
        ax[1].loglog([r["spp"] for r in recs], [r["relmse"] for r in recs], "o-", label=method)
        for r in recs:
            ax[0].annotate(str(r["spp"]), (r["time_s"], r["psnr_db"]), fontsize=7)
    ax[0].set_xscale("log")
    ax[0].set_xlabel("frame time (s, 2-core CPU)")
    ax[0].set_ylabel("PSNR (dB) vs ground truth")
    ax[1].set_xlabel("samples per pixel")
    ax[1].set_ylabel("relative MSE")
    ref = np.array([records["brdf_is"][0]["relmse"] * spps[0] / s for s in spps])
    ax[1].loglog(spps, ref, "k:", label="1/spp")
    for a in ax:
        a.grid(True, which="both", alpha=0.3)
        a.legend()
    fig.suptitle(f"bunny, {args.material} (NPF->MERL), {args.probe}, {w}x{h}; G-buffer {gbuffer_ms:.0f} ms")
    fig.tight_layout()
    # all, or none: an error leaves the old set; --check-only rewrites the earlier run's own outputs
    with staged_outputs([*previews, json_path, plot_path], force=args.force or args.check_only) as at:
        for path, image in previews.items():
            write_png(at[path], image)
        at[json_path].write_text(json.dumps(record, indent=2) + "\n")
        fig.savefig(at[plot_path], dpi=110)
    print(f"G-buffer {gbuffer_ms:.1f} ms; wrote {out / 'bench_reference.json'} and {out / 'bench_reference.png'}")
    warning = None if args.check_only else few_runs_warning(args.runs)   # as warpbw bench's
    if warning is not None:
        print(f"bench_reference.py: warning: {warning}", file=sys.stderr)
    return 0 if all(math.isfinite(r["psnr_db"]) for v in records.values() for r in v) else 1


if __name__ == "__main__":
    sys.exit(run_command("bench_reference.py", lambda _: main(), None))
