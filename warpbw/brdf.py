"""BRDF evaluation and importance sampling as Warp functions, for the material kinds a scene uses.

Public:
    ``MaterialTable``               Warp struct: every material's parameters and tabulated data
    ``BrdfFuncs`` / ``make_brdf_funcs(kinds)``  the eval / sample / pdf ``wp.func`` s for a set of kinds
    ``MaterialSpec``                one material's kind and parameters, as the scene gives them
    ``build_material_table(specs, device, sampling=True) -> MaterialBuffers``  host: pack material specs into a
                                    ``MaterialTable`` (``MaterialBuffers``: the table and the kinds and names it
                                    holds; without ``sampling``, for lights alone, no sampling table)
    ``check_material_spec(s, i)``  a spec the table can hold, else a ``WarpbwError`` naming the field
    ``check_sampling_tables(mb, where, gb_material)``  a one-line error for a tabulated material packed without its
                                    sampling table that a pass sampling the BRDF would read (the passes call it)
    ``pack_npf_curves(rho_d, rho_s, d, g1, f)``  an NPF fit's curves in the table's layout
    ``KIND_NAMES``                  material type name -> kind id
    ``eval_brdf(...)``, ``sample_brdf(...)``, ``pdf_brdf(...)``  host wrappers (numpy in, numpy out) for tests
    ``LAMBERT``, ``GGX``, ``MERL``, ``NPF``     material kind ids
    Warp functions the kernels are built of: ``angle_to_z`` (warpbw.sampling's), ``angle_between``,
    ``half_vector``, ``sample_cosine_hemisphere``, ``lambert_eval``; GGX's ``ggx_d``, ``ggx_g1``, ``fresnel_conductor``,
    ``ggx_fresnel``, ``ggx_eval``, ``ggx_sample_vndf``, ``ggx_pdf``; ``rusinkiewicz``, ``merl_cell``, ``merl_eval``
    (MERL's look-up), ``npf_curve`` and ``npf_eval``

All directions are in the local shading frame (+Z is the normal) and point away from the surface:
``wi`` towards the light, ``wo`` towards the viewer.  BRDF values are in 1/sr.

Models
------
* ``lambert``: f = albedo / pi, cosine-weighted sampling.
* ``ggx``: f = F D(h) G1(wi) G1(wo) / (4 cos_i cos_o), GGX (Trowbridge-Reitz) D with the given alpha,
  separable Smith G1, Fresnel constant (= specular) or conductor (eta, k) times specular.
  Sampled by visible normals (Heitz 2018), so f cos_i / pdf = F G1(wi) <= 1 for specular <= 1.
* ``merl``: the 90x90x180 tabulated isotropic BRDF in Rusinkiewicz half/difference angles, nearest-bin
  (MERL's own lookup) or trilinear between bin centres.
* ``npf``: rho_d + rho_s D(theta_h) F(theta_d) G1(theta_i) G1(theta_o) / (16 cos_i cos_o), 1D curves.
* ``merl`` and ``npf`` are sampled with tabulated half-vector distributions built by numerical inversion
  of the CDF (002 Sec. 3.3, see :mod:`warpbw.sampling`), mixed with a small share of cosine sampling so
  that every direction the BRDF reaches keeps a positive pdf.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import warp as wp

from warpbw import sampling as tabsamp
from warpbw.io.npf import NPF_BINS, NPF_COS_MIN, NPF_FIRST_VALID_BIN
from warpbw.sampling import angle_to_z
from warpbw.scene import CONDUCTOR_INDEX_MAX, GGX_MIN_ALPHA
from warpbw.errors import (BRDF_VALUE_MAX, FLOAT32_MAX, INT32_MAX, WarpbwError, check_count, check_device,
                           check_direction_pairs, check_flag, check_instance, check_seed, is_int,
                           unit_directions)

# Material kind ids (stable: stored in MaterialTable.kind).
LAMBERT = 0
GGX = 1
MERL = 2
NPF = 3
KIND_NAMES = {"lambert": LAMBERT, "ggx": GGX, "merl": MERL, "npf": NPF}

# MERL table shape and binning (data README, "MERL .binary format").
MERL_N_TH = 90
MERL_N_TD = 90
MERL_N_PD = 180
MERL_CELLS = MERL_N_TH * MERL_N_TD * MERL_N_PD  # 1,458,000 RGB cells per material

# NPF row layout (data README, "npf.bin layout"): rho_d, rho_s, then D, G1, F curves of warpbw.io.npf.NPF_BINS = 90
# bins each.
NPF_STRIDE = 2 + 3 * NPF_BINS  # vec3 entries per NPF material in MaterialTable.npf
NPF_D_OFF = 2
NPF_G1_OFF = 2 + NPF_BINS
NPF_F_OFF = 2 + 2 * NPF_BINS
# G1 and F bin 0 hold no fitted value (G1's is stored as 0, F's is a placeholder): both curves start at
# bin warpbw.io.npf.NPF_FIRST_VALID_BIN = 1, on the device as on the host; the model's 1 / (cos_i cos_o) clamps
# cos_i, cos_o at warpbw.io.npf.NPF_COS_MIN, likewise.

# Share of cosine-weighted samples mixed into tabulated sampling (defensive mixture; keeps pdf > 0
# wherever cos_i > 0, so the estimator of 002 Eq. 2 stays unbiased even where a table cell is empty).
TAB_COSINE_MIX = 0.1

# Below this cosine a direction counts as grazing: the BRDF is evaluated there, but divisions by the
# cosine are guarded so that silhouettes stay finite.
COS_EPS = 1.0e-6

HALF_PI = 0.5 * math.pi
# Below this largest component, wi + wo is scaled up before normalising (ours): its squared length, about 4 cos^2 for
# a mirror pair at the horizon, leaves float32's normal range (1.2e-38) under |wi + wo| ~ 1e-19 and is 0 under ~1e-23.
HALF_VECTOR_RESCALE = 1.0e-15
# The scene's bounds, imported above: GGX alphas below warpbw.scene.GGX_MIN_ALPHA are clamped to it (D stays finite
# in float32 far below it; see ggx_d), and a conductor's eta or k above CONDUCTOR_INDEX_MAX is refused
# (fresnel_conductor squares eta^2 k^2, which overflows float32 from about 5e9: the reflectance then read 0 instead of
# nearly 1, a mirror rendered black).


@wp.struct
class MaterialTable:
    kind: wp.array(dtype=wp.int32)
    albedo: wp.array(dtype=wp.vec3)       # lambert albedo
    alpha: wp.array(dtype=wp.float32)     # ggx roughness
    specular: wp.array(dtype=wp.vec3)     # ggx constant Fresnel / tint
    eta: wp.array(dtype=wp.vec3)          # ggx conductor Fresnel (used when conductor != 0)
    k: wp.array(dtype=wp.vec3)
    conductor: wp.array(dtype=wp.int32)
    linear: wp.array(dtype=wp.int32)      # merl / npf: 1 = interpolate between bin centres
    data: wp.array(dtype=wp.int32)        # merl / npf: index of this material's table
    sampler: wp.array(dtype=wp.int32)     # merl / npf: index of its tabulated sampler
    merl: wp.array(dtype=wp.vec3)         # n_merl * MERL_CELLS
    npf: wp.array(dtype=wp.vec3)          # n_npf * NPF_STRIDE
    samplers: tabsamp.TabulatedSamplers


# ---------------------------------------------------------------------------------------------
# Shared Warp helpers
# ---------------------------------------------------------------------------------------------

@wp.func
def angle_between(a: wp.vec3, b: wp.vec3):
    return wp.atan2(wp.length(wp.cross(a, b)), wp.dot(a, b))


@wp.func
def sample_cosine_hemisphere(u: wp.vec2):
    # Malley's method: a uniform point of the unit disk (polar mapping) lifted to the hemisphere; pdf = cos / pi.
    r = wp.sqrt(u[0])
    phi = 2.0 * wp.pi * u[1]
    return wp.vec3(r * wp.cos(phi), r * wp.sin(phi), wp.sqrt(wp.max(0.0, 1.0 - u[0])))


@wp.func
def half_vector(wi: wp.vec3, wo: wp.vec3):
    """normalize(wi + wo), the sum scaled by its largest component first when that is below HALF_VECTOR_RESCALE:
    for a pair grazing the horizon (wi = (0, 1, 1e-30), wo = (0, -1, 1e-30)) wp.normalize saw a zero length and
    returned 0, where GGX's D(0) = inf times G1 G1 = 0 made f NaN and NPF's theta_d read 0 instead of 90 degrees (and
    MERL's theta_h, ``rusinkiewicz``, 0 instead of 45 for wi = (c, 1, c), wo = (c, -1, c))."""
    s = wi + wo
    m = wp.max(wp.max(wp.abs(s[0]), wp.abs(s[1])), wp.abs(s[2]))
    if m > 0.0 and m < HALF_VECTOR_RESCALE:
        s = s / m
    return wp.normalize(s)


@wp.func
def rusinkiewicz(wi: wp.vec3, wo: wp.vec3):
    """(theta_h, theta_d, phi_d) of a direction pair, phi_d folded into [0, pi) by reciprocity.  h is
    ``half_vector``'s: wp.normalize(wi + wo) was 0 for wi = (c, 1, c), wo = (c, -1, c) below c ~ 1e-23, and theta_h
    read 0, not 45 degrees."""
    h = half_vector(wi, wo)
    theta_h = angle_to_z(h)
    phi_h = wp.atan2(h[1], h[0])
    # d = R_y(-theta_h) R_z(-phi_h) wi
    cp = wp.cos(phi_h)
    sp = wp.sin(phi_h)
    x1 = cp * wi[0] + sp * wi[1]
    y1 = -sp * wi[0] + cp * wi[1]
    z1 = wi[2]
    ct = wp.cos(theta_h)
    st = wp.sin(theta_h)
    dx = ct * x1 - st * z1
    dy = y1
    dz = st * x1 + ct * z1
    theta_d = wp.atan2(wp.sqrt(dx * dx + dy * dy), dz)
    phi_d = wp.atan2(dy, dx)
    if phi_d < 0.0:
        phi_d = phi_d + wp.pi
    return theta_h, theta_d, phi_d


# ---------------------------------------------------------------------------------------------
# Lambert
# ---------------------------------------------------------------------------------------------

@wp.func
def lambert_eval(albedo: wp.vec3):
    return albedo / wp.pi


# ---------------------------------------------------------------------------------------------
# GGX with separable Smith G1
# ---------------------------------------------------------------------------------------------

@wp.func
def ggx_d(h: wp.vec3, alpha: float):
    # GGX / Trowbridge-Reitz normal distribution, normalised so that int D(h) cos_h dh = 1:
    # D = a^2 / (pi (sin_h^2 + a^2 cos_h^2)^2).  Written with sin_h^2 = h_x^2 + h_y^2 rather than the usual
    # 1 + cos_h^2 (a^2 - 1), which in float32 is exactly 0 at h = n once a < ~1.7e-4 (a^2 - 1 rounds to -1).
    a2 = alpha * alpha
    t = h[0] * h[0] + h[1] * h[1] + a2 * h[2] * h[2]
    return a2 / (wp.pi * t * t)


@wp.func
def ggx_g1(cos_w: float, alpha: float):
    # Smith G1 for GGX: 2 cos / (cos + sqrt(a^2 + (1 - a^2) cos^2)).
    c = wp.max(cos_w, 0.0)
    a2 = alpha * alpha
    return 2.0 * c / (c + wp.sqrt(a2 + (1.0 - a2) * c * c) + 1.0e-20)


@wp.func
def fresnel_conductor(cos_d: float, eta: float, k: float):
    # Unpolarised Fresnel reflectance of a conductor with complex IOR eta + i k.
    c = wp.clamp(cos_d, 0.0, 1.0)
    c2 = c * c
    s2 = 1.0 - c2
    e2 = eta * eta
    k2 = k * k
    t0 = e2 - k2 - s2
    a2b2 = wp.sqrt(wp.max(t0 * t0 + 4.0 * e2 * k2, 0.0))
    t1 = a2b2 + c2
    a = wp.sqrt(wp.max(0.5 * (a2b2 + t0), 0.0))
    t2 = 2.0 * c * a
    # both are squared magnitudes (>= 0); rounding made them -1e-8 where the two terms cancel (eta = 1, k = 0)
    rs = wp.max((t1 - t2) / wp.max(t1 + t2, 1.0e-20), 0.0)
    t3 = c2 * a2b2 + s2 * s2
    t4 = t2 * s2
    rp = rs * wp.max((t3 - t4) / wp.max(t3 + t4, 1.0e-20), 0.0)
    return 0.5 * (rp + rs)


@wp.func
def ggx_fresnel(mats: MaterialTable, m: int, cos_d: float):
    spec = mats.specular[m]
    if mats.conductor[m] == 0:
        return spec
    e = mats.eta[m]
    kk = mats.k[m]
    return wp.vec3(
        spec[0] * fresnel_conductor(cos_d, e[0], kk[0]),
        spec[1] * fresnel_conductor(cos_d, e[1], kk[1]),
        spec[2] * fresnel_conductor(cos_d, e[2], kk[2]),
    )


@wp.func
def ggx_eval(mats: MaterialTable, m: int, wi: wp.vec3, wo: wp.vec3):
    ci = wi[2]
    co = wo[2]
    if ci <= 0.0 or co <= 0.0:
        return wp.vec3(0.0)
    alpha = mats.alpha[m]
    h = half_vector(wi, wo)
    d = ggx_d(h, alpha)
    g = ggx_g1(ci, alpha) * ggx_g1(co, alpha)
    f = ggx_fresnel(mats, m, wp.dot(wi, h))
    return f * (d * g / (4.0 * wp.max(ci, COS_EPS) * wp.max(co, COS_EPS)))


@wp.func
def ggx_sample_vndf(wo: wp.vec3, alpha: float, u: wp.vec2):
    # Visible-normal sampling (Heitz 2018, "Sampling the GGX distribution of visible normals").
    vh = wp.normalize(wp.vec3(alpha * wo[0], alpha * wo[1], wp.max(wo[2], COS_EPS)))
    lensq = vh[0] * vh[0] + vh[1] * vh[1]
    t1 = wp.vec3(1.0, 0.0, 0.0)
    if lensq > 1.0e-12:
        t1 = wp.vec3(-vh[1], vh[0], 0.0) / wp.sqrt(lensq)
    t2 = wp.cross(vh, t1)
    r = wp.sqrt(u[0])
    phi = 2.0 * wp.pi * u[1]
    p1 = r * wp.cos(phi)
    p2 = r * wp.sin(phi)
    s = 0.5 * (1.0 + vh[2])
    p2 = (1.0 - s) * wp.sqrt(wp.max(0.0, 1.0 - p1 * p1)) + s * p2
    nh = p1 * t1 + p2 * t2 + wp.sqrt(wp.max(0.0, 1.0 - p1 * p1 - p2 * p2)) * vh
    h = wp.normalize(wp.vec3(alpha * nh[0], alpha * nh[1], wp.max(nh[2], 0.0)))
    return 2.0 * wp.dot(wo, h) * h - wo


@wp.func
def ggx_pdf(wi: wp.vec3, wo: wp.vec3, alpha: float):
    # pdf of VNDF sampling in solid angle: G1(wo) D(h) / (4 cos_o).  Defined over the whole sphere
    # (samples reflected below the horizon carry their share), so it integrates to exactly 1.  VNDF's factor
    # max(wo . h, 0) needs no test: h ~ wi + wo gives wo . h = (1 + wo . wi) / |wi + wo| >= 0 for unit directions,
    # and a test on the rounded dot product read 0 for directions the sampler draws at grazing views (sharp lobes).
    if wo[2] <= 0.0:
        return 0.0
    h = half_vector(wi, wo)
    if h[2] <= 0.0:
        return 0.0
    return ggx_g1(wo[2], alpha) * ggx_d(h, alpha) / (4.0 * wp.max(wo[2], COS_EPS))


# ---------------------------------------------------------------------------------------------
# MERL (tabulated, Rusinkiewicz coordinates)
# ---------------------------------------------------------------------------------------------

@wp.func
def merl_cell(base: int, i_th: int, i_td: int, i_pd: int):
    return base + (i_th * MERL_N_TD + i_td) * MERL_N_PD + i_pd


@wp.func
def merl_eval(mats: MaterialTable, m: int, wi: wp.vec3, wo: wp.vec3):
    if wi[2] <= 0.0 or wo[2] <= 0.0:
        return wp.vec3(0.0)
    theta_h, theta_d, phi_d = rusinkiewicz(wi, wo)
    base = mats.data[m] * MERL_CELLS
    # continuous bin coordinates (data README binning)
    x_th = wp.sqrt(wp.max(theta_h, 0.0) / HALF_PI) * float(MERL_N_TH)
    x_td = theta_d / HALF_PI * float(MERL_N_TD)
    x_pd = phi_d / wp.pi * float(MERL_N_PD)
    if mats.linear[m] == 0:
        i_th = wp.clamp(int(x_th), 0, MERL_N_TH - 1)
        i_td = wp.clamp(int(x_td), 0, MERL_N_TD - 1)
        i_pd = wp.clamp(int(x_pd), 0, MERL_N_PD - 1)
        return mats.merl[merl_cell(base, i_th, i_td, i_pd)]
    # trilinear between bin centres: clamped in theta_h / theta_d, periodic (period pi) in phi_d
    c_th = wp.clamp(x_th - 0.5, 0.0, float(MERL_N_TH - 1))
    c_td = wp.clamp(x_td - 0.5, 0.0, float(MERL_N_TD - 1))
    c_pd = x_pd - 0.5
    a0 = wp.min(int(c_th), MERL_N_TH - 2)
    b0 = wp.min(int(c_td), MERL_N_TD - 2)
    fa = c_th - float(a0)
    fb = c_td - float(b0)
    p0f = wp.floor(c_pd)
    fc = c_pd - p0f
    p0 = int(p0f)
    p0 = (p0 + MERL_N_PD) % MERL_N_PD
    p1 = (p0 + 1) % MERL_N_PD
    r = wp.vec3(0.0)
    for da in range(2):
        wa = wp.where(da == 0, 1.0 - fa, fa)
        for db in range(2):
            wb = wp.where(db == 0, 1.0 - fb, fb)
            c0 = mats.merl[merl_cell(base, a0 + da, b0 + db, p0)]
            c1 = mats.merl[merl_cell(base, a0 + da, b0 + db, p1)]
            r = r + (wa * wb) * ((1.0 - fc) * c0 + fc * c1)
    return r


# ---------------------------------------------------------------------------------------------
# NPF (non-parametric factored microfacet fit)
# ---------------------------------------------------------------------------------------------

@wp.func
def npf_curve(mats: MaterialTable, base: int, x: float, first: int, linear: int):
    # x: continuous bin coordinate in [0, 90]; bins below ``first`` are skipped;
    # nearest bin or linear between bin centres (constant beyond the end centres).
    if linear == 0:
        return mats.npf[base + wp.clamp(int(x), first, NPF_BINS - 1)]
    c = wp.clamp(x - 0.5, float(first), float(NPF_BINS - 1))
    i0 = wp.min(int(c), NPF_BINS - 2)
    t = c - float(i0)
    return (1.0 - t) * mats.npf[base + i0] + t * mats.npf[base + i0 + 1]


@wp.func
def npf_eval(mats: MaterialTable, m: int, wi: wp.vec3, wo: wp.vec3):
    ci = wi[2]
    co = wo[2]
    if ci <= 0.0 or co <= 0.0:
        return wp.vec3(0.0)
    base = mats.data[m] * NPF_STRIDE
    lin = mats.linear[m]
    h = half_vector(wi, wo)
    theta_h = angle_to_z(h)
    theta_d = angle_between(wi, h)
    theta_i = angle_to_z(wi)
    theta_o = angle_to_z(wo)
    d = npf_curve(mats, base + NPF_D_OFF, wp.sqrt(theta_h / HALF_PI) * float(NPF_BINS), 0, lin)
    f = npf_curve(mats, base + NPF_F_OFF, theta_d / HALF_PI * float(NPF_BINS), NPF_FIRST_VALID_BIN, lin)
    gi = npf_curve(mats, base + NPF_G1_OFF, theta_i / HALF_PI * float(NPF_BINS), NPF_FIRST_VALID_BIN, lin)
    go = npf_curve(mats, base + NPF_G1_OFF, theta_o / HALF_PI * float(NPF_BINS), NPF_FIRST_VALID_BIN, lin)
    rho_d = mats.npf[base]
    rho_s = mats.npf[base + 1]
    spec = wp.cw_mul(wp.cw_mul(rho_s, d), wp.cw_mul(f, wp.cw_mul(gi, go)))
    # 1/(16 cos_i cos_o), data README
    return rho_d + spec / (16.0 * wp.max(ci, NPF_COS_MIN) * wp.max(co, NPF_COS_MIN))


# ---------------------------------------------------------------------------------------------
# Dispatch: one eval / sample / pdf per set of kinds (only the kinds a scene uses are compiled)
# ---------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class BrdfFuncs:
    """The Warp functions for one set of material kinds.

    ``eval(mats, m, wi, wo) -> vec3``; ``sample(mats, m, wo, u: vec3) -> vec3`` (wi, may lie below the
    horizon: the caller's estimate is then 0); ``pdf(mats, m, wi, wo) -> float`` (solid angle).
    """

    kinds: frozenset
    eval: Callable
    sample: Callable
    pdf: Callable


def make_brdf_funcs(kinds: Sequence[int]) -> BrdfFuncs:
    """Build (once per set of kinds) the dispatching Warp functions for the given material kinds."""
    return _brdf_funcs(frozenset(int(k) for k in kinds))


@functools.cache  # one set of functions per set of kinds
def _brdf_funcs(key: frozenset) -> BrdfFuncs:
    has_l = LAMBERT in key
    has_g = GGX in key
    has_m = MERL in key
    has_n = NPF in key
    has_tab = has_m or has_n

    @wp.func
    def brdf_eval(mats: MaterialTable, m: int, wi: wp.vec3, wo: wp.vec3):
        kind = mats.kind[m]
        r = wp.vec3(0.0)
        if wp.static(has_l):
            if kind == LAMBERT:
                if wi[2] > 0.0 and wo[2] > 0.0:
                    r = lambert_eval(mats.albedo[m])
        if wp.static(has_g):
            if kind == GGX:
                r = ggx_eval(mats, m, wi, wo)
        if wp.static(has_m):
            if kind == MERL:
                r = merl_eval(mats, m, wi, wo)
        if wp.static(has_n):
            if kind == NPF:
                r = npf_eval(mats, m, wi, wo)
        return r

    @wp.func
    def brdf_sample(mats: MaterialTable, m: int, wo: wp.vec3, u: wp.vec3):
        kind = mats.kind[m]
        wi = sample_cosine_hemisphere(wp.vec2(u[1], u[2]))
        if wp.static(has_g):
            if kind == GGX:
                wi = ggx_sample_vndf(wo, mats.alpha[m], wp.vec2(u[1], u[2]))
        if wp.static(has_tab):
            if kind == MERL or kind == NPF:
                if u[0] >= TAB_COSINE_MIX:
                    wi = tabsamp.tab_sample(mats.samplers, mats.sampler[m], wo, wp.vec2(u[1], u[2]))
        return wi

    @wp.func
    def brdf_pdf(mats: MaterialTable, m: int, wi: wp.vec3, wo: wp.vec3):
        kind = mats.kind[m]
        p = wp.max(wi[2], 0.0) / wp.pi
        if wp.static(has_g):
            if kind == GGX:
                p = ggx_pdf(wi, wo, mats.alpha[m])
        if wp.static(has_tab):
            if kind == MERL or kind == NPF:
                p = TAB_COSINE_MIX * p + (1.0 - TAB_COSINE_MIX) * tabsamp.tab_pdf(
                    mats.samplers, mats.sampler[m], wi, wo)
        return p

    return BrdfFuncs(key, brdf_eval, brdf_sample, brdf_pdf)


# ---------------------------------------------------------------------------------------------
# Host side: packing materials
# ---------------------------------------------------------------------------------------------

@dataclass
class MaterialSpec:
    """One material as the renderer needs it (built by the pipeline from the scene)."""

    name: str
    kind: int
    albedo: tuple = (0.0, 0.0, 0.0)
    alpha: float = 0.0
    specular: tuple = (0.0, 0.0, 0.0)
    eta: tuple | None = None
    k: tuple | None = None
    linear: bool = False
    merl: np.ndarray | None = None       # (90, 90, 180, 3) float32 scaled BRDF values
    npf: np.ndarray | None = None        # (NPF_STRIDE, 3): rho_d, rho_s, D[90], G1[90], F[90]
    sampler: "tabsamp.SamplerTable | None" = None


@dataclass
class MaterialBuffers:
    table: MaterialTable
    kinds: frozenset
    names: list


def pack_npf_curves(rho_d, rho_s, d, g1, f) -> np.ndarray:
    """NPF curves in MaterialTable.npf order, (NPF_STRIDE, 3) float32."""
    rows = [_spec_table(v, name, n) for v, name, n in ((rho_d, "rho_d", 1), (rho_s, "rho_s", 1),
                                                      (d, "d", NPF_BINS), (g1, "g1", NPF_BINS), (f, "f", NPF_BINS))]
    return np.concatenate(rows)


def _spec_vec3(value, what: str, optional: bool = False):
    """Three finite numbers >= 0 (a colour, eta or k), else a WarpbwError naming ``what``."""
    if value is None and optional:
        return None
    try:
        v = np.asarray(value, np.float64)
    except (TypeError, ValueError):
        v = np.zeros(0)
    if v.shape != (3,) or not np.isfinite(v).all() or (v < 0.0).any() or (v > FLOAT32_MAX).any():
        # (1e39 passed, and became inf in the float32 table)
        raise WarpbwError(f"{what}: expected three finite numbers >= 0 (within float32), got {value!r}")
    return v


def _spec_table(values, what: str, rows: int) -> np.ndarray:
    """A tabulated BRDF's values as (rows, 3) float32, else a WarpbwError giving the size expected."""
    try:
        v = np.asarray(values, np.float32) if values is not None else np.zeros(0, np.float32)
    except (TypeError, ValueError):
        raise WarpbwError(f"{what}: expected {rows} x 3 numbers, got {type(values).__name__}") from None
    if v.size != rows * 3:
        raise WarpbwError(f"{what}: expected {rows} x 3 values, got {v.size}")
    if v.ndim > 1 and v.shape[-1] != 3:   # channels first, (3, 90, 90, 180), was read as scrambled RGB
        raise WarpbwError(f"{what}: expected the RGB channels on the last axis (or a flat list), got shape {v.shape}")
    if not np.all(np.isfinite(v)):
        raise WarpbwError(f"{what}: expected finite values, got {int((~np.isfinite(v)).sum())} NaN or infinite")
    return np.ascontiguousarray(v).reshape(rows, 3)


def check_material_spec(s: MaterialSpec, i: int) -> MaterialSpec:
    """A spec the table can hold (the scene parser's specs always pass): a known kind, colours of three finite
    numbers >= 0, a finite alpha >= 0 (a NaN one made every GGX lookup NaN), tables of the right size."""
    what = f"material {i} ({getattr(s, 'name', '?')!r})"
    if not isinstance(s, MaterialSpec):
        raise WarpbwError(f"{what}: expected a MaterialSpec, got {type(s).__name__}")
    if not is_int(s.kind) or int(s.kind) not in KIND_NAMES.values():
        raise WarpbwError(f"{what}.kind: expected one of {KIND_NAMES}, got {s.kind!r}")
    for field in ("albedo", "specular"):
        _spec_vec3(getattr(s, field), f"{what}.{field}")
    for field in ("eta", "k"):
        v = _spec_vec3(getattr(s, field), f"{what}.{field}", optional=True)
        if v is not None and (v > CONDUCTOR_INDEX_MAX).any():
            raise WarpbwError(f"{what}.{field}: expected values up to {CONDUCTOR_INDEX_MAX:g}, "
                              f"got {getattr(s, field)!r}")
    if (s.eta is None) != (s.k is None):
        raise WarpbwError(f"{what}: a conductor needs both eta and k, got only one")
    if not isinstance(s.alpha, (int, float, np.floating)) or not math.isfinite(s.alpha) or s.alpha < 0.0:
        raise WarpbwError(f"{what}.alpha: expected a finite number >= 0, got {s.alpha!r}")
    if s.kind == MERL:
        table = _spec_table(s.merl, f"{what}.merl", MERL_CELLS)
        if table.min() < 0.0 or table.max() > BRDF_VALUE_MAX:   # read_merl zeroes unmeasured (negative) entries
            raise WarpbwError(f"{what}.merl: expected BRDF values from 0 to {BRDF_VALUE_MAX:g} (unmeasured entries "
                              f"0, as read_merl gives them), got {table.min():.3g} to {table.max():.3g}")
    elif s.kind == NPF:
        _spec_table(s.npf, f"{what}.npf", NPF_STRIDE)
    return s


def build_material_table(specs: Sequence[MaterialSpec], device: str = "cpu", sampling: bool = True) -> MaterialBuffers:
    """Pack material specs (in material-id order) into device arrays (each checked by ``check_material_spec``).
    Without ``sampling`` (for kernels that sample no BRDF: directional lights alone) no sampling table is packed
    and a tabulated material needs none (``sample_brdf`` and ``pdf_brdf`` then refuse it)."""
    check_device(device)
    sampling = check_flag(sampling, "build_material_table: sampling")   # "no" read as True, 0 as False
    specs = [check_material_spec(s, i) for i, s in enumerate(specs)]
    n = len(specs)
    kind = np.array([s.kind for s in specs], np.int32)
    data_idx = np.full(n, -1, np.int32)
    samp_idx = np.full(n, -1, np.int32)
    merls, npfs, samplers = [], [], []
    for i, s in enumerate(specs):
        if s.kind == MERL:
            data_idx[i] = len(merls)
            merls.append(_spec_table(s.merl, s.name, MERL_CELLS))
        elif s.kind == NPF:
            data_idx[i] = len(npfs)
            npfs.append(_spec_table(s.npf, s.name, NPF_STRIDE))
        if s.kind in (MERL, NPF) and sampling:
            if s.sampler is None:
                raise WarpbwError(f"material {s.name!r}: a tabulated BRDF needs its sampling table")
            samp_idx[i] = len(samplers)
            samplers.append(s.sampler)

    def vec3s(rows):
        return wp.array(np.asarray(rows, np.float32).reshape(-1, 3), dtype=wp.vec3, device=device)

    t = MaterialTable()
    t.kind = wp.array(kind, dtype=wp.int32, device=device)
    t.albedo = vec3s([s.albedo for s in specs])
    t.alpha = wp.array(np.array([max(s.alpha, GGX_MIN_ALPHA) for s in specs], np.float32), dtype=wp.float32,
                       device=device)
    t.specular = vec3s([s.specular for s in specs])
    t.eta = vec3s([s.eta if s.eta is not None else (0.0, 0.0, 0.0) for s in specs])
    t.k = vec3s([s.k if s.k is not None else (0.0, 0.0, 0.0) for s in specs])
    t.conductor = wp.array(np.array([0 if s.eta is None else 1 for s in specs], np.int32),
                           dtype=wp.int32, device=device)
    t.linear = wp.array(np.array([1 if s.linear else 0 for s in specs], np.int32), dtype=wp.int32,
                        device=device)
    t.data = wp.array(data_idx, dtype=wp.int32, device=device)
    t.sampler = wp.array(samp_idx, dtype=wp.int32, device=device)
    t.merl = vec3s(np.concatenate(merls) if merls else np.zeros((0, 3)))
    t.npf = vec3s(np.concatenate(npfs) if npfs else np.zeros((0, 3)))
    t.samplers = tabsamp.pack_samplers(samplers, device=device)
    return MaterialBuffers(t, frozenset(int(k) for k in kind), [s.name for s in specs])


# ---------------------------------------------------------------------------------------------
# Host wrappers for tests and examples
# ---------------------------------------------------------------------------------------------

@functools.cache  # one set of host kernels per set of kinds
def _host_kernels(kinds: frozenset):
    f = make_brdf_funcs(kinds)

    @wp.kernel(module="unique", enable_backward=False)
    def eval_kernel(mats: MaterialTable, m: int, wi: wp.array(dtype=wp.vec3),
                    wo: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.vec3)):
        t = wp.tid()
        out[t] = f.eval(mats, m, wi[t], wo[t])

    @wp.kernel(module="unique", enable_backward=False)
    def pdf_kernel(mats: MaterialTable, m: int, wi: wp.array(dtype=wp.vec3),
                   wo: wp.array(dtype=wp.vec3), out: wp.array(dtype=float)):
        t = wp.tid()
        out[t] = f.pdf(mats, m, wi[t], wo[t])

    @wp.kernel(module="unique", enable_backward=False)
    def sample_kernel(mats: MaterialTable, m: int, wo: wp.array(dtype=wp.vec3), seed: int,
                      out: wp.array(dtype=wp.vec3)):
        t = wp.tid()
        st = wp.rand_init(seed, t)
        u = wp.vec3(wp.randf(st), wp.randf(st), wp.randf(st))
        out[t] = f.sample(mats, m, wo[t], u)

    return eval_kernel, pdf_kernel, sample_kernel


