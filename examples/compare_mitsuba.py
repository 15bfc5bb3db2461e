"""Render one sphere under an HDR probe with Mitsuba 3 and with warpbw's forward reference; compare.

Usage::

    python examples/compare_mitsuba.py                       # lambert, ggx0.1, ggx0.4 at 256x256, 1024 spp
    python examples/compare_mitsuba.py --noise-floor         # also two Mitsuba seeds against each other
    python examples/compare_mitsuba.py --no-mis              # warpbw with BRDF sampling only
    python examples/compare_mitsuba.py --cases ggx0.1 --spp 256 --resolution 128 --out /tmp/cmp
    python examples/compare_mitsuba.py --mitsuba-only --out /tmp/mitsuba_out
    python examples/compare_mitsuba.py --json cmp.json --plot cmp.png   # and the record and its plot

For every case it prints the relative MSE and PSNR of warpbw's image against Mitsuba's over the
sphere's interior (warpbw's coverage mask eroded by 2 pixels, so that silhouette pixels, whose value
depends on how each renderer filters the edge, do not count), the wall time of each renderer (the median of
``--runs`` renders, default 3 -- fewer warn, as ``warpbw bench``'s --runs -- after one warm-up render at 1 spp, so
kernel compilation is not counted) and PASS/FAIL against the 1 %
acceptance threshold.  The exit code is 0 whatever the figures are; it is non-zero only on an error.
``--json OUT.json`` / ``--plot OUT.png`` (as ``warpbw bench``'s: the one not given goes beside the other; an
existing file is kept without ``--force``, refused before any render) write the record of the run (the settings,
Mitsuba's version and variant, and every figure of the table per case, units in the names) and its plot (relMSE
against the acceptance, and each renderer's time, per case).  Compare the times as their ratio only.

Install Mitsuba 3 (an optional extra, not a dependency of warpbw)::

    pip install -e ".[mitsuba]"           # in the checkout; i.e. pip install mitsuba
    apt-get install -y libllvm19           # Mitsuba's llvm_* variants abort with LLVM 14/15

This script sets ``DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM-19.so`` when the variable is
unset and that file exists, and uses the ``llvm_ad_rgb`` variant; without LLVM 19 it falls back to
``scalar_rgb`` (correct, about 20x slower).

Conventions checked with Mitsuba 3.9.1 alone (the renders below are the evidence; rerun them with
``--check-conventions``)
------------------------------------------------------------------------------------------------------
Camera.  ``perspective`` with ``fov_axis='x'`` and ``to_world = look_at(origin, target, up)``, camera at
    (0, 0, 4) looking at the origin with up +Y: a sphere at world +X appears in the RIGHT half of the
    image (column 48 of 64) and one at +Y in the TOP half (row 15 of 64, row 0 = top).  This is
    warpbw's camera (right = normalize(cross(forward, up)), row 0 at the top), so images compare
    pixel for pixel without flips.

Environment map (``envmap`` emitter, src/emitters/envmap.cpp).  For a unit direction d in the
    emitter's frame (d = R^-1 d_world with R = to_world):

        u = atan2(d.x, -d.z) / (2 pi)   (wrapped into [0, 1))       v = acos(d.y) / pi

    and conversely d = (sin(2 pi u) sin(pi v), cos(pi v), -cos(2 pi u) sin(pi v)).
    So u = 0 (the left edge) looks towards -Z, u = 1/4 towards +X, u = 1/2 (the centre column)
    towards +Z (i.e. back at a camera on +Z), u = 3/4 towards -X; v = 0 is +Y (row 0, the top).
    Texel placement for the bilinear lookup of a W x H image:
      * columns are texel-centred: column c sits at u = (c + 0.5) / W and the lookup wraps in u
        (Mitsuba appends a copy of column 0 as column W);
      * rows are NOT texel-centred: row r sits at v = r / (H - 1), so row 0 is exactly the +Y pole
        and row H-1 exactly the -Y pole; the lookup clamps in v.
    Measured: in a 64 x 32 probe with one bright texel, texel (r=16, c=32) lights direction
    (-0.049, -0.051, 0.998), texel (r=8, c=16) lights (0.724, 0.689, 0.036), texel (16, 0) lights
    (0.049, -0.051, -0.998) and (16, 48) lights (-0.998, -0.051, -0.049) -- exactly the formulas
    above with v = r / 31 (a texel-centred v = (r + 0.5) / 32 would give y = 0.671 for r = 8).
    Rotation: ``to_world = rotate([0, 1, 0], a)`` maps an emitter-frame direction d to R_y(a) d with
    the right-handed R_y (x' = x cos a + z sin a, z' = -x sin a + z cos a); a = 90 degrees moves the
    light of texel (8, 16) from (0.724, 0.689, 0.036) to (0.036, 0.689, -0.724).
    ``scale`` multiplies the radiance.

rough conductor (src/bsdfs/roughconductor.cpp, include/mitsuba/render/microfacet.h, fresnel.h).
    With no ``material`` and no ``eta``/``k`` the plugin uses eta = 0 + 1i; ``fresnel_conductor`` then
    gives r_s = r_p = 1 exactly (the term 2 cos a with a = 0 vanishes), so F = 1 at every angle and
    ``specular_reflectance`` = specular makes the Fresnel term a constant, as warpbw's ggx does.
    G is separable: ``G(wi, wo, m) = smith_g1(wi, m) * smith_g1(wo, m)`` with the GGX
    ``smith_g1 = 2 / (1 + sqrt(1 + alpha^2 tan^2 theta))`` (0 on the back of the microfacet), and
    D = 1 / (pi alpha^2 (m_x^2/alpha^2 + m_y^2/alpha^2 + m_z^2)^2).  eval() returns
    D G / (4 cos_i) (that is f cos_o), so f = F D G1 G1 / (4 cos_i cos_o): warpbw's ggx.
    ``--check-conventions`` also evaluates the BSDF against this closed form.

Both renderers get the same radiance: the probe is read once by warpbw's loader (``warpbw.envmap.load_envmap``,
negative and non-finite texels set to 0), and the array is handed to Mitsuba as a Bitmap while warpbw reads the
file itself the same way.  Mitsuba's own reader applies an EXR's ``chromaticities`` attribute without adapting
its white, where warpbw's converts to Rec. 709 with Bradford's adaptation (``warpbw.io.exr.rec709_transform``):
city.exr declares sRGB's primaries adapted to a D50 white, which warpbw reads as stored (the identity within 2e-4),
and read through Mitsuba's Bitmap its mean went from (1.05, 1.06, 1.04) to (1.24, 1.03, 0.75); the lambert sphere
under it read relMSE 0.059 against Mitsuba's (48x48, 512 spp; the noise floor 2.0e-3), where a quadrature of the
probe in numpy agreed with warpbw's image (1.2e-3).  Mitsuba uses ``path`` with max_depth 2 (direct light
only, MIS between light and BSDF sampling) and hide_emitters, a box pixel filter, and the analytic
``sphere`` shape.

Pixel footprint.  warpbw's G-buffer traces one ray through each pixel centre; Mitsuba's film jitters
    over the pixel and box-filters.  Measured with Mitsuba alone (its integrator on explicit
    pixel-centre rays against the box-filtered film, 4096 spp each, 256x256, interior mask): the
    centre-vs-box relMSE (lambert 5.5e-4, ggx0.1 1.1e-3 / 1.2e-3, ggx0.4 7.0e-4) equals the
    centre-vs-centre and box-vs-box noise (5.4e-4, 1.2e-3, 7.1e-4), so at this resolution the
    footprint difference is far below the noise and the box filter is a fair reference.

relMSE is ``warpbw.metrics.relmse(test, ref, mask)`` when that exists, else the local fallback
sum((a - b)^2) / sum(b^2) over the mask; the header line says which one ran.  ``test`` is warpbw,
``ref`` is Mitsuba.  Two renders at 1024 spp still carry Monte-Carlo noise: ``--noise-floor``
renders Mitsuba a second time with another seed and prints the relMSE between the two, i.e. the
figure a warpbw exactly as noisy as Mitsuba would reach.  Measured at 256x256 and 1024 spp under
studio.exr: lambert 2.2e-3, ggx0.1 4.7e-3, ggx0.4 2.8e-3 (it falls as 1/spp; ``--mitsuba-spp 4096``
takes most of the reference's share out).  Mitsuba 3.9.1 llvm_ad_rgb on 2 cores renders these at
11-13 M samples/s (5-6 s per case at 256x256, 1024 spp).

Results (256x256, 1024 spp each, studio.exr, 2 shared cores; relMSE = warpbw.metrics.relmse)::

    estimator            case     relMSE   rel(sum)  PSNR dB   Mitsuba-vs-Mitsuba floor
    warpbw --mis         lambert  2.7e-3   2.2e-3    33.4      2.6e-3
                         ggx0.1   2.1e-3   4.9e-3    46.7      2.0e-3
                         ggx0.4   2.8e-3   2.9e-3    38.0      2.7e-3
    warpbw default       lambert  1.9e-1   1.7e-1    14.4      (BRDF sampling only: FAIL on noise)
                         ggx0.1   1.4e-1   1.7e-2    41.3
                         ggx0.4   1.9e-1   1.2e-1    21.9

With MIS, warpbw sits on Mitsuba's own noise floor; averaged over 8x8 blocks (noise / 64) the
relMSE(sum) falls to 3e-5 / 1.4e-4 / 4e-5 and the interior means agree to 0.03 %, 0.2 %, 0.06 %:
no measurable bias.  The default (BRDF-sampling) estimator is unbiased too (its block-averaged error
falls by the same factor of about 60) but 50-100x noisier under the probe's small bright lights.
Coverage masks agree to IoU 0.9999.
"""
from __future__ import annotations

