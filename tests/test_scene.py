"""Scene files: the embedded default scene, path resolution, validation errors (each a one-line
WarpbwError naming the scene file and the key), exactly-one-of rules, `info` summaries and content hashes.

Pure Python (no Warp kernels, no shared data): runs in a second or two.
"""
from __future__ import annotations

import dataclasses
import math
import os
import re
import sys
import textwrap
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:   # Python 3.10: the backport pyproject installs there, as warpbw.scene reads it
    import tomli as tomllib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from warpbw.errors import WarpbwError
from warpbw.pipeline import scene_summary
from warpbw.scene import (DEFAULT_SCENE_TOML, GGX_MIN_ALPHA, MAX_RESOLUTION, MeshObject, SphereObject, default_scene,
                          load_scene, parse_scene)

CAMERA = """\
[camera]
position = [0.0, 0.0, 4.0]
look_at = [0.0, 0.0, 0.0]
up = [0.0, 1.0, 0.0]
fov = 40.0
resolution = [32, 24]
"""
ENVIRONMENT = """\
[environment]
constant = [1.0, 1.0, 1.0]
"""
SPHERE = """\
[[object]]
shape = "sphere"
center = [0.0, 0.0, 0.0]
radius = 1.0
material = "paint"
"""
PAINT = """\
[material.paint]
type = "lambert"
albedo = [0.5, 0.5, 0.5]
"""


def scene_text(camera=CAMERA, environment=ENVIRONMENT, objects=SPHERE, materials=PAINT) -> str:
    return "\n".join(s for s in (camera, environment, objects, materials) if s)


def write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(textwrap.dedent(text))
    return path


def expect_error(path: Path, key: str) -> str:
    """load_scene(path) must fail with one line '<path>: ...<key>...'; returns the message."""
    with pytest.raises(WarpbwError) as ei:
        load_scene(path)
    msg = str(ei.value)
    assert "\n" not in msg, msg
    assert msg.startswith(f"{path}: "), msg
    assert key in msg, f"{key!r} not in {msg!r}"
    return msg


# ------------------------------------------------------------------------------------------ default scene

def test_default_scene_parses_and_matches_its_toml():
    s = default_scene()
    assert (s.camera.width, s.camera.height) == (384, 256)
    assert s.camera.fov == 40.0
    assert s.environment.procedural == "sky" and s.environment.file is None and s.environment.constant is None
    assert s.environment.rotation == 30.0
    assert all(isinstance(o, SphereObject) for o in s.objects) and len(s.objects) == 3
    assert s.material_order == ["clay", "gold", "glossy"]
    assert {n: m.type for n, m in s.materials.items()} == {"clay": "lambert", "gold": "ggx", "glossy": "ggx"}
    gold = s.materials["gold"]
    assert gold.eta == (0.143, 0.374, 1.442) and gold.k == (3.983, 2.385, 1.603) and gold.alpha == 0.15
    assert s.files() == []  # needs no file at all
    again = parse_scene(DEFAULT_SCENE_TOML, Path.cwd(), "x")
    assert again.content_hash() == s.content_hash()


def test_minimal_scene_defaults(tmp_path):
    s = load_scene(write(tmp_path / "s.toml", scene_text()))
    assert s.source == str(tmp_path / "s.toml")
    assert s.environment.constant == (1.0, 1.0, 1.0)
    assert s.environment.rotation == 0.0 and s.environment.scale == 1.0
    m = s.materials["paint"]
    assert m.type == "lambert" and m.albedo == (0.5, 0.5, 0.5)


# ------------------------------------------------------------------------------------------ paths

