"""Non-Parametric Factor (NPF) microfacet fits of the 100 MERL materials (Bagher, Snyder,
Nowrouzezahrai 2016), as stored in ``npf.bin`` (see ``../shared/data/README.md``).

Public functions:

- ``read_npf(path, name) -> NPFMaterial``: one material's row of the table (float64 curves).
- ``npf_eval(mat, wi, wo, interpolate=True) -> (N, 3)``: the README's model, 0 below the horizon.
- ``canonical_name(name) -> str``: the name ``read_npf`` looks ``name`` up by (``NPFMaterial.name``).

Classes: ``NPFMaterial``; ``UnknownNpfMaterial``, the ``WarpbwError`` of a name the table lacks.
Constants: ``NPF_MATERIAL_NAMES`` (100 names, table order), ``NPF_ROWS``,
``NPF_COLS``, ``NPF_FILE_SIZE``, column offsets ``NPF_COL_*``, ``NPF_BINS``.

Model (README): f = rho_d + rho_s D(theta_h) F(theta_d) G1(theta_i) G1(theta_o) / (cos_i cos_o) / 16.
Binning: D like MERL's theta_h axis (bin = floor(sqrt(theta_h/(pi/2)) * 90)); G1 and F uniform over
[0, pi/2]. Bin 0 of G1 and of F holds no fitted value (README: G1 bin 0 "unused and stored as 0";
F bin 0 is a 1e-6 placeholder in 99 of the 100 rows, against ~0.1-1 in bin 1), so lookups in those
two curves clamp to bin 1 (``NPF_FIRST_VALID_BIN``) instead of reading bin 0.

Colour: the three channels are MERL's RGB after ``BRDFRead.cpp``'s channel scales (``warpbw.io.merl.MERL_SCALE``), read
as linear Rec. 709 as a MERL file is: white-paint's rho_d is 1 : 0.98 : 0.96 and teflon's 1 : 0.98 : 0.94 (their
directional albedo at 30 degrees grey within 4%), where a fit of the unscaled values would read 1 : 0.87 : 0.60.
"""
from __future__ import annotations

import difflib
from dataclasses import dataclass

import numpy as np

from warpbw.errors import BRDF_VALUE_MAX, WarpbwError, check_direction_pairs, check_flag, check_input_file

# Material order of the rows of npf.bin (data README, "npf.bin layout"; the MERL database's names).
NPF_MATERIAL_NAMES: tuple[str, ...] = (
    "alum-bronze", "alumina-oxide", "aluminium", "aventurnine", "beige-fabric", "black-fabric",
    "black-obsidian", "black-oxidized-steel", "black-phenolic", "black-soft-plastic", "blue-acrylic",
    "blue-fabric", "blue-metallic-paint2", "blue-metallic-paint", "blue-rubber", "brass", "cherry-235",
    "chrome", "chrome-steel", "colonial-maple-223", "color-changing-paint1", "color-changing-paint2",
    "color-changing-paint3", "dark-blue-paint", "dark-red-paint", "dark-specular-fabric", "delrin",
    "fruitwood-241", "gold-metallic-paint2", "gold-metallic-paint3", "gold-metallic-paint", "gold-paint",
    "gray-plastic", "grease-covered-steel", "green-acrylic", "green-fabric", "green-latex",
    "green-metallic-paint2", "green-metallic-paint", "green-plastic", "hematite", "ipswich-pine-221",
    "light-brown-fabric", "light-red-paint", "maroon-plastic", "natural-209", "neoprene-rubber", "nickel",
    "nylon", "orange-paint", "pearl-paint", "pickled-oak-260", "pink-fabric2", "pink-fabric", "pink-felt",
    "pink-jasper", "pink-plastic", "polyethylene", "polyurethane-foam", "pure-rubber", "purple-paint", "pvc",
    "red-fabric2", "red-fabric", "red-metallic-paint", "red-phenolic", "red-plastic", "red-specular-plastic",
    "silicon-nitrade", "silver-metallic-paint2", "silver-metallic-paint", "silver-paint",
    "special-walnut-224", "specular-black-phenolic", "specular-blue-phenolic", "specular-green-phenolic",
    "specular-maroon-phenolic", "specular-orange-phenolic", "specular-red-phenolic",
    "specular-violet-phenolic", "specular-white-phenolic", "specular-yellow-phenolic", "ss440", "steel",
    "teflon", "tungsten-carbide", "two-layer-gold", "two-layer-silver", "violet-acrylic", "violet-rubber",
    "white-acrylic", "white-diffuse-bball", "white-fabric2", "white-fabric", "white-marble", "white-paint",
    "yellow-matte-plastic", "yellow-paint", "yellow-phenolic", "yellow-plastic",
)
# Table layout (data README): 256 rows x 512 columns x RGB float32, little-endian, no header.
NPF_ROWS = 256
NPF_COLS = 512
NPF_CHANNELS = 3
NPF_FILE_SIZE = NPF_ROWS * NPF_COLS * NPF_CHANNELS * 4  # 1,572,864 bytes
NPF_BINS = 90  # bins per curve (D, G1, F)
NPF_COL_RHO_D = 0
NPF_COL_RHO_S = 1
NPF_COL_D = 2
NPF_COL_G1 = NPF_COL_D + NPF_BINS  # 92
NPF_COL_F = NPF_COL_G1 + NPF_BINS  # 182
NPF_FIRST_VALID_BIN = 1  # first bin of G1 and F holding a fitted value (module docstring)
NPF_NORMALISATION = 1.0 / 16.0  # the README model's constant factor
# Lower bound on cos(theta_i), cos(theta_o) in the 1/(cos_i cos_o) factor: keeps values finite
# within ~6e-4 degrees of the horizon (the same 1e-5 clamp as the NPF demo shader in
# jdupuy/opengl-framework, demo-merl/shaders/npf.glsl, dotProduct()).
NPF_COS_MIN = 1e-5
_HALF_PI = 0.5 * np.pi