from warpbw.entry import interrupt_in_one_line

interrupt_in_one_line(__name__)   # first: a Ctrl-C while the imports below load says one line, no traceback

import argparse
import math
import os
import statistics
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from warpbw.cli_common import (PROTOCOL_RUNS, RUNS_MAX, OneLineParser, check_output_dir, check_overwrite,
                               check_record_outputs, few_runs_warning, init_warp, parse_seed, run_command, write_record)
from warpbw.errors import SEED_MAX, WarpbwError
from warpbw.io.shared_data import shared_data_dir
from warpbw.io.staged import staged_outputs
from warpbw.scene import toml_string

# The repository root, so that `python examples/compare_mitsuba.py` finds warpbw without installing.
REPO_ROOT = Path(__file__).resolve().parents[1]
if str(REPO_ROOT) not in sys.path:
    sys.path.insert(0, str(REPO_ROOT))

# ../shared/data relative to the project root (see ../shared/data/README.md).
DEFAULT_PROBE = shared_data_dir(REPO_ROOT) / "envmaps" / "studio.exr"
LLVM19 = "/usr/lib/x86_64-linux-gnu/libLLVM-19.so"
ACCEPT_RELMSE = 0.01          # acceptance: relMSE below 1 % per case
ERODE_PX = 2                  # interior = coverage eroded by this many pixels (5x5 square)
RESOLUTION_MIN = 9            # the least side whose interior holds a pixel (at 8 none: the error was undefined)
VARIANTS = ("llvm_ad_rgb", "llvm_rgb", "scalar_rgb")

