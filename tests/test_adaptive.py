"""Hierarchical adaptive shading (002 Sec. 3.2): against the reference and a closed form."""
from __future__ import annotations

import numpy as np

from warpbw.adaptive import shade_hierarchical
from warpbw.pipeline import prepare_scene, render_reference
from warpbw.scene import parse_scene

SCENE = """
[camera]
position = [0.0, 0.0, 4.0]
look_at = [0.0, 0.0, 0.0]
fov = 35.0
resolution = [{w}, {h}]
[environment]
{env}
[[object]]
shape = "sphere"
center = [-0.5, 0.0, 0.0]
radius = 0.8
material = "m"
[[object]]
shape = "sphere"
center = [0.7, 0.2, -2.5]
radius = 1.0
material = "m"
[material.m]
{mat}
"""


def setup(mat, env="constant = 1.0", w=45, h=33):
    prep = prepare_scene(parse_scene(SCENE.format(w=w, h=h, env=env, mat=mat)))
    base = render_reference(prep, spp=4, seed=5)
    return prep, base


def run(prep, base, level, spp, seed=5):
    return shade_hierarchical(base.gbuffer, prep.camera, prep.materials, prep.env.data, level, spp, seed=seed)


def test_finest_level_everywhere_is_the_reference():
    prep, base = setup('type = "ggx"\nalpha = 0.3\nspecular = [0.9, 0.9, 0.9]', env='procedural = "sky"')
    shape = base.coverage.shape
    r = run(prep, base, np.zeros(shape, np.int32), np.full(shape, 4, np.int32))
    assert np.array_equal(r.image, base.image)
    assert r.stats["samples"] == base.stats["samples"]
    assert r.shaded.sum() == base.coverage.sum()


def test_coarse_levels_reproduce_a_constant_image_with_fewer_shaded_pixels():
    # Lambert under a constant sky: every pixel is exactly the albedo, whatever is up-sampled from where
    prep, base = setup('type = "lambert"\nalbedo = [0.6, 0.4, 0.2]')
    cov = base.coverage
    fractions = []
    for lvl in (0, 1, 2, 3):
        r = run(prep, base, np.full(cov.shape, lvl, np.int32), np.full(cov.shape, 2, np.int32))
        assert np.allclose(r.image[cov], [0.6, 0.4, 0.2], atol=1e-5), lvl
        assert (r.image[~cov] == 0).all()
        fractions.append(r.stats["shaded_fraction"])
        # texels of two levels can share a clamped representative pixel at the image border
        assert sum(s["shaded"] for s in r.stats["levels"]) >= r.shaded.sum()
    assert fractions[0] == 1.0
    assert fractions[0] > fractions[1] > fractions[2] > fractions[3]
    assert fractions[2] < 0.25   # roughly 1/16 of the pixels plus those at depth edges and borders


def test_mixed_levels_shade_each_pixel_at_most_once_and_fill_every_covered_pixel():
    prep, base = setup('type = "ggx"\nalpha = 0.2\nspecular = [1.0, 1.0, 1.0]', env='procedural = "sky"')
    cov = base.coverage
    rng = np.random.default_rng(2)
    level = rng.integers(0, 4, size=cov.shape).astype(np.int32)
    spp = rng.integers(48, 80, size=cov.shape).astype(np.int32)
    r = run(prep, base, level, spp)
    assert np.isfinite(r.image).all()
    # the sky lights every visible point: no covered pixel is left unfilled (at 1 spp a single GGX sample
    # reflected below the horizon would legitimately give 0, hence the sample counts)
    assert (r.image[cov].sum(-1) > 0).all()
    # a pixel is shaded at a level no coarser than its own requirement, and samples are accounted for
    sl = r.shaded_level
    assert (sl[r.shaded] <= level[r.shaded]).all()
    assert r.stats["samples"] >= r.shaded.sum()


def test_thread_count_and_tiling_do_not_change_the_frame():
    """The bandwidth pass and every level's shading are cut into tiles over threads; pixels seed their own
    random numbers, so one thread and three (many small tiles per launch) give the same frame bit for bit."""
    from warpbw.pipeline import render_adaptive

    prep = prepare_scene(parse_scene(SCENE.format(w=96, h=72, env='procedural = "sky"',
                                                  mat='type = "ggx"\nalpha = 0.2\nspecular = 0.8')))
    one = render_adaptive(prep, budget=2.0, seed=3, mis=True, threads=1)
    three = render_adaptive(prep, budget=2.0, seed=3, mis=True, threads=3)
    assert one.coverage.sum() > 3 * 256 * 3   # enough covered pixels for several tiles per thread
    np.testing.assert_array_equal(one.image, three.image)
    for k in ("level", "n_p", "b_p", "sigma2"):
        np.testing.assert_array_equal(one.aovs[k], three.aovs[k])
