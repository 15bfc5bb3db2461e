"""Bandwidth-buffer pyramid (002 Sec. 3.1): Eq. 11 level map and min/max mip-maps of any size,
checked against a brute-force numpy reference written here."""
from __future__ import annotations

import math

import numpy as np
import pytest
import warp as wp
from hypothesis import given, settings, strategies as st

from warpbw.errors import WarpbwError
from warpbw.pyramid import (Pyramid, build_pyramid, curvature_pyramid, image_level, level_pyramid,
                            max_level, pyramid_shapes, variance_pyramid)

SIZES = [(1, 1), (1, 7), (7, 1), (7, 5), (16, 16), (33, 17), (512, 3), (3, 512)]  # (width, height)


# ---------------------------------------------------------------------------------------------
# Brute-force references
# ---------------------------------------------------------------------------------------------
def ref_pyramid(base: np.ndarray, op: str) -> list[np.ndarray]:
    """Each texel (x, y) of level l = op over the finest pixels [x 2^l, (x+1) 2^l) x [y 2^l, (y+1) 2^l)
    clipped to the image; levels until 1 x 1 with ceil halving."""
    f = np.min if op == "min" else np.max
    if base.dtype.kind == "f":
        base = np.where(np.isnan(base), -np.inf if op == "min" else np.inf, base).astype(np.float32)
    h, w = base.shape
    out, l = [], 0
    while True:
        s = 1 << l
        rows, cols = -(-h // s), -(-w // s)
        lev = np.empty((rows, cols), base.dtype)
        for y in range(rows):
            for x in range(cols):
                lev[y, x] = f(base[y * s:min((y + 1) * s, h), x * s:min((x + 1) * s, w)])
        out.append(lev)
        if rows == 1 and cols == 1:
            return out
        l += 1


def ref_level(b: np.ndarray, cov: np.ndarray | None, w: int, h: int, nan_level: str = "finest") -> np.ndarray:
    """Eq. 11 with the conventions of warpbw.pyramid: largest l in [0, top] with b 2^l <= 1."""
    top = int(math.floor(math.log2(min(w, h))))
    out = np.empty(b.shape, np.int32)
    for idx, v in np.ndenumerate(b.astype(np.float32)):
        if cov is not None and not cov[idx]:
            out[idx] = top
        elif np.isnan(v):
            out[idx] = 0 if nan_level == "finest" else top
        elif v <= 0:
            out[idx] = top
        else:
            l = 0
            while l < top and np.ldexp(np.float64(v), l + 1) <= 1.0:   # exact in float64
                l += 1
            out[idx] = l
    return out


def eq11(b: float, w: int, h: int) -> int:
    """002 Eq. 11 as printed, clamped at 0: min(floor(log2(1/b)), min(log2 W, log2 H))."""
    return max(0, min(math.floor(math.log2(1.0 / b)), math.floor(min(math.log2(w), math.log2(h)))))


def check_pyramid(p: Pyramid, base: np.ndarray, op: str):
    ref = ref_pyramid(base, op)
    w, h = base.shape[1], base.shape[0]
    assert p.shapes == pyramid_shapes(w, h) == [r.shape for r in ref]
    assert p.num_levels == len(ref)
    got = p.numpy()
    for l, (g, r) in enumerate(zip(got, ref)):
        assert g.shape == r.shape, l
        np.testing.assert_array_equal(g, r, err_msg=f"level {l} of {w}x{h} {op}")


# ---------------------------------------------------------------------------------------------
# Size rule and mip-maps
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("w,h", SIZES)
def test_size_rule(w, h):
    shapes = pyramid_shapes(w, h)
    assert shapes[0] == (h, w) and shapes[-1] == (1, 1)
    for (h0, w0), (h1, w1) in zip(shapes, shapes[1:]):
        assert (h1, w1) == ((h0 + 1) // 2, (w0 + 1) // 2)
    assert len(shapes) == 1 + math.ceil(math.log2(max(w, h)))
    assert max_level(w, h) == math.floor(math.log2(min(w, h)))


@pytest.mark.parametrize("w,h", SIZES)
@pytest.mark.parametrize("op", ["min", "max"])
@pytest.mark.parametrize("kind", ["float", "int"])
def test_pyramid_matches_bruteforce(w, h, op, kind):
    rng = np.random.default_rng(w * 1000 + h)
    if kind == "float":
        base = rng.normal(size=(h, w)).astype(np.float32)
    else:
        base = rng.integers(-5, 12, size=(h, w)).astype(np.int32)
    p = build_pyramid(base, op, "cpu")
    assert p.op == op and p.width == w and p.height == h
    assert p.levels[0].dtype == (wp.float32 if kind == "float" else wp.int32)
    check_pyramid(p, base, op)


@settings(max_examples=40, deadline=None)
@given(w=st.integers(1, 70), h=st.integers(1, 70), op=st.sampled_from(["min", "max"]),
       kind=st.sampled_from(["float", "int"]), seed=st.integers(0, 2**31 - 1))
def test_pyramid_random_sizes(w, h, op, kind, seed):
    rng = np.random.default_rng(seed)
    base = (rng.normal(size=(h, w)).astype(np.float32) if kind == "float"
            else rng.integers(0, 9, size=(h, w)).astype(np.int32))
    check_pyramid(build_pyramid(base, op, "cpu"), base, op)


def test_pyramid_inputs_wp_flat_and_not_aliased():
    rng = np.random.default_rng(3)
    base = rng.random((17, 33)).astype(np.float32)
    arr = wp.array(base, dtype=wp.float32, device="cpu")
    p = build_pyramid(arr, "max")                       # device taken from the array
    check_pyramid(p, base, "max")
    assert p.levels[0].ptr != arr.ptr                   # level 0 is a copy
    p.levels[0].fill_(0.0)
    np.testing.assert_array_equal(arr.numpy(), base)
    flat = wp.array(base.reshape(-1), dtype=wp.float32, device="cpu")   # G-buffer layout
    check_pyramid(build_pyramid(flat, "min", "cpu", width=33, height=17), base, "min")
    check_pyramid(build_pyramid(base > 0.5, "max", "cpu"), (base > 0.5).astype(np.int32), "max")


def test_nan_values_are_conservative():
    base = np.arange(35, dtype=np.float32).reshape(7, 5)
    base[3, 2] = np.nan
    pmax, pmin = variance_pyramid(base, "cpu"), build_pyramid(base, "min", "cpu")
    check_pyramid(pmax, base, "max")
    check_pyramid(pmin, base, "min")
    assert pmax.level(pmax.num_levels - 1)[0, 0] == np.inf
    assert pmin.level(1)[1, 1] == -np.inf and pmin.level(0)[3, 2] == -np.inf


def test_curvature_pyramid_takes_abs():
    rng = np.random.default_rng(5)
    c = rng.normal(size=(9, 13)).astype(np.float32)
    check_pyramid(curvature_pyramid(c, "cpu"), np.abs(c), "max")
    check_pyramid(curvature_pyramid(c, "cpu", absolute=False), c, "max")


def test_bad_input():
    with pytest.raises(WarpbwError, match="op"):
        build_pyramid(np.zeros((2, 2), np.float32), "mean", "cpu")
    with pytest.raises(WarpbwError, match="empty"):
        build_pyramid(np.zeros((0, 3), np.float32), "min", "cpu")
    with pytest.raises(WarpbwError, match="width and height"):
        build_pyramid(np.zeros(6, np.float32), "min", "cpu")
    with pytest.raises(WarpbwError, match="do not make"):
        build_pyramid(np.zeros(6, np.float32), "min", "cpu", width=4, height=2)
    with pytest.raises(WarpbwError, match="size"):
        pyramid_shapes(0, 3)
    with pytest.raises(WarpbwError, match="nan_level"):
        image_level(np.ones((2, 2), np.float32), nan_level="middle")
    with pytest.raises(WarpbwError, match="coverage"):
        image_level(np.ones((2, 2), np.float32), np.ones((3, 2), bool))


# ---------------------------------------------------------------------------------------------
# Eq. 11
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("b,want", [(1.0, 0), (0.5, 1), (1.0 / 3.0, 1), (0.25, 2), (0.3, 1), (0.125, 3),
                                    (0.126, 2), (2.0, 0), (1.5, 0), (0.9, 0), (2.0 ** -5, 5),
                                    (2.0 ** -6, 6), (2.0 ** -7, 6), (1e-30, 6), (1e-45, 6)])
def test_eq11_sample_values(b, want):
    w, h = 100, 64                                      # top level floor(log2 64) = 6
    lv = image_level(np.full((h, w), b, np.float32), None, device="cpu").numpy()
    assert lv.dtype == np.int32 and lv.shape == (h, w)
    assert np.all(lv == want)
    if b >= 1e-30:
        assert want == eq11(float(np.float32(b)), w, h)


@pytest.mark.parametrize("w,h", [(1, 1), (1, 7), (7, 5), (16, 16), (33, 17), (512, 3)])
def test_eq11_random_against_formula(w, h):
    rng = np.random.default_rng(w + 7 * h)
    b = (2.0 ** rng.uniform(-12, 2, size=(h, w))).astype(np.float32)
    exact = np.array([2.0 ** -3, 0.5, 1.0, 2.0 ** -10], np.float32)   # powers of two: no off-by-one
    n = min(b.size, exact.size)
    b.flat[:n] = exact[:n]
    lv = image_level(b, None, device="cpu").numpy()
    np.testing.assert_array_equal(lv, ref_level(b, None, w, h))
    formula = np.vectorize(lambda v: eq11(float(v), w, h))(b)
    np.testing.assert_array_equal(lv, formula)
    assert lv.min() >= 0 and lv.max() <= max_level(w, h)


@pytest.mark.parametrize("nan_level", ["finest", "coarsest"])
def test_eq11_non_finite_and_non_positive(nan_level):
    vals = np.array([[np.nan, np.inf, -np.inf, 0.0, -0.0, -1.0, 3.0e38, 1e-45]], np.float32)
    lv = image_level(np.repeat(vals, 8, 0), device="cpu", nan_level=nan_level).numpy()[0]
    top = 3                                            # 8 x 8 image
    assert list(lv) == [0 if nan_level == "finest" else top, 0, top, top, top, top, 0, top]
    np.testing.assert_array_equal(lv, ref_level(vals, None, 8, 8, nan_level)[0])


def test_coverage_and_min_filter_ignore_empty_pixels():
    rng = np.random.default_rng(11)
    w, h = 33, 17
    b = (2.0 ** rng.uniform(-6, 0, size=(h, w))).astype(np.float32)
    cov = np.zeros((h, w), bool)
    cov[4:12, 8:25] = True
    b[~cov] = 4.0                                      # background bandwidth that would ask for level 0
    b[~cov & (rng.random((h, w)) < 0.3)] = np.nan
    lv = image_level(b, cov, device="cpu").numpy()
    np.testing.assert_array_equal(lv, ref_level(b, cov, w, h))
    assert np.all(lv[~cov] == max_level(w, h))
    # the min pyramid equals the min over covered pixels only (coarsest where a texel sees none)
    p = level_pyramid(lv, "cpu")
    top = max_level(w, h)
    for l, got in enumerate(p.numpy()):
        s = 1 << l
        for y in range(got.shape[0]):
            for x in range(got.shape[1]):
                c = cov[y * s:(y + 1) * s, x * s:(x + 1) * s]
                v = lv[y * s:(y + 1) * s, x * s:(x + 1) * s]
                assert got[y, x] == (v[c].min() if c.any() else top)
    # flat G-buffer-layout inputs give the same map; int coverage works like bool
    flat = image_level(b.reshape(-1), cov.reshape(-1).astype(np.int32), w, h, device="cpu").numpy()
    np.testing.assert_array_equal(flat, lv)
    wpflat = image_level(wp.array(b.reshape(-1), dtype=wp.float32), wp.array(cov.reshape(-1), dtype=wp.bool),
                         w, h).numpy()
    np.testing.assert_array_equal(wpflat, lv)


def test_level_pyramid_is_conservative():
    """A finest pixel is never shaded coarser than its Eq. 11 level: at every pyramid level l the
    texel over (x, y) holds a level <= level(x, y)."""
    rng = np.random.default_rng(2)
    w, h = 40, 23
    lv = image_level((2.0 ** rng.uniform(-8, 1, size=(h, w))).astype(np.float32), device="cpu").numpy()
    p = level_pyramid(lv, "cpu")
    ys, xs = np.mgrid[0:h, 0:w]
    for l, got in enumerate(p.numpy()):
        assert np.all(got[ys >> l, xs >> l] <= lv)


# ------------------------------------------------------------------------------------------ properties (hypothesis)
# Property-based tests of the bandwidth-buffer pyramid (warpbw.pyramid, 002 Sec. 3.1): metamorphic relations that
# hold for any image size (odd, prime, 1 x N, taller than wide) and need no reference implementation: the min and max
# filters commute with monotone maps, a transposed image gives transposed levels, an image cut at a multiple of 2^l
# reduces block by block, and Eq. 11's level rises by exactly one when the bandwidth halves.


sizes = st.integers(1, 37)
seeds = st.integers(0, 2**31 - 1)


def random_image(w, h, seed, kind, nan_share=0.0):
    """A float32 image of normal values with ``nan_share`` of NaN, or an int32 level-like map."""
    rng = np.random.default_rng(seed)
    if kind == "int":
        return rng.integers(-3, 12, size=(h, w)).astype(np.int32)
    x = rng.normal(size=(h, w)).astype(np.float32)
    x[rng.random((h, w)) < nan_share] = np.nan
    return x


# monotone maps (float32 in, float32 out; evaluated elementwise, so each pixel's image is one fixed number)
INCREASING = {"affine": lambda x: np.float32(3.0) * x + np.float32(0.5),
              "cube": lambda x: x * x * x,
              "step": lambda x: np.floor(x * np.float32(2.0))}     # non-strict: still commutes


DECREASING = {"negate": lambda x: -x,
              "negated-cube": lambda x: -(x * x * x)}


@settings(max_examples=40, deadline=None)
@given(w=sizes, h=sizes, seed=seeds, nan_share=st.sampled_from([0.0, 0.1]),
       f=st.sampled_from(sorted(INCREASING)), g=st.sampled_from(sorted(DECREASING)))
def test_min_and_max_filters_commute_with_monotone_maps(w, h, seed, nan_share, f, g):
    """For f increasing, min over a footprint of f(x) is f(min x) and max of f(x) is f(max x); for g decreasing,
    min of g(x) is g(max x).  The filters only select values, so this holds exactly, texel by texel, at every level
    and for any size.  NaN reads as -inf under min and +inf under max (module docstring), the extremes f and g map
    to the opposite or the same infinity, so NaN pixels keep the relation; and the 1 x 1 top is the image's extreme."""
    x = random_image(w, h, seed, "float", nan_share)
    fi, gd = INCREASING[f], DECREASING[g]
    with np.errstate(over="ignore", invalid="ignore"):
        mn, mx = build_pyramid(x, "min").numpy(), build_pyramid(x, "max").numpy()
        mn_f, mx_f = build_pyramid(fi(x), "min").numpy(), build_pyramid(fi(x), "max").numpy()
        mn_g = build_pyramid(gd(x), "min").numpy()
        for l in range(len(mn)):
            np.testing.assert_array_equal(mn_f[l], fi(mn[l]), err_msg=f"min of {f}, level {l}")
            np.testing.assert_array_equal(mx_f[l], fi(mx[l]), err_msg=f"max of {f}, level {l}")
            np.testing.assert_array_equal(mn_g[l], gd(mx[l]), err_msg=f"min of {g}, level {l}")
    # the top texel is the extreme of the whole image, NaN as the conservative infinity
    nan = np.isnan(x)
    assert mn[-1].shape == (1, 1)
    assert mn[-1][0, 0] == (-np.inf if nan.any() else x.min())
    assert mx[-1][0, 0] == (np.inf if nan.any() else x.max())


@settings(max_examples=40, deadline=None)
@given(w=sizes, h=sizes, seed=seeds, op=st.sampled_from(["min", "max"]), kind=st.sampled_from(["float", "int"]))
def test_transposing_the_image_transposes_every_level(w, h, seed, op, kind):
    """The size rule and the 2 x 2 footprints treat rows and columns alike (module docstring), so the pyramid of
    the transposed image is the transposed pyramid, level by level, for any W x H: an axis slip (a column clamped
    by the row count, a width halved as a height) shows on images that are not square."""
    x = random_image(w, h, seed, kind)
    p = build_pyramid(x, op).numpy()
    pt = build_pyramid(np.ascontiguousarray(x.T), op).numpy()
    assert len(p) == len(pt)
    for l, (a, b) in enumerate(zip(p, pt)):
        np.testing.assert_array_equal(b, a.T, err_msg=f"level {l} of {w}x{h}")


@settings(max_examples=40, deadline=None)
@given(l=st.integers(1, 3), blocks=st.integers(1, 3), rest=st.integers(1, 20), h=sizes, seed=seeds,
       op=st.sampled_from(["min", "max"]), axis=st.sampled_from([0, 1]))
def test_an_image_cut_at_a_multiple_of_2_to_the_l_reduces_block_by_block(l, blocks, rest, h, seed, op, axis):
    """Texel x of level l covers the finest pixels [x 2^l, (x + 1) 2^l) (clipped at the border; module docstring),
    so cutting an image at column (or row) k 2^l cuts no footprint of level l: level l of the whole is level l of
    the left part beside level l of the right part, whatever the right part's (odd) size."""
    s = 1 << l
    a = random_image(blocks * s, h, seed, "float")
    b = random_image(rest, h, seed + 1, "float")
    if axis == 0:       # cut between rows instead of columns
        a, b = np.ascontiguousarray(a.T), np.ascontiguousarray(b.T)
    whole = np.concatenate([a, b], axis=axis)
    got = build_pyramid(whole, op).numpy()
    pa, pb = build_pyramid(a, op).numpy(), build_pyramid(b, op).numpy()
    # a part already reduced to 1 x 1 stays so (an axis that reached 1 stays 1)
    at = lambda p: p[min(l, len(p) - 1)]   # noqa: E731
    np.testing.assert_array_equal(at(got), np.concatenate([at(pa), at(pb)], axis=axis))


@settings(max_examples=50, deadline=None)
@given(w=st.integers(1, 70), h=st.integers(1, 70), seed=seeds)
def test_halving_the_bandwidth_coarsens_the_level_by_one_up_to_the_top(w, h, seed):
    """Eq. 11, level = min(floor(log2(1 / b_p)), floor(log2(min(W, H)))) clamped at 0: halving b_p adds exactly 1 to
    floor(log2(1 / b_p)) (power-of-two scalings are exact in float32), so the level of b_p / 2 is the level of b_p
    plus one, up to the top (for b_p <= 1; above, both clamp to 0); a larger bandwidth never gets a coarser level;
    and every level lies in [0, top]."""
    rng = np.random.default_rng(seed)
    b = np.exp2(rng.uniform(-10.0, 3.0, size=(h, w))).astype(np.float32)
    b.flat[: min(b.size, 4)] = np.float32(2.0) ** rng.integers(-9, 2, size=min(b.size, 4))   # exact powers of two
    top = min(w, h).bit_length() - 1    # floor(log2(min(W, H))), exactly
    assert max_level(w, h) == top
    lv = image_level(b).numpy()
    lv_half = image_level(b * np.float32(0.5)).numpy()
    assert lv.min() >= 0 and lv.max() <= top
    # b_p <= 1: one level coarser, up to the top; b_p > 1 (floor(log2(1 / b_p)) < 0): still the finest
    np.testing.assert_array_equal(lv_half, np.where(b <= 1.0, np.minimum(lv + 1, top), 0))
    # monotone: sorting the bandwidths sorts the levels the other way
    order = np.argsort(b, axis=None, kind="stable")
    assert np.all(np.diff(lv.reshape(-1)[order]) <= 0)