def test_relative_paths_resolve_against_the_scene_directory(tmp_path, monkeypatch):
    (tmp_path / "assets").mkdir()
    probe = tmp_path / "assets" / "probe.exr"
    probe.write_bytes(b"not read by the parser")
    mesh = tmp_path / "scenes" / "mesh.obj"
    write(mesh, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    table = tmp_path / "abs_table.bin"
    table.write_bytes(b"x")
    write(tmp_path / "scenes" / "s.toml", scene_text(
        environment='[environment]\nfile = "../assets/probe.exr"\n',
        objects='[[object]]\nmesh = "mesh.obj"\nmaterial = "paint"\n',
        materials=PAINT + f'\n[material.unused]\ntype = "npf"\ntable = "{table}"\nname = "chrome"\n'))
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    s = load_scene(Path("..") / "scenes" / "s.toml")  # a relative scene path, from another directory
    assert s.environment.file.resolve() == probe.resolve()
    assert isinstance(s.objects[0], MeshObject) and s.objects[0].file.resolve() == mesh.resolve()
    assert s.materials["unused"].table == table  # absolute paths are kept as they are
    assert s.base_dir == (tmp_path / "scenes").resolve()


def test_relative_path_is_not_resolved_against_the_working_directory(tmp_path, monkeypatch):
    (tmp_path / "cwd").mkdir()
    (tmp_path / "cwd" / "probe.exr").write_bytes(b"x")  # exists beside the cwd, not beside the scene
    scene = write(tmp_path / "scenes" / "s.toml",
                  scene_text(environment='[environment]\nfile = "probe.exr"\n'))
    monkeypatch.chdir(tmp_path / "cwd")
    msg = expect_error(scene, "[environment].file")
    assert str(tmp_path / "scenes" / "probe.exr") in msg


def test_a_scene_parsed_against_a_relative_folder_is_checked_and_prepared_as_parsed(tmp_path, monkeypatch):
    """parse_scene(text, "sub") resolved "probe.exr" to sub/probe.exr, relative to the working directory, and kept
    "sub" as the scene's folder: check_scene (which prepare_scene runs) then joined the two, and refused the scene
    it had just accepted ("file not found: sub/sub/probe.exr").  The folder is taken as absolute when parsed, so the
    paths also survive a later change of working directory."""
    from warpbw.scene import check_scene

    write(tmp_path / "sub" / "probe.exr", "not read by the parser")
    monkeypatch.chdir(tmp_path)
    s = parse_scene(scene_text(environment='[environment]\nfile = "probe.exr"\n'), "sub", "s.toml")
    assert s.environment.file == tmp_path / "sub" / "probe.exr" and s.base_dir == tmp_path / "sub"
    monkeypatch.chdir(tmp_path / "sub")
    assert check_scene(s).environment.file == tmp_path / "sub" / "probe.exr"
    # a Scene built in Python with a relative folder: checked twice, the same file
    monkeypatch.chdir(tmp_path)
    built = dataclasses.replace(s, base_dir=Path("sub"),
                                environment=dataclasses.replace(s.environment, file=Path("probe.exr")))
    assert check_scene(check_scene(built)).environment.file == tmp_path / "sub" / "probe.exr"


# ------------------------------------------------------------------------------------------ validation errors

def _replace(text: str, old: str, new: str) -> str:
    assert old in text, old
    return text.replace(old, new)


BASE = scene_text()
CASES = [
    # (id, scene text, key that the message must name)
    ("negative resolution", _replace(BASE, "[32, 24]", "[-1, 512]"), "[camera].resolution"),
    ("zero resolution", _replace(BASE, "[32, 24]", "[0, 24]"), "[camera].resolution"),
    ("float resolution", _replace(BASE, "[32, 24]", "[32.5, 24]"), "[camera].resolution"),
    ("bool resolution", _replace(BASE, "[32, 24]", "[true, 24]"), "[camera].resolution"),
    ("one-number resolution", _replace(BASE, "[32, 24]", "[32]"), "[camera].resolution"),
    ("string resolution", _replace(BASE, "[32, 24]", '"32x24"'), "[camera].resolution"),
    ("huge resolution", _replace(BASE, "[32, 24]", f"[{MAX_RESOLUTION + 1}, 24]"), "[camera].resolution"),
    ("missing resolution", _replace(BASE, "resolution = [32, 24]\n", ""), "[camera].resolution"),
    ("fov 0", _replace(BASE, "fov = 40.0", "fov = 0"), "[camera].fov"),
    ("fov 180", _replace(BASE, "fov = 40.0", "fov = 180.0"), "[camera].fov"),
    ("fov nan", _replace(BASE, "fov = 40.0", "fov = nan"), "[camera].fov"),
    ("fov string", _replace(BASE, "fov = 40.0", 'fov = "wide"'), "[camera].fov"),
    ("position one number", _replace(BASE, "position = [0.0, 0.0, 4.0]", "position = 4.0"),
     "[camera].position: expected three numbers [x, y, z] (a point or direction, not one number), got 4.0"),
    ("center one number", _replace(BASE, "center = [0.0, 0.0, 0.0]", "center = 1.0"), "[[object]] #1.center"),
    ("position of 2", _replace(BASE, "position = [0.0, 0.0, 4.0]", "position = [0.0, 4.0]"), "[camera].position"),
    ("look_at == position", _replace(BASE, "look_at = [0.0, 0.0, 0.0]", "look_at = [0.0, 0.0, 4.0]"),
     "[camera].look_at"),
    ("up parallel", _replace(BASE, "up = [0.0, 1.0, 0.0]", "up = [0.0, 0.0, 2.0]"), "[camera].up"),
    ("no camera", scene_text(camera=""), "[camera]"),
    ("camera not a table", "camera = 3\n" + scene_text(camera=""), "[camera]"),
    ("unknown camera key", _replace(BASE, "fov = 40.0", "fov = 40.0\nfovy = 30.0"), "[camera].fovy"),
    ("unknown material type", _replace(BASE, 'type = "lambert"', 'type = "phong"'), "[material.paint].type"),
    ("missing material type", _replace(BASE, 'type = "lambert"\n', ""),
     "[material.paint].type: missing required key (one of: lambert, ggx"),
    ("[object] for [[object]]", _replace(BASE, "[[object]]", "[object]"),
     "[object]: expected [[object]] (double brackets: one table per object)"),
    # a value that is not tables was told only that no object was given
    ("object a number", "object = 3\n" + scene_text(objects=""),
     "[[object]]: expected at least one [[object]] table, got object = 3"),
    ("object empty", "object = []\n" + scene_text(objects=""),
     "[[object]]: expected at least one [[object]] table, got object = []"),
    ("light a string", 'light = "sun"\n' + BASE, "[[light]]: expected one or more [[light]] tables, got light = 'sun'"),
    ("albedo > 1", _replace(BASE, "albedo = [0.5, 0.5, 0.5]", "albedo = [0.5, 1.5, 0.5]"),
     "[material.paint].albedo"),
    ("albedo negative", _replace(BASE, "albedo = [0.5, 0.5, 0.5]", "albedo = -0.5"), "[material.paint].albedo"),
    ("unknown material key", _replace(BASE, "albedo = [0.5, 0.5, 0.5]", "albedo = 0.5\nroughness = 0.3"),
     "[material.paint].roughness"),
    ("ggx alpha 0", scene_text(materials='[material.paint]\ntype = "ggx"\nalpha = 0.0\nspecular = 1.0\n'),
     "[material.paint].alpha"),
    ("ggx alpha below the minimum",
     scene_text(materials='[material.paint]\ntype = "ggx"\nalpha = 5e-5\nspecular = 1.0\n'),
     "[material.paint].alpha: expected a number >= 0.0001"),
    ("ggx alpha > 1", scene_text(materials='[material.paint]\ntype = "ggx"\nalpha = 1.5\nspecular = 1.0\n'),
     "[material.paint].alpha"),
    ("ggx specular above one", scene_text(materials='[material.paint]\ntype = "ggx"\nalpha = 0.3\n'
                                                   'specular = [1.0, 1.2, 0.5]\n'),
     "[material.paint].specular: expected components in [0, 1]"),
    ("ggx missing specular", scene_text(materials='[material.paint]\ntype = "ggx"\nalpha = 0.3\n'),
     "[material.paint].specular"),
    ("ggx eta without k",
     scene_text(materials='[material.paint]\ntype = "ggx"\nalpha = 0.3\nspecular = 1.0\neta = [1.0, 1.0, 1.0]\n'),
     "[material.paint]"),
    ("merl missing file", scene_text(materials='[material.paint]\ntype = "merl"\nfile = "nope.binary"\n'),
     "[material.paint].file"),
    ("merl bad lookup", scene_text(materials='[material.paint]\ntype = "merl"\nfile = "s.toml"\nlookup = "cubic"\n'),
     "[material.paint].lookup"),
    ("npf missing name", scene_text(materials='[material.paint]\ntype = "npf"\ntable = "s.toml"\n'),
     "[material.paint].name"),
    ("npf key on merl", scene_text(materials='[material.paint]\ntype = "merl"\nfile = "s.toml"\nname = "chrome"\n'),
     "[material.paint].name"),
    ("material array", scene_text(materials='[[material]]\ntype = "lambert"\n'), "[material]"),
    ("undefined material", scene_text(objects=SPHERE + _replace(SPHERE, '"paint"', '"gloss"')),
     "[[object]] #2.material"),
    ("missing mesh file", scene_text(objects=SPHERE + '[[object]]\nmesh = "missing.obj"\nmaterial = "paint"\n'),
     "[[object]] #2.mesh"),
    ("mesh is a directory", scene_text(objects=SPHERE + '[[object]]\nmesh = "."\nmaterial = "paint"\n'),
     "[[object]] #2.mesh"),
    ("negative radius", _replace(BASE, "radius = 1.0", "radius = -1.0"), "[[object]] #1.radius"),
    ("missing radius", _replace(BASE, "radius = 1.0\n", ""), "[[object]] #1.radius"),
    ("unknown shape", _replace(BASE, 'shape = "sphere"', 'shape = "cube"'), "[[object]] #1.shape"),
    ("shape mesh", scene_text(objects='[[object]]\nshape = "mesh"\nfile = "bunny.obj"\nmaterial = "paint"\n'),
     '[[object]] #1.shape: a mesh object is written mesh = "file.obj" without shape'),
    ("unknown object key", _replace(BASE, "radius = 1.0", "radius = 1.0\ncolour = [1, 0, 0]"),
     "[[object]] #1.colour"),
    ("missing material", _replace(BASE, 'material = "paint"\n', ""), "[[object]] #1.material"),
    ("misspelt material key", _replace(BASE, 'material = "paint"', 'materal = "paint"'), "[[object]] #1.materal"),
    ("mesh scale 0", scene_text(objects='[[object]]\nmesh = "s.toml"\nmaterial = "paint"\nscale = 0.0\n'),
     "[[object]] #1.scale"),
    ("no objects", scene_text(objects=""), "[[object]]"),
    ("no environment", scene_text(environment=""), "[environment]"),
    ("missing environment file", scene_text(environment='[environment]\nfile = "probe.exr"\n'),
     "[environment].file"),
    ("unknown procedural", scene_text(environment='[environment]\nprocedural = "moon"\n'),
     "[environment].procedural"),
    ("negative constant", scene_text(environment="[environment]\nconstant = [1.0, -1.0, 1.0]\n"),
     "[environment].constant"),
    ("negative scale", scene_text(environment="[environment]\nconstant = 1.0\nscale = -2.0\n"),
     "[environment].scale"),
    ("infinite rotation", scene_text(environment="[environment]\nconstant = 1.0\nrotation = inf\n"),
     "[environment].rotation"),
    ("unknown environment key", scene_text(environment="[environment]\nconstant = 1.0\nintensity = 2.0\n"),
     "[environment].intensity"),
    ("unknown top-level table", BASE + "\n[lights]\nsun = 1.0\n", ": lights: unknown key"),
    # numbers the kernels cannot hold: an integer too large for a float, values beyond float32
    ("400-digit radius", _replace(BASE, "radius = 1.0", "radius = 1" + "0" * 400),
     "[[object]] #1.radius: expected a finite number"),
    ("radius beyond float32", _replace(BASE, "radius = 1.0", "radius = 1e300"),
     "[[object]] #1.radius: expected a number within the float32 range"),
    ("camera position beyond float32", _replace(BASE, "[0.0, 0.0, 4.0]", "[0.0, 0.0, 1e300]"),
     "[camera].position: expected a number within the float32 range"),
    ("constant beyond float32", scene_text(environment="[environment]\nconstant = [1e39, 1.0, 1.0]\n"),
     "[environment].constant: expected a number within the float32 range"),
    ("environment scale beyond float32", scene_text(environment="[environment]\nconstant = 1.0\nscale = 1e300\n"),
     "[environment].scale: expected a number within the float32 range"),
    ("constant * scale beyond float32", scene_text(environment="[environment]\nconstant = 1e30\nscale = 1e10\n"),
     "[environment].scale: constant * scale must stay within the float32 range"),
]


@pytest.mark.parametrize("text,key", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_validation_error_names_file_and_key(tmp_path, text, key):
    expect_error(write(tmp_path / "s.toml", text), key)


def test_unknown_key_lists_the_allowed_keys(tmp_path):
    msg = expect_error(write(tmp_path / "s.toml", _replace(BASE, "fov = 40.0", "fov = 40.0\nfovy = 30.0")),
                       "[camera].fovy")
    assert "unknown key" in msg and "resolution" in msg


def test_not_toml(tmp_path):
    p = tmp_path / "s.toml"
    p.write_text("[camera\nfov = = 3\n")
    with pytest.raises(WarpbwError, match=re.escape(f"{p}: not valid TOML")):
        load_scene(p)


def test_missing_and_unreadable_scene_files(tmp_path):
    with pytest.raises(WarpbwError, match=re.escape(f"{tmp_path / 'nope.toml'}: scene file not found")):
        load_scene(tmp_path / "nope.toml")
    with pytest.raises(WarpbwError, match=re.escape(f"{tmp_path}: not a file")):
        load_scene(tmp_path)
    p = tmp_path / "binary.toml"
    p.write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe\x00")
    with pytest.raises(WarpbwError, match=re.escape(f"{p}: cannot read the scene file as UTF-8")):
        load_scene(p)


def test_parse_scene_names_its_source():
    with pytest.raises(WarpbwError, match=r"^my scene: \[camera\]\.fov: "):
        parse_scene(_replace(BASE, "fov = 40.0", "fov = -1"), source="my scene")


# ------------------------------------------------------------------------------------------ exactly one of

@pytest.mark.parametrize("env", [
    "[environment]\n",
    '[environment]\nprocedural = "sky"\nconstant = 1.0\n',
    '[environment]\nfile = "s.toml"\nconstant = 1.0\n',
    '[environment]\nfile = "s.toml"\nprocedural = "sky"\nconstant = 1.0\n',
], ids=["none", "procedural+constant", "file+constant", "all three"])
def test_environment_needs_exactly_one_light(tmp_path, env):
    msg = expect_error(write(tmp_path / "s.toml", scene_text(environment=env)), "[environment]")
    assert "exactly one of" in msg


@pytest.mark.parametrize("env,attr", [('[environment]\nfile = "s.toml"\n', "file"),
                                      ('[environment]\nprocedural = "sky"\n', "procedural"),
                                      ("[environment]\nconstant = 0.25\n", "constant")])
def test_environment_each_light_alone_is_accepted(tmp_path, env, attr):
    s = load_scene(write(tmp_path / "s.toml", scene_text(environment=env)))
    given = [a for a in ("file", "procedural", "constant") if getattr(s.environment, a) is not None]
    assert given == [attr]
    if attr == "constant":
        assert s.environment.constant == (0.25, 0.25, 0.25)


@pytest.mark.parametrize("env", ['file = "probe.exr"', 'procedural = "sky"', "constant = 0.25"])
def test_environment_rotation_and_scale_are_read_whichever_light(tmp_path, env):
    """The scene file's rotation (degrees) and scale reach the environment as written, for each kind of light,
    and the loaded light turns by them (a probe, file or procedural, whose texels are about +Y)."""
    from warpbw.envmap import load_environment
    from warpbw.io.exr import write_exr

    write_exr(tmp_path / "probe.exr", np.random.default_rng(0).random((8, 16, 3)).astype(np.float32))
    s = load_scene(write(tmp_path / "s.toml", scene_text(
        environment=f"[environment]\n{env}\nrotation = 37.5\nscale = 2.0\n")))
    assert (s.environment.rotation, s.environment.scale) == (37.5, 2.0)
    light = load_environment(s.environment)
    if not env.startswith("constant"):   # a constant light has no orientation (its scale is folded in)
        assert (light.rotation_deg, light.scale) == (37.5, 2.0)


def test_mesh_transform_is_read_as_written(tmp_path):
    """translate, scale and rotate_y (degrees) of a mesh object reach the loaded mesh: the image of (1, 0, 0)
    under x' = R_y(90) (2 x) + t, R_y right-handed about +Y (+X -> -Z), worked out by hand: (0, 0, -2) + t."""
    import trimesh

    from warpbw.pipeline import surface_geometry

    trimesh.Trimesh(vertices=[[1, 0, 0], [0, 1, 0], [0, 0, 0]], faces=[[0, 1, 2]], process=False).export(
        tmp_path / "tri.obj")
    obj = ('[[object]]\nmesh = "tri.obj"\ntranslate = [0.5, 0.25, -1.0]\nscale = 2.0\nrotate_y = 90.0\n'
           'material = "paint"\n')
    s = load_scene(write(tmp_path / "s.toml", scene_text(objects=obj)))
    o = s.objects[0]
    assert (o.translate, o.scale, o.rotate_y) == ((0.5, 0.25, -1.0), 2.0, 90.0)
    pts = surface_geometry(s).mesh.points.numpy()
    want = np.array([[0.0, 0.0, -2.0], [0.0, 2.0, 0.0], [0.0, 0.0, 0.0]]) + (0.5, 0.25, -1.0)
    assert all(np.abs(pts - w).max(axis=1).min() < 1e-5 for w in want), pts


@pytest.mark.parametrize("obj", [
    '[[object]]\nmaterial = "paint"\nradius = 1.0\n',
    '[[object]]\nshape = "sphere"\nmesh = "s.toml"\nradius = 1.0\nmaterial = "paint"\n',
], ids=["neither", "both"])
def test_object_needs_exactly_one_shape(tmp_path, obj):
    msg = expect_error(write(tmp_path / "s.toml", scene_text(objects=SPHERE + obj)), "[[object]] #2")
    assert "exactly one of" in msg


# ------------------------------------------------------------------------------------------ info summary

def test_summary_lists_only_the_materials_used(tmp_path):
    (tmp_path / "unused.binary").write_bytes(b"never read")
    mats = PAINT + """
[material.shiny]
type = "ggx"
alpha = 0.2
specular = [0.9, 0.9, 0.9]

[material.spare]
type = "merl"
file = "unused.binary"
"""
    objs = SPHERE + '[[object]]\nshape = "sphere"\ncenter = [2.0, 0.0, 0.0]\nradius = 0.5\nmaterial = "shiny"\n'
    s = load_scene(write(tmp_path / "s.toml", scene_text(objects=objs, materials=mats)))
    assert s.material_order == ["paint", "shiny"]
    summ = scene_summary(s)
    assert summ["materials"] == {"paint": "lambert", "shiny": "ggx"}
    assert summ["unused_materials"] == ["spare"]
    assert summ["files"] == []  # the unused material's file is not read
    assert summ["resolution"] == [32, 24]
    assert len(summ["objects"]) == 2 and "material=shiny" in summ["objects"][1]
    assert any(st.startswith("brdf: ggx, lambert") for st in summ["stages"])
    assert not any("tabulated" in st for st in summ["stages"])  # merl is unused: no tabulated sampling


def test_summary_gives_a_mesh_its_transform_as_written(tmp_path):
    """warpbw info shows a mesh's scale, rotate_y and translate (in the order they are applied) where they are not
    the identity; it once showed the file alone, so two placements of one mesh read the same."""
    write(tmp_path / "tri.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    objs = ('[[object]]\nmesh = "tri.obj"\nmaterial = "paint"\n'
            '[[object]]\nmesh = "tri.obj"\nmaterial = "paint"\nscale = 0.7\nrotate_y = 30.0\n'
            'translate = [0.5, 0.0, -1.0]\n')
    summ = scene_summary(load_scene(write(tmp_path / "s.toml", scene_text(objects=objs))))
    plain, placed = summ["objects"]
    assert plain == f"mesh {tmp_path / 'tri.obj'} material=paint"
    assert placed == f"mesh {tmp_path / 'tri.obj'} scale=0.7 rotate_y=30 deg translate=[0.5, 0.0, -1.0] material=paint"


# ------------------------------------------------------------------------------------------ content hash

def _hash_scene(tmp_path) -> Path:
    write(tmp_path / "mesh.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (tmp_path / "probe.exr").write_bytes(b"probe bytes v1")
    (tmp_path / "unused.binary").write_bytes(b"unused v1")
    return write(tmp_path / "s.toml", scene_text(
        environment='[environment]\nfile = "probe.exr"\n',
        objects=SPHERE + '[[object]]\nmesh = "mesh.obj"\nmaterial = "paint"\n',
        materials=PAINT + '\n[material.spare]\ntype = "merl"\nfile = "unused.binary"\n'))


def test_content_hash_follows_the_bytes_of_referenced_files(tmp_path):
    p = _hash_scene(tmp_path)
    h0 = load_scene(p).content_hash()
    assert re.fullmatch(r"[0-9a-f]{32}", h0)
    assert load_scene(p).content_hash() == h0  # deterministic

    mesh = tmp_path / "mesh.obj"
    original = mesh.read_bytes()
    mesh.write_bytes(original.replace(b"v 1 0 0", b"v 2 0 0"))  # same size, different bytes
    os.utime(mesh, ns=(0, 0))
    h1 = load_scene(p).content_hash()
    assert h1 != h0
    mesh.write_bytes(original)
    assert load_scene(p).content_hash() == h0

    (tmp_path / "probe.exr").write_bytes(b"probe bytes v2")
    assert load_scene(p).content_hash() not in (h0, h1)
    (tmp_path / "probe.exr").write_bytes(b"probe bytes v1")
    assert load_scene(p).content_hash() == h0


def test_content_hash_follows_the_files_bytes_not_their_paths(tmp_path):
    """The ground truth is cached under this hash: a scene folder copied elsewhere, or its probe renamed (the scene
    edited to match), is the same scene, and its ground truth was rendered again (the files' absolute paths were
    in the hash)."""
    import shutil

    h0 = load_scene(_hash_scene(tmp_path / "a")).content_hash()
    shutil.copytree(tmp_path / "a", tmp_path / "b")
    assert load_scene(tmp_path / "b" / "s.toml").content_hash() == h0
    (tmp_path / "b" / "probe.exr").rename(tmp_path / "b" / "sky.exr")
    scene = tmp_path / "b" / "s.toml"
    scene.write_text(scene.read_text().replace('"probe.exr"', '"sky.exr"'))
    assert load_scene(scene).content_hash() == h0
    (tmp_path / "b" / "sky.exr").write_bytes(b"another probe")
    assert load_scene(scene).content_hash() != h0


def test_content_hash_ignores_unused_materials_but_not_parameters(tmp_path):
    p = _hash_scene(tmp_path)
    h0 = load_scene(p).content_hash()
    (tmp_path / "unused.binary").write_bytes(b"unused v2")  # not part of the render
    assert load_scene(p).content_hash() == h0
    p.write_text(p.read_text().replace("fov = 40.0", "fov = 41.0"))
    assert load_scene(p).content_hash() != h0
    p.write_text(p.read_text().replace("fov = 41.0", "fov = 40.0").replace("[0.5, 0.5, 0.5]", "[0.5, 0.5, 0.6]"))
    assert load_scene(p).content_hash() != h0


# ------------------------------------------------------------------------------------------ properties

def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v) if math.isfinite(v) else ("nan" if math.isnan(v) else ("inf" if v > 0 else "-inf"))
    if isinstance(v, str):
        return '"' + v + '"'
    return str(v)


_bad_side = st.one_of(
    st.integers(min_value=-(2**63), max_value=0),
    st.floats(allow_nan=True, allow_infinity=True),
    st.booleans(),
    st.text(alphabet="abc0123456789", max_size=4),
    st.integers(min_value=MAX_RESOLUTION + 1, max_value=10**9),
)
_good_side = st.integers(min_value=1, max_value=MAX_RESOLUTION)


@settings(max_examples=150, deadline=None)
@given(st.tuples(_bad_side, _good_side) | st.tuples(_good_side, _bad_side) | st.tuples(_bad_side, _bad_side))
def test_property_bad_resolution_is_rejected(res):
    text = _replace(BASE, "[32, 24]", f"[{_toml_value(res[0])}, {_toml_value(res[1])}]")
    with pytest.raises(WarpbwError, match=r"^prop: \[camera\]\.resolution: expected"):
        parse_scene(text, source="prop")


@settings(max_examples=100, deadline=None)
@given(_good_side, _good_side)
def test_property_good_resolution_is_accepted(w, h):
    s = parse_scene(_replace(BASE, "[32, 24]", f"[{w}, {h}]"), source="prop")
    assert (s.camera.width, s.camera.height) == (w, h)


@settings(max_examples=150, deadline=None)
@given(st.floats(min_value=0.0, max_value=180.0, exclude_min=True, exclude_max=True) | st.integers(1, 179))
def test_property_fov_in_open_interval_is_accepted(fov):
    s = parse_scene(_replace(BASE, "fov = 40.0", f"fov = {_toml_value(fov)}"), source="prop")
    assert s.camera.fov == float(fov)


@settings(max_examples=100, deadline=None)
@given(st.floats(max_value=0.0) | st.floats(min_value=180.0) | st.just(float("nan")))
def test_property_fov_outside_is_rejected(fov):
    with pytest.raises(WarpbwError, match=r"^prop: \[camera\]\.fov: expected"):
        parse_scene(_replace(BASE, "fov = 40.0", f"fov = {_toml_value(fov)}"), source="prop")


@settings(max_examples=60, deadline=None)
@given(st.floats(min_value=GGX_MIN_ALPHA, max_value=1.0))
def test_property_ggx_alpha_in_range_is_accepted(alpha):
    text = scene_text(materials=f'[material.paint]\ntype = "ggx"\nalpha = {_toml_value(alpha)}\nspecular = 1.0\n')
    assert parse_scene(text).materials["paint"].alpha == alpha


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(min_value=0.0, max_value=1.0), min_size=3, max_size=3))
def test_property_albedo_in_unit_cube_is_accepted(albedo):
    text = _replace(BASE, "albedo = [0.5, 0.5, 0.5]", "albedo = [" + ", ".join(map(_toml_value, albedo)) + "]")
    assert parse_scene(text).materials["paint"].albedo == tuple(albedo)


