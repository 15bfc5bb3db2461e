"""Reference estimator (002 Eq. 2) against closed forms: Lambert under a constant sky, white furnace.  The scripts
examples/reference_estimator.py and compare_mitsuba.py with stand-ins for the renders (and for Mitsuba): what they
hand the estimator, and their figures (throughput, relMSE over the eroded interior) against values worked by
hand."""
from __future__ import annotations

import json
import math
import re
import sys
from pathlib import Path
from types import SimpleNamespace

if sys.version_info >= (3, 11):
    import tomllib
else:   # Python 3.10: the backport pyproject installs there, as warpbw.scene reads it
    import tomli as tomllib

import numpy as np
import pytest
import warp as wp
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import StandInClock, load_example, outcome, plot_png
from warpbw.errors import WarpbwError
from warpbw.pipeline import prepare_scene, render_reference
from warpbw.scene import parse_scene
from warpbw.launch import tile_ranges

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


def test_a_pixel_of_twenty_million_samples_still_reads_its_albedo():
    """Every cosine-sampled sample of a Lambert sphere under a constant sky is the albedo, so any sample count
    reads it: the per-pixel sum was float32 and stopped growing past about 1.7e7 samples (2e7 read 0.885 x albedo,
    4e7 0.586 x)."""
    albedo = np.array([0.5, 0.25, 0.125])
    res = render_reference(sphere_scene(f'type = "lambert"\nalbedo = {albedo.tolist()}', w=1, h=1), spp=20_000_000)
    assert res.coverage.all()
    np.testing.assert_allclose(res.image[0, 0], albedo, rtol=1e-6)


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


SCALED_MATERIALS = ('type = "lambert"\nalbedo = [0.8, 0.5, 0.2]',
                    'type = "ggx"\nalpha = 0.2\nspecular = [0.9, 0.6, 0.3]',
                    'type = "ggx"\nalpha = 0.05\nspecular = [1.0, 1.0, 1.0]\neta = [0.143, 0.374, 1.442]\n'
                    'k = [3.983, 2.385, 1.603]')


@settings(max_examples=12, deadline=None)
@given(log2_k=st.integers(-10, 10), mis=st.booleans(), mat=st.sampled_from(SCALED_MATERIALS),
       rotation=st.floats(-180, 180), seed=st.integers(0, 2**16))
def test_scaling_the_environment_scales_the_image_sample_for_sample(log2_k, mis, mat, rotation, seed):
    """002 Eq. 2 is linear in L_i, and each sampler's pdf is normalised (the environment's by its luminance's total),
    so neither the directions drawn nor the MIS weights see the environment's scale: with the same seed, an
    environment k times brighter gives k times the image, bit for bit, with BRDF sampling or MIS, for any material
    and rotation.  A pdf that read the unnormalised radiance, or a clamp on radiance, breaks it.  k is a power of
    two, which float32 scales exactly: any other k rounds each texel, so the float32 CDF can move by an ulp and a
    row's or column's pdf (a difference of two such entries) by up to an ulp over its probability (k = 30.625 moved
    one pixel by 1.5e-5, session 80)."""
    k = 2.0 ** log2_k
    env = f'procedural = "sky"\nrotation = {rotation!r}\nscale = '
    a = render_reference(sphere_scene(mat, env=env + "1.0", w=16, h=12), spp=8, seed=seed, mis=mis)
    b = render_reference(sphere_scene(mat, env=env + repr(k), w=16, h=12), spp=8, seed=seed, mis=mis)
    assert np.array_equal(a.coverage, b.coverage) and a.coverage.any()
    assert np.array_equal(b.image, np.float32(k) * a.image)


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
    with pytest.raises(WarpbwError, match=r"spp: expected per-pixel integer counts .* got float64 \(144,\)"):
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



@wp.kernel
def _mark_item(offset: int, out: wp.array(dtype=float)):
    out[offset + wp.tid()] += 1.0


def test_the_shading_bar_counts_every_pixel_once_over_threads_and_none_when_off(tqdm_bars):
    """launch.progress_bar, fed the tile counts launch_tiled reports from two threads, stands at the launch's
    item count at the end (the bar is precompute.progress's, which takes running totals); off, it is None."""
    from warpbw.launch import launch_tiled, progress_bar

    out = wp.zeros(5000, dtype=wp.float32, device="cpu")
    with progress_bar(5000, "shading 4 spp") as add:
        launch_tiled(_mark_item, 5000, lambda o, c: [o, out], "cpu", threads=2, progress=add, tile=300)
    assert [(b.desc, b.n, b.total) for b in tqdm_bars] == [("shading 4 spp", 5000, 5000)]
    assert np.all(out.numpy() == 1.0)
    with progress_bar(5000, "off", enabled=False) as add:
        assert add is None



