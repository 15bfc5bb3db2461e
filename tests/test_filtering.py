"""Multiresolution reflectance filtering (004; warpbw.filtering): planes with normal-mapped Cook-Torrance
materials under directional lights and environments.

Truths are independent of the code under test: a numpy pinhole camera, ray-plane hit and Cook-Torrance
BRDF (flat map); the closed-form moment-matched component (filtering between texels); brute-force
quadrature over the hemisphere (NDF normalisation, a flat plane under a constant environment); a small sun
in the environment against the directional light of the same irradiance; every filtered method re-derived in
numpy from warpbw.filtering's documentation (footprint level, trilinear filter, lobes, shading); the ground
truth renderer (many rays per pixel against the finest normals) at the finest level; and finiteness at the
extremes.  Tiny resolutions and maps: the whole module runs in well under a minute on two cores.
"""
from __future__ import annotations

import copy
import math
import textwrap
from pathlib import Path

import numpy as np
import pytest
import warp as wp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import (PLANE_DIFFUSE, PLANE_F0, PLANE_LIGHT_DIR, PLANE_RADIANCE, numpy_camera_rays,
                      numpy_square_distance, plane_scene_toml)

from precompute.surfaces import hemispherical_scales
from warpbw.envmap import EnvMapData, envmap_from_array, eval_radiance
from warpbw.errors import WarpbwError
from warpbw.filtering import (ALL_METHODS, DIFFUSE_PICK_MIN, FLAT_SHADED_AS, MAX_LOBES, METHODS, MIN_COS,
                              MIN_GT_SPP, Lobes, PlaneData, diffuse_pick, fetch_gmm, gmm_ndf, lobes_env, lobes_ndf,
                              lobes_sample, normal_moment_mipmap, pair_offset, pair_uniforms, prepare_filtering,
                              render_filtering, sample_pdf, zoomed_camera)
from warpbw.io.exr import write_exr
from warpbw.scene import file_digest, parse_scene

def scene_with_map(tmp_path: Path, heights=None, normals=None, scale: float = 1.0, tiling: float = 1.0, **kw):
    if heights is not None:
        write_exr(tmp_path / "map.exr", np.asarray(heights, np.float32)[..., None], channels=["Y"])
        extra = f'normal_map = "map.exr"\nnormal_map_scale = {scale}\ntiling = {tiling}\n'
    else:
        write_exr(tmp_path / "map.exr", np.asarray(normals, np.float32), channels=["R", "G", "B"])
        extra = f'normal_map = "map.exr"\nnormal_map_kind = "normal"\ntiling = {tiling}\n'
    return parse_scene(plane_scene_toml(extra, **kw), tmp_path, "s.toml")


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("WARPBW_CACHE", str(tmp_path / "_cache"))


# ------------------------------------------------------------------------------------------ independent numpy truth

def numpy_flat_cook_torrance(position, fov, w, h, roughness, size=2.0, light_dir=PLANE_LIGHT_DIR):
    """Radiance of a flat Cook-Torrance plane (y = 0, normal +Y) under the directional light: Gaussian NDF of
    per-axis variance m^2/2 over projected normals, Schlick Fresnel, Lambert, G = 1 (warpbw.filtering docs)."""
    o, d = numpy_camera_rays(position, (0, 0, 0), fov, w, h)
    cov = np.isfinite(numpy_square_distance(o, d, size))
    n = np.array([0.0, 1.0, 0.0])
    wo = -d
    wi = np.asarray(light_dir, float) / np.linalg.norm(light_dir)
    hv = wi + wo
    hv /= np.linalg.norm(hv, axis=-1, keepdims=True)
    hxy2 = hv[..., 0] ** 2 + hv[..., 2] ** 2          # the projection on the plane
    var = roughness ** 2 / 2
    D = np.exp(-hxy2 / (2 * var)) / (2 * np.pi * var)
    u = np.clip(np.sum(wo * hv, -1), 0, None)
    f0 = np.asarray(PLANE_F0)
    F = f0 + (1 - f0) * (1 - u[..., None]) ** 5
    cos_o = wo @ n
    spec = F * (D / (4 * cos_o))[..., None]
    diff = np.asarray(PLANE_DIFFUSE) / np.pi * (1 - F) * max(wi @ n, 0.0)
    return (spec + diff) * np.asarray(PLANE_RADIANCE), cov


def colour_error(img, ref, mask):
    """Mean per-pixel Euclidean colour error normalised by the reference's mean colour norm."""
    e = np.linalg.norm(img - ref, axis=-1)[mask]
    return float(e.mean() / np.linalg.norm(ref, axis=-1)[mask].mean())


# ------------------------------------------------------------------------------------------ flat map

@pytest.mark.parametrize("roughness", [0.05, 0.3])
def test_flat_map_shades_as_the_plain_cook_torrance_brdf(tmp_path, roughness):
    """With an all-zero height map every method's own kernel (the GMMs' fitted mipmaps included) shades the plain
    BRDF; without a normal map the plane shades it too, with no GMM fitted (the scene needs none)."""
    s = parse_scene(plane_scene_toml(roughness=roughness), Path.cwd(), "s.toml")
    zero = scene_with_map(tmp_path, heights=np.zeros((8, 8)), tiling=3, roughness=roughness)
    ref, cov = numpy_flat_cook_torrance((0.0, 1.5, 2.0), 40.0, 24, 16, roughness)
    prep = prepare_filtering(s, ALL_METHODS)
    assert prep.notes["m"]["shaded_as"] == FLAT_SHADED_AS and not any(k.startswith("gmm") for k in prep.notes["m"])
    prep_zero = prepare_filtering(zero, ALL_METHODS)
    assert prep_zero.notes["m"]["gmm_aligned"]["components"] == 4 and "shaded_as" not in prep_zero.notes["m"]
    for scene, pr in ((s, prep), (zero, prep_zero)):
        for m in METHODS:
            r = render_filtering(scene, m, prepared=pr)
            assert np.array_equal(r.coverage, cov), m
            assert np.allclose(r.image[cov], ref[cov], rtol=2e-4, atol=1e-6), (m, np.abs(r.image[cov] - ref[cov]).max())
            assert np.all(r.image[~cov] == 0)
            flat_stage = "plain_brdf:planes_without_normal_map" in r.stats["stages"]
            assert flat_stage == (scene is s) and any(st.endswith(m) for st in r.stats["stages"]) == (scene is zero)
    if roughness < 0.3:
        return  # a sharp highlight varies within a pixel: the ground truth's pixel average differs from it
    # the ground truth averages over the pixel: equal where the BRDF is smooth over it, within 1%
    g = render_filtering(s, "ground_truth", spp=64, prepared=prep)
    interior = cov & np.roll(cov, 1, 0) & np.roll(cov, -1, 0) & np.roll(cov, 1, 1) & np.roll(cov, -1, 1)
    assert colour_error(g.image, ref, interior) < 0.01


def test_ground_truth_on_a_planes_outline_is_the_planes_own_radiance():
    """A pixel the plane covers in part (share 0.2-0.8, from a numpy 16 x 16 grid of rays): the ground truth
    averages over the rays that hit the plane, so it is the plain BRDF's radiance there (smooth over a pixel at
    roughness 0.3), not that radiance scaled by the share (blended with the black beyond)."""
    s = parse_scene(plane_scene_toml(roughness=0.3, size=1.0), Path.cwd(), "s.toml")
    ref, cov = numpy_flat_cook_torrance((0.0, 1.5, 2.0), 40.0, 24, 16, 0.3, size=1.0)
    g = render_filtering(s, "ground_truth", spp=64)
    assert np.array_equal(g.coverage, cov)
    share = np.zeros(cov.shape)
    for jx, jy in np.ndindex(16, 16):
        o, d = numpy_camera_rays((0.0, 1.5, 2.0), (0, 0, 0), 40.0, 24, 16, jitter=((jx + 0.5) / 16, (jy + 0.5) / 16))
        share += np.isfinite(numpy_square_distance(o, d, 1.0))
    outline = cov & (share / 256 > 0.2) & (share / 256 < 0.8)
    assert outline.sum() >= 5
    assert colour_error(g.image, ref, outline) < 0.02


def test_two_lights_add_up():
    one = parse_scene(plane_scene_toml(lights=1), Path.cwd(), "s.toml")
    two = parse_scene(plane_scene_toml(lights=2), Path.cwd(), "s.toml")
    only_second = parse_scene(plane_scene_toml(lights=2).replace(
        f"direction = {list(PLANE_LIGHT_DIR)}\nradiance = {list(PLANE_RADIANCE)}",
        f"direction = {list(PLANE_LIGHT_DIR)}\nradiance = [0.0, 0.0, 0.0]"), Path.cwd(), "s.toml")
    a = render_filtering(one, "fixed").image
    b = render_filtering(two, "fixed").image
    c = render_filtering(only_second, "fixed").image
    assert np.abs(c).max() > 0
    assert np.allclose(a + c, b, rtol=1e-5, atol=1e-7)


# ------------------------------------------------------------------------------------------ filtering the moments

def _random_gmm(rng, K):
    a = rng.dirichlet(np.ones(K))
    a[rng.random(K) < 0.25] = 0.0       # some empty components
    if a.sum() == 0:
        a[0] = 1.0
    a /= a.sum()
    mu = rng.uniform(-0.6, 0.6, (K, 2))
    s2 = rng.uniform(1e-4, 0.02, K)
    return a, mu, s2


def _moments(a, mu, s2):
    """The stored form: (a, a mu, a E|n|^2), E|n|^2 = 2 s^2 + |mu|^2 for an isotropic 2D Gaussian of per-axis
    variance s^2 (precompute.gmm_mipmap's module docstring)."""
    return np.concatenate([a[:, None], a[:, None] * mu, (a * (2 * s2 + (mu ** 2).sum(-1)))[:, None]], -1)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2 ** 31 - 1), f=st.floats(0.0, 1.0), lam=st.floats(0.0, 1.0))
def test_filtering_two_texels_is_the_moment_matched_component(seed, f, lam):
    rng = np.random.default_rng(seed)
    K = 3
    t0, t1 = _random_gmm(rng, K), _random_gmm(rng, K)
    q0, q1 = _moments(*t0), _moments(*t1)
    level0 = np.stack([q0, q1])[None].astype(np.float32)                 # (1, 2, K, 4): two texels in a row
    level1 = (0.5 * (q0 + q1))[None, None].astype(np.float32)            # the 1x1 parent: their box average
    # s between the two texel centres (0.5 and 1.5): bilinear weights (1 - f, f) at level 0; level 1 is one texel
    got = fetch_gmm([level0, level1], 0.5 + f, 0.5, lam)[0]
    w0 = (1 - lam) * (1 - f) + lam * 0.5
    w1 = (1 - lam) * f + lam * 0.5
    for k in range(K):
        # closed form (004 Sec. 4.2 / Appendix): the isotropic Gaussian with the mean and second moment E|n|^2 of
        # the two weighted components, each of which has E|n|^2 = 2 s^2 + |mu|^2
        a = w0 * t0[0][k] + w1 * t1[0][k]
        if a < 1e-6:
            assert got[k, 0] < 1e-6
            continue
        mu = (w0 * t0[0][k] * t0[1][k] + w1 * t1[0][k] * t1[1][k]) / a
        second = (w0 * t0[0][k] * (2 * t0[2][k] + t0[1][k] @ t0[1][k])
                  + w1 * t1[0][k] * (2 * t1[2][k] + t1[1][k] @ t1[1][k])) / a
        s2 = (second - mu @ mu) / 2
        assert got[k, 0] == pytest.approx(a, rel=1e-5, abs=1e-7)
        assert np.allclose(got[k, 1:3], mu, atol=2e-5)
        assert got[k, 3] == pytest.approx(max(s2, 1e-6), rel=2e-3, abs=2e-6)


def test_fetch_wraps_around_and_empty_components_are_zero():
    q = np.zeros((1, 2, 2, 4), np.float32)
    q[0, 0, 0] = _moments(np.array([1.0]), np.array([[0.2, 0.0]]), np.array([0.01]))[0]
    q[0, 1, 0] = _moments(np.array([1.0]), np.array([[-0.2, 0.0]]), np.array([0.01]))[0]
    levels = [q, q.mean(axis=1, keepdims=True)]
    # s = 0 is half way between texel 1 (wrapped, centre -0.5) and texel 0 (centre 0.5): the two means cancel
    got = fetch_gmm(levels, 0.0, 0.5, 0.0)[0]
    assert got[0, 0] == pytest.approx(1.0) and abs(got[0, 1]) < 1e-6
    # the spread of the two means is variance: total 2 (0.01) + 0.2^2, per axis half of it
    assert got[0, 3] == pytest.approx(0.01 + 0.04 / 2, rel=1e-4)
    assert np.all(got[1] == 0) and np.all(np.isfinite(got))


def test_trilinear_fetch_of_a_tiled_mipmap_is_the_brute_force_filter():
    # a 4x4 map of random mixtures, its 2x2 and 1x1 levels box averages; at random (s, t, level) the renderer's
    # fetch must equal the moment-matched mixture under the filter written out here independently: texel j of
    # level l centred at (j + 1/2) 2^l finest texels, a tent of half-width 2^l per axis (bilinear), the map
    # tiling (distances taken modulo the level's width), and a linear blend of levels floor(lam) and +1.
    rng = np.random.default_rng(5)
    K, n = 3, 4
    q0 = np.stack([np.stack([_moments(*_random_gmm(rng, K)) for _ in range(n)]) for _ in range(n)])
    levels = [q0, q0.reshape(2, 2, 2, 2, K, 4).mean(axis=(1, 3)), q0.mean(axis=(0, 1))[None, None]]
    pts = np.column_stack([rng.uniform(-3.0, 9.0, 40), rng.uniform(-3.0, 9.0, 40), rng.uniform(0.0, 1.999, 40)])
    got = fetch_gmm([q.astype(np.float32) for q in levels], pts[:, 0], pts[:, 1], pts[:, 2])

    def tent(x, size, period):
        # the tent around every periodic image of each texel centre (a 1x1 level is its own neighbour)
        c = (np.arange(period) + 0.5) * size
        images = np.arange(-8, 9)[:, None] * period * size
        return np.maximum(1.0 - np.abs(x - c[None, :] - images) / size, 0.0).sum(axis=0)

    for (s, t, lam), g in zip(pts, got):
        acc = _trilinear_moments(levels, s, t, lam, lambda x, l, n_l, n: tent(x, 2.0 ** l, n_l))
        _assert_fetched_as_filtered(g, acc, abs_a=1e-7)


def _trilinear_moments(levels: list, s: float, t: float, lam: float, weights) -> np.ndarray:
    """(K, 4) stored moments at finest coordinates (s, t), blended linearly between levels floor(lam) and the next
    (the last level alone beyond it); ``weights(x, l, n_l, n)`` gives the (n_l,) weights of level l's texels along
    an axis of n finest texels at coordinate x."""
    H, W = levels[0].shape[:2]
    last = len(levels) - 1
    l0 = min(int(np.floor(lam)), last)
    acc = np.zeros(levels[0].shape[2:])
    for l, wl in ((l0, 1.0 - (lam - l0)), (min(l0 + 1, last), lam - l0)):
        q = levels[l]
        w = weights(t, l, q.shape[0], H)[:, None] * weights(s, l, q.shape[1], W)[None, :]
        acc += wl * np.einsum("rc,rckm->km", w, q)
    return acc


def _assert_fetched_as_filtered(g: np.ndarray, acc: np.ndarray, abs_a: float, where=()):
    """The fetch's recovered (a, mu, s2) per component, ``g`` (K, 4), against the filtered moments ``acc`` (K, 4)
    recovered here: a component of no weight stays of no weight."""
    for k in range(len(acc)):
        if acc[k, 0] < 1e-6:
            assert g[k, 0] < 1e-6, where
            continue
        mu = acc[k, 1:3] / acc[k, 0]
        assert g[k, 0] == pytest.approx(acc[k, 0], rel=1e-5, abs=abs_a), where
        assert np.allclose(g[k, 1:3], mu, atol=2e-5), where
        assert g[k, 3] == pytest.approx(max((acc[k, 3] / acc[k, 0] - mu @ mu) / 2, 1e-6), rel=2e-3, abs=2e-6), where


def test_trilinear_fetch_of_a_map_of_no_power_of_two_side_tiles_with_the_maps_period():
    # a 5 x 7 map (levels 3 x 4, 2 x 2, 1 x 1: the border clips the last texel of each axis at levels 1-2).  The map
    # tiles, so every fetch must repeat with its period (7 columns, 5 rows), whatever level; and between texel
    # centres it is the bilinear (hat) interpolation of the level's texels, each centred on the finest texels it
    # covers (a clipped texel: [j 2^l, n)), periodic with period n -- np.interp with period=n, written out here.
    # (The fetch took the level's period n_l 2^l, 8 columns and 6 rows at level 1: from the second tile on it read
    # other texels, the mean of the fetch 0.24 projected units off.)
    rng = np.random.default_rng(11)
    K, H, W = 2, 5, 7
    levels = [np.stack([np.stack([_moments(*_random_gmm(rng, K)) for _ in range(w)]) for _ in range(h)])
              for h, w in ((5, 7), (3, 4), (2, 2), (1, 1))]
    levels32 = [q.astype(np.float32) for q in levels]
    pts = np.column_stack([rng.uniform(0.0, W, 60), rng.uniform(0.0, H, 60), rng.uniform(0.0, 3.0, 60)])
    base = fetch_gmm(levels32, pts[:, 0], pts[:, 1], pts[:, 2])
    for tx, ty in ((1, 0), (0, 1), (3, -2), (-1, 6)):
        moved = fetch_gmm(levels32, pts[:, 0] + tx * W, pts[:, 1] + ty * H, pts[:, 2])
        assert np.allclose(moved, base, atol=1e-5), (tx, ty, np.abs(moved - base).max())

    def hats(x, l, n_l, n):
        # (n_l,) weights of the level's texels at finest coordinate x: periodic linear interpolation between centres
        lo = np.arange(n_l) * 2.0 ** l
        centres = 0.5 * (lo + np.minimum(lo + 2.0 ** l, n))
        return np.array([np.interp(x, centres, np.eye(n_l)[j], period=n) for j in range(n_l)])

    for (s, t, lam), g in zip(pts, base):
        _assert_fetched_as_filtered(g, _trilinear_moments(levels, s, t, lam, hats), abs_a=1e-6, where=(s, t, lam))


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2 ** 31 - 1), m=st.floats(0.05, 0.3))
def test_mixture_ndf_is_projected_area_normalised(seed, m):
    rng = np.random.default_rng(seed)
    a, mu, s2 = _random_gmm(rng, 4)
    mu *= 0.5 / 0.6                                    # means within 0.5 of the pole: tails stay on the disk
    params = np.concatenate([a[:, None], mu, s2[:, None]], -1)
    # brute force over the hemisphere in spherical coordinates: int D(h) cos(theta) sin(theta) dtheta dphi
    nt, nphi = 400, 400
    th = (np.arange(nt) + 0.5) * (np.pi / 2) / nt
    ph = (np.arange(nphi) + 0.5) * 2 * np.pi / nphi
    T, P = np.meshgrid(th, ph, indexing="ij")
    h = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(-1, 3)
    D = gmm_ndf(params, m * m / 2, h).reshape(nt, nphi)
    total = np.sum(D * np.cos(T) * np.sin(T)) * (np.pi / 2 / nt) * (2 * np.pi / nphi)
    # = the mixture's mass on the unit disk of projected normals (1 but for the tails beyond the horizon),
    # here by sampling the Gaussians directly
    n = 200_000
    comp = rng.choice(len(a), size=n, p=a)
    x = mu[comp] + rng.normal(size=(n, 2)) * np.sqrt(s2[comp] + m * m / 2)[:, None]
    on_disk = float(np.mean(np.sum(x * x, -1) < 1.0))
    assert total == pytest.approx(on_disk, abs=0.005)
    assert total > 0.9


# ------------------------------------------------------------------------------------------ box-filtered normal mipmap

def test_normal_moment_mipmap_means_over_clipped_footprints():
    rng = np.random.default_rng(3)
    n = rng.normal(size=(5, 7, 3))
    n[..., 2] = np.abs(n[..., 2]) + 0.5
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    lv = normal_moment_mipmap(n)
    assert [x[0].shape[:2] for x in lv] == [(5, 7), (3, 4), (2, 2), (1, 1)]
    # level 1, texel (2, 3): the clipped footprint rows 4, columns 6 only; level 2 texel (0, 1): rows 0-3, cols 4-6
    assert np.allclose(lv[1][0][2, 3], n[4, 6], atol=1e-6)
    block = n[0:4, 4:7].reshape(-1, 3)
    assert np.allclose(lv[2][0][0, 1], block.mean(0), atol=1e-6)
    assert np.allclose(lv[2][1][0, 1], [np.mean(block[:, 0] ** 2), np.mean(block[:, 1] ** 2),
                                        np.mean(block[:, 0] * block[:, 1])], atol=1e-6)
    assert np.allclose(lv[-1][0][0, 0], n.reshape(-1, 3).mean(0), atol=1e-6)



