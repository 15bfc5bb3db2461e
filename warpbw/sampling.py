"""Importance sampling of tabulated BRDFs by numerical inversion of their CDF (002 Sec. 3.3).

Public:
    ``TabulatedSamplers``               Warp struct holding the tables of every tabulated material
    ``tab_sample(samplers, s, wo, u)``  wp.func: draw wi for view wo from sampler s
    ``tab_pdf(samplers, s, wi, wo)``    wp.func: its solid-angle pdf
    ``SamplerTable``                    host dataclass: one material's tables (numpy)
    ``build_sampler_table(brdf, ...)``  host: tabulate f cos_i over half-vectors and invert the CDF
    ``directional_albedo(brdf, theta_o)``  host: the integral of f cos_i over those same cells, per channel
    ``pack_samplers(tables, device)``   host: concatenate tables into a ``TabulatedSamplers``
    ``N_U``, ``N_PHI``, ``TABLE_VERSION``   the tables' cells and format version (the precompute stage writes them)
    Warp functions ``upper_cell`` (the CDF's binary search), ``angle_to_z``, ``theta_o_bin`` (the view's bin)

Parametrisation (isotropic BRDFs, so the table drops the view azimuth)
----------------------------------------------------------------------
For each of ``N_THETA_O`` view-elevation bins (uniform in theta_o) the table is a 2D
piecewise-constant density over the half vector h = (theta_h, phi_h), with
``theta_h = u^2 * pi/2`` (the square-root warp of MERL's theta_h axis, which spends most cells near
the specular peak, where narrow lobes such as chrome live) and ``phi_h`` measured from the view's
azimuth.  A cell's weight is the integral over the cell of ``Y(f(wi, wo)) cos_i |d wi / d(u, phi_h)|``,
with ``wi`` the reflection of ``wo`` about ``h`` and ``|d wi / d(u, phi)| = 4 (wo.h) sin(theta_h) pi u``,
estimated with ``SUBCELLS^2`` midpoint samples.  The marginal CDF over u and the conditional CDFs over
phi_h are inverted by binary search at run time; within a cell (u, phi_h) is uniform.  The view
elevation of a query picks its bin's table, in sampling and in the pdf alike, so both agree exactly.

Each bin's table is the mean of the normalised densities of ``VIEW_SUBSAMPLES`` view elevations spread evenly over the
bin (ours): a mixture, so sampling it and its pdf stay exact.  A table built at the bin centre alone missed what a
tabulated BRDF does within a degree of the horizon.  gold-metallic-paint's NPF fit written as a MERL table (the
benchmark bunny's material) has an albedo of 0.05 at theta_o = 88.6 degrees (the last bin's centre), 0.10 at 89.15 and
0.25 at 89.9: its lobe grows where the centre's table had almost none.  (These figures and those below are of the
table written before session 69, whose bins cut by the horizon held their centre's value; with their cos-weighted
mean, ``warpbw.io.merl.horizon_bins``, it reads 0.05, 0.066 and 0.15, the fit itself 0.049, 0.060 and 0.39.)  There
BRDF sampling's weight f cos_i / pdf had 0.92 and 0.75 times the standard deviation of uniform sampling's at 89.0 and
89.15 degrees (tests/test_sampling.py); with 4 elevations per bin it has 0.50 and 0.42 (16 elevations lower these by a
few hundredths).  On the benchmark bunny (examples/bench_scenes.py) these were the fireflies of its silhouette: in one
adaptive frame at budget 8 a single grazing pixel held 53% of the squared error.  Its reference at 32 spp, 6 seeds,
read an MSE of 1.16e-5 +/- 0.25e-5 with the centre's tables and 0.83e-5 +/- 0.02e-5 with these; the benchmark's three
other scenes moved by less than their noise.  A MERL table's build takes 1.0 s instead of 0.25 s.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import warp as wp

from warpbw.errors import WarpbwError, check_count, check_device, check_instance, numeric_array
from warpbw.io.exr import REC709_LUMINANCE

N_THETA_O = 32      # view-elevation bins tabulated (uniform over [0, pi/2))
N_U = 64            # half-vector elevation cells, theta_h = u^2 pi/2 (MERL-like warp)
N_PHI = 64          # half-vector azimuth cells over [0, 2 pi), relative to the view azimuth
SUBCELLS = 3        # midpoint samples per cell side when integrating the cell weight
VIEW_SUBSAMPLES = 4  # ours: view elevations averaged into each theta_o bin (grazing views; module docstring)
LUMINANCE = REC709_LUMINANCE  # Rec. 709's Y weights (0.2126, 0.7152, 0.0722): the importance function is Y(f) cos_i

TABLE_FORMAT = "warpbw.brdf-sampling"
TABLE_VERSION = 2    # 2: bins average VIEW_SUBSAMPLES view elevations (session 35); 1: the bin centre's

HALF_PI = 0.5 * math.pi
TWO_PI = 2.0 * math.pi
# Below this wo . h, tab_pdf takes it as |wi + wo| / 2 (equal for unit directions, ours): the rounded dot product's
# error, about 1e-7, is then under 1e-4 of it.
COS_D_EXACT = 1.0e-3


@wp.struct
class TabulatedSamplers:
    marginal: wp.array(dtype=wp.float32)      # [s][theta_o][N_U + 1] CDF over u
    conditional: wp.array(dtype=wp.float32)   # [s][theta_o][u][N_PHI + 1] CDF over phi_h
    density: wp.array(dtype=wp.float32)       # [s][theta_o][u][phi] density in (u, phi_h)
    n_theta_o: int
    n_u: int
    n_phi: int


@wp.func
def upper_cell(cdf: wp.array(dtype=wp.float32), start: int, n: int, x: float):
    """Largest i in [0, n) with cdf[start + i] <= x (cdf has n + 1 entries, 0 ... 1)."""
    lo = int(0)
    hi = n - 1
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if cdf[start + mid] <= x:
            lo = mid
        else:
            hi = mid - 1
    return lo


@wp.func
def angle_to_z(v: wp.vec3):
    """Angle between unit v and +Z, accurate near 0 (float32 acos(z) is 0 below ~3e-4 rad, which would swallow the
    first bins of MERL's sqrt-warped theta_h axis).  warpbw.brdf's functions use it too."""
    return wp.atan2(wp.sqrt(v[0] * v[0] + v[1] * v[1]), v[2])


@wp.func
def theta_o_bin(samplers: TabulatedSamplers, wo: wp.vec3):
    theta_o = angle_to_z(wo)
    return wp.clamp(int(theta_o / HALF_PI * float(samplers.n_theta_o)), 0, samplers.n_theta_o - 1)


@wp.func
def tab_sample(samplers: TabulatedSamplers, s: int, wo: wp.vec3, u: wp.vec2):
    nt = samplers.n_theta_o
    nu = samplers.n_u
    npf = samplers.n_phi
    j = theta_o_bin(samplers, wo)
    m_start = (s * nt + j) * (nu + 1)
    a = upper_cell(samplers.marginal, m_start, nu, u[0])
    c0 = samplers.marginal[m_start + a]
    c1 = samplers.marginal[m_start + a + 1]
    t0 = wp.clamp((u[0] - c0) / wp.max(c1 - c0, 1.0e-30), 0.0, 1.0)
    c_start = ((s * nt + j) * nu + a) * (npf + 1)
    b = upper_cell(samplers.conditional, c_start, npf, u[1])
    d0 = samplers.conditional[c_start + b]
    d1 = samplers.conditional[c_start + b + 1]
    t1 = wp.clamp((u[1] - d0) / wp.max(d1 - d0, 1.0e-30), 0.0, 1.0)
    uh = (float(a) + t0) / float(nu)
    theta_h = uh * uh * HALF_PI
    phi_h = wp.atan2(wo[1], wo[0]) + (float(b) + t1) / float(npf) * TWO_PI
    st = wp.sin(theta_h)
    h = wp.vec3(st * wp.cos(phi_h), st * wp.sin(phi_h), wp.cos(theta_h))
    return 2.0 * wp.dot(wo, h) * h - wo


@wp.func
def tab_pdf(samplers: TabulatedSamplers, s: int, wi: wp.vec3, wo: wp.vec3):
    # Defined over the whole sphere (a cell straddling the horizon sends part of its samples below), so that it
    # integrates to 1 -- less, within a degree of the horizon, the share of draws whose cell's half vector faces
    # away from this view (the bin's tables were built at other views): they reflect to below the surface, where f
    # is 0, and read pdf 0 here (chrome's NPF fit: 4.6% of its draws at 89.9 degrees, 7.2% at 89.99, none above
    # the surface).  The estimate stays unbiased; those draws are wasted.  At such views a float32 wi no longer
    # holds a half vector within ~1e-4 rad of the normal (wi + wo cancels to ~1e-7): there the pdf read back is up
    # to 2x, in places 200x, the cell's (u cell 0, 5% of black-obsidian's draws at 89.9 degrees), yet the estimate
    # of every NPF fit's albedo at 89.9 stayed within noise of a quadrature (session 79, docs/testing.md).
    if wo[2] <= 0.0:
        return 0.0
    nt = samplers.n_theta_o
    nu = samplers.n_u
    npf = samplers.n_phi
    j = theta_o_bin(samplers, wo)
    s_io = wi + wo
    h = wp.normalize(s_io)
    # wo . h = |wi + wo| / 2 for unit wi, wo (|wi + wo|^2 = 2 + 2 wi . wo): at a grazing view the rounded dot
    # product of wo and h lost its digits and read <= 0 for directions tab_sample draws (pdf 0: weights of up to
    # f pi / TAB_COSINE_MIX), so where it is small the length is taken instead
    cos_d = wp.dot(wo, h)
    if cos_d < COS_D_EXACT:
        cos_d = 0.5 * wp.length(s_io)
    if h[2] <= 0.0 or cos_d <= 0.0:
        return 0.0
    theta_h = angle_to_z(h)
    uh = wp.sqrt(theta_h / HALF_PI)
    rel = wp.atan2(h[1], h[0]) - wp.atan2(wo[1], wo[0])
    rel = rel - TWO_PI * wp.floor(rel / TWO_PI)
    a = wp.clamp(int(uh * float(nu)), 0, nu - 1)
    b = wp.clamp(int(rel / TWO_PI * float(npf)), 0, npf - 1)
    p_uphi = samplers.density[((s * nt + j) * nu + a) * npf + b]
    # (u, phi_h) -> half-vector solid angle -> reflected direction (002 Sec. 3.3 change of variables)
    jac = wp.sin(theta_h) * wp.pi * uh * 4.0 * cos_d
    return p_uphi / wp.max(jac, 1.0e-12)


# ---------------------------------------------------------------------------------------------
# Host side
# ---------------------------------------------------------------------------------------------

@dataclass
class SamplerTable:
    """One tabulated material's sampling tables (numpy, float32)."""

    marginal: np.ndarray      # (N_THETA_O, N_U + 1)
    conditional: np.ndarray   # (N_THETA_O, N_U, N_PHI + 1)
    density: np.ndarray       # (N_THETA_O, N_U, N_PHI)

    @property
    def shape(self):
        return self.density.shape


def _cell_midpoints(n: int, sub: int) -> np.ndarray:
    """Midpoints of ``sub`` equal parts of each of ``n`` unit cells on [0, 1), shape (n, sub)."""
    return (np.arange(n)[:, None] + (np.arange(sub)[None, :] + 0.5) / sub) / n


def _half_vector_grid(n_u: int, n_phi: int, sub: int):
    """The (u, phi_h) cells' sub-cell half vectors ``h`` (n_u * n_phi * sub^2, 3) (theta_h = u^2 pi/2), d omega_h /
    du dphi at each (``jac_h``), and the cell's sides ``du``, ``dphi``."""
    uu = _cell_midpoints(n_u, sub)                       # (n_u, sub)
    pp = _cell_midpoints(n_phi, sub) * TWO_PI            # (n_phi, sub)
    U = uu[:, None, :, None]                             # (n_u, 1, sub, 1)
    P = pp[None, :, None, :]                             # (1, n_phi, 1, sub)
    theta_h = U * U * HALF_PI
    sh, ch = np.sin(theta_h), np.cos(theta_h)
    hx = np.broadcast_to(sh * np.cos(P), (n_u, n_phi, sub, sub))
    hy = np.broadcast_to(sh * np.sin(P), (n_u, n_phi, sub, sub))
    hz = np.broadcast_to(ch, (n_u, n_phi, sub, sub))
    h = np.stack([hx, hy, hz], axis=-1).reshape(-1, 3)
    jac_h = np.broadcast_to(sh * math.pi * U, (n_u, n_phi, sub, sub)).reshape(-1)  # d omega_h / du dphi
    return h, jac_h, 1.0 / n_u, TWO_PI / n_phi


def build_sampler_table(brdf: Callable[[np.ndarray, np.ndarray], np.ndarray],
                        n_theta_o: int = N_THETA_O, n_u: int = N_U, n_phi: int = N_PHI,
                        sub: int = SUBCELLS, progress: Callable[[int], None] | None = None,
                        sub_views: int = VIEW_SUBSAMPLES) -> SamplerTable:
    """Tabulate and invert the CDF of Y(f) cos_i over half vectors, for each view elevation.

    ``brdf(wi, wo)`` takes (N, 3) local directions and returns (N, 3) BRDF values (numpy, vectorised).
    Each view-elevation bin holds the mean of the normalised densities of ``sub_views`` elevations spread
    over the bin (module docstring; 1: the bin centre's alone).  ``progress(k)`` is called after each view
    elevation bin (for a progress bar).
    """
    if not callable(brdf):   # "'NoneType' object is not callable" from the first view
        raise WarpbwError(f"build_sampler_table takes a function (wi, wo) -> BRDF values, got {type(brdf).__name__}")
    # n_u 0 was a ZeroDivisionError, n_phi 2.5 and n_theta_o -1 numpy's errors
    n_theta_o, n_u, n_phi, sub = (check_count(v, f"build_sampler_table: {k}", 1) for k, v in
                                  (("n_theta_o", n_theta_o), ("n_u", n_u), ("n_phi", n_phi), ("sub", sub)))
    sub_views = check_count(sub_views, "sub_views (view elevations per bin)", 1)
    brdf = _checked_values(brdf, "build_sampler_table")   # values of another shape: numpy's matmul error
    h, jac_h, du, dphi = _half_vector_grid(n_u, n_phi, sub)

    marginal = np.zeros((n_theta_o, n_u + 1))
    conditional = np.zeros((n_theta_o, n_u, n_phi + 1))
    density = np.zeros((n_theta_o, n_u, n_phi))
    for j in range(n_theta_o):
        w = np.zeros((n_u, n_phi))
        for k in range(sub_views):
            theta_o = (j + (k + 0.5) / sub_views) / n_theta_o * HALF_PI
            w += _cell_shares(brdf, theta_o, h, jac_h, n_u, n_phi)
        w /= sub_views                   # the mixture's share of each cell; sums to 1
        row = w.sum(axis=1)
        marginal[j, 1:] = np.cumsum(row)
        safe_row = np.where(row > 0.0, row, 1.0)
        cond = np.cumsum(w, axis=1) / safe_row[:, None]
        cond[row <= 0.0] = (np.arange(1, n_phi + 1) / n_phi)
        conditional[j, :, 1:] = cond
        density[j] = w / (du * dphi)
        if progress is not None:
            progress(j + 1)
    marginal[:, -1] = 1.0
    conditional[:, :, -1] = 1.0
    return SamplerTable(marginal.astype(np.float32), conditional.astype(np.float32),
                        density.astype(np.float32))


def _luminance(f: np.ndarray) -> np.ndarray:
    """(M, 1) Y(f) of BRDF values (M, 3), NaN, +inf and negative values read as 0 (the importance function)."""
    return np.clip(np.nan_to_num(f @ np.asarray(LUMINANCE), nan=0.0, posinf=0.0), 0.0, None)[:, None]


def _rgb(f: np.ndarray) -> np.ndarray:
    """(M, 3) BRDF values with NaN, +inf and negative values read as 0 (what ``directional_albedo`` integrates)."""
    return np.clip(np.nan_to_num(f, nan=0.0, posinf=0.0), 0.0, None)


def _cell_integrals(brdf, theta_o: float, h: np.ndarray, jac_h: np.ndarray, n_u: int, n_phi: int,
                    value=_luminance) -> np.ndarray:
    """(n_u, n_phi, k) integrals of ``value(f)`` (k columns) cos_i over each (u, phi_h) cell for the view at
    elevation ``theta_o``, per unit cell area du dphi (midpoint rule on the sub-cell half vectors ``h`` of
    ``_half_vector_grid``)."""
    wo = np.array([math.sin(theta_o), 0.0, math.cos(theta_o)])
    wo_h = h @ wo
    wi = 2.0 * wo_h[:, None] * h - wo
    ok = (wi[:, 2] > 0.0) & (wo_h > 0.0)
    k = value(np.zeros((1, 3))).shape[1]
    g = np.zeros((len(h), k))
    if ok.any():
        f = np.asarray(brdf(wi[ok], np.broadcast_to(wo, (int(ok.sum()), 3))), np.float64)
        # d omega_i = 4 (wo . h) d omega_h
        g[ok] = value(f) * wi[ok, 2, None] * 4.0 * wo_h[ok, None] * jac_h[ok, None]
    return g.reshape(n_u, n_phi, -1, k).mean(axis=2)


def _cell_shares(brdf, theta_o: float, h: np.ndarray, jac_h: np.ndarray, n_u: int, n_phi: int) -> np.ndarray:
    """(n_u, n_phi) shares, summing to 1, of the integral of Y(f) cos_i over each (u, phi_h) cell for the
    view at elevation ``theta_o``; uniform shares for a BRDF that is black at this view."""
    w = _cell_integrals(brdf, theta_o, h, jac_h, n_u, n_phi)[..., 0]
    total = w.sum()
    if not np.isfinite(total) or total <= 0.0:
        return np.full((n_u, n_phi), 1.0 / (n_u * n_phi))
    return w / total


def directional_albedo(brdf: Callable[[np.ndarray, np.ndarray], np.ndarray], theta_o,
                       n_u: int = N_U, n_phi: int = N_PHI, sub: int = 1) -> np.ndarray:
    """(len(theta_o), 3) directional albedo a(w_o) = integral of f(w_i, w_o) cos_i d w_i over the hemisphere, per
    RGB channel, for views at the elevations ``theta_o`` (radians, from the normal), by the midpoint rule over the
    sampling tables' half-vector cells (``sub``^2 points per cell): at most 1 for a BRDF that conserves energy."""
    if not callable(brdf):   # "'int' object is not callable" from the first view
        raise WarpbwError(f"directional_albedo takes a function (wi, wo) -> BRDF values, got {type(brdf).__name__}")
    angles = np.atleast_1d(numeric_array(theta_o, "directional_albedo: theta_o", "view elevations in radians"))
    if angles.ndim != 1 or not np.all((angles >= 0.0) & (angles < HALF_PI)):   # NaN fails too
        raise WarpbwError(f"directional_albedo: theta_o must be elevations from 0 to below pi/2 radians (a view above "
                          f"the surface), got {np.asarray(theta_o).tolist() if np.size(theta_o) < 6 else angles}")
    n_u, n_phi, sub = (check_count(v, f"directional_albedo: {k}", 1) for k, v in
                       (("n_u", n_u), ("n_phi", n_phi), ("sub", sub)))
    h, jac_h, du, dphi = _half_vector_grid(n_u, n_phi, sub)

    def integrals(t: float) -> np.ndarray:
        f = _cell_integrals(_checked_values(brdf, "directional_albedo"), t, h, jac_h, n_u, n_phi, _rgb)
        return f.sum(axis=(0, 1)) * (du * dphi)

    return np.array([integrals(float(t)) for t in angles]).reshape(len(angles), 3)


def _checked_values(brdf, caller: str):
    """``brdf`` whose values must be (N, 3) numbers for N direction pairs, else a one-line ``WarpbwError`` that
    ``caller`` starts."""
    def f(wi, wo):
        v = numeric_array(brdf(wi, wo), f"{caller}: the BRDF's values", f"({len(wi)}, 3) numbers")
        if v.shape != (len(wi), 3):
            raise WarpbwError(f"{caller}: the BRDF returned shape {v.shape} for {len(wi)} direction pairs, "
                              f"expected ({len(wi)}, 3)")
        return v
    return f


def pack_samplers(tables: Sequence[SamplerTable], device: str = "cpu") -> TabulatedSamplers:
    """Concatenate per-material tables (all of one shape) into a ``TabulatedSamplers`` struct."""
    check_device(device)
    if not isinstance(tables, (list, tuple)):   # None packed no table: the kernels then read an empty one
        raise WarpbwError(f"pack_samplers: tables: expected a list of SamplerTable, got {type(tables).__name__}")
    for i, t in enumerate(tables):   # None: an AttributeError ('shape') from the loop below
        check_instance(t, SamplerTable, f"pack_samplers: tables[{i}]", "a SamplerTable (build_sampler_table's)")
    s = TabulatedSamplers()
    if tables:
        shape = tables[0].shape
        for t in tables:
            if t.shape != shape:
                raise WarpbwError(f"pack_samplers: sampling tables of different shapes {t.shape} and {shape}")
        nt, nu, nphi = shape
        cat = lambda name: np.concatenate([getattr(t, name).reshape(-1) for t in tables])  # noqa: E731
        s.marginal = wp.array(cat("marginal"), dtype=wp.float32, device=device)
        s.conditional = wp.array(cat("conditional"), dtype=wp.float32, device=device)
        s.density = wp.array(cat("density"), dtype=wp.float32, device=device)
    else:
        nt = nu = nphi = 1
        s.marginal = wp.zeros(0, dtype=wp.float32, device=device)
        s.conditional = wp.zeros(0, dtype=wp.float32, device=device)
        s.density = wp.zeros(0, dtype=wp.float32, device=device)
    s.n_theta_o, s.n_u, s.n_phi = int(nt), int(nu), int(nphi)
    return s
