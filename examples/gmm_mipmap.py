"""GMM normal mipmaps, aligned against unaligned, like 004 Fig. 5: the mixtures of a 2x2 block of texels,
the mixture the renderer's trilinear filter makes of them midway between their centres (the corner they
share; equal weights), and the true distribution of the finest normals of the four texels together (what that
mixture stands for: each texel a quarter, shared by its normals; where the border of a map of no power-of-two size
clips a texel, its fewer normals weigh more, and its centre, so the pixel, is off the corner).

    python examples/gmm_mipmap.py -o gmm_mipmap.png                      # hemispherical scales, 128x128
    python examples/gmm_mipmap.py -o dunes.png --surface dunes --size 128 --level 3

Each panel is the square root of the density of the normal distribution over the projected-normal disk (n_x right, n_y
up; the circle is the horizon; white at each panel's own 99.7th percentile, so a sharp peak saturates), the means of the
components of weight above 0.01 marked with their index; the truth shows each finest normal as a small Gaussian
(TRUTH_KERNEL_VAR).  Top row: the EM-aligned mipmap (004 Sec. 4.1, c = 1); bottom row: independent EM per texel (c = 0,
own initialisation).  Filtering interpolates component i with component i (004 Sec. 4.2): aligned components interpolate
into a distribution close to the truth, unaligned ones are averaged into lobes that are not there (004 Fig. 5c).
"""
from __future__ import annotations

from warpbw.entry import interrupt_in_one_line

interrupt_in_one_line(__name__)   # first: a Ctrl-C while the imports below load says one line, no traceback

import sys
from pathlib import Path

import numpy as np

from warpbw.cli_common import OneLineParser, check_overwrite, init_warp, run_command
from warpbw.io.staged import staged_outputs

DEFAULT_LEVEL = 3   # --level: a 2x2 block of level 3 covers 16x16 finest texels
DEFAULT_TEXEL = 1   # --texel ROW COL: the block one texel in from the corner
GRID = 161          # density image resolution over [-1, 1]^2


def density(params, grid=GRID):
    """Mixture density (grid, grid) of (K, 4) (a, mu_x, mu_y, s^2) over the projected disk (row 0 = n_y = +1)."""
    t = np.linspace(-1, 1, grid)
    X, Y = np.meshgrid(t, -t)
    d = np.zeros_like(X)
    for a, mx, my, s2 in params:
        if a > 0:
            d += a * np.exp(-((X - mx) ** 2 + (Y - my) ** 2) / (2 * s2)) / (2 * np.pi * s2)
    return d


# Per-axis variance of the kernel that turns the footprint's normals into a density for display (the
# normals themselves are points); about a material roughness of 0.1.
TRUTH_KERNEL_VAR = 0.005


def truth_density(n2, weights=None, grid=GRID):
    """The footprint's finest normals as a density: one small Gaussian per normal, of the given weights (summing to
    1; default equal)."""
    w = np.full(len(n2), 1.0 / len(n2)) if weights is None else np.asarray(weights, np.float64)
    p = np.concatenate([w[:, None], n2, np.full((len(n2), 1), TRUTH_KERNEL_VAR)], -1)
    return density(p, grid)


def texel_centre(j: int, level: int, n: int) -> float:
    """Finest coordinate of the centre of level-``level`` texel j along an axis of n finest texels: it covers
    [j 2^l, min((j + 1) 2^l, n)) (``warpbw.filtering.axis_base``: a texel the border clips has its clipped centre)."""
    f = 1 << level
    return 0.5 * (j * f + min((j + 1) * f, n))


def block(n2, level: int, r0: int, c0: int):
    """The 2x2 block of level-``level`` texels from (r0, c0) of the finest projected normals n2 (H, W, 2): the pixel
    (s, t) where the bilinear fetch weighs the four equally (midway between their centres), and the four texels'
    finest normals (M, 2) with their weights (M,): a quarter per texel, shared equally by its (clipped) footprint."""
    H, W = n2.shape[:2]
    f = 1 << level
    s = 0.5 * (texel_centre(c0, level, W) + texel_centre(c0 + 1, level, W))
    t = 0.5 * (texel_centre(r0, level, H) + texel_centre(r0 + 1, level, H))
    normals, weights = [], []
    for r in (r0, r0 + 1):
        for c in (c0, c0 + 1):
            n = n2[r * f:(r + 1) * f, c * f:(c + 1) * f].reshape(-1, 2)
            normals.append(n)
            weights.append(np.full(len(n), 0.25 / len(n)))
    return s, t, np.concatenate(normals), np.concatenate(weights)


def show(ax, d):
    ax.imshow(np.sqrt(d), extent=(-1, 1, -1, 1), cmap="magma", vmin=0,
              vmax=max(float(np.percentile(np.sqrt(d), 99.7)), 1e-12))


