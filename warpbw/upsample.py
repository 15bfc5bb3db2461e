"""Anisotropic bilateral up-sampling of one pyramid level from its parents (002 Sec. 3.2, Fig. 8).

Public:
    ``level_size(width, height, level) -> (w, h)``   size of a pyramid level (ceil-halving)
    ``top_level(width, height)``                      the 1 x 1 level's index, the last ``upsample_level`` takes
    ``UpsampleResult`` / ``upsample_level(gb, cam, level, ..., mode, weights)``  fill the requested pixels of level
                                                      L from level L+1 (``gb``: a ``GBuffer`` or its ``GBufferData``)
    ``UPSAMPLE_MODES``, ``UPSAMPLE_DEFAULT``, ``check_upsample_mode(mode)``
    ``parent_weights(...)``                           host wrapper returning the four weights (tests)
    ``representative_pixel(gb, x, y, level)``         Warp func: the finest pixel at the centre of a level-L pixel's
                                                      whole footprint, clamped to the image
    ``upsample_level_kernel``                         the up-sampling's kernel (warpbw.adaptive compiles it ahead)
    Warp functions of the weights: ``screen_frame``, ``screen_normal``, ``anisotropic_gaussian`` (g_a),
    ``depth_gaussian`` (g_z), ``parent_axis`` (alpha_i), ``parent_weight`` (w_i) and ``normal_fit`` (the normal fit)

A pixel p of level L takes the weighted mean of its four nearest parents p_i at level L+1 that are
already computed (``parent_valid``), or by default the value at its normal of a plane fitted to them under the
same weights (the normal fit, below):

    w_i = g_z(z - z_i) g_a(p - p_i) alpha_i                                           (002 Sec. 3.2)

* alpha_i: bilinear weights of the parent centres (9/16, 3/16, 3/16, 1/16 in the interior, Fig. 8).  A known shift,
  kept by choice: a texel's value is shaded at its representative pixel, half a finest pixel from its footprint's
  centre, where these weights place it; levels 1 and up are shifted alike, but level 0's pixels sit at their own
  centres, so level 0 reads its parents half a pixel on (more on the last row or column of an odd size;
  ``tests/test_upsample.py``'s ramp test, a strict xfail).  Weights between the representative pixels remove it
  (noise-free up-sampling +0.4 to +1.9 dB on the four benchmark scenes), but a level-0 pixel then weighs one or two
  parents where it weighed four, and more pixels are shaded: end to end, 4 paired runs, it lost 0.2-0.46 dB at
  budgets 0.5-2 on three scenes, gained at 16-32, and lost 0.24-0.41 dB at every budget on the acrylic bunny
  (session 73, docs/measurements.md).
* A parent of another material than the pixel's has weight 0 (the paper is silent).  Two objects of different
  materials side by side at one depth are an edge of the image that depth and normal do not see, and that the
  bandwidth pass does not see either when the light is smooth: under a constant environment every pixel's b_p
  is 0, and the paper's weights gave a gold sphere the colour of the clay and glossy spheres beside it (the
  demo scene at 128x96, budget 8, seeds 1-3: 14.2-14.3 dB against the reference at 8 spp's 21.3, 34.5-34.9 dB with
  the material check; session 60, docs/measurements.md).
* g_z(dz) = exp(-(dz / (DEPTH_SIGMA_REL z))^2): cancels parents at another depth (relative tolerance).
* g_a(v) = exp(-v^T M v), M = R_phi^T diag(1, 1 / cos^2 theta_x) R_phi, phi the angle of the
  screen-projected normal and theta_x the angle between normal and view: the kernel is narrower along the
  projected normal, where foreshortening raises the screen-space frequency.  cos theta_x is clamped to
  COS_X_MIN so that silhouettes stay finite.  The projected normal is the pinhole's image of the normal at the
  surface point (``screen_frame``), the direction the surface is foreshortened along; until session 75 it was
  the normal projected along the camera's axes, up to 26 degrees off it where cos theta_x < 0.5 on a sphere off
  the optical axis at a 90 degree field of view (three off-axis spheres, budgets 1 and 4: +0.001 / +0.003 dB).
* A level-0 pixel whose shading normal faces away from the eye (normals interpolated across a mesh's
  silhouette) takes 0, as the estimator gives it (``warpbw.shading``), not its parents' light.
* The unit of v, where the paper is silent: ``G_A_UNIT`` = 4 level-L pixels (two parent spacings).  With v
  in level-L pixels (our first version) the nearest parent took 92% of the weight on a surface facing the
  camera (78% from g_a alone, the rest from alpha_i; closed form): nearly nearest-neighbour up-sampling, blocks
  of 2^L pixels on smooth shading.  In units of
  4 pixels a frontal surface's normalised weights are within 20% of the bilinear alpha_i, while at a silhouette
  (cos theta_x = 0.05) the parent 1.5 pixels away along the normal keeps only exp(-56) of its bilinear
  weight.  Measured on the four scenes of examples/bench_scenes.py (MIS, budgets 1-8, 2 seeds each,
  PSNR against the cached ground truths): unit 1 -> 2 -> 4 raised PSNR by up to 1.5 / 2.3 dB (ccp3 sphere),
  1.2 / 1.5 dB (gold bunny) and 0.4 / 0.5 dB (acrylic bunny), and left the chrome sphere within 0.01 dB;
  dropping g_a altogether (bilinear alpha_i and g_z only) gained 0.04-0.3 dB more, but has no anisotropy.

The normal fit (``mode="normal"``, the default since session 36; ``"paper"`` is the weighted mean alone).  Under
the same weights w_i, the pixel takes the value at its own normal of the least-squares plane through its
parents' values as a function of their normals,

    min_{a, g} sum_i w_i (L_i - a - g . du_i)^2 + NORMAL_RIDGE |g|^2,   du_i = u(n_i) - u(n),

u(n) = (n . right, n . up) the normal's screen components, n_i at the parents' and n at the pixel's
representative pixels,

so L = a, clamped per channel to the parents' range [min_i L_i, max_i L_i].  With g = 0 (equal normals, or
parents whose values do not follow their normals) it is the paper's weighted mean; a constant stays constant,
and a parent the weights drop (another depth, an invalid texel) takes no part.  Why: on a bumpy surface the
reflected light follows the normal, and the normal changes faster than the parents' spacing, so the weighted
mean blurs the bumps' highlights.  On the benchmark's gold bunny (``examples/bench_scenes.py``), shading every
shaded texel with its ground-truth value (noise-free; budget 8's levels; ``/work/bench/s36/upbias.py``) leaves a
relative MSE of 9.8e-4 with the weighted mean and 5.3e-4 with the fit, and that bias is most of its frames' error
at budgets of 4 and more.  End to end, with the same N_p and seeds (3 runs; a numpy patch of the fit,
``/work/bench/s36/upreg_e2e.py``, against the weighted mean; the kernel reproduces it to 0.01 dB; MSE against the
cached 8192-spp ground truth), ridge 2e-4 / 1e-3, and the clamp:

* gold bunny (512x512, forest.exr): +1.13 / +1.08 dB at budget 4, +2.03 / +1.81 dB at budget 16 (without the
  clamp +0.95 / +1.03 and +1.95 / +1.84: the clamp helps: the fit picks the parent whose normal is nearest
  more than it extrapolates);
* acrylic bunny (256x256, studio.exr, noise-limited: its parents are noisy, and a slope fitted to noise
  extrapolates it): -0.10 / -0.04 dB at budget 8, -0.03 / +0.02 at 32 (without the clamp -0.29 / -0.09 and
  -0.20 / -0.01);
* ccp3 sphere: +0.15 / +0.05 at budget 4, +0.26 / +0.07 at 16 (without the clamp); chrome sphere: within
  0.01 dB (on a sphere the normal is nearly linear in the image, and the weights already reproduce a linear
  function);
* bunnies the ridge was not chosen on (with the clamp): gold-metallic-paint under studio.exr at 256x256
  -0.04 / +0.36 / +1.03 dB at budgets 2 / 8 / 32 with ridge 1e-3 (-0.17 / +0.25 / +1.00 with 2e-4);
  color-changing-paint3 and nickel under forest.exr at 256x256 and red-metallic-paint under city.exr (a sun)
  at 512x512, whose error is noise: within -0.01 to +0.05 dB.

With the defaults, in ``examples/bench_scenes.py``'s 8-run benchmark against session 35's
(same seeds, docs/measurements.md):
with MIS the gold bunny +0.68 to +1.98 dB at budgets 2-32 (equal-quality speed-up 3.68x -> 5.07x), the ccp3
sphere +0.03 to +0.10, the chrome sphere within 0.01, the acrylic bunny -0.03 to -0.05 at budgets 0.5-8; with BRDF
sampling alone, noisier, the gold bunny -0.05 to -0.09 dB at budgets 0.5-4 and +0.05 to +0.49 at 8-32, the acrylic
bunny -0.07 to -0.22.

The ridge of 1e-3 (about (0.03 rad)^2 of normal spread) is the larger of the two: it gives up 0.05-0.2 dB of
the gold bunny's gain for the noise-limited scenes.  Coordinates: the normal's screen components (tried against
the components in the child's tangent frame: 0.02-0.11 dB less on the gold bunny, without the clamp).

Measured, not adopted (session 29; MIS, 4 or 8 paired seeds, PSNR against cached 8192-spp ground truths):

* a normal weight g_n = exp(-2 (c_max - n . n_i) / sigma^2), c_max the largest n . n_i of the four parents
  (so the best-matching parent keeps its weight, and WEIGHT_MIN still tests the paper's weights).  On the
  benchmark's gold bunny, with sigma = 0.1 rad doubling per level, it gained 0.2 / 0.4 / 0.5 dB at budgets
  2 / 4 / 8 (0.15 rad fixed: 0.2 / 0.4 / 0.5), left the spheres within 0.02 dB and cost the acrylic bunny
  0.09 dB; sigma = 0.04 rad cost the ccp3 sphere 0.3 dB.  On two bunnies it was not tuned on (256x256,
  gold-metallic-paint under studio.exr, color-changing-paint3 under forest.exr; budgets 1-8) it lost up to
  0.23 dB at low budgets and gained at most 0.12 dB, so the gain did not carry over;
* up-sampling the ratio of the shading to a per-pixel proxy (the environment's MIP pyramid at the mirror
  direction, a split-sum-like demodulation), multiplied back by the child's proxy: on the gold bunny the
  up-sampled pixels' ratio to the ground truth reached 5.8x (MIP level 4) and 10.7x (level 2) at the 99th
  percentile, against 1.9x with a constant proxy, and PSNR fell from 36.5-38.3 dB to below 25 dB at budgets
  2-8.  A proxy would need the lobe's own pre-filtered light.  The normal fit above lets the parents themselves
  say how the shading follows the normal.

Measured, not adopted (session 37; the same levels, N_p and seeds, 3 runs, paired dB against the fit above;
``/work/bench/s37/ridge_sweep.py``, ``noise_shrink.patch``): a fit that backs off where its parents are noisy.  Each
shaded parent carried the variance the bandwidth pass measures for one sample over its N_p, each up-sampled one
that of its weighted mean.

* The ridge widened by k times the parents' relative noise variance (sum_i w_i sigma_i^2 / sum_i w_i over the
  luminance of the mean, squared).  With k = 0.01 / 0.03 the acrylic bunny gains 0.03-0.04 / 0.04-0.05 dB at
  budgets 2-8 with MIS and 0.05-0.08 / 0.07-0.11 dB at budgets 2-32 without, and the gold bunny without MIS
  +0.06 / +0.09 dB at budget 2.  But the gold bunny with MIS, the scene the fit is for, loses 0.01-0.03 /
  0.03-0.08 dB at budgets 2-32.
* The slope shrunk by its own noise, g |g|^2 / (|g|^2 + k tr V_g), V_g = C^-1 V_b C^-1 from the parents' noise
  (Wiener's factor): with k = 1 the gold bunny with MIS loses 0.12 / 0.18 / 0.09 dB at budgets 2 / 8 / 32, and
  the acrylic bunny gains at most 0.04 dB.

Why neither helps: the pass's noise estimate is too coarse per pixel to tell a slope from noise.  Against the spread
of four seeds at the pixels a budget-8 frame shades at level 0 (``/work/bench/s37/calib.py``), the pass's variance
over N_p is right in sum (the measured is 0.93x the predicted on the gold bunny with MIS) but about 3x the typical
pixel's noise (median ratio 0.30 / 0.32 / 0.33 on the gold bunny, the acrylic bunny and the ccp3 sphere with MIS),
and it ranks the pixels' noise at 0.56 / 0.09 / 0.61 (Spearman; 0.45 / 0.11 / 0.37 without MIS).  Four seeds' spread
is itself noisy, which lowers these ranks, most where the noise is spread evenly (the acrylic bunny).

Depth, normal and view are read at the finest level (the G-buffer is not mip-mapped): a level-L pixel
is represented by the finest pixel at the centre of its footprint.  A pixel whose weights sum to less
than WEIGHT_MIN (no parent at its depth, e.g. across a depth edge) is not guessed: it is returned in
``needs_shading`` for the caller to shade at this level.  That test is absolute, and g_z relative: at a limb in
front of a surface about 20% deeper, g_a leaves the near parents along the normal little weight while g_z leaves a
far parent exp(-(0.21 / 0.1)^2) = 1.2% of its own, and the paper's weighted mean took 73% of the far value at one
pixel (two spheres, 64x48; ``test_the_default_fit_keeps_a_near_spheres_limb_from_a_sphere_just_behind_it``).  The
fit explains the far parent's value by its far-off normal and takes at most 0.4% there (not a guarantee: it is the
default for the reasons above, and ``mode="paper"`` keeps this bleed).

Level sizes halve with rounding up, ``w_{L+1} = ceil(w_L / 2)``, so any image size works.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from warpbw.errors import FLOAT32_MAX, WarpbwError, check_count, check_device, check_warp_array, numeric_array
from warpbw.gbuffer import CameraData, GBuffer, GBufferData, check_camera_of

DEPTH_SIGMA_REL = 0.1   # g_z tolerance, relative to the child's depth (a 10% depth step is an edge)
COS_X_MIN = 0.05        # clamp of cos theta_x in M (grazing: the kernel width along the normal stays > 0)
WEIGHT_MIN = 1.0e-4     # below this total weight the pixel is shaded instead of up-sampled
G_A_UNIT = 4.0          # level-L pixels per unit of v in g_a (module docstring: measured, the paper is silent)
UPSAMPLE_MODES = ("normal", "paper")   # first-order fit in the normal / the paper's weighted mean (docstring)
UPSAMPLE_DEFAULT = "normal"
NORMAL_RIDGE = 1.0e-3   # ridge on the normal fit's slope, in (n . axis)^2 units (about 0.03 rad; docstring)


@wp.func
def representative_pixel(gb: GBufferData, x: int, y: int, level: int):
    """Finest pixel at the centre of level-L pixel (x, y)'s whole 2^L x 2^L footprint, clamped to the image: where the
    image's border clips the footprint (a side of no power of two), that pixel lies off the clipped part's centre
    (7 pixels wide, level 2, texel 1 covers pixels 4-6 and is represented by pixel 6)."""
    s = 1 << level
    fx = wp.min(x * s + s // 2, gb.width - 1)
    fy = wp.min(y * s + s // 2, gb.height - 1)
    return fy * gb.width + fx


@wp.func
def screen_frame(cam: CameraData, n: wp.vec3, p: wp.vec3):
    """Unit screen-space direction of the projected normal (x right, y down), as a vec2: the pinhole's image of the
    normal at the surface point p, d/de of the projection of p + e n (the direction the surface is foreshortened
    along), ((n . right) z - (q . right)(n . forward), -((n . up) z - (q . up)(n . forward))),
    q = (p - eye) / |p - eye|, z = q . forward."""
    q = wp.normalize(p - cam.origin)   # unit: nx, ny without units, as the threshold below
    z = wp.dot(q, cam.forward)
    nf = wp.dot(n, cam.forward)
    nx = wp.dot(n, cam.right) * z - wp.dot(q, cam.right) * nf
    ny = -(wp.dot(n, cam.up) * z - wp.dot(q, cam.up) * nf)
    l = wp.sqrt(nx * nx + ny * ny)
    if l < 1.0e-6:
        return wp.vec2(1.0, 0.0)
    return wp.vec2(nx / l, ny / l)


@wp.func
def anisotropic_gaussian(v: wp.vec2, n_screen: wp.vec2, cos_x: float):
    # g_a(v) = exp(-v^T M v), M = R_phi^T diag(1, 1/cos^2) R_phi (002 Sec. 3.2)
    b = v[0] * n_screen[0] + v[1] * n_screen[1]      # along the projected normal
    a = -v[0] * n_screen[1] + v[1] * n_screen[0]     # across it
    c = wp.max(cos_x, COS_X_MIN)
    return wp.exp(-(a * a + b * b / (c * c)))


@wp.func
def depth_gaussian(z: float, zi: float):
    d = (z - zi) / (DEPTH_SIGMA_REL * wp.max(z, 1.0e-20))
    return wp.exp(-d * d)


@wp.func
def parent_weight(gb: GBufferData, x: int, y: int, px: int, py: int, pi: int,
                  alpha: float, z: float, n_screen: wp.vec2, cos_x: float, m: int):
    """w_i for parent (px, py) at the next level, represented by finest pixel ``pi``, of child (x, y) of
    material ``m`` (0 when the parent is empty or of another material: module docstring)."""
    if gb.material[pi] != m:
        return 0.0
    # parent centre minus child centre, in level-L pixels: (2 px + 1) - (x + 0.5), then in units of G_A_UNIT
    v = wp.vec2(2.0 * float(px) + 1.0 - (float(x) + 0.5), 2.0 * float(py) + 1.0 - (float(y) + 0.5)) / G_A_UNIT
    return alpha * depth_gaussian(z, gb.depth[pi]) * anisotropic_gaussian(v, n_screen, cos_x)


@wp.func
def parent_axis(x: int, n_parent: int):
    """Lower parent index and the bilinear weight of the upper one, along one axis."""
    u = (float(x) + 0.5) * 0.5 - 0.5
    i0 = int(wp.floor(u))
    f = u - float(i0)
    if i0 < 0:
        i0 = 0
        f = 0.0
    if i0 >= n_parent - 1:
        i0 = n_parent - 1
        f = 0.0
    return i0, f


@wp.func
def screen_normal(cam: CameraData, n: wp.vec3):
    """The normal's components along the image axes, (n . right, n . up): the coordinates of the normal fit."""
    return wp.vec2(wp.dot(n, cam.right), wp.dot(n, cam.up))


