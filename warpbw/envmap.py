"""Lat-long (equirectangular) HDR environment light: lookup, importance sampling, MIP pyramid.

Orientation -- identical to Mitsuba 3's ``envmap`` emitter (mitsuba-renderer/mitsuba3,
src/emitters/envmap.cpp at 0179ad9f: ``direction_to_uv``, ``uv_to_direction``,
``eval_spectrum``; tests/test_envmap.py also compares with mitsuba 3.9.1 ``scalar_rgb`` when it
is installed):

* A direction ``d = (x, y, z)`` in the map's local frame has texture coordinates
  ``u = atan2(x, -z) / (2 pi)`` (wrapped into [0, 1)) and ``v = acos(y) / pi``.
  The inverse is ``d = (sin(phi) sin(theta), cos(theta), -cos(phi) sin(theta))`` with
  ``phi = 2 pi u``, ``theta = pi v``.
* So ``u = 0`` looks down **-Z**, ``u`` increases towards **+X** (u = 0.25 is +X, 0.5 is +Z,
  0.75 is -X), and ``v = 0`` is **+Y** (row 0, the top of the image), ``v = 1`` is -Y.
* Texel placement for the bilinear lookup (Mitsuba's half-texel shift plus an extra wrapped
  column): column ``i`` of a ``W``-wide map is centred at ``u = (i + 0.5) / W`` and the lookup
  is periodic in ``u`` (column ``W`` is column 0). Rows are *not* cell-centred: row ``j`` of an
  ``H``-high map sits at ``v = j / (H - 1)``, so row 0 is exactly the +Y pole and row ``H - 1``
  the -Y pole; ``v`` is clamped (Mitsuba wraps it, which only differs at exactly v = 1).
* ``rotation_deg`` is Mitsuba's ``to_world = rotate([0, 1, 0], angle)`` (right-handed, about
  +Y): a local direction ``d`` appears in the world at ``R d`` with
  ``R = [[c, 0, s], [0, 1, 0], [-s, 0, c]]``, e.g. +90 degrees takes local -Z (u = 0) to world -X.
  ``scale`` multiplies the radiance (applied to the pixels at load time).

Sampling (``env_sample`` / ``env_pdf``) is our own, not Mitsuba's (Mitsuba warps with a
bilinear ``Hierarchical2D`` over luminance x sin(theta) at the rows, which gives the pole rows
zero weight); only the radiance lookup follows Mitsuba. It is a
piecewise-constant 2D distribution over texel
*cells* -- the region of the sphere closest to each texel, i.e. ``u`` in ``[i/W, (i+1)/W]`` and
``v`` in ``[(j - 1/2)/(H - 1), (j + 1/2)/(H - 1)]`` clipped to [0, 1] (the two pole rows get
half-height cells). A marginal CDF over rows and one conditional CDF over columns per row are
searched by bisection. A cell's weight is ``luminance x solid angle of the cell`` (the exact
integral of ``sin(theta)``, so the pole rows keep a nonzero weight), where the luminance is the
cell average of the bilinear interpolant (a separable 1/8, 3/4, 1/8 filter): every direction
whose bilinear radiance is nonzero lies in a cell with nonzero probability. Inside a cell the
direction is uniform in solid angle (uniform in ``phi`` and in ``cos(theta)``), so the
solid-angle pdf is constant per cell (``P(cell) / solid_angle(cell)``), finite at the poles, and
exactly ``1 / (4 pi)`` for a constant map. An all-black map falls back to uniform sphere
sampling (pdf ``1 / (4 pi)``). The per-cell pdf is computed from the float32 CDFs actually
searched, so ``env_pdf`` matches ``env_sample`` even where float32 rounding changes a cell's
probability.

MIP pyramid (``env_radiance_lod``): level 0 is the map; each next level is a 2x2 box reduction
(``n -> max(1, n // 2)`` per axis; an odd axis is box-resampled with fractional coverage so the
mean is preserved exactly) down to 1x1. A level's column ``i`` is centred at ``u = (i + 1/2) / W_l`` as
above, and its row ``k`` at the centre of the rows it averages, ``v = v0_l + k dv_l`` (level 0: 0 and
``1 / (H - 1)``; an even reduction: ``v0 + dv / 2`` and ``2 dv``), clamped to its first and last rows'
``v`` towards the poles.  (Placed at ``k / (H_l - 1)``, as level 0's rows are, the rows' contents moved
towards the nearer pole: a bright cap's edge by 3 rows of level 0 at lod 3.)  ``lod`` interpolates
linearly between the two nearest levels (trilinear).

Warp functions (take an ``EnvMapData`` and a world direction; directions need not be unit):
    env_radiance(env, w) -> wp.vec3        bilinear radiance (scaled) towards w
    env_radiance_lod(env, w, lod) -> wp.vec3   needs build_mip_pyramid(env) first (else every lod reads level 0)
    env_uv(env, w) -> wp.vec2               lat-long (u, v) of w (for per-texel maps such as nu_a)
    env_sample(env, u: wp.vec2) -> wp.vec3 unit world direction, u in [0, 1)^2
    env_pdf(env, w) -> float               solid-angle pdf of env_sample
    env_radiance_uv(env, uv), env_pdf_uv(env, uv)   the same at uv = env_uv(env, w): a caller that needs both
                                           at one direction converts it once (a shading sample's MIS weight)

Host functions:
    envmap_from_array(rgb, rotation_deg=0.0, scale=1.0, name="array", device="cpu") -> EnvMap
        (``EnvMap.source_digest`` hashes the map as given, before its scale: what the exposure does not change,
        the nu_a map, is cached by it)
    load_envmap(path, rotation_deg=0.0, scale=1.0, device="cpu", sampling=True) -> EnvMap   (warns first where it
                                                 would take more memory than is available,
                                                 ``load_memory(width, height)``;
                                                 ``file_load_memory(path) -> (width, height, bytes)`` from the
                                                 EXR's header)
    constant_envmap(radiance, device="cpu") -> EnvMap
    load_environment(spec, device="cpu", sampling=True) -> EnvMap   a scene's [environment]
                                                 (``warpbw.scene.Environment``)
    ensure_sampling(env) -> EnvMap   the sampling distribution on the device, once: a map loaded with
                                     ``sampling=False`` builds it on first need (``EnvMap.data`` does;
                                     ``EnvMap.lookup_data`` is the struct as it is, for radiance look-ups alone;
                                     ``EnvMap.has_sampling`` says whether it is built)
    check_env_data(env_data, where, sampled=True)   a one-line error for a struct without its map or (``sampled``)
                                     its sampling distribution (the renderers' passes call it)
    procedural_sky(width=256, height=128, ...) -> np.ndarray (H, W, 3) float32
    build_mip_levels(pixels) -> list[np.ndarray]
    mip_row_positions(heights) -> np.ndarray (n_levels, 2)   where each level's rows sit: (v0, dv)
    build_mip_pyramid(env) -> EnvMap   the pyramid on the device, built on first need (no renderer reads it yet)
    texel_directions(width, height) -> np.ndarray (H, W, 3) local directions of texel centres
    eval_radiance(env, dirs) -> (N, 3)           debug / test wrappers: launch a kernel
    eval_radiance_lod(env, dirs, lod) -> (N, 3)
    eval_pdf(env, dirs) -> (N,)
    sample_directions(env, n, seed=0) -> (dirs (n, 3), pdf (n,))
"""
from __future__ import annotations

