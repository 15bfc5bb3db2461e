"""Reading warpbw's asset files from another renderer, with numpy alone.

    python examples/read_assets.py FILE [--view-deg 45] [--samples 100000] [--seed 0] [--roughness 0.08]
        [--json]

``warpbw-precompute`` writes three kinds of asset (README, "Asset files"): a BRDF's sampling tables
(``brdf-sampling``), its angular bandwidth table (``brdf``) and a GMM normal mipmap (``gmm``).  Each is a numpy
``.npz`` archive (no pickles) of named float32 arrays and a JSON header.  The functions above ``main()`` read them
and do what the renderer's Warp kernels do with them -- the table look-up of nu_rho (``warpbw.bandwidth``), the
tabulated sampler and its pdf (``warpbw.sampling``), the mipmap's trilinear fetch and mixture NDF
(``warpbw.filtering``) -- using nothing but numpy and the standard library, so that they can be copied into another
renderer's tools or ported to its shading language.  ``tests/test_read_assets.py`` checks each against the
renderer's kernels.

The script prints a file's header and arrays and checks it with those functions alone: a sampling table's pdf
must integrate to 1 over the sphere and its draws must follow it; a bandwidth table's look-ups are printed for the
view ``--view-deg`` degrees from the normal; a GMM mipmap's every level is fetched and its NDF integrated.

Conventions (warpbw's): directions are unit 3-vectors in the surface's local frame, +z the normal; a BRDF's
tables are isotropic (they drop the view's azimuth: the look-ups turn each query about z first); angles are
radians; float32 on disk.
"""
if __name__ == "__main__":   # first: a Ctrl-C while numpy loads says one line (the readers below need no warpbw)
    from warpbw.entry import interrupt_in_one_line

    interrupt_in_one_line(__name__)

import argparse
import json
import math
import os
import sys
import zipfile

import numpy as np

HEADER_KEY = "__header__"     # the archive member holding the JSON header
FORMATS = {                   # format name -> (version read here, what the file is)
    "warpbw.brdf-sampling": (2, "importance-sampling tables of a tabulated BRDF"),
    "warpbw.brdf-bandwidth": (4, "angular bandwidth nu_rho of a BRDF's lobes, cycles/radian"),
    "warpbw-gmm-mipmap": (2, "GMM normal mipmap"),
}
HALF_PI = 0.5 * math.pi
TWO_PI = 2.0 * math.pi
COS_D_EXACT = 1.0e-3          # below this wo . h the pdf takes |wi + wo| / 2 (the rounded dot product lost its digits)
WEIGHT_EPS = 1.0e-8           # a filtered GMM component of weight up to this is empty
VARIANCE_FLOOR = 1.0e-6       # the least per-axis variance a recovered GMM component keeps
NORMAL_DIM = 2                # dimension of the projected normal space (the moments' d)
SAMPLES_MIN, SAMPLES_MAX = 1000, 10_000_000   # the sampling check's directions: enough for its bins, memory bound
ROUGHNESS_DEFAULT = 0.08      # README's cook-torrance plane
ROUGHNESS_MIN = 0.02          # a lobe of per-axis sigma 0.014: 3 points of the GMM check's grid
VIEW_DEG_MAX = 89.0           # the last degree above the horizon holds the tables' sharpest change


class AssetError(Exception):
    """A file this reader cannot read, said in one line."""


