"""BRDF lookup and importance sampling example: a tabulated material's lobe, its sampling pdf and a
histogram of drawn directions, side by side, for a few view elevations.

    python examples/brdf_sampling.py [--material gold-metallic-paint] [--table ../shared/data/brdf/npf.bin]
        [--out brdf_out]

Uses the same Warp functions the renderer uses (warpbw.brdf: eval / sample / pdf) on an NPF material,
with sampling tables built by numerical inversion of the CDF (002 Sec. 3.3).  The three panels per
view should match in shape: f cos_i (what we want to follow), the pdf (what the tables give), and the
histogram of samples (what the sampler draws).  Plotted over the projected hemisphere (x, y of wi).
"""
from warpbw.entry import interrupt_in_one_line

interrupt_in_one_line(__name__)   # first: a Ctrl-C while the imports below load says one line, no traceback

import argparse
import sys
from pathlib import Path

import numpy as np

from warpbw import brdf as B
from warpbw.cli_common import OneLineParser, check_overwrite, init_warp, run_command
from warpbw.errors import INT32_MAX, check_count
from warpbw.io.npf import npf_eval, read_npf
from warpbw.io.shared_data import shared_data_dir
from warpbw.io.staged import staged_outputs
from warpbw.sampling import build_sampler_table

GRID = 160   # cells per side of the projected-hemisphere images


def main():
    here = Path(__file__).resolve().parent
    ap = OneLineParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--material", default="gold-metallic-paint", help="NPF material name (default gold-metallic-paint)")
    ap.add_argument("--table", default=str(shared_data_dir(here.parent) / "brdf" / "npf.bin"),
                    help="NPF table (default %(default)s: ../shared/data, or $WARPBW_SHARED_DATA)")
    ap.add_argument("--samples", type=int, default=400_000, help="directions drawn per view (default 400000)")
    ap.add_argument("--out", default="brdf_out", help="folder of brdf_sampling_MATERIAL.png (default brdf_out)")
    ap.add_argument("--force", action="store_true", help="overwrite an existing brdf_sampling_MATERIAL.png")
    args = ap.parse_args()
    check_count(args.samples, "--samples", 1, INT32_MAX)   # the sampling kernel counts them in int32
    init_warp("cpu")           # Warp's no-CUDA-driver line kept off stderr
    from matplotlib.figure import Figure

    mat = read_npf(args.table, args.material)
    out_png = Path(args.out) / f"brdf_sampling_{mat.name}.png"
    check_overwrite([out_png], args.force, option="--out")   # before the table is built
    table = build_sampler_table(lambda wi, wo: npf_eval(mat, wi, wo))
    mb = B.build_material_table([B.MaterialSpec(mat.name, B.NPF, linear=True, sampler=table,
                                                npf=B.pack_npf_curves(mat.rho_d, mat.rho_s, mat.D, mat.G1, mat.F))])
    x = (np.arange(GRID) + 0.5) / GRID * 2 - 1
    X, Y = np.meshgrid(x, -x)
    inside = X ** 2 + Y ** 2 < 1
    wi = np.stack([X[inside], Y[inside], np.sqrt(1 - X[inside] ** 2 - Y[inside] ** 2)], -1)
    thetas = (0.2, 0.8, 1.3)
    fig = Figure(figsize=(9, 3 * len(thetas)))   # not pyplot's: nothing to close, the caller's backend kept
    axes = fig.subplots(len(thetas), 3)
    for row, th in enumerate(thetas):
        wo = np.array([np.sin(th), 0.0, np.cos(th)])
        f = B.eval_brdf(mb, 0, wi, wo).mean(1) * wi[:, 2]
        p = B.pdf_brdf(mb, 0, wi, wo)
        s = B.sample_brdf(mb, 0, wo, args.samples, seed=row)
        s = s[s[:, 2] > 0]
        hist, _, _ = np.histogram2d(-s[:, 1], s[:, 0], bins=GRID, range=[[-1, 1], [-1, 1]])
        # counts per projected-area cell -> density per solid angle (d omega = dA / cos)
        cell = (2.0 / GRID) ** 2
        dens = np.zeros((GRID, GRID))
        dens[inside] = (hist[inside] / max(len(s), 1) / cell) * wi[:, 2]   # none above: zero
        # pdf and sample density share one colour scale (they are the same quantity, per steradian)
        lo, hi = np.log10(max(np.percentile(p, 1), 1e-6)), np.log10(p.max())
        for col, (img_vals, title) in enumerate(((f, "f cos_i"), (p, "pdf"), (None, "samples"))):
            img = np.full((GRID, GRID), np.nan)
            if img_vals is None:
                img = np.where(inside, dens, np.nan)
            else:
                img[inside] = img_vals
            ax = axes[row, col]
            scale = {} if col == 0 else {"vmin": lo, "vmax": hi}
            ax.imshow(np.log10(np.maximum(img, 1e-6)), extent=(-1, 1, -1, 1), cmap="magma", **scale)
            ax.set_title(f"{title}, theta_o = {th:.1f}", fontsize=9)
            ax.set_xticks([])
            ax.set_yticks([])
        print(f"theta_o {th:.1f}: {len(s)} of {args.samples} samples above the horizon, "
              f"peak pdf {p.max():.3g} /sr, peak f cos_i {f.max():.3g}")
    fig.suptitle(f"{mat.name} (NPF), log10 scale, projected hemisphere")
    fig.tight_layout()
    # whole or not at all: a failed save leaves the old figure
    with staged_outputs([out_png], force=args.force) as at:
        fig.savefig(at[out_png], dpi=100)
    print(f"wrote {out_png}")


if __name__ == "__main__":
    sys.exit(run_command("brdf_sampling.py", lambda _: main(), None))
