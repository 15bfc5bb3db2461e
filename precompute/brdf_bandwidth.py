"""Angular bandwidth tables of BRDF lobes (002 Sec. 2.3, "Reflectance (angular)").

Public:
    ``N_THETA_I`` (16), ``N_CELLS`` (16), ``SHAPE`` (the table's), ``DEFAULT_RESOLUTION`` (128), ``FORMAT``,
    ``VERSION``
    ``brdf_bandwidth_table(evaluate, resolution=128, progress=None, threads=None) -> (16, 16, 16) float32``
        (``evaluate(wi, wo) -> (N, 3)``, RGB; ``threads``: the slices' analyses run on that many, default one per
        core up to ``TABLE_THREADS_MAX``, bit for bit one thread's table)
    ``analytic_brdf_bandwidth_table(evaluate, resolution=128) -> (16, 16, 16) float32``
    ``build_brdf_bandwidth(source, progress=True, resolution=128, threads=None) -> (16, 16, 16) float32``
        (``source``: what :func:`precompute.brdf_sampling.brdf_source` returns, not a path)
    ``write_brdf_bandwidth(path, table, source, force=False)`` / ``read_brdf_bandwidth(path, source=None)``   (the
        writer refuses the tables the reader refuses, and never writes over the source's file or a read-only file;
        the reader refuses a table of another lookup than the source's, below)
    ``load_or_build_bandwidth(source, explicit=None, cache=None, progress=True) -> (table, origin)``
    ``bandwidth_settings(resolution=128) -> dict``, ``BANDWIDTH_UNRECORDED``   the builder settings a table records
    ``theta_i_centres()``, ``wo_map(n)``, ``wo_to_map(wo)``, ``map_radians_per_pixel(n)``,
    ``nu_rho_max(resolution)``, ``lobe_slice(evaluate, theta_i, resolution)``, ``slice_bandwidth(f)``,
    ``narrowest_band(n)``, ``GRAZING_LIMIT``, ``UNRESOLVED_PEAK``   one lobe's map (each checks its input: ``n``
    and ``resolution`` integers >= 1, ``wo`` finite non-zero 3-vectors, ``theta_i`` in [0, pi/2) radians, ``f`` a
    square slice, ``evaluate`` and ``progress`` callables; else a one-line ``WarpbwError``)

Table: ``nu_rho[t, row, col]`` in cycles/radian, float32, shape ``(N_THETA_I, N_CELLS, N_CELLS)``:
``t`` = incident-elevation bin (centres ``theta_i = (t + 1/2) (pi/2) / 16``, uniform over
[0, pi/2)), ``(row, col)`` = 16x16 cell of the outgoing-direction map below.

Isotropy.  The BRDFs warpbw reads (MERL, NPF, Lambert, GGX) are isotropic, so the lobe for an
incident direction of azimuth phi_i is the phi_i = 0 lobe rotated by phi_i about +Z: we drop the
incident azimuth and tabulate ``wi = (sin theta_i, 0, cos theta_i)`` only.  A lookup rotates
``wo`` by ``-phi_i`` about +Z first.  (The paper's 16x16 *input* directions are for general 4D
data; for isotropic data the second input axis is redundant.)

What is analysed.  The lobe itself, ``rho(wi, .) = f(wi, wo)``, not ``f cos(theta_o)``: the paper
takes "the angular bandwidth map of the outgoing BRDF lobe", and rho is the factor whose spectrum
enters the shading integrand ``L_i rho`` (Sec. 2.4).  The slice is divided by its maximum (over
pixels and channels); the estimator's significance floor is relative to the slice's strongest
coefficient, so this scale does not change the result and only keeps HDR lobes (chrome peaks at
~1e3-1e4 /sr) well scaled.  We deliberately do *not* take a log: a log changes the spectrum (a
Gaussian lobe becomes a parabola, with energy at every scale) and would credit high frequencies to
tails that carry no energy in the integrand.  Channels: the slice analysed is the sum of the
colour channels (one wavelet analysis instead of three, 3x faster).  The channels of a lobe share
its shape and differ by scale (rho_d, rho_s, Fresnel tint); a fast feature present in one channel
only is kept unless it is under the 1% significance floor, which it would be in a joint
analysis too, the floor being relative to the strongest coefficient over all channels.

Outgoing map: Lambert azimuthal equal-area projection of the upper hemisphere onto the unit disc,
``(x, y) = r (cos phi_o, sin phi_o)``, ``r = sqrt(2) sin(theta_o / 2)`` (``r = 1`` at the horizon),
rasterised on ``n x n`` pixels covering the square [-1, 1]^2: column ``c`` at
``x = -1 + (c + 1/2) 2/n``, row ``k`` at ``y = -1 + (k + 1/2) 2/n`` (row index increases with
wo.y; the plane of incidence is the x axis, the mirror direction of wi lies at x < 0).

Grazing limit and the border.  Microfacet forms (NPF, GGX) and measured data carry a
``1/cos(theta_o)`` that diverges at the horizon (pink-felt's lobe there is ~10x its interior), where
the integrand ``f cos`` that shading sees is near zero; analysed as is, that divergence (a 1-pixel
rise at n = 128) sets every slice's bandwidth to the resolution limit.  So f is evaluated only up to
``GRAZING_LIMIT`` = 85 deg; beyond it, along each azimuth, the lobe is continued by odd
reflection, ``f(theta) = 2 f(85 deg) - f(170 deg - theta)``, which keeps value and slope
continuous, through the rim and the square's corners (the map formula extended to ``r <= sqrt 2``),
and the image is edge-padded for the wavelet transform.  Zero padding or a hard stop would put a
false step or kink at the rim (a Lambert lobe would read as a sharp disc).  Cells beyond the rim
carry the bandwidth of that continuation: a by-product, never looked up for real directions (a look-up,
:func:`wo_to_map` and the renderer's, puts every direction at ``r <= 1``).  A cell crossing the rim takes
only its pixels of real directions (below): the continuation's pixels had put GGX's rim cells up to 1.9x,
gold-metallic-paint's 1.8x, above what their real pixels give (session 67).

Jacobian to radians (per unit of map coordinate, at ``r``; ``cos(theta_o/2) = sqrt(1 - r^2/2)``):
radial ``d theta / d r = sqrt(2) / cos(theta_o/2)`` (sqrt 2 .. 2), tangential
``sin(theta_o) / r = sqrt(2) cos(theta_o/2)`` (sqrt 2 .. 1); their product is 2 everywhere (equal
area: 2 pi sr over a disc of area pi).  A pixel is ``2/n`` map units, so the radians per pixel
are those times ``2/n``.  We convert cycles/pixel to cycles/radian by dividing by the *smaller*
one, ``lambda_min = sqrt(2 - r^2) * 2/n`` (r clamped to 1): the estimator does not say in which
direction the signal varies, and the smaller side gives the larger bandwidth (conservative, as the
block maximum below).  A purely radial variation is overestimated by ``1/cos^2(theta_o/2)``: 1 at
the zenith, 2 at the horizon; at the zenith the map is isotropic (sqrt(2) * 2/n rad per pixel).

Resolution: at n = 128 a pixel is 0.022 rad (1.3 deg) at the zenith, so the largest expressible
bandwidth (0.5 cycles/pixel) is ~22 cycles/radian there; narrower lobes (a mirror) saturate (a lobe of one pixel
reads ~0.34 cycles/pixel: ~15 cycles/radian at the zenith, ~21 near the rim), as long as a pixel centre sees them:
the slice is sampled at the pixel centres, which miss a lobe narrower than a pixel between them (a MERL mirror whose
lobe lies in its first 5 theta_h bins, theta_h < 0.28 deg, read 0 in every cell before session 76).  So f is also
evaluated at the mirror direction, on the edge of two pixels; where it exceeds both their values UNRESOLVED_PEAK
times over, the peak is unresolved and both pixels read what a lobe of those two pixels reads, the narrowest the
map resolves (``narrowest_band``: 0.34 cycles/pixel, as chrome's measured lobe reads; the map's limit, 0.5, moved
chrome's cells from 15.3 to 22.6-30 cycles/radian and cost its benchmark frames 0.02-0.2 dB).  Bin 15's mirror
direction (87.2 deg) lies past ``GRAZING_LIMIT`` (below), where the lobe is continued from 85 deg: a lobe past it
speaks through its flank up to 85 deg only
(gold-metallic-paint's mirror cell there reads 18.1 cycles/radian, 19.4 when evaluated up to 89.5 deg).  The
per-pixel bandwidth (:func:`precompute.wavelets.local_bandwidth`, 95% energy rule, db4, 7 bands:
periods 2 .. 256 px, so a lobe broader than the map reads as at most ~2^-7.5 cycles/px, ~0.25
cycles/radian; an exactly constant lobe reads 0) is
reduced to 16x16 cells by a MAX over each ``n/16`` x ``n/16`` block (conservative), as the paper
computes "the bandwidth for higher-resolution angular slices and scale[s] down the slices".  In a block
that holds real directions the max runs over its pixels whose square meets the closed disc ``r <= 1``
(centre inside the rim or not: every real direction a look-up can put in the cell lies in one of them,
down to a cell the rim only grazes, as at n = 16 or 32); a block wholly beyond the rim takes all its pixels.

Lookup.  A tabulated BRDF's table is the bandwidth of the BRDF its material shades: ``source.evaluate`` reads the
MERL or NPF tables with the source's lookup (``brdf_source(file, material, lookup)``; the renderer asks for the
material's ``lookup``).  The nearest-bin steps of an NPF fit read faster than its interpolated curves in places (the
nearest table over the linear one, by the cell: median 1.00-1.01x, 99th percentile 1.05-1.20x, largest 1.30-1.94x
over gold-metallic-paint, chrome and color-changing-paint3; session 70), so a table of the other lookup may lie below
what is shaded.  The file records the lookup (``params["lookup"]``); the reader refuses a table of
another lookup than its source's, naming both and the command that rebuilds it.  A file written before session 70
records none: it was built with its kind's default (``precompute.brdf_sampling.TABLE_LOOKUP``: MERL nearest, NPF
linear) and is read for that lookup only.  The cache keys the tables by the source's digest, which carries any other
lookup (``:lookup-nearest``), so the default's entries are the ones built before.

Builder settings. A table records what it was built with (``bandwidth_settings(resolution)``: its cells, the
analysed resolution, and the wavelet analysis's wavelet, bands, epsilon and energy fraction,
:mod:`precompute.wavelets`; beside them the map, the units and the lookup). A cache entry is read only when they
equal the builder's current ones (at ``DEFAULT_RESOLUTION``; ``precompute.assetfile.settings_mismatch``), else it is
rebuilt and replaced without a word, so that ``precompute.wavelets.EPSILON`` changed without a version bump no
longer serves the old tables. A file written before session 71 records no wavelet settings; it was built with db4, 7
bands, epsilon 0.01 and 95% of the energy (``BANDWIDTH_UNRECORDED``). A file the scene names (``bandwidth =``) is
read whatever settings it records (one that ``build_brdf_bandwidth`` analysed at a ``resolution`` of 64 and
``write_brdf_bandwidth`` wrote with it, say).

Cost: ``16 (n^2 + p)`` BRDF evaluations, ``p`` the pixels past ``GRAZING_LIMIT`` (28% of ``n^2``: 4,628 at n = 128,
each evaluated once more at its mirrored elevation), and 16 wavelet analyses; a few seconds per material at n = 128.
"""
from __future__ import annotations

