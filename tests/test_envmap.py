"""Tests of warpbw.envmap: orientation (Mitsuba 3 convention), sampling, pdf, clamping, MIP.

Truth comes from formulas written out here, independently of the module: Mitsuba's lat-long
mapping (u = atan2(x, -z) / 2pi, v = acos(y) / pi; column i centred at u = (i + 1/2) / W, row j
at v = j / (H - 1)), its rotate-about-+Y matrix, texel-cell solid angles, box-filter means, and,
when it is installed, Mitsuba 3 itself.
"""
from __future__ import annotations

import math
from pathlib import Path
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
import warp as wp

from conftest import shared_file
from warpbw import envmap as E
from warpbw.errors import WarpbwError

LUM = np.array([0.212671, 0.715160, 0.072169])


# ----------------------------------------------------------------------------- independent helpers


def mitsuba_dir(u, v):
    """Mitsuba 3 envmap uv_to_direction: phi = 2 pi u, theta = pi v."""
    phi = 2.0 * np.pi * np.asarray(u, dtype=np.float64)
    theta = np.pi * np.asarray(v, dtype=np.float64)
    return np.stack(np.broadcast_arrays(np.sin(phi) * np.sin(theta), np.cos(theta), -np.cos(phi) * np.sin(theta)), -1)


def texel_dir(i, j, width, height):
    return mitsuba_dir((i + 0.5) / width, j / max(height - 1, 1))


def rot_y(deg):
    """Mitsuba's Transform4f.rotate([0, 1, 0], deg) (right-handed)."""
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def cell_solid_angles(height, width):
    """(H,) solid angle of one texel cell of each row: theta edges at pi (j +- 1/2) / (H - 1)."""
    if height == 1:
        return np.full(1, 4.0 * np.pi / width)
    edges = np.clip((np.arange(height + 1) - 0.5) / (height - 1), 0.0, 1.0) * np.pi
    return (np.cos(edges[:-1]) - np.cos(edges[1:])) * 2.0 * np.pi / width


def cell_of(dirs, height, width):
    """(row, column) of the texel cell containing each direction (identity rotation)."""
    d = np.asarray(dirs, dtype=np.float64)
    u = np.mod(np.arctan2(d[:, 0], -d[:, 2]) / (2.0 * np.pi), 1.0)
    v = np.arccos(np.clip(d[:, 1] / np.linalg.norm(d, axis=1), -1.0, 1.0)) / np.pi
    col = np.clip(np.floor(u * width).astype(int), 0, width - 1)
    row = np.clip(np.floor(v * (height - 1) + 0.5).astype(int), 0, height - 1)
    return row, col


def sphere_grid(n_theta, n_phi, seed=0):
    """Jittered (theta, phi) grid over the sphere: directions and quadrature weights."""
    rng = np.random.default_rng(seed)
    th = (np.arange(n_theta)[:, None] + rng.random((n_theta, n_phi))) * (np.pi / n_theta)
    ph = (np.arange(n_phi)[None, :] + rng.random((n_theta, n_phi))) * (2.0 * np.pi / n_phi)
    d = np.stack([np.sin(th) * np.cos(ph), np.cos(th), np.sin(th) * np.sin(ph)], -1).reshape(-1, 3)
    w = (np.sin(th) * (np.pi / n_theta) * (2.0 * np.pi / n_phi)).reshape(-1)
    return d, w


def read_probe(path):
    """RGB of a lat-long EXR, read with OpenEXR directly (independent of warpbw.io)."""
    import OpenEXR

    with OpenEXR.File(str(path)) as f:
        ch = f.channels()
        if "RGB" in ch:
            return np.array(ch["RGB"].pixels, dtype=np.float32)
        return np.stack([np.array(ch[c].pixels, dtype=np.float32) for c in "RGB"], -1)


def write_probe(path, rgb):
    import OpenEXR

    hdr = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(hdr, {"RGB": np.ascontiguousarray(rgb, dtype=np.float32)}).write(str(path))


def chi_square(observed, expected, min_expected=5.0):
    keep = expected >= min_expected
    chi2 = float((((observed[keep] - expected[keep]) ** 2) / expected[keep]).sum())
    return chi2, int(keep.sum()) - 1


def synthetic_map(height=12, width=24, seed=3):
    rng = np.random.default_rng(seed)
    img = rng.gamma(0.7, 1.0, size=(height, width, 3)).astype(np.float32)
    img[2:6, 5:10] = 0.0  # a black patch: sampleable only where the bilinear footprint reaches
    img[7, 17] = (400.0, 300.0, 200.0)  # a small bright light
    img[0, 3] = 5.0  # pole rows must stay sampleable
    img[-1, 11] = 5.0
    return img


@pytest.fixture(scope="module")
def studio():
    rgb = read_probe(shared_file("envmaps/studio.exr"))
    return E.envmap_from_array(rgb, name="studio.exr")   # its 3 negative values: pyproject's named ignore


# ----------------------------------------------------------------------------- orientation


def test_single_bright_texel_is_seen_at_its_mitsuba_direction():
    h, w = 9, 16
    img = np.zeros((h, w, 3), np.float32)
    img[3, 5] = 1000.0
    env = E.envmap_from_array(img)
    d = texel_dir(5, 3, w, h)
    assert np.allclose(E.eval_radiance(env, d), 1000.0, rtol=1e-4)
    # bilinear: a quarter / half texel away in u or v gives 3/4 / 1/2 of it
    du, dv = 1.0 / w, 1.0 / (h - 1)
    probes = mitsuba_dir([5.75 * du, 6.0 * du, 5.5 * du, 5.5 * du], [3 * dv, 3 * dv, 3.25 * dv, 3.5 * dv])
    got = E.eval_radiance(env, probes)[:, 0]
    assert np.allclose(got, [750.0, 500.0, 750.0, 500.0], rtol=1e-3)
    # everything farther than one texel spacing is dark
    far = mitsuba_dir([0.0, 0.5, 5.5 * du, 7.6 * du], [0.5, 0.5, 0.0, 3 * dv])
    assert np.all(E.eval_radiance(env, far) == 0.0)


def test_axes_of_the_mapping():
    h, w = 17, 16  # row 8 is the equator
    img = np.zeros((h, w, 3), np.float32)
    img[0] = 5.0  # +Y
    img[-1] = 7.0  # -Y
    img[8, [15, 0]] = 100.0  # straddles u = 0 through the wrapped column: -Z
    img[8, [3, 4]] = 200.0  # straddles u = 0.25: +X
    img[8, [7, 8]] = 300.0  # u = 0.5: +Z
    img[8, [11, 12]] = 400.0  # u = 0.75: -X
    env = E.envmap_from_array(img)
    axes = np.array([[0, 1, 0], [0, -1, 0], [0, 0, -1], [1, 0, 0], [0, 0, 1], [-1, 0, 0]], np.float64)
    got = E.eval_radiance(env, axes)[:, 0]
    assert np.allclose(got, [5.0, 7.0, 100.0, 200.0, 300.0, 400.0], rtol=1e-5)


