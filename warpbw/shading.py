"""Forward reference estimator (002 Eq. 2): N BRDF-importance samples per pixel, optional MIS.

Public:
    ``make_reference_kernel(kinds, mis)``  the shading kernel for a set of material kinds
    ``ShadeResult`` / ``shade_reference(gb, materials, env_data, spp, seed, ..., lights)``  run it over covered pixels
    ``ShadingFrame`` / ``pixel_frame(gb, i)``  a pixel's (t, b, n) frame and local view direction (Warp)
    ``to_local(fr, w)`` / ``to_world(fr, w)``  directions between world and the frame (Warp)
    ``covered_pixels(gb, device) -> wp.array``  the covered pixels' indices
    ``lighting_inputs(env_data, lights)``  the kernel's environment and lights arguments (placeholders if absent)
    ``finite3(v)``  Warp func: all three components finite (a sample that is not is dropped)

Per pixel p with surface point x, normal n and view direction wo (ignoring visibility, as 002 Eq. 1):

    L_p ~= 1/N sum_i L_i(w_i) rho(x, w_i, wo) (w_i . n) / g(w_i)              (002 Eq. 2)

with w_i drawn from the BRDF's sampler (``g`` its pdf; G = 1).  With ``mis=True`` each of the N steps
also draws one direction from the environment's distribution and the two are combined by the balance
heuristic (Veach 1997), which tames small bright sources such as the sun of ``city.exr``.

Directional ``[[light]]``s (:mod:`warpbw.lights`) add their exact term E rho(l, wo) (l . n) to every pixel
besides the estimate: they cost no samples and add no variance.  A scene without an environment (lights
only) compiles no sampling loop: its image is the lights' term whatever ``spp`` is, and it takes 0 samples.

Samples whose contribution is not finite (a pdf that underflows at a grazing angle, say) are dropped:
they add nothing to the sum, which is still divided by ``spp`` (each counts as a sample of value 0, so such a
pixel reads low, never NaN), and they are counted in ``ShadeResult.non_finite``.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Callable

import numpy as np
import warp as wp

from warpbw.brdf import MaterialBuffers, MaterialTable, check_sampling_tables, make_brdf_funcs
from warpbw.envmap import EnvMapData, check_env_data, env_pdf_uv, env_radiance_uv, env_sample, env_uv
from warpbw.errors import INT32_MAX, WarpbwError, check_count, check_device, check_flag, check_instance, check_seed
from warpbw.gbuffer import GBuffer, GBufferData
from warpbw.launch import LAUNCH_COST_MAX, launch_tiled
from warpbw.lights import DirectionalLights, Lights, as_lights

# Samples summed in float32 before their sum joins the pixel's float64 total: a float32 sum of ~1.7e7 equal
# terms stops growing, and one of 256 is within 256 float32 roundings (1.5e-5) of exact.  Each sample enters the
# float32 sum divided by SUM_BATCH (a power of two: exact), so that the sum never exceeds its largest sample (four
# samples of a sky of 3e38 overflowed float32, though their mean does not).
SUM_BATCH = 256
SUM_SCALE = 1.0 / SUM_BATCH
SUM_BATCH_F64 = wp.constant(wp.float64(SUM_BATCH))   # the batch's sum back to its size, in float64


@wp.struct
class ShadingFrame:
    """A covered pixel's orthonormal shading frame and the direction to the eye in it."""
    t: wp.vec3    # tangent (G-buffer)
    b: wp.vec3    # bitangent n x t
    n: wp.vec3    # shading normal (G-buffer)
    wo: wp.vec3   # direction to the eye, local: wo[2] = cos theta_o


@wp.func
def to_local(fr: ShadingFrame, w: wp.vec3):
    """World direction w in the frame's (t, b, n) coordinates."""
    return wp.vec3(wp.dot(w, fr.t), wp.dot(w, fr.b), wp.dot(w, fr.n))


@wp.func
def to_world(fr: ShadingFrame, w: wp.vec3):
    """Local direction w back to world coordinates."""
    return w[0] * fr.t + w[1] * fr.b + w[2] * fr.n


