"""Where the filtered methods' error comes from (issue 4): the mip footprint's floor, and the GMM's merge.

    python examples/filtering_floor.py SCENE.toml [SCENE.toml ...] [--zoom 8,16,32] [--max-anisotropy N]
                                       [--json OUT.json] [--plot OUT.png] [--force]

For scenes with one normal-mapped plane under directional lights (those of ``examples/filtering_scenes.py``),
at each zoom, the error against the ground truth (``warpbw.bench_filtering.colour_error``, the benchmark's
metric) of the five filtered methods and of three references that no method can be asked to beat by much:

* ``floor``: every finest-level texel normal under the mip filter's trilinear weights (the same level and
  position as the methods, ``warpbw.filtering``), each shaded with the fine-scale BRDF -- the exact normal
  distribution of the filter's footprint, no NDF model at all.  What is left is the footprint itself: a
  trilinear tent of box-filtered texels is not the pixel's box, and texel centres are not the bilinear
  normal field the ground truth's rays hit.  It is the error of a perfect NDF model at the footprint every
  method filters at.  A method lands below it where its model's errors offset the footprint's: where a pixel
  covers few texels (the carved disk at zoom 8, level 0.4), the wide lobes of a moment-matched blend stand in
  for the normals between texel centres that the ground truth's bilinear normal field has.  Where a pixel
  covers many (the benchmark surfaces at zooms 16 and 32) no method does, and ``floor / toksvig`` is about
  the lowest ratio issue 4's "at most half of Toksvig's" check can show on that surface.
* ``floor_bilinear``: the same footprint over the normal field the ground truth's rays hit, bilinear between
  texel centres (``field_normals``, ``BILINEAR_SUB``^2 samples per texel).  Across a sharp edge (a scale's
  rim, a groove's wall) that field sweeps through normals no texel holds, and where a light's half-vector falls
  in such a sweep the texel-centre ``floor`` misses light the ground truth sees: there a method whose lobes are
  wider than a texel's single normal lands below ``floor`` (the scales under a 20-degree camera at zoom 32:
  floor .54, floor_bilinear .13, the aligned GMM .39).  Every mipmap here is built from texel-centre normals
  (004 Sec. 4.1 fits "the normals of its footprint at the finest level"); floor - floor_bilinear is what that
  costs at the footprint.
* ``gmm_per_tap``: the aligned GMM's eight texels of the trilinear footprint (4 per level, 2 levels) shaded
  as separate mixtures (8 K lobes), instead of first merging corresponding components by moments
  (004 Sec. 4.2).  The difference to ``gmm_aligned`` is what interpolating the components costs -- or gains:
  the merged lobe is wider than each tap's, and on the hemispherical scales at zoom 32 the merged mixture is
  the closer of the two (docs/measurements.md, "The floor under every mipmapped method").

With ``--max-anisotropy N`` (``warpbw.filtering``'s anisotropic footprints, not in 004) every method renders
with up to N probes along each footprint's major axis, and both references filter at the same probes: each
probe a trilinear footprint of the probe's level, the probes weighted equally (``footprint_probes``).  The
row's ``mean_probes`` says how many a pixel took on average.

All three are numpy, written from ``warpbw.filtering``'s documentation; ``gmm_merged_check`` re-derives the
renderer's own ``gmm_aligned`` image the same way and reports its largest deviation (float32 rounding).
Prints a table per scene and, with ``--json`` / ``--plot`` (as ``warpbw bench``'s: the one not given goes beside
the other; existing files are kept unless --force, refused before any work), writes them all (a list, one record
per scene) and the plot of every method's error and the references against zoom, one panel per scene.  A scene
whose every light lies at or below the plane's horizon (every figure 0) is refused before any work; a zoom at which
the ground truth is black over every pixel compared (a mirror's highlight out of view) is left out, saying so.
"""
from __future__ import annotations

from warpbw.entry import interrupt_in_one_line

interrupt_in_one_line(__name__)   # first: a Ctrl-C while the imports below load says one line, no traceback

import argparse
import math
import sys
from pathlib import Path

import numpy as np

from warpbw.cli_common import OneLineParser, check_record_outputs, init_warp, run_command, write_record
from warpbw.errors import INT32_MAX
# the renderer's own constants: the references filter and shade at its footprint, with its floors
from warpbw.filtering import (ANISO_PROBE_SLACK, DEFAULT_ANISOTROPY, LOD_BIAS, MAX_ANISOTROPY, MIN_COS, MIN_GT_SPP,
                               VARIANCE_FLOOR, roughness_variance)