# The scene: camera on +Z looking at a unit sphere at the origin.
CAMERA = dict(position=(0.0, 0.0, 4.0), look_at=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov=35.0)
SPHERE = dict(center=(0.0, 0.0, 0.0), radius=1.0)

# case name -> material parameters (warpbw names)
CASES = {
    "lambert": dict(type="lambert", albedo=(0.8, 0.8, 0.8)),
    "ggx0.1": dict(type="ggx", alpha=0.1, specular=(1.0, 1.0, 1.0)),
    "ggx0.4": dict(type="ggx", alpha=0.4, specular=(1.0, 1.0, 1.0)),
}


def fail(msg: str) -> None:
    """Stop with a one-line message, ``compare_mitsuba.py: error: ...`` (status 2, as every refusal)."""
    raise WarpbwError(msg)


# ----------------------------------------------------------------------------------------- Mitsuba
def import_mitsuba(variant: str | None = None):
    """Import Mitsuba 3 and pick a variant; returns (mi, variant)."""
    if "DRJIT_LIBLLVM_PATH" not in os.environ and os.path.exists(LLVM19):
        os.environ["DRJIT_LIBLLVM_PATH"] = LLVM19
    try:
        import mitsuba as mi
    except ImportError:
        fail('Mitsuba 3 is not installed: pip install -e ".[mitsuba]" in the checkout (and apt-get install libllvm19 '
             'for its fast variants)')
    available = mi.variants()
    if variant is not None:
        candidates = [variant]
    elif "DRJIT_LIBLLVM_PATH" in os.environ:
        candidates = list(VARIANTS)
    else:
        # The default libLLVM 14/15 makes the llvm_* variants abort the process ("Cannot select
        # fminimum"), which cannot be caught: without LLVM 19 stay on the scalar variant.
        candidates = ["scalar_rgb"]
    for v in candidates:
        if v not in available:
            continue
        try:
            mi.set_variant(v)
            return mi, v
        except Exception:  # noqa: BLE001 - e.g. LLVM not found: try the next variant
            continue
    fail(f"none of the Mitsuba variants {candidates} can be used (available: {available})")


def load_probe(mi, path: Path) -> np.ndarray:
    """Probe as (H, W, 3) float32 linear RGB as warpbw's renderer reads it (``warpbw.envmap.load_envmap``: negative /
    non-finite texels set to 0; other primaries converted to Rec. 709), for Mitsuba's Bitmap: Mitsuba's own reader
    applies an EXR's chromaticities without adapting the white (module docstring), and the two renderers would then
    be lit differently.  ``mi``: unused, kept for callers."""
    if not path.is_file():
        fail(f"{path}: environment map not found (give one with --probe)")
    init_warp("cpu")         # no banner or module-load lines, nor Warp's no-CUDA-driver line on stderr
    from warpbw.envmap import load_envmap

    with warnings.catch_warnings():   # the negative texels it sets to 0: warpbw's render of the file says so
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.array(load_envmap(path).pixels, dtype=np.float32, copy=True)   # its errors name the file


def mitsuba_bsdf(mat: dict) -> dict:
    if mat["type"] == "lambert":
        return {"type": "diffuse", "reflectance": {"type": "rgb", "value": list(mat["albedo"])}}
    if mat["type"] == "ggx":
        # No material/eta/k: eta = 0 + 1i, i.e. F = 1 exactly; specular_reflectance = constant Fresnel.
        return {"type": "roughconductor", "distribution": "ggx", "alpha": float(mat["alpha"]),
                "sample_visible": True,
                "specular_reflectance": {"type": "rgb", "value": list(mat["specular"])}}
    raise ValueError(f"unknown material type {mat['type']!r}")


def mitsuba_scene(mi, probe_rgb: np.ndarray, mat: dict, res: int, spp: int,
                  rotation: float, scale: float):
    T = mi.ScalarTransform4f
    return mi.load_dict({
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 2, "hide_emitters": True},
        "sensor": {
            "type": "perspective", "fov_axis": "x", "fov": CAMERA["fov"],
            "to_world": T().look_at(origin=list(CAMERA["position"]), target=list(CAMERA["look_at"]),
                                    up=list(CAMERA["up"])),
            "film": {"type": "hdrfilm", "width": res, "height": res, "pixel_format": "rgba",
                     "rfilter": {"type": "box"}},
            "sampler": {"type": "independent", "sample_count": spp},
        },
        "env": {"type": "envmap", "bitmap": mi.Bitmap(probe_rgb), "scale": float(scale),
                "to_world": T().rotate([0.0, 1.0, 0.0], float(rotation))},
        "sphere": {"type": "sphere", "center": list(SPHERE["center"]), "radius": SPHERE["radius"],
                   "bsdf": mitsuba_bsdf(mat)},
    })