@wp.func
def pixel_frame(gb: GBufferData, i: int):
    """Pixel i's shading frame from the G-buffer, with its view direction in local coordinates."""
    fr = ShadingFrame()
    fr.n = gb.normal[i]
    fr.t = gb.tangent[i]
    fr.b = wp.cross(fr.n, fr.t)
    fr.wo = to_local(fr, gb.view[i])
    return fr


@wp.func
def finite3(v: wp.vec3):
    return wp.isfinite(v[0]) and wp.isfinite(v[1]) and wp.isfinite(v[2])


def make_reference_kernel(kinds, mis: bool, per_pixel_spp: bool = False, has_env: bool = True,
                          has_lights: bool = False):
    """The reference shading kernel for the given material kinds, with or without MIS.

    With ``per_pixel_spp`` the sample count of pixel i is ``spp_map[i]`` (N_p of 002 Sec. 2.4, for
    adaptive shading) instead of the scalar ``spp``; a pixel with N_p = 0 gets the lights' term only.
    ``has_env`` compiles the environment's sampling loop, ``has_lights`` the directional lights' term.
    """
    return _reference_kernel(frozenset(int(k) for k in kinds), bool(mis), bool(per_pixel_spp), bool(has_env),
                             bool(has_lights))


@functools.cache  # one kernel per combination: Warp compiles each once
def _reference_kernel(kinds: frozenset, mis: bool, per_pixel_spp: bool, has_env: bool, has_lights: bool):
    f = make_brdf_funcs(kinds)

    @wp.kernel(module="unique", enable_backward=False)
    def shade_reference_kernel(gb: GBufferData, mats: MaterialTable, env: EnvMapData, lights: DirectionalLights,
                               pixels: wp.array(dtype=wp.int32), offset: int, spp_all: int,
                               spp_map: wp.array(dtype=wp.int32), seed: int,
                               out: wp.array(dtype=wp.vec3), non_finite: wp.array(dtype=wp.int64),
                               first: int, last: int, carry_state: wp.array(dtype=wp.uint32),
                               carry_sum: wp.array(dtype=wp.vec3d)):
        j = wp.tid() + offset
        i = pixels[j]
        spp = spp_all
        if wp.static(per_pixel_spp):
            spp = spp_map[i]
        m = gb.material[i]
        fr = pixel_frame(gb, i)
        wo = fr.wo
        state = wp.rand_init(seed, i)
        acc = wp.vec3d(0.0)   # float64: a float32 sum stops growing past ~1.7e7 samples of one size
        part = wp.vec3(0.0)   # float32 sums of SUM_BATCH samples / SUM_BATCH, added to acc (float64 per sample
        # cost 5% of a frame)
        s_end = wp.min(spp, last)   # this launch draws the pixel's samples first .. s_end - 1 (all: first = 0,
        if first > 0:               # last = spp); a later pass of a pixel too long for one launch goes on from
            if first >= s_end:      # the random state and the sum its previous pass left in carry_*
                return
            state = carry_state[j]
            acc = carry_sum[j]
        direct = wp.vec3(0.0)
        bad = wp.int64(0)   # int64, as the frame's count: 2 x spp (MIS) passes int32 in one pixel at spp >= 2^30
        if wp.static(has_lights):
            if wo[2] > 0.0 and s_end == spp:   # once, in the pixel's last pass
                for k in range(lights.direction.shape[0]):
                    ld = to_local(fr, lights.direction[k])
                    if ld[2] > 0.0:
                        c = wp.cw_mul(f.eval(mats, m, ld, wo), lights.radiance[k]) * ld[2]  # E rho cos, Eq. 1
                        if finite3(c):
                            direct = direct + c
                        else:
                            bad = bad + wp.int64(1)
        if wp.static(has_env):
            if wo[2] > 0.0:
                for s in range(first, s_end):
                    if s % SUM_BATCH == 0:
                        acc = acc + wp.vec3d(part) * SUM_BATCH_F64
                        part = wp.vec3(0.0)
                    # BRDF-sampled direction (002 Eq. 2)
                    u = wp.vec3(wp.randf(state), wp.randf(state), wp.randf(state))
                    wi = f.sample(mats, m, wo, u)
                    if wi[2] > 0.0:
                        p = f.pdf(mats, m, wi, wo)
                        if p > 0.0:
                            uv = env_uv(env, to_world(fr, wi))   # once: the radiance and the MIS pdf need it
                            p_sum = p
                            if wp.static(mis):
                                p_sum = p + env_pdf_uv(env, uv)
                            c = wp.cw_mul(f.eval(mats, m, wi, wo), env_radiance_uv(env, uv)) * (wi[2] / p_sum)
                            if finite3(c):
                                part = part + c * SUM_SCALE
                            else:
                                bad = bad + wp.int64(1)
                    if wp.static(mis):
                        # environment-sampled direction, balance heuristic
                        ul = wp.vec2(wp.randf(state), wp.randf(state))
                        wl = env_sample(env, ul)
                        wl_local = to_local(fr, wl)
                        if wl_local[2] > 0.0:
                            uvl = env_uv(env, wl)
                            pl = env_pdf_uv(env, uvl)
                            if pl > 0.0:
                                pb = f.pdf(mats, m, wl_local, wo)
                                c = wp.cw_mul(f.eval(mats, m, wl_local, wo), env_radiance_uv(env, uvl)) * (
                                    wl_local[2] / (pl + pb))
                                if finite3(c):
                                    part = part + c * SUM_SCALE
                                else:
                                    bad = bad + wp.int64(1)
        if s_end < spp:   # a pass ends at a multiple of SUM_BATCH: its sum is the one the next batch would start from
            carry_state[j] = state
            carry_sum[j] = acc + wp.vec3d(part) * SUM_BATCH_F64
        else:
            out[i] = wp.vec3((acc + wp.vec3d(part) * SUM_BATCH_F64) / wp.float64(wp.max(spp, 1))) + direct
        if bad > 0:
            wp.atomic_add(non_finite, 0, bad)

    return shade_reference_kernel


