"""Bandwidth operators of paper 002 (Fig. 4, Eq. 3, Eq. 4): warpbw.bandwidth_ops.

The reference matrices below are written here from the paper's Fig. 4, independently of the module.
One kernel (one compile) serves every test.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from warpbw import bandwidth_ops as bo
from warpbw.errors import WarpbwError


# --- 002 Fig. 4, written independently ---------------------------------------------------------------
def T(d):
    return np.array([[1.0, 0.0], [-d, 1.0]])


def Pi(ci):
    return np.array([[ci, 0.0], [0.0, 1.0]])


def Px(cx):
    return np.array([[1.0 / cx, 0.0], [0.0, 1.0]])


S = np.array([[1.0, 0.0], [0.0, -1.0]])


def C(c):
    return np.array([[1.0, c], [0.0, 1.0]])


def B_literal(nu, t, rho):
    return np.array([nu[0] + t, min(rho, nu[1])])


def close(got, want, rtol=2e-5):
    """float32 result against a float64 reference, tolerance scaled by the reference's magnitude."""
    got = np.asarray(got, np.float64)
    want = np.asarray(want, np.float64)
    scale = max(1.0, float(np.abs(want).max()))
    np.testing.assert_allclose(got, want, rtol=rtol, atol=rtol * scale)


SET = settings(max_examples=60, deadline=None)
val = st.floats(-1e3, 1e3, allow_nan=False, width=32)
nu2 = st.tuples(val, val)
pos = st.floats(0.0, 1e3, allow_nan=False, width=32)
cosv = st.floats(0.0625, 1.0, width=32)
f32 = lambda x: float(np.float32(x))  # parameters as the kernel sees them
# smallest nonzero bandwidth component in the sign test: far above float32's subnormals (1e-38) after the
# chain's factors (cos >= 1/16)
TINY_NU = 1e-30


def one(op, nu, **kw):
    return bo.apply_operator(op, [nu], **kw)[0]


# --- each operator against its matrix ----------------------------------------------------------------
@SET
@given(nu=nu2, d=val)
def test_transport_matches_fig4(nu, d):
    close(one("T", nu, d=d), T(f32(d)) @ np.array(nu))


@SET
@given(nu=nu2, ci=st.floats(-1.0, 1.0, width=32))
def test_incident_projection_matches_fig4(nu, ci):
    close(one("P_i", nu, cos_i=ci), Pi(f32(ci)) @ np.array(nu))


@SET
@given(nu=nu2, cx=cosv)
def test_exitant_projection_matches_fig4(nu, cx):
    close(one("P_x", nu, cos_x=cx), Px(f32(cx)) @ np.array(nu))


@SET
@given(nu=nu2)
def test_mirror_matches_fig4(nu):
    close(one("S", nu), S @ np.array(nu))


@SET
@given(nu=nu2, c=val)
def test_curvature_matches_fig4(nu, c):
    close(one("C", nu, c=c), C(f32(c)) @ np.array(nu))


@pytest.mark.parametrize("d, cos", [(0.0, 0.5), (2.5, 0.9), (-1.0, 0.05)])
def test_numpy_twins_match_fig4(d, cos):
    np.testing.assert_array_equal(bo.transport_matrix(d), T(d))
    np.testing.assert_array_equal(bo.curvature_matrix(d), C(d))
    np.testing.assert_array_equal(bo.incident_matrix(cos), Pi(cos))
    np.testing.assert_array_equal(bo.exitant_matrix(cos), Px(cos))
    np.testing.assert_array_equal(bo.mirror_matrix(), S)
    np.testing.assert_array_equal(bo.exitant_matrix(0.0), Px(bo.COS_X_MIN))


def test_vectorised_operators_match_their_numpy_twins():
    rng = np.random.default_rng(3)
    nu = rng.uniform(-50, 50, (256, 2)).astype(np.float32)
    p = rng.uniform(-3, 3, 256).astype(np.float32)
    cs = rng.uniform(0.01, 1, 256).astype(np.float32)
    for op, kw, mat in [("T", dict(d=p), bo.transport_matrix), ("C", dict(c=p), bo.curvature_matrix),
                        ("P_i", dict(cos_i=cs), bo.incident_matrix), ("P_x", dict(cos_x=cs), bo.exitant_matrix)]:
        got = bo.apply_operator(op, nu, **kw)
        arg = next(iter(kw.values()))
        want = np.stack([mat(a) @ v for a, v in zip(arg.astype(np.float64), nu.astype(np.float64))])
        close(got, want)


