"""Procedural test surfaces and the height/normal-map helpers (issue 4 item 4)."""
from __future__ import annotations

import re

import numpy as np
import pytest
from conftest import attempt
from hypothesis import given, settings
from hypothesis import strategies as st

from precompute.surfaces import (SURFACES, carved_disk, dunes, height_to_normals, hemispherical_scales,
                                 normals_from_map, nyquist_share)
from warpbw.errors import WarpbwError


@pytest.mark.parametrize("name", sorted(SURFACES))
@pytest.mark.parametrize("size", [64, 37])
def test_surface_shape_dtype_finite_and_varied(name, size):
    h = SURFACES[name](size)
    assert h.shape == (size, size) and h.dtype == np.float64
    assert np.all(np.isfinite(h))
    assert np.ptp(h) > 1e-3 and np.std(h) > 1e-4          # heights in map-width units: visibly bumpy
    n = height_to_normals(h)
    tilt = np.degrees(np.arccos(n[..., 2]))
    assert tilt.max() > 5.0                                 # non-trivial normals
    assert np.std(n[..., 0]) > 1e-3 and np.std(n[..., 1]) > 1e-3


@pytest.mark.parametrize("name", sorted(SURFACES))
def test_surfaces_are_deterministic(name):
    assert np.array_equal(SURFACES[name](48), SURFACES[name](48))


def test_dunes_seed_changes_the_surface():
    assert not np.allclose(dunes(32, seed=0), dunes(32, seed=1))


def test_surfaces_tile():
    # the wrap-around step (last column -> first) is no larger than the steps inside the map
    for f in (dunes, carved_disk, hemispherical_scales):
        h = f(128)
        inside = np.abs(np.diff(h, axis=1)).max()
        assert np.abs(h[:, 0] - h[:, -1]).max() <= inside + 1e-12
        inside = np.abs(np.diff(h, axis=0)).max()
        assert np.abs(h[0] - h[-1]).max() <= inside + 1e-12
    # the scales' rims are steps, so the seam check above cannot see them: their pattern repeats every 1 / n of
    # the map in u, and every two staggered rows (1 / n) in v, so a map of 16 n texels equals itself shifted by 16
    h = hemispherical_scales(128, scales_across=8)
    assert all(np.allclose(h, np.roll(h, 16, axis=a), rtol=0, atol=1e-9) for a in (0, 1))


def test_carved_disk_has_grooves_and_a_flat_surround():
    h = carved_disk(256)
    assert h[0, 0] == 0.0 and h[128, 5] == 0.0              # outside the disk
    ring = h[128, 128:128 + 100]                            # centre to the rim along a row
    assert ring.max() - ring[ring > 0].min() > 0.002        # grooves cut into the plateau


@pytest.mark.parametrize("size", [0, 1025, 2.5])
def test_bad_sizes(size):
    with pytest.raises(WarpbwError, match="size"):
        dunes(size)


def test_height_to_normals_of_a_tilted_plane():
    # h = gx * x + gy * y with x = column * t, y = -row * t (tangent y is image up)
    gx, gy, t = 0.3, -0.7, 0.01
    r, c = np.mgrid[0:20, 0:30].astype(np.float64)
    h = gx * c * t + gy * (-r) * t
    n = height_to_normals(h, scale=2.0, texel_size=t)
    want = np.array([-2.0 * gx, -2.0 * gy, 1.0]) / np.sqrt(1.0 + 4.0 * gx * gx + 4.0 * gy * gy)
    np.testing.assert_allclose(n[1:-1, 1:-1], np.broadcast_to(want, n[1:-1, 1:-1].shape), atol=1e-12)



@settings(max_examples=40, deadline=None)
@given(gx=st.floats(-50.0, 50.0), gy=st.floats(-50.0, 50.0), scale=st.floats(-20.0, 20.0),
       t=st.floats(1e-4, 1.0))
