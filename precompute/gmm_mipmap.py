"""GMM normal-distribution mipmaps, EM-aligned (004 Sec. 3 and 4.1): the offline builder.

Public functions and classes:

- ``GmmMipmap``: ``levels`` (list, finest first, of float32 ``(h_l, w_l, K, 4)`` moments), ``components``,
  ``prior``, ``unaligned``, ``kind``, ``scale``, ``seed``, ``max_samples``; ``params()``.
- ``fit_settings(seed=0, max_samples=256, refine_sweeps=0) -> dict``, ``fit_constants() -> dict``, ``GMM_UNRECORDED``,
  ``NORMAL_SPACE``: the fit's settings as a file's parameters record them (what the renderer's cache compares,
  ``warpbw.filtering``).
- ``build_gmm_mipmap(heights_or_normals, kind="height", components=4, prior=1.0, scale=1.0, seed=0,
  progress=True, unaligned=False, texel_size=None, max_samples=256, refine_sweeps=0) -> GmmMipmap``; a non-square
  height map's build records ``ROW_SPACING_KEY: ROW_SPACING`` (its rows 1 / H apart) in its parameters.
- ``write_gmm_mipmap(path, mip, source_name, source_hash, force=False, inputs=())``,
  ``read_gmm_mipmap(path) -> GmmMipmap``; ``mipmap_problem(levels, components, prior, scale)``, what both refuse;
  ``header_fields(header, components_unrecorded) -> dict``, a ``GmmMipmap``'s fields but its levels from a header;
  ``rebuild_command(source, params, out)``, the command that rebuilds a mipmap.
- ``load_map(path, kind) -> ndarray``: an EXR or PNG (or other Pillow) height field (H, W) or normal map (H, W, 3 unit).
- ``load_source(spec, kind) -> (array, name, content_hash)``: a file, or ``surface:NAME[:SIZE]``.
- ``level_shapes(h, w)``, ``normal_space(normals)``, ``footprint_samples(n2, level, max_samples, rng)``.
- ``build_memory(height, width, components) -> bytes``, ``BUILD_BYTES_PER_TEXEL_COMPONENT``: what a build takes at
  the peak (a build warns first where that is more than the memory available).
- ``em_fit(x, a, mu, s2, c=0.0, prior_sum=None, prior_weight=None, max_iter=..., tol=...)``: the
  vectorised (MAP-)EM of 004 Sec. 4.1 over many texels at once.
- ``kmeans_init(x, centres, ...)``, ``kmeans_plus_plus(x, K, rng)``: vectorised clustering initialisation.
- ``to_moments(a, mu, s2) -> q``, ``from_moments(q) -> (a, mu, s2)``, ``filter_moments(q, weights)``,
  ``moment_match(a, mu, s2, weights)``: the linearly filterable form of 004 Sec. 4.2 (below).
  Each of these helpers refuses a wrong shape, a NaN or infinite value, a negative weight or a variance <= 0 with a
  one-line WarpbwError; the builder, whose input ``_validate`` checked, calls their unchecked cores (``_em_fit``...).

Representation.  A unit normal n is the 2D point (n_x, n_y) -- its projection on the tangent plane,
as 004 Sec. 3 does ("a unit normal n can be represented as a 2D vector in x-y space").  Projected
coordinates stay in the unit disk, so normals at grazing angles (89 degrees, even 90) are finite, where
slopes (-dh/dx, -dh/dy) would blow up.  Axes: x along +column, y along -row (``precompute.surfaces``).
Each texel holds an N-component mixture G(n) = sum_i a_i g(n; mu_i, s_i) of isotropic 2D Gaussians
(s_i^2 the variance per axis).  Mip level 0 is the finest; a texel of level l covers a 2^l x 2^l
footprint of finest-level normals (clipped at the border; sizes halve rounding up, down to 1x1).

The filterable form (004 Sec. 4.2).  Component i is stored as (a, a mu_x, a mu_y, a (d s^2 + |mu|^2)), d = 2
the dimension of the normal space: the fourth quantity is a E|n|^2, the component's second moment (its
total variance E|n - mu|^2 = d s^2 plus |mu|^2).  Linear (trilinear) filtering of these quantities gives the
weight, mean and second moment of the filtered mixture exactly, and s^2 = (E|n|^2 - |mu|^2) / d recovers the
isotropic Gaussian of that mean and second moment -- the one the M-step, which divides by d, would fit to the
union of the filtered components' normals.  004 prints the same form with a (s^2 + |mu|^2): with its own
per-axis s^2 that counts the spread between the filtered components' means d times over (it is the variance
along the line through two means, not per axis), and every filtered lobe comes out wider than an isotropic
fit of its normals.
Measured (docs/measurements.md, "Reflectance filtering: measurements"):
under the benchmark's ring of lights the isotropic match lowers
the aligned GMM's error at zooms 8-32 on all three surfaces (zoom 32: 0.168 to 0.129, 0.219 to 0.207, 0.0119
to 0.0106).  Files of ``GMM_VERSION`` 1 held 004's form and are refused.

Fitting (004 Sec. 4.1).  Coarse to fine; each texel by EM on its footprint's finest-level normals,
with the MAP prior that pulls component i's mean toward component i of the already-fitted neighbours
(eight at the same level, the coarser parent, the four finer children), each weighted by the
neighbour's mixture weight a_ki and by the constant c.  Vectorisation: every E/M step runs on arrays
(texels, samples, components); within a level the texels are fitted in four interleaved classes
(row and column parity), so a texel's already-fitted same-level neighbours are those of the earlier
classes -- the vectorised stand-in for the paper's scan-line order.  Children are never fitted before
their parent in the coarse-to-fine pass; ``refine_sweeps`` > 0 repeats the pass with all 13 neighbours.
Initialisation is clustering: k-means (scikit-learn) on the whole map's normals for the 1x1 top level,
then at each finer level Lloyd iterations started from the parent's means, so component i keeps its
meaning from level to level.  Footprints with more than ``max_samples`` normals (default 256) are
subsampled by stratified jittered sampling (one normal per cell of a 16x16 grid), seeded: at most
(texels x 256 x K) work per level.  A footprint the map's border clips (a side that is no power of two) weighs each
of its texels equally: its enumerated slots, some on the same texel, are weighted in the clustering and EM.  The
data term always counts 256 samples (a smaller footprint's normals are weighted up, as if 256 stratified samples
were drawn from it), so the prior has the same strength against the data at every level (see
``build_gmm_mipmap``).  ``unaligned=True`` is the baseline: c = 0 and each texel initialised independently (seeded
k-means++ then Lloyd), no neighbour information at all.

Measured (docs/measurements.md, "Reflectance filtering: measurements"; with 004's printed merge):
with this order the labels of a texel
and its parent are the best of all K! relabellings at levels >= 3 (within 0.0023 of it below), so cross-level
correspondence is not what limits the filtered result; a stronger prior, 004's literal sample count,
refinement sweeps and per-texel restarts (better local fits, relabelled to the neighbours) each left the
filtered NDF no closer to the truth, the restarts further from it (texels refitted alone stop sharing their
neighbours' split).
Also tried, on the carved disk at zoom 32, where the aligned GMM's error is 0.199, 0.56x
Toksvig's (``examples/filtering_floor.py``):
- a label step before or after each texel's EM: the permutation of its components that minimises the
  prior's penalty sum_i a_i sum_k a_ki |mu_i - mu_ki|^2: 0.196-0.210 over the variants tried.  The penalty
  counts nothing for a slot the neighbours leave empty, so the step favours those slots; and the seams it
  can remove (the disk's symmetry axes, where the 2x2 level's quadrants are labelled apart) hold only
  9-23% of the cost of merging neighbours (levels 2 and 3);
- reviving the components that the parent-initialised Lloyd iterations leave empty (a footprint with more
  clusters than its parent's non-empty components), each at the normal furthest from every centre when it
  lies more than 0.2 projected units from them.  The taps fit closer (shaded apart, 0.108 to 0.088), the
  merged error fell to 0.179 (0.507x Toksvig's) and at zoom 16 from 0.190 to 0.160.  It is not the default:
  the disk's zoom-32 flicker rose from 0.056 to 0.059, above the unaligned GMM's 0.058, the scales' zoom-8
  error rose from 0.219 to 0.226, and a threshold of 0.05 units took the dunes' zoom-32 error from 0.0051
  to 0.0078;
- seeding the revived component by splitting the widest cluster along its major axis: 0.182-0.194;
- fitting each texel at levels >= 1 first to the normals under a tent of half-width 2^l about its centre
  (the trilinear filter's support, so neighbours share half their data), then to its own footprint with
  those means kept (weights and spreads refitted) or as EM's start: 0.201 and 0.200, per tap 0.113 and
  0.103.  Neighbours that share data still fill a slot with unlike structures (the flat top in one, a groove
  wall where the other has no flat normals), and that is what the merge widens.
- fitting every mipmap (this one, and the renderer's mean-normal and second-moment mipmaps of Toksvig and
  LEAN) to the normal field the ground truth's rays see, bilinear between texel centres, sampled 4 x 4 times
  per finest texel, instead of to the texel normals (``examples/filtering_floor.py``'s ``floor_bilinear``):
  zoom-32 error 0.199 to 0.214 on the disk (0.64x Toksvig's, whose own error fell to 0.336), though zoom 8
  fell from 0.183 to 0.132; on the scales 0.129 to 0.080 (0.27x), still tied with the unaligned GMM (1.02x);
  the dunes unchanged (0.0051 to 0.0050).  An aligned build of a 256x256 map took 57-59 s against 3-6 s
  (a scratch patch: the field supersampled to 1024x1024 and fitted from its level 2 up).
- 004's literal data count: each footprint's 4^l normals, so that the prior (up to 13 neighbour weights
  times c) rivals the data at levels 0-2 and counts for little above.  Tried with and without the revival
  above (threshold 0.2).  Zoom-32 error / flicker on the disk, against the default's 0.199 / 0.056:
  - literal count: 0.187 / 0.055;
  - literal count with revival: 0.167 / 0.062, which is 0.47x Toksvig's error.
  Elsewhere both lose a little: the scales' zoom-8 error is 0.225 and 0.233 against 0.219, and the dunes'
  is 0.0054 against 0.0049.
  In every fitting variant whose flicker was measured, a lower zoom-32 error on the disk came with higher
  flicker there.  The (error, flicker) pairs:
  - revival (0.179, 0.059); c = 16 (0.166, 0.071); c = 64 (0.125, 0.079); K = 8 (0.078, 0.063);
  - the unaligned GMM flickers 0.058 (0.059 with K = 8);
  - the literal count alone is the one exception, and it lowers the error too little.
  So no variant tried both halves Toksvig's error on the disk and keeps the lowest flicker there
  (``examples/filtering_scenes.py --run``, scratch builds;
  docs/measurements.md, "Reflectance filtering: measurements") -- on one frame
  pair.  Over the octave (eight pairs, ``--flicker-pairs 8``) c = 16 does: 0.166 (0.47x Toksvig's) with
  flicker 0.060 against the unaligned GMM's 0.065 (docs/measurements.md, session 32).

On the scales at zoom 32 the aligned GMM ties with the unaligned one (1.008x its error).  The two are not the
same mixtures (L1 distance between their densities 0.2-0.4 at levels 4-8), but the prior costs each texel some
fit: the L1 distance between a texel's mixture and the density of its footprint's normals (both widened by the
material's roughness 0.08; a 97 x 97 grid in normal space; up to 24 texels per level, the 1x1 level's one) is,
at levels 3 to 8, 0.435 / 0.420 / 0.431 / 0.452 / 0.455 / 0.470 aligned against 0.373 / 0.415 / 0.404 /
0.429 / 0.432 / 0.356 unaligned (session 28, a scratch script).  That poorer fit is not the whole cause: 004's
literal data count, which leaves the prior little weight above level 2, left the tie (0.130 against 0.128).
The four-Gaussian model limit binds: with 8 components per texel the aligned GMM's zoom-32 error on the scales
is 0.50x the unaligned GMM's (docs/measurements.md, "A stronger alignment prior, more components").
"""
from __future__ import annotations

