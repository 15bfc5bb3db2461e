"""warpbw bench: the equal-quality interpolation against a closed form, and a tiny end-to-end run.  The scripts
examples/bench_reference.py and bench_scenes.py, with stand-ins for the renders, the ground truth, the clock and
the commands they run: their figures against values worked by hand, their options and documented defaults."""
from __future__ import annotations

import json
import math
import sys
import warnings
from pathlib import Path
from types import SimpleNamespace

if sys.version_info >= (3, 11):
    import tomllib
else:   # Python 3.10: the backport pyproject installs there, as warpbw.scene reads it
    import tomli as tomllib

import numpy as np
import pytest

from conftest import MIXED_SCENE, StandInClock, capture_call, killed_writer_temp, load_example, outcome
from warpbw import bench
from warpbw.cli import main as cli_main
from warpbw.errors import WarpbwError

SCENE = """
[camera]
position = [0.0, 0.0, 4.0]
look_at = [0.0, 0.0, 0.0]
fov = 30.0
resolution = [24, 24]
[environment]
procedural = "sky"
[[object]]
shape = "sphere"
center = [0.0, 0.0, 0.0]
radius = 1.0
material = "m"
[material.m]
type = "lambert"
albedo = [0.5, 0.5, 0.5]
"""


def test_equal_quality_interpolates_on_log_log():
    # reference: MSE = 8 / spp^0.7, time = 0.01 spp (exact power laws: log-log interpolation is exact; with
    # 1 / spp itself, interpolating spp linearly in 1 / MSE would be exact too)
    ref = [{"spp": s, "mse": 8.0 / s ** 0.7, "time_s": 0.01 * s} for s in (1, 2, 4, 8, 16, 32)]
    spp, t, ext = bench.equal_quality_time(ref, 8.0 / 11.0 ** 0.7)
    assert math.isclose(spp, 11.0, rel_tol=1e-9) and math.isclose(t, 0.11, rel_tol=1e-9) and not ext
    spp, t, ext = bench.equal_quality_time(ref, 8.0 / 64.0 ** 0.7)   # beyond the measured counts
    assert ext and math.isclose(spp, 64.0, rel_tol=1e-9)


def _psnr_of_mean(m):
    return -10.0 * np.log10(m.mean(axis=-1))   # peak 1


@pytest.mark.parametrize("runs", [3, 8])
def test_psnr_standard_error_matches_the_spread_of_repeated_benchmarks(runs):
    """Brute force: repeat a 'benchmark' of ``runs`` runs whose MSEs are gamma-distributed (coefficient of
    variation 0.3, as one run's MSE at a few spp) 20,000 times; the RMS of the delta-method standard errors
    matches the spread of the PSNRs of the mean MSE within 10%."""
    rng = np.random.default_rng(1)
    m = rng.gamma(11.0, 1e-4 / 11.0, size=(20000, runs))
    truth = _psnr_of_mean(m).std()
    se = np.array([bench.psnr_standard_error(row) for row in m])
    assert abs(math.sqrt(np.mean(se ** 2)) / truth - 1.0) < 0.1
    assert bench.psnr_standard_error([2e-4]) is None and bench.psnr_standard_error([0.0, 0.0]) is None
    # no MSE is negative or infinite: [-1, 3] read 8.69 dB
    assert bench.psnr_standard_error([-1.0, 3.0]) is None and bench.psnr_standard_error([1e-4, math.inf]) is None


def test_paired_difference_se_sees_what_shared_seeds_cancel():
    """Two settings whose runs share a firefly factor run by run (log-normal, sigma 0.5) on top of their own
    noise (sigma 0.05): the paired standard error matches the brute-force spread of the PSNR difference
    within 15%, and is far below the two points' standard errors combined as if independent."""
    rng = np.random.default_rng(2)
    runs, reps = 8, 20000
    shared = rng.lognormal(0.0, 0.5, size=(reps, runs))
    a = 1e-4 * shared * rng.lognormal(0.0, 0.05, size=(reps, runs))
    b = 1.2e-4 * shared * rng.lognormal(0.0, 0.05, size=(reps, runs))
    d = 10.0 * np.log10(a / b).mean(axis=1)   # the paired per-run differences' mean
    se = np.array([bench.paired_difference_se(x, y) for x, y in zip(a, b)])
    assert abs(math.sqrt(np.mean(se ** 2)) / d.std() - 1.0) < 0.15
    independent = np.hypot(bench.psnr_standard_error(a[0]), bench.psnr_standard_error(b[0]))
    assert se[0] < 0.3 * independent
    assert bench.paired_difference_se([1e-4], [1e-4]) is None
    assert bench.paired_difference_se([1e-4, math.inf], [1e-4, 2e-4]) is None    # was NaN


def test_bench_cli_writes_json_and_plot(tmp_path, capsys):
    """Every benchmark writes its record and its plot (DESIGN.md): given --json alone, the plot goes beside it.
    One run is allowed, with a warning that the protocol's time is a median of three."""
    scene = tmp_path / "s.toml"
    scene.write_text(SCENE)
    out, png = tmp_path / "b.json", tmp_path / "b.png"
    rc = cli_main(["bench", str(scene), "--json", str(out), "--spp", "1,4",
                   "--budgets", "1,4", "--nb", "1,4", "--gt-spp", "64", "--runs", "1", "--cache", str(tmp_path / "gt"),
                   "--seed", "7", "-q"])
    assert rc == 0 and png.stat().st_size > 0
    assert "--runs 1: the measurement protocol times the median of at least 3 runs" in capsys.readouterr().err
    r = json.loads(out.read_text())
    for key in ("scene", "ground_truth_spp", "methods", "equal_quality_speedup", "bandwidth_time_fraction"):
        assert key in r
    assert r["seed"] == 7 and r["device"] == "cpu"   # two records at different --seed told apart (clifuzz F12)
    assert [x["spp"] for x in r["methods"]["reference"]] == [1, 4]
    for rec in r["methods"]["adaptive"]:
        assert {"budget", "time_s", "psnr_db", "relmse", "bandwidth_time_s"} <= set(rec)
        assert rec["time_s"] > 0 and rec["bandwidth_time_s"] >= 0
    assert [x["n_b"] for x in r["nb_sweep"]] == [1, 4]
    assert r["nb_sweep"][0]["psnr_se_db"] is None and r["nb_psnr_range_se_db"] is None   # one run: no spread
    assert list((tmp_path / "gt").glob("ground_truth-*.exr"))  # cached
    # nothing is overwritten without --force
    assert cli_main(["bench", str(scene), "--json", str(out), "--gt-spp", "64", "-q"]) == 2


def test_bench_of_planes_beside_a_sphere_measures_the_visible_sphere(tmp_path):
    """A sphere sunk into a floor: bench measures the sphere where the floor does not hide it.  The hidden
    pixels (the sphere-only render's coverage that the floor's distance clips, counted independently here)
    are left out of the covered pixels, the cached ground truth is black there and keyed by the whole scene,
    and the table says so."""

    from warpbw.filtering import plane_distance
    from warpbw.io.exr import read_exr
    from warpbw.pipeline import render_reference, split_planes
    from warpbw.scene import parse_scene

    scene = parse_scene(MIXED_SCENE, tmp_path, "mixed.toml")
    rec = bench.run_bench(scene, spp_list=(1, 4), budgets=(1,), gt_spp=64, runs=1, cache_dir=tmp_path / "gt",
                          progress=False, log=lambda *a, **k: None)
    sphere_only, planes = split_planes(scene)
    cov = render_reference(sphere_only, 1).gbuffer
    t_plane = plane_distance(planes)
    o = np.asarray([0.0, 1.5, 3.0])                                          # the camera's position
    t_sphere = np.linalg.norm(cov.numpy("position") - o, axis=-1)          # distance along each centre ray
    sphere = cov.coverage
    hidden = sphere & (t_sphere > t_plane + 1e-4)
    assert hidden.sum() > 3 and (sphere & ~hidden).sum() > 50
    assert rec["planes"]["pixels_hidden"] == int(hidden.sum())
    assert rec["pixels_covered"] == int(sphere.sum() - hidden.sum())
    chunks = sorted((tmp_path / "gt").glob(f"ground_truth-{bench.gt_key(scene, bench.GT_SEED)}-*.exr"))
    assert len(chunks) == 2
    gt = read_exr(chunks[0]).pixels[..., :3]
    assert np.all(gt[hidden] == 0) and np.all(gt[sphere & ~hidden].sum(-1) > 0)
    assert "pixels hidden by 1 plane(s) left out" in bench.format_table(rec)


@pytest.mark.parametrize("args, match", [(["--budgets", "0,1"], "budgets"), (["--spp", "x"], "spp"),
                                         (["--plot", "p.jpg"], ".png"), ([], "--json")])
def test_bench_bad_arguments(tmp_path, capsys, args, match):
    scene = tmp_path / "s.toml"
    scene.write_text(SCENE)
    extra = [] if args == [] or "--plot" in args else ["--json", str(tmp_path / "o.json")]
    try:
        rc = cli_main(["bench", str(scene), *extra, *args])
    except SystemExit as exc:  # argparse usage errors exit from parse_args
        rc = exc.code
    assert rc == 2
    err = capsys.readouterr().err
    assert match in err and "Traceback" not in err


def test_bench_records_the_runs_and_their_standard_errors(tmp_path):
    """With two runs every point keeps its runs' MSEs (their mean is the point's MSE), its PSNR's standard error,
    and the n_b sweep the paired standard error of its two ends; the table prints them.  The standard errors of two
    runs by hand (not from bench's own helpers, which gave the expected values before): the sample standard
    deviation of m1, m2 is |m1 - m2| / sqrt(2), so the PSNR's is (10 / ln 10) |m1 - m2| / (m1 + m2), and the paired
    difference's, of per-run differences d1, d2, is |d1 - d2| / 2."""
    from warpbw.scene import parse_scene

    scene = parse_scene(SCENE, tmp_path, "s.toml")
    rec = bench.run_bench(scene, spp_list=(1, 4, 16), budgets=(1,), nb_list=(1, 4), gt_spp=64, runs=2,
                          cache_dir=tmp_path / "gt", progress=False, log=lambda *a, **k: None)
    points = rec["methods"]["reference"] + rec["methods"]["adaptive"] + rec["nb_sweep"]
    for p in points:
        assert len(p["mse_runs"]) == 2 and math.isclose(p["mse"], np.mean(p["mse_runs"]), rel_tol=1e-12)
        m1, m2 = p["mse_runs"]
        assert p["psnr_se_db"] == pytest.approx(10 / math.log(10) * abs(m1 - m2) / (m1 + m2), rel=1e-12)
        assert p["psnr_se_db"] > 0
    for p in rec["methods"]["adaptive"]:
        assert p["equal_quality_speedup_se"] == p["equal_quality_speedup"] * bench.speedup_relative_se(
            rec["methods"]["reference"], p["mse"], p["psnr_se_db"])
    nb = rec["nb_sweep"]
    lo, hi = sorted(nb, key=lambda p: p["psnr_db"])
    d1, d2 = (10 * math.log10(a / b) for a, b in zip(lo["mse_runs"], hi["mse_runs"]))
    assert rec["nb_psnr_range_se_db"] == pytest.approx(abs(d1 - d2) / 2, rel=1e-9)
    table = bench.format_table(rec)
    assert f"{points[0]['psnr_se_db']:.2f}" in table and "over 2 paired runs" in table
    assert f"{rec['bandwidth_pass_reference_spp']:.1f} samples per pixel" in table
    json.dumps(rec, allow_nan=False)   # the record stays valid JSON


def test_bench_table_says_where_the_frame_goes(tmp_path):
    """Under an environment and a directional light, the table breaks the best budget's frame into every stage the
    frame timed: the record's stage times add up to the frame's (within the stats' rounding), and the table names
    them all, in order."""
    from warpbw.scene import parse_scene

    scene = parse_scene(MIXED_SCENE, tmp_path, "s.toml")
    rec = bench.run_bench(scene, spp_list=(1, 4, 16), budgets=(1,), gt_spp=64, runs=1, cache_dir=tmp_path / "gt",
                          progress=False, log=lambda *a, **k: None)
    best = next(p for p in rec["methods"]["adaptive"] if p["budget"] == rec["equal_quality_budget"])
    assert best["lights_time_s"] > 1e-5
    # the stages account for the frame (each rounded to a microsecond in the stats)
    assert sum(best[key] for _, key in bench.FRAME_STAGES) == pytest.approx(best["frame_time_s"], abs=4e-6)
    line = next(x for x in bench.format_table(rec).splitlines() if x.startswith("where the frame's time goes"))
    assert line.startswith(f"where the frame's time goes at budget {best['budget']:g}")
    assert [part.rsplit(" ", 2)[0] for part in line.split(": ", 1)[1].split(", ")] == [
        name for name, _ in bench.FRAME_STAGES]


def test_pass_in_reference_spp_reads_the_reference_at_its_largest_count():
    """The pass's time over the reference's shading time per sample per pixel, read at the largest count (its
    fixed costs weigh least there); None without an adaptive point or a reference."""
    refs = [{"spp": 1, "shading_time_s": 0.3}, {"spp": 8, "shading_time_s": 0.8}, {"spp": 4, "shading_time_s": 0.5}]
    assert bench.pass_in_reference_spp({"bandwidth_time_s": 0.25}, refs) == pytest.approx(2.5)
    assert bench.pass_in_reference_spp(None, refs) is None
    assert bench.pass_in_reference_spp({"bandwidth_time_s": 0.25}, []) is None
    assert bench.pass_in_reference_spp({"bandwidth_time_s": 0.25}, [{"spp": 0, "shading_time_s": 0.1}]) is None


def test_speedup_standard_error_follows_the_power_law_and_brute_force():
    """Closed form: with the reference's MSE = 8 / spp at a time 0.01 spp, t_eq = 0.08 / MSE, so the speed-up's
    relative standard error is the two curves' log-MSE standard errors combined (half that at a time 0.01
    sqrt(spp)).  Brute force: 5,000 repeated
    benchmarks whose every run's MSE is gamma-noisy (coefficient of variation 0.3, 8 runs per point); the RMS of
    the predicted errors matches the spread of log speed-up within 15%."""
    spps = (1, 2, 4, 8, 16, 32)
    se_a, se_r = 0.3, 0.2
    ref = [{"spp": s, "mse": 8.0 / s, "time_s": 0.01 * s, "psnr_se_db": se_r} for s in spps]
    rel = bench.speedup_relative_se(ref, 8.0 / 11.0, se_a)
    assert math.isclose(rel, math.hypot(se_a, se_r) / bench.DB_PER_LN, rel_tol=1e-6)
    # a time growing as sqrt(spp) (fixed costs): t_eq ~ MSE^-1/2, half the relative error
    slow = [{**r, "time_s": 0.01 * math.sqrt(r["spp"])} for r in ref]
    assert math.isclose(bench.speedup_relative_se(slow, 8.0 / 11.0, se_a), rel / 2.0, rel_tol=1e-6)
    assert bench.speedup_relative_se(ref, 8.0 / 11.0, None) is None
    assert bench.speedup_relative_se([{**r, "psnr_se_db": None} for r in ref], 8.0 / 11.0, se_a) is None

    rng = np.random.default_rng(3)
    runs, shape = 8, 1.0 / 0.3 ** 2
    logs, preds = [], []
    for _ in range(5000):
        rec = []
        for s in spps:
            m = rng.gamma(shape, 8.0 / s / shape, size=runs)
            rec.append({"spp": s, "mse": m.mean(), "time_s": 0.01 * s, "psnr_se_db": bench.psnr_standard_error(m)})
        a = rng.gamma(shape, (8.0 / 11.0) / shape, size=runs)
        _, t_eq, _ = bench.equal_quality_time(rec, a.mean())
        logs.append(math.log(t_eq / 0.01))
        preds.append(bench.speedup_relative_se(rec, a.mean(), bench.psnr_standard_error(a)))
    assert abs(math.sqrt(np.mean(np.square(preds))) / np.std(logs) - 1.0) < 0.15


def _fake_adaptive_result(image, cov, t, budget, pass_share=0.1, over_budget=False):
    """What a fake render_adaptive returns: its image, and a frame time t split over the stages (``pass_share`` of
    it, a tenth by default, in the bandwidth pass); ``over_budget``: its allocation's flag."""
    ts = {"bandwidth": pass_share * t, "shading": (0.8 - pass_share) * t, "upsampling": 0.1 * t,
          "hierarchy": 0.05 * t, "gbuffer": 0.05 * t, "frame": t}
    return SimpleNamespace(image=image, coverage=cov,
                           stats={"time_s": ts, "shaded_fraction": 0.5, "samples": 10,
                                  "samples_per_covered_pixel": max(float(budget), 1.0 if over_budget else 0.0),
                                  "allocation": {"over_budget": over_budget}})


