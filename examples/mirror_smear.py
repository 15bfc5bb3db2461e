"""Where adaptive shading fails: a near-mirror GGX sphere under a measured probe (README, "Where it fails").

    python examples/mirror_smear.py [--probe ../shared/data/envmaps/city.exr] [--alpha 1e-4]
        [--res 32,64,128] [--budget 4] [--truth-spp 256] [--seed 1] [--clamp-quantile Q]
        [--env-signal log | radiance] [--worst 8] [--json OUT.json] [--plot OUT.png] [--force] [--write-scene DIR]

For each resolution: a radius-1 sphere of GGX (F = 1, ``--alpha``) at the origin, seen from z = 4 with a
40-degree field of view, lit by the probe alone, MIS throughout.  The reference at ``--budget`` samples per
pixel and the adaptive frame at budget ``--budget`` are each compared, by relative MSE (warpbw.metrics), with
the reference at ``--truth-spp``.  A mirror reflects the probe's edges (a building against the sky) at full
sharpness; where the adaptive frame gives the pixels beside such an edge a coarse level, it smears the edge and
its relative MSE exceeds the reference's at equal samples.

The report names the ``--worst`` pixels by their share of the adaptive frame's error, with their truth, the
adaptive value, the shading level, b_p (cycles/pixel; level 0 needs 0.25 at the Nyquist rate) and whether the
pixel was shaded or up-sampled, and the quantiles of the probe's angular bandwidth nu_a (cycles/radian).

``--clamp-quantile Q`` is a diagnostic, not a method of warpbw: the bandwidth pass reads nu_a from the probe's
pixels clamped at their Q-quantile of luminance (shading still uses the whole probe), which shows how much of
the failure comes from the probe's brightest texels dominating the wavelet analysis (Eq. 7's 95% energy rule
over coarse bands).  Q = 1 leaves the probe as it is.  ``--env-signal`` is the renderer's own option
(``warpbw render --env-signal``): the analysis reads log(1 + L / mean L) ("log", the default) or the luminance
("radiance", 002's).

``--write-scene DIR`` writes the sphere's scene file for each ``--res`` (DIR/mirror_RES.toml, the probe by its
absolute path) and renders nothing: ``warpbw render`` and ``warpbw compare --error-map`` then show the frames and
where their errors lie (docs/measurements.md, "Adaptive shading: where it fails").

``--json`` / ``--plot`` (as ``warpbw bench``'s: the one not given goes beside the other; an existing file is kept
without ``--force``, refused before any work) write every figure printed, with the settings, and the plot of both
frames' relative MSE and the adaptive frame's shaded fraction against resolution.  A probe black everywhere (every
error 0) is refused once read, before any render.
"""
from __future__ import annotations

from warpbw.entry import interrupt_in_one_line

interrupt_in_one_line(__name__)   # first: a Ctrl-C while the imports below load says one line, no traceback

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

from warpbw.cli import BUDGET_MAX, ENV_SIGNALS
from warpbw.cli_common import (OneLineParser, check_output_dir, check_output_file, check_record_outputs, init_warp,
                               run_command, write_record)
from warpbw.errors import INT32_MAX, WarpbwError, check_count
from warpbw.io.shared_data import shared_data_dir
from warpbw.io.staged import staged_outputs
from warpbw.scene import GGX_MIN_ALPHA, toml_string

PROBE_DEFAULT = shared_data_dir(Path(__file__).resolve().parents[1]) / "envmaps" / "city.exr"
ALPHA_DEFAULT = 1.0e-4        # GGX roughness: the smallest a scene accepts (warpbw.scene.GGX_MIN_ALPHA)
RES_DEFAULT = (32, 64, 128)
BUDGET_DEFAULT = 4.0          # samples per covered pixel, both frames
TRUTH_SPP_DEFAULT = 256
WORST_DEFAULT = 8
NU_A_QUANTILES = (0.5, 0.9, 0.99, 1.0)
CAMERA_Z, FOV_DEG, RADIUS = 4.0, 40.0, 1.0


def mirror_scene_text(probe: Path, alpha: float, res: int) -> str:
    """The scene file (TOML) of the sphere of the module docstring at ``res`` x ``res`` pixels."""
    return "\n".join([
        "[camera]", f"position = [0.0, 0.0, {CAMERA_Z}]", "look_at = [0.0, 0.0, 0.0]", f"fov = {FOV_DEG}",
        f"resolution = [{res}, {res}]", "",
        "[environment]", f"file = {toml_string(str(probe), f'--probe {probe}')}", "",
        "[[object]]", 'shape = "sphere"', "center = [0.0, 0.0, 0.0]", f"radius = {RADIUS}", 'material = "m"', "",
        "[material.m]", 'type = "ggx"', f"alpha = {alpha!r}", "specular = [1.0, 1.0, 1.0]", ""])