def main(argv=None) -> int:
    ap = OneLineParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-o", "--output", default="gmm_mipmap.png", help="output PNG (default gmm_mipmap.png)")
    ap.add_argument("--surface", default="hemispherical_scales",
                    help="procedural surface (precompute.surfaces; default hemispherical_scales)")
    ap.add_argument("--size", type=int, default=128, help="height-field size, 2 to 1024, at least 17 for "
                    "hemispherical_scales (default 128)")
    ap.add_argument("--level", type=int, default=None,
                    help=f"mip level of the 2x2 texel block (default {DEFAULT_LEVEL}, or the coarsest level of at "
                    "least 2x2 texels where --size has fewer levels)")
    ap.add_argument("--texel", type=int, nargs=2, default=None, metavar=("ROW", "COL"),
                    help=f"top-left texel of the block at that level (default {DEFAULT_TEXEL} {DEFAULT_TEXEL}, or 0 0 "
                    "where the level has only 2x2 texels)")
    ap.add_argument("--components", type=int, default=4, help="Gaussians per texel of both mipmaps (default 4)")
    ap.add_argument("--force", action="store_true", help="overwrite an existing output")
    args = ap.parse_args(argv)
    from precompute.gmm_mipmap import MAX_COMPONENTS, level_shapes
    from precompute.surfaces import MAX_SURFACE_SIZE, MIN_SURFACE_SIZE, SURFACES

    if Path(args.output).suffix.lower() != ".png":
        ap.error(f"-o {args.output}: expected a path ending in .png")
    check_overwrite([Path(args.output)], args.force)
    if args.surface not in SURFACES:
        ap.error(f"--surface {args.surface}: expected one of {', '.join(SURFACES)}")
    if not 2 <= args.size <= MAX_SURFACE_SIZE:
        ap.error(f"--size {args.size}: expected an integer from 2 to {MAX_SURFACE_SIZE}")
    if args.surface == "hemispherical_scales" and args.size < MIN_SURFACE_SIZE:   # else refused by its generator,
        # naming no option ("scales_across at most 3 (an argument from Python)")
        ap.error(f"--size {args.size}: expected an integer from {MIN_SURFACE_SIZE} to {MAX_SURFACE_SIZE} for "
                 f"hemispherical_scales (more than 2 texels per scale spacing; the other surfaces take 2 to "
                 f"{MAX_SURFACE_SIZE})")
    if not 1 <= args.components <= MAX_COMPONENTS:
        ap.error(f"--components {args.components}: expected an integer from 1 to {MAX_COMPONENTS}")
    sides = [hw[0] for hw in level_shapes(args.size, args.size) if hw[0] >= 2]   # levels with a 2x2 block
    if args.level is None:   # the defaults adapt to a small --size, which would otherwise refuse them
        args.level = min(DEFAULT_LEVEL, len(sides) - 1)
    if not 0 <= args.level < len(sides):
        ap.error(f"--level {args.level}: expected 0 to {len(sides) - 1} (levels of at least 2x2 texels at "
                 f"--size {args.size})")
    side = sides[args.level]
    if args.texel is None:
        args.texel = [min(DEFAULT_TEXEL, side - 2)] * 2
    if not all(0 <= t <= side - 2 for t in args.texel):
        ap.error(f"--texel {args.texel[0]} {args.texel[1]}: expected ROW and COL from 0 to {side - 2} "
                 f"(level {args.level} has {side}x{side} texels)")

    from matplotlib.figure import Figure
    from matplotlib.patches import Circle

    init_warp("cpu")           # Warp's no-CUDA-driver line kept off stderr
    from precompute.gmm_mipmap import build_gmm_mipmap, from_moments, normal_space
    from precompute.surfaces import height_to_normals
    from warpbw.filtering import fetch_gmm

    h = SURFACES[args.surface](args.size)
    n2 = normal_space(height_to_normals(h))
    mips = {"aligned (004 Sec. 4.1)": build_gmm_mipmap(h, components=args.components, progress=False),
            "unaligned (per-texel EM)": build_gmm_mipmap(h, components=args.components, unaligned=True,
                                                         progress=False)}
    l = args.level
    r0, c0 = args.texel
    # the pixel: midway between the four texels' centres (the corner they share), where bilinear filtering weighs
    # them equally; what the filtered mixture stands for is then the four texels' finest normals, a quarter each
    # (the corner was off the middle, and every normal weighed the same, where the border clips the last texel)
    s_c, t_c, foot, weights = block(n2, l, r0, c0)
    truth = truth_density(foot, weights)
    fig = Figure(figsize=(15, 5.4))   # not pyplot's: nothing to close, the caller's backend kept
    axes = fig.subplots(2, 6)
    for row, (name, mip) in enumerate(mips.items()):
        q = mip.levels[l]
        panels = []
        for dr in (0, 1):
            for dc in (0, 1):
                a, mu, s2 = from_moments(q[(r0 + dr) % q.shape[0], (c0 + dc) % q.shape[1]])
                panels.append((f"texel ({r0 + dr}, {c0 + dc})", np.concatenate([a[:, None], mu, s2[:, None]], -1)))
        filt = fetch_gmm(mip.levels, s_c, t_c, float(l))[0]
        panels.append(("filtered (004 Sec. 4.2)", filt))
        for ax, (title, p) in zip(axes[row], panels):
            show(ax, density(p))
            for i, (a, mx, my, _) in enumerate(p):
                if a > 0.01:
                    ax.text(mx, my, str(i), color="cyan", ha="center", va="center", fontsize=8)
            ax.set_title(title, fontsize=9)
        show(axes[row][5], truth)
        axes[row][5].set_title(f"truth: the four texels' {len(foot)} finest normals", fontsize=9)
        axes[row][0].set_ylabel(name, fontsize=10)
    for ax in axes.ravel():
        ax.add_patch(Circle((0, 0), 1.0, fill=False, color="w", lw=0.5))
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle(f"{args.surface} {args.size}x{args.size}, level {l}: GMM of four texels and their filtered "
                 "mixture (sqrt density over the projected normal disk)", fontsize=10)
    fig.tight_layout()
    out = Path(args.output)
    with staged_outputs([out], force=args.force) as at:   # whole or not at all: a failed save leaves the old figure
        fig.savefig(at[out], dpi=100)
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(run_command("gmm_mipmap.py", lambda _: main(), None))
