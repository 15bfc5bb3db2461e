"""2D bandwidth operators of paper 002 (Fig. 4, Eq. 3, Eq. 4) as Warp functions.

The local light field around a ray has bandwidth ``nu = [nu_s, nu_a]`` (spatial in cycles/metre,
angular in cycles/radian): the rectangle with corners ``-nu`` and ``+nu`` holds its spectrum (002 Sec. 2).

Public:
    Warp functions (``wp.vec2`` in, ``wp.vec2`` out; for use inside other kernels, e.g. the bandwidth pass)
    ``bw_transport(nu, d)``                   T_d: free-space transport by a distance d (m)
    ``bw_incident(nu, cos_i)``                P_i: spatial scale by cos theta_i
    ``bw_exitant(nu, cos_x)``                 P_x: spatial scale by 1 / max(|cos theta_x|, COS_X_MIN)
    ``bw_mirror(nu)``                         S: mirror re-parametrization
    ``bw_curvature(nu, c)``                   C_c: curvature shear, c in 1/m
    ``bw_band_limit(nu, t, rho)``             B_{t,rho}: texture t added to nu_s, nu_a limited to rho
    ``bw_reflect_signed(nu, cos_i, cos_x, c, t, rho)``   R = P_x C_{-c} S B_{t,rho} C_c P_i (Eq. 3), signed
    ``bw_reflect(nu, cos_i, cos_x, c, t, rho)``          |R nu|: the reflected bandwidth
    ``bw_one_bounce(nu, d, dp, cos_i, cos_x, c, t, rho)`` |T_{d'} R T_d nu| (Eq. 4)
    Host numpy twins of the linear operators (2x2 float64 matrices)
    ``transport_matrix(d)``, ``incident_matrix(cos_i)``, ``exitant_matrix(cos_x)``, ``mirror_matrix()``,
    ``curvature_matrix(c)``
    Host wrappers (numpy in, numpy out; one kernel launch each, for tests and the bandwidth pass)
    ``apply_operator(op, nu, ...)``           any operator above by name (``OPS``)
    ``apply_reflection(nu, cos_i, cos_x, c, t, rho)``    -> (N, 2), |R nu|
    ``one_bounce(nu, d, dp, cos_i, cos_x, c, t, rho)``   -> (N, 2), Eq. 4
    Constants ``COS_X_MIN``, ``NU_MAX``, ``OPS``

Signs
-----
The matrices of Fig. 4 act on a *signed* vector and can make components negative (T_d puts
``-d nu_s`` into the angular component, S flips it).  A bandwidth is a maximum frequency, i.e. a
magnitude, but the spectrum of a real signal is point-symmetric, so ``nu`` and ``-nu`` describe the
same spectrum and the signed vector is a representative corner whose signs record how the spectrum
is sheared.  We therefore:

1. keep the elementary operators exactly linear (they equal their Fig. 4 matrices, signs included);
2. keep the signs through the whole chain of Eq. 3 / Eq. 4, because the paper's matrices rely on them:
   S followed by C_{-c} makes the two curvature shears of a mirror *add* (a convex mirror under a
   distant light, nu = [0, a], gives nu_s = 2 c a), and S makes T_{d'} *add* d' nu_s to |nu_a|;
3. apply B_{t,rho} as its odd extension, so that it never depends on which representative is used:
   ``B(nu) = [nu_s + sgn(nu_s) t, sgn(nu_a) min(rho, |nu_a|)]`` (sgn(nu_s) taken from nu_a when
   nu_s = 0, +1 when both are 0).  Texture grows |nu_s| by exactly t and the BRDF clamps |nu_a| to
   rho whatever the signs; for the non-negative vectors of the paper's examples this *is* Fig. 4;
4. take absolute values only where a physical bandwidth leaves the chain: the outputs of
   ``bw_reflect`` and ``bw_one_bounce`` (never between R and T_{d'}, which would lose the sign
   that S sets).  ``bw_reflect_signed`` exposes the signed R for composing further operators.

Consequence: as in the paper's linear model, shears may partly cancel (e.g. nu_s (cos_i - c d) for a
local light), which describes focusing of a sheared spectrum; a strictly conservative bound of the
rectangle would use |M| |nu| instead and never cancel.  002 Eq. 5 averages these per-path bandwidths
anyway, so we follow the paper.

Finiteness
----------
The composite functions saturate their inputs and every intermediate to ``[-NU_MAX, NU_MAX]``
(002 Sec. 2: "an arbitrarily large value" for non-band-limited signals; inf is accepted for rho and
any input), so no product 0 * inf or difference inf - inf can arise: results are finite for any
curvature, distance or cosine.  P_x divides by ``max(|cos theta_x|, COS_X_MIN)``; inside R (and Eq. 4) P_i scales
by ``min(|cos theta_i|, 1)``, so a cosine's sign never matters there (``bw_incident`` alone is the signed matrix).
"""
from __future__ import annotations