# --- composition identities --------------------------------------------------------------------------
@SET
@given(nu=nu2, a=st.floats(-30, 30, width=32), b=st.floats(-30, 30, width=32))
def test_transport_composes_additively(nu, a, b):
    ab = bo.apply_operator("T", bo.apply_operator("T", [nu], d=b), d=a)[0]
    close(ab, one("T", nu, d=f32(a) + f32(b)), rtol=1e-4)


@SET
@given(nu=nu2, a=st.floats(-30, 30, width=32), b=st.floats(-30, 30, width=32))
def test_curvature_composes_additively(nu, a, b):
    ab = bo.apply_operator("C", bo.apply_operator("C", [nu], c=b), c=a)[0]
    close(ab, one("C", nu, c=f32(a) + f32(b)), rtol=1e-4)


@SET
@given(nu=nu2)
def test_mirror_is_an_involution_and_unit_projections_are_identity(nu):
    v = np.array(nu, np.float32)
    np.testing.assert_array_equal(bo.apply_operator("S", bo.apply_operator("S", [v]))[0], v)
    np.testing.assert_array_equal(one("P_i", v, cos_i=1.0), v)
    np.testing.assert_array_equal(one("P_x", v, cos_x=1.0), v)
    np.testing.assert_array_equal(one("T", v, d=0.0), v)
    np.testing.assert_array_equal(one("C", v, c=0.0), v)


@SET
@given(nu=nu2)
def test_reflection_reduces_to_mirror(nu):
    """c = 0, t = 0, rho = inf, cos_i = cos_x = 1: R_signed = S, and R = |S nu|."""
    v = np.array(nu, np.float32)
    kw = dict(cos_i=1.0, cos_x=1.0, c=0.0, t=0.0, rho=math.inf)
    np.testing.assert_array_equal(one("R_signed", v, **kw), S @ v)
    np.testing.assert_array_equal(bo.apply_reflection([v], **kw)[0], np.abs(S @ v))


@SET
@given(nu=nu2, ci=cosv, cx=cosv, c=st.floats(-10, 10, width=32))
def test_reflection_is_the_matrix_product_when_b_is_inactive(nu, ci, cx, c):
    """t = 0, rho = inf: R = P_x C_{-c} S C_c P_i exactly as Eq. 3, any signs."""
    ci, cx, c = f32(ci), f32(cx), f32(c)
    want = Px(cx) @ C(-c) @ S @ C(c) @ Pi(ci) @ np.array(nu)
    close(one("R_signed", nu, cos_i=ci, cos_x=cx, c=c, t=0.0, rho=math.inf), want, rtol=1e-4)
    close(bo.apply_reflection([nu], ci, cx, c, 0.0, math.inf)[0], np.abs(want), rtol=1e-4)


@SET
@given(nu=st.tuples(pos, pos), ci=cosv, cx=cosv, c=st.floats(0, 10, width=32), t=pos, rho=pos)
def test_reflection_equals_literal_eq3_on_the_papers_non_negative_vectors(nu, ci, cx, c, t, rho):
    """Non-negative bandwidths and convex c >= 0: the odd B is Fig. 4's B literally."""
    ci, cx, c, t, rho = map(f32, (ci, cx, c, t, rho))
    v = C(c) @ Pi(ci) @ np.array(nu)
    want = Px(cx) @ C(-c) @ S @ B_literal(v, t, rho)
    close(one("R_signed", nu, cos_i=ci, cos_x=cx, c=c, t=t, rho=rho), want, rtol=1e-4)


@SET
@given(nu=st.tuples(pos, pos), dnu=st.tuples(pos, pos), ci=cosv, dci=st.floats(0.0, 1.0), cx=cosv,
       dcx=st.floats(0.0, 1.0), c=st.floats(0, 10, width=32), dc=st.floats(0, 10, width=32), t=pos, dt=pos, rho=pos,
       drho=pos)
