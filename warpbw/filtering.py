"""Multiresolution reflectance filtering (004): planes with normal-mapped Cook-Torrance materials under
directional lights and / or an environment, shaded from GMM normal mipmaps or from the simpler filters, and a
ground truth.

Public:
    ``METHODS``                          the filtered methods: gmm_aligned, gmm_unaligned, toksvig, lean, fixed
    ``ALL_METHODS``                      ``METHODS`` + ``ground_truth``
    ``DEFAULT_ENV_SPP``, ``MIN_GT_SPP``, ``DEFAULT_GT_SPP``   environment samples and ground-truth rays per pixel
    ``FilteringScene``                   what ``prepare_filtering`` returns: the planes' mipmaps on the device
    ``scene_environment(scene, device) -> EnvMap | None``   the scene's [environment], loaded
    ``prepare_filtering(scene, methods, device, progress, cache, env, gmm_files) -> FilteringScene``   load / build
                                         the mipmaps
    ``check_gmm_files(scene, methods) -> {material: (GmmMipmap, seconds)}``   the planes' ``gmm`` files read and
                                         checked against their materials before any other work (below)
    ``gmm_header_problem(scene, name, path) -> str | None``   why a render refuses material NAME's gmm file PATH,
                                         as its header tells (``warpbw info``)
    ``render_filtering(scene, method, spp, seed, device, prepared, camera, progress, lod_bias, threads,
                       env_spp, max_anisotropy, background)``        -> ``FilterResult``; ``scene`` a ``Scene``
                                         or its ``FilteringScene`` (then the prepared one, on its own device)
    ``check_render_args(scene, method, spp, env_spp, max_anisotropy)``  its argument checks, before any work
    ``FilterResult``                     image, coverage, level map, time_s, stats; ``aovs`` ({"level": level})
    ``Background``                       image and camera-space depth the planes are drawn over
    ``plane_distance(scene, device) -> (H, W)``   per pixel, the distance along the centre ray to the nearest
                                         plane (``inf`` where none): what hides the spheres and meshes
    ``filtering_summary(scene) -> dict``  what ``warpbw info`` prints for a scene with planes
    ``filtering_stages(method, flat, with_env, with_lights) -> list``   the stages a frame ran (its stats)
    ``FLAT_SHADED_AS``                   what a plane without a normal map shades with (no GMM is fitted for it)
    ``plane_objects(scene) -> list``     the scene's planes; a one-line error when it has other objects too
    ``check_plane_reach(camera, planes, source)``   refuse a scene too large or too small for float32 intersection
                                         (``PLANE_REACH_MIN``, ``PLANE_REACH_MAX``)
    ``normal_moment_mipmap(normals) -> list``   box-filtered (mean normal, second moments) levels (numpy)
    ``fetch_gmm(levels, s, t, level, device) -> (N, K, 4)``  the kernel's trilinear fetch, recovered (a, mu, s2)
    ``gmm_ndf(params, rough_var, h, device) -> (N,)``           the kernels' mixture NDF at directions h for
                                         components of variance s^2 (not quite at ``fetch_gmm``'s: ``gmm_ndf``)
    ``pair_uniforms(seed, pixel, n, device) -> (n, 5)``        the environment term's uniforms at a pixel
    ``zoomed_camera(camera, zoom) -> Camera``   the camera moved away from its look-at point (distance x zoom)
    ``LOD_BIAS``                         added to log2(footprint): the mip filter then blurs as the pixel box
    ``MAX_ANISOTROPY``, ``DEFAULT_ANISOTROPY``   the most probes along a footprint's major axis; the default (1)
    ``roughness_variance(m)``            the Gaussian NDF's per-axis variance m^2 / 2 of roughness m
    ``diffuse_pick(diffuse, f0)``        the BRDF sampler's probability of a cosine-weighted draw
    ``Lobes``, a Warp matrix type (``MAX_LOBES`` rows: weight, mean, 2x2 covariance), Warp struct ``PlaneData``;
    Warp functions ``lobes_ndf(L, nl, h)``, ``lobes_sample(L, nl, wo, pl, u)``, ``sample_pdf(D, at, h, wi,
    wo, pl)``: the lobes' NDF, the BRDF strategy's draw and its solid-angle pdf (tests launch them in kernels)
    Warp functions its kernels are built of: the view (``ray_dir``, ``plane_t``, ``plane_st``, ``inside``,
    ``to_plane``, ``plane_to_world``, struct ``Footprint``, ``pixel_footprint``, ``probe_offset``), the mipmap
    fetch (``pmod``, ``texel_index``, ``axis_base``, ``bilinear_base``, ``fetch4``, ``fetch3``, ``trilinear4``,
    ``trilinear3``, ``recover``), the model (``gauss2``, ``gauss2_cov``, ``lift``, ``schlick``, ``cook_torrance_cos``,
    ``half_xy``, ``shade_fine``, ``set_lobe``, ``lobes_lambert``, ``lobes_cos``, ``lobes_direct``), the
    environment (``env_mis_term``, ``pair_offset``, ``pair_uniform``, ``lobes_env``); the kernels
    ``background_distance_kernel``, ``plane_distance_kernel`` and, behind ``fetch_gmm`` / ``gmm_ndf`` /
    ``pair_uniforms``, ``fetch_gmm_kernel``, ``gmm_ndf_kernel``, ``pair_uniforms_kernel``

The model (004 Sec. 3).  Normals live in the projected normal space of ``precompute.gmm_mipmap``: a unit
normal n is the 2D point (n_x, n_y) in the plane's tangent frame (x along +u = +X, y along -v = -Z, z = +Y:
x along +column and y along -row of the map, as ``precompute.surfaces``).  The microfacet normals of a
footprint are distributed as the mixture D(h) = sum_i a_i g(h_xy; mu_i, s_i^2 + m^2/2), g the isotropic 2D
Gaussian density of per-axis variance s^2: each component's own spread plus the material's roughness (a
Gaussian NDF of roughness m has per-axis slope variance m^2/2, as Beckmann's).  As a density over projected
coordinates it is projected-area normalised: int D(h) h_z dw_h = int g dp = 1 (dw_h = dp / h_z).  A
directional light of radiance E from direction wi gives, seen from wo (both in the plane's frame):

    L = E [ F(u) D(h) / (4 wo_z)  +  diffuse / pi (1 - F(u)) sum_i a_i max(n_i . wi, 0) ]

with h = normalize(wi + wo), u = max(wo . h, 0), F Schlick's approximation from f0, and n_i the unit normal
of mean mu_i (004 Sec. 3: Cook-Torrance summed over the components, Lambert with the component means).
The specular term is the microfacet BRDF F D G / (4 wi_z wo_z) times wi_z with no shadowing (G = 1), as
004's sum carries none.  An environment of radiance L_env gives the integral of L_env(wi) times the bracket
over the plane's upper hemisphere.  The *fine-scale* BRDF (the ground truth's, per ray) is the same with one
component: mu = the finest-level normal at the hit point (bilinear fetch), s = 0.

The methods, per pixel: an analytic ray-plane hit, uv, and the pixel's footprint in finest-level texels from
the ray differentials (the neighbouring pixels' rays against the same plane); the level is log2 of the
footprint's larger side plus ``LOD_BIAS`` (which matches the mip filter's blur to the pixel's box), fractional,
and every method filters trilinearly at it (004 Sec. 4.2).  With ``max_anisotropy`` > 1 (not in 004; by
default off) an elongated footprint is filtered as GPUs filter anisotropically: n <= max_anisotropy
trilinear probes spaced along its major axis, at the level of its minor one (no finer than level 0), their
stored quantities averaged before a method recovers its lobes -- the same linear filtering with a footprint
whose variance along both axes is the pixel box's (``pixel_footprint``).  Below level 0 (a pixel smaller than
a texel) the result blends towards the fine-scale BRDF at the bilinearly interpolated finest normal, fully at
level -1: level-0 texels are point samples of the normal field, not distributions.  Every method's NDF is a
few lobes (``Lobes``: weight, mean, 2x2 covariance; the magnification blend is one more lobe, the shading
being linear in the weights), shaded in closed form under each directional light and, under an environment,
estimated with ``env_spp`` pairs of one BRDF sample (a lobe picked by weight, its Gaussian sampled and
reflected; or, with probability ``diffuse_pick``, a cosine-weighted direction) and one environment sample
(``warpbw.envmap``), combined by the balance heuristic.  A pixel's pairs draw their uniforms from a
quasi-random set, the R_3 and R_2 Kronecker sequences shifted by one random offset per pixel (``PAIR_ALPHA``),
not from independent uniforms: each estimate stays unbiased, and its error is lower.  The methods:
    gmm_aligned / gmm_unaligned   the stored moments (a, a mu, a E|n|^2 = a (2 s^2 + |mu|^2)) of each
                                  component, filtered linearly, then a, mu, s^2 recovered: the isotropic
                                  Gaussian of the filtered mean and second moment (004 Sec. 4.2, in the form
                                  ``precompute.gmm_mipmap`` stores); EM-aligned mipmap (004 Sec. 4.1) or
                                  independent per-texel EM;
    toksvig                       one Gaussian about the renormalised mean normal, widened by Toksvig's
                                  per-axis variance (1 - |n|) / |n| of the mean normal's length |n|;
    lean                          one anisotropic Gaussian with the filtered mean and covariance of the
                                  projected normals (LEAN-style first and second moments);
    fixed                         the fine-scale BRDF on the renormalised mean normal;
    ground_truth                  ``spp`` (>= 64) jittered rays per pixel, each shaded with the fine-scale BRDF
                                  at its own hit point (under an environment: one BRDF and one environment
                                  sample per ray), averaged over the rays that hit the plane (a box filter over
                                  the part of the pixel the plane covers).  On a plane's outline the pixel is
                                  the plane's mean radiance there, not blended with what lies behind: the
                                  methods shade the plane at the centre ray, and reflectance filtering cannot
                                  change how much of a pixel a plane covers.
The box-filtered normal mipmaps (toksvig, lean, fixed) hold per texel the mean unit normal and the second
moments (E[x^2], E[y^2], E[xy]) of the projected normals over the texel's footprint (clipped at the border,
like the GMM mipmap).  The GMM mipmaps come from the material's ``gmm`` file (aligned) or are built by
``precompute.gmm_mipmap`` and cached under ``$WARPBW_CACHE`` (``precompute.brdf_sampling.load_or_build``), with
the material's ``gmm_components`` (both) and ``gmm_prior`` (the aligned one's c; the unaligned one has none).
A cache entry fitted with other settings than the fit's current ones (``precompute.gmm_mipmap.fit_settings``: seed,
samples per footprint, refinement sweeps) is rebuilt; a material's ``gmm`` file is taken whatever seed it was fitted
with.  That file is read and checked first (``check_gmm_files``: format, version, and that it was fitted to the
material's normal map with its kind, scale, components and prior), before the environment, the normal mipmaps, and
in ``warpbw.pipeline.render_with_planes`` before the spheres and meshes are loaded: a wrong file is refused in one
line naming it before any rendering work.

Scope: planes only (spheres and meshes are refused); several planes composite by the depth of each pixel's
centre ray, and so do planes drawn over a ``Background`` (the spheres and meshes of a scene that has both,
rendered by :mod:`warpbw.pipeline`); no light is occluded (a plane does not shadow another).  A kernel is
compiled per method kind with or without the environment term and the directional lights' loop: a scene without
an environment compiles no sampling, one without lights no light loop.
The device is an argument (CPU launches are tiled over a thread pool); the kernels have been run on the CPU
only.
"""
from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import warp as wp

from precompute.gmm_mipmap import NORMAL_DIM, VARIANCE_FLOOR, WEIGHT_EPS, level_shapes
from warpbw.envmap import (LUMINANCE_RGB, EnvMapData, env_pdf_uv, env_radiance_uv, env_sample, env_uv,
                           ensure_sampling, load_environment)
from warpbw.errors import (FLOAT32_MAX, INT32_MAX, WarpbwError, available_memory, check_camera_reach,
                           check_coordinate_spacing, check_count, check_device, check_finite_image, check_flag,
                           check_instance, check_path, check_real, check_seed, numeric_array, unit_directions,
                           warn_if_short_of_memory)
from warpbw.gbuffer import CameraData, scene_camera
from warpbw.scene import GMM_MAX_COMPONENTS, Camera, PlaneObject, Scene, check_scene

