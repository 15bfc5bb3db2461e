"""How much noise any sample allocation could save on a scene, and how much the adaptive frame's saves.

    python examples/allocation_ceiling.py SCENE.toml [--budget 8] [--seeds 32] [--spp 16] [--seed 7]
        [--json OUT.json] [--plot OUT.png] [--force]

Brute force: the scene's reference (MIS) rendered ``--seeds`` times at ``--spp`` samples per pixel; the
spread of each pixel over the seeds gives v_p, the variance of one MIS step (RGB channels summed, as
the benchmark's MSE sums them).  Every figure is a noise gain: the reference's noise MSE at the same
number of samples per covered pixel, B, over the noise MSE of the allocation named:

* ``oracle_all``: every pixel shaded, N_p proportional to sqrt(v_p) (Neyman), the most any per-pixel
  allocation can gain without skipping pixels: mean(v) / mean(sqrt(v))^2;
* on the pixels the adaptive frame shades (``warpbw render --method adaptive --budget B --mis``, default
  allocation), with the samples the frame spent there (B per covered pixel: since session 39 the texels the
  up-sampling cannot fill are planned, and paid for, within the budget): ``uniform_shaded`` (equal N_p),
  ``oracle_shaded`` (Neyman's with the true v_p; ``oracle_shaded_min1`` with at least one sample per
  pixel, as the frame must) and ``frame`` (the samples the frame took at each of those pixels, its ``spp`` AOV: a
  coarse texel's is the largest N_p of its footprint), each against the reference at that many
  samples.  Each shaded pixel counts once: the noise a coarse texel spreads over its footprint and the
  up-sampling's bias are left out, so the oracles bound from above what skipping pixels and allocating
  samples can buy at this budget;
* ``rank_measured``: Spearman rank correlation, over those pixels, of the variance the bandwidth pass
  measured for its own directions with v_p: the frame's variance map times N_p, the MIS step's variance since
  session 74 (before, the one-sample MIS variance, which the default allocation keeps as its key).

A scene whose v_p is nearly the same everywhere (``oracle_all`` near 1) and whose frame shades most of its
pixels has little to gain from adaptive shading at any budget: on the benchmark's blue-acrylic bunny under
studio.exr (examples/bench_scenes.py, budget 32) the frame shades 57% of the pixels, ``oracle_all`` is
1.15x and ``oracle_shaded`` 3.13x, against 101x and 124x (budget 2) on the chrome sphere (session 58's code;
before it, 75% and 2.06x, and 126x; docs/measurements.md).

``--json`` / ``--plot`` (as ``warpbw bench``'s: the one not given goes beside the other; an existing file is kept
without ``--force``, refused before any work) write every figure, with the settings and the device, and the plot
of the noise gains (``GAINS``) against 1x.  A scene with no noise to allocate (a black environment, refused before the
brute force; surfaces that reflect none of the light) or no covered pixel is refused: every gain is a ratio of noise
MSEs.
"""
from __future__ import annotations

from warpbw.entry import interrupt_in_one_line

interrupt_in_one_line(__name__)   # first: a Ctrl-C while the imports below load says one line, no traceback

import argparse
import sys
from pathlib import Path

import numpy as np

from warpbw.cli import BUDGET_MAX
from warpbw.cli_common import OneLineParser, check_record_outputs, init_warp, run_command, write_record
from warpbw.errors import INT32_MAX, check_count

SEEDS_DEFAULT = 32        # brute-force renders: the oracle's sqrt(v) is biased by about 1 / (2 x seeds)
SPP_DEFAULT = 16          # samples per pixel of each brute-force render
BUDGET_DEFAULT = 8.0
GAINS = ("oracle_all", "uniform_shaded", "oracle_shaded", "oracle_shaded_min1", "frame")   # the report's noise gains