import hashlib
import math
import numbers
import shlex
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from warpbw.errors import (SEED_MAX, WarpbwError, available_memory, check_count, check_flag, check_input_file,
                           check_path, check_real, is_int, numeric_array, warn_if_short_of_memory)

GMM_FORMAT = "warpbw-gmm-mipmap"
# 2: the fourth stored quantity is a (d s^2 + |mu|^2) (module docstring); 1 held 004's a (s^2 + |mu|^2).
GMM_VERSION = 2
# A non-square height map's rows are 1 / H apart (precompute.surfaces.height_to_normals; they were 1 / W before
# session 69): its builds say so in their parameters, and a file of such a map without it is refused by the renderer
ROW_SPACING_KEY = "row_spacing"
ROW_SPACING = "1/H"
# 004 Sec. 4.2: "Our current implementation utilizes mixtures of four Gaussians".
# The representation a file's parameters name (module docstring, "Representation")
NORMAL_SPACE = "projected (n_x, n_y); x = +column, y = -row"
# How a footprint the map's border clips weighs its texels: each equally (``_footprint_weights``, session 72); files
# from before record nothing, and were fitted with some texels of such footprints counted twice ("strata")
CLIPPED_FOOTPRINTS_KEY, CLIPPED_FOOTPRINTS = "clipped_footprints", "texels weighed equally"
# What a file records nothing of was fitted with: refine_sweeps is recorded only when it is not 0, and files before
# session 72 record neither how clipped footprints were weighed nor the fit's constants (``fit_constants``), which
# have had these values since the builder was written (git log -G)
GMM_UNRECORDED = {"refine_sweeps": 0, CLIPPED_FOOTPRINTS_KEY: "strata", "em_tolerance": 1e-4,
                  "em_max_iterations": 60, "kmeans_iterations": 10, "top_kmeans_restarts": 4,
                  "variance_floor": 1e-6, "weight_eps": 1e-8, "batch_elements": 1 << 21}
DEFAULT_COMPONENTS = 4
MAX_COMPONENTS = 16            # a sanity bound on --components (each is one texture in the renderer)
# 004 Sec. 4.1: c "modulates smoothness among corresponding Gaussians, which we set to 1 for all experiments".
DEFAULT_PRIOR = 1.0
# A sanity bound on c: beyond it the prior outweighs the data many times over (a typo), and near 1e308 the
# prior's weighted sums overflowed into NaN moments.  warpbw.scene.GMM_MAX_PRIOR spells the same bound.
MAX_PRIOR = 1.0e6
# d in the M-step for s_i^2 (004 Sec. 4.1): the dimension of the normal space.
NORMAL_DIM = 2
# Variance floor (per axis, projected-normal units^2).  A perfectly flat footprint would give s^2 = 0 and
# a Gaussian of zero width; the stored a*(d s^2 + |mu|^2) is float32, whose resolution near |mu|^2 <= 1 is
# 2^-24 ~ 6e-8, so a floor 16x above it keeps the recovered s^2 positive and within ~6%.  Std 1e-3 is
# ~0.06 degrees, far below any material roughness the renderer adds.
VARIANCE_FLOOR = 1e-6
# Footprint subsampling: one normal per cell of a 16 x 16 grid -> at most 256 normals per texel.
SAMPLE_GRID_SIDE = 16
DEFAULT_MAX_SAMPLES = SAMPLE_GRID_SIDE * SAMPLE_GRID_SIDE
# EM stops when no mean moves and no weight changes by more than this (projected units, ~0.006 degrees)...
EM_TOLERANCE = 1e-4
# ...or after this many iterations (EM converges linearly; 004 reports quick convergence).
EM_MAX_ITERATIONS = 60
# Lloyd iterations of the vectorised k-means initialisation.
KMEANS_ITERATIONS = 10
# k-means restarts of scikit-learn at the 1x1 top level.
TOP_KMEANS_RESTARTS = 4
# A component whose responsibilities sum below this (in samples) is empty: weight 0, and it keeps a
# defined mean (the prior's, or its previous one) and std (its previous one) instead of 0/0.
EMPTY_RESPONSIBILITY = 1e-9
# Stored weights below this recover as an empty component (mean 0, s^2 = VARIANCE_FLOOR).
WEIGHT_EPS = 1e-8
# What a file's moments may stray from a mixture of unit-disk normals by (float32 storage and sums; a texel's
# weights sum to 1 within 1.2e-7 in the builder's files): beyond it a hand-edited or damaged file would filter
# weights of 1000 or negative variances into the image (read_gmm_mipmap)
WEIGHT_SUM_TOL = 1e-3
MOMENT_TOL = 1e-5
# Texels x samples x components per vectorised batch (float64: ~16 MB per (T, M, K) array).
BATCH_ELEMENTS = 1 << 21
# Peak memory of a build per texel of the map and per component (ours; session 79, peak RSS of build_gmm_mipmap on
# synthetic height maps): 172 / 717 / 1396 bytes per texel at 1 / 4 / 8 components at 512^2, 720 at 4 components
# from 512^2 to 1024^2 (its float64 fits of every level, A, MU and S2, and their moments at the end), rounded up.  A
# build that would take more than the memory available warns first (MAX_MAP_SIDE^2 at 4 components: 48 GB).
BUILD_BYTES_PER_TEXEL_COMPONENT = 180
KINDS = ("height", "normal")
# A [0, 1]-encoded 8-bit normal map stores z in steps of 2/255, so a texel at the horizon can decode to a
# z just below 0: normals up to one step below the tangent plane are taken as lying in it (z set to 0),
# normals further below are an error (an object-space map, or garbage, given as a tangent-space map).
NORMAL_Z_TOL = 2.0 / 255.0
# |v| = 1 within this: the texels of a float normal map hold the vectors themselves (a [0, 1]-encoded
# texel (n + 1) / 2 has |v|^2 = 1 + (n_x + n_y + n_z) / 2, about 1.5 on a flat map), and the normals
# given to build_gmm_mipmap are unit (half-float EXRs round each component by up to 2^-11)
UNIT_TOL = 1e-2


# --------------------------------------------------------------------------------------------------
# Input checks of the public numeric helpers.  Each helper checks its arguments once and calls its unchecked core
# (``_name``), which the builder calls on the map ``_validate`` checked: nothing is checked per EM batch or iteration.

def _checked(values, name: str, expected: str, shape=(...,), lo: float | None = None, lo_open: bool = False,
             at_least: tuple = ()) -> np.ndarray:
    """``values`` as finite float64 numbers of ``shape`` (``None`` items: any length; a leading ``...``: any leading
    axes), each >= ``lo`` (> with ``lo_open``), axis i at least ``at_least[i]`` long; else a one-line WarpbwError
    naming ``name`` (a wrong shape was numpy's broadcast error, NaN or a variance <= 0 a NaN result)."""
    a = numeric_array(values, name, expected)
    tail = shape[1:] if shape[:1] == (...,) else shape
    fits = (a.ndim >= len(tail) if shape[:1] == (...,) else a.ndim == len(tail)) \
        and all(t is None or n == t for n, t in zip(a.shape[a.ndim - len(tail):], tail)) \
        and all(n >= m for n, m in zip(a.shape, at_least))
    if not fits:
        raise WarpbwError(f"{name}: expected {expected}, got shape {a.shape}")
    bad = ~np.isfinite(a)
    if lo is not None:
        bad |= ~(a > lo) if lo_open else ~(a >= lo)
    if bad.any():
        k = int(np.argmax(bad.reshape(-1)))
        raise WarpbwError(f"{name}: expected {expected}, {int(bad.sum())} of {a.size} values are not (the first: "
                          f"{a.reshape(-1)[k]!r})")
    return a


def _checked_components(a, mu, s2, where: str, lead: tuple = (...,)):
    """Weights a (``lead``, K) >= 0, means mu (a's shape, 2) and variances s2 (a's shape) > 0, all finite, checked."""
    a = _checked(a, f"{where}: a", f"finite weights ({'..., ' if lead == (...,) else 'T, '}K) >= 0", lead + (None,),
                 lo=0.0)
    mu = _checked(mu, f"{where}: mu", f"finite means of shape {a.shape + (2,)} (a's, then 2)", a.shape + (2,))
    s2 = _checked(s2, f"{where}: s2", f"finite variances of shape {a.shape} (a's) > 0", a.shape, lo=0.0, lo_open=True)
    return a, mu, s2


# --------------------------------------------------------------------------------------------------
# The filterable form (004 Sec. 4.2)

def to_moments(a, mu, s2) -> np.ndarray:
    """(..., K), (..., K, 2), (..., K) -> (..., K, 4): (a, a mu_x, a mu_y, a (d s^2 + |mu|^2)), s^2 per axis
    (the filterable form, module docstring; 004 Sec. 4.2)."""
    return _to_moments(*_checked_components(a, mu, s2, "to_moments"))


