"""Validation of the bandwidth pass's predictions (002 Sec. 2.2, 2.4 and Fig. 12).

    python examples/validate_bandwidth.py --out DIR [--size 256] [--scenes NAME ...]
        [--env-signal log | radiance] [--quick] [--force]

For each validation scene (a sphere with the NPF fit of color-changing-paint3 under forest.exr, as in
002 Fig. 12; the bunny with gold-metallic-paint under studio.exr; a GGX gold sphere under studio.exr):

1. Converged image: the forward reference (002 Eq. 2) with MIS at ``--ref-spp`` samples per pixel,
   rendered as two independently seeded halves.  Their difference estimates the image's residual
   noise, reported as the share of each FFT window's energy that is noise ("noise_fraction"): white
   noise spreads over all frequencies and would push the reference bandwidth up, so its expected power
   (flat over frequency, known from the per-pixel noise variance) is subtracted from every window's
   spectrum, and windows where it is more than ``MAX_NOISE_FRACTION`` of the energy are left out.
   The subtraction removes the noise's expected power, not its scatter, so the sample count is doubled
   while the median window is more than ``--ref-noise`` noise (default ``REF_NOISE_TARGET``, 1%), up to
   ``--ref-spp-max`` (:func:`converged_image`).
2. Image bandwidth: the predicted b_p (Eq. 6, cycles/pixel) against a reference from a 32x32 Hann-windowed
   FFT of the converged image's luminance, centred on every ``--stride``-th pixel and bilinearly
   interpolated to the others: the radial frequency below which 95% of the window's spectral energy
   lies, the mean (DC) removed (002 Sec. 2: "the 95th percentile of the power spectra").  Only windows
   whose Hann-weighted coverage is at least ``MIN_WINDOW_COVER`` and whose residual noise is at most
   ``MAX_NOISE_FRACTION`` of their AC energy count (the noise's expected power is subtracted first);
   uncovered pixels inside them take the covered pixels' mean, so the silhouette does not read as a step
   (filling them instead with the nearest covered pixel's value, which leaves no step where the rim differs
   from the mean, was measured with 4096-spp images: 0.565 / 0.345 / 0.464 per pixel against 0.568 / 0.351 /
   0.491).  Reported:
   Spearman rank correlation over those pixels, against b_p itself and against b_p averaged over the same window;
   for information, the first over the interior alone (:func:`interior`: more than half a window from the
   silhouette; 0.613 / 0.546 / 0.107 at 256x256, docs/measurements.md says why the GGX sphere's is low);
   and, as a yardstick, the same for the converged image's own relative gradient |grad L| / L (an oracle
   that knows the true image: how far any per-pixel statistic can get against this reference).  For
   information, not the check: the same two correlations against the same windows' mirrored (DCT) spectrum,
   which resolves down to about 1/64 cycles/pixel (the Hann window reads anything slower than 1/32 as 0.06)
   ("bandwidth_spearman_even", "bandwidth_spearman_even_windowed").  At 256x256 it reads 0.51 / 0.25 / 0.49
   per pixel and 0.63 / 0.50 / 0.52 window-averaged (Hann: 0.60 / 0.35 / 0.49 and 0.69 / 0.57 / 0.53): a
   reference that resolves slower frequencies does not lift the per-pixel figure.  Also reported, the
   ceiling (:func:`spearman_ceiling`): the most any predictor can reach against the reference's ties.  At
   256x256 the Hann reference reads 68% of the GGX sphere's scored pixels at its plateau (slower than it
   resolves), which caps the correlation there at 0.83 (0.99 and 1.00 on the other two scenes).  The
   plateau is one radius shared by eight symmetric bins, inside which the interpolation is flat.  Measured,
   not adopted: interpolating between distinct radii instead (each radius's bins summed first) leaves no
   ties, but drops the GGX sphere from 0.49 to 0.32 per pixel (512x512: 0.51 to 0.35).  The other two
   scenes move by at most 0.03.  So the ties do not hide agreement that a finer reading of the plateau
   would show (recomputed from the session-26 maps of both sizes).  Nor may the prediction be floored at
   the window's bin spacing 1/32 so that it ties where the reference does: that lifts the GGX sphere from
   0.49 to 0.62 (session 43, from session 42's maps), but the reference still orders sines between 0.016
   and 0.03 cycles/pixel (medians 0.061 to 0.067; its plateau, 0.056, starts below about 0.012), and an
   exact predictor of sines from 0.004 to 0.3 falls from 0.95 to 0.92 with that floor.  At 1/64 the floor
   changes nothing.
3. Variance: the predicted sigma2 (Eq. 9, V(L_p) <= sigma2 / N_p for UNIFORM hemisphere sampling,
   002 Sec. 2.4) against the brute-force per-pixel variance of the one-sample uniform estimator
   X = 2 pi lum(L_i rho) cos theta_i, from ``--uniform-samples`` stratified directions per pixel (a Warp
   kernel below: E[X] and E[X^2] are both integrals over the hemisphere, so a jittered grid estimates
   them better than independent samples).  Reported: Spearman rank correlation, the fraction of covered
   pixels where the bound is conservative (sigma2 >= brute-force variance) and the median ratio.  For
   information the same against the renderer's actual estimator (BRDF importance sampling, no MIS,
   ``--bis-samples`` independent samples per pixel, same kernel).
   Diagnostic: the pass run again with ``--nb-diagnostic`` (1024) directions instead of n_b = 16 tells
   the bound's own shape apart from the sampling error of estimating it from 16 directions.
4. Writes DIR/validate_<scene>.png (a figure like 002 Fig. 12: predicted and reference variance,
   predicted and reference bandwidth on shared log colour scales, the converged image, scatter plots),
   DIR/validate_<scene>_maps.npz (every map), DIR/validate_bandwidth.json (all figures) and prints a
   table.  Existing outputs are kept unless --force.

The bunny's figures quoted above were measured with the signed mean curvature H that the pass read until
session 28; with the local |H| (``warpbw.bandwidth`` docstring) it reads 0.516 per pixel and 0.613
window-averaged at 256x256 (DCT 0.368 and 0.555), 0.507 and 0.582 at 512x512.
``--scenes bunny-ccp3-forest bunny-gmp-forest``: the bunny under forest.exr, with 002 Fig. 12's material and
with the default bunny's, for information (not run by default; figures beside ``SCENES``).
``--quick``: tiny sizes and sample counts (for the smoke test; the numbers then mean little).
The acceptance targets (issue 3) are rank correlations > 0.5 and a bound conservative on > 90% of
pixels; the script reports them and exits 0 unless ``--strict``.
"""
from __future__ import annotations

from warpbw.entry import interrupt_in_one_line

interrupt_in_one_line(__name__)   # first: a Ctrl-C while the imports below load says one line, no traceback

import argparse
import functools
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import warp as wp

from warpbw.bandwidth import ENV_SIGNAL_DEFAULT, ENV_SIGNALS, LUMINANCE, N_B_MAX
from warpbw.brdf import MaterialTable, make_brdf_funcs
from warpbw.cli_common import OneLineParser, check_output_dir, init_warp, parse_seed, run_command
from warpbw.errors import SEED_MAX
from warpbw.envmap import EnvMapData, env_radiance
from warpbw.gbuffer import GBufferData
from warpbw.io.shared_data import shared_data_dir
from warpbw.io.staged import staged_outputs
from warpbw.scene import MAX_RESOLUTION, toml_escape
from warpbw.launch import launch_tiled
from warpbw.shading import covered_pixels, pixel_frame, to_world

HERE = Path(__file__).resolve().parent
DATA = shared_data_dir(HERE.parent)   # ../shared/data beside the repository, or $WARPBW_SHARED_DATA