import hashlib
import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import warp as wp

from warpbw.errors import (WarpbwError, available_memory, check_count, check_device, check_flag, check_instance,
                           check_real, check_seed, is_int, numeric_array, unit_directions, warn_if_short_of_memory)

wp.set_module_options({"enable_backward": False})  # no gradients are taken: halves compile time

# Resolution of the built-in procedural sky (lat-long, 2:1).
PROCEDURAL_SKY_SIZE = (512, 256)

# Rec. 709 / sRGB luminance weights, the ones Mitsuba 3's luminance() uses for linear RGB
# (include/mitsuba/core/spectrum.h): the Y row of Rec. 709's RGB -> XYZ, as warpbw.io.exr.REC709_LUMINANCE within
# 1e-4.  They only shape the probe's sampling distribution (and the filtered planes' diffuse / specular pick), never
# the expected radiance: kept rather than rounded as REC709_LUMINANCE is, which would move the environment samples of
# every frame drawn with them (session 82).
LUMINANCE_RGB = (0.212671, 0.715160, 0.072169)

# Fraction of a cell's width kept clear at its edges when sampling inside the cell, so that
# float32 rounding in direction -> (u, v) (about 1e-4 of a cell for a 1024-wide map) does not
# move a sampled direction into a neighbouring cell.  The rounding grows with the cells along the axis (phi's and
# theta's float32 error is a fixed fraction of a turn): with this margin alone none of 4M samples crossed on maps of
# 4096 columns, turned or not, but at 8192 columns about 1e-5 of them read the adjacent column's pdf, and at 16384
# 3.5e-4 (0.4-5 times their own; session 77).  So each axis keeps the larger of this and CELL_EDGE_MARGIN_PER_CELL
# times its cells (the same 1e-3 up to 2048 cells).  env_sample clamps onto it: the density stays
# uniform inside, and the 1e-3 of a cell's probability that falls in each edge strip lands on the
# strip's inner line, which matters only for integrands that vary inside one texel.
CELL_EDGE_MARGIN = 1.0e-3
CELL_EDGE_MARGIN_PER_CELL = 5.0e-7

# Texels a probe is converted, scaled and checked in at a time when it loads (ours): a block's float64 temporaries
# are then about 40 MB whatever the probe's size (session 63: the whole map's took 60 bytes per texel).
SANITIZE_BLOCK_TEXELS = 1 << 20
# Peak memory of loading a probe, numpy's allocations under tracemalloc (session 63): 44 bytes per texel at
# 4096x2048 and 8192x4096 (1.5 GB), the file's pixels, the map and its sampling distribution; rounded up.
LOAD_BYTES_PER_TEXEL = 48

_PI = wp.constant(math.pi)
_INV_PI = wp.constant(1.0 / math.pi)
_TWO_PI = wp.constant(2.0 * math.pi)
_INV_TWO_PI = wp.constant(0.5 / math.pi)
_MARGIN = wp.constant(CELL_EDGE_MARGIN)
_MARGIN_PER_CELL = wp.constant(CELL_EDGE_MARGIN_PER_CELL)
# largest float32 below 1: keeps a uniform variate strictly inside the last CDF interval
_ONE_MINUS_EPS = wp.constant(1.0 - 2.0**-24)


@wp.struct
class EnvMapData:
    base: wp.array2d(dtype=wp.vec3)  # (H, W) radiance, clamped and scaled
    width: wp.int32
    height: wp.int32
    rot_cos: wp.float32  # to_world = rotate([0, 1, 0], rotation_deg)
    rot_sin: wp.float32
    marginal_cdf: wp.array2d(dtype=wp.float32)  # (1, H + 1), 0 ... 1 over rows
    conditional_cdf: wp.array2d(dtype=wp.float32)  # (H, W + 1), 0 ... 1 over columns of a row
    row_omc: wp.array(dtype=wp.float32)  # (H + 1,) 1 - cos(theta) at the row-cell boundaries
    row_opc: wp.array(dtype=wp.float32)  # (H + 1,) 1 + cos(theta) at the row-cell boundaries
    cell_pdf: wp.array2d(dtype=wp.float32)  # (H, W) solid-angle pdf inside each texel cell
    mip_data: wp.array(dtype=wp.vec3)  # all MIP levels, row-major, packed one after another
    mip_offset: wp.array(dtype=wp.int32)  # (n_levels,) start of each level in mip_data
    mip_width: wp.array(dtype=wp.int32)
    mip_height: wp.array(dtype=wp.int32)
    mip_row_v: wp.array(dtype=wp.vec2)  # (n_levels,) (v0, dv): row k of the level sits at v = v0 + k dv
    n_levels: wp.int32


# ----------------------------------------------------------------------------- Warp functions


@wp.func
def _to_local(env: EnvMapData, w: wp.vec3) -> wp.vec3:
    # inverse of to_world (R^T): rotate by -angle about +Y
    return wp.vec3(env.rot_cos * w[0] - env.rot_sin * w[2], w[1], env.rot_sin * w[0] + env.rot_cos * w[2])


@wp.func
def _to_world(env: EnvMapData, d: wp.vec3) -> wp.vec3:
    return wp.vec3(env.rot_cos * d[0] + env.rot_sin * d[2], d[1], -env.rot_sin * d[0] + env.rot_cos * d[2])


@wp.func
def _dir_to_uv(d: wp.vec3) -> wp.vec2:
    # Mitsuba's direction_to_uv; theta via atan2 (accurate near the poles, no need to normalise)
    u = wp.atan2(d[0], -d[2]) * _INV_TWO_PI
    u = u - wp.floor(u)
    v = wp.atan2(wp.sqrt(d[0] * d[0] + d[2] * d[2]), d[1]) * _INV_PI
    return wp.vec2(u, wp.clamp(v, 0.0, 1.0))


@wp.func
def _lerp3(a: wp.vec3, b: wp.vec3, t: float) -> wp.vec3:
    # a + t (b - a): exactly a when a == b (a constant map stays exactly constant)
    return a + (b - a) * t


