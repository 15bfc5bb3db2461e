"""Speed against accuracy: the measurement protocol of ../shared/DESIGN.md for ``warpbw bench``.

Public:
    ``GT_CHUNK_SPP``, ``DEFAULT_SPP``, ``DEFAULT_BUDGETS``, ``DEFAULT_GT_SPP``, ``NB_SWEEP_BUDGET``, ``DOUBLING_DB``
    ``GroundTruth`` / ``ground_truth(prep, gt_spp, cache_dir, ...)``   cached, with the doubling check
    ``ground_truth_chunks(gt_spp) -> (spp per chunk, chunks)``, ``gt_spp_refusal(gt_spp)``   how it splits, or why not
    ``GT_VERSION``, ``GT_SEED``, ``gt_key(scene, seed, moved="")``, ``gt_cache_dir()``   where a scene's chunks are
                                       cached (a prepared scene's camera or geometry moved since: apart);
    ``CHUNK_DIGEST_NOTE``   the note in a chunk's file that holds its pixels' digest
    ``equal_quality_time(ref, mse) -> (spp, time_s, extrapolated)``   log-log interpolation (the first crossing);
    ``mse_rises(ref)``   the counts between which a reference curve's MSE rises (noise)
    ``psnr_standard_error(mses)``, ``paired_difference_se(mses_a, mses_b)``   noise of the PSNR figures (dB)
    ``speedup_relative_se(ref, mse, psnr_se_db)``   noise of an equal-quality speed-up (relative)
    ``pass_in_reference_spp(best, ref_recs)``   the bandwidth pass's time in reference samples per pixel
    ``FRAME_STAGES``                  the adaptive frame's stages (name, record key) the table breaks down
    ``run_bench(scene, spp_list, budgets, nb_list, gt_spp, runs, mis, cache_dir, ...) -> dict``
    ``write_plot(record, path)``      error against time, one curve per method (+ the n_b sweep)
    ``format_table(record) -> str``

Protocol:
* Ground truth: the MIS reference at ``gt_spp``, the mean of two or more independently seeded chunks of equal
  size, at most ``GT_CHUNK_SPP`` each, in an even number (any even count up to 8192 splits so, and beyond it a
  multiple of 4096, an odd multiple in chunks of 2048; a count that does not is refused, naming the nearest that
  do), every chunk cached as EXR keyed by the
  scene's content hash, the seed and ``GT_VERSION`` (``gt_key``; so raising ``gt_spp`` renders only the
  missing chunks, and a chunk of another scene, seed or estimator is never read); a chunk whose pixels are not
  those its digest records is rendered again.  Accepted when the PSNR
  of a render at the largest reference spp (whatever the order of ``spp_list``) against half the ground truth and
  against all of it differ by < 0.5 dB (recorded).  The chunks are seeded ``GT_SEED + k GT_SEED_STEP`` whatever
  ``seed`` says, and a ``seed`` whose runs would be seeded as a chunk is (and so draw its samples) is refused.
* Error: PSNR and relative MSE of linear radiance over covered pixels (:mod:`warpbw.metrics`), averaged
  over the ``runs`` frames (MSE and relative MSE as means, PSNR of the mean MSE).  With two runs or more
  every point also records its runs' MSEs and the standard error of its PSNR (``psnr_se_db``), and the
  n_b sweep the standard error of its range (``nb_psnr_range_se_db``): the runs of every n_b share their
  seeds, so the range's noise is that of the paired per-run differences between its two ends (picked after
  the fact, so noise alone widens the range: four equal points spread over about twice their standard
  error).  At a few samples per pixel one run's MSE moves by tens of percent (a firefly), so a PSNR
  difference of a few tenths of a dB between two points of 3 runs each may be noise (the gold bunny's n_b
  sweep, docs/measurements.md: a range of 0.50 +/- 0.33 dB over 3 runs, 0.15 +/- 0.09 dB over 16); the table prints the
  standard errors.
* Time: wall time of a whole frame (G-buffer included; for adaptive also the bandwidth pass) after a
  warm-up frame, median of ``runs`` runs; stage times from the frames' stats.  Where the time goes: the table
  breaks the best budget's frame into its stages (``FRAME_STAGES``, from its last run); an adaptive point's
  ``bandwidth_time_fraction`` is each run's bandwidth pass over that run's wall time, median over the runs; and the
  record's ``bandwidth_pass_reference_spp`` is that frame's bandwidth pass over the reference's shading time per
  sample per pixel (at its largest count): what the pass costs, in the samples it could have paid for.
* Equal-quality speed-up of an adaptive point: the reference's time at the sample count that reaches
  the same MSE, interpolated linearly in (log spp, log MSE) and (log spp, log time) between adjacent measured
  counts, divided by the adaptive time.  On a curve whose MSE rises somewhere (noise, or the ground truth's own noise
  at the largest counts; warned, ``mse_rises``) the count is the first at which the curve falls to that MSE.
  Outside the measured range it is extrapolated along the end segment and flagged ``extrapolated`` (NaN where that
  segment does not fall).  The headline ``equal_quality_speedup`` is the best
  non-extrapolated point of the budget sweep (the operating point a user would pick) among the budgets the frames
  kept (``over_budget`` points, whose shaded pixels' minimum of ``n_min`` samples took more, only where no budget was
  kept: such a point is the frame of a larger budget, timed again, and would be picked for its timing noise); every
  point is in the record.  Its standard error (``equal_quality_speedup_se``, :func:`speedup_relative_se`) carries the
  noise of both curves' errors, not of the times.  The headline, the best of the sweep, is picked after the
  fact, so it leans high where several budgets lie within their standard errors of each other.
* A scene with planes beside spheres or meshes: its spheres and meshes are benchmarked where no plane hides
  them.  The planes are not rendered (``warpbw bench-filtering`` measures the filtering renderer, where no
  sphere or mesh hides the planes), but every frame, the ground truth's included, is clipped at their distances
  (``warpbw.pipeline.render_with_planes`` does the same), so the hidden pixels take no samples and are left
  out of every error; the ground truth is cached under the whole scene's hash.
"""
from __future__ import annotations