def test_reflected_bandwidth_never_falls_with_more_light_curvature_texture_band_or_grazing(
        nu, dnu, ci, dci, cx, dcx, c, dc, t, dt, rho, drho):
    """On the paper's non-negative vectors with convex c >= 0 (002 Sec. 2.3): a wider incident spectrum, a more
    frontal light (cos_i up), a more curved surface (more shear), more texture, a wider BRDF band (rho) or a more
    grazing view (cos_x down) never lowers either component of |R nu|: each enters Eq. 3 with a non-negative
    sign.  Every parameter moves its own way at once (float32: 1e-5 relative)."""
    lo = dict(cos_i=f32(ci), cos_x=f32(cx), c=f32(c), t=f32(t), rho=f32(rho))
    hi = dict(cos_i=f32(ci + dci * (1.0 - ci)), cos_x=f32(cx - dcx * (cx - 0.0625)), c=f32(c + dc), t=f32(t + dt),
              rho=f32(rho + drho))
    a = bo.apply_reflection([nu], **lo)[0].astype(np.float64)
    b = bo.apply_reflection([(nu[0] + dnu[0], nu[1] + dnu[1])], **hi)[0].astype(np.float64)
    assert np.all(b >= a * (1.0 - 1e-5) - 1e-30), (a, b)


@SET
@given(nu=nu2, d=st.floats(-20, 20, width=32), dp=st.floats(-20, 20, width=32), ci=cosv, cx=cosv,
       c=st.floats(-10, 10, width=32))
def test_one_bounce_is_eq4(nu, d, dp, ci, cx, c):
    d, dp, ci, cx, c = map(f32, (d, dp, ci, cx, c))
    want = np.abs(T(dp) @ Px(cx) @ C(-c) @ S @ C(c) @ Pi(ci) @ T(d) @ np.array(nu))
    close(bo.one_bounce([nu], d, dp, ci, cx, c, 0.0, math.inf)[0], want, rtol=1e-4)
    # without transport, one bounce is the reflection
    close(bo.one_bounce([nu], 0.0, 0.0, ci, cx, c, 3.0, 7.0)[0],
          bo.apply_reflection([nu], ci, cx, c, 3.0, 7.0)[0])


@SET
@given(nu=nu2, d=st.floats(-20, 20, width=32), dp=st.floats(-20, 20, width=32), ci=cosv, cx=cosv,
       c=st.floats(-10, 10, width=32), t=pos, rho=pos)
def test_sign_of_the_representative_does_not_matter(nu, d, dp, ci, cx, c, t, rho):
    """nu and -nu describe the same spectrum: R is odd, |R| and Eq. 4 are even; outputs are >= 0."""
    assume(nu != (0.0, 0.0))
    # a component so small that cos_i times it underflows to zero leaves no sign to be odd in (B reads the
    # sign of nu_s; hypothesis found nu_s = 1.4e-45, which 0.5 * nu_s rounds to +0 or -0, and -0 + 0 = +0)
    assume(all(x == 0.0 or abs(x) >= TINY_NU for x in nu))
    v = np.array(nu, np.float32)
    kw = dict(cos_i=ci, cos_x=cx, c=c, t=t, rho=rho)
    r_pos, r_neg = bo.apply_operator("R_signed", np.stack([v, -v]), **kw)
    np.testing.assert_array_equal(r_neg, -r_pos)
    ob = bo.one_bounce(np.stack([v, -v]), d, dp, **kw)
    np.testing.assert_array_equal(ob[0], ob[1])
    assert (ob >= 0).all() and (bo.apply_reflection([v], **kw) >= 0).all()


def test_curved_mirror_doubles_curvature_for_convex_and_concave():
    """Distant light nu = [0, a] on a perfect mirror: nu_s = 2 |c| a (both shears add), nu_a = a."""
    for c in (2.0, -2.0):
        close(bo.apply_reflection([[0.0, 10.0]], 1.0, 1.0, c, 0.0, math.inf)[0], [40.0, 10.0])
    # then d' = 2 m to the eye: nu_a grows by d' nu_s (S makes the transport add)
    close(bo.one_bounce([[0.0, 10.0]], 5.0, 2.0, c=2.0)[0], [40.0, 90.0])


