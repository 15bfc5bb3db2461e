"""examples/dynamic_geometry.py (002 Sec. 4.3, Fig. 18): a mesh deformed every frame, rendered adaptively.

Runs the example's ``main`` on a trimesh icosphere at 48x48 for two frames (no shared data needed); the
sampling and bandwidth caches are a temporary directory (``WARPBW_CACHE``), never ~/.cache.
"""
from __future__ import annotations

import importlib.util
import json
import math
import os
import re
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
        # the plot stacks PLOT_STAGES as the frame's whole time (stage times rounded to 1e-6 s)
        assert math.isclose(sum(r[k] for k in ex.PLOT_STAGES), r["total_s"], rel_tol=0, abs_tol=1e-5), r
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
    assert all(ln.startswith("dynamic_geometry.py: warning: ") for ln in r.stderr.splitlines()), r.stderr
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
    turn = lambda v: np.angle((v[off, 0] + 1j * v[off, 2]) / (rest[off, 0] + 1j * rest[off, 2]))  # noqa: E731
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
    how, calls = _run_with_known_frames(tmp_path, monkeypatch, ["--frames", "2", "--budget", "3", "--seed", "40"])
    assert how.startswith("returned {"), how
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


def _run_with_known_frames(tmp_path, monkeypatch, argv, mesh=None):
    """The example's main with a stand-in render_adaptive whose call k (the warm-up is call 1) takes stage times
    and a shaded fraction that grow with k; returns the main's outcome and the calls' (budget, seed).  ``mesh``: an
    OBJ's text (default: an icosphere)."""
    import types

    import warpbw.pipeline
    from conftest import outcome

    monkeypatch.setenv("WARPBW_CACHE", str(tmp_path / "cache"))
    ex = _example()
    monkeypatch.setattr(ex, "DEFAULT_ENV", tmp_path / "no-probe.exr")
    if mesh is None:
        mesh = tmp_path / "sphere.obj"
        trimesh.creation.icosphere(subdivisions=1, radius=0.8).export(mesh)
    else:
        (tmp_path / "mesh.obj").write_text(mesh)
        mesh = tmp_path / "mesh.obj"
    calls = []

    def spy(prep, budget, *a, **kw):        # a frame with known stage times and shaded fraction
        calls.append((budget, kw.get("seed")))
        k = len(calls)
        ts = {"gbuffer": 0.001 * k, "bandwidth": 0.002 * k, "shading": 0.003, "upsampling": 0.001,
              "hierarchy": 0.0005, "frame": 0.0055 + 0.003 * k}
        n = prep.width * prep.height
        return types.SimpleNamespace(image=np.zeros((prep.height, prep.width, 3), np.float32),
                                     coverage=np.ones((prep.height, prep.width), bool),
                                     aovs={"shaded": np.ones((prep.height, prep.width), bool)},
                                     stats={"time_s": ts, "shaded_fraction": 0.1 * k, "pixels_shaded": k,
                                            "pixels_covered": n, "samples": 3 * k, "samples_per_covered_pixel": 3.0,
                                            "stages": ["gbuffer", "bandwidth_pass"]})

    monkeypatch.setattr(warpbw.pipeline, "render_adaptive", spy)
    return outcome(ex.main, ["--mesh", str(mesh), "--out", str(tmp_path / "o"), "--size", "8", "--material", "ggx",
                             *argv]), calls