# ----------------------------------------------------------------------------------------- settings
# image side in pixels: half 002's 512, so that a 32x32 window spans about a sixth of the sphere's
# diameter rather than a third at 128 (about 7 minutes for all scenes on 2 cores).  At 512 (--size 512, about
# 30 minutes) the Hann reference reads 0.565 / 0.507 / 0.514 per pixel (the bunny 0.292 with the signed H of
# before session 28; the spheres 0.296 / 0.453 when every image had 4096 spp, 10.3% / 3.0% noise); the variance
# figures hold at both sizes (512: Spearman 0.680 / 0.940 / 0.944, conservative on >= 99.7% of pixels).
# README "Measured" has both sizes.
DEFAULT_SIZE = 256
# converged image: MIS samples per pixel to start with (two halves of 2048), doubled (:func:`converged_image`)
# while the residual noise is more than REF_NOISE_TARGET of the median FFT window's AC energy, up to REF_SPP_MAX.
# The noise's expected power is subtracted from the spectra, but its scatter is not: on the ccp3 sphere at
# 512x512 the median window was 10.3% noise at 4096 spp and the per-pixel bandwidth Spearman read 0.296; at
# 16384 spp, 2.8% and 0.530 (at 256x256: 3.1% and 0.568, 0.8% and 0.601)
REF_SPP = 4096
REF_NOISE_TARGET = 0.01
REF_SPP_MAX = 16384           # at most 4x the starting cost (the ccp3 sphere at 512x512 stops there, at 2.8%)
UNIFORM_SAMPLES = 4096        # stratified uniform directions per pixel for the brute-force variance (64 x 64)
BIS_SAMPLES = 4096            # BRDF-importance samples per pixel for the renderer's estimator's variance
FFT_WINDOW = 32               # 002 Sec. 4.1: "a window size of 32x32 pixels"
FFT_STRIDE = 4                # window centres every 4 pixels, bilinear in between
FFT_PAD = 2                   # zero-padding factor: finer frequency sampling (not resolution) of the spectrum
ENERGY_FRACTION = 0.95        # 002 Sec. 2: bandwidth = the 95th percentile of the power spectrum
FLAT_ENERGY = 1e-10           # a window whose AC energy is below this share of its energy is flat (rounding)
# windows whose AC energy is more than half residual noise are left out: the noise's expected power is
# subtracted from the spectrum, but where it dominates, the difference is mostly the noise's own scatter
MAX_NOISE_FRACTION = 0.5
MIN_WINDOW_COVER = 0.9        # Hann-weighted share of covered pixels a window needs to count
MIN_INTERP_WEIGHT = 0.5       # a pixel needs this much bilinear weight on valid window centres
SEED = 1
GRADIENT_EPS = 1e-3           # added to L in |grad L| / L (the oracle statistic): black pixels do not divide by 0
N_B_DIAGNOSTIC = 1024         # a second bandwidth pass with many directions: separates the bound from its n_b estimate
# issue 3's acceptance targets
TARGET_SPEARMAN = 0.5
TARGET_CONSERVATIVE = 0.9
# --quick: tiny everything (a smoke test, < 60 s with warm caches)
QUICK = {"size": 40, "ref_spp": 32, "uniform_samples": 256, "bis_samples": 256, "window": 16,
         "nb_diagnostic": 64, "max_noise": 1.0, "ref_spp_max": 64}
BOOTSTRAP_REPS = 200          # block-bootstrap resamples of each rank correlation (its standard error)
BOOTSTRAP_TILE = 2            # bootstrap tiles span this many FFT windows (block_bootstrap_se)
SCATTER_POINTS = 4000         # points per scatter plot (a random subset)
COLOUR_PERCENTILES = (1.0, 99.0)   # shared log colour range of a pair of maps

_LUM = wp.constant(wp.vec3(*LUMINANCE))
_TWO_PI = wp.constant(2.0 * math.pi)


# ----------------------------------------------------------------------------------------- kernel
@wp.func
def uniform_hemisphere(u: wp.vec2):
    """Uniform direction over the +Z hemisphere (pdf 1 / 2 pi): cos theta = u0."""
    z = u[0]
    s = wp.sqrt(wp.max(1.0 - z * z, 0.0))
    phi = _TWO_PI * u[1]
    return wp.vec3(s * wp.cos(phi), s * wp.sin(phi), z)


def make_moments_kernel(kinds, importance: bool):
    """Per-pixel E[X] and E[X^2] of a one-sample shading estimator's luminance X.

    ``importance=False``: X = 2 pi lum(L_i(w) rho(w, wo)) cos theta, w uniform over the hemisphere
    (pdf 1 / 2 pi), the estimator the bound of 002 Sec. 2.4 assumes; the n = n_side^2 directions are
    a jittered n_side x n_side grid in (cos theta, phi / 2 pi), the bandwidth pass's parametrisation.
    ``importance=True``: the renderer's estimator without MIS (warpbw.shading): w from the BRDF's
    sampler, X = lum(L_i rho) cos theta / pdf, ``n_s`` independent samples; non-finite contributions count
    as 0 (the renderer drops them from a sum it divides by N)."""
    return _moments_kernel(frozenset(int(k) for k in kinds), bool(importance))


