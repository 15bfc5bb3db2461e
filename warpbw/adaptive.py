"""Hierarchical adaptive shading (002 Sec. 3.2, Fig. 8): shade coarse to fine, up-sample the rest.

Public:
    ``HierarchyPlan`` / ``plan_hierarchy(gb, cam, level_map, device)``   which texels each level shades and
                               up-samples, from the levels and the G-buffer alone (before any sample is drawn)
    ``AdaptiveResult`` / ``shade_hierarchical(gb, cam, materials, env_data, level_map, spp_map, ..., plan, progress)``
    ``load_kernels(device)``   compile (or load from Warp's cache) the hierarchy's own kernels:
                               ``classify_level_kernel``, ``gather_shaded_kernel``, ``level_spp_kernel``
    ``PlanLevel``              one level of a ``HierarchyPlan``

Inputs are the per-pixel shading level (002 Eq. 11, 0 = finest; see :mod:`warpbw.pyramid`) and the
per-pixel sample count N_p.  The level is mip-mapped with a min filter and N_p with a max filter
(Sec. 3.1).  From the coarsest level down to 0, a texel of level L whose min-filtered level m is

* m == L: is shaded, at the finest pixel at the centre of its footprint (depth and normal are always
  read at the finest level), with the max-filtered N_p of its footprint;
* m > L:  is up-sampled from its already computed parents at level L + 1 (:mod:`warpbw.upsample`: the paper's
  weights, fitting a plane in the normal unless ``upsample="paper"``); when no parent can be used (a depth
  edge, an empty parent) it is shaded instead, never guessed;
* m < L:  is left for finer levels (some pixel under it needs more resolution).

A texel whose centre pixel is empty is left for finer levels too, and so, above level 0, is one whose centre pixel's
shading normal faces away from the eye (normals interpolated across a mesh's silhouette): the estimator gives that
pixel no radiance (:mod:`warpbw.shading`), and shaded there the texel stood for its whole footprint with 0 and
darkened the pixels up-sampled from it (a Lambert torus of 20 x 10 quads under a constant sky at 96 x 72: 391 of
its 4,387 front-facing pixels below the albedo, 9 of them under a seventh of it; session 77).  No texel of the
benchmark's scenes was such a one (examples/bench_scenes.py, 8 seeds).

Level 0 then holds every covered pixel.  ``AdaptiveResult.stats`` counts pixels shaded and up-sampled
per level and the samples spent.

Which texels are shaded does not depend on what the shading returns: a parent can be used when it was shaded
or up-sampled, and the up-sampling's weights read only depth, normal, view and those flags.  So
:func:`plan_hierarchy` settles every level's texels first, with the weighted-mean up-sampling run on zeros, and
the budget can be spread over exactly the texels that will be shaded, those the up-sampling cannot fill included
(``warpbw.bandwidth.allocate_samples``'s ``plan``).  Before session 39 the allocation counted only the texels
whose min-filtered level is their own (and, wrongly, those whose centre pixel is empty), and the others were
shaded at their footprint's N_p on top of the budget: 0.1-2.4% more samples on the benchmark's scenes at their
budgets (docs/measurements.md),
and 4.5x the budget under a constant environment (tests/test_extremes.py), where the plan was
one texel.

The hierarchy shades and up-samples the environment's part of the image only.  Directional lights
(:mod:`warpbw.lights`) are exact and cost one BRDF evaluation per light, less than one sample: their term
E rho cos is added at every covered pixel of level 0 after the up-sampling, never interpolated.  Measured
with ``warpbw bench`` on the ccp3 sphere under forest.exr with a sun (radiance 3, MIS, budgets 1-16, against
a 4096-spp ground truth): up-sampling the sun's highlight with the rest held PSNR at 46.0-49.2 dB (speed-up
2.9x); adding it after the up-sampling gives 47.7-57.1 dB (7.3x).  A scene without an environment has
nothing to adapt and is refused.

Measured, not adopted (session 31, with a scratch patch; the gold bunny of examples/bench_scenes.py, MIS, 4 runs,
against its cached 8192-spp ground truth):

* Folding the bandwidth pass's own directions into the shading.  The pass's n_b one-sample MIS directions at a
  traced pixel estimate L_p (with the full-resolution radiance instead of the pass's reduced table), worth
  about n_b / 2 of this module's two-sample MIS steps; a shaded pixel that the pass traced averaged the two
  by their sample counts (with each block's traced pixel moved to the level-1 representative, so that every
  level-1 texel had one).  N_p comes from the same directions, so the blend is not strictly unbiased; the
  PSNRs include whatever bias that left.  Budgets 1 / 2 / 4 / 8 gained 1.34 / 0.56 / 0.24 / 0.21 dB and the
  pass's time did not move, but the best speed-up stayed where it was (3.10x against 3.09x, budget 4):
  there the error is mostly the up-sampling's bias, which no extra sample at a shaded pixel reaches.
* Refining a posteriori (session 32).  An up-sampled texel at level 0 or 1 whose parents in use spread in
  luminance by more than 1.2 times their mean (max - min) was shaded instead, with its footprint's N_p.  Over
  8 runs, back to back with the baseline, budgets 2 / 4 / 8 read 36.82 / 38.52 / 39.22 dB against 36.62 /
  38.20 / 38.85, with 27.6% of the pixels shaded at budget 4 instead of 24.7%; the best speed-up was 3.35x
  +/- 0.26 against 3.25x +/- 0.23 (budget 4).  The patch measured the spread in numpy, which added 20 ms to
  the hierarchy's 15; a kernel would win back most of that, about 5% of the frame, still within the noise.
  The parents' own noise trips a lower threshold (0.8 at level 0 alone: 33% shaded, 3.07x against 3.10x over
  4 runs), and a ridge thinner than the parents' spacing can fall between them and leave no trace.
* Allocating by each pixel's true variance (session 35, ``/work/bench/s35/oracle_e2e.py``): N_p from a
  brute-force v_p (Neyman's on the pixels the frame shades, with the same levels and samples) gains 1.09 / 0.63 /
  0.36 dB on the gold bunny at budgets 2 / 4 / 8 (4 runs), the most an a-posteriori estimate of the variance could
  give.  Offline, 4 pilot samples per shaded pixel blended with the pass's variance reach about a third of that
  in dB (docs/measurements.md, "How much any allocation could do"), so a two-stage allocation was not built.
"""
from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import warp as wp

