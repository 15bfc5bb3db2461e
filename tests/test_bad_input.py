"""Bad input through the real command lines (``python -m warpbw.cli`` / ``python -m precompute``).

Every case must exit with status 2 and print exactly ONE line on stderr, ``warpbw: error: ...`` (or
``warpbw-precompute: error: ...``), naming the file or key and what was expected, with no traceback, and
must leave no output behind.  Runs in a fresh temporary directory with stdin closed; needs no shared data
(the bad files are made here).  Warp's native "could not find the CUDA driver" line is not filtered out:
``warpbw.native_output.init_warp_quietly`` keeps it off stderr, and these tests check that.
"""
from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from conftest import (attempt, capture_call, damage_deflate_stream, fake_npf_table, load_example, outcome,
                      plane_scene_toml, uniform_sampler_table)

from warpbw.errors import WarpbwError
from warpbw.io.exr import read_exr, write_exr
from warpbw.io.merl import MERL_FILE_SIZE
from warpbw.io.npf import NPF_FILE_SIZE

EXIT_USER_ERROR = 2


def run(args, cwd: Path, module: str = "warpbw.cli", timeout: float = 180.0,
        cache: str | None = None) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    env["WARPBW_CACHE"] = cache or str(cwd / "_cache")  # never ~/.cache
    env.pop("PYTHONWARNINGS", None)
    env.pop("PYTHONUNBUFFERED", None)   # stdout a block-buffered pipe, as a user's shell gives it
    return subprocess.run([sys.executable, "-m", module, *map(str, args)], cwd=cwd, env=env,
                          stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=timeout)


def assert_one_line_error(r: subprocess.CompletedProcess, *needles: str, prog: str = "warpbw") -> str:
    """Status 2, one non-empty stderr line '<prog>: error: ...' containing every needle, no traceback."""
    out = r.stdout + r.stderr
    assert "Traceback" not in out, out
    assert r.returncode == EXIT_USER_ERROR, f"status {r.returncode}\n{out}"
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, f"expected one line on stderr, got {len(lines)}:\n{r.stderr}"
    line = lines[0]
    assert line.startswith(f"{prog}: error: "), line
    for n in needles:
        assert n in line, f"{n!r} not in {line!r}"
    return line


def assert_no_outputs(d: Path, stem: str = "out"):
    left = [p.name for p in d.iterdir() if p.stem == stem]
    assert not left, f"outputs written despite the error: {left}"


SCENE = """\
[camera]
position = [0.0, 0.0, 3.0]
look_at = [0.0, 0.0, 0.0]
fov = 40.0
resolution = {resolution}

[environment]
{environment}

[[object]]
{object}
material = "m"

[material.m]
{material}
"""


def write_scene(d: Path, name: str = "scene.toml", resolution="[8, 8]", environment="constant = [1.0, 1.0, 1.0]",
                obj='shape = "sphere"\nradius = 1.0', material='type = "lambert"\nalbedo = 0.5') -> Path:
    p = d / name
    p.write_text(SCENE.format(resolution=resolution, environment=environment, object=obj, material=material))
    return p


def png_named_exr(path: Path) -> Path:
    from PIL import Image

    Image.fromarray(np.full((4, 8, 3), 200, np.uint8)).save(path, format="PNG")
    assert path.read_bytes()[:4] == b"\x89PNG"
    return path


# ------------------------------------------------------------------------------------------ files

def test_truncated_merl_in_a_scene(tmp_path):
    (tmp_path / "truncated.binary").write_bytes(np.array([90, 90, 180], "<i4").tobytes() + bytes(4096))
    write_scene(tmp_path, material='type = "merl"\nfile = "truncated.binary"')
    r = run(["render", "scene.toml", "-o", "out.exr", "--spp", "1"], tmp_path)
    assert_one_line_error(r, "truncated.binary", f"expected {MERL_FILE_SIZE} bytes", "got 4108")
    assert_no_outputs(tmp_path)


def test_merl_of_the_right_size_with_a_foreign_header(tmp_path):
    p = tmp_path / "foreign.binary"
    with open(p, "wb") as f:
        f.write(np.array([1, 2, 3], "<i4").tobytes())
        f.truncate(MERL_FILE_SIZE)
    write_scene(tmp_path, material='type = "merl"\nfile = "foreign.binary"')
    r = run(["render", "scene.toml", "-o", "out.exr", "--spp", "1"], tmp_path)
    assert_one_line_error(r, "foreign.binary", "header dims (1, 2, 3)", "expected (90, 90, 180)")
    assert_no_outputs(tmp_path)


def test_precompute_brdf_sampling_of_a_truncated_merl(tmp_path):
    (tmp_path / "truncated.binary").write_bytes(bytes(1000))
    r = run(["brdf-sampling", "truncated.binary", "-o", "x.npz"], tmp_path, module="precompute")
    assert_one_line_error(r, "truncated.binary", f"expected {MERL_FILE_SIZE} bytes", "got 1000",
                          prog="warpbw-precompute")
    assert not (tmp_path / "x.npz").exists()