@dataclass
class ShadeResult:
    radiance: wp.array          # (H*W,) vec3, 0 where no geometry
    pixels_shaded: int
    samples: int                # BRDF samples (N per pixel; 0 without an environment); with MIS as many
                                # environment samples again
    non_finite: int             # samples dropped (counted as 0 in the mean) because their contribution was not finite


def lighting_inputs(env_data: EnvMapData | None, lights: Lights | None):
    """The environment and light structs a kernel takes: an empty struct for what the scene lacks (the kernel
    compiles no code that reads it, as ``warpbw.filtering``'s), and a one-line error when it lacks both."""
    lights = as_lights(lights)
    if env_data is None and lights is None:
        raise WarpbwError("shading: the scene has no light (expected an environment or directional lights)")
    return (EnvMapData() if env_data is None else env_data), (DirectionalLights() if lights is None else lights.data)


def covered_pixels(gb: GBuffer, device: str = "cpu") -> wp.array:
    """Indices of the pixels that see geometry, as an int32 device array."""
    check_device(device)
    check_instance(gb, GBuffer, "covered_pixels: gb", "a GBuffer (render_gbuffer's)")
    idx = np.flatnonzero(gb.coverage.reshape(-1)).astype(np.int32)
    return wp.array(idx, dtype=wp.int32, device=device)


def _check_pixel_indices(pixels, n_pix: int) -> np.ndarray:
    """``pixels`` on the host, checked: the kernel indexes the G-buffer with them, and one out of 0..n_pix-1
    crashed the process (segfault)."""
    expected = f"shade_reference: pixels: expected a 1-D int32 wp.array of pixel indices in 0..{n_pix - 1}"
    if not isinstance(pixels, wp.array) or pixels.ndim != 1 or pixels.dtype != wp.int32:
        raise WarpbwError(f"{expected}, got {type(pixels).__name__}"
                          + (f" {pixels.dtype.__name__} {pixels.shape}" if isinstance(pixels, wp.array) else ""))
    idx = pixels.numpy()
    if idx.size and not (0 <= idx.min() and idx.max() < n_pix):
        raise WarpbwError(f"{expected}, got values from {idx.min()} to {idx.max()}")
    return idx


