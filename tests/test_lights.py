"""Directional lights on spheres and meshes (warpbw.lights, through the 002 renderer): closed forms,
superposition with the environment (reference and adaptive), the adaptive method's refusal of lights alone,
and the pipeline's stages."""
from __future__ import annotations

import functools
import math
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from warpbw import bandwidth as bw
from warpbw import brdf as B
from warpbw.gbuffer import SphereSpec, build_geometry, make_camera, render_gbuffer
from warpbw.lights import Lights, directional_struct
from warpbw.pipeline import _gbuffer, prepare_bandwidth, prepare_scene, render_adaptive, render_reference
from warpbw.scene import parse_scene
from warpbw.shading import shade_reference

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
    assert res.stats["spp"] == 0   # none taken, whatever was asked (it recorded 3)
    mis = render_reference(scene(lights=[light()]), spp=3, mis=True)
    assert np.array_equal(mis.image, res.image)
    assert mis.stats["mis"] is False and "+mis" not in " ".join(mis.stats["stages"])   # nothing was sampled


def test_two_lights_add():
    """Two lights give the sum of their images (each term is exact)."""
    other = light((-0.5, 0.2, 0.6), (1.0, 0.5, 2.0))
    a = render_reference(scene(mat=GGX, lights=[light()]), spp=1).image
    b = render_reference(scene(mat=GGX, lights=[other]), spp=1).image
    both = render_reference(scene(mat=GGX, lights=[light(), other]), spp=1).image
    np.testing.assert_allclose(both, a + b, rtol=1e-6, atol=1e-7)
    assert (a > 0).sum() > 100 and (b > 0).sum() > 100


def _ggx_numpy(wi, wo, alpha, spec):
    """GGX with the separable Smith G and a constant F = spec (a GGX material without eta and k), float64, written
    here from the textbook formula (as test_brdf's ggx_numpy): D G1(wi) G1(wo) / (4 cos_i cos_o),
    D = a^2 / (pi (cos_h^2 (a^2 - 1) + 1)^2), G1(c) = 2 c / (c + sqrt(a^2 + (1 - a^2) c^2))."""
    h = wi + wo
    h = h / np.linalg.norm(h, axis=1, keepdims=True)
    a2 = alpha * alpha
    d = a2 / (np.pi * (h[:, 2] ** 2 * (a2 - 1.0) + 1.0) ** 2)
    g1 = lambda c: 2.0 * c / (c + np.sqrt(a2 + (1.0 - a2) * c * c))  # noqa: E731
    f = d * g1(wi[:, 2]) * g1(wo[:, 2]) / (4.0 * wi[:, 2] * wo[:, 2])
    return f[:, None] * np.asarray(spec)[None]


def test_ggx_sphere_under_a_light_matches_the_brdf_in_each_pixels_frame():
    """E f(l, wo) (l . n) with f the GGX formula written out in numpy here (not the BRDF module's own evaluation,
    which the shading shares), at each pixel's local directions (the frame is rebuilt here from the G-buffer's
    normal and tangent)."""
    sc = scene(mat=GGX, lights=[light()])
    prep = prepare_scene(sc)
    res = render_reference(prep, spp=1)
    cov = res.coverage
    n = res.gbuffer.numpy("normal")[cov].astype(np.float64)
    t = res.gbuffer.numpy("tangent")[cov].astype(np.float64)
    v = res.gbuffer.numpy("view")[cov].astype(np.float64)
    b = np.cross(n, t)
    to_local = lambda w: np.stack([np.sum(w * t, 1), np.sum(w * b, 1), np.sum(w * n, 1)], axis=1)  # noqa: E731
    wl = to_local(np.broadcast_to(unit(SUN_DIR), n.shape))
    wo = to_local(v)
    lit = (wl[:, 2] > 0) & (wo[:, 2] > 0)
    f = np.zeros((len(wl), 3))
    f[lit] = _ggx_numpy(wl[lit], wo[lit], 0.1, (0.9, 0.7, 0.5))   # GGX: alpha 0.1, specular [0.9, 0.7, 0.5]
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