# ---------------------------------------------------------------------------------------------- the archive
def read_asset(path) -> tuple[dict, dict]:
    """(header, arrays) of an asset file.  The header holds ``format``, ``version``, ``source`` (the asset it was
    built from), ``source_hash`` (blake2b of its bytes), ``params`` (what it was built with) and ``writer``."""
    if not os.path.isfile(path):
        raise AssetError(f"{path}: {'a folder, not a file' if os.path.isdir(path) else 'no such file'}")
    try:
        if not zipfile.is_zipfile(path):
            raise AssetError(f"{path}: not a .npz archive (a warpbw asset is a zip of .npy arrays)")
        with np.load(path, allow_pickle=False) as z:
            if HEADER_KEY not in z.files:
                raise AssetError(f"{path}: not a warpbw asset (no {HEADER_KEY} member)")
            text = str(z[HEADER_KEY])
            arrays = {k: z[k] for k in z.files if k != HEADER_KEY}
    except AssetError:
        raise
    except OSError as e:     # not readable (permissions), or a read error
        raise AssetError(f"{path}: cannot be read ({e.strerror or e})") from None
    except MemoryError:      # a damaged member's header declaring more data than memory holds (numpy allocates first)
        raise AssetError(f"{path}: a damaged .npz archive (a member declares more data than memory holds)") from None
    except Exception as e:   # a damaged member or zip entry (numpy's parser raises several kinds), a pickled one
        why = (str(e).splitlines() or [type(e).__name__])[0][:200]
        raise AssetError(f"{path}: a damaged .npz archive ({why})") from None
    try:
        header = json.loads(text)
    except ValueError:
        raise AssetError(f"{path}: its {HEADER_KEY} member is not JSON") from None
    if not isinstance(header, dict) or header.get("format") not in FORMATS:
        raise AssetError(f"{path}: not a warpbw asset of a known format ({', '.join(FORMATS)})")
    version = FORMATS[header["format"]][0]
    if header.get("version") != version:
        raise AssetError(f"{path}: {header['format']} version {header.get('version')}; this reader reads version "
                         f"{version}")
    problem = _shape_problem(header["format"], arrays)
    if problem:
        raise AssetError(f"{path}: {header['format']} arrays not as the format has them: {problem}")
    return header, arrays


def _shape_problem(fmt: str, arrays: dict) -> str | None:
    """What is wrong with a file's arrays for its format (README, "Asset files"), or None."""
    if any(a.dtype.kind != "f" for a in arrays.values()):
        return "expected floating-point arrays"
    if fmt == "warpbw.brdf-bandwidth":
        t = arrays.get("nu_rho")
        return None if t is not None and t.ndim == 3 else "expected nu_rho of 3 axes (t, row, col)"
    if fmt == "warpbw.brdf-sampling":
        m, c, d = (arrays.get(k) for k in ("marginal", "conditional", "density"))
        if m is None or c is None or d is None or d.ndim != 3:
            return "expected marginal, conditional and density, density of 3 axes"
        nt, nu, nphi = d.shape
        if m.shape != (nt, nu + 1) or c.shape != (nt, nu, nphi + 1):
            return f"expected marginal {(nt, nu + 1)} and conditional {(nt, nu, nphi + 1)} for density {d.shape}"
        return None
    levels = gmm_levels(arrays)
    if not levels or len(levels) != len(arrays):
        return "expected levels level_0, level_1, ... and nothing else"
    if any(q.ndim != 4 or q.shape[2:] != levels[0].shape[2:] or q.shape[3] != 4 for q in levels):
        return "expected every level (h, w, K, 4) with one K"
    return None


def gmm_levels(arrays: dict) -> list:
    """A GMM mipmap's levels, finest first: ``level_0``, ``level_1``, ... each (h_l, w_l, K, 4)."""
    return [arrays[f"level_{l}"] for l in range(len(arrays)) if f"level_{l}" in arrays]


def _unit(v) -> np.ndarray:
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _elevation(v: np.ndarray) -> np.ndarray:
    """Angle from +z; atan2 keeps its digits near 0, where acos(z) does not."""
    return np.arctan2(np.hypot(v[..., 0], v[..., 1]), v[..., 2])