def render_mitsuba(mi, scene, spp: int, seed: int) -> tuple[np.ndarray, np.ndarray, float]:
    """Returns (rgb (H,W,3) float32, alpha (H,W) float32, seconds)."""
    t0 = time.perf_counter()
    img = np.array(mi.render(scene, spp=spp, seed=seed), dtype=np.float32)
    dt = time.perf_counter() - t0
    return img[..., :3].copy(), img[..., 3].copy(), dt


# ------------------------------------------------------------------------------------------ warpbw
def warpbw_toml(probe: Path, mat: dict, res: int, rotation: float, scale: float) -> str:
    def vec(v):
        return "[" + ", ".join(f"{float(x)!r}" for x in v) + "]"

    lines = [
        "[camera]",
        f"position = {vec(CAMERA['position'])}",
        f"look_at = {vec(CAMERA['look_at'])}",
        f"up = {vec(CAMERA['up'])}",
        f"fov = {CAMERA['fov']!r}",
        f"resolution = [{res}, {res}]",
        "",
        "[environment]",
        f"file = {toml_string(str(probe.resolve()), f'--probe {probe}')}",   # repr() doubled no backslash
        f"rotation = {float(rotation)!r}",
        f"scale = {float(scale)!r}",
        "",
        "[[object]]",
        'shape = "sphere"',
        f"center = {vec(SPHERE['center'])}",
        f"radius = {float(SPHERE['radius'])!r}",
        'material = "m"',
        "",
        "[material.m]",
        f'type = "{mat["type"]}"',
    ]
    if mat["type"] == "lambert":
        lines.append(f"albedo = {vec(mat['albedo'])}")
    else:
        lines += [f"alpha = {float(mat['alpha'])!r}", f"specular = {vec(mat['specular'])}"]
    return "\n".join(lines) + "\n"


def import_warpbw():
    """Returns (prepare, render_reference), ``prepare(toml_text, base_dir)`` the scene parsed and its assets (probe,
    materials, geometry) loaded; or raises ImportError with the reason.  Mitsuba's scene is built before its timed
    render, and so is warpbw's: a Scene handed to render_reference was loaded inside the timed call (the probe
    alone 0.07-0.15 s, a 128x128 GGX sphere's 16-spp frame timed 0.28 s where it takes 0.11 s)."""
    init_warp("cpu")         # no banner or module-load lines, nor Warp's no-CUDA-driver line on stderr
    from warpbw.pipeline import prepare_scene, render_reference
    from warpbw.scene import parse_scene

    def prepare(toml_text: str, base_dir=None):
        return prepare_scene(parse_scene(toml_text, base_dir=base_dir), device="cpu")
    return prepare, render_reference


def render_warpbw(prepare, render_reference, toml_text: str, spp: int, seed: int, mis: bool = False):
    """Returns (rgb (H,W,3) float32, coverage (H,W) bool, seconds of the render alone); ``prepare`` is
    ``import_warpbw``'s."""
    scene = prepare(toml_text, base_dir=REPO_ROOT)
    kw = {"mis": True} if mis else {}
    t0 = time.perf_counter()
    res = render_reference(scene, spp=spp, seed=seed, device="cpu", **kw)
    dt = time.perf_counter() - t0
    return (np.asarray(res.image, dtype=np.float32)[..., :3],
            np.asarray(res.coverage).astype(bool), dt)


# ----------------------------------------------------------------------------------------- metrics
def erode(mask: np.ndarray, r: int) -> np.ndarray:
    """Binary erosion with a (2r+1)^2 square; outside the image counts as uncovered."""
    m = np.pad(mask.astype(bool), r, constant_values=False)
    h, w = mask.shape
    out = np.ones((h, w), bool)
    for dy in range(2 * r + 1):
        for dx in range(2 * r + 1):
            out &= m[dy:dy + h, dx:dx + w]
    return out


def relmse_sum(test, ref, mask) -> float:
    """Global relative MSE: sum((a - b)^2) / sum(b^2) over the mask (all channels)."""
    d = (test - ref)[mask].astype(np.float64)
    return float(np.sum(d ** 2) / max(np.sum(ref[mask].astype(np.float64) ** 2), 1e-30))


def metric_functions():
    """(relmse, psnr, label): warpbw.metrics when it exists, else local fallbacks."""
    try:
        from warpbw.metrics import psnr, relmse
        return relmse, psnr, ("warpbw.metrics.relmse = mean over pixels and channels of (a-b)^2 / (b^2 + 1e-2); "
                              "relMSE(sum) = sum((a-b)^2) / sum(b^2)")
    except ImportError:
        pass

    def psnr_local(test, ref, mask):
        mse = float(np.mean((test - ref)[mask].astype(np.float64) ** 2))
        peak = float(np.max(ref[mask]))
        return math.inf if mse == 0 else 10.0 * math.log10(peak * peak / mse)

    return relmse_sum, psnr_local, "local fallback relMSE = sum((a-b)^2) / sum(b^2) (no warpbw.metrics); PSNR peak = max(ref)"


# ---------------------------------------------------------------------------------------- file out
def save_exr(mi, path: Path, rgb: np.ndarray) -> None:
    try:
        from warpbw.io.exr import write_exr
        write_exr(path, rgb)
    except ImportError:
        mi.Bitmap(np.ascontiguousarray(rgb, dtype=np.float32)).write(str(path))


def to_srgb8(rgb: np.ndarray, exposure: float = 0.0) -> np.ndarray:
    x = np.nan_to_num(rgb * 2.0 ** exposure, nan=0.0, posinf=1.0, neginf=0.0).clip(0.0, 1.0)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return (s * 255.0 + 0.5).astype(np.uint8)