def test_adaptive_adds_the_lights_exactly_after_the_up_sampling():
    """Superposition through the hierarchy: environment + light, adaptive, equals the environment alone,
    adaptive at the same seed (same levels, same N_p, same samples), plus the light's exact term at every
    pixel.  Up-sampling the light with the environment, or counting it in the bandwidth pass, breaks it."""
    env_only = render_adaptive(scene(mat=GGX, env=SKY, w=48, h=48), budget=2.0, seed=4, mis=True)
    light_only = render_reference(scene(mat=GGX, lights=[light()], w=48, h=48), spp=1).image
    both = render_adaptive(scene(mat=GGX, env=SKY, lights=[light()], w=48, h=48), budget=2.0, seed=4, mis=True)
    for k in ("level", "n_p"):
        np.testing.assert_array_equal(both.aovs[k], env_only.aovs[k])
    assert both.stats["samples"] == env_only.stats["samples"] > 0
    assert env_only.stats["shaded_fraction"] < 0.9   # some pixels are up-sampled: the check has teeth
    np.testing.assert_allclose(both.image, env_only.image + light_only, rtol=1e-5, atol=1e-6)
    assert "lights" in both.stats["time_s"] and "lights" not in env_only.stats["time_s"]


@pytest.mark.parametrize("mis", [False, True])
def test_adaptive_frame_uses_the_lights_kernel_it_compiled_before_timing(monkeypatch, mis):
    """The frame compiles its kernels before it times its stages (the "compile" stage); the lights' kernel it
    then runs must be the variant it compiled: with MIS a different one was built inside the timed lights stage."""
    from warpbw import shading

    made = []
    real = shading._reference_kernel

    def recording(*key):
        made.append(key)
        return real(*key)

    monkeypatch.setattr(shading, "_reference_kernel", recording)
    render_adaptive(scene(mat=GGX, env=SKY, lights=[light()], w=24, h=24), budget=1.0, seed=1, mis=mis)
    lights_only = {k for k in made if not k[3]}                  # has_env False: the lights' term alone
    assert lights_only == {(k[0], mis, False, False, True) for k in lights_only} and len(lights_only) == 1


def test_adaptive_and_the_bandwidth_pass_refuse_a_scene_lit_by_lights_alone():
    """Lights alone are exact at any spp: there is nothing to adapt, and the pass has nothing to predict."""
    from warpbw.errors import WarpbwError

    sc = scene(mat=GGX, lights=[light()])
    with pytest.raises(WarpbwError, match=r"needs an \[environment\].*exact"):
        render_adaptive(sc, budget=1.0)
    prep = prepare_scene(sc)
    with pytest.raises(WarpbwError, match=r"needs an \[environment\]"):
        prepare_bandwidth(prep)
    with pytest.raises(WarpbwError, match=r"no environment"):
        bw.bandwidth_pass(_gbuffer(prep, {})[0], prep.camera, prep.materials, None, None)


def test_adaptive_under_a_sun_and_a_sky_is_close_to_the_reference():
    """A sun 10^3 brighter than the sky beside it, on a sharp GGX sphere whose highlight is about two pixels
    wide: adaptive stays finite and within a few per cent of the reference, in the mean and in the highlight
    (the sun's term is exact at every pixel; when it was up-sampled with the sky, the mean was 14% high)."""
    sharp = 'type = "ggx"\nalpha = 0.1\nspecular = [0.9, 0.7, 0.5]'
    sc = scene(mat=sharp, env=SKY, lights=[light(radiance=(1e3, 1e3, 1e3))], w=48, h=48)
    ref = render_reference(sc, spp=64, seed=2, mis=True)
    ad = render_adaptive(sc, budget=4.0, seed=2, mis=True)
    cov = ref.coverage
    assert np.isfinite(ad.image).all()
    rel = abs(ad.image[cov].mean() / ref.image[cov].mean() - 1)
    assert rel < 0.005, rel
    peak = np.unravel_index(np.argmax(ref.image.sum(-1)), cov.shape)
    assert abs(ad.image[peak].sum() / ref.image[peak].sum() - 1) < 0.005


