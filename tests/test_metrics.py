"""Image error metrics (warpbw.metrics) against closed forms and explicit per-pixel loops.

Truth used: PSNR of a constant offset, 10 log10(peak^2 / d^2); relMSE and its map written out pixel by pixel;
the worst-share of an error held by one pixel (1) or spread evenly (the fraction); the mask's pixels only."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from warpbw.errors import WarpbwError
from warpbw.metrics import (RELMSE_EPS, WORST_FRACTION, compare_images, coverage_from_alpha, mse, psnr, relmse,
                            relmse_map, worst_share)


def _pair(seed=0, h=6, w=9):
    rng = np.random.default_rng(seed)
    ref = rng.uniform(0.1, 2.0, (h, w, 3))
    mask = rng.random((h, w)) < 0.6
    return ref, mask


def test_psnr_of_a_constant_offset_is_the_closed_form_over_the_mask_only():
    ref, mask = _pair()
    d = 0.05
    test = ref + d
    test[~mask] = 1e6                      # what lies outside the mask is not compared
    peak = ref[mask].max()
    assert psnr(test, ref, mask) == pytest.approx(10 * math.log10(peak ** 2 / d ** 2), rel=1e-12)
    assert mse(test, ref, mask) == pytest.approx(d * d, rel=1e-12)


def test_psnr_is_infinite_for_identical_images_and_minus_infinite_for_a_black_reference():
    ref, mask = _pair(1)
    assert psnr(ref, ref, mask) == math.inf
    assert psnr(ref, np.zeros_like(ref), mask) == -math.inf


def test_relmse_and_its_map_match_a_per_pixel_loop():
    ref, mask = _pair(2)
    test = ref * np.random.default_rng(3).uniform(0.5, 1.5, ref.shape)
    h, w, _ = ref.shape
    want_map = np.zeros((h, w))
    terms = []
    for y in range(h):
        for x in range(w):
            t = [(test[y, x, c] - ref[y, x, c]) ** 2 / (ref[y, x, c] ** 2 + RELMSE_EPS) for c in range(3)]
            if mask[y, x]:
                want_map[y, x] = sum(t) / 3
                terms += t
    assert relmse(test, ref, mask) == pytest.approx(sum(terms) / len(terms), rel=1e-12)
    np.testing.assert_allclose(relmse_map(test, ref, mask), want_map, rtol=1e-12, atol=0)
    # relMSE is the map's mean over the mask (module docstring)
    assert relmse_map(test, ref, mask)[mask].mean() == pytest.approx(relmse(test, ref, mask), rel=1e-12)


@settings(max_examples=30, deadline=None)
@given(k=st.floats(1e-3, 1e3), seed=st.integers(0, 2 ** 16))
def test_relmse_is_scale_free_when_its_regulariser_scales_too(k, seed):
    """(k a - k b)^2 / ((k b)^2 + k^2 eps) = (a - b)^2 / (b^2 + eps): exposure does not change the error."""
    ref, mask = _pair(seed)
    test = ref * np.random.default_rng(seed + 1).uniform(0.8, 1.2, ref.shape)
    assert relmse(k * test, k * ref, mask, eps=k * k * RELMSE_EPS) == pytest.approx(relmse(test, ref, mask),
                                                                                      rel=1e-9)


@settings(max_examples=60, deadline=None)
@given(e=st.integers(-1000, 1020), seed=st.integers(0, 2 ** 16))
def test_psnr_and_relmse_are_the_same_at_every_power_of_two_exposure_float64_holds(e, seed):
    """PSNR does not depend on the exposure, and relMSE does not once its regulariser scales with it: scaled by 2^e,
    exactly, anywhere in float64's range, they give the unscaled figures.  A reference past ~1e154 squared to inf
    (PSNR inf / inf = NaN, relMSE NaN) and values below ~1e-162 to 0 (PSNR inf for unequal images)."""
    ref, mask = _pair(seed)
    test = ref * np.random.default_rng(seed + 1).uniform(0.8, 1.2, ref.shape)
    k = 2.0 ** e
    assert psnr(test * k, ref * k, mask) == pytest.approx(psnr(test, ref, mask), rel=1e-12)
    if abs(e) <= 500:   # k^2 eps stays a normal float64
        assert relmse(test * k, ref * k, mask, eps=RELMSE_EPS * k * k) == pytest.approx(relmse(test, ref, mask),
                                                                                        rel=1e-9)
    big = 2.0 ** 1020   # the eps of 1e-2 does not matter beside a reference this bright: relMSE is mean((a / b - 1)^2)
    want = np.mean((test[mask] / ref[mask] - 1.0) ** 2)
    assert relmse(test * big, ref * big, mask) == pytest.approx(want, rel=1e-9)


def test_worst_share_of_one_bad_pixel_and_of_an_even_error():
    n = 1000
    mask = np.ones((1, n), bool)
    one = np.zeros((1, n))
    one[0, 123] = 5.0
    share, k = worst_share(one, mask)
    assert (share, k) == (1.0, math.ceil(WORST_FRACTION * n))
    even, k = worst_share(np.full((1, n), 0.3), mask)
    assert even == pytest.approx(k / n) and k == 10
    assert worst_share(np.zeros((1, n)), mask)[0] == 0.0


@settings(max_examples=50, deadline=None)
@given(h=st.integers(1, 12), w=st.integers(1, 12), channels=st.sampled_from([None, 1, 3]),
       flip=st.sampled_from(["rows", "columns", "transpose"]), spread=st.floats(0.0, 4.0),
       f1=st.floats(1e-3, 1.0), f2=st.floats(1e-3, 1.0), seed=st.integers(0, 2 ** 16))
def test_figures_ignore_where_the_pixels_lie_and_the_worst_share_is_bounded_and_grows_with_the_fraction(
        h, w, channels, flip, spread, f1, f2, seed):
    """The figures are means and a ranking over the covered pixels, so flipping or transposing both images with
    their mask leaves every figure of compare_images (float64 sums in another order: 1e-12).  The worst ceil(f n)
    of n errors hold at least their count's share of the total (the largest values' mean is at least the mean) and
    at most all of it, a larger fraction holds no less, and the share is that of the largest errors (sorted here)."""
    rng = np.random.default_rng(seed)
    shape = (h, w) if channels is None else (h, w, channels)
    ref = rng.uniform(0.0, 2.0, shape)
    test = ref * np.exp(spread * rng.normal(size=shape))
    mask = rng.random((h, w)) < 0.7
    mask.flat[rng.integers(mask.size)] = True
    move = {"rows": lambda a: a[::-1], "columns": lambda a: a[:, ::-1], "transpose": lambda a: np.swapaxes(a, 0, 1)}
    a, b = compare_images(test, ref, mask), compare_images(move[flip](test), move[flip](ref), move[flip](mask))
    assert a.keys() == b.keys()
    for key in a:
        assert b[key] == pytest.approx(a[key], rel=1e-12, abs=1e-300), key
    err = relmse_map(test, ref, mask)
    v = np.sort(err[mask])[::-1]
    lo, hi = sorted((f1, f2))
    (s_lo, k_lo), (s_hi, k_hi) = worst_share(err, mask, lo), worst_share(err, mask, hi)
    assert k_lo == math.ceil(lo * v.size) and k_hi == math.ceil(hi * v.size)
    if v.sum() > 0.0:
        assert s_lo == pytest.approx(v[:k_lo].sum() / v.sum(), rel=1e-12)
        assert k_lo / v.size * (1 - 1e-12) <= s_lo <= s_hi * (1 + 1e-12) and s_hi <= 1.0 + 1e-12


def test_compare_images_ranks_the_worst_pixels_among_the_covered_ones_only():
    """A 40 x 25 image of which 300 pixels are covered: the worst 1% are 3 covered pixels (of 1000 pixels, 10), and
    an error at one covered pixel holds all of it; 10 pixels off by far more outside the mask change nothing."""
    ref = np.full((25, 40, 3), 0.5)
    mask = np.zeros((25, 40), bool)
    mask[5:20, 10:30] = True                                # 15 x 20 = 300 covered pixels
    test = ref.copy()
    test[~mask] += 100.0                                    # uncovered: in no figure
    test[7, 12] += 0.2                                      # the one covered error
    r = compare_images(test, ref, mask)
    assert r["pixels"] == 300 and r["worst_pixels"] == 3 and r["worst_share"] == 1.0
    assert r["relmse"] == pytest.approx(0.2 ** 2 / (0.25 + RELMSE_EPS) / 300, rel=1e-9)
    assert (r["worst_share"], r["worst_pixels"]) == worst_share(relmse_map(test, ref, mask), mask)


def test_worst_share_refuses_maps_it_cannot_rank():
    """A NaN map gave a NaN share, a negative one a share above 1, a mask of another shape raised numpy's
    IndexError, a fraction "0.5" Python's TypeError."""
    e = np.ones((4, 4))
    for bad in (np.full((4, 4), np.nan), -e):
        with pytest.raises(WarpbwError, match="err_map: expected finite errors >= 0"):
            worst_share(bad)
    with pytest.raises(WarpbwError, match="mask of shape"):
        worst_share(e, np.ones((3, 4), bool))
    with pytest.raises(WarpbwError, match="fraction"):
        worst_share(e, fraction="0.5")
    assert worst_share(e, fraction=0.25) == (0.25, 4)


