"""Reference estimator (002 Eq. 2) against closed forms: Lambert under a constant sky, white furnace."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from warpbw.errors import WarpbwError
from warpbw.pipeline import prepare_scene, render_reference
from warpbw.scene import parse_scene
from warpbw.shading import tile_ranges

SPHERE_SCENE = """
[camera]
position = [0.0, 0.0, 4.0]
look_at = [0.0, 0.0, 0.0]
fov = 35.0
resolution = [{w}, {h}]
[environment]
{env}
[[object]]
shape = "sphere"
radius = 1.0
material = "m"
[material.m]
{mat}
"""


def sphere_scene(mat: str, env: str = "constant = 1.0", w: int = 48, h: int = 48, base_dir=None):
    return parse_scene(SPHERE_SCENE.format(mat=mat, env=env, w=w, h=h), base_dir=base_dir)


def facing(res, min_cos=0.02):
    n = res.gbuffer.numpy("normal")
    v = res.gbuffer.numpy("view")
    return res.coverage & (np.einsum("hwc,hwc->hw", n, v) > min_cos)


def test_lambert_sphere_under_constant_sky_returns_albedo():
    albedo = np.array([0.8, 0.5, 0.2])
    scene = sphere_scene(f'type = "lambert"\nalbedo = {albedo.tolist()}')
    res = render_reference(scene, spp=256, seed=3)
    m = facing(res)
    assert m.sum() > 500
    # cosine sampling makes every sample exactly albedo: 1% on every pixel
    assert np.abs(res.image[m] / albedo - 1.0).max() < 0.01
    assert (res.image[~res.coverage] == 0).all()


def test_lambert_sphere_with_mis_returns_albedo_on_average():
    albedo = np.array([0.8, 0.5, 0.2])
    res = render_reference(sphere_scene(f'type = "lambert"\nalbedo = {albedo.tolist()}'), spp=256, seed=4, mis=True)
    m = facing(res)
    assert np.abs(res.image[m].mean(0) / albedo - 1.0).max() < 0.01
    assert np.abs(res.image[m] / albedo - 1.0).max() < 0.15


def _ggx_albedo_quadrature(alpha, cos_o, n=1500, fresnel=None):
    """Directional albedo of the separable-Smith GGX with F = 1 (or F = ``fresnel(wi . h)``), by midpoint
    quadrature (float64)."""
    th = (np.arange(n) + 0.5) / n * (np.pi / 2)
    ph = (np.arange(2 * n) + 0.5) / (2 * n) * 2 * np.pi
    T, P = np.meshgrid(th, ph, indexing="ij")
    wi = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1)
    wo = np.array([np.sqrt(1 - cos_o ** 2), 0.0, cos_o])
    h = wi + wo
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    a2 = alpha * alpha
    D = a2 / (np.pi * (h[..., 2] ** 2 * (a2 - 1) + 1) ** 2)
    g1 = lambda c: 2 * c / (c + np.sqrt(a2 + (1 - a2) * c * c))  # noqa: E731
    f = D * g1(wi[..., 2]) * g1(cos_o) / (4 * wi[..., 2] * cos_o)
    if fresnel is not None:
        f = f * fresnel(np.clip(np.einsum("...c,...c->...", wi, h), 0.0, 1.0))
    dA = (np.pi / 2 / n) * (2 * np.pi / (2 * n)) * np.sin(T)
    return float(np.sum(f * wi[..., 2] * dA))


@pytest.mark.parametrize("alpha", [0.05, 0.3, 1.0])
def test_ggx_white_furnace(alpha):
    scene = sphere_scene(f'type = "ggx"\nalpha = {alpha}\nspecular = [1.0, 1.0, 1.0]')
    res = render_reference(scene, spp=64, seed=1)
    assert np.isfinite(res.image).all()
    # VNDF sampling: each sample weighs F G1(wi) <= 1, so no pixel can exceed 1 (white furnace)
    assert res.image.max() <= 1.0 + 1e-5
    # the centre pixel sees wo = n: its value is the directional albedo at normal incidence
    centre = res.image[23:25, 23:25].mean()
    cos_c = float(np.einsum("c,c->", res.gbuffer.numpy("normal")[23, 23], res.gbuffer.numpy("view")[23, 23]))
    expect = _ggx_albedo_quadrature(alpha, cos_c)
    # each sample's weight lies in [0, 1] with mean `expect`, so its variance is at most expect (1 - expect)
    # (Bhatia-Davis): 3 standard errors over the 4 x 64 samples, plus 0.002 for the quadrature and the
    # four pixels' slightly different views
    assert abs(centre - expect) < 0.002 + 3 * np.sqrt(expect * (1 - expect) / (64 * 4))
    assert expect <= 1.0


def test_ggx_conductor_fresnel_darkens_and_stays_below_one():
    gold = 'type = "ggx"\nalpha = 0.3\nspecular = [1.0, 1.0, 1.0]\neta = [0.143, 0.374, 1.442]\nk = [3.983, 2.385, 1.603]'
    res = render_reference(sphere_scene(gold), spp=64, seed=2)
    m = facing(res)
    assert res.image.max() <= 1.0 + 1e-5
    # gold: red reflects more than blue at normal incidence (F0 about 0.99, 0.85, 0.33 at R, G, B)
    c = res.image[23:25, 23:25].reshape(-1, 3).mean(0)
    assert c[0] > c[1] > c[2] > 0.0
    # and by how much: per channel the albedo with the exact conductor Fresnel (complex arithmetic, test_brdf),
    # within 3 standard errors (weights in [0, 1]: variance at most e (1 - e)) plus 0.002
    from test_brdf import fresnel_conductor_numpy

    cos_c = float(np.einsum("c,c->", res.gbuffer.numpy("normal")[23, 23], res.gbuffer.numpy("view")[23, 23]))
    for ch, (eta, k) in enumerate(zip((0.143, 0.374, 1.442), (3.983, 2.385, 1.603))):
        e = _ggx_albedo_quadrature(0.3, cos_c, n=600, fresnel=lambda cd: fresnel_conductor_numpy(cd, eta, k))
        assert abs(c[ch] - e) < 0.002 + 3 * np.sqrt(e * (1 - e) / (64 * 4)), (ch, c[ch], e)
    assert np.isfinite(res.image[m]).all()


def test_mis_and_brdf_sampling_agree_under_a_real_probe(shared):
    probe = shared("envmaps/studio.exr")
    scene = sphere_scene('type = "ggx"\nalpha = 0.4\nspecular = [0.9, 0.9, 0.9]', env=f'file = "{probe}"', w=24, h=24)
    prep = prepare_scene(scene)
    a = render_reference(prep, spp=512, seed=1)
    b = render_reference(prep, spp=512, seed=2, mis=True)
    m = facing(a, 0.2)
    # two independent unbiased estimators: their sphere means agree to a few percent
    ma, mb = a.image[m].mean(0), b.image[m].mean(0)
    assert np.abs(ma / mb - 1.0).max() < 0.03


def test_same_seed_same_image_different_seed_different_noise():
    scene = sphere_scene('type = "lambert"\nalbedo = [0.5, 0.5, 0.5]', env='procedural = "sky"', w=16, h=16)
    prep = prepare_scene(scene)
    a = render_reference(prep, spp=4, seed=7, mis=True)
    b = render_reference(prep, spp=4, seed=7, mis=True, threads=1)
    c = render_reference(prep, spp=4, seed=8, mis=True)
    assert np.array_equal(a.image, b.image)      # tiling over threads does not change the result
    assert not np.array_equal(a.image, c.image)
    assert a.stats["samples"] == 4 * a.stats["pixels_covered"]


def test_per_pixel_sample_counts_for_adaptive_shading():
    """N_p per pixel (002 Sec. 2.4): a constant map reproduces the fixed-spp image bit for bit, a subset of
    pixels leaves the others as they were, and N_p = 0 shades to 0."""
    import warp as wp

    from warpbw.shading import shade_reference

    scene = sphere_scene('type = "ggx"\nalpha = 0.3\nspecular = [0.9, 0.9, 0.9]', env='procedural = "sky"', w=20, h=16)
    prep = prepare_scene(scene)
    base = render_reference(prep, spp=6, seed=3, mis=True)
    gb = base.gbuffer
    n = gb.width * gb.height
    const = wp.array(np.full(n, 6, np.int32), dtype=wp.int32)
    r = shade_reference(gb, prep.materials, prep.env.data, const, seed=3, mis=True)
    assert np.array_equal(r.radiance.numpy().reshape(base.image.shape), base.image)
    assert r.samples == base.stats["samples"]

    cov = np.flatnonzero(base.coverage.reshape(-1))
    subset, zero = cov[::2], cov[1::4]
    counts = np.full(n, 6, np.int32)
    counts[zero] = 0
    sentinel = np.full((n, 3), 7.0, np.float32)
    out = wp.array(sentinel, dtype=wp.vec3)
    r = shade_reference(gb, prep.materials, prep.env.data, wp.array(counts, dtype=wp.int32), seed=3, mis=True,
                        pixels=wp.array(np.union1d(subset, zero).astype(np.int32), dtype=wp.int32), out=out)
    img = r.radiance.numpy()
    shaded_nonzero = np.setdiff1d(subset, zero)
    assert np.array_equal(img[shaded_nonzero], base.image.reshape(-1, 3)[shaded_nonzero])
    assert (img[zero] == 0).all()
    untouched = np.setdiff1d(np.arange(n), np.union1d(subset, zero))
    assert (img[untouched] == 7.0).all()
    assert r.samples == 6 * len(shaded_nonzero)
    # the map as numpy integers of the image's shape, as the docstring offers (it was refused unless a wp.array)
    r = shade_reference(gb, prep.materials, prep.env.data, counts.astype(np.int64).reshape(base.coverage.shape),
                        seed=3, mis=True)
    assert np.array_equal(r.radiance.numpy()[shaded_nonzero], base.image.reshape(-1, 3)[shaded_nonzero])
    assert (r.radiance.numpy()[zero] == 0).all()


def test_shade_reference_refuses_material_ids_past_its_table_and_an_envmap_for_its_data():
    """A G-buffer built with ids into another table: id 1 against a table of one material read past its end and
    shaded black (a large id crashed the process).  An ``EnvMap`` given for its ``.data`` failed inside Warp."""
    from warpbw.brdf import LAMBERT, MaterialSpec, build_material_table
    from warpbw.envmap import constant_envmap
    from warpbw.gbuffer import SphereSpec, build_geometry, make_camera, render_gbuffer
    from warpbw.shading import shade_reference

    cam = make_camera((0.0, 0.0, 4.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 35.0, 12, 12)
    gb = render_gbuffer(cam, build_geometry([SphereSpec((0, 0, 0), 1.0, 1)], []))
    one = build_material_table([MaterialSpec("m", LAMBERT, albedo=(0.5, 0.5, 0.5))])
    env = constant_envmap(1.0)
    with pytest.raises(WarpbwError, match=r"material id 1, the material table has 1 \(ids 0\.\.0\)"):
        shade_reference(gb, one, env.data, 4)
    two = build_material_table([MaterialSpec("a", LAMBERT, albedo=(0.5, 0.5, 0.5)),
                                MaterialSpec("b", LAMBERT, albedo=(0.25, 0.25, 0.25))])
    with pytest.raises(WarpbwError, match="env_data: expected an EnvMapData .an EnvMap's .data., got EnvMap"):
        shade_reference(gb, two, env, 4)
    with pytest.raises(WarpbwError, match=r"spp: expected 144 per-pixel integer counts, got float64 \(144,\)"):
        shade_reference(gb, two, env.data, np.full(144, 4.0))
    img = shade_reference(gb, two, env.data, 4).radiance.numpy()[gb.coverage.reshape(-1)]
    assert np.allclose(img, 0.25, rtol=1e-5)      # Lambert under a constant sky of 1: its albedo, material b's


# --- tiles over threads ------------------------------------------------------------------------------

@given(st.integers(1, 5000), st.integers(1, 700), st.integers(0, 2**31 - 1))
@settings(max_examples=60, deadline=None)
def test_tiles_of_equal_cost_cover_every_item_once_and_balance(n_items, tile, seed):
    """Tiles cut by cost are contiguous, cover every item once, number as many as tiles of equal counts
    (or fewer, when one item outweighs a share), and none costs more than an equal share plus its heaviest item."""
    rng = np.random.default_rng(seed)
    costs = np.where(rng.random(n_items) < 0.05, rng.integers(0, 2000, n_items), rng.integers(0, 4, n_items))
    plain = tile_ranges(n_items, tile)
    tiles = tile_ranges(n_items, tile, costs)
    assert [o for o, _ in tiles] == [0] + list(np.cumsum([c for _, c in tiles])[:-1])
    assert sum(c for _, c in tiles) == n_items and all(c > 0 for _, c in tiles)
    assert len(tiles) <= len(plain)
    w = costs + 1.0
    share = w.sum() / len(plain)
    for o, c in tiles:
        assert w[o:o + c].sum() <= share + w[o:o + c].max() + 1e-9


def test_tiles_of_equal_cost_split_a_compact_hot_spot():
    """A highlight: 100 items of cost 500 among 3,900 of cost 1 end up spread over several tiles, where
    tiles of equal counts give one of them nearly all the work."""
    costs = np.ones(4000)
    costs[1000:1100] = 500
    heavy = lambda tiles: max((costs[o:o + c] + 1).sum() for o, c in tiles) / (costs + 1).sum()
    assert heavy(tile_ranges(4000, 500)) > 0.85
    assert heavy(tile_ranges(4000, 500, costs)) < 0.2
    with pytest.raises(WarpbwError, match="tile costs"):
        tile_ranges(10, 4, np.full(10, np.nan))
