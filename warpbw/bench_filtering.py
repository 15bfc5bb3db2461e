"""Reflectance-filtering benchmark (issue 4, 004 Fig. 4 / 8): error, flicker, temporal error and time of each
filtered method along a zoom-out, against the ground truth.

Public:
    ``DEFAULT_ZOOMS``, ``DEFAULT_GT_SPP``, ``FLICKER_STEP``, ``FLICKER_PAIRS_MAX``, ``GMM_TEMP_PREFIX``
    ``colour_error(image, ref, mask) -> float``     per-pixel normalised Euclidean colour error, mean
    ``flicker(a0, a1, g0, g1, mask, norm) -> float``  frame-to-frame change in excess of the ground truth's
    ``temporal_error(a0, a1, g0, g1, mask, norm) -> float``  frame-to-frame change's distance to the truth's
    ``run_bench_filtering(scene, zooms, gt_spp, runs, seed, device, cache, progress, log, methods,
                          env_spp, max_anisotropy, flicker_pairs) -> dict``
    ``write_plot(record, path)``                    error, flicker and temporal error against zoom; error against time
    ``format_table(record) -> str``

Protocol.  Zoom z: the camera moved away from its look-at point to z times its distance, same resolution
and field of view (``warpbw.filtering.zoomed_camera``), so the surface shrinks on screen and every pixel
covers z^2 times more texels.
* Error: per covered pixel, the Euclidean distance of the RGB radiance to the ground truth's, divided by
  the ground truth's mean colour norm over covered pixels (so 0.1 = off by a tenth of a typical pixel),
  averaged over the covered pixels (004 Fig. 4 / 8 report a "normalized Euclidean color error per pixel").
* Flicker: a continuous zoom-out seen in two consecutive frames, z and z * FLICKER_STEP.  Per pixel
  covered in both, the change |I(z') - I(z)| in excess of the ground truth's own change
  |G(z') - G(z)| (clamped at 0: a method may change less than the truth without flickering), normalised as
  the error, mean over the pixels.  A method that follows the truth scores 0; shimmering (a highlight that
  pops between frames as the footprint moves over the texels) scores high.  One pair of frames is one
  sample of where the footprints fall on the texels; ``flicker_pairs`` = P > 1 measures P consecutive pairs,
  z * FLICKER_STEP^j to z * FLICKER_STEP^(j+1) for j < P, and averages the flicker (and the temporal error) over
  them, each pair normalised by its first frame's truth, so that pair j scores what a one-pair run at zoom
  z * FLICKER_STEP^j does (the error stays that of the frame at z).  Recorded as ``flicker_pairs``.
* Temporal error (ours, not the issue's; recorded beside the flicker): per pixel covered in both frames, the
  distance |(I(z') - I(z)) - (G(z') - G(z))| between the method's change and the truth's, normalised and
  averaged as the flicker.  The flicker counts only change beyond the truth's, so an image that changes less
  than the truth everywhere scores 0 -- even one that does not change at all, or changes where the truth
  does not -- and blurrier filters, whose images change less, score lower.  The temporal error is 0 only
  for a method that changes as the truth does, and a frozen image scores the truth's whole mean change.
  The ground truth's own floor is ``ground_truth[i].temporal_noise``: the temporal error of a second,
  independently seeded ground-truth pair.
* PSNR and relative MSE (``warpbw.metrics``, the measurement protocol's) of the frame at z against the ground
  truth over its covered pixels, recorded beside the error as ``psnr_db`` and ``relmse``.
* Time: kernel time of one frame after a warm-up frame (compiled kernels), median of ``runs``.
* Under an [environment] every method also samples it (``warpbw.filtering``: ``env_spp`` BRDF + environment
  pairs per pixel, by default ``warpbw.filtering.DEFAULT_ENV_SPP``; the same seed in both frames of a flicker
  pair), so errors and flicker then include that noise; the record holds ``env_spp`` (null without an
  environment).
* Ground truth: ``gt_spp`` jittered rays per pixel (``warpbw.filtering``), the same seed in both frames of
  a flicker pair; its own noise is reported per zoom as ``ground_truth[i].noise`` = error of a second,
  independently seeded ground truth / sqrt(2), the floor under every method's error, and
  ``flicker_noise`` = what the truth's noise alone scores as flicker: the first truth's change, G(z') - G(z),
  scored against the change from the second truth's frame at z to the first truth's at z', G(z') - G2(z),
  which carries one frame's independent noise.
* Footprints: isotropic by default (004 Sec. 4.2's trilinear filtering); ``max_anisotropy`` > 1 filters every
  method with up to that many probes along each footprint's major axis (``warpbw.filtering``), recorded as
  ``max_anisotropy``.  The ground truth does not depend on it.
* A scene with planes beside spheres or meshes: the planes are measured where no sphere or mesh hides them.
  Per camera a G-buffer pass of the spheres and meshes alone (``warpbw.pipeline.surface_geometry``) gives
  their depth, and every frame (ground truth and methods) draws the planes over that depth with a black
  image (``warpbw.filtering.Background``), so the hidden pixels are neither shaded nor counted as covered
  (the spheres and meshes are measured by ``warpbw bench``).  The record lists them under ``surfaces``
  (empty for planes alone).
* A zoom at which no pixel sees a plane (in either frame, or in both frames of a flicker pair: a plane of a pixel or
  two that moves to the next one), or spheres or meshes hide every pixel that does, is refused before any work,
  saying which; one whose ground truth is black at every pixel that sees a plane (lit from below the planes'
  horizon, or by nothing: every method is black too, and the error relative to the truth's mean is undefined)
  once that truth is rendered.
* Precompute time: the time to obtain the aligned GMM mipmaps (built unless the scene names a file or
  ``cache`` holds them: the origin is recorded, and the table and the plot say where they were read).
"""
from __future__ import annotations