@wp.func
def _grid_coords(uv: wp.vec2, w: wp.int32, h: wp.int32) -> wp.vec4:
    """(x0, y0, fx, fy): top-left texel of the bilinear footprint and the fractions."""
    fw = float(w)
    x = uv[0] * fw - 0.5  # column i centred at u = (i + 0.5) / W
    x = x - wp.floor(x / fw) * fw  # periodic in u
    x0 = wp.min(wp.floor(x), fw - 1.0)
    fx = wp.clamp(x - x0, 0.0, 1.0)
    y = uv[1] * float(wp.max(h - 1, 0))  # row j at v = j / (H - 1)
    y0 = wp.min(wp.floor(y), float(wp.max(h - 2, 0)))
    fy = wp.clamp(y - y0, 0.0, 1.0)
    return wp.vec4(x0, y0, fx, fy)


@wp.func
def _bilinear_base(env: EnvMapData, uv: wp.vec2) -> wp.vec3:
    w = env.width
    h = env.height
    g = _grid_coords(uv, w, h)
    i0 = wp.clamp(int(g[0]), 0, w - 1)  # integer clamps: a NaN direction must not index out of range
    j0 = wp.clamp(int(g[1]), 0, wp.max(h - 2, 0))
    i1 = i0 + 1
    if i1 >= w:
        i1 = 0
    j1 = wp.min(j0 + 1, h - 1)
    top = _lerp3(env.base[j0, i0], env.base[j0, i1], g[2])
    bot = _lerp3(env.base[j1, i0], env.base[j1, i1], g[2])
    return _lerp3(top, bot, g[3])


@wp.func
def _bilinear_level(env: EnvMapData, level: wp.int32, uv: wp.vec2) -> wp.vec3:
    w = env.mip_width[level]
    h = env.mip_height[level]
    off = env.mip_offset[level]
    rv = env.mip_row_v[level]
    v = float(0.0)   # the level's own row coordinate as a lat-long v (row k at k / (h - 1)), its end rows clamped
    if h > 1:
        v = wp.clamp((uv[1] - rv[0]) / rv[1], 0.0, float(h - 1)) / float(h - 1)
    g = _grid_coords(wp.vec2(uv[0], v), w, h)
    i0 = wp.clamp(int(g[0]), 0, w - 1)  # integer clamps: a NaN direction must not index out of range
    j0 = wp.clamp(int(g[1]), 0, wp.max(h - 2, 0))
    i1 = i0 + 1
    if i1 >= w:
        i1 = 0
    j1 = wp.min(j0 + 1, h - 1)
    top = _lerp3(env.mip_data[off + j0 * w + i0], env.mip_data[off + j0 * w + i1], g[2])
    bot = _lerp3(env.mip_data[off + j1 * w + i0], env.mip_data[off + j1 * w + i1], g[2])
    return _lerp3(top, bot, g[3])


@wp.func
def _cdf_search(cdf: wp.array2d(dtype=wp.float32), row: wp.int32, n: wp.int32, x: float) -> wp.int32:
    """Largest k in [0, n) with cdf[row, k] <= x, for cdf[row, 0] = 0 <= x < cdf[row, n] = 1.

    The interval found always has positive width, so zero-probability bins are never chosen.
    """
    lo = wp.int32(0)
    hi = wp.int32(n)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if cdf[row, mid] <= x:
            lo = mid
        else:
            hi = mid
    return lo


@wp.func
def env_uv(env: EnvMapData, w: wp.vec3) -> wp.vec2:
    """Lat-long coordinates (u, v) in [0, 1]^2 of world direction w (column u * W, row v * H)."""
    return _dir_to_uv(_to_local(env, w))


@wp.func
def env_radiance(env: EnvMapData, w: wp.vec3) -> wp.vec3:
    """Bilinear radiance arriving from world direction w (Mitsuba envmap convention)."""
    return env_radiance_uv(env, env_uv(env, w))


@wp.func
def env_radiance_uv(env: EnvMapData, uv: wp.vec2) -> wp.vec3:
    """env_radiance at the lat-long coordinates uv = env_uv(env, w): a caller that also needs env_pdf_uv there
    computes them once."""
    return _bilinear_base(env, uv)


@wp.func
def env_radiance_lod(env: EnvMapData, w: wp.vec3, lod: float) -> wp.vec3:
    """Trilinear lookup in the MIP pyramid: lod 0 is the map, lod k is 2^k times coarser."""
    uv = env_uv(env, w)
    top = float(env.n_levels - 1)
    l = wp.clamp(lod, 0.0, top)
    if l != l:  # NaN lod -> finest level
        l = 0.0
    l0 = wp.clamp(int(wp.floor(l)), 0, env.n_levels - 1)
    l1 = wp.min(l0 + 1, env.n_levels - 1)
    a = _bilinear_level(env, l0, uv)
    b = _bilinear_level(env, l1, uv)
    return _lerp3(a, b, l - float(l0))


@wp.func
def env_sample(env: EnvMapData, u: wp.vec2) -> wp.vec3:
    """Unit world direction drawn with density env_pdf from a uniform u in [0, 1)^2."""
    h = env.height
    w = env.width
    xv = wp.clamp(u[1], 0.0, _ONE_MINUS_EPS)
    j = _cdf_search(env.marginal_cdf, 0, h, xv)
    c0 = env.marginal_cdf[0, j]
    c1 = env.marginal_cdf[0, j + 1]
    m_v = wp.max(_MARGIN, _MARGIN_PER_CELL * float(h))
    tv = wp.clamp((xv - c0) / (c1 - c0), m_v, 1.0 - m_v)
    xu = wp.clamp(u[0], 0.0, _ONE_MINUS_EPS)
    i = _cdf_search(env.conditional_cdf, j, w, xu)
    d0 = env.conditional_cdf[j, i]
    d1 = env.conditional_cdf[j, i + 1]
    m_u = wp.max(_MARGIN, _MARGIN_PER_CELL * float(w))
    tu = wp.clamp((xu - d0) / (d1 - d0), m_u, 1.0 - m_u)
    # uniform in cos(theta) inside the row cell; 1 -/+ cos kept separately for precision at the poles
    omc = env.row_omc[j] + tv * (env.row_omc[j + 1] - env.row_omc[j])
    opc = env.row_opc[j] + tv * (env.row_opc[j + 1] - env.row_opc[j])
    sin_t = wp.sqrt(wp.max(omc * opc, 0.0))
    cos_t = 0.5 * (opc - omc)
    phi = _TWO_PI * (float(i) + tu) / float(w)
    d = wp.vec3(wp.sin(phi) * sin_t, cos_t, -wp.cos(phi) * sin_t)
    return wp.normalize(_to_world(env, d))


@wp.func
def env_pdf(env: EnvMapData, w: wp.vec3) -> float:
    """Solid-angle pdf of env_sample at world direction w (constant inside each texel cell)."""
    return env_pdf_uv(env, env_uv(env, w))


