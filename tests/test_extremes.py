"""Numerical extremes of the reference renderer: a sun of ~34,000 (city.exr), grazing silhouettes, 1x1 and
7x5 images, a camera inside a sphere, an environment with NaN / inf / negative pixels, GGX at the smallest
allowed roughness and at alpha = 1, with and without MIS; and the reflectance-filtering renderer's planes
under the city sun, seen down to the horizon.

Truth comes from closed forms and independent numpy computations:
- a Lambert surface under a constant sky L returns albedo * L exactly per BRDF sample (cosine sampling);
- a GGX surface with F = 1 and alpha = 1 has directional albedo 2 (1 - ln 2) / (1 + cos_o) (D = 1/pi);
- a Lambert surface under city.exr has radiance albedo / pi * E(n), with the irradiance E summed here over
  the probe's texels;
- coverage of a sphere is decided by the distance from its centre to each pixel's centre ray.

Kernels: every scene here uses one of two material-kind sets ({ggx, lambert}; {ggx, lambert, npf}), with
and without MIS, so the module compiles four shading kernels at most; materials a test does not look at sit
on spheres hidden behind the camera or outside a surrounding sphere.
"""
from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import warnings

import numpy as np
import pytest

from conftest import plane_scene_toml

from warpbw.errors import WarpbwError
from warpbw.envmap import envmap_from_array
from warpbw.io.exr import read_rgb, write_exr
from warpbw.pipeline import render_adaptive, render_reference
from warpbw.scene import GGX_MIN_ALPHA, parse_scene

GRAZING = 0.05  # n . v below this counts as a grazing pixel


@pytest.fixture(scope="module", autouse=True)
def _sampling_cache(tmp_path_factory):
    """Sampling tables built for NPF materials go to a temporary cache, never ~/.cache."""
    old = os.environ.get("WARPBW_CACHE")
    os.environ["WARPBW_CACHE"] = str(tmp_path_factory.mktemp("warpbw_cache"))
    yield
    if old is None:
        os.environ.pop("WARPBW_CACHE", None)
    else:
        os.environ["WARPBW_CACHE"] = old


def scene(*, env: str, objects: list, resolution=(32, 32), position=(0.0, 0.0, 4.0), look_at=(0.0, 0.0, 0.0),
          fov=40.0, alpha=0.05, npf_table=None, base_dir="."):
    """A scene with materials g (GGX, F = 1), l (Lambert 0.8) and, with npf_table, n (NPF chrome).

    objects: (center, radius, material) triples.
    """
    lines = ["[camera]", f"position = {list(position)}", f"look_at = {list(look_at)}", f"fov = {fov}",
             f"resolution = {list(resolution)}", "", "[environment]", env, ""]
    for c, r, m in objects:
        lines += ["[[object]]", 'shape = "sphere"', f"center = {list(c)}", f"radius = {r}", f'material = "{m}"', ""]
    lines += ["[material.g]", 'type = "ggx"', f"alpha = {alpha!r}", "specular = [1.0, 1.0, 1.0]", "",
              "[material.l]", 'type = "lambert"', "albedo = 0.8", ""]
    if npf_table is not None:
        lines += ["[material.n]", 'type = "npf"', f'table = "{npf_table}"', 'name = "chrome"', 'lookup = "linear"']
    return parse_scene("\n".join(lines), base_dir, "extremes")


# Spheres behind the camera (it looks down -Z from +Z): they make a material "used" (same kernel) unseen.
def hidden(*materials):
    return [((3.0 * k, 0.0, 40.0), 0.5, m) for k, m in enumerate(materials)]


def n_dot_v(res) -> np.ndarray:
    return np.einsum("hwc,hwc->hw", res.gbuffer.numpy("normal"), res.gbuffer.numpy("view"))


def assert_clean(res):
    """Finite, non-negative, black outside coverage, and no sample dropped as non-finite."""
    img = res.image
    assert np.isfinite(img).all(), f"{(~np.isfinite(img)).sum()} non-finite values"
    assert (img >= 0.0).all(), img.min()
    assert (img[~res.coverage] == 0.0).all()
    assert res.stats["non_finite_samples"] == 0, res.stats["non_finite_samples"]


@pytest.fixture(scope="module")
def city(shared):
    # its few negative pixels are set to 0 with a warning that pyproject.toml's filterwarnings ignores by the file's
    # name: the tests under it filter no RuntimeWarning wholesale (they did until session 82, which would have hidden
    # a new overflow or invalid-value warning of the renderer's), and expect each warning they cause by its words
    return shared("envmaps/city.exr")


@pytest.fixture(scope="module")
def npf_table(shared):
    return shared("brdf/npf.bin")


# ------------------------------------------------------------------------------------------ city.exr, sun ~34,000

def test_city_probe_really_has_a_bright_sun(city):
    rgb = read_rgb(city)
    assert rgb.max() > 1.0e4 and np.median(rgb) < 10.0  # the extreme this module is about


@pytest.mark.parametrize("mis", [False, True], ids=["brdf", "mis"])
def test_city_three_materials_are_finite(city, npf_table, mis):
    objs = [((-2.2, 0.0, 0.0), 1.0, "g"), ((0.0, 0.0, 0.0), 1.0, "l"), ((2.2, 0.0, 0.0), 1.0, "n")]
    s = scene(env=f'file = "{city}"', objects=objs, resolution=(64, 24), position=(0.0, 0.0, 6.0), fov=50.0,
              npf_table=npf_table)
    res = render_reference(s, spp=16, seed=3, mis=mis)
    assert_clean(res)
    mat = res.gbuffer.numpy("material")
    for m in range(3):
        sel = mat == m
        assert sel.sum() > 50
        assert res.image[sel].mean() > 0.0
    assert res.stats["assets"]["environment"]["clamped_values"] > 0  # the probe's negative pixels


