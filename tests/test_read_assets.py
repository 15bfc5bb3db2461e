"""examples/read_assets.py: warpbw's asset files read with numpy alone, against the renderer's own kernels.

The script's readers are a second implementation of the layouts README's "Asset files" documents, written without
warpbw.  Where they agree with the Warp functions the renderer runs (``warpbw.bandwidth.brdf_nu_rho``,
``warpbw.sampling.tab_sample`` / ``tab_pdf``, ``warpbw.filtering.fetch_gmm`` / ``gmm_ndf``), the README says what
the renderer does, and a renderer that ports them reads the files as warpbw does.  The script's own checks are held
to closed forms: a sampling table's pdf integrates to 1 and its draws follow its cells' masses; a mixture NDF
integrates to 1 over the projected disc.
"""
from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import warp as wp

from conftest import load_example
from warpbw.bandwidth import brdf_nu_rho
from warpbw.sampling import TabulatedSamplers, tab_pdf, tab_sample

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "examples" / "read_assets.py"
ra = load_example("read_assets")


def run_script(*argv, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *map(str, argv)], cwd=cwd, stdin=subprocess.DEVNULL,
                          capture_output=True, text=True, timeout=120)


def hemisphere(rng, n: int, z_min: float = 1e-3) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2]) + z_min
    return v / np.linalg.norm(v, axis=1, keepdims=True)


# ------------------------------------------------------------------------------------------ BRDF bandwidth


@wp.kernel(module="unique", enable_backward=False)
def _nu_rho_kernel(tab: wp.array(dtype=wp.float32), wi: wp.array(dtype=wp.vec3), wo: wp.array(dtype=wp.vec3),
                   out: wp.array(dtype=wp.float32)):
    i = wp.tid()
    out[i] = brdf_nu_rho(tab, 0, wi[i], wo[i])


def test_nu_rho_look_up_is_the_renderers():
    """The table's cells hold their own index, so each look-up says which cell it read: the script's and the
    renderer's are the same cell for all but directions within float32 rounding of a cell's edge, and there a
    neighbouring one.  Views from the normal to 0.06 degrees above the horizon, light from every elevation and
    azimuth (normal incidence included, where the azimuth is undefined and both take phi_i = 0)."""
    rng = np.random.default_rng(3)
    n = 20000
    wi, wo = hemisphere(rng, n, 1e-3), hemisphere(rng, n, 1e-3)
    wi[:50] = [0.0, 0.0, 1.0]
    table = np.arange(16 ** 3, dtype=np.float32).reshape(16, 16, 16)
    out = wp.zeros(n, dtype=wp.float32)
    wp.launch(_nu_rho_kernel, dim=n, inputs=[wp.array(table.ravel(), dtype=wp.float32),
                                             wp.array(wi.astype(np.float32), dtype=wp.vec3),
                                             wp.array(wo.astype(np.float32), dtype=wp.vec3), out])
    kernel = np.array(np.unravel_index(out.numpy().astype(np.int64), table.shape)).T
    script = np.array(np.unravel_index(ra.nu_rho_at(table, wi, wo).astype(np.int64), table.shape)).T
    apart = np.abs(kernel - script).max(axis=1)
    assert apart.max() <= 1 and np.mean(apart > 0) < 1e-3, (apart.max(), np.mean(apart > 0))
    # isotropy: turning view and light together about z reads the same cell, turning the light alone does not
    # (except at normal incidence, where the light has no azimuth)
    phi = 1.1
    turn = np.array([[np.cos(phi), -np.sin(phi), 0.0], [np.sin(phi), np.cos(phi), 0.0], [0.0, 0.0, 1.0]])
    wi, wo = wi[50:], wo[50:]
    before = ra.nu_rho_at(table, wi, wo)
    assert (ra.nu_rho_at(table, wi @ turn.T, wo @ turn.T) == before).mean() > 0.999
    assert (ra.nu_rho_at(table, wi @ turn.T, wo) == before).mean() < 0.5