METHODS = ("gmm_aligned", "gmm_unaligned", "toksvig", "lean", "fixed")
ALL_METHODS = METHODS + ("ground_truth",)
# What a plane without a normal map shades with, whatever the filter: all of them are the plain BRDF there.
FLAT_SHADED_AS = "fixed (no normal map: every filter is the plain BRDF; no GMM is fitted)"
# Kernel codes of the filtered methods (the two GMM methods share a kernel; only their mipmaps differ).
_CODE = {"gmm_aligned": 0, "gmm_unaligned": 0, "toksvig": 1, "lean": 2, "fixed": 3}
# Ground truth: at least this many rays per pixel (issue 4: ">= 64"); 004 Fig. 4 used 16.
MIN_GT_SPP = 64
# render_filtering's (and `warpbw render --filter ground_truth`'s --spp) default; bench-filtering's truth takes
# 1024 (warpbw.bench_filtering.DEFAULT_GT_SPP)
DEFAULT_GT_SPP = 64
# The GMM builder's bounds, read here as it wrote the mipmaps: mixture weights below WEIGHT_EPS recover as empty
# components (004 Sec. 4.1), and a recovered per-axis variance is floored at VARIANCE_FLOOR (float32 moments lose s^2
# below), which the shading subtracts again (a flat map, stored with s^2 = floor, shades as the plain BRDF).
# Smallest length of a filtered mean normal for Toksvig (a footprint of opposite normals averages to ~0).
MIN_MEAN_LENGTH = 1e-4
# Toksvig: a mean normal this close to unit length is unit (float32 rounding of the filter weights, ~8 ulps).
TOKSVIG_LENGTH_EPS = 1e-6
# LEAN: the filtered covariance's correlation is clamped to within this of +-1 (|s_xy| <= 0.999 sqrt(s_xx s_yy); ours),
# so that float32 moments of a footprint of one slope never leave a singular or indefinite lobe.
LEAN_CORRELATION_MAX = 0.999
# wo_z below this (a grazing view of the macro surface) shades nothing: 1 / (4 wo_z) would blow up.
MIN_COS = 1e-4
# How far from unit length a normal ``normal_moment_mipmap`` takes may be: float32 maps renormalised in float64
# are within 1e-7; a vector 5 long was averaged as it was, its level's mean normal and moments 5 and 25 times too large.
UNIT_LENGTH_TOL = 1e-3
# LOD bias (levels): trilinear filtering at log2(footprint) blurs over a bilinear tent of level-l texels that
# are themselves box averages -- a filter of variance 4^l / 12 + 4^l / 6 = 4^l / 4 finest texels^2, where the
# pixel's box of side rho has rho^2 / 12.  Equal variances at l = log2(rho) - log2(3) / 2: the mipmap then
# blurs as much as the pixel does (the ground truth's box filter), not three times as much.
LOD_BIAS = -0.5 * math.log2(3.0)
# Anisotropic footprints (not in 004, whose Sec. 4.2 filters trilinearly): at most this many probes along the
# footprint's major axis, as GPUs' anisotropic texture filtering (EXT_texture_filter_anisotropic's usual 16x).
MAX_ANISOTROPY = 16
# The default: 1, one isotropic trilinear probe (004 Sec. 4.2, and every benchmark of record).
DEFAULT_ANISOTROPY = 1
# Probes: ceil(s1 / r - slack), so that float rounding of an exact ratio (s1 = 2 r) does not add one.
ANISO_PROBE_SLACK = 1e-4
# Footprint of a pixel whose neighbouring ray misses the (infinite) plane -- at the horizon: this many
# finest texels (larger than any map, so the coarsest level).
HORIZON_FOOTPRINT = 1.0e9
INV_PI = 1.0 / math.pi
TWO_PI = 2.0 * math.pi
# A pixel's NDF as lobes, one row each (a, mu_x, mu_y, s_xx, s_yy, s_xy): up to GMM_MAX_COMPONENTS filtered
# components, plus the fine-scale lobe a magnified pixel blends towards.
MAX_LOBES = GMM_MAX_COMPONENTS + 1
Lobes = wp.types.matrix(shape=(MAX_LOBES, 6), dtype=wp.float32)
# Under an [environment]: pairs of one BRDF and one environment sample per pixel of the filtered methods
# (multiple importance sampling, balance heuristic); the ground truth takes one pair per ray.
DEFAULT_ENV_SPP = 64
# The BRDF strategy draws cosine-weighted directions (the Lambert term) with probability q = the diffuse
# albedo's share of diffuse + f0 luminance, kept in [DIFFUSE_PICK_MIN, 1 - DIFFUSE_PICK_MIN] so that neither
# term goes unsampled (Schlick's Fresnel is bright at grazing angles even for f0 = 0).
DIFFUSE_PICK_MIN = 0.1


def _rd_alphas(d: int) -> list:
    """The R_d sequence's steps alpha_j = phi_d^-j, j = 1..d, phi_d the real root of x^(d+1) = x + 1 (Roberts,
    "The unreasonable effectiveness of quasirandom sequences", 2018; R_1 is the golden ratio's)."""
    phi = 2.0
    for _ in range(100):                       # fixed-point iteration, contracting: converges to double precision
        phi = (1.0 + phi) ** (1.0 / (d + 1))
    return [phi ** -(j + 1) for j in range(d)]


# The uniforms of a pixel's k-th pair: coordinate j = frac(r_j + k alpha_j), R_3 for the BRDF draw (term or
# lobe, then a 2D point) and R_2 for the environment draw, r a uniform offset per pixel (Cranley-Patterson
# rotation, so every estimate is unbiased).  In 32-bit fixed point, where uint32 arithmetic wraps modulo 1
# exactly (float32 would lose k alpha's fraction at thousands of pairs).  Measured against independent uniforms
# (64 pairs against a 4096-pair render of the same method, gmm_aligned and toksvig on the three benchmark
# surfaces under forest.exr at zooms 1, 8, 32): mean colour error 27-39% lower, what 1.9-2.7x the pairs would
# give.  (R_4 with separate uniforms for the term and the lobe did less well: its 2D projections are coarser.)
PAIR_DIMS = 5
PairVec = wp.types.vector(length=PAIR_DIMS, dtype=wp.uint32)
PAIR_ALPHA = wp.constant(PairVec(*[int(a * 2.0 ** 32) for a in _rd_alphas(3) + _rd_alphas(2)]))
INV_2_24 = wp.constant(1.0 / float(1 << 24))  # the top 24 bits of a fixed-point fraction -> float32 in [0, 1)
# GMM mipmap cache: file name prefix and the version of what is cached (precompute.gmm_mipmap.GMM_VERSION).
GMM_CACHE_PREFIX = "gmm"
# Distance along a pixel's centre ray of "nothing in front": every plane hit is closer (float32 range).
NO_HIT = 3.0e38
_NO_HIT = wp.constant(NO_HIT)
# Planes are intersected in float32, and every length there (plane_t, plane_st, the ray differentials) is linear
# in the scene's scale: the camera's distance to a plane's far corner must lie in float32's normal range and below
# NO_HIT.  Measured (session 39, a plane seen from 2.5 sizes away, scaled by s): every method's image within 1.2e-6
# of s = 1's brightest pixel from reach 3.5e-38 to 3.5e37; at 3.5e-42 off by 0.2%; at 3.5e-45 62% of the plane
# lost, at 3.5e38 15%.  Margins as gbuffer's: 1000 at the bottom, 10 at the top (``check_plane_reach``).
PLANE_REACH_MIN = float(np.finfo(np.float32).tiny) * 1.0e3
PLANE_REACH_MAX = NO_HIT / 10.0


def roughness_variance(m: float) -> float:
    """Per-axis variance of the Gaussian NDF of roughness m: m^2 / 2 (Beckmann's slope variance)."""
    m = check_real(m, "m (roughness)", 0.0)   # "0.3" was squared as 0.045, None was float()'s TypeError, NaN NaN
    return 0.5 * m * m


# ---------------------------------------------------------------------------------------------------
# Kernels and their functions

@wp.struct
class PlaneData:
    center: wp.vec3
    size: float
    tiling: float
    map_w: int          # finest level, texels
    map_h: int
    levels: int
    components: int     # K of the GMM mipmap (0 for the other methods)
    f0: wp.vec3
    diffuse: wp.vec3
    rough_var: float    # m^2 / 2
    lod_bias: float     # added to log2(footprint)
    max_aniso: int      # most probes along the footprint's major axis (1: isotropic, ``MAX_ANISOTROPY``)
    diffuse_pick: float  # probability of a cosine-weighted draw in the BRDF strategy (``DIFFUSE_PICK_MIN``)


@wp.func
def ray_dir(cam: CameraData, px: float, py: float):
    """Unit direction of the ray through the image point (px, py), in pixels from the top-left corner."""
    sx = (2.0 * px / float(cam.width) - 1.0) * cam.tan_half_x
    sy = (1.0 - 2.0 * py / float(cam.height)) * cam.tan_half_y
    return wp.normalize(cam.forward + sx * cam.right + sy * cam.up)


@wp.func
def plane_t(o: wp.vec3, d: wp.vec3, pl: PlaneData):
    """Distance along d to the plane's (infinite, front-facing) supporting plane; -1 when there is none."""
    t = float(-1.0)
    if d[1] < 0.0:
        t = (pl.center[1] - o[1]) / d[1]
    return t


@wp.func
def plane_st(p: wp.vec3, pl: PlaneData):
    """Continuous finest-level texel coordinates (s along columns = +X, t along rows = +Z), not wrapped."""
    u = (p[0] - pl.center[0]) / pl.size + 0.5
    v = (p[2] - pl.center[2]) / pl.size + 0.5
    return wp.vec2(u * pl.tiling * float(pl.map_w), v * pl.tiling * float(pl.map_h))


@wp.func
def inside(p: wp.vec3, pl: PlaneData):
    h = 0.5 * pl.size
    return wp.abs(p[0] - pl.center[0]) <= h and wp.abs(p[2] - pl.center[2]) <= h


@wp.func
def to_plane(w: wp.vec3):
    """World -> the plane's tangent frame (x = +X, y = -Z, z = +Y)."""
    return wp.vec3(w[0], -w[2], w[1])


@wp.func
def pmod(i: int, n: int):
    r = i % n
    if r < 0:
        r = r + n
    return r


@wp.func
def texel_index(lw: wp.array(dtype=wp.int32), lh: wp.array(dtype=wp.int32), loff: wp.array(dtype=wp.int32),
                l: int, col: int, row: int):
    w = lw[l]
    return loff[l] + pmod(row, lh[l]) * w + pmod(col, w)


@wp.func
def axis_base(l: int, n_l: int, n: int, s: float):
    """Along one axis of n finest texels (n_l at level l): the index of the level-l texel whose centre is the last at
    or before finest coordinate s, and the fraction (0 to 1) of the way from that centre to the next, the map tiling
    with period n.  Level-l texel j covers finest texels [j 2^l, min((j + 1) 2^l, n)), its centre in the middle:
    (j + 1/2) 2^l, but where the border clips the last texel (n_l 2^l > n: n is no power of two) that texel's clipped
    centre, and the texel after it is texel 0 of the next tile, n further on (a period of n_l 2^l mixed the tiles
    up: their texels were read off the map's period from the second tile on)."""
    f = wp.pow(2.0, float(l))
    x = s / f - 0.5
    x0 = wp.floor(x)
    fx = x - x0
    if n_l * int(f) != n:
        period = float(n)
        u = s - wp.floor(s / period) * period      # s in the first tile, [0, n] (n only by rounding)
        last = float(n_l - 1)
        c_last = 0.5 * (last * f + period)         # the clipped last texel's centre
        if u < 0.5 * f:                            # between the previous tile's last texel and texel 0
            x0 = -1.0
            fx = (u - (c_last - period)) / (0.5 * f + period - c_last)
        elif u >= c_last:                          # between the last texel and the next tile's texel 0
            x0 = last
            fx = (u - c_last) / (period + 0.5 * f - c_last)
        else:
            x0 = wp.floor(u / f - 0.5)
            c0 = (x0 + 0.5) * f
            if x0 == last - 1.0:                   # towards the clipped last texel
                fx = (u - c0) / (c_last - c0)
            else:
                fx = u / f - 0.5 - x0
        fx = wp.clamp(fx, 0.0, 1.0)
    return wp.vec2(x0, fx)


@wp.func
def bilinear_base(lw: wp.array(dtype=wp.int32), lh: wp.array(dtype=wp.int32), l: int, s: float, t: float):
    """(column, row) of the lower-left of the 2 x 2 level-l texels around finest coordinates (s, t), and the
    fractions (fx, fy) towards the next ones (``axis_base`` along each axis; lw, lh the levels' sizes, level 0 the
    map's): level-l texel j covers finest texels [j 2^l, (j + 1) 2^l), its centre at (j + 1/2) 2^l (a last texel
    the map's border clips, at its clipped centre)."""
    bx = axis_base(l, lw[l], lw[0], s)
    by = axis_base(l, lh[l], lh[0], t)
    return wp.vec4(bx[0], by[0], bx[1], by[1])


@wp.func
def fetch4(q: wp.array(dtype=wp.vec4), lw: wp.array(dtype=wp.int32), lh: wp.array(dtype=wp.int32),
           loff: wp.array(dtype=wp.int32), l: int, s: float, t: float, K: int, k: int):
    """Bilinear fetch of component k of a K-component vec4 texture at level l (wrap-around: the map tiles)."""
    b = bilinear_base(lw, lh, l, s, t)
    c = int(b[0])
    r = int(b[1])
    fx = b[2]
    fy = b[3]
    return ((1.0 - fx) * (1.0 - fy) * q[texel_index(lw, lh, loff, l, c, r) * K + k]
            + fx * (1.0 - fy) * q[texel_index(lw, lh, loff, l, c + 1, r) * K + k]
            + (1.0 - fx) * fy * q[texel_index(lw, lh, loff, l, c, r + 1) * K + k]
            + fx * fy * q[texel_index(lw, lh, loff, l, c + 1, r + 1) * K + k])