def test_bench_figures_follow_closed_forms_with_fake_renderers(tmp_path, monkeypatch):
    """Renderers whose errors and times are known exactly: the reference's MSE is 8 k / spp^0.7 (k the runs'
    mean error factor) at 0.01 s per spp, the adaptive frame's error and time are set per budget, and a
    pixel outside the coverage carries a huge error.  Then PSNR, relative MSE, the equal-quality spp, time
    and speed-up, and the best budget follow in closed form (log-log interpolation is exact on power laws)."""

    from warpbw import pipeline
    from warpbw.metrics import RELMSE_EPS
    from warpbw.scene import parse_scene

    h = w = 24
    yy, xx = np.mgrid[0:h, 0:w]
    cov = (yy - 11.5) ** 2 + (xx - 11.5) ** 2 < 10 ** 2
    truth = (0.2 + 0.6 * np.stack([xx / w, yy / h, np.full((h, w), 0.5)], -1)).astype(np.float32) * cov[..., None]
    sign = np.where((yy + xx) % 2 == 0, 1.0, -1.0)[..., None]     # the error's pattern: +/- a in every channel
    run_factor = (1.0, 1.1)                                        # run r's error amplitude is scaled by this
    k = np.mean(np.square(run_factor))
    clock = StandInClock()
    monkeypatch.setattr(bench, "time", clock)
    # adaptive: budget -> (reference spp it matches, its frame time, the bandwidth pass's share of that time)
    ada = {1.0: (11.0, 0.02, 0.1), 2.0: (40.0, 0.05, 0.2), 4.0: (100.0, 0.5, 0.3)}

    def image(amplitude):
        out = truth + amplitude * sign * cov[..., None]
        out[0, 0] = 1e3                                            # uncovered: must not count
        return out.astype(np.float32)

    def fake_reference(prep, spp, seed=0, mis=False, **kw):
        if seed >= 1_000_000:                                      # the ground truth's chunks: exact
            return SimpleNamespace(image=truth.copy(), coverage=cov, stats={})
        r = seed - 101 * spp if 0 <= seed - 101 * spp < len(run_factor) else 0   # run r (0 for the warm-up)
        clock.now += 0.01 * spp
        amp = run_factor[r] * math.sqrt(8.0 / spp ** 0.7)
        return SimpleNamespace(image=image(amp), coverage=cov,
                               stats={"time_s": {"shading": 0.009 * spp, "gbuffer": 0.001 * spp}})

    def fake_adaptive(prep, budget, seed=0, mis=False, **kw):
        spp_eq, t, share = ada.get(float(budget), (1.0, 0.01, 0.1))   # the warm-up frame is budget 1 too
        r = seed // 7
        clock.now += t
        amp = run_factor[r] * math.sqrt(8.0 / spp_eq ** 0.7)
        return _fake_adaptive_result(image(amp), cov, t, budget, share)

    monkeypatch.setattr(pipeline, "render_reference", fake_reference)
    monkeypatch.setattr(pipeline, "render_adaptive", fake_adaptive)
    scene = parse_scene(SCENE, tmp_path, "s.toml")
    rec = bench.run_bench(scene, spp_list=(1, 4, 16, 64, 256), budgets=(1, 2, 4), gt_spp=64, runs=2,
                          cache_dir=tmp_path / "gt", progress=False, log=lambda *a, **kw: None)
    peak = float(truth[cov].max())
    t_cov = truth[cov].astype(np.float64)
    for p in rec["methods"]["reference"] + rec["methods"]["adaptive"]:
        spp = p.get("spp") or ada[p["budget"]][0]
        m = 8.0 * k / spp ** 0.7
        assert math.isclose(p["mse"], m, rel_tol=1e-4), p
        assert math.isclose(p["psnr_db"], 10 * math.log10(peak ** 2 / m), abs_tol=1e-4), p
        rel = np.mean([np.mean(f * f * 8.0 / spp ** 0.7 / (t_cov ** 2 + RELMSE_EPS)) for f in run_factor])
        assert math.isclose(p["relmse"], rel, rel_tol=1e-4), p
    for p in rec["methods"]["reference"]:
        assert math.isclose(p["time_s"], 0.01 * p["spp"], rel_tol=1e-9)
    for p in rec["methods"]["adaptive"]:
        spp_eq, t, share = ada[p["budget"]]
        assert math.isclose(p["equal_quality_spp"], spp_eq, rel_tol=1e-4), p
        assert math.isclose(p["equal_quality_reference_time_s"], 0.01 * spp_eq, rel_tol=1e-4), p
        assert math.isclose(p["equal_quality_speedup"], 0.01 * spp_eq / t, rel_tol=1e-4), p
        assert math.isclose(p["bandwidth_time_fraction"], share, rel_tol=1e-9) and not p["extrapolated"]
    # speed-ups 5.5x, 8x and 2x: the best is budget 2's, and the record's headline figures are that frame's (the
    # bandwidth pass's share of the first budget's frame passed while every frame's share was the same)
    assert rec["equal_quality_budget"] == 2.0 and math.isclose(rec["equal_quality_speedup"], 8.0, rel_tol=1e-4)
    assert math.isclose(rec["bandwidth_time_fraction"], 0.2, rel_tol=1e-9)
    assert rec["pixels_covered"] == int(cov.sum()) and rec["ground_truth_doubling_delta_db"] == 0.0


def test_a_scene_with_nothing_to_measure_is_a_clear_error(tmp_path, monkeypatch):
    """An all-black probe, and a probe whose light reaches no visible pixel (every frame then equals the ground
    truth exactly), stopped in a ZeroDivisionError traceback at the ground truth's doubling check."""
    from warpbw import pipeline
    from warpbw.io.exr import write_exr
    from warpbw.scene import parse_scene

    write_exr(tmp_path / "zero.exr", np.zeros((8, 16, 3), np.float32))
    black = parse_scene(SCENE.replace('procedural = "sky"', 'file = "zero.exr"'), tmp_path, "black.toml")
    with pytest.raises(WarpbwError, match="black.toml: \\[environment\\] 'zero.exr' is black everywhere"):
        bench.run_bench(black, spp_list=(1,), budgets=(1,), gt_spp=64, runs=1, cache_dir=tmp_path / "gt",
                        progress=False, log=lambda *a, **kw: None)
    cov = np.zeros((24, 24), bool)
    cov[8:16, 8:16] = True
    still = np.zeros((24, 24, 3), np.float32)
    monkeypatch.setattr(pipeline, "render_reference", lambda prep, spp, seed=0, mis=False, **kw: SimpleNamespace(
        image=still, coverage=cov, stats={"time_s": {"shading": 0.01, "gbuffer": 0.001}}))
    monkeypatch.setattr(pipeline, "render_adaptive", lambda prep, budget, seed=0, mis=False, **kw:
                        _fake_adaptive_result(still, cov, 0.01, budget))
    with pytest.raises(WarpbwError, match="s.toml: the 4-spp reference equals the ground truth exactly"):
        bench.run_bench(parse_scene(SCENE, tmp_path, "s.toml"), spp_list=(1, 4), budgets=(1,), gt_spp=64, runs=1,
                        cache_dir=tmp_path / "gt", progress=False, log=lambda *a, **kw: None)


# its stand-in frames are random noise at every count, so the reference's MSE need not fall
@pytest.mark.filterwarnings("ignore:.*the reference's MSE rises:RuntimeWarning")
def test_a_ground_truth_chunk_that_cannot_be_cached_is_used_and_said(tmp_path, monkeypatch):
    """A chunk's cache name taken by a folder (or a full disk) stopped the bench with "cannot write" after the chunk
    was rendered, and minutes of rendering were lost.  Now it warns, naming the file, and the bench goes on with the
    chunk it holds; the other chunk is cached."""
    from warpbw import pipeline
    from warpbw.scene import parse_scene

    cov = np.zeros((24, 24), bool)
    cov[8:16, 8:16] = True
    rng = np.random.default_rng(0)

    def noisy(*a, **kw):
        return rng.random((24, 24, 3)).astype(np.float32) * cov[..., None]

    monkeypatch.setattr(pipeline, "render_reference", lambda prep, spp, seed=0, mis=False, **kw: SimpleNamespace(
        image=noisy(), coverage=cov, stats={"time_s": {"shading": 0.01, "gbuffer": 0.001}}))
    monkeypatch.setattr(pipeline, "render_adaptive", lambda prep, budget, seed=0, mis=False, **kw:
                        _fake_adaptive_result(noisy(), cov, 0.01, budget))
    scene = parse_scene(SCENE, tmp_path, "s.toml")
    chunk, n = bench.ground_truth_chunks(128)
    taken = tmp_path / "gt" / f"ground_truth-{bench.gt_key(scene, bench.GT_SEED)}-chunk1-{chunk}spp.exr"
    taken.mkdir(parents=True)
    with pytest.warns(UserWarning, match=f"ground truth not cached \\({taken}: cannot write"):
        rec = bench.run_bench(scene, spp_list=(1, 4), budgets=(1,), gt_spp=128, runs=1, cache_dir=tmp_path / "gt",
                              progress=False, log=lambda *a, **kw: None)
    assert n == 2 and rec["ground_truth_spp"] == 128 and taken.is_dir()
    assert (taken.parent / taken.name.replace("chunk1", "chunk0")).is_file()


@pytest.mark.parametrize("cache", ["afile", "afile/sub"])
def test_a_ground_truth_cache_folder_that_is_a_file_is_said_and_the_bench_goes_on(tmp_path, monkeypatch, cache):
    """From Python, ``ground_truth(prep, gt_spp, cache_dir)`` with a cache folder that is a file, or lies under one,
    raised a bare FileExistsError / NotADirectoryError ("[Errno 17] File exists") naming no parameter, before any
    chunk was rendered; a chunk that cannot be cached for another reason (a full disk, its name taken) is said and
    the bench goes on with it.  Now the same holds here, naming the file in the way.  Truth: the stand-in chunk of
    N spp is N everywhere."""
    rendered = _gt_stand_in(monkeypatch)
    (tmp_path / "afile").write_text("mine")
    with pytest.warns(UserWarning, match=f"ground truth not cached .*: cannot write \\({tmp_path / 'afile'} is not "
                                         "a directory\\)"):
        gt = bench.ground_truth(_prep(tmp_path), 8, tmp_path / cache, progress=False)
    assert rendered == [4, 4] and np.all(gt.image == 4.0) and gt.spp == 8
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"] and (tmp_path / "afile").read_text() == "mine"


def test_ground_truth_chunks_of_another_seed_or_version_are_never_read(tmp_path, monkeypatch):
    """Chunks were cached under the scene's hash alone: another seed's chunks, an older estimator's (a chunk under
    the old name, here a plain 1e3 image) and the current ones were all read as this ground truth, silently.  Now
    the name holds the seed and GT_VERSION: each of those renders anew, and only the same seed and version hit."""
    from warpbw.io.exr import write_exr
    from warpbw.pipeline import prepare_scene
    from warpbw.scene import parse_scene

    scene = parse_scene(SCENE, tmp_path, "s.toml")
    prep = prepare_scene(scene)
    cache = tmp_path / "gt"
    cache.mkdir()
    for k in range(2):   # what the old naming (scene hash, chunk, spp) would have read
        write_exr(cache / f"ground_truth-{scene.content_hash()[:16]}-chunk{k}-2spp.exr",
                  np.full((24, 24, 3), 1e3, np.float32))
    first = bench.ground_truth(prep, 4, cache, progress=False)
    assert first.render_time_s > 0 and first.image.max() < 1e2
    other_seed = bench.ground_truth(prep, 4, cache, seed=bench.GT_SEED + 1, progress=False)
    assert other_seed.render_time_s > 0 and not np.array_equal(other_seed.image, first.image)
    assert bench.ground_truth(prep, 4, cache, progress=False).render_time_s == 0   # the same seed and version hit
    monkeypatch.setattr(bench, "GT_VERSION", bench.GT_VERSION + 1)                 # the estimator changed
    newer = bench.ground_truth(prep, 4, cache, progress=False)
    assert newer.render_time_s > 0 and newer.key != first.key
    assert len(list(cache.glob("ground_truth-*.exr"))) == 2 + 3 * 2 and not list(cache.glob(".*"))


def test_a_ground_truth_of_a_prepared_scene_moved_since_is_not_the_scenes(tmp_path):
    """A loop over an animation's frames on one prepared scene (a camera set on it, as examples/dynamic_geometry.py
    sets its own; a mesh deformed by update_mesh) asked ground_truth for each frame's truth: every chunk was cached,
    and read back, under the scene's hash, so each frame after the first was measured against the first frame's
    truth.  Truth: the same frame's ground truth rendered into an empty cache.  Back in the scene's own camera, the
    scene's chunks are read again."""
    import trimesh

    from warpbw.gbuffer import make_camera, scene_camera, update_mesh
    from warpbw.pipeline import prepare_scene
    from warpbw.scene import parse_scene

    trimesh.creation.icosphere(subdivisions=1).export(tmp_path / "ico.obj")
    text = SCENE.replace('shape = "sphere"\ncenter = [0.0, 0.0, 0.0]\nradius = 1.0', 'mesh = "ico.obj"')
    prep = prepare_scene(parse_scene(text, tmp_path, "s.toml"))
    cache = tmp_path / "gt"
    first = bench.ground_truth(prep, 4, cache, progress=False)
    rest = prep.geometry.mesh.points.numpy().copy()
    for move in ("camera", "mesh"):
        if move == "camera":
            prep.camera = make_camera((1.5, 0.5, 3.5), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 30.0, 24, 24)
        else:
            update_mesh(prep.geometry, 0, rest * 0.8)
        moved = bench.ground_truth(prep, 4, cache, progress=False)
        fresh = bench.ground_truth(prep, 4, tmp_path / f"cold-{move}", progress=False)
        assert fresh.render_time_s > 0 and moved.key == fresh.key != first.key, move
        assert np.array_equal(moved.image, fresh.image) and not np.array_equal(moved.image, first.image), move
        if move == "camera":   # (update_mesh back to the rest pose derives its normals on the device: not the bits
            prep.camera = scene_camera(prep.scene.camera)   # the file's load gave, so not the scene's frame)
            back = bench.ground_truth(prep, 4, cache, progress=False)
            assert back.key == first.key and back.render_time_s == 0 and np.array_equal(back.image, first.image)


@pytest.mark.parametrize("damage", ["one channel", "nan", "cut off", "other size", "negated", "zeroed", "doubled",
                                    "no digest"])
