"""Scene files (TOML): parsing and validation, and the embedded default scene.

Public:
    ``load_scene(path) -> Scene``               read and validate a scene file
    ``parse_scene(text, base_dir, source) -> Scene``  the same from a string
    ``default_scene() -> Scene``                the embedded demo scene (needs no file)
    ``check_scene(scene) -> Scene``             a checked copy of a Scene built or edited in Python
    ``Scene``, ``Camera``, ``Environment``, ``DirectionalLight``, ``SphereObject``, ``MeshObject``,
    ``PlaneObject``, ``Material``, ``DEFAULT_SCENE_TOML``; ``Scene.input_files()``, every file a scene reads;
    ``Scene.content_hash()``, of its content and files, and ``Scene.reference_hash()``, of what the reference renders
    ``file_digest(path) -> str``               blake2b of a file's bytes (the content hashes of scenes and tables)
    ``toml_string(text, what)``, ``toml_escape(text, what)``  a path written into a scene file by a tool
    ``GMM_MAX_COMPONENTS``                     the most components a material's ``gmm_components`` may ask for
    ``SCENE_FILE_MAX_BYTES``                   the largest scene file read (checked before reading)

Lights: an ``[environment]`` and/or ``[[light]]`` tables (``type = "directional"``, ``direction`` towards the
light, ``radiance``); a scene needs at least one of them (``Scene.environment`` is None without one).
Directional lights light planes (``warpbw.filtering``) and spheres and meshes (``warpbw.lights``) alike.
Planes (``shape = "plane"``: a square of side ``size`` in the XZ plane facing +Y, centred at ``center``,
uv in [0, 1]^2 with u along +X and v along +Z; seen from above only, a camera below one sees through it) carry
``cook-torrance`` materials with an optional normal map (004); they are rendered by ``warpbw.filtering``, and may
share a scene with spheres and meshes (``warpbw.pipeline.render_with_planes``).

Every error is a ``WarpbwError`` naming the scene file and the key, e.g.
``scene.toml: [camera].resolution: expected two positive integers [width, height], got [-1, 512]``.
Paths are relative to the scene file.  Unknown keys are errors too (a typo silently ignored would
render the wrong scene).
"""
from __future__ import annotations

import hashlib
import json
import math
import sys
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

from warpbw.errors import FLOAT32_MAX, WarpbwError, check_path, is_int
from warpbw.io.mesh_files import suffix_problem
from warpbw.io.staged import check_name_length

MATERIAL_TYPES = ("lambert", "ggx", "merl", "npf", "cook-torrance")
LIGHT_TYPES = ("directional",)
NORMAL_MAP_KINDS = ("height", "normal")
# Smallest Cook-Torrance roughness m accepted: the Gaussian NDF's per-axis variance m^2 / 2 must stay well
# above float32 resolution in the kernels (warpbw.filtering).
CT_MIN_ROUGHNESS = 1.0e-3
# Largest tiling: more repeats than this across one plane is almost certainly a typo.
MAX_TILING = 4096
# Gaussians per texel of a GMM mipmap: 004 Sec. 4.2 uses four; the bound is precompute.gmm_mipmap's
# MAX_COMPONENTS (spelled here so that parsing a scene needs no precompute import)
GMM_DEFAULT_COMPONENTS = 4
GMM_MAX_COMPONENTS = 16
# The alignment constant c of the GMM builder's MAP prior: 004 Sec. 4.1 sets it to 1 (precompute.gmm_mipmap's
# DEFAULT_PRIOR); the bound only catches typos (the prior then outweighs the data many times over)
GMM_DEFAULT_PRIOR = 1.0
GMM_MAX_PRIOR = 1.0e6
PROCEDURAL_ENVIRONMENTS = ("sky",)
LOOKUP_MODES = ("nearest", "linear")
# A tabulated material's lookup when its scene names none.  MERL's own is the nearest bin; an NPF fit's 90-bin curves
# sample smooth functions, read between bin centres ("linear interpolation between bin centres is better", data
# README, npf.bin layout; the nearest bins' steps put nu_rho cells up to 1.9x above the curves').  The precomputed
# tables of each kind are built with the same lookup by default (precompute.brdf_sampling.TABLE_LOOKUP).
LOOKUP_DEFAULT = {"merl": "nearest", "npf": "linear"}
MAX_RESOLUTION = 16384  # per side; larger is almost certainly a typo (and would not fit in memory)
# A scene file's size, checked before it is read: a scene is a few kB of TOML (meshes, maps and probes are files it
# names), and a 1 GB data file given by mistake took 2 GB of memory and seconds to be called "not valid TOML"
SCENE_FILE_MAX_BYTES = 4 << 20
# Smallest GGX alpha accepted (a mirror at any image resolution); warpbw.brdf clamps to the same bound (it imports it).
GGX_MIN_ALPHA = 1.0e-4
# Largest eta or k of a conductor (warpbw.brdf refuses more, with this bound): measured metals lie below
# 100 in the visible; from about 5e9 the Fresnel terms' squares overflow float32 and a mirror rendered black.
CONDUCTOR_INDEX_MAX = 1.0e4

