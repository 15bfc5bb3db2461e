"""Shared fixtures: where the real test data lives, and a skip when it is absent; a cache folder of the run
(``_run_cache``), so that the tests never write into the user's."""
from __future__ import annotations

import math
import os
import textwrap
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, settings

from warpbw.io.shared_data import shared_data_dir

ROOT = Path(__file__).resolve().parents[1]
# ../shared/data beside the repository; WARPBW_SHARED_DATA overrides it (as for the examples)
SHARED_DATA = shared_data_dir(ROOT)


def shared_file(rel: str) -> Path:
    """Path of a file under ../shared/data, or skip the test saying why."""
    p = SHARED_DATA / rel
    if not p.exists():
        pytest.skip(f"real test data {p} is absent (clone ../shared beside the repository or set $WARPBW_SHARED_DATA)")
    return p


def rewrite_asset(src: Path, dst: Path, arrays=None, params=None, drop=(), **fields) -> Path:
    """A copy of the asset file ``src`` with its header's ``fields`` and ``params`` replaced (``drop``: params
    removed) and ``arrays`` replaced, written with NumPy alone (a file of another version, format or settings)."""
    import json

    with np.load(src) as z:
        members = {k: z[k] for k in z.files}
    header = json.loads(str(members["__header__"]))
    header.update(fields)
    header["params"] = {k: v for k, v in {**header["params"], **(params or {})}.items() if k not in drop}
    members["__header__"] = np.array(json.dumps(header))
    members.update(arrays or {})
    with open(dst, "wb") as f:
        np.savez_compressed(f, **members)
    return dst


def load_example(name: str):
    """The module examples/NAME.py, imported from its file (examples/ is not a package)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(name, ROOT / "examples" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def lambert_sphere_scene(w: int, h: int) -> str:
    """A unit Lambert sphere of albedo 0.5 under a constant white sky, seen from (0, 0, 4) at 40 degrees, as a scene
    file of w x h pixels: the smallest scene a render needs (every covered pixel is the albedo)."""
    return (f"[camera]\nposition = [0.0, 0.0, 4.0]\nlook_at = [0.0, 0.0, 0.0]\nfov = 40.0\nresolution = [{w}, {h}]\n\n"
            "[environment]\nconstant = [1.0, 1.0, 1.0]\n\n"
            '[[object]]\nshape = "sphere"\nradius = 1.0\nmaterial = "m"\n\n'
            '[material.m]\ntype = "lambert"\nalbedo = 0.5\n')


# A plane beside a sphere sunk into it (both renderers, composited): test_end_to_end, test_bench.
MIXED_SCENE = """\
[camera]
position = [0.0, 1.5, 3.0]
look_at = [0.0, 0.0, 0.0]
fov = 40.0
resolution = [48, 32]

[environment]
procedural = "sky"

[[light]]
type = "directional"
direction = [0.3, 0.8, 0.5]
radiance = [2.0, 2.0, 2.0]

[[object]]
shape = "plane"
size = 3.0
material = "floor"

[[object]]
shape = "sphere"
radius = 0.5
center = [0.0, 0.1, 0.0]
material = "ball"

[material.floor]
type = "cook-torrance"
roughness = 0.2
f0 = [0.04, 0.04, 0.04]
diffuse = [0.5, 0.5, 0.5]

[material.ball]
type = "lambert"
albedo = 0.8
"""


# One plane with a Cook-Torrance material under directional lights (issue 4's scene syntax), as TOML text:
# test_filtering's scenes, and the planes of test_extremes and test_bad_input.
PLANE_F0 = (0.9, 0.75, 0.4)
PLANE_DIFFUSE = (0.05, 0.04, 0.02)
PLANE_LIGHT_DIR = (0.3, 0.8, -0.5)
PLANE_RADIANCE = (3.0, 2.5, 2.0)


def plane_scene_toml(material_extra: str = "", roughness: float = 0.2, position=(0.0, 1.5, 2.0),
                     resolution=(24, 16), size: float = 2.0, fov: float = 40.0, lights: int = 1,
                     environment: str = "", light_dir=PLANE_LIGHT_DIR, radiance=PLANE_RADIANCE,
                     diffuse=PLANE_DIFFUSE) -> str:
    """A camera looking at a plane of material "m" at the origin; `lights` directional lights (0-2),
    `environment` and `material_extra` (normal_map = ..., tiling = ...) appended as given; diffuse=None
    leaves the Lambert term out."""
    light = f"""