import functools
import hashlib
import itertools
import math
import statistics
import sys
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from warpbw.errors import WarpbwError, check_path, offset_seed
from warpbw.io.staged import remove_stale_temps, staged_outputs

GT_CHUNK_SPP = 4096                                   # spp per cached ground-truth chunk
DEFAULT_SPP = (1, 2, 4, 8, 16, 32, 64, 128, 256)      # reference sweep
DEFAULT_BUDGETS = (0.5, 1, 2, 4, 8, 16, 32)           # adaptive sweep, mean samples per covered pixel
DEFAULT_GT_SPP = 8192
# of the cached ground-truth chunks: raise it whenever what render_reference renders changes, its estimator or its
# inputs (3, session 65: the tabulated and GGX pdfs at grazing views, warpbw.sampling.COS_D_EXACT; 4, session 74: a
# mesh's normals along a texture seam, session 73's f916b81, which moved a uv sphere's seam pixels by up to 57%; 5,
# session 81: a mesh's triangles wound against their neighbours turned to match them, and a mesh smaller than 1e-3
# merged at its own scale, warpbw.io.mesh.consistent_winding and MERGE_MIN_COORD: consistently wound meshes of 1e-3
# and more, the benchmark's bunny among them, render as before)
GT_VERSION = 5
CHUNK_DIGEST_NOTE = "rgb_blake2b"   # a chunk file's note (warpbw.io.exr) holding its pixels' digest
GT_SEED, GT_SEED_STEP = 1_000_001, 1_000_002          # ground-truth chunk k is seeded GT_SEED + k * GT_SEED_STEP
DOUBLING_DB = 0.5                                     # ../shared/DESIGN.md: doubling GT spp moves PSNR < 0.5 dB
NB_SWEEP_BUDGET = 8                                   # budget of the n_b sweep unless given
LOG_FLOAT_MAX = math.log(sys.float_info.max)          # beyond it math.exp overflows
DB_PER_LN = 10.0 / math.log(10.0)                     # d(10 log10 m) = DB_PER_LN dm / m
SPEEDUP_SE_STEP = 0.05                                # log-MSE step of the slope d log t_eq / d log MSE


@dataclass
class GroundTruth:
    image: np.ndarray          # (H, W, 3)
    half: np.ndarray           # mean of the first half of the chunks
    spp: int
    chunks: int
    render_time_s: float       # time spent rendering missing chunks in this run
    key: str