def test_height_to_normals_of_any_tilted_plane_is_its_closed_form_normal(gx, gy, scale, t):
    """Any plane h = gx x + gy y (x = column t, y = -row t) has the normal (-s gx, -s gy, 1) / |.| away from the
    wrap-around seam, whatever its slopes, scale s and texel size t (the docstring's convention: x along +column,
    y along -row); central differences are exact on a plane, so only rounding is left."""
    r, c = np.mgrid[0:7, 0:9].astype(np.float64)
    n = height_to_normals(gx * c * t + gy * (-r) * t, scale=scale, texel_size=t)
    want = np.array([-scale * gx, -scale * gy, 1.0])
    want /= np.linalg.norm(want)
    np.testing.assert_allclose(n[1:-1, 1:-1], np.broadcast_to(want, n[1:-1, 1:-1].shape), atol=1e-9)


@settings(max_examples=30, deadline=None)
@given(gx=st.floats(-5.0, 5.0), gy=st.floats(-5.0, 5.0), rows=st.integers(3, 12), cols=st.integers(3, 12))
def test_height_to_normals_default_lays_the_map_on_the_unit_square(gx, gy, rows, cols):
    """By default a W x H map spans the unit square, as a plane lays it: column j at x = j / W, row i at y = -i / H.
    So the plane h = gx x + gy y has the normal (-gx, -gy, 1) / |.| whatever the map's shape (rows were 1 / W apart:
    a 2:1 map came out twice as steep along its rows)."""
    r, c = np.mgrid[0:rows, 0:cols].astype(np.float64)
    n = height_to_normals(gx * c / cols + gy * (-r) / rows)
    want = np.array([-gx, -gy, 1.0]) / np.sqrt(1.0 + gx * gx + gy * gy)
    np.testing.assert_allclose(n[1:-1, 1:-1], np.broadcast_to(want, n[1:-1, 1:-1].shape), atol=1e-9)


@pytest.mark.filterwarnings("ignore:height field of")   # small random maps hold much texel-to-texel detail
@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), rows=st.integers(3, 12), cols=st.integers(3, 12),
       scale=st.floats(0.05, 20.0))
def test_height_to_normals_turns_with_the_map(seed, rows, cols, scale):
    """Mirroring or transposing a height field mirrors or transposes its normal map, with the tangent components
    turned the same way (x = +column, y = -row): a left-right flip negates n_x, an up-down flip n_y, and the
    transpose (x <-> -y) maps (n_x, n_y) to (-n_y, -n_x).  Texel size given, so the transpose's width is no
    matter.  Central differences are symmetric, so this holds to rounding for any heights."""
    h = np.random.default_rng(seed).normal(size=(rows, cols))
    t = 0.1
    n = height_to_normals(h, scale=scale, texel_size=t)
    lr = height_to_normals(h[:, ::-1], scale=scale, texel_size=t)
    np.testing.assert_allclose(lr, n[:, ::-1] * [-1.0, 1.0, 1.0], atol=1e-12)
    ud = height_to_normals(h[::-1], scale=scale, texel_size=t)
    np.testing.assert_allclose(ud, n[::-1] * [1.0, -1.0, 1.0], atol=1e-12)
    tr = height_to_normals(h.T, scale=scale, texel_size=t)
    np.testing.assert_allclose(tr, np.stack([-n[..., 1], -n[..., 0], n[..., 2]], -1).transpose(1, 0, 2),
                               atol=1e-12)

def test_height_to_normals_of_a_sine_matches_the_analytic_derivative():
    W, A, k = 64, 0.01, 2                                  # periodic: wrap-around is exact
    x = np.arange(W) / W
    h = np.broadcast_to(A * np.sin(2 * np.pi * k * x), (8, W))
    n = height_to_normals(h)                               # texel_size 1/W: x in map widths
    slope = -n[..., 0] / n[..., 2]                         # = dh/dx
    analytic = A * 2 * np.pi * k * np.cos(2 * np.pi * k * x)
    # central differences: exactly analytic * sin(d) / d with d = 2 pi k / W (truncation error ~ d^2 / 6)
    d = 2 * np.pi * k / W
    np.testing.assert_allclose(slope[3], analytic * np.sin(d) / d, atol=1e-12)
    np.testing.assert_allclose(slope[3], analytic, atol=d * d / 6 * 1.01 * np.abs(analytic).max())
    np.testing.assert_allclose(n[..., 1], 0.0, atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-12)