import math
import numbers

import numpy as np
import warp as wp

from warpbw.errors import FLOAT32_MAX, WarpbwError, check_device, numeric_array

# Grazing clamp of P_x (002 Fig. 4 has 1 / cos theta_x, unbounded at the silhouette): cos theta_x
# below 1e-3 (theta_x > 89.94 deg) counts as 1e-3, so P_x scales nu_s by at most 1000.  The image-space
# step (002 Sec. 2.2) clamps to the largest representable frequency anyway; this only keeps the
# intermediate finite and float32-friendly.
COS_X_MIN = 1.0e-3

# "Arbitrarily large value" stored for non-band-limited signals (002 Sec. 2, "2D bandwidth"): the
# composite operators saturate to +-NU_MAX (float32 max is 3.4e38, so NU_MAX * small factors stay finite).
NU_MAX = 1.0e30


# --- elementary operators (002 Fig. 4), exactly linear except B -------------------------------------

@wp.func
def bw_transport(nu: wp.vec2, d: float):
    """T_d = [[1, 0], [-d, 1]]: free-space transport by d metres (angular shear; 002 Fig. 4)."""
    return wp.vec2(nu[0], nu[1] - d * nu[0])


@wp.func
def bw_incident(nu: wp.vec2, cos_i: float):
    """P_i = [[cos_i, 0], [0, 1]]: re-parametrization into the surface frame (002 Fig. 4)."""
    return wp.vec2(cos_i * nu[0], nu[1])


@wp.func
def bw_exitant(nu: wp.vec2, cos_x: float):
    """P_x = [[1 / cos_x, 0], [0, 1]] with |cos_x| clamped below at COS_X_MIN (002 Fig. 4)."""
    return wp.vec2(nu[0] / wp.max(wp.abs(cos_x), COS_X_MIN), nu[1])


@wp.func
def bw_mirror(nu: wp.vec2):
    """S = [[1, 0], [0, -1]]: mirror re-parametrization (002 Fig. 4)."""
    return wp.vec2(nu[0], -nu[1])


@wp.func
def bw_curvature(nu: wp.vec2, c: float):
    """C_c = [[1, c], [0, 1]]: curvature shear, c in 1/m (002 Fig. 4)."""
    return wp.vec2(nu[0] + c * nu[1], nu[1])


@wp.func
def bw_band_limit(nu: wp.vec2, t: float, rho: float):
    """B_{t,rho} nu = [nu_s + t, min(rho, nu_a)] (002 Fig. 4), applied to magnitudes, signs kept.

    t >= 0 (texture spatial bandwidth) and rho >= 0 (BRDF angular bandwidth, may be inf); see the
    module docstring, "Signs", item 3.
    """
    s = nu[0]
    a = nu[1]
    sa = 1.0
    if a < 0.0:
        sa = -1.0
    ss = sa
    if s > 0.0:
        ss = 1.0
    elif s < 0.0:
        ss = -1.0
    return wp.vec2(s + ss * t, sa * wp.min(rho, wp.abs(a)))


# --- composites (002 Eq. 3, Eq. 4) -----------------------------------------------------------------------

@wp.func
def _sat(x: float):
    return wp.clamp(x, -NU_MAX, NU_MAX)


@wp.func
def _sat2(v: wp.vec2):
    return wp.vec2(_sat(v[0]), _sat(v[1]))


@wp.func
def bw_reflect_signed(nu: wp.vec2, cos_i: float, cos_x: float, c: float, t: float, rho: float):
    """R nu = P_x C_{-c} S B_{t,rho} C_c P_i nu (002 Eq. 3), signed and saturated to +-NU_MAX.  P_i scales by
    min(|cos theta_i|, 1): the incident angle's cosine is taken by magnitude, as P_x's is."""
    cc = _sat(c)
    v = _sat2(nu)
    v = bw_incident(v, wp.min(wp.abs(cos_i), 1.0))
    v = _sat2(bw_curvature(v, cc))
    v = _sat2(bw_band_limit(v, wp.clamp(t, 0.0, NU_MAX), wp.clamp(rho, 0.0, NU_MAX)))
    v = bw_mirror(v)
    v = _sat2(bw_curvature(v, -cc))
    return _sat2(bw_exitant(v, cos_x))