def test_brdf_tables_beyond_float32_shading_are_refused(tmp_path):
    """A MERL file of finite float64 entries 1e300, and an NPF row of float32-finite 1e38: both overflowed in the
    float32 kernels, every sample was dropped and a black image written with status 0."""
    from warpbw.io.npf import NPF_COLS, NPF_MATERIAL_NAMES

    p = tmp_path / "huge.binary"
    with open(p, "wb") as f:
        f.write(np.array([90, 90, 180], "<i4").tobytes())
        np.full(MERL_FILE_SIZE // 8 - 1, 1e300, "<f8").tofile(f)
    assert p.stat().st_size == MERL_FILE_SIZE
    write_scene(tmp_path, material='type = "merl"\nfile = "huge.binary"')
    r = run(["render", "scene.toml", "-o", "out.exr", "--spp", "1"], tmp_path)
    assert_one_line_error(r, "huge.binary", "beyond 1e+20", "float32 shading would overflow")
    assert_no_outputs(tmp_path)
    npf = fake_npf_table(tmp_path / "npf.bin")
    row = NPF_MATERIAL_NAMES.index("chrome")
    with open(npf, "r+b") as f:
        f.seek(row * NPF_COLS * 3 * 4)
        np.full(NPF_COLS * 3, 1e38, "<f4").tofile(f)
    r = run(["npf-to-merl", "--table", "npf.bin", "--material", "chrome", "-o", "out.binary"], tmp_path,
            module="precompute")
    assert_one_line_error(r, "npf.bin", "(chrome) holds values up to 1e+38", "beyond 1e+20", prog="warpbw-precompute")
    assert not (tmp_path / "out.binary").exists()


def test_png_renamed_exr_as_environment(tmp_path):
    png_named_exr(tmp_path / "probe.exr")
    write_scene(tmp_path, environment='file = "probe.exr"')
    r = run(["render", "scene.toml", "-o", "out.exr", "--spp", "1"], tmp_path)
    assert_one_line_error(r, "probe.exr", "not an OpenEXR file", "PNG")
    assert_no_outputs(tmp_path)


@pytest.mark.parametrize("which", ["test", "reference"])
def test_png_renamed_exr_in_compare(tmp_path, which):
    png_named_exr(tmp_path / "fake.exr")
    write_exr(tmp_path / "good.exr", np.ones((4, 8, 3), np.float32))
    args = ["compare", "fake.exr", "good.exr"] if which == "test" else ["compare", "good.exr", "fake.exr"]
    r = run(args, tmp_path)
    assert_one_line_error(r, "fake.exr", "not an OpenEXR file", "PNG")
    assert r.stdout == ""


def test_compare_refuses_a_display_window_larger_than_any_frame_before_allocating_it(tmp_path):
    """compare places each image in its display window, allocated in full: a 2 x 2 image framed in 40000 x 3 pixels
    is refused by name before a pixel is read (a frame of 1e5 x 1e5 pixels would take 120 GB)."""
    import OpenEXR

    write_exr(tmp_path / "good.exr", np.ones((4, 8, 3), np.float32))
    OpenEXR.File({"dataWindow": (np.array([0, 0], np.int32), np.array([1, 1], np.int32)),
                  "displayWindow": (np.array([0, 0], np.int32), np.array([39999, 2], np.int32))},
                 {c: np.ones((2, 2), np.float32) for c in "RGB"}).write(str(tmp_path / "huge.exr"))
    r = run(["compare", "huge.exr", "good.exr"], tmp_path)
    assert_one_line_error(r, "huge.exr", "display window", "40000x3", "at most 16384 pixels per side")


def test_compare_missing_image(tmp_path):
    write_exr(tmp_path / "good.exr", np.ones((4, 8, 3), np.float32))
    r = run(["compare", "good.exr", "nothere.exr"], tmp_path)
    assert_one_line_error(r, "nothere.exr", "file not found")


def test_a_directory_given_as_an_input_file_is_called_one(tmp_path):
    """Not 'file not found' for a path that exists: the message says it is a directory."""
    write_exr(tmp_path / "good.exr", np.ones((4, 8, 3), np.float32))
    (tmp_path / "adir").mkdir()
    r = run(["compare", "good.exr", "adir"], tmp_path)
    assert_one_line_error(r, "adir: a directory, not a file", "expected an OpenEXR image")
    r = run(["gmm", "adir", "-o", "g.npz"], tmp_path, module="precompute")
    assert_one_line_error(r, "adir: a directory, not a file", "expected a height map", prog="warpbw-precompute")
    assert not (tmp_path / "g.npz").exists()


def test_compare_refuses_an_image_without_colour_channels_and_names_a_black_reference(tmp_path):
    """An R,G image was compared through its R channel as grey; a black reference printed 'PSNR -inf' (and
    --json a bare -Infinity)."""
    rgb = np.random.default_rng(0).random((4, 8, 3)).astype(np.float32)
    write_exr(tmp_path / "good.exr", rgb)
    write_exr(tmp_path / "rg.exr", rgb[..., :2], channels=["R", "G"])
    r = run(["compare", "rg.exr", "good.exr"], tmp_path)
    assert_one_line_error(r, "rg.exr", "['R', 'G']", "expected R,G,B or Y")
    write_exr(tmp_path / "black.exr", np.zeros((4, 8, 3), np.float32))
    r = run(["compare", "good.exr", "black.exr"], tmp_path)
    assert r.returncode == 0 and "PSNR   undefined (the reference has no positive value" in r.stdout
    black = json.loads(run(["compare", "good.exr", "black.exr", "--json"], tmp_path).stdout)
    assert black["psnr_db"] is None and "no positive value" in black["psnr_note"]
    # identical images are null in strict JSON too: the note tells the two apart (only mse did)
    same = json.loads(run(["compare", "good.exr", "good.exr", "--json"], tmp_path).stdout)
    assert same["psnr_db"] is None and same["psnr_note"].startswith("identical") and same["mse"] == 0.0
    assert "psnr_note" not in json.loads(run(["compare", "black.exr", "good.exr", "--json"], tmp_path).stdout)


def test_compare_error_map_is_refused_before_it_could_replace_a_file(tmp_path):
    """--error-map: a path not ending in .exr; an existing map (or its PNG) without --force; one of the images
    compared, whatever --force says; --error-range not LO < HI, or without a map.  Nothing is written or changed."""
    write_exr(tmp_path / "a.exr", np.ones((4, 8, 3), np.float32))
    write_exr(tmp_path / "b.exr", np.full((4, 8, 3), 0.5, np.float32))
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    r = run(["compare", "a.exr", "b.exr", "--error-map", "err.png"], tmp_path)
    assert_one_line_error(r, "--error-map err.png", "expected a path ending in .exr")
    for target in ("b.exr", "a.exr"):
        r = run(["compare", "a.exr", "b.exr", "--error-map", target, "--force"], tmp_path)
        assert_one_line_error(r, f"--error-map {target}", f"would overwrite {target}", "one of the images compared")
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
    (tmp_path / "err.png").write_bytes(b"mine")
    r = run(["compare", "a.exr", "b.exr", "--error-map", "err.exr"], tmp_path)
    assert_one_line_error(r, "err.png: already exists", "--force")
    assert r.stdout == "" and not (tmp_path / "err.exr").exists() and (tmp_path / "err.png").read_bytes() == b"mine"
    for rng, needle in (("2,1", "two numbers LO,HI with 0 < LO < HI"), ("1", "two numbers LO,HI"),
                        ("1,2,3", "two numbers LO,HI"), ("0,1", "comma-separated positive numbers")):
        r = run(["compare", "a.exr", "b.exr", "--error-map", "new.exr", "--error-range", rng], tmp_path)
        assert_one_line_error(r, "--error-range", needle)
    r = run(["compare", "a.exr", "b.exr", "--error-range", "1,2"], tmp_path)
    assert_one_line_error(r, "--error-range", "give --error-map PATH.exr too")
    assert not (tmp_path / "new.exr").exists() and not (tmp_path / "new.png").exists()
    r = run(["compare", "a.exr", "b.exr", "--error-map", "err.exr", "--force"], tmp_path)
    assert r.returncode == 0 and (tmp_path / "err.exr").exists() and (tmp_path / "err.png").read_bytes() != b"mine"


def test_compare_images_of_different_sizes(tmp_path):
    write_exr(tmp_path / "a.exr", np.ones((4, 8, 3), np.float32))
    write_exr(tmp_path / "b.exr", np.ones((5, 8, 3), np.float32))
    r = run(["compare", "a.exr", "b.exr"], tmp_path)
    assert_one_line_error(r, "a.exr is 8x4", "b.exr is 8x5", "same size")


def test_missing_mesh_file(tmp_path):
    write_scene(tmp_path, obj='mesh = "meshes/bunny.obj"')
    r = run(["render", "scene.toml", "-o", "out.exr", "--spp", "1"], tmp_path)
    assert_one_line_error(r, "scene.toml", "[[object]] #1.mesh", "file not found", str(tmp_path / "meshes"))
    assert_no_outputs(tmp_path)


@pytest.mark.parametrize("name", ["bunny.toml", "bunny", "bunny.obj.bak"])
def test_a_mesh_named_without_a_suffix_trimesh_reads_is_refused_by_the_scene(tmp_path, name):
    """trimesh picks its reader by the name's suffix: an OBJ saved as "bunny" or "bunny.obj.bak" passed the scene's
    checks and ``warpbw info``, and the render stopped after loading the probe with "malformed or unsupported mesh
    file (trimesh: file_type '...' not supported)", a good mesh called malformed.  The scene names the key."""
    (tmp_path / name).write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    write_scene(tmp_path, obj=f'mesh = "{name}"')
    for command in (["info", "scene.toml"], ["render", "scene.toml", "-o", "out.exr", "--spp", "1"]):
        assert_one_line_error(run(command, tmp_path), "scene.toml: [[object]] #1.mesh:", name,
                              "expected a name ending in .obj, .ply, .stl or .glb")
    assert_no_outputs(tmp_path)


def test_garbage_obj(tmp_path):
    (tmp_path / "garbage.obj").write_text("this is not a mesh\n@@@ ### !!!\nf foo bar baz\n")
    write_scene(tmp_path, obj='mesh = "garbage.obj"')
    r = run(["render", "scene.toml", "-o", "out.exr", "--spp", "1"], tmp_path)
    line = assert_one_line_error(r, "garbage.obj", "expected")
    assert "no triangles" in line or "malformed" in line, line
    assert_no_outputs(tmp_path)


def test_obj_face_referencing_a_missing_vertex(tmp_path):
    (tmp_path / "badface.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 9\n")
    write_scene(tmp_path, obj='mesh = "badface.obj"')
    r = run(["render", "scene.toml", "-o", "out.exr", "--spp", "1"], tmp_path)
    line = assert_one_line_error(r, "badface.obj:5: face index 9 is past the file's 3 vertices")
    assert "malformed" in line
    assert_no_outputs(tmp_path)


@pytest.mark.parametrize("vertex,scale", [("1e39", "1.0"), ("1e10", "1e30")], ids=["in the file", "scaled"])
def test_obj_vertex_beyond_float32(tmp_path, vertex, scale):
    (tmp_path / "big.obj").write_text(f"v 0 0 0\nv 1 0 0\nv 0 1 0\nv {vertex} 1 0\nf 1 2 3\nf 1 2 4\n")
    write_scene(tmp_path, obj=f'mesh = "big.obj"\nscale = {scale}')
    r = run(["render", "scene.toml", "-o", "out.exr", "--spp", "1"], tmp_path)
    assert_one_line_error(r, "big.obj", "1 vertices lie outside the float32 range")
    assert_no_outputs(tmp_path)


@pytest.mark.parametrize("vt", ["inf 0", "nan 0.5", "1e39 0"], ids=["inf", "nan", "beyond float32"])
def test_obj_texture_coordinates_that_are_not_finite_name_the_file(tmp_path, vt):
    """A ``vt`` line of inf, NaN or 1e39: two lines, numpy's "invalid value encountered in cast" (trimesh's merge
    rounds uv to integers) and "build_geometry: meshes[0] uv: expected finite values", naming no file (session
    77).  One line naming the mesh file now; a mesh with finite uv still renders."""
    (tmp_path / "uv.obj").write_text(f"v 0 0 0\nv 1 0 0\nv 0 1 0\nvt {vt}\nvt 0 0\nf 1/1 2/2 3/2\n")
    write_scene(tmp_path, obj='mesh = "uv.obj"')
    r = run(["render", "scene.toml", "-o", "out.exr", "--spp", "1"], tmp_path)
    assert_one_line_error(r, "uv.obj: 1 vertices have texture coordinates (uv) that are not finite or lie outside "
                          "the float32 range")
    assert_no_outputs(tmp_path)
    (tmp_path / "uv.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0.5 0\nvt 0 0\nf 1/1 2/2 3/2\n")
    r = run(["render", "scene.toml", "-o", "out.exr", "--spp", "1", "-q"], tmp_path)
    assert r.returncode == 0, r.stderr


def test_scene_file_with_a_byte_order_mark_reads(tmp_path):
    """Saved as UTF-8 with a BOM (as editors on Windows may): read as the same scene, not 'Invalid statement'."""
    p = write_scene(tmp_path)
    p.write_bytes(b"\xef\xbb\xbf" + p.read_bytes())
    r = run(["info", "scene.toml"], tmp_path)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr


def test_nb_budget_without_nb_is_refused(tmp_path):
    write_scene(tmp_path)
    r = run(["bench", "scene.toml", "--json", "b.json", "--nb-budget", "2"], tmp_path)
    assert_one_line_error(r, "--nb-budget", "only --nb asks for")
    assert_no_outputs(tmp_path, "b")


def test_cache_variable_naming_a_file_is_refused(tmp_path, monkeypatch):
    from precompute.brdf_sampling import cache_dir

    (tmp_path / "file").write_text("x")
    monkeypatch.setenv("WARPBW_CACHE", str(tmp_path / "file"))
    with pytest.raises(WarpbwError, match="WARPBW_CACHE=.*file: not a directory"):
        cache_dir()
    monkeypatch.setenv("WARPBW_CACHE", str(tmp_path / "new"))    # one that does not exist yet is made when needed
    assert cache_dir() == tmp_path / "new"


# ------------------------------------------------------------------------------------------ scene content

def test_unknown_material_type(tmp_path):
    write_scene(tmp_path, material='type = "phong"\nalbedo = 0.5')
    r = run(["render", "scene.toml", "-o", "out.exr"], tmp_path)
    assert_one_line_error(r, "scene.toml", "[material.m].type", "'phong'", "expected one of", "lambert")
    assert_no_outputs(tmp_path)


def test_negative_resolution(tmp_path):
    write_scene(tmp_path, resolution="[-64, 64]")
    r = run(["render", "scene.toml", "-o", "out.exr"], tmp_path)
    assert_one_line_error(r, "scene.toml", "[camera].resolution", "positive integers", "[-64, 64]")
    assert_no_outputs(tmp_path)


def test_scene_that_is_not_toml(tmp_path):
    (tmp_path / "scene.toml").write_text("[camera\nposition = = [0, 0]\n")
    r = run(["render", "scene.toml", "-o", "out.exr"], tmp_path)
    assert_one_line_error(r, "scene.toml", "not valid TOML", "line 1")
    r = run(["info", "scene.toml"], tmp_path)
    assert_one_line_error(r, "scene.toml", "not valid TOML")


def test_binary_scene_file(tmp_path):
    (tmp_path / "scene.toml").write_bytes(bytes(range(256)))
    r = run(["info", "scene.toml"], tmp_path)
    assert_one_line_error(r, "scene.toml", "UTF-8")


def test_a_scene_file_of_megabytes_is_refused_before_it_is_read(tmp_path):
    """``warpbw info big.toml`` read a 1 GB file whole (2 GB of memory, seconds) to call it not valid TOML
    (clifuzz F11): its size is checked first."""
    from warpbw.scene import SCENE_FILE_MAX_BYTES

    with open(tmp_path / "big.toml", "wb") as f:
        f.truncate(SCENE_FILE_MAX_BYTES + 1)   # sparse: no disk, and zeros are no TOML either way
    r = run(["info", "big.toml"], tmp_path)
    assert_one_line_error(r, "big.toml", f"{SCENE_FILE_MAX_BYTES + 1} bytes", "a scene file is a few kB")


_LONG = "L" * 300


@pytest.mark.parametrize("args, cache, needles", [
    (["demo", "-o", _LONG, "--spp", "1"], None, ["-o LLL", "a file name of 300 bytes"]),
    (["bench", "scene.toml", "--json", "r.json", "--spp", "1", "--budgets", "1", "--gt-spp", "16", "--cache", _LONG],
     None, ["--cache LLL", "a file name of 300 bytes"]),
    (["bench-filtering", "scene.toml", "--json", "r.json", "--zoom", "1", "--cache", _LONG], None,
     ["--cache LLL", "a file name of 300 bytes"]),
    (["render", "scene.toml", "-o", "out.exr", "--method", "adaptive", "--budget", "1"], _LONG,
     ["WARPBW_CACHE=", "/LLL", "a file name of 300 bytes"]),
    (["info", _LONG + ".toml"], None, [f"{_LONG}.toml: a file name of 305 bytes"]),
    (["render", "scene.toml", "-o", "/".join(["d" * 200] * 25) + "/out.exr", "--spp", "1"], None,
     ["-o dddd", "a path of 5032 bytes", "expected a shorter path"]),
], ids=["demo -o", "bench --cache", "bench-filtering --cache", "WARPBW_CACHE", "info scene", "render -o path"])
def test_names_too_long_are_refused_naming_the_option(tmp_path, args, cache, needles):
    """Each gave a bare "[Errno 36] File name too long: 'LLL...'" naming no option (clifuzz F3): Python 3.11's
    Path.exists raises on such a name, and a path of names that each fit can pass PATH_MAX."""
    write_scene(tmp_path, environment='procedural = "sky"',   # a probe with a bandwidth map to cache
                material='type = "ggx"\nalpha = 0.2\nspecular = [0.9, 0.8, 0.5]')
    r = run(args, tmp_path, cache=str(tmp_path / cache) if cache else None)
    line = assert_one_line_error(r, *needles)
    assert "Errno" not in line, line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.toml"]


def test_a_home_that_is_a_file_names_warps_kernel_cache(tmp_path, monkeypatch):
    """``HOME=hf`` (a file) failed in Warp's kernel-cache init with a bare "[Errno 20] Not a directory: 'hf/.cache'"
    naming neither the kernel cache nor HOME (clifuzz F4)."""
    (tmp_path / "hf").write_text("x")
    monkeypatch.setenv("HOME", "hf")
    monkeypatch.delenv("WARP_CACHE_PATH", raising=False)
    write_scene(tmp_path)
    r = run(["render", "scene.toml", "-o", "out.exr", "--spp", "1"], tmp_path)
    assert_one_line_error(r, "Warp's kernel cache hf/.cache/warp", "Not a directory at hf/.cache", "set HOME",
                          "WARP_CACHE_PATH")
    assert_no_outputs(tmp_path)


def test_a_kernel_cache_that_cannot_take_a_compiled_module_is_named(tmp_path):
    """Warp writes each module it compiles into its kernel cache (~/.cache/warp, or WARP_CACHE_PATH): on a full disk
    or quota the run ended with a bare "[Errno 28] No space left on device", naming neither a file nor the kernel
    cache (a write to an open file names none).  Truth: a real write refused by the system, here a file-size limit
    (``ulimit -f``: Python ignores SIGXFSZ, so the write fails with "File too large") and an empty kernel cache, so
    that the first module is compiled and written."""
    import resource

    write_scene(tmp_path)
    env = dict(os.environ, WARPBW_CACHE=str(tmp_path / "_cache"), WARP_CACHE_PATH=str(tmp_path / "kernels"))
    limit = 4096   # bytes: a module's C++ source is tens of kB

    def small_files():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    r = subprocess.run([sys.executable, "-m", "warpbw.cli", "render", "scene.toml", "-o", "out.exr", "--spp", "1"],
                       cwd=tmp_path, env=env, stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=180,
                       preexec_fn=small_files)
    assert_one_line_error(r, f"Warp's kernel cache {tmp_path / 'kernels'}", "cannot write a compiled module there",
                          "File too large", "WARP_CACHE_PATH")
    assert_no_outputs(tmp_path)
    # nor the build folder of the module it could not write (MODULE_pPID_tTHREAD, with its cut-off source)
    assert [p.name for p in (tmp_path / "kernels").glob("*/*_p*_t*")] == []


def test_missing_scene_file(tmp_path):
    r = run(["render", "nothere.toml", "-o", "out.exr"], tmp_path)
    assert_one_line_error(r, "nothere.toml", "scene file not found")
    r = run(["info", "nothere.toml"], tmp_path)
    assert_one_line_error(r, "nothere.toml", "scene file not found")


def test_unknown_npf_material_name(tmp_path):
    fake_npf_table(tmp_path / "npf.bin")
    write_scene(tmp_path, material='type = "npf"\ntable = "npf.bin"\nname = "chrom"')
    r = run(["render", "scene.toml", "-o", "out.exr", "--spp", "1"], tmp_path)
    # the scene and its key are named, not the table alone
    assert_one_line_error(r, "scene.toml: [material.m].name: ", "npf.bin", "unknown NPF material 'chrom'", "chrome")
    assert_no_outputs(tmp_path)


def test_unknown_npf_material_name_in_precompute(tmp_path):
    fake_npf_table(tmp_path / "npf.bin")
    r = run(["npf-to-merl", "--table", "npf.bin", "--material", "gold-metalic-paint", "-o", "out.binary"],
            tmp_path, module="precompute")
    assert_one_line_error(r, "npf.bin", "'gold-metalic-paint'", "gold-metallic-paint", prog="warpbw-precompute")
    assert not (tmp_path / "out.binary").exists()
    r = run(["brdf-sampling", "npf.bin", "--material", "nope", "-o", "x.npz"], tmp_path, module="precompute")
    # no close match: every valid name is listed
    assert_one_line_error(r, "npf.bin", "'nope'", "expected one of the 100 MERL material names: alum-bronze, ",
                          ", chrome, ", prog="warpbw-precompute")
    assert not (tmp_path / "x.npz").exists()


def test_precompute_names_pipes_npf_tables_and_materials_as_they_are(tmp_path):
    """A FIFO or a device given as the input read "file not found"; brdf / brdf-sampling on an NPF table without
    --material explained only how a scene reads one; npf-to-merl echoed --material as typed."""
    os.mkfifo(tmp_path / "pipe.exr")
    for args in (["gmm", "pipe.exr", "-o", "g.npz"], ["gmm", "/dev/zero", "-o", "g.npz"]):
        assert_one_line_error(run(args, tmp_path, module="precompute"), "not a regular file (a pipe, socket or device)",
                              prog="warpbw-precompute")
    fake_npf_table(tmp_path / "npf.bin")
    for cmd in ("brdf", "brdf-sampling"):
        assert_one_line_error(run([cmd, "npf.bin", "-o", "t.npz"], tmp_path, module="precompute"),
                              "npf.bin: the size of an NPF table: name one of its materials with --material NAME",
                              prog="warpbw-precompute")
    r = run(["npf-to-merl", "--table", "npf.bin", "--material", " Chrome ", "-o", "c.binary"], tmp_path,
            module="precompute")
    assert r.returncode == 0 and "(MERL .binary from npf.bin:chrome, " in r.stdout, r.stdout + r.stderr


def test_bench_filtering_zooms_that_put_the_camera_on_its_target_say_so(tmp_path):
    """--zoom 5e-324 read "make_camera: look_at: must differ from position", a key the user never gave; 1e-300
    (no pixel sees the plane) asked for smaller zooms."""
    (tmp_path / "planes.toml").write_text(PLANE_SCENE.replace('normal_map = "map.exr"\n', ""))
    for z in ("5e-324", "1e-300"):
        r = run(["bench-filtering", "planes.toml", "--zoom", z, "--gt-spp", "64", "--runs", "1", "--json", "b.json"],
                tmp_path)
        assert_one_line_error(r, "puts the camera on its look_at point", "expected a larger zoom")
    assert not (tmp_path / "b.json").exists()


def _npz_with_header(header: str) -> bytes:
    import io

    buf = io.BytesIO()
    np.savez(buf, __header__=np.array(header), marginal=np.zeros(3, np.float32))
    return buf.getvalue()


@pytest.mark.parametrize("content", [b"not a zip archive at all", b"", _npz_with_header("[1, 2]"),
                                     _npz_with_header('"a string"')],
                         ids=["garbage", "zero bytes", "header a JSON list", "header a JSON string"])
def test_sampling_file_that_is_not_an_asset(tmp_path, content):
    """Zero bytes (numpy's EOFError) and an .npz whose header is JSON but not an object (AttributeError on
    .get) were tracebacks."""
    fake_npf_table(tmp_path / "npf.bin")
    (tmp_path / "tables.npz").write_bytes(content)
    write_scene(tmp_path, material='type = "npf"\ntable = "npf.bin"\nname = "chrome"\nsampling = "tables.npz"')
    r = run(["render", "scene.toml", "-o", "out.exr", "--spp", "1"], tmp_path)
    # the rebuild command names the NPF material (without --material it fails on an NPF table)
    assert_one_line_error(r, "tables.npz", "not a warpbw asset file", "warpbw-precompute brdf-sampling",
                          "npf.bin --material chrome -o OUT")
    assert_no_outputs(tmp_path)


def _sampling_arrays(what: str) -> dict:
    a = dict(vars(uniform_sampler_table()))
    if what == "nan cdf":
        a["marginal"][3, 5] = np.nan
    elif what == "strings":
        a["marginal"] = np.array(["a", "b"])
    elif what == "scalar density":
        a["density"] = np.float32(1.0)
    elif what == "density zeroed":          # rendered 65,000x too bright
        a["density"][:] = 0.0
    elif what == "density doubled":
        a["density"] *= 2.0
    elif what == "marginal zeroed":         # rendered 40x too dark
        a["marginal"][:] = 0.0
    elif what == "conditional falling":
        a["conditional"][2, 3, 10] = 0.9
    return a


@pytest.mark.parametrize("what,needle", [("nan cdf", "negative or non-finite"), ("strings", "not numeric"),
                                         ("scalar density", "inconsistent table shapes"),
                                         ("density zeroed", "density is not the one the CDFs sample"),
                                         ("density doubled", "density is not the one the CDFs sample"),
                                         ("marginal zeroed", "marginal CDF does not rise from 0 to 1"),
                                         ("conditional falling", "conditional CDF does not rise from 0 to 1")])
def test_sampling_file_with_bad_arrays(tmp_path, what, needle):
    """A sampling-table asset of the right format, version and source whose arrays are unusable: NaN CDFs
    rendered a near-black image silently, string arrays and a 0-d density were tracebacks, and a density or CDFs
    that do not agree rendered too bright or too dark, silently."""
    from precompute.assetfile import write_asset
    from precompute.brdf_sampling import brdf_source
    from warpbw.sampling import TABLE_FORMAT, TABLE_VERSION

    src = brdf_source(fake_npf_table(tmp_path / "npf.bin"), "chrome")
    write_asset(tmp_path / "tables.npz", TABLE_FORMAT, TABLE_VERSION, src.name, src.digest, _sampling_arrays(what))
    write_scene(tmp_path, material='type = "npf"\ntable = "npf.bin"\nname = "chrome"\nsampling = "tables.npz"')
    r = run(["render", "scene.toml", "-o", "out.exr", "--spp", "1"], tmp_path)
    assert_one_line_error(r, "tables.npz", needle, "npf.bin --material chrome -o OUT")
    assert_no_outputs(tmp_path)


def test_sampling_file_of_an_older_version(tmp_path):
    """A version-1 sampling table (each view bin built at its centre alone, before session 35) is refused
    with the command that rebuilds it, not used as if it were current."""
    from precompute.assetfile import write_asset
    from precompute.brdf_sampling import brdf_source
    from warpbw.sampling import TABLE_FORMAT, TABLE_VERSION

    src = brdf_source(fake_npf_table(tmp_path / "npf.bin"), "chrome")
    write_asset(tmp_path / "tables.npz", TABLE_FORMAT, TABLE_VERSION - 1, src.name, src.digest,
                _sampling_arrays("ok"))
    write_scene(tmp_path, material='type = "npf"\ntable = "npf.bin"\nname = "chrome"\nsampling = "tables.npz"')
    r = run(["render", "scene.toml", "-o", "out.exr", "--spp", "1"], tmp_path)
    assert_one_line_error(r, "tables.npz", f"version {TABLE_VERSION - 1}", "npf.bin --material chrome -o OUT")
    assert_no_outputs(tmp_path)


@pytest.mark.parametrize("stored", [3, None, "2"], ids=["newer", "missing", "a string"])
def test_an_asset_of_a_newer_or_no_version_is_refused(tmp_path, stored):
    """A reader of version 2 takes version 2 only: a newer file may mean something else, and a file without a
    version (or with "2") is not one this code wrote."""
    import json

    from precompute.assetfile import HEADER_KEY, read_asset

    header = {"format": "fmt", "source": "s", "source_hash": "h"}
    if stored is not None:
        header["version"] = stored
    np.savez(tmp_path / "a.npz", **{HEADER_KEY: np.array(json.dumps(header)), "x": np.zeros(2)})
    with pytest.raises(WarpbwError, match=rf"a\.npz: fmt version {stored!r}, this warpbw reads version 2 \(rebuild"):
        read_asset(tmp_path / "a.npz", "fmt", 2, "warpbw-precompute x")
    header["version"] = 2
    np.savez(tmp_path / "a.npz", **{HEADER_KEY: np.array(json.dumps(header)), "x": np.zeros(2)})
    assert read_asset(tmp_path / "a.npz", "fmt", 2, "warpbw-precompute x").header["version"] == 2
    # the right version of another format is another file
    with pytest.raises(WarpbwError, match=r"a\.npz: is a 'fmt' file, expected 'other' \(rebuild"):
        read_asset(tmp_path / "a.npz", "other", 2, "warpbw-precompute x")


# ------------------------------------------------------------------------------------------ command line

def test_spp_zero(tmp_path):
    write_scene(tmp_path)
    r = run(["render", "scene.toml", "-o", "out.exr", "--spp", "0"], tmp_path)
    assert_one_line_error(r, "--spp", "positive integer", "got 0")
    r = run(["demo", "-o", "d", "--spp", "-3"], tmp_path)
    assert_one_line_error(r, "--spp", "positive integer")
    assert_no_outputs(tmp_path)
    assert not (tmp_path / "d").exists()


@pytest.mark.parametrize("args,needles", [
    (["render", "scene.toml"], ["-o/--output", "required"]),
    (["render", "scene.toml", "-o", "out.exr", "--threads", "x"], ["--threads", "'x'"]),
    (["render", "scene.toml", "-o", "out.png"], ["out.png", ".exr"]),
    (["frobnicate"], ["invalid choice", "frobnicate"]),
    ([], ["COMMAND"]),
    (["render", "scene.toml", "-o", "out.exr", "--method", "adaptive"], ["--method adaptive", "--budget"]),
    (["render", "scene.toml", "-o", "out.exr", "--method", "adaptive", "--budget", "-1"], ["--budget", "positive"]),
    (["render", "scene.toml", "-o", "out.exr", "--method", "adaptive", "--budget", "nan"], ["--budget", "positive"]),
    (["render", "scene.toml", "-o", "out.exr", "--method", "adaptive", "--budget", "2", "--nb", "0"], ["--nb"]),
    (["render", "scene.toml", "-o", "out.exr", "--budget", "2"], ["--budget", "adaptive only"]),
    (["render", "scene.toml", "-o", "out.exr", "--method", "fast"], ["--method", "invalid choice"]),
    (["render", "scene.toml", "-o", "out.exr", "--allocation", "variance"], ["--allocation", "adaptive only"]),
    (["render", "scene.toml", "-o", "out.exr", "--method", "adaptive", "--budget", "2", "--allocation", "magic"],
     ["--allocation", "invalid choice"]),
    (["render", "scene.toml", "-o", "out.exr", "--method", "adaptive", "--budget", "2", "--nyquist", "0"],
     ["--nyquist", "positive"]),
    (["render", "scene.toml", "-o", "out.exr", "--env-signal", "log"], ["--env-signal", "adaptive only"]),
    (["bench", "scene.toml", "--json", "b.json", "--env-signal", "linear"], ["--env-signal", "invalid choice"]),
    # the rate nyquist x b_p is float32: 1e40 became +inf and 0 x inf NaN, with numpy's warnings
    (["render", "scene.toml", "-o", "out.exr", "--method", "adaptive", "--budget", "2", "--nyquist", "1e40"],
     ["--nyquist", "<= 3.40282e+38", "float32", "got 1e40"]),
    # counts the kernels hold in int32: 2^31 would wrap to a negative count (a black image), 2^32 + 1 to one
    (["render", "scene.toml", "-o", "out.exr", "--spp", "2147483648"], ["--spp", "<= 2147483647", "int32"]),
    (["render", "scene.toml", "-o", "out.exr", "--spp", "4294967297"], ["--spp", "<= 2147483647"]),
    (["demo", "-o", "out", "--spp", "2147483648"], ["--spp", "<= 2147483647"]),
    (["render", "scene.toml", "-o", "out.exr", "--method", "adaptive", "--budget", "3e9"],
     ["--budget", "<= 8.38861e+06", "int32"]),
    # 2^31 - 1 directions were accepted and the pass's direction set ran the machine out of memory (killed)
    (["render", "scene.toml", "-o", "out.exr", "--method", "adaptive", "--budget", "2", "--nb", "65537"],
     ["--nb", "<= 65536", "002 Fig. 13"]),
    (["bench", "scene.toml", "--json", "b.json", "--nb", "16,2147483647"], ["--nb", "<= 65536"]),
    (["bench", "scene.toml", "--json", "b.json", "--spp", "1,2147483648"], ["--spp", "<= 2.14748e+09"]),
    (["bench", "scene.toml", "--json", "b.json", "--budgets", "1,1e9"], ["--budgets", "<= 8.38861e+06"]),
    # a value twice in a list would only repeat its measurement
    (["bench", "scene.toml", "--json", "b.json", "--spp", "1,4,1"], ["--spp", "distinct", "got 1 more than once"]),
    (["bench-filtering", "scene.toml", "--json", "b.json", "--zoom", "2,2.0"], ["--zoom", "got 2 more than once"]),
    (["bench", "scene.toml", "--json", "b.json", "--gt-spp", "2147483648"], ["--gt-spp", "<= 2147483647"]),
    (["bench", "scene.toml", "--json", "b.json", "--gt-spp", "3"], ["--gt-spp", "expected 2 or 4, got 3"]),
    (["bench", "scene.toml", "--json", "b.json", "--runs", "1001"], ["--runs", "<= 1000", "got 1001"]),
    (["bench-filtering", "scene.toml", "--json", "b.json", "--runs", "2147483648"], ["--runs", "<= 1000"]),
    (["render", "scene.toml", "-o", "out.exr", "--threads", str(4 * (os.cpu_count() or 1) + 1)],
     ["--threads", f"<= {4 * (os.cpu_count() or 1)}", "per CPU core"]),
    (["bench-filtering", "scene.toml", "--json", "b.json", "--spp", "2147483648"], ["--spp", "<= 2147483647"]),
    # seeds are uint32: -1 and 2^32 wrapped onto 2^32 - 1 and 0
    (["render", "scene.toml", "-o", "out.exr", "--seed", "-1"], ["--seed", "0 to 4294967295", "got -1"]),
    (["render", "scene.toml", "-o", "out.exr", "--seed", "4294967296"], ["--seed", "0 to 4294967295"]),
    (["bench", "scene.toml", "--json", "b.json", "--seed", "-1"], ["--seed", "0 to 4294967295"]),
    (["bench-filtering", "scene.toml", "--json", "b.json", "--seed", "4294967296"], ["--seed", "0 to 4294967295"]),
    # the preview's exposure: 1e10 overflowed 2^exposure after the EXR was written, nan gave a black PNG
    (["render", "scene.toml", "-o", "out.exr", "--exposure", "1e10"], ["--exposure", "-150 to 150", "'1e10'"]),
    (["render", "scene.toml", "-o", "out.exr", "--exposure", "nan"], ["--exposure", "finite", "'nan'"]),
    (["render", "scene.toml", "-o", "out.exr", "--exposure", "inf"], ["--exposure", "finite", "'inf'"]),
    (["demo", "-o", "out", "--exposure=-1e3"], ["--exposure", "-150 to 150"]),
    (["render", "scene.toml", "-o", "out.exr", "--method", "adaptive", "--budget", "2", "--spp", "7"],
     ["--spp", "--method reference only", "--budget"]),
    # probes along a footprint's major axis: 1 to MAX_ANISOTROPY (16), an integer; planes only
    (["render", "scene.toml", "-o", "out.exr", "--max-anisotropy", "0"], ["--max-anisotropy", "got 0"]),
    (["render", "scene.toml", "-o", "out.exr", "--max-anisotropy", "17"], ["--max-anisotropy", "<= 16", "got 17"]),
    (["render", "scene.toml", "-o", "out.exr", "--max-anisotropy", "2.5"], ["--max-anisotropy", "got '2.5'"]),
    (["render", "scene.toml", "-o", "out.exr", "--max-anisotropy", "abc"], ["--max-anisotropy", "got 'abc'"]),
    (["bench-filtering", "scene.toml", "--json", "b.json", "--max-anisotropy", "0"], ["--max-anisotropy", "got 0"]),
    (["bench-filtering", "scene.toml", "--json", "b.json", "--max-anisotropy", "17"],
     ["--max-anisotropy", "<= 16", "got 17"]),
    (["bench-filtering", "scene.toml", "--json", "b.json", "--max-anisotropy", "2.5"],
     ["--max-anisotropy", "got '2.5'"]),
    (["bench-filtering", "scene.toml", "--json", "b.json", "--max-anisotropy", "abc"],
     ["--max-anisotropy", "got 'abc'"]),
    (["render", "scene.toml", "-o", "out.exr", "--max-anisotropy", "4"],
     ["--max-anisotropy 4", "scenes with planes", "only"]),
], ids=["no output", "bad threads", "png output", "unknown command", "no command", "adaptive without budget",
        "negative budget", "nan budget", "zero nb", "budget without adaptive", "unknown method",
        "allocation without adaptive", "unknown allocation", "zero nyquist", "env-signal without adaptive",
        "unknown env-signal", "nyquist 1e40",
        "spp 2^31", "spp 2^32+1", "demo spp 2^31", "budget 3e9", "nb 65537", "bench nb 2^31-1", "bench spp 2^31",
        "bench budgets 1e9",
        "bench spp twice", "bench-filtering zoom twice", "bench gt-spp 2^31", "bench gt-spp 3", "bench runs 1001", "bench-filtering runs 2^31",
        "threads beyond 4 per core",
        "bench-filtering spp 2^31",
        "seed -1", "seed 2^32", "bench seed -1",
        "bench-filtering seed 2^32", "exposure 1e10", "exposure nan", "exposure inf", "demo exposure -1e3",
        "spp with adaptive", "max-anisotropy 0", "max-anisotropy 17", "max-anisotropy 2.5", "max-anisotropy abc",
        "bench-filtering max-anisotropy 0", "bench-filtering max-anisotropy 17",
        "bench-filtering max-anisotropy 2.5", "bench-filtering max-anisotropy abc", "max-anisotropy on a sphere"])
def test_usage_errors_are_one_line(tmp_path, args, needles):
    write_scene(tmp_path)
    assert_one_line_error(run(args, tmp_path), *needles)
    assert_no_outputs(tmp_path)
    assert_no_outputs(tmp_path, "b")


@pytest.mark.parametrize("args,needles", [
    (["brdf-sampling"], ["required"]),
    (["gmm", "surface:dunes:8", "-o", "out.npz", "--seed", "-1"], ["--seed", "0 to 4294967295", "got -1"]),
    (["gmm", "surface:dunes:8", "-o", "out.npz", "--seed", "4294967296"], ["--seed", "0 to 4294967295"]),
    # the builder's ranges, said by the parser whatever the value (argparse's "invalid int value: '2.5'" had none)
    (["gmm", "surface:dunes:8", "-o", "out.npz", "--components", "0"],
     ["--components", "expected an integer from 1 to 16, got 0"]),
    (["gmm", "surface:dunes:8", "-o", "out.npz", "--prior", "-1"], ["--prior", "expected a number from 0 to 1e+06"]),
    (["gmm", "surface:dunes:8", "-o", "out.npz", "--scale", "0"], ["--scale", "expected a finite number > 0, got 0"]),
    (["gmm", "surface:dunes:8", "-o", "out.npz", "--components", "2.5"],
     ["--components", "expected an integer from 1 to 16, got '2.5'"]),
    (["gmm", "surface:dunes:8", "-o", "out.npz", "--prior", "0x10"],
     ["--prior", "expected a number from 0 to 1e+06, got '0x10'"]),
    (["gmm", "surface:dunes:8", "-o", "out.npz", "--scale="], ["--scale", "expected a finite number > 0, got ''"]),
], ids=["no file", "gmm seed -1", "gmm seed 2^32", "gmm components 0", "gmm prior -1", "gmm scale 0",
        "gmm components 2.5", "gmm prior 0x10", "gmm scale empty"])
def test_precompute_usage_errors_are_one_line(tmp_path, args, needles):
    assert_one_line_error(run(args, tmp_path, module="precompute"), *needles, prog="warpbw-precompute")
    assert_no_outputs(tmp_path)


@pytest.mark.parametrize("module,args,option,values", [
    ("warpbw.cli", ["render", "scene.toml", "-o", "out.exr", "--output", "out2.exr"], "-o/--output",
     "(out.exr, then out2.exr)"),
    ("warpbw.cli", ["render", "scene.toml", "-o", "out.exr", "--spp", "2", "--spp=8"], "--spp", "(2, then 8)"),
    ("warpbw.cli", ["render", "scene.toml", "-o", "out.exr", "--method", "adaptive", "--method", "reference"],
     "--method", "(adaptive, then reference)"),
    ("warpbw.cli", ["bench", "scene.toml", "--json", "out.json", "--json", "out2.json", "--spp", "1",
                    "--budgets", "1", "--runs", "1"], "--json", "(out.json, then out2.json)"),
    ("warpbw.cli", ["compare", "a.exr", "b.exr", "--error-map", "out.exr", "--error-map", "out2.exr"],
     "--error-map", "(out.exr, then out2.exr)"),
    ("precompute", ["brdf", "npf.bin", "--material", "chrome", "-o", "out.npz", "-o", "out2.npz"], "-o/--output",
     "(out.npz, then out2.npz)"),
], ids=["render -o twice", "render --spp twice", "render --method twice", "bench --json twice",
        "compare --error-map twice", "precompute brdf -o twice"])
def test_an_option_given_twice_is_a_one_line_usage_error(tmp_path, module, args, option, values):
    """argparse kept the last of an option's values without a word (clifuzz F8: ``-o a1.exr -o a2.exr --spp 2 --spp 8``
    wrote a2.exr only, at 8 spp): the second is refused, naming the option and both values, before any work."""
    write_scene(tmp_path)
    for name in ("a.exr", "b.exr"):
        write_exr(tmp_path / name, np.full((4, 4, 3), 0.5, np.float32))
    fake_npf_table(tmp_path / "npf.bin")
    prog = "warpbw-precompute" if module == "precompute" else "warpbw"
    line = assert_one_line_error(run(args, tmp_path, module=module), f"{option} given twice {values}: give it once",
                                 prog=prog)
    assert f"{prog} {args[0]} --help" in line
    assert_no_outputs(tmp_path)
    assert_no_outputs(tmp_path, "out2")


def test_a_bounds_reason_is_its_own_options_not_another_bounds_of_the_same_value(monkeypatch):
    """The parsers' reasons for a bound were looked up by the bound's value, and --threads' (4 per core) varies with the
    machine: on 2 cores it is 8, so "--flicker-pairs 9" read "expected a positive integer <= 8 (4 per CPU core, 2
    here)" (on 4 cores --max-anisotropy 17 would have).  Only --threads gives that reason."""
    import argparse

    from warpbw import cli
    from warpbw.bench_filtering import FLICKER_PAIRS_MAX

    for name, hi, said in (("flicker-pairs", FLICKER_PAIRS_MAX, False), ("max-anisotropy", cli.MAX_ANISOTROPY, False),
                           ("threads", FLICKER_PAIRS_MAX, True)):
        monkeypatch.setattr(cli, "THREADS_MAX", hi)   # a machine of hi / 4 cores
        with pytest.raises(argparse.ArgumentTypeError) as refused:
            cli._positive_int(name, hi)(str(hi + 1))
        assert ("per CPU core" in str(refused.value)) == said, (name, str(refused.value))


def test_options_given_once_and_a_flag_given_twice_are_usage_that_still_works(tmp_path):
    """A flag given twice means what it means once (``--force --force``); each store option given once runs."""
    write_scene(tmp_path)
    r = run(["render", "scene.toml", "-o", "out.exr", "--spp", "1", "--force", "--force", "-q", "-q"], tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    assert (tmp_path / "out.exr").exists()


@pytest.mark.parametrize("argv,missing", [
    ([], "COMMAND"),
    (["npf-to-merl", "--material", "chrome", "-o", "x.binary"], "--table"),
    (["npf-to-merl", "--table", "npf.bin", "-o", "x.binary"], "--material"),
    (["brdf-sampling", "npf.bin", "--material", "chrome"], "-o/--output"),
    (["brdf", "npf.bin", "--material", "chrome"], "-o/--output"),
], ids=["no command", "npf-to-merl no --table", "npf-to-merl no --material", "brdf-sampling no -o", "brdf no -o"])
def test_precompute_options_the_synopsis_always_gives_are_required(tmp_path, monkeypatch, capsys, argv, missing):
    """README's synopsis: ``warpbw-precompute npf-to-merl --table T --material NAME -o OUT``, ``brdf-sampling FILE -o
    OUT``, ``brdf FILE -o OUT``.  Leaving one out is a one-line usage error naming it (status 2), not a traceback (no
    command: 'Namespace' has no 'func'; no --table: Path(None)) nor a guessed value."""
    from precompute.__main__ import main

    monkeypatch.chdir(tmp_path)
    fake_npf_table(tmp_path / "npf.bin")
    got = outcome(main, argv)
    err = capsys.readouterr().err
    assert got == "exit 2", (got, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("warpbw-precompute: error: the following arguments are required:")
    assert missing in lines[0], lines[0]
    assert not (tmp_path / "x.binary").exists()


@pytest.mark.parametrize("command", ["brdf-sampling", "gmm", "npf-to-merl", "gmm folder"])
def test_a_precompute_output_that_appears_during_the_work_is_said_to_have_appeared(tmp_path, monkeypatch, capsys,
                                                                                    command):
    """Two ``warpbw-precompute brdf chrome.binary -o c.npz`` at once (processes audit, session 79): the one that
    finished second was refused with "c.npz: already exists (pass --force to overwrite it)", about a file that was
    not there when it started, and pointing to --force as if the user had named a file of theirs.  An output that
    appears while the command works (another run of it, the user) is refused as staged_outputs refuses it, saying
    it appeared, and the file that appeared is kept; so is a folder that appears there (mutation round 12)."""
    import precompute.brdf_sampling
    import precompute.gmm_mipmap
    import precompute.npf_to_merl
    from precompute.__main__ import main
    from warpbw.io.merl import MERL_SHAPE

    monkeypatch.chdir(tmp_path)
    fake_npf_table(tmp_path / "npf.bin")
    command, folder = command.split(" ")[0], command.endswith(" folder")
    out = {"brdf-sampling": "s.npz", "gmm": "g.npz", "npf-to-merl": "m.binary"}[command]

    def meanwhile(work):   # the other run finishes first, during this one's work
        def stand_in(*args, **kwargs):
            if folder:
                (tmp_path / out).mkdir()
            else:
                (tmp_path / out).write_text("the other run's")
            return work(*args, **kwargs)
        return stand_in

    monkeypatch.setattr(precompute.brdf_sampling, "build_brdf_sampling",
                        meanwhile(lambda *a, **k: uniform_sampler_table()))
    monkeypatch.setattr(precompute.gmm_mipmap, "build_gmm_mipmap", meanwhile(precompute.gmm_mipmap.build_gmm_mipmap))
    monkeypatch.setattr(precompute.npf_to_merl, "tabulate_merl", meanwhile(lambda *a, **k: np.full(MERL_SHAPE, 0.1)))
    argv = {"brdf-sampling": ["brdf-sampling", "npf.bin", "--material", "chrome"],
            "gmm": ["gmm", "surface:dunes:33"],
            "npf-to-merl": ["npf-to-merl", "--table", "npf.bin", "--material", "chrome"]}[command]
    got = outcome(main, [*argv, "-o", out, "-q"][: None if command != "npf-to-merl" else -1])
    err = capsys.readouterr().err.strip()
    assert got == "returned 2", (got, err)
    assert err == (f"warpbw-precompute: error: {out}: already exists: it appeared while this run worked (another run "
                   "writing it, or you), and is kept; nothing of this run was written (pass --force to overwrite it)")
    assert (tmp_path / out).is_dir() if folder else (tmp_path / out).read_text() == "the other run's"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["npf.bin", out])


def _written(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


def _asset_with_header(path: Path, header_text: str) -> Path:
    np.savez_compressed(path, __header__=np.array(header_text), nu_rho=np.zeros((2, 2), np.float32))
    return path


_NOT_AN_ASSET = "not a warpbw asset file, or a damaged one"
INFO_BAD_FILES = {   # name -> (make it in a folder, what its one line says after "PATH: ")
    "missing": (lambda d: d / "absent.npz", "file not found (expected an asset file of warpbw)"),
    "directory": (lambda d: (d / "folder.npz").mkdir() or d / "folder.npz",
                  "a directory, not a file (expected an asset file of warpbw)"),
    "empty": (lambda d: _written(d / "empty.npz", b""), _NOT_AN_ASSET),
    "npf table": (lambda d: fake_npf_table(d / "npf.bin"), _NOT_AN_ASSET),
    "truncated npz": (lambda d: _written(d / "cut.npz", (d / "good.npz").read_bytes()[:-100]), _NOT_AN_ASSET),
    "damaged array": (lambda d: damage_deflate_stream(_written(d / "torn.npz", (d / "good.npz").read_bytes()),
                                                      "nu_rho.npy"), _NOT_AN_ASSET),
    "header not JSON": (lambda d: _asset_with_header(d / "text.npz", "format: warpbw.brdf-bandwidth"), _NOT_AN_ASSET),
    "header a list": (lambda d: _asset_with_header(d / "list.npz", "[1, 2]"), _NOT_AN_ASSET),
    "header without format": (lambda d: _asset_with_header(d / "nofmt.npz", '{"version": 3}'),
                              f"{_NOT_AN_ASSET} (its header names no format"),
}


@pytest.mark.parametrize("case", list(INFO_BAD_FILES))
@pytest.mark.parametrize("as_json", [False, True], ids=["text", "json"])
def test_precompute_info_names_a_bad_file_and_still_shows_the_others(tmp_path, capsys, case, as_json):
    """``warpbw-precompute info good.npz BAD good.npz``: BAD (missing, a directory, no asset file, a damaged one) is
    named in one error line saying what was expected, the good files are shown all the same (--json: the list holds
    ``{"path", "error"}`` in BAD's place), and the command exits 2, without a traceback."""
    from precompute.__main__ import main
    from precompute.brdf_bandwidth import VERSION

    good = np.savez_compressed(tmp_path / "good.npz", __header__=np.array(json.dumps(
        {"format": "warpbw.brdf-bandwidth", "version": VERSION, "source": "m.binary", "source_hash": "h", "params": {},
         "writer": "warpbw test"})), nu_rho=np.full((16, 16, 16), 1.5, np.float32)) or tmp_path / "good.npz"
    make, said = INFO_BAD_FILES[case]
    bad = make(tmp_path)
    argv = ["info", *(["--json"] if as_json else []), str(good), str(bad), str(good)]
    got = outcome(main, argv)
    out, err = capsys.readouterr()
    assert got == "returned 2", (got, err)
    assert err.startswith(f"warpbw-precompute: error: {bad}: {said}") and err.count("\n") == 1, err
    if as_json:
        records = json.loads(out)
        assert [sorted(r) if "error" in r else r["path"] for r in records] == [
            str(good), ["error", "path"], str(good)], records
        assert records[1] == {"path": str(bad), "error": err.split("error: ", 1)[1].strip()}
        assert records[0]["arrays"][0]["max"] == 1.5
    else:
        assert out.count(f"{good}\n  format    warpbw.brdf-bandwidth version {VERSION}") == 2, out
        assert str(bad) not in out, out


def test_counts_beyond_int32_are_refused_by_the_library_too():
    """The bounds the CLI checks at parse time hold for the Python API as well (before any work)."""
    from warpbw import bandwidth, cli, filtering
    from warpbw.pipeline import render_reference
    from warpbw.scene import default_scene
    from precompute.gmm_mipmap import build_gmm_mipmap

    assert cli.BUDGET_MAX == bandwidth.BUDGET_MAX  # spelled in the CLI so that --help needs no Warp import
    assert cli.MAX_ANISOTROPY == filtering.MAX_ANISOTROPY  # likewise
    with pytest.raises(WarpbwError, match="spp: expected a positive integer <= 2147483647"):
        render_reference(default_scene(), spp=2**31)
    with pytest.raises(WarpbwError, match="seed: expected an integer from 0 to 4294967295"):
        build_gmm_mipmap(np.zeros((4, 4)), seed=2**32, progress=False)


@pytest.mark.parametrize("max_anisotropy", [0, 17, 2.5, True])
def test_max_anisotropy_out_of_range_is_refused_by_the_library(tmp_path, max_anisotropy):
    """``render_filtering``'s max_anisotropy, 1 to MAX_ANISOTROPY (16) probes, as the CLI's --max-anisotropy."""
    from warpbw.filtering import render_filtering
    from warpbw.scene import parse_scene

    scene = parse_scene(PLANE_SCENE.replace('normal_map = "map.exr"\n', ""), tmp_path, "planes.toml")
    for method in ("toksvig", "ground_truth"):   # the ground truth ignores it, but a bad value is still refused
        with pytest.raises(WarpbwError, match=r"^max_anisotropy .*: expected an integer"):
            render_filtering(scene, method, max_anisotropy=max_anisotropy)


def test_existing_output_is_not_overwritten(tmp_path):
    write_scene(tmp_path)
    out = tmp_path / "out.exr"
    out.write_bytes(b"precious bytes")
    old = time.time() - 3600
    os.utime(out, (old, old))
    before = out.stat().st_mtime_ns
    r = run(["render", "scene.toml", "-o", "out.exr", "--spp", "1"], tmp_path)
    assert_one_line_error(r, "out.exr", "already exists", "--force")
    assert out.read_bytes() == b"precious bytes"
    assert out.stat().st_mtime_ns == before
    assert not (tmp_path / "out.png").exists() and not (tmp_path / "out.json").exists()


def test_existing_preview_is_not_overwritten(tmp_path):
    # any of the three outputs (EXR, PNG preview, JSON stats) blocks the render
    write_scene(tmp_path)
    (tmp_path / "out.json").write_text("{}")
    r = run(["render", "scene.toml", "-o", "out.exr", "--spp", "1"], tmp_path)
    assert_one_line_error(r, "out.json", "already exists", "--force")
    assert (tmp_path / "out.json").read_text() == "{}"
    assert not (tmp_path / "out.exr").exists()


def test_existing_precompute_output_is_not_overwritten(tmp_path):
    fake_npf_table(tmp_path / "npf.bin")
    (tmp_path / "out.binary").write_bytes(b"keep")
    r = run(["npf-to-merl", "--table", "npf.bin", "--material", "chrome", "-o", "out.binary"], tmp_path,
            module="precompute")
    line = assert_one_line_error(r, "out.binary", "already exists", "--force", prog="warpbw-precompute")
    assert "force=True" not in line  # the Python API's keyword is no advice on the command line
    assert (tmp_path / "out.binary").read_bytes() == b"keep"


def test_device_cuda_without_a_gpu(tmp_path):
    import warp as wp

    wp.init()
    if wp.is_cuda_available():
        pytest.skip("this machine has a CUDA device: --device cuda is valid here")
    write_scene(tmp_path)
    r = run(["render", "scene.toml", "-o", "out.exr", "--device", "cuda", "--spp", "1"], tmp_path)
    assert_one_line_error(r, "--device cuda", "no CUDA device", "--device cpu")
    assert "Warp CUDA" not in r.stderr
    assert_no_outputs(tmp_path)
    r = run(["demo", "-o", "d", "--device", "cuda:1", "--spp", "1"], tmp_path)
    assert_one_line_error(r, "--device cuda:1")
    r = run(["demo", "-o", "d", "--device", "tpu", "--spp", "1"], tmp_path)
    assert_one_line_error(r, "--device tpu", "not available", "cpu")


# ------------------------------------------------------------------------------------------ recoverable input

def test_environment_with_non_finite_pixels_warns_in_one_line(tmp_path):
    env = np.full((8, 16, 3), 0.5, np.float32)
    env[1, 2, 0] = np.nan
    env[2, 3, :] = np.inf        # 3 channel values, one pixel
    env[4, 5, 1] = -np.inf
    env[6, 7, 2] = -0.25
    write_exr(tmp_path / "bad.exr", env)
    write_scene(tmp_path, environment='file = "bad.exr"', resolution="[6, 6]")
    r = run(["render", "scene.toml", "-o", "out.exr", "--spp", "2", "-q"], tmp_path)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, r.stderr
    # 6 channel values in 4 pixels: NaN, +inf x 3 and -inf are non-finite (5), -0.25 is negative (1)
    assert lines[0].startswith("warpbw: warning: envmap 'bad.exr': set 6 channel values to 0 in 4 pixels"), lines
    assert "(1 negative, 5 NaN or infinite)" in lines[0]
    from warpbw.io.exr import read_exr

    img = read_exr(tmp_path / "out.exr")
    assert img.channels == ["R", "G", "B", "A"] and np.all(np.isfinite(img.pixels))


_BRIGHT_LIGHT = ('[[light]]\ntype = "directional"\ndirection = [0.3, 0.8, 0.5]\nradiance = [3e38, 3e38, 3e38]\n'
                 '\n[[light]]')


@pytest.mark.parametrize("what", ["sphere", "plane"])
def test_radiance_that_overflows_float32_is_refused_not_written(tmp_path, what):
    """Radiance within the float32 range whose pixel overflows it (a sky of 3e38 on white Lambert, plus a light of
    3e38): the image was written with inf pixels (a white preview) and status 0.  Now one line naming the scene,
    nothing written.  (The sky alone renders: its samples are summed in float64 since session 61, where a float32
    sum of four overflowed.)"""
    if what == "sphere":
        write_scene(tmp_path, environment="constant = [3e38, 3e38, 3e38]")
        assert run(["render", "scene.toml", "-o", "sky.exr", "--spp", "4", "-q"], tmp_path).returncode == 0
        img = read_exr(tmp_path / "sky.exr").pixels
        np.testing.assert_allclose(img[img[..., 3] > 0][:, :3], 1.5e38, rtol=1e-6)   # albedo 0.5 x the sky
        for f in tmp_path.glob("sky.*"):
            f.unlink()
        light = '\n[[light]]\ntype = "directional"\ndirection = [0.0, 0.0, 1.0]\nradiance = [3e38, 3e38, 3e38]'
        write_scene(tmp_path, environment="constant = [3e38, 3e38, 3e38]" + light,
                    material='type = "lambert"\nalbedo = 1.0')
    else:
        text = PLANE_SCENE.replace('normal_map = "map.exr"\n', "").replace("[[light]]", _BRIGHT_LIGHT, 1)
        (tmp_path / "scene.toml").write_text(text.replace("[3.0, 3.0, 3.0]", "[3e38, 3e38, 3e38]"))
    spp = ["--spp", "4"] if what == "sphere" else []     # planes under lights alone take no samples
    r = run(["render", "scene.toml", "-o", "out.exr", *spp, "-q"], tmp_path)
    assert_one_line_error(r, "scene.toml", "pixels came out infinite or NaN", "float32", "nothing written")
    assert_no_outputs(tmp_path)


def test_environment_scale_that_overflows_float32_names_the_scale(tmp_path):
    """Finite texels that [environment] scale sends past float32: they were set to 0 with a warning about
    'NaN or infinite' texels (a damaged map, it said) and the render went on.  Now one line naming scale."""
    from warpbw.io.exr import write_exr

    write_exr(tmp_path / "big.exr", np.full((4, 8, 3), 1e30, np.float32))  # finite float32 texels
    write_scene(tmp_path, environment='file = "big.exr"\nscale = 1e10')  # (a constant's product is checked on parse)
    r = run(["render", "scene.toml", "-o", "out.exr", "--spp", "4", "-q"], tmp_path)
    assert_one_line_error(r, "scale = 1e+10", "float32", "smaller [environment] scale")
    assert_no_outputs(tmp_path)


# ------------------------------------------------------------------------------------------ normal maps (issue 4)

PLANE_SCENE = plane_scene_toml(roughness=0.1, resolution=(8, 8), radiance=(3.0, 3.0, 3.0), diffuse=None,
                               material_extra='normal_map = "map.exr"\n')


def _bad_map(tmp_path: Path, what: str) -> None:
    p = tmp_path / "map.exr"
    if what == "not an image":
        p.write_bytes(b"height field? no, just bytes\n" * 4)
    elif what == "rgb as height":
        write_exr(p, np.random.default_rng(0).random((4, 4, 3)).astype(np.float32), channels=["R", "G", "B"])
    elif what == "two data channels":
        write_exr(p, np.random.default_rng(0).random((4, 4, 2)).astype(np.float32), channels=["Z", "W"])
    elif what == "normals into the surface":
        n = np.zeros((4, 4, 3), np.float32)
        n[..., 2] = 1.0
        n[1, 3] = [0.0, 0.6, -0.8]
        write_exr(p, n, channels=["R", "G", "B"])
    else:
        h = np.zeros((4, 4, 1), np.float32)
        h[2, 1] = np.nan
        write_exr(p, h, channels=["Y"])
    kind = 'normal_map_kind = "normal"\n' if what == "normals into the surface" else ""
    (tmp_path / "scene.toml").write_text(PLANE_SCENE + kind)


@pytest.mark.parametrize("what,needle", [("not an image", "not an image"),
                                         ("rgb as height", "RGB image with differing channels"),
                                         ("two data channels", "channels Z, W: expected R, G, B"),
                                         ("normals into the surface", "pointing below the surface"),
                                         ("nan texels", "NaN")])
def test_bad_normal_map_in_a_plane_scene(tmp_path, what, needle):
    _bad_map(tmp_path, what)
    r = run(["render", "scene.toml", "-o", "out.exr", "--filter", "fixed"], tmp_path)
    assert_one_line_error(r, "scene.toml", "[material.m].normal_map", "map.exr", needle)
    assert_no_outputs(tmp_path)


def test_plane_scene_scaled_beyond_float32_is_refused_not_rendered_empty(tmp_path):
    """A plane scene scaled by 1e-200 once rendered an empty image, with a warning that blamed the camera: float32
    intersection cannot reach it.  Now one line names the plane and asks for a larger scene; nothing is written."""
    write_exr(tmp_path / "map.exr", np.zeros((4, 4, 1), np.float32), channels=["Y"])
    (tmp_path / "scene.toml").write_text(PLANE_SCENE.replace("position = [0.0, 1.5, 2.0]",
                                                             "position = [0.0, 1.5e-200, 2.0e-200]")
                                         .replace("size = 2.0", "size = 2.0e-200"))
    r = run(["render", "scene.toml", "-o", "out.exr", "--filter", "fixed"], tmp_path)
    assert_one_line_error(r, "scene.toml", "far corner of the plane", "float32", "expected a larger scene")
    assert_no_outputs(tmp_path)


def test_height_field_with_an_alpha_channel_is_read_from_its_data_channel(tmp_path):
    """A one-channel EXR height field (channel Z) saved with alpha: the heights are Z, never the alpha (OpenEXR
    lists A before Z)."""
    from precompute.gmm_mipmap import load_map

    h = np.random.default_rng(2).random((5, 6)).astype(np.float32)
    write_exr(tmp_path / "za.exr", np.stack([h, np.ones_like(h)], -1), channels=["Z", "A"])
    np.testing.assert_array_equal(load_map(tmp_path / "za.exr"), h)
    write_exr(tmp_path / "ya.exr", np.stack([h, np.ones_like(h)], -1), channels=["Y", "A"])
    np.testing.assert_array_equal(load_map(tmp_path / "ya.exr"), h)


def test_gmm_file_built_unaligned_is_refused_as_such(tmp_path):
    """A material's gmm file built with --unaligned: said so, not 'a GMM mipmap of another map'."""
    h = np.random.default_rng(1).random((8, 8, 1)).astype(np.float32) * 0.05
    write_exr(tmp_path / "map.exr", h, channels=["Y"])
    r = run(["gmm", "map.exr", "-o", "g.npz", "--unaligned", "-q"], tmp_path, module="precompute")
    assert r.returncode == 0, r.stderr
    (tmp_path / "scene.toml").write_text(PLANE_SCENE + 'gmm = "g.npz"\n')
    r = run(["render", "scene.toml", "-o", "out.exr", "--filter", "gmm_aligned"], tmp_path)
    assert_one_line_error(r, "scene.toml", "[material.m].gmm", "g.npz", "built with --unaligned",
                          "aligned GMM mipmap", "without --unaligned")
    assert_no_outputs(tmp_path)


def _damage_moments(level, what):
    if what == "nan level":
        level[0, 0, 0, 3] = np.nan
    elif what == "weights x1000":         # rendered 3400x too bright, silently
        level[..., 0] *= 1000.0
    elif what == "a negative weight":
        level[0, 0, 0, 0] = -0.5
    elif what == "E|n|^2 zeroed":        # a negative variance
        level[..., 3] = 0.0
    elif what == "E|n|^2 beyond the disk":
        level[..., 3] = 2.0 * level[..., 0]


GMM_DAMAGE = [("nan level", "NaN or infinite moments at level 1"), ("weights x1000", "weights sum to 1000"),
              ("a negative weight", "negative weights at level 1"),
              ("E|n|^2 zeroed", "negative variances\\) at level 1"),
              ("E|n|^2 beyond the disk", "beyond the unit disk of projected normals at level 1")]
GMM_HEADER_DAMAGE = [("prior", "one", "non-numeric levels or parameters"), ("prior", float("nan"), "prior nan"),
                     ("components", 7, "expected 7 components"), ("components", 0, "0 components"),
                     ("components", 2.5, "non-numeric levels or parameters"), ("scale", "abc", "non-numeric"),
                     ("scale", -1.0, "height scale -1.0"), ("kind", "bump", "map kind 'bump'")]


@pytest.mark.parametrize("what,needle", GMM_DAMAGE + [(f"{k} = {v!r}", n) for k, v, n in GMM_HEADER_DAMAGE]
                         + [("empty levels", "inconsistent shapes"),
                            ("float64 beyond float32", "NaN or infinite moments at level 1"),
                            ("integer level", "levels of type int64, expected floating-point numbers")])
def test_gmm_file_with_bad_contents(tmp_path, what, needle):
    """A GMM mipmap of the right format and version whose moments are no mixture (NaN, weights that do not sum to
    1, negative weights or variances: each rendered without a word) or whose header's parameters are not what it
    holds (a ValueError traceback, or a mipmap of 0 components read)."""
    import json

    from precompute.gmm_mipmap import build_gmm_mipmap, read_gmm_mipmap, write_gmm_mipmap

    path = tmp_path / "g.npz"
    heights = np.random.default_rng(3).random((8, 8)) * 0.3
    write_gmm_mipmap(path, build_gmm_mipmap(heights, components=2, progress=False), "map.exr", "hash")
    assert read_gmm_mipmap(path).components == 2   # the builder's own file passes every check
    z = dict(np.load(path))
    header = json.loads(str(z["__header__"]))
    damage = {k: v for k, v, _ in GMM_HEADER_DAMAGE if what == f"{k} = {v!r}"}
    header["params"].update(damage)
    if what == "empty levels":   # level_shapes' "map size 0x0" named no file
        z.update({k: np.zeros((0, 0, 2, 4), np.float32) for k in z if k.startswith("level_")})
    elif what == "float64 beyond float32":   # numpy's "overflow encountered in cast" came first, as a warning
        z["level_1"] = z["level_1"].astype(np.float64) * 1e300
    elif what == "integer level":   # moments truncated to integers passed every check (file audit, session 63)
        z["level_0"] = z["level_0"].astype(np.int64)   # and rendered another image, exit 0
    elif not damage:
        _damage_moments(z["level_1"], what)
    z["__header__"] = np.array(json.dumps(header))
    np.savez_compressed(path, **z)
    with pytest.raises(WarpbwError, match=needle) as ei, warnings.catch_warnings():
        warnings.simplefilter("error")   # the error alone, no warning before it
        read_gmm_mipmap(path)
    assert str(path) in str(ei.value) and "rebuild it with" in str(ei.value)
    # the command it prints takes none of the damaged header's values ("--prior nan", "--scale abc")
    hint = str(ei.value).split("rebuild it with: ")[1]
    assert not any(word in hint for word in ("nan", "abc", "bump", "-1.0", "2.5", "--components 0"))


@pytest.mark.parametrize("what,needle", GMM_DAMAGE)
def test_a_gmm_mipmap_its_reader_would_refuse_is_not_written(tmp_path, what, needle):
    from precompute.gmm_mipmap import build_gmm_mipmap, write_gmm_mipmap

    mip = build_gmm_mipmap(np.random.default_rng(3).random((8, 8)) * 0.3, components=2, progress=False)
    _damage_moments(mip.levels[1], what)
    with pytest.raises(WarpbwError, match=r"^write_gmm_mipmap: not a GMM mipmap \(.*" + needle):
        write_gmm_mipmap(tmp_path / "g.npz", mip, "map.exr", "hash")
    assert not list(tmp_path.iterdir())


def test_filter_on_a_scene_without_planes(tmp_path):
    write_scene(tmp_path)
    r = run(["render", "scene.toml", "-o", "out.exr", "--filter", "toksvig"], tmp_path)
    assert_one_line_error(r, "--filter toksvig", "planes")
    assert_no_outputs(tmp_path)


def test_plane_scene_with_an_environment_that_is_not_an_exr(tmp_path):
    (tmp_path / "map.exr").unlink(missing_ok=True)
    (tmp_path / "sky.exr").write_bytes(b"not an image at all\n")
    (tmp_path / "scene.toml").write_text(PLANE_SCENE.replace('normal_map = "map.exr"\n', "")
                                         .replace("[[light]]", '[environment]\nfile = "sky.exr"\n\n[[light]]'))
    r = run(["render", "scene.toml", "-o", "out.exr", "--filter", "gmm_aligned"], tmp_path)
    assert_one_line_error(r, "scene.toml", "[environment]", "sky.exr")
    assert_no_outputs(tmp_path)


_SPHERE_OBJECT = ('\n[[object]]\nshape = "sphere"\nradius = 0.5\nmaterial = "s"\n\n'
                  '[material.s]\ntype = "lambert"\nalbedo = 0.5\n')


def test_bench_of_planes_beside_a_sphere_lit_by_lights_alone_is_refused(tmp_path):
    """bench measures the spheres and meshes a plane scene leaves visible against an environment-lit reference:
    lit by directional lights alone, a one-line error naming the scene and what is missing, nothing written.
    (bench-filtering measures the planes of such a scene: test_bench_filtering.)"""
    (tmp_path / "scene.toml").write_text(PLANE_SCENE.replace('normal_map = "map.exr"\n', "") + _SPHERE_OBJECT)
    r = run(["bench", "scene.toml", "--json", "out.json", "--spp", "1", "--budgets", "1"], tmp_path)
    assert_one_line_error(r, "scene.toml", "[environment]: missing")
    assert_no_outputs(tmp_path)


def test_render_with_planes_needs_both_kinds_of_object(tmp_path):
    from warpbw.pipeline import render_with_planes
    from warpbw.scene import parse_scene

    planes = parse_scene(PLANE_SCENE.replace('normal_map = "map.exr"\n', ""), tmp_path, "p.toml")
    with pytest.raises(WarpbwError, match=r"p\.toml: .*planes only .*render_filtering"):
        render_with_planes(planes, "fixed", 4)
    both = parse_scene(PLANE_SCENE.replace('normal_map = "map.exr"\n', "") + _SPHERE_OBJECT, tmp_path, "b.toml")
    with pytest.raises(WarpbwError, match="method: expected 'reference' or 'adaptive', got 'fast'"):
        render_with_planes(both, "fixed", 4, method="fast")
    with pytest.raises(WarpbwError, match="needs an \\[environment\\]"):
        render_with_planes(both, "fixed", 4, method="adaptive", budget=2)
    # the adaptive method's options on a reference frame were taken without a word
    with pytest.raises(WarpbwError, match=r"^method 'reference': budget, upsample apply to method 'adaptive' only$"):
        render_with_planes(both, "fixed", 4, budget=2, upsample="paper")


def test_a_loaded_environment_for_a_scene_without_one_is_refused(tmp_path):
    from warpbw.envmap import constant_envmap
    from warpbw.filtering import prepare_filtering
    from warpbw.scene import parse_scene

    planes = parse_scene(PLANE_SCENE.replace('normal_map = "map.exr"\n', ""), tmp_path, "p.toml")
    with pytest.raises(WarpbwError, match=r"p\.toml: env: given a loaded environment, but the scene has no "
                                          r"\[environment\]"):
        prepare_filtering(planes, ("fixed",), env=constant_envmap((1.0, 1.0, 1.0)))


def test_planes_beside_a_sphere_check_the_planes_before_rendering_the_sphere(tmp_path, monkeypatch):
    """A bad filter argument or normal map of the planes is refused before the spheres and meshes render."""
    from warpbw import pipeline
    from warpbw.scene import parse_scene

    def no_render(*a, **k):
        raise AssertionError("the sphere was rendered before the planes' arguments were checked")
    monkeypatch.setattr(pipeline, "render_reference", no_render)
    both = parse_scene(PLANE_SCENE.replace('normal_map = "map.exr"\n', "") + _SPHERE_OBJECT, tmp_path, "b.toml")
    with pytest.raises(WarpbwError, match=r"spp \(ground-truth rays per pixel\)"):
        pipeline.render_with_planes(both, "ground_truth", 16)
    with pytest.raises(WarpbwError, match="filter method 'blur'"):
        pipeline.render_with_planes(both, "blur", 16)
    (tmp_path / "map.exr").write_bytes(b"not an image\n")
    bad_map = parse_scene(PLANE_SCENE + _SPHERE_OBJECT, tmp_path, "m.toml")
    with pytest.raises(WarpbwError, match=r"normal_map"):
        pipeline.render_with_planes(bad_map, "fixed", 4)


def test_clip_distance_of_the_wrong_shape_or_nan_is_refused():
    """render_reference's clip_distance (a per-pixel distance, as render_with_planes passes): one line naming it."""
    from warpbw.pipeline import render_reference
    from warpbw.scene import default_scene

    scene = default_scene()
    w, h = scene.camera.width, scene.camera.height
    with pytest.raises(WarpbwError, match=rf"^clip_distance: expected an \({h}, {w}\) array .* got shape \({h}, "
                                          rf"{w - 1}\)"):
        render_reference(scene, 1, clip_distance=np.ones((h, w - 1)))
    bad = np.full((h, w), np.inf)
    bad[0, 0] = np.nan
    with pytest.raises(WarpbwError, match="^clip_distance: expected positive distances"):
        render_reference(scene, 1, clip_distance=bad)
    with pytest.raises(WarpbwError, match="^clip_distance: expected positive distances"):
        render_reference(scene, 1, clip_distance=np.zeros((h, w)))


def test_plane_scene_through_the_environment_pipeline_is_refused(tmp_path):
    """The 002 pipeline (render_reference / render_adaptive) called directly on a plane scene lit by
    [[light]]s only: a clear error naming the scene, not a failure inside the environment loader."""
    from warpbw.pipeline import render_reference
    from warpbw.scene import parse_scene

    scene = parse_scene(PLANE_SCENE.replace('normal_map = "map.exr"\n', ""), tmp_path, "planes.toml")
    with pytest.raises(WarpbwError, match=r"planes\.toml: .*does not render planes"):
        render_reference(scene, spp=1)


def test_a_scene_built_in_code_without_any_light_is_refused_by_the_environment_pipeline():
    """A Scene built in Python (no parser) with neither an [environment] nor a [[light]]: a one-line error,
    not a black image."""
    from dataclasses import replace

    from warpbw.pipeline import render_reference
    from warpbw.scene import default_scene

    scene = replace(default_scene(), environment=None, lights=[])
    with pytest.raises(WarpbwError, match=r"^<default scene>: \[environment\]: missing \(the scene needs a light"):
        render_reference(scene, spp=1)


def test_bench_refuses_a_sphere_scene_lit_by_lights_alone(tmp_path):
    """Lights alone render exactly at any spp: ``warpbw bench`` has nothing to measure and says so."""
    (tmp_path / "scene.toml").write_text(PLANE_SCENE.replace('normal_map = "map.exr"\n', "").split("[[object]]")[0]
                                         + _SPHERE_OBJECT)
    r = run(["bench", "scene.toml", "--json", "b.json", "--spp", "1", "--budgets", "1"], tmp_path)
    assert_one_line_error(r, "scene.toml", "[environment]", "exactly")
    assert_no_outputs(tmp_path, "b")


@pytest.mark.parametrize("command, cache, outputs, needles", [
    ("bench", "r.json", ["--json", "r.json"], ["--cache r.json", "the same path as --json r.json"]),
    ("bench", "r.png", ["--json", "r.json"], ["--cache r.png", "the same path as --plot r.png"]),
    ("bench", "r.json/c", ["--json", "r.json"], ["--cache r.json/c", "lies under --json r.json"]),
    ("bench", "res", ["--json", "res/r.json"], ["--cache res", "holds --json res/r.json"]),
    ("bench-filtering", "r.json", ["--json", "r.json"], ["--cache r.json", "the same path as --json r.json"]),
], ids=["bench json", "bench derived plot", "bench under json", "bench holds json", "bench-filtering json"])
def test_bench_cache_that_is_an_output_is_refused_before_the_work(tmp_path, command, cache, outputs, needles):
    """``--cache r.json --json r.json`` rendered everything, made the folder r.json (left behind) and ended with
    "r.json: already exists: it appeared while this run worked" (clifuzz F2)."""
    if command == "bench":
        write_scene(tmp_path)
        extra = ["--spp", "1", "--budgets", "1", "--gt-spp", "16"]
    else:
        (tmp_path / "scene.toml").write_text(PLANE_SCENE.replace('normal_map = "map.exr"\n', ""))
        extra = ["--zoom", "1", "--gt-spp", "64"]
    r = run([command, "scene.toml", *outputs, "--cache", cache, "--runs", "1", "-q", "--force", *extra], tmp_path)
    assert_one_line_error(r, *needles)
    assert not (tmp_path / "r.json").exists() and not (tmp_path / "res").exists()


@pytest.mark.parametrize("command", ["render", "info"])
def test_the_success_summary_escapes_control_characters_in_paths(tmp_path, command):
    """A newline in ``-o`` made the summary's second line read ``warpbw: error: fake.exr  (8x8, 1 spp, ...)`` on
    stdout, and an ESC coloured the terminal (clifuzz F13): paths are printed as the error lines print them."""
    name = "a\nwarpbw: error: fake\x1b[31m"
    if command == "render":
        write_scene(tmp_path)
        r = run(["render", "scene.toml", "-o", name + ".exr", "--spp", "1"], tmp_path)
    else:
        write_scene(tmp_path, name=name + ".toml")
        r = run(["info", name + ".toml"], tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "\x1b" not in r.stdout and not any(ln.startswith("warpbw: error") for ln in r.stdout.splitlines())
    assert "a\\nwarpbw: error: fake\\x1b[31m" in r.stdout, r.stdout


def test_adaptive_render_refuses_a_sphere_scene_lit_by_lights_alone(tmp_path):
    """``--method adaptive`` adapts the environment's sampling; lights alone are exact: a one-line error."""
    (tmp_path / "scene.toml").write_text(PLANE_SCENE.replace('normal_map = "map.exr"\n', "").split("[[object]]")[0]
                                         + _SPHERE_OBJECT)
    r = run(["render", "scene.toml", "-o", "out.exr", "--method", "adaptive", "--budget", "2"], tmp_path)
    assert_one_line_error(r, "scene.toml", "[environment]", "exact", "reference")
    assert_no_outputs(tmp_path)


# ------------------------------------------------------------------------------------------ examples/

EXAMPLES_DIR = Path(__file__).resolve().parents[1] / "examples"


@pytest.mark.parametrize("argv,needle", [
    (["gmm_mipmap.py", "--size", "16", "--surface", "dunes", "--level", "99"], "--level 99: expected 0 to 3"),
    (["gmm_mipmap.py", "--size", "16", "--surface", "dunes", "--texel", "5", "0"],
     "--texel 5 0: expected ROW and COL from 0 to 0"),
    (["bench_scenes.py", "--only", "nonsense", "--run"], "--only nonsense: expected scene names"),
    (["filtering_scenes.py", "--size", "0"], "--size 0: expected an integer from 17 to 1024"),
    (["filtering_scenes.py", "--size", "16"], "--size 16: expected an integer from 17 to 1024"),
    (["filtering_scenes.py", "--prior", "-1"], "--prior -1: expected a finite c >= 0"),
    (["bunny_on_floor.py", "--out", "m", "--size", "16"], "--size 16: expected an integer from 17 to 1024"),
    (["bunny_on_floor.py", "--out", "m", "--size", "1025"], "--size 1025: expected an integer from 17 to 1024"),
    (["bunny_on_floor.py"], "the following arguments are required: --out"),
    (["gmm_precompute_time.py", "--size", "0"], "--size 0: expected an integer from 17 to 1024"),
    # the default surface, the scales, was refused by its generator, naming no option: "hemispherical_scales: size 8
    # gives 1 texels per scale spacing ... scales_across at most 3 (an argument from Python)"
    (["gmm_mipmap.py", "--size", "8"], "--size 8: expected an integer from 17 to 1024 for hemispherical_scales (more "
     "than 2 texels per scale spacing; the other surfaces take 2 to 1024)"),
    (["filtering_zoom.py", "missing.toml"], "missing.toml: scene file not found"),
    (["filtering_floor.py", "missing.toml"], "missing.toml: no such scene file"),
    (["filtering_floor.py", "--zoom", "0", "s.toml"], "--zoom '0': expected comma-separated positive numbers"),
    (["filtering_floor.py", "--max-anisotropy", "0", "s.toml"], "--max-anisotropy 0: expected an integer from 1 to 16"),
    (["gbuffer.py", "--mesh", "missing.obj"], "--mesh missing.obj: no such file"),
    (["dynamic_geometry.py", "--mesh", "missing.obj"], "--mesh missing.obj: no such file"),
    (["gbuffer.py", "--resolution", "0", "0"], "--resolution 0 0: expected a width and a height of at least 1"),
    (["gbuffer.py", "--device", "nope"], "--device nope: not available"),
    (["reference_estimator.py", "--resolution", "0", "12"], "--resolution 0 12: expected a width and a height"),
    (["reference_estimator.py", "--device", "nope"], "--device nope: not available"),
    (["reference_estimator.py", "--spp", "0"], "--spp: expected an integer >= 1, got 0"),
    (["reference_estimator.py", "--probe", "missing.exr"], "--probe missing.exr: no such file"),
    (["dynamic_geometry.py", "--env", "missing.exr"], "--env missing.exr: no such file"),
    (["dynamic_geometry.py", "--material", "nope"], "--material 'nope': expected 'ggx' or an NPF material"),
    (["dynamic_geometry.py", "--device", "nope", "--material", "ggx"], "--device nope: not available"),
    (["brdf_sampling.py", "--samples", "-5"], "--samples: expected an integer >= 1, got -5"),
    (["brdf_sampling.py", "--samples", "0"], "--samples: expected an integer >= 1, got 0"),
    (["gmm_mipmap.py", "-o", "gm.txt", "--size", "16"], "-o gm.txt: expected a path ending in .png"),
    (["filtering_zoom.py", "s.toml", "--zoom", "0"], "--zoom '0': expected comma-separated positive numbers"),
    (["filtering_zoom.py", "s.toml", "--zoom", "nan"], "--zoom 'nan': expected comma-separated positive numbers"),
    (["filtering_scenes.py", "--components", "0"], "--components 0: expected an integer from 1 to 16"),
    (["filtering_scenes.py", "--elevation", "0"], "--elevation 0: expected degrees strictly between 0 and 90"),
    (["filtering_scenes.py", "--elevation", "90"], "--elevation 90: expected degrees strictly between 0 and 90"),
    (["filtering_scenes.py", "--elevation", "nan"], "--elevation nan: expected degrees strictly between 0 and 90"),
    (["filtering_scenes.py", "--max-anisotropy", "0"], "--max-anisotropy 0: expected an integer from 1 to 16"),
    (["filtering_scenes.py", "--max-anisotropy", "2.5"], "--max-anisotropy 2.5: expected an integer from 1 to 16"),
    (["filtering_zoom.py", "s.toml", "--max-anisotropy", "17"], "--max-anisotropy 17: expected an integer from 1"),
    (["anisotropy_cost.py", "s.toml", "--size", "0x4"], "expected a positive --size"),
    (["anisotropy_cost.py", "s.toml", "--zoom", "a"], "--zoom 'a': expected WxH and comma-separated numbers"),
    (["bench_reference.py", "--material", "nope"], "--material nope: "),
    (["validate_bandwidth.py", "--out", "v", "--ref-noise", "0"], "--ref-noise 0: expected a positive share"),
    (["validate_bandwidth.py", "--out", "v", "--ref-noise", "nan"], "--ref-noise nan: expected a positive share"),
    # shares above 1 ran, meaning nothing (the doubling never ran, no window was left out)
    (["validate_bandwidth.py", "--out", "v", "--ref-noise", "1.5"], "--ref-noise 1.5: expected a positive share, at "
     "most 1"),
    (["validate_bandwidth.py", "--out", "v", "--max-noise", "2"], "--max-noise 2: expected a positive share, at "
     "most 1"),
    (["validate_bandwidth.py", "--out", "v", "--quick", "--stride", "100000"], "--stride 100000: expected at most "
     "--size"),
    (["validate_bandwidth.py", "--out", "v", "--ref-spp-max", "0"], "--ref-spp-max: expected a positive integer"),
    # values a script passes on to warpbw bench / bench-filtering are checked by their parsers up front
    (["bench_scenes.py", "--runs", "0"], "--runs 0: expected a positive integer"),
    # an empty value was left unchecked: --gt-spp '' ran at 8192 (an empty --nb means no sweep)
    (["bench_scenes.py", "--gt-spp", ""], "--gt-spp '': expected a positive integer"),
    (["bench_scenes.py", "--runs", ""], "--runs '': expected a positive integer"),
    (["bench_scenes.py", "--nb", "abc"], "--nb abc: expected comma-separated ints"),
    (["bench_scenes.py", "--env-signal", "lin"], "--env-signal lin: expected one of log, radiance"),
    (["mirror_smear.py", "--env-signal", "lin"], "--env-signal"),
    (["validate_bandwidth.py", "--out", "v", "--env-signal", "lin"], "--env-signal"),
    (["filtering_scenes.py", "--zoom", "0"], "--zoom 0: expected comma-separated positive numbers"),
    (["filtering_scenes.py", "--gt-spp", "1e40"], "--gt-spp 1e40: expected a positive integer"),
    # --spp counts environment samples; --run passed it to bench-filtering, which refuses it on the light-lit scenes
    (["filtering_scenes.py", "--spp", "64"], "--spp 64: counts the samples of an --environment"),
    (["bench_reference.py", "--spp", "abc"], "--spp abc: expected comma-separated ints"),
    (["bench_reference.py", "--runs", "0"], "--runs 0: expected a positive integer"),
    (["bench_reference.py", "--gt-spp", "100"], "--gt-spp 100: expected a multiple of 4096 of at least 8192"),
    (["bench_reference.py", "--resolution", "0", "5"], "--resolution 0 5: expected a width and a height"),
    (["bench_reference.py", "--check-only"], "--check-only: bench_out/bench_reference.json not found"),
    # --seed -1 was a traceback from inside the adaptive render; --threads 0 was taken as 1
    (["dynamic_geometry.py", "--seed", "-1"], "--seed: expected an integer from 0 to 4294967295"),
    (["dynamic_geometry.py", "--seed", "4294967295"], "--seed 4294967295: frame f uses seed + f"),
    (["dynamic_geometry.py", "--threads", "0"], "--threads 0: expected a positive integer"),
    # checked before Mitsuba is imported, so these run without it
    (["compare_mitsuba.py", "--scale", "nan"], "--scale nan: expected a finite positive radiance scale"),
    (["compare_mitsuba.py", "--seed", "4294967000"], "--seed 4294967000: expected at most 4294966295"),
    (["compare_mitsuba.py", "--probe", "missing.exr"], "--probe missing.exr: no such file"),
    # each of these named every limit at once until session 43
    (["compare_mitsuba.py", "--resolution", "-1"], "--resolution -1: expected at least 9 pixels"),
    # 8 was accepted and both renderers ran before "no pixel is covered by geometry" (the interior, coverage eroded
    # by 2 pixels, was empty); no case ran nothing and exited 0; a case given twice ran twice
    (["compare_mitsuba.py", "--resolution", "8"], "--resolution 8: expected at least 9 pixels"),
    (["compare_mitsuba.py", "--cases", ","], "--cases ',': expected distinct names among lambert, ggx0.1, ggx0.4"),
    (["compare_mitsuba.py", "--cases", "lambert,ggx0.1,lambert"], "--cases 'lambert,ggx0.1,lambert': expected "
     "distinct names"),
    (["compare_mitsuba.py", "--cases", "lambert,foo"], "--cases 'lambert,foo': expected distinct names among"),
    (["compare_mitsuba.py", "--spp", "0"], "--spp 0: expected a positive integer"),
    (["dynamic_geometry.py", "--frames", "0"], "--frames 0: expected a positive integer"),
    (["dynamic_geometry.py", "--size", "4"], "--size 4: expected 8 to 16384 pixels"),
    (["dynamic_geometry.py", "--budget", "nan"], "--budget nan: expected a positive number"),
])
def test_examples_refuse_bad_arguments_in_one_line(tmp_path, argv, needle):
    """The example scripts answer bad arguments the way the commands do: status 2, one stderr line
    '<script>: error: ...' naming the argument, no traceback (nor Warp's no-CUDA-driver line), and nothing
    written."""
    example_error(run_example(argv, tmp_path), argv[0], needle)
    assert list(tmp_path.iterdir()) == []


def test_gmm_precompute_time_keeps_an_existing_json_without_force(tmp_path):
    """The timing script overwrote its --json silently until session 43; it now refuses before any work."""
    (tmp_path / "t.json").write_text("kept\n")
    example_error(run_example(["gmm_precompute_time.py", "--size", "17", "--json", "t.json"], tmp_path),
                  "gmm_precompute_time.py", "t.json: already exists", "--force")
    assert (tmp_path / "t.json").read_text() == "kept\n"
    r = run_example(["gmm_precompute_time.py", "--size", "17", "--components", "1", "--json", "t.json", "--force"],
                    tmp_path)
    assert r.returncode == 0, r.stderr
    record = json.loads((tmp_path / "t.json").read_text())
    assert record["size"] == 17 and set(record["time_s"]) == {"dunes", "hemispherical_scales", "carved_disk"}


def _asset_variants(tmp_path: Path) -> dict:
    """Files examples/read_assets.py must refuse, by what its one line should say."""
    import zipfile

    from precompute.assetfile import write_asset
    from precompute.brdf_bandwidth import VERSION

    ok = write_asset(tmp_path / "ok.npz", "warpbw.brdf-bandwidth", VERSION, "m", "d0",
                     {"nu_rho": np.ones((16, 16, 16), np.float32)})
    (tmp_path / "folder.npz").mkdir()
    (tmp_path / "text.npz").write_text("not an archive\n")
    (tmp_path / "cut.npz").write_bytes(ok.read_bytes()[:200])
    write_asset(tmp_path / "old.npz", "warpbw.brdf-bandwidth", VERSION - 1, "m", "d0",
                {"nu_rho": np.ones((16, 16, 16))})
    write_asset(tmp_path / "other.npz", "someone-elses-format", 2, "m", "d0", {"x": np.ones(3)})
    write_asset(tmp_path / "lacks.npz", "warpbw.brdf-sampling", 2, "m", "d0", {"density": np.ones((2, 3, 4))})
    write_asset(tmp_path / "ints.npz", "warpbw.brdf-bandwidth", VERSION, "m", "d0",
                {"nu_rho": np.ones((16, 16, 16), int)})
    np.savez(tmp_path / "plain.npz", a=np.ones(3))
    with zipfile.ZipFile(tmp_path / "badjson.npz", "w") as z:
        with z.open("__header__.npy", "w") as f:
            np.lib.format.write_array(f, np.array("{not json"))
    with zipfile.ZipFile(ok) as src, zipfile.ZipFile(tmp_path / "huge.npz", "w") as z:
        z.writestr("__header__.npy", src.read("__header__.npy"))
        with z.open("nu_rho.npy", "w") as f:   # a damaged header: 2^40 floats declared, 64 bytes held
            np.lib.format.write_array_header_1_0(f, {"descr": "<f4", "fortran_order": False, "shape": (2 ** 40,)})
            f.write(bytes(64))
    return {"missing.npz": "no such file", "folder.npz": "a folder, not a file", "text.npz": "not a .npz archive",
            "cut.npz": "not a .npz archive", "old.npz": f"version {VERSION - 1}; this reader reads version {VERSION}",
            "other.npz": "not a warpbw asset of a known format", "lacks.npz": "arrays not as the format has them",
            "ints.npz": "expected floating-point arrays", "plain.npz": "not a warpbw asset (no __header__ member)",
            "badjson.npz": "__header__ member is not JSON", "huge.npz": "a damaged .npz archive"}


def test_read_assets_refuses_what_is_not_an_asset_in_one_line(tmp_path):
    """examples/read_assets.py reads with numpy alone, so it does its own refusing: each file that is no asset of a
    format it reads gets one line naming the file and what is wrong (numpy's and zipfile's own errors, a KeyError
    or a traceback otherwise)."""
    for name, said in _asset_variants(tmp_path).items():
        example_error(run_example(["read_assets.py", name], tmp_path), "read_assets.py", name, said)
    for argv, said in ((["--view-deg", "90"], "--view-deg: expected degrees from 0 to 89"),
                       (["--samples", "10"], "--samples: expected an integer >= 1000"),
                       (["--roughness", "0"], "--roughness: expected 0.02 to 1"),
                       (["--seed", "-1"], "--seed: expected an integer >= 0")):
        example_error(run_example(["read_assets.py", "ok.npz", *argv], tmp_path), "read_assets.py", said)


@pytest.mark.parametrize("script", sorted(p.name for p in EXAMPLES_DIR.glob("*.py")))
def test_every_example_refuses_an_unknown_option_in_one_line(tmp_path, script):
    """(Scripts with a required argument name that one first.)"""
    last = example_error(run_example([script, "--no-such-option"], tmp_path), script, f"(see '{script} --help')")
    assert "--no-such-option" in last or "required" in last, last


def run_example(argv, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(EXAMPLES_DIR / argv[0]), *argv[1:]], cwd=cwd,
                          stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=180)


def example_error(r: subprocess.CompletedProcess, script: str, *needles: str) -> str:
    assert "Traceback" not in r.stderr and "CUDA driver" not in r.stderr, r.stderr
    assert r.returncode == EXIT_USER_ERROR, (r.returncode, r.stderr)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, r.stderr        # argparse's usage block was printed above the error until session 38
    last = lines[0]
    # the script's file name, as argparse's own refusals give it (run_command's said NAME: until session 72)
    assert last.startswith(f"{Path(script).name}: error: "), last
    for n in needles:
        assert n in last, last
    return last


@pytest.mark.parametrize("argv,existing", [
    (["gbuffer.py", "--resolution", "8", "8"], "gbuffer_out/gbuffer.exr"),
    (["reference_estimator.py", "--resolution", "8", "8", "--spp", "1"], "ref_out/ref_mis.png"),
    (["filtering_scenes.py", "--size", "17"], "bench_filtering/dunes.exr"),
    (["gmm_mipmap.py", "--size", "16", "-o", "figs/g.png"], "figs/g.png"),
])
def test_examples_do_not_overwrite_without_force(tmp_path, argv, existing):
    """An output the user already has is refused up front, naming it and --force, and left as it was."""
    p = tmp_path / existing
    p.parent.mkdir()
    p.write_text("mine\n")
    example_error(run_example(argv, tmp_path), argv[0], existing, "--force")
    assert p.read_text() == "mine\n" and list(p.parent.iterdir()) == [p]


def test_filtering_zoom_and_brdf_sampling_do_not_overwrite_without_force(tmp_path, shared):
    """The two examples that need a scene or the NPF table refuse an existing output before any rendering."""
    (tmp_path / "planes.toml").write_text(PLANE_SCENE.replace('normal_map = "map.exr"\n', ""))
    mine = tmp_path / "zoom" / "lean.png"
    mine.parent.mkdir()
    mine.write_text("mine\n")
    r = run_example(["filtering_zoom.py", "planes.toml", "-o", "zoom", "--zoom", "1"], tmp_path)
    example_error(r, "filtering_zoom.py", "zoom/lean.png", "--force")
    assert mine.read_text() == "mine\n" and list(mine.parent.iterdir()) == [mine]
    table = shared("brdf/npf.bin")
    mine = tmp_path / "brdf" / "brdf_sampling_chrome.png"
    mine.parent.mkdir()
    mine.write_text("mine\n")
    r = run_example(["brdf_sampling.py", "--table", str(table), "--material", "chrome", "--out", "brdf",
                     "--samples", "1000"], tmp_path)
    example_error(r, "brdf_sampling.py", "brdf_sampling_chrome.png", "--force")
    assert mine.read_text() == "mine\n" and list(mine.parent.iterdir()) == [mine]


def test_bench_scripts_keep_an_earlier_run_and_a_scene_edited_by_hand(tmp_path, shared):
    """bench_reference.py refuses an earlier run's records before any work; bench_scenes.py rewrites its
    scenes as they were without --force, but refuses one edited by hand."""
    shared("brdf/npf.bin")
    mine = tmp_path / "bench_out" / "bench_reference.json"
    mine.parent.mkdir()
    mine.write_text("mine\n")
    example_error(run_example(["bench_reference.py"], tmp_path), "bench_reference.py", "bench_reference.json",
                  "--force")
    assert mine.read_text() == "mine\n" and list(mine.parent.iterdir()) == [mine]
    assert run_example(["bench_scenes.py", "--out", "s"], tmp_path).returncode == 0
    assert run_example(["bench_scenes.py", "--out", "s"], tmp_path).returncode == 0   # the same contents
    edited = tmp_path / "s" / "sphere_chrome_studio.toml"
    edited.write_text(edited.read_text() + "# mine\n")
    example_error(run_example(["bench_scenes.py", "--out", "s"], tmp_path), "bench_scenes.py",
                  "s/sphere_chrome_studio.toml", "--force")
    assert edited.read_text().endswith("# mine\n")


def test_filtering_scenes_rewrites_its_own_scenes_and_keeps_others_without_force(tmp_path):
    """filtering_scenes.py refused its own scenes and height fields, unchanged, without --force, so that writing the
    scenes and then benching them with --run (README's two commands, bench_scenes.py's flow) needed --force, which
    also replaces the results (session 76's audit).  The same contents are rewritten; a scene edited by hand, a height
    field of another --size and, with --run, an existing record are refused before anything is written."""
    from warpbw.io.exr import read_exr

    args = ["filtering_scenes.py", "--out", "fs", "--size", "17"]
    assert run_example(args, tmp_path).returncode == 0
    r = run_example(args, tmp_path)
    assert r.returncode == 0, r.stderr                                                   # the same contents
    scene, heights = tmp_path / "fs" / "dunes.toml", tmp_path / "fs" / "dunes.exr"
    scene.write_text(scene.read_text() + "# mine\n")
    example_error(run_example(args, tmp_path), "filtering_scenes.py", "fs/dunes.toml: already exists", "--force")
    assert scene.read_text().endswith("# mine\n")
    scene.write_text(scene.read_text().removesuffix("# mine\n"))
    example_error(run_example(["filtering_scenes.py", "--out", "fs", "--size", "19"], tmp_path), "filtering_scenes.py",
                  "fs/scales.exr: already exists", "as do 5 more outputs", "--force")   # scenes and height fields
    assert read_exr(heights).pixels.shape == (17, 17, 1)
    (tmp_path / "fs" / "dunes.json").write_text("mine\n")
    example_error(run_example(args + ["--run", "--zoom", "1", "--gt-spp", "64"], tmp_path), "filtering_scenes.py",
                  "fs/dunes.json: already exists", "--force")
    assert (tmp_path / "fs" / "dunes.json").read_text() == "mine\n"
    assert sorted(p.name for p in scene.parent.iterdir()) == sorted(
        [f"{n}{e}" for n in ("scales", "carved_disk", "dunes") for e in (".toml", ".exr")] + ["dunes.json"])


def test_bunny_on_floor_keeps_a_scene_or_height_field_of_other_contents_without_force(tmp_path, shared):
    """examples/bunny_on_floor.py rewrites its scene as it was without --force, but refuses a scene edited by hand or
    a height field of another --size, before anything is written (the height field stays the earlier one)."""
    from warpbw.io.exr import read_exr

    for rel in ("meshes/bunny.obj", "envmaps/forest.exr", "brdf/npf.bin"):
        shared(rel)
    assert run_example(["bunny_on_floor.py", "--out", "m", "--size", "19"], tmp_path).returncode == 0
    assert run_example(["bunny_on_floor.py", "--out", "m", "--size", "19"], tmp_path).returncode == 0   # the same
    scene, heights = tmp_path / "m" / "bunny_on_floor.toml", tmp_path / "m" / "dunes.exr"
    example_error(run_example(["bunny_on_floor.py", "--out", "m", "--size", "17"], tmp_path), "bunny_on_floor.py",
                  "m/dunes.exr: already exists", "--force")
    assert read_exr(heights).pixels.shape == (19, 19, 1)
    scene.write_text(scene.read_text() + "# mine\n")
    example_error(run_example(["bunny_on_floor.py", "--out", "m", "--size", "19"], tmp_path), "bunny_on_floor.py",
                  "m/bunny_on_floor.toml: already exists", "--force")
    example_error(run_example(["bunny_on_floor.py", "--out", "m", "--size", "17"], tmp_path), "bunny_on_floor.py",
                  "m/bunny_on_floor.toml: already exists", "as does 1 more output of this command", "--force")
    assert scene.read_text().endswith("# mine\n") and read_exr(heights).pixels.shape == (19, 19, 1)
    assert sorted(p.name for p in scene.parent.iterdir()) == ["bunny_on_floor.toml", "dunes.exr"]
    r = run_example(["bunny_on_floor.py", "--out", "m", "--size", "17", "--force"], tmp_path)
    assert r.returncode == 0, r.stderr
    assert "# mine" not in scene.read_text() and read_exr(heights).pixels.shape == (17, 17, 1)


def test_bunny_on_floor_without_the_shared_data_says_so_and_writes_nothing(tmp_path, monkeypatch):
    """The scene names the shared bunny, probe and NPF table by their absolute paths: without them, one line naming
    the missing file and where the folder is looked for, and no scene naming files that are not there."""
    (tmp_path / "data" / "meshes").mkdir(parents=True)
    (tmp_path / "data" / "meshes" / "bunny.obj").write_text("v 0 0 0\n")
    monkeypatch.setenv("WARPBW_SHARED_DATA", str(tmp_path / "data"))
    example_error(run_example(["bunny_on_floor.py", "--out", "m"], tmp_path), "bunny_on_floor.py",
                  f"{tmp_path / 'data' / 'envmaps' / 'forest.exr'}: not found", "WARPBW_SHARED_DATA")
    assert not (tmp_path / "m").exists()


def test_bench_scenes_without_the_shared_data_says_so_as_an_error_and_writes_nothing(tmp_path, monkeypatch):
    """bench_scenes.py printed "bench_scenes: DIR not found ...", without the "error:" every other refusal has, and
    without saying where the folder is looked for."""
    monkeypatch.setenv("WARPBW_SHARED_DATA", str(tmp_path / "nowhere"))
    example_error(run_example(["bench_scenes.py", "--out", "s"], tmp_path), "bench_scenes.py",
                  f"{tmp_path / 'nowhere'}: not found", "WARPBW_SHARED_DATA")
    assert not (tmp_path / "s").exists()


def test_filtering_zoom_on_a_scene_without_planes(tmp_path):
    """Not the filtering renderer's 'renders planes only' (there is no plane to keep): says there is none."""
    write_scene(tmp_path)
    r = run_example(["filtering_zoom.py", "scene.toml", "-o", "zoom"], tmp_path)
    example_error(r, "filtering_zoom.py", "scene.toml: no [[object]] is a plane")
    assert not (tmp_path / "zoom").exists()



# ------------------------------------------------------------------------------------------ empty images

@pytest.mark.parametrize("planes", [False, True], ids=["sphere", "plane"])
def test_camera_that_sees_nothing_warns_in_one_line(tmp_path, planes):
    """A camera looking away from every object renders (empty pixels are legal) but says so: status 0,
    one warning line, the image written with a zero A channel."""
    from warpbw.io.exr import read_exr

    if planes:
        text = PLANE_SCENE.replace('normal_map = "map.exr"\n', "").replace(
            "look_at = [0.0, 0.0, 0.0]", "look_at = [0.0, 3.0, 4.0]")
        (tmp_path / "scene.toml").write_text(text)
    else:
        write_scene(tmp_path, obj='shape = "sphere"\nradius = 1.0\ncenter = [0.0, 0.0, 50.0]')
    r = run(["render", "scene.toml", "-o", "out.exr"] + ([] if planes else ["--spp", "64"]), tmp_path)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    warnings_ = [ln for ln in r.stderr.splitlines() if ln.startswith("warpbw: warning: ")]
    assert len(warnings_) == 1 and "no pixel is covered by geometry" in warnings_[0], r.stderr
    assert not read_exr(tmp_path / "out.exr").pixels[..., 3].any()



@pytest.mark.parametrize("scene", ["constant zero", "scale zero", "all-NaN probe", "light from below", "albedo 0",
                                   "plane, light from below", "lit"])
def test_a_frame_whose_covered_pixels_are_all_black_warns_in_one_line(tmp_path, scene):
    """A scene whose light is zero where the surfaces are (a constant or scale of 0, a probe whose every texel was
    NaN and set to 0, a directional light from behind the surfaces) or whose material reflects nothing rendered an
    all-black image, status 0, without a word (scene fuzzing, session 63).  It still renders, and says so in one
    line (after the probe's own warning); a lit scene says nothing."""
    from warpbw.io.exr import read_exr

    below = ('[[light]]\ntype = "directional"\ndirection = [0.0, -1.0, 0.0]\nradiance = [2.0, 2.0, 2.0]\n')
    if scene == "all-NaN probe":
        write_exr(tmp_path / "nan.exr", np.full((8, 16, 3), np.nan, np.float32))
    if scene.startswith("plane"):
        (tmp_path / "scene.toml").write_text(plane_scene_toml(resolution=(8, 8), light_dir=(0.0, -1.0, 0.0)))
    else:
        env = {"constant zero": "constant = [0.0, 0.0, 0.0]", "scale zero": 'procedural = "sky"\nscale = 0.0',
               "all-NaN probe": 'file = "nan.exr"'}.get(scene, "constant = [1.0, 1.0, 1.0]")
        write_scene(tmp_path, environment=env, material='type = "lambert"\nalbedo = ' + (
            "0.0" if scene == "albedo 0" else "0.5"))
        if scene == "light from below":   # no environment: a plane-less sphere lit from below is half lit
            text = (tmp_path / "scene.toml").read_text().replace("[environment]\nconstant = [1.0, 1.0, 1.0]\n", "")
            (tmp_path / "scene.toml").write_text(text.replace("shape = \"sphere\"", "shape = \"sphere\"\ncenter = "
                                                              "[0.0, 0.0, 0.0]") + below)
    lights_alone = "light from below" in scene   # closed form, no samples: --spp is refused
    r = run(["render", "scene.toml", "-o", "out.exr"] + ([] if lights_alone else ["--spp", "4"]), tmp_path)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    said = [ln for ln in r.stderr.splitlines() if "every covered pixel is black" in ln]
    px = read_exr(tmp_path / "out.exr").pixels
    covered = px[..., 3] > 0
    assert covered.any()
    assert len(said) == int(not px[covered][:, :3].any()), r.stderr
    assert len(said) == (scene not in ("lit", "light from below")), (scene, r.stderr)
    if said:
        assert said[0].startswith("warpbw: warning: ") and "[environment] constant, scale" in said[0]


# ------------------------------------------------------------------------------------------ output paths

@pytest.mark.parametrize("module,args,needles", [
    ("precompute", ["gmm", "surface:dunes:8", "-o", "outdir", "--force"], ["-o outdir", "is a directory"]),
    ("precompute", ["brdf-sampling", "npf.bin", "--material", "chrome", "-o", "outdir", "--force"],
     ["-o outdir", "is a directory"]),
    ("precompute", ["brdf", "npf.bin", "--material", "chrome", "-o", "afile/x.npz"], ["afile is not a directory"]),
    ("precompute", ["npf-to-merl", "--table", "npf.bin", "--material", "chrome", "-o", "outdir", "--force"],
     ["-o outdir", "is a directory"]),
    ("warpbw.cli", ["demo", "-o", "afile", "--spp", "1"], ["-o afile", "not a directory"]),
    ("warpbw.cli", ["render", "scene.toml", "-o", "afile/x.exr", "--spp", "1"],
     ["-o afile/x.exr", "afile is not a directory"]),
    ("warpbw.cli", ["render", "scene.toml", "-o", "dir.exr", "--spp", "1", "--force"],
     ["-o dir.exr", "is a directory"]),
    ("warpbw.cli", ["bench", "scene.toml", "--json", "b.json", "--cache", "afile"],
     ["--cache afile", "not a directory"]),
    ("warpbw.cli", ["bench-filtering", "planes.toml", "--json", "b.json", "--cache", "afile"],
     ["--cache afile", "not a directory"]),
    ("warpbw.cli", ["bench", "scene.toml", "--json", "dir.json", "--force"], ["--json dir.json", "is a directory"]),
    # under a link to a folder that is not there (processes audit, session 79): the whole work, then "cannot write
    # (File exists)", the errno of the mkdir on the link
    ("warpbw.cli", ["render", "scene.toml", "-o", "gone/sub/x.exr", "--spp", "1"],
     ["-o gone/sub/x.exr: gone is a link to", "which does not exist"]),
    ("warpbw.cli", ["demo", "-o", "gone", "--spp", "1"], ["-o gone: a link to", "which does not exist"]),
    ("warpbw.cli", ["bench", "scene.toml", "--json", "gone/b.json"], ["--json gone/b.json: gone is a link to"]),
    ("warpbw.cli", ["bench", "scene.toml", "--json", "b.json", "--cache", "gone"], ["--cache gone: a link to"]),
    ("precompute", ["gmm", "surface:dunes:17", "-o", "gone/x.npz"], ["-o gone/x.npz: gone is a link to"]),
], ids=["gmm -o dir", "brdf-sampling -o dir", "brdf -o under a file", "npf-to-merl -o dir", "demo -o file",
        "render -o under a file", "render -o dir", "bench --cache file", "bench-filtering --cache file",
        "bench --json dir", "render -o under a dangling link", "demo -o dangling link",
        "bench --json under a dangling link", "bench --cache dangling link", "gmm -o under a dangling link"])
def test_unwritable_output_paths_are_refused_up_front(tmp_path, module, args, needles):
    """An -o that is a directory (even with --force), a path under a file or under a link to nothing, a --cache that
    is a file: one line naming the option before any work (these failed after the build with a raw errno, leaving
    OUT.tmp behind, or ignored the --cache), and nothing written."""
    (tmp_path / "gone").symlink_to(tmp_path / "never-made")
    write_scene(tmp_path)
    (tmp_path / "planes.toml").write_text(PLANE_SCENE.replace('normal_map = "map.exr"\n', ""))
    fake_npf_table(tmp_path / "npf.bin")
    for d in ("outdir", "dir.exr", "dir.json"):
        (tmp_path / d).mkdir()
    (tmp_path / "afile").write_text("keep")
    before = sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*"))
    r = run(args, tmp_path, module=module)
    assert_one_line_error(r, *needles, prog="warpbw-precompute" if module == "precompute" else "warpbw")
    assert sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*")) == before
    assert (tmp_path / "afile").read_text() == "keep"


def test_write_asset_refuses_a_directory_and_leaves_no_tmp(tmp_path):
    from precompute.assetfile import write_asset

    (tmp_path / "out.npz").mkdir()
    with pytest.raises(WarpbwError, match="out.npz: is a directory"):
        write_asset(tmp_path / "out.npz", "fmt", 1, "src", "hash", {"a": np.zeros(2)}, force=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.npz"]


# ------------------------------------------------------------------------------------------ bench-filtering

def test_bench_filtering_zoom_that_sees_no_plane_is_refused_up_front(tmp_path):
    """At zoom 1000 the plane is smaller than a pixel: every score was NaN (and bare NaN went into the JSON)."""
    (tmp_path / "planes.toml").write_text(PLANE_SCENE.replace('normal_map = "map.exr"\n', ""))
    r = run(["bench-filtering", "planes.toml", "--json", "b.json", "--zoom", "1,1000", "--gt-spp", "64",
             "--runs", "1", "-q"], tmp_path)
    assert_one_line_error(r, "--zoom 1000", "no pixel sees a plane", "smaller zooms")
    assert r.stdout == ""
    assert_no_outputs(tmp_path, "b")
    # so far that float32 cannot place the camera: the zoom is named, not the scene alone
    r = run(["bench-filtering", "planes.toml", "--json", "b.json", "--zoom", "1e6", "--gt-spp", "64", "--runs", "1",
             "-q"], tmp_path)
    assert_one_line_error(r, "--zoom 1e+06 (camera distance x 1e+06): planes.toml: the camera", "float32")
    assert_no_outputs(tmp_path, "b")


def test_bench_filtering_of_planes_a_sphere_hides_entirely_is_refused_up_front(tmp_path):
    """A sphere between the camera and the whole plane: not 'choose smaller zooms' (no zoom helps) but what hides
    the planes, before any work and with nothing written."""
    sphere = _SPHERE_OBJECT.replace("radius = 0.5", "radius = 2.0")
    (tmp_path / "planes.toml").write_text(PLANE_SCENE.replace('normal_map = "map.exr"\n', "") + sphere)
    r = run(["bench-filtering", "planes.toml", "--json", "b.json", "--zoom", "1", "--gt-spp", "64", "--runs", "1",
             "-q"], tmp_path)
    assert_one_line_error(r, "--zoom 1", "spheres or meshes hide every pixel of the planes", "move them")
    assert r.stdout == ""
    assert_no_outputs(tmp_path, "b")


def test_json_records_never_hold_nan():
    from warpbw.cli_common import json_text

    # tuples too: a record built from dataclasses (asdict keeps them) holds them
    text = json_text({"a": float("nan"), "b": [1.0, float("inf")], "c": {"d": -float("inf"), "e": 2},
                      "f": (1.0, float("nan")), "g": [(float("inf"), 2)]})

    def refuse(name):
        raise AssertionError(f"{name} in strict JSON")

    assert json.loads(text, parse_constant=refuse) == {"a": None, "b": [1.0, None], "c": {"d": None, "e": 2},
                                                       "f": [1.0, None], "g": [[None, 2]]}


def test_truncated_exr_is_called_truncated_or_corrupt(tmp_path):
    """OpenEXR's own message for a cut-off file ("file has 0 parts") is misleading, and its C library writes
    warnings of its own to the descriptors: those go into the one line, nothing else is printed."""
    write_exr(tmp_path / "good.exr", np.random.default_rng(0).random((64, 64, 3)).astype(np.float32))
    data = (tmp_path / "good.exr").read_bytes()
    (tmp_path / "cut.exr").write_bytes(data[: len(data) // 2])
    r = run(["compare", "good.exr", "cut.exr"], tmp_path)
    assert r.returncode == EXIT_USER_ERROR and "Traceback" not in r.stderr, r.stderr
    assert_one_line_error(r, "cut.exr", "unreadable OpenEXR file, truncated or corrupt")
    assert r.stdout == ""


def test_out_of_memory_in_warp_is_one_line(capsys):
    """Warp reports a failed allocation (CPU or GPU) as a RuntimeError: one line and status 2, not a traceback;
    any other RuntimeError is a bug and stays one."""
    from warpbw.cli_common import run_command

    def oom(args):
        raise RuntimeError("Failed to allocate 3221225472 bytes on device 'cpu'")

    assert run_command("warpbw", oom, None) == EXIT_USER_ERROR
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("warpbw: error: out of memory: Failed to allocate 3221225472 bytes")
    assert "[camera].resolution" in err[0]

    def bug(args):
        raise RuntimeError("something else")

    with pytest.raises(RuntimeError, match="something else"):
        run_command("warpbw", bug, None)


def test_out_of_memory_in_numpy_is_one_line(capsys):
    """A host allocation that fails (numpy's MemoryError) is one line and status 2, as Warp's is."""
    from warpbw.cli_common import run_command

    def oom(args):
        raise MemoryError("Unable to allocate 96.0 GiB for an array with shape (65536, 65536, 6)")

    assert outcome(run_command, "warpbw", oom, None) == f"returned {EXIT_USER_ERROR}"
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("warpbw: error: Unable to allocate 96.0 GiB"), err


# ------------------------------------------------------------------------------------------ session 43's audit


def test_outputs_never_replace_an_input_even_with_force(tmp_path):
    """--force once let a render replace its own light probe, and a precompute its own source, with status 0."""
    from warpbw.io.exr import write_exr

    probe = np.ones((4, 8, 3), np.float32)
    write_exr(tmp_path / "probe.exr", probe)
    before = (tmp_path / "probe.exr").read_bytes()
    write_scene(tmp_path, environment='file = "probe.exr"')
    r = run(["render", "scene.toml", "-o", "probe.exr", "--spp", "1", "--force"], tmp_path)
    assert_one_line_error(r, "-o probe.exr", "would overwrite", "probe.exr", "a file this command reads")
    assert "link" not in r.stderr   # the probe itself, named relatively: no link (it once said "a link to it")
    # an output beside the image (its preview, its stats) that is an input is named
    write_scene(tmp_path, environment='file = "probe.png"')
    (tmp_path / "probe.png").write_bytes(b"a probe the scene names")
    r = run(["render", "scene.toml", "-o", "probe.exr", "--spp", "1", "--force"], tmp_path)
    assert_one_line_error(r, "-o probe.exr (its output probe.png): would overwrite", "probe.png, a file this command")
    assert "link" not in r.stderr and (tmp_path / "probe.png").read_bytes() == b"a probe the scene names"
    write_scene(tmp_path, environment='file = "probe.exr"')
    r = run(["render", "scene.toml", "-o", "scene.exr", "--spp", "1", "--force"], tmp_path)   # its JSON is fine
    assert r.returncode == 0, r.stderr
    r = run(["bench", "scene.toml", "--json", "scene.toml", "--force"], tmp_path)
    assert_one_line_error(r, "--json scene.toml", "expected a path ending in .json")
    assert (tmp_path / "probe.exr").read_bytes() == before
    # bench's outputs are named by their own options (it said "-o", an option bench does not have)
    (tmp_path / "scene.json").write_text((tmp_path / "scene.toml").read_text())
    r = run(["bench", "scene.json", "--json", "scene.json", "--force"], tmp_path)
    assert_one_line_error(r, "--json scene.json: would overwrite scene.json, a file this command reads")
    write_scene(tmp_path, environment='file = "probe.png"')
    r = run(["bench", "scene.toml", "--json", "b.json", "--plot", "probe.png", "--force"], tmp_path)
    assert_one_line_error(r, "--plot probe.png: would overwrite", "probe.png, a file this command reads")
    write_scene(tmp_path, environment='file = "probe.exr"')
    npf = fake_npf_table(tmp_path / "npf.bin").read_bytes()
    for argv, needles in [
        (["npf-to-merl", "--table", "npf.bin", "--material", "chrome", "-o", "npf.bin", "--force"],
         ["-o npf.bin", "expected a path ending in .binary"]),
        (["npf-to-merl", "--table", "t.binary", "--material", "chrome", "-o", "t.binary", "--force"],
         ["-o t.binary", "would overwrite", "the file it is made from"]),
        (["brdf-sampling", "npf.bin", "--material", "chrome", "-o", "x.txt"], ["-o x.txt", "ending in .npz"]),
        (["brdf", "npf.bin", "--material", "chrome", "-o", "npf.bin", "--force"], ["-o npf.bin", ".npz"]),
        (["gmm", "probe.exr", "-o", "probe.exr", "--force"], ["-o probe.exr", "ending in .npz or .gmm"]),
        (["gmm", "m.gmm", "-o", "m.gmm", "--force"], ["-o m.gmm", "would overwrite", "the file it is made from"]),
        (["gmm", "probe.exr", "-o", "g.npz", "--kind", "normal", "--scale", "2"], ["--scale 2", "--kind height"]),
        (["gmm", "probe.exr", "-o", "g.npz", "--unaligned", "--prior", "5"], ["--prior 5", "--unaligned"]),
        # given at their defaults they were accepted and dropped (options audit, session 64)
        (["gmm", "probe.exr", "-o", "g.npz", "--kind", "normal", "--scale", "1"], ["--scale 1", "--kind height"]),
        (["gmm", "probe.exr", "-o", "g.npz", "--unaligned", "--prior", "1"], ["--prior 1", "--unaligned"]),
        (["gmm", "probe.exr", "-o", ""], ["-o/--output", "expected a file name, got an empty one"]),
    ]:
        assert_one_line_error(run(argv, tmp_path, module="precompute"), *needles, prog="warpbw-precompute")
    assert (tmp_path / "npf.bin").read_bytes() == npf and not (tmp_path / "g.npz").exists()


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux's /proc, a folder no file can be made in")
def test_an_output_folder_that_cannot_be_written_is_refused_before_the_work(tmp_path):
    """bench ran its whole benchmark, then failed on --json with a bare OS error and lost the results."""
    write_scene(tmp_path)
    t0 = time.perf_counter()
    r = run(["bench", "scene.toml", "--json", "/proc/b.json", "--spp", "1", "--budgets", "1"], tmp_path)
    assert_one_line_error(r, "--json /proc/b.json", "cannot write in /proc")
    r = run(["bench", "scene.toml", "--json", "b.json", "--cache", "/proc/gt"], tmp_path)
    assert_one_line_error(r, "--cache /proc/gt", "cannot write in /proc")
    r = run(["render", "scene.toml", "-o", "/proc/out.exr", "--spp", "1"], tmp_path)
    assert_one_line_error(r, "-o /proc/out.exr", "cannot write in /proc")
    assert time.perf_counter() - t0 < 60 and not (tmp_path / "b.json").exists()


@pytest.mark.parametrize("fill", ["zeros", "unmeasured", "nan", "tiny"])
def test_a_merl_file_without_a_positive_entry_is_refused(tmp_path, fill):
    """It rendered a black sphere with status 0 (after a warning for the unmeasured entries, none for zeros).  Entries
    of 1e-300 passed the check in float64 and were all 0 in the float32 table kept."""
    p = tmp_path / "black.binary"
    value = {"zeros": 0.0, "unmeasured": -1.0, "nan": np.nan, "tiny": 1e-300}[fill]
    with open(p, "wb") as f:
        f.write(np.array([90, 90, 180], "<i4").tobytes())
        np.full(MERL_FILE_SIZE // 8 - 1, value, "<f8").tofile(f)
    write_scene(tmp_path, material='type = "merl"\nfile = "black.binary"')
    r = run(["render", "scene.toml", "-o", "out.exr", "--spp", "1"], tmp_path)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == EXIT_USER_ERROR and "Traceback" not in r.stderr, r.stderr
    assert "black.binary: no positive MERL entry" in lines[-1] and "expected a measured BRDF" in lines[-1], r.stderr
    assert_no_outputs(tmp_path)


@pytest.mark.parametrize("fill,needle", [("zeros", "no positive MERL entry"), ("unmeasured", "no positive MERL entry"),
                                         ("tiny", "no positive MERL entry"), ("huge", r"MERL entries up to 3e\+25")])
def test_write_merl_refuses_what_read_merl_would(tmp_path, fill, needle):
    """npf-to-merl wrote, with status 0, a file its own reader then refused (an NPF curve of 1e19 tabulates beyond
    read_merl's 1e20), and write_merl wrote an all-zero table."""
    from warpbw.io.merl import MERL_SHAPE, read_merl, write_merl

    value = {"zeros": 0.0, "unmeasured": -1.0, "tiny": 1e-300, "huge": 3e25}[fill]
    data = np.full(MERL_SHAPE, value)
    with pytest.raises(WarpbwError, match=rf"out\.binary: refusing to write a file read_merl would refuse: {needle}"):
        write_merl(tmp_path / "out.binary", data)
    assert not list(tmp_path.iterdir())
    data[3, 4, 5] = 0.5        # one positive entry, the others as they were: what the reader takes, the writer writes
    if fill != "huge":
        write_merl(tmp_path / "out.binary", data)
        with warnings.catch_warnings(record=True) as caught:
            assert read_merl(tmp_path / "out.binary").data.max() == pytest.approx(0.5, rel=1e-6)
        # the reader says so where it sets entries to 0, and only there
        said = [str(w.message) for w in caught if "unmeasured" in str(w.message)]
        unmeasured = (f"{tmp_path / 'out.binary'}: 4373997 of 4374000 MERL entries are unmeasured (negative or "
                      "non-finite); set to 0")
        assert said == ([unmeasured] if fill == "unmeasured" else []), said


def test_an_npf_row_that_reflects_nothing_is_refused(tmp_path):
    from warpbw.io.npf import NPF_COLS, NPF_CHANNELS, NPF_MATERIAL_NAMES

    table = np.full(NPF_FILE_SIZE // 4, 0.5, "<f4")
    row = NPF_MATERIAL_NAMES.index("chrome")
    table[row * NPF_COLS * NPF_CHANNELS:(row + 1) * NPF_COLS * NPF_CHANNELS] = 0.0
    table.tofile(tmp_path / "npf.bin")
    r = run(["npf-to-merl", "--table", "npf.bin", "--material", "chrome", "-o", "out.binary"], tmp_path,
            module="precompute")
    assert_one_line_error(r, "npf.bin", "(chrome) reflects nothing", prog="warpbw-precompute")
    assert_no_outputs(tmp_path)
    # a row of random bytes: numpy's cast warning no longer precedes the error
    np.random.default_rng(0).integers(0, 256, NPF_FILE_SIZE, dtype=np.uint8).tofile(tmp_path / "rand.bin")
    r = run(["npf-to-merl", "--table", "rand.bin", "--material", "chrome", "-o", "out.binary"], tmp_path,
            module="precompute")
    assert_one_line_error(r, "rand.bin", "(chrome) holds negative or non-finite values", prog="warpbw-precompute")


def test_options_that_would_be_ignored_are_refused(tmp_path):
    """--spp 1,,2 dropped its empty item; --spp on planes lit by lights alone was accepted and unused."""
    write_scene(tmp_path)
    r = run(["bench", "scene.toml", "--json", "b.json", "--spp", "1,,2"], tmp_path)
    assert "--spp" in r.stderr and "empty item" in r.stderr and r.returncode == EXIT_USER_ERROR, r.stderr
    (tmp_path / "planes.toml").write_text(PLANE_SCENE.replace('normal_map = "map.exr"\n', ""))
    r = run(["render", "planes.toml", "-o", "out.exr", "--filter", "toksvig", "--spp", "8"], tmp_path)
    assert_one_line_error(r, "--spp 8", "planes.toml", "[[light]]s alone", "--filter ground_truth")
    # --seed too: the frame was byte for byte the seed-0 one
    r = run(["render", "planes.toml", "-o", "out.exr", "--filter", "toksvig", "--seed", "5"], tmp_path)
    assert_one_line_error(r, "--seed 5", "planes.toml", "[[light]]s alone", "--filter ground_truth")
    r = run(["bench-filtering", "planes.toml", "--json", "f.json", "--spp", "4"], tmp_path)
    assert_one_line_error(r, "--spp 4", "planes.toml has none")
    # planes beside a sphere, all under lights alone: --spp, --mis and --seed were accepted and drew nothing
    (tmp_path / "mixed.toml").write_text((tmp_path / "planes.toml").read_text() + (
        '[[object]]\nshape = "sphere"\ncenter = [0.0, 0.5, 0.0]\nradius = 0.3\nmaterial = "d"\n'
        '[material.d]\ntype = "lambert"\nalbedo = 0.5\n'))
    for opt, needles in ((["--spp", "8"], ("--spp 8", "--filter ground_truth")), (["--mis"], ("--mis",)),
                         (["--seed", "7"], ("--seed 7", "--filter ground_truth"))):
        r = run(["render", "mixed.toml", "-o", "out.exr", "--filter", "toksvig", *opt], tmp_path)
        assert_one_line_error(r, *needles, "mixed.toml", "[[light]]s alone")
    r = run(["demo", "-o", "out.exr"], tmp_path)
    assert_one_line_error(r, "-o out.exr", "expected a folder")
    # a sphere lit by a directional light alone takes no sample: "8 spp" and MIS were printed and recorded
    sun = '[[light]]\ntype = "directional"\ndirection = [0.0, 0.0, 1.0]\nradiance = [1.0, 1.0, 1.0]'
    (tmp_path / "sun.toml").write_text(SCENE.format(resolution="[8, 8]", environment="", object='shape = "sphere"\n'
                                                    'radius = 1.0', material='type = "lambert"\nalbedo = 0.5')
                                       .replace("[environment]\n", sun))
    for opt, needle in ((["--spp", "8"], "--spp 8"), (["--mis"], "--mis"), (["--seed", "7"], "--seed 7")):
        r = run(["render", "sun.toml", "-o", "out.exr", *opt], tmp_path)
        assert_one_line_error(r, needle, "sun.toml", "[[light]]s alone", "without samples")
    r = run(["render", "sun.toml", "-o", "out.exr"], tmp_path)   # no option to refuse: it renders
    assert r.returncode == 0, r.stderr
    # and says so: it printed "64 spp" and recorded spp 64, the default it never took
    assert "directional lights alone: exact, no samples" in r.stdout and " spp" not in r.stdout
    assert json.loads((tmp_path / "out.json").read_text())["spp"] == 0
    for name in ("out.exr", "out.png", "out.json"):
        (tmp_path / name).unlink()
    assert_no_outputs(tmp_path) and not (tmp_path / "f.json").exists()


def test_a_mesh_whose_detail_is_lost_to_its_extent_says_so(tmp_path):
    """It said 'every triangle has zero area' of a triangle of area 5e29: the vertex merge had collapsed it."""
    (tmp_path / "big.obj").write_text("v 1e30 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    write_scene(tmp_path, obj='mesh = "big.obj"')
    r = run(["render", "scene.toml", "-o", "out.exr", "--spp", "1"], tmp_path)
    assert_one_line_error(r, "big.obj", "every triangle collapses", "coordinates reach 1e+30")


def test_huge_environment_scale_under_adaptive_gives_one_error_line(tmp_path):
    """numpy's 'overflow encountered in reduce' was printed as a warpbw warning above the error."""
    write_scene(tmp_path, environment='procedural = "sky"\nscale = 1e36')
    r = run(["render", "scene.toml", "-o", "out.exr", "--method", "adaptive", "--budget", "2", "-q"], tmp_path)
    assert_one_line_error(r, "scene.toml", "overflowed float32")   # (-q: the probe's bandwidth bar comes first)


def test_a_probe_that_is_not_two_to_one_warns(tmp_path):
    from warpbw.io.exr import write_exr

    write_exr(tmp_path / "square.exr", np.ones((8, 8, 3), np.float32))
    write_scene(tmp_path, environment='file = "square.exr"')
    r = run(["render", "scene.toml", "-o", "out.exr", "--spp", "1"], tmp_path)
    assert r.returncode == 0, r.stderr
    assert "8x8 is not a 2:1 lat-long map" in r.stderr, r.stderr


def _furnace(c: float) -> str:
    """A near-mirror GGX sphere (F = 1) under a constant environment of radiance c."""
    return SCENE.format(resolution="[8, 8]", environment=f"constant = [{c}, {c}, {c}]",
                        object='shape = "sphere"\nradius = 1.0',
                        material='type = "ggx"\nalpha = 1e-4\nspecular = [1.0, 1.0, 1.0]')


def test_a_reference_frame_that_loses_samples_to_float32_overflow_is_refused(tmp_path):
    """A near-mirror in a white furnace returns its radiance c (F = 1); at c = 1e32 radiance times the lobe passed
    float32, the shading dropped those samples and the frame read 0.42 c with status 0 (a warning on the CLI)."""
    from warpbw.pipeline import render_reference
    from warpbw.scene import parse_scene

    ok = render_reference(parse_scene(_furnace(1e30), tmp_path, "f.toml"), 2)
    assert ok.stats["non_finite_samples"] == 0
    assert np.mean(ok.image[ok.coverage]) / 1e30 == pytest.approx(1.0, rel=0.02)
    with pytest.raises(WarpbwError, match=r"f.toml: \d+ of \d+ samples overflowed float32 .*radiance up to 1e\+32"):
        render_reference(parse_scene(_furnace(1e32), tmp_path, "f.toml"), 2)


def test_library_renderers_refuse_bad_seeds_devices_and_scenes(tmp_path):
    """The CLIs checked these; called from Python they wrapped (seed 2**32 rendered seed 0's image), failed inside
    numpy or Warp, or on a missing attribute of a path given as the scene."""
    from warpbw.filtering import render_filtering
    from warpbw.pipeline import render_adaptive, render_reference
    from warpbw.scene import parse_scene

    scene = parse_scene(_furnace(1.0), tmp_path, "f.toml")
    for seed in (-1, 2**32, 1.5, None, "1"):
        with pytest.raises(WarpbwError, match="seed: expected an integer"):
            render_reference(scene, 1, seed=seed)
    with pytest.raises(WarpbwError, match="seed: expected an integer"):
        render_adaptive(scene, 2, seed=-5)
    planes = parse_scene(PLANE_SCENE.replace('normal_map = "map.exr"\n', ""), tmp_path, "p.toml")
    with pytest.raises(WarpbwError, match="seed: expected an integer"):
        render_filtering(planes, "fixed", seed=2**70)
    for device in ("bogus", "", 0):
        with pytest.raises(WarpbwError, match="device .*Warp found: cpu"):
            render_reference(scene, 1, device=device)
    with pytest.raises(WarpbwError, match="device bogus"):
        render_filtering(planes, "fixed", device="bogus")
    import warp as wp

    assert render_reference(scene, 1, device=wp.get_device("cpu")).image.shape == (8, 8, 3)   # a Device object
    # flags are True or False: "no" is truthy, and ran the Eq. 10 bound / an unaligned GMM build
    with pytest.raises(WarpbwError, match="preconvolved: expected True or False, got 'no'"):
        render_adaptive(scene, 2, preconvolved="no")
    from precompute.gmm_mipmap import build_gmm_mipmap

    with pytest.raises(WarpbwError, match="unaligned: expected True or False, got 'no'"):
        build_gmm_mipmap(np.zeros((4, 4)), unaligned="no", progress=False)
    # a prepared scene renders where it lives: another device was ignored ("cuda" rendered on the CPU)
    from warpbw.pipeline import prepare_scene

    prep = prepare_scene(scene)
    assert render_reference(prep, 1).image.shape == render_reference(prep, 1, device="cpu").image.shape
    for device in ("cuda", "gpu", 0):
        with pytest.raises(WarpbwError, match="device"):
            render_reference(prep, 1, device=device)
        with pytest.raises(WarpbwError, match="device"):
            render_adaptive(prep, 2, device=device)
    for given in ("f.toml", None):
        with pytest.raises(WarpbwError, match="scene: expected a warpbw.scene.Scene"):
            render_reference(given, 1)


def test_the_lower_level_entry_points_refuse_what_crashed_or_rendered_wrong(tmp_path):
    """Called from Python (edge-case audit, session 47): pixel indices outside the G-buffer crashed the process in
    shade_reference (segfault), spp 0 or -1 returned a black image (-1 reported -120 samples), "yes" switched
    MIS on; make_camera turned a NaN, coincident or parallel argument into NaN rays and an empty image."""
    import warp as wp

    from warpbw.gbuffer import make_camera, render_gbuffer
    from warpbw.pipeline import prepare_scene
    from warpbw.scene import parse_scene
    from warpbw.shading import shade_reference

    prep = prepare_scene(parse_scene(_furnace(1.0), tmp_path, "f.toml"))
    gb = render_gbuffer(prep.camera, prep.geometry)
    n = gb.width * gb.height

    def shade(spp=1, **kw):
        return shade_reference(gb, prep.materials, prep.env_data, spp, **kw)

    assert shade().pixels_shaded == int(gb.coverage.sum()) > 0
    for kw, needle in [({"pixels": wp.array([0, n], dtype=wp.int32)}, f"pixels: .* in 0..{n - 1}, got values from 0 "
                        f"to {n}"),
                       ({"pixels": wp.array([-1], dtype=wp.int32)}, "pixels: .*got values from -1 to -1"),
                       ({"pixels": [0, 1]}, "pixels: expected a 1-D int32 wp.array .*got list"),
                       ({"spp": 0}, "spp: expected an integer >= 1, got 0"),
                       ({"spp": -1}, "spp: expected an integer >= 1, got -1"),
                       ({"spp": 2.0}, "spp: expected an integer"),
                       ({"spp": wp.zeros(n - 1, dtype=wp.int32)}, f"spp: expected an int32 array of {n} per-pixel"),
                       ({"spp": wp.array(np.full(n, -1, np.int32))}, "spp: per-pixel counts must be >= 0"),
                       ({"mis": "yes"}, "mis: expected True or False, got 'yes'"),
                       ({"out": wp.zeros(3, dtype=wp.vec3)}, f"out: expected a vec3 array of {n} pixels")]:
        with pytest.raises(WarpbwError, match=f"^shade_reference: {needle}"):
            shade(**kw)
    ok = ((0.0, 0.0, 3.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 40.0, 8, 8)
    make_camera(*ok)
    for i, bad, needle in [(0, (np.nan, 0.0, 3.0), "position: expected three finite"),
                           (0, (0.0, 3.0), "position: expected three finite"),
                           (1, ok[0], "look_at: must differ from position"),
                           (2, (0.0, 0.0, 2.0), "up: must not be zero or parallel"),
                           (2, (0.0, 0.0, 0.0), "up: must not be zero or parallel"),
                           (3, float("nan"), "fov_deg: expected degrees in"), (3, 0.0, "fov_deg"),
                           (3, -40.0, "fov_deg"), (0, ("a", "b", "c"), "position: expected three finite"),
                           (4, 16.5, "width: expected an integer >= 1"), (5, 0, "height: expected an integer >= 1")]:
        args = list(ok)
        args[i] = bad
        with pytest.raises(WarpbwError, match=f"^make_camera: {needle}"):
            make_camera(*args)


def test_gmm_builder_refuses_sizes_and_parameters_that_hung_or_failed_inside(tmp_path):
    """level_shapes(0, 0) never returned (it grew to 24 GB); texel_size 0 divided by zero, nan failed in
    scikit-learn, -1 flipped the normals; max_samples and refine_sweeps were not checked."""
    code = ("from precompute.gmm_mipmap import level_shapes\n"
            "from warpbw.errors import WarpbwError\n"
            "for hw in ((0, 0), (0, 5), (-1, -1), (2.5, 2)):\n"
            "    try:\n        level_shapes(*hw)\n    except WarpbwError as e:\n        print(e)\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and r.stdout.count("expected at least 1x1 texels") == 4, r.stdout + r.stderr
    from precompute.gmm_mipmap import build_gmm_mipmap

    h = np.random.default_rng(0).random((8, 8))
    for kw, needle in [({"texel_size": 0.0}, "texel_size"), ({"texel_size": float("nan")}, "texel_size"),
                       ({"texel_size": -1.0}, "texel_size"), ({"max_samples": 0}, "max_samples"),
                       ({"max_samples": -1}, "max_samples"), ({"refine_sweeps": -1}, "refine_sweeps"),
                       ({"refine_sweeps": 2.5}, "refine_sweeps")]:
        with pytest.raises(WarpbwError, match=needle):
            build_gmm_mipmap(h, progress=False, **kw)


def test_library_helpers_refuse_values_they_once_took_or_failed_on(tmp_path):
    """threads 0 or 1.5 ran as 1; a NaN bandwidth came back NaN or 1e30 and a cosine of 2 was used; 50 wavelet
    levels asked numpy for 64 PiB and values of 1e160 gave NaN bandwidths; an exposure of 1e6 stops raised
    Python's OverflowError."""
    from precompute.wavelets import band_maxima, local_bandwidth
    from warpbw.bandwidth_ops import apply_operator
    from warpbw.io.exr import write_png
    from warpbw.pipeline import render_reference
    from warpbw.scene import parse_scene

    scene = parse_scene(_furnace(1.0), tmp_path, "f.toml")
    for threads in (0, -1, 1.5, "2", True):
        with pytest.raises(WarpbwError, match="threads: expected an integer >= 1"):
            render_reference(scene, 1, threads=threads)
    with pytest.raises(WarpbwError, match="nu has NaN values"):
        apply_operator("T", [[np.nan, 1.0]], d=1.0)
    for op in ("R", "one_bounce"):
        with pytest.raises(WarpbwError, match="nu has NaN values"):
            apply_operator(op, [[1.0, np.nan]])
    for cos in (2.0, -1.5):
        with pytest.raises(WarpbwError, match="cos_i is a cosine"):
            apply_operator("P_i", [[1.0, 1.0]], cos_i=cos)
    img = np.random.default_rng(0).random((8, 8))
    with pytest.raises(WarpbwError, match="levels must be an integer from 1 to 7, got 50"):
        band_maxima(img, levels=50)
    with pytest.raises(WarpbwError, match="beyond 1e\\+150"):
        local_bandwidth(img * 1e160)
    assert np.isfinite(local_bandwidth(img * 1e140)).all()     # the same image, scaled, below the limit
    np.testing.assert_allclose(local_bandwidth(img * 1e140), local_bandwidth(img), rtol=1e-9)
    for exposure in (1e6, -1e6, float("nan")):
        with pytest.raises(WarpbwError, match="exposure"):
            write_png(tmp_path / "p.png", np.ones((2, 2, 3)), exposure=exposure)
    assert not (tmp_path / "p.png").exists()


def test_metrics_refuse_non_finite_images_and_a_non_positive_eps():
    """psnr of a NaN image was NaN, mse of an inf one inf, relmse with eps = -1 negative (-0.33)."""
    from warpbw.metrics import compare_images, mse, psnr, relmse, relmse_map

    ref = np.ones((2, 3, 3))
    bad = ref.copy()
    bad[0, 1, 2] = np.nan
    for f in (mse, psnr, relmse, relmse_map, compare_images):
        with pytest.raises(WarpbwError, match="test image: 1 non-finite values"):
            f(bad, ref)
        with pytest.raises(WarpbwError, match="reference image: 1 non-finite values"):
            f(ref, bad)
    mask = np.ones((2, 3), bool)
    mask[0, 1] = False                                   # a non-finite pixel outside the mask does not count
    assert mse(bad, ref, mask) == 0.0
    for eps in (-1.0, 0.0, float("nan"), float("inf")):
        with pytest.raises(WarpbwError, match="eps: expected a finite number > 0"):
            relmse(ref, ref, eps=eps)
    assert relmse(2 * ref, ref, eps=1.0) == pytest.approx(0.5)   # (2 - 1)^2 / (1 + 1)


def test_brdf_evaluators_and_probe_helpers_name_bad_arguments(tmp_path):
    """merl_eval / npf_eval failed in numpy's broadcasting or with an IndexError; read_npf(path, None) answered
    'close matches: nylon'; procedural_sky with a NaN elevation returned an all-NaN map; sample_directions(env, -1)
    failed in Warp."""
    from warpbw.envmap import constant_envmap, procedural_sky, sample_directions
    from warpbw.io.npf import npf_eval, read_npf

    mat = read_npf(fake_npf_table(tmp_path / "npf.bin"), "chrome")
    up = [0.0, 0.0, 1.0]
    assert npf_eval(mat, [up, up], up).shape == (2, 3)            # one direction broadcasts
    with pytest.raises(WarpbwError, match="as many incident as outgoing"):
        npf_eval(mat, [up, up], [up, up, up])
    with pytest.raises(WarpbwError, match="3 components"):
        npf_eval(mat, [[0.0, 1.0]], up)
    with pytest.raises(WarpbwError, match="NPF material name: expected a string"):
        read_npf(tmp_path / "npf.bin", None)
    for kw in ({"sun_elevation_deg": float("nan")}, {"sun_radius_deg": 0.0}, {"sun_radiance": -5.0}):
        with pytest.raises(WarpbwError, match=f"procedural_sky: {next(iter(kw))}"):
            procedural_sky(8, 4, **kw)
    assert np.isfinite(procedural_sky(8, 4, sun_radiance=0.0)).all()
    with pytest.raises(WarpbwError, match="n: expected an integer >= 0"):
        sample_directions(constant_envmap(1.0), -1)


def test_renderer_switches_and_levels_are_checked(tmp_path):
    """mis="yes" switched MIS on; lod_bias inf moved every pixel to the coarsest level; upsample_level took level
    2.5 as 2 and failed on -1 inside a shift; write_exr stored 1e39 as inf with only numpy's cast warning."""
    from warpbw.filtering import render_filtering
    from warpbw.io.exr import write_exr
    from warpbw.pipeline import render_adaptive, render_reference
    from warpbw.scene import parse_scene
    from warpbw.upsample import upsample_level

    scene = parse_scene(_furnace(1.0), tmp_path, "f.toml")
    with pytest.raises(WarpbwError, match="mis: expected True or False, got 'yes'"):
        render_reference(scene, 1, mis="yes")
    with pytest.raises(WarpbwError, match="mis: expected True or False"):
        render_adaptive(scene, 2, mis=1)
    planes = parse_scene(PLANE_SCENE.replace('normal_map = "map.exr"\n', ""), tmp_path, "p.toml")
    for bias in (float("inf"), float("nan")):
        with pytest.raises(WarpbwError, match="lod_bias"):
            render_filtering(planes, "lean", lod_bias=bias)
    from warpbw.gbuffer import SphereSpec, build_geometry, make_camera, render_gbuffer

    cam = make_camera((0.0, 0.0, 4.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 35.0, 8, 8)
    gb = render_gbuffer(cam, build_geometry([SphereSpec((0.0, 0.0, 0.0), 1.0, 0)], []))
    for level in (-1, 2.5, 4):
        with pytest.raises(WarpbwError, match=r"level \(of a 8x8 G-buffer\): expected an integer"):
            upsample_level(gb, cam, level, None, None, None)
    with pytest.raises(WarpbwError, match="beyond float32"):
        write_exr(tmp_path / "big.exr", np.full((2, 2, 3), 1e39))
    assert not (tmp_path / "big.exr").exists()
    write_exr(tmp_path / "inf.exr", np.full((2, 2, 3), np.inf))      # inf itself is stored as it is


def test_lower_level_functions_check_devices_specs_shapes_and_directions(tmp_path):
    """Called from Python these failed inside Warp or numpy (device "gpu" in every function that takes one, a
    2-component albedo, short NPF curves, (N, 2) directions, a 0-d image, a path of None), or gave a wrong answer
    without a word: alpha NaN and kind 99 were packed into the material table, npf_eval read a NaN direction as 0
    (below the horizon), and coverage_from_alpha read the B channel as A when the pixels had fewer channels than
    names."""
    from warpbw import adaptive, bandwidth
    from warpbw import brdf as B
    from warpbw.bandwidth_ops import one_bounce
    from warpbw.envmap import envmap_from_array
    from warpbw.gbuffer import allocate_gbuffer, build_geometry, hide_beyond, render_gbuffer
    from warpbw.io.merl import half_diff_from_dirs, merl_eval
    from warpbw.io.npf import npf_eval, read_npf
    from warpbw.lights import directional_struct
    from warpbw.mesh_normals import mesh_topology
    from warpbw.metrics import compare_images, coverage_from_alpha, psnr
    from warpbw.pipeline import prepare_scene
    from warpbw.pyramid import image_level
    from warpbw.sampling import pack_samplers
    from warpbw.scene import parse_scene
    from warpbw.shading import covered_pixels, shade_reference
    from warpbw.upsample import parent_weights

    prep = prepare_scene(parse_scene(_furnace(1.0), tmp_path, "f.toml"))
    gb = render_gbuffer(prep.camera, prep.geometry)
    for call in (lambda d: B.build_material_table([B.MaterialSpec("a", B.LAMBERT, albedo=(0.5,) * 3)], device=d),
                 lambda d: envmap_from_array(np.ones((4, 8, 3)), device=d),
                 lambda d: render_gbuffer(prep.camera, prep.geometry, device=d),
                 lambda d: image_level(np.ones((4, 4), np.float32), device=d),
                 lambda d: one_bounce([[1.0, 1.0]], 1.0, 1.0, device=d),
                 lambda d: shade_reference(gb, prep.materials, prep.env_data, 1, device=d),
                 lambda d: build_geometry([], [], device=d), lambda d: allocate_gbuffer(4, 4, device=d),
                 lambda d: hide_beyond(gb, prep.camera, np.full((gb.height, gb.width), 1e9), device=d),
                 lambda d: directional_struct([[0.0, 0.0, 1.0]], [[1.0, 1.0, 1.0]], device=d),
                 lambda d: covered_pixels(gb, device=d), lambda d: parent_weights(gb.data, prep.camera, 0, device=d),
                 lambda d: pack_samplers([], device=d), lambda d: mesh_topology(np.zeros((1, 3)), 0, 1, device=d),
                 adaptive.load_kernels, bandwidth.load_kernels):
        with pytest.raises(WarpbwError, match="device gpu: not available on this machine"):
            call("gpu")

    def spec(**kw):
        return B.MaterialSpec("m", **{"kind": B.GGX, "alpha": 0.2, "specular": (1.0, 1.0, 1.0), **kw})

    assert B.build_material_table([spec()]).names == ["m"]
    for kw, needle in [({"kind": 99}, "kind: expected one of"), ({"kind": 1.0}, "kind: expected one of"),
                       ({"alpha": float("nan")}, "alpha: expected a finite number >= 0"),
                       ({"alpha": -0.1}, "alpha"), ({"albedo": (0.5, 0.5)}, "albedo: expected three finite"),
                       ({"specular": (1.0, np.inf, 1.0)}, "specular"), ({"eta": (1.0, 1.0, 1.0)}, "both eta and k"),
                       ({"eta": (1.0,) * 3, "k": (-1.0,) * 3}, "k: expected three finite numbers >= 0"),
                       ({"kind": B.NPF, "npf": np.zeros(5)}, f"npf: expected {B.NPF_STRIDE} x 3 values, got 5"),
                       ({"kind": B.MERL, "merl": np.zeros((90, 90, 3))}, "merl: expected 1458000 x 3")]:
        with pytest.raises(WarpbwError, match=f"material 0 \\('m'\\).*{needle}"):
            B.build_material_table([spec(**kw)])
    curves = [np.ones(3), np.ones(3), np.ones((90, 3)), np.ones((90, 3)), np.ones((90, 3))]
    assert B.pack_npf_curves(*curves).shape == (B.NPF_STRIDE, 3)
    curves[3] = np.ones((80, 3))
    with pytest.raises(WarpbwError, match="g1: expected 90 x 3 values, got 240"):
        B.pack_npf_curves(*curves)

    up, tilt = [0.0, 0.0, 1.0], [0.6, 0.0, 0.8]
    assert np.shape(half_diff_from_dirs(up, tilt)[0]) == ()              # one pair in, scalars out, as before
    with pytest.raises(WarpbwError, match="3 components"):
        half_diff_from_dirs(np.ones((4, 2)), np.ones((4, 2)))
    mat = read_npf(fake_npf_table(tmp_path / "npf.bin"), "chrome")
    merl = type("M", (), {"data": np.ones((90, 90, 180, 3))})()
    for f in (lambda wi, wo: half_diff_from_dirs(wi, wo), lambda wi, wo: npf_eval(mat, wi, wo),
              lambda wi, wo: merl_eval(merl, wi, wo)):
        for bad in ([np.nan, 0.0, 1.0], [0.0, 0.0, 0.0], [np.inf, 0.0, 1.0]):
            with pytest.raises(WarpbwError, match="wi: expected finite non-zero directions"):
                f(bad, tilt)
    # a direction of any length reads as its unit vector, as the device evaluators take it
    np.testing.assert_allclose(npf_eval(mat, [0.0, 0.0, 7.0], tilt), npf_eval(mat, up, tilt), rtol=1e-12)

    with pytest.raises(WarpbwError, match="test image: expected an array of numbers, got str"):
        psnr("a", "b")
    with pytest.raises(WarpbwError, match=r"test image: expected \(H, W\) or \(H, W, C\) values, got shape \(\)"):
        compare_images(np.float64(1.0), np.float64(1.0))
    rgba = np.zeros((2, 2, 4))
    rgba[0, 0, 3] = 1.0
    assert coverage_from_alpha(rgba, "RGBA").sum() == 1
    with pytest.raises(WarpbwError, match=r"do not hold the 4 channels"):
        coverage_from_alpha(rgba[..., :3], "RGBA")
    from warpbw.io.exr import write_exr

    with pytest.raises(WarpbwError, match=r"^write_exr: path: expected a file name \(str or Path\), got None"):
        write_exr(None, np.ones((2, 2, 3)))
    # the readers and the other writers said it with a TypeError from pathlib
    from warpbw.io.exr import read_exr, write_false_colour_png, write_png
    from warpbw.io.mesh import load_mesh

    for call, name in ((lambda: read_exr(None), "input file (an OpenEXR image)"),
                       (lambda: load_mesh(None), "input file"),
                       (lambda: write_png(None, np.ones((2, 2, 3))), "write_png: path"),
                       (lambda: write_false_colour_png(None, np.ones((2, 2))), "write_false_colour_png: path")):
        with pytest.raises(WarpbwError, match=rf"^{re.escape(name)}.*: expected a file name \(str or Path\), got None"):
            call()
    with pytest.raises(WarpbwError, match="cannot write pixels of type <U1"):
        write_exr(tmp_path / "s.exr", [["a"]])
    assert not (tmp_path / "s.exr").exists()


def test_a_reader_that_leaves_early_stops_the_command_quietly(tmp_path):
    """``warpbw compare A B | head -1``: the closed pipe printed 'warpbw: error: [Errno 32] Broken pipe' and exited
    with 2, a user error.  Now it stops without a word with 141, as a shell reports a command killed by SIGPIPE.  Its
    stdout is block-buffered, as a pipe's is by default: with PYTHONUNBUFFERED (which a test runner may set) nothing
    is left to flush at exit, and the interpreter's own flush meeting the closed pipe ("Exception ignored ...
    BrokenPipeError", status 120) could not be seen."""
    write_exr(tmp_path / "a.exr", np.ones((4, 4, 3)))
    env = dict(os.environ, WARPBW_CACHE=str(tmp_path / "_cache"))
    env.pop("PYTHONUNBUFFERED", None)
    for _ in range(3):   # the reader leaves before the command writes (Python's start-up alone takes longer)
        p = subprocess.Popen([sys.executable, "-m", "warpbw.cli", "compare", "a.exr", "a.exr"], cwd=tmp_path, env=env,
                             stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        p.stdout.close()
        err = p.stderr.read().decode()
        assert p.wait(timeout=120) == 141 and err == "", (p.returncode, err)


# ------------------------------------------------------------------------------------ examples: options, outputs

def _example_inputs(d: Path) -> None:
    """What the example tests below read: a sphere scene, a plane scene without a normal map, a small probe, a
    one-triangle mesh, a file and a folder."""
    write_scene(d)
    (d / "planes.toml").write_text(PLANE_SCENE.replace('normal_map = "map.exr"\n', ""))
    write_exr(d / "probe.exr", np.ones((4, 8, 3), np.float32))
    (d / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (d / "afile").write_text("keep")
    (d / "adir").mkdir()
    (d / "gone").symlink_to(d / "never-made")   # a link to nothing


def _tree(d: Path) -> dict:
    return {str(p.relative_to(d)): (p.read_bytes() if p.is_file() else None) for p in sorted(d.rglob("*"))}


@pytest.mark.parametrize("argv,needles", [
    # --json: a .json name, never one of the inputs (the scene was replaced by the JSON, status 0, with --force)
    (["allocation_ceiling.py", "scene.toml", "--seeds", "2", "--spp", "1", "--budget", "1", "--json", "scene.toml",
      "--force"], ["--json scene.toml: expected a path ending in .json"]),
    (["allocation_ceiling.py", "scene.toml", "--seeds", "2", "--spp", "1", "--budget", "1", "--json", "a.png"],
     ["--json a.png: expected a path ending in .json"]),
    (["allocation_ceiling.py", "s.json", "--seeds", "2", "--spp", "1", "--budget", "1", "--json", "s.json",
      "--force"], ["--json s.json: would overwrite s.json"]),
    (["filtering_floor.py", "planes.toml", "--zoom", "8", "--json", "planes.toml", "--force"],
     ["--json planes.toml: expected a path ending in .json"]),
    (["filtering_floor.py", "p.json", "--zoom", "8", "--json", "p.json", "--force"], ["--json p.json: would overwrite"]),
    # checked before the analysis (these failed after it with a raw errno)
    (["filtering_floor.py", "planes.toml", "--zoom", "8", "--json", "afile/x.json"],
     ["--json afile/x.json: afile is not a directory"]),
    (["filtering_floor.py", "planes.toml", "--zoom", "8", "--json", "adir", "--force"],
     ["--json adir: expected a path ending in .json"]),
    (["filtering_floor.py", "planes.toml", "--zoom", "8", "--json", "d.json", "--force"],
     ["--json d.json: is a directory"]),
    (["mirror_smear.py", "--probe", "probe.exr", "--res", "8", "--budget", "1", "--truth-spp", "1", "--json", "m.txt"],
     ["--json m.txt: expected a path ending in .json"]),
    (["gmm_precompute_time.py", "--size", "17", "--components", "1", "--json", "t.txt"],
     ["--json t.txt: expected a path ending in .json"]),
], ids=["allocation_ceiling scene", "allocation_ceiling png", "allocation_ceiling input", "filtering_floor scene",
        "filtering_floor input", "filtering_floor under a file", "filtering_floor dir", "filtering_floor dir.json",
        "mirror_smear", "gmm_precompute_time"])
def test_example_json_outputs_end_in_json_and_never_replace_an_input(tmp_path, argv, needles):
    """the examples' --json took any name, the scene itself with --force; filtering_floor checked
    only that it existed, after the whole analysis.  Now: one line before any work, and nothing changed."""
    _example_inputs(tmp_path)
    write_scene(tmp_path, "s.json")
    (tmp_path / "p.json").write_text((tmp_path / "planes.toml").read_text())
    (tmp_path / "d.json").mkdir()
    before = _tree(tmp_path)
    example_error(run_example(argv, tmp_path), argv[0], *needles)
    assert _tree(tmp_path) == before


# a file name TOML cannot take as it is: a double quote, a backslash, a control character and a non-BMP character
_AWKWARD_NAME = 'we"ird\\back\x01\U0001F600.exr'


def test_example_scenes_escape_the_paths_they_write(tmp_path):
    """filtering_scenes.py pasted --environment into "..." (a quote or a backslash made the scene
    invalid TOML) and mirror_smear.py wrote json.dumps' surrogate pairs, which TOML refuses; both exited 0."""
    from warpbw.scene import load_scene

    probe = tmp_path / _AWKWARD_NAME
    write_exr(probe, np.ones((4, 8, 3), np.float32))
    r = run_example(["filtering_scenes.py", "--out", "fs", "--size", "17", "--environment", _AWKWARD_NAME], tmp_path)
    assert r.returncode == 0, r.stderr
    for name in ("scales", "carved_disk", "dunes"):
        assert load_scene(tmp_path / "fs" / f"{name}.toml").environment.file == probe.resolve()
    r = run_example(["mirror_smear.py", "--probe", _AWKWARD_NAME, "--res", "8", "--write-scene", "ms"], tmp_path)
    assert r.returncode == 0, r.stderr
    assert load_scene(tmp_path / "ms" / "mirror_8.toml").environment.file == probe.resolve()


@pytest.mark.parametrize("alpha", ["1e300", "2", "1e-9"])
def test_mirror_smear_writes_no_scene_the_loader_would_refuse(tmp_path, alpha):
    """--write-scene --alpha 1e300 wrote a scene the loader refuses ("[material.m].alpha"), status 0;
    the render path refused it only after loading the probe."""
    write_exr(tmp_path / "probe.exr", np.ones((4, 8, 3), np.float32))
    r = run_example(["mirror_smear.py", "--probe", "probe.exr", "--res", "8", "--alpha", alpha, "--write-scene", "ms"],
                    tmp_path)
    example_error(r, "mirror_smear.py", f"--alpha {float(alpha)!r}: expected a GGX roughness from")
    assert not (tmp_path / "ms").exists()


def test_compare_mitsubas_least_resolution_leaves_an_interior_to_compare(tmp_path):
    """The sphere's interior (warpbw's coverage eroded by ERODE_PX) over which compare_mitsuba.py measures the error
    holds pixels from RESOLUTION_MIN on, and none one pixel below it (where the comparison failed after both
    renders)."""
    cm = load_example("compare_mitsuba")
    prepare, render_reference = cm.import_warpbw()
    probe = tmp_path / "probe.exr"
    write_exr(probe, np.full((8, 16, 3), 0.5, np.float32))
    interior = {}
    for res in (cm.RESOLUTION_MIN - 1, cm.RESOLUTION_MIN):
        toml_text = cm.warpbw_toml(probe, cm.CASES["lambert"], res, 0.0, 1.0)
        _, cov, _ = cm.render_warpbw(prepare, render_reference, toml_text, 1, 0)
        interior[res] = int(cm.erode(cov, cm.ERODE_PX).sum())
    assert interior[cm.RESOLUTION_MIN - 1] == 0 < interior[cm.RESOLUTION_MIN], interior


def test_compare_mitsubas_refusals_are_error_lines(tmp_path):
    """Its refusals past the parser (a Mitsuba variant it cannot use) printed "compare_mitsuba: ..." with status 1,
    without the "error:" of every other refusal."""
    pytest.importorskip("mitsuba")
    write_exr(tmp_path / "probe.exr", np.full((8, 16, 3), 0.5, np.float32))
    example_error(run_example(["compare_mitsuba.py", "--variant", "nonesuch", "--probe", "probe.exr", "--resolution",
                               "16", "--spp", "1"], tmp_path), "compare_mitsuba.py",
                  "none of the Mitsuba variants ['nonesuch'] can be used")


def test_compare_mitsuba_without_mitsuba_says_how_to_install_it_from_the_checkout(monkeypatch):
    """It said "pip install 'warpbw[mitsuba]'", which asks the package index for a project named warpbw (not this
    one); README installs the extra from the checkout."""
    import builtins

    cm = load_example("compare_mitsuba")
    real_import = builtins.__import__

    def no_mitsuba(name, *a, **kw):
        if name == "mitsuba" or name.startswith("mitsuba."):
            raise ImportError("No module named 'mitsuba'")
        return real_import(name, *a, **kw)

    monkeypatch.setattr(builtins, "__import__", no_mitsuba)
    with pytest.raises(WarpbwError, match=re.escape('Mitsuba 3 is not installed: pip install -e ".[mitsuba]"')):
        cm.import_mitsuba()


def test_compare_mitsuba_keeps_existing_outputs_without_force(tmp_path):
    """compare_mitsuba.py had no --force and wrote its images over any already in --out.  It refuses
    them now before Mitsuba is imported (so here, where it is not installed, too), and an --out that is a file."""
    _example_inputs(tmp_path)
    mine = tmp_path / "cmp" / "lambert.png"
    mine.parent.mkdir()
    mine.write_text("mine\n")
    base = ["compare_mitsuba.py", "--probe", "probe.exr", "--cases", "lambert"]
    example_error(run_example(base + ["--out", "cmp"], tmp_path), "compare_mitsuba.py", "cmp/lambert.png",
                  "already exists", "--force")
    example_error(run_example(base + ["--out", "probe.exr", "--force"], tmp_path), "compare_mitsuba.py",
                  "--out probe.exr: not a directory")
    assert mine.read_text() == "mine\n" and list(mine.parent.iterdir()) == [mine]
    assert "--force" in run_example(["compare_mitsuba.py", "--help"], tmp_path).stdout


def test_compare_mitsuba_lights_mitsuba_with_the_radiance_warpbw_reads(tmp_path):
    """Module docstring: "both renderers get the same radiance".  Mitsuba's Bitmap applies an EXR's chromaticities,
    which warpbw's loader ignores: city.exr's (sRGB's primaries adapted to D50) made Mitsuba's probe 25% redder and
    31% less blue than warpbw's, and the lambert sphere under it read relMSE 0.059, 30x the noise floor.  Truth: the
    pixels written (a negative one read as 0), and Mitsuba's envmap at a texel's direction returns that texel (rows at
    v = r / (H - 1), columns at u = (c + 1/2) / W, d = (sin 2 pi u sin pi v, cos pi v, -cos 2 pi u sin pi v))."""
    pytest.importorskip("mitsuba")
    import OpenEXR

    cm = load_example("compare_mitsuba")
    mi, _ = cm.import_mitsuba("scalar_rgb")
    px = np.random.default_rng(7).uniform(0.1, 2.0, (8, 16, 3)).astype(np.float32)
    px[2, 3, 1] = -0.5
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage,
              "chromaticities": (0.6484, 0.3309, 0.3212, 0.5979, 0.1559, 0.0661, 0.3457, 0.3585)}   # city.exr's
    OpenEXR.File(header, {"RGB": px}).write(str(tmp_path / "probe.exr"))
    want = np.maximum(px, 0.0)
    got = cm.load_probe(mi, tmp_path / "probe.exr")
    np.testing.assert_array_equal(got, want)
    em = cm.mitsuba_scene(mi, got, cm.CASES["lambert"], cm.RESOLUTION_MIN, 1, 0.0, 1.0).environment()
    si = mi.SurfaceInteraction3f()
    for r, c in ((3, 5), (5, 12), (2, 3)):
        u, v = (c + 0.5) / 16, r / 7
        d = (math.sin(2 * math.pi * u) * math.sin(math.pi * v), math.cos(math.pi * v),
             -math.cos(2 * math.pi * u) * math.sin(math.pi * v))
        si.wi = mi.Vector3f(-d[0], -d[1], -d[2])
        # atol: Mitsuba's float32 direction lands ~1e-7 of a texel off its centre, and its bilinear lookup takes that
        # much of a neighbour (<= 2): mitsuba 3.5.0 read 4.9e-7 for the texel of 0 (session 82)
        np.testing.assert_allclose(np.array(em.eval(si)), want[r, c], rtol=1e-4, atol=1e-5, err_msg=f"texel {r} {c}")


def test_compare_mitsuba_checks_its_conventions_on_the_scalar_variant(tmp_path):
    """--check-conventions handed Mitsuba's Vector3f numpy arrays, which only its vectorised variants take: on
    scalar_rgb, the fallback without LLVM 19, it stopped with a TypeError; and it refused a missing --probe, which
    it does not read.  Truth: the docstring's camera (+X right, +Y up), envmap formula (rotation R_y) and GGX."""
    pytest.importorskip("mitsuba")
    cm = load_example("compare_mitsuba")
    assert cm.parse_args(["--check-conventions", "--probe", str(tmp_path / "missing.exr")]).check_conventions
    mi, _ = cm.import_mitsuba("scalar_rgb")
    found = cm.check_conventions(mi, n=100)
    (xr, xc), (yr, yc) = found["camera"]["+X"], found["camera"]["+Y"]
    assert xc > 40 and abs(xr - 31.5) < 1 and yr < 20 and abs(yc - 31.5) < 1, found["camera"]
    assert len(found["envmap"]) == 10
    for r, c, rot, lit, _ in found["envmap"]:
        if r == 0:   # the pole row's texel lights a lopsided patch around +Y
            continue
        u, v, a = (c + 0.5) / 64, r / 31, math.radians(rot)
        d = np.array([math.sin(2 * math.pi * u) * math.sin(math.pi * v), math.cos(math.pi * v),
                      -math.cos(2 * math.pi * u) * math.sin(math.pi * v)])
        want = [d[0] * math.cos(a) + d[2] * math.sin(a), d[1], -d[0] * math.sin(a) + d[2] * math.cos(a)]
        np.testing.assert_allclose(lit, want, atol=0.01, err_msg=f"texel {r} {c}, rotation {rot}")
    assert sorted(found["roughconductor"]) == [0.1, 0.4] and max(found["roughconductor"].values()) < 1e-4


@pytest.mark.parametrize("argv,needles", [
    # sizes beyond MAX_RESOLUTION: a raw Warp traceback after loading the assets
    (["gbuffer.py", "--mesh", "tri.obj", "--resolution", "100000", "100000"],
     ["--resolution 100000 100000: expected a width and a height", "at most 16384"]),
    (["reference_estimator.py", "--probe", "probe.exr", "--npf", "afile", "--spp", "1", "--resolution", "100000",
      "8"], ["--resolution 100000 8: expected a width and a height", "at most 16384"]),
    (["anisotropy_cost.py", "planes.toml", "--zoom", "1", "--size", "100000x100000", "--runs", "1"],
     ["--size 100000x100000: expected at most 16384 pixels per side"]),
    # nan and inf passed the zoom check and failed after the preparation
    (["anisotropy_cost.py", "planes.toml", "--zoom", "nan", "--size", "8x8"], ["--zoom 'nan': expected"]),
    (["anisotropy_cost.py", "planes.toml", "--zoom", "1,inf", "--size", "8x8"], ["--zoom '1,inf': expected"]),
    # a huge --frames blamed --seed, with a negative bound
    (["dynamic_geometry.py", "--frames", "100000000000", "--material", "ggx"],
     ["--frames 100000000000: expected at most 4294967296"]),
    # duplicate zooms rendered twice; warpbw bench-filtering refuses them
    (["filtering_zoom.py", "planes.toml", "--zoom", "1,1"], ["--zoom '1,1': expected distinct values, got 1"]),
    (["filtering_floor.py", "planes.toml", "--zoom", "8,16,8"], ["--zoom '8,16,8': expected distinct values, got 8"]),
    # limits named by the library's parameter ("n", "spp", "-o"), after loading the assets
    (["brdf_sampling.py", "--table", "afile", "--samples", "100000000000"],
     ["--samples: expected an integer from 1 to 2147483647"]),
    (["reference_estimator.py", "--probe", "probe.exr", "--npf", "afile", "--spp", "3000000000",
      "--resolution", "8", "8"], ["--spp: expected an integer from 1 to 2147483647"]),
    (["mirror_smear.py", "--probe", "probe.exr", "--res", "8", "--budget", "1e12"],
     ["--budget 1000000000000.0: expected a whole number of samples per pixel from 1 to 8388607"]),
    (["filtering_floor.py", "planes.toml", "--gt-spp", "100000000000"],
     ["--gt-spp 100000000000: expected from 64 to 2147483647"]),
    # filtering_zoom named the renderer's "spp (ground-truth rays per pixel)", after loading the scene
    (["filtering_zoom.py", "planes.toml", "--zoom", "1", "--gt-spp", "2147483648"],
     ["--gt-spp 2147483648: expected from 64 to 2147483647"]),
    (["dynamic_geometry.py", "--mesh", "tri.obj", "--material", "ggx", "--size", "8", "--out", "afile"],
     ["--out afile: not a directory"]),
    # allocation_ceiling: a budget past the kernels' int32 N_p was refused as "budget" after the --seeds brute-force
    # renders (minutes on a bench scene), an spp past int32 as "spp"
    (["allocation_ceiling.py", "scene.toml", "--seeds", "2", "--spp", "1", "--budget", "1e30"],
     ["--budget 1e+30: expected a positive number of samples per pixel, at most 8.38861e+06"]),
    (["allocation_ceiling.py", "scene.toml", "--seeds", "2", "--spp", "2147483648"],
     ["--spp: expected an integer from 1 to 2147483647"]),
    # a budget past the kernels' int32 N_p was refused as "budget" after loading the mesh and the probe (16 s), a
    # size past the scene's largest as "<dynamic_geometry>: [camera].resolution"
    (["dynamic_geometry.py", "--mesh", "tri.obj", "--material", "ggx", "--size", "8", "--budget", "1e30"],
     ["--budget 1e+30: expected a positive number of samples per pixel, at most 8.38861e+06"]),
    (["dynamic_geometry.py", "--mesh", "tri.obj", "--material", "ggx", "--size", "16385"],
     ["--size 16385: expected 8 to 16384 pixels"]),
    # validate_bandwidth: --size 1 failed late on an internal "stride", --seed -1 named "seed", an --out that is a
    # file gave "[Errno 17] File exists"
    (["validate_bandwidth.py", "--out", "v", "--quick", "--size", "1"], ["--size 1: expected at least", "--window"]),
    (["validate_bandwidth.py", "--out", "v", "--quick", "--seed", "-1"], ["--seed: expected an integer from 0"]),
    # past the scenes' largest side it was refused as "sphere-ccp3-forest: [camera].resolution", after the probe
    (["validate_bandwidth.py", "--out", "v", "--quick", "--size", "16385"], ["--size 16385: expected at most 16384"]),
    # n_b past the pass's largest was refused as "n_b" after the converged image (16 to 24 s at --quick)
    (["validate_bandwidth.py", "--out", "v", "--quick", "--nb", "65537"], ["--nb 65537: expected at most 65536"]),
    (["validate_bandwidth.py", "--out", "v", "--quick", "--nb-diagnostic", "65537"],
     ["--nb-diagnostic 65537: expected at most 65536"]),
    (["validate_bandwidth.py", "--out", "afile", "--quick"], ["--out afile: not a directory"]),
    # bench_scenes: an --out that is a file; a --results under one, refused before the scenes are written
    (["bench_scenes.py", "--out", "afile"], ["--out afile: not a directory"]),
    (["bench_scenes.py", "--out", "s", "--run", "--results", "afile/r"], ["--results afile/r: afile is not a directory"]),
    (["bunny_on_floor.py", "--out", "afile"], ["--out afile: not a directory"]),
    (["bunny_on_floor.py", "--out", "afile/m"], ["--out afile/m: afile is not a directory"]),
    # these two named their --out "-o" (-o afile/normal.png: afile is not a directory; session 79)
    (["gbuffer.py", "--resolution", "8", "8", "--out", "afile"], ["--out afile: not a directory"]),
    (["reference_estimator.py", "--probe", "probe.exr", "--spp", "1", "--resolution", "8", "8", "--out", "gone/r"],
     ["--out gone/r: gone is a link to", "which does not exist"]),
    # --runs had no upper bound in these (warpbw bench's is 1000): 2^31 ran until killed
    (["anisotropy_cost.py", "planes.toml", "--zoom", "1", "--size", "8x8", "--runs", "1001"],
     ["--runs 1001: expected at most 1000"]),
    (["compare_mitsuba.py", "--resolution", "16", "--runs", "2147483648"],
     ["--runs 2147483648: expected an integer from 1 to 1000"]),
    (["gmm_precompute_time.py", "--runs", "1001"], ["--runs 1001: expected an integer from 1 to 1000"]),
    (["reference_estimator.py", "--probe", "probe.exr", "--npf", "afile", "--spp", "1", "--resolution", "8", "8",
      "--runs", "1001"], ["--runs: expected an integer from 1 to 1000"]),
], ids=["gbuffer resolution", "reference_estimator resolution", "anisotropy_cost size", "anisotropy_cost nan",
        "anisotropy_cost inf", "dynamic_geometry frames", "filtering_zoom duplicate", "filtering_floor duplicate",
        "brdf_sampling samples", "reference_estimator spp", "mirror_smear budget", "filtering_floor gt-spp",
        "filtering_zoom gt-spp", "dynamic_geometry out", "allocation_ceiling budget", "allocation_ceiling spp",
        "dynamic_geometry budget", "dynamic_geometry size", "validate_bandwidth size", "validate_bandwidth seed",
        "validate_bandwidth size past 16384", "validate_bandwidth nb", "validate_bandwidth nb-diagnostic",
        "validate_bandwidth out", "bench_scenes out", "bench_scenes results", "bunny_on_floor out",
        "bunny_on_floor out under a file", "gbuffer out", "reference_estimator out under a dangling link",
        "anisotropy_cost runs", "compare_mitsuba runs", "gmm_precompute_time runs",
        "reference_estimator runs"])
def test_examples_refuse_values_up_front_naming_their_own_options(tmp_path, argv, needles):
    """each of these failed after loading assets or preparing the scene (a raw traceback, or an error
    naming a parameter or bound the user never gave).  Now: one line naming the option, before any work, and
    nothing written."""
    _example_inputs(tmp_path)
    before = _tree(tmp_path)
    t0 = time.perf_counter()
    example_error(run_example(argv, tmp_path), argv[0], *needles)
    assert _tree(tmp_path) == before
    assert time.perf_counter() - t0 < 60


def test_filtering_floor_refuses_zooms_at_which_no_pixel_filters(tmp_path):
    """on a 16x16 map, --zoom 8 magnifies every pixel (level < 0) and the script wrote a record with
    "zooms": [] and exited 0.  It has nothing to compare there: an error naming the zooms, before the mipmaps are
    built, and no JSON."""
    r = run_example(["filtering_scenes.py", "--out", "fs", "--size", "17"], tmp_path)
    assert r.returncode == 0, r.stderr
    r = run_example(["filtering_floor.py", "fs/carved_disk.toml", "--zoom", "8", "--gt-spp", "64", "--json", "f.json"],
                    tmp_path)
    example_error(r, "filtering_floor.py", "fs/carved_disk.toml: at --zoom 8", "level 0 or above", "larger zooms")
    assert not (tmp_path / "f.json").exists()


def test_filtering_floor_checks_every_scene_before_analysing_the_first(tmp_path):
    """With several scenes, one that cannot be analysed (no normal map) failed only after the scenes before it had
    been analysed (minutes each at real sizes), and no JSON was written for them."""
    r = run_example(["filtering_scenes.py", "--out", "fs", "--size", "17"], tmp_path)
    assert r.returncode == 0, r.stderr
    (tmp_path / "planes.toml").write_text(PLANE_SCENE.replace('normal_map = "map.exr"\n', ""))
    r = run_example(["filtering_floor.py", "fs/carved_disk.toml", "planes.toml", "--zoom", "128", "--gt-spp", "64"],
                    tmp_path)
    example_error(r, "filtering_floor.py", "planes.toml: [material.m] has no normal_map")
    assert r.stdout.strip() == "", r.stdout      # nothing analysed, nothing printed
    # a zoom at which the plane is smaller than a pixel asked for larger zooms
    r = run_example(["filtering_floor.py", "fs/carved_disk.toml", "--zoom", "2048", "--gt-spp", "64"], tmp_path)
    example_error(r, "filtering_floor.py", "at --zoom 2048 no pixel's centre ray hits the plane", "smaller zooms")


def test_gmm_mipmap_defaults_fit_a_small_size(tmp_path):
    """--size 2 passed the size check, then the defaults the user never gave were refused ("--level 3:
    expected 0 to 0", with --level 0 "--texel 1 1: expected ROW and COL from 0 to 0")."""
    # dunes: the default surface, the scales, needs 17 texels (precompute.surfaces.MIN_SURFACE_SIZE)
    for argv in (["--size", "2", "-o", "a.png"], ["--size", "4", "--level", "0", "-o", "b.png"]):
        argv += ["--surface", "dunes"]
        r = run_example(["gmm_mipmap.py", *argv], tmp_path)
        assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    assert (tmp_path / "a.png").is_file() and (tmp_path / "b.png").is_file()


def test_validate_bandwidth_takes_a_relative_data_folder(tmp_path, shared):
    """a relative --data was joined twice ("../shared/data/../shared/data/envmaps/studio.exr: file
    not found"), whether or not it pointed at the data."""
    (tmp_path / "data").symlink_to(shared("envmaps/studio.exr").parents[1], target_is_directory=True)
    r = run_example(["validate_bandwidth.py", "--quick", "--scenes", "sphere-ggx-studio", "--size", "16", "--data",
                     "data", "--out", "v"], tmp_path)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    assert (tmp_path / "v" / "validate_bandwidth.json").is_file()


def test_bench_scenes_help_says_a_merl_file_in_out_is_reused():
    """an existing OUT/MATERIAL.binary is used as a cache without a check; --help now says so."""
    r = run_example(["bench_scenes.py", "--help"], Path.cwd())
    assert r.returncode == 0 and "MATERIAL.binary already there is used as it is" in " ".join(r.stdout.split())


# ------------------------------------------------------------------------------------------ caches and outputs
# (session 50's audit of the on-disk caches and of output-file safety)

def _npz_member_replaced(path: Path, member: str, payload: bytes) -> None:
    """Rewrite the .npz ``path`` with ``member``'s bytes replaced (the archive otherwise as it was)."""
    import zipfile

    with zipfile.ZipFile(path) as z:
        members = {n: z.read(n) for n in z.namelist()}
    members[member] = payload
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        for n, b in members.items():
            z.writestr(n, b)


def _central_field_set(path: Path, member: str, offset: int, fmt: str, value: int) -> None:
    """Set one field of ``member``'s central-directory record (PKWARE APPNOTE 4.3.12: the flags at offset 8, the
    compression method at 10), where zipfile reads them."""
    import struct

    data = bytearray(path.read_bytes())
    at = data.find(b"PK\x01\x02")   # the records' signature; the member's name follows its 46 fixed bytes
    while data[at + 46:at + 46 + len(member)] != member.encode():
        at = data.find(b"PK\x01\x02", at + 4)
        assert at >= 0, member
    struct.pack_into(fmt, data, at + offset, value)
    path.write_bytes(bytes(data))


def _huge_npy() -> bytes:
    """A .npy header declaring 2**40 float32 values, and 64 bytes of them."""
    import io

    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": "<f4", "fortran_order": False, "shape": (2**40,)})
    return buf.getvalue() + bytes(64)


def _deep_json_npy() -> bytes:
    import io

    buf = io.BytesIO()
    np.save(buf, np.array("[" * 100_000 + "]" * 100_000))
    return buf.getvalue()


ASSET_DAMAGE = {   # each was a traceback or a line that named no file, and such a cache entry ended every render
    "a damaged deflate stream": lambda p: damage_deflate_stream(p, "density.npy"),   # a torn sector: zlib.error
    "a member declaring 2**40 values": lambda p: _npz_member_replaced(p, "density.npy", _huge_npy()),
    "a header nested 100,000 deep": lambda p: _npz_member_replaced(p, "__header__.npy", _deep_json_npy()),
    "compression method 99": lambda p: _central_field_set(p, "density.npy", 10, "<H", 99),
    "the encrypted flag": lambda p: _central_field_set(p, "density.npy", 8, "<H", 1),
}


@pytest.fixture(scope="module")
def fake_npf_sampling_entry(tmp_path_factory):
    """The sampling-table cache entry a one-spp render of the fake NPF sphere writes: (its name, its bytes).  Built
    once for the ASSET_DAMAGE cases (the same table file, so the same entry: one render instead of five)."""
    d = tmp_path_factory.mktemp("fake_npf_entry")
    fake_npf_table(d / "npf.bin")
    write_scene(d, material='type = "npf"\ntable = "npf.bin"\nname = "chrome"')
    assert run(["render", "scene.toml", "-o", "a.exr", "--spp", "1", "-q"], d).returncode == 0
    (entry,) = (d / "_cache").glob("sampling-*.npz")
    return entry.name, entry.read_bytes()


@pytest.mark.parametrize("damage", list(ASSET_DAMAGE))
def test_a_damaged_asset_is_refused_by_name_and_a_damaged_cache_entry_rebuilt(tmp_path, damage,
                                                                              fake_npf_sampling_entry):
    """Damage the asset reader let through: a torn sector in a compressed member (a zlib.error traceback), and
    (file audit, session 63) "Unable to allocate 4.00 TiB", naming no file, for a .npy header declaring a huge
    array (numpy allocates before it reads), and RecursionError, NotImplementedError and RuntimeError tracebacks for
    a deeply nested header, an unknown compression method and the zip's encrypted flag.  A table the scene names is
    refused in one line naming it; a cache entry so damaged ended every render (only a WarpbwError takes the
    rebuild path) and is now rebuilt."""
    from precompute.assetfile import read_asset
    from warpbw.sampling import TABLE_FORMAT, TABLE_VERSION

    fake_npf_table(tmp_path / "npf.bin")
    npf = 'type = "npf"\ntable = "npf.bin"\nname = "chrome"'
    write_scene(tmp_path, material=npf)
    name, entry_bytes = fake_npf_sampling_entry   # the entry this scene's render writes (same table file)
    entry = tmp_path / "_cache" / name
    entry.parent.mkdir()
    entry.write_bytes(entry_bytes)
    (tmp_path / "tables.npz").write_bytes(entry_bytes)
    ASSET_DAMAGE[damage](entry)
    with pytest.raises(WarpbwError, match="not a warpbw asset file, or a damaged one"):
        read_asset(entry, TABLE_FORMAT, TABLE_VERSION, "rebuild")
    r = run(["render", "scene.toml", "-o", "b.exr", "--spp", "1", "-q"], tmp_path)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    assert read_asset(entry, TABLE_FORMAT, TABLE_VERSION, "rebuild").arrays["density"].size   # rebuilt
    ASSET_DAMAGE[damage](tmp_path / "tables.npz")
    write_scene(tmp_path, material=npf + '\nsampling = "tables.npz"')
    r = run(["render", "scene.toml", "-o", "out.exr", "--spp", "1"], tmp_path)
    assert_one_line_error(r, "tables.npz", "not a warpbw asset file, or a damaged one",
                          "warpbw-precompute brdf-sampling")
    assert_no_outputs(tmp_path)

@pytest.fixture
def read_only():
    """Make a file or folder read-only for this process: mode 0444 (0555), and where that does not hold (root)
    chattr +i, undone after the test; skips where neither can."""
    made = []

    def make(p: Path) -> Path:
        p.chmod(0o555 if p.is_dir() else 0o444)
        if os.access(p, os.W_OK):
            r = subprocess.run(["chattr", "+i", str(p)], capture_output=True)
            if r.returncode != 0:
                pytest.skip(f"cannot make {p.name} read-only here (root, and chattr +i failed)")
            made.append(p)
        return p

    yield make
    for p in made:
        subprocess.run(["chattr", "-i", str(p)], check=True)


@pytest.mark.parametrize("command", ["render", "bench"])
def test_a_read_only_output_is_refused_before_any_work_even_with_force(tmp_path, read_only, command):
    """With --force, a read-only out.json was found only when it was written: render left the new image beside the
    old record, bench lost its whole record.  Now refused up front; every earlier output is as it was."""
    write_scene(tmp_path)
    first = {"render": ["render", "scene.toml", "-o", "out.exr", "--spp", "1", "-q"],
             "bench": ["bench", "scene.toml", "--json", "out.json", "--spp", "1", "--budgets", "1", "--gt-spp", "2",
                       "--runs", "1", "-q"]}[command]
    assert run(first, tmp_path).returncode == 0
    before = {p.name: p.read_bytes() for p in tmp_path.glob("out.*")}
    read_only(tmp_path / "out.json")
    r = run(first + ["--force"], tmp_path)
    assert_one_line_error(r, "out.json: cannot be overwritten", "make it writable")
    assert {p.name: p.read_bytes() for p in tmp_path.glob("out.*")} == before
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_a_hard_link_to_an_input_is_never_an_output(tmp_path):
    """The rule "never overwrite an input, even with --force" compared resolved paths only: -o a hard link to the
    light probe rewrote the probe (status 0), and --error-map a hard link to the test image replaced it."""
    write_exr(tmp_path / "probe.exr", np.ones((4, 8, 3), np.float32))
    (tmp_path / "hard.exr").hardlink_to(tmp_path / "probe.exr")
    probe = (tmp_path / "probe.exr").read_bytes()
    write_scene(tmp_path, environment='file = "probe.exr"')
    r = run(["render", "scene.toml", "-o", "hard.exr", "--spp", "1", "--force"], tmp_path)
    assert_one_line_error(r, "-o hard.exr: would overwrite", "probe.exr, a file this command reads",
                          "hard.exr is a link to it")
    (tmp_path / "t_link.exr").hardlink_to(tmp_path / "probe.exr")
    r = run(["compare", "probe.exr", "probe.exr", "--error-map", "t_link.exr", "--force"], tmp_path)
    assert_one_line_error(r, "--error-map t_link.exr", "one of the images compared", "t_link.exr is a link to it")
    assert (tmp_path / "probe.exr").read_bytes() == probe


def test_a_write_that_fails_leaves_every_earlier_output(tmp_path, monkeypatch, capsys):
    """A full disk while the PNG was written (after the EXR) left the new EXR, a 0-byte PNG and the old JSON: a
    mixed set.  Now the outputs are written beside and moved into place together, so all stay as they were, the
    message names out.png, and no temporary is left."""
    from PIL import Image

    from warpbw.cli import main as cli_main

    write_scene(tmp_path)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("WARPBW_CACHE", str(tmp_path / "_cache"))
    assert cli_main(["render", "scene.toml", "-o", "out.exr", "--spp", "1", "-q"]) == 0
    before = {p.name: p.read_bytes() for p in tmp_path.glob("out.*")}
    assert sorted(before) == ["out.exr", "out.json", "out.png"]

    def full_disk(self, fp, *args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(Image.Image, "save", full_disk)
    capsys.readouterr()
    assert cli_main(["render", "scene.toml", "-o", "out.exr", "--spp", "4", "--force", "-q"]) == 2
    err = capsys.readouterr().err
    assert "out.png: cannot write PNG" in err and "No space left on device" in err and ".part" not in err, err
    assert {p.name: p.read_bytes() for p in tmp_path.glob("out.*")} == before
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_bench_checks_its_default_ground_truth_cache_before_any_work(tmp_path):
    """--cache was checked up front, the default $WARPBW_CACHE/ground_truth only when the first chunk was written,
    after it was rendered, with a raw errno that did not say where the folder came from."""
    write_scene(tmp_path)
    (tmp_path / "afile").write_text("keep")
    r = run(["bench", "scene.toml", "--json", "out.json"], tmp_path, cache="afile/sub")
    assert_one_line_error(r, "afile is not a directory", "WARPBW_CACHE=afile/sub", "--cache DIR")
    assert_no_outputs(tmp_path)


def test_a_cache_that_cannot_be_written_costs_only_the_rebuild(tmp_path, read_only):
    """The table caches (sampling, BRDF bandwidth, the probe's bandwidth) are an optimisation: a cache folder that
    is read-only or lies under a file, or an entry's name taken by a folder (which aborted the render after the
    build), must still render, and leave the cache as it was."""
    fake_npf_table(tmp_path / "npf.bin")
    write_exr(tmp_path / "probe.exr", np.linspace(0.5, 2.0, 4 * 8 * 3, dtype=np.float32).reshape(4, 8, 3))
    write_scene(tmp_path, environment='file = "probe.exr"', material='type = "npf"\ntable = "npf.bin"\nname = "chrome"')
    (tmp_path / "afile").write_text("keep")
    argv = ["render", "scene.toml", "-o", "out.exr", "--method", "adaptive", "--budget", "1", "--force", "-q"]
    assert run(argv, tmp_path).returncode == 0
    entries = sorted(p.name for p in (tmp_path / "_cache").iterdir())
    assert [e.split("-")[0] for e in entries] == ["bandwidth", "env", "sampling"], entries
    for p in (tmp_path / "_cache").iterdir():   # every entry's name taken by a folder
        p.unlink()
        p.mkdir()
    (tmp_path / "ro").mkdir()
    read_only(tmp_path / "ro")
    for cache in (None, str(tmp_path / "ro"), "afile/sub"):
        r = run(argv, tmp_path, cache=cache)
        assert r.returncode == 0 and not r.stderr.strip(), (cache, r.stderr)
    assert all(p.is_dir() for p in (tmp_path / "_cache").iterdir()) and not list((tmp_path / "ro").iterdir())
    assert (tmp_path / "afile").read_text() == "keep"


def test_an_asset_whose_header_names_no_format_is_refused(tmp_path):
    """An .npz whose JSON header has the right version but no "format" key at all is not a file this reader wrote: it
    must be refused with the rebuild hint, as a file of another format is."""
    from precompute.assetfile import HEADER_KEY, read_asset

    p = tmp_path / "x.npz"
    header = {"version": 3, "source": "s", "source_hash": "h", "params": {}}
    np.savez_compressed(p, **{HEADER_KEY: np.array(json.dumps(header))}, a=np.zeros(3))
    with pytest.raises(WarpbwError, match="rebuild it with: REBUILD"):
        read_asset(p, "warpbw-test-format", 3, "REBUILD")


def test_an_npz_without_a_header_is_not_a_warpbw_asset(tmp_path):
    """An .npz with no header (numpy's KeyError) is "not a warpbw asset file", with the rebuild hint, as a garbage
    file is: a KeyError escaped read_asset, and the cache's rebuild path takes a WarpbwError only."""
    from precompute.assetfile import read_asset

    np.savez(tmp_path / "plain.npz", marginal=np.zeros(3, np.float32))
    got = outcome(read_asset, tmp_path / "plain.npz", "fmt", 1, "REBUILD")
    assert got.startswith("WarpbwError: ") and "not a warpbw asset file" in got and "REBUILD" in got, got


UNPICKLED = []


def _note_unpickling():
    UNPICKLED.append(True)
    return "unpickled"


class _Sentinel:
    """Pickled as a call of _note_unpickling: loading it runs code, as any pickle can."""

    def __reduce__(self):
        return _note_unpickling, ()


def test_an_asset_holding_pickled_objects_is_refused_without_unpickling_them(tmp_path):
    """Assets are "a NumPy .npz archive (no pickles)" (precompute.assetfile): an archive whose array holds objects,
    otherwise a valid asset, is refused as not a warpbw asset, and its pickle never runs (a cache folder is a
    place others can write)."""
    from precompute.assetfile import HEADER_KEY, read_asset

    header = {"format": "fmt", "version": 1, "source": "s", "source_hash": "h", "params": {}}
    np.savez(tmp_path / "x.npz", **{HEADER_KEY: np.array(json.dumps(header))},
             table=np.array([_Sentinel()], dtype=object))
    got = outcome(read_asset, tmp_path / "x.npz", "fmt", 1, "REBUILD")
    assert got.startswith("WarpbwError: ") and "not a warpbw asset file" in got, got
    assert UNPICKLED == []


def _accepted(f, *a):
    """True when the check takes the value, False when it refuses it with its one-line error."""
    return attempt(f, *a)[1] == ""


def test_the_bounds_of_the_integer_and_real_checks_are_inclusive():
    """The limits the checks name are themselves accepted: a seed of 2^32 - 1 ("0 to 4294967295") and a count
    equal to its upper bound pass, one more is refused; the largest float32 (finite, as the kernels take it)
    passes check_real and the next float64 above it is refused."""
    from warpbw.errors import FLOAT32_MAX, SEED_MAX, check_count, check_real, check_seed

    assert SEED_MAX == 4294967295
    assert _accepted(check_seed, 4294967295) and not _accepted(check_seed, 4294967296)
    assert _accepted(check_count, 5, "n", 1, 5) and not _accepted(check_count, 6, "n", 1, 5)
    f32max = float(np.finfo(np.float32).max)
    assert FLOAT32_MAX == f32max
    assert _accepted(check_real, f32max, "x") and _accepted(check_real, -f32max, "x")
    assert not _accepted(check_real, float(np.nextafter(f32max, np.inf)), "x")


def test_coordinate_spacing_exactly_at_the_limit_is_accepted():
    """A frame is refused only where float32 spaces coordinates by *more than* COORD_SPACING_REL_MAX (2^-10) of
    the object's size: at 1024 units float32's spacing is 2^-13, exactly 2^-10 of an object of size 1/8, which is
    accepted; a slightly smaller object is refused."""
    from warpbw.errors import COORD_SPACING_REL_MAX, check_coordinate_spacing

    assert COORD_SPACING_REL_MAX == 2.0 ** -10 and float(np.spacing(np.float32(1024.0))) == 2.0 ** -13
    assert _accepted(check_coordinate_spacing, 1024.0, 0.125, "a sphere")
    assert not _accepted(check_coordinate_spacing, 1024.0, 0.124, "a sphere")


# ------------------------------------------------------------------------------------------ session 54's audit
# (mutation round 6: cli_common, native_output and errors; each test fails when its check is weakened or dropped)


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux's /proc, a folder no file can be made in")
def test_an_existing_cache_folder_that_cannot_be_written_is_refused_before_the_work(tmp_path, monkeypatch, capsys):
    """README: an output folder that cannot be written is refused before the work.  `bench --cache /proc` (a folder
    that exists, in which no file can be made) ran the benchmark and failed on its first ground-truth chunk."""
    import warpbw.bench as bench
    from warpbw.cli import main

    write_scene(tmp_path)
    monkeypatch.chdir(tmp_path)
    capture_call(monkeypatch, bench, "run_bench")
    assert outcome(main, ["bench", "scene.toml", "--json", "b.json", "--cache", "/proc", "-q"]) == "returned 2"
    err = capsys.readouterr().err
    assert "--cache /proc" in err and "cannot write in /proc" in err, err


def test_check_overwrite_counts_the_other_existing_outputs(tmp_path):
    """Three of four outputs exist: the message names the first and counts the two others (counted by hand)."""
    from warpbw.cli_common import check_overwrite

    outs = [tmp_path / n for n in ("o.exr", "o.png", "o.json", "o.mip_level.exr")]
    for p in outs[:3]:
        p.write_text("earlier")
    assert outcome(check_overwrite, outs, False) == \
        f"WarpbwError: {outs[0]}: already exists, as do 2 more outputs of this command (pass --force to overwrite them)"
    for p in outs[1:3]:
        p.unlink()
    assert outcome(check_overwrite, outs, False) == \
        f"WarpbwError: {outs[0]}: already exists (pass --force to overwrite it)"


def test_captured_native_output_returns_what_was_written_to_the_descriptor(capfd):
    """captured_native_output: bytes written to file descriptor 2 (as C code writes them, below Python's sys.stderr)
    inside the block come back as lines, and none reaches the terminal."""
    from warpbw.native_output import captured_native_output

    with captured_native_output(fds=(2,)) as lines:
        os.write(2, b"OpenEXR: first line\nsecond line\n")
    assert lines == ["OpenEXR: first line", "second line"]
    assert "first line" not in capfd.readouterr().err


def test_warps_notice_that_it_will_drop_python_3_10_is_kept_off_stderr_and_no_other_warning(capfd, monkeypatch):
    """Warp 1.19 on Python 3.10 printed "Warp FutureWarning: Support for Python 3.10 is deprecated and will be removed
    in Warp 1.20. ..." at wp.init(), before every command's one error line (10 command-line tests failed there, session
    81).  init_warp_quietly ignores that notice alone.  A stand-in for Warp's init warns as Warp 1.19 does (its
    Runtime.__init__ and LoggerBasic.warning, copied by hand): the notice, then another FutureWarning, which is passed
    on whole; the truth is the stderr Warp's own formatting gives."""
    import types

    import warpbw.native_output as native_output

    def warp_warning(message):   # warp/_src/logger.py: LoggerBasic.warning with its _warp_showwarning_stderr
        with warnings.catch_warnings():
            warnings.showwarning = lambda m, c, *_a, **_k: sys.stderr.write(f"Warp {c.__name__}: {m}\n")
            warnings.warn(message, FutureWarning)

    def init():
        warp_warning("Support for Python 3.10 is deprecated and will be removed in Warp 1.20. Please upgrade to "
                     "Python 3.11 or newer.")
        warp_warning("wp.something is deprecated")

    fake = types.ModuleType("warp")
    fake.init = init
    monkeypatch.setitem(sys.modules, "warp", fake)
    monkeypatch.setattr(native_output, "_warp_initialised", False)
    native_output.init_warp_quietly()
    assert capfd.readouterr().err == "Warp FutureWarning: wp.something is deprecated\n"


def test_two_threads_capturing_at_once_leave_the_descriptors_as_they_were():
    """The descriptors are the process's: two threads that read EXR files at once (a notebook's thread pool, a
    service) each saved the other's redirection as the descriptor to put back, and the last one out left stdout and
    stderr on a deleted temporary file for the rest of the process (4 threads of 200 reads: every run; a print after
    them was lost).  The order forced here: thread a captures, b starts its capture, a ends, then b.  Truth: the
    descriptors' files (device and inode) before and after."""
    import threading

    from warpbw.native_output import captured_native_output

    def ident(fd):
        st = os.fstat(fd)
        return st.st_dev, st.st_ino

    before = {fd: ident(fd) for fd in (1, 2)}
    kept = {fd: os.dup(fd) for fd in (1, 2)}   # to mend the descriptors for the rest of the run if they break
    a_in, b_in, a_out = threading.Event(), threading.Event(), threading.Event()

    def a():
        with captured_native_output():
            a_in.set()
            b_in.wait(0.3)   # b's capture, when it can start before this one ends (it may not)
        a_out.set()

    def b():
        a_in.wait(5)
        with captured_native_output():
            b_in.set()
            a_out.wait(5)    # a ends first

    try:
        threads = [threading.Thread(target=a), threading.Thread(target=b)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(10)
        assert {fd: ident(fd) for fd in (1, 2)} == before
    finally:
        for fd, saved in kept.items():
            os.dup2(saved, fd)
            os.close(saved)


_PRINT_THEN_CAPTURE = """
import sys
from warpbw.native_output import captured_native_output
print("wrote out.exr")            # block-buffered: stdout is a pipe
with captured_native_output() as lines:
    pass
print("captured:", lines, file=sys.stderr)
"""


def test_output_printed_before_a_capture_is_not_swallowed_by_it(tmp_path):
    """A line Python printed before the capture, still in sys.stdout's buffer (stdout a pipe, buffered as by
    default), reaches stdout, not the capture's lines (where it was lost, or passed on as a native warning)."""
    env = dict(os.environ)
    env.pop("PYTHONUNBUFFERED", None)
    r = subprocess.run([sys.executable, "-c", _PRINT_THEN_CAPTURE], cwd=tmp_path, env=env, capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout == "wrote out.exr\n", (r.stdout, r.stderr)
    assert "captured: []" in r.stderr, r.stderr


def test_a_pixel_with_one_non_finite_channel_is_refused():
    """README: every renderer refuses an image with inf or NaN pixels.  A pixel whose red alone is NaN, or whose blue
    alone is inf, is such a pixel: two of the 12 here, counted by hand."""
    from warpbw.errors import check_finite_image

    img = np.zeros((3, 4, 3), np.float32)
    img[0, 1, 0] = np.nan
    img[2, 3, 2] = np.inf
    with pytest.raises(WarpbwError, match=r"^frame: 2 of 12 pixels came out infinite or NaN"):
        check_finite_image(img, "frame")
    check_finite_image(np.zeros((3, 4, 3), np.float32), "frame")   # a finite image passes


def test_a_numpy_bool_is_taken_as_a_flag():
    """check_flag: True or False, a numpy bool too (what indexing a boolean array gives); the string "no", which is
    truthy, is refused."""
    from warpbw.errors import check_flag

    assert check_flag(np.array([True, False])[0], "mis") is True
    assert outcome(check_flag, "no", "mis") == "WarpbwError: mis: expected True or False, got 'no'"


def test_check_real_with_an_open_lower_bound_refuses_the_bound_itself():
    """check_real: >= lo, or > lo with lo_open.  A zoom of 0 (the camera on its look_at point) is refused by it, the
    smallest positive one is not; with a closed bound 0 itself is taken."""
    from warpbw.errors import check_real

    assert outcome(check_real, 0.0, "zoom", 0.0, True) == "WarpbwError: zoom: expected a finite number > 0, got 0.0"
    assert check_real(1e-300, "zoom", 0.0, True) == 1e-300
    assert check_real(0.0, "scale", 0.0, False) == 0.0


def test_gbuffer_example_resolution_default_and_bound(tmp_path, monkeypatch):
    """--help: 'image width and height in pixels (default 512 512)'; the largest accepted side is the scene's
    MAX_RESOLUTION, one more is refused.  The camera is a stand-in: nothing is rendered."""
    from warpbw.scene import MAX_RESOLUTION

    ex = load_example("gbuffer")
    monkeypatch.chdir(tmp_path)
    got = capture_call(monkeypatch, ex, "make_camera")
    monkeypatch.setattr(sys, "argv", ["gbuffer.py"])
    assert outcome(ex.main) == "Handed"
    assert got["_args"][4:6] == (512, 512)
    big = str(MAX_RESOLUTION)
    monkeypatch.setattr(sys, "argv", ["gbuffer.py", "--resolution", big, big])
    assert outcome(ex.main) == "Handed"
    assert got["_args"][4:6] == (MAX_RESOLUTION, MAX_RESOLUTION)
    monkeypatch.setattr(sys, "argv", ["gbuffer.py", "--resolution", str(MAX_RESOLUTION + 1), "8"])
    assert outcome(ex.main) == "exit 2"


def test_gbuffer_example_keeps_every_existing_output_without_force(tmp_path, monkeypatch):
    """Any one of the five outputs existing stops the example before any work (README: nothing is overwritten
    without --force); here normal.png, the first."""
    ex = load_example("gbuffer")
    out = tmp_path / "gb"
    out.mkdir()
    (out / "normal.png").write_bytes(b"mine")
    (tmp_path / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    capture_call(monkeypatch, ex, "build_geometry")
    monkeypatch.setattr(sys, "argv", ["gbuffer.py", "--mesh", str(tmp_path / "tri.obj"), "--out", str(out),
                                      "--resolution", "8", "8"])
    res = outcome(ex.main)
    assert res.startswith("WarpbwError: ") and "normal.png" in res and "--force" in res, res
    assert (out / "normal.png").read_bytes() == b"mine"


def test_gmm_mipmap_example_level_and_texel_ranges(tmp_path, monkeypatch):
    """At --size 16 the levels of at least 2x2 texels are 16, 8, 4 and 2 texels across: --level 0 to 3 (4 is
    refused in one line); at level 2 (4x4 texels) a 2x2 block starts at texel 0 to 2 (2 2 is accepted)."""
    import precompute.gmm_mipmap as gm

    ex = load_example("gmm_mipmap")
    capture_call(monkeypatch, gm, "build_gmm_mipmap")
    out = str(tmp_path / "g.png")
    base = ["-o", out, "--surface", "dunes", "--size", "16"]
    assert outcome(ex.main, base + ["--level", "3"]) == "Handed"
    assert outcome(ex.main, base + ["--level", "4"]) == "exit 2"
    assert outcome(ex.main, base + ["--level", "2", "--texel", "2", "2"]) == "Handed"
    assert outcome(ex.main, base + ["--level", "2", "--texel", "3", "2"]) == "exit 2"


def test_filtering_floor_takes_the_bounds_its_help_states(tmp_path, monkeypatch):
    """--max-anisotropy 'at most 16' (MAX_ANISOTROPY) and --gt-spp 'at least 64' are accepted at the bound; the
    scene loading is a stand-in."""
    from warpbw.filtering import MAX_ANISOTROPY, MIN_GT_SPP

    ff = load_example("filtering_floor")
    p = tmp_path / "s.toml"
    p.write_text("")
    got = capture_call(monkeypatch, ff, "load_checked")
    assert outcome(ff.main, [str(p), "--max-anisotropy", str(MAX_ANISOTROPY)]) == "Handed"
    assert got["_args"][2:] == (MAX_ANISOTROPY,), got["_args"]
    assert outcome(ff.main, [str(p), "--gt-spp", str(MIN_GT_SPP)]) == "Handed"
    assert outcome(ff.main, [str(p), "--max-anisotropy", str(MAX_ANISOTROPY + 1)]) == "exit 2"


def test_filtering_floor_hands_its_options_to_the_analysis(tmp_path, monkeypatch):
    """--gt-spp and --max-anisotropy reach the analysis of every scene (the loading is a stand-in)."""
    ff = load_example("filtering_floor")
    p = tmp_path / "s.toml"
    p.write_text("")
    monkeypatch.setattr(ff, "load_checked", lambda *a, **k: "loaded")
    got = capture_call(monkeypatch, ff, "analyse")
    assert outcome(ff.main, [str(p), "--gt-spp", "100", "--max-anisotropy", "3", "--zoom", "2,4"]) == "Handed"
    assert got["_args"][1:3] == ([2.0, 4.0], 100) and got.get("max_anisotropy") == 3 and got.get("loaded") == "loaded", got


# --------------------------------------------------------------------------------------------------------- asset files
# (mutation round 8: each test fails on a plausible mistake the suite let through)


def test_an_asset_header_holds_every_field_its_docstring_lists(tmp_path):
    """An asset file's header holds what assetfile's docstring lists: "format name, its version, the source asset's
    name, the source's content hash, the parameters it was built with and the warpbw version that wrote it"."""
    from precompute.assetfile import read_asset, write_asset
    from warpbw import __version__

    p = write_asset(tmp_path / "a.npz", "fmt", 3, "src.exr", "hash1", {"x": np.arange(3)}, {"k": 1})
    a = read_asset(p, "fmt", 3, "rebuild")
    assert a.header == {"format": "fmt", "version": 3, "source": "src.exr", "source_hash": "hash1",
                        "params": {"k": 1}, "writer": f"warpbw {__version__}"}
    np.testing.assert_array_equal(a.arrays["x"], np.arange(3))


API_MISUSE = {   # a public function called with the wrong type: numpy's, Python's or pathlib's error, from deep inside
    "build_gmm_mipmap scale '2'": (lambda c: c.build_gmm_mipmap(c.h, scale="2", progress=False), "scale '2'"),
    "build_gmm_mipmap scale None": (lambda c: c.build_gmm_mipmap(c.h, scale=None, progress=False), "scale None"),
    "build_gmm_mipmap strings": (lambda c: c.build_gmm_mipmap([["a", "b"], ["c", "d"]], progress=False),
                                 "height map: expected"),
    "build_gmm_mipmap ragged": (lambda c: c.build_gmm_mipmap([[1, 2], [3]], progress=False), "height map: expected"),
    "build_gmm_mipmap complex": (lambda c: c.build_gmm_mipmap(c.h + 1j, progress=False), "complex numbers"),
    "height_to_normals strings": (lambda c: c.height_to_normals([["a"]]), "height field: expected"),
    "merl_eval a path": (lambda c: c.merl_eval("m.binary", c.up, c.up), "expected a MerlBRDF"),
    "merl_eval a string direction": (lambda c: c.merl_eval(c.merl, "abc", c.up), "wi: expected directions"),
    "npf_eval None": (lambda c: c.npf_eval(None, c.up, c.up), "expected an NPFMaterial"),
    "write_merl strings": (lambda c: c.write_merl(c.tmp / "x.binary", np.full(c.MERL_SHAPE, "a")), "MERL data"),
    "write_merl to None": (lambda c: c.write_merl(None, np.full(c.MERL_SHAPE, 0.1)), "output path"),
    "tabulate_merl of an int": (lambda c: c.tabulate_merl(5, "n"), "takes a function"),
    "tabulate_merl of strings": (lambda c: c.tabulate_merl(lambda wi, wo: "x", "n"), "the BRDF's values"),
    "directional_albedo of an int": (lambda c: c.directional_albedo(5, 0.0), "takes a function"),
    "directional_albedo of strings": (lambda c: c.directional_albedo(lambda wi, wo: "x", 0.0), "the BRDF's values"),
    "directional_albedo of one channel": (lambda c: c.directional_albedo(lambda wi, wo: wi[:, 2], 0.0),
                                          "returned shape"),
    "directional_albedo below the surface": (lambda c: c.directional_albedo(c.lambert, [0.0, 2.0]), "below pi/2"),
    "directional_albedo of NaN": (lambda c: c.directional_albedo(c.lambert, float("nan")), "below pi/2"),
    "directional_albedo of a string view": (lambda c: c.directional_albedo(c.lambert, "abc"), "theta_o"),
    "directional_albedo of no cells": (lambda c: c.directional_albedo(c.lambert, 0.0, n_u=0), "n_u"),
    "read_sampling with a path": (lambda c: c.read_sampling(c.tmp / "t.npz", "m.binary"), "is a path"),
    "read_brdf_bandwidth with a path": (lambda c: c.read_brdf_bandwidth(c.tmp / "b.npz", "m.binary"), "is a path"),
    "write_sampling of None": (lambda c: c.write_sampling(c.tmp / "t.npz", None, c.src), "expected a SamplerTable"),
    "write_gmm_mipmap of None": (lambda c: c.write_gmm_mipmap(c.tmp / "g.gmm", None, "n", "h"),
                                 "expected a GmmMipmap"),
    "write_gmm_mipmap of no levels": (lambda c: c.write_gmm_mipmap(c.tmp / "g.gmm", c.GmmMipmap([]), "n", "h"),
                                      "no levels"),
}


@pytest.mark.parametrize("case", sorted(API_MISUSE))
def test_public_functions_refuse_the_wrong_types_in_one_line(tmp_path, case):
    from types import SimpleNamespace

    from precompute.brdf_bandwidth import read_brdf_bandwidth
    from precompute.brdf_sampling import brdf_source, read_sampling, write_sampling
    from precompute.gmm_mipmap import GmmMipmap, build_gmm_mipmap, write_gmm_mipmap
    from precompute.surfaces import height_to_normals
    from warpbw.io.merl import MERL_SHAPE, merl_eval, read_merl, tabulate_merl, write_merl
    from warpbw.io.npf import npf_eval
    from warpbw.sampling import directional_albedo

    write_merl(tmp_path / "m.binary", np.full(MERL_SHAPE, 0.1))
    c = SimpleNamespace(tmp=tmp_path, h=np.random.default_rng(0).random((8, 8)), up=np.array([[0.0, 0.0, 1.0]]),
                        merl=read_merl(tmp_path / "m.binary"), src=brdf_source(tmp_path / "m.binary"),
                        MERL_SHAPE=MERL_SHAPE, GmmMipmap=GmmMipmap, build_gmm_mipmap=build_gmm_mipmap,
                        height_to_normals=height_to_normals, merl_eval=merl_eval, npf_eval=npf_eval,
                        write_merl=write_merl, tabulate_merl=tabulate_merl, read_sampling=read_sampling,
                        read_brdf_bandwidth=read_brdf_bandwidth, write_sampling=write_sampling,
                        write_gmm_mipmap=write_gmm_mipmap, directional_albedo=directional_albedo,
                        lambert=lambda wi, wo: np.full((len(wi), 3), 0.1))
    call, needle = API_MISUSE[case]
    with pytest.raises(WarpbwError, match=re.escape(needle)) as ei:
        call(c)
    assert "\n" not in str(ei.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.binary"]   # nothing written


def test_bench_of_a_scene_whose_camera_misses_every_object_says_so_before_the_ground_truth(tmp_path):
    """It rendered the ground truth, then said "no pixel is covered by geometry: the error is undefined", naming
    neither the scene nor why."""
    write_scene(tmp_path, obj='shape = "sphere"\ncenter = [50.0, 0.0, 0.0]\nradius = 1.0')
    r = run(["bench", "scene.toml", "--json", "b.json", "--cache", "gt"], tmp_path)
    assert_one_line_error(r, "scene.toml: no pixel shows a sphere or mesh", "the camera misses them")
    assert not (tmp_path / "gt").exists() or not any((tmp_path / "gt").iterdir())   # no ground truth was rendered
    assert_no_outputs(tmp_path, "b")


def test_a_scene_float32_cannot_place_is_named_and_told_what_would_fit(tmp_path):
    """The float32 range and spacing refusals named neither the scene nor what to change: a sphere of radius
    1e-300 at the origin was told to translate the scene (it is too small where it is), one of 1e30 too."""
    write_scene(tmp_path, obj='shape = "sphere"\nradius = 1e-300')
    r = run(["render", "scene.toml", "-o", "out.exr", "--spp", "1"], tmp_path)
    line = assert_one_line_error(r, "scene.toml: the camera and a sphere of radius 1e-300",
                                 "an object of at least 0.000")
    # at the origin already: what would fit comes first, moving the scene last (scene fuzzing, session 63)
    assert line.index("an object of at least") < line.index("the camera nearer the object") < line.index("translated")
    write_scene(tmp_path, obj='shape = "sphere"\nradius = 1e30')
    r = run(["render", "scene.toml", "-o", "out.exr", "--spp", "1"], tmp_path)
    assert_one_line_error(r, "scene.toml: the camera is 1e+30 scene units from the far side of a sphere")
    assert_no_outputs(tmp_path)


def test_an_output_named_only_by_its_suffix_is_told_what_is_missing(tmp_path):
    """-o .exr said "expected a path ending in .exr" of a path that ends so (it is a hidden file's whole name)."""
    write_scene(tmp_path)
    r = run(["render", "scene.toml", "-o", "imgs/.exr", "--spp", "1"], tmp_path)
    assert_one_line_error(r, "-o imgs/.exr: expected a path ending in .exr after a name (such as out.exr)")
    assert_no_outputs(tmp_path)


# ------------------------------------------------------------------------------------- stages driven one at a time
# (session 62's audit of the stage functions called from Python: each case crashed the process, gave a silently
# wrong result, or failed deep inside with another exception)

STAGE_SCENE = SCENE.format(resolution="[24, 16]", environment='procedural = "sky"',
                           object='shape = "sphere"\nradius = 0.8', material='type = "lambert"\nalbedo = 0.5')


@pytest.fixture(scope="module")
def stage_inputs():
    from types import SimpleNamespace

    from warpbw.adaptive import plan_hierarchy
    from warpbw.bandwidth import allocate_samples, bandwidth_pass
    from warpbw.gbuffer import make_camera
    from warpbw.pipeline import prepare_bandwidth, prepare_scene, render_reference
    from warpbw.scene import parse_scene

    prep = prepare_scene(parse_scene(STAGE_SCENE))
    gb = render_reference(prep, spp=1).gbuffer
    tables = prepare_bandwidth(prep)
    buf = bandwidth_pass(gb, prep.camera, prep.materials, prep.env_data, tables)
    level = buf.level.numpy().reshape(16, 24)
    return SimpleNamespace(prep=prep, gb=gb, cam=prep.camera, tables=tables, buf=buf, level=level,
                           spp=np.full((16, 24), 2, np.int32), plan=plan_hierarchy(gb, prep.camera, level),
                           big_cam=make_camera([0, 0, 3], [0, 0, 0], [0, 1, 0], 50.0, 48, 32),
                           allocate_samples=allocate_samples, bandwidth_pass=bandwidth_pass)


def _stage_cases():
    from warpbw import bandwidth, bandwidth_ops, brdf, envmap, filtering, gbuffer, pyramid, shading, upsample
    from warpbw.adaptive import plan_hierarchy, shade_hierarchical
    from warpbw.brdf import MERL_CELLS
    from warpbw.io.merl import MERL_SHAPE

    assert MERL_CELLS * 3 == np.prod(MERL_SHAPE)

    def merl(table):
        return brdf.build_material_table([brdf.MaterialSpec("m", brdf.MERL, merl=table)])

    def shade(c, **kw):
        args = dict(gb=c.gb, materials=c.prep.materials, env_data=c.prep.env_data, spp=1)
        return shading.shade_reference(**{**args, **kw})

    def hier(c, **kw):
        args = dict(gb=c.gb, cam=c.cam, materials=c.prep.materials, env_data=c.prep.env_data, level_map=c.level,
                    spp_map=c.spp)
        return shade_hierarchical(**{**args, **kw})

    def lods(c, level):
        return filtering.fetch_gmm([np.zeros((2, 2, 1, 4))], 0.5, 0.5, level)

    return {   # case: (call, the message's start or a part of it)
        "shade_reference lights=EnvMap (segfault)": (lambda c: shade(c, lights=c.prep.env),
                                                     "shade_reference: lights: expected a Lights"),
        "shade_reference gb=GBufferData": (lambda c: shade(c, gb=c.gb.data), "shade_reference: gb: expected a GBuffer"),
        "shade_reference seed 2**32 (seed 0's samples)": (lambda c: shade(c, seed=2**32), "shade_reference: seed"),
        "shade_reference spp map transposed": (lambda c: shade(c, spp=c.spp.T),
                                               "shade_reference: spp: expected per-pixel integer counts of shape"),
        "shade_hierarchical level_map transposed": (lambda c: hier(c, level_map=c.level.T),
                                                    "level_map: expected an (height, width) = (16, 24) map"),
        "shade_hierarchical spp_map transposed": (lambda c: hier(c, spp_map=c.spp.T), "spp_map: expected an (height"),
        "shade_hierarchical seed -1": (lambda c: hier(c, seed=-1), "shade_hierarchical: seed"),
        "shade_hierarchical plan []": (lambda c: hier(c, plan=[]),
                                       "shade_hierarchical: plan: expected a HierarchyPlan"),
        "shade_hierarchical cam of another size": (lambda c: hier(c, cam=c.big_cam),
                                                   "shade_hierarchical: cam: 48x32, but the G-buffer is 24x16"),
        "plan_hierarchy gb None": (lambda c: plan_hierarchy(None, c.cam, c.level), "plan_hierarchy: gb: expected"),
        "bandwidth_pass cam of another size (b_p halved)": (
            lambda c: c.bandwidth_pass(c.gb, c.big_cam, c.prep.materials, c.prep.env_data, c.tables),
            "bandwidth pass: cam: 48x32, but the G-buffer is 24x16"),
        "bandwidth_pass preconvolved 'yes'": (
            lambda c: c.bandwidth_pass(c.gb, c.cam, c.prep.materials, c.prep.env_data, c.tables, preconvolved="yes"),
            "bandwidth pass: preconvolved: expected True or False"),
        "upsample_level cam of another size": (
            lambda c: upsample.upsample_level(c.gb, c.big_cam, 0, np.zeros((12 * 8, 3)), np.ones(12 * 8, np.int32),
                                              np.ones(24 * 16, np.int32)), "upsample_level: cam: 48x32"),
        "allocate_samples plan of wrong masks": (lambda c: c.allocate_samples(c.buf, 2.0, plan=[np.ones((3, 3), bool)]),
                                                 "plan: expected a HierarchyPlan or up to"),
        "build_geometry zero normals (black)": (
            lambda c: gbuffer.build_geometry([], [gbuffer.MeshSpec(
                vertices=np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32), faces=np.array([[0, 1, 2]]),
                normals=np.zeros((3, 3), np.float32), curvature=np.zeros(3, np.float32), uv=None, material=0)]),
            "build_geometry: meshes[0] normals: expected unit vectors, got lengths from 0 to 0"),
        "build_geometry spheres None": (lambda c: gbuffer.build_geometry(None, []),
                                        "build_geometry: spheres: expected a list of SphereSpec"),
        "allocate_gbuffer width 8.5": (lambda c: gbuffer.allocate_gbuffer(8.5, 8), "allocate_gbuffer: width"),
        "render_gbuffer cam None": (lambda c: gbuffer.render_gbuffer(None, c.prep.geometry),
                                    "render_gbuffer: cam: expected a CameraData"),
        "render_gbuffer curvature 'no'": (lambda c: gbuffer.render_gbuffer(c.cam, c.prep.geometry, curvature="no"),
                                          "render_gbuffer: curvature: expected True or False"),
        "sample_directions seed 2**32": (lambda c: envmap.sample_directions(c.prep.env, 4, seed=2**32),
                                         "seed: expected"),
        "sample_directions of EnvMapData": (lambda c: envmap.sample_directions(c.prep.env_data, 4),
                                            "env: expected an EnvMap"),
        "fetch_gmm level 99 (segfault)": (lambda c: lods(c, 99.0), "level: expected levels from 0 to 0"),
        "fetch_gmm level NaN (segfault)": (lambda c: lods(c, np.nan), "level: expected levels from 0 to 0"),
        "fetch_gmm one array for the levels": (lambda c: filtering.fetch_gmm(np.zeros((2, 2, 1, 4)), 0, 0, 0),
                                               "levels: expected a list"),
        "gmm_ndf params (4, 3) (reshaped)": (lambda c: filtering.gmm_ndf(np.zeros((4, 3)), 0.01, [[0, 0, 1]]),
                                             "params: expected finite (K, 4)"),
        "gmm_ndf h (6, 2) (reshaped)": (lambda c: filtering.gmm_ndf(np.zeros((3, 4)), 0.01, np.zeros((6, 2))),
                                        "h: expected (N, 3)"),
        "eval_brdf of the raw table": (lambda c: brdf.eval_brdf(c.prep.materials.table, 0, [[0, 0, 1]], [[0, 0, 1]]),
                                       "mb: expected MaterialBuffers"),
        "MERL table of NaN": (lambda c: merl(np.full(MERL_SHAPE, np.nan)), "expected finite values"),
        "MERL table of negative values": (lambda c: merl(np.full(MERL_SHAPE, -1.0)), "expected BRDF values from 0 to"),
        "MERL table channels first (scrambled)": (lambda c: merl(np.zeros((3,) + MERL_SHAPE[:3])),
                                                  "expected the RGB channels on the last axis"),
        "albedo 1e39 (inf in float32)": (
            lambda c: brdf.build_material_table([brdf.MaterialSpec("a", brdf.LAMBERT, albedo=(1e39,) * 3)]),
            "albedo: expected three finite numbers >= 0 (within float32)"),
        "upsample_level todo of 2**32 (read 0)": (
            lambda c: upsample.upsample_level(c.gb, c.cam, 0, np.zeros((12 * 8, 3)), np.ones(12 * 8),
                                              np.full(24 * 16, 2**32)), "todo: expected flags of 0 or 1"),
        "upsample_level parent_valid of 0.5 (read 0)": (
            lambda c: upsample.upsample_level(c.gb, c.cam, 0, np.zeros((12 * 8, 3)), np.full(12 * 8, 0.5),
                                              np.ones(24 * 16)), "parent_valid: expected flags of 0 or 1"),
        "upsample_level todo of strings": (
            lambda c: upsample.upsample_level(c.gb, c.cam, 0, np.zeros((12 * 8, 3)), np.ones(12 * 8),
                                              ["a"] * (24 * 16)), "todo: expected"),
        "Pyramid.level 99 (IndexError)": (lambda c: pyramid.build_pyramid(c.level).level(99),
                                          "level: expected an integer from 0 to"),
        "pyramid_shapes None": (lambda c: pyramid.pyramid_shapes(None, 4), "image size must be positive integers"),
        "level_pyramid of floats": (lambda c: pyramid.level_pyramid(np.full((3, 3), 1.5)),
                                    "level_map: expected integer levels"),
        "build_pyramid of strings": (lambda c: pyramid.build_pyramid(np.full((2, 2), "a")), "values: expected numbers"),
        "apply_operator nu of strings": (lambda c: bandwidth_ops.apply_operator("T", [["a", "b"]]), "nu: expected"),
        "transport_matrix 'a'": (lambda c: bandwidth_ops.transport_matrix("a"), "d: expected one number"),
        "curvature_matrix [1, 2]": (lambda c: bandwidth_ops.curvature_matrix([1, 2]), "c: expected one number"),
        "texel_directions 0 wide (empty)": (lambda c: envmap.texel_directions(0, 4), "width: expected"),
        "env_bandwidth_map cache 5": (lambda c: bandwidth.env_bandwidth_map(c.prep.env.pixels, cache=5),
                                      "cache: expected a folder"),
        "env_bandwidth_map source a path": (   # it names the cache file
            lambda c: bandwidth.env_bandwidth_map(c.prep.env.pixels, source="../../x:ab"),
            "source: expected the probe's source digest"),
        "make_bandwidth_tables of strings": (
            lambda c: bandwidth.make_bandwidth_tables([["a"]], np.zeros((1, 16, 16, 16))),
            "environment bandwidth table: expected"),
    }


STAGE_CASES = _stage_cases()


@pytest.mark.parametrize("case", sorted(STAGE_CASES))
def test_stage_functions_refuse_what_would_crash_or_mislead_in_one_line(stage_inputs, case):
    call, needle = STAGE_CASES[case]
    with pytest.raises(WarpbwError, match=re.escape(needle)) as ei:
        call(stage_inputs)
    assert "\n" not in str(ei.value)


def test_options_the_run_would_drop_or_misname_are_refused_in_its_own_words(tmp_path):
    """Options audit, session 64: options a run would not use were accepted without a word (compare --force without
    --error-map, --max-anisotropy with the ground truth, which filters nothing); a mixed scene's ground-truth --spp
    was named by the library's parameter ("spp (ground-truth rays per pixel)"); an empty -o was shown as "-o .", an
    empty scene name as "(str or Path)"; --material on a MERL file said only that it was not an NPF table; --zoom
    1e300 was told it was not a finite number and named no option."""
    from warpbw.io.merl import MERL_SHAPE, write_merl

    write_scene(tmp_path)
    (tmp_path / "planes.toml").write_text(plane_scene_toml(resolution=(8, 8)))
    (tmp_path / "mixed.toml").write_text(plane_scene_toml(resolution=(8, 8)) + (
        '[[object]]\nshape = "sphere"\ncenter = [0.0, 0.5, 0.0]\nradius = 0.3\nmaterial = "d"\n'
        '[material.d]\ntype = "lambert"\nalbedo = 0.5\n'))
    write_exr(tmp_path / "a.exr", np.ones((4, 4, 3), np.float32))
    write_merl(tmp_path / "m.binary", np.full(MERL_SHAPE, 0.1))
    cases = [
        (["compare", "a.exr", "a.exr", "--force"], ["--force", "writes nothing but --error-map"]),
        (["render", "planes.toml", "-o", "o.exr", "--filter", "ground_truth", "--max-anisotropy", "8"],
         ["--max-anisotropy 8", "--filter ground_truth", "filters nothing"]),
        (["render", "mixed.toml", "-o", "o.exr", "--filter", "ground_truth", "--max-anisotropy", "8"],
         ["--max-anisotropy 8", "filters nothing"]),
        (["render", "mixed.toml", "-o", "o.exr", "--filter", "ground_truth", "--spp", "8"],
         ["--spp 8", "--filter ground_truth traces at least 64 rays per pixel"]),
        (["render", "scene.toml", "-o", ""], ["-o/--output", "expected a file name, got an empty one"]),
        (["info", ""], ["scene", "expected a file name, got an empty one"]),
        (["bench-filtering", "planes.toml", "--json", "b.json", "--zoom", "1,1e300"],
         ["--zoom 1e+300", "within float32's range"]),
    ]
    for argv, needles in cases:
        r = run(argv, tmp_path)
        assert_one_line_error(r, *needles)
        assert "(str or Path)" not in r.stderr and "-o ." not in r.stderr, r.stderr
    r = run(["brdf-sampling", "m.binary", "--material", "chrome", "-o", "t.npz"], tmp_path, module="precompute")
    assert_one_line_error(r, "--material chrome: applies to NPF tables", "m.binary is the size of a MERL file",
                          "leave --material out", prog="warpbw-precompute")
    assert_no_outputs(tmp_path)
    assert not any((tmp_path / n).exists() for n in ("o.exr", "b.json", "t.npz"))


def _api_cases():
    """Python API audit, session 65: each public stage function called with bad input (api_scratch/report.md of the
    session).  Each case: (call taking a scratch folder, the refusal's start or a part of it)."""
    from types import SimpleNamespace

    from precompute import brdf_sampling, surfaces
    from warpbw import bandwidth, bandwidth_ops, envmap, filtering, gbuffer, launch, pyramid, sampling, shading
    from warpbw.io import exr, merl

    def lambert(wi, wo):
        return np.full((len(wi), 3), 1.0 / np.pi)

    def table(**kw):
        return sampling.build_sampler_table(lambert, **{"n_theta_o": 2, "n_u": 4, "n_phi": 4, "sub": 1, **kw})

    unit = np.zeros((4, 4, 3))
    unit[..., 2] = 1.0
    nan_normal = unit.copy()
    nan_normal[1, 2] = np.nan
    return {
        "fetch_gmm level 1 the size of level 0 (read at other texels)": (
            lambda d: filtering.fetch_gmm([np.zeros((2, 2, 1, 4)), np.zeros((2, 2, 1, 4))], 0.5, 0.5, 1.0),
            "levels[1]: expected level 0's (2, 2) halved 1 times (rounded up), (1, 1), got (2, 2)"),
        "fetch_gmm a level below 1x1": (
            lambda d: filtering.fetch_gmm([np.zeros((1, 1, 1, 4)), np.zeros((1, 1, 1, 4))], 0.5, 0.5, 0.0),
            "levels: expected at most 1 levels for a level 0 of (1, 1)"),
        "normal_moment_mipmap (H, W) (numpy's broadcast error)": (
            lambda d: filtering.normal_moment_mipmap(np.ones((4, 4))), "normals: expected unit normals (H, W, 3)"),
        "normal_moment_mipmap None (an IndexError)": (
            lambda d: filtering.normal_moment_mipmap(None), "normals: expected unit normals (H, W, 3)"),
        "normal_moment_mipmap a NaN normal (NaN on every level)": (
            lambda d: filtering.normal_moment_mipmap(nan_normal), "1 of 16 are not (the first, texel (1, 2)"),
        "normal_moment_mipmap normals 5 long (means 5 long)": (
            lambda d: filtering.normal_moment_mipmap(5.0 * unit), "normals: expected unit normals (length 1 within"),
        "roughness_variance '0.3' (squared as 0.045)": (
            lambda d: filtering.roughness_variance("0.3"), "m (roughness): expected a finite number >= 0"),
        "roughness_variance NaN": (lambda d: filtering.roughness_variance(np.nan), "m (roughness): expected"),
        "roughness_variance None (float()'s TypeError)": (lambda d: filtering.roughness_variance(None),
                                                         "m (roughness): expected"),
        "build_sampler_table n_u 0 (ZeroDivisionError)": (lambda d: table(n_u=0), "build_sampler_table: n_u"),
        "build_sampler_table n_phi 2.5 (numpy's TypeError)": (lambda d: table(n_phi=2.5), "build_sampler_table: n_phi"),
        "build_sampler_table n_theta_o -1 (numpy's ValueError)": (lambda d: table(n_theta_o=-1),
                                                                 "build_sampler_table: n_theta_o"),
        "build_sampler_table brdf None": (lambda d: sampling.build_sampler_table(None),
                                          "build_sampler_table takes a function (wi, wo)"),
        "build_sampler_table values (N,) (numpy's matmul error)": (
            lambda d: sampling.build_sampler_table(lambda wi, wo: np.ones(len(wi)), n_theta_o=1, n_u=2, n_phi=2),
            "build_sampler_table: the BRDF returned shape"),
        "pack_samplers [None] (an AttributeError)": (lambda d: sampling.pack_samplers([None]),
                                                     "pack_samplers: tables[0]: expected a SamplerTable"),
        "pack_samplers None (packed as no table)": (lambda d: sampling.pack_samplers(None),
                                                    "pack_samplers: tables: expected a list"),
        "pack_samplers tables of two shapes (a ValueError)": (
            lambda d: sampling.pack_samplers([table(), table(n_u=2)]), "pack_samplers: sampling tables of different"),
        "env_signal log of a black map (NaN everywhere)": (lambda d: bandwidth.env_signal(np.zeros((4, 8)), "log"),
                                                           "env_signal: the log signal divides"),
        "nyquist_share NaN heights (share 0)": (lambda d: surfaces.nyquist_share(np.full((4, 4), np.nan)),
                                               "nyquist_share: expected finite heights"),
        "nyquist_share (N,) (an IndexError)": (lambda d: surfaces.nyquist_share(np.ones(8)),
                                              "nyquist_share: expected a non-empty height field (H, W)"),
        "write_false_colour_png log 'no' (a log scale)": (
            lambda d: exr.write_false_colour_png(d / "m.png", np.ones((2, 2)), log="no"),
            "log: expected True or False"),
        "rgb_of an array (an AttributeError)": (lambda d: exr.rgb_of(np.zeros((2, 2, 3))),
                                                "rgb_of: expected an ExrImage"),
        "camera_rays None": (lambda d: gbuffer.camera_rays(None), "camera_rays: cam: expected a CameraData"),
        "check_reach of a scene Camera": (lambda d: gbuffer.check_reach(SimpleNamespace(), None),
                                          "check_reach: cam: expected a CameraData"),
        "ensure_curvature None": (lambda d: gbuffer.ensure_curvature(None), "ensure_curvature: geometry: expected"),
        "build_mip_pyramid of EnvMapData": (lambda d: envmap.build_mip_pyramid(envmap.constant_envmap(1.0).data),
                                            "build_mip_pyramid: env: expected an EnvMap"),
        "covered_pixels None": (lambda d: shading.covered_pixels(None), "covered_pixels: gb: expected a GBuffer"),
        "pixel_angle None": (lambda d: bandwidth.pixel_angle(None), "pixel_angle: cam: expected a CameraData"),
        "allocate_samples None": (lambda d: bandwidth.allocate_samples(None, 4.0),
                                  "allocate_samples: buf: expected a BandwidthBuffer"),
        "zoomed_camera None": (lambda d: filtering.zoomed_camera(None, 2.0), "zoomed_camera: camera: expected"),
        "plane_objects None": (lambda d: filtering.plane_objects(None), "plane_objects: scene: expected a Scene"),
        "sampling_problem None": (lambda d: brdf_sampling.sampling_problem(None),
                                  "sampling_problem: table: expected a SamplerTable"),
        "procedural_sky width 8.5 (drawn 8 wide)": (lambda d: envmap.procedural_sky(8.5, 4),
                                                    "procedural_sky: width: expected an integer >= 1"),
        "procedural_sky sun_radiance 1e39 (inf in float32)": (
            lambda d: envmap.procedural_sky(8, 4, sun_radiance=1e39), "procedural_sky: sun_radiance: expected"),
        "transport_matrix NaN (a matrix of NaN)": (lambda d: bandwidth_ops.transport_matrix(np.nan),
                                                   "d: expected a number, got NaN"),
        "apply_operator d 1e39 (inf in the kernel)": (
            lambda d: bandwidth_ops.apply_operator("T", [[1.0, 1.0]], d=1e39), "parameter d: 1e+39 is beyond float32"),
        "apply_operator nu 1e39 (inf in the kernel)": (
            lambda d: bandwidth_ops.apply_operator("S", [[1e39, 1.0]]), "nu: 1e+39 is beyond float32's range"),
        "curvature_pyramid absolute 'no' (|curvature| taken)": (
            lambda d: pyramid.curvature_pyramid(-np.ones((2, 2)), absolute="no"),
            "curvature_pyramid: absolute: expected True or False"),
        "estimator_variance mis 'no' (MIS's variance)": (
            lambda d: bandwidth.BandwidthBuffer.estimator_variance(SimpleNamespace(variance_mis=1, variance_bis=2),
                                                                   "no"), "estimator_variance: mis: expected True"),
        "tile_ranges tile 0 (range()'s ValueError)": (lambda d: launch.tile_ranges(10, 0), "tile_ranges: tile"),
        "tile_ranges n_items -1 (no tile)": (lambda d: launch.tile_ranges(-1, 4), "tile_ranges: n_items"),
        "merl_eval of tabulate_merl's array (numpy's NotImplementedError)": (
            lambda d: merl.merl_eval(np.zeros((90, 90, 180, 3)), [[0, 0, 1]], [[0, 0, 1]]),
            "merl_eval: brdf is ndarray, expected a MerlBRDF"),
        "merl_eval interpolate 'no' (trilinear)": (
            lambda d: merl.merl_eval(merl.MerlBRDF("m", None, np.zeros((90, 90, 180, 3), np.float32)), [[0, 0, 1]],
                                     [[0, 0, 1]], interpolate="no"), "merl_eval: interpolate: expected True or False"),
        "diffuse_pick NaN diffuse (0.5)": (lambda d: filtering.diffuse_pick((np.nan, 0, 0), (0.5, 0.5, 0.5)),
                                           "diffuse_pick: diffuse: expected three finite numbers >= 0"),
        "diffuse_pick inf f0 (NaN)": (lambda d: filtering.diffuse_pick((0.5, 0.5, 0.5), (np.inf, 0, 0)),
                                      "diffuse_pick: f0: expected three finite numbers >= 0"),
        "gmm_ndf a weight of 1e39 (inf in float32)": (
            lambda d: filtering.gmm_ndf([[1e39, 0.0, 0.0, 0.1]], 0.01, [[0.0, 0.0, 1.0]]),
            "params: expected finite (K, 4) components (a, mu_x, mu_y, s^2 >= 0) within float32's range"),
    }


API_CASES = _api_cases()


@pytest.mark.parametrize("case", sorted(API_CASES))
def test_api_functions_refuse_bad_input_in_one_line(tmp_path, case):
    """Before session 65 each of these was a traceback from inside numpy or the function (ZeroDivisionError,
    AttributeError, numpy's broadcast and matmul errors) or a silently wrong result (NaN, a string squared)."""
    call, needle = API_CASES[case]
    with pytest.raises(WarpbwError, match=re.escape(needle)) as ei:
        call(tmp_path)
    assert "\n" not in str(ei.value)


# In a child, after its imports, with its address space capped 2 GB above what it holds: on the old code the first
# case died of SIGFPE and the second never returned, filling memory (12 GB in four minutes).
_CHILD = """
import resource, sys
import numpy as np
from warpbw import filtering
from warpbw.errors import WarpbwError
held = int(next(l for l in open("/proc/self/status") if l.startswith("VmSize")).split()[1]) * 1024
resource.setrlimit(resource.RLIMIT_AS, (held + 2 * 2**30, resource.getrlimit(resource.RLIMIT_AS)[1]))
try:
    {call}
except WarpbwError as exc:
    print("WarpbwError:", exc)
"""


@pytest.mark.parametrize("call, needle", [
    ("filtering.fetch_gmm([np.zeros((0, 0, 1, 4))], 0.5, 0.5, 0.0)", "levels[0]: expected at least 1x1 texels"),
    ("filtering.normal_moment_mipmap(np.zeros((0, 4, 3)))", "normals: expected unit normals (H, W, 3) of at least 1x1"),
], ids=["fetch_gmm empty level (SIGFPE)", "normal_moment_mipmap empty (endless loop)"])
def test_api_inputs_that_crashed_or_hung_the_process_are_refused(tmp_path, call, needle):
    env = {**os.environ, "WARPBW_CACHE": str(tmp_path)}
    try:
        r = subprocess.run([sys.executable, "-c", _CHILD.format(call=call)], capture_output=True, text=True,
                           timeout=300, env=env, cwd=tmp_path)
    except subprocess.TimeoutExpired:
        pytest.fail(f"{call} did not return within 300 s")
    last = (r.stdout.strip().splitlines() or [""])[-1]   # after Warp's banner
    assert r.returncode == 0 and last.startswith("WarpbwError: ") and needle in last, \
        (r.returncode, r.stdout, r.stderr[-800:])


def test_api_edge_inputs_that_are_valid_still_work():
    """The session 65 checks refuse only what is wrong: no item has no tile (it was an IndexError with costs), a
    1x1 normal map is one level, inf parameters still reach the operators, and float32 unit normals pass."""
    from warpbw.bandwidth_ops import apply_operator
    from warpbw.filtering import normal_moment_mipmap
    from warpbw.launch import tile_ranges

    assert tile_ranges(0, 4, np.zeros(0)) == [] and tile_ranges(0, 4) == []
    (mean, second), = normal_moment_mipmap(np.array([[[0.6, 0.0, 0.8]]], np.float32))
    assert np.allclose(mean, [[[0.6, 0.0, 0.8]]]) and np.allclose(second, [[[0.36, 0.0, 0.0]]])
    # T_d = [[1, 0], [-d, 1]] (002 Fig. 4): an infinite distance shears nu_a to -inf, nu_s unchanged
    assert np.array_equal(apply_operator("T", [[1.0, 1.0]], d=np.inf), [[1.0, -np.inf]])


def test_nyquist_share_is_scale_free_up_to_float64s_top():
    """A checkerboard alternates from texel to texel: all of its variance is at frequency 1/2 (share 1), at any
    height; at 1e300 the variance overflowed, and the check for NaN heights must not refuse it."""
    from precompute.surfaces import nyquist_share

    board = (np.indices((4, 6)).sum(axis=0) % 2).astype(np.float64)
    assert nyquist_share(board) == pytest.approx(1.0)
    assert nyquist_share(1e300 * board) == pytest.approx(1.0)


def _gmm_helper_cases():
    """precompute.gmm_mipmap's public numeric helpers (the module docstring's list; the builder checks its own input
    and calls their unchecked cores), called with bad input: each was a traceback from inside numpy (broadcast,
    index, shift and unpacking errors) or a NaN or silently wrong result.  Each case: (call, the refusal's start)."""
    from precompute import gmm_mipmap as gm

    x = np.random.default_rng(2).normal(0.0, 0.1, (3, 16, 2))           # 3 texels of 16 samples
    a, mu, s2 = np.full((3, 2), 0.5), np.zeros((3, 2, 2)), np.full((3, 2), 0.01)
    nan_x = x.copy()
    nan_x[1, 4, 0] = np.nan
    q = gm.to_moments(a, mu, s2)                                        # (3, 2, 4)
    return {
        "to_moments mu (K,) for a (K,) (numpy's stack error)": (
            lambda: gm.to_moments([1.0], [0.0], [0.1]), "to_moments: mu: expected finite means of shape (1, 2)"),
        "to_moments a variance of -0.1 (a negative second moment)": (
            lambda: gm.to_moments([1.0], [[0.0, 0.0]], [-0.1]), "to_moments: s2: expected finite variances"),
        "to_moments a NaN weight": (lambda: gm.to_moments([np.nan], [[0.0, 0.0]], [0.1]),
                                    "to_moments: a: expected finite weights (..., K) >= 0"),
        "from_moments (K, 3) (numpy's IndexError)": (lambda: gm.from_moments(np.ones((2, 3))),
                                                     "from_moments: q: expected finite moments (..., K, 4)"),
        "from_moments a NaN moment (a NaN mean)": (lambda: gm.from_moments([[0.5, np.nan, 0.0, 0.1]]),
                                                   "from_moments: q: expected finite moments"),
        "filter_moments 3 weights for 2 texels (numpy's tensordot error)": (
            lambda: gm.filter_moments(q[:2], [0.2, 0.3, 0.5]), "filter_moments: weights: expected 2 finite"),
        "filter_moments axis 5 (numpy's AxisError)": (
            lambda: gm.filter_moments(q, [0.5, 0.5, 0.0], axis=5),
            "filter_moments: axis: expected an integer from -3 to 1, not -1 or 2 (the moments)"),
        "filter_moments a NaN weight (NaN moments)": (lambda: gm.filter_moments(q, [0.5, np.nan, 0.5]),
                                                      "filter_moments: weights: expected 3 finite filter weights"),
        "moment_match weights 0 (0/0: NaN)": (lambda: gm.moment_match(a, mu, s2, [0.0, 0.0, 0.0]),
                                              "moment_match: the filtered weight sum w_k a_k is not > 0 at 2 of 2"),
        "moment_match mu (3, 2, 3) (numpy's broadcast error)": (
            lambda: gm.moment_match(a, np.zeros((3, 2, 3)), s2, [1.0, 0.0, 0.0]),
            "moment_match: mu: expected finite means of shape (3, 2, 2)"),
        "moment_match a variance of -1": (lambda: gm.moment_match(a, mu, -s2, [1.0, 0.0, 0.0]),
                                          "moment_match: s2: expected finite variances of shape (3, 2) (a's) > 0"),
        "normal_space a (0, 0, 0) normal (NaN)": (lambda: gm.normal_space([[0.0, 0.0, 1.0], [0.0, 0.0, 0.0]]),
                                                  "normal_space: normals: expected non-zero normals, 1 of 2"),
        "normal_space 2-vectors (projected as if 3-D)": (lambda: gm.normal_space(np.ones((4, 4, 2))),
                                                         "normal_space: normals: expected finite normals (..., 3)"),
        "footprint_samples level -1 (a negative shift count)": (
            lambda: gm.footprint_samples(np.zeros((4, 4, 2)), -1), "footprint_samples: level (of a 4x4 map)"),
        "footprint_samples an (H, W) map (numpy's indexing error)": (
            lambda: gm.footprint_samples(np.zeros((4, 4)), 1),
            "footprint_samples: n2: expected a finite map (H, W, C)"),
        "footprint_samples max_samples -4 (isqrt's ValueError)": (
            lambda: gm.footprint_samples(np.zeros((4, 4, 2)), 1, max_samples=-4), "footprint_samples: max_samples"),
        "kmeans_plus_plus no sample per texel (rng.integers' ValueError)": (
            lambda: gm.kmeans_plus_plus(np.zeros((3, 0, 2)), 2, 0), "kmeans_plus_plus: x: expected finite samples"),
        "kmeans_plus_plus K 0 (no centre, without a word)": (lambda: gm.kmeans_plus_plus(x, 0, 0),
                                                             "kmeans_plus_plus: K (components): expected an integer"),
        "kmeans_plus_plus samples (M, 2) (an unpacking ValueError)": (
            lambda: gm.kmeans_plus_plus(x[0], 2, 0), "kmeans_plus_plus: x: expected finite samples (T, M, 2)"),
        "kmeans_init centres of 2 texels for 3 (numpy's einsum error)": (
            lambda: gm.kmeans_init(x, np.zeros((2, 2, 2))), "kmeans_init: centres: expected finite centres (3, K, 2)"),
        "kmeans_init a NaN sample (a NaN centroid)": (lambda: gm.kmeans_init(nan_x, mu),
                                                      "kmeans_init: x: expected finite samples"),
        "em_fit weights all 0 (NaN responsibilities)": (lambda: gm.em_fit(x, np.zeros((3, 2)), mu, s2),
                                                        "em_fit: a: expected weights of sum > 0 per texel, 3 of 3"),
        "em_fit a NaN sample (NaN fit)": (lambda: gm.em_fit(nan_x, a, mu, s2), "em_fit: x: expected finite samples"),
        "em_fit a variance of 0": (lambda: gm.em_fit(x, a, mu, 0 * s2), "em_fit: s2: expected finite variances"),
        "em_fit prior_sum (3, 2) (numpy's broadcast error)": (
            lambda: gm.em_fit(x, a, mu, s2, 1.0, np.zeros((3, 2)), a), "em_fit: prior_sum: expected finite sums"),
        "em_fit c '1' (a TypeError)": (lambda: gm.em_fit(x, a, mu, s2, "1", mu, a), "em_fit: c (prior weight)"),
        "em_fit c NaN (plain EM, without a word)": (lambda: gm.em_fit(x, a, mu, s2, np.nan, mu, a),
                                                    "em_fit: c (prior weight): expected a finite number >= 0"),
        "em_fit mu (3, 2, 3) (numpy's einsum error)": (lambda: gm.em_fit(x, a, np.zeros((3, 2, 3)), s2),
                                                       "em_fit: mu: expected finite means of shape (3, 2, 2)"),
    }


GMM_HELPER_CASES = _gmm_helper_cases()


@pytest.mark.parametrize("case", sorted(GMM_HELPER_CASES))
def test_gmm_mipmap_helpers_refuse_bad_input_in_one_line(case):
    """Each of precompute.gmm_mipmap's public EM and moment helpers refuses bad input with a one-line WarpbwError
    naming the helper and the parameter (leftovers of the session 65 API audit)."""
    call, needle = GMM_HELPER_CASES[case]
    with pytest.raises(WarpbwError, match=re.escape(needle)) as ei:
        call()
    assert "\n" not in str(ei.value)


def test_the_gmm_mipmap_helpers_still_take_their_edge_inputs():
    """What the checks must not refuse: an empty batch of texels (T = 0), a component of weight 0 beside others, one
    sample per texel, the top level of a map, an axis counted from the end as numpy counts it; each as the module
    docstring's formulas give it."""
    from precompute import gmm_mipmap as gm

    a, mu, s2 = np.array([[1.0, 0.0]]), np.array([[[0.2, -0.1], [0.0, 0.0]]]), np.array([[0.01, 0.02]])
    q = gm.to_moments(a, mu, s2)
    assert np.allclose(q[0, 0], [1.0, 0.2, -0.1, 2 * 0.01 + 0.05]) and np.all(q[0, 1] == 0.0)
    assert np.allclose(gm.filter_moments(np.stack([q, 3 * q]), [0.25, 0.25], axis=-4), q)   # numpy's axis 0
    x = np.array([[[0.3, 0.4]]])                                          # one texel of one sample
    fa, fmu, fs2, _ = gm.em_fit(x, a, mu, s2)
    assert np.allclose(fmu[0, 0], [0.3, 0.4]) and fa[0, 0] == 1.0 and fs2[0, 0] == gm.VARIANCE_FLOOR
    e = gm.em_fit(np.zeros((0, 4, 2)), np.zeros((0, 2)), np.zeros((0, 2, 2)), np.zeros((0, 2)))
    assert [v.shape for v in e[:3]] == [(0, 2), (0, 2, 2), (0, 2)]
    assert gm.footprint_samples(np.zeros((4, 4, 2)), 2).shape == (1, 16, 2)   # the top level: the whole map
    n = gm.normal_space([[0.0, 0.6, 0.8]])
    assert np.allclose(n, [[0.0, 0.6]])


# ------------------------------------------------------------------------------------- warpbw-precompute batch

@pytest.mark.parametrize("argv,needles", [
    (["npf.bin", "--materials", "chrom"], ["npf.bin: unknown NPF material 'chrom'", "close matches: chrome"]),
    (["npf.bin", "--materials", "chrome,,steel"], ["--materials: expected comma-separated names"]),
    (["grey.binary", "--materials", "chrome"], ["--materials: apply to NPF tables, and no source is one"]),
    (["npf.bin", "--materials", "chrome,Chrome"], ["npf.bin:chrome and npf.bin:chrome would both write the tables "
                                                    "named 'chrome'"]),
    (["grey.binary", "sub"], ["grey.binary and sub/grey.binary would both write the tables named 'grey'"]),
    (["notes.txt"], ["notes.txt: not an NPF table (1572864 bytes), a MERL file (a name ending in .binary) or a "
                     "folder of MERL files"]),
    (["missing.bin"], ["missing.bin: no such file or folder"]),
    (["empty"], ["empty: a folder without MERL files"]),
    (["grey.binary", "--tables", "sampling,normals"], ["--tables: expected some of sampling, bandwidth, each once"]),
    (["grey.binary", "--tables", "sampling,sampling"], ["--tables: expected some of sampling, bandwidth, each once"]),
    (["grey.binary", "--json", "rec.txt"], ["--json rec.txt: expected a path ending in .json"]),
    (["grey.binary", "--workers", "0"], ["--workers: expected an integer from 1 to 1024"]),
    # session 77: accepted, recorded in the record, and dropped
    (["grey.binary", "--tables", "sampling", "--lookup", "linear"], ["--lookup linear: applies to the bandwidth "
                                                                     "tables", "--tables sampling builds none"]),
], ids=["unknown material", "empty name", "materials without NPF", "material twice", "one name twice",
        "not a BRDF", "missing", "empty folder", "unknown table", "table twice", "record suffix", "no workers",
        "lookup without bandwidth tables"])
def test_batch_refuses_bad_sources_and_options_before_any_work(tmp_path, argv, needles):
    """Each is one line naming the source or option (unknown names with their close matches), status 2, and no
    output folder made: a batch of 100 BRDFs is not started to fail on the last one's name."""
    from warpbw.io.merl import MERL_SHAPE, write_merl

    fake_npf_table(tmp_path / "npf.bin")
    write_merl(tmp_path / "grey.binary", np.full(MERL_SHAPE, 0.3))
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub/grey.binary").write_bytes((tmp_path / "grey.binary").read_bytes())
    (tmp_path / "notes.txt").write_text("not a BRDF")
    (tmp_path / "empty").mkdir()
    r = run(["batch", *argv, "-o", "out", "-q"], tmp_path, module="precompute")
    assert_one_line_error(r, *needles, prog="warpbw-precompute")
    assert not (tmp_path / "out").exists()


def test_batch_refuses_an_output_folder_that_is_a_file_or_a_source_in_it(tmp_path):
    """-o naming a file is refused before any work; so is a batch whose outputs would replace one of its own BRDF
    files, whatever --force says."""
    from warpbw.io.merl import MERL_SHAPE, write_merl

    write_merl(tmp_path / "grey.binary", np.full(MERL_SHAPE, 0.3))
    (tmp_path / "out").write_text("a file")
    r = run(["batch", "grey.binary", "-o", "out", "-q"], tmp_path, module="precompute")
    assert_one_line_error(r, "-o out: not a directory", prog="warpbw-precompute")
    assert (tmp_path / "out").read_text() == "a file"
    (tmp_path / "t").mkdir()
    (tmp_path / "t/grey.sampling.npz").symlink_to(tmp_path / "grey.binary")    # an output that is the source
    before = (tmp_path / "grey.binary").read_bytes()
    r = run(["batch", "grey.binary", "-o", "t", "--tables", "sampling", "--force", "-q"], tmp_path,
            module="precompute")
    assert_one_line_error(r, "t/grey.sampling.npz", "grey.binary, a BRDF file of the batch", prog="warpbw-precompute")
    assert (tmp_path / "grey.binary").read_bytes() == before


def test_batch_without_dask_says_how_to_install_it(tmp_path, monkeypatch):
    """Dask is an optional dependency: without it the batch is refused in one line that says what to install."""
    import builtins

    from precompute.batch import BatchItem, run_batch

    real_import = builtins.__import__

    def no_dask(name, *a, **kw):
        if name == "dask" or name.startswith("dask."):
            raise ImportError("No module named 'dask'")
        return real_import(name, *a, **kw)

    monkeypatch.setattr(builtins, "__import__", no_dask)
    with pytest.raises(WarpbwError, match=r'not installed: pip install -e "\.\[batch\]"'):
        run_batch([BatchItem("x.binary", None, "x")], tmp_path / "out")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("kw,needle", [
    ({"items": []}, "items: expected at least one BRDF"),
    ({"workers": 0}, "workers: expected an integer >= 1, got 0"),
    ({"workers": True}, "workers: expected an integer >= 1, got True"),
    ({"scheduler": "cluster"}, "scheduler: expected one of processes, threads, sync (or a Dask client), got 'cluster'"),
    ({"tables": ()}, "tables: expected some of sampling, bandwidth, each once, got none"),
])
def test_run_batch_refuses_bad_arguments_before_any_work(tmp_path, kw, needle):
    """The Python entry of the batch names its parameter, as the command names its option; no folder is made."""
    from precompute.batch import BatchItem, run_batch

    args = {"items": [BatchItem("x.binary", None, "x")], "out_dir": tmp_path / "out", **kw}
    with pytest.raises(WarpbwError, match=re.escape(needle)):
        run_batch(**args)
    assert not (tmp_path / "out").exists()


def test_a_bandwidth_file_built_for_another_lookup_than_the_materials_is_refused(tmp_path, monkeypatch):
    """The renderer asks for the nu_rho table of the BRDF its material shades, read with the material's ``lookup``
    (precompute.brdf_bandwidth, "Lookup"): a scene's ``bandwidth = "bw.npz"`` built for NPF's default (linear, as
    ``warpbw-precompute brdf`` builds without --lookup) under a material of ``lookup = "nearest"`` is refused in one
    line naming the file, both lookups and the command that rebuilds it; the same file under NPF's default lookup
    is read.  Without a file the table is built for the nearest lookup and cached apart from
    the linear one, while the sampling tables keep their one lookup-free entry."""
    from precompute.brdf_bandwidth import VERSION, write_brdf_bandwidth
    from precompute.brdf_sampling import brdf_source
    from warpbw.pipeline import render_adaptive
    from warpbw.sampling import TABLE_VERSION
    from warpbw.scene import file_digest, load_scene

    cache = tmp_path / "cache"
    monkeypatch.setenv("WARPBW_CACHE", str(cache))
    npf = fake_npf_table(tmp_path / "npf.bin")
    bw = write_brdf_bandwidth(tmp_path / "bw.npz", np.full((16, 16, 16), 2.0, np.float32), brdf_source(npf, "chrome"))
    lines = ["[camera]", "position = [0.0, 0.0, 3.0]", "look_at = [0.0, 0.0, 0.0]", "fov = 50.0", "resolution = [8, 8]",
             "[environment]", 'procedural = "sky"', "[[object]]", 'shape = "sphere"', "radius = 0.8", 'material = "m"',
             "[material.m]", 'type = "npf"', 'table = "npf.bin"', 'name = "chrome"']
    for name, extra in (("nearest.toml", ['bandwidth = "bw.npz"', 'lookup = "nearest"']),
                        ("linear.toml", ['bandwidth = "bw.npz"']), ("built.toml", ['lookup = "nearest"'])):
        (tmp_path / name).write_text("\n".join(lines + extra))
    said = attempt(render_adaptive, load_scene(tmp_path / "nearest.toml"), budget=2.0)[1]
    assert "\n" not in said and said.startswith(f"{bw}: a nu_rho table of 'npf.bin:chrome' read with the linear "
                                                "lookup, expected the nearest lookup the material shades with"), said
    assert said.endswith(f"(rebuild it with: warpbw-precompute brdf {npf} --material chrome --lookup nearest -o OUT "
                         "--force)"), said
    rec = render_adaptive(load_scene(tmp_path / "linear.toml"), budget=2.0).stats["assets"]["material.m"]
    assert rec["bandwidth"] == "file" and rec["bandwidth_file"] == str(bw)
    rec = render_adaptive(load_scene(tmp_path / "built.toml"), budget=2.0).stats["assets"]["material.m"]
    assert rec["bandwidth"] == "built"
    key = f"{file_digest(npf)}-chrome"
    assert sorted(p.name for p in cache.glob("sampling-*")) == [f"sampling-{key}-v{TABLE_VERSION}.npz"]
    assert sorted(p.name for p in cache.glob("bandwidth-*")) == [f"bandwidth-{key}-lookup-nearest-v{VERSION}.npz"]


# ------------------------------------------------------------------------ session 77: asset headers, info, --resume

def _asset_header_edited(src: Path, dst: Path, edit) -> Path:
    """A copy of the asset file ``src`` whose JSON header is ``edit(header)`` (a dict changed in place), written with
    NumPy alone: a damaged or hand-edited header."""
    with np.load(src) as z:
        members = {k: z[k] for k in z.files}
    header = json.loads(str(members["__header__"]))
    edit(header)
    members["__header__"] = np.array(json.dumps(header))
    with open(dst, "wb") as f:
        np.savez_compressed(f, **members)
    return dst


@pytest.mark.parametrize("params", [None, [128], "resolution 128"], ids=["null", "list", "text"])
def test_an_asset_whose_header_params_are_no_table_is_refused_in_one_line(tmp_path, params):
    """A header's ``params`` that are no JSON object (null, a list, text) gave an AttributeError from inside the nu_rho
    table's reader: a traceback from an adaptive render naming the table, and from ``warpbw-precompute info`` (session
    77's fuzzing).  Every reader refuses it in one line naming the file, and info says it is not read."""
    from precompute.brdf_bandwidth import read_brdf_bandwidth, write_brdf_bandwidth
    from precompute.brdf_sampling import brdf_source, read_sampling, write_sampling

    source = brdf_source(fake_npf_table(tmp_path / "npf.bin"), "chrome")
    bw = write_brdf_bandwidth(tmp_path / "bw.npz", np.full((16, 16, 16), 2.0, np.float32), source)
    sp = write_sampling(tmp_path / "sp.npz", uniform_sampler_table(), source)
    for src, reader in ((bw, read_brdf_bandwidth), (sp, read_sampling)):
        bad = _asset_header_edited(src, tmp_path / f"bad_{src.name}", lambda h: h.update(params=params))
        said = attempt(reader, bad, source)[1]
        assert said.startswith(f"{bad}: a ") and "header records params" in said and "\n" not in said, said
        r = run(["info", bad.name], tmp_path, module="precompute")
        assert "Traceback" not in r.stderr and r.returncode == 0, r.stderr   # a file it describes, not one it cannot
        assert "  read      no: its header's params are no JSON object" in r.stdout, r.stdout


def test_a_nu_rho_table_whose_header_records_no_resolution_is_refused_not_read_unbounded(tmp_path):
    """A nu_rho table's bandwidths are bounded by the resolution its header records (nu_rho_max); a header without
    it, or with one that is no integer, skipped the bound: a table of 3e38 was read, and the adaptive frame refused
    "the bandwidth pass's variance overflowed ... lower [environment] scale or the map's values", naming neither the
    table nor its header (session 77).  Such a table is refused naming its file; 128.0 is 128."""
    from precompute.brdf_bandwidth import read_brdf_bandwidth, write_brdf_bandwidth
    from precompute.brdf_sampling import brdf_source

    source = brdf_source(fake_npf_table(tmp_path / "npf.bin"), "chrome")
    ok = write_brdf_bandwidth(tmp_path / "ok.npz", np.full((16, 16, 16), 2.0, np.float32), source)
    huge = {"nu_rho": np.full((16, 16, 16), 3e38, np.float32)}

    def edited(name, resolution, arrays=None):
        def edit(h):
            if resolution is None:
                del h["params"]["resolution"]
            else:
                h["params"]["resolution"] = resolution
        p = _asset_header_edited(ok, tmp_path / name, edit)
        if arrays is not None:
            with np.load(p) as z:
                members = {k: z[k] for k in z.files}
            np.savez_compressed(p, **{**members, **arrays})
        return p

    for name, resolution in (("none.npz", None), ("text.npz", "128"), ("zero.npz", 0), ("bool.npz", True)):
        p = edited(name, resolution, huge)
        said = attempt(read_brdf_bandwidth, p, source)[1]
        assert said.startswith(f"{p}: its header records resolution ") and "an integer >= 16" in said, said
    p = edited("float.npz", 128.0, huge)
    assert "beyond the 32 an analysis at resolution 128 gives" in attempt(read_brdf_bandwidth, p, source)[1]
    np.testing.assert_array_equal(read_brdf_bandwidth(edited("float_ok.npz", 128.0), source), 2.0)


def test_info_says_which_named_tables_and_mipmaps_a_render_refuses(tmp_path, capsys):
    """``warpbw info`` said "builder settings current" of a precomputed file a material names that the render then
    refuses (session 76 mended it for a nu_rho table of another lookup): a table of another BRDF, a file of another
    kind than its key reads (a nu_rho table as sampling =), a GMM mipmap of another normal map or fitted with other
    options.  Truth: the renderer's own readers, given the material's source (read_sampling, read_brdf_bandwidth with
    brdf_source; warpbw.filtering.check_gmm_files), refuse exactly the files info flags, and read the others."""
    from conftest import plane_scene_toml
    from precompute.brdf_bandwidth import read_brdf_bandwidth, write_brdf_bandwidth
    from precompute.brdf_sampling import brdf_source, read_sampling, write_sampling
    from precompute.gmm_mipmap import build_gmm_mipmap, load_source, write_gmm_mipmap
    from warpbw.cli import main as cli_main
    from warpbw.filtering import check_gmm_files
    from warpbw.scene import load_scene

    npf = fake_npf_table(tmp_path / "npf.bin")
    for name in ("chrome", "nylon"):
        src = brdf_source(npf, name)
        write_sampling(tmp_path / f"{name}.sp.npz", uniform_sampler_table(), src)
        write_brdf_bandwidth(tmp_path / f"{name}.bw.npz", np.full((16, 16, 16), 2.0, np.float32), src)
    sphere = ["[camera]", "position = [0.0, 0.0, 3.0]", "look_at = [0.0, 0.0, 0.0]", "fov = 50.0",
              "resolution = [8, 8]", "[environment]", 'procedural = "sky"', "[[object]]", 'shape = "sphere"',
              "radius = 0.8", 'material = "m"', "[material.m]", 'type = "npf"', 'table = "npf.bin"', 'name = "chrome"']

    def info_of(scene: Path, path: Path) -> tuple:
        assert cli_main(["info", str(scene), "--method", "adaptive", "--json"]) == 0
        (a,) = [a for a in json.loads(capsys.readouterr().out)["assets"] if a["path"] == str(path)]
        assert cli_main(["info", str(scene), "--method", "adaptive"]) == 0
        line = next(ln for ln in capsys.readouterr().out.splitlines() if str(path) in ln)
        assert ("a render refuses it" in line) == ("refused" in a) != ("builder settings current" in line), line
        return a.get("refused"), line

    source = brdf_source(npf, "chrome")
    for key, file, reader in (("sampling", "chrome.sp.npz", read_sampling), ("sampling", "nylon.sp.npz", read_sampling),
                              ("sampling", "chrome.bw.npz", read_sampling),
                              ("bandwidth", "chrome.bw.npz", read_brdf_bandwidth),
                              ("bandwidth", "nylon.bw.npz", read_brdf_bandwidth),
                              ("bandwidth", "chrome.sp.npz", read_brdf_bandwidth)):
        (tmp_path / "s.toml").write_text("\n".join(sphere + [f'{key} = "{file}"']))
        refused = attempt(reader, tmp_path / file, source)[1] != ""
        said, line = info_of(tmp_path / "s.toml", tmp_path / file)
        assert (said is not None) == refused, (key, file, line)
        if refused:
            assert ("nylon" in said) == ("nylon" in file) and ("warpbw-precompute brdf" in said), said
    # GMM mipmaps of a 8 x 8 height field: of the material's map, of another map, with other options
    from warpbw.io.exr import write_exr

    rng = np.random.default_rng(0)
    for name in ("a", "b"):
        write_exr(tmp_path / f"{name}.exr", rng.random((8, 8, 1)).astype(np.float32) * 0.05, ["Y"])
    for name, map_name, kw in (("ok", "a", {}), ("other_map", "b", {}), ("k2", "a", {"components": 2}),
                               ("prior", "a", {"prior": 3.0}), ("scale", "a", {"scale": 2.0}),
                               ("unaligned", "a", {"unaligned": True})):
        data, source_name, digest = load_source(str(tmp_path / f"{map_name}.exr"))
        mip = build_gmm_mipmap(data, progress=False, **kw)
        write_gmm_mipmap(tmp_path / f"{name}.gmm.npz", mip, source_name, digest)
    for name in ("ok", "other_map", "k2", "prior", "scale", "unaligned"):
        scene = tmp_path / "p.toml"
        scene.write_text(plane_scene_toml(material_extra=f'normal_map = "a.exr"\ngmm = "{name}.gmm.npz"\n'))
        refused = attempt(check_gmm_files, load_scene(scene), "gmm_aligned")[1] != ""
        assert refused == (name != "ok"), name
        assert cli_main(["info", str(scene), "--json"]) == 0
        (a,) = [a for a in json.loads(capsys.readouterr().out)["assets"] if a["path"].endswith(f"{name}.gmm.npz")]
        assert ("refused" in a) == refused, (name, a)


def test_batch_resume_keeps_a_file_in_the_records_place_that_is_no_batch_record(tmp_path):
    """``--resume`` keeps an earlier batch's tables and refuses another file in their place unless ``--force`` is given
    too; the record's place was not checked so: a JSON of the user's, or text, named by --json (or OUT/batch.json)
    was replaced without --force (session 77).  It is refused before any work; an earlier batch's record is
    replaced, and with --force anything is."""
    fake_npf_table(tmp_path / "npf.bin")
    (tmp_path / "out").mkdir()
    args = ["batch", "npf.bin", "--materials", "chrome", "--tables", "sampling", "--scheduler", "sync", "-o", "out",
            "-q", "--resume"]
    for text in ('{"mine": 1}\n', "notes\n", "\xff\xfe"):
        (tmp_path / "out/batch.json").write_text(text)
        r = run(args, tmp_path, module="precompute")
        assert_one_line_error(r, "--json out/batch.json: exists and is not the record of a batch",
                              "pass --force as well", prog="warpbw-precompute")
        assert (tmp_path / "out/batch.json").read_text() == text and not (tmp_path / "out/chrome.sampling.npz").exists()
    r = run([*args, "--force"], tmp_path, module="precompute")
    assert r.returncode == 0, r.stderr
    assert json.loads((tmp_path / "out/batch.json").read_text())["format"] == "warpbw-precompute-batch"
    r = run(args, tmp_path, module="precompute")   # the record of the batch before: replaced, its table kept
    assert r.returncode == 0 and "1 kept" in r.stdout, r.stdout + r.stderr


def test_an_error_map_beyond_float32_is_refused_not_written_with_infinities(tmp_path):
    """``warpbw compare --error-map`` of a test image near float32's top (3e38) against an ordinary reference: the
    per-pixel relative squared error (about 1e78) was cast to the float32 EXR as inf, with numpy's "overflow
    encountered in cast" as the only word (session 77).  Refused in one line naming --error-map; nothing written.
    Truth: the error's formula, (t - r)^2 / (r^2 + 0.01), in float64 by hand."""
    rng = np.random.default_rng(0)
    ref = np.concatenate([rng.random((4, 6, 3)), np.ones((4, 6, 1))], -1).astype(np.float32)
    big = ref.copy()
    big[..., :3] = 3e38
    write_exr(tmp_path / "ref.exr", ref, ["R", "G", "B", "A"])
    write_exr(tmp_path / "big.exr", big, ["R", "G", "B", "A"])
    top = float(np.max(np.mean((3e38 - ref[..., :3].astype(np.float64)) ** 2
                               / (ref[..., :3].astype(np.float64) ** 2 + 0.01), -1)))
    assert top > 3.4028234663852886e38
    r = run(["compare", "big.exr", "ref.exr", "--error-map", "err.exr"], tmp_path)
    assert_one_line_error(r, "--error-map err.exr: the per-pixel relative squared error reaches "
                          f"{top:.3g}, beyond the 3.4e+38 a float32 EXR holds", "nothing written")
    assert not (tmp_path / "err.exr").exists() and not (tmp_path / "err.png").exists()
    r = run(["compare", "ref.exr", "big.exr", "--error-map", "err.exr"], tmp_path)   # errors near 1: written
    assert r.returncode == 0 and "every error is 1" in r.stdout, r.stdout + r.stderr


# A child, as above: on the old code each MIS, BRDF-sampling or bandwidth-pass call below died of a segfault (its kernel
# read the environment's empty sampling arrays, or a MERL material's sampler past the empty tables).
_NO_SAMPLING_CHILD = """
import sys
import numpy as np
from warpbw.errors import WarpbwError
from warpbw.gbuffer import render_gbuffer
from warpbw.io.exr import write_exr
from warpbw.pipeline import prepare_bandwidth, prepare_scene
from warpbw.scene import parse_scene
from warpbw.shading import shade_reference
from warpbw.bandwidth import bandwidth_pass
sky = np.ones((8, 16, 3), np.float32)
sky[1:3, 4:6] = 40.0
write_exr("sky.exr", sky)
prep = prepare_scene(parse_scene(sys.argv[1], ".", "scene.toml"), sampling=False)
gb = render_gbuffer(prep.camera, prep.geometry)
plain = shade_reference(gb, prep.materials, prep.env.lookup_data, 2, mis=False)   # looks the radiance up alone
print("plain", np.isfinite(plain.radiance.numpy()).all() and plain.radiance.numpy().max() > 0, prep.env.has_sampling)
tables = prepare_bandwidth(prep)
from warpbw.brdf import MERL, MERL_CELLS, MaterialSpec, build_material_table
lights_only = build_material_table([MaterialSpec("m", MERL, merl=np.full((MERL_CELLS, 3), 0.1, np.float32))],
                                   sampling=False)   # for directional lights alone: no sampling table
for name, call in [("mis", lambda: shade_reference(gb, prep.materials, prep.env.lookup_data, 2, mis=True)),
                   ("pass", lambda: bandwidth_pass(gb, prep.camera, prep.materials, prep.env.lookup_data, tables)),
                   ("brdf", lambda: shade_reference(gb, lights_only, prep.env.data, 2)),
                   ("brdf-pass", lambda: bandwidth_pass(gb, prep.camera, lights_only, prep.env.data, tables))]:
    try:
        call()
        print(name, "returned")
    except WarpbwError as exc:
        print(name, "WarpbwError:", exc)
"""


def test_a_sampling_pass_refuses_an_environment_or_material_table_without_its_sampling_tables(tmp_path):
    """``EnvMap.lookup_data`` of a map loaded with ``sampling=False`` (``prepare_scene(scene, sampling=False)``) is
    documented for radiance look-ups alone; given to ``shade_reference`` with MIS or to ``bandwidth_pass``, whose
    kernels sample the environment, it crashed the process (a segfault reading its empty CDFs).  Now a one-line error
    naming the pass and what to pass instead; the look-up alone still renders, and builds no distribution.  So for a
    MERL material packed without its sampling table (``build_material_table(..., sampling=False)``, documented for
    directional lights alone) under an environment: its sampler index read past the empty tables."""
    toml = ('[camera]\nposition = [0.0, 0.0, 3.0]\nlook_at = [0.0, 0.0, 0.0]\nup = [0.0, 1.0, 0.0]\nfov = 40.0\n'
            'resolution = [8, 6]\n[environment]\nfile = "sky.exr"\n[[object]]\nshape = "sphere"\n'
            'center = [0.0, 0.0, 0.0]\nradius = 0.8\nmaterial = "m"\n[material.m]\ntype = "lambert"\n'
            'albedo = [0.5, 0.5, 0.5]\n')
    r = subprocess.run([sys.executable, "-c", _NO_SAMPLING_CHILD, toml], capture_output=True, text=True, timeout=300,
                       env={**os.environ, "WARPBW_CACHE": str(tmp_path / "cache")}, cwd=tmp_path)
    out = r.stdout.splitlines()
    assert r.returncode == 0, (r.returncode, r.stdout, r.stderr[-800:])
    assert "plain True False" in out, r.stdout
    for name, where in (("mis", "shade_reference"), ("pass", "bandwidth pass")):
        line = next((ln for ln in out if ln.startswith(f"{name} ")), "")
        assert line.startswith(f"{name} WarpbwError: {where}: env_data: this pass samples the environment"), r.stdout
        assert "EnvMap's .data" in line
    # the same crash from a MERL material packed without its sampling table (for lights alone) under an environment
    for name, where in (("brdf", "shade_reference"), ("brdf-pass", "bandwidth pass")):
        line = next((ln for ln in out if ln.startswith(f"{name} ")), "")
        assert line.startswith(f"{name} WarpbwError: {where}: materials: material 0 ('m') was packed without its "
                               "sampling table"), r.stdout


def _flag_cases():
    """Calls given a truthy string (or 0, or None) for a flag of a function added or changed since session 65, and the
    parameter the refusal must name."""
    from precompute.batch import batch_items, check_outputs, run_batch
    from warpbw import bandwidth, brdf, envmap, gbuffer, pipeline
    from warpbw.scene import parse_scene

    def scene(tmp_path):
        return parse_scene(write_scene(tmp_path).read_text(), tmp_path, "scene.toml")

    def batch_with_an_output(tmp_path):   # one table already there: only --force or --resume goes past it
        items = batch_items([fake_npf_table(tmp_path / "npf.bin")], ["chrome"])
        (tmp_path / "out").mkdir()
        (tmp_path / "out" / "chrome.sampling.npz").write_bytes(b"an earlier table")
        return items, tmp_path / "out"

    lambert = brdf.MaterialSpec("m", brdf.LAMBERT, albedo=(0.5, 0.5, 0.5))
    return {
        "prepare_scene sampling 'no'": (lambda t: pipeline.prepare_scene(scene(t), sampling="no"),
                                        "prepare_scene: sampling: expected True or False, got 'no'"),
        "prepare_scene progress 'no'": (lambda t: pipeline.prepare_scene(scene(t), progress="no"),
                                        "prepare_scene: progress: expected True or False"),
        "load_envmap sampling 0": (lambda t: envmap.load_envmap(write_exr(t / "e.exr", np.ones((4, 8, 3), np.float32))
                                                                or t / "e.exr", sampling=0),
                                   "load_envmap: sampling: expected True or False, got 0"),
        "load_environment sampling None": (lambda t: envmap.load_environment(scene(t).environment, sampling=None),
                                           "load_environment: sampling: expected True or False, got None"),
        "build_material_table sampling 'no'": (lambda t: brdf.build_material_table([lambert], sampling="no"),
                                               "build_material_table: sampling: expected True or False"),
        "make_gbuffer_kernel attributes 'no'": (lambda t: gbuffer.make_gbuffer_kernel(True, False, attributes="no"),
                                                "make_gbuffer_kernel: attributes: expected True or False"),
        "make_gbuffer_kernel has_mesh 'no'": (lambda t: gbuffer.make_gbuffer_kernel(True, "no"),
                                              "make_gbuffer_kernel: has_mesh: expected True or False"),
        "load_kernels relative 'no'": (lambda t: bandwidth.load_kernels(relative="no"),
                                       "load_kernels: relative: expected True or False"),
        "check_outputs force 'no'": (lambda t: check_outputs(*batch_with_an_output(t), tables=("sampling",),
                                                             force="no"),
                                     "force: expected True or False, got 'no'"),
        "run_batch resume 'no'": (lambda t: run_batch(*batch_with_an_output(t), tables=("sampling",),
                                                      scheduler="sync", resume="no", progress=False),
                                  "resume: expected True or False, got 'no'"),
        "run_batch progress 'yes'": (lambda t: run_batch(batch_items([fake_npf_table(t / "npf.bin")], ["chrome"]),
                                                         t / "out", tables=("sampling",), scheduler="sync",
                                                         progress="yes"),
                                     "progress: expected True or False, got 'yes'"),
    }


FLAG_CASES = _flag_cases()


@pytest.mark.parametrize("case", sorted(FLAG_CASES))
def test_the_newer_functions_flags_take_true_or_false_alone(tmp_path, case):
    """The README says the stage functions check their flags (True or False); the ``sampling``, ``attributes``,
    ``relative``, ``force``, ``resume`` and ``progress`` flags added since took any object for its truth: ``force="no"``
    let ``precompute.batch`` replace the tables a batch had written (and ``resume="no"`` kept them), ``sampling="no"``
    built a sampling distribution and ``sampling=0`` packed a MERL material without its table."""
    call, needle = FLAG_CASES[case]
    with pytest.raises(WarpbwError, match=re.escape(needle)) as ei:
        call(tmp_path)
    assert "\n" not in str(ei.value)


@pytest.mark.parametrize("heights", [[8, 3], [8, 4, 4], [6, 3, 2], "12", [8.0, 4.0], [], [0], [True], 7, None],
                         ids=repr)
def test_mip_row_positions_refuses_counts_no_pyramid_has(heights):
    """Each level's row positions follow from the level before (n -> max(1, n // 2), ``build_mip_levels``): ``[8, 3]``
    came back as the positions of ``[8, 4]`` without a word, ``"12"`` was read digit by digit and ``[8.0, 4.0]``
    rounded; an int or None was a TypeError from inside."""
    from warpbw.envmap import build_mip_levels, mip_row_positions

    with pytest.raises(WarpbwError, match=r"^mip_row_positions: heights: expected the row counts of build_mip_levels"):
        mip_row_positions(heights)
    pyramid = [lv.shape[0] for lv in build_mip_levels(np.ones((5, 12, 3), np.float32))]   # 5, 2, 1, 1
    assert pyramid == [5, 2, 1, 1] and mip_row_positions(np.array(pyramid)).shape == (4, 2)


@pytest.mark.parametrize("call, needle", [
    ("fit_settings(seed=1.5)", "seed: expected an integer"), ("fit_settings(seed=-1)", "seed: expected an integer"),
    ("fit_settings(seed=True)", "seed: expected an integer"), ("fit_settings(max_samples='1')", "max_samples"),
    ("fit_settings(max_samples=0)", "max_samples"), ("fit_settings(refine_sweeps=-1)", "refine_sweeps"),
    ("fit_settings(refine_sweeps=None)", "refine_sweeps"), ("bandwidth_settings(1.5)", "resolution"),
    ("bandwidth_settings(0)", "resolution"), ("bandwidth_settings('128')", "resolution"),
    ("bandwidth_settings(100)", "resolution: expected a multiple of 16")])
def test_the_settings_a_builder_records_are_checked_as_the_builder_checks_them(call, needle):
    """``fit_settings`` and ``bandwidth_settings`` give the parameters a file records, and its reader compares with:
    they took ``int()`` of anything (1.5, "1" and True recorded as 1, -1 as -1, None a TypeError), values their
    builders (``build_gmm_mipmap``, ``build_brdf_bandwidth``) refuse."""
    from precompute.brdf_bandwidth import DEFAULT_RESOLUTION, bandwidth_settings
    from precompute.gmm_mipmap import DEFAULT_MAX_SAMPLES, fit_settings

    with pytest.raises(WarpbwError, match=re.escape(needle)) as ei:
        eval(call, {"fit_settings": fit_settings, "bandwidth_settings": bandwidth_settings})
    assert "\n" not in str(ei.value)
    assert fit_settings()["max_samples"] == DEFAULT_MAX_SAMPLES and fit_settings(seed=2**32 - 1)["seed"] == 2**32 - 1
    assert bandwidth_settings()["resolution"] == DEFAULT_RESOLUTION == bandwidth_settings(np.int64(128))["resolution"]


def test_gmm_header_problem_names_a_material_without_a_map_and_a_file_that_is_no_asset(tmp_path):
    """``filtering.gmm_header_problem(scene, name, path)`` (what ``warpbw info`` says of a ``gmm`` file): a material
    of another name was a bare KeyError, one without a normal map an AttributeError, and a file that is no asset file
    (a probe, a damaged mipmap), or none at all, was said to be "a None file"."""
    from warpbw.filtering import gmm_header_problem
    from warpbw.scene import parse_scene

    write_exr(tmp_path / "h.exr", np.random.default_rng(0).random((8, 8)).astype(np.float32), channels=["Y"])
    scene = parse_scene(plane_scene_toml('normal_map = "h.exr"\nnormal_map_scale = 0.05\n'), tmp_path, "s.toml")
    bare = parse_scene(plane_scene_toml(), tmp_path, "bare.toml")
    for s, name in ((scene, "nosuch"), (scene, None), (bare, "m")):
        with pytest.raises(WarpbwError, match=r"^gmm_header_problem: name: expected a material of \S+ with a "
                                              r"normal_map \((m|it has none)\), got"):
            gmm_header_problem(s, name, tmp_path / "h.gmm")
    with pytest.raises(WarpbwError, match="^gmm_header_problem: path: expected a file name"):
        gmm_header_problem(scene, "m", None)
    (tmp_path / "cut.gmm").write_bytes(b"PK\x03\x04" + bytes(40))
    assert gmm_header_problem(scene, "m", tmp_path / "none.gmm") == "file not found"
    for p in (tmp_path / "h.exr", tmp_path / "cut.gmm"):
        said = gmm_header_problem(scene, "m", p)
        assert said.startswith("not a warpbw asset file, or a damaged one") and "None" not in said, said
    # mutation round 12: the right mipmap is accepted, and the same file labelled another format is refused
    from conftest import rewrite_asset
    from precompute.gmm_mipmap import GMM_FORMAT, build_gmm_mipmap, write_gmm_mipmap
    from warpbw.scene import file_digest

    h = read_exr(tmp_path / "h.exr").pixels[..., 0]
    write_gmm_mipmap(tmp_path / "h.gmm", build_gmm_mipmap(h, scale=0.05, progress=False), "h.exr",
                     file_digest(tmp_path / "h.exr"))
    assert gmm_header_problem(scene, "m", tmp_path / "h.gmm") is None
    rewrite_asset(tmp_path / "h.gmm", tmp_path / "other.gmm", format="warpbw-brdf-sampling")
    assert gmm_header_problem(scene, "m", tmp_path / "other.gmm") == (
        f"is a 'warpbw-brdf-sampling' file, expected {GMM_FORMAT!r} (build one with: warpbw-precompute gmm)")


def _path_taking_calls(tmp_path):
    """(name, call of a path) for every public function that takes a file or folder name and had no check of it
    (session 80: pathlib's TypeError from deep inside, an AttributeError, or, for an int, open()'s file descriptor)."""
    from precompute import batch
    from types import SimpleNamespace

    from precompute.asset_info import asset_info, header_status
    from precompute.brdf_sampling import load_or_build
    from precompute.assetfile import read_header
    from precompute.gmm_mipmap import load_source
    from precompute.npf_to_merl import npf_to_merl, tabulation_is_current, tabulation_stamp, write_tabulation_stamp
    from warpbw import bench, bench_filtering
    from warpbw.cli_common import write_json
    from warpbw.envmap import load_environment
    from warpbw.io import staged
    from warpbw.io.exr import colour_conversion
    from warpbw.io.exr_layout import exr_damage, first_header_declares
    from warpbw.io.mesh import mesh_triangles
    from warpbw.io.png import png_header, read_png
    from warpbw.scene import file_digest, parse_scene

    item, table = batch.BatchItem("a.binary", None, "a"), fake_npf_table(tmp_path / "npf.bin")
    out = tmp_path / "o"
    scene = parse_scene(STAGE_SCENE, tmp_path, "s.toml")
    return [
        ("file_digest: path", file_digest), ("<string>: base_dir", lambda p: parse_scene("", base_dir=p)),
        ("colour_conversion: path", colour_conversion), ("exr_damage: path", exr_damage),
        ("first_header_declares: path", lambda p: first_header_declares(p, "dataWindow", "box2i")),
        ("mesh_triangles: path", mesh_triangles), ("write_json: path", lambda p: write_json(p, {}, say=False)),
        ("read_png: path", read_png), ("png_header: path", png_header),
        ("asset_info: path", asset_info), ("header_status: path", header_status), ("read_header: path", read_header),
        ("load_source: spec", load_source),
        ("load_environment: spec", load_environment),
        ("write_plot: path", lambda p: bench.write_plot({}, p)),
        ("write_plot: path", lambda p: bench_filtering.write_plot({}, p)),
        ("ground_truth: cache_dir", lambda p: bench.ground_truth(None, 8, p)),
        ("run_bench: cache_dir", lambda p: bench.run_bench(scene, cache_dir=p, progress=False)),
        ("run_bench_filtering: cache", lambda p: bench_filtering.run_bench_filtering(scene, cache=p)),
        ("cache", lambda p: load_or_build(SimpleNamespace(digest="d"), None, p, "sampling", 1, None, None, None)),
        ("batch_items: sources", lambda p: batch.batch_items([p])),
        ("output_paths: out_dir", lambda p: batch.output_paths(item, p)),
        ("output_paths: item", lambda p: batch.output_paths(p, out)),
        ("out_dir", lambda p: batch.check_outputs([item], p)),
        ("run_batch: out_dir", lambda p: batch.run_batch([item], p, scheduler="sync", progress=False)),
        ("run_batch: items", lambda p: batch.run_batch([p], out, scheduler="sync", progress=False)),
        ("npf_to_merl: table", lambda p: npf_to_merl(p, "chrome", tmp_path / "c.binary")),
        ("tabulation_stamp: table", lambda p: tabulation_stamp(p, "chrome")),
        ("tabulation_is_current: merl", lambda p: tabulation_is_current(p, table, "chrome")),
        ("tabulation_is_current: table", lambda p: tabulation_is_current(tmp_path / "c.binary", p, "chrome")),
        ("merl", lambda p: write_tabulation_stamp(p, table, "chrome")),
        ("input_clash: path", lambda p: staged.input_clash(p, [])),
        ("input_clash: inputs", lambda p: staged.input_clash(out, [p])),
        ("check_not_read_only: path", lambda p: staged.check_not_read_only(p, "L")),
        ("output_exists: path", staged.output_exists), ("dangling_link: path", staged.dangling_link),
        ("check_existing_output: path", lambda p: staged.check_existing_output(p, True, "L")),
        ("check_name_length: path", lambda p: staged.check_name_length(p, "L")),
        ("remove_stale_temps: path", staged.remove_stale_temps),
        ("temporary_folder: parent", lambda p: staged.temporary_folder("x", p).__enter__()),
        ("check_still_free: path", lambda p: staged.check_still_free(p, False)),
        ("staged_outputs: paths", lambda p: staged.staged_outputs([p]).__enter__()),
    ]


def test_every_public_function_that_takes_a_path_names_it_when_given_none_or_a_number(tmp_path):
    """None, a number, a list or bytes given as a path to these public functions was pathlib's TypeError from deep
    inside ("expected str, bytes or os.PathLike object, not int"), an AttributeError, or read as a file named "None"
    (session 79 left them; found by calling every public function whose body made a Path of an argument).  Each now
    says in one line which parameter wanted a file name.  Truth: the parameter names of the signatures."""
    calls = _path_taking_calls(tmp_path)
    for bad in (987654, None, [], b"x.exr", 1.5):
        for name, call in calls:
            if bad is None and name in ("<string>: base_dir", "temporary_folder: parent", "run_bench: cache_dir",
                                        "run_bench_filtering: cache", "cache"):
                continue   # None is their default (the working folder, the system's temporary folder, ...)
            expected = "a warpbw.scene.Environment" if "spec" in name and "environment" in name else \
                "(a )?BatchItem" if name.endswith(("item", "items")) else "a file name"
            with pytest.raises(WarpbwError, match=rf"^{re.escape(name)}: expected {expected}") as exc:
                call(bad)
            assert "\n" not in str(exc.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["npf.bin"]


def test_a_number_given_as_a_path_is_not_read_as_a_file_descriptor(tmp_path):
    """``open(3)`` opens file descriptor 3: ``file_digest(1)`` hashed what stdout held and closed it (the next print
    failed with "Bad file descriptor"), and ``mesh_triangles``, ``exr_damage``, ``first_header_declares`` and
    ``check_not_read_only`` (opened for appending) closed the caller's descriptor likewise, returning a figure or
    None without a word (session 80).  Truth: the descriptor of a pipe this test made, still open afterwards."""
    calls = dict(_path_taking_calls(tmp_path))
    r, w = os.pipe()
    os.write(w, b"v/f 1/1 2/2 3/3\n")
    os.close(w)   # a reader of r then meets its end
    try:
        for name, call in calls.items():
            with pytest.raises(WarpbwError, match=rf"^{re.escape(name)}: expected"):
                call(r)
            os.fstat(r)   # still open: OSError "Bad file descriptor" on the old code
    finally:
        os.close(r)


# Every path a command takes, as an option or an argument, given empty: (program, argv, how argparse names it)
_EMPTY_PATHS = [
    ("warpbw", ["render", "", "-o", "x.exr"], "argument scene"),
    ("warpbw", ["render", "s.toml", "-o", ""], "argument -o/--output"),
    ("warpbw", ["demo", "-o", ""], "argument -o/--output"),
    ("warpbw", ["info", ""], "argument scene"),
    ("warpbw", ["compare", "", "r.exr"], "argument test"),
    ("warpbw", ["compare", "t.exr", ""], "argument reference"),
    ("warpbw", ["compare", "t.exr", "r.exr", "--error-map", ""], "argument --error-map"),
    *[("warpbw", [cmd, *argv], name) for cmd in ("bench", "bench-filtering") for argv, name in (
        (["", "--json", "b.json"], "argument scene"),
        (["s.toml", "--json", "", "--plot", "b.png"], "argument --json"),
        (["s.toml", "--json", "b.json", "--plot", ""], "argument --plot"),
        (["s.toml", "--json", "b.json", "--cache", ""], "argument --cache"))],
    ("warpbw-precompute", ["npf-to-merl", "--table", "", "--material", "chrome", "-o", "c.binary"],
     "argument --table"),
    ("warpbw-precompute", ["npf-to-merl", "--table", "npf.bin", "--material", "chrome", "-o", ""],
     "argument -o/--output"),
    ("warpbw-precompute", ["brdf-sampling", "", "-o", "t.npz"], "argument file"),
    ("warpbw-precompute", ["brdf", "", "-o", "t.npz"], "argument file"),
    ("warpbw-precompute", ["batch", "", "-o", "tables"], "argument SOURCE"),
    ("warpbw-precompute", ["batch", "npf.bin", "-o", "tables", "--json", ""], "argument --json"),
    ("warpbw-precompute", ["gmm", "", "-o", "g.gmm"], "argument MAP"),
    ("warpbw-precompute", ["info", ""], "argument FILE"),
]


@pytest.mark.parametrize("prog,argv,name", _EMPTY_PATHS, ids=[f"{c[0]} {' '.join(c[1])}" for c in _EMPTY_PATHS])
def test_every_path_a_command_takes_refuses_an_empty_name_naming_itself(prog, argv, name, capsys):
    """Every -o took a file name checked not to be empty (``parse_path``), but bench's and bench-filtering's --json,
    --plot and --cache and compare's --error-map did not: ``--json "" --plot p.png`` wrote p.json without a word,
    ``--cache ""`` used the default cache, and ``--error-map ""`` wrote no map (command-line audit, session 81).  The
    empty input paths were refused deeper down, in the words of a library parameter ("load_source: spec",
    "asset_info: path", "batch_items: sources"), or of none ("input file (an OpenEXR image)": the test image or the
    reference?).  Each is now refused by the parser, naming the option or argument as --help does.  Truth: the
    argparse convention ("argument NAME: ...", status 2) every other refusal of these parsers follows."""
    from precompute.__main__ import build_parser as precompute_parser
    from warpbw.cli import build_parser as warpbw_parser

    parser = warpbw_parser() if prog == "warpbw" else precompute_parser()
    with pytest.raises(SystemExit) as exc:
        parser.parse_args(argv)
    err = capsys.readouterr().err.strip()
    assert exc.value.code == EXIT_USER_ERROR
    assert err.startswith(f"{prog}: error: {name}: expected a file name, got an empty one"), err
    assert "\n" not in err


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs Linux's /dev/full, a file every write to fails")
def test_stdout_on_a_full_disk_is_named_and_a_closed_stdout_is_no_traceback(tmp_path, monkeypatch, capsys):
    """``warpbw compare A B > out.txt`` on a full disk (or quota, or past a file-size limit) said "warpbw: error:
    [Errno 28] No space left on device", naming nothing: it now names standard output.  Started with stdout closed
    (``>&-``), Python has no sys.stdout, print() writes nothing, and run_command's flush raised AttributeError with a
    traceback and status 1 after the command had written its outputs: it now ends as it would on a terminal (command-
    line audit, session 81).  Truth: /dev/full, where every write fails with ENOSPC."""
    from warpbw.cli import main as cli_main

    write_exr(tmp_path / "a.exr", np.ones((4, 4, 3), np.float32))
    write_exr(tmp_path / "b.exr", np.full((4, 4, 3), 2.0, np.float32))
    argv = ["compare", str(tmp_path / "a.exr"), str(tmp_path / "b.exr")]
    with open("/dev/full", "w") as full:
        monkeypatch.setattr(sys, "stdout", full)
        assert cli_main(argv) == EXIT_USER_ERROR
    assert capsys.readouterr().err == ("warpbw: error: standard output: cannot write there (No space left on "
                                       "device); what the command printed is lost\n")
    monkeypatch.setattr(sys, "stdout", None)
    assert cli_main([*argv, "--error-map", str(tmp_path / "e.exr")]) == 0
    assert capsys.readouterr().err == ""
    assert (tmp_path / "e.exr").is_file() and (tmp_path / "e.png").is_file()


def test_npf_to_merl_takes_its_table_as_brdf_and_batch_take_theirs(monkeypatch, capsys):
    """``warpbw-precompute brdf npf.bin --material chrome`` (and brdf-sampling, batch) take the NPF table as their
    first argument, but npf-to-merl took it only as ``--table npf.bin``: the same words there were refused, "the
    following arguments are required: --table" (command-line audit, session 81).  It now takes either, once.
    Truth: the table the command is handed, read off the call run_command receives."""
    import precompute.__main__ as pre

    monkeypatch.setattr(pre, "run_command", lambda prog, func, args: (func.__name__, args.table))
    tail = ["--material", "chrome", "-o", "c.binary"]
    assert pre.main(["npf-to-merl", "npf.bin", *tail]) == ("cmd_npf_to_merl", "npf.bin")
    assert pre.main(["npf-to-merl", "--table", "npf.bin", *tail]) == ("cmd_npf_to_merl", "npf.bin")
    for argv, said in ((["npf-to-merl", "a.bin", "--table", "b.bin", *tail], "the NPF table given twice (a.bin, then "
                        "--table b.bin): give it once"),
                       (["npf-to-merl", *tail], "the following arguments are required: TABLE (or --table TABLE)")):
        with pytest.raises(SystemExit) as exc:
            pre.main(argv)
        err = capsys.readouterr().err.strip()
        # in npf-to-merl's words, its --help named (read off the parser it was built with since session 82, not
        # found through argparse's private _actions)
        assert exc.value.code == EXIT_USER_ERROR, exc.value.code
        assert err == f"warpbw-precompute: error: {said} (see 'warpbw-precompute npf-to-merl --help')", err
        assert exc.value.code == EXIT_USER_ERROR and err.startswith(f"warpbw-precompute: error: {said}"), err


@pytest.mark.parametrize("buffering", [1, -1], ids=["line-buffered: the write", "buffered: the flush"])
def test_a_reader_that_left_stops_a_command_quietly_whether_a_write_or_the_flush_meets_it(tmp_path, monkeypatch,
                                                                                          capsys, buffering):
    """While a command runs, stdout's writes and flushes that fail name standard output (a full disk), but a closed
    pipe is the reader leaving (``| head -1``): the command stops quietly with the shell's status for SIGPIPE (141,
    README: Command-line conventions), whether the print's write itself (a line-buffered stdout, a terminal's) or the
    flush after the command meets it.  Truth: a pipe whose reading end this test closed."""
    from warpbw.cli import main as cli_main

    write_exr(tmp_path / "a.exr", np.ones((4, 4, 3), np.float32))
    write_exr(tmp_path / "b.exr", np.full((4, 4, 3), 2.0, np.float32))
    r, w = os.pipe()
    os.close(r)
    with open(w, "w", buffering=buffering) as gone:
        monkeypatch.setattr(sys, "stdout", gone)
        assert cli_main(["compare", str(tmp_path / "a.exr"), str(tmp_path / "b.exr")]) == 128 + 13
        monkeypatch.undo()
    assert capsys.readouterr().err == ""


def test_a_command_run_with_no_stderr_leaves_none_behind(tmp_path, monkeypatch):
    """Started with stderr closed (``2>&-``: no ``sys.stderr``), a command writes its warnings and errors nowhere
    while it runs, and afterwards ``sys.stderr`` is None again, not the closed stand-in of the run (a second command in
    the same process, or a print to stderr, then failed on a closed file).  Truth: the state before the call."""
    from warpbw.cli import main as cli_main

    write_exr(tmp_path / "a.exr", np.ones((4, 4, 3), np.float32))
    monkeypatch.setattr(sys, "stderr", None)
    for _ in range(2):
        assert cli_main(["compare", str(tmp_path / "a.exr"), str(tmp_path / "missing.exr")]) == EXIT_USER_ERROR
        assert sys.stderr is None
