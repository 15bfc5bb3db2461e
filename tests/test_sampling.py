"""Importance sampling: every sampler's pdf integrates to 1, its samples follow its pdf, and the
importance-sampled estimate of a pixel agrees with a uniform-sampling estimate.  examples/brdf_sampling.py with a
Lambertian stand-in: its three panels (f cos, the pdf, the density of drawn directions per steradian) by hand."""
from __future__ import annotations

import math
import sys

import numpy as np
import pytest
import warp as wp
from hypothesis import example, given, settings, strategies as st

from conftest import fake_npf_table, load_example, named_as, uniform_sampler_table
from warpbw import brdf as B
from warpbw.sampling import TabulatedSamplers, build_sampler_table, pack_samplers, tab_pdf, tab_sample

NPF_NAMES = ("chrome", "gold-metallic-paint", "pink-felt")


def half_vector_grid(wo, nu, nphi):
    """Quadrature over half vectors, sqrt-warped in theta_h (resolves narrow lobes):
    returns wi (K, 3) and the solid-angle weights d omega_i (K,), covering every wi with h.z > 0."""
    u = (np.arange(nu) + 0.5) / nu
    phi = (np.arange(nphi) + 0.5) / nphi * 2 * np.pi
    U, P = np.meshgrid(u, phi, indexing="ij")
    th = U * U * np.pi / 2
    h = np.stack([np.sin(th) * np.cos(P), np.sin(th) * np.sin(P), np.cos(th)], -1).reshape(-1, 3)
    wo_h = h @ wo
    jac = (4 * wo_h * np.sin(th).reshape(-1) * np.pi * U.reshape(-1)) / nu * (2 * np.pi / nphi)
    ok = wo_h > 0
    wi = 2 * wo_h[ok, None] * h[ok] - wo
    return wi, jac[ok], U.reshape(-1)[ok], P.reshape(-1)[ok]


@pytest.fixture(scope="module")
def materials(shared):
    from warpbw.io.npf import npf_eval, read_npf

    table = shared("brdf/npf.bin")
    specs = [B.MaterialSpec("lambert", B.LAMBERT, albedo=(0.5, 0.5, 0.5)),
             B.MaterialSpec("ggx-0.05", B.GGX, alpha=0.05, specular=(1, 1, 1)),
             B.MaterialSpec("ggx-0.4", B.GGX, alpha=0.4, specular=(1, 1, 1))]
    for name in NPF_NAMES:
        m = read_npf(table, name)
        samp = build_sampler_table(lambda wi, wo, m=m: npf_eval(m, wi, wo))
        specs.append(B.MaterialSpec(name, B.NPF, npf=B.pack_npf_curves(m.rho_d, m.rho_s, m.D, m.G1, m.F),
                                    linear=True, sampler=samp))
    return B.build_material_table(specs)


def view(theta):
    return np.array([np.sin(theta), 0.0, np.cos(theta)])


def uniform_hemisphere(rng, n):
    """n directions uniform over the upper hemisphere (pdf 1 / (2 pi)), z first, then the azimuth."""
    z = rng.uniform(0, 1, n)
    ph = rng.uniform(0, 2 * np.pi, n)
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(ph), r * np.sin(ph), z], -1)


def means_agree(a, b) -> bool:
    """The means of two independent samples agree within 3 standard errors of their difference."""
    return abs(a.mean() - b.mean()) < 3 * np.hypot(a.std() / np.sqrt(len(a)), b.std() / np.sqrt(len(b)))


@pytest.mark.parametrize("theta_o", [0.05, 0.8, 1.45])
def test_pdf_integrates_to_one(materials, theta_o):
    wo = view(theta_o)
    wi, dw, _, _ = half_vector_grid(wo, 2048, 512)
    for m, name in enumerate(materials.names):
        total = float(np.sum(B.pdf_brdf(materials, m, wi, wo) * dw))
        assert abs(total - 1.0) < 5e-3, (name, theta_o, total)


@pytest.mark.parametrize("theta_o", [0.3, 1.2])
def test_samples_follow_the_pdf(materials, theta_o):
    """Histogram of sampled half vectors in (u, phi) cells against the pdf integrated over each cell."""
    wo = view(theta_o)
    n = 200_000
    nu_c, nphi_c = 8, 16
    wi_q, dw, U, P = half_vector_grid(wo, 1024, 256)
    cell_q = np.minimum((U * nu_c).astype(int), nu_c - 1) * nphi_c + np.minimum((P / (2 * np.pi) * nphi_c).astype(int), nphi_c - 1)
    for m, name in enumerate(materials.names):
        expected = np.bincount(cell_q, weights=B.pdf_brdf(materials, m, wi_q, wo) * dw, minlength=nu_c * nphi_c) * n
        wi = B.sample_brdf(materials, m, wo, n, seed=17 + m)
        assert np.isfinite(wi).all()
        h = wi + wo
        h /= np.linalg.norm(h, axis=1, keepdims=True)
        keep = h[:, 2] > 0
        u = np.sqrt(np.arccos(np.clip(h[keep, 2], -1, 1)) / (np.pi / 2))
        phi = np.mod(np.arctan2(h[keep, 1], h[keep, 0]), 2 * np.pi)
        cell = np.minimum((u * nu_c).astype(int), nu_c - 1) * nphi_c + np.minimum((phi / (2 * np.pi) * nphi_c).astype(int), nphi_c - 1)
        observed = np.bincount(cell, minlength=nu_c * nphi_c)
        # Poisson noise (5 sigma) plus 5 samples for the quadrature: refining its grid 4x per axis moves no
        # cell's expected count by more than 0.8 samples
        dev = np.abs(observed - expected) / (5 * np.sqrt(expected) + 5)
        assert np.all(dev < 1), (name, dev.max())


@pytest.fixture(scope="module")
def studio(shared):
    from warpbw.envmap import load_envmap

    return load_envmap(shared("envmaps/studio.exr"))