@settings(max_examples=10, deadline=None)
@given(scale=st.floats(1e-6, 1e6), rotation=st.floats(-360.0, 360.0), i=st.integers(0, 4 * 8 * 3 - 1))
def test_the_source_digest_names_the_map_as_given_whatever_its_scale_and_rotation(tmp_path_factory, scale, rotation,
                                                                                   i):
    """EnvMap.source_digest keys the caches of what the exposure does not change (the nu_a map): the same values at
    any scale and rotation share it, the file's and the array's alike; one value one float32 step away does not."""
    from warpbw.io.exr import write_exr

    px = np.random.default_rng(1).gamma(0.5, 1.0, size=(4, 8, 3)).astype(np.float32)
    base = E.envmap_from_array(px)
    assert base.source_digest and E.envmap_from_array(px, rotation, scale).source_digest == base.source_digest
    nudged = px.copy()
    nudged.reshape(-1)[i] = np.nextafter(nudged.reshape(-1)[i], np.float32(np.inf))
    assert E.envmap_from_array(nudged, rotation, scale).source_digest != base.source_digest
    path = tmp_path_factory.mktemp("digest") / "p.exr"
    write_exr(path, px)
    assert E.load_envmap(path, rotation, scale).source_digest == base.source_digest


def test_rotation_about_y_moves_the_light_like_mitsuba():
    h, w = 9, 16
    img = np.zeros((h, w, 3), np.float32)
    img[3, 5] = 1000.0
    img[4, 0] = img[4, -1] = 50.0  # equator around local -Z
    d_local = texel_dir(5, 3, w, h)
    env90 = E.envmap_from_array(img, rotation_deg=90.0)
    assert np.allclose(E.eval_radiance(env90, rot_y(90.0) @ d_local), 1000.0, rtol=1e-4)
    assert np.all(E.eval_radiance(env90, d_local) == 0.0)
    # local -Z (u = 0) appears at world -X after +90 degrees about +Y
    assert np.allclose(E.eval_radiance(env90, [-1.0, 0.0, 0.0]), 50.0, rtol=1e-5)
    assert np.all(E.eval_radiance(env90, [0.0, 0.0, -1.0]) == 0.0)
    env_m30 = E.envmap_from_array(img, rotation_deg=-30.0)
    assert np.allclose(E.eval_radiance(env_m30, rot_y(-30.0) @ d_local), 1000.0, rtol=1e-4)
    # sampling follows the rotation: the bright texel's cell carries the same pdf
    env0 = E.envmap_from_array(img)
    assert np.isclose(E.eval_pdf(env90, rot_y(90.0) @ d_local)[0], E.eval_pdf(env0, d_local)[0], rtol=1e-6)