import math
import statistics
import time
from pathlib import Path

import numpy as np

from warpbw.errors import INT32_MAX, WarpbwError, check_count, check_path, offset_seed
from warpbw.io.staged import temporary_folder
from warpbw.metrics import psnr, relmse

DEFAULT_ZOOMS = (1, 2, 4, 8, 16, 32)
# Ground-truth rays per pixel of the benchmark: a pixel of the far zooms covers hundreds of texels.
DEFAULT_GT_SPP = 1024
# Zoom ratio of two consecutive frames of the continuous zoom-out the flicker is measured on (8 frames per
# doubling of the distance).
FLICKER_STEP = 2.0 ** (1.0 / 8.0)
FLICKER_PAIRS_MAX = 8   # at most one octave of the zoom (8 steps of FLICKER_STEP) per zoom
# Seeds of the ground truths (plus ``seed``; the second one estimates the ground truth's noise).
GT_SEED = 1_000_003
GT_SEED_2 = 2_000_003
# The system's temporary folder holds the GMM mipmaps a run without ``cache`` builds, in a folder of this prefix
# named after its process (``warpbw.io.staged.temporary_folder``: the next run removes one a SIGKILL left).
GMM_TEMP_PREFIX = "warpbw-gmm-"


def _norm(ref, mask) -> float:
    n = np.linalg.norm(ref, axis=-1)[mask]
    m = float(n.mean()) if n.size else 0.0
    return m if m > 0 else 1.0


def colour_error(image, ref, mask) -> float:
    """Mean over ``mask`` of |image - ref| (RGB Euclidean) / mean |ref|."""
    mask = np.asarray(mask, bool)
    if not mask.any():
        return float("nan")
    d = np.linalg.norm(np.asarray(image, np.float64) - ref, axis=-1)[mask]
    return float(d.mean() / _norm(ref, mask))


def flicker(a0, a1, g0, g1, mask, norm: float) -> float:
    """Mean over ``mask`` of max(0, |a1 - a0| - |g1 - g0|) / norm (RGB Euclidean norms)."""
    mask = np.asarray(mask, bool)
    if not mask.any():
        return float("nan")
    da = np.linalg.norm(np.asarray(a1, np.float64) - a0, axis=-1)
    dg = np.linalg.norm(np.asarray(g1, np.float64) - g0, axis=-1)
    return float(np.maximum(da - dg, 0.0)[mask].mean() / norm)


def temporal_error(a0, a1, g0, g1, mask, norm: float) -> float:
    """Mean over ``mask`` of |(a1 - a0) - (g1 - g0)| / norm (RGB Euclidean norms)."""
    mask = np.asarray(mask, bool)
    if not mask.any():
        return float("nan")
    d = (np.asarray(a1, np.float64) - a0) - (np.asarray(g1, np.float64) - g0)
    return float(np.linalg.norm(d, axis=-1)[mask].mean() / norm)


