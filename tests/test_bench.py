"""warpbw bench: the equal-quality interpolation against a closed form, and a tiny end-to-end run."""
from __future__ import annotations

import json
import math

import pytest

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