DEFAULT_SCENE_TOML = """\
# warpbw's embedded default scene: three spheres with analytic materials under the procedural sky.
[camera]
position = [0.0, 0.8, 5.2]
look_at = [0.0, 0.05, 0.0]
up = [0.0, 1.0, 0.0]
fov = 40.0
resolution = [384, 256]

[environment]
procedural = "sky"
rotation = 30.0
scale = 1.0

[[object]]
shape = "sphere"
center = [-1.25, 0.0, 0.0]
radius = 0.6
material = "clay"

[[object]]
shape = "sphere"
center = [0.0, 0.0, 0.0]
radius = 0.6
material = "gold"

[[object]]
shape = "sphere"
center = [1.25, 0.0, 0.0]
radius = 0.6
material = "glossy"

[material.clay]
type = "lambert"
albedo = [0.75, 0.45, 0.3]

[material.gold]
type = "ggx"
alpha = 0.15
specular = [1.0, 1.0, 1.0]
eta = [0.143, 0.374, 1.442]     # gold, complex IOR at R, G, B
k = [3.983, 2.385, 1.603]

[material.glossy]
type = "ggx"
alpha = 0.35
specular = [0.3, 0.5, 0.9]
"""


@dataclass(frozen=True)
class Camera:
    position: tuple
    look_at: tuple
    up: tuple
    fov: float            # degrees, along the image width
    width: int
    height: int


@dataclass(frozen=True)
class Environment:
    file: Path | None = None
    procedural: str | None = None
    constant: tuple | None = None
    rotation: float = 0.0  # degrees about +Y, right-handed (+90 turns +X to -Z; warpbw.envmap), as rotate_y
    scale: float = 1.0

    def describe(self) -> str:
        """One line for ``warpbw info``: the source, rotation and scale."""
        src = (f"file {self.file}" if self.file else f"procedural {self.procedural}" if self.procedural
               else f"constant {list(self.constant)}")
        return f"{src}, rotation {self.rotation:g} deg, scale {self.scale:g}"


@dataclass(frozen=True)
class SphereObject:
    center: tuple
    radius: float
    material: str

    def describe(self) -> str:
        """One line for ``warpbw info``."""
        return f"sphere r={self.radius:g} at {list(self.center)} material={self.material}"


@dataclass(frozen=True)
class MeshObject:
    file: Path
    material: str
    translate: tuple = (0.0, 0.0, 0.0)
    scale: float = 1.0
    rotate_y: float = 0.0  # degrees about +Y, right-handed (+90 turns +X to -Z), after scale, before translate

    def describe(self) -> str:
        """One line for ``warpbw info``: the file, its transform where it is not the identity, the material."""
        moves = ((f" scale={self.scale:g}" if self.scale != 1.0 else "")
                 + (f" rotate_y={self.rotate_y:g} deg" if self.rotate_y != 0.0 else "")
                 + (f" translate={list(self.translate)}" if any(t != 0.0 for t in self.translate) else ""))
        return f"mesh {self.file}{moves} material={self.material}"


@dataclass(frozen=True)
class PlaneObject:
    center: tuple
    size: float
    material: str

    def describe(self) -> str:
        """One line for ``warpbw info``."""
        return f"plane size={self.size:g} at {list(self.center)} material={self.material}"


@dataclass(frozen=True)
class DirectionalLight:
    direction: tuple      # unit vector towards the light
    radiance: tuple       # RGB; a surface facing the light receives irradiance radiance * cos(theta)

    def describe(self) -> str:
        """One line for ``warpbw info``."""
        return f"directional towards {[round(c, 4) for c in self.direction]} radiance {list(self.radiance)}"


@dataclass(frozen=True)
class Material:
    name: str
    type: str
    albedo: tuple = (0.0, 0.0, 0.0)
    alpha: float = 0.0
    specular: tuple = (0.0, 0.0, 0.0)
    eta: tuple | None = None
    k: tuple | None = None
    file: Path | None = None          # merl .binary
    table: Path | None = None         # npf table
    npf_name: str | None = None
    lookup: str | None = None         # merl / npf: nearest bin or linear between bin centres (None: LOOKUP_DEFAULT)
    sampling: Path | None = None      # merl / npf: precomputed sampling tables (built and cached if absent)
    bandwidth: Path | None = None     # merl / npf: precomputed nu_rho table (adaptive method; built, cached if absent)
    # cook-torrance (004 Sec. 3): Gaussian NDF of roughness m, Schlick Fresnel from f0, Lambert albedo
    roughness: float = 0.0
    f0: tuple = (0.0, 0.0, 0.0)
    diffuse: tuple = (0.0, 0.0, 0.0)
    normal_map: Path | None = None    # height field or tangent-space normal map (EXR / PNG)
    normal_map_kind: str = "height"
    normal_map_scale: float = 1.0     # heights (in units of the map's width) times this
    tiling: float = 1.0               # repeats of the map across the surface
    gmm: Path | None = None           # precomputed GMM mipmap (built and cached if absent)
    gmm_components: int = GMM_DEFAULT_COMPONENTS   # Gaussians per texel of the built (or given) GMM mipmaps
    gmm_prior: float = GMM_DEFAULT_PRIOR           # alignment constant c of the built (or given) aligned one

    def __post_init__(self):
        if self.lookup is None:   # the kind's (other kinds look nothing up: "nearest", as their hashes always held)
            object.__setattr__(self, "lookup", LOOKUP_DEFAULT.get(self.type, "nearest"))


