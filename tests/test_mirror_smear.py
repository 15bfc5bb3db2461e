"""examples/mirror_smear.py: its diagnostic clamp against an independent formula, its figures against relative
MSEs computed here from renders of its protocol, and its refusals of bad options."""
from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from conftest import load_example, plot_png
from warpbw.errors import WarpbwError
from warpbw.io.exr import write_exr
from warpbw.pipeline import prepare_scene, render_adaptive, render_reference


@pytest.fixture(scope="module")
def ms():
    return load_example("mirror_smear")


def _lum(px):
    """Rec. 709 luminance (ITU-R BT.709 weights, written here: the example takes warpbw.bandwidth's own)."""
    return px @ np.array([0.2126, 0.7152, 0.0722])


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), q=st.floats(0.05, 1.0), sun=st.floats(1.0, 1e4))
def test_clamp_caps_luminance_at_the_quantile_and_keeps_each_texels_colour(ms, seed, q, sun):
    rng = np.random.default_rng(seed)
    px = rng.uniform(0.0, 1.0, (8, 16, 3)).astype(np.float32)
    px[2, 3] *= sun   # one HDR texel
    out = ms.clamp_probe_luminance(px, q)
    lum, cap = _lum(px), np.quantile(_lum(px), q)
    np.testing.assert_allclose(_lum(out), np.minimum(lum, cap), rtol=2e-5, atol=1e-7)
    below = lum <= cap
    np.testing.assert_array_equal(out[below], px[below])   # untouched below the cap
    ratio = out / np.maximum(px, 1e-30)                     # one factor per texel: the chromaticity is kept
    keep = (px > 1e-3).all(axis=-1)
    np.testing.assert_allclose(ratio[keep], np.repeat(ratio[keep][:, :1], 3, axis=1), rtol=1e-5)


def _probe(tmp_path, pixels):
    path = tmp_path / "probe.exr"
    write_exr(path, np.asarray(pixels, np.float32))
    return path


def test_clamped_bandwidth_leaves_the_shading_and_the_probe_alone(ms, tmp_path):
    rng = np.random.default_rng(3)
    px = rng.uniform(0.05, 1.0, (32, 64, 3)).astype(np.float32)
    px[8:10, 20:22] = 1e3
    prep = prepare_scene(ms.mirror_scene(_probe(tmp_path, px), 1e-3, 16))
    before = render_reference(prep, 2, seed=5, mis=True).image
    env = prep.env
    ms.prepare_with_clamped_bandwidth(prep, 0.9)
    assert prep.env is env and prep.bandwidth is not None
    np.testing.assert_array_equal(render_reference(prep, 2, seed=5, mis=True).image, before)


def test_clamped_bandwidth_reads_the_clamped_probe_whatever_the_cache_holds(ms, tmp_path, monkeypatch):
    """--clamp-quantile's nu_a map is the clamped probe's own, after a render of the whole probe, and leaves the
    whole probe's map in the cache for the renders after it.  The pass keys the cache by the probe's source digest
    (the probe before its exposure): the clamped pixels under that key read the whole probe's map where a render
    had cached it, and left theirs for every later render.  Truth: each probe's analysis in a cache of its own."""
    import warpbw.bandwidth as wb
    from warpbw.pipeline import prepare_bandwidth

    monkeypatch.setenv("WARPBW_CACHE", str(tmp_path / "cache"))
    rng = np.random.default_rng(3)
    px = rng.uniform(0.05, 1.0, (32, 64, 3)).astype(np.float32)
    px[8:10, 20:22] = 1e3
    scene = ms.mirror_scene(_probe(tmp_path, px), 1e-3, 8)
    read = []
    analyse = wb.env_bandwidth_map

    def spy(*a, **k):
        nu, origin = analyse(*a, **k)
        read.append(nu)
        return nu, origin
    monkeypatch.setattr(wb, "env_bandwidth_map", spy)
    pixels = prepare_scene(scene).env.pixels
    whole = analyse(pixels, "whole", cache=tmp_path / "c1")[0]
    clamped = analyse(ms.clamp_probe_luminance(pixels, 0.9), "clamped", cache=tmp_path / "c2")[0]
    assert np.abs(whole - clamped).max() > 1.0   # the clamp changes the map
    prepare_bandwidth(prepare_scene(scene))                                # a render of the whole probe first
    np.testing.assert_array_equal(read[-1], whole)
    ms.prepare_with_clamped_bandwidth(prepare_scene(scene), 0.9)
    np.testing.assert_array_equal(read[-1], clamped)
    prepare_bandwidth(prepare_scene(scene))                                # and one after it
    np.testing.assert_array_equal(read[-1], whole)