@wp.func
def bw_reflect(nu: wp.vec2, cos_i: float, cos_x: float, c: float, t: float, rho: float):
    """|R nu|: bandwidth reflected at a surface point (002 Eq. 3), components >= 0."""
    r = bw_reflect_signed(nu, cos_i, cos_x, c, t, rho)
    return wp.vec2(wp.abs(r[0]), wp.abs(r[1]))


@wp.func
def bw_one_bounce(nu: wp.vec2, d: float, dp: float, cos_i: float, cos_x: float, c: float, t: float,
                  rho: float):
    """|T_{d'} R T_d nu| (002 Eq. 4): light -> d -> reflection -> d' -> image plane, components >= 0."""
    v = _sat2(bw_transport(_sat2(nu), _sat(d)))
    v = bw_reflect_signed(v, cos_i, cos_x, c, t, rho)
    v = _sat2(bw_transport(v, _sat(dp)))
    return wp.vec2(wp.abs(v[0]), wp.abs(v[1]))


# --- host numpy twins of the linear operators (002 Fig. 4) --------------------------------------------

def _scalar(value, name: str) -> float:
    """A matrix's parameter as a float, else a one-line ``WarpbwError`` ("a" and [1, 2] gave float()'s errors)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (numbers.Real, np.ndarray)) or np.ndim(value):
        raise WarpbwError(f"{name}: expected one number, got {value!r:.60}")
    if math.isnan(float(value)):   # a matrix of NaN, where apply_operator refuses a NaN parameter
        raise WarpbwError(f"{name}: expected a number, got NaN")
    return float(value)


def transport_matrix(d: float) -> np.ndarray:
    """T_d as a 2x2 float64 matrix."""
    return np.array([[1.0, 0.0], [-_scalar(d, "d"), 1.0]])


def incident_matrix(cos_i: float) -> np.ndarray:
    """P_i as a 2x2 float64 matrix."""
    return np.array([[_scalar(cos_i, "cos_i"), 0.0], [0.0, 1.0]])


def exitant_matrix(cos_x: float) -> np.ndarray:
    """P_x as a 2x2 float64 matrix, with |cos_x| clamped below at COS_X_MIN as ``bw_exitant``."""
    return np.array([[1.0 / max(abs(_scalar(cos_x, "cos_x")), COS_X_MIN), 0.0], [0.0, 1.0]])


def mirror_matrix() -> np.ndarray:
    """S as a 2x2 float64 matrix."""
    return np.array([[1.0, 0.0], [0.0, -1.0]])


def curvature_matrix(c: float) -> np.ndarray:
    """C_c as a 2x2 float64 matrix."""
    return np.array([[1.0, _scalar(c, "c")], [0.0, 1.0]])


# --- host wrappers ------------------------------------------------------------------------------------------

# Operator names accepted by apply_operator, with the kernel's op ids.
OPS = {"T": 0, "P_i": 1, "P_x": 2, "S": 3, "C": 4, "B": 5, "R_signed": 6, "R": 7, "one_bounce": 8}
# Column order of the per-row parameter table passed to the kernel.
_PARAMS = ("d", "dp", "cos_i", "cos_x", "c", "t", "rho")


@wp.kernel(module="unique", enable_backward=False)
def _bandwidth_op_kernel(op: int, nu: wp.array(dtype=wp.vec2), p: wp.array2d(dtype=float),
                         out: wp.array(dtype=wp.vec2)):
    i = wp.tid()
    v = nu[i]
    d = p[i, 0]
    dp = p[i, 1]
    cos_i = p[i, 2]
    cos_x = p[i, 3]
    c = p[i, 4]
    t = p[i, 5]
    rho = p[i, 6]
    r = v
    if op == 0:
        r = bw_transport(v, d)
    elif op == 1:
        r = bw_incident(v, cos_i)
    elif op == 2:
        r = bw_exitant(v, cos_x)
    elif op == 3:
        r = bw_mirror(v)
    elif op == 4:
        r = bw_curvature(v, c)
    elif op == 5:
        r = bw_band_limit(v, t, rho)
    elif op == 6:
        r = bw_reflect_signed(v, cos_i, cos_x, c, t, rho)
    elif op == 7:
        r = bw_reflect(v, cos_i, cos_x, c, t, rho)
    elif op == 8:
        r = bw_one_bounce(v, d, dp, cos_i, cos_x, c, t, rho)
    out[i] = r


def _check_float32(name: str, a: np.ndarray) -> None:
    """Refuse finite values beyond float32's range: the kernel takes float32, where 1e39 became inf without a word."""
    big = np.isfinite(a) & (np.abs(a) > FLOAT32_MAX)
    if big.any():
        raise WarpbwError(f"{name}: {a[big].reshape(-1)[0]:.3g} is beyond float32's range (+-{FLOAT32_MAX:.4g}, as the "
                          "kernel takes it); expected a smaller value, or inf")


