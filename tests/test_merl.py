"""MERL .binary reader/writer and lookups (warpbw.io.merl).

Truth comes from the data README's rules re-implemented here independently (a different formula
for the Rusinkiewicz difference vector: projection on the frame at h instead of two rotations),
from a closed-form BRDF written in this file, and from bytes patched into the file at offsets
computed from the README's layout.
"""
from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from conftest import ref_half_diff_angles
from warpbw.errors import WarpbwError
from warpbw.io.merl import (
    MERL_FILE_SIZE,
    MerlBRDF,
    dirs_from_half_diff,
    half_diff_from_dirs,
    horizon_bins,
    merl_bin_centres,
    merl_eval,
    merl_indices,
    read_merl,
    tabulate_merl,
    write_merl,
)

HALF_PI = math.pi / 2
SCALE = np.array([1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0])  # data README
N_BINS = 90 * 90 * 180


# ----------------------------------------------------------------- independent reference code


def ref_coords(wi, wo):
    """Continuous README bin coordinates (before floor) of each pair."""
    th, td, pd = ref_half_diff_angles(wi, wo)
    pd = np.where(pd < 0, pd + math.pi, pd)
    return np.sqrt(th / HALF_PI) * 90, td / HALF_PI * 90, pd / math.pi * 180


def ref_bins(wi, wo):
    """README bins and a mask of pairs safely away (1e-6 bins) from any bin boundary."""
    cs = ref_coords(wi, wo)
    idx = [np.clip(np.floor(c), 0, n - 1).astype(int) for c, n in zip(cs, (90, 90, 180))]
    frac = [c - np.floor(c) for c in cs]
    safe = np.all([(f > 1e-6) & (f < 1 - 1e-6) for f in frac], axis=0)
    return idx, safe


def ref_centre_dirs(i, j, k):
    """(wi, wo) at the centre of bin (i, j, k), phi_h = 0, by the README's bin-centre angles."""
    th = ((i + 0.5) / 90) ** 2 * HALF_PI
    td = (j + 0.5) / 90 * HALF_PI
    pd = (k + 0.5) / 180 * math.pi
    h = np.stack([np.sin(th), np.zeros_like(th), np.cos(th)], -1)
    u = np.stack([np.cos(th), np.zeros_like(th), -np.sin(th)], -1)
    v = np.stack([np.zeros_like(th), np.ones_like(th), np.zeros_like(th)], -1)
    wi = np.cos(td)[:, None] * h + np.sin(td)[:, None] * (np.cos(pd)[:, None] * u + np.sin(pd)[:, None] * v)
    wo = 2 * np.sum(wi * h, -1, keepdims=True) * h - wi
    return wi, wo


KD = np.array([0.1, 0.2, 0.3]) / math.pi
KS = np.array([1.0, 2.0, 3.0])
EXPONENT = np.array([20.0, 50.0, 100.0])
F0 = np.array([0.04, 0.5, 0.9])
KC = np.array([0.05, 0.1, 0.02])


def analytic_brdf(wi, wo):
    """Blinn-Phong lobe x Schlick Fresnel + a cos_i cos_o term (depends on all of theta_h, theta_d, phi_d)."""
    wi = wi / np.linalg.norm(wi, axis=-1, keepdims=True)
    wo = wo / np.linalg.norm(wo, axis=-1, keepdims=True)
    h = wi + wo
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    cos_h = np.clip(h[:, 2:3], 0, 1)
    cos_d = np.clip(np.sum(wi * h, -1, keepdims=True), 0, 1)
    fres = F0 + (1 - F0) * (1 - cos_d) ** 5
    ci, co = wi[:, 2:3], wo[:, 2:3]
    f = KD + KS * cos_h**EXPONENT * fres + KC * ci * co
    return np.where((ci > 0) & (co > 0), f, 0.0)


def hemisphere(rng, n, max_theta=HALF_PI):
    cos_t = rng.uniform(math.cos(max_theta), 1.0, n)
    phi = rng.uniform(-math.pi, math.pi, n)
    s = np.sqrt(1 - cos_t**2)
    return np.stack([s * np.cos(phi), s * np.sin(phi), cos_t], -1)


