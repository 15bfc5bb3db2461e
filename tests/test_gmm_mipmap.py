"""GMM normal mipmaps (004 Sec. 4.1, 4.2; issue 4 items 1 and the acceptance list).

Truths used here come from outside the code under test: samples drawn from a known mixture,
scikit-learn's GaussianMixture, a float64 loop-per-texel reference of 004's MAP-EM written below,
the law of total variance for a two-Gaussian mixture, and maps made by hand.  examples/gmm_mipmap.py's options,
stated defaults and the block it filters, worked out by hand.
"""
from __future__ import annotations

import contextlib
import itertools
import json
import re
import shlex
import warnings
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import (Handed, StandInClock, attempt, capture_call, exr_claiming_size, load_example, outcome,
                      plot_png)
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from precompute.gmm_mipmap import (GMM_FORMAT, VARIANCE_FLOOR, build_gmm_mipmap, em_fit, filter_moments,
                                   footprint_samples, from_moments, kmeans_init, kmeans_plus_plus, level_shapes,
                                   load_map, load_source, moment_match, read_gmm_mipmap, to_moments,
                                   write_gmm_mipmap)
from precompute.surfaces import dunes, hemispherical_scales
from warpbw.errors import WarpbwError

EXAMPLE_GMM_TIME = Path(__file__).resolve().parents[1] / "examples" / "gmm_precompute_time.py"

K = 4


def draw_mixture(rng, a, mu, s, m):
    """m samples of sum_i a_i N(mu_i, s_i^2 I_2)."""
    comp = rng.choice(len(a), size=m, p=a)
    return mu[comp] + rng.normal(size=(m, 2)) * s[comp, None]


def best_permutation(mu_true, mu_fit):
    return min(itertools.permutations(range(len(mu_true))),
               key=lambda p: np.sum(np.linalg.norm(mu_true - mu_fit[list(p)], axis=-1)))


# --------------------------------------------------------------------------------------------------
# EM

def test_em_recovers_a_known_mixture():
    rng = np.random.default_rng(11)
    truths, xs = [], []
    for t in range(3):                           # three texels fitted together (vectorised)
        a = rng.permutation(np.array([0.4, 0.3, 0.2, 0.1]))
        ang = rng.uniform(0, 2 * np.pi) + np.arange(K) * np.pi / 2
        mu = 0.35 * np.stack([np.cos(ang), np.sin(ang)], -1)
        s = rng.uniform(0.03, 0.06, size=K)
        truths.append((a, mu, s))
        xs.append(draw_mixture(rng, a, mu, s, 4000))
    x = np.stack(xs)
    a0, mu0, s20 = kmeans_init(x, kmeans_plus_plus(x, K, 5))
    a, mu, s2, _ = em_fit(x, a0, mu0, s20, c=0.0, max_iter=200, tol=1e-8)
    for t, (a_t, mu_t, s_t) in enumerate(truths):
        p = list(best_permutation(mu_t, mu[t]))
        assert np.linalg.norm(mu[t][p] - mu_t, axis=-1).max() < 0.02
        assert np.abs(a[t][p] - a_t).max() < 0.05
        np.testing.assert_allclose(np.sqrt(s2[t][p]), s_t, rtol=0.15)


def test_em_without_prior_equals_sklearn_spherical_gmm():
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.mixture import GaussianMixture

    rng = np.random.default_rng(2)
    x = np.stack([draw_mixture(rng, np.full(K, 0.25), rng.uniform(-0.5, 0.5, (K, 2)), np.full(K, 0.08), 300)
                  for _ in range(3)])
    a0, mu0, s20 = kmeans_init(x, kmeans_plus_plus(x, K, 1), iterations=2)
    assert np.all(a0 > 0)
    n_iter = 15
    a, mu, s2, it = em_fit(x, a0, mu0, s20, c=0.0, max_iter=n_iter, tol=0.0)
    assert it == n_iter
    # "c = 0 must reduce exactly to plain EM": a non-zero prior with zero constant changes nothing
    a_b, mu_b, s2_b, _ = em_fit(x, a0, mu0, s20, c=0.0, prior_sum=np.ones((3, K, 2)), prior_weight=np.ones((3, K)),
                                max_iter=n_iter, tol=0.0)
    assert np.array_equal(mu, mu_b) and np.array_equal(s2, s2_b) and np.array_equal(a, a_b)
    for t in range(3):
        gm = GaussianMixture(K, covariance_type="spherical", weights_init=a0[t] / a0[t].sum(), means_init=mu0[t],
                             precisions_init=1.0 / s20[t], reg_covar=0.0, max_iter=n_iter, tol=0.0,
                             init_params="random_from_data")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ConvergenceWarning)
            gm.fit(x[t])
        np.testing.assert_allclose(a[t], gm.weights_, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(mu[t], gm.means_, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(s2[t], gm.covariances_, rtol=1e-9, atol=1e-14)



def mixture_log_likelihood(x, a, mu, s2):
    """sum_j log sum_i a_i g(x_j; mu_i, s_i^2 I_2) per texel, written from the density (T, M, 2) -> (T,)."""
    d2 = np.sum((x[:, :, None, :] - mu[:, None, :, :]) ** 2, axis=-1)
    with np.errstate(divide="ignore"):
        terms = np.log(a)[:, None, :] - d2 / (2 * s2[:, None, :]) - np.log(2 * np.pi * s2)[:, None, :]
    top = terms.max(axis=-1, keepdims=True)
    return np.sum(top[..., 0] + np.log(np.exp(terms - top).sum(axis=-1)), axis=1)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), k=st.integers(1, 5), m=st.integers(8, 120), spread=st.floats(0.01, 0.4))
def test_plain_em_never_lowers_the_likelihood(seed, k, m, spread):
    """Dempster, Laird and Rubin: each EM iteration (E-step, then the M-step's maximum) never lowers the data's
    log-likelihood under the mixture, from any start, for any data; the M-step's variance floor is a bound the
    maximum is clipped to, which keeps it so.  Checked over 12 iterations on random texels and random starts."""
    rng = np.random.default_rng(seed)
    T = 3
    x = rng.normal(scale=spread, size=(T, m, 2)) + rng.uniform(-0.4, 0.4, (T, 1, 2)) * (rng.random((T, m, 1)) < 0.5)
    a, mu, s2 = rng.dirichlet(np.ones(k), size=T), rng.uniform(-0.5, 0.5, (T, k, 2)), rng.uniform(1e-3, 0.1, (T, k))
    ll = [mixture_log_likelihood(x, a, mu, s2)]
    for _ in range(12):
        a, mu, s2, _ = em_fit(x, a, mu, s2, c=0.0, max_iter=1, tol=0.0)
        ll.append(mixture_log_likelihood(x, a, mu, s2))
    ll = np.array(ll)
    assert np.all(np.isfinite(ll))
    assert np.all(np.diff(ll, axis=0) >= -1e-9 * np.abs(ll[1:])), np.diff(ll, axis=0).min()


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), k=st.integers(1, 6), m=st.integers(4, 100))
def test_lloyd_iterations_never_raise_the_within_cluster_sum_of_squares(seed, k, m):
    """Lloyd's algorithm: assigning each sample to its nearest centre and moving each centre to its cluster's mean
    each never raise sum_j min_i |x_j - mu_i|^2 (an empty cluster keeps its centre, which raises nothing), from
    any start (here k-means++ seeds or arbitrary points); and the returned weights are the cluster fractions."""
    rng = np.random.default_rng(seed)
    T = 3
    x = rng.normal(scale=0.2, size=(T, m, 2)) + rng.uniform(-0.5, 0.5, (T, m, 1)) * [1.0, -0.5]
    start = kmeans_plus_plus(x, k, seed) if seed % 2 else rng.uniform(-0.8, 0.8, (T, k, 2))

    def sse(mu):
        return np.sum(np.min(np.sum((x[:, :, None] - mu[:, None]) ** 2, axis=-1), axis=-1), axis=-1)

    costs = [sse(start)]
    for iterations in range(1, 8):
        a, mu, _ = kmeans_init(x, start, iterations=iterations)
        costs.append(sse(mu))
        nearest = np.argmin(np.sum((x[:, :, None] - mu[:, None]) ** 2, axis=-1), axis=-1)
        np.testing.assert_allclose(a, (nearest[..., None] == np.arange(k)).mean(axis=1), atol=1e-12)
    costs = np.array(costs)
    assert np.all(np.diff(costs, axis=0) <= 1e-12 * costs[:-1] + 1e-15), np.diff(costs, axis=0).max()

def reference_map_em(x, a, mu, s2, c, p_sum, p_w, n_iter):
    """004 Sec. 4.1 MAP-EM written plainly, one texel, one sample at a time (float64)."""
    a, mu, s2 = a.copy(), mu.copy(), s2.copy()
    M, Kc = len(x), len(a)
    for _ in range(n_iter):
        z = np.zeros((M, Kc))
        for j in range(M):
            for i in range(Kc):
                z[j, i] = a[i] * np.exp(-np.sum((x[j] - mu[i]) ** 2) / (2 * s2[i])) / (2 * np.pi * s2[i])
            z[j] /= z[j].sum()
        for i in range(Kc):
            zi = z[:, i].sum()
            a[i] = zi / M
            mu[i] = (np.sum(z[:, i, None] * x, axis=0) + c * p_sum[i]) / (zi + c * p_w[i])
            s2[i] = np.sum(z[:, i] * np.sum((x - mu[i]) ** 2, axis=1)) / (2 * zi)
    return a, mu, s2


