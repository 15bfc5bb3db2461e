"""BRDF evaluation in Warp against independent host formulas and lookups; reciprocity, positivity."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from warpbw import brdf as B
from warpbw.sampling import build_sampler_table

N_DIRS = 4000


def uniform_sampler():
    return build_sampler_table(lambda wi, wo: np.ones((len(wi), 3)), n_theta_o=2, n_u=4, n_phi=4, sub=1)


def random_hemisphere(rng, n, min_cos=0.0):
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v[:, 2] = np.abs(v[:, 2])
    return v[v[:, 2] > min_cos]


def ggx_numpy(wi, wo, alpha, spec):
    h = wi + wo
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    a2 = alpha * alpha
    D = a2 / (np.pi * (h[:, 2] ** 2 * (a2 - 1) + 1) ** 2)
    g1 = lambda c: 2 * c / (c + np.sqrt(a2 + (1 - a2) * c * c))  # noqa: E731
    return (D * g1(wi[:, 2]) * g1(wo[:, 2]) / (4 * wi[:, 2] * wo[:, 2]))[:, None] * np.asarray(spec)[None]


def fresnel_conductor_numpy(cos_d, eta, k):
    """Exact unpolarised conductor Fresnel via complex arithmetic (independent of the kernel's form)."""
    n = eta + 1j * k
    c = cos_d.astype(complex)
    s2 = 1 - c * c
    ct = np.sqrt(1 - s2 / (n * n))
    rs = (c - n * ct) / (c + n * ct)
    rp = (n * c - ct) / (n * c + ct)
    return 0.5 * (np.abs(rs) ** 2 + np.abs(rp) ** 2)


@pytest.fixture(scope="module")
def analytic():
    specs = [B.MaterialSpec("lam", B.LAMBERT, albedo=(0.2, 0.5, 0.9)),
             B.MaterialSpec("ggx", B.GGX, alpha=0.25, specular=(0.9, 0.6, 0.3)),
             B.MaterialSpec("gold", B.GGX, alpha=0.4, specular=(1.0, 1.0, 1.0), eta=(0.143, 0.374, 1.442),
                            k=(3.983, 2.385, 1.603))]
    return B.build_material_table(specs)


def test_lambert_and_ggx_match_closed_forms(analytic):
    rng = np.random.default_rng(1)
    wi = random_hemisphere(rng, N_DIRS, 0.01)
    wo = random_hemisphere(rng, len(wi) * 2, 0.01)[: len(wi)]
    f = B.eval_brdf(analytic, 0, wi, wo)
    assert np.allclose(f, np.array([0.2, 0.5, 0.9]) / np.pi, rtol=1e-6)
    f = B.eval_brdf(analytic, 1, wi, wo)
    assert np.allclose(f, ggx_numpy(wi, wo, 0.25, (0.9, 0.6, 0.3)), rtol=2e-4, atol=1e-7)


def test_conductor_fresnel_matches_complex_formula(analytic):
    rng = np.random.default_rng(2)
    wi = random_hemisphere(rng, N_DIRS, 0.01)
    wo = random_hemisphere(rng, len(wi) * 2, 0.01)[: len(wi)]
    f = B.eval_brdf(analytic, 2, wi, wo)
    h = wi + wo
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    cos_d = np.einsum("ij,ij->i", wi, h)
    F = np.stack([fresnel_conductor_numpy(cos_d, e, k) for e, k in zip((0.143, 0.374, 1.442),
                                                                       (3.983, 2.385, 1.603))], -1)
    assert np.allclose(f, ggx_numpy(wi, wo, 0.4, (1, 1, 1)) * F, rtol=5e-4, atol=1e-7)


def test_an_index_matched_conductor_reflects_nothing_and_never_below_zero():
    """eta = 1, k = 0 (a conductor matched to its medium) has Fresnel 0 at every angle; the kernel's form cancels
    two equal terms there, and rounding once left values of -1e-8 in the image (negative radiance).  Near it
    (eta = 1 +- 1e-3, k = 1e-4) the values are >= 0 and follow the complex formula."""
    rng = np.random.default_rng(5)
    wi = random_hemisphere(rng, N_DIRS, 0.01)
    wo = random_hemisphere(rng, len(wi) * 2, 0.01)[: len(wi)]
    h = wi + wo
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    cos_d = np.einsum("ij,ij->i", wi, h)
    for eta, k in ((1.0, 0.0), (1.001, 1e-4), (0.999, 0.0)):
        mats = B.build_material_table([B.MaterialSpec("m", B.GGX, alpha=0.2, specular=(1.0, 1.0, 1.0),
                                                      eta=(eta,) * 3, k=(k,) * 3)])
        f = B.eval_brdf(mats, 0, wi, wo)
        assert f.min() >= 0.0, (eta, k, f.min())
        g = ggx_numpy(wi, wo, 0.2, (1, 1, 1))[:, 0]
        keep = g > 1e-3
        fresnel = f[keep, 0] / g[keep]        # the kernel's F, against the complex formula (0 to float32 rounding)
        assert np.allclose(fresnel, fresnel_conductor_numpy(cos_d[keep], eta, k), rtol=5e-3, atol=1e-6), (eta, k)


def _kernel_and_formula_fresnel(eta: float, k: float, seed: int):
    """(min f, the kernel's conductor F read off GGX evaluations at random pairs, the complex formula's F there)."""
    rng = np.random.default_rng(seed)
    wi = random_hemisphere(rng, 200, 0.01)
    wo = random_hemisphere(rng, len(wi) * 2, 0.01)[: len(wi)]
    mats = B.build_material_table([B.MaterialSpec("m", B.GGX, alpha=0.3, specular=(1.0, 1.0, 1.0),
                                                  eta=(eta,) * 3, k=(k,) * 3)])
    f = B.eval_brdf(mats, 0, wi, wo)[:, 0]
    g = ggx_numpy(wi, wo, 0.3, (1, 1, 1))[:, 0]
    keep = g > 1e-3
    h = wi + wo
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    return f.min(), f[keep] / g[keep], fresnel_conductor_numpy(np.einsum("ij,ij->i", wi, h)[keep], eta, k)


@settings(max_examples=40, deadline=None)
@given(st.floats(0.01, 10.0), st.floats(0.0, 10.0), st.integers(0, 2**31 - 1))
def test_conductor_fresnel_lies_in_zero_one_and_follows_the_complex_formula(eta, k, seed):
    """Over eta in [0.01, 10] and k in [0, 10] (dielectric-like to silver-like), the kernel's conductor Fresnel,
    read off a GGX evaluation, lies in [0, 1] and is the complex formula's |r_s|^2 / |r_p|^2 mean."""
    f_min, fresnel, want = _kernel_and_formula_fresnel(eta, k, seed)
    assert f_min >= 0.0 and fresnel.max() <= 1.0 + 1e-3
    np.testing.assert_allclose(fresnel, want, rtol=5e-3, atol=1e-6)


def test_host_wrappers_refuse_what_read_outside_the_table_and_scale_directions_to_unit(analytic):
    """A material index outside the table read memory beyond it (m = -1 gave 0.62, m = 5 a negative value); a NaN
    direction gave inf, a zero one zero vectors; wi * 10 read 0.0116 for 0.62; seed 2**32 drew seed 0's samples."""
    from warpbw.errors import WarpbwError

    wi = np.array([[0.2, 0.1, 0.97]])
    wo = np.array([[-0.3, 0.2, 0.93]])
    for m in (-1, 3, 1.0, None):
        for call in (lambda: B.eval_brdf(analytic, m, wi, wo), lambda: B.pdf_brdf(analytic, m, wi, wo),
                     lambda: B.sample_brdf(analytic, m, wo, 4)):
            with pytest.raises(WarpbwError, match=r"m \(material index\): expected an integer"):
                call()
    np.testing.assert_allclose(B.eval_brdf(analytic, 1, wi * 10, wo), B.eval_brdf(analytic, 1, wi, wo), rtol=1e-5)
    np.testing.assert_allclose(B.pdf_brdf(analytic, 1, wi, wo * 0.1), B.pdf_brdf(analytic, 1, wi, wo), rtol=1e-5)
    for bad in (np.array([[np.nan, 0.0, 1.0]]), np.zeros((1, 3))):
        with pytest.raises(WarpbwError, match="wi: expected finite non-zero directions, 1 of 1"):
            B.eval_brdf(analytic, 1, bad, wo)
        with pytest.raises(WarpbwError, match="wo: expected finite non-zero directions"):
            B.sample_brdf(analytic, 1, bad, 4)
    with pytest.raises(WarpbwError, match="wi, wo: expected as many"):
        B.eval_brdf(analytic, 1, np.ones((3, 3)), np.ones((2, 3)))
    with pytest.raises(WarpbwError, match=r"seed: expected an integer from 0 to 4294967295"):
        B.sample_brdf(analytic, 1, wo, 4, seed=2**32)
    with pytest.raises(WarpbwError, match="n: expected an integer >= 1"):
        B.sample_brdf(analytic, 1, wo, 0)


def test_zero_below_horizon(analytic):
    wi = np.array([[0.3, 0.1, -0.2], [0.0, 0.0, 1.0]])
    wo = np.array([[0.0, 0.0, 1.0], [0.5, 0.0, -0.1]])
    for m in range(3):
        assert (B.eval_brdf(analytic, m, wi, wo) == 0).all()


# --- tabulated BRDFs: the kernel's lookups against warpbw.io's host lookups ----------------------

@pytest.fixture(scope="module")
def random_merl():
    from warpbw.io.merl import MerlBRDF

    rng = np.random.default_rng(5)
    data = rng.uniform(0.0, 2.0, size=(90, 90, 180, 3)).astype(np.float32)
    brdf = MerlBRDF(name="random", path=None, data=data)
    specs = [B.MaterialSpec("n", B.MERL, merl=data, linear=False, sampler=uniform_sampler()),
             B.MaterialSpec("l", B.MERL, merl=data, linear=True, sampler=uniform_sampler())]
    return brdf, B.build_material_table(specs)


def test_merl_kernel_lookup_matches_host_reader(random_merl):
    from warpbw.io.merl import merl_eval

    brdf, mb = random_merl
    rng = np.random.default_rng(6)
    wi = random_hemisphere(rng, N_DIRS, 0.02)
    wo = random_hemisphere(rng, len(wi) * 2, 0.02)[: len(wi)]
    near = B.eval_brdf(mb, 0, wi, wo)
    ref = merl_eval(brdf, wi, wo, interpolate=False)
    # random data: a wrong bin shows as an O(1) error; float32 angles may round into the neighbour bin
    assert np.mean(np.abs(near - ref).max(1) < 1e-5) > 0.995
    lin = B.eval_brdf(mb, 1, wi, wo)
    ref_lin = merl_eval(brdf, wi, wo, interpolate=True)
    assert np.median(np.abs(lin - ref_lin)) < 1e-4
    assert np.mean(np.abs(lin - ref_lin).max(1) < 2e-2) > 0.995


@settings(max_examples=60, deadline=None)
@given(st.floats(0.0, 1.5), st.floats(0.0, 6.28), st.floats(0.0, 1.5), st.floats(0.0, 6.28))
def test_merl_and_ggx_reciprocity(random_merl, analytic, ti, pi_, to, po):
    wi = np.array([[np.sin(ti) * np.cos(pi_), np.sin(ti) * np.sin(pi_), np.cos(ti)]])
    wo = np.array([[np.sin(to) * np.cos(po), np.sin(to) * np.sin(po), np.cos(to)]])
    _, mb = random_merl
    # The interpolated lookup is continuous, so swapping wi and wo may only move it by float32 rounding
    # of phi_d, which is ill-conditioned near the mirror direction, d(phi_d) ~ 1e-7 / theta_h rad, and where
    # wi and wo nearly coincide, d(phi_d) ~ 1e-7 / theta_d rad (the half-vector frame's components of wi are
    # then differences of nearly equal numbers; hypothesis found theta_d = 0.0033 moving it by 0.0032).
    # Random data change by O(1) per bin (180 bins over pi), so allow that times a safety factor.
    h = (wi + wo) / np.linalg.norm(wi + wo)
    theta_h = float(np.arccos(np.clip(h[0, 2], -1, 1)))
    theta_d = 0.5 * float(np.arccos(np.clip(np.sum(wi * wo), -1, 1)))
    tol = 2e-3 + 50 * 2.0 * (180 / np.pi) * 1e-7 * (1 / max(theta_h, 1e-6) + 1 / max(theta_d, 1e-6))
    a = B.eval_brdf(mb, 1, wi, wo)
    b = B.eval_brdf(mb, 1, wo, wi)
    assert np.allclose(a, b, rtol=0.0, atol=tol)
    a = B.eval_brdf(analytic, 1, wi, wo)
    b = B.eval_brdf(analytic, 1, wo, wi)
    assert np.allclose(a, b, rtol=1e-5, atol=1e-7)


def test_merl_nearest_reciprocity_on_most_pairs(random_merl):
    _, mb = random_merl
    rng = np.random.default_rng(9)
    wi = random_hemisphere(rng, N_DIRS, 0.02)
    wo = random_hemisphere(rng, len(wi) * 2, 0.02)[: len(wi)]
    a, b = B.eval_brdf(mb, 0, wi, wo), B.eval_brdf(mb, 0, wo, wi)
    assert np.mean(np.abs(a - b).max(1) < 1e-6) > 0.995


@pytest.fixture(scope="module")
def npf_materials(shared):
    from warpbw.io.npf import read_npf

    table = shared("brdf/npf.bin")
    mats = [read_npf(table, n) for n in ("gold-metallic-paint", "chrome", "pink-felt", "blue-acrylic")]
    specs = []
    for m in mats:
        curves = B.pack_npf_curves(m.rho_d, m.rho_s, m.D, m.G1, m.F)
        specs.append(B.MaterialSpec(m.name, B.NPF, npf=curves, linear=True, sampler=uniform_sampler()))
        specs.append(B.MaterialSpec(m.name, B.NPF, npf=curves, linear=False, sampler=uniform_sampler()))
    return mats, B.build_material_table(specs)


def test_npf_kernel_matches_host_formula(npf_materials):
    from warpbw.io.npf import npf_eval

    mats, mb = npf_materials
    rng = np.random.default_rng(11)
    wi = random_hemisphere(rng, N_DIRS, 0.02)
    wo = random_hemisphere(rng, len(wi) * 2, 0.02)[: len(wi)]
    # near-specular pairs too, where the narrow lobes live
    wo2 = wi * np.array([-1, -1, 1]) + rng.normal(scale=0.02, size=wi.shape)
    wo2 /= np.linalg.norm(wo2, axis=1, keepdims=True)
    wo2[:, 2] = np.abs(wo2[:, 2]) + 0.02
    wo2 /= np.linalg.norm(wo2, axis=1, keepdims=True)
    for k, mat in enumerate(mats):
        for pairs in ((wi, wo), (wi, wo2)):
            lin = B.eval_brdf(mb, 2 * k, *pairs)
            ref = npf_eval(mat, *pairs, interpolate=True)
            rel = np.abs(lin - ref) / (np.abs(ref) + 1e-6)
            # float32 kernel angles against a float64 reference: chrome's D falls 10x within a few
            # bins, so near-mirror pairs differ by a few 1e-4 relative
            assert np.median(rel) < 1e-3, mat.name
            assert np.mean(rel < 1e-2) > 0.99, mat.name
            near = B.eval_brdf(mb, 2 * k + 1, *pairs)
            ref = npf_eval(mat, *pairs, interpolate=False)
            rel = np.abs(near - ref) / (np.abs(ref) + 1e-6)
            assert np.mean(rel < 1e-3) > 0.99, mat.name
            assert (lin >= 0).all() and (near >= 0).all()


def test_npf_kernel_reciprocity(npf_materials):
    mats, mb = npf_materials
    rng = np.random.default_rng(12)
    wi = random_hemisphere(rng, N_DIRS, 0.02)
    wo = random_hemisphere(rng, len(wi) * 2, 0.02)[: len(wi)]
    for k in range(len(mats)):
        a, b = B.eval_brdf(mb, 2 * k, wi, wo), B.eval_brdf(mb, 2 * k, wo, wi)
        assert np.allclose(a, b, rtol=1e-3, atol=1e-6)


def merl_phi_d_rounding_tol(wi, wo):
    """Per pair, how far float32 rounding of phi_d may move a trilinear lookup of the random MERL table (the
    reciprocity test's bound: d(phi_d) ~ 1e-7 / theta_h and 1e-7 / theta_d rad, data O(1) per 1-degree bin)."""
    h = (wi + wo) / np.linalg.norm(wi + wo, axis=1, keepdims=True)
    theta_h = np.arccos(np.clip(h[:, 2], -1, 1))
    theta_d = 0.5 * np.arccos(np.clip(np.sum(wi * wo, axis=1), -1, 1))
    return 2e-3 + 50 * 2.0 * (180 / np.pi) * 1e-7 * (1 / np.maximum(theta_h, 1e-6) + 1 / np.maximum(theta_d, 1e-6))


def turned_pairs(turn, seed):
    """600 random pairs over the hemisphere and the rotation by ``turn`` about the normal."""
    rng = np.random.default_rng(seed)
    wi = random_hemisphere(rng, 600, 0.02)
    wo = random_hemisphere(rng, 2 * len(wi), 0.02)[: len(wi)]
    c, s_ = np.cos(turn), np.sin(turn)
    return wi, wo, np.array([[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]])


@settings(max_examples=25, deadline=None)
@given(turn=st.floats(-np.pi, np.pi), seed=st.integers(0, 2**31 - 1))
def test_turning_both_directions_about_the_normal_leaves_every_isotropic_brdf(analytic, random_merl, turn, seed):
    """Every kind the renderer evaluates is isotropic (module docstring: MERL's tables are isotropic, GGX's D is
    round): f(R wi, R wo) = f(wi, wo) for any rotation R about the normal, over the whole hemisphere.  A Rusinkiewicz
    frame taken from a fixed axis instead of the half vector's azimuth, or an anisotropic slip in D, shows as a
    change with the turn."""
    wi, wo, R = turned_pairs(turn, seed)
    for m in range(3):   # Lambert, GGX, gold conductor: closed forms, float32 rounding only
        a, b = B.eval_brdf(analytic, m, wi, wo), B.eval_brdf(analytic, m, wi @ R.T, wo @ R.T)
        np.testing.assert_allclose(b, a, rtol=1e-4, atol=1e-7, err_msg=analytic.names[m])
    _, mb = random_merl   # trilinear: continuous, moved only by phi_d's rounding
    a, b = B.eval_brdf(mb, 1, wi, wo), B.eval_brdf(mb, 1, wi @ R.T, wo @ R.T)
    assert np.all(np.abs(a - b).max(1) <= merl_phi_d_rounding_tol(wi, wo)), np.abs(a - b).max()


@settings(max_examples=15, deadline=None)
@given(turn=st.floats(-np.pi, np.pi), seed=st.integers(0, 2**31 - 1))
def test_turning_both_directions_about_the_normal_leaves_every_npf_fit(npf_materials, turn, seed):
    """NPF's curves read theta_h, theta_d, theta_i and theta_o only (module docstring), none of which a rotation
    about the normal changes: f(R wi, R wo) = f(wi, wo) for the four real fits.  The interpolated lookup to the
    reciprocity test's tolerance (chrome's D falls 10x within a few bins); the nearest one is piecewise constant, so
    float32 rounding of an angle at a bin edge may pick the neighbour bin: all but 1% of the pairs exactly."""
    wi, wo, R = turned_pairs(turn, seed)
    mats, nb = npf_materials
    for k, mat in enumerate(mats):
        a, b = B.eval_brdf(nb, 2 * k, wi, wo), B.eval_brdf(nb, 2 * k, wi @ R.T, wo @ R.T)
        np.testing.assert_allclose(b, a, rtol=1e-3, atol=1e-6, err_msg=mat.name)
        a, b = B.eval_brdf(nb, 2 * k + 1, wi, wo), B.eval_brdf(nb, 2 * k + 1, wi @ R.T, wo @ R.T)
        assert np.mean(np.all(np.isclose(b, a, rtol=1e-5, atol=1e-7), axis=1)) > 0.99, mat.name


@pytest.fixture(scope="module")
def ggx_by_alpha():
    """One white GGX material per alpha, built once (each build_material_table allocates device arrays)."""
    cache = {}

    def get(alpha):
        if alpha not in cache:
            cache[alpha] = B.build_material_table([B.MaterialSpec("g", B.GGX, alpha=alpha, specular=(1.0, 1.0, 1.0))])
        return cache[alpha]
    return get


@settings(max_examples=40, deadline=None)
@given(log_alpha=st.integers(-8, 0), log_cos_o=st.floats(-6.0, 0.0), phi_o=st.floats(0.0, 6.28),
       seed=st.integers(0, 2**31 - 1))
def test_every_ggx_sample_weighs_g1_of_its_direction(ggx_by_alpha, log_alpha, log_cos_o, phi_o, seed):
    """VNDF sampling (Heitz 2018): f cos_i / pdf = F G1(wi) for every direction drawn above the horizon, at every
    roughness from the scene's smallest alpha to 1 and every view down to 1e-6 above the horizon (G1 here in
    float64; cosines clamped at COS_EPS as the kernel documents)."""
    alpha = max(2.0 ** (log_alpha * 1.66), B.GGX_MIN_ALPHA)   # 1 ... 1e-4
    mb = ggx_by_alpha(alpha)
    cos_o = 10.0 ** log_cos_o
    s = np.sqrt(1.0 - cos_o ** 2)
    wo = np.array([np.cos(phi_o) * s, np.sin(phi_o) * s, cos_o])
    wi = B.sample_brdf(mb, 0, wo, 4096, seed=seed).astype(np.float64)
    wi = wi[wi[:, 2] > 0.0]
    p = B.pdf_brdf(mb, 0, wi, wo)
    assert (p > 0.0).all(), int((p <= 0.0).sum())
    f = B.eval_brdf(mb, 0, wi, wo)[:, 0]
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    c = wi[:, 2]
    g1 = 2.0 * c / (c + np.sqrt(alpha ** 2 + (1.0 - alpha ** 2) * c * c))
    np.testing.assert_allclose(f * c / p, g1 * c / np.maximum(c, B.COS_EPS), rtol=2e-3, atol=1e-6)


def ggx_half_vector_grid(alpha, wo, n_s=256, n_phi=128):
    """Quadrature over the half vectors h with wo . h > 0 (each reflects wo to one wi of the sphere, once):
    theta_h = atan(alpha tan s), s uniform, makes GGX's D smooth in s at every roughness.  Returns wi (K, 3) and
    d omega_i = 4 (wo . h) sin(theta_h) d theta_h d phi (the half-vector Jacobian, Walter et al. 2007)."""
    s = (np.arange(n_s) + 0.5) / n_s * np.pi / 2
    ph = (np.arange(n_phi) + 0.5) / n_phi * 2 * np.pi
    S, P = np.meshgrid(s, ph, indexing="ij")
    th = np.arctan(alpha * np.tan(S))
    dth = alpha / np.cos(S) ** 2 / (1.0 + (alpha * np.tan(S)) ** 2)
    h = np.stack([np.sin(th) * np.cos(P), np.sin(th) * np.sin(P), np.cos(th)], -1).reshape(-1, 3)
    dwh = (np.sin(th) * dth).reshape(-1) * (np.pi / 2 / n_s) * (2 * np.pi / n_phi)
    oh = h @ wo
    ok = oh > 0
    return 2 * oh[ok, None] * h[ok] - wo, 4 * oh[ok] * dwh[ok]


@settings(max_examples=30, deadline=None)
@given(log_alpha=st.integers(-8, 0), theta_o=st.floats(0.0, 1.5), phi_o=st.floats(0.0, 6.28))
def test_ggx_pdf_integrates_to_one_and_its_albedo_is_at_most_one_at_every_roughness(ggx_by_alpha, log_alpha,
                                                                                     theta_o, phi_o):
    """Over alpha from 1e-4 to 1 and every view: the VNDF pdf integrates to 1 over the sphere (Heitz 2018; at
    theta_o = 0 this is D's normalisation, int D cos_h d omega_h = 1), and a white GGX (F = 1) reflects at most what
    arrives, int f cos_i d omega_i <= 1 (energy conservation; Smith's G1 <= 1).  The quadrature's own error is
    below 1e-5 (checked against a float64 sum at 4x the cells); float32 kernels: 2e-4."""
    alpha = max(2.0 ** (log_alpha * 1.66), B.GGX_MIN_ALPHA)   # 1 ... 1e-4
    mb = ggx_by_alpha(alpha)
    wo = np.array([np.sin(theta_o) * np.cos(phi_o), np.sin(theta_o) * np.sin(phi_o), np.cos(theta_o)])
    wi, dw = ggx_half_vector_grid(alpha, wo)
    total = float(np.sum(B.pdf_brdf(mb, 0, wi, wo) * dw))
    assert abs(total - 1.0) < 2e-4, total
    albedo = np.sum(B.eval_brdf(mb, 0, wi, wo) * np.maximum(wi[:, 2], 0.0)[:, None] * dw[:, None], axis=0)
    assert np.all(albedo <= 1.0 + 2e-4) and np.all(albedo > 0.0), albedo


@pytest.mark.parametrize("c", [1e-25, 1e-30, 1e-37])
def test_npf_kernel_at_a_mirror_pair_grazing_the_horizon_matches_the_host_formula(npf_materials, c):
    # wi + wo = (0, 0, 2c) normalised to 0 below c ~ 1e-23: theta_d (90 degrees) read 0, and F with it (the red of
    # gold-metallic-paint 100 times too dark).  The host's float64 npf_eval is the truth.
    from warpbw.io.npf import npf_eval

    mats, mb = npf_materials
    wi, wo = np.array([[-1.0, 0.0, c]]), np.array([[1.0, 0.0, c]])
    for k, mat in enumerate(mats):
        np.testing.assert_allclose(B.eval_brdf(mb, 2 * k, wi, wo), npf_eval(mat, wi, wo, interpolate=True),
                                   rtol=1e-3, err_msg=mat.name)


def test_unmeasured_merl_entries_never_reach_shading(tmp_path):
    from warpbw.io.merl import read_merl, write_merl

    data = np.full((90, 90, 180, 3), 0.5, np.float64)
    data[10:20, 30:40, :, 1] = -1.0 * 1.15 / 1500   # stored as -1 after write's inverse scaling
    data[0, :, :, :] = -1.0 / 1500
    p = tmp_path / "holes.binary"
    write_merl(p, data)
    with pytest.warns(RuntimeWarning):
        brdf = read_merl(p)
    assert brdf.n_unmeasured == 10 * 10 * 180 + 90 * 180 * 3
    mb = B.build_material_table([B.MaterialSpec("h", B.MERL, merl=brdf.data, linear=True, sampler=uniform_sampler())])
    rng = np.random.default_rng(3)
    wi = random_hemisphere(rng, N_DIRS)
    wo = random_hemisphere(rng, len(wi) * 2)[: len(wi)]
    f = B.eval_brdf(mb, 0, wi, wo)
    assert (f >= 0).all() and np.isfinite(f).all()
    # the holes read as 0, everything else as written
    assert np.all(brdf.data[10:20, 30:40, :, 1] == 0) and np.all(brdf.data[0] == 0)
    rest = np.ones(brdf.data.shape, bool)
    rest[10:20, 30:40, :, 1] = False
    rest[0] = False
    assert np.allclose(brdf.data[rest], 0.5, rtol=1e-6)
    # the kernel's nearest look-up at bin centres inside the holes: green 0 in the first hole, black in the
    # theta_h row 0 (the mirror direction), red and blue untouched by the green hole
    from warpbw.io.merl import dirs_from_half_diff, merl_bin_centres

    near = B.build_material_table([B.MaterialSpec("h", B.MERL, merl=brdf.data, linear=False,
                                                  sampler=uniform_sampler())])
    th, td, pd = merl_bin_centres()
    for i_th, i_td, hole in ((15, 35, "green"), (0, 20, "row 0"), (50, 60, "none")):
        wi_c, wo_c = dirs_from_half_diff(np.full(6, th[i_th]), np.linspace(0, 2, 6), np.full(6, td[i_td]),
                                         pd[[5, 40, 80, 100, 140, 170]])
        ok = (wi_c[:, 2] > 0.05) & (wo_c[:, 2] > 0.05)
        assert ok.sum() >= 3, hole
        g = B.eval_brdf(near, 0, wi_c[ok], wo_c[ok])
        expect = {"green": [1, 0, 1], "row 0": [0, 0, 0], "none": [1, 1, 1]}[hole]
        assert np.all((g > 0) == np.array(expect, bool)), (hole, g)


@pytest.mark.parametrize("eta,k", [(1e4, 0.0), (1.0, 1e4), (1e4, 1e4), (1e3, 50.0), (0.0, 1e4)])
def test_conductor_fresnel_up_to_the_largest_index_accepted_follows_the_complex_formula(eta, k):
    """From about 5e9 the kernel's squares overflowed float32 and F read 0 (a mirror rendered black, status 0, no
    sample reported): eta and k are bounded by CONDUCTOR_INDEX_MAX, in the scene and in the table, and up to it F
    is the complex formula's (near 1)."""
    from warpbw.errors import WarpbwError
    from warpbw.scene import CONDUCTOR_INDEX_MAX, parse_scene

    assert B.CONDUCTOR_INDEX_MAX == CONDUCTOR_INDEX_MAX
    _, fresnel, want = _kernel_and_formula_fresnel(eta, k, 9)
    np.testing.assert_allclose(fresnel, want, rtol=5e-3, atol=1e-6)
    with pytest.raises(WarpbwError, match="eta: expected values up to 10000"):
        B.build_material_table([B.MaterialSpec("m", B.GGX, alpha=0.3, specular=(1.0,) * 3, eta=(5e9,) * 3,
                                               k=(0.0,) * 3)])
    text = ('[camera]\nposition = [0, 0, 3]\nlook_at = [0, 0, 0]\nresolution = [4, 4]\n[environment]\nconstant = 1.0\n'
            '[[object]]\nshape = "sphere"\ncenter = [0, 0, 0]\nradius = 1\nmaterial = "m"\n[material.m]\ntype = "ggx"\n'
            'alpha = 0.1\nspecular = [1, 1, 1]\neta = [5e9, 1, 1]\nk = [0, 0, 0]\n')
    with pytest.raises(WarpbwError, match=r"\[material.m\].eta: expected a number <= 10000"):
        parse_scene(text, ".", "s.toml")


def test_merl_trilinear_lookup_wraps_phi_d_across_0_and_pi(random_merl):
    """MERL's phi_d axis is periodic with period pi, so within half a bin of phi_d = 0 or pi the
    trilinear lookup blends the last bin (179) with the first (0).  The random-direction comparison above
    allows 0.5% of pairs to disagree, and only 1/180 of random pairs fall there.  Truth: the host reader's
    interpolation (tests/test_merl.py::test_interpolation_is_trilinear_with_phi_wrap checks its wrap by hand)."""
    from warpbw.io.merl import dirs_from_half_diff, merl_eval

    brdf, mb = random_merl
    rng = np.random.default_rng(11)
    n = 600
    bin_w = np.pi / 180.0
    th = rng.uniform(0.05, 0.6, n)
    td = rng.uniform(0.05, 0.6, n)
    off = rng.uniform(0.05, 0.45, n) * bin_w           # within the outer half of the first / last bin
    pd = np.where(np.arange(n) % 2 == 0, off, np.pi - off)
    wi, wo = dirs_from_half_diff(th, rng.uniform(0.0, 2.0 * np.pi, n), td, pd)
    keep = (wi[:, 2] > 0.05) & (wo[:, 2] > 0.05)
    assert keep.sum() > 400
    lin = B.eval_brdf(mb, 1, wi[keep], wo[keep])
    ref = merl_eval(brdf, wi[keep], wo[keep], interpolate=True)
    # float32 angles move phi_d by ~1e-7 / min(theta_h, theta_d) rad = 1e-4 bins here: 2e-4 on O(1) data
    assert np.abs(lin - ref).max() < 5e-3


def test_npf_kernel_at_normal_incidence_skips_the_placeholder_bins(npf_materials):
    """The kernel's linear NPF lookup starts at the first valid bin, not bin 0 (no test saw the difference).  G1's bin 0
    is stored as 0 and F's is a placeholder (data README), so at normal incidence the model must read bin 1;
    reading bin 0 loses the highlight of a sphere's centre.  Random pairs almost never come within
    1.5 bins (1.5 degrees) of the normal.  Truth: the README formula at wi = wo = +Z,
    rho_d + rho_s D[0] F[1] G1[1]^2 / 16 (tests/test_npf.py::test_normal_incidence_keeps_specular checks the
    host model the same way), in both lookup modes."""
    mats, mb = npf_materials
    z = np.array([[0.0, 0.0, 1.0]])
    for k, mat in enumerate(mats):
        truth = mat.rho_d + mat.rho_s * mat.D[0] * mat.F[1] * mat.G1[1] ** 2 / 16.0
        for m in (2 * k, 2 * k + 1):
            got = B.eval_brdf(mb, m, z, z)[0]
            np.testing.assert_allclose(got, truth, rtol=1e-5, err_msg=f"{mat.name} material {m}")


def test_a_measured_brdf_after_analytic_materials_reads_its_own_table():
    """Materials in a table are looked up by their own tabulated data, wherever they sit: a Lambert, a MERL table A,
    a GGX and a MERL table B; material 1 (then 3) agrees with the host MERL reader of A (then B), as
    this module's fixture (two MERL materials, sharing one table, at 0 and 1) checks for the first."""
    from warpbw.io.merl import MerlBRDF, merl_eval

    rng = np.random.default_rng(11)
    a, b = (rng.uniform(0.0, 2.0, size=(90, 90, 180, 3)).astype(np.float32) for _ in range(2))
    specs = [B.MaterialSpec("lam", B.LAMBERT, albedo=(0.2, 0.5, 0.9)),
             B.MaterialSpec("A", B.MERL, merl=a, sampler=uniform_sampler()),
             B.MaterialSpec("ggx", B.GGX, alpha=0.25, specular=(0.9, 0.6, 0.3)),
             B.MaterialSpec("B", B.MERL, merl=b, sampler=uniform_sampler())]
    mb = B.build_material_table(specs)
    wi = random_hemisphere(rng, N_DIRS, 0.02)
    wo = random_hemisphere(rng, len(wi) * 2, 0.02)[: len(wi)]
    for m, data in ((1, a), (3, b)):
        got = B.eval_brdf(mb, m, wi, wo)
        ref = merl_eval(MerlBRDF(name="t", path=None, data=data), wi, wo)
        # random tables: a wrong table is an O(1) error; float32 angles may round into the neighbour bin
        assert np.mean(np.abs(got - ref).max(1) < 1e-5) > 0.995, m


@pytest.mark.parametrize("c", [1e-18, 1e-22, 1e-23, 1e-25, 1e-30, 1e-37])
def test_ggx_mirror_pair_grazing_the_horizon_is_finite_and_follows_the_closed_form(c):
    # wi + wo = (0, 0, 2c): its squared length is subnormal below c ~ 1e-19 (f 3% off at 1e-22) and 0 below ~1e-23,
    # where the half vector came out 0 and f = D(0) G1 G1 = inf (1e-23) or inf * 0 = NaN.  Truth: h = n, so
    # D = 1 / (pi alpha^2); cosines clamped at COS_EPS as documented.
    alpha = 0.05
    mb = B.build_material_table([B.MaterialSpec("g", B.GGX, alpha=alpha, specular=(1.0, 1.0, 1.0))])
    wi, wo = np.array([[0.0, 1.0, c]]), np.array([[0.0, -1.0, c]])
    g1 = 2.0 * c / (c + np.sqrt(alpha ** 2 + (1.0 - alpha ** 2) * c * c))
    d = 1.0 / (np.pi * alpha ** 2)
    cc = max(c, B.COS_EPS)
    f = B.eval_brdf(mb, 0, wi, wo)   # G1^2 underflows float32 below c ~ 1e-21: compared to 1e-30 absolute
    np.testing.assert_allclose(f, np.full((1, 3), d * g1 * g1 / (4.0 * cc * cc)), rtol=1e-3, atol=1e-30)
    np.testing.assert_allclose(B.pdf_brdf(mb, 0, wi, wo), [g1 * d / (4.0 * cc)], rtol=1e-3, atol=1e-30)


@pytest.mark.parametrize("alpha", [1e-4, 2e-3, 0.02])
@pytest.mark.parametrize("phi_o", [1.0, 2.0])
def test_ggx_pdf_is_positive_for_every_direction_its_sampler_draws_at_grazing_views(alpha, phi_o):
    # VNDF sampling (Heitz 2018): f cos_i / pdf = F G1(wi) for every sample above the horizon.  The pdf tested the
    # rounded wo . h, which is >= 0 in exact arithmetic, and read 0 for up to 18% of the samples of a mirror
    # (alpha 1e-4) seen 2e-5 above the horizon: the renderer dropped them, a darker silhouette.
    mb = B.build_material_table([B.MaterialSpec("g", B.GGX, alpha=alpha, specular=(1.0, 1.0, 1.0))])
    for k, cos_o in enumerate([2e-5, 7e-5, 3e-4, 1e-3]):
        s = np.sqrt(1.0 - cos_o ** 2)
        wo = np.array([np.cos(phi_o) * s, np.sin(phi_o) * s, cos_o])
        wi = B.sample_brdf(mb, 0, wo, 4096, seed=k).astype(np.float64)
        wi = wi[wi[:, 2] > 0.0]
        p = B.pdf_brdf(mb, 0, wi, wo)
        f = B.eval_brdf(mb, 0, wi, wo)[:, 0]
        assert (p > 0.0).all(), (cos_o, int((p <= 0.0).sum()))
        wi /= np.linalg.norm(wi, axis=1, keepdims=True)
        c = wi[:, 2]
        g1 = 2.0 * c / (c + np.sqrt(alpha ** 2 + (1.0 - alpha ** 2) * c * c))
        np.testing.assert_allclose(f * c / p, g1 * c / np.maximum(c, B.COS_EPS), rtol=2e-3, atol=1e-6)


@pytest.mark.parametrize("c", [1e-25, 1e-30, 1e-37])
def test_merl_kernel_at_a_mirror_pair_grazing_the_horizon_reads_the_bins_of_its_angles(c):
    # wi = (c, 1, c), wo = (c, -1, c): h = (1, 0, 1) / sqrt(2), theta_h = 45 degrees, so i_th = floor(sqrt(1/2) 90)
    # = 63; wi . h = sqrt(2) c, theta_d = 90 degrees (bin 89); d = R_y(-45) wi = (0, 1, sqrt(2) c), phi_d = 90
    # degrees (bin 90).  wi + wo = (2c, 0, 2c) normalised to 0 below c ~ 1e-23 (float32's squared length
    # underflows), and the kernel read theta_h 0 (bin 0).  Each entry of the table holds its own bin (i, j, k).
    i, j, k = np.meshgrid(np.arange(90.0), np.arange(90.0), np.arange(180.0), indexing="ij")
    data = np.stack([i, j, k], axis=-1).astype(np.float32)
    mb = B.build_material_table([B.MaterialSpec("n", B.MERL, merl=data, linear=False, sampler=uniform_sampler()),
                                 B.MaterialSpec("l", B.MERL, merl=data, linear=True, sampler=uniform_sampler())])
    wi, wo = np.array([[c, 1.0, c]]), np.array([[c, -1.0, c]])
    np.testing.assert_array_equal(B.eval_brdf(mb, 0, wi, wo), [[63.0, 89.0, 90.0]])
    # trilinear between bin centres: u_h = sqrt(1/2) 90 - 1/2, u_d = 89.5 clamped to 89, u_p = 89.5
    np.testing.assert_allclose(B.eval_brdf(mb, 1, wi, wo), [[np.sqrt(0.5) * 90.0 - 0.5, 89.0, 89.5]], rtol=1e-5)


def test_check_sampling_tables_names_the_first_unsampled_tabulated_material_the_frame_shows():
    """``check_sampling_tables(mb, where, gb_material)``: a MERL or NPF material packed without its sampling table
    (``sampling=False``) is refused, the first by index, only where the G-buffer's ids (numpy or Warp; -1 empty)
    show it; an analytic material needs no table.  Truth: the materials' kinds and the ids as built here."""
    import warp as wp

    from warpbw.errors import WarpbwError

    curves = B.pack_npf_curves((0.2, 0.2, 0.2), (0.1, 0.1, 0.1), np.ones((90, 3)), np.ones((90, 3)),
                               np.ones((90, 3)))
    specs = [B.MaterialSpec("plain", B.LAMBERT, albedo=(0.5, 0.5, 0.5)),
             B.MaterialSpec("measured", B.MERL, merl=np.full((B.MERL_CELLS, 3), 0.1, np.float32)),
             B.MaterialSpec("fitted", B.NPF, npf=curves)]
    mb = B.build_material_table(specs, sampling=False)
    for ids, named in (([0, -1, 0], None), ([-1, -1], None), (np.array([[0, 2], [2, -1]], np.int32), 2),
                       ([2, 1], 1), (wp.array(np.array([0, 2], np.int32), dtype=wp.int32), 2), (None, 1)):
        if named is None:
            B.check_sampling_tables(mb, "the pass", ids)
            continue
        with pytest.raises(WarpbwError, match=rf"^the pass: materials: material {named} \('{specs[named].name}'\) "
                                              "was packed without its sampling table"):
            B.check_sampling_tables(mb, "the pass", ids)
    B.check_sampling_tables(B.build_material_table(specs[:1], sampling=False), "the pass")   # nothing to sample
    measured = B.MaterialSpec("measured", B.MERL, merl=specs[1].merl, sampler=uniform_sampler())
    packed = B.build_material_table([measured, specs[0]])
    assert packed.table.sampler.numpy()[0] == 0   # the first table's index: packed with it
    B.check_sampling_tables(packed, "the pass", [0, 1])