def test_dynamic_geometry_writes_a_plot_and_records_what_it_prints(tmp_path, monkeypatch, capsys):
    """DESIGN.md, measurement protocol: every benchmark writes a JSON record and a PNG plot.  The example wrote the
    record and Fig. 18's strip of frames, but no plot of what it measures; now dynamic_geometry_times.png (stage
    times, fps and shaded fraction per frame) is written beside them, the record names the threads, and every
    number of the printed table is the record's (stand-in frames: the bandwidth pass 2k ms and the shaded
    fraction 10k % on call k)."""
    from conftest import plot_png

    how, calls = _run_with_known_frames(tmp_path, monkeypatch, ["--frames", "3", "--threads", "2"])
    assert how.startswith("returned {"), how
    out = capsys.readouterr().out
    rec = json.loads((tmp_path / "o" / "dynamic_geometry.json").read_text())
    assert rec["device"] == "cpu" and rec["threads"] == 2 and rec["budget_spp"] == 8.0 and rec["size"] == [8, 8]
    rows = [ln.split() for ln in out.splitlines() if ln.split() and ln.split()[0].isdigit() and len(ln.split()) == 11]
    assert [int(r[0]) for r in rows] == [0, 1, 2], out
    keys = ("geometry_s", "update_refit_s", "gbuffer_s", "bandwidth_s", "shading_s", "upsampling_s", "total_s")
    for row, fr in zip(rows, rec["frames"]):
        assert row[1:8] == [f"{fr[k] * 1e3:.1f}" for k in keys]
        assert row[8] == f"{fr['fps']:.2f}" and row[9] == f"{fr['shaded_fraction']:.1%}"
        assert int(row[10]) == fr["samples"]
    assert [r[4] for r in rows] == ["4.0", "6.0", "8.0"] and [r[9] for r in rows] == ["20.0%", "30.0%", "40.0%"]
    mean = re.search(r"mean: ([\d.]+) ms per frame, ([\d.]+) fps; shaded fraction ([\d.]+)%", out)
    s = rec["summary"]
    assert mean.groups() == (f"{s['mean_total_s'] * 1e3:.1f}", f"{s['mean_fps']:.2f}",
                             f"{s['mean_shaded_fraction'] * 100:.1f}")
    png = tmp_path / "o" / "dynamic_geometry_times.png"
    plot_png(png)
    assert f"plot {png}" in out


def test_dynamic_geometry_names_the_strips_frames_in_frame_order(tmp_path, monkeypatch, capsys):
    """--frames 100: the strip shows MAX_STRIP_FRAMES = 10 evenly spaced frames, 0, 11, ..., 99 (99 / 9 = 11 apart,
    by hand), and the closing line names them in that order, as the strip shows them.  Session 74: the line listed a
    set's order, "frames 0, 33, 66, 99, 11, 44, ..."."""
    how, calls = _run_with_known_frames(tmp_path, monkeypatch, ["--frames", "100"])
    assert how.startswith("returned {") and len(calls) == 101, how
    said = re.search(r"dynamic_geometry\.png \(frames ([\d, ]+)\)", capsys.readouterr().out)
    assert said is not None
    assert said.group(1) == ", ".join(str(11 * i) for i in range(10)), said.group(1)


def test_dynamic_geometry_keeps_an_existing_plot_without_force(tmp_path, monkeypatch):
    """The new plot is one of the outputs --force guards: an existing one is refused before any frame."""
    (tmp_path / "o").mkdir()
    (tmp_path / "o" / "dynamic_geometry_times.png").write_text("kept\n")
    how, calls = _run_with_known_frames(tmp_path, monkeypatch, ["--frames", "3"])
    assert "dynamic_geometry_times.png: already exists" in how and calls == [], how
    assert (tmp_path / "o" / "dynamic_geometry_times.png").read_text() == "kept\n"
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["dynamic_geometry_times.png"]


@pytest.mark.parametrize("frames, warns", [(1, True), (2, True), (3, False)])
def test_dynamic_geometry_warns_of_fewer_frames_than_the_protocols_three(tmp_path, monkeypatch, capsys, frames,
                                                                        warns):
    """As warpbw bench warns of fewer than 3 --runs: fewer than 3 timed frames are rendered, with the warning."""
    how, calls = _run_with_known_frames(tmp_path, monkeypatch, ["--frames", str(frames)])
    assert how.startswith("returned {") and len(calls) == 1 + frames, how
    err = capsys.readouterr().err
    assert (f"dynamic_geometry.py: warning: --frames {frames}: the measurement protocol times the median of at least 3"
            in err) == warns, err