@wp.func
def normal_fit(mean: wp.vec3, total: float, s_u: wp.vec2, s_uu: wp.vec3, s_ul_x: wp.vec3, s_ul_y: wp.vec3,
               lo: wp.vec3, hi: wp.vec3):
    """The value at du = 0 of the w_i-weighted least-squares plane L = a + g . du (ridge NORMAL_RIDGE on g),
    clamped to the parents' range [lo, hi] per channel (module docstring)."""
    m = s_u / total                                       # weighted mean of du
    cxx = s_uu[0] / total - m[0] * m[0] + NORMAL_RIDGE    # weighted covariance of du, + ridge
    cxy = s_uu[1] / total - m[0] * m[1]
    cyy = s_uu[2] / total - m[1] * m[1] + NORMAL_RIDGE
    bx = s_ul_x / total - m[0] * mean                     # weighted covariance of du and L
    by = s_ul_y / total - m[1] * mean
    det = cxx * cyy - cxy * cxy                           # >= NORMAL_RIDGE^2 > 0
    gx = (cyy * bx - cxy * by) / det
    gy = (cxx * by - cxy * bx) / det
    return wp.min(wp.max(mean - (m[0] * gx + m[1] * gy), lo), hi)


@wp.kernel(module="unique", enable_backward=False)
def upsample_level_kernel(gb: GBufferData, cam: CameraData, level: int,
                          width: int, height: int, parent_width: int, parent_height: int,
                          parent: wp.array(dtype=wp.vec3), parent_valid: wp.array(dtype=wp.int32),
                          todo: wp.array(dtype=wp.int32), fit: int, given: int,
                          out: wp.array(dtype=wp.vec3), out_valid: wp.array(dtype=wp.int32),
                          needs_shading: wp.array(dtype=wp.int32), weights: wp.array(dtype=wp.vec4)):
    """Up-sample texel t of level L (when ``todo``); the four w_i are computed into ``weights``, or with ``given``
    read from it (the same parents and flags computed them before: ``warpbw.adaptive.plan_hierarchy``)."""
    t = wp.tid()
    if todo[t] == 0:
        return
    x = t % width
    y = t // width
    rp = representative_pixel(gb, x, y, level)
    if gb.material[rp] < 0:
        return   # background: nothing to up-sample
    z = gb.depth[rp]
    n = gb.normal[rp]
    n_v = wp.dot(n, gb.view[rp])
    cos_x = wp.abs(n_v)
    n_screen = screen_frame(cam, n, gb.position[rp])
    u_c = screen_normal(cam, n)
    i0, fx = parent_axis(x, parent_width)
    j0, fy = parent_axis(y, parent_height)
    i1 = wp.min(i0 + 1, parent_width - 1)
    j1 = wp.min(j0 + 1, parent_height - 1)
    w = wp.vec4(0.0)
    acc = wp.vec3(0.0)
    total = float(0.0)
    # sums of the normal fit over the parents in use: du = u_i - u_c, du du^T (xx, xy, yy), du_x L, du_y L
    s_u = wp.vec2(0.0)
    s_uu = wp.vec3(0.0)
    s_ul_x = wp.vec3(0.0)
    s_ul_y = wp.vec3(0.0)
    lo = wp.vec3(FLOAT32_MAX)
    hi = wp.vec3(-FLOAT32_MAX)
    for k in range(4):
        px = wp.where(k % 2 == 0, i0, i1)
        py = wp.where(k < 2, j0, j1)
        ax = wp.where(k % 2 == 0, 1.0 - fx, fx)
        ay = wp.where(k < 2, 1.0 - fy, fy)
        q = py * parent_width + px
        pi = representative_pixel(gb, px, py, level + 1)
        wk = float(0.0)
        if given != 0:
            wk = weights[t][k]
        elif ax * ay > 0.0 and parent_valid[q] != 0:
            wk = parent_weight(gb, x, y, px, py, pi, ax * ay, z, n_screen, cos_x, gb.material[rp])
        w = w + wp.vec4(wp.where(k == 0, wk, 0.0), wp.where(k == 1, wk, 0.0), wp.where(k == 2, wk, 0.0),
                        wp.where(k == 3, wk, 0.0))
        if wk > 0.0:   # never read an unused parent: 0 * NaN would poison the sum
            l_k = parent[q]
            acc = acc + wk * l_k
            total = total + wk
            if fit != 0:
                du = screen_normal(cam, gb.normal[pi]) - u_c
                s_u = s_u + wk * du
                s_uu = s_uu + wk * wp.vec3(du[0] * du[0], du[0] * du[1], du[1] * du[1])
                s_ul_x = s_ul_x + (wk * du[0]) * l_k
                s_ul_y = s_ul_y + (wk * du[1]) * l_k
                lo = wp.min(lo, l_k)
                hi = wp.max(hi, l_k)
    if given == 0:
        weights[t] = w
    if level == 0 and n_v <= 0.0:
        # the eye lies below the pixel's shading normal's horizon (normals interpolated across a silhouette): the
        # estimator gives such a pixel no radiance (warpbw.shading: wo[2] <= 0), and nor does its up-sampling
        out[t] = wp.vec3(0.0)
        out_valid[t] = 1
        return
    if total < WEIGHT_MIN:
        needs_shading[t] = 1
        return
    mean = acc / total
    # the fit's clamp to [lo, hi] would turn a non-finite parent into a finite guess: such a mean is kept as it is
    if fit != 0 and wp.isfinite(mean[0]) and wp.isfinite(mean[1]) and wp.isfinite(mean[2]):
        mean = normal_fit(mean, total, s_u, s_uu, s_ul_x, s_ul_y, lo, hi)
    out[t] = mean
    out_valid[t] = 1