@dataclass
class Scene:
    camera: Camera
    environment: Environment
    objects: list
    materials: dict
    source: str = "<string>"
    base_dir: Path = field(default_factory=Path.cwd)
    lights: list = field(default_factory=list)

    @property
    def has_planes(self) -> bool:
        """True when some object is a plane (rendered by ``warpbw.filtering``)."""
        return any(isinstance(o, PlaneObject) for o in self.objects)

    @property
    def has_surfaces(self) -> bool:
        """True when some object is a sphere or a mesh (rendered by ``warpbw.pipeline``)."""
        return any(not isinstance(o, PlaneObject) for o in self.objects)

    def input_files(self) -> list:
        """Every file the scene names or is read from: the scene file, the probe, meshes, BRDF files and tables,
        normal maps and precomputed assets, unused materials' too (a command's outputs may not replace them)."""
        source = [Path(self.source)] if Path(self.source).is_file() else []   # not "<string>" / "<default scene>"
        return source + self._files(self.materials)

    @property
    def material_order(self) -> list:
        """Material names in id order: only materials some object uses (one table each in memory)."""
        used = []
        for o in self.objects:
            if o.material not in used:
                used.append(o.material)
        return used

    def content_hash(self) -> str:
        """A hash of the scene's content and of the files it names (for caching ground truths): a file enters by
        its bytes' digest, not its path, so the same scene copied to another folder, or a probe renamed, hashes
        alike (a moved bench folder rendered its ground truths again)."""
        digests = {p: file_digest(p) for p in self.files()}

        def text(x) -> bytes:
            return json.dumps(_jsonable(x, digests), sort_keys=True).encode()

        h = hashlib.blake2b(digest_size=16)
        h.update(text(asdict(self.camera)))
        if self.environment is not None:
            h.update(text(asdict(self.environment)))
            if self.environment.file is not None:
                from warpbw.io.exr import colour_conversion

                # a probe read converted to Rec. 709 (since session 75) renders other ground truths than earlier
                # code did from the same bytes; one read as stored adds nothing, and its hashes stay as they were
                h.update((colour_conversion(self.environment.file) or "").encode())
        for li in self.lights:
            h.update(text({"light": asdict(li)}))
        for o in self.objects:
            h.update(text(asdict(o)))
        for name in self.material_order:
            h.update(text(_material_fields(self.materials[name])))
        return h.hexdigest()

    def reference_hash(self) -> str:
        """``content_hash`` of what the forward reference renders (the key of ``warpbw bench``'s cached ground truths):
        the scene without its materials' ``bandwidth`` files, nu_rho tables only the adaptive method's pass reads, so
        that a table built again does not render a ground truth again.  A scene that names no such file hashes as
        ``content_hash`` does (ground truths cached before session 70 stay valid)."""
        mats = {name: replace(m, bandwidth=None) for name, m in self.materials.items()}
        return replace(self, materials=mats).content_hash()

    def files(self) -> list:
        """Every file the scene reads."""
        return self._files(self.material_order)

    def _files(self, material_names) -> list:
        """The probe, the meshes, and the files of the materials ``material_names``, each once (materials sharing a
        normal map, meshes placed twice: ``warpbw info`` listed such a file once per use)."""
        out = []
        if self.environment is not None and self.environment.file is not None:
            out.append(self.environment.file)
        out += [o.file for o in self.objects if isinstance(o, MeshObject)]
        for name in material_names:
            m = self.materials[name]
            out += [p for p in (m.file, m.table, m.sampling, m.bandwidth, m.normal_map, m.gmm) if p is not None]
        return list(dict.fromkeys(out))


# Material fields only cook-torrance materials use: left out of other materials' hashes, so that the hashes
# (and the ground truths cached under them) of scenes written before these fields existed stay the same.
_CT_FIELDS = ("roughness", "f0", "diffuse", "normal_map", "normal_map_kind", "normal_map_scale", "tiling", "gmm",
              "gmm_components", "gmm_prior")


def _material_fields(m: Material) -> dict:
    d = asdict(m)
    if m.type != "cook-torrance":
        for k in _CT_FIELDS:
            d.pop(k)
    return d


def toml_escape(text: str, what: str) -> str:
    """``text`` escaped for the inside of a TOML basic string ("..."), for tools that write scene files: a double
    quote and a backslash by a backslash, a control character (U+0000-U+001F, U+007F) by its \\uXXXX code, any
    other character as it is (UTF-8; json.dumps wrote a non-BMP one as a surrogate pair, which TOML refuses).  A
    text no UTF-8 file can hold (lone surrogates: a file name of undecodable bytes) is a WarpbwError naming
    ``what`` (an option and its value)."""
    if any(0xD800 <= ord(c) <= 0xDFFF for c in text):
        raise WarpbwError(f"{what}: cannot be written in a scene file (expected a path of valid UTF-8 characters)")

    def escaped(c: str) -> str:
        if c in '"\\':
            return "\\" + c
        return f"\\u{ord(c):04X}" if ord(c) < 0x20 or ord(c) == 0x7F else c

    return "".join(map(escaped, text))


def toml_string(text: str, what: str) -> str:
    """``text`` as a TOML basic string, quotes included (``toml_escape``)."""
    return '"' + toml_escape(text, what) + '"'