@pytest.mark.parametrize("period", [2, 4, 8])
def test_detail_central_differences_cannot_see_warns(period):
    """A height field alternating from texel to texel (period 2) has central differences of exactly 0: its normals are
    a mirror.  A checkerboard's mipmap was built as one, silently; it warns now, and a period of 4 or more, whose
    slopes the differences see (the sine above), does not."""
    import warnings

    W = 16
    x = np.arange(W)
    # rounded: numpy 1.24's cos gives cos(5 pi) = -1 + 1.1e-16 (2.x's: -1), and the closed form below is exact only
    # for heights that repeat exactly
    waves = {"rows": np.broadcast_to(np.cos(2 * np.pi * x / period).round(12), (W, W)),
             "checkerboard": np.cos(2 * np.pi * (x[:, None] + x[None, :]) / period).round(12)}
    for name, h in waves.items():
        with warnings.catch_warnings(record=True) as said:
            warnings.simplefilter("always")
            n = height_to_normals(0.1 * h)
        if period == 2:
            np.testing.assert_array_equal(n, np.broadcast_to([0.0, 0.0, 1.0], n.shape), err_msg=name)   # closed form
            assert nyquist_share(h) == pytest.approx(1.0) and len(said) == 1, name
            assert re.search(r"16x16 texels: 100% of its variance alternates from texel to texel", str(said[0].message))
        else:
            assert nyquist_share(h) == pytest.approx(0.0, abs=1e-12) and not said, name
            assert n[..., 2].min() < 0.999, name   # bumpy, as it should be
    assert nyquist_share(np.ones((4, 4))) == 0.0 and nyquist_share(np.arange(5.0)[None]) == 0.0   # odd: no such band


def test_normals_unit_length_on_every_surface():
    for f in SURFACES.values():
        n = height_to_normals(f(40), scale=3.0)
        np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-12)
        assert np.all(n[..., 2] > 0)


def test_height_to_normals_refuses_what_gave_nan_or_divided_by_zero():
    h = np.random.default_rng(1).random((8, 8))
    for kw in ({"texel_size": 0.0}, {"texel_size": -1.0}, {"scale": float("nan")}):
        with pytest.raises(WarpbwError, match="height_to_normals: expected finite heights"):
            height_to_normals(h, **kw)
    h[2, 2] = np.nan
    with pytest.raises(WarpbwError, match="1 non-finite heights"):
        height_to_normals(h)


def test_normals_from_map_decodes_the_encoding():
    rng = np.random.default_rng(3)
    n = rng.normal(size=(5, 7, 3))
    n[..., 2] = np.abs(n[..., 2]) + 0.1
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    np.testing.assert_allclose(normals_from_map((n + 1) / 2), n, atol=1e-12)
    bad = (n + 1) / 2
    bad[2, 3] = 0.5
    with pytest.raises(WarpbwError, match="row 2, column 3"):
        normals_from_map(bad)
    # 8-bit values were read as [0, 1] floats (255 -> (0.577, 0.577, 0.577)); NaN was "a zero-length normal"
    with pytest.raises(WarpbwError, match="normal map of uint8 values: expected floats in"):
        normals_from_map(np.round(bad * 255).astype(np.uint8))
    bad[1, 1, 0] = np.nan
    with pytest.raises(WarpbwError, match="1 texels are NaN or infinite"):
        normals_from_map(bad)


# ------------------------------------------------------- parameters checked, not coerced (API audit, from Python)


