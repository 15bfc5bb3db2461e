"""Speed against accuracy: the measurement protocol of DESIGN.md for ``warpbw bench``.

Public:
    ``GT_CHUNK_SPP``, ``DEFAULT_SPP``, ``DEFAULT_BUDGETS``
    ``ground_truth(prep, gt_spp, cache_dir, ...) -> GroundTruth``   cached, with the doubling check
    ``equal_quality_time(ref_records, mse) -> (time_s, extrapolated)``   log-log interpolation
    ``run_bench(scene, spp_list, budgets, nb_list, gt_spp, runs, mis, cache_dir, ...) -> dict``
    ``write_plot(record, path)``      error against time, one curve per method (+ the n_b sweep)
    ``format_table(record) -> str``

Protocol:
* Ground truth: the MIS reference at ``gt_spp``, the mean of independently seeded chunks of at most
  ``GT_CHUNK_SPP`` each, every chunk cached as EXR keyed by the scene's content hash (so raising
  ``gt_spp`` renders only the missing chunks).  Accepted when the PSNR of a render at the largest
  reference spp against half the ground truth and against all of it differ by < 0.5 dB (recorded).
* Error: PSNR and relative MSE of linear radiance over covered pixels (:mod:`warpbw.metrics`), averaged
  over the ``runs`` frames (MSE and relative MSE as means, PSNR of the mean MSE).
* Time: wall time of a whole frame (G-buffer included; for adaptive also the bandwidth pass) after a
  warm-up frame, median of ``runs`` runs; stage times from the frames' stats.
* Equal-quality speed-up of an adaptive point: the reference's time at the sample count that reaches
  the same MSE, interpolated linearly in (log spp, log MSE) and (log spp, log time) between measured
  counts, divided by the adaptive time.  Outside the measured range it is extrapolated along the end
  segment and flagged ``extrapolated``.  The headline ``equal_quality_speedup`` is the best
  non-extrapolated point of the budget sweep (the operating point a user would pick); every point is
  in the record.
* A scene with planes beside spheres or meshes: its spheres and meshes are benchmarked where no plane hides
  them.  The planes are not rendered (``warpbw bench-filtering`` measures the filtering renderer, where no
  sphere or mesh hides the planes), but every frame, the ground truth's included, is clipped at their distances
  (``warpbw.pipeline.render_with_planes`` does the same), so the hidden pixels take no samples and are left
  out of every error; the ground truth is cached under the whole scene's hash.
"""
from __future__ import annotations

import functools
import math
import statistics
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from warpbw.errors import WarpbwError

GT_CHUNK_SPP = 4096                                   # spp per cached ground-truth chunk
DEFAULT_SPP = (1, 2, 4, 8, 16, 32, 64, 128, 256)      # reference sweep
DEFAULT_BUDGETS = (0.5, 1, 2, 4, 8, 16, 32)           # adaptive sweep, mean samples per covered pixel
DEFAULT_GT_SPP = 8192
DOUBLING_DB = 0.5                                     # DESIGN.md: doubling the GT spp changes PSNR by < 0.5 dB
NB_SWEEP_BUDGET = 8                                   # budget of the n_b sweep unless given


@dataclass
class GroundTruth:
    image: np.ndarray          # (H, W, 3)
    half: np.ndarray           # mean of the first half of the chunks
    spp: int
    chunks: int
    render_time_s: float       # time spent rendering missing chunks in this run
    key: str