@dataclass
class NPFMaterial:
    """One NPF fit: ``rho_d``, ``rho_s`` (3,) and the curves ``D``, ``G1``, ``F`` (90, 3), float64."""

    name: str
    rho_d: np.ndarray
    rho_s: np.ndarray
    D: np.ndarray
    G1: np.ndarray
    F: np.ndarray


def canonical_name(name: str) -> str:
    """The name an NPF material is stored under (``NPF_MATERIAL_NAMES``): lower case, without ``.binary``."""
    n = str(name).strip().lower()
    return n[: -len(".binary")] if n.endswith(".binary") else n


class UnknownNpfMaterial(WarpbwError):
    """A material name the NPF table does not hold (a scene names its key when it says so)."""


def read_npf(path, name: str) -> NPFMaterial:
    """Read material ``name`` (one of ``NPF_MATERIAL_NAMES``; case and a ``.binary`` suffix ignored)."""
    path = check_input_file(path, f"the NPF table npf.bin, {NPF_FILE_SIZE} bytes")
    size = path.stat().st_size
    if size != NPF_FILE_SIZE:
        raise WarpbwError(
            f"{path}: expected {NPF_FILE_SIZE} bytes (NPF table, {NPF_ROWS}x{NPF_COLS} RGB float32), got {size}"
        )
    if not isinstance(name, str):   # None was answered with "close matches: nylon"
        raise WarpbwError(f"{path}: NPF material name: expected a string such as 'gold-metallic-paint', got {name!r}")
    key = canonical_name(name)
    if key not in NPF_MATERIAL_NAMES:
        close = difflib.get_close_matches(key, NPF_MATERIAL_NAMES, n=5, cutoff=0.5)
        hint = (f"close matches: {', '.join(close)}" if close else
                f"expected one of the {len(NPF_MATERIAL_NAMES)} MERL material names: {', '.join(NPF_MATERIAL_NAMES)}")
        raise UnknownNpfMaterial(f"{path}: unknown NPF material {name!r}; {hint}")
    row = NPF_MATERIAL_NAMES.index(key)
    row_floats = NPF_COLS * NPF_CHANNELS
    try:
        vals = np.fromfile(path, dtype="<f4", count=row_floats, offset=row * row_floats * 4)
    except OSError as exc:
        raise WarpbwError(f"{path}: cannot read NPF table ({exc.strerror or exc})") from None
    with np.errstate(invalid="ignore"):   # a signalling NaN's cast warns; non-finite values are refused below
        vals = vals.astype(np.float64).reshape(NPF_COLS, NPF_CHANNELS)
    used = vals[: NPF_COL_F + NPF_BINS]
    if not np.all(np.isfinite(used)) or np.any(used < 0.0):
        raise WarpbwError(f"{path}: row {row} ({key}) holds negative or non-finite values (expected a valid NPF fit)")
    if used.max() > BRDF_VALUE_MAX:
        raise WarpbwError(f"{path}: row {row} ({key}) holds values up to {used.max():.3g}, beyond {BRDF_VALUE_MAX:g} "
                          "(float32 shading would overflow them to infinity; expected a valid NPF fit)")
    lobe = [vals[c : c + NPF_BINS] for c in (NPF_COL_D, NPF_COL_G1, NPF_COL_F)]
    if not (vals[NPF_COL_RHO_D].max() > 0.0 or (vals[NPF_COL_RHO_S].max() > 0.0 and all(x.max() > 0.0 for x in lobe))):
        raise WarpbwError(f"{path}: row {row} ({key}) reflects nothing (rho_d 0, and rho_s, D, G1 or F all 0; expected "
                          "a valid NPF fit)")
    return NPFMaterial(
        name=key,
        rho_d=vals[NPF_COL_RHO_D].copy(),
        rho_s=vals[NPF_COL_RHO_S].copy(),
        D=vals[NPF_COL_D : NPF_COL_D + NPF_BINS].copy(),
        G1=vals[NPF_COL_G1 : NPF_COL_G1 + NPF_BINS].copy(),
        F=vals[NPF_COL_F : NPF_COL_F + NPF_BINS].copy(),
    )