def test_info_lists_the_lights_and_no_environment(tmp_path):
    from warpbw.pipeline import scene_summary

    s = scene_summary(scene(lights=[light(), light((0.0, 1.0, 0.0))]))
    assert len(s["lights"]) == 2 and s["lights"][1].startswith("directional towards [0.0, 1.0, 0.0]")
    assert s["environment"].startswith("none")
    assert "directional lights exact" in s["stages"][-1] and "environment light" not in s["stages"][-1]


def test_render_adaptive_cli_reports_the_lights_pass(tmp_path, capsys):
    """``warpbw render --method adaptive`` on a sky + sun scene: the summary and the stats JSON time the
    lights' exact pass on its own."""
    import json

    from warpbw.cli import main

    p = tmp_path / "s.toml"
    p.write_text(SCENE.format(w=24, h=24, env=SKY, lights=light(), mat=GGX))
    assert main(["render", str(p), "-o", str(tmp_path / "o.exr"), "--method", "adaptive", "--budget", "1"]) == 0
    assert "lights (exact, every pixel)" in capsys.readouterr().out
    stats = json.loads((tmp_path / "o.json").read_text())
    assert stats["time_s"]["lights"] > 0 and "light:environment+directional" in stats["stages"]


def test_directional_struct_refuses_mismatched_counts_nan_and_zero_directions_and_scales_to_unit():
    """2 directions with 1 radiance were taken (the shading loops over the directions and reads radiance[k]: past
    its end), a NaN direction was stored, and [0, 5, 0] stored as it is (the shading takes unit vectors)."""
    from warpbw.errors import WarpbwError
    from warpbw.lights import directional_struct

    for d, e, msg in (([[0, 1, 0], [1, 0, 0]], [[1, 1, 1]], r"one per direction, got shapes \(2, 3\) and \(1, 3\)"),
                      ([0, 1, 0, 1], [[1, 1, 1]], r"got shapes \(4,\) and \(1, 3\)"),
                      ([[np.nan, 0, 0]], [[1, 1, 1]], r"^directional_struct: directions: expected finite non-zero"),
                      ([[0, 0, 0]], [[1, 1, 1]], r"^directional_struct: directions: expected finite non-zero"),
                      ([[0, 1, 0]], [[-1, 1, 1]], r"^directional_struct: radiances: expected radiances that are "
                                                  r"finite, >= 0"),
                      ([[0, 1, 0]], [[np.nan, 1, 1]], r"^directional_struct: radiances"),
                      ([["a", 1, 0]], [[1, 1, 1]], r"^directional_struct: expected \(n, 3\) numbers")):
        with pytest.raises(WarpbwError, match=msg):
            directional_struct(d, e)
    s = directional_struct([[0, 5, 0], [3, 0, 4]], [[1, 2, 3], [0, 0, 0]])
    np.testing.assert_allclose(s.direction.numpy(), [[0, 1, 0], [0.6, 0, 0.8]], rtol=1e-6)
    np.testing.assert_array_equal(s.radiance.numpy(), [[1, 2, 3], [0, 0, 0]])
    assert directional_struct([], []).direction.shape == (0,)