def file_digest(path: Path, chunk: int = 1 << 22) -> str:
    """blake2b digest of a file's bytes."""
    path = check_path(path, "file_digest: path")   # an int was open()'s file descriptor: hashed it, then closed it
    h = hashlib.blake2b(digest_size=16)
    with open(path, "rb") as f:
        while True:
            b = f.read(chunk)
            if not b:
                break
            h.update(b)
    return h.hexdigest()


def _jsonable(x: Any, digests: dict | None = None):
    """``x`` with paths as text, or, for those in ``digests``, as ``{"file": DIGEST}``."""
    if isinstance(x, dict):
        return {k: _jsonable(v, digests) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v, digests) for v in x]
    if isinstance(x, Path):
        return {"file": digests[x]} if digests and x in digests else str(x)
    return x


# ---------------------------------------------------------------------------------------------
# Validation helpers: each names the key in its error
# ---------------------------------------------------------------------------------------------

class _Ctx:
    def __init__(self, source: str, base_dir: Path):
        self.source = source
        self.base_dir = base_dir

    def fail(self, key: str, msg: str):
        raise WarpbwError(f"{self.source}: {key}: {msg}")

    def table(self, d: dict, key: str, allowed: tuple, required: tuple = ()):
        if not isinstance(d, dict):
            self.fail(key, f"expected a table, got {d!r}")
        for k in d:
            if k not in allowed:
                self.fail(f"{key}.{k}" if key else k, f"unknown key (expected one of: {', '.join(allowed)})")
        for k in required:
            if k not in d:
                self.fail(f"{key}.{k}", "missing required key")
        return d

    def number(self, v, key: str, lo=None, hi=None, lo_open=False) -> float:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            self.fail(key, f"expected a finite number, got {v!r}")
        if is_int(v) and abs(v) > FLOAT32_MAX:  # float(v) may overflow; hundreds of digits are too long to repeat
            self.fail(key, f"expected a finite number within the float32 range (|x| <= {FLOAT32_MAX:.4g}), "
                      f"got an integer of {len(str(abs(v)))} digits")
        v = float(v)
        if not math.isfinite(v):
            self.fail(key, f"expected a finite number, got {v!r}")
        if abs(v) > FLOAT32_MAX:  # the kernels compute in float32
            self.fail(key, f"expected a number within the float32 range (|x| <= {FLOAT32_MAX:.4g}), got {v:g}")
        if lo is not None and (v < lo or (lo_open and v == lo)):
            self.fail(key, f"expected a number {'>' if lo_open else '>='} {lo:g}, got {v:g}")
        if hi is not None and v > hi:
            self.fail(key, f"expected a number <= {hi:g}, got {v:g}")
        return v

    def vec3(self, v, key: str, lo=None, point: bool = False, hi=None) -> tuple:
        """Three numbers; one number stands for three equal ones (a grey colour) unless ``point`` (a position
        or direction, where 4.0 for [4, 4, 4] is more likely a slip than a wish)."""
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            if point:
                self.fail(key, f"expected three numbers [x, y, z] (a point or direction, not one number), got {v!r}")
            v = [v, v, v]
        if not isinstance(v, list) or len(v) != 3:
            self.fail(key, f"expected three numbers [x, y, z], got {v!r}")
        return tuple(self.number(c, key, lo=lo, hi=hi) for c in v)

    def string(self, v, key: str, choices=None) -> str:
        if not isinstance(v, str) or not v:
            self.fail(key, f"expected a non-empty string, got {v!r}")
        if choices is not None and v not in choices:
            self.fail(key, f"unknown value {v!r} (expected one of: {', '.join(choices)})")
        return v

    def path(self, v, key: str) -> Path:
        s = self.string(v, key)
        p = Path(s).expanduser()
        if not p.is_absolute():
            p = self.base_dir / p
        if not p.exists():
            self.fail(key, f"file not found: {p}")
        if not p.is_file():
            self.fail(key, f"not a file: {p}")
        return p


def _camera(ctx: _Ctx, d: dict) -> Camera:
    ctx.table(d, "[camera]", ("position", "look_at", "up", "fov", "resolution"),
              required=("position", "look_at", "fov", "resolution"))
    pos = ctx.vec3(d["position"], "[camera].position", point=True)
    at = ctx.vec3(d["look_at"], "[camera].look_at", point=True)
    up = ctx.vec3(d.get("up", [0.0, 1.0, 0.0]), "[camera].up", point=True)
    fov = ctx.number(d["fov"], "[camera].fov", lo=0.0, lo_open=True)
    if fov >= 180.0:
        ctx.fail("[camera].fov", f"expected degrees in (0, 180), got {fov:g}")
    res = d["resolution"]
    if (not isinstance(res, list) or len(res) != 2
            or not all(is_int(r) and r > 0 for r in res)):
        ctx.fail("[camera].resolution", f"expected two positive integers [width, height], got {res!r}")
    if max(res) > MAX_RESOLUTION:
        ctx.fail("[camera].resolution", f"expected at most {MAX_RESOLUTION} pixels per side, got {res!r}")
    fwd = [a - b for a, b in zip(at, pos)]
    # relative to the scene's scale: warpbw.gbuffer.check_reach says how far down a scene may be scaled
    if math.hypot(*fwd) <= 1e-12 * max(math.hypot(*at), math.hypot(*pos)):
        ctx.fail("[camera].look_at", "must differ from [camera].position")
    n_up = math.hypot(*up)
    if n_up == 0.0:
        ctx.fail("[camera].up", "must not be zero or parallel to the viewing direction")
    f = [c / math.hypot(*fwd) for c in fwd]
    u = [c / n_up for c in up]
    cross = (f[1] * u[2] - f[2] * u[1], f[2] * u[0] - f[0] * u[2], f[0] * u[1] - f[1] * u[0])
    if math.hypot(*cross) < 1e-9:
        ctx.fail("[camera].up", "must not be zero or parallel to the viewing direction")
    return Camera(pos, at, up, fov, int(res[0]), int(res[1]))