# ------------------------------------------------------------------------------ planes, lights, cook-torrance
# (issue 4: directional lights, shape = "plane", material type = "cook-torrance" with a normal map)

LIGHT = """\
[[light]]
type = "directional"
direction = [0.0, 2.0, 0.0]
radiance = [3.0, 2.0, 1.0]
"""
PLANE = """\
[[object]]
shape = "plane"
center = [0.0, -1.0, 0.0]
size = 2.0
material = "armour"
"""
ARMOUR = """\
[material.armour]
type = "cook-torrance"
roughness = 0.08
f0 = [0.9, 0.75, 0.4]
diffuse = [0.05, 0.04, 0.02]
"""


def _plane_scene(tmp_path, material=ARMOUR, environment="", lights=LIGHT, objects=PLANE, name="p.toml"):
    return write(tmp_path / name, scene_text(environment=environment, objects=lights + "\n" + objects,
                                             materials=material))


def test_plane_scene_with_a_directional_light_needs_no_environment(tmp_path):
    from warpbw.scene import DirectionalLight, PlaneObject

    s = load_scene(_plane_scene(tmp_path))
    assert s.environment is None and s.has_planes
    (li,) = s.lights
    assert isinstance(li, DirectionalLight)
    assert li.direction == (0.0, 1.0, 0.0)      # normalised
    assert li.radiance == (3.0, 2.0, 1.0)
    (p,) = s.objects
    assert isinstance(p, PlaneObject) and p.center == (0.0, -1.0, 0.0) and p.size == 2.0
    m = s.materials["armour"]
    assert (m.type, m.roughness, m.f0, m.diffuse) == ("cook-torrance", 0.08, (0.9, 0.75, 0.4), (0.05, 0.04, 0.02))
    assert m.normal_map is None and m.gmm is None and m.tiling == 1.0 and m.normal_map_kind == "height"
    assert s.files() == []