# ------------------------------------------------------------------------------- BRDF bandwidth (002 Sec. 2.3)
def nu_rho_at(nu_rho: np.ndarray, wi, wo) -> np.ndarray:
    """nu_rho(w_i, w_o), cycles/radian: the nearest cell of the table ``nu_rho[t, row, col]`` (16, 16, 16).

    ``t`` is the incident elevation's bin, ``floor(theta_i / (pi/2) * 16)``.  The table holds w_i in the x-z
    plane (azimuth 0), so w_o is first turned by -phi_i about z.  It is then placed on the Lambert equal-area map
    of the upper hemisphere, ``(x, y) = sqrt(2) sin(theta_o / 2) (cos phi_o, sin phi_o)``, and the 16 x 16 cells
    cover [-1, 1]^2: ``col = floor((x + 1) / 2 * 16)``, ``row = floor((y + 1) / 2 * 16)``."""
    n_t, n_row, n_col = nu_rho.shape
    wi, wo = _unit(wi), _unit(wo)
    t = np.clip((_elevation(wi) / HALF_PI * n_t).astype(np.int64), 0, n_t - 1)
    phi_i = np.arctan2(wi[..., 1], wi[..., 0])
    c, s = np.cos(phi_i), np.sin(phi_i)
    ox, oy = c * wo[..., 0] + s * wo[..., 1], -s * wo[..., 0] + c * wo[..., 1]
    r = np.sqrt(1.0 - np.clip(wo[..., 2], 0.0, 1.0))        # sqrt(2) sin(theta_o / 2) for unit w_o; 1 at the rim
    phi_o = np.arctan2(oy, ox)
    col = np.clip(((r * np.cos(phi_o) + 1.0) * 0.5 * n_col).astype(np.int64), 0, n_col - 1)
    row = np.clip(((r * np.sin(phi_o) + 1.0) * 0.5 * n_row).astype(np.int64), 0, n_row - 1)
    return nu_rho[t, row, col]


# ------------------------------------------------------------------------- BRDF sampling tables (002 Sec. 3.3)
def _view_bin(wo: np.ndarray, n_theta_o: int) -> np.ndarray:
    return np.clip((_elevation(wo) / HALF_PI * n_theta_o).astype(np.int64), 0, n_theta_o - 1)