def _environment(ctx: _Ctx, d: dict) -> Environment:
    ctx.table(d, "[environment]", ("file", "procedural", "constant", "rotation", "scale"))
    given = [k for k in ("file", "procedural", "constant") if k in d]
    if len(given) != 1:
        ctx.fail("[environment]", "expected exactly one of file = \"probe.exr\", procedural = \"sky\", "
                 f"constant = [r, g, b]; got {given or 'none'}")
    rot = ctx.number(d.get("rotation", 0.0), "[environment].rotation")
    scale = ctx.number(d.get("scale", 1.0), "[environment].scale", lo=0.0)
    if "file" in d:
        return Environment(file=ctx.path(d["file"], "[environment].file"), rotation=rot, scale=scale)
    if "procedural" in d:
        return Environment(procedural=ctx.string(d["procedural"], "[environment].procedural",
                                                 PROCEDURAL_ENVIRONMENTS), rotation=rot, scale=scale)
    constant = ctx.vec3(d["constant"], "[environment].constant", lo=0.0)
    if max(constant) * scale > FLOAT32_MAX:  # the radiance the kernels see is constant * scale, in float32
        ctx.fail("[environment].scale", f"constant * scale must stay within the float32 range "
                 f"(<= {FLOAT32_MAX:.4g}), got {max(constant):g} * {scale:g}")
    return Environment(constant=constant, rotation=rot, scale=scale)


def _light(ctx: _Ctx, d: dict, i: int) -> DirectionalLight:
    key = f"[[light]] #{i + 1}"
    if not isinstance(d, dict):
        ctx.fail(key, f"expected a table, got {d!r}")
    ctx.table(d, key, ("type", "direction", "radiance"), required=("type", "direction", "radiance"))
    ctx.string(d["type"], f"{key}.type", LIGHT_TYPES)
    direction = ctx.vec3(d["direction"], f"{key}.direction", point=True)
    big = max(abs(c) for c in direction)   # scaled: [0, 1e-10, 0] is a direction (an absolute 1e-9 floor refused it)
    if big == 0.0:
        ctx.fail(f"{key}.direction", f"expected a non-zero vector towards the light, got {list(direction)}")
    # subnormal components (the largest below the normal range) are scaled by the largest first: their length kept
    # few digits ([1e-320, 3e-320, 0] was stored 7e-5 longer than unit); others as they are (the same bits as before)
    scaled = tuple(c / big for c in direction) if big < sys.float_info.min else direction
    length = math.hypot(*scaled)
    radiance = ctx.vec3(d["radiance"], f"{key}.radiance", lo=0.0)
    return DirectionalLight(tuple(c / length for c in scaled), radiance)


def _object(ctx: _Ctx, d: dict, i: int, materials: dict):
    key = f"[[object]] #{i + 1}"
    if not isinstance(d, dict):
        ctx.fail(key, f"expected a table, got {d!r}")
    if ("shape" in d) == ("mesh" in d):
        ctx.fail(key, "expected exactly one of shape = \"sphere\" / \"plane\" or mesh = \"file.obj\"")
    # keys first: a misspelt key ("materal") is reported as unknown, not as a missing "material"
    if d.get("shape") == "mesh":   # the one shape that is not a shape: meshes name their file instead
        ctx.fail(f"{key}.shape", 'a mesh object is written mesh = "file.obj" without shape; shape is "sphere" '
                 'or "plane"')
    if "shape" in d:
        ctx.string(d["shape"], f"{key}.shape", ("sphere", "plane"))
    if "shape" in d and d["shape"] == "plane":
        ctx.table(d, key, ("shape", "center", "size", "material"), required=("material", "size"))
    elif "shape" in d:
        ctx.table(d, key, ("shape", "center", "radius", "material"), required=("material", "radius"))
    else:
        ctx.table(d, key, ("mesh", "material", "translate", "scale", "rotate_y"), required=("material",))
    mat = ctx.string(d["material"], f"{key}.material")
    if mat not in materials:
        ctx.fail(f"{key}.material", f"no [material.{mat}] in the scene (defined: "
                 f"{', '.join(materials) or 'none'})")
    if "mesh" in d and materials[mat].type == "cook-torrance":
        ctx.fail(f"{key}.material", "cook-torrance materials apply to planes only (shape = \"plane\"), not to a mesh")
    if "shape" in d:
        shape = ctx.string(d["shape"], f"{key}.shape", ("sphere", "plane"))
        if shape == "plane":
            if materials[mat].type != "cook-torrance":
                ctx.fail(f"{key}.material", f"planes take a cook-torrance material, [material.{mat}] is "
                         f"{materials[mat].type!r}")
            return PlaneObject(ctx.vec3(d.get("center", [0.0, 0.0, 0.0]), f"{key}.center", point=True),
                               ctx.number(d["size"], f"{key}.size", lo=0.0, lo_open=True), mat)
        if materials[mat].type == "cook-torrance":
            ctx.fail(f"{key}.material", f"cook-torrance materials apply to planes only (shape = \"plane\"), "
                     f"not to a {shape}")
        return SphereObject(ctx.vec3(d.get("center", [0.0, 0.0, 0.0]), f"{key}.center", point=True),
                            ctx.number(d["radius"], f"{key}.radius", lo=0.0, lo_open=True), mat)
    obj = MeshObject(ctx.path(d["mesh"], f"{key}.mesh"), mat,
                     ctx.vec3(d.get("translate", [0.0, 0.0, 0.0]), f"{key}.translate", point=True),
                     ctx.number(d.get("scale", 1.0), f"{key}.scale", lo=0.0, lo_open=True),
                     ctx.number(d.get("rotate_y", 0.0), f"{key}.rotate_y"))
    problem = suffix_problem(obj.file)
    if problem:   # here, not after loading the probe, and not left unsaid by warpbw info
        ctx.fail(f"{key}.mesh", problem)
    return obj