def test_cook_torrance_normal_map_keys_and_files(tmp_path):
    (tmp_path / "scales.exr").write_bytes(b"height field bytes")
    (tmp_path / "scales.gmm").write_bytes(b"mipmap bytes")
    mat = ARMOUR + ('normal_map = "scales.exr"\nnormal_map_kind = "height"\nnormal_map_scale = 0.05\n'
                    'tiling = 6\ngmm = "scales.gmm"\n')
    p = _plane_scene(tmp_path, material=mat, environment=ENVIRONMENT)
    s = load_scene(p)
    m = s.materials["armour"]
    assert m.normal_map == tmp_path / "scales.exr" and m.gmm == tmp_path / "scales.gmm"
    assert m.normal_map_scale == 0.05 and m.tiling == 6.0
    assert s.environment is not None and s.environment.constant == (1.0, 1.0, 1.0)
    assert s.files() == [tmp_path / "scales.exr", tmp_path / "scales.gmm"]
    h0 = s.content_hash()
    (tmp_path / "scales.exr").write_bytes(b"other height field bytes")
    assert load_scene(p).content_hash() != h0          # the normal map's bytes are hashed
    (tmp_path / "scales.exr").write_bytes(b"height field bytes")
    assert load_scene(p).content_hash() == h0
    (tmp_path / "scales.gmm").write_bytes(b"other mipmap")
    assert load_scene(p).content_hash() != h0          # so are the GMM mipmap's


def test_content_hash_follows_lights_and_plane_parameters(tmp_path):
    h0 = load_scene(_plane_scene(tmp_path)).content_hash()
    h_light = load_scene(_plane_scene(tmp_path, lights=_replace(LIGHT, "[3.0, 2.0, 1.0]", "[3.0, 2.0, 1.5]"),
                                      name="q.toml")).content_hash()
    h_size = load_scene(_plane_scene(tmp_path, objects=_replace(PLANE, "size = 2.0", "size = 2.5"),
                                     name="r.toml")).content_hash()
    h_rough = load_scene(_plane_scene(tmp_path, material=_replace(ARMOUR, "0.08", "0.09"),
                                      name="t.toml")).content_hash()
    assert len({h0, h_light, h_size, h_rough}) == 4


def test_default_scene_hash_does_not_depend_on_cook_torrance_fields():
    # the new material fields are left out of other materials' hashes (cached ground truths stay valid)
    from dataclasses import replace

    s = default_scene()
    h = s.content_hash()
    s.materials["clay"] = replace(s.materials["clay"], roughness=0.5)
    assert s.content_hash() == h


