"""Directional lights on spheres and meshes (warpbw.lights, through the 002 renderer): closed forms,
superposition with the environment, the bandwidth pass's weights, and the pipeline's stages."""
from __future__ import annotations

import math

import numpy as np
import pytest

from warpbw import bandwidth as bw
from warpbw.brdf import eval_brdf
from warpbw.pipeline import _gbuffer, prepare_bandwidth, prepare_scene, render_adaptive, render_reference
from warpbw.scene import parse_scene

SCENE = """
[camera]
position = [0.0, 0.0, 4.0]
look_at = [0.0, 0.0, 0.0]
fov = 35.0
resolution = [{w}, {h}]
{env}
{lights}
[[object]]
shape = "sphere"
radius = 1.0
material = "m"
[material.m]
{mat}
"""
LAMBERT = 'type = "lambert"\nalbedo = [0.8, 0.5, 0.2]'
GGX = 'type = "ggx"\nalpha = 0.1\nspecular = [0.9, 0.7, 0.5]'
SKY = '[environment]\nprocedural = "sky"'
SUN_DIR = (0.3, 0.6, 0.8)


def light(direction=SUN_DIR, radiance=(2.0, 1.5, 1.0)) -> str:
    return (f'[[light]]\ntype = "directional"\ndirection = {list(direction)}\n'
            f'radiance = {list(radiance)}\n')


def scene(mat=LAMBERT, env="", lights=(), w=40, h=40):
    return parse_scene(SCENE.format(w=w, h=h, env=env, lights="\n".join(lights), mat=mat))


def unit(v):
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


def test_lambert_sphere_under_a_light_alone_is_the_closed_form():
    """L = albedo / pi * E * max(n . l, 0) on every covered pixel, exactly (no sampling); black elsewhere."""
    res = render_reference(scene(lights=[light()]), spp=3)
    n = res.gbuffer.numpy("normal")
    expect = (np.array([0.8, 0.5, 0.2]) / math.pi)[None, None] * np.array([2.0, 1.5, 1.0]) \
        * np.maximum(n @ unit(SUN_DIR), 0.0)[..., None]
    cov = res.coverage
    assert cov.sum() > 600
    np.testing.assert_allclose(res.image[cov], expect[cov], atol=1e-6)
    assert (res.image[~cov] == 0).all()
    assert (n[cov] @ unit(SUN_DIR) < 0).sum() > 30  # the unlit side is in view, and black
    assert res.stats["samples"] == 0 and "light:directional" in res.stats["stages"]


def test_two_lights_add():
    """Two lights give the sum of their images (each term is exact)."""
    other = light((-0.5, 0.2, 0.6), (1.0, 0.5, 2.0))
    a = render_reference(scene(mat=GGX, lights=[light()]), spp=1).image
    b = render_reference(scene(mat=GGX, lights=[other]), spp=1).image
    both = render_reference(scene(mat=GGX, lights=[light(), other]), spp=1).image
    np.testing.assert_allclose(both, a + b, rtol=1e-6, atol=1e-7)
    assert (a > 0).sum() > 100 and (b > 0).sum() > 100


def test_ggx_sphere_under_a_light_matches_the_brdf_in_each_pixels_frame():
    """E f(l, wo) (l . n) with f evaluated by the BRDF's own host wrapper at each pixel's local directions
    (the frame is rebuilt here from the G-buffer's normal and tangent)."""
    sc = scene(mat=GGX, lights=[light()])
    prep = prepare_scene(sc)
    res = render_reference(prep, spp=1)
    cov = res.coverage
    n = res.gbuffer.numpy("normal")[cov]
    t = res.gbuffer.numpy("tangent")[cov]
    v = res.gbuffer.numpy("view")[cov]
    b = np.cross(n, t)
    to_local = lambda w: np.stack([np.sum(w * t, 1), np.sum(w * b, 1), np.sum(w * n, 1)], axis=1)  # noqa: E731
    wl = to_local(np.broadcast_to(unit(SUN_DIR), n.shape))
    wo = to_local(v)
    f = eval_brdf(prep.materials, 0, wl.astype(np.float32), wo.astype(np.float32))
    lit = (wl[:, 2] > 0) & (wo[:, 2] > 0)
    expect = np.where(lit[:, None], f * np.array([2.0, 1.5, 1.0]) * wl[:, 2:3], 0.0)
    np.testing.assert_allclose(res.image[cov], expect, rtol=2e-4, atol=1e-6)
    assert res.image[cov].max() > 5 * np.median(res.image[cov][lit])  # a highlight, not a flat sphere


@pytest.mark.parametrize("mis", [False, True])
def test_a_light_adds_its_exact_term_to_the_environment_estimate(mis):
    """Superposition: with the same seed, environment + light = environment alone + light alone (the light
    takes no random numbers), for both estimators."""
    env_only = render_reference(scene(mat=GGX, env=SKY), spp=8, seed=5, mis=mis).image
    light_only = render_reference(scene(mat=GGX, lights=[light()]), spp=8, seed=5, mis=mis).image
    both = render_reference(scene(mat=GGX, env=SKY, lights=[light()]), spp=8, seed=5, mis=mis)
    np.testing.assert_allclose(both.image, env_only + light_only, rtol=1e-5, atol=1e-6)
    assert {"light:environment+directional"} <= set(both.stats["stages"])
    assert both.stats["samples"] == 8 * both.stats["pixels_covered"]