@wp.func
def fetch3(q: wp.array(dtype=wp.vec3), lw: wp.array(dtype=wp.int32), lh: wp.array(dtype=wp.int32),
           loff: wp.array(dtype=wp.int32), l: int, s: float, t: float):
    """``fetch4`` for a one-component vec3 texture."""
    b = bilinear_base(lw, lh, l, s, t)
    c = int(b[0])
    r = int(b[1])
    fx = b[2]
    fy = b[3]
    return ((1.0 - fx) * (1.0 - fy) * q[texel_index(lw, lh, loff, l, c, r)]
            + fx * (1.0 - fy) * q[texel_index(lw, lh, loff, l, c + 1, r)]
            + (1.0 - fx) * fy * q[texel_index(lw, lh, loff, l, c, r + 1)]
            + fx * fy * q[texel_index(lw, lh, loff, l, c + 1, r + 1)])


@wp.func
def trilinear4(q: wp.array(dtype=wp.vec4), lw: wp.array(dtype=wp.int32), lh: wp.array(dtype=wp.int32),
               loff: wp.array(dtype=wp.int32), levels: int, lam: float, s: float, t: float, K: int, k: int):
    """Trilinear filtering (004 Sec. 4.2: the texture unit's T(p)) at fractional level lam."""
    l0 = int(wp.floor(lam))
    l1 = wp.min(l0 + 1, levels - 1)
    fl = lam - float(l0)
    return (1.0 - fl) * fetch4(q, lw, lh, loff, l0, s, t, K, k) + fl * fetch4(q, lw, lh, loff, l1, s, t, K, k)


@wp.func
def trilinear3(q: wp.array(dtype=wp.vec3), lw: wp.array(dtype=wp.int32), lh: wp.array(dtype=wp.int32),
               loff: wp.array(dtype=wp.int32), levels: int, lam: float, s: float, t: float):
    l0 = int(wp.floor(lam))
    l1 = wp.min(l0 + 1, levels - 1)
    fl = lam - float(l0)
    return (1.0 - fl) * fetch3(q, lw, lh, loff, l0, s, t) + fl * fetch3(q, lw, lh, loff, l1, s, t)


@wp.func
def recover(q: wp.vec4):
    """(a, a mu_x, a mu_y, a E|n|^2) -> (a, mu_x, mu_y, s^2)  (004 Sec. 4.2: mu = T(a mu) / T(a); the per-axis
    s^2 = (T(a E|n|^2) / T(a) - |mu|^2) / d, ``precompute.gmm_mipmap``); an empty component (a <= WEIGHT_EPS)
    comes back as zeros."""
    out = wp.vec4(0.0)
    a = q[0]
    if a > WEIGHT_EPS:
        mx = q[1] / a
        my = q[2] / a
        s2 = (q[3] / a - (mx * mx + my * my)) / float(NORMAL_DIM)
        out = wp.vec4(a, mx, my, wp.max(s2, VARIANCE_FLOOR))
    return out


@wp.func
def gauss2(dx: float, dy: float, var: float):
    """Isotropic 2D Gaussian density of per-axis variance var at offset (dx, dy)."""
    return wp.exp(-(dx * dx + dy * dy) / (2.0 * var)) / (TWO_PI * var)


@wp.func
def gauss2_cov(dx: float, dy: float, sxx: float, syy: float, sxy: float):
    """2D Gaussian density of covariance [[sxx, sxy], [sxy, syy]] at offset (dx, dy)."""
    det = sxx * syy - sxy * sxy
    e = (syy * dx * dx - 2.0 * sxy * dx * dy + sxx * dy * dy) / det
    return wp.exp(-0.5 * e) / (TWO_PI * wp.sqrt(det))


@wp.func
def lift(mx: float, my: float):
    """The unit normal whose projection is (mx, my) (clamped to the unit disk)."""
    r2 = mx * mx + my * my
    n = wp.vec3(mx, my, wp.sqrt(wp.max(1.0 - r2, 0.0)))
    if r2 > 1.0:
        n = wp.normalize(wp.vec3(mx, my, 0.0))
    return n


@wp.func
def schlick(f0: wp.vec3, u: float):
    """Schlick's Fresnel approximation (004 Sec. 3, [Sch94])."""
    c = wp.pow(1.0 - u, 5.0)
    return f0 + (wp.vec3(1.0) - f0) * c


@wp.func
def cook_torrance_cos(wi: wp.vec3, wo: wp.vec3, pl: PlaneData, D: float, lamb: float):
    """004 Sec. 3's BRDF times wi_z: F D / (4 wo_z) + diffuse / pi (1 - F) lamb, h the bisector, D the
    (mixture) NDF at h and lamb = sum_i a_i max(n_i . wi, 0) of the Lambert term's normals."""
    h = wp.normalize(wi + wo)
    F = schlick(pl.f0, wp.max(wp.dot(wo, h), 0.0))
    return F * (D / (4.0 * wo[2])) + wp.cw_mul(pl.diffuse, wp.vec3(1.0) - F) * (INV_PI * lamb)


@wp.func
def half_xy(wi: wp.vec3, wo: wp.vec3):
    h = wp.normalize(wi + wo)
    return wp.vec2(h[0], h[1])


@wp.func
def shade_fine(n: wp.vec3, wo: wp.vec3, pl: PlaneData, ldir: wp.array(dtype=wp.vec3),
               lrad: wp.array(dtype=wp.vec3)):
    """The fine-scale BRDF (one component at the finest normal n) under every directional light."""
    c = wp.vec3(0.0)
    for j in range(ldir.shape[0]):
        wi = ldir[j]
        if wi[2] > 0.0 and wo[2] > MIN_COS:
            hx = half_xy(wi, wo)
            D = gauss2(hx[0] - n[0], hx[1] - n[1], pl.rough_var)
            c = c + wp.cw_mul(lrad[j], cook_torrance_cos(wi, wo, pl, D, wp.max(wp.dot(n, wi), 0.0)))
    return c


@wp.func
def lobes_ndf(L: Lobes, nl: int, h: wp.vec3):
    """The pixel's NDF at half-vector h for its nl lobes (rows of L: a, mu_x, mu_y, s_xx, s_yy, s_xy),
    sum_k a_k g(h_xy; mu_k, S_k), and the lobes' total weight sum_k a_k."""
    D = float(0.0)
    at = float(0.0)
    for k in range(nl):
        a = L[k, 0]
        at = at + a
        D = D + a * gauss2_cov(h[0] - L[k, 1], h[1] - L[k, 2], L[k, 3], L[k, 4], L[k, 5])
    return D, at


@wp.func
def lobes_lambert(L: Lobes, nl: int, wi: wp.vec3):
    """sum_k a_k max(n_k . wi, 0) over the lobes' mean normals n_k (004 Sec. 3: Lambert with the means)."""
    lamb = float(0.0)
    for k in range(nl):
        lamb = lamb + L[k, 0] * wp.max(wp.dot(lift(L[k, 1], L[k, 2]), wi), 0.0)
    return lamb


@wp.func
def lobes_cos(L: Lobes, nl: int, wi: wp.vec3, wo: wp.vec3, pl: PlaneData):
    """The pixel's BRDF times wi_z for its nl lobes: the mixture NDF and Lambert on the lobes' mean normals."""
    D, at = lobes_ndf(L, nl, wp.normalize(wi + wo))
    return cook_torrance_cos(wi, wo, pl, D, lobes_lambert(L, nl, wi))


@wp.func
def lobes_direct(L: Lobes, nl: int, wo: wp.vec3, pl: PlaneData, ldir: wp.array(dtype=wp.vec3),
                 lrad: wp.array(dtype=wp.vec3)):
    """Radiance towards wo under every directional light (E times the BRDF times wi_z)."""
    c = wp.vec3(0.0)
    for j in range(ldir.shape[0]):
        wi = ldir[j]
        if wi[2] > 0.0 and wo[2] > MIN_COS:
            c = c + wp.cw_mul(lrad[j], lobes_cos(L, nl, wi, wo, pl))
    return c


@wp.func
def sample_pdf(D: float, at: float, h: wp.vec3, wi: wp.vec3, wo: wp.vec3, pl: PlaneData):
    """Solid-angle pdf of ``lobes_sample`` at wi, given the lobes' NDF D at the bisector h and their total
    weight at (``lobes_ndf``): with probability 1 - q the NDF's half-vector reflected (density D / at over
    projected h, times h_z = dp / dw_h, over 4 wo.h = dw_i / dw_h), with probability q = pl.diffuse_pick a
    cosine-weighted direction about the plane's normal (wi_z / pi)."""
    spec = float(0.0)
    if at > 0.0:
        spec = D / at * h[2] / (4.0 * wp.max(wp.dot(wo, h), MIN_COS))
    return (1.0 - pl.diffuse_pick) * spec + pl.diffuse_pick * wp.max(wi[2], 0.0) * INV_PI


@wp.func
def lobes_sample(L: Lobes, nl: int, wo: wp.vec3, pl: PlaneData, u: wp.vec3):
    """A direction wi drawn with density ``sample_pdf`` from uniforms u in [0, 1)^3: u[0] picks the Lambert
    term or, rescaled, a lobe by weight; (u[1], u[2]) place the direction (wi_z <= 0 when the draw leaves the
    hemisphere or its half-vector leaves the unit disk: a lost sample, which the pdf counts)."""
    wi = wp.vec3(0.0, 0.0, -1.0)
    q = pl.diffuse_pick
    if u[0] < q:
        # cosine-weighted about +z (Malley)
        r = wp.sqrt(u[1])
        phi = TWO_PI * u[2]
        wi = wp.vec3(r * wp.cos(phi), r * wp.sin(phi), wp.sqrt(wp.max(1.0 - r * r, 0.0)))
    else:
        at = float(0.0)
        for k in range(nl):
            at = at + L[k, 0]
        x = (u[0] - q) / (1.0 - q) * at         # uniform on [0, at) given that the Lambert term was not picked
        j = int(0)
        acc = L[0, 0]
        while acc < x and j < nl - 1:
            j = j + 1
            acc = acc + L[j, 0]
        # a 2D Gaussian of covariance S_j (Box-Muller, Cholesky factor of S_j)
        r = wp.sqrt(-2.0 * wp.log(wp.max(1.0 - u[1], 1.0e-30)))
        phi = TWO_PI * u[2]
        z0 = r * wp.cos(phi)
        z1 = r * wp.sin(phi)
        l00 = wp.sqrt(L[j, 3])
        l10 = L[j, 5] / l00
        l11 = wp.sqrt(wp.max(L[j, 4] - l10 * l10, 0.0))
        px = L[j, 1] + l00 * z0
        py = L[j, 2] + l10 * z0 + l11 * z1
        r2 = px * px + py * py
        if r2 < 1.0:
            h = wp.vec3(px, py, wp.sqrt(1.0 - r2))
            wi = 2.0 * wp.dot(wo, h) * h - wo
    return wi


@wp.func
def plane_to_world(w: wp.vec3):
    """The plane's tangent frame -> world (inverse of ``to_plane``)."""
    return wp.vec3(w[0], w[2], -w[1])


@wp.func
def env_mis_term(L: Lobes, nl: int, wi: wp.vec3, wo: wp.vec3, pl: PlaneData, env: EnvMapData):
    """L_env(wi) f(wi) / (p_brdf(wi) + p_env(wi)): one sample's share of the balance heuristic (either
    strategy's draw); 0 below the plane."""
    c = wp.vec3(0.0)
    if wi[2] > 0.0:
        uv = env_uv(env, plane_to_world(wi))   # once: the radiance and the pdf need it
        h = wp.normalize(wi + wo)
        D, at = lobes_ndf(L, nl, h)          # once: both the BRDF and the BRDF strategy's pdf need it
        p = sample_pdf(D, at, h, wi, wo, pl) + env_pdf_uv(env, uv)
        if p > 0.0:
            f = cook_torrance_cos(wi, wo, pl, D, lobes_lambert(L, nl, wi))
            c = wp.cw_mul(env_radiance_uv(env, uv), f) / p
    return c


@wp.func
def pair_offset(state: wp.uint32):
    """A pixel's random offset r of its pairs' sequence (``PAIR_ALPHA``), one uniform 32-bit fraction per
    coordinate; returns it and the advanced RNG state (Warp passes the state by value)."""
    r = PairVec()
    for j in range(PAIR_DIMS):
        r[j] = wp.uint32(wp.randi(state))
    return r, state


@wp.func
def pair_uniform(r: PairVec, k: int, j: int):
    """Coordinate j of pair k: frac(r_j + k alpha_j), in fixed point (``PAIR_ALPHA``)."""
    return float((r[j] + wp.uint32(k) * PAIR_ALPHA[j]) >> wp.uint32(8)) * INV_2_24


@wp.func
def lobes_env(L: Lobes, nl: int, wo: wp.vec3, pl: PlaneData, env: EnvMapData, r: PairVec, k0: int, n: int):
    """Radiance towards wo under the environment: pairs k0 .. k0 + n - 1 of the sequence offset by r, each
    one BRDF and one environment sample, combined by the balance heuristic (multiple importance sampling)."""
    c = wp.vec3d(0.0)   # float64: a float32 sum of 1.7e7 pairs stops growing
    if wo[2] > MIN_COS:
        for k in range(k0, k0 + n):
            ub = wp.vec3(pair_uniform(r, k, 0), pair_uniform(r, k, 1), pair_uniform(r, k, 2))
            c = c + wp.vec3d(env_mis_term(L, nl, lobes_sample(L, nl, wo, pl, ub), wo, pl, env))
            ue = wp.vec2(pair_uniform(r, k, 3), pair_uniform(r, k, 4))
            c = c + wp.vec3d(env_mis_term(L, nl, to_plane(env_sample(env, ue)), wo, pl, env))
        c = c / wp.float64(n)
    return wp.vec3(c)