@functools.cache  # one kernel per combination: Warp compiles each once
def _moments_kernel(kinds: frozenset, importance: bool):
    f = make_brdf_funcs(kinds)

    @wp.kernel(module="unique", enable_backward=False)
    def estimator_moments_kernel(gb: GBufferData, mats: MaterialTable, env: EnvMapData,
                                 pixels: wp.array(dtype=wp.int32), offset: int, n_side: int, n_s: int, seed: int,
                                 mean: wp.array(dtype=wp.float64), mean_sq: wp.array(dtype=wp.float64)):
        i = pixels[wp.tid() + offset]
        m = gb.material[i]
        fr = pixel_frame(gb, i)
        wo = fr.wo
        state = wp.rand_init(seed, i)
        s1 = wp.float64(0.0)
        s2 = wp.float64(0.0)
        if wo[2] > 0.0:
            for k in range(n_s):
                x = float(0.0)
                if wp.static(importance):
                    u = wp.vec3(wp.randf(state), wp.randf(state), wp.randf(state))
                    wi = f.sample(mats, m, wo, u)
                    if wi[2] > 0.0:
                        p = f.pdf(mats, m, wi, wo)
                        if p > 0.0:
                            c = wp.cw_mul(f.eval(mats, m, wi, wo), env_radiance(env, to_world(fr, wi)))
                            x = wp.dot(_LUM, c) * (wi[2] / p)
                else:
                    cell = wp.vec2((float(k % n_side) + wp.randf(state)) / float(n_side),
                                   (float(k // n_side) + wp.randf(state)) / float(n_side))
                    wi = uniform_hemisphere(cell)
                    c = wp.cw_mul(f.eval(mats, m, wi, wo), env_radiance(env, to_world(fr, wi)))
                    x = wp.dot(_LUM, c) * (wi[2] * _TWO_PI)
                if not wp.isfinite(x):
                    x = 0.0
                xd = wp.float64(x)
                s1 += xd
                s2 += xd * xd
        mean[i] = s1 / wp.float64(n_s)
        mean_sq[i] = s2 / wp.float64(n_s)

    return estimator_moments_kernel


def estimator_variance(gb, materials, env_data, n_samples: int, importance: bool, seed: int,
                       device: str = "cpu") -> tuple[np.ndarray, np.ndarray]:
    """(mean, variance) of the one-sample estimator per pixel, (H, W) float64 (0 where no geometry).
    ``n_samples`` is rounded to a square for the stratified (uniform) case; the BRDF-sampled one takes it as given
    (it rounded it too: 2 samples were 1, 1000 were 961)."""
    n_side = max(1, int(round(math.sqrt(n_samples))))
    n_s = int(n_samples) if importance else n_side * n_side
    H, W = gb.height, gb.width
    mean = wp.zeros(H * W, dtype=wp.float64, device=device)
    mean_sq = wp.zeros(H * W, dtype=wp.float64, device=device)
    pix = covered_pixels(gb, device)
    kernel = make_moments_kernel(materials.kinds, importance)
    launch_tiled(kernel, pix.shape[0],
                 lambda o, c: [gb.data, materials.table, env_data, pix, o, n_side, n_s, seed, mean, mean_sq],
                 device)
    m1 = mean.numpy().reshape(H, W)
    m2 = mean_sq.numpy().reshape(H, W)
    return m1, np.maximum(m2 - m1 * m1, 0.0)


# ----------------------------------------------------------------------------------------- scenes
SCENE_HEADER = """
[camera]
position = {position}
look_at = {look_at}
fov = {fov}
resolution = [{w}, {h}]
[environment]
file = "{data}/envmaps/{probe}"
rotation = {rotation}
"""
# the shapes the scenes frame, each with its camera ([camera] position, look_at, fov), and the NPF materials
SPHERE = {"camera": ("[0.0, 0.0, 3.0]", "[0.0, 0.0, 0.0]", 45.0),
          "objects": '[[object]]\nshape = "sphere"\ncenter = [0.0, 0.0, 0.0]\nradius = 1.0\nmaterial = "m"\n'}
BUNNY = {"camera": ("[0.0, 0.1, 3.4]", "[0.0, 0.0, 0.0]", 38.0),
         "objects": '[[object]]\nmesh = "{data}/meshes/bunny.obj"\nmaterial = "m"\n'}


def npf_material(name: str) -> str:
    """[material.m] body of the NPF fit ``name`` read from ../shared/data."""
    return f'type = "npf"\ntable = "{{data}}/brdf/npf.bin"\nname = "{name}"\nlookup = "linear"\n'


SCENES = {
    # 002 Fig. 12's material on a sphere filling most of the frame
    "sphere-ccp3-forest": {**SPHERE, "probe": "forest.exr", "rotation": 0.0,
                           "material": npf_material("color-changing-paint3")},
    # a mesh (curvature from the G-buffer) with a glossy NPF material
    "bunny-gmp-studio": {**BUNNY, "probe": "studio.exr", "rotation": 0.0,
                         "material": npf_material("gold-metallic-paint")},
    # an analytic material: GGX conductor (gold)
    "sphere-ggx-studio": {**SPHERE, "probe": "studio.exr", "rotation": 90.0,
                          "material": 'type = "ggx"\nalpha = 0.2\nspecular = [1.0, 1.0, 1.0]\n'
                                      'eta = [0.143, 0.374, 1.442]\nk = [3.983, 2.385, 1.603]\n'},
    # not run by default: the bunny under forest.exr, with 002 Fig. 12's material and with the default bunny's
    # (256x256, session 28: per pixel 0.383 and 0.350; b_p window-averaged 0.535 and 0.382; with the signed H
    # of sessions <= 27: 0.302 and 0.221, 0.529 and 0.369; the converged image's own |grad L| / L 0.214 and
    # 0.023 per pixel, 0.587 and 0.270 window-averaged)
    "bunny-ccp3-forest": {**BUNNY, "probe": "forest.exr", "rotation": 0.0,
                          "material": npf_material("color-changing-paint3")},
    "bunny-gmp-forest": {**BUNNY, "probe": "forest.exr", "rotation": 0.0,
                         "material": npf_material("gold-metallic-paint")},
}
# the validation scenes of issue 3 (run when --scenes is not given); the others are for information
DEFAULT_SCENES = ("sphere-ccp3-forest", "bunny-gmp-studio", "sphere-ggx-studio")


def scene_toml(name: str, size: int, data: Path = DATA) -> str:
    s = SCENES[name]
    pos, at, fov = s["camera"]
    d = toml_escape(data.as_posix(), f"--data {data}")   # inside the scene's quoted paths
    text = SCENE_HEADER.format(position=pos, look_at=at, fov=fov, w=size, h=size, data=d, probe=s["probe"],
                               rotation=s["rotation"])
    return text + s["objects"].format(data=d) + "[material.m]\n" + s["material"].format(data=d)


# ----------------------------------------------------------------------------------------- analysis
def hann(n: int) -> np.ndarray:
    """Periodic Hann window of n points."""
    return 0.5 - 0.5 * np.cos(2.0 * np.pi * np.arange(n) / n)


def _window_stack(a: np.ndarray, window: int, stride: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Windows of ``a`` (zero-padded) centred on pixels (ys[j], xs[i]), rows y - window/2 .. y + window/2 - 1.
    Returns (ys, xs, (ny, nx, window, window) view)."""
    H, W = a.shape
    half = window // 2
    pad = np.pad(a, ((half, half), (half, half)))
    ys = np.arange(0, H, stride)
    xs = np.arange(0, W, stride)
    view = np.lib.stride_tricks.sliding_window_view(pad, (window, window))
    return ys, xs, view[ys][:, xs]


def _interp_to_pixels(grid: np.ndarray, valid: np.ndarray, shape, stride: int) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear interpolation of a coarse grid (centres every ``stride`` pixels) to every pixel, using only
    valid centres (normalised weights).  Returns (values, weight on valid centres in [0, 1]).

    The weights average the corners' differences from the most-weighted valid corner, so that equal corners
    give exactly their value: a plain sum(w g) / sum(w) is off by an ulp or two, and rank statistics would
    then order pixels that the reference reads alike (a Hann window's plateau) by round-off."""
    H, W = shape
    ny, nx = grid.shape
    gy = np.arange(H) / stride
    gx = np.arange(W) / stride
    y0 = np.minimum(np.floor(gy).astype(int), ny - 1)
    x0 = np.minimum(np.floor(gx).astype(int), nx - 1)
    y1 = np.minimum(y0 + 1, ny - 1)
    x1 = np.minimum(x0 + 1, nx - 1)
    fy = np.clip(gy - y0, 0.0, 1.0)[:, None]
    fx = np.clip(gx - x0, 0.0, 1.0)[None, :]
    g = np.where(valid, grid, 0.0)
    v = valid.astype(np.float64)
    corners = [(wy * wx * v[np.ix_(yy, xx)], g[np.ix_(yy, xx)])
               for yy, wy in ((y0, 1.0 - fy), (y1, fy)) for xx, wx in ((x0, 1.0 - fx), (x1, fx))]
    w_all = np.stack([w for w, _ in corners])
    g_all = np.stack([c for _, c in corners])
    base = np.take_along_axis(g_all, np.argmax(w_all, axis=0)[None], axis=0)[0]
    wsum = w_all.sum(axis=0)
    acc = (w_all * (g_all - base)).sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(wsum > 0, base + acc / np.maximum(wsum, 1e-300), np.nan)
    return out, wsum


def _hann_spectrum(filled, w2, nv, m):
    """Power spectrum of each window (..., n, n) tapered by the Hann window ``w2``, zero-padded by ``FFT_PAD``:
    (power with the DC bin 0 and, given the per-pixel noise variance ``nv``, the noise's expected power
    subtracted; |f| of every bin, flat; AC energy; the noise's expected share of it by Parseval, or None)."""
    window = w2.shape[-1]
    dc = (w2 * filled).sum(axis=(-2, -1)) / w2.sum()
    d = (filled - dc[..., None, None]) * w2
    n_fft = FFT_PAD * window
    power = np.abs(np.fft.fft2(d, s=(n_fft, n_fft))) ** 2
    ac = (d * d).sum(axis=(-2, -1))
    noise_share = None
    if nv is not None:
        # white noise of per-pixel variance v adds E|DFT|^2 = sum(w^2 v) to every bin: subtract it, so the
        # residual noise of the converged image does not read as high frequencies
        noise_power = (w2 * w2 * nv * m).sum(axis=(-2, -1))
        power = power - noise_power[..., None, None]
        with np.errstate(invalid="ignore", divide="ignore"):
            noise_share = noise_power / ac       # Parseval: the noise's energy in the tapered window
    power[..., 0, 0] = 0.0
    f = np.fft.fftfreq(n_fft)
    radius = np.sqrt(f[:, None] ** 2 + f[None, :] ** 2).reshape(-1)
    return power, radius, ac, noise_share


def _even_spectrum(filled, nv, m):
    """Power spectrum of each window's even (mirrored) extension, no taper: the orthonormal 2D DCT-II, whose
    bin k lies at k / (2 n) cycles/pixel.  The mirror has no seam, so a smooth window needs no taper and keeps
    its lines narrow.  Same returns as ``_hann_spectrum``."""
    window = filled.shape[-1]
    k, x = np.meshgrid(np.arange(window), np.arange(window) + 0.5, indexing="ij")
    c = np.sqrt(2.0 / window) * np.cos(np.pi * k * x / window)     # orthonormal DCT-II matrix, row k
    c[0] /= math.sqrt(2.0)
    d = filled - filled.mean(axis=(-2, -1), keepdims=True)
    power = np.einsum("ky,...yx,lx->...kl", c, d, c, optimize=True) ** 2
    ac = (d * d).sum(axis=(-2, -1))
    noise_share = None
    if nv is not None:
        # an orthonormal basis function's squares average 1 / n^2 over the window: white noise of per-pixel
        # variance v adds about the window's mean v to every bin (exactly, for v constant)
        noise_power = (nv * m).mean(axis=(-2, -1))
        power = power - noise_power[..., None, None]
        with np.errstate(invalid="ignore", divide="ignore"):
            noise_share = noise_power * window * window / ac      # Parseval (orthonormal): n^2 bins
    power[..., 0, 0] = 0.0
    f = np.arange(window) / (2.0 * window)
    radius = np.sqrt(f[:, None] ** 2 + f[None, :] ** 2).reshape(-1)
    return power, radius, ac, noise_share


SPECTRA = ("hann", "even")    # windowed_bandwidth's spectrum: the Hann-tapered FFT (the reference), or the DCT


def windowed_bandwidth(image: np.ndarray, mask: np.ndarray | None = None, window: int = FFT_WINDOW,
                       stride: int = FFT_STRIDE, fraction: float = ENERGY_FRACTION,
                       min_cover: float = MIN_WINDOW_COVER, noise_var: np.ndarray | None = None,
                       max_noise: float = MAX_NOISE_FRACTION, spectrum: str = "hann") -> dict:
    """Reference image bandwidth (cycles/pixel) of a 2D signal by a Hann-windowed FFT.

    For each window (centres every ``stride`` pixels): uncovered pixels take the covered pixels'
    weighted mean, the window's weighted mean (DC) is removed, the power spectrum of the windowed
    signal is taken (zero-padded by ``FFT_PAD``), and the bandwidth is the radial frequency
    |f| = sqrt(fx^2 + fy^2) at which the cumulative energy (bins sorted by |f|, linear between bins)
    reaches ``fraction`` of the total.  A flat window has bandwidth 0.  The window's own spectrum
    widens every line: a 32-point Hann window reads a sine of frequency f as about f + 0.03 cycles/pixel
    (within 1.4x for f >= 0.08), and anything slower than about 1/32 as 0.06-0.07 (uncertainty
    principle, 002 footnote 1), though its median over positions still grows with f.

    ``spectrum="even"`` takes instead the spectrum of the same window's mirrored extension (``_even_spectrum``,
    the DCT; its mean, not a Hann-weighted one, is removed and filled in): half the bin spacing and no taper,
    so it resolves down to about 1/64 cycles/pixel (a sine of 0.01 reads about 0.02, where the Hann window reads
    0.06).  The windows and the rules for leaving one out are the same (the noise share is that of the untapered
    window).

    Returns a dict: "map" (H, W) interpolated to every pixel (NaN where not valid), "valid" (H, W) bool,
    "grid" / "grid_valid" at the centres, "ys", "xs", "energy" (AC energy per window) and, with
    ``noise_var`` (per-pixel variance of ``image``), "noise_fraction" (the expected noise share of each
    window's AC energy, by Parseval).  White noise would read as a high bandwidth, so with ``noise_var``
    its expected power sum(w^2 var), the same in every frequency bin, is subtracted from the spectrum
    before the energy fraction is taken, and windows above ``max_noise`` are not valid."""
    if spectrum not in SPECTRA:
        raise ValueError(f"spectrum: expected one of {SPECTRA}, got {spectrum!r}")
    img = np.asarray(image, np.float64)
    H, W = img.shape
    cov = np.ones((H, W), bool) if mask is None else np.asarray(mask, bool)
    w1 = hann(window)
    w2 = np.outer(w1, w1)
    ys, xs, v = _window_stack(np.where(cov, img, 0.0), window, stride)
    _, _, m = _window_stack(cov.astype(np.float64), window, stride)
    wm = w2 * m
    cover = wm.sum(axis=(-2, -1)) / w2.sum()
    fill_w = wm if spectrum == "hann" else m
    with np.errstate(invalid="ignore", divide="ignore"):
        mu = (fill_w * v).sum(axis=(-2, -1)) / fill_w.sum(axis=(-2, -1))
    mu = np.nan_to_num(mu)[..., None, None]
    filled = np.where(m > 0, v, mu)
    nv = None
    if noise_var is not None:
        _, _, nv = _window_stack(np.where(cov, noise_var, 0.0), window, stride)
    if spectrum == "hann":
        power, radius, ac, noise_share = _hann_spectrum(filled, w2, nv, m)
        scale = ((filled * w2) ** 2).sum(axis=(-2, -1))
    else:
        power, radius, ac, noise_share = _even_spectrum(filled, nv, m)
        scale = (filled ** 2).sum(axis=(-2, -1))
    order = np.argsort(radius, kind="stable")
    r_sorted = radius[order]
    ps = power.reshape(power.shape[:2] + (-1,))[..., order]
    cum = np.cumsum(ps, axis=-1)
    total = cum[..., -1]
    target = fraction * total
    k = np.argmax(cum >= target[..., None], axis=-1)        # first bin reaching the target
    c1 = np.take_along_axis(cum, k[..., None], -1)[..., 0]
    c0 = np.take_along_axis(cum, np.maximum(k - 1, 0)[..., None], -1)[..., 0]
    r1, r0 = r_sorted[k], r_sorted[np.maximum(k - 1, 0)]
    with np.errstate(invalid="ignore", divide="ignore"):
        t = np.clip((target - c0) / (c1 - c0), 0.0, 1.0)
    flat = ac <= FLAT_ENERGY * scale
    grid = np.where(flat | ~(total > 0), 0.0, r0 + np.nan_to_num(t) * (r1 - r0))   # linear in the cumulative energy
    grid_valid = cover >= min_cover
    out = {"ys": ys, "xs": xs, "grid": grid, "cover": cover, "energy": ac}
    if noise_var is not None:
        out["noise_fraction"] = noise_share
        grid_valid = grid_valid & ~(out["noise_fraction"] > max_noise)   # NaN (0 / 0: flat, noiseless) stays
        grid_valid = grid_valid & ~((noise_share > 0) & ~(total > 0))   # nothing left above the noise: unknown, not 0
    out["grid_valid"] = grid_valid
    mp, wsum = _interp_to_pixels(grid, grid_valid, (H, W), stride)
    valid = cov & (wsum >= MIN_INTERP_WEIGHT)
    out["map"] = np.where(valid, mp, np.nan)
    out["valid"] = valid
    return out


def windowed_mean(values: np.ndarray, mask: np.ndarray, window: int = FFT_WINDOW, stride: int = FFT_STRIDE,
                  grid_valid: np.ndarray | None = None) -> np.ndarray:
    """Hann-weighted mean of ``values`` over the covered pixels of each window, interpolated to pixels:
    the prediction seen through the reference's footprint."""
    w1 = hann(window)
    w2 = np.outer(w1, w1)
    _, _, v = _window_stack(np.where(mask, values, 0.0), window, stride)
    _, _, m = _window_stack(mask.astype(np.float64), window, stride)
    with np.errstate(invalid="ignore", divide="ignore"):
        g = (w2 * m * v).sum(axis=(-2, -1)) / (w2 * m).sum(axis=(-2, -1))
    valid = np.isfinite(g) if grid_valid is None else (grid_valid & np.isfinite(g))
    mp, _ = _interp_to_pixels(np.nan_to_num(g), valid, mask.shape, stride)
    return mp


def ranks(x: np.ndarray) -> np.ndarray:
    """Ranks 1..n of x, ties given the mean of the ranks they span."""
    uniq, inverse, counts = np.unique(np.asarray(x, np.float64), return_inverse=True, return_counts=True)
    last = np.cumsum(counts)                       # rank of the last element of each group of ties
    mean_rank = last - 0.5 * (counts - 1)          # mean of ranks last - counts + 1 .. last
    return mean_rank[inverse.reshape(-1)]


def spearman(a: np.ndarray, b: np.ndarray) -> float:
    """Spearman rank correlation (Pearson correlation of the tie-averaged ranks); NaN if undefined."""
    a = np.asarray(a, np.float64).reshape(-1)
    b = np.asarray(b, np.float64).reshape(-1)
    if a.size < 3:
        return float("nan")
    ra = ranks(a) - 0.5 * (a.size + 1)
    rb = ranks(b) - 0.5 * (b.size + 1)
    den = math.sqrt(float(ra @ ra) * float(rb @ rb))
    return float(ra @ rb) / den if den > 0 else float("nan")


def block_bootstrap_se(a: np.ndarray, b: np.ndarray, mask: np.ndarray, block: int, reps: int = BOOTSTRAP_REPS,
                       seed: int = SEED) -> float:
    """Standard error of ``spearman(a[mask], b[mask])`` by a block bootstrap: the image is cut into ``block`` x
    ``block`` tiles, and the tiles holding masked pixels are drawn ``reps`` times with replacement, each time
    as many as there are.  Neighbouring pixels are not independent (the reference reads overlapping FFT
    windows, the prediction pools its directions), so a per-pixel formula would count thousands of pixels
    where there are a few independent regions.  Tiles must span several correlation lengths, or the
    bootstrap reads the spread low: on smooth random fields (tests) tiles of three correlation lengths read
    it about 20% low, of one about 50% low.  The reference is correlated over an FFT window, so the script
    uses tiles of ``BOOTSTRAP_TILE`` windows: on session 28's maps at 256x256 the GGX sphere's per-pixel figure
    reads +/- 0.071, 0.105, 0.139 and 0.138 with tiles of 16, 32, 48 and 64 pixels.  NaN with fewer than two
    tiles."""
    m = np.asarray(mask, bool)
    H, W = m.shape
    ty, tx = np.divmod(np.arange(H * W), W)
    tile = ((ty // block) * (-(-W // block)) + tx // block)[m.reshape(-1)]
    av, bv = np.asarray(a, np.float64)[m], np.asarray(b, np.float64)[m]
    order = np.argsort(tile, kind="stable")
    ids, starts, counts = np.unique(tile[order], return_index=True, return_counts=True)
    if ids.size < 2:
        return float("nan")
    rng = np.random.default_rng(seed)
    rs = []
    for _ in range(int(reps)):
        pick = rng.integers(0, ids.size, ids.size)
        idx = order[np.concatenate([np.arange(starts[k], starts[k] + counts[k]) for k in pick])]
        rs.append(spearman(av[idx], bv[idx]))
    return float(np.nanstd(rs, ddof=1))


def spearman_ceiling(ref: np.ndarray) -> float:
    """The largest Spearman correlation any tie-free predictor can reach against ``ref``: one that orders
    the pixels as ``ref`` does, ties broken in any order.  Each group of c tied values spreads the
    predictor's ranks over c places where ``ref``'s sit at their mean, so the ceiling is the usual tie
    correction, sqrt(1 - sum(c^3 - c) / (n^3 - n)): 1 without ties, below it when a reference reads many
    pixels alike (a Hann window's plateau at its lowest resolvable frequency).  NaN below 3 values."""
    r = np.asarray(ref, np.float64).reshape(-1)
    n = float(r.size)
    if r.size < 3:
        return float("nan")
    _, c = np.unique(r, return_counts=True)
    c = c.astype(np.float64)
    return math.sqrt(max(1.0 - float(np.sum(c ** 3 - c)) / (n ** 3 - n), 0.0))


def luminance(rgb: np.ndarray) -> np.ndarray:
    return np.asarray(rgb, np.float64) @ np.asarray(LUMINANCE)


def relative_gradient(lum: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """|grad L| / L of the converged image (central differences, 0 where no geometry): a per-pixel
    statistic of the true image, the yardstick for what any per-pixel predictor can reach against the
    windowed FFT reference."""
    gy, gx = np.gradient(np.where(cov, lum, 0.0))
    return np.where(cov, np.hypot(gx, gy) / (np.abs(lum) + GRADIENT_EPS), 0.0)


def interior(cov: np.ndarray, margin: float) -> np.ndarray:
    """The covered pixels farther than ``margin`` pixels from any uncovered one (or from the image's border): with
    margin = half an FFT window, the pixels whose reference window lies on the object, away from its silhouette.
    There P_x's 1 / cos theta_x, which raises b_p in a ring a few pixels wide, plays no part, so a rank there says
    how well the prediction follows the shading itself."""
    from scipy.ndimage import distance_transform_edt

    return distance_transform_edt(np.pad(cov, 1))[1:-1, 1:-1] > margin


def compare_variance(pred: np.ndarray, ref: np.ndarray, mask: np.ndarray) -> dict:
    """Rank correlation, conservative fraction (pred >= ref) and median pred/ref over ``mask``."""
    p, r = pred[mask].astype(np.float64), ref[mask].astype(np.float64)
    both = (r > 0) & (p > 0)
    return {"spearman": spearman(p, r), "conservative_fraction": float(np.mean(p >= r)) if p.size else float("nan"),
            "median_ratio": float(np.median(p[both] / r[both])) if both.any() else float("nan"),
            "pixels": int(p.size)}


# ----------------------------------------------------------------------------------------- figure
def _log_range(*maps_masks) -> tuple[float, float]:
    vals = np.concatenate([m[k & np.isfinite(m) & (m > 0)] for m, k in maps_masks])
    if vals.size == 0:
        return 1e-3, 1.0
    lo, hi = np.percentile(vals, COLOUR_PERCENTILES)
    return float(lo), float(max(hi, lo * 1.0001))


def _tonemap(rgb: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The figure's picture of the image: x / (1 + x) of the radiance over 4 times its median luminance (Reinhard's
    curve), sRGB-encoded (IEC 61966-2-1, as the PNG previews; a 2.2 power was up to 0.034 of the range too bright
    near black), black off ``mask``."""
    from warpbw.io.exr import linear_to_srgb

    lum = luminance(rgb)
    key = float(np.median(lum[mask])) if mask.any() else 1.0
    x = rgb / (4.0 * max(key, 1e-8))
    return np.clip(linear_to_srgb(x / (1.0 + x)), 0.0, 1.0) * mask[..., None]


def write_figure(path: Path, title: str, r: dict) -> None:
    from matplotlib.figure import Figure
    from matplotlib.colors import LogNorm
    from matplotlib.ticker import NullFormatter

    cov, bw_valid = r["coverage"], r["bw_valid"]
    fig = Figure(figsize=(17, 8.2))   # not pyplot's: nothing to close, the caller's backend kept
    ax = fig.subplots(2, 4)
    vr = _log_range((r["sigma2"], cov), (r["var_uniform"], cov))
    br = _log_range((r["b_p"], bw_valid), (r["bw_ref"], bw_valid))
    panels = [
        (ax[0, 0], r["sigma2"], cov, vr, "(a) predicted variance sigma2 (Eq. 9)", "magma"),
        (ax[0, 1], r["var_uniform"], cov, vr, "(b) brute-force variance, uniform sampling", "magma"),
        (ax[0, 2], r["b_p"], cov, br, "(c) predicted bandwidth b_p (cycles/px)", "viridis"),
        (ax[0, 3], r["bw_ref"], bw_valid, br, f"(d) {r['window']}x{r['window']} windowed FFT bandwidth", "viridis"),
        (ax[1, 1], r["var_bis"], cov, vr, "variance, BRDF importance sampling (info)", "magma"),
    ]
    for a, mp, k, (lo, hi), name, cmap in panels:
        im = a.imshow(np.where(k & (mp > 0), mp, np.nan), norm=LogNorm(lo, hi), cmap=cmap, interpolation="nearest")
        a.set_title(name, fontsize=9)
        a.axis("off")
        fig.colorbar(im, ax=a, fraction=0.046, pad=0.02)
    ax[1, 0].imshow(_tonemap(r["image"], cov), interpolation="nearest")
    ax[1, 0].set_title(f"(e) converged image, {r['ref_spp']} spp MIS", fontsize=9)
    ax[1, 0].axis("off")
    rng = np.random.default_rng(0)
    for a, x, y, k, name, lab in (
            (ax[1, 2], r["var_uniform"], r["sigma2"], cov & (r["var_uniform"] > 0) & (r["sigma2"] > 0),
             f"variance: Spearman {r['stats']['variance_spearman']:.2f}, "
             f"conservative {r['stats']['variance_conservative_fraction']:.0%}", ("brute-force", "predicted")),
            (ax[1, 3], r["bw_ref"], r["b_p"], bw_valid & (r["bw_ref"] > 0) & (r["b_p"] > 0),
             f"bandwidth: Spearman {r['stats']['bandwidth_spearman']:.2f}", ("windowed FFT", "predicted"))):
        xs, ys = x[k], y[k]
        if xs.size > SCATTER_POINTS:
            sel = rng.choice(xs.size, SCATTER_POINTS, replace=False)
            xs, ys = xs[sel], ys[sel]
        a.scatter(xs, ys, s=2, alpha=0.3, lw=0)
        if xs.size:
            lo = min(xs.min(), ys.min())
            hi = max(xs.max(), ys.max())
            a.plot([lo, hi], [lo, hi], "k--", lw=0.8, label="y = x")
            a.legend(fontsize=8, loc="upper left")
            a.set_xscale("log")
            a.set_yscale("log")
            a.xaxis.set_minor_formatter(NullFormatter())   # narrow ranges: minor labels would overlap
            a.yaxis.set_minor_formatter(NullFormatter())
        a.set_xlabel(lab[0])
        a.set_ylabel(lab[1])
        a.set_title(name, fontsize=9)
    fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=90)


# ----------------------------------------------------------------------------------------- driver
def window_noise_shares(wb: dict) -> np.ndarray:
    """The residual noise's share of the AC energy of every FFT window that counts (covered, not flat), from
    :func:`windowed_bandwidth` run with ``noise_var``."""
    counted = (wb["cover"] >= MIN_WINDOW_COVER) & (wb["energy"] > 0)
    return wb["noise_fraction"][counted]


def converged_image(prep, cfg: dict, log=print) -> dict:
    """Step 1: the MIS reference as two independently seeded halves, at ``cfg["ref_spp"]`` samples per pixel, then
    doubled -- two more halves as large as everything rendered so far, averaged in -- while the median FFT window's
    residual noise share (:func:`window_noise_shares`) exceeds ``cfg["ref_noise"]`` and the doubled count stays
    within ``cfg["ref_spp_max"]``.  Returns "image" (float64 RGB, the mean of the halves), "coverage", "noise_var"
    (per-pixel variance of the mean's luminance: a quarter of the halves' squared difference), "luminance" (the
    image's), "spp", "gbuffer", "rounds" ([spp, median noise share] after each) and "windows" (the last
    :func:`windowed_bandwidth`, Hann)."""
    from warpbw.pipeline import render_reference

    half = max(1, cfg["ref_spp"] // 2)
    sums, n_half, rounds = [0.0, 0.0], 0, []
    while True:
        n = half if n_half == 0 else n_half      # the first pair, then pairs that double the total
        for h in (0, 1):                         # round k = len(rounds) takes seeds seed + 2k and seed + 2k + 1
            r = render_reference(prep, spp=n, seed=cfg["seed"] + 2 * len(rounds) + h, mis=True,
                                 device=cfg["device"])
            sums[h] = sums[h] + r.image.astype(np.float64) * n
        n_half += n
        a, b = sums[0] / n_half, sums[1] / n_half
        image, cov = 0.5 * (a + b), r.coverage
        lum = luminance(image)
        noise_var = (0.5 * (luminance(a) - luminance(b))) ** 2   # unbiased for the mean's variance
        wb = windowed_bandwidth(lum, cov, window=cfg["window"], stride=cfg["stride"],
                                noise_var=noise_var, max_noise=cfg["max_noise"])
        nf = window_noise_shares(wb)
        share = float(np.median(nf)) if nf.size else float("nan")
        rounds.append([2 * n_half, share])
        over = share > cfg["ref_noise"]
        more = over and 4 * n_half <= cfg["ref_spp_max"]
        verdict = ("doubling" if more else "--ref-spp-max reached") if over else ""
        log(f"    {2 * n_half} spp: residual noise {share:.1%} of the median window's AC energy"
            + (f" (target {cfg['ref_noise']:.1%}): {verdict}" if over else ""))
        if not more:
            return {"image": image, "coverage": cov, "noise_var": noise_var, "luminance": lum, "spp": 2 * n_half,
                    "gbuffer": r.gbuffer, "rounds": rounds, "windows": wb}


def validate_scene(name: str, cfg: dict, log=print) -> dict:
    """Run the whole comparison for one scene; returns the maps and the figures ("stats")."""
    from warpbw.bandwidth import bandwidth_pass
    from warpbw.pipeline import prepare_bandwidth, prepare_scene
    from warpbw.scene import parse_scene

    times = {}
    t0 = time.perf_counter()
    data = Path(cfg["data"]).resolve()   # scene_toml writes the paths with it: a relative one was joined twice
    scene = parse_scene(scene_toml(name, cfg["size"], data), data, source=name)
    prep = prepare_scene(scene, device=cfg["device"], progress=False)
    tables = prepare_bandwidth(prep, env_signal=cfg["env_signal"])
    times["prepare"] = time.perf_counter() - t0
    log(f"[{name}] assets ready in {times['prepare']:.1f} s ({', '.join(prep.materials.names)}, {prep.env.name})")

    t0 = time.perf_counter()
    conv = converged_image(prep, cfg, log)
    image, cov, noise_var, gb = conv["image"], conv["coverage"], conv["noise_var"], conv["gbuffer"]
    times["reference_image"] = time.perf_counter() - t0
    log(f"[{name}] converged image: {conv['spp']} spp MIS in {times['reference_image']:.1f} s, "
        f"{int(cov.sum())} covered pixels")

    t0 = time.perf_counter()
    buf = bandwidth_pass(gb, prep.camera, prep.materials, prep.env.data, tables, n_b=cfg["n_b"], seed=cfg["seed"],
                         device=cfg["device"])
    H, W = prep.height, prep.width
    b_p = buf.b_p.numpy().reshape(H, W).astype(np.float64)
    sigma2 = buf.sigma2.numpy().reshape(H, W).astype(np.float64)
    times["bandwidth_pass"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    diag = bandwidth_pass(gb, prep.camera, prep.materials, prep.env.data, tables, n_b=cfg["n_b_diag"],
                          seed=cfg["seed"], device=cfg["device"])
    b_p_diag = diag.b_p.numpy().reshape(H, W).astype(np.float64)
    sigma2_diag = diag.sigma2.numpy().reshape(H, W).astype(np.float64)
    times["bandwidth_pass_diagnostic"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    _, var_u = estimator_variance(gb, prep.materials, prep.env.data, cfg["uniform_samples"], False, cfg["seed"],
                                  cfg["device"])
    times["uniform_variance"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    _, var_b = estimator_variance(gb, prep.materials, prep.env.data, cfg["bis_samples"], True, cfg["seed"],
                                  cfg["device"])
    times["bis_variance"] = time.perf_counter() - t0
    log(f"[{name}] brute-force variance: {cfg['uniform_samples']} uniform samples/px in "
        f"{times['uniform_variance']:.1f} s, {cfg['bis_samples']} BRDF samples/px in {times['bis_variance']:.1f} s")

    t0 = time.perf_counter()
    lum = conv["luminance"]
    wb = conv["windows"]    # the Hann reference of the converged image
    bw_ref, bw_valid = wb["map"], wb["valid"]
    b_p_win = windowed_mean(b_p, cov, cfg["window"], cfg["stride"], wb["grid_valid"])
    # the same windows' mirrored (DCT) spectrum: resolves twice as low a frequency (information, not the check)
    we = windowed_bandwidth(lum, cov, window=cfg["window"], stride=cfg["stride"],
                            noise_var=noise_var, max_noise=cfg["max_noise"], spectrum="even")
    bw_even, both = we["map"], we["valid"] & bw_valid
    grad = relative_gradient(lum, cov)
    grad_win = windowed_mean(grad, cov, cfg["window"], cfg["stride"], wb["grid_valid"])
    times["windowed_fft"] = time.perf_counter() - t0

    vmask = cov & np.isfinite(sigma2) & np.isfinite(var_u)
    tile = BOOTSTRAP_TILE * cfg["window"]   # the block bootstrap's tile side, pixels
    vu = compare_variance(sigma2, var_u, vmask)
    vb = compare_variance(sigma2, var_b, vmask & np.isfinite(var_b))
    vd = compare_variance(sigma2_diag, var_u, vmask & np.isfinite(sigma2_diag))
    bp, br = b_p[bw_valid], bw_ref[bw_valid]
    pos = (bp > 0) & (br > 0)
    inner = bw_valid & interior(cov, cfg["window"] / 2)
    nf = window_noise_shares(wb)
    stats = {
        "material": scene.materials["m"].npf_name or scene.materials["m"].type,
        "environment": SCENES[name]["probe"],
        "resolution": [W, H],
        "covered_pixels": int(cov.sum()),
        "bandwidth_spearman": spearman(bp, br),
        "bandwidth_spearman_windowed": spearman(b_p_win[bw_valid], br),
        # block-bootstrap standard errors over tiles of BOOTSTRAP_TILE FFT windows (block_bootstrap_se)
        "bandwidth_spearman_se": block_bootstrap_se(b_p, bw_ref, bw_valid, tile),
        "bandwidth_spearman_windowed_se": block_bootstrap_se(b_p_win, bw_ref, bw_valid, tile),
        # the most any predictor can reach against this reference, given its ties (spearman_ceiling)
        "bandwidth_spearman_ceiling": spearman_ceiling(br),
        "bandwidth_reference_largest_tie": (float(np.unique(br, return_counts=True)[1].max()) / br.size
                                            if br.size else float("nan")),
        # away from the silhouette (interior): the prediction, and what it and the reference share with the
        # converged image's luminance there (for information, not the check)
        "bandwidth_spearman_interior": spearman(b_p[inner], bw_ref[inner]),
        "bandwidth_interior_pixels": int(inner.sum()),
        "bandwidth_luminance_spearman_interior": spearman(b_p[inner], lum[inner]),
        "reference_luminance_spearman_interior": spearman(bw_ref[inner], lum[inner]),
        # the same two correlations for a statistic of the converged image itself (relative_gradient)
        "oracle_gradient_spearman": spearman(grad[bw_valid], br),
        "oracle_gradient_spearman_windowed": spearman(grad_win[bw_valid], br),
        # against the mirrored-window (DCT) reference, over the pixels both references keep
        "bandwidth_spearman_even": spearman(b_p[both], bw_even[both]),
        "bandwidth_spearman_even_windowed": spearman(b_p_win[both], bw_even[both]),
        "bandwidth_even_reference_median": float(np.median(bw_even[both])) if both.any() else float("nan"),
        "bandwidth_pixels": int(bw_valid.sum()),
        "bandwidth_median_ratio": float(np.median(bp[pos] / br[pos])) if pos.any() else float("nan"),
        "bandwidth_predicted_median": float(np.median(bp)) if bp.size else float("nan"),
        "bandwidth_reference_median": float(np.median(br)) if br.size else float("nan"),
        "noise_fraction_median": float(np.median(nf)) if nf.size else float("nan"),
        "noise_fraction_p90": float(np.percentile(nf, 90)) if nf.size else float("nan"),
        # the share the reference left out for noise, at the --max-noise it used (not MAX_NOISE_FRACTION's default)
        "noisy_windows_left_out": float(np.mean(nf > cfg["max_noise"])) if nf.size else float("nan"),
        "variance_spearman": vu["spearman"],
        "variance_spearman_se": block_bootstrap_se(sigma2, var_u, vmask, tile),
        "variance_conservative_fraction": vu["conservative_fraction"],
        "variance_median_ratio": vu["median_ratio"],
        "variance_pixels": vu["pixels"],
        "bis_variance_spearman": vb["spearman"],
        "bis_conservative_fraction": vb["conservative_fraction"],
        "bis_median_ratio": vb["median_ratio"],
        # the same pass with n_b = N_B_DIAGNOSTIC directions (diagnostic: the bound's shape without the
        # sampling error of n_b directions)
        "diagnostic_n_b": cfg["n_b_diag"],
        "diagnostic_bandwidth_spearman": spearman(b_p_diag[bw_valid], br),
        "diagnostic_bandwidth_median_ratio": float(np.median(b_p_diag[bw_valid][pos] / br[pos])) if pos.any()
        else float("nan"),
        "diagnostic_variance_spearman": vd["spearman"],
        "diagnostic_variance_conservative_fraction": vd["conservative_fraction"],
        "diagnostic_variance_median_ratio": vd["median_ratio"],
        "reference_spp": conv["spp"],
        "reference_rounds": conv["rounds"],    # [spp, median window noise share] after each doubling
        "uniform_samples": int(round(math.sqrt(cfg["uniform_samples"]))) ** 2,
        "bis_samples": int(cfg["bis_samples"]),   # independent samples: not rounded to a square
        "n_b": cfg["n_b"],
        "env_signal": cfg["env_signal"],
        "time_s": {k: round(v, 3) for k, v in times.items()},
    }
    log(f"[{name}] bandwidth Spearman {stats['bandwidth_spearman']:.3f} over {stats['bandwidth_pixels']} px; "
        f"variance Spearman {stats['variance_spearman']:.3f}, conservative on "
        f"{stats['variance_conservative_fraction']:.1%}")
    return {"stats": stats, "image": image, "coverage": cov, "b_p": b_p, "b_p_windowed": b_p_win,
            "sigma2": sigma2, "b_p_diagnostic": b_p_diag, "sigma2_diagnostic": sigma2_diag, "var_uniform": var_u,
            "var_bis": var_b, "bw_ref": bw_ref, "bw_valid": bw_valid, "bw_ref_even": bw_even,
            "bw_valid_even": we["valid"], "noise_var": noise_var, "window": cfg["window"], "ref_spp": conv["spp"]}


def check_targets(results: dict) -> tuple[list, list]:
    """Issue 3's checks on every scene's figures: those missed, and those (met or missed) whose figure lies within
    one block-bootstrap standard error of its target, which the check cannot tell from it.  Each is named
    "scene: key (figure +/- standard error)"."""
    missed, close = [], []
    for name, st in results.items():
        for key, target in (("bandwidth_spearman", TARGET_SPEARMAN), ("variance_spearman", TARGET_SPEARMAN),
                            ("variance_conservative_fraction", TARGET_CONSERVATIVE)):
            se = st.get(key + "_se")
            has_se = se is not None and math.isfinite(se)
            label = f"{name}: {key} ({st[key]:.3f}" + (f" +/- {se:.3f})" if has_se else ")")
            if not st[key] > target:
                missed.append(label)
            if has_se and abs(st[key] - target) < se:
                close.append(label)
    return missed, close


def _finite(x):
    """JSON-safe: NaN / inf become None."""
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def print_table(results: dict) -> None:
    rows = [("scene", "{:<22}", None),
            ("bw rho", "{:>7.3f}", "bandwidth_spearman"), ("+/-", "{:>5.3f}", "bandwidth_spearman_se"),
            ("bw rho(win)", "{:>11.3f}", "bandwidth_spearman_windowed"),
            ("+/-", "{:>5.3f}", "bandwidth_spearman_windowed_se"),
            ("ceiling", "{:>7.3f}", "bandwidth_spearman_ceiling"),
            ("interior", "{:>8.3f}", "bandwidth_spearman_interior"),
            ("DCT rho", "{:>7.3f}", "bandwidth_spearman_even"),
            ("DCT rho(win)", "{:>12.3f}", "bandwidth_spearman_even_windowed"),
            ("bp/ref", "{:>7.2f}", "bandwidth_median_ratio"), ("noise", "{:>6.1%}", "noise_fraction_median"),
            ("var rho", "{:>7.3f}", "variance_spearman"), ("+/-", "{:>5.3f}", "variance_spearman_se"),
            ("conserv.", "{:>8.1%}", "variance_conservative_fraction"),
            ("pred/bf", "{:>8.3g}", "variance_median_ratio"),
            ("BIS rho", "{:>7.3f}", "bis_variance_spearman"), ("BIS cons.", "{:>9.1%}", "bis_conservative_fraction"),
            ("| diag: bw rho", "{:>14.3f}", "diagnostic_bandwidth_spearman"),
            ("var rho", "{:>7.3f}", "diagnostic_variance_spearman"),
            ("conserv.", "{:>8.1%}", "diagnostic_variance_conservative_fraction")]
    widths = [len(fmt.format(0.0)) if key else 22 for _, fmt, key in rows]
    head = " ".join(f"{h:>{w}}" if key else f"{h:<{w}}" for (h, _, key), w in zip(rows, widths))
    print(head)
    print("-" * len(head))
    for name, st in results.items():
        cells = []
        for (_, fmt, key), w in zip(rows, widths):
            v = name if key is None else st[key]
            cells.append(fmt.format(v) if (key is None or math.isfinite(v)) else f"{'n/a':>{w}}")
        print(" ".join(cells))
    n_b = next(iter(results.values()))["diagnostic_n_b"] if results else N_B_DIAGNOSTIC
    print(f"(diag: the same bandwidth pass with n_b = {n_b} directions; DCT: against the same windows' mirrored "
          f"spectrum, for information; ceiling: the most any predictor can reach against the reference's ties; "
          f"interior: bw rho over the pixels more than half a window from the silhouette)")


def outputs(out: Path, scenes) -> list:
    files = [out / "validate_bandwidth.json"]
    for s in scenes:
        files += [out / f"validate_{s}.png", out / f"validate_{s}_maps.npz"]
    return files


def parse_args(argv=None):
    ap = OneLineParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True, help="output directory (created)")
    ap.add_argument("--size", type=int, default=None, help=f"image side in pixels (default {DEFAULT_SIZE}; "
                                                            f"{QUICK['size']} with --quick)")
    ap.add_argument("--scenes", nargs="+", default=list(DEFAULT_SCENES), choices=list(SCENES), metavar="NAME",
                    help=f"scenes to validate (default: {', '.join(DEFAULT_SCENES)}; also "
                    f"{', '.join(n for n in SCENES if n not in DEFAULT_SCENES)})")
    ap.add_argument("--quick", action="store_true", help="tiny sizes and sample counts (smoke test)")
    ap.add_argument("--ref-spp", type=int, default=None,
                    help=f"converged image spp to start with, MIS (default {REF_SPP}; {QUICK['ref_spp']} with --quick)")
    ap.add_argument("--ref-noise", type=float, default=REF_NOISE_TARGET,
                    help="double the converged image's spp while its residual noise is more than this share of the "
                         f"median FFT window's AC energy (default {REF_NOISE_TARGET})")
    ap.add_argument("--ref-spp-max", type=int, default=None,
                    help=f"at most this many spp for the converged image (default {REF_SPP_MAX}; "
                         f"{QUICK['ref_spp_max']} with --quick; --ref-spp or below: no doubling)")
    ap.add_argument("--uniform-samples", type=int, default=None,
                    help=f"stratified uniform directions per pixel, rounded to a square (default {UNIFORM_SAMPLES}; "
                         f"{QUICK['uniform_samples']} with --quick)")
    ap.add_argument("--bis-samples", type=int, default=None,
                    help=f"BRDF-importance samples per pixel (default {BIS_SAMPLES}; {QUICK['bis_samples']} with "
                         "--quick)")
    ap.add_argument("--window", type=int, default=None,
                    help=f"FFT window side (default {FFT_WINDOW}; {QUICK['window']} with --quick)")
    ap.add_argument("--stride", type=int, default=FFT_STRIDE,
                    help=f"pixels between FFT window centres (default {FFT_STRIDE})")
    ap.add_argument("--max-noise", type=float, default=None,
                    help=f"leave out FFT windows whose AC energy is more than this share noise "
                         f"(default {MAX_NOISE_FRACTION}; {QUICK['max_noise']} with --quick)")
    ap.add_argument("--nb", type=int, default=16, help="n_b directions of the bandwidth pass (default 16, as 002)")
    ap.add_argument("--env-signal", choices=ENV_SIGNALS, default=ENV_SIGNAL_DEFAULT,
                    help="what the analysis of the probe's angular bandwidth reads (warpbw render --env-signal; "
                    f"default {ENV_SIGNAL_DEFAULT})")
    ap.add_argument("--nb-diagnostic", type=int, default=None,
                    help=f"n_b of a second, diagnostic bandwidth pass (default {N_B_DIAGNOSTIC}; 64 with --quick)")
    ap.add_argument("--seed", type=parse_seed, default=SEED, help=f"seed of the converged image's halves, the "
                    "bandwidth passes and the brute-force variances, 0 to 2^32-1 less what the halves add (round k "
                    f"of the converged image takes seed + 2k and seed + 2k + 1) (default {SEED})")
    ap.add_argument("--data", default=str(DATA), help="the shared data directory, envmaps/, meshes/, brdf/ (default "
                    "%(default)s: ../shared/data beside the repository, or $WARPBW_SHARED_DATA)")
    ap.add_argument("--device", default="cpu", help="Warp device (default cpu; cuda where there is one)")
    ap.add_argument("--force", action="store_true", help="overwrite existing outputs")
    ap.add_argument("--strict", action="store_true", help="exit 1 when an acceptance target is missed")
    args = ap.parse_args(argv)
    q = args.quick
    pick = (lambda v, full, quick: v if v is not None else (quick if q else full))
    args.size = pick(args.size, DEFAULT_SIZE, QUICK["size"])
    args.ref_spp = pick(args.ref_spp, REF_SPP, QUICK["ref_spp"])
    args.ref_spp_max = pick(args.ref_spp_max, REF_SPP_MAX, QUICK["ref_spp_max"])
    args.uniform_samples = pick(args.uniform_samples, UNIFORM_SAMPLES, QUICK["uniform_samples"])
    args.bis_samples = pick(args.bis_samples, BIS_SAMPLES, QUICK["bis_samples"])
    args.window = pick(args.window, FFT_WINDOW, QUICK["window"])
    args.nb_diagnostic = pick(args.nb_diagnostic, N_B_DIAGNOSTIC, QUICK["nb_diagnostic"])
    args.max_noise = pick(args.max_noise, MAX_NOISE_FRACTION, QUICK["max_noise"])
    # shares of a window's energy: above 1 --max-noise leaves no window out and --ref-noise never doubles the spp
    if not 0 < args.max_noise <= 1:
        ap.error(f"--max-noise {args.max_noise:g}: expected a positive share, at most 1")
    if not 0 < args.ref_noise <= 1:
        ap.error(f"--ref-noise {args.ref_noise:g}: expected a positive share, at most 1")
    for k in ("size", "ref_spp", "ref_spp_max", "uniform_samples", "bis_samples", "window", "stride", "nb",
              "nb_diagnostic"):
        if getattr(args, k) < 1:
            ap.error(f"--{k.replace('_', '-')}: expected a positive integer")
    if args.window < 4 or args.window % 2:
        ap.error("--window: expected an even number >= 4")
    for opt, n_b in (("--nb", args.nb), ("--nb-diagnostic", args.nb_diagnostic)):   # not as the pass's "n_b", later
        if n_b > N_B_MAX:
            ap.error(f"{opt} {n_b}: expected at most {N_B_MAX} directions (002 Fig. 13 sweeps n_b from 16 to 1024)")
    if args.size > MAX_RESOLUTION:   # not after loading the first scene's probe, as its [camera].resolution
        ap.error(f"--size {args.size}: expected at most {MAX_RESOLUTION} pixels (a scene's largest side)")
    if args.size < args.window:   # the bandwidth pass wants 2 pixels a side, the comparison whole windows
        ap.error(f"--size {args.size}: expected at least the FFT window's side, {args.window} pixels (--window)")
    if args.stride > args.size:   # one window centre, and a map of the others interpolated from none
        ap.error(f"--stride {args.stride}: expected at most --size, {args.size} pixels")
    # round k of the converged image renders its halves with seeds seed + 2k and seed + 2k + 1
    last_round = max(0, (args.ref_spp_max // (2 * max(1, args.ref_spp // 2))).bit_length() - 1)
    if args.seed + 2 * last_round + 1 > SEED_MAX:
        ap.error(f"--seed {args.seed}: expected at most {SEED_MAX - 2 * last_round - 1} (the converged image's "
                 f"halves use seeds up to seed + {2 * last_round + 1}, a uint32)")
    check_output_dir(args.out, "--out")
    if not Path(args.data).is_dir():
        ap.error(f"--data {args.data}: no such directory (expected the shared data: envmaps/, meshes/, brdf/)")
    files = [p for p in outputs(Path(args.out), args.scenes) if p.exists()]
    if files and not args.force:
        ap.error(f"{files[0]} exists (and {len(files) - 1} more outputs); pass --force to overwrite")
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    init_warp(args.device)     # --device checked; Warp's no-CUDA-driver line kept off stderr
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cfg = {"size": args.size, "ref_spp": args.ref_spp, "ref_noise": args.ref_noise, "ref_spp_max": args.ref_spp_max,
           "uniform_samples": args.uniform_samples,
           "bis_samples": args.bis_samples, "window": args.window, "stride": args.stride, "n_b": args.nb,
           "env_signal": args.env_signal,
           "n_b_diag": args.nb_diagnostic, "max_noise": args.max_noise,
           "seed": args.seed, "device": args.device, "data": Path(args.data)}
    print(f"validating {len(args.scenes)} scene(s) at {args.size}x{args.size}: reference {args.ref_spp} spp MIS "
          f"(doubled while noise > {args.ref_noise:.1%}, up to {args.ref_spp_max}), "
          f"{args.uniform_samples} uniform / {args.bis_samples} BRDF samples per pixel, "
          f"{args.window}x{args.window} FFT windows every {args.stride} px" + (" (quick)" if args.quick else ""),
          flush=True)
    results, maps = {}, {}
    for name in args.scenes:
        r = validate_scene(name, cfg, log=lambda s: print(s, flush=True))
        results[name] = r["stats"]
        maps[name] = r   # its figure and maps are written with the record at the end
    misses, close = check_targets(results)
    record = {
        "paper": "002 Fig. 12 (validation of predicted variance and bandwidth)",
        "settings": {k: (str(v) if isinstance(v, Path) else v) for k, v in cfg.items()} | {
            "quick": args.quick, "energy_fraction": ENERGY_FRACTION, "min_window_cover": MIN_WINDOW_COVER,
            "reference_mis": True, "bis_mis": False},
        "targets": {"spearman": TARGET_SPEARMAN, "conservative_fraction": TARGET_CONSERVATIVE},
        "missed": misses,
        "within_one_standard_error": close,
        "scenes": results,
    }
    # all, or none: an error leaves the old set
    with staged_outputs(outputs(out, args.scenes), force=args.force) as at:
        for name, r in maps.items():
            write_figure(at[out / f"validate_{name}.png"],
                         f"{name}: {r['stats']['material']} under {r['stats']['environment']}, "
                         f"{args.size}x{args.size}", r)
            np.savez_compressed(at[out / f"validate_{name}_maps.npz"], **{k: r[k] for k in (
                "image", "coverage", "b_p", "b_p_windowed", "sigma2", "b_p_diagnostic", "sigma2_diagnostic",
                "var_uniform", "var_bis", "bw_ref", "bw_valid", "bw_ref_even", "bw_valid_even", "noise_var")})
        at[out / "validate_bandwidth.json"].write_text(json.dumps(_finite(record), indent=2) + "\n")
    print()
    print_table(results)
    print(f"\ntargets: Spearman > {TARGET_SPEARMAN}, conservative > {TARGET_CONSERVATIVE:.0%}: "
          + ("all met" if not misses else "missed " + "; ".join(misses)))
    if close:
        print("within one standard error of the target (the check cannot tell them from it): " + "; ".join(close))
    print(f"wrote {out}/validate_bandwidth.json and one figure + maps per scene")
    return 1 if (args.strict and misses) else 0


if __name__ == "__main__":
    sys.exit(run_command("validate_bandwidth.py", lambda _: main(), None))