# ----------------------------------------------------------------- fixtures (few 35 MB writes)


@pytest.fixture(scope="module")
def analytic_table():
    return tabulate_merl(analytic_brdf, "analytic")


@pytest.fixture(scope="module")
def analytic_file(analytic_table, tmp_path_factory):
    path = tmp_path_factory.mktemp("merl") / "analytic.binary"
    write_merl(path, analytic_table)
    return path


@pytest.fixture(scope="module")
def analytic_brdf_read(analytic_file):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a clean table must read without an "unmeasured" warning
        return read_merl(analytic_file)


@pytest.fixture(scope="module")
def random_brdf():
    """In-memory table of unrelated random values: any bin mismatch shows as a different value."""
    rng = np.random.default_rng(7)
    data = rng.uniform(0.5, 1.5, (90, 90, 180, 3)).astype(np.float32)
    return MerlBRDF(name="random", path=None, data=data)


# ----------------------------------------------------------------- coordinates


def test_half_diff_matches_independent_formula():
    rng = np.random.default_rng(1)
    wi, wo = hemisphere(rng, 5000), hemisphere(rng, 5000)
    th, _, td, pd = half_diff_from_dirs(wi, wo)
    rth, rtd, rpd = ref_half_diff_angles(wi, wo)
    np.testing.assert_allclose(th, rth, atol=1e-9)
    np.testing.assert_allclose(td, rtd, atol=1e-7)  # arccos near 0 amplifies rounding
    dphi = np.angle(np.exp(1j * (pd - rpd)))
    assert np.all(np.abs(dphi) < 1e-6)


def test_half_diff_known_configurations():
    a = 0.3
    same = np.array([[math.sin(a), 0, math.cos(a)]])
    th, _, td, _ = half_diff_from_dirs(same, same)  # wi == wo: theta_h = angle, theta_d = 0
    assert th[0] == pytest.approx(a, abs=1e-12) and td[0] == pytest.approx(0, abs=1e-7)
    mirror = np.array([[-math.sin(a), 0, math.cos(a)]])
    th, _, td, pd = half_diff_from_dirs(same, mirror)  # mirror pair: h = normal, theta_d = angle
    assert th[0] == pytest.approx(0, abs=1e-12) and td[0] == pytest.approx(a, abs=1e-12)
    assert pd[0] == pytest.approx(0, abs=1e-12)


angle = st.floats(min_value=0.0, max_value=1.0, allow_nan=False)


@settings(max_examples=200, deadline=None)
@given(th=angle, ph=angle, td=angle, pd=angle)
def test_dirs_from_half_diff_round_trip(th, ph, td, pd):
    # keep both directions above the horizon and away from the poles where phi is undefined
    theta_h = 0.01 + th * 0.7
    theta_d = 0.01 + td * 0.7
    phi_h = -math.pi + 0.001 + ph * (2 * math.pi - 0.002)
    phi_d = -math.pi + 0.001 + pd * (2 * math.pi - 0.002)
    wi, wo = dirs_from_half_diff(theta_h, phi_h, theta_d, phi_d)
    assert wi[2] > 0 and wo[2] > 0
    np.testing.assert_allclose([np.linalg.norm(wi), np.linalg.norm(wo)], 1.0, atol=1e-12)
    got = half_diff_from_dirs(wi[None], wo[None])
    np.testing.assert_allclose([g[0] for g in got], [theta_h, phi_h, theta_d, phi_d], atol=1e-7)


def test_dirs_round_trip_from_directions():
    rng = np.random.default_rng(2)
    wi, wo = hemisphere(rng, 2000), hemisphere(rng, 2000)
    wi2, wo2 = dirs_from_half_diff(*half_diff_from_dirs(wi, wo))
    np.testing.assert_allclose(wi2, wi, atol=1e-7)
    np.testing.assert_allclose(wo2, wo, atol=1e-7)