@pytest.mark.parametrize("host_normals", [False, True], ids=["device-normals", "host-normals"])
def test_a_texture_seam_deforms_as_one_surface(tmp_path, monkeypatch, host_normals):
    """A mesh with a texture seam (a lat-long sphere whose uv split the vertices at longitude 0 and the poles): every
    deformed frame gives the copies of a split vertex one normal and one curvature, the seamless surface's, whether
    the device derives them or --host-normals computes them with the seam map load_mesh made (each copy took its own
    side's faces: 5.9 degrees apart on the seam, 180 at the south pole).  Truth: the copies are one point of the
    surface, and the deformed sphere written without uv (no seam) gives their normal."""
    import warpbw.gbuffer
    from conftest import latlong_sphere_obj

    from warpbw.io.mesh import vertex_normals

    seen = []
    real = warpbw.gbuffer.update_mesh

    def spy(geo, k, v, *nh):
        real(geo, k, v, *nh)
        start, count = geo.mesh_vertex_ranges[k]
        seen.append((np.asarray(v, np.float64), geo.mesh_attr.normal.numpy()[start:start + count].copy(),
                     geo.mesh_attr.curvature.numpy()[start:start + count].copy(), geo.mesh_surface[k],
                     geo.mesh_attr.indices.numpy().reshape(-1, 3) - start, bool(nh)))

    monkeypatch.setattr(warpbw.gbuffer, "update_mesh", spy)
    how, calls = _run_with_known_frames(tmp_path, monkeypatch, ["--frames", "2"] + (["--host-normals"] * host_normals),
                                        mesh=latlong_sphere_obj(32, 16, 0.8))
    assert how.startswith("returned {") and len(seen) == 3, how
    for v, n, c, surface, faces, given in seen:
        assert given == host_normals and surface is not None
        copies = surface != np.arange(len(v))
        assert copies.sum() == 15 + 2 * 32
        np.testing.assert_array_equal(n[copies], n[surface[copies]])
        np.testing.assert_array_equal(c[copies], c[surface[copies]])
        # the seamless mesh: the faces with each seam's copies welded into one vertex
        welded = np.unique(surface, return_inverse=True)[1].reshape(-1)
        w = np.zeros((welded.max() + 1, 3))
        w[welded] = v
        truth = vertex_normals(w, welded[faces])[welded]
        off = np.degrees(np.arctan2(np.linalg.norm(np.cross(n, truth), axis=1), np.einsum("ij,ij->i", n, truth)))
        assert off.max() < 0.01, f"normals off the seamless surface's by up to {off.max():.2f} degrees"