from warpbw.brdf import MaterialBuffers
from warpbw.envmap import EnvMapData
from warpbw.errors import INT32_MAX, WarpbwError, check_device, check_instance, check_seed, offset_seed
from warpbw.gbuffer import CameraData, GBuffer, GBufferData, check_camera_of
from warpbw.lights import Lights
from warpbw.pyramid import build_pyramid, max_level
from warpbw.shading import shade_reference
from warpbw.upsample import (UPSAMPLE_DEFAULT, check_upsample_mode, level_size, representative_pixel,
                             upsample_level)

MODE_SKIP = 0
MODE_SHADE = 1
MODE_UPSAMPLE = 2
LEVEL_SEED_STEP = 7919   # level L is shaded with seed + LEVEL_SEED_STEP L (warpbw.bench keeps its runs off the
# ground truth's seeds with it)


@wp.kernel(module="unique", enable_backward=False)
def classify_level_kernel(gb: GBufferData, level: int, width: int, min_level: wp.array2d(dtype=wp.int32),
                          mode: wp.array(dtype=wp.int32), rep: wp.array(dtype=wp.int32)):
    """Per texel of level L: shade (m == L), up-sample (m > L) or skip (m < L, or no geometry, or above level 0 a
    representative pixel whose shading normal faces away from the eye)."""
    t = wp.tid()
    x = t % width
    y = t // width
    r = representative_pixel(gb, x, y, level)
    rep[t] = r
    m = min_level[y, x]
    if gb.material[r] < 0:
        mode[t] = MODE_SKIP
    elif level > 0 and wp.dot(gb.normal[r], gb.view[r]) <= 0.0:
        mode[t] = MODE_SKIP
    elif m == level:
        mode[t] = MODE_SHADE
    elif m > level:
        mode[t] = MODE_UPSAMPLE
    else:
        mode[t] = MODE_SKIP


@wp.kernel(module="unique", enable_backward=False)
def gather_shaded_kernel(pixels: wp.array(dtype=wp.int32), texels: wp.array(dtype=wp.int32),
                         shaded: wp.array(dtype=wp.vec3), values: wp.array(dtype=wp.vec3),
                         valid: wp.array(dtype=wp.int32)):
    """Copy the radiance shaded at finest pixel ``pixels[t]`` into level texel ``texels[t]``."""
    t = wp.tid()
    values[texels[t]] = shaded[pixels[t]]
    valid[texels[t]] = 1