_MATERIAL_KEYS = {
    "lambert": (("type", "albedo"), ("albedo",)),
    "ggx": (("type", "alpha", "specular", "eta", "k"), ("alpha", "specular")),
    "merl": (("type", "file", "lookup", "sampling", "bandwidth"), ("file",)),
    "npf": (("type", "table", "name", "lookup", "sampling", "bandwidth"), ("table", "name")),
    "cook-torrance": (("type", "roughness", "f0", "diffuse", "normal_map", "normal_map_kind", "normal_map_scale",
                       "tiling", "gmm", "gmm_components", "gmm_prior"), ("roughness", "f0")),
}


def _cook_torrance(ctx: _Ctx, name: str, key: str, d: dict) -> Material:
    rough = ctx.number(d["roughness"], f"{key}.roughness", lo=CT_MIN_ROUGHNESS, hi=1.0)
    f0 = ctx.vec3(d["f0"], f"{key}.f0", lo=0.0)
    if max(f0) > 1.0:
        ctx.fail(f"{key}.f0", f"expected Fresnel reflectance components in [0, 1], got {f0}")
    diffuse = ctx.vec3(d.get("diffuse", 0.0), f"{key}.diffuse", lo=0.0)
    if max(diffuse) > 1.0:
        ctx.fail(f"{key}.diffuse", f"expected components in [0, 1] (energy conservation), got {diffuse}")
    for k in ("normal_map_kind", "normal_map_scale", "tiling", "gmm", "gmm_components", "gmm_prior"):
        if k in d and "normal_map" not in d:
            ctx.fail(f"{key}.{k}", "applies only with a normal_map")
    nmap = ctx.path(d["normal_map"], f"{key}.normal_map") if "normal_map" in d else None
    kind = ctx.string(d.get("normal_map_kind", "height"), f"{key}.normal_map_kind", NORMAL_MAP_KINDS)
    scale = ctx.number(d.get("normal_map_scale", 1.0), f"{key}.normal_map_scale", lo=0.0, lo_open=True)
    if "normal_map_scale" in d and kind != "height":
        ctx.fail(f"{key}.normal_map_scale", "applies only to normal_map_kind = \"height\"")
    tiling = ctx.number(d.get("tiling", 1.0), f"{key}.tiling", lo=0.0, lo_open=True, hi=MAX_TILING)
    gmm = ctx.path(d["gmm"], f"{key}.gmm") if "gmm" in d else None
    k_gmm = d.get("gmm_components", GMM_DEFAULT_COMPONENTS)
    if not is_int(k_gmm) or not 1 <= k_gmm <= GMM_MAX_COMPONENTS:
        ctx.fail(f"{key}.gmm_components", f"expected an integer from 1 to {GMM_MAX_COMPONENTS}, got {k_gmm!r}")
    c_gmm = ctx.number(d.get("gmm_prior", GMM_DEFAULT_PRIOR), f"{key}.gmm_prior", lo=0.0, hi=GMM_MAX_PRIOR)
    return Material(name, "cook-torrance", roughness=rough, f0=f0, diffuse=diffuse, normal_map=nmap,
                    normal_map_kind=kind, normal_map_scale=scale, tiling=tiling, gmm=gmm, gmm_components=k_gmm,
                    gmm_prior=c_gmm)