def _split(gt_spp: int) -> tuple[int, int]:
    """(spp per chunk, chunks): two chunks up to 2 x GT_CHUNK_SPP, beyond it as many chunks of GT_CHUNK_SPP as fit
    (their product may fall short of gt_spp), an odd number of them as twice as many of half the size: the doubling
    check averages half of the chunks, which must hold half the samples.  Three chunks of 1 spp made --gt-spp 3
    pass, an odd count below 8192 that the help refuses, and its "doubling" check compared 1 spp with 3 (clifuzz
    F10); --gt-spp 12288 was three chunks of 4096, and its check compared 4096 spp with 12288 (session 74)."""
    chunk = min(GT_CHUNK_SPP, max(1, gt_spp // 2))
    if chunk < GT_CHUNK_SPP:
        return chunk, 2
    n = max(2, gt_spp // chunk)
    return (chunk // 2, 2 * n) if n % 2 else (chunk, n)


def gt_spp_refusal(gt_spp: int) -> str | None:
    """Why ``gt_spp`` cannot be the ground truth's count, naming the nearest counts that can; None when it can."""
    chunk, n = _split(gt_spp)
    if chunk * n == gt_spp:
        return None
    above = next(s for s in itertools.count(gt_spp + 1) if math.prod(_split(s)) == s)
    near = sorted({chunk * n, above})
    return (f"the ground truth is the mean of two or more equal chunks of at most {GT_CHUNK_SPP} spp; expected "
            f"{' or '.join(map(str, near))}")


def ground_truth_chunks(gt_spp: int) -> tuple[int, int]:
    """(spp per chunk, number of chunks) of a ground truth of ``gt_spp`` samples per pixel: at least two chunks
    (the doubling check compares half of them with all) of equal size, at most ``GT_CHUNK_SPP``.  A count that does
    not split so is refused, naming the nearest counts that do (it was rounded down without a word: 12000 rendered
    8192)."""
    why = gt_spp_refusal(gt_spp)
    if why is not None:
        raise WarpbwError(f"--gt-spp {gt_spp}: {why}")
    return _split(gt_spp)


def ground_truth(prep, gt_spp: int, cache_dir: Path, seed: int = GT_SEED, progress: bool = True,
                 clip_distance=None, scene=None) -> GroundTruth:
    """MIS reference at ``gt_spp`` as the mean of cached chunks (at least two, for the doubling check),
    clipped at ``clip_distance`` (``render_reference``'s) and cached under ``scene``'s hash (default: the
    prepared scene's; a clipped ground truth must name the scene whose planes clip it).  A prepared scene that no
    longer renders its scene's camera or geometry (a camera set on it, a mesh moved by ``update_mesh``) is cached
    apart, under a hash of its camera and geometry as they are (``gt_key``'s ``moved``)."""
    from warpbw.io.exr import write_exr
    from warpbw.pipeline import render_reference

    cache_dir = check_path(cache_dir, "ground_truth: cache_dir")   # a str failed on str / str, None in pathlib
    chunk, n = ground_truth_chunks(gt_spp)
    key = gt_key(scene if scene is not None else prep.scene, seed, _moved_since_prepared(prep))
    # the chunks' running sum, not the chunks: a list of them held n frames (16 B/px each, cached ones their file's
    # RGBA) and np.mean stacked them again, 28 bytes per pixel per chunk (--gt-spp 65536 at 2048^2: 1.9 GB)
    total, half, t_gt = None, None, 0.0

    def add(img, k):
        nonlocal total, half
        img = np.asarray(img, np.float32)
        if total is None:
            total = img.copy()
        else:   # in float32 and in chunk order: np.mean over the stacked chunks' axis 0 summed so, bit for bit
            total += img
        if k == n // 2 - 1:
            half = total.copy()

    for k in range(n):
        path = cache_dir / f"ground_truth-{key}-chunk{k}-{chunk}spp.exr"
        img = _cached_chunk(path, prep.height, prep.width)
        if img is not None:
            add(img, k)
            continue
        t0 = time.perf_counter()
        img = render_reference(prep, spp=chunk, seed=seed + k * GT_SEED_STEP, mis=True, progress=progress,
                               clip_distance=clip_distance).image
        t_gt += time.perf_counter() - t0
        try:   # an interrupted run leaves no cut-off chunk; two benches of one scene at once both write it
            with staged_outputs([path], force=True) as tmp:   # a cache: the last writer wins
                write_exr(tmp[path], img, notes={CHUNK_DIGEST_NOTE: _pixels_digest(img)})
        except WarpbwError as exc:   # a full disk, a name taken by a folder: the chunk rendered is not lost
            warnings.warn(f"ground truth not cached ({exc}); this bench goes on, and the next renders it again",
                          stacklevel=2)
        add(img, k)
    # np.mean divides its float32 sum by the count as an intp (in float64, rounded back to float32): the same here
    return GroundTruth(np.true_divide(total, np.intp(n), out=total, casting="unsafe"),
                       np.true_divide(half, np.intp(n // 2), out=half, casting="unsafe"), n * chunk, n, t_gt, key)


def gt_cache_dir() -> Path:
    """Where ground-truth chunks are cached unless a folder is given: ``$WARPBW_CACHE/ground_truth``."""
    from precompute.brdf_sampling import cache_dir

    return cache_dir() / "ground_truth"


def gt_key(scene, seed: int, moved: str = "") -> str:
    """The name under which a scene's ground-truth chunks are cached: the hash of what the reference renders
    (``Scene.reference_hash``), the first chunk's seed and GT_VERSION (so that chunks of another estimator or seed are
    never read as this one's); ``moved``, where the prepared scene no longer renders its scene's camera or geometry
    (``_moved_since_prepared``), keys that frame apart."""
    text = f"{scene.reference_hash()}|seed {seed}|gt v{GT_VERSION}" + (f"|moved {moved}" if moved else "")
    h = hashlib.blake2b(text.encode(), digest_size=8)
    return f"v{GT_VERSION}-{h.hexdigest()}"


def _camera_values(cam) -> tuple:
    return (*(tuple(float(x) for x in v) for v in (cam.origin, cam.forward, cam.right, cam.up)),
            float(cam.tan_half_x), float(cam.tan_half_y), int(cam.width), int(cam.height))


def _moved_since_prepared(prep) -> str:
    """"" where ``prep`` renders what its scene says; else a hash of its camera and geometry as they are now: a camera
    set on the prepared scene (``prep.camera = ...``), a mesh deformed by ``update_mesh``.  The ground truth of such a
    frame is cached apart from the scene's (it was cached, and read back by the next frame, as the scene's own: in a
    loop over the frames of an animation, every frame was measured against the first one's truth)."""
    from warpbw.gbuffer import geometry_digest, scene_camera

    camera, geometry = getattr(prep, "camera", None), getattr(prep, "geometry", None)
    if camera is None or geometry is None:   # a stand-in without them (tests)
        return ""
    cam = _camera_values(camera)
    geo = geometry_digest(geometry)
    if cam == _camera_values(scene_camera(prep.scene.camera)) and geo == geometry.digest_built:
        return ""
    return hashlib.blake2b(repr((cam, geo)).encode(), digest_size=8).hexdigest()


def _pixels_digest(rgb: np.ndarray) -> str:
    """blake2b of a chunk's RGB as float32 in C order: what its file's ``CHUNK_DIGEST_NOTE`` records."""
    return hashlib.blake2b(np.ascontiguousarray(rgb, np.float32).tobytes(), digest_size=16).hexdigest()


def _cached_chunk(path: Path, height: int, width: int) -> np.ndarray | None:
    """A cached ground-truth chunk's RGB, or None when it is missing, unreadable, of another size or channels, not
    finite, or not the pixels its digest note records: such a chunk is rendered again (as the table caches rebuild
    a damaged entry).  EXR has no checksum: pixels negated, zeroed or read as another pixel type were averaged into
    the truth, and every reference PSNR fell by 15 dB with only a "raise --gt-spp" hint (file audit, session 63)."""
    from warpbw.io.exr import read_exr

    remove_stale_temps(path)   # a killed writer's, where another bench wrote the chunk whole: none writes it again
    if not path.is_file():
        return None
    try:
        img = read_exr(path)
    except WarpbwError:
        return None
    if img.channels[:3] != ["R", "G", "B"] or img.pixels.shape[:2] != (height, width):
        return None
    rgb = img.pixels[..., :3]
    if not np.isfinite(rgb).all() or img.notes.get(CHUNK_DIGEST_NOTE) != _pixels_digest(rgb):
        return None
    return rgb


def _on_segment(x: float, xs: np.ndarray, ys: np.ndarray, i: int) -> float:
    """y(x) on the line through points i and i + 1 (y_i where the two share an x)."""
    t = (x - xs[i]) / (xs[i + 1] - xs[i]) if xs[i + 1] != xs[i] else 0.0
    return float(ys[i] + t * (ys[i + 1] - ys[i]))


def _interp(x: float, xs: np.ndarray, ys: np.ndarray) -> tuple[float, bool]:
    """Piecewise-linear y(x) through sorted xs, extrapolating along the end segments."""
    if len(xs) == 1:
        return float(ys[0]), True
    i = int(np.clip(np.searchsorted(xs, x) - 1, 0, len(xs) - 2))
    return _on_segment(x, xs, ys, i), bool(x < xs[0] or x > xs[-1])


def equal_quality_time(ref: list, mse: float) -> tuple[float, float, bool]:
    """(spp, time) at which the reference reaches ``mse``, interpolated on log-log between adjacent counts; and
    whether it was extrapolated beyond the measured counts.

    The count is the first at which the curve, followed from its smallest count, falls to ``mse``: on a curve whose
    MSE does not fall at every count (noise, or the ground truth's own noise near the largest counts) the points were
    interpolated in the order of their MSEs, across counts that are not adjacent, and a flat end of 0.12, 0.06, 0.07
    at 8, 16, 32 spp read 0.08 at 22.7 spp instead of 12, unflagged: a speed-up 1.9 times too high.  Below every
    measured MSE it is extrapolated along the last segment, above them all along the first; where that segment does
    not fall, no count is read (NaN, flagged).  ``mse_rises(ref)`` lists where a curve rises."""
    pts = sorted((r["spp"], r["mse"], r["time_s"]) for r in ref if r["mse"] > 0)
    if not pts or not (mse > 0):
        return math.nan, math.nan, True
    ls = np.log([p[0] for p in pts])
    lm = np.log([p[1] for p in pts])
    lt = np.log([p[2] for p in pts])
    if len(pts) == 1:
        return math.exp(ls[0]), math.exp(lt[0]), True
    x = -math.log(mse)   # -log MSE grows with spp: interpolate log spp against it, segment by segment
    xs = -lm
    if x <= xs[0]:
        i, ext = 0, bool(x < xs[0])                           # reached at the first count, or before it
    else:
        crossing = np.flatnonzero((xs[:-1] < x) & (x <= xs[1:]))   # the segments that fall through mse
        i, ext = (int(crossing[0]), False) if crossing.size else (len(xs) - 2, True)
    if ext and not xs[i + 1] > xs[i]:   # an end segment that does not fall reaches no other count
        return math.nan, math.nan, True
    l_spp = _on_segment(x, xs, ls, i)
    l_t, ext_t = _interp(l_spp, ls, lt)
    if max(l_spp, l_t) > LOG_FLOAT_MAX:   # far along a nearly flat end segment: math.exp's OverflowError
        return math.inf, math.inf, True
    return math.exp(l_spp), math.exp(l_t), ext or ext_t


def mse_rises(ref: list) -> list:
    """The (spp, next spp) of the reference's adjacent counts between which its MSE rises: noise, or the ground
    truth's own noise reached (``run_bench`` warns of them; ``equal_quality_time`` reads the first crossing)."""
    pts = sorted((r["spp"], r["mse"]) for r in ref if r["mse"] > 0)
    return [(a[0], b[0]) for a, b in zip(pts, pts[1:]) if b[1] > a[1]]


def psnr_standard_error(mses) -> float | None:
    """Standard error (dB) of the PSNR of the mean of independent runs' MSEs (delta method: the PSNR moves
    by DB_PER_LN dm / m); None with fewer than two runs, or a run's MSE not finite and >= 0 (no MSE is negative:
    [-1, 3] read 8.69 dB)."""
    m = np.asarray(mses, np.float64)
    if m.size < 2 or not (np.all(np.isfinite(m)) and np.all(m >= 0) and m.mean() > 0):
        return None
    return float(DB_PER_LN * m.std(ddof=1) / math.sqrt(m.size) / m.mean())


def paired_difference_se(mses_a, mses_b) -> float | None:
    """Standard error (dB) of the PSNR difference between two settings whose runs share seeds run by run: the
    spread of the per-run differences 10 log10(m_a / m_b) over sqrt(runs).  What the seeds share (the same
    fireflies in both) cancels, unlike the two points' own standard errors combined.  None with fewer than
    two runs, or an MSE not finite and > 0 (an inf gave NaN)."""
    a, b = np.asarray(mses_a, np.float64), np.asarray(mses_b, np.float64)
    if a.shape != b.shape or a.size < 2 or not all(np.all(np.isfinite(x) & (x > 0)) for x in (a, b)):
        return None
    d = 10.0 * np.log10(a / b)
    return float(d.std(ddof=1) / math.sqrt(d.size))


def speedup_relative_se(ref: list, mse: float, psnr_se_db: float | None) -> float | None:
    """Relative standard error of the equal-quality speed-up at ``mse`` from the noise of the errors: the
    adaptive point's (its PSNR's standard error ``psnr_se_db``) and the reference curve's at the equal-quality
    count (its points' standard errors, interpolated in log spp), both carried through the slope of
    log t_eq against log MSE (-1 where the reference's error falls as 1/spp at a time proportional to spp).
    Timing noise is not in it.  None with fewer than two runs or outside a finite curve."""
    if psnr_se_db is None or not (mse > 0) or any(r.get("psnr_se_db") is None for r in ref):
        return None
    h = SPEEDUP_SE_STEP
    _, t_lo, _ = equal_quality_time(ref, mse * math.exp(-h))
    spp, _, _ = equal_quality_time(ref, mse)
    _, t_hi, _ = equal_quality_time(ref, mse * math.exp(h))
    if not all(math.isfinite(x) and x > 0 for x in (t_lo, t_hi, spp)):
        return None
    slope = (math.log(t_hi) - math.log(t_lo)) / (2.0 * h)
    pts = sorted((r["spp"], r["psnr_se_db"]) for r in ref)
    se_ref, _ = _interp(math.log(spp), np.log([q[0] for q in pts]), np.array([q[1] for q in pts]))
    return abs(slope) * math.hypot(psnr_se_db, se_ref) / DB_PER_LN


def _timed(render, runs: int, gt: GroundTruth):
    """Render ``runs`` frames (run r seeded by the caller); the last frame, the median time, the
    errors averaged over the frames: MSE and relative MSE are means over the runs' independent noise,
    PSNR is that of the mean MSE (one frame's error is one draw: at a few samples per pixel a single
    firefly moves it by dB); and each run's (wall time, stage times) for figures that must pair a run's stage
    with that run's time."""
    from warpbw.metrics import mse, relmse

    times, res, mses, rels, stages = [], None, [], [], []
    for r in range(runs):
        t0 = time.perf_counter()
        res = render(r)
        times.append(time.perf_counter() - t0)
        stages.append((times[-1], res.stats.get("time_s", {})))
        mses.append(mse(res.image, gt.image, res.coverage))
        rels.append(relmse(res.image, gt.image, res.coverage))
    m = statistics.fmean(mses)
    peak = float(np.max(gt.image[res.coverage])) if res.coverage.any() else 0.0
    psnr = math.inf if m == 0.0 else (-math.inf if peak <= 0.0 else 10.0 * math.log10(peak * peak / m))
    return res, statistics.median(times), {"psnr_db": psnr, "relmse": statistics.fmean(rels), "mse": m,
                                           "psnr_se_db": psnr_standard_error(mses), "mse_runs": mses}, stages


# run r of a reference count spp is seeded seed + REF_SEED_SPP * spp + r, adaptive run r seed + ADA_SEED_RUN * r (its
# hierarchy's level L adds warpbw.adaptive.LEVEL_SEED_STEP * L)
REF_SEED_SPP, ADA_SEED_RUN = 101, 7


def _seed_refusal(seed: int, spp_list, runs: int, adaptive: bool, levels: int, chunks: int) -> str | None:
    """Why ``seed`` cannot seed the bench's runs: one of them would be seeded as a ground-truth chunk is, and so draw
    that chunk's samples pixel by pixel (the shading seeds pixel i with rand_init(seed, i)), which hides part of its
    error (--seed 998385 read the 16-spp reference's MSE as 1.04e-3 against 1.7-2.1e-3 at seeds 0-3, 2.5 dB high);
    None when none is."""
    from warpbw.adaptive import LEVEL_SEED_STEP

    gt = {GT_SEED + k * GT_SEED_STEP: k for k in range(chunks)}
    for spp in spp_list:
        for r in range(runs):
            s = offset_seed(seed, REF_SEED_SPP * spp + r)
            if s in gt:
                return (f"the reference's run {r} at {spp} spp would be seeded {s}, the seed of the ground truth's "
                        f"chunk {gt[s]}")
    for r in range(runs if adaptive else 0):
        for L in range(levels):
            s = offset_seed(offset_seed(seed, ADA_SEED_RUN * r), LEVEL_SEED_STEP * L)
            if s in gt:
                return (f"the adaptive run {r} would shade its level {L} seeded {s}, the seed of the ground truth's "
                        f"chunk {gt[s]}")
    return None


def run_bench(scene, spp_list=DEFAULT_SPP, budgets=DEFAULT_BUDGETS, nb_list=(), gt_spp: int = DEFAULT_GT_SPP,
              runs: int = 3, mis: bool = True, cache_dir: Path | None = None, nb_budget: float | None = None,
              seed: int = 0, device: str = "cpu", progress: bool = True, log=print,
              adaptive_options: dict | None = None) -> dict:
    """Run the protocol on one scene and return the JSON record (see the module docstring; a scene with planes
    beside spheres or meshes benches the spheres and meshes the planes leave visible).
    ``adaptive_options`` go to every ``render_adaptive`` call (e.g. ``allocation``, ``nyquist``)."""
    from warpbw import pipeline
    from warpbw.pyramid import pyramid_shapes

    if runs < 1:
        raise WarpbwError(f"runs: expected at least 1, got {runs}")
    cache_dir = check_path(cache_dir, "run_bench: cache_dir") if cache_dir is not None else gt_cache_dir()
    _, chunks = ground_truth_chunks(gt_spp)   # before any work
    if not len(spp_list):   # the doubling check renders the largest
        raise WarpbwError("spp_list: expected at least one reference sample count")
    why = _seed_refusal(seed, spp_list, runs, bool(len(budgets) or len(nb_list)),
                        len(pyramid_shapes(scene.camera.width, scene.camera.height)), chunks)
    if why is not None:
        raise WarpbwError(f"seed {seed}: {why}, so it would draw that chunk's samples and its error would read "
                          "low; expected another seed")
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
    t0 = time.perf_counter()
    prep = pipeline.prepare_scene(surfaces, device=device, progress=progress)
    if prep.env is not None and not np.any(prep.env.pixels):   # else a ZeroDivisionError after the ground truth
        raise WarpbwError(f"{scene.source}: [environment] {prep.env.name!r} is black everywhere (after its scale and "
                          "the clamp of negative values): the methods have no light to sample and every error is 0 "
                          "(expected an environment with light in it)")
    # warm-up frames: compile every kernel variant and build the bandwidth tables
    warm = render_reference(prep, spp=1, seed=seed, mis=mis)
    hidden = warm.stats.get("pixels_hidden", 0)
    if not warm.coverage.any():   # else "no pixel is covered by geometry: the error is undefined", after the truth
        raise WarpbwError(f"{scene.source}: no pixel shows a sphere or mesh, so the benchmark's errors are undefined: "
                          + (f"its planes hide all {hidden} pixels they would cover (move them or the camera)" if hidden
                             else "the camera misses them (check [camera] position, look_at and fov)"))
    opts = dict(adaptive_options or {})
    render_adaptive(prep, budget=1.0, seed=seed, mis=mis, progress=progress, **opts)
    t_prep = time.perf_counter() - t0
    log(f"assets and warm-up: {t_prep:.1f} s")
    gt = ground_truth(prep, gt_spp, cache_dir, progress=progress, clip_distance=clip, scene=scene)
    log(f"ground truth: {gt.spp} spp MIS ({gt.chunks} chunks, {gt.render_time_s:.1f} s rendering missing ones)")
    est = "mis" if mis else "brdf_is"
    ref_recs = []
    cov = None
    top = None   # (spp, frame) of the largest count: the doubling check's render (--spp comes in any order)
    for spp in spp_list:
        res, t, err, _ = _timed(lambda r: render_reference(
            prep, spp=spp, seed=offset_seed(seed, REF_SEED_SPP * spp + r), mis=mis), runs, gt)
        cov = res.coverage
        if top is None or spp > top[0]:
            top = (spp, res.image)
        rec = {"spp": int(spp), "time_s": t, **err,
               "shading_time_s": res.stats["time_s"]["shading"], "gbuffer_time_s": res.stats["time_s"]["gbuffer"]}
        ref_recs.append(rec)
        log(f"reference {spp:6d} spp   {t:8.3f} s   PSNR {rec['psnr_db']:6.2f} dB +/- {_se(rec)}   "
            f"relMSE {rec['relmse']:.3e}")
    rises = mse_rises(ref_recs)
    if rises:   # the equal-quality counts then read the first crossing (equal_quality_time); said, not silent
        where = ", ".join(f"{a} to {b}" for a, b in rises)
        warnings.warn(f"{scene.source}: the reference's MSE rises from {where} spp (noise, or the ground truth's own "
                      "noise reached: raise --runs or --gt-spp); each equal-quality count is the first at which its "
                      "curve falls to the adaptive frame's MSE", RuntimeWarning, stacklevel=2)
    # doubling check of the ground truth, with the largest reference render
    from warpbw.metrics import mse as mse_of

    spp, last = top   # the check read the last count given: --spp 16,1 checked the 1-spp frame (0.22 dB, converged,
    # where the 16-spp frame's 0.92 dB is not)
    mse_full, mse_half = mse_of(last, gt.image, cov), mse_of(last, gt.half, cov)
    if mse_full == 0.0 or mse_half == 0.0:   # no noise anywhere: the environment lights nothing the camera sees
        raise WarpbwError(f"{scene.source}: the {spp}-spp reference equals the ground truth exactly, so there is no "
                          "error to measure: the environment's light reaches no pixel the camera sees (expected a "
                          "scene whose visible surfaces the environment lights)")
    d_db = abs(10.0 * math.log10(mse_half / mse_full))
    converged = d_db < DOUBLING_DB
    log(f"ground-truth check: {d_db:.3f} dB ({'converged' if converged else 'NOT converged: raise --gt-spp'})")
    ada_recs = []
    for b in budgets:
        res, t, err, stages = _timed(lambda r: render_adaptive(
            prep, budget=b, seed=offset_seed(seed, ADA_SEED_RUN * r), mis=mis, **opts), runs, gt)
        ts = res.stats["time_s"]
        spp_eq, t_eq, ext = equal_quality_time(ref_recs, err["mse"])
        rec = {"budget": float(b), "time_s": t, **err,
               "bandwidth_time_s": ts["bandwidth"], "shading_time_s": ts["shading"],
               "upsampling_time_s": ts["upsampling"], "hierarchy_time_s": ts["hierarchy"],
               "gbuffer_time_s": ts["gbuffer"], "frame_time_s": ts["frame"],
               **({"lights_time_s": ts["lights"]} if "lights" in ts else {}),
               # each run's pass over that run's wall time, median over the runs: the last run's pass over the
               # median time read 2.0 where every frame's share was 0.1 and the last run took 20 times as long
               "bandwidth_time_fraction": statistics.median(s["bandwidth"] / w if w > 0 else 0.0 for w, s in stages),
               "shaded_fraction": res.stats["shaded_fraction"], "samples": res.stats["samples"],
               "samples_per_covered_pixel": res.stats["samples_per_covered_pixel"],
               "over_budget": res.stats["allocation"]["over_budget"],
               "equal_quality_spp": spp_eq, "equal_quality_reference_time_s": t_eq,
               "equal_quality_speedup": t_eq / t if t > 0 else math.nan, "extrapolated": ext}
        rel = speedup_relative_se(ref_recs, err["mse"], err["psnr_se_db"])
        rec["equal_quality_speedup_se"] = rel * rec["equal_quality_speedup"] if rel is not None else None
        ada_recs.append(rec)
        log(f"adaptive  {b:6g} spp   {t:8.3f} s   PSNR {rec['psnr_db']:6.2f} dB +/- {_se(rec)}   "
            f"relMSE {rec['relmse']:.3e}   "
            f"shaded {100 * rec['shaded_fraction']:5.1f}%   bandwidth {100 * rec['bandwidth_time_fraction']:4.1f}%   "
            f"speed-up {rec['equal_quality_speedup']:.2f}x +/- {_se(rec, 'equal_quality_speedup_se')}"
            f"{' (extrapolated)' if ext else ''}")
    nb_recs = []
    nbb = NB_SWEEP_BUDGET if nb_budget is None else nb_budget
    for n_b in nb_list:
        res, t, err, _ = _timed(lambda r: render_adaptive(
            prep, budget=nbb, seed=offset_seed(seed, ADA_SEED_RUN * r), mis=mis, n_b=int(n_b), **opts), runs, gt)
        rec = {"n_b": int(n_b), "budget": float(nbb), "time_s": t, **err,
               "bandwidth_time_s": res.stats["time_s"]["bandwidth"], "shaded_fraction": res.stats["shaded_fraction"]}
        nb_recs.append(rec)
        log(f"n_b {n_b:5d} (budget {nbb:g})   {t:8.3f} s   PSNR {rec['psnr_db']:6.2f} dB +/- {_se(rec)}   "
            f"bandwidth {rec['bandwidth_time_s'] * 1e3:.1f} ms")
    valid = [r for r in ada_recs if not r["extrapolated"] and math.isfinite(r["equal_quality_speedup"])]
    kept = [r for r in valid if not r["over_budget"]] or valid   # module docstring
    best = max(kept, key=lambda r: r["equal_quality_speedup"]) if kept else None
    record = {
        "scene": str(scene.source),
        "scene_hash": scene.content_hash()[:16],
        "ground_truth_key": gt.key,
        "resolution": [prep.width, prep.height],
        "pixels_covered": int(cov.sum()) if cov is not None else 0,
        "materials": {n: prep.scene.materials[n].type for n in prep.scene.material_order},
        "environment": prep.env.name,
        "estimator": est,
        "adaptive_options": opts,
        "runs": int(runs),
        "seed": int(seed),   # the methods' runs (the ground truth's is GT_SEED, whatever --seed says)
        "device": device,
        "ground_truth_spp": gt.spp,
        "ground_truth_doubling_delta_db": d_db,
        "ground_truth_converged": converged,
        "methods": {"reference": ref_recs, "adaptive": ada_recs},
        "equal_quality_speedup": best["equal_quality_speedup"] if best else None,
        "equal_quality_speedup_se": best["equal_quality_speedup_se"] if best else None,
        "equal_quality_budget": best["budget"] if best else None,
        "bandwidth_time_fraction": (best["bandwidth_time_fraction"] if best
                                    else statistics.median(r["bandwidth_time_fraction"] for r in ada_recs)
                                    if ada_recs else None),
        "asset_and_warmup_time_s": t_prep,
        "bandwidth_pass_reference_spp": pass_in_reference_spp(best, ref_recs),
    }
    if planes is not None:
        record["planes"] = {"objects": len(planes.objects), "pixels_hidden": int(hidden),
                            "rendered": False,
                            "note": "spheres and meshes benched where no plane hides them; the planes are not "
                                    "rendered (bench-filtering measures them where no sphere or mesh hides them)"}
    if nb_recs:
        ps = [r["psnr_db"] for r in nb_recs]
        hi, lo = nb_recs[int(np.argmax(ps))], nb_recs[int(np.argmin(ps))]
        record["nb_sweep"] = nb_recs
        record["nb_psnr_range_db"] = max(ps) - min(ps)
        record["nb_psnr_range_se_db"] = paired_difference_se(lo["mse_runs"], hi["mse_runs"])
    return record


def _se(rec: dict, key: str = "psnr_se_db") -> str:
    """A standard error of the record (default: its PSNR's, dB), or '-' (one run)."""
    se = rec.get(key)
    return f"{se:.2f}" if se is not None else "-"


# the adaptive frame's stages, as the table names them, and their record keys (directional lights only in
# scenes that have them)
FRAME_STAGES = (("G-buffer", "gbuffer_time_s"), ("bandwidth pass", "bandwidth_time_s"),
                ("shading", "shading_time_s"), ("directional lights", "lights_time_s"),
                ("hierarchy", "hierarchy_time_s"), ("up-sampling", "upsampling_time_s"))


def pass_in_reference_spp(best: dict | None, ref_recs: list) -> float | None:
    """The bandwidth pass's time at ``best`` (an adaptive record) in units of the reference's shading time per
    sample per pixel, read at the reference's largest sample count (where fixed costs weigh least); None without
    either."""
    if best is None or not ref_recs:
        return None
    top = max(ref_recs, key=lambda r: r["spp"])
    if not top["spp"] > 0:   # a ZeroDivisionError
        return None
    per_spp = top["shading_time_s"] / top["spp"]
    return best["bandwidth_time_s"] / per_spp if per_spp > 0 else None


def format_table(record: dict) -> str:
    lines = [f"{record['scene']}  {record['resolution'][0]}x{record['resolution'][1]}, "
             f"{record['pixels_covered']} covered pixels, estimator {record['estimator']}, "
             f"ground truth {record['ground_truth_spp']} spp "
             f"(doubling {record['ground_truth_doubling_delta_db']:.2f} dB)"]
    if "planes" in record:
        lines.append(f"spheres and meshes only: {record['planes']['pixels_hidden']} pixels hidden by "
                     f"{record['planes']['objects']} plane(s) left out; the planes are not rendered (bench-filtering)")
    lines.append(f"{'method':10s} {'spp/budget':>10s} {'time (s)':>9s} {'PSNR':>7s} {'+/-':>5s} {'relMSE':>10s} "
                 f"{'shaded':>7s} {'bw %':>5s} {'speed-up':>9s} {'+/-':>5s}")
    for r in record["methods"]["reference"]:
        lines.append(f"{'reference':10s} {r['spp']:10d} {r['time_s']:9.3f} {r['psnr_db']:7.2f} {_se(r):>5s} "
                     f"{r['relmse']:10.3e}")
    for r in record["methods"]["adaptive"]:
        lines.append(f"{'adaptive':10s} {r['budget']:9g}{'!' if r.get('over_budget') else ' '} {r['time_s']:9.3f} "
                     f"{r['psnr_db']:7.2f} {_se(r):>5s} "
                     f"{r['relmse']:10.3e} "
                     f"{100 * r['shaded_fraction']:6.1f}% {100 * r['bandwidth_time_fraction']:5.1f} "
                     f"{r['equal_quality_speedup']:8.2f}x {_se(r, 'equal_quality_speedup_se'):>5s}"
                     f"{'*' if r['extrapolated'] else ''}")
    s = record["equal_quality_speedup"]
    best = next((r for r in record["methods"]["adaptive"] if r["budget"] == record.get("equal_quality_budget")), None)
    over = (f" (over budget: {best['samples_per_covered_pixel']:.2f} samples per covered pixel)"
            if best is not None and best.get("over_budget") else "")
    lines.append(f"equal-quality speed-up: {s:.2f}x +/- {_se(record, 'equal_quality_speedup_se')} at budget "
                 f"{record['equal_quality_budget']:g}{over}" if s is not None
                 else "equal-quality speed-up: none within the measured reference range")
    if record.get("bandwidth_time_fraction") is not None:
        lines.append(f"bandwidth pass: {100 * record['bandwidth_time_fraction']:.1f}% of the frame")
    if best is not None:
        lines.append(f"where the frame's time goes at budget {best['budget']:g} (its last run): "
                     + ", ".join(f"{name} {1e3 * best[key]:.0f} ms" for name, key in FRAME_STAGES if key in best))
        spp = record.get("bandwidth_pass_reference_spp")
        if spp is not None:
            lines.append(f"the bandwidth pass costs what the reference's shading spends on {spp:.1f} samples per "
                         "pixel")
    for r in record.get("nb_sweep", []):
        lines.append(f"n_b {r['n_b']:5d}: PSNR {r['psnr_db']:.2f} +/- {_se(r)} dB, {r['time_s']:.3f} s, "
                     f"bandwidth {r['bandwidth_time_s'] * 1e3:.1f} ms")
    if "nb_psnr_range_db" in record:
        se = record.get("nb_psnr_range_se_db")
        lines.append(f"n_b sweep: PSNR range {record['nb_psnr_range_db']:.2f} dB"
                     + (f" (standard error {se:.2f} dB over {record['runs']} paired runs)" if se is not None else ""))
    lines.append("(+/-: standard errors over the runs, of the PSNR in dB and of the speed-up from the errors' noise; "
                 "* extrapolated beyond the measured reference counts"
                 + ("; ! over budget: n_min samples per shaded pixel took more, and the headline skips it where "
                    "another budget was kept" if any(r.get("over_budget") for r in record["methods"]["adaptive"])
                    else "")
                 + ")")
    return "\n".join(lines)


def write_plot(record: dict, path) -> None:
    """PSNR against frame time (one curve per method), and the n_b sweep when present; error bars of one standard
    error where the record has them (two runs or more)."""
    check_path(path, "write_plot: path")   # before the plot, not from the writer after it
    # a Figure of its own, not pyplot's: the caller's backend (a notebook's inline one) stays as it was (pyplot with
    # matplotlib.use("Agg") replaced it), and nothing holds the figure once it is saved, or once it failed (pyplot
    # kept a failed plot's figure open)
    from matplotlib.figure import Figure

    has_nb = bool(record.get("nb_sweep"))
    fig = Figure(figsize=(11 if has_nb else 6, 4.2))
    axes = fig.subplots(1, 2 if has_nb else 1, squeeze=False)
    ax = axes[0][0]
    # each curve in the order of its counts (--spp, --budgets and --nb come in any order: 16,1,4 drew 16 -> 1 -> 4)
    ref = sorted(record["methods"]["reference"], key=lambda r: r["spp"])
    ada = sorted(record["methods"]["adaptive"], key=lambda r: r["budget"])
    for recs, fmt, label in ((ref, "o-", f"reference ({record['estimator']})"), (ada, "s-", "adaptive (002)")):
        ax.errorbar([r["time_s"] for r in recs], [r["psnr_db"] for r in recs], fmt=fmt, label=label, capsize=3,
                    yerr=[r.get("psnr_se_db") or 0.0 for r in recs])
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
    se = record.get("equal_quality_speedup_se")
    ax.set_title(f"equal-quality speed-up {s:.1f}x" + (f" \u00b1 {se:.1f}" if se is not None else "") if s is not None
                 else "speed against accuracy", fontsize=10)
    if has_nb:
        ax2 = axes[0][1]
        nb = sorted(record["nb_sweep"], key=lambda r: r["n_b"])
        ax2.errorbar([r["n_b"] for r in nb], [r["psnr_db"] for r in nb], fmt="o-", color="C2", label="PSNR",
                     yerr=[r.get("psnr_se_db") or 0.0 for r in nb], capsize=3)
        ax2.set_xscale("log")
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