def test_compare_images_refuses_an_error_past_float64_naming_the_test_image(recwarn):
    """A float64 test image of 1e200 against a black reference: its relative squared error, 1e400 / eps, passes
    float64 (the metrics' own answer is inf).  compare_images said "err_map: expected finite errors", a parameter
    the caller never passed, after numpy's divide warning; now one line naming the test image.  The same values
    within float32's range, as an EXR holds them, compare."""
    ref = np.zeros((4, 4, 3))
    with pytest.raises(WarpbwError, match=r"^test image: its relative squared error against the reference passes "
                                          r"float64's range \(values up to 1e\+200\)"):
        compare_images(np.full((4, 4, 3), 1e200), ref)
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]
    r = compare_images(np.full((4, 4, 3), 3e38), ref)
    assert r["relmse"] == pytest.approx(9e76 / RELMSE_EPS) and r["worst_share"] == pytest.approx(r["worst_pixels"] / 16)


def test_compare_images_gathers_the_same_figures():
    ref, mask = _pair(4)
    test = ref + 0.01 * np.random.default_rng(5).normal(size=ref.shape)
    r = compare_images(test, ref, mask)
    assert r["psnr_db"] == psnr(test, ref, mask) and r["relmse"] == relmse(test, ref, mask)
    assert r["mse"] == mse(test, ref, mask) and r["pixels"] == int(mask.sum())
    assert (r["worst_share"], r["worst_pixels"]) == worst_share(relmse_map(test, ref, mask), mask)
    # a mask of 0 / 2 (or 0 / 0.5) selects what its bools select, and counts the same pixels
    for scaled in (mask.astype(np.int64) * 2, mask * 0.5):
        r2 = compare_images(test, ref, scaled)
        assert r2["pixels"] == int(mask.sum()) and r2["mse"] == r["mse"]


