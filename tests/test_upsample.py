"""Bilateral up-sampling (002 Sec. 3.2): constants are preserved, depth edges do not bleed, invalid parents
are ignored, weights follow the closed form, grazing pixels narrow the kernel along the normal; the normal
fit follows shading that is a function of the normal on a bumpy surface, where the weighted mean blurs it."""
from __future__ import annotations

import functools
import math

import numpy as np
import pytest
import warp as wp
from hypothesis import given, settings, strategies as st

from warpbw.errors import WarpbwError
from warpbw.gbuffer import GBufferData, MeshSpec, SphereSpec, build_geometry, make_camera, render_gbuffer
from warpbw.upsample import (UPSAMPLE_DEFAULT, UPSAMPLE_MODES, anisotropic_gaussian, level_size, parent_weights,
                             representative_pixel, top_level, upsample_level)

MODES = pytest.mark.parametrize("mode", UPSAMPLE_MODES)

# The weights' constants as warpbw.upsample documents them, not read from the module (a closed form that takes the
# module's own constant passes whatever value it holds):
G_A_UNIT = 4.0          # module docstring: "G_A_UNIT = 4 level-L pixels (two parent spacings)"
COS_X_MIN = 0.05        # module docstring: at a silhouette (cos theta_x = 0.05) the parent 1.5 pixels away along the
                        # normal keeps exp(-56) of its weight: (1.5 / G_A_UNIT / 0.05)^2 = 56.25
DEPTH_SIGMA_REL = 0.1   # module docstring (the normal fit): a far parent 21% deeper keeps exp(-(0.21 / 0.1)^2) = 1.2%
                        # of its weight under g_z(dz) = exp(-(dz / (DEPTH_SIGMA_REL z))^2)