import functools
import json
import math
import os
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from typing import Callable

import numpy as np

from precompute.assetfile import check_float_arrays, read_asset, write_asset
from precompute.progress import progress_callback
from precompute.wavelets import local_bandwidth
from warpbw.errors import WarpbwError, check_count, check_real, is_int, unit_directions
from warpbw.scene import LOOKUP_MODES

__all__ = [
    "N_THETA_I", "N_CELLS", "SHAPE", "DEFAULT_RESOLUTION", "FORMAT", "VERSION",
    "GRAZING_LIMIT", "UNRESOLVED_PEAK", "narrowest_band", "theta_i_centres", "wo_map", "wo_to_map",
    "map_radians_per_pixel", "nu_rho_max", "lobe_slice", "slice_bandwidth",
    "brdf_bandwidth_table", "analytic_brdf_bandwidth_table", "build_brdf_bandwidth",
    "write_brdf_bandwidth", "read_brdf_bandwidth", "load_or_build_bandwidth", "bandwidth_settings",
    "BANDWIDTH_UNRECORDED",
]

N_THETA_I = 16          # incident elevations (bin centres uniform over [0, pi/2)); paper: 16 inputs
N_CELLS = 16            # outgoing map cells per side; paper: "a 16x16 image for each reflectance lobe"
DEFAULT_RESOLUTION = 128  # analysed slice, n x n pixels (a multiple of N_CELLS)
FORMAT = "warpbw.brdf-bandwidth"
VERSION = 4   # 4: an unresolved peak at the mirror direction reads a two-pixel lobe's band (session 76); 3: a cell
              # crossing the rim takes its real directions' pixels only (session 67); 2: wavelet bands centred on the
              # cascade's delays (session 58); 1: on one level's