[[light]]
type = "directional"
direction = {list(light_dir)}
radiance = {list(radiance)}
"""
    second = """
[[light]]
type = "directional"
direction = [-0.6, 0.5, 0.4]
radiance = [0.5, 1.0, 1.5]
"""
    return textwrap.dedent(f"""\
        [camera]
        position = {list(position)}
        look_at = [0.0, 0.0, 0.0]
        fov = {fov}
        resolution = {list(resolution)}
        """) + environment + (light if lights > 0 else "") + (second if lights > 1 else "") + textwrap.dedent(f"""
        [[object]]
        shape = "plane"
        size = {size}
        material = "m"

        [material.m]
        type = "cook-torrance"
        roughness = {roughness}
        f0 = {list(PLANE_F0)}
        """) + (f"diffuse = {list(diffuse)}\n" if diffuse is not None else "") + material_extra


def exr_claiming_size(path, width: int, height: int) -> Path:
    """A 4 x 4 one-channel EXR whose header's dataWindow is rewritten to claim width x height texels (OpenEXR file
    layout: the attribute "dataWindow", type "box2i", a 4-byte size, then xMin yMin xMax yMax as int32): a few
    hundred bytes that a full read would try to decode as the size it claims."""
    import struct

    from warpbw.io.exr import write_exr

    path = Path(path)
    write_exr(path, np.zeros((4, 4, 1), np.float32), ["Y"])
    data = bytearray(path.read_bytes())
    at = data.index(b"dataWindow\0box2i\0") + len(b"dataWindow\0box2i\0") + 4
    data[at:at + 16] = struct.pack("<4i", 0, 0, width - 1, height - 1)
    path.write_bytes(bytes(data))
    return path


def damage_deflate_stream(path, member: str) -> Path:
    """Make the deflate stream of ``member`` (e.g. "density.npy") in the .npz ``path`` start with an invalid block
    type (RFC 1951: bits 1-2 of the first byte, 11 is reserved), as a torn sector would: reading it raises
    zlib.error before any CRC is checked.  The ZIP local header (PKWARE APPNOTE 4.3.7) is 30 bytes, then the
    name and the extra field, whose lengths it holds at offsets 26 and 28."""
    import struct
    import zipfile

    path = Path(path)
    with zipfile.ZipFile(path) as z:
        info = z.getinfo(member)
    assert info.compress_type == zipfile.ZIP_DEFLATED, info
    data = bytearray(path.read_bytes())
    name_len, extra_len = struct.unpack_from("<HH", data, info.header_offset + 26)
    data[info.header_offset + 30 + name_len + extra_len] |= 0b110
    path.write_bytes(bytes(data))
    return path


def check_colour_scale(exr_path, scale: dict, mask, log: bool) -> None:
    """A false-colour map's recorded scale (``colour_scales`` in a render's JSON) against its EXR: from the
    smallest to the largest value shown (over ``mask``; positive values only on a log scale), and the PNG beside
    the EXR says the same in its Description text chunk."""
    from PIL import Image

    from warpbw.io.exr import read_exr

    exr_path = Path(exr_path)
    v = read_exr(exr_path).pixels[..., 0]
    shown = v[np.asarray(mask, bool) & (v > 0)] if log else v[np.asarray(mask, bool)]
    assert shown.size, exr_path
    png = exr_path.with_suffix(".png")
    assert scale["png"] == png.name and scale["scale"] == ("log" if log else "linear")
    assert scale["from"] == pytest.approx(float(shown.min()), rel=1e-6)
    assert scale["to"] == pytest.approx(float(shown.max()), rel=1e-6)
    text = Image.open(png).text["Description"]
    assert ("log10" if log else "linear") in text, text
    assert f"from {scale['from']:.6g} (dark blue) to {scale['to']:.6g} (yellow)" in text, text


def named_as(src: Path, link: str | None, other: Path) -> Path:
    """An output path that is ``src`` itself (``link`` None), or ``other`` made a "symlink" or a "hardlink" to it:
    the three ways a writer can be handed its own input."""
    if link == "symlink":
        other.symlink_to(src)
    elif link == "hardlink":
        other.hardlink_to(src)
    return src if link is None else other


class Handed(Exception):
    """Raised by ``capture_call``'s stand-in once it has recorded what a command handed it."""