@pytest.mark.parametrize("call,said", [
    (lambda: hemispherical_scales(64, scales_across=2.7), r"^hemispherical_scales: scales_across: expected an integer "
                                                          r">= 1, got 2\.7$"),                      # ran as 2
    (lambda: hemispherical_scales(64, scales_across="3"), r"scales_across: expected an integer >= 1, got '3'$"),
    (lambda: hemispherical_scales(64, radius=float("inf")), r"^hemispherical_scales: radius: expected a finite number "
                                                            r"> 0, got inf$"),                      # OverflowError
    (lambda: hemispherical_scales(64, radius=1e6), r"radius: expected a number > 0 and at most 4 scale spacings"),
    (lambda: hemispherical_scales(64, height=float("inf")), r"height: expected a finite number > 0, got inf$"),
    (lambda: carved_disk(32, thickness=float("nan")), r"^carved_disk: thickness: expected a finite number >= 0, got "
                                                      r"nan$"),                                     # all-NaN map
    (lambda: carved_disk(32, rings=2.5), r"^carved_disk: rings: expected an integer >= 0, got 2\.5$"),
    (lambda: carved_disk(32, groove_width=float("inf")), r"carved_disk: groove_width: expected a finite number > 0"),
    (lambda: carved_disk(32, radius=0.5), r"carved_disk: radius: expected a number > 0 and < 0\.5"),
    (lambda: dunes(32, dune_amplitude=float("nan")), r"^dunes: dune_amplitude: expected a finite number >= 0, got "
                                                     r"nan$"),                                      # all-NaN map
    (lambda: dunes(32, wind=(0.5, 0.5)), r"^dunes: wind: expected two integers .*, not both 0, got \(0\.5, 0\.5\)$"),
    (lambda: dunes(32, wind=(0, 0)), r"^dunes: wind: expected two integers"),
    (lambda: dunes(32, wind=3), r"^dunes: wind: expected two integers"),                            # TypeError
    (lambda: dunes(32, ripples_per_wind=0.5), r"^dunes: ripples_per_wind: expected an integer >= 1, got 0\.5$"),
    (lambda: dunes(32, seed=None), r"^dunes: seed: expected an integer >= 0, got None$"),  # a new map every call
    (lambda: dunes(32, seed=-1), r"^dunes: seed: expected an integer >= 0, got -1$"),      # numpy's ValueError
    (lambda: dunes(32, seed=2**32), r"^dunes: seed: expected an integer from 0 to 4294967295"),
])
def test_generators_refuse_what_they_coerced(call, said):
    with pytest.raises(WarpbwError, match=said):
        call()


@pytest.mark.parametrize("size,across", [(8, 8), (16, 8), (3, 2), (2, 1), (12, 8)])
def test_scales_refuse_a_size_that_cannot_hold_them(size, across):
    """At 1 or 2 texels per scale spacing every texel centre falls on the same point of its top scale: sizes 8 and
    16 at the default 8 scales came out flat (peak-to-peak 0); below 2 texels the pattern aliases."""
    with pytest.raises(WarpbwError, match=rf"^hemispherical_scales: size {size} gives .* texels per scale spacing "
                                          rf"with scales_across {across}; expected more than 2 .*a size of at least "
                                          rf"{2 * across + 1}"):
        hemispherical_scales(size, scales_across=across)


@pytest.mark.parametrize("size,across", [(17, 8), (5, 2), (3, 1), (40, 8)])
def test_scales_just_above_the_bound_are_bumpy(size, across):
    h = hemispherical_scales(size, scales_across=across)
    assert np.ptp(h) > 0.01 and np.degrees(np.arccos(height_to_normals(h)[..., 2])).max() > 5.0


def test_unit_normals_scales_before_the_norm_and_refuses_non_finite_or_2d_vectors():
    from precompute.surfaces import unit_normals

    # (1e200, 0, 1) squared overflowed: the texel came back (0, 0, 0)
    np.testing.assert_array_equal(unit_normals(np.array([[[1e200, 0.0, 1.0]]])), [[[1.0, 0.0, 1e-200]]])
    np.testing.assert_allclose(unit_normals([[[1e300, 1e300, 1.0]]])[0, 0, :2], np.sqrt(0.5), rtol=1e-15)
    np.testing.assert_allclose(unit_normals([[0, 0, 2.0], [0, 3.0, 0]]), [[0, 0, 1], [0, 1, 0]])
    with pytest.raises(WarpbwError, match=r"^1 normal-map texels hold NaN or infinite vectors \(first at row 0, column "
                                          r"0\)"):
        unit_normals(np.array([[[np.inf, 0.0, 1.0]]]))       # (nan, 0, 0) with a RuntimeWarning
    with pytest.raises(WarpbwError, match=r"^normal-map texels of shape \(2, 2, 2\): expected 3-vectors"):
        unit_normals(np.ones((2, 2, 2)))                     # accepted, renormalised as 2-vectors