PLANE_CASES = [
    ("no light at all", dict(lights=""), "[environment]"),
    ("unknown light type", dict(lights=_replace(LIGHT, '"directional"', '"spot"')), "[[light]] #1.type"),
    ("zero light direction", dict(lights=_replace(LIGHT, "[0.0, 2.0, 0.0]", "[0.0, 0.0, 0.0]")),
     "[[light]] #1.direction"),
    ("negative radiance", dict(lights=_replace(LIGHT, "[3.0, 2.0, 1.0]", "[3.0, -2.0, 1.0]")), "[[light]] #1.radiance"),
    ("radiance beyond float32", dict(lights=_replace(LIGHT, "[3.0, 2.0, 1.0]", "[1e300, 2.0, 1.0]")),
     "[[light]] #1.radiance: expected a number within the float32 range"),
    ("unknown light key", dict(lights=LIGHT + "colour = 1.0\n"), "[[light]] #1.colour"),
    ("[light] for [[light]]", dict(lights=_replace(LIGHT, "[[light]]", "[light]")),
     "[light]: expected [[light]] (double brackets: one table per light)"),
    ("light without radiance", dict(lights=LIGHT.replace("radiance = [3.0, 2.0, 1.0]\n", "")),
     "[[light]] #1.radiance"),
    ("plane size zero", dict(objects=_replace(PLANE, "size = 2.0", "size = 0.0")), "[[object]] #1.size"),
    ("plane without size", dict(objects=PLANE.replace("size = 2.0\n", "")), "[[object]] #1.size"),
    ("plane with radius", dict(objects=PLANE + "radius = 1.0\n"), "[[object]] #1.radius"),
    ("unknown shape", dict(objects=_replace(PLANE, '"plane"', '"disk"')), "[[object]] #1.shape"),
    ("plane with a lambert material", dict(objects=_replace(PLANE, '"armour"', '"paint"'),
                                           material=ARMOUR + PAINT), "[[object]] #1.material"),
    ("sphere with a cook-torrance material", dict(objects=_replace(SPHERE, '"paint"', '"armour"')),
     "[[object]] #1.material"),
    ("roughness zero", dict(material=_replace(ARMOUR, "0.08", "0.0")), "[material.armour].roughness"),
    ("roughness NaN", dict(material=_replace(ARMOUR, "0.08", "nan")), "[material.armour].roughness"),
    ("f0 above one", dict(material=_replace(ARMOUR, "[0.9, 0.75, 0.4]", "[1.9, 0.75, 0.4]")),
     "[material.armour].f0"),
    ("f0 missing", dict(material=ARMOUR.replace("f0 = [0.9, 0.75, 0.4]\n", "")), "[material.armour].f0"),
    ("diffuse negative", dict(material=_replace(ARMOUR, "[0.05, 0.04, 0.02]", "-0.1")), "[material.armour].diffuse"),
    ("unknown material key", dict(material=ARMOUR + "alpha = 0.1\n"), "[material.armour].alpha"),
    ("normal map missing", dict(material=ARMOUR + 'normal_map = "absent.exr"\n'), "[material.armour].normal_map"),
    ("tiling without a map", dict(material=ARMOUR + "tiling = 4\n"), "[material.armour].tiling"),
]


@pytest.mark.parametrize("case", PLANE_CASES, ids=[c[0] for c in PLANE_CASES])
def test_plane_scene_errors_name_the_key(tmp_path, case):
    _, kw, key = case
    expect_error(_plane_scene(tmp_path, **kw), key)


def test_normal_map_value_errors_name_the_key(tmp_path):
    (tmp_path / "n.png").write_bytes(b"x")
    base = ARMOUR + 'normal_map = "n.png"\n'
    for extra, key in (('normal_map_kind = "bump"\n', "normal_map_kind"), ("tiling = -2\n", "tiling"),
                       ("tiling = 1e9\n", "tiling"), ("normal_map_scale = 0\n", "normal_map_scale"),
                       ('normal_map_kind = "normal"\nnormal_map_scale = 2.0\n', "normal_map_scale"),
                       ('gmm = "nope.gmm"\n', "gmm"), ("gmm_components = 0\n", "gmm_components"),
                       ("gmm_components = 17\n", "gmm_components"), ("gmm_components = 2.5\n", "gmm_components"),
                       ("gmm_prior = -1\n", "gmm_prior"), ("gmm_prior = nan\n", "gmm_prior"),
                       ('gmm_prior = "strong"\n', "gmm_prior"), ("gmm_prior = 1e9\n", "gmm_prior")):
        expect_error(_plane_scene(tmp_path, material=base + extra), f"[material.armour].{key}")


def test_gmm_components_default_and_bound_match_the_builder(tmp_path):
    from precompute.gmm_mipmap import DEFAULT_COMPONENTS, DEFAULT_PRIOR, MAX_COMPONENTS, MAX_PRIOR

    from warpbw.scene import GMM_DEFAULT_COMPONENTS, GMM_DEFAULT_PRIOR, GMM_MAX_COMPONENTS, GMM_MAX_PRIOR

    assert (GMM_DEFAULT_COMPONENTS, GMM_MAX_COMPONENTS) == (DEFAULT_COMPONENTS, MAX_COMPONENTS)
    assert (GMM_DEFAULT_PRIOR, GMM_MAX_PRIOR) == (DEFAULT_PRIOR, MAX_PRIOR)
    (tmp_path / "n.png").write_bytes(b"x")
    s = load_scene(_plane_scene(tmp_path, material=ARMOUR + 'normal_map = "n.png"\ngmm_components = 8\n'))
    assert s.materials["armour"].gmm_components == 8


def test_gmm_prior_defaults_to_the_builders_and_is_read(tmp_path):
    from precompute.gmm_mipmap import DEFAULT_PRIOR

    from warpbw.scene import GMM_DEFAULT_PRIOR

    assert GMM_DEFAULT_PRIOR == DEFAULT_PRIOR == 1.0          # 004 Sec. 4.1
    (tmp_path / "n.png").write_bytes(b"x")
    base = ARMOUR + 'normal_map = "n.png"\n'
    assert load_scene(_plane_scene(tmp_path, material=base)).materials["armour"].gmm_prior == 1.0
    for text, c in (("gmm_prior = 16\n", 16.0), ("gmm_prior = 0\n", 0.0), ("gmm_prior = 2.5\n", 2.5)):
        assert load_scene(_plane_scene(tmp_path, material=base + text)).materials["armour"].gmm_prior == c
    expect_error(_plane_scene(tmp_path, material=ARMOUR + "gmm_prior = 4\n"), "[material.armour].gmm_prior")


# ------------------------------------------------------------------------------------------ README

def _walk_strings(d):
    if isinstance(d, dict):
        for v in d.values():
            yield from _walk_strings(v)
    elif isinstance(d, list):
        for v in d:
            yield from _walk_strings(v)
    elif isinstance(d, str):
        yield d


def test_readme_scene_snippets_parse(tmp_path):
    """The README's TOML blocks are valid scenes (unknown keys are errors, so the README cannot drift
    from the schema unnoticed).  The files they name are created empty: parsing checks that they exist,
    loading them is not what this tests.  The plane-scene block is a fragment: it borrows the first
    block's camera."""
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    blocks = re.findall(r"```toml\n(.*?)```", readme, re.S)
    assert len(blocks) >= 2, "README: expected the scene-file and plane-scene TOML blocks"
    camera = re.search(r"\[camera\].*?(?=\n\[[^\[])", blocks[0], re.S).group(0)
    for b in blocks:
        text = b if "[camera]" in b else camera + "\n" + b
        for s in _walk_strings(tomllib.loads(text)):
            if re.fullmatch(r"[\w.-]+\.(exr|obj|binary|npz|gmm|bin|png)", s):
                (tmp_path / s).touch()
        scene = parse_scene(text, tmp_path, "README.md")
        assert scene.objects, text


def test_every_scene_key_is_in_the_readme_and_every_readme_key_is_accepted(tmp_path):
    """The keys the parser accepts, read from its own "unknown key (expected one of: ...)" message of each kind of
    table (the top level, [camera], [environment], [[light]], a sphere, a plane, a mesh, each material type), are
    each named in the README's TOML blocks, where a user looks them up; and every ``key = ...`` those blocks write,
    in their comments too (``# type = "npf": table = ...``), is one the parser accepts."""
    tables = [CAMERA, ENVIRONMENT, '[[light]]\ntype = "directional"\ndirection = [0, 1, 0]\nradiance = [1, 1, 1]\n',
              SPHERE, '[[object]]\nshape = "plane"\nsize = 1.0\nmaterial = "ct"\n',
              '[[object]]\nmesh = "m.obj"\nmaterial = "paint"\n', PAINT,
              '[material.g]\ntype = "ggx"\nalpha = 0.2\nspecular = [1, 1, 1]\n',
              '[material.me]\ntype = "merl"\nfile = "x.binary"\n',
              '[material.n]\ntype = "npf"\ntable = "npf.bin"\nname = "chrome"\n',
              '[material.ct]\ntype = "cook-torrance"\nroughness = 0.1\nf0 = [0.5, 0.5, 0.5]\n']
    for name in ("m.obj", "x.binary", "npf.bin"):
        (tmp_path / name).touch()
    parse_scene("".join(tables), tmp_path, "s.toml")   # each table valid as it is
    accepted = set()
    for i in range(-1, len(tables)):   # -1: the top level
        text = "zzz_unknown = 1\n" + "".join(tables) if i < 0 else \
            "".join(t + "zzz_unknown = 1\n" if j == i else t for j, t in enumerate(tables))
        with pytest.raises(WarpbwError, match=r"zzz_unknown: unknown key \(expected one of: ") as err:
            parse_scene(text, tmp_path, "s.toml")
        accepted |= set(str(err.value).rsplit("expected one of: ", 1)[1].rstrip(")").split(", "))
    assert {"camera", "look_at", "rotate_y", "normal_map_kind", "bandwidth", "eta"} <= accepted, accepted

    blocks = "\n".join(re.findall(r"```toml\n(.*?)```", (Path(__file__).resolve().parents[1] / "README.md").read_text(),
                                  re.S))
    undocumented = sorted(k for k in accepted if not re.search(rf"\b{k}\b", blocks))
    assert not undocumented, f"scene keys the README's TOML blocks do not name: {undocumented}"
    written = set(re.findall(r"\b([a-z_0-9]+) *=", blocks))
    assert len(written) > 30 and written <= accepted, f"README keys the parser refuses: {sorted(written - accepted)}"