def _material(ctx: _Ctx, name: str, d: dict) -> Material:
    if not name:   # no object can name it (an object's material = "" is refused), and lists showed it as a blank
        ctx.fail('[material.""]', "expected a non-empty material name (objects refer to a material by its name)")
    key = f"[material.{name}]"
    if not isinstance(d, dict):
        ctx.fail(key, f"expected a table, got {d!r}")
    if "type" not in d:
        ctx.fail(f"{key}.type", f"missing required key (one of: {', '.join(MATERIAL_TYPES)})")
    t = ctx.string(d["type"], f"{key}.type", MATERIAL_TYPES)
    allowed, required = _MATERIAL_KEYS[t]
    ctx.table(d, key, allowed, required)
    if t == "cook-torrance":
        return _cook_torrance(ctx, name, key, d)
    if t == "lambert":
        albedo = ctx.vec3(d["albedo"], f"{key}.albedo", lo=0.0)
        if max(albedo) > 1.0:
            ctx.fail(f"{key}.albedo", f"expected components in [0, 1] (energy conservation), got {albedo}")
        return Material(name, t, albedo=albedo)
    if t == "ggx":
        alpha = ctx.number(d["alpha"], f"{key}.alpha", lo=GGX_MIN_ALPHA, hi=1.0)
        spec = ctx.vec3(d["specular"], f"{key}.specular", lo=0.0)
        if max(spec) > 1.0:  # f cos / pdf = specular F G1 (warpbw.brdf): above 1 the lobe reflects more than it gets
            ctx.fail(f"{key}.specular", f"expected components in [0, 1] (energy conservation), got {spec}")
        if ("eta" in d) != ("k" in d):
            ctx.fail(key, "conductor Fresnel needs both eta and k")
        eta = ctx.vec3(d["eta"], f"{key}.eta", lo=0.0, hi=CONDUCTOR_INDEX_MAX) if "eta" in d else None
        k = ctx.vec3(d["k"], f"{key}.k", lo=0.0, hi=CONDUCTOR_INDEX_MAX) if "k" in d else None
        return Material(name, t, alpha=alpha, specular=spec, eta=eta, k=k)
    lookup = ctx.string(d.get("lookup", LOOKUP_DEFAULT[t]), f"{key}.lookup", LOOKUP_MODES)
    sampling = ctx.path(d["sampling"], f"{key}.sampling") if "sampling" in d else None
    bandwidth = ctx.path(d["bandwidth"], f"{key}.bandwidth") if "bandwidth" in d else None
    if t == "merl":
        return Material(name, t, file=ctx.path(d["file"], f"{key}.file"), lookup=lookup, sampling=sampling,
                        bandwidth=bandwidth)
    return Material(name, t, table=ctx.path(d["table"], f"{key}.table"),
                    npf_name=ctx.string(d["name"], f"{key}.name"), lookup=lookup, sampling=sampling,
                    bandwidth=bandwidth)


def parse_scene(text: str, base_dir: Path | str | None = None, source: str = "<string>") -> Scene:
    """Parse and validate a scene from TOML text; relative paths resolve against ``base_dir``."""
    if not isinstance(text, str):   # bytes, a Path: a TypeError from tomllib
        raise WarpbwError(f"{source}: expected the scene's TOML text as a str, got {type(text).__name__} (a file "
                          "reads with load_scene)")
    # absolute: a relative folder made relative paths that check_scene joined to it again (sub/sub/probe.exr)
    base = check_path(base_dir, f"{source}: base_dir").absolute() if base_dir is not None else Path.cwd()
    ctx = _Ctx(source, base)
    try:
        d = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise WarpbwError(f"{source}: not valid TOML: {exc}") from None
    return _scene_from_tables(ctx, d)


def _scene_from_tables(ctx: _Ctx, d: dict) -> Scene:
    """The Scene a TOML document's tables describe, every value checked."""
    ctx.table(d, "", ("camera", "environment", "light", "object", "material"))  # top level: keys named as they are
    if "camera" not in d:
        ctx.fail("[camera]", "missing (every scene needs a camera)")
    if "environment" not in d and "light" not in d:
        ctx.fail("[environment]", "missing (the scene needs a light: an [environment] with file, procedural = "
                 "\"sky\" or constant, or a [[light]] with type = \"directional\")")
    lights_in = d.get("light", [])
    if isinstance(lights_in, dict):
        ctx.fail("[light]", "expected [[light]] (double brackets: one table per light), got a single [light]")
    if not isinstance(lights_in, list) or ("light" in d and not lights_in):
        ctx.fail("[[light]]", f"expected one or more [[light]] tables, got light = {lights_in!r}")
    lights = [_light(ctx, li, i) for i, li in enumerate(lights_in)]
    mats_in = d.get("material", {})
    if not isinstance(mats_in, dict):
        ctx.fail("[material]", "expected tables [material.NAME]")
    materials = {name: _material(ctx, name, m) for name, m in mats_in.items()}
    objs_in = d.get("object", [])
    if isinstance(objs_in, dict):   # [object], one table, where each object is one of an array of tables
        ctx.fail("[object]", "expected [[object]] (double brackets: one table per object), got a single [object]")
    if not isinstance(objs_in, list) or not objs_in:   # object = 3 was told only that none was given
        ctx.fail("[[object]]", "expected at least one [[object]]"
                 + (f" table, got object = {objs_in!r}" if "object" in d else ""))
    objects = [_object(ctx, o, i, materials) for i, o in enumerate(objs_in)]
    env = _environment(ctx, d["environment"]) if "environment" in d else None
    return Scene(_camera(ctx, d["camera"]), env, objects, materials, ctx.source, ctx.base_dir, lights)


# --------------------------------------------------------------------------------------------------
# A Scene built in Python, checked as a scene file is

def _plain(v):
    """A field's value as TOML holds it: a list for a tuple or array, a str for a path, a Python number for a
    numpy one (the checks take int and float only)."""
    if isinstance(v, Path):
        return str(v)
    if hasattr(v, "tolist"):   # numpy arrays and scalars
        return v.tolist()
    if isinstance(v, (tuple, list)):
        return [_plain(c) for c in v]
    return v