SHAPE = (N_THETA_I, N_CELLS, N_CELLS)
GRAZING_LIMIT = math.radians(85.0)  # outgoing elevations past this are continued, not evaluated
# A lobe whose value at the mirror direction exceeds both pixels beside it this many times over is unresolved (ours)
UNRESOLVED_PEAK = 2.0
WAVELET_LEVELS = 7                  # bands analysed: periods 2 .. 256 px (module docstring)
# Threads the slices' wavelet analyses share, at most (ours): pywt's transforms (96% of a table's time) release the
# GIL, and 2 threads built gold-metallic-paint's table in 3.3 s against 6.3 s on one (2 cores; bit for bit the same)
TABLE_THREADS_MAX = N_THETA_I
# What a table built before session 71 was built with where it records nothing: precompute.wavelets' defaults and
# WAVELET_LEVELS, unchanged since the first tables
BANDWIDTH_UNRECORDED = {"wavelet": "db4", "wavelet_levels": 7, "epsilon": 0.01, "energy_fraction": 0.95}


def _analysis() -> dict:
    """The wavelet analysis a slice's bandwidth takes (``precompute.wavelets``' constants, read now)."""
    from precompute import wavelets

    return {"wavelet": wavelets.DEFAULT_WAVELET, "wavelet_levels": WAVELET_LEVELS, "epsilon": wavelets.EPSILON,
            "energy_fraction": wavelets.ENERGY_FRACTION}