@wp.func
def set_lobe(L: Lobes, k: int, a: float, mx: float, my: float, sxx: float, syy: float, sxy: float):
    """Row k of L = (a, mu_x, mu_y, s_xx, s_yy, s_xy); returns L."""
    L[k, 0] = a
    L[k, 1] = mx
    L[k, 2] = my
    L[k, 3] = sxx
    L[k, 4] = syy
    L[k, 5] = sxy
    return L


@wp.struct
class Footprint:
    lam: float          # fractional mip level, clamped to [-1, levels - 1] (below 0: magnification)
    n: int              # probes along the footprint's major axis (1: one trilinear fetch at the pixel's centre)
    step: wp.vec2       # finest texels between neighbouring probes, along the major axis


@wp.func
def pixel_footprint(cam: CameraData, pl: PlaneData, x: int, y: int, st: wp.vec2):
    """The pixel's footprint from the ray differentials (the rays through the next pixel right and down,
    against the same infinite plane): J = [ds/dx ds/dy] in finest texels per pixel.  Isotropic
    (``max_aniso`` = 1): one probe at log2 of J's larger column + the LOD bias.  Anisotropic: J's singular
    values s1 >= s2 (the pixel box maps to a parallelogram of covariance J J^T / 12, axes s1^2 / 12 and
    s2^2 / 12 along J's left singular vectors), n = ceil(s1 / r) probes along the major axis
    (``ANISO_PROBE_SLACK``), each an isotropic trilinear filter of radius r = max(s2, s1 / max_aniso,
    2^-lod_bias), the last the radius whose level is 0.  With n = 1 the isotropic level stands: for a sheared
    footprint, whose longer column is shorter than s1, the two differ by up to half a level."""
    o = cam.origin
    fp = Footprint()
    fp.n = 1
    fp.step = wp.vec2(0.0, 0.0)
    rho = float(HORIZON_FOOTPRINT)
    dx = ray_dir(cam, float(x) + 1.5, float(y) + 0.5)
    dy = ray_dir(cam, float(x) + 0.5, float(y) + 1.5)
    tx = plane_t(o, dx, pl)
    ty = plane_t(o, dy, pl)
    if tx > 0.0 and ty > 0.0:
        jx = plane_st(o + tx * dx, pl) - st
        jy = plane_st(o + ty * dy, pl) - st
        rho = wp.max(wp.length(jx), wp.length(jy))
        if pl.max_aniso > 1:
            # J J^T = [[p, r], [r, q]]: eigenvalues e +- f, the larger one's eigenvector u
            p = jx[0] * jx[0] + jy[0] * jy[0]
            q = jx[1] * jx[1] + jy[1] * jy[1]
            r = jx[0] * jx[1] + jy[0] * jy[1]
            e = 0.5 * (p + q)
            f = wp.sqrt(0.25 * (p - q) * (p - q) + r * r)
            s1 = wp.sqrt(e + f)
            s2 = wp.sqrt(wp.max(e - f, 0.0))
            u = wp.vec2(1.0, 0.0)
            if p >= q:
                if f > 0.0:
                    u = wp.normalize(wp.vec2(e + f - q, r))
            else:
                u = wp.normalize(wp.vec2(r, e + f - p))
            # a probe no finer than level 0 (level-0 texels are point samples: finer probes add nothing)
            radius = wp.max(wp.max(s2, s1 / float(pl.max_aniso)), wp.pow(2.0, -pl.lod_bias))
            n = wp.clamp(int(wp.ceil(s1 / radius - ANISO_PROBE_SLACK)), 1, pl.max_aniso)
            if n > 1:
                rho = radius
                fp.n = n
                # n probes spaced d apart have variance (n^2 - 1) d^2 / 12 along u; with each probe's own
                # r^2 / 12 that is the box's s1^2 / 12
                fp.step = u * wp.sqrt(wp.max(s1 * s1 - radius * radius, 0.0) / float(n * n - 1))
    fp.lam = wp.clamp(wp.log2(wp.max(rho, 1.0e-6)) + pl.lod_bias, -1.0, float(pl.levels - 1))
    return fp


@wp.func
def probe_offset(fp: Footprint, j: int):
    """Finest-texel offset of probe j of the footprint from the pixel's centre (probes centred on it)."""
    return (float(j) - 0.5 * float(fp.n - 1)) * fp.step


@functools.cache  # one kernel per method kind and light set: Warp compiles each once
def _filtered_kernel(code: int, with_env: bool, with_lights: bool):
    @wp.kernel(module="unique", enable_backward=False)
    def filtered_kernel(cam: CameraData, pl: PlaneData, lw: wp.array(dtype=wp.int32),
                        lh: wp.array(dtype=wp.int32), loff: wp.array(dtype=wp.int32),
                        gmm: wp.array(dtype=wp.vec4), nmean: wp.array(dtype=wp.vec3),
                        nm2: wp.array(dtype=wp.vec3), ldir: wp.array(dtype=wp.vec3),
                        lrad: wp.array(dtype=wp.vec3), env: EnvMapData, env_spp: int, seed: int, offset: int,
                        depth: wp.array(dtype=wp.float32), out: wp.array(dtype=wp.vec3),
                        level: wp.array(dtype=wp.float32)):
        i = wp.tid() + offset
        x = i % cam.width
        y = i / cam.width
        d = ray_dir(cam, float(x) + 0.5, float(y) + 0.5)
        t = plane_t(cam.origin, d, pl)
        if t > 0.0 and t < depth[i]:
            p = cam.origin + t * d
            if inside(p, pl):
                depth[i] = t
                st = plane_st(p, pl)
                fp = pixel_footprint(cam, pl, x, y, st)
                lam_px = fp.lam
                level[i] = lam_px
                lam = wp.max(lam_px, 0.0)
                s = st[0]
                tt = st[1]
                wo = to_plane(-d)
                L = Lobes()
                nl = int(0)
                if wp.static(code == 0):
                    # GMM: trilinear filtering of the stored moments, per component (004 Sec. 4.2), averaged over
                    # the footprint's probes
                    for k in range(pl.components):
                        acc = wp.vec4(0.0)
                        for j in range(fp.n):
                            dj = probe_offset(fp, j)
                            acc += trilinear4(gmm, lw, lh, loff, pl.levels, lam, s + dj[0], tt + dj[1],
                                              pl.components, k)
                        g = recover(acc / float(fp.n))
                        if g[0] > 0.0:
                            # the builder's floor is numerical, not surface: a flat footprint adds nothing
                            var = wp.max(g[3] - VARIANCE_FLOOR, 0.0) + pl.rough_var
                            L = set_lobe(L, nl, g[0], g[1], g[2], var, var, 0.0)
                            nl = nl + 1
                else:
                    m = wp.vec3(0.0)
                    q2 = wp.vec3(0.0)
                    for j in range(fp.n):
                        dj = probe_offset(fp, j)
                        m += trilinear3(nmean, lw, lh, loff, pl.levels, lam, s + dj[0], tt + dj[1])
                        if wp.static(code == 2):
                            q2 += trilinear3(nm2, lw, lh, loff, pl.levels, lam, s + dj[0], tt + dj[1])
                    m = m / float(fp.n)
                    ln = wp.length(m)
                    n = wp.vec3(0.0, 0.0, 1.0)
                    if ln > MIN_MEAN_LENGTH:
                        n = m / ln
                    var = pl.rough_var
                    if wp.static(code == 1):
                        # Toksvig: per-axis variance (1 - |n|) / |n| of the mean normal's length
                        lc = wp.max(ln, MIN_MEAN_LENGTH)
                        var = var + wp.max(1.0 - lc - TOKSVIG_LENGTH_EPS, 0.0) / lc
                    mx = n[0]
                    my = n[1]
                    sxx = var
                    syy = var
                    sxy = float(0.0)
                    if wp.static(code == 2):
                        # LEAN-style: filtered first and second moments of the projected normals
                        q2 = q2 / float(fp.n)
                        mx = m[0]
                        my = m[1]
                        sxx = wp.max(q2[0] - mx * mx, 0.0) + pl.rough_var
                        syy = wp.max(q2[1] - my * my, 0.0) + pl.rough_var
                        sxy = q2[2] - mx * my
                        lim = LEAN_CORRELATION_MAX * wp.sqrt(sxx * syy)
                        sxy = wp.clamp(sxy, -lim, lim)
                    L = set_lobe(L, 0, 1.0, mx, my, sxx, syy, sxy)
                    nl = 1
                # magnification (a pixel smaller than a texel): level 0 holds point samples of the normal field,
                # so blend towards the fine-scale BRDF at the bilinear normal, fully at half a texel (level -1);
                # the shading is linear in the lobe weights, so the blend is one more lobe
                w_fine = wp.clamp(-lam_px, 0.0, 1.0)
                if w_fine > 0.0:
                    for k in range(nl):
                        L[k, 0] = (1.0 - w_fine) * L[k, 0]
                    nf = wp.normalize(fetch3(nmean, lw, lh, loff, 0, s, tt))
                    L = set_lobe(L, nl, w_fine, nf[0], nf[1], pl.rough_var, pl.rough_var, 0.0)
                    nl = nl + 1
                c = wp.vec3(0.0)
                if wp.static(with_lights):   # a scene without lights compiles no light loop
                    c = lobes_direct(L, nl, wo, pl, ldir, lrad)
                if wp.static(with_env):
                    r, state = pair_offset(wp.rand_init(seed, i))
                    c = c + lobes_env(L, nl, wo, pl, env, r, 0, env_spp)
                out[i] = c

    return filtered_kernel


@functools.cache
def _ground_truth_kernel(with_env: bool, with_lights: bool):
    @wp.kernel(module="unique", enable_backward=False)
    def ground_truth_kernel(cam: CameraData, pl: PlaneData, lw: wp.array(dtype=wp.int32),
                            lh: wp.array(dtype=wp.int32), loff: wp.array(dtype=wp.int32),
                            nmean: wp.array(dtype=wp.vec3), ldir: wp.array(dtype=wp.vec3),
                            lrad: wp.array(dtype=wp.vec3), env: EnvMapData, spp: int, seed: int, offset: int,
                            depth: wp.array(dtype=wp.float32), out: wp.array(dtype=wp.vec3)):
        """spp jittered rays per pixel (stratified on a g x g grid, g = floor(sqrt(spp)), the rest uniform),
        each shaded with the fine-scale BRDF at the bilinearly fetched finest normal (under the environment:
        one BRDF and one environment sample per ray, balance heuristic); box pixel filter over the rays that
        hit the plane.  A pixel belongs to this plane when its centre ray hits it in front of ``depth``; if
        none of its jittered rays does (a sliver of plane), the centre ray alone is shaded."""
        i = wp.tid() + offset
        x = i % cam.width
        y = i / cam.width
        d0 = ray_dir(cam, float(x) + 0.5, float(y) + 0.5)
        t0 = plane_t(cam.origin, d0, pl)
        if t0 > 0.0 and t0 < depth[i] and inside(cam.origin + t0 * d0, pl):
            depth[i] = t0
            state = wp.rand_init(seed, i)
            g = int(wp.sqrt(float(spp)))
            r = PairVec()
            if wp.static(with_env):
                r, state = pair_offset(state)   # ray k takes pair k of the pixel's sequence
            c = wp.vec3d(0.0)   # float64: a float32 sum of 1.7e7 rays stops growing
            hits = int(0)
            for k in range(spp + 1):   # ray spp: the centre ray, only when no jittered ray hit the plane
                jx = float(0.5)
                jy = float(0.5)
                if k < spp:
                    jx = wp.randf(state)
                    jy = wp.randf(state)
                    if k < g * g:
                        jx = (float(k % g) + jx) / float(g)
                        jy = (float(k / g) + jy) / float(g)
                elif hits > 0:
                    break
                d = ray_dir(cam, float(x) + jx, float(y) + jy)
                t = plane_t(cam.origin, d, pl)
                if t > 0.0:
                    p = cam.origin + t * d
                    if inside(p, pl):
                        st = plane_st(p, pl)
                        n = wp.normalize(fetch3(nmean, lw, lh, loff, 0, st[0], st[1]))
                        wo = to_plane(-d)
                        if wp.static(with_lights):
                            c = c + wp.vec3d(shade_fine(n, wo, pl, ldir, lrad))
                        if wp.static(with_env):
                            L = set_lobe(Lobes(), 0, 1.0, n[0], n[1], pl.rough_var, pl.rough_var, 0.0)
                            c = c + wp.vec3d(lobes_env(L, 1, wo, pl, env, r, k, 1))
                        hits = hits + 1
            # the plane's mean over the part of the pixel it covers: what is behind it is not blended in
            out[i] = wp.vec3(c / wp.float64(hits))

    return ground_truth_kernel


@wp.kernel(module="unique", enable_backward=False)
def background_distance_kernel(cam: CameraData, z: wp.array(dtype=wp.float32), depth: wp.array(dtype=wp.float32)):
    """A background's camera-space depth z (0: empty) -> distance along the pixel's centre ray, the planes'
    depth test (``NO_HIT`` where the background is empty)."""
    i = wp.tid()
    t = float(_NO_HIT)
    if z[i] > 0.0:
        d = ray_dir(cam, float(i % cam.width) + 0.5, float(i / cam.width) + 0.5)
        t = z[i] / wp.dot(d, cam.forward)   # z = t (d . forward) for a unit d
    depth[i] = t