def _cell_in_cdf(cdf: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Per row of ``cdf`` (..., n + 1), the largest cell i < n with cdf[i] <= x (cells of zero width skipped)."""
    n = cdf.shape[-1] - 1
    return np.clip((cdf[..., :n] <= x[..., None]).sum(-1) - 1, 0, n - 1)


def sample_wi(marginal, conditional, density, wo, u) -> np.ndarray:
    """Directions w_i drawn for views ``wo`` (N, 3) from uniforms ``u`` (N, 2) in [0, 1).

    The tables: for each of the n_theta_o view-elevation bins (uniform over [0, pi/2)), a piecewise-constant
    density over the half vector's (u, phi_h) cells, ``theta_h = u^2 pi/2`` and phi_h measured from the view's
    azimuth: ``marginal[j]`` (n_u + 1) is the CDF over u, ``conditional[j, a]`` (n_phi + 1) the CDF over phi_h in
    u cell a.  Within a cell (u, phi_h) is uniform.  w_i is the reflection of w_o about h: it may lie below the
    surface (a cell straddling the horizon), where the BRDF is 0."""
    wo = _unit(wo)
    u = np.asarray(u, np.float64)
    n_theta_o, n_u = marginal.shape[0], marginal.shape[1] - 1
    n_phi = conditional.shape[2] - 1
    j = _view_bin(wo, n_theta_o)
    m = marginal[j].astype(np.float64)
    a = _cell_in_cdf(m, u[:, 0])
    c0, c1 = np.take_along_axis(m, a[:, None], 1)[:, 0], np.take_along_axis(m, a[:, None] + 1, 1)[:, 0]
    t0 = np.clip((u[:, 0] - c0) / np.maximum(c1 - c0, 1e-30), 0.0, 1.0)
    cond = conditional[j, a].astype(np.float64)
    b = _cell_in_cdf(cond, u[:, 1])
    d0, d1 = np.take_along_axis(cond, b[:, None], 1)[:, 0], np.take_along_axis(cond, b[:, None] + 1, 1)[:, 0]
    t1 = np.clip((u[:, 1] - d0) / np.maximum(d1 - d0, 1e-30), 0.0, 1.0)
    theta_h = ((a + t0) / n_u) ** 2 * HALF_PI
    phi_h = np.arctan2(wo[:, 1], wo[:, 0]) + (b + t1) / n_phi * TWO_PI
    h = np.stack([np.sin(theta_h) * np.cos(phi_h), np.sin(theta_h) * np.sin(phi_h), np.cos(theta_h)], -1)
    return 2.0 * np.sum(wo * h, -1, keepdims=True) * h - wo


def sampling_pdf(marginal, conditional, density, wi, wo) -> np.ndarray:
    """The solid-angle pdf of ``sample_wi``'s draws at ``wi`` for views ``wo`` (both (N, 3)), over the whole
    sphere: ``density[j, a, b]`` (per unit u and phi_h) divided by d w_i / d(u, phi_h) = 4 (w_o . h) sin(theta_h)
    pi u.  0 for a view below the surface."""
    wi, wo = _unit(wi), _unit(wo)
    n_theta_o, n_u, n_phi = density.shape
    j = _view_bin(wo, n_theta_o)
    s = wi + wo
    length = np.linalg.norm(s, axis=-1)
    h = s / np.maximum(length, 1e-300)[:, None]
    cos_d = np.sum(wo * h, -1)
    cos_d = np.where(cos_d < COS_D_EXACT, 0.5 * length, cos_d)     # = wo . h for unit directions
    theta_h = _elevation(h)
    uh = np.sqrt(theta_h / HALF_PI)
    rel = np.mod(np.arctan2(h[:, 1], h[:, 0]) - np.arctan2(wo[:, 1], wo[:, 0]), TWO_PI)
    a = np.clip((uh * n_u).astype(np.int64), 0, n_u - 1)
    b = np.clip((rel / TWO_PI * n_phi).astype(np.int64), 0, n_phi - 1)
    jac = np.sin(theta_h) * math.pi * uh * 4.0 * cos_d
    pdf = density[j, a, b] / np.maximum(jac, 1e-12)
    return np.where((wo[:, 2] > 0.0) & (h[:, 2] > 0.0) & (cos_d > 0.0) & (length > 0.0), pdf, 0.0)


# ------------------------------------------------------------------------------- GMM normal mipmaps (004 Sec. 4)
def gmm_fetch(levels: list, s, t, lam) -> np.ndarray:
    """(N, K, 4) components (a, mu_x, mu_y, s^2) at finest-texel coordinates (s along columns, t along rows) and
    fractional level ``lam`` (0 the finest), by trilinear filtering of the stored moments.

    Level l is (h_l, w_l, K, 4), each level the one below halved rounding up, down to 1 x 1; its texel j covers
    finest texels [j 2^l, (j + 1) 2^l), centred at (j + 1/2) 2^l -- but where a side is no power of two the border
    clips the last texel, [j 2^l, n), centred on those texels; the map tiles with its own period n.  A component is
    stored as (a, a mu_x, a mu_y, a (2 s^2 + |mu|^2)), so filtering is linear; mu and the per-axis variance s^2
    are recovered after it."""
    s, t, lam = np.broadcast_arrays(*(np.asarray(v, np.float64) for v in (s, t, lam)))
    s, t, lam = s.ravel(), t.ravel(), lam.ravel()
    l0 = np.floor(lam).astype(np.int64)
    l1 = np.minimum(l0 + 1, len(levels) - 1)
    fl = (lam - l0)[:, None, None]
    q = (1.0 - fl) * _bilinear(levels, l0, s, t) + fl * _bilinear(levels, l1, s, t)
    a = q[..., 0]
    full = a > WEIGHT_EPS
    safe = np.where(full, a, 1.0)
    mx, my = q[..., 1] / safe, q[..., 2] / safe
    s2 = np.maximum((q[..., 3] / safe - (mx * mx + my * my)) / NORMAL_DIM, VARIANCE_FLOOR)
    return np.where(full[..., None], np.stack([a, mx, my, s2], -1), 0.0)


def _axis(l: int, n_l: int, n: int, x: np.ndarray):
    """Along one axis of n finest texels (n_l at level l): the texel whose centre is the last at or before finest
    coordinate x and the fraction of the way to the next centre, the map tiling with period n (a last texel the
    border clips is centred on the texels it covers, and the texel after it is texel 0 of the next tile)."""
    f = 2.0 ** l
    u = x / f - 0.5
    x0 = np.floor(u)
    fx = u - x0
    if n_l * f != n:
        u = x - np.floor(x / n) * n                    # in the first tile
        last = n_l - 1.0
        c_last = 0.5 * (last * f + n)
        x0 = np.floor(u / f - 0.5)
        fx = u / f - 0.5 - x0
        c0 = (x0 + 0.5) * f
        before = u < 0.5 * f                           # between the previous tile's last texel and texel 0
        after = u >= c_last                            # between the last texel and the next tile's texel 0
        towards = ~before & ~after & (x0 == last - 1)  # towards the clipped last texel
        fx = np.where(towards, (u - c0) / np.where(towards, c_last - c0, 1.0), fx)
        fx = np.where(before, (u - (c_last - n)) / (0.5 * f + n - c_last), fx)
        fx = np.where(after, (u - c_last) / (n + 0.5 * f - c_last), fx)
        x0 = np.where(before, -1.0, np.where(after, last, x0))
        fx = np.clip(fx, 0.0, 1.0)
    return x0.astype(np.int64), fx


def _bilinear(levels: list, level: np.ndarray, s: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(N, K, 4) moments of each point's own level, bilinear between the four nearest texel centres."""
    out = np.zeros((len(s),) + levels[0].shape[2:])
    H, W = levels[0].shape[:2]
    for l in np.unique(level):
        at = level == l
        q = levels[l].astype(np.float64)
        h, w = q.shape[:2]
        c, fx = _axis(int(l), w, W, s[at])
        r, fy = _axis(int(l), h, H, t[at])
        fx, fy = fx[:, None, None], fy[:, None, None]
        out[at] = ((1 - fx) * (1 - fy) * q[r % h, c % w] + fx * (1 - fy) * q[r % h, (c + 1) % w]
                   + (1 - fx) * fy * q[(r + 1) % h, c % w] + fx * fy * q[(r + 1) % h, (c + 1) % w])
    return out


def gmm_ndf(params: np.ndarray, rough_var: float, h) -> np.ndarray:
    """D(h) = sum_i a_i g(h_xy; mu_i, s_i^2 + rough_var) at unit half vectors h (N, 3) for one texel's components
    ``params`` (K, 4), g the isotropic 2D Gaussian density of that per-axis variance (004 Sec. 3).  h is in the
    map's tangent frame: x along +column, y along -row, z the mean surface normal.  A material of roughness m
    adds rough_var = m^2 / 2.  D is a density over the projected normal (h_x, h_y): the integral of D(h) h_z over
    solid angle is 1, less what the Gaussians put outside the unit disc."""
    h = _unit(h)
    d = np.zeros(len(h))
    for a, mx, my, s2 in np.asarray(params, np.float64):
        if a > 0.0:
            var = s2 + rough_var
            d += a * np.exp(-((h[:, 0] - mx) ** 2 + (h[:, 1] - my) ** 2) / (2.0 * var)) / (TWO_PI * var)
    return d


# ---------------------------------------------------------------------------------------------- checks
def check_sampling(arrays: dict, view: float, n: int, rng) -> dict:
    """For the view ``view`` radians from the normal: the pdf's integral over the sphere (1 expected), by the
    midpoint rule over the table's own (u, phi_h) cells (2 x 2 points each) through the change of variables to
    w_i; the share of ``n`` draws below the surface; and how far the draws' histogram over those cells is from
    the cells' masses (chi-square per degree of freedom: about 1 when the draws follow the table)."""
    m, c, d = (arrays[k] for k in ("marginal", "conditional", "density"))
    n_theta_o, n_u, n_phi = d.shape
    wo1 = np.array([math.sin(view), 0.0, math.cos(view)])
    sub = 2
    uu = (np.arange(n_u * sub) + 0.5) / (n_u * sub)
    pp = (np.arange(n_phi * sub) + 0.5) / (n_phi * sub) * TWO_PI
    U, P = (g.ravel() for g in np.meshgrid(uu, pp, indexing="ij"))
    theta_h = U * U * HALF_PI
    h = np.stack([np.sin(theta_h) * np.cos(P), np.sin(theta_h) * np.sin(P), np.cos(theta_h)], -1)
    cos_d = h @ wo1
    wi = 2.0 * cos_d[:, None] * h - wo1
    jac = np.sin(theta_h) * math.pi * U * 4.0 * cos_d          # d w_i / d(u, phi_h)
    front = cos_d > 0.0                                         # half vectors a reflection can have
    wo = np.broadcast_to(wo1, wi[front].shape)
    integral = float(np.sum(sampling_pdf(m, c, d, wi[front], wo) * jac[front]) / (n_u * sub * n_phi * sub)
                     * TWO_PI)
    draws = sample_wi(m, c, d, np.broadcast_to(wo1, (n, 3)), rng.random((n, 2)))
    # each draw's cell, from its half vector (as the pdf finds it)
    hd = _unit(draws + wo1)
    a = np.clip((np.sqrt(_elevation(hd) / HALF_PI) * n_u).astype(np.int64), 0, n_u - 1)
    b = np.clip((np.mod(np.arctan2(hd[:, 1], hd[:, 0]), TWO_PI) / TWO_PI * n_phi).astype(np.int64), 0, n_phi - 1)
    counts = np.bincount(a * n_phi + b, minlength=n_u * n_phi)
    expected = d[_view_bin(wo1[None], n_theta_o)[0]].astype(np.float64).ravel() / (n_u * n_phi) * TWO_PI * n
    keep = expected > 20.0                                      # the chi-square's usual validity
    chi2 = float(np.sum((counts[keep] - expected[keep]) ** 2 / expected[keep]) / max(int(keep.sum()) - 1, 1))
    return {"pdf_integral": integral, "below_surface": float(np.mean(draws[:, 2] <= 0.0)), "chi2_per_cell": chi2}


def check_bandwidth(arrays: dict, view: float) -> dict:
    """nu_rho for light from ``view`` radians, seen from the mirror direction, the normal and 60 degrees across."""
    wi = np.array([[math.sin(view), 0.0, math.cos(view)]] * 3)
    wo = np.array([[-math.sin(view), 0.0, math.cos(view)], [0.0, 0.0, 1.0], [0.0, math.sin(1.047), math.cos(1.047)]])
    got = nu_rho_at(arrays["nu_rho"], wi, wo)
    return {"mirror": float(got[0]), "normal": float(got[1]), "across_60_deg": float(got[2])}


def check_gmm(arrays: dict, roughness: float) -> dict:
    """Per level: its size, the components in use at its first texel's centre, and the integral there of the NDF
    of a material of ``roughness`` over the projected disc (1 expected, less the Gaussians' tails past the disc;
    midpoint rule on 401 x 401 points)."""
    levels = gmm_levels(arrays)
    n = 401
    x = (np.arange(n) + 0.5) / n * 2.0 - 1.0
    X, Y = np.meshgrid(x, x)
    disc = X ** 2 + Y ** 2 < 1.0
    h = np.stack([X[disc], Y[disc], np.sqrt(1.0 - X[disc] ** 2 - Y[disc] ** 2)], -1)
    out = []
    for l, q in enumerate(levels):
        centre = 0.5 * 2 ** l
        p = gmm_fetch(levels, centre, centre, float(l))[0]
        integral = float(gmm_ndf(p, 0.5 * roughness ** 2, h).sum() * (2.0 / n) ** 2)
        out.append({"level": l, "shape": list(q.shape[:2]), "components_used": int((p[:, 0] > 0).sum()),
                    "ndf_integral": integral})
    return {"roughness": roughness, "levels": out}


def summary(path, header: dict, arrays: dict, view: float, n: int, seed: int, roughness: float) -> dict:
    rng = np.random.default_rng(seed)
    fmt = header["format"]
    record = {"file": str(path), "header": header,
              "arrays": {k: {"shape": list(v.shape), "dtype": str(v.dtype)} for k, v in arrays.items()}}
    if fmt == "warpbw.brdf-sampling":
        record["check"] = check_sampling(arrays, view, n, rng)
    elif fmt == "warpbw.brdf-bandwidth":
        record["check"] = check_bandwidth(arrays, view)
    else:
        record["check"] = check_gmm(arrays, roughness)
    return record


def main() -> int:
    # the command line is warpbw's (one-line errors, exit statuses); the reading above needs none of it
    from warpbw.cli_common import OneLineParser, json_text
    from warpbw.errors import WarpbwError, check_count, check_real

    ap = OneLineParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("file", help="an asset written by warpbw-precompute (brdf-sampling, brdf or gmm)")
    ap.add_argument("--view-deg", type=float, default=45.0,
                    help="view elevation of the sampling check and light elevation of the bandwidth look-ups, "
                         "degrees from the normal, 0 to 89 (default 45)")
    ap.add_argument("--samples", type=int, default=100_000,
                    help=f"directions of the sampling check, {SAMPLES_MIN} to {SAMPLES_MAX} (default 100000)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the sampling check's random numbers (default 0)")
    ap.add_argument("--roughness", type=float, default=ROUGHNESS_DEFAULT,
                    help=f"the material's roughness m in the GMM check's NDF (per-axis variance m^2/2), "
                         f"{ROUGHNESS_MIN} to 1 (default {ROUGHNESS_DEFAULT})")
    ap.add_argument("--json", action="store_true", help="print the record as JSON instead of lines")
    args = ap.parse_args()
    view_deg = check_real(args.view_deg, "--view-deg", 0.0)
    if view_deg > VIEW_DEG_MAX:
        raise WarpbwError(f"--view-deg: expected degrees from 0 to {VIEW_DEG_MAX:g} (a view above the surface), got "
                          f"{view_deg:g}")
    n = check_count(args.samples, "--samples", SAMPLES_MIN, SAMPLES_MAX)
    seed = check_count(args.seed, "--seed", 0)
    roughness = check_real(args.roughness, "--roughness", 0.0)
    if not ROUGHNESS_MIN <= roughness <= 1.0:   # finer lobes than the check's grid resolves read as lost mass
        raise WarpbwError(f"--roughness: expected {ROUGHNESS_MIN} to 1, got {roughness:g}")
    try:
        header, arrays = read_asset(args.file)
        record = summary(args.file, header, arrays, math.radians(view_deg), n, seed, roughness)
    except AssetError as e:
        raise WarpbwError(str(e)) from None
    if args.json:
        print(json_text(record), end="")
        return 0
    print(f"{args.file}: {header['format']} version {header['version']} ({FORMATS[header['format']][1]})")
    print(f"  source {header.get('source')} (blake2b {str(header.get('source_hash'))[:16]}...), "
          f"written by {header.get('writer')}")
    print(f"  params {json.dumps(header.get('params'))}")
    for k, v in record["arrays"].items():
        print(f"  {k}: {tuple(v['shape'])} {v['dtype']}")
    print("  check: " + json.dumps(record["check"]))
    return 0


if __name__ == "__main__":
    from warpbw.cli_common import run_command

    sys.exit(run_command("read_assets.py", lambda _: main(), None))
