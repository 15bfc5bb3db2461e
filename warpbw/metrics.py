"""Image error metrics over the pixels covered by geometry (../shared/DESIGN.md measurement protocol).

Public: ``psnr(test, ref, mask)``, ``relmse(test, ref, mask)``, ``mse(test, ref, mask)``,
``compare_images(test, ref, mask) -> dict``, ``coverage_from_alpha(pixels, channels)``,
``relmse_map(test, ref, mask) -> (H, W)``, ``worst_share(err_map, mask, fraction)``, ``WORST_FRACTION``.

Both images are linear radiance (H, W, 3), or one channel (H, W) / (H, W, 1); channels first and a fourth
(alpha) channel are refused.  ``mask`` (H, W) selects the covered pixels; None means all.
* PSNR = 10 log10(peak^2 / MSE) with ``peak`` the reference's largest value over the mask.
* relMSE = mean over masked pixels and channels of (test - ref)^2 / (ref^2 + RELMSE_EPS)
  (Rousselle et al. 2011), insensitive to the overall exposure of bright pixels.
* The relMSE map is that term per pixel, averaged over the channels (0 outside the mask), so relMSE is its mean
  over the mask; ``worst_share`` is the share of relMSE held by the worst ``fraction`` of the masked pixels:
  ``fraction`` when every pixel has the same error, near 1 when a few hold it (fireflies, or a smeared edge).
"""
from __future__ import annotations

import math
import numbers

import numpy as np

from warpbw.errors import WarpbwError

# Rousselle, Knaus, Zwicker 2011, "Adaptive sampling and reconstruction using greedy error minimization"
RELMSE_EPS = 1.0e-2
WORST_FRACTION = 0.01   # the worst 1% of the covered pixels (ours: how concentrated the error is)
CHANNEL_COUNTS = (1, 3, 4)   # grey, RGB, RGBA: what a last axis of channels holds


def _image(x, what: str) -> np.ndarray:
    """An (H, W) or (H, W, C) image as float64, else a WarpbwError (numpy's own for strings, an IndexError for 0-d)."""
    try:
        a = np.asarray(x, np.float64)
    except (TypeError, ValueError):
        raise WarpbwError(f"{what} image: expected an array of numbers, got {type(x).__name__}") from None
    if a.ndim not in (2, 3):
        raise WarpbwError(f"{what} image: expected (H, W) or (H, W, C) values, got shape {a.shape}")
    if a.ndim == 3 and a.shape[0] in CHANNEL_COUNTS and a.shape[-1] not in CHANNEL_COUNTS:
        # (3, H, W) was read as an image 3 rows high
        raise WarpbwError(f"{what} image: expected channels last, (H, W, C), got shape {a.shape} (channels first? "
                          "np.moveaxis(image, 0, -1))")
    if a.ndim == 3 and a.shape[-1] == 4:   # an EXR's R, G, B, A: the coverage or opacity counted as a colour
        raise WarpbwError(f"{what} image: expected radiance (H, W, 3) or one channel, got 4 channels (drop the "
                          "alpha channel: image[..., :3])")
    return a


def _checked(test, ref, mask):
    """(test, reference, mask) as float64 images and an (H, W) bool mask, checked against each other."""
    a = _image(test, "test")
    b = _image(ref, "reference")
    if a.shape != b.shape:
        raise WarpbwError(f"images differ in size: {a.shape} and {b.shape}")
    if mask is None:
        mask = np.ones(a.shape[:2], bool)
    mask = np.asarray(mask, bool)
    if mask.shape != a.shape[:2]:
        raise WarpbwError(f"mask of shape {mask.shape} does not match images of shape {a.shape[:2]}")
    if not mask.any():
        raise WarpbwError("no pixel is covered by geometry: the error is undefined")
    for what, x in (("test", a), ("reference", b)):   # psnr / mse read NaN or inf from them without a word
        bad = int(np.count_nonzero(~np.isfinite(x[mask])))
        if bad:
            raise WarpbwError(f"{what} image: {bad} non-finite values over the covered pixels (expected finite "
                              "radiance)")
    return a, b, mask


def _masked(test, ref, mask):
    """The covered pixels of (test, reference), checked."""
    a, b, m = _checked(test, ref, mask)
    return a[m], b[m]


def _check_eps(eps) -> float:
    if not (isinstance(eps, (int, float, np.floating)) and 0.0 < eps < math.inf):
        raise WarpbwError(f"eps: expected a finite number > 0 (relMSE's regulariser), got {eps!r}")
    return float(eps)


# The figures of checked images (``_masked`` / ``_checked``): each public metric checks its own, and
# compare_images checks once for all of them.

def _mse_of(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.mean((a - b) ** 2))


def _pow2_below(x) -> np.ndarray:
    """2^(e - 1) for x = f 2^e (0.5 <= |f| < 1): a power of two within a factor 2 below |x| (1 for x = 0).  Dividing
    by it is exact, so a metric computed on the scaled values has the same bits, without squares that leave float64
    (values past 1e154 squared to inf, below 1e-162 to 0)."""
    return np.ldexp(1.0, np.frexp(x)[1] - 1)