def _pass(sc, n_b=16, **kw):
    prep = prepare_scene(sc)
    tables = prepare_bandwidth(prep)
    gb = _gbuffer(prep, {})
    return gb, bw.bandwidth_pass(gb, prep.camera, prep.materials, prep.env_data, tables, n_b=n_b,
                                 lights=prep.lights, **kw)


def test_pass_under_lights_alone_measures_no_variance():
    """Lights alone are exact: the pass's MIS variance and Eq. 9's bound are 0 on every covered pixel, while
    the lights' lobes still give the image a bandwidth."""
    sc = scene(mat=GGX, lights=[light()])
    gb, buf = _pass(sc, stride=1, pool_radius=0)  # per pixel: pooling would add the spread of D over neighbours
    cov = gb.coverage.reshape(-1)
    lum = render_reference(sc, spp=1).image.reshape(-1, 3)[cov] @ np.array(bw.LUMINANCE)
    # sum_k (w_k + D)^2 / n - D^2 = 0 up to float32 rounding of the two terms
    assert np.all(buf.variance_mis.numpy()[cov] <= 1e-5 * lum ** 2 + 1e-12)
    assert np.all(buf.sigma2.numpy()[cov] == 0)
    assert np.any(buf.b_p.numpy()[cov] > 0)


def test_pass_adds_a_light_without_changing_the_environment_variance():
    """Adding a constant term D to each of the pass's one-sample estimates leaves their variance unchanged:
    variance_mis with environment + light equals the environment's alone (same directions), while Eq. 5's
    mean radiance grows by D (seen through sigma2_rel = sigma2 / (mu^2 + eps))."""
    kw = dict(stride=1, pool_radius=0, seed=3)
    gb, env_only = _pass(scene(mat=GGX, env=SKY), **kw)
    _, both = _pass(scene(mat=GGX, env=SKY, lights=[light(radiance=(0.5, 0.5, 0.5))]), **kw)
    cov = gb.coverage.reshape(-1)
    v0 = env_only.variance_mis.numpy()[cov]
    v1 = both.variance_mis.numpy()[cov]
    scale = max(float(v0.max()), 1e-12)
    assert np.all(np.abs(v1 - v0) <= 1e-3 * scale + 2e-3 * v0)
    np.testing.assert_array_equal(both.sigma2.numpy()[cov], env_only.sigma2.numpy()[cov])
    lit = np.sum(gb.data.normal.numpy()[cov] * unit(SUN_DIR).astype(np.float32), axis=1) > 0.3
    r0 = env_only.sigma2_rel.numpy()[cov][lit]
    r1 = both.sigma2_rel.numpy()[cov][lit]
    assert np.all(r1 < r0)  # the light raised mu where it shines


def test_sharp_highlight_of_a_sun_is_shaded_finer_than_a_lambert_sphere():
    """Ordering, not magic numbers: under a light alone the sharp GGX sphere asks for level 0 at its
    highlight; the Lambert sphere (smooth irradiance) puts no pixel finer than the GGX highlight's."""
    lv = {}
    for name, mat in (("lambert", LAMBERT), ("ggx", 'type = "ggx"\nalpha = 0.03\nspecular = 0.9')):
        res = render_adaptive(scene(mat=mat, lights=[light((0.0, 0.3, 1.0))], w=64, h=64), budget=1.0, seed=1)
        cov = res.coverage
        lv[name] = res.aovs["level"][cov]
        assert res.stats["samples"] == 0 and np.isfinite(res.image).all()  # no environment: nothing sampled
    assert np.mean(lv["ggx"] == 0) > np.mean(lv["lambert"] == 0)
    assert lv["ggx"].min() == 0 and np.median(lv["lambert"]) > np.median(lv["ggx"])


def test_adaptive_under_a_sun_and_a_sky_is_close_to_the_reference():
    """A sun 10^3 brighter than the sky beside it, on a glossy sphere: adaptive stays finite and within a few
    per cent of the reference in the mean (the sun's term is exact in every shaded pixel; a lobe only two
    pixels wide, alpha = 0.1 here, is under-resolved by the up-sampling: +14% in the mean)."""
    glossy = 'type = "ggx"\nalpha = 0.3\nspecular = [0.9, 0.7, 0.5]'
    sc = scene(mat=glossy, env=SKY, lights=[light(radiance=(1e3, 1e3, 1e3))], w=48, h=48)
    ref = render_reference(sc, spp=64, seed=2, mis=True)
    ad = render_adaptive(sc, budget=4.0, seed=2, mis=True)
    cov = ref.coverage
    assert np.isfinite(ad.image).all()
    rel = abs(ad.image[cov].mean() / ref.image[cov].mean() - 1)
    assert rel < 0.05, rel


def test_info_lists_the_lights_and_no_environment(tmp_path):
    from warpbw.pipeline import scene_summary

    s = scene_summary(scene(lights=[light(), light((0.0, 1.0, 0.0))]))
    assert len(s["lights"]) == 2 and s["lights"][1].startswith("directional towards [0.0, 1.0, 0.0]")
    assert s["environment"].startswith("none")
    assert "directional lights exact" in s["stages"][-1] and "environment sampled" not in s["stages"][-1]