# --- B: texture add, angular band limit ----------------------------------------------------------------
@SET
@given(nu=nu2, t=pos, rho=pos)
def test_band_limit_adds_texture_and_clamps_angle(nu, t, rho):
    s, a = map(f32, nu)
    t, rho = f32(t), f32(rho)
    r = one("B", (s, a), t=t, rho=rho)
    assert abs(r[1]) == pytest.approx(min(rho, abs(a)), rel=1e-6)
    assert abs(r[0]) == pytest.approx(abs(s) + t, rel=1e-6, abs=1e-3)
    if a != 0.0:
        assert np.sign(r[1]) == np.sign(a) or r[1] == 0.0
    if s != 0.0:
        assert np.sign(r[0]) == np.sign(s)
    if s >= 0.0 and a >= 0.0:
        close(r, B_literal((s, a), t, rho))


def test_band_limit_edges():
    np.testing.assert_array_equal(one("B", (3.0, 5.0), t=0.0, rho=math.inf), [3.0, 5.0])
    np.testing.assert_array_equal(one("B", (3.0, 5.0), t=2.0, rho=4.0), [5.0, 4.0])
    np.testing.assert_array_equal(one("B", (3.0, 5.0), t=2.0, rho=0.0), [5.0, 0.0])
    np.testing.assert_array_equal(one("B", (3.0, -5.0), t=2.0, rho=4.0), [5.0, -4.0])
    np.testing.assert_array_equal(one("B", (-3.0, 5.0), t=2.0, rho=9.0), [-5.0, 5.0])
    # nu_s = 0: t takes nu_a's sign (B stays odd); zero vector: +t
    np.testing.assert_array_equal(one("B", (0.0, -5.0), t=2.0, rho=9.0), [-2.0, -5.0])
    np.testing.assert_array_equal(one("B", (0.0, 0.0), t=2.0, rho=9.0), [2.0, 0.0])
    # a diffuse BRDF (rho = 0) removes all angular bandwidth from the reflection
    r = bo.apply_reflection([[0.0, 100.0]], 1.0, 1.0, 0.0, 0.0, 0.0)[0]
    np.testing.assert_array_equal(r, [0.0, 0.0])


# --- finiteness ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("cx", [0.0, -0.0, 1e-9, 1e-4, bo.COS_X_MIN, -1e-6])
def test_grazing_exitant_is_finite_and_clamped(cx):
    nu = [[10.0, 4.0]]
    r = bo.apply_reflection(nu, 1.0, cx, 0.0, 0.0, math.inf)[0]
    assert np.isfinite(r).all()
    close(r, [10.0 / bo.COS_X_MIN, 4.0])
    assert np.isfinite(one("P_x", (10.0, 4.0), cos_x=cx)).all()


def test_exitant_scale_grows_monotonically_towards_grazing():
    cx = np.array([1.0, 0.5, 0.1, 0.01, 0.002, 1e-3, 1e-5, 0.0], np.float32)
    r = bo.apply_reflection(np.tile([[1.0, 0.0]], (len(cx), 1)), 1.0, cx, 0.0, 0.0, math.inf)[:, 0]
    assert (np.diff(r) >= 0).all() and r[-1] == pytest.approx(1.0 / bo.COS_X_MIN)


@pytest.mark.parametrize("c", [0.0, 1e-30, 1e10, -1e10, 1e30, 1e38, math.inf, -math.inf])
def test_zero_and_huge_curvature_stay_finite(c):
    nu = np.array([[0.0, 10.0], [3.0, 0.0], [1e30, 1e30], [math.inf, -math.inf], [0.0, 0.0]], np.float32)
    r = bo.apply_reflection(nu, 0.7, 0.3, c, 5.0, 50.0)
    ob = bo.one_bounce(nu, 1e20, math.inf, 0.7, 0.0, c, math.inf, math.inf)
    for x in (r, ob):
        assert np.isfinite(x).all() and (x >= 0).all() and (x <= np.float32(bo.NU_MAX)).all()
    if c == 0.0:
        close(r[0], [5.0 / 0.3, 10.0])  # only the texture reaches nu_s; rho = 50 does not clip a = 10


def test_non_band_limited_input_saturates_at_nu_max():
    r = bo.apply_reflection([[math.inf, 0.0]], 1.0, 1.0, 0.0, 0.0, math.inf)[0]
    np.testing.assert_array_equal(r, [np.float32(bo.NU_MAX), 0.0])