@wp.func
def env_pdf_uv(env: EnvMapData, uv: wp.vec2) -> float:
    """env_pdf at the lat-long coordinates uv = env_uv(env, w)."""
    i = wp.clamp(int(wp.floor(uv[0] * float(env.width))), 0, env.width - 1)
    j = wp.clamp(int(wp.floor(uv[1] * float(wp.max(env.height - 1, 0)) + 0.5)), 0, env.height - 1)
    return env.cell_pdf[j, i]


# ----------------------------------------------------------------------------- debug kernels


@wp.kernel
def _eval_radiance_kernel(env: EnvMapData, dirs: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.vec3)):
    tid = wp.tid()
    out[tid] = env_radiance(env, dirs[tid])


@wp.kernel
def _eval_radiance_lod_kernel(
    env: EnvMapData, dirs: wp.array(dtype=wp.vec3), lod: wp.array(dtype=wp.float32), out: wp.array(dtype=wp.vec3)
):
    tid = wp.tid()
    out[tid] = env_radiance_lod(env, dirs[tid], lod[tid])


@wp.kernel
def _eval_pdf_kernel(env: EnvMapData, dirs: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.float32)):
    tid = wp.tid()
    out[tid] = env_pdf(env, dirs[tid])


@wp.kernel
def _sample_kernel(
    env: EnvMapData, seed: wp.int32, dirs: wp.array(dtype=wp.vec3), pdf: wp.array(dtype=wp.float32)
):
    tid = wp.tid()
    state = wp.rand_init(seed, tid)
    u = wp.vec2(wp.randf(state), wp.randf(state))
    d = env_sample(env, u)
    dirs[tid] = d
    pdf[tid] = env_pdf(env, d)


# ----------------------------------------------------------------------------- host side


@dataclass
class EnvMap:
    """An environment light ready for kernels (``data``) plus its host-side copies."""

    _data: EnvMapData
    width: int
    height: int
    n_clamped: int  # channel values (not pixels) that were negative or non-finite, set to 0
    pixels: np.ndarray  # (H, W, 3) float32, clamped and scaled
    name: str
    rotation_deg: float = 0.0
    scale: float = 1.0
    device: str = "cpu"
    # a hash of the map as given, before its scale (the input's values, dtype and shape): the same probe at any
    # exposure has the same one, so what does not depend on the exposure (the nu_a map) is cached by it
    source_digest: str = ""
    _keep: list = field(default_factory=list, repr=False)  # wp.arrays referenced by data
    _mips: list | None = field(default=None, repr=False)   # the MIP levels, once build_mip_pyramid made them
    _sampled: bool = field(default=True, repr=False)       # its sampling distribution is on the device

    @property
    def data(self) -> EnvMapData:
        """The kernels' struct, its sampling distribution built first where the map was loaded without it
        (``ensure_sampling``): whatever reads ``data`` may call ``env_sample`` and ``env_pdf``."""
        return ensure_sampling(self)._data

    @property
    def has_sampling(self) -> bool:
        """Whether its sampling distribution is on the device (else ``data`` builds it first)."""
        return self._sampled

    @property
    def lookup_data(self) -> EnvMapData:
        """The kernels' struct as it is, for a kernel that only looks the radiance up (no ``env_sample`` or
        ``env_pdf``): without ``ensure_sampling`` its distribution's arrays are empty."""
        return self._data

    @property
    def mip_levels(self) -> list[np.ndarray]:
        """Level 0 == pixels, then 2x2 box reductions down to 1x1 (built on first use, as on the device)."""
        return build_mip_pyramid(self)._mips