@wp.kernel(module="unique", enable_backward=False)
def level_spp_kernel(rep: wp.array(dtype=wp.int32), width: int, max_spp: wp.array2d(dtype=wp.int32),
                     texels: wp.array(dtype=wp.int32), spp_at_pixel: wp.array(dtype=wp.int32)):
    """N_p of a shaded texel: the max-filtered sample count of its footprint, at its shading pixel."""
    t = wp.tid()
    q = texels[t]
    spp_at_pixel[rep[q]] = max_spp[q // width, q % width]


def load_kernels(device: str = "cpu") -> None:
    """Load the classification, gather, up-sampling and pyramid kernels (the shading kernel is the
    reference estimator's, see :func:`warpbw.shading.make_reference_kernel`)."""
    check_device(device)
    from warpbw import pyramid, upsample

    for k in (classify_level_kernel, gather_shaded_kernel, level_spp_kernel, upsample.upsample_level_kernel,
              pyramid.image_level_kernel):
        wp.load_module(k.module, device=device)


@dataclass
class AdaptiveResult:
    image: np.ndarray            # (H, W, 3) radiance, 0 where no geometry
    shaded: np.ndarray           # (H, W) bool: finest pixels that were shaded (at any level)
    shaded_level: np.ndarray     # (H, W) int: finest level at which the pixel was shaded, -1 if up-sampled/empty
    spp: np.ndarray              # (H, W) int32: samples taken at the pixel (its texel's N_p, summed over the levels
                                 # that shaded it; 0 if up-sampled/empty): sums to stats["samples"], but for a pixel
                                 # past INT32_MAX, clipped there (only an n_max near 2^31 at two levels or more)
    stats: dict = field(default_factory=dict)


@dataclass
class PlanLevel:
    level: int
    size: tuple                  # (w, h) of the level
    rep: wp.array                # (w h,) int32: the finest pixel that represents each texel
    shade: np.ndarray            # texel indices shaded at this level (sorted)
    upsample: np.ndarray         # texel indices up-sampled from the level above (sorted)
    weights: wp.array | None = None   # (w h,) vec4: the w_i of the up-sampled texels (warpbw.upsample)


@dataclass
class HierarchyPlan:
    """What :func:`shade_hierarchical` will do with ``level_map``, coarsest level first (module docstring)."""
    width: int
    height: int
    level_map: np.ndarray        # (H, W) int32: the levels the plan was made for
    levels: list                 # PlanLevel per level, coarsest first

    def shade_masks(self) -> list:
        """Per level, finest first: (h_L, w_L) bool, the texels shaded at that level."""
        out = []
        for pl in reversed(self.levels):
            w, h = pl.size
            m = np.zeros(w * h, bool)
            m[pl.shade] = True
            out.append(m.reshape(h, w))
        return out

    @property
    def shaded_texels(self) -> int:
        return int(sum(len(pl.shade) for pl in self.levels))


def _int_map(a, h, w, name, lo: int, hi: int):
    """An (h, w) int32 map of integers in lo..hi, else a WarpbwError naming ``name`` (a level beyond the top was
    accepted and dimmed the image; a negative or NaN level failed inside the hierarchy; an spp of 2^31 - 1 ran for
    hours)."""
    a = np.asarray(a.numpy() if isinstance(a, wp.array) else a)
    if a.shape not in ((h, w), (h * w,)):   # a transposed (w, h) map was taken and scrambled the levels
        raise WarpbwError(f"{name}: expected an (height, width) = ({h}, {w}) map (or {h * w} values, row-major), got "
                          f"shape {a.shape}")
    if a.dtype.kind not in "iuf" or not (np.all(np.isfinite(a)) and np.all(a == np.round(a))
                                         and a.min() >= lo and a.max() <= hi):
        raise WarpbwError(f"{name}: expected integers from {lo} to {hi}, got {a.dtype} values"
                          + (f" from {a.min()} to {a.max()}" if a.dtype.kind in "iuf" else ""))
    return np.ascontiguousarray(a.reshape(h, w).astype(np.int32))


def _classify(gb: GBuffer, levels, L: int, device: str):
    w, h = level_size(gb.width, gb.height, L)
    mode = wp.zeros(w * h, dtype=wp.int32, device=device)
    rep = wp.zeros(w * h, dtype=wp.int32, device=device)
    wp.launch(classify_level_kernel, dim=w * h, inputs=[gb.data, L, w, levels.levels[L], mode, rep], device=device)
    return (w, h), mode.numpy(), rep


def plan_hierarchy(gb: GBuffer, cam: CameraData, level_map, device: str = "cpu") -> HierarchyPlan:
    """The texels each level will shade and up-sample for ``level_map`` (module docstring): classify each level,
    then run the up-sampling's weights on zeros to find the texels no parent can fill, which are shaded too.  The
    weights are kept for the up-sampling itself, which then reads them instead of computing them again."""
    check_instance(gb, GBuffer, "plan_hierarchy: gb", "a GBuffer (render_gbuffer's)")
    check_camera_of(cam, gb, "plan_hierarchy")
    W, H = gb.width, gb.height
    level = _int_map(level_map, H, W, "level_map", 0, max_level(W, H))
    levels = build_pyramid(level, op="min", device=device)
    cov = gb.coverage
    top = min(int(level[cov].max()) if cov.any() else 0, levels.num_levels - 1)
    out = []
    parent_valid = None
    for L in range(top, -1, -1):
        (w, h), mode_np, rep = _classify(gb, levels, L, device)
        up = np.flatnonzero(mode_np == MODE_UPSAMPLE)
        shade = np.flatnonzero(mode_np == MODE_SHADE)
        weights = None
        if parent_valid is None:
            shade, up = np.union1d(shade, up), up[:0]   # the coarsest level has no parents: shade it all
        elif len(up):
            todo = np.zeros(w * h, np.int32)
            todo[up] = 1
            pw, ph = level_size(W, H, L + 1)
            r = upsample_level(gb.data, cam, L, np.zeros((pw * ph, 3), np.float32), parent_valid, todo,
                               device=device, mode="paper")
            need = r.needs_shading.numpy()[up] != 0
            shade, up, weights = np.union1d(shade, up[need]), up[~need], r.weights
        valid = np.zeros(w * h, np.int32)
        valid[shade] = 1
        valid[up] = 1
        parent_valid = wp.array(valid, dtype=wp.int32, device=device)
        out.append(PlanLevel(L, (w, h), rep, shade, up, weights))
    return HierarchyPlan(W, H, level, out)


def shade_hierarchical(gb: GBuffer, cam: CameraData, materials: MaterialBuffers, env_data: EnvMapData,
                       level_map, spp_map, seed: int = 0, mis: bool = False, device: str = "cpu",
                       threads: int | None = None, lights: Lights | None = None,
                       upsample: str = UPSAMPLE_DEFAULT, plan: HierarchyPlan | None = None,
                       progress: Callable[[int], None] | None = None) -> AdaptiveResult:
    """Coarse-to-fine shading of the covered pixels with per-pixel levels and sample counts; ``lights``
    (directional, or None) are then added exactly at every covered pixel (module docstring).  ``upsample``:
    "normal" or "paper" (:mod:`warpbw.upsample`).  ``plan``: :func:`plan_hierarchy`'s for ``level_map``
    (made here when None).  ``progress(count)`` is called as the shaded pixels' tiles finish, over all levels
    (``plan.shaded_texels`` in all)."""
    check_device(device)
    check_upsample_mode(upsample)
    check_instance(gb, GBuffer, "shade_hierarchical: gb", "a GBuffer (render_gbuffer's)")
    check_camera_of(cam, gb, "shade_hierarchical")
    seed = check_seed(seed, "shade_hierarchical: seed")   # 2**32 shaded seed 0's frame
    if plan is not None:
        check_instance(plan, HierarchyPlan, "shade_hierarchical: plan", "a HierarchyPlan (plan_hierarchy's) or None")
    if env_data is None:
        raise WarpbwError("adaptive shading: the scene has no environment to adapt to (directional lights alone "
                          "are exact at any spp: use the reference renderer)")
    W, H = gb.width, gb.height
    level = _int_map(level_map, H, W, "level_map", 0, max_level(W, H))
    if plan is None:
        plan = plan_hierarchy(gb, cam, level, device=device)
    elif (plan.width, plan.height) != (W, H) or not np.array_equal(plan.level_map, level):
        raise WarpbwError("plan: made for another level map")
    spp = _int_map(spp_map, H, W, "spp_map", 0, INT32_MAX)
    spps = build_pyramid(spp, op="max", device=device)
    cov = gb.coverage
    shaded_full = wp.zeros(W * H, dtype=wp.vec3, device=device)
    spp_at_pixel = wp.zeros(W * H, dtype=wp.int32, device=device)
    # samples taken per pixel over all levels: a texel's representative pixel may be shaded again at a finer level
    # (no parent at its depth there), and spp_at_pixel holds only the last level's N_p
    spp_taken = np.zeros(W * H, np.int64)
    shaded_level = np.full(W * H, -1, np.int32)   # int32, as the level map
    per_level = []
    samples = 0
    non_finite = 0
    unplanned = 0
    t_shade = t_up = 0.0
    parent_vals = parent_valid = None
    for pl in plan.levels:
        L, (w, h), rep = pl.level, pl.size, pl.rep
        vals = wp.zeros(w * h, dtype=wp.vec3, device=device)
        valid = wp.zeros(w * h, dtype=wp.int32, device=device)
        to_shade = pl.shade
        n_up = len(pl.upsample)
        if n_up:
            t0 = time.perf_counter()
            todo = np.zeros(w * h, np.int32)
            todo[pl.upsample] = 1
            r = upsample_level(gb.data, cam, L, parent_vals, parent_valid, todo, out=vals, out_valid=valid,
                               device=device, mode=upsample, weights=pl.weights)
            t_up += time.perf_counter() - t0
            need = np.flatnonzero(r.needs_shading.numpy())
            if len(need):   # the plan read the same weights, so never; shaded rather than left empty
                unplanned += len(need)
                n_up -= len(need)
                to_shade = np.union1d(to_shade, need)
        n_shaded = len(to_shade)
        if n_shaded:
            t0 = time.perf_counter()
            texels = wp.array(to_shade.astype(np.int32), dtype=wp.int32, device=device)
            pix_np = rep.numpy()[to_shade]   # the texels' representative pixels: one texel per pixel a level
            pix = wp.array(pix_np.astype(np.int32), dtype=wp.int32, device=device)
            wp.launch(level_spp_kernel, dim=n_shaded, inputs=[rep, w, spps.levels[L], texels, spp_at_pixel],
                      device=device)
            res = shade_reference(gb, materials, env_data, spp_at_pixel, seed=offset_seed(seed, LEVEL_SEED_STEP * L),
                                  mis=mis, device=device, threads=threads, pixels=pix, out=shaded_full,
                                  progress=progress)
            samples += res.samples
            non_finite += res.non_finite
            wp.launch(gather_shaded_kernel, dim=n_shaded, inputs=[pix, texels, shaded_full, vals, valid],
                      device=device)
            shaded_level[pix_np] = L
            spp_taken[pix_np] += spp_at_pixel.numpy()[pix_np]
            t_shade += time.perf_counter() - t0
        per_level.append({"level": L, "size": [w, h], "shaded": n_shaded, "upsampled": n_up})
        parent_vals, parent_valid = vals, valid
    image = parent_vals.numpy().reshape(H, W, 3) * cov[..., None]
    t_lights = 0.0
    if lights is not None:
        t0 = time.perf_counter()
        direct = shade_reference(gb, materials, None, 0, mis=mis, device=device, threads=threads, lights=lights)
        image = image + direct.radiance.numpy().reshape(H, W, 3)
        non_finite += direct.non_finite
        t_lights = time.perf_counter() - t0
    sl = shaded_level.reshape(H, W)
    n_cov = int(cov.sum())
    stats = {"levels": per_level, "samples": samples, "non_finite_samples": non_finite, "pixels_covered": n_cov,
             "unplanned_shaded": unplanned,
             "pixels_shaded": int((sl >= 0).sum()),
             "shaded_fraction": float((sl >= 0).sum() / n_cov) if n_cov else 0.0,
             "time_s": {"shading": t_shade, "upsampling": t_up, "lights": t_lights}}
    return AdaptiveResult(image.astype(np.float32), sl >= 0, sl,
                          np.minimum(spp_taken, INT32_MAX).astype(np.int32).reshape(H, W), stats)