def test_make_lights_takes_directions_whose_norm_overflows_or_underflows():
    """(1e200, 1e200, 0) and (1e-200, 0, 0) were refused as not "non-zero finite": their plain norm overflows or
    underflows (each is now divided by its largest component first)."""
    from warpbw.errors import WarpbwError
    from warpbw.lights import make_lights

    class L:
        def __init__(self, d, e=(1.0, 1.0, 1.0)):
            self.direction, self.radiance = d, e
    got = make_lights([L((1e200, 1e200, 0.0)), L((1e-200, 0.0, 0.0)), L((0.0, -1e-320, 0.0))]).data.direction.numpy()
    np.testing.assert_allclose(got, [[2 ** -0.5, 2 ** -0.5, 0], [1, 0, 0], [0, -1, 0]], rtol=1e-6)
    for lights, msg in (([L((0.0, 0.0, 0.0))], r"^\[\[light\]\]: expected finite non-zero directions"),
                        ([L((np.inf, 0.0, 0.0))], r"^\[\[light\]\]: expected finite non-zero directions"),
                        ([L((0.0, 1.0))], r"^\[\[light\]\] 0: expected a direction and a radiance of 3 numbers"),
                        ([L((0.0, 1.0, 0.0), 1.0)], r"^\[\[light\]\] 0: expected a direction and a radiance")):
        with pytest.raises(WarpbwError, match=msg):
            make_lights(lights)


def test_a_frame_whose_light_overflows_the_shading_is_refused():
    """warpbw.pipeline: a frame whose shading dropped samples to float32 overflow is refused when the light's
    radiance passes RADIANCE_OVERFLOW_MIN (FLOAT32_MAX / BRDF_VALUE_MAX), so that the image is not returned
    short of its light.  Truth: a GGX sphere (alpha 0.05, lobe peak about 30) lit along the view by a directional
    light of radiance 3e38: E f cos passes FLOAT32_MAX at the highlight; at radiance 1 it renders finite."""
    from warpbw.errors import WarpbwError

    ggx = 'type = "ggx"\nalpha = 0.05\nspecular = [1.0, 1.0, 1.0]'

    def lit(e):
        return scene(mat=ggx, lights=[f'[[light]]\ntype = "directional"\ndirection = [0.0, 0.0, 1.0]\n'
                                      f'radiance = [{e}, {e}, {e}]\n'], w=15, h=15)

    ok = render_reference(lit(1.0), spp=1)
    assert np.isfinite(ok.image).all() and ok.image.max() > 1.0     # the highlight: f cos above 1
    with pytest.raises(WarpbwError, match="overflowed float32"):
        render_reference(lit(3e38), spp=1)