def mirror_scene(probe: Path, alpha: float, res: int):
    """The sphere of the module docstring at ``res`` x ``res`` pixels, parsed."""
    from warpbw.scene import parse_scene

    probe = Path(probe).resolve()   # the scene names it by an absolute path: a relative --probe is the user's cwd's
    return parse_scene(mirror_scene_text(probe, alpha, res), str(probe.parent), f"mirror sphere {res}x{res}")


def write_scenes(out_dir: Path, probe: Path, alpha: float, resolutions: list, force: bool) -> list:
    """DIR/mirror_RES.toml for each resolution (refused, before any is written, if one exists without --force)."""
    paths = [out_dir / f"mirror_{r}.toml" for r in resolutions]
    for p in paths:
        check_output_file(p, "--write-scene", force)
    for r in resolutions:   # a scene the loader would refuse is not written (the render path parses it the same way)
        mirror_scene(probe, alpha, r)
    with staged_outputs(paths, force=force) as at:   # every scene, or none: an error leaves the old ones
        for p, r in zip(paths, resolutions):
            at[p].write_text(mirror_scene_text(probe.resolve(), alpha, r))
    for p in paths:
        print(f"wrote {p}")
    return paths


def clamp_probe_luminance(pixels: np.ndarray, q: float) -> np.ndarray:
    """The probe's pixels scaled down where their luminance exceeds its ``q``-quantile (to that quantile)."""
    from warpbw.bandwidth import LUMINANCE

    lum = pixels @ np.asarray(LUMINANCE, np.float32)   # the weights env_bandwidth_map analyses
    cap = float(np.quantile(lum, q))
    scale = np.where(lum > cap, cap / np.maximum(lum, 1e-30), 1.0).astype(np.float32)
    return pixels * scale[..., None]


def prepare_with_clamped_bandwidth(prep, q: float, env_signal: str = ENV_SIGNALS[0]) -> None:
    """Build ``prep``'s bandwidth inputs from the clamped probe; the shading keeps the whole probe.  The clamped
    probe has no source digest: its nu_a map is cached by its own pixels, not as the probe's (which would read the
    whole probe's map from the cache, and leave the clamped one there for every later render of the probe)."""
    from warpbw.pipeline import prepare_bandwidth

    env = prep.env
    prep.env = dataclasses.replace(env, pixels=clamp_probe_luminance(env.pixels, q), source_digest="")
    try:
        prepare_bandwidth(prep, env_signal=env_signal)
    finally:
        prep.env = env


def nu_a_quantiles(pixels: np.ndarray, name: str, env_signal: str = ENV_SIGNALS[0]) -> list:
    """nu_a of ``pixels`` (cycles/radian), analysed on ``env_signal``, at NU_A_QUANTILES of the probe's texels."""
    from warpbw.bandwidth import env_bandwidth_map

    nu, _ = env_bandwidth_map(pixels, name, signal=env_signal)
    return [float(np.quantile(nu, q)) for q in NU_A_QUANTILES]


def worst_pixels(adaptive, truth: np.ndarray, cov: np.ndarray, k: int) -> tuple[float, list]:
    """(share of the adaptive frame's relative squared error in its ``k`` worst pixels, those pixels)."""
    from warpbw.metrics import relmse_map

    err = relmse_map(adaptive.image, truth, cov)
    order = np.argsort(err, axis=None)[::-1][:k]
    total = float(err.sum())
    rows = []
    for i in order:
        y, x = np.unravel_index(i, err.shape)
        rows.append({"x": int(x), "y": int(y), "share": float(err[y, x] / total) if total else 0.0,
                     "truth": float(truth[y, x].mean()), "adaptive": float(adaptive.image[y, x].mean()),
                     "level": int(adaptive.aovs["level"][y, x]), "b_p": float(adaptive.aovs["b_p"][y, x]),
                     "shaded": bool(adaptive.aovs["shaded"][y, x])})
    return (sum(r["share"] for r in rows), rows)


