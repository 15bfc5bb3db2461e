"""Wavelet local bandwidth (precompute/wavelets.py, 002 Sec. 2.3 Eq. 7, 000 App. A).

The truth is not the code: synthetic signals of known frequency, and a 32x32 Hann-windowed FFT
(the "naive" estimator 002 Sec. 2.3 compares against) with the 95% energy rule of 000 Fig. 3.
Acceptance (issue 3): predicted bandwidth within a factor 2 of the true frequency.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import attempt
from hypothesis import given, settings
from hypothesis import strategies as st

from precompute.wavelets import (
    EPSILON,
    ENERGY_FRACTION,
    band_maxima,
    envmap_angular_bandwidth,
    envmap_bandwidth_max,
    local_bandwidth,
    texture_spatial_bandwidth,
)
from warpbw.errors import WarpbwError

N = 128
Y, X = np.mgrid[0:N, 0:N].astype(np.float64)
FACTOR = 2.0  # issue 3 acceptance: within a factor 2


def fft_bandwidth(img: np.ndarray, cy: int, cx: int, n: int = 32, frac: float = 0.95) -> float:
    """Windowed-FFT reference: radius (cycles/pixel) holding ``frac`` of the AC spectral energy of
    the ``n x n`` Hann-windowed patch centred on (cy, cx)."""
    p = img[cy - n // 2: cy + n // 2, cx - n // 2: cx + n // 2].astype(np.float64)
    p = p - p.mean()
    w = np.hanning(n + 2)[1:-1]
    power = np.abs(np.fft.fft2(p * np.outer(w, w))) ** 2
    k = np.fft.fftfreq(n)
    r = np.hypot(k[:, None], k[None, :]).ravel()
    order = np.argsort(r, kind="stable")
    cum = np.cumsum(power.ravel()[order])
    if cum[-1] <= 1e-20:
        return 0.0
    return float(r[order][np.searchsorted(cum, frac * cum[-1])])


def sine(f: float, angle_deg: float, n: int = N) -> np.ndarray:
    a = math.radians(angle_deg)
    y, x = np.mgrid[0:n, 0:n].astype(np.float64)
    return np.sin(2 * np.pi * f * (x * math.cos(a) + y * math.sin(a)) + 0.3)


def test_constants_cite_the_paper():
    assert EPSILON == 0.01 and ENERGY_FRACTION == 0.95


def test_fft_reference_finds_a_sines_frequency():
    # the reference itself: within 30% of f once a 32-px window holds a few periods
    for f in (0.1, 0.2, 0.3, 0.4):
        ref = fft_bandwidth(sine(f, 0), 64, 64)
        assert 0.95 * f <= ref <= 1.3 * f, (f, ref)


@pytest.mark.parametrize("f", [0.04, 0.06, 0.1, 0.15, 0.22, 0.3, 0.4, 0.47])
@pytest.mark.parametrize("angle", [0, 30, 45, 90, 120])
def test_sine_within_factor_two(f, angle):
    img = sine(f, angle)
    b = local_bandwidth(img, pad="reflect")
    interior = b[32:96, 32:96]
    lo, hi = np.percentile(interior, [2, 98])
    assert lo >= f / FACTOR and hi <= f * FACTOR, (f, angle, lo, hi)
    # and against the windowed FFT where the window resolves f
    if f >= 0.1:
        for cy, cx in ((48, 48), (64, 80), (80, 60)):
            ref = fft_bandwidth(img, cy, cx)
            assert ref / FACTOR <= b[cy, cx] <= ref * FACTOR, (f, angle, b[cy, cx], ref)


@pytest.mark.parametrize("period", [4, 6, 8])
def test_checker_within_factor_two_of_fft(period):
    img = ((X // (period / 2) + Y // (period / 2)) % 2).astype(np.float64)
    b = local_bandwidth(img, pad="reflect")
    ratios = [b[cy, cx] / fft_bandwidth(img, cy, cx)
              for cy in range(40, 90, 7) for cx in range(40, 90, 9)]
    assert min(ratios) >= 1 / FACTOR and max(ratios) <= FACTOR, (period, min(ratios), max(ratios))


@pytest.mark.parametrize("period", [16, 32])
def test_large_checker_edges_within_factor_two_of_fft(period):
    # squares of 8 and 16 px: the 32-px FFT window always straddles an edge while the wavelets
    # resolve the flat square centres (per pixel down to 0.2-0.3 of the FFT there), so compare
    # the high end of the prediction (the edges) with the FFT's typical value
    img = ((X // (period / 2) + Y // (period / 2)) % 2).astype(np.float64)
    b = local_bandwidth(img, pad="reflect")
    ref = np.median([fft_bandwidth(img, cy, cx) for cy in range(40, 90, 7) for cx in range(40, 90, 9)])
    p90 = np.percentile(b[32:96, 32:96], 90)
    assert ref / FACTOR <= p90 <= ref * FACTOR, (period, p90, ref)


def test_step_edge():
    img = (X >= 64.5).astype(np.float64)  # edge between columns 64 and 65
    b = local_bandwidth(img, pad="edge")
    ref = fft_bandwidth(img, 64, 65)
    at_edge = b[20:108, 64:66].max(axis=1)
    assert np.all(at_edge >= ref / FACTOR) and np.all(at_edge <= ref * FACTOR), (ref, at_edge.min(), at_edge.max())
    # away from the edge the image is flat: far lower bandwidth, 0 beyond the widest wavelet
    assert b[20:108, :40].max() < 0.05 and b[20:108, 100:].max() < 0.05


def test_constant_image():
    img = np.full((64, 64), 3.0)
    assert np.all(local_bandwidth(img, pad="edge") == 0.0)
    assert np.all(local_bandwidth(img, pad="reflect") == 0.0)
    # as a finite source (zero-padded, 002 Sec. 2.3) only its border varies
    bz = local_bandwidth(img)
    assert bz[28:36, 28:36].max() < 0.05
    assert bz[0, :].min() > 0.15 and bz[:, -1].min() > 0.15  # a step: FFT says 0.25


def test_sine_patch_in_flat_image_is_localised():
    f = 0.2
    img = np.zeros((N, N))
    img[48:80, 48:80] = sine(f, 0)[48:80, 48:80]
    b = local_bandwidth(img)
    inside = b[54:74, 54:74]
    assert inside.min() >= f / FACTOR and inside.max() <= f * FACTOR
    far = np.ones_like(b, dtype=bool)
    far[24:104, 24:104] = False
    assert b[far].max() < f / 2  # only the coarse, wide db4 bands reach that far
    assert np.median(b[far]) == 0.0


@settings(max_examples=25, deadline=None)
@given(f1=st.floats(0.03, 0.45), f2=st.floats(0.03, 0.45))
def test_monotone_in_frequency(f1, f2):
    f1, f2 = sorted((f1, f2))
    m1 = float(np.median(local_bandwidth(sine(f1, 0, 64), pad="reflect")[16:48, 16:48]))
    m2 = float(np.median(local_bandwidth(sine(f2, 0, 64), pad="reflect")[16:48, 16:48]))
    assert m2 >= m1 * 0.97  # non-decreasing up to a 3% wobble between band centres
    if f2 >= 1.5 * f1:
        assert m2 > m1


@settings(max_examples=20, deadline=None)
@given(exponent=st.integers(-300, 140))
def test_bandwidth_does_not_depend_on_the_images_scale(exponent):
    """Only ratios of wavelet coefficients enter Eq. 7 and the energy rule: scaling the image by 10^k changes
    nothing, down to 1e-300 (at 1e-170 the squared coefficients underflowed and every pixel read 0)."""
    img = sine(0.12, 0.3, 48) + 0.5 * (X[:48, :48] > 20)
    np.testing.assert_allclose(local_bandwidth(img * 10.0 ** exponent), local_bandwidth(img), rtol=1e-9, atol=0)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), h=st.integers(6, 40), w=st.integers(6, 40),
       pad=st.sampled_from(["zero", "edge", "reflect", "wrap"]), rule=st.sampled_from(["energy", "eq7"]))
def test_a_transposed_image_reads_its_bandwidth_transposed(seed, h, w, pad, rule):
    """The 2D transform is separable and the same filters run along both axes; the horizontal and vertical details
    swap under a transpose and the per-pixel maximum takes all three orientations.  So the transposed image's
    bands and bandwidth are the transposed ones, for any size, pad mode and rule (rows and columns treated
    alike)."""
    img = np.random.default_rng(seed).normal(size=(h, w)).cumsum(axis=0).cumsum(axis=1)   # some smooth, some rough
    np.testing.assert_allclose(band_maxima(img.T, pad=pad), band_maxima(img, pad=pad).transpose(0, 2, 1),
                               rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(local_bandwidth(img.T, pad=pad, rule=rule), local_bandwidth(img, pad=pad, rule=rule).T,
                               rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("shape", [(97, 150), (33, 70), (50, 50)])
def test_non_power_of_two_sizes(shape):
    h, w = shape
    f = 0.15
    img = np.sin(2 * np.pi * f * np.arange(w))[None, :] * np.ones((h, 1))
    b = local_bandwidth(img)  # zero-padded to a multiple of 2^L internally, cropped back
    assert b.shape == shape and np.all(np.isfinite(b))
    core = b[h // 2 - 4: h // 2 + 4, w // 2 - 4: w // 2 + 4]
    assert core.min() >= f / FACTOR and core.max() <= f * FACTOR


def test_colour_channels_take_the_fastest():
    """The fastest channel, wherever it is: with the 0.3 cycles/pixel sine last only, a bandwidth read from the last
    channel alone passed.  Truth: the fast sine's own f (factor 2) and its reading alone; the slow channel alone
    reads far lower, so the mean or the slowest channel fail too."""
    fast = np.median(local_bandwidth(sine(0.3, 90), pad="reflect")[32:96, 32:96])
    slow = np.median(local_bandwidth(sine(0.05, 0), pad="reflect")[32:96, 32:96])
    assert 0.3 / FACTOR <= fast <= 0.3 * FACTOR and slow < 0.5 * fast
    channels = [sine(0.05, 0), np.zeros((N, N)), sine(0.3, 90)]
    for k in range(3):                                  # the fast sine in channel 2, 0 and 1
        img = np.dstack(channels[k:] + channels[:k])
        b = local_bandwidth(img, pad="reflect")
        assert b.shape == (N, N)
        assert np.median(b[32:96, 32:96]) == pytest.approx(fast, rel=0.05), k


def test_band_maxima_shape_and_units():
    lam = band_maxima(sine(0.2, 0), levels=5, pad="reflect")
    assert lam.shape == (5, N, N) and np.all(lam >= 0)
    # f = 0.2 lies in band 2 (0.125 .. 0.25 cycles/px): its maximum is the largest
    assert np.argmax(np.median(lam[:, 32:96, 32:96], axis=(1, 2))) == 1


def test_eq7_rule_is_a_power_of_two_and_overestimates():
    for f in (0.06, 0.2):
        b = local_bandwidth(sine(f, 0), pad="reflect", rule="eq7")[32:96, 32:96]
        levels = -np.log2(b)
        assert np.allclose(levels, np.round(levels))
        assert b.min() >= f  # Eq. 7 errs on the high side (002 Sec. 2.3 says so): never below the sine's f


def test_haar_is_accepted():
    b = local_bandwidth(sine(0.3, 0), wavelet="haar", pad="reflect")
    assert 0.3 / FACTOR <= np.median(b[32:96, 32:96]) <= 0.3 * FACTOR


def test_bad_input_is_refused():
    """Refused as the renderer's one-line WarpbwError (these were plain ValueErrors, which the CLIs print with a
    traceback)."""
    with pytest.raises(WarpbwError):
        local_bandwidth(np.zeros(16))
    with pytest.raises(WarpbwError):
        local_bandwidth(np.full((16, 16), np.nan))
    with pytest.raises(WarpbwError):
        local_bandwidth(np.zeros((16, 16)), epsilon=0.0)
    with pytest.raises(WarpbwError):
        local_bandwidth(np.zeros((16, 16)), rule="median")
    with pytest.raises(WarpbwError):
        texture_spatial_bandwidth(np.zeros((16, 16)), metres_per_pixel=0.0)
    # a NaN floor switched the flatness test off; 2.5 levels were cut to 2; a string was read as a length
    with pytest.raises(WarpbwError, match="floor must be a finite number >= 0"):
        local_bandwidth(np.zeros((16, 16)), floor=float("nan"))
    with pytest.raises(WarpbwError, match="levels must be an integer"):
        local_bandwidth(np.zeros((16, 16)), levels=2.5)
    with pytest.raises(WarpbwError, match="metres_per_pixel .* got '0.01'"):
        texture_spatial_bandwidth(np.zeros((16, 16)), metres_per_pixel="0.01")


def test_texture_spatial_bandwidth_in_cycles_per_metre():
    f_px = 0.125
    mpp = 0.002  # 2 mm texels: truth 62.5 cycles/metre
    img = np.sin(2 * np.pi * f_px * X)
    t = texture_spatial_bandwidth(img, metres_per_pixel=mpp, pad="wrap")
    truth = f_px / mpp
    assert truth / FACTOR <= np.median(t[32:96, 32:96]) <= truth * FACTOR
    np.testing.assert_allclose(t * mpp, local_bandwidth(img, pad="wrap"))


def _latlong(h=128, w=256):
    theta = (np.arange(h) + 0.5) * np.pi / h
    phi = (np.arange(w) + 0.5) * 2 * np.pi / w
    return theta, phi


def test_envmap_latitude_frequency():
    # L = cos(n theta): n / (2 pi) cycles per radian along every meridian (exact under lambda_max)
    theta, phi = _latlong()
    n = 16
    img = np.cos(n * theta)[:, None] * np.ones((1, phi.size))
    nu = envmap_angular_bandwidth(np.dstack([img] * 3))
    truth = n / (2 * np.pi)
    band = nu[16:112]
    assert band.min() >= truth / FACTOR and band.max() <= truth * FACTOR, (truth, band.min(), band.max())


def test_envmap_longitude_frequency_at_equator():
    # L = cos(m phi): m / (2 pi sin theta) cycles per radian of arc; m / (2 pi) at the equator
    theta, phi = _latlong()
    m = 32
    img = np.ones((theta.size, 1)) * np.cos(m * phi)[None, :]
    nu = envmap_angular_bandwidth(img)
    truth = m / (2 * np.pi)
    eq = nu[56:72]
    assert eq.min() >= truth / FACTOR and eq.max() <= truth * FACTOR, (truth, eq.min(), eq.max())
    # longitude wraps: no seam at phi = 0
    assert abs(float(np.median(eq[:, :4])) - float(np.median(eq[:, 120:136]))) < 0.1 * truth


def _sphere_grid(rows, w):
    """Directions (x, y, z) of lat-long texel centres at the given (possibly out-of-range) row indices, from the
    spherical formulas continued past the poles: theta < 0 or > pi is the same direction as |theta| (or
    2 pi - theta) at longitude phi + pi, which is what crossing a pole means."""
    h = 128
    theta = (np.asarray(rows) + 0.5) * np.pi / h
    phi = (np.arange(w) + 0.5) * 2 * np.pi / w
    T, P = np.meshgrid(theta, phi, indexing="ij")
    return np.sin(T) * np.cos(P), np.cos(T), np.sin(T) * np.sin(P)


@pytest.mark.parametrize("k", [9, 128, 148, 261, 400])
def test_latlong_pole_padding_continues_the_sphere_across_both_poles(k):
    """Rows padded beyond a pole are the texels on the far side of it: the map of a smooth function on the
    sphere, padded, equals that function on the rows continued past theta = 0 and theta = pi.  Also past more rows
    than the map has (k >= h), which band_maxima's margin asks of every map under about 352 rows (a 512 x 256
    probe, the procedural sky): past both poles the map comes back unturned (period 2h); until session 73 row
    -1 - k read row k mod h turned by pi, a step from one pole's value to the other's h rows out."""
    from precompute.wavelets import _pad_axis

    h, w = 128, 256

    def f(rows):
        x, y, z = _sphere_grid(rows, w)
        return x + 0.5 * z + 0.3 * x * y + 0.2 * z * z * x

    padded = _pad_axis(f(np.arange(h)), 0, k, k, "latlong_pole")
    np.testing.assert_allclose(padded, f(np.arange(-k, h + k)), atol=1e-12)


@pytest.mark.parametrize("h", [64, 128])
def test_a_small_latlong_maps_bands_are_those_of_the_sphere_unfolded_over_its_period(h):
    """A lat-long map continued across both poles is periodic in rows with period 2h: its h rows, then the same
    rows mirrored at longitude + pi.  So band_maxima of an h x 2h map padded ("latlong_pole", "wrap") equals that
    of the unfolded 2h x 2h image padded ("wrap", np.pad's), on the map's rows.  At h = 64 both padded grids (768
    and 896 rows) hold whole periods; the margin (352 rows) is 5.5 map heights, and until session 73 the coarse
    bands differed by up to 0.11 (of 1.2).  At h = 128 the map's grid (896 rows) holds 3.5 periods: its seam
    differs from the unfolded image's (1024 rows, 4 periods) by up to 0.014 in the coarse bands."""
    w = 2 * h
    theta = (np.arange(h) + 0.5) * np.pi / h
    phi = (np.arange(w) + 0.5) * 2 * np.pi / w
    x, y = np.sin(theta)[:, None] * np.cos(phi)[None], np.cos(theta)[:, None] * np.ones((1, w))
    img = 1.2 + 0.5 * y + 0.3 * x * y + 0.2 * np.cos(9 * np.arccos(np.clip(x, -1.0, 1.0)))
    unfolded = np.concatenate([img, np.roll(img[::-1], w // 2, axis=1)], axis=0)
    got = band_maxima(img, pad=("latlong_pole", "wrap"))
    want = band_maxima(unfolded, pad="wrap")[:, :h]
    assert got.shape == (7, h, w)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)


@pytest.mark.parametrize("h", [8, 32, 64])
def test_envmap_bandwidth_max_bounds_the_finest_probes(h):
    """envmap_bandwidth_max(H) = H / (2 pi): no map of H rows reads above it (a checker at the pixel rate, noise,
    one bright texel at a pole), and the checker reads more than half of it (the bound is not loose by orders)."""
    y, x = np.mgrid[0:h, 0:2 * h]
    spike = np.ones((h, 2 * h))
    spike[0, 3] = 1e4
    maps = {"checker": 1.0 + 0.5 * ((x + y) % 2), "noise": np.random.default_rng(h).random((h, 2 * h)),
            "spike": spike}
    most = envmap_bandwidth_max(h)
    assert most == pytest.approx(h / (2 * math.pi), rel=1e-12)
    for name, img in maps.items():
        assert envmap_angular_bandwidth(img).max() <= most, name
    assert envmap_angular_bandwidth(maps["checker"]).max() > 0.5 * most

def test_envmap_bandwidth_at_the_poles_reads_as_elsewhere():
    """L = cos(15 a), a the angle from the horizontal +X axis: 15 / (2 pi) cycles/rad along every great circle
    through +-X, the same everywhere on the sphere, and smooth across the map's poles (odd, so a pole crossed
    without turning the longitude by pi would meet -L there).  No row near a pole may read faster than the
    map's other rows (they read 1.0-1.4x the truth; a seam at the pole reads up to 2x)."""
    n = 15
    x, _, _ = _sphere_grid(np.arange(128), 256)
    nu = envmap_angular_bandwidth(np.cos(n * np.arccos(np.clip(x, -1.0, 1.0))))
    polar = np.concatenate([nu[:8], nu[-8:]])
    assert polar.max() <= nu[8:-8].max(), (polar.max(), nu[8:-8].max())
    truth = n / (2 * np.pi)
    assert truth / FACTOR <= np.median(nu) <= truth * FACTOR


def test_envmap_constant_is_zero():
    assert np.all(envmap_angular_bandwidth(np.full((32, 64, 3), 0.7)) == 0.0)


@pytest.mark.slow
def test_real_probe_studio(shared):
    from warpbw.io.exr import read_rgb

    px = read_rgb(shared("envmaps/studio.exr"))
    nu = envmap_angular_bandwidth(px)
    assert nu.shape == px.shape[:2]
    assert np.all(np.isfinite(nu)) and np.all(nu >= 0)
    lum = px.mean(axis=2)
    lights = lum > np.percentile(lum, 99.9)  # the small bright lights
    assert 0 < lights.sum() < 0.01 * lum.size
    # flat: more than 40 px from any light pixel (box dilation via a summed-area table)
    r = 40
    sat = np.pad(lights.astype(np.int64), ((r + 1, r), (r + 1, r))).cumsum(0).cumsum(1)
    near = (sat[2 * r + 1:, 2 * r + 1:] - sat[:-2 * r - 1, 2 * r + 1:]
            - sat[2 * r + 1:, :-2 * r - 1] + sat[:-2 * r - 1, :-2 * r - 1]) > 0
    flat = ~near
    assert np.median(nu[lights]) > 4 * np.median(nu[flat])


# ------------------------------------------------------- parameters named in one line (API audit, from Python)


@pytest.mark.parametrize("kw,said", [
    ({"wavelet": "db99"}, r"^wavelet 'db99': expected the name of an orthogonal discrete wavelet"),  # pywt's ValueError
    ({"wavelet": None}, r"^wavelet None: expected the name"),                                        # pywt's TypeError
    ({"pad": "bogus"}, r"^pad 'bogus': expected one mode or a \(rows, columns\) pair of modes from zero, "),  # np.pad's
    ({"pad": ("wrap",)}, r"^pad \('wrap',\): expected one mode or a \(rows, columns\) pair"),       # unpacking error
    ({"pad": ("wrap", "wrap", "wrap")}, r"^pad \('wrap', 'wrap', 'wrap'\): expected"),               # accepted
    ({"pad": None}, r"^pad None: expected"),
    ({"pad": "empty"}, r"^pad 'empty': expected"),                                                   # uninitialised
    ({"epsilon": "0.1"}, r"^epsilon must be a number in \(0, 1\), got '0\.1'$"),                      # TypeError
    ({"energy_fraction": "x"}, r"^energy_fraction must be a number in \(0, 1\], got 'x'$"),
    ({"epsilon": True}, r"^epsilon must be a number in \(0, 1\), got True$"),
])
def test_bad_parameters_are_named(kw, said):
    with pytest.raises(WarpbwError, match=said):
        local_bandwidth(np.eye(8), **kw)


def test_a_pad_pair_and_np_pad_modes_still_work():
    img = sine(0.2, 0, 32)
    np.testing.assert_array_equal(local_bandwidth(img, pad=["wrap", "wrap"]), local_bandwidth(img, pad="wrap"))
    assert np.all(np.isfinite(local_bandwidth(img, pad=("reflect", "symmetric"))))


@pytest.mark.parametrize("mpp", [True, 1e-320, 1e-45])
def test_texture_metres_per_pixel_must_be_a_length_that_keeps_the_bandwidth_finite(mpp):
    """True was read as 1 metre; 1e-320 gave inf everywhere (0.5 cycles/pixel / 1e-320)."""
    with pytest.raises(WarpbwError, match=rf"^metres_per_pixel must be a positive finite number >= 1\.47e-39 .*got "
                                          rf"{mpp!r}$"):
        texture_spatial_bandwidth(np.eye(8), metres_per_pixel=mpp)
    assert np.all(np.isfinite(texture_spatial_bandwidth(np.eye(8), metres_per_pixel=1.5e-39).astype(np.float32)))


def test_complex_or_string_images_are_refused():
    with pytest.raises(WarpbwError, match="complex values"):   # the imaginary part was dropped with a warning
        local_bandwidth(np.ones((8, 8)) * (1 + 1j))
    with pytest.raises(WarpbwError, match=r"image must be \(H, W\) or \(H, W, C\) numbers, got str"):
        local_bandwidth("abc")


def test_envmap_longitude_frequency_at_the_equator_of_a_square_map():
    """A lat-long map that is not 2:1 (loaded with a warning) has texels 2 pi / W wide at the equator: L = cos(m
    phi) is m / (2 pi) cycles per radian there, within issue 3's factor 2.  On 2:1 maps the longitude term of
    lambda_max never binds, so only such a map reads it."""
    h = w = 128
    phi = (np.arange(w) + 0.5) * 2 * np.pi / w
    m = 16
    nu = envmap_angular_bandwidth(np.ones((h, 1)) * np.cos(m * phi)[None, :])
    truth = m / (2 * np.pi)
    eq = nu[60:68]
    assert eq.min() >= truth / 2 and eq.max() <= truth * 2, (truth, eq.min(), eq.max())


@pytest.mark.parametrize("band", [1, 2, 3, 4])
@pytest.mark.parametrize("axis", [0, 1])
def test_band_maxima_of_a_line_spread_over_the_filter_support_and_one_wavelet_width(band, axis):
    """Module docstring of precompute.wavelets: lambda_i^max(x) is the largest band-i coefficient over the 2^i + 1
    coefficients around x.  Across a line, the band-i coefficients are non-zero over the support of the level-i
    equivalent high-pass filter, (2^i - 1)(L - 1) + 1 taps (L = 8 for db4), so lambda_i^max is non-zero over that
    plus 2^i pixels, and (centred) covers the line.  (A line, not an impulse: across it only one detail orientation
    answers, where an impulse's row is the union of a high-passed and a low-passed response.)"""
    n = 256
    img = np.zeros((n, n))
    if axis == 0:
        img[:, n // 2] = 1.0
    else:
        img[n // 2, :] = 1.0
    lam = band_maxima(img, levels=4)[band - 1]
    across = lam[n // 2] if axis == 0 else lam[:, n // 2]
    on = np.flatnonzero(across > 1e-12 * across.max())
    assert len(on) == on[-1] - on[0] + 1 == (2 ** band - 1) * 7 + 1 + 2 ** band, on
    assert on[0] < n // 2 < on[-1]


def test_eq7_rule_reads_the_top_of_the_band_that_holds_the_sine():
    """002 Eq. 7's discrete level I_w gives 2^-I_w cycles/pixel, the top of band I_w: a sine in the finest band
    (f in 0.25 .. 0.5 cycles/pixel) reads 0.5, and "overestimates" means never below f (the other tests check f = 0.06
    and 0.2 only, where halving the result still stays above f)."""
    for f in (0.3, 0.4, 0.47):   # band 1 (0.25 .. 0.5 cycles/pixel): Eq. 7 reads its top, 0.5, and never below f
        b = local_bandwidth(sine(f, 0), pad="reflect", rule="eq7")[32:96, 32:96]
        assert np.all(b == 0.5), (f, b.min(), b.max())


# ------------------------------------------------------------------------------------------- inputs, outputs and units
# (mutation round 8: each test fails on a plausible mistake the suite let through)


def _latlong_spot(h=32, w=64, col=0):
    img = np.zeros((h, w))
    img[:, col] = 1.0
    return img


def test_envmap_bandwidth_turns_with_the_map_in_longitude():
    """Longitude wraps (the docstring: a sphere has no border), so rolling the map in longitude rolls its bandwidth: a
    bright meridian at column 0 reads as one at column 20."""
    img = _latlong_spot()
    b = envmap_angular_bandwidth(img)
    for k in (1, 20, 33):
        np.testing.assert_allclose(envmap_angular_bandwidth(np.roll(img, k, axis=1)), np.roll(b, k, axis=1),
                                   rtol=1e-9, atol=1e-12)


def test_envmap_bandwidth_of_a_map_whose_padded_width_is_no_whole_number_of_turns_turns_with_it():
    """As above on a 256 x 512 map: its padded width, 1280 columns, is 2.5 turns of longitude, so the periodic
    transform meets a seam 416 columns past the map's right edge (352 before its left), and the bandwidth near
    longitude 0 depends on where the map starts (0.6% here; 1024 x 512 probes are padded to 1.75 turns: forest.exr's
    map changes by up to 11% on 0.45% of its texels when the probe is turned by half a turn and back)."""
    h, w = 256, 512
    y, x = np.mgrid[0:h, 0:w]
    img = 0.2 + 0.1 * np.sin(2 * np.pi * 3 * x / w) * np.sin(np.pi * (y + 0.5) / h)
    img[100:104, 2:6] = 30.0   # a small bright light beside longitude 0
    b = envmap_angular_bandwidth(img)
    for k in (1, 256):
        np.testing.assert_allclose(np.roll(envmap_angular_bandwidth(np.roll(img, k, axis=1)), -k, axis=1), b,
                                   rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("h, w", [(250, 500), (60, 120)])
def test_envmap_bandwidth_of_a_map_whose_whole_turns_do_not_fit_the_margin_turns_with_it(h, w):
    """As above on maps whose whole turns no multiple of 2^L within the margin holds (500 columns: 32 turns at L = 7;
    120 columns: 8 turns at L = 6; their rows across both poles likewise): until session 74 they got the margin
    rounded up to 2^L and its seam (a 1000 x 500 probe turned half a turn and back: up to 13% on 0.41% of its texels);
    now the transform is circular on one period, and the map turns with the probe bit for bit."""
    y, x = np.mgrid[0:h, 0:w]
    img = 0.2 + 0.1 * np.sin(2 * np.pi * 3 * x / w) * np.sin(np.pi * (y + 0.5) / h)
    img[h // 3:h // 3 + 4, 2:6] = 30.0   # a small bright light beside longitude 0
    b = envmap_angular_bandwidth(img)
    for k in (1, 7, w // 2):
        np.testing.assert_array_equal(np.roll(envmap_angular_bandwidth(np.roll(img, k, axis=1)), -k, axis=1), b)


@pytest.mark.parametrize("pad", [("latlong_pole", "wrap"), ("wrap", "wrap"), ("zero", "wrap")])
def test_a_periodic_axis_whose_whole_periods_do_not_fit_reads_as_the_same_signal_tiled_to_whole_periods(pad):
    """A 60 x 120 map on 6 levels: 120 columns (and 120 rows across both poles) reach a multiple of 2^6 only at 8
    periods, beyond the margin.  The truth: the same periodic signal tiled 8 times, whose width pywt.swt2 takes as it
    is (whole periods, swt2's own wrap), cut back to the map.  Until session 74 the map's own bands met the seam of
    its margin (up to 0.0095, 2.4%, in the coarse bands)."""
    h, w, tiles = 60, 120, 8   # 8 x 120 = 960 = 15 x 2^6
    theta = (np.arange(h) + 0.5) * np.pi / h
    phi = (np.arange(w) + 0.5) * 2 * np.pi / w
    x, y = np.sin(theta)[:, None] * np.cos(phi)[None], np.cos(theta)[:, None] * np.ones((1, w))
    img = 1.2 + 0.5 * y + 0.3 * x * y + 0.2 * np.cos(9 * np.arccos(np.clip(x, -1.0, 1.0)))
    img[20:23, 2:5] += 3.0
    got = band_maxima(img, levels=6, pad=pad)
    if pad[0] == "zero":
        truth = band_maxima(np.tile(img, (1, tiles)), levels=6, pad=pad)
    else:
        period = np.concatenate([img, np.roll(img[::-1], w // 2, axis=1)]) if pad[0] == "latlong_pole" else img
        truth = band_maxima(np.tile(period, (tiles * w // len(period), tiles)), levels=6, pad="wrap")
    np.testing.assert_allclose(got, truth[:, :h, :w], rtol=0, atol=1e-12)


@pytest.mark.parametrize("n, level0", [(64, 2), (1000, 6), (1000, 3), (45, 5), (50, 5)])
def test_the_circular_transform_of_any_length_is_the_dilated_filters_convolution(n, level0):
    """precompute.wavelets._swt2_level: where pywt.swt2 applies (n a multiple of 2^(level0 + 1)) it gives pywt's
    coefficients; on any n it is the circular correlation with the filters dilated by 2^level0 at pywt's alignment,
    computed here through the DFT (filter response times the signal's spectrum), and keeps the energy (an orthogonal
    filter pair scaled by 1/sqrt(2), |H|^2 + |G|^2 = 1 at every frequency, so on every circle).  n = 45 and 50 are
    shorter than the level's filter (7 * 32 + 1 taps): it wraps several times.  Asked for the details on some rows
    only, it gives those rows of them."""
    import pywt

    from precompute.wavelets import _swt2_level

    wav = pywt.Wavelet("db4")
    x = np.random.default_rng(n + level0).standard_normal((2, n, n + 3 if n % 2 ** (level0 + 1) else n))
    a, (ch, cv, cd) = _swt2_level(x, wav, level0)
    if x.shape[1] % 2 ** (level0 + 1) == 0 and x.shape[2] % 2 ** (level0 + 1) == 0:
        (pa, (ph, pv, pd)), = pywt.swt2(x, wav, level=1, start_level=level0, axes=(-2, -1), norm=True)
        for p, q in ((a, pa), (ch, ph), (cv, pv), (cd, pd)):
            np.testing.assert_allclose(p, q, rtol=0, atol=1e-12)

    def response(f, m):
        # out[j] = sum_k f[k] x[j + (K/2 - k) s]: in the DFT, X[q] times sum_k f[k] exp(2 pi i q (K/2 - k) s / m)
        k = np.arange(len(f))
        q = np.arange(m)[:, None]
        return (np.asarray(f) / np.sqrt(2) * np.exp(2j * np.pi * q * (len(f) // 2 - k) * 2 ** level0 / m)).sum(1)

    spec = np.fft.fft2(x)
    filt = {"a": wav.dec_lo, "d": wav.dec_hi}
    for name, got in (("aa", a), ("da", ch), ("ad", cv), ("dd", cd)):
        r = response(filt[name[0]], x.shape[1])[:, None] * response(filt[name[1]], x.shape[2])[None, :]
        np.testing.assert_allclose(got, np.fft.ifft2(spec * r).real, rtol=0, atol=1e-10)
    energy = sum((c ** 2).sum() for c in (a, ch, cv, cd))
    assert energy == pytest.approx((x ** 2).sum(), rel=1e-12)
    # the details on some rows only (band_maxima's window), from before row 0 on: those rows of the whole
    first, count = -7, min(20, n - 1)
    part, details = _swt2_level(x, wav, level0, (first, count))
    assert np.array_equal(part, a)
    for got, whole in zip(details, (ch, cv, cd)):
        np.testing.assert_allclose(got, whole[:, np.arange(first, first + count) % n], rtol=0, atol=1e-12)


def test_envmap_bandwidth_of_a_map_whose_whole_turns_do_not_fit_reads_a_known_frequency():
    """L = cos(15 a), a the angle from +X: 15 / (2 pi) cycles/rad along every great circle through +-X (the test
    above at 128 x 256), on a 100 x 200 map, whose turns and rows the circular transform takes: the median nu_a
    within the factor 2 of issue 3, and no row near a pole faster than the others."""
    n, h, w = 15, 100, 200
    theta = (np.arange(h) + 0.5) * np.pi / h
    phi = (np.arange(w) + 0.5) * 2 * np.pi / w
    x = np.sin(theta)[:, None] * np.cos(phi)[None]
    nu = envmap_angular_bandwidth(np.cos(n * np.arccos(np.clip(x, -1.0, 1.0))))
    truth = n / (2 * np.pi)
    assert truth / FACTOR <= np.median(nu) <= truth * FACTOR, np.median(nu)
    assert np.concatenate([nu[:8], nu[-8:]]).max() <= nu[8:-8].max()


def test_envmap_floor_is_the_flatness_threshold_and_rule_is_passed_on():
    """Floor "is local_bandwidth's flatness threshold" (absolute: above every coefficient, every pixel is flat); rule
    "eq7" gives powers of two in cycles/pixel, 2^-I_w, here times the pixels per radian."""
    h, w = 32, 64
    theta = (np.arange(h) + 0.5) * np.pi / h
    img = np.cos(6 * theta)[:, None] * np.ones((1, w)) + 1.0
    assert envmap_angular_bandwidth(img).max() > 0
    assert np.all(envmap_angular_bandwidth(img, floor=1e3) == 0.0)
    nu = envmap_angular_bandwidth(img, rule="eq7")
    lam = np.maximum(2 * math.pi * np.sin(theta) / w, math.pi / h)
    b = (nu * lam[:, None])[nu > 0]
    np.testing.assert_allclose(np.log2(b), np.round(np.log2(b)), atol=1e-9)


def test_texture_bandwidth_passes_on_pad_and_rule():
    """A tiling texture with pad="wrap" rolls with its bandwidth (no border), and rule="eq7" gives powers of two
    cycles/pixel."""
    y, x = np.mgrid[0:32, 0:32].astype(np.float64)
    img = np.sin(2 * np.pi * x / 8) + 0.5 * np.sin(2 * np.pi * y / 16)
    img[:, :3] += 1.0                                        # a band at the left edge that wraps to the right
    mpp = 0.01
    t = texture_spatial_bandwidth(img, mpp, pad="wrap")
    np.testing.assert_allclose(texture_spatial_bandwidth(np.roll(img, 11, axis=1), mpp, pad="wrap"),
                               np.roll(t, 11, axis=1), rtol=1e-9, atol=1e-9)
    b = texture_spatial_bandwidth(img, mpp, pad="wrap", rule="eq7") * mpp
    b = b[b > 0]
    np.testing.assert_allclose(np.log2(b), np.round(np.log2(b)), atol=1e-9)


def test_energy_fraction_one_is_accepted_and_reads_no_lower():
    """Energy_fraction in (0, 1] (its own refusal says so); all the energy lies at or above 95% of it."""
    y, x = np.mgrid[0:32, 0:32].astype(np.float64)
    img = np.sin(2 * np.pi * x / 6) + np.sin(2 * np.pi * y / 20)
    b1, err = attempt(local_bandwidth, img, energy_fraction=1.0)
    assert err == "" and np.all(b1 >= local_bandwidth(img) - 1e-12) and np.all(np.isfinite(b1)), err
    for bad in (1.01, 0.0):
        assert "energy_fraction must be a number in (0, 1]" in attempt(local_bandwidth, img, energy_fraction=bad)[1]


def test_epsilon_of_one_is_refused():
    """Epsilon "must be a number in (0, 1)" (Eq. 7's significance threshold; at 1 only the strongest band would
    count)"""
    said = attempt(local_bandwidth, np.eye(8), epsilon=1.0)[1]
    assert said == "epsilon must be a number in (0, 1), got 1.0", said


def test_a_wide_image_is_analysed_down_to_the_period_of_its_long_side():
    """A 16 x 256 image of a sine of period 128 along its long side: within a factor 2 of 1/128 cycles/px."""
    x = np.arange(256, dtype=np.float64)
    img = np.broadcast_to(np.sin(2 * np.pi * x / 128 + 0.3), (16, 256))
    b = local_bandwidth(img, pad="wrap")
    med = float(np.median(b[:, 64:192]))
    f = 1 / 128                                   # the sine's frequency, cycles per pixel
    assert f / 2 <= med <= 2 * f, (med, f)


def test_a_small_source_reads_as_the_same_source_embedded_in_zeros():
    """"finite sources are embedded in zeros": an 8 x 8 patch reads as it does inside a larger zero field."""
    rng = np.random.default_rng(4)
    img = rng.random((8, 8))
    big = np.zeros((40, 40))
    big[16:24, 16:24] = img
    floor = 0.01 * 0.3
    a = local_bandwidth(img, levels=3, floor=floor)
    b = local_bandwidth(big, levels=3, floor=floor)[16:24, 16:24]
    np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12)


def test_a_floor_of_zero_is_accepted():
    """A floor of 0 is accepted (the refusal: "floor must be a finite number >= 0 (or None)")."""
    img = np.sin(np.arange(16) / 2.0)[None, :] * np.ones((16, 1))
    b, err = attempt(local_bandwidth, img, floor=0.0)
    assert err == "" and b.shape == (16, 16) and np.all(np.isfinite(b)) and b.max() > 0, err


def test_a_smooth_source_bands_read_as_the_same_source_embedded_in_zeros_down_to_the_coarsest_band():
    """Zero embedding (002 Sec. 2.3) and the SWT's shift invariance: a 16x16 blob analysed on 5 bands has the same
    lambda_i^max in every band, the coarsest too, as inside a large zero field (no wrap-around onto itself)."""
    n, lev, pad = 16, 5, 64
    yy, xx = np.mgrid[0:n, 0:n] - (n - 1) / 2
    img = np.exp(-(xx ** 2 + yy ** 2) / (2 * (n / 6) ** 2))
    big = np.zeros((n + 2 * pad, n + 2 * pad))
    big[pad:pad + n, pad:pad + n] = img
    lam_big = band_maxima(big, levels=lev)[:, pad:pad + n, pad:pad + n]
    np.testing.assert_allclose(band_maxima(img, levels=lev), lam_big, rtol=1e-6, atol=1e-9 * lam_big.max())
    floor = 0.01 * lam_big.max()
    np.testing.assert_allclose(local_bandwidth(img, levels=lev, floor=floor),
                               local_bandwidth(big, levels=lev, floor=floor)[pad:pad + n, pad:pad + n], rtol=1e-6)


def _energy_rule_by_hand(lam, epsilon, floor, fraction=0.95):
    """The module docstring's energy rule, pixel by pixel: bands under epsilon * the pixel's peak dropped, energies
    lam^2 at log2 f = -(i + 1/2), cumulative from the coarsest band (from 0 one octave below its centre), linear in
    log2 f up to ``fraction`` of the total, capped at 0.5 cycles/pixel; 0 where the peak is at most ``floor``."""
    L, H, W = lam.shape
    out = np.zeros((H, W))
    for y in range(H):
        for x in range(W):
            v = lam[:, y, x]
            peak = v.max()
            if peak <= floor:
                continue
            e = np.where(v >= epsilon * peak, v, 0.0) ** 2
            pts_f = [-(L + 0.5) - 1.0]
            pts_c = [0.0]
            for i in range(L, 0, -1):         # coarsest band first
                pts_f.append(-(i + 0.5))
                pts_c.append(pts_c[-1] + e[i - 1])
            target = fraction * pts_c[-1]
            j = next(k for k in range(1, len(pts_c)) if pts_c[k] >= target * (1 - 1e-12))
            t = (target - pts_c[j - 1]) / (pts_c[j] - pts_c[j - 1])
            out[y, x] = min(2.0 ** (pts_f[j - 1] + t * (pts_f[j] - pts_f[j - 1])), 0.5)
    return out


def test_bands_under_epsilon_are_dropped_from_the_energy_rule():
    """Eq. 7's significance test drops (zeroes) the bands under epsilon * peak: with epsilon = 0.2 the bandwidth is the
    docstring's energy rule over the kept bands only, re-done by hand pixel by pixel from band_maxima."""
    n = 32
    yy, xx = np.mgrid[0:n, 0:n].astype(np.float64)
    img = (xx > 13).astype(np.float64) + 0.5 * np.sin(2 * np.pi * 0.02 * xx * xx / 4)   # a step and a chirp
    lam = band_maxima(img, levels=5)
    eps = 0.2
    want = _energy_rule_by_hand(lam, eps, floor=eps * lam.max())
    got = local_bandwidth(img, epsilon=eps, levels=5)
    assert np.count_nonzero(want) > n * n // 2
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12)


def test_eq7_level_is_where_the_finer_bands_sum_reaches_epsilon_of_the_peak():
    """Eq. 7 as the docstring reads it, by hand from band_maxima: I_w is the finest band i for which the sum of
    lambda_k^max over bands k = 1..i reaches epsilon * the pixel's peak; bandwidth 2^-I_w (a sum, not one band)."""
    n, lev, eps = 32, 5, 0.2
    rng = np.random.default_rng(5)
    yy, xx = np.mgrid[0:n, 0:n] - (n - 1) / 2
    img = np.exp(-(xx ** 2 + yy ** 2) / (2 * 6.0 ** 2)) + 0.02 * rng.standard_normal((n, n))
    lam = band_maxima(img, levels=lev)
    want = np.zeros((n, n))
    for y in range(n):
        for x in range(n):
            v = lam[:, y, x]
            if v.max() <= eps * lam.max():
                continue
            i = next(i for i in range(1, lev + 1) if v[:i].sum() >= eps * v.max())
            want[y, x] = 2.0 ** -i
    got = local_bandwidth(img, epsilon=eps, levels=lev, rule="eq7")
    assert len(np.unique(want)) >= 2
    np.testing.assert_array_equal(got, want)


# two Gaussian blobs, (sigma, centre x, centre y), far enough apart that neither reaches the other's 1% contour
MIRROR_BLOBS = ((4.0, 40, 44), (8.0, 84, 80))


@pytest.mark.parametrize("wavelet, ratio_max", [("sym8", 1.5), ("db4", 2.0)])
def test_a_mirrored_blob_reads_the_mirrored_bandwidth(wavelet, ratio_max):
    """A Gaussian blob's mirror image has the mirrored local frequencies, so its bandwidth, mirrored back, reads what
    the blob's does, up to the asymmetry of the wavelet: within 1.5x for sym8 (least asymmetric) and within the
    estimator's factor 2 for db4, over the pixels the blobs cover.  (With the bands off-centre, session 57, the
    ratio reached 1.9x with sym8 and 3.0x with db4.)  Each blob's own bandwidth is held to its closed form first: the
    power spectrum exp(-4 pi^2 sigma^2 f^2) of a Gaussian of width sigma holds 95% of its energy below
    1.96 / (2 sqrt(2) pi sigma) along an axis, and the estimator reads known frequencies within a factor 2.  The two
    blobs' widths differ by 2x, and so must their bandwidths (their medians within 25% of that ratio; measured 1.96
    and 1.97), so that no bandwidth blind to where it looks, a constant for one, passes the mirror check."""
    n = 128
    ys, xs = np.mgrid[0:n, 0:n]
    blobs = [np.exp(-((xs - x) ** 2 + (ys - y) ** 2) / (2 * sigma ** 2)) for sigma, x, y in MIRROR_BLOBS]
    img = sum(blobs)
    b = local_bandwidth(img, wavelet=wavelet)
    medians = []
    for (sigma, _, _), blob in zip(MIRROR_BLOBS, blobs):
        inside = blob > 0.01
        f95 = 1.96 / (2.0 * math.sqrt(2.0) * math.pi * sigma)
        assert f95 / 2 <= b[inside].min() and b[inside].max() <= 2 * f95, (sigma, f95, b[inside].min(), b[inside].max())
        medians.append(np.median(b[inside]))
    want = MIRROR_BLOBS[1][0] / MIRROR_BLOBS[0][0]
    assert abs(medians[0] / medians[1] / want - 1.0) <= 0.25, medians
    inside = img > 0.01
    for flip in (lambda a: a[:, ::-1], lambda a: a[::-1]):
        ratio = flip(local_bandwidth(flip(img), wavelet=wavelet))[inside] / b[inside]
        assert 1 / ratio_max <= ratio.min() and ratio.max() <= ratio_max, (ratio.min(), ratio.max())


def test_each_bands_energy_lies_over_the_impulse_it_describes():
    """The module's roll puts each band's coefficients over the pixels they describe (``_centre_shift``): for a
    unit impulse, the energy centroid of lambda_i^max in x and in y lies within a quarter of band i's finest period
    (2^(i-2) pixels, band i = 1 finest) of the impulse."""
    n = 256
    img = np.zeros((n, n))
    img[n // 2, n // 2] = 1.0
    lam = band_maxima(img, levels=6)
    ys, xs = np.mgrid[0:n, 0:n]
    for i, band in enumerate(lam, start=1):
        e = band ** 2
        off = ((e * xs).sum() / e.sum() - n // 2, (e * ys).sum() / e.sum() - n // 2)
        assert max(map(abs, off)) <= 2.0 ** (i - 2), (i, off)


@pytest.mark.parametrize("shape, channels, pad, levels", [
    ((61, 130), 1, ("latlong_pole", "wrap"), None),   # a lat-long map, as the renderer pads it
    ((40, 24), 3, "zero", None),                        # colour, zero-padded
    ((5, 3), 1, "reflect", 7),                          # a tiny image on 7 levels: the capped margin wraps
])
def test_band_maxima_equal_rolling_and_filtering_the_whole_padded_grid(shape, channels, pad, levels):
    """band_maxima reads each rolled detail only on the window around the image (memory: an 8192x4096 probe took
    250 B per texel when every detail was rolled whole).  Reference: pywt's swt2 of the same padded grid, each
    detail rolled whole by np.roll, maxima over channels and orientations, scipy's maximum_filter (the window
    clipped at the grid's edges), then cut out.  Bit for bit, the capped margin included, where the window reaches
    past the grid.  The 61 x 130 lat-long map's 122 rows across both poles and 130 columns reach a multiple of 2^7
    only far beyond the margin: its grid is one period of each, transformed circularly (_swt2_level, which its own
    tests check against pywt and the DFT), and the window and the filter wrap around it."""
    import pywt
    from scipy.ndimage import maximum_filter

    from precompute.wavelets import _centre_shift, _pad_axis, _swt2_level

    h, w = shape
    img = np.random.default_rng(4).random((h, w, channels)) ** 3
    nlev = levels or int(math.log2(max(h, w)))
    step = 2 ** nlev
    margin = min(7 * 2 ** (nlev - 1) // 2 + step, 4 * max(h, w))   # db4: 8 taps
    modes = (pad, pad) if isinstance(pad, str) else pad
    circular = modes == ("latlong_pole", "wrap")
    start = 0 if circular else margin
    padded = img
    for axis, (n, mode) in enumerate(zip((h, w), modes)):
        before, after = (0, n if mode == "latlong_pole" else 0) if circular else (margin, margin + (-(n + 2 * margin))
                                                                                  % step)
        padded = _pad_axis(padded, axis, before, after, mode)
    approx = np.moveaxis(padded, 2, 0)
    want = []
    for i in range(nlev):
        if circular:
            approx, (ch, cv, cd) = _swt2_level(approx, pywt.Wavelet("db4"), i)
        else:
            (approx, (ch, cv, cd)), = pywt.swt2(approx, "db4", level=1, start_level=i, axes=(-2, -1), norm=True)
        hi, lo = _centre_shift("db4", i)
        mag = np.max([np.roll(np.abs(d).max(axis=0), s, axis=(0, 1))
                      for d, s in ((ch, (hi, lo)), (cv, (lo, hi)), (cd, (hi, hi)))], axis=0)
        mag = maximum_filter(mag, size=2 ** (i + 1) + 1, mode="wrap" if circular else "constant", cval=-np.inf)
        want.append(mag[start:start + h, start:start + w])
    got = band_maxima(img, levels=levels, pad=pad)
    assert got.shape == (nlev, h, w)
    assert np.array_equal(got, np.array(want))


def test_the_bandwidth_reports_its_progress_band_by_band():
    img = sine(0.1, 30)
    calls = []
    lam = band_maxima(img, levels=4, progress=lambda k, n: calls.append((k, n)))
    assert calls == [(1, 4), (2, 4), (3, 4), (4, 4)]
    assert np.array_equal(lam, band_maxima(img, levels=4))
    calls.clear()
    b = local_bandwidth(img, levels=3, progress=lambda k, n: calls.append((k, n)))
    assert calls == [(1, 4), (2, 4), (3, 4), (4, 4)]   # three bands, then the energy rule
    assert np.array_equal(b, local_bandwidth(img, levels=3))


SEAM_XFAIL = ("session 76: an axis padded by edge/reflect/symmetric meets its other end's continuation where "
              "swt2 wraps the padded grid, one margin (352 texels) out, within the coarsest band's reach (792 "
              "texels); the fix (a margin past the reach for these modes) changes the BRDF tables and so the "
              "benchmark's frames")


@pytest.mark.xfail(strict=True, reason=SEAM_XFAIL)
@pytest.mark.parametrize("mode", ["edge", "reflect", "symmetric"])
def test_an_axis_continued_past_the_image_has_no_seam_where_the_padded_grid_wraps(mode):
    """``pad="edge"`` (``"reflect"``, ``"symmetric"``) reads the image continued by np.pad's rule without end.  Truth:
    the image padded by np.pad itself far beyond any wavelet's reach (1100 texels; band 7's details and its window
    reach 792), analysed on the same 7 bands and cut back: the bands must be the same.  Closed form for a step
    continued by its edge values: everything within 792 texels of a column left of 108 is 0, so those columns are
    flat (bandwidth 0).  The code's wrap joins the two ends' continuations 352 texels out (the fix is not applied:
    the xfail's reason), a step that band 7 reads (session 76, edge: columns 0-90 at 0.0053 cycles/pixel)."""
    w, x = 1024, np.arange(1024, dtype=np.float64)
    step, ramp = [np.repeat(a[None], 4, axis=0) for a in ((x >= 900).astype(np.float64), x / w)]
    for img in (step, ramp):
        far = np.pad(img, ((0, 0), (1100, 1100)), mode=mode)
        want = band_maxima(far, levels=7, pad=(mode, "zero"))[:, :, 1100:-1100]
        np.testing.assert_allclose(band_maxima(img, pad=mode), want, rtol=1e-9, atol=1e-12 * want.max())
    if mode == "edge":
        assert local_bandwidth(step, pad=mode)[:, :108].max() == 0.0


@pytest.mark.parametrize("h, w", [(256, 256), (128, 256), (64, 256)])
def test_envmap_reads_variation_along_a_texels_shorter_side_low_by_that_side_over_the_longer(h, w):
    """envmap_angular_bandwidth's docstring: longitudinal variation reads low by ``min(1, 2 H sin(theta) / W)`` and
    latitudinal by ``min(1, W / (2 H sin(theta)))``.  Truth: the closed forms, ``cos(m phi)`` varies at
    ``m / (2 pi sin(theta))`` cycles/radian and ``cos(k theta)`` at ``k / (2 pi)``; the estimator's own factor on a
    pure sine (cycles/pixel read over cycles/pixel painted) is taken out, since it is the same in every row of such a
    map.  Square, 2:1 and 4:1 maps (until session 76 the docstring gave ``sin(theta) W / (2 H)``, right on 2:1 maps
    only; plant: the code written to that factor, lambda_max = max(2 pi sin(theta) / W, 4 pi H / W^2), which is
    the same on a 2:1 map, fails the square and 4:1 ones)."""
    m, k = 12, 24
    theta = (np.arange(h) + 0.5) * math.pi / h
    phi = 2 * math.pi * (np.arange(w) + 0.5) / w
    rows = [int(np.argmin(abs(theta - math.radians(d)))) for d in (20, 40, 60, 90)]
    for img, true, pixel_f, low in (
            (np.cos(m * phi)[None, :] * np.ones((h, 1)), m / (2 * math.pi * np.sin(theta)), m / w,
             np.minimum(1.0, 2 * h * np.sin(theta) / w)),
            (np.cos(k * theta)[:, None] * np.ones((1, w)), np.full(h, k / (2 * math.pi)), k / (2 * h),
             np.minimum(1.0, w / (2 * h * np.sin(theta))))):
        nu = envmap_angular_bandwidth(img)[:, w // 3]
        factor = local_bandwidth(img, pad=("latlong_pole", "wrap"))[:, w // 3] / pixel_f   # the estimator's own
        for j in rows:
            np.testing.assert_allclose(nu[j] / true[j] / factor[j], low[j], rtol=1e-9)
