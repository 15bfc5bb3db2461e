"""The command lines end to end, in a temporary directory: ``warpbw demo``, ``render``, ``info``, ``compare``
and ``warpbw-precompute npf-to-merl`` / ``brdf-sampling``, run as subprocesses (``python -m ...``) the way a
user runs them.  The sampling-table cache is a temporary directory (``WARPBW_CACHE``), never ~/.cache.

Checks are against file bytes and independent computations: the EXR's A channel against the JSON's covered
pixel count, a re-render with the same seed against the first one bit for bit, a MERL tabulation of an NPF fit
against the fit itself (means over the sphere), a precomputed sampling file against the renderer's own build
(identical images), and ``compare``'s PSNR against its closed form for a scaled image.  Every script in ``examples/``
answers ``--help`` without running anything.  ``info``'s text and stages against the scene and the stages a frame
records, and ``compare``'s figures over the covered pixels against hand values.
"""
from __future__ import annotations

import json
import math
import os
import re
import stat
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

if sys.version_info >= (3, 11):
    import tomllib
else:   # Python 3.10: the backport pyproject installs there, as warpbw.scene reads it
    import tomli as tomllib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from conftest import (MIXED_SCENE, Handed, StandInClock, capture_call, check_colour_scale, lambert_sphere_scene,
                      numpy_camera_rays, numpy_sphere_distance, numpy_square_distance, outcome, plane_scene_toml)
from warpbw.io.exr import read_exr, write_exr
from warpbw.io.merl import MERL_FILE_SIZE

NPF_MATERIAL = "gold-metallic-paint"


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    d = tmp_path_factory.mktemp("e2e")
    (d / "cache").mkdir()
    return d


def run(args, cwd: Path, module: str = "warpbw.cli", check: bool = True, timeout: float = 300.0):
    env = dict(os.environ)
    env["WARPBW_CACHE"] = str(cwd / "cache")
    env.pop("PYTHONUNBUFFERED", None)   # stdout a block-buffered pipe, as a user's shell gives it
    r = subprocess.run([sys.executable, "-m", module, *map(str, args)], cwd=cwd, env=env, stdin=subprocess.DEVNULL,
                       capture_output=True, text=True, timeout=timeout)
    assert "Traceback" not in r.stderr, r.stderr
    if check:
        assert r.returncode == 0, f"{args}: status {r.returncode}\n{r.stdout}\n{r.stderr}"
        # -q: no progress bar; no Warp banner; warnings (the probes' clamped negative pixels) in one line each
        prog = "warpbw-precompute" if module == "precompute" else "warpbw"
        assert all(ln.startswith(f"{prog}: warning: ") for ln in r.stderr.splitlines()), r.stderr
    return r


def rgba(path: Path) -> tuple[np.ndarray, np.ndarray]:
    img = read_exr(path)
    assert img.channels == ["R", "G", "B", "A"]
    return img.pixels[..., :3], img.pixels[..., 3]


SCENE = """\
[camera]
position = [0.0, 0.0, 4.0]
look_at = [0.0, 0.0, 0.0]
fov = 36.0
resolution = [32, 32]

[environment]
file = "{probe}"
rotation = 90.0

[[object]]
shape = "sphere"
center = [0.0, 0.0, 0.0]
radius = 1.0
material = "m"

[material.m]
{material}
lookup = "linear"
{extra}
[material.unused]
type = "lambert"
albedo = [0.2, 0.2, 0.2]
"""


def write_scene(d: Path, name: str, probe: Path, material: str, extra: str = "") -> Path:
    p = d / name
    p.write_text(SCENE.format(probe=probe, material=material, extra=extra))
    return p


# ------------------------------------------------------------------------------------------ demo

def test_a_render_says_which_outputs_of_an_earlier_render_at_its_o_it_leaves(tmp_path):
    """An adaptive render, then a reference one at the same -o with --force: the reference image, preview and stats
    replaced the adaptive ones, and the adaptive run's twelve AOVs (level, N_p, spp... maps) stayed beside them
    without a word, as if they described the new image (processes audit, session 79).  The render now warns, before
    its work, naming them; it leaves them as they are (they are not its outputs to remove)."""
    (tmp_path / "scene.toml").write_text(lambert_sphere_scene(8, 8))
    run(["render", "scene.toml", "-o", "a.exr", "--method", "adaptive", "--budget", "1", "-q"], tmp_path)
    aovs = sorted(p.name for p in tmp_path.glob("a.*.*"))
    assert len(aovs) == 12
    before = {n: (tmp_path / n).read_bytes() for n in aovs}
    r = run(["render", "scene.toml", "-o", "a.exr", "--spp", "1", "-q", "--force"], tmp_path)
    assert r.stderr.splitlines() == [
        "warpbw: warning: a.level.exr and 11 more: outputs of an earlier render at -o a.exr that this render does "
        "not write: they stay beside the new image and do not describe it (remove them, or render to another -o)"]
    assert {n: (tmp_path / n).read_bytes() for n in aovs} == before
    assert json.loads((tmp_path / "a.json").read_text())["spp"] == 1
    r = run(["render", "scene.toml", "-o", "a.exr", "--spp", "1", "-q", "--force"], tmp_path)   # said each time
    assert len(r.stderr.splitlines()) == 1
    for n in aovs:
        (tmp_path / n).unlink()
    assert run(["render", "scene.toml", "-o", "a.exr", "--spp", "1", "-q", "--force"], tmp_path).stderr == ""


def test_demo_writes_exr_png_json_and_respects_force(tmp_path):

    out = tmp_path / "demo_out"
    r = run(["demo", "-o", out, "--spp", "4", "-q"], tmp_path)
    assert r.stdout == ""  # -q
    exr, png, js = out / "demo.exr", out / "demo.png", out / "demo.json"
    for p in (exr, png, js):
        assert p.is_file() and p.stat().st_size > 0

    rgb, alpha = rgba(exr)
    assert rgb.shape == (256, 384, 3)
    assert set(np.unique(alpha)) <= {0.0, 1.0}
    covered = alpha > 0
    assert np.isfinite(rgb).all() and (rgb >= 0).all()
    assert (rgb[~covered] == 0).all() and (rgb[covered].sum(-1) > 0).mean() > 0.99

    stats = json.loads(js.read_text())
    for key in ("time_s", "samples", "stages"):
        assert key in stats
    assert stats["pixels_covered"] == int(covered.sum())
    assert stats["samples"] == 4 * stats["pixels_covered"]
    assert stats["environment_samples"] == stats["samples"]  # the demo uses MIS
    assert stats["resolution"] == [384, 256] and stats["spp"] == 4 and stats["mis"] is True
    assert stats["stages"] == ["gbuffer:spheres", "brdf:ggx+lambert", "light:environment",
                              "reference_shading+mis"]
    assert {"gbuffer", "shading", "frame", "total"} <= set(stats["time_s"])
    t = stats["time_s"]   # the frame as the adaptive method times its own: the G-buffer and the shading
    assert t["frame"] == pytest.approx(t["gbuffer"] + t["shading"], abs=2e-6) and t["total"] >= t["frame"]
    assert stats["non_finite_samples"] == 0
    with Image.open(png) as im:
        assert im.size == (384, 256) and im.mode == "RGB"
        px = np.asarray(im)
    assert (px[~covered] == 0).all() and px[covered].max() > 50

    # the scene itself, beside the image: rendered with warpbw render as the demo renders it (MIS, the same seed),
    # it gives the demo's image bit for bit
    scene_file = out / "scene.toml"
    run(["render", scene_file, "-o", tmp_path / "again.exr", "--spp", "4", "--mis", "-q"], tmp_path)
    again, again_alpha = rgba(tmp_path / "again.exr")
    np.testing.assert_array_equal(again, rgb)
    np.testing.assert_array_equal(again_alpha, alpha)

    # again without --force: refused, nothing touched
    before = {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in (exr, png, js, scene_file)}
    scene_file.write_text(scene_file.read_text() + "# my edit\n")   # an edited scene is the user's
    before[scene_file] = (scene_file.read_bytes(), scene_file.stat().st_mtime_ns)
    r = run(["demo", "-o", out, "--spp", "4", "-q"], tmp_path, check=False)
    assert r.returncode == 2
    assert r.stderr.startswith("warpbw: error: ") and "--force" in r.stderr and len(r.stderr.splitlines()) == 1
    assert {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in (exr, png, js, scene_file)} == before

    # with --force: rewritten; the same seed gives the same image bit for bit
    run(["demo", "-o", out, "--spp", "4", "-q", "--force"], tmp_path)
    assert js.stat().st_mtime_ns != before[js][1] or js.read_bytes() != before[js][0]
    rgb2, alpha2 = rgba(exr)
    np.testing.assert_array_equal(rgb2, rgb)
    np.testing.assert_array_equal(alpha2, alpha)

    # another seed: a different image of the same scene
    run(["demo", "-o", tmp_path / "seed7", "--spp", "4", "-q", "--seed", "7"], tmp_path)
    rgb3, alpha3 = rgba(tmp_path / "seed7" / "demo.exr")
    np.testing.assert_array_equal(alpha3, alpha)
    assert not np.array_equal(rgb3, rgb)

    # compare: an image against itself, against another seed, against a scaled copy (closed form)
    r = run(["compare", exr, exr], tmp_path)
    assert "PSNR   inf" in r.stdout and "relMSE 0\n" in r.stdout
    assert f"pixels {int(covered.sum())} covered" in r.stdout
    # strict JSON (no bare Infinity, which JSON parsers outside Python refuse): an infinite PSNR is null
    j = json.loads(run(["compare", exr, exr, "--json"], tmp_path).stdout,
                   parse_constant=lambda c: pytest.fail(f"{c} in strict JSON"))
    assert j["psnr_db"] is None and j["relmse"] == 0.0 and j["mse"] == 0.0

    j = json.loads(run(["compare", tmp_path / "seed7" / "demo.exr", exr, "--json"], tmp_path).stdout)
    assert math.isfinite(j["psnr_db"]) and 5.0 < j["psnr_db"] < 80.0 and j["relmse"] > 0.0

    scaled = tmp_path / "scaled.exr"
    img = read_exr(exr)
    px = img.pixels.copy()
    px[..., :3] *= 1.1
    write_exr(scaled, px, channels=img.channels)
    j = json.loads(run(["compare", scaled, exr, "--json"], tmp_path).stdout)
    ref = rgb[covered].astype(np.float64)
    mse = np.mean((0.1 * ref) ** 2)  # float32 rounding of the scaled copy is far below the tolerance
    assert j["psnr_db"] == pytest.approx(10.0 * math.log10(ref.max() ** 2 / mse), abs=1e-3)
    assert j["relmse"] == pytest.approx(np.mean((0.1 * ref) ** 2 / (ref ** 2 + 1e-2)), rel=1e-4)
    assert j["pixels"] == int(covered.sum())


def test_compare_warns_when_both_renders_share_their_seed(tmp_path):
    """At one seed an image at 4 spp is the first 4 samples of one at 16 (the same stream per pixel): compared with
    it, its error reads low.  Independent truth: the 4-spp image's squared error against a 16-spp render at its own
    seed holds its own noise (mean square of the difference) less the shared part, so it is below the error against
    a 16-spp render at another seed.  compare warns when the .json records show the same seed and scene, and not
    otherwise."""
    (tmp_path / "s.toml").write_text(SCENE.replace('file = "{probe}"\nrotation = 90.0', 'procedural = "sky"')
                                     .format(material='type = "ggx"\nalpha = 0.3\nspecular = [0.9, 0.9, 0.9]',
                                             extra="").replace('lookup = "linear"\n', ""))
    for name, spp, seed in (("a", 4, 0), ("t0", 16, 0), ("t1", 16, 1)):
        run(["render", "s.toml", "-o", f"{name}.exr", "--spp", spp, "--seed", seed, "-q"], tmp_path)
    same = run(["compare", "a.exr", "t0.exr", "--json"], tmp_path)
    other = run(["compare", "a.exr", "t1.exr", "--json"], tmp_path)
    assert json.loads(same.stdout)["mse"] < json.loads(other.stdout)["mse"]
    assert "same --seed 0" in same.stderr and "another --seed" in same.stderr
    assert other.stderr == ""
    for ext in (".exr", ".json"):   # a name holding a newline stays on the warning's one line, escaped
        (tmp_path / f"a\nb{ext}").write_bytes((tmp_path / f"a{ext}").read_bytes())
    odd = run(["compare", "a\nb.exr", "t0.exr", "--json"], tmp_path).stderr
    assert odd.count("\n") == 1 and "a\\nb.exr and t0.exr were rendered" in odd, odd
    (tmp_path / "t0.json").unlink()   # no record beside the reference: nothing to tell
    assert run(["compare", "a.exr", "t0.exr"], tmp_path).stderr == ""
    (tmp_path / "t0.json").write_text("[" * 100_000 + "]" * 100_000)   # nested past json's parser: no record either
    assert run(["compare", "a.exr", "t0.exr"], tmp_path).stderr == ""   # (a RecursionError traceback, session 63)


def test_compare_error_map_and_worst_share_follow_hand_made_images(tmp_path):
    """``compare --error-map``: per pixel (t - r)^2 / (r^2 + 0.01), averaged over R, G, B, 0 where not covered; its
    mean over the covered pixels is the relMSE; the worst 1% of the covered pixels' share of it.  Images made here:
    a reference of 0.5 with its last column uncovered (A = 0), and a test off by 0.1, 0.2, 0.3 at three pixels."""

    h, w = 10, 20
    ref = np.full((h, w, 4), 0.5, np.float32)
    ref[:, -1, 3] = 0.0                                   # 190 covered pixels: the worst 1% are 2
    test = ref.copy()
    bad = {(1, 2): 0.1, (4, 7): 0.2, (8, 15): 0.3}
    for (y, x), d in bad.items():
        test[y, x, :3] += d
    test[3, -1, :3] = 9.0                                 # not covered: in neither figure
    write_exr(tmp_path / "ref.exr", ref, channels=["R", "G", "B", "A"])
    write_exr(tmp_path / "test.exr", test, channels=["R", "G", "B", "A"])
    j = json.loads(run(["compare", "test.exr", "ref.exr", "--json", "--error-map", "err.exr"], tmp_path).stdout)
    e = {k: d * d / (0.25 + 0.01) for k, d in bad.items()}
    assert j["pixels"] == 190 and j["worst_pixels"] == 2 and j["error_map"] == "err.exr"
    assert j["error_range"] == pytest.approx([bad[(1, 2)] ** 2 / 0.26, bad[(8, 15)] ** 2 / 0.26], rel=1e-5)
    assert j["relmse"] == pytest.approx(sum(e.values()) / 190, rel=1e-5)
    assert j["worst_share"] == pytest.approx((e[(4, 7)] + e[(8, 15)]) / sum(e.values()), rel=1e-5)
    img = read_exr(tmp_path / "err.exr")
    assert img.channels == ["Y", "A"]
    want = np.zeros((h, w))
    for k, v in e.items():
        want[k] = v
    np.testing.assert_allclose(img.pixels[..., 0], want, rtol=1e-5, atol=1e-9)
    np.testing.assert_array_equal(img.pixels[..., 1], (ref[..., 3] > 0).astype(np.float32))
    with Image.open(tmp_path / "err.png") as im:
        px = np.asarray(im.convert("RGB")).astype(int)
    lit = px.sum(-1) > 0
    assert {tuple(int(i) for i in k) for k in np.argwhere(lit)} == set(bad)   # black: no error, or not covered
    # the default log colour scale runs from the smallest error to the largest (within 10^6 of it): viridis' ends
    viridis_lo, viridis_hi = [68, 1, 84], [253, 231, 37]
    assert px[1, 2].tolist() == viridis_lo and px[8, 15].tolist() == viridis_hi
    r = run(["compare", "test.exr", "ref.exr", "--error-map", "err.exr", "--force"], tmp_path)
    lo, hi = e[(1, 2)], e[(8, 15)]
    assert f"log colour scale {lo:.3g} to {hi:.3g}: --error-range {lo:.3g},{hi:.3g}" in r.stdout
    # on a scale set by hand, a pixel at its top or above is at viridis' top, one at its bottom at the bottom
    run(["compare", "test.exr", "ref.exr", "--error-map", "err.exr", "--force", "--error-range", f"{e[(4, 7)]!r},1"],
        tmp_path)
    with Image.open(tmp_path / "err.png") as im:
        px2 = np.asarray(im.convert("RGB")).astype(int)
    assert px2[1, 2].tolist() == viridis_lo and px2[4, 7].tolist() == viridis_lo
    assert px2[8, 15].tolist() not in (viridis_lo, viridis_hi) and (px2.sum(-1) > 0).sum() == 3

    # every covered pixel 10% off: the error is spread evenly, and the worst 2 hold 2 of the 190 pixels' share
    test[..., :3] = ref[..., :3] * 1.1
    write_exr(tmp_path / "even.exr", test, channels=["R", "G", "B", "A"])
    j = json.loads(run(["compare", "even.exr", "ref.exr", "--json"], tmp_path).stdout)
    assert j["worst_share"] == pytest.approx(2 / 190, rel=1e-5)
    r = run(["compare", "even.exr", "ref.exr"], tmp_path)
    assert "pixels 190 covered; the worst 1% of them (2) hold 1.1% of the relMSE" in r.stdout
    assert "error map" not in r.stdout
    # no scale to print when the map holds one value (it was "log colour scale 1 to 1: --error-range 1,1 draws
    # another map on it", an option it then refused): an image against itself, and one off evenly
    r = run(["compare", "ref.exr", "ref.exr", "--error-map", "same.exr"], tmp_path)
    assert "error map same.exr (+ same.png; no covered pixel has any error)" in r.stdout, r.stdout
    r = run(["compare", "even.exr", "ref.exr", "--error-map", "even_err.exr"], tmp_path)
    one = float(np.mean((0.05 ** 2) / (0.25 + 0.01)))
    assert f"(+ even_err.png; every error is {one:.3g})" in r.stdout and "--error-range" not in r.stdout, r.stdout


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(0.0, 1e6), min_size=1, max_size=400), st.floats(1e-3, 1.0))
def test_worst_share_lies_between_its_pixel_share_and_one(values, fraction):
    """The k = ceil(fraction n) largest of n non-negative errors hold at least k / n of their sum, and at most all of
    it; both bounds are reached (every value equal; one value alone).  And --help quotes metrics' constants."""
    from warpbw import cli, metrics

    v = np.asarray(values)
    share, k = metrics.worst_share(v, None, fraction)
    assert k == max(1, math.ceil(fraction * v.size))
    if v.sum() > 0:
        assert k / v.size - 1e-9 <= share <= 1.0 + 1e-9
        assert share == pytest.approx(np.sort(v)[::-1][:k].sum() / v.sum(), rel=1e-9)
    else:
        assert share == 0.0
    assert cli._RELMSE_EPS == metrics.RELMSE_EPS and cli._WORST_FRACTION == metrics.WORST_FRACTION


# ------------------------------------------------------------------------------------------ NPF, MERL, sampling

@pytest.fixture(scope="module")
def npf_scene(work, shared):
    table = shared("brdf/npf.bin")
    probe = shared("envmaps/studio.exr")
    return write_scene(work, "npf.toml", probe, f'type = "npf"\ntable = "{table}"\nname = "{NPF_MATERIAL}"')


@pytest.fixture(scope="module")
def npf_render(work, npf_scene):
    run(["render", npf_scene, "-o", work / "npf.exr", "--spp", "8", "--seed", "3", "--mis", "-q"], work)
    return work / "npf.exr"


def test_render_npf_scene(work, npf_render):
    rgb, alpha = rgba(npf_render)
    assert rgb.shape == (32, 32, 3)
    covered = alpha > 0
    # a sphere of radius 1 seen from 4 at fov 36: its disc covers pi (tan(asin(1/4)) / tan(18 deg))^2 / 4 of
    # the image (about 0.40)
    frac = math.pi * (math.tan(math.asin(0.25)) / math.tan(math.radians(18.0))) ** 2 / 4.0
    assert abs(covered.mean() - frac) < 0.03
    assert np.isfinite(rgb).all() and rgb[covered].min() > 0.0
    stats = json.loads(npf_render.with_suffix(".json").read_text())
    assert stats["stages"] == ["gbuffer:spheres", "brdf:npf", "tabulated_sampling", "light:environment",
                              "reference_shading+mis"]
    assert stats["samples"] == 8 * int(covered.sum())
    assert stats["assets"]["material.m"] == {"type": "npf", "name": NPF_MATERIAL, "sampling": "built"}
    assert "material.unused" not in stats["assets"]  # an unused material is not loaded
    cached = list((work / "cache").glob("sampling-*.npz"))
    assert len(cached) == 1 and NPF_MATERIAL in cached[0].name


def test_render_again_uses_the_sampling_cache(work, npf_scene, npf_render):
    run(["render", npf_scene, "-o", work / "npf2.exr", "--spp", "8", "--seed", "3", "--mis", "-q"], work)
    stats = json.loads((work / "npf2.json").read_text())
    assert stats["assets"]["material.m"]["sampling"] == "cache"
    np.testing.assert_array_equal(rgba(work / "npf2.exr")[0], rgba(npf_render)[0])


def test_info(work, npf_scene):
    r = run(["info", npf_scene], work)
    assert "materials   m (npf)" in r.stdout
    assert "unused      unused (not loaded)" in r.stdout
    assert "tabulated importance sampling" in r.stdout and "resolution  32 x 32" in r.stdout
    j = json.loads(run(["info", npf_scene, "--json"], work).stdout)
    assert j["materials"] == {"m": "npf"} and j["unused_materials"] == ["unused"]
    assert [Path(f).name for f in j["files"]] == ["studio.exr", "npf.bin"]
    assert j["resolution"] == [32, 32]


@pytest.fixture(scope="module")
def merl_file(work, shared):
    table = shared("brdf/npf.bin")
    r = run(["npf-to-merl", "--table", table, "--material", NPF_MATERIAL, "-o", work / "gmp.binary"], work,
            module="precompute")
    assert "gmp.binary" in r.stdout
    return work / "gmp.binary"


def test_npf_to_merl_writes_a_merl_file(work, merl_file):
    assert merl_file.stat().st_size == MERL_FILE_SIZE
    head = np.fromfile(merl_file, dtype="<i4", count=3)
    assert head.tolist() == [90, 90, 180]
    # the file gets the ordinary mode of a new file (not mkstemp's 0600)
    probe = work / "mode_probe"
    probe.write_bytes(b"")
    assert stat.S_IMODE(merl_file.stat().st_mode) == stat.S_IMODE(probe.stat().st_mode)
    # refuses to overwrite
    r = run(["npf-to-merl", "--table", "x.bin", "--material", "chrome", "-o", merl_file], work, module="precompute",
            check=False)
    assert r.returncode == 2 and "already exists" in r.stderr


def test_merl_from_npf_renders_like_the_npf_fit(work, shared, npf_scene, merl_file):
    probe = shared("envmaps/studio.exr")
    merl_scene = write_scene(work, "merl.toml", probe, 'type = "merl"\nfile = "gmp.binary"')
    spp = ["--spp", "48", "--seed", "11", "--mis", "-q"]
    run(["render", merl_scene, "-o", work / "merl.exr", *spp], work)
    run(["render", npf_scene, "-o", work / "npf48.exr", *spp], work)
    m_rgb, m_a = rgba(work / "merl.exr")
    n_rgb, n_a = rgba(work / "npf48.exr")
    np.testing.assert_array_equal(m_a, n_a)
    cov = m_a > 0
    # different BRDF representations and sampling tables: the images differ pixel by pixel, but the means
    # over the sphere agree (the MERL table is the fit sampled at its bin centres)
    assert not np.array_equal(m_rgb, n_rgb)
    ratio = m_rgb[cov].mean(0) / n_rgb[cov].mean(0)
    assert np.all(np.abs(ratio - 1.0) < 0.03), ratio
    stats = json.loads((work / "merl.json").read_text())
    assert stats["stages"][1] == "brdf:merl"
    assert stats["assets"]["material.m"]["unmeasured"] == 0


def test_precomputed_sampling_file_is_used_and_equals_the_built_one(work, shared, npf_render):
    table = shared("brdf/npf.bin")
    probe = shared("envmaps/studio.exr")
    r = run(["brdf-sampling", table, "--material", NPF_MATERIAL, "-o", work / "gmp_sampling.npz", "-q"], work,
            module="precompute")
    assert "gmp_sampling.npz" in r.stdout
    scene = write_scene(work, "npf_sampling.toml", probe,
                        f'type = "npf"\ntable = "{table}"\nname = "{NPF_MATERIAL}"', 'sampling = "gmp_sampling.npz"\n')
    run(["render", scene, "-o", work / "npf_sampling.exr", "--spp", "8", "--seed", "3", "--mis", "-q"], work)
    stats = json.loads((work / "npf_sampling.json").read_text())
    assert stats["assets"]["material.m"]["sampling"] == "file"
    assert stats["assets"]["material.m"]["sampling_file"] == str(work / "gmp_sampling.npz")   # which file it was
    assert str(work / "gmp_sampling.npz") in run(["info", scene], work).stdout
    # the same tables as the renderer builds itself: the same image, bit for bit
    np.testing.assert_array_equal(rgba(work / "npf_sampling.exr")[0], rgba(npf_render)[0])

    # tables of another material are refused, with the command that rebuilds them
    r = run(["brdf-sampling", table, "--material", "chrome", "-o", work / "chrome_sampling.npz", "-q"], work,
            module="precompute")
    wrong = write_scene(work, "wrong.toml", probe, f'type = "npf"\ntable = "{table}"\nname = "{NPF_MATERIAL}"',
                        'sampling = "chrome_sampling.npz"\n')
    r = run(["render", wrong, "-o", work / "wrong.exr", "--spp", "1", "-q"], work, check=False)
    assert r.returncode == 2
    lines = [ln for ln in r.stderr.splitlines() if not ln.startswith("warpbw: warning: ")]  # studio.exr's clamp
    assert len(lines) == 1 and lines[0].startswith("warpbw: error: "), r.stderr
    assert "chrome_sampling.npz" in lines[0] and "different content" in lines[0]
    assert "warpbw-precompute brdf-sampling" in lines[0]
    assert not (work / "wrong.exr").exists()


def test_stats_time_keys_add_up_to_the_total(tmp_path):
    """DESIGN's stats JSON, "time per stage": the time_s keys other than frame (the sum of the frame's own stages)
    add up to total, for each method and for a scene with planes, where the loading, compiling and stages once left
    a third of a small reference frame's total unrecorded.  Truth: the sum by hand and the frame's own identity."""
    (tmp_path / "s.toml").write_text(lambert_sphere_scene(16, 16))
    (tmp_path / "m.toml").write_text(MIXED_SCENE.replace("[48, 32]", "[16, 12]"))
    for name, scene, extra in (("ref", "s.toml", ["--spp", "2"]), ("ada", "s.toml", ["--method", "adaptive",
                               "--budget", "2"]), ("mix", "m.toml", ["--spp", "2"])):
        run(["render", scene, "-o", f"{name}.exr", "-q", *extra], tmp_path)
        t = json.loads((tmp_path / f"{name}.json").read_text())["time_s"]
        parts = {k: v for k, v in t.items() if k not in ("frame", "total")}
        assert t["unstaged"] >= 0 and t["total"] >= t["frame"] > 0, (name, t)
        assert sum(parts.values()) == pytest.approx(t["total"], abs=1e-6 * len(parts)), (name, t)


# ------------------------------------------------------------------------------------------ adaptive (issue 3)