def test_the_defaults_the_readme_gives_scene_keys_are_the_parsers(tmp_path):
    """A key of the README's TOML blocks whose comment says "(default X)" (or "; default X") parses, left out, to the
    scene it gives written ``key = X``; "(default)" alone, to the scene of the value the line writes.  (README said
    nothing of tiling's or normal_map_scale's default, 1, nor that "height" is normal_map_kind's.)"""
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    blocks = re.findall(r"```toml\n(.*?)```", readme, re.S)
    camera = re.search(r"\[camera\].*?(?=\n\[[^\[])", blocks[0], re.S).group(0)
    for name in set(re.findall(r'"([\w.-]+\.(?:exr|obj|binary|npz|gmm|bin|png))"', readme)):
        (tmp_path / name).touch()
    checked = []
    for b in blocks:
        text = b if "[camera]" in b else camera + "\n" + b
        for line, key, said in re.findall(r"^((\w+) = [^#\n]*?) *#.*[(;] ?default(?: ([^,;)\s]+))?", text, re.M):
            written = parse_scene(text if not said else text.replace(line, f"{key} = {said}"), tmp_path, "README")
            left_out = parse_scene(text.replace(line, ""), tmp_path, "README")
            assert left_out == written, f"README: {line} (default {said or 'as written'}), but left out it parses as " \
                                        f"another scene"
            checked.append(key)
    assert {"diffuse", "tiling", "normal_map_scale", "normal_map_kind", "gmm_prior"} <= set(checked), checked


@settings(max_examples=200, deadline=None)
@given(text=st.text(alphabet=st.characters(blacklist_categories=("Cs",)), max_size=40))
def test_toml_string_round_trips_any_path_through_a_toml_reader(text):
    """Tools that write scenes (examples/filtering_scenes.py, mirror_smear.py ...) pasted paths into "...": a quote or
    a backslash made the file invalid, and json.dumps wrote non-BMP characters as surrogate pairs, which TOML
    refuses.  Python's own TOML reader (not ours) gives back exactly the text."""
    from warpbw.scene import toml_escape, toml_string

    assert tomllib.loads(f"file = {toml_string(text, 'p')}")["file"] == text
    assert tomllib.loads(f'file = "dir/{toml_escape(text, "p")}/x.exr"')["file"] == f"dir/{text}/x.exr"


def test_toml_string_refuses_text_no_utf8_file_can_hold():
    """A file name of undecodable bytes reaches Python as lone surrogates: named, not written as broken TOML."""
    from warpbw.scene import toml_string

    with pytest.raises(WarpbwError, match="--environment a\\udcff.exr: cannot be written in a scene file"):
        toml_string("a\udcff.exr", "--environment a\udcff.exr")


# ------------------------------------------------------------------------------------------ scenes built in Python

def test_check_scene_returns_an_equal_copy_of_every_scene_file(tmp_path):
    """check_scene writes a Scene back into a scene file's tables and reads them with the file's own checks: every
    scene a file gives (the default scene, lights and planes, normal maps, MERL and NPF materials with their
    tables) comes back equal, and a copy."""
    from dataclasses import replace

    from warpbw.scene import check_scene

    (tmp_path / "scales.exr").write_bytes(b"height field bytes")
    (tmp_path / "scales.gmm").write_bytes(b"mipmap bytes")
    for name in ("a.binary", "npf.bin", "a.sampling.npz", "a.bandwidth.npz", "bunny.obj"):
        (tmp_path / name).write_bytes(b"x")
    normal_mapped = ARMOUR + ('normal_map = "scales.exr"\nnormal_map_kind = "normal"\ntiling = 6\ngmm = "scales.gmm"\n'
                              "gmm_components = 2\ngmm_prior = 3.0\n")
    measured = """
[material.paint]
type = "merl"
file = "a.binary"
lookup = "linear"
sampling = "a.sampling.npz"
bandwidth = "a.bandwidth.npz"
[material.fit]
type = "npf"
table = "npf.bin"
name = "gold-metallic-paint"
[material.metal]
type = "ggx"
alpha = 0.2
specular = [0.9, 0.8, 0.7]
eta = [0.2, 0.4, 1.5]
k = [3.0, 2.4, 1.8]
"""
    objects = SPHERE + '\n[[object]]\nmesh = "bunny.obj"\nmaterial = "fit"\nscale = 2.0\nrotate_y = 30.0\n' \
        + '\n[[object]]\nshape = "sphere"\nradius = 0.5\nmaterial = "metal"\n'
    scenes = [default_scene(),
              load_scene(_plane_scene(tmp_path, material=normal_mapped, environment=ENVIRONMENT)),
              load_scene(write(tmp_path / "m.toml", scene_text(objects=objects, materials=measured,
                                                              environment=ENVIRONMENT + "rotation = 30\n"
                                                              + "scale = 2.0\n")))]
    for s in scenes:
        copy = check_scene(s)
        assert copy == s and copy is not s and copy.objects is not s.objects
    # numpy numbers, and tuples where lists were read, are what a Python user writes
    s = scenes[0]
    s2 = replace(s, objects=[replace(o, radius=np.float32(0.5), center=np.array([0.0, 0.0, 0.0]))
                             for o in s.objects])
    assert all(o.radius == 0.5 and o.center == (0.0, 0.0, 0.0) for o in check_scene(s2).objects)


@pytest.mark.parametrize("edit, message", [
    (lambda s: {"objects": []}, r"\[\[object\]\]: expected at least one"),
    (lambda s: {"objects": [SphereObject((0.0, 0.0, 0.0), 1.0, "nonexistent")]},
     r"\[\[object\]\] #1.material: no \[material.nonexistent\] in the scene"),
    (lambda s: {"objects": [SphereObject((0.0, 0.0, 0.0), -1.0, s.objects[0].material)]},
     r"\[\[object\]\] #1.radius: expected a number > 0"),
    (lambda s: {"materials": {**s.materials, "clay": _replaced(s.materials["clay"], albedo=(2.0, 0.5, 0.5))}},
     r"\[material.clay\].albedo: expected components in \[0, 1\]"),
    (lambda s: {"materials": {**s.materials, "clay": _replaced(s.materials["clay"], alpha=0.3)}},
     r"\[material.clay\].alpha: unknown key"),
    (lambda s: {"materials": {**s.materials, "clay": _replaced(s.materials["clay"], name="mud")}},
     r"\[material.clay\]: its Material is named 'mud'"),
    (lambda s: {"camera": _replaced(s.camera, width=16.0)}, r"\[camera\].resolution: expected two positive"),
    (lambda s: {"environment": None}, r"\[environment\]: missing"),
    (lambda s: {"objects": ["a sphere"]}, r"\[\[object\]\] #1: expected a table, got 'a sphere'"),
])
def test_a_scene_built_in_python_is_checked_as_a_scene_file_is(edit, message):
    """A Scene edited in Python skipped every check of the scene file: an unknown material failed with a bare
    KeyError inside prepare_scene, an albedo of 2 rendered, no object at all rendered an empty image."""
    from dataclasses import replace

    from warpbw.pipeline import prepare_scene
    from warpbw.scene import check_scene

    s = default_scene()
    bad = replace(s, **edit(s))
    with pytest.raises(WarpbwError, match=rf"^<default scene>: {message}"):
        check_scene(bad)
    with pytest.raises(WarpbwError, match=message):
        prepare_scene(bad)


def _replaced(obj, **changes):
    from dataclasses import replace

    return replace(obj, **changes)


def test_check_scene_and_load_scene_refuse_what_is_not_a_scene():
    from warpbw.scene import check_scene

    with pytest.raises(WarpbwError, match="scene: expected a warpbw.scene.Scene .*, got str"):
        check_scene("scene.toml")
    with pytest.raises(WarpbwError, match="scene path: expected a file name .str or Path., got None"):
        load_scene(None)
    with pytest.raises(WarpbwError, match="expected the scene's TOML text as a str, got bytes"):
        parse_scene(DEFAULT_SCENE_TOML.encode())


def test_a_camera_without_up_is_y_up_as_the_readme_writes_it(tmp_path):
    """[camera].up may be left out; the camera it gives must be the one README's example (and the embedded scene)
    writes, up = [0, 1, 0]: the environment rotates about +Y and every probe is Y-up, so an omitted up that
    defaulted to another axis would silently roll or tilt every image."""
    side = CAMERA.replace("position = [0.0, 0.0, 4.0]", "position = [4.0, 0.0, 0.0]")   # looking along -x
    no_up = side.replace("up = [0.0, 1.0, 0.0]\n", "")
    assert side != CAMERA and no_up != side
    omitted = parse_scene(scene_text(camera=no_up), tmp_path)
    written = parse_scene(scene_text(camera=side), tmp_path)
    assert tuple(written.camera.up) == (0.0, 1.0, 0.0)
    assert tuple(omitted.camera.up) == tuple(written.camera.up)


def test_cook_torrance_diffuse_defaults_to_zero_as_documented(tmp_path):
    """README: a cook-torrance material's ``diffuse`` is the Lambert albedo, 'default 0'.  Leaving it out must
    give a purely specular material, not one with a hidden diffuse lobe that brightens every plane."""
    no_diffuse = ARMOUR.replace("diffuse = [0.05, 0.04, 0.02]\n", "")
    assert no_diffuse != ARMOUR
    m = parse_scene(scene_text(objects=PLANE, materials=no_diffuse), tmp_path).materials["armour"]
    assert tuple(m.diffuse) == (0.0, 0.0, 0.0)