def _axis_box_matrix(n: int) -> np.ndarray:
    """(m, n) row-stochastic box filter n -> m = max(1, n // 2), exact 2:1 for even n.

    Output k averages the input over [k n / m, (k + 1) n / m) with fractional end coverage,
    so every input sample carries total weight m / n and the mean is preserved exactly.
    """
    m = max(1, n // 2)
    edges = np.arange(m + 1) * (n / m)
    lo = np.maximum(edges[:-1, None], np.arange(n)[None, :])
    hi = np.minimum(edges[1:, None], np.arange(n)[None, :] + 1.0)
    cover = np.clip(hi - lo, 0.0, None)
    return cover / cover.sum(axis=1, keepdims=True)


def _reduce_axis(x: np.ndarray, axis: int) -> np.ndarray:
    n = x.shape[axis]
    if n == 1:
        return x
    x = np.moveaxis(x, axis, 0)
    if n % 2 == 0:
        y = 0.5 * (x[0::2] + x[1::2])
    else:
        y = np.tensordot(_axis_box_matrix(n), x, axes=(1, 0))
    return np.moveaxis(y, 0, axis)


def build_mip_levels(pixels: np.ndarray) -> list[np.ndarray]:
    """MIP pyramid of an (H, W, 3) map: level 0 is the map, 2x2 box reductions down to 1x1."""
    cur = np.asarray(pixels, dtype=np.float64)
    levels = [np.ascontiguousarray(pixels, dtype=np.float32)]
    while cur.shape[0] > 1 or cur.shape[1] > 1:
        cur = _reduce_axis(_reduce_axis(cur, 0), 1)
        levels.append(np.ascontiguousarray(cur, dtype=np.float32))
    return levels


def mip_row_positions(heights) -> np.ndarray:
    """(n_levels, 2) float32 (v0, dv) of MIP levels of ``heights`` rows (``build_mip_levels``' sizes): row k of a
    level sits at ``v = v0 + k dv``, the centre of the level-0 rows it averages (level 0: row j at j / (H - 1)).
    Other counts are a one-line error: each level's positions follow from the one before (``[8, 3]`` was placed as
    ``[8, 4]``, and ``"12"`` or a float were read digit by digit or rounded)."""
    try:
        hs = list(heights)
    except TypeError:
        hs = None
    if (not hs or isinstance(heights, str) or not all(is_int(n) and n >= 1 for n in hs)
            or any(b != max(1, a // 2) for a, b in zip(hs, hs[1:]))):
        raise WarpbwError(f"mip_row_positions: heights: expected the row counts of build_mip_levels' levels (positive "
                          f"integers, each max(1, the previous // 2)), got {heights!r}")
    h0 = int(hs[0])
    v0, dv = 0.0, (1.0 / (h0 - 1) if h0 > 1 else 1.0)
    out = [(v0, dv)]
    for n in hs[:-1]:
        n = int(n)
        if n > 1:   # output k averages input rows [k n / m, (k + 1) n / m): centred at (k + 1/2) n / m - 1/2
            m = max(1, n // 2)
            v0, dv = v0 + dv * (0.5 * n / m - 0.5), dv * n / m
        out.append((v0, dv))
    return np.array(out, np.float32)


def _row_boundaries(height: int) -> np.ndarray:
    """theta at the H + 1 row-cell boundaries: 0, pi (j - 1/2) / (H - 1) for j = 1..H-1, pi."""
    if height == 1:
        return np.array([0.0, math.pi])
    inner = math.pi * (np.arange(1, height) - 0.5) / (height - 1)
    return np.concatenate([[0.0], inner, [math.pi]])


def texel_directions(width: int, height: int) -> np.ndarray:
    """(H, W, 3) local-frame directions of the texel centres (u = (i + 1/2) / W, v = j / (H - 1))."""
    width, height = check_count(width, "width", 1), check_count(height, "height", 1)   # 0 gave an empty array
    u = (np.arange(width) + 0.5) / width
    v = np.arange(height) / max(height - 1, 1)
    phi = 2.0 * math.pi * u[None, :]
    theta = math.pi * v[:, None]
    return np.stack(
        np.broadcast_arrays(np.sin(phi) * np.sin(theta), np.cos(theta), -np.cos(phi) * np.sin(theta)), axis=-1
    )


def _cell_average_filter(lum: np.ndarray) -> np.ndarray:
    """Average of the bilinear interpolant over each texel's cell (separable 1/8, 3/4, 1/8)."""
    # u: periodic (np.roll handles W == 1 and W == 2 correctly)
    f = 0.75 * lum + 0.125 * (np.roll(lum, 1, axis=1) + np.roll(lum, -1, axis=1))
    h = f.shape[0]
    if h == 1:
        return f
    g = 0.75 * f
    g[1:-1] += 0.125 * (f[:-2] + f[2:])
    # pole rows own half cells [0, 1/2] (in row units): average = 3/4 own + 1/4 neighbour
    g[0] += 0.25 * f[1]
    g[-1] += 0.25 * f[-2]
    return g


def _row_blocks(h: int, w: int) -> list[slice]:
    """The rows of an ``h`` x ``w`` map in blocks of about ``SANITIZE_BLOCK_TEXELS`` texels (at least one row)."""
    rows = max(1, SANITIZE_BLOCK_TEXELS // w)
    return [slice(r0, r0 + rows) for r0 in range(0, h, rows)]


def _build_distribution(pixels: np.ndarray) -> dict[str, np.ndarray]:
    h, w, _ = pixels.shape
    theta_b = _row_boundaries(h)
    cos_b = np.cos(theta_b)
    # 1 - cos and 1 + cos at the boundaries, computed without cancellation
    omc = 2.0 * np.sin(theta_b / 2.0) ** 2
    opc = 2.0 * np.cos(theta_b / 2.0) ** 2
    cell_omega = (cos_b[:-1] - cos_b[1:]) * (2.0 * math.pi / w)  # (H,) solid angle of one cell

    blocks = _row_blocks(h, w)   # float64 temporaries of the whole map held about 50 bytes per texel (session 63)
    lum = np.empty((h, w))
    for r in blocks:
        lum[r] = pixels[r].astype(np.float64) @ np.asarray(LUMINANCE_RGB)
    weight = _cell_average_filter(lum) * cell_omega[:, None]
    del lum
    total = weight.sum()
    if not (total > 0.0 and np.isfinite(total)):
        weight = np.broadcast_to(cell_omega[:, None], (h, w)).copy()  # all black: uniform sphere
        total = weight.sum()

    row_w = weight.sum(axis=1)
    cdf_m = np.concatenate([[0.0], np.cumsum(row_w)]) / total
    cdf_m32 = np.maximum.accumulate(cdf_m.astype(np.float32))
    cdf_m32[-1] = 1.0
    p_row = np.diff(cdf_m32.astype(np.float64))

    empty = ~(row_w > 0.0)
    cdf_c32 = np.empty((h, w + 1), np.float32)
    cell_pdf = np.empty((h, w), np.float32)
    for r in blocks:   # each row's conditional CDF is its own
        cdf_c = np.concatenate([np.zeros((weight[r].shape[0], 1)), np.cumsum(weight[r], axis=1)], axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            cdf_c = cdf_c / row_w[r, None]
        cdf_c[empty[r]] = np.linspace(0.0, 1.0, w + 1)[None, :]  # never chosen, kept well-formed
        c32 = np.maximum.accumulate(cdf_c.astype(np.float32), axis=1)
        c32[:, -1] = 1.0
        cdf_c32[r] = c32
        # the probabilities the float32 CDFs actually realise
        p_col = np.diff(c32.astype(np.float64), axis=1)
        cell_pdf[r] = p_row[r, None] * p_col / cell_omega[r, None]
    return {
        "marginal_cdf": cdf_m32.reshape(1, h + 1),
        "conditional_cdf": cdf_c32,
        "row_omc": omc.astype(np.float32),
        "row_opc": opc.astype(np.float32),
        "cell_pdf": cell_pdf,
    }


def _sanitize(rgb, name: str, scale: float, stacklevel: int) -> tuple[np.ndarray, int, str]:
    """The map times ``scale`` as float32 with its negative and non-finite values set to 0 (one warning counts
    them), and the map's ``source_digest`` (a hash of the input as given, before the scale).  Numeric input is
    converted, scaled and checked ``SANITIZE_BLOCK_TEXELS`` at a time, each block as the whole map would be (the
    same bits): a float64 copy of the whole map held 60 bytes per texel at the peak."""
    try:
        src = np.asarray(rgb)
        if src.dtype.kind not in "biuf":   # strings, objects: converted whole, refused as before
            src = np.asarray(src, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise WarpbwError(f"envmap {name!r}: pixels are not numeric ({exc})") from None
    if src.ndim != 3 or src.shape[2] != 3 or src.shape[0] < 1 or src.shape[1] < 1:
        raise WarpbwError(f"envmap {name!r}: expected an (H, W, 3) RGB array, got shape {src.shape}")
    h, w = src.shape[:2]
    out = np.empty((h, w, 3), np.float32)
    digest = hashlib.sha256(f"{src.dtype.str} {src.shape}".encode())   # 2.5x blake2b's speed here (4 ms per 1024x512)
    n_overflow, overflow_max, n_nonfinite, n_negative, n_pix = 0, 0.0, 0, 0, 0
    for r in _row_blocks(h, w):
        digest.update(np.ascontiguousarray(src[r]).tobytes())   # the values as given: a float32 probe, 12 B/texel
        arr = np.asarray(src[r], dtype=np.float64)
        with np.errstate(over="ignore", invalid="ignore"):
            block = (arr * scale).astype(np.float32)
        overflow = np.isfinite(arr) & ~np.isfinite(block)
        if overflow.any():  # finite texels that the scale (or the float32 cast) sends to inf: not a damaged map
            n_overflow += int(overflow.sum())
            overflow_max = max(overflow_max, float(np.abs(arr[overflow]).max()))
            continue
        finite = np.isfinite(block)
        bad = ~finite | (block < 0.0)
        if bad.any():
            n_nonfinite += int((~finite).sum())
            n_negative += int((finite & (block < 0.0)).sum())
            n_pix += int(bad.any(axis=2).sum())
            block[bad] = np.float32(0.0)
        out[r] = block
    if n_overflow:
        raise WarpbwError(f"envmap {name!r}: {n_overflow} channel values (up to {overflow_max:g}) times scale = "
                          f"{scale:g} exceed the float32 range; expected a smaller [environment] scale or smaller "
                          "map values")
    n_bad = n_nonfinite + n_negative
    if n_bad:
        warnings.warn(
            f"envmap {name!r}: set {n_bad} channel values to 0 in {n_pix} pixels "
            f"({n_negative} negative, {n_nonfinite} NaN or infinite)",
            RuntimeWarning,
            stacklevel=stacklevel + 1,
        )
    return out, n_bad, "sha256-source:" + digest.hexdigest()


def _check_scalar(value, what: str, name: str, nonnegative: bool = False) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise WarpbwError(f"envmap {name!r}: {what} must be a number, got {value!r}") from None
    if not math.isfinite(x) or (nonnegative and x < 0.0):
        need = "a finite number >= 0" if nonnegative else "a finite number"
        raise WarpbwError(f"envmap {name!r}: {what} must be {need}, got {value!r}")
    return x


def _make_envmap(rgb, rotation_deg, scale, name, device, stacklevel, sampling: bool = True) -> EnvMap:
    rotation_deg, scale = _check_envmap_args(rotation_deg, scale, name, device)
    pixels, n_clamped, digest = _sanitize(rgb, name, scale, stacklevel + 1)
    return _envmap_of(pixels, n_clamped, rotation_deg, scale, name, device, digest, sampling)


def _check_envmap_args(rotation_deg, scale, name, device) -> tuple[float, float]:
    check_device(device)
    return (_check_scalar(rotation_deg, "rotation_deg", name),
            _check_scalar(scale, "scale", name, nonnegative=True))


_DISTRIBUTION = (("marginal_cdf", (1, 0)), ("conditional_cdf", (0, 0)), ("row_omc", (0,)), ("row_opc", (0,)),
                 ("cell_pdf", (0, 0)))   # EnvMapData's sampling fields, and their empty shapes before ensure_sampling


def _envmap_of(pixels, n_clamped, rotation_deg, scale, name, device, source_digest, sampling: bool = True) -> EnvMap:
    """The EnvMap of sanitised ``pixels`` (float32, C order), its sampling distribution built (without ``sampling``:
    on first need, ``ensure_sampling``)."""
    h, w, _ = pixels.shape
    # first: its temporaries (about 32 bytes per texel) peak before the map's device copy is made
    dist = _build_distribution(pixels) if sampling else None
    keep = []

    def arr(x, dtype):
        a = wp.array(np.ascontiguousarray(x), dtype=dtype, device=device)
        keep.append(a)
        return a

    data = EnvMapData()
    data.base = arr(pixels, wp.vec3)
    data.width = w
    data.height = h
    rad = math.radians(rotation_deg)
    data.rot_cos = math.cos(rad)
    data.rot_sin = math.sin(rad)
    for key, shape in _DISTRIBUTION:
        setattr(data, key, arr(dist[key], wp.float32) if dist is not None
                else wp.zeros(shape, dtype=wp.float32, device=device))
    # no renderer reads the MIP pyramid (DESIGN: a stage the scene does not need is not run): until
    # build_mip_pyramid, the "pyramid" is level 0 alone, the map itself (no copy)
    data.mip_data = data.base.reshape((h * w,))   # a view of the map
    keep.append(data.mip_data)
    data.mip_offset = arr(np.zeros(1, np.int32), wp.int32)
    data.mip_width = arr(np.array([w], np.int32), wp.int32)
    data.mip_height = arr(np.array([h], np.int32), wp.int32)
    data.mip_row_v = arr(mip_row_positions([h]), wp.vec2)
    data.n_levels = 1
    env = EnvMap(
        _data=data,
        width=w,
        height=h,
        n_clamped=n_clamped,
        pixels=pixels,
        name=name,
        rotation_deg=rotation_deg,
        scale=scale,
        device=str(device),
        source_digest=source_digest,
        _keep=keep,
        _sampled=dist is not None,
    )
    return env


def ensure_sampling(env: EnvMap) -> EnvMap:
    """Build ``env``'s sampling distribution (what ``env_sample`` and ``env_pdf`` read) and put it on the device,
    once; returns ``env``.  A map loaded with ``sampling=False`` (``load_environment``) has none until then: a frame
    that samples no environment direction (the reference without MIS) does not build it."""
    check_instance(env, EnvMap, "ensure_sampling: env", "an EnvMap (load_envmap, constant_envmap, ...)")
    if not env._sampled:
        dist = _build_distribution(env.pixels)
        for key, _ in _DISTRIBUTION:
            a = wp.array(np.ascontiguousarray(dist[key]), dtype=wp.float32, device=env.device)
            setattr(env._data, key, a)
            env._keep.append(a)
        env._sampled = True
    return env


def check_env_data(env_data, where: str, sampled: bool = True) -> None:
    """Refuse, in one line naming ``where``, an ``env_data`` that is no EnvMapData with a map, or (``sampled``: a kernel
    that calls ``env_sample`` / ``env_pdf``) one without its sampling distribution: ``EnvMap.lookup_data`` of a map
    loaded with ``sampling=False``, whose empty arrays such a kernel read past their end (a segfault).  Shapes
    alone, not contents: the renderers call it every frame."""
    if not isinstance(env_data, EnvMapData.cls):
        raise WarpbwError(f"{where}: env_data: expected an EnvMapData (an EnvMap's .data), got "
                          f"{type(env_data).__name__}")
    h, w = int(env_data.height), int(env_data.width)
    base = env_data.base
    if base is None or h < 1 or w < 1 or tuple(base.shape) != (h, w):
        raise WarpbwError(f"{where}: env_data: expected an EnvMapData holding its map (an EnvMap's .data), got one "
                          f"without ({'no map' if base is None else f'a map of shape {tuple(base.shape)}'} for "
                          f"{w} x {h})")
    if not sampled:
        return
    expected = {"marginal_cdf": (1, h + 1), "conditional_cdf": (h, w + 1), "row_omc": (h + 1,), "row_opc": (h + 1,),
                "cell_pdf": (h, w)}
    if any(getattr(env_data, k) is None or tuple(getattr(env_data, k).shape) != shape for k, shape in expected.items()):
        raise WarpbwError(f"{where}: env_data: this pass samples the environment, and the EnvMapData given has no "
                          "sampling distribution (EnvMap.lookup_data of a map loaded with sampling=False); pass the "
                          "EnvMap's .data, which builds it (warpbw.envmap.ensure_sampling)")


def envmap_from_array(rgb, rotation_deg: float = 0.0, scale: float = 1.0, name: str = "array", device="cpu") -> EnvMap:
    """Environment light from an (H, W, 3) lat-long RGB array (row 0 = +Y, see module docstring).

    Negative, NaN and infinite values are set to 0 with one RuntimeWarning that counts them.
    """
    return _make_envmap(rgb, rotation_deg, scale, name, device, stacklevel=2)


def load_memory(width: int, height: int) -> int:
    """Bytes loading a ``width`` x ``height`` probe takes at the peak (``LOAD_BYTES_PER_TEXEL``)."""
    return LOAD_BYTES_PER_TEXEL * int(width) * int(height)


def file_load_memory(path) -> tuple[int, int, int]:
    """From an EXR's header alone: the probe's size, its display window (the frame ``read_rgb`` returns), and the
    bytes loading it takes at the peak, over the larger of that and its data window (the pixels decoded, which may be
    larger: overscan)."""
    from warpbw.io.exr import exr_size  # lazy: keeps this module importable on its own

    w, h = exr_size(path, window="display")
    data = exr_size(path)
    return w, h, load_memory(*max((w, h), data, key=lambda s: s[0] * s[1]))


def load_envmap(path, rotation_deg: float = 0.0, scale: float = 1.0, device="cpu", sampling: bool = True) -> EnvMap:
    """Environment light from a lat-long EXR file (via warpbw.io.exr.read_rgb): its display window spans the sphere,
    texels of it that the file does not store are 0.  Oriented as Mitsuba 3's ``envmap`` (the module docstring):
    row 0 is +Y (the zenith), the left edge looks down -Z, a quarter across +X, the middle +Z, three quarters -X; a
    probe made for a Z-up world or another renderer's layout is read in this one, and ``rotation_deg`` turns it
    about +Y only.  Radiance is linear as stored (an EXR's ``chromaticities`` other than Rec. 709's are converted).
    Without ``sampling`` its sampling distribution is built on first need (``ensure_sampling``)."""
    from warpbw.io.exr import read_rgb  # lazy: keeps this module importable on its own

    sampling = check_flag(sampling, "load_envmap: sampling")   # before the file is read
    w, h, need = file_load_memory(path)   # the header alone: a probe too large to load warns before it is read
    warn_if_short_of_memory(need, available_memory(), f"loading {Path(path).name} ({w}x{h})", "a smaller probe",
                            stacklevel=2)
    rgb = read_rgb(path)
    h, w = rgb.shape[:2]
    if w != 2 * h:   # e.g. a cube-map cross or an angular (mirror-ball) probe: read as lat-long, it is another light
        warnings.warn(f"envmap {Path(path).name!r}: {w}x{h} is not a 2:1 lat-long map (expected width = 2 x "
                      "height); read as lat-long anyway", RuntimeWarning, stacklevel=2)
    name = Path(path).name
    rotation_deg, scale = _check_envmap_args(rotation_deg, scale, name, device)
    pixels, n_clamped, digest = _sanitize(rgb, name, scale, stacklevel=2)
    del rgb   # the file's pixels, no longer needed while the distribution is built (12 bytes per texel)
    return _envmap_of(pixels, n_clamped, rotation_deg, scale, name, device, digest, sampling)


def constant_envmap(radiance, device="cpu") -> EnvMap:
    """A 4x8 map whose radiance is exactly ``radiance`` (RGB triple or scalar) in every direction."""
    try:
        rgb = np.broadcast_to(np.asarray(radiance, dtype=np.float64), (3,))
    except (TypeError, ValueError):
        raise WarpbwError(f"constant envmap: radiance must be a number or an RGB triple, got {radiance!r}") from None
    if not (np.all(np.isfinite(rgb)) and np.all(rgb >= 0.0)):
        raise WarpbwError(f"constant envmap: radiance must be finite and >= 0, got {radiance!r}")
    return _make_envmap(np.broadcast_to(rgb, (4, 8, 3)), 0.0, 1.0, "constant", device, stacklevel=2)


def load_environment(spec, device="cpu", sampling: bool = True) -> EnvMap:
    """The light of a scene's ``[environment]`` table (a ``warpbw.scene.Environment``: exactly one of
    ``file``, ``procedural = "sky"`` or ``constant``, with ``rotation`` and ``scale``).  Without ``sampling`` its
    sampling distribution is built on first need (``ensure_sampling``; ``EnvMap.data`` does it)."""
    from warpbw.scene import Environment   # lazy: keeps this module importable on its own

    sampling = check_flag(sampling, "load_environment: sampling")   # "no" built it, 0 deferred it
    # a file name (load_envmap takes it) was an AttributeError on .file
    check_instance(spec, Environment, "load_environment: spec", "a warpbw.scene.Environment (a scene's [environment]; "
                   "a probe file loads with load_envmap)")
    if spec.file is not None:
        return load_envmap(spec.file, rotation_deg=spec.rotation, scale=spec.scale, device=device, sampling=sampling)
    if spec.procedural == "sky":
        w, h = PROCEDURAL_SKY_SIZE
        return _make_envmap(procedural_sky(w, h), spec.rotation, spec.scale, "procedural sky", device, 2, sampling)
    return constant_envmap(tuple(c * spec.scale for c in spec.constant), device=device)   # 4 x 8 texels


# procedural sky colours (linear RGB), chosen by eye to read as a clear day
_SKY_ZENITH = np.array([0.18, 0.34, 0.80])
_SKY_HORIZON = np.array([0.70, 0.80, 0.95])
_GROUND = np.array([0.16, 0.13, 0.10])


def procedural_sky(
    width: int = 256,
    height: int = 128,
    sun_elevation_deg: float = 35.0,
    sun_azimuth_deg: float = 120.0,
    sun_radius_deg: float = 2.5,
    sun_radiance: float = 80.0,
) -> np.ndarray:
    """A built-in clear sky as an (H, W, 3) float32 lat-long map (Mitsuba convention).

    Blue gradient above the horizon (luminance about 0.3 to 0.8), a darker ground below, and a
    sun disk of ``sun_radiance`` (about 100x to 250x the sky) with a soft edge and a faint glow.
    The azimuth follows u: 0 degrees is -Z, 90 degrees is +X. Deterministic, no file needed.
    """
    width = check_count(width, "procedural_sky: width", 1)   # 8.5 was drawn 8 wide, None was int()'s TypeError
    height = check_count(height, "procedural_sky: height", 2)
    # NaN made the whole map NaN; "35" was math.isfinite's TypeError; a radiance of 1e39 is inf in float32
    sun_elevation_deg = check_real(sun_elevation_deg, "procedural_sky: sun_elevation_deg (degrees)")
    sun_azimuth_deg = check_real(sun_azimuth_deg, "procedural_sky: sun_azimuth_deg (degrees)")
    sun_radius_deg = check_real(sun_radius_deg, "procedural_sky: sun_radius_deg (degrees)", 0.0, lo_open=True)
    sun_radiance = check_real(sun_radiance, "procedural_sky: sun_radiance", 0.0)
    d = texel_directions(width, height)
    el = math.radians(sun_elevation_deg)
    az = math.radians(sun_azimuth_deg)
    sun = np.array([math.sin(az) * math.cos(el), math.sin(el), -math.cos(az) * math.cos(el)])
    y = d[..., 1:2]
    up = np.clip(y, 0.0, 1.0)
    t = np.sqrt(up)
    sky = _SKY_HORIZON * (1.0 - t) + _SKY_ZENITH * t
    ground = _GROUND * (0.6 + 0.4 * np.clip(1.0 + y, 0.0, 1.0))
    # soft horizon over about 1.5 degrees
    blend = np.clip(0.5 + y / (2.0 * math.sin(math.radians(1.5))), 0.0, 1.0)
    rgb = ground * (1.0 - blend) + sky * blend
    cos_a = np.clip(d @ sun, -1.0, 1.0)
    ang = np.arccos(cos_a)[..., None]
    r = math.radians(sun_radius_deg)
    edge = max(r * 0.25, math.pi / max(height - 1, 1) * 0.5)
    disk = np.clip((r + edge - ang) / (2.0 * edge), 0.0, 1.0)
    glow = 2.0 * np.exp(-((ang / (6.0 * r)) ** 2)) * blend
    sun_rgb = sun_radiance * np.array([1.0, 0.93, 0.82])
    rgb = rgb + glow * np.array([1.0, 0.9, 0.7]) + disk * sun_rgb
    return rgb.astype(np.float32)


# ----------------------------------------------------------------------------- debug wrappers


def _dirs_array(env: EnvMap, dirs) -> wp.array:
    """``dirs`` ((N, 3) or one (3,)) as unit vec3s on the environment's device, else a one-line error: (4, 2) was a
    ValueError from numpy's reshape, a zero direction read a pixel, and a long one a NaN latitude."""
    if not isinstance(env, EnvMap):
        got = "its .data (a Warp struct)" if isinstance(env, EnvMapData.instance_type) else type(env).__name__
        raise WarpbwError(f"env: expected an EnvMap (load_envmap, constant_envmap, ...), got {got}")
    try:
        d = np.asarray(dirs, dtype=np.float64)
    except (TypeError, ValueError):
        raise WarpbwError(f"dirs: expected (N, 3) directions, got {type(dirs).__name__}") from None
    if d.shape != (3,) and (d.ndim != 2 or d.shape[1] != 3):
        raise WarpbwError(f"dirs: expected (N, 3) directions (or one (3,)), got shape {d.shape}")
    d = unit_directions(d.reshape(-1, 3), "dirs")
    return wp.array(np.ascontiguousarray(d, dtype=np.float32), dtype=wp.vec3, device=env.device)


def eval_radiance(env: EnvMap, dirs) -> np.ndarray:
    """(N, 3) radiance towards the (N, 3) world directions."""
    d = _dirs_array(env, dirs)
    out = wp.empty(d.shape[0], dtype=wp.vec3, device=env.device)
    wp.launch(_eval_radiance_kernel, dim=d.shape[0], inputs=[env.data, d, out], device=env.device)
    return out.numpy()


def build_mip_pyramid(env: EnvMap) -> EnvMap:
    """Build ``env``'s MIP pyramid (``build_mip_levels``) and put it on the device, once; returns ``env``.  A
    kernel that calls ``env_radiance_lod`` needs it: before it, every lod reads level 0."""
    check_instance(env, EnvMap, "build_mip_pyramid: env", "an EnvMap (load_envmap, constant_envmap, ...)")
    if env._mips is None:
        levels = build_mip_levels(env.pixels)
        offsets = np.cumsum([0] + [lv.shape[0] * lv.shape[1] for lv in levels[:-1]]).astype(np.int32)
        packed = np.concatenate([lv.reshape(-1, 3) for lv in levels]).astype(np.float32)
        arrays = [wp.array(np.ascontiguousarray(x), dtype=t, device=env.device) for x, t in (
            (packed, wp.vec3), (offsets, wp.int32), (np.array([lv.shape[1] for lv in levels], np.int32), wp.int32),
            (np.array([lv.shape[0] for lv in levels], np.int32), wp.int32),
            (mip_row_positions([lv.shape[0] for lv in levels]), wp.vec2))]
        (env._data.mip_data, env._data.mip_offset, env._data.mip_width, env._data.mip_height,
         env._data.mip_row_v) = arrays
        env._data.n_levels = len(levels)
        env._keep.extend(arrays)
        env._mips = levels
    return env


def eval_radiance_lod(env: EnvMap, dirs, lod) -> np.ndarray:
    """(N, 3) trilinear MIP lookup; lod is a scalar or (N,) finite levels (clamped to the pyramid's, 0 the map
    itself).  Builds the pyramid first (``build_mip_pyramid``)."""
    d = _dirs_array(env, dirs)
    n = d.shape[0]
    lods = numeric_array(lod, "lod", "a number or one per direction")   # "x" and None: numpy's errors
    if lods.shape not in ((), (n,)) or not np.all(np.isfinite(lods)):   # NaN read level 0 without a word
        raise WarpbwError(f"lod: expected a finite level, or {n} of them (one per direction), got "
                          + (f"shape {lods.shape}" if lods.shape not in ((), (n,)) else "NaN or infinite values"))
    build_mip_pyramid(env)
    lods = np.broadcast_to(lods.astype(np.float32), (n,))
    lw = wp.array(np.ascontiguousarray(lods), dtype=wp.float32, device=env.device)
    out = wp.empty(n, dtype=wp.vec3, device=env.device)
    wp.launch(_eval_radiance_lod_kernel, dim=n, inputs=[env.data, d, lw, out], device=env.device)
    return out.numpy()


def eval_pdf(env: EnvMap, dirs) -> np.ndarray:
    """(N,) solid-angle pdf of env_sample at the (N, 3) world directions."""
    d = _dirs_array(env, dirs)
    out = wp.empty(d.shape[0], dtype=wp.float32, device=env.device)
    wp.launch(_eval_pdf_kernel, dim=d.shape[0], inputs=[env.data, d, out], device=env.device)
    return out.numpy()


def sample_directions(env: EnvMap, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """n directions drawn by env_sample (Warp RNG seeded by seed) and their pdfs."""
    check_instance(env, EnvMap, "env", "an EnvMap (load_envmap, constant_envmap, ...)")
    n = check_count(n, "n", 0)
    seed = check_seed(seed)   # 2**32 drew seed 0's directions, 1.9 and "0" were taken
    dirs = wp.empty(n, dtype=wp.vec3, device=env.device)
    pdf = wp.empty(n, dtype=wp.float32, device=env.device)
    wp.launch(_sample_kernel, dim=n, inputs=[env.data, int(seed), dirs, pdf], device=env.device)
    return dirs.numpy(), pdf.numpy()