def _surfaces_behind(surfaces, device: str):
    """``camera -> Background | None``: the spheres and meshes of ``surfaces`` (a scene, or None) as the black
    background the planes are drawn over, their camera-space depth from a G-buffer pass at that camera
    (module docstring); None for planes alone."""
    if surfaces is None:
        return lambda camera: None
    from warpbw.filtering import Background
    from warpbw.gbuffer import render_gbuffer, scene_camera
    from warpbw.pipeline import surface_geometry

    geometry = surface_geometry(surfaces, device)

    def behind(c):
        depth = render_gbuffer(scene_camera(c), geometry, device, curvature=False, attributes=False).numpy("depth")
        return Background(np.zeros(depth.shape + (3,), np.float32), depth)

    return behind


def _zoom_frames(scene, zooms, behind, pairs: int = 1) -> list:
    """Per zoom z, its frames' zooms z * FLICKER_STEP^j (j = 0 ... ``pairs``), cameras and the spheres and meshes
    behind each (``behind``): ``[(z, (zoom, ...), (camera, ...), (background, ...)), ...]``, computed once for the
    coverage check and the measurement."""
    from warpbw.filtering import zoomed_camera

    frames = []
    for z in zooms:
        zz = tuple(z * FLICKER_STEP ** j for j in range(pairs + 1))
        try:   # the library's "zoom (times the camera's distance ...)" named no option
            cams = tuple(zoomed_camera(scene.camera, x) for x in zz)
        except WarpbwError as exc:
            raise WarpbwError(f"--zoom {z:g}: {exc}") from None
        frames.append((z, zz, cams, tuple(behind(c) for c in cams)))
    return frames


def _check_coverage(scene, frames, device: str, env=None) -> None:
    """Refuse, before the mipmaps are built, a zoom at which no pixel sees a plane (in front of the spheres and
    meshes behind it) in one of its ``frames`` (``_zoom_frames``), or in both frames of one of its flicker pairs: its
    error, flicker and noise would be undefined (a mean over no pixel).  ``env``: the scene's environment, loaded."""
    from warpbw.filtering import prepare_filtering, render_filtering

    # the cheapest method: the coverage is the same for all
    prep = prepare_filtering(scene, ("fixed",), device, env=env)
    for z, zooms, cams, bgs in frames:
        covered = []
        for zz, cam, bg in zip(zooms, cams, bgs):
            try:   # the zoomed camera's own limits (float32 far from the origin) were blamed on the scene alone
                seen = render_filtering(scene, "fixed", prepared=prep, camera=cam, env_spp=1, background=bg)
            except WarpbwError as exc:
                raise WarpbwError(f"--zoom {z:g} (camera distance x {zz:g}): {exc}") from None
            covered.append(seen.coverage)
            if seen.coverage.any():
                continue
            if bg is not None and render_filtering(scene, "fixed", prepared=prep, camera=cam, env_spp=1).coverage.any():
                raise WarpbwError(f"--zoom {z:g}: spheres or meshes hide every pixel of the planes at this zoom "
                                  f"(camera distance x {zz:g}), so error and flicker are undefined there: move them "
                                  "or the camera")
            raise WarpbwError(f"--zoom {z:g}: no pixel sees a plane at this zoom (camera distance x {zz:g}), so "
                              "error and flicker are undefined there: choose "
                              + ("larger zooms (this one moves the camera closer)" if zz < 1.0 else "smaller zooms"))
        for j in range(len(zooms) - 1):   # a plane of a pixel or two can move to the next pixel within a pair
            if not (covered[j] & covered[j + 1]).any():
                raise WarpbwError(f"--zoom {z:g}: no pixel sees a plane in both frames of a flicker pair (camera "
                                  f"distance x {zooms[j]:g} and x {zooms[j + 1]:g}), so the flicker, a mean over those "
                                  "pixels, is undefined there: choose other zooms")


