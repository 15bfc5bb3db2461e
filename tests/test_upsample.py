"""Bilateral up-sampling (002 Sec. 3.2): constants are preserved, depth edges do not bleed, invalid parents
are ignored, weights follow the closed form, grazing pixels narrow the kernel along the normal."""
from __future__ import annotations

import numpy as np
import warp as wp

from warpbw.gbuffer import SphereSpec, build_geometry, make_camera, render_gbuffer
from warpbw.upsample import (COS_X_MIN, G_A_UNIT, anisotropic_gaussian, level_size, parent_weights,
                             upsample_level)


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


def test_constant_image_upsamples_to_itself():
    gb, cam = gbuffer([SphereSpec((0, 0, 0), 1.2, 0)])
    for level in (0, 1, 2):
        valid, _ = parent_valid_from_coverage(gb, level + 1)
        c = np.array([0.25, 0.5, 2.0], np.float32)
        parents = np.tile(c, (len(valid), 1))
        w, h = level_size(gb.width, gb.height, level)
        r = upsample_level(gb.data, cam, level, parents, valid, np.ones(w * h))
        ok = r.valid.numpy() == 1
        assert ok.sum() > 0.5 * valid.sum()
        assert np.allclose(r.values.numpy()[ok], c, rtol=1e-6)


def test_depth_edge_does_not_bleed():
    # a near sphere partly in front of a far one: values A (near) and B (far) must not mix
    gb, cam = gbuffer([SphereSpec((-0.4, 0, 1.5), 0.8, 0), SphereSpec((0.6, 0, -3.0), 1.6, 1)], w=64, h=48)
    valid, mat = parent_valid_from_coverage(gb, 1)
    A, B = np.array([1.0, 0, 0], np.float32), np.array([0, 0, 10.0], np.float32)
    parents = np.where((mat == 0)[:, None], A, B).astype(np.float32)
    r = upsample_level(gb.data, cam, 0, parents, valid, np.ones(gb.width * gb.height))
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


def test_invalid_parents_are_ignored():
    gb, cam = gbuffer([SphereSpec((0, 0, 0), 1.2, 0)])
    valid, _ = parent_valid_from_coverage(gb, 1)
    rng = np.random.default_rng(0)
    poisoned = valid.copy()
    poisoned[rng.random(len(valid)) < 0.3] = 0
    parents = np.tile(np.float32([1.0, 1.0, 1.0]), (len(valid), 1))
    parents[poisoned == 0] = np.nan
    r = upsample_level(gb.data, cam, 0, parents, poisoned, np.ones(gb.width * gb.height))
    ok = r.valid.numpy() == 1
    assert np.isfinite(r.values.numpy()[ok]).all()
    assert np.allclose(r.values.numpy()[ok], 1.0)
    assert (r.needs_shading.numpy() == 1).sum() + ok.sum() >= 0.9 * gb.coverage.sum()


def test_weights_follow_the_closed_form_on_a_frontal_surface():
    # the centre of a big sphere faces the camera: cos theta_x ~ 1, M ~ I, g_z ~ 1
    gb, cam = gbuffer([SphereSpec((0, 0, 0), 3.0, 0)], w=32, h=32, pos=(0.0, 0.0, 8.0))
    wts = parent_weights(gb.data, cam, 0)
    for x, y in ((16, 16), (15, 16), (16, 15), (15, 15)):
        u = (np.array([x, y]) + 0.5) * 0.5 - 0.5
        i0 = np.floor(u)
        f = u - i0
        expect = []
        for k in range(4):
            px = i0[0] + (k % 2)
            py = i0[1] + (k // 2)
            ax = (1 - f[0]) if k % 2 == 0 else f[0]
            ay = (1 - f[1]) if k < 2 else f[1]
            v = np.array([2 * px + 1 - (x + 0.5), 2 * py + 1 - (y + 0.5)]) / G_A_UNIT
            expect.append(ax * ay * np.exp(-(v @ v)))
        # a sphere is not a plane: cos theta_x and depth vary slightly over 1.5 pixels (1% on the far parent)
        assert np.allclose(wts[y, x], expect, rtol=1e-2, atol=1e-6)
    # the bilinear part alone: 9/16, 3/16, 3/16, 1/16 up to the Gaussian factor
    assert sorted(np.round(np.array([0.75 * 0.75, 0.75 * 0.25, 0.25 * 0.75, 0.0625]) * 16)) == [1, 3, 3, 9]


def test_grazing_narrows_the_kernel_along_the_projected_normal():
    @wp.kernel(enable_backward=False)
    def ga(vs: wp.array(dtype=wp.vec2), n: wp.vec2, c: float, out: wp.array(dtype=float)):
        t = wp.tid()
        out[t] = anisotropic_gaussian(vs[t], n, c)

    vs = wp.array(np.array([[1.0, 0.0], [0.0, 1.0]], np.float32), dtype=wp.vec2)
    out = wp.zeros(2, dtype=float)
    for c in (1.0, 0.5, 0.1, 0.0):
        wp.launch(ga, 2, inputs=[vs, wp.vec2(1.0, 0.0), c, out])
        along, across = out.numpy()
        assert np.isclose(across, np.exp(-1.0), rtol=1e-6)
        assert np.isclose(along, np.exp(-1.0 / max(c, COS_X_MIN) ** 2), rtol=1e-5, atol=1e-30)
        assert along <= across


def test_odd_sizes_and_tiny_images_run():
    for w, h in ((7, 5), (1, 1), (3, 1)):
        gb, cam = gbuffer([SphereSpec((0, 0, 0), 1.5, 0)], w=w, h=h)
        for level in range(3):
            lw, lh = level_size(w, h, level)
            valid, _ = parent_valid_from_coverage(gb, level + 1)
            r = upsample_level(gb.data, cam, level, np.ones((len(valid), 3)), valid, np.ones(lw * lh))
            assert np.isfinite(r.values.numpy()).all()