def _to_moments(a, mu, s2) -> np.ndarray:
    a = np.asarray(a, np.float64)
    mu = np.asarray(mu, np.float64)
    s2 = np.asarray(s2, np.float64)
    return np.stack([a, a * mu[..., 0], a * mu[..., 1], a * (NORMAL_DIM * s2 + np.sum(mu * mu, axis=-1))],
                    axis=-1)


def from_moments(q):
    """Inverse of ``to_moments`` (004 Sec. 4.2: mu = T(a mu)/T(a); s^2 = (T(a E|n|^2)/T(a) - |mu|^2) / d).
    Safe for a = 0: such a component comes back with mean 0 and s^2 = VARIANCE_FLOOR."""
    return _from_moments(_checked(q, "from_moments: q", "finite moments (..., K, 4)", (..., None, 4)))


def _from_moments(q):
    q = np.asarray(q, np.float64)
    a = q[..., 0]
    ok = a > WEIGHT_EPS
    inv = np.where(ok, 1.0 / np.where(ok, a, 1.0), 0.0)
    mu = q[..., 1:3] * inv[..., None]
    s2 = np.where(ok, (q[..., 3] * inv - np.sum(mu * mu, axis=-1)) / NORMAL_DIM, VARIANCE_FLOOR)
    return np.where(ok, a, 0.0), mu, np.maximum(s2, VARIANCE_FLOOR)


def filter_moments(q, weights, axis: int = 0) -> np.ndarray:
    """Linear (bi/trilinear) filtering of stored moments: sum_k w_k q_k along ``axis`` (what the texture
    unit does at run time, 004 Sec. 4.2)."""
    q = _checked(q, "filter_moments: q", "finite moments (..., 4)", (..., 4))
    axis = _checked_axis(axis, q.ndim, "filter_moments", "moments")
    _checked(weights, "filter_moments: weights", f"{q.shape[axis]} finite filter weights (q's axis {axis})",
             (q.shape[axis],))
    q = np.moveaxis(np.asarray(q, np.float64), axis, 0)
    w = np.asarray(weights, np.float64)
    return np.tensordot(w, q, axes=(0, 0))


def moment_match(a, mu, s2, weights, axis: int = 0):
    """Closed-form interpolation of corresponding components (004 Sec. 4.2 and Appendix, in the isotropic
    form of the module docstring): with filter weights w_k, a = sum w_k a_k, mu = sum w_k a_k mu_k / a,
    s^2 = (sum w_k a_k (d s_k^2 + |mu_k|^2) / a - |mu|^2) / d -- the isotropic Gaussian with the weighted
    mixture's mean and second moment (per axis, its total variance over d)."""
    a, mu, s2 = _checked_components(a, mu, s2, "moment_match")
    axis = _checked_axis(axis, a.ndim, "moment_match", "components")
    w = _checked(weights, "moment_match: weights", f"{a.shape[axis]} finite filter weights (a's axis {axis})",
                 (a.shape[axis],))
    a_f = np.tensordot(w, np.moveaxis(a, axis, 0), axes=(0, 0))
    if not np.all(a_f > 0):   # mu = sum w_k a_k mu_k / a: 0/0
        raise WarpbwError(f"moment_match: the filtered weight sum w_k a_k is not > 0 at {int(np.sum(~(a_f > 0)))} of "
                          f"{a_f.size} places (no component to match there)")
    a = np.moveaxis(np.asarray(a, np.float64), axis, 0)
    mu = np.moveaxis(np.asarray(mu, np.float64), axis, 0)
    s2 = np.moveaxis(np.asarray(s2, np.float64), axis, 0)
    w = np.asarray(weights, np.float64).reshape((-1,) + (1,) * (a.ndim - 1))
    a_f = np.sum(w * a, axis=0)
    mu_f = np.sum((w * a)[..., None] * mu, axis=0) / a_f[..., None]
    second = np.sum(w * a * (NORMAL_DIM * s2 + np.sum(mu * mu, axis=-1)), axis=0) / a_f
    s2_f = (second - np.sum(mu_f * mu_f, axis=-1)) / NORMAL_DIM
    return a_f, mu_f, s2_f


# --------------------------------------------------------------------------------------------------
# Normal space, levels, footprints

def _checked_axis(axis, ndim: int, where: str, last: str) -> int:
    """``axis`` of an array of ``ndim`` axes as numpy counts them, any but the last (``last``), as 0 .. ndim - 2."""
    if not (is_int(axis) and -ndim <= axis < ndim and axis % ndim != ndim - 1):
        raise WarpbwError(f"{where}: axis: expected an integer from {-ndim} to {ndim - 2}, not {-1} or {ndim - 1} "
                          f"(the {last}), got {axis!r}")
    return int(axis) % ndim


def normal_space(normals) -> np.ndarray:
    """Unit normals (..., 3) -> projected coordinates (n_x, n_y) (..., 2) (004 Sec. 3)."""
    n = _checked(normals, "normal_space: normals", "finite normals (..., 3)", (..., 3))
    if not np.all(np.linalg.norm(n, axis=-1) > 0):   # 0/0
        raise WarpbwError(f"normal_space: normals: expected non-zero normals, "
                          f"{int(np.sum(~(np.linalg.norm(n, axis=-1) > 0)))} of {n.size // 3} are (0, 0, 0)")
    return _normal_space(n)


def _normal_space(normals) -> np.ndarray:
    n = np.asarray(normals, np.float64)
    return n[..., :2] / np.linalg.norm(n, axis=-1, keepdims=True)