def test_normals_from_map_refuses_values_outside_the_encoding():
    """A float map of 255.0 (an 8-bit map not divided) decoded as (0.577, 0.577, 0.577) without a word."""
    with pytest.raises(WarpbwError, match=r"^normal map: 4 texels hold values outside \[0, 1\] \(first at row 0, column "
                                          r"0: \(255\.0, 255\.0, 255\.0\)\).* divide it by 255\)$"):
        normals_from_map(np.full((2, 2, 3), 255.0))
    with pytest.raises(WarpbwError, match=r"values up to 6\.554e\+04: a 16-bit map stored as floats\? divide it by "
                                          r"65535\)$"):
        normals_from_map(np.full((2, 2, 3), 65535.0))
    with pytest.raises(WarpbwError) as ei:    # beyond any integer map's range: no such guess ("an 16-bit map")
        normals_from_map(np.full((2, 2, 3), 1e30))
    assert "bit map" not in str(ei.value) and str(ei.value).endswith("n = 2 rgb - 1")
    with pytest.raises(WarpbwError, match=r"outside \[0, 1\] \(first at row 1, column 0: \(-0\.5, 0\.5, 1\.0\)\)"):
        normals_from_map(np.array([[[0.5, 0.5, 1.0]], [[-0.5, 0.5, 1.0]]]))
    # within ENCODING_TOL (a resampled map's overshoot) it decodes, renormalised
    np.testing.assert_allclose(normals_from_map(np.array([[[0.5, 0.5, 1.05]]])), [[[0.0, 0.0, 1.0]]])


def test_height_to_normals_names_a_scale_that_is_not_a_number():
    for kw in ({"scale": "2"}, {"scale": None}, {"texel_size": "x"}, {"scale": True}):
        with pytest.raises(WarpbwError, match="height_to_normals: expected finite heights, a finite scale"):
            height_to_normals(np.zeros((4, 4)), **kw)