@pytest.mark.parametrize("theta_o", [0.4, 1.2])
def test_importance_sampled_pixel_agrees_with_uniform_sampling(materials, studio, theta_o):
    """One shading point (normal +Y world, view at theta_o) under studio.exr: the BRDF-sampled estimate of
    002 Eq. 2 and a uniform-hemisphere estimate agree within 3 standard errors."""
    from warpbw.envmap import eval_radiance

    # local frame: t = +X, b = -Z, n = +Y (so local z maps to world +Y, the probe's up)
    def to_world(w):
        return np.stack([w[:, 0], w[:, 2], -w[:, 1]], -1)

    wo = view(theta_o)
    rng = np.random.default_rng(5)
    for m, name in enumerate(materials.names):
        if name in ("chrome", "ggx-0.05"):
            continue   # uniform sampling of a mirror-like lobe has no usable standard error
        n_is = 20_000
        wi = B.sample_brdf(materials, m, wo, n_is, seed=99 + m)
        ok = wi[:, 2] > 0
        val = np.zeros(n_is)
        f = B.eval_brdf(materials, m, wi[ok], wo)
        p = B.pdf_brdf(materials, m, wi[ok], wo)
        L = eval_radiance(studio, to_world(wi[ok]))
        val[ok] = ((f * L).mean(1) * wi[ok, 2] / p)
        wu = uniform_hemisphere(rng, 400_000)
        fu = B.eval_brdf(materials, m, wu, wo)
        Lu = eval_radiance(studio, to_world(wu))
        valu = (fu * Lu).mean(1) * wu[:, 2] * 2 * np.pi
        assert means_agree(val, valu), (name, val.mean(), valu.mean())
        # Under L = 1 the integrand is f cos_i, which BRDF sampling follows: it must beat uniform sampling
        # per sample (under the probe it need not: small bright lights dominate there; that is MIS's job).
        g_is = np.zeros(n_is)
        g_is[ok] = f.mean(1) * wi[ok, 2] / p
        g_u = fu.mean(1) * wu[:, 2] * 2 * np.pi
        assert means_agree(g_is, g_u), (name, g_is.mean(), g_u.mean())
        assert g_is.std() < 0.7 * g_u.std(), (name, g_is.std(), g_u.std())


@pytest.fixture(scope="module")
def gold_paint_merl(shared, tmp_path_factory):
    """gold-metallic-paint's NPF fit written as a MERL table (the benchmark's bunny material)."""
    from precompute.npf_to_merl import npf_to_merl
    from warpbw.io.merl import read_merl

    path = npf_to_merl(shared("brdf/npf.bin"), "gold-metallic-paint",
                       tmp_path_factory.mktemp("merl") / "gold-metallic-paint.binary")
    return read_merl(path)


@pytest.mark.parametrize("theta_o_deg", [89.0, 89.15])
def test_grazing_views_are_importance_sampled(gold_paint_merl, theta_o_deg):
    """At a view within a degree of the horizon the tabulated gold paint's f cos_i grows several-fold across
    one view-elevation bin (its albedo: 0.05 at 88.6 degrees, 0.10 at 89.15, 0.25 at 89.9).  BRDF sampling
    must still beat uniform sampling per sample there, as it does at other views.  A table built at the bin
    centre alone did not: 0.92x and 0.75x uniform sampling's standard deviation at these two views, the
    fireflies of the benchmark bunny's silhouette."""
    from warpbw.io.merl import merl_eval

    brdf = gold_paint_merl
    samp = build_sampler_table(lambda wi, wo: merl_eval(brdf, wi, wo))
    mb = B.build_material_table([B.MaterialSpec("gmp", B.MERL, merl=brdf.data, linear=False, sampler=samp)])
    wo = view(np.radians(theta_o_deg))
    n = 400_000
    wi = B.sample_brdf(mb, 0, wo, n, seed=3)
    ok = wi[:, 2] > 0
    g_is = np.zeros(n)
    g_is[ok] = B.eval_brdf(mb, 0, wi[ok], wo).mean(1) * wi[ok, 2] / B.pdf_brdf(mb, 0, wi[ok], wo)
    wu = uniform_hemisphere(np.random.default_rng(1), 2_000_000)
    g_u = B.eval_brdf(mb, 0, wu, wo).mean(1) * wu[:, 2] * 2 * np.pi
    assert means_agree(g_is, g_u), (theta_o_deg, g_is.mean(), g_u.mean())
    assert g_is.std() < 0.6 * g_u.std(), (theta_o_deg, g_is.std(), g_u.std())


def view_at(theta, azimuth):
    """The view at elevation theta whose azimuth about the normal is ``azimuth`` (``view(theta)`` at 0)."""
    return np.array([np.sin(theta) * np.cos(azimuth), np.sin(theta) * np.sin(azimuth), np.cos(theta)])


@pytest.fixture(scope="module")
def gold_paint_merl_table(gold_paint_merl):
    """The tabulated (MERL) gold paint with its sampling table, as a one-material table."""
    from warpbw.io.merl import merl_eval

    samp = build_sampler_table(lambda wi, wo: merl_eval(gold_paint_merl, wi, wo))
    return B.build_material_table([B.MaterialSpec("gold-metallic-paint (MERL)", B.MERL, merl=gold_paint_merl.data,
                                                  linear=False, sampler=samp)])