# ------------------------------------------------------------------------------------------ BRDF sampling tables


def _lobe_brdf(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """A diffuse floor, a lobe about the mirror direction and a brighter +y side: no symmetry a reader's swapped
    axis or flipped azimuth could hide behind."""
    mirror = wo * [-1.0, -1.0, 1.0]
    lobe = np.exp(40.0 * (np.sum(wi * mirror, -1) - 1.0))
    side = 1.0 + 0.8 * (wi[:, 1] > 0.0)
    return (0.05 + 3.0 * lobe * side)[:, None] * [1.0, 0.9, 0.8]


@pytest.fixture(scope="module")
def lobe_table():
    from warpbw.sampling import build_sampler_table

    return build_sampler_table(_lobe_brdf, n_theta_o=8, n_u=16, n_phi=32, sub=2, sub_views=2)


@wp.kernel(module="unique", enable_backward=False)
def _sample_kernel(s: TabulatedSamplers, wo: wp.array(dtype=wp.vec3), u: wp.array(dtype=wp.vec2),
                   wi: wp.array(dtype=wp.vec3), pdf: wp.array(dtype=wp.float32), probe: wp.array(dtype=wp.vec3),
                   pdf_probe: wp.array(dtype=wp.float32)):
    i = wp.tid()
    d = tab_sample(s, 0, wo[i], u[i])
    wi[i] = d
    pdf[i] = tab_pdf(s, 0, d, wo[i])
    pdf_probe[i] = tab_pdf(s, 0, probe[i], wo[i])


def test_tabulated_draws_and_pdf_are_the_renderers(lobe_table):
    """For views of every elevation and azimuth, the script's draw from the same uniforms is the renderer's direction
    (to float32's rounding), and its pdf the renderer's, at the draws and at directions over the whole sphere (below
    the surface included).  Where a uniform lies within rounding of a CDF step the two pick neighbouring cells:
    fewer than 0.2% of the draws."""
    from warpbw.sampling import pack_samplers

    rng = np.random.default_rng(5)
    n = 20000
    wo = hemisphere(rng, n, 2e-3).astype(np.float32)
    u = rng.random((n, 2)).astype(np.float32)
    probe = rng.normal(size=(n, 3))
    probe = (probe / np.linalg.norm(probe, axis=1, keepdims=True)).astype(np.float32)
    wi, pdf, pdf_probe = wp.zeros(n, dtype=wp.vec3), wp.zeros(n, dtype=wp.float32), wp.zeros(n, dtype=wp.float32)
    wp.launch(_sample_kernel, dim=n, inputs=[pack_samplers([lobe_table]), wp.array(wo, dtype=wp.vec3),
                                             wp.array(u, dtype=wp.vec2), wi, pdf,
                                             wp.array(probe, dtype=wp.vec3), pdf_probe])
    m, c, d = lobe_table.marginal, lobe_table.conditional, lobe_table.density
    got = ra.sample_wi(m, c, d, wo, u)
    off = np.linalg.norm(got - wi.numpy(), axis=1)
    assert np.mean(off > 1e-3) < 2e-3, np.mean(off > 1e-3)
    same = off <= 1e-3
    # a draw on a cell's edge (a uniform at a CDF step) may read either cell's density: a few in ten thousand
    close = np.isclose(ra.sampling_pdf(m, c, d, got, wo), pdf.numpy(), rtol=2e-3, atol=1e-6)
    assert close[same].mean() > 0.998, close[same].mean()
    p_probe = ra.sampling_pdf(m, c, d, probe, wo)
    close = np.isclose(p_probe, pdf_probe.numpy(), rtol=2e-3, atol=1e-6)
    assert close.mean() > 0.998 and (p_probe == 0).mean() > 0.3, (close.mean(), (p_probe == 0).mean())


def test_the_sampling_check_holds_a_table_to_its_closed_forms(tmp_path, lobe_table):
    """The script's check of a table warpbw wrote: the pdf integrates to 1 over the sphere (to the midpoint rule's
    rounding), and its draws over the table's cells have a chi-square per cell near 1 (for some 4,000 cells of
    at least 20 expected draws its spread is about 0.02).  A table whose density was halved in one half of its
    cells and doubled in the other (CDFs kept) fails both."""
    from precompute.assetfile import read_asset, write_asset
    from precompute.brdf_sampling import BrdfSource, write_sampling
    from warpbw.sampling import build_sampler_table

    src = BrdfSource("lobe", tmp_path / "lobe", "d0", None)
    write_sampling(tmp_path / "t.npz", build_sampler_table(_lobe_brdf), src)
    r = run_script(tmp_path / "t.npz", "--json", "--view-deg", 35, "--samples", 400000, "--seed", 2)
    assert r.returncode == 0, r.stderr
    check = json.loads(r.stdout)["check"]
    assert abs(check["pdf_integral"] - 1.0) < 1e-4 and 0.85 < check["chi2_per_cell"] < 1.15, check
    a = read_asset(tmp_path / "t.npz", "warpbw.brdf-sampling", 2, "")
    density = a.arrays["density"].copy()
    density[:, : density.shape[1] // 2] *= 0.5
    density[:, density.shape[1] // 2:] *= 2.0
    write_asset(tmp_path / "bad.npz", "warpbw.brdf-sampling", 2, "lobe", "d0", {**a.arrays, "density": density})
    bad = json.loads(run_script(tmp_path / "bad.npz", "--json", "--view-deg", 35).stdout)["check"]
    assert abs(bad["pdf_integral"] - 1.0) > 0.1 and bad["chi2_per_cell"] > 10.0, bad


# ------------------------------------------------------------------------------------------ GMM normal mipmaps


@pytest.fixture(scope="module")
def dunes_mipmap():
    from precompute.gmm_mipmap import build_gmm_mipmap
    from precompute.surfaces import SURFACES

    return build_gmm_mipmap(SURFACES["dunes"](24), components=3, progress=False)


def test_gmm_fetch_and_ndf_are_the_renderers(dunes_mipmap):
    """The trilinear fetch at texel coordinates anywhere (outside the map too: it tiles) and fractional levels from
    the finest to the 1x1 one, then the mixture NDF at directions of every slope: the script's values are the
    renderer's to float32's rounding (the recovered variance is a difference of moments, so it is compared
    against the moments' scale)."""
    from warpbw.filtering import fetch_gmm, gmm_ndf

    levels = dunes_mipmap.levels
    rng = np.random.default_rng(7)
    n = 3000
    s, t = rng.uniform(-30.0, 60.0, n), rng.uniform(-30.0, 60.0, n)
    lam = rng.uniform(0.0, len(levels) - 1, n)
    lam[:40] = np.arange(40) % len(levels)            # whole levels, the coarsest among them
    kernel = fetch_gmm(levels, s, t, lam)
    script = ra.gmm_fetch(levels, s, t, lam)
    assert np.allclose(script[..., :3], kernel[..., :3], atol=2e-5)
    assert np.allclose(script[..., 3], kernel[..., 3], atol=2e-5, rtol=1e-3)
    h = hemisphere(rng, 500, 0.05)
    for i in rng.choice(n, 8, replace=False):
        assert np.allclose(ra.gmm_ndf(kernel[i], 0.0032, h), gmm_ndf(kernel[i], 0.0032, h), rtol=1e-3, atol=1e-4)


def test_the_gmm_check_integrates_every_level_to_one(tmp_path):
    """``warpbw-precompute gmm`` then the script: at every level the mixture NDF of a roughness-0.08 material
    integrates to 1 over the projected disc (each component is a normalised Gaussian whose mean lies well inside
    the disc for the dunes' gentle slopes), and the levels halve down to 1x1 (README)."""
    from precompute.__main__ import main

    out = tmp_path / "d.gmm.npz"
    assert main(["gmm", "surface:dunes:20", "-o", str(out), "--components", "2", "--quiet"]) == 0
    r = run_script(out, "--json")
    assert r.returncode == 0, r.stderr
    levels = json.loads(r.stdout)["check"]["levels"]
    assert [lv["shape"] for lv in levels] == [[20, 20], [10, 10], [5, 5], [3, 3], [2, 2], [1, 1]]
    assert all(abs(lv["ndf_integral"] - 1.0) < 1e-3 and 1 <= lv["components_used"] <= 2 for lv in levels), levels


# ------------------------------------------------------------------------------------------ the files and the README


def test_the_bandwidth_check_reads_the_cells_the_precompute_map_names(tmp_path):
    """A table written by ``write_brdf_bandwidth``, looked up by the script for light 45 degrees from the normal:
    each value is the table's at the cell ``precompute.brdf_bandwidth.wo_to_map`` gives (its own numpy mapping),
    in the incident bin floor(45 / 90 * 16) = 8."""
    from precompute.brdf_bandwidth import wo_to_map, write_brdf_bandwidth
    from precompute.brdf_sampling import BrdfSource

    table = np.random.default_rng(0).uniform(0.1, 20.0, (16, 16, 16)).astype(np.float32)
    write_brdf_bandwidth(tmp_path / "b.npz", table, BrdfSource("m", tmp_path / "m", "d0", None))
    r = run_script(tmp_path / "b.npz", "--json", "--view-deg", 45)
    assert r.returncode == 0, r.stderr
    check = json.loads(r.stdout)["check"]
    a = np.radians(45.0)
    wo = np.array([[-np.sin(a), 0.0, np.cos(a)], [0.0, 0.0, 1.0], [0.0, np.sin(1.047), np.cos(1.047)]])
    xy = wo_to_map(wo)
    col, row = (np.floor((xy + 1.0) / 2.0 * 16).astype(int).T)
    expect = table[8, row, col]
    assert [check["mirror"], check["normal"], check["across_60_deg"]] == pytest.approx(expect.tolist(), rel=1e-6)


def test_the_readers_versions_and_the_readme_follow_the_package():
    """A format's version raised in the package (a layout changed) must be raised in the script, which refuses other
    versions, as must a constant the script copies; and README's "Asset files" must name each format, its version
    and its arrays."""
    from precompute.brdf_bandwidth import FORMAT, VERSION
    from precompute.gmm_mipmap import GMM_FORMAT, GMM_VERSION
    from warpbw.sampling import TABLE_FORMAT, TABLE_VERSION

    package = {TABLE_FORMAT: TABLE_VERSION, FORMAT: VERSION, GMM_FORMAT: GMM_VERSION}
    assert {k: v[0] for k, v in ra.FORMATS.items()} == package
    # the constants the numpy reader copies (it imports nothing of warpbw) are the package's
    import precompute.gmm_mipmap as gm
    import warpbw.filtering as wf
    import warpbw.sampling as ws
    assert (ra.COS_D_EXACT, ra.WEIGHT_EPS, ra.VARIANCE_FLOOR, ra.NORMAL_DIM) == \
        (ws.COS_D_EXACT, wf.WEIGHT_EPS, wf.VARIANCE_FLOOR, gm.NORMAL_DIM)
    readme = (ROOT / "README.md").read_text()
    section = readme.split("### Asset files", 1)[1].split("\n## ", 1)[0]
    for fmt, version in package.items():
        assert re.search(rf"`{re.escape(fmt)}`[^\n]*version {version}", section), fmt
    for array in ("marginal", "conditional", "density", "nu_rho", "level_0", "__header__"):
        assert f"`{array}`" in section, array
    assert "python examples/read_assets.py" in section