def _check_lit(z: float, zooms, truths) -> None:
    """Refuse a zoom whose ground truth (``truths``, one frame per zoom of ``zooms``) is black at every covered pixel:
    a plane lit from below its horizon, or by nothing, shades black in every method too, and the error, relative to
    the truth's mean, is undefined (it read 0 for every method, as if each matched the truth)."""
    for zz, g in zip(zooms, truths):
        if not np.any(g.image[g.coverage]):
            raise WarpbwError(f"--zoom {z:g}: the ground truth is black at every pixel that sees a plane (camera "
                              f"distance x {zz:g}), so its error and flicker are undefined: no light reaches the "
                              "planes, or they reflect none (check each [[light]]'s direction, towards the light and "
                              "above the planes, the [environment] and the materials)")


def run_bench_filtering(scene, zooms=DEFAULT_ZOOMS, gt_spp: int = DEFAULT_GT_SPP, runs: int = 3, seed: int = 0,
                        device: str = "cpu", cache: Path | None = None, progress: bool = False,
                        log=lambda *a, **k: None, methods=None, env_spp: int | None = None,
                        max_anisotropy: int | None = None, flicker_pairs: int = 1) -> dict:
    """The benchmark record (module docstring) for a scene with planes (beside spheres or meshes or not)."""
    from warpbw.filtering import (DEFAULT_ANISOTROPY, DEFAULT_ENV_SPP, MAX_ANISOTROPY, METHODS, MIN_GT_SPP,
                                  prepare_filtering, render_filtering, scene_environment)
    from warpbw.pipeline import split_planes

    methods = tuple(methods or METHODS)
    cache = check_path(cache, "run_bench_filtering: cache") if cache is not None else None   # pathlib's TypeError
    if not scene.has_planes:
        raise WarpbwError(f"{scene.source}: bench-filtering needs a scene with planes (shape = \"plane\") and "
                          "cook-torrance materials")
    surfaces, scene = split_planes(scene)                 # the spheres and meshes: what the planes hide
    if gt_spp < MIN_GT_SPP:
        raise WarpbwError(f"--gt-spp {gt_spp}: expected at least {MIN_GT_SPP} rays per pixel")
    env_spp = DEFAULT_ENV_SPP if env_spp is None else env_spp
    check_count(env_spp, "--spp (environment pairs per pixel)", 1, INT32_MAX)  # int32 in the kernels
    aniso = DEFAULT_ANISOTROPY if max_anisotropy is None else max_anisotropy
    check_count(aniso, "--max-anisotropy (probes along a footprint's major axis)", 1, MAX_ANISOTROPY)
    check_count(flicker_pairs, "--flicker-pairs (consecutive frame pairs per zoom)", 1, FLICKER_PAIRS_MAX)
    zooms = [float(z) for z in zooms]
    frames_by_zoom = _zoom_frames(scene, zooms, _surfaces_behind(surfaces, device), int(flicker_pairs))
    env = scene_environment(scene, device)   # once: the coverage check and the measured frames share it
    _check_coverage(scene, frames_by_zoom, device, env)
    with temporary_folder(GMM_TEMP_PREFIX) as tmp:   # named after this process: the next run removes it if killed
        t0 = time.perf_counter()
        prep = prepare_filtering(scene, methods + ("ground_truth",), device, progress,
                                 cache=cache if cache is not None else Path(tmp), env=env)
        prep_time = time.perf_counter() - t0
    gmm_time = sum(n.get("gmm_aligned", {}).get("time_s", 0.0) for n in prep.notes.values())
    log(f"precompute: {prep_time:.2f} s (aligned GMM mipmaps {gmm_time:.2f} s)")
    record = {"scene": scene.source, "resolution": [scene.camera.width, scene.camera.height], "zooms": zooms,
              "gt_spp": int(gt_spp), "env_spp": int(env_spp) if scene.environment is not None else None,
              "runs": int(runs), "seed": int(seed), "device": device, "flicker_step": FLICKER_STEP,
              "flicker_pairs": int(flicker_pairs), "max_anisotropy": int(aniso),
              "methods": {m: [] for m in methods}, "ground_truth": [],
              "precompute_time_s": round(gmm_time, 4), "prepare_time_s": round(prep_time, 4),
              "precompute": prep.notes,
              "surfaces": [] if surfaces is None else [o.describe() for o in surfaces.objects]}
    for m in methods:                                     # warm-up: compile every kernel once
        render_filtering(scene, m, prepared=prep, max_anisotropy=aniso)
    for z, zz_all, cams, bgs in frames_by_zoom:
        # the same seed in every frame: the same jitter pattern per pixel, so the truth's frame-to-frame change
        # carries as little of its own noise as possible
        g = [render_filtering(scene, "ground_truth", spp=gt_spp, seed=offset_seed(seed, GT_SEED), prepared=prep,
                              camera=c, background=b) for c, b in zip(cams, bgs)]
        _check_lit(z, zz_all, g)
        g2 = [render_filtering(scene, "ground_truth", spp=gt_spp, seed=offset_seed(seed, GT_SEED_2), prepared=prep,
                               camera=c, background=b) for c, b in zip(cams, bgs)]
        cov = g[0].coverage
        both = [g[j].coverage & g[j + 1].coverage for j in range(len(g) - 1)]
        norms = [_norm(x.image, x.coverage) for x in g[:-1]]   # each pair normalised by its first frame's truth

        def over_pairs(metric, a, ref):
            """``metric`` of the frames ``a`` against ``ref``, mean over the consecutive pairs."""
            return statistics.fmean(metric(a[j].image, a[j + 1].image, ref[j].image, ref[j + 1].image, both[j],
                                           norms[j]) for j in range(len(both)))

        noise = colour_error(g2[0].image, g[0].image, cov) / math.sqrt(2.0)
        # the first truth's change scored against one whose first frame is the second truth's (its own noise)
        gt_flicker = statistics.fmean(flicker(g[j].image, g[j + 1].image, g2[j].image, g[j + 1].image, both[j],
                                              norms[j]) for j in range(len(both)))
        gt_temporal = over_pairs(temporal_error, g2, g)
        record["ground_truth"].append({"zoom": z, "time_s": round(g[0].time_s, 6), "noise": noise,
                                       "flicker_noise": gt_flicker, "temporal_noise": gt_temporal,
                                       "pixels_covered": int(cov.sum())})
        line = [f"zoom {z:g} (error/flicker/temporal error): gt noise {noise:.3f}/{gt_flicker:.4f}/{gt_temporal:.4f}"]
        for m in methods:
            times = []
            for k in range(max(1, runs)):
                r = render_filtering(scene, m, seed=seed, prepared=prep, camera=cams[0], env_spp=env_spp,
                                     max_anisotropy=aniso, background=bgs[0])
                times.append(r.time_s)
            frames = [r] + [render_filtering(scene, m, seed=seed, prepared=prep, camera=c, env_spp=env_spp,
                                             max_anisotropy=aniso, background=b) for c, b in zip(cams[1:], bgs[1:])]
            err = colour_error(frames[0].image, g[0].image, cov)
            fl = over_pairs(flicker, frames, g)
            te = over_pairs(temporal_error, frames, g)
            record["methods"][m].append({"zoom": z, "error": err, "flicker": fl, "temporal_error": te,
                                         "psnr_db": psnr(frames[0].image, g[0].image, cov),
                                         "relmse": relmse(frames[0].image, g[0].image, cov),
                                         "time_s": round(statistics.median(times), 6),
                                         "mean_level": float(frames[0].level[cov].mean()) if cov.any() else 0.0})
            line.append(f"{m} {err:.3f}/{fl:.4f}/{te:.4f}")
        log("  ".join(line))
    return record


