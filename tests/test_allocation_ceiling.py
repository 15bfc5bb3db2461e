"""examples/allocation_ceiling.py: the oracle's noise gains against closed forms on Lambert spheres under a
constant sky, where every pixel of one sphere has the same one-step variance, proportional to albedo^2."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from conftest import ROOT, load_example, plot_png
from warpbw.pipeline import prepare_scene
from warpbw.scene import parse_scene

SCENE = """
[camera]
position = [0.0, 0.0, 6.0]
look_at = [0.0, 0.0, 0.0]
fov = 30.0
resolution = [48, 24]
[environment]
constant = [1.0, 1.0, 1.0]
{objects}
[material.bright]
type = "lambert"
albedo = [0.8, 0.8, 0.8]
[material.dark]
type = "lambert"
albedo = [0.2, 0.2, 0.2]
"""
SPHERE = '[[object]]\nshape = "sphere"\ncenter = [{x}, 0.0, 0.0]\nradius = 0.7\nmaterial = "{m}"\n'


@pytest.fixture(scope="module")
def ac():
    return load_example("allocation_ceiling")


def scene(*spheres):
    return parse_scene(SCENE.format(objects="".join(SPHERE.format(x=x, m=m) for x, m in spheres)))


def test_one_lambert_sphere_has_nothing_to_allocate(ac):
    """Under a constant sky every pixel of a Lambert sphere sees the same integrand in its own frame: v_p is
    constant, so Neyman's allocation is the uniform one (gain 1, up to sqrt(v)'s estimation bias of about
    1 / (2 x seeds)), and so is the oracle on the shaded pixels."""
    r = ac.allocation_ceiling(prepare_scene(scene((0.0, "bright"))), budget=4.0, seeds=32, spp=8)
    assert r["oracle_all"] < 1.06   # never below 1 (Cauchy-Schwarz): the check is how close it comes
    assert r["oracle_shaded"] == pytest.approx(r["uniform_shaded"], rel=0.06)
    assert 0.0 < r["shaded_fraction"] < 0.2      # nothing varies: a few coarse texels are shaded


def test_two_albedos_give_the_closed_form_neyman_gain(ac):
    """Spheres of albedo 0.8 and 0.2: v_p proportional to albedo^2, so with n_1 and n_2 pixels the oracle gain is
    (n_1 a_1^2 + n_2 a_2^2) (n_1 + n_2) / (n_1 a_1 + n_2 a_2)^2 (1.36 for equal counts)."""
    prep = prepare_scene(scene((-1.0, "bright"), (1.0, "dark")))
    cov, v = ac.per_pixel_variance(prep, seeds=32, spp=8)
    left = np.zeros(cov.shape, bool)
    left[:, : cov.shape[1] // 2] = True
    n1, n2 = int((cov & left).sum()), int((cov & ~left).sum())
    assert n1 == n2 > 50
    np.testing.assert_allclose(np.median(v[cov & left]) / np.median(v[cov & ~left]), 16.0, rtol=0.1)
    expect = (n1 * 0.64 + n2 * 0.04) * (n1 + n2) / (n1 * 0.8 + n2 * 0.2) ** 2
    r = ac.allocation_ceiling(prep, budget=4.0, seeds=32, spp=8)
    assert r["oracle_all"] == pytest.approx(expect, rel=0.05)
    assert r["frame"] <= r["oracle_shaded"] * 1.0001   # nothing beats Neyman's with the same samples on the same pixels


def test_noise_gain_and_neyman_by_hand(ac):
    v = np.array([4.0, 1.0])
    n = ac.neyman(np.sqrt(v), 6.0)                    # 2 : 1
    np.testing.assert_allclose(n, [4.0, 2.0])
    # reference at 3 spp: (4 + 1) / 3; allocation: 4 / 4 + 1 / 2 = 1.5 (sums over pixels: the 1 / n_cov cancels)
    assert ac.noise_gain(v, v, n, 3.0) == pytest.approx((5 / 3) / 1.5)
    # a floor of one sample: weights 9 : 1 : 1 : 1 over 8 samples want 6 and 2/3 each; the floor gives 1 each
    # to the three, 5 to the first
    np.testing.assert_allclose(ac.neyman(np.array([9.0, 1.0, 1.0, 1.0]), 8.0, 1.0), [5.0, 1.0, 1.0, 1.0], rtol=1e-9)
    np.testing.assert_allclose(ac.neyman(np.array([9.0, 1.0, 1.0, 1.0]), 8.0), [6.0, 2 / 3, 2 / 3, 2 / 3])
    # only the first pixel shaded, the second noise-free: 4 / 6 against (4 + 1) / 3
    assert ac.noise_gain(v, v[:1], np.array([6.0]), 3.0) == pytest.approx((5 / 3) / (4 / 6))


def test_command_line_writes_json_and_refuses_to_overwrite(tmp_path):
    p = tmp_path / "s.toml"
    p.write_text(SCENE.format(objects=SPHERE.format(x=0.0, m="bright")))
    out = tmp_path / "c.json"
    cmd = [sys.executable, str(ROOT / "examples" / "allocation_ceiling.py"), str(p), "--budget", "2", "--seeds", "4",
           "--spp", "2", "--json", str(out)]
    r = subprocess.run(cmd, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "oracle, every pixel shaded" in r.stdout
    rec = json.loads(out.read_text())
    assert rec["budget"] == 2.0 and rec["covered_pixels"] > 0
    r = subprocess.run(cmd, capture_output=True, text=True)
    assert r.returncode == 2 and "--force" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    r = subprocess.run(cmd[:3] + ["--seeds", "1"], capture_output=True, text=True)
    assert r.returncode == 2 and "--seeds" in r.stderr


def test_every_figure_by_hand_on_a_fake_frame(ac, monkeypatch):
    """Truth worked out by hand (no renderer): five covered pixels with one-step variances v = [16, 4, 1, 0.04, 4]
    (a sixth not covered), a frame that shades all but the third with N_p = [6, 3, -, 1, 2], the fourth as a coarse
    texel that took 2 samples (its footprint's largest N_p): spp = [6, 3, -, 2, 2], 13 samples, 2.6 per covered
    pixel; its pass measured variance key / N_p with key = v.
      oracle_all = mean(v) / mean(sqrt v)^2 = 5.008 / 1.84^2;  top 10% (one pixel): 16 / 25.04;
      reference at 2.6 spp: sum(v) / 2.6 = 25.04 / 2.6, over the shaded pixels' sum(v / N):
      uniform (3.25 each): 24.04 / 3.25;  Neyman: (4 + 2 + 0.2 + 2)^2 / 13 = 8.2^2 / 13;
      Neyman with at least one each: the 0.04 pixel gets 1, the other 12 go 4 : 2 : 2 -> 16 / 6 + 4 / 3 + 0.04 +
      4 / 3;  the frame's: 16 / 6 + 4 / 3 + 0.04 / 2 + 4 / 2 (the samples taken, not the N_p map: 12 samples and
      0.04 / 1 read the frame as spending less than it did);
      rank_measured: key = v on the shaded pixels, so 1 (the measured variance key / N_p alone would rank them
      otherwise)."""
    from types import SimpleNamespace

    import warpbw.pipeline

    cov = np.array([[True, True, True, True, True, False]])
    var = np.array([[16.0, 4.0, 1.0, 0.04, 4.0, 100.0]])
    n_p = np.array([[6.0, 3.0, 0.0, 1.0, 2.0, 0.0]])
    shaded = np.array([[True, True, False, True, True, False]])
    spp = np.array([[6.0, 3.0, 0.0, 2.0, 2.0, 0.0]])
    key = var.copy()
    seen = {}

    def fake_variance(prep, seeds, spp, progress=False):
        seen["variance"] = (seeds, spp)
        return cov, var

    def fake_adaptive(prep, budget, seed=0, mis=False, **kw):
        seen["adaptive"] = (budget, seed, mis)
        with np.errstate(divide="ignore", invalid="ignore"):
            measured = np.where(n_p > 0, key / np.maximum(n_p, 1e-30), 0.0)
        return SimpleNamespace(aovs={"n_p": n_p, "spp": spp, "shaded": shaded, "variance": measured})

    monkeypatch.setattr(ac, "per_pixel_variance", fake_variance)
    monkeypatch.setattr(warpbw.pipeline, "render_adaptive", fake_adaptive)
    r = ac.allocation_ceiling(None, budget=2.0, seeds=5, spp=3, seed=11)
    assert seen == {"variance": (5, 3), "adaptive": (2.0, 11, True)}
    ref = 25.04 / 2.6
    want = {"covered_pixels": 5, "frame_samples_per_covered_pixel": 2.6, "shaded_fraction": 0.8,
            "top_10pct_variance_share": 16.0 / 25.04, "oracle_all": 5.008 / 1.84 ** 2,
            "uniform_shaded": ref / (24.04 / 3.25), "oracle_shaded": ref / (8.2 ** 2 / 13.0),
            "oracle_shaded_min1": ref / (16.0 / 6.0 + 4.0 / 3.0 + 0.04 + 4.0 / 3.0),
            "frame": ref / (16.0 / 6.0 + 4.0 / 3.0 + 0.02 + 2.0), "rank_measured": 1.0}
    for k, v in want.items():
        assert r[k] == pytest.approx(v, rel=1e-9), k


def test_top_tenth_share_counts_a_tenth_of_the_covered_pixels(ac, monkeypatch):
    """Twenty covered pixels with v = 1 .. 20: the noisiest tenth is two pixels, 20 + 19 of 210."""
    from types import SimpleNamespace

    import warpbw.pipeline

    var = np.arange(1.0, 21.0)[None, :]
    monkeypatch.setattr(ac, "per_pixel_variance", lambda prep, seeds, spp, progress=False: (var > 0, var))
    monkeypatch.setattr(warpbw.pipeline, "render_adaptive", lambda prep, budget, **kw: SimpleNamespace(
        aovs={"n_p": np.full(var.shape, 2.0), "spp": np.full(var.shape, 2.0), "shaded": var > 0,
              "variance": var / 2.0}))
    r = ac.allocation_ceiling(None, budget=2.0, seeds=2, spp=1)
    assert r["top_10pct_variance_share"] == pytest.approx(39.0 / 210.0, rel=1e-12)
    assert r["uniform_shaded"] == pytest.approx(1.0, rel=1e-12) and r["rank_measured"] == pytest.approx(1.0)


def test_per_pixel_variance_is_the_unbiased_variance_over_the_seeds_times_spp(ac, monkeypatch):
    """v = spp x the unbiased (n - 1) variance of a pixel over the seeds, RGB summed: renders reading 0, 1 and 5
    in every channel at 4 spp give 4 x 3 x var([0, 1, 5], ddof=1) = 4 x 3 x 7 = 84 (the n divisor would read 56),
    and the seeds are 1000, 1001, 1002."""
    import types

    import warpbw.pipeline

    vals = {1000: 0.0, 1001: 1.0, 1002: 5.0}
    seen = []

    def fake(prep, spp, seed=0, mis=False, **kw):
        seen.append((spp, seed, mis))
        return types.SimpleNamespace(image=np.full((2, 3, 3), vals[seed], np.float32),
                                     coverage=np.ones((2, 3), bool))

    monkeypatch.setattr(warpbw.pipeline, "render_reference", fake)
    cov, v = ac.per_pixel_variance(None, 3, 4)
    assert seen == [(4, 1000, True), (4, 1001, True), (4, 1002, True)]
    assert cov.all() and np.allclose(v, 4 * 3 * np.var([0.0, 1.0, 5.0], ddof=1), rtol=1e-12)


_FIGURES = {"budget": 2.0, "seeds": 5, "spp": 3, "covered_pixels": 5, "frame_samples_per_covered_pixel": 2.6,
            "shaded_fraction": 0.8, "top_10pct_variance_share": 0.639, "oracle_all": 1.4792, "uniform_shaded": 1.3018,
            "oracle_shaded": 1.8617, "oracle_shaded_min1": 1.8025, "frame": 1.6643, "rank_measured": 1.0}


def _run_main(ac, monkeypatch, argv):
    """main with stand-ins for Warp, the scene and the analysis (which returns _FIGURES); returns its outcome and
    whether the analysis ran."""
    import warpbw.pipeline
    import warpbw.scene
    from conftest import outcome

    ran = []
    monkeypatch.setattr(ac, "init_warp", lambda dev: ran.append("warp"))
    monkeypatch.setattr(warpbw.scene, "load_scene", lambda path: path)
    monkeypatch.setattr(warpbw.pipeline, "prepare_scene", lambda scene, device=None: scene)
    monkeypatch.setattr(ac, "allocation_ceiling", lambda *a, **k: (ran.append("analysis"), dict(_FIGURES))[1])
    return outcome(ac.main, argv), ran


def test_record_and_plot_hold_the_printed_figures(ac, monkeypatch, tmp_path, capsys):
    """DESIGN.md, measurement protocol: every benchmark writes a JSON record and a PNG plot.  The script wrote the
    record alone; --plot now writes the noise gains beside it, and every figure printed is the record's."""
    import re

    monkeypatch.chdir(tmp_path)
    (tmp_path / "s.toml").write_text("")
    how, ran = _run_main(ac, monkeypatch, ["s.toml", "--plot", "a.png", "--device", "cpu"])
    assert how == "returned 0" and ran == ["warp", "analysis"], how
    out = capsys.readouterr().out
    rec = json.loads((tmp_path / "a.json").read_text())
    assert rec == {**_FIGURES, "scene": "s.toml", "device": "cpu"}
    gains = dict(re.findall(r"(uniform|oracle|at least 1 sample each:|the frame's) ([\d.]+)x", out))
    gains["every pixel shaded"] = re.search(r"oracle, every pixel shaded +([\d.]+)x", out)[1]
    want = {"every pixel shaded": rec["oracle_all"], "uniform": rec["uniform_shaded"], "oracle": rec["oracle_shaded"],
            "at least 1 sample each:": rec["oracle_shaded_min1"], "the frame's": rec["frame"]}
    assert set(gains) == set(want), out
    for k, v in gains.items():
        assert v == f"{want[k]:.3f}", (k, out)
    assert f"rank correlation of the pass's measured variance with the brute force: {rec['rank_measured']:.3f}" in out
    plot_png(tmp_path / "a.png")