def test_damaged_ground_truth_chunk_is_rendered_again(tmp_path, damage):
    """A cached chunk that is unreadable, of other channels or size, or not finite is stale: rendered anew and
    replaced (the first render's chunk comes back bit for bit: same seed), never averaged in or refused.  So is one
    whose pixels are readable but not those its digest note records (negated, zeroed, doubled: each was averaged
    into the truth, file audit, session 63), and one without the note (written before it, or by hand)."""
    from warpbw.io.exr import read_exr, write_exr
    from warpbw.pipeline import prepare_scene
    from warpbw.scene import parse_scene

    prep = prepare_scene(parse_scene(SCENE, tmp_path, "s.toml"))
    cache = tmp_path / "gt"
    first = bench.ground_truth(prep, 4, cache, progress=False)
    chunk = sorted(cache.glob("ground_truth-*-chunk0-*.exr"))
    assert len(chunk) == 1 and first.render_time_s > 0
    chunk = chunk[0]
    good = chunk.read_bytes()
    if damage == "one channel":
        write_exr(chunk, np.ones((24, 24), np.float32), channels=["Y"])
    elif damage == "nan":
        write_exr(chunk, np.full((24, 24, 3), np.nan, np.float32))
    elif damage == "other size":
        write_exr(chunk, np.ones((12, 24, 3), np.float32))
    elif damage == "cut off":
        chunk.write_bytes(good[: len(good) // 2])
    else:   # readable pixels under the note the renderer wrote (or none)
        img = read_exr(chunk)
        px = {"negated": -img.pixels, "zeroed": 0.0 * img.pixels, "doubled": 2.0 * img.pixels}.get(damage, img.pixels)
        write_exr(chunk, px, channels=img.channels, notes=None if damage == "no digest" else img.notes)
    again = bench.ground_truth(prep, 4, cache, progress=False)
    assert again.render_time_s > 0 and np.array_equal(again.image, first.image)
    assert read_exr(chunk).pixels.shape == (24, 24, 3) and len(list(cache.iterdir())) == 2   # no .part file left
    cached = bench.ground_truth(prep, 4, cache, progress=False)       # and now it is read, not rendered
    assert cached.render_time_s == 0 and np.array_equal(cached.image, first.image)


# --- fake renderers whose every frame is the truth plus a known, signed error -------------------------------------

_YY, _XX = np.mgrid[0:24, 0:24]
_COV = (_YY - 11.5) ** 2 + (_XX - 11.5) ** 2 < 10 ** 2                    # SCENE's 24x24, a covered disc
_TRUTH = ((0.2 + 0.6 * np.stack([_XX / 24, _YY / 24, np.full((24, 24), 0.5)], -1)) * _COV[..., None]).astype(np.float32)
_SIGN = np.where((_YY + _XX) % 2 == 0, 1.0, -1.0)[..., None] * _COV[..., None]   # +/-1 on covered pixels


def _frame(amplitude):
    """The truth plus ``amplitude`` times a +/-1 checkerboard on the covered pixels, and a huge uncovered pixel:
    two such frames of amplitudes a and g differ by an MSE of exactly (a - g)^2 over the coverage."""
    out = _TRUTH + amplitude * _SIGN
    out[0, 0] = 1e3
    return out.astype(np.float32)


def _fake_renderers(monkeypatch, ref_amp, ada, chunk_amp=lambda k: 0.0, run_time=(1.0,), ada_host_time=0.0):
    """Install fake ``render_reference`` / ``render_adaptive`` and a fake clock in bench.  The reference's run r at
    ``spp`` (seeded seed + 101 spp + r, as run_bench does) has amplitude ``ref_amp(spp)`` and takes
    0.01 spp run_time[r] s; budget b's run r (seeded 7 r) has amplitude ``ada[b][0]`` and takes ada[b][1] run_time[r]
    s (over budget where ``ada[b]`` has a third item, True); the ground truth's k-th chunk rendered (seed >= 1e6)
    has amplitude ``chunk_amp(k)``.  Returns the list of the chunks' seeds, in the order rendered.  Each adaptive
    frame also spends ``ada_host_time`` s of wall time outside its stages (its stats' time_s still sum to the
    frame's t)."""

    from warpbw import pipeline

    clock = StandInClock()
    monkeypatch.setattr(bench, "time", clock)
    chunk_seeds = []

    def fake_reference(prep, spp, seed=0, mis=False, **kw):
        if seed >= 1_000_000:
            chunk_seeds.append(seed)
            return SimpleNamespace(image=_frame(chunk_amp(len(chunk_seeds) - 1)), coverage=_COV, stats={})
        r = seed - 101 * spp                                             # negative for the warm-up frame
        t = 0.01 * spp * (run_time[r % len(run_time)] if r >= 0 else 1.0)
        clock.now += t
        return SimpleNamespace(image=_frame(ref_amp(spp)), coverage=_COV,
                               stats={"time_s": {"shading": 0.9 * t, "gbuffer": 0.1 * t}})

    def fake_adaptive(prep, budget, seed=0, mis=False, **kw):
        amp, t, *over = ada.get(float(budget), (0.1, 0.01))               # the warm-up frame is budget 1
        t *= run_time[(seed // 7) % len(run_time)]
        clock.now += t + ada_host_time
        return _fake_adaptive_result(_frame(amp), _COV, t, budget, over_budget=bool(over and over[0]))

    monkeypatch.setattr(pipeline, "render_reference", fake_reference)
    monkeypatch.setattr(pipeline, "render_adaptive", fake_adaptive)
    return chunk_seeds


def _power_law_amp(spp):
    """Amplitude of a frame whose MSE against an exact ground truth is 8 / spp^0.7."""
    return math.sqrt(8.0 / spp ** 0.7)


def test_doubling_check_compares_the_first_half_of_the_chunks_with_all_of_them(tmp_path, monkeypatch):
    """Closed form (fake renderers, ../shared/DESIGN.md's doubling check): four ground-truth chunks of amplitudes
    0, 0.02, 0.07, 0.03 (each independently seeded) make a ground truth of amplitude 0.03 and a half (the first
    two chunks) of 0.01; the largest reference frame, of amplitude 0.1, then has an MSE of (0.1 - 0.03)^2 and a
    doubling delta of 20 log10(0.09 / 0.07) = 2.18 dB: not converged."""
    from warpbw.scene import parse_scene

    amps = (0.0, 0.02, 0.07, 0.03)
    seeds = _fake_renderers(monkeypatch, ref_amp=lambda spp: 0.1, ada={}, chunk_amp=lambda k: amps[k])
    scene = parse_scene(SCENE, tmp_path, "s.toml")
    rec = bench.run_bench(scene, spp_list=(4,), budgets=(), gt_spp=4 * bench.GT_CHUNK_SPP, runs=1,
                          cache_dir=tmp_path / "gt", progress=False, log=lambda *a, **kw: None)
    assert len(seeds) == 4 and len(set(seeds)) == 4                       # independently seeded chunks
    assert rec["ground_truth_spp"] == 4 * bench.GT_CHUNK_SPP
    assert math.isclose(rec["methods"]["reference"][0]["mse"], 0.07 ** 2, rel_tol=1e-4)
    assert math.isclose(rec["ground_truth_doubling_delta_db"], 20.0 * math.log10(0.09 / 0.07), rel_tol=1e-4)
    assert rec["ground_truth_converged"] is False


def test_a_ground_truth_count_that_does_not_split_into_equal_chunks_is_refused(tmp_path, monkeypatch, capsys):
    """The ground truth is the mean of two or more equal chunks of at most 4096 spp.  --gt-spp 12000 was rendered
    as 8192 (two chunks of 4096) without a word; such a count is now refused, naming the nearest counts that split
    (worked by hand), before anything is prepared or rendered: by the command's parser, by the scripts' option
    check, and by run_bench and ground_truth from Python."""
    from warpbw import pipeline
    from warpbw.cli import check_command_options
    from warpbw.errors import WarpbwError
    from warpbw.scene import parse_scene

    assert bench.GT_CHUNK_SPP == 4096
    assert [bench.ground_truth_chunks(s) for s in (2, 4, 64, 8192, 12288, 16384)] == \
        [(1, 2), (2, 2), (32, 2), (4096, 2), (2048, 6), (4096, 4)]
    for s, near in [(12000, "8192 or 12288"), (8193, "8192 or 12288"), (16383, "12288 or 16384"), (7, "6 or 8"),
                    (1, "2"), (3, "2 or 4")]:   # 3 was three chunks of 1 spp, an odd count the help refuses
        assert outcome(bench.ground_truth_chunks, s).endswith(f"chunks of at most 4096 spp; expected {near}"), s
        with pytest.raises(WarpbwError, match=f"^--gt-spp {s}: .*expected {near}, got {s}$"):
            check_command_options("bench", {"--gt-spp": str(s)})
    scene_path = tmp_path / "s.toml"
    scene_path.write_text(SCENE)
    handed = capture_call(monkeypatch, bench, "run_bench")
    assert outcome(cli_main, ["bench", str(scene_path), "--json", str(tmp_path / "b.json"), "--gt-spp", "12000"]) \
        == "exit 2" and handed == {}
    assert "argument --gt-spp: the ground truth is the mean of two or more equal chunks" in capsys.readouterr().err
    monkeypatch.undo()
    prepared = capture_call(monkeypatch, pipeline, "prepare_scene")
    got = outcome(bench.run_bench, parse_scene(SCENE, tmp_path, "s.toml"), gt_spp=12000, cache_dir=tmp_path / "gt")
    assert got.startswith("WarpbwError: --gt-spp 12000: ") and prepared == {}, got
    assert outcome(bench.ground_truth, None, 12000, tmp_path / "gt").startswith("WarpbwError: --gt-spp 12000: ")


def test_half_of_the_ground_truths_chunks_hold_half_its_samples(tmp_path, monkeypatch):
    """The doubling check (../shared/DESIGN.md: doubling the ground truth's samples moves PSNR < 0.5 dB) averages
    the first half of the chunks: for every count accepted, those hold half the samples.  --gt-spp 12288 was three
    chunks of 4096 and its "half" the first one, 4096 spp against 12288 (a tripling check; 20480: 8192 against
    20480).  Closed form (fake renderers) at 12288: six chunks of amplitudes 0, 0, 0, 0.06, 0.06, 0.06 make a truth
    of 0.03 and a half of 0; a 16-spp frame of amplitude 0.1 reads 20 log10(0.1 / 0.07) = 3.10 dB."""
    from warpbw.scene import parse_scene

    accepted = [*range(2, 8193, 2), *range(3 * 4096, 40 * 4096 + 1, 4096)]   # the help's: even to 8192, then 4096 k
    for s in accepted:
        assert bench.gt_spp_refusal(s) is None, s
        chunk, n = bench.ground_truth_chunks(s)
        assert chunk * n == s and n % 2 == 0 and chunk * (n // 2) * 2 == s and chunk <= bench.GT_CHUNK_SPP, s
    seeds = _fake_renderers(monkeypatch, ref_amp=lambda spp: 0.1, ada={}, chunk_amp=lambda k: 0.06 * (k >= 3))
    rec = bench.run_bench(parse_scene(SCENE, tmp_path, "s.toml"), spp_list=(16,), budgets=(), gt_spp=12288, runs=1,
                          cache_dir=tmp_path / "gt", progress=False, log=lambda *a, **kw: None)
    assert len(seeds) == 6 and rec["ground_truth_spp"] == 12288
    assert rec["ground_truth_doubling_delta_db"] == pytest.approx(20.0 * math.log10(0.1 / 0.07), rel=1e-4)


def test_ground_truth_chunks_of_a_real_render_differ(tmp_path, monkeypatch):
    """Independent truth: a Monte Carlo frame's noise follows its seed, so the two 4-spp chunks of a tiny scene's
    ground truth (real renderer) differ, and the bench's doubling delta is > 0 and equals the one computed here
    from the cached chunks (half: chunk 0; whole: their mean) and the bench's last reference frame (spied on)."""
    from warpbw import pipeline
    from warpbw.io.exr import read_exr
    from warpbw.metrics import mse
    from warpbw.scene import parse_scene

    real, frames = pipeline.render_reference, []

    def spy(*a, **kw):
        res = real(*a, **kw)
        frames.append((kw.get("spp"), res))
        return res

    monkeypatch.setattr(pipeline, "render_reference", spy)
    scene = parse_scene(SCENE, tmp_path, "s.toml")
    rec = bench.run_bench(scene, spp_list=(1,), budgets=(), gt_spp=8, runs=1, cache_dir=tmp_path / "gt",
                          progress=False, log=lambda *a, **kw: None)
    c0, c1 = (read_exr(p).pixels[..., :3] for p in sorted((tmp_path / "gt").glob("ground_truth-*-chunk*.exr")))
    cov = frames[-1][1].coverage
    assert frames[-1][0] == 1 and cov.sum() > 50
    assert mse(c0, c1, cov) > 0                                           # the chunks differ
    last = frames[-1][1].image
    want = abs(10.0 * math.log10(mse(last, c0, cov) / mse(last, (c0 + c1) / 2, cov)))
    assert rec["ground_truth_doubling_delta_db"] > 0
    assert math.isclose(rec["ground_truth_doubling_delta_db"], want, rel_tol=1e-5)


def _power_law_bench(tmp_path, monkeypatch, ada):
    """``run(budgets) -> record``: run_bench on ``_fake_renderers`` with the reference of MSE 8 / spp^0.7 at 0.01 s
    per spp, measured from 1 to 256 spp, and the adaptive points ``ada`` (2 runs, a 64-spp ground truth)."""
    from warpbw.scene import parse_scene

    _fake_renderers(monkeypatch, ref_amp=_power_law_amp, ada=ada)
    scene = parse_scene(SCENE, tmp_path, "s.toml")
    return lambda budgets: bench.run_bench(scene, budgets=budgets, spp_list=(1, 4, 16, 64, 256), gt_spp=64, runs=2,
                                           cache_dir=tmp_path / "gt", progress=False, log=lambda *a, **k: None)


def test_headline_speedup_is_never_an_extrapolated_point(tmp_path, monkeypatch):
    """Closed form (fake renderers, reference MSE 8 / spp^0.7 at 0.01 s per spp up to 256 spp): budget 1 matches
    11 spp in 0.02 s (5.5x); budget 2 matches 1000 spp, beyond the measured counts, in 0.05 s: 200x, but
    extrapolated, so the headline is budget 1's 5.5x; with budget 2 alone there is no headline."""
    run = _power_law_bench(tmp_path, monkeypatch,
                           {1.0: (_power_law_amp(11.0), 0.02), 2.0: (_power_law_amp(1000.0), 0.05)})
    rec = run((1, 2))
    one, two = rec["methods"]["adaptive"]
    assert not one["extrapolated"] and math.isclose(one["equal_quality_speedup"], 5.5, rel_tol=1e-4)
    assert two["extrapolated"] and math.isclose(two["equal_quality_speedup"], 200.0, rel_tol=1e-3)
    assert rec["equal_quality_budget"] == 1.0 and math.isclose(rec["equal_quality_speedup"], 5.5, rel_tol=1e-4)
    assert rec["equal_quality_speedup_se"] == one["equal_quality_speedup_se"]
    alone = run((2,))
    assert alone["methods"]["adaptive"][0]["extrapolated"]
    assert alone["equal_quality_speedup"] is None and alone["equal_quality_budget"] is None


def test_headline_speedup_skips_an_over_budget_point_where_a_budget_was_kept(tmp_path, monkeypatch):
    """Closed form as above: budget 0.5 is over budget (every shaded pixel's n_min took more: the frame of a larger
    budget) and matches 11 spp in 0.01 s (11x); budget 1 matches 11 spp in 0.02 s (5.5x).  The headline is budget
    1's; the table marks budget 0.5.  With budget 0.5 alone it is the headline, said to be over budget."""
    run = _power_law_bench(tmp_path, monkeypatch,
                           {0.5: (_power_law_amp(11.0), 0.01, True), 1.0: (_power_law_amp(11.0), 0.02)})
    rec = run((0.5, 1))
    half, one = rec["methods"]["adaptive"]
    assert half["over_budget"] and not one["over_budget"]
    assert math.isclose(half["equal_quality_speedup"], 11.0, rel_tol=1e-4)
    assert rec["equal_quality_budget"] == 1.0 and math.isclose(rec["equal_quality_speedup"], 5.5, rel_tol=1e-4)
    table = bench.format_table(rec).splitlines()
    assert [ln.split()[1] for ln in table if ln.startswith("adaptive")] == ["0.5!", "1"]
    assert "! over budget" in table[-1] and "over budget:" not in "\n".join(table[:-1])
    alone = run((0.5,))
    assert alone["equal_quality_budget"] == 0.5 and math.isclose(alone["equal_quality_speedup"], 11.0, rel_tol=1e-4)
    assert "at budget 0.5 (over budget: 1.00 samples per covered pixel)" in bench.format_table(alone)


def test_the_largest_seed_runs_its_derived_seeds_wrapped_into_the_renderers_range(tmp_path, monkeypatch):
    """bench derives each run's seed from --seed (seed + 101 spp + r, seed + 7 r).  At --seed 4294967295 those
    passed 2^32 - 1 and the renderers refused them after the ground truth was rendered.  They now wrap modulo 2^32:
    the renderers' own seed check (``check_seed``) passes on every frame."""
    from warpbw import pipeline
    from warpbw.errors import SEED_MAX, check_seed, offset_seed
    from warpbw.scene import parse_scene

    assert offset_seed(SEED_MAX, 1) == 0 and offset_seed(SEED_MAX, 101 * 4 + 2) == 101 * 4 + 1
    assert offset_seed(5, 7) == 12
    _fake_renderers(monkeypatch, ref_amp=_power_law_amp, ada={1.0: (_power_law_amp(11.0), 0.02)})
    seeds = []
    for name in ("render_reference", "render_adaptive"):
        fake = getattr(pipeline, name)

        def checked(prep, *a, fake=fake, seed=0, **kw):
            seeds.append(check_seed(seed))
            return fake(prep, *a, seed=seed, **kw)
        monkeypatch.setattr(pipeline, name, checked)
    rec = bench.run_bench(parse_scene(SCENE, tmp_path, "s.toml"), spp_list=(1, 4), budgets=(1,), gt_spp=8, runs=2,
                          seed=SEED_MAX, cache_dir=tmp_path / "gt", progress=False, log=lambda *a, **k: None)
    assert len(rec["methods"]["reference"]) == 2 and max(seeds) == SEED_MAX and 6 in seeds   # SEED_MAX + 7 r, r = 1


def test_equal_quality_below_the_smallest_count_is_extrapolated():
    """Closed form: on MSE = 8 / spp^0.7 at 0.01 s per spp measured from 1 to 32 spp, an MSE above the 1-spp
    reference's (that of 0.5 spp) is reached at 0.5 spp in 0.005 s, extrapolated along the first segment, and
    flagged so; the measured ends themselves are not."""
    ref = [{"spp": s, "mse": 8.0 / s ** 0.7, "time_s": 0.01 * s} for s in (1, 2, 4, 8, 16, 32)]
    spp, t, ext = bench.equal_quality_time(ref, 8.0 / 0.5 ** 0.7)
    assert ext and math.isclose(spp, 0.5, rel_tol=1e-9) and math.isclose(t, 0.005, rel_tol=1e-9)
    for s in (1, 32):
        spp, t, ext = bench.equal_quality_time(ref, 8.0 / s ** 0.7)
        assert not ext and math.isclose(spp, s, rel_tol=1e-9)


def test_speedup_standard_error_reads_the_reference_se_at_the_equal_quality_count():
    """Closed form: reference MSE = 8 / spp at 0.01 s per spp (slope -1), its PSNR's standard error growing as
    0.1 + 0.05 log2(spp) dB (linear in log spp, so interpolation is exact): at the MSE of 11 spp the reference's
    standard error is 0.1 + 0.05 log2(11) = 0.273 dB, and the relative standard error of the speed-up is
    hypot(0.3, 0.273) / (10 / ln 10); beyond the counts, at 64 spp, the line extends to 0.4 dB."""
    ref = [{"spp": s, "mse": 8.0 / s, "time_s": 0.01 * s, "psnr_se_db": 0.1 + 0.05 * math.log2(s)}
           for s in (32, 1, 8, 2, 16, 4)]                                 # in no order
    for spp in (11.0, 3.0, 64.0):
        se_r = 0.1 + 0.05 * math.log2(spp)
        rel = bench.speedup_relative_se(ref, 8.0 / spp, 0.3)
        assert math.isclose(rel, math.hypot(0.3, se_r) / bench.DB_PER_LN, rel_tol=1e-6), spp


def test_standard_errors_by_hand():
    """Hand-computed: per-run PSNR differences of 0 and 10 dB have a sample standard deviation (n - 1) of
    sqrt(50) and a standard error of sqrt(50) / sqrt(2) = 5 dB; of 0, 10 and 20 dB, 10 / sqrt(3) dB.  Run MSEs 1 and
    3: mean 2, sample standard deviation sqrt(2), so a PSNR standard error of (10 / ln 10) sqrt(2) / sqrt(2) / 2."""
    assert math.isclose(bench.paired_difference_se([1e-4, 1e-3], [1e-4, 1e-4]), 5.0, rel_tol=1e-12)
    assert math.isclose(bench.paired_difference_se([1e-4, 1e-4], [1e-4, 1e-3]), 5.0, rel_tol=1e-12)
    assert math.isclose(bench.paired_difference_se([1e-4, 1e-3, 1e-2], [1e-4] * 3), 10.0 / math.sqrt(3),
                        rel_tol=1e-12)
    assert math.isclose(bench.psnr_standard_error([1.0, 3.0]), bench.DB_PER_LN / 2.0, rel_tol=1e-12)


def test_bench_times_are_the_median_of_the_runs(tmp_path, monkeypatch):
    """A fake clock with known times (../shared/DESIGN.md: median of at least 3 runs): runs 0, 1, 2 take 1, 5 and 2
    times a frame's base time, so every point's time is twice its base (median; not the minimum 1, mean 2.67 or
    maximum 5), and the equal-quality speed-up, a ratio of two medians, is the base times' ratio, 5.5x."""
    from warpbw.scene import parse_scene

    _fake_renderers(monkeypatch, ref_amp=_power_law_amp, ada={1.0: (_power_law_amp(11.0), 0.02)},
                    run_time=(1.0, 5.0, 2.0))
    scene = parse_scene(SCENE, tmp_path, "s.toml")
    rec = bench.run_bench(scene, spp_list=(1, 4, 16, 64), budgets=(1,), gt_spp=64, runs=3, cache_dir=tmp_path / "gt",
                          progress=False, log=lambda *a, **kw: None)
    for p in rec["methods"]["reference"]:
        assert math.isclose(p["time_s"], 2 * 0.01 * p["spp"], rel_tol=1e-9), p
    (a,) = rec["methods"]["adaptive"]
    assert math.isclose(a["time_s"], 2 * 0.02, rel_tol=1e-9)
    assert math.isclose(a["equal_quality_reference_time_s"], 2 * 0.11, rel_tol=1e-4)
    assert math.isclose(a["equal_quality_speedup"], 5.5, rel_tol=1e-4)


# ------------------------------------------------------------ examples/bench_scenes.py (mutation audit, session 44)

# README's benchmark table (the figures it reports are for exactly these scenes): object, NPF material, probe, size
README_BENCH_SCENES = {
    "bunny_gold_forest": ("bunny", "gold-metallic-paint", "forest.exr", 512),
    "sphere_chrome_studio": ("sphere", "chrome", "studio.exr", 256),
    "sphere_ccp3_forest": ("sphere", "color-changing-paint3", "forest.exr", 256),
    "bunny_acrylic_studio": ("bunny", "blue-acrylic", "studio.exr", 256),
}


def _bench_scenes():
    return load_example("bench_scenes")


def _after(cmd, flag):
    """The value that follows ``flag`` in ``cmd``, or None where ``flag`` is absent."""
    return cmd[cmd.index(flag) + 1] if flag in cmd else None


def _bench_scenes_with_fake_run(monkeypatch, status=0):
    """bench_scenes with subprocess.run recorded: npf-to-merl writes an empty MERL file, warpbw bench returns
    ``status``."""
    import subprocess

    bs = _bench_scenes()
    calls = []

    def fake_run(cmd, check=False, **kw):
        cmd = [str(c) for c in cmd]
        calls.append(cmd)
        if "npf-to-merl" in cmd:
            Path(cmd[cmd.index("-o") + 1]).write_bytes(b"")
            return SimpleNamespace(returncode=0)
        return SimpleNamespace(returncode=status)

    monkeypatch.setattr(subprocess, "run", fake_run)
    return bs, calls


def _benches(calls):
    """The ``warpbw bench`` commands among ``calls``, each as ``["warpbw", "bench", ...]``: bench_scenes runs them as
    ``python -m warpbw.cli bench ...`` with its own interpreter."""
    prefix = [sys.executable, "-m", "warpbw.cli"]
    return [["warpbw", *c[len(prefix):]] for c in calls if c[:len(prefix) + 1] == [*prefix, "bench"]]


def test_bench_scenes_runs_the_bench_of_its_own_interpreter(tmp_path, monkeypatch, shared):
    """--run ran ``warpbw`` from $PATH: with the interpreter of a virtual environment not activated it stopped on
    "[Errno 2] No such file or directory: 'warpbw'", and with another install's ``warpbw`` first on $PATH it benched
    that install's code.  Each bench is ``sys.executable -m warpbw.cli bench``, as npf-to-merl's conversion here and
    filtering_scenes.py's --run are."""
    shared("brdf/npf.bin")
    bs, calls = _bench_scenes_with_fake_run(monkeypatch)
    assert bs.main(["--out", str(tmp_path / "s"), "--run", "--only", "sphere_chrome_studio"]) == 0
    runs = [c for c in calls if "npf-to-merl" not in c]
    assert len(runs) == 1 and runs[0][:4] == [sys.executable, "-m", "warpbw.cli", "bench"], runs


def test_bench_scenes_are_the_readme_table(tmp_path):
    """Each scene file parses to README's row: its object (the bunny mesh or a sphere), the MERL file made from its
    NPF material, its probe and its size; the fifth, not run by default, is the ccp3 scene with a sun added."""

    bs = _bench_scenes()
    texts = bs.scene_texts(tmp_path)
    assert sorted(p.stem for p in texts) == sorted([*README_BENCH_SCENES, "sphere_ccp3_forest_sun"])
    sun = tomllib.loads(texts.pop(tmp_path / "sphere_ccp3_forest_sun.toml"))
    assert sun.pop("light") == [{"type": "directional", "direction": [0.4, 0.7, 0.6], "radiance": [5.0, 4.8, 4.4]}]
    assert sun == tomllib.loads(texts[tmp_path / "sphere_ccp3_forest.toml"])   # the ccp3 scene plus the sun
    for p, text in texts.items():
        obj, material, probe, size = README_BENCH_SCENES[p.stem]
        t = tomllib.loads(text)
        assert "light" not in t, p.stem
        assert t["camera"]["resolution"] == [size, size], p.stem
        assert Path(t["environment"]["file"]).name == probe, p.stem
        (o,) = t["object"]
        assert (Path(o["mesh"]).name == "bunny.obj") if obj == "bunny" else (o.get("shape") == "sphere"), p.stem
        assert t["material"]["m"] == {"type": "merl", "file": f"{material}.binary"}, p.stem


def test_bench_scenes_run_passes_its_options_to_every_bench_and_the_sweep_to_the_first(tmp_path, monkeypatch, shared):
    """--run: one `warpbw bench` per scene (those of --only), each with --no-mis, --runs, --gt-spp and the records
    in --results; the n_b sweep (--nb) on the first scene only (module docstring).  No bench is run: the commands
    are recorded."""
    shared("brdf/npf.bin")
    bs, calls = _bench_scenes_with_fake_run(monkeypatch)
    out, res = tmp_path / "s", tmp_path / "r"
    assert bs.main(["--out", str(out), "--run", "--no-mis", "--runs", "8", "--gt-spp", "16384", "--nb", "16,64",
                    "--results", str(res)]) == 0
    benches = _benches(calls)
    assert [Path(c[2]).stem for c in benches] == list(bs.SCENES)
    for i, c in enumerate(benches):
        stem = Path(c[2]).stem
        assert "--no-mis" in c and c[c.index("--runs") + 1] == "8" and c[c.index("--gt-spp") + 1] == "16384"
        assert c[c.index("--json") + 1] == str(res / f"{stem}.json")
        assert (c[c.index("--nb") + 1] == "16,64") if i == 0 else ("--nb" not in c), stem
    # every command is one `warpbw bench` accepts (filtering_scenes.py's --run once passed an option its command
    # refused on its own scenes, and nothing ran its command lines)
    from warpbw.cli import build_parser

    for c in benches:
        build_parser().parse_args(c[1:])
    calls.clear()
    assert bs.main(["--out", str(out), "--run", "--only", "sphere_chrome_studio"]) == 0
    benches = _benches(calls)
    assert [Path(c[2]).stem for c in benches] == ["sphere_chrome_studio"]
    assert "--no-mis" not in benches[0] and "--runs" not in benches[0] and "--nb" not in benches[0]
    calls.clear()   # the sun scene is written with the others, and run only when named
    assert bs.main(["--out", str(out), "--run", "--only", "sphere_ccp3_forest_sun,sphere_ccp3_forest"]) == 0
    benches = _benches(calls)
    assert [Path(c[2]).stem for c in benches] == ["sphere_ccp3_forest", "sphere_ccp3_forest_sun"]


def test_bench_scenes_passes_cache_env_signal_force_and_the_documented_defaults(tmp_path, monkeypatch, shared):
    """--cache, --env-signal and --force are "passed on to warpbw bench" (--help) for every scene; without
    options, --gt-spp 8192 (--help) and the n_b sweep 16,64,256,1024 on the gold bunny (module docstring)."""
    from warpbw.cli import build_parser

    shared("brdf/npf.bin")
    bs, calls = _bench_scenes_with_fake_run(monkeypatch)
    out = tmp_path / "s"
    assert bs.main(["--out", str(out), "--run", "--cache", str(tmp_path / "gt"), "--env-signal", "log",
                    "--force", "--only", "sphere_chrome_studio,bunny_acrylic_studio"]) == 0
    benches = _benches(calls)
    assert len(benches) == 2
    for c in benches:
        assert _after(c, "--cache") == str(tmp_path / "gt"), c
        assert _after(c, "--env-signal") == "log" and "--force" in c, c
        build_parser().parse_args(c[1:])
    calls.clear()
    assert bs.main(["--out", str(out), "--run"]) == 0
    benches = _benches(calls)
    assert [Path(c[2]).stem for c in benches] == list(bs.SCENES)
    for i, c in enumerate(benches):
        assert _after(c, "--gt-spp") == "8192", c
        assert _after(c, "--nb") == ("16,64,256,1024" if i == 0 else None), c
        assert not {"--cache", "--env-signal", "--force", "--runs", "--no-mis"} & set(c), c


def test_bench_scenes_reuses_its_merl_files_and_force_rewrites_an_edited_scene(tmp_path, monkeypatch, shared):
    """--help: an OUT/MATERIAL.binary already there is used as it is (no second conversion); --force rewrites a
    scene file edited by hand, as the script writes it."""
    shared("brdf/npf.bin")
    bs, calls = _bench_scenes_with_fake_run(monkeypatch)
    out = tmp_path / "s"
    assert bs.main(["--out", str(out)]) == 0
    assert sorted(_after(c, "--material") for c in calls) == ["blue-acrylic", "chrome", "color-changing-paint3",
                                                                     "gold-metallic-paint"]
    calls.clear()
    edited = out / "sphere_chrome_studio.toml"
    text = edited.read_text()
    edited.write_text(text + "# mine\n")
    assert outcome(bs.main, ["--out", str(out), "--force"]) == "returned 0"
    assert calls == [] and edited.read_text() == text


def test_bench_scenes_converts_again_a_merl_file_an_earlier_tabulation_wrote(tmp_path, monkeypatch, shared):
    """The MERL files are a cache of npf-to-merl's tabulation (warpbw.io.merl.TABULATION_VERSION), which session 69
    changed (the bins the horizon cuts), and a MERL file cannot say which one wrote it: a file of the earlier one was
    used as it was.  A file whose stamp (OUT/MATERIAL.binary.tabulation) is missing or names another version is
    converted again; a current one is not."""
    shared("brdf/npf.bin")
    bs, calls = _bench_scenes_with_fake_run(monkeypatch)
    out = tmp_path / "s"
    assert bs.main(["--out", str(out)]) == 0
    calls.clear()
    (out / "chrome.binary.tabulation").unlink()                    # a folder of an earlier warpbw: no stamp
    (out / "blue-acrylic.binary.tabulation").write_text("1\n")     # the earlier tabulation's
    assert bs.main(["--out", str(out)]) == 0
    assert sorted(_after(c, "--material") for c in calls) == ["blue-acrylic", "chrome"]
    calls.clear()
    assert bs.main(["--out", str(out)]) == 0 and calls == []


def test_bench_scenes_converts_again_a_merl_file_of_another_npf_table(tmp_path, monkeypatch, shared):
    """The tabulation depends on the NPF table's bytes as much as on TABULATION_VERSION, and a stamp of the version
    alone kept a file converted from another npf.bin (cache-key audit, session 70).  The stamp now holds the
    table's digest (precompute.npf_to_merl.tabulation_stamp): the table changed, every material is converted again,
    and a stamp of the version alone (session 69's) counts as stale."""
    table = tmp_path / "npf.bin"
    table.write_bytes(shared("brdf/npf.bin").read_bytes())
    bs, calls = _bench_scenes_with_fake_run(monkeypatch)
    monkeypatch.setattr(bs, "NPF_TABLE", table)
    out = tmp_path / "s"
    assert bs.main(["--out", str(out)]) == 0 and len(calls) == 4
    calls.clear()
    assert bs.main(["--out", str(out)]) == 0 and calls == []
    table.write_bytes(table.read_bytes()[:-1] + b"\x01")      # another fit, same size
    assert bs.main(["--out", str(out)]) == 0
    assert sorted(_after(c, "--material") for c in calls) == ["blue-acrylic", "chrome", "color-changing-paint3",
                                                                     "gold-metallic-paint"]
    assert all(_after(c, "--table") == str(table) for c in calls)
    calls.clear()
    (out / "chrome.binary.tabulation").write_text("2\n")      # session 69's stamp: the version alone
    assert bs.main(["--out", str(out)]) == 0
    assert [_after(c, "--material") for c in calls] == ["chrome"]


def _bench_reference_until_the_render(monkeypatch, tmp_path, shared, argv):
    """examples/bench_reference.py with ``argv``, its shared data in ``tmp_path/data`` (a copy of npf.bin, the
    probes linked), npf_to_merl recorded (it writes a stand-in file) and parse_scene stopping the run: returns the
    run, the materials converted and the table."""
    import precompute.npf_to_merl
    import warpbw.scene

    data = tmp_path / "data"
    (data / "brdf").mkdir(parents=True)
    table = data / "brdf" / "npf.bin"
    table.write_bytes(shared("brdf/npf.bin").read_bytes())
    (data / "envmaps").symlink_to(shared("envmaps/forest.exr").parent)
    br = load_example("bench_reference")
    monkeypatch.setattr(br, "DATA", data)
    converted = []

    def convert(tab, material, out, force=False):
        converted.append(material)
        Path(out).write_bytes(b"stand-in MERL")
        return Path(out)

    class Stop(Exception):
        pass

    def stop(*a, **k):
        raise Stop

    monkeypatch.setattr(precompute.npf_to_merl, "npf_to_merl", convert)
    monkeypatch.setattr(warpbw.scene, "parse_scene", stop)

    def run(*extra):
        monkeypatch.setattr(sys, "argv", ["bench_reference.py", *argv, *extra])
        with pytest.raises(Stop):
            br.main()
    return run, converted, table


def test_bench_reference_converts_again_a_stale_merl_file(tmp_path, monkeypatch, shared):
    """OUT/MATERIAL.binary is bench_reference's cache of npf-to-merl's tabulation, and was used whenever it existed:
    a file of session 68's tabulation (before the horizon bins' means, warpbw.io.merl.TABULATION_VERSION 2) or of
    another npf.bin was benchmarked as the current NPF fit (cache-key audit, session 70).  It is now stamped as
    bench_scenes.py stamps its files: a missing or stale stamp converts it again; a current one does not."""
    out = tmp_path / "out"
    run, converted, table = _bench_reference_until_the_render(monkeypatch, tmp_path, shared, ["--out", str(out)])
    run()
    assert converted == ["gold-metallic-paint"]
    run()
    assert converted == ["gold-metallic-paint"]                # current: used as it is
    stamp = out / "gold-metallic-paint.binary.tabulation"
    stamp.unlink()                                             # a folder of an earlier warpbw: no stamp
    run()
    assert converted == ["gold-metallic-paint"] * 2
    table.write_bytes(table.read_bytes()[:-1] + b"\x01")       # another NPF table
    run()
    assert converted == ["gold-metallic-paint"] * 3


def test_bench_reference_check_only_refuses_a_stale_merl_file(tmp_path, monkeypatch, shared):
    """--check-only keeps the sweep an earlier run measured on OUT's MERL file: a stale one (converted again, the
    ground truth would be another material's) is refused, saying to run without --check-only."""
    out = tmp_path / "out"
    run, converted, _ = _bench_reference_until_the_render(monkeypatch, tmp_path, shared,
                                                          ["--out", str(out), "--resolution", "8", "8"])
    out.mkdir()
    (out / "gold-metallic-paint.binary").write_bytes(b"session 68's MERL")
    (out / "bench_reference.json").write_text(json.dumps(
        {"scene": {"material": "gold-metallic-paint", "probe": "forest.exr", "rotation_deg": 0.0,
                   "resolution": [8, 8]}, "methods": {"brdf_is": [{"spp": 4}], "mis": [{"spp": 4}]}}))
    monkeypatch.setattr(sys, "argv", ["bench_reference.py", "--out", str(out), "--resolution", "8", "8",
                                      "--check-only"])
    br = load_example("bench_reference")
    monkeypatch.setattr(br, "DATA", tmp_path / "data")
    with pytest.raises(WarpbwError, match="--check-only: .*gold-metallic-paint.binary is not the current tabulation"):
        br.main()
    assert converted == []


def test_two_bench_scenes_into_one_out_at_once_both_go_on_with_a_whole_merl_file(tmp_path, monkeypatch, shared):
    """Two bench_scenes runs into one --out at once (two --only runs, say) both convert a material that is not there
    yet.  The later one found the other's file when its npf-to-merl started, was refused ("already exists") and
    ended in a CalledProcessError traceback.  OUT holds these files as a cache (--help): the conversion now replaces
    the file whole, and the run goes on.  Truth: the real npf-to-merl command, with the other run's file written
    between this run's look for it and its command; the file ends as the NPF fit's MERL tabulation."""
    import subprocess

    from precompute.__main__ import main as precompute_main
    from warpbw.io.merl import read_merl

    npf = shared("brdf/npf.bin")
    bs = _bench_scenes()
    out = tmp_path / "s"

    def run(cmd, check=False, **kw):
        cmd = [str(c) for c in cmd]
        merl = Path(cmd[cmd.index("-o") + 1])
        if _after(cmd, "--material") != "chrome":
            merl.write_bytes(b"")
            return SimpleNamespace(returncode=0)
        merl.write_bytes(b"the other run's file")   # the other run, here first
        status = precompute_main(cmd[3:])
        if check and status:
            raise subprocess.CalledProcessError(status, cmd)
        return SimpleNamespace(returncode=status)

    monkeypatch.setattr(subprocess, "run", run)
    assert bs.main(["--out", str(out)]) == 0
    theirs = tmp_path / "chrome.binary"
    assert precompute_main(["npf-to-merl", "--table", str(npf), "--material", "chrome", "-o", str(theirs)]) == 0
    assert (out / "chrome.binary").read_bytes() == theirs.read_bytes()
    assert read_merl(out / "chrome.binary").name == "chrome"


def test_bench_scenes_stops_at_the_first_bench_that_fails(tmp_path, monkeypatch, shared):
    """A failing `warpbw bench` (it has said why) ends the run with its status; the other scenes are not run."""
    shared("brdf/npf.bin")
    bs, calls = _bench_scenes_with_fake_run(monkeypatch, status=3)
    assert bs.main(["--out", str(tmp_path / "s"), "--run"]) == 3
    assert len(_benches(calls)) == 1


@pytest.mark.parametrize("spp_list", [(1, 16), (16, 1)])
def test_doubling_check_reads_the_largest_reference_count_in_any_order(tmp_path, monkeypatch, spp_list):
    """The doubling check renders "at the largest reference spp" (module docstring), whatever order --spp gives.
    Closed form (fake renderers): chunks of amplitudes 0 and 0.02 make a ground truth of 0.01 and a half of 0; the
    16-spp frame, of amplitude 0.4 / sqrt(16) = 0.1, has a delta of 20 log10(0.1 / 0.09) = 0.92 dB, not converged.
    With --spp 16,1 the check read the 1-spp frame (amplitude 0.4): 0.22 dB, converged."""
    from warpbw.scene import parse_scene

    _fake_renderers(monkeypatch, ref_amp=lambda spp: 0.4 / math.sqrt(spp), ada={}, chunk_amp=lambda k: (0.0, 0.02)[k])
    rec = bench.run_bench(parse_scene(SCENE, tmp_path, "s.toml"), spp_list=spp_list, budgets=(), gt_spp=64, runs=1,
                          cache_dir=tmp_path / "gt", progress=False, log=lambda *a, **kw: None)
    assert [r["spp"] for r in rec["methods"]["reference"]] == list(spp_list)   # the records keep the order given
    assert rec["ground_truth_doubling_delta_db"] == pytest.approx(20.0 * math.log10(0.1 / 0.09), rel=1e-4)
    assert rec["ground_truth_converged"] is False


@pytest.mark.parametrize("seed, runs, budgets, match", [
    (bench.GT_SEED - 101 * 16, 1, (), "reference's run 0 at 16 spp would be seeded 1000001, the seed of the ground "
                                      "truth's chunk 0"),
    (bench.GT_SEED + bench.GT_SEED_STEP - 101 * 4 - 2, 3, (), "reference's run 2 at 4 spp .* chunk 1"),
    (bench.GT_SEED - 7 * 2, 3, (1,), "adaptive run 2 would shade its level 0 seeded 1000001"),
    (bench.GT_SEED - 7919 * 3, 1, (1,), "adaptive run 0 would shade its level 3 seeded 1000001"),
])
def test_a_seed_whose_runs_would_draw_the_ground_truths_samples_is_refused(tmp_path, monkeypatch, seed, runs,
                                                                          budgets, match):
    """The ground truth's chunks are seeded GT_SEED + k GT_SEED_STEP "whatever --seed says", and the shading seeds
    pixel i with rand_init(seed, i): a run seeded as a chunk draws that chunk's first samples, pixel by pixel, and its
    error against the truth reads low (--seed 998385: the 16-spp reference's MSE 1.04e-3, against 1.7e-3 to 2.1e-3 at
    seeds 0 to 3 on this scene, real renders).  Such a seed is refused before any frame, naming the run; the default
    seed passes (fake renderers), and so do the neighbouring seeds (the check alone: the fakes take them for chunks)."""
    from warpbw.scene import parse_scene

    _fake_renderers(monkeypatch, ref_amp=_power_law_amp, ada={1.0: (_power_law_amp(11.0), 0.02)})
    scene = parse_scene(SCENE, tmp_path, "s.toml")
    kw = dict(spp_list=(4, 16), budgets=budgets, gt_spp=4 * bench.GT_CHUNK_SPP, runs=runs, cache_dir=tmp_path / "gt",
              progress=False, log=lambda *a, **k: None)
    with pytest.raises(WarpbwError, match=f"seed {seed}: the {match}.*expected another seed"):
        bench.run_bench(scene, seed=seed, **kw)
    assert bench.run_bench(scene, seed=0, **kw)["seed"] == 0
    for ok in (seed - 1, seed + 1) if runs == 1 else (seed + 1000,):
        assert bench._seed_refusal(ok, kw["spp_list"], runs, bool(budgets), 5, 4) is None


# What the reference reads of a uv-seamed lat-long sphere (load_mesh's vertices and normals, rounded to 1e-4), per
# GT_VERSION: 3's is the loader's before session 73 (f916b81) gave the seam's copies the surface's normal; 5 (session
# 81) changed other meshes only (MIXED_WINDING_DIGEST).
SEAMED_MESH_DIGEST = {3: "bff296236e97b9e2", 4: "3b277a56f7fdda6b", 5: "3b277a56f7fdda6b"}
# ... and of the same sphere with every third triangle wound the other way: 4's is the loader's before session 81
# turned such triangles to match their neighbours (warpbw.io.mesh.consistent_winding).
MIXED_WINDING_DIGEST = {4: "078a91e358280fd0", 5: "3b277a56f7fdda6b"}   # 5: the consistent sphere's


def test_the_ground_truths_version_follows_what_the_reference_reads_of_a_mesh(tmp_path):
    """A cached ground-truth chunk is keyed by the scene's content, its seed and GT_VERSION only: a change of what the
    reference renders of the same files must raise GT_VERSION, else the old truth is read as the new one's.  Session
    73 changed a uv-seamed mesh's normals (f916b81) under GT_VERSION 3: the same key, v3-28451f995e6d531d, for a
    48x48 GGX (alpha 0.05) uv sphere before and after, whose 256-spp frames at the same seed differed on 448 of 1664
    covered pixels, by up to 0.18 (57%) on the seam's columns.  The loader's output is pinned per version here, so
    that the next such change fails until GT_VERSION is raised with it."""
    import hashlib

    from conftest import latlong_sphere_obj
    from warpbw.io.mesh import load_mesh

    p = tmp_path / "uvsphere.obj"
    p.write_text(latlong_sphere_obj(32, 16, 1.0))
    m = load_mesh(p)
    a = np.round(np.concatenate([np.asarray(m.vertices, np.float64), np.asarray(m.normals, np.float64)]), 4) + 0.0
    assert hashlib.blake2b(a.tobytes(), digest_size=8).hexdigest() == SEAMED_MESH_DIGEST.get(bench.GT_VERSION), \
        f"load_mesh's output changed: raise GT_VERSION (now {bench.GT_VERSION}) and record the new digest"
    lines = p.read_text().splitlines()
    faces = [k for k, ln in enumerate(lines) if ln.startswith("f ")]
    for k in faces[::3]:
        tag, a0, b0, c0 = lines[k].split()
        lines[k] = f"{tag} {a0} {c0} {b0}"
    p.write_text("\n".join(lines) + "\n")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")      # 5: the triangles turned, said
        m = load_mesh(p)
    a = np.round(np.concatenate([np.asarray(m.vertices, np.float64), np.asarray(m.normals, np.float64)]), 4) + 0.0
    assert hashlib.blake2b(a.tobytes(), digest_size=8).hexdigest() == MIXED_WINDING_DIGEST.get(bench.GT_VERSION), \
        f"load_mesh's output changed: raise GT_VERSION (now {bench.GT_VERSION}) and record the new digest"


def test_bandwidth_time_fraction_is_over_the_frames_wall_time(tmp_path, monkeypatch):
    """The record's times are wall times of whole frames (bench docstring) and "bandwidth pass: x% of the frame"
    divides the bandwidth pass by that time: with a frame whose stage sum is half its wall time (host work
    between stages), the fraction is bandwidth / time_s, not bandwidth / the stage sum."""
    from warpbw.scene import parse_scene

    _fake_renderers(monkeypatch, ref_amp=_power_law_amp, ada={1.0: (_power_law_amp(11.0), 0.02)},
                    ada_host_time=0.02)                            # wall time 0.04 s, stages sum to 0.02 s
    rec = bench.run_bench(parse_scene(SCENE, tmp_path, "s.toml"), spp_list=(1, 4, 16), budgets=(1,), gt_spp=64,
                          runs=1, cache_dir=tmp_path / "gt", progress=False, log=lambda *a, **kw: None)
    (p,) = rec["methods"]["adaptive"]
    assert p["time_s"] == pytest.approx(0.04, rel=1e-9)
    assert p["bandwidth_time_fraction"] == pytest.approx(0.002 / 0.04, rel=1e-9)


@pytest.mark.parametrize("module", ["bench", "bench_filtering"])
def test_a_plot_leaves_the_callers_matplotlib_as_it_was(tmp_path, module):
    """bench's and bench-filtering's write_plot draw on a Figure of their own: the caller's backend (a notebook's
    inline one; here svg) is the same after a plot (matplotlib.use("Agg") replaced it for the rest of the session),
    and no figure stays open in pyplot, after a plot saved or one that cannot be (its folder gone, a format matplotlib
    lacks: pyplot kept each, and warns from the 21st open one on).  The PNG is byte for byte pyplot's (checked when
    this changed)."""
    import importlib

    import matplotlib
    import matplotlib.pyplot as plt

    mod = importlib.import_module(f"warpbw.{module}")
    if module == "bench":
        rec = {"scene": "s.toml", "resolution": [8, 8], "ground_truth_spp": 64, "estimator": "MIS",
               "equal_quality_speedup": None,
               "methods": {"reference": [{"spp": 1, "time_s": 0.1, "psnr_db": 20.0}],
                           "adaptive": [{"budget": 1.0, "time_s": 0.05, "psnr_db": 24.0}]}}
    else:
        rec = {"scene": "p.toml", "zooms": [1.0, 2.0], "max_anisotropy": 1, "precompute_time_s": 1.25,
               "methods": {"toksvig": [{"error": 0.1, "flicker": 0.01, "temporal_error": 0.5, "time_s": 0.5}] * 2},
               "ground_truth": [{"noise": 0.01, "flicker_noise": 0.002, "temporal_noise": 0.003}] * 2}
    was = matplotlib.get_backend()
    matplotlib.use("svg")
    try:
        before = plt.get_fignums()
        for path in (tmp_path / "gone" / "p.png", tmp_path / "p.nosuchformat"):
            with pytest.raises((OSError, ValueError)):
                mod.write_plot(rec, path)
            assert plt.get_fignums() == before
        mod.write_plot(rec, tmp_path / "p.png")
        assert plt.get_fignums() == before and (tmp_path / "p.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert matplotlib.get_backend() == "svg"
    finally:
        matplotlib.use(was)


def test_bench_plot_draws_each_method_from_its_own_records(tmp_path, monkeypatch):
    """The bench plot's curves are PSNR against frame time, one per method, each labelled with its method and
    drawn from that method's records (a swap would put the adaptive curve under the reference's label), and the
    title gives the headline speed-up with its standard error."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.axes

    curves, titles = [], []
    real_eb, real_title = matplotlib.axes.Axes.errorbar, matplotlib.axes.Axes.set_title

    def eb(self, x, y, *a, **kw):
        curves.append((kw.get("label"), list(x), list(y)))
        return real_eb(self, x, y, *a, **kw)

    def title(self, t, *a, **kw):
        titles.append(t)
        return real_title(self, t, *a, **kw)

    monkeypatch.setattr(matplotlib.axes.Axes, "errorbar", eb)
    monkeypatch.setattr(matplotlib.axes.Axes, "set_title", title)
    rec = {"scene": "s.toml", "resolution": [8, 8], "ground_truth_spp": 64, "estimator": "MIS",
           "equal_quality_speedup": 3.25, "equal_quality_speedup_se": 0.5,
           "methods": {"reference": [{"spp": 1, "time_s": 0.1, "psnr_db": 20.0}, {"spp": 4, "time_s": 0.4,
                                                                                 "psnr_db": 26.0}],
                       "adaptive": [{"budget": 1.0, "time_s": 0.05, "psnr_db": 24.0}]}}
    bench.write_plot(rec, tmp_path / "p.png")
    assert curves == [("reference (MIS)", [0.1, 0.4], [20.0, 26.0]), ("adaptive (002)", [0.05], [24.0])]
    assert titles[0] == "equal-quality speed-up 3.2x \u00b1 0.5" and (tmp_path / "p.png").stat().st_size > 0
    # --spp, --budgets and --nb in any order: each curve runs along its counts (16, 1, 4 was drawn 16 -> 1 -> 4)
    curves.clear()
    rec["methods"]["reference"] = [{"spp": s, "time_s": 0.1 * s, "psnr_db": 20.0 + s} for s in (16, 1, 4)]
    rec["methods"]["adaptive"] = [{"budget": b, "time_s": 0.05 * b, "psnr_db": 24.0 + b} for b in (2.0, 0.5, 1.0)]
    rec["nb_sweep"] = [{"n_b": n, "budget": 8.0, "time_s": 0.001 * n, "psnr_db": 30.0} for n in (64, 16, 1024)]
    bench.write_plot(rec, tmp_path / "p2.png")
    assert curves == [("reference (MIS)", [0.1, 0.4, 1.6], [21.0, 24.0, 36.0]),
                      ("adaptive (002)", [0.025, 0.05, 0.1], [24.5, 25.0, 26.0]), ("PSNR", [16, 64, 1024], [30.0] * 3)]


# -------------------------------------------------------------------------------- examples/bench_reference.py

RELMSE_EPS_DOC = 1e-2     # relMSE = mean of (a - b)^2 / (b^2 + 1e-2) (README's metrics; compare_mitsuba's label)
AMP = {False: 0.4, True: 0.1}   # stand-in noise amplitude at 1 spp: BRDF sampling, MIS
GT_HALF_OFFSET = 0.03           # the first half of the ground truth's chunks: GT + 0.03 * checker


def _br_images(h, w):
    """(ground truth, checker, coverage): GT 1 or 2 by column parity (peak 2), a +-1 checker, the first column not
    covered."""
    cols = np.arange(w)[None, :, None]
    gt = np.broadcast_to(1.0 + (cols % 2), (h, w, 3)).astype(np.float64)
    c = np.where((np.arange(h)[:, None] + np.arange(w)[None, :]) % 2 == 0, 1.0, -1.0)[..., None] * np.ones(3)
    cov = np.ones((h, w), bool)
    cov[:, 0] = False
    return gt, c, cov


def _run_bench_reference(monkeypatch, tmp_path, argv):
    """bench_reference.main with stand-ins for the MERL conversion, the scene, the renders and the ground truth.
    A render at N spp is GT + AMP[mis] / sqrt(N) * checker (and 100 on the uncovered column); a timed run r of
    run_reference takes (1, 2, 6)[r % 3] ms * N * (2 with MIS) on the stand-in clock, and its stats' shading and
    G-buffer times are (1, 2, 6)[r % 3] x 0.1 s and 0.05 s (its samples per second 2e6 / (1, 2, 6)[r % 3])."""
    import precompute.npf_to_merl
    import warpbw.bench
    import warpbw.gbuffer
    import warpbw.pipeline
    import warpbw.scene

    mod = load_example("bench_reference")
    clock = StandInClock()
    got = {"renders": [], "merl": [], "toml": None, "gt_spp": None, "loglog": []}

    def npf_to_merl(table, material, out, force=False):
        got["merl"].append(material)
        Path(out).write_bytes(b"merl")
        return out

    def parse_scene(text, base_dir=None, source=None):
        got["toml"] = tomllib.loads(text)
        w, h = got["toml"]["camera"]["resolution"]
        return SimpleNamespace(w=w, h=h)

    def prepare_scene(scene, progress=True):
        return SimpleNamespace(timings={}, camera=None, geometry=None, w=scene.w, h=scene.h)

    def render_reference(prep, spp=1, seed=0, mis=False, **kw):
        timed = sys._getframe(1).f_code.co_name == "timed_render"
        got["renders"].append(dict(spp=spp, seed=seed, mis=mis, timed=timed))
        if timed:
            clock.now += (1, 2, 6)[(seed - 10 - spp) % 3] * 1e-3 * spp * (2 if mis else 1)
        gt, c, cov = _br_images(prep.h, prep.w)
        img = gt + AMP[mis] / math.sqrt(spp) * c
        img[~cov] = 100.0
        k = (1, 2, 6)[(seed - 10 - spp) % 3] if timed else 1   # the stages' times vary as the run's does
        stats = {"time_s": {"shading": 0.1 * k, "gbuffer": 0.05 * k}, "samples_per_second": 2e6 / k,
                 "non_finite_samples": 0}
        return SimpleNamespace(image=img, coverage=cov, stats=stats)

    def ground_truth(prep, gt_spp, cache_dir, progress=True):
        got["gt_spp"] = gt_spp
        gt, c, _ = _br_images(prep.h, prep.w)
        return SimpleNamespace(image=gt, half=gt + GT_HALF_OFFSET * c, spp=gt_spp, chunks=gt_spp // 4096,
                               render_time_s=0.0)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.axes

    real_loglog = matplotlib.axes.Axes.loglog

    def loglog(self, x, y, *a, **kw):
        got["loglog"].append((kw.get("label"), list(map(float, x)), list(map(float, y))))
        return real_loglog(self, x, y, *a, **kw)

    monkeypatch.setattr(matplotlib.axes.Axes, "loglog", loglog)
    monkeypatch.setattr(precompute.npf_to_merl, "npf_to_merl", npf_to_merl)
    monkeypatch.setattr(warpbw.scene, "parse_scene", parse_scene)
    monkeypatch.setattr(warpbw.pipeline, "prepare_scene", prepare_scene)
    monkeypatch.setattr(warpbw.pipeline, "render_reference", render_reference)
    monkeypatch.setattr(warpbw.gbuffer, "render_gbuffer", lambda *a, **k: None)
    monkeypatch.setattr(warpbw.bench, "ground_truth", ground_truth)
    monkeypatch.setattr(mod, "time", clock)
    monkeypatch.setattr(sys, "argv", ["bench_reference.py", *argv])
    import matplotlib.pyplot as plt

    open_before = plt.get_fignums()
    got["outcome"] = outcome(mod.main)
    assert plt.get_fignums() == open_before   # its figure closed, whatever the outcome (one per call stayed open)
    return got


def test_bench_reference_records_each_estimator_against_the_ground_truth(tmp_path, monkeypatch, shared):
    """Module docstring: times are medians of --runs runs; PSNR and relMSE of each render against the ground truth
    (peak and denominator from the ground truth, over the covered pixels); the doubling check compares a MIS render
    at the largest spp against GT/2 and GT; throughput counts evaluations (with MIS a BRDF and an environment
    sample each).  --material, --probe, --rotation, --resolution and --gt-spp reach the scene and the ground
    truth; the plot's 1/spp line starts at BRDF sampling's first relMSE.  Then --check-only keeps the sweep."""
    shared("brdf/npf.bin")
    shared("envmaps/studio.exr")
    out = tmp_path / "b"
    argv = ["--material", "chrome", "--probe", "studio.exr", "--rotation", "30", "--resolution", "12", "8",
            "--spp", "64,16", "--gt-spp", "8192", "--runs", "3", "--out", str(out)]
    got = _run_bench_reference(monkeypatch, tmp_path, argv)
    assert got["outcome"] == "returned 0", got["outcome"]
    assert got["merl"] == ["chrome"] and got["gt_spp"] == 8192
    env, cam = got["toml"]["environment"], got["toml"]["camera"]
    assert Path(env["file"]).name == "studio.exr" and env["rotation"] == 30.0 and cam["resolution"] == [12, 8]
    rec = json.loads((out / "bench_reference.json").read_text())
    assert rec["scene"]["material"].startswith("chrome") and rec["scene"]["probe"] == "studio.exr"
    assert rec["scene"]["resolution"] == [12, 8] and rec["scene"]["covered_pixels"] == 8 * 11
    gt, _, cov = _br_images(8, 12)
    inv = np.mean(1.0 / (gt[cov] ** 2 + RELMSE_EPS_DOC))
    for method, mis in (("brdf_is", False), ("mis", True)):
        recs = rec["methods"][method]
        assert [r["spp"] for r in recs] == [16, 64], method
        for r in recs:
            n = r["spp"]
            mse = AMP[mis] ** 2 / n
            assert r["time_s"] == pytest.approx(2e-3 * n * (2 if mis else 1), rel=1e-9), (method, n)
            assert r["psnr_db"] == pytest.approx(10 * math.log10(2.0 ** 2 / mse), rel=1e-9), (method, n)
            assert r["relmse"] == pytest.approx(mse * inv, rel=1e-9), (method, n)
            # the stages' times are medians of the runs too (runs 1, 2, 6 x 0.1 s and 0.05 s), not the last run's, and
            # the throughput is the samples over that median shading time
            assert r["shading_s"] == pytest.approx(0.2) and r["gbuffer_s"] == pytest.approx(0.1), r
            assert r["samples_per_s"] == pytest.approx(2e6 if mis else 1e6), (method, n)
    timed = [(r["spp"], r["mis"]) for r in got["renders"] if r["timed"]]
    assert sorted(timed) == sorted([(n, m) for n in (16, 64) for m in (False, True)] * 3)
    b = AMP[True] / math.sqrt(64)                  # the MIS render at the largest spp
    d = abs(20 * math.log10(abs(b - GT_HALF_OFFSET) / b))
    assert rec["ground_truth_doubling_delta_db"] == pytest.approx(d, rel=1e-9) and d > 0.5
    assert rec["ground_truth_converged"] is False
    assert sorted(p.name for p in out.glob("*.png")) == ["bench_reference.png", "brdf_is_64spp.png",
                                                          "ground_truth.png", "mis_64spp.png"]
    (line,) = [c for c in got["loglog"] if c[0] == "1/spp"]
    r16 = rec["methods"]["brdf_is"][0]["relmse"]
    assert line[1] == [16, 64] and line[2] == pytest.approx([r16, r16 * 16 / 64], rel=1e-9)
    # --check-only: the sweep of the earlier run is kept, the check redone, no timed render
    before = rec["methods"]
    got = _run_bench_reference(monkeypatch, tmp_path, argv + ["--check-only"])
    assert got["outcome"] == "returned 0", got["outcome"]
    assert not any(r["timed"] for r in got["renders"])
    assert json.loads((out / "bench_reference.json").read_text())["methods"] == before


@pytest.mark.parametrize("runs, warns", [(1, True), (2, True), (3, False)])
def test_bench_reference_records_its_runs_and_warns_below_three(tmp_path, monkeypatch, capsys, shared, runs, warns):
    """DESIGN.md's protocol times the median of at least 3 runs: the record now says how many runs each time is the
    median of (it did not), fewer than 3 are timed with warpbw bench's warning, and --check-only, which times
    nothing, keeps the earlier sweep's count and says nothing of it."""
    shared("brdf/npf.bin")
    shared("envmaps/studio.exr")
    out = tmp_path / "b"
    argv = ["--probe", "studio.exr", "--resolution", "12", "8", "--spp", "16", "--gt-spp", "8192",
            "--runs", str(runs), "--out", str(out)]
    got = _run_bench_reference(monkeypatch, tmp_path, argv)
    assert got["outcome"] == "returned 0", got["outcome"]
    assert sum(r["timed"] for r in got["renders"]) == 2 * runs      # both estimators
    assert json.loads((out / "bench_reference.json").read_text())["runs"] == runs
    err = capsys.readouterr().err
    assert (f"bench_reference.py: warning: --runs {runs}: the measurement protocol times the median of at least 3"
            in err) == warns, err
    got = _run_bench_reference(monkeypatch, tmp_path, argv[:-4] + ["--runs", "5", "--out", str(out), "--check-only"])
    assert got["outcome"] == "returned 0", got["outcome"]
    assert json.loads((out / "bench_reference.json").read_text())["runs"] == runs
    assert "warning: --runs" not in capsys.readouterr().err


def test_bench_reference_check_only_keeps_the_sweep_it_was_run_with(tmp_path, monkeypatch, shared):
    """--check-only redoes the ground truth's doubling check on an earlier run's sweep (module docstring): at that
    sweep's largest spp, with the plot's 1/spp line over its spp, whatever --spp defaults to (it once took both
    from this command's --spp default, 1024, for a sweep of 64 and 256).  Options that describe another scene or
    sweep are refused before anything is rendered, naming the value to pass, and a file that is not a record is
    refused naming it."""
    shared("brdf/npf.bin")
    shared("envmaps/studio.exr")
    out = tmp_path / "b"
    base = ["--material", "chrome", "--probe", "studio.exr", "--resolution", "12", "8", "--gt-spp", "8192",
            "--out", str(out)]
    got = _run_bench_reference(monkeypatch, tmp_path, base + ["--spp", "64,256", "--runs", "1"])
    assert got["outcome"] == "returned 0", got["outcome"]
    json_path = out / "bench_reference.json"
    swept = json.loads(json_path.read_text())["methods"]
    for again in ([], ["--spp", "256,64"]):   # the sweep's spp, given or not
        got = _run_bench_reference(monkeypatch, tmp_path, base + ["--check-only", *again])
        assert got["outcome"] == "returned 0", got["outcome"]
        assert [r for r in got["renders"] if r["spp"] > 1] == [dict(spp=256, seed=77, mis=True, timed=False)]
        (line,) = [c for c in got["loglog"] if c[0] == "1/spp"]
        r64 = swept["brdf_is"][0]["relmse"]
        assert line[1] == [64, 256] and line[2] == pytest.approx([r64, r64 / 4], rel=1e-9)
        assert json.loads(json_path.read_text())["methods"] == swept
    for option, then, now in (("--material", "chrome", "gold-metallic-paint"), ("--resolution", "12 8", "8 8"),
                              ("--rotation", "0", "30"), ("--spp", "64,256", "64,128")):
        given = base.copy()   # the option once, with the other value (an option given twice is refused)
        if option in given:
            at = given.index(option) + 1
            given[at:at + len(now.split())] = now.split()
        else:
            given += [option, *now.split()]
        argv = given + ["--check-only"]
        got = _run_bench_reference(monkeypatch, tmp_path, argv)
        assert got["outcome"] == (f"WarpbwError: --check-only: {json_path} holds a sweep run with {option} {then}, "
                                  f"not {now}; pass {option} {then}"), got["outcome"]
        assert got["renders"] == [] and json.loads(json_path.read_text())["methods"] == swept
    json_path.write_text('{"scene": {}}')
    got = _run_bench_reference(monkeypatch, tmp_path, base + ["--check-only"])
    assert got["outcome"].startswith(f"WarpbwError: --check-only: {json_path} is not the records of a "
                                     "bench_reference run"), got["outcome"]
    assert got["renders"] == []

def test_bench_reference_defaults_are_the_documented_ones(tmp_path, monkeypatch, shared):
    """Module docstring: gold-metallic-paint under forest.exr at 512x512, spp 16 to 1024 by powers of 2, a 16384-spp
    ground truth, medians of 3 runs, rotation 0."""
    shared("brdf/npf.bin")
    shared("envmaps/forest.exr")
    got = _run_bench_reference(monkeypatch, tmp_path, ["--out", str(tmp_path / "b")])
    assert got["outcome"] == "returned 0", got["outcome"]
    assert got["merl"] == ["gold-metallic-paint"] and got["gt_spp"] == 16384
    env, cam = got["toml"]["environment"], got["toml"]["camera"]
    assert Path(env["file"]).name == "forest.exr" and env["rotation"] == 0.0 and cam["resolution"] == [512, 512]
    timed = [(r["spp"], r["mis"]) for r in got["renders"] if r["timed"]]
    assert sorted(timed) == sorted([(2 ** k, m) for k in range(4, 11) for m in (False, True)] * 3)


# -------------------------------------------- what the bench command prints and writes; its table, n_b sweep and cache
# (mutation round 8: each test fails on a plausible mistake the suite let through)


@pytest.fixture
def bench_dir(tmp_path, monkeypatch):
    """A working folder holding SCENE as env.toml."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("WARPBW_CACHE", str(tmp_path / "_cache"))
    (tmp_path / "env.toml").write_text(SCENE)
    return tmp_path


def _bench_record(converged=True):
    return {"scene": "s.toml", "resolution": [6, 4], "pixels_covered": 12, "estimator": "mis",
            "ground_truth_spp": 64, "ground_truth_doubling_delta_db": 0.1 if converged else 0.75,
            "ground_truth_converged": converged, "runs": 3, "methods": {"reference": [], "adaptive": []},
            "equal_quality_speedup": None, "equal_quality_speedup_se": None, "equal_quality_budget": None,
            "bandwidth_time_fraction": None}


@pytest.mark.parametrize("converged", [True, False])
def test_bench_says_where_it_wrote_and_warns_only_of_an_unconverged_ground_truth(bench_dir, monkeypatch, capsys,
                                                                                   converged):
    """bench says where it wrote the record and the plot, and warns of the ground truth only when it is not converged
    (doubling changes PSNR by >= 0.5 dB)."""
    import warpbw.bench as bench
    from warpbw.cli import main

    monkeypatch.setattr(bench, "run_bench", lambda *a, **k: _bench_record(converged))
    monkeypatch.setattr(bench, "write_plot", lambda rec, path: Path(path).write_bytes(b"png"))
    assert main(["bench", "env.toml", "--json", "b.json", "--cache", "gt"]) == 0
    out, err = capsys.readouterr()
    assert "record b.json, plot b.png" in out.splitlines()
    assert Path("b.png").read_bytes() == b"png" and json.loads(Path("b.json").read_text())["runs"] == 3
    warned = [x for x in err.splitlines() if "ground truth is not converged" in x]
    assert warned == ([] if converged else ["warpbw: warning: the ground truth is not converged (doubling changes "
                                            "PSNR by 0.75 dB >= 0.5 dB): raise --gt-spp"]), err


def test_bench_writes_the_record_beside_a_plot_given_alone(bench_dir, monkeypatch, capsys):
    """bench --plot alone writes the record beside the plot (--help: "--json ...: without it, beside --plot as
    OUT.json")."""
    import warpbw.bench as bench
    from warpbw.cli import main

    monkeypatch.setattr(bench, "run_bench", lambda *a, **k: _bench_record())
    monkeypatch.setattr(bench, "write_plot", lambda rec, path: Path(path).write_bytes(b"png"))
    assert main(["bench", "env.toml", "--plot", "b.png", "--cache", "gt"]) == 0
    assert sorted(p.name for p in Path().glob("b.*")) == ["b.json", "b.png"]
    assert json.loads(Path("b.json").read_text())["runs"] == 3 and Path("b.png").read_bytes() == b"png"
    assert "record b.json, plot b.png" in capsys.readouterr().out.splitlines()


def test_bench_refuses_to_replace_a_plot_left_alone(bench_dir, monkeypatch, capsys):
    """The plot goes beside the record (--help) and is an output like it."""
    import warpbw.bench as bench
    from warpbw.cli import main

    capture_call(monkeypatch, bench, "run_bench")   # reaching it fails the test
    Path("b.png").write_bytes(b"mine")
    assert outcome(main, ["bench", "env.toml", "--json", "b.json", "--cache", "gt", "-q"]) == "returned 2"
    assert "b.png: already exists" in capsys.readouterr().err and Path("b.png").read_bytes() == b"mine"


@pytest.mark.parametrize("runs, warns", [(1, True), (2, True), (3, False), (5, False)])
def test_bench_warns_of_fewer_runs_than_the_protocols_three(tmp_path, capsys, runs, warns):
    """bench warns of fewer runs than DESIGN.md's protocol times (the median of at least 3 runs); 3 is enough."""
    from warpbw.cli import _write_bench

    args = SimpleNamespace(json=str(tmp_path / "r.json"), plot=str(tmp_path / "r.png"), quiet=True, runs=runs,
                           force=False)
    _write_bench(args, {"x": 1}, lambda rec, path: Path(path).write_bytes(b"png"))
    assert ("--runs" in capsys.readouterr().err) == warns


def _table_record():
    ada = {"budget": 2.0, "time_s": 0.5, "psnr_db": 30.0, "psnr_se_db": 0.25, "relmse": 1e-3,
           "shaded_fraction": 0.4, "bandwidth_time_fraction": 0.125, "equal_quality_speedup": 3.5,
           "equal_quality_speedup_se": 0.75, "extrapolated": False,
           "gbuffer_time_s": 0.004, "bandwidth_time_s": 0.0625, "shading_time_s": 0.3, "hierarchy_time_s": 0.002,
           "upsampling_time_s": 0.011}
    far = {**ada, "budget": 8.0, "time_s": 0.25, "psnr_db": 40.0, "psnr_se_db": 0.5, "shaded_fraction": 0.9,
           "bandwidth_time_fraction": 0.3, "equal_quality_speedup": 10.0, "equal_quality_speedup_se": 2.0,
           "extrapolated": True, "gbuffer_time_s": 0.5}
    ref = {"spp": 4, "time_s": 1.25, "psnr_db": 28.0, "psnr_se_db": 0.125, "relmse": 2e-3}
    return {"scene": "s.toml", "resolution": [6, 4], "pixels_covered": 12, "estimator": "mis", "ground_truth_spp": 64,
            "ground_truth_doubling_delta_db": 0.1, "runs": 3, "methods": {"reference": [ref], "adaptive": [ada, far]},
            "equal_quality_speedup": 3.5, "equal_quality_speedup_se": 0.75, "equal_quality_budget": 2.0,
            "bandwidth_time_fraction": 0.125, "bandwidth_pass_reference_spp": 2.5,
            "nb_sweep": [{"n_b": 16, "psnr_db": 29.0, "psnr_se_db": 0.2, "time_s": 0.4, "bandwidth_time_s": 0.0123},
                         {"n_b": 64, "psnr_db": 29.5, "psnr_se_db": 0.3, "time_s": 0.6, "bandwidth_time_s": 0.05}],
            "nb_psnr_range_db": 0.5, "nb_psnr_range_se_db": 0.2}


def test_bench_table_puts_each_figure_under_its_heading(tmp_path):
    """Each figure of bench's table sits under its heading: shaded as a percentage, bw % the bandwidth pass's share of
    the frame, the speed-up with its own standard error and * when extrapolated; the stage breakdown of the headline's
    budget in ms; the n_b rows. Hand-made record."""
    from warpbw.bench import format_table

    lines = format_table(_table_record()).splitlines()
    head = next(x for x in lines if x.startswith("method"))
    assert head.split() == ["method", "spp/budget", "time", "(s)", "PSNR", "+/-", "relMSE", "shaded", "bw", "%",
                            "speed-up", "+/-"]
    rows = [x.split() for x in lines if x.startswith(("reference ", "adaptive "))]
    # shaded in %, bw % as the percentage of the frame, speed-up with its own standard error, * when extrapolated
    assert rows == [["reference", "4", "1.250", "28.00", "0.12", "2.000e-03"],
                    ["adaptive", "2", "0.500", "30.00", "0.25", "1.000e-03", "40.0%", "12.5", "3.50x", "0.75"],
                    ["adaptive", "8", "0.250", "40.00", "0.50", "1.000e-03", "90.0%", "30.0", "10.00x", "2.00*"]]
    assert "equal-quality speed-up: 3.50x +/- 0.75 at budget 2" in lines
    assert "bandwidth pass: 12.5% of the frame" in lines
    # the frame of the headline's budget (2), not of the extrapolated one's, in milliseconds
    assert ("where the frame's time goes at budget 2 (its last run): G-buffer 4 ms, bandwidth pass 62 ms, "
            "shading 300 ms, hierarchy 2 ms, up-sampling 11 ms") in lines
    assert "the bandwidth pass costs what the reference's shading spends on 2.5 samples per pixel" in lines
    assert "n_b    16: PSNR 29.00 +/- 0.20 dB, 0.400 s, bandwidth 12.3 ms" in lines
    assert "n_b sweep: PSNR range 0.50 dB (standard error 0.20 dB over 3 paired runs)" in lines


def test_nb_sweep_range_is_between_its_best_and_worst_points_not_its_ends(tmp_path, monkeypatch):
    """Three n_b whose PSNRs are not monotone; the range and its paired standard error are those of the highest and the
    lowest PSNR (bench docstring: "the paired per-run differences between its two ends", "picked after the fact")"""
    from warpbw import bench, pipeline
    from warpbw.scene import parse_scene


    amps = {16: (0.2, 0.25), 64: (0.1, 0.15), 256: (0.4, 0.5)}    # per run r: the frame's error amplitude

    clock = StandInClock()

    def fake_reference(prep, spp, seed=0, mis=False, **kw):
        clock.now += 0.01 * spp
        return SimpleNamespace(image=_frame(0.0 if seed >= 1_000_000 else 0.3 / math.sqrt(spp)), coverage=_COV,
                               stats={"time_s": {"shading": 0.01, "gbuffer": 0.001}})

    def fake_adaptive(prep, budget, seed=0, mis=False, n_b=None, **kw):
        amp = 0.2 if n_b is None else amps[n_b][seed // 7]
        clock.now += 0.01
        return _fake_adaptive_result(_frame(amp), _COV, 0.01, budget)

    monkeypatch.setattr(bench, "time", clock)
    monkeypatch.setattr(pipeline, "render_reference", fake_reference)
    monkeypatch.setattr(pipeline, "render_adaptive", fake_adaptive)
    rec = bench.run_bench(parse_scene(SCENE, tmp_path, "s.toml"), spp_list=(1, 4), budgets=(1,), nb_list=(16, 64, 256),
                          gt_spp=64, runs=2, cache_dir=tmp_path / "gt", progress=False, log=lambda *a, **k: None)
    peak = float(bench.np.max(_frame(0.0)[_COV]))
    psnr = {n: 10 * math.log10(peak ** 2 / np.mean(np.square(a))) for n, a in amps.items()}
    assert [r["psnr_db"] for r in rec["nb_sweep"]] == pytest.approx([psnr[16], psnr[64], psnr[256]], rel=1e-4)
    assert rec["nb_psnr_range_db"] == pytest.approx(psnr[64] - psnr[256], rel=1e-4)
    d = [20 * math.log10(amps[256][r] / amps[64][r]) for r in range(2)]      # per-run differences, dB
    assert rec["nb_psnr_range_se_db"] == pytest.approx(abs(d[0] - d[1]) / 2, rel=1e-4)   # std (n-1) / sqrt(2)


def _gt_stand_in(monkeypatch, h=24, w=24):
    """ground_truth's renderer as a stand-in: a chunk of N spp is the image N everywhere; the spp rendered listed."""
    from warpbw import pipeline

    rendered = []

    def fake(prep, spp=1, seed=0, mis=False, **kw):
        rendered.append(spp)
        return SimpleNamespace(image=np.full((h, w, 3), float(spp), np.float32))

    monkeypatch.setattr(pipeline, "render_reference", fake)
    return rendered


def _prep(tmp_path, h=24, w=24):
    from warpbw.scene import parse_scene


    return SimpleNamespace(scene=parse_scene(SCENE, tmp_path, "s.toml"), height=h, width=w)


def test_ground_truth_of_more_samples_does_not_read_chunks_of_fewer(tmp_path, monkeypatch):
    """64 spp are 2 chunks of 32; 128 spp are 2 chunks of 64, not the 32-spp chunks read again."""
    rendered = _gt_stand_in(monkeypatch)
    prep = _prep(tmp_path)
    assert bench.ground_truth(prep, 64, tmp_path / "gt", progress=False).image.max() == 32.0 and rendered == [32, 32]
    more = bench.ground_truth(prep, 128, tmp_path / "gt", progress=False)
    assert rendered == [32, 32, 64, 64] and np.all(more.image == 64.0) and more.spp == 128


def test_ground_truth_records_the_samples_it_took(tmp_path, monkeypatch):
    """Chunks of at most GT_CHUNK_SPP, in an even number: 16384 spp are four chunks of 4096, 12288 six of 2048 (three
    of 4096 have no half), and the record's spp is what they hold together."""
    rendered = _gt_stand_in(monkeypatch)
    gt = bench.ground_truth(_prep(tmp_path), 16384, tmp_path / "gt", progress=False)
    assert rendered == [4096] * 4 and gt.spp == sum(rendered) == 16384 and gt.chunks == 4
    rendered.clear()
    gt = bench.ground_truth(_prep(tmp_path), 12288, tmp_path / "gt", progress=False)
    assert rendered == [2048] * 6 and gt.spp == sum(rendered) == 12288 and gt.chunks == 6


def test_ground_truth_of_a_wide_image_is_read_from_the_cache(tmp_path, monkeypatch):
    """A 24x12 frame's chunks are read back, not rendered again every time."""
    rendered = _gt_stand_in(monkeypatch, h=12, w=24)
    prep = _prep(tmp_path, h=12, w=24)
    bench.ground_truth(prep, 8, tmp_path / "gt", progress=False)
    again = bench.ground_truth(prep, 8, tmp_path / "gt", progress=False)
    assert rendered == [4, 4] and again.render_time_s == 0.0 and again.image.shape == (12, 24, 3)


def test_reading_a_cached_chunk_removes_what_a_killed_writer_of_it_left(tmp_path, monkeypatch):
    """Two benches of one scene render its chunks at once and one is killed while it writes a chunk (SIGKILL); the
    other writes the chunk whole, and later benches read it.  No bench wrote it again, so the killed one's hidden
    temporary stayed in the cache for good; reading the chunk now removes it.  Truth: a real process killed while it
    wrote the chunk; the chunks are read, not rendered again."""
    rendered = _gt_stand_in(monkeypatch)
    prep = _prep(tmp_path)
    first = bench.ground_truth(prep, 8, tmp_path / "gt", progress=False)
    chunks = sorted((tmp_path / "gt").iterdir())
    killed_writer_temp(chunks[1])
    again = bench.ground_truth(prep, 8, tmp_path / "gt", progress=False)
    assert rendered == [4, 4] and np.array_equal(again.image, first.image)
    assert sorted((tmp_path / "gt").iterdir()) == chunks


def test_ground_truth_chunk_with_one_nan_pixel_is_rendered_again(tmp_path, monkeypatch):
    """A cached chunk with one NaN pixel is rendered again (_cached_chunk: "not finite: such a chunk is rendered
    again"); one is enough to poison the mean."""
    from warpbw.io.exr import write_exr

    rendered = _gt_stand_in(monkeypatch)
    prep = _prep(tmp_path)
    bench.ground_truth(prep, 8, tmp_path / "gt", progress=False)
    (chunk,) = sorted((tmp_path / "gt").glob("ground_truth-*-chunk0-*.exr"))
    img = np.full((24, 24, 3), 4.0, np.float32)
    img[3, 5, 1] = np.nan
    write_exr(chunk, img)
    again = bench.ground_truth(prep, 8, tmp_path / "gt", progress=False)
    assert rendered == [4, 4, 4] and np.isfinite(again.image).all()


_KEY_SCENE = """
[camera]
position = [0.0, 0.0, 4.0]
look_at = [0.0, 0.0, 0.0]
up = [0.0, 1.0, 0.0]
fov = 30.0
resolution = [24, 16]
[environment]
file = "probe.exr"
rotation = 10.0
scale = 1.0
[[light]]
type = "directional"
direction = [0.0, 1.0, 0.0]
radiance = [1.0, 1.0, 1.0]
[[object]]
shape = "sphere"
center = [0.0, 0.0, 0.0]
radius = 1.0
material = "g"
[[object]]
mesh = "m.obj"
material = "t"
translate = [0.0, 0.0, 0.0]
scale = 1.0
rotate_y = 0.0
[[object]]
shape = "plane"
center = [0.0, -1.0, 0.0]
size = 4.0
material = "ct"
[material.g]
type = "ggx"
alpha = 0.2
specular = [0.9, 0.9, 0.9]
eta = [0.2, 0.4, 1.4]
k = [3.9, 2.4, 1.6]
[material.t]
type = "merl"
file = "a.binary"
lookup = "nearest"
sampling = "samp.npz"
[material.ct]
type = "cook-torrance"
roughness = 0.3
f0 = [0.04, 0.04, 0.04]
"""

# Every input of the reference the ground truth's chunks are rendered with, changed alone (cache-key audit, session
# 70): scene text edits (old, new) and file rewrites (name, bytes).  The plane clips the truth (run_bench).
_GT_INPUTS = {
    "camera position": ("position = [0.0, 0.0, 4.0]", "position = [0.0, 0.0, 4.5]"),
    "camera look_at": ("look_at = [0.0, 0.0, 0.0]", "look_at = [0.0, 0.1, 0.0]"),
    "camera up": ("up = [0.0, 1.0, 0.0]", "up = [0.1, 1.0, 0.0]"),
    "camera fov": ("fov = 30.0", "fov = 31.0"),
    "resolution": ("[24, 16]", "[24, 18]"),
    "env rotation": ("rotation = 10.0", "rotation = 11.0"),
    "env scale": ("scale = 1.0\n[[light]]", "scale = 2.0\n[[light]]"),
    "env source": ('file = "probe.exr"', 'procedural = "sky"'),
    "light direction": ("direction = [0.0, 1.0, 0.0]", "direction = [0.0, 0.0, 1.0]"),
    "light radiance": ("radiance = [1.0, 1.0, 1.0]", "radiance = [2.0, 1.0, 1.0]"),
    "sphere centre": ("center = [0.0, 0.0, 0.0]", "center = [0.1, 0.0, 0.0]"),
    "sphere radius": ("radius = 1.0", "radius = 0.9"),
    "mesh translate": ("translate = [0.0, 0.0, 0.0]", "translate = [0.1, 0.0, 0.0]"),
    "mesh scale": ("scale = 1.0\nrotate_y", "scale = 1.5\nrotate_y"),
    "mesh rotate_y": ("rotate_y = 0.0", "rotate_y = 5.0"),
    "plane centre": ("center = [0.0, -1.0, 0.0]", "center = [0.0, -0.9, 0.0]"),
    "plane size": ("size = 4.0", "size = 5.0"),
    "ggx alpha": ("alpha = 0.2", "alpha = 0.25"),
    "ggx specular": ("specular = [0.9, 0.9, 0.9]", "specular = [0.8, 0.9, 0.9]"),
    "ggx eta": ("eta = [0.2, 0.4, 1.4]", "eta = [0.3, 0.4, 1.4]"),
    "ggx k": ("k = [3.9, 2.4, 1.6]", "k = [3.8, 2.4, 1.6]"),
    "merl lookup": ('lookup = "nearest"', 'lookup = "linear"'),
    "materials swapped": ('material = "g"\n[[object]]\nmesh = "m.obj"\nmaterial = "t"',
                          'material = "t"\n[[object]]\nmesh = "m.obj"\nmaterial = "g"'),
    "probe bytes": ("probe.exr", b"another probe"),
    "mesh bytes": ("m.obj", b"v 0 0 0\nv 2 0 0\nv 0 1 0\nf 1 2 3\n"),
    "merl bytes": ("a.binary", b"another merl"),
    "sampling table bytes": ("samp.npz", b"other tables"),
}


@pytest.mark.parametrize("what", list(_GT_INPUTS))
def test_every_input_of_the_reference_changes_the_ground_truths_key(tmp_path, what):
    """A cached chunk is read back by its key alone (and its size): an input of the reference the key missed would
    average a chunk of another scene into the truth, silently.  Each input of the audit's table changed alone gives
    another key; the seed too, and the same scene gives the same key."""
    from warpbw.scene import parse_scene

    files = {"probe.exr": b"probe", "m.obj": b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "a.binary": b"merl",
             "samp.npz": b"tables"}
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)

    def key(text, seed=bench.GT_SEED):
        return bench.gt_key(parse_scene(text, base_dir=tmp_path, source="s.toml"), seed)

    k0 = key(_KEY_SCENE)
    assert key(_KEY_SCENE) == k0 and key(_KEY_SCENE, bench.GT_SEED + 1) != k0
    old, new = _GT_INPUTS[what]
    if isinstance(new, bytes):
        (tmp_path / old).write_bytes(new)
        assert key(_KEY_SCENE) != k0
    else:
        assert old in _KEY_SCENE
        assert key(_KEY_SCENE.replace(old, new, 1)) != k0


def test_a_bandwidth_file_leaves_the_ground_truths_key_and_the_reference_frame_alone(tmp_path, monkeypatch):
    """The reference never reads a material's nu_rho table (``bandwidth =``, which only the adaptive pass reads), so
    the truth's key ignores it (``Scene.reference_hash``): a scene naming one, naming another, and naming none share
    a key, and a table built again renders no truth again.  A scene naming none keys as before session 70 (the
    content hash; the truths cached then stay valid).  And why it may: the reference frame of a scene naming a file
    that is no table at all is the frame without it, bit for bit."""
    import hashlib

    from conftest import fake_npf_table
    from warpbw.pipeline import render_reference
    from warpbw.scene import load_scene, parse_scene

    monkeypatch.setenv("WARPBW_CACHE", str(tmp_path / "cache"))
    fake_npf_table(tmp_path / "npf.bin")
    (tmp_path / "bw1.npz").write_bytes(b"one table")
    (tmp_path / "bw2.npz").write_bytes(b"another table")
    lines = ["[camera]", "position = [0.0, 0.0, 3.0]", "look_at = [0.0, 0.0, 0.0]", "fov = 50.0", "resolution = [8, 8]",
             "[environment]", 'procedural = "sky"', "[[object]]", 'shape = "sphere"', "radius = 0.8", 'material = "m"',
             "[material.m]", 'type = "npf"', 'table = "npf.bin"', 'name = "chrome"']
    texts = {bw: "\n".join(lines + ([] if bw is None else [f'bandwidth = "{bw}"'])) for bw in (None, "bw1.npz",
                                                                                             "bw2.npz")}
    scenes = {bw: parse_scene(t, base_dir=tmp_path, source="s.toml") for bw, t in texts.items()}
    keys = {bw: bench.gt_key(s, bench.GT_SEED) for bw, s in scenes.items()}
    assert len(set(keys.values())) == 1, keys
    assert len({s.content_hash() for s in scenes.values()}) == 3   # the record's scene_hash still tells them apart
    before = hashlib.blake2b(f"{scenes[None].content_hash()}|seed {bench.GT_SEED}|gt v{bench.GT_VERSION}".encode(),
                             digest_size=8)
    assert keys[None] == f"v{bench.GT_VERSION}-{before.hexdigest()}"
    (tmp_path / "with.toml").write_text(texts["bw1.npz"])
    (tmp_path / "without.toml").write_text(texts[None])
    frames = [render_reference(load_scene(tmp_path / f"{n}.toml"), spp=4, seed=3, mis=True).image
              for n in ("with", "without")]
    np.testing.assert_array_equal(frames[0], frames[1])


def test_bandwidth_time_fraction_is_each_frames_own_share_not_one_runs_pass_over_the_median(tmp_path, monkeypatch):
    """Closed form (session 78): every adaptive frame spends a tenth of its wall time in the bandwidth pass
    (``_fake_adaptive_result``), and the last of 3 runs takes 20 times as long (a stall).  The fraction is then 0.1
    whatever the runs took; it was the last run's pass over the runs' median time, 0.1 x 20 = 2.0, and the table said
    "bandwidth pass: 200.0% of the frame" (runs of 2, 1 and 3 times: 0.15; the slow run first: 0.1 by chance)."""
    from warpbw.scene import parse_scene

    for run_time in ((1.0, 1.0, 20.0), (20.0, 1.0, 1.0), (2.0, 1.0, 3.0)):
        _fake_renderers(monkeypatch, ref_amp=_power_law_amp, ada={1.0: (_power_law_amp(11.0), 0.02)},
                        run_time=run_time)
        rec = bench.run_bench(parse_scene(SCENE, tmp_path, "s.toml"), spp_list=(1, 4, 16), budgets=(1,), gt_spp=64,
                              runs=3, cache_dir=tmp_path / "gt", progress=False, log=lambda *a, **kw: None)
        (p,) = rec["methods"]["adaptive"]
        assert p["time_s"] == pytest.approx(0.02 * sorted(run_time)[1], rel=1e-9)   # the median, as before
        assert p["bandwidth_time_fraction"] == pytest.approx(0.1, rel=1e-9), run_time
        assert rec["bandwidth_time_fraction"] == pytest.approx(0.1, rel=1e-9), run_time
        assert "bandwidth pass: 10.0% of the frame" in bench.format_table(rec)


def test_bandwidth_time_fraction_is_the_median_of_the_runs_shares(tmp_path, monkeypatch):
    """Closed form (mutation round 12): each adaptive frame of 0.02 s times its run's factor (1, 1, 20) spends a tenth
    of it in the bandwidth pass and 0.02 s more of wall time outside its stages, so its share of the wall time is
    0.1 t / (t + 0.02): 0.05, 0.05 and 0.0952.  The fraction is their median, 0.05 (their mean 0.065, the last
    run's 0.0952)."""
    from warpbw.scene import parse_scene

    _fake_renderers(monkeypatch, ref_amp=_power_law_amp, ada={1.0: (_power_law_amp(11.0), 0.02)},
                    run_time=(1.0, 1.0, 20.0), ada_host_time=0.02)
    rec = bench.run_bench(parse_scene(SCENE, tmp_path, "s.toml"), spp_list=(1, 4, 16), budgets=(1,), gt_spp=64,
                          runs=3, cache_dir=tmp_path / "gt", progress=False, log=lambda *a, **kw: None)
    (p,) = rec["methods"]["adaptive"]
    assert p["bandwidth_time_fraction"] == pytest.approx(0.05, rel=1e-9)


def test_the_ground_truth_holds_a_running_sum_not_every_chunk(tmp_path, monkeypatch):
    """``ground_truth`` kept every chunk in a list (a cached one with its file's RGBA) and ``np.mean`` stacked them
    again: 28 bytes per pixel per chunk at the peak, 1.9 GB for --gt-spp 65536 at 2048 x 2048 (session 79).  Now it
    sums them as they come: numpy's peak over 16 chunks is that over 2, rendered or read from the cache.  Truth: the
    mean of the chunks and of their first half, computed here (``np.mean`` over the stacked chunks: the old code's,
    bit for bit) from the chunks the stand-in renderer returned (drawn again from their seeds)."""
    import tracemalloc

    from warpbw import pipeline

    h, w = 96, 128
    frame = h * w * 3 * 4
    seeds = []

    def chunk(seed):
        return np.random.default_rng(seed).lognormal(0.0, 2.0, (h, w, 3)).astype(np.float32)

    def fake(prep, spp=1, seed=0, mis=False, **kw):
        seeds.append(seed)
        return SimpleNamespace(image=chunk(seed))

    monkeypatch.setattr(pipeline, "render_reference", fake)
    prep = _prep(tmp_path, h, w)
    peaks = {}
    for gt_spp, n in ((8192, 2), (16 * bench.GT_CHUNK_SPP, 16)):
        for cached in (False, True):
            seeds.clear()
            tracemalloc.start()
            try:
                gt = bench.ground_truth(prep, gt_spp, tmp_path / f"gt{n}", progress=False)
                peaks[n, cached] = tracemalloc.get_traced_memory()[1]
            finally:
                tracemalloc.stop()
            assert len(seeds) == (0 if cached else n) and gt.chunks == n and (gt.render_time_s == 0) == cached
            made = [chunk(bench.GT_SEED + k * bench.GT_SEED_STEP) for k in range(n)]
            assert np.array_equal(gt.image, np.mean(made, axis=0)) and gt.image.dtype == np.float32
            assert np.array_equal(gt.half, np.mean(made[: n // 2], axis=0))
            del made
    for cached in (False, True):   # chunks in flight and the two sums, not 16 frames
        assert peaks[16, cached] < peaks[2, cached] + frame, (cached, peaks[16, cached] / frame,
                                                               peaks[2, cached] / frame)


def test_equal_quality_on_a_curve_whose_mse_rises_reads_the_first_crossing_and_warns(tmp_path, monkeypatch):
    """A reference curve whose MSE does not fall at every count (noise; near the largest counts, the ground truth's
    own noise) was interpolated in the order of its MSEs, across counts that are not adjacent: a flat end of 0.12,
    0.06, 0.07 at 8, 16, 32 spp read 0.08 at 22.7 spp, unflagged, where the curve reaches it at 12 (a speed-up 1.9x
    too high, without a word; session 78 left it).  Now the count is the first at which the curve falls to the MSE,
    and run_bench warns of the rise.  Truth: log-log interpolation by hand between the adjacent counts."""
    from warpbw import pipeline
    from warpbw.scene import parse_scene

    def curve(spp, mse):
        return [{"spp": s, "mse": m, "time_s": 0.01 * s} for s, m in zip(spp, mse)]

    flat_end = curve((1, 2, 4, 8, 16, 32), (1.0, 0.5, 0.25, 0.12, 0.06, 0.07))
    spp, t, ext = bench.equal_quality_time(flat_end, 0.08)   # between 8 and 16: the MSE halves per doubling
    assert math.isclose(spp, 8 * 0.12 / 0.08, rel_tol=1e-12) and math.isclose(t, 0.12, rel_tol=1e-12) and not ext
    spp, t, ext = bench.equal_quality_time(flat_end, 0.05)   # below every MSE, and the last segment rises
    assert math.isnan(spp) and math.isnan(t) and ext
    bump = curve((1, 2, 4, 8, 16, 32), (1.0, 0.5, 0.26, 0.12, 0.51, 0.03))   # session 78's example: read 5.69
    spp, _, ext = bench.equal_quality_time(bump, 0.505)
    assert math.isclose(spp, 2.0 ** (math.log(1 / 0.505) / math.log(2.0)), rel_tol=1e-12) and not ext
    assert bench.mse_rises(bump) == [(8, 16)] and bench.mse_rises(flat_end) == [(16, 32)]

    h = w = 8
    cov = np.ones((h, w), bool)
    truth = np.full((h, w, 3), 0.5, np.float32)
    sign = np.where(np.indices((h, w)).sum(0) % 2 == 0, 1.0, -1.0)[..., None]
    amp = {1: 1.0, 2: 0.5, 4: 0.25, 8: 0.2, 16: 0.1, 32: 0.11}   # the MSE rises from 16 to 32 spp
    clock = StandInClock()
    monkeypatch.setattr(bench, "time", clock)

    def fake_reference(prep, spp, seed=0, mis=False, **kw):
        if seed >= 1_000_000:   # the ground truth's chunks: exact
            return SimpleNamespace(image=truth.copy(), coverage=cov, stats={})
        clock.now += 0.01 * spp
        return SimpleNamespace(image=(truth + amp[spp] * sign).astype(np.float32), coverage=cov,
                               stats={"time_s": {"shading": 0.009 * spp, "gbuffer": 0.001 * spp}})

    def fake_adaptive(prep, budget, seed=0, mis=False, **kw):
        clock.now += 0.01
        return _fake_adaptive_result((truth + 0.15 * sign).astype(np.float32), cov, 0.01, budget)

    monkeypatch.setattr(pipeline, "render_reference", fake_reference)
    monkeypatch.setattr(pipeline, "render_adaptive", fake_adaptive)
    scene = parse_scene(SCENE, tmp_path, "s.toml")
    with pytest.warns(RuntimeWarning, match=r"s.toml: the reference's MSE rises from 16 to 32 spp .*the first at "):
        rec = bench.run_bench(scene, spp_list=sorted(amp), budgets=(1,), gt_spp=64, runs=1,
                              cache_dir=tmp_path / "gt", progress=False, log=lambda *a, **kw: None)
    (p,) = rec["methods"]["adaptive"]   # MSE 0.0225 between 8 (0.04) and 16 (0.01) spp: 8 x 2^(log(0.04/0.0225)/log 4)
    assert math.isclose(p["equal_quality_spp"], 8 * 2 ** (math.log(0.04 / 0.0225) / math.log(4)), rel_tol=1e-6), p
    assert not p["extrapolated"]


def test_equal_quality_reads_the_first_count_of_a_flat_step_and_no_count_past_a_flat_end():
    """Rules of ``equal_quality_time`` and ``mse_rises`` (their docstrings; truth: the curves' closed forms).  A
    curve flat from 1 to 2 spp reaches its MSE at 1 spp, the first count; below a flat end no count is read (NaN,
    flagged); a single count is read as extrapolated; a time that grows as spp^2 along a nearly flat end overflows
    to inf (flagged) rather than raising.  A flat step is no rise, nor is the step from a count of MSE 0 (left out, as
    ``equal_quality_time`` leaves it out)."""
    def curve(spp, mse, time=None):
        return [{"spp": s, "mse": m, "time_s": 0.01 * s if time is None else t}
                for s, m, t in zip(spp, mse, time or spp)]

    step = curve((1, 2, 4), (0.5, 0.5, 0.25))
    spp, t, ext = bench.equal_quality_time(step, 0.5)
    assert (spp, ext) == (1.0, False) and math.isclose(t, 0.01, rel_tol=1e-12)
    assert bench.mse_rises(step) == [] and bench.mse_rises(curve((1, 2, 4), (0.0, 0.5, 0.25))) == []
    flat_end = curve((1, 2, 4), (0.5, 0.25, 0.25))
    spp, t, ext = bench.equal_quality_time(flat_end, 0.1)
    assert math.isnan(spp) and math.isnan(t) and ext
    spp, t, ext = bench.equal_quality_time(curve((4,), (0.2,)), 0.1)
    assert (spp, ext) == (4.0, True) and math.isclose(t, 0.04, rel_tol=1e-12)
    squared = curve((1, 2), (1.0, 0.99), time=(1.0, 4.0))   # MSE 0.99^log2(spp), time spp^2
    spp, t, ext = bench.equal_quality_time(squared, 0.99 ** (400 / math.log(2)))   # at spp = e^400: time e^800
    assert math.isinf(t) and ext


def test_each_frame_of_an_animation_and_a_rolled_camera_has_a_ground_truth_of_its_own(tmp_path):
    """Frames of an animation on one prepared scene, the mesh deformed anew for each (update_mesh) with the camera
    left as it is, and a camera rolled about its axis (the scene's position and look-at, another up): each frame's
    ground truth is its own, as rendered into an empty cache (truth), not the one of the frame before it or of the
    scene (their camera values and geometry digests differ)."""
    import trimesh

    from warpbw.gbuffer import make_camera, update_mesh
    from warpbw.pipeline import prepare_scene
    from warpbw.scene import parse_scene

    trimesh.creation.icosphere(subdivisions=1).export(tmp_path / "ico.obj")
    text = SCENE.replace('shape = "sphere"\ncenter = [0.0, 0.0, 0.0]\nradius = 1.0', 'mesh = "ico.obj"')
    prep = prepare_scene(parse_scene(text, tmp_path, "s.toml"))
    cache = tmp_path / "gt"
    keys = {bench.ground_truth(prep, 4, cache, progress=False).key}
    rest = prep.geometry.mesh.points.numpy().copy()
    for k, frame in enumerate(("squeezed", "stretched", "rolled")):
        if frame == "rolled":
            update_mesh(prep.geometry, 0, rest * np.array([1.0, 0.6, 1.0]))   # as squeezed: only the camera differs
            prep.camera = make_camera((0.0, 0.0, 4.0), (0.0, 0.0, 0.0), (1.0, 0.0, 0.0), 30.0, 24, 24)
        else:
            update_mesh(prep.geometry, 0, rest * np.array([1.0, 0.6 if frame == "squeezed" else 1.4, 1.0]))
        gt = bench.ground_truth(prep, 4, cache, progress=False)
        fresh = bench.ground_truth(prep, 4, tmp_path / f"cold-{frame}", progress=False)
        assert gt.key == fresh.key and gt.key not in keys and np.array_equal(gt.image, fresh.image), frame
        keys.add(gt.key)