def test_written_scene_renders_as_the_scripts_own(ms, tmp_path):
    """--write-scene: the file parses to the scene the script renders (the same image, bit for bit, at one seed),
    renders nothing else, and is not overwritten without --force."""
    from warpbw.scene import load_scene

    probe = _probe(tmp_path, np.random.default_rng(4).uniform(0.05, 2.0, (16, 32, 3)))
    out = tmp_path / "scenes"
    assert ms.main(["--probe", str(probe), "--alpha", "0.01", "--res", "12,16", "--write-scene", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["mirror_12.toml", "mirror_16.toml"]
    mine = render_reference(prepare_scene(ms.mirror_scene(probe, 0.01, 16)), 2, seed=3, mis=True).image
    written = render_reference(prepare_scene(load_scene(out / "mirror_16.toml")), 2, seed=3, mis=True).image
    np.testing.assert_array_equal(written, mine)
    before = (out / "mirror_12.toml").read_text()
    with pytest.raises(WarpbwError, match="mirror_12.toml: already exists .*--force"):
        ms.main(["--probe", str(probe), "--alpha", "0.5", "--res", "12", "--write-scene", str(out)])
    assert (out / "mirror_12.toml").read_text() == before
    ms.main(["--probe", str(probe), "--alpha", "0.5", "--res", "12", "--write-scene", str(out), "--force"])
    assert "alpha = 0.5" in (out / "mirror_12.toml").read_text()


def test_a_relative_probe_path_is_read_from_the_working_directory(ms, tmp_path, monkeypatch):
    # the README runs it as --probe ../shared/data/envmaps/city.exr: the path is the shell's, not the scene's
    (tmp_path / "probes").mkdir()
    _probe(tmp_path / "probes", np.random.default_rng(5).uniform(0.05, 2.0, (8, 16, 3)))
    (tmp_path / "work").mkdir()
    monkeypatch.chdir(tmp_path / "work")
    sc = ms.mirror_scene(Path("../probes/probe.exr"), 0.05, 8)
    assert Path(sc.environment.file) == tmp_path / "probes" / "probe.exr"
    assert ms.main(["--probe", "../probes/probe.exr", "--res", "8", "--truth-spp", "4", "--worst", "0"]) == 0


def _relmse(test, truth, cov):
    """Rousselle et al.'s relative MSE with eps = 0.01 over covered pixels and channels, written out here."""
    a, b = test[cov].astype(np.float64), truth[cov].astype(np.float64)
    return float(np.mean((a - b) ** 2 / (b * b + 0.01)))


@pytest.mark.parametrize("signal", ["radiance", "log"])
def test_measure_compares_both_frames_with_the_truth_as_its_docstring_says(ms, tmp_path, signal):
    """Both frames at seed s, the truth at seed s + 1 and truth_spp, MIS; the shares from the same errors."""
    rng = np.random.default_rng(11)
    px = rng.uniform(0.05, 2.0, (16, 32, 3)).astype(np.float32)
    probe = _probe(tmp_path, px)
    r = ms.measure(probe, 0.05, 16, budget=2.0, truth_spp=8, seed=4, clamp_q=1.0, worst=3, env_signal=signal)
    prep = prepare_scene(ms.mirror_scene(probe, 0.05, 16))
    truth = render_reference(prep, 8, seed=5, mis=True)
    cov = truth.coverage.astype(bool)
    ada = render_adaptive(prep, 2.0, seed=4, mis=True, env_signal=signal).image
    assert r["covered_pixels"] == int(cov.sum()) > 50
    assert r["relmse_reference"] == pytest.approx(
        _relmse(render_reference(prep, 2, seed=4, mis=True).image, truth.image, cov), rel=1e-6)
    assert r["relmse_adaptive"] == pytest.approx(_relmse(ada, truth.image, cov), rel=1e-6)
    err = ((ada - truth.image) ** 2 / (truth.image ** 2 + 0.01)).sum(axis=-1) * cov
    top = r["worst"][0]
    assert err[top["y"], top["x"]] == pytest.approx(err.max(), rel=1e-6)
    assert top["share"] == pytest.approx(err.max() / err.sum(), rel=1e-5)
    shares = [p["share"] for p in r["worst"]]
    assert shares == sorted(shares, reverse=True) and r["worst_share"] == pytest.approx(sum(shares))


@pytest.mark.parametrize("argv, match", [
    (["--clamp-quantile", "0"], "--clamp-quantile"),
    (["--clamp-quantile", "1.5"], "--clamp-quantile"),
    (["--res", "32,x"], "--res"),
    (["--res", "4"], "--res"),
    (["--budget", "2.5"], "--budget"),
    (["--alpha", "-1"], "--alpha"),
])
def test_bad_options_are_refused_by_name(ms, tmp_path, argv, match):
    probe = _probe(tmp_path, np.ones((4, 8, 3), np.float32))
    with pytest.raises(WarpbwError, match=match):
        ms.main(["--probe", str(probe)] + argv)


def test_a_missing_probe_is_refused_by_name(ms, tmp_path):
    with pytest.raises(WarpbwError, match="--probe .*no such file"):
        ms.main(["--probe", str(tmp_path / "nope.exr")])


def test_a_black_probe_is_refused_before_any_render(ms, tmp_path, monkeypatch):
    """A probe black everywhere (here but for a negative texel, which loading clamps to 0) leaves the mirror black:
    every relative MSE 0, a record of zeros, matplotlib's "Data has no positive values, and therefore cannot be
    log-scaled" for the plot, exit 0.  It is refused once the probe is read, before any render, as warpbw bench
    refuses it."""
    px = np.zeros((8, 16, 3), np.float32)
    px[3, 5] = -1.0
    probe = _probe(tmp_path, px)
    monkeypatch.setattr(ms, "measure", lambda *a, **k: pytest.fail("rendered"))
    with pytest.warns(RuntimeWarning, match="3 negative"):
        with pytest.raises(WarpbwError, match=r"^--probe .*probe\.exr: black everywhere \(after the clamp of negative "
                                              r"values\): the mirror reflects nothing and every error is 0 \(expected "
                                              r"a probe with light in it\)$"):
            ms.main(["--probe", str(probe), "--res", "8", "--budget", "1", "--truth-spp", "1",
                     "--json", str(tmp_path / "m.json")])
    assert not (tmp_path / "m.json").exists()


def test_measure_reports_the_shaded_share_and_the_worst_pixels_values_of_the_covered_pixels(ms, tmp_path):
    """The shaded share is over the pixels the sphere covers (the truth: the adaptive frame's own "shaded" AOV over
    the truth's coverage, counted here, not over the whole image); each listed pixel's truth and adaptive
    values are those frames' channel means there."""
    px = np.random.default_rng(12).uniform(0.05, 2.0, (16, 32, 3)).astype(np.float32)
    px[4:6, 10:12] = 200.0                        # a bright patch: some pixels get shaded, not all
    probe = _probe(tmp_path, px)
    r = ms.measure(probe, 0.05, 16, budget=2.0, truth_spp=8, seed=4, clamp_q=1.0, worst=3)
    prep = prepare_scene(ms.mirror_scene(probe, 0.05, 16))
    truth = render_reference(prep, 8, seed=5, mis=True)
    cov = truth.coverage.astype(bool)
    ada = render_adaptive(prep, 2.0, seed=4, mis=True)
    shaded = np.asarray(ada.aovs["shaded"], bool)
    assert 0 < cov.sum() < cov.size and shaded[cov].sum() > 0
    assert r["shaded_fraction"] == pytest.approx(shaded[cov].sum() / cov.sum(), rel=1e-12)
    assert r["samples_per_covered_pixel"] == pytest.approx(ada.stats["samples_per_covered_pixel"], rel=1e-12)
    for p in r["worst"]:
        assert p["truth"] == pytest.approx(float(truth.image[p["y"], p["x"]].mean()), rel=1e-6)
        assert p["adaptive"] == pytest.approx(float(ada.image[p["y"], p["x"]].mean()), rel=1e-6)
        assert p["shaded"] == bool(shaded[p["y"], p["x"]])


def test_nu_a_quantiles_read_the_signal_asked_for(ms, tmp_path, monkeypatch):
    """--env-signal log: the reported nu_a quantiles are those of the log analysis (warpbw.bandwidth's map on that
    signal, at NU_A_QUANTILES), which on a probe with a small, very bright sun differ from the radiance's."""
    from warpbw.bandwidth import env_bandwidth_map

    monkeypatch.setenv("WARPBW_CACHE", str(tmp_path / "_cache"))   # the maps are cached: not in ~/.cache

    px = np.random.default_rng(6).uniform(0.05, 1.0, (32, 64, 3)).astype(np.float32)
    px[6:8, 40:42] = 5e3
    got = {s: ms.nu_a_quantiles(px, "p", s) for s in ("radiance", "log")}
    for s, q in got.items():
        nu, _ = env_bandwidth_map(px, "p", signal=s)
        np.testing.assert_allclose(q, np.quantile(nu, ms.NU_A_QUANTILES), rtol=1e-6)   # float32 map
    assert got["log"] != pytest.approx(got["radiance"], rel=1e-3)


@pytest.mark.parametrize("signal", ["radiance", "log"])
def test_measure_hands_the_env_signal_to_the_adaptive_frame(ms, tmp_path, monkeypatch, signal):
    """--env-signal decides what the adaptive frame's bandwidth pass reads (the module docstring): measure hands
    it to render_adaptive, whichever it is (a fixed default would leave the "log" rows measuring "radiance")."""
    import warpbw.pipeline
    from conftest import Handed, capture_call

    probe = tmp_path / "p.exr"
    write_exr(probe, np.random.default_rng(3).uniform(0.1, 1.0, (8, 16, 3)).astype(np.float32))
    got = capture_call(monkeypatch, warpbw.pipeline, "render_adaptive")
    with pytest.raises(Handed):
        ms.measure(probe, 0.05, 8, budget=1.0, truth_spp=1, seed=2, clamp_q=1.0, worst=1, env_signal=signal)
    assert got["env_signal"] == signal and got["seed"] == 2 and got["_args"][1] == 1.0


def test_record_and_plot_hold_the_printed_figures(ms, tmp_path, capsys):
    """DESIGN.md, measurement protocol: every benchmark writes a JSON record and a PNG plot.  The script wrote the
    record alone; --plot now writes both frames' relMSE and the shaded fraction against resolution beside it, and
    the record's figures are those printed (at their printed precision)."""
    probe = _probe(tmp_path, np.random.default_rng(5).uniform(0.05, 2.0, (8, 16, 3)))
    assert ms.main(["--probe", str(probe), "--res", "8,16", "--truth-spp", "4", "--budget", "1", "--worst", "2",
                    "--plot", str(tmp_path / "m.png")]) == 0
    out = capsys.readouterr().out
    rec = json.loads((tmp_path / "m.json").read_text())
    assert (rec["budget"], rec["truth_spp"], rec["seed"], rec["device"]) == (1.0, 4, 1, "cpu")
    printed = re.findall(r"^ *(\d+)x(\d+) +reference (\S+) +adaptive (\S+) \(shaded (\d+)%, ([\d.]+) samples per "
                         r"covered pixel; its (\d+) worst pixels hold (\d+)% of its error\)$", out, flags=re.M)
    assert [int(p[0]) for p in printed] == [r["res"] for r in rec["rows"]] == [8, 16], out
    for p, r in zip(printed, rec["rows"]):
        assert p[2:] == (f"{r['relmse_reference']:.3g}", f"{r['relmse_adaptive']:.3g}",
                         f"{r['shaded_fraction']:.0%}"[:-1], f"{r['samples_per_covered_pixel']:.2f}",
                         str(len(r["worst"])), f"{r['worst_share']:.0%}"[:-1])
    plot_png(tmp_path / "m.png")


@pytest.mark.parametrize("argv, needle", [
    (["--json", "old.json"], "old.json: already exists"),
    (["--plot", "q.png"], "q.png: already exists"),
    (["--json", "new.json"], "new.png: already exists"),
    (["--plot", "m.jpg"], "--plot m.jpg: expected a path ending in .png"),
    (["--json", "probe.json", "--plot", "probe.exr", "--force"], "--plot probe.exr: expected a path ending in .png"),
])
def test_record_outputs_are_refused_before_any_work(ms, tmp_path, monkeypatch, argv, needle):
    """--json / --plot follow warpbw bench's rules, checked before Warp is started or the probe read."""
    from conftest import Handed

    monkeypatch.chdir(tmp_path)
    probe = _probe(tmp_path, np.ones((8, 16, 3)))
    for name in ("old.json", "q.png", "new.png"):
        (tmp_path / name).write_text("kept\n")
    monkeypatch.setattr(ms, "init_warp", lambda dev: (_ for _ in ()).throw(Handed()))
    with pytest.raises(WarpbwError, match=re.escape(needle)):
        ms.main(["--probe", str(probe), "--res", "8", *argv])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["new.png", "old.json", "probe.exr", "q.png"]
    assert all((tmp_path / n).read_text() == "kept\n" for n in ("old.json", "q.png", "new.png"))