def test_merl_indices_readme_rules():
    th = np.array([0.0, -0.1, HALF_PI, 2.0, (10.5 / 90) ** 2 * HALF_PI, (89.99 / 90) ** 2 * HALF_PI])
    i, _, _ = merl_indices(th, np.zeros_like(th), np.zeros_like(th))
    assert i.tolist() == [0, 0, 89, 89, 10, 89]
    td = np.array([0.0, 0.5 / 90 * HALF_PI, 45.5 / 90 * HALF_PI, HALF_PI, -0.2])
    _, j, _ = merl_indices(np.zeros_like(td), td, np.zeros_like(td))
    assert j.tolist() == [0, 0, 45, 89, 0]
    pd = np.array([0.0, 0.5 / 180 * math.pi, math.pi, -0.5 / 180 * math.pi, -math.pi + 1e-9, 100.5 / 180 * math.pi])
    _, _, k = merl_indices(np.zeros_like(pd), np.zeros_like(pd), pd)
    assert k.tolist() == [0, 0, 179, 179, 0, 100]


def test_bin_centres():
    th, td, pd = merl_bin_centres()
    assert th.shape == (90,) and td.shape == (90,) and pd.shape == (180,)
    np.testing.assert_allclose(th[[0, 89]], [(0.5 / 90) ** 2 * HALF_PI, (89.5 / 90) ** 2 * HALF_PI])
    np.testing.assert_allclose(pd[[0, 179]], [0.5 / 180 * math.pi, 179.5 / 180 * math.pi])
    i, j, k = merl_indices(th, td[:90], pd[:90])
    assert i.tolist() == list(range(90)) and j.tolist() == list(range(90)) and k.tolist() == list(range(90))


# ----------------------------------------------------------------- file round trip


def test_write_read_round_trip_random_directions(analytic_brdf_read):
    brdf = analytic_brdf_read
    assert brdf.data.shape == (90, 90, 180, 3) and brdf.data.dtype == np.float32
    assert brdf.n_unmeasured == 0 and brdf.unmeasured is None
    rng = np.random.default_rng(3)
    wi, wo = hemisphere(rng, 20000), hemisphere(rng, 20000)
    (i, j, k), safe = ref_bins(wi, wo)
    assert safe.mean() > 0.99
    safe &= ~horizon_bins()[i, j, k]   # those hold a mean over the bin (test_tabulate_near_the_horizon_...)
    assert safe.mean() > 0.9
    wi, wo, i, j, k = wi[safe], wo[safe], i[safe], j[safe], k[safe]
    truth = analytic_brdf(*ref_centre_dirs(i, j, k))
    got = merl_eval(brdf, wi, wo)
    assert got.shape == truth.shape
    np.testing.assert_allclose(got, truth, rtol=1e-6, atol=1e-30)
    assert np.count_nonzero(truth > 1.0) > 10  # the sample reached the glossy lobe


def test_file_layout_and_scale(analytic_file, analytic_table):
    """Header ints and the flat index ((i*90)+j)*180+k per channel, values divided by the README scales."""
    head = np.fromfile(analytic_file, dtype="<i4", count=3)
    assert head.tolist() == [90, 90, 180]
    assert analytic_file.stat().st_size == 34_992_012
    rng = np.random.default_rng(4)
    i, j, k, c = rng.integers(0, 90, 50), rng.integers(0, 90, 50), rng.integers(0, 180, 50), rng.integers(0, 3, 50)
    flat = c * N_BINS + (i * 90 + j) * 180 + k
    raw = np.fromfile(analytic_file, dtype="<f8", offset=12)[flat]
    np.testing.assert_allclose(raw * SCALE[c], analytic_table[i, j, k, c], rtol=1e-14)


def test_interpolation_at_centres(analytic_brdf_read):
    brdf = analytic_brdf_read
    rng = np.random.default_rng(5)
    i, j, k = rng.integers(0, 60, 500), rng.integers(0, 60, 500), rng.integers(0, 180, 500)
    wi, wo = ref_centre_dirs(i, j, k)
    truth = analytic_brdf(wi, wo)
    np.testing.assert_allclose(merl_eval(brdf, wi, wo, interpolate=True), truth, rtol=1e-5, atol=1e-12)