# --- bad input -------------------------------------------------------------------------------------------
@pytest.mark.parametrize("kw", [dict(t=-1.0), dict(rho=-0.5), dict(c=math.nan), dict(cos_x=[0.5, 0.5, 0.5])])
def test_bad_parameters_are_refused(kw):
    with pytest.raises(WarpbwError):
        bo.apply_operator("R", [[1.0, 2.0], [3.0, 4.0]], **kw)


@pytest.mark.parametrize("value", [None, "0.5", [None]], ids=["None", "str", "list of None"])
def test_a_parameter_that_is_not_a_number_is_named_as_such(value):
    """d=None was refused as 'parameter d is NaN' (None reads as NaN in a float array), a string by numpy."""
    with pytest.raises(WarpbwError, match=r"^parameter d: expected a number or one number per bandwidth vector"):
        bo.apply_operator("T", [[1.0, 2.0]], d=value)
    np.testing.assert_allclose(bo.apply_operator("T", [[1.0, 2.0]], d=np.float32(0.5)), [[1.0, 1.5]])


def test_bad_shape_and_operator_are_refused():
    with pytest.raises(WarpbwError):
        bo.apply_operator("R", [[1.0, 2.0, 3.0]])
    with pytest.raises(WarpbwError):
        bo.apply_operator("Q", [[1.0, 2.0]])
    assert bo.apply_reflection(np.zeros((0, 2)), 1.0, 1.0, 0.0, 0.0, 1.0).shape == (0, 2)


def test_exitant_projection_scales_the_spatial_bandwidth_by_at_most_1000():
    """warpbw.bandwidth_ops docstring: cos theta_x below 1e-3 (theta_x > 89.94 deg) counts as 1e-3, so P_x scales
    nu_s by at most 1000 (the other tests compare with the module's own COS_X_MIN, so any clamp passed them)."""
    out = bo.apply_operator("P_x", [[1.0, 2.0], [1.0, 2.0]], cos_x=np.array([0.0, math.cos(math.radians(89.9))]))
    np.testing.assert_allclose(out, [[1000.0, 2.0], [1.0 / math.cos(math.radians(89.9)), 2.0]], rtol=1e-5)


@pytest.mark.parametrize("cx", [-1.0, -0.5, -0.1, -0.01, -1e-4])
def test_exitant_projection_scales_by_the_magnitude_of_a_negative_cosine(cx):
    """Module docstring: P_x scales nu_s by 1 / max(|cos theta_x|, COS_X_MIN), for a negative cos theta_x too."""
    scale = 1.0 / max(abs(cx), bo.COS_X_MIN)
    r = bo.apply_operator("P_x", [[10.0, 4.0]], cos_x=cx)[0]
    assert abs(r[0]) == pytest.approx(10.0 * scale, rel=1e-5)
    assert r[1] == pytest.approx(4.0)
    # and inside R (B inactive, c = 0): |R [s, a]| = [s / max(|cos_x|, COS_X_MIN), a]
    rr = bo.apply_reflection([[10.0, 4.0]], 1.0, cx, 0.0, 0.0, math.inf)[0]
    np.testing.assert_allclose(rr, [10.0 * scale, 4.0], rtol=1e-5)


@SET
@given(nu=nu2, ci=st.floats(-1.0, -0.0625, width=32), cx=cosv, c=st.floats(-10, 10, width=32))
def test_reflection_takes_the_incident_cosine_by_magnitude(nu, ci, cx, c):
    """Module docstring (Finiteness): inside R and Eq. 4, P_i scales by |cos theta_i|, so a negative cos_i is Eq. 3 at
    -cos_i, while P_i alone stays the signed matrix."""
    ci, cx, c = f32(ci), f32(cx), f32(c)
    want = Px(cx) @ C(-c) @ S @ C(c) @ Pi(-ci) @ np.array(nu)
    close(one("R_signed", nu, cos_i=ci, cos_x=cx, c=c, t=0.0, rho=math.inf), want, rtol=1e-4)
    close(bo.one_bounce([nu], 0.0, 0.0, ci, cx, c, 0.0, math.inf)[0], np.abs(want), rtol=1e-4)
    close(one("P_i", nu, cos_i=ci), Pi(ci) @ np.array(nu))