def bandwidth_settings(resolution: int = DEFAULT_RESOLUTION) -> dict:
    """The settings ``build_brdf_bandwidth`` builds with at ``resolution``, as a table's ``params`` records them
    (module docstring, "Builder settings"; beside them it records the map and the units, which name what the table
    is, and the lookup, which the reader checks).  ``resolution`` is checked as the builder checks it (1.5 or "1"
    were recorded as 1, 0 and -1 as they came)."""
    return {"n_theta_i": N_THETA_I, "n_cells": N_CELLS, "resolution": _check_resolution(resolution), **_analysis()}


def theta_i_centres() -> np.ndarray:
    """Incident elevations of the table's bins, radians: ``(t + 1/2) (pi/2) / N_THETA_I``."""
    return (np.arange(N_THETA_I) + 0.5) * (0.5 * math.pi / N_THETA_I)


def _pixel_coords(n: int) -> tuple[np.ndarray, np.ndarray]:
    n = check_count(n, "n", 1)   # 0 divided by zero, -2 gave an empty map, 2.5 a 3x3 one
    c = -1.0 + (np.arange(n) + 0.5) * (2.0 / n)
    x, y = np.meshgrid(c, c)  # x varies along columns, y along rows
    return x, y


def _map_angles(n: int) -> tuple[np.ndarray, np.ndarray]:
    """``(theta_o, phi_o)`` of the pixel centres; past the disc (r > 1) the map's formula goes on,
    ``theta_o = 2 asin(r / sqrt 2)`` up to pi at the corners (used only by the extension)."""
    x, y = _pixel_coords(n)
    r = np.minimum(np.hypot(x, y), math.sqrt(2.0))
    return 2.0 * np.arcsin(r / math.sqrt(2.0)), np.arctan2(y, x)