def test_interpolation_is_trilinear_with_phi_wrap(random_brdf):
    """Against scipy's RegularGridInterpolator on the table padded periodically in phi_d."""
    from scipy.interpolate import RegularGridInterpolator

    data = random_brdf.data.astype(np.float64)
    padded = np.concatenate([data[:, :, -1:], data, data[:, :, :1]], axis=2)  # phi_d period pi
    rgi = RegularGridInterpolator((np.arange(90.0), np.arange(90.0), np.arange(-1.0, 181.0)), padded)
    rng = np.random.default_rng(8)
    wi, wo = hemisphere(rng, 5000), hemisphere(rng, 5000)
    u_h, u_d, u_p = ref_coords(wi, wo)
    pts = np.stack([np.clip(u_h - 0.5, 0, 89), np.clip(u_d - 0.5, 0, 89), u_p - 0.5], -1)
    np.testing.assert_allclose(merl_eval(random_brdf, wi, wo, interpolate=True), rgi(pts), rtol=1e-6, atol=1e-9)
    # phi_d = 0 at bin centres in theta_h, theta_d lies halfway between phi bins 179 and 0
    i = np.arange(50)
    j = (7 * i) % 50  # theta_h + theta_d < 90 degrees: both directions above the horizon
    si, so = dirs_from_half_diff(((i + 0.5) / 90) ** 2 * HALF_PI, 0.3, (j + 0.5) / 90 * HALF_PI, 1e-12)
    expected = 0.5 * (data[i, j, 179] + data[i, j, 0])
    np.testing.assert_allclose(merl_eval(random_brdf, si, so, interpolate=True), expected, rtol=1e-6)


def test_negative_table_values_never_returned():
    """A hand-built table with negative entries (not zeroed by read_merl) still never shades negative."""
    data = -np.ones((90, 90, 180, 3), np.float32)
    brdf = MerlBRDF(name="neg", path=None, data=data)
    rng = np.random.default_rng(9)
    wi, wo = hemisphere(rng, 100), hemisphere(rng, 100)
    for interp in (False, True):
        assert np.all(merl_eval(brdf, wi, wo, interpolate=interp) == 0.0)