@pytest.mark.parametrize("azimuth", [1.0, 2.5])
def test_importance_sampling_is_unbiased_for_views_off_the_xz_plane(materials, gold_paint_merl_table, studio,
                                                                     azimuth):
    """The tabulated samplers measure the half vector's azimuth from the view's, which a view in the x-z plane
    (azimuth 0, every other test's) cannot tell from its negative.  With the view rotated about the normal, the
    BRDF-sampled estimates of the integral of f cos_i (L = 1) and of the pixel under studio.exr must agree with
    independent uniform-hemisphere estimates (pdf 1 / (2 pi); neither the sampler nor its pdf is used) within 3
    standard errors of their difference (``means_agree``).  Sampling at the mirrored azimuth biased the gold
    paint's L = 1 estimate by -4% at azimuth 1 (0.0270 against 0.0282, ~25 of these standard errors)."""
    from warpbw.envmap import eval_radiance

    def to_world(w):   # local frame: t = +X, b = -Z, n = +Y (as the test above)
        return np.stack([w[:, 0], w[:, 2], -w[:, 1]], -1)

    wo = view_at(0.8, azimuth)
    wu = uniform_hemisphere(np.random.default_rng(21), 2_000_000)
    Lu = eval_radiance(studio, to_world(wu))
    cases = [(materials, m, name) for m, name in enumerate(materials.names) if name not in ("chrome", "ggx-0.05")]
    cases.append((gold_paint_merl_table, 0, gold_paint_merl_table.names[0]))
    for mb, m, name in cases:   # (uniform sampling of a mirror-like lobe has no usable standard error)
        n_is = 200_000
        wi = B.sample_brdf(mb, m, wo, n_is, seed=41 + m)
        ok = wi[:, 2] > 0
        f = B.eval_brdf(mb, m, wi[ok], wo)
        p = B.pdf_brdf(mb, m, wi[ok], wo)
        g_is, val = np.zeros(n_is), np.zeros(n_is)
        g_is[ok] = f.mean(1) * wi[ok, 2] / p
        val[ok] = (f * eval_radiance(studio, to_world(wi[ok]))).mean(1) * wi[ok, 2] / p
        fu = B.eval_brdf(mb, m, wu, wo)
        g_u = fu.mean(1) * wu[:, 2] * 2 * np.pi
        valu = (fu * Lu).mean(1) * wu[:, 2] * 2 * np.pi
        assert means_agree(g_is, g_u), (name, azimuth, g_is.mean(), g_u.mean())
        assert means_agree(val, valu), (name, azimuth, val.mean(), valu.mean())


# ----------------------------------------------------------------- bad input from Python (an API audit)


def test_build_brdf_sampling_refuses_a_path_saying_what_to_pass():
    """A path gave AttributeError: 'str' object has no attribute 'name'."""
    from precompute.brdf_sampling import build_brdf_sampling
    from warpbw.errors import WarpbwError

    with pytest.raises(WarpbwError, match=r"build_brdf_sampling: source 'chrome\.binary' is a path; pass "
                                          r"brdf_source\(path, material\)"):
        build_brdf_sampling("chrome.binary", progress=False)


@pytest.mark.parametrize("link", [None, "hardlink", "symlink"])
def test_write_sampling_never_replaces_its_source(tmp_path, link):
    """``write_sampling(src.path, table, src, force=True)`` overwrote the .binary the tables were built from; a
    read-only output is refused too."""
    from precompute.brdf_sampling import BrdfSource, write_sampling
    from warpbw.errors import WarpbwError

    src = tmp_path / "m.binary"
    src.write_bytes(b"the BRDF file")
    source = BrdfSource(src.name, src, "d1", lambda wi, wo: np.ones((len(wi), 3)))
    table = uniform_sampler_table()   # of the shapes the renderer reads (the writer refuses others first)
    out = named_as(src, link, tmp_path / "t.npz")
    with pytest.raises(WarpbwError) as e:
        write_sampling(out, table, source, force=True)
    assert str(e.value).startswith(f"{out}: would overwrite {src}, the file it is made from")
    assert src.read_bytes() == b"the BRDF file"
    ro = tmp_path / "ro.npz"
    ro.write_bytes(b"keep me")
    ro.chmod(0o444)
    with pytest.raises(WarpbwError, match=r"ro\.npz: cannot be overwritten"):
        write_sampling(ro, table, source, force=True)
    assert ro.read_bytes() == b"keep me"


@pytest.fixture(scope="module")
def phong_merl():
    """A MERL table of a sharp lobe, (n + 2) / (2 pi) cos^n(theta_h) with n = 1000 at the theta_h bins' centres (MERL's
    sqrt warp): a Phong-like measured material, 0.045 rad wide, whose reflection of a grazing view grazes too."""
    from warpbw.io.merl import MerlBRDF, merl_eval

    n = 1000.0
    th = ((np.arange(B.MERL_N_TH) + 0.5) / B.MERL_N_TH) ** 2 * (np.pi / 2)
    data = np.ascontiguousarray(np.broadcast_to(((n + 2) / (2 * np.pi) * np.cos(th) ** n)[:, None, None, None],
                                                (90, 90, 180, 3)), np.float32)
    brdf = MerlBRDF(name="phong", path=None, data=data)
    samp = build_sampler_table(lambda wi, wo: merl_eval(brdf, wi, wo))
    return B.build_material_table([B.MaterialSpec("phong", B.MERL, merl=data, linear=False, sampler=samp)])


def _albedo_terms_sampled_and_uniform(mats, cos_o: float, n: int = 100_000):
    """The directional albedo's terms f cos / pdf at a view cos_o above the horizon (azimuth 1 rad), from ``n`` of
    the material's own samples (0 where a sample falls below the horizon), and f cos 2 pi from 2e6 uniform ones."""
    wo = view_at(np.arccos(cos_o), 1.0)
    wi = B.sample_brdf(mats, 0, wo, n, seed=3)
    ok = wi[:, 2] > 0
    g_is = np.zeros(n)
    g_is[ok] = B.eval_brdf(mats, 0, wi[ok], wo).mean(1) * wi[ok, 2] / B.pdf_brdf(mats, 0, wi[ok], wo)
    wu = uniform_hemisphere(np.random.default_rng(1), 2_000_000)
    return g_is, B.eval_brdf(mats, 0, wu, wo).mean(1) * wu[:, 2] * 2 * np.pi


@pytest.mark.parametrize("cos_o", [2e-5, 1e-4])
def test_a_sharp_lobe_seen_at_the_horizon_is_importance_sampled_without_fireflies(phong_merl, cos_o):
    """tab_pdf took wo . h as the rounded dot product, which at a view 1e-4 above the horizon read <= 0 for about a
    tenth of the directions tab_sample draws near the mirror direction: their pdf was the cosine share alone, and
    each weighed f pi / TAB_COSINE_MIX = 5000 where the directional albedo is 0.004 (the estimate read 1.6 and 0.8,
    200-400 times too bright: a silhouette of fireflies).  Now it agrees with uniform sampling, as at other views."""
    g_is, g_u = _albedo_terms_sampled_and_uniform(phong_merl, cos_o)
    assert means_agree(g_is, g_u), (cos_o, g_is.mean(), g_u.mean())
    assert g_is.max() < 100 * g_u.mean(), (g_is.max(), g_u.mean())