DEFAULT_ZOOMS = "8,16,32"
DEFAULT_GT_SPP = 1024
GT_SEED = 1_000_003              # warpbw.bench_filtering's ground-truth seed (seed 0)
# floor_bilinear: the ground truth's bilinear normal field sampled this many times per finest texel and axis.
BILINEAR_SUB = 4
# Finest normals gathered per batch of pixels (bounds the memory of the floor: a level-l texel holds 4^l).
BATCH_NORMALS = 1 << 21


def _plane_frame(v):
    """World -> the plane's tangent frame (x = +X, y = -Z, z = +Y)."""
    return np.stack([v[..., 0], -v[..., 2], v[..., 1]], -1)


def _pixels(scene, camera, shape):
    """Flat indices of the pixels whose centre ray hits the plane (and whose neighbours' rays hit its supporting
    plane), their finest-texel coordinates (s, t), the footprint's Jacobian columns (jx, jy) (finest texels per
    pixel right and down) and wo in the plane frame."""
    from warpbw.gbuffer import camera_rays, scene_camera

    (pl,) = scene.objects
    mat = scene.materials[pl.material]
    cam = scene_camera(camera)
    o, d = camera_rays(cam)
    o = o[0]
    right = np.array(list(cam.right)) * (2.0 * cam.tan_half_x / camera.width)
    down = -np.array(list(cam.up)) * (2.0 * cam.tan_half_y / camera.height)
    raw = d / np.linalg.norm(d, axis=-1, keepdims=True)

    def hit(ray):
        t = (pl.center[1] - o[1]) / ray[:, 1]
        xz = (o + t[:, None] * ray)[:, [0, 2]] - np.array([pl.center[0], pl.center[2]])
        inside = (t > 0) & np.all(np.abs(xz) <= pl.size / 2, axis=-1)
        return (xz / pl.size + 0.5) * mat.tiling * np.array([shape[1], shape[0]]), t, inside

    # the rays through the next pixel right and down: the centre ray with a unit forward component, plus one
    # pixel's step along the image axes
    base = raw / (raw @ np.array(list(cam.forward)))[:, None]
    st, t, inside = hit(raw)
    stx, tx, _ = hit(base + right)
    sty, ty, _ = hit(base + down)
    idx = np.flatnonzero(inside & (tx > 0) & (ty > 0))
    return idx, st[idx], (stx - st)[idx], (sty - st)[idx], _plane_frame(-raw[idx])


def footprint_probes(jx, jy, max_aniso: int):
    """``warpbw.filtering.pixel_footprint`` in numpy: per pixel the level lam (unclamped), the number of probes
    n along the major axis and the step (P, 2) between them, in finest texels.  Isotropic (max_aniso = 1): one
    probe at log2 of J's longer column + the LOD bias.  Otherwise J J^T's eigen-axes s1 >= s2, probes of radius
    r = max(s2, s1 / max_aniso, 2^-LOD_BIAS), n = ceil(s1 / r) of them spaced so that their spread and their own
    r^2 / 12 add up to the pixel box's s1^2 / 12."""
    rho = np.maximum(np.linalg.norm(jx, axis=-1), np.linalg.norm(jy, axis=-1))
    n = np.ones(rho.shape, int)
    step = np.zeros(jx.shape)
    if max_aniso > 1:
        jjt = np.einsum("pi,pj->pij", jx, jx) + np.einsum("pi,pj->pij", jy, jy)
        e, v = np.linalg.eigh(jjt)                       # ascending: e[:, 1] = s1^2, v[:, :, 1] its axis
        s1, s2 = np.sqrt(np.maximum(e[:, 1], 0.0)), np.sqrt(np.maximum(e[:, 0], 0.0))
        radius = np.maximum(np.maximum(s2, s1 / max_aniso), 2.0 ** -LOD_BIAS)
        n_a = np.clip(np.ceil(s1 / radius - ANISO_PROBE_SLACK).astype(int), 1, max_aniso)
        many = n_a > 1
        n = np.where(many, n_a, 1)
        rho = np.where(many, radius, rho)
        d = np.sqrt(np.maximum(s1 * s1 - radius * radius, 0.0) / np.maximum(n * n - 1, 1))
        step = np.where(many[:, None], v[:, :, 1] * d[:, None], 0.0)
    return np.log2(np.maximum(rho, 1e-6)) + LOD_BIAS, n, step