def test_the_overflow_refusal_counts_the_lights_terms_and_names_only_what_the_scene_has():
    """The count of dropped terms holds the lights' (one per light and pixel shaded) beside the samples: a scene lit
    by one light alone was told "1 of 0 samples overflowed" and to "lower [environment] scale", which it has not.
    Truth: the 15 x 15 GGX sphere of the test above (121 covered pixels, counted here by numpy's ray-sphere test) under
    a light of 3e38 along the view drops the highlight's one term; no sample is taken."""
    from warpbw.errors import WarpbwError

    ggx = 'type = "ggx"\nalpha = 0.05\nspecular = [1.0, 1.0, 1.0]'
    sc = scene(mat=ggx, lights=[light((0.0, 0.0, 1.0), (3e38, 3e38, 3e38))], w=15, h=15)
    x, y = np.meshgrid(np.arange(15) + 0.5, np.arange(15) + 0.5)
    t = math.tan(math.radians(35.0) / 2)
    d = np.stack([(2 * x / 15 - 1) * t, (1 - 2 * y / 15) * t, -np.ones_like(x)], -1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    covered = int(((d[..., 2] * 4.0) ** 2 - 15.0 > 0).sum())   # |o + t d| = 1 has a root: (d . o)^2 - (|o|^2 - 1) > 0
    assert covered == 121
    with pytest.raises(WarpbwError) as e:
        render_reference(sc, spp=1)
    msg = str(e.value)
    assert f"1 of {covered} terms (0 samples, {covered} of directional lights) overflowed float32" in msg, msg
    assert "[environment]" not in msg and msg.endswith("lower the lights' radiance"), msg


def test_an_adaptive_frame_whose_light_overflows_the_shading_is_refused_as_the_reference_is():
    """The adaptive method adds the lights' exact term after the hierarchy, outside the bandwidth pass (whose own
    overflow check therefore never sees a light): a light whose term E f cos overflows float32 at the highlight
    had that term dropped, and the frame came back with the highlight's pixel at the sky's 0.16 (a warning only),
    where the reference refuses the same scene.  Truth: the GGX sphere of the test above (alpha 0.05, peak about
    30, lit along the view) under a sky, with the light at 3e38 (E f cos passes FLOAT32_MAX) and at 1 (finite)."""
    from warpbw.errors import WarpbwError

    ggx = 'type = "ggx"\nalpha = 0.05\nspecular = [1.0, 1.0, 1.0]'

    def lit(e):
        return scene(mat=ggx, env=SKY, lights=[f'[[light]]\ntype = "directional"\ndirection = [0.0, 0.0, 1.0]\n'
                                               f'radiance = [{e}, {e}, {e}]\n'], w=15, h=15)

    ok = render_adaptive(lit(1.0), budget=2.0, seed=1)
    assert np.isfinite(ok.image).all() and ok.image[7, 7].min() > 10.0   # the highlight at the centre: f cos ~ 32
    with pytest.raises(WarpbwError, match="overflowed float32"):
        render_reference(lit(3e38), spp=1)
    with pytest.raises(WarpbwError, match="overflowed float32"):
        render_adaptive(lit(3e38), budget=2.0, seed=1)


# ------------------------------------------------------------------------------------------ properties (hypothesis)
# Property-based tests of directional lights (warpbw.lights, shaded by warpbw.shading's reference kernel): for any
# direction (of any length, above or below either sphere's horizon) and any RGB radiance, the exact term
# E rho(l, wo) max(l . n, 0) of 002 Eq. 1 is linear in E channel by channel, zero wherever the light is below the
# surface, the Lambert closed form, and the lights of a scene add.  One G-buffer (a Lambert and a GGX sphere) and one
# compiled kernel serve every example: no environment, so no sample is taken.


ALBEDO = np.array([0.8, 0.5, 0.2])
W, H = 30, 22                       # wider than tall; the spheres side by side


@functools.cache
def two_spheres():
    """The G-buffer (a Lambert and a GGX sphere), its material table, and per pixel the normal, the material and
    whether it is covered; made on first use, not when the module is collected."""
    cam = make_camera((0.7, 1.1, 4.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 50.0, W, H)
    gb = render_gbuffer(cam, build_geometry([SphereSpec((-0.8, 0.0, 0.0), 0.75, 0),
                                             SphereSpec((0.8, 0.1, -0.2), 0.7, 1)], []), threads=1)
    mats = B.build_material_table([B.MaterialSpec("clay", B.LAMBERT, albedo=tuple(ALBEDO)),
                                   B.MaterialSpec("metal", B.GGX, alpha=0.3, specular=(0.9, 0.7, 0.5))])
    material = gb.numpy("material").reshape(-1)
    return SimpleNamespace(gb=gb, mats=mats, normal=gb.numpy("normal").reshape(-1, 3).astype(np.float64),
                           material=material, covered=material >= 0)


def shade(directions, radiances):
    """The image (H*W, 3) of the scene lit by these directional lights alone."""
    d = np.asarray(directions, np.float64).reshape(-1, 3)
    e = np.asarray(radiances, np.float64).reshape(-1, 3)
    lights = Lights(directional_struct(d, e), len(d))
    sc = two_spheres()
    return shade_reference(sc.gb, sc.mats, None, 0, lights=lights, threads=1).radiance.numpy().astype(np.float64)


directions = st.tuples(*[st.floats(-1.0, 1.0)] * 3).filter(lambda v: np.linalg.norm(v) > 0.05)
radiances = st.tuples(*[st.just(0.0) | st.floats(1e-3, 50.0)] * 3)   # within float32: 1e-93 would read 0


def test_the_scene_shows_both_materials():
    """The fixture the properties below rely on: both spheres in view, each over many pixels."""
    sc = two_spheres()
    assert (sc.material == 0).sum() > 60 and (sc.material == 1).sum() > 60


@settings(max_examples=40, deadline=None)
@given(direction=directions, radiance=radiances, s=st.floats(1e-3, 1e3))
def test_a_light_is_linear_in_its_radiance_channel_by_channel(direction, radiance, s):
    """L_p = E rho(l, wo) max(l . n, 0) (002 Eq. 1 with a Dirac delta at l; module docstring): each channel of E
    multiplies the same channel of rho cos only.  So the image under E is E times (per channel) the image under
    white light (1, 1, 1), and scaling E by s scales the image by s."""
    white = shade(direction, (1.0, 1.0, 1.0))
    lit = shade(direction, radiance)
    np.testing.assert_allclose(lit, white * np.asarray(radiance), rtol=2e-6, atol=1e-30)
    np.testing.assert_allclose(shade(direction, np.asarray(radiance) * s), lit * s, rtol=2e-6, atol=1e-30)


@settings(max_examples=40, deadline=None)
@given(direction=directions, length=st.floats(1e-3, 1e3), radiance=radiances)
def test_a_light_below_the_horizon_adds_nothing_and_a_lambert_surface_reads_the_closed_form(direction, length,
                                                                                             radiance):
    """With l the unit direction towards the light (any length is scaled to unit: directional_struct), a pixel
    whose normal faces away from it (l . n <= 0) receives exactly 0, on any material; on the Lambert sphere every
    pixel reads albedo / pi * E * max(l . n, 0), and so does not depend on the length given; the background stays
    0."""
    sc = two_spheres()
    l = unit(direction)
    img = shade(l * length, radiance)
    cos = sc.normal @ l
    below = sc.covered & (cos <= 0.0)
    assert np.all(img[below] == 0.0)
    assert np.all(img[~sc.covered] == 0.0)
    clay = sc.material == 0
    expect = ALBEDO / math.pi * np.asarray(radiance) * np.maximum(cos[clay], 0.0)[:, None]
    np.testing.assert_allclose(img[clay], expect, rtol=1e-5, atol=1e-6 * max(radiance))


@settings(max_examples=25, deadline=None)
@given(lights=st.lists(st.tuples(directions, radiances), min_size=2, max_size=4))
def test_the_lights_of_a_scene_add(lights):
    """Each light's term is exact and independent of the others (no visibility, no sampling: module docstring),
    so n lights together give the sum of the n images each gives alone."""
    dirs = [d for d, _ in lights]
    rads = [e for _, e in lights]
    together = shade(dirs, rads)
    alone = sum(shade(d, e) for d, e in lights)
    np.testing.assert_allclose(together, alone, rtol=1e-5, atol=1e-6 * (1.0 + max(max(e) for e in rads)))


def test_the_shading_takes_directional_structs_own_struct_as_the_lights():
    """directional_struct (the documented builder of lights from arrays) returns the Warp struct; shade_reference
    takes it as it takes the Lights wrapper (it was an AttributeError): the Lambert sphere reads
    albedo / pi * E * max(l . n, 0) (closed form) both ways, bit for bit the same."""
    sc = two_spheres()
    d, e = np.array([[0.3, 0.8, 0.5]]), np.array([[2.0, 1.0, 0.5]])
    bare = shade_reference(sc.gb, sc.mats, None, 0, lights=directional_struct(d, e), threads=1).radiance.numpy()
    np.testing.assert_array_equal(bare, shade(d, e).astype(np.float32))
    lam = sc.material == 0
    l_unit = d[0] / np.linalg.norm(d[0])
    want = ALBEDO / np.pi * e[0] * np.maximum(sc.normal[lam] @ l_unit, 0.0)[:, None]
    np.testing.assert_allclose(bare[lam], want, rtol=1e-5, atol=1e-7)