def _check_material(mb: MaterialBuffers, m, device) -> int:
    """The host wrappers' material index (one outside the table read memory beyond it) and device."""
    check_device(device)
    check_instance(mb, MaterialBuffers, "mb", "MaterialBuffers (build_material_table's)")   # its .table: no names
    return check_count(m, "m (material index)", 0, len(mb.names) - 1)


def check_sampling_tables(mb: MaterialBuffers, where: str, gb_material=None) -> None:
    """Refuse, in one line naming ``where``, a MERL or NPF material packed without its sampling table
    (``build_material_table(..., sampling=False)``, for directional lights alone) when a kernel that samples the BRDF
    (a pass under an environment) would read it: its sampler index read past the empty tables (a segfault).
    ``gb_material``: the G-buffer's per-pixel material ids (-1 empty; numpy or Warp), so that only the materials it
    shows count (None: every material).  Reads the material ids only when the table holds such a material."""
    kind, sampler = mb.table.kind.numpy(), mb.table.sampler.numpy()
    unsampled = np.isin(kind, (MERL, NPF)) & (sampler < 0)
    if not unsampled.any():
        return
    if gb_material is not None:
        shown = np.zeros(len(kind), bool)
        ids = np.unique(gb_material.numpy() if isinstance(gb_material, wp.array) else np.asarray(gb_material))
        shown[ids[(ids >= 0) & (ids < len(kind))]] = True
        unsampled &= shown
    if unsampled.any():
        m = int(np.argmax(unsampled))
        raise WarpbwError(f"{where}: materials: material {m} ({mb.names[m]!r}) was packed without its sampling table "
                          "(build_material_table(..., sampling=False), for directional lights alone), and this pass "
                          "samples its BRDF under the environment: pack it with sampling=True")