def save_side_by_side(path: Path, ref: np.ndarray, test: np.ndarray | None) -> None:
    """Mitsuba | warpbw | 10 x |difference| (sRGB, exposure 0)."""
    from PIL import Image
    panels = [ref] if test is None else [ref, test, 10.0 * np.abs(test - ref)]
    gap = np.ones((ref.shape[0], 4, 3), np.float32)
    row = np.concatenate(sum(([p, gap] for p in panels), [])[:-1], axis=1)
    Image.fromarray(to_srgb8(row)).save(path)


# ------------------------------------------------------------------------------------- conventions
def first_channel(mi, evaluate, *dirs) -> np.ndarray:
    """The first channel (N,) of ``evaluate(*vectors)`` at the N rows of the (N, 3) arrays ``dirs`` (one Vector3f
    each): one call on a vectorised variant (llvm_*, cuda_*), one per row on a scalar one, whose Vector3f holds one
    direction (given arrays, it raised a TypeError: ``--check-conventions`` failed on scalar_rgb, the fallback)."""
    if mi.variant().startswith("scalar"):
        return np.array([float(evaluate(*(mi.Vector3f(*map(float, v[i])) for v in dirs))[0])
                         for i in range(len(dirs[0]))])
    got = np.array(evaluate(*(mi.Vector3f(v[:, 0], v[:, 1], v[:, 2]) for v in dirs)))
    return got[0] if got.shape[0] == 3 else got[:, 0]


def check_conventions(mi, n: int = 400) -> dict:
    """Print the camera / envmap / roughconductor conventions measured with Mitsuba alone (the envmap's lit directions
    over an n x 2n grid of directions), and return them: {"camera": {name: (row, column)}, "envmap": [(row, column,
    rotation, lit direction, formula)], "roughconductor": {alpha: largest relative difference}}."""
    found = {"camera": {}, "envmap": [], "roughconductor": {}}
    T = mi.ScalarTransform4f
    for name, c in (("+X", [1.2, 0.0, 0.0]), ("+Y", [0.0, 1.2, 0.0])):
        sc = mi.load_dict({
            "type": "scene", "integrator": {"type": "path", "max_depth": 2, "hide_emitters": True},
            "sensor": {"type": "perspective", "fov_axis": "x", "fov": 60.0,
                       "to_world": T().look_at(origin=[0, 0, 4], target=[0, 0, 0], up=[0, 1, 0]),
                       "film": {"type": "hdrfilm", "width": 64, "height": 64, "pixel_format": "rgba",
                                "rfilter": {"type": "box"}}},
            "env": {"type": "constant"},
            "s": {"type": "sphere", "center": c, "radius": 0.3, "bsdf": {"type": "diffuse"}}})
        a = np.array(mi.render(sc, spp=4))[..., 3]
        ys, xs = np.nonzero(a > 0.5)
        found["camera"][name] = (float(ys.mean()), float(xs.mean()))
        print(f"camera: sphere at world {name} -> image row {ys.mean():.1f}, column {xs.mean():.1f} "
              f"(64x64, row 0 = top)")

    h, w = 32, 64
    th = (np.arange(n) + 0.5) / n * np.pi
    ph = (np.arange(2 * n) + 0.5) / (2 * n) * 2 * np.pi
    TH, PH = np.meshgrid(th, ph, indexing="ij")
    d = np.stack([np.sin(TH) * np.cos(PH), np.cos(TH), np.sin(TH) * np.sin(PH)], -1).reshape(-1, 3)
    si = mi.SurfaceInteraction3f()

    def emitted(em):
        def at(wi):
            si.wi = wi
            return em.eval(si)
        return at
    for (r, c) in ((8, 16), (16, 0), (16, 32), (16, 48), (0, 5)):
        for rot in (0.0, 90.0):
            arr = np.zeros((h, w, 3), np.float32)
            arr[r, c] = 1000.0
            em = mi.load_dict({"type": "envmap", "bitmap": mi.Bitmap(arr),
                               "to_world": T().rotate([0, 1, 0], rot)})
            v = first_channel(mi, emitted(em), -d)
            cen = (d * (v / v.sum())[:, None]).sum(0)
            cen /= np.linalg.norm(cen)
            u_, v_ = (c + 0.5) / w, r / (h - 1)
            pred = np.array([math.sin(2 * math.pi * u_) * math.sin(math.pi * v_), math.cos(math.pi * v_),
                             -math.cos(2 * math.pi * u_) * math.sin(math.pi * v_)])
            a = math.radians(rot)
            pred = np.array([pred[0] * math.cos(a) + pred[2] * math.sin(a), pred[1],
                             -pred[0] * math.sin(a) + pred[2] * math.cos(a)])
            found["envmap"].append((r, c, rot, cen, pred))
            print(f"envmap {w}x{h}: texel (row {r}, col {c}), rotation {rot:4.0f} -> lit direction "
                  f"{np.round(cen, 3)}  formula {np.round(pred, 3)}")

    rng = np.random.default_rng(0)
    for alpha in (0.1, 0.4):
        bsdf = mi.load_dict(mitsuba_bsdf(dict(type="ggx", alpha=alpha, specular=(1, 1, 1))))
        wi = rng.normal(size=(1000, 3)); wi[:, 2] = np.abs(wi[:, 2]); wi /= np.linalg.norm(wi, axis=1, keepdims=True)
        wo = rng.normal(size=(1000, 3)); wo[:, 2] = np.abs(wo[:, 2]); wo /= np.linalg.norm(wo, axis=1, keepdims=True)
        s = mi.SurfaceInteraction3f()
        s.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))

        def reflected(wi_, wo_, bsdf=bsdf, s=s):
            s.wi = wi_
            return bsdf.eval(mi.BSDFContext(), s, wo_)
        got = first_channel(mi, reflected, wi, wo)
        hv = wi + wo; hv /= np.linalg.norm(hv, axis=1, keepdims=True)
        a2 = alpha * alpha
        D = 1.0 / (np.pi * a2 * ((hv[:, 0] ** 2 + hv[:, 1] ** 2) / a2 + hv[:, 2] ** 2) ** 2)

        def g1(v):
            t2 = (1 - v[:, 2] ** 2) / v[:, 2] ** 2
            return 2.0 / (1.0 + np.sqrt(1.0 + a2 * t2))
        want = D * g1(wi) * g1(wo) / (4 * wi[:, 2] * wo[:, 2]) * wo[:, 2]   # f cos_o, F = 1
        err = np.max(np.abs(got - want) / np.maximum(want, 1e-6))
        found["roughconductor"][alpha] = float(err)
        print(f"roughconductor ggx alpha={alpha}: eval vs F=1 * D G1 G1 / (4 cos_i cos_o) * cos_o: "
              f"max relative difference {err:.2e} over 1000 random pairs")
    return found