def _largest_ndc(cam, centre, points, width, height, fov_deg):
    """The largest |x| or |y| of ``points`` (N, 3) in normalised image coordinates (1 at the image's edge) of a
    pinhole at ``cam.origin`` looking at ``centre`` with +Y up and ``fov_deg`` across the width, by numpy here."""
    eye = np.array([cam.origin[0], cam.origin[1], cam.origin[2]], np.float64)
    fwd = (centre - eye) / np.linalg.norm(centre - eye)
    right = np.cross(fwd, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    q = points - eye
    z = q @ fwd
    assert np.all(z > 0)
    tx = math.tan(math.radians(fov_deg) / 2)
    return max(np.abs(q @ right / z).max() / tx, np.abs(q @ up / z).max() / (tx * height / width))


@pytest.mark.parametrize("shape", ["cube", "flat box", "tall box", "icosphere"])
def test_the_camera_frames_every_pose_within_its_margin(shape):
    """The camera, set once from the rest pose, frames the deformed mesh: every vertex of every pose within
    1 / FRAMING_MARGIN of the image's half size ("half extent of the deformed mesh to the half field of view").  Its
    distance took the larger half extent along x and z as the twist's reach, and half the depth extent for the near
    parts: a cube's rest pose reached 1.04 (out of the image), its twisted poses 1.23, a flat 2 x 0.3 x 2 box 1.18, and
    the bunny 0.919 (session 77).  Truth: the poses the example's deform gives over two twist periods, projected with
    numpy; and the frame is not far from full (the icosphere's poses reach at least 0.85)."""
    ex = _example()
    box = {"cube": (1.0, 1.0, 1.0), "flat box": (2.0, 0.3, 2.0), "tall box": (0.5, 3.0, 0.5)}
    m = (trimesh.creation.icosphere(subdivisions=3) if shape == "icosphere"
         else trimesh.creation.box(extents=box[shape]).subdivide().subdivide())
    rest = np.asarray(m.vertices, np.float64) + np.array([0.3, -0.2, 0.5])
    centre = 0.5 * (rest.min(0) + rest.max(0))
    y_range = (float(rest[:, 1].min()), float(rest[:, 1].max()))
    for width, height in ((256, 256), (256, 128), (96, 160)):
        cam = ex._camera(rest, width, height)
        reach = max(_largest_ndc(cam, centre, ex.deform(rest, f, centre[[0, 2]], y_range), width, height, ex.FOV_DEG)
                    for f in range(2 * ex.TWIST_PERIOD_FRAMES))
        assert reach <= 1.0 / ex.FRAMING_MARGIN + 1e-9, (shape, width, height, reach)
        if shape == "icosphere":
            assert reach > 0.85, (width, height, reach)


def test_a_frame_after_other_poses_is_the_frame_of_a_fresh_scene(tmp_path, monkeypatch):
    """"Nothing is precomputed from geometry": a frame rendered after frames of other poses (twice the size and moved,
    shrunk, squashed) is, bit for bit, the frame of the same pose on a scene prepared afresh (G-buffer, the bandwidth
    pass's level, b_p and sigma2, the samples, the image, the shaded fraction and its denominator).  And it is the
    frame of that pose loaded from a file as a static scene: the same hits, depths and levels, the normals as load_mesh
    derives them (given, as --host-normals gives them), the curvature and the image to float32 rounding; the device's
    normals and curvature, from the float32 positions, to theirs (session 77)."""
    from warpbw.gbuffer import update_mesh
    from warpbw.io.mesh import normals_and_curvature
    from warpbw.pipeline import prepare_scene, render_adaptive
    from warpbw.scene import parse_scene

    monkeypatch.setenv("WARPBW_CACHE", str(tmp_path / "cache"))
    ex = _example()
    ico = trimesh.creation.icosphere(subdivisions=3, radius=0.8)
    ico.export(tmp_path / "rest.obj")

    def scene(mesh):
        return parse_scene(ex.SCENE.format(fov=ex.FOV_DEG, w=32, h=32, env='procedural = "sky"', mesh=mesh,
                                           material=ex.GGX_MATERIAL), source="<test>")

    def prepared(mesh, rest):
        prep = prepare_scene(scene(mesh))
        prep.camera = ex._camera(rest, 32, 32)
        return prep

    def frame(prep, seed=7):
        r = render_adaptive(prep, 4.0, seed=seed)
        out = {k: r.gbuffer.numpy(k) for k in ("depth", "normal", "curvature", "material", "position")}
        out.update({k: r.aovs[k] for k in ("level", "b_p", "sigma2", "n_p", "shaded")})
        out.update(image=r.image, **{k: np.asarray(r.stats[k]) for k in ("shaded_fraction", "pixels_covered",
                                                                          "samples")})
        return out

    a = prepared(tmp_path / "rest.obj", np.asarray(ico.vertices, np.float32))   # the positions the device holds
    start, count = a.geometry.mesh_vertex_ranges[0]
    rest = a.geometry.mesh.points.numpy()[start:start + count].astype(np.float64)
    faces = a.geometry.mesh_attr.indices.numpy().reshape(-1, 3) - start
    axis, y_range = 0.5 * (rest.min(0) + rest.max(0))[[0, 2]], (rest[:, 1].min(), rest[:, 1].max())
    pose = ex.deform(rest, 5, axis, y_range)
    for v in (rest * 2.0 + 0.3, rest * 0.2, rest * np.array([1.0, 0.1, 1.0])):
        update_mesh(a.geometry, 0, v)
        frame(a, seed=3)
    update_mesh(a.geometry, 0, pose)
    got = frame(a)
    b = prepared(tmp_path / "rest.obj", rest)
    update_mesh(b.geometry, 0, pose)
    want = frame(b)
    assert got["pixels_covered"] > 300 and 0 < got["shaded_fraction"] < 1
    for k in want:
        np.testing.assert_array_equal(got[k], want[k], err_msg=k)
    # the pose as a static scene: its file, its normals and H as load_mesh derives them, given to update_mesh as
    # --host-normals gives them
    with open(tmp_path / "pose.obj", "w") as fh:
        fh.writelines("v %.17g %.17g %.17g\n" % tuple(p) for p in pose)
        fh.writelines("f %d %d %d\n" % tuple(t + 1) for t in faces)
    static = frame(prepared(tmp_path / "pose.obj", rest))
    update_mesh(b.geometry, 0, pose, *normals_and_curvature(pose, faces))
    host = frame(b)
    for k in ("depth", "position", "material", "normal", "level", "n_p", "shaded"):
        np.testing.assert_array_equal(host[k], static[k], err_msg=k)
    for k in ("curvature", "b_p", "image"):
        np.testing.assert_allclose(host[k], static[k], rtol=1e-5, atol=1e-7, err_msg=k)
    # the device's normals and H, from the float32 positions, to their rounding
    np.testing.assert_allclose(got["normal"], static["normal"], atol=1e-5)
    np.testing.assert_allclose(got["curvature"], static["curvature"], rtol=1e-4)


def test_dynamic_geometry_plot_stacks_each_frames_stages_to_its_total(tmp_path, monkeypatch, drawn_figures):
    """Read back (session 78): per frame the stage bars (ms) stack in ``PLOT_STAGES`` order, each from the top of the
    one below (their sum is total_s in a real frame: ``test_two_frames_on_a_sphere``); the fps line is the record's
    fps (its wall time's) and the lower panel its shaded fraction (stand-in frames whose stages grow with the
    call)."""
    how, _ = _run_with_known_frames(tmp_path, monkeypatch, ["--frames", "3"])
    assert how.startswith("returned {"), how
    rec = json.loads((tmp_path / "o" / "dynamic_geometry.json").read_text())
    (fig,) = drawn_figures
    top, bottom_ax, fps_ax = fig.axes
    ex = _example()
    assert [c.get_label() for c in top.containers] == [k[:-2] for k in ex.PLOT_STAGES]
    base = np.zeros(3)
    for k, bars in zip(ex.PLOT_STAGES, top.containers):
        assert [p.get_x() + p.get_width() / 2 for p in bars.patches] == [0, 1, 2]
        np.testing.assert_allclose([p.get_y() for p in bars.patches], base, rtol=1e-12, atol=1e-12)
        base = base + [fr[k] * 1e3 for fr in rec["frames"]]
        np.testing.assert_allclose([p.get_y() + p.get_height() for p in bars.patches], base, rtol=1e-12)
    (fps,) = fps_ax.get_lines()
    assert list(fps.get_ydata()) == [fr["fps"] for fr in rec["frames"]] and fps_ax.get_ylabel().startswith("frames")
    (shaded,) = bottom_ax.get_lines()
    assert list(shaded.get_ydata()) == [fr["shaded_fraction"] for fr in rec["frames"]]
    assert bottom_ax.get_ylabel() == "shaded fraction" and top.get_ylabel() == "stage time (ms)"