@pytest.fixture(scope="module")
def chrome_npf(shared):
    """npf.bin's chrome (the sharpest lobe of the real fits) with its sampling table."""
    from warpbw.io.npf import npf_eval, read_npf

    m = read_npf(shared("brdf/npf.bin"), "chrome")
    samp = build_sampler_table(lambda wi, wo: npf_eval(m, wi, wo))
    return B.build_material_table([B.MaterialSpec("chrome", B.NPF, npf=B.pack_npf_curves(m.rho_d, m.rho_s, m.D, m.G1,
                                                                                         m.F), linear=True,
                                                  sampler=samp)])


@pytest.mark.parametrize("cos_o", [2e-5, 1e-4])
def test_real_chrome_seen_at_the_horizon_is_importance_sampled_without_fireflies(chrome_npf, cos_o):
    """The same on real data: chrome's BRDF-sampled directional albedo at these views read about 3e7 and 3e6 (single
    weights up to 6e10) where uniform sampling reads 1.34 and 0.27."""
    g_is, g_u = _albedo_terms_sampled_and_uniform(chrome_npf, cos_o)
    assert means_agree(g_is, g_u), (cos_o, g_is.mean(), g_u.mean())


@pytest.fixture(scope="module")
def halves_merl():
    """A MERL table ten times brighter for phi_d < pi/2 than above: isotropic and reciprocal (MERL's own
    parametrisation) but not mirror-symmetric about the plane of incidence, as a measured table need not be."""
    from warpbw.io.merl import MerlBRDF, merl_eval

    data = np.full((90, 90, 180, 3), 0.2, np.float32)
    data[:, :, :90] = 2.0
    brdf = MerlBRDF(name="halves", path=None, data=data)
    samp = build_sampler_table(lambda wi, wo: merl_eval(brdf, wi, wo), n_theta_o=4, n_u=16, n_phi=32, sub=2,
                               sub_views=1)
    return B.build_material_table([B.MaterialSpec("halves", B.MERL, merl=data, linear=False, sampler=samp)])


@pytest.mark.parametrize("theta_o", [0.3, 0.9])
def test_tabulated_pdf_is_the_density_sampled_on_both_sides_of_the_plane_of_incidence(halves_merl, theta_o):
    """tab_pdf wraps the relative half-vector azimuth into [0, 2 pi) (folding it with |.| passed every test).
    Truth: for directions drawn from the sampler, E[g(wi) / pdf(wi)] is the solid angle of the region g marks,
    whatever the density, if and only if pdf is the density the sampler draws from.  With wo in the xz-plane,
    wi_y < 0 exactly when the half vector lies on the negative-azimuth side; the region {wi_y < 0, wi_z > 0.1}
    has solid angle 0.9 pi (half of the cap z > 0.1), and so has {wi_y > 0, wi_z > 0.1}.  The cosine share
    of the mixture keeps the pdf positive there, so the estimate is unbiased."""
    wo = np.array([np.sin(theta_o), 0.0, np.cos(theta_o)])
    n = 200_000
    wi = B.sample_brdf(halves_merl, 0, wo, n, seed=3)
    p = B.pdf_brdf(halves_merl, 0, wi, np.broadcast_to(wo, wi.shape))
    for side in (wi[:, 1] < 0.0, wi[:, 1] > 0.0):
        g = side & (wi[:, 2] > 0.1)
        assert np.all(p[g] > 0.0)
        x = np.where(g, 1.0 / np.where(g, p, 1.0), 0.0)
        se = x.std() / np.sqrt(n)
        assert abs(x.mean() - 0.9 * np.pi) < max(4.0 * se, 0.01 * 0.9 * np.pi), (x.mean(), se)


# --------------------------------------------------------------------------------- examples/brdf_sampling.py