def _shade(mat, lights, wo, a, mx, my, var):
    """Radiance (P, 3) of lobes (P, J) of isotropic per-axis variance var under the directional lights
    (004 Sec. 3: Cook-Torrance with a Gaussian NDF per lobe, Schlick, no shadowing; Lambert on the means)."""
    f0, diffuse = np.asarray(mat.f0), np.asarray(mat.diffuse)
    nz = np.sqrt(np.maximum(1.0 - mx * mx - my * my, 0.0))
    out = np.zeros((wo.shape[0], 3))
    for light in lights:
        wi = _plane_frame(np.asarray(light.direction, float) / np.linalg.norm(light.direction))
        if wi[2] <= 0:
            continue
        h = wi + wo
        h /= np.linalg.norm(h, axis=-1, keepdims=True)
        F = f0 + (1 - f0) * (1 - np.clip(np.sum(wo * h, -1), 0, None))[:, None] ** 5
        ex, ey = h[:, :1] - mx, h[:, 1:2] - my
        D = np.sum(a * np.exp(-(ex * ex + ey * ey) / (2 * var)) / (2 * np.pi * var), -1)
        lamb = np.sum(a * np.maximum(mx * wi[0] + my * wi[1] + nz * wi[2], 0.0), -1)
        c = F * (D / (4 * np.maximum(wo[:, 2], MIN_COS)))[:, None] + diffuse / np.pi * (1 - F) * lamb[:, None]
        out += np.where(wo[:, 2:3] > MIN_COS, c, 0.0) * np.asarray(light.radiance)
    return out


def axis_base(lv, n_l, n: int, s):
    """``warpbw.filtering.axis_base`` in numpy: along one axis of n finest texels (n_l (P,) at levels lv (P,)), the
    level-l texel (P,) whose centre is the last at or before finest coordinate s (P,), and the fraction (0 to 1) of
    the way to the next, the map tiling with period n.  Level-l texel j covers finest texels [j 2^l,
    min((j + 1) 2^l, n)), centred on what of it the border leaves: where n is no power of two the last texel's
    centre is (c_last, below) and the texel after it is texel 0 of the next tile (texel centres at (j + 1/2) 2^l
    read another texel's footprint there, 0.18 of the mean colour off the renderer on a 100x100 map)."""
    f = 2.0 ** lv
    x = s / f - 0.5
    x0 = np.floor(x)
    fx = x - x0
    clipped = n_l * 2 ** lv != n
    if clipped.any():
        u = s - np.floor(s / n) * n                       # s in the first tile
        last = n_l - 1.0
        c_last = 0.5 * (last * f + n)                     # the clipped last texel's centre
        before, after = u < 0.5 * f, u >= c_last
        inner = np.floor(u / f - 0.5)
        c0 = (inner + 0.5) * f
        with np.errstate(divide="ignore", invalid="ignore"):   # each branch where it applies (np.where computes all)
            fx_c = np.where(before, (u - (c_last - n)) / (0.5 * f + n - c_last),
                            np.where(after, (u - c_last) / (n + 0.5 * f - c_last),
                                     np.where(inner == last - 1.0, (u - c0) / (c_last - c0), u / f - 0.5 - inner)))
        x0_c = np.where(before, -1.0, np.where(after, last, inner))
        x0 = np.where(clipped, x0_c, x0)
        fx = np.where(clipped, np.clip(fx_c, 0.0, 1.0), fx)
    return x0.astype(int), fx


def _taps(st, lam, shapes, n=None, step=None):
    """The texels the filter reads per pixel: (level (P,), column, row, weight) for each.  One probe: the
    trilinear filter's eight texels.  ``n`` probes (P,) spaced ``step`` (P, 2) apart along the major axis,
    centred on st (``warpbw.filtering.probe_offset``): eight per probe, each probe weighted 1 / n (a pixel with
    fewer probes than the most gets weight 0 from the others)."""
    top = len(shapes) - 1
    l0 = np.floor(lam).astype(int)
    fl = lam - l0
    if n is None:
        n, step = np.ones(st.shape[0], int), np.zeros(st.shape)
    for j in range(int(n.max())):
        p = st + ((j - 0.5 * (n - 1)) * (j < n))[:, None] * step
        wj = (j < n) / n
        for lv, wl in ((l0, 1.0 - fl), (np.minimum(l0 + 1, top), fl)):
            hw = np.array(shapes)[lv]
            x0, fx = axis_base(lv, hw[:, 1], shapes[0][1], p[:, 0])
            y0, fy = axis_base(lv, hw[:, 0], shapes[0][0], p[:, 1])
            for dc, dr, w in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy),
                              (1, 1, fx * fy)):
                yield lv, (x0 + dc) % hw[:, 1], (y0 + dr) % hw[:, 0], w * wl * wj