def apply_operator(op: str, nu, *, d=0.0, dp=0.0, cos_i=1.0, cos_x=1.0, c=0.0, t=0.0, rho=math.inf,
                   device: str = "cpu") -> np.ndarray:
    """Apply the operator named ``op`` (a key of ``OPS``) to N bandwidth vectors ``nu`` (N, 2) -> (N, 2).

    Parameters are scalars or length-N arrays (broadcast); only the ones the operator uses matter.
    ``t`` and ``rho`` are bandwidths and must be >= 0 (rho may be inf); NaN parameters are refused, and so are finite
    values (of ``nu`` too) beyond float32's range, which the kernel would read as inf.
    Cosines lie in [-1, 1]; "P_i" alone is the signed matrix, while P_x, and P_i inside R and Eq. 4, take |cos|.
    """
    if op not in OPS:
        raise WarpbwError(f"unknown bandwidth operator {op!r}; expected one of {sorted(OPS)}")
    check_device(device)
    nu = numeric_array(nu, "nu", "(N, 2) bandwidths")   # strings: numpy's ValueError
    _check_float32("nu", nu)
    v = nu.astype(np.float32)
    if v.ndim == 1:
        v = v.reshape(1, -1)
    if v.ndim != 2 or v.shape[1] != 2:
        raise WarpbwError(f"nu must have shape (N, 2), got {np.shape(nu)}")
    if np.isnan(v).any():   # "T" passed NaN on, "R" turned it into 1e30
        raise WarpbwError("nu has NaN values (expected bandwidths >= 0, or inf)")
    n = v.shape[0]
    vals = dict(d=d, dp=dp, cos_i=cos_i, cos_x=cos_x, c=c, t=t, rho=rho)
    p = np.empty((n, len(_PARAMS)), dtype=np.float32)
    for k, name in enumerate(_PARAMS):
        try:   # None read as NaN ("parameter d is NaN"), a string as numpy's error
            raw = np.asarray(vals[name])
        except (TypeError, ValueError):   # ragged lists
            raw = np.asarray(None)
        if raw.dtype.kind not in "biuf":   # None and [None] are objects, strings "U" or "S"
            raise WarpbwError(f"parameter {name}: expected a number or one number per bandwidth vector, got "
                              f"{vals[name]!r:.60}")
        col = raw.astype(np.float64).reshape(-1)
        if col.size not in (1, n):
            raise WarpbwError(f"parameter {name} has {col.size} values for {n} bandwidth vectors")
        if np.isnan(col).any():
            raise WarpbwError(f"parameter {name} is NaN")
        _check_float32(f"parameter {name}", col)
        if name in ("t", "rho") and (col < 0).any():
            raise WarpbwError(f"parameter {name} is a bandwidth and must be >= 0, got {col.min()}")
        if name in ("cos_i", "cos_x") and (np.abs(col) > 1.0).any():
            raise WarpbwError(f"parameter {name} is a cosine and must lie in [-1, 1], got {col[np.abs(col) > 1.0][0]}")
        p[:, k] = np.broadcast_to(col, (n,))
    if n == 0:
        return np.zeros((0, 2), dtype=np.float32)
    out = wp.zeros(n, dtype=wp.vec2, device=device)
    wp.launch(_bandwidth_op_kernel, dim=n,
              inputs=[OPS[op], wp.array(np.ascontiguousarray(v), dtype=wp.vec2, device=device),
                      wp.array(p, dtype=float, device=device), out], device=device)
    return out.numpy()


def apply_reflection(nu, cos_i, cos_x, c, t, rho, device: str = "cpu") -> np.ndarray:
    """|R nu| (002 Eq. 3) for N bandwidth vectors (N, 2); parameters scalar or length N -> (N, 2)."""
    return apply_operator("R", nu, cos_i=cos_i, cos_x=cos_x, c=c, t=t, rho=rho, device=device)


def one_bounce(nu, d, dp, cos_i=1.0, cos_x=1.0, c=0.0, t=0.0, rho=math.inf, device: str = "cpu") -> np.ndarray:
    """|T_{d'} R T_d nu| (002 Eq. 4): bandwidth at the image plane of N light paths -> (N, 2)."""
    return apply_operator("one_bounce", nu, d=d, dp=dp, cos_i=cos_i, cos_x=cos_x, c=c, t=t, rho=rho,
                          device=device)