def test_below_horizon_is_zero(random_brdf):
    wi = np.array([[0.0, 0.6, 0.8], [0.6, 0.0, -0.8], [1.0, 0.0, 0.0]])
    wo = np.array([[0.0, -0.6, -0.8], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    for interp in (False, True):
        assert np.all(merl_eval(random_brdf, wi, wo, interpolate=interp) == 0.0)


def _sph(t, p):
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


theta_above = st.floats(min_value=0.0, max_value=HALF_PI - 1e-6, allow_nan=False)
phi_any = st.floats(min_value=-math.pi, max_value=math.pi, allow_nan=False)


@settings(max_examples=400, deadline=None)
@given(ti=theta_above, pi_=phi_any, to=theta_above, po=phi_any)
@example(ti=0.7, pi_=0.0, to=0.7, po=math.pi)  # mirror pair in the plane: phi_d on the 0/pi seam
@example(ti=0.3, pi_=0.2, to=1.1, po=0.2 + math.pi)  # in-plane, not mirror
@example(ti=0.5, pi_=1.0, to=0.5, po=1.0)  # wi == wo
@example(ti=0.0, pi_=0.0, to=0.9, po=2.0)  # normal incidence
@example(ti=0.0, pi_=0.0, to=0.0, po=-2.0)  # wi == wo == normal up to signed zeros (0 vs pi in atan2)
def test_reciprocity(random_brdf, ti, pi_, to, po):
    wi, wo = _sph(ti, pi_)[None], _sph(to, po)[None]
    for interp in (False, True):
        a = merl_eval(random_brdf, wi, wo, interpolate=interp)
        b = merl_eval(random_brdf, wo, wi, interpolate=interp)
        assert np.array_equal(a, b), (interp, a, b)


@settings(max_examples=60, deadline=None)
@given(ti=theta_above, pi_=phi_any, to=theta_above, po=phi_any, turn=phi_any)
# both within 1e-5 of the normal, phi_d on the bin boundary at pi / 2: the reference's arccos judged it 1.5e-4 of a bin
# away from it (session 81, a draw of hypothesis's)
@example(ti=1e-5, pi_=0.0, to=1e-5, po=1.0, turn=1.0)
# wi and wo mirrored about the normal: theta_h is 0 and phi_h whatever h's rounding says, so phi_d, measured from it, is
# undefined too (session 82, a draw of hypothesis's in the whole suite's run)
@example(ti=1.0, pi_=0.0, to=1.0, po=3.1415926535897927, turn=1.0)
def test_turning_both_directions_about_the_normal_changes_nothing_but_phi_h(random_brdf, ti, pi_, to, po, turn):
    """Isotropy: turning wi and wo together by any angle about the normal (+Z) keeps theta_h, theta_d and phi_d
    (Rusinkiewicz's difference vector lives in the frame of h) and adds the angle to phi_h, so a table of unrelated
    random values looks up the same value: trilinear to rounding, nearest wherever the pair is not within 1e-6 of a
    bin boundary (by the README's bins, conftest's reference).  Rounding moves phi_d by ~1e-16 / sin(theta_d), so
    the lookups are compared where sin(theta_d) > 1e-6 (at most ~1e-8 of a bin)."""
    c, s = math.cos(turn), math.sin(turn)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    wi, wo = _sph(ti, pi_)[None], _sph(to, po)[None]
    th, ph, td, pd = (float(x[0]) for x in half_diff_from_dirs(wi, wo))
    th2, ph2, td2, pd2 = (float(x[0]) for x in half_diff_from_dirs(wi @ rot.T, wo @ rot.T))
    assert (th2, td2) == pytest.approx((th, td), abs=1e-7)
    if not math.sin(th) > 1e-6:   # phi_h at the normal is undefined, and phi_d, measured from it, with it
        return
    assert math.remainder(ph2 - ph - turn, 2 * math.pi) == pytest.approx(0.0, abs=1e-6)
    if not math.sin(td) > 1e-6:   # phi_d of wi == wo (theta_d = 0) is undefined: rounding picks any
        return
    assert math.remainder(pd2 - pd, 2 * math.pi) == pytest.approx(0.0, abs=1e-6)
    a = merl_eval(random_brdf, wi, wo, interpolate=True)
    b = merl_eval(random_brdf, wi @ rot.T, wo @ rot.T, interpolate=True)
    np.testing.assert_allclose(b, a, rtol=1e-5, atol=1e-9)
    (_, safe), (_, safe2) = ref_bins(wi, wo), ref_bins(wi @ rot.T, wo @ rot.T)
    if safe[0] and safe2[0]:
        np.testing.assert_array_equal(merl_eval(random_brdf, wi @ rot.T, wo @ rot.T), merl_eval(random_brdf, wi, wo))


def test_unmeasured_entries_counted_and_never_negative(analytic_table, tmp_path):
    data = analytic_table.copy()
    rng = np.random.default_rng(6)
    flat = rng.choice(data.size, 1000, replace=False)
    data.reshape(-1)[flat] = -1.0
    path = tmp_path / "holes.binary"
    write_merl(path, analytic_table)
    with pytest.raises(WarpbwError, match="already exists"):
        write_merl(path, data)
    write_merl(path, data, force=True)
    # patch two NaNs and one known positive value straight into the bytes (README layout)
    nan_at = [(5, 6, 7, 0), (80, 10, 170, 2)]
    val_at, value = (12, 34, 56, 1), 3.0
    with open(path, "r+b") as fh:
        for (i, j, k, c), v in [(p, np.nan) for p in nan_at] + [(val_at, value)]:
            fh.seek(12 + 8 * (c * N_BINS + (i * 90 + j) * 180 + k))
            fh.write(np.float64(v).astype("<f8").tobytes())
    neg = data < 0
    expected_bad = int(neg.sum()) + sum(not neg[p] for p in nan_at)
    with pytest.warns(RuntimeWarning, match=str(expected_bad)):
        brdf = read_merl(path)
    assert brdf.n_unmeasured == expected_bad
    expected_mask = neg.copy()
    for p in nan_at:
        expected_mask[p] = True
    assert np.array_equal(brdf.unmeasured, expected_mask)
    assert np.all(brdf.data[expected_mask] == 0.0) and np.all(brdf.data >= 0.0)
    assert brdf.data[val_at] == pytest.approx(value * SCALE[1], rel=1e-7)
    # lookups at the centres of unmeasured bins give 0 in that channel, never a negative number
    idx = np.argwhere(expected_mask)
    wi, wo = ref_centre_dirs(idx[:, 0], idx[:, 1], idx[:, 2])
    above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    for interp in (False, True):
        got = merl_eval(brdf, wi[above], wo[above], interpolate=interp)
        assert np.all(got >= 0.0)
    got = merl_eval(brdf, wi[above], wo[above])
    assert np.all(got[np.arange(len(got)), idx[above, 3]] == 0.0)
    hs = hemisphere(rng, 5000)
    assert np.all(merl_eval(brdf, hs, hemisphere(rng, 5000), interpolate=True) >= 0.0)


# ----------------------------------------------------------------- bad input


def test_truncated_file_refused(tmp_path):
    path = tmp_path / "short.binary"
    path.write_bytes(np.asarray([90, 90, 180], "<i4").tobytes() + b"\0" * 4000)
    with pytest.raises(WarpbwError) as ei:
        read_merl(path)
    msg = str(ei.value)
    assert str(path) in msg and str(MERL_FILE_SIZE) in msg and "4012" in msg and "\n" not in msg
    assert "NPF" not in msg
    # an NPF table given as a MERL file (both are "brdf" files in ../shared/data): the message says what it is
    from warpbw.io.npf import NPF_FILE_SIZE

    npf = tmp_path / "npf.bin"
    npf.write_bytes(b"\0" * NPF_FILE_SIZE)
    with pytest.raises(WarpbwError, match=r"npf\.bin: expected .* got 1572864 -- the size of an NPF table: a material "
                       r"reads it with type = \"npf\""):
        read_merl(npf)


def test_bad_header_refused(tmp_path):
    path = tmp_path / "wrongdims.binary"
    with open(path, "wb") as fh:  # right size (sparse), wrong dims
        fh.write(np.asarray([90, 90, 360], "<i4").tobytes())
        fh.truncate(MERL_FILE_SIZE)
    with pytest.raises(WarpbwError, match="wrongdims.binary.*90, 90, 180"):
        read_merl(path)


@pytest.mark.parametrize("kind, said", [
    ("float32", r"got 17496012 -- the size of a MERL table of float32 values \(MERL's files hold float64"),
    ("phi360", r"got 69984012 -- the size of a table of 360 phi_d bins"),
    ("headerless", r"got 34992000 -- the size of MERL's values without their 12-byte header"),
    ("gzip", r"got \d+ -- a gzip-compressed file: decompress it first"),
    ("big-endian", r"header dims \(1509949440, 1509949440, -1275068416\), expected \(90, 90, 180\) "
                   r"\(MERL \.binary\) -- a big-endian file: MERL's are little-endian")])
def test_files_other_tools_write_in_merls_place_are_named_for_what_they_are(tmp_path, kind, said):
    """What a user's MERL file may differ in, told by its size or header (the data README's layout and BRDFRead.cpp's
    constants are the truth): float32 values, all 360 phi_d bins, no header, gzip compression, big-endian.  Each was
    refused before with the bare size or header, not what the file is."""
    import gzip

    path = tmp_path / f"{kind}.binary"
    n = 3 * 90 * 90 * 180
    if kind == "gzip":
        path.write_bytes(gzip.compress(np.asarray([90, 90, 180], "<i4").tobytes() + bytes(1000)))
    elif kind == "big-endian":
        with open(path, "wb") as fh:
            fh.write(np.asarray([90, 90, 180], ">i4").tobytes())
            fh.truncate(MERL_FILE_SIZE)
    else:
        size = {"float32": 12 + 4 * n, "phi360": 12 + 16 * n, "headerless": 8 * n}[kind]
        with open(path, "wb") as fh:
            fh.write(np.asarray([90, 90, 180], "<i4").tobytes())
            fh.truncate(size)
    with pytest.raises(WarpbwError, match=said):
        read_merl(path)


def test_missing_file(tmp_path):
    with pytest.raises(WarpbwError, match="nope.binary"):
        read_merl(tmp_path / "nope.binary")


def test_write_refuses_overwrite_and_bad_shape(analytic_file, tmp_path):
    size_before = analytic_file.stat().st_mtime_ns
    with pytest.raises(WarpbwError, match="already exists"):
        write_merl(analytic_file, np.full((90, 90, 180, 3), 0.1))
    assert analytic_file.stat().st_mtime_ns == size_before
    with pytest.raises(WarpbwError, match=r"x.binary.*\(90, 90, 180, 3\)"):
        write_merl(tmp_path / "x.binary", np.zeros((90, 90, 90, 3)))
    bad = np.zeros((90, 90, 180, 3))
    bad[1, 2, 3, 0] = np.inf
    with pytest.raises(WarpbwError, match="non-finite"):
        write_merl(tmp_path / "y.binary", bad)
    assert not (tmp_path / "y.binary").exists()


def inverse_cosines(wi, wo):
    """1 / (cos_i cos_o) above the horizon, 0 below: the factor NPF's model has (its 1e-5 clamp of the cosines)."""
    ci, co = wi[:, 2], wo[:, 2]
    return np.where((ci > 0) & (co > 0), 1.0 / (np.maximum(ci, 1e-5) * np.maximum(co, 1e-5)), 0.0)


def test_horizon_bins_match_brute_force():
    """horizon_bins() against 7^3 points on each box (faces included) of 4000 random bins: some pair above the horizon
    (both cosines > 0) and some at or below it."""
    rng = np.random.default_rng(11)
    idx = np.stack([rng.integers(0, 90, 4000), rng.integers(0, 90, 4000), rng.integers(0, 180, 4000)], 1)
    q = np.arange(7) / 6.0
    i, j, k = (a[:, None, None, None] for a in idx.T)
    th, td, pd = np.broadcast_arrays(((i + q[:, None, None]) / 90) ** 2 * HALF_PI, (j + q[:, None]) / 90 * HALF_PI,
                                     (k + q) / 180 * math.pi)
    h = np.stack([np.sin(th), np.zeros_like(th), np.cos(th)], -1)
    u = np.stack([np.cos(th), np.zeros_like(th), -np.sin(th)], -1)
    v = np.broadcast_to(np.array([0.0, 1.0, 0.0]), h.shape)
    wi = np.cos(td)[..., None] * h + np.sin(td)[..., None] * (np.cos(pd)[..., None] * u + np.sin(pd)[..., None] * v)
    wo = 2 * np.sum(wi * h, -1, keepdims=True) * h - wi
    low = np.minimum(wi[..., 2], wo[..., 2]).reshape(len(idx), -1)
    truth = (low.max(axis=1) > 1e-12) & (low.min(axis=1) <= 1e-12)
    assert truth.sum() > 50
    np.testing.assert_array_equal(horizon_bins()[idx[:, 0], idx[:, 1], idx[:, 2]], truth)


def test_tabulate_near_the_horizon_stays_near_the_function():
    """A bin the horizon cuts held its centre's value, which may lie a hair above the horizon: f = 1 / (cos_i cos_o)
    (NPF's factor) read 2000x its value at pairs above the horizon with cos_o 0.005 to 0.05, and 0 at others (a
    centre below), where the benchmark's ccp3 sphere made a firefly of 25 at a pixel of 0.02 (session 69).  The
    cos-weighted mean over such a bin stays within a factor 20 of f at every pair tried."""
    table = tabulate_merl(inverse_cosines, "inverse cosines")
    brdf = MerlBRDF(name="inverse cosines", path=None, data=table.astype(np.float32))
    rng = np.random.default_rng(5)
    wo = hemisphere(rng, 50000, math.acos(0.005))
    wo = wo[wo[:, 2] < 0.05]
    wi = hemisphere(rng, len(wo), math.acos(0.005))
    ratio = merl_eval(brdf, wi, wo)[:, 0] / inverse_cosines(wi, wo)
    assert len(ratio) > 1000
    assert ratio.min() > 0.05 and ratio.max() < 20.0, (ratio.min(), ratio.max())


def test_tabulate_rejects_non_finite():
    def bad(wi, wo):
        return np.where(wi[:, :1] > 0.5, np.nan, 1.0) * np.ones((len(wi), 3))

    with pytest.raises(WarpbwError, match="mybrdf.*non-finite"):
        tabulate_merl(bad, "mybrdf")