def ground_truth(prep, gt_spp: int, cache_dir: Path, seed: int = 1_000_001, progress: bool = True,
                 clip_distance=None, scene=None) -> GroundTruth:
    """MIS reference at ``gt_spp`` as the mean of cached chunks (at least two, for the doubling check),
    clipped at ``clip_distance`` (``render_reference``'s) and cached under ``scene``'s hash (default: the
    prepared scene's; a clipped ground truth must name the scene whose planes clip it)."""
    from warpbw.io.exr import read_exr, write_exr
    from warpbw.pipeline import render_reference

    chunk = min(GT_CHUNK_SPP, max(1, gt_spp // 2))
    n = max(2, gt_spp // chunk)
    key = (scene if scene is not None else prep.scene).content_hash()[:16]
    cache_dir.mkdir(parents=True, exist_ok=True)
    imgs, t_gt = [], 0.0
    for k in range(n):
        path = cache_dir / f"ground_truth-{key}-chunk{k}-{chunk}spp.exr"
        if path.exists():
            img = read_exr(path).pixels[..., :3]
            if img.shape[:2] == (prep.height, prep.width):
                imgs.append(img)
                continue
        t0 = time.perf_counter()
        img = render_reference(prep, spp=chunk, seed=seed + k * 1_000_002, mis=True, progress=progress,
                               clip_distance=clip_distance).image
        t_gt += time.perf_counter() - t0
        write_exr(path, img)
        imgs.append(img)
    return GroundTruth(np.mean(imgs, axis=0), np.mean(imgs[: n // 2], axis=0), n * chunk, n, t_gt, key)


def _interp(x: float, xs: np.ndarray, ys: np.ndarray) -> tuple[float, bool]:
    """Piecewise-linear y(x) through sorted xs, extrapolating along the end segments."""
    if len(xs) == 1:
        return float(ys[0]), True
    i = int(np.clip(np.searchsorted(xs, x) - 1, 0, len(xs) - 2))
    t = (x - xs[i]) / (xs[i + 1] - xs[i]) if xs[i + 1] != xs[i] else 0.0
    return float(ys[i] + t * (ys[i + 1] - ys[i])), bool(x < xs[0] or x > xs[-1])


def equal_quality_time(ref: list, mse: float) -> tuple[float, float, bool]:
    """(spp, time) at which the reference reaches ``mse``, interpolated on log-log; and whether it was
    extrapolated beyond the measured counts."""
    pts = sorted((r["spp"], r["mse"], r["time_s"]) for r in ref if r["mse"] > 0)
    if not pts or not (mse > 0):
        return math.nan, math.nan, True
    ls = np.log([p[0] for p in pts])
    lm = np.log([p[1] for p in pts])
    lt = np.log([p[2] for p in pts])
    # MSE falls with spp: interpolate log spp against -log MSE (increasing)
    order = np.argsort(-lm, kind="stable")
    l_spp, ext = _interp(-math.log(mse), -lm[order], ls[order])
    l_t, ext_t = _interp(l_spp, ls, lt)
    return math.exp(l_spp), math.exp(l_t), ext or ext_t


def _timed(render, runs: int, gt: GroundTruth):
    """Render ``runs`` frames (run r seeded by the caller); the last frame, the median time, and the
    errors averaged over the frames: MSE and relative MSE are means over the runs' independent noise,
    PSNR is that of the mean MSE (one frame's error is one draw: at a few samples per pixel a single
    firefly moves it by dB)."""
    from warpbw.metrics import mse, relmse

    times, res, mses, rels = [], None, [], []
    for r in range(runs):
        t0 = time.perf_counter()
        res = render(r)
        times.append(time.perf_counter() - t0)
        mses.append(mse(res.image, gt.image, res.coverage))
        rels.append(relmse(res.image, gt.image, res.coverage))
    m = statistics.fmean(mses)
    peak = float(np.max(gt.image[res.coverage])) if res.coverage.any() else 0.0
    psnr = math.inf if m == 0.0 else (-math.inf if peak <= 0.0 else 10.0 * math.log10(peak * peak / m))
    return res, statistics.median(times), {"psnr_db": psnr, "relmse": statistics.fmean(rels), "mse": m}


def run_bench(scene, spp_list=DEFAULT_SPP, budgets=DEFAULT_BUDGETS, nb_list=(), gt_spp: int = DEFAULT_GT_SPP,
              runs: int = 3, mis: bool = True, cache_dir: Path | None = None, nb_budget: float | None = None,
              seed: int = 0, device: str = "cpu", progress: bool = True, log=print,
              adaptive_options: dict | None = None) -> dict:
    """Run the protocol on one scene and return the JSON record (see the module docstring; a scene with planes
    beside spheres or meshes benches the spheres and meshes the planes leave visible).
    ``adaptive_options`` go to every ``render_adaptive`` call (e.g. ``allocation``, ``nyquist``)."""
    from precompute.brdf_sampling import cache_dir as default_cache
    from warpbw import pipeline

    if runs < 1:
        raise WarpbwError(f"runs: expected at least 1, got {runs}")
    surfaces, planes = pipeline.split_planes(scene)
    if surfaces is None:
        raise WarpbwError(f"{scene.source}: bench measures spheres and meshes, and the scene has planes only "
                          "(use bench-filtering)")
    clip = None
    if planes is not None:
        from warpbw.filtering import plane_distance

        clip = plane_distance(planes, device)
    render_reference = functools.partial(pipeline.render_reference, clip_distance=clip)
    render_adaptive = functools.partial(pipeline.render_adaptive, clip_distance=clip)
    cache_dir = Path(cache_dir) if cache_dir is not None else default_cache() / "ground_truth"
    t0 = time.perf_counter()
    prep = pipeline.prepare_scene(surfaces, device=device, progress=progress)
    # warm-up frames: compile every kernel variant and build the bandwidth tables
    hidden = render_reference(prep, spp=1, seed=seed, mis=mis).stats.get("pixels_hidden", 0)
    opts = dict(adaptive_options or {})
    render_adaptive(prep, budget=1.0, seed=seed, mis=mis, progress=progress, **opts)
    t_prep = time.perf_counter() - t0
    log(f"assets and warm-up: {t_prep:.1f} s")
    gt = ground_truth(prep, gt_spp, cache_dir, progress=progress, clip_distance=clip, scene=scene)
    log(f"ground truth: {gt.spp} spp MIS ({gt.chunks} chunks, {gt.render_time_s:.1f} s rendering missing ones)")
    est = "mis" if mis else "brdf_is"
    ref_recs = []
    cov = None
    last = None
    for spp in spp_list:
        res, t, err = _timed(lambda r: render_reference(prep, spp=spp, seed=seed + 101 * spp + r, mis=mis), runs, gt)
        cov = res.coverage
        last = res.image
        rec = {"spp": int(spp), "time_s": t, **err,
               "shading_time_s": res.stats["time_s"]["shading"], "gbuffer_time_s": res.stats["time_s"]["gbuffer"]}
        ref_recs.append(rec)
        log(f"reference {spp:6d} spp   {t:8.3f} s   PSNR {rec['psnr_db']:6.2f} dB   relMSE {rec['relmse']:.3e}")
    # doubling check of the ground truth, with the largest reference render
    from warpbw.metrics import mse as mse_of

    d_db = abs(10.0 * math.log10(mse_of(last, gt.half, cov) / mse_of(last, gt.image, cov)))
    converged = d_db < DOUBLING_DB
    log(f"ground-truth check: {d_db:.3f} dB ({'converged' if converged else 'NOT converged: raise --gt-spp'})")
    ada_recs = []
    for b in budgets:
        res, t, err = _timed(lambda r: render_adaptive(prep, budget=b, seed=seed + 7 * r, mis=mis, **opts), runs, gt)
        ts = res.stats["time_s"]
        spp_eq, t_eq, ext = equal_quality_time(ref_recs, err["mse"])
        rec = {"budget": float(b), "time_s": t, **err,
               "bandwidth_time_s": ts["bandwidth"], "shading_time_s": ts["shading"],
               "upsampling_time_s": ts["upsampling"], "hierarchy_time_s": ts["hierarchy"],
               "gbuffer_time_s": ts["gbuffer"], "frame_time_s": ts["frame"],
               "bandwidth_time_fraction": ts["bandwidth"] / t if t > 0 else 0.0,
               "shaded_fraction": res.stats["shaded_fraction"], "samples": res.stats["samples"],
               "samples_per_covered_pixel": res.stats["samples_per_covered_pixel"],
               "over_budget": res.stats["allocation"]["over_budget"],
               "equal_quality_spp": spp_eq, "equal_quality_reference_time_s": t_eq,
               "equal_quality_speedup": t_eq / t if t > 0 else math.nan, "extrapolated": ext}
        ada_recs.append(rec)
        log(f"adaptive  {b:6g} spp   {t:8.3f} s   PSNR {rec['psnr_db']:6.2f} dB   relMSE {rec['relmse']:.3e}   "
            f"shaded {100 * rec['shaded_fraction']:5.1f}%   bandwidth {100 * rec['bandwidth_time_fraction']:4.1f}%   "
            f"speed-up {rec['equal_quality_speedup']:.2f}x{' (extrapolated)' if ext else ''}")
    nb_recs = []
    nbb = NB_SWEEP_BUDGET if nb_budget is None else nb_budget
    for n_b in nb_list:
        res, t, err = _timed(lambda r: render_adaptive(prep, budget=nbb, seed=seed + 7 * r, mis=mis, n_b=int(n_b),
                                                       **opts), runs, gt)
        rec = {"n_b": int(n_b), "budget": float(nbb), "time_s": t, **err,
               "bandwidth_time_s": res.stats["time_s"]["bandwidth"], "shaded_fraction": res.stats["shaded_fraction"]}
        nb_recs.append(rec)
        log(f"n_b {n_b:5d} (budget {nbb:g})   {t:8.3f} s   PSNR {rec['psnr_db']:6.2f} dB   "
            f"bandwidth {rec['bandwidth_time_s'] * 1e3:.1f} ms")
    valid = [r for r in ada_recs if not r["extrapolated"] and math.isfinite(r["equal_quality_speedup"])]
    best = max(valid, key=lambda r: r["equal_quality_speedup"]) if valid else None
    record = {
        "scene": str(scene.source),
        "scene_hash": gt.key,
        "resolution": [prep.width, prep.height],
        "pixels_covered": int(cov.sum()) if cov is not None else 0,
        "materials": {n: prep.scene.materials[n].type for n in prep.scene.material_order},
        "environment": prep.env.name,
        "estimator": est,
        "adaptive_options": opts,
        "runs": int(runs),
        "ground_truth_spp": gt.spp,
        "ground_truth_doubling_delta_db": d_db,
        "ground_truth_converged": converged,
        "methods": {"reference": ref_recs, "adaptive": ada_recs},
        "equal_quality_speedup": best["equal_quality_speedup"] if best else None,
        "equal_quality_budget": best["budget"] if best else None,
        "bandwidth_time_fraction": (best["bandwidth_time_fraction"] if best
                                    else statistics.median(r["bandwidth_time_fraction"] for r in ada_recs)
                                    if ada_recs else None),
        "asset_and_warmup_time_s": t_prep,
    }
    if planes is not None:
        record["planes"] = {"objects": len(planes.objects), "pixels_hidden": int(hidden),
                            "rendered": False,
                            "note": "spheres and meshes benched where no plane hides them; the planes are not "
                                    "rendered (bench-filtering measures them where no sphere or mesh hides them)"}
    if nb_recs:
        ps = [r["psnr_db"] for r in nb_recs]
        record["nb_sweep"] = nb_recs
        record["nb_psnr_range_db"] = max(ps) - min(ps)
    return record


def format_table(record: dict) -> str:
    lines = [f"{record['scene']}  {record['resolution'][0]}x{record['resolution'][1]}, "
             f"{record['pixels_covered']} covered pixels, estimator {record['estimator']}, "
             f"ground truth {record['ground_truth_spp']} spp "
             f"(doubling {record['ground_truth_doubling_delta_db']:.2f} dB)"]
    if "planes" in record:
        lines.append(f"spheres and meshes only: {record['planes']['pixels_hidden']} pixels hidden by "
                     f"{record['planes']['objects']} plane(s) left out; the planes are not rendered (bench-filtering)")
    lines.append(f"{'method':10s} {'spp/budget':>10s} {'time (s)':>9s} {'PSNR':>7s} {'relMSE':>10s} {'shaded':>7s} "
                 f"{'bw %':>5s} {'speed-up':>9s}")
    for r in record["methods"]["reference"]:
        lines.append(f"{'reference':10s} {r['spp']:10d} {r['time_s']:9.3f} {r['psnr_db']:7.2f} {r['relmse']:10.3e}")
    for r in record["methods"]["adaptive"]:
        lines.append(f"{'adaptive':10s} {r['budget']:10g} {r['time_s']:9.3f} {r['psnr_db']:7.2f} {r['relmse']:10.3e} "
                     f"{100 * r['shaded_fraction']:6.1f}% {100 * r['bandwidth_time_fraction']:5.1f} "
                     f"{r['equal_quality_speedup']:8.2f}x{'*' if r['extrapolated'] else ''}")
    s = record["equal_quality_speedup"]
    lines.append(f"equal-quality speed-up: {s:.2f}x at budget {record['equal_quality_budget']:g}" if s is not None
                 else "equal-quality speed-up: none within the measured reference range")
    if record.get("bandwidth_time_fraction") is not None:
        lines.append(f"bandwidth pass: {100 * record['bandwidth_time_fraction']:.1f}% of the frame")
    for r in record.get("nb_sweep", []):
        lines.append(f"n_b {r['n_b']:5d}: PSNR {r['psnr_db']:.2f} dB, {r['time_s']:.3f} s, "
                     f"bandwidth {r['bandwidth_time_s'] * 1e3:.1f} ms")
    if "nb_psnr_range_db" in record:
        lines.append(f"n_b sweep: PSNR range {record['nb_psnr_range_db']:.2f} dB")
    lines.append("(* extrapolated beyond the measured reference counts)")
    return "\n".join(lines)


def write_plot(record: dict, path) -> None:
    """PSNR against frame time (one curve per method), and the n_b sweep when present."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    has_nb = bool(record.get("nb_sweep"))
    fig, axes = plt.subplots(1, 2 if has_nb else 1, figsize=(11 if has_nb else 6, 4.2), squeeze=False)
    ax = axes[0][0]
    ref, ada = record["methods"]["reference"], record["methods"]["adaptive"]
    ax.plot([r["time_s"] for r in ref], [r["psnr_db"] for r in ref], "o-", label=f"reference ({record['estimator']})")
    ax.plot([r["time_s"] for r in ada], [r["psnr_db"] for r in ada], "s-", label="adaptive (002)")
    for r in ref:
        ax.annotate(f"{r['spp']}", (r["time_s"], r["psnr_db"]), fontsize=7, xytext=(3, -8), textcoords="offset points")
    for r in ada:
        ax.annotate(f"{r['budget']:g}", (r["time_s"], r["psnr_db"]), fontsize=7, xytext=(3, 3),
                    textcoords="offset points")
    ax.set_xscale("log")
    ax.set_xlabel("frame time (s)")
    ax.set_ylabel("PSNR (dB) against the ground truth")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    s = record["equal_quality_speedup"]
    ax.set_title(f"equal-quality speed-up {s:.1f}x" if s is not None else "speed against accuracy", fontsize=10)
    if has_nb:
        ax2 = axes[0][1]
        nb = record["nb_sweep"]
        ax2.semilogx([r["n_b"] for r in nb], [r["psnr_db"] for r in nb], "o-", color="C2", label="PSNR")
        ax2.set_xlabel("n_b (directions of the bandwidth estimate)")
        ax2.set_ylabel("PSNR (dB)")
        ax3 = ax2.twinx()
        ax3.semilogx([r["n_b"] for r in nb], [r["time_s"] for r in nb], "s--", color="C3", label="time")
        ax3.set_ylabel("frame time (s)")
        ax2.set_title(f"n_b sweep at budget {nb[0]['budget']:g} (002 Fig. 13)", fontsize=10)
        ax2.grid(True, which="both", alpha=0.3)
    fig.suptitle(f"{Path(record['scene']).name}: {record['resolution'][0]}x{record['resolution'][1]}, "
                 f"ground truth {record['ground_truth_spp']} spp", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