def measure(probe: Path, alpha: float, res: int, budget: float, truth_spp: int, seed: int,
            clamp_q: float, worst: int, env_signal: str = ENV_SIGNALS[0]) -> dict:
    """The figures of the module docstring for one resolution."""
    from warpbw.metrics import relmse
    from warpbw.pipeline import prepare_scene, render_adaptive, render_reference

    prep = prepare_scene(mirror_scene(probe, alpha, res))
    truth = render_reference(prep, truth_spp, seed=seed + 1, mis=True)
    cov = truth.coverage.astype(bool)
    ref = render_reference(prep, int(round(budget)), seed=seed, mis=True)
    if clamp_q < 1.0:
        prepare_with_clamped_bandwidth(prep, clamp_q, env_signal)
    ada = render_adaptive(prep, budget, seed=seed, mis=True, env_signal=env_signal)
    share, rows = worst_pixels(ada, truth.image, cov, worst)
    return {"res": res, "covered_pixels": int(cov.sum()),
            "relmse_reference": relmse(ref.image, truth.image, cov),
            "relmse_adaptive": relmse(ada.image, truth.image, cov),
            "shaded_fraction": float(np.asarray(ada.aovs["shaded"], bool)[cov].mean()),
            "samples_per_covered_pixel": float(ada.stats["samples_per_covered_pixel"]),
            "worst_share": share, "worst": rows}


def format_row(r: dict) -> str:
    worst = f"; its {len(r['worst'])} worst pixels hold {r['worst_share']:.0%} of its error" if r["worst"] else ""
    lines = [f"{r['res']:4d}x{r['res']:<4d} reference {r['relmse_reference']:.3g}   adaptive {r['relmse_adaptive']:.3g}"
             f" (shaded {r['shaded_fraction']:.0%}, {r['samples_per_covered_pixel']:.2f} samples per covered pixel"
             f"{worst})"]
    for p in r["worst"]:
        lines.append(f"    ({p['x']:3d},{p['y']:3d}) {p['share']:5.1%}  truth {p['truth']:.3g}  adaptive "
                     f"{p['adaptive']:.3g}  level {p['level']}  b_p {p['b_p']:.3f}  "
                     f"{'shaded' if p['shaded'] else 'up-sampled'}")
    return "\n".join(lines)