def test_map_em_matches_a_reference_of_the_paper_equations():
    rng = np.random.default_rng(4)
    T, M = 3, 60
    x = rng.normal(scale=0.2, size=(T, M, 2))
    a0 = rng.dirichlet(np.ones(K), size=T)
    mu0 = rng.normal(scale=0.2, size=(T, K, 2))
    s20 = rng.uniform(0.01, 0.05, size=(T, K))
    # neighbours: sum_k a_ki mu_ki and sum_k a_ki over three neighbours
    na = rng.dirichlet(np.ones(K), size=(T, 3))
    nmu = rng.normal(scale=0.2, size=(T, 3, K, 2))
    p_sum = np.einsum("tnk,tnkd->tkd", na, nmu)
    p_w = na.sum(axis=1)
    c = 1.7
    a, mu, s2, _ = em_fit(x, a0, mu0, s20, c, p_sum, p_w, max_iter=7, tol=0.0)
    for t in range(T):
        ra, rmu, rs2 = reference_map_em(x[t], a0[t], mu0[t], s20[t], c, p_sum[t], p_w[t], 7)
        np.testing.assert_allclose(a[t], ra, rtol=1e-10)
        np.testing.assert_allclose(mu[t], rmu, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(s2[t], rs2, rtol=1e-9)


def test_empty_component_stays_defined():
    rng = np.random.default_rng(0)
    x = rng.normal(scale=0.01, size=(2, 50, 2))
    mu0 = np.array([[[0.0, 0.0], [0.9, 0.0], [0.0, 0.01], [-0.9, 0.0]]] * 2)
    a0 = np.array([[0.7, 0.1, 0.1, 0.1]] * 2)
    s20 = np.full((2, K), 1e-4)
    for c, p_sum, p_w in ((0.0, None, None), (1.0, np.full((2, K, 2), 0.3), np.array([[1, 1, 1, 0]] * 2, float))):
        a, mu, s2, _ = em_fit(x, a0, mu0, s20, c, p_sum, p_w)
        assert np.all(np.isfinite(a)) and np.all(np.isfinite(mu)) and np.all(np.isfinite(s2))
        assert np.all(s2 >= VARIANCE_FLOOR) and a[0, 1] == 0.0 and a[0, 3] == 0.0
        np.testing.assert_allclose(a.sum(axis=1), 1.0)
        if c > 0:       # an empty component with neighbours takes their mean
            np.testing.assert_allclose(mu[:, 1], 0.3)
        else:           # without, it keeps its previous mean
            np.testing.assert_allclose(mu[:, 1], mu0[:, 1])


# --------------------------------------------------------------------------------------------------
# Alignment on a real test surface

def misalignment(mip, levels):
    """Mean distance between component k of adjacent texels, weighted by the smaller of their weights."""
    tot = wt = 0.0
    for lvl in levels:
        a, mu, _ = from_moments(mip.levels[lvl])
        for ax in (0, 1):
            n = a.shape[ax]
            d = np.linalg.norm(np.diff(mu, axis=ax), axis=-1)
            w = np.minimum(a.take(range(1, n), axis=ax), a.take(range(0, n - 1), axis=ax))
            tot += float((d * w).sum())
            wt += float(w.sum())
    return tot / wt


@pytest.fixture(scope="module")
def scales_mips():
    h = hemispherical_scales(48, scales_across=4)
    return {name: build_gmm_mipmap(h, progress=False, **kw) for name, kw in
            (("aligned", {}), ("no_prior", {"prior": 0.0}), ("unaligned", {"unaligned": True}))}


def test_prior_aligns_neighbouring_components(scales_mips):
    levels = range(1, 5)
    m = {k: misalignment(v, levels) for k, v in scales_mips.items()}
    assert m["aligned"] < 0.5 * m["unaligned"], m
    assert m["aligned"] < m["no_prior"], m           # the prior itself, beyond the parent initialisation


def parent_mismatch(mip, lvl, perm=None):
    """Per texel of level lvl: sum_i a_i a'_i / (a_i + a'_i) |mu_i - mu'_i|^2 against its parent (a', mu') --
    the spread that moment-matching component i of the two adds (law of total variance, 50/50 blend),
    i.e. what trilinear filtering between the levels loses to misaligned components."""
    a, mu, _ = from_moments(mip.levels[lvl].astype(np.float64))
    ap, mup, _ = from_moments(mip.levels[lvl + 1].astype(np.float64))
    h, w = a.shape[:2]
    ii, jj = np.meshgrid(np.arange(h) // 2, np.arange(w) // 2, indexing="ij")
    ap, mup = ap[ii, jj], mup[ii, jj]
    if perm is not None:
        a, mu = a[..., list(perm)], mu[..., list(perm), :]
    hm = a * ap / np.maximum(a + ap, 1e-12)
    return np.sum(hm * np.sum((mu - mup) ** 2, -1), -1)


def test_components_correspond_across_levels(scales_mips):
    # trilinear filtering blends component i of level l with component i of level l + 1, so the labels must
    # agree between a texel and its parent.  Truth: the best of all K! relabellings of each child, by brute force.
    for lvl in range(1, 4):
        got = {k: parent_mismatch(v, lvl).mean() for k, v in scales_mips.items()}
        best = np.min([parent_mismatch(scales_mips["aligned"], lvl, p)
                       for p in itertools.permutations(range(K))], axis=0).mean()
        assert got["aligned"] < 0.5 * got["unaligned"], (lvl, got)
        assert got["aligned"] <= 1.5 * best + 1e-4, (lvl, got["aligned"], best)


def test_dunes_aligned_vs_unaligned():
    h = dunes(32)
    al = misalignment(build_gmm_mipmap(h, progress=False), range(1, 4))
    un = misalignment(build_gmm_mipmap(h, progress=False, unaligned=True), range(1, 4))
    assert al < un


def test_mixture_reproduces_footprint_mean(scales_mips):
    # without prior the mixture's mean is the footprint mean (EM keeps the first moment exactly); the projected
    # normals (n_x, n_y) of 004 Sec. 3 taken here from the unit normals themselves (normal_space, the builder's own
    # projection, gave them before, so a slip in it was in both means)
    h = hemispherical_scales(48, scales_across=4)
    from precompute.surfaces import height_to_normals
    n = height_to_normals(h)
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-12)
    n2 = n[..., :2]
    for lvl in (0, 2, 4):
        a, mu, _ = from_moments(scales_mips["no_prior"].levels[lvl])
        mean = np.sum(a[..., None] * mu, axis=-2)
        f = 1 << lvl         # the level's 2^l x 2^l footprints, sliced from the map itself (48 = 3 x 16)
        fp = n2.reshape(48 // f, f, 48 // f, f, 2).mean(axis=(1, 3))
        np.testing.assert_allclose(mean, fp, atol=2e-5)
        np.testing.assert_allclose(a.sum(-1), 1.0, atol=1e-5)


@pytest.mark.parametrize("unaligned", [False, True], ids=["aligned", "unaligned"])
def test_a_footprint_the_border_clips_weighs_each_of_its_texels_once(unaligned):
    """One component without a prior is the footprint's plain mean and variance, also where the map's border
    clips the footprint (sides of 45 and 70 texels, no power of two).  The truth is numpy's mean and variance of
    the normals in each texel's box, sliced from the map.  Levels 1-4 enumerate the footprint's 2^l x 2^l slots;
    on a clipped side of n < 2^l texels some texels took two slots, so a last row's mean strayed up to 0.12
    projected units (about 7 degrees) from its box's."""
    from precompute.surfaces import height_to_normals

    h = np.random.default_rng(3).random((45, 70)) * 0.05
    n2 = height_to_normals(h)[..., :2]
    mip = build_gmm_mipmap(h, components=1, prior=0.0, progress=False, unaligned=unaligned)
    for lvl in range(1, 5):
        f = 1 << lvl
        a, mu, s2 = from_moments(mip.levels[lvl].astype(np.float64))
        for i, j in itertools.product(range(a.shape[0]), range(a.shape[1])):
            box = n2[i * f:(i + 1) * f, j * f:(j + 1) * f].reshape(-1, 2)
            np.testing.assert_allclose(mu[i, j, 0], box.mean(axis=0), atol=1e-6, err_msg=f"level {lvl} ({i}, {j})")
            np.testing.assert_allclose(s2[i, j, 0], max(box.var(axis=0).mean(), VARIANCE_FLOOR), rtol=1e-3,
                                       atol=1e-7, err_msg=f"level {lvl} ({i}, {j})")


def test_two_normals_in_clipped_footprints_weigh_their_share_of_the_texels():
    """A normal map of two normals, scattered at random over 6 x 10 texels: with two components each texel's
    weights are the two normals' shares of its footprint's texels, counted by hand, clipped footprints too (the
    whole map's share of tilted normals read 0.312 for 0.300 when some texels counted twice)."""
    rng = np.random.default_rng(5)
    tilt = np.array([np.sin(0.6), 0.0, np.cos(0.6)])
    tilted = rng.random((6, 10)) < 0.3
    normals = np.where(tilted[..., None], tilt, np.array([0.0, 0.0, 1.0]))
    mip = build_gmm_mipmap(normals, kind="normal", components=2, prior=0.0, progress=False)
    for lvl in range(1, len(mip.levels)):
        f = 1 << lvl
        a, mu, _ = from_moments(mip.levels[lvl].astype(np.float64))
        for i, j in itertools.product(range(a.shape[0]), range(a.shape[1])):
            share = tilted[i * f:(i + 1) * f, j * f:(j + 1) * f].mean()
            got = np.sum(a[i, j] * (mu[i, j, :, 0] > 0.5 * tilt[0]))   # the components at the tilted normal
            assert got == pytest.approx(share, abs=1e-5), (lvl, i, j)


def test_footprint_samples_come_from_each_texels_own_footprint():
    """Small footprints give every normal of the 2^l x 2^l block once; large ones one normal per cell of a
    16 x 16 grid over it; a border-clipped footprint only normals inside the map.  The normals are coded by
    their own pixel position, so each sample says where it came from."""
    H, W = 70, 45
    rr, cc = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
    n2 = np.stack([rr, cc], -1).astype(np.float64)
    for lvl in (0, 1, 3, 4, 5, 6):
        f = 1 << lvl
        h_l, w_l = -(-H // f), -(-W // f)
        smp = footprint_samples(n2, lvl, rng=1).reshape(h_l, w_l, -1, 2)
        tr, tc = np.meshgrid(np.arange(h_l), np.arange(w_l), indexing="ij")
        assert np.all(smp[..., 0] // f == tr[..., None]) and np.all(smp[..., 1] // f == tc[..., None]), lvl
        if lvl <= 4:       # full footprints: each of the block's 4^l normals exactly once
            full = smp[: H // f, : W // f]
            key = np.sort(full[..., 0] * W + full[..., 1], axis=-1)
            r0, c0 = np.meshgrid(np.arange(H // f) * f, np.arange(W // f) * f, indexing="ij")
            block = (r0[..., None, None] + np.arange(f)[:, None]) * W + c0[..., None, None] + np.arange(f)
            assert np.array_equal(key, np.sort(block.reshape(H // f, W // f, -1), axis=-1)), lvl
        elif H // f and W // f:   # one per cell of a 16 x 16 grid over a full footprint (none at level 6)
            cell = f // 16
            full = smp[: H // f, : W // f]
            cr = (full[..., 0] % f) // cell
            ccl = (full[..., 1] % f) // cell
            key = np.sort(cr * 16 + ccl, axis=-1)
            assert full.shape[2] == 256 and np.all(key == np.arange(256)), lvl


# --------------------------------------------------------------------------------------------------
# The filterable form

def test_linear_filtering_is_the_moment_matched_component():
    rng = np.random.default_rng(7)
    a = rng.uniform(0.1, 1.0, size=(2, K))
    mu = rng.uniform(-0.6, 0.6, size=(2, K, 2))
    s2 = rng.uniform(1e-4, 0.02, size=(2, K))
    for t in (0.0, 0.25, 0.5, 0.9, 1.0):
        w = np.array([1 - t, t])
        af, muf, s2f = from_moments(filter_moments(to_moments(a, mu, s2), w))
        # independent truth: component k of the mixture (1-t) a_0k g_0k + t a_1k g_1k
        p = w[:, None] * a / (w[:, None] * a).sum(axis=0)
        mean = np.sum(p[..., None] * mu, axis=0)
        np.testing.assert_allclose(af, np.sum(w[:, None] * a, axis=0), rtol=1e-13)
        np.testing.assert_allclose(muf, mean, rtol=1e-12, atol=1e-14)
        # its total variance E|n - mean|^2 by the law of total variance (an isotropic 2D Gaussian of per-axis
        # variance s^2 spreads 2 s^2 about its mean): the filtered isotropic component has the same, 2 s2f
        total = np.sum(p * 2 * s2, 0) + np.sum(p * np.sum((mu - mean) ** 2, -1), 0)
        np.testing.assert_allclose(2 * s2f, total, rtol=1e-10)
        ma, mmu, ms2 = moment_match(a, mu, s2, w)
        np.testing.assert_allclose((af, s2f), (ma, ms2), rtol=1e-12)
        np.testing.assert_allclose(muf, mmu, rtol=1e-12, atol=1e-15)
    # and by sampling: normals drawn from the half-and-half mixture of the two texels' component k spread about
    # their mean by s2f per axis
    af, muf, s2f = from_moments(filter_moments(to_moments(a, mu, s2), np.array([0.5, 0.5])))
    n = 400_000
    for k in range(K):
        texel = rng.random(n) < a[1, k] / (a[0, k] + a[1, k])
        x = mu[texel.astype(int), k] + rng.normal(size=(n, 2)) * np.sqrt(s2[texel.astype(int), k])[:, None]
        assert np.allclose(x.mean(0), muf[k], atol=3e-3)
        assert np.var(x, axis=0).mean() == pytest.approx(s2f[k], rel=0.02)



@settings(max_examples=50, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), texels=st.integers(1, 8), k=st.integers(1, 5), convex=st.booleans())
def test_filtering_any_texels_with_any_weights_is_the_mixture_of_their_components(seed, texels, k, convex):
    """Linear filtering of the stored moments, sum_t w_t q_t, over any number of texels and any non-negative
    weights (convex ones, as trilinear and anisotropic filters use, or not): component i comes back as the
    isotropic Gaussian of the mixture sum_t w_t a_ti g_ti -- weight sum_t w_t a_ti, its mean, and its per-axis
    variance by the law of total variance, sum_t p_t s_ti^2 + sum_t p_t |mu_ti - mean|^2 / 2 (p_t = w_t a_ti /
    sum w a; an isotropic 2D Gaussian spreads 2 s^2 about its mean).  moment_match agrees."""
    rng = np.random.default_rng(seed)
    a = rng.uniform(0.05, 1.0, (texels, k))
    r, ang = np.sqrt(rng.uniform(0.0, 0.8, (texels, k))), rng.uniform(0.0, 2 * np.pi, (texels, k))
    mu = np.stack([r * np.cos(ang), r * np.sin(ang)], -1)            # means inside the unit disk
    s2 = np.exp(rng.uniform(np.log(1e-4), np.log(0.05), (texels, k)))
    w = rng.dirichlet(np.ones(texels)) if convex else rng.uniform(0.01, 3.0, texels)
    af, muf, s2f = from_moments(filter_moments(to_moments(a, mu, s2), w))
    wa = w[:, None] * a
    p = wa / wa.sum(axis=0)
    mean = np.sum(p[..., None] * mu, axis=0)
    var = np.sum(p * s2, axis=0) + np.sum(p * np.sum((mu - mean) ** 2, axis=-1), axis=0) / 2
    np.testing.assert_allclose(af, wa.sum(axis=0), rtol=1e-12)
    np.testing.assert_allclose(muf, mean, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(s2f, var, rtol=1e-7, atol=1e-12)
    ma, mmu, ms2 = moment_match(a, mu, s2, w)
    np.testing.assert_allclose(np.concatenate([ma, ms2]), np.concatenate([af, s2f]), rtol=1e-9)
    np.testing.assert_allclose(mmu, muf, rtol=1e-9, atol=1e-12)

def test_trilinear_filtering_of_stored_float32_levels(scales_mips):
    """Four stored float32 texels of a built level, filtered with weights w: component k is the mixture of the
    texels' component k weighted w_t a_t.  Truth decoded here from the stored layout (a, a mu_x, a mu_y,
    a (2 s^2 + |mu|^2)) without the module's from_moments or moment_match (which once gave the expected value, so a
    mistake shared by from_moments on both sides, such as mu_x and mu_y read swapped, went unseen): weight
    sum w_t a_t, mean sum p_t mu_t, and per-axis variance by the law of total variance, sum p_t s_t^2 +
    sum p_t |mu_t - mean|^2 / 2 (p_t = w_t a_t / sum w a), floored at VARIANCE_FLOOR."""
    q = scales_mips["aligned"].levels[1].astype(np.float64)
    w = np.array([0.1, 0.2, 0.3, 0.4])
    texels = np.stack([q[0, 0], q[0, 1], q[1, 0], q[1, 1]])           # (4 texels, K, 4)
    af, muf, s2f = from_moments(filter_moments(texels, w))
    a_t = texels[..., 0]                                               # (4, K)
    ok = np.sum(w[:, None] * a_t, axis=0) > 1e-6                       # components the four texels hold
    used = a_t > 0
    safe = np.where(used, a_t, 1.0)
    mu_t = np.where(used[..., None], texels[..., 1:3] / safe[..., None], 0.0)                   # (4, K, 2)
    s2_t = np.where(used, (texels[..., 3] / safe - np.sum(mu_t ** 2, axis=-1)) / 2, 0.0)        # per axis
    wa = w[:, None] * a_t
    p = wa / np.where(ok, wa.sum(axis=0), 1.0)
    mean = np.sum(p[..., None] * mu_t, axis=0)
    var = np.sum(p * s2_t, axis=0) + np.sum(p * np.sum((mu_t - mean) ** 2, axis=-1), axis=0) / 2
    assert ok.sum() >= 2 and np.ptp(mu_t[:, ok], axis=0).max() > 1e-3   # the texels' components do differ
    np.testing.assert_allclose(af, wa.sum(axis=0), rtol=1e-12)
    np.testing.assert_allclose(muf[ok], mean[ok], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(s2f[ok], np.maximum(var[ok], VARIANCE_FLOOR), rtol=1e-6, atol=1e-9)


def test_moments_round_trip_and_zero_weight():
    rng = np.random.default_rng(1)
    a = rng.uniform(0.01, 1, (5, K))
    mu = rng.uniform(-0.7, 0.7, (5, K, 2))
    s2 = rng.uniform(1e-5, 0.05, (5, K))
    a2, mu2, s22 = from_moments(to_moments(a, mu, s2))
    np.testing.assert_allclose(a2, a)
    np.testing.assert_allclose(mu2, mu, atol=1e-14)
    np.testing.assert_allclose(s22, s2, rtol=1e-9)
    a0, mu0, s20 = from_moments(np.zeros((3, K, 4)))
    assert np.all(a0 == 0) and np.all(mu0 == 0) and np.all(s20 == VARIANCE_FLOOR)


# --------------------------------------------------------------------------------------------------
# Extremes

def all_finite(mip):
    for q in mip.levels:
        assert q.dtype == np.float32 and np.all(np.isfinite(q))
        a, mu, s2 = from_moments(q)
        assert np.all(np.isfinite(mu)) and np.all(np.isfinite(s2)) and np.all(s2 >= VARIANCE_FLOOR)
        np.testing.assert_allclose(a.sum(-1), 1.0, atol=1e-5)


def test_flat_map():
    mip = build_gmm_mipmap(np.zeros((16, 16)), progress=False)
    all_finite(mip)
    for q in mip.levels:
        a, mu, s2 = from_moments(q)
        assert np.all(s2 <= 2 * VARIANCE_FLOOR) and np.abs(mu).max() < 1e-6


def test_single_spike_and_level_shapes():
    h = np.zeros((16, 16))
    h[5, 9] = 1.0
    for kw in ({}, {"unaligned": True}):
        mip = build_gmm_mipmap(h, scale=0.05, progress=False, **kw)
        all_finite(mip)
        a, mu, s2 = from_moments(mip.levels[-1])
        assert np.sum(a[0, 0] > 0) >= 2      # the top mixture sees flat and tilted normals


def test_one_by_one_map():
    for kw in ({}, {"unaligned": True}):
        mip = build_gmm_mipmap(np.zeros((1, 1)), progress=False, **kw)
        assert len(mip.levels) == 1 and mip.levels[0].shape == (1, 1, K, 4)
        all_finite(mip)
        a, mu, s2 = from_moments(mip.levels[0])     # one flat normal: all the weight on n = (0, 0), no spread
        assert np.isclose(a.sum(), 1.0, atol=1e-6) and np.abs(mu).max() < 1e-6 and np.all(s2 <= 2 * VARIANCE_FLOOR)


def test_non_power_of_two_map():
    h = dunes(64)[:37, :23]
    assert level_shapes(37, 23) == [(37, 23), (19, 12), (10, 6), (5, 3), (3, 2), (2, 1), (1, 1)]
    for kw in ({}, {"unaligned": True}):
        mip = build_gmm_mipmap(h, progress=False, **kw)
        assert [q.shape[:2] for q in mip.levels] == level_shapes(37, 23)
        all_finite(mip)


def test_normals_at_89_degrees():
    rng = np.random.default_rng(3)
    th = np.radians(89.0)
    phi = rng.uniform(0, 2 * np.pi, (12, 12))
    n = np.stack([np.sin(th) * np.cos(phi), np.sin(th) * np.sin(phi), np.full_like(phi, np.cos(th))], -1)
    mip = build_gmm_mipmap(n, kind="normal", progress=False)
    all_finite(mip)
    a, mu, _ = from_moments(mip.levels[0])
    np.testing.assert_allclose(np.sum(a[..., None] * mu, -2), n[..., :2], atol=0.05)
    assert np.linalg.norm(mu, axis=-1).max() <= 1.0 + 1e-6


def test_deterministic():
    h = dunes(24)
    m1, m2 = build_gmm_mipmap(h, progress=False, seed=3), build_gmm_mipmap(h, progress=False, seed=3)
    assert all(np.array_equal(x, y) for x, y in zip(m1.levels, m2.levels))


# --------------------------------------------------------------------------------------------------
# Files, input, command line

def test_write_read_round_trip_and_force(tmp_path):
    mip = build_gmm_mipmap(dunes(20), progress=False, components=3)
    out = tmp_path / "d.gmm"
    write_gmm_mipmap(out, mip, "surface:dunes:20", "abc")
    back = read_gmm_mipmap(out)
    assert back.components == 3 and len(back.levels) == len(mip.levels)
    assert all(np.array_equal(x, y) for x, y in zip(mip.levels, back.levels))
    with pytest.raises(WarpbwError, match="already exists"):
        write_gmm_mipmap(out, mip, "surface:dunes:20", "abc")
    write_gmm_mipmap(out, mip, "surface:dunes:20", "abc", force=True)
    # never over the map it was built from, whatever force says (a link to it neither)
    (tmp_path / "map.exr").write_bytes(b"the height field")
    (tmp_path / "link.gmm").symlink_to(tmp_path / "map.exr")
    for target in (tmp_path / "map.exr", tmp_path / "link.gmm"):
        with pytest.raises(WarpbwError, match=rf"{target}: would overwrite {tmp_path / 'map.exr'}, the file it is "
                                              "made from"):
            write_gmm_mipmap(target, mip, "map.exr", "abc", force=True, inputs=[tmp_path / "map.exr"])
    assert (tmp_path / "map.exr").read_bytes() == b"the height field"


def test_reading_another_format_is_refused(tmp_path):
    from precompute.assetfile import write_asset

    p = write_asset(tmp_path / "x.npz", GMM_FORMAT, 999, "s", "h", {"level_0": np.zeros((1, 1, 4, 4))})
    with pytest.raises(WarpbwError, match="warpbw-precompute gmm"):
        read_gmm_mipmap(p)
    # version 1 stored 004's a (s^2 + |mu|^2): read as a E|n|^2 its lobes would be too narrow, so it is refused
    p = write_asset(tmp_path / "v1.npz", GMM_FORMAT, 1, "dunes.exr", "h", {"level_0": np.zeros((1, 1, 4, 4))},
                    params={"kind": "height", "scale": 0.05, "components": 2})
    with pytest.raises(WarpbwError) as e:
        read_gmm_mipmap(p)
    assert "\n" not in str(e.value) and "version 1" in str(e.value)
    # the command rebuilds it from its own map with its own options ("gmm MAP -o OUT" rebuilt it at scale 1)
    assert str(e.value).endswith("(rebuild it with: warpbw-precompute gmm dunes.exr -o OUT --components 2 --scale "
                                 "0.05 --force)"), str(e.value)


def save_png(path, arr, mode=None):
    from PIL import Image

    Image.fromarray(arr, mode=mode).save(path) if mode else Image.fromarray(arr).save(path)


def test_load_16_bit_png_height_and_grey_rgb(tmp_path):
    v = (np.arange(12 * 10).reshape(12, 10) * 500).astype(np.uint16)
    save_png(tmp_path / "h16.png", v)
    np.testing.assert_allclose(load_map(tmp_path / "h16.png", "height"), v / 65535.0)
    g = np.repeat((np.arange(30).reshape(5, 6) * 8).astype(np.uint8)[..., None], 3, axis=-1)
    save_png(tmp_path / "grey.png", g)
    with pytest.warns(UserWarning, match="8 bits"):
        np.testing.assert_allclose(load_map(tmp_path / "grey.png", "height"), g[..., 0] / 255.0)


def test_an_exr_map_is_read_over_its_display_window(tmp_path):
    """An EXR's display window is the map's frame, its data window the texels stored (OpenEXR, Technical
    Introduction): an overscan border outside the frame is no part of the map (it was read as its edge texels, the
    map 13 x 8 where it is 10 x 6), and a frame's texels the file does not store are 0 (a map cropped to rows 0-3 was
    4 rows high).  The map's size bound covers the frame too.  Files written by OpenEXR itself."""
    import OpenEXR

    heights = np.random.default_rng(5).uniform(0.0, 1.0, (6, 10)).astype(np.float32)

    def write(name, pixels, data, frame):
        box = [(np.array(w[:2], np.int32), np.array(w[2:], np.int32)) for w in (data, frame)]
        OpenEXR.File({"dataWindow": box[0], "displayWindow": box[1]}, {"Y": np.ascontiguousarray(pixels)}).write(
            str(tmp_path / name))
        return tmp_path / name

    over = np.full((8, 13), 99.0, np.float32)
    over[1:7, 2:12] = heights
    assert np.array_equal(load_map(write("overscan.exr", over, (-2, -1, 10, 6), (0, 0, 9, 5)), "height"), heights)
    cropped = heights.copy()
    cropped[4:] = 0.0
    assert np.array_equal(load_map(write("cropped.exr", heights[:4], (0, 0, 9, 3), (0, 0, 9, 5)), "height"), cropped)
    wide = write("wide.exr", heights[:1, :1], (0, 0, 0, 0), (0, 0, 8192, 8191))   # one texel stored, 8193 x 8192
    with pytest.raises(WarpbwError, match=r"wide\.exr: 8193 x 8192 texels: expected a map of at most"):
        load_map(wide, "height")


def _png(path, samples, bits):
    """A greyscale PNG of ``bits`` (1, 2, 4, 8 or 16) per sample, written from the PNG specification (signature, IHDR
    of colour type 0, one IDAT of rows each led by filter byte 0, samples packed from the most significant bit and
    16-bit ones big-endian, IEND; each chunk length, type, data, CRC-32), not by Pillow, which reads it."""
    import struct
    import zlib

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    h, w = samples.shape
    rows = b""
    for row in samples:
        if bits == 16:
            packed = row.astype(">u2").tobytes()
        else:
            per = 8 // bits
            padded = np.concatenate([row, np.zeros(-w % per, row.dtype)]).reshape(-1, per).astype(np.uint16)
            packed = bytes((padded << (8 - bits * (np.arange(per) + 1))).sum(axis=1).astype(np.uint8))
        rows += b"\0" + packed
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, bits, 0, 0, 0, 0))
                     + chunk(b"IDAT", zlib.compress(rows)) + chunk(b"IEND", b""))
    return path


@pytest.mark.parametrize("bits", [1, 2, 4, 8, 16])
def test_a_greyscale_png_height_field_reads_each_sample_over_its_largest_code(tmp_path, bits):
    """A height field PNG of b bits per sample holds the codes 0 to 2^b - 1: each reads as code / (2^b - 1), 1 at the
    largest at every depth, all 16 bits of a 16-bit file kept.  The terracing warning counts the file's own levels: a
    4-bit map was said to be read "with 8 bits: 256 levels" (Pillow widens it to 8) where it holds 16."""
    codes = np.random.default_rng(bits).integers(0, 2 ** bits, (5, 11))
    codes[0, :2] = 0, 2 ** bits - 1
    path = _png(tmp_path / f"h{bits}.png", codes, bits)
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        heights = load_map(path, "height")
    assert np.array_equal(heights, codes / (2 ** bits - 1))
    told = [str(w.message) for w in said]
    if bits == 16:
        assert told == []
    else:
        assert len(told) == 1 and f"read with {bits} bit{'s' if bits > 1 else ''}: {2 ** bits} levels" in told[0], told


def test_load_normal_map_png_and_exr(tmp_path):
    from warpbw.io.exr import write_exr

    n = np.zeros((4, 5, 3))
    n[..., 2] = 1.0
    save_png(tmp_path / "n.png", np.round((n + 1) / 2 * 255).astype(np.uint8))
    got = load_map(tmp_path / "n.png", "normal")
    np.testing.assert_allclose(got[..., 2], 1.0, atol=1e-4)
    n[0, 0] = [-0.6, 0.0, 0.8]
    write_exr(tmp_path / "n.exr", n.astype(np.float32))
    np.testing.assert_allclose(load_map(tmp_path / "n.exr", "normal"), n, atol=1e-6)
    # unit vectors without a negative component are vectors too, not [0, 1]-encoded (which would put
    # this 89-degree normal at (1, -1, -0.97), below the surface)
    n[0, 0] = [np.sin(np.radians(89.0)), 0.0, np.cos(np.radians(89.0))]
    write_exr(tmp_path / "n89.exr", n.astype(np.float32))
    np.testing.assert_allclose(load_map(tmp_path / "n89.exr", "normal"), n, atol=1e-6)
    # and a [0, 1]-encoded EXR (flat texels (0.5, 0.5, 1)) still decodes
    write_exr(tmp_path / "enc.exr", ((n + 1.0) / 2.0).astype(np.float32))
    np.testing.assert_allclose(load_map(tmp_path / "enc.exr", "normal"), n, atol=1e-6)


@pytest.mark.parametrize("length", [0.7, 2.0])
def test_exr_of_unnormalised_vectors_all_non_negative_is_read_as_vectors(tmp_path, length):
    """Raw vectors of length 0.7 or 2 with no negative component: no texel is unit either way, and they were
    decoded as (n + 1) / 2 and refused as pointing below the surface.  Read as vectors (one warning: renormalised);
    the same normals [0, 1]-encoded at 0.97 of their length still decode."""
    from warpbw.io.exr import write_exr

    rng = np.random.default_rng(1)
    n = np.abs(rng.normal(size=(8, 8, 3))) * 0.2
    n[..., 2] = 1.0
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    write_exr(tmp_path / "raw.exr", (n * length).astype(np.float32))
    with pytest.warns(UserWarning, match="64 of 64 texels are not unit normals as stored \\(raw vectors\\)"):
        np.testing.assert_allclose(load_map(tmp_path / "raw.exr", "normal"), n, atol=1e-6)
    write_exr(tmp_path / "enc.exr", ((n + 1.0) / 2.0 * 0.97).astype(np.float32))
    with pytest.warns(UserWarning, match="as decoded"):
        np.testing.assert_allclose(load_map(tmp_path / "enc.exr", "normal"), n, atol=0.05)


def test_normal_map_below_the_surface(tmp_path):
    """An 8-bit texel one step below the horizon (z = -1/255) lies in the tangent plane; a normal pointing
    into the surface (an object-space map, an all-black image) is an error naming the file and the texel."""
    enc = np.full((3, 4, 3), 128, np.uint8)
    enc[..., 2] = 255
    enc[1, 2] = [255, 128, 127]          # n = (1, 1/255, -1/255) before normalising: the horizon
    save_png(tmp_path / "horizon.png", enc)
    n = load_map(tmp_path / "horizon.png", "normal")
    assert n[1, 2, 2] == 0.0 and n[1, 2, 0] > 0.99
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-12)
    enc[2, 3] = [128, 128, 0]            # straight into the surface
    save_png(tmp_path / "into.png", enc)
    with pytest.raises(WarpbwError, match=r"into.png: 1 texels hold normals pointing below the surface "
                                          r"\(first at row 2, column 3: z = -1.000\)"):
        load_map(tmp_path / "into.png", "normal")
    # an all-black image, as PNG or EXR: said to be empty, without a "renormalised" warning first
    from warpbw.io.exr import write_exr

    save_png(tmp_path / "black.png", np.zeros((2, 2, 3), np.uint8))
    write_exr(tmp_path / "black.exr", np.zeros((2, 2, 3), np.float32))
    for name in ("black.png", "black.exr"):
        with pytest.raises(WarpbwError, match=rf"{name}: every texel is \(0, 0, 0\): an empty image, not a normal "
                                              "map"), warnings.catch_warnings():
            warnings.simplefilter("error")
            load_map(tmp_path / name, "normal")


def test_a_float_normal_map_is_read_as_most_of_its_texels_say(tmp_path):
    """A float map of raw unit normals with one texel off unit length (1.05, or 0.97 in a resampled map) was
    decoded as (n + 1) / 2 as a whole: every flat normal became (-0.577, -0.577, 0.577), without a word.  It is
    read as vectors (most texels are unit as stored), and the odd texel is renormalised with a warning."""
    from warpbw.io.exr import write_exr

    n = np.zeros((6, 6, 3))
    n[..., 2] = 1.0
    n[2, 3] = [0.0, 0.0, 1.05]
    write_exr(tmp_path / "raw.exr", n.astype(np.float32))
    with pytest.warns(UserWarning, match=r"raw.exr: 1 of 36 texels are not unit normals as stored .*row 2, column 3: "
                                         r"length 1.05\); renormalised"):
        got = load_map(tmp_path / "raw.exr", "normal")
    np.testing.assert_allclose(got, np.broadcast_to([0.0, 0.0, 1.0], got.shape), atol=1e-7)
    tilt = np.array([0.3, 0.0, np.sqrt(1 - 0.09)])
    n = np.broadcast_to(tilt, (6, 6, 3)).copy()
    n[1, 1] *= 0.97
    write_exr(tmp_path / "tilt.exr", n.astype(np.float32))
    with pytest.warns(UserWarning, match="tilt.exr: 1 of 36"):
        np.testing.assert_allclose(load_map(tmp_path / "tilt.exr", "normal"), np.broadcast_to(tilt, n.shape), atol=1e-6)
    # the same map [0, 1]-encoded, odd texel and all, is still decoded
    write_exr(tmp_path / "enc.exr", ((n / np.linalg.norm(n, axis=-1, keepdims=True) + 1) / 2).astype(np.float32))
    np.testing.assert_allclose(load_map(tmp_path / "enc.exr", "normal"), np.broadcast_to(tilt, n.shape), atol=1e-6)
    n[4, 4] = 0.0                        # a zero vector is named as one (it was called "below the surface")
    write_exr(tmp_path / "zero.exr", n.astype(np.float32))
    with pytest.raises(WarpbwError, match=r"zero.exr: 1 normal-map texels hold vectors shorter than 0.5 \(first at "
                                          r"row 4, column 4: length 0\)"):
        load_map(tmp_path / "zero.exr", "normal")


def test_a_grey_texel_of_a_normal_map_is_refused(tmp_path):
    """(128, 128, 128) decodes to (0.004, 0.004, 0.004): it passed a 1e-6 length bound and was renormalised to a
    normal 55 degrees off the surface's.  An all-grey placeholder image went through the same way."""
    enc = np.full((4, 4, 3), 128, np.uint8)
    enc[..., 2] = 255
    enc[3, 1] = 128
    save_png(tmp_path / "hole.png", enc)
    with pytest.raises(WarpbwError, match=r"hole.png: 1 normal-map texels decode to vectors shorter than 0.5 "
                                          r"\(first at row 3, column 1: length 0.00679\)"):
        load_map(tmp_path / "hole.png", "normal")
    save_png(tmp_path / "grey.png", np.full((4, 4, 3), 128, np.uint8))
    with pytest.raises(WarpbwError, match="grey.png: 16 normal-map texels decode to vectors shorter"):
        load_map(tmp_path / "grey.png", "normal")


@pytest.mark.parametrize("prior", [1.0, 64.0])
def test_steep_random_heights_build_a_mipmap_its_own_writer_takes(tmp_path, prior):
    """Uniform random heights at scale 1 (slopes of tens: normals near the horizon): the prior pulls a component's
    mean off its samples' mean, and E|n|^2 = d s^2 + |mu|^2 came out up to 3e-4 above the weight, beyond the unit
    disk every normal lies in, and warpbw-precompute gmm refused its own output.  The stored moments stay within it."""
    from precompute.gmm_mipmap import mipmap_problem, write_gmm_mipmap

    h = np.random.default_rng(0).random((37, 53))
    mip = build_gmm_mipmap(h, prior=prior, progress=False)
    for q in mip.levels:
        assert np.all(q[..., 3] <= q[..., 0] * (1 + 1e-6) + 1e-7)
    assert mipmap_problem(mip.levels, mip.components, mip.prior, mip.scale) is None
    write_gmm_mipmap(tmp_path / "h.gmm", mip, "h.exr", "hash")


def test_gmm_builder_refuses_a_prior_and_slopes_that_overflowed_into_nan(tmp_path):
    """c = 1e308 wrote levels of NaN moments (exit 0); heights times scale 1e155 stopped in scikit-learn ("Input X
    contains NaN"), and with --unaligned wrote NaN everywhere.  c is bounded by MAX_PRIOR; slopes up to the
    largest float64 give normals (beyond, a clear error)."""
    from precompute.gmm_mipmap import MAX_PRIOR

    h = np.random.default_rng(3).random((8, 8))
    for c in (1e308, MAX_PRIOR * 2, float("nan"), -1.0, True):   # True: a flag, not the c the CLI would take
        with pytest.raises(WarpbwError, match="prior .*expected a finite c >= 0, at most 1e\\+06"):
            build_gmm_mipmap(h, prior=c, progress=False)
    for key, value in (("components", True), ("components", 2.0), ("scale", False), ("scale", "2")):
        with pytest.raises(WarpbwError, match=f"{key} {value!r}: expected"):
            build_gmm_mipmap(h, progress=False, **{key: value})
    mip = build_gmm_mipmap(h, prior=MAX_PRIOR, progress=False)
    assert all(np.isfinite(q).all() for q in mip.levels)
    for unaligned in (False, True):
        mip = build_gmm_mipmap(h, scale=1e155, unaligned=unaligned, progress=False)
        assert all(np.isfinite(q).all() for q in mip.levels)
        top = mip.levels[-1][0, 0]
        # slopes of 1e155: every normal lies in the tangent plane, |mu| = 1 in normal space
        assert np.linalg.norm(top[:, 1:3].sum(0)) <= top[:, 0].sum() + 1e-5
    with pytest.raises(WarpbwError, match="slopes overflow float64"):
        build_gmm_mipmap(h * 3e38, scale=1e300, progress=False)


def test_map_files_too_large_or_truncated_are_named(tmp_path):
    """A 20000 x 20000 PNG (389 kB) stopped in Pillow's DecompressionBombError, with a traceback; a truncated PNG
    was "not an image file"."""
    from precompute.gmm_mipmap import MAX_MAP_TEXELS

    save_png(tmp_path / "big.png", np.zeros((20000, 20000), np.uint8))
    with pytest.raises(WarpbwError, match=f"big.png: over .* texels: expected a map of at most {MAX_MAP_TEXELS}"):
        load_map(tmp_path / "big.png", "height")
    save_png(tmp_path / "wide.png", np.zeros((2, MAX_MAP_TEXELS // 2 + 1), np.uint8))
    with pytest.raises(WarpbwError, match=f"wide.png: {MAX_MAP_TEXELS // 2 + 1} x 2 texels: expected a map"):
        load_map(tmp_path / "wide.png", "height")
    # an EXR's size is read from its header before its pixels: this one claims more texels than it holds
    exr_claiming_size(tmp_path / "claims.exr", 20000, 20000)
    with pytest.raises(WarpbwError, match="claims.exr: 20000 x 20000 texels: expected a map of at most"):
        load_map(tmp_path / "claims.exr", "height")
    v = (np.arange(64 * 64).reshape(64, 64) * 13 % 65536).astype(np.uint16)
    save_png(tmp_path / "h.png", v)
    data = (tmp_path / "h.png").read_bytes()
    (tmp_path / "cut.png").write_bytes(data[: len(data) // 2])
    with pytest.raises(WarpbwError, match="cut.png: cannot decode this PNG \\(truncated or corrupt"):
        load_map(tmp_path / "cut.png", "height")


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(theta=st.floats(0.0, np.pi / 2), phi=st.floats(0.0, 2 * np.pi), exr=st.booleans())
def test_encoded_normal_round_trip(tmp_path, theta, phi, exr):
    """Any normal of the upper hemisphere, horizon included, [0, 1]-encoded in an 8-bit PNG or a float
    EXR beside a flat texel, reads back as a unit normal with z >= 0 within the encoding's quantisation.
    (Without the flat texel an EXR of one normal with n_x + n_y + n_z = 0 is ambiguous: its encoded
    texels are unit vectors too, and ``load_map`` then reads them as vectors.)"""
    from warpbw.io.exr import write_exr

    n = np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
    normals = np.broadcast_to(n, (2, 3, 3)).copy()
    normals[0, 0] = [0.0, 0.0, 1.0]
    enc = (normals + 1.0) / 2.0
    if exr:
        write_exr(tmp_path / "n.exr", enc.astype(np.float32), channels=["R", "G", "B"])
        got, tol = load_map(tmp_path / "n.exr", "normal"), 1e-6
    else:
        save_png(tmp_path / "n.png", np.round(enc * 255).astype(np.uint8))
        got, tol = load_map(tmp_path / "n.png", "normal"), 2.0 / 255.0
    np.testing.assert_allclose(np.linalg.norm(got, axis=-1), 1.0, atol=1e-12)
    assert np.all(got[..., 2] >= 0.0)
    assert np.abs(got - normals).max() <= 2.0 * tol


def test_builder_refuses_normals_that_are_not_unit_or_point_down():
    n = np.zeros((4, 4, 3))
    n[..., 2] = 1.0
    build_gmm_mipmap(n, kind="normal", progress=False)
    with pytest.raises(WarpbwError, match=r"not unit vectors \(first at row 1, column 0: length 1.1"):
        m = n.copy()
        m[1, 0] = [0.0, 0.0, 1.1]
        build_gmm_mipmap(m, kind="normal", progress=False)
    with pytest.raises(WarpbwError, match="below the surface"):
        m = n.copy()
        m[3, 3] = [0.6, 0.0, -0.8]
        build_gmm_mipmap(m, kind="normal", progress=False)


def _png16(path, values, colour_type):
    """A 16-bit PNG of ``values`` (H, W, C) uint16, written by hand (Pillow writes 16-bit greyscale only): colour
    type 2 is RGB, 4 grey + alpha, 6 RGBA (PNG spec 11.2.2)."""
    import struct
    import zlib

    h, w = values.shape[:2]
    rows = b"".join(b"\x00" + values[r].astype(">u2").tobytes() for r in range(h))

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, colour_type, 0, 0, 0))
                     + chunk(b"IDAT", zlib.compress(rows)) + chunk(b"IEND", b""))


@pytest.mark.parametrize("colour_type,kind", [(2, "height"), (4, "height"), (6, "height"), (2, "normal"),
                                              (6, "normal")])
def test_a_16_bit_colour_png_is_read_with_its_16_bits(tmp_path, colour_type, kind):
    """16-bit RGB, grey + alpha and RGBA PNGs (a common normal-map asset) were read by Pillow with 8 bits, with a
    warning: a smooth ramp in the low byte kept one level of 48, and a normal map's vectors moved by up to 1/255 of
    the range (terraced normals).  warpbw.io.png reads them whole (session 82): each value as stored over 65535,
    alpha not read, quietly.  Truth: the codes written (an alpha varying everywhere, so that reading it would show)."""
    ramp = (30000 + 97 * np.arange(8 * 6).reshape(8, 6)).astype(np.uint16)
    alpha = (np.arange(48).reshape(8, 6) * 1000).astype(np.uint16)
    if kind == "height":
        values = np.stack([ramp] * 3 + [alpha] * (colour_type == 6), -1) if colour_type != 4 else \
            np.stack([ramp, alpha], -1)
    else:   # a [0, 1]-encoded normal map tilted along x by the ramp, n_y 0 (32767.5: 16 bits can say half)
        nx = ramp / 65535.0 * 2.0 - 1.0
        nz = np.round((np.sqrt(1.0 - nx ** 2) + 1.0) / 2.0 * 65535.0).astype(np.uint16)
        values = np.stack([ramp, np.full_like(ramp, 32768), nz] + [alpha] * (colour_type == 6), -1)
    _png16(tmp_path / "m.png", values, colour_type)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = load_map(tmp_path / "m.png", kind)
    if kind == "height":
        assert np.array_equal(got, ramp / 65535.0)
    else:
        stored = values[..., :3] / 65535.0 * 2.0 - 1.0
        np.testing.assert_allclose(got, stored / np.linalg.norm(stored, axis=-1, keepdims=True), rtol=0, atol=1e-15)
    _png16(tmp_path / "g.png", ramp[..., None], 0)   # the same heights as 16-bit grey (Pillow's): the same values
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert np.array_equal(load_map(tmp_path / "g.png", "height"), ramp / 65535.0)


def test_8_bit_height_field_warns_of_terraces(tmp_path):
    ramp = (np.arange(8 * 6).reshape(8, 6) * 5).astype(np.uint8)
    save_png(tmp_path / "h8.png", ramp)
    with pytest.warns(UserWarning, match="h8.png: heights read with 8 bits"):
        np.testing.assert_allclose(load_map(tmp_path / "h8.png", "height"), ramp / 255.0)
    from PIL import Image

    Image.fromarray(ramp > 100).convert("1").save(tmp_path / "h1.png")      # 1 bit: two levels
    with pytest.warns(UserWarning, match="h1.png: heights read with 1 bit: 2 levels"):
        np.testing.assert_array_equal(load_map(tmp_path / "h1.png", "height"), (ramp > 100).astype(float))
    save_png(tmp_path / "h16.png", ramp.astype(np.uint16) * 257)
    save_png(tmp_path / "flat8.png", np.full((4, 4), 7, np.uint8))
    with warnings.catch_warnings():
        warnings.simplefilter("error")   # a 16-bit map, and a flat 8-bit one (no terraces), are quiet
        load_map(tmp_path / "h16.png", "height")
        load_map(tmp_path / "flat8.png", "height")


def test_other_pillow_formats_are_read_and_jpeg_warns(tmp_path):
    """A 16-bit TIFF height field is read whole, like a 16-bit PNG; a JPEG normal map is read, and warns that its
    lossy compression reads as bumps: its flat blue decodes to normals off the vertical by JPEG's rounding."""
    from PIL import Image

    ramp = (30000 + np.arange(8 * 6).reshape(8, 6) * 3).astype(np.uint16)
    Image.fromarray(ramp).save(tmp_path / "h.tif")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        np.testing.assert_allclose(load_map(tmp_path / "h.tif", "height"), ramp / 65535.0)
    flat = np.zeros((16, 16, 3), np.uint8)
    flat[..., :2], flat[..., 2] = 128, 255
    Image.fromarray(flat).save(tmp_path / "n.jpg", quality=90)
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        n = load_map(tmp_path / "n.jpg", "normal")
    assert any("n.jpg: a JPEG image: its lossy compression" in str(w.message) for w in said), said
    assert n.shape == (16, 16, 3) and n[..., 2].min() > 0.99
    Image.fromarray(flat).save(tmp_path / "n.png")     # the same texels lossless: quiet
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_map(tmp_path / "n.png", "normal")


def test_bad_inputs_name_the_file(tmp_path):
    from warpbw.io.exr import write_exr

    txt = tmp_path / "notes.png"
    txt.write_text("not an image")
    with pytest.raises(WarpbwError, match="notes.png.*not an image"):
        load_map(txt, "height")
    rgb = np.zeros((6, 6, 3), np.uint8)
    rgb[..., 0] = 200
    save_png(tmp_path / "colour.png", rgb)
    with pytest.raises(WarpbwError, match="colour.png.*RGB.*height field"):
        load_map(tmp_path / "colour.png", "height")
    with pytest.raises(WarpbwError, match="single-channel.*normal map"):
        save_png(tmp_path / "grey.png", np.zeros((4, 4), np.uint8))
        load_map(tmp_path / "grey.png", "normal")
    h = np.zeros((8, 9, 1), np.float32)
    h[3, 4] = np.nan
    h[6, 1] = np.inf
    write_exr(tmp_path / "holes.exr", h, channels=["Y"])
    with pytest.raises(WarpbwError, match=r"holes.exr: 2 texels are NaN or infinite \(first at row 3, column 4\)"):
        load_map(tmp_path / "holes.exr", "height")
    with pytest.raises(WarpbwError, match="missing.exr.*not found"):
        load_map(tmp_path / "missing.exr", "height")
    with pytest.raises(WarpbwError, match="unknown procedural surface"):
        load_source("surface:dune:32")


def cli(argv):
    from precompute.__main__ import main

    return main([str(a) for a in argv])


def test_cli_builds_a_surface_and_refuses_to_overwrite(tmp_path, capsys):
    out = tmp_path / "d.gmm"
    assert cli(["gmm", "surface:dunes:24", "-o", out, "--components", "2", "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "d.gmm" in printed and " s)" in printed
    mip = read_gmm_mipmap(out)
    assert mip.components == 2 and mip.shape == (24, 24)
    assert cli(["gmm", "surface:dunes:24", "-o", out, "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "already exists" in err and "--force" in err
    assert cli(["gmm", "surface:dunes:24", "-o", out, "--quiet", "--force", "--unaligned"]) == 0
    assert read_gmm_mipmap(out).unaligned


@pytest.mark.parametrize("case", ["text", "rgb", "nan"])
def test_cli_bad_input_is_one_line(tmp_path, capsys, case):
    from warpbw.io.exr import write_exr

    if case == "text":
        src = tmp_path / "readme.exr"
        src.write_text("hello")
        needle = "readme.exr"
    elif case == "rgb":
        src = tmp_path / "rgb.png"
        rgb = np.zeros((6, 6, 3), np.uint8)
        rgb[..., 1] = 90
        save_png(src, rgb)
        needle = "RGB image with differing channels"
    else:
        src = tmp_path / "nan.exr"
        h = np.zeros((5, 5, 1), np.float32)
        h[2, 2] = np.nan
        write_exr(src, h, channels=["Y"])
        needle = "NaN"
    out = tmp_path / "out.gmm"
    assert cli(["gmm", src, "-o", out, "--quiet"]) == 2
    cap = capsys.readouterr()
    lines = [ln for ln in cap.err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("warpbw-precompute: error: "), cap.err
    assert src.name in lines[0] and needle in lines[0] and "Traceback" not in cap.err + cap.out
    assert not out.exists()


def test_neighbour_prior_sums_over_the_13_neighbours_of_004_by_brute_force():
    """The prior's sums (004 Sec. 4.1: eight neighbours at the same level, the map tiling; the parent; the four
    children) against explicit loops over a small odd-sized pyramid, with random weights, means and fitted
    flags: every neighbour counts once, only when fitted, never the texel itself."""
    from precompute.gmm_mipmap import _neighbour_prior

    rng = np.random.default_rng(7)
    K = 3
    shapes = level_shapes(7, 5)
    A = [rng.random((h, w, K)) for h, w in shapes]
    MU = [rng.normal(size=(h, w, K, 2)) for h, w in shapes]
    fitted = [rng.random((h, w)) < 0.7 for h, w in shapes]
    for l, (h, w) in enumerate(shapes):
        ii, jj = np.divmod(np.arange(h * w), w)
        p_sum, p_w = _neighbour_prior(l, ii, jj, A, MU, fitted, shapes)
        for t, (i, j) in enumerate(zip(ii, jj)):
            same = {((i + di) % h, (j + dj) % w) for di in (-1, 0, 1) for dj in (-1, 0, 1)} - {(i, j)}
            nbrs = [(l, a, b) for a, b in same]
            if l + 1 < len(shapes):
                nbrs.append((l + 1, i // 2, j // 2))
            if l > 0:
                hc, wc = shapes[l - 1]
                nbrs += [(l - 1, 2 * i + a, 2 * j + b) for a in (0, 1) for b in (0, 1)
                         if 2 * i + a < hc and 2 * j + b < wc]
            want_w = sum((A[m][a, b] for m, a, b in nbrs if fitted[m][a, b]), np.zeros(K))
            want_s = sum((A[m][a, b][:, None] * MU[m][a, b] for m, a, b in nbrs if fitted[m][a, b]), np.zeros((K, 2)))
            np.testing.assert_allclose(p_w[t], want_w, rtol=1e-12, atol=1e-12, err_msg=f"level {l} texel {(i, j)}")
            np.testing.assert_allclose(p_sum[t], want_s, rtol=1e-12, atol=1e-12, err_msg=f"level {l} texel {(i, j)}")


def test_same_level_neighbours_fitted_earlier_enter_each_texels_prior(monkeypatch):
    """004 Sec. 4.1 fits a level's texels in scan-line order, each pulled towards its already fitted neighbours at the
    same level as well as its parent and children; the builder's stand-in is four interleaved parity classes.  So at
    every level of at least 2 x 2 texels, the classes after the first must see same-level neighbours already fitted
    -- and the fitted ones are exactly the earlier classes' texels.  (Recorded at the prior's input; the truth is
    the order 004 prescribes, not the builder's result.)"""
    import precompute.gmm_mipmap as gm

    seen = []
    real = gm._neighbour_prior

    def spy(l, ii, jj, A, MU, fitted, shapes):
        seen.append((l, ii.copy(), jj.copy(), fitted[l].copy()))
        return real(l, ii, jj, A, MU, fitted, shapes)

    monkeypatch.setattr(gm, "_neighbour_prior", spy)
    mip = gm.build_gmm_mipmap(hemispherical_scales(16, scales_across=2), components=2, progress=False)
    shapes = [q.shape[:2] for q in mip.levels]
    for l, (h, w) in enumerate(shapes):
        calls = [c for c in seen if c[0] == l]
        if h < 2 or w < 2:
            continue
        assert len(calls) == 4, (l, len(calls))
        done = np.zeros((h, w), bool)
        for _, ii, jj, fitted in calls:
            np.testing.assert_array_equal(fitted, done)      # exactly the earlier classes' texels
            done[ii, jj] = True
        assert done.all()
        assert calls[-1][3].sum() == h * w - len(calls[-1][1]) > 0


def _gmm_capture(monkeypatch, tmp_path, argv, source="surface:dunes:8"):
    import precompute.gmm_mipmap as gm
    from precompute.__main__ import main

    monkeypatch.chdir(tmp_path)
    got = {}

    def fake(data, **kwargs):
        got.update(kwargs)
        raise Handed

    monkeypatch.setattr(gm, "build_gmm_mipmap", fake)
    with pytest.raises(Handed):
        main(["gmm", source, "-o", "d.npz", "-q", *argv])
    return got


def test_precompute_gmm_hands_each_option_to_the_builder(tmp_path, monkeypatch):
    """``warpbw-precompute gmm``: --components, --prior, --scale, --seed and --unaligned must reach
    ``build_gmm_mipmap`` as given (a mipmap built with other settings than asked is refused later by the scene
    that names it, or worse, matches a scene written for the defaults)."""
    got = _gmm_capture(monkeypatch, tmp_path, ["--components", "3", "--prior", "0.25", "--scale", "0.05",
                                               "--seed", "8"])
    assert (got["kind"], got["components"], got["prior"], got["scale"], got["seed"], got["unaligned"]) == \
        ("height", 3, 0.25, 0.05, 8, False)
    got = _gmm_capture(monkeypatch, tmp_path, ["--unaligned"])
    assert got["unaligned"] is True
    from PIL import Image

    Image.fromarray(np.full((8, 8, 3), (128, 128, 255), np.uint8)).save(tmp_path / "n.png")
    got = _gmm_capture(monkeypatch, tmp_path, ["--kind", "normal"], source="n.png")
    assert got["kind"] == "normal"


def test_precompute_gmm_defaults_are_the_scene_files_defaults(tmp_path, monkeypatch):
    """README: a scene's ``gmm_components`` and ``gmm_prior`` default to 4 and 1, and a ``gmm`` file must have been
    built with the scene's components and prior.  So ``warpbw-precompute gmm`` without options must build with 4
    components, prior 1 (its --help says so too), kind height, scale 1 and seed 0."""
    from warpbw.scene import GMM_DEFAULT_COMPONENTS, GMM_DEFAULT_PRIOR

    got = _gmm_capture(monkeypatch, tmp_path, [])
    assert (got["components"], got["prior"]) == (4, 1.0) == (GMM_DEFAULT_COMPONENTS, GMM_DEFAULT_PRIOR)
    assert (got["kind"], got["scale"], got["seed"], got["unaligned"]) == ("height", 1.0, 0, False)


def test_gmm_precompute_time_builds_with_the_components_asked_for(monkeypatch):
    """--components and --size reach the timed build (the figure is "N components at SIZE"): the first surface
    is built from a SIZE x SIZE height field with that many Gaussians."""

    gt = load_example("gmm_precompute_time")
    got = []

    def fake(h, **kw):   # the first build is the untimed warm-up; the second the first timed one
        got.append(dict(kw, shape=np.shape(h)))
        if len(got) == 2:
            raise Handed
        return SimpleNamespace(levels=[None])

    monkeypatch.setattr(gt, "build_gmm_mipmap", fake)
    with pytest.raises(Handed):
        gt.main(["--size", "24", "--components", "2"])
    assert [g["components"] for g in got] == [2, 2] and got[1]["shape"][:2] == (24, 24)


def _run_gmm_precompute_time(monkeypatch, argv, runs: int = 3):
    """gmm_precompute_time.main with stand-ins for the build and the clock: the warm-up takes 100 s, and the
    ``runs`` timed builds of each surface 3, 1, 2, 3, 1, 2, ... seconds (the median of three runs is 2 s); the
    builds of the i-th surface have 5 + i levels."""
    gt = load_example("gmm_precompute_time")
    clock, calls = StandInClock(), []

    def build(h, components, progress):
        k = len(calls)
        calls.append(np.shape(h))
        clock.now += 100.0 if k == 0 else (3.0, 1.0, 2.0)[(k - 1) % 3]
        return SimpleNamespace(levels=[None] * (5 + max(0, k - 1) // runs))

    monkeypatch.setattr(gt, "build_gmm_mipmap", build)
    monkeypatch.setattr(gt, "time", clock)
    return gt, calls, outcome(gt.main, argv)


def test_gmm_precompute_time_record_and_plot_hold_what_it_prints(monkeypatch, capsys, tmp_path):
    """DESIGN.md, measurement protocol: every benchmark writes a JSON record and a PNG plot, its time the median of
    at least 3 runs after a warm-up.  The script timed one build per surface (the first paying the imports) and
    wrote no plot; now each surface's printed seconds and its record's ``time_s`` are the median of --runs timed
    builds (stand-in clock: runs of 3, 1 and 2 s, median 2), the 100 s warm-up in none of them, and --json's plot is
    beside it."""
    monkeypatch.chdir(tmp_path)
    gt, calls, how = _run_gmm_precompute_time(monkeypatch, ["--size", "20", "--components", "2", "--json", "t.json"])
    assert how == "returned 0", how
    assert len(calls) == 1 + 3 * 3 and set(calls[1:]) == {(20, 20)}
    out = capsys.readouterr().out
    rows = re.findall(r"^(\w+) +20x20, 2 components, (\d+) levels: +([\d.]+) s$", out, flags=re.M)
    assert [r[0] for r in rows] == ["dunes", "hemispherical_scales", "carved_disk"], out
    rec = json.loads((tmp_path / "t.json").read_text())
    assert (rec["size"], rec["components"], rec["runs"], rec["aim_time_s"]) == (20, 2, 3, 60.0)
    assert rec["cpu_count"] >= 1
    for i, (name, levels, secs) in enumerate(rows):
        assert rec["time_s"][name] == 2.0 and f"{rec['time_s'][name]:.1f}" == secs
        assert rec["time_runs_s"][name] == [3.0, 1.0, 2.0]
        assert rec["levels"][name] == int(levels) == 5 + i
    plot_png(tmp_path / "t.png")
    assert "record t.json, plot t.png" in out


@pytest.mark.parametrize("argv, needle", [
    (["--json", "old.json"], "old.json: already exists"),
    (["--plot", "p.png"], "p.png: already exists"),
    (["--json", "new.json"], "new.png: already exists"),      # the plot beside it would replace a file
    (["--json", "t.txt"], "--json t.txt: expected a path ending in .json"),
    (["--plot", "t.jpg", "--force"], "--plot t.jpg: expected a path ending in .png"),
    (["--plot", "d.png", "--force"], "--plot d.png: is a directory"),
])
def test_gmm_precompute_time_refuses_its_outputs_before_any_build(monkeypatch, tmp_path, argv, needle):
    """--json / --plot follow warpbw bench's rules (suffix, an existing file kept without --force), checked before
    the first build (the stand-in records none), nothing written."""
    monkeypatch.chdir(tmp_path)
    for name in ("old.json", "p.png", "new.png"):
        (tmp_path / name).write_text("kept\n")
    (tmp_path / "d.png").mkdir()
    before = sorted(p.name for p in tmp_path.iterdir())
    gt, calls, how = _run_gmm_precompute_time(monkeypatch, ["--size", "20", *argv])
    assert how.startswith("WarpbwError") and needle in how and calls == [], how
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    assert all((tmp_path / n).read_text() == "kept\n" for n in ("old.json", "p.png", "new.png"))


@pytest.mark.parametrize("runs, warns", [(1, True), (2, True), (3, False)])
def test_gmm_precompute_time_times_runs_and_warns_below_three(monkeypatch, capsys, runs, warns):
    """--runs builds per surface (default 3, warpbw bench's); fewer are timed with the protocol's warning."""
    gt, calls, how = _run_gmm_precompute_time(monkeypatch, ["--size", "20", "--runs", str(runs)], runs)
    assert how == "returned 0" and len(calls) == 1 + 3 * runs, how
    err = capsys.readouterr().err
    assert (f"gmm_precompute_time.py: warning: --runs {runs}: the measurement protocol times the median of at least 3"
            in err) == warns, err


def test_gmm_precompute_time_writes_a_real_record(tmp_path):
    """The script itself on the smallest map it takes (17x17, 1 component, 1 run): the record's keys, its times
    those printed, and a PNG matplotlib reads."""
    import subprocess
    import sys

    import matplotlib.image

    r = subprocess.run([sys.executable, str(EXAMPLE_GMM_TIME), "--size", "17", "--components", "1", "--runs", "1",
                        "--plot", "t.png"], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    rec = json.loads((tmp_path / "t.json").read_text())
    assert {"size", "components", "runs", "cpu_count", "aim_time_s", "time_s", "time_runs_s", "levels"} <= set(rec)
    rows = re.findall(r"^(\w+) +17x17, 1 components, (\d+) levels: +([\d.]+) s$", r.stdout, flags=re.M)
    assert len(rows) == 3, r.stdout
    for name, levels, secs in rows:
        assert f"{rec['time_s'][name]:6.1f}".strip() == secs and rec["time_runs_s"][name] == [rec["time_s"][name]]
        assert rec["levels"][name] == int(levels) == 6   # 17, 9, 5, 3, 2, 1 texels a side
    assert matplotlib.image.imread(tmp_path / "t.png").ndim == 3
    assert "--runs 1: the measurement protocol" in r.stderr


def _rebuild_hint(path, match=None):
    """(program, parsed arguments, refusal text) of the rebuild hint in read_gmm_mipmap's refusal of ``path``, split
    as a POSIX shell splits it and parsed by warpbw-precompute's own parser."""
    from precompute.__main__ import build_parser

    with pytest.raises(WarpbwError, match=match) as e:
        read_gmm_mipmap(path)
    prog, *argv = shlex.split(str(e.value).split("rebuild it with: ", 1)[1].rstrip(")"))
    return prog, build_parser().parse_args(argv), str(e.value)


@pytest.mark.parametrize("params, expected", [
    ({"kind": "normal", "components": 2, "prior": 0.1234567891, "unaligned": False, "scale": 1.0, "seed": 7},
     dict(kind="normal", components=2, prior=0.1234567891, unaligned=False, scale=1.0, seed=7)),
    ({"kind": "height", "components": 8, "prior": 1.0, "unaligned": True, "scale": 3.0, "seed": 0},
     dict(kind="height", components=8, prior=1.0, unaligned=True, scale=3.0, seed=0)),
    ({}, dict(kind="height", components=4, prior=1.0, unaligned=False, scale=1.0, seed=0)),
], ids=["normal map", "unaligned height field", "no parameters recorded"])
def test_a_refused_mipmap_names_the_command_that_rebuilds_it_as_it_was_built(tmp_path, params, expected):
    """The hint in a refusal, split as a POSIX shell splits it and parsed by warpbw-precompute's own parser, rebuilds
    the same mipmap: the map (a name with a space is one word) and every option the header records, to the last
    digit.  It named the map only, so a normal map was rebuilt as a height field, with the default components and
    prior."""
    from precompute.__main__ import cmd_gmm
    from precompute.assetfile import write_asset
    from precompute.gmm_mipmap import GMM_VERSION

    write_asset(tmp_path / "m.npz", GMM_FORMAT, GMM_VERSION, "my scales.png", "h", {}, params)   # no levels
    prog, args, said = _rebuild_hint(tmp_path / "m.npz", match="without its levels")
    assert (prog, args.func, args.map, args.force) == ("warpbw-precompute", cmd_gmm, "my scales.png", True)
    assert {k: getattr(args, k) for k in expected} == expected, said


def test_gmm_mipmap_example_defaults_are_those_its_help_states(tmp_path, monkeypatch):
    """--help: --size 'default 128', --components 'default 4', the surface hemispherical scales (the module
    docstring's first example); --components and --size up to their builders' maxima, one more refused."""
    import precompute.gmm_mipmap as gm
    import precompute.surfaces as surfaces

    ex = load_example("gmm_mipmap")
    got = capture_call(monkeypatch, gm, "build_gmm_mipmap")
    out = str(tmp_path / "g.png")
    assert outcome(ex.main, ["-o", out]) == "Handed"
    h = got["_args"][0]
    assert h.shape == (128, 128) and got["components"] == 4
    np.testing.assert_array_equal(h, surfaces.SURFACES["hemispherical_scales"](128))
    assert outcome(ex.main, ["-o", out, "--components", str(gm.MAX_COMPONENTS)]) == "Handed"
    assert got["components"] == gm.MAX_COMPONENTS
    assert outcome(ex.main, ["-o", out, "--components", str(gm.MAX_COMPONENTS + 1)]) == "exit 2"
    sizes = []

    def surface(size):
        sizes.append(size)
        raise Handed

    monkeypatch.setitem(surfaces.SURFACES, "dunes", surface)
    assert outcome(ex.main, ["-o", out, "--surface", "dunes", "--size", str(surfaces.MAX_SURFACE_SIZE)]) == "Handed"
    assert sizes == [surfaces.MAX_SURFACE_SIZE]
    assert outcome(ex.main, ["-o", out, "--surface", "dunes", "--size", str(surfaces.MAX_SURFACE_SIZE + 1)]) == "exit 2"


def test_gmm_mipmap_example_small_size_takes_the_coarsest_2x2_level_and_block(tmp_path, monkeypatch):
    """--help: level 'default 3, or the coarsest level of at least 2x2 texels where --size has fewer levels', texel
    'default 1 1, or 0 0 where the level has only 2x2 texels'.  At --size 8 the levels are 8, 4, 2, 1 texels
    across: level 2, block 0 0, and the filtered mixture is fetched at the block's centre corner, finest texel
    (4, 4), level 2."""
    import warpbw.filtering as filtering

    ex = load_example("gmm_mipmap")
    got = capture_call(monkeypatch, filtering, "fetch_gmm")
    import matplotlib.pyplot as plt

    open_before = plt.get_fignums()
    res = outcome(ex.main, ["-o", str(tmp_path / "g.png"), "--surface", "dunes", "--size", "8", "--components", "1"])
    assert res == "Handed", res
    assert got["_args"][1:4] == (4, 4, 2.0), got["_args"][1:4]
    assert plt.get_fignums() == open_before   # a stopped figure is closed too (each stayed open in pyplot)


def test_gmm_mipmap_example_builds_both_mipmaps_and_filters_at_the_block_corner(tmp_path, monkeypatch):
    """--level 1 --texel 0 2 at --size 16: texels of 2x2 finest ones, the block's rows 0-1 and columns 2-3, so
    the corner they share is at column s = 6 and row t = 2 (finest texels; s along the width), level 1; the truth
    panel holds the block's 4 x 2^2 = 16 finest normals; one mipmap aligned and one unaligned, both with
    --components."""
    import precompute.gmm_mipmap as gm
    import warpbw.filtering as filtering

    ex = load_example("gmm_mipmap")
    builds, truths = [], []
    real_build, real_truth = gm.build_gmm_mipmap, ex.truth_density
    monkeypatch.setattr(gm, "build_gmm_mipmap", lambda h, **k: builds.append(k) or real_build(h, **k))
    monkeypatch.setattr(ex, "truth_density", lambda n2, *a: truths.append(len(n2)) or real_truth(n2, *a))
    got = capture_call(monkeypatch, filtering, "fetch_gmm")
    res = outcome(ex.main, ["-o", str(tmp_path / "g.png"), "--surface", "dunes", "--size", "16", "--components", "1",
                            "--level", "1", "--texel", "0", "2"])
    assert res == "Handed", res
    assert got["_args"][1:4] == (6, 2, 1.0), got["_args"][1:4]
    assert truths == [16]
    assert sorted(bool(k.get("unaligned", False)) for k in builds) == [False, True], builds
    assert [k.get("components") for k in builds] == [1, 1], builds


def test_gmm_mipmap_example_weighs_a_block_the_border_clips_equally_and_its_truth_a_quarter_per_texel(tmp_path,
                                                                                                      monkeypatch):
    """The docstring: the filtered mixture is fetched where the four texels weigh equally, and the truth is the four
    texels' finest normals together.  At --size 20 level 3 has 3 texels of 8 finest ones, the last clipped to 4
    (finest 16-19): texel 1's centre is at 12, texel 2's at 18 (``axis_base``: the clipped centre), so the equal
    weights are at s = t = 15, not at the corner 16 (weights 1/3, 2/3 there); and the block from (1, 1) holds
    64 + 32 + 32 + 16 normals, each texel's a quarter: 1/256, 1/128 and 1/64 per normal (hand counts).  Session 74:
    the corner and equal weights per normal were used."""
    import warpbw.filtering as filtering
    from precompute.gmm_mipmap import level_shapes

    ex = load_example("gmm_mipmap")
    truths = []
    real_truth = ex.truth_density
    monkeypatch.setattr(ex, "truth_density", lambda n2, *a: truths.append((n2, a)) or real_truth(n2, *a))
    real_fetch = filtering.fetch_gmm
    got = capture_call(monkeypatch, filtering, "fetch_gmm")
    res = outcome(ex.main, ["-o", str(tmp_path / "g.png"), "--surface", "dunes", "--size", "20", "--components", "1",
                            "--level", "3", "--texel", "1", "1"])
    assert res == "Handed", res
    s, t, level = got["_args"][1:4]
    assert (s, t, level) == (15.0, 15.0, 3.0), (s, t, level)
    (n2, extra), = truths
    assert len(n2) == 64 + 32 + 32 + 16
    w = extra[0] if extra else np.full(len(n2), 1.0 / len(n2))
    assert sorted(np.unique(np.round(np.asarray(w) * 256, 9)).tolist()) == [1.0, 2.0, 4.0], np.unique(w)
    assert np.sum(np.isclose(w, 1 / 256)) == 64 and np.sum(np.isclose(w, 1 / 64)) == 16
    # the renderer's fetch at that pixel: the mean of the four texels' weights a = 1, 2, 4, 8 is 3.75 (5 at the corner)
    levels = [np.zeros((h, w_, 1, 4)) for h, w_ in level_shapes(20, 20)]
    for q in levels:
        q[..., 0], q[..., 3] = 0.5, 0.01
    for (r, c), a in zip(((1, 1), (1, 2), (2, 1), (2, 2)), (1.0, 2.0, 4.0, 8.0)):
        levels[3][r, c, 0] = (a, 0.0, 0.0, 0.02 * a)
    np.testing.assert_allclose(real_fetch(levels, s, t, level)[0, 0, 0], 3.75, rtol=1e-6)


# ------------------------------------------------------------------------------------------- inputs, outputs and units
# (mutation round 8: each test fails on a plausible mistake the suite let through)


@pytest.mark.filterwarnings("ignore:height field of")   # its 2 x 2 random map holds much texel-to-texel detail
def test_the_builder_takes_every_documented_value_at_the_ends_of_its_ranges():
    """The builder takes the ends of its documented ranges: 16 components (MAX_COMPONENTS; 17 is refused) and prior 0
    (--help: "0 is plain EM")."""
    from precompute.gmm_mipmap import MAX_COMPONENTS, build_gmm_mipmap

    h = np.random.default_rng(0).random((2, 2)) * 0.1
    assert MAX_COMPONENTS == 16
    mip, err = attempt(build_gmm_mipmap, h, components=16, progress=False)
    assert err == "" and mip.levels[0].shape == (2, 2, 16, 4), err
    assert "components 17: expected an integer from 1 to 16" in attempt(build_gmm_mipmap, h, components=17,
                                                                       progress=False)[1]
    mip, err = attempt(build_gmm_mipmap, h, prior=0.0, progress=False)
    assert err == "" and mip.prior == 0.0, err


def test_a_zero_height_scale_is_refused():
    """Scale 0 flattens every normal (a finite number > 0, the builder's own message)"""
    h = np.random.default_rng(0).random((4, 4))
    for s in (0.0, -1.0):
        said = attempt(build_gmm_mipmap, h, scale=s, progress=False)[1]
        assert re.match(r"scale .*: expected a finite number > 0", said), (s, said)


def test_a_normal_map_texel_two_8_bit_steps_below_the_horizon_is_refused(tmp_path):
    """Load_map's docstring: normals more than NORMAL_Z_TOL (one 8-bit step, 2/255) below the tangent plane are an
    error.  (255, 128, 126) decodes to (1, 1/255, -3/255): z = -0.0118 after normalising."""
    enc = np.full((3, 4, 3), 128, np.uint8)
    enc[..., 2] = 255
    enc[1, 2] = [255, 128, 126]
    save_png(tmp_path / "below.png", enc)
    said = attempt(load_map, tmp_path / "below.png", "normal")[1]
    assert "below.png: 1 texels hold normals pointing below the surface (first at row 1, column 2: z = -0.012)" \
        in said, said


def test_the_rebuild_hint_of_a_normal_map_mipmap_is_a_command_the_tool_accepts(tmp_path):
    """A normal-map mipmap built from Python with scale 2 (ignored for normals) must not be told to rebuild with
    --scale, which the command refuses for --kind normal."""
    from precompute.__main__ import cmd_gmm
    from precompute.assetfile import write_asset
    from precompute.gmm_mipmap import GMM_FORMAT, GMM_VERSION

    params = {"kind": "normal", "components": 4, "prior": 1.0, "unaligned": False, "scale": 2.0, "seed": 0}
    write_asset(tmp_path / "m.npz", GMM_FORMAT, GMM_VERSION, "n.png", "h", {}, params)
    args = _rebuild_hint(tmp_path / "m.npz")[1]
    assert args.kind == "normal" and args.scale == 1.0
    args.output = str(tmp_path / "x.npz")
    got = outcome(cmd_gmm, args)
    assert "--scale" not in got, got            # it goes on to read the (missing) map, not refuse --scale


def test_a_written_mipmap_reads_back_with_every_parameter_and_its_source(tmp_path):
    """What the header records (the builder's parameters, the map and its hash) comes back from the file; the renderer
    compares kind, scale and the map's hash with the material's."""
    n = np.zeros((4, 6, 3))
    n[..., 2] = 1.0
    n[1, 2] = [0.6, 0.0, 0.8]
    mip = build_gmm_mipmap(n, kind="normal", components=3, prior=0.5, seed=9, max_samples=64, progress=False)
    write_gmm_mipmap(tmp_path / "n.gmm", mip, "n.exr", "hash-n")
    back = read_gmm_mipmap(tmp_path / "n.gmm")
    assert (back.kind, back.components, back.prior, back.seed, back.max_samples, back.unaligned) == \
        ("normal", 3, 0.5, 9, 64, False)
    assert (back.source, back.source_hash) == ("n.exr", "hash-n")
    h = np.random.default_rng(1).random((5, 5)) * 0.1
    mip = build_gmm_mipmap(h, scale=2.5, unaligned=True, components=2, progress=False)
    write_gmm_mipmap(tmp_path / "h.gmm", mip, "surface:dunes:5", "hash-h")
    back = read_gmm_mipmap(tmp_path / "h.gmm")
    assert (back.kind, back.scale, back.unaligned, back.source) == ("height", 2.5, True, "surface:dunes:5")


def test_a_map_of_exactly_the_largest_size_is_not_refused_for_its_size(tmp_path):
    """MAX_MAP_SIDE x MAX_MAP_SIDE is "at most" the bound; this EXR claims it and holds 4 x 4 texels, so it is read (and
    found truncated), not refused for its size."""
    from precompute.gmm_mipmap import MAX_MAP_SIDE, load_map

    exr_claiming_size(tmp_path / "at.exr", MAX_MAP_SIDE, MAX_MAP_SIDE)
    got = outcome(load_map, tmp_path / "at.exr", "height")
    assert got.startswith("WarpbwError: ") and "expected a map of at most" not in got, got
    exr_claiming_size(tmp_path / "over.exr", MAX_MAP_SIDE, MAX_MAP_SIDE + 1)
    assert "expected a map of at most" in outcome(load_map, tmp_path / "over.exr", "height")


def test_a_height_field_whose_blue_channel_differs_is_refused(tmp_path):
    """load_map's docstring: "an RGB image is accepted only with identical channels"; the blue one counts too."""
    rgb = np.full((4, 5, 3), 100, np.uint8)
    rgb[2, 3, 2] = 101
    save_png(tmp_path / "b.png", rgb)
    said = attempt(load_map, tmp_path / "b.png", "height")[1]
    assert "b.png: RGB image with differing channels given as a height field" in said, said


def test_an_encoded_exr_normal_map_with_a_zero_value_is_decoded(tmp_path):
    """A [0, 1]-encoded texel of n_x = -1 stores 0, which is not negative: the map is still [0, 1]-encoded (most texels,
    the flat (0.5, 0.5, 1), are unit only as decoded)"""
    from warpbw.io.exr import write_exr

    n = np.zeros((3, 4, 3))
    n[..., 2] = 1.0
    n[1, 1] = [-1.0, 0.0, 0.0]
    write_exr(tmp_path / "enc.exr", ((n + 1) / 2).astype(np.float32), channels=["R", "G", "B"])
    np.testing.assert_allclose(load_map(tmp_path / "enc.exr", "normal"), n, atol=1e-6)


@pytest.mark.parametrize("value, where", [(1.02, 0), (1.09, 2), (-0.02, 0), (-0.09, 1)])
def test_a_float_normal_map_overshooting_0_1_by_a_resamplings_few_percent_is_still_decoded(tmp_path, value, where):
    """A [0, 1]-encoded float map whose one texel a bicubic resampling left at 1.02 (or -0.02: a few percent, within
    ``ENCODING_TOL``) was read as raw vectors, the rule being "any value below 0 or above 1.01": every texel about 35
    degrees off, with only a "renormalised" warning.  Decoded, as most of its texels say.  Truth: the normals of a
    sine height field in numpy (central differences, x along +column, y towards row 0), (n + 1) / 2-encoded."""
    from warpbw.io.exr import write_exr

    W = 16
    u = (np.arange(W) + 0.5) / W
    slope = (np.sin(2 * np.pi * (u + 1 / W)) - np.sin(2 * np.pi * (u - 1 / W))) * 0.04 / (2 / W)
    n = np.zeros((W, W, 3))
    n[..., 0], n[..., 2] = -slope[None, :], 1.0
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    enc = (n + 1) / 2
    enc[5, 7, where] = value
    write_exr(tmp_path / "enc.exr", enc.astype(np.float32), channels=["R", "G", "B"])
    with pytest.warns(UserWarning, match=r"enc.exr: 1 of 256 texels are not unit normals as decoded"):
        got = load_map(tmp_path / "enc.exr", "normal")
    ok = np.ones((W, W), bool)
    ok[5, 7] = False
    np.testing.assert_allclose(got[ok], n[ok], atol=1e-6)


def test_a_float_normal_map_unit_neither_as_stored_nor_as_decoded_is_decoded(tmp_path):
    """"holds the vectors themselves when it has a negative value or when MORE of its texels are unit vectors as stored
    than as decoded ..., otherwise it is [0, 1]-encoded too": a tie (none either way) decodes."""
    from warpbw.io.exr import write_exr

    enc = np.broadcast_to([0.5, 0.5, 0.985], (3, 3, 3)).astype(np.float32)    # decodes to (0, 0, 0.97)
    write_exr(tmp_path / "soft.exr", enc, channels=["R", "G", "B"])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        got = load_map(tmp_path / "soft.exr", "normal")
    said = " ".join(str(w.message) for w in caught)
    assert "9 of 9 texels are not unit normals as decoded" in said, said
    np.testing.assert_allclose(got, np.broadcast_to([0.0, 0.0, 1.0], got.shape), atol=1e-6)


def test_a_surface_spec_takes_at_most_a_size():
    """A surface spec is surface:NAME[:SIZE]: anything after the size is refused, as more fields (the dunes, which
    exist, were called "unknown procedural surface")."""
    for spec, fields in (("surface:dunes:20:3", 2), ("surface:dunes:20:", 2), ("surface:dunes:64:3:1", 3)):
        said = attempt(load_source, spec)[1]
        assert f"{spec}: expected surface:NAME[:SIZE], one size at most (got {fields} fields after dunes)" in said, \
            (spec, said)
        assert "unknown" not in said, said


def test_a_surface_without_a_size_is_512_texels_as_help_says():
    """--help "SIZE 1..1024, default 512"; the name recorded is the spec that rebuilds it exactly."""
    h, name, digest = load_source("surface:dunes")
    assert h.shape == (512, 512) and name == "surface:dunes:512"
    h2, _, digest2 = load_source(name)
    assert np.array_equal(h, dunes(512)) and digest == digest2


def test_the_gmm_builder_reports_progress_up_to_its_total_over_refinement_sweeps(monkeypatch):
    """Step(k) reports k of total done (the normals fitted at all levels, per sweep: 16 texels of 1, 4 of 4, 1 of 16
    on a 4x4 map): increasing, never past the total, ending at it."""
    import precompute.progress as pg

    seen = {}

    @contextlib.contextmanager
    def fake(total, desc, unit, enabled=True):
        seen["total"], seen["steps"] = total, []
        yield seen["steps"].append

    monkeypatch.setattr(pg, "progress_callback", fake)
    h = np.random.default_rng(0).random((4, 4)) * 0.1
    for sweeps in (0, 2):
        build_gmm_mipmap(h, components=2, refine_sweeps=sweeps, progress=False)
        steps = seen["steps"]
        assert steps == sorted(set(steps)) and steps[-1] == seen["total"] == (16 + 4 * 4 + 16) * (1 + sweeps), seen


def test_gmm_refuses_options_its_help_says_do_not_apply(tmp_path, monkeypatch, capsys):
    """--scale "--kind height only"; --prior "not with --unaligned"."""
    import precompute.gmm_mipmap as gm

    capture_call(monkeypatch, gm, "build_gmm_mipmap")
    n = np.zeros((4, 4, 3), np.uint8)
    n[..., :2], n[..., 2] = 128, 255
    save_png(tmp_path / "n.png", n)
    got = outcome(cli, ["gmm", tmp_path / "n.png", "--kind", "normal", "--scale", "2", "-o", tmp_path / "a.npz", "-q"])
    assert got == "returned 2" and "--scale 2: applies to --kind height only" in capsys.readouterr().err, got
    got = outcome(cli, ["gmm", "surface:dunes:20", "--unaligned", "--prior", "3", "-o", tmp_path / "b.npz", "-q"])
    err = capsys.readouterr().err
    assert got == "returned 2" and "--prior 3: the unaligned baseline (--unaligned) has no alignment prior" in err, got


def test_gmm_refuses_to_write_over_its_map_before_any_work(tmp_path, monkeypatch, capsys):
    """-o naming the map (through a link) is refused before the fit, whatever --force says."""
    import precompute.gmm_mipmap as gm

    got = capture_call(monkeypatch, gm, "build_gmm_mipmap")
    save_png(tmp_path / "h.png", (np.arange(16).reshape(4, 4) * 4000).astype(np.uint16))
    (tmp_path / "h.gmm").symlink_to(tmp_path / "h.png")
    ran = outcome(cli, ["gmm", tmp_path / "h.png", "-o", tmp_path / "h.gmm", "--force", "-q"])
    assert ran == "returned 2" and got == {}, ran      # "Handed": the fit was started first
    assert "the file it is made from" in capsys.readouterr().err


def test_gmm_prints_what_it_built(tmp_path, capsys):
    """The levels it wrote (level_shapes: 20 -> 10 -> 5 -> 3 -> 2 -> 1, six) and the prior it used."""
    out = tmp_path / "d.gmm"
    assert cli(["gmm", "surface:dunes:20", "-o", out, "--components", "2", "--prior", "0.5", "-q"]) == 0
    printed = capsys.readouterr().out
    assert len(read_gmm_mipmap(out).levels) == 6
    assert "20x20, 6 levels, 2 components, aligned, prior c=0.5," in printed, printed


def test_gmm_prints_the_map_size_as_width_x_height(tmp_path, capsys):
    """The size is printed width x height, as warpbw prints every size (the renderer's refusal of the same mipmap says
    "built from a 8x5 map"): an 8-wide, 5-tall height field reads 8x5 (it read 5x8)."""
    save_png(tmp_path / "h.png", (np.arange(40).reshape(5, 8) * 1000).astype(np.uint16))
    assert cli(["gmm", tmp_path / "h.png", "-o", tmp_path / "h.gmm", "-q"]) == 0
    printed = capsys.readouterr().out
    assert "(GMM mipmap of h.png: 8x5, " in printed, printed
    assert outcome(level_shapes, 0, 5).startswith("WarpbwError: map size 5x0 (width x height)")   # h = 0, w = 5


def test_gmm_names_the_option_a_bad_scale_came_from(tmp_path, capsys):
    """The builder's "scale ..." is the command's --scale (the parser now says so itself, before the builder)."""
    with pytest.raises(SystemExit) as stop:   # a usage error: argparse exits with status 2
        cli(["gmm", "surface:dunes:20", "--scale", "0", "-o", tmp_path / "d.gmm", "-q"])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and "error: argument --scale: expected a finite number > 0, got 0" in err, err


def test_gmm_quiet_shows_no_progress_bar(tmp_path, capsys):
    """-q, --quiet "no progress bar" (the bar is drawn on stderr)"""
    assert cli(["gmm", "surface:dunes:20", "-o", tmp_path / "d.gmm", "-q"]) == 0
    assert capsys.readouterr().err == ""
    assert cli(["gmm", "surface:dunes:20", "-o", tmp_path / "e.gmm"]) == 0
    assert "GMM mipmap" in capsys.readouterr().err          # without -q there is one (the check can fail)


@pytest.mark.parametrize("unaligned", [False, True])
def test_gmm_progress_counts_normals_fitted_batch_by_batch(monkeypatch, unaligned):
    """The bar counts the normals fitted as their batches finish (it moved once per level): strictly increasing,
    ending at the texels of all levels of the mipmap built times the normals each fits, min(4^l, 256) at level l.  It
    counted texels, though the finest level's three quarters of them fit one normal each: a 1024^2 build spent 4% of
    its time there and 87% at levels 1-4, and its bar stood at 25% at 96% of the time (session 79)."""
    import precompute.gmm_mipmap as gm
    import precompute.progress as pg

    seen = []

    @contextlib.contextmanager
    def recording(total, desc, unit, enabled=True):
        seen.append(("total", total, unit))
        yield lambda k, total=None: seen.append(k)

    monkeypatch.setattr(pg, "progress_callback", recording)
    monkeypatch.setattr(gm, "BATCH_ELEMENTS", 3 * 2)   # finest level: 3 texels of 1 normal and K = 2 per batch
    mip = gm.build_gmm_mipmap(np.random.default_rng(1).random((13, 11)) * 0.2, components=2, unaligned=unaligned)
    normals = sum(lv.shape[0] * lv.shape[1] * min(4 ** l, 256) for l, lv in enumerate(mip.levels))
    assert seen[0] == ("total", normals, "sample")
    steps = seen[1:]
    assert steps[-1] == normals and all(b > a for a, b in zip(steps, steps[1:]))
    assert len(steps) > len(mip.levels) + 40   # 143 finest texels in batches of at most 3


def test_kmeans_init_variance_is_per_axis_of_clusters_of_known_spread():
    """Samples of two isotropic Gaussians of known sigma: the initial s^2 is sigma^2 per axis (not the total 2 sigma^2)."""
    rng = np.random.default_rng(3)
    sigma = np.array([0.03, 0.06])
    centres = np.array([[-0.4, 0.1], [0.35, -0.2]])
    lab = np.repeat([0, 1], 4000)
    x = centres[lab] + rng.normal(size=(8000, 2)) * sigma[lab, None]
    a, mu, s2 = kmeans_init(x[None], centres[None])
    assert np.allclose(a[0], [0.5, 0.5], atol=1e-3)
    assert np.allclose(mu[0], centres, atol=5e-3)
    assert np.allclose(s2[0], sigma ** 2, rtol=0.1)


def test_kmeans_init_gives_an_empty_cluster_the_texels_variance_per_axis():
    """Samples of one isotropic Gaussian of known sigma, and a second centre far from all of them: that empty cluster
    starts with weight 0, its own centre and s^2 = sigma^2 (the texel's variance per axis, not 2 sigma^2)."""
    rng = np.random.default_rng(9)
    sigma = 0.05
    x = np.array([0.2, -0.1]) + sigma * rng.normal(size=(6000, 2))
    centres = np.array([[0.2, -0.1], [0.9, 0.9]])
    a, mu, s2 = kmeans_init(x[None], centres[None])
    assert a[0, 1] == 0.0 and np.array_equal(mu[0, 1], centres[1])
    assert np.allclose(s2[0], sigma ** 2, rtol=0.1), s2


def test_footprint_jitter_is_uniform_over_each_cell_not_on_its_diagonal():
    """Jittered stratified sampling draws a uniform point in each grid cell: row and column offsets independent."""
    H = W = 128
    rr, cc = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
    n2 = np.stack([rr, cc], -1).astype(np.float64)      # each normal codes its own position
    smp = footprint_samples(n2, 6, max_samples=256, rng=7)   # f = 64 texels, 16 x 16 cells of 4 x 4 texels
    dr = smp[..., 0].astype(int) % 4
    dc = smp[..., 1].astype(int) % 4
    counts = np.bincount((dr * 4 + dc).ravel(), minlength=16)
    assert counts.size == 16 and counts.min() > 0.5 * counts.mean(), counts
    assert abs(np.mean(dr == dc) - 0.25) < 0.06


@pytest.mark.parametrize("iterations", [0, 1, 2])
def test_kmeans_init_runs_exactly_the_lloyd_iterations_asked_for(iterations):
    """``iterations`` Lloyd steps (assign each sample to its nearest centre, move each centre to its samples' mean),
    worked out by hand on 1D points: 0 steps keep the given centres (the shares and spreads are those of the nearest-
    centre assignment about them); 0 was accepted and ran one step, the same as 1."""
    x = np.array([[[0.0, 0.0], [0.4, 0.0], [0.6, 0.0], [1.0, 0.0]]])
    centres = np.array([[[0.1, 0.0], [0.9, 0.0]]])
    # step 0: {0, 0.4} and {0.6, 1} around 0.1 and 0.9; step 1: centres 0.2 and 0.8, the same clusters (converged)
    want_mu = [0.1, 0.9] if iterations == 0 else [0.2, 0.8]
    spread = [0.1 ** 2 + 0.3 ** 2] * 2 if iterations == 0 else [0.2 ** 2 * 2] * 2   # sum |x - mu|^2 per cluster
    a, mu, s2 = kmeans_init(x, centres, iterations=iterations)
    np.testing.assert_allclose(mu[0, :, 0], want_mu, atol=1e-15)
    np.testing.assert_allclose(a[0], [0.5, 0.5], atol=1e-15)
    np.testing.assert_allclose(s2[0], np.array(spread) / (2 * 2), rtol=1e-12)   # / (d * cluster size)


def _one_texel(a, mu, e2):
    """A 1 x 1 level of K components from weights a (K,), means mu (K, 2) and E|n|^2 e2 (K,), as moments
    (a, a mu_x, a mu_y, a E|n|^2): written out here, not with the module's converter."""
    a, mu, e2 = np.asarray(a, float), np.asarray(mu, float), np.asarray(e2, float)
    return [np.stack([a, a * mu[:, 0], a * mu[:, 1], a * e2], axis=-1)[None, None].astype(np.float32)]


@pytest.mark.parametrize("a, mu, e2, said", [
    ([0.5, 0.4], [[0.1, 0.0], [0.0, 0.2]], [0.1, 0.1], "weights sum to 0.9"),            # below 1 by 0.1
    ([0.5, 0.5], [[0.1, 0.0], [0.0, 0.2]], [1.01, 0.1], "beyond the unit disk"),         # E|n|^2 > 1 by 1%
    ([0.5, 0.5], [[0.6, 0.0], [0.0, 0.2]], [0.30, 0.1], "negative variances"),           # E|n|^2 < |mu|^2 = 0.36
    ([-0.01, 1.01], [[0.0, 0.0], [0.0, 0.2]], [0.0, 0.1], "negative weights"),           # a weight of -0.01
])
def test_mipmap_problem_finds_each_damage_by_its_own_bound(a, mu, e2, said):
    """Round 11: ``mipmap_problem`` refuses weights that sum to other than 1 (either side), a second moment beyond
    the unit disk of projected normals, one below the squared mean (a negative variance, at a weight under 1, where
    the moments carry a), and a negative weight, each at its tolerance (``WEIGHT_SUM_TOL``, ``MOMENT_TOL``).  Truth:
    the moments written out for components whose damage is set by hand, beside the same texel undamaged."""
    from precompute.gmm_mipmap import mipmap_problem

    assert mipmap_problem(_one_texel([0.5, 0.5], [[0.1, 0.0], [0.0, 0.2]], [0.1, 0.1]), 2, 0.0, 1.0) is None
    problem = mipmap_problem(_one_texel(a, mu, e2), 2, 0.0, 1.0)
    assert problem is not None and said in problem, problem


def test_a_prior_beyond_the_command_lines_bound_is_refused_and_left_out_of_a_rebuild_hint():
    """Round 11: the prior is held to what ``warpbw-precompute gmm --prior`` takes, 0 to ``MAX_PRIOR`` (1e6): a file
    recording 1e7 is refused by ``mipmap_problem``, and ``rebuild_command`` leaves it out (the default rebuilds)."""
    from precompute.gmm_mipmap import MAX_PRIOR, mipmap_problem, rebuild_command

    level = _one_texel([1.0], [[0.1, 0.0]], [0.1])
    assert mipmap_problem(level, 1, MAX_PRIOR, 1.0) is None
    assert "prior 10000000.0 (expected 0 to 1e+06)" in mipmap_problem(level, 1, 1e7, 1.0)
    assert "--prior 1000000.0" in rebuild_command("bumps.png", {"prior": MAX_PRIOR})
    assert "--prior" not in rebuild_command("bumps.png", {"prior": 1e7})


def test_weighted_kmeans_is_unweighted_kmeans_of_the_samples_repeated_by_their_weights():
    """Round 11: the builder weighs a clipped footprint's samples (``_footprint_weights``, mean 1 per texel).  Truth:
    a sample of weight 2 is that sample twice, and one of weight 0 none: ``_kmeans_init`` with weights (2, 0, 1, 1,
    2, 0) gives what it gives for the six samples (x0, x0, x2, x3, x4, x4) unweighted, fractions, centres and
    spreads, with a centre that no sample is nearest (its spread is then the texel's variance, weighted).  And
    k-means++ never seeds a centre at a sample of weight 0 (400 seeds)."""
    from precompute.gmm_mipmap import _kmeans_init, _kmeans_plus_plus

    x = np.array([[[0.0, 0.0], [0.3, 0.1], [0.1, 0.05], [0.5, 0.5], [0.6, 0.4], [-0.4, 0.2]]])
    w = np.array([[2.0, 0.0, 1.0, 1.0, 2.0, 0.0]])
    dup = x[:, [0, 0, 2, 3, 4, 4]]
    centres = np.array([[[0.0, 0.0], [0.55, 0.45], [5.0, 5.0]]])
    for it in (0, 3):
        got, want = _kmeans_init(x, centres, it, w=w), _kmeans_init(dup, centres, it)
        for g, e in zip(got, want):
            np.testing.assert_allclose(g, e, rtol=1e-12, atol=1e-15)
    rng = np.random.default_rng(3)
    for _ in range(400):
        c = _kmeans_plus_plus(x, 3, rng, w)
        hits = np.all(np.isclose(c[0][:, None, :], x[0][None, [1, 5], :]), axis=-1)
        assert not hits.any(), c


def test_a_build_larger_than_the_memory_left_warns_before_the_fit(tmp_path, capsys, monkeypatch):
    """A build takes about BUILD_BYTES_PER_TEXEL_COMPONENT bytes per texel and component at the peak (session 79:
    172 / 717 / 1396 per texel at 1 / 4 / 8 components, peak RSS at 512^2; a 8192^2 map, the largest read, at 4
    components: 48 GB and hours), and nothing said so: the system stops such a process without a word.  Now a build
    whose estimate passes the memory available warns first, naming the map's size and components, as a frame and a
    probe do; one that fits, or where the memory available is unknown, says nothing.  The memory available is set by
    hand around a 16x8 map's estimate; the command line says it in one line before the fit."""
    import precompute.gmm_mipmap as gm

    h = np.random.default_rng(2).random((8, 16)) * 0.1
    need = gm.build_memory(8, 16, 3)
    assert need == gm.BUILD_BYTES_PER_TEXEL_COMPONENT * 3 * 8 * 16 and gm.build_memory(8192, 8192, 4) > 40e9
    fitted = []
    real_fit = gm._em_fit
    monkeypatch.setattr(gm, "_em_fit", lambda *a, **k: fitted.append(1) or real_fit(*a, **k))
    monkeypatch.setattr(gm, "available_memory", lambda: need - 1)
    with pytest.warns(RuntimeWarning, match=r"^building the GMM mipmap of a 16x8 map \(3 components\) takes about "
                                            r"0\.0 GB, but 0\.0 GB of memory is available: the system may stop it "
                                            r"\(a smaller map, or fewer components\)$") as said:
        gm.build_gmm_mipmap(h, components=3, progress=False, unaligned=True)
    assert len(said) == 1 and fitted
    for have in (need, None):
        monkeypatch.setattr(gm, "available_memory", lambda have=have: have)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            gm.build_gmm_mipmap(h, components=3, progress=False, unaligned=True)
    from warpbw.io.exr import write_exr

    write_exr(tmp_path / "h.exr", h.astype(np.float32))
    monkeypatch.setattr(gm, "available_memory", lambda: 1000)

    def stop(*a, **k):
        raise WarpbwError("the fit began")

    monkeypatch.setattr(gm, "_em_fit", stop)
    with warnings.catch_warnings():
        warnings.simplefilter("always")   # the test run's filters ignore this warning (pyproject.toml: the machine's)
        assert cli(["gmm", tmp_path / "h.exr", "-o", tmp_path / "h.gmm.npz", "--unaligned", "--quiet"]) == 2
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 2 and lines[1].endswith("the fit began"), lines
    assert lines[0].startswith("warpbw-precompute: warning: building the GMM mipmap of a 16x8 map (4 components) "
                               "takes about 0.0 GB, but 0.0 GB of memory is available"), lines
