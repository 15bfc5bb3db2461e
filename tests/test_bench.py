"""warpbw bench: the equal-quality interpolation against a closed form, and a tiny end-to-end run."""
from __future__ import annotations

import json
import math

import pytest

from conftest import MIXED_SCENE
from warpbw import bench
from warpbw.cli import main as cli_main

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
    # reference: MSE = 8 / spp, time = 0.01 spp (exact power laws: log-log interpolation is exact)
    ref = [{"spp": s, "mse": 8.0 / s, "time_s": 0.01 * s} for s in (1, 2, 4, 8, 16, 32)]
    spp, t, ext = bench.equal_quality_time(ref, 8.0 / 11.0)
    assert math.isclose(spp, 11.0, rel_tol=1e-9) and math.isclose(t, 0.11, rel_tol=1e-9) and not ext
    spp, t, ext = bench.equal_quality_time(ref, 8.0 / 64.0)   # beyond the measured counts
    assert ext and math.isclose(spp, 64.0, rel_tol=1e-9)


def test_bench_cli_writes_json_and_plot(tmp_path):
    scene = tmp_path / "s.toml"
    scene.write_text(SCENE)
    out, png = tmp_path / "b.json", tmp_path / "b.png"
    rc = cli_main(["bench", str(scene), "--json", str(out), "--plot", str(png), "--spp", "1,4",
                   "--budgets", "1,4", "--nb", "1,4", "--gt-spp", "64", "--runs", "1", "--cache", str(tmp_path / "gt"),
                   "-q"])
    assert rc == 0 and png.stat().st_size > 0
    r = json.loads(out.read_text())
    for key in ("scene", "ground_truth_spp", "methods", "equal_quality_speedup", "bandwidth_time_fraction"):
        assert key in r
    assert [x["spp"] for x in r["methods"]["reference"]] == [1, 4]
    for rec in r["methods"]["adaptive"]:
        assert {"budget", "time_s", "psnr_db", "relmse", "bandwidth_time_s"} <= set(rec)
        assert rec["time_s"] > 0 and rec["bandwidth_time_s"] >= 0
    assert [x["n_b"] for x in r["nb_sweep"]] == [1, 4]
    assert list((tmp_path / "gt").glob("ground_truth-*.exr"))  # cached
    # nothing is overwritten without --force
    assert cli_main(["bench", str(scene), "--json", str(out), "--gt-spp", "64", "-q"]) == 2


def test_bench_of_planes_beside_a_sphere_measures_the_visible_sphere(tmp_path):
    """A sphere sunk into a floor: bench measures the sphere where the floor does not hide it.  The hidden
    pixels (the sphere-only render's coverage that the floor's distance clips, counted independently here)
    are left out of the covered pixels, the cached ground truth is black there and keyed by the whole scene,
    and the table says so."""
    import numpy as np

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
    chunks = sorted((tmp_path / "gt").glob(f"ground_truth-{scene.content_hash()[:16]}-*.exr"))
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