def _aniso_note(record: dict) -> str:
    a = record.get("max_anisotropy", 1)
    return f"; anisotropic footprints (up to {a} probes)" if a > 1 else ""


def _precompute_origin(record: dict) -> str:
    """What the precompute time timed where the aligned GMM mipmaps were not all built: read from the cache or the
    scene's gmm files (a second run with --cache printed 0.01 s where the build took 1.9 s), else ''."""
    origins = sorted({n["gmm_aligned"]["origin"] for n in record.get("precompute", {}).values()
                      if "gmm_aligned" in n} - {"built"})
    if not origins:
        return ""
    where = " and ".join({"cache": "the cache", "file": "the scene's gmm file"}.get(o, o) for o in origins)
    return f" (read from {where}, not built)"


def format_table(record: dict) -> str:
    """Error and flicker per method (rows) at each zoom (columns), then the temporal error."""
    zooms = record["zooms"]
    head = f"{'method':<14}" + "".join(f"{'x' + format(z, 'g'):>16}" for z in zooms)
    lines = [f"{record['scene']}  {record['resolution'][0]}x{record['resolution'][1]}, ground truth "
             f"{record['gt_spp']} rays/pixel; error / flicker per zoom{_aniso_note(record)}"
             + (f"; flicker over {record['flicker_pairs']} frame pairs per zoom"
                if record.get("flicker_pairs", 1) > 1 else "")]
    if record.get("surfaces"):
        lines.append("planes measured where no sphere or mesh hides them: " + "; ".join(record["surfaces"]))
    lines.append(head)
    for m, rows in record["methods"].items():
        lines.append(f"{m:<14}" + "".join(f"{r['error']:>9.3f} /{r['flicker']:.3f}" for r in rows))
    lines.append(f"{'gt noise':<14}" + "".join(f"{g['noise']:>9.3f} /{g['flicker_noise']:.3f}"
                                               if "flicker_noise" in g else f"{g['noise']:>9.3f}       "
                                               for g in record["ground_truth"]))
    lines.append("(gt noise: the ground truth's own noise, a second, independently seeded one's error / sqrt(2), and "
                 "the flicker that noise scores; two methods whose flicker differs by less than it are not told "
                 "apart: raise --gt-spp)")
    lines.append("temporal error (distance of the frame-to-frame change to the truth's) per zoom")
    for m, rows in record["methods"].items():
        lines.append(f"{m:<14}" + "".join(f"{r['temporal_error']:>16.4f}" for r in rows))
    lines.append(f"{'gt noise':<14}" + "".join(f"{g['temporal_noise']:>16.4f}" for g in record["ground_truth"]))
    lines.append(f"precompute (aligned GMM mipmaps): {record['precompute_time_s']:.2f} s{_precompute_origin(record)}")
    return "\n".join(lines)