def _lookup(curve: np.ndarray, fb: np.ndarray, first: int, interpolate: bool) -> np.ndarray:
    """curve (90, 3) at continuous bin coordinate ``fb`` (bin k spans [k, k+1)); bins < ``first`` skipped."""
    fb = np.where(np.isfinite(fb), fb, 0.0)
    last = NPF_BINS - 1
    if not interpolate:
        return curve[np.clip(np.floor(fb), first, last).astype(np.int64)]
    x = np.clip(fb - 0.5, first, last)  # linear between bin centres, constant beyond the end centres
    i0 = np.minimum(np.floor(x), last - 1).astype(np.int64)
    t = (x - i0)[..., None]
    return curve[i0] * (1.0 - t) + curve[i0 + 1] * t


def npf_eval(mat: NPFMaterial, wi, wo, interpolate: bool = True) -> np.ndarray:
    """The README's NPF model at direction pairs (N, 3) -> (N, 3) float64; 0 where wi or wo is at/below the horizon.

    Exactly reciprocal: every quantity is computed symmetrically in (wi, wo).
    """
    if not all(hasattr(mat, k) for k in ("D", "F", "G1", "rho_d", "rho_s")):   # a path or None: "no attribute 'D'"
        raise WarpbwError(f"npf_eval: mat is {type(mat).__name__}, expected an NPFMaterial (read_npf(path, name) "
                          "reads one)")
    wi, wo = check_direction_pairs(wi, wo)   # unit length; NaN and zero directions refused
    interpolate = check_flag(interpolate, "interpolate")   # "no" was truthy
    ci, co = wi[..., 2], wo[..., 2]
    above = (ci > 0.0) & (co > 0.0)
    s = wi + wo
    h = s / np.maximum(np.linalg.norm(s, axis=-1, keepdims=True), np.finfo(np.float64).tiny)
    theta_h = np.arccos(np.clip(h[..., 2], 0.0, 1.0))
    cos_d = 0.5 * (np.sum(wi * h, axis=-1) + np.sum(wo * h, axis=-1))
    theta_d = np.arccos(np.clip(cos_d, 0.0, 1.0))
    theta_i = np.arccos(np.clip(ci, 0.0, 1.0))
    theta_o = np.arccos(np.clip(co, 0.0, 1.0))
    D = _lookup(mat.D, np.sqrt(theta_h / _HALF_PI) * NPF_BINS, 0, interpolate)
    F = _lookup(mat.F, theta_d / _HALF_PI * NPF_BINS, NPF_FIRST_VALID_BIN, interpolate)
    G1i = _lookup(mat.G1, theta_i / _HALF_PI * NPF_BINS, NPF_FIRST_VALID_BIN, interpolate)
    G1o = _lookup(mat.G1, theta_o / _HALF_PI * NPF_BINS, NPF_FIRST_VALID_BIN, interpolate)
    cos_prod = (np.maximum(ci, NPF_COS_MIN) * np.maximum(co, NPF_COS_MIN))[..., None]
    spec = mat.rho_s * D * F * (G1i * G1o) / cos_prod * NPF_NORMALISATION
    f = np.asarray(mat.rho_d) + spec
    return np.where(above[..., None], f, 0.0)