def test_render_adaptive_writes_aovs_and_caches_tables(work, npf_scene):
    out = work / "ada.exr"
    run(["render", npf_scene, "-o", out, "--method", "adaptive", "--budget", "4", "--mis", "-q"], work)
    rgb, alpha = rgba(out)
    covered = alpha > 0
    assert np.isfinite(rgb).all()
    shaded_mask = read_exr(out.with_suffix(".shaded.exr")).pixels[..., 0] > 0
    # no hole in the hierarchy: every up-sampled pixel has a value; a shaded pixel given N_p = 1 (low
    # measured variance) may draw a zero estimate (both MIS samples miss), but rarely
    assert rgb[covered & ~shaded_mask].max(-1).min() > 0.0
    assert (rgb[covered].max(-1) > 0).mean() > 0.98
    for name in ("level", "n_p", "spp", "variance", "shaded", "b_p"):
        aov = read_exr(out.with_suffix(f".{name}.exr"))
        assert aov.pixels.shape == (32, 32, 2) and np.isfinite(aov.pixels).all()
        # A is the image's coverage: the level map's background held the coarsest level, unmarked (session 76)
        assert aov.channels == ["Y", "A"] and np.array_equal(aov.pixels[..., 1], alpha), name
        assert out.with_suffix(f".{name}.png").stat().st_size > 0
    n_p = read_exr(out.with_suffix(".n_p.exr")).pixels[..., 0]
    shaded = read_exr(out.with_suffix(".shaded.exr")).pixels[..., 0] > 0
    assert np.all(n_p[covered] >= 1) and np.all(n_p[~covered] == 0) and shaded[covered].any()
    stats = json.loads(out.with_suffix(".json").read_text())
    assert stats["method"] == "adaptive" and "bandwidth_pass" in stats["stages"]
    spp = read_exr(out.with_suffix(".spp.exr")).pixels[..., 0]   # what the frame took, where it shaded
    assert spp.sum() == stats["samples"] and np.array_equal(spp > 0, shaded)
    assert stats["samples"] >= stats["pixels_shaded"] >= 1
    # each false-colour PNG's scale, in the JSON and in the PNG itself, is its EXR's range over the pixels shown
    for name, log in (("level", False), ("n_p", True), ("spp", True), ("variance", True), ("shaded", False),
                      ("b_p", True)):
        check_colour_scale(out.with_suffix(f".{name}.exr"), stats["colour_scales"][name], covered, log)
    assert {"gbuffer", "bandwidth", "shading", "upsampling", "frame"} <= set(stats["time_s"])
    assert sum(lv["shaded"] for lv in stats["levels"]) == stats["pixels_shaded"]
    assert stats["assets"]["material.m"]["bandwidth"] == "built"
    assert len(list((work / "cache").glob("bandwidth-*.npz"))) == 1
    assert len(list((work / "cache").glob("env-bandwidth-*.npz"))) == 1
    # a second frame reads both from the cache; the AOVs are not overwritten without --force
    r = run(["render", npf_scene, "-o", out, "--method", "adaptive", "--budget", "4", "-q"], work, check=False)
    assert r.returncode == 2 and "--force" in r.stderr
    run(["render", npf_scene, "-o", out, "--method", "adaptive", "--budget", "4", "-q", "--force"], work)
    assert json.loads(out.with_suffix(".json").read_text())["assets"]["material.m"]["bandwidth"] == "cache"
    # the paper's allocation (N_p proportional to the Eq. 9 bound) and a finer Nyquist rate, on request
    run(["render", npf_scene, "-o", out, "--method", "adaptive", "--budget", "4", "-q", "--force",
         "--allocation", "variance", "--nyquist", "4"], work)
    stats2 = json.loads(out.with_suffix(".json").read_text())
    assert stats2["allocation"]["allocation"] == "variance"
    assert stats2["pixels_shaded"] >= stats["pixels_shaded"]  # twice the rate: levels no coarser
    assert stats["upsample"] == "normal"
    # the paper's weighted mean for up-sampling: same seed, so the same pixels are shaded with the same samples;
    # those of level 0 keep their values, the others (up-sampled at level 0) change
    frames = {}
    for mode in ("normal", "paper"):
        run(["render", npf_scene, "-o", out, "--method", "adaptive", "--budget", "4", "-q", "--force",
             "--upsample", mode], work)
        assert json.loads(out.with_suffix(".json").read_text())["upsample"] == mode
        frames[mode] = (read_exr(out).pixels[..., :3], read_exr(out.with_suffix(".level.exr")).pixels[..., 0])
    (normal, level), (paper, level_paper) = frames["normal"], frames["paper"]
    fine = covered & (level == 0)
    assert np.array_equal(level, level_paper) and fine.any() and np.array_equal(normal[fine], paper[fine])
    up = covered & (level > 0)
    assert up.any() and np.isfinite(normal).all() and not np.array_equal(normal[up], paper[up])
    # the probe's bandwidth analysed on log(1 + L / mean L), on request: its own cache entry beside the radiance one
    run(["render", npf_scene, "-o", out, "--method", "adaptive", "--budget", "4", "-q", "--force",
         "--env-signal", "log"], work)
    assert json.loads(out.with_suffix(".json").read_text())["env_signal"] == "log"
    assert len(list((work / "cache").glob("env-bandwidth-log-*.npz"))) == 1


def test_a_mesh_curvature_is_derived_only_for_a_frame_with_the_bandwidth_pass(tmp_path, monkeypatch):
    """Only the bandwidth pass reads a mesh's curvature (002 Eq. 3), so a reference frame never derives it: the
    mean-curvature operator is not called until the first adaptive frame, which calls it once, lists the stage
    and times it; the G-buffer then holds local_curvature of the mesh's H, as when it was derived at load."""
    import trimesh

    import warpbw.io.mesh as mesh_io
    from warpbw.pipeline import prepare_scene, render_adaptive, render_reference
    from warpbw.scene import parse_scene

    trimesh.creation.icosphere(subdivisions=3, radius=0.8).export(tmp_path / "ico.obj")
    write_exr(tmp_path / "sky.exr", np.full((16, 32, 3), 0.5, np.float32))
    calls = []
    derive = mesh_io.mesh_mean_curvature
    monkeypatch.setattr(mesh_io, "mesh_mean_curvature", lambda *a: calls.append(1) or derive(*a))
    text = "\n".join(["[camera]", "position = [0.0, 0.0, 3.0]", "look_at = [0.0, 0.0, 0.0]", "fov = 40.0",
                      "resolution = [24, 24]", "[environment]", 'file = "sky.exr"', "[[object]]",
                      'mesh = "ico.obj"', 'material = "m"', "[material.m]", 'type = "lambert"', "albedo = 0.5"])
    prep = prepare_scene(parse_scene(text, tmp_path, "ico.toml"))
    ref = render_reference(prep, spp=4, seed=1)
    assert not calls and ref.coverage.sum() > 100 and "mesh_curvature" not in ref.stats["stages"]
    ada = render_adaptive(parse_scene(text, tmp_path, "ico.toml"), budget=2.0, seed=1)
    assert len(calls) == 1 and "mesh_curvature" in ada.stats["stages"]
    assert ada.stats["time_s"]["load_mesh_curvature"] > 0
    render_adaptive(prep, budget=2.0, seed=1)
    render_adaptive(prep, budget=2.0, seed=2)
    assert len(calls) == 2   # once per prepared scene
    md = mesh_io.load_mesh(tmp_path / "ico.obj")
    want = mesh_io.local_curvature(derive(md.vertices.astype(np.float64), md.faces, md.normals.astype(np.float64)),
                                   md.faces)
    np.testing.assert_allclose(prep.geometry.mesh_attr.curvature.numpy(), want, rtol=1e-4)
    assert abs(np.median(want) * 0.8 - 1.0) < 0.02   # |H| = 1 / r


# what a stage of stats["stages"] is called in warpbw info's list
STAGE_WORDS = {"mesh_curvature": "mesh curvature", "bandwidth_pass": "bandwidth pass", "pyramid": "level pyramid",
               "hierarchical_shading": "hierarchical shading", "upsampling": "up-sampling",
               "reference_shading": "reference shading"}


def test_info_lists_a_bandwidth_table_only_for_the_method_that_reads_it(tmp_path, monkeypatch, capsys):
    """warpbw info's "files" are the files a frame of that method reads: a tabulated material's precomputed
    bandwidth table only with --method adaptive (the bandwidth pass reads it; it was listed for the reference
    too).  Truth: the table here is not a table at all, and the reference renders the scene while the adaptive
    method refuses it, naming it."""
    from conftest import fake_npf_table
    from warpbw.cli import main as cli_main
    from warpbw.errors import WarpbwError
    from warpbw.pipeline import render_adaptive, render_reference
    from warpbw.scene import load_scene

    monkeypatch.setenv("WARPBW_CACHE", str(tmp_path / "cache"))
    fake_npf_table(tmp_path / "npf.bin")
    (tmp_path / "bw.npz").write_bytes(b"not a table")
    (tmp_path / "s.toml").write_text("\n".join([
        "[camera]", "position = [0.0, 0.0, 3.0]", "look_at = [0.0, 0.0, 0.0]", "fov = 50.0", "resolution = [8, 8]",
        "[environment]", 'procedural = "sky"', "[[object]]", 'shape = "sphere"', "radius = 0.8", 'material = "m"',
        "[material.m]", 'type = "npf"', 'table = "npf.bin"', 'name = "chrome"', 'bandwidth = "bw.npz"']))
    from warpbw.pipeline import FRAME_BYTES_PER_PIXEL

    listed = {}
    for method in ("reference", "adaptive"):
        assert cli_main(["info", str(tmp_path / "s.toml"), "--json", "--method", method]) == 0
        summary = json.loads(capsys.readouterr().out)
        listed[method] = [Path(f).name for f in summary["files"]]
        assert summary["frame_memory_bytes"] == FRAME_BYTES_PER_PIXEL[method] * 8 * 8   # the frame's estimate
        assert cli_main(["info", str(tmp_path / "s.toml"), "--method", method]) == 0
        assert f"GB per {method} frame beyond the assets" in capsys.readouterr().out
    assert listed == {"reference": ["npf.bin"], "adaptive": ["npf.bin", "bw.npz"]}, listed
    scene = load_scene(tmp_path / "s.toml")
    assert render_reference(scene, spp=1).coverage.any()
    with pytest.raises(WarpbwError, match="bw.npz"):
        render_adaptive(scene, budget=1.0)