@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("item_cost, costs", [(50_000, None), (3_000_000, None), (0, None), (None, "ramp")])
def test_cpu_launches_hold_at_most_launch_cost_max_samples_so_ctrl_c_acts_within_a_second(monkeypatch, threads,
                                                                                          item_cost, costs):
    """Python acts on Ctrl-C and SIGTERM only between launches: tiles cut by pixels alone made one launch of 256 pixels
    x 2e6 samples (SIGINT at 5 s acted on at 36 s; options audit, session 64).  Every item is launched once, and a
    launch's summed cost (each item's, from the caller) stays within LAUNCH_COST_MAX plus one item's, the part a
    tile of equal summed cost may pass it by; an item dearer than that is a launch of its own."""
    from warpbw import launch
    from warpbw.launch import LAUNCH_COST_MAX, launch_tiled

    n = 5000
    cost = np.linspace(0, 20_000, n).astype(np.int64) if costs == "ramp" else np.full(n, item_cost)
    launches = []
    real = launch.wp.launch
    monkeypatch.setattr(launch.wp, "launch", lambda k, dim, inputs, device: launches.append((inputs[0], dim))
                        or real(k, dim=dim, inputs=inputs, device=device))
    out = wp.zeros(n, dtype=wp.float32, device="cpu")
    launch_tiled(_mark_item, n, lambda o, c: [o, out], "cpu", threads=threads,
                 costs=cost if costs == "ramp" else None, item_cost=item_cost)
    assert np.all(out.numpy() == 1.0)
    sums = [int(cost[o:o + c].sum()) for o, c in launches]
    assert max(sums) <= LAUNCH_COST_MAX + cost.max() or all(c == 1 for _, c in launches), sorted(sums)[-3:]
    if int(cost.sum()) > 4 * LAUNCH_COST_MAX:
        assert len(launches) >= min(n, int(cost.sum()) // LAUNCH_COST_MAX)
    else:   # cheap items: the tiles the pixel counts make, as before
        assert len(launches) <= -(-n // launch.MIN_PIXELS_PER_TILE) * threads


def test_cutting_launches_by_their_samples_leaves_every_pixel_as_it_was(monkeypatch, tmp_path):
    """The samples of a pixel are drawn from its own seed whatever the tile: a frame cut into many launches by
    LAUNCH_COST_MAX is bit for bit the frame of the few launches its pixel count makes, reference and adaptive."""
    from warpbw import launch, shading
    from warpbw.pipeline import render_adaptive, render_reference
    from warpbw.scene import parse_scene

    text = ("[camera]\nposition = [0.0, 0.0, 3.0]\nlook_at = [0.0, 0.0, 0.0]\nfov = 40.0\nresolution = [24, 16]\n"
            "[environment]\nprocedural = \"sky\"\n[material.m]\ntype = \"ggx\"\nalpha = 0.3\nspecular = 0.8\n"
            "[[object]]\nshape = \"sphere\"\nradius = 1.0\nmaterial = \"m\"\n")
    scene = parse_scene(text, tmp_path, "s.toml")
    frames = {}
    for limit in (10**12, 64):
        monkeypatch.setattr(shading, "LAUNCH_COST_MAX", limit)   # a pixel's passes
        monkeypatch.setattr(launch, "LAUNCH_COST_MAX", limit)    # the tiles, cut by their samples
        frames[limit] = (render_reference(scene, spp=16, seed=3).image, render_adaptive(scene, budget=4.0).image)
    for a, b in zip(frames[10**12], frames[64]):
        assert np.array_equal(a, b)



# ------------------------------------------------------------------------------ examples/reference_estimator.py

def _run_reference_estimator(monkeypatch, tmp_path, argv, out, seconds=lambda k: 1.0):
    """Run reference_estimator.main with stand-ins for every stage; returns what they were handed.  Shading call k
    (from 0) "takes" seconds(k) on the stand-in clock."""
    mod = load_example("reference_estimator")
    got = {"shade": [], "camera": None, "probe": None, "npf": None}
    clock = StandInClock()

    def load_envmap(path, device=None):
        got["probe"] = Path(path)
        return SimpleNamespace(name="probe", data=None)

    def read_npf(path, material):
        got["npf"] = (Path(path), material)
        return SimpleNamespace(name=material, rho_d=None, rho_s=None, D=None, G1=None, F=None)

    def make_camera(pos, look, up, fov, w, h):
        got["camera"] = (w, h)
        return SimpleNamespace(w=w, h=h)

    def render_gbuffer(cam, geo, device=None):
        return SimpleNamespace(coverage=np.ones((cam.h, cam.w), bool), w=cam.w, h=cam.h)

    def shade_reference(gb, mats, env, spp, seed=0, mis=False, device=None):
        clock.now += seconds(len(got["shade"]))                # by default every shading "takes" exactly 1 s
        got["shade"].append((spp, mis))
        img = np.full((gb.h * gb.w, 3), 0.5 if mis else 0.25, np.float32)
        return SimpleNamespace(samples=2_500_000, pixels_shaded=gb.h * gb.w, non_finite=0,
                               radiance=SimpleNamespace(numpy=lambda: img))

    import warpbw.io.npf
    import warpbw.sampling

    monkeypatch.setattr(mod, "init_warp", lambda dev: None)
    monkeypatch.setattr(mod, "load_envmap", load_envmap)
    monkeypatch.setattr(warpbw.io.npf, "read_npf", read_npf)
    monkeypatch.setattr(warpbw.sampling, "build_sampler_table", lambda f: None)
    monkeypatch.setattr(mod.B, "pack_npf_curves", lambda *a: None)
    monkeypatch.setattr(mod.B, "MaterialSpec", lambda *a, **k: a[0])
    monkeypatch.setattr(mod.B, "build_material_table", lambda specs, device=None: SimpleNamespace(names=specs))
    monkeypatch.setattr(mod, "build_geometry", lambda *a, **k: None)
    monkeypatch.setattr(mod, "make_camera", make_camera)
    monkeypatch.setattr(mod, "render_gbuffer", render_gbuffer)
    monkeypatch.setattr(mod, "shade_reference", shade_reference)
    monkeypatch.setattr(mod, "time", clock)
    monkeypatch.setattr(sys, "argv", ["reference_estimator.py", *argv, "--out", str(out)])
    mod.main()
    return got


def test_reference_estimator_passes_its_options_and_names_each_image_by_its_estimator(tmp_path, monkeypatch,
                                                                                      capsys):
    """--probe, --npf, --material, --spp and --resolution reach the stages they name (module docstring, --help);
    the timed renders are BRDF sampling then MIS, written to ref_bis.exr and ref_mis.exr; and the throughput counts
    evaluations: with MIS a sample is a BRDF and an environment sample (warpbw.shading.ShadeResult.samples), so
    2.5 M samples in 1 s are 2.50 M evaluations/s without MIS and 5.00 M with it."""
    from warpbw.io.exr import read_exr

    probe, npf = tmp_path / "p.exr", tmp_path / "t.bin"
    probe.write_bytes(b"x")
    npf.write_bytes(b"x")
    got = _run_reference_estimator(monkeypatch, tmp_path, ["--probe", str(probe), "--npf", str(npf), "--material",
                                                           "chrome", "--spp", "7", "--resolution", "8", "4"],
                                   tmp_path / "o")
    assert got["probe"] == probe and got["npf"] == (npf, "chrome")
    assert got["camera"] == (8, 4)
    assert got["shade"] == [(1, False), *[(7, False)] * 3, (1, True), *[(7, True)] * 3]   # warm-up, 3 timed
    assert float(np.unique(read_exr(tmp_path / "o" / "ref_bis.exr").pixels)[0]) == 0.25
    assert float(np.unique(read_exr(tmp_path / "o" / "ref_mis.exr").pixels)[0]) == 0.5
    out = capsys.readouterr().out
    assert re.search(r"ref_bis: 7 spp .*\(2\.50 M evaluations/s\)", out), out
    assert re.search(r"ref_mis: 7 spp .*\(5\.00 M evaluations/s\)", out), out


def test_reference_estimator_defaults_are_the_documented_ones(tmp_path, monkeypatch):
    """Without options: --spp 64, --runs 3 and --resolution 384 160 (module docstring and --help), the NPF sphere
    of gold-metallic-paint."""
    probe, npf = tmp_path / "p.exr", tmp_path / "t.bin"
    probe.write_bytes(b"x")
    npf.write_bytes(b"x")
    got = _run_reference_estimator(monkeypatch, tmp_path, ["--probe", str(probe), "--npf", str(npf)], tmp_path / "o")
    assert got["shade"] == [(1, False), *[(64, False)] * 3, (1, True), *[(64, True)] * 3]
    assert got["camera"] == (384, 160) and got["npf"] == (npf, "gold-metallic-paint")


def test_reference_estimator_times_the_median_of_its_runs_and_records_what_it_prints(tmp_path, monkeypatch,
                                                                                      capsys):
    """DESIGN.md, measurement protocol: the median of at least 3 runs after a warm-up, and a JSON record and a PNG
    plot.  The example timed one frame per estimator and wrote neither.  Stand-in clock: the warm-ups take 100 s,
    the timed frames 3, 1 and 2 s (BRDF sampling) and 6, 2 and 4 s (MIS): medians 2 s and 4 s, so 2.5 M samples
    read 1.25 M evaluations/s and, two evaluations each with MIS, 1.25 again."""
    probe, npf = tmp_path / "p.exr", tmp_path / "t.bin"
    probe.write_bytes(b"x")
    npf.write_bytes(b"x")
    secs = [100.0, 3.0, 1.0, 2.0, 100.0, 6.0, 2.0, 4.0]
    _run_reference_estimator(monkeypatch, tmp_path, ["--probe", str(probe), "--npf", str(npf), "--spp", "7",
                                                     "--resolution", "8", "4", "--json", str(tmp_path / "r.json")],
                             tmp_path / "o", seconds=lambda k: secs[k])
    out = capsys.readouterr().out
    rec = json.loads((tmp_path / "r.json").read_text())
    assert (rec["resolution"], rec["spp"], rec["runs"], rec["device"]) == ([8, 4], 7, 3, "cpu") and rec["threads"] >= 1
    for name, runs, median in (("ref_bis", [3.0, 1.0, 2.0], 2.0), ("ref_mis", [6.0, 2.0, 4.0], 4.0)):
        e = rec["estimators"][name]
        assert e["time_runs_s"] == runs and e["time_s"] == median and e["evaluations_per_s"] == 1.25e6
        m = re.search(rf"{name}: 7 spp over (\d+) pixels in ([\d.]+) s \(([\d.]+) M evaluations/s\), non-finite "
                      rf"samples (\d+); mean radiance \[([\d. ]+)\]", out)
        assert m, out
        assert (int(m[1]), m[2], m[3], int(m[4])) == (e["pixels_shaded"], f"{e['time_s']:.2f}",
                                                     f"{e['evaluations_per_s'] / 1e6:.2f}", e["non_finite_samples"])
        assert [float(v) for v in m[5].split()] == pytest.approx(e["mean_radiance"], abs=1e-4)
    assert rec["estimators"]["ref_mis"]["mean_radiance"] == [0.5, 0.5, 0.5]
    plot_png(tmp_path / "r.png")


@pytest.mark.parametrize("argv, needle", [
    (["--json", "old.json"], "old.json: already exists"),
    (["--plot", "q.png"], "q.png: already exists"),
    (["--json", "r.txt"], "--json r.txt: expected a path ending in .json"),
    (["--plot", "r.jpg"], "--plot r.jpg: expected a path ending in .png"),
])
def test_reference_estimator_refuses_its_record_before_any_work(tmp_path, monkeypatch, argv, needle):
    """--json / --plot follow warpbw bench's rules, checked before the probe is read or anything shaded."""
    monkeypatch.chdir(tmp_path)
    probe, npf = tmp_path / "p.exr", tmp_path / "t.bin"
    probe.write_bytes(b"x")
    npf.write_bytes(b"x")
    for name in ("old.json", "q.png"):
        (tmp_path / name).write_text("kept\n")
    how = outcome(_run_reference_estimator, monkeypatch, tmp_path, ["--probe", str(probe), "--npf", str(npf),
                                                                    *argv], tmp_path / "o")
    assert how.startswith("WarpbwError") and needle in how, how
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.json", "p.exr", "q.png", "t.bin"]


@pytest.mark.parametrize("runs, warns", [(1, True), (2, True), (3, False)])
def test_reference_estimator_warns_of_fewer_runs_than_the_protocols_three(tmp_path, monkeypatch, capsys, runs,
                                                                          warns):
    probe, npf = tmp_path / "p.exr", tmp_path / "t.bin"
    probe.write_bytes(b"x")
    npf.write_bytes(b"x")
    got = _run_reference_estimator(monkeypatch, tmp_path, ["--probe", str(probe), "--npf", str(npf), "--runs",
                                                           str(runs)], tmp_path / "o")
    assert len(got["shade"]) == 2 * (1 + runs)
    err = capsys.readouterr().err
    assert (f"reference_estimator.py: warning: --runs {runs}: the measurement protocol times the median of at least 3"
            in err) == warns, err


# ------------------------------------------------------------------------------- examples/compare_mitsuba.py

def test_compare_mitsuba_erode_and_relmse_sum_by_hand():
    """erode: binary erosion by the (2r+1)^2 square, outside the image uncovered (its docstring; the interior mask
    of the module docstring); relmse_sum = sum((a - b)^2) / sum(b^2) with b the reference (Mitsuba)."""
    cm = load_example("compare_mitsuba")
    full = np.ones((7, 7), bool)
    want = np.zeros((7, 7), bool)
    want[2:5, 2:5] = True
    np.testing.assert_array_equal(cm.erode(full, 2), want)
    block = np.zeros((9, 10), bool)
    block[1:8, 1:9] = True
    want = np.zeros((9, 10), bool)
    want[3:6, 3:7] = True
    np.testing.assert_array_equal(cm.erode(block, 2), want)
    test, ref = np.full((2, 2, 3), 2.0), np.ones((2, 2, 3))
    assert cm.relmse_sum(test, ref, np.ones((2, 2), bool)) == pytest.approx(1.0)


def test_compare_mitsuba_warpbw_side_gets_the_scale_rotation_and_estimator(tmp_path):
    """The warpbw scene has the probe's --rotation and --scale (the same radiance as Mitsuba's, module docstring);
    MIS is passed to render_reference only when asked (--no-mis: "its CLI default")."""
    cm = load_example("compare_mitsuba")
    t = tomllib.loads(cm.warpbw_toml(tmp_path / "p.exr", cm.CASES["ggx0.4"], 32, 30.0, 2.5))
    assert t["environment"]["rotation"] == 30.0 and t["environment"]["scale"] == 2.5
    assert t["camera"]["resolution"] == [32, 32] and t["material"]["m"]["alpha"] == 0.4
    seen = []

    def render_reference(scene, spp=1, seed=0, device=None, **kw):
        seen.append(kw)
        return SimpleNamespace(image=np.zeros((2, 2, 3)), coverage=np.zeros((2, 2), bool))

    for mis in (True, False):
        cm.render_warpbw(lambda text, base_dir=None: text, render_reference, "", 4, 0, mis)
    assert seen == [{"mis": True}, {}]


def test_compare_mitsuba_times_warpbws_render_alone_as_mitsubas(tmp_path, monkeypatch):
    """Mitsuba's scene is built before its timed render; warpbw's scene was handed to render_reference as a Scene,
    so its probe, materials and geometry were loaded inside the timed call (DESIGN.md: the wall time of a frame).
    Stand-ins on a stand-in clock: loading a scene takes 100 s, a render 1 s, and render_reference loads a scene it
    is handed unprepared, as warpbw.pipeline's does.  The time is the render's alone: 1 s."""
    import warpbw.pipeline

    cm = load_example("compare_mitsuba")
    clock = StandInClock()
    prepared = []

    def prepare_scene(scene, device="cpu", progress=False):
        clock.now += 100.0
        prepared.append(scene)
        return SimpleNamespace(prepared=scene)

    def render_reference(scene, spp=1, seed=0, mis=False, device=None, **kw):
        if not hasattr(scene, "prepared"):
            scene = prepare_scene(scene)
        clock.now += 1.0
        return SimpleNamespace(image=np.zeros((2, 2, 3)), coverage=np.zeros((2, 2), bool))

    monkeypatch.setattr(warpbw.pipeline, "prepare_scene", prepare_scene)
    monkeypatch.setattr(warpbw.pipeline, "render_reference", render_reference)
    monkeypatch.setattr(cm, "time", clock)
    monkeypatch.setattr(cm, "init_warp", lambda dev: None)
    from warpbw.io.exr import write_exr

    probe = tmp_path / "p.exr"
    write_exr(probe, np.ones((4, 8, 3), np.float32))
    toml_text = cm.warpbw_toml(probe, cm.CASES["lambert"], 8, 0.0, 1.0)
    _, _, seconds = cm.render_warpbw(*cm.import_warpbw(), toml_text, 4, 0, True)
    assert seconds == 1.0 and len(prepared) == 1


def test_compare_mitsuba_options_defaults(tmp_path):
    """--help: --spp 1024, --resolution 256, --runs 3; MIS by default, BRDF sampling with --no-mis."""
    cm = load_example("compare_mitsuba")
    probe = tmp_path / "p.exr"
    probe.write_bytes(b"x")
    a = cm.parse_args(["--probe", str(probe)])
    assert (a.spp, a.resolution, a.mitsuba_spp, a.mis, a.runs) == (1024, 256, None, True, 3)
    assert cm.parse_args(["--probe", str(probe), "--no-mis"]).mis is False


def _run_compare_mitsuba(monkeypatch, tmp_path, argv):
    """compare_mitsuba.main with stand-ins for Mitsuba and warpbw on 16x16 images: both cover rows and columns
    2-13 (so the 2-pixel erosion leaves 4-11, 64 pixels); Mitsuba's image is 1 (at seed 6, 1 + 0.05 * checker);
    warpbw's is Mitsuba's seed-5 image plus 0.5 on the rim and, in the interior, 0.05 (lambert) or 0.123085
    (ggx0.1)."""
    cm = load_example("compare_mitsuba")
    R = 16
    cov = np.zeros((R, R), bool)
    cov[2:14, 2:14] = True
    inner = cm.erode(cov, 2)
    c = np.where((np.arange(R)[:, None] + np.arange(R)[None, :]) % 2 == 0, 1.0, -1.0)[..., None] * np.ones(3)
    got = {"scenes": [], "mitsuba": [], "warpbw": []}

    def mitsuba_scene(mi, probe_rgb, mat, res, spp, rotation, scale):
        got["scenes"].append(dict(res=res, spp=spp, rotation=rotation, scale=scale))
        return mat

    def render_mitsuba(mi, scene, spp, seed):
        got["mitsuba"].append((spp, seed))
        img = np.ones((R, R, 3), np.float32) + (0.05 * c if seed == 6 else 0.0)
        return img.astype(np.float32), cov.astype(np.float32), 2.0

    def render_warpbw(ps, rr, toml_text, spp, seed, mis):
        got["warpbw"].append((spp, seed, mis))
        d = 0.123085 if tomllib.loads(toml_text)["material"]["m"]["type"] == "ggx" else 0.05
        img = np.ones((R, R, 3)) + np.where(inner, d, np.where(cov, 0.5, 0.0))[..., None]
        return img.astype(np.float32), cov.copy(), 1.0

    monkeypatch.setattr(cm, "import_mitsuba", lambda variant=None: (SimpleNamespace(__version__="fake"), "fake"))
    monkeypatch.setattr(cm, "load_probe", lambda mi, path: np.ones((4, 8, 3), np.float32))
    monkeypatch.setattr(cm, "import_warpbw", lambda: ("parse_scene", "render_reference"))
    monkeypatch.setattr(cm, "mitsuba_scene", mitsuba_scene)
    monkeypatch.setattr(cm, "render_mitsuba", render_mitsuba)
    monkeypatch.setattr(cm, "render_warpbw", render_warpbw)
    probe = tmp_path / "p.exr"
    probe.write_bytes(b"x")
    got["outcome"] = outcome(cm.main, ["--probe", str(probe), "--resolution", str(R), *argv])
    return got


def test_compare_mitsuba_reports_relmse_over_the_interior_against_mitsuba(tmp_path, monkeypatch, capsys):
    """Module docstring: relMSE (test = warpbw, ref = Mitsuba: mean of (a - b)^2 / (b^2 + 1e-2)) over warpbw's
    coverage eroded by 2 pixels, PASS below 1 %; --noise-floor renders Mitsuba again with seed + 1; --mitsuba-spp is
    Mitsuba's spp, --spp warpbw's; --scale and --rotation reach Mitsuba's scene; --no-mis reaches warpbw.
    By hand: lambert 0.05^2 / 1.01 = 2.48e-3 (PASS), ggx0.1 0.123085^2 / 1.01 = 1.50e-2 (FAIL), relMSE(sum) d^2,
    PSNR -20 log10 d (peak 1), 64 pixels, coverage IoU 1, floor 0.05^2 / 1.01."""
    got = _run_compare_mitsuba(monkeypatch, tmp_path, ["--cases", "lambert,ggx0.1", "--spp", "16", "--mitsuba-spp",
                                                       "64", "--scale", "2.5", "--rotation", "30", "--seed", "5",
                                                       "--noise-floor", "--no-mis"])
    assert got["outcome"] == "returned 0", got["outcome"]
    assert got["scenes"] == [dict(res=16, spp=64, rotation=30.0, scale=2.5)] * 2
    assert got["mitsuba"] == [(1, 1005), *[(64, 5)] * 3, (64, 6)] * 2      # the warm-up, 3 timed runs, the floor
    assert got["warpbw"] == [(1, 1005, False), *[(16, 5, False)] * 3] * 2
    rows = {ln.split()[0]: ln.split() for ln in capsys.readouterr().out.splitlines()
            if ln.split() and ln.split()[0] in ("lambert", "ggx0.1")}
    for case, d, verdict in (("lambert", 0.05, "PASS"), ("ggx0.1", 0.123085, "FAIL")):
        r = rows[case]
        assert float(r[1]) == pytest.approx(d * d / 1.01, rel=5e-3), r
        assert float(r[2]) == pytest.approx(d * d, rel=5e-3), r
        assert float(r[3]) == pytest.approx(-20 * math.log10(d), abs=0.01), r
        assert (int(r[4]), float(r[5])) == (64, 1.0), r
        assert float(r[9]) == pytest.approx(0.05 ** 2 / 1.01, rel=5e-3), r
        assert r[10] == verdict, r


def test_compare_mitsuba_record_holds_the_printed_table_and_a_plot(tmp_path, monkeypatch, capsys):
    """DESIGN.md, measurement protocol: every benchmark writes a JSON record and a PNG plot.  The comparison printed
    its table only; --json now holds every figure of each row under a name with its unit (the stand-ins' by hand:
    lambert relMSE 0.05^2 / 1.01, Mitsuba 2 s, warpbw 1 s, ratio 0.5), the settings and Mitsuba's version, and its
    plot is beside it."""
    monkeypatch.chdir(tmp_path)
    got = _run_compare_mitsuba(monkeypatch, tmp_path, ["--cases", "lambert,ggx0.1", "--spp", "16", "--mitsuba-spp",
                                                       "64", "--noise-floor", "--json", "c.json"])
    assert got["outcome"] == "returned 0", got["outcome"]
    rows = {ln.split()[0]: ln.split() for ln in capsys.readouterr().out.splitlines()
            if ln.split() and ln.split()[0] in ("lambert", "ggx0.1")}
    rec = json.loads((tmp_path / "c.json").read_text())
    assert (rec["resolution"], rec["mitsuba_spp"], rec["warpbw_spp"], rec["mis"]) == (16, 64, 16, True)
    assert rec["mitsuba_version"] == "fake" and rec["acceptance_relmse"] == 0.01 and rec["device"] == "cpu"
    assert [c["case"] for c in rec["cases"]] == ["lambert", "ggx0.1"]
    for c in rec["cases"]:
        r = rows[c["case"]]
        assert r[1:] == [f"{c['relmse']:.2e}", f"{c['relmse_sum']:.2e}", f"{c['psnr_db']:.2f}", str(c["pixels"]),
                         f"{c['coverage_iou']:.4f}", f"{c['mitsuba_time_s']:.2f}", f"{c['warpbw_time_s']:.2f}",
                         f"{c['time_ratio']:.2f}", f"{c['noise_floor_relmse']:.2e}", c["result"]]
        assert (c["mitsuba_time_s"], c["warpbw_time_s"], c["time_ratio"], c["pixels"]) == (2.0, 1.0, 0.5, 64)
        assert c["mitsuba_msamples_per_s"] == pytest.approx(16 * 16 * 64 / 2.0 / 1e6)
    assert rec["cases"][0]["relmse"] == pytest.approx(0.05 ** 2 / 1.01, rel=5e-3)
    assert [c["result"] for c in rec["cases"]] == ["PASS", "FAIL"]
    plot_png(tmp_path / "c.png")


@pytest.mark.parametrize("argv, needle", [
    (["--json", "old.json"], "old.json: already exists"),
    (["--plot", "q.png"], "q.png: already exists"),
    (["--json", "new.json"], "new.png: already exists"),
    (["--json", "c.txt"], "--json c.txt: expected a path ending in .json"),
    (["--plot", "c.jpg", "--force"], "--plot c.jpg: expected a path ending in .png"),
    (["--json", "p.exr.json", "--plot", "p.exr", "--force"], "--plot p.exr: expected a path ending in .png"),
])
def test_compare_mitsuba_refuses_its_record_before_any_render(tmp_path, monkeypatch, argv, needle):
    """--json / --plot follow warpbw bench's rules, checked before Mitsuba is imported or anything rendered."""
    monkeypatch.chdir(tmp_path)
    for name in ("old.json", "q.png", "new.png"):
        (tmp_path / name).write_text("kept\n")
    got = _run_compare_mitsuba(monkeypatch, tmp_path, ["--cases", "lambert", "--spp", "8", *argv])
    assert got["outcome"].startswith("WarpbwError") and needle in got["outcome"], got["outcome"]
    assert got["mitsuba"] == got["warpbw"] == []
    assert all((tmp_path / n).read_text() == "kept\n" for n in ("old.json", "q.png", "new.png"))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["new.png", "old.json", "p.exr", "q.png"]


def test_compare_mitsuba_runs_warpbw_with_mis_by_default(tmp_path, monkeypatch):
    """Without --no-mis, warpbw renders with MIS (--help: like for like with Mitsuba's path integrator), at --spp
    for both renderers."""
    got = _run_compare_mitsuba(monkeypatch, tmp_path, ["--cases", "lambert", "--spp", "8", "--no-warmup", "--runs",
                                                       "1"])
    assert got["outcome"] == "returned 0", got["outcome"]
    assert got["warpbw"] == [(8, 0, True)] and got["mitsuba"] == [(8, 0)]


def test_compare_mitsuba_times_the_median_of_its_runs_and_warns_below_three(tmp_path, monkeypatch, capsys):
    """DESIGN.md's protocol times the median of at least 3 runs; the comparison timed one render of each renderer.
    Now --runs renders of each (the same seed), the median of their times (stand-ins on a stand-in clock: Mitsuba
    3, 1, 2 s, warpbw 6, 2, 4 s: medians 2 and 4, ratio 2.00); fewer than 3 warn as warpbw bench's --runs."""
    cm = load_example("compare_mitsuba")
    secs = {"mitsuba": iter([3.0, 1.0, 2.0]), "warpbw": iter([6.0, 2.0, 4.0])}
    got = {"mitsuba": [], "warpbw": []}
    img = np.ones((16, 16, 3), np.float32)
    cov = np.zeros((16, 16), bool)
    cov[2:14, 2:14] = True

    def render_mitsuba(mi, scene, spp, seed):
        got["mitsuba"].append((spp, seed))
        return img, cov.astype(np.float32), next(secs["mitsuba"])

    def render_warpbw(ps, rr, toml_text, spp, seed, mis):
        got["warpbw"].append((spp, seed))
        return img, cov.copy(), next(secs["warpbw"])

    monkeypatch.setattr(cm, "import_mitsuba", lambda variant=None: (SimpleNamespace(__version__="fake"), "fake"))
    monkeypatch.setattr(cm, "load_probe", lambda mi, path: np.ones((4, 8, 3), np.float32))
    monkeypatch.setattr(cm, "import_warpbw", lambda: ("parse_scene", "render_reference"))
    monkeypatch.setattr(cm, "mitsuba_scene", lambda *a: None)
    monkeypatch.setattr(cm, "render_mitsuba", render_mitsuba)
    monkeypatch.setattr(cm, "render_warpbw", render_warpbw)
    probe = tmp_path / "p.exr"
    probe.write_bytes(b"x")
    assert outcome(cm.main, ["--probe", str(probe), "--resolution", "16", "--cases", "lambert", "--spp", "8",
                             "--no-warmup"]) == "returned 0"
    assert got == {"mitsuba": [(8, 0)] * 3, "warpbw": [(8, 0)] * 3}
    out, err = capsys.readouterr()
    row = next(ln.split() for ln in out.splitlines() if ln.startswith("lambert"))
    assert row[6:9] == ["2.00", "4.00", "2.00"], row
    assert "warning" not in err
    for runs, warns in ((1, True), (2, True)):
        secs = {"mitsuba": iter([1.0] * runs), "warpbw": iter([1.0] * runs)}
        assert outcome(cm.main, ["--probe", str(probe), "--resolution", "16", "--cases", "lambert", "--spp", "8",
                                 "--no-warmup", "--runs", str(runs)]) == "returned 0"
        assert (f"compare_mitsuba.py: warning: --runs {runs}: the measurement protocol times the median of at least 3"
                in capsys.readouterr().err) == warns


def test_a_reference_frame_without_mis_draws_no_environment_samples():
    """warpbw.shading: only with mis=True does each step also draw a direction from the environment's
    distribution.  Truth: the stats of a reference frame count 0 environment samples without MIS and as many as
    the BRDF samples (covered pixels x spp) with it."""
    from test_lights import SKY, scene

    for mis in (False, True):
        res = render_reference(scene(env=SKY, w=12, h=16), spp=3, mis=mis)
        n_cov = int(res.coverage.sum())
        assert n_cov > 20 and res.stats["samples"] == 3 * n_cov
        assert res.stats["environment_samples"] == (3 * n_cov if mis else 0), mis


def test_an_adaptive_frame_without_mis_draws_no_environment_samples():
    """warpbw.shading (the adaptive frame shades with the same estimator): only with mis=True does each step also
    draw a direction from the environment's distribution.  Truth: an adaptive frame's stats count 0 environment
    samples without MIS and as many as its samples with it."""
    from test_lights import SKY, scene
    from warpbw.pipeline import render_adaptive

    for mis in (False, True):
        res = render_adaptive(scene(env=SKY, w=12, h=16), budget=2.0, mis=mis)
        assert res.stats["samples"] > 0
        assert res.stats["environment_samples"] == (res.stats["samples"] if mis else 0), mis


def test_a_pixel_of_more_than_launch_cost_max_samples_is_shaded_in_passes_as_in_one_launch(monkeypatch):
    """A pixel of more than LAUNCH_COST_MAX samples was one launch (Ctrl-C waited for all of it); now its samples are
    drawn in passes of launches, each carrying the pixel's random state and float64 sum to the next.  Truth: the same
    frame shaded in one launch per pixel (LAUNCH_COST_MAX above every count), bit for bit, with the lights' term added
    once; one count for every pixel and a per-pixel map whose pixels end in different passes (N_p = 0 the lights
    alone).  The passes are seen: launches that start past a pixel's first sample."""
    from test_lights import GGX, SKY, light, scene
    from warpbw import launch, shading
    from warpbw.shading import shade_reference

    prep = prepare_scene(scene(GGX, env=SKY, lights=(light(),), w=10, h=8))
    gb = render_reference(prep, spp=1, seed=1).gbuffer
    n = gb.width * gb.height
    counts = np.random.default_rng(5).choice([0, 1, 255, 256, 257, 700, 1300], n).astype(np.int32)
    real, starts = shading.wp.launch, []
    monkeypatch.setattr(shading.wp, "launch", lambda k, dim, inputs, device: starts.append(inputs[11])
                        or real(k, dim=dim, inputs=inputs, device=device))
    for spp in (1300, counts):
        frames = []
        for limit in (10**12, 300):   # 300: passes of 256 samples, one float32 batch
            monkeypatch.setattr(shading, "LAUNCH_COST_MAX", limit)   # the passes
            monkeypatch.setattr(launch, "LAUNCH_COST_MAX", limit)    # and the tiles, as when they were one constant
            starts.clear()
            r = shade_reference(gb, prep.materials, prep.env.data, spp, seed=9, mis=True, lights=prep.lights)
            frames.append((r.radiance.numpy(), r.samples, r.non_finite, sorted(set(starts))))
        (one, samples, bad, one_starts), (passes, samples_p, bad_p, pass_starts) = frames
        assert one_starts == [0] and pass_starts == [0, 256, 512, 768, 1024, 1280]
        assert np.array_equal(one, passes) and (samples, bad) == (samples_p, bad_p)
        assert np.all(np.isfinite(one)) and one.max() > 0


def _bright_texels_map():
    """An 8 x 16 probe: a dim noisy sky with bright texels on the +Y pole row, on the u seam (last column, whose
    bilinear footprint wraps to column 0), in column 0 and near the -Y pole."""
    rng = np.random.default_rng(7)
    rgb = (0.05 + 0.05 * rng.random((8, 16, 3))).astype(np.float32)
    for (j, i), v in {(0, 15): (30.0, 20.0, 10.0), (4, 15): (40.0, 30.0, 20.0), (2, 0): (5.0, 25.0, 15.0),
                      (7, 6): (20.0, 20.0, 40.0)}.items():
        rgb[j, i] = v
    return rgb


def _hemisphere_quadrature(n=300):
    """Midpoint (theta, phi) directions over the upper local hemisphere and their solid angles (float64)."""
    th = (np.arange(n) + 0.5) / n * (np.pi / 2)
    ph = (np.arange(2 * n) + 0.5) / (2 * n) * 2 * np.pi
    T, P = np.meshgrid(th, ph, indexing="ij")
    wl = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(-1, 3)
    return wl, ((np.pi / 2 / n) * (2 * np.pi / (2 * n)) * np.sin(T)).reshape(-1)


@pytest.mark.parametrize("mat", ["lambert", "ggx"])
def test_reference_estimators_mean_is_the_quadrature_of_L_f_cos_under_a_turned_probe_of_bright_texels(mat):
    """002 Eq. 1 per pixel by midpoint quadrature over the pixel's hemisphere (its frame rebuilt here from the
    G-buffer, f written out here: albedo / pi, or GGX with a constant F), the radiance read by the map's bilinear
    look-up (checked against Mitsuba in test_envmap), against the estimator with BRDF sampling alone and with MIS,
    under a probe turned by -123 degrees whose bright texels sit on the pole row, on the u seam and in column 0:
    the sampling pdfs, the MIS weights, the turn of env_sample and env_pdf and their cells at the pole and the seam
    must all agree for the mean to.  A planted MIS weight that leaves the environment's pdf out of the BRDF sample's
    sum, env_sample turning the wrong way, or env_pdf's row cell read half a row off fails it (session 73)."""
    from warpbw.envmap import envmap_from_array, eval_radiance

    spec = {"lambert": 'type = "lambert"\nalbedo = [0.8, 0.5, 0.2]',
            "ggx": 'type = "ggx"\nalpha = 0.3\nspecular = [0.9, 0.7, 0.5]'}[mat]
    prep = prepare_scene(sphere_scene(spec, w=8, h=8))
    prep.env = envmap_from_array(_bright_texels_map(), rotation_deg=-123.0)
    gb_res = {m: render_reference(prep, spp=16384, seed=11, mis=m) for m in (False, True)}
    gb = gb_res[False].gbuffer
    sel = facing(gb_res[False], 0.3)
    assert sel.sum() >= 20
    n, t, v = (gb.numpy(k)[sel].astype(np.float64) for k in ("normal", "tangent", "view"))
    wl, d_omega = _hemisphere_quadrature()
    truth = []
    for k in range(len(n)):
        b = np.cross(n[k], t[k])
        wo = np.array([v[k] @ t[k], v[k] @ b, v[k] @ n[k]])
        world = wl[:, :1] * t[k] + wl[:, 1:2] * b + wl[:, 2:3] * n[k]
        L = eval_radiance(prep.env, world.astype(np.float32)).astype(np.float64)
        if mat == "lambert":
            f = np.broadcast_to(np.array([0.8, 0.5, 0.2]) / np.pi, L.shape)
        else:
            h = wl + wo
            h /= np.linalg.norm(h, axis=1, keepdims=True)
            a2 = 0.09
            d = a2 / (np.pi * (h[:, 2] ** 2 * (a2 - 1.0) + 1.0) ** 2)
            g1 = lambda c: 2.0 * c / (c + np.sqrt(a2 + (1.0 - a2) * c * c))  # noqa: E731
            f = (d * g1(wl[:, 2]) * g1(wo[2]) / (4.0 * wl[:, 2] * wo[2]))[:, None] * np.array([0.9, 0.7, 0.5])
        truth.append((L * f * (wl[:, 2] * d_omega)[:, None]).sum(axis=0))
    truth = np.array(truth)
    for m, res in gb_res.items():
        ratio = res.image[sel].astype(np.float64) / truth
        # seeds 1-6 at 16384 spp (both materials): per-pixel ratios within 0.13 (BRDF sampling) and 0.06 (MIS) of 1,
        # their mean over the pixels within 0.013 and 0.0046
        assert np.abs(ratio - 1.0).max() < (0.25 if not m else 0.12), (m, ratio)
        assert np.abs(ratio.mean(axis=0) - 1.0).max() < (0.03 if not m else 0.012), (m, ratio.mean(axis=0))


def test_shade_reference_under_an_environment_renders_a_frame_that_shows_no_unsampled_material():
    """A table holding a MERL material packed without its sampling table (for directional lights alone) beside the
    Lambert the frame shows: a frame under the environment reads no sampler of the MERL, and renders (with and
    without MIS), the Lambert sphere at its albedo under a constant sky of 1; a frame showing the MERL is refused.
    Truth: the white furnace (albedo 0.5 at every covered pixel, BRDF sampling alone; on average, MIS)."""
    from warpbw.brdf import LAMBERT, MERL, MERL_CELLS, MaterialSpec, build_material_table
    from warpbw.envmap import constant_envmap
    from warpbw.gbuffer import SphereSpec, build_geometry, make_camera, render_gbuffer
    from warpbw.shading import shade_reference

    cam = make_camera((0.0, 0.0, 4.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 35.0, 12, 12)
    specs = [MaterialSpec("plain", LAMBERT, albedo=(0.5, 0.5, 0.5)),
             MaterialSpec("measured", MERL, merl=np.full((MERL_CELLS, 3), 0.1, np.float32))]
    table = build_material_table(specs, sampling=False)
    env = constant_envmap(1.0)
    gb = render_gbuffer(cam, build_geometry([SphereSpec((0, 0, 0), 1.0, 0)], []))
    for mis in (False, True):
        img = shade_reference(gb, table, env.data, 4, mis=mis).radiance.numpy()[gb.coverage.reshape(-1)]
        assert img.size and (abs(img.mean() - 0.5) < 0.02 if mis else np.allclose(img, 0.5, atol=1e-4))
    shown = render_gbuffer(cam, build_geometry([SphereSpec((0, 0, 0), 1.0, 1)], []))
    with pytest.raises(WarpbwError, match=r"^shade_reference: materials: material 1 \('measured'\) was packed"):
        shade_reference(shown, table, env.data, 4)


def test_the_dropped_sample_count_goes_past_int32():
    """The frame's count of dropped samples (non-finite contributions) was an int32 atomic: 4096 spp with MIS at
    2048^2 draws 3.4e10 samples, and a frame of overflowing radiance drops most of them, so the count wrapped
    (negative in the message, or 0: the overflow check then passed the frame without a word).  The kernel is run
    here with its counter already at 2^31 - 1 - D/2 over a small frame that drops D samples, which must come out as
    the exact sum.  Truth: D from shade_reference on the same frame (counted from 0), plain integer addition."""
    from warpbw.shading import make_reference_kernel, shade_reference

    # a near-mirror (F = 1) in a white furnace of 1e32: radiance times the lobe passes float32 in many samples
    prep = prepare_scene(sphere_scene('type = "ggx"\nalpha = 1e-4\nspecular = [1.0, 1.0, 1.0]',
                                      env="constant = [1e32, 1e32, 1e32]", w=8, h=8))
    from warpbw.gbuffer import render_gbuffer
    from warpbw.shading import covered_pixels, lighting_inputs

    gb = render_gbuffer(prep.camera, prep.geometry)
    spp, seed = 16, 5
    # BRDF sampling alone: the kernel test_bad_input's furnace compiles too (a fresh clone compiles each kernel once)
    d = shade_reference(gb, prep.materials, prep.env_data, spp, seed=seed, mis=False).non_finite
    assert 0 < d <= spp * int(gb.coverage.sum())
    start = 2**31 - 1 - d // 2
    counter = wp.array([start], dtype=wp.int64)   # an int32 array is refused by the kernel's signature
    env_data, lights_data = lighting_inputs(prep.env_data, None)
    pix = covered_pixels(gb)
    n = int(pix.shape[0])
    kernel = make_reference_kernel(prep.materials.kinds, False)
    wp.launch(kernel, dim=n, inputs=[gb.data, prep.materials.table, env_data, lights_data, pix, 0, spp,
                                     wp.zeros(0, dtype=wp.int32), seed, wp.zeros(gb.width * gb.height, dtype=wp.vec3),
                                     counter, 0, 2**31 - 1, wp.zeros(0, dtype=wp.uint32), wp.zeros(0, dtype=wp.vec3d)])
    assert int(counter.numpy()[0]) == start + d > 2**31 - 1