def _relmse_terms(a: np.ndarray, b: np.ndarray, eps: float) -> np.ndarray:
    """(a - b)^2 / (b^2 + eps) per value, numerator and denominator divided by q^2, q = max(1, _pow2_below(max(|a|,
    |b|))): the same bits below 2, and no inf / inf = NaN where a value's square overflows."""
    q = np.maximum(_pow2_below(np.maximum(np.abs(a), np.abs(b))), 1.0)
    return (a / q - b / q) ** 2 / ((b / q) ** 2 + eps / q / q)


def _relmse_of(a: np.ndarray, b: np.ndarray, eps: float) -> float:
    return float(np.mean(_relmse_terms(a, b, eps)))


def _psnr_of(a: np.ndarray, b: np.ndarray) -> float:
    # PSNR does not depend on the scale: both images divided by a power of two near their largest magnitude first
    # (a reference of 1.3e154 against a black test gave inf / inf = NaN; values of 1e-200 gave an MSE of 0, inf dB)
    s = _pow2_below(max(float(np.max(np.abs(a))), float(np.max(np.abs(b)))))
    a, b = a / s, b / s
    m = _mse_of(a, b)
    peak = float(np.max(b))
    if m == 0.0:
        return math.inf
    if peak <= 0.0:
        return -math.inf
    return 10.0 * math.log10(peak * peak / m)


def _relmse_map_of(a: np.ndarray, b: np.ndarray, m: np.ndarray, masked: bool, eps: float) -> np.ndarray:
    if a.ndim == 2:                               # one channel: the mean over channels is the value itself
        a, b = a[..., None], b[..., None]
    e = np.mean(_relmse_terms(a, b, eps), axis=-1)
    return np.where(m, e, 0.0) if masked else e


def mse(test, ref, mask=None) -> float:
    return _mse_of(*_masked(test, ref, mask))


def relmse(test, ref, mask=None, eps: float = RELMSE_EPS) -> float:
    a, b = _masked(test, ref, mask)
    return _relmse_of(a, b, _check_eps(eps))


def psnr(test, ref, mask=None) -> float:
    return _psnr_of(*_masked(test, ref, mask))


def relmse_map(test, ref, mask=None, eps: float = RELMSE_EPS) -> np.ndarray:
    """(H, W) float64: per pixel the mean over channels of (test - ref)^2 / (ref^2 + eps); 0 outside ``mask``."""
    a, b, m = _checked(test, ref, mask)           # the same checks as the scalar metrics
    return _relmse_map_of(a, b, m, mask is not None, _check_eps(eps))


def worst_share(err_map, mask=None, fraction: float = WORST_FRACTION) -> tuple[float, int]:
    """(share of the summed ``err_map`` over ``mask`` held by its ceil(fraction n) largest pixels, that count);
    the share is 0 when there is no error at all."""
    if not (isinstance(fraction, numbers.Real) and 0.0 < fraction <= 1.0):
        raise WarpbwError(f"fraction: expected a number in (0, 1], got {fraction!r}")
    e = np.asarray(err_map, np.float64)
    if not np.all(np.isfinite(e)) or (e.size and e.min() < 0.0):   # NaN gave a NaN share, a negative one above 1
        raise WarpbwError(f"err_map: expected finite errors >= 0, got values from {e.min():.3g} to {e.max():.3g}")
    if mask is not None and np.shape(mask) != e.shape:   # an IndexError from numpy
        raise WarpbwError(f"mask of shape {np.shape(mask)} does not match err_map of shape {e.shape}")
    v = e[np.asarray(mask, bool)] if mask is not None else e.ravel()
    k = max(1, math.ceil(fraction * v.size))
    total = float(v.sum())
    if total <= 0.0:
        return 0.0, k
    return float(np.partition(v, v.size - k)[v.size - k:].sum() / total), k


def compare_images(test, ref, mask=None) -> dict:
    a, b, m = _checked(test, ref, mask)   # once for every figure (each metric alone converted and checked again)
    masked = mask is not None
    with np.errstate(over="ignore", divide="ignore"):   # said below
        rel = _relmse_map_of(a, b, m, masked, RELMSE_EPS)
    if not np.all(np.isfinite(rel)):   # float64 values past ~1e154 against a dark reference: worst_share named err_map
        raise WarpbwError(f"test image: its relative squared error against the reference passes float64's range "
                          f"(values up to {max(float(np.abs(a).max()), float(np.abs(b).max())):.3g}); expected "
                          "radiance within float32's range, as EXR holds it")
    share, k = worst_share(rel, m if masked else None)
    am, bm = a[m], b[m]
    # counted as the metrics read the mask (a 0/2 mask counted 64 where 32 were compared)
    return {"psnr_db": _psnr_of(am, bm), "relmse": _relmse_of(am, bm, RELMSE_EPS), "mse": _mse_of(am, bm),
            "pixels": int(np.count_nonzero(m)), "worst_pixels": k, "worst_share": share}


def coverage_from_alpha(pixels: np.ndarray, channels) -> np.ndarray | None:
    """The coverage mask stored in an EXR's A channel (written by ``warpbw render``), else None."""
    ch = list(channels)
    if "A" not in ch:
        return None
    px = np.asarray(pixels)
    if px.ndim != 3 or px.shape[-1] != len(ch):   # an IndexError, or another channel read as A
        raise WarpbwError(f"pixels of shape {px.shape} do not hold the {len(ch)} channels {ch} as (H, W, {len(ch)})")
    return px[..., ch.index("A")] > 0.0