@wp.kernel(module="unique", enable_backward=False)
def plane_distance_kernel(cam: CameraData, pl: PlaneData, depth: wp.array(dtype=wp.float32)):
    """Lower depth[i] to the distance along pixel i's centre ray where it hits the plane (the renderers' test)."""
    i = wp.tid()
    d = ray_dir(cam, float(i % cam.width) + 0.5, float(i / cam.width) + 0.5)
    t = plane_t(cam.origin, d, pl)
    if t > 0.0 and t < depth[i]:
        if inside(cam.origin + t * d, pl):
            depth[i] = t


@wp.kernel(module="unique", enable_backward=False)
def fetch_gmm_kernel(gmm: wp.array(dtype=wp.vec4), lw: wp.array(dtype=wp.int32), lh: wp.array(dtype=wp.int32),
                     loff: wp.array(dtype=wp.int32), levels: int, K: int, st: wp.array(dtype=wp.vec3),
                     out: wp.array(dtype=wp.vec4)):
    """Test hook: the renderer's trilinear fetch + recovery at (s, t, level) = st[i], every component."""
    i, k = wp.tid()
    q = st[i]
    out[i * K + k] = recover(trilinear4(gmm, lw, lh, loff, levels, q[2], q[0], q[1], K, k))


@wp.kernel(module="unique", enable_backward=False)
def gmm_ndf_kernel(params: wp.array(dtype=wp.vec4), K: int, rough_var: float, h: wp.array(dtype=wp.vec3),
                   out: wp.array(dtype=wp.float32)):
    """Test hook: the mixture NDF sum_k a_k g(h_xy; mu_k, s_k^2 + rough_var) at directions h (``gmm_ndf``)."""
    i = wp.tid()
    d = float(0.0)
    for k in range(K):
        g = params[k]
        if g[0] > 0.0:
            d = d + g[0] * gauss2(h[i][0] - g[1], h[i][1] - g[2], g[3] + rough_var)
    out[i] = d


@wp.kernel(module="unique", enable_backward=False)
def pair_uniforms_kernel(seed: int, pixel: int, out: wp.array2d(dtype=wp.float32)):
    """Test hook: coordinate j of pair k of a pixel's sequence (``lobes_env``'s uniforms)."""
    k, j = wp.tid()
    r, state = pair_offset(wp.rand_init(seed, pixel))
    out[k, j] = pair_uniform(r, k, j)


# ---------------------------------------------------------------------------------------------------
# Mipmaps (precompute-time, numpy)