def _run_brdf_sampling(monkeypatch, tmp_path, argv):
    """brdf_sampling.main with a stand-in material: f = 1/pi (Lambert), pdf = cos/pi, and a "sampler" that returns
    every projected-hemisphere cell's centre once where y > 0 and three times where y < 0, plus 100 directions
    below the horizon.  Returns the sampler's calls and the 9 panels drawn (log10 values, row by row)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.axes

    mod = load_example("brdf_sampling")
    G = mod.GRID
    x = (np.arange(G) + 0.5) / G * 2 - 1
    X, Y = np.meshgrid(x, -x)
    inside = X ** 2 + Y ** 2 < 1
    up = np.stack([X[inside], Y[inside], np.sqrt(1 - X[inside] ** 2 - Y[inside] ** 2)], -1)
    drawn = np.concatenate([up, up[up[:, 1] < 0], up[up[:, 1] < 0], np.tile([[0.6, 0.0, -0.8]], (100, 1))])
    sampled, panels = [], []

    def sample_brdf(mb, i, wo, n, seed=0):
        sampled.append((np.asarray(wo, float).copy(), n))
        return drawn.copy()

    real_imshow = matplotlib.axes.Axes.imshow

    def imshow(self, img, *a, **kw):
        panels.append(np.array(img))
        return real_imshow(self, img, *a, **kw)

    monkeypatch.setattr(mod, "build_sampler_table", lambda f: None)
    monkeypatch.setattr(mod.B, "MaterialSpec", lambda *a, **k: None)
    monkeypatch.setattr(mod.B, "pack_npf_curves", lambda *a: None)
    monkeypatch.setattr(mod.B, "build_material_table", lambda specs: "mb")
    monkeypatch.setattr(mod.B, "eval_brdf", lambda mb, i, wi, wo: np.full((len(wi), 3), 1 / math.pi))
    monkeypatch.setattr(mod.B, "pdf_brdf", lambda mb, i, wi, wo: wi[:, 2] / math.pi)
    monkeypatch.setattr(mod.B, "sample_brdf", sample_brdf)
    monkeypatch.setattr(matplotlib.axes.Axes, "imshow", imshow)
    monkeypatch.setattr(sys, "argv", ["brdf_sampling.py", "--table", str(fake_npf_table(tmp_path / "t.bin")),
                                      *argv])
    import matplotlib.pyplot as plt

    open_before = plt.get_fignums()
    mod.main()
    assert plt.get_fignums() == open_before   # its figure closed (one per call stayed open in pyplot)
    return sampled, panels, inside, X, Y


def test_brdf_sampling_panels_are_f_cos_the_pdf_and_the_sample_density_per_steradian(tmp_path, monkeypatch):
    """Module docstring: per view, f cos_i, the pdf and the histogram of drawn directions, over the projected
    hemisphere (x, y of wi), at view elevations theta_o = 0.2, 0.8, 1.3 (wo = (sin, 0, cos)).  A cell of the
    projected disk of area A holds the directions of solid angle A / cos_i, so its density per steradian is
    count / (N above the horizon) / A * cos_i; the sampler's 100 directions below the horizon do not count, and
    the top of the image is +y."""
    sampled, panels, inside, X, Y = _run_brdf_sampling(monkeypatch, tmp_path, ["--out", str(tmp_path / "o"),
                                                                               "--samples", "1000"])
    assert (tmp_path / "o" / "brdf_sampling_gold-metallic-paint.png").is_file()
    assert len(sampled) == 3 and len(panels) == 9
    for (wo, n), th in zip(sampled, (0.2, 0.8, 1.3)):
        assert n == 1000
        np.testing.assert_allclose(wo, [math.sin(th), 0.0, math.cos(th)], atol=1e-12)
    cos = np.sqrt(np.clip(1 - X ** 2 - Y ** 2, 0, None))
    cell = (2.0 / len(X)) ** 2
    n_up = int(inside.sum() + 2 * (inside & (Y < 0)).sum())
    density = np.where(Y > 0, 1.0, 3.0) / n_up / cell * cos
    for row in range(3):
        f, pdf, dens = panels[3 * row: 3 * row + 3]
        np.testing.assert_allclose(f[inside], np.log10(cos[inside] / math.pi), atol=1e-5)
        np.testing.assert_allclose(pdf[inside], np.log10(cos[inside] / math.pi), atol=1e-5)
        np.testing.assert_allclose(dens[inside], np.log10(np.maximum(density[inside], 1e-6)), atol=1e-5)


def test_brdf_sampling_defaults_and_figure_named_as_the_table_spells_the_material(tmp_path, monkeypatch):
    """--help: 400000 directions per view by default; the figure is brdf_sampling_MATERIAL.png with the material as
    the NPF table names it (read_npf ignores case and spaces: " Chrome " is chrome), as npf-to-merl echoes it."""
    sampled, _, _, _, _ = _run_brdf_sampling(monkeypatch, tmp_path, ["--out", str(tmp_path / "o"),
                                                                     "--material", " Chrome "])
    assert [n for _, n in sampled] == [400_000] * 3
    assert [p.name for p in (tmp_path / "o").iterdir()] == ["brdf_sampling_chrome.png"]


# ------------------------------------------------------------------------------------------ properties (hypothesis)
# Property-based tests of the tabulated BRDF samplers (warpbw.sampling, 002 Sec. 3.3), on tables built here from
# random synthetic BRDFs (a diffuse floor, a lobe about the mirror direction, one side of the plane of incidence
# dimmed or blacked out) and views of any elevation and azimuth.  ``tab_sample`` and ``tab_pdf`` are called
# directly from one kernel compiled once for the module, so what is checked is the sampler alone, not the cosine
# mixture of warpbw.brdf.


# small tables, so that each example builds its own in milliseconds
N_THETA_O, N_U, N_PHI, SUB = 4, 16, 32, 2


@wp.kernel(enable_backward=False)
def _sample_and_pdf(s: TabulatedSamplers, wo: wp.vec3, u: wp.array(dtype=wp.vec2),
                    wi: wp.array(dtype=wp.vec3), pdf: wp.array(dtype=wp.float32)):
    t = wp.tid()
    d = tab_sample(s, 0, wo, u[t])
    wi[t] = d
    pdf[t] = tab_pdf(s, 0, d, wo)


@wp.kernel(enable_backward=False)
def _pdf_at(s: TabulatedSamplers, wo: wp.vec3, wi: wp.array(dtype=wp.vec3), pdf: wp.array(dtype=wp.float32)):
    t = wp.tid()
    pdf[t] = tab_pdf(s, 0, wi[t], wo)


def sample(samplers, wo, n, seed):
    """n directions drawn by tab_sample for view wo (uniform random numbers from numpy), and tab_pdf at each."""
    u = np.random.default_rng(seed).random((n, 2)).astype(np.float32)
    wi = wp.empty(n, dtype=wp.vec3)
    pdf = wp.empty(n, dtype=wp.float32)
    wp.launch(_sample_and_pdf, dim=n, inputs=[samplers, wp.vec3(*wo), wp.array(u, dtype=wp.vec2), wi, pdf])
    return wi.numpy().astype(np.float64), pdf.numpy().astype(np.float64)


def pdf_at(samplers, wo, wi):
    out = wp.empty(len(wi), dtype=wp.float32)
    wp.launch(_pdf_at, dim=len(wi), inputs=[samplers, wp.vec3(*wo), wp.array(wi.astype(np.float32), dtype=wp.vec3),
                                            out])
    return out.numpy().astype(np.float64)


def synthetic_brdf(kd, ks, width, side, colour=(1.0, 1.0, 1.0)):
    """f(wi, wo) = colour (kd + ks exp(-|wi - r|^2 / width^2)), r the mirror of wo, times ``side`` where wi_y < 0
    (the table's view lies in the xz-plane, so this dims one side of the plane of incidence; 0 blacks it out)."""
    c = np.asarray(colour, np.float64)

    def f(wi, wo):
        r = wo * np.array([-1.0, -1.0, 1.0])
        g = kd + ks * np.exp(-np.sum((wi - r) ** 2, axis=1) / width ** 2)
        g = np.where(wi[:, 1] < 0.0, side * g, g)
        return g[:, None] * c[None, :]
    return f


def table_of(brdf):
    return build_sampler_table(brdf, n_theta_o=N_THETA_O, n_u=N_U, n_phi=N_PHI, sub=SUB, sub_views=1)


brdfs = st.builds(synthetic_brdf, kd=st.sampled_from([0.0, 0.05, 0.5]), ks=st.floats(0.2, 5.0),
                  width=st.floats(0.15, 0.6), side=st.sampled_from([0.0, 0.1, 1.0]))
elevations = st.floats(0.05, 1.5)
azimuths = st.floats(-math.pi, math.pi)


@settings(max_examples=30, deadline=None)
@given(brdf=brdfs, theta=elevations, azimuth=azimuths, seed=st.integers(0, 2**31 - 1))
def test_samples_are_unit_and_their_pdf_is_positive_wherever_they_land_above_the_surface(brdf, theta, azimuth, seed):
    """A direction drawn is the reflection of the unit view about a unit half vector, so it is unit; where it lands
    above the surface its half vector lies in a cell the sampler chose, whose probability is positive, so tab_pdf
    (the density the sampler draws from) is positive and finite there (samples below the horizon are allowed: a
    cell straddling it sends part of its samples there, tab_pdf's comment)."""
    s = pack_samplers([table_of(brdf)])
    wo = view_at(theta, azimuth)
    wi, pdf = sample(s, wo, 4000, seed)
    # unit length, up to float32 rounding
    np.testing.assert_allclose(np.linalg.norm(wi, axis=1), 1.0, atol=1e-5)
    up = wi[:, 2] > 0.0
    assert np.all(np.isfinite(pdf))
    assert np.all(pdf[up] > 0.0), (pdf[up].min(), np.sum(pdf[up] <= 0.0))


Z_BINS, PHI_BINS = 8, 12
NEAR_NORMAL_H = 1e-3   # sin of the half vector's angle to the normal below which its float32 azimuth is noise


def direction_bin(d):
    """A bin of 8 bands of equal z (equal solid angle) times 12 sectors of absolute azimuth."""
    zb = np.clip(((d[:, 2] + 1.0) * 0.5 * Z_BINS).astype(int), 0, Z_BINS - 1)
    pb = np.clip((np.mod(np.arctan2(d[:, 1], d[:, 0]), 2.0 * math.pi) / (2.0 * math.pi) * PHI_BINS).astype(int),
                 0, PHI_BINS - 1)
    return zb * PHI_BINS + pb


def reflected_quadrature(wo, n_u: int = 512, n_phi: int = 1024):
    """Directions w_i and their solid angles for integrating a density over the sphere, laid out by their half vector
    h with the view ``wo``: w_i = 2 (wo . h) h - wo, d omega_i = 4 (wo . h) d omega_h (the reflection's Jacobian),
    h on a grid uniform in u = sqrt(theta_h / (pi / 2)) and absolute phi_h (d omega_h = sin(theta_h) pi u du dphi),
    where wo . h > 0 (every w_i but -wo, once).  A grid uniform over the sphere undersamples a tabulated density near
    the mirror direction, which rises as theta_h^-3/2 within the table's first u cell: 768 x 1536 read 1.021 for a
    one-sided lobe of width 0.25 seen 0.73 rad from the normal, 1536 x 3072 read 1.024 for the same lobe seen 0.0625
    rad from it, and 3072 x 6144 0.997 (session 74); this grid reads 1.00000 on both."""
    u = (np.arange(n_u) + 0.5) / n_u
    theta = 0.5 * math.pi * u * u
    phi = (np.arange(n_phi) + 0.5) * 2.0 * math.pi / n_phi
    T_, P_ = np.meshgrid(theta, phi, indexing="ij")
    h = np.stack([np.sin(T_) * np.cos(P_), np.sin(T_) * np.sin(P_), np.cos(T_)], -1).reshape(-1, 3)
    d_omega_h = (np.sin(T_) * math.pi * u[:, None]).reshape(-1) * (1.0 / n_u) * (2.0 * math.pi / n_phi)
    c = h @ np.asarray(wo, np.float64)
    keep = c > 0.0
    h, c, d_omega_h = h[keep], c[keep], d_omega_h[keep]
    return 2.0 * c[:, None] * h - wo, 4.0 * c * d_omega_h


@settings(max_examples=12, deadline=None)
@given(brdf=brdfs, theta=elevations, azimuth=azimuths, seed=st.integers(0, 2**31 - 1))
@example(brdf=synthetic_brdf(0.0, 1.0, 0.1875, 0.0), theta=1.0, azimuth=1.0, seed=0)   # the quadrature's worst yet
@example(brdf=synthetic_brdf(0.0, 1.0, 0.5, 0.0), theta=1.5, azimuth=0.0, seed=0)   # 0.3% of draws wasted, one bin
@example(brdf=synthetic_brdf(0.0, 1.0, 0.25, 0.0), theta=0.732421875, azimuth=-1.0, seed=187)   # see NEAR_NORMAL_H
@example(brdf=synthetic_brdf(0.0, 1.0, 0.25, 0.0), theta=0.0625, azimuth=1.0, seed=0)   # reflected_quadrature
def test_histogram_of_samples_matches_the_pdf_integrated_over_each_bin(brdf, theta, azimuth, seed):
    """tab_pdf is the solid-angle density of tab_sample's directions: binned in world bands of z and sectors of
    absolute azimuth (a binning that knows nothing of the table's half-vector cells), the count of samples in each
    bin matches N times the integral of tab_pdf over it, computed by a fine quadrature over the sphere laid out by
    the half vector (``reflected_quadrature``); the integrals also sum to 1 less the share of draws wasted below the
    surface (the pdf is normalised over the sphere, as its comment promises).  Views off the xz-plane and one-sided
    lobes make an error in the half vector's relative azimuth (mirrored, folded, measured from the wrong axis) or in the
    change of variables (the Jacobian 4 (wo . h) sin(theta_h) pi u) show.
    A grid uniform in (z, phi), used until session 74, was off by up to 2.4% (hypothesis found the one-sided lobes of
    the examples below; ``reflected_quadrature``), and reads 1 within 1e-5 where no draw is wasted.
    Near the horizon a draw whose cell's half vector faces away from the view reflects below the surface, where
    tab_pdf reads 0 (its comment: wasted, the estimate unbiased); those draws are set apart, each checked below the
    surface, and the rest binned.  Hypothesis found 154 of them in one bin (kd 0, ks 1, width 0.5, side 0, a view
    1.5 rad from the normal; 0.31% of the draws, the pdf's mass 0.9969) when they were binned with the others."""
    s = pack_samplers([table_of(brdf)])
    wo = view_at(theta, azimuth)
    n = 60_000
    wi, pdf = sample(s, wo, n, seed)
    wasted = pdf == 0.0
    h = wi + np.asarray(wo)
    h /= np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-30)
    # a draw whose half vector is within NEAR_NORMAL_H of the normal: tab_pdf's float32 half vector loses its azimuth
    # there, and a one-sided lobe's neighbouring cell may hold 0 (1 of 60,000 draws, h 0.004 cells from the normal)
    near_normal = np.hypot(h[:, 0], h[:, 1]) < NEAR_NORMAL_H
    assert np.all((wi[wasted, 2] <= 0.0) | near_normal[wasted]), wi[wasted & (wi[:, 2] > 0.0) & ~near_normal][:5]
    assert np.sum(wasted & (wi[:, 2] > 0.0)) <= 2, np.sum(wasted & (wi[:, 2] > 0.0))
    observed = np.bincount(direction_bin(wi[~wasted]), minlength=Z_BINS * PHI_BINS)
    grid, domega = reflected_quadrature(wo)
    mass = np.bincount(direction_bin(grid), weights=pdf_at(s, wo, grid) * domega, minlength=Z_BINS * PHI_BINS)
    assert 0.98 < mass.sum() < 1.0 + 1e-4, mass.sum()
    lost = 1.0 - mass.sum()   # the mass of the draws that reflect below the surface: 5 sigma of their count, + 1e-4
    assert abs(wasted.mean() - lost) < 5.0 * math.sqrt(max(lost, 1e-6) / n) + 1e-4, (wasted.mean(), lost)
    expected = mass * n
    # Poisson noise (5 sigma), plus 0.2% of N for the quadrature of a piecewise-constant density
    dev = np.abs(observed - expected) / (5.0 * np.sqrt(expected) + 0.002 * n)
    assert np.all(dev < 1.0), (dev.max(), observed[dev.argmax()], expected[dev.argmax()])