def capture_call(monkeypatch, module, name: str) -> dict:
    """Replace ``module.name`` by a stand-in that records its arguments (keywords by name, positionals as
    ``_args``) and stops the command with ``Handed``: the commands import the functions they call at call time,
    so the stand-in is what they call, and no rendering happens."""
    got = {}

    def fake(*args, **kwargs):
        got.update(kwargs, _args=args)
        raise Handed

    monkeypatch.setattr(module, name, fake)
    return got


def uniform_sampler_table(n_theta_o=None, n_u=None, n_phi=None):
    """A consistent ``SamplerTable`` (of warpbw.sampling's sizes unless given): every cell of every view bin equally
    likely, as ``build_sampler_table`` tabulates a BRDF black at every view.  Its CDFs rise from 0 to 1 in equal
    steps, and its density is each cell's share over the cell's du dphi = 1 / (2 pi)."""
    from warpbw.sampling import N_PHI, N_THETA_O, N_U, SamplerTable

    nt, nu, nphi = n_theta_o or N_THETA_O, n_u or N_U, n_phi or N_PHI
    return SamplerTable(np.linspace(0, 1, nu + 1, dtype=np.float32)[None].repeat(nt, 0),
                        np.linspace(0, 1, nphi + 1, dtype=np.float32)[None, None].repeat(nu, 1).repeat(nt, 0),
                        np.full((nt, nu, nphi), 1.0 / (2.0 * np.pi), np.float32))


def plot_png(path) -> np.ndarray:
    """A benchmark's plot: a whole PNG (its signature, and matplotlib reads it), a real figure (over 100 pixels a
    side) and not blank; returned as (H, W, 3+) floats."""
    import matplotlib.image

    with open(path, "rb") as f:
        assert f.read(8) == b"\x89PNG\r\n\x1a\n", path
    img = matplotlib.image.imread(path)
    assert img.ndim == 3 and min(img.shape[:2]) > 100 and np.ptp(img[..., :3]) > 0, (path, img.shape)
    return img


@pytest.fixture
def drawn_figures(monkeypatch):
    """The figures a plotting function saves (``matplotlib.figure.Figure.savefig``: the examples and bench draw on
    a ``Figure`` of their own, not pyplot's), so that a test reads back what they draw (the Axes' lines, bars,
    images, scales and labels) rather than their pixels."""
    import matplotlib.figure

    figures, save = [], matplotlib.figure.Figure.savefig

    def saved(fig, *args, **kwargs):
        figures.append(fig)
        return save(fig, *args, **kwargs)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", saved)
    return figures