def normal_moment_mipmap(normals) -> list:
    """Box-filtered normal mipmap of unit normals (H, W, 3): levels finest first (ceil-halving to 1x1, as
    ``precompute.gmm_mipmap.level_shapes``), each a pair (mean normal (h, w, 3), second moments of the
    projected normals (h, w, 3) = (E[x^2], E[y^2], E[xy])), means over the texel's clipped footprint."""
    n = numeric_array(normals, "normals", "unit normals (H, W, 3)")
    if n.ndim != 3 or n.shape[2] != 3 or n.size == 0:   # an empty map never halved to 1x1: a loop that filled memory
        raise WarpbwError(f"normals: expected unit normals (H, W, 3) of at least 1x1 texels, got shape {n.shape}")
    off = np.abs(np.linalg.norm(n, axis=-1) - 1.0)   # NaN too: it spread to every level above its texel
    if not np.all(off <= UNIT_LENGTH_TOL):
        k = int(np.argmax(~(off <= UNIT_LENGTH_TOL)))
        at = tuple(int(i) for i in np.unravel_index(k, off.shape))
        raise WarpbwError(f"normals: expected unit normals (length 1 within {UNIT_LENGTH_TOL:g}), "
                          f"{int(np.sum(~(off <= UNIT_LENGTH_TOL)))} of {off.size} are not (the first, texel {at}: "
                          f"{n.reshape(-1, 3)[k].tolist()})")
    q = np.concatenate([n, n[..., :1] ** 2, n[..., 1:2] ** 2, n[..., :1] * n[..., 1:2]], axis=-1)
    sums, counts = q, np.ones(q.shape[:2])
    out = [(q[..., :3].astype(np.float32), q[..., 3:].astype(np.float32))]
    while sums.shape[:2] != (1, 1):
        h, w = sums.shape[:2]
        ph, pw = h + h % 2, w + w % 2
        S = np.zeros((ph, pw, 6))
        S[:h, :w] = sums
        C = np.zeros((ph, pw))
        C[:h, :w] = counts
        sums = S.reshape(ph // 2, 2, pw // 2, 2, 6).sum(axis=(1, 3))
        counts = C.reshape(ph // 2, 2, pw // 2, 2).sum(axis=(1, 3))
        mean = sums / counts[..., None]
        out.append((mean[..., :3].astype(np.float32), mean[..., 3:].astype(np.float32)))
    return out


@dataclass
class _GmmSource:
    """What ``load_or_build`` needs of a GMM mipmap's source: its data and a digest of data + parameters (data None:
    the map not read, ``gmm_header_problem``)."""
    data: np.ndarray | None
    kind: str
    scale: float
    unaligned: bool
    name: str
    content_hash: str
    components: int
    prior: float

    @property
    def digest(self) -> str:
        return (f"{self.content_hash}-{self.kind}-s{float(self.scale)!r}-K{self.components}-c{float(self.prior)!r}-"
                f"{'unaligned' if self.unaligned else 'aligned'}")


def _build_gmm(src: _GmmSource, progress: bool = True):
    from precompute.gmm_mipmap import build_gmm_mipmap, fit_settings

    k = fit_settings()   # what a cache entry records and is compared with (load_or_build)
    return build_gmm_mipmap(src.data, kind=src.kind, components=src.components, prior=src.prior,
                            scale=src.scale, seed=k["seed"], progress=progress, unaligned=src.unaligned,
                            max_samples=k["max_samples"], refine_sweeps=k["refine_sweeps"])


def _write_gmm(path, mip, src: _GmmSource, force: bool = False):
    from precompute.gmm_mipmap import write_gmm_mipmap

    return write_gmm_mipmap(path, mip, src.name, src.content_hash, force=force)


@dataclass
class _Mips:
    """One material's mipmaps on the device."""
    shape: tuple
    levels: int
    lw: wp.array
    lh: wp.array
    loff: wp.array
    nmean: wp.array
    nm2: wp.array
    gmm: dict = field(default_factory=dict)        # method -> (wp.array of vec4, K)
    flat: bool = False     # no normal map: every filtered method shades the plain BRDF (the "fixed" kernel), no GMM


@dataclass
class FilteringScene:
    """A scene's planes and their materials' mipmaps, ready to render any method."""
    scene: Scene
    device: str
    mips: dict                 # material name -> _Mips
    ldir: wp.array             # light directions in the plane frame
    lrad: wp.array
    env: object                # warpbw.envmap.EnvMap of the scene's [environment], or None
    notes: dict                # per material: map shape, GMM origin ("file", "cache", "built"), times
    precompute_time_s: float   # time to load the maps and load or build every mipmap


def plane_objects(scene: Scene) -> list:
    """The scene's planes; a scene without one, or with spheres and meshes beside them, is refused: this renderer
    draws planes only (``warpbw.pipeline.render_with_planes``, ``warpbw render``, draw planes beside the others)."""
    check_instance(scene, Scene, "plane_objects: scene", "a Scene (warpbw.scene.parse_scene's)")
    if not any(isinstance(o, PlaneObject) for o in scene.objects):
        raise WarpbwError(f"{scene.source}: no [[object]] is a plane (the filtering renderer draws planes, shape = "
                          "\"plane\"; render spheres and meshes with warpbw render or warpbw.pipeline)")
    planes = []
    for i, o in enumerate(scene.objects):
        if not isinstance(o, PlaneObject):
            # it said "a scene with planes renders planes only", of a scene warpbw render draws whole
            raise WarpbwError(f"{scene.source}: [[object]] #{i + 1}: not a plane, and the filtering renderer draws "
                              "planes only (for planes beside spheres and meshes use warpbw render, or "
                              "warpbw.pipeline.render_with_planes)")
        planes.append(o)
    return planes


def check_plane_reach(camera: Camera, planes, source: str) -> None:
    """Refuse a camera whose distance to a plane's far corner lies outside ``PLANE_REACH_MIN`` to
    ``PLANE_REACH_MAX``: float32 intersection would leave the plane's pixels empty without a word; and a camera
    and plane so far from the origin that float32 cannot place them (``warpbw.errors.check_coordinate_spacing``)."""
    o = np.asarray(camera.position, np.float64)
    for p in planes:
        h = 0.5 * float(p.size)
        corners = np.asarray(p.center, np.float64) + np.array([[a * h, 0.0, b * h] for a in (-1, 1) for b in (-1, 1)])
        with np.errstate(over="ignore"):
            reach = float(np.max(np.linalg.norm(corners - o, axis=1)))
        check_camera_reach(reach, PLANE_REACH_MIN, PLANE_REACH_MAX, f"the far corner of the {p.describe()}", "plane",
                           source=source)
        coord = float(np.abs(np.concatenate([corners.ravel(), o])).max())
        check_coordinate_spacing(coord, float(p.size), f"the {p.describe()}", source)


def _load_normals(scene: Scene, name: str):
    """The material's finest normals (H, W, 3), its source array, kind, scale, display name and hash."""
    from precompute.gmm_mipmap import load_map
    from precompute.surfaces import height_to_normals
    from warpbw.scene import file_digest

    m = scene.materials[name]
    key = f"[material.{name}].normal_map"
    if m.normal_map is None:       # flat: a 1x1 height field
        data = np.zeros((1, 1))
        return height_to_normals(data), data, "height", 1.0, "flat", "flat"
    try:
        data = load_map(m.normal_map, m.normal_map_kind)
        normals = height_to_normals(data, m.normal_map_scale) if m.normal_map_kind == "height" else data
    except WarpbwError as exc:
        raise WarpbwError(f"{scene.source}: {key}: {exc}") from None
    return normals, data, m.normal_map_kind, m.normal_map_scale, m.normal_map.name, file_digest(m.normal_map)


def _gmm_source(scene: Scene, name: str, data, kind, scale, src_name, digest, unaligned: bool) -> _GmmSource:
    from precompute.gmm_mipmap import DEFAULT_PRIOR

    m = scene.materials[name]
    # the unaligned baseline fits with c = 0 whatever the material's prior: its cache entry does not depend on it
    return _GmmSource(None if data is None else np.asarray(data), kind, float(scale), unaligned, src_name, digest,
                      int(m.gmm_components), DEFAULT_PRIOR if unaligned else float(m.gmm_prior))


def check_gmm_files(scene: Scene, methods=METHODS) -> dict:
    """Read the ``gmm`` file of each plane material of ``scene`` when ``methods`` (a name or several) shade with it
    (``gmm_aligned``), and check it as ``prepare_filtering`` reads it: its format and version, its levels, and that it
    was fitted to the material's normal map (by content and size) with the material's kind, scale, components and
    prior.  A wrong file is one line naming the scene, the material's key and the file, and the command that
    rebuilds it.  Returns ``{material: (GmmMipmap, seconds the read took, the normal map as _load_normals gives
    it)}``, which ``prepare_filtering`` takes as ``gmm_files`` instead of reading the files and the maps again; {}
    when no method reads them."""
    scene = check_scene(_as_scene(scene))
    if "gmm_aligned" not in ((methods,) if isinstance(methods, str) else tuple(methods)):
        return {}
    out = {}
    for name in dict.fromkeys(o.material for o in scene.objects if isinstance(o, PlaneObject)):
        m = scene.materials[name]
        if m.gmm is None:
            continue
        loaded = _load_normals(scene, name)   # (normals, data, kind, scale, name, digest): read once, kept
        src = _gmm_source(scene, name, *loaded[1:], False)
        t0 = time.perf_counter()   # the file's read, as _load_gmm's time would count it
        try:
            out[name] = (_read_gmm_checked(scene, name)(m.gmm, src), time.perf_counter() - t0, loaded)
        except WarpbwError as exc:
            raise _gmm_error(scene, name, exc) from None
    return out


def _gmm_error(scene: Scene, name: str, exc: WarpbwError) -> WarpbwError:
    """The error of a material's gmm file, naming the scene and the key (once)."""
    return exc if str(exc).startswith(scene.source) else WarpbwError(f"{scene.source}: [material.{name}].gmm: {exc}")


def _load_gmm(scene: Scene, name: str, data, kind, scale, src_name, digest, unaligned: bool, cache, progress):
    from precompute.brdf_sampling import load_or_build
    from precompute.gmm_mipmap import GMM_UNRECORDED, GMM_VERSION, fit_settings

    m = scene.materials[name]
    src = _gmm_source(scene, name, data, kind, scale, src_name, digest, unaligned)
    explicit = None if unaligned else m.gmm
    try:
        mip, origin = load_or_build(src, explicit, cache, GMM_CACHE_PREFIX, GMM_VERSION, _read_gmm_checked(scene, name),
                                    _build_gmm, _write_gmm, progress, fit_settings(), GMM_UNRECORDED)
    except WarpbwError as exc:
        if explicit is not None:
            raise _gmm_error(scene, name, exc) from None
        raise
    return mip, origin


def _read_gmm_checked(scene: Scene, name: str):
    """The reader for ``load_or_build``: an explicit file must match the material's map and parameters."""
    def read(path, src: _GmmSource):
        from precompute.gmm_mipmap import read_gmm_mipmap

        mip = read_gmm_mipmap(path)
        problem = _gmm_file_problem(mip, src, _gmm_rebuild(scene, name, src, path))
        if problem is not None:
            raise WarpbwError(f"{path}: {problem}")
        return mip
    return read


def _gmm_rebuild(scene: Scene, name: str, src: _GmmSource, path) -> str:
    """The command that rebuilds material ``name``'s gmm file ``path`` from its own map (its full path: the scene's
    folder need not be the current one) with the material's parameters, as it is printed."""
    from precompute.gmm_mipmap import rebuild_command

    return rebuild_command(scene.materials[name].normal_map or src.name, {
        "kind": src.kind, "scale": src.scale, "components": src.components, "prior": src.prior,
        "unaligned": src.unaligned}, path)


def _gmm_file_problem(mip, src: _GmmSource, rebuild: str) -> str | None:
    """Why the GMM mipmap ``mip`` (a ``GmmMipmap``, or its file's header as one: ``gmm_header_problem``) is not the
    one ``src`` asks for, ending in what mends it (``rebuild``: the command that builds the right one); None when
    they agree.  ``src.data`` None: the map's size is unknown and taken as the file's (its content is checked)."""
    from precompute.gmm_mipmap import ROW_SPACING, ROW_SPACING_KEY

    if mip.source_hash != src.content_hash:   # the file's header names the map it was fitted to, by content
        return (f"built from {mip.source or 'another map'} with different content than the material's normal_map "
                f"{src.name} (rebuild it with: {rebuild})")
    want = tuple(mip.shape) if src.data is None else tuple(src.data.shape[:2])
    if tuple(mip.shape) != want:
        return (f"built from a {mip.shape[1]}x{mip.shape[0]} map, but the normal_map is {want[1]}x{want[0]} (rebuild "
                f"it with: {rebuild})")
    if (src.kind == "height" and want[0] != want[1]
            and mip.kind == "height" and mip.extra.get(ROW_SPACING_KEY) != ROW_SPACING):
        return (f"built from this {want[1]}x{want[0]} height map with its rows 1/{want[1]} apart (an earlier "
                f"warpbw's build), where the plane lays them 1/{want[0]} apart (rebuild it with: {rebuild})")
    if mip.kind != src.kind or (src.kind == "height" and not math.isclose(mip.scale, src.scale, rel_tol=1e-6)):
        return (f"built with --kind {mip.kind} --scale {mip.scale:g}, but the material has normal_map_kind = "
                f"{src.kind!r}, normal_map_scale = {src.scale:g} (rebuild it with: {rebuild})")
    if mip.unaligned and not src.unaligned:  # the material's gmm file is the aligned mipmap (004 Sec. 4.1)
        return ("built with --unaligned (the independent-EM baseline), but a material's gmm file must be the aligned "
                f"GMM mipmap (rebuild it without --unaligned: {rebuild})")
    if mip.unaligned != src.unaligned:
        return "an aligned GMM mipmap, but the unaligned baseline was asked for"
    if mip.components != src.components:
        return (f"built with --components {mip.components}, but the material has gmm_components = {src.components} "
                f"(the unaligned baseline is built with as many; set gmm_components = {mip.components} or rebuild it "
                f"with: {rebuild})")
    if not mip.unaligned and not math.isclose(mip.prior, src.prior, rel_tol=1e-9):
        return (f"built with --prior {mip.prior:g}, but the material has gmm_prior = {src.prior:g} (set gmm_prior = "
                f"{mip.prior:g} or rebuild it with: {rebuild})")
    return None


def gmm_header_problem(scene: Scene, name: str, path) -> str | None:
    """Why a render refuses ``path`` as material ``name``'s ``gmm`` file, as the file's header
    (``precompute.assetfile.read_header``, read as ``precompute.gmm_mipmap.header_fields`` reads it for the
    render's reader) and the material's normal map (by content) tell, in the words of ``check_gmm_files``' reader;
    None where they agree.  Its levels are not read (``warpbw info`` reads headers: a mipmap may take hundreds of
    MB), nor the map's pixels (its size is taken as the file's once its content matches); a header that records no
    component count is taken to hold the material's (the reader takes its levels')."""
    from types import SimpleNamespace

    from precompute.assetfile import read_header
    from precompute.gmm_mipmap import GMM_FORMAT, header_fields, rebuild_command
    from warpbw.scene import file_digest

    scene = check_scene(_as_scene(scene))
    m = scene.materials.get(name) if isinstance(name, str) else None
    if m is None or m.normal_map is None:   # a KeyError, or an AttributeError on the missing map, before
        maps = [k for k, v in scene.materials.items() if v.normal_map is not None]
        raise WarpbwError(f"gmm_header_problem: name: expected a material of {scene.source} with a normal_map "
                          f"({', '.join(maps) or 'it has none'}), got {name!r}")
    path = check_path(path, "gmm_header_problem: path")
    if not path.is_file():
        return "file not found" if not path.exists() else "is not a file"
    header = read_header(path)
    if header is None:   # was "is a None file"
        return (f"not a warpbw asset file, or a damaged one (expected a {GMM_FORMAT} file written by "
                "warpbw-precompute; build one with: warpbw-precompute gmm)")
    if header.get("format") != GMM_FORMAT:
        return f"is a {header.get('format')!r} file, expected {GMM_FORMAT!r} (build one with: warpbw-precompute gmm)"
    try:
        fields = header_fields(header, m.gmm_components)
        shape = header.get("params", {}).get("shape")
    except (TypeError, ValueError, AttributeError):   # the reader's words for a hand-edited header
        hint = rebuild_command(header.get("source", "MAP"), header.get("params"))
        return f"GMM mipmap with non-numeric levels or parameters (rebuild it with: {hint})"
    mip = SimpleNamespace(**fields, shape=tuple(shape) if isinstance(shape, list) and len(shape) == 2 else (0, 0))
    src = _gmm_source(scene, name, None, m.normal_map_kind, m.normal_map_scale, m.normal_map.name,
                      file_digest(m.normal_map), False)
    return _gmm_file_problem(mip, src, _gmm_rebuild(scene, name, src, path))


def _level_arrays(shapes, device):
    off = np.concatenate([[0], np.cumsum([h * w for h, w in shapes])[:-1]]).astype(np.int32)
    return (wp.array(np.array([w for _, w in shapes], np.int32), dtype=wp.int32, device=device),
            wp.array(np.array([h for h, _ in shapes], np.int32), dtype=wp.int32, device=device),
            wp.array(off, dtype=wp.int32, device=device))


def _gmm_array(levels, device):
    flat = np.concatenate([np.asarray(q, np.float32).reshape(-1, 4) for q in levels])
    return wp.array(flat, dtype=wp.vec4, device=device), int(levels[0].shape[2])


def scene_environment(scene: Scene, device: str = "cpu"):
    """The scene's ``[environment]`` loaded on ``device`` (an ``EnvMap``; None without one); a file it cannot load is
    refused in one line naming the scene."""
    if scene.environment is None:
        return None
    try:
        return load_environment(scene.environment, device)
    except WarpbwError as exc:
        raise WarpbwError(f"{scene.source}: [environment]: {exc}") from None


def prepare_filtering(scene: Scene, methods=METHODS, device: str = "cpu", progress: bool = False,
                      cache: Path | None = None, env=None, gmm_files: dict | None = None) -> FilteringScene:
    """Load every plane material's normal map and the mipmaps ``methods`` need: the box-filtered normal
    mipmap (always: the ground truth reads its finest level) and, for gmm_aligned / gmm_unaligned, the GMM
    mipmap from the material's ``gmm`` file or the cache, else built (and cached).  ``env``: the scene's
    ``[environment]`` already loaded on ``device`` (``warpbw.envmap.EnvMap``, as another renderer of the same
    scene holds it), used instead of loading it again.  The materials' ``gmm`` files are read and checked first
    (``check_gmm_files``), before the environment and any mipmap; ``gmm_files``: what ``check_gmm_files(scene,
    methods)`` returned, taken instead of reading them again.  The FilteringScene holds a checked copy of ``scene``
    (``warpbw.scene.check_scene``); ``methods`` may be one method's name."""
    scene = check_scene(_as_scene(scene))
    if isinstance(methods, str):   # "lean" was taken letter by letter: filter method 'l'
        methods = (methods,)
    progress = check_flag(progress, "progress")
    planes = plane_objects(scene)
    unknown = [m for m in methods if m not in ALL_METHODS]
    if unknown:
        raise WarpbwError(f"filter method {unknown[0]!r}: expected one of {', '.join(ALL_METHODS)}")
    check_device(device)
    t0 = time.perf_counter()
    if env is not None and scene.environment is None:
        raise WarpbwError(f"{scene.source}: env: given a loaded environment, but the scene has no [environment]")
    if gmm_files is None:   # first: a wrong file is refused before any other work
        gmm_files = check_gmm_files(scene, methods)
    if env is None:   # first: a bad file fails before any mipmap is built
        env = scene_environment(scene, device)
    if env is not None:   # the planes sample it (one given may have been loaded without its distribution)
        ensure_sampling(env)
    mips, notes = {}, {}
    for name in dict.fromkeys(p.material for p in planes):
        normals, data, kind, scale, src_name, digest = (gmm_files[name][2] if name in gmm_files   # read already
                                                        else _load_normals(scene, name))
        levels = normal_moment_mipmap(normals)
        shapes = [lv[0].shape[:2] for lv in levels]
        lw, lh, loff = _level_arrays(shapes, device)
        nmean = wp.array(np.concatenate([lv[0].reshape(-1, 3) for lv in levels]), dtype=wp.vec3, device=device)
        nm2 = wp.array(np.concatenate([lv[1].reshape(-1, 3) for lv in levels]), dtype=wp.vec3, device=device)
        flat = scene.materials[name].normal_map is None
        mp = _Mips(tuple(shapes[0]), len(shapes), lw, lh, loff, nmean, nm2, flat=flat)
        note = {"map": list(shapes[0]), "levels": len(shapes), "source": src_name}
        if flat:
            note["shaded_as"] = FLAT_SHADED_AS
        for method in ("gmm_aligned", "gmm_unaligned"):
            if method in methods and not flat:
                tb = time.perf_counter()
                if method == "gmm_aligned" and name in gmm_files:   # read and checked already
                    mip, t_read, _ = gmm_files[name]
                    origin, tb = "file", tb - t_read
                else:
                    mip, origin = _load_gmm(scene, name, data, kind, scale, src_name, digest,
                                            method == "gmm_unaligned", cache, progress)
                mp.gmm[method] = _gmm_array(mip.levels, device)
                note[method] = {"origin": origin, "time_s": round(time.perf_counter() - tb, 6),
                                "components": int(mip.components), "prior": 0.0 if mip.unaligned else float(mip.prior),
                                "seed": int(mip.seed)}   # the clustering's: two fits of one map differ by it
                if origin == "file":   # which one (a cache entry or a fit is keyed by the map's content)
                    note[method]["file"] = str(scene.materials[name].gmm)
        mips[name] = mp
        notes[name] = note
    ldir = np.array([[d[0], -d[2], d[1]] for d in (li.direction for li in scene.lights)], np.float32).reshape(-1, 3)
    lrad = np.array([li.radiance for li in scene.lights], np.float32).reshape(-1, 3)
    return FilteringScene(scene, device, mips, wp.array(ldir, dtype=wp.vec3, device=device),
                          wp.array(lrad, dtype=wp.vec3, device=device), env, notes, time.perf_counter() - t0)


# ---------------------------------------------------------------------------------------------------
# Rendering

@dataclass
class Background:
    """What the planes are drawn over (``render_filtering``'s ``background``): another renderer's image of the
    scene's spheres and meshes and their camera-space depth, the G-buffer's (0 where nothing was hit)."""
    image: np.ndarray       # (H, W, 3) float32 linear radiance
    depth: np.ndarray       # (H, W) float32 distance along the camera's forward axis, 0 = empty


@dataclass
class FilterResult:
    image: np.ndarray       # (H, W, 3) float32 linear radiance (over the background, when one was given)
    coverage: np.ndarray    # (H, W) bool: the pixel's centre ray hits a plane (in front of the background)
    level: np.ndarray       # (H, W) float32 fractional mip level in [-1, levels - 1] (0 for the ground truth and
                            # uncovered pixels; below 0: magnified, blended towards the fine-scale BRDF)
    time_s: float           # kernel time of the frame (launches + synchronise)
    method: str
    stats: dict

    @property
    def aovs(self) -> dict:
        """The per-pixel maps by name, ``{"level": level}``, as ``warpbw.pipeline.RenderResult.aovs`` holds the
        adaptive renderer's: code that reads one result reads the other the same way.  (``stats["time_s"]`` stays
        the frame's kernel time, a float; ``RenderResult``'s is a dict by stage: changing it would break callers.)"""
        return {"level": self.level}


def _plane_data(p: PlaneObject, m, mp: _Mips, K: int, lod_bias: float = LOD_BIAS,
                max_aniso: int = DEFAULT_ANISOTROPY) -> PlaneData:
    pl = PlaneData()
    pl.center = wp.vec3(*p.center)
    pl.size = float(p.size)
    pl.tiling = float(m.tiling)
    pl.map_h, pl.map_w = int(mp.shape[0]), int(mp.shape[1])
    pl.levels = int(mp.levels)
    pl.components = int(K)
    pl.f0 = wp.vec3(*m.f0)
    pl.diffuse = wp.vec3(*m.diffuse)
    pl.rough_var = roughness_variance(m.roughness)
    pl.lod_bias = float(lod_bias)
    pl.max_aniso = int(max_aniso)
    pl.diffuse_pick = diffuse_pick(m.diffuse, m.f0)
    return pl


def diffuse_pick(diffuse, f0) -> float:
    """Probability that the BRDF strategy draws a cosine-weighted direction (``DIFFUSE_PICK_MIN``)."""
    for name, v in (("diffuse", diffuse), ("f0", f0)):   # NaN gave 0.5, inf NaN, (0.5, 0.5) numpy's dot error
        rgb = numeric_array(v, f"diffuse_pick: {name}", "an RGB triple")
        if rgb.shape != (3,) or not (np.all(np.isfinite(rgb)) and np.all(rgb >= 0.0)):
            raise WarpbwError(f"diffuse_pick: {name}: expected three finite numbers >= 0, got {np.asarray(v).tolist()}")
    ld = float(np.dot(LUMINANCE_RGB, diffuse))
    ls = float(np.dot(LUMINANCE_RGB, f0))
    q = ld / (ld + ls) if ld + ls > 0.0 else 0.5
    return min(max(q, DIFFUSE_PICK_MIN), 1.0 - DIFFUSE_PICK_MIN)


def check_render_args(scene: Scene, method: str, spp: int = DEFAULT_GT_SPP, env_spp: int = DEFAULT_ENV_SPP,
                      max_anisotropy: int = DEFAULT_ANISOTROPY) -> None:
    """What ``render_filtering`` refuses in its arguments, before any work (a clear one-line error)."""
    scene = _as_scene(scene)
    if method not in ALL_METHODS:
        raise WarpbwError(f"filter method {method!r}: expected one of {', '.join(ALL_METHODS)}")
    check_count(max_anisotropy, "max_anisotropy (probes along a footprint's major axis)", 1, MAX_ANISOTROPY)
    if method == "ground_truth":
        check_count(spp, "spp (ground-truth rays per pixel)", MIN_GT_SPP, INT32_MAX)  # int32 in the kernels
    elif scene.environment is not None:
        check_count(env_spp, "env_spp (environment samples per pixel)", 1, INT32_MAX)


# What a FilteringScene's mipmaps were built from, per material (the rest of a material is read from the scene at
# render time): the box-filtered normal mipmaps, and the GMM mipmaps of each GMM method (``_load_gmm``: the
# unaligned baseline reads no gmm file and fits with no prior).
_MIP_FIELDS = ("normal_map", "normal_map_kind", "normal_map_scale")
_GMM_FIELDS = {"gmm_aligned": ("gmm", "gmm_components", "gmm_prior"), "gmm_unaligned": ("gmm_components",)}


def _scene_and_prepared(scene, prepared) -> tuple:
    """``(Scene, FilteringScene or None)`` from ``render_filtering``'s ``scene`` and ``prepared``: a FilteringScene
    in the scene's place is the prepared one (as ``warpbw.pipeline.render_reference`` takes a PreparedScene)."""
    if isinstance(scene, FilteringScene):
        if prepared is not None and prepared is not scene:
            raise WarpbwError("prepared: given a FilteringScene as the scene too, and another here; expected one "
                              "FilteringScene (as the scene, or a Scene with prepared=)")
        return scene.scene, scene
    scene = _as_scene(scene)
    if prepared is not None and not isinstance(prepared, FilteringScene):
        raise WarpbwError(f"prepared: expected a FilteringScene (prepare_filtering), got {type(prepared).__name__}")
    if prepared is not None and scene == prepared.scene:
        # its checked copy, made when it was prepared: a frame loop does not check (and stat) the scene each frame
        return prepared.scene, prepared
    return check_scene(scene), prepared   # a Scene built or edited in Python is checked as a scene file is


def _as_scene(scene) -> Scene:
    """The Scene of ``scene``: itself, or a FilteringScene's; anything else is a one-line error (an AttributeError
    deep inside, before)."""
    if isinstance(scene, FilteringScene):
        return scene.scene
    if not isinstance(scene, Scene):
        raise WarpbwError(f"scene: expected a Scene (warpbw.scene.load_scene) or a FilteringScene "
                          f"(prepare_filtering), got {type(scene).__name__}")
    return scene


def _shown(v) -> str:
    return "none" if v is None else f'"{v}"' if isinstance(v, (str, Path)) else f"{v!r}"


def _check_prepared(prepared: FilteringScene, scene: Scene, planes, method: str, device) -> None:
    """Refuse a FilteringScene that does not hold what ``scene`` renders with: it lives on another device than an
    explicit ``device``, or it was prepared for a scene whose plane materials, their maps, its lights or its
    environment differ (its mipmaps, light arrays and environment are used as they are: a missing material was a
    bare KeyError, a changed map or light rendered the old one without a word)."""
    if device is not None and wp.get_device(device) != wp.get_device(prepared.device):
        raise WarpbwError(f"device {device}: the prepared scene {prepared.scene.source} lives on {prepared.device}; "
                          "prepare it on that device, or pass the Scene")
    ps = prepared.scene
    if ps is scene:
        return
    head = f"prepared: prepared for {ps.source}"
    tail = f"; expected prepare_filtering of this scene ({scene.source})"
    names = list(dict.fromkeys(p.material for p in planes))
    missing = [n for n in names if n not in prepared.mips]
    if missing:
        raise WarpbwError(f"{head}, with planes of material {', '.join(prepared.mips) or '(none)'}; this scene has "
                          f"planes of material {', '.join(missing)}{tail}")
    for n in names:
        a, b = ps.materials[n], scene.materials[n]
        diff = [f for f in _MIP_FIELDS + _GMM_FIELDS.get(method, ()) if getattr(a, f) != getattr(b, f)]
        if diff:
            was = ", ".join(f"{f} = {_shown(getattr(a, f))}" for f in diff)
            raise WarpbwError(f"{head}, where [material.{n}] has {was}; this scene's has "
                              f"{', '.join(_shown(getattr(b, f)) for f in diff)}{tail}")
    if list(ps.lights) != list(scene.lights):
        def said(sc):
            return "; ".join(li.describe() for li in sc.lights) or "none"
        raise WarpbwError(f"{head}, with [[light]]s {said(ps)}; this scene has {said(scene)}{tail}")
    if ps.environment != scene.environment:
        def env(sc):
            return "none" if sc.environment is None else sc.environment.describe()
        raise WarpbwError(f"{head}, with [environment] {env(ps)}; this scene has {env(scene)}{tail}")


def render_filtering(scene: Scene | FilteringScene, method: str, spp: int = DEFAULT_GT_SPP, seed: int = 0,
                     device: str | None = None, prepared: FilteringScene | None = None, camera: Camera | None = None,
                     progress: bool = False, lod_bias: float = LOD_BIAS, threads: int | None = None,
                     env_spp: int = DEFAULT_ENV_SPP, max_anisotropy: int = DEFAULT_ANISOTROPY,
                     background: Background | None = None) -> FilterResult:
    """Render ``scene`` (planes under directional lights and / or an environment) with ``method`` (``ALL_METHODS``).
    ``scene`` is a ``Scene``, or a ``FilteringScene`` (``prepare_filtering``'s), which is then ``prepared``;
    ``prepared`` holds the scene's maps, lights and environment (one prepared for a scene whose materials' maps,
    lights or environment differ is refused) and renders on its own device (``device``, when given, must be it;
    without ``prepared``, the device to prepare on, default cpu); ``camera`` overrides the scene's; ``spp`` is the
    ground truth's rays per pixel (>= MIN_GT_SPP); ``env_spp`` the filtered methods' BRDF + environment sample pairs
    per pixel when the scene has an [environment] (the ground truth takes one pair per ray); ``seed`` seeds both;
    ``lod_bias`` is added to every pixel's mip level; ``max_anisotropy`` (1 to ``MAX_ANISOTROPY``) the most probes
    along a footprint's major axis (1: isotropic); CPU launches are tiled over ``threads`` (default: all cores, up
    to 8).  With a ``background`` (:class:`Background`, at the camera's resolution) the planes are drawn over it: a
    pixel shows a plane when its centre ray hits one in front of the background's depth, and only those pixels are
    shaded (the scene's spheres and meshes, rendered by :mod:`warpbw.pipeline`)."""
    from warpbw.launch import launch_tiled, progress_bar

    scene, prepared = _scene_and_prepared(scene, prepared)
    check_render_args(scene, method, spp, env_spp, max_anisotropy)
    check_seed(seed)
    progress = check_flag(progress, "progress")
    # a real number: inf moved every pixel to the coarsest level, and "1" was a TypeError from math.isfinite
    lod_bias = check_real(lod_bias, "lod_bias (mip levels added to every pixel's level)")
    if threads is not None:   # launch_tiled checks it too, but only after the mipmaps are built
        check_count(threads, "threads", 1)
    if device is not None:
        check_device(device)
    planes = plane_objects(scene)
    check_plane_reach(camera or scene.camera, planes, scene.source)
    if prepared is not None:
        _check_prepared(prepared, scene, planes, method, device)
    if prepared is None or (method.startswith("gmm") and any(method not in mp.gmm and not mp.flat
                                                             for mp in prepared.mips.values())):
        on = prepared.device if prepared is not None else "cpu" if device is None else device
        prepared = prepare_filtering(scene, (method,), on, progress)
    cam_s = camera or scene.camera
    cam = scene_camera(cam_s)
    n = cam_s.width * cam_s.height
    h, w = cam_s.height, cam_s.width
    dev = prepared.device
    if background is not None:
        bg_img = np.asarray(background.image)
        bg_z = np.asarray(background.depth)
        if bg_img.shape != (h, w, 3) or bg_z.shape != (h, w):
            raise WarpbwError(f"background: expected an ({h}, {w}, 3) image and an ({h}, {w}) depth (the camera's "
                              f"{w}x{h}), got {bg_img.shape} and {bg_z.shape}")
        out = wp.array(bg_img.reshape(n, 3).astype(np.float32), dtype=wp.vec3, device=dev)
        z = wp.array(bg_z.reshape(n).astype(np.float32), dtype=wp.float32, device=dev)
    else:
        out = wp.zeros(n, dtype=wp.vec3, device=dev)
    depth = wp.full(n, NO_HIT, dtype=wp.float32, device=dev)
    level = wp.zeros(n, dtype=wp.float32, device=dev)
    env = prepared.env.data if prepared.env is not None else EnvMapData()
    with_env = prepared.env is not None
    with_lights = len(prepared.scene.lights) > 0   # the lights' loop is compiled only for a scene that has some
    kernel = (_ground_truth_kernel(with_env, with_lights) if method == "ground_truth"
              else _filtered_kernel(_CODE[method], with_env, with_lights))
    # a plane without a normal map shades the plain BRDF whatever the filter: no GMM is fitted or filtered for it
    flat_kernel = kernel if method == "ground_truth" else _filtered_kernel(_CODE["fixed"], with_env, with_lights)
    used = {flat_kernel if prepared.mips[p.material].flat else kernel for p in planes}
    for k in used:
        wp.load_module(k.module, device=dev)   # compile before the clock starts
    if background is not None:
        wp.load_module(background_distance_kernel.module, device=dev)
    wp.synchronize_device(dev)
    t0 = time.perf_counter()
    if background is not None:
        wp.launch(background_distance_kernel, dim=n, inputs=[cam, z, depth], device=dev)
        start = depth.numpy().reshape(h, w).copy()   # numpy() of a CPU array is a view of it
    # a bar for the ground truth alone, the long one (1024 rays per pixel at 1024^2: minutes)
    with progress_bar(n * len(planes), f"ground truth, {spp} rays per pixel",
                      progress and method == "ground_truth") as step:
        for p in planes:
            m = scene.materials[p.material]
            mp = prepared.mips[p.material]
            if method == "ground_truth":
                pl = _plane_data(p, m, mp, 0)
                launch_tiled(kernel, n, lambda o, c, pl=pl, mp=mp: [cam, pl, mp.lw, mp.lh, mp.loff, mp.nmean,
                                                                   prepared.ldir, prepared.lrad, env, int(spp),
                                                                   int(seed), o, depth, out],
                             dev, threads, step, item_cost=int(spp))
            else:
                gmm, K = mp.gmm.get(method, (wp.zeros(1, dtype=wp.vec4, device=dev), 0))
                pl = _plane_data(p, m, mp, K, lod_bias, max_anisotropy)
                launch_tiled(flat_kernel if mp.flat else kernel, n,
                             lambda o, c, pl=pl, mp=mp, gmm=gmm: [cam, pl, mp.lw, mp.lh, mp.loff, gmm, mp.nmean,
                                                                 mp.nm2, prepared.ldir, prepared.lrad, env,
                                                                 int(env_spp), int(seed), o, depth, out, level],
                             dev, threads, item_cost=int(env_spp))
        wp.synchronize_device(dev)
    dt = time.perf_counter() - t0
    img = out.numpy().reshape(h, w, 3).astype(np.float32)
    cov = depth.numpy().reshape(h, w) < (start if background is not None else NO_HIT)
    lev = level.numpy().reshape(h, w)
    check_finite_image(img, prepared.scene.source)
    stats = {"method": method, "device": str(dev), "resolution": [w, h], "pixels_covered": int(cov.sum()),
             "time_s": round(dt, 6),
             "materials": prepared.notes,
             "stages": filtering_stages(method, [prepared.mips[p.material].flat for p in planes], with_env,
                                        with_lights),
             "non_finite_pixels": 0}   # check_finite_image refused any
    if method == "ground_truth":
        stats["spp"] = int(spp)
        stats["seed"] = int(seed)
    else:
        stats["mean_level"] = float(lev[cov].mean()) if cov.any() else 0.0
        stats["max_anisotropy"] = int(max_anisotropy)
    if with_env:
        stats["environment"] = {"name": prepared.env.name, "size": [prepared.env.width, prepared.env.height],
                                "samples_per_pixel": 2 * (int(spp) if method == "ground_truth" else int(env_spp)),
                                "seed": int(seed), "sampler": "R_3 + R_2 Kronecker, random offset per pixel"}
    return FilterResult(img, cov, lev, dt, method, stats)


def plane_distance(scene: Scene, device: str = "cpu") -> np.ndarray:
    """(H, W) float32: per pixel, the distance along its centre ray to the nearest of the scene's planes, ``inf``
    where it hits none -- the same hit test the renderer makes, from the scene file alone (no map is loaded).
    A scene that has planes beside spheres and meshes hides the spheres and meshes beyond it
    (:func:`warpbw.gbuffer.hide_beyond`) before shading them."""
    check_device(device)
    scene = _as_scene(scene)
    cam_s = scene.camera
    check_plane_reach(cam_s, [p for p in scene.objects if isinstance(p, PlaneObject)], scene.source)
    cam = scene_camera(cam_s)
    n = cam_s.width * cam_s.height
    depth = wp.full(n, NO_HIT, dtype=wp.float32, device=device)
    for p in scene.objects:
        if isinstance(p, PlaneObject):
            pl = PlaneData()
            pl.center = wp.vec3(*p.center)
            pl.size = float(p.size)
            wp.launch(plane_distance_kernel, dim=n, inputs=[cam, pl, depth], device=device)
    t = depth.numpy().reshape(cam_s.height, cam_s.width)
    return np.where(t < NO_HIT, t, np.inf).astype(np.float32)


def zoomed_camera(camera: Camera, zoom: float) -> Camera:
    """The camera moved away from its look-at point: distance times ``zoom``, same resolution and fov."""
    check_instance(camera, Camera, "zoomed_camera: camera", "a scene's Camera (warpbw.scene.Camera)")
    # a real number > 0: NaN or inf gave a camera at NaN / inf, a negative zoom one behind the look-at point
    zoom = check_real(zoom, "zoom (times the camera's distance to its look_at point)", 0.0, lo_open=True)
    pos = tuple(a + (p - a) * zoom for p, a in zip(camera.position, camera.look_at))
    if np.array_equal(np.float32(pos), np.float32(camera.look_at)):   # make_camera's "look_at: must differ" later
        raise WarpbwError(f"zoom {zoom:g} puts the camera on its look_at point (its distance times {zoom:g} rounds "
                          "to 0 in float32): expected a larger zoom")
    return replace(camera, position=pos)


def filtering_stages(method: str, flat, with_env: bool, with_lights: bool) -> list:
    """The stages a filtering frame ran (``FilterResult.stats["stages"]``, as ``warpbw.pipeline.stages_used``
    names the other renderer's): ``flat`` per plane, whether it has no normal map."""
    s = ["plane_hit+footprint"]
    if method == "ground_truth":
        s.append("ground_truth_rays")
    else:
        if not all(flat):
            s.append(("gmm_filtering:" if method.startswith("gmm") else "filtering:") + method)
        if any(flat):
            s.append("plain_brdf:planes_without_normal_map")
    s.append("light:" + "+".join(n for n, on in (("environment", with_env), ("directional", with_lights)) if on))
    return s


def filtering_summary(scene: Scene) -> dict:
    """What ``warpbw info`` says about a scene with planes (from the scene file alone)."""
    scene = _as_scene(scene)
    objects = [o.describe() + ("" if isinstance(o, PlaneObject) else " (not rendered by the filtering renderer)")
               for o in scene.objects]
    lights = [li.describe() for li in scene.lights]
    e = scene.environment
    env = "none" if e is None else (
        f"{e.describe()}; sampled per pixel: BRDF and environment samples, multiple importance sampling, "
        "quasi-random (R_3 and R_2 sequences, a random offset per pixel)")
    mats = {n: scene.materials[n].type for n in scene.material_order}
    # as a frame runs them (filtering_stages): a plane without a normal map has no mipmap, and every filter shades
    # it with the plain BRDF
    flat = [scene.materials[o.material].normal_map is None for o in scene.objects if isinstance(o, PlaneObject)]
    stages = ["analytic ray-plane hit + ray-differential footprint"]
    if not all(flat):
        stages += ["normal mipmaps (box filter; GMM, 004 Sec. 4.1, from file or cache or built)",
                   "filtered shading (004 Sec. 3, 4.2): " + ", ".join(ALL_METHODS)]
    if any(flat):
        stages.append("plain BRDF for the planes without a normal map (no mipmap, the same for every filter)")
    stages += ([] if e is None else ["environment: per pixel BRDF + environment samples (MIS)"]) + \
        (["directional lights: exact, per pixel"] if scene.lights else [])
    return {
        "scene": scene.source,
        "resolution": [scene.camera.width, scene.camera.height],
        "environment": env,
        "lights": lights,
        "objects": objects,
        "materials": mats,
        "unused_materials": sorted(set(scene.materials) - set(scene.material_order)),
        "files": [str(p) for p in scene.files()],
        "stages": stages,
    }


# ---------------------------------------------------------------------------------------------------
# Test hooks: the kernels' own functions on given data

def fetch_gmm(levels, s, t, level, device: str = "cpu") -> np.ndarray:
    """Recovered (a, mu_x, mu_y, s^2) per component, (N, K, 4), of the GMM mipmap ``levels`` (finest first,
    (h, w, K, 4) moments) at finest-texel coordinates (s, t) and fractional ``level``, by the renderer's
    trilinear fetch (empty components come back as zeros).  ``level`` from 0 to the coarsest level's index (the
    kernel reads the level arrays at it: 99 or NaN crashed the process)."""
    check_device(device)
    if not isinstance(levels, (list, tuple)) or not levels:   # one array was iterated as its rows
        raise WarpbwError(f"levels: expected a list of the mipmap's levels, finest first, got {type(levels).__name__}")
    levels = [numeric_array(q, f"levels[{i}]", "(h, w, K, 4) moments") for i, q in enumerate(levels)]
    K = levels[0].shape[2] if levels[0].ndim == 4 else 0
    for i, q in enumerate(levels):
        if q.ndim != 4 or q.shape[2:] != (K, 4) or K < 1 or not np.all(np.isfinite(q)):
            raise WarpbwError(f"levels[{i}]: expected finite (h, w, K, 4) moments with level 0's K = {K}, got shape "
                              f"{q.shape}")
    # the kernel wraps texel indices by each level's size: an empty level divided by zero (SIGFPE: the process died),
    # and a level of another size than level 0 halved was read at other texels than the renderer's
    if levels[0].shape[0] < 1 or levels[0].shape[1] < 1:
        raise WarpbwError(f"levels[0]: expected at least 1x1 texels, got shape {levels[0].shape}")
    chain = level_shapes(*levels[0].shape[:2])
    if len(levels) > len(chain):
        raise WarpbwError(f"levels: expected at most {len(chain)} levels for a level 0 of {levels[0].shape[:2]} (down "
                          f"to 1x1), got {len(levels)}")
    for i, (q, hw) in enumerate(zip(levels, chain)):
        if q.shape[:2] != hw:
            raise WarpbwError(f"levels[{i}]: expected level 0's {levels[0].shape[:2]} halved {i} times (rounded up), "
                              f"{hw}, got {q.shape[:2]}")
    s, t, level = (numeric_array(v, name) for v, name in ((s, "s"), (t, "t"), (level, "level")))
    try:
        s, t, level = np.broadcast_arrays(s, t, level)
    except ValueError:
        raise WarpbwError(f"s, t, level: expected shapes that broadcast, got {s.shape}, {t.shape}, {level.shape}") \
            from None
    if not (np.all(np.isfinite(s)) and np.all(np.isfinite(t))):
        raise WarpbwError("s, t: expected finite texel coordinates")
    top = len(levels) - 1
    if level.size and not (np.all(np.isfinite(level)) and level.min() >= 0 and level.max() <= top):
        got = "NaN or infinite values" if not np.all(np.isfinite(level)) else f"{level.min():g} to {level.max():g}"
        raise WarpbwError(f"level: expected levels from 0 to {top} (the mipmap's), got {got}")
    shapes = [tuple(q.shape[:2]) for q in levels]
    lw, lh, loff = _level_arrays(shapes, device)
    gmm, K = _gmm_array(levels, device)
    st = wp.array(np.stack([s.ravel(), t.ravel(), level.ravel()], -1).astype(np.float32), dtype=wp.vec3,
                  device=device)
    out = wp.zeros(st.shape[0] * K, dtype=wp.vec4, device=device)
    wp.launch(fetch_gmm_kernel, dim=(st.shape[0], K), inputs=[gmm, lw, lh, loff, len(levels), K, st, out],
              device=device)
    return out.numpy().reshape(-1, K, 4)


def gmm_ndf(params, rough_var: float, h, device: str = "cpu") -> np.ndarray:
    """The renderer's mixture NDF, sum_k a_k g(h_xy; mu_k, s_k^2 + rough_var), at unit directions h (N, 3) for
    components ``params`` (K, 4) of (a, mu_x, mu_y, s^2), s^2 each component's own variance.  A component the
    renderer fetches (``fetch_gmm``, whose recovery floors s^2 at ``VARIANCE_FLOOR``) it shades with s^2 less that
    floor (a flat map's components, at the floor, as the plain BRDF): given ``fetch_gmm``'s output, this NDF is
    ``VARIANCE_FLOOR`` wider per axis than the renderer's (on a flat map at roughness 1e-3 its peak is a third of
    the renderer's, at 0.01 2% lower, at 0.08 0.03%)."""
    check_device(device)
    rough_var = check_real(rough_var, "rough_var (the roughness's per-axis variance)", 0.0)  # < 0: NDF below 0
    # (4, 3) params and (6, 2) directions were reshaped to (3, 4) and (4, 3) without a word
    p, hv = numeric_array(params, "params", "(K, 4) components"), numeric_array(h, "h", "(N, 3) unit directions")
    # 1e39 is inf in float32, as the kernel takes it: an inf or NaN NDF
    if p.ndim != 2 or p.shape[1] != 4 or not np.all(np.abs(p) <= FLOAT32_MAX) or np.any(p[:, 3] < 0):
        raise WarpbwError(f"params: expected finite (K, 4) components (a, mu_x, mu_y, s^2 >= 0) within float32's "
                          f"range, got shape {p.shape}" + (f", values up to {np.abs(p).max():.3g}" if p.size else ""))
    if hv.ndim != 2 or hv.shape[1] != 3:
        raise WarpbwError(f"h: expected (N, 3) directions, got shape {hv.shape}")
    p = p.astype(np.float32)
    # a component's Gaussian has per-axis variance s^2 + rough_var (module docstring): 0 is a delta, which the kernel
    # read as 0 / 0 = NaN, and below 1 / (2 pi FLOAT32_MAX) = 4.7e-40 its peak 1 / (2 pi var) is inf in float32
    var = p[:, 3] + np.float32(rough_var)
    sharp = (p[:, 0] > 0.0) & ~(var > 1.0 / (TWO_PI * FLOAT32_MAX))
    if sharp.any():
        raise WarpbwError(f"params: expected s^2 + rough_var > {1.0 / (TWO_PI * FLOAT32_MAX):.2g} for every component "
                          f"of weight > 0 (a Gaussian of variance 0 is a delta), got {float(var[sharp][0]):g}")
    hh = wp.array(unit_directions(hv, "h").astype(np.float32), dtype=wp.vec3, device=device)
    out = wp.zeros(hh.shape[0], dtype=wp.float32, device=device)
    wp.launch(gmm_ndf_kernel, dim=hh.shape[0], inputs=[wp.array(p, dtype=wp.vec4, device=device), p.shape[0],
                                                       float(rough_var), hh, out], device=device)
    return out.numpy()


def pair_uniforms(seed: int, pixel: int, n: int, device: str = "cpu") -> np.ndarray:
    """The uniforms (n, ``PAIR_DIMS``) of pairs 0 .. n - 1 of the environment term at a pixel (``PAIR_ALPHA``):
    columns 0-2 drive the BRDF draw, 3-4 the environment draw."""
    check_device(device)
    # as the renderer takes them: a uint32 seed, an int32 pixel index (2.5 and "1" were taken as 2 and 1)
    seed, pixel = check_seed(seed), check_count(pixel, "pixel", 0, INT32_MAX)
    n = check_count(n, "n (pairs)", 0, INT32_MAX)
    # n float32 rows of PAIR_DIMS on the host (n = 2^31 - 1: 43 GB, allocated without a word)
    warn_if_short_of_memory(int(n) * PAIR_DIMS * 4, available_memory(), f"pair_uniforms: n = {n} pairs",
                            "ask for fewer pairs")
    out = wp.zeros((int(n), PAIR_DIMS), dtype=wp.float32, device=device)
    wp.launch(pair_uniforms_kernel, dim=(int(n), PAIR_DIMS), inputs=[int(seed), int(pixel), out], device=device)
    return out.numpy()