@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), h=st.integers(1, 19), w=st.integers(1, 19))
def test_normal_moment_mipmap_of_any_size_is_the_mean_over_each_clipped_footprint(seed, h, w):
    """Dense brute force over every texel of every level, any map size: levels ceil-halve to 1x1, and texel (i, j)
    of level l holds the mean normal and the mean (x^2, y^2, xy) of the projected normals over finest rows
    [i 2^l, (i + 1) 2^l) and columns [j 2^l, (j + 1) 2^l), clipped at the map's border (module docstring)."""
    rng = np.random.default_rng(seed)
    n = rng.normal(size=(h, w, 3))
    n[..., 2] = np.abs(n[..., 2]) + 0.2
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    q = np.concatenate([n, n[..., :1] ** 2, n[..., 1:2] ** 2, n[..., :1] * n[..., 1:2]], -1)
    lv = normal_moment_mipmap(n)
    shapes = [(h, w)]
    while shapes[-1] != (1, 1):
        shapes.append((-(-shapes[-1][0] // 2), -(-shapes[-1][1] // 2)))
    assert [m.shape[:2] for m, _ in lv] == shapes
    for l, (mean, second) in enumerate(lv):
        f = 2 ** l
        want = np.array([[q[i * f:(i + 1) * f, j * f:(j + 1) * f].reshape(-1, 6).mean(0)
                          for j in range(mean.shape[1])] for i in range(mean.shape[0])])
        np.testing.assert_allclose(np.concatenate([mean, second], -1), want, atol=2e-7)

# ------------------------------------------------------------------------------------------ against the ground truth

def _bumps(size=16):
    u = (np.arange(size) + 0.5) / size
    U, V = np.meshgrid(u, u)
    return 0.02 * np.sin(2 * np.pi * U) * np.cos(2 * np.pi * V)


def test_finest_level_every_method_agrees_with_the_ground_truth(tmp_path):
    # a smooth 16x16 map seen close: a pixel covers under one texel, so every method filters at level ~0
    s = scene_with_map(tmp_path, heights=_bumps(), scale=1.0, position=(0.0, 0.6, 0.3), size=0.25,
                       resolution=(32, 24), roughness=0.15, fov=20.0)
    prep = prepare_filtering(s, ALL_METHODS)
    gt = render_filtering(s, "ground_truth", spp=64, prepared=prep)
    errs = {}
    for m in METHODS:
        r = render_filtering(s, m, prepared=prep)
        assert r.level[r.coverage].max() <= 0.0, m        # magnified: at most level 0
        errs[m] = colour_error(r.image, gt.image, r.coverage)
    assert max(errs.values()) < 0.03, errs
    # ...and the map matters: shading it flat differs from the ground truth by far more than that
    flat = parse_scene(plane_scene_toml(position=(0.0, 0.6, 0.3), size=0.25, resolution=(32, 24), roughness=0.15,
                                  fov=20.0),
                       tmp_path, "s.toml")
    assert colour_error(render_filtering(flat, "fixed").image, gt.image, gt.coverage) > 0.1


def test_a_map_without_finer_levels_stays_at_level_0_or_below():
    s = parse_scene(plane_scene_toml(material_extra="", position=(0.0, 2.0, 0.0001), resolution=(16, 16), fov=30.0),
                    Path.cwd(), "s.toml")
    # no normal map: one 1x1 level spread over the whole plane, a pixel far smaller than it: level -1
    r = render_filtering(s, "toksvig")
    assert r.coverage.any() and np.all(r.level[r.coverage] == -1.0)


def test_level_doubles_with_distance(tmp_path):
    h = np.zeros((64, 64))
    s = scene_with_map(tmp_path, heights=h, position=(0.0, 4.0, 0.01), size=2.0, resolution=(16, 16), fov=20.0)
    prep = prepare_filtering(s, ("fixed",))
    # looking straight down from height y with fov 20 deg over 16 pixels: a pixel spans 2 y tan(10 deg) / 16
    # of the plane, i.e. 64 / 2 of that in texels at the centre; the level is log2 of that + the LOD bias
    lv = []
    for z in (1.0, 2.0):
        cam = zoomed_camera(s.camera, z)
        r = render_filtering(s, "fixed", prepared=prep, camera=cam, lod_bias=0.0)
        lv.append(r.level[8, 8])
        expect = math.log2(2 * cam.position[1] * math.tan(math.radians(10)) / 16 * 32)
        assert r.level[8, 8] == pytest.approx(expect, abs=0.05)
        biased = render_filtering(s, "fixed", prepared=prep, camera=cam)
        assert biased.level[8, 8] == pytest.approx(expect - 0.5 * math.log2(3.0), abs=0.05)
    assert lv[1] - lv[0] == pytest.approx(1.0, abs=0.05)


def test_gmm_beats_the_fixed_brdf_far_away(tmp_path):
    s = scene_with_map(tmp_path, heights=hemispherical_scales(32, scales_across=4), scale=0.5, tiling=4,
                       position=(0.0, 2.0, 2.0), size=2.0, resolution=(24, 16), roughness=0.1)
    prep = prepare_filtering(s, ALL_METHODS)
    gt = render_filtering(s, "ground_truth", spp=256, prepared=prep)
    err = {m: colour_error(render_filtering(s, m, prepared=prep).image, gt.image, gt.coverage)
           for m in ("gmm_aligned", "fixed")}
    # far away the fixed BRDF on the averaged normal is far too shiny; the mixture is not (the ordering
    # against Toksvig and LEAN is the benchmark's business: on a map this small the margins are thin)
    assert err["gmm_aligned"] < 0.5 * err["fixed"], err


@pytest.mark.parametrize("towards", ["highlight", "elsewhere"])
def test_normals_of_one_gaussian_seen_whole_shade_as_the_fine_brdf_averaged_over_them(tmp_path, towards):
    """004 Sec. 3: a footprint's normals distributed as N(mu, s^2) (projected normal space, s^2 per axis) shade as
    the fine-scale BRDF averaged over them -- the Gaussian NDF of variance m^2/2 about each normal convolved with
    N(mu, s^2) is one Gaussian of variance s^2 + m^2/2 -- and Lambert with the mean normal.  A 16 x 16 map of
    normals drawn from N((0.15, -0.1), 0.1^2), one pixel far enough that it filters at the coarsest level (the whole
    map, one component fitted to all 256 normals), a light at the mean normal's mirror direction or elsewhere: the
    GMM methods (K = 1) and LEAN are within 1.5% of numpy's average of the fine BRDF over the map's 256 normals
    plus Lambert on the lift of their mean (measured: GMM 0.03% at the highlight and 0.7% elsewhere, LEAN 0.02% and
    0.4% -- the sample is not exactly Gaussian); the fixed BRDF on the mean normal is 3.7-13% off.  Seen failing
    (GMM off by 2.7-10% and more): the recovered s^2 not divided by the dimension, the builder storing 004's printed
    a (s^2 + |mu|^2), the lobe without the roughness's m^2/2, the GMM fit's projected y mirrored; and (LEAN off by
    6.7-24%) the box-filtered mipmap's normals with y mirrored."""
    rng = np.random.default_rng(2)
    mu, s, m = np.array([0.15, -0.1]), 0.1, 0.4
    p = mu + s * rng.standard_normal((16, 16, 2))
    n = np.concatenate([p, np.sqrt(1 - np.sum(p * p, -1, keepdims=True))], -1).reshape(-1, 3)
    pos = (0.0, 6.0, 4.0)
    d = numpy_camera_rays(pos, (0, 0, 0), 40.0, 1, 1)[1][0, 0]
    wo = np.array([-d[0], d[2], -d[1]])               # the plane's frame: x = +X, y = -Z, z = +Y
    pm = n[:, :2].mean(0)
    n_mean = np.array([pm[0], pm[1], math.sqrt(1 - pm @ pm)])
    wi = 2 * (wo @ n_mean) * n_mean - wo if towards == "highlight" else np.array([-0.3, 0.5, 0.8])
    wi /= np.linalg.norm(wi)
    write_exr(tmp_path / "map.exr", n.reshape(16, 16, 3).astype(np.float32), channels=["R", "G", "B"])
    extra = 'normal_map = "map.exr"\nnormal_map_kind = "normal"\ngmm_components = 1\n'
    sc = parse_scene(plane_scene_toml(extra, roughness=m, position=pos, resolution=(1, 1), radiance=(1.0, 1.0, 1.0),
                                      light_dir=[float(wi[0]), float(wi[2]), float(-wi[1])]), tmp_path, "s.toml")
    h = (wi + wo) / np.linalg.norm(wi + wo)
    F = np.asarray(PLANE_F0) + (1 - np.asarray(PLANE_F0)) * (1 - max(h @ wo, 0.0)) ** 5
    D = np.mean(np.exp(-np.sum((h[:2] - n[:, :2]) ** 2, 1) / m ** 2) / (np.pi * m * m))
    truth = F * D / (4 * wo[2]) + np.asarray(PLANE_DIFFUSE) / np.pi * (1 - F) * max(n_mean @ wi, 0.0)
    prep = prepare_filtering(sc, METHODS)
    err = {}
    for method in METHODS:
        r = render_filtering(sc, method, prepared=prep)
        assert r.coverage[0, 0] and r.level[0, 0] == 4.0, (method, r.level)     # the 1 x 1 level
        err[method] = float(np.max(np.abs(r.image[0, 0] / truth - 1)))
    assert max(err[k] for k in ("gmm_aligned", "gmm_unaligned", "lean")) < 0.015, err
    assert err["fixed"] > 0.03, err


def test_a_map_of_one_tilted_normal_shades_as_the_plain_brdf_about_it_at_the_least_roughness(tmp_path):
    """Every texel the same tilted normal: every level holds a delta, so every method at every level is the plain
    BRDF about that normal (004 Sec. 3 with s^2 = 0), down to the least roughness a material takes (1e-3: a lobe
    of per-axis variance 5e-7).  The light at the normal's mirror direction (the NDF's peak) and a pixel at levels
    0.3, 1.7 and 4 (the 1 x 1 level): within 2e-3 of numpy's Cook-Torrance about the normal, here 0.05% at most.
    The GMM's recovered s^2 is floored at VARIANCE_FLOOR = 1e-6, which the shading subtracts again (``gmm_ndf`` on
    ``fetch_gmm``'s output does not: a third of this peak).  Seen failing: the floor left in the GMM's lobes
    (GMM 0.33x), Toksvig without its unit-length tolerance (its float32 mean normal read as spread: 0.89x)."""
    nt = np.array([0.2, 0.1, math.sqrt(0.95)])
    write_exr(tmp_path / "map.exr", np.broadcast_to(nt, (16, 16, 3)).astype(np.float32), channels=["R", "G", "B"])
    pos, m = (0.0, 6.0, 4.0), 1e-3
    d = numpy_camera_rays(pos, (0, 0, 0), 40.0, 1, 1)[1][0, 0]
    wo = np.array([-d[0], d[2], -d[1]])                # the plane's frame: x = +X, y = -Z, z = +Y
    wi = 2 * (wo @ nt) * nt - wo
    extra = 'normal_map = "map.exr"\nnormal_map_kind = "normal"\ngmm_components = 2\n'
    sc = parse_scene(plane_scene_toml(extra, roughness=m, position=pos, resolution=(1, 1), radiance=(1.0, 1.0, 1.0),
                                      light_dir=[float(wi[0]), float(wi[2]), float(-wi[1])], diffuse=None),
                     tmp_path, "s.toml")
    h = (wi + wo) / np.linalg.norm(wi + wo)
    F = np.asarray(PLANE_F0) + (1 - np.asarray(PLANE_F0)) * (1 - h @ wo) ** 5
    var = m * m / 2
    truth = F * math.exp(-np.sum((h[:2] - nt[:2]) ** 2) / (2 * var)) / (2 * math.pi * var) / (4 * wo[2])
    prep = prepare_filtering(sc, METHODS)
    for zoom, level in ((0.05, 0.28), (0.13, 1.66), (1.0, 4.0)):
        cam = zoomed_camera(sc.camera, zoom)
        for method in METHODS:
            r = render_filtering(sc, method, prepared=prep, camera=cam)
            assert r.level[0, 0] == pytest.approx(level, abs=0.01)
            assert np.max(np.abs(r.image[0, 0] / truth - 1)) < 2e-3, (method, zoom, r.image[0, 0], truth)


# ------------------------------------------------------------------------------------------ every method, re-derived

LOD_BIAS_DOC = -0.5 * math.log2(3.0)   # warpbw.filtering: the mip filter then blurs as much as the pixel's box


def _numpy_bilinear(q, s, t, l):
    """Level-l texels around finest coordinates (s, t) (texel j centred at (j + 1/2) 2^l), bilinear weights, the
    map tiling: the (P, ...) weighted sum of q's (h, w, ...) texels."""
    f = 2.0 ** l
    x, y = s / f - 0.5, t / f - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = x - x0, y - y0
    h, w = q.shape[:2]
    out = 0.0
    for dc, dr, wt in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
        r = (y0.astype(int) + dr) % h
        c = (x0.astype(int) + dc) % w
        out = out + wt.reshape(wt.shape + (1,) * (q.ndim - 2)) * q[r, c]
    return out


def _numpy_trilinear(levels, s, t, lam):
    """Blend of levels floor(lam) and the next (clamped at the coarsest), lam per point."""
    top = len(levels) - 1
    l0 = np.floor(lam).astype(int)
    fl = lam - l0
    out = np.zeros((s.size,) + levels[0].shape[2:])
    for l in np.unique(l0):
        sel = l0 == l
        f = fl[sel].reshape((-1,) + (1,) * (out.ndim - 1))
        out[sel] = ((1 - f) * _numpy_bilinear(levels[l], s[sel], t[sel], l)
                    + f * _numpy_bilinear(levels[min(l + 1, top)], s[sel], t[sel], min(l + 1, top)))
    return out


# Anisotropic footprints (warpbw.filtering, max_anisotropy > 1), as its documentation states them: the radius of one
# probe is never below the level-0 radius 2^-LOD_BIAS (a probe finer than level 0 adds nothing), and the probe count
# is ceil(s1 / r - 1e-4) (the slack keeps an exact ratio such as s1 = 2 r from rounding up to one probe more).
LEVEL0_RADIUS_DOC = 2.0 ** -LOD_BIAS_DOC
PROBE_SLACK_DOC = 1e-4


def numpy_footprint(scene, zoom, levels, max_anisotropy=1):
    """Per pixel of the zoomed camera, from the rays through the pixel's centre and the next pixel right and down
    (warpbw.filtering's footprint): st (H, W, 2) the centre's finest-texel coordinates, lam (H, W) the fractional
    level, n (H, W) the probe count and offsets (H, W, max_anisotropy, 2) each probe's offset from st (zero beyond
    n), and bound (H, W) which of the radius's three terms binds where n > 1 ("s2", "cap", "level 0"; "" else).
    Isotropic: lam = log2 of J's larger column + the LOD bias.  Anisotropic: s1 >= s2 and u the singular values
    and major axis (numpy's SVD of J = [jx jy]); r = max(s2, s1 / N, the level-0 radius); n = clamp(ceil(s1 / r -
    slack), 1, N); when n > 1, lam = log2(r) + the LOD bias and the probes sit at (j - (n - 1) / 2) d u, d =
    sqrt((s1^2 - r^2) / (n^2 - 1)).  lam is clamped to [-1, levels - 1]."""
    cam = zoomed_camera(scene.camera, zoom)
    (pl,), mat = scene.objects, scene.materials["m"]
    W, H = cam.width, cam.height
    o, d = numpy_camera_rays(cam.position, cam.look_at, cam.fov, W, H)
    _, dx = numpy_camera_rays(cam.position, cam.look_at, cam.fov, W, H, jitter=(1.5, 0.5))
    _, dy = numpy_camera_rays(cam.position, cam.look_at, cam.fov, W, H, jitter=(0.5, 1.5))
    mh, mw = levels[0].shape[:2]

    def st_of(ray):                                 # finest-texel coordinates of the hit on the plane y = 0
        p = o + (-o[1] / ray[..., 1])[..., None] * ray
        return np.stack([(p[..., 0] / pl.size + 0.5) * mw, (p[..., 2] / pl.size + 0.5) * mh], -1) * mat.tiling

    st0 = st_of(d)
    jx, jy = st_of(dx) - st0, st_of(dy) - st0
    rho = np.maximum(np.linalg.norm(jx, axis=-1), np.linalg.norm(jy, axis=-1))
    lam = np.log2(rho) + LOD_BIAS_DOC
    n = np.ones((H, W), int)
    offsets = np.zeros((H, W, max_anisotropy, 2))
    bound = np.full((H, W), "", dtype=object)
    if max_anisotropy > 1:
        U, S, _ = np.linalg.svd(np.stack([jx, jy], -1))          # J's columns: the offsets right and down
        s1, s2, u = S[..., 0], S[..., 1], U[..., :, 0]
        terms = np.stack([s2, s1 / max_anisotropy, np.full_like(s1, LEVEL0_RADIUS_DOC)], -1)
        r = terms.max(-1)
        n = np.clip(np.ceil(s1 / r - PROBE_SLACK_DOC).astype(int), 1, max_anisotropy)
        many = n > 1
        lam = np.where(many, np.log2(r) + LOD_BIAS_DOC, lam)
        step = np.sqrt(np.maximum(s1 ** 2 - r ** 2, 0.0) / np.maximum(n ** 2 - 1, 1))
        for j in range(max_anisotropy):
            pos = np.where(j < n, j - (n - 1) / 2, 0.0) * step
            offsets[:, :, j] = np.where(many, pos, 0.0)[..., None] * u
        bound[many] = np.array(["s2", "cap", "level 0"], dtype=object)[terms.argmax(-1)][many]
    return st0, np.clip(lam, -1.0, len(levels) - 1), n, offsets, bound


def numpy_box_mipmap(normals):
    """The box-filtered normal mipmap the docstring of warpbw.filtering describes, for a map whose sides are powers of
    two (every footprint whole): level l's texel is the mean over its 2^l x 2^l block of the unit normals n and of
    the projected second moments (n_x^2, n_y^2, n_x n_y).  Written here so that the re-derivation does not take its
    mipmap from ``normal_moment_mipmap``, the renderer's own (a mistake there would be in both images: coarse levels
    transposed on a square map passed the comparison)."""
    n = np.asarray(normals, np.float64)
    h, w = n.shape[:2]
    assert h & (h - 1) == 0 and w & (w - 1) == 0, (h, w)
    m2 = np.stack([n[..., 0] ** 2, n[..., 1] ** 2, n[..., 0] * n[..., 1]], -1)
    levels, f = [], 1
    while True:
        hl, wl = max(h // f, 1), max(w // f, 1)
        fh, fw = h // hl, w // wl
        levels.append(tuple(q.reshape(hl, fh, wl, fw, 3).mean(axis=(1, 3)) for q in (n, m2)))
        if (hl, wl) == (1, 1):
            return levels
        f *= 2


def numpy_filtered_render(scene, method, normals, gmm_levels, zoom, max_anisotropy=1):
    """What warpbw.filtering's docstring says a filtered method renders, written out in numpy (float64) for one
    plane: per pixel the footprint (``numpy_footprint``: isotropic, its larger side rho from the neighbouring
    pixels' rays, lam = log2(rho) + the LOD bias; or n probes along its major axis); the method's stored
    quantities trilinearly filtered at max(lam, 0) at each probe and averaged over them, the lobes recovered from
    the averages; below level 0 a blend towards the fine-scale lobe at the bilinear finest normal; 004 Sec. 3's
    Cook-Torrance (Gaussian NDF, Schlick, no shadowing) plus Lambert on the lobes' mean normals under each
    directional light.  Returns (image, level)."""
    cam = zoomed_camera(scene.camera, zoom)
    mat = scene.materials["m"]
    W, H = cam.width, cam.height
    _, d = numpy_camera_rays(cam.position, cam.look_at, cam.fov, W, H)
    box = numpy_box_mipmap(normals)
    st0, lam_px, n_px, offsets, _ = numpy_footprint(scene, zoom, [b[0] for b in box], max_anisotropy)
    s, t, lam = st0[..., 0].ravel(), st0[..., 1].ravel(), np.maximum(lam_px, 0.0).ravel()
    n_probes, offsets = n_px.ravel(), offsets.reshape(-1, max_anisotropy, 2)

    def filtered(levels):                           # trilinear at max(lam, 0), averaged over each pixel's probes
        acc = 0.0
        for j in range(max_anisotropy):
            f = _numpy_trilinear(levels, s + offsets[:, j, 0], t + offsets[:, j, 1], lam)
            w = (j < n_probes) / n_probes
            acc = acc + w.reshape((-1,) + (1,) * (f.ndim - 1)) * f
        return acc

    rv = mat.roughness ** 2 / 2
    mean = filtered([b[0].astype(np.float64) for b in box])        # (P, 3)
    lobes = []                                       # (a, mx, my, sxx, syy, sxy), each (P,)
    if method.startswith("gmm"):
        q = filtered([g.astype(np.float64) for g in gmm_levels[method]])   # (P, K, 4)
        for k in range(q.shape[1]):
            a = q[:, k, 0]
            ok = a > 1e-8
            mx, my = np.where(ok, q[:, k, 1] / np.where(ok, a, 1), 0), np.where(ok, q[:, k, 2] / np.where(ok, a, 1), 0)
            # per-axis s^2 of the stored second moment a E|n|^2 = a (2 s^2 + |mu|^2)
            s2 = np.maximum((np.where(ok, q[:, k, 3] / np.where(ok, a, 1), 0) - mx * mx - my * my) / 2, 1e-6)
            var = s2 - 1e-6 + rv                     # the builder's floor is numerical: taken off again
            lobes.append((np.where(ok, a, 0), mx, my, var, var, 0 * var))
    else:
        ln = np.linalg.norm(mean, axis=-1)
        n = mean / ln[:, None]
        var = np.full_like(ln, rv)
        if method == "toksvig":
            var = var + np.maximum(1 - ln - 1e-6, 0) / ln       # Toksvig: (1 - |n|) / |n| per axis
        if method == "lean":
            m2 = filtered([b[1].astype(np.float64) for b in box])
            mx, my = mean[:, 0], mean[:, 1]
            sxx, syy = m2[:, 0] - mx * mx + rv, m2[:, 1] - my * my + rv
            lobes.append((np.ones_like(ln), mx, my, sxx, syy, m2[:, 2] - mx * my))
        else:
            lobes.append((np.ones_like(ln), n[:, 0], n[:, 1], var, var, 0 * var))
    w_fine = np.clip(-lam_px.ravel(), 0, 1)
    lobes = [(lobe[0] * (1 - w_fine),) + lobe[1:] for lobe in lobes]
    nf = _numpy_bilinear(box[0][0].astype(np.float64), s, t, 0)
    nf /= np.linalg.norm(nf, axis=-1, keepdims=True)
    lobes.append((w_fine, nf[:, 0], nf[:, 1], np.full_like(s, rv), np.full_like(s, rv), 0 * s))
    def frame(v):                                   # the plane's tangent frame: x = +X, y = -Z, z = +Y
        return np.stack([v[..., 0], -v[..., 2], v[..., 1]], -1)

    wo = frame(-d.reshape(-1, 3))
    img = np.zeros((s.size, 3))
    for light in scene.lights:
        wi = frame(np.asarray(light.direction, float) / np.linalg.norm(light.direction))
        hv = wi + wo
        hv /= np.linalg.norm(hv, axis=-1, keepdims=True)
        D = lamb = 0.0
        for a, mx, my, sxx, syy, sxy in lobes:
            det = sxx * syy - sxy * sxy
            ex, ey = hv[:, 0] - mx, hv[:, 1] - my
            D = D + a * np.exp(-0.5 * (syy * ex * ex - 2 * sxy * ex * ey + sxx * ey * ey) / det) / (
                2 * np.pi * np.sqrt(det))
            nz = np.sqrt(np.maximum(1 - mx * mx - my * my, 0))
            lamb = lamb + a * np.maximum(mx * wi[0] + my * wi[1] + nz * wi[2], 0)
        F = np.asarray(mat.f0) + (1 - np.asarray(mat.f0)) * (1 - np.clip(np.sum(wo * hv, -1), 0, None))[:, None] ** 5
        c = F * (D / (4 * wo[:, 2]))[:, None] + np.asarray(mat.diffuse) / np.pi * (1 - F) * lamb[:, None]
        img += np.where((wi[2] > 0) & (wo[:, 2] > 1e-4), 1.0, 0.0)[:, None] * c * np.asarray(light.radiance)
    return img.reshape(H, W, 3), lam_px


# A camera at 20 degrees above the plane (the isotropic re-derivation's 45-degree one lowered, same distance): a
# pixel's footprint is 1 / sin(20 deg) ~ 2.9 times longer than wide at the image centre, more towards the horizon.
GRAZING_DEG = 20.0
CAMERA_DISTANCE = math.hypot(2.0, 2.0)


def grazing_position(elevation_deg=GRAZING_DEG, distance=CAMERA_DISTANCE):
    el = math.radians(elevation_deg)
    return (0.0, distance * math.sin(el), distance * math.cos(el))


def _scales_with_gmm_files(tmp_path, position):
    """The scales (32x32, tiling 4) under two lights, seen from ``position``; the GMM mipmaps built here (the
    aligned one given to the scene as its gmm file, the unaligned one as the renderer builds it).  Returns the
    scene, its finest normals, the GMM levels per method and the prepared mipmaps."""
    from precompute.gmm_mipmap import build_gmm_mipmap, write_gmm_mipmap
    from precompute.surfaces import height_to_normals

    h = hemispherical_scales(32, scales_across=4)
    mips = {"gmm_aligned": build_gmm_mipmap(h, scale=0.5, progress=False),
            "gmm_unaligned": build_gmm_mipmap(h, scale=0.5, unaligned=True, progress=False)}
    write_exr(tmp_path / "map.exr", np.asarray(h, np.float32)[..., None], channels=["Y"])
    write_gmm_mipmap(tmp_path / "scales.gmm", mips["gmm_aligned"], "map.exr", file_digest(tmp_path / "map.exr"))
    s = parse_scene(plane_scene_toml('normal_map = "map.exr"\nnormal_map_scale = 0.5\ntiling = 4\ngmm = "scales.gmm"\n',
                               roughness=0.1, position=position, resolution=(24, 16), lights=2)
                    .replace(f"diffuse = {list(PLANE_DIFFUSE)}", "diffuse = [0.5, 0.4, 0.3]"),   # both terms count
                    tmp_path, "s.toml")
    prep = prepare_filtering(s, METHODS)
    assert prep.notes["m"]["gmm_aligned"]["origin"] == "file"
    # the record says which file, and the clustering's seed (two fits of one map differ by it)
    assert prep.notes["m"]["gmm_aligned"]["file"] == str(tmp_path / "scales.gmm")
    assert prep.notes["m"]["gmm_aligned"]["seed"] == 0 and "file" not in prep.notes["m"]["gmm_unaligned"]
    return s, height_to_normals(h, 0.5), {k: v.levels for k, v in mips.items()}, prep


# The re-derivation and the renderer agree to float32 precision: levels within this, images within this relative
# to the reference's mean colour norm.
LEVEL_ATOL = 1e-4
IMAGE_RTOL = 1e-3


def _assert_as_documented(s, prep, normals, gmm_levels, zoom, max_anisotropy=None):
    kw = {} if max_anisotropy is None else {"max_anisotropy": max_anisotropy}
    for m in METHODS:
        r = render_filtering(s, m, prepared=prep, camera=zoomed_camera(s.camera, zoom), **kw)
        ref, lam = numpy_filtered_render(s, m, normals, gmm_levels, zoom, **kw)
        cov = r.coverage
        assert np.allclose(r.level[cov], lam[cov], atol=LEVEL_ATOL), (m, zoom, kw)
        scale = np.linalg.norm(ref[cov], axis=-1).mean()
        err = np.abs(r.image[cov] - ref[cov]).max() / scale
        assert err < IMAGE_RTOL, (m, zoom, kw, err)
    return lam[cov]


def test_every_filtered_method_is_what_its_documentation_says(tmp_path):
    # scales under two lights, from magnified (level < 0) to several levels down: each method's image must be
    # the numpy re-derivation above, from the same mipmaps, to float32 precision
    s, normals, gmm_levels, prep = _scales_with_gmm_files(tmp_path, (0.0, 2.0, 2.0))
    levels_seen = []
    for zoom in (0.2, 1.0, 4.0):
        lam = _assert_as_documented(s, prep, normals, gmm_levels, zoom)
        levels_seen.append((lam.min(), lam.max()))
    assert levels_seen[0][0] < -0.5 and levels_seen[-1][1] > 2.5, levels_seen   # magnified ... several levels down


# (max_anisotropy, zoom) at the grazing camera: 16 with pixels from under two texels wide (some n = 1, some at the
# level-0 radius, magnified) and with pixels several texels wide (r = s2, 2 to 4 probes); 2 and 4, where the cap
# s1 / N binds on most pixels.
ANISOTROPIC_CASES = ((16, 0.25), (16, 1.0), (2, 0.5), (4, 0.25))


def test_every_filtered_method_with_anisotropic_footprints_is_what_its_documentation_says(tmp_path):
    # the grazing camera: each method's image with up to N probes along the footprint's major axis must be the
    # numpy re-derivation (footprint from numpy's SVD of J), to the isotropic comparison's precision
    s, normals, gmm_levels, prep = _scales_with_gmm_files(tmp_path, grazing_position())
    box = [b[0] for b in numpy_box_mipmap(normals)]
    bounds, probes = set(), set()
    for max_aniso, zoom in ANISOTROPIC_CASES:
        lam = _assert_as_documented(s, prep, normals, gmm_levels, zoom, max_aniso)
        _, _, n, _, bound = numpy_footprint(s, zoom, box, max_aniso)
        cov = render_filtering(s, "fixed", prepared=prep, camera=zoomed_camera(s.camera, zoom)).coverage
        bounds |= set(bound[cov & (n > 1)])
        probes |= set(n[cov])
        if (max_aniso, zoom) == ANISOTROPIC_CASES[0]:
            assert lam.min() < 0.0 and (n[cov] == 1).any()    # magnified pixels, isotropic, in the same image
    # every regime of the footprint was compared: n = 1, the radius bound by s2, by the cap and by level 0
    assert bounds == {"s2", "cap", "level 0"} and {1, 2, 3, 4} <= probes, (bounds, probes)


def test_a_footprint_that_is_not_elongated_takes_one_probe_whatever_max_anisotropy(tmp_path):
    # looking straight down, the image plane is parallel to the plane: a pixel's footprint is a square (J a
    # scaled rotation, s1 = s2), so n = 1 and max_anisotropy 16 renders exactly what 1 does -- at zooms where a
    # pixel covers about 1, 4 and 16 texels (r = the level-0 radius, then s2)
    s, _, _, prep = _scales_with_gmm_files(tmp_path, (0.0, 2.0, 1e-4))
    for zoom in (0.25, 1.0, 4.0):
        cam = zoomed_camera(s.camera, zoom)
        for m in METHODS:
            one = render_filtering(s, m, prepared=prep, camera=cam, max_anisotropy=1)
            many = render_filtering(s, m, prepared=prep, camera=cam, max_anisotropy=16)
            assert one.coverage.sum() >= 64, (m, zoom)     # at zoom 4 the plane fills the central 8x8
            assert np.array_equal(one.image, many.image) and np.array_equal(one.level, many.level), (m, zoom)
            assert (one.stats["max_anisotropy"], many.stats["max_anisotropy"]) == (1, 16)


def test_max_anisotropy_1_is_the_default_and_16_changes_a_grazing_view(tmp_path):
    s, _, _, prep = _scales_with_gmm_files(tmp_path, grazing_position())
    cam = zoomed_camera(s.camera, 1.0)
    for m in METHODS:
        default = render_filtering(s, m, prepared=prep, camera=cam)
        one = render_filtering(s, m, prepared=prep, camera=cam, max_anisotropy=1)
        assert np.array_equal(default.image, one.image) and np.array_equal(default.level, one.level), m
        assert default.stats["max_anisotropy"] == 1
        # ...and the option is not inert: at 20 degrees every pixel's footprint is elongated enough for probes
        many = render_filtering(s, m, prepared=prep, camera=cam, max_anisotropy=16)
        cov = one.coverage
        assert np.all(np.any(many.image[cov] != one.image[cov], axis=-1)), m
        assert np.all(many.level[cov] < one.level[cov]), m     # filtered at the minor axis: a finer level


# Against the ground truth at the grazing camera (dunes, 64x64 tiled twice, pixels covering 2 to 10 texels):
# anisotropic footprints bring each method's error to at most this fraction of the isotropic one (measured:
# 0.45 to 0.73 over toksvig, lean and gmm_aligned at zooms 2 and 3), and the gain is many times the ground
# truth's own noise (measured: 0.003 to 0.006 of the mean colour, against gains of 0.03 to 0.4).
ANISOTROPIC_ERROR_RATIO = 0.85
GAIN_OVER_NOISE = 5.0


def test_anisotropic_footprints_are_closer_to_the_ground_truth_at_a_grazing_angle(tmp_path):
    from precompute.surfaces import dunes
    from warpbw.bench_filtering import colour_error as bench_colour_error

    s = scene_with_map(tmp_path, heights=dunes(64), scale=1.0, tiling=2, roughness=0.15,
                       position=grazing_position(distance=1.0), resolution=(32, 24))
    prep = prepare_filtering(s, ("gmm_aligned",))
    for zoom in (2.0, 3.0):
        cam = zoomed_camera(s.camera, zoom)
        gt = render_filtering(s, "ground_truth", spp=256, prepared=prep, camera=cam)
        cov = gt.coverage
        # the ground truth's noise: a second, independently seeded one differs by sqrt(2) times it
        noise = bench_colour_error(render_filtering(s, "ground_truth", spp=256, seed=1, prepared=prep,
                                                    camera=cam).image, gt.image, cov) / math.sqrt(2)
        levels = render_filtering(s, "fixed", prepared=prep, camera=cam).level[cov]
        assert cov.sum() > 100 and levels.min() > 0.5, (zoom, cov.sum(), levels.min())   # several texels per pixel
        for m in ("toksvig", "lean", "gmm_aligned"):
            err = {n: bench_colour_error(render_filtering(s, m, prepared=prep, camera=cam, max_anisotropy=n).image,
                                         gt.image, cov) for n in (1, 16)}
            assert err[16] < ANISOTROPIC_ERROR_RATIO * err[1], (m, zoom, err)
            assert err[1] - err[16] > GAIN_OVER_NOISE * noise, (m, zoom, err, noise)


# ------------------------------------------------------------------------------------------ extremes

def _spike(n=9):
    h = np.zeros((n, n))
    h[n // 2, n // 2] = 1.0
    return h


EXTREMES = {
    "flat map": dict(heights=np.zeros((8, 8))),
    "single spike": dict(heights=_spike(), scale=0.5),
    "1x1 map": dict(heights=np.full((1, 1), 0.3)),
    "non-power-of-two": dict(heights=np.random.default_rng(1).random((5, 7)) * 0.05),
    "normals at 89 degrees": dict(normals=np.broadcast_to(
        [math.sin(math.radians(89)), 0.0, math.cos(math.radians(89))], (4, 4, 3)).copy()),
    "normals at 89 degrees, mixed": dict(normals=np.stack(np.broadcast_arrays(
        np.where(np.arange(4)[:, None] % 2 == 0, 1.0, -1.0) * math.sin(math.radians(89)), np.zeros((4, 4)),
        np.full((4, 4), math.cos(math.radians(89)))), -1)),
}


@pytest.mark.parametrize("name", list(EXTREMES))
def test_extremes_give_finite_images(tmp_path, name):
    s = scene_with_map(tmp_path, tiling=3, resolution=(16, 12), **EXTREMES[name])
    prep = prepare_filtering(s, ALL_METHODS)
    for zoom in (1.0, 4.0):
        cam = zoomed_camera(s.camera, zoom)
        for m in ALL_METHODS:
            r = render_filtering(s, m, prepared=prep, camera=cam, spp=MIN_GT_SPP)
            assert r.coverage.any(), (name, m, zoom)
            assert np.all(np.isfinite(r.image)) and np.all(r.image >= 0), (name, m, zoom)
            assert np.all(np.isfinite(r.level)), (name, m, zoom)


# ------------------------------------------------------------------------------------------ bad input

def test_bad_normal_maps_name_the_material_key(tmp_path):
    (tmp_path / "map.exr").write_bytes(b"this is not an image")
    s = parse_scene(plane_scene_toml('normal_map = "map.exr"\n'), tmp_path, "s.toml")
    with pytest.raises(WarpbwError, match=r"^s\.toml: \[material\.m\]\.normal_map: .*not an image"):
        prepare_filtering(s, ("fixed",))
    rgb = np.random.default_rng(0).random((4, 4, 3)).astype(np.float32)
    write_exr(tmp_path / "map.exr", rgb, channels=["R", "G", "B"])
    with pytest.raises(WarpbwError, match=r"\[material\.m\]\.normal_map: .*RGB image .* height field"):
        prepare_filtering(s, ("fixed",))
    h = np.zeros((4, 4, 1), np.float32)
    h[1, 2] = np.nan
    write_exr(tmp_path / "map.exr", h, channels=["Y"])
    with pytest.raises(WarpbwError, match=r"\[material\.m\]\.normal_map: .*NaN"):
        prepare_filtering(s, ("fixed",))


def test_scene_problems_are_clear_errors(tmp_path):
    s = parse_scene(plane_scene_toml().replace('radiance = [3.0, 2.5, 2.0]', 'radiance = [1.0, 1.0, 1.0]')
                    + '\n[[object]]\nshape = "sphere"\nradius = 1.0\nmaterial = "p"\n[material.p]\n'
                    'type = "lambert"\nalbedo = 0.5\n', tmp_path, "s.toml")
    with pytest.raises(WarpbwError, match=r"\[\[object\]\] #2: not a plane, .*planes only .*use warpbw render"):
        prepare_filtering(s, ("fixed",))
    # a scene without a plane is told so (it was told that "a scene with planes renders planes only")
    s = parse_scene(plane_scene_toml().split("[[object]]")[0] + '[[object]]\nshape = "sphere"\nradius = 1.0\n'
                    'material = "m"\n[material.m]\ntype = "lambert"\nalbedo = 0.5\n', tmp_path, "s.toml")
    with pytest.raises(WarpbwError, match=r"^s\.toml: no \[\[object\]\] is a plane"):
        prepare_filtering(s, ("fixed",))
    s = parse_scene(plane_scene_toml(), tmp_path, "s.toml")
    with pytest.raises(WarpbwError, match="filter method 'blur'"):
        render_filtering(s, "blur")
    with pytest.raises(WarpbwError, match=">= 64"):
        render_filtering(s, "ground_truth", spp=8)



def test_a_filtering_scene_renders_in_the_scenes_place(tmp_path):
    """render_filtering(prepare_filtering(s), m) was an AttributeError ('FilteringScene' object has no attribute
    'environment'), where warpbw.pipeline.render_reference takes its PreparedScene there: now it is the prepared
    scene, on its own device, and renders as prepared= does."""
    s = scene_with_map(tmp_path, heights=_bumps(8), scale=0.5, resolution=(16, 16))
    prep = prepare_filtering(s, ("lean", "gmm_aligned"))
    for m in ("lean", "gmm_aligned"):
        r = render_filtering(prep, m, seed=3)
        assert r.coverage.any() and np.array_equal(r.image, render_filtering(s, m, seed=3, prepared=prep).image), m
    assert np.array_equal(render_filtering(prep, "fixed", prepared=prep, device="cpu").image,
                          render_filtering(s, "fixed").image)
    # the result reads as RenderResult's: its per-pixel maps by name
    assert render_filtering(prep, "lean").aovs["level"] is not None
    with pytest.raises(WarpbwError, match=r"^prepared: given a FilteringScene as the scene too"):
        render_filtering(prep, "lean", prepared=prepare_filtering(s, ("lean",)))
    with pytest.raises(WarpbwError, match=r"^scene: expected a Scene .* or a FilteringScene .*got str"):
        render_filtering("s.toml", "lean")
    with pytest.raises(WarpbwError, match=r"^prepared: expected a FilteringScene .*got Scene"):
        render_filtering(s, "lean", prepared=s)


def test_a_filtering_scene_prepared_for_another_scene_is_refused(tmp_path):
    """A FilteringScene of another scene was used as it is: a plane material it lacks was a bare KeyError, and a
    changed map, light or environment rendered the old one without a word.  What it does not hold (a material's
    roughness, the camera) is read from the scene: such a scene renders with it."""
    text = plane_scene_toml('normal_map = "map.exr"\nnormal_map_scale = 0.5\n', resolution=(16, 16))
    write_exr(tmp_path / "map.exr", _bumps(8)[..., None].astype(np.float32), channels=["Y"])
    s = parse_scene(text, tmp_path, "s.toml")
    prep = prepare_filtering(s, ("lean",))

    def refused(other, match, method="lean"):
        with pytest.raises(WarpbwError, match=match):
            render_filtering(parse_scene(other, tmp_path, "o.toml"), method, prepared=prep)

    refused(text.replace('material = "m"', 'material = "rock"').replace("[material.m]", "[material.rock]"),
            r"^prepared: prepared for s\.toml, with planes of material m; this scene has planes of material rock; "
            r"expected prepare_filtering of this scene \(o\.toml\)$")
    refused(text.replace("normal_map_scale = 0.5", "normal_map_scale = 2.0"),
            r"^prepared: prepared for s\.toml, where \[material\.m\] has normal_map_scale = 0\.5; this scene's has "
            r"2\.0; expected")
    refused(text.replace("radiance = [3.0, 2.5, 2.0]", "radiance = [1.0, 1.0, 1.0]"),
            r"^prepared: prepared for s\.toml, with \[\[light\]\]s directional .*radiance \[3\.0, 2\.5, 2\.0\]; "
            r"this scene has directional .*radiance \[1\.0, 1\.0, 1\.0\]; expected")
    refused(plane_scene_toml('normal_map = "map.exr"\nnormal_map_scale = 0.5\n', resolution=(16, 16),
                             environment="[environment]\nconstant = [1.0, 1.0, 1.0]\n"),
            r"^prepared: prepared for s\.toml, with \[environment\] none; this scene has constant \[1\.0, 1\.0, "
            r"1\.0\].*; expected")
    # round 11: a GMM method's mipmap holds the material's components too
    gprep = prepare_filtering(s, ("gmm_aligned",))
    with pytest.raises(WarpbwError, match=r"^prepared: prepared for s\.toml, where \[material\.m\] has gmm_components "
                                          r"= \d+; this scene's has 3; expected"):
        three = text.replace("normal_map_scale = 0.5", "normal_map_scale = 0.5\ngmm_components = 3")
        render_filtering(parse_scene(three, tmp_path, "o.toml"), "gmm_aligned", prepared=gprep)
    # the same scene read again, or another camera and roughness: rendered with the prepared mipmaps
    again = parse_scene(text, tmp_path, "o.toml")
    assert np.array_equal(render_filtering(again, "lean", prepared=prep).image, render_filtering(s, "lean").image)
    rough = parse_scene(text.replace("roughness = 0.2", "roughness = 0.4"), tmp_path, "o.toml")
    assert np.array_equal(render_filtering(rough, "lean", prepared=prep).image, render_filtering(rough, "lean").image)
    with pytest.raises(WarpbwError, match=r"^device bogus: not available"):
        render_filtering(s, "lean", prepared=prep, device="bogus")


@pytest.mark.parametrize("bad", ["1", True, None, float("inf"), float("nan"), 1e39, 10**400, np.array([0.5])],
                         ids=["str", "bool", "None", "inf", "nan", "1e39", "10**400", "array"])
def test_lod_bias_and_the_other_numbers_must_be_finite_real_numbers(bad):
    """lod_bias="1" was a TypeError from math.isfinite; zoomed_camera took "2", NaN, inf and -1 (a camera at NaN,
    inf, or behind its look-at point); gmm_ndf a negative or NaN rough_var; pair_uniforms a seed of -1 and 2.5
    pairs; threads=0 was refused only after the mipmaps were built.  Each is now a one-line error naming it."""
    s = parse_scene(plane_scene_toml(resolution=(16, 16)), Path.cwd(), "s.toml")
    # a finite number beyond float32 (1e39) is told so: "expected a finite number" misled (options audit, session 64)
    f32 = r" within float32's range \(\+-3\.403e\+38, as the kernels take it\)" if bad == 1e39 else ""
    with pytest.raises(WarpbwError, match=r"^lod_bias \(mip levels added to every pixel's level\): expected a finite "
                                          rf"number{f32}, got "):
        render_filtering(s, "lean", lod_bias=bad)
    with pytest.raises(WarpbwError, match=rf"^zoom .*: expected a finite number > 0{f32}, got "):
        zoomed_camera(s.camera, bad)
    with pytest.raises(WarpbwError, match=rf"^rough_var .*: expected a finite number >= 0{f32}, got "):
        gmm_ndf([[1.0, 0.0, 0.0, 0.01]], bad, [[0.0, 0.0, 1.0]])
    with pytest.raises(WarpbwError, match=r"^n \(pairs\): expected an integer"):
        pair_uniforms(0, 0, bad)


def test_gmm_ndf_of_a_component_too_sharp_for_float32_is_refused_and_a_sharp_one_is_the_closed_form():
    """A component of s^2 = rough_var = 0 is a delta: the kernel's Gaussian read 0 / 0 and returned NaN (inf below
    var 4.7e-40); now a one-line error.  Sharp but representable, the NDF at its mean is 1 / (2 pi var)."""
    h = [[0.0, 0.0, 1.0], [0.1, 0.0, 1.0]]
    for s2, rough_var in ((0.0, 0.0), (1e-45, 0.0), (0.0, 1e-41)):
        with pytest.raises(WarpbwError, match=r"^params: expected s\^2 \+ rough_var > 4\.7e-40 for every component"):
            gmm_ndf([[1.0, 0.0, 0.0, s2]], rough_var, h)
    assert gmm_ndf([[0.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.01]], 0.0, h)[0] == pytest.approx(1.0 / (2 * np.pi * 0.01),
                                                                                              rel=1e-6)
    np.testing.assert_allclose(gmm_ndf([[1.0, 0.0, 0.0, 1e-10]], 0.0, h), [1.0 / (2 * np.pi * 1e-10), 0.0], rtol=1e-6)
    # round 11: a component of s^2 = 0 is no delta where the roughness widens it: var = rough_var (the closed form)
    assert gmm_ndf([[1.0, 0.0, 0.0, 0.0]], 0.01, h)[0] == pytest.approx(1.0 / (2 * np.pi * 0.01), rel=1e-6)


def test_numbers_of_other_types_are_taken_where_they_are_real(monkeypatch):
    s = parse_scene(plane_scene_toml(resolution=(16, 16)), Path.cwd(), "s.toml")
    ref = render_filtering(s, "lean", lod_bias=0.5).image
    for bias in (np.float32(0.5), np.float64(0.5)):
        assert np.array_equal(render_filtering(s, "lean", lod_bias=bias).image, ref)
    assert np.array_equal(render_filtering(s, "lean", lod_bias=1).image,
                          render_filtering(s, "lean", lod_bias=1.0).image)
    assert zoomed_camera(s.camera, np.float32(2.0)).position == zoomed_camera(s.camera, 2).position
    for bad, match in ((-1.0, r"^zoom .*> 0, got -1\.0"), (0, r"^zoom .*> 0, got 0")):
        with pytest.raises(WarpbwError, match=match):
            zoomed_camera(s.camera, bad)
    with pytest.raises(WarpbwError, match=r"^rough_var .*>= 0, got -0\.1"):
        gmm_ndf([[1.0, 0.0, 0.0, 0.01]], -0.1, [[0.0, 0.0, 1.0]])
    assert gmm_ndf([[1.0, 0.0, 0.0, 0.01]], np.float32(0.02), [[0.0, 0.0, 1.0]])[0] > 0
    with pytest.raises(WarpbwError, match=r"^seed: expected an integer"):
        pair_uniforms(-1, 0, 2)
    with pytest.raises(WarpbwError, match=r"^pixel: expected an integer"):
        pair_uniforms(0, 2**31, 2)
    assert pair_uniforms(np.uint32(2**32 - 1), np.int64(3), np.int32(2)).shape == (2, 5)
    # threads is refused before the mipmaps are loaded or built (a GMM fit of a large map takes minutes)
    import warpbw.filtering

    def no_prepare(*a, **k):
        raise AssertionError("prepared before the arguments were checked")

    monkeypatch.setattr(warpbw.filtering, "prepare_filtering", no_prepare)
    with pytest.raises(WarpbwError, match=r"^threads: expected an integer >= 1, got 0"):
        render_filtering(s, "gmm_aligned", threads=0)

def test_the_filtering_entry_points_take_a_filtering_scene_and_check_a_scene_built_in_python():
    """check_render_args, plane_distance and filtering_summary failed on a FilteringScene with an AttributeError;
    prepare_filtering("lean") took the name letter by letter ("filter method 'l'"); a plane scene edited in Python
    skipped the scene file's checks (a plane given a Lambert material failed inside the renderer)."""
    from dataclasses import replace

    from warpbw.filtering import check_render_args, filtering_summary, plane_distance
    from warpbw.scene import Material

    s = parse_scene(plane_scene_toml(resolution=(12, 12)), Path.cwd(), "s.toml")
    prep = prepare_filtering(s, "lean")
    assert prep.scene == s and prep.scene is not s            # a checked copy
    check_render_args(prep, "lean")
    assert np.array_equal(plane_distance(prep), plane_distance(s))
    assert filtering_summary(prep) == filtering_summary(s)
    with pytest.raises(WarpbwError, match=r"^scene: expected a Scene .*got str"):
        plane_distance("s.toml")
    with pytest.raises(WarpbwError, match=r"^progress: expected True or False, got 'no'"):
        render_filtering(s, "lean", progress="no")
    lambert = replace(s, materials={"m": Material("m", "lambert", albedo=(0.5, 0.5, 0.5))})
    with pytest.raises(WarpbwError, match=r"^s\.toml: \[\[object\]\] #1\.material: planes take a cook-torrance "
                                          r"material"):
        render_filtering(lambert, "lean")
    with pytest.raises(WarpbwError, match=r"^s\.toml: \[\[object\]\] #1\.material: planes take"):
        prepare_filtering(lambert, "lean")


@pytest.mark.parametrize("params,refused", [({"unaligned": 0}, None), ({"unaligned": 1}, "--unaligned"),
                                             ({"prior": "one"}, "non-numeric levels or parameters"),
                                             ({"components": 2.5}, "non-numeric levels or parameters")])
def test_info_gmm_check_reads_a_header_as_the_render_reads_it(tmp_path, params, refused):
    """``gmm_header_problem`` (``warpbw info``'s check, levels unread) and the render's reader
    (``check_gmm_files``) give one verdict on a hand-edited header.  The header check parsed the parameters on its
    own: ``unaligned = 0``, which the reader takes as False, read as --unaligned, and a prior of "one" as a prior
    of NaN, where the render refuses the file as non-numeric.  Truth: the render's own refusal or acceptance."""
    from conftest import rewrite_asset
    from precompute.gmm_mipmap import build_gmm_mipmap, write_gmm_mipmap
    from warpbw.filtering import check_gmm_files, gmm_header_problem

    h = _bumps(8)
    write_exr(tmp_path / "map.exr", h.astype(np.float32)[..., None], ["Y"])
    write_gmm_mipmap(tmp_path / "ok.gmm", build_gmm_mipmap(h, scale=0.5, progress=False), "map.exr",
                     file_digest(tmp_path / "map.exr"))
    rewrite_asset(tmp_path / "ok.gmm", tmp_path / "g.gmm", params=params)
    s = parse_scene(plane_scene_toml('normal_map = "map.exr"\nnormal_map_scale = 0.5\ngmm = "g.gmm"\n'), tmp_path,
                    "s.toml")
    said = gmm_header_problem(s, "m", tmp_path / "g.gmm")
    if refused is None:
        assert said is None and check_gmm_files(s, ("gmm_aligned",))["m"][0].unaligned is False
        return
    assert refused in said
    with pytest.raises(WarpbwError, match=refused):
        check_gmm_files(s, ("gmm_aligned",))


def test_info_gmm_check_takes_a_header_without_a_component_count_as_the_materials(tmp_path):
    """Mutation round 12: a GMM file whose header records no ``components`` (a hand-edited or older file) is read with
    its levels' count by the render's reader; ``gmm_header_problem``, which reads no levels, takes the material's
    (``header_fields``' ``components_unrecorded``), and both accept a file fitted with the material's count (taking 1
    refused it).  Truth: the render's own reader."""
    from conftest import rewrite_asset
    from precompute.gmm_mipmap import build_gmm_mipmap, write_gmm_mipmap
    from warpbw.filtering import check_gmm_files, gmm_header_problem

    h = _bumps(8)
    write_exr(tmp_path / "map.exr", h.astype(np.float32)[..., None], ["Y"])
    write_gmm_mipmap(tmp_path / "ok.gmm", build_gmm_mipmap(h, scale=0.5, components=2, progress=False), "map.exr",
                     file_digest(tmp_path / "map.exr"))
    rewrite_asset(tmp_path / "ok.gmm", tmp_path / "g.gmm", drop=("components",))
    s = parse_scene(plane_scene_toml('normal_map = "map.exr"\nnormal_map_scale = 0.5\ngmm_components = 2\n'
                                     'gmm = "g.gmm"\n'), tmp_path, "s.toml")
    assert gmm_header_problem(s, "m", tmp_path / "g.gmm") is None
    assert check_gmm_files(s, ("gmm_aligned",))["m"][0].components == 2


def test_gmm_file_of_another_map_is_refused_and_a_matching_one_used(tmp_path, monkeypatch):
    import shlex

    from precompute.__main__ import main as precompute_main
    from precompute.gmm_mipmap import build_gmm_mipmap, load_map, write_gmm_mipmap

    h = _bumps(8)
    s = scene_with_map(tmp_path, heights=h, scale=0.5)
    digest = file_digest(tmp_path / "map.exr")     # the header names the map a file was built from, by content
    text = plane_scene_toml('normal_map = "map.exr"\nnormal_map_scale = 0.5\ngmm = "other.gmm"\n')
    # a file of another map: of another size, or of this size and parameters but other heights
    write_gmm_mipmap(tmp_path / "other.gmm", build_gmm_mipmap(np.zeros((4, 4)), progress=False), "x", digest)
    with pytest.raises(WarpbwError, match=r"\[material\.m\]\.gmm: .*4x4 map"):
        prepare_filtering(parse_scene(text, tmp_path, "s.toml"), ("gmm_aligned",))
    write_gmm_mipmap(tmp_path / "other.gmm", build_gmm_mipmap(2.0 * h, scale=0.5, progress=False),
                     "taller.exr", "0123", force=True)
    with pytest.raises(WarpbwError, match=r"\[material\.m\]\.gmm: .*built from taller.exr with different "
                                          r"content than the material's normal_map map.exr.*gmm \S*/map.exr -o"):
        prepare_filtering(parse_scene(text, tmp_path, "s.toml"), ("gmm_aligned",))
    write_gmm_mipmap(tmp_path / "wrong_scale.gmm", build_gmm_mipmap(h, scale=1.0, progress=False), "x", digest)
    with pytest.raises(WarpbwError, match=r"\[material\.m\]\.gmm: .*--scale 0\.5"):
        prepare_filtering(parse_scene(text.replace("other.gmm", "wrong_scale.gmm"), tmp_path, "s.toml"),
                          ("gmm_aligned",))
    write_gmm_mipmap(tmp_path / "good.gmm", build_gmm_mipmap(h, scale=0.5, progress=False), "x", digest)
    prep = prepare_filtering(parse_scene(text.replace("other.gmm", "good.gmm"), tmp_path, "s.toml"),
                             ("gmm_aligned",))
    assert prep.notes["m"]["gmm_aligned"]["origin"] == "file"
    # a file with another number of components than the material's gmm_components (default 4)
    write_gmm_mipmap(tmp_path / "k2.gmm", build_gmm_mipmap(h, scale=0.5, components=2, progress=False), "x",
                     digest)
    k2 = text.replace("other.gmm", "k2.gmm")
    with pytest.raises(WarpbwError, match=r"\[material\.m\]\.gmm: .*--components 2.*gmm_components = 4"):
        prepare_filtering(parse_scene(k2, tmp_path, "s.toml"), ("gmm_aligned",))
    prep = prepare_filtering(parse_scene(k2 + "gmm_components = 2\n", tmp_path, "s.toml"),
                             ("gmm_aligned", "gmm_unaligned"))
    assert prep.notes["m"]["gmm_aligned"]["components"] == prep.notes["m"]["gmm_unaligned"]["components"] == 2
    # a file built with another prior than the material's gmm_prior (default 1)
    write_gmm_mipmap(tmp_path / "c4.gmm", build_gmm_mipmap(h, scale=0.5, prior=4.0, progress=False), "x", digest)
    c4 = text.replace("other.gmm", "c4.gmm")
    with pytest.raises(WarpbwError, match=r"\[material\.m\]\.gmm: .*--prior 4.*gmm_prior = 1"):
        prepare_filtering(parse_scene(c4, tmp_path, "s.toml"), ("gmm_aligned",))
    prep = prepare_filtering(parse_scene(c4 + "gmm_prior = 4\n", tmp_path, "s.toml"), ("gmm_aligned",))
    assert prep.notes["m"]["gmm_aligned"]["prior"] == 4.0
    # the command a refusal prints rebuilds the file as the material wants it, from any folder
    write_gmm_mipmap(tmp_path / "stale.gmm", build_gmm_mipmap(np.zeros((4, 4)), progress=False), "x", digest)
    stale = text.replace("other.gmm", "stale.gmm") + "gmm_components = 2\ngmm_prior = 4\n"
    with pytest.raises(WarpbwError) as ei:
        prepare_filtering(parse_scene(stale, tmp_path, "s.toml"), ("gmm_aligned",))
    command = shlex.split(str(ei.value).split("rebuild it with: ")[1].rstrip(")"))
    assert command[:2] == ["warpbw-precompute", "gmm"] and "--components" in command and "--prior" in command
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    assert precompute_main(command[1:] + ["-q"]) == 0
    prep = prepare_filtering(parse_scene(stale, tmp_path, "s.toml"), ("gmm_aligned",))
    assert prep.notes["m"]["gmm_aligned"]["origin"] == "file"
    # without a file: built once, then read from the cache
    p1 = prepare_filtering(s, ("gmm_aligned",))
    p2 = prepare_filtering(s, ("gmm_aligned",))
    assert (p1.notes["m"]["gmm_aligned"]["origin"], p2.notes["m"]["gmm_aligned"]["origin"]) == ("built", "cache")
    a = render_filtering(s, "gmm_aligned", prepared=p1).image
    b = render_filtering(s, "gmm_aligned", prepared=p2).image
    assert np.array_equal(a, b)
    # the material's gmm_prior builds (and caches) the aligned mipmap it names, exactly the builder's; the
    # unaligned baseline (c = 0 whatever the prior) comes from the cache it already has
    s16 = parse_scene(plane_scene_toml('normal_map = "map.exr"\nnormal_map_scale = 0.5\ngmm_prior = 16\n'), tmp_path,
                      "s.toml")
    p0 = prepare_filtering(s, ("gmm_unaligned",))
    p3 = prepare_filtering(s16, ("gmm_aligned", "gmm_unaligned"))
    assert (p3.notes["m"]["gmm_aligned"]["origin"], p3.notes["m"]["gmm_aligned"]["prior"]) == ("built", 16.0)
    assert p3.notes["m"]["gmm_unaligned"]["origin"] == "cache" and p0.notes["m"]["gmm_unaligned"]["prior"] == 0.0
    want = build_gmm_mipmap(load_map(tmp_path / "map.exr"), scale=0.5, prior=16.0, progress=False).levels
    got = p3.mips["m"].gmm["gmm_aligned"][0].numpy()
    assert np.array_equal(got, np.concatenate([q.reshape(-1, 4) for q in want]))
    assert not np.array_equal(got, p1.mips["m"].gmm["gmm_aligned"][0].numpy())


def test_a_named_gmm_file_and_its_normal_map_are_each_read_once(tmp_path, monkeypatch):
    """check_gmm_files reads the normal map to check the gmm file against it; prepare_filtering then read the map
    again (and hashed it again).  Each is read once, and the frame's mipmaps are those of a map read afresh."""
    import precompute.gmm_mipmap as gm

    h = _bumps(8)
    scene_with_map(tmp_path, heights=h, scale=0.5)
    digest = file_digest(tmp_path / "map.exr")
    gm.write_gmm_mipmap(tmp_path / "good.gmm", gm.build_gmm_mipmap(h, scale=0.5, progress=False), "x", digest)
    text = plane_scene_toml('normal_map = "map.exr"\nnormal_map_scale = 0.5\ngmm = "good.gmm"\n')
    reads = []
    real = gm.load_map

    def counting(path, *a, **kw):
        reads.append(Path(path).name)
        return real(path, *a, **kw)

    monkeypatch.setattr(gm, "load_map", counting)
    prep = prepare_filtering(parse_scene(text, tmp_path, "s.toml"), ("gmm_aligned", "toksvig"))
    assert reads == ["map.exr"], reads
    assert prep.notes["m"]["gmm_aligned"]["origin"] == "file"
    monkeypatch.setattr(gm, "load_map", real)
    fresh = prepare_filtering(parse_scene(text.replace('gmm = "good.gmm"\n', ""), tmp_path, "s.toml"), ("toksvig",))
    assert np.array_equal(prep.mips["m"].nmean.numpy(), fresh.mips["m"].nmean.numpy())


def _info_json(scene) -> dict:
    """What ``warpbw info SCENE --json`` prints."""
    import contextlib
    import io
    import json

    from warpbw.cli import main as cli_main

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert cli_main(["info", str(scene), "--json"]) == 0
    return json.loads(out.getvalue())


def test_gmm_file_of_a_non_square_height_map_fitted_with_rows_1_over_w_apart_is_refused(tmp_path, monkeypatch):
    """A W x H height map spans the plane's square, its rows 1/H apart; before session 69 they were differentiated
    1/W apart, and a GMM file fitted then (a builder given that texel size does the same) holds slopes the other
    methods no longer shade.  Such a file is refused with the command that rebuilds it, whose file is then used.
    ``warpbw info`` says so in the same words (its header-level twin of the reader's checks lacked this one until
    session 78)."""
    import shlex

    from precompute.__main__ import main as precompute_main
    from precompute.gmm_mipmap import build_gmm_mipmap, write_gmm_mipmap

    h = _bumps(8)[:4]                                       # 8 wide, 4 tall
    scene_with_map(tmp_path, heights=h, scale=0.5)          # writes map.exr
    digest = file_digest(tmp_path / "map.exr")
    text = plane_scene_toml('normal_map = "map.exr"\nnormal_map_scale = 0.5\ngmm = "old.gmm"\n')
    write_gmm_mipmap(tmp_path / "old.gmm", build_gmm_mipmap(h, scale=0.5, texel_size=1.0 / 8, progress=False),
                     "map.exr", digest)
    with pytest.raises(WarpbwError, match=r"\[material\.m\]\.gmm: .*8x4 height map with its rows 1/8 apart") as ei:
        prepare_filtering(parse_scene(text, tmp_path, "s.toml"), ("gmm_aligned",))
    (tmp_path / "s.toml").write_text(text)   # warpbw info, from the file's header, says it in the same words
    assert _info_json(tmp_path / "s.toml")["assets"][0]["refused"] == str(ei.value).split(".gmm: ")[-1]
    command = shlex.split(str(ei.value).split("rebuild it with: ")[1].rstrip(")"))
    monkeypatch.chdir(tmp_path)
    assert precompute_main(command[1:] + ["-q"]) == 0
    prep = prepare_filtering(parse_scene(text, tmp_path, "s.toml"), ("gmm_aligned",))
    assert prep.notes["m"]["gmm_aligned"]["origin"] == "file"


def test_a_gmm_cache_entry_fitted_with_other_settings_is_rebuilt_and_a_gmm_file_so_fitted_used(tmp_path):
    """A GMM mipmap records the fit's settings (seed, samples per footprint, refinement sweeps).  A cache entry of
    this map and material fitted with others is stale: rebuilt, as a fresh fit, and replaced; then read without a
    fit.  A material's gmm file fitted so is the user's choice and is used as it is."""
    from precompute.assetfile import read_header
    from precompute.gmm_mipmap import build_gmm_mipmap, load_map, write_gmm_mipmap

    h = _bumps(8)
    s = scene_with_map(tmp_path, heights=h, scale=0.5)
    digest = file_digest(tmp_path / "map.exr")
    fresh = build_gmm_mipmap(load_map(tmp_path / "map.exr"), scale=0.5, progress=False)
    other = build_gmm_mipmap(load_map(tmp_path / "map.exr"), scale=0.5, max_samples=16, progress=False)
    assert not np.array_equal(fresh.levels[0], other.levels[0])

    def flat(mip):
        return np.concatenate([q.reshape(-1, 4) for q in mip.levels])

    assert prepare_filtering(s, ("gmm_aligned",)).notes["m"]["gmm_aligned"]["origin"] == "built"
    (entry,) = (tmp_path / "_cache").glob("gmm-*.npz")
    write_gmm_mipmap(entry, other, "map.exr", digest, force=True)
    prep = prepare_filtering(s, ("gmm_aligned",))
    assert prep.notes["m"]["gmm_aligned"]["origin"] == "built"
    assert np.array_equal(prep.mips["m"].gmm["gmm_aligned"][0].numpy(), flat(fresh))
    assert read_header(entry)["params"]["max_samples"] == fresh.max_samples
    assert prepare_filtering(s, ("gmm_aligned",)).notes["m"]["gmm_aligned"]["origin"] == "cache"
    write_gmm_mipmap(tmp_path / "mine.gmm", other, "map.exr", digest)
    text = plane_scene_toml('normal_map = "map.exr"\nnormal_map_scale = 0.5\ngmm = "mine.gmm"\n')
    prep = prepare_filtering(parse_scene(text, tmp_path, "s.toml"), ("gmm_aligned",))
    assert prep.notes["m"]["gmm_aligned"]["origin"] == "file"
    assert np.array_equal(prep.mips["m"].gmm["gmm_aligned"][0].numpy(), flat(other))


def test_a_gmm_cache_entry_from_before_clipped_footprints_were_weighed_is_rebuilt(tmp_path):
    """Entries written before session 72 fitted a footprint the border clips with some of its texels counted twice
    and record nothing of it: such an entry (its params without ``clipped_footprints``) is rebuilt; a gmm file the
    material names that lacks it is read as it is."""
    from precompute.assetfile import read_header
    from precompute.gmm_mipmap import build_gmm_mipmap, load_map, write_gmm_mipmap

    s = scene_with_map(tmp_path, heights=_bumps(8), scale=0.5)
    digest = file_digest(tmp_path / "map.exr")
    old = build_gmm_mipmap(load_map(tmp_path / "map.exr"), scale=0.5, progress=False)
    old.extra.pop("clipped_footprints")
    assert prepare_filtering(s, ("gmm_aligned",)).notes["m"]["gmm_aligned"]["origin"] == "built"
    (entry,) = (tmp_path / "_cache").glob("gmm-*.npz")
    write_gmm_mipmap(entry, old, "map.exr", digest, force=True)
    assert "clipped_footprints" not in read_header(entry)["params"]
    assert prepare_filtering(s, ("gmm_aligned",)).notes["m"]["gmm_aligned"]["origin"] == "built"
    assert read_header(entry)["params"]["clipped_footprints"] == "texels weighed equally"
    write_gmm_mipmap(tmp_path / "mine.gmm", old, "map.exr", digest)
    text = plane_scene_toml('normal_map = "map.exr"\nnormal_map_scale = 0.5\ngmm = "mine.gmm"\n')
    assert prepare_filtering(parse_scene(text, tmp_path, "s.toml"), ("gmm_aligned",)).notes["m"]["gmm_aligned"][
        "origin"] == "file"


def test_a_gmm_cache_entry_records_the_fits_constants_and_is_rebuilt_when_one_changes(tmp_path, monkeypatch):
    """Since session 72 a GMM mipmap records the fit's constants (EM's and k-means' stopping rules, the variance
    floor, ...), guarded before by version bumps alone.  An entry that records none of them (an earlier build's) is
    read, at the values they have had since the builder was written (1e-4, 60, 10, 4, 1e-6, 1e-8, 2^21, written here);
    with EM's tolerance changed it is stale and rebuilt, and the rebuilt entry records the new value."""
    import precompute.gmm_mipmap as gm
    from precompute.assetfile import read_header

    s = scene_with_map(tmp_path, heights=_bumps(8), scale=0.5)
    digest = file_digest(tmp_path / "map.exr")
    assert prepare_filtering(s, ("gmm_aligned",)).notes["m"]["gmm_aligned"]["origin"] == "built"
    (entry,) = (tmp_path / "_cache").glob("gmm-*.npz")
    recorded = read_header(entry)["params"]
    then = {"em_tolerance": 1e-4, "em_max_iterations": 60, "kmeans_iterations": 10, "top_kmeans_restarts": 4,
            "variance_floor": 1e-6, "weight_eps": 1e-8, "batch_elements": 2 ** 21}
    assert {k: recorded[k] for k in then} == then
    mip = gm.build_gmm_mipmap(gm.load_map(tmp_path / "map.exr"), scale=0.5, progress=False)
    for k in then:
        mip.extra.pop(k)
    gm.write_gmm_mipmap(entry, mip, "map.exr", digest, force=True)
    assert prepare_filtering(s, ("gmm_aligned",)).notes["m"]["gmm_aligned"]["origin"] == "cache"
    monkeypatch.setattr(gm, "EM_TOLERANCE", 1e-5)
    assert prepare_filtering(s, ("gmm_aligned",)).notes["m"]["gmm_aligned"]["origin"] == "built"
    assert read_header(entry)["params"]["em_tolerance"] == 1e-5


MIXED_SPHERE = """
[[object]]
shape = "sphere"
center = [0.0, 0.5, 0.0]
radius = 0.3
material = "d"

[material.d]
type = "lambert"
albedo = [0.5, 0.5, 0.5]
"""


@pytest.mark.parametrize("mixed", [False, True], ids=["planes", "planes and a sphere"])
def test_warpbw_render_refuses_a_wrong_gmm_file_before_any_other_work(tmp_path, monkeypatch, capsys, mixed):
    """A material's gmm file fitted to another map is refused in one line naming the scene, the key and the file,
    before anything else is loaded or rendered: the environment, the normal mipmaps, the spheres' materials and
    geometry, the G-buffer (each stands in here by a function that fails).  It was read after the environment and
    the box mipmaps, and in a scene with spheres after those were loaded."""
    import warpbw.filtering as fl
    import warpbw.pipeline as pl
    from precompute.gmm_mipmap import build_gmm_mipmap, write_gmm_mipmap
    from warpbw.cli import main

    scene_with_map(tmp_path, heights=_bumps(8), scale=0.5)    # writes map.exr
    write_gmm_mipmap(tmp_path / "bad.gmm", build_gmm_mipmap(np.zeros((4, 4)), progress=False), "x",
                     file_digest(tmp_path / "map.exr"))
    text = plane_scene_toml('normal_map = "map.exr"\nnormal_map_scale = 0.5\ngmm = "bad.gmm"\n',
                            environment='[environment]\nconstant = [0.5, 0.5, 0.5]\n')
    (tmp_path / "scene.toml").write_text(text + (MIXED_SPHERE if mixed else ""))

    def work(*a, **kw):
        raise AssertionError("work done before the gmm file was checked")

    for module, name in ((fl, "load_environment"), (fl, "normal_moment_mipmap"), (pl, "prepare_scene"),
                         (pl, "render_gbuffer"), (pl, "_gbuffer")):
        monkeypatch.setattr(module, name, work)
    monkeypatch.chdir(tmp_path)
    assert main(["render", "scene.toml", "-o", "out.exr", "-q"]) != 0
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "scene.toml: [material.m].gmm: " in err and "bad.gmm" in err and "4x4 map" in err, err
    assert not (tmp_path / "out.exr").exists()


def test_gmm_priors_that_agree_to_six_digits_are_cached_apart(tmp_path):
    """The cache key wrote gmm_prior with %g (6 digits) while the reader compares it to 1e-9: priors 0.5 and
    0.5000001 shared one entry and evicted each other, so every render paid the whole EM fit again."""
    write_exr(tmp_path / "map.exr", _bumps(8)[..., None].astype(np.float32), channels=["Y"])

    def origin(prior):
        text = plane_scene_toml(f'normal_map = "map.exr"\nnormal_map_scale = 0.5\ngmm_prior = {prior!r}\n')
        return prepare_filtering(parse_scene(text, tmp_path, "s.toml"), ("gmm_aligned",)).notes["m"]["gmm_aligned"]

    assert [origin(c)["origin"] for c in (0.5, 0.5000001, 0.5, 0.5000001)] == ["built", "built", "cache", "cache"]
    assert origin(0.5000001)["prior"] == 0.5000001


def test_nearer_plane_wins_and_threads_do_not_change_the_image(tmp_path):
    text = plane_scene_toml(resolution=(20, 14)) + textwrap.dedent("""
        [[object]]
        shape = "plane"
        center = [0.0, 0.5, 0.0]
        size = 0.5
        material = "n"

        [material.n]
        type = "cook-torrance"
        roughness = 0.3
        f0 = [0.1, 0.1, 0.1]
        diffuse = [0.0, 0.9, 0.0]
        """)
    s = parse_scene(text, tmp_path, "s.toml")
    one = parse_scene(plane_scene_toml(resolution=(20, 14)), tmp_path, "s.toml")
    for m in ("fixed", "ground_truth"):
        both = render_filtering(s, m, threads=2)
        big = render_filtering(one, m, threads=1)
        # where the small, raised, green plane is in front, green dominates; elsewhere the image is the big plane's
        green = both.image[..., 1] > 2 * both.image[..., 0] + 1e-6
        assert green.sum() > 4
        same = ~green & both.coverage
        assert np.allclose(both.image[same], big.image[same], rtol=1e-5, atol=1e-7)
        assert np.array_equal(render_filtering(one, m, threads=2).image, big.image)


def test_plane_distance_is_the_nearest_plane_along_each_centre_ray(tmp_path):
    """plane_distance against a numpy ray cast of two squares at different heights (the raised one smaller and
    partly over the other): the nearer hit per pixel, inf where a ray misses both; and the pixels it finds are
    the ones the renderer covers."""
    from warpbw.filtering import plane_distance

    w, h = 24, 16
    raised = textwrap.dedent("""
        [[object]]
        shape = "plane"
        center = [0.3, 0.4, 0.1]
        size = 0.6
        material = "m"
        """)
    s = parse_scene(plane_scene_toml(resolution=(w, h), size=1.5) + raised, tmp_path, "s.toml")
    o, d = numpy_camera_rays((0.0, 1.5, 2.0), (0, 0, 0), 40.0, w, h)
    t_ref = np.full((h, w), np.inf)
    for c, size in (((0.0, 0.0, 0.0), 1.5), ((0.3, 0.4, 0.1), 0.6)):
        t_ref = np.minimum(t_ref, numpy_square_distance(o, d, size, c))
    t_w = plane_distance(s)
    assert t_w.shape == (h, w) and t_w.dtype == np.float32
    hit = np.isfinite(t_ref)
    assert 0 < hit.sum() < h * w and np.array_equal(np.isfinite(t_w), hit)
    assert np.allclose(t_w[hit], t_ref[hit], rtol=1e-5)
    assert (t_w[hit] < t_ref.max() - 0.1).sum() > 4   # the raised square is in front somewhere
    assert np.array_equal(np.isfinite(t_w), render_filtering(s, "fixed").coverage)


@pytest.mark.parametrize("method", ["fixed", "ground_truth"])
def test_planes_over_a_background_show_where_they_are_in_front(tmp_path, method):
    """A background at camera-space depth z_b (a wall facing the camera, written as a depth image): a pixel shows
    the plane exactly where the plane's own camera-space depth, from a numpy ray cast, is below z_b; there the
    image is the plane alone, elsewhere the background untouched.  An empty background (depth 0) is no
    background at all."""
    from warpbw.filtering import Background

    w, h = 24, 16
    s = parse_scene(plane_scene_toml(resolution=(w, h)), tmp_path, "s.toml")
    alone = render_filtering(s, method)
    o, d = numpy_camera_rays((0.0, 1.5, 2.0), (0, 0, 0), 40.0, w, h)
    fwd = -np.asarray((0.0, 1.5, 2.0)) / np.linalg.norm((0.0, 1.5, 2.0))
    z_plane = (-o[1] / d[..., 1]) * (d @ fwd)           # distance along the ray times cos(ray, forward)
    z_b = float(np.median(z_plane[alone.coverage]))     # a wall through the middle of the plane
    z = np.full((h, w), z_b, np.float32)
    z[:, : w // 4] = 0.0                                # and no background at all in the left quarter
    bg = np.tile(np.array([0.1, 0.2, 0.3], np.float32), (h, w, 1))
    over = render_filtering(s, method, background=Background(bg, z))
    clear = np.abs(z_plane - z_b) > 1e-4 * z_b          # not on the wall's own line
    front = alone.coverage & ((z == 0) | (z_plane < z_b))
    assert 0 < (front & clear).sum() < (alone.coverage & clear).sum()
    assert np.array_equal(over.coverage[clear], front[clear])
    assert np.array_equal(over.image[over.coverage], alone.image[over.coverage])
    assert np.array_equal(over.image[~over.coverage], bg[~over.coverage])
    assert over.stats["pixels_covered"] == int(over.coverage.sum())
    empty = render_filtering(s, method, background=Background(np.zeros((h, w, 3), np.float32), np.zeros((h, w))))
    assert np.array_equal(empty.image, alone.image) and np.array_equal(empty.coverage, alone.coverage)
    with pytest.raises(WarpbwError, match=r"background: expected an \(16, 24, 3\) image"):
        render_filtering(s, method, background=Background(bg[:-1], z[:-1]))


# ------------------------------------------------------------------------------------------ environment light

def numpy_flat_under_constant_sky(cos_o, roughness, radiance=1.0, nt=600, nphi=720):
    """int over the upper hemisphere of f(wi) wi_z dwi for a flat plane (the model of warpbw.filtering: Gaussian
    NDF of per-axis variance m^2/2 over projected half-vectors, Schlick, Lambert, G = 1), viewed at cos_o;
    midpoint quadrature in spherical coordinates (the integrand is isotropic about the normal)."""
    wo = np.array([math.sqrt(1 - cos_o ** 2), 0.0, cos_o])
    th = (np.arange(nt) + 0.5) * (np.pi / 2) / nt
    ph = (np.arange(nphi) + 0.5) * 2 * np.pi / nphi
    T, P = np.meshgrid(th, ph, indexing="ij")
    wi = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1)
    h = wi + wo
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    var = roughness ** 2 / 2
    D = np.exp(-(h[..., 0] ** 2 + h[..., 1] ** 2) / (2 * var)) / (2 * np.pi * var)
    u = np.clip(h @ wo, 0, None)[..., None]
    F = np.asarray(PLANE_F0) + (1 - np.asarray(PLANE_F0)) * (1 - u) ** 5
    f = F * (D / (4 * cos_o))[..., None] + np.asarray(PLANE_DIFFUSE) / np.pi * (1 - F) * wi[..., 2:3]
    dw = np.sin(T)[..., None] * (np.pi / 2 / nt) * (2 * np.pi / nphi)
    return radiance * (f * dw).sum(axis=(0, 1))


def flat_under_constant_sky_of_cos(cos_o, roughness, nodes=16):
    """numpy_flat_under_constant_sky at every cos_o of an array (..., 3 out), read from its Chebyshev interpolant at
    ``nodes`` points over the array's range: the integral is smooth in cos_o (16 nodes agree with the quadrature to
    about 1e-8 relative; checked here between two nodes), and one quadrature per ray took 20 s for 800 rays."""
    lo, hi = float(np.min(cos_o)), float(np.max(cos_o))
    x = np.cos((np.arange(nodes) + 0.5) * np.pi / nodes)          # Chebyshev nodes on [-1, 1]
    coef = np.polynomial.chebyshev.chebfit(x, [numpy_flat_under_constant_sky(lo + (hi - lo) * (t + 1) / 2, roughness)
                                               for t in x], nodes - 1)

    def at(c):
        return np.moveaxis(np.polynomial.chebyshev.chebval(2 * (np.asarray(c) - lo) / (hi - lo) - 1, coef), 0, -1)

    for t in (x[nodes // 2] + x[nodes // 2 - 1]) / 2, (x[0] + x[1]) / 2:   # off the nodes, mid-range and at the end
        c = lo + (hi - lo) * (t + 1) / 2
        np.testing.assert_allclose(at(c), numpy_flat_under_constant_sky(c, roughness), rtol=1e-6)
    return at(cos_o)


def test_flat_plane_under_a_constant_environment_is_the_hemisphere_integral():
    s = parse_scene(plane_scene_toml(roughness=0.3, lights=0, resolution=(8, 6),
                               environment="[environment]\nconstant = [1.0, 1.0, 1.0]\n"), Path.cwd(), "s.toml")
    o, d = numpy_camera_rays((0.0, 1.5, 2.0), (0, 0, 0), 40.0, 8, 6)
    prep = prepare_filtering(s, ALL_METHODS)
    sub = np.stack(np.meshgrid((np.arange(4) + 0.5) / 4, (np.arange(4) + 0.5) / 4), -1).reshape(-1, 2)
    rays = np.stack([numpy_camera_rays((0.0, 1.5, 2.0), (0, 0, 0), 40.0, 8, 6, jitter)[1] for jitter in sub])
    cos_o = -rays[..., 1]                            # every ray looks down on the plane y = 0
    assert cos_o.min() > 0.1, cos_o.min()
    at_centre, in_box = np.split(flat_under_constant_sky_of_cos(np.concatenate([-d[..., 1][None], cos_o]), 0.3),
                                 [1])
    for m in ("gmm_aligned", "lean"):
        r = render_filtering(s, m, prepared=prep, env_spp=2048, seed=3)
        assert r.stats["environment"]["samples_per_pixel"] == 4096
        cov = r.coverage
        ref = at_centre[0][cov]
        rel = np.abs(r.image[cov] - ref) / ref
        assert rel.mean() < 0.01 and rel.max() < 0.03, (m, rel.mean(), rel.max())
    # the ground truth: 1024 rays, one BRDF and one environment sample each, averaged over the pixel box
    g = render_filtering(s, "ground_truth", spp=1024, prepared=prep)
    ref = in_box.mean(axis=0)                        # the box filter, as 16 sub-pixel ray directions
    cov = g.coverage                                 # pixels wholly on the plane (an edge pixel's box is not)
    interior = cov & np.roll(cov, 1, 0) & np.roll(cov, -1, 0) & np.roll(cov, 1, 1) & np.roll(cov, -1, 1)
    assert interior.sum() >= 12 and colour_error(g.image, ref, interior) < 0.02


def test_twenty_million_environment_pairs_or_rays_per_pixel_still_converge():
    """The filtered methods' environment pairs and the ground truth's rays were summed in float32, which stops
    growing past about 1.7e7 terms: 2e7 of them read far below 1e6 of them.  A flat plane under a constant sky,
    one pixel: 2e7 agree with 1e6 to within their noise (the closed forms are checked above).  The ground truth's
    rays under the directional light alone (its environment pairs are the same sum)."""
    sky = "[environment]\nconstant = [1.0, 1.0, 1.0]\n"
    for method, key, lights, env in (("fixed", "env_spp", 0, sky), ("ground_truth", "spp", 1, "")):
        s = parse_scene(plane_scene_toml(roughness=0.3, lights=lights, resolution=(1, 1), position=(0.0, 1.5, 0.2),
                                         environment=env), Path.cwd(), "s.toml")
        prep = prepare_filtering(s, (method,))
        few, many = (render_filtering(s, method, prepared=prep, seed=1, **{key: n}).image[0, 0]
                     for n in (1_000_000, 20_000_000))
        assert np.all(few > 0) and np.abs(many / few - 1.0).max() < 2e-3, (method, few, many)


def test_the_ground_truth_shows_a_progress_bar_and_the_filters_do_not(capsys):
    """The ground truth takes minutes at 1024 rays per pixel and 1024^2 pixels, and showed nothing (progress was
    taken and dropped); the filtered methods take milliseconds and stay quiet."""
    s = parse_scene(plane_scene_toml(resolution=(16, 12)), Path.cwd(), "s.toml")
    prep = prepare_filtering(s, ("fixed", "ground_truth"))
    render_filtering(s, "ground_truth", spp=64, prepared=prep, progress=True)
    assert "ground truth, 64 rays per pixel" in capsys.readouterr().err
    render_filtering(s, "fixed", prepared=prep, progress=True)
    assert capsys.readouterr().err == ""


def _small_sun_env(tmp_path, i=64, j=57, w=512, h=256, value=5000.0, sigma=3.0):
    """A black lat-long EXR with a small sun: a Gaussian blob of texels (sigma in texels) around texel (i, j).
    Returns the centre's direction and the irradiance E of the map's bilinear interpolant: a tent of one texel
    per axis in (u, v) around each texel, and dw = 2 pi^2 sin(theta) du dv (warpbw.envmap's convention)."""
    jj, ii = np.mgrid[0:h, 0:w]
    img = value * np.exp(-((ii - i) ** 2 + (jj - j) ** 2) / (2 * sigma ** 2))
    img[img < 1e-6 * value] = 0.0
    write_exr(tmp_path / "sky.exr", np.repeat(img[..., None], 3, -1).astype(np.float32))
    phi, theta = 2 * np.pi * (i + 0.5) / w, np.pi * j / (h - 1)
    d = (math.sin(phi) * math.sin(theta), math.cos(theta), -math.cos(phi) * math.sin(theta))
    E = float(np.sum(img * np.sin(np.pi * jj / (h - 1)))) * 2 * np.pi ** 2 / (w * (h - 1))
    return d, E


def test_a_small_sun_in_the_environment_shades_as_the_directional_light_of_its_irradiance(tmp_path):
    # every method's environment path (MIS of BRDF and environment samples over its lobes) against its own
    # closed-form directional path, on a bumpy map whose GMM and LEAN lobes differ from the fine-scale BRDF;
    # the sun (about 6 degrees across) is small against the lobes (roughness 0.4); the tolerance is about twice
    # the estimators' noise (the environment sampler is piecewise constant per texel, the sun's radiance not)
    d, E = _small_sun_env(tmp_path)
    heights = np.random.default_rng(2).normal(size=(16, 16)) * 0.02
    env_scene = scene_with_map(tmp_path, heights=heights, tiling=4.0, roughness=0.4, lights=0,
                               environment='[environment]\nfile = "sky.exr"\n')
    lit = scene_with_map(tmp_path, heights=heights, tiling=4.0, roughness=0.4, light_dir=d, radiance=(E, E, E))
    pe, pl = prepare_filtering(env_scene, ALL_METHODS), prepare_filtering(lit, ALL_METHODS)
    for m in METHODS:
        a = render_filtering(env_scene, m, prepared=pe, env_spp=512)
        b = render_filtering(lit, m, prepared=pl)
        assert np.array_equal(a.coverage, b.coverage) and np.abs(b.image).max() > 0
        assert colour_error(a.image, b.image, a.coverage) < 0.015, m
        assert a.image.mean() == pytest.approx(b.image.mean(), rel=0.01), m
    a = render_filtering(env_scene, "ground_truth", spp=1024, prepared=pe)
    b = render_filtering(lit, "ground_truth", spp=1024, prepared=pl)
    assert colour_error(a.image, b.image, a.coverage) < 0.02
    assert a.image.mean() == pytest.approx(b.image.mean(), rel=0.01)


def test_environment_and_lights_add_up_and_the_seed_is_the_only_noise(tmp_path):
    env = "[environment]\nprocedural = \"sky\"\n"
    both = parse_scene(plane_scene_toml(environment=env), Path.cwd(), "s.toml")
    sky = parse_scene(plane_scene_toml(environment=env, lights=0), Path.cwd(), "s.toml")
    sun = parse_scene(plane_scene_toml(), Path.cwd(), "s.toml")
    a = render_filtering(both, "toksvig", env_spp=4, seed=7).image
    b = render_filtering(sky, "toksvig", env_spp=4, seed=7).image
    c = render_filtering(sun, "toksvig").image
    assert np.abs(b).max() > 0 and np.allclose(a, b + c, rtol=1e-5, atol=1e-6)
    assert np.array_equal(render_filtering(sky, "toksvig", env_spp=4, seed=7).image, b)
    assert not np.array_equal(render_filtering(sky, "toksvig", env_spp=4, seed=8).image, b)
    # the random streams are per pixel: how the launch is tiled over threads (tiles of 1024 or 256 pixels here)
    # does not change the image
    big = parse_scene(plane_scene_toml(environment=env, lights=0, resolution=(64, 64)), Path.cwd(), "s.toml")
    for m, kw in (("toksvig", {"env_spp": 4}), ("ground_truth", {"spp": 64})):
        assert np.array_equal(render_filtering(big, m, seed=7, threads=1, **kw).image,
                              render_filtering(big, m, seed=7, threads=4, **kw).image), m


def test_a_scene_without_lights_compiles_no_light_loop(tmp_path):
    """README ("Only what a scene needs is compiled") and the module docstring: the lights' loop is compiled only for
    a scene that has lights.  The planes' kernels looped over the light arrays whatever the scene (none: no
    iteration).  Truth: a plane under a sky alone, its prepared light arrays replaced by one bright light (which the
    scene does not have): a kernel without the loop never reads them, so every method's frame is the sky's alone,
    bit for bit; with the loop the light was shaded.  The same light in the scene itself is shaded (sanity)."""
    from dataclasses import replace

    write_exr(tmp_path / "map.exr", np.asarray(hemispherical_scales(32, scales_across=4), np.float32)[..., None],
              channels=["Y"])
    extra = 'normal_map = "map.exr"\nnormal_map_scale = 0.5\ntiling = 4\n'
    env = "[environment]\nconstant = [0.2, 0.3, 0.4]\n"
    sky = parse_scene(plane_scene_toml(extra, environment=env, lights=0), tmp_path, "s.toml")
    methods = ("gmm_aligned", "toksvig", "lean", "fixed", "ground_truth")
    prep = prepare_filtering(sky, methods)
    planted = replace(prep, ldir=wp.array(np.array([[0.0, 0.0, 1.0]], np.float32), dtype=wp.vec3),
                      lrad=wp.array(np.array([[50.0, 50.0, 50.0]], np.float32), dtype=wp.vec3))
    for m in methods:
        alone = render_filtering(sky, m, prepared=prep, spp=64, env_spp=2, seed=3)
        given = render_filtering(sky, m, prepared=planted, spp=64, env_spp=2, seed=3)
        assert alone.coverage.sum() > 100 and np.array_equal(given.image, alone.image), m
    lit = parse_scene(plane_scene_toml(extra, environment=env, light_dir=(0.0, 1.0, 0.0), radiance=(50.0, 50.0, 50.0)),
                      tmp_path, "s.toml")
    r = render_filtering(lit, "toksvig", env_spp=2, seed=3)
    assert r.image[r.coverage].mean() > 2 * render_filtering(sky, "toksvig", env_spp=2, seed=3).image[r.coverage].mean()


@pytest.mark.parametrize("env_spp", [0, -1, 2.5, True])
def test_environment_sample_count_must_be_a_positive_integer(env_spp):
    s = parse_scene(plane_scene_toml(lights=0, environment="[environment]\nconstant = [1.0, 1.0, 1.0]\n"),
                    Path.cwd(), "s.toml")
    with pytest.raises(WarpbwError, match=r"env_spp"):
        render_filtering(s, "toksvig", env_spp=env_spp)


def _rd_steps(d):
    """Roberts' R_d sequence steps phi^-1 .. phi^-d, phi the real root > 1 of x^(d+1) = x + 1 (numpy's roots)."""
    r = np.roots([1.0] + [0.0] * (d - 1) + [-1.0, -1.0])
    return r[np.abs(r.imag) < 1e-12].real.max() ** -np.arange(1, d + 1)


def test_environment_pairs_step_through_the_r3_and_r2_sequences():
    n = 4096
    u = pair_uniforms(seed=5, pixel=17, n=n).astype(np.float64)
    assert u.shape == (n, 5) and (u >= 0).all() and (u < 1).all()
    # pair k = frac(u_0 + k alpha): R_3 (the BRDF draw), then R_2 (the environment draw); the tolerance is the
    # 32-bit fixed point's (alpha truncated to 2^-32, times k) and float32's 2^-24
    alpha = np.concatenate([_rd_steps(3), _rd_steps(2)])
    dev = (u - u[0] - np.arange(n)[:, None] * alpha) % 1.0
    assert np.minimum(dev, 1.0 - dev).max() < 2e-6
    # the offset is drawn per pixel and per seed
    assert not np.allclose(pair_uniforms(5, 18, 1)[0], u[0]) and not np.allclose(pair_uniforms(6, 17, 1)[0], u[0])


def _box_discrepancy(p):
    """max over the boxes [0, a) x [0, b), a and b multiples of 1/8, of |fraction of the points inside - a b|."""
    g = np.arange(1, 9) / 8
    inside = (p[:, 0, None, None] < g[:, None]) & (p[:, 1, None, None] < g[None, :])
    return np.abs(inside.mean(0) - g[:, None] * g[None, :]).max()


def test_environment_pairs_cover_the_square_more_evenly_than_independent_uniforms():
    # 64 pairs per pixel, over 64 pixels: the 2D points that place the BRDF draw (columns 1, 2) and the
    # environment draw (3, 4) have a box discrepancy near 0.05; independent uniforms average about 0.11
    pts = [pair_uniforms(seed=0, pixel=i, n=64) for i in range(64)]
    rng = np.random.default_rng(0)
    assert np.mean([_box_discrepancy(rng.random((64, 2))) for _ in range(64)]) > 0.09   # the yardstick
    for cols in ((1, 2), (3, 4)):
        assert np.mean([_box_discrepancy(p[:, cols]) for p in pts]) < 0.07, cols


# ------------------------------------------------------------------------------------------ the lobes' BRDF sampler

@wp.kernel(module="unique", enable_backward=False)
def _lobes_sample_kernel(lobes: wp.array(dtype=Lobes), nl: int, wo: wp.vec3, pl: PlaneData,
                         u: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.vec3)):
    """The renderer's ``lobes_sample`` for the uniforms u[i]."""
    i = wp.tid()
    out[i] = lobes_sample(lobes[0], nl, wo, pl, u[i])


@wp.kernel(module="unique", enable_backward=False)
def _sample_pdf_kernel(lobes: wp.array(dtype=Lobes), nl: int, wo: wp.vec3, pl: PlaneData,
                       wi: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.float32)):
    """The renderer's ``sample_pdf`` at wi[i], with D and the total weight from ``lobes_ndf`` (as env_mis_term)."""
    i = wp.tid()
    h = wp.normalize(wi[i] + wo)
    D, at = lobes_ndf(lobes[0], nl, h)
    out[i] = sample_pdf(D, at, h, wi[i], wo, pl)


# Rows (a, mu_x, mu_y, s_xx, s_yy, s_xy): anisotropic lobes with correlations +0.73 and -0.35, their means at least
# 4 standard deviations inside the unit disk (tails beyond it, whose draws are lost, carry < 1e-4 of the mass).
SAMPLER_LOBES = {"one": [(1.0, 0.2, -0.1, 0.03, 0.02, 0.018)],
                 "two": [(0.6, 0.2, -0.1, 0.03, 0.02, 0.018), (0.4, -0.25, 0.15, 0.01, 0.03, -0.006)]}
SAMPLER_WO = np.array([math.sin(0.6) * math.cos(0.4), math.sin(0.6) * math.sin(0.4), math.cos(0.6)])


def _lobes_args(rows, q):
    L = np.zeros((1, MAX_LOBES, 6), np.float32)
    L[0, :len(rows)] = rows
    pl = PlaneData()
    pl.diffuse_pick = q
    return [wp.array(L, dtype=Lobes), len(rows), wp.vec3(*SAMPLER_WO), pl]


def lobes_sample_np(rows, q, u) -> np.ndarray:
    out = wp.zeros(len(u), dtype=wp.vec3)
    wp.launch(_lobes_sample_kernel, dim=len(u),
              inputs=_lobes_args(rows, q) + [wp.array(np.asarray(u, np.float32), dtype=wp.vec3), out])
    return out.numpy().astype(np.float64)


def sample_pdf_np(rows, q, wi) -> np.ndarray:
    out = wp.zeros(len(wi), dtype=wp.float32)
    wp.launch(_sample_pdf_kernel, dim=len(wi),
              inputs=_lobes_args(rows, q) + [wp.array(np.asarray(wi, np.float32), dtype=wp.vec3), out])
    return out.numpy().astype(np.float64)


def numpy_lobes_pdf(rows, q, wi, wo=SAMPLER_WO):
    """The BRDF strategy's solid-angle pdf as warpbw.filtering documents it: with probability 1 - q the lobes'
    mixture of 2D Gaussians over the projected half vector h (weights a_k / sum a), times h_z / (4 wo.h); with
    probability q the cosine-weighted wi_z / pi."""
    h = wi + wo
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    D = np.zeros(len(wi))
    for a, mx, my, sxx, syy, sxy in rows:
        S = np.array([[sxx, sxy], [sxy, syy]])
        d = h[:, :2] - (mx, my)
        e = np.einsum("ni,ij,nj->n", d, np.linalg.inv(S), d)
        D += a * np.exp(-0.5 * e) / (2 * np.pi * np.sqrt(np.linalg.det(S)))
    total = sum(r[0] for r in rows)
    return (1 - q) * D / total * h[:, 2] / (4 * np.maximum(h @ wo, MIN_COS)) + q * np.maximum(wi[:, 2], 0) / np.pi


@pytest.mark.parametrize("lobes", list(SAMPLER_LOBES))
def test_lobe_draws_have_the_lobes_mean_and_covariance(lobes):
    """The lobe branch of ``lobes_sample`` (u[0] >= diffuse_pick) draws the projected half vector from the lobes'
    Gaussian mixture (module docstring: weight, mean, 2x2 covariance).  Its half vector, the bisector of wi and
    wo, must have the mixture's mean sum a mu and covariance sum a (S + mu mu^T) - mean mean^T, computed in numpy
    from the rows.  Tolerance: 5 standard errors of each sample moment (estimated from the draws)."""
    rows = SAMPLER_LOBES[lobes]
    q = DIFFUSE_PICK_MIN
    n = 200_000
    u = np.random.default_rng(7).uniform(size=(n, 3))
    u[:, 0] = q + (1 - q) * u[:, 0]                      # the lobes, never the Lambert term
    wi = lobes_sample_np(rows, q, u)
    drawn = ~np.all(wi == (0.0, 0.0, -1.0), axis=1)      # (0, 0, -1): a half vector off the disk, lost
    assert drawn.mean() > 0.999
    h = wi[drawn] + SAMPLER_WO
    x = (h / np.linalg.norm(h, axis=1, keepdims=True))[:, :2]
    a = np.array([r[0] for r in rows]) / sum(r[0] for r in rows)
    mu = np.array([r[1:3] for r in rows])
    S = np.array([[[r[3], r[5]], [r[5], r[4]]] for r in rows])
    mean = a @ mu
    cov = np.einsum("k,kij->ij", a, S + mu[:, :, None] * mu[:, None, :]) - np.outer(mean, mean)
    m = x.mean(0)
    assert np.all(np.abs(m - mean) < 5 * x.std(0) / np.sqrt(len(x))), (m, mean)
    d = x - m
    prods = np.stack([d[:, 0] ** 2, d[:, 1] ** 2, d[:, 0] * d[:, 1]], 1)
    want = np.array([cov[0, 0], cov[1, 1], cov[0, 1]])
    got = prods.mean(0)
    assert np.all(np.abs(got - want) < 5 * prods.std(0) / np.sqrt(len(x))), (got, want)


@pytest.mark.parametrize("lobes", list(SAMPLER_LOBES))
def test_lobe_sampler_follows_its_pdf(lobes):
    """Histogram of ``lobes_sample``'s directions (Lambert term and lobes, diffuse_pick 0.1) in equal-solid-angle
    cells (16 bands of wi_z x 32 of azimuth, plus one for lost draws) against ``sample_pdf`` integrated over each
    cell by midpoint quadrature (32 x 32 points a cell), which MIS under an environment assumes; ``sample_pdf``
    is itself checked against its documented formula re-derived in numpy (``numpy_lobes_pdf``)."""
    rows = SAMPLER_LOBES[lobes]
    q = DIFFUSE_PICK_MIN
    nz, nphi, sub = 16, 32, 32

    def cell(w):
        iz = np.minimum((w[:, 2] * nz).astype(int), nz - 1)
        ip = np.minimum((np.mod(np.arctan2(w[:, 1], w[:, 0]), 2 * np.pi) / (2 * np.pi) * nphi).astype(int), nphi - 1)
        return iz * nphi + ip

    z = (np.arange(nz * sub) + 0.5) / (nz * sub)
    ph = (np.arange(nphi * sub) + 0.5) / (nphi * sub) * 2 * np.pi
    Z, P = np.meshgrid(z, ph, indexing="ij")
    r = np.sqrt(1 - Z * Z)
    wq = np.stack([r * np.cos(P), r * np.sin(P), Z], -1).reshape(-1, 3)
    pdf = sample_pdf_np(rows, q, wq)
    assert np.allclose(pdf, numpy_lobes_pdf(rows, q, wq), rtol=1e-4, atol=1e-5)
    mass = np.bincount(cell(wq), weights=pdf * (2 * np.pi / (nz * nphi * sub * sub)), minlength=nz * nphi)
    assert 0.98 < mass.sum() <= 1.0 + 1e-4              # the rest: draws whose wi leaves the hemisphere
    n = 200_000
    wi = lobes_sample_np(rows, q, np.random.default_rng(11).uniform(size=(n, 3)))
    up = wi[:, 2] > 0
    observed = np.append(np.bincount(cell(wi[up]), minlength=nz * nphi), (~up).sum()).astype(np.float64)
    expected = n * np.append(mass, 1.0 - mass.sum())
    # Pearson's chi-square, cells expecting fewer than 5 draws pooled into one; bound: dof + 5 sd of the chi-square
    # distribution (sqrt(2 dof)).  The quadrature's error (doubling its points per axis moves no cell by more than
    # 1 draw in these 2 x 10^5) is well inside a cell's Poisson noise.
    small = expected < 5
    obs = np.append(observed[~small], observed[small].sum())
    exp = np.append(expected[~small], expected[small].sum())
    chi2 = float(np.sum((obs - exp) ** 2 / exp))
    dof = len(exp) - 1
    assert chi2 < dof + 5 * math.sqrt(2 * dof), (lobes, chi2, dof)




REC709_LUMINANCE = np.array([0.2126, 0.7152, 0.0722])   # ITU-R BT.709 luminance of linear RGB


@settings(max_examples=60, deadline=None)
@given(diffuse=st.lists(st.floats(0.0, 1.0), min_size=3, max_size=3),
       f0=st.lists(st.floats(0.0, 1.0), min_size=3, max_size=3), channel=st.integers(0, 2), more=st.floats(0.0, 1.0))
def test_diffuse_pick_is_the_diffuse_luminance_share_kept_off_zero_and_one(diffuse, f0, channel, more):
    """diffuse_pick is the diffuse albedo's share of the diffuse + f0 luminance (Rec. 709 weights), clamped to
    [DIFFUSE_PICK_MIN, 1 - DIFFUSE_PICK_MIN] (1/2 when both are black); so more diffuse in any channel never
    lowers it and more f0 never raises it."""
    d, f = np.array(diffuse), np.array(f0)
    ld, ls = REC709_LUMINANCE @ d, REC709_LUMINANCE @ f
    share = ld / (ld + ls) if ld + ls > 0 else 0.5
    q = diffuse_pick(d, f)
    # BT.709 prints 4 digits; weights of more digits (0.212671, ...) differ by at most 4.3e-4 of a weight, which
    # moves a share s by at most 2 * 4.3e-4 * s (1 - s) <= 2.2e-4
    assert q == pytest.approx(min(max(share, DIFFUSE_PICK_MIN), 1 - DIFFUSE_PICK_MIN), abs=2.5e-4)
    bump = np.zeros(3)
    bump[channel] = more
    assert diffuse_pick(d + bump, f) >= q - 1e-12
    assert diffuse_pick(d, f + bump) <= q + 1e-12

@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), nl=st.integers(1, 3), q=st.floats(DIFFUSE_PICK_MIN, 0.9),
       theta_o=st.floats(0.0, 1.2), phi_o=st.floats(-math.pi, math.pi))
def test_lobe_sampler_pdf_holds_the_mass_of_the_draws_it_keeps_for_any_lobes_and_view(seed, nl, q, theta_o, phi_o):
    """For random lobes (weights, means, correlated covariances), any view up to 69 degrees and any diffuse_pick:
    ``sample_pdf`` is the documented formula (``numpy_lobes_pdf``) and is never negative, and its integral over
    the upper hemisphere (midpoint rule, 256 x 512 equal-solid-angle cells) is the share of ``lobes_sample``'s
    draws that land there (5 x 10^4 draws; bound: 5 binomial standard errors plus 2e-3 for the quadrature),
    at most 1: what leaves the hemisphere (a half vector off the disk, a reflection below the horizon) is lost
    from both alike."""
    rng = np.random.default_rng(seed)
    rows = []
    for _ in range(nl):
        ev, ang = rng.uniform(0.004, 0.03, 2), rng.uniform(0.0, math.pi)
        R = np.array([[math.cos(ang), -math.sin(ang)], [math.sin(ang), math.cos(ang)]])
        S = R @ np.diag(ev) @ R.T
        r, t = rng.uniform(0.0, 0.3), rng.uniform(0.0, 2 * math.pi)
        rows.append((rng.uniform(0.1, 1.0), r * math.cos(t), r * math.sin(t), S[0, 0], S[1, 1], S[0, 1]))
    wo = np.array([math.sin(theta_o) * math.cos(phi_o), math.sin(theta_o) * math.sin(phi_o), math.cos(theta_o)])
    L = np.zeros((1, MAX_LOBES, 6), np.float32)
    L[0, :nl] = rows
    pl = PlaneData()
    pl.diffuse_pick = q
    args = [wp.array(L, dtype=Lobes), nl, wp.vec3(*wo), pl]
    nz, nphi = 256, 512
    z = (np.arange(nz) + 0.5) / nz
    ph = (np.arange(nphi) + 0.5) / nphi * 2 * np.pi
    Z, P = np.meshgrid(z, ph, indexing="ij")
    rr = np.sqrt(1 - Z * Z)
    wq = np.stack([rr * np.cos(P), rr * np.sin(P), Z], -1).reshape(-1, 3)
    pdf = wp.zeros(len(wq), dtype=wp.float32)
    wp.launch(_sample_pdf_kernel, dim=len(wq), inputs=args + [wp.array(wq.astype(np.float32), dtype=wp.vec3), pdf])
    pdf = pdf.numpy().astype(np.float64)
    assert pdf.min() >= 0.0
    np.testing.assert_allclose(pdf, numpy_lobes_pdf(rows, q, wq, wo), rtol=2e-4, atol=1e-5)
    mass = pdf.sum() * 2 * np.pi / (nz * nphi)
    n = 50_000
    out = wp.zeros(n, dtype=wp.vec3)
    wp.launch(_lobes_sample_kernel, dim=n, inputs=args + [wp.array(rng.uniform(size=(n, 3)).astype(np.float32),
                                                                     dtype=wp.vec3), out])
    kept = float(np.mean(out.numpy()[:, 2] > 0.0))
    assert mass <= 1.0 + 2e-3
    assert abs(mass - kept) < 5 * math.sqrt(max(kept * (1 - kept), 1e-4) / n) + 2e-3, (mass, kept)


@wp.kernel(module="unique", enable_backward=False)
def _lobes_env_kernel(lobes: wp.array(dtype=Lobes), nl: int, wo: wp.vec3, pl: PlaneData, env: EnvMapData, seed: int,
                      n: int, out: wp.array(dtype=wp.vec3)):
    """The renderer's ``lobes_env``: n pairs of estimate i from its own random offset (as pixel i's)."""
    i = wp.tid()
    r, state = pair_offset(wp.rand_init(seed, i))
    out[i] = lobes_env(lobes[0], nl, wo, pl, env, r, 0, n)


def numpy_lobes_cos(rows, wi, wo, f0, diffuse):
    """The lobes' BRDF times wi_z as the module docstring writes it (004 Sec. 3), in float64: F(u) D(h) / (4 wo_z)
    + diffuse / pi (1 - F(u)) sum_k a_k max(n_k . wi, 0), D the lobes' mixture of 2D Gaussians over the projected
    half vector, n_k the unit normal of projection mu_k (horizontal, along mu_k, for a mean off the unit disk)."""
    h = wi + wo
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    D = np.zeros(len(wi))
    lamb = np.zeros(len(wi))
    for a, mx, my, sxx, syy, sxy in rows:
        S = np.array([[sxx, sxy], [sxy, syy]])
        d = h[:, :2] - (mx, my)
        D += a * np.exp(-0.5 * np.einsum("ni,ij,nj->n", d, np.linalg.inv(S), d)) / (2 * np.pi * math.sqrt(
            np.linalg.det(S)))
        r2 = mx * mx + my * my
        n = np.array([mx, my, math.sqrt(1 - r2)]) if r2 <= 1 else np.array([mx, my, 0.0]) / math.sqrt(r2)
        lamb += a * np.maximum(wi @ n, 0.0)
    F = np.asarray(f0) + (1 - np.asarray(f0)) * (1 - np.clip(np.sum(h * wo, -1), 0, None)[:, None]) ** 5
    return F * (D / (4 * wo[2]))[:, None] + np.asarray(diffuse) / np.pi * (1 - F) * lamb[:, None]


# (a, mu_x, mu_y, s_xx, s_yy, s_xy): a weightless lobe first (the pick skips it), a correlated one, a lobe whose
# mean lies off the unit disk (most of its draws lost, its Lambert normal horizontal) and a wide one
ENV_LOBES = [(0.0, 0.3, 0.3, 0.01, 0.01, 0.0), (0.45, 0.2, -0.1, 0.04, 0.06, 0.035),
             (0.2, 1.05, 0.0, 0.05, 0.05, 0.0), (0.35, -0.3, 0.2, 0.25, 0.2, -0.05)]


@pytest.mark.parametrize("theta_o, q", [(20.0, 0.1), (80.0, 0.5)])
def test_lobes_environment_term_is_the_hemisphere_integral_under_a_lat_long_map(theta_o, q):
    """``lobes_env`` (balance heuristic over one BRDF and one environment sample per pair) estimates the integral
    over the upper hemisphere of L_env(wi) times the lobes' BRDF times wi_z: for the lobes above under a rotated
    32 x 64 map of smooth colours and a bright patch, against a midpoint quadrature (600 x 1200 cells in theta,
    phi) of the module docstring's bracket re-derived in numpy (``numpy_lobes_cos``) times the map's radiance
    (``warpbw.envmap.eval_radiance``).  8192 estimates of 64 pairs each; bound: 4.5 standard errors of their mean
    (estimated from them) plus 2e-4 of the integral for the quadrature.  Seen failing, by 11 to 1500 standard
    errors: MIS with the BRDF strategy's pdf alone, lobes picked uniformly (not by weight), the sampler's
    correlation term with the wrong sign, the lobe pdf without h_z, and the Lambert cosine unclamped."""
    f0, diffuse = (0.04, 0.5, 0.9), (0.6, 0.3, 0.1)
    H, W = 32, 64
    v = (np.arange(H) / (H - 1))[:, None]
    u = ((np.arange(W) + 0.5) / W)[None, :]
    one = np.ones((H, W))
    img = np.stack([1 + 0.5 * np.sin(2 * np.pi * u) * np.cos(np.pi * v), 0.5 + 0.3 * np.cos(4 * np.pi * u + 1) * one,
                    0.2 + v * one], -1)
    img[6:9, 20:24] += 40.0
    env = envmap_from_array(img.astype(np.float32), rotation_deg=30.0)
    wo = np.array([math.sin(math.radians(theta_o)), 0.0, math.cos(math.radians(theta_o))])
    nt, nph = 600, 1200
    T, P = np.meshgrid((np.arange(nt) + 0.5) / nt * np.pi / 2, (np.arange(nph) + 0.5) / nph * 2 * np.pi, indexing="ij")
    wi = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(-1, 3)
    dw = (np.sin(T) * (np.pi / 2 / nt) * (2 * np.pi / nph)).reshape(-1, 1)
    world = np.stack([wi[:, 0], wi[:, 2], -wi[:, 1]], -1)        # the plane's frame: x = +X, y = -Z, z = +Y
    truth = np.sum(eval_radiance(env, world).astype(np.float64) * numpy_lobes_cos(ENV_LOBES, wi, wo, f0, diffuse)
                   * dw, 0)
    L = np.zeros((1, MAX_LOBES, 6), np.float32)
    L[0, :len(ENV_LOBES)] = ENV_LOBES
    pl = PlaneData()
    pl.f0, pl.diffuse, pl.diffuse_pick = wp.vec3(*f0), wp.vec3(*diffuse), q
    n = 8192
    out = wp.zeros(n, dtype=wp.vec3)
    wp.launch(_lobes_env_kernel, dim=n, inputs=[wp.array(L, dtype=Lobes), len(ENV_LOBES), wp.vec3(*wo), pl, env.data,
                                                5, 64, out])
    est = out.numpy().astype(np.float64)
    mean, se = est.mean(0), est.std(0) / math.sqrt(n)
    assert np.all(np.abs(mean - truth) < 4.5 * se + 2e-4 * truth), (mean, truth, (mean - truth) / se)


def _translated(text: str, c) -> str:
    """The scene moved rigidly by c: the plane's centre and the camera's position and look-at point (each key
    found once, so that a change of plane_scene_toml cannot leave the scene unmoved and the test passing)."""
    cam_old = text.split("position = ")[1].split("\n")[0]
    pos = [float(v) for v in cam_old.strip("[]").split(",")]
    for old, new in ((f"position = {cam_old}", f"position = {[p + d for p, d in zip(pos, c)]}"),
                     ("look_at = [0.0, 0.0, 0.0]", f"look_at = {list(map(float, c))}"),
                     ('shape = "plane"', f'shape = "plane"\ncenter = {list(map(float, c))}')):
        assert text.count(old) == 1 and "center = " not in text, old
        text = text.replace(old, new)
    return text


@pytest.mark.parametrize("method", ["fixed", "ground_truth"])
def test_moving_plane_camera_and_look_at_together_leaves_the_image_unchanged(tmp_path, method):
    """Directional lights do not depend on position, so a rigid translation of the whole scene (plane, camera, look-at
    point) is invisible.  A normal map that stays glued to world X or Z instead of to the plane's own corner would
    slide under a plane that is not centred at the origin."""
    write_exr(tmp_path / "map.exr", np.asarray(hemispherical_scales(32, scales_across=4), np.float32)[..., None],
              channels=["Y"])
    text = plane_scene_toml('normal_map = "map.exr"\nnormal_map_scale = 0.5\ntiling = 2\n', roughness=0.1,
                            position=(0.0, 1.2, 1.2), resolution=(24, 16))
    images = []
    for c in ((0.0, 0.0, 0.0), (0.37, 0.25, -0.61)):
        s = parse_scene(_translated(text, c), tmp_path, "s.toml")
        images.append(render_filtering(s, method, spp=64))
    a, b = images
    both = a.coverage & b.coverage
    assert both.sum() > 0.9 * max(a.coverage.sum(), b.coverage.sum())
    scale = np.linalg.norm(a.image[both], axis=-1).mean()
    err = np.linalg.norm(a.image[both] - b.image[both], axis=-1).mean() / scale
    assert err < 2e-3, err


_UNIT_LIGHT_FRAMES = {}


@settings(max_examples=10, deadline=None)
@given(log_k=st.floats(-4.0, 4.0), method=st.sampled_from(ALL_METHODS))
def test_lights_and_environment_k_times_brighter_give_k_times_the_frame_at_the_same_levels(tmp_path_factory, log_k,
                                                                                           method):
    """Light is linear and a footprint is geometry: a normal-mapped plane under a directional light and the sky, both
    scaled by k (1e-4 to 1e4), renders k times the frame at the same mip levels, by every method (the same seed).
    Measured (session 68, 32 x 24, k = 1e-4 ... 1e4, each method under lights, the sky and both): levels identical,
    image / k within 2.1e-5 of the unit frame (relative, pixels above 1e-4 of the brightest)."""
    if "folder" not in _UNIT_LIGHT_FRAMES:                 # one noisy height map for every example
        _UNIT_LIGHT_FRAMES["folder"] = tmp_path_factory.mktemp("exposure")
        heights = np.random.default_rng(1).standard_normal((32, 32)) * 0.05
        write_exr(_UNIT_LIGHT_FRAMES["folder"] / "map.exr", heights.astype(np.float32)[..., None], channels=["Y"])
    folder = _UNIT_LIGHT_FRAMES["folder"]
    k = 10.0 ** log_k

    def frame(scale):
        text = plane_scene_toml('normal_map = "map.exr"\nnormal_map_scale = 1.0\ntiling = 2\n', resolution=(32, 24),
                                radiance=[c * scale for c in PLANE_RADIANCE],
                                environment=f'[environment]\nprocedural = "sky"\nscale = {scale!r}\n')
        return render_filtering(parse_scene(text, folder, "s.toml"), method, spp=MIN_GT_SPP, seed=2, env_spp=8)

    if method not in _UNIT_LIGHT_FRAMES:
        _UNIT_LIGHT_FRAMES[method] = frame(1.0)
    one, bright = _UNIT_LIGHT_FRAMES[method], frame(float(k))
    cov = one.coverage
    assert cov.sum() > 200 and np.array_equal(bright.coverage, cov)
    assert np.array_equal(bright.level, one.level)
    assert method == "ground_truth" or np.ptp(one.level[cov]) > 0.5        # the footprints span levels
    lit = cov[..., None] & (one.image > 1e-4 * one.image[cov].max())
    np.testing.assert_allclose(bright.image[lit] / one.image[lit], k, rtol=1e-4)


def _quarter_turns(v, k: int) -> list:
    """``v`` turned k quarter turns about +Y, right-handed (warpbw.envmap's R: (x, y, z) -> (z, y, -x)), exactly."""
    x, y, z = v
    for _ in range(k):
        x, z = z, -x
    return [x, y, z]


@pytest.mark.filterwarnings("ignore:height field of")   # small random maps hold much texel-to-texel detail
@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), rows=st.sampled_from((4, 8, 16)), cols=st.sampled_from((4, 8, 16)),
       k=st.integers(1, 3),
       method=st.sampled_from(("fixed", "toksvig", "lean", "ground_truth")))
def test_camera_light_and_height_map_turned_about_the_plane_give_the_same_frame(tmp_path_factory, seed, rows, cols,
                                                                                k, method):
    """The plane has no preferred direction: the camera and the light turned k quarter turns about its centre (+Y),
    and its height map turned with them (np.rot90(h, k): the plane lays column j at u = (j + 1/2) / W along +X and
    row i at v = (i + 1/2) / H along +Z), render the same frame at the same levels, for a square map or not -- a
    W x H map spans the plane's unit square, so its rows lie 1 / H apart.  Powers of two: an odd side's coarser
    levels clip their last texel's footprint, which a turn moves to the first (9 x 4 turned twice: 11%).  Measured
    (session 69, 48 x 36, a 64 x 64 and a 64 x 32 map, each deterministic method and the ground truth): within 9e-6
    of the brightest pixel; the 64 x 32 map's rows were differentiated over 1 / W, and its turned frame differed by
    64% on average."""
    folder = tmp_path_factory.mktemp("turned")
    heights = np.random.default_rng(seed).standard_normal((rows, cols)) * 0.02
    frames = []
    for turns, h in ((0, heights), (k, np.rot90(heights, k))):
        write_exr(folder / f"map{turns}.exr", np.ascontiguousarray(h, np.float32)[..., None], channels=["Y"])
        text = plane_scene_toml(f'normal_map = "map{turns}.exr"\nnormal_map_scale = 1.0\ntiling = 2\n',
                                resolution=(24, 16), position=_quarter_turns((0.4, 1.5, 2.0), turns),
                                light_dir=_quarter_turns(PLANE_LIGHT_DIR, turns))
        frames.append(render_filtering(parse_scene(text, folder, "s.toml"), method, spp=MIN_GT_SPP, seed=2))
    a, b = frames
    assert a.coverage.sum() > 200 and np.array_equal(a.coverage, b.coverage)
    np.testing.assert_allclose(b.level, a.level, atol=1e-4)
    np.testing.assert_allclose(b.image, a.image, atol=1e-4 * float(a.image.max()))


_TILED = {}


@pytest.mark.filterwarnings("ignore:height field of")   # small random maps hold much texel-to-texel detail
@settings(max_examples=10, deadline=None)
@given(n=st.integers(2, 4), zoom=st.floats(0.25, 4.0), lod_bias=st.floats(-1.5, 3.0),
       method=st.sampled_from(("fixed", "toksvig", "lean", "ground_truth")))
def test_tiling_n_is_the_map_tiled_n_times_at_one_nth_the_scale(tmp_path_factory, n, zoom, lod_bias, method):
    """A plane's texel coordinates are (u, v) tiling (W, H), so ``tiling = n`` with a W x W map reads the same texels as
    ``tiling = 1`` with the map tiled n x n (np.tile), whose width is n times the map's: its heights, in units of its
    width, shade alike at 1/n the scale.  Level l of both pyramids holds the same texels (a power-of-two map's level-l
    texel covers 2^l x 2^l finest ones, the tiled one's whole copies beyond its own top), so every zoom and LOD bias
    gives the same frame.  Measured (session 69, 48 x 36, dunes 8 x 8 and 32 x 32, zoom 0.25-16, levels -1 to 6):
    identical to the bit, but for the reported level, which stops at the single map's top."""
    if "folder" not in _TILED:
        _TILED["folder"] = tmp_path_factory.mktemp("tiled")
        _TILED["h"] = np.random.default_rng(7).standard_normal((8, 8)) * 0.02
    folder, h = _TILED["folder"], _TILED["h"]
    frames = []
    for tiling, heights, scale in ((n, h, 1.0), (1, np.tile(h, (n, n)), 1.0 / n)):
        name = f"map{n}_{tiling}.exr"
        if not (folder / name).exists():
            write_exr(folder / name, heights.astype(np.float32)[..., None], channels=["Y"])
        s = parse_scene(plane_scene_toml(f'normal_map = "{name}"\nnormal_map_scale = {scale!r}\ntiling = {tiling}\n',
                                         resolution=(32, 24), lights=2), folder, "s.toml")
        frames.append(render_filtering(s, method, spp=MIN_GT_SPP, seed=2, lod_bias=lod_bias,
                                       camera=zoomed_camera(s.camera, zoom)))
    a, b = frames
    assert a.coverage.sum() > 10 and np.array_equal(a.coverage, b.coverage)
    below_top = a.coverage & (a.level < 3.0)              # the single 8 x 8 map's top is level 3
    np.testing.assert_allclose(b.level[below_top], a.level[below_top], atol=1e-5)
    np.testing.assert_allclose(b.image, a.image, rtol=1e-5, atol=1e-6 * float(a.image.max()))


def test_a_light_below_the_plane_lights_nothing_whatever_the_method(tmp_path):
    """A directional light under the plane's macro surface (its direction has y < 0) reaches no point of the plane's
    upper side: every method's image is black there, the filtered ones as the ground truth.  A tilted lobe mean or a
    half-vector that still falls inside a wide lobe must not let such a light leak in."""
    write_exr(tmp_path / "map.exr", np.asarray(hemispherical_scales(32, scales_across=4), np.float32)[..., None],
              channels=["Y"])
    s = parse_scene(plane_scene_toml('normal_map = "map.exr"\nnormal_map_scale = 0.5\ntiling = 4\n',
                                     roughness=0.3, position=(0.0, 1.2, 1.2), light_dir=(0.2, -0.08, -1.0)),
                    tmp_path, "s.toml")
    methods = [m for m in ALL_METHODS if m != "gmm_unaligned"]   # its kernel is gmm_aligned's
    prep = prepare_filtering(s, methods)
    for m in methods:
        r = render_filtering(s, m, prepared=prep, spp=64)
        assert r.coverage.sum() > 100
        assert float(np.abs(r.image[r.coverage]).max()) == 0.0, m
    # the same light moved above the plane does light it (the scene is not black for another reason)
    s_up = parse_scene(plane_scene_toml('normal_map = "map.exr"\nnormal_map_scale = 0.5\ntiling = 4\n',
                                        roughness=0.3, position=(0.0, 1.2, 1.2), light_dir=(0.2, 0.08, -1.0)),
                       tmp_path, "s.toml")
    r = render_filtering(s_up, "fixed", prepared=prepare_filtering(s_up, ("fixed",)))
    assert float(r.image[r.coverage].max()) > 1e-3


def test_mean_level_in_the_stats_averages_the_covered_pixels_only(tmp_path):
    """stats["mean_level"] is the mean mip level of the pixels the plane covers; the uncovered pixels' level map holds
    0, which must not pull the figure towards the finest level.  A plane seen far off covers part of the frame at
    levels well above 0, so the two means differ by a wide margin."""
    s = scene_with_map(tmp_path, heights=hemispherical_scales(32, scales_across=4), scale=0.5, tiling=4,
                       position=(0.0, 4.0, 6.0), size=2.0, resolution=(24, 16), roughness=0.1)
    r = render_filtering(s, "fixed")
    cov = r.coverage
    assert 0.05 < cov.mean() < 0.8
    want = float(r.level[cov].astype(np.float64).mean())
    assert want > 1.0
    assert r.stats["mean_level"] == pytest.approx(want, rel=1e-5)
    assert abs(r.stats["mean_level"] - float(r.level.mean())) > 0.2


def test_ground_truth_shades_each_ray_with_the_unit_normal_between_two_tilted_texels(tmp_path):
    """Two columns of normals tilted 30 degrees apart in opposite directions, seen from straight above so close that a
    pixel covers about a hundredth of a texel: each ground-truth pixel is then the fine-scale BRDF at its centre, at
    the bilinear blend of the two normals renormalised to unit length (between the texels the blend is 13% short of
    unit length: an unnormalised one darkens the Lambert term and pulls the specular lobe in). Truth:
    numpy_filtered_render, whose pixels here are all magnified past level -1 (the fine-scale lobe only)."""
    t = math.radians(30.0)
    normals = np.zeros((2, 2, 3), np.float32)
    normals[:, 0] = (math.sin(t), 0.0, math.cos(t))
    normals[:, 1] = (-math.sin(t), 0.0, math.cos(t))
    write_exr(tmp_path / "map.exr", normals, channels=["R", "G", "B"])
    s = parse_scene(plane_scene_toml('normal_map = "map.exr"\nnormal_map_kind = "normal"\n', roughness=0.3,
                                     position=(0.0, 0.6, 1e-4), resolution=(16, 12), fov=20.0, size=2.0,
                                     diffuse=(0.5, 0.4, 0.3), lights=2), tmp_path, "s.toml")
    prep = prepare_filtering(s, ("ground_truth", "fixed"))
    gt = render_filtering(s, "ground_truth", spp=64, prepared=prep)
    ref, lam = numpy_filtered_render(s, "fixed", normals, {}, 1.0)
    cov = gt.coverage
    assert cov.all() and np.all(lam <= -1.0)
    err = np.linalg.norm(gt.image - ref, axis=-1).max() / np.linalg.norm(ref, axis=-1).mean()
    assert err < 5e-3, err


def test_ground_truth_lambert_term_follows_each_rays_fine_normal(tmp_path):
    """A uniform normal map tilted 30 degrees: every ray's fine-scale BRDF (specular and Lambert) is the one at that
    normal, so the ground truth is this module's numpy re-derivation of 004 Sec. 3's BRDF at the tilted normal
    (the second light sits where the tilted normal's cosine is a quarter of the plane's)."""
    t = math.radians(30.0)
    normals = np.broadcast_to(np.array([math.sin(t), 0.0, math.cos(t)], np.float32), (2, 2, 3))
    s = scene_with_map(tmp_path, normals=normals, roughness=0.3, position=(0.0, 0.6, 1e-4), resolution=(16, 12),
                       fov=20.0, size=2.0, diffuse=(0.5, 0.4, 0.3), lights=2)
    prep = prepare_filtering(s, ("ground_truth",))
    gt = render_filtering(s, "ground_truth", spp=64, prepared=prep)
    ref, _ = numpy_filtered_render(s, "fixed", normals, {}, 1.0)
    assert gt.coverage.all()
    err = np.linalg.norm(gt.image - ref, axis=-1).max() / np.linalg.norm(ref, axis=-1).mean()
    assert err < 5e-3, err


def test_a_map_twice_as_wide_as_high_filters_as_documented(tmp_path):
    """A 16-row x 32-column height map (every benchmark map is square): toksvig, lean and fixed render what
    this module's numpy re-derivation of the documentation gives (footprint, level, trilinear filter with the
    rows and columns of each level, lobes, shading), levels to 1e-4 and images to 1e-3 of the mean colour."""
    from precompute.surfaces import height_to_normals

    r, c = np.meshgrid(np.arange(16) / 16.0, np.arange(32) / 32.0, indexing="ij")
    h = 0.3 * np.sin(2 * np.pi * 3 * c) * np.cos(2 * np.pi * 2 * r) + 0.2 * np.sin(2 * np.pi * (r + 2 * c))
    s = scene_with_map(tmp_path, heights=h, scale=0.5, tiling=4, roughness=0.15, diffuse=(0.5, 0.4, 0.3), lights=2)
    normals = height_to_normals(h, 0.5)
    prep = prepare_filtering(s, ("toksvig", "lean", "fixed"))
    for m in ("toksvig", "lean", "fixed"):
        res = render_filtering(s, m, prepared=prep)
        ref, lam = numpy_filtered_render(s, m, normals, {}, 1.0)
        cov = res.coverage
        assert cov.sum() > 100 and lam[cov].max() > 1.5, m     # the coarser levels are read too
        assert np.allclose(res.level[cov], lam[cov], atol=1e-4), m
        err = np.abs(res.image[cov] - ref[cov]).max() / np.linalg.norm(ref[cov], axis=-1).mean()
        assert err < 1e-3, (m, err)


def test_anisotropic_footprints_elongated_along_the_columns_filter_as_documented(tmp_path):
    """The grazing camera of test_filtering turned 90 degrees about +Y (looking along -X, so footprints are longer
    along the map's columns than its rows, J J^T's p > q): every method's image with up to 16 and 4 probes is the
    numpy re-derivation (footprint and major axis from numpy's SVD of J), as at the camera looking along -Z."""
    x, y, z = grazing_position()
    s, normals, gmm_levels, prep = _scales_with_gmm_files(tmp_path, (z, y, x))
    box = [b[0] for b in numpy_box_mipmap(normals)]
    for max_aniso, zoom in ((16, 1.0), (4, 0.25)):
        _assert_as_documented(s, prep, normals, gmm_levels, zoom, max_aniso)
        _, _, n, _, _ = numpy_footprint(s, zoom, box, max_aniso)
        assert (n > 1).sum() > 50, (max_aniso, zoom)            # most pixels take several probes


def test_a_plane_seen_from_below_shows_nothing(tmp_path):
    """A plane faces +Y (scene docs; plane_t: "front-facing"): a camera below it sees no plane pixel with any method,
    and plane_distance is infinite at every pixel."""
    from warpbw.filtering import plane_distance

    s = parse_scene(plane_scene_toml(position=(0.0, -1.5, 2.0)), tmp_path, "s.toml")
    prep = prepare_filtering(s, ("fixed", "ground_truth"))
    for m in ("fixed", "ground_truth"):
        r = render_filtering(s, m, prepared=prep)
        assert not r.coverage.any() and np.all(r.image == 0), m
    assert np.all(np.isinf(plane_distance(s)))
    above = parse_scene(plane_scene_toml(position=(0.0, 1.5, 2.0)), tmp_path, "s.toml")
    assert render_filtering(above, "fixed").coverage.sum() > 50   # the same plane, seen from above


@pytest.mark.filterwarnings("ignore:height field of")   # a 4 x 4 random map holds much texel-to-texel detail
def test_a_footprint_beyond_the_coarsest_level_is_filtered_at_it_and_reported_as_it(tmp_path):
    """A 4x4 map (3 levels) tiled 32 times, seen straight down from 5 plane half-sizes away: every pixel's footprint
    lies between levels 2 and 3 (the numpy footprint's unclipped lam), past the coarsest level 2,
    so its level is levels - 1 = 2 (FilterResult.level lies in [-1, levels - 1]; the numpy re-derivation clips lam
    there), the mean level is 2, and the image is the re-derivation's at that level."""
    from precompute.surfaces import height_to_normals

    h = np.random.default_rng(7).random((4, 4)) * 0.3
    s = scene_with_map(tmp_path, heights=h, scale=0.5, tiling=32, roughness=0.15, diffuse=(0.5, 0.4, 0.3),
                       position=(0.0, 5.0, 1e-4), fov=40.0)
    normals = height_to_normals(h, 0.5)
    box = [b[0] for b in numpy_box_mipmap(normals)]
    assert len(box) == 3
    _, lam_free, _, _, _ = numpy_footprint(s, 1.0, box * 4)      # clipped at 11 levels: in effect unclipped
    prep = prepare_filtering(s, ("toksvig", "lean", "fixed"))
    for m in ("toksvig", "lean", "fixed"):
        res = render_filtering(s, m, prepared=prep)
        ref, lam = numpy_filtered_render(s, m, normals, {}, 1.0)
        cov = res.coverage
        assert cov.sum() > 50 and np.all((lam_free[cov] > 2.0) & (lam_free[cov] < 3.0)), m
        assert np.all(lam[cov] == 2.0) and np.all(res.level[cov] == 2.0), (m, res.level[cov].max())
        assert res.stats["mean_level"] == 2.0, m
        err = np.abs(res.image[cov] - ref[cov]).max() / np.linalg.norm(ref[cov], axis=-1).mean()
        assert err < 1e-3, (m, err)


@pytest.mark.xfail(strict=True, reason="pixel_footprint takes forward differences (the rays through the next pixel), "
                   "not the pixel box's edges: 1.2 levels too fine below the horizon here; the box's edges raised the "
                   "isotropic benchmark's errors at 10 and 20 degrees (docs/testing.md, session 75), so not changed")
def test_the_level_at_a_grazing_view_is_the_pixel_boxs_extent_up_to_the_horizon(tmp_path):
    """A camera 10 degrees above a large plane (128 units, a 64x64 map tiled 16 times: 8 texels per unit, 7 levels),
    the horizon in the image's top rows: per covered pixel the level is log2 of the pixel box's extent on the plane +
    the LOD bias, clipped to [-1, 6] -- the extent from numpy ray-plane hits of the rays through the midpoints of the
    box's edges (right minus left, bottom minus top, the longer of the two), and the coarsest level where one of
    them misses the plane (the box reaches over the horizon).  The ground truth averages over that box.  The rays
    through the next pixel (forward differences) took the box half a pixel nearer: 1.2 levels too fine in the row
    below the horizon's, finite in the horizon's own row."""
    h = 0.05 * np.outer(np.sin(np.linspace(0.0, 2.0 * np.pi, 64, endpoint=False)), np.ones(64))
    e = math.radians(10.0)
    pos = (0.0, 0.35 * math.sin(e), 0.35 * math.cos(e))
    W, H, size, tiling, mw = 48, 36, 128.0, 16.0, 64
    s = scene_with_map(tmp_path, heights=h, scale=1.0, tiling=tiling, size=size, position=pos, fov=40.0,
                       resolution=(W, H))
    res = render_filtering(s, "fixed")
    o, _ = numpy_camera_rays(pos, (0, 0, 0), 40.0, W, H)

    def hit(jitter):                                # finest-texel coordinates of the hits on y = 0, NaN if none
        r = numpy_camera_rays(pos, (0, 0, 0), 40.0, W, H, jitter=jitter)[1]
        with np.errstate(divide="ignore"):
            t = np.where(r[..., 1] < 0, -o[1] / r[..., 1], np.nan)
        return ((o + t[..., None] * r)[..., [0, 2]] / size + 0.5) * mw * tiling

    box = np.maximum(np.linalg.norm(hit((1.0, 0.5)) - hit((0.0, 0.5)), axis=-1),
                     np.linalg.norm(hit((0.5, 1.0)) - hit((0.5, 0.0)), axis=-1))
    over = np.isnan(box)                            # an edge ray misses: the coarsest level
    with np.errstate(invalid="ignore"):
        lam = np.where(over, 6.0, np.clip(np.log2(box) + LOD_BIAS_DOC, -1.0, 6.0))
    cov = res.coverage
    rows = np.flatnonzero(cov.any(1))
    assert (over & cov).sum() >= W and not over[rows[1:]].any(), rows[:3]   # the horizon's row is covered
    assert np.sum(cov & (lam > -1) & (lam < 6)) > 4 * W                       # unclipped levels in rows below
    err = np.abs(res.level - lam)[cov]
    assert err.max() < 0.01, (err.max(), np.unravel_index(np.argmax(np.where(cov, np.abs(res.level - lam), 0)),
                                                          cov.shape))


def test_ground_truth_is_the_box_average_of_a_highlight_narrower_than_a_pixel(tmp_path):
    """A flat plane seen straight down under a light straight up, roughness 0.015: the centre pixel's highlight is
    about six times brighter at the pixel's centre than on average over it.  The ground truth there (mean of 64
    seeds; one seed's noise is about 5%) is the box average over the pixel: a 64 x 64 grid of rays shaded with
    004 Sec. 3's BRDF in numpy (Gaussian NDF of variance m^2 / 2, Schlick, Lambert, G = 1), within 3%."""
    m, res, fov, pos = 0.015, 9, 60.0, (0.0, 1.0, 1e-4)
    s = parse_scene(plane_scene_toml(roughness=m, position=pos, resolution=(res, res), fov=fov, size=20.0,
                                     light_dir=(0.0, 1.0, 0.0)), tmp_path, "s.toml")
    prep = prepare_filtering(s, ("ground_truth",))
    c = res // 2
    gt = np.mean([render_filtering(s, "ground_truth", spp=64, seed=k, prepared=prep).image[c, c] for k in range(64)], 0)
    k = 64
    L, _ = numpy_flat_cook_torrance(pos, fov, res * k, res * k, m, size=20.0, light_dir=(0.0, 1.0, 0.0))
    ref = L.reshape(res, k, res, k, 3).mean(axis=(1, 3))
    centre = L[c * k + k // 2, c * k + k // 2]
    assert np.linalg.norm(centre) > 4 * np.linalg.norm(ref[c, c])     # the highlight is narrower than the pixel
    err = np.linalg.norm(gt - ref[c, c]) / np.linalg.norm(ref[c, c])
    assert err < 0.03, err


def test_a_flat_plane_seen_half_a_degree_above_grazing_is_the_cook_torrance_brdf(tmp_path):
    """A camera 0.3 degrees above a flat plane (under half a degree at every covered pixel; wo_z about 0.005, where
    1 / (4 wo_z) is still finite): every method shades this module's numpy Cook-Torrance closed form, not black
    (MIN_COS: only wo_z below 1e-4 shades nothing)."""
    pos = (0.0, 0.02, 4.0)
    s = parse_scene(plane_scene_toml(roughness=0.3, position=pos, resolution=(24, 16), fov=1.0), tmp_path, "s.toml")
    ref, cov = numpy_flat_cook_torrance(pos, 1.0, 24, 16, 0.3)
    prep = prepare_filtering(s, METHODS)
    for m in METHODS:
        r = render_filtering(s, m, prepared=prep)
        assert np.array_equal(r.coverage, cov) and cov.sum() > 10, m
        assert np.all(np.linalg.norm(ref[cov], axis=-1) > 0), m
        assert np.allclose(r.image[cov], ref[cov], rtol=2e-3, atol=1e-6), (m, np.abs(r.image[cov] - ref[cov]).max())


def test_pair_uniforms_warns_before_it_takes_more_memory_than_is_available(monkeypatch):
    """pair_uniforms(seed, pixel, 2**31 - 1) allocated its (n, 5) float32 uniforms, 43 GB, without a word (the system
    then stops the process without one either); it now warns as the frames do (warpbw.errors.warn_if_short_of_memory)
    first.  Truth: the uniforms' own size, 20 bytes a pair (5 float32: u.nbytes), against the memory a stand-in
    reports available; the 43 GB are never allocated (a stand-in for wp.zeros stops the call there)."""
    import warnings

    import warpbw.filtering as F

    class Allocated(Exception):
        """Where the stand-in stops a large allocation."""

    real_zeros = F.wp.zeros

    def zeros(shape, *args, **kwargs):
        if int(np.prod(shape)) > 10**6:
            raise Allocated
        return real_zeros(shape, *args, **kwargs)

    monkeypatch.setattr(F.wp, "zeros", zeros)
    monkeypatch.setattr(F, "available_memory", lambda: 10**9, raising=False)
    with pytest.warns(RuntimeWarning, match=r"^pair_uniforms: n = 2147483647 pairs takes about 42\.9 GB, but 1\.0 GB "
                                            r"of memory is available: the system may stop it \(ask for fewer pairs\)"):
        with pytest.raises(Allocated):
            pair_uniforms(0, 0, 2**31 - 1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        u = pair_uniforms(0, 0, 1000)   # 20,000 bytes
        monkeypatch.setattr(F, "available_memory", lambda: u.nbytes)   # exactly enough: no warning
        assert np.array_equal(pair_uniforms(0, 0, 1000), u)
        monkeypatch.setattr(F, "available_memory", lambda: None)        # unknown (not Linux): no warning
        assert np.array_equal(pair_uniforms(0, 0, 1000), u)
    assert u.shape == (1000, 5) and u.nbytes == 20_000
    monkeypatch.setattr(F, "available_memory", lambda: u.nbytes - 1)
    with pytest.warns(RuntimeWarning, match=r"^pair_uniforms: n = 1000 pairs takes about 0\.0 GB"):
        assert np.array_equal(pair_uniforms(0, 0, 1000), u)


_PERMUTED = {}


@settings(max_examples=8, deadline=None)
@given(order=st.permutations(range(4)), zoom=st.sampled_from((0.5, 1.0, 4.0)))
def test_the_gmm_components_listed_in_another_order_render_the_same_frame(tmp_path_factory, order, zoom):
    """A GMM mipmap's components are a set: the filter interpolates corresponding components (the same index at every
    texel and level, 004 Sec. 4.2) and the shading sums over them (specular NDF and Lambert alike), so the same
    permutation of the stored components at every texel renders the same frame under directional lights, at every
    level (zoom 0.5: the fine blend of magnification too).  Measured (session 69, the scales 32 x 32 at zooms 1, 4
    and 16): within 1.2e-7 of the brightest pixel (float32 sums in another order)."""
    from precompute.gmm_mipmap import build_gmm_mipmap, load_map, write_gmm_mipmap

    if "folder" not in _PERMUTED:
        folder = _PERMUTED["folder"] = tmp_path_factory.mktemp("permuted")
        write_exr(folder / "map.exr", np.asarray(hemispherical_scales(32, scales_across=4), np.float32)[..., None],
                  channels=["Y"])
        _PERMUTED["mip"] = build_gmm_mipmap(load_map(folder / "map.exr"), scale=0.5, progress=False)
    folder, mip = _PERMUTED["folder"], _PERMUTED["mip"]
    frames = []
    for perm in (range(4), order):
        m = copy.copy(mip)
        m.levels = [np.ascontiguousarray(lv[:, :, list(perm)]) for lv in mip.levels]
        name = "m" + "".join(map(str, perm)) + ".gmm"
        if not (folder / name).exists():
            write_gmm_mipmap(folder / name, m, "map.exr", file_digest(folder / "map.exr"))
        material = f'normal_map = "map.exr"\nnormal_map_scale = 0.5\ntiling = 4\ngmm = "{name}"\n'
        s = parse_scene(plane_scene_toml(material, roughness=0.1, position=(0.3, 1.2, 2.0), lights=2,
                                         resolution=(48, 32), diffuse=(0.5, 0.4, 0.3)), folder, "s.toml")
        frames.append(render_filtering(s, "gmm_aligned", camera=zoomed_camera(s.camera, zoom)))
    a, b = frames
    assert a.coverage.sum() >= 100
    assert np.array_equal(a.level, b.level)
    np.testing.assert_allclose(b.image, a.image, rtol=0.0, atol=1e-6 * float(a.image.max()))


@pytest.mark.filterwarnings("ignore:height field of")   # small random maps hold much texel-to-texel detail
@settings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), offset=st.floats(-4.0, 4.0), factor=st.floats(0.05, 20.0),
       method=st.sampled_from(("fixed", "toksvig", "lean", "gmm_aligned")))
def test_a_height_map_its_normal_map_its_offset_and_its_rescaling_render_the_same_frame(tmp_path_factory, seed, offset,
                                                                                        factor, method):
    """Normals are the slopes of ``normal_map_scale * h``: the map plus a constant (its level), the map times s with
    ``normal_map_scale`` / s, and the EXR of unit vectors that ``precompute.surfaces.height_to_normals`` computes from
    it (``normal_map_kind = "normal"``, raw vectors as README's convention reads them: x along +column, y along -row)
    give the same normals, so the same mipmaps and frames, the GMM from each one's own build (EM, seeded, on the
    same normals).  Measured (session 69, the scales 32 x 32, zooms 1, 4, 16): within 1e-6 of the brightest pixel,
    float32 EXR storage of the heights and of the vectors."""
    from precompute.surfaces import height_to_normals

    folder = tmp_path_factory.mktemp("heights")
    h = np.random.default_rng(seed).standard_normal((8, 8)) * 0.02
    h32 = h.astype(np.float32).astype(np.float64)              # the heights the EXR holds
    maps = {"h.exr": (h32, None), "offset.exr": (h32 + offset, None), "scaled.exr": (h32 * factor, None),
            "normals.exr": (height_to_normals(h32, 0.5), "normal")}
    frames = []
    for name, (data, kind) in maps.items():
        if kind is None:
            write_exr(folder / name, np.asarray(data, np.float32)[..., None], channels=["Y"])
            scale = 0.5 / factor if name == "scaled.exr" else 0.5
            extra = f'normal_map = "{name}"\nnormal_map_scale = {scale!r}\n'
        else:
            write_exr(folder / name, np.asarray(data, np.float32), channels=["R", "G", "B"])
            extra = f'normal_map = "{name}"\nnormal_map_kind = "normal"\n'
        s = parse_scene(plane_scene_toml(extra + "tiling = 2\n", roughness=0.1, position=(0.3, 1.2, 2.0), lights=2,
                                         diffuse=(0.5, 0.4, 0.3)), folder, "s.toml")
        frames.append(render_filtering(s, method))
    a = frames[0]
    assert a.coverage.sum() > 100
    for name, b in zip(list(maps)[1:], frames[1:]):
        np.testing.assert_allclose(b.level, a.level, atol=1e-5, err_msg=name)
        # float32 heights: an offset of 4 leaves differences of 4 * 2^-24 over texels 1/8 apart
        np.testing.assert_allclose(b.image, a.image, rtol=0.0, atol=1e-4 * float(a.image.max()), err_msg=name)


@pytest.mark.parametrize("field, value", [("content_hash", "another-map"), ("kind", "normal"), ("scale", 2.0),
                                          ("components", 3), ("prior", 0.5), ("unaligned", True)])
def test_every_input_of_a_gmm_fit_changes_its_cache_key(field, value):
    """A GMM mipmap is cached under its source's digest (warpbw.filtering._GmmSource; the reader then checks the map's
    hash, shape, kind, scale, components, prior and alignment): each input of build_gmm_mipmap the material sets,
    changed alone, gives another key (cache-key audit, session 70); the map's file name does not."""
    from dataclasses import replace

    from warpbw.filtering import _GmmSource

    src = _GmmSource(None, "height", 1.0, False, "h.exr", "map-hash", 4, 1.0)
    assert replace(src, name="renamed.exr").digest == src.digest
    assert replace(src, **{field: value}).digest != src.digest


# ------------------------------------------------------------------------------------------ world geometry (session 75)

def _world_cook_torrance(wo, wi, n, roughness, f0, diffuse, radiance):
    """004 Sec. 3's fine-scale BRDF times the light's E cos written in world coordinates for a plane facing +Y (G = 1;
    the NDF a Gaussian of per-axis variance m^2 / 2 about the normal's projection on the plane, XZ; Schlick at
    wo . h; Lambert at n . wi), per ray: wo (..., 3), wi (3,), n (..., 3) unit world vectors."""
    hv = wi + wo
    hv /= np.linalg.norm(hv, axis=-1, keepdims=True)
    var = roughness ** 2 / 2
    D = np.exp(-((hv[..., 0] - n[..., 0]) ** 2 + (hv[..., 2] - n[..., 2]) ** 2) / (2 * var)) / (2 * np.pi * var)
    u = np.clip(np.sum(wo * hv, -1), 0, None)[..., None]
    F = np.asarray(f0) + (1 - np.asarray(f0)) * (1 - u) ** 5
    lamb = np.clip(n @ wi, 0, None)[..., None]
    return np.asarray(radiance) * (F * (D / (4 * wo[..., 1]))[..., None] + np.asarray(diffuse) / np.pi * (1 - F) * lamb)


def _world_box_average(position, fov, res, size, centre, normal_at, shade, k=16):
    """Each pixel's mean over a k x k grid of rays of shade(wo, n) at the rays that hit the square plane (numpy
    pinhole camera), n = normal_at(x, z) the world normal at the hit; also the count of rays that hit."""
    acc, hits = np.zeros((res[1], res[0], 3)), np.zeros((res[1], res[0]))
    for jx, jy in np.ndindex(k, k):
        o, d = numpy_camera_rays(position, (0, 0, 0), fov, res[0], res[1], jitter=((jx + 0.5) / k, (jy + 0.5) / k))
        t = numpy_square_distance(o, d, size, centre)
        hit = np.isfinite(t)
        p = o + np.where(hit, t, 0.0)[..., None] * d
        acc += np.where(hit[..., None], shade(-d, normal_at(p[..., 0], p[..., 2])), 0.0)
        hits += hit
    return acc / np.maximum(hits, 1)[..., None], hits


def test_a_height_field_on_a_plane_shades_as_the_surface_it_describes_in_world_coordinates(tmp_path):
    """The plane's stated geometry (README: a square in XZ facing +Y, u along +X and v along +Z, the map's column j at
    u = (j + 1/2) / W and row i at v = (i + 1/2) / H of each of ``tiling`` repeats; heights in units of a repeat's
    width times ``normal_map_scale``) describes the surface Y = (size / tiling) scale h(u, v): its world normal is
    (-scale dh/du, 1, -scale dh/dv) normalised. A smooth periodic field of known derivatives on a 256 x 128 map
    (non-square), tiling 1.5, the plane off the origin, under a light from -Z and +X: the ground truth is the numpy
    box average (16 x 16 rays per pixel) of the fine-scale BRDF at that analytic normal, written in world
    coordinates. Measured (session 75): within 0.15% on average and 1.5% at most (central differences and the
    bilinear normal: 0.40% / 4.3% on a 96 x 64 map, 0.04% / 0.4% on 384 x 256); each of these planted gave 42% to
    104% on average: the map's y along +row, rows 1 / W apart, v along -Z, normal_map_scale or the rows' tiling left
    out of the slopes or texel coordinates, the tangent frame's y = +Z."""
    W, H, tiling, scale, size, centre = 256, 128, 1.5, 0.7, 2.0, (0.3, -0.2, 0.5)

    def grad(u, v):                    # h = 0.03 sin 2pi(u + 0.1) + 0.04 cos 2pi(v + 0.3) + 0.01 sin 2pi(u + 2v)
        w = np.cos(2 * np.pi * (u + 2 * v))
        return (0.06 * np.pi * np.cos(2 * np.pi * (u + 0.1)) + 0.02 * np.pi * w,
                -0.08 * np.pi * np.sin(2 * np.pi * (v + 0.3)) + 0.04 * np.pi * w)

    v, u = np.meshgrid((np.arange(H) + 0.5) / H, (np.arange(W) + 0.5) / W, indexing="ij")
    h = (0.03 * np.sin(2 * np.pi * (u + 0.1)) + 0.04 * np.cos(2 * np.pi * (v + 0.3))
         + 0.01 * np.sin(2 * np.pi * (u + 2 * v)))
    write_exr(tmp_path / "map.exr", h.astype(np.float32)[..., None], channels=["Y"])
    light = np.array([0.2, 0.7, -0.6]) / np.linalg.norm([0.2, 0.7, -0.6])
    position, fov, res, m = (0.5, 1.4, 1.6), 50.0, (24, 18), 0.15
    text = plane_scene_toml(f'normal_map = "map.exr"\nnormal_map_scale = {scale}\ntiling = {tiling}\n', roughness=m,
                            position=position, fov=fov, resolution=res, size=size, light_dir=tuple(map(float, light)),
                            diffuse=(0.3, 0.2, 0.1))
    text = text.replace('shape = "plane"', f'shape = "plane"\ncenter = {list(centre)}')
    s = parse_scene(text, tmp_path, "s.toml")
    prep = prepare_filtering(s, ("ground_truth",))

    def normal_at(x, z):
        du, dv = grad(((x - centre[0]) / size + 0.5) * tiling % 1.0, ((z - centre[2]) / size + 0.5) * tiling % 1.0)
        n = np.stack([-scale * du, np.ones_like(du), -scale * dv], -1)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    def shade(wo, n):
        return _world_cook_torrance(wo, light, n, m, PLANE_F0, (0.3, 0.2, 0.1), PLANE_RADIANCE)

    ref, hits = _world_box_average(position, fov, res, size, centre, normal_at, shade)
    inner = hits == 16 * 16                          # pixels wholly on the plane
    gt = render_filtering(s, "ground_truth", spp=256, seed=1, prepared=prep)
    assert inner.sum() > 150 and np.all(gt.coverage[inner])
    e = np.linalg.norm(gt.image[inner] - ref[inner], axis=-1) / np.linalg.norm(ref[inner], axis=-1).mean()
    assert e.mean() < 0.004 and e.max() < 0.02, (e.mean(), e.max())


def test_ground_truth_reads_each_rays_normal_bilinearly_between_texel_centres_wrapping_across_tiles(tmp_path):
    """A 5 x 3 map of random tilted normals (non-square), tiling 2.3 (the plane's edges cut a repeat), the plane off
    the origin, pixels of a third to one texel: each ground-truth ray reads the finest normals bilinearly between
    texel centres, column j's at s = j + 1/2 with s = u tiling W, wrapping from the last column and row to the first
    across every repeat's edge, and renormalises the blend. Truth: a numpy box average (16 x 16 rays per pixel) of
    the fine-scale BRDF, written in world coordinates, at that normal (np.floor and the modulo of numpy). Measured
    (session 75, 1024 rays): within 0.05% on average and 0.6% at most; planted, the fetch without the half-texel
    offset, clamped at the map's edge instead of wrapping, wrapping rows with the columns' period, or the blend not
    renormalised gave 7% to 107% on average."""
    rng = np.random.default_rng(5)
    H, W, tiling, size, centre, m = 3, 5, 2.3, 2.0, (-0.2, 0.1, 0.3), 0.25
    nt = np.concatenate([rng.normal(size=(H, W, 2)) * 0.35, np.ones((H, W, 1))], -1)
    nt = (nt / np.linalg.norm(nt, axis=-1, keepdims=True)).astype(np.float32)
    write_exr(tmp_path / "n.exr", nt, channels=["R", "G", "B"])
    nt = nt.astype(np.float64)
    light = (-0.3, 0.8, 0.4)
    position, fov, res = (0.4, 1.3, 1.6), 45.0, (20, 14)
    text = plane_scene_toml(f'normal_map = "n.exr"\nnormal_map_kind = "normal"\ntiling = {tiling}\n', roughness=m,
                            position=position, fov=fov, resolution=res, size=size, light_dir=light,
                            diffuse=(0.4, 0.3, 0.2))
    s = parse_scene(text.replace('shape = "plane"', f'shape = "plane"\ncenter = {list(centre)}'), tmp_path, "s.toml")

    def normal_at(x, z):
        sx = ((x - centre[0]) / size + 0.5) * tiling * W - 0.5     # texel j's centre at s = j + 1/2
        ty = ((z - centre[2]) / size + 0.5) * tiling * H - 0.5
        c0, r0 = np.floor(sx), np.floor(ty)
        fx, fy = (sx - c0)[..., None], (ty - r0)[..., None]
        c0, r0 = c0.astype(int), r0.astype(int)

        def at(dc, dr):
            return nt[(r0 + dr) % H, (c0 + dc) % W]
        n = (1 - fx) * (1 - fy) * at(0, 0) + fx * (1 - fy) * at(1, 0) + (1 - fx) * fy * at(0, 1) + fx * fy * at(1, 1)
        n = np.stack([n[..., 0], n[..., 2], -n[..., 1]], -1)      # tangent (x = +X, y = -Z, z = +Y) -> world
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    wi = np.asarray(light) / np.linalg.norm(light)
    def shade(wo, n):
        return _world_cook_torrance(wo, wi, n, m, PLANE_F0, (0.4, 0.3, 0.2), PLANE_RADIANCE)

    ref, hits = _world_box_average(position, fov, res, size, centre, normal_at, shade)
    inner = hits == 16 * 16
    gt = render_filtering(s, "ground_truth", spp=1024, seed=3)
    assert inner.sum() > 150 and np.all(gt.coverage[inner])
    e = np.linalg.norm(gt.image[inner] - ref[inner], axis=-1) / np.linalg.norm(ref[inner], axis=-1).mean()
    assert e.mean() < 0.003 and e.max() < 0.02, (e.mean(), e.max())


def _white_furnace_of_the_fine_lobe(wo, n, roughness, N=1500):
    """The directional albedo towards wo (plane frame) of 004 Sec. 3's fine-scale BRDF at the unit normal n with f0 = 1
    and no diffuse term: int F D(h) / (4 wo_z) dw_i over the upper hemisphere, F = 1, by a midpoint rule over the
    projected half-vector p in the unit disk (dw_i = 4 (wo . h) dw_h, dw_h = dp / h_z), D the Gaussian of per-axis
    variance m^2 / 2 about n's projection; a half-vector whose mirror direction lies below the plane adds nothing."""
    x = ((np.arange(N) + 0.5) / N) * 2 - 1
    px, py = np.meshgrid(x, x)
    on = px * px + py * py < 1
    hz = np.sqrt(np.where(on, 1 - px * px - py * py, 1.0))
    var = roughness ** 2 / 2
    D = np.exp(-((px - n[0]) ** 2 + (py - n[1]) ** 2) / (2 * var)) / (2 * np.pi * var)
    woh = px * wo[0] + py * wo[1] + hz * wo[2]
    wi_z = 2 * woh * hz - wo[2]
    keep = on & (woh > 0) & (wi_z > 0)
    return float(np.sum(np.where(keep, D * woh / (wo[2] * hz), 0.0)) * (2 / N) ** 2)


@pytest.mark.parametrize("towards", [False, True])
def test_a_tilted_fine_normal_under_a_white_sky_reflects_what_the_models_quadrature_gives(tmp_path, towards):
    """A uniform normal map tilted 25 degrees away from the camera or towards it (tangent y = -Z), f0 = 1, no diffuse,
    roughness 0.3, under a constant environment of 1, seen 67 degrees from the plane's normal: the fixed method (at
    the fine-scale lobe on a uniform map) and the ground truth read the directional albedo of the fine-scale BRDF at
    that normal, by quadrature (``_white_furnace_of_the_fine_lobe``). Without masking (G = 1) and with the 1 / wo_z of
    the macro surface, that is 0.105 away from the camera and 2.30 towards it: a normal-mapped plane's white furnace
    exceeds 1 away from grazing views (on a sine of slopes up to 21 degrees it averages 0.97 at 45 degrees and 0.93 at
    67 over a period, its pointwise values 0.45-1.38 and 0.01-1.89 at roughness 0.1). Measured (session 75): within
    0.7% (away; the pixel box against its centre) and 0.1%; planted, the tangent frame's y = +Z, the BRDF strategy's
    pdf without h_z, or the specular term over 4 wo.h instead of 4 wo_z gave 2.4% to 48% (and the two views swapped)."""
    t = math.radians(25.0) * (-1.0 if towards else 1.0)
    n = np.array([0.0, math.sin(t), math.cos(t)])
    write_exr(tmp_path / "n.exr", np.broadcast_to(n.astype(np.float32), (4, 4, 3)).copy(), channels=["R", "G", "B"])
    text = plane_scene_toml('normal_map = "n.exr"\nnormal_map_kind = "normal"\n', roughness=0.3,
                            position=(0.0, 1.0, 2.5), fov=10.0, resolution=(6, 4), size=4.0, lights=0, diffuse=None,
                            environment="[environment]\nconstant = [1.0, 1.0, 1.0]\n")
    s = parse_scene(text.replace(f"f0 = {list(PLANE_F0)}", "f0 = [1.0, 1.0, 1.0]"), tmp_path, "s.toml")
    _, d = numpy_camera_rays((0.0, 1.0, 2.5), (0, 0, 0), 10.0, 6, 4)
    wo = -d[2, 3]
    albedo = _white_furnace_of_the_fine_lobe(np.array([wo[0], -wo[2], wo[1]]), n, 0.3)
    assert (albedo > 2.0) if towards else (albedo < 0.2)
    prep = prepare_filtering(s, ("fixed", "ground_truth"))
    fixed = render_filtering(s, "fixed", prepared=prep, env_spp=8192, seed=1).image[2, 3]
    gt = render_filtering(s, "ground_truth", spp=8192, prepared=prep, seed=1).image[2, 3]
    assert np.allclose(fixed, albedo, rtol=0.02) and np.allclose(gt, albedo, rtol=0.02), (albedo, fixed, gt)


def test_a_zoomed_camera_moves_along_its_line_to_the_look_at_point():
    """Round 11: ``zoomed_camera`` keeps the look-at point, direction, up, fov and size, and puts the camera at zoom
    times its distance from the look-at point, on the same side.  Truth: a camera at (1, 3, 5) looking at (2, -1, 0)
    zoomed by 0.5 stands at (1.5, 1, 2.5), by 3 at (-1, 11, 15).  (Scaling the position about the origin moved it
    off the line unless the look-at point was the origin, as in the zoom figures' scenes.)"""
    from warpbw.scene import Camera

    cam = Camera((1.0, 3.0, 5.0), (2.0, -1.0, 0.0), (0.0, 1.0, 0.0), 40.0, 32, 24)
    for zoom, want in ((0.5, (1.5, 1.0, 2.5)), (3.0, (-1.0, 11.0, 15.0))):
        z = zoomed_camera(cam, zoom)
        np.testing.assert_allclose(z.position, want, rtol=1e-12)
        assert (z.look_at, z.up, z.fov, z.width, z.height) == (cam.look_at, cam.up, 40.0, 32, 24)


def test_normal_moment_mipmap_names_the_first_normal_off_unit_length_and_counts_them():
    """Round 11: ``normal_moment_mipmap`` refuses normals off unit length by more than ``UNIT_LENGTH_TOL``, counting
    them and naming the first in row-major order (not the farthest off).  Truth: a 3 x 4 map of +Z with texel (0, 2)
    1.01 long and texel (2, 1) 3 long: 2 of 12, the first (0, 2)."""
    n = np.zeros((3, 4, 3))
    n[..., 2] = 1.0
    n[0, 2, 2] = 1.01
    n[2, 1, 2] = 3.0
    with pytest.raises(WarpbwError, match=r"2 of 12 are not \(the first, texel \(0, 2\): \[0\.0, 0\.0, 1\.01\]\)"):
        normal_moment_mipmap(n)