def write_plot(record: dict, path) -> None:
    """Error, flicker and temporal error against zoom, one curve per method; the ground truth's noise (error,
    flicker, temporal error) as a dashed line; and the error against frame time (the protocol's plot), one curve
    per method through its zooms."""
    check_path(path, "write_plot: path")   # before the plot, not from the writer after it
    # a Figure of its own, not pyplot's: the caller's backend (a notebook's inline one) stays as it was (pyplot with
    # matplotlib.use("Agg") replaced it), and nothing holds the figure once it is saved, or once it failed (pyplot
    # kept a failed plot's figure open)
    from matplotlib.figure import Figure

    fig = Figure(figsize=(20, 4.2))
    axes = fig.subplots(1, 4)
    # each curve along the zoom (--zoom comes in any order: 4,1,2 drew 4 -> 1 -> 2), the rows in the zooms' order
    order = sorted(range(len(record["zooms"])), key=record["zooms"].__getitem__)
    zooms = [record["zooms"][i] for i in order]
    gts = [record["ground_truth"][i] for i in order]
    for m, rows in record["methods"].items():
        rows = [rows[i] for i in order]
        axes[3].plot([r["time_s"] * 1e3 for r in rows], [r["error"] for r in rows], "o-", label=m)
        axes[0].plot(zooms, [r["error"] for r in rows], "o-", label=m)
        axes[1].plot(zooms, [r["flicker"] for r in rows], "o-", label=m)
        axes[2].plot(zooms, [r["temporal_error"] for r in rows], "o-", label=m)
    axes[0].plot(zooms, [g["noise"] for g in gts], "k--", label="ground-truth noise")
    axes[2].plot(zooms, [g["temporal_noise"] for g in gts], "k--", label="ground-truth noise")
    if all("flicker_noise" in g for g in gts):
        axes[1].plot(zooms, [g["flicker_noise"] for g in gts], "k--", label="ground-truth noise")
    for ax, what in zip(axes[:3], ("error against the ground truth", "flicker (change beyond the truth's)",
                                   "temporal error (change against the truth's)")):
        ax.set_xscale("log", base=2)
        ax.set_xlabel("zoom (camera distance factor)")
        ax.set_ylabel(what)
        ax.grid(True, which="both", alpha=0.3)
    axes[3].set_xlabel("frame time (ms, kernels; one point per zoom)")
    axes[3].set_ylabel("error against the ground truth")
    axes[3].grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(f"{Path(record['scene']).name}: reflectance filtering (004){_aniso_note(record)}; precompute "
                 f"{record['precompute_time_s']:.1f} s{_precompute_origin(record)}", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