def write_plot(record: dict, path) -> None:
    """Both frames' relative MSE against the truth, and the adaptive frame's shaded fraction, against resolution."""
    from matplotlib.figure import Figure

    rows = record["rows"]
    res = [r["res"] for r in rows]
    fig = Figure(figsize=(6.5, 4.2))   # not pyplot's: nothing to close, the caller's backend kept
    ax = fig.subplots()
    ax.plot(res, [r["relmse_reference"] for r in rows], "o-", label=f"reference, {record['budget']:g} spp")
    ax.plot(res, [r["relmse_adaptive"] for r in rows], "s-", label=f"adaptive, budget {record['budget']:g}")
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xlabel("resolution (pixels a side)")
    ax.set_ylabel(f"relative MSE against {record['truth_spp']} spp")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)
    ax2 = ax.twinx()
    ax2.plot(res, [r["shaded_fraction"] for r in rows], "^--", color="C2", label="adaptive: shaded fraction")
    ax2.set_ylim(0, 1.05)
    ax2.set_ylabel("shaded fraction of covered pixels")
    ax2.legend(loc="upper right", fontsize=8)
    ax.set_title(f"{Path(record['probe']).name}, GGX alpha {record['alpha']:g} (nu_a from its "
                 f"{record['env_signal']})", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def _resolutions(text: str) -> list:
    try:
        res = [int(t) for t in text.split(",") if t.strip()]
    except ValueError:
        res = []
    if not res or any(r < 8 or r > 2048 for r in res):
        raise WarpbwError(f"--res {text!r}: expected comma-separated square resolutions in [8, 2048], e.g. 32,64,128")
    return res


def main(argv=None) -> int:
    ap = OneLineParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--probe", default=str(PROBE_DEFAULT), help="lat-long HDR probe (default: shared city.exr)")
    ap.add_argument("--alpha", type=float, default=ALPHA_DEFAULT, help=f"GGX roughness (default {ALPHA_DEFAULT:g})")
    ap.add_argument("--res", default=",".join(map(str, RES_DEFAULT)),
                    help="square resolutions, comma-separated (default %(default)s)")
    ap.add_argument("--budget", type=float, default=BUDGET_DEFAULT,
                    help=f"samples per covered pixel of both frames, a whole number (default {BUDGET_DEFAULT:g})")
    ap.add_argument("--truth-spp", type=int, default=TRUTH_SPP_DEFAULT,
                    help=f"samples per pixel of the truth (default {TRUTH_SPP_DEFAULT})")
    ap.add_argument("--seed", type=int, default=1, help="seed of both frames; the truth uses seed + 1 (default 1)")
    ap.add_argument("--clamp-quantile", type=float, default=1.0,
                    help="diagnostic: nu_a from the probe clamped at this luminance quantile, in (0, 1] (default 1)")
    ap.add_argument("--env-signal", choices=ENV_SIGNALS, default=ENV_SIGNALS[0],
                    help="what the bandwidth pass's analysis of the probe reads (warpbw render --env-signal; "
                    f"default {ENV_SIGNALS[0]})")
    ap.add_argument("--worst", type=int, default=WORST_DEFAULT, help=f"pixels to list (default {WORST_DEFAULT})")
    ap.add_argument("--json", help="write the figures here (JSON); without it, beside --plot as OUT.json")
    ap.add_argument("--plot", help="write the plot here (PNG): both frames' relative MSE and the shaded fraction "
                    "against resolution; without it, beside --json as OUT.png")
    ap.add_argument("--force", action="store_true", help="overwrite --json / --plot or --write-scene's files")
    ap.add_argument("--write-scene", metavar="DIR",
                    help="write the scene file of each --res as DIR/mirror_RES.toml and render nothing")
    args = ap.parse_args(argv)
    probe = Path(args.probe)
    if not probe.is_file():
        raise WarpbwError(f"--probe {probe}: no such file (expected a lat-long HDR probe, EXR or PFM)")
    if not GGX_MIN_ALPHA <= args.alpha <= 1.0:   # the scene loader's range for a GGX alpha (nan fails too)
        raise WarpbwError(f"--alpha {args.alpha!r}: expected a GGX roughness from {GGX_MIN_ALPHA:g} to 1")
    if not (1 <= args.budget <= BUDGET_MAX and float(args.budget).is_integer()):
        raise WarpbwError(f"--budget {args.budget!r}: expected a whole number of samples per pixel from 1 to "
                          f"{int(BUDGET_MAX)} (the reference renders that many; the adaptive frame's N_p, up to 256 "
                          "x budget, is an int32 in the kernels)")
    if not (0.0 < args.clamp_quantile <= 1.0):
        raise WarpbwError(f"--clamp-quantile {args.clamp_quantile!r}: expected a quantile in (0, 1]")
    check_count(args.truth_spp, "--truth-spp", 1, INT32_MAX)   # the shading kernel counts samples in int32
    check_count(args.seed, "--seed", 0, 2**32 - 2)
    check_count(args.worst, "--worst", 0)
    res = _resolutions(args.res)
    if args.write_scene:
        check_output_dir(args.write_scene, "--write-scene")
        write_scenes(Path(args.write_scene), probe, args.alpha, res, args.force)
        return 0
    json_path, plot_path = check_record_outputs(args.json, args.plot, args.force, inputs=[probe])
    init_warp("cpu")
    from tqdm import tqdm

    from warpbw.envmap import load_envmap

    env = load_envmap(probe)
    if not np.any(env.pixels):   # every error 0, and a plot with no positive value on its log axis
        raise WarpbwError(f"--probe {probe}: black everywhere (after the clamp of negative values): the mirror "
                          "reflects nothing and every error is 0 (expected a probe with light in it)")
    nu_q = {"probe": nu_a_quantiles(env.pixels, env.name, args.env_signal)}
    if args.clamp_quantile < 1.0:
        nu_q["clamped"] = nu_a_quantiles(clamp_probe_luminance(env.pixels, args.clamp_quantile), env.name,
                                         args.env_signal)
    print(f"{probe.name}, GGX alpha {args.alpha:g}, budget {args.budget:g} against the reference at "
          f"{args.budget:g} spp, relative MSE against {args.truth_spp} spp (MIS, seed {args.seed}; nu_a analysed on "
          f"the probe's {args.env_signal})")
    for key, what in (("probe", "the probe"), ("clamped", f"the probe clamped at its {args.clamp_quantile:g} "
                                                            "luminance quantile (the bandwidth pass reads this)")):
        if key in nu_q:
            print(f"  nu_a of {what}, cycles/radian, at quantiles "
                  + ", ".join(f"{q:g}: {v:.3g}" for q, v in zip(NU_A_QUANTILES, nu_q[key])))
    rows = []
    with tqdm(res, desc="resolutions", unit="res", leave=False, disable=None) as bar:   # no bar off a terminal
        for r in bar:
            rows.append(measure(probe, args.alpha, r, args.budget, args.truth_spp, args.seed, args.clamp_quantile,
                                args.worst, args.env_signal))
            tqdm.write(format_row(rows[-1]))
    if json_path is not None:
        out = {"probe": str(probe), "alpha": args.alpha, "budget": args.budget, "truth_spp": args.truth_spp,
               "seed": args.seed, "clamp_quantile": args.clamp_quantile, "env_signal": args.env_signal,
               "device": "cpu",
               "nu_a_quantiles": {k: dict(zip(map(str, NU_A_QUANTILES), v)) for k, v in nu_q.items()}, "rows": rows}
        write_record(json_path, plot_path, out, write_plot, force=args.force)
    return 0


if __name__ == "__main__":
    sys.exit(run_command("mirror_smear.py", lambda _: main(), None))
