"""examples/dynamic_geometry.py (002 Sec. 4.3, Fig. 18): a mesh deformed every frame, rendered adaptively.

Runs the example's ``main`` on a trimesh icosphere at 48x48 for two frames (no shared data needed); the
sampling and bandwidth caches are a temporary directory (``WARPBW_CACHE``), never ~/.cache.
"""
from __future__ import annotations

import importlib.util
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from warpbw.errors import WarpbwError

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "dynamic_geometry.py"


def _example():
    spec = importlib.util.spec_from_file_location("dynamic_geometry_example", EXAMPLE)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture()
def sphere_obj(tmp_path):
    p = tmp_path / "sphere.obj"
    trimesh.creation.icosphere(subdivisions=3, radius=0.8).export(p)
    return p


@pytest.mark.parametrize("host_normals", [False, True], ids=["device-normals", "host-normals"])
def test_two_frames_on_a_sphere(tmp_path, sphere_obj, monkeypatch, host_normals):
    monkeypatch.setenv("WARPBW_CACHE", str(tmp_path / "cache"))
    ex = _example()
    monkeypatch.setattr(ex, "DEFAULT_ENV", tmp_path / "no-probe.exr")    # the default absent: the procedural sky
    out = tmp_path / "out"
    argv = ["--mesh", str(sphere_obj), "--out", str(out), "--frames", "2", "--size", "48", "--budget", "4",
            "--material", "ggx"] + (["--host-normals"] if host_normals else [])
    result = ex.main(argv)
    rec = json.loads((out / "dynamic_geometry.json").read_text())
    assert rec["frames"] == json.loads(json.dumps(result["frames"]))
    assert len(rec["frames"]) == 2 and rec["triangles"] == 1280
    for r in rec["frames"]:
        for k, v in r.items():
            if k == "normals_curvature_s" and not host_normals:
                assert v is None      # on the device they are timed with the update
            else:
                assert isinstance(v, (int, float)) and math.isfinite(v), (k, v)
        assert 0.0 < r["shaded_fraction"] <= 1.0
        assert 0 < r["pixels_shaded"] <= r["pixels_covered"] <= 48 * 48
        assert r["samples"] > 0 and r["fps"] > 0
        assert r["total_s"] >= r["geometry_s"] + r["gbuffer_s"] + r["bandwidth_s"] + r["shading_s"] - 1e-9
    assert math.isfinite(rec["summary"]["mean_fps"]) and rec["summary"]["mean_fps"] > 0
    assert "bandwidth_pass" in rec["stages"]
    assert rec["normals_and_curvature"].startswith("host" if host_normals else "device")
    # the strip: two rows (frames, shaded masks) of two 48-pixel frames, STRIP_GAP apart
    from PIL import Image

    png = np.asarray(Image.open(out / "dynamic_geometry.png"))
    assert png.shape[:2] == (2 * 48 + ex.STRIP_GAP, 2 * 48 + ex.STRIP_GAP)
    # nothing is overwritten without --force
    with pytest.raises(WarpbwError, match="--force"):
        ex.main(argv)