def _check_sampled(mb: MaterialBuffers, m: int, what: str) -> None:
    """A tabulated material of a table packed without sampling tables (``build_material_table(sampling=False)``)
    has no sampler: its index would read past the empty tables."""
    if mb.table.kind.numpy()[m] in (MERL, NPF) and mb.table.sampler.numpy()[m] < 0:
        raise WarpbwError(f"{what}: material {m} ({mb.names[m]!r}) was packed without its sampling table "
                          "(build_material_table(..., sampling=True) packs it)")


def _device_dirs(d: np.ndarray, name: str, device) -> wp.array:
    return wp.array(np.ascontiguousarray(unit_directions(d, name), np.float32), dtype=wp.vec3, device=device)


def eval_brdf(mb: MaterialBuffers, m: int, wi, wo, device: str = "cpu") -> np.ndarray:
    """f(wi, wo) for material m at N direction pairs (local frame; scaled to unit length) -> (N, 3)."""
    m = _check_material(mb, m, device)
    wi, wo = (d.reshape(-1, 3) for d in check_direction_pairs(wi, wo))
    out = wp.zeros(len(wi), dtype=wp.vec3, device=device)
    wp.launch(_host_kernels(mb.kinds)[0], dim=len(wi),
              inputs=[mb.table, m, _device_dirs(wi, "wi", device), _device_dirs(wo, "wo", device), out], device=device)
    return out.numpy()