# ---------------------------------------------------------------------------------------------
# Host side
# ---------------------------------------------------------------------------------------------

def level_size(width: int, height: int, level: int) -> tuple[int, int]:
    """Size of pyramid level ``level`` (0 = finest): ceil-halving per level."""
    width = check_count(width, "width", 1)     # 0 or -8 came out as 1, 7.5 as 8, "7" a TypeError
    height = check_count(height, "height", 1)
    s = 1 << check_count(level, "level", 0)    # -1 failed on a negative shift, 2.7 ran as 2
    return max(1, -(-width // s)), max(1, -(-height // s))


def top_level(width: int, height: int) -> int:
    """Index of the pyramid's 1 x 1 level (``level_size`` halves until then); 0 for a 1 x 1 image."""
    return (max(check_count(width, "width", 1), check_count(height, "height", 1)) - 1).bit_length()


@dataclass
class UpsampleResult:
    values: wp.array          # (w_L * h_L,) vec3: up-sampled values where ``valid``
    valid: wp.array           # (w_L * h_L,) int32: 1 where a value was written
    needs_shading: wp.array   # (w_L * h_L,) int32: 1 where no parent could be used
    weights: wp.array         # (w_L * h_L,) vec4: the four parent weights (unnormalised)


def _i32(a, name: str, n: int, device, what: str) -> wp.array:
    if isinstance(a, wp.array):
        return check_warp_array(a, name, wp.int32, n, device, what)
    a = numeric_array(a, name, f"{n} flags ({what})")   # strings: numpy's ValueError
    if a.size != n:
        raise WarpbwError(f"{name}: expected {n} flags ({what}), got an array of shape {a.shape}")
    if not np.all((a == 0) | (a == 1)):   # cast to int32, 2**32 read 0 (nothing done) and 0.5 read 0
        raise WarpbwError(f"{name}: expected flags of 0 or 1 ({what}), got other values")
    return wp.array(np.ascontiguousarray(a.astype(np.int32).reshape(n)), dtype=wp.int32, device=device)


def _gbuffer_data(gb) -> GBufferData:
    """The GBufferData the kernel takes, from a GBuffer or itself; anything else a one-line ``WarpbwError``."""
    data = gb.data if isinstance(gb, GBuffer) else gb
    if not isinstance(data, GBufferData.cls):
        raise WarpbwError(f"gb: expected a GBuffer or its GBufferData, got {type(gb).__name__}")
    return data


def check_upsample_mode(mode: str) -> int:
    """The kernel's ``fit`` flag for an up-sampling mode name (``UPSAMPLE_MODES``)."""
    if mode not in UPSAMPLE_MODES:
        raise WarpbwError(f"upsample: expected one of {', '.join(UPSAMPLE_MODES)}, got {mode!r}")
    return int(mode == "normal")


def upsample_level(gb: GBuffer | GBufferData, cam: CameraData, level: int, parent_values, parent_valid, todo,
                   out: wp.array | None = None, out_valid: wp.array | None = None,
                   device: str = "cpu", mode: str = UPSAMPLE_DEFAULT,
                   weights: wp.array | None = None) -> UpsampleResult:
    """Up-sample the pixels of level ``level`` marked in ``todo`` from level ``level + 1``.

    ``gb``: the G-buffer (a ``GBuffer`` or its ``GBufferData``); ``level``: from 0 to ``top_level``.
    ``parent_values`` ((w_{L+1} h_{L+1},) vec3) and ``parent_valid`` (int32) describe the parent level;
    ``out`` / ``out_valid`` (level L) are updated in place when given (pixels not in ``todo`` keep theirs).
    Every array must have its level's size (a Warp array also its dtype and ``device``), else a ``WarpbwError``.
    ``mode``: "normal" (the weights' least-squares fit in the normal) or "paper" (their weighted mean).
    ``weights``: the w_i of an earlier call with the same ``parent_valid`` and ``todo`` (its
    ``UpsampleResult.weights``), read instead of computed again.
    A non-finite parent value propagates to the pixels that give it weight (nothing replaces it with a guess).
    (The hierarchy's parents are shaded values, which are finite: the shading drops a non-finite sample and
    counts it, ``warpbw.shading``.)
    """
    check_device(device)
    fit = check_upsample_mode(mode)
    gb = _gbuffer_data(gb)
    check_camera_of(cam, gb, "upsample_level")
    # up to the 1 x 1 top (whose parent is itself, clamped); 99 ran, shifting an int32 past its width in the kernel
    level = check_count(level, f"level (of a {gb.width}x{gb.height} G-buffer)", 0, top_level(gb.width, gb.height))
    w, h = level_size(gb.width, gb.height, level)
    pw, ph = level_size(gb.width, gb.height, level + 1)
    n, pn = w * h, pw * ph
    at, parent_at = f"level {level}, {w}x{h}", f"level {level + 1}, {pw}x{ph}"
    if isinstance(parent_values, wp.array):
        check_warp_array(parent_values, "parent_values", wp.vec3, pn, device, parent_at)
    else:
        parent_values = numeric_array(parent_values, "parent_values", f"{pn} RGB values").astype(np.float32)
        if parent_values.size != pn * 3:
            raise WarpbwError(f"parent_values: expected {pn} RGB values ({parent_at}), got an array of shape "
                              f"{parent_values.shape}")
        parent_values = wp.array(parent_values.reshape(pn, 3), dtype=wp.vec3, device=device)
    parent_valid = _i32(parent_valid, "parent_valid", pn, device, parent_at)
    todo = _i32(todo, "todo", n, device, at)
    out = (wp.zeros(n, dtype=wp.vec3, device=device) if out is None
           else check_warp_array(out, "out", wp.vec3, n, device, at))
    out_valid = (wp.zeros(n, dtype=wp.int32, device=device) if out_valid is None
                 else check_warp_array(out_valid, "out_valid", wp.int32, n, device, at))
    needs = wp.zeros(n, dtype=wp.int32, device=device)
    given = int(weights is not None)
    weights = (check_warp_array(weights, "weights", wp.vec4, n, device, at) if given
               else wp.zeros(n, dtype=wp.vec4, device=device))
    wp.launch(upsample_level_kernel, dim=n,
              inputs=[gb, cam, int(level), w, h, pw, ph, parent_values, parent_valid, todo, fit, given, out,
                      out_valid, needs, weights], device=device)
    return UpsampleResult(out, out_valid, needs, weights)


def parent_weights(gb: GBuffer | GBufferData, cam: CameraData, level: int, device: str = "cpu") -> np.ndarray:
    """The four parent weights of every pixel of ``level`` with every parent valid, (h_L, w_L, 4)."""
    check_device(device)
    data = _gbuffer_data(gb)
    w, h = level_size(data.width, data.height, level)
    pw, ph = level_size(data.width, data.height, level + 1)
    r = upsample_level(data, cam, level, np.zeros((pw * ph, 3)), np.ones(pw * ph), np.ones(w * h), device=device)
    return r.weights.numpy().reshape(h, w, 4)