def test_info_says_what_the_precomputed_files_a_scene_names_are(tmp_path, monkeypatch, capsys):
    """warpbw info lists beside each precomputed file a material names (gmm, sampling, bandwidth) what its header
    says: its kind and version, another version this warpbw does not read, builder settings other than the
    builder's (read as they are), or a file that is no asset file.  Truth: a GMM mipmap written here, and copies whose
    headers are rewritten here with numpy (version 1; EM's tolerance 1e-3), and bytes that are no archive."""
    from conftest import rewrite_asset
    from precompute.gmm_mipmap import build_gmm_mipmap, write_gmm_mipmap
    from warpbw.cli import main as cli_main
    from warpbw.io.exr import write_exr
    from warpbw.scene import file_digest

    monkeypatch.setenv("WARPBW_CACHE", str(tmp_path / "cache"))
    heights = np.add.outer(np.sin(np.arange(8.0)), np.cos(np.arange(8.0))) * 0.02
    write_exr(tmp_path / "h.exr", heights.astype(np.float32)[..., None], ["Y"])
    # the map's own content hash: with another ("x") the render refuses the file, and info says so (session 77)
    write_gmm_mipmap(tmp_path / "ok.gmm", build_gmm_mipmap(heights, progress=False), "h.exr",
                     file_digest(tmp_path / "h.exr"))

    rewrite_asset(tmp_path / "ok.gmm", tmp_path / "v1.gmm", version=1)
    rewrite_asset(tmp_path / "ok.gmm", tmp_path / "other.gmm", params={"em_tolerance": 1e-3})
    (tmp_path / "junk.gmm").write_bytes(b"not an archive")
    lines = ["[camera]", "position = [0.0, 1.2, 1.2]", "look_at = [0.0, 0.0, 0.0]", "fov = 40.0",
             "resolution = [8, 8]", "[[light]]", 'type = "directional"', "direction = [0.3, 0.8, -0.5]",
             "radiance = [3.0, 3.0, 3.0]"]
    names = ["ok", "v1", "other", "junk"]
    for i, n in enumerate(names):
        lines += ["[[object]]", 'shape = "plane"', f"center = [{3.0 * i}, 0.0, 0.0]", "size = 2.0",
                  f'material = "{n}"']
    for n in names:
        lines += [f"[material.{n}]", 'type = "cook-torrance"', "roughness = 0.08", "f0 = [0.9, 0.75, 0.4]",
                  'normal_map = "h.exr"', f'gmm = "{n}.gmm"']
    (tmp_path / "s.toml").write_text("\n".join(lines))
    assert cli_main(["info", str(tmp_path / "s.toml"), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    # the four materials' one normal map listed once (it was listed once per material)
    assert [Path(f).name for f in summary["files"]] == ["h.exr", "ok.gmm", "v1.gmm", "other.gmm", "junk.gmm"]
    assets = {Path(a["path"]).name: a for a in summary["assets"]}
    assert list(assets) == [f"{n}.gmm" for n in names]
    assert assets["ok.gmm"]["version"] == 2 and assets["ok.gmm"]["not_read"] is None
    assert assets["ok.gmm"]["settings"] == "current"
    assert assets["v1.gmm"]["not_read"] == "version 1, this warpbw reads 2" and assets["v1.gmm"]["settings"] is None
    assert assets["other.gmm"]["settings"] == "differ"
    assert assets["other.gmm"]["settings_differ"] == "em_tolerance 0.001, the builder's 0.0001"
    assert assets["junk.gmm"] == {"path": str(tmp_path / "junk.gmm"),
                                  "error": "not a warpbw asset file, or a damaged one"}
    assert cli_main(["info", str(tmp_path / "s.toml")]) == 0
    text = capsys.readouterr().out
    for name, said in (("ok", "version 2; builder settings current"),
                       ("v1", ": version 1, this warpbw reads 2"),
                       ("other", "builder settings differ (em_tolerance 0.001, the builder's 0.0001): read as it is"),
                       ("junk", "not a warpbw asset file, or a damaged one")):
        assert f"{name}.gmm (" in text and said in text.split(f"{name}.gmm (")[1].splitlines()[0], (name, text)


def test_info_estimates_the_memory_a_probe_file_takes_to_load_and_analyse(tmp_path, capsys):
    """warpbw info gives, from the probe's header alone, the peak of loading it (LOAD_BYTES_PER_TEXEL) and, with
    --method adaptive, of building its bandwidth map (ENV_BW_BYTES_PER_TEXEL plus ENV_BW_BYTES_FIXED): an 8192x4096
    probe takes 1.6 and 5.2 GB there (session 63).  A procedural sky gives neither; nor does a header that does not
    read (the render names what is wrong)."""
    from warpbw.bandwidth import ENV_BW_BYTES_FIXED, ENV_BW_BYTES_PER_TEXEL
    from warpbw.cli import main as cli_main
    from warpbw.envmap import LOAD_BYTES_PER_TEXEL

    write_exr(tmp_path / "probe.exr", np.ones((24, 48, 3), np.float32))
    scene = ("[camera]\nposition = [0.0, 0.0, 3.0]\nlook_at = [0.0, 0.0, 0.0]\nfov = 50.0\nresolution = [8, 8]\n"
             "[environment]\n{env}\n[[object]]\nshape = \"sphere\"\nradius = 0.8\nmaterial = \"m\"\n"
             "[material.m]\ntype = \"lambert\"\nalbedo = 0.5\n")
    (tmp_path / "s.toml").write_text(scene.format(env='file = "probe.exr"'))
    for method, want in (("reference", {"probe_load_memory_bytes": LOAD_BYTES_PER_TEXEL * 48 * 24}),
                         ("adaptive", {"probe_load_memory_bytes": LOAD_BYTES_PER_TEXEL * 48 * 24,
                                       "probe_bandwidth_memory_bytes": ENV_BW_BYTES_PER_TEXEL * 48 * 24
                                       + ENV_BW_BYTES_FIXED})):
        assert cli_main(["info", str(tmp_path / "s.toml"), "--json", "--method", method]) == 0
        summary = json.loads(capsys.readouterr().out)
        assert {k: v for k, v in summary.items() if k.startswith("probe_")} == want
        assert cli_main(["info", str(tmp_path / "s.toml"), "--method", method]) == 0
        text = capsys.readouterr().out
        assert "GB at the peak to load the probe" in text
        assert ("GB to build its bandwidth map (once; then cached)" in text) == (method == "adaptive")
    (tmp_path / "probe.exr").write_bytes(b"not an exr")
    (tmp_path / "sky.toml").write_text(scene.format(env='procedural = "sky"'))
    for name in ("s.toml", "sky.toml"):
        assert cli_main(["info", str(tmp_path / name), "--json", "--method", "adaptive"]) == 0
        assert not [k for k in json.loads(capsys.readouterr().out) if k.startswith("probe_")]

def test_info_estimates_the_memory_the_placed_meshes_take(tmp_path, capsys):
    """warpbw info gives, from the mesh file's face lines alone, what the render warns on after loading one copy:
    MESH_BYTES_PER_TRIANGLE for each triangle of each placed copy (an OBJ of two quads placed three times: 12
    triangles) and MESH_FILE_BYTES_PER_TRIANGLE for each of the file's own (4; a file's triangles were not counted
    once for its parse and first copy, which took twice the estimate of a 1.1M-triangle mesh placed once: session
    79).  A file that does not say (a damaged PLY header) gives nothing, and info still lists the scene."""
    from warpbw.cli import main as cli_main
    from warpbw.pipeline import MESH_BYTES_PER_TRIANGLE, MESH_FILE_BYTES_PER_TRIANGLE

    (tmp_path / "quads.obj").write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 2 0\nv 1 2 0\nf 1 2 3 4\nf 4 3 6 5\n")
    (tmp_path / "cut.ply").write_text("ply\nformat ascii 1.0\nelement vertex 3\n")
    scene = ("[camera]\nposition = [0.0, 0.0, 3.0]\nlook_at = [0.0, 0.0, 0.0]\nfov = 50.0\nresolution = [8, 8]\n"
             "[environment]\nprocedural = \"sky\"\n[material.m]\ntype = \"lambert\"\nalbedo = 0.5\n"
             + "".join(f"[[object]]\nmesh = \"{{name}}\"\ntranslate = [{x}.0, 0.0, 0.0]\n"
                       "material = \"m\"\n" for x in range(3)))
    (tmp_path / "s.toml").write_text(scene.format(name="quads.obj"))
    assert cli_main(["info", str(tmp_path / "s.toml"), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert (summary["mesh_triangles"], summary["mesh_memory_bytes"]) == \
        (12, 12 * MESH_BYTES_PER_TRIANGLE + 4 * MESH_FILE_BYTES_PER_TRIANGLE)
    assert cli_main(["info", str(tmp_path / "s.toml")]) == 0
    assert "GB for the meshes' 12 triangles" in capsys.readouterr().out
    (tmp_path / "cut.toml").write_text(scene.format(name="cut.ply"))
    assert cli_main(["info", str(tmp_path / "cut.toml"), "--json"]) == 0
    assert not [k for k in json.loads(capsys.readouterr().out) if k.startswith("mesh_")]


def test_the_render_record_names_the_bandwidth_file_it_read(tmp_path, monkeypatch):
    """Two renders from different precomputed files read alike but for the tables: the record says which file was
    read (``bandwidth_file``), and nothing where the table was built or cached."""
    from conftest import fake_npf_table
    from precompute.brdf_bandwidth import write_brdf_bandwidth
    from precompute.brdf_sampling import brdf_source
    from warpbw.pipeline import render_adaptive
    from warpbw.scene import load_scene

    monkeypatch.setenv("WARPBW_CACHE", str(tmp_path / "cache"))
    fake_npf_table(tmp_path / "npf.bin")
    write_brdf_bandwidth(tmp_path / "bw.npz", np.full((16, 16, 16), 2.0, np.float32),
                         brdf_source(tmp_path / "npf.bin", "chrome"))   # NPF's default lookup, the scene's too
    lines = ["[camera]", "position = [0.0, 0.0, 3.0]", "look_at = [0.0, 0.0, 0.0]", "fov = 50.0", "resolution = [8, 8]",
             "[environment]", 'procedural = "sky"', "[[object]]", 'shape = "sphere"', "radius = 0.8", 'material = "m"',
             "[material.m]", 'type = "npf"', 'table = "npf.bin"', 'name = "chrome"']
    for name, extra in (("file.toml", ['bandwidth = "bw.npz"']), ("built.toml", [])):
        (tmp_path / name).write_text("\n".join(lines + extra))
    rec = render_adaptive(load_scene(tmp_path / "file.toml"), budget=2.0).stats["assets"]["material.m"]
    assert rec["bandwidth"] == "file" and rec["bandwidth_file"] == str(tmp_path / "bw.npz")
    rec = render_adaptive(load_scene(tmp_path / "built.toml"), budget=2.0).stats["assets"]["material.m"]
    assert rec["bandwidth"] == "built" and "bandwidth_file" not in rec and "sampling_file" not in rec


def test_info_says_a_named_bandwidth_table_of_another_lookup_is_refused(tmp_path, capsys):
    """A scene naming a nu_rho table built for another lookup than its material shades with is refused by the render
    (README, "Scene files"), but warpbw info --method adaptive said "builder settings current" of it (session 76's
    audit): info now says the render refuses it and the --lookup that builds the right one.  Truth: the renderer's
    own reader, given the material's source, refuses exactly the file info flags."""
    from conftest import fake_npf_table
    from precompute.brdf_bandwidth import read_brdf_bandwidth, write_brdf_bandwidth
    from precompute.brdf_sampling import brdf_source
    from warpbw.cli import main as cli_main
    from warpbw.errors import WarpbwError

    fake_npf_table(tmp_path / "npf.bin")
    for lookup in ("nearest", "linear"):
        write_brdf_bandwidth(tmp_path / f"{lookup}.npz", np.full((16, 16, 16), 2.0, np.float32),
                             brdf_source(tmp_path / "npf.bin", "chrome", lookup))
    lines = ["[camera]", "position = [0.0, 0.0, 3.0]", "look_at = [0.0, 0.0, 0.0]", "fov = 50.0", "resolution = [8, 8]",
             "[environment]", 'procedural = "sky"', "[[object]]", 'shape = "sphere"', "radius = 0.8", 'material = "m"',
             "[material.m]", 'type = "npf"', 'table = "npf.bin"', 'name = "chrome"']
    for scene_lookup in ("nearest", "linear"):
        for file_lookup in ("nearest", "linear"):
            table = tmp_path / f"{file_lookup}.npz"
            named = [f'lookup = "{scene_lookup}"', f'bandwidth = "{table.name}"']
            (tmp_path / "s.toml").write_text("\n".join(lines + named))
            try:
                read_brdf_bandwidth(table, brdf_source(tmp_path / "npf.bin", "chrome", scene_lookup))
                refused = ""
            except WarpbwError as exc:
                refused = str(exc)
            assert bool(refused) == (scene_lookup != file_lookup)
            assert cli_main(["info", str(tmp_path / "s.toml"), "--method", "adaptive", "--json"]) == 0
            (a,) = [a for a in json.loads(capsys.readouterr().out)["assets"] if a["path"] == str(table)]
            assert ("refused" in a) == bool(refused), (scene_lookup, file_lookup, a)
            assert cli_main(["info", str(tmp_path / "s.toml"), "--method", "adaptive"]) == 0
            line = next(ln for ln in capsys.readouterr().out.splitlines() if str(table) in ln)
            # the render's own words, after the file's name; they name the lookup and the command that builds it
            said = f"a render refuses it: {refused[len(str(table)) + 2:]}"
            assert (said in line) == bool(refused) and ("builder settings current" in line) != bool(refused), line
            assert (f"read with the {file_lookup} lookup, expected the {scene_lookup} lookup" in line) == bool(refused)
            assert (f"--lookup {scene_lookup}" in line) == (scene_lookup == "nearest" != file_lookup), line


def test_info_says_a_named_table_the_render_finds_damaged_is_refused(tmp_path, capsys):
    """A nu_rho table whose header is current but whose cells hold NaN is refused by the render's reader; warpbw info
    said "builder settings current" of it (its header-level twin of the readers did not read the arrays) until
    session 78, when info asked the readers themselves.  Truth: the reader, given the material's source, and the
    same table written whole, which both read."""
    from conftest import fake_npf_table
    from precompute.assetfile import write_asset
    from precompute.brdf_bandwidth import FORMAT, VERSION, bandwidth_settings, read_brdf_bandwidth
    from precompute.brdf_sampling import brdf_source
    from warpbw.cli import main as cli_main

    source = brdf_source(fake_npf_table(tmp_path / "npf.bin"), "chrome")
    lines = ["[camera]", "position = [0.0, 0.0, 3.0]", "look_at = [0.0, 0.0, 0.0]", "fov = 50.0", "resolution = [8, 8]",
             "[environment]", 'procedural = "sky"', "[[object]]", 'shape = "sphere"', "radius = 0.8", 'material = "m"',
             "[material.m]", 'type = "npf"', 'table = "npf.bin"', 'name = "chrome"', 'bandwidth = "bw.npz"']
    (tmp_path / "s.toml").write_text("\n".join(lines))
    for fill, damaged in ((2.0, False), (np.nan, True)):
        write_asset(tmp_path / "bw.npz", FORMAT, VERSION, source.name, source.digest,
                    {"nu_rho": np.full((16, 16, 16), fill, np.float32)}, params=bandwidth_settings(), force=True)
        said = outcome(read_brdf_bandwidth, tmp_path / "bw.npz", source)
        assert said.startswith("WarpbwError: ") == damaged, said
        assert cli_main(["info", str(tmp_path / "s.toml"), "--method", "adaptive", "--json"]) == 0
        (a,) = json.loads(capsys.readouterr().out)["assets"]
        assert a.get("refused") == (said[len(f"WarpbwError: {tmp_path / 'bw.npz'}: "):] if damaged else None), a


def test_info_lists_the_stages_a_frame_of_each_method_runs(tmp_path):
    """warpbw info --method M, from the scene file alone, names the stages a frame of M then records having run
    (stats["stages"]), in their order; the adaptive method is refused where warpbw render refuses it."""
    import trimesh

    from warpbw.pipeline import render_adaptive, render_reference, scene_summary
    from warpbw.scene import parse_scene

    trimesh.creation.icosphere(subdivisions=2, radius=0.5).export(tmp_path / "ico.obj")
    write_exr(tmp_path / "sky.exr", np.full((16, 32, 3), 0.5, np.float32))
    camera = ["[camera]", "position = [0.0, 0.0, 3.0]", "look_at = [0.0, 0.0, 0.0]", "fov = 50.0",
              "resolution = [16, 16]"]
    text = "\n".join(camera + ["[environment]", 'file = "sky.exr"', "[[object]]", 'mesh = "ico.obj"',
                               "translate = [-0.6, 0.0, 0.0]", 'material = "m"', "[[object]]", 'shape = "sphere"',
                               "center = [0.6, 0.0, 0.0]", "radius = 0.5", 'material = "g"', "[material.m]",
                               'type = "lambert"', "albedo = 0.5", "[material.g]", 'type = "ggx"', "alpha = 0.3",
                               "specular = [0.5, 0.5, 0.5]"])
    (tmp_path / "s.toml").write_text(text)
    scene = parse_scene(text, tmp_path, "s.toml")
    for method, frame in (("reference", lambda: render_reference(scene, spp=2)),
                          ("adaptive", lambda: render_adaptive(scene, budget=2.0))):
        listed = [w for st in scene_summary(scene, method)["stages"] for w in STAGE_WORDS.values()
                  if st.startswith(w)]
        ran = [STAGE_WORDS[st.split("+")[0]] for st in frame().stats["stages"] if st.split("+")[0] in STAGE_WORDS]
        assert listed == ran and ran, (method, listed, ran)
        assert len(ran) == (5 if method == "adaptive" else 1)
        info = json.loads(run(["info", "s.toml", "--json", "--method", method], tmp_path).stdout)
        assert info["stages"] == scene_summary(scene, method)["stages"]
    # refused as render refuses it: lights alone (nothing to adapt), planes alone (reflectance filtering)
    lit = "\n".join(camera + ["[[light]]", 'type = "directional"', "direction = [0.0, 0.0, 1.0]",
                              "radiance = [1.0, 1.0, 1.0]", "[[object]]", 'shape = "sphere"', "radius = 0.5",
                              'material = "m"', "[material.m]", 'type = "lambert"', "albedo = 0.5"])
    (tmp_path / "lit.toml").write_text(lit)
    (tmp_path / "planes.toml").write_text(plane_scene_toml())
    for name in ("lit.toml", "planes.toml"):
        r = run(["info", name, "--method", "adaptive"], tmp_path, check=False)
        told = run(["render", name, "-o", "x.exr", "--method", "adaptive", "--budget", "2"], tmp_path, check=False)
        assert r.returncode == told.returncode == 2 and r.stderr.count("\n") == 1, (r.stderr, told.stderr)
        assert ("needs an [environment]" if name == "lit.toml" else "reflectance filtering") in r.stderr
        assert run(["info", name], tmp_path).returncode == 0


def test_a_frame_compiles_and_launches_only_the_kernels_its_scene_needs(tmp_path, monkeypatch):
    """"No stage is compiled or run that the scene does not use", seen from Warp's side: every kernel a frame
    launches, and every module it loads (compiles) ahead of the clock, is recorded at ``wp.launch`` /
    ``wp.load_module``.  A Lambert sphere under a constant sky, reference: the spheres-only G-buffer kernel and
    the reference kernel specialised to {Lambert}, with the environment's loop and no light loop -- nothing
    else.  With a directional light instead of the sky: the same, with the light loop and no environment loop.
    Adaptive: the bandwidth pass, the pyramid, the hierarchy and the up-sampling join them, and nothing of the
    planes' filtering, the mesh operators or the host-side BRDF kernels."""
    import warp as wp

    from warpbw.brdf import LAMBERT
    from warpbw.gbuffer import make_gbuffer_kernel
    from warpbw.pipeline import render_adaptive, render_reference
    from warpbw.scene import parse_scene
    from warpbw.shading import make_reference_kernel

    launched, loaded = [], []
    launch, load_module = wp.launch, wp.load_module
    monkeypatch.setattr(wp, "launch", lambda kernel, *a, **k: launched.append(kernel) or launch(kernel, *a, **k))
    monkeypatch.setattr(wp, "load_module", lambda m, *a, **k: loaded.append(m) or load_module(m, *a, **k))

    def frame(render, light: str, **kw) -> tuple[list, list]:
        launched.clear()
        loaded.clear()
        text = "\n".join(["[camera]", "position = [0.0, 0.0, 4.0]", "look_at = [0.0, 0.0, 0.0]", "fov = 30.0",
                          "resolution = [32, 32]", light, "[[object]]", 'shape = "sphere"', "radius = 1.0",
                          'material = "m"', "[material.m]", 'type = "lambert"', "albedo = 0.5"])
        res = render(parse_scene(text, tmp_path, "s.toml"), seed=1, **kw)
        assert res.coverage.sum() > 100
        return list(launched), list(loaded)

    sky = "[environment]\nconstant = [1.0, 1.0, 1.0]"
    sun = '[[light]]\ntype = "directional"\ndirection = [0.0, 0.0, 1.0]\nradiance = [1.0, 1.0, 1.0]'
    gbuffer = make_gbuffer_kernel(has_spheres=True, has_mesh=False, attributes=False)
    for light, has_env in ((sky, True), (sun, False)):
        shade = make_reference_kernel({LAMBERT}, False, has_env=has_env, has_lights=not has_env)
        kernels, modules = frame(render_reference, light, spp=2)
        assert {id(k) for k in kernels} == {id(gbuffer), id(shade)}, [k.key for k in kernels]
        assert {id(m) for m in modules} <= {id(gbuffer.module), id(shade.module)}, [m.name for m in modules]

    kernels, modules = frame(render_adaptive, sky, budget=2.0)
    launched_by = {k.func.__module__ for k in kernels}
    assert launched_by == {"warpbw.gbuffer", "warpbw.shading", "warpbw.bandwidth", "warpbw.pyramid",
                           "warpbw.adaptive", "warpbw.upsample"}
    assert id(gbuffer) in {id(k) for k in kernels}
    # nothing compiled ahead goes unused
    assert {id(m) for m in modules} <= {id(k.module) for k in kernels}, [m.name for m in modules]


def test_a_scene_lit_by_lights_alone_reads_or_builds_no_brdf_sampling_table(tmp_path, monkeypatch):
    """"No stage is compiled or run that the scene does not use": directional lights alone are exact (no BRDF is
    sampled), so an NPF material under them loads no sampling table -- none read, none built (seconds for a new
    material: session 76 measured 4.5 s for an NPF fit, 1.3 s for a MERL file), none packed on the device -- and
    neither the frame's stages nor ``warpbw info``'s name tabulated sampling.  The same sphere under a black
    environment as well (which samples the BRDF, so loads the table) gives the same image bit for bit: the lights'
    term did not need it."""
    import precompute.brdf_sampling as bs
    from conftest import fake_npf_table
    from warpbw.brdf import pdf_brdf, sample_brdf
    from warpbw.errors import WarpbwError
    from warpbw.pipeline import prepare_scene, render_reference, scene_summary
    from warpbw.scene import parse_scene

    fake_npf_table(tmp_path / "npf.bin")
    loaded, load = [], bs.load_or_build_sampling
    monkeypatch.setattr(bs, "load_or_build_sampling", lambda *a, **k: loaded.append(a) or load(*a, **k))
    lights = ('[[light]]\ntype = "directional"\ndirection = [0.3, 0.6, 0.8]\nradiance = [2.0, 1.5, 1.0]\n'
              '[material.m]\ntype = "npf"\ntable = "npf.bin"\nname = "chrome"\n')
    frames = {}
    for env in ("", "[environment]\nconstant = [0.0, 0.0, 0.0]\n"):
        loaded.clear()
        sphere = lambert_sphere_scene(24, 24).split("[material.m]")[0].replace("constant = [1.0, 1.0, 1.0]", "")
        scene = parse_scene(sphere.replace("[environment]", env) + lights, tmp_path, "s.toml")
        prep = prepare_scene(scene)
        res = render_reference(prep, spp=2)
        frames[bool(env)] = res.image
        tabulated = "tabulated_sampling" in res.stats["stages"]
        listed = any("tabulated importance sampling" in st for st in scene_summary(scene)["stages"])
        assert len(loaded) == tabulated == listed == bool(env), (env, len(loaded), res.stats["stages"])
        assert (prep.materials.table.samplers.density.shape[0] > 0) == bool(env)
        assert ("sampling" in res.stats["assets"]["material.m"]) == bool(env), res.stats["assets"]
        if not env:   # the host wrappers refuse to sample it (its sampler index would read past the empty tables)
            for f, args in ((sample_brdf, ([0.0, 0.0, 1.0], 4)), (pdf_brdf, ([[0.0, 0.0, 1.0]], [[0.0, 0.0, 1.0]]))):
                with pytest.raises(WarpbwError, match="packed without its sampling table"):
                    f(prep.materials, 0, *args)
    assert np.abs(frames[False]).max() > 0.01 and np.array_equal(frames[False], frames[True])


def test_the_environment_s_sampling_distribution_is_built_only_for_a_frame_that_samples_it(tmp_path, monkeypatch):
    """"No stage is compiled or run that the scene does not use": the reference without MIS draws BRDF directions
    only and looks the environment's radiance up, so its frame of a Scene builds no sampling distribution for the
    environment (``env_sample`` / ``env_pdf``'s CDFs and cell pdf: session 76 measured 0.4-0.8 s and 67 MB for a
    4096 x 2048 probe), nor does a scene prepared with ``sampling=False`` until a frame samples it: the first MIS or
    adaptive frame builds it, once, ahead of its clock, and times it as loading the environment.  The frame without
    MIS is the same bit for bit before and after."""
    from warpbw import envmap
    from warpbw.pipeline import prepare_scene, render_adaptive, render_reference
    from warpbw.scene import parse_scene

    built, build = [], envmap._build_distribution
    monkeypatch.setattr(envmap, "_build_distribution", lambda *a, **k: built.append(1) or build(*a, **k))
    text = lambert_sphere_scene(20, 20).replace("constant = [1.0, 1.0, 1.0]", 'procedural = "sky"')
    scene = parse_scene(text, tmp_path, "s.toml")
    first = render_reference(scene, spp=2, seed=4)
    assert built == [] and first.stats["time_s"]["load_environment"] > 0
    prep = prepare_scene(scene, sampling=False)
    plain = render_reference(prep, spp=2, seed=4)
    assert built == [] and prep.env.lookup_data.cell_pdf.shape == (0, 0) and np.array_equal(plain.image, first.image)
    assert not prep.env.has_sampling
    assert "load_environment" not in plain.stats["time_s"]
    mis = render_reference(prep, spp=2, seed=4, mis=True)
    assert len(built) == 1 and mis.stats["time_s"]["load_environment"] > 0
    assert prep.env.lookup_data.cell_pdf.shape == (prep.env.height, prep.env.width) and prep.env.has_sampling
    render_reference(prep, spp=2, seed=4, mis=True)
    assert len(built) == 1   # once
    assert np.array_equal(render_reference(prep, spp=2, seed=4).image, plain.image)
    built.clear()
    render_adaptive(prepare_scene(scene, sampling=False), budget=1.0)   # the bandwidth pass samples it
    assert len(built) == 1


def test_an_adaptive_frame_derives_the_relative_bound_only_for_the_relative_allocation(tmp_path, monkeypatch):
    """"No stage is compiled or run that the scene does not use": ``sigma2_rel`` (the bound over the pixel's own
    radiance, a kernel over the frame and a median of the pass's radiance) is read by the "relative" allocation
    alone.  An adaptive frame of every other allocation neither loads nor launches its kernel (session 76: 4-16 ms at
    512 x 512, inside the bandwidth pass's time); the relative one does, once.  A pass without it says so when the
    relative allocation asks for it."""
    import warp as wp

    from warpbw import bandwidth
    from warpbw.errors import WarpbwError
    from warpbw.pipeline import prepare_scene, render_adaptive
    from warpbw.scene import parse_scene

    launched, loaded = [], []
    launch, load_module = wp.launch, wp.load_module
    monkeypatch.setattr(wp, "launch", lambda kernel, *a, **k: launched.append(kernel) or launch(kernel, *a, **k))
    monkeypatch.setattr(wp, "load_module", lambda m, *a, **k: loaded.append(m) or load_module(m, *a, **k))
    prep = prepare_scene(parse_scene(lambert_sphere_scene(24, 24), tmp_path, "s.toml"))
    for allocation in bandwidth.ALLOCATIONS:
        launched.clear()
        loaded.clear()
        render_adaptive(prep, budget=2.0, allocation=allocation)
        want = int(allocation == "relative")
        assert sum(k is bandwidth.relative_bound_kernel for k in launched) == want, allocation
        assert (bandwidth.relative_bound_kernel.module in loaded) == bool(want), allocation
    res = render_adaptive(prep, budget=2.0)
    buf = bandwidth.bandwidth_pass(res.gbuffer, prep.camera, prep.materials, prep.env_data, prep.bandwidth,
                                   relative=False)
    assert buf.sigma2_rel is None
    with pytest.raises(WarpbwError, match="no relative bound"):
        bandwidth.allocate_samples(buf, 2.0, allocation="relative")


def test_a_frame_s_g_buffer_holds_no_channel_that_no_stage_reads(tmp_path):
    """"No stage is compiled or run that the scene does not use": the G-buffer's ``geo_normal`` and ``uv`` are read
    by no later stage, so a frame's G-buffer (reference, adaptive, and planes beside a sphere, which hide what lies
    behind them) neither holds nor writes them (20 of its 80 bytes per pixel; session 76: a 1024^2 G-buffer of a
    sphere in 45 ms instead of 62 on one thread).  Asked for, ``render_gbuffer`` writes them, and every other channel
    is the same bit for bit either way; a G-buffer without them says so when one is read."""
    from warpbw.errors import WarpbwError
    from warpbw.gbuffer import render_gbuffer
    from warpbw.pipeline import prepare_scene, render_adaptive, render_reference, render_with_planes
    from warpbw.scene import parse_scene

    prep = prepare_scene(parse_scene(lambert_sphere_scene(24, 20), tmp_path, "s.toml"))
    mixed = parse_scene(MIXED_SCENE, tmp_path, "mixed.toml")
    for res in (render_reference(prep, spp=1), render_adaptive(prep, budget=1.0),
                render_with_planes(mixed, "fixed", 1)):
        assert res.gbuffer.data.uv.shape[0] == res.gbuffer.data.geo_normal.shape[0] == 0
        with pytest.raises(WarpbwError, match="uv: not rendered"):
            res.gbuffer.numpy("uv")
    full = render_gbuffer(prep.camera, prep.geometry)
    lean = render_gbuffer(prep.camera, prep.geometry, attributes=False)
    assert full.numpy("uv").shape == (20, 24, 2) and np.abs(full.numpy("geo_normal")).max() > 0.5
    for name in ("position", "normal", "tangent", "view", "depth", "curvature", "material"):
        assert np.array_equal(full.numpy(name), lean.numpy(name)), name
    with pytest.raises(WarpbwError, match="allocated without geo_normal and uv"):
        render_gbuffer(prep.camera, prep.geometry, out=lean)


# ------------------------------------------------------------------------------------------ planes beside a sphere

def _numpy_plane_and_sphere_depths(w, h):
    """Distances along each pixel's centre ray to the plane y = 0 (inside its 3 x 3 square) and to the sphere of
    MIXED_SCENE, inf where missed: a numpy pinhole camera and the quadratic's nearer positive root."""
    o, d = numpy_camera_rays((0.0, 1.5, 3.0), (0.0, 0.0, 0.0), 40.0, w, h)
    return numpy_square_distance(o, d, 3.0), numpy_sphere_distance(o, d, (0.0, 0.1, 0.0), 0.5)


def test_planes_beside_a_sphere_show_whichever_surface_is_nearer(tmp_path, monkeypatch):
    """render_with_planes against the two renderers alone and a numpy ray cast: each pixel is the plane's
    where the plane is nearer along the centre ray, the sphere's where the sphere is (its lower part sinks
    below the floor, so each hides the other somewhere), and nothing where neither is hit.  The two renderers
    share one loaded environment."""
    from warpbw import envmap, filtering
    from warpbw.filtering import render_filtering
    from warpbw.pipeline import render_reference, render_with_planes, split_planes
    from warpbw.scene import parse_scene

    loads, load = [], envmap.load_environment

    def counted(*a, **k):
        loads.append(a)
        return load(*a, **k)
    scene = parse_scene(MIXED_SCENE, tmp_path, "mixed.toml")
    with monkeypatch.context() as mp:
        for module in (envmap, filtering):
            mp.setattr(module, "load_environment", counted)
        both = render_with_planes(scene, "fixed", 4, mis=True)
    assert len(loads) == 1
    sphere_scene, plane_scene = split_planes(scene)
    sphere = render_reference(sphere_scene, 4, mis=True)
    plane = render_filtering(plane_scene, "fixed", env_spp=4)
    t_p, t_s = _numpy_plane_and_sphere_depths(48, 32)
    with np.errstate(invalid="ignore"):                 # inf - inf where both miss: not a tie
        clear = ~(np.abs(t_p - t_s) < 1e-3)              # not on the circle where the sphere meets the floor
    plane_wins = t_p < t_s
    sphere_wins = t_s < t_p
    assert (plane_wins & np.isfinite(t_s) & clear).sum() > 5     # the floor hides the sphere's lower part
    assert (sphere_wins & np.isfinite(t_p) & clear).sum() > 50   # the sphere hides some floor
    assert np.array_equal(both.aovs["plane"][clear], plane_wins[clear])
    assert np.array_equal(both.coverage, sphere.coverage | plane.coverage)
    assert np.array_equal(both.coverage, np.isfinite(np.minimum(t_p, t_s)))
    m = both.aovs["plane"]
    assert np.array_equal(both.image[m], plane.image[m])
    assert np.array_equal(both.image[~m], sphere.image[~m])
    assert both.stats["planes"]["pixels_covered"] == int(m.sum())
    assert both.stats["pixels_covered"] == int(both.coverage.sum())
    # the stages of both renderers, the planes' named as such (the floor has no normal map: no GMM is fitted)
    assert both.stats["stages"] == sphere.stats["stages"] + [f"planes:{st}" for st in plane.stats["stages"]]
    assert "planes:plain_brdf:planes_without_normal_map" in both.stats["stages"]
    # the sphere's pixels the floor hides are not shaded: the same image from fewer shaded pixels
    hidden = int((sphere.coverage & m).sum())
    assert hidden > 5 and both.stats["pixels_hidden"] == hidden
    assert both.stats["pixels_shaded"] == sphere.stats["pixels_shaded"] - hidden
    assert both.stats["samples"] == sphere.stats["samples"] - 4 * hidden


def test_adaptive_spheres_behind_a_plane_take_no_samples(tmp_path):
    """Adaptive beside a plane: no sample and no shaded pixel falls where the floor is in front (the sphere's
    pixels there are hidden before the bandwidth pass)."""
    from warpbw.pipeline import render_with_planes
    from warpbw.scene import parse_scene

    scene = parse_scene(MIXED_SCENE, tmp_path, "mixed.toml")
    res = render_with_planes(scene, "fixed", 4, method="adaptive", budget=4)
    m = res.aovs["plane"]
    assert res.stats["pixels_hidden"] > 5
    assert not res.aovs["shaded"][m].any() and np.all(res.aovs["n_p"][m] == 0)
    visible = res.coverage & ~m
    assert res.aovs["shaded"][visible].any()
    # the adaptive stats per pixel stay over the sphere's visible pixels (render_with_planes' docstring), where
    # pixels_covered counts the planes' too
    st = res.stats
    n_sphere = st["pixels_covered"] - st["planes"]["pixels_covered"]
    assert n_sphere == int(visible.sum()) and st["pixels_covered"] == int(res.coverage.sum())
    assert st["samples_per_covered_pixel"] == pytest.approx(st["samples"] / n_sphere, rel=1e-12)
    assert st["shaded_fraction"] == pytest.approx(st["pixels_shaded"] / n_sphere, rel=1e-12)
    assert st["samples"] == int(res.aovs["spp"][visible].sum())


def _numpy_triangle_distance(o, d, a, b, c):
    """Distance along the unit rays ``d`` from ``o`` to the triangle abc (either side; Moller-Trumbore), inf where
    a ray misses."""
    a, b, c = (np.asarray(v, float) for v in (a, b, c))
    e1, e2 = b - a, c - a
    pv = np.cross(d, e2)
    det = pv @ e1
    with np.errstate(divide="ignore", invalid="ignore"):
        tv = o - a
        u = (pv @ tv) / det
        qv = np.cross(tv, e1)
        v = (d @ qv) / det
        t = (e2 @ qv) / det
    return np.where((np.abs(det) > 1e-12) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0), t, np.inf)


def test_planes_a_mesh_and_spheres_each_pixel_shows_the_nearest_surface_lit_as_in_closed_form(tmp_path):
    """render_with_planes of two planes (a floor cutting a sphere and a wall mesh, and a small plane hiding the
    wall's lower part), a sphere over the floor nearer the camera and one behind the camera, lit by a directional
    light alone (exact: no samples), against a numpy ray cast of our own: every pixel holds the value of the surface
    its centre ray hits first, Lambert's rho / pi E n.l on the spheres and the wall, README's Cook-Torrance bracket
    (Gaussian D of roughness m, Schlick F, G = 1) on the planes.  Measured (session 78, 64 x 48, 6 filters): every
    covered pixel within 3.2e-6; no sphere or wall shades the floor (35 floor pixels lie in their shadow)."""
    from warpbw.filtering import Background, render_filtering
    from warpbw.pipeline import render_reference, render_with_planes, split_planes
    from warpbw.scene import parse_scene

    w, h, cam = 48, 36, ((0.0, 1.2, 3.0), (0.0, 0.2, 0.0), 50.0)
    light, e, m = np.array([0.3, 0.8, 0.5]) / np.linalg.norm([0.3, 0.8, 0.5]), 2.0, 0.3
    spheres = [((-0.6, 0.1, 0.0), 0.4, (0.8, 0.0, 0.0)), ((0.0, 1.2, 4.0), 0.3, (0.0, 0.8, 0.0)),
               ((0.0, 0.9, 1.2), 0.15, (0.6, 0.0, 0.0))]
    planes = [((0.0, 0.0, 0.0), 3.0, (0.0, 0.0, 0.8)), ((0.6, 0.4, -0.2), 0.6, (0.0, 0.5, 0.5))]
    wall = [(0.2, -0.2, -0.5), (1.0, -0.2, -0.5), (1.0, 0.8, -0.5), (0.2, 0.8, -0.5)]
    (tmp_path / "wall.obj").write_text("".join(f"v {x} {y} {z}\n" for x, y, z in wall) + "f 1 2 3\nf 1 3 4\n")
    text = (f"[camera]\nposition = {list(cam[0])}\nlook_at = {list(cam[1])}\nfov = {cam[2]}\nresolution = [{w}, {h}]\n"
            f"[[light]]\ntype = \"directional\"\ndirection = {light.tolist()}\nradiance = [{e}, {e}, {e}]\n"
            "[[object]]\nmesh = \"wall.obj\"\nmaterial = \"wall\"\n"
            "[material.wall]\ntype = \"lambert\"\nalbedo = [0.0, 0.7, 0.0]\n")
    for i, (c, r, rho) in enumerate(spheres):
        text += (f"[[object]]\nshape = \"sphere\"\ncenter = {list(c)}\nradius = {r}\nmaterial = \"s{i}\"\n"
                 f"[material.s{i}]\ntype = \"lambert\"\nalbedo = {list(rho)}\n")
    for i, (c, size, rho) in enumerate(planes):
        text += (f"[[object]]\nshape = \"plane\"\ncenter = {list(c)}\nsize = {size}\nmaterial = \"p{i}\"\n"
                 f"[material.p{i}]\ntype = \"cook-torrance\"\nroughness = {m}\nf0 = [0.0, 0.0, 0.0]\n"
                 f"diffuse = {list(rho)}\n")
    scene = parse_scene(text, tmp_path, "mixed.toml")

    o, d = numpy_camera_rays(*cam, w, h)
    dist = [numpy_sphere_distance(o, d, c, r) for c, r, _ in spheres]
    dist += [np.minimum(_numpy_triangle_distance(o, d, *[wall[k] for k in (0, 1, 2)]),
                        _numpy_triangle_distance(o, d, *[wall[k] for k in (0, 2, 3)]))]
    dist += [numpy_square_distance(o, d, size, c) for c, size, _ in planes]
    dist = np.stack(dist)
    near = np.argmin(dist, axis=0)
    covered = np.isfinite(dist.min(axis=0))
    two = np.sort(dist, axis=0)
    with np.errstate(invalid="ignore"):
        clear = ~(two[1] - two[0] < 1e-3)                # not where two surfaces meet (a tie along the ray)
    truth = np.zeros((h, w, 3))
    for k, (c, r, rho) in enumerate(spheres):
        on = covered & (near == k)
        n = (o + dist[k][on][:, None] * d[on] - np.asarray(c)) / r
        truth[on] = np.asarray(rho) / np.pi * e * np.maximum(n @ light, 0.0)[:, None]
    on = covered & (near == 3)
    truth[on] = np.array([0.0, 0.7, 0.0]) / np.pi * e * light[2]          # the wall faces +Z
    for k, (_, _, rho) in enumerate(planes):
        on = covered & (near == 4 + k)
        wo = -d[on]
        hv = (wo + light) / np.linalg.norm(wo + light, axis=-1, keepdims=True)
        f = (1.0 - np.sum(wo * hv, axis=-1)) ** 5                            # Schlick, f0 = 0
        dd = np.exp(-(hv[:, 0] ** 2 + hv[:, 2] ** 2) / m ** 2) / (np.pi * m ** 2)
        truth[on] = e * ((f * dd / (4.0 * wo[:, 1]))[:, None]
                         + np.asarray(rho) / np.pi * (1.0 - f)[:, None] * light[1])
    counts = [int((covered & clear & (near == k)).sum()) for k in range(6)]
    assert counts[1] == 0 and min(counts[k] for k in (0, 2, 3, 4, 5)) >= 10, counts   # each seen, bar the one behind
    assert (np.isfinite(dist[4]) & (near != 4)).sum() > 50 and (np.isfinite(dist[3]) & (near > 3)).sum() > 20

    in_front = covered & (near >= 4)
    hidden = np.isfinite(dist[:4].min(axis=0)) & in_front          # a sphere or the wall behind a plane
    for method in ("toksvig", "ground_truth"):
        res = render_with_planes(scene, method, 64 if method == "ground_truth" else 1)
        assert np.array_equal(res.coverage, covered)
        assert np.array_equal(res.aovs["plane"][clear], in_front[clear])
        assert abs(res.stats["pixels_hidden"] - hidden.sum()) <= (~clear).sum() and hidden[clear].sum() > 20
        assert res.stats["pixels_hidden"] == int((res.aovs["plane"] & np.isfinite(dist[:4].min(axis=0))).sum())
        err = np.abs(res.image - truth).max(axis=-1)[clear]
        assert err.max() < 1e-4 * max(1.0, truth.max()), (method, float(err.max()))
    # the planes over the spheres' and the wall's unclipped G-buffer (Background: camera-space depth), as
    # bench-filtering draws them
    surfaces, only_planes = split_planes(scene)
    behind = render_reference(surfaces, 1)
    drawn = render_filtering(only_planes, "fixed", background=Background(np.zeros((h, w, 3), np.float32),
                                                                         behind.gbuffer.numpy("depth")))
    assert np.array_equal(drawn.coverage[clear], in_front[clear])


_UNIT_MIXED_FRAMES = {}


@settings(max_examples=6, deadline=None)
@given(log_k=st.floats(-4.0, 4.0), method=st.sampled_from(["reference", "adaptive"]))
def test_planes_beside_a_sphere_k_times_brighter_give_k_times_the_frame_with_the_same_decisions(log_k, method):
    """Light is linear: MIXED_SCENE with its sky and its directional light scaled by k (1e-4 to 1e4) renders, through
    render_with_planes, k times the frame with the same planes in front, mip levels and (adaptive) plan.  Measured
    (session 68, 32 x 24, k = 1e-4 ... 1e4): every map identical, image / k within 2.3e-5 of the unit frame."""
    from warpbw.pipeline import render_with_planes
    from warpbw.scene import parse_scene

    k = 10.0 ** log_k

    def frame(scale):
        text = MIXED_SCENE.replace('procedural = "sky"', f'procedural = "sky"\nscale = {scale!r}').replace(
            "radiance = [2.0, 2.0, 2.0]", f"radiance = {[2.0 * scale] * 3}").replace("[48, 32]", "[32, 24]")
        assert f"radiance = {[2.0 * scale] * 3}" in text and f"scale = {scale!r}" in text   # both lights scaled
        kw = {"budget": 2.0} if method == "adaptive" else {}
        return render_with_planes(parse_scene(text, Path.cwd(), "mixed.toml"), "fixed", 4, seed=3, method=method,
                                  mis=True, **kw)

    if method not in _UNIT_MIXED_FRAMES:
        _UNIT_MIXED_FRAMES[method] = frame(1.0)
    one, bright = _UNIT_MIXED_FRAMES[method], frame(float(k))
    cov = one.coverage
    assert one.aovs["plane"].sum() > 100 and (cov & ~one.aovs["plane"]).sum() > 50
    for name in ("plane", "mip_level"):   # geometry: exactly the same
        assert np.array_equal(bright.aovs[name], one.aovs[name]), name
    check = cov
    if method == "adaptive":   # a share within float32 rounding of a step may take the next one (test_adaptive)
        same = cov & (bright.aovs["spp"] == one.aovs["spp"]) & (bright.aovs["shaded"] == one.aovs["shaded"])
        assert same.sum() >= 0.99 * cov.sum() and np.mean(bright.aovs["level"] == one.aovs["level"]) >= 0.99
        if (same != cov).any():   # then compare the planes and the shaded pixels that agree, not those up-sampled
            check = one.aovs["plane"] | (same & one.aovs["shaded"])
    lit = check[..., None] & (one.image > 1e-4 * one.image[cov].max())
    np.testing.assert_allclose(bright.image[lit] / one.image[lit], k, rtol=1e-4)


def test_render_and_info_of_a_scene_with_planes_beside_a_sphere(tmp_path):
    (tmp_path / "cache").mkdir()
    (tmp_path / "mixed.toml").write_text(MIXED_SCENE)
    info = json.loads(run(["info", "mixed.toml", "--json"], tmp_path).stdout)
    assert len(info["objects"]) == 2 and info["objects"][0].startswith("plane")
    assert info["materials"] == {"floor": "cook-torrance", "ball": "lambert"}
    assert any(st.startswith("planes: ") for st in info["stages"]) and any("composite" in st for st in info["stages"])
    # the files a render reads include the planes' (a normal map), not only the spheres and meshes'
    write_exr(tmp_path / "bumps.exr", np.zeros((4, 4, 1), np.float32), channels=["Y"])
    (tmp_path / "bumpy.toml").write_text(MIXED_SCENE.replace('diffuse = [0.5, 0.5, 0.5]\n',
                                                             'diffuse = [0.5, 0.5, 0.5]\nnormal_map = "bumps.exr"\n'))
    bumpy = json.loads(run(["info", "bumpy.toml", "--json"], tmp_path).stdout)
    assert [Path(f).name for f in bumpy["files"]] == ["bumps.exr"]
    out = tmp_path / "m.exr"
    args = ["render", "mixed.toml", "-o", out, "--method", "adaptive", "--budget", "2", "--filter", "toksvig",
            "--spp", "4", "-q"]
    run(args, tmp_path)
    rgb, alpha = rgba(out)
    stats = json.loads(out.with_suffix(".json").read_text())
    assert np.isfinite(rgb).all() and int((alpha > 0).sum()) == stats["pixels_covered"]
    assert stats["method"] == "adaptive" and stats["planes"]["method"] == "toksvig"
    assert 0 < stats["planes"]["pixels_covered"] < stats["pixels_covered"]
    assert stats["time_s"]["frame"] >= stats["time_s"]["planes"] > 0
    mip_exr = read_exr(out.with_suffix(".mip_level.exr"))
    mip, on_plane = mip_exr.pixels[..., 0], mip_exr.pixels[..., 1]
    assert (mip != 0).sum() > 0 and np.all(mip[alpha == 0] == 0)
    # its A marks the plane's pixels, the ones it speaks of
    assert mip_exr.channels == ["Y", "A"] and on_plane.sum() == stats["planes"]["pixels_covered"]
    assert np.all(alpha[on_plane > 0] > 0) and set(np.unique(on_plane)) == {0.0, 1.0}
    for name in ("level", "n_p", "spp", "variance", "shaded", "b_p"):
        assert out.with_suffix(f".{name}.exr").exists() and out.with_suffix(f".{name}.png").exists()
        # the adaptive maps speak of the spheres' pixels alone: a plane pixel is not a sphere pixel read at the
        # coarsest level with N_p 0, up-sampled (session 78: their A was the frame's coverage, planes included)
        aov = read_exr(out.with_suffix(f".{name}.exr")).pixels
        assert np.array_equal(aov[..., 1] > 0, (alpha > 0) & (on_plane == 0)), name
    assert out.with_suffix(".mip_level.png").stat().st_size > 0
    # both renderers' false-colour maps carry their scales (their ranges are checked in the single-renderer tests)
    scales = stats["colour_scales"]
    assert set(scales) == {"level", "n_p", "spp", "variance", "shaded", "b_p", "mip_level"}
    text = Image.open(out.with_suffix(".mip_level.png")).text["Description"]
    assert f"from {scales['mip_level']['from']:.6g} (dark blue) to {scales['mip_level']['to']:.6g}" in text
    before = out.read_bytes()
    r = run(args, tmp_path, check=False)
    assert r.returncode == 2 and "--force" in r.stderr and out.read_bytes() == before


def test_bunny_on_floor_scene_shows_the_bunny_and_the_floor(tmp_path, shared):
    """examples/bunny_on_floor.py writes the README's mixed scene: the shared bunny (NPF) sunk a little into a plane
    with the dunes height field, under forest.exr.  A small render of it (the scene's resolution shrunk) against a
    numpy ray cast of its camera against the floor's square and the OBJ's own vertices: every pixel of the floor
    is covered, the floor is drawn nowhere else, the bunny hides part of it and shows beyond it, and the bunny's
    lowest point lies just below the floor."""
    from conftest import load_example
    from precompute.surfaces import dunes
    from warpbw.pipeline import render_with_planes
    from warpbw.scene import MeshObject, PlaneObject, parse_scene

    mesh, probe, table = (shared(rel) for rel in ("meshes/bunny.obj", "envmaps/forest.exr", "brdf/npf.bin"))
    path = load_example("bunny_on_floor").write_scene(tmp_path, 17)
    text = path.read_text()
    assert text.count("resolution = [256, 192]") == 1
    scene = parse_scene(text.replace("resolution = [256, 192]", "resolution = [64, 48]"), tmp_path, str(path))
    (floor,) = [o for o in scene.objects if isinstance(o, PlaneObject)]
    (bunny,) = [o for o in scene.objects if isinstance(o, MeshObject)]
    assert len(scene.objects) == 2 and bunny.file.resolve() == mesh.resolve()
    assert scene.environment.file.resolve() == probe.resolve()
    gold, sand = scene.materials[bunny.material], scene.materials[floor.material]
    assert (gold.type, gold.table.resolve(), gold.npf_name) == ("npf", table.resolve(), NPF_MATERIAL)
    assert sand.type == "cook-torrance" and sand.normal_map == tmp_path / "dunes.exr"
    np.testing.assert_array_equal(read_exr(sand.normal_map).pixels[..., 0], dunes(17).astype(np.float32))
    # sunk a little: the OBJ's lowest vertex, moved as the scene says, below the floor by under a tenth of its height
    y = np.array([ln.split()[2] for ln in mesh.read_text().splitlines() if ln.startswith("v ")], float)
    y = y * bunny.scale + bunny.translate[1]
    assert 0 < floor.center[1] - y.min() < 0.1 * (y.max() - y.min())

    cam = scene.camera
    o, d = numpy_camera_rays(cam.position, cam.look_at, cam.fov, 64, 48)
    on_floor = np.isfinite(numpy_square_distance(o, d, floor.size, floor.center))
    res = render_with_planes(scene, "fixed", 1)
    drawn = res.aovs["plane"]
    assert on_floor.mean() > 0.5                                  # the floor fills much of the frame
    assert np.array_equal(res.coverage & on_floor, on_floor)     # each of its pixels shows the floor or the bunny
    assert not (drawn & ~on_floor).any()
    hidden = on_floor & ~drawn                                    # the floor's pixels the bunny hides
    assert 0.1 * on_floor.sum() < hidden.sum() < 0.5 * on_floor.sum()
    assert (res.coverage & ~on_floor).sum() > 10                  # the bunny's ears beyond the floor's far edge
    assert res.stats["pixels_hidden"] > 0                         # the floor hides the bunny's sunk part
    assert res.stats["pixels_covered"] == int(res.coverage.sum())


EXAMPLES = sorted((Path(__file__).resolve().parents[1] / "examples").glob("*.py"))


@pytest.mark.parametrize("script", EXAMPLES, ids=lambda p: p.name)
def test_every_example_explains_itself(script, tmp_path):
    """``python examples/X.py --help`` prints a usage line and exits 0 (no traceback, nothing run)."""
    r = subprocess.run([sys.executable, str(script), "--help"], cwd=tmp_path, stdin=subprocess.DEVNULL,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    assert r.stdout.startswith("usage:"), r.stdout[:200]
    assert list(tmp_path.iterdir()) == []


def test_no_plot_goes_through_pyplot():
    """Every plot (the examples', bench's and bench-filtering's) draws on a ``matplotlib.figure.Figure`` of its own:
    no module imports pyplot or calls ``matplotlib.use``.  Through pyplot a plot switched the caller's backend to
    Agg for the rest of its session (a notebook's inline plots stopped showing) and had to close its figure
    whatever happened; 13 examples did (session 82; bench's write_plot since session 81).  Read off the syntax
    trees, so that a comment naming them does not count."""
    import ast

    root = Path(__file__).resolve().parents[1]
    found = []
    for f in sorted(p for d in ("examples", "warpbw", "precompute") for p in (root / d).rglob("*.py")):
        for node in ast.walk(ast.parse(f.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [f"{node.module}.{a.name}" for a in node.names] if isinstance(node, ast.ImportFrom) else []
            if any(n.startswith(("matplotlib.pyplot", "matplotlib.pylab")) for n in names) or (
                    isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "use"
                    and isinstance(node.func.value, ast.Name) and node.func.value.id == "matplotlib"):
                found.append(f"{f.relative_to(root)}:{node.lineno}")
    assert found == []


# A sitecustomize for the children below: a real SIGINT, sent by the child to itself when the script it runs first
# imports numpy, Warp or warpbw's command line (every example imports one of them before its run_command), so that
# the stop lands while it loads, as a Ctrl-C in its first seconds does, at no time left to chance
_SIGINT_AS_IT_LOADS = """\
import os, signal, sys

class _StopAsItLoads:
    def find_spec(self, name, path=None, target=None):
        if name in ("numpy", "warp", "warpbw.cli_common") and sys.argv[0].endswith(".py"):
            sys.meta_path.remove(self)
            os.kill(os.getpid(), signal.SIGINT)
        return None

sys.meta_path.insert(0, _StopAsItLoads())
"""


def test_every_example_says_a_ctrl_c_while_it_loads_in_one_line(tmp_path):
    """A Ctrl-C while an example imports numpy, Warp and warpbw (1 to 18 s on a busy machine, before its
    run_command) printed the traceback of whichever import it stopped, where the warpbw commands say one line
    (processes audit, session 79).  Each example, run as a script and sent SIGINT as it first imports one of them, now
    says "SCRIPT: interrupted" alone and ends by SIGINT (status 130 in a shell), having written nothing."""
    import signal

    (tmp_path / "hook").mkdir()
    (tmp_path / "hook" / "sitecustomize.py").write_text(_SIGINT_AS_IT_LOADS)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path / "hook"), *sys.path]))
    work = tmp_path / "work"
    work.mkdir()
    children = {script.name: subprocess.Popen([sys.executable, str(script), "--help"], cwd=work, env=env,
                                              stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                              text=True,
                                              preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
                for script in EXAMPLES}
    said = {}
    for name, child in children.items():
        out, err = child.communicate(timeout=120)
        said[name] = (child.returncode, err.strip(), out)
    assert said == {name: (-signal.SIGINT, f"{name}: interrupted", "") for name in children}
    assert list(work.iterdir()) == []


def _readme_commands():
    """(program, argv) of every ``warpbw`` / ``warpbw-precompute`` line in the README's code blocks:
    continuation lines joined, comments dropped, optional ``[...]`` groups kept with their first
    alternative (``a|b`` -> a; a group of ``...`` dropped)."""

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    lines = []
    for block in re.findall(r"```[a-z]*\n(.*?)```", readme, re.S):
        for ln in block.splitlines():
            code = ln.split(" #")[0].rstrip()
            if re.match(r"(warpbw|warpbw-precompute) ", code):
                lines.append(code)
            elif lines and code.strip().startswith("[") and ln.startswith(" "):
                lines[-1] += " " + code.strip()
    out = []
    for ln in lines:
        ln = re.sub(r"\[[^\]]*\.\.\.\]", "", ln)
        ln = re.sub(r"\[([^\]]*)\]", r"\1", ln)
        argv = [a.split("|")[0] for a in ln.split()]
        out.append((argv[0], argv[1:]))
    return out


def test_readme_commands_parse():
    """Every command line the README shows is accepted by the command's own parser (flags, choices and
    argument types): the README cannot advertise an option that does not exist."""
    from precompute.__main__ import build_parser as precompute_parser
    from warpbw.cli import build_parser as warpbw_parser

    cmds = _readme_commands()
    assert len(cmds) >= 10, cmds
    parsers = {"warpbw": warpbw_parser(), "warpbw-precompute": precompute_parser()}
    for prog, argv in cmds:
        try:
            parsers[prog].parse_args(argv)
        except SystemExit as exc:
            pytest.fail(f"README: '{prog} {' '.join(argv)}' is refused by its parser (status {exc.code})")


def _documents() -> list:
    """README.md and the Markdown files under docs/."""
    root = Path(__file__).resolve().parents[1]
    return [root / "README.md", *sorted((root / "docs").glob("*.md"))]


def test_inline_commands_in_readme_and_docs_parse():
    """The `warpbw ...` / `warpbw-precompute ...` command lines quoted inline (between backticks) in README.md and
    docs/measurements.md are accepted by their parsers, as the code blocks' are (test_readme_commands_parse): the
    record says how each figure was made, so a renamed option would leave a command nobody can rerun.  Bare
    mentions ("`warpbw bench`", "`warpbw-precompute gmm --prior`") are not command lines and are skipped."""
    import contextlib
    import io

    from precompute.__main__ import build_parser as precompute_parser
    from warpbw.cli import build_parser as warpbw_parser

    checked = 0
    for doc in _documents():
        text = re.sub(r"```.*?```", "", doc.read_text(), flags=re.S)
        for m in re.finditer(r"`((?:warpbw|warpbw-precompute) [^`]+)`", text):
            argv = m.group(1).split()
            if len(argv) < 3 or argv[-1].startswith("--"):
                continue
            parser = warpbw_parser() if argv[0] == "warpbw" else precompute_parser()
            err = io.StringIO()
            try:
                with contextlib.redirect_stderr(err):
                    parser.parse_args(argv[1:])
            except SystemExit:
                pytest.fail(f"{doc.name}: '{' '.join(argv)}' is refused: {err.getvalue().strip()[-200:]}")
            checked += 1
    assert checked >= 5, checked


def _example_commands() -> list:
    """(document, script name, argv) of every ``python examples/X.py ...`` line in README.md and docs/*.md, in code
    blocks and inline: comments dropped, optional ``[...]`` groups kept, placeholders (SCENE, B, DIR) given a
    value that every option type accepts ("1"); a line that elides arguments (``...``) is skipped."""
    import shlex

    out = []
    for doc in _documents():
        text = doc.read_text()
        lines = [ln.split(" #")[0] for block in re.findall(r"```[a-z]*\n(.*?)```", text, re.S)
                 for ln in block.splitlines() if ln.startswith("python examples/")]
        lines += re.findall(r"`(python\s+examples/[^`]+)`", re.sub(r"```.*?```", "", text, flags=re.S))
        for ln in lines:
            argv = shlex.split(re.sub(r"\[([^\]]*)\]", r"\1", ln))
            if "..." not in argv:
                out.append((doc.name, Path(argv[1]).stem, [re.sub(r"^[A-Z]+$", "1", a) for a in argv[2:]]))
    return out


def test_example_commands_in_readme_and_docs_parse(monkeypatch):
    """The ``python examples/X.py ...`` command lines that README.md and docs/measurements.md give are accepted by
    the script's own parser (``_example_parser``: the one its main() builds; nothing is rendered).  A renamed or
    removed option would otherwise leave a recorded figure nobody can reproduce."""
    import argparse
    import contextlib
    import io

    parse = argparse.ArgumentParser.parse_args   # _example_parser replaces it with a stop
    cmds = _example_commands()
    assert len(cmds) >= 30 and len({c[1] for c in cmds}) >= 10, cmds
    parsers = {}
    for doc, name, argv in cmds:
        if name not in parsers:
            parsers[name] = _example_parser(monkeypatch, name)[1]
        err = io.StringIO()
        try:
            with contextlib.redirect_stderr(err):
                parse(parsers[name], argv)
        except SystemExit:
            pytest.fail(f"{doc}: 'python examples/{name}.py {' '.join(argv)}' is refused: "
                        f"{err.getvalue().strip()[-300:]}")


def _example_parser(monkeypatch, name: str):
    """The argument parser examples/NAME.py builds: its main() runs until it parses, and stops there."""
    import argparse

    from conftest import load_example

    class Built(Exception):
        pass

    def stop(self, args=None, namespace=None):
        raise Built(self)

    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", stop)
    monkeypatch.setattr(sys, "argv", [f"{name}.py"])
    mod = load_example(name)
    with pytest.raises(Built) as built:
        mod.main()
    return mod, built.value.args[0]


def _states_default(text: str, default, root: Path):
    """Whether ``text`` (what a help line's "(default ...)" or a usage line's ``[--opt VALUE]`` says) names
    ``default``: True or False, or None where it cannot say (a computed default, a flag, a sentence).  The value
    is the text up to a ";" (and for a single value up to ": " or ", "); lists compare item by item, numbers as
    numbers, paths resolved from the repository root (``../shared/data/...``: the shared data folder, as
    ``warpbw.io.shared_data`` finds it)."""
    if default is None or isinstance(default, bool):
        return None
    head = text.split(";")[0].strip()

    def value(x):
        try:
            return float(x)
        except (TypeError, ValueError):
            return str(x)

    if isinstance(default, (list, tuple)):
        return [value(x) for x in re.split(r"[,\s]+", head) if x] == [value(x) for x in default]
    head = re.split(r": |, ", head)[0].strip()
    if " " in head or not head:
        return None
    if isinstance(default, (int, float)):
        return value(head) == float(default)
    if isinstance(default, Path) or "/" in head:
        from warpbw.io.shared_data import shared_data_dir

        # "../shared/data/..." in a usage line is the shared data folder, $WARPBW_SHARED_DATA where it is set
        head = re.sub(r"^\.\./shared/data(?=/|$)", str(shared_data_dir(root)), head)
        return (root / head).resolve() == (root / Path(default)).resolve()
    return head == str(default)


def _help_default_mismatches(parser, where: str, root: Path) -> tuple:
    """(mismatches, checked) over every option of ``parser`` and its subcommands whose help says
    "(default X)", as --help prints it (``%(default)s`` expanded)."""
    import argparse

    bad, checked = [], 0
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            for name, sub in a.choices.items():
                b, c = _help_default_mismatches(sub, f"{where} {name}", root)
                bad, checked = bad + b, checked + c
            continue
        for said in re.findall(r"\(defaults?:? ([^)]*)\)", parser._get_formatter()._expand_help(a) if a.help else ""):
            same = _states_default(said, a.default, root)
            checked += same is not None
            if same is False:
                bad.append(f"{where} {'/'.join(a.option_strings) or a.dest}: --help says (default {said}), "
                           f"the parser's default is {a.default!r}")
    return bad, checked


def test_every_stated_default_is_the_default(monkeypatch):
    """A default that --help or a script's usage line states is the one the parser applies: the scripts' figures
    are reproduced from what their docs say (brdf_sampling.py's usage line once read ``[--material chrome]``, and
    ran gold-metallic-paint).  Checked: every "(default X)" of warpbw, warpbw-precompute and every example's
    --help, and every ``[--option VALUE]`` of an example's usage line (not a placeholder such as N or DIR)."""
    import ast

    from precompute.__main__ import build_parser as precompute_parser
    from warpbw.cli import build_parser as warpbw_parser

    root = Path(__file__).resolve().parents[1]
    bad, checked = [], 0
    for prog, parser in (("warpbw", warpbw_parser()), ("warpbw-precompute", precompute_parser())):
        b, c = _help_default_mismatches(parser, prog, root)
        bad, checked = bad + b, checked + c
    n_help = checked
    for script in sorted((root / "examples").glob("*.py")):
        mod, parser = _example_parser(monkeypatch, script.stem)
        b, c = _help_default_mismatches(parser, script.name, root)
        bad, checked = bad + b, checked + c
        doc = ast.get_docstring(ast.parse(script.read_text())) or ""
        usage = re.findall(rf"python examples/{script.stem}\.py.*(?:\n {{8}}.*)*", doc)
        options = {o: a for a in parser._actions for o in a.option_strings}
        for text in usage:
            for opt, said in re.findall(r"\[(--[\w-]+) ([^\]\[|]+)\]", re.sub(r" #.*", "", text)):
                assert opt in options, f"{script.name}: the usage line names {opt}, which the parser does not have"
                if said[0].isupper():   # a placeholder: N, DIR, OUT.json
                    continue
                same = _states_default(said.strip(), options[opt].default, root)
                checked += same is not None
                if same is False:
                    bad.append(f"{script.name}: the usage line says [{opt} {said}], the parser's default is "
                               f"{options[opt].default!r}")
    assert not bad, "\n".join(bad)
    assert n_help >= 15 and checked - n_help >= 60, (n_help, checked)   # the rules did read the docs


def _options_whose_default_is_unsaid(parser, where: str, usage: str = "") -> list:
    """Options of ``parser`` and its subcommands with a default (not None or False: a flag, or an option whose
    absence the help describes) whose --help says no "default" and which ``usage`` (a script's usage line) does not
    give as ``[--option VALUE]``."""
    import argparse

    out = []
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            for name, sub in a.choices.items():
                out += _options_whose_default_is_unsaid(sub, f"{where} {name}")
            continue
        if (not a.option_strings or a.default is None or a.default is False or a.default == argparse.SUPPRESS
                or isinstance(a, (argparse._HelpAction, argparse._VersionAction))):
            continue
        said = "default" in (parser._get_formatter()._expand_help(a) if a.help else "")
        if not said and not any(re.search(rf"\[{re.escape(o)} [^\]]+\]", usage) for o in a.option_strings):
            out.append(f"{where} {'/'.join(a.option_strings)} (default {a.default!r})")
    return out


def test_every_option_with_a_default_says_it(monkeypatch):
    """A user reads an option's default in --help (or in a script's usage line, which --help prints): bench_scenes.py
    --out, compare_mitsuba.py --cases and --seed, dynamic_geometry.py --seed and validate_bandwidth.py --data said
    none (compare_mitsuba's "(1024)" said a number, not that it is the default).
    test_every_stated_default_is_the_default holds what they say to the parsers' defaults."""
    import ast

    from precompute.__main__ import build_parser as precompute_parser
    from warpbw.cli import build_parser as warpbw_parser

    root = Path(__file__).resolve().parents[1]
    unsaid = (_options_whose_default_is_unsaid(warpbw_parser(), "warpbw")
              + _options_whose_default_is_unsaid(precompute_parser(), "warpbw-precompute"))
    for script in sorted((root / "examples").glob("*.py")):
        doc = ast.get_docstring(ast.parse(script.read_text())) or ""
        usage = "\n".join(re.findall(rf"python examples/{script.stem}\.py.*(?:\n {{8}}.*)*", doc))
        unsaid += _options_whose_default_is_unsaid(_example_parser(monkeypatch, script.stem)[1], script.name, usage)
    assert not unsaid, "\n".join(unsaid)


def _computed_defaults() -> dict:
    """(command, option) -> the value the code applies where the parser's default is None (the command tells an
    option given from one left out, to refuse what the scene would not use) and --help states it; None where
    --help says a sentence, not a value (all cores, beside --json)."""
    import inspect

    from precompute import batch
    from warpbw import bandwidth, bench, cli, filtering
    from warpbw.upsample import UPSAMPLE_DEFAULT

    adaptive = {"--nb": bandwidth.N_B_DEFAULT, "--nyquist": bandwidth.NYQUIST_FACTOR,
                "--allocation": bandwidth.ALLOCATION_DEFAULT, "--upsample": UPSAMPLE_DEFAULT,
                "--env-signal": bandwidth.ENV_SIGNAL_DEFAULT}
    filter_default = re.search(r'args\.filter or "(\w+)"', inspect.getsource(cli)).group(1)
    seed_default = int(re.search(r"if args\.seed is None:\n\s+args\.seed = (\d+)", inspect.getsource(cli)).group(1))
    out = {("warpbw render", k): v for k, v in adaptive.items()}
    out |= {("warpbw bench", k): v for k, v in adaptive.items() if k != "--nb"}
    out |= {("warpbw render", "--filter"): filter_default, ("warpbw render", "--max-anisotropy"):
            filtering.DEFAULT_ANISOTROPY, ("warpbw render", "--spp"): cli.DEFAULT_SPP,
            ("warpbw render", "--seed"): seed_default, ("warpbw demo", "--spp"): cli.DEMO_SPP,
            ("warpbw demo", "--seed"): 0, ("warpbw bench", "--nb-budget"): bench.NB_SWEEP_BUDGET,
            ("warpbw bench-filtering", "--spp"): cli.DEFAULT_SPP,
            ("warpbw-precompute batch", "--tables"): "both" if tuple(batch.TABLES) == ("sampling", "bandwidth")
            else ",".join(batch.TABLES)}
    out |= {k: None for k in (("warpbw render", "--threads"), ("warpbw demo", "--threads"), ("warpbw bench", "--cache"),
                              ("warpbw bench-filtering", "--cache"), ("warpbw compare", "--error-range"),
                              ("warpbw-precompute batch", "--workers"), ("warpbw-precompute batch", "--json"))}
    return out


def _effective_defaults() -> dict:
    """(command, option) -> the default a command applies, for warpbw and warpbw-precompute: the parser's, or
    _computed_defaults' where the parser's is None."""
    import argparse

    from precompute.__main__ import build_parser as precompute_parser
    from warpbw.cli import build_parser as warpbw_parser

    computed, out = _computed_defaults(), {}
    for prog, parser in (("warpbw", warpbw_parser()), ("warpbw-precompute", precompute_parser())):
        for a in parser._actions:
            if isinstance(a, argparse._SubParsersAction):
                for name, sub in a.choices.items():
                    for b in sub._actions:
                        for o in b.option_strings:
                            key = (f"{prog} {name}", o)
                            out[key] = computed.get(key, b.default) if b.default is None else b.default
    return out


def test_every_default_the_code_computes_is_the_one_help_states():
    """An option whose parser default is None (render's --nb, --nyquist, --spp, --filter; bench's --nb-budget: the
    command fills them in, so that it can refuse one the scene would not use) and whose --help states a default
    states the one the code applies (``_computed_defaults``: bandwidth.N_B_DEFAULT, NYQUIST_FACTOR, ...).
    test_every_stated_default_is_the_default cannot read these: the parser's default says nothing.  Each such option
    is in the table, so a new one must be added."""
    import argparse

    from precompute.__main__ import build_parser as precompute_parser
    from warpbw.cli import build_parser as warpbw_parser

    computed, bad, seen = _computed_defaults(), [], set()
    for prog, parser in (("warpbw", warpbw_parser()), ("warpbw-precompute", precompute_parser())):
        for a in parser._actions:
            if not isinstance(a, argparse._SubParsersAction):
                continue
            for name, sub in a.choices.items():
                for b in sub._actions:
                    helptext = re.sub(r"\s+", " ", sub._get_formatter()._expand_help(b)) if b.help else ""
                    if b.default is not None or "default" not in helptext or not b.option_strings:
                        continue
                    key = (f"{prog} {name}", b.option_strings[-1])
                    seen.add(key)
                    if key not in computed:
                        bad.append(f"{key}: --help states a default the parser does not hold; add it to "
                                   "_computed_defaults")
                        continue
                    if computed[key] is None:
                        continue
                    if b.choices:   # "measured (default; ...)", "log (default), ..."
                        said = re.search(r"(\w+) \(default[;)]", helptext)
                    else:           # "(default 16, 002 Sec. 2.6)", "(1 to 16; default 1: ...)"
                        said = re.search(r"default ([\w.]+)", helptext)
                    same = said is not None and (said.group(1) == str(computed[key]) if isinstance(computed[key], str)
                                                 else float(said.group(1)) == float(computed[key]))
                    if not same:
                        bad.append(f"{key}: --help says {said.group(0) if said else helptext!r}, the code applies "
                                   f"{computed[key]!r}")
    assert not bad, "\n".join(bad)
    assert seen == set(computed), set(computed) - seen   # the table names no option that states no default


def test_the_readmes_bracketed_values_are_the_defaults():
    """README's command lines give an option's default in brackets (``[--gt-spp 8192]``, ``[--components 4]``,
    ``[--nb 16]``): each single value so given is the default the command applies (``_effective_defaults``), but
    for the options listed here, whose brackets show an example (``[--device cuda]``, this machine's ``[--threads
    2]``).  Choices (``[--upsample normal|paper]``), lists, placeholders (``[--cache DIR]``) and the values of an option
    without a default (``[--error-map err.exr]``) are not defaults."""
    examples = {("warpbw render", "--device"), ("warpbw render", "--threads"), ("warpbw info", "--method"),
                ("warpbw-precompute batch", "--workers"), ("warpbw-precompute batch", "--materials")}
    defaults = _effective_defaults()
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    bad, checked = [], 0
    for block in re.findall(r"```[a-z]*\n(.*?)```", readme, re.S):
        cmd = None
        for line in block.splitlines():
            m = re.match(r"(warpbw(?:-precompute)?) ([\w-]+)", line)
            cmd = f"{m.group(1)} {m.group(2)}" if m else cmd if line.startswith(" ") else None
            if cmd is None:
                continue
            for opt, said in re.findall(r"\[(--[\w-]+) ([^\]\[|]+)\]", line.split("#")[0]):
                if (cmd, opt) in examples or said[0].isupper() or "," in said or "..." in said:
                    continue
                assert (cmd, opt) in defaults, f"README: {cmd} has no option {opt}"
                d = defaults[(cmd, opt)]
                if d is None:   # an option without a default: [--error-map err.exr] names an example
                    continue
                same = (said == d) if isinstance(d, str) else float(said) == float(d)
                checked += 1
                if not same:
                    bad.append(f"README: [{opt} {said}] of {cmd}, whose default is {d!r}")
    assert not bad, "\n".join(bad)
    assert checked >= 15, checked


def test_the_constants_the_readme_states_are_the_codes():
    """README states the values of constants a reader relies on (an asset file's version and array shapes, the
    launch's cap, the memory per pixel, triangle and texel, the refusal thresholds).
    test_the_names_the_readme_points_to_exist checks that a named constant is there, not that the number beside it is
    its value: each number here is
    read from README's text and compared with the code's (a figure derived from it, such as GB at 4096 x 4096, to
    the digits README gives).  README said 13 MB per bunny where 200 bytes x 69,666 triangles are 14 MB (decimal,
    as its GB, and as warpbw info prints it)."""
    import math

    from precompute import brdf_bandwidth, brdf_sampling, gmm_mipmap, progress
    from warpbw import bandwidth, bench, brdf, envmap, errors, filtering, gbuffer, launch, pipeline, sampling, scene

    readme = re.sub(r"\s+", " ", (Path(__file__).resolve().parents[1] / "README.md").read_text())

    def said(pattern: str) -> str:
        m = re.search(pattern, readme)
        assert m, f"README no longer says {pattern!r}: update this test with it"
        return m.group(1)

    def near(x: float, value: float, digits: int) -> bool:   # README's x is value to the digits it gives
        return float(f"{value:.{digits}g}") == x

    frame = pipeline.FRAME_BYTES_PER_PIXEL
    checks = {
        "sampling format, version": (said(r"\* `([\w.-]+)`, version \d+ \(`brdf-sampling`\)"),
                                     said(r"`[\w.-]+`, version (\d+) \(`brdf-sampling`\)")) ==
                                    (sampling.TABLE_FORMAT, str(sampling.TABLE_VERSION)),
        "nu_rho format, version": (said(r"\* `([\w.-]+)`, version \d+ \(`brdf`\)"),
                                   said(r"`[\w.-]+`, version (\d+) \(`brdf`\)")) ==
                                  (brdf_bandwidth.FORMAT, str(brdf_bandwidth.VERSION)),
        "GMM format, version": (said(r"\* `([\w.-]+)`, version \d+ \(`gmm`\)"),
                                said(r"`[\w.-]+`, version (\d+) \(`gmm`\)")) ==
                               (gmm_mipmap.GMM_FORMAT, str(gmm_mipmap.GMM_VERSION)),
        "sampling arrays": said(r"(`marginal` \(\d+, \d+\) is the CDF over u, `conditional` \(\d+, \d+, \d+\))")
        == f"`marginal` ({sampling.N_THETA_O}, {sampling.N_U + 1}) is the CDF over u, `conditional` "
           f"({sampling.N_THETA_O}, {sampling.N_U}, {sampling.N_PHI + 1})",
        "sampling density": said(r"`density` (\(\d+, \d+, \d+\))") ==
                            f"({sampling.N_THETA_O}, {sampling.N_U}, {sampling.N_PHI})",
        "view bins": int(said(r"For each of (\d+) view-elevation bins")) == sampling.N_THETA_O,
        "views per bin": int(said(r"view-elevation bins averages the distributions of (\d+) views"))
                         == sampling.VIEW_SUBSAMPLES,
        "nu_rho shape": said(r"`nu_rho` (\(\d+, \d+, \d+\))") == str(brdf_bandwidth.SHAPE),
        "cosine mix": int(said(r"with (\d+)% cosine sampling")) / 100 == brdf.TAB_COSINE_MIX,
        "GT_VERSION": int(said(r"`warpbw\.bench\.GT_VERSION`, which is raised whenever .*?; (\d+): "))
                      == bench.GT_VERSION,
        "launch samples": near(float(said(r"a launch holds at most about (\d+) million samples")) * 1e6,
                               launch.LAUNCH_COST_MAX, 1),
        "launch pixels": int(said(r"and at most ([\d,]+) pixels").replace(",", "")) == launch.PIXELS_PER_TILE,
        "T_EPS_REL": float(said(r"a hit nearer than ([\de.-]+) of that object's size")) == gbuffer.T_EPS_REL,
        "overflow": near(float(said(r"where a light's radiance passes ([\de.]+)")), pipeline.RADIANCE_OVERFLOW_MIN, 2),
        "underflow": near(float(said(r"is below ([\de.-]+) \(`warpbw\.pipeline\.RADIANCE_UNDERFLOW_MAX`")),
                          pipeline.RADIANCE_UNDERFLOW_MAX, 2),
        "frame bytes": said(r"about (\d+ bytes per pixel beyond its assets with the reference method and \d+)")
        == f"{frame['reference']} bytes per pixel beyond its assets with the reference method and {frame['adaptive']}",
        "frame GB": said(r"(\S+ and \S+ GB at 4096 x 4096, \S+ and \S+ GB)") ==
        "{:.2g} and {:.2g} GB at 4096 x 4096, {:.2g} and {:.2g} GB".format(
            *(frame[m] * s * s / 1e9 for s in (4096, scene.MAX_RESOLUTION) for m in ("reference", "adaptive"))),
        "largest resolution": said(r"the largest resolution a scene may ask, (\d+ x \d+)")
                              == f"{scene.MAX_RESOLUTION} x {scene.MAX_RESOLUTION}",
        "probe load": (int(said(r"Loading a probe takes about (\d+) bytes per texel")),
                       float(said(r"32 held \(([\d.]+) GB at 8192 x 4096\)"))) ==
                      (envmap.LOAD_BYTES_PER_TEXEL, round(envmap.LOAD_BYTES_PER_TEXEL * 8192 * 4096 / 1e9, 1)),
        "probe map": (int(said(r"its bandwidth map \(.*?\) about (\d+) bytes per texel")),
                      float(said(r"about \d+ bytes per texel \(([\d.]+) GB\)"))) ==
                     (bandwidth.ENV_BW_BYTES_PER_TEXEL, round(bandwidth.env_bandwidth_memory(8192, 4096) / 1e9, 1)),
        "mesh bytes": (int(said(r"meshes take about (\d+) bytes per triangle")),
                       int(said(r"\((\d+) MB per bunny"))) ==
                      (pipeline.MESH_BYTES_PER_TRIANGLE,
                       round(pipeline.MESH_BYTES_PER_TRIANGLE * int(said(r"Stanford bunny \(([\d,]+) triangles\)")
                                                                    .replace(",", "")) / 1e6)),
        # session 79's estimates (mutation round 12: each halved was read by no test)
        "mesh file bytes": int(said(r"and each file (\d+) more per triangle of its own")) ==
                           pipeline.MESH_FILE_BYTES_PER_TRIANGLE,
        "curvature bytes": int(said(r"derives each mesh's curvature, about (\d+) bytes per triangle")) ==
                           pipeline.CURVATURE_BYTES_PER_TRIANGLE,
        "GMM build": (int(said(r"takes about (\d+) bytes per texel and component")),
                      int(said(r"per texel and component \((\d+) GB for an 8192 x 8192 map at 4 components")))
                     == (gmm_mipmap.BUILD_BYTES_PER_TEXEL_COMPONENT,
                         round(gmm_mipmap.build_memory(8192, 8192, 4) / 1e9)),
        "N_p cap": int(said(r"up to (\d+) times the budget at one pixel \(`N_P_MAX_PER_BUDGET`"))
                   == bandwidth.N_P_MAX_PER_BUDGET,
        "n_b": int(said(r"the \*\*bandwidth pass\*\* \(`warpbw/bandwidth\.py`, n_b = (\d+)"))
               == bandwidth.N_B_DEFAULT,
        "albedo warning": float(said(r"whose directional albedo passes ([\d.]+)")) == brdf_sampling.ALBEDO_WARN,
        "conductor": float(said(r"A conductor's eta and k are at most ([\de.]+)")) == scene.CONDUCTOR_INDEX_MAX,
        "camera far": (near(float(said(r"a sphere's far side beyond ([\de.]+) scene units")), gbuffer.SPHERE_REACH_MAX,
                            2),
                       near(float(said(r"a mesh's beyond ([\de.]+)\)")), gbuffer.MESH_REACH_MAX, 1)),
        "camera near": said(r"that it would land wrong \(([\de.-]+ and [\de.-]+)\)") ==
                       f"{gbuffer.SPHERE_REACH_MIN:.2g} and {gbuffer.MESH_REACH_MIN:.2g}",
        "far from the origin": (said(r"spaces coordinates by more than 1/(\d+) of a sphere's radius"),
                                said(r"that is from [\d,]+ units \(2\^(\d+)\) on")) ==
                               (str(round(1 / errors.COORD_SPACING_REL_MAX)),
                                str(int(math.log2(errors.COORD_SPACING_REL_MAX / 2.0 ** -24)))),
        "map texels": said(r"Maps read from files hold at most (\d+ x \d+ = [\d,]+) texels") ==
                      f"{gmm_mipmap.MAX_MAP_SIDE} x {gmm_mipmap.MAX_MAP_SIDE} = {gmm_mipmap.MAX_MAP_TEXELS:,}",
        "progress interval": float(said(r"a line per state at most every (\d+) s")) == progress.LOG_INTERVAL_S,
        "LOD bias": said(r"\* LOD bias (-log2\(3\)/2):") and filtering.LOD_BIAS == -math.log2(3.0) / 2,
        "anisotropy": said(r"`--max-anisotropy N` on `render` and `bench-filtering`, (1 to \d+)\)")
                      == f"{filtering.DEFAULT_ANISOTROPY} to {filtering.MAX_ANISOTROPY}",
        "ground-truth rays": int(said(r"ground_truth \(--spp >= (\d+) rays per pixel")) == filtering.MIN_GT_SPP,
        "roughness floor": float(said(r"on a flat plane of roughness ([\de.-]+) \(the smallest accepted\)"))
                           == scene.CT_MIN_ROUGHNESS,
    }
    wrong = [k for k, ok in checks.items() if not ok]
    assert not wrong, f"README's figure is not the code's: {wrong}"


def test_every_numeric_options_help_gives_its_range(monkeypatch):
    """An option whose value the command refuses below or above a bound says the range in its --help ("1 to 16",
    "a positive number", "up to 8.39e+06"): render's --nb (1 to 65536), --budget (up to 2^31 / 256), --spp, bench's
    lists and --nb-budget, bench-filtering's --zoom and batch's --workers said none, and a user learnt the bound from
    the refusal (and examples/validate_bandwidth.py's --seed, whose halves add to it).  Probed through each option's
    own argparse type, for warpbw, warpbw-precompute and every example: one that takes "1" (or "64") and refuses "0"
    must say its least value, one that refuses 1e11 its greatest."""
    import argparse

    from precompute.__main__ import build_parser as precompute_parser
    from warpbw.cli import build_parser as warpbw_parser

    def takes(a, s: str) -> bool:
        try:
            a.type(s)
            return True
        except (argparse.ArgumentTypeError, ValueError, TypeError):
            return False

    commands = []
    for prog, parser in (("warpbw", warpbw_parser()), ("warpbw-precompute", precompute_parser())):
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)][0]
        commands += [(f"{prog} {name}", sub) for name, sub in subs.choices.items()]
    for script in sorted((Path(__file__).resolve().parents[1] / "examples").glob("*.py")):
        commands.append((script.name, _example_parser(monkeypatch, script.stem)[1]))
    bad, checked = [], 0
    for name, sub in commands:
        for a in sub._actions:
            if not a.option_strings or a.nargs == 0 or a.choices or a.type is None:
                continue
            least = next((s for s in ("1", "64") if takes(a, s)), None)
            if least is None:
                continue   # not a number: a path, a list of names
            helptext = re.sub(r"\s+", " ", sub._get_formatter()._expand_help(a))
            checked += 1
            if not takes(a, "0") and not re.search(r"positive|\b\d+ to |> ?0|>= ?\d", helptext):
                bad.append(f"{name} {a.option_strings[-1]}: refuses 0, its help gives no least value")
            if not takes(a, "99999999999") and not re.search(r"\bto [\d2-]|up to \d|at most \d|<= ?\d",
                                                              helptext):
                bad.append(f"{name} {a.option_strings[-1]}: refuses 1e11, its help gives no greatest value")
    assert not bad, "\n".join(bad)
    assert checked >= 60, checked


def test_the_readmes_scene_defaults_are_the_loaders(tmp_path):
    """README's plane block gives keys' defaults in its comments (``diffuse ... (default 0)``, ``normal_map_kind =
    "height" # (default)``, ``tiling ... (default 1)``, ``gmm_components ... (default 4, ...)``): a plane material
    that leaves each key out loads with that value (warpbw.scene.load_scene, the loader's own defaults)."""
    from warpbw.scene import load_scene

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    stated = {}
    for block in re.findall(r"```toml\n(.*?)```", readme, re.S):
        for key, value, said in re.findall(r"^(\w+) *= *([^#\n]*?) *#[^\n]*?[(;] ?default\b ?([^,;)]*)", block, re.M):
            stated[key] = said.strip() if said.strip() else value.strip().strip('"')
    assert {"diffuse", "normal_map_kind", "normal_map_scale", "tiling", "gmm_components", "gmm_prior"} <= set(stated)
    Image.fromarray(np.zeros((8, 8), np.uint16)).save(tmp_path / "h.png")
    (tmp_path / "s.toml").write_text(plane_scene_toml('normal_map = "h.png"\n', diffuse=None))
    m = load_scene(tmp_path / "s.toml").materials["m"]
    for key, said in stated.items():
        got = getattr(m, key)
        if isinstance(got, str):
            assert got == said, (key, said, got)
        else:
            assert np.allclose(np.asarray(got, float), float(said)), (key, said, got)


def test_validate_bandwidths_help_gives_every_quick_setting(monkeypatch):
    """validate_bandwidth.py --quick replaces the defaults of QUICK's options: each option's --help says what it
    becomes ("N with --quick"; --uniform-samples, --bis-samples and --window said only their full default).  The
    full defaults are test_every_stated_default_is_the_default's."""
    mod, parser = _example_parser(monkeypatch, "validate_bandwidth")
    helps = {a.dest: parser._get_formatter()._expand_help(a) for a in parser._actions if a.help}
    missing = [k for k, v in mod.QUICK.items() if f"{v} with --quick" not in helps[k]]
    assert len(mod.QUICK) >= 8 and not missing, {k: helps[k] for k in missing}

def _heading_slugs(text: str) -> set:
    """GitHub's anchors for a Markdown file's headings: lower case, punctuation dropped, spaces to hyphens."""

    return {re.sub(r"[^a-z0-9 _-]", "", h.strip().lower()).replace(" ", "-")
            for h in re.findall(r"^#+ (.*)$", text, re.M)}


def test_readme_links_resolve():
    """Every relative link in README.md and docs/*.md names a file of the repository, and its #anchor a heading
    of that file: the README points to docs/measurements.md for the full record, and a moved section would
    otherwise leave a dead link."""

    checked = 0
    for doc in _documents():
        for target in re.findall(r"\]\(([^)\s]+)\)", doc.read_text()):
            if re.match(r"[a-z]+://", target):
                continue
            path, _, anchor = target.partition("#")
            f = (doc.parent / path).resolve() if path else doc
            assert f.is_file(), f"{doc.name}: link to {target!r}, but {f} does not exist"
            if anchor:
                assert anchor in _heading_slugs(f.read_text()), f"{doc.name}: no heading in {f.name} for #{anchor}"
            checked += 1
    assert checked >= 3, checked


def test_the_readme_layout_names_every_module_and_example():
    """README's Layout names the files of warpbw/, warpbw/io/, precompute/ and examples/ (the map a newcomer reads
    first), each under its own folder, and names no file that is not there."""
    root = Path(__file__).resolve().parents[1]
    block = re.search(r"## Layout\n\n```\n(.*?)```", (root / "README.md").read_text(), re.S).group(1)
    named = {}
    folder = None
    for line in block.splitlines():
        folder = re.match(r"([\w/]+/) ", line).group(1) if re.match(r"[\w/]+/ ", line) else folder
        named.setdefault(folder, set()).update(re.findall(r"\b[\w]+\.py\b", line))
    for folder in ("warpbw/", "warpbw/io/", "precompute/", "examples/"):
        there = {p.name for p in (root / folder).glob("*.py")} - {"__init__.py"}
        assert named[folder] == there, (folder, "not named:", there - named[folder], "not there:",
                                        named[folder] - there)


def test_the_readme_says_what_its_first_command_needs():
    """README's first command, ``pip install -e ".[test]"``, is refused on Debian's or Ubuntu's own Python (an
    externally managed environment), and ``warpbw`` is on the PATH only where the environment is active: the README
    says which Python (pyproject's requires-python) and how to make the virtual environment, in a folder git ignores
    (session 76's audit of a fresh clone: it said neither)."""
    root = Path(__file__).resolve().parents[1]
    intro = (root / "README.md").read_text().split("\n## ")[0]
    need = tomllib.loads((root / "pyproject.toml").read_text())["project"]["requires-python"]
    assert re.fullmatch(r">=\d+\.\d+", need), need
    assert f"Python {need[2:]} or later" in intro
    venv = re.search(r"`python3? -m venv (\S+) && \. (\S+)/bin/activate`", intro)
    assert venv and venv.group(1) == venv.group(2), "README's introduction gives no virtual environment to make"
    assert "externally-managed-environment" in intro
    assert f"{venv.group(1)}/" in (root / ".gitignore").read_text().split()


def test_the_readme_names_the_oldest_release_of_every_dependency_that_was_run():
    """README's introduction names, for every dependency pyproject.toml bounds from below (the test extras too), the
    release the suite ran with, and it is the oldest the bound admits: its version begins with the bound's.  A bound
    raised or lowered without the record (session 81: warp-lang>=1.5, trimesh>=4.0 and OpenEXR>=3.3 were declared,
    but their releases failed the suite) fails here; the run itself is README's command, not CI's (old wheels)."""
    root = Path(__file__).resolve().parents[1]
    project = tomllib.loads((root / "pyproject.toml").read_text())["project"]
    intro = (root / "README.md").read_text().split("\n## ")[0]
    record = [p for p in intro.split("\n\n") if p.startswith("pyproject.toml's lower bounds are releases the code was "
                                                              "run with: on 20")]
    assert len(record) == 1, "README's introduction does not say which releases the bounds were checked with"
    ran = {}   # the first release named of each (the paragraph goes on to Python 3.10's newer ones)
    for name, version in re.findall(r"([A-Za-z][\w-]*) (\d+(?:\.\d+)+)\b", record[0]):
        ran.setdefault(name.lower(), version)
    bounds = [re.fullmatch(r"([\w-]+)>=([\d.]+)(; .*)?", req) for req in
              project["dependencies"] + project["optional-dependencies"]["test"]]
    assert all(bounds), bounds
    for name, bound, _ in (b.groups() for b in bounds):
        version = ran.get(name.lower())
        assert version is not None, f"README does not say which {name} release was run"
        assert version == bound or version.startswith(bound + "."), (name, bound, version)


def test_the_folders_the_readmes_commands_write_are_ignored_by_git():
    """Every folder README's commands write into the repository (an example's ``--out DIR``, ``-o DIR`` of demo, batch
    and filtering_zoom.py) is one .gitignore names: a newcomer who follows README keeps a clean ``git status``
    (session 76's audit: mixed/, bench/, bench_out/, dyn/, val/, zoom_out/ and tables/ were not)."""
    root = Path(__file__).resolve().parents[1]
    readme = (root / "README.md").read_text()
    folders = set(re.findall(r"--out ([\w/-]+)", readme)) | set(re.findall(r" -o ([\w/-]+)(?=[\s`])", readme))
    ignored = (root / ".gitignore").read_text().split()
    missing = sorted(f for f in folders if f"/{f.split('/')[0]}/" not in ignored)
    assert {"warpbw_demo", "mixed", "tables", "zoom_out"} <= folders and not missing, (folders, missing)


def test_ci_runs_the_hypothesis_examples_derandomized_and_a_local_run_draws_new_ones(request):
    """A CI run ($CI set, as CI services and .ci/run set it) takes tests/conftest.py's profile "ci": the same examples
    on every run (derandomize), no example database; a local run keeps Hypothesis's "default", new examples each
    time (session 81; docs/testing.md).  The profile this run took is the one its environment names."""
    from hypothesis import settings

    from conftest import hypothesis_profile

    for value, profile in (("true", "ci"), ("1", "ci"), ("True", "ci"), ("", "default"), ("false", "default"),
                           ("0", "default"), (None, "default")):
        assert hypothesis_profile({} if value is None else {"CI": value}) == profile, value
    ci = settings.get_profile("ci")
    assert ci.derandomize and ci.database is None and ci.print_blob and ci.deadline is None
    assert not settings.get_profile("default").derandomize
    chosen = settings.get_profile(hypothesis_profile(os.environ))
    if request.config.getoption("hypothesis_profile") is None:   # not chosen on the command line
        assert (settings().derandomize, settings().database is None) == (chosen.derandomize, chosen.database is None)
    assert "CI=true" in (Path(__file__).resolve().parents[1] / ".ci" / "run").read_text()


def test_every_module_lists_its_public_functions_in_its_docstring():
    """DESIGN.md's convention, 'a module's public functions are listed in its docstring': every function or class
    of warpbw/ and precompute/ whose name does not start with _ is named in its module's docstring, the Warp
    functions, kernels and structs the stages are built of included (a researcher testing one kernel reads them
    there)."""
    import ast

    root = Path(__file__).resolve().parents[1]
    modules = sorted([*(root / "warpbw").rglob("*.py"), *(root / "precompute").rglob("*.py")])
    unlisted, checked = {}, 0
    for path in modules:
        tree = ast.parse(path.read_text())
        doc = ast.get_docstring(tree) or ""
        names = [n.name for n in tree.body if isinstance(n, (ast.FunctionDef, ast.ClassDef))
                 and not n.name.startswith("_")]
        checked += len(names)
        missing = [n for n in names if not re.search(rf"\b{n}\b", doc)]
        if missing:
            unlisted[str(path.relative_to(root))] = missing
    assert checked > 100 and not unlisted, unlisted



def test_a_modules_all_holds_every_public_function():
    """Where a module of warpbw/ or precompute/ spells ``__all__``, it holds every function and class its docstring
    lists as public (no name starting with _), and nothing it lacks: ``from M import *`` gives what the docstring
    promises (precompute.brdf_bandwidth's left out lobe_slice and slice_bandwidth; session 80)."""
    import ast
    import importlib

    root = Path(__file__).resolve().parents[1]
    wrong, checked = {}, 0
    for path in sorted([*(root / "warpbw").rglob("*.py"), *(root / "precompute").glob("*.py")]):
        tree = ast.parse(path.read_text())
        if not any(isinstance(n, ast.Assign) and any(getattr(t, "id", None) == "__all__" for t in n.targets)
                   for n in tree.body):
            continue
        mod = importlib.import_module(".".join(path.relative_to(root).with_suffix("").parts).removesuffix(".__init__"))
        public = {n.name for n in tree.body if isinstance(n, (ast.FunctionDef, ast.ClassDef))
                  and not n.name.startswith("_")}
        checked += 1
        bad = sorted(public - set(mod.__all__)) + [f"{a} (absent)" for a in mod.__all__ if not hasattr(mod, a)]
        if bad:
            wrong[mod.__name__] = bad
    assert checked >= 3 and not wrong, wrong

def _call_arguments(text: str) -> list:
    """The arguments of a call as a docstring writes it (``a, b=(0, 0), c: int = 1, ...``), split at its top-level
    commas."""
    out, depth, cur = [], 0, ""
    for ch in text:
        depth += (ch in "([{") - (ch in ")]}")
        if ch == "," and depth == 0:
            out.append(cur.strip())
            cur = ""
        else:
            cur += ch
    return [a for a in [*out, cur.strip()] if a]


def test_every_signature_a_module_docstring_shows_is_the_functions():
    """A call a module's docstring shows, ``f(a, b=1)``, names parameters ``f`` has, and a default it states is
    ``f``'s: a researcher calls the stage functions by the names the docstring lists (assetfile's listed
    ``check_float_arrays(arrays, what, rebuild_hint)``, whose parameter is ``hint``; brdf_bandwidth's
    ``nu_rho_max(n)``, whose parameter is ``resolution``: either keyword was a TypeError)."""
    import ast
    import importlib
    import inspect

    root = Path(__file__).resolve().parents[1]
    bad, checked = [], 0
    for path in sorted([*(root / "warpbw").rglob("*.py"), *(root / "precompute").glob("*.py")]):
        name = ".".join(path.relative_to(root).with_suffix("").parts).removesuffix(".__init__")
        mod = importlib.import_module(name)
        doc = re.sub(r"\s*\n\s*", " ", mod.__doc__ or "")
        for m in re.finditer(r"(?<![\w.])([A-Za-z_]\w*)\(((?:[^()]|\([^()]*\))*)\)", doc):
            obj = getattr(mod, m.group(1), None)
            if obj is None or not (getattr(obj, "__module__", None) == mod.__name__ or hasattr(obj, "func")):
                continue   # a formula (``cos(theta)``) or another module's function
            try:
                params = inspect.signature(getattr(obj, "func", obj)).parameters   # a Warp function's Python body
            except (TypeError, ValueError):
                continue
            if any(p.kind == p.VAR_KEYWORD for p in params.values()):
                continue
            for arg in _call_arguments(m.group(2)):
                said = re.fullmatch(r"(\w+)\s*(?::[^=]*)?(?:=\s*(.+))?", arg)
                if not said or arg == "...":
                    continue
                checked += 1
                p, default = said.groups()
                if p not in params:
                    bad.append(f"{name}: {m.group(0)[:80]}: {m.group(1)} has no parameter {p} ({', '.join(params)})")
                elif default is not None and default != "...":
                    try:
                        value = ast.literal_eval(default)
                    except ValueError:
                        value = getattr(mod, default)   # a named constant
                    if value != params[p].default:
                        bad.append(f"{name}: {m.group(1)}: the docstring says {p}={default}, the default is "
                                   f"{params[p].default!r}")
    assert checked > 500 and not bad, "\n".join(bad)


def test_readme_python_example_runs(tmp_path):
    """The README's ``python`` block runs as written, in a fresh interpreter in a folder where warpbw demo has
    written its scene (here at a smaller resolution, so that it runs in seconds): a renamed function, result field
    or stats key would otherwise leave a newcomer's first script broken.  Its stderr has no Warp line: the
    no-CUDA-driver line that ``wp.init()`` prints on a machine without a GPU was kept off the command lines only."""
    from warpbw.scene import DEFAULT_SCENE_TOML

    blocks = re.findall(r"```python\n(.*?)```", (Path(__file__).resolve().parents[1] / "README.md").read_text(), re.S)
    assert blocks
    small = DEFAULT_SCENE_TOML.replace("resolution = [384, 256]", "resolution = [48, 32]")
    assert small != DEFAULT_SCENE_TOML
    (tmp_path / "warpbw_demo").mkdir()
    (tmp_path / "warpbw_demo" / "scene.toml").write_text(small)
    r = subprocess.run([sys.executable, "-c", "\n".join(blocks)], cwd=tmp_path, stdin=subprocess.DEVNULL,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert re.match(r"\d+\.\d dB, shaded \d+%, frame ", r.stdout), r.stdout
    assert "Warp" not in r.stderr and "Traceback" not in r.stderr, r.stderr
    n_p = read_exr(tmp_path / "n_p.exr")
    assert n_p.channels == ["Y"] and n_p.pixels.shape == (32, 48, 1) and n_p.pixels.max() >= 1


def test_readme_plane_block_accepts_the_gmm_its_comment_builds(tmp_path, monkeypatch):
    """The README's plane block says where its ``gmm`` file comes from ("from warpbw-precompute gmm scales.exr --scale
    0.05 -o scales.gmm", and that a file of another map, kind, scale, components or prior is refused): that command,
    run on a small height field, builds a mipmap the block's material takes as it is.  A block whose scale, kind,
    components or prior moved away from its comment would be refused here, as it is for a newcomer who runs it."""
    from precompute.__main__ import main as precompute_main
    from precompute.surfaces import hemispherical_scales
    from warpbw.filtering import prepare_filtering
    from warpbw.scene import parse_scene

    blocks = re.findall(r"```toml\n(.*?)```", (Path(__file__).resolve().parents[1] / "README.md").read_text(), re.S)
    plane = next(b for b in blocks if 'shape = "plane"' in b)
    camera = re.search(r"\[camera\].*?(?=\n\[[^\[])", blocks[0], re.S).group(0)
    command = re.search(r"from warpbw-precompute (gmm [^(\n]*?)\s*\n", plane).group(1).split()
    assert "-o" in command and command[command.index("-o") + 1] == re.search(r'gmm = "([^"]+)"', plane).group(1)
    normal_map = re.search(r'normal_map = "([^"]+)"', plane).group(1)
    write_exr(tmp_path / normal_map, hemispherical_scales(24).astype(np.float32), channels=["Y"])
    monkeypatch.chdir(tmp_path)
    assert precompute_main([*command, "-q"]) == 0
    scene = parse_scene(camera.replace("resolution = [512, 512]", "resolution = [16, 12]") + "\n" + plane, tmp_path,
                        "README.md")
    import precompute.gmm_mipmap as gmm_mipmap

    def no_build(*args, **kwargs):   # the file must be taken as it is, not rebuilt
        raise AssertionError("the README's gmm file was not used")

    monkeypatch.setattr(gmm_mipmap, "build_gmm_mipmap", no_build)
    prepared = prepare_filtering(scene, methods=("gmm_aligned",))
    assert list(prepared.mips) == ["armour"]


def _names_not_there(text: str, root: Path) -> list:
    """What ``text`` names in backticks for a reader to look up and the repository does not have: a dotted name
    (``warpbw.shading.LAUNCH_COST_MAX``) that does not import or lacks that attribute, a bare constant
    (``MESH_BYTES_PER_TRIANGLE``) that no module of warpbw/ or precompute/ defines and no Python file of the
    repository quotes (an environment variable such as ``WARP_CACHE_PATH``), a file path (``warpbw/upsample.py``)
    that is not a file, and a test (``test_the_reference_agrees_with_mitsuba``) that is neither a test function nor
    a module under tests/."""
    import importlib

    dotted = set(re.findall(r"`((?:warpbw|precompute)(?:\.\w+)+)(?:\([^`]*\))?`", text))
    constants = set(re.findall(r"`([A-Z][A-Z0-9_]{4,})`", text))
    paths = set(re.findall(r"`((?:warpbw|precompute|examples|tests|docs)/[\w/]+\.(?:py|md))`", text))
    tests = set(re.findall(r"`(test_\w+)`", text))
    missing, absent = [], object()
    for name in sorted(dotted):
        parts = name.split(".")
        for cut in range(len(parts), 0, -1):   # the longest importable prefix, then attributes
            try:
                obj = importlib.import_module(".".join(parts[:cut]))
            except ModuleNotFoundError:
                continue
            for attr in parts[cut:]:
                obj = getattr(obj, attr, absent)
            if obj is absent:
                missing.append(name)
            break
    defined = "\n".join(f.read_text() for d in ("warpbw", "precompute") for f in (root / d).rglob("*.py"))
    quoted = "\n".join(f.read_text() for d in ("warpbw", "precompute", "examples", "tests")
                       for f in (root / d).rglob("*.py"))
    missing += [c for c in sorted(constants)
                if not re.search(rf"^{c} *[:=]", defined, re.M) and not re.search(rf"[\"']{c}[\"']", quoted)]
    missing += [p for p in sorted(paths) if not (root / p).is_file()]
    test_src = "\n".join(f.read_text() for f in (root / "tests").glob("*.py"))
    missing += [n for n in sorted(tests)
                if not re.search(rf"^\s*def {n}\(", test_src, re.M) and not (root / "tests" / f"{n}.py").is_file()]
    return missing


def test_the_names_the_readme_points_to_exist():
    """What the README names in backticks for a reader to look up is there (``_names_not_there``): a dotted name
    (``warpbw.shading.LAUNCH_COST_MAX``, ``warpbw.scene.check_scene``), a bare constant (``MESH_BYTES_PER_TRIANGLE``),
    a file path (``warpbw/upsample.py``, ``tests/test_lights.py``), a test.  A renamed constant or moved module would
    otherwise leave the README pointing at nothing."""
    root = Path(__file__).resolve().parents[1]
    readme = (root / "README.md").read_text()
    assert len(re.findall(r"`(?:warpbw|precompute)(?:\.\w+)+`", readme)) >= 10
    assert len(set(re.findall(r"`([A-Z][A-Z0-9_]{4,})`", readme))) >= 2
    assert len(set(re.findall(r"`((?:warpbw|precompute|examples|tests|docs)/[\w/]+\.(?:py|md))`", readme))) >= 10
    missing = _names_not_there(readme, root)
    assert not missing, f"README names what is not there: {missing}"


def test_the_names_the_docs_point_to_exist():
    """The same for docs/measurements.md and docs/testing.md, which name the constants, functions, files and tests
    a figure or an audit finding rests on (``warpbw.bench.speedup_relative_se``, ``warpbw.io.merl.horizon_bins``,
    ``test_the_reference_agrees_with_mitsuba``): testing.md still named `REL_EPS`, the relative allocation's floor
    that session 68 replaced with ``REL_FLOOR``."""
    root = Path(__file__).resolve().parents[1]
    bad, checked = {}, 0
    for doc in sorted((root / "docs").glob("*.md")):
        text = doc.read_text()
        checked += len(set(re.findall(r"`((?:warpbw|precompute)(?:\.\w+)+|[A-Z][A-Z0-9_]{4,}|test_\w+)`", text)))
        missing = _names_not_there(text, root)
        if missing:
            bad[doc.name] = missing
    assert checked >= 40 and not bad, (checked, bad)


def test_a_prepared_scene_keeps_its_own_copy_of_the_scene():
    """prepare_scene shared the caller's Scene: a camera resized afterwards failed the next frame inside numpy
    (the camera on the device was the old one), an object appended was ignored.  The prepared scene now holds a
    checked copy: its frames are those of the scene as prepared."""
    from dataclasses import replace

    from warpbw.pipeline import prepare_scene, render_reference
    from warpbw.scene import SphereObject, default_scene

    s = default_scene()
    s.camera = replace(s.camera, width=24, height=16)
    prep = prepare_scene(s)
    before = render_reference(prep, spp=2, seed=5)
    s.camera = replace(s.camera, width=40, height=20)
    s.objects.append(SphereObject((0.0, 0.0, 2.0), 0.5, s.objects[0].material))
    after = render_reference(prep, spp=2, seed=5)
    assert after.image.shape == (16, 24, 3) and np.array_equal(after.image, before.image)
    assert prep.scene is not s and len(prep.scene.objects) == len(s.objects) - 1


def test_a_budget_below_one_sample_per_shaded_pixel_is_one_warning_line(tmp_path):
    """The renderer warns (warpbw.pipeline) and the command line prints it once, as one line.  (A Lambert sphere
    under the procedural sky: no bandwidth table to build, a small map to analyse.)"""
    (tmp_path / "s.toml").write_text(
        '[camera]\nposition = [0.0, 0.0, 4.0]\nlook_at = [0.0, 0.0, 0.0]\nfov = 35.0\nresolution = [48, 32]\n'
        '[environment]\nprocedural = "sky"\n[[object]]\nshape = "sphere"\nradius = 1.0\nmaterial = "m"\n'
        '[material.m]\ntype = "lambert"\nalbedo = 0.5\n')
    r = run(["render", "s.toml", "-o", "a.exr", "--method", "adaptive", "--budget", "0.01", "-q"], tmp_path)
    lines = r.stderr.splitlines()
    assert len(lines) == 1 and re.match(r"warpbw: warning: budget 0\.01 is below 1 sample\(s\) per shaded pixel ",
                                        lines[0]), r.stderr


def test_adaptive_samples_per_covered_pixel_divides_by_the_covered_pixels():
    """samples_per_covered_pixel divides by the covered pixels, not every pixel.  ``warpbw bench`` records this
    figure (warpbw/bench.py); its test mocks the renderer, so nothing checked the renderer's own.  Truth: the
    definition, from the frame's own sample count and its coverage image, on a sphere that leaves most of the
    image empty (308 of 576 pixels covered: the two denominators differ by a factor 1.9)."""
    from test_shading import sphere_scene

    from warpbw.pipeline import render_adaptive

    res = render_adaptive(sphere_scene('type = "lambert"\nalbedo = [0.5, 0.5, 0.5]', w=24, h=24), budget=4.0, seed=1)
    covered = int(res.coverage.sum())
    assert 0 < covered < 0.6 * res.coverage.size
    assert res.stats["samples"] > 0
    assert res.stats["samples_per_covered_pixel"] == pytest.approx(res.stats["samples"] / covered, rel=1e-12)


def test_a_frame_with_planes_times_both_renderers(tmp_path, monkeypatch):
    """time_s.frame of a scene with planes beside a sphere is the sum of the two frames: the spheres' and the planes'.
    The planes' frame is made to report 100 s more than it took, so a frame time that left it out cannot reach it."""
    import dataclasses

    from warpbw import filtering
    from warpbw.pipeline import render_with_planes
    from warpbw.scene import parse_scene

    real = filtering.render_filtering
    took = []

    def slow(*a, **k):
        r = real(*a, **k)
        took.append(r.time_s + 100.0)
        return dataclasses.replace(r, time_s=took[-1])

    monkeypatch.setattr(filtering, "render_filtering", slow)
    res = render_with_planes(parse_scene(MIXED_SCENE, tmp_path, "mixed.toml"), "fixed", 4, mis=True)
    ts = res.stats["time_s"]
    assert len(took) == 1 and ts["planes"] == pytest.approx(took[0], abs=1e-5)
    assert ts["frame"] >= ts["planes"] + ts["shading"] - 1e-5
    assert ts["frame"] < ts["planes"] + 60.0


_ENV_SCENE = lambert_sphere_scene(16, 12)


# a plane under a sky (the option tests hand its --spp to the environment) and a light
_PLANE_SCENE = plane_scene_toml(resolution=(16, 12), environment="[environment]\nconstant = [1.0, 1.0, 1.0]\n")


@pytest.fixture
def env_scene(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("WARPBW_CACHE", str(tmp_path / "_cache"))
    (tmp_path / "s.toml").write_text(_ENV_SCENE)
    (tmp_path / "p.toml").write_text(_PLANE_SCENE)
    return tmp_path


def test_render_adaptive_hands_each_option_to_render_adaptive(env_scene, monkeypatch):
    """Every option of ``render --method adaptive`` must reach ``render_adaptive`` under the keyword it names,
    with the value given: an option parsed but dropped on the way would render with the default and say
    nothing."""
    import warpbw.pipeline as pipeline
    from warpbw.cli import main

    got = capture_call(monkeypatch, pipeline, "render_adaptive")
    with pytest.raises(Handed):
        main(["render", "s.toml", "-o", "o.exr", "--method", "adaptive", "--budget", "3.5", "--nb", "40", "--mis",
              "--seed", "17", "--allocation", "sqrt", "--nyquist", "3", "--upsample", "paper",
              "--env-signal", "log", "--threads", "2", "-q"])
    assert got["budget"] == 3.5 and got["n_b"] == 40 and got["mis"] is True and got["seed"] == 17
    assert got["allocation"] == "sqrt" and got["nyquist"] == 3.0 and got["upsample"] == "paper"
    assert got["env_signal"] == "log" and got["threads"] == 2 and got["progress"] is False


def test_render_reference_hands_spp_seed_mis_and_quiet_on(env_scene, monkeypatch):
    """``render`` (reference): --spp, --seed, --mis and -q must reach ``render_reference`` as spp, seed, mis and
    progress; without them, the --help defaults (spp as --help prints it, seed 0, no MIS, a progress bar)."""
    import warpbw.pipeline as pipeline
    from warpbw.cli import build_parser, main

    got = capture_call(monkeypatch, pipeline, "render_reference")
    with pytest.raises(Handed):
        main(["render", "s.toml", "-o", "o.exr", "--spp", "5", "--seed", "9", "--mis", "-q"])
    assert (got["spp"], got["seed"], got["mis"], got["progress"]) == (5, 9, True, False)
    got.clear()
    with pytest.raises(Handed):
        main(["render", "s.toml", "-o", "o.exr"])
    sub = next(a for a in build_parser()._actions if hasattr(a, "choices") and isinstance(a.choices, dict))
    helped = int(re.search(r"default (\d+)", next(a.help for a in sub.choices["render"]._actions
                                                  if "--spp" in a.option_strings)).group(1))
    assert (got["spp"], got["seed"], got["mis"], got["progress"]) == (helped, 0, False, True)
    seed_help = next(a.help for a in sub.choices["render"]._actions if "--seed" in a.option_strings)
    assert "0 to 2^32-1" in seed_help, seed_help
    for seed in (0, 2**32 - 1):   # both ends --help names parse and arrive as given (the default 0 is not parsed)
        got.clear()
        with pytest.raises(Handed):
            main(["render", "s.toml", "-o", "o.exr", "--seed", str(seed), "-q"])
        assert got["seed"] == seed


def test_render_of_planes_hands_filter_spp_seed_and_anisotropy_on(env_scene, monkeypatch):
    """``render`` of a scene of planes: --filter, --spp (the environment's pairs), --seed and --max-anisotropy
    must reach ``render_filtering``; without --filter the method is gmm_aligned, as --help says."""
    import warpbw.filtering as filtering
    from warpbw.cli import main

    got = capture_call(monkeypatch, filtering, "render_filtering")
    with pytest.raises(Handed):
        main(["render", "p.toml", "-o", "o.exr", "--filter", "toksvig", "--spp", "7", "--seed", "3",
              "--max-anisotropy", "4", "-q"])
    assert got["_args"][1] == "toksvig" and got["env_spp"] == 7 and got["seed"] == 3 and got["max_anisotropy"] == 4
    got.clear()
    with pytest.raises(Handed):
        main(["render", "p.toml", "-o", "o.exr", "-q"])
    assert got["_args"][1] == "gmm_aligned"


def test_bench_hands_each_option_to_run_bench(env_scene, monkeypatch):
    """Every option of ``bench`` must reach ``run_bench``: the sweeps, the n_b sweep, --no-mis, the seed and the
    adaptive options (which every adaptive frame of the sweep must use)."""
    import warpbw.bench as bench
    from warpbw.cli import main

    got = capture_call(monkeypatch, bench, "run_bench")
    with pytest.raises(Handed):
        main(["bench", "s.toml", "--json", "b.json", "--spp", "2,8", "--budgets", "1,3", "--nb", "16,32",
              "--nb-budget", "5", "--gt-spp", "128", "--runs", "4", "--no-mis", "--seed", "11",
              "--allocation", "uniform", "--nyquist", "4", "-q"])
    assert got["spp_list"] == [2, 8] and got["budgets"] == [1.0, 3.0] and list(got["nb_list"]) == [16, 32]
    assert got["nb_budget"] == 5.0 and got["gt_spp"] == 128 and got["runs"] == 4 and got["mis"] is False
    assert got["seed"] == 11 and got["adaptive_options"] == {"allocation": "uniform", "nyquist": 4.0}
    got.clear()
    with pytest.raises(Handed):
        main(["bench", "s.toml", "--json", "b.json", "-q"])
    assert got["mis"] is True and got["seed"] == 0 and got["runs"] == 3   # --help: MIS, seed 0, 3 runs


def test_bench_filtering_hands_each_option_to_run_bench_filtering(env_scene, monkeypatch):
    """Every option of ``bench-filtering`` must reach ``run_bench_filtering``; without --spp the environment's
    pairs are 64 (--help: 'default 64, as warpbw render') and without --max-anisotropy one probe."""
    import warpbw.bench_filtering as bf
    from warpbw.cli import main

    got = capture_call(monkeypatch, bf, "run_bench_filtering")
    with pytest.raises(Handed):
        main(["bench-filtering", "p.toml", "--json", "f.json", "--zoom", "1,3", "--gt-spp", "96", "--spp", "6",
              "--runs", "2", "--seed", "5", "--flicker-pairs", "3", "--max-anisotropy", "8", "-q"])
    assert got["zooms"] == [1.0, 3.0] and got["gt_spp"] == 96 and got["env_spp"] == 6 and got["runs"] == 2
    assert got["seed"] == 5 and got["flicker_pairs"] == 3 and got["max_anisotropy"] == 8
    got.clear()
    with pytest.raises(Handed):
        main(["bench-filtering", "p.toml", "--json", "f.json", "-q"])
    assert got["env_spp"] == 64 and got["max_anisotropy"] == 1 and got["flicker_pairs"] == 1 and got["runs"] == 3


def test_info_hands_method_on(env_scene, monkeypatch):
    """``info --method adaptive`` must summarise the stages of an adaptive frame, not the reference's."""
    import warpbw.pipeline as pipeline
    from warpbw.cli import main

    got = capture_call(monkeypatch, pipeline, "scene_summary")
    with pytest.raises(Handed):
        main(["info", "s.toml", "--method", "adaptive"])
    assert got["_args"][1] == "adaptive"


# the same sphere under one directional light instead of the sky: exact, no samples
_LIGHT_SCENE = _ENV_SCENE.replace("[environment]\nconstant = [1.0, 1.0, 1.0]",
                                  '[[light]]\ntype = "directional"\ndirection = [0.3, 0.8, 1.0]\n'
                                  "radiance = [0.2, 0.15, 0.1]")
assert _LIGHT_SCENE != _ENV_SCENE


def test_render_exposure_sets_the_preview_in_stops(tmp_path, monkeypatch):
    """--exposure E (stops) must reach the PNG preview: the preview of a render at E = 1 is the preview of the same
    radiance doubled (what 'one stop' means), and a render without --exposure previews at 0 stops ('default 0')
    -- while the EXR, the radiance itself, does not change with it."""
    from warpbw.cli import main
    from warpbw.io.exr import write_png

    monkeypatch.chdir(tmp_path)
    (tmp_path / "l.toml").write_text(_LIGHT_SCENE)   # lights alone: exact, no samples, fast
    assert main(["render", "l.toml", "-o", "a.exr", "-q"]) == 0
    assert main(["render", "l.toml", "-o", "b.exr", "--exposure", "1", "-q"]) == 0
    a, b = read_exr(tmp_path / "a.exr").pixels, read_exr(tmp_path / "b.exr").pixels
    assert np.array_equal(a, b)
    rgb = a[..., :3]
    write_png(tmp_path / "x0.png", rgb, exposure=0.0)
    write_png(tmp_path / "x1.png", 2.0 * rgb, exposure=0.0)
    png = {n: np.asarray(Image.open(tmp_path / f"{n}.png").convert("RGB"), dtype=np.int32)
           for n in ("a", "b", "x0", "x1")}
    assert png["a"].sum() > 0 and png["b"].sum() > png["a"].sum()
    assert np.abs(png["a"] - png["x0"]).max() <= 1
    assert np.abs(png["b"] - png["x1"]).max() <= 1


def test_compare_error_map_default_scale_spans_six_decades(tmp_path, monkeypatch, capsys):
    """compare --error-map, without --error-range: --help promises a log colour scale 'from 10^-6 times the map's
    largest value ... to the largest'.  With errors spread over ten decades, the range it reports must be exactly
    [1e-6 * largest, largest], not wider (the smallest errors would swamp the map) or narrower."""
    from warpbw.cli import main

    monkeypatch.chdir(tmp_path)
    ref = np.full((4, 6, 4), 0.5, np.float32)
    test = ref.copy()
    test[1, 1, :3] += 1.0e-5     # relative squared error ~4e-10
    test[2, 4, :3] += 1.0        # ~3.85
    write_exr(tmp_path / "ref.exr", ref, channels=["R", "G", "B", "A"])
    write_exr(tmp_path / "test.exr", test, channels=["R", "G", "B", "A"])
    assert main(["compare", "test.exr", "ref.exr", "--json", "--error-map", "err.exr"]) == 0
    j = json.loads(capsys.readouterr().out)
    hi = 1.0 ** 2 / (0.25 + 0.01)
    assert j["error_range"] == pytest.approx([1e-6 * hi, hi], rel=1e-4)


INFO_CAMERA = """\
[camera]
position = [0.0, 0.0, 4.0]
look_at = [0.0, 0.0, 0.0]
fov = 40.0
resolution = [24, 16]
"""
INFO_SKY = '[environment]\nconstant = [1.0, 1.0, 1.0]\n'
INFO_SPHERE = '[[object]]\nshape = "sphere"\nradius = 0.5\nmaterial = "paint"\n'
INFO_MESH = '[[object]]\nmesh = "tri.obj"\nmaterial = "paint"\n'
INFO_PAINT = '[material.paint]\ntype = "lambert"\nalbedo = 0.5\n'
INFO_SHINY = '[material.shiny]\ntype = "ggx"\nalpha = 0.2\nspecular = [0.5, 0.5, 0.5]\n'
INFO_LIGHT = '[[light]]\ntype = "directional"\ndirection = [0.0, 1.0, 0.0]\nradiance = [1.0, 1.0, 1.0]\n'
INFO_LIGHT2 = '[[light]]\ntype = "directional"\ndirection = [1.0, 0.0, 0.0]\nradiance = [0.5, 0.5, 0.5]\n'


def _info_scene(tmp_path, *parts, name="s.toml"):
    from warpbw.scene import load_scene

    (tmp_path / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    p = tmp_path / name
    p.write_text("\n".join(parts))
    return load_scene(p)


def test_info_text_shows_every_line_of_the_summary(tmp_path, monkeypatch, capsys):
    """The text of ``warpbw info``: width x height (24 x 16, as the scene writes [width, height]), the environment's
    source, rotation and scale, one line per light, per object and per file, and every stage (the same list as
    ``--json`` prints), the last being the shading."""
    from warpbw.cli import main

    monkeypatch.chdir(tmp_path)
    write_exr(tmp_path / "sky.exr", np.full((4, 8, 3), 0.5, np.float32))
    env = '[environment]\nfile = "sky.exr"\nrotation = 30.0\nscale = 2.0\n'
    _info_scene(tmp_path, INFO_CAMERA, env, INFO_LIGHT, INFO_LIGHT2, INFO_SPHERE, INFO_MESH, INFO_PAINT)
    assert main(["info", "s.toml"]) == 0
    text = capsys.readouterr().out
    assert main(["info", "s.toml", "--json"]) == 0
    j = json.loads(capsys.readouterr().out)
    lines = text.splitlines()
    assert "resolution  24 x 16" in lines, text
    assert f"environment file {tmp_path / 'sky.exr'}, rotation 30 deg, scale 2" in lines, text
    assert [ln for ln in lines if ln.startswith("light ")] == [
        "light       directional towards [0.0, 1.0, 0.0] radiance [1.0, 1.0, 1.0]",
        "light       directional towards [1.0, 0.0, 0.0] radiance [0.5, 0.5, 0.5]"], text
    objects = lines[lines.index("objects") + 1:lines.index("objects") + 3]
    assert objects[0].startswith("  - sphere r=0.5") and objects[1].startswith(f"  - mesh {tmp_path / 'tri.obj'}")
    files = lines[lines.index("files") + 1:]
    assert files == [f"  - {tmp_path / 'sky.exr'}", f"  - {tmp_path / 'tri.obj'}"], text
    stages = next(ln for ln in lines if ln.startswith("stages      "))
    assert stages == "stages      " + "; ".join(j["stages"]) and len(j["stages"]) == 3, (stages, j["stages"])
    assert j["stages"][-1].startswith("reference shading"), j["stages"]


def test_summary_names_only_the_geometry_stages_the_scene_uses(tmp_path):
    """The G-buffer stage names analytic spheres only where the scene has a sphere and the mesh BVH only where it has
    a mesh (a frame records "gbuffer:spheres", "gbuffer:mesh_bvh"), and the mesh curvature only in an adaptive
    frame of a scene with a mesh."""
    from warpbw.pipeline import scene_summary

    spheres = _info_scene(tmp_path, INFO_CAMERA, INFO_SKY, INFO_SPHERE, INFO_PAINT)
    mesh = _info_scene(tmp_path, INFO_CAMERA, INFO_SKY, INFO_MESH, INFO_PAINT, name="m.toml")
    both = _info_scene(tmp_path, INFO_CAMERA, INFO_SKY, INFO_SPHERE, INFO_MESH, INFO_PAINT, name="b.toml")
    assert scene_summary(spheres)["stages"][0] == "gbuffer (analytic spheres)"
    assert scene_summary(mesh)["stages"][0] == "gbuffer (mesh BVH)"
    res = outcome(scene_summary, spheres, "fast")
    assert res.startswith("WarpbwError: method 'fast'"), res
    assert scene_summary(both)["stages"][0] == "gbuffer (analytic spheres + mesh BVH)"
    assert not any(st.startswith("mesh curvature") for st in scene_summary(spheres, "adaptive")["stages"])
    assert sum(st.startswith("mesh curvature") for st in scene_summary(mesh, "adaptive")["stages"]) == 1


def test_summary_lists_tabulated_sampling_for_a_merl_material_and_only_the_used_kinds(tmp_path):
    """A MERL material is sampled from tables as an NPF one is (a frame records "tabulated_sampling"); the BRDF
    stage names the kinds the objects use, not an unused material's."""
    from warpbw.pipeline import scene_summary

    (tmp_path / "m.binary").write_bytes(b"not read by info")
    merl = '[material.paint]\ntype = "merl"\nfile = "m.binary"\n'
    s = scene_summary(_info_scene(tmp_path, INFO_CAMERA, INFO_SKY, INFO_SPHERE, merl))
    assert "brdf: merl" in s["stages"] and "tabulated importance sampling (002 Sec. 3.3)" in s["stages"], s["stages"]
    s = scene_summary(_info_scene(tmp_path, INFO_CAMERA, INFO_SKY, INFO_SPHERE, INFO_PAINT, INFO_SHINY, name="u.toml"))
    assert s["stages"][1] == "brdf: lambert" and s["unused_materials"] == ["shiny"], s


def test_summary_of_a_sky_and_a_sun_shades_both(tmp_path):
    """Under an environment and directional lights, the shading stage names both light terms (a frame records
    "light:environment+directional"), for either method."""
    from warpbw.pipeline import scene_summary

    sc = _info_scene(tmp_path, INFO_CAMERA, INFO_SKY, INFO_LIGHT, INFO_SPHERE, INFO_PAINT)
    for method, word in (("reference", "reference shading"), ("adaptive", "hierarchical shading")):
        (shade,) = [st for st in scene_summary(sc, method)["stages"] if st.startswith(word)]
        assert "environment light" in shade and "directional lights exact" in shade, (method, shade)


def test_summary_of_planes_beside_a_sphere_gives_the_spheres_renderer_its_own_materials(tmp_path):
    """Planes beside a sphere: the spheres' renderer compiles the sphere's Lambert kind only (the planes' Cook-Torrance
    is the filtering renderer's), and the floor's material is used, not unused."""
    from warpbw.pipeline import scene_summary

    s = scene_summary(_info_scene(tmp_path, MIXED_SCENE))
    assert "spheres and meshes: brdf: lambert" in s["stages"], s["stages"]
    assert s["unused_materials"] == [] and s["materials"] == {"floor": "cook-torrance", "ball": "lambert"}


def _rgba(value, h=4, w=8, alpha=None):
    px = np.zeros((h, w, 4), np.float32)
    px[..., :3] = value
    px[..., 3] = 1.0 if alpha is None else alpha
    return px


def test_compare_reads_the_coverage_of_the_test_image_when_the_reference_has_none(tmp_path, monkeypatch, capsys):
    """--help: the covered pixels are the reference's A channel, else the test image's, else non-black pixels.  A render
    compared with a reference that has no A channel (from another renderer): its A channel still says which
    pixels count.  Here the images differ only where A = 0, so over the covered pixels they are identical."""
    from warpbw.cli import main

    monkeypatch.chdir(tmp_path)
    alpha = np.ones((4, 8), np.float32)
    alpha[:, 0] = 0.0
    test = _rgba(0.5, alpha=alpha)
    test[:, 0, :3] = 3.0
    write_exr(tmp_path / "test.exr", test, channels=["R", "G", "B", "A"])
    write_exr(tmp_path / "ref.exr", np.full((4, 8, 3), 0.5, np.float32))
    assert main(["compare", "test.exr", "ref.exr", "--json"]) == 0
    j = json.loads(capsys.readouterr().out)
    assert j["pixels"] == 28 and j["relmse"] == 0.0 and j["mse"] == 0.0, j
    # and says so, since the image judged then chose the pixels it is judged on
    assert j["coverage_from"] == "test.exr"
    assert main(["compare", "test.exr", "ref.exr"]) == 0
    assert "coverage from test.exr's A channel (ref.exr has none)" in capsys.readouterr().out
    assert main(["compare", "ref.exr", "test.exr", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["coverage_from"] == "test.exr"   # the reference's A


def test_compare_places_each_image_in_its_display_window(tmp_path, monkeypatch, capsys):
    """An EXR's display window is the image's frame and its data window the pixels stored (OpenEXR, Technical
    Introduction): one picture, its background rows 0 and 4 black with A = 0, stored as rows 0-3 (the reference) and
    as rows 1-4 (the test), is one image.  Compared as stored arrays, row for row, each test row met the next
    reference row (relMSE 1.59 where it is 0); stored as rows 1-3 only (auto-cropped), the test was refused as 8x3
    against 8x4.  Files written by OpenEXR itself."""
    import OpenEXR

    from warpbw.cli import main

    monkeypatch.chdir(tmp_path)
    picture = np.zeros((5, 8, 4), np.float32)
    picture[1:4, :, :3] = np.random.default_rng(3).uniform(0.2, 2.0, (3, 8, 3))
    picture[1:4, :, 3] = 1.0

    def write(name, rows):
        windows = {"dataWindow": (np.array([0, rows[0]], np.int32), np.array([7, rows[-1]], np.int32)),
                   "displayWindow": (np.array([0, 0], np.int32), np.array([7, 4], np.int32))}
        OpenEXR.File(windows, {c: np.ascontiguousarray(picture[rows[0]:rows[-1] + 1, :, i])
                               for i, c in enumerate("RGBA")}).write(name)

    write("ref.exr", [0, 3])
    for test in ([1, 4], [1, 3]):
        write("test.exr", test)
        assert main(["compare", "test.exr", "ref.exr", "--json"]) == 0
        j = json.loads(capsys.readouterr().out)
        assert j["pixels"] == 24 and j["relmse"] == 0.0 and j["psnr_db"] is None, (test, j)


def test_compare_json_prints_the_keys_its_help_lists(tmp_path, monkeypatch, capsys):
    """compare --json's --help lists the record's keys: every key it prints, with --error-map and for identical
    images (psnr_note) too, is among them (error_map and error_range were not)."""
    from warpbw.cli import build_parser, main

    monkeypatch.chdir(tmp_path)
    write_exr(tmp_path / "a.exr", _rgba(0.5))
    write_exr(tmp_path / "b.exr", _rgba(0.25))
    keys = set()
    for argv in (["a.exr", "b.exr", "--error-map", "e.exr"], ["a.exr", "a.exr"]):
        assert main(["compare", *argv, "--json"]) == 0
        keys |= set(json.loads(capsys.readouterr().out))
    sub = next(a for a in build_parser()._actions if a.dest == "command").choices["compare"]
    listed = set(re.findall(r"\b[a-z]+_?[a-z_]*\b", next(a.help for a in sub._actions if a.dest == "json")))
    assert {"psnr_note", "error_map", "error_range", "coverage_from"} <= keys and keys <= listed, keys - listed


def test_compare_counts_the_pixels_the_reference_covers_even_where_the_test_misses_them(tmp_path, monkeypatch,
                                                                                          capsys):
    """'truth.exr: a render at high --spp' (README): the reference says where the geometry is.  A test render that
    misses a sphere (A = 0 and black there) is wrong at those pixels: they are compared, (0 - 0.5)^2 / 0.26 at
    each of the 4 of 32, and not dropped as the test's own A channel would drop them."""
    from warpbw.cli import main

    monkeypatch.chdir(tmp_path)
    ref = _rgba(0.5)
    test = ref.copy()
    test[1, 2:6] = 0.0            # RGB and A: the test image does not cover these four pixels
    write_exr(tmp_path / "ref.exr", ref, channels=["R", "G", "B", "A"])
    write_exr(tmp_path / "test.exr", test, channels=["R", "G", "B", "A"])
    assert main(["compare", "test.exr", "ref.exr", "--json"]) == 0
    j = json.loads(capsys.readouterr().out)
    assert j["pixels"] == 32 and j["relmse"] == pytest.approx(4 * 0.25 / 0.26 / 32, rel=1e-6), j


def test_compare_without_alpha_counts_a_pixel_black_in_the_test_only(tmp_path, monkeypatch, capsys):
    """Without A channels, 'non-black pixels' of either image count: a test that misses geometry (black where the
    reference is not) is wrong there, and the pixel must be in the figures: (0 - 0.5)^2 / (0.25 + 0.01) over 32."""
    from warpbw.cli import main

    monkeypatch.chdir(tmp_path)
    test = np.full((4, 8, 3), 0.5, np.float32)
    test[2, 3] = 0.0
    write_exr(tmp_path / "test.exr", test)
    write_exr(tmp_path / "ref.exr", np.full((4, 8, 3), 0.5, np.float32))
    assert main(["compare", "test.exr", "ref.exr", "--json"]) == 0
    j = json.loads(capsys.readouterr().out)
    assert j["pixels"] == 32 and j["relmse"] == pytest.approx(0.25 / 0.26 / 32, rel=1e-6), j


def test_compare_ignores_non_finite_values_outside_the_covered_pixels(tmp_path, monkeypatch, capsys):
    """The figures are 'over covered pixels' (the refusal itself says 'non-finite values over covered pixels'):
    a NaN where A = 0 is not compared and not refused; one in a covered pixel is refused in one line naming
    the image."""
    from warpbw.cli import main

    monkeypatch.chdir(tmp_path)
    alpha = np.ones((4, 8), np.float32)
    alpha[0, 0] = 0.0
    ref = _rgba(0.5, alpha=alpha)
    test = ref.copy()
    test[0, 0, :3] = np.nan
    write_exr(tmp_path / "ref.exr", ref, channels=["R", "G", "B", "A"])
    write_exr(tmp_path / "test.exr", test, channels=["R", "G", "B", "A"])
    assert main(["compare", "test.exr", "ref.exr", "--json"]) == 0
    j = json.loads(capsys.readouterr().out)
    assert j["pixels"] == 31 and j["relmse"] == 0.0
    test[1, 1, 0] = np.nan
    write_exr(tmp_path / "bad.exr", test, channels=["R", "G", "B", "A"])
    assert main(["compare", "bad.exr", "ref.exr"]) == 2
    err = capsys.readouterr().err
    assert err == "warpbw: error: bad.exr: 1 non-finite values over covered pixels\n", err


def test_compare_text_prints_the_relative_mse_and_names_the_map(tmp_path, monkeypatch, capsys):
    """The text figures: 'relMSE' is the relative MSE, mean of (t - r)^2 / (r^2 + 0.01) = 0.01 / 0.26 at every
    pixel (not the MSE, 0.01); the error map line names the EXR given to --error-map, with its PNG beside it."""
    from warpbw.cli import main

    monkeypatch.chdir(tmp_path)
    write_exr(tmp_path / "ref.exr", np.full((4, 8, 3), 0.5, np.float32))
    test = np.full((4, 8, 3), 0.6, np.float32)
    test[0, 0] = 0.7   # a second error value: the map has a colour scale to print
    write_exr(tmp_path / "test.exr", test)
    assert main(["compare", "test.exr", "ref.exr", "--error-map", "err.exr"]) == 0
    out = capsys.readouterr().out
    rel = (31 * (0.1 ** 2) + 0.2 ** 2) / 0.26 / 32
    assert f"relMSE {rel:.6g}\n" in out, out
    assert "\nerror map err.exr (+ err.png, log colour scale " in out, out


# -------------------------------------------------------------------------------- what render and demo print and write
# (mutation round 8: each test fails on a plausible mistake the suite let through)


# Stand-in renderers draw 6x4 frames whose figures are known. The scene files are the ones above at 6x4, and
# conftest's MIXED_SCENE (whose size the stand-ins ignore).
H, W = 4, 6
COV = np.zeros((H, W), bool)   # the stand-ins' coverage: 12 of the 24 pixels (the left half)
COV[:, :3] = True


@pytest.fixture
def small_scenes(env_scene, monkeypatch):
    """Scene files in env_scene's working folder, the command's clock a stand-in (only the stand-in renders move
    it)."""
    import warpbw.cli as cli

    tmp_path = env_scene
    (tmp_path / "env.toml").write_text(lambert_sphere_scene(6, 4))
    (tmp_path / "light.toml").write_text(_LIGHT_SCENE.replace("resolution = [16, 12]", "resolution = [6, 4]"))
    (tmp_path / "plane.toml").write_text(plane_scene_toml(resolution=(6, 4)))
    (tmp_path / "mixed.toml").write_text(MIXED_SCENE)
    clock = StandInClock()
    monkeypatch.setattr(cli, "time", clock)
    return SimpleNamespace(dir=tmp_path, clock=clock)


def _image(cov=COV):
    img = np.zeros((H, W, 3), np.float32)
    img[cov] = [0.5, 0.25, 0.125]
    return img


def _fake_reference(monkeypatch, clock, stats, took=4.0, cov=COV):
    import warpbw.pipeline as pipeline

    def fake(scene, spp=1, seed=0, mis=False, **kw):
        clock.now += took
        return SimpleNamespace(image=_image(cov), coverage=cov.copy(), stats=json.loads(json.dumps(stats)))

    monkeypatch.setattr(pipeline, "render_reference", fake)


def _lines(out: str, start: str) -> str:
    return next(x for x in out.splitlines() if x.startswith(start))


def test_render_reference_summary_gives_each_figure_in_its_unit(small_scenes, monkeypatch, capsys):
    """The reference render's summary gives each figure in its unit: the G-buffer in ms, samples per second in millions,
    the command's total wall time (the stand-in clock's 4 s), also in the JSON."""
    from warpbw.cli import main

    stats = {"time_s": {"gbuffer": 0.0123, "shading": 1.5, "frame": 1.5123}, "resolution": [W, H],
             "pixels_covered": 12, "samples_per_second": 2.5e6, "spp": 8}
    _fake_reference(monkeypatch, small_scenes.clock, stats, took=4.0)
    assert main(["render", "env.toml", "-o", "o.exr", "--spp", "8"]) == 0
    out = capsys.readouterr().out
    assert _lines(out, "o.exr") == f"o.exr  ({W}x{H}, 8 spp, 12 covered pixels)"
    # 12.3 ms of G-buffer, 2.5 million samples per second, and the command's own 4 s (the stand-in clock)
    assert _lines(out, "  gbuffer") == "  gbuffer 12.3 ms, shading 1.500 s (2.50 M samples/s), total 4.00 s"
    assert json.loads(Path("o.json").read_text())["time_s"]["total"] == pytest.approx(4.0)
    assert _lines(out, "  preview") == "  preview o.png, stats o.json"


def test_render_of_lights_alone_does_not_print_a_sample_count(small_scenes, capsys):
    """A frame of directional lights takes no sample, whatever the default --spp is."""
    from warpbw.cli import main

    assert main(["render", "light.toml", "-o", "l.exr"]) == 0
    out = capsys.readouterr().out
    assert json.loads(Path("l.json").read_text())["spp"] == 0
    first = out.splitlines()[0]
    assert "directional lights alone: exact, no samples" in first and " spp" not in first, first


def _aovs(cov=COV):
    """Per-pixel AOVs with a known range over the covered pixels, and other values outside them."""
    yy, xx = np.mgrid[0:H, 0:W]
    level = np.where(cov, yy % 3, 7).astype(np.float32)                       # 0..2 covered
    n_p = np.where(cov, np.where(level == 0, 16, 2 ** level), 0).astype(np.float32)   # 2, 4, 16 covered
    variance = np.where(cov, 0.001 * (1 + xx + yy), 9.0).astype(np.float32)   # 0.001 .. 0.006 covered
    variance[0, 0] = 0.0                                                      # no estimate there: not on a log scale
    shaded = np.where(cov, (level == 0), 0).astype(np.float32)
    spp = np.where(shaded > 0, n_p * (1 + xx % 2), 0).astype(np.float32)      # 0 (up-sampled); 16, 32 shaded
    b_p = np.where(cov, 0.05 * (1 + yy), 0).astype(np.float32)               # 0.05 .. 0.2
    return {"level": level, "n_p": n_p, "spp": spp, "variance": variance, "shaded": shaded, "b_p": b_p}


def _scale(v, cov, log):
    shown = v[cov & (v > 0)] if log else v[cov]
    return float(shown.min()), float(shown.max())


def test_render_adaptive_summary_and_colour_scales_by_hand(small_scenes, monkeypatch, capsys):
    """The adaptive render's summary and colour scales, worked by hand from stand-in AOVs: shaded pixels and their
    percentage, the bandwidth pass in ms with its share, the AOV files, each scale's range over the covered pixels (log
    scales over the positive ones), and a zero on a log scale drawn black, not as its smallest value."""
    import warpbw.pipeline as pipeline
    from warpbw.cli import main

    aovs = _aovs()
    stats = {"time_s": {"gbuffer": 0.002, "bandwidth": 0.004, "shading": 0.02, "upsampling": 0.001,
                        "hierarchy": 0.003, "frame": 0.032}, "resolution": [W, H], "n_b": 16,
             "pixels_covered": 12, "pixels_shaded": 3, "shaded_fraction": 0.25, "samples": 36,
             "samples_per_covered_pixel": 3.0, "bandwidth_time_fraction": 0.125}

    def fake(scene, budget=None, **kw):
        small_scenes.clock.now += 0.5
        return SimpleNamespace(image=_image(), coverage=COV.copy(), stats=json.loads(json.dumps(stats)),
                               aovs={k: v.copy() for k, v in aovs.items()})

    monkeypatch.setattr(pipeline, "render_adaptive", fake)
    assert main(["render", "env.toml", "-o", "a.exr", "--method", "adaptive", "--budget", "3"]) == 0
    out = capsys.readouterr().out
    assert _lines(out, "a.exr") == f"a.exr  ({W}x{H}, adaptive, budget 3 spp, n_b 16, 12 covered pixels)"
    assert _lines(out, "  shaded") == "  shaded 3 pixels (25.0%), 36 samples (3.00 per covered pixel)"
    assert _lines(out, "  gbuffer") == ("  gbuffer 2.0 ms, bandwidth 4.0 ms (12.5% of the frame), shading 0.020 s, "
                                        "up-sampling 1.0 ms, frame 0.032 s, total 0.50 s")
    assert _lines(out, "  AOVs") == ("  AOVs a.level.exr, a.n_p.exr, a.spp.exr, a.variance.exr, a.shaded.exr, "
                                     "a.b_p.exr (+ .png)")
    want = {}
    for name, log in (("level", False), ("n_p", True), ("spp", True), ("variance", True), ("shaded", False),
                      ("b_p", True)):
        lo, hi = _scale(aovs[name], COV, log)
        want[name] = (lo, hi, log)
        assert read_exr(Path(f"a.{name}.exr")).pixels[..., 0] == pytest.approx(aovs[name])
        assert Path(f"a.{name}.png").stat().st_size > 0
    line = _lines(out, "  colour scales")
    assert line == "  colour scales (dark blue to yellow): " + ", ".join(
        f"{n} {lo:.3g} to {hi:.3g}" + (" (log)" if log else "") for n, (lo, hi, log) in want.items())
    # a log scale cannot show a zero: the covered pixel of variance 0 is black ("not shown", the PNG's own text),
    # not dark blue, which the scale says is its smallest value

    with Image.open("a.variance.png") as im:
        assert "black: not shown" in im.text["Description"]
        px = np.asarray(im.convert("RGB"))
    assert not px[0, 0].any() and px[0, 1].any() and not px[:, 3:].any()
    scales = json.loads(Path("a.json").read_text())["colour_scales"]
    for name, (lo, hi, log) in want.items():
        assert scales[name] == {"png": f"a.{name}.png", "scale": "log" if log else "linear",
                                "from": pytest.approx(lo), "to": pytest.approx(hi)}


def test_render_adaptive_refuses_to_replace_an_aov_left_alone(small_scenes, monkeypatch, capsys):
    """The AOVs are outputs like the image ("Nothing the user has is overwritten without --force")"""
    import warpbw.pipeline as pipeline
    from warpbw.cli import main

    capture_call(monkeypatch, pipeline, "render_adaptive")   # reaching it fails the test
    Path("a.b_p.png").write_bytes(b"mine")
    assert outcome(main, ["render", "env.toml", "-o", "a.exr", "--method", "adaptive", "--budget", "3", "-q"]) == \
        "returned 2"
    assert "a.b_p.png: already exists" in capsys.readouterr().err
    assert Path("a.b_p.png").read_bytes() == b"mine" and not Path("a.exr").exists()


def test_demo_refuses_to_replace_an_edited_scene_file_alone(small_scenes, monkeypatch, capsys):
    """Demo writes DIR/scene.toml "to edit"; an edited one is the user's, even where the images are gone."""
    import warpbw.pipeline as pipeline
    from warpbw.cli import main

    capture_call(monkeypatch, pipeline, "render_reference")   # reaching it fails the test
    Path("d").mkdir()
    Path("d/scene.toml").write_text("# my edit\n")
    assert outcome(main, ["demo", "-o", "d", "-q"]) == "returned 2"
    assert "scene.toml: already exists" in capsys.readouterr().err
    assert Path("d/scene.toml").read_text() == "# my edit\n" and not Path("d/demo.exr").exists()


def test_demo_next_command_runs_as_printed_from_a_folder_with_a_space(small_scenes, monkeypatch, capsys):
    """The "next:" command demo prints parses as the shell splits it, from an output folder with a space too (a path
    with a space split in two, as the rebuild hints once did)."""
    import shlex

    from warpbw.cli import build_parser, main

    stats = {"time_s": {"gbuffer": 0.001, "shading": 0.01, "frame": 0.011}, "resolution": [W, H],
             "pixels_covered": 12, "samples_per_second": 1e6, "spp": 4}
    _fake_reference(monkeypatch, small_scenes.clock, stats, took=1.0)
    assert main(["demo", "-o", "my out", "--spp", "4"]) == 0
    line = _lines(capsys.readouterr().out, "next: ")
    argv = shlex.split(line[len("next: "):])
    assert argv[0] == "warpbw", line
    try:
        args = build_parser().parse_args(argv[1:])
    except SystemExit as exc:   # argparse's usage error: the printed command does not run
        raise AssertionError(f"{line!r} does not parse (exit {exc.code})") from None
    assert (args.command, args.scene, args.output, args.method, args.budget) == (
        "render", str(Path("my out") / "scene.toml"), str(Path("my out") / "adaptive.exr"), "adaptive", 4.0)
    assert Path("my out/scene.toml").is_file()
    # from README's first command's folder, the line README quotes (it wrote adaptive.* into the working folder, where
    # demo's own line writes them beside the demo's: session 76's audit)
    assert main(["demo", "-o", "warpbw_demo", "--spp", "4"]) == 0
    line = _lines(capsys.readouterr().out, "next: ")
    readme = re.sub(r"\s+", " ", (Path(__file__).resolve().parents[1] / "README.md").read_text())
    assert f"`{line[len('next: '):]}`" in readme, line


def _fake_filtering(monkeypatch, clock, level, cov=COV, time_s=0.0125, stats_extra=None):
    import warpbw.filtering as filtering

    def fake(scene, method, spp=None, seed=0, **kw):
        clock.now += 2.0
        st = {"method": method, "resolution": [W, H], "pixels_covered": int(cov.sum()),
              "mean_level": float(level[cov].mean()) if cov.any() else 0.0, **(stats_extra or {})}
        return SimpleNamespace(image=_image(cov), coverage=cov.copy(), level=level.copy(), time_s=time_s, stats=st)

    monkeypatch.setattr(filtering, "render_filtering", fake)


def test_render_of_planes_summary_and_level_map_by_hand(small_scenes, monkeypatch, capsys):
    """The planes' render summary by hand: the mean mip level over the covered pixels (1.5; over all 24 pixels 0.75),
    the frame in ms, the level map's scale over the covered pixels."""
    from warpbw.cli import main

    level = np.where(COV, 1.0 + np.arange(W)[None, :] * 0.5, 0.0).astype(np.float32)   # 1, 1.5, 2 covered; 0 outside
    _fake_filtering(monkeypatch, small_scenes.clock, level)
    assert main(["render", "plane.toml", "-o", "p.exr", "--filter", "toksvig"]) == 0
    out = capsys.readouterr().out
    # the mean mip level over the 12 pixels the plane covers: (1 + 1.5 + 2) / 3 = 1.50 (over all 24 pixels: 0.75)
    assert _lines(out, "p.exr") == f"p.exr  ({W}x{H}, filter toksvig, mean mip level 1.50, 12 covered pixels)"
    assert _lines(out, "  frame") == "  frame 12.5 ms, total 2.00 s"
    assert _lines(out, "  preview") == "  preview p.png, stats p.json, mip level p.level.exr (+ .png)"
    assert _lines(out, "  colour scales") == "  colour scales (dark blue to yellow): level 1 to 2"
    # in another folder, the level map named with it, as the preview is (it said "mip level p.level.exr": session 76)
    assert main(["render", "plane.toml", "-o", str(Path("sub", "p.exr")), "--filter", "toksvig"]) == 0
    sub = {k: Path("sub", f"p.{k}") for k in ("png", "json", "level.exr")}
    assert _lines(capsys.readouterr().out, "  preview") == \
        f"  preview {sub['png']}, stats {sub['json']}, mip level {sub['level.exr']} (+ .png)"
    st = json.loads(Path("p.json").read_text())
    assert st["time_s"] == {"frame": 0.0125, "total": 2.0}
    assert st["colour_scales"]["level"]["from"] == 1.0 and st["colour_scales"]["level"]["to"] == 2.0


def test_render_of_planes_ground_truth_summary_gives_the_rays_asked_for(small_scenes, monkeypatch, capsys):
    """--filter ground_truth traces --spp rays per pixel (--help), and the summary says how many."""
    from warpbw.cli import main

    level = np.where(COV, 1.0, 0.0).astype(np.float32)
    _fake_filtering(monkeypatch, small_scenes.clock, level)
    assert main(["render", "plane.toml", "-o", "g.exr", "--filter", "ground_truth", "--spp", "128"]) == 0
    out = capsys.readouterr().out
    assert _lines(out, "g.exr") == f"g.exr  ({W}x{H}, filter ground_truth, 128 rays/pixel, 12 covered pixels)"
    # the ground truth reads no mip level: no level map (it wrote one of zeros, session 77), nor its colour scale
    assert _lines(out, "  preview") == "  preview g.png, stats g.json"
    assert "colour scales" not in out
    assert not Path("g.level.exr").exists() and not Path("g.level.png").exists()
    assert json.loads(Path("g.json").read_text())["colour_scales"] == {}


def test_render_of_planes_beside_a_sphere_ground_truth_writes_no_mip_level_map(small_scenes, monkeypatch, capsys):
    """Planes beside a sphere under --filter ground_truth: the planes read no mip level, so no mip level map is
    written or named (the reference spheres have no AOVs either: no colour scales at all)."""
    from warpbw.cli import main

    plane = np.zeros((H, W), bool)
    plane[:, :2] = True
    _fake_mixed(monkeypatch, small_scenes.clock, COV, plane, np.zeros((H, W), np.float32), spp=64)
    assert main(["render", "mixed.toml", "-o", "m.exr", "--filter", "ground_truth", "--spp", "64"]) == 0
    out = capsys.readouterr().out
    assert _lines(out, "  preview") == "  preview m.png, stats m.json"
    assert "colour scales" not in out
    assert not Path("m.mip_level.exr").exists() and not Path("m.mip_level.png").exists()
    assert json.loads(Path("m.json").read_text())["colour_scales"] == {}


def test_render_of_planes_refuses_to_replace_a_level_map_left_alone(small_scenes, monkeypatch, capsys):
    """The level map is an output like the image: one left alone is not replaced without --force."""
    import warpbw.filtering as filtering
    from warpbw.cli import main

    capture_call(monkeypatch, filtering, "render_filtering")   # reaching it fails the test
    Path("p.level.png").write_bytes(b"mine")
    assert outcome(main, ["render", "plane.toml", "-o", "p.exr", "-q"]) == "returned 2"
    assert "p.level.png: already exists" in capsys.readouterr().err
    assert Path("p.level.png").read_bytes() == b"mine" and not Path("p.exr").exists()


def _fake_mixed(monkeypatch, clock, cov, plane, mip, spp=4):
    import warpbw.pipeline as pipeline

    def fake(scene, filter_method, spp_, **kw):
        clock.now += 3.0
        st = {"time_s": {"frame": 0.75, "planes": 0.25}, "resolution": [W, H], "pixels_covered": int(cov.sum()),
              "pixels_shaded": 5, "pixels_hidden": 2, "spp": spp,
              "planes": {"pixels_covered": int(plane.sum()), "mean_level": float(mip[plane].mean()) if plane.any()
                         else 0.0}}
        return SimpleNamespace(image=_image(cov), coverage=cov.copy(), stats=st,
                               aovs={"mip_level": mip.copy(), "plane": plane.copy()})

    monkeypatch.setattr(pipeline, "render_with_planes", fake)


def test_render_of_planes_beside_a_sphere_summary_and_mip_map_by_hand(small_scenes, monkeypatch, capsys):
    """Planes beside a sphere, by hand: the spheres' own frame is the whole frame less the planes', the planes' pixel
    count is theirs, and the mip level map's scale is over the plane's pixels only."""
    from warpbw.cli import main

    plane = np.zeros((H, W), bool)
    plane[:, :2] = True                                   # 8 plane pixels; the sphere covers 4 more (column 2)
    mip = np.where(plane, 2.0 + np.arange(H)[:, None] * 0.2, 0.0).astype(np.float32)   # 2 .. 2.6 on the plane
    _fake_mixed(monkeypatch, small_scenes.clock, COV, plane, mip)
    assert main(["render", "mixed.toml", "-o", "m.exr", "--filter", "fixed", "--spp", "4"]) == 0
    out = capsys.readouterr().out
    assert _lines(out, "m.exr") == f"m.exr  ({W}x{H}, 12 covered pixels)"
    # the spheres' own frame is the whole frame less the planes' (0.75 - 0.25 s)
    assert _lines(out, "  spheres and meshes") == ("  spheres and meshes: reference, 4 spp, 5 pixels shaded (2 hidden "
                                                   "by planes, not shaded), frame 0.500 s")
    assert _lines(out, "  planes in front") == ("  planes in front: 8 pixels, filter fixed, mean mip level 2.30, "
                                                "frame 0.250 s")
    assert _lines(out, "  frame") == "  frame 0.750 s, total 3.00 s"
    # the mip level map's scale is over the plane's pixels, not the sphere's (level 0 there)
    assert _lines(out, "  colour scales") == "  colour scales (dark blue to yellow): mip_level 2 to 2.6"


def test_render_of_planes_beside_a_sphere_refuses_to_replace_a_mip_map_left_alone(small_scenes, monkeypatch, capsys):
    """The mip level map of planes beside a sphere is an output like the image: one left alone is not replaced without
    --force."""
    import warpbw.pipeline as pipeline
    from warpbw.cli import main

    capture_call(monkeypatch, pipeline, "render_with_planes")   # reaching it fails the test
    Path("m.mip_level.exr").write_bytes(b"mine")
    assert outcome(main, ["render", "mixed.toml", "-o", "m.exr", "--spp", "4", "-q"]) == "returned 2"
    assert "m.mip_level.exr: already exists" in capsys.readouterr().err
    assert Path("m.mip_level.exr").read_bytes() == b"mine"


def test_render_of_planes_beside_a_sphere_that_covers_nothing_warns(small_scenes, monkeypatch, capsys):
    """Every renderer's empty image is said, in one line (warpbw/cli.py _warn_if_empty)"""
    from warpbw.cli import main

    none = np.zeros((H, W), bool)
    _fake_mixed(monkeypatch, small_scenes.clock, none, none, np.zeros((H, W), np.float32))
    assert main(["render", "mixed.toml", "-o", "m.exr", "--spp", "4", "-q"]) == 0
    err = capsys.readouterr().err
    assert err.count("warpbw: warning: no pixel is covered by geometry") == 1, err


@pytest.mark.parametrize("camera_y", [-1.5, 0.0, 1.5])
def test_an_empty_frame_of_planes_seen_from_below_says_planes_are_seen_from_above_only(tmp_path, monkeypatch, capsys,
                                                                                         camera_y):
    """README: a plane faces +Y and is seen from above only (a camera below it sees through it).  A camera below the
    plane, or in its height, looking at its centre renders nothing, and the empty-image warning names the reason
    instead of only the camera's aim; from above, the plane is drawn and nothing is said (session 78: the warning
    said "check [camera] position, look_at and fov against the objects" of a camera that was aimed right)."""
    from warpbw.cli import main

    monkeypatch.chdir(tmp_path)
    z = 2.0 if camera_y != 0.0 else 3.0
    Path("p.toml").write_text(plane_scene_toml(position=(0.0, camera_y, z), resolution=(8, 6)))
    assert main(["render", "p.toml", "-o", "p.exr", "--filter", "fixed", "-q"]) == 0
    err = capsys.readouterr().err
    covered = read_exr("p.exr").pixels.any(axis=-1).sum()
    if camera_y > 0.0:
        assert covered > 0 and "no pixel is covered" not in err, err
    else:
        assert covered == 0
        assert err.count("warpbw: warning: no pixel is covered by geometry") == 1, err
        assert f"seen from above only, and the camera (y = {camera_y:g}) is not above any (y = 0 at the lowest)" \
            in err, err


def test_an_empty_frame_of_a_camera_between_two_planes_does_not_say_it_is_below_them(tmp_path, monkeypatch, capsys):
    """Mutation round 12: the hint names a camera at or below every plane, the lowest: one at y = 1 between planes
    at y = 0 and y = 2, looking up at the higher (seen from below: nothing) with the lower out of view, renders an
    empty frame, and the warning keeps to the camera's aim (it is above a plane)."""
    from warpbw.cli import main

    monkeypatch.chdir(tmp_path)
    text = plane_scene_toml(position=(0.0, 1.0, 3.0), resolution=(8, 6)).replace(
        "look_at = [0.0, 0.0, 0.0]", "look_at = [0.0, 2.0, 0.0]")
    Path("p.toml").write_text(text + '\n[[object]]\nshape = "plane"\nsize = 2.0\ncenter = [0.0, 2.0, 0.0]\n'
                                     'material = "m"\n')
    assert main(["render", "p.toml", "-o", "p.exr", "--filter", "fixed", "-q"]) == 0
    err = capsys.readouterr().err
    assert not read_exr("p.exr").pixels.any()
    assert err.count("warpbw: warning: no pixel is covered by geometry") == 1, err
    assert "seen from above only" not in err, err


def test_the_examples_read_the_shared_data_where_the_tests_do(monkeypatch, tmp_path):
    """README: the real inputs are read from ../shared/data, or $WARPBW_SHARED_DATA.  The examples read
    ../shared/data whatever the variable said (a clone elsewhere failed 7 of test_bench's tests)."""
    from conftest import ROOT, load_example
    from warpbw.io.shared_data import shared_data_dir

    monkeypatch.delenv("WARPBW_SHARED_DATA", raising=False)
    assert shared_data_dir(ROOT) == ROOT.parent / "shared" / "data"
    assert shared_data_dir() == Path(__import__("warpbw").__file__).resolve().parents[1].parent / "shared" / "data"
    monkeypatch.setenv("WARPBW_SHARED_DATA", str(tmp_path))
    assert shared_data_dir(ROOT) == shared_data_dir() == tmp_path
    for name in ("bench_scenes", "bench_reference", "dynamic_geometry", "validate_bandwidth"):
        assert load_example(name).DATA == tmp_path, name
    assert load_example("mirror_smear").PROBE_DEFAULT == tmp_path / "envmaps" / "city.exr"
    assert load_example("compare_mitsuba").DEFAULT_PROBE == tmp_path / "envmaps" / "studio.exr"


@pytest.mark.parametrize("argv", [["render", "s.toml", "-o", "o.exr", "--for"], ["bench", "s.toml", "--js", "b.json"],
                                  ["gmm", "m.exr", "-o", "g.gmm", "--comp", "2"]])
def test_options_are_spelled_out(argv, capsys):
    """argparse took any unambiguous prefix: --for ran as --force (and a later option beginning alike would have
    changed what a prefix meant).  Each is an unknown option now."""
    from precompute.__main__ import build_parser as precompute_parser
    from warpbw.cli import build_parser

    parser = precompute_parser() if argv[0] == "gmm" else build_parser()
    with pytest.raises(SystemExit) as ei:
        parser.parse_args(argv)
    err = capsys.readouterr().err
    assert ei.value.code == 2 and f"unrecognized arguments: {argv[-1] if argv[0] == 'render' else argv[-2]}" in err
    # the subcommand's own --help is the one to read (it pointed to the program's)
    assert "--help')" in err and f" {argv[0]} --help" in err, err


def test_a_second_scene_is_refused_by_the_subcommand(capsys):
    from warpbw.cli import main

    with pytest.raises(SystemExit) as ei:
        main(["render", "a.toml", "b.toml", "-o", "x.exr"])
    assert ei.value.code == 2
    assert capsys.readouterr().err == ("warpbw: error: unrecognized arguments: b.toml (see 'warpbw render --help')\n")


@pytest.mark.parametrize("command", ["warpbw", "warpbw-precompute"])
def test_version_is_the_packages(command, capsys):
    """--version prints the version pyproject.toml installs (it was an unknown option)."""
    from importlib.metadata import version

    from precompute.__main__ import build_parser as precompute_parser
    from warpbw.cli import build_parser

    text = (Path(__file__).resolve().parents[1] / "pyproject.toml").read_text()
    declared = re.search(r'^version = "([^"]+)"', text, re.M).group(1)
    assert version("warpbw") == declared
    with pytest.raises(SystemExit) as ei:
        (build_parser if command == "warpbw" else precompute_parser)().parse_args(["--version"])
    assert ei.value.code == 0 and capsys.readouterr().out == f"{command} {declared}\n"


@pytest.mark.parametrize("stops", ["150", "-150"])
def test_exposure_accepts_the_ends_help_names(stops):
    """--help "-150 to 150"."""
    from warpbw.cli import build_parser

    got = outcome(build_parser().parse_args, ["render", "s.toml", "-o", "o.exr", "--exposure", stops])
    assert got.startswith("returned Namespace(") and f"exposure={float(stops)!r}" in got, got



def test_an_adaptive_frame_of_spheres_lists_no_mesh_curvature_stage():
    """warpbw.pipeline: no stage is compiled or run that the scene does not use, and only a mesh has a curvature to
    derive (a sphere's is 1 / r in the G-buffer kernel).  Truth: a scene of one sphere (no mesh) under a sky: its
    adaptive stages (the list ends with the adaptive frame's up-sampling) name no mesh curvature."""
    from test_lights import SKY, scene
    from warpbw.pipeline import prepare_scene, stages_used

    prep = prepare_scene(scene(env=SKY, w=12, h=16))
    assert not prep.geometry.has_mesh
    assert not any("curvature" in s for s in stages_used(prep, mis=True, adaptive=True))
    assert stages_used(prep, mis=True, adaptive=True)[-1] == "upsampling"   # the adaptive list itself


# case, square image side, spp; ggx0.1's lobe varies within a 48-pixel image's pixel, which Mitsuba's box filter
# averages and warpbw's G-buffer (one point per pixel) does not: its relMSE read 2.7x Mitsuba's noise floor at 48x48
# (1.14x once warpbw's image was rendered at 2x2 per pixel and averaged), 1.05x at 96x96
MITSUBA_CASES = [("lambert", 48, 4096, 0.005), ("ggx0.4", 48, 4096, 0.005), ("ggx0.1", 96, 1024, 0.02)]


@pytest.mark.slow
@pytest.mark.parametrize("case, res, spp, mean_tol", MITSUBA_CASES)
def test_the_reference_agrees_with_mitsuba(case, res, spp, mean_tol):
    """An independent renderer: Mitsuba 3's path integrator (scalar_rgb) renders examples/compare_mitsuba.py's sphere
    under studio.exr, twice with other seeds.  Over the sphere's interior warpbw's MIS reference lies from Mitsuba's
    image as far as Mitsuba's second seed does (relMSE within 1.35x of that noise floor; measured 0.99x / 1.01x /
    1.05x) and its mean radiance within ``mean_tol`` (measured 1e-4 / 1e-4 / 1.5e-4; Mitsuba's own two seeds differ
    by 2e-4 / 3e-4 / 5e-3).  What it catches, measured on warpbw rendering the probe altered: turned by 5 degrees,
    14x / 17x / 29x the floor; 2% brighter, 1.69x / 1.70x (and a 2% mean) / 1.26x (a 2% mean)."""
    from conftest import load_example, shared_file

    pytest.importorskip("mitsuba", reason="Mitsuba 3 is not installed (pip install -e '.[test]' installs it)")
    probe = shared_file("envmaps/studio.exr")
    cm = load_example("compare_mitsuba")
    mi, variant = cm.import_mitsuba("scalar_rgb")
    mat = cm.CASES[case]
    scene = cm.mitsuba_scene(mi, cm.load_probe(mi, probe), mat, res, spp, 0.0, 1.0)
    first, _, _ = cm.render_mitsuba(mi, scene, spp, 1)
    second, _, _ = cm.render_mitsuba(mi, scene, spp, 2)
    prepare, render_reference = cm.import_warpbw()
    with pytest.warns(RuntimeWarning, match="studio.exr"):   # three negative texels set to 0, as Mitsuba's are
        ours, cov, _ = cm.render_warpbw(prepare, render_reference, cm.warpbw_toml(probe, mat, res, 0.0, 1.0),
                                        spp, 1, mis=True)
    inside = cm.erode(cov, cm.ERODE_PX)
    assert inside.sum() > 0.3 * res * res
    floor = cm.relmse_sum(second, first, inside)
    assert cm.relmse_sum(ours, first, inside) < 1.35 * floor, (variant, floor)
    assert abs(ours[inside].mean() / first[inside].mean() - 1.0) < mean_tol


@pytest.mark.slow
def test_compare_mitsuba_script_writes_both_renderers_images_and_its_table(tmp_path):
    """examples/compare_mitsuba.py end to end with Mitsuba installed (its Mitsuba side had run only by hand): one line
    per case with both renderers' figures and Mitsuba's noise floor, and the images it names, each renderer's as an
    EXR of the requested size whose interior mean agrees with the other's (Lambert, 24x24, 256 spp: within 5%)."""
    pytest.importorskip("mitsuba", reason="Mitsuba 3 is not installed (pip install -e '.[test]' installs it)")
    from conftest import shared_file

    probe = shared_file("envmaps/studio.exr")
    script = Path(__file__).resolve().parents[1] / "examples" / "compare_mitsuba.py"
    r = subprocess.run([sys.executable, str(script), "--cases", "lambert,ggx0.4", "--resolution", "24", "--spp", "256",
                        "--noise-floor", "--variant", "scalar_rgb", "--probe", str(probe), "--out", "cmp", "--seed", "3"],
                       cwd=tmp_path, stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    rows = {ln.split()[0]: ln.split() for ln in r.stdout.splitlines() if ln.split()[:1] in (["lambert"], ["ggx0.4"])}
    assert set(rows) == {"lambert", "ggx0.4"}, r.stdout
    for case, cells in rows.items():
        assert cells[-1] in ("PASS", "FAIL") and all(math.isfinite(float(c)) for c in cells[1:-1]), cells
    names = sorted(p.name for p in (tmp_path / "cmp").iterdir())
    assert names == sorted(f"{c}{k}" for c in rows for k in ("_mitsuba.exr", "_warpbw.exr", ".png")), names
    mit, ours = (read_exr(tmp_path / "cmp" / f"lambert_{who}.exr").pixels[..., :3] for who in ("mitsuba", "warpbw"))
    assert mit.shape == ours.shape == (24, 24, 3)
    inside = np.zeros((24, 24), bool)
    inside[8:16, 8:16] = True   # the sphere's middle: radius 1 at distance 4, 35 degrees across, covers +-8 px
    assert abs(ours[inside].mean() / mit[inside].mean() - 1.0) < 0.05


_SHADING_SIGNALLED = """
import sys
import warp as wp

real = wp.launch

def launch(kernel, *args, **kwargs):   # says when the first shading launch starts (its module loaded)
    if "shade_reference" in kernel.key and not said:
        wp.load_module(kernel.module, device="cpu")
        said.append(print("shading", flush=True))
    return real(kernel, *args, **kwargs)

said = []
wp.launch = launch
from warpbw.cli import main
sys.exit(main(["render", "scene.toml", "-o", "out.exr", "--spp", "2147483647", "-q", "--threads", "1"]))
"""


def test_ctrl_c_stops_a_one_pixel_frame_of_two_billion_samples_between_its_launches(tmp_path):
    """One pixel of more than LAUNCH_COST_MAX samples was one launch: a 1 x 1 frame at --spp 2^31 - 1 held Ctrl-C for
    that pixel's 2e9 samples (about half an hour on one thread; leftovers of the options audit, session 64).  Now it is
    shaded in passes of LAUNCH_COST_MAX samples (about a second each): a real process, sent SIGINT once its shading
    has begun, ends with the interruption's line and status and writes no image, long before the samples are done."""
    import signal

    (tmp_path / "scene.toml").write_text(lambert_sphere_scene(1, 1))
    env = dict(os.environ, WARPBW_CACHE=str(tmp_path / "cache"))
    child = subprocess.Popen([sys.executable, "-c", _SHADING_SIGNALLED], cwd=tmp_path, env=env, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, stdin=subprocess.DEVNULL, text=True,
                             preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        assert child.stdout.readline() == "shading\n"
        child.send_signal(signal.SIGINT)
        _, err = child.communicate(timeout=120)   # a pass is about a second; the whole pixel, half an hour
    finally:
        child.kill()
    assert (child.returncode, err.strip()) == (130, "warpbw: interrupted")
    assert [p.name for p in tmp_path.iterdir() if p.name != "cache"] == ["scene.toml"]   # no image, no temporary


def test_info_says_which_nu_rho_tables_the_scene_names_rather_than_builds(tmp_path):
    """warpbw info --method adaptive said every glossy material's nu_rho table is "built once and cached", also for a
    material whose scene names a precomputed ``bandwidth`` file (which the pass reads, and builds nothing): the
    materials that name one are now listed as read from the scene's files."""
    from conftest import fake_npf_table
    from warpbw.pipeline import scene_summary
    from warpbw.scene import parse_scene

    npf = fake_npf_table(tmp_path / "npf.bin")
    write_exr(tmp_path / "sky.exr", np.full((16, 32, 3), 0.5, np.float32))
    head = ['[camera]', 'position = [0.0, 0.0, 3.0]', 'look_at = [0.0, 0.0, 0.0]', 'fov = 50.0',
            'resolution = [16, 16]', '[environment]', 'file = "sky.exr"']
    objs = ['[[object]]', 'shape = "sphere"', 'center = [-0.6, 0.0, 0.0]', 'radius = 0.5', 'material = "a"',
            '[[object]]', 'shape = "sphere"', 'center = [0.6, 0.0, 0.0]', 'radius = 0.5', 'material = "b"']
    mats = [f'[material.{m}]\ntype = "npf"\ntable = "{npf.name}"\nname = "{n}"' for m, n in (("a", "chrome"),
                                                                                          ("b", "nickel"))]

    def bandwidth_stage(extra_a: str) -> str:
        text = "\n".join(head + objs + [mats[0] + extra_a, mats[1]])
        stages = scene_summary(parse_scene(text, tmp_path, "s.toml"), "adaptive")["stages"]
        return next(st for st in stages if st.startswith("bandwidth pass"))

    assert bandwidth_stage("").endswith("nu_rho table, built once and cached")
    (tmp_path / "a.npz").write_bytes(b"")   # named, not read: the summary loads no asset
    assert bandwidth_stage('\nbandwidth = "a.npz"').endswith(
        "nu_rho table, built once and cached (a's read from the scene's bandwidth file)")


_STOP_AS_IT_LOADS = """\
import os, signal, sys

class _StopAsItLoads:
    def find_spec(self, name, path=None, target=None):
        if name in ("numpy", "warp", "warpbw.cli_common") and sys.argv[0].endswith(".py"):
            sys.meta_path.remove(self)
            os.kill(os.getpid(), getattr(signal, os.environ["STOP_AS_IT_LOADS"]))
        return None

sys.meta_path.insert(0, _StopAsItLoads())
"""


def test_every_example_says_a_sigterm_while_it_loads_in_one_line(tmp_path):
    """A SIGTERM or SIGHUP while an example imports numpy, Warp and warpbw (before its run_command) ended it without a
    word, where the warpbw commands say one line and exit with the shell's status for the signal (session 79 fixed
    the commands and the examples' Ctrl-C; session 80 the examples' other stops).  Each example, run as a script and
    sent SIGTERM or SIGHUP (in turns) as it first imports one of them, now says "SCRIPT: terminated" ("hung up")
    alone and exits 143 (129), as its own run_command would, having written nothing."""
    import signal

    (tmp_path / "hook").mkdir()
    (tmp_path / "hook" / "sitecustomize.py").write_text(_STOP_AS_IT_LOADS)
    work = tmp_path / "work"
    work.mkdir()
    stops = (("SIGTERM", 143, "terminated"), ("SIGHUP", 129, "hung up"))
    children, expected = {}, {}
    for k, script in enumerate(EXAMPLES):
        sig, status, said = stops[k % 2]
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path / "hook"), *sys.path]), STOP_AS_IT_LOADS=sig)
        children[script.name] = subprocess.Popen(
            [sys.executable, str(script), "--help"], cwd=work, env=env, stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            preexec_fn=lambda: signal.signal(signal.SIGHUP, signal.SIG_DFL))
        expected[script.name] = (status, f"{script.name}: {said}", "")
    got = {}
    for name, child in children.items():
        out, err = child.communicate(timeout=120)
        got[name] = (child.returncode, err.strip(), out)
    assert got == expected
    assert list(work.iterdir()) == []


def test_every_help_fits_the_terminal_it_is_printed_on(monkeypatch):
    """``warpbw bench --help`` printed its description as one line of 753 characters (a raw-text formatter, kept for
    an epilog it does not have), ``warpbw --help`` its description as one of 130 and its examples up to 108 wide,
    and ``warpbw render --help`` a usage line of 91 (the --filter choices, one word argparse cannot break): on an
    80-column terminal they wrapped mid-word, where every other command's help is wrapped to the terminal
    (command-line audit, session 81).  Truth: the terminal's width, which argparse reads from COLUMNS."""
    import argparse

    from precompute.__main__ import build_parser as precompute_parser
    from warpbw.cli import build_parser as warpbw_parser

    monkeypatch.setenv("COLUMNS", "80")
    wide = []
    for prog, parser in (("warpbw", warpbw_parser()), ("warpbw-precompute", precompute_parser())):
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        for name, p in [("", parser), *sub.choices.items()]:
            wide += [f"{prog} {name} --help: {len(ln)} wide: {ln[:60]}..." for ln in p.format_help().splitlines()
                     if len(ln) > 80]
    assert not wide, "\n".join(wide)


def test_info_json_is_strict_json_as_every_json_a_command_prints(tmp_path, monkeypatch, capsys):
    """``warpbw info --json`` printed a header's NaN (a damaged or hand-edited file a material names) as a bare
    ``NaN``, which jq and strict parsers refuse, where ``warpbw compare --json`` and ``warpbw-precompute info --json``
    print strict JSON, a non-finite number as null (command-line audit, session 81).  Truth: Python's json parser
    told to refuse NaN and Infinity, and the header's version, written here as NaN with numpy."""
    from precompute.gmm_mipmap import GMM_FORMAT
    from warpbw.cli import main as cli_main
    from warpbw.io.exr import write_exr

    monkeypatch.setenv("WARPBW_CACHE", str(tmp_path / "cache"))
    write_exr(tmp_path / "h.exr", np.zeros((8, 8, 1), np.float32), ["Y"])
    with open(tmp_path / "nan.gmm", "wb") as f:   # a header alone: info reads no more of a file of another version
        np.savez(f, __header__=np.array(json.dumps({"format": GMM_FORMAT, "version": float("nan"), "params": {}})))
    (tmp_path / "s.toml").write_text("\n".join([
        "[camera]", "position = [0.0, 1.2, 1.2]", "look_at = [0.0, 0.0, 0.0]", "fov = 40.0", "resolution = [8, 8]",
        "[[light]]", 'type = "directional"', "direction = [0.3, 0.8, -0.5]", "radiance = [3.0, 3.0, 3.0]",
        "[[object]]", 'shape = "plane"', "center = [0.0, 0.0, 0.0]", "size = 2.0", 'material = "m"',
        "[material.m]", 'type = "cook-torrance"', "roughness = 0.08", "f0 = [0.9, 0.75, 0.4]",
        'normal_map = "h.exr"', 'gmm = "nan.gmm"']))

    def refuse(constant):
        raise ValueError(f"not strict JSON: {constant}")

    assert cli_main(["info", str(tmp_path / "s.toml"), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out, parse_constant=refuse)
    (asset,) = summary["assets"]
    assert Path(asset["path"]).name == "nan.gmm" and asset["version"] is None
    assert asset["not_read"] == "version nan, this warpbw reads 2"


def test_a_command_started_with_stderr_closed_runs_and_leaves_stdout_to_its_results(tmp_path, monkeypatch, capsys):
    """Started with stderr closed (``2>&-``), Python has no sys.stderr: every progress bar's first line raised
    AttributeError, and a render, a demo or a precompute ended with status 1 and not a word (its traceback had nowhere
    to go either); and an error or warning line, printed to ``file=sys.stderr`` that is None, went to stdout, among
    the results (command-line audit, session 81).  Now the bars are off, as asked for with -q, and the lines go
    nowhere, as the shell's other commands' do there.  Truth: the bar's own library, tqdm, drawing nothing, and
    stdout holding nothing but what the command prints there."""
    from tqdm import tqdm

    from precompute.progress import bar_options, progress_callback
    from warpbw.cli import main as cli_main

    monkeypatch.setattr(sys, "stderr", None)
    with progress_callback(3, "work", "item") as step:   # AttributeError on the old code
        step(1)
        step(3)
    with tqdm(total=2, **bar_options()) as bar:   # the batch's bar
        bar.update(2)
    assert cli_main(["render", str(tmp_path / "missing.toml"), "-o", str(tmp_path / "x.exr")]) == 2
    assert capsys.readouterr().out == ""   # "warpbw: error: ...missing.toml: scene file not found" landed here


def test_the_command_line_conventions_hold_for_every_command():
    """README's "Command-line conventions", read off the parsers of both programs (command-line audit, session 81):
    every path an option or argument takes is a non-empty name (``parse_path``: bench's --json, --plot and --cache
    and compare's --error-map took "" and dropped it); every command that writes files takes --force, every one that
    draws a progress bar -q/--quiet; every --seed is ``parse_seed``'s 0 to 2^32-1 with default 0; every --device is
    worded alike, default cpu; --json is a flag that prints where README says so and a path where it names a
    record; a new command or option must take its place here."""
    import argparse

    from precompute.__main__ import build_parser as precompute_parser
    from warpbw.cli import build_parser as warpbw_parser
    from warpbw.cli_common import parse_path, parse_seed

    commands = {}
    for prog, parser in (("warpbw", warpbw_parser()), ("warpbw-precompute", precompute_parser())):
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        commands |= {f"{prog} {name}": {a.option_strings[-1] if a.option_strings else a.dest: a for a in p._actions}
                     for name, p in sub.choices.items()}
    w, pc = "warpbw ", "warpbw-precompute "
    writers = {w + c for c in ("render", "demo", "bench", "bench-filtering", "compare")} | {
        pc + c for c in ("npf-to-merl", "brdf-sampling", "brdf", "batch", "gmm")}
    with_bars = writers - {w + "compare", pc + "npf-to-merl"}
    assert set(commands) == writers | {w + "info", pc + "info"}
    assert {c for c, opts in commands.items() if "--force" in opts} == writers
    assert {c for c, opts in commands.items() if "--quiet" in opts} == with_bars
    assert all(commands[c]["--quiet"].option_strings == ["-q", "--quiet"] for c in with_bars)
    assert {c for c, opts in commands.items() if "--seed" in opts} == {
        w + "render", w + "demo", w + "bench", w + "bench-filtering", pc + "gmm"}
    assert {c for c, opts in commands.items() if "--device" in opts} == {
        w + "render", w + "demo", w + "bench", w + "bench-filtering"}
    assert {commands[c]["--device"].help for c in commands if "--device" in commands[c]} == {
        "Warp device: cpu (default) or cuda / cuda:N"}
    json_flag = {c for c, opts in commands.items() if "--json" in opts and opts["--json"].nargs == 0}
    json_path = {c for c, opts in commands.items() if "--json" in opts and opts["--json"].nargs != 0}
    assert json_flag == {w + "info", w + "compare", pc + "info"}
    assert json_path == {w + "bench", w + "bench-filtering", pc + "batch"}
    paths = {"--output", "--plot", "--cache", "--error-map", "--table", "table", "scene", "file", "map", "files",
             "sources", "test", "reference"}
    wrong = [f"{c} {name}" for c, opts in commands.items() for name, a in opts.items()
             if (name in paths or c in json_path and name == "--json") and a.type is not parse_path]
    wrong += [f"{c} --seed" for c, opts in commands.items() if "--seed" in opts
              and (opts["--seed"].type is not parse_seed or opts["--seed"].default not in (None, 0))]
    assert not wrong, wrong
    for parser in (warpbw_parser(), precompute_parser()):   # each --help gives the exit statuses in brief
        said = re.sub(r"\s+", " ", parser.epilog)
        assert all(s in said for s in ("0 done", "2 a usage error or bad input", "130, 143 or 129", "141")), said


def test_radiance_keeps_its_units_and_channels_from_the_probe_to_the_exr_and_the_preview(tmp_path, monkeypatch):
    """Radiance end to end, each channel apart: under a constant sky of L = (0.2, 1, 5) a Lambert sphere of albedo
    (0.9, 0.5, 0.3) reflects exactly albedo x L per channel (BRDF sampling of a Lambert: f cos / pdf = albedo, no
    noise), with the sky given as a constant, as a probe file, and as a probe in ACES2065-1 primaries holding the same
    light (its stored RGB M^-1 L, M the published AP0 -> Rec. 709 matrix), for the reference and the adaptive method.
    A channel swap, a luminance shortcut or a probe read in the wrong primaries shows.  Truth: the product, the EXR
    read by OpenEXR's own binding (R, G, B, A by name; no chromaticities written: Rec. 709 by OpenEXR's definition),
    the PNG against IEC 61966-2-1's curve written out here, rounded; the sphere's pixels by a ray cast in numpy."""
    import OpenEXR

    from warpbw.cli import main as cli_main

    monkeypatch.setenv("WARPBW_CACHE", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)
    light, albedo = np.array([0.2, 1.0, 5.0]), np.array([0.9, 0.5, 0.3])
    ap0_to_rec709 = np.array([[2.52168619, -1.13413099, -0.38755520], [-0.27647991, 1.37271909, -0.09623917],
                              [-0.01537801, -0.15297534, 1.16835335]])
    for name, rgb, chroma in (("probe", light, None),
                              ("aces", np.linalg.solve(ap0_to_rec709, light),
                               (0.7347, 0.2653, 0.0, 1.0, 0.0001, -0.0770, 0.32168, 0.33767))):
        px = np.broadcast_to(rgb.astype(np.float32), (8, 16, 3))
        OpenEXR.File({} if chroma is None else {"chromaticities": chroma},
                     {c: np.ascontiguousarray(px[..., i]) for i, c in enumerate("RGB")}).write(f"{name}.exr")
    w, h = 12, 10
    hit = (numpy_sphere_distance(*numpy_camera_rays((0.0, 0.0, 4.0), (0.0, 0.0, 0.0), 40.0, w, h), (0.0, 0.0, 0.0),
                                 1.0) < np.inf)
    want = albedo * light
    x = np.clip(want, 0.0, 1.0)
    code = np.round(255.0 * np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1.0 / 2.4) - 0.055))
    for env in ("constant = [0.2, 1.0, 5.0]", 'file = "probe.exr"', 'file = "aces.exr"'):
        Path("s.toml").write_text(lambert_sphere_scene(w, h).replace("constant = [1.0, 1.0, 1.0]", env)
                                  .replace("albedo = 0.5", "albedo = [0.9, 0.5, 0.3]"))
        for out, method in (("ref", ["--spp", "2"]), ("ada", ["--method", "adaptive", "--budget", "2"])):
            assert cli_main(["render", "s.toml", "-o", f"{out}.exr", *method, "-q", "--force"]) == 0
            ch = OpenEXR.File(f"{out}.exr", separate_channels=True).channels()
            assert sorted(ch) == ["A", "B", "G", "R"] and "chromaticities" not in OpenEXR.File(f"{out}.exr").header()
            img = np.stack([ch[c].pixels for c in "RGB"], axis=-1).astype(np.float64)
            cov = ch["A"].pixels > 0
            assert np.array_equal(cov, hit), (env, method)
            np.testing.assert_allclose(img[cov], np.broadcast_to(want, img[cov].shape), rtol=2e-6, err_msg=env)
            assert not img[~cov].any()
            png = np.asarray(Image.open(f"{out}.png"))
            assert np.array_equal(png[cov], np.broadcast_to(code, png[cov].shape)) and not png[~cov].any()