def field_normals(normals, r, c, f: int):
    """The ground truth's normal field at sub-texel (r, c) of an f x f grid per finest texel (integer arrays of
    one shape, within the map): the bilinear blend of the four texel normals nearest the sub-texel's centre
    (texel centres at half-integers, the map tiled), renormalised, as ``warpbw.filtering``'s ground truth
    fetches it.  f = 1: the texel normals themselves."""
    if f == 1:
        return normals[r, c]
    H, W = normals.shape[:2]
    x, y = (c + 0.5) / f - 0.5, (r + 0.5) / f - 0.5
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]

    def at(dy, dx):
        return normals[(y0 + dy) % H, (x0 + dx) % W]

    n = (1 - fy) * ((1 - fx) * at(0, 0) + fx * at(0, 1)) + fy * ((1 - fx) * at(1, 0) + fx * at(1, 1))
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def floor_image(mat, lights, normals, shapes, st, lam, wo, n=None, step=None, sub: int = 1):
    """Every finest normal of each tap's footprint (a level-l texel covers 2^l x 2^l of them, clipped at the
    border), weighted by the tap's weight, shaded with the fine-scale BRDF (``_taps``: n probes per pixel).
    ``sub`` > 1: the ground truth's normal field sampled ``sub`` x ``sub`` times per finest texel instead
    (``field_normals``): a level-l texel covers (2^l sub)^2 of those samples."""
    H, W = normals.shape[0] * sub, normals.shape[1] * sub
    rv = roughness_variance(mat.roughness)
    out = np.zeros((st.shape[0], 3))
    for lv, col, row, w in _taps(st, lam, shapes, n, step):
        for l in np.unique(lv):
            b = 2 ** int(l) * sub
            oy, ox = (g.ravel() for g in np.meshgrid(np.arange(b), np.arange(b), indexing="ij"))
            sel_all = np.flatnonzero(lv == l)
            batch = max(1, BATCH_NORMALS // (b * b))
            for start in range(0, sel_all.size, batch):
                sel = sel_all[start:start + batch]
                r = row[sel, None] * b + oy[None]
                c = col[sel, None] * b + ox[None]
                ok = (r < H) & (c < W)
                nrm = field_normals(normals, np.minimum(r, H - 1), np.minimum(c, W - 1), sub)
                a = ok / ok.sum(1, keepdims=True)
                out[sel] += w[sel, None] * _shade(mat, lights, wo[sel], a, nrm[..., 0], nrm[..., 1], rv)
    return out


def _recover(q, rv):
    """Stored moments -> (a, mu_x, mu_y, per-axis variance of the lobe): the builder's recovery, the renderer's
    floor taken off and the roughness added (``warpbw.filtering``)."""
    from precompute.gmm_mipmap import from_moments

    a, mu, s2 = from_moments(q)
    return a, mu[..., 0], mu[..., 1], s2 - VARIANCE_FLOOR + rv


def gmm_images(mat, lights, levels, st, lam, wo, n=None, step=None):
    """(per tap, merged): the aligned GMM's taps as separate mixtures, and merged by moments (the renderer:
    its probes' trilinear moments averaged, then recovered)."""
    rv = roughness_variance(mat.roughness)
    shapes = [q.shape[:2] for q in levels]
    K = levels[0].shape[2]
    merged = np.zeros((st.shape[0], K, 4))
    lobes = []
    for lv, col, row, w in _taps(st, lam, shapes, n, step):
        q = np.zeros((st.shape[0], K, 4))
        for l in np.unique(lv):
            sel = lv == l
            q[sel] = levels[l][row[sel], col[sel]]
        merged += w[:, None, None] * q
        a, mx, my, var = _recover(q, rv)
        lobes.append((w[:, None] * a, mx, my, var))
    per_tap = _shade(mat, lights, wo, *(np.concatenate([lb[i] for lb in lobes], 1) for i in range(4)))
    return per_tap, _shade(mat, lights, wo, *_recover(merged, rv))


def load_checked(path: Path, zooms, max_anisotropy: int = DEFAULT_ANISOTROPY) -> tuple:
    """The scene at ``path``, its plane, material, finest normals and level shapes, once it is known that the
    analysis can run on it: one plane under directional lights, a normal map, and a zoom at which some pixel
    filters at level 0 or above.  ``main`` checks every scene so before the first analysis."""
    from precompute.surfaces import height_to_normals
    from precompute.gmm_mipmap import level_shapes, load_map
    from warpbw.errors import WarpbwError
    from warpbw.filtering import zoomed_camera
    from warpbw.scene import PlaneObject, load_scene

    scene = load_scene(path)
    if (len(scene.objects) != 1 or not isinstance(scene.objects[0], PlaneObject) or scene.environment is not None
            or not scene.lights):
        raise WarpbwError(f"{path}: expected one plane under directional lights and no [environment] "
                          "(the numpy references shade directional lights only)")
    if not any(light.direction[1] > 0.0 and max(light.radiance) > 0.0 for light in scene.lights):
        # the plane faces +Y: every figure 0, and the table's ratios to Toksvig's error a ZeroDivisionError
        raise WarpbwError(f"{path}: every [[light]] lies at or below the plane's horizon, or is black: the plane is "
                          "black in every method and in the ground truth, nothing to compare (expected a light above "
                          "the plane)")
    (pl,) = scene.objects
    mat = scene.materials[pl.material]
    if mat.normal_map is None:
        raise WarpbwError(f"{path}: [material.{pl.material}] has no normal_map: there is nothing to filter")
    data = load_map(mat.normal_map, mat.normal_map_kind)
    normals = height_to_normals(data, mat.normal_map_scale) if mat.normal_map_kind == "height" else data
    shapes = level_shapes(*normals.shape[:2])
    # a zoom whose pixels are all smaller than a finest texel (level < 0) has nothing to compare: refused before the
    # mipmaps are built and the ground truth rendered, when that holds for every zoom asked for
    levels = [footprint_probes(*_pixels(scene, zoomed_camera(scene.camera, z), shapes[0])[2:4], max_anisotropy)[0]
              for z in zooms]
    if not any(lam.size for lam in levels):   # the plane smaller than a pixel: the rule below would ask for more zoom
        raise WarpbwError(f"{path}: at --zoom {','.join(f'{z:g}' for z in zooms)} no pixel's centre ray hits the "
                          "plane: nothing to compare (expected smaller zooms, which bring the camera closer)")
    if not any((lam >= 0).any() for lam in levels):
        raise WarpbwError(f"{path}: at --zoom {','.join(f'{z:g}' for z in zooms)} no pixel that sees the plane filters "
                          f"at level 0 or above (a pixel covers less than a texel of the {shapes[0][1]}x{shapes[0][0]} "
                          "map): nothing to compare (expected larger zooms, which move the camera away)")
    return scene, pl, mat, normals, shapes


def analyse(path: Path, zooms, gt_spp: int, log=print, max_anisotropy: int = DEFAULT_ANISOTROPY,
            loaded: tuple | None = None) -> dict:
    """The analysis of one scene (module docstring); ``loaded``: its ``load_checked``, when already done."""
    from warpbw.bench_filtering import colour_error
    from warpbw.filtering import METHODS, prepare_filtering, render_filtering, zoomed_camera

    scene, pl, mat, normals, shapes = loaded if loaded is not None else load_checked(path, zooms, max_anisotropy)
    prep = prepare_filtering(scene, METHODS + ("ground_truth",))
    mp = prep.mips[pl.material]
    flat, K = mp.gmm["gmm_aligned"]
    flat = flat.numpy()
    off = mp.loff.numpy()                                  # each level's first texel in the flat array
    levels = [flat[o * K:(o + h * w) * K].reshape(h, w, K, 4) for o, (h, w) in zip(off, shapes)]
    rows = []
    for z in zooms:
        cam = zoomed_camera(scene.camera, z)
        gt = render_filtering(scene, "ground_truth", spp=gt_spp, seed=GT_SEED, prepared=prep, camera=cam)
        row = {"zoom": z}
        imgs = {m: render_filtering(scene, m, prepared=prep, camera=cam, max_anisotropy=max_anisotropy).image
                for m in METHODS}
        idx, st, jx, jy, wo = _pixels(scene, cam, shapes[0])
        lam, n, step = footprint_probes(jx, jy, max_anisotropy)
        lam_f = np.clip(lam, 0.0, len(shapes) - 1)
        if (lam < 0).any():
            log(f"  zoom {z:g}: {int((lam < 0).sum())} magnified pixels (level < 0) left out of every figure")
        keep = lam >= 0
        idx, st, lam_f, wo, n, step = idx[keep], st[keep], lam_f[keep], wo[keep], n[keep], step[keep]
        if idx.size == 0:
            log(f"  zoom {z:g}: no pixel filters at level 0 or above: nothing to compare")
            continue
        mask = np.zeros(gt.coverage.size, bool)
        mask[idx] = True
        mask = mask.reshape(gt.coverage.shape) & gt.coverage
        if not np.any(gt.image[mask]):   # every error relative to a mean of 0 (a mirror's highlight out of view)
            log(f"  zoom {z:g}: the ground truth is black at every pixel compared: nothing to compare")
            continue

        def as_image(vals):
            img = np.zeros((gt.coverage.size, 3))
            img[idx] = vals
            return img.reshape(gt.image.shape)

        for m in METHODS:
            row[m] = colour_error(imgs[m], gt.image, mask)
        row["floor"] = colour_error(as_image(floor_image(mat, scene.lights, normals, shapes, st, lam_f, wo, n, step)),
                                    gt.image, mask)
        row["floor_bilinear"] = colour_error(as_image(floor_image(mat, scene.lights, normals, shapes, st, lam_f, wo,
                                                                  n, step, sub=BILINEAR_SUB)), gt.image, mask)
        per_tap, merged = gmm_images(mat, scene.lights, levels, st, lam_f, wo, n, step)
        row["gmm_per_tap"] = colour_error(as_image(per_tap), gt.image, mask)
        scale = float(np.linalg.norm(gt.image[mask], axis=-1).mean())
        row["gmm_merged_check"] = float(np.abs(as_image(merged)[mask] - imgs["gmm_aligned"][mask]).max() / scale)
        row["pixels"] = int(mask.sum())
        row["mean_level"] = float(lam_f.mean())
        row["mean_probes"] = float(n.mean())
        rows.append(row)
    return {"scene": str(path), "gt_spp": gt_spp, "components": int(K), "max_anisotropy": int(max_anisotropy),
            "zooms": rows}


def format_table(rec: dict) -> str:
    cols = ("gmm_aligned", "gmm_unaligned", "toksvig", "lean", "fixed", "gmm_per_tap", "floor", "floor_bilinear")
    aniso = rec.get("max_anisotropy", 1)
    lines = [f"{rec['scene']}: error against the ground truth ({rec['gt_spp']} rays/pixel), K = {rec['components']}"
             + (f", up to {aniso} probes per footprint" if aniso > 1 else ""),
             f"{'zoom':>5} {'level':>6} {'probes':>6}" + "".join(f"{c:>{max(14, len(c) + 2)}}" for c in cols)
             + f"{'aligned/toks':>14}{'floor/toks':>12}{'check':>9}"]
    for r in rec["zooms"]:
        lines.append(f"{r['zoom']:>5g} {r['mean_level']:>6.2f} {r['mean_probes']:>6.2f}"
                     + "".join(f"{r[c]:>{max(14, len(c) + 2)}.4f}" for c in cols)
                     + f"{r['gmm_aligned'] / r['toksvig']:>14.2f}{r['floor'] / r['toksvig']:>12.2f}"
                     + f"{r['gmm_merged_check']:>9.1e}")
    return "\n".join(lines)


def write_plot(records: list, path) -> None:
    """Per scene, the error against the ground truth against zoom: one line per method, the references dashed."""
    from matplotlib.figure import Figure

    from warpbw.filtering import METHODS

    fig = Figure(figsize=(5.5 * len(records), 4.2))   # not pyplot's: nothing to close, the caller's backend kept
    axes = fig.subplots(1, len(records), squeeze=False)
    for ax, rec in zip(axes[0], records):
        rows = sorted(rec["zooms"], key=lambda r: r["zoom"])   # along the zoom (--zoom 4,1,2 drew 4 -> 1 -> 2)
        zooms = [r["zoom"] for r in rows]
        for c in (*METHODS, "gmm_per_tap", "floor", "floor_bilinear"):
            ax.plot(zooms, [r[c] for r in rows], "o-" if c in METHODS else "x--", label=c)
        ax.set_xscale("log", base=2)
        ax.set_xlabel("zoom (camera distance factor)")
        ax.set_ylabel(f"error against the ground truth ({rec['gt_spp']} rays/pixel)")
        ax.set_title("/".join(Path(rec["scene"]).parts[-2:]), fontsize=10)   # graze20/scales, filtering/scales
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv=None) -> int:
    ap = OneLineParser(description=__doc__.split("\n\n")[0],
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       epilog="The scenes: python examples/filtering_scenes.py --out DIR (DIR/*.toml).")
    ap.add_argument("scenes", nargs="+", type=Path, help="scene files: one normal-mapped plane, directional lights")
    ap.add_argument("--zoom", default=DEFAULT_ZOOMS, help=f"zoom factors (default {DEFAULT_ZOOMS})")
    ap.add_argument("--gt-spp", type=int, default=DEFAULT_GT_SPP,
                    help=f"ground-truth rays per pixel (default {DEFAULT_GT_SPP}, at least 64)")
    ap.add_argument("--max-anisotropy", type=int, default=DEFAULT_ANISOTROPY, metavar="N",
                    help=f"up to N probes along each footprint's major axis, for the methods and both references "
                         f"(default {DEFAULT_ANISOTROPY}: isotropic, 004; at most {MAX_ANISOTROPY})")
    ap.add_argument("--json", type=Path, help="write every table here; without it, beside --plot as OUT.json")
    ap.add_argument("--plot", type=Path, help="write the plot here (PNG): each scene's errors against zoom; "
                    "without it, beside --json as OUT.png")
    ap.add_argument("--force", action="store_true", help="overwrite --json and --plot if they exist")
    args = ap.parse_args(argv)
    try:
        zooms = [float(z) for z in args.zoom.split(",") if z.strip()]
    except ValueError:
        ap.error(f"--zoom {args.zoom!r}: expected comma-separated positive numbers, e.g. 8,16,32")
    if not zooms or not all(z > 0 and math.isfinite(z) for z in zooms):
        ap.error(f"--zoom {args.zoom!r}: expected comma-separated positive numbers, e.g. 8,16,32")
    twice = sorted({z for z in zooms if zooms.count(z) > 1})
    if twice:   # each zoom is one measurement: a repeat would only render it again
        ap.error(f"--zoom {args.zoom!r}: expected distinct values, got {', '.join(f'{z:g}' for z in twice)} more "
                 "than once")
    if not 1 <= args.max_anisotropy <= MAX_ANISOTROPY:
        ap.error(f"--max-anisotropy {args.max_anisotropy}: expected an integer from 1 to {MAX_ANISOTROPY}")
    if not MIN_GT_SPP <= args.gt_spp <= INT32_MAX:   # the shading kernels count rays in int32
        ap.error(f"--gt-spp {args.gt_spp}: expected from {MIN_GT_SPP} to {INT32_MAX} rays per pixel")
    for p in args.scenes:
        if not p.is_file():
            ap.error(f"{p}: no such scene file")
    # before the analysis: a directory, under a file, a scene, or kept without --force
    json_path, plot_path = check_record_outputs(args.json, args.plot, args.force, inputs=args.scenes)

    init_warp("cpu")           # Warp's no-CUDA-driver line, banner and module-load lines kept off the output
    # every scene checked before the first is analysed (a later one failed after minutes of work, and no JSON)
    loaded = [load_checked(p, zooms, args.max_anisotropy) for p in args.scenes]
    records = []
    for p, ld in zip(args.scenes, loaded):
        rec = analyse(p, zooms, args.gt_spp, max_anisotropy=args.max_anisotropy, loaded=ld)
        print(format_table(rec), flush=True)
        records.append({**rec, "device": "cpu"})
    if json_path is not None:   # both or neither: a full disk leaves the old record
        write_record(json_path, plot_path, records, write_plot, force=args.force)
    return 0


if __name__ == "__main__":
    sys.exit(run_command("filtering_floor.py", lambda _: main(), None))