_MATERIAL_DEFAULTS = Material("", "")
_NORMAL_MAP_FIELDS = ("normal_map", "normal_map_kind", "normal_map_scale", "tiling", "gmm", "gmm_components",
                      "gmm_prior")


def _material_table(m) -> dict:
    """A Material as its [material.NAME] table: the keys its type takes, and any other field set away from its
    default (which the checks then name as a key the type does not take)."""
    if not isinstance(m, Material):
        return m     # the checks say what a table was expected to be
    allowed = _MATERIAL_KEYS.get(m.type, (("type",), ()))[0]
    d = {"type": m.type}
    for f in fields(Material):
        key = "name" if f.name == "npf_name" else f.name
        if f.name in ("name", "type"):
            continue
        v, default = _plain(getattr(m, f.name)), _plain(getattr(_MATERIAL_DEFAULTS, f.name))
        if key in _NORMAL_MAP_FIELDS:   # with a normal map (and its scale with heights only)
            in_type = m.normal_map is not None and (key != "normal_map_scale" or m.normal_map_kind == "height")
        else:
            in_type = key in allowed
        if (in_type and v is not None) or v != default:
            d[key] = v
    return d


def _object_table(o) -> dict:
    if isinstance(o, SphereObject):
        return {"shape": "sphere", "center": _plain(o.center), "radius": _plain(o.radius), "material": o.material}
    if isinstance(o, PlaneObject):
        return {"shape": "plane", "center": _plain(o.center), "size": _plain(o.size), "material": o.material}
    if isinstance(o, MeshObject):
        return {"mesh": _plain(o.file), "material": o.material, "translate": _plain(o.translate),
                "scale": _plain(o.scale), "rotate_y": _plain(o.rotate_y)}
    return o


def _scene_tables(scene: Scene) -> dict:
    """``scene`` as the tables of a scene file (paths absolute or as given)."""
    c = scene.camera
    d = {"camera": {"position": _plain(c.position), "look_at": _plain(c.look_at), "up": _plain(c.up),
                    "fov": _plain(c.fov), "resolution": [_plain(c.width), _plain(c.height)]}
         if isinstance(c, Camera) else c,
         "object": [_object_table(o) for o in scene.objects] if isinstance(scene.objects, (list, tuple))
         else scene.objects,
         "material": ({name: _material_table(m) for name, m in scene.materials.items()}
                      if isinstance(scene.materials, dict) else scene.materials)}
    e = scene.environment
    if isinstance(e, Environment):
        d["environment"] = {k: _plain(v) for k, v in (("file", e.file), ("procedural", e.procedural),
                                                      ("constant", e.constant)) if v is not None}
        d["environment"].update(rotation=_plain(e.rotation), scale=_plain(e.scale))
    elif e is not None:
        d["environment"] = e
    if scene.lights:
        d["light"] = [{"type": "directional", "direction": _plain(li.direction), "radiance": _plain(li.radiance)}
                      if isinstance(li, DirectionalLight) else li for li in scene.lights]
    return d


def check_scene(scene) -> Scene:
    """A checked copy of ``scene``: a Scene built or edited in Python passes the checks a scene file does (an
    object naming a material the scene lacks, an albedo above 1, no object at all, ...), and later edits of
    ``scene`` do not reach the copy.  Errors name the keys as a scene file would."""
    if not isinstance(scene, Scene):
        raise WarpbwError(f"scene: expected a warpbw.scene.Scene (from load_scene / parse_scene), got "
                          f"{type(scene).__name__}")
    for name, m in (scene.materials.items() if isinstance(scene.materials, dict) else ()):
        if isinstance(m, Material) and m.name != name:
            raise WarpbwError(f"{scene.source}: [material.{name}]: its Material is named {m.name!r}; expected the "
                              "name it is filed under")
    return _scene_from_tables(_Ctx(scene.source, Path(scene.base_dir).absolute()), _scene_tables(scene))


def load_scene(path: Path | str) -> Scene:
    """Read and validate a scene file."""
    p = check_path(path, "scene path")   # None: a TypeError from pathlib
    check_name_length(p, str(p))   # first: Python 3.11's exists raises on a name too long
    if not p.exists():
        raise WarpbwError(f"{p}: scene file not found")
    if not p.is_file():
        raise WarpbwError(f"{p}: not a file")
    try:
        size = p.stat().st_size
    except OSError as exc:
        raise WarpbwError(f"{p}: cannot read the scene file ({exc.strerror or exc.__class__.__name__})") from None
    if size > SCENE_FILE_MAX_BYTES:
        raise WarpbwError(f"{p}: {size} bytes; a scene file is a few kB of TOML (expected at most "
                          f"{SCENE_FILE_MAX_BYTES} bytes)")
    try:
        text = p.read_text(encoding="utf-8-sig")   # a byte-order mark (editors on Windows) is not TOML
    except (OSError, UnicodeDecodeError) as exc:
        raise WarpbwError(f"{p}: cannot read the scene file as UTF-8 text ({exc.__class__.__name__})") from None
    return parse_scene(text, p.resolve().parent, str(p))


def default_scene() -> Scene:
    """The embedded demo scene."""
    return parse_scene(DEFAULT_SCENE_TOML, Path.cwd(), "<default scene>")