def test_agrees_with_mitsuba_scalar_rgb():
    mi = pytest.importorskip("mitsuba", reason="mitsuba (optional extra) is not installed")
    mi.set_variant("scalar_rgb")
    rng = np.random.default_rng(7)
    img = rng.gamma(0.8, 1.0, size=(7, 12, 3)).astype(np.float32)
    dirs = rng.normal(size=(300, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    dirs[:4] = [[0, 0, -1], [1, 0, 0], [0, 0, 1], [-1, 0, 0]]
    for angle in (0.0, 37.0):
        em = mi.load_dict(
            {"type": "envmap", "bitmap": mi.Bitmap(img), "to_world": mi.ScalarTransform4f().rotate([0, 1, 0], angle)}
        )
        ref = []
        for d in dirs:
            si = mi.SurfaceInteraction3f()
            si.wi = mi.Vector3f(*(-d))
            ref.append(np.array(em.eval(si)))
        ours = E.eval_radiance(E.envmap_from_array(img, rotation_deg=angle), dirs)
        assert np.allclose(ours, np.array(ref), rtol=2e-4, atol=1e-5)


# ----------------------------------------------------------------------------- pdf and sampling


def _pdf_sum_over_cells(env, height, width):
    rows, cols = np.mgrid[0:height, 0:width]
    # a point inside each cell: the texel centre, except on the pole rows (half cells) where
    # the centre is the pole itself and belongs to no column in particular
    v = np.clip(rows.ravel(), 0.25, height - 1.25) / (height - 1)
    d = mitsuba_dir((cols.ravel() + 0.5) / width, v)
    pdf = E.eval_pdf(env, d).reshape(height, width).astype(np.float64)
    return pdf, float((pdf * cell_solid_angles(height, width)[:, None]).sum())


def test_pdf_integrates_to_one_synthetic():
    img = synthetic_map()
    env = E.envmap_from_array(img, rotation_deg=23.0)
    d, wq = sphere_grid(600, 1200)
    total = float((E.eval_pdf(env, d) * wq).sum())
    assert total == pytest.approx(1.0, rel=5e-3)
    env0 = E.envmap_from_array(img)
    pdf, s = _pdf_sum_over_cells(env0, *img.shape[:2])
    assert s == pytest.approx(1.0, rel=1e-5)
    assert np.all(pdf[0] > 0) and np.all(pdf[-1] > 0)  # pole rows sampleable
    # the black patch's inner cells (all 3x3 neighbours black) have pdf 0, its rim does not
    assert pdf[3:5, 6:9].max() == 0.0
    assert np.all(pdf[2, 5:10] > 0) and np.all(pdf[5, 5:10] > 0) and pdf[3, 5] > 0 and pdf[4, 9] > 0
    assert np.all(pdf[img.max(axis=2) > 0] > 0)


def _bilinear_cell_averages(lum, sub=32):
    """Brute force: each texel cell's mean (over u and v, midpoint rule on sub x sub points, exact for the
    interpolant, whose kinks at the texel centres fall on the sub-cells' edges) of the bilinear interpolant
    of ``lum``: texel centres at u = (i + 1/2) / W (periodic), v = j / (H - 1) (clamped)."""
    h, w = lum.shape
    t = (np.arange(sub) + 0.5) / sub
    out = np.zeros((h, w))
    for j in range(h):
        v0, v1 = max(j - 0.5, 0.0), min(j + 0.5, h - 1.0)        # the cell in row units (half at the poles)
        y = v0 + (v1 - v0) * t
        for i in range(w):
            x = i - 0.5 + t                   # u W - 1/2 over the cell: texel-centre units, i at its middle
            i0, fx = np.floor(x).astype(int), x - np.floor(x)
            j0 = np.minimum(np.floor(y).astype(int), h - 2)
            fy = y - j0
            a, b = lum[j0][:, i0 % w], lum[j0][:, (i0 + 1) % w]
            c, d = lum[j0 + 1][:, i0 % w], lum[j0 + 1][:, (i0 + 1) % w]
            f = ((1 - fy)[:, None] * ((1 - fx) * a + fx * b) + fy[:, None] * ((1 - fx) * c + fx * d))
            out[j, i] = f.mean()
    return out


def test_cell_probabilities_are_luminance_times_solid_angle():
    """Each cell's probability, computed here from the docstring's definition: Rec. 709 luminance of the
    bilinear interpolant averaged over the cell (brute force), times the cell's solid angle, normalised.
    Isolated pure red, green and blue texels on a dim floor tell the channel weights apart."""
    h, w = 7, 12
    img = np.full((h, w, 3), 0.01, np.float32)
    img[2, 2] = (1.0, 0.0, 0.0)
    img[2, 7] = (0.0, 1.0, 0.0)
    img[4, 4] = (0.0, 0.0, 1.0)
    img[0, 9] = (0.0, 3.0, 0.0)                                     # and one on a pole row
    lum = img.astype(np.float64) @ np.array([0.212671, 0.715160, 0.072169])   # Y of the sRGB / Rec. 709 primaries
    mass = _bilinear_cell_averages(lum) * cell_solid_angles(h, w)[:, None]
    expected = mass / mass.sum()
    pdf, total = _pdf_sum_over_cells(E.envmap_from_array(img), h, w)
    got = pdf * cell_solid_angles(h, w)[:, None]
    assert total == pytest.approx(1.0, rel=1e-5)
    np.testing.assert_allclose(got, expected, rtol=1e-5, atol=2e-7)     # float32 CDFs
    assert got[2, 7] / got[4, 4] == pytest.approx(expected[2, 7] / expected[4, 4], rel=1e-4)
    assert got[2, 7] / got[4, 4] > 5.0                              # green weighs ~10x blue, not equally


@settings(max_examples=25, deadline=None)
@given(h=st.integers(2, 8), w=st.integers(1, 10), dark=st.floats(0.0, 0.9), angle=st.floats(-180.0, 180.0),
       seed=st.integers(0, 2**16))
def test_any_maps_cell_probabilities_and_its_turned_pdf_follow_the_definition(h, w, dark, angle, seed):
    """For any map (sizes down to one column, black patches): each cell's probability is the Rec. 709 luminance of
    the bilinear interpolant averaged over the cell times its solid angle, normalised (brute force), so the pdf
    integrates to 1; turning the map about +Y turns its pdf (pdf_R(R d) = pdf(d)) and its samples (counted per cell,
    5 sigma of Poisson noise); a sample's pdf is the pdf at its direction, positive.  (A cell edge moved by float32
    rounding may put a direction in its neighbour: 1%.)"""
    rng = np.random.default_rng(seed)
    img = (rng.gamma(0.7, 1.0, size=(h, w, 3)) * (rng.random((h, w, 1)) >= dark)).astype(np.float32)
    lum = img.astype(np.float64) @ LUM
    mass = _bilinear_cell_averages(lum) * cell_solid_angles(h, w)[:, None]
    if mass.sum() == 0.0:   # all black: the documented fallback is uniform over the sphere
        mass = np.broadcast_to(cell_solid_angles(h, w)[:, None], (h, w))
    env = E.envmap_from_array(img)
    pdf, total = _pdf_sum_over_cells(env, h, w)
    assert total == pytest.approx(1.0, rel=1e-5)
    np.testing.assert_allclose(pdf * cell_solid_angles(h, w)[:, None], mass / mass.sum(), rtol=1e-4, atol=2e-7)
    d, _ = sphere_grid(40, 80, seed=seed)
    turned = E.envmap_from_array(img, rotation_deg=angle)
    same = np.isclose(E.eval_pdf(turned, d @ rot_y(angle).T), E.eval_pdf(env, d), rtol=1e-4, atol=1e-7)
    assert same.mean() > 0.99, same.mean()
    n = 20_000
    dirs, pdf_s = E.sample_directions(turned, n, seed=seed)
    assert np.all(pdf_s > 0.0)
    assert np.isclose(E.eval_pdf(turned, dirs), pdf_s, rtol=1e-4).mean() > 0.99
    # the turned map's samples, turned back, fall in the map's cells as often as its cell probabilities say
    rows, cols = cell_of(dirs @ rot_y(angle), h, w)
    observed = np.bincount(rows * w + cols, minlength=h * w)
    expected = n * (mass / mass.sum()).ravel()
    assert observed[expected == 0.0].sum() == 0
    assert np.all(np.abs(observed - expected) < 5.0 * np.sqrt(expected) + 0.002 * n), np.abs(observed - expected).max()


def test_pdf_integrates_to_one_studio(studio):
    d, wq = sphere_grid(1024, 2048, seed=1)
    total = float((E.eval_pdf(studio, d) * wq).sum())
    assert total == pytest.approx(1.0, rel=1e-2)
    _, s = _pdf_sum_over_cells(studio, studio.height, studio.width)
    assert s == pytest.approx(1.0, rel=1e-4)


def test_sample_histogram_matches_pdf_synthetic():
    img = synthetic_map()
    h, w = img.shape[:2]
    env = E.envmap_from_array(img)
    n = 400_000
    dirs, pdf_s = E.sample_directions(env, n, seed=11)
    assert np.allclose(np.linalg.norm(dirs, axis=1), 1.0, atol=1e-5)
    assert np.all(pdf_s > 0) and np.all(np.isfinite(pdf_s))
    rows, cols = cell_of(dirs, h, w)
    observed = np.bincount(rows * w + cols, minlength=h * w).astype(np.float64)
    pdf_cells, _ = _pdf_sum_over_cells(env, h, w)
    expected = n * (pdf_cells * cell_solid_angles(h, w)[:, None]).ravel()
    assert observed[expected == 0].sum() == 0
    chi2, dof = chi_square(observed, expected)
    assert chi2 < dof + 5.0 * math.sqrt(2.0 * dof), (chi2, dof)
    # the pdf returned with a sample is the pdf of the cell the test finds it in
    assert np.allclose(pdf_s, pdf_cells[rows, cols], rtol=1e-6)


def test_sample_histogram_matches_pdf_studio(studio):
    h, w = studio.height, studio.width
    n = 1_000_000
    dirs, _ = E.sample_directions(studio, n, seed=5)
    rows, cols = cell_of(dirs, h, w)
    b = 16  # 16 x 16 texel bins -> 32 x 64
    observed = np.bincount((rows // b) * (w // b) + cols // b, minlength=(h // b) * (w // b)).astype(np.float64)
    pdf_cells, _ = _pdf_sum_over_cells(studio, h, w)
    mass = pdf_cells * cell_solid_angles(h, w)[:, None]
    expected = n * mass.reshape(h // b, b, w // b, b).sum(axis=(1, 3)).ravel()
    chi2, dof = chi_square(observed, expected)
    assert chi2 < dof + 5.0 * math.sqrt(2.0 * dof), (chi2, dof)


def _texel_integral(pixels):
    h, w = pixels.shape[:2]
    return (pixels.astype(np.float64) * cell_solid_angles(h, w)[:, None, None]).sum(axis=(0, 1))


@pytest.mark.parametrize("which", ["synthetic", "studio"])
def test_importance_sampled_integral_matches_texel_sum(which, request):
    if which == "studio":
        env = request.getfixturevalue("studio")
        rel = 3e-3
    else:
        env = E.envmap_from_array(synthetic_map(48, 96), rotation_deg=-71.0)
        rel = 5e-3  # bilinear interpolant vs piecewise-constant texel sum, plus MC noise
    n = 400_000
    dirs, pdf = E.sample_directions(env, n, seed=2)
    est = (E.eval_radiance(env, dirs).astype(np.float64) / pdf[:, None]).mean(axis=0)
    assert np.allclose(est, _texel_integral(env.pixels), rtol=rel)
    # and against a brute-force quadrature of the same bilinear radiance (tight: no texel model)
    d, wq = sphere_grid(768, 1536, seed=4)
    quad = (E.eval_radiance(env, d).astype(np.float64) * wq[:, None]).sum(axis=0)
    assert np.allclose(est, quad, rtol=5e-3)


def test_constant_map_is_exact_and_uniform():
    rgb = (0.25, 1.5, 3.0)
    env = E.constant_envmap(rgb)
    rng = np.random.default_rng(0)
    d = rng.normal(size=(20_000, 3))
    d = np.concatenate([d, [[0, 1, 0], [0, -1, 0], [0, 0, -1], [0, 0, -1e-9], [1e-7, 0, -1]]])
    assert np.all(E.eval_radiance(env, d) == np.float32(rgb))
    assert np.all(E.eval_radiance_lod(env, d, 2.3) == np.float32(rgb))
    assert np.allclose(E.eval_pdf(env, d), 1.0 / (4.0 * np.pi), rtol=1e-5)
    dirs, pdf = E.sample_directions(env, 200_000, seed=9)
    assert np.allclose(pdf, 1.0 / (4.0 * np.pi), rtol=1e-5)
    # uniform on the sphere: y uniform on [-1, 1] (Archimedes), mean direction ~ 0
    hist, _ = np.histogram(dirs[:, 1], bins=20, range=(-1, 1))
    chi2, dof = chi_square(hist.astype(float), np.full(20, len(dirs) / 20.0))
    assert chi2 < dof + 5.0 * math.sqrt(2.0 * dof)
    assert np.all(np.abs(dirs.mean(axis=0)) < 0.01)
    with pytest.raises(WarpbwError):
        E.constant_envmap((1.0, -1.0, 0.0))


def test_all_black_map_falls_back_to_uniform_sphere():
    env = E.envmap_from_array(np.zeros((8, 16, 3), np.float32))
    dirs, pdf = E.sample_directions(env, 100_000, seed=1)
    assert np.allclose(pdf, 1.0 / (4.0 * np.pi), rtol=1e-5)
    assert np.all(np.abs(dirs.mean(axis=0)) < 0.015)
    assert np.all(E.eval_radiance(env, dirs) == 0.0)


# ----------------------------------------------------------------------------- bad pixels


def test_negative_and_nonfinite_pixels_are_clamped_with_one_warning():
    img = np.ones((6, 10, 3), np.float32)
    img[0, 0, 0] = -0.004
    img[1, 2, 1] = -3.0
    img[2, 3] = np.nan  # three channel values
    img[4, 9, 2] = np.inf
    img[5, 5, 0] = -np.inf
    with pytest.warns(RuntimeWarning) as record:
        env = E.envmap_from_array(img, name="bad")
    assert len(record) == 1
    msg = str(record[0].message)
    assert "7 channel values" in msg and "5 pixels" in msg and "2 negative" in msg and "5 NaN or infinite" in msg
    assert env.n_clamped == 7
    assert np.all(np.isfinite(env.pixels)) and env.pixels.min() == 0.0
    assert env.pixels[2, 3].tolist() == [0.0, 0.0, 0.0]
    dirs, pdf = E.sample_directions(env, 10_000, seed=0)
    assert np.all(np.isfinite(E.eval_radiance(env, dirs))) and np.all(np.isfinite(pdf)) and np.all(pdf > 0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert E.envmap_from_array(np.ones((4, 8, 3))).n_clamped == 0



@pytest.mark.parametrize("block", [7, 20, 1 << 20])
@pytest.mark.parametrize("dtype", [np.float16, np.float32, np.float64, np.int64])
def test_a_probe_is_scaled_and_cleaned_block_by_block_as_it_would_be_whole(monkeypatch, block, dtype):
    """The probe is converted, scaled and cleaned a few rows at a time (``SANITIZE_BLOCK_TEXELS``; here blocks of
    one row and of two, over bad values in several of them): the pixels are those of numpy on the whole map
    (float64 times the scale, to float32, negative and non-finite values to 0) bit for bit, the one warning
    counts every block's, and an overflow in a later block than the first is counted with the others."""
    monkeypatch.setattr(E, "SANITIZE_BLOCK_TEXELS", block)
    rng = np.random.default_rng(3)
    img = (rng.random((9, 10, 3)) * 7.0 - 1.0).astype(dtype)
    if np.dtype(dtype).kind == "i":
        img = rng.integers(-3, 7, (9, 10, 3)).astype(dtype)
    else:
        img[4, 2, 1], img[8, 9, 2] = np.nan, -np.inf
    a = img.astype(np.float64)
    with np.errstate(invalid="ignore"):
        want = (a * 0.37).astype(np.float32)
    bad = ~np.isfinite(want) | (want < 0)
    want[bad] = 0.0
    with pytest.warns(RuntimeWarning) as record:
        env = E.envmap_from_array(img, scale=0.37, name="blocks")
    assert len(record) == 1 and env.n_clamped == int(bad.sum()) > 2
    assert f"in {int(bad.any(axis=2).sum())} pixels" in str(record[0].message)
    assert env.pixels.dtype == np.float32 and env.pixels.flags["C_CONTIGUOUS"]
    assert np.array_equal(env.pixels.view(np.uint32), want.view(np.uint32))
    big = np.ones((9, 10, 3))
    big[2, 0, 0], big[7, 5, 1] = 1e30, 3e38
    with pytest.raises(WarpbwError, match=r"'blocks': 2 channel values \(up to 3e\+38\) times scale = 1e\+10 exceed"):
        E.envmap_from_array(big, scale=1e10, name="blocks")


def test_the_clamping_warning_points_at_the_callers_line(tmp_path):
    """The one warning of a map with bad values names the line that loaded it (load_envmap, envmap_from_array),
    not a line inside warpbw: a user's script sees where its probe came in."""
    from warpbw.io.exr import write_exr

    img = np.ones((4, 8, 3), np.float32)
    img[1, 1, 1] = -2.0
    write_exr(tmp_path / "neg.exr", img)
    for load in (lambda: E.load_envmap(tmp_path / "neg.exr"), lambda: E.envmap_from_array(img, name="neg")):
        with pytest.warns(RuntimeWarning, match="set 1 channel values to 0") as record:
            load()
        assert [Path(r.filename).name for r in record] == [Path(__file__).name]

def test_bad_arguments_raise_warpbw_error():
    with pytest.raises(WarpbwError, match=r"\(H, W, 3\)"):
        E.envmap_from_array(np.ones((4, 8)))
    with pytest.raises(WarpbwError, match="scale"):
        E.envmap_from_array(np.ones((4, 8, 3)), scale=-1.0)
    with pytest.raises(WarpbwError, match="rotation_deg"):
        E.envmap_from_array(np.ones((4, 8, 3)), rotation_deg=float("nan"))
    with pytest.raises(WarpbwError, match="numeric"):
        E.envmap_from_array([["a"]])


def test_city_sun_stays_finite():
    rgb = read_probe(shared_file("envmaps/city.exr"))
    with pytest.warns(RuntimeWarning, match="negative"):
        env = E.envmap_from_array(rgb, name="city.exr")
    assert np.all(np.isfinite(env.pixels)) and env.pixels.min() >= 0.0
    lum = env.pixels @ LUM
    j, i = np.unravel_index(np.argmax(lum), lum.shape)
    assert lum[j, i] > 20_000
    sun = texel_dir(i, j, env.width, env.height)
    p_sun = float(E.eval_pdf(env, sun)[0])
    assert np.isfinite(p_sun) and p_sun > 0
    assert E.eval_radiance(env, sun)[0] @ LUM == pytest.approx(lum[j, i], rel=1e-4)
    # the sun cell gets far more than a uniform share of samples
    assert p_sun > 100.0 / (4.0 * np.pi)
    dirs, pdf = E.sample_directions(env, 200_000, seed=3)
    ratio = E.eval_radiance(env, dirs) / pdf[:, None]
    assert np.all(np.isfinite(pdf)) and np.all(pdf > 0) and np.all(np.isfinite(ratio))
    est = ratio.astype(np.float64).mean(axis=0)
    assert np.allclose(est, _texel_integral(env.pixels), rtol=5e-3)
    # bounded estimator: no direction gets radiance far beyond what its pdf expects
    assert (ratio @ LUM).max() < 50.0 * (est @ LUM)


# ----------------------------------------------------------------------------- MIP pyramid


@settings(max_examples=40, deadline=None)
@given(h=st.integers(1, 23), w=st.integers(1, 23), seed=st.integers(0, 2**16))
def test_mip_levels_preserve_the_mean(h, w, seed):
    img = np.random.default_rng(seed).random((h, w, 3)).astype(np.float32)
    levels = E.build_mip_levels(img)
    assert levels[0].shape == (h, w, 3) and levels[-1].shape == (1, 1, 3)
    mean0 = img.astype(np.float64).mean(axis=(0, 1))
    for a, b in zip(levels[:-1], levels[1:]):
        assert b.shape[:2] == (max(1, a.shape[0] // 2), max(1, a.shape[1] // 2))
        assert np.allclose(b.astype(np.float64).mean(axis=(0, 1)), mean0, rtol=1e-5)
        assert b.min() >= img.min() - 1e-6 and b.max() <= img.max() + 1e-6


def test_mip_box_filter_and_trilinear_lookup():
    rng = np.random.default_rng(4)
    coarse = rng.random((5, 8, 3)).astype(np.float32)
    img = np.repeat(np.repeat(coarse, 2, axis=0), 2, axis=1)  # 10 x 16, 2x2 blocks
    env = E.envmap_from_array(img)
    assert np.array_equal(env.mip_levels[1], coarse)
    # odd 5 rows -> 2 rows: rows (0, 1, half of 2) and (half of 2, 3, 4), width 8 -> 4 pairs
    l2 = env.mip_levels[2]
    pairs = 0.5 * (coarse[:, 0::2] + coarse[:, 1::2])
    expect = np.stack([(pairs[0] + pairs[1] + 0.5 * pairs[2]) / 2.5, (0.5 * pairs[2] + pairs[3] + pairs[4]) / 2.5])
    assert np.allclose(l2, expect, rtol=1e-6)
    d = rng.normal(size=(500, 3))
    lod0 = E.eval_radiance_lod(env, d, 0.0)
    assert np.allclose(lod0, E.eval_radiance(env, d), rtol=1e-6, atol=1e-7)
    # level 1 with the lookup convention written out here: column k at u = (k + 1/2) / 8, row k at the centre of the
    # level-0 rows 2k and 2k + 1, v = (2k + 1/2) / 9, clamped to rows 0 and 4 beyond them
    lod1 = E.eval_radiance_lod(env, d, 1.0)
    dn = d / np.linalg.norm(d, axis=1, keepdims=True)
    x = np.mod(np.arctan2(dn[:, 0], -dn[:, 2]) / (2 * np.pi) * 8 - 0.5, 8)
    y = np.clip((np.arccos(np.clip(dn[:, 1], -1, 1)) / np.pi * 9 - 0.5) / 2, 0, 4)
    x0, y0 = np.floor(x).astype(int), np.minimum(np.floor(y).astype(int), 3)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x1 = (x0 + 1) % 8
    expect1 = ((coarse[y0, x0] * (1 - fx) + coarse[y0, x1] * fx) * (1 - fy)
               + (coarse[y0 + 1, x0] * (1 - fx) + coarse[y0 + 1, x1] * fx) * fy)
    assert np.allclose(lod1, expect1, rtol=1e-4, atol=1e-5)
    half = E.eval_radiance_lod(env, d, 0.5)
    assert np.allclose(half, 0.5 * (lod0 + lod1), rtol=1e-5, atol=1e-6)
    top = E.eval_radiance_lod(env, d, 99.0)
    assert np.allclose(top, img.astype(np.float64).mean(axis=(0, 1)), rtol=1e-5)
    assert np.allclose(E.eval_radiance_lod(env, d, -3.0), lod0, rtol=1e-6)
    # the kernel reads level 0 at a NaN lod (no crash); the host-side lookup refuses one, and a lod of another count
    unit = (d[:3] / np.linalg.norm(d[:3], axis=1, keepdims=True)).astype(np.float32)
    out = wp.empty(3, dtype=wp.vec3)
    wp.launch(E._eval_radiance_lod_kernel, dim=3, device="cpu",
              inputs=[env.data, wp.array(unit, dtype=wp.vec3), wp.array(np.full(3, np.nan, np.float32)), out])
    assert np.allclose(out.numpy(), lod0[:3], rtol=1e-6)
    for bad, msg in ((np.nan, "NaN or infinite"), (None, "NaN or infinite"), ([1.0, 2.0], r"shape \(2,\)")):
        with pytest.raises(WarpbwError, match=r"^lod: expected a finite level, or 3 of them .* " + msg):
            E.eval_radiance_lod(env, d[:3], bad)
    # a NaN direction reaching the kernels gives no crash (indices are clamped), whatever value it returns; the
    # host-side lookups refuse it
    nan_dir = wp.array(np.array([[np.nan, 0.0, 1.0]], np.float32), dtype=wp.vec3)
    for kernel, dtype in ((E._eval_radiance_kernel, wp.vec3), (E._eval_pdf_kernel, wp.float32)):
        wp.launch(kernel, dim=1, inputs=[env.data, nan_dir, wp.empty(1, dtype=dtype)])
    with pytest.raises(WarpbwError, match=r"^dirs: expected finite non-zero directions, 1 of 1 are not"):
        E.eval_radiance(env, [[np.nan, 0.0, 1.0]])


def test_host_lookups_check_their_directions():
    """eval_radiance read (4, 2) through numpy's reshape (a ValueError), a zero direction as a pixel, and a
    direction of length 10 as a NaN latitude; now directions are checked and scaled to unit length."""
    env = E.envmap_from_array(np.random.default_rng(1).random((8, 16, 3)).astype(np.float32))
    d = np.array([[0.3, 0.5, -0.2], [0.0, -1.0, 0.0]])
    unit = d / np.linalg.norm(d, axis=1, keepdims=True)
    assert np.array_equal(E.eval_radiance(env, 10.0 * d), E.eval_radiance(env, unit))
    assert np.array_equal(E.eval_pdf(env, 10.0 * d), E.eval_pdf(env, unit))
    assert np.array_equal(E.eval_radiance_lod(env, 3.0 * d, 1.0), E.eval_radiance_lod(env, unit, 1.0))
    for bad, msg in ((np.ones((4, 2)), r"^dirs: expected \(N, 3\) directions \(or one \(3,\)\), got shape \(4, 2\)"),
                     ([0.0, 0.0, 0.0], r"^dirs: expected finite non-zero directions, 1 of 1 are not"),
                     ("up", r"^dirs: expected \(N, 3\) directions, got str")):
        for f in (E.eval_radiance, E.eval_pdf):
            with pytest.raises(WarpbwError, match=msg):
                f(env, bad)
    with pytest.raises(WarpbwError, match=r"^env: expected an EnvMap .*got its \.data \(a Warp struct\)"):
        E.eval_radiance_lod(env.data, d, 0.0)


def test_mip_pyramid_is_built_only_when_a_lookup_needs_it():
    """No renderer reads the pyramid, so loading a map does not build it (DESIGN: a stage the scene does not need
    is not run); the first lod lookup does, once, and the lookups agree with a 2x2 box of the map, whose row k
    sits at the centre of the rows it averages, v = (2k + 1/2) / 7 (the box map as a map of its own reads it at
    v' = k / 3: the same u, v' = clip((7 v - 1/2) / 2, 0, 3) / 3)."""
    img = np.random.default_rng(5).random((8, 16, 3)).astype(np.float32)
    env = E.envmap_from_array(img)
    assert env._mips is None and env.data.n_levels == 1
    d = np.random.default_rng(6).normal(size=(200, 3))
    E.eval_radiance_lod(env, d, 1.0)
    assert env.data.n_levels == 5 and len(env._mips) == 5
    box = img.reshape(4, 2, 8, 2, 3).mean(axis=(1, 3))
    dn = d / np.linalg.norm(d, axis=1, keepdims=True)
    # (off the poles by 1e-6 of a row: a direction at a pole has no u of its own)
    v_box = np.clip((7.0 * np.arccos(dn[:, 1]) / np.pi - 0.5) / 2.0, 1e-6, 3.0 - 1e-6) / 3.0
    rho = np.hypot(dn[:, 0], dn[:, 2])[:, None]
    d_box = np.concatenate([dn[:, :1] / rho * np.sin(np.pi * v_box)[:, None], np.cos(np.pi * v_box)[:, None],
                            dn[:, 2:] / rho * np.sin(np.pi * v_box)[:, None]], axis=1)
    assert np.allclose(E.eval_radiance_lod(env, d, 1.0), E.eval_radiance(E.envmap_from_array(box), d_box), rtol=1e-4)
    assert E.build_mip_pyramid(env)._mips[1] is env.mip_levels[1]   # built once


def test_one_by_one_map():
    env = E.envmap_from_array(np.array([[[2.0, 3.0, 4.0]]], np.float32))
    assert env.mip_levels[0].shape == (1, 1, 3) and len(env.mip_levels) == 1
    d = np.random.default_rng(0).normal(size=(1000, 3))
    assert np.all(E.eval_radiance(env, d) == np.float32([2.0, 3.0, 4.0]))
    assert np.all(E.eval_radiance_lod(env, d, 3.0) == np.float32([2.0, 3.0, 4.0]))
    dirs, pdf = E.sample_directions(env, 50_000, seed=0)
    assert np.allclose(pdf, 1.0 / (4.0 * np.pi), rtol=1e-5)
    assert np.all(np.abs(dirs.mean(axis=0)) < 0.02)


# ----------------------------------------------------------------------------- procedural sky, files


def test_procedural_sky():
    sky = E.procedural_sky(128, 64, sun_elevation_deg=40.0, sun_azimuth_deg=90.0)
    assert sky.shape == (64, 128, 3) and sky.dtype == np.float32
    assert np.all(np.isfinite(sky)) and sky.min() >= 0.0
    assert np.array_equal(sky, E.procedural_sky(128, 64, sun_elevation_deg=40.0, sun_azimuth_deg=90.0))
    lum = sky @ LUM
    j, i = np.unravel_index(np.argmax(lum), lum.shape)
    d = texel_dir(i, j, 128, 64)
    # azimuth 90 = +X (u = 0.25), elevation 40 degrees
    assert np.degrees(np.arccos(d @ [math.cos(math.radians(40)), math.sin(math.radians(40)), 0.0])) < 4.0
    sky_lum = np.median(lum[: 64 // 2 - 2])
    ground_lum = np.median(lum[64 // 2 + 2 :])
    assert 50.0 < lum.max() / sky_lum < 250.0
    assert ground_lum < 0.5 * sky_lum
    zen, hor = sky[0].mean(axis=0), sky[64 // 2 - 2].mean(axis=0)
    assert zen[2] > zen[0] and hor.sum() > zen.sum() * 0.8  # blue zenith, bright horizon
    env = E.envmap_from_array(sky)
    assert E.eval_pdf(env, d)[0] > 50.0 / (4.0 * np.pi)


def test_load_envmap_matches_array(tmp_path):
    pytest.importorskip("warpbw.io.exr", reason="warpbw.io.exr is not available")
    img = synthetic_map()
    img[1, 1, 0] = -1.0
    p = tmp_path / "probe.exr"
    write_probe(p, img)
    with pytest.warns(RuntimeWarning, match="1 channel values"):
        env = E.load_envmap(p, rotation_deg=15.0, scale=2.0)
    assert env.name == "probe.exr" and env.n_clamped == 1
    with pytest.warns(RuntimeWarning):
        ref = E.envmap_from_array(img, rotation_deg=15.0, scale=2.0)
    assert np.array_equal(env.pixels, ref.pixels)
    assert np.array_equal(env.pixels, np.where(img < 0, 0, img * 2).astype(np.float32))
    with pytest.raises(WarpbwError):
        E.load_envmap(tmp_path / "missing.exr")


def test_a_probe_is_read_over_its_display_window_not_its_data_window(tmp_path):
    """An EXR's display window is the image's frame; its data window holds the pixels stored, which may leave part
    of the frame out (a probe auto-cropped to its non-black texels) or reach past it (overscan).  Pixels of the frame
    outside the data window are empty, those stored outside the frame are not shown (OpenEXR, Technical Introduction:
    "Display window", "Data window"; test images DisplayWindow/t05, t08).  A lat-long probe spreads its frame over the
    sphere: read as its data window, a sky cropped to its upper half was stretched over the whole sphere (lit from
    below), and the overscan's border was read as the poles and the seam.  Files written by OpenEXR itself."""
    import OpenEXR

    from warpbw.io.exr import exr_size, read_rgb

    rng = np.random.default_rng(7)
    full = np.zeros((8, 16, 3), np.float32)
    full[:4] = rng.uniform(0.5, 2.0, (4, 16, 3))   # a sky above the horizon, a black ground

    def write(name, pixels, data, display):
        box = [(np.array(w[:2], np.int32), np.array(w[2:], np.int32)) for w in (data, display)]
        OpenEXR.File({"dataWindow": box[0], "displayWindow": box[1]},
                     {c: np.ascontiguousarray(pixels[..., i]) for i, c in enumerate("RGB")}).write(str(tmp_path / name))
        return tmp_path / name

    over = np.full((12, 20, 3), 99.0, np.float32)
    over[2:10, 3:19] = full
    right = full.copy()
    right[:, :5] = 0.0                             # the frame's first 5 columns hold no stored pixel
    files = {write("cropped.exr", full[:4], (0, 0, 15, 3), (0, 0, 15, 7)): full,
             write("overscan.exr", over, (-3, -2, 16, 9), (0, 0, 15, 7)): full,
             write("right.exr", full[:, 5:], (105, -50, 115, -43), (100, -50, 115, -43)): right,
             write("moved.exr", full, (100, -50, 115, -43), (100, -50, 115, -43)): full}   # the same windows
    for path, want in files.items():
        assert np.array_equal(read_rgb(path), want), path.name
        assert np.array_equal(E.load_envmap(path).pixels, want), path.name   # and no warning (before: "not 2:1")
        assert exr_size(path, window="display") == (16, 8), path.name
    cropped, overscan = list(files)[:2]
    assert exr_size(cropped) == (16, 4) and exr_size(overscan) == (20, 12)   # the data window: what is decoded


def test_texel_directions_are_where_the_lookup_reads_each_texel():
    """Round trip: the bilinear lookup (whose orientation this module checks against Mitsuba) at texel_directions'
    direction of an interior texel returns that texel's value; and, from the docstring, row j lies at the polar
    angle pi j / (H - 1) (row 0 the +Y pole, row H - 1 the -Y pole) and column i at the azimuth 2 pi (i + 1/2) / W."""
    H, W = 6, 12
    rng = np.random.default_rng(3)
    pix = rng.uniform(0.1, 2.0, (H, W, 3)).astype(np.float32)
    d = E.texel_directions(W, H)
    assert d.shape == (H, W, 3)
    theta = np.arccos(np.clip(d[..., 1], -1.0, 1.0))
    np.testing.assert_allclose(theta, np.pi * np.arange(H)[:, None] / (H - 1) + 0 * d[..., 0], atol=1e-9)
    inner = d[1:-1]
    phi = np.arctan2(inner[..., 0], -inner[..., 2]) % (2 * np.pi)
    np.testing.assert_allclose(phi, 2 * np.pi * (np.arange(W)[None, :] + 0.5) / W + 0 * phi, atol=1e-9)
    got = E.eval_radiance(E.envmap_from_array(pix), inner.reshape(-1, 3)).reshape(H - 2, W, 3)
    np.testing.assert_allclose(got, pix[1:-1], rtol=1e-4, atol=1e-5)


def test_procedural_sun_sits_at_its_azimuth_and_elevation():
    """procedural_sky's docstring: azimuth 0 is -Z and 90 is +X (it follows u), so the sun of azimuth az and
    elevation el is (sin az cos el, sin el, -cos az cos el); the brightest texel, placed by the module docstring's
    texel centres (u = (i + 1/2) / W, v = j / (H - 1)), lies within 3 degrees of it, at azimuths off the X axis."""
    W, H = 128, 64
    rec709 = np.array([0.2126, 0.7152, 0.0722])   # ITU-R BT.709 luminance weights
    for az, el in ((0.0, 30.0), (45.0, 20.0), (200.0, 50.0), (300.0, 10.0)):
        lum = E.procedural_sky(W, H, sun_elevation_deg=el, sun_azimuth_deg=az) @ rec709
        j, i = np.unravel_index(np.argmax(lum), lum.shape)
        phi, th = 2 * np.pi * (i + 0.5) / W, np.pi * j / (H - 1)
        d = np.array([np.sin(phi) * np.sin(th), np.cos(th), -np.cos(phi) * np.sin(th)])
        a, e = math.radians(az), math.radians(el)
        sun = np.array([math.sin(a) * math.cos(e), math.sin(e), -math.cos(a) * math.cos(e)])
        assert np.degrees(np.arccos(np.clip(d @ sun, -1, 1))) < 3.0, (az, el)


def test_environment_samples_fill_each_cell_uniformly_up_to_its_edges():
    """envmap's docstring: inside a cell the direction is uniform in phi, kept clear of the cell's edges by 1e-3 of
    its width (CELL_EDGE_MARGIN).  1e6 samples of a constant 4x8 map, their position across their cell's width
    (from u = atan2(x, -z) / 2 pi) in 125 bins of 0.008: every bin holds its uniform share within 25% (the binomial
    noise is 1.1%; a margin of 1e-3 moves at most 1e-3 / 0.008 = 12.5% of an edge bin, whether squeezed or clamped)."""
    env = E.constant_envmap(1.0)
    d, _ = E.sample_directions(env, 1_000_000, seed=3)
    u = (np.arctan2(d[:, 0], -d[:, 2]) / (2 * np.pi)) % 1.0
    t = (u * env.width) % 1.0
    share = np.histogram(t, bins=125, range=(0.0, 1.0))[0] / (len(t) / 125)
    assert np.all(np.abs(share - 1.0) < 0.25), (share.min(), share.max(), share[:2], share[-2:])


@pytest.mark.parametrize("w", [4096, 16384])
@pytest.mark.parametrize("angle", [0.0, -137.0])
def test_a_sampled_direction_reads_the_pdf_of_the_cell_it_lies_in_on_wide_maps(angle, w):
    """CELL_EDGE_MARGIN: float32 rounding in env_sample's phi and in env_pdf's u does not carry a sampled direction
    into the next column on a map 4096 texels wide (4e-4 of a cell at most there, against the margin's 1e-3), turned
    or not: the pdf returned with each of 2M samples is that of the cell the direction lies in, found in float64 (the
    map turned back by Mitsuba's matrix, the cell's pdf read at its centre).  Columns of very different luminance
    make a neighbour's pdf tell.  At 16384 columns the rounding reaches past 1e-3 of a cell: with that margin alone
    671 of the 2M turned samples (and some unturned) read a neighbour's pdf, 0.4-5 times their own; the margin now
    grows with the cells (CELL_EDGE_MARGIN_PER_CELL, session 77)."""
    h = 2
    img = np.random.default_rng(8).gamma(0.3, 1.0, size=(h, w, 3)).astype(np.float32)
    env = E.envmap_from_array(img, rotation_deg=angle)
    pdf_cells, _ = _pdf_sum_over_cells(E.envmap_from_array(img), h, w)
    dirs, pdf_s = E.sample_directions(env, 2_000_000, seed=4)
    rows, cols = cell_of(dirs.astype(np.float64) @ rot_y(angle), h, w)
    wrong = ~np.isclose(pdf_s, pdf_cells[rows, cols], rtol=1e-6, atol=0.0)
    assert wrong.sum() == 0, (int(wrong.sum()), pdf_s[wrong][:3], pdf_cells[rows, cols][wrong][:3])


@pytest.mark.parametrize("h", [64, 63, 33])
def test_mip_levels_keep_what_they_average_where_it_was(h):
    """A box filter is symmetric: a step filtered by it still crosses half its height where it stepped.  Truth: level
    0's crossing, between the 8th and 9th rows from the bottom, for the levels whose rows (up to 8 of level 0's) are no
    taller than the bright cap.  A level's rows were placed at k / (H_l - 1), as level 0's are, which moved each row's
    contents towards the nearer pole: at lod 3 the cap's edge moved by 3.0 rows of level 0 on 64 rows (2.3 on 33), at
    lod 2 by 1.2 (0.8); now by 0 on 64 rows and at most 0.44 where odd heights are resampled (63, 33)."""
    img = np.zeros((h, 2 * h, 3), np.float32)
    img[h - 8:] = 1.0     # a bright cap about -Y
    env = E.envmap_from_array(img)
    v = np.linspace(0.6, 1.0, 8001)
    d = np.stack([np.full_like(v, 1e-7), np.cos(np.pi * v), -np.sin(np.pi * v)], 1)
    step = (h - 8.5) / (h - 1)
    for lod in range(4):
        val = E.eval_radiance_lod(env, d, float(lod))[:, 0]
        moved = (v[np.argmax(val >= 0.5)] - step) * (h - 1)   # in rows of level 0
        assert abs(moved) < 0.5, f"lod {lod}: the cap's edge moved by {moved:+.2f} rows of level 0"



def test_maps_of_the_same_bytes_in_another_shape_or_type_have_other_source_digests():
    """Round 11: ``EnvMap.source_digest`` names the map as given: the same bytes as a 4 x 8 and an 8 x 4 map, or as
    float32 and int32 values, are other maps (the bandwidth cache is keyed by the digest: one map's entry was read for
    the other).  Truth: the arrays built here."""
    a = np.random.default_rng(3).random((4, 8, 3)).astype(np.float32)
    digests = {E.envmap_from_array(x).source_digest for x in (a, a.reshape(8, 4, 3), a.view(np.int32))}
    assert len(digests) == 3


@pytest.mark.parametrize("field", ["marginal_cdf", "conditional_cdf", "row_omc", "row_opc", "cell_pdf"])
def test_check_env_data_refuses_a_struct_missing_any_one_sampling_array(field):
    """``check_env_data`` (what every sampling pass calls) refuses a struct whose one sampling array is empty or of
    another shape, each alone: a kernel reads every one of them (``env_sample``, ``env_pdf``).  Truth: the
    documented shapes of EnvMapData's fields ((1, H+1), (H, W+1), (H+1,), (H+1,), (H, W))."""
    from warpbw.envmap import check_env_data, envmap_from_array

    h, w = 4, 8
    data = envmap_from_array(np.ones((h, w, 3), np.float32)).data
    check_env_data(data, "here")   # whole: accepted
    full = getattr(data, field)
    shorter = wp.zeros(tuple(s - 1 if i == len(full.shape) - 1 else s for i, s in enumerate(full.shape)),
                       dtype=wp.float32)
    for bad in (wp.zeros((0,) * len(full.shape), dtype=wp.float32), shorter):
        setattr(data, field, bad)
        with pytest.raises(WarpbwError, match=r"^here: env_data: this pass samples the environment"):
            check_env_data(data, "here")
        check_env_data(data, "here", sampled=False)   # a look-up alone reads none of them


@pytest.mark.parametrize("what", ["height", "width", "zero"])
def test_check_env_data_refuses_a_map_of_another_size_than_the_struct_says(what):
    """The struct's ``base`` must be the (height, width) map it says it holds (each look-up indexes it so): a map of
    another shape, or a size of 0, is refused in one line, sampled or not.  Truth: EnvMapData's documented layout."""
    from warpbw.envmap import check_env_data, envmap_from_array

    data = envmap_from_array(np.ones((4, 8, 3), np.float32)).data
    if what == "height":
        data.height = 5
    elif what == "width":
        data.width = 7
    else:
        data.base = wp.zeros((0, 0), dtype=wp.vec3)
        data.height, data.width = 0, 0
    for sampled in (False, True):
        with pytest.raises(WarpbwError, match=r"^there: env_data: expected an EnvMapData holding its map"):
            check_env_data(data, "there", sampled=sampled)