def _rot_z(a):
    c, s_ = math.cos(a), math.sin(a)
    return np.array([[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]])


@settings(max_examples=30, deadline=None)
@given(brdf=brdfs, theta=elevations, azimuth=azimuths, turn=azimuths, seed=st.integers(0, 2**31 - 1))
def test_turning_the_view_about_the_normal_turns_its_samples_and_keeps_their_pdf(brdf, theta, azimuth, turn, seed):
    """The tables drop the view azimuth (isotropic BRDFs; module docstring: phi_h is measured from the view's
    azimuth), so for the same random numbers the samples of the view turned by an angle about the normal are the
    samples of the view, turned by that angle, and their pdf is the same (but where rounding moves a sample across
    the edge of a piecewise-constant cell)."""
    s = pack_samplers([table_of(brdf)])
    wo = view_at(theta, azimuth)
    R = _rot_z(turn)
    wi, pdf = sample(s, wo, 2000, seed)
    wi_t, pdf_t = sample(s, R @ wo, 2000, seed)
    # same random numbers: each turned sample is the sample turned (float32 trigonometry: 2e-4)
    np.testing.assert_allclose(wi_t, wi @ R.T, atol=2e-4)
    # the pdf is piecewise constant over cells: a sample within rounding of a cell's edge may read its neighbour's
    same = np.isclose(pdf_t, pdf, rtol=2e-3, atol=1e-6)
    assert same.mean() > 0.99, (same.mean(), pdf_t[~same][:5], pdf[~same][:5])