@pytest.mark.parametrize("argv, needle", [
    (["--json", "old.json"], "old.json: already exists"),
    (["--plot", "q.png"], "q.png: already exists"),
    (["--json", "new.json"], "new.png: already exists"),
    (["--plot", "a.jpg"], "--plot a.jpg: expected a path ending in .png"),
    (["--json", "s.json", "--plot", "s.toml", "--force"], "--plot s.toml: expected a path ending in .png"),
])
def test_record_outputs_are_refused_before_any_work(ac, monkeypatch, tmp_path, argv, needle):
    """--json / --plot follow warpbw bench's rules, checked before Warp is started or the scene read."""
    monkeypatch.chdir(tmp_path)
    for name in ("s.toml", "old.json", "q.png", "new.png"):
        (tmp_path / name).write_text("kept\n")
    how, ran = _run_main(ac, monkeypatch, ["s.toml", *argv])
    assert how.startswith("WarpbwError") and needle in how and ran == [], how
    assert sorted(p.name for p in tmp_path.iterdir()) == ["new.png", "old.json", "q.png", "s.toml"]
    assert all((tmp_path / n).read_text() == "kept\n" for n in ("s.toml", "old.json", "q.png", "new.png"))


def test_a_frame_with_no_noise_to_allocate_is_refused(ac, monkeypatch):
    """Every gain is a ratio of noise MSEs: a black environment or surfaces that reflect none of the light (every
    v_p 0) printed 'infx' and 'nan' with numpy's "invalid value" warnings, and recorded null gains (exit 0); a camera
    that sees nothing ended in a ZeroDivisionError traceback.  Each is now refused in one line, the black environment
    before the brute-force renders, as warpbw bench refuses it."""
    from warpbw.errors import WarpbwError

    renders = []
    brute_force = ac.per_pixel_variance
    monkeypatch.setattr(ac, "per_pixel_variance", lambda *a, **k: (renders.append(1), brute_force(*a, **k))[1])
    lit = SCENE.format(objects=SPHERE.format(x=0.0, m="bright"))
    black = parse_scene(lit.replace("constant = [1.0, 1.0, 1.0]", "constant = [0.0, 0.0, 0.0]"), ".", "extremes")
    with pytest.raises(WarpbwError, match=r"^extremes: \[environment\] .* is black everywhere \(after its scale and "
                                          r"the clamp of negative values\): no light to sample, so no noise to "
                                          r"allocate"):
        ac.allocation_ceiling(prepare_scene(black), budget=2.0, seeds=2, spp=1)
    assert renders == []
    dark = parse_scene(lit.replace("albedo = [0.8, 0.8, 0.8]", "albedo = [0.0, 0.0, 0.0]"), ".", "extremes")
    with pytest.raises(WarpbwError, match=r"^extremes: every covered pixel reads the same in the 2 brute-force "
                                          r"renders \(surfaces that reflect none of the light\): no noise to allocate"):
        ac.allocation_ceiling(prepare_scene(dark), budget=2.0, seeds=2, spp=1)
    away = parse_scene(lit.replace("look_at = [0.0, 0.0, 0.0]", "look_at = [0.0, 0.0, 12.0]"), ".", "extremes")
    with pytest.raises(WarpbwError, match=r"^extremes: no pixel shows a sphere or mesh, so there is nothing to "
                                          r"allocate \(check \[camera\] position, look_at and fov\)$"):
        ac.allocation_ceiling(prepare_scene(away), budget=2.0, seeds=2, spp=1)


def test_the_plot_draws_each_gain_of_the_record_under_its_name(ac, drawn_figures, tmp_path):
    """Read back (session 78): one bar per noise gain of ``GAINS``, its height the record's figure and its tick the
    figure's name, on a log axis with the 1x line (no gain)."""
    ac.write_plot({**_FIGURES, "scene": "s.toml"}, tmp_path / "a.png")
    (fig,) = drawn_figures
    (ax,) = fig.axes
    (bars,) = ax.containers
    ticks = [t.get_text() for t in ax.get_xticklabels()]
    heights = dict(zip(ticks, (p.get_height() for p in bars.patches)))
    assert heights == {k: _FIGURES[k] for k in ac.GAINS}
    assert [p.get_x() + p.get_width() / 2 for p in bars.patches] == [t for t in ax.get_xticks()]
    assert ax.get_yscale() == "log" and [tuple(ln.get_ydata()) for ln in ax.get_lines()] == [(1.0, 1.0)]