def _check_material_ids(gb: GBuffer, materials: MaterialBuffers) -> np.ndarray:
    """Every material id the G-buffer holds must index ``materials``: the kernel reads the table with it, and an
    id past its end shaded black, or crashed the process (segfault).  Returns the ids (host copy)."""
    if not isinstance(materials, MaterialBuffers):
        raise WarpbwError(f"shade_reference: materials: expected build_material_table's MaterialBuffers, got "
                          f"{type(materials).__name__}")
    n = len(materials.names)
    ids = gb.data.material.numpy()
    top = int(ids.max(initial=-1))
    if top >= n:
        raise WarpbwError(f"shade_reference: the G-buffer holds material id {top}, the material table has {n} "
                          f"(ids 0..{n - 1}): build the geometry with ids into that table")
    return ids


def _spp_map(spp, gb: GBuffer, device: str):
    """``spp`` as an int32 device array when it is a per-pixel map (a wp.array, or a numpy array of integers of
    the G-buffer's (height, width) or flat); None when it is one count."""
    n_pix = gb.width * gb.height
    if isinstance(spp, np.ndarray) and spp.ndim >= 1:
        # a transposed (width, height) map has the size too, and was taken
        if not np.issubdtype(spp.dtype, np.integer) or spp.shape not in ((gb.height, gb.width), (n_pix,)):
            raise WarpbwError(f"shade_reference: spp: expected per-pixel integer counts of shape (height, width) = "
                              f"({gb.height}, {gb.width}) or ({n_pix},), got {spp.dtype} {spp.shape}")
        if spp.size and (spp.min() < 0 or spp.max() > INT32_MAX):
            raise WarpbwError(f"shade_reference: spp: per-pixel counts must be from 0 to {INT32_MAX}, got "
                              f"{spp.min()} to {spp.max()}")
        return wp.array(spp.reshape(-1).astype(np.int32), dtype=wp.int32, device=device)
    return spp if isinstance(spp, wp.array) else None