@settings(max_examples=20, deadline=None)
@given(kd=st.floats(0.0, 1.0), ks=st.floats(0.2, 5.0), width=st.floats(0.15, 0.6),
       c1=st.tuples(*[st.floats(0.05, 1.0)] * 3), c2=st.tuples(*[st.floats(0.05, 1.0)] * 3),
       scale=st.floats(1e-3, 1e3))
def test_the_tables_depend_only_on_the_luminance_of_f_up_to_scale(kd, ks, width, c1, c2, scale):
    """The importance function is Y(f) cos_i (Rec. 709 luminance; module docstring), normalised per view bin, so a
    coloured BRDF whose colour changes across the hemisphere (a diffuse floor of one colour, a lobe of another)
    gives the tables of the grey BRDF of the same luminance, and scaling f by any positive factor changes nothing.
    The CDFs rise from 0 to 1 and the density's cell shares sum to 1 in every view bin."""
    lum = np.array([0.2126, 0.7152, 0.0722])   # ITU-R BT.709 luminance weights (written here, not the module's)
    y1, y2 = float(np.dot(c1, lum)), float(np.dot(c2, lum))
    diffuse = synthetic_brdf(kd, 0.0, 1.0, 1.0)
    lobe = synthetic_brdf(0.0, ks, width, 1.0)
    coloured = table_of(lambda wi, wo: diffuse(wi, wo) * np.asarray(c1) + lobe(wi, wo) * np.asarray(c2))
    grey = table_of(lambda wi, wo: scale * (diffuse(wi, wo) * y1 + lobe(wi, wo) * y2))
    for name in ("marginal", "conditional", "density"):
        np.testing.assert_allclose(getattr(coloured, name), getattr(grey, name), rtol=2e-5, atol=1e-6, err_msg=name)
    # CDFs from 0 to 1, non-decreasing; cell shares (density du dphi) sum to 1 per bin
    assert np.all(grey.marginal[:, 0] == 0.0) and np.all(grey.marginal[:, -1] == 1.0)
    assert np.all(np.diff(grey.marginal, axis=1) >= 0.0)
    assert np.all(np.diff(grey.conditional, axis=2) >= 0.0) and np.all(grey.conditional[..., -1] == 1.0)
    shares = grey.density.astype(np.float64) * (1.0 / N_U) * (2.0 * math.pi / N_PHI)
    np.testing.assert_allclose(shares.sum(axis=(1, 2)), 1.0, rtol=1e-4)


@settings(max_examples=20, deadline=None)
@given(brdf_args=st.tuples(st.sampled_from([0.0, 0.05, 0.5]), st.floats(0.2, 5.0), st.floats(0.15, 0.6),
                           st.sampled_from([0.0, 0.1, 3.0])))