@pytest.mark.parametrize("mtype, default, other", [("merl", "nearest", "linear"), ("npf", "linear", "nearest")])
def test_tabulated_materials_look_up_their_kinds_default(tmp_path, mtype, default, other):
    """README: a MERL material's ``lookup`` is "nearest" (MERL's own) unless "linear" is asked for; an NPF material's
    is "linear", between the fit's bin centres (../shared/data/README.md: "linear interpolation between bin centres
    is better"; since session 70, before which it was "nearest"), unless "nearest" is asked for.  A default that
    moves changes every such material's image and which precomputed nu_rho tables it accepts."""
    f = tmp_path / "table.bin"
    f.write_bytes(b"x")   # parsing only checks that the file exists
    keys = f'file = "{f.name}"' if mtype == "merl" else f'table = "{f.name}"\nname = "chrome"'
    paint = f'[material.paint]\ntype = "{mtype}"\n{keys}\n'
    m = parse_scene(scene_text(materials=paint), tmp_path).materials["paint"]
    assert m.lookup == default
    asked = parse_scene(scene_text(materials=paint + f'lookup = "{other}"\n'), tmp_path).materials["paint"]
    assert asked.lookup == other   # and the key, when written, is read


# ------------------------------------------------------------------------------------------ the ends of each range
# (mutation round 6: each test fails when its bound moves by one step or its check is dropped)


def test_cook_torrance_accepts_the_ends_readme_uses_and_refuses_beyond(tmp_path):
    """README's reflectance-filtering notes use a plane of "diffuse 1, f0 0 and roughness 0.001" and "f0 = 1 at
    roughness 1", and call roughness 1e-3 the smallest accepted: those ends are accepted; just below the smallest
    roughness and above 1 are refused, naming the key."""
    extremes = (ARMOUR.replace("roughness = 0.08", "roughness = 1.0").replace("[0.9, 0.75, 0.4]", "[1.0, 1.0, 1.0]")
                .replace("[0.05, 0.04, 0.02]", "1.0"))
    m = load_scene(_plane_scene(tmp_path, material=extremes, name="a.toml")).materials["armour"]
    assert (m.roughness, m.f0, m.diffuse) == (1.0, (1.0, 1.0, 1.0), (1.0, 1.0, 1.0))
    smallest = ARMOUR.replace("roughness = 0.08", "roughness = 1e-3").replace("[0.9, 0.75, 0.4]", "0.0")
    m = load_scene(_plane_scene(tmp_path, material=smallest, name="b.toml")).materials["armour"]
    assert (m.roughness, m.f0) == (1e-3, (0.0, 0.0, 0.0))
    for rough in ("9e-4", "1.5"):
        expect_error(_plane_scene(tmp_path, material=_replace(ARMOUR, "0.08", rough), name="c.toml"),
                     "[material.armour].roughness: expected a number")


def test_lambert_and_ggx_colours_of_one_are_accepted(tmp_path):
    """README: lambert albedo and ggx specular each in [0, 1]: 1 itself is accepted (a white furnace).  The property
    test over [0, 1] drew exactly 1.0 only in some runs."""
    mats = ('[material.paint]\ntype = "lambert"\nalbedo = [1.0, 1.0, 1.0]\n'
            '[material.white]\ntype = "ggx"\nalpha = 0.3\nspecular = 1.0\n')
    s = parse_scene(scene_text(materials=mats), tmp_path)
    assert s.materials["paint"].albedo == s.materials["white"].specular == (1.0, 1.0, 1.0)


def test_environment_radiance_up_to_float32_max_and_a_zero_scale_are_accepted(tmp_path):
    """The kernels see constant * scale in float32, so the largest float32 itself (numpy's finfo) is a radiance they
    hold: accepted.  A scale of 0 gives the same black light as constant = 0, which is accepted."""
    f32_max = float(np.finfo(np.float32).max)
    top = parse_scene(scene_text(environment=f"[environment]\nconstant = {f32_max!r}\nscale = 1.0\n"), tmp_path)
    assert top.environment.constant == (f32_max,) * 3
    off = parse_scene(scene_text(environment="[environment]\nconstant = 1.0\nscale = 0.0\n"), tmp_path).environment
    assert max(off.constant) * off.scale == 0.0


def test_a_conductor_needs_both_eta_and_k(tmp_path):
    """README: "optional eta, k = [r, g, b] (conductor)", the two together.  k alone was dropped silently: the
    material rendered as a dielectric."""
    ggx = '[material.paint]\ntype = "ggx"\nalpha = 0.3\nspecular = 1.0\n'
    for extra in ("k = [3.0, 2.4, 1.8]\n", "eta = [0.2, 0.4, 1.5]\n"):
        msg = expect_error(write(tmp_path / "s.toml", scene_text(materials=ggx + extra)), "[material.paint]")
        assert "both eta and k" in msg


def test_a_conductor_k_beyond_the_largest_index_is_refused_in_the_scene(tmp_path):
    """README: "A conductor's eta and k are at most 1e4".  k = 5e9 passed the scene and was refused only by the
    material table, naming no scene key.  Both at 1e4 are accepted."""
    ggx = '[material.paint]\ntype = "ggx"\nalpha = 0.3\nspecular = 1.0\neta = [1e4, 1.0, 1.0]\n'
    s = parse_scene(scene_text(materials=ggx + "k = [1e4, 1e4, 1e4]\n"), tmp_path)
    assert s.materials["paint"].k == (1e4,) * 3
    expect_error(write(tmp_path / "s.toml", scene_text(materials=ggx + "k = [5e9, 1.0, 1.0]\n")),
                 "[material.paint].k: expected a number <= 10000")


def test_a_tiling_of_zero_repeats_is_refused(tmp_path):
    """tiling is the number of repeats across the plane (README): zero repeats is no map at all."""
    (tmp_path / "n.png").write_bytes(b"x")
    expect_error(_plane_scene(tmp_path, material=ARMOUR + 'normal_map = "n.png"\ntiling = 0\n'),
                 "[material.armour].tiling: expected a number > 0")


def test_gmm_components_up_to_the_builders_maximum_are_accepted(tmp_path):
    """Every count the GMM builder takes (1 to precompute.gmm_mipmap.MAX_COMPONENTS) is a count a scene may ask for;
    one more is refused."""
    from precompute.gmm_mipmap import MAX_COMPONENTS

    (tmp_path / "n.png").write_bytes(b"x")
    base = ARMOUR + 'normal_map = "n.png"\n'
    for k in (1, MAX_COMPONENTS):
        s = load_scene(_plane_scene(tmp_path, material=base + f"gmm_components = {k}\n"))
        assert s.materials["armour"].gmm_components == k
    expect_error(_plane_scene(tmp_path, material=base + f"gmm_components = {MAX_COMPONENTS + 1}\n"),
                 "[material.armour].gmm_components")


@pytest.mark.parametrize("old, new, key", [
    ("fov = 40.0", "fov = true", "[camera].fov"),
    ("radius = 1.0", "radius = true", "[[object]] #1.radius"),
    ("albedo = [0.5, 0.5, 0.5]", "albedo = [true, 0.5, 0.5]", "[material.paint].albedo"),
    ("constant = [1.0, 1.0, 1.0]", "constant = [1.0, true, 1.0]", "[environment].constant"),
])
def test_a_boolean_is_not_a_number(tmp_path, old, new, key):
    """TOML's booleans are their own type (toml.io, "Boolean"): `radius = true` must not render a unit sphere."""
    expect_error(write(tmp_path / "s.toml", _replace(BASE, old, new)), f"{key}: expected a finite number")


@pytest.mark.parametrize("old, new, key", [
    ("position = [0.0, 0.0, 4.0]", "position = [0.0, 0.0, 4.0, 1.0]", "[camera].position"),
    ("albedo = [0.5, 0.5, 0.5]", "albedo = [0.5, 0.5, 0.5, 1.0]", "[material.paint].albedo"),
    ("center = [0.0, 0.0, 0.0]", "center = [0.0, 0.0, 0.0, 0.0]", "[[object]] #1.center"),
])
def test_four_numbers_are_not_three(tmp_path, old, new, key):
    """Points and colours are [x, y, z] / [r, g, b] (README): a fourth number (a homogeneous w, an alpha) is refused
    rather than dropped."""
    expect_error(write(tmp_path / "s.toml", _replace(BASE, old, new)), f"{key}: expected three numbers")


def test_an_empty_npf_material_name_is_refused_by_the_scene(tmp_path):
    """README: name = "gold-metallic-paint".  An empty name names no NPF material: refused at the key, not later
    naming the table."""
    (tmp_path / "npf.bin").write_bytes(b"x")
    expect_error(write(tmp_path / "s.toml", scene_text(materials='[material.paint]\ntype = "npf"\n'
                                                                 'table = "npf.bin"\nname = ""\n')),
                 "[material.paint].name: expected a non-empty string")