def test_coverage_comes_from_the_alpha_channel():
    px = np.zeros((2, 3, 4), np.float32)
    px[0, 1, 3] = 1.0
    px[1, 2, 3] = 0.25
    np.testing.assert_array_equal(coverage_from_alpha(px, ["R", "G", "B", "A"]),
                                  [[False, True, False], [False, False, True]])
    assert coverage_from_alpha(px[..., :3], ["R", "G", "B"]) is None


def test_channels_first_and_an_alpha_channel_are_refused_not_compared():
    """A (3, H, W) pair was compared as an image three rows high (72 'pixels' for a 6x9 image), and RGBA pairs
    counted the alpha channel (an EXR's coverage) in every figure."""
    ref, mask = _pair()
    test = ref * 1.1
    for f in (compare_images, relmse, psnr, mse, relmse_map):
        with pytest.raises(WarpbwError, match=r"^test image: expected channels last, \(H, W, C\), got shape "
                                              r"\(3, 6, 9\) \(channels first\? np\.moveaxis"):
            f(np.moveaxis(test, -1, 0), np.moveaxis(ref, -1, 0))
        rgba = np.concatenate([ref, mask[..., None].astype(float)], -1)
        with pytest.raises(WarpbwError, match=r"^test image: expected radiance \(H, W, 3\) or one channel, got 4 "
                                              r"channels \(drop the alpha channel"):
            f(rgba * 1.1, rgba)
    # an image three rows high, in RGB or grey, is still an image
    assert compare_images(test[:3], ref[:3])["pixels"] == 27
    assert compare_images(test[:3, :, :1], ref[:3, :, :1])["pixels"] == 27


def test_relmse_regulariser_is_rousselle_2011s_one_hundredth():
    """relMSE's regulariser is Rousselle, Knaus and Zwicker 2011's 0.01: a pixel of 2 against a reference of 1
    gives 1 / 1.01, a pixel of 0.1 against 0 gives 0.01 / 0.01 = 1 (another epsilon changes both)."""
    assert relmse(np.full((2, 2), 2.0), np.ones((2, 2))) == pytest.approx(1.0 / 1.01, rel=1e-12)
    assert relmse(np.full((2, 2), 0.1), np.zeros((2, 2))) == pytest.approx(1.0, rel=1e-12)


def test_worst_share_counts_the_ceiling_of_the_fraction():
    """The worst pixels are ceil(fraction x n) of them (docstring): 1% of 150 pixels is 2 pixels, not 1, and
    their share is then the two largest errors over the total."""
    e = np.arange(1.0, 151.0)
    share, k = worst_share(e, fraction=0.01)
    assert k == 2 and share == pytest.approx((150.0 + 149.0) / e.sum(), rel=1e-12)


def test_worst_share_of_the_whole_image_is_one():
    """fraction may be 1 (the range is (0, 1]): every pixel is among the "worst", they hold all of the error."""
    assert worst_share(np.array([[1.0, 2.0], [3.0, 0.0]]), fraction=1.0) == (1.0, 4)