def level_shapes(h: int, w: int) -> list:
    """(h_l, w_l) of every level, finest first: ceil-halving down to 1x1 (a 1x1 map has one level)."""
    if not (is_int(h) and is_int(w) and h >= 1 and w >= 1):   # 0 never halves to 1: the loop never ended
        raise WarpbwError(f"map size {w!r}x{h!r} (width x height): expected at least 1x1 texels")
    shapes = [(int(h), int(w))]
    while shapes[-1] != (1, 1):
        hh, ww = shapes[-1]
        shapes.append(((hh + 1) // 2, (ww + 1) // 2))
    return shapes


def footprint_samples(n2, level: int, max_samples: int = DEFAULT_MAX_SAMPLES, rng=None) -> np.ndarray:
    """The finest-level normals of each level-``level`` texel's footprint: (h_l * w_l, M, 2), row-major
    texels.  M = 4^level when that is at most ``max_samples`` (every normal, once, for full footprints);
    otherwise one jittered normal per cell of a g x g grid over the footprint (g^2 <= max_samples, seeded).
    Footprints clipped by the map's border are covered by the same M samples: jittered cells over the clipped
    footprint, or the 2^l x 2^l slots spread over its texels, some of which then take two (the builder weighs
    them by ``_footprint_weights``, so that each texel counts once)."""
    n2 = _checked(n2, "footprint_samples: n2", "a finite map (H, W, C) of at least 1x1 texels", (None, None, None),
                  at_least=(1, 1))
    top = len(level_shapes(*n2.shape[:2])) - 1
    level = check_count(level, f"footprint_samples: level (of a {n2.shape[1]}x{n2.shape[0]} map)", 0, top)
    max_samples = check_count(max_samples, "footprint_samples: max_samples", 1)
    return _footprint_samples(n2, level, max_samples, rng)


def _grid_side(f: int, max_samples: int) -> int:
    """Samples per axis of a footprint f texels wide: every texel (g = f, enumerated) while f^2 <= ``max_samples``,
    else one per cell of a g x g grid, g^2 <= ``max_samples``."""
    return min(f, max(1, int(math.isqrt(int(max_samples)))))


def _block_sides(size: int, f: int) -> np.ndarray:
    """Texels of each f-texel block along an axis of ``size`` texels: f, and the border's clipped remainder last."""
    return np.minimum(f, size - np.arange(-(-size // f)) * f).astype(np.float64)


def _footprint_samples(n2, level: int, max_samples: int = DEFAULT_MAX_SAMPLES, rng=None) -> np.ndarray:
    n2 = np.asarray(n2)
    H, W = n2.shape[:2]
    f = 1 << level
    h_l, w_l = -(-H // f), -(-W // f)
    g = _grid_side(f, max_samples)
    r0 = np.arange(h_l) * f
    c0 = np.arange(w_l) * f
    nr = _block_sides(H, f)
    nc = _block_sides(W, f)
    cell = np.arange(g, dtype=np.float64)
    if g == f:      # enumerate: stratum centres are the texels themselves
        ju = jv = 0.5
    else:
        rng = np.random.default_rng(rng)
        ju = rng.random((h_l, w_l, g, g))
        jv = rng.random((h_l, w_l, g, g))
    rows = r0[:, None, None, None] + np.floor((cell[None, None, :, None] + jv) * nr[:, None, None, None] / g)
    cols = c0[None, :, None, None] + np.floor((cell[None, None, None, :] + ju) * nc[None, :, None, None] / g)
    rows = np.broadcast_to(rows, (h_l, w_l, g, g)).astype(np.int64)
    cols = np.broadcast_to(cols, (h_l, w_l, g, g)).astype(np.int64)
    return n2[rows, cols].reshape(h_l * w_l, g * g, n2.shape[-1])


def _footprint_weights(H: int, W: int, level: int, max_samples: int = DEFAULT_MAX_SAMPLES) -> np.ndarray | None:
    """Per-sample weights (h_l * w_l, M) that weigh every texel of a footprint equally in ``_footprint_samples``'
    samples, mean 1 per texel; None when they are all 1.  Jittered strata cover a clipped footprint uniformly, but
    enumerated ones (a footprint of at most ``max_samples`` texels) put 2^l slots per axis on the n < 2^l texels the
    border leaves: where n does not divide 2^l some texels take two slots (a 7-texel side: one of them 2/8 of the
    weight, the others 1/8).  A slot's weight is (2^l / n) / (the slots its texel takes), per axis."""
    f = 1 << level
    if _grid_side(f, max_samples) != f:
        return None

    def per_axis(size: int) -> np.ndarray:   # (blocks, f): the weight of each slot along one axis
        n = _block_sides(size, f)[:, None]
        texel = np.floor((np.arange(f) + 0.5) * n / f)                           # the slot's texel, as above
        slots = np.sum(texel[:, :, None] == texel[:, None, :], axis=-1)          # slots its texel takes
        return (f / n) / slots

    wr, wc = per_axis(H), per_axis(W)
    if np.all(wr == 1.0) and np.all(wc == 1.0):
        return None
    return (wr[:, None, :, None] * wc[None, :, None, :]).reshape(wr.shape[0] * wc.shape[0], f * f)


# --------------------------------------------------------------------------------------------------
# Clustering initialisation and EM, vectorised over texels

def _sq_dist(x, mu):
    """|x_j - mu_k|^2: (T, M, 2), (T, K, 2) -> (T, M, K)."""
    d2 = (np.sum(x * x, axis=-1)[:, :, None] - 2.0 * np.einsum("tmd,tkd->tmk", x, mu)
          + np.sum(mu * mu, axis=-1)[:, None, :])
    return np.maximum(d2, 0.0)


def kmeans_plus_plus(x, K: int, rng) -> np.ndarray:
    """Seeded k-means++ seeding per texel, vectorised: (T, M, 2) -> centres (T, K, 2)."""
    x = _checked_samples(x, "kmeans_plus_plus")
    return _kmeans_plus_plus(x, check_count(K, "kmeans_plus_plus: K (components)", 1), rng)


def _checked_samples(x, where: str) -> np.ndarray:
    """Samples x (T, M, 2), M >= 1, finite."""
    return _checked(x, f"{where}: x", "finite samples (T, M, 2) of at least 1 per texel", (None, None, 2),
                    at_least=(0, 1))


def _kmeans_plus_plus(x, K: int, rng, w=None) -> np.ndarray:
    """``w`` (T, M): the samples' weights (``_footprint_weights``), None: all 1."""
    rng = np.random.default_rng(rng)
    T, M, _ = x.shape
    t = np.arange(T)
    centres = np.empty((T, K, 2))
    if w is None:
        centres[:, 0] = x[t, rng.integers(0, M, size=T)]
    else:   # the first centre drawn in proportion to the weights
        cdf = np.cumsum(w, axis=1)
        centres[:, 0] = x[t, np.minimum(np.sum(cdf < (rng.random(T) * cdf[:, -1])[:, None], axis=1), M - 1)]
    mind = np.sum((x - centres[:, :1]) ** 2, axis=-1)
    for k in range(1, K):
        cdf = np.cumsum(mind if w is None else w * mind, axis=1)
        u = rng.random(T) * cdf[:, -1]
        j = np.minimum(np.sum(cdf < u[:, None], axis=1), M - 1)
        centres[:, k] = x[t, j]
        mind = np.minimum(mind, np.sum((x - centres[:, k:k + 1]) ** 2, axis=-1))
    return centres


def kmeans_init(x, centres, iterations: int = KMEANS_ITERATIONS, fallback_s2=None):
    """Lloyd iterations from ``centres`` (T, K, 2), vectorised; returns the initial (a, mu, s2) of EM:
    cluster fractions, centroids, within-cluster variance per axis (``iterations=0``: the given centres, and the
    nearest-centre assignment's fractions and spread about them).  An empty cluster keeps its centre,
    weight 0 and ``fallback_s2`` (T, K) (default: the texel's variance per axis), floored."""
    x = _checked_samples(x, "kmeans_init")
    centres = _checked(centres, "kmeans_init: centres", f"finite centres ({x.shape[0]}, K, 2) (x's T)",
                       (x.shape[0], None, 2), at_least=(0, 1))
    iterations = check_count(iterations, "kmeans_init: iterations", 0)
    if fallback_s2 is not None:
        fallback_s2 = _checked(fallback_s2, "kmeans_init: fallback_s2",
                               f"finite variances of shape {centres.shape[:2]} (centres' T, K) > 0",
                               centres.shape[:2], lo=0.0, lo_open=True)
    return _kmeans_init(x, centres, iterations, fallback_s2)


def _kmeans_init(x, centres, iterations: int = KMEANS_ITERATIONS, fallback_s2=None, w=None):
    """``w`` (T, M): the samples' weights, mean 1 per texel (``_footprint_weights``); None: all 1."""
    x = np.asarray(x, np.float64)
    mu = np.array(centres, np.float64)
    T, M, _ = x.shape
    K = mu.shape[1]
    ks = np.arange(K)

    def assigned(lab):   # (T, M, K): each sample's weight on its cluster
        onehot = (lab[..., None] == ks).astype(np.float64)
        return onehot if w is None else onehot * w[..., None]

    for _ in range(iterations):   # 0: the centres kept (max(1, .) ran one step, as 1 did)
        lab = np.argmin(_sq_dist(x, mu), axis=-1)
        onehot = assigned(lab)
        cnt = onehot.sum(axis=1)
        sums = np.einsum("tmk,tmd->tkd", onehot, x)
        new = np.where(cnt[..., None] > 0, sums / np.where(cnt > 0, cnt, 1.0)[..., None], mu)
        done = np.array_equal(new, mu)
        mu = new
        if done:
            break
    lab = np.argmin(_sq_dist(x, mu), axis=-1)
    onehot = assigned(lab)
    cnt = onehot.sum(axis=1)
    within = np.einsum("tmk,tmk->tk", onehot, _sq_dist(x, mu))
    if fallback_s2 is None and w is None:
        fallback_s2 = np.broadcast_to(np.var(x, axis=1).mean(axis=-1)[:, None], (T, K))
    elif fallback_s2 is None:   # the weighted variance per axis
        mean = np.einsum("tm,tmd->td", w, x) / M
        var = np.einsum("tm,tmd->td", w, (x - mean[:, None, :]) ** 2) / M
        fallback_s2 = np.broadcast_to(var.mean(axis=-1)[:, None], (T, K))
    s2 = np.where(cnt > 0, within / (NORMAL_DIM * np.where(cnt > 0, cnt, 1.0)), fallback_s2)
    return cnt / M, mu, np.maximum(s2, VARIANCE_FLOOR)


def em_fit(x, a, mu, s2, c: float = 0.0, prior_sum=None, prior_weight=None,
           max_iter: int = EM_MAX_ITERATIONS, tol: float = EM_TOLERANCE, sample_count: float | None = None):
    """MAP-EM of 004 Sec. 4.1 on T texels at once: samples x (T, M, 2); initial a (T, K), mu (T, K, 2),
    s2 (T, K).  The prior enters as prior_sum = sum_k a_ki mu_ki (T, K, 2) and prior_weight = sum_k a_ki
    (T, K) over the valid neighbours k; c = 0 (or no prior) is plain EM.  ``sample_count`` is the M the
    data term counts (default: M, the samples given; the builder passes ``max_samples``, as if that many
    samples were drawn from every footprint, see ``build_gmm_mipmap``); it only sets the data's weight
    against the prior.  Stops when the largest change of a mean or weight is below ``tol`` (``tol=0``:
    exactly ``max_iter`` iterations).  Returns float64 (a, mu, s2, iterations)."""
    x = _checked_samples(x, "em_fit")
    a, mu, s2 = _checked_components(a, mu, s2, "em_fit", lead=(x.shape[0],))
    if not np.all(a.sum(axis=-1) > 0):   # log a = -inf for every component: NaN responsibilities
        raise WarpbwError(f"em_fit: a: expected weights of sum > 0 per texel, {int(np.sum(~(a.sum(axis=-1) > 0)))} "
                          f"of {a.shape[0]} texels have none")
    c = check_real(c, "em_fit: c (prior weight)", 0.0)
    if prior_sum is not None:
        prior_sum = _checked(prior_sum, "em_fit: prior_sum", f"finite sums of shape {mu.shape} (mu's)", mu.shape)
    if prior_weight is not None:
        prior_weight = _checked(prior_weight, "em_fit: prior_weight", f"finite weights of shape {a.shape} (a's) >= 0",
                                a.shape, lo=0.0)
    max_iter = check_count(max_iter, "em_fit: max_iter", 0)
    tol = check_real(tol, "em_fit: tol", 0.0)
    if sample_count is not None:
        sample_count = check_real(sample_count, "em_fit: sample_count", 0.0, lo_open=True)
    return _em_fit(x, a, mu, s2, c, prior_sum, prior_weight, max_iter, tol, sample_count)


def _em_fit(x, a, mu, s2, c: float = 0.0, prior_sum=None, prior_weight=None,
            max_iter: int = EM_MAX_ITERATIONS, tol: float = EM_TOLERANCE, sample_count: float | None = None, w=None):
    """``w`` (T, M): the samples' weights, mean 1 per texel (``_footprint_weights``); None: all 1."""
    x = np.asarray(x, np.float64)
    a = np.array(a, np.float64)
    mu = np.array(mu, np.float64)
    s2 = np.maximum(np.array(s2, np.float64), VARIANCE_FLOOR)
    T, M, _ = x.shape
    use_prior = c > 0 and prior_sum is not None and prior_weight is not None
    if use_prior:
        p_sum = c * np.asarray(prior_sum, np.float64)
        p_w = c * np.asarray(prior_weight, np.float64)
    xx = np.sum(x * x, axis=-1)                                     # (T, M)
    # data weight of one sample; it cancels without a prior, so c = 0 stays plain EM bit for bit
    per_sample = float(sample_count) / M if (use_prior and sample_count is not None) else 1.0
    it = 0
    for it in range(1, max_iter + 1):
        # E-step: E[z_ij] = a_i g(n_j; mu_i, s_i) / sum_k a_k g(n_j; mu_k, s_k)   (004 Sec. 4.1)
        d2 = np.maximum(xx[:, :, None] - 2.0 * np.einsum("tmd,tkd->tmk", x, mu)
                        + np.sum(mu * mu, axis=-1)[:, None, :], 0.0)
        with np.errstate(divide="ignore"):
            log_a = np.log(a)
        # log of a_i g(n; mu_i, s_i) with g the isotropic 2D Gaussian: (2 pi s^2)^-1 exp(-|n - mu|^2 / (2 s^2))
        logp = log_a[:, None, :] - d2 / (2.0 * s2[:, None, :]) - np.log(2.0 * np.pi * s2)[:, None, :]
        logp -= logp.max(axis=-1, keepdims=True)
        r = np.exp(logp)
        r /= r.sum(axis=-1, keepdims=True)
        if w is not None:   # a sample's responsibilities count its weight
            r *= w[..., None]
        # M-step (004 Sec. 4.1):
        #   a_i = (1/M) sum_j E[z_ij]
        #   mu_i = (sum_j E[z_ij] n_j + c sum_k a_ki mu_ki) / (sum_j E[z_ij] + c sum_k a_ki)
        #   s_i^2 = sum_j E[z_ij] |n_j - mu_i|^2 / (d sum_j E[z_ij]),  d = 2
        nk = r.sum(axis=1)                                          # (T, K)
        s1 = np.einsum("tmk,tmd->tkd", r, x)                        # (T, K, 2)
        s_xx = np.einsum("tmk,tm->tk", r, xx)                       # (T, K)
        if per_sample != 1.0:
            nk, s1, s_xx = nk * per_sample, s1 * per_sample, s_xx * per_sample
        num, den = s1, nk
        if use_prior:
            num, den = s1 + p_sum, nk + p_w
        has = den > EMPTY_RESPONSIBILITY
        mu_new = np.where(has[..., None], num / np.where(has, den, 1.0)[..., None], mu)
        full = nk > EMPTY_RESPONSIBILITY
        spread = s_xx - 2.0 * np.sum(mu_new * s1, axis=-1) + nk * np.sum(mu_new * mu_new, axis=-1)
        s2_new = np.where(full, spread / (NORMAL_DIM * np.where(full, nk, 1.0)), s2)
        s2_new = np.maximum(s2_new, VARIANCE_FLOOR)
        a_new = np.where(full, nk / (M * per_sample), 0.0)
        change = max(float(np.abs(mu_new - mu).max(initial=0.0)), float(np.abs(a_new - a).max(initial=0.0)))
        a, mu, s2 = a_new, mu_new, s2_new
        if change < tol:
            break
    return a, mu, s2, it


def _batched(T: int, per_texel: int):
    step = max(1, BATCH_ELEMENTS // max(1, per_texel))
    for start in range(0, T, step):
        yield slice(start, min(T, start + step))


# --------------------------------------------------------------------------------------------------
# The builder

@dataclass
class GmmMipmap:
    """A GMM normal mipmap: ``levels[l]`` is float32 (h_l, w_l, K, 4) = (a, a mu_x, a mu_y,
    a (2 s^2 + |mu|^2)) per component (s^2 per axis: the filterable form), level 0 finest."""

    levels: list
    components: int = DEFAULT_COMPONENTS
    prior: float = DEFAULT_PRIOR
    unaligned: bool = False
    kind: str = "height"
    scale: float = 1.0
    seed: int = 0
    max_samples: int = DEFAULT_MAX_SAMPLES
    extra: dict = field(default_factory=dict)
    source: str | None = None          # read from a file: the map it was built from, and that map's content hash
    source_hash: str | None = None

    @property
    def shape(self):
        return self.levels[0].shape[:2]

    def params(self) -> dict:
        return {"components": int(self.components), "prior": float(self.prior), "unaligned": bool(self.unaligned),
                "kind": self.kind, "scale": float(self.scale), "seed": int(self.seed),
                "max_samples": int(self.max_samples), "levels": len(self.levels),
                "shape": [int(s) for s in self.shape],
                "normal_space": NORMAL_SPACE, **self.extra}


def fit_settings(seed: int = 0, max_samples: int = DEFAULT_MAX_SAMPLES, refine_sweeps: int = 0) -> dict:
    """The fit's settings beyond the map and the material's (kind, scale, components, prior, unaligned), as a file's
    parameters record them (``GMM_UNRECORDED`` for what they leave out): the renderer builds its cache entries with
    ``fit_settings()`` and rebuilds an entry that records others (``precompute.brdf_sampling.load_or_build``).  The
    values are checked as ``build_gmm_mipmap`` checks them (1.5, "1" or True were recorded as 1, -1 as -1)."""
    return {"seed": check_count(seed, "seed", 0, SEED_MAX), "max_samples": check_count(max_samples, "max_samples", 1),
            "refine_sweeps": check_count(refine_sweeps, "refine_sweeps", 0),
            "normal_space": NORMAL_SPACE, **fit_constants()}


def fit_constants() -> dict:
    """The module's constants a fit depends on, as a file records them (read now: a changed constant makes the
    cache's entries stale) -- how clipped footprints weigh their texels, EM's and k-means' stopping rules, the
    variance floor, the empty-weight threshold and the batch size (the unaligned fit's random draws follow it)."""
    return {CLIPPED_FOOTPRINTS_KEY: CLIPPED_FOOTPRINTS, "em_tolerance": EM_TOLERANCE,
            "em_max_iterations": EM_MAX_ITERATIONS, "kmeans_iterations": KMEANS_ITERATIONS,
            "top_kmeans_restarts": TOP_KMEANS_RESTARTS, "variance_floor": VARIANCE_FLOOR, "weight_eps": WEIGHT_EPS,
            "batch_elements": BATCH_ELEMENTS}


def _neighbour_prior(l, ii, jj, A, MU, fitted, shapes):
    """sum_k a_ki mu_ki and sum_k a_ki over the valid (already fitted) neighbours of texels (ii, jj) of
    level l: eight at the same level (wrap-around: the map tiles), the parent, four children (004 Sec. 4.1)."""
    n = ii.size
    K = A[l].shape[-1]
    p_sum = np.zeros((n, K, 2))
    p_w = np.zeros((n, K))

    def add(level, ni, nj, valid):
        wa = A[level][ni, nj] * valid[:, None]
        p_w[...] += wa
        p_sum[...] += wa[..., None] * MU[level][ni, nj]

    h, w = shapes[l]
    offs_r = (-1, 0, 1) if h >= 3 else tuple(range(h))
    offs_c = (-1, 0, 1) if w >= 3 else tuple(range(w))
    for di in offs_r:
        for dj in offs_c:
            if di == 0 and dj == 0:
                continue
            ni, nj = (ii + di) % h, (jj + dj) % w
            add(l, ni, nj, fitted[l][ni, nj] & ~((ni == ii) & (nj == jj)))
    if l + 1 < len(shapes):
        add(l + 1, ii // 2, jj // 2, fitted[l + 1][ii // 2, jj // 2])
    if l >= 1:
        hc, wc = shapes[l - 1]
        for di in (0, 1):
            for dj in (0, 1):
                ci, cj = 2 * ii + di, 2 * jj + dj
                inside = (ci < hc) & (cj < wc)
                ci, cj = np.minimum(ci, hc - 1), np.minimum(cj, wc - 1)
                add(l - 1, ci, cj, inside & fitted[l - 1][ci, cj])
    return p_sum, p_w


def _top_centres(x, K: int, seed: int, w=None) -> np.ndarray:
    """k-means (scikit-learn) on the whole map's normals -> (K, 2) centres, largest cluster first; with
    fewer distinct normals than K the extra centres repeat the first (they start empty).  ``w`` (M,): the samples'
    weights (``_footprint_weights``); None: all 1."""
    from sklearn.cluster import KMeans

    distinct = np.unique(x, axis=0)
    k = min(K, len(distinct))
    if k == len(distinct):
        centres = distinct
        counts = np.array([np.sum(np.all(x == c, axis=-1) if w is None else w[np.all(x == c, axis=-1)])
                           for c in distinct])
    else:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            km = KMeans(n_clusters=k, n_init=TOP_KMEANS_RESTARTS, random_state=seed).fit(x, sample_weight=w)
        centres = km.cluster_centers_
        counts = np.bincount(km.labels_, weights=w, minlength=k)
    centres = centres[np.argsort(-counts, kind="stable")]
    if k < K:
        centres = np.concatenate([centres, np.repeat(centres[:1], K - k, axis=0)])
    return centres


def build_memory(height: int, width: int, components: int) -> int:
    """Bytes ``build_gmm_mipmap`` takes at the peak for a ``height`` x ``width`` map of ``components`` Gaussians per
    texel (``BUILD_BYTES_PER_TEXEL_COMPONENT``)."""
    return BUILD_BYTES_PER_TEXEL_COMPONENT * int(components) * int(height) * int(width)


def _validate(data, kind, components, prior, scale):
    if kind not in KINDS:
        raise WarpbwError(f"kind {kind!r}: expected one of {', '.join(KINDS)}")
    # the command line's ranges (_valid_option); "2", None, [1, 2], True: refused here, not by numpy
    if not _valid_option("components", components):
        raise WarpbwError(f"components {components!r}: expected an integer from 1 to {MAX_COMPONENTS}")
    if not _valid_option("prior", prior):
        raise WarpbwError(f"prior {prior!r}: expected a finite c >= 0, at most {MAX_PRIOR:g}")
    if not _valid_option("scale", scale):
        raise WarpbwError(f"scale {scale!r}: expected a finite number > 0")
    data = numeric_array(data, f"{kind} map", "(H, W) heights" if kind == "height" else "(H, W, 3) normals")
    want = 2 if kind == "height" else 3
    if data.ndim != want or (kind == "normal" and data.shape[-1] != 3) or data.size == 0:
        raise WarpbwError(f"{kind} map of shape {data.shape}: expected "
                          + ("(H, W) heights" if kind == "height" else "(H, W, 3) normals"))
    if not np.all(np.isfinite(data)):
        raise WarpbwError(f"{kind} map has {int(np.sum(~np.isfinite(data)))} NaN or infinite values")
    if kind == "normal":
        length = np.linalg.norm(data, axis=-1)
        off = np.abs(length - 1.0) > UNIT_TOL
        if off.any():
            r, c = np.argwhere(off)[0]
            raise WarpbwError(f"normal map: {int(off.sum())} normals are not unit vectors (first at row {r}, "
                              f"column {c}: length {length[r, c]:.4g}); expected unit tangent-space normals")
        _check_upward(data, "normal map")
        data = data / length[..., None]
    return data


def _check_upward(normals, where: str) -> None:
    """A one-line WarpbwError starting with ``where`` when some unit normals (H, W, 3) point below the
    tangent plane by more than ``NORMAL_Z_TOL``."""
    below = normals[..., 2] < -NORMAL_Z_TOL
    if below.any():
        r, c = np.argwhere(below)[0]
        raise WarpbwError(f"{where}: {int(below.sum())} texels hold normals pointing below the surface (first at "
                          f"row {r}, column {c}: z = {normals[r, c, 2]:.3f}); expected a tangent-space normal map "
                          "(z up, mostly blue)")


def build_gmm_mipmap(heights_or_normals, kind: str = "height", components: int = DEFAULT_COMPONENTS,
                     prior: float = DEFAULT_PRIOR, scale: float = 1.0, seed: int = 0, progress: bool = True,
                     unaligned: bool = False, texel_size: float | None = None,
                     max_samples: int = DEFAULT_MAX_SAMPLES, refine_sweeps: int = 0) -> GmmMipmap:
    """Build the GMM mipmap of a height field (H, W) (normals by ``height_to_normals(h, scale, texel_size)``)
    or of unit normals (H, W, 3) (``scale`` ignored).  See the module docstring for the method.

    The data term of the MAP objective counts ``max_samples`` samples at every level: a footprint of
    fewer normals (levels 0-3 with the default 256) weighs each of its normals ``max_samples / 4^l``
    times -- exactly what drawing ``max_samples`` stratified samples from it would give.  So c weighs
    the prior (at most ~13 neighbour weights) against the same amount of data at every level; counting
    a level-0 texel's single normal once would let the prior move it most of the way to its neighbours'."""
    from precompute.progress import progress_callback
    from precompute.surfaces import height_to_normals

    data = _validate(heights_or_normals, kind, components, prior, scale)
    seed = check_count(seed, "seed", 0, SEED_MAX)  # numpy's SeedSequence and scikit-learn take uint32 seeds
    max_samples = check_count(max_samples, "max_samples", 1)
    refine_sweeps = check_count(refine_sweeps, "refine_sweeps", 0)
    unaligned = check_flag(unaligned, "unaligned")   # "no" was truthy: an unaligned build
    if texel_size is not None and not (isinstance(texel_size, numbers.Real) and 0.0 < texel_size < math.inf):
        raise WarpbwError(f"texel_size: expected a finite length > 0 (or None: the map spans the unit square), got "
                          f"{texel_size!r}")
    K = int(components)
    c = 0.0 if unaligned else float(prior)
    # hours and tens of GB at the largest maps: the system stops a process that runs out without a word
    warn_if_short_of_memory(build_memory(data.shape[0], data.shape[1], K), available_memory(),
                            f"building the GMM mipmap of a {data.shape[1]}x{data.shape[0]} map ({K} components)",
                            "a smaller map, or fewer components")
    normals = height_to_normals(data, scale, texel_size) if kind == "height" else data
    n2 = _normal_space(normals)   # the map _validate checked: the helpers' unchecked cores below
    H, W = n2.shape[:2]
    shapes = level_shapes(H, W)
    L = len(shapes)
    A = [np.zeros(s + (K,)) for s in shapes]
    MU = [np.zeros(s + (K, 2)) for s in shapes]
    S2 = [np.full(s + (K,), VARIANCE_FLOOR) for s in shapes]
    fitted = [np.zeros(s, bool) for s in shapes]
    ss = np.random.SeedSequence(seed)
    sweeps = 1 if unaligned else 1 + max(0, int(refine_sweeps))
    # a bar over the normals fitted (texels times their footprints' samples), not levels (67 s without a word at
    # 2048^2) nor texels: the finest level holds three quarters of the texels but one normal each, and took 4% of a
    # 1024^2 build's time, levels 1-4 87% (at 96% of the time a bar over texels read 25%, over samples 84%; a 512^2
    # build's ETA read 35 min with 40 s left; session 79)
    samples = [h * w * _grid_side(1 << l, max_samples) ** 2 for l, (h, w) in enumerate(shapes)]
    with progress_callback(sweeps * sum(samples), "GMM mipmap", "sample", progress) as step:
        done = 0
        for sweep in range(sweeps):
            for l in range(L - 1, -1, -1):                       # coarse to fine (004 Sec. 4.1)
                rng = np.random.default_rng(ss.spawn(1)[0])
                x_all = _footprint_samples(n2, l, max_samples, rng)
                w_all = _footprint_weights(H, W, l, max_samples)   # None: every sample weighs 1
                h, w = shapes[l]
                M = x_all.shape[1]
                ii_all, jj_all = np.divmod(np.arange(h * w), w)
                if unaligned:
                    classes = [np.arange(h * w)]
                else:
                    classes = [np.flatnonzero((ii_all % 2 == pi) & (jj_all % 2 == pj))
                               for pi in (0, 1) for pj in (0, 1)]
                for idx in classes:
                    if idx.size == 0:
                        continue
                    ii, jj = ii_all[idx], jj_all[idx]
                    if not unaligned:
                        p_sum, p_w = _neighbour_prior(l, ii, jj, A, MU, fitted, shapes)
                    for b in _batched(idx.size, M * K):
                        x = x_all[idx[b]]
                        # a batch of unclipped footprints takes the unweighted path: their fits stay bit for bit
                        wx = None if w_all is None else w_all[idx[b]]
                        wx = None if wx is None or np.all(wx == 1.0) else wx
                        bi, bj = ii[b], jj[b]
                        if unaligned:
                            a0, mu0, s20 = _kmeans_init(x, _kmeans_plus_plus(x, K, rng, wx), w=wx)
                        elif sweep > 0:
                            a0, mu0, s20 = A[l][bi, bj], MU[l][bi, bj], S2[l][bi, bj]
                        elif l == L - 1:
                            top = _top_centres(x[0], K, seed, None if wx is None else wx[0])
                            a0, mu0, s20 = _kmeans_init(x, top[None], w=wx)
                        else:                                  # from the parent: component i keeps its meaning
                            a0, mu0, s20 = _kmeans_init(x, MU[l + 1][bi // 2, bj // 2],
                                                        fallback_s2=S2[l + 1][bi // 2, bj // 2], w=wx)
                        if unaligned:
                            a1, mu1, s21, _ = _em_fit(x, a0, mu0, s20, w=wx)
                        else:
                            a1, mu1, s21, _ = _em_fit(x, a0, mu0, s20, c, p_sum[b], p_w[b],
                                                      sample_count=max(M, max_samples), w=wx)
                        A[l][bi, bj], MU[l][bi, bj], S2[l][bi, bj] = a1, mu1, s21
                        done += (b.stop - b.start) * M
                        step(done)
                    fitted[l][ii, jj] = True
    levels = []
    for l in range(L):
        a = np.where(A[l] > WEIGHT_EPS, A[l], 0.0)
        # E|n|^2 = d s^2 + |mu|^2 <= 1 for normals in the unit disk, which the MAP fit can overstep: the prior
        # moves mu off its samples' mean, adding |mean - mu|^2 to their spread (steep random heights: E|n|^2 up to
        # 1 + 3e-4, a file its own reader refuses; mipmap_problem)
        s2_max = np.maximum((1.0 - np.sum(MU[l] * MU[l], axis=-1)) / NORMAL_DIM, VARIANCE_FLOOR)
        levels.append(_to_moments(a, MU[l], np.minimum(S2[l], s2_max)).astype(np.float32))
        if not np.all(np.isfinite(levels[-1])):   # never written: the renderer would refuse the file later
            raise WarpbwError(f"GMM fit of level {l} gave NaN or infinite moments (components {K}, prior {c:g}); "
                              "this is a defect, please report it with the map")
    extra = {"refine_sweeps": int(refine_sweeps)} if refine_sweeps else {}
    extra.update(fit_constants())
    if kind == "height" and texel_size is None and H != W:
        extra[ROW_SPACING_KEY] = ROW_SPACING   # what a renderer checks before it shades with a non-square map's file
    return GmmMipmap(levels, K, float(prior), bool(unaligned), kind, float(scale), int(seed), int(max_samples),
                     extra=extra)


# --------------------------------------------------------------------------------------------------
# Files

def _valid_option(key: str, value) -> bool:
    """Whether ``warpbw-precompute gmm --KEY VALUE`` would be accepted (for ``rebuild_command`` and
    ``mipmap_problem``)."""
    if isinstance(value, bool):
        return key == "unaligned"
    if key == "kind":
        return value in KINDS
    if key in ("components", "seed"):
        return is_int(value) and (1 <= value <= MAX_COMPONENTS if key == "components" else 0 <= value <= SEED_MAX)
    if key in ("prior", "scale"):
        return isinstance(value, numbers.Real) and math.isfinite(value) and \
            (0.0 <= value <= MAX_PRIOR if key == "prior" else value > 0.0)
    return False


def rebuild_command(source: str, params=None, out="OUT") -> str:
    """The ``warpbw-precompute gmm`` line that rebuilds a mipmap of ``source`` into ``out`` with the options
    ``params`` (a header's, or a material's) records (those that differ from the defaults: a normal map rebuilt
    without ``--kind normal`` was read as heights), quoted for a POSIX shell.  ``str`` of a float is the shortest
    text that reads back as it (``:g`` kept six digits: a prior of 0.1234567891 was rebuilt as 0.123457).  A value
    the tool would refuse (a damaged header's prior of NaN, a scale of "abc") is left out: the default rebuilds."""
    p = {k: v for k, v in (params if isinstance(params, dict) else {}).items() if _valid_option(k, v)}
    unaligned = p.get("unaligned") is True
    # the CLI refuses --prior with --unaligned, and --scale with a normal map
    unused = ({"prior"} if unaligned else set()) | ({"scale"} if p.get("kind", "height") != "height" else set())
    defaults = {"kind": "height", "components": DEFAULT_COMPONENTS, "prior": DEFAULT_PRIOR, "scale": 1.0, "seed": 0}
    words = ["warpbw-precompute", "gmm", str(source), "-o", str(out)]
    for key, default in defaults.items():
        if key in p and key not in unused and p[key] != default:
            words += [f"--{key}", str(p[key])]
    return " ".join(shlex.quote(w) for w in words + ["--unaligned"] * unaligned + ["--force"])


def mipmap_problem(levels, components, prior, scale) -> str | None:
    """What makes ``levels`` (float32 moments, finest first) no GMM mipmap of ``components`` components fitted
    with ``prior`` at height ``scale``, or None: shapes that do not halve, non-finite moments, negative weights,
    a texel's weights not summing to 1, a second moment beyond the unit disk or below the squared mean (a negative
    variance).  What the writer and the reader both check; the parameters are held to what the command line takes
    (``_valid_option``)."""
    if not _valid_option("components", components):
        return f"{components!r} components (expected 1 to {MAX_COMPONENTS})"
    if not _valid_option("prior", prior):
        return f"prior {prior!r} (expected 0 to {MAX_PRIOR:g})"
    if not _valid_option("scale", scale):
        return f"height scale {scale!r} (expected a finite value above 0)"
    if not levels or levels[0].ndim != 4:
        return "no levels" if not levels else f"level 0 of shape {levels[0].shape} (expected (h, w, K, 4))"
    shapes = level_shapes(*levels[0].shape[:2])
    if len(shapes) != len(levels) or any(q.shape != s + (components, 4) for q, s in zip(levels, shapes)):
        return (f"levels of shapes {[tuple(q.shape) for q in levels]} (expected {components} components of 4 "
                f"moments on levels {shapes})")
    for l, q in enumerate(levels):
        if not np.all(np.isfinite(q)):   # NaN moments filtered into the image silently
            return f"NaN or infinite moments at level {l}"
        a, qe = q[..., 0].astype(np.float64), q[..., 3].astype(np.float64)
        m2 = np.square(q[..., 1:3].astype(np.float64)).sum(axis=-1)
        if np.any(a < -MOMENT_TOL):
            return f"negative weights at level {l} (down to {a.min():.3g})"
        total = a.sum(axis=-1)
        if np.any(np.abs(total - 1.0) > WEIGHT_SUM_TOL):
            return (f"a texel's weights sum to {total.min():.6g} to {total.max():.6g} at level {l} "
                    f"(expected 1)")
        if np.any(qe > a * (1.0 + MOMENT_TOL) + MOMENT_TOL):    # |n| <= 1: E|n|^2 <= 1
            return f"second moments beyond the unit disk of projected normals at level {l}"
        if np.any(a * qe < m2 - MOMENT_TOL * a * a - MOMENT_TOL * MOMENT_TOL):   # E|n|^2 >= |mu|^2
            return f"second moments below the squared means (negative variances) at level {l}"
    return None


def write_gmm_mipmap(path, mip: GmmMipmap, source_name: str, source_hash: str, force: bool = False,
                     inputs=()) -> Path:
    """Write ``mip`` in the versioned asset format (arrays ``level_0`` ... finest first); never over one of
    ``inputs`` (the map it was built from: a file, or a link to it) whatever ``force`` says.  A mipmap that
    ``read_gmm_mipmap`` would refuse is refused here, before anything is written."""
    from precompute.assetfile import write_asset

    if not isinstance(mip, GmmMipmap):
        raise WarpbwError(f"write_gmm_mipmap: mip is {type(mip).__name__}, expected a GmmMipmap")
    try:
        arrays = {f"level_{l}": np.asarray(q, np.float32) for l, q in enumerate(mip.levels)}
        problem = mipmap_problem(list(arrays.values()), mip.components, float(mip.prior), float(mip.scale))
    except (TypeError, ValueError) as exc:
        raise WarpbwError(f"write_gmm_mipmap: levels or parameters that are not numbers ({exc})") from None
    if problem is not None:
        raise WarpbwError(f"write_gmm_mipmap: not a GMM mipmap ({problem}); {path} is not written")
    return write_asset(path, GMM_FORMAT, GMM_VERSION, source_name, source_hash, arrays, mip.params(), force,
                       inputs=inputs)


def header_fields(header: dict, components_unrecorded) -> dict:
    """``GmmMipmap``'s fields but its levels, as a GMM file's ``header`` records them (``components_unrecorded``: the
    count taken where the header has none; the reader passes its levels' K); TypeError, ValueError or
    AttributeError where the header's parameters are no numbers (a hand-edited header).  ``read_gmm_mipmap`` and
    ``warpbw.filtering.gmm_header_problem`` (which reads no levels) read the header alike through it."""
    params = header.get("params", {})
    components = params.get("components", components_unrecorded)
    if isinstance(components, bool) or not is_int(components):
        raise ValueError(components)
    return dict(components=int(components), prior=float(params.get("prior", DEFAULT_PRIOR)),
                unaligned=bool(params.get("unaligned", False)), kind=params.get("kind", "height"),
                scale=float(params.get("scale", 1.0)), seed=int(params.get("seed", 0)),
                max_samples=int(params.get("max_samples", DEFAULT_MAX_SAMPLES)),
                extra={k: params[k] for k in ("refine_sweeps", ROW_SPACING_KEY, *fit_constants()) if k in params},
                source=header.get("source"), source_hash=header.get("source_hash"))


def read_gmm_mipmap(path) -> GmmMipmap:
    """Read a file written by ``write_gmm_mipmap``; refuses other formats/versions and malformed levels."""
    from precompute.assetfile import check_float_arrays, read_asset

    # a file of another version is told the command that rebuilds it from its own header's map and options
    asset = read_asset(path, GMM_FORMAT, GMM_VERSION,
                       lambda h: rebuild_command(h.get("source", "MAP"), h.get("params")))
    hint = rebuild_command(asset.header.get("source", "MAP"), asset.header.get("params"))
    n = len([k for k in asset.arrays if k.startswith("level_")])
    levels = [asset.arrays.get(f"level_{l}") for l in range(n)]
    if n == 0 or any(q is None for q in levels):
        raise WarpbwError(f"{path}: GMM mipmap without its levels (rebuild it with: {hint})")
    K = levels[0].shape[2] if levels[0].ndim == 4 else -1
    # an empty level 0 (0 x 0 texels) has no level shapes: level_shapes' error named no file
    shapes = level_shapes(*levels[0].shape[:2]) if levels[0].ndim == 4 and min(levels[0].shape[:2]) >= 1 else []
    if len(shapes) != n or any(q.shape != s + (K, 4) for q, s in zip(levels, shapes)):
        raise WarpbwError(f"{path}: GMM mipmap levels have inconsistent shapes (rebuild it with: {hint})")
    check_float_arrays(levels, f"{path}: GMM mipmap levels", f" (rebuild it with: {hint})")   # strings: below
    try:
        with np.errstate(over="ignore"):   # float64 moments beyond float32 become inf, refused below (numpy warned)
            levels = [np.asarray(q, np.float32) for q in levels]
        mip = GmmMipmap(levels, **header_fields(asset.header, K))
    except (TypeError, ValueError, AttributeError):  # arrays of strings, a hand-edited header
        raise WarpbwError(f"{path}: GMM mipmap with non-numeric levels or parameters (rebuild it with: {hint})") \
            from None
    if mip.kind not in KINDS:
        raise WarpbwError(f"{path}: GMM mipmap of map kind {mip.kind!r}, expected one of {', '.join(KINDS)} "
                          f"(rebuild it with: {hint})")
    problem = mipmap_problem(levels, mip.components, mip.prior, mip.scale)
    if problem is not None:   # a damaged or hand-edited file: weights of 1000 rendered 3400x too bright, silently
        raise WarpbwError(f"{path}: not a GMM mipmap warpbw wrote: {problem} (rebuild it with: {hint})")
    return mip


# --------------------------------------------------------------------------------------------------
# Input

# PNG colour types that Pillow reads with 8 bits per channel at a bit depth of 16 (it has no 16-bit colour mode):
# RGB, grey + alpha, RGBA (PNG spec 11.2.2).  warpbw.io.png reads them whole (Pillow read 16-bit greyscale whole).
PNG_COLOUR_TYPES_OF_OUR_OWN = (2, 4, 6)
# Pillow formats whose compression is lossy: its block artifacts become slopes, hence normals, that the surface
# does not have.  Read, with a warning (JPEG normal maps are common in game assets).
LOSSY_FORMATS = ("JPEG", "MPO")   # MPO: JPEG frames (a phone camera's)


# Largest map read from a file (8192 x 8192): a sanity bound, as for procedural surfaces (MAX_SURFACE_SIZE); a
# 20000 x 20000 PNG of 389 kB stopped in Pillow's decompression-bomb error, with a traceback.
MAX_MAP_SIDE = 8192
MAX_MAP_TEXELS = MAX_MAP_SIDE * MAX_MAP_SIDE
EXR_ALPHA_CHANNELS = ("A",)    # OpenEXR's alpha (coverage) channel: skipped when looking for a map's data channel


_MAP_SIZE_EXPECTED = f"expected a map of at most {MAX_MAP_TEXELS} texels ({MAX_MAP_SIDE} x {MAX_MAP_SIDE})"


def _check_map_size(p: Path, width: int, height: int) -> None:
    if width * height > MAX_MAP_TEXELS:
        raise WarpbwError(f"{p}: {width} x {height} texels: {_MAP_SIZE_EXPECTED}")


def _read_pixels(p: Path) -> tuple[np.ndarray, int | None]:
    """(H, W, C) float64 in [0, 1] for PNG and the other images Pillow reads (TIFF, BMP, ...; a lossy one, such as
    JPEG, warns), raw floats for EXR; and the bits per channel the values were read with (None for floating point).
    16-bit RGB, grey + alpha and RGBA PNGs are read by ``warpbw.io.png`` (Pillow gives them 8 bits); alpha is
    dropped, as Pillow's conversions to L and RGB drop it."""
    from warpbw.io.exr import EXR_MAGIC, exr_size, in_display_window, read_exr
    from warpbw.io.png import PNG_SIGNATURE, png_header, read_png

    with open(p, "rb") as fh:
        head = fh.read(32)
    if head.startswith(EXR_MAGIC):
        # from the header: a map too large is never decoded (the data window) nor made (the display window, its frame)
        _check_map_size(p, *exr_size(p))
        _check_map_size(p, *exr_size(p, window="display"))
        img = in_display_window(read_exr(p))   # the frame's texels: 0 where none is stored, overscan dropped
        ch = img.channels
        if all(k in ch for k in ("R", "G", "B")):
            return img.pixels[..., [ch.index("R"), ch.index("G"), ch.index("B")]].astype(np.float64), None
        data = [k for k in ch if k not in EXR_ALPHA_CHANNELS]      # coverage or opacity, never a height
        if "Y" in data and set(data) <= {"Y", "RY", "BY"}:
            data = ["Y"]                                            # luminance (and chroma): the luminance
        if len(data) != 1:
            raise WarpbwError(f"{p}: OpenEXR channels {', '.join(ch)}: expected R, G, B (a normal map) or one "
                              "data channel besides alpha (a height field)")
        return img.pixels[..., [ch.index(data[0])]].astype(np.float64), None
    is_png = head.startswith(PNG_SIGNATURE)
    # (width, height, bit depth, colour type, interlace) from its IHDR, None for other images
    header = png_header(p) if is_png else None
    depth, colour = (header[2], header[3]) if header is not None else (None, None)
    if depth == 16 and colour in PNG_COLOUR_TYPES_OF_OUR_OWN:
        _check_map_size(p, *header[:2])   # from the header: a map too large is never decoded
        png = read_png(p)
        grey = png.colour_type == 4
        return png.pixels[..., :1 if grey else 3].astype(np.float64) / 65535.0, 16
    from PIL import Image, UnidentifiedImageError

    bits = None
    try:
        with warnings.catch_warnings():   # Pillow's decompression-bomb warning: the bound below is tighter
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            im = Image.open(p)
        with im:
            _check_map_size(p, *im.size)
            im.load()
            mode = im.mode
            if im.format in LOSSY_FORMATS:
                warnings.warn(f"{p}: a {im.format} image: its lossy compression's block artifacts read as bumps "
                              "(a PNG or an OpenEXR image keeps the map as made)", stacklevel=3)
            if mode in ("I;16", "I;16B", "I;16L", "I;16N"):
                arr = np.asarray(im, dtype=np.float64) / 65535.0
                bits = 16
            elif mode == "I":
                sixteen = depth == 16
                arr = np.asarray(im, dtype=np.float64) / (65535.0 if sixteen else 1.0)
                bits = 16 if sixteen else 32
            elif mode == "F":
                arr = np.asarray(im, dtype=np.float64)
            elif mode in ("1", "L", "LA", "P", "PA") and not (mode in ("P", "PA") and im.palette.mode != "L"):
                arr = np.asarray(im.convert("L"), dtype=np.float64) / 255.0
                bits = 1 if mode == "1" else 8
                if mode == "L" and colour == 0 and depth < 8:
                    bits = depth   # a 2- or 4-bit greyscale PNG, which Pillow widens to 8 bits
            else:
                arr = np.asarray(im.convert("RGB"), dtype=np.float64) / 255.0
                bits = 8
    except Image.DecompressionBombError:   # beyond Pillow's own bound (above ours), raised before any size is known
        raise WarpbwError(f"{p}: over {2 * Image.MAX_IMAGE_PIXELS} texels: {_MAP_SIZE_EXPECTED}") from None
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError) as exc:
        if is_png:   # it is a PNG: "not an image file" was wrong
            raise WarpbwError(f"{p}: cannot decode this PNG (truncated or corrupt: {exc})") from None
        raise WarpbwError(f"{p}: not an image file (expected an OpenEXR or PNG image; {type(exc).__name__})") from None
    return (arr[..., None] if arr.ndim == 2 else arr), bits


def load_map(path, kind: str = "height") -> np.ndarray:
    """Read a height field (single channel; an RGB image is accepted only with identical channels) as
    (H, W) float64, or a tangent-space normal map (RGB) as unit (H, W, 3); an EXR over its display window (0 where
    the file stores no texel; ``warpbw.io.exr.in_display_window``).  Conventions (``precompute.surfaces``): a larger
    height is higher; an integer image's values are read as stored over 255 or 65535 (no sRGB or gamma curve), so
    white is 1 (one map width, before ``scale``); a normal map's R, G, B hold n_x along +column, n_y towards row 0
    (OpenGL's convention: a DirectX map's G is the other way, and nothing in the file says which) and n_z out of the
    surface, an 8-bit value k decoding to 2 k / 255 - 1 (128 is +0.004).  PNG normal maps are
    [0, 1]-encoded; an EXR normal map holds the vectors themselves when it has a value more than 0.1
    outside [0, 1] (``precompute.surfaces.ENCODING_TOL``), or when more of its texels are unit vectors as stored
    than as decoded (a [0, 1]-encoded map's texels are not: the flat normal is stored as (0.5, 0.5, 1)), otherwise
    it is [0, 1]-encoded too (``_holds_vectors``).
    Texels shorter than ``NORMAL_LENGTH_MIN`` (as stored or decoded) are an error; texels off unit length by more than
    ``UNIT_TOL`` are renormalised, with a warning; an image of (0, 0, 0) texels only is an error.  16-bit PNGs keep
    their precision (greyscale through Pillow, RGB, grey + alpha and RGBA through ``warpbw.io.png``).  Normals more than
    ``NORMAL_Z_TOL`` below the tangent plane are an error; those closer are put in it.  A varying height field read
    with 8 bits warns (terraced normals).  Every problem is a one-line WarpbwError naming the file."""
    from precompute.surfaces import normals_from_map, unit_normals

    if kind not in KINDS:
        raise WarpbwError(f"kind {kind!r}: expected one of {', '.join(KINDS)}")
    p = check_input_file(path, f"a {kind} map: OpenEXR or PNG image")
    px, bits = _read_pixels(p)
    if px.shape[0] == 0 or px.shape[1] == 0 or px.shape[2] == 0:
        raise WarpbwError(f"{p}: empty image ({px.shape[1]}x{px.shape[0]} texels); expected a {kind} map")
    bad = ~np.isfinite(px).all(axis=-1)
    if bad.any():
        r, col = np.argwhere(bad)[0]
        raise WarpbwError(f"{p}: {int(bad.sum())} texels are NaN or infinite (first at row {r}, column {col}); "
                          f"expected finite {kind} values")
    if kind == "height":
        if px.shape[2] >= 3:
            rgb = px[..., :3]
            if not (np.array_equal(rgb[..., 0], rgb[..., 1]) and np.array_equal(rgb[..., 0], rgb[..., 2])):
                raise WarpbwError(f"{p}: RGB image with differing channels given as a height field (expected a "
                                  "single-channel image; for a tangent-space normal map use --kind normal, or "
                                  "normal_map_kind = \"normal\" in a scene)")
        heights = np.ascontiguousarray(px[..., 0])
        if bits is not None and bits <= 8 and np.ptp(heights) > 0:
            warnings.warn(f"{p}: heights read with {bits} bit{'s' if bits > 1 else ''}: {2 ** bits} levels give "
                          "terraced normals (a 16-bit greyscale PNG or an EXR keeps the detail)", stacklevel=2)
        return heights
    if px.shape[2] < 3:
        raise WarpbwError(f"{p}: single-channel image given as a normal map (expected an RGB tangent-space "
                          "normal map; for a height field use --kind height, or normal_map_kind = \"height\" in a "
                          "scene)")
    rgb = px[..., :3]
    if not np.any(rgb):   # read as [0, 1]-encoded, it warned "renormalised", then "pointing below the surface"
        raise WarpbwError(f"{p}: every texel is (0, 0, 0): an empty image, not a normal map (expected unit normals, "
                          "or a [0, 1]-encoded map whose flat texel is (0.5, 0.5, 1))")
    try:
        raw = bits is None and _holds_vectors(rgb)
        n = unit_normals(rgb) if raw else normals_from_map(rgb)
    except WarpbwError as exc:
        raise WarpbwError(f"{p}: {exc}") from None
    stored = rgb if raw else 2.0 * rgb - 1.0
    off = np.abs(np.linalg.norm(stored, axis=-1) - 1.0) > UNIT_TOL
    if off.any():   # said, since a resampled map's are renormalised here, not by the user
        r, c = np.argwhere(off)[0]
        warnings.warn(f"{p}: {int(off.sum())} of {off.size} texels are not unit normals as "
                      f"{'stored (raw vectors)' if raw else 'decoded (n = 2 rgb - 1)'} (first at row {r}, column "
                      f"{c}: length {np.linalg.norm(stored[r, c]):.3g}); renormalised", stacklevel=2)
    _check_upward(n, str(p))
    n[..., 2] = np.maximum(n[..., 2], 0.0)   # within NORMAL_Z_TOL below: in the tangent plane
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def _holds_vectors(rgb) -> bool:
    """Whether a float (EXR) normal map holds the vectors themselves rather than (n + 1) / 2: it has a value more
    than ``ENCODING_TOL`` outside [0, 1] (no [0, 1]-encoded map's, a resampling's overshoot included), or more of its
    texels are unit vectors as stored than as decoded.  (The rule was "every texel unit": one texel of length 1.05 in
    a flat map made the tool decode all of them, tilting each by 55 degrees.  Then "any value below 0 or above
    1.01": one texel of a [0, 1]-encoded map overshooting to 1.02, as a bicubic resampling leaves at a crease, made it
    read every texel as a raw vector, each about 35 degrees off, with only a "renormalised" warning.)  When neither
    reading makes most texels unit (a map of unnormalised vectors), the one whose normals lie nearer the vertical on
    average wins: a tangent-space map is mostly near +z (unnormalised raw vectors were decoded, and refused as
    pointing below the surface)."""
    from precompute.surfaces import ENCODING_TOL

    if rgb.min() < -ENCODING_TOL or rgb.max() > 1.0 + ENCODING_TOL:
        return True
    as_stored = np.count_nonzero(np.abs(np.linalg.norm(rgb, axis=-1) - 1.0) <= UNIT_TOL)
    decoded = 2.0 * rgb - 1.0
    as_decoded = np.count_nonzero(np.abs(np.linalg.norm(decoded, axis=-1) - 1.0) <= UNIT_TOL)
    if max(as_stored, as_decoded) > rgb[..., 0].size // 2:
        return as_stored > as_decoded

    def mean_z(v):   # zero vectors count as horizontal
        length = np.linalg.norm(v, axis=-1)
        return float(np.mean(np.where(length > 0.0, v[..., 2] / np.maximum(length, 1e-300), 0.0)))

    return mean_z(rgb) > mean_z(decoded)


def load_source(spec: str, kind: str = "height"):
    """A map from a file path, or ``surface:NAME[:SIZE]`` (``precompute.surfaces.SURFACES``, a height
    field, default size 512).  Returns (array, name, content hash: blake2b of the file or of the heights)."""
    from precompute.surfaces import SURFACES

    check_path(spec, "load_source: spec")   # None or 3 was read as a file named "None" or "3"
    s = str(spec)
    if s.startswith("surface:"):
        parts = s.split(":")
        name = parts[1] if len(parts) > 1 else ""
        if name not in SURFACES:
            raise WarpbwError(f"{s}: unknown procedural surface (expected surface:NAME[:SIZE] with NAME one of "
                              f"{', '.join(SURFACES)})")
        if len(parts) > 3:   # a known surface with more fields was called unknown
            raise WarpbwError(f"{s}: expected surface:NAME[:SIZE], one size at most (got {len(parts) - 2} fields "
                              f"after {name})")
        if kind != "height":
            raise WarpbwError(f"{s}: procedural surfaces are height fields (use --kind height)")
        try:
            size = int(parts[2]) if len(parts) == 3 else 512
        except ValueError:
            raise WarpbwError(f"{s}: size {parts[2]!r} is not an integer") from None
        h = SURFACES[name](size)
        digest = hashlib.blake2b(np.ascontiguousarray(h).tobytes(), digest_size=16).hexdigest()
        return h, f"surface:{name}:{size}", digest
    from warpbw.scene import file_digest

    data = load_map(s, kind)
    return data, Path(s).name, file_digest(Path(s))