def fake_npf_table(path: Path) -> Path:
    """An NPF table of the right size whose every value is 0.25: each row a valid (if odd) fit, reflecting 0.79 of
    the light it receives (precompute.brdf_sampling.ALBEDO_WARN)."""
    from warpbw.io.npf import NPF_FILE_SIZE

    np.full(NPF_FILE_SIZE // 4, 0.25, "<f4").tofile(path)
    return path


class StandInClock:
    """Stands in for a module's ``time``: ``perf_counter`` reads ``now``, which only the stand-ins that "take
    time" move, so a figure made of times is known exactly."""

    def __init__(self):
        self.now = 0.0

    def perf_counter(self):
        return self.now


_KILLED_WRITER = """
import sys, time
from pathlib import Path
from warpbw.io.staged import staged_outputs

out = Path(sys.argv[1])
with staged_outputs([out]) as temps:
    temps[out].write_bytes(b"half of it")
    print("written", flush=True)
    time.sleep(60)
"""


def kill_when_written(script: str, *args: str, timeout: float = 60.0) -> int:
    """Run ``script`` (Python source) in a child process with ``args``, SIGKILL it once it prints "written" (its
    outputs staged, not yet moved into place), and return its process id once it is gone (within ``timeout``
    seconds)."""
    import os
    import signal
    import subprocess
    import sys

    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    child = subprocess.Popen([sys.executable, "-c", script, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True, env=env)
    try:
        assert child.stdout.readline() == "written\n"
        child.send_signal(signal.SIGKILL)
        child.communicate(timeout=timeout)
    finally:
        child.kill()
    return child.pid


def killed_writer_temp(path) -> Path:
    """The hidden temporary that a real process, killed with SIGKILL while it wrote ``path`` (``staged_outputs``),
    left beside it (``path`` itself is as it was)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    before = set(path.parent.iterdir())
    pid = kill_when_written(_KILLED_WRITER, str(path))
    (temp,) = set(path.parent.iterdir()) - before
    assert temp.name.startswith(".") and f"-{pid}." in temp.name
    return temp


def attempt(f, *args, **kwargs):
    """``(value, "")`` when ``f`` returns, ``(None, message)`` when it refuses with a WarpbwError: a test then reads the
    value or fails on an assertion that prints the refusal, never on the exception."""
    from warpbw.errors import WarpbwError

    try:
        return f(*args, **kwargs), ""
    except WarpbwError as exc:
        return None, str(exc) or "(empty message)"


def outcome(f, *args, **kwargs) -> str:
    """What a call did, as text an assertion can print: "returned X", "WarpbwError: MESSAGE", "exit N" (argparse's
    usage errors), "Handed" (``capture_call``'s stand-in was reached), or "not a WarpbwError: ..." (a traceback the
    user would have seen)."""
    from warpbw.errors import WarpbwError

    try:
        return f"returned {f(*args, **kwargs)!r}"
    except WarpbwError as exc:
        return f"WarpbwError: {exc}"
    except Handed:
        return "Handed"
    except SystemExit as exc:
        return f"exit {exc.code}"
    except Exception as exc:   # noqa: BLE001
        return f"not a WarpbwError: {exc!r}"


def ref_half_diff_angles(wi, wo):
    """Rusinkiewicz theta_h, theta_d, phi_d (unfolded, in (-pi, pi]) of direction pairs, by projecting wi on the
    frame at h (u = R(phi_h) R(theta_h) e_x, v = R(phi_h) e_y) instead of the two rotations warpbw.io.merl uses:
    test_merl's and test_npf's reference for the MERL bins."""
    wi = wi / np.linalg.norm(wi, axis=-1, keepdims=True)
    wo = wo / np.linalg.norm(wo, axis=-1, keepdims=True)
    h = wi + wo
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    # the angles by atan2, not arccos: arccos near 1 loses theta to eps / sin(theta), and phi_d, read off a frame
    # turned by theta, to eps / (sin(theta_h) sin(theta_d)) (both within 1e-5 of the normal: 1.5e-4 of a phi_d bin,
    # where test_merl's "safe" margin is 1e-6 of a bin)
    th = np.arctan2(np.hypot(h[:, 0], h[:, 1]), h[:, 2])
    ph = np.arctan2(h[:, 1], h[:, 0])
    u = np.stack([np.cos(th) * np.cos(ph), np.cos(th) * np.sin(ph), -np.sin(th)], -1)
    v = np.stack([-np.sin(ph), np.cos(ph), np.zeros_like(ph)], -1)
    td = np.arctan2(np.linalg.norm(np.cross(wi, h), axis=-1), np.sum(wi * h, -1))
    pd = np.arctan2(np.sum(wi * v, -1), np.sum(wi * u, -1))
    return th, td, pd


def turned_about_y(v, theta_deg: float) -> np.ndarray:
    """Points or directions (..., 3) turned by theta_deg about +Y, right-handed (+90 degrees takes -Z to -X: the
    envmap's rotation and a mesh's rotate_y, README): the turned-world tests of test_gbuffer and test_adaptive."""
    c, s = math.cos(math.radians(theta_deg)), math.sin(math.radians(theta_deg))
    v = np.asarray(v, np.float64)
    return np.stack([v[..., 0] * c + v[..., 2] * s, v[..., 1], -v[..., 0] * s + v[..., 2] * c], -1)


def grid_mesh(n_u, n_v, fn):
    """Triangulated (n_u x n_v) vertex grid; fn(u, v) -> (N, 3) points; faces wound (dv x du)."""
    uu, vv = np.meshgrid(np.arange(n_u), np.arange(n_v), indexing="ij")
    verts = fn(uu.ravel(), vv.ravel())
    idx = np.arange(n_u * n_v).reshape(n_u, n_v)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    c, d = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([b, d, c], 1)])
    return verts, faces


def latlong_sphere_obj(nu: int, nv: int, radius: float, normals: bool = False, deform=None, uv: bool = True) -> str:
    """A lat-long sphere as an OBJ with a texture seam: the vertex at longitude 0 is written again at u = 1, and each
    pole once per column, as UV-unwrapped meshes are (``normals``: a ``vn`` per vertex, its own closed form).
    ``deform``: (N, 3) positions -> (N, 3), applied to the vertices written (a function of the position, so that the
    copies stay together); ``uv`` False: the same file without its ``vt``, whose copies a load merges (no seam)."""
    pts, uvs, faces = [], [], []
    for j in range(nv + 1):
        th = math.pi * j / nv
        for i in range(nu + 1):
            ph = 2.0 * math.pi * i / nu
            pts.append((math.sin(th) * math.sin(ph), math.cos(th), math.sin(th) * math.cos(ph)))
            uvs.append((i / nu, 1.0 - j / nv))
    unit = np.array(pts)
    pos = radius * unit if deform is None else np.asarray(deform(radius * unit), np.float64)
    lines = []
    for p, n, t in zip(pos, unit, uvs):
        lines.append("v %.12f %.12f %.12f" % tuple(p))
        if uv:
            lines.append("vt %.12f %.12f" % t)
        if normals:
            lines.append("vn %.12f %.12f %.12f" % tuple(n))
    ref = "{k}/{k}/{k}" if normals and uv else "{k}//{k}" if normals else "{k}/{k}" if uv else "{k}"
    for j in range(nv):
        for i in range(nu):
            a, b, c, d = (j * (nu + 1) + i + 1, j * (nu + 1) + i + 2, (j + 1) * (nu + 1) + i + 2,
                          (j + 1) * (nu + 1) + i + 1)
            for tri in ((a, d, c), (a, c, b)):
                faces.append("f " + " ".join(ref.format(k=k) for k in tri))
    return "\n".join(lines + faces) + "\n"


def numpy_camera_rays(position, look_at, fov_deg, w, h, jitter=(0.5, 0.5), up=(0.0, 1.0, 0.0)):
    """The origin and the unit rays (h, w, 3) through the point ``jitter`` (in [0, 1)^2) of every pixel: README's
    pinhole (fov along the width, right = forward x up, row 0 at the top)."""
    o = np.asarray(position, float)
    fwd = np.asarray(look_at, float) - o
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, np.asarray(up, float))
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    tx = math.tan(math.radians(fov_deg) / 2)
    ty = tx * h / w
    x, y = np.meshgrid(np.arange(w) + jitter[0], np.arange(h) + jitter[1])
    d = fwd + ((2 * x / w - 1) * tx)[..., None] * right + ((1 - 2 * y / h) * ty)[..., None] * up
    return o, d / np.linalg.norm(d, axis=-1, keepdims=True)


def numpy_square_distance(o, d, size, centre=(0.0, 0.0, 0.0)):
    """Distance along the unit rays ``d`` (..., 3) from ``o`` to a scene plane: the square of side ``size`` about
    ``centre`` in the plane y = centre[1] (XZ, facing +Y); inf where a ray misses it."""
    c = np.asarray(centre, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(d[..., 1] != 0, (c[1] - o[1]) / d[..., 1], -1.0)
    p = o + t[..., None] * d
    on = (t > 0) & (np.abs(p[..., 0] - c[0]) <= size / 2) & (np.abs(p[..., 2] - c[2]) <= size / 2)
    return np.where(on, t, np.inf)


def numpy_sphere_distance(o, d, centre, radius):
    """Distance along the unit rays ``d`` (..., 3) from ``o`` to the sphere: the quadratic's nearer root where it
    is positive, inf where a ray misses."""
    oc = o - np.asarray(centre, float)
    b = d @ oc
    disc = b * b - (oc @ oc - radius * radius)
    t = -b - np.sqrt(np.maximum(disc, 0.0))
    return np.where((disc > 0) & (t > 0), t, np.inf)


@pytest.fixture
def tqdm_bars(monkeypatch):
    """``tqdm.tqdm`` replaced by a stand-in that records each bar made (its ``total``, ``desc`` and the count ``n``
    its updates add up to); yields the list of bars, in the order they were made."""
    import tqdm

    bars = []

    class Bar:
        def __init__(self, total, **kw):
            self.total, self.n, self.desc = total, 0, kw.get("desc")
            bars.append(self)

        def update(self, k):
            self.n += k

        def close(self):
            pass

    monkeypatch.setattr(tqdm, "tqdm", Bar)
    return bars


@pytest.fixture(scope="session")
def shared():
    return shared_file


@pytest.fixture(scope="session", autouse=True)
def _run_cache(tmp_path_factory):
    """The tables the renderer caches (sampling, bandwidth, GMM, ground truth) go to a folder of this test run,
    never the user's ``$WARPBW_CACHE`` or ``~/.cache/warpbw``; command-line tests' children inherit it.  A test that
    needs another folder sets its own with ``monkeypatch``, which restores this one afterwards."""
    patch = pytest.MonkeyPatch()
    patch.setenv("WARPBW_CACHE", str(tmp_path_factory.mktemp("warpbw_cache")))
    yield
    patch.undo()


# Hypothesis's examples (session 81).  A local run draws new examples on every run, after replaying the failures its
# example database (.hypothesis/) holds: the runs that explore.  A CI run ($CI set, as CI services set it) takes the
# profile "ci": derandomize, each test's examples drawn from a seed hashed from its source, the same on every run
# under one Hypothesis version; no database (a fresh clone has none), and the blob that replays a failure printed.  A
# rare draw then fails the local run that meets it, where it can be looked into, not a landing at random; a regression
# the fixed draws reach fails CI on every run.  The profile is Hypothesis's own "ci" (which Hypothesis loads itself
# when $CI is set to anything), written here so that the choice does not hang on its version; CI=false or 0 is local.
# `--hypothesis-profile NAME` on the command line overrides it (Hypothesis's pytest plugin loads it after this file).
settings.register_profile("ci", derandomize=True, database=None, print_blob=True, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])


def hypothesis_profile(environ) -> str:
    """The profile the suite runs under: "ci" where ``environ`` has CI set (to anything but "", "0", "false",
    "no"), else Hypothesis's "default"."""
    return "ci" if environ.get("CI", "").strip().lower() not in ("", "0", "false", "no") else "default"


settings.load_profile(hypothesis_profile(os.environ))


# Warp: hide the banner and module-load lines in test output (warp._src.logger.LOG_WARNING).
def pytest_configure(config):
    import warp as wp

    wp.config.log_level = 30


# The test modules from the longest to the shortest (session 80: each module's summed test times in a run from a
# cold Warp kernel cache on 2 cores, --junitxml; test_bad_input alone was 31% of the sum).  With --dist loadfile and
# --no-loadscope-reorder (pyproject.toml) the workers take the modules in this order, the longest first
# (longest-processing-time-first): xdist's default, most tests first, started test_batch (13 tests, 5% of the time)
# near the end, with the other worker idle once it ran out of modules.  A module not listed (a new one) comes after
# these, in file order; the tests within a module keep the file's order (a stable sort), and no test changes.
SLOW_MODULES_FIRST = (
    "test_bad_input.py", "test_end_to_end.py", "test_brdf_bandwidth.py", "test_sampling.py", "test_batch.py",
    "test_bandwidth.py", "test_bench.py", "test_extremes.py", "test_filtering.py", "test_dynamic_geometry.py",
    "test_shading.py", "test_bench_filtering.py", "test_mirror_smear.py", "test_wavelets.py", "test_adaptive.py",
    "test_validate_bandwidth.py", "test_gmm_mipmap.py", "test_lights.py", "test_npf.py", "test_brdf_sampling.py",
    "test_envmap.py", "test_gbuffer.py", "test_merl.py", "test_allocation_ceiling.py", "test_read_assets.py",
    "test_brdf.py", "test_io_staged.py")


@pytest.hookimpl(trylast=True)   # after any plugin that reorders tests: the modules' order is set last
def pytest_collection_modifyitems(config, items):
    rank = {name: i for i, name in enumerate(SLOW_MODULES_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))