def test_an_empty_material_name_is_refused_where_it_is_defined(tmp_path):
    """[material.""] was accepted though no object can name it (material = "" is refused): warpbw info listed a
    blank, and an object's unknown material said "defined: none" with it the only one (scene fuzzing, session
    63)."""
    expect_error(write(tmp_path / "s.toml", scene_text(materials=PAINT + '\n[material.""]\ntype = "lambert"\n'
                                                                         'albedo = 0.5\n')),
                 '[material.""]: expected a non-empty material name')

def test_a_path_from_the_home_folder_is_expanded(tmp_path, monkeypatch):
    """README: paths are relative to the scene file, and ``~/`` is the home folder ($HOME here), not a folder named
    "~" beside the scene."""
    home = tmp_path / "home"
    home.mkdir()
    (home / "probe.exr").write_bytes(b"not read by the parser")
    monkeypatch.setenv("HOME", str(home))
    at_home = scene_text(environment='[environment]\nfile = "~/probe.exr"\n')
    s = load_scene(write(tmp_path / "scenes" / "s.toml", at_home))
    assert s.environment.file == home / "probe.exr"


def test_a_mesh_with_a_cook_torrance_material_is_refused(tmp_path):
    """README: planes carry cook-torrance materials; spheres and meshes the other types (the sphere case is tested
    above)."""
    write(tmp_path / "tri.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    msg = expect_error(_plane_scene(tmp_path, objects='[[object]]\nmesh = "tri.obj"\nmaterial = "armour"\n'),
                       "[[object]] #1.material")
    assert "cook-torrance" in msg and "planes only" in msg


def test_a_material_two_objects_share_is_one_material(tmp_path):
    """Scene.material_order holds only materials some object uses, one table each in memory: two spheres of one MERL
    material are one material and one file read."""
    (tmp_path / "a.binary").write_bytes(b"x")
    two = SPHERE + _replace(SPHERE, "center = [0.0, 0.0, 0.0]", "center = [2.5, 0.0, 0.0]")
    s = parse_scene(scene_text(objects=two, materials='[material.paint]\ntype = "merl"\nfile = "a.binary"\n'),
                    tmp_path)
    assert s.material_order == ["paint"]
    assert s.files() == [tmp_path / "a.binary"]


def test_an_empty_array_of_lights_is_no_light(tmp_path):
    """`light = []` is valid TOML; with no [environment] the scene has no light at all, which README refuses ("a
    scene needs at least one of them")."""
    with pytest.raises(WarpbwError, match=r"^s: \[\[light\]\]: expected one or more"):
        parse_scene("light = []\n" + scene_text(environment=""), tmp_path, "s")


def test_a_light_direction_is_scaled_not_floored(tmp_path):
    """A direction towards the light is any non-zero vector (README: normalised), whatever its length: [0, 1e-10, 0]
    is straight up, as [0, 1e10, 0] is (an absolute floor of 1e-9 refused it, saying "expected a non-zero vector"
    of a non-zero vector)."""
    for d in ("[0.0, 1e-10, 0.0]", "[0.0, 1e10, 0.0]", "[0.0, 5e-324, 0.0]"):
        s = load_scene(_plane_scene(tmp_path, lights=_replace(LIGHT, "[0.0, 2.0, 0.0]", d)))
        assert s.lights[0].direction == (0.0, 1.0, 0.0), d


def test_a_light_direction_of_subnormal_components_is_scaled_to_unit_length(tmp_path):
    """The direction is stored scaled to unit length (DirectionalLight; the planes' renderer takes it as stored).  Its
    length was taken with math.hypot of the components as given: of subnormal ones it keeps few digits, and
    [1e-320, 3e-320, 0] was stored 7e-5 longer than a unit vector (the planes read E cos theta that much high).
    Truth: the components over the largest, a ratio of two floats of normal range, normalised in float64."""
    for d in ((1e-320, 3e-320, 0.0), (2e-322, -7e-322, 5e-322), (3e-310, 1e-310, 2e-310)):
        s = load_scene(_plane_scene(tmp_path, lights=_replace(LIGHT, "[0.0, 2.0, 0.0]", str(list(d)))))
        v = np.array(d) / max(abs(c) for c in d)
        np.testing.assert_allclose(s.lights[0].direction, v / np.sqrt(np.sum(v * v)), rtol=0, atol=1e-15)


# ------------------------------------------------------------------------------------------ what a scene file can hold


def test_toml_string_refuses_exactly_what_utf8_cannot_encode():
    """toml_string refuses the lone surrogates U+D800-U+DFFF, both ends included: Python's own UTF-8 codec says
    which characters a file cannot hold.  Their neighbours round-trip through Python's TOML reader."""
    from warpbw.scene import toml_string

    for c in ("\ud800", "\udbff", "\udc00", "\udfff", "\ud7ff", "\ue000"):
        try:
            c.encode("utf-8")
        except UnicodeEncodeError:
            with pytest.raises(WarpbwError, match="cannot be written in a scene file"):
                toml_string("a" + c, "p")
        else:
            assert tomllib.loads(f"f = {toml_string('a' + c, 'p')}")["f"] == "a" + c


def test_toml_string_escapes_every_character_toml_refuses_raw():
    """TOML 1.0 (toml.io, "String"): a basic string may not hold a raw quote, backslash, or control character other
    than tab (U+0000-U+001F, U+007F).  A path holding each round-trips through Python's TOML reader (the property
    test's kills of these were Hypothesis' luck)."""
    from warpbw.scene import toml_string

    for c in [chr(i) for i in range(0x20)] + ["\x7f", '"', "\\"]:
        text = f"dir{c}/probe.exr"
        written = f"f = {toml_string(text, 'p')}"
        try:
            back = tomllib.loads(written)["f"]
        except tomllib.TOMLDecodeError as exc:
            back = f"refused by the TOML reader: {exc}"
        assert back == text, (hex(ord(c)), written)


def test_file_digest_covers_every_byte_of_a_large_file(tmp_path):
    """file_digest keys the cached tables and ground truths: two files differing only in their last byte, past the
    first 4 MiB read, differ, and the digest is blake2b-128 of the whole file (hashlib's)."""
    import hashlib

    from warpbw.scene import file_digest

    data = bytes(range(256)) * (5 << 12)             # 5 MiB
    a, b = tmp_path / "a.bin", tmp_path / "b.bin"
    a.write_bytes(data)
    b.write_bytes(data[:-1] + bytes([data[-1] ^ 1]))
    assert file_digest(a) == hashlib.blake2b(data, digest_size=16).hexdigest()
    assert file_digest(a) != file_digest(b)


def test_check_scene_returns_scenes_with_black_materials(tmp_path):
    """Every scene a file gives comes back from check_scene (README: a Scene built or edited in Python is checked as
    a scene file is), albedo 0, a GGX specular 0 and a Cook-Torrance f0 0 included: a value equal to the field's
    Python default is still written back when the type requires the key."""
    from warpbw.scene import check_scene

    mats = ('[material.paint]\ntype = "lambert"\nalbedo = 0.0\n'
            '[material.dark]\ntype = "ggx"\nalpha = 0.3\nspecular = 0.0\n')
    objs = SPHERE + '[[object]]\nshape = "sphere"\ncenter = [2.5, 0.0, 0.0]\nradius = 0.5\nmaterial = "dark"\n'
    spheres = parse_scene(scene_text(objects=objs, materials=mats), tmp_path)
    plane = load_scene(_plane_scene(tmp_path, material=_replace(ARMOUR, "[0.9, 0.75, 0.4]", "0.0")))
    for s in (spheres, plane):
        assert check_scene(s) == s


@pytest.mark.parametrize("old, new, key", [
    ("up = [0.0, 1.0, 0.0]", "up = [0.0, 0.0, 0.0]", "[camera].up"),
    ("position = [0.0, 0.0, 4.0]", "position = [0.0, 0.0, 0.0]", "[camera].look_at: must differ from"),
], ids=["zero up", "position = look_at = origin"])
def test_a_camera_without_a_direction_is_one_line_not_a_traceback(tmp_path, old, new, key):
    """A zero up vector, and a camera at its own look_at point at the origin (0 <= 1e-12 x 0), name the key: both
    were a ZeroDivisionError traceback."""
    path = write(tmp_path / "s.toml", _replace(BASE, old, new))
    try:
        expect_error(path, key)
    except ZeroDivisionError as exc:
        raise AssertionError(f"ZeroDivisionError ({exc}) instead of a one-line error naming {key}") from None


def test_input_files_hold_every_file_the_scene_names(tmp_path):
    """Scene.input_files(): every file the scene names or is read from, unused materials' too (a command's outputs
    may not replace them): the scene file, the probe and an unused material's MERL file, listed by hand."""
    (tmp_path / "probe.exr").write_bytes(b"x")
    (tmp_path / "spare.binary").write_bytes(b"x")
    spare = '[material.spare]\ntype = "merl"\nfile = "spare.binary"\n'
    probe = '[environment]\nfile = "probe.exr"\n'
    p = write(tmp_path / "s.toml", scene_text(environment=probe, materials=PAINT + spare))
    s = load_scene(p)
    assert s.files() == [tmp_path / "probe.exr"]          # what the render reads
    assert sorted(map(str, s.input_files())) == sorted(map(str, [p, tmp_path / "probe.exr", tmp_path / "spare.binary"]))