def test_the_tables_of_a_brdf_mirrored_across_the_plane_of_incidence_are_its_tables_with_phi_h_reversed(brdf_args):
    """Mirroring a BRDF across the xz-plane, f'(wi, wo) = f(M wi, M wo) with M = diag(1, -1, 1) (a MERL table with its
    phi_d axis reversed is such a mirror: phi_d -> pi - phi_d, i.e. -phi_d by reciprocity), mirrors every view's
    density: the table's views lie in the xz-plane and phi_h is measured from the view's azimuth, so cell j of phi_h
    in [0, 2 pi) becomes cell N_PHI - 1 - j, the u cells and view bins unchanged.  ``synthetic_brdf``'s ``side``
    makes f differ on the two sides of the plane (3.0: brighter where wi_y < 0); the midpoint rule's sub-cells lie
    symmetrically in each cell, so the tables agree to rounding.  (A MERL table of the 90 x 90 x 180 bins gave
    identical densities, session 69's audit.)"""
    f = synthetic_brdf(*brdf_args)
    m = np.array([1.0, -1.0, 1.0])
    t, tm = table_of(f), table_of(lambda wi, wo: f(wi * m, wo * m))
    np.testing.assert_allclose(tm.density, t.density[:, :, ::-1], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(tm.marginal, t.marginal, rtol=1e-5, atol=1e-6)
    assert not np.allclose(t.density, t.density[:, :, ::-1], rtol=1e-3)   # f itself is not mirror-symmetric


# ---------------------------------------------------------------------------------------------- directional albedo

def _phong_about_the_mirror(n: float, scale: float = 1.0):
    """The normalised Phong lobe (n + 2) / (2 pi) cos^n(alpha), alpha the angle of wi from wo's mirror direction:
    its albedo at normal incidence is exactly 1 (the integral of (n + 2) / (2 pi) cos^(n+1) theta over the
    hemisphere)."""
    def f(wi, wo):
        mirror = wo * np.array([-1.0, -1.0, 1.0])
        c = np.clip(np.sum(wi * mirror, axis=1), 0.0, None)
        return np.repeat((scale * (n + 2) / (2 * np.pi) * c ** n)[:, None], 3, axis=1)
    return f


@settings(max_examples=25, deadline=None)
@given(albedo=st.floats(0.0, 1.0), theta_deg=st.floats(0.0, 89.0))
def test_directional_albedo_of_a_lambertian_brdf_is_its_albedo(albedo, theta_deg):
    """a / pi integrated with cos_i over the hemisphere is a, at every view (closed form)."""
    from warpbw.sampling import directional_albedo

    rgb = np.array([albedo, 0.5 * albedo, 0.25])
    a = directional_albedo(lambda wi, wo: np.broadcast_to(rgb / np.pi, (len(wi), 3)), np.radians(theta_deg))
    assert a.shape == (1, 3)
    np.testing.assert_allclose(a[0], rgb, rtol=2e-3, atol=1e-9)


@pytest.mark.parametrize("n", [1.0, 100.0, 1e4, 1e5])
def test_directional_albedo_of_a_normalised_lobe_is_one_at_normal_incidence_however_sharp(n):
    """Sharp lobes (n = 1e5: 0.2 degrees wide; chrome's is about 0.5) are resolved by the sqrt-warped half-vector
    cells, one point each; a lobe of n = 1e6 needs sub=3 (1.04 with one point)."""
    from warpbw.sampling import directional_albedo

    np.testing.assert_allclose(directional_albedo(_phong_about_the_mirror(n), 0.0)[0], 1.0, rtol=2e-3)
    np.testing.assert_allclose(directional_albedo(_phong_about_the_mirror(1e6), 0.0, sub=3)[0], 1.0, rtol=2e-3)


def test_directional_albedo_of_a_sharp_lobe_at_oblique_views_is_the_cosine_of_its_mirror_direction():
    """As n grows the lobe tends to a mirror's delta times cos_i: albedo cos(theta_o) (to 1 / n)."""
    from warpbw.sampling import directional_albedo

    t = np.radians([30.0, 60.0, 80.0])
    np.testing.assert_allclose(directional_albedo(_phong_about_the_mirror(1e4), t)[:, 1], np.cos(t), rtol=2e-3)


@pytest.mark.parametrize("theta_deg", [30.0, 70.0])
def test_directional_albedo_agrees_with_a_brute_force_estimate_at_oblique_views(theta_deg):
    """Part of the lobe lies below the horizon at oblique views: no closed form, so 4 million uniform hemisphere
    samples, within four of their standard errors."""
    from warpbw.sampling import directional_albedo

    f = _phong_about_the_mirror(20.0)
    t = math.radians(theta_deg)
    wo = np.array([math.sin(t), 0.0, math.cos(t)])
    rng = np.random.default_rng(7)
    z, phi = rng.random(4_000_000), rng.random(4_000_000) * 2 * np.pi
    r = np.sqrt(1 - z * z)
    wi = np.stack([r * np.cos(phi), r * np.sin(phi), z], 1)
    g = f(wi, np.broadcast_to(wo, wi.shape))[:, 0] * z * 2 * np.pi        # pdf 1 / (2 pi)
    a = directional_albedo(f, t)[0, 0]
    assert abs(a - g.mean()) < 4 * g.std() / math.sqrt(len(g)) + 1e-3 * g.mean(), (a, g.mean())


def test_directional_albedo_reads_negative_and_nan_brdf_values_as_zero():
    """Round 11: ``directional_albedo`` integrates f cos_i with NaN, +inf and negative values read as 0 (``_rgb``'s
    docstring), as the sampling tables' importance does.  Truth: a Lambertian of 0.5 / pi in red, -0.5 / pi in green
    and NaN in blue has albedo (0.5, 0, 0) at every view, to the midpoint rule's 1e-3."""
    from warpbw.sampling import directional_albedo

    def brdf(wi, wo):
        return np.tile([0.5 / np.pi, -0.5 / np.pi, np.nan], (len(wi), 1))

    a = directional_albedo(brdf, [0.0, 0.7])
    np.testing.assert_allclose(a, [[0.5, 0.0, 0.0]] * 2, atol=1e-3)