def gbuffer(spheres, w=48, h=40, pos=(0.0, 0.0, 5.0)):
    cam = make_camera(pos, (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 40.0, w, h)
    gb = render_gbuffer(cam, build_geometry(spheres, []))
    return gb, cam


def parent_valid_from_coverage(gb, level):
    """1 for parent pixels whose representative finest pixel is covered (what the pyramid would compute)."""
    pw, ph = level_size(gb.width, gb.height, level)
    s = 1 << level
    xs = np.minimum(np.arange(pw) * s + s // 2, gb.width - 1)
    ys = np.minimum(np.arange(ph) * s + s // 2, gb.height - 1)
    cov = gb.coverage[np.ix_(ys, xs)]
    mat = gb.numpy("material")[np.ix_(ys, xs)]
    return cov.astype(np.int32).reshape(-1), mat.reshape(-1)


def test_level_sizes_ceil_halve():
    assert level_size(7, 5, 0) == (7, 5)
    assert level_size(7, 5, 1) == (4, 3)
    assert level_size(7, 5, 2) == (2, 2)
    assert level_size(7, 5, 5) == (1, 1)


@MODES
def test_constant_image_upsamples_to_itself(mode):
    gb, cam = gbuffer([SphereSpec((0, 0, 0), 1.2, 0)])
    for level in (0, 1, 2):
        valid, _ = parent_valid_from_coverage(gb, level + 1)
        c = np.array([0.25, 0.5, 2.0], np.float32)
        parents = np.tile(c, (len(valid), 1))
        w, h = level_size(gb.width, gb.height, level)
        r = upsample_level(gb.data, cam, level, parents, valid, np.ones(w * h), mode=mode)
        ok = r.valid.numpy() == 1
        assert ok.sum() > 0.5 * valid.sum()
        assert np.allclose(r.values.numpy()[ok], c, rtol=1e-6)


@MODES
def test_depth_edge_does_not_bleed(mode):
    # a near sphere partly in front of a far one: values A (near) and B (far) must not mix
    gb, cam = gbuffer([SphereSpec((-0.4, 0, 1.5), 0.8, 0), SphereSpec((0.6, 0, -3.0), 1.6, 1)], w=64, h=48)
    valid, mat = parent_valid_from_coverage(gb, 1)
    A, B = np.array([1.0, 0, 0], np.float32), np.array([0, 0, 10.0], np.float32)
    parents = np.where((mat == 0)[:, None], A, B).astype(np.float32)
    r = upsample_level(gb.data, cam, 0, parents, valid, np.ones(gb.width * gb.height), mode=mode)
    vals = r.values.numpy().reshape(gb.height, gb.width, 3)
    ok = r.valid.numpy().reshape(gb.height, gb.width) == 1
    own = gb.numpy("material")
    near, far = ok & (own == 0), ok & (own == 1)
    assert near.sum() > 100 and far.sum() > 100
    # bleed from the other object, as a fraction of the difference between the two values
    assert np.abs(vals[near] - A).max() < 1e-3 * 10.0
    assert np.abs(vals[far] - B).max() < 1e-3 * 10.0
    # pixels with no parent at their depth are left to be shaded, never guessed
    needs = r.needs_shading.numpy().reshape(gb.height, gb.width) == 1
    assert not (needs & ok).any()


@MODES
def test_invalid_parents_are_ignored(mode):
    gb, cam = gbuffer([SphereSpec((0, 0, 0), 1.2, 0)])
    valid, _ = parent_valid_from_coverage(gb, 1)
    rng = np.random.default_rng(0)
    poisoned = valid.copy()
    poisoned[rng.random(len(valid)) < 0.3] = 0
    parents = np.tile(np.float32([1.0, 1.0, 1.0]), (len(valid), 1))
    parents[poisoned == 0] = np.nan
    r = upsample_level(gb.data, cam, 0, parents, poisoned, np.ones(gb.width * gb.height), mode=mode)
    ok = r.valid.numpy() == 1
    assert np.isfinite(r.values.numpy()[ok]).all()
    assert np.allclose(r.values.numpy()[ok], 1.0)
    assert (r.needs_shading.numpy() == 1).sum() + ok.sum() >= 0.9 * gb.coverage.sum()


@MODES
def test_a_non_finite_valid_parent_propagates_to_the_pixels_that_weigh_it(mode):
    """The docstring's promise: a valid parent holding NaN or inf is not replaced by a guess; the pixels that give it
    weight come out non-finite, and the pixels that do not (each level-0 pixel weighs only its four nearest
    parents) keep their finite values."""
    gb, cam = gbuffer([SphereSpec((0, 0, 0), 1.2, 0)])
    valid, _ = parent_valid_from_coverage(gb, 1)
    todo = np.ones(gb.width * gb.height)
    k = int(np.flatnonzero(valid)[len(np.flatnonzero(valid)) // 2])   # a valid parent inside the sphere

    def upsample(value, how):
        parents = np.tile(np.float32([1.0, 1.0, 1.0]), (len(valid), 1))
        parents[k] = value
        return upsample_level(gb.data, cam, 0, parents, valid, todo, mode=how)

    # the pixels that weigh parent k: those whose weighted mean moves when it does (the weights are the modes')
    moved = upsample(2.0, "paper")
    weighs_k = (moved.valid.numpy() == 1) & np.any(moved.values.numpy() != 1.0, axis=1)
    # each level-0 pixel weighs its four nearest parents, so parent (px, py), centred on level-0 coordinate
    # 2 p + 1, is weighed by the 4 x 4 pixels 2 p - 1 .. 2 p + 2 on each axis (inside the sphere: no edge cuts it)
    pw = level_size(gb.width, gb.height, 1)[0]
    px, py = k % pw, k // pw
    block = np.zeros((gb.height, gb.width), bool)
    block[2 * py - 1:2 * py + 3, 2 * px - 1:2 * px + 3] = True
    np.testing.assert_array_equal(weighs_k, block.ravel())
    for bad in (np.nan, np.inf):
        r = upsample(bad, mode)
        ok = r.valid.numpy() == 1
        finite = np.isfinite(r.values.numpy()).all(axis=1)
        np.testing.assert_array_equal(ok & ~finite, weighs_k, err_msg=str(bad))
        assert np.allclose(r.values.numpy()[ok & finite], 1.0)


def _parents(x: int, y: int, pw: int, ph: int) -> list:
    """Per parent k (002 Sec. 3.2) of pixel (x, y), at the next level of pw x ph pixels: its index (px, py), its
    bilinear weight alpha_k, and v, its centre's offset from the pixel's in units of G_A_UNIT; the parents stop
    at the last row and column, as the kernel's do."""
    u = (np.array([x, y]) + 0.5) * 0.5 - 0.5
    i0 = np.clip(np.floor(u).astype(int), 0, [pw - 1, ph - 1])
    f = np.where(np.floor(u) < 0, 0.0, u - np.floor(u))
    out = []
    for k in range(4):
        px, py = min(i0[0] + k % 2, pw - 1), min(i0[1] + k // 2, ph - 1)
        alpha = ((1 - f[0]) if k % 2 == 0 else f[0]) * ((1 - f[1]) if k < 2 else f[1])
        out.append((px, py, alpha, np.array([2 * px + 1 - (x + 0.5), 2 * py + 1 - (y + 0.5)]) / G_A_UNIT))
    return out


def test_weights_follow_the_closed_form_on_a_frontal_surface():
    # the centre of a big sphere faces the camera: cos theta_x ~ 1, M ~ I, g_z ~ 1
    gb, cam = gbuffer([SphereSpec((0, 0, 0), 3.0, 0)], w=32, h=32, pos=(0.0, 0.0, 8.0))
    wts = parent_weights(gb.data, cam, 0)
    for x, y in ((16, 16), (15, 16), (16, 15), (15, 15)):
        expect = [alpha * np.exp(-(v @ v)) for _, _, alpha, v in _parents(x, y, 16, 16)]
        # a sphere is not a plane: cos theta_x and depth vary slightly over 1.5 pixels (1% on the far parent)
        assert np.allclose(wts[y, x], expect, rtol=1e-2, atol=1e-6)


def test_grazing_narrows_the_kernel_along_the_projected_normal():
    @wp.kernel(enable_backward=False)
    def ga(vs: wp.array(dtype=wp.vec2), n: wp.vec2, c: float, out: wp.array(dtype=float)):
        t = wp.tid()
        out[t] = anisotropic_gaussian(vs[t], n, c)

    # offsets of one unit across the projected normal and of 2 COS_X_MIN along it: the exponent along it,
    # (2 COS_X_MIN / max(c, COS_X_MIN))^2, stays of order 1 down to the clamp, which it then pins to 1/4
    vs = wp.array(np.array([[2 * COS_X_MIN, 0.0], [0.0, 1.0]], np.float32), dtype=wp.vec2)
    out = wp.zeros(2, dtype=float)
    for c in (1.0, 0.5, 0.1, 0.05, 0.01, 0.0):
        wp.launch(ga, 2, inputs=[vs, wp.vec2(1.0, 0.0), c, out])
        along, across = out.numpy()
        assert np.isclose(across, np.exp(-1.0), rtol=1e-6)
        assert np.isclose(along, np.exp(-(2 * COS_X_MIN / max(c, COS_X_MIN)) ** 2), rtol=1e-5), c
    assert np.isclose(along, np.exp(-4.0), rtol=1e-5)     # c = 0: the clamp itself


@MODES
def test_odd_sizes_and_tiny_images_run(mode):
    n_done = 0
    for w, h in ((7, 5), (1, 1), (3, 1)):
        gb, cam = gbuffer([SphereSpec((0, 0, 0), 1.5, 0)], w=w, h=h)
        for level in range(min(3, top_level(w, h) + 1)):   # up to the 1 x 1 top (upsample_level's last level)
            lw, lh = level_size(w, h, level)
            valid, _ = parent_valid_from_coverage(gb, level + 1)
            r = upsample_level(gb.data, cam, level, np.ones((len(valid), 3)), valid, np.ones(lw * lh), mode=mode)
            assert np.isfinite(r.values.numpy()).all()
            # every parent is 1: an up-sampled texel is 1 (a weighted mean, or a fit through equal values)
            done = r.valid.numpy().astype(bool)
            assert np.allclose(r.values.numpy()[done], 1.0, rtol=1e-5), (w, h, level)
            n_done += int(done.sum())
    assert n_done > 0


@functools.cache   # read-only: shared by the tests below
def bumpy_gbuffer(size=64, period=0.8, amplitude=0.1, n=161):
    """A height field z = a sin(k x) sin(k y) over [-1.5, 1.5]^2 seen from above, with analytic vertex normals:
    about 14 pixels per period, normals tilted by up to 38 degrees."""
    xs = np.linspace(-1.5, 1.5, n)
    X, Y = np.meshgrid(xs, xs)
    k = 2 * np.pi / period
    Z = amplitude * np.sin(k * X) * np.sin(k * Y)
    dzdx = amplitude * k * np.cos(k * X) * np.sin(k * Y)
    dzdy = amplitude * k * np.sin(k * X) * np.cos(k * Y)
    nrm = np.stack([-dzdx, -dzdy, np.ones_like(Z)], -1)
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    v = np.stack([X, Y, Z], -1).reshape(-1, 3)
    i = np.arange(n * n).reshape(n, n)
    a, b, c, d = i[:-1, :-1].ravel(), i[:-1, 1:].ravel(), i[1:, :-1].ravel(), i[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])
    mesh = MeshSpec(v.astype(np.float32), faces.astype(np.int32), nrm.reshape(-1, 3).astype(np.float32),
                    np.zeros(n * n, np.float32), None, 0)
    cam = make_camera((0.0, 0.0, 4.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 40.0, size, size)
    return render_gbuffer(cam, build_geometry([], [mesh])), cam


@wp.kernel(enable_backward=False)
def _representatives(gb: GBufferData, width: int, level: int, out: wp.array(dtype=wp.int32)):
    t = wp.tid()
    out[t] = representative_pixel(gb, t % width, t // width, level)


def representatives(gb, level):
    w, h = level_size(gb.width, gb.height, level)
    out = wp.zeros(w * h, dtype=wp.int32)
    wp.launch(_representatives, w * h, inputs=[gb.data, w, level, out])
    return out.numpy()


def upsampling_error(shade, mode):
    """RMS error, over the up-sampled level-0 pixels of the bumpy surface, of up-sampling L = shade(n) from
    the level-1 texels (each holding L at its representative pixel's normal) against L at each pixel's own
    normal (the truth, in closed form)."""
    gb, cam = bumpy_gbuffer()
    normals = gb.numpy("normal").reshape(-1, 3)
    parents = shade(normals[representatives(gb, 1)]).astype(np.float32)
    valid, _ = parent_valid_from_coverage(gb, 1)
    r = upsample_level(gb.data, cam, 0, parents, valid, np.ones(gb.width * gb.height), mode=mode)
    ok = r.valid.numpy() == 1
    assert ok.sum() > 0.9 * gb.width * gb.height
    truth = shade(normals[representatives(gb, 0)])
    return float(np.sqrt(np.mean((r.values.numpy()[ok] - truth[ok]) ** 2)))


def glossy(n):
    """A highlight that follows the normal: a Gaussian lobe around a tilted direction, on a dim floor."""
    d = np.array([0.3, 0.2, 0.93]) / np.linalg.norm([0.3, 0.2, 0.93])
    lobe = np.exp(-np.sum((n - d) ** 2, axis=-1) / 0.05)
    return 0.1 + lobe[:, None] * np.array([1.0, 0.6, 0.3])


def linear_in_the_normal(n):
    return 1.0 + np.stack([0.5 * n[:, 0], 0.3 * n[:, 1], -0.4 * n[:, 0] + 0.2 * n[:, 1]], -1)


def test_normal_fit_follows_shading_that_follows_the_normal():
    # on bumps a few pixels wide the parents' weighted mean blurs what the normal already says; the truth
    # is the closed-form shading at each pixel's own normal, not anything the up-sampler computes.  Measured:
    # 0.74x and 0.23x the paper's error.  Not exact on the plane: the ridge shrinks the slope where the parents'
    # normals are close, and a pixel on a bump's crest, whose normal lies beyond its parents', is clamped
    for shade, most in ((glossy, 0.85), (linear_in_the_normal, 0.35)):
        paper, normal = upsampling_error(shade, "paper"), upsampling_error(shade, "normal")
        assert paper > 1e-3, shade.__name__   # the surface is bumpy enough for the paper's mean to miss
        assert normal < most * paper, (shade.__name__, normal, paper)


def test_normal_fit_stays_within_its_parents():
    # clamped to the parents' range per channel: no overshoot, no negative radiance, even where the fit's
    # plane would extrapolate (values unrelated to the normals)
    gb, cam = bumpy_gbuffer()
    valid, _ = parent_valid_from_coverage(gb, 1)
    parents = np.random.default_rng(1).exponential(1.0, (len(valid), 3)).astype(np.float32)
    r = upsample_level(gb.data, cam, 0, parents, valid, np.ones(gb.width * gb.height), mode="normal")
    ok = r.valid.numpy() == 1
    x, y = np.divmod(np.flatnonzero(ok), gb.width)[::-1]
    pw, ph = level_size(gb.width, gb.height, 1)
    lo_x, lo_y = np.clip((x - 1) // 2, 0, pw - 1), np.clip((y - 1) // 2, 0, ph - 1)
    hi_x, hi_y = np.minimum(lo_x + 1, pw - 1), np.minimum(lo_y + 1, ph - 1)
    four = parents.reshape(ph, pw, 3)[np.stack([lo_y, lo_y, hi_y, hi_y], 1), np.stack([lo_x, hi_x, lo_x, hi_x], 1)]
    v = r.values.numpy()[ok]
    assert np.all(v >= four.min(1) - 1e-6) and np.all(v <= four.max(1) + 1e-6)


def test_unknown_mode_is_refused_and_the_cli_spells_the_modes():
    from warpbw import cli

    gb, cam = gbuffer([SphereSpec((0, 0, 0), 1.2, 0)], w=8, h=8)
    with pytest.raises(WarpbwError, match="upsample: expected one of normal, paper, got 'bicubic'"):
        upsample_level(gb.data, cam, 0, np.ones((16, 3)), np.ones(16), np.ones(64), mode="bicubic")
    assert set(cli._UPSAMPLE_MODES) == set(UPSAMPLE_MODES) and cli._UPSAMPLE_MODES[0] == UPSAMPLE_DEFAULT


def test_top_level_is_the_one_by_one_level():
    for w, h in ((1, 1), (3, 1), (7, 5), (16, 12), (17, 2)):
        top = top_level(w, h)
        assert level_size(w, h, top) == (1, 1) and (top == 0 or level_size(w, h, top - 1) != (1, 1))


def test_level_size_refuses_what_is_not_a_size_or_a_level():
    """-1 failed on a negative shift (ValueError), 2.7 ran as level 2, a width of 0 or -8 came out as 1, "7" a
    TypeError."""
    for args, what in (((7, 5, -1), "level"), ((7, 5, 2.7), "level"), ((0, 5, 0), "width"), ((-8, 5, 1), "width"),
                       ((7.5, 5, 0), "width"), (("7", 5, 0), "width"), ((7, 0, 0), "height")):
        with pytest.raises(WarpbwError, match=f"^{what}: expected an integer"):
            level_size(*args)
    with pytest.raises(WarpbwError, match="^level: expected an integer >= 0, got -1"):
        parent_weights(gbuffer([SphereSpec((0, 0, 0), 1.2, 0)], w=8, h=8)[0].data, make_camera(
            (0.0, 0.0, 5.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 40.0, 8, 8), -1)


def _level0(w=16, h=12):
    gb, cam = gbuffer([SphereSpec((0, 0, 0), 1.2, 0)], w=w, h=h)
    (w0, h0), (w1, h1) = level_size(w, h, 0), level_size(w, h, 1)
    return gb, cam, w0 * h0, w1 * h1


def test_out_arrays_of_the_wrong_size_are_refused_before_the_launch(monkeypatch):
    """``out`` / ``out_valid`` of 3 texels for a level of 192 were written past their end: the call returned and
    the process aborted later ("double free or corruption").  Checked before anything is launched (the launch is
    replaced by a failure here, so that the old code cannot corrupt this process's heap)."""
    import warpbw.upsample as U

    def no_launch(*a, **k):
        raise AssertionError("launched")
    gb, cam, n, pn = _level0()
    monkeypatch.setattr(U.wp, "launch", no_launch)
    args = (gb.data, cam, 0, np.zeros((pn, 3)), np.ones(pn), np.ones(n))
    for kw, name in (({"out": wp.zeros(3, dtype=wp.vec3)}, "out"), ({"out_valid": wp.zeros(3, dtype=wp.int32)},
                                                                    "out_valid"),
                     ({"out": wp.zeros(n, dtype=wp.vec4)}, "out"), ({"out_valid": wp.zeros(n, dtype=wp.float32)},
                                                                    "out_valid"),
                     ({"out": wp.zeros((n, 1), dtype=wp.vec3)}, "out")):
        with pytest.raises(WarpbwError, match=rf"^{name}: expected a Warp array of {n} .*\(level 0, 16x12\), got"):
            upsample_level(*args, **kw)


def test_inputs_of_the_wrong_size_or_dtype_are_refused():
    """parent_values of 2 texels (48 needed) were read past their end (values up to 1e27), a ``todo`` of 3 ints
    (192 needed) returned without error; a float32 parent array, a GBuffer for its data and weights of the wrong
    size failed in Warp or as a ValueError."""
    gb, cam, n, pn = _level0()
    ok = (np.zeros((pn, 3)), np.ones(pn), np.ones(n))
    cases = [
        ((wp.zeros(2, dtype=wp.vec3), ok[1], ok[2]), {}, rf"^parent_values: expected a Warp array of {pn} vec3f "
                                                         r"\(level 1, 8x6\), got a Warp array of shape \(2,\)"),
        ((wp.zeros(pn * 3, dtype=wp.float32), ok[1], ok[2]), {}, r"^parent_values: .*got a Warp array .* float32"),
        ((np.zeros((5, 3)), ok[1], ok[2]), {}, rf"^parent_values: expected {pn} RGB values"),
        ((ok[0], wp.array(np.ones(2, np.int32)), ok[2]), {}, rf"^parent_valid: expected a Warp array of {pn} int32"),
        ((ok[0], np.ones(5), ok[2]), {}, rf"^parent_valid: expected {pn} flags"),
        ((ok[0], ok[1], wp.array(np.ones(3, np.int32))), {}, rf"^todo: expected a Warp array of {n} int32"),
        ((ok[0], ok[1], wp.array(np.ones(n), dtype=wp.float32)), {}, r"^todo: .*float32"),
        (ok, {"weights": wp.zeros(3, dtype=wp.vec4)}, rf"^weights: expected a Warp array of {n} vec4f"),
    ]
    for (pv, valid, todo), kw, msg in cases:
        with pytest.raises(WarpbwError, match=msg):
            upsample_level(gb.data, cam, 0, pv, valid, todo, **kw)
    with pytest.raises(WarpbwError, match=r"^gb: expected a GBuffer or its GBufferData, got str"):
        upsample_level("gb", cam, 0, *ok)
    with pytest.raises(WarpbwError, match=r"^upsample_level: cam: expected a CameraData"):
        upsample_level(gb.data, None, 0, *ok)


def test_a_gbuffer_is_taken_for_its_data_and_levels_stop_at_the_top():
    gb, cam, n, pn = _level0()
    ok = (np.full((pn, 3), 0.5), np.ones(pn), np.ones(n))
    a, b = upsample_level(gb, cam, 0, *ok), upsample_level(gb.data, cam, 0, *ok)
    assert np.array_equal(a.values.numpy(), b.values.numpy()) and a.valid.numpy().sum() > 0
    assert top_level(16, 12) == 4
    r = upsample_level(gb, cam, 4, np.full((1, 3), 0.5), np.ones(1), np.ones(1))   # the 1 x 1 top
    assert r.values.shape == (1,)
    for level in (5, 99):   # 99 ran: an int32 shifted past its width in the kernel
        with pytest.raises(WarpbwError, match=r"^level \(of a 16x12 G-buffer\): expected an integer from 0 to 4, "
                                              f"got {level}"):
            upsample_level(gb, cam, level, np.zeros((1, 3)), np.ones(1), np.ones(1))


def _paper_weights(x, y, mat, depth, ns, c):
    """002 Sec. 3.2's w_i = g_z g_a alpha_i of pixel (x, y)'s four parents, written out: M narrows the kernel by c
    (cos theta_x, clamped) along the unit screen direction ns; a parent off the object or of no bilinear weight is
    0."""
    H, W = mat.shape
    want = []
    for px, py, alpha, v in _parents(x, y, (W + 1) // 2, (H + 1) // 2):
        qx, qy = min(2 * px + 1, W - 1), min(2 * py + 1, H - 1)
        if mat[qy, qx] < 0 or alpha == 0:
            want.append(0.0)
            continue
        along, across = v @ ns, v @ np.array([-ns[1], ns[0]])
        gz = math.exp(-((depth[y, x] - depth[qy, qx]) / (DEPTH_SIGMA_REL * depth[y, x])) ** 2)
        want.append(alpha * gz * math.exp(-(across ** 2 + along ** 2 / c ** 2)))
    return want


def test_upsampling_weights_narrow_along_the_radial_direction_at_a_spheres_limb():
    """On a sphere centred on the optical axis the projected normal at an image point points away from the
    sphere's image centre (rotational symmetry), and cos theta_x -> 0 at the limb.  The four weights follow
    002 Sec. 3.2's w_i = alpha_i g_z g_a with M built from that radial direction.  (Neither cos_x := 1 nor a flipped
    screen y of the projected normal failed a test before this one.)"""
    W, H = 48, 40
    gb, cam = gbuffer([SphereSpec((0, 0, 0), 1.5, 0)], w=W, h=H)
    wts = parent_weights(gb.data, cam, 0)
    depth = gb.numpy("depth").reshape(H, W)
    nrm = gb.numpy("normal").reshape(H, W, 3)
    view = gb.numpy("view").reshape(H, W, 3)
    mat = gb.numpy("material").reshape(H, W)
    checked = 0
    for y in range(H):
        for x in range(W):
            if mat[y, x] < 0:
                continue
            r = np.array([x + 0.5 - W / 2, y + 0.5 - H / 2])          # image right, down
            cos_x = abs(float(nrm[y, x] @ view[y, x]))
            if np.linalg.norm(r) < 1 or cos_x > 0.6 or min(abs(r[0]), abs(r[1])) < 0.4 * np.linalg.norm(r):
                continue                                               # grazing, diagonal pixels only
            ns = r / np.linalg.norm(r)
            c = max(cos_x, COS_X_MIN)
            want = _paper_weights(x, y, mat, depth, ns, c)
            np.testing.assert_allclose(wts[y, x], want, rtol=2e-3, atol=1e-7, err_msg=str((x, y, cos_x)))
            checked += 1
    assert checked >= 8, checked


def test_upsampling_weights_narrow_along_the_perspective_image_of_the_normal_off_the_optical_axis():
    """002 Sec. 3.2: M narrows the kernel by cos theta_x along the screen-projected normal, the direction along which
    the surface is foreshortened.  Under the pinhole camera (gbuffer.py's model) that is the image of the normal at
    the surface point: with q = p - eye and z = q . forward, d/de of the projection of q + e n is along
    ((n . right) z - (q . right)(n . forward), -((n . up) z - (q . up)(n . forward))) (x right, y down); the tangent
    t = v - (v . n) n in the plane of the normal and the ray v images along it too (v itself images to a point).  On
    a sphere centred on the optical axis that is the radial direction (the test above), as is the normal projected
    along the camera's axes, (n . right, -n . up); on one off the axis, seen with a 90 degree field of view, the two
    differ by up to 26 degrees (median 11) where cos theta_x < 0.5 (/work/s75/scratch_c/nscreen.py).  Truth: the
    perspective image in float64 from the G-buffer's position and normal (the sphere's G-buffer is checked against
    float64 closed forms in tests/test_gbuffer.py)."""
    W, H = 64, 48
    cam = make_camera((0.0, 0.0, 4.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 90.0, W, H)
    gb = render_gbuffer(cam, build_geometry([SphereSpec((1.5, 1.0, 0.0), 1.0, 0)], []))
    wts = parent_weights(gb.data, cam, 0)
    depth = gb.numpy("depth").reshape(H, W)
    pos = gb.numpy("position").reshape(H, W, 3).astype(np.float64)
    nrm = gb.numpy("normal").reshape(H, W, 3).astype(np.float64)
    view = gb.numpy("view").reshape(H, W, 3)
    mat = gb.numpy("material").reshape(H, W)
    eye = np.array([0.0, 0.0, 4.0])
    fwd, right, up = np.array([0.0, 0.0, -1.0]), np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    checked, turned = 0, 0.0
    for y in range(H):
        for x in range(W):
            cos_x = abs(float(nrm[y, x] @ view[y, x]))
            if mat[y, x] < 0 or cos_x > 0.5:
                continue
            q, n = pos[y, x] - eye, nrm[y, x]
            z = q @ fwd
            ns = np.array([(n @ right) * z - (q @ right) * (n @ fwd), -((n @ up) * z - (q @ up) * (n @ fwd))])
            ns /= np.linalg.norm(ns)
            ortho = np.array([n @ right, -(n @ up)]) / np.linalg.norm([n @ right, n @ up])
            turned = max(turned, math.degrees(math.acos(min(1.0, abs(float(ns @ ortho))))))
            c = max(cos_x, COS_X_MIN)
            want = _paper_weights(x, y, mat, depth, ns, c)
            np.testing.assert_allclose(wts[y, x], want, rtol=2e-3, atol=1e-7, err_msg=str((x, y, cos_x)))
            checked += 1
    assert checked >= 40 and turned > 10.0, (checked, turned)


def _quad(x0, x1, y0, y1, z, material, normal=(0.0, 0.0, 1.0)):
    v = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], np.float32)
    f = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    return MeshSpec(v, f, np.tile(np.float32(normal), (4, 1)), np.zeros(4, np.float32), None, material)


@MODES
def test_a_one_pixel_bar_in_front_of_a_wall_has_no_parent_at_its_depth(mode):
    """002 Sec. 3.2 / upsample docstring: a pixel whose weights sum to less than WEIGHT_MIN (no parent at its depth)
    is shaded, never guessed.  A bar one pixel high (row 24, at depth 3) in front of a wall (depth 4.4) has both
    parent rows (23 and 25) on the wall: g_z = exp(-(1.4 / 0.3)^2) = 3e-10 for every parent, so every bar pixel
    needs shading and none takes the wall's value.  (The depth-edge test's steps underflow g_z to 0: a WEIGHT_MIN of
    1e-12 filled this bar from the wall, and no test saw it.)"""
    needs, ok, bar = _bar_in_front_of_a_wall(0.6, mode)
    assert needs[bar].all() and not ok[bar].any()


def _bar_in_front_of_a_wall(wall_z, mode, normal=(0.0, 0.0, 1.0)):
    """Level 0 up-sampled from level 1 over a bar one pixel high (row 24, at z = 2, 3 from the camera) in front of a
    wall at ``wall_z``, both of one material (depth alone separates them): (needs shading, up-sampled, bar pixels)."""
    W, H = 64, 48
    cam = make_camera((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 40.0, W, H)
    ty = math.tan(math.radians(20.0)) * H / W
    bar = _quad(-0.5, 0.5, -0.04 * ty * 3.0, 0.0, 2.0, 0, normal)    # ndc y in [-0.04, 0]: row 24's centre only
    wall = _quad(-5.0, 5.0, -5.0, 5.0, wall_z, 0, normal)
    gb = render_gbuffer(cam, build_geometry([], [bar, wall]))
    depth = gb.numpy("depth").reshape(H, W)
    near = depth < 0.5 * (3.0 + 5.0 - wall_z)
    assert np.array_equal(np.unique(np.nonzero(near)[0]), [24])
    valid, _ = parent_valid_from_coverage(gb, 1)
    pw, ph = level_size(W, H, 1)
    rep = depth[np.minimum(np.arange(ph) * 2 + 1, H - 1)][:, np.minimum(np.arange(pw) * 2 + 1, W - 1)]
    parents = np.where((rep < 0.5 * (3.0 + 5.0 - wall_z)).reshape(-1, 1), [1.0, 0, 0], [0, 0, 10.0])
    r = upsample_level(gb.data, cam, 0, parents.astype(np.float32), valid, np.ones(W * H), mode=mode)
    return r.needs_shading.numpy().reshape(H, W) == 1, r.valid.numpy().reshape(H, W) == 1, near


@MODES
@pytest.mark.parametrize("total,shaded", [(3e-5, True), (3e-4, False)])
def test_weight_min_decides_between_shading_and_up_sampling_a_pixel(mode, total, shaded):
    """WEIGHT_MIN (1e-4) is the total weight below which a pixel is shaded: the bar above, 3 from the camera, before
    a wall 3 (1 + r) away, whose parents all weigh g_z = exp(-(r / DEPTH_SIGMA_REL)^2) times their bilinear alpha and
    g_a (0.955 in all: two parent rows 1.5 and 0.5 pixels off, in units of G_A_UNIT; frontal, so M = I), set to
    ``total``.  A WEIGHT_MIN of 1e-6 or 1e-3 no longer told the two apart (the bar's 3e-10 sat below both)."""
    g_a = 0.25 * math.exp(-(1.5 / G_A_UNIT) ** 2) + 0.75 * math.exp(-(0.5 / G_A_UNIT) ** 2)
    ratio = DEPTH_SIGMA_REL * math.sqrt(math.log(g_a / total))
    needs, ok, bar = _bar_in_front_of_a_wall(5.0 - 3.0 * (1.0 + ratio), mode)
    inner = bar & (np.arange(64) > 20)[None, :] & (np.arange(64) < 44)[None, :]   # away from the bar's ends
    assert inner.sum() >= 20
    if shaded:   # the documented 1e-4 of the upsample docstring, not the module's constant, is the truth here
        assert needs[inner].all() and not ok[inner].any()
    else:
        assert ok[inner].all() and not needs[inner].any()


def test_a_shading_normal_facing_away_from_the_camera_weighs_as_the_one_facing_it():
    """cos theta_x of M is |n . view|: an interpolated normal may face away at a silhouette.  A frontal wall whose
    shading normal is (0, 0, -1) has the frontal closed form alpha exp(-v . v) (without the |.|, M narrowed by
    1 / COS_X_MIN^2 along a screen axis)."""
    W = H = 32
    cam = make_camera((0.0, 0.0, 8.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 30.0, W, H)
    for normal in ((0.0, 0.0, 1.0), (0.0, 0.0, -1.0)):
        gb = render_gbuffer(cam, build_geometry([], [_quad(-9.0, 9.0, -9.0, 9.0, 0.0, 0, normal)]))
        wts = parent_weights(gb.data, cam, 0)
        for x, y in ((16, 16), (15, 16), (16, 15), (15, 15), (9, 20)):
            expect = [alpha * np.exp(-(v @ v)) for _, _, alpha, v in _parents(x, y, 16, 16)]
            # off the axis the view is a little oblique (cos theta_x 0.99 at (9, 20)) and the depth varies
            assert np.allclose(wts[y, x], expect, rtol=1e-2, atol=1e-7), (normal, x, y)


def test_the_default_fit_keeps_a_near_spheres_limb_from_a_sphere_just_behind_it():
    """A sphere 21% nearer than the one behind it (at their overlap the depth step is about 20%): the near sphere's
    parents hold A = (1, 0, 0), the far one's B = (0, 0, 10), so a pixel's blue channel is the share of B it took
    (times 10).  At the near limb g_a leaves the near parents, along the normal, little weight, while g_z leaves a
    far parent 21% deeper exp(-(0.21 / 0.1)^2) = 1.2% of its own: the paper's weighted mean took 73% of B at one
    pixel (module docstring).  The default fit explains the far parent's value by its far-off normal and takes
    the value at the pixel's own normal, which is the near sphere's: at most 1% of B."""
    W, H = 64, 48
    cam = make_camera((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 40.0, W, H)
    gb = render_gbuffer(cam, build_geometry([SphereSpec((-0.4, 0, 0.5), 0.8, 0), SphereSpec((0.6, 0, -1.2), 1.0, 1)],
                                            []))
    own = gb.numpy("material").reshape(H, W)
    valid, mat = parent_valid_from_coverage(gb, 1)
    parents = np.where((mat == 0)[:, None], np.float32([1, 0, 0]), np.float32([0, 0, 10])).astype(np.float32)
    r = upsample_level(gb.data, cam, 0, parents, valid, np.ones(W * H))
    near = (own == 0) & (r.valid.numpy().reshape(H, W) == 1)
    taken = r.values.numpy().reshape(H, W, 3)[near][:, 2] / 10.0
    beside = np.zeros_like(near)   # near pixels with a far-sphere pixel beside them
    for axis in (0, 1):
        for step in (-1, 1):
            beside |= np.roll(own, step, axis) == 1
    assert near.sum() > 500 and (near & beside).sum() >= 5, (near.sum(), (near & beside).sum())
    assert taken.max() <= 0.01, taken.max()


@pytest.mark.parametrize("level", [0, 1])
def test_a_tall_images_rows_upsample_from_the_two_parent_rows_around_them(level):
    """002 Sec. 3.2: a texel takes a weighted mean of its four nearest parents. Parents holding their own row index give
    every texel a value between the two parent rows around its centre, u = (y + 1/2) / 2 - 1/2, and nearer the nearer
    one (bilinear alpha and g_a both favour it), on an image taller than it is wide too."""
    W, H = 8, 48
    cam = make_camera((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 10.0, W, H)
    gb = render_gbuffer(cam, build_geometry([SphereSpec((0, 0, 0), 1.5, 0)], []))
    w, h = level_size(W, H, level)
    pw, ph = level_size(W, H, level + 1)
    s = 1 << (level + 1)
    ys = np.minimum(np.arange(ph) * s + s // 2, H - 1)
    xs = np.minimum(np.arange(pw) * s + s // 2, W - 1)
    valid = gb.coverage[np.ix_(ys, xs)].astype(np.int32).reshape(-1)
    parents = np.repeat(np.arange(ph, dtype=np.float32), pw)[:, None] * np.ones(3, np.float32)
    r = upsample_level(gb.data, cam, level, parents, valid, np.ones(w * h), mode="paper")
    vals = r.values.numpy()[:, 0].reshape(h, w)
    ok = r.valid.numpy().reshape(h, w) == 1
    vmap = valid.reshape(ph, pw)
    checked = 0
    for y in range(h):
        u = (y + 0.5) * 0.5 - 0.5
        j0 = int(math.floor(u))
        f = u - j0
        if j0 < 0 or j0 + 1 > ph - 1:
            continue
        for x in range(w):
            if not ok[y, x] or not vmap[j0:j0 + 2, :].all():
                continue
            checked += 1
            assert j0 - 1e-4 <= vals[y, x] <= j0 + 1 + 1e-4, (x, y, vals[y, x], j0)
            assert (vals[y, x] - j0 - 0.5) * (f - 0.5) > 0, (x, y, vals[y, x], u)
    assert checked > 10 * w // 4


@pytest.mark.parametrize("axis", [0, 1])
def test_a_border_texel_outside_its_parents_centres_takes_the_nearest_parent(axis):
    """002 Sec. 3.2's bilinear alpha_i, clamped at the border: texel 0 of a row or column lies a quarter parent spacing
    outside parent 0's centre ((0 + 1/2) / 2 - 1/2 = -1/4), so it takes parent 0 alone. Parents holding their own column
    (row) index then give column (row) 0 of the level exactly 0, on a sphere filling the frame."""
    W = H = 32
    cam = make_camera((0.0, 0.0, 8.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 40.0, W, H)
    gb = render_gbuffer(cam, build_geometry([SphereSpec((0, 0, 0), 3.0, 0)], []))
    for level in (0, 1):
        w, h = level_size(W, H, level)
        pw, ph = level_size(W, H, level + 1)
        s = 1 << (level + 1)
        ys = np.minimum(np.arange(ph) * s + s // 2, H - 1)
        xs = np.minimum(np.arange(pw) * s + s // 2, W - 1)
        valid = gb.coverage[np.ix_(ys, xs)].astype(np.int32)
        idx = np.meshgrid(np.arange(pw), np.arange(ph))[axis].astype(np.float32)   # column (0) or row (1) index
        parents = idx.reshape(-1, 1) * np.ones(3, np.float32)
        r = upsample_level(gb.data, cam, level, parents, valid.reshape(-1), np.ones(w * h), mode="paper")
        vals = r.values.numpy()[:, 0].reshape(h, w)
        ok = r.valid.numpy().reshape(h, w) == 1
        edge = ok[:, 0] if axis == 0 else ok[0, :]
        assert edge.sum() >= 4, level
        got = vals[:, 0] if axis == 0 else vals[0, :]
        np.testing.assert_allclose(got[edge], 0.0, atol=1e-6, err_msg=f"level {level}")


# ------------------------------------------------------------------------------------------ properties (hypothesis)
# Property-based tests of the bilateral up-sampling (warpbw.upsample, 002 Sec. 3.2) over random scenes of spheres,
# random cameras (any direction, images taller or wider than high), random levels and random sets of valid parents:
# a constant stays that constant, the result follows an affine change of the parents' values, the weights are
# non-negative and zero where a parent may not be used, and a depth edge never takes a parent across it.


def camera_around(azimuth, elevation, distance, w, h, look_at=(0.0, 0.0, 0.0), fov=45.0):
    """A camera at ``distance`` from ``look_at`` in the direction (azimuth, elevation), looking at it, +Y up."""
    d = np.array([math.cos(elevation) * math.sin(azimuth), math.sin(elevation),
                  math.cos(elevation) * math.cos(azimuth)])
    pos = np.asarray(look_at) + distance * d
    return make_camera(tuple(pos), look_at, (0.0, 1.0, 0.0), fov, w, h), pos


def centre_representatives(w, h, level):
    """Finest pixel index at the centre of each texel of ``level`` (clamped to the image), as the docstring says."""
    lw, lh = level_size(w, h, level)
    s = 1 << level
    xs = np.minimum(np.arange(lw) * s + s // 2, w - 1)
    ys = np.minimum(np.arange(lh) * s + s // 2, h - 1)
    return (ys[:, None] * w + xs[None, :]).reshape(-1)


sphere = st.builds(lambda c, r, m: SphereSpec(c, r, m), st.tuples(*[st.floats(-1.0, 1.0)] * 3), st.floats(0.3, 1.0),
                   st.integers(0, 1))


layouts = dict(spheres=st.lists(sphere, min_size=1, max_size=3), azimuth=st.floats(-math.pi, math.pi),
               elevation=st.floats(-1.2, 1.2), distance=st.floats(4.0, 7.0), w=st.integers(6, 40),
               h=st.integers(6, 40), level=st.integers(0, 2), valid_share=st.sampled_from([0.5, 0.9, 1.0]),
               mode=st.sampled_from(UPSAMPLE_MODES), seed=st.integers(0, 2**31 - 1))


def frame(spheres, azimuth, elevation, distance, w, h, level, valid_share, seed):
    """G-buffer, camera, level (clamped to the top), and parent_valid: the parents over covered pixels, of which
    a random share is kept (as if the rest were not yet computed)."""
    cam, _ = camera_around(azimuth, elevation, distance, w, h)
    gb = render_gbuffer(cam, build_geometry(spheres, []), threads=1)
    level = min(level, top_level(w, h))
    rep = centre_representatives(w, h, level + 1)
    covered = gb.numpy("material").reshape(-1)[rep] >= 0
    keep = np.random.default_rng(seed).random(len(rep)) < valid_share
    return gb, cam, level, (covered & keep).astype(np.int32)


@settings(max_examples=40, deadline=None)
@given(c=st.tuples(*[st.floats(1e-3, 1e3)] * 3), **layouts)
def test_a_constant_image_up_samples_to_that_constant_for_any_layout(c, spheres, azimuth, elevation, distance, w, h,
                                                                     level, valid_share, mode, seed):
    """The weighted mean of equal values is that value, whatever the (non-negative) weights; the normal fit of a
    constant has slope 0 and is then clamped to the parents' range, the constant itself (module docstring: "a
    constant stays constant").  So every texel written equals c, for any scene, camera, level and set of valid
    parents; a texel is never both written and left to be shaded, and background texels are neither."""
    gb, cam, level, valid = frame(spheres, azimuth, elevation, distance, w, h, level, valid_share, seed)
    lw, lh = level_size(w, h, level)
    parents = np.tile(np.float32(c), (len(valid), 1))
    r = upsample_level(gb.data, cam, level, parents, valid, np.ones(lw * lh), mode=mode)
    ok = r.valid.numpy() == 1
    needs = r.needs_shading.numpy() == 1
    np.testing.assert_allclose(r.values.numpy()[ok], np.broadcast_to(np.float32(c), (ok.sum(), 3)), rtol=2e-6)
    assert not (ok & needs).any()
    background = gb.numpy("material").reshape(-1)[centre_representatives(w, h, level)] < 0
    assert not (ok | needs)[background].any()
    # with every covered parent valid, a covered texel is written or shaded
    if valid_share == 1.0:
        assert (ok | needs)[~background].all()


@settings(max_examples=40, deadline=None)
@given(scale=st.floats(0.01, 100.0), shift=st.floats(-10.0, 10.0), **layouts)
def test_up_sampling_follows_an_affine_change_of_the_parents_values(scale, shift, spheres, azimuth, elevation,
                                                                   distance, w, h, level, valid_share, mode, seed):
    """The weights w_i depend on the G-buffer only, never on the parents' values; the weighted mean and the
    weighted least-squares plane (its value at the pixel's normal) both commute with L -> a L + b for a > 0, and so
    does the clamp to the parents' range [min_i L_i, max_i L_i].  So up-sampling a L + b gives a times the
    up-sampling of L, plus b, with the same texels written and the same weights.  The weights are non-negative, and
    0 for a parent that is not valid."""
    gb, cam, level, valid = frame(spheres, azimuth, elevation, distance, w, h, level, valid_share, seed)
    lw, lh = level_size(w, h, level)
    pw, ph = level_size(w, h, level + 1)
    L = np.random.default_rng(seed + 1).uniform(0.0, 2.0, size=(len(valid), 3)).astype(np.float32)
    a = upsample_level(gb.data, cam, level, L, valid, np.ones(lw * lh), mode=mode)
    b = upsample_level(gb.data, cam, level, (scale * L.astype(np.float64) + shift).astype(np.float32), valid,
                       np.ones(lw * lh), mode=mode)
    ok = a.valid.numpy() == 1
    np.testing.assert_array_equal(b.valid.numpy(), a.valid.numpy())
    np.testing.assert_array_equal(b.weights.numpy(), a.weights.numpy())
    # float32 rounding, relative to the values' range: the weighted mean loses under 3e-7 of it (measured over 300
    # random frames), the fit's 2 x 2 solve (determinant down to the ridge squared, 1e-6) up to 2e-4
    tol = (2e-6 if mode == "paper" else 1e-3) * (scale * 2.0 + abs(shift))
    np.testing.assert_allclose(b.values.numpy()[ok], scale * a.values.numpy()[ok].astype(np.float64) + shift,
                               rtol=0, atol=tol)
    # weights: non-negative; 0 on every parent not valid (parent k of texel (x, y): lower/upper along each axis)
    wts = a.weights.numpy().reshape(lh, lw, 4)
    assert np.all(wts >= 0.0)
    x, y = np.arange(lw), np.arange(lh)
    i0 = np.clip(np.floor((x + 0.5) * 0.5 - 0.5).astype(int), 0, pw - 1)
    j0 = np.clip(np.floor((y + 0.5) * 0.5 - 0.5).astype(int), 0, ph - 1)
    i1, j1 = np.minimum(i0 + 1, pw - 1), np.minimum(j0 + 1, ph - 1)
    vv = valid.reshape(ph, pw)
    for k, (jj, ii) in enumerate([(j0, i0), (j0, i1), (j1, i0), (j1, i1)]):
        invalid = vv[np.ix_(jj, ii)] == 0
        assert np.all(wts[..., k][invalid] == 0.0), k


@settings(max_examples=30, deadline=None)
@given(near=st.floats(2.0, 4.0), r_near=st.floats(0.3, 0.9), off=st.tuples(st.floats(-0.5, 0.5), st.floats(-0.5, 0.5)),
       gap=st.floats(2.5, 6.0), azimuth=st.floats(-math.pi, math.pi), elevation=st.floats(-1.2, 1.2),
       w=st.integers(8, 40), h=st.integers(8, 40), level=st.integers(0, 2), mode=st.sampled_from(UPSAMPLE_MODES))
def test_a_depth_edge_never_takes_a_parent_across_it(near, r_near, off, gap, azimuth, elevation, w, h, level, mode):
    """A near sphere in front of a far one of the same material (so that only depth can tell them apart), the far
    sphere's nearest depth at least 2.5 times the near one's farthest.  g_z = exp(-((z - z_i) / (0.1 z))^2) gives a
    parent across that edge at most exp(-36) of its weight (seen from the far side; exp(-225) from the near side),
    while a texel is written only where its weights sum to WEIGHT_MIN = 1e-4 or more: so the near sphere's texels
    take the near value and the far sphere's the far value, to float32 rounding, whatever the camera,
    level and mode (the normal fit's clamp keeps it between parents it weighs)."""
    cam, pos = camera_around(azimuth, elevation, 5.0, w, h)
    fwd = np.array(list(cam.forward), np.float64)
    right, up = np.array(list(cam.right), np.float64), np.array(list(cam.up), np.float64)
    c_near = pos + near * fwd + off[0] * right + off[1] * up
    far_min = gap * (near + r_near)         # the far sphere's nearest depth
    r_far = far_min                         # large: it fills the view behind the near sphere
    c_far = pos + (far_min + r_far) * fwd
    gb = render_gbuffer(cam, build_geometry([SphereSpec(tuple(c_near), r_near, 0),
                                             SphereSpec(tuple(c_far), r_far, 0)], []), threads=1)
    depth = gb.numpy("depth").reshape(-1)
    mat = gb.numpy("material").reshape(-1)
    is_near = (mat >= 0) & (depth <= near + r_near * 1.0001)
    is_far = (mat >= 0) & (depth >= far_min * 0.9999)
    assert np.all(is_near | is_far | (mat < 0))
    level = min(level, top_level(w, h))
    rep_p = centre_representatives(w, h, level + 1)
    valid = (mat[rep_p] >= 0).astype(np.int32)
    A, B = np.float32([1.0, 0.0, 0.0]), np.float32([0.0, 0.0, 1.0])
    parents = np.where(is_near[rep_p][:, None], A, B).astype(np.float32)
    lw, lh = level_size(w, h, level)
    r = upsample_level(gb.data, cam, level, parents, valid, np.ones(lw * lh), mode=mode)
    ok = r.valid.numpy() == 1
    rep = centre_representatives(w, h, level)
    vals = r.values.numpy()
    np.testing.assert_allclose(vals[ok & is_near[rep]], np.broadcast_to(A, ((ok & is_near[rep]).sum(), 3)), atol=1e-6)
    np.testing.assert_allclose(vals[ok & is_far[rep]], np.broadcast_to(B, ((ok & is_far[rep]).sum(), 3)), atol=1e-6)


@pytest.mark.xfail(strict=True, reason="kept by choice (upsample docstring, alpha_i): the weights place a texel at "
                   "its footprint's centre, but its value was shaded at its representative pixel, half a finest pixel "
                   "(more on the last row/column of an odd size) away, so level 0 reads its parents half a pixel on; "
                   "weights between the representative pixels lost 0.2-0.46 dB end to end at low budgets (session 73)")
@MODES
@pytest.mark.parametrize("w, h", [(32, 32), (33, 17)])
def test_a_screen_ramp_up_samples_to_itself_where_its_parents_were_shaded(mode, w, h):
    """A texel's value is shaded at its representative pixel, the finest pixel (x 2^L + 2^L // 2, y 2^L + 2^L // 2)
    clamped to the image (upsample docstring: depth and normal are read there).  On a frontal wall (one depth, one
    normal: g_z = 1, M = I, and the normal fit reduces to the weighted mean), parents holding a ramp in screen x or y
    measured at their pixels' centres must give: at a texel whose own pixel is a parent's pixel, that parent's value
    (002 Fig. 8's bilinear alpha_i are 1 and 0 at a parent's centre), and over the interior an error of mean 0 (no
    shift).  The truth is the ramp in closed form at each texel's pixel.  The kernel's weights read the ramp half a
    pixel on at level 0 (mean error +0.5 px, 0.45 px at a parent's own pixel), and the last column of 33 at level 2
    0.9 px off: a shift kept by choice (the xfail's reason)."""
    cam = make_camera((0.0, 0.0, 20.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 10.0, w, h)
    gb = render_gbuffer(cam, build_geometry([], [_quad(-5.0, 5.0, -5.0, 5.0, 0.0, 0)]))
    assert gb.coverage.all()

    def centres(level):   # the representative pixels' centres along x and y, in finest pixels (docstring's rule)
        lw, lh = level_size(w, h, level)
        s = 1 << level
        return np.minimum(np.arange(lw) * s + s // 2, w - 1) + 0.5, np.minimum(np.arange(lh) * s + s // 2, h - 1) + 0.5

    for level in (0, 1, 2):
        lw, lh = level_size(w, h, level)
        pw, ph = level_size(w, h, level + 1)
        (cx, cy), (px, py) = centres(level), centres(level + 1)
        on_parent = np.isin(cx, px)[None, :] & np.isin(cy, py)[:, None]
        for axis in (0, 1):
            pv = np.tile(px, ph) if axis == 0 else np.repeat(py, pw)
            truth = (np.tile(cx, lh) if axis == 0 else np.repeat(cy, lw)).reshape(lh, lw)
            parents = np.repeat(pv[:, None], 3, 1).astype(np.float32)
            r = upsample_level(gb.data, cam, level, parents, np.ones(pw * ph), np.ones(lw * lh), mode=mode)
            assert (r.valid.numpy() == 1).all()
            err = r.values.numpy()[:, 0].reshape(lh, lw) - truth
            where = f"level {level}, axis {axis}"
            if on_parent.any():
                np.testing.assert_allclose(err[on_parent], 0.0, atol=1e-3, err_msg=where)
            if level == 0:   # the interior, two texels from each border (no clamped parent)
                assert abs(err[2:-2, 2:-2].mean()) < 0.05, (where, err[2:-2, 2:-2].mean())