def test_hemispherical_scales_peak_where_the_staggered_rows_put_their_centres():
    """Odd rows are staggered by half a spacing (a square grid, not armour, passed every other test).  Truth: the
    docstring's layout in closed form.  With n scales across, row j of 2n has its scale centres at
    u = (i + 1/2 + (j mod 2) / 2) / n, v = (j + 1/2) / (2n); the next rows' scales (centres 0.71 and 1 spacing
    away) do not reach a centre for radius 0.6 spacings, so each centre shows the scale's own top,
    height * sqrt(r^2 - d^2), d the half-texel diagonal to the four texel centres around it."""
    n, size, radius, height = 4, 64, 0.6, 0.5
    h = hemispherical_scales(size, scales_across=n, radius=radius, height=height)
    r = radius / n
    want = height * np.sqrt(r * r - 2.0 * (0.5 / size) ** 2)
    tex = size // n                                  # texels per spacing (16); a row is tex / 2 high
    for j in range(2 * n):
        row = j * tex // 2 + tex // 4                # the texel rows tex/4 - 1 and tex/4 straddle the centre
        for i in range(n):
            col = (i * tex + tex // 2 + (j % 2) * tex // 2) % size
            block = h[np.ix_([row - 1, row], [(col - 1) % size, col % size])]
            assert np.allclose(block, want, rtol=1e-9, atol=0.0), (j, i, block, want)


# ------------------------------------------------------------------------------------------- inputs, outputs and units
# (mutation round 8: each test fails on a plausible mistake the suite let through)


def test_min_surface_size_is_the_smallest_size_every_surface_holds_at_its_defaults():
    """MIN_SURFACE_SIZE (17, the module docstring) is a size every surface holds at its defaults; the scales refuse one
    less."""
    from precompute.surfaces import MIN_SURFACE_SIZE, SURFACES, hemispherical_scales

    assert MIN_SURFACE_SIZE == 17          # the module docstring: "(17)"
    for name, make in SURFACES.items():
        h, err = attempt(make, MIN_SURFACE_SIZE)
        assert err == "" and h.shape == (MIN_SURFACE_SIZE,) * 2, (name, err)
    assert "texels per scale spacing" in attempt(hemispherical_scales, MIN_SURFACE_SIZE - 1)[1]


def test_a_surface_of_the_largest_size_is_made_and_one_more_is_refused():
    """A surface of MAX_SURFACE_SIZE (1024, issue 4: "up to 1024x1024") is made; one more is refused."""
    from precompute.surfaces import MAX_SURFACE_SIZE, carved_disk

    assert MAX_SURFACE_SIZE == 1024        # issue 4: "up to 1024x1024"
    h, err = attempt(carved_disk, 1024, rings=0, spokes=0)
    assert err == "" and h.shape == (1024, 1024), err
    assert "expected an integer from 1 to 1024" in attempt(carved_disk, 1025)[1]


def test_the_scales_refusal_suggests_a_count_that_fits():
    """The count the scales' refusal suggests ("scales_across at most N") is accepted at that size; N + 1 is not.
    The refusal says it is a Python argument: `warpbw-precompute gmm surface:hemispherical_scales:SIZE` takes none."""
    for size, across in [(16, 8), (9, 8), (12, 8), (5, 3)]:
        _, said = attempt(hemispherical_scales, size, scales_across=across)
        fits = int(re.search(r"scales_across at most (\d+) \(an argument from Python\)", said).group(1))
        h, err = attempt(hemispherical_scales, size, scales_across=fits)
        assert err == "" and h.shape == (size, size), (size, across, said, err)
        assert "texels per scale spacing" in attempt(hemispherical_scales, size, scales_across=fits + 1)[1]


def test_the_largest_scale_radius_the_refusal_states_is_accepted():
    """The refusal's "at most 4 scale spacings" includes 4: a radius of 4 spacings is accepted."""
    h, err = attempt(hemispherical_scales, 32, scales_across=2, radius=4.0)
    assert err == "" and h.shape == (32, 32) and np.all(np.isfinite(h)), err
    assert "at most 4 scale spacings" in attempt(hemispherical_scales, 32, scales_across=2, radius=4.0001)[1]


def test_carved_disk_spokes_run_over_the_outer_two_thirds_only():
    """carved_disk's spokes run over the outer two thirds of the disk (docstring). On the +x axis (theta = 0, a spoke:
    spokes at multiples of 2 pi / spokes), half-way between rings, the height is the plateau (thickness) inside radius /
    3 and thickness - depth beyond it."""
    size, radius, rings, depth, thickness = 257, 0.42, 10, 0.004, 0.01
    h = carved_disk(size, radius=radius, rings=rings, depth=depth, thickness=thickness)
    row = size // 2                                    # v = 0.5 exactly: y = 0
    step = radius / (rings + 1)
    for k, grooved in [(2, False), (4, True), (6, True)]:   # rho/radius = 0.23, 0.41, 0.59
        rho = (k + 0.5) * step
        col = int(round((rho + 0.5) * size - 0.5))
        x = (col + 0.5) / size - 0.5
        assert abs(x / step - round(x / step)) * step > 0.006 * 1.5    # clear of the ring grooves
        want = thickness - depth if grooved else thickness
        assert h[row, col] == pytest.approx(want, abs=1e-12), (k, x / radius, h[row, col])


def test_the_generators_list_every_surface_the_help_names():
    """--help and the docstring name three procedural surfaces for surface:NAME[:SIZE]."""
    from precompute.__main__ import build_parser
    from precompute.gmm_mipmap import load_source

    sub = build_parser()._subparsers._group_actions[0].choices["gmm"]
    text = " ".join(sub.description.split())
    for name in ("hemispherical_scales", "carved_disk", "dunes"):
        assert name in text
        got, err = attempt(load_source, f"surface:{name}:20")
        assert err == "" and got[0].shape == (20, 20) and got[1] == f"surface:{name}:20", err


def test_height_to_normals_wraps_around_along_rows_too():
    """A height field periodic down the rows, sin(2 pi k y), y = -row / H map widths: its central-difference slope with
    wrap-around is exact at every row, the first and last included; the same along columns."""
    H, W, A, k = 32, 8, 0.01, 2
    r = np.arange(H)
    h = np.broadcast_to((A * np.sin(2 * np.pi * k * (-r / H)))[:, None], (H, W))
    n = height_to_normals(h, texel_size=1.0 / H)
    slope_y = -n[..., 1] / n[..., 2]                     # dh/dy, y up the image
    d = 2 * np.pi * k / H
    want = A * 2 * np.pi * k * np.cos(2 * np.pi * k * (-r / H)) * np.sin(d) / d
    np.testing.assert_allclose(slope_y[:, 3], want, atol=1e-12)
    np.testing.assert_allclose(n[..., 0], 0.0, atol=1e-15)
    nt = height_to_normals(h.T.copy(), texel_size=1.0 / H)      # the same along columns (x = +column)
    np.testing.assert_allclose(-nt[3, :, 0] / nt[3, :, 2], -want, atol=1e-12)


def test_a_normal_map_value_well_outside_the_encoding_is_refused():
    """Resampling overshoots [0, 1] by a few percent (ENCODING_TOL's comment); 20% over is not that."""
    np.testing.assert_allclose(normals_from_map(np.array([[[0.5, 0.5, 1.05]]])), [[[0.0, 0.0, 1.0]]])
    for v in ([0.5, 0.5, 1.2], [-0.2, 0.5, 1.0]):
        said = attempt(normals_from_map, np.array([[v]]))[1]
        assert "texels hold values outside [0, 1]" in said, (v, said)


def test_vectors_shorter_than_the_stated_minimum_are_refused():
    """NORMAL_LENGTH_MIN is 0.5; a texel of length 0.3 or 0.45 holds no trustworthy direction."""
    from precompute.surfaces import NORMAL_LENGTH_MIN, normals_from_map, unit_normals

    assert NORMAL_LENGTH_MIN == 0.5
    for length in (0.3, 0.45):
        assert "hold vectors shorter than 0.5" in attempt(unit_normals, np.array([[[0.0, 0.0, length]]]))[1]
        said = attempt(normals_from_map, np.array([[[0.5, 0.5, (length + 1) / 2]]]))[1]
        assert "decode to vectors shorter than 0.5" in said, said
    np.testing.assert_allclose(unit_normals(np.array([[[0.0, 0.0, 0.55]]])), [[[0.0, 0.0, 1.0]]])


def _scales_by_brute_force(size, n, radius, height):
    """hemispherical_scales from its docstring alone: every scale of every row (centres unwrapped over three periods
    either way, so wrap-around needs no care), and each texel shows, of the scales covering it, the one of the
    latest row (lowest centre) and, in that row, the one farthest right."""
    t = (np.arange(size) + 0.5) / size
    v, u = np.meshgrid(t, t, indexing="ij")
    sx, sy, r = 1.0 / n, 1.0 / (2 * n), radius / n
    best = np.full((size, size, 2), -np.inf)
    out = np.zeros((size, size))
    for j in range(-6 * n, 8 * n):                            # rows, unwrapped
        for i in range(-3 * n, 4 * n):                        # scales of the row, unwrapped
            xc, yc = (i + 0.5 + 0.5 * (j % 2)) * sx, (j + 0.5) * sy
            d2 = (u - xc) ** 2 + (v - yc) ** 2
            on_top = (d2 < r * r) & ((yc > best[..., 0]) | ((yc == best[..., 0]) & (xc > best[..., 1])))
            best[on_top] = (yc, xc)
            out = np.where(on_top, height * np.sqrt(np.maximum(r * r - d2, 0.0)), out)
    return out


@pytest.mark.parametrize("radius", [0.6, 2.0, 3.0, 4.0])
def test_hemispherical_scales_overlap_as_the_docstring_says_at_every_accepted_radius(radius):
    """Of the scales covering a texel, the one of the latest row and, in it, the one farthest right is on top,
    whatever the radius (up to MAX_SCALE_RADIUS, 4 spacings).  Only the scales one spacing either side were painted,
    so from about 2 spacings on the overlap order flipped at every cell boundary: at 3 spacings 0.16 of a 0.17
    height range off, in steps across the map."""
    got = hemispherical_scales(48, scales_across=3, radius=radius, height=0.5)
    np.testing.assert_allclose(got, _scales_by_brute_force(48, 3, radius, 0.5), rtol=0, atol=1e-12)