def _irradiance(env: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """E(n) = sum over texel cells of L max(0, n . w) dOmega, with the envmap module's documented convention:
    column i at u = (i + 1/2) / W, row j at v = j / (H - 1) (pole rows own half cells),
    w = (sin phi sin theta, cos theta, -cos phi sin theta), phi = 2 pi u, theta = pi v."""
    h, w, _ = env.shape
    edges = np.clip((np.arange(h + 1) - 0.5) / (h - 1), 0.0, 1.0) * np.pi
    d_omega = (np.cos(edges[:-1]) - np.cos(edges[1:])) * 2.0 * np.pi / w  # per texel of each row
    assert abs(d_omega.sum() * w - 4.0 * np.pi) < 1e-9
    phi = 2.0 * np.pi * (np.arange(w) + 0.5) / w
    theta = np.pi * np.arange(h) / (h - 1)
    dirs = np.stack(np.broadcast_arrays(np.sin(phi)[None] * np.sin(theta)[:, None], np.cos(theta)[:, None],
                                        -np.cos(phi)[None] * np.sin(theta)[:, None]), -1).reshape(-1, 3)
    weighted = (np.maximum(env, 0.0) * d_omega[:, None, None]).reshape(-1, 3)
    out = np.zeros((len(normals), 3))
    for k in range(0, len(dirs), 1 << 15):  # chunks keep the (pixels x texels) cosines small
        out += np.maximum(normals @ dirs[k:k + (1 << 15)].T, 0.0) @ weighted[k:k + (1 << 15)]
    return out


def test_lambert_under_city_matches_the_irradiance_integral(city, npf_table):
    objs = [((-2.2, 0.0, 0.0), 1.0, "g"), ((0.0, 0.0, 0.0), 1.0, "l"), ((2.2, 0.0, 0.0), 1.0, "n")]
    s = scene(env=f'file = "{city}"', objects=objs, resolution=(64, 24), position=(0.0, 0.0, 6.0), fov=50.0,
              npf_table=npf_table)
    res = render_reference(s, spp=64, seed=5, mis=True)
    assert_clean(res)
    sel = res.gbuffer.numpy("material") == 1
    normals = res.gbuffer.numpy("normal")[sel].astype(np.float64)
    expect = 0.8 / np.pi * _irradiance(read_rgb(city).astype(np.float64), normals)
    got = res.image[sel].astype(np.float64)
    ratio = got.mean(0) / expect.mean(0)
    assert np.all(np.abs(ratio - 1.0) < 0.03), ratio
    rel = np.abs(got - expect) / expect
    assert np.median(rel) < 0.15, np.median(rel)


# ------------------------------------------------------------------------------------------ grazing silhouettes

@pytest.mark.parametrize("mis", [False, True], ids=["brdf", "mis"])
@pytest.mark.parametrize("material", ["g", "l", "n"])
def test_grazing_pixels_are_finite(city, npf_table, material, mis):
    # A huge sphere seen from 5 cm above its surface, looking at the horizon: many pixels hit it at n.v -> 0.
    others = [m for m in "gln" if m != material]
    objs = [((0.0, -50.0, 0.0), 50.0, material)] + hidden(*others)
    s = scene(env=f'file = "{city}"', objects=objs, resolution=(32, 32), position=(0.0, 0.05, 0.0),
              look_at=(0.0, 0.05 - math.tan(math.radians(6.0)), -1.0), fov=16.0, npf_table=npf_table)
    res = render_reference(s, spp=8, seed=7, mis=mis)
    assert_clean(res)
    ndv = n_dot_v(res)
    grazing = res.coverage & (ndv < GRAZING)
    assert grazing.sum() >= 20, grazing.sum()
    assert ndv[grazing].min() < 0.02
    assert np.isfinite(res.image[grazing]).all()


# ------------------------------------------------------------------------------------------ tiny images

def _analytic_coverage(width, height, fov, position, center, radius):
    """Which pixel centres' rays hit the sphere (camera looking at the origin, +Y up), and the margin."""
    o = np.asarray(position, np.float64)
    fwd = -o / np.linalg.norm(o)
    right = np.cross(fwd, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    tx = math.tan(math.radians(fov) / 2.0)
    ty = tx * height / width
    x, y = np.meshgrid(np.arange(width), np.arange(height))
    sx = (2.0 * (x + 0.5) / width - 1.0) * tx
    sy = (1.0 - 2.0 * (y + 0.5) / height) * ty  # row 0 at the top
    d = fwd + sx[..., None] * right + sy[..., None] * up
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    oc = np.asarray(center) - o
    t = d @ oc
    dist = np.linalg.norm(oc - t[..., None] * d, axis=-1)
    return (dist < radius) & (t > 0), np.abs(dist - radius)


@pytest.mark.parametrize("size", [(1, 1), (7, 5), (5, 7), (2, 1)])
def test_tiny_images_have_the_right_coverage(size):
    w, h = size
    pos = (0.0, 0.0, 4.0)
    s = scene(env="constant = [1.0, 1.0, 1.0]", objects=[((0.0, 0.0, 0.0), 1.0, "l")] + hidden("g"),
              resolution=size, position=pos, fov=45.0)
    res = render_reference(s, spp=4, seed=1)
    assert res.image.shape == (h, w, 3)
    assert_clean(res)
    expect, margin = _analytic_coverage(w, h, 45.0, pos, (0.0, 0.0, 0.0), 1.0)
    assert margin.min() > 1e-3  # no pixel centre grazes the silhouette: the comparison is well posed
    np.testing.assert_array_equal(res.coverage, expect)
    if w % 2 and h % 2:
        assert res.coverage[h // 2, w // 2]  # the centre pixel looks at the sphere's centre
    # Lambert under a constant sky: every cosine-sampled BRDF sample returns albedo * L exactly
    np.testing.assert_allclose(res.image[res.coverage], 0.8, rtol=1e-5)
    # and adaptively, with the default pass (its 2 x 2 blocks refused a 1 x 1 frame: "stride: expected 1 to 1")
    ada = render_adaptive(s, budget=2, seed=1)
    np.testing.assert_array_equal(ada.coverage, expect)
    np.testing.assert_allclose(ada.image[ada.coverage], 0.8, rtol=1e-5)


# ------------------------------------------------------------------------------------------ camera inside a sphere

@pytest.mark.parametrize("mis", [False, True], ids=["brdf", "mis"])
def test_camera_inside_a_sphere(mis):
    # The camera sits off-centre inside a Lambert sphere of radius 5; the GGX sphere outside it is hidden
    # behind the wall.  Shading ignores visibility (002 Eq. 1), so the inner wall sees the whole sky.
    objs = [((0.0, 0.0, 0.0), 5.0, "l"), ((0.0, 0.0, -9.0), 1.0, "g")]
    s = scene(env="constant = [1.0, 1.0, 1.0]", objects=objs, resolution=(24, 16), position=(1.0, 0.5, 3.0),
              look_at=(0.0, 0.0, -1.0), fov=90.0)
    res = render_reference(s, spp=32, seed=2, mis=mis)
    assert_clean(res)
    assert res.coverage.all()
    assert (res.gbuffer.numpy("material") == s.material_order.index("l")).all()  # only the inner wall is seen
    ndv = n_dot_v(res)
    assert (ndv > 0.0).all()  # normals face the camera (flipped inwards)
    if not mis:
        np.testing.assert_allclose(res.image, 0.8, rtol=1e-5)
    else:
        # balance heuristic: unbiased, each pixel a bounded mix; the mean over 384 pixels is tight
        assert abs(res.image.mean() - 0.8) < 0.01
        assert res.image.max() < 0.8 * 2.0


# ------------------------------------------------------------------------------------------ bad environment pixels

@pytest.mark.parametrize("mis", [False, True], ids=["brdf", "mis"])
def test_environment_with_nan_inf_and_negative_pixels(tmp_path, mis):
    env = np.full((16, 32, 3), 0.5, np.float32)
    env[3, 4, :] = np.nan           # 3 values
    env[5, 6, 1] = np.inf           # 1
    env[7, 8, 2] = -np.inf          # 1
    env[9, 10, 0] = -2.0            # 1 negative
    env[0, :, :] = 1e30             # a finite but extreme top row (not clamped)
    write_exr(tmp_path / "bad.exr", env)
    objs = [((-1.1, 0.0, 0.0), 1.0, "g"), ((1.1, 0.0, 0.0), 1.0, "l")]
    s = scene(env='file = "bad.exr"', objects=objs, base_dir=tmp_path, position=(0.0, 0.0, 5.0))
    with pytest.warns(RuntimeWarning, match=r"'bad\.exr': set 6 channel values to 0 in 4 pixels "
                                            r"\(1 negative, 5 NaN or infinite\)"):
        res = render_reference(s, spp=8, seed=4, mis=mis)
    assert res.stats["assets"]["environment"]["clamped_values"] == 6
    assert np.isfinite(res.image).all()
    assert res.stats["non_finite_samples"] == 0
    assert res.coverage.sum() > 100


@pytest.mark.parametrize("probe", ["2x1", "nan"])
def test_a_probe_of_one_row_or_of_nan_gives_its_closed_form_with_either_env_signal(tmp_path, probe):
    """A probe of 2 x 1 texels of 0.7 (one row: the row positions, cells and MIP rows of a map of H = 1) is a constant
    sky: a Lambert sphere of albedo 0.8 returns 0.8 x 0.7 per BRDF sample (cosine sampling), so the reference and the
    adaptive frame without MIS give exactly that, with both env signals (the bandwidth map of a constant probe is 0).
    A probe whose every texel is NaN is set to 0 with a warning (the loader's promise): every method renders black,
    with finite AOVs, and the adaptive frame is neither refused nor NaN (the log signal divides by the probe's mean,
    0 here).  Session 77 (no test rendered either probe adaptively)."""
    from warpbw.pipeline import prepare_scene, render_adaptive

    env = np.full((1, 2, 3), 0.7, np.float32) if probe == "2x1" else np.full((8, 16, 3), np.nan, np.float32)
    write_exr(tmp_path / "probe.exr", env)
    s = scene(env='file = "probe.exr"', objects=[((0.0, 0.0, 0.0), 1.0, "l")] + hidden("g"), base_dir=tmp_path,
              resolution=(12, 10))
    with warnings.catch_warnings():
        if probe == "nan":
            warnings.filterwarnings("ignore", r".*set 384 channel values to 0", RuntimeWarning)
        prep = prepare_scene(s)
    want = 0.8 * 0.7 if probe == "2x1" else 0.0
    frames = [render_reference(prep, spp=4, seed=1), render_reference(prep, spp=4, seed=1, mis=True)]
    frames += [render_adaptive(prep, budget=2.0, seed=1, env_signal=signal, mis=mis)
               for signal in ("log", "radiance") for mis in (False, True)]
    for k, res in enumerate(frames):
        assert_clean(res)
        assert res.coverage.sum() > 30
        for name, a in res.aovs.items():
            assert np.isfinite(np.asarray(a, np.float64)).all(), (k, name)
        lit = res.image[res.coverage]
        if k == 0 or (k >= 2 and k % 2 == 0) or probe == "nan":   # BRDF sampling alone, or a black sky: exact
            np.testing.assert_allclose(lit, want, rtol=1e-4, atol=0.0, err_msg=str(k))
        else:   # MIS: unbiased, each pixel a bounded mix
            assert abs(lit.mean() / want - 1.0) < 0.1, (k, lit.mean())


# ------------------------------------------------------------------------------------------ GGX roughness extremes

def _furnace_scene(alpha):
    return scene(env="constant = [1.0, 1.0, 1.0]", objects=[((0.0, 0.0, 0.0), 1.0, "g")] + hidden("l"),
                 alpha=alpha)


@pytest.mark.parametrize("mis", [False, True], ids=["brdf", "mis"])
def test_ggx_smallest_alpha_is_a_white_mirror(mis):
    # F = 1 and VNDF sampling: each BRDF sample weighs G1(wi) = 1 - O(alpha^2 / cos^2), so a near-mirror
    # under a white sky is white wherever the view is not grazing.
    res = render_reference(_furnace_scene(GGX_MIN_ALPHA), spp=16, seed=6, mis=mis)
    assert_clean(res)
    sel = res.coverage & (n_dot_v(res) > 0.3)
    assert sel.sum() > 100
    if not mis:
        np.testing.assert_allclose(res.image[sel], 1.0, atol=1e-3)
    else:
        assert abs(res.image[sel].mean() - 1.0) < 0.01
    assert res.image.max() < 1.5


def test_ggx_alpha_below_the_scene_minimum_stays_a_finite_mirror():
    # float32 ggx_d once broke below alpha ~1.7e-4 (1 + cos^2 (a^2 - 1) == 0 at h = n); 1e-4 is the scene's
    # bound, and 1e-6, below it, reaches the material table only through the stage API
    # (build_material_table clamps it to GGX_MIN_ALPHA): a Scene edited in Python is checked as a file is
    from warpbw.brdf import GGX, LAMBERT, MaterialSpec, build_material_table
    from warpbw.pipeline import prepare_scene

    prep = prepare_scene(_furnace_scene(GGX_MIN_ALPHA))
    _check_white_mirror(prep)
    below = build_material_table([MaterialSpec("g", GGX, alpha=1e-6, specular=(1.0, 1.0, 1.0)),
                                  MaterialSpec("l", LAMBERT, albedo=(0.8, 0.8, 0.8))])
    _check_white_mirror(dataclasses.replace(prep, materials=below))
    edited = _furnace_scene(GGX_MIN_ALPHA)
    edited.materials["g"] = dataclasses.replace(edited.materials["g"], alpha=1e-6)
    with pytest.raises(WarpbwError, match=r"\[material\.g\]\.alpha: expected a number >= 0\.0001, got 1e-06"):
        render_reference(edited, spp=1)


def _check_white_mirror(s):
    res = render_reference(s, spp=16, seed=6)
    sel = res.coverage & (n_dot_v(res) > 0.3)
    assert res.stats["non_finite_samples"] == 0
    np.testing.assert_allclose(res.image[sel], 1.0, atol=1e-3)


@pytest.mark.parametrize("mis", [False, True], ids=["brdf", "mis"])
def test_ggx_alpha_one_matches_its_closed_form_albedo(mis):
    # alpha = 1: D = 1/pi, G1(c) = 2c / (1 + c), so E(cos_o) = G1(cos_o) / (4 pi cos_o) * 2 pi int_0^1 G1(c) dc
    #          = 2 (1 - ln 2) / (1 + cos_o)
    res = render_reference(_furnace_scene(1.0), spp=32, seed=8, mis=mis)
    assert_clean(res)
    sel = res.coverage
    expect = 2.0 * (1.0 - math.log(2.0)) / (1.0 + np.clip(n_dot_v(res)[sel], 0.0, 1.0))
    got = res.image[sel]
    assert np.allclose(got[:, 0], got[:, 1]) and np.allclose(got[:, 0], got[:, 2])
    # per sample the weight lies in [0, 1]: std <= 0.5 / sqrt(32) per pixel, ~0.004 over the ~400 pixels
    assert abs(got[:, 0].mean() - expect.mean()) < 0.015, (got[:, 0].mean(), expect.mean())
    assert np.all(np.abs(got[:, 0] - expect) < 0.35)
    assert got.max() <= 1.0 + 1e-5 or mis


# ------------------------------------------------------------------------------------------ adaptive shading (002)

def assert_adaptive_clean(res):
    """assert_clean, plus finite AOVs, b_p >= 0 and at least one sample on every shaded pixel."""
    assert_clean(res)
    for name, a in res.aovs.items():
        assert np.isfinite(np.asarray(a, np.float64)).all(), name
    assert (res.aovs["b_p"] >= 0).all()
    shaded = res.aovs["shaded"] > 0
    assert (res.aovs["n_p"][shaded] >= 1).all()


@pytest.mark.parametrize("n_b, budget", [(16, 2.0), (1, 2.0), (16, 0.25)], ids=["nb16", "nb1", "budget0.25"])
def test_adaptive_under_the_city_sun(city, npf_table, n_b, budget):
    """The sun (~34,000) through the bandwidth pass and the hierarchy: finite everywhere; a budget below
    one sample per shaded pixel gives every shaded pixel one sample and says so."""
    from warpbw.pipeline import render_adaptive

    objs = [((-2.2, 0.0, 0.0), 1.0, "g"), ((0.0, 0.0, 0.0), 1.0, "l"), ((2.2, 0.0, 0.0), 1.0, "n")]
    s = scene(env=f'file = "{city}"', objects=objs, resolution=(64, 24), position=(0.0, 0.0, 6.0), fov=50.0,
              npf_table=npf_table)
    # the one warning expected, on its call (a blanket ignore of RuntimeWarning hid it and any other until session 82)
    with pytest.warns(RuntimeWarning, match=r"^budget 0\.25 is below 1 sample\(s\) per shaded pixel \(\d+ pixels to "
                      r"shade, \d+ samples\): every shaded pixel got 1") if budget < 1 else contextlib.nullcontext():
        res = render_adaptive(s, budget=budget, n_b=n_b, seed=2, mis=True)
    assert res.stats["allocation"]["over_budget"] == (budget < 1)
    ref = render_reference(s, spp=64, seed=5, mis=True)
    assert_adaptive_clean(res)
    n_cov = int(res.coverage.sum())
    alloc = res.stats["allocation"]
    if alloc["over_budget"]:
        assert np.all(res.aovs["n_p"][res.aovs["shaded"] > 0] == 1)
    else:
        # the plan spends the budget; pixels the up-sampling cannot reach from valid parents (depth edges)
        # are shaded on top of it, at their footprint's N_p
        assert alloc["planned_samples"] <= budget * n_cov + 1
        assert res.stats["samples"] <= 1.15 * budget * n_cov
    # the diffuse sphere's mean radiance against the reference (MIS, 64 spp): a gross-error check only, the
    # sun makes a 2-sample estimate of a 380-pixel mean scatter by ~15% (measured over seeds)
    lam = res.gbuffer.numpy("material") == 1
    np.testing.assert_allclose(res.image[lam].mean(axis=0), ref.image[lam].mean(axis=0), rtol=0.35)


def test_adaptive_zero_and_huge_curvature(tmp_path):
    """A flat quad (mesh curvature 0) and a 1 mm sphere 1 cm from the eye (curvature 1000 / m): finite
    bandwidths; the tiny sphere's curvature magnifies the light's bandwidth into the finest level."""
    from warpbw.pipeline import render_adaptive

    (tmp_path / "quad.obj").write_text("v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nf 1 2 3\nf 1 3 4\n")
    text = "\n".join([
        "[camera]", "position = [0.0, 0.0, 4.0]", "look_at = [0.0, 0.0, 0.0]", "fov = 40.0",
        "resolution = [40, 40]", "[environment]", 'procedural = "sky"',
        "[[object]]", 'mesh = "quad.obj"', 'material = "g"', "translate = [0.0, 0.0, -1.0]",
        "[[object]]", 'shape = "sphere"', "center = [0.0, 0.0, 3.99]", "radius = 0.001", 'material = "g"',
        "[material.g]", 'type = "ggx"', "alpha = 0.3", "specular = [0.9, 0.9, 0.9]"])
    res = render_adaptive(parse_scene(text, tmp_path, "curvature"), budget=2.0, seed=1)
    assert_adaptive_clean(res)
    curv = res.gbuffer.numpy("curvature")
    depth = res.gbuffer.numpy("depth")
    tiny = res.coverage & (depth < 0.1)
    flat = res.coverage & (depth > 1.0)
    assert tiny.sum() > 20 and flat.sum() > 20
    np.testing.assert_allclose(curv[tiny], 1000.0, rtol=1e-3)
    assert np.all(curv[flat] == 0.0)
    assert np.all(res.aovs["level"][tiny] == 0)
    assert np.median(res.aovs["b_p"][tiny]) > 10 * np.median(res.aovs["b_p"][flat])


def test_adaptive_grazing_silhouettes_are_finite(city):
    """cos theta_x -> 0 (P_x clamps at COS_X_MIN): finite b_p and levels on a horizon of grazing pixels."""
    from warpbw.pipeline import render_adaptive

    objs = [((0.0, -50.0, 0.0), 50.0, "g")] + hidden("l")
    s = scene(env=f'file = "{city}"', objects=objs, resolution=(32, 32), position=(0.0, 0.05, 0.0),
              look_at=(0.0, 0.05 - math.tan(math.radians(6.0)), -1.0), fov=16.0)
    res = render_adaptive(s, budget=2.0, seed=3, mis=True)
    assert_adaptive_clean(res)
    grazing = res.coverage & (n_dot_v(res) < GRAZING)
    assert grazing.sum() >= 20
    # P_x's 1 / cos theta_x (and the larger distance) raise the bandwidth towards the horizon
    steep = res.coverage & (n_dot_v(res) > 4 * GRAZING)
    assert steep.sum() >= 20
    assert np.median(res.aovs["b_p"][grazing]) > np.median(res.aovs["b_p"][steep])


# ------------------------------------------------------------------------------------------ planes under the city sun

PLANE_UNDER_CITY = """\
[camera]
position = [0.0, 0.4, 2.0]
look_at = [0.0, 0.0, -1.0]
fov = 50.0
resolution = [48, 32]

[environment]
file = "{city}"

[[object]]
shape = "plane"
size = 40.0
material = "m"

[material.m]
type = "cook-torrance"
roughness = 0.05
f0 = [0.9, 0.75, 0.4]
diffuse = [0.05, 0.04, 0.02]
{extra}"""


def test_planes_under_the_city_sun_every_method_is_finite(city, tmp_path):
    """A plane of side 40 seen from 0.4 above it: pixels down to grazing at the horizon (the coarsest mip level)
    under a sun of ~34,000, sampled by MIS: every method finite and non-negative; on a flat plane the filtered
    methods (all one model there) and the ground truth, independent estimators, agree on the mean."""
    from warpbw.filtering import ALL_METHODS, METHODS, prepare_filtering, render_filtering

    heights = np.random.default_rng(2).normal(size=(32, 32)) * 0.01
    write_exr(tmp_path / "map.exr", heights.astype(np.float32)[..., None], channels=["Y"])
    means = {}
    for extra in ('normal_map = "map.exr"\ntiling = 40.0\n', ""):
        s = parse_scene(PLANE_UNDER_CITY.format(city=city, extra=extra), tmp_path, "plane.toml")
        prep = prepare_filtering(s, ALL_METHODS)
        for m in ALL_METHODS:
            r = render_filtering(s, m, prepared=prep, spp=256, env_spp=64, seed=1)
            assert np.isfinite(r.image).all() and (r.image >= 0.0).all(), m
            assert (r.image[~r.coverage] == 0.0).all() and r.stats["non_finite_pixels"] == 0
            assert r.coverage.sum() > 500 and r.image[r.coverage].mean() > 0.0, m
            if m != "ground_truth":
                assert r.level[r.coverage].max() >= prep.mips["m"].levels - 1.5 or not extra, m  # reaches the top
            means[m] = float(r.image[r.coverage].mean())
    for m in METHODS:                                  # the flat plane (the last one rendered)
        assert means[m] == pytest.approx(means["ground_truth"], rel=0.03), (m, means)


@pytest.mark.parametrize("allocation", ["measured", "variance", "relative"])   # round 11: "relative" too
def test_adaptive_refuses_radiance_whose_square_overflows_the_bandwidth_pass(allocation):
    """The bandwidth pass sums squared radiance (Eq. 9's chi * w, the MIS second moment) in float32: a sky of
    1e20, within float32 (the reference renders it), squares to 1e40 > 3.4e38.  It once returned inf sigma2 (and,
    with allocation="variance", an inf variance AOV and N_p = n_max everywhere: 24x the budget); now a one-line
    error.  Below the limit (1e15: 1e30 squared) every AOV stays finite."""
    from warpbw.pipeline import render_adaptive

    objs = [((0.0, 0.0, 0.0), 1.0, "l")] + hidden("g")
    s = scene(env="constant = [1e20, 1e20, 1e20]", objects=objs, resolution=(24, 16))
    assert np.isfinite(render_reference(s, spp=4, seed=1).image).all()  # the radiance itself is within float32
    with pytest.raises(WarpbwError, match=r"extremes: the bandwidth pass's variance .*overflowed float32.*"
                                          r"the material's BRDF values"):
        render_adaptive(s, budget=2.0, seed=1, allocation=allocation)
    s = scene(env="constant = [1e15, 1e15, 1e15]", objects=objs, resolution=(24, 16))
    res = render_adaptive(s, budget=2.0, seed=1, allocation=allocation)
    assert_adaptive_clean(res)
    assert res.stats["samples"] <= 2.0 * res.coverage.sum()
    np.testing.assert_allclose(res.image[res.coverage], 0.8e15, rtol=1e-5)  # Lambert 0.8 under a constant sky


@pytest.mark.parametrize("allocation", ["measured", "variance", "relative"])
def test_adaptive_refuses_radiance_whose_square_underflows_the_bandwidth_pass(allocation):
    """Light is linear (README, "Exposure"): a sky k times dimmer renders k times the frame with the same decisions.
    The pass's squares of radiance (its variances) are float32: below sqrt(float32's smallest normal), 1.1e-19, they
    underflow.  Session 77: a probe of one texel of 1e4 over a sky of 1 scaled by k = 1e-25 gave the "measured"
    allocation other N_p than k = 1 and an image / k up to 0.8 of the brightest pixel away from the k = 1 frame,
    without a word (k = 1e-30: every allocation but "uniform"); now a one-line error, as for an overflow.  At
    k = 1e-15 (squares of 1e-30, normal) the decisions are those of k = 1 and the image k times its."""
    from warpbw.pipeline import prepare_scene, render_adaptive

    env = np.ones((16, 32, 3), np.float32)
    env[5, 10] = 1e4
    objs = [((0.0, 0.0, 0.0), 1.0, "l"), ((2.2, 0.0, 0.0), 1.0, "g")]

    def frame(k):
        prep = prepare_scene(scene(env="constant = [1.0, 1.0, 1.0]", objects=objs, resolution=(24, 12),
                                   position=(1.1, 0.0, 6.0), look_at=(1.1, 0.0, 0.0)))
        prep.env = envmap_from_array(env, scale=k, name="sun")   # the probe at exposure k
        return render_adaptive(prep, budget=4.0, seed=1, mis=True, allocation=allocation)

    one, dim = frame(1.0), frame(1e-15)
    for name in ("level", "n_p", "spp"):
        np.testing.assert_array_equal(dim.aovs[name], one.aovs[name], err_msg=name)
    np.testing.assert_allclose(dim.image / 1e-15, one.image, rtol=0, atol=1e-4 * float(one.image.max()))
    with pytest.raises(WarpbwError, match=r"extremes: the frame's radiance from the environment \(median "
                                          r"[0-9.e+-]+ over its lit pixels\) is below sqrt\(float32's smallest "
                                          r"normal\) = 1.1e-19"):
        frame(1e-25)


def test_the_underflow_refusal_lies_at_sqrt_of_float32_tiny_and_spares_the_uniform_allocation():
    """Round 11: the refusal of a dark frame reads the median of the pass's lit radiance against sqrt(float32's
    smallest normal) (``RADIANCE_UNDERFLOW_MAX``, computed here from numpy): a probe scaled to put that median 3 times
    below it is refused, 3 times above it renders; the "uniform" allocation, which reads no variance, renders at
    1e-25.  Truth: the median at exposure 1e-25, read off the refusal, times 1e25 is the frame's at 1 (light is
    linear).  The old test's 1e-25 and 1e-15 lay 6 and 4 decades from the threshold.  A black probe lights no pixel
    (median 0): it is no underflow, and renders black."""
    import re

    from warpbw.pipeline import prepare_scene, render_adaptive

    limit = math.sqrt(float(np.finfo(np.float32).tiny))
    env = np.ones((16, 32, 3), np.float32)
    env[5, 10] = 1e4
    objs = [((0.0, 0.0, 0.0), 1.0, "l"), ((2.2, 0.0, 0.0), 1.0, "g")]

    def frame(k, allocation="measured"):
        prep = prepare_scene(scene(env="constant = [1.0, 1.0, 1.0]", objects=objs, resolution=(24, 12),
                                   position=(1.1, 0.0, 6.0), look_at=(1.1, 0.0, 0.0)))
        prep.env = envmap_from_array(env, scale=k, name="sun")
        return render_adaptive(prep, budget=4.0, seed=1, mis=True, allocation=allocation)

    with pytest.raises(WarpbwError) as err:
        frame(1e-25)
    m1 = float(re.search(r"\(median ([0-9.e+-]+) over", str(err.value)).group(1)) / 1e-25
    with pytest.raises(WarpbwError, match="is below sqrt"):
        frame(limit / (3.0 * m1))
    assert frame(3.0 * limit / m1).coverage.any()
    assert frame(1e-25, "uniform").coverage.any()
    black = frame(0.0)   # no pixel lit (median 0): nothing underflows, and the frame is black (mutation round 12)
    assert black.coverage.any() and not black.image.any()


# ------------------------------------------------------------------------------------------ scene scale

@pytest.mark.parametrize("shape", ["sphere", "mesh"])
def test_a_scene_scaled_from_1e_minus_8_to_1e11_renders_the_same_images(city, tmp_path, shape):
    """Nothing in either renderer has a length scale: a GGX object under the city sun and its camera, scaled by
    s, give the reference and the adaptive image of s = 1 (within 1e-4 of the brightest pixel; measured 2e-5),
    and the same pixels shaded.  (A sphere once vanished at s = 1e-7 to an absolute epsilon; a mesh with file
    coordinates beyond 9e10 lost vertices to trimesh's merge.)"""
    import trimesh

    from warpbw.pipeline import prepare_scene, render_adaptive

    trimesh.creation.icosphere(subdivisions=3).export(tmp_path / "ico.obj")

    def render(s):
        obj = ('shape = "sphere"\ncenter = [0.0, 0.0, 0.0]\nradius = %r' % s if shape == "sphere"
               else 'mesh = "ico.obj"\nscale = %r' % s)
        text = "\n".join([
            "[camera]", f"position = [{0.3 * s!r}, {0.5 * s!r}, {4.0 * s!r}]", "look_at = [0.0, 0.0, 0.0]",
            "fov = 35.0", "resolution = [32, 32]", "[environment]", f'file = "{city}"',
            "[[object]]", obj, 'material = "g"',
            "[[object]]", 'shape = "sphere"', f"center = [0.0, 0.0, {40.0 * s!r}]", f"radius = {0.5 * s!r}",
            'material = "l"',   # behind the camera: the {ggx, lambert} kernels the module already compiled
            "[material.g]", 'type = "ggx"', "alpha = 0.15", "specular = [1.0, 1.0, 1.0]",
            "[material.l]", 'type = "lambert"', "albedo = 0.8"])
        prep = prepare_scene(parse_scene(text, tmp_path, "scaled"))
        return render_reference(prep, spp=8, seed=3, mis=True), render_adaptive(prep, budget=4.0, seed=3, mis=True)

    ref1, ada1 = render(1.0)
    assert ref1.coverage.sum() > 200 and 0.0 < ada1.stats["shaded_fraction"] < 1.0
    for s in (1e-8, 1e11):
        ref, ada = render(s)
        assert np.array_equal(ref.coverage, ref1.coverage), s
        np.testing.assert_allclose(ref.image, ref1.image, rtol=0, atol=1e-4 * ref1.image.max())
        assert ada.stats["shaded_fraction"] == ada1.stats["shaded_fraction"], s
        np.testing.assert_allclose(ada.image, ada1.image, rtol=0, atol=1e-4 * ada1.image.max())


def test_planes_scaled_from_1e_minus_30_to_1e30_render_the_same_images_and_beyond_are_refused(tmp_path):
    """Planes are intersected in float32 with lengths linear in the scene's scale: a plane scene scaled by s
    renders every method's image of s = 1 (measured: within 1.2e-6 of the brightest pixel from 1e-38 to 1e37);
    beyond float32's range, less its margins (warpbw.filtering.PLANE_REACH_MIN / _MAX), it is refused, naming
    the plane.  A scene scaled by 1e-200 once rendered an empty image with a warning that blamed the camera;
    without the check, 1e-45 loses 62% of the plane and 1e38 15% (session 39; the scene parser refuses 1e39)."""
    from warpbw.filtering import ALL_METHODS, PLANE_REACH_MAX, PLANE_REACH_MIN, plane_distance, prepare_filtering
    from warpbw.filtering import render_filtering

    u = (np.arange(8) + 0.5) / 8
    write_exr(tmp_path / "map.exr", (0.02 * np.sin(2 * np.pi * u)[None, :] * np.cos(2 * np.pi * u)[:, None])
              .astype(np.float32)[..., None], channels=["Y"])

    def plane_scene(k):
        text = plane_scene_toml(position=(0.0, 1.5 * k, 2.0 * k), size=2.0 * k, radiance=(3.0, 3.0, 3.0),
                                material_extra='normal_map = "map.exr"\nnormal_map_scale = 0.5\ntiling = 2\n')
        return parse_scene(text, tmp_path, "scaled.toml")

    def render(k):
        sc = plane_scene(k)
        prep = prepare_filtering(sc, ALL_METHODS)
        return {m: render_filtering(sc, m, prepared=prep, spp=64) for m in ALL_METHODS}

    ref = render(1.0)
    assert ref["fixed"].coverage.sum() > 200
    for k in (1e-30, 1e30):
        out = render(k)
        for m in ALL_METHODS:
            assert np.array_equal(out[m].coverage, ref[m].coverage), (k, m)
            np.testing.assert_allclose(out[m].image, ref[m].image, rtol=0, atol=1e-4 * ref[m].image.max())
    for k, word in ((1e-200, "larger"), (1e-40, "larger"), (2e37, "smaller")):
        with pytest.raises(WarpbwError, match=rf"^scaled\.toml: the camera is .* from the far corner of the plane "
                                              rf"size=.*outside the .* float32 ray-plane .*expected a {word} scene"):
            render_filtering(plane_scene(k), "fixed")
        with pytest.raises(WarpbwError, match="float32 ray-plane"):
            plane_distance(plane_scene(k))     # the depth test that hides spheres behind planes
    assert PLANE_REACH_MIN < 3.5e-30 and 3.5e30 < PLANE_REACH_MAX


def test_planes_translated_far_from_the_origin_render_the_same_until_float32_cannot_place_them(tmp_path):
    """A plane scene moved by t along x (camera, look_at and the plane's center): the aligned GMM's image of t = 0
    at t = 1e3 (float32 spacing 6e-5, 3e-5 of the plane's side); refused beyond COORD_SPACING_REL_MAX of it.
    Before the check the benchmark's dunes read 37 dB against their frame at the origin at t = 1e5 and 23 dB at
    1e7, exit 0."""
    from warpbw.errors import COORD_SPACING_REL_MAX, WarpbwError
    from warpbw.filtering import plane_distance, render_filtering

    u = (np.arange(8) + 0.5) / 8
    write_exr(tmp_path / "map.exr", (0.02 * np.sin(2 * np.pi * u)[None, :] * np.cos(2 * np.pi * u)[:, None])
              .astype(np.float32)[..., None], channels=["Y"])

    def plane_scene(t):
        text = plane_scene_toml(position=(t, 1.5, 2.0), material_extra='normal_map = "map.exr"\n'
                                'normal_map_scale = 0.5\ntiling = 2\n')
        text = text.replace("look_at = [0.0, 0.0, 0.0]", f"look_at = [{t!r}, 0.0, 0.0]")
        text = text.replace('shape = "plane"', f'shape = "plane"\ncenter = [{t!r}, 0.0, 0.0]')
        return parse_scene(text, tmp_path, "moved.toml")

    ref = render_filtering(plane_scene(0.0), "gmm_aligned")
    assert ref.coverage.sum() > 200
    out = render_filtering(plane_scene(1e3), "gmm_aligned")
    assert np.array_equal(out.coverage, ref.coverage)
    np.testing.assert_allclose(out.image, ref.image, rtol=0, atol=1e-3 * ref.image.max())
    for t in (1e5, 1e10):
        with pytest.raises(WarpbwError, match=r"^moved\.toml: the camera and the plane size=2.* lie up to .* from "
                                              r"the origin, where float32 spaces coordinates .*objects translated"):
            render_filtering(plane_scene(t), "fixed")
        with pytest.raises(WarpbwError, match="float32 spaces coordinates"):
            plane_distance(plane_scene(t))     # the depth test that hides spheres behind planes
    assert COORD_SPACING_REL_MAX < 1e-2


def test_adaptive_frame_spends_at_most_its_budget_when_the_up_sampling_cannot_fill_texels():
    """Under a constant environment the pass plans one texel at the top level, and the up-sampling cannot fill
    the texels at the silhouette, whose parents lie on the background: they are shaded too.  Before session 39
    the allocation did not count them, gave the planned texel the cap N_max = 256 x budget everywhere, and the
    frame spent 4.5x its budget (8.96 samples per covered pixel).  Now the allocation is spread over the
    hierarchy's own plan: the frame takes exactly the samples the allocation planned, on the texels it planned,
    within the budget.  Under a sky too."""
    from warpbw.pipeline import render_adaptive

    for env in ("constant = [1.0, 1.0, 1.0]", 'procedural = "sky"'):
        s = scene(env=env, objects=[((0.0, 0.0, 0.0), 1.0, "g")], alpha=0.5)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            res = render_adaptive(s, budget=2.0, seed=1)
        st, alloc = res.stats, res.stats["allocation"]
        levels = res.aovs["level"][res.coverage]
        shaded = sum(lv["shaded"] for lv in st["levels"])
        assert not alloc["over_budget"] and st["unplanned_shaded"] == 0, env
        assert (shaded, st["samples"]) == (alloc["planned_pixels"], alloc["planned_samples"]), env
        assert st["samples"] <= 2.0 * res.coverage.sum(), env
        if env.startswith("constant"):   # one level everywhere, one texel of it, and the silhouette's
            assert levels.min() == levels.max() and st["levels"][0]["shaded"] == 1 and shaded > 1, st["levels"]


def test_radiance_that_overflows_in_the_shading_is_refused_by_the_renderers_not_returned(tmp_path):
    """A sky of 1e33 on a mirror-like plane (roughness 1e-3) seen at a grazing angle: 447 of 512 pixels came back
    inf or NaN from render_filtering (only stats said so); the command line refused the image, Python returned it.
    The same sky of 1e18 renders finite."""
    from warpbw.filtering import METHODS, render_filtering

    def scene(c):
        env = f"[environment]\nconstant = [{c}, {c}, {c}]\n"
        return parse_scene(plane_scene_toml(roughness=1e-3, position=(0.0, 0.02, 2.0), size=40.0, resolution=(16, 16),
                                            fov=30.0, lights=0, environment=env, diffuse=None), tmp_path, "p.toml")

    for method in METHODS + ("ground_truth",):
        assert np.isfinite(render_filtering(scene(1e18), method, spp=64).image).all(), method
        with pytest.raises(WarpbwError, match="p.toml: .* pixels came out infinite or NaN"):
            render_filtering(scene(1e33), method, spp=64)


def test_a_frame_larger_than_the_memory_left_warns_naming_its_resolution(monkeypatch, tmp_path):
    """The system stops a process that runs out of memory without a word (no error, no image).  A frame whose
    estimate (FRAME_BYTES_PER_PIXEL times its pixels) passes the memory available warns first; one that fits, or
    where the available memory is unknown, does not.  Here the available memory is set by hand around the 40x30
    frame's estimate, and /proc/meminfo's reading is checked against the file itself."""
    from warpbw import pipeline

    text = ("[camera]\nposition = [0.0, 0.0, 3.0]\nlook_at = [0.0, 0.0, 0.0]\nfov = 50.0\nresolution = [40, 30]\n"
            "[environment]\nconstant = 1.0\n[[object]]\nshape = \"sphere\"\nradius = 0.8\nmaterial = \"m\"\n"
            "[material.m]\ntype = \"lambert\"\nalbedo = [0.5, 0.5, 0.5]\n")
    scene = parse_scene(text, tmp_path, "big.toml")
    for method, render in (("reference", lambda: render_reference(scene, spp=1)),
                           ("adaptive", lambda: render_adaptive(scene, budget=1.0))):
        need = pipeline.FRAME_BYTES_PER_PIXEL[method] * 40 * 30
        assert pipeline.frame_memory(40, 30, method) == need
        monkeypatch.setattr(pipeline, "available_memory", lambda: need - 1)
        with pytest.warns(RuntimeWarning, match=f"40x30 {method} frame takes about .* GB, but .* available"):
            render()
        for have in (need, None):
            monkeypatch.setattr(pipeline, "available_memory", lambda have=have: have)
            with warnings.catch_warnings():
                warnings.simplefilter("error")
                render()
    monkeypatch.undo()
    if os.path.exists("/proc/meminfo"):
        kb = next(int(ln.split()[1]) for ln in open("/proc/meminfo") if ln.startswith("MemAvailable:"))
        assert abs(pipeline.available_memory() - kb * 1024) < 2**30   # the same reading, a moment later


def test_a_probe_too_large_to_load_or_analyse_warns_before_the_work(monkeypatch, tmp_path):
    """Loading a probe peaks at LOAD_BYTES_PER_TEXEL, building its bandwidth map at ENV_BW_BYTES_PER_TEXEL plus
    ENV_BW_BYTES_FIXED (5 GB for an 8192x4096 probe, a minute): where the memory available is less, each warns
    first, naming the probe and its size, as a frame does (session 63).  One that fits, an unknown reading, and a
    map read from the cache say nothing.  The available memory is set by hand around each estimate."""
    from warpbw import bandwidth, envmap

    px = np.random.default_rng(5).random((16, 32, 3), dtype=np.float32) + 0.1
    write_exr(tmp_path / "probe.exr", px)
    load_need = envmap.LOAD_BYTES_PER_TEXEL * 16 * 32
    build_need = bandwidth.ENV_BW_BYTES_PER_TEXEL * 16 * 32 + bandwidth.ENV_BW_BYTES_FIXED
    cache = tmp_path / "cache"
    monkeypatch.setattr(envmap, "available_memory", lambda: load_need - 1)
    with pytest.warns(RuntimeWarning, match=r"loading probe\.exr \(32x16\) takes about 0\.0 GB, but 0\.0 GB .*"
                                            r"available: the system may stop it \(a smaller probe\)"):
        env = envmap.load_envmap(tmp_path / "probe.exr")
    monkeypatch.setattr(bandwidth, "available_memory", lambda: build_need - 1)
    with pytest.warns(RuntimeWarning, match=r"building the bandwidth map of probe\.exr \(32x16\) takes about 0\.2 "
                                            r"GB, .*the reference method does not build it"):
        assert bandwidth.env_bandwidth_map(env.pixels, env.name, cache=cache)[1] == "built"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert bandwidth.env_bandwidth_map(env.pixels, env.name, cache=cache)[1] == "cache"
        for have in (load_need, build_need, None):
            monkeypatch.setattr(envmap, "available_memory", lambda have=have: have)
            monkeypatch.setattr(bandwidth, "available_memory", lambda have=have: have)
            envmap.load_envmap(tmp_path / "probe.exr")
            if have != load_need:
                assert bandwidth.env_bandwidth_map(env.pixels, env.name, cache=tmp_path / f"c{have}")[1] == "built"


def test_a_mesh_whose_curvature_would_not_fit_warns_before_the_adaptive_method_derives_it(monkeypatch, tmp_path):
    """The bandwidth pass derives each mesh's curvature (adaptive method only), which took 479 MB at the peak for a
    1.1M-triangle mesh (the bunny subdivided twice; session 79) on top of what the scene holds, 430 bytes per
    triangle, and nothing estimated it.  Now CURVATURE_BYTES_PER_TRIANGLE times the largest mesh's triangles (trimesh's
    count, of the file written here) past the memory available warns before it is derived, naming the scene and the
    mesh; the reference method derives none and says nothing, nor does a fit or an unknown reading.  Of two meshes
    (a box beside the ball: mutation round 12) the estimate is the larger's, the one mesh derived at a time."""
    import trimesh

    from warpbw import pipeline

    trimesh.creation.icosphere(subdivisions=2).export(tmp_path / "ball.obj")
    trimesh.creation.box(extents=(0.3, 0.3, 0.3)).export(tmp_path / "box.obj")
    n = len(trimesh.load(tmp_path / "ball.obj", process=False).faces)
    assert n > 12   # the box's
    text = ("[camera]\nposition = [0.0, 0.0, 3.0]\nlook_at = [0.0, 0.0, 0.0]\nfov = 50.0\nresolution = [8, 8]\n"
            "[environment]\nconstant = 1.0\n[material.m]\ntype = \"lambert\"\nalbedo = [0.5, 0.5, 0.5]\n"
            '[[object]]\nmesh = "box.obj"\nmaterial = "m"\ntranslate = [1.5, 0.0, 0.0]\n'
            '[[object]]\nmesh = "ball.obj"\nmaterial = "m"\n')
    scene = parse_scene(text, tmp_path, "ball.toml")
    assert pipeline.CURVATURE_BYTES_PER_TRIANGLE >= 400
    # scaled up, so that the memory set around its estimate leaves the mesh's and the frame's to spare
    monkeypatch.setattr(pipeline, "CURVATURE_BYTES_PER_TRIANGLE", 10**6)
    need = 10**6 * n
    monkeypatch.setattr(pipeline, "available_memory", lambda: need - 1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        render_reference(scene, spp=1)
    with pytest.warns(RuntimeWarning, match=rf"^ball.toml: deriving the curvature of a mesh of {n:,} triangles takes "
                                            r"about .* GB, but .* available: the system may stop it \(a coarser mesh; "
                                            r"the reference method does not derive it\)$") as said:
        render_adaptive(scene, budget=1.0)
    assert len(said) == 1
    for have in (need, None):
        monkeypatch.setattr(pipeline, "available_memory", lambda have=have: have)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            render_adaptive(scene, budget=1.0)


@pytest.mark.parametrize("headers_say", [True, False])
def test_meshes_placed_beyond_the_memory_left_warn_before_loading_them(monkeypatch, tmp_path, headers_say):
    """A scene placing a mesh thousands of times ran for minutes, 13 MB a bunny, without a word (scene fuzzing,
    session 63).  MESH_BYTES_PER_TRIANGLE times the copies' triangles and MESH_FILE_BYTES_PER_TRIANGLE times the
    files' (trimesh's counts, of the files written here; session 79: a file's parse and first copy took twice the
    copies' estimate of a 1.1M-triangle mesh placed once) past the memory available warns once: before any is loaded
    where the files' face lines give the count, else
    after one copy of each file (a file whose format does not say, here by a stand-in); exactly that much memory,
    or an unknown reading, says nothing."""
    import trimesh

    from warpbw import pipeline
    from warpbw.io import mesh as mesh_io

    trimesh.creation.icosphere(subdivisions=2).export(tmp_path / "ball.obj")
    trimesh.creation.box().export(tmp_path / "box.obj")
    n_ball, n_box = (len(trimesh.load(tmp_path / f, process=False).faces) for f in ("ball.obj", "box.obj"))
    objects = "".join(f'[[object]]\nmesh = "{f}"\nmaterial = "m"\ntranslate = [{3.0 * i}, 0.0, -9.0]\n'
                      for i, f in enumerate(["ball.obj", "box.obj", "ball.obj", "ball.obj", "box.obj"]))
    text = ("[camera]\nposition = [0.0, 0.0, 3.0]\nlook_at = [0.0, 0.0, 0.0]\nfov = 50.0\nresolution = [8, 8]\n"
            "[environment]\nconstant = 1.0\n[material.m]\ntype = \"lambert\"\nalbedo = [0.5, 0.5, 0.5]\n" + objects)
    scene = parse_scene(text, tmp_path, "many.toml")
    triangles = 3 * n_ball + 2 * n_box
    need = pipeline.mesh_memory(triangles, n_ball + n_box)
    files = n_ball + n_box
    assert need == pipeline.MESH_BYTES_PER_TRIANGLE * triangles + pipeline.MESH_FILE_BYTES_PER_TRIANGLE * files
    loads, loaded_when_warned = [], []
    load_mesh, warn = mesh_io.load_mesh, pipeline.warn_if_short_of_memory
    monkeypatch.setattr(mesh_io, "load_mesh", lambda path, **kw: loads.append(path) or load_mesh(path, **kw))
    monkeypatch.setattr(pipeline, "warn_if_short_of_memory",
                        lambda *a, **kw: loaded_when_warned.append(len(loads)) or warn(*a, **kw))
    monkeypatch.setattr(pipeline, "available_memory", lambda: need - 1)
    if not headers_say:
        monkeypatch.setattr(mesh_io, "mesh_triangles", lambda path: None)
    with pytest.warns(RuntimeWarning, match=rf"placing 5 meshes \({triangles:,} triangles\) takes about .* GB, but "
                                            r".* available: the system may stop it \(fewer copies, or a coarser mesh\)"):
        prep = pipeline.prepare_scene(scene)
    assert prep.geometry.has_mesh and len(loads) == 5 and loaded_when_warned == [0 if headers_say else 2]
    for have in (need, None):
        monkeypatch.setattr(pipeline, "available_memory", lambda have=have: have)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            pipeline.prepare_scene(scene)