def per_pixel_variance(prep, seeds: int, spp: int, progress: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(coverage (H, W) bool, v (H, W)): the variance of one MIS step per pixel, RGB summed, from ``seeds``
    renders of ``spp`` samples (v = spp x the variance of a render's pixel over the seeds)."""
    from warpbw.pipeline import render_reference

    from tqdm import tqdm

    from precompute.progress import bar_options

    s1 = s2 = 0.0
    with tqdm(range(seeds), desc=f"brute force, {spp} spp", unit="render", leave=False, disable=not progress,
              **bar_options()) as it:
        for k in it:
            r = render_reference(prep, spp, seed=1_000 + k, mis=True)
            img = r.image.astype(np.float64)
            s1 = s1 + img
            s2 = s2 + img * img
    var = np.maximum(s2 - s1 * s1 / seeds, 0.0) / (seeds - 1)
    return r.coverage.astype(bool), var.sum(axis=-1) * spp


def noise_gain(v_all: np.ndarray, v: np.ndarray, n_p: np.ndarray, spp: float) -> float:
    """The reference's noise MSE at ``spp`` samples per covered pixel (``v_all``: every covered pixel's
    variance) over that of the pixels ``v`` shaded with ``n_p`` samples each (the other covered pixels
    count as noise-free)."""
    mse = float(np.sum(v / n_p))
    return (float(np.sum(v_all)) / spp) / mse if mse > 0 else float("inf")


def neyman(weights: np.ndarray, total: float, n_min: float = 0.0) -> np.ndarray:
    """``total`` samples in proportion to ``weights``, each at least ``n_min`` (real-valued: the optimum of
    sum v / N for sum N = total, N = max(n_min, weight / lambda), lambda found by bisection)."""
    w = np.maximum(np.asarray(weights, np.float64), 1e-30)
    if n_min <= 0.0 or n_min * len(w) >= total:
        return total * w / w.sum() if n_min <= 0.0 else np.full(len(w), total / len(w))
    lo, hi = np.log(w.min() / total) - 1.0, np.log(w.max() / n_min) + 1.0   # log lambda
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        if np.maximum(n_min, w / np.exp(mid)).sum() > total:
            lo = mid
        else:
            hi = mid
    n = np.maximum(n_min, w / np.exp(hi))
    return n * (total / n.sum())


def allocation_ceiling(prep, budget: float = BUDGET_DEFAULT, seeds: int = SEEDS_DEFAULT, spp: int = SPP_DEFAULT,
                       seed: int = 7, progress: bool = False) -> dict:
    """The figures of the module docstring for a prepared scene."""
    from scipy.stats import spearmanr

    from warpbw.errors import WarpbwError
    from warpbw.pipeline import render_adaptive

    where = f"{prep.scene.source}: " if prep is not None else ""   # None: the tests' stand-in renders
    env = getattr(prep, "env", None)
    if env is not None and not np.any(env.pixels):   # before the brute force, as warpbw bench refuses it
        raise WarpbwError(f"{where}[environment] {env.name!r} is black everywhere (after its scale and the clamp of "
                          "negative values): no light to sample, so no noise to allocate (expected an environment with "
                          "light in it)")
    cov, var = per_pixel_variance(prep, seeds, spp, progress)
    v = var[cov]
    n_cov = int(cov.sum())
    # every gain is a ratio of noise MSEs: inf and nan for no noise, a ZeroDivisionError for no pixel
    if not n_cov:
        raise WarpbwError(f"{where}no pixel shows a sphere or mesh, so there is nothing to allocate (check [camera] "
                          "position, look_at and fov)")
    if not np.any(v):
        raise WarpbwError(f"{where}every covered pixel reads the same in the {seeds} brute-force renders (surfaces "
                          "that reflect none of the light): no noise to allocate, so every gain is undefined (expected "
                          "surfaces the environment lights)")
    sig = np.sqrt(v)
    frame = render_adaptive(prep, budget, seed=seed, mis=True)
    n_p = np.maximum(np.asarray(frame.aovs["n_p"], np.float64)[cov], 1.0)
    shaded = np.asarray(frame.aovs["shaded"], bool)[cov]
    measured = np.asarray(frame.aovs["variance"], np.float64)[cov] * n_p   # the MIS step's: (map = v / N_p) x N_p
    vs = v[shaded]
    # the samples each shaded pixel took: a coarse texel's is the largest N_p of its footprint, not its pixel's N_p
    # (summing n_p instead read 1.82 samples per covered pixel where the gold bunny's budget-2 frame took 2.00)
    took = np.asarray(frame.aovs["spp"], np.float64)[cov][shaded]
    total = float(took.sum()) if shaded.any() else budget * n_cov
    spent = total / max(n_cov, 1)   # samples per covered pixel the frame spent on the pixels it shaded
    out = {
        "budget": float(budget), "seeds": int(seeds), "spp": int(spp), "covered_pixels": n_cov,
        "frame_samples_per_covered_pixel": spent,
        "shaded_fraction": float(shaded.mean()) if n_cov else 0.0,
        "top_10pct_variance_share": float(np.sort(v)[::-1][:max(1, n_cov // 10)].sum() / v.sum()) if v.sum() else 0.0,
        "oracle_all": float(v.mean() / sig.mean() ** 2) if sig.sum() else 1.0,
        "uniform_shaded": noise_gain(v, vs, np.full(len(vs), total / max(len(vs), 1)), spent),
        "oracle_shaded": noise_gain(v, vs, neyman(np.sqrt(vs), total), spent),
        "oracle_shaded_min1": noise_gain(v, vs, neyman(np.sqrt(vs), total, 1.0), spent),
        "frame": noise_gain(v, vs, took, spent),
        "rank_measured": float(spearmanr(measured[shaded], vs).correlation) if len(vs) > 2 else float("nan"),
    }
    return out


def write_plot(record: dict, path) -> None:
    """The noise gains over the reference at equal samples (``GAINS``), against 1x (no gain)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7, 4))   # not pyplot's: nothing to close, the caller's backend kept
    ax = fig.subplots()
    ax.bar(range(len(GAINS)), [record[k] for k in GAINS], color=["C0", "C1", "C2", "C2", "C3"])
    ax.axhline(1.0, color="k", lw=0.8, ls="--")
    ax.set_xticks(range(len(GAINS)), GAINS, fontsize=8)
    ax.set_yscale("log")
    ax.set_ylabel("noise gain over the reference at equal samples")
    ax.grid(True, axis="y", which="both", alpha=0.3)
    ax.set_title(f"{Path(record['scene']).name}: budget {record['budget']:g}, {record['shaded_fraction']:.0%} "
                 f"shaded; brute force {record['seeds']} x {record['spp']} spp", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def format_report(name: str, r: dict) -> str:
    return "\n".join([
        f"{name}: {r['covered_pixels']} covered pixels, budget {r['budget']:g} (the frame spent "
        f"{r['frame_samples_per_covered_pixel']:.2f}), brute force {r['seeds']} x {r['spp']} spp",
        f"  the 10% noisiest pixels hold {r['top_10pct_variance_share']:.0%} of the variance",
        "  noise gain over the reference at equal samples (noise only: no up-sampling bias, no footprints):",
        f"    oracle, every pixel shaded      {r['oracle_all']:8.3f}x",
        f"    on the frame's {r['shaded_fraction']:6.1%} shaded:  uniform {r['uniform_shaded']:.3f}x, "
        f"oracle {r['oracle_shaded']:.3f}x (at least 1 sample each: {r['oracle_shaded_min1']:.3f}x), "
        f"the frame's {r['frame']:.3f}x",
        f"  rank correlation of the pass's measured variance with the brute force: {r['rank_measured']:.3f}",
    ])


def main(argv=None) -> int:
    ap = OneLineParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene", help="scene file (TOML) with an environment")
    ap.add_argument("--budget", type=float, default=BUDGET_DEFAULT,
                    help="samples per covered pixel of the adaptive frame and of the comparison "
                    f"(default {BUDGET_DEFAULT:g})")
    ap.add_argument("--seeds", type=int, default=SEEDS_DEFAULT,
                    help=f"brute-force renders, at least 2 (default {SEEDS_DEFAULT})")
    ap.add_argument("--spp", type=int, default=SPP_DEFAULT, help=f"samples per pixel of each (default {SPP_DEFAULT})")
    ap.add_argument("--seed", type=int, default=7, help="seed of the adaptive frame (default 7)")
    ap.add_argument("--json", help="write the figures here (JSON); without it, beside --plot as OUT.json")
    ap.add_argument("--plot", help="write the plot here (PNG): the noise gains; without it, beside --json as "
                    "OUT.png")
    ap.add_argument("--device", default="cpu", help="Warp device (default cpu; cuda where there is one)")
    ap.add_argument("--force", action="store_true", help="overwrite --json and --plot")
    args = ap.parse_args(argv)
    if not 0 < args.budget <= BUDGET_MAX:   # not after the brute-force renders, as the renderer's "budget"
        ap.error(f"--budget {args.budget:g}: expected a positive number of samples per pixel, at most {BUDGET_MAX:g} "
                 "(N_p, up to 256 x budget, is an int32 in the kernels)")
    check_count(args.seeds, "--seeds", 2)
    check_count(args.spp, "--spp", 1, INT32_MAX)
    check_count(args.seed, "--seed", 0, 2**32 - 1)
    # never the scene itself
    json_path, plot_path = check_record_outputs(args.json, args.plot, args.force, inputs=[args.scene])
    init_warp(args.device)
    from warpbw.pipeline import prepare_scene
    from warpbw.scene import load_scene

    scene = load_scene(args.scene)
    prep = prepare_scene(scene, device=args.device)
    r = allocation_ceiling(prep, args.budget, args.seeds, args.spp, args.seed, progress=True)
    r["scene"] = str(args.scene)
    r["device"] = args.device
    print(format_report(str(args.scene), r))
    if json_path is not None:
        write_record(json_path, plot_path, r, write_plot, force=args.force)
    return 0


if __name__ == "__main__":
    sys.exit(run_command("allocation_ceiling.py", lambda _: main(), None))