# -------------------------------------------------------------------------------------------- main
def parse_args(argv=None):
    p = OneLineParser(description=__doc__.split("\n\n")[0],
                      formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--spp", type=int, default=1024, help="samples per pixel for both renderers (default %(default)s)")
    p.add_argument("--mitsuba-spp", type=int, default=None, help="Mitsuba's spp if different from --spp")
    p.add_argument("--resolution", type=int, default=256,
                   help=f"square image side in pixels, at least {RESOLUTION_MIN} (default %(default)s)")
    p.add_argument("--runs", type=int, default=PROTOCOL_RUNS,
                   help=f"timed renders per renderer and case, the same seed (median; default {PROTOCOL_RUNS})")
    p.add_argument("--probe", type=Path, default=DEFAULT_PROBE, help="lat-long EXR probe (default %(default)s)")
    p.add_argument("--rotation", type=float, default=0.0, help="probe rotation about +Y, degrees (default %(default)g)")
    p.add_argument("--scale", type=float, default=1.0, help="probe radiance scale (default %(default)g)")
    p.add_argument("--cases", default=",".join(CASES), help=f"comma list of {', '.join(CASES)} (default %(default)s)")
    p.add_argument("--seed", type=parse_seed, default=0,
                   help="0 to 2^32-1001 (default %(default)s; the warm-up frames use seed + 1000)")
    p.add_argument("--out", type=Path, default=None, help="save <case>_mitsuba.exr, <case>_warpbw.exr, <case>.png")
    p.add_argument("--json", help="write the record here (JSON): the settings and every figure of the table; "
                   "without it, beside --plot as OUT.json")
    p.add_argument("--plot", help="write the plot here (PNG): relMSE against the acceptance and each renderer's "
                   "time, per case; without it, beside --json as OUT.png")
    p.add_argument("--force", action="store_true", help="overwrite those files where --out already holds them, and "
                   "--json / --plot")
    p.add_argument("--variant", default=None, help=f"Mitsuba variant (default: first usable of {VARIANTS})")
    p.add_argument("--no-mis", dest="mis", action="store_false",
                   help="warpbw with BRDF sampling only (its CLI default, 002 Eq. 2).  Default: MIS, one BRDF and "
                        "one environment sample per spp, like for like with Mitsuba's path integrator")
    p.add_argument("--mitsuba-only", action="store_true", help="render Mitsuba only (no warpbw)")
    p.add_argument("--noise-floor", action="store_true",
                   help="also render Mitsuba with seed+1 and report the relMSE between the two Mitsuba images")
    p.add_argument("--no-warmup", action="store_true", help="do not render a 1-spp warm-up frame first")
    p.add_argument("--check-conventions", action="store_true",
                   help="print the camera / envmap / roughconductor conventions measured with Mitsuba, then exit")
    a = p.parse_args(argv)
    if a.spp < 1:
        p.error(f"--spp {a.spp}: expected a positive integer")
    if a.resolution < RESOLUTION_MIN:
        p.error(f"--resolution {a.resolution}: expected at least {RESOLUTION_MIN} pixels (the sphere's interior, "
                f"its coverage eroded by {ERODE_PX}, holds none below)")
    if not 1 <= a.runs <= RUNS_MAX:
        p.error(f"--runs {a.runs}: expected an integer from 1 to {RUNS_MAX} (the timed runs of one point)")
    if a.mitsuba_spp is not None and a.mitsuba_spp < 1:
        p.error(f"--mitsuba-spp {a.mitsuba_spp}: expected a positive integer")
    if not math.isfinite(a.rotation):
        p.error(f"--rotation {a.rotation}: expected a finite angle in degrees")
    if not (math.isfinite(a.scale) and a.scale > 0):
        p.error(f"--scale {a.scale}: expected a finite positive radiance scale")
    if a.seed + 1000 > SEED_MAX:
        p.error(f"--seed {a.seed}: expected at most {SEED_MAX - 1000} (the warm-up frames use seed + 1000)")
    cases = [c.strip() for c in a.cases.split(",") if c.strip()]
    if not cases or len(set(cases)) < len(cases) or not set(cases) <= set(CASES):   # none ran nothing, exit 0
        p.error(f"--cases {a.cases!r}: expected distinct names among {', '.join(CASES)}")
    a.cases = cases
    if not a.check_conventions and not a.probe.expanduser().is_file():   # no probe in the conventions
        p.error(f"--probe {a.probe}: no such file (expected a lat-long EXR probe)")
    if a.out is not None and not a.check_conventions:   # before Mitsuba is imported, and before any render
        check_output_dir(a.out, "--out")
        kinds = ("_mitsuba.exr", ".png") if a.mitsuba_only else ("_mitsuba.exr", "_warpbw.exr", ".png")
        check_overwrite([a.out / f"{c}{k}" for c in a.cases for k in kinds], a.force, "--out",
                        inputs=[a.probe.expanduser()])
    if not a.check_conventions:   # as warpbw bench's: the one not given beside the other, checked before any render
        a.json, a.plot = check_record_outputs(a.json, a.plot, a.force, inputs=[a.probe.expanduser()])
    return a


def median_of_runs(render, runs: int) -> tuple:
    """``render()`` -> (..., seconds), called ``runs`` times: the last call's results with the median seconds."""
    outs = [render() for _ in range(runs)]
    return (*outs[-1][:-1], statistics.median(o[-1] for o in outs))


# the record's names of a table row's figures (units in the names, as warpbw bench's record)
RECORD_KEYS = {"t_mi": "mitsuba_time_s", "t_wb": "warpbw_time_s", "mean_mi": "mitsuba_mean", "mean_wb": "warpbw_mean",
               "relmse": "relmse", "relmse_sum": "relmse_sum", "psnr": "psnr_db", "n": "pixels",
               "iou": "coverage_iou", "floor": "noise_floor_relmse"}


def write_plot(record: dict, path) -> None:
    """Per case: warpbw's relMSE against Mitsuba (and Mitsuba's own noise floor) with the acceptance line, and each
    renderer's time."""
    from matplotlib.figure import Figure

    cases = record["cases"]
    x = np.arange(len(cases))
    fig = Figure(figsize=(10, 4))   # not pyplot's: nothing to close, the caller's backend kept
    ax, ax2 = fig.subplots(1, 2)
    if any("relmse" in c for c in cases):
        ax.bar(x - 0.2, [c.get("relmse", np.nan) for c in cases], 0.4, label="warpbw vs Mitsuba")
    if any("noise_floor_relmse" in c for c in cases):
        ax.bar(x + 0.2, [c.get("noise_floor_relmse", np.nan) for c in cases], 0.4, label="Mitsuba vs Mitsuba")
    ax.axhline(record["acceptance_relmse"], color="C3", ls="--",
               label=f"acceptance {record['acceptance_relmse']:.0%}")
    ax.set_yscale("log")
    ax.set_ylabel("relMSE over the interior")
    ax2.bar(x - 0.2, [c["mitsuba_time_s"] for c in cases], 0.4, label=f"Mitsuba ({record['mitsuba_spp']} spp)")
    if any("warpbw_time_s" in c for c in cases):
        ax2.bar(x + 0.2, [c.get("warpbw_time_s", np.nan) for c in cases], 0.4,
                label=f"warpbw ({record['warpbw_spp']} spp, {'MIS' if record['mis'] else 'BRDF sampling'})")
    ax2.set_ylabel("render time (s)")
    for a in (ax, ax2):
        a.set_xticks(x, [c["case"] for c in cases])
        a.grid(True, axis="y", which="both", alpha=0.3)
        a.legend(fontsize=8)
    fig.suptitle(f"{Path(record['probe']).name}, {record['resolution']}x{record['resolution']}; Mitsuba "
                 f"{record['mitsuba_version']} {record['mitsuba_variant']}", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv=None) -> int:
    args = parse_args(argv)
    mi, variant = import_mitsuba(args.variant)
    if args.check_conventions:
        check_conventions(mi)
        return 0
    mspp = args.mitsuba_spp or args.spp
    probe = args.probe.expanduser()
    probe_rgb = load_probe(mi, probe)

    wb = None
    if not args.mitsuba_only:
        try:
            wb = import_warpbw()
        except Exception as exc:  # noqa: BLE001 - report and carry on with Mitsuba alone
            print(f"warpbw side unavailable ({type(exc).__name__}: {exc}); rendering Mitsuba only")
    relmse, psnr, metric_label = metric_functions()

    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
    print(f"Mitsuba {mi.__version__} variant {variant}; probe {probe} ({probe_rgb.shape[1]}x{probe_rgb.shape[0]}), "
          f"rotation {args.rotation} deg, scale {args.scale}; {args.resolution}x{args.resolution}, "
          f"spp Mitsuba {mspp} / warpbw {args.spp}")
    if wb is not None:
        print(f"metric: {metric_label}; interior = warpbw coverage eroded by {ERODE_PX} px; "
              f"test = warpbw, ref = Mitsuba; acceptance relMSE < {ACCEPT_RELMSE:.0%}")

    rows = []
    exrs, sides = {}, {}   # images by output path, written together at the end
    for case in args.cases:
        mat = CASES[case]
        scene = mitsuba_scene(mi, probe_rgb, mat, args.resolution, mspp, args.rotation, args.scale)
        if not args.no_warmup:
            render_mitsuba(mi, scene, 1, args.seed + 1000)
        ref, alpha, t_mi = median_of_runs(lambda: render_mitsuba(mi, scene, mspp, args.seed), args.runs)
        row = dict(case=case, t_mi=t_mi, mean_mi=float(ref[alpha > 0.5].mean()))
        if args.noise_floor:
            ref2, _, _ = render_mitsuba(mi, scene, mspp, args.seed + 1)
            row["floor"] = float(relmse(ref2, ref, erode(alpha > 0.5, ERODE_PX)))
        if args.out is not None:
            exrs[args.out / f"{case}_mitsuba.exr"] = ref
        test = None
        if wb is not None:
            toml_text = warpbw_toml(probe, mat, args.resolution, args.rotation, args.scale)
            if not args.no_warmup:
                render_warpbw(*wb, toml_text, 1, args.seed + 1000, args.mis)
            test, cov, t_wb = median_of_runs(lambda: render_warpbw(*wb, toml_text, args.spp, args.seed, args.mis),
                                             args.runs)
            if test.shape != ref.shape:
                fail(f"warpbw image {test.shape} and Mitsuba image {ref.shape} differ in shape")
            mask = erode(cov, ERODE_PX)
            cov_mi = alpha > 0.5
            iou = float((cov & cov_mi).sum() / max((cov | cov_mi).sum(), 1))
            row.update(t_wb=t_wb, relmse=float(relmse(test, ref, mask)), psnr=float(psnr(test, ref, mask)),
                       relmse_sum=relmse_sum(test, ref, mask),
                       n=int(mask.sum()), iou=iou, mean_wb=float(test[cov].mean()))
            if args.out is not None:
                exrs[args.out / f"{case}_warpbw.exr"] = test
        if args.out is not None:
            sides[args.out / f"{case}.png"] = (ref, test)
        rows.append(row)

    if wb is None:
        print(f"{'case':<8} {'Mitsuba s':>10} {'Msamples/s':>10} {'mean':>8}" + ("  relMSE(M vs M)" if args.noise_floor else ""))
        for r in rows:
            ms = args.resolution ** 2 * mspp / r["t_mi"] / 1e6
            print(f"{r['case']:<8} {r['t_mi']:>10.2f} {ms:>10.1f} {r['mean_mi']:>8.4f}"
                  + (f"  {r['floor']:.2e}" if args.noise_floor else ""))
    else:
        hdr = (f"{'case':<8} {'relMSE':>9} {'rel(sum)':>9} {'PSNR dB':>8} {'pixels':>7} {'cov IoU':>7} {'Mitsuba s':>9} "
               f"{'warpbw s':>9} {'wb/Mi':>6}" + (f" {'floor':>9}" if args.noise_floor else "") + "  result")
        print(hdr)
        for r in rows:
            verdict = "PASS" if r["relmse"] < ACCEPT_RELMSE else "FAIL"
            print(f"{r['case']:<8} {r['relmse']:>9.2e} {r['relmse_sum']:>9.2e} {r['psnr']:>8.2f} {r['n']:>7d} {r['iou']:>7.4f} "
                  f"{r['t_mi']:>9.2f} {r['t_wb']:>9.2f} {r['t_wb'] / r['t_mi']:>6.2f}"
                  + (f" {r['floor']:>9.2e}" if args.noise_floor else "") + f"  {verdict}")
        if not args.mis and any(r["relmse"] >= ACCEPT_RELMSE for r in rows):
            print("note: warpbw ran its default estimator (BRDF sampling only); Mitsuba's path tracer uses MIS. "
                  "Rerun without --no-mis for the equal-estimator comparison, or --noise-floor to see Mitsuba's own noise.")
    if args.out is not None:
        # every image, or none: an error leaves the old set
        with staged_outputs([*exrs, *sides], force=args.force) as at:
            for p, rgb in exrs.items():
                save_exr(mi, at[p], rgb)
            for p, pair in sides.items():
                save_side_by_side(at[p], *pair)
        print(f"images written to {args.out}")
    if args.json is not None:
        cases = []
        for r in rows:
            c = {"case": r["case"], **{RECORD_KEYS[k]: v for k, v in r.items() if k in RECORD_KEYS}}
            c["mitsuba_msamples_per_s"] = args.resolution ** 2 * mspp / r["t_mi"] / 1e6
            if "t_wb" in r:
                c["time_ratio"] = r["t_wb"] / r["t_mi"]
                c["result"] = "PASS" if r["relmse"] < ACCEPT_RELMSE else "FAIL"
            cases.append(c)
        record = {"probe": str(probe), "rotation_deg": args.rotation, "scale": args.scale,
                  "resolution": args.resolution, "mitsuba_spp": mspp, "warpbw_spp": None if wb is None else args.spp,
                  "mis": args.mis, "seed": args.seed, "runs": args.runs, "warmup": not args.no_warmup,
                  "erode_px": ERODE_PX,
                  "acceptance_relmse": ACCEPT_RELMSE, "metric": metric_label, "mitsuba_version": str(mi.__version__),
                  "mitsuba_variant": variant, "device": "cpu", "cases": cases}
        write_record(args.json, args.plot, record, write_plot, force=args.force)
    warning = few_runs_warning(args.runs)
    if warning is not None:
        print(f"compare_mitsuba.py: warning: {warning}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(run_command("compare_mitsuba.py", lambda _: main(), None))