def test_a_successful_run_exits_0(tmp_path, sphere_obj):
    """Run as a script: status 0 (not the result dict handed to sys.exit), nothing on stderr but one-line
    warnings (city.exr's negative texels are clamped, with a warning, when ../shared is present)."""
    env = dict(os.environ, WARPBW_CACHE=str(tmp_path / "cache"))
    r = subprocess.run([sys.executable, str(EXAMPLE), "--mesh", str(sphere_obj), "--out", str(tmp_path / "out"),
                        "--frames", "1", "--size", "8", "--budget", "1", "--material", "ggx"],
                       cwd=tmp_path, env=env, stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, (r.returncode, r.stderr)
    assert all(ln.startswith("dynamic_geometry: warning: ") for ln in r.stderr.splitlines()), r.stderr
    assert (tmp_path / "out" / "dynamic_geometry.json").is_file()


def test_deformation_moves_the_mesh_and_frame_zero_only_ripples():
    ex = _example()
    rest = np.asarray(trimesh.creation.icosphere(subdivisions=2, radius=1.0).vertices)
    v0 = ex.deform(rest, 0, np.zeros(2), (-1.0, 1.0))
    v3 = ex.deform(rest, 3, np.zeros(2), (-1.0, 1.0))
    assert np.array_equal(v0[:, 1], rest[:, 1])                 # heights are kept
    r_rest = np.hypot(rest[:, 0], rest[:, 2])
    # the ripple scales the distance to the vertical axis by at most 1 +- RIPPLE_AMPLITUDE (twist keeps it)
    for v in (v0, v3):
        ratio = np.hypot(v[:, 0], v[:, 2])[r_rest > 1e-6] / r_rest[r_rest > 1e-6]
        assert np.all(np.abs(ratio - 1.0) <= ex.RIPPLE_AMPLITUDE + 1e-12)
    assert np.abs(v3 - v0).max() > 0.01                        # frames differ
    # "frame zero only ripples": the twist swings as sin(2 pi frame / period), 0 at frame 0, so every vertex keeps
    # its azimuth about the axis there (the checks above hold for any twist, which keeps the distance to the axis);
    # at frame 3 the top and the bottom turn opposite ways (the twist grows with the height from the middle)
    off = r_rest > 1e-6
    turn = lambda v: np.angle((v[:, 0] + 1j * v[:, 2]) / (rest[:, 0] + 1j * rest[:, 2]))[off]  # noqa: E731
    np.testing.assert_allclose(turn(v0), 0.0, atol=1e-12)
    top, bottom = rest[off, 1] > 0.5, rest[off, 1] < -0.5
    assert np.all(np.sign(turn(v3)[top]) == -np.sign(turn(v3)[bottom][0])) and np.abs(turn(v3)).max() > 0.05


def test_absent_default_mesh_is_skipped_and_a_missing_mesh_is_an_error(tmp_path, capsys, monkeypatch):
    ex = _example()
    # the default (the shared bunny) absent: the example skips, saying why
    monkeypatch.setattr(ex, "DEFAULT_MESH", tmp_path / "ghost.obj")
    assert ex.main(["--out", str(tmp_path / "o")]) is None
    assert "ghost.obj not found; skipping" in capsys.readouterr().out
    # a --mesh the user named that does not exist: a usage error naming it
    with pytest.raises(SystemExit) as e:
        ex.main(["--mesh", str(tmp_path / "typo.obj"), "--out", str(tmp_path / "o")])
    assert e.value.code == 2 and "--mesh" in capsys.readouterr().err
    # so is a --env the user named that does not exist (not a silent fall-back to the procedural sky)
    with pytest.raises(SystemExit) as e:
        ex.main(["--env", str(tmp_path / "typo.exr"), "--out", str(tmp_path / "o")])
    assert e.value.code == 2 and "--env" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_dynamic_geometry_hands_budget_and_per_frame_seeds_and_reports_wall_fps(tmp_path, monkeypatch):
    """--budget reaches every frame's render_adaptive, frame f is rendered with --seed + f (the option's help),
    and each frame's fps is 1 / its wall time (the whole iteration, as the record's wall_s) with the summary's
    mean_fps 1 / the mean wall time, bandwidth_share the mean bandwidth time over the mean stage total, and
    mean_shaded_fraction the mean of the frames' shaded fractions: a figure computed from another time (the
    stage sum alone), a fixed seed or the default budget would break these identities."""
    import types

    import warpbw.pipeline

    monkeypatch.setenv("WARPBW_CACHE", str(tmp_path / "cache"))
    ex = _example()
    monkeypatch.setattr(ex, "DEFAULT_ENV", tmp_path / "no-probe.exr")
    mesh = tmp_path / "sphere.obj"
    trimesh.creation.icosphere(subdivisions=1, radius=0.8).export(mesh)
    calls = []

    def spy(prep, budget, *a, **kw):        # a frame with known stage times and shaded fraction
        calls.append((budget, kw.get("seed")))
        k = len(calls)
        ts = {"gbuffer": 0.001 * k, "bandwidth": 0.002 * k, "shading": 0.003, "upsampling": 0.001,
              "hierarchy": 0.0005, "frame": 0.0075 + 0.003 * k}
        n = prep.width * prep.height
        return types.SimpleNamespace(image=np.zeros((prep.height, prep.width, 3), np.float32),
                                     coverage=np.ones((prep.height, prep.width), bool),
                                     aovs={"shaded": np.ones((prep.height, prep.width), bool)},
                                     stats={"time_s": ts, "shaded_fraction": 0.1 * k, "pixels_shaded": k,
                                            "pixels_covered": n, "samples": 3 * k, "samples_per_covered_pixel": 3.0,
                                            "stages": ["gbuffer", "bandwidth_pass"]})

    monkeypatch.setattr(warpbw.pipeline, "render_adaptive", spy)
    ex.main(["--mesh", str(mesh), "--out", str(tmp_path / "o"), "--frames", "2", "--size", "8", "--budget", "3",
             "--seed", "40", "--material", "ggx"])
    assert calls == [(3.0, 40), (3.0, 40), (3.0, 41)]    # warm-up, then frames 0 and 1
    rec = json.loads((tmp_path / "o" / "dynamic_geometry.json").read_text())
    fr, s = rec["frames"], rec["summary"]
    for r in fr:
        assert r["fps"] == pytest.approx(1.0 / r["wall_s"], rel=1e-12)
    assert s["mean_fps"] == pytest.approx(len(fr) / sum(r["wall_s"] for r in fr), rel=1e-12)
    assert s["bandwidth_share"] == pytest.approx(sum(r["bandwidth_s"] for r in fr) / sum(r["total_s"] for r in fr),
                                                 rel=1e-12)
    assert [r["shaded_fraction"] for r in fr] == [0.2, pytest.approx(0.3)]     # frames 0, 1 (calls 2, 3)
    assert s["mean_shaded_fraction"] == pytest.approx(0.25, rel=1e-12)
    assert [r["bandwidth_s"] for r in fr] == [0.004, 0.006]
    assert rec["budget_spp"] == 3.0 and rec["seed"] == 40