def pdf_brdf(mb: MaterialBuffers, m: int, wi, wo, device: str = "cpu") -> np.ndarray:
    """Solid-angle pdf of the material's sampler at N direction pairs (scaled to unit length) -> (N,)."""
    m = _check_material(mb, m, device)
    _check_sampled(mb, m, "pdf_brdf")
    wi, wo = (d.reshape(-1, 3) for d in check_direction_pairs(wi, wo))
    out = wp.zeros(len(wi), dtype=float, device=device)
    wp.launch(_host_kernels(mb.kinds)[1], dim=len(wi),
              inputs=[mb.table, m, _device_dirs(wi, "wi", device), _device_dirs(wo, "wo", device), out], device=device)
    return out.numpy()


def sample_brdf(mb: MaterialBuffers, m: int, wo, n: int, seed: int = 0, device: str = "cpu") -> np.ndarray:
    """n directions wi drawn from the material's sampler for view wo (broadcast; scaled to unit length) -> (n, 3)."""
    m = _check_material(mb, m, device)
    _check_sampled(mb, m, "sample_brdf")
    n = check_count(n, "n", 1, INT32_MAX)
    seed = check_seed(seed)   # 2**32 drew seed 0's directions
    wo = np.atleast_2d(np.asarray(wo, np.float64))
    if wo.shape not in ((1, 3), (n, 3)):
        raise WarpbwError(f"wo: expected one direction (3,) or ({n}, 3), got shape {wo.shape}")
    out = wp.zeros(n, dtype=wp.vec3, device=device)
    wp.launch(_host_kernels(mb.kinds)[2], dim=n,
              inputs=[mb.table, m, _device_dirs(np.broadcast_to(wo, (n, 3)), "wo", device), seed, out],
              device=device)
    return out.numpy()
