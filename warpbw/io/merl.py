"""MERL ``.binary`` measured isotropic BRDFs: read, write, look up, tabulate.

Public functions:

- ``read_merl(path) -> MerlBRDF``: scaled linear BRDF values (1/sr), unmeasured entries zeroed and counted.
- ``write_merl(path, data, force=False, inputs=()) -> Path``: the inverse (MERL channel scales undone, float64);
  never over one of ``inputs`` or a read-only file.
- ``half_diff_from_dirs(wi, wo) -> (theta_h, phi_h, theta_d, phi_d)``: Rusinkiewicz (1998) coordinates.
- ``dirs_from_half_diff(theta_h, phi_h, theta_d, phi_d) -> (wi, wo)``: their inverse.
- ``merl_indices(theta_h, theta_d, phi_d) -> (i_th, i_td, i_pd)``: the MERL binning rules.
- ``merl_bin_centres() -> (theta_h (90,), theta_d (90,), phi_d (180,))``: angle at each bin's centre.
- ``merl_eval(brdf, wi, wo, interpolate=False) -> (N, 3)``: host reference lookup, 0 below the horizon.
- ``tabulate_merl(func, name) -> (90, 90, 180, 3)``: an analytic / fitted BRDF sampled at the bin centres (a
  cos-weighted mean over the bins the horizon cuts, ``horizon_bins() -> (90, 90, 180) bool``).

Class: ``MerlBRDF``. Constants: ``MERL_THETA_H_RES``, ``MERL_THETA_D_RES``, ``MERL_PHI_D_RES``,
``MERL_SCALE``, ``MERL_FILE_SIZE``, ``HORIZON_SUBSAMPLES``, ``TABULATION_VERSION``.

Format and binning follow the MERL database's ``BRDFRead.cpp`` (Matusik et al. 2003) as restated
in ``../shared/data/README.md``. Directions point away from the surface, +Z is the normal.  The scaled values are
taken as linear Rec. 709 RGB, the renderer's (the files declare no colour space).
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from warpbw.errors import (BRDF_VALUE_MAX, WarpbwError, check_direction_pairs, check_flag, check_input_file,
                           check_path, numeric_array)
from warpbw.io.staged import check_replaceable, staged_outputs

# Table resolution of the MERL database (BRDFRead.cpp: BRDF_SAMPLING_RES_THETA_H = 90,
# BRDF_SAMPLING_RES_THETA_D = 90, BRDF_SAMPLING_RES_PHI_D = 360 of which 180 are stored).
MERL_THETA_H_RES = 90
MERL_THETA_D_RES = 90
MERL_PHI_D_RES = 180
# Per-channel scale applied on reading (BRDFRead.cpp: RED_SCALE, GREEN_SCALE, BLUE_SCALE).
MERL_SCALE = (1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0)
MERL_N_BINS = MERL_THETA_H_RES * MERL_THETA_D_RES * MERL_PHI_D_RES  # 1,458,000 per channel
MERL_HEADER_BYTES = 12  # three int32 dims (data README, "MERL .binary format")
MERL_FILE_SIZE = MERL_HEADER_BYTES + 3 * MERL_N_BINS * 8  # 34,992,012 bytes: float64 values
MERL_SHAPE = (MERL_THETA_H_RES, MERL_THETA_D_RES, MERL_PHI_D_RES, 3)
_HALF_PI = 0.5 * np.pi
# Files other tools write in MERL's place, by their size, and what read_merl says of them (ours): the values as
# float32, a table of all 360 phi_d bins (MERL's BRDF_SAMPLING_RES_PHI_D; its files store 180, by reciprocity), and
# the values without the header.  A gzip-compressed file is told by its first two bytes (RFC 1952).
_FOREIGN_SIZES = {
    MERL_HEADER_BYTES + 3 * MERL_N_BINS * 4: " -- the size of a MERL table of float32 values (MERL's files hold "
                                             "float64: convert it)",
    MERL_HEADER_BYTES + 3 * MERL_N_BINS * 2 * 8: " -- the size of a table of 360 phi_d bins (MERL's files store the "
                                                 "180 of [0, pi), phi_d folded by reciprocity)",
    3 * MERL_N_BINS * 8: " -- the size of MERL's values without their 12-byte header (three int32: 90, 90, 180)",
}
_GZIP_MAGIC = b"\x1f\x8b"
# theta_h rows evaluated per call of the user's BRDF in tabulate_merl (bounds memory: ~146k pairs).
_TABULATE_ROWS_PER_CHUNK = 9
# Points per axis of a bin the horizon cuts, averaged by tabulate_merl (ours).  Its centre's value alone was no value
# of the bin: color-changing-paint3's NPF fit written as MERL held 287.7 at bin (29, 85, 117), whose centre has
# cos_o = 2.7e-5, where the fit over the part of that bin a view at theta_o = 89.6 degrees reaches is 0.88 to 1.13.
# A sample of the benchmark's ccp3 sphere that read it made a firefly of 25 (its silhouette pixel's mean: 0.02),
# and 4x one 16-spp run's MSE (session 69).  Weighted by cos_i cos_o, the mean stays finite under the 1 / (cos_i
# cos_o) of the fit.
HORIZON_SUBSAMPLES = 4
# What tabulate_merl writes, for whoever keeps its files as a cache (examples/bench_scenes.py): 2, the horizon bins'
# weighted means (session 69); 1, every bin its centre's value.  A MERL file has no header to say it.
TABULATION_VERSION = 2
_HORIZON_BINS_PER_CHUNK = 2048   # horizon bins per call of the BRDF (x HORIZON_SUBSAMPLES^3 pairs)


@dataclass
class MerlBRDF:
    """A MERL table: ``data`` (90, 90, 180, 3) float32, already scaled to BRDF values (1/sr).

    ``n_unmeasured`` counts entries (over all 3 channels) stored as negative (or non-finite) numbers;
    they are 0 in ``data`` and True in ``unmeasured`` (None when there are none).
    """

    name: str
    path: str | None
    data: np.ndarray
    n_unmeasured: int = 0
    unmeasured: np.ndarray | None = None


# --------------------------------------------------------------------------- coordinates


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 0.0, n, 1.0)


def _half_diff_xyz(wi, wo):
    """theta_h, phi_h and the difference vector d = (dx, dy, dz), computed symmetrically in (wi, wo).

    d is Rusinkiewicz's: wi rotated by -phi_h about z, then by -theta_h about y. Mathematically
    rotating wo the same way gives (-dx, -dy, dz); averaging the two makes swapping wi and wo negate
    (dx, dy) exactly and keep dz and theta_h bit-identical, so lookups are exactly reciprocal.
    """
    wi, wo = np.broadcast_arrays(_unit(wi), _unit(wo))
    s = wi + wo
    n = np.linalg.norm(s, axis=-1, keepdims=True)
    h = np.where(n > 0.0, s / np.where(n > 0.0, n, 1.0), np.array([0.0, 0.0, 1.0]))
    theta_h = np.arccos(np.clip(h[..., 2], -1.0, 1.0))
    phi_h = np.arctan2(h[..., 1], h[..., 0])
    cp, sp = np.cos(phi_h), np.sin(phi_h)
    ct, st = np.cos(theta_h), np.sin(theta_h)

    def rot(w):
        # rotate by -phi_h about z
        x = w[..., 0] * cp + w[..., 1] * sp
        y = -w[..., 0] * sp + w[..., 1] * cp
        z = w[..., 2]
        # rotate by -theta_h about y (Rodrigues about (0, 1, 0))
        return x * ct - z * st, y, z * ct + x * st

    xi, yi, zi = rot(wi)
    xo, yo, zo = rot(wo)
    return theta_h, phi_h, 0.5 * (xi - xo), 0.5 * (yi - yo), 0.5 * (zi + zo)


def half_diff_from_dirs(wi, wo):
    """Rusinkiewicz half/difference angles of direction pairs (..., 3) (normalised here).

    Returns ``(theta_h, phi_h, theta_d, phi_d)``, phi in (-pi, pi]: h = normalize(wi + wo);
    d = wi rotated by -phi_h about z then by -theta_h about y.
    """
    a, b = check_direction_pairs(wi, wo)   # (N, 3) or a clear error; then back to the inputs' own shape
    shape = np.broadcast_shapes(np.shape(wi), np.shape(wo))
    theta_h, phi_h, dx, dy, dz = _half_diff_xyz(a.reshape(shape), b.reshape(shape))
    return theta_h, phi_h, np.arccos(np.clip(dz, -1.0, 1.0)), np.arctan2(dy, dx)


def dirs_from_half_diff(theta_h, phi_h, theta_d, phi_d):
    """Inverse of :func:`half_diff_from_dirs`: unit ``(wi, wo)``, arrays of shape (..., 3)."""
    theta_h, phi_h, theta_d, phi_d = np.broadcast_arrays(
        *(np.asarray(a, dtype=np.float64) for a in (theta_h, phi_h, theta_d, phi_d))
    )
    d = np.stack([np.sin(theta_d) * np.cos(phi_d), np.sin(theta_d) * np.sin(phi_d), np.cos(theta_d)], -1)
    ct, st = np.cos(theta_h), np.sin(theta_h)
    cp, sp = np.cos(phi_h), np.sin(phi_h)
    # rotate by +theta_h about y, then by +phi_h about z
    x1 = d[..., 0] * ct + d[..., 2] * st
    z1 = d[..., 2] * ct - d[..., 0] * st
    y1 = d[..., 1]
    wi = np.stack([x1 * cp - y1 * sp, x1 * sp + y1 * cp, z1], -1)
    h = np.stack([st * cp, st * sp, ct], -1)
    wo = 2.0 * np.sum(wi * h, axis=-1, keepdims=True) * h - wi
    return wi, wo


def _finite_or_zero(x) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    return np.where(np.isfinite(x), x, 0.0)


def merl_indices(theta_h, theta_d, phi_d):
    """MERL bin indices (int64 arrays), exactly the data README's rules.

    i_th = floor(sqrt(theta_h / (pi/2)) * 90) (theta_h <= 0 -> 0); i_td = floor(theta_d / (pi/2) * 90);
    phi_d folded into [0, pi) by adding pi when negative, i_pd = floor(phi_d / pi * 180); all clamped.
    """
    th, td, pd = (_finite_or_zero(a) for a in (theta_h, theta_d, phi_d))
    i_th = np.where(th <= 0.0, 0.0, np.floor(np.sqrt(np.maximum(th, 0.0) / _HALF_PI) * MERL_THETA_H_RES))
    i_td = np.floor(td / _HALF_PI * MERL_THETA_D_RES)
    pd = np.where(pd < 0.0, pd + np.pi, pd)
    i_pd = np.floor(pd / np.pi * MERL_PHI_D_RES)
    return (
        np.clip(i_th, 0, MERL_THETA_H_RES - 1).astype(np.int64),
        np.clip(i_td, 0, MERL_THETA_D_RES - 1).astype(np.int64),
        np.clip(i_pd, 0, MERL_PHI_D_RES - 1).astype(np.int64),
    )


def merl_bin_centres():
    """Angles (radians) at the centre of each bin: theta_h (90,) (square-root spacing), theta_d (90,), phi_d (180,)."""
    i = np.arange(MERL_THETA_H_RES, dtype=np.float64)
    j = np.arange(MERL_THETA_D_RES, dtype=np.float64)
    k = np.arange(MERL_PHI_D_RES, dtype=np.float64)
    theta_h = ((i + 0.5) / MERL_THETA_H_RES) ** 2 * _HALF_PI
    theta_d = (j + 0.5) / MERL_THETA_D_RES * _HALF_PI
    phi_d = (k + 0.5) / MERL_PHI_D_RES * np.pi
    return theta_h, theta_d, phi_d


def _folded_angles(wi, wo):
    """theta_h, theta_d and phi_d folded into [0, pi], exactly symmetric under swapping wi and wo."""
    theta_h, _, dx, dy, dz = _half_diff_xyz(wi, wo)
    # Folding phi_d by pi (README: add pi when negative) == flipping the sign of (dx, dy) when dy < 0;
    # done on the vector, it maps (dx, dy) and (-dx, -dy) to the same bits.
    flip = (dy < 0.0) | ((dy == 0.0) & (dx < 0.0))
    # "+ 0.0" turns -0.0 into +0.0, so atan2 cannot tell the pair (+0, 0) from (-0, 0) (0 against pi)
    dx = np.where(flip, -dx, dx) + 0.0
    dy = np.where(flip, -dy, dy) + 0.0
    return theta_h, np.arccos(np.clip(dz, -1.0, 1.0)), np.arctan2(dy, dx)


# --------------------------------------------------------------------------- lookup


def merl_eval(brdf: MerlBRDF, wi, wo, interpolate: bool = False) -> np.ndarray:
    """BRDF values (N, 3) float64 for direction pairs (N, 3); 0 where wi or wo is at/below the horizon.

    Nearest bin by default; ``interpolate=True`` is trilinear in the continuous bin coordinates
    (u_h = sqrt(theta_h/(pi/2))*90 - 0.5, u_d = theta_d/(pi/2)*90 - 0.5, u_p = phi_d/pi*180 - 0.5),
    clamped at the theta edges and periodic (period pi) in phi_d.
    """
    # a path or None: "'str' object has no attribute 'data'"; tabulate_merl's array: its .data is a memoryview,
    # which numpy refused to index as a sub-view (a traceback from inside numpy)
    if isinstance(brdf, np.ndarray) or not hasattr(brdf, "data"):
        raise WarpbwError(f"merl_eval: brdf is {type(brdf).__name__}, expected a MerlBRDF (read_merl(path) reads one)")
    interpolate = check_flag(interpolate, "merl_eval: interpolate")   # "no" is truthy: trilinear
    wi, wo = check_direction_pairs(wi, wo)
    above = (wi[..., 2] > 0.0) & (wo[..., 2] > 0.0)
    theta_h, theta_d, phi_d = _folded_angles(wi, wo)
    data = brdf.data
    if not interpolate:
        i, j, k = merl_indices(theta_h, theta_d, phi_d)
        out = data[i, j, k].astype(np.float64)
    else:
        u_h = np.sqrt(np.maximum(theta_h, 0.0) / _HALF_PI) * MERL_THETA_H_RES - 0.5
        u_d = theta_d / _HALF_PI * MERL_THETA_D_RES - 0.5
        u_p = phi_d / np.pi * MERL_PHI_D_RES - 0.5

        def clamped(u, n):
            u = np.clip(_finite_or_zero(u), 0.0, n - 1)
            i0 = np.minimum(np.floor(u), n - 2).astype(np.int64)
            return i0, i0 + 1, (u - i0)[..., None]

        h0, h1, th = clamped(u_h, MERL_THETA_H_RES)
        d0, d1, td = clamped(u_d, MERL_THETA_D_RES)
        u_p = _finite_or_zero(u_p)
        pf = np.floor(u_p)
        tp = (u_p - pf)[..., None]
        p0 = np.mod(pf.astype(np.int64), MERL_PHI_D_RES)
        p1 = np.mod(p0 + 1, MERL_PHI_D_RES)

        def lerp_p(i, j):
            return data[i, j, p0] * (1.0 - tp) + data[i, j, p1] * tp

        lo = lerp_p(h0, d0) * (1.0 - td) + lerp_p(h0, d1) * td
        hi = lerp_p(h1, d0) * (1.0 - td) + lerp_p(h1, d1) * td
        out = lo * (1.0 - th) + hi * th
    out = np.maximum(out, 0.0)  # never shade with a negative (unmeasured) value
    return np.where(above[..., None], out, 0.0)


# --------------------------------------------------------------------------- files


def read_merl(path) -> MerlBRDF:
    """Read a MERL ``.binary`` file; negative (unmeasured) and non-finite entries become 0, with a warning.

    The file is MERL's own layout (``BRDFRead.cpp``): three little-endian int32 (90, 90, 180), then the float64
    values of all red, then all green, then all blue entries, flat index ((i_theta_h * 90) + i_theta_d) * 180 +
    i_phi_d, phi_d in [0, pi) (folded by reciprocity); each channel is multiplied by ``MERL_SCALE`` (1/1500,
    1.15/1500, 1.66/1500) on reading.  A file of another size or header is refused, naming what it looks like
    (float32 values, 360 phi_d bins, no header, gzip, big-endian: ``_FOREIGN_SIZES``).  A file whose values were
    stored already scaled reads 1500 times too dark, and nothing in it says so."""
    path = check_input_file(path, f"a MERL .binary BRDF of {MERL_FILE_SIZE} bytes")
    size = path.stat().st_size
    if size != MERL_FILE_SIZE:
        from warpbw.io.npf import NPF_FILE_SIZE

        with open(path, "rb") as fh:
            head = fh.read(2)
        hint = (" -- the size of an NPF table: a material reads it with type = \"npf\", table and name, and "
                "warpbw-precompute npf-to-merl --table FILE --material NAME tabulates one as MERL"
                if size == NPF_FILE_SIZE else _FOREIGN_SIZES.get(size, ""))
        if head == _GZIP_MAGIC:
            hint = " -- a gzip-compressed file: decompress it first (gunzip)"
        raise WarpbwError(f"{path}: expected {MERL_FILE_SIZE} bytes (MERL .binary), got {size}{hint}")
    try:
        dims = np.fromfile(path, dtype="<i4", count=3)
        raw = np.fromfile(path, dtype="<f8", offset=MERL_HEADER_BYTES)
    except OSError as exc:
        raise WarpbwError(f"{path}: cannot read MERL file ({exc.strerror or exc})") from None
    expected = (MERL_THETA_H_RES, MERL_THETA_D_RES, MERL_PHI_D_RES)
    if tuple(int(d) for d in dims) != expected:
        swapped = tuple(int(d) for d in dims.byteswap()) == expected
        raise WarpbwError(f"{path}: header dims {tuple(int(d) for d in dims)}, expected {expected} (MERL .binary)"
                          + (" -- a big-endian file: MERL's are little-endian (byte-swap its header and values)"
                             if swapped else ""))
    raw = raw.reshape(3, *expected)
    bad = ~(np.isfinite(raw) & (raw >= 0.0))
    n_bad = int(np.count_nonzero(bad))
    scale = np.asarray(MERL_SCALE, dtype=np.float64).reshape(3, 1, 1, 1)
    scaled = np.where(bad, 0.0, raw * scale)
    problem = _values_problem(scaled, n_bad)
    if problem is not None:
        raise WarpbwError(f"{path}: {problem}")
    data = np.ascontiguousarray(np.moveaxis(scaled, 0, -1), dtype=np.float32)
    mask = np.ascontiguousarray(np.moveaxis(bad, 0, -1)) if n_bad else None
    if n_bad:
        warnings.warn(
            f"{path}: {n_bad} of {3 * MERL_N_BINS} MERL entries are unmeasured (negative or non-finite); set to 0",
            RuntimeWarning,
            stacklevel=2,
        )
    return MerlBRDF(name=path.stem, path=str(path), data=data, n_unmeasured=n_bad, unmeasured=mask)


def _values_problem(scaled: np.ndarray, n_bad: int) -> str | None:
    """What makes BRDF values (after the channel scales; unmeasured entries 0) no MERL BRDF warpbw can shade, or
    None: what ``read_merl`` refuses, and so ``write_merl`` (npf-to-merl wrote files its reader then refused)."""
    if scaled.max() > BRDF_VALUE_MAX:
        return (f"MERL entries up to {scaled.max():.3g} after the channel scales, beyond {BRDF_VALUE_MAX:g} (float32 "
                "shading would overflow them to infinity; expected a MERL BRDF)")
    if not np.float32(scaled.max()) > 0.0:   # a black image from a file of zeros or of unmeasured entries helps no
        # one (read as stored, in float32: entries of 1e-300 passed in float64 and were all 0 there)
        return (f"no positive MERL entry in float32 ({n_bad} of {3 * MERL_N_BINS} unmeasured, the largest "
                f"{scaled.max():.3g}; expected a measured BRDF)")
    return None


def write_merl(path, data, force: bool = False, inputs=()) -> Path:
    """Write scaled BRDF values (90, 90, 180, 3) as a MERL ``.binary`` file (float64, channel scales undone).

    Negative values are written as they are (readers treat them as unmeasured). Refuses to
    overwrite an existing file unless ``force``, and whatever ``force`` says, a read-only file or one of
    ``inputs`` (the files ``data`` was made from): :func:`warpbw.io.staged.check_replaceable`. The file
    appears atomically (temporary + rename).
    """
    path = check_path(path, "write_merl: output path")   # None was a TypeError from pathlib
    arr = numeric_array(data, f"{path}: MERL data", f"BRDF values of shape {MERL_SHAPE}")
    if arr.shape != MERL_SHAPE:
        raise WarpbwError(f"{path}: cannot write MERL data of shape {arr.shape}, expected {MERL_SHAPE}")
    arr = arr.astype(np.float64, copy=False)
    n_nonfinite = int(np.count_nonzero(~np.isfinite(arr)))
    if n_nonfinite:
        raise WarpbwError(f"{path}: refusing to write {n_nonfinite} non-finite MERL values (expected finite numbers)")
    problem = _values_problem(np.maximum(arr, 0.0), int(np.count_nonzero(arr < 0.0)))   # negatives: unmeasured
    if problem is not None:
        raise WarpbwError(f"{path}: refusing to write a file read_merl would refuse: {problem}")
    check_replaceable(path, force, inputs)
    scale = np.asarray(MERL_SCALE, dtype=np.float64)
    values = np.ascontiguousarray(np.moveaxis(arr / scale, -1, 0), dtype="<f8")
    header = np.asarray([MERL_THETA_H_RES, MERL_THETA_D_RES, MERL_PHI_D_RES], dtype="<i4")
    with staged_outputs([path], force=force) as tmp:   # appears whole (temporary + rename)
        with open(tmp[path], "wb") as fh:
            fh.write(header.tobytes())
            fh.write(values.tobytes())
    return path


def tabulate_merl(func, name: str) -> np.ndarray:
    """Evaluate ``func(wi (N,3), wo (N,3)) -> (N,3)`` (or (N,)) at every MERL bin centre (phi_h = 0).

    Returns float64 (90, 90, 180, 3), ready for :func:`write_merl`. ``func`` also receives the bin
    centres whose wi or wo lies below the horizon (large theta_h + theta_d) and should return its own
    value there (0 for a BRDF that is 0 below the horizon). ``name`` labels error messages.

    A bin the horizon cuts (``horizon_bins``) holds instead the mean of ``func`` over ``HORIZON_SUBSAMPLES``^3
    points of its (theta_h, theta_d, phi_d) box weighted by cos_i cos_o (0 below the horizon): its centre may lie
    a hair above the horizon, where a BRDF with a factor 1 / (cos_i cos_o) (NPF's) is hundreds of times what it is
    anywhere above the surface that the bin holds for (see ``HORIZON_SUBSAMPLES``).
    """
    if not callable(func):   # "'int' object is not callable" from the first chunk
        raise WarpbwError(f"{name}: tabulate_merl takes a function (wi, wo) -> BRDF values, got "
                          f"{type(func).__name__}")
    th, td, pd = merl_bin_centres()
    out = np.empty(MERL_SHAPE, dtype=np.float64)
    for r0 in range(0, MERL_THETA_H_RES, _TABULATE_ROWS_PER_CHUNK):
        r1 = min(r0 + _TABULATE_ROWS_PER_CHUNK, MERL_THETA_H_RES)
        TH, TD, PD = np.meshgrid(th[r0:r1], td, pd, indexing="ij")
        wi, wo = dirs_from_half_diff(TH.ravel(), 0.0, TD.ravel(), PD.ravel())
        vals = _tabulated_values(func, name, wi, wo, "MERL bin centres")
        out[r0:r1] = vals.reshape(r1 - r0, MERL_THETA_D_RES, MERL_PHI_D_RES, 3)
    cut = np.argwhere(horizon_bins())
    s = HORIZON_SUBSAMPLES
    q = (np.arange(s) + 0.5) / s   # the sub-points' places in a bin, per axis
    for c0 in range(0, len(cut), _HORIZON_BINS_PER_CHUNK):
        ii, jj, kk = cut[c0:c0 + _HORIZON_BINS_PER_CHUNK].T
        i, j, k = (a[:, None, None, None] for a in (ii, jj, kk))
        TH = ((i + q[:, None, None]) / MERL_THETA_H_RES) ** 2 * _HALF_PI
        TD = (j + q[:, None]) / MERL_THETA_D_RES * _HALF_PI
        PD = (k + q) / MERL_PHI_D_RES * np.pi
        TH, TD, PD = (np.broadcast_to(a, TH.shape[:1] + (s, s, s)).ravel() for a in (TH, TD, PD))
        wi, wo = dirs_from_half_diff(TH, 0.0, TD, PD)
        vals = _tabulated_values(func, name, wi, wo, "points of MERL bins at the horizon")
        w = (np.maximum(wi[:, 2], 0.0) * np.maximum(wo[:, 2], 0.0)).reshape(-1, s ** 3, 1)
        total = w.sum(axis=1)
        mean = (vals.reshape(-1, s ** 3, 3) * w).sum(axis=1) / np.where(total > 0.0, total, 1.0)
        out[ii, jj, kk] = np.where(total > 0.0, mean, out[ii, jj, kk])
    return out


def _tabulated_values(func, name: str, wi, wo, where: str) -> np.ndarray:
    """(N, 3) ``func`` at the direction pairs ``wi``, ``wo`` (N, 3), checked."""
    n = len(wi)
    vals = numeric_array(func(wi, wo), f"{name}: the BRDF's values", f"({n}, 3) numbers")
    if vals.shape == (n,):
        vals = np.repeat(vals[:, None], 3, axis=1)
    if vals.shape != (n, 3):
        raise WarpbwError(f"{name}: BRDF returned shape {vals.shape} for {n} direction pairs, expected ({n}, 3)")
    n_bad = int(np.count_nonzero(~np.isfinite(vals)))
    if n_bad:
        raise WarpbwError(f"{name}: BRDF returned {n_bad} non-finite values at {where} (expected finite)")
    return vals


def horizon_bins() -> np.ndarray:
    """(90, 90, 180) bool: the MERL bins whose (theta_h, theta_d, phi_d) box holds pairs with both directions above
    the horizon and pairs with one below.  min(cos_i, cos_o) = cos th cos td - sin th sin td |cos pd| (phi_h = 0)
    falls as th, td and |cos pd| grow, so its extremes over a box lie at the box's corners."""
    edges = [np.arange(n + 1) / n for n in (MERL_THETA_H_RES, MERL_THETA_D_RES, MERL_PHI_D_RES)]
    th = edges[0] ** 2 * _HALF_PI
    td = edges[1] * _HALF_PI
    c = np.abs(np.cos(edges[2] * np.pi))
    c_lo = np.where((edges[2][:-1] < 0.5) & (edges[2][1:] > 0.5), 0.0, np.minimum(c[:-1], c[1:]))   # pd = pi/2 inside
    c_hi = np.maximum(c[:-1], c[1:])

    def lowest(t_h, t_d, cc):   # min(cos_i, cos_o) at the given corner angles, broadcast over the bins
        return (np.cos(t_h)[:, None, None] * np.cos(t_d)[None, :, None]
                - np.sin(t_h)[:, None, None] * np.sin(t_d)[None, :, None] * cc[None, None, :])

    return (lowest(th[:-1], td[:-1], c_lo) > 0.0) & (lowest(th[1:], td[1:], c_hi) <= 0.0)