def _dirs(theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    s = np.sin(theta)
    return np.stack([s * np.cos(phi), s * np.sin(phi), np.cos(theta)], axis=-1)


def wo_map(n: int) -> np.ndarray:
    """Outgoing directions at the ``n x n`` pixel centres of the equal-area map, ``(n, n, 3)``.

    Elevations are clamped to ``GRAZING_LIMIT`` (pixels beyond it: module docstring)."""
    theta, phi = _map_angles(n)
    return _dirs(np.minimum(theta, GRAZING_LIMIT), phi)


def wo_to_map(wo) -> np.ndarray:
    """Map coordinates ``(x, y)`` in [-1, 1]^2 of directions ``wo`` (..., 3) of the upper hemisphere.

    Cell of a table: ``col = floor((x + 1) / 2 * N_CELLS)``, ``row = floor((y + 1) / 2 * N_CELLS)``.  ``wo`` need
    not be unit length; a direction below the horizon maps onto the rim (r = 1).  A zero, NaN or infinite one is
    refused (it gave NaN coordinates)."""
    try:
        wo = np.asarray(wo, dtype=np.float64)
    except (TypeError, ValueError):
        raise WarpbwError(f"wo: expected directions of 3 components, (..., 3), got {type(wo).__name__}") from None
    if wo.ndim < 1 or wo.shape[-1] != 3:
        raise WarpbwError(f"wo: expected directions of 3 components, (..., 3), got shape {wo.shape}")
    wo = unit_directions(wo, "wo")
    theta = np.arccos(np.clip(wo[..., 2], -1.0, 1.0))
    r = math.sqrt(2.0) * np.sin(np.minimum(theta, 0.5 * math.pi) / 2.0)
    phi = np.arctan2(wo[..., 1], wo[..., 0])
    return np.stack([r * np.cos(phi), r * np.sin(phi)], axis=-1)


def map_radians_per_pixel(n: int) -> np.ndarray:
    """Smaller side of each pixel in radians, ``sqrt(2 - r^2) * 2/n`` with r clamped to 1, ``(n, n)``."""
    x, y = _pixel_coords(n)
    r = np.minimum(np.hypot(x, y), 1.0)
    return np.sqrt(2.0 - r * r) * (2.0 / n)


def _check_resolution(resolution: int) -> int:
    """``resolution`` (pixels per side of the analysed slice) as an int: a multiple of N_CELLS, else a WarpbwError."""
    n = check_count(resolution, "resolution", N_CELLS)
    if n % N_CELLS:
        raise WarpbwError(f"resolution: expected a multiple of {N_CELLS} (the table's cells per side; default "
                          f"{DEFAULT_RESOLUTION}), got {n}")
    return n


def _check_evaluate(evaluate) -> None:
    if not callable(evaluate):
        raise WarpbwError(f"evaluate: expected a function evaluate(wi, wo) -> (N, 3), got {evaluate!r}")


def _evaluated(evaluate: Callable, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """``evaluate(wi, wo)`` as float64 ``(N, 3)``; any other shape (a grey ``(N,)`` lobe) refused in one line."""
    n = len(wi)
    try:
        f = np.asarray(evaluate(wi, wo), dtype=np.float64)
    except (TypeError, ValueError):   # None, strings, ragged lists
        raise WarpbwError(f"evaluate: returned no numeric array for {n} direction pairs (expected shape ({n}, 3), "
                          "one RGB value per pair)") from None
    if f.shape != (n, 3):
        raise WarpbwError(f"evaluate: returned shape {f.shape} for {n} direction pairs (expected ({n}, 3), one RGB "
                          "value per pair)")
    return f


def lobe_slice(evaluate: Callable, theta_i: float, resolution: int = DEFAULT_RESOLUTION) -> np.ndarray:
    """``f(wi, wo)`` over the outgoing map for ``wi = (sin theta_i, 0, cos theta_i)``, ``(n, n, 3)`` float64.

    Past ``GRAZING_LIMIT`` the lobe is continued by odd reflection about the limit along each
    azimuth, ``f(theta) = 2 f(theta_max) - f(2 theta_max - theta)`` (value and slope continuous).  ``theta_i`` is
    the incident elevation from the zenith, in [0, pi/2) radians: at or below the horizon a BRDF is zero (2.0 gave a
    slice of zeros, and a bandwidth of 0, without a word)."""
    n = _check_resolution(resolution)
    _check_evaluate(evaluate)
    theta_i = check_real(theta_i, "theta_i", 0.0)
    if not theta_i < 0.5 * math.pi:
        raise WarpbwError(f"theta_i: expected an incident elevation in [0, pi/2) radians (from the zenith; at or below "
                          f"the horizon the lobe is zero), got {theta_i!r}")
    theta, phi = _map_angles(n)
    past = theta > GRAZING_LIMIT
    w = np.array([math.sin(theta_i), 0.0, math.cos(theta_i)])

    def ev(th, ph):   # f at the outgoing directions (th, ph), 1-D arrays
        return _evaluated(evaluate, np.ascontiguousarray(np.broadcast_to(w, (th.size, 3))), _dirs(th, ph))

    f = ev(np.minimum(theta, GRAZING_LIMIT).ravel(), phi.ravel()).reshape(n, n, 3)
    if np.any(past):   # the mirrored directions of the pixels past the limit only (they had all n^2 evaluated)
        f[past] = 2.0 * f[past] - ev(np.maximum(2.0 * GRAZING_LIMIT - theta[past], 0.0), phi[past])
    return f


def _unresolved_peak(evaluate: Callable, theta_i: float, f: np.ndarray) -> np.ndarray:
    """``(n, n)`` bool: the two pixels of the slice ``f`` (``lobe_slice``'s) whose shared edge holds the mirror
    direction ``(theta_i, pi)``, where the lobe exceeds both their values ``UNRESOLVED_PEAK`` times over (the sum of
    its channels): a peak narrower than the pixels, which their centres miss (module docstring, "Resolution").  All
    False where it does not, or where the mirror direction lies past ``GRAZING_LIMIT``."""
    n = f.shape[0]
    mask = np.zeros((n, n), dtype=bool)
    if n < 2 or theta_i > GRAZING_LIMIT:
        return mask
    mirror = _dirs(np.array([theta_i]), np.array([math.pi]))
    col = min(int((wo_to_map(mirror)[0, 0] + 1.0) * 0.5 * n), n - 1)   # its y is 0: the edge of the middle rows
    wi = np.array([[math.sin(theta_i), 0.0, math.cos(theta_i)]])
    peak = float(_evaluated(evaluate, wi, mirror)[0].sum())
    rows = [n // 2 - 1, n // 2]
    if peak > UNRESOLVED_PEAK * float(f[rows, col].sum(axis=-1).max()):
        mask[rows, col] = True
    return mask


def slice_bandwidth(f: np.ndarray) -> np.ndarray:
    """Per-pixel angular bandwidth (cycles/radian, ``(n, n)``) of one lobe slice ``(n, n[, C])`` (channels summed).
    A slice that is not square (numpy's broadcast error), empty, or of other rank is refused."""
    try:
        f = np.asarray(f, dtype=np.float64)
    except (TypeError, ValueError):
        raise WarpbwError("f: expected a lobe slice of numbers, (n, n) or (n, n, C)") from None
    if f.ndim not in (2, 3) or f.shape[0] != f.shape[1] or f.shape[0] < 1 or (f.ndim == 3 and f.shape[2] < 1):
        raise WarpbwError(f"f: expected a square lobe slice (n, n) or (n, n, C) over the outgoing map, got shape "
                          f"{f.shape}")
    if f.ndim == 3:
        f = f.sum(axis=-1)
    n = f.shape[0]
    if not np.all(np.isfinite(f)):
        raise WarpbwError("BRDF lobe has NaN or infinite values; its bandwidth is undefined")
    peak = float(np.max(np.abs(f))) if f.size else 0.0
    if peak <= 0.0:
        return np.zeros((n, n))
    return _cycles_per_pixel(f / peak, _analysis()) / map_radians_per_pixel(n)   # what the table records


def _cycles_per_pixel(f: np.ndarray, k: dict) -> np.ndarray:
    """The local bandwidth of slice ``f``, cycles/pixel, under the analysis ``k`` (``_analysis``'s)."""
    return local_bandwidth(f, k["epsilon"], k["wavelet"], k["wavelet_levels"], pad="edge",
                           energy_fraction=k["energy_fraction"])


def _real_pixels(n: int) -> np.ndarray:
    """``(n, n)`` bool: the pixels that hold real directions, those whose square meets the closed disc ``r <= 1``
    (the square's nearest point to the map's centre lies within it), centre beyond the rim or not."""
    x, y = _pixel_coords(n)
    half = 1.0 / n   # half a pixel's side, 2/n map units
    return np.hypot(np.maximum(np.abs(x) - half, 0.0), np.maximum(np.abs(y) - half, 0.0)) <= 1.0


def _block_max(a: np.ndarray) -> np.ndarray:
    """16x16 cells of a per-pixel map: the max over the block's pixels of real directions (``_real_pixels``), or
    over the whole block where it holds none (beyond the rim: the continuation's, module docstring)."""
    n = a.shape[0]
    k = n // N_CELLS
    blocks = a.reshape(N_CELLS, k, N_CELLS, k)
    real = _real_pixels(n).reshape(N_CELLS, k, N_CELLS, k)
    return np.where(real.any(axis=(1, 3)), np.where(real, blocks, -np.inf).max(axis=(1, 3)), blocks.max(axis=(1, 3)))


def brdf_bandwidth_table(evaluate: Callable, resolution: int = DEFAULT_RESOLUTION,
                         progress: Callable[[int], None] | None = None, threads: int | None = None) -> np.ndarray:
    """nu_rho table ``(16, 16, 16)`` float32, cycles/radian, of any numpy ``evaluate(wi, wo) -> (N, 3)``.

    ``progress(k)`` is called after each of the 16 incident elevations with the count done (checked before the
    first slice: a non-callable one failed only after it).  The slices' wavelet analyses run on ``threads`` threads
    (default: one per CPU core, at most ``TABLE_THREADS_MAX``); ``evaluate`` is only ever called from the calling
    thread, and the table is bit for bit the one thread's."""
    n = _check_resolution(resolution)
    _check_evaluate(evaluate)
    if progress is not None and not callable(progress):
        raise WarpbwError(f"progress: expected a function progress(k) or None, got {progress!r}")
    threads = min(os.cpu_count() or 1, TABLE_THREADS_MAX) if threads is None else \
        check_count(threads, "threads", 1, TABLE_THREADS_MAX)
    out = np.zeros(SHAPE, dtype=np.float32)
    pending = deque()   # (t, the analysis of slice t), in order of t
    with ThreadPoolExecutor(threads) as pool:
        try:
            for t, th in enumerate(theta_i_centres()):   # each slice is evaluated here, then analysed on the pool
                f = lobe_slice(evaluate, float(th), n)
                pending.append((t, pool.submit(_peaked_bandwidth, f, _unresolved_peak(evaluate, float(th), f))))
                if len(pending) > threads:   # at most threads + 1 slices held at once
                    _take(out, pending, progress)
            while pending:
                _take(out, pending, progress)
        except BaseException:   # an error or Ctrl-C: the slices not yet analysed are dropped
            for _, f in pending:
                f.cancel()
            raise
    return out


def _peaked_bandwidth(f: np.ndarray, peak: np.ndarray) -> np.ndarray:
    """``slice_bandwidth(f)``, with the pixels of an unresolved peak (``_unresolved_peak``'s mask) at least at a
    two-pixel lobe's band (``narrowest_band``)."""
    b = slice_bandwidth(f)
    return np.where(peak, np.maximum(b, narrowest_band(f.shape[0]) / map_radians_per_pixel(f.shape[0])), b)


def narrowest_band(n: int) -> float:
    """Cycles per pixel that the analysis reads on a lobe of two vertically adjacent pixels of an ``n x n`` map (the
    narrowest lobe the map resolves; what an unresolved peak is given): 0.34 at n = 128, in whichever column."""
    return _narrowest_band(_check_resolution(n), tuple(sorted(_analysis().items())))


@functools.cache   # per map size and analysis: one analysis, not one per slice
def _narrowest_band(n: int, analysis: tuple) -> float:
    f = np.zeros((n, n))
    rows, col = [n // 2 - 1, n // 2], n // 4
    f[rows, col] = 1.0
    return float(_cycles_per_pixel(f, dict(analysis))[rows, col].max())


def _take(out: np.ndarray, pending: deque, progress) -> None:
    """Wait for the earliest pending slice's bandwidth and block-reduce it into its row of ``out``."""
    t, f = pending.popleft()
    out[t] = _block_max(f.result())
    if progress is not None:
        progress(t + 1)


def analytic_brdf_bandwidth_table(evaluate: Callable, resolution: int = DEFAULT_RESOLUTION) -> np.ndarray:
    """Table of an analytic BRDF (Lambert, GGX...): :func:`brdf_bandwidth_table` without a progress bar."""
    return brdf_bandwidth_table(evaluate, resolution=resolution)


def build_brdf_bandwidth(source, progress: bool = True, resolution: int = DEFAULT_RESOLUTION,
                         threads: int | None = None) -> np.ndarray:
    """Table of a :class:`precompute.brdf_sampling.BrdfSource` (a few seconds per material); a path is refused,
    saying to pass ``brdf_source(path, material)``.  ``threads``: as :func:`brdf_bandwidth_table`'s."""
    from precompute.brdf_sampling import check_brdf_source

    check_brdf_source(source, "build_brdf_bandwidth")
    with progress_callback(N_THETA_I, f"bandwidth {source.name}", "theta_i", progress) as step:
        return brdf_bandwidth_table(source.evaluate, resolution=resolution, progress=step, threads=threads)


def write_brdf_bandwidth(path, table: np.ndarray, source, force: bool = False,
                         resolution: int = DEFAULT_RESOLUTION):
    """Write a table built from ``source`` (anything with ``name`` and ``digest``): only one that
    :func:`read_brdf_bandwidth` would read back, and never over the source's own file (its ``path``), whatever
    ``force`` says."""
    from precompute.brdf_sampling import check_brdf_source, source_files, source_lookup

    check_brdf_source(source, "write_brdf_bandwidth", needs=("name", "digest"))
    n = _check_resolution(resolution)
    t = _checked_table(table, f"table for {path}", resolution=n)
    params = {**bandwidth_settings(n), "map": "lambert-equal-area", "units": "cycles/radian"}
    lookup = source_lookup(source)
    if lookup is not None:   # a tabulated BRDF's (an analytic one has no tables to look up)
        params["lookup"] = lookup
    return write_asset(path, FORMAT, VERSION, source.name, source.digest, {"nu_rho": t}, params=params,
                       force=force, inputs=source_files(source))


def _checked_table(table, what: str, fix: str = "", resolution=None) -> np.ndarray:
    """``table`` as float32 when it is one the renderer reads (shape SHAPE, finite bandwidths >= 0, and with the
    ``resolution`` it was analysed at, at most what that analysis gives); else a WarpbwError starting with
    ``what`` and ending with ``fix``.  The writer and the reader both check with it."""
    try:
        with np.errstate(over="ignore"):   # float64 beyond float32 becomes inf, refused below
            t = np.asarray(table, dtype=np.float32)
    except (TypeError, ValueError):   # strings, objects
        raise WarpbwError(f"{what} is not numeric{fix}") from None
    if t.shape != SHAPE:
        raise WarpbwError(f"{what} of shape {t.shape}, this warpbw uses {SHAPE}{fix}")
    if not np.all(np.isfinite(t)) or np.any(t < 0):
        raise WarpbwError(f"{what} has negative or non-finite bandwidths{fix}")
    if is_int(resolution) and resolution > 0:
        most = nu_rho_max(int(resolution))
        if float(t.max()) > most * (1.0 + 1e-6):   # 3e38 was read, and the frame refused for its light's radiance
            raise WarpbwError(f"{what} holds bandwidths up to {float(t.max()):.3g} cycles/radian, beyond the "
                              f"{most:g} an analysis at resolution {int(resolution)} gives{fix}")
    return t


def nu_rho_max(resolution: int) -> float:
    """The largest nu_rho an analysis at ``resolution`` gives: 0.5 cycles/pixel over the smallest pixel side,
    ``2 / resolution`` radians (:func:`map_radians_per_pixel`), i.e. ``resolution / 4`` cycles/radian."""
    return 0.5 / (2.0 / check_count(resolution, "resolution", 1))


def read_brdf_bandwidth(path, source=None) -> np.ndarray:
    """Read a table ``(16, 16, 16)`` float32; with ``source``, refuse one built from different data or with another
    lookup than the source's (module docstring, "Lookup")."""
    from precompute.brdf_sampling import check_brdf_source, rebuild_command

    if source is not None:
        check_brdf_source(source, "read_brdf_bandwidth", needs=("name", "digest"))
    hint = rebuild_command("brdf", source)
    a = read_asset(path, FORMAT, VERSION, hint)
    if source is not None:
        _check_source(path, a.header, source, hint)
    if "nu_rho" not in a.arrays:
        raise WarpbwError(f"{path}: brdf-bandwidth file lacks array 'nu_rho' (rebuild it with: {hint})")
    check_float_arrays([a.arrays["nu_rho"]], f"{path}: table", f" (rebuild it with: {hint})")
    resolution = a.header.get("params", {}).get("resolution")
    if isinstance(resolution, float) and resolution.is_integer():   # JSON's 128.0, as settings_mismatch takes it
        resolution = int(resolution)
    if not (is_int(resolution) and resolution >= N_CELLS):
        # every table of this version records it (bandwidth_settings); without it the bound below was skipped, and a
        # table of 3e38 refused the frame for its light's radiance, naming neither this file nor its table
        raise WarpbwError(f"{path}: its header records resolution {json.dumps(resolution)[:40]}, expected the "
                          f"analysed resolution, an integer >= {N_CELLS}, which bounds the bandwidths it may hold "
                          f"(rebuild it with: {hint})")
    return _checked_table(a.arrays["nu_rho"], f"{path}: table", f" (rebuild it with: {hint})", resolution)


def _check_source(path, header: dict, source, hint: str) -> None:
    """Refuse the file of ``header`` unless it was built from ``source``'s data with ``source``'s lookup."""
    from precompute.brdf_sampling import default_lookup, digest_at, source_lookup

    got = want = source_lookup(source)   # None: an analytic source, which looks nothing up
    if want is not None:
        params = header.get("params")
        recorded = params.get("lookup") if isinstance(params, dict) else None
        got = default_lookup(source) if recorded is None else recorded
        if got != want and got in LOOKUP_MODES and header.get("source_hash") == digest_at(source, got):
            old = "" if recorded is not None else " (recorded by none: a file from before session 70, built then " \
                                                  "with the kind's default)"
            raise WarpbwError(f"{path}: a nu_rho table of {header.get('source')!r} read with the {got} lookup{old}, "
                              f"expected the {want} lookup the material shades with (rebuild it with: {hint})")
    if got != want or header.get("source_hash") != source.digest:   # another BRDF's (with another lookup or not)
        raise WarpbwError(f"{path}: built from {header.get('source')!r} with different content than "
                          f"{source.name!r} (rebuild it with: {hint})")


def load_or_build_bandwidth(source, explicit=None, cache=None, progress: bool = True) -> tuple[np.ndarray, str]:
    """The source's nu_rho table: from ``explicit`` if given, else the cache, else built and cached; the table of the
    lookup ``source`` reads with (module docstring, "Lookup").

    Returns the table and where it came from ("file", "cache" or "built"); the cache is the sampling
    tables' (``$WARPBW_CACHE``), keyed by the source's digest (content hash, material, lookup when not the
    default); an entry that records other builder settings than ``bandwidth_settings()`` is rebuilt (module
    docstring, "Builder settings")."""
    from precompute.brdf_sampling import load_or_build

    return load_or_build(source, explicit, cache, "bandwidth", VERSION, read_brdf_bandwidth, build_brdf_bandwidth,
                         write_brdf_bandwidth, progress, bandwidth_settings(), BANDWIDTH_UNRECORDED)