def shade_reference(gb: GBuffer, materials: MaterialBuffers, env_data: EnvMapData | None, spp, seed: int = 0,
                    mis: bool = False, device: str = "cpu", threads: int | None = None,
                    progress: Callable[[int], None] | None = None, pixels: wp.array | None = None,
                    out: wp.array | None = None, lights: Lights | None = None) -> ShadeResult:
    """Shade every covered pixel (or the given ``pixels``) and return radiance.

    ``spp`` is one sample count for all pixels, or H*W per-pixel counts N_p (an int32 wp.array, or numpy
    integers of shape (H, W) or (H*W,)).  Pixels not shaded keep the value they have in ``out`` (zeros when ``out``
    is not given).  ``env_data`` (``EnvMap.data``) None: no environment (``lights`` must then be given); ``lights``:
    directional lights, or None.  On the CPU a pixel of more than ``LAUNCH_COST_MAX`` samples is shaded in passes
    of launches (Ctrl-C acts between them), bit for bit the image of one launch per pixel.
    """
    mis = check_flag(mis, "shade_reference: mis")
    check_device(device, "shade_reference: device")
    check_instance(gb, GBuffer, "shade_reference: gb", "a GBuffer (render_gbuffer's)")
    seed = check_seed(seed, "shade_reference: seed")   # 2**32 drew seed 0's samples, -1 those of 2**32 - 1
    lights = as_lights(lights, "shade_reference: lights")
    n_pix = gb.width * gb.height
    material_ids = _check_material_ids(gb, materials)
    if env_data is not None:   # another object was an AttributeError in Warp; MIS from a struct without its
        check_env_data(env_data, "shade_reference", sampled=mis)   # sampling distribution, a segfault
        check_sampling_tables(materials, "shade_reference", material_ids)   # BRDF samples: the same
    as_map = _spp_map(spp, gb, device)
    per_pixel = as_map is not None
    if per_pixel:
        spp = as_map
    has_env = env_data is not None
    if per_pixel:
        if spp.shape != (n_pix,) or spp.dtype != wp.int32:
            raise WarpbwError(f"shade_reference: spp: expected an int32 array of {n_pix} per-pixel counts (the "
                              f"G-buffer's {gb.width} x {gb.height}), got {spp.dtype.__name__} {spp.shape}")
        spp_np = spp.numpy()   # one host copy: the check here, the tiles' costs and the sample count below
        if int(spp_np.min(initial=0)) < 0:
            raise WarpbwError("shade_reference: spp: per-pixel counts must be >= 0")
    else:   # no environment: the lights' term takes no sample, and 0 says so
        check_count(spp, "shade_reference: spp", 1 if has_env else 0, INT32_MAX)
    env_data, lights_data = lighting_inputs(env_data, lights)
    kernel = make_reference_kernel(materials.kinds, mis, per_pixel, has_env, lights is not None)
    pix = covered_pixels(gb, device) if pixels is None else pixels
    pix_np = _check_pixel_indices(pixels, n_pix) if pixels is not None else None
    if out is None:
        out = wp.zeros(n_pix, dtype=wp.vec3, device=device)
    elif not isinstance(out, wp.array) or out.shape != (n_pix,) or out.dtype != wp.vec3:
        raise WarpbwError(f"shade_reference: out: expected a vec3 array of {n_pix} pixels, got {out!r:.80}")
    # the frame's dropped samples: int32 wrapped past 2^31 (4096 spp with MIS at 2048^2 draws 3.4e10 samples; a frame
    # of overflowing radiance drops most of them), and a count wrapped to 0 passed the overflow check without a word
    bad = wp.zeros(1, dtype=wp.int64, device=device)
    spp_map = spp if per_pixel else wp.zeros(0, dtype=wp.int32, device=device)
    spp_all = 0 if per_pixel else int(spp)
    if per_pixel:   # N_p of each pixel shaded: tile costs, samples
        pixel_spp = spp_np[pix.numpy() if pix_np is None else pix_np]
    else:
        pixel_spp = None
    n = int(pix.shape[0])
    longest = (int(pixel_spp.max(initial=0)) if per_pixel else spp_all) if has_env else 0
    # a pixel of more than LAUNCH_COST_MAX samples is shaded in passes of `chunk` samples on the CPU, each its own
    # launches, so that Ctrl-C acts between them (a 1 x 1 frame at 2^31 - 1 spp was one launch of hours)
    chunk = max(SUM_BATCH, LAUNCH_COST_MAX // SUM_BATCH * SUM_BATCH)
    split = str(device).startswith("cpu") and longest > LAUNCH_COST_MAX
    passes = [(s, min(s + chunk, INT32_MAX)) for s in range(0, longest, chunk)] if split else [(0, INT32_MAX)]
    carry_state = wp.zeros(n if split else 0, dtype=wp.uint32, device=device)
    carry_sum = wp.zeros(n if split else 0, dtype=wp.vec3d, device=device)
    step = progress if progress is None or not split else (lambda c: progress(c / len(passes)))
    for first, last in passes:
        costs = None if pixel_spp is None else np.clip(pixel_spp - first, 0, last - first)
        launch_tiled(kernel, n,
                     lambda o, c, first=first, last=last: [gb.data, materials.table, env_data, lights_data, pix, o,
                                                           spp_all, spp_map, int(seed), out, bad, first, last,
                                                           carry_state, carry_sum], device, threads, step,
                     costs=costs, item_cost=max(0, min(spp_all - first, last - first)) if has_env else 0)
    if not has_env:
        samples = 0
    elif per_pixel:
        samples = int(pixel_spp.sum()) if n else 0
    else:
        samples = n * spp_all
    return ShadeResult(out, n, samples, int(bad.numpy()[0]))
