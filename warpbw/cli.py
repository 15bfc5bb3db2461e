"""The ``warpbw`` command: render, demo, info, compare, bench, bench-filtering.

Public: ``main(argv=None) -> int``; ``check_command_options(command, options)`` for scripts that pass
options on to a ``warpbw`` command or take the same ones (examples/bench_scenes.py, filtering_scenes.py,
bench_reference.py).

The command line's own parts, not an API: ``build_parser()`` with ``add_adaptive_options`` and
``add_anisotropy_option``, and the subcommands' handlers ``cmd_render``, ``cmd_demo``, ``cmd_info``, ``cmd_compare``,
``cmd_bench`` and ``cmd_bench_filtering`` (each takes the parsed arguments and returns the exit status).

Errors the user can cause print one line, ``warpbw: error: ...``, and exit with status 2.
Nothing the user has is overwritten without ``--force``.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import shlex
import sys
import time
from pathlib import Path

from warpbw import __version__
from warpbw.cli_common import (PROTOCOL_RUNS, RUNS_MAX, OneLineParser, check_output_dir, check_output_file,
                               check_overwrite, few_runs_warning, init_warp, json_text, parse_path, parse_seed,
                               printable, record_paths, run_command, write_record)
from warpbw.errors import FLOAT32_MAX, INT32_MAX, WarpbwError
from warpbw.io.staged import staged_outputs

DEFAULT_SPP = 64
DEMO_SPP = 64
DEMO_SCENE_NAME = "scene.toml"   # the demo's scene, written beside its image to edit and render
# warpbw.filtering.ALL_METHODS (spelled here so that --help needs no Warp import)
_FILTER_METHODS = ("gmm_aligned", "gmm_unaligned", "toksvig", "lean", "fixed", "ground_truth")
# warpbw.bandwidth.ALLOCATIONS, default first (spelled here for the same reason)
_ALLOCATIONS = ("measured", "variance", "sqrt", "relative", "uniform")
# warpbw.upsample.UPSAMPLE_MODES, default first (spelled here for the same reason)
_UPSAMPLE_MODES = ("normal", "paper")
# warpbw.bandwidth.ENV_SIGNALS, default first (spelled here for the same reason)
ENV_SIGNALS = ("log", "radiance")
# warpbw.metrics.RELMSE_EPS and WORST_FRACTION (spelled here for the same reason)
_RELMSE_EPS = 1.0e-2
_WORST_FRACTION = 0.01
ERROR_MAP_DECADES = 6   # compare --error-map's default colour scale: 10^6 below the largest error (ours)
# warpbw.bandwidth.BUDGET_MAX (spelled here for the same reason): the adaptive N_p goes up to
# N_P_MAX_PER_BUDGET = 256 x --budget and is an int32 in the kernels
BUDGET_MAX = INT32_MAX / 256
# warpbw.bandwidth.N_B_MAX (spelled here for the same reason): a sanity bound on --nb
N_B_MAX = 1 << 16
# warpbw.filtering.MIN_GT_SPP (spelled here for the same reason): the ground truth's fewest rays per pixel
MIN_GT_SPP = 64
# warpbw.pipeline.SUMMARY_METHODS (spelled here for the same reason): render's and info's --method, default first
METHODS = ("reference", "adaptive")
# warpbw.filtering.MAX_ANISOTROPY (spelled here for the same reason): the most probes along a footprint's axis
MAX_ANISOTROPY = 16
# --exposure in stops: beyond +-150 every non-zero float32 radiance (2^-149 .. 2^128) previews white, or black
EXPOSURE_MAX_STOPS = 150.0
# --threads: the launches' CPU threads, at most 4 per core the machine reports (more only adds idle threads and tiles)
THREADS_PER_CORE_MAX = 4
THREADS_MAX = THREADS_PER_CORE_MAX * (os.cpu_count() or 1)

EPILOG = """\
examples:
  warpbw demo -o demo_out
      render the embedded default scene
  warpbw info scene.toml
      what a scene needs, without rendering
  warpbw render scene.toml -o out.exr --spp 256 --seed 1
      the reference estimator, 256 samples per pixel
  warpbw render scene.toml -o out.exr --method adaptive --budget 8
      adaptive shading (002): AOVs out.level.exr, out.n_p.exr, ...
  warpbw bench scene.toml --json b.json --plot b.png
      speed against accuracy, adaptive vs reference
  warpbw compare out.exr ground_truth.exr
      PSNR and relative MSE over covered pixels
  warpbw compare out.exr gt.exr --error-map err.exr
      and where the error is (err.exr + err.png)
  warpbw render planes.toml -o out.exr --filter gmm_aligned
      a scene with planes: reflectance filtering (004)
  warpbw render mixed.toml -o out.exr --method adaptive --budget 8
      planes beside spheres or meshes: both renderers, composited
  warpbw bench-filtering planes.toml --zoom 1,2,4,8,16,32 --json f.json
      error, flicker and time of each filter along a zoom-out (and f.png)

Scene files are TOML; see README.md for the keys.  Images are linear radiance
in EXR (R, G, B and the coverage mask as A), with an sRGB PNG preview and a
JSON of statistics beside them.  Results and summaries go to stdout; progress
bars, warnings and errors to stderr.  Exit status: 0 done; 2 a usage error or
bad input (one line on stderr); 130, 143 or 129 stopped by Ctrl-C, SIGTERM or
SIGHUP; 141 the reader of stdout left (README: Command-line conventions).
"""


def _outputs(out: Path) -> dict:
    if out.suffix.lower() != ".exr":   # ".exr" alone is a hidden file's name, without a suffix
        raise WarpbwError(f"-o {out}: expected a path ending in .exr" + (" after a name (such as out.exr)"
                                                                         if out.name.lower() == ".exr" else ""))
    return {"exr": out, "png": out.with_suffix(".png"), "json": out.with_suffix(".json")}


def _write_render(res, outs: dict, exposure: float, at: dict):
    """The image as EXR (RGB + coverage as A), its PNG preview and its stats as JSON, each written to ``at[path]``
    (``staged_outputs``' temporaries)."""
    import numpy as np

    from warpbw.io.exr import write_exr, write_png

    rgba = np.concatenate([res.image, res.coverage[..., None].astype(np.float32)], axis=-1)
    write_exr(at[outs["exr"]], rgba, channels=["R", "G", "B", "A"])
    write_png(at[outs["png"]], res.image, exposure=exposure)
    at[outs["json"]].write_text(json_text(res.stats, default=str))


# AOVs of the adaptive method (002 Fig. 1d / 18): name -> (what it is, false-colour scale)
AOVS = {
    "level": ("shading level per pixel (002 Eq. 11, 0 = full resolution)", "linear"),
    "n_p": ("samples allocated per pixel, N_p (002 Sec. 2.4)", "log"),
    "spp": ("samples the frame took at the pixel: a texel shaded at a coarser level takes the largest N_p of its "
            "footprint (002 Sec. 3.1); 0 where up-sampled", "log"),
    "variance": ("predicted variance of an estimate of the allocated N_p samples, v / N_p (the plan's, not of the "
                 "frame's pixel: one that took more samples, see spp, is less noisy; an up-sampled one is "
                 "interpolated): v the variance the bandwidth pass measured for the frame's estimator (--allocation "
                 "measured, the default) or the bound sigma2 (002 Eq. 9)", "log"),
    "shaded": ("1 where the pixel was shaded, 0 where up-sampled", "linear"),
    "b_p": ("predicted image bandwidth, cycles/pixel (002 Eq. 6)", "log"),
}


def _aov_paths(out: Path) -> dict:
    return {name: (out.with_suffix(f".{name}.exr"), out.with_suffix(f".{name}.png")) for name in AOVS}


def _write_map(at: dict, exr: Path, png: Path, values, mask, log: bool = False) -> dict:
    """A per-pixel map as EXR (Y, and A = ``mask``: 1 where Y holds the map's value, 0 on pixels it does not speak
    of, such as the background) and false-colour PNG (``mask``'s pixels coloured), each written to ``at[path]``;
    returns the PNG's colour scale as the stats JSON records it (``colour_scales``)."""
    import numpy as np

    from warpbw.io.exr import write_exr, write_false_colour_png

    v = np.asarray(values, dtype=np.float32)
    write_exr(at[exr], np.stack([v, np.asarray(mask, dtype=np.float32)], axis=-1), channels=["Y", "A"])
    lo, hi = write_false_colour_png(at[png], v, mask=mask & (v > 0) if log else mask, log=log)
    return {"png": png.name, "scale": "log" if log else "linear", "from": lo, "to": hi}


def _write_aovs(res, out: Path, at: dict) -> dict:
    """The adaptive method's AOVs (EXR + false-colour PNG each); returns their colour scales by name.  They speak of
    the spheres' and meshes' pixels: in a frame with planes in front (``aovs["plane"]``) not of the planes' pixels,
    where the adaptive maps hold what they hold on the background (N_p 0, not shaded)."""
    mask = res.coverage & ~res.aovs["plane"] if "plane" in res.aovs else res.coverage
    return {name: _write_map(at, exr, png, res.aovs[name], mask, log=AOVS[name][1] == "log")
            for name, (exr, png) in _aov_paths(out).items()}


def _scales_line(scales: dict) -> str:
    """The false-colour PNGs' scales, for the summary a render prints."""
    return "  colour scales (dark blue to yellow): " + ", ".join(
        f"{name} {s['from']:.3g} to {s['to']:.3g}" + (" (log)" if s["scale"] == "log" else "")
        for name, s in scales.items())


def _record_total(stats: dict, t0: float) -> None:
    """``time_s.total``, the render call since ``t0``, and ``time_s.unstaged``, the part of it no other key holds
    (Python imports on a process's first frame, scene checks, progress bars): the keys other than ``frame`` (itself a
    sum of the frame's stages) then add up to ``total`` (a 24x24 reference frame's held 0.056 s of its 0.095 s)."""
    t = stats["time_s"]
    total = time.perf_counter() - t0
    t["unstaged"] = round(max(total - sum(v for k, v in t.items() if k != "frame"), 0.0), 6)
    t["total"] = round(total, 6)


def _render(scene, out: Path, spp: int, seed: int, mis: bool, device: str, exposure: float, force: bool,
            threads, quiet: bool, method: str = "reference", budget: float | None = None,
            n_b: int | None = None, adaptive_options: dict | None = None, texts: dict | None = None) -> dict:
    """Render ``scene`` and write the image, its preview, stats (and AOVs); ``texts`` (path -> text) are written
    with them, in the same set (the demo's scene file)."""
    from warpbw.pipeline import render_adaptive, render_reference

    outs = _outputs(out)
    texts = texts or {}
    adaptive = method == "adaptive"
    paths = (list(outs.values()) + ([p for pair in _aov_paths(out).values() for p in pair] if adaptive else [])
             + list(texts))
    check_overwrite(paths, force, inputs=scene.input_files())
    _warn_of_earlier_outputs(out, paths)
    init_warp(device)
    t0 = time.perf_counter()
    if adaptive:
        res = render_adaptive(scene, budget=budget, seed=seed, mis=mis, n_b=n_b, device=device, progress=not quiet,
                              threads=threads, **(adaptive_options or {}))
    else:
        res = render_reference(scene, spp=spp, seed=seed, mis=mis, device=device, progress=not quiet,
                               threads=threads)
    _record_total(res.stats, t0)
    with staged_outputs(paths, force=force) as at:   # all of them, or none: an error leaves the old set
        if adaptive:   # first, so that the stats JSON records their colour scales
            res.stats["colour_scales"] = _write_aovs(res, out, at)
        _write_render(res, outs, exposure, at)
        for p, text in texts.items():
            at[p].write_text(text)
    _warn_if_empty(res)
    if not quiet:
        t = res.stats["time_s"]
        w, h = res.stats["resolution"]
        if adaptive:
            print(f"{printable(outs['exr'])}  ({w}x{h}, adaptive, budget {budget:g} spp, n_b {res.stats['n_b']}, "
                  f"{res.stats['pixels_covered']} covered pixels)")
            print(f"  shaded {res.stats['pixels_shaded']} pixels ({100 * res.stats['shaded_fraction']:.1f}%), "
                  f"{res.stats['samples']} samples ({res.stats['samples_per_covered_pixel']:.2f} per covered pixel)")
            print(f"  gbuffer {t['gbuffer'] * 1e3:.1f} ms, bandwidth {t['bandwidth'] * 1e3:.1f} ms "
                  f"({100 * res.stats['bandwidth_time_fraction']:.1f}% of the frame), shading {t['shading']:.3f} s, "
                  f"up-sampling {t['upsampling'] * 1e3:.1f} ms"
                  + (f", lights (exact, every pixel) {t['lights'] * 1e3:.1f} ms" if "lights" in t else "")
                  + f", frame {t['frame']:.3f} s, total {t['total']:.2f} s")
            print(f"  AOVs {', '.join(printable(str(p[0])) for p in _aov_paths(out).values())} (+ .png)")
            print(_scales_line(res.stats["colour_scales"]))
        else:
            sps = res.stats["samples_per_second"]
            taken = f"{spp} spp" if res.stats["spp"] else "directional lights alone: exact, no samples"
            print(f"{printable(outs['exr'])}  ({w}x{h}, {taken}, {res.stats['pixels_covered']} covered pixels)")
            print(f"  gbuffer {t['gbuffer'] * 1e3:.1f} ms, shading {t['shading']:.3f} s"
                  + (f" ({sps / 1e6:.2f} M samples/s)" if sps else "") + f", total {t['total']:.2f} s")
        print(f"  preview {printable(outs['png'])}, stats {printable(outs['json'])}"
              + "".join(f", {printable(p)}" for p in texts))
    return res.stats


def _warn_if_empty(res, scene=None) -> None:
    """An image in which no pixel sees geometry is almost always a camera or a scene mistake, and so is one whose
    covered pixels are all black (a light of zero: a probe whose every texel was NaN, say): say so.  With ``scene``,
    a camera at or below every plane is named: planes face +Y and are seen from above only (``warpbw.scene``)."""
    import numpy as np

    if res.stats.get("pixels_covered") == 0:
        from warpbw.scene import PlaneObject

        heights = [o.center[1] for o in (scene.objects if scene is not None else ()) if isinstance(o, PlaneObject)]
        y = scene.camera.position[1] if heights else 0.0
        below = (f"; planes face +Y and are seen from above only, and the camera (y = {y:g}) is not above any "
                 f"(y = {min(heights):g} at the lowest)" if heights and y <= min(heights) else "")
        print("warpbw: warning: no pixel is covered by geometry, so the image is empty (check [camera] "
              f"position, look_at and fov against the objects{below})", file=sys.stderr)
    elif not np.any(res.image[res.coverage]):
        print("warpbw: warning: every covered pixel is black (0): no light reaches the surfaces, or they reflect "
              "none (check [environment] constant, scale and its probe's values, each [[light]]'s radiance and "
              "direction, and the materials)", file=sys.stderr)


def _is_mixed(scene) -> bool:
    """Planes beside spheres or meshes: both renderers, composited (warpbw.pipeline.render_with_planes)."""
    return scene.has_planes and scene.has_surfaces


def _render_filtering_cli(scene, args) -> int:
    """``warpbw render`` of a scene with planes: the reflectance-filtering renderer (004)."""
    from warpbw.filtering import render_filtering

    if args.method != "reference" or args.budget is not None or args.nb is not None or args.mis \
            or _adaptive_options(args):
        raise WarpbwError(f"{scene.source}: a scene with planes renders with --filter METHOD (reflectance "
                          "filtering, 004); --method, --budget, --nb and --mis apply to spheres and meshes")
    method = _filter_method(args)
    out = Path(args.output)
    outs = _outputs(out)
    level_paths = _level_map_paths(out, ".level", method)
    check_overwrite(list(outs.values()) + level_paths, args.force, inputs=scene.input_files())
    _warn_of_earlier_outputs(out, list(outs.values()) + level_paths)
    init_warp(args.device)
    t0 = time.perf_counter()
    aniso = {} if args.max_anisotropy is None else {"max_anisotropy": args.max_anisotropy}
    res = render_filtering(scene, method, spp=args.spp, seed=args.seed, device=args.device,
                           progress=not args.quiet, threads=args.threads, env_spp=args.spp, **aniso)
    res.stats["time_s"] = {"frame": round(res.time_s, 6), "total": round(time.perf_counter() - t0, 6)}
    with staged_outputs(list(outs.values()) + level_paths, force=args.force) as at:
        res.stats["colour_scales"] = {"level": _write_map(at, *level_paths, res.level, res.coverage)} \
            if level_paths else {}
        _write_render(res, outs, args.exposure, at)
    _warn_if_empty(res, scene)
    if not args.quiet:
        w, h = res.stats["resolution"]
        extra = f", {args.spp} rays/pixel" if method == "ground_truth" else \
            f", mean mip level {res.stats['mean_level']:.2f}"
        if "environment" in res.stats:
            n_env = res.stats["environment"]["samples_per_pixel"]
            extra += f", environment: {n_env} samples/pixel (BRDF + environment)"
        print(f"{printable(outs['exr'])}  ({w}x{h}, filter {method}{extra}, "
              f"{res.stats['pixels_covered']} covered pixels)")
        print(f"  frame {res.time_s * 1e3:.1f} ms, total {res.stats['time_s']['total']:.2f} s")
        print(f"  preview {printable(outs['png'])}, stats {printable(outs['json'])}"
              + (f", mip level {printable(str(level_paths[0]))} (+ .png)" if level_paths else ""))
        if res.stats["colour_scales"]:
            print(_scales_line(res.stats["colour_scales"]))
    return 0


def _level_map_paths(out: Path, suffix: str, method: str) -> list:
    """The mip level map's EXR and PNG (OUT{suffix}.exr / .png); none for --filter ground_truth, which traces rays
    and reads no mip level (it wrote a map of zeros, as if every plane pixel were read at level 0)."""
    if method == "ground_truth":
        return []
    return [out.with_suffix(f"{suffix}.exr"), out.with_suffix(f"{suffix}.png")]


def _warn_of_earlier_outputs(out: Path, paths) -> None:
    """Warn, before the work, of the outputs an earlier render at ``-o out`` wrote that this one does not (``paths``
    are this one's): an adaptive render's AOVs, a filtered one's mip level map.  They stay beside the new image and
    no longer describe it (an adaptive render, then a reference one with --force, left the adaptive run's level,
    N_p and spp maps beside the reference image: processes audit, session 79)."""
    import warnings

    every = dict.fromkeys([*_outputs(out).values(), *(p for pair in _aov_paths(out).values() for p in pair),
                           *_level_map_paths(out, ".level", None), *_level_map_paths(out, ".mip_level", None)])
    left = [p for p in every if p not in set(paths) and p.is_file()]
    if len(left) == 1:
        said = (f"{left[0]}: an earlier render's output at -o {out} that this render does not write: it stays beside "
                "the new image and does not describe it (remove it")
    elif left:
        said = (f"{left[0]} and {len(left) - 1} more: outputs of an earlier render at -o {out} that this render does "
                "not write: they stay beside the new image and do not describe it (remove them")
    if left:
        warnings.warn(f"{said}, or render to another -o)", stacklevel=2)


def _filter_method(args) -> str:
    """--filter (gmm_aligned by default), with the options that go with it checked before any work: the ground truth
    traces at least MIN_GT_SPP rays per pixel and filters nothing (a plane scene and a mixed one alike; the mixed
    one said "spp (ground-truth rays per pixel)", the library's name, and both took --max-anisotropy and dropped it)."""
    method = args.filter or "gmm_aligned"
    if method == "ground_truth" and args.spp is not None and args.spp < MIN_GT_SPP:
        raise WarpbwError(f"--spp {args.spp}: --filter ground_truth traces at least {MIN_GT_SPP} rays per pixel "
                          "(004's 'many rays')")
    if method == "ground_truth" and args.max_anisotropy is not None:
        raise WarpbwError(f"--max-anisotropy {args.max_anisotropy}: --filter ground_truth traces rays and filters "
                          "nothing (the option applies to the filtered methods)")
    return method


def _render_mixed_cli(scene, args) -> int:
    """``warpbw render`` of a scene with planes beside spheres or meshes: the spheres and meshes with --method
    (reference or adaptive), then the planes in front of them with --filter (warpbw.pipeline.render_with_planes)."""
    from warpbw.pipeline import render_with_planes

    method = _filter_method(args)
    adaptive = args.method == "adaptive"
    out = Path(args.output)
    outs = _outputs(out)
    mip_paths = _level_map_paths(out, ".mip_level", method)
    aov_paths = [p for pair in _aov_paths(out).values() for p in pair] if adaptive else []
    paths = list(outs.values()) + aov_paths + mip_paths
    check_overwrite(paths, args.force, inputs=scene.input_files())
    _warn_of_earlier_outputs(out, paths)
    init_warp(args.device)
    t0 = time.perf_counter()
    res = render_with_planes(scene, method, args.spp, seed=args.seed, method=args.method, budget=args.budget,
                             mis=args.mis, n_b=args.nb, device=args.device, progress=not args.quiet,
                             threads=args.threads, max_anisotropy=args.max_anisotropy, **_adaptive_options(args))
    _record_total(res.stats, t0)
    with staged_outputs(paths, force=args.force) as at:
        scales = _write_aovs(res, out, at) if adaptive else {}
        if mip_paths:
            scales["mip_level"] = _write_map(at, *mip_paths, res.aovs["mip_level"], res.aovs["plane"])
        res.stats["colour_scales"] = scales
        _write_render(res, outs, args.exposure, at)
    _warn_if_empty(res, scene)
    if not args.quiet:
        t = res.stats["time_s"]
        w, h = res.stats["resolution"]
        pl = res.stats["planes"]
        surf = (f"adaptive, budget {args.budget:g} spp" if adaptive else f"reference, {res.stats['spp']} spp"
                if res.stats["spp"] else "reference, directional lights alone: exact, no samples")
        planes = (f"{args.spp} rays/pixel" if method == "ground_truth" else f"mean mip level {pl['mean_level']:.2f}")
        print(f"{printable(outs['exr'])}  ({w}x{h}, {res.stats['pixels_covered']} covered pixels)")
        print(f"  spheres and meshes: {surf}, {res.stats['pixels_shaded']} pixels shaded "
              f"({res.stats['pixels_hidden']} hidden by planes, not shaded), frame {(t['frame'] - t['planes']):.3f} s")
        print(f"  planes in front: {pl['pixels_covered']} pixels, filter {method}, {planes}, frame {t['planes']:.3f} s")
        print(f"  frame {t['frame']:.3f} s, total {t['total']:.2f} s")
        print(f"  preview {printable(outs['png'])}, stats {printable(outs['json'])}"
              + (f", mip level {printable(str(mip_paths[0]))} (+ .png)" if mip_paths else "")
              + (f", AOVs {', '.join(printable(str(p[0])) for p in _aov_paths(out).values())} (+ .png)"
                 if adaptive else ""))
        if res.stats["colour_scales"]:
            print(_scales_line(res.stats["colour_scales"]))
    return 0


def _adaptive_options(args) -> dict:
    """--allocation / --nyquist / --upsample / --env-signal as render_adaptive keywords (only those given)."""
    return {k: getattr(args, k) for k in ("allocation", "nyquist", "upsample", "env_signal")
            if getattr(args, k, None) is not None}


def add_adaptive_options(p) -> None:
    """--allocation, --nyquist, --upsample and --env-signal, shared by render and bench."""
    p.add_argument("--allocation", choices=_ALLOCATIONS, default=None,
                   help="adaptive: how N_p follows the pass's estimates: measured (default; the pass's own MIS "
                   "standard deviation), variance (002 Sec. 2.4: the Eq. 9 bound), sqrt (its square root), "
                   "relative (bound / radiance^2), uniform")
    p.add_argument("--nyquist", type=_positive_float("nyquist", FLOAT32_MAX), default=None,
                   help="adaptive: sampling rate in multiples of the image bandwidth b_p for the level of Eq. 11, a "
                   "positive number (default 2, Nyquist; larger shades more pixels at finer levels)")
    p.add_argument("--upsample", choices=_UPSAMPLE_MODES, default=None,
                   help="adaptive: how a pixel that is not shaded is filled from its parents: normal (default; the "
                   "paper's bilateral weights fitting a plane in the surface normal, so that shading that follows "
                   "the normal, on bumps, is not blurred) or paper (002 Sec. 3.2: the weighted mean)")
    p.add_argument("--env-signal", choices=ENV_SIGNALS, default=None,
                   help="adaptive: what the wavelet analysis of the probe's angular bandwidth (002 Eq. 7) reads: "
                   "log (default), log(1 + L / mean L), where a sun or a small bright light no longer hides the edges "
                   "around it, or radiance (the paper's), which near-mirrors and sharp lobes under small lights "
                   "up-sample across (README)")


def add_anisotropy_option(p, default) -> None:
    """--max-anisotropy, shared by render and bench-filtering (scenes with planes)."""
    p.add_argument("--max-anisotropy", type=_positive_int("max-anisotropy", MAX_ANISOTROPY), default=default,
                   metavar="N", help="scenes with planes: filter each pixel's footprint with up to N trilinear probes "
                   f"along its major axis, as GPUs' anisotropic filtering (1 to {MAX_ANISOTROPY}; default 1: one "
                   "isotropic probe at the footprint's larger side, 004 Sec. 4.2). Where the plane is seen at a "
                   "grazing angle, sharper and mostly closer to the ground truth, but it flickers more "
                   "(docs/measurements.md); up to N times the texture fetches")


def cmd_render(args) -> int:
    from warpbw.scene import load_scene

    if args.method == "adaptive" and args.budget is None:
        raise WarpbwError("--method adaptive needs --budget SAMPLES_PER_PIXEL (mean samples per covered pixel)")
    if args.method == "reference" and (args.budget is not None or args.nb is not None
                                       or _adaptive_options(args)):
        raise WarpbwError("--budget, --nb, --allocation, --nyquist, --upsample and --env-signal apply to --method "
                          "adaptive only, on spheres and meshes under an [environment] (the reference takes --spp; "
                          "a scene of planes alone renders with --filter METHOD)")
    scene = load_scene(args.scene)
    mixed = _is_mixed(scene)
    if args.method == "adaptive" and args.spp is not None and not mixed:
        raise WarpbwError("--spp applies to --method reference only (--method adaptive takes --budget)")
    if scene.has_planes and (args.spp is not None or args.seed is not None) \
            and scene.environment is None and args.filter != "ground_truth":
        # a mixed scene's spheres and meshes under lights alone take no samples either (their term is exact)
        opt = f"--spp {args.spp}" if args.spp is not None else f"--seed {args.seed}"
        lit = f"{scene.source} is" if mixed else f"the planes of {scene.source} are"
        raise WarpbwError(f"{opt}: {lit} lit by [[light]]s alone, shaded in closed form without random numbers; "
                          "--spp and --seed apply to the rays of --filter ground_truth, or the samples of an "
                          "[environment]")
    if mixed and scene.environment is None and args.mis:
        raise WarpbwError(f"--mis: {scene.source} is lit by [[light]]s alone, shaded in closed form without samples; "
                          "--mis weighs the samples of an [environment]")
    if not scene.has_planes and scene.environment is None \
            and (args.spp is not None or args.mis or args.seed is not None):
        # the directional lights' term is exact: a reference frame of them takes no sample for --spp to count,
        # --mis to weigh or --seed to draw (a frame that printed "8 spp" and recorded MIS had taken none)
        opt = (f"--spp {args.spp}" if args.spp is not None else "--mis" if args.mis else f"--seed {args.seed}")
        raise WarpbwError(f"{opt}: {scene.source} is lit by [[light]]s alone, shaded in closed form without "
                          "samples; --spp, --mis and --seed apply to the samples of an [environment]")
    if args.spp is None:
        args.spp = DEFAULT_SPP
    if args.seed is None:
        args.seed = 0
    if mixed:
        return _render_mixed_cli(scene, args)
    if scene.has_planes:
        return _render_filtering_cli(scene, args)
    if args.filter is not None:
        raise WarpbwError(f"--filter {args.filter}: applies to scenes with planes (shape = \"plane\") only")
    if args.max_anisotropy is not None:
        raise WarpbwError(f"--max-anisotropy {args.max_anisotropy}: applies to scenes with planes "
                          "(shape = \"plane\") only")
    _render(scene, Path(args.output), args.spp, args.seed, args.mis, args.device, args.exposure, args.force,
            args.threads, args.quiet, args.method, args.budget, args.nb, _adaptive_options(args))
    return 0


def cmd_demo(args) -> int:
    from warpbw.scene import DEFAULT_SCENE_TOML, default_scene

    if Path(args.output).suffix.lower() in (".exr", ".png", ".json", ".toml"):
        raise WarpbwError(f"-o {args.output}: expected a folder (demo writes demo.exr, demo.png, demo.json and "
                          f"{DEMO_SCENE_NAME} into it)")
    check_output_dir(args.output, "-o")
    out = Path(args.output) / "demo.exr"
    scene_file = Path(args.output) / DEMO_SCENE_NAME
    spp = DEMO_SPP if args.spp is None else args.spp
    _render(default_scene(), out, spp, args.seed or 0, True, args.device, args.exposure, args.force,
            args.threads, args.quiet, texts={scene_file: DEFAULT_SCENE_TOML})
    if not args.quiet:   # where to go next: the same scene, adaptively (the AOVs show where it shaded)
        import shlex

        print(f"next: warpbw render {shlex.quote(str(scene_file))} -o "
              f"{shlex.quote(str(Path(args.output) / 'adaptive.exr'))} --method adaptive --budget 4 --mis")
    return 0


def cmd_info(args) -> int:
    from precompute.asset_info import header_status
    from warpbw.pipeline import scene_summary
    from warpbw.scene import load_scene

    scene = load_scene(args.scene)
    s = scene_summary(scene, args.method)   # planes, spheres and meshes, or both
    # the precomputed files the materials name (sampling, bandwidth, gmm), as their headers describe them: another
    # version or other builder settings said before a render (the render still checks each against its source)
    used = [scene.materials[n] for n in scene.material_order]
    named = {str(p) for m in used for p in (m.sampling, m.bandwidth, m.gmm) if p is not None}
    s["assets"] = [header_status(f) for f in s["files"] if f in named]
    _say_refused(scene, s["assets"], used)
    if args.json:   # strict JSON, as compare's and warpbw-precompute info's: a header's NaN printed NaN, not null
        print(json_text(s), end="")
        return 0
    print(f"scene       {printable(s['scene'])}")
    print(f"resolution  {s['resolution'][0]} x {s['resolution'][1]}")
    print(f"environment {printable(s['environment'])}")
    for li in s.get("lights", []):
        print(f"light       {printable(li)}")
    print("objects")
    for o in s["objects"]:
        print(f"  - {printable(o)}")
    print("materials   " + printable(", ".join(f"{k} ({v})" for k, v in s["materials"].items())))
    if s["unused_materials"]:
        print("unused      " + printable(", ".join(s["unused_materials"])) + " (not loaded)")
    print("stages      " + "; ".join(s["stages"]))
    if "frame_memory_bytes" in s:
        print(f"memory      about {s['frame_memory_bytes'] / 1e9:.2g} GB per {args.method} frame"
              + (" of the spheres and meshes" if any("planes:" in st for st in s["stages"]) else "")
              + " beyond the assets")
    if "probe_load_memory_bytes" in s:
        print(f"            about {s['probe_load_memory_bytes'] / 1e9:.2g} GB at the peak to load the probe"
              + (f", {s['probe_bandwidth_memory_bytes'] / 1e9:.2g} GB to build its bandwidth map (once; then cached)"
                 if "probe_bandwidth_memory_bytes" in s else ""))
    if "mesh_memory_bytes" in s:
        print(f"            about {s['mesh_memory_bytes'] / 1e9:.2g} GB for the meshes' {s['mesh_triangles']:,} "
              "triangles")
    if s["files"]:
        print("files")
        status = {a["path"]: a for a in s["assets"]}
        for f in s["files"]:
            print(f"  - {printable(f)}" + (f" ({printable(_asset_status_text(status[f]))})" if f in status else ""))
    return 0


def _say_refused(scene, assets: list, materials: list) -> None:
    """Add ``refused``, the reader's words, to each of ``assets`` (``header_status`` records) that one of
    ``materials`` names where a render refuses it (``_refusal``): ``warpbw info`` said "builder settings current" of a
    nu_rho table of another lookup (session 76's audit), and of a file of another format than its key reads, one
    built from another BRDF or normal map, and a GMM mipmap fitted with other options (session 77's)."""
    for a in assets:
        if "error" in a or a["not_read"] is not None:
            continue
        for m in materials:
            for key in ("sampling", "bandwidth", "gmm"):
                if "refused" not in a and str(getattr(m, key)) == a["path"]:
                    why = _refusal(scene, a["path"], m, key)
                    if why is not None:
                        a["refused"] = why


def _refusal(scene, path: str, m, key: str) -> str | None:
    """Why a render refuses the asset file ``path`` as material ``m``'s ``key`` (sampling, bandwidth, gmm), in its
    reader's words (each ends in what builds the right one); None where it reads it.  The tables (a few MB) are read
    by the render's own readers, given what the material's BRDF file is by content; a GMM mipmap (up to hundreds of
    MB) is checked from its header alone, by the checks of its reader that need no levels
    (``warpbw.filtering.gmm_header_problem``)."""
    from precompute.brdf_bandwidth import read_brdf_bandwidth
    from precompute.brdf_sampling import brdf_source_unread, read_sampling
    from warpbw.filtering import gmm_header_problem

    if key == "gmm":
        return gmm_header_problem(scene, m.name, path)
    lookup = m.lookup if key == "bandwidth" else None   # sampling tables are the kind default's
    file, material = (m.table, m.npf_name) if m.type == "npf" else (m.file, None)
    source = brdf_source_unread(file, material, lookup)
    try:
        (read_brdf_bandwidth if key == "bandwidth" else read_sampling)(path, source)
    except WarpbwError as exc:
        said = str(exc)
        return said[len(f"{path}: "):] if said.startswith(f"{path}: ") else said
    return None


def _asset_status_text(a: dict) -> str:
    """An asset file's ``header_status`` in a few words, for ``warpbw info``'s list of files."""
    if "error" in a:
        return a["error"]
    if "refused" in a:
        return f"{a['what']}, version {a['version']}; a render refuses it: {a['refused']}"
    if a["not_read"] is not None:   # another version, or a format this warpbw does not know
        return f"{a['what'] or a['format']}: {a['not_read']}"
    what = f"{a['what']}, version {a['version']}"
    if a["settings"] == "differ":
        return f"{what}; builder settings differ ({a['settings_differ']}): read as it is"
    return f"{what}; builder settings current"


_PSNR_IDENTICAL = "identical over the covered pixels"
_PSNR_UNDEFINED = "the reference has no positive value over the covered pixels"


def cmd_compare(args) -> int:
    import numpy as np

    from warpbw.io.exr import exr_size, in_display_window, read_exr, rgb_of
    from warpbw.metrics import compare_images, coverage_from_alpha, relmse_map
    from warpbw.scene import MAX_RESOLUTION

    maps = _error_map_paths(args)
    for name in (args.test, args.reference):   # the frame is allocated in full: bounded before any pixel is read
        w, h = exr_size(name, window="display")
        if max(w, h) > MAX_RESOLUTION:
            raise WarpbwError(f"{name}: its display window (the image's frame) is {w}x{h}; expected at most "
                              f"{MAX_RESOLUTION} pixels per side, the largest frame warpbw renders")
    # each over its display window, the image's frame, whatever part of it the file stores (its data window)
    a = in_display_window(read_exr(args.test))
    b = in_display_window(read_exr(args.reference))
    ta, tb = rgb_of(a), rgb_of(b)   # R,G,B, or a lone grey channel; anything else is refused by name
    if ta.shape != tb.shape:
        raise WarpbwError(f"{args.test} is {ta.shape[1]}x{ta.shape[0]} but {args.reference} is "
                          f"{tb.shape[1]}x{tb.shape[0]}: expected images of the same size")
    # the reference's A says what is covered; without one (another renderer's image, whose background shows the
    # probe), the test image's, and the output says so: the image judged then chooses the pixels it is judged on
    mask, coverage_from = coverage_from_alpha(b.pixels, b.channels), "reference"
    if mask is None:
        mask, coverage_from = coverage_from_alpha(a.pixels, a.channels), "test"
    if mask is None:
        mask, coverage_from = (np.abs(ta).sum(-1) > 0) | (np.abs(tb).sum(-1) > 0), None
    for name, img in ((args.test, ta), (args.reference, tb)):
        bad = int((~np.isfinite(img[mask])).sum())
        if bad:
            raise WarpbwError(f"{name}: {bad} non-finite values over covered pixels")
    r = compare_images(ta, tb, mask)
    _warn_if_seed_shared(args.test, args.reference)
    # whose A channel said which pixels count; None: the non-black pixels
    r["coverage_from"] = {"reference": str(args.reference), "test": str(args.test)}.get(coverage_from)
    if maps:
        err = relmse_map(ta, tb, mask)
        top = float(err[mask].max()) if mask.any() else 0.0
        if top > FLOAT32_MAX:   # the EXR holds float32: numpy's "overflow encountered in cast" and inf texels
            raise WarpbwError(f"--error-map {maps[0]}: the per-pixel relative squared error reaches {top:.3g}, beyond "
                              f"the {FLOAT32_MAX:.3g} a float32 EXR holds (radiance of {args.test} or "
                              f"{args.reference} near float32's top); nothing written (without --error-map, compare "
                              "gives the PSNR and relMSE)")
        with staged_outputs(maps, force=args.force) as at:
            lo, hi = _write_error_map([at[m] for m in maps], err, mask, args.error_range)
        r.update(error_map=str(maps[0]), error_range=[lo, hi])
    p = r["psnr_db"]
    why = None if math.isfinite(p) else _PSNR_IDENTICAL if p > 0 else _PSNR_UNDEFINED
    if args.json:
        if why:   # strict JSON writes an infinite PSNR as null: say which one it is
            r["psnr_note"] = why
        print(json_text(r), end="")
    else:
        print(f"PSNR   {p:.3f} dB" if why is None else f"PSNR   {'inf' if p > 0 else 'undefined'} ({why})")
        print(f"relMSE {r['relmse']:.6g}")
        print(f"pixels {r['pixels']} covered; the worst {_WORST_FRACTION:.0%} of them ({r['worst_pixels']}) hold "
              f"{100 * r['worst_share']:.1f}% of the relMSE")
        if coverage_from == "test":   # the image judged chose its own pixels
            print(f"coverage from {printable(args.test)}'s A channel ({printable(args.reference)} has none)")
        if maps and lo < hi:
            print(f"error map {printable(maps[0])} (+ {printable(maps[1].name)}, "
                  f"log colour scale {lo:.3g} to {hi:.3g}: "
                  f"--error-range {lo:.3g},{hi:.3g} draws another map on it)")
        elif maps:   # no scale to give: no error anywhere, or one value wherever there is any
            what = "no covered pixel has any error" if r["relmse"] == 0 else f"every error is {hi:.3g}"
            print(f"error map {printable(maps[0])} (+ {printable(maps[1].name)}; {what})")
    return 0


def _render_record(exr) -> dict | None:
    """The stats JSON ``warpbw render`` wrote beside ``exr`` (its name with .json), when it is one of a sampled
    frame (reference or adaptive, with a seed); else None."""
    try:
        rec = json.loads(Path(exr).with_suffix(".json").read_text())
    except (OSError, ValueError, RecursionError):   # none, unreadable, not JSON, or nested past the parser: nothing
        return None
    ok = isinstance(rec, dict) and rec.get("method") in ("reference", "adaptive") and type(rec.get("seed")) is int
    return rec if ok else None


def _warn_if_seed_shared(test, reference) -> None:
    """At one seed every pixel draws the same stream of samples, so an image at N spp is the first N samples of one
    at more (and an adaptive frame's finest pixels are the reference's): its error against such a "ground truth"
    reads low (in theory 10 log10((1 + 1/16) / (1 - 1/16)) = 0.54 dB at 64 against 1024 spp; 0.8 dB measured on the
    bunny, session 62).  Say so when both images' render records show it."""
    a, b = _render_record(test), _render_record(reference)
    if a is not None and b is not None and a["seed"] == b["seed"] and a.get("scene") == b.get("scene"):
        print(printable(f"warpbw: warning: {test} and {reference} were rendered from one scene at the same --seed "
                        f"{a['seed']} (their .json records say so): they share their random samples, so the error "
                        "reads lower than against an independent reference; render the reference with another "
                        "--seed"), file=sys.stderr)   # the paths as given: a newline in one split the line


def _error_map_paths(args) -> list:
    """--error-map PATH.exr and its PNG beside it ([] without --error-map), refused before any work if either exists
    (without --force) or would replace one of the images compared (whatever --force says); --error-range checked."""
    rng = args.error_range
    if args.force and not args.error_map:   # it was accepted and did nothing
        raise WarpbwError("--force: compare writes nothing but --error-map PATH.exr (give it, or leave --force out)")
    if rng is not None and not args.error_map:
        raise WarpbwError("--error-range: give --error-map PATH.exr too (the range is that map's colour scale)")
    if rng is not None and (len(rng) != 2 or rng[0] >= rng[1]):
        raise WarpbwError(f"--error-range {','.join(f'{v:g}' for v in rng)}: expected two numbers LO,HI with "
                          "0 < LO < HI")
    if not args.error_map:
        return []
    out = Path(args.error_map)
    if out.suffix.lower() != ".exr":
        raise WarpbwError(f"--error-map {out}: expected a path ending in .exr")
    paths = [out, out.with_suffix(".png")]
    check_overwrite(paths, args.force, option="--error-map", inputs=(args.test, args.reference),
                    inputs_are="one of the images compared")
    return paths


def _write_error_map(paths: list, err, mask, error_range) -> tuple:
    """The per-pixel relMSE term as EXR (Y; A = the pixels compared) and a log-scaled false-colour PNG over
    ``error_range`` (LO, HI), else ERROR_MAP_DECADES below the map's largest value (or from its smallest, when
    nearer) up to it; returns the range used."""
    import numpy as np

    from warpbw.io.exr import write_exr, write_false_colour_png

    write_exr(paths[0], np.stack([err, mask], -1).astype(np.float32), channels=["Y", "A"])
    if error_range is None:
        shown = err[mask & (err > 0)]
        hi = float(shown.max()) if shown.size else 1.0
        error_range = (max(float(shown.min()) if shown.size else hi, hi * 10.0 ** -ERROR_MAP_DECADES), hi)
    lo, hi = error_range
    return write_false_colour_png(paths[1], err, mask=mask & (err > 0), vmin=lo, vmax=hi, log=True)


def _positive_int(name, hi=None):
    def parse(s):
        try:
            v = int(s)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a positive integer, got {s!r}") from None
        if v < 1:
            raise argparse.ArgumentTypeError(f"expected a positive integer, got {v}")
        if hi is not None and v > hi:
            raise argparse.ArgumentTypeError(f"expected a positive integer <= {hi}{_why(hi, name)}, got {v}")
        return v
    parse.__name__ = name
    return parse


def _gt_spp(s):
    """--gt-spp of warpbw bench: a positive int32 that splits into the ground truth's equal chunks."""
    from warpbw.bench import gt_spp_refusal

    v = _positive_int("gt-spp", INT32_MAX)(s)
    why = gt_spp_refusal(v)
    if why is not None:
        raise argparse.ArgumentTypeError(f"{why}, got {v}")
    return v


def _why(hi, name: str) -> str:
    """Why the option ``name`` has the upper bound ``hi``, for the parsers' messages.  --threads' bound varies with the
    machine, so it is told by the name: by its value, --flicker-pairs (8) read "4 per CPU core" on 2 cores."""
    if name == "threads":
        return f" ({THREADS_PER_CORE_MAX} per CPU core, {os.cpu_count() or 1} here)"
    return {INT32_MAX: " (an int32 in the kernels)",
            BUDGET_MAX: " (N_p, up to 256 x budget, is an int32 in the kernels)",
            FLOAT32_MAX: " (a float32 in the kernels)",
            N_B_MAX: " (002 Fig. 13 sweeps n_b from 16 to 1024)",
            RUNS_MAX: " (the timed runs of one point)"}.get(hi, "")


def _number_list(name, kind, hi=None):
    def parse(s):
        if any(not x.strip() for x in s.split(",")):   # "1,,2" once dropped the empty item without a word
            raise argparse.ArgumentTypeError(f"expected comma-separated {kind.__name__}s, got an empty item in {s!r}")
        try:
            vals = [kind(x) for x in s.split(",")]
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected comma-separated {kind.__name__}s, got {s!r}") from None
        if not vals or any(not (v > 0 and math.isfinite(v)) for v in vals):
            raise argparse.ArgumentTypeError(f"expected comma-separated positive numbers, got {s!r}")
        if hi is not None and max(vals) > hi:
            raise argparse.ArgumentTypeError(f"expected comma-separated positive numbers <= {hi:g}{_why(hi, name)}, "
                                             f"got {max(vals):g}")
        twice = sorted({v for v in vals if vals.count(v) > 1})
        if twice:  # each value is one measurement: a repeat would only run it again
            raise argparse.ArgumentTypeError(f"expected distinct values, got {', '.join(f'{v:g}' for v in twice)} "
                                             f"more than once in {s!r}")
        return vals
    parse.__name__ = name
    return parse


def _bench_outputs(args, scene, default_cache: Path | None = None) -> None:
    """Validate --json / --plot of a bench command and refuse to overwrite them without --force (or to overwrite one
    of the scene's files at all).  Every benchmark writes both (DESIGN.md, measurement protocol): the one not
    given goes beside the other, with its suffix.  The cache folder the command will write (--cache, else
    ``default_cache`` where the command has one) is checked too: a ground-truth chunk once failed to be written
    after it was rendered."""
    if not (args.json or args.plot):
        raise WarpbwError("give --json OUT.json and/or --plot OUT.png (where to write the results)")
    args.json, args.plot = record_paths(args.json, args.plot)
    outs = [Path(args.json), Path(args.plot)]
    for option, path in (("--json", args.json), ("--plot", args.plot)):
        check_output_file(path, option, force=True)
    if args.cache:
        _cache_apart_from_outputs(args.cache, (("--json", args.json), ("--plot", args.plot)))
        check_output_dir(args.cache, "--cache")
    elif default_cache is not None:
        env = os.environ.get("WARPBW_CACHE")
        try:
            check_output_dir(default_cache, "the ground-truth cache")
        except WarpbwError as exc:
            raise WarpbwError(f"{exc} ({f'WARPBW_CACHE={env}' if env else 'the default cache'}; pass --cache DIR to "
                              "cache the ground truth elsewhere)") from None
    check_overwrite(outs, args.force, option=("--json", "--plot"), inputs=scene.input_files())


def _cache_apart_from_outputs(cache, outputs) -> None:
    """Refuse a --cache folder that is, holds or lies under one of the outputs (``--cache r.json --json r.json``
    rendered everything, made the folder r.json and then failed to write the record there)."""
    c = Path(os.path.realpath(cache))   # realpath: a link loop gives a path, not an error
    for option, path in outputs:
        p = Path(os.path.realpath(path))
        if c == p:
            raise WarpbwError(f"--cache {cache}: the same path as {option} {path} (expected a folder of its own)")
        if c.is_relative_to(p):
            raise WarpbwError(f"--cache {cache}: lies under {option} {path} (expected a folder of its own)")
        if p.is_relative_to(c):
            raise WarpbwError(f"--cache {cache}: holds {option} {path} (expected a folder of its own, apart from "
                              "the outputs)")


def _write_bench(args, record: dict, write_plot) -> None:
    """The bench record as JSON and its plot as PNG (both: ``_bench_outputs`` names them), both or neither: a plot
    that fails leaves an earlier record as it was."""
    write_record(args.json, args.plot, record, write_plot, force=args.force, say=not args.quiet)
    warning = few_runs_warning(args.runs)
    if warning is not None:
        print(f"warpbw: warning: {warning}", file=sys.stderr)


def cmd_bench(args) -> int:
    from warpbw import bench
    from warpbw.scene import load_scene

    if args.nb_budget is not None and not args.nb:
        raise WarpbwError("--nb-budget: the budget of the n_b sweep, which only --nb asks for "
                          "(e.g. --nb 16,64,256,1024)")
    scene = load_scene(args.scene)
    _bench_outputs(args, scene, default_cache=bench.gt_cache_dir())
    if scene.has_planes and not scene.has_surfaces:
        raise WarpbwError(f"{scene.source}: a scene with planes is benchmarked by 'warpbw bench-filtering'")
    if scene.environment is None:
        # lights alone are exact (no sampling): every method would match the ground truth at 1 spp
        raise WarpbwError(f"{scene.source}: [environment]: missing; bench measures how the methods sample an "
                          "environment, and [[light]]s alone render exactly at any spp (add an [environment])")
    init_warp(args.device)
    log = (lambda *a, **k: None) if args.quiet else print
    record = bench.run_bench(scene, spp_list=args.spp, budgets=args.budgets, nb_list=args.nb or (),
                             gt_spp=args.gt_spp, runs=args.runs, mis=not args.no_mis,
                             cache_dir=Path(args.cache) if args.cache else None, nb_budget=args.nb_budget,
                             seed=args.seed, device=args.device, progress=not args.quiet, log=log,
                             adaptive_options=_adaptive_options(args))
    _write_bench(args, record, bench.write_plot)
    print(bench.format_table(record))
    if not record["ground_truth_converged"]:
        print(f"warpbw: warning: the ground truth is not converged (doubling changes PSNR by "
              f"{record['ground_truth_doubling_delta_db']:.2f} dB >= 0.5 dB): raise --gt-spp", file=sys.stderr)
    return 0


def cmd_bench_filtering(args) -> int:
    from warpbw import bench_filtering as bf
    from warpbw.scene import load_scene

    scene = load_scene(args.scene)
    _bench_outputs(args, scene)
    if not scene.has_planes:
        raise WarpbwError(f"{scene.source}: bench-filtering needs a scene with planes (shape = \"plane\"); "
                          "spheres and meshes are benchmarked by 'warpbw bench'")
    if args.spp is not None and scene.environment is None:
        raise WarpbwError(f"--spp {args.spp}: counts the samples of an [environment], and {scene.source} has none "
                          "(its [[light]]s are shaded in closed form)")
    init_warp(args.device)
    log = (lambda *a, **k: None) if args.quiet else print
    record = bf.run_bench_filtering(scene, zooms=args.zoom, gt_spp=args.gt_spp, runs=args.runs, seed=args.seed,
                                    env_spp=DEFAULT_SPP if args.spp is None else args.spp, device=args.device,
                                    max_anisotropy=args.max_anisotropy, flicker_pairs=args.flicker_pairs,
                                    cache=Path(args.cache) if args.cache else None, progress=not args.quiet, log=log)
    _write_bench(args, record, bf.write_plot)
    print(bf.format_table(record))
    return 0


def _positive_float(name, hi=None):
    def parse(s):
        try:
            v = float(s)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a positive number, got {s!r}") from None
        if not (v > 0 and math.isfinite(v)):
            raise argparse.ArgumentTypeError(f"expected a positive number, got {s}")
        if hi is not None and v > hi:
            raise argparse.ArgumentTypeError(f"expected a positive number <= {hi:g}{_why(hi, name)}, got {s}")
        return v
    parse.__name__ = name
    return parse


def _exposure(s):
    """--exposure: a finite number of stops within +-EXPOSURE_MAX_STOPS."""
    try:
        v = float(s)
    except ValueError:
        v = math.nan
    if not (math.isfinite(v) and abs(v) <= EXPOSURE_MAX_STOPS):
        raise argparse.ArgumentTypeError(f"expected a finite number of stops from {-EXPOSURE_MAX_STOPS:g} to "
                                         f"{EXPOSURE_MAX_STOPS:g}, got {s!r}")
    return v


def build_parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="warpbw", description="Render measured materials under HDR light with NVIDIA Warp "
                      "kernels\n(CPU by default; --device cuda selects a GPU, untested so far).",
                epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    def common(sp, spp_default):
        # default None: render refuses --spp with --method adaptive, so it must know whether --spp was given
        sp.add_argument("--spp", type=_positive_int("spp", INT32_MAX), default=None,
                        help=f"BRDF samples per pixel, N in 002 Eq. 2, 1 to 2^31-1 (default {spp_default})")
        # default None: render refuses a --seed its scene would not use, so it must know whether one was given
        sp.add_argument("--seed", type=parse_seed, default=None,
                        help="random seed, 0 to 2^32-1 (default 0); at one seed a pixel draws the same samples, so a "
                        "ground truth to compare with takes another")
        sp.add_argument("--device", default="cpu", help="Warp device: cpu (default) or cuda / cuda:N")
        sp.add_argument("--exposure", type=_exposure, default=0.0,
                        help=f"PNG preview exposure in stops, -{EXPOSURE_MAX_STOPS:g} to {EXPOSURE_MAX_STOPS:g} "
                        "(default 0): the preview is 2^exposure times the radiance clipped to [0, 1] per channel, "
                        "sRGB-encoded (IEC 61966-2-1); the EXR holds the radiance unscaled")
        sp.add_argument("--threads", type=_positive_int("threads", THREADS_MAX), default=None,
                        help=f"CPU threads tiling the shading launches, 1 to {THREADS_PER_CORE_MAX} per core "
                        f"({THREADS_MAX} here; default: all cores)")
        sp.add_argument("--force", action="store_true", help="overwrite existing output files")
        sp.add_argument("-q", "--quiet", action="store_true", help="no progress bar or summary")

    r = sub.add_parser("render", help="render a scene (reference or adaptive shading, 002; planes: filtered, 004)",
                       description="Render SCENE. Spheres and meshes: with the forward reference estimator, --spp "
                       "BRDF-importance samples per pixel (002 Eq. 2; --mis pairs each with an environment sample), "
                       "or with --method adaptive, bandwidth prediction and hierarchical shading at --budget samples "
                       "per covered pixel (002), which also writes its AOVs. Planes: reflectance filtering with "
                       "--filter (004). Writes "
                       "OUT.exr (linear radiance, A = coverage), OUT.png (sRGB preview) and OUT.json (time per "
                       "stage, samples, which stages ran; for a scene of planes, filtered by --filter: the "
                       "filter, its mean mip level and the frame's time, and the mip level map as "
                       "OUT.level.exr / .png (not for --filter ground_truth, which reads no mip level); planes "
                       "beside spheres or meshes: under 'planes', with "
                       "OUT.mip_level.exr / .png).")
    r.add_argument("scene", type=parse_path, help="scene file (TOML)")
    r.add_argument("-o", "--output", type=parse_path, required=True, metavar="OUT.exr",
                   help="output image (a name ending in .exr; OUT.png and OUT.json, and any AOVs, go beside it)")
    r.add_argument("--mis", action="store_true",
                   help="also sample the environment and combine by multiple importance sampling")
    r.add_argument("--method", choices=METHODS, default=METHODS[0],
                   help="reference: every pixel with --spp samples (default); adaptive: bandwidth prediction and "
                   "hierarchical shading (002), which also writes the AOVs OUT.level/.n_p/.spp/.variance/.shaded/.b_p "
                   "as EXR and false-colour PNG")
    r.add_argument("--budget", type=_positive_float("budget", BUDGET_MAX), default=None,
                   help="adaptive: mean samples per covered pixel, spread over the shaded pixels in proportion to the "
                   f"standard deviation the bandwidth pass measures: a positive number (may be below 1) up to "
                   f"{BUDGET_MAX:.3g}; required with --method adaptive")
    r.add_argument("--nb", type=_positive_int("nb", N_B_MAX), default=None,
                   help="adaptive: directions the bandwidth pass traces per 2x2 block of alike pixels (per pixel at "
                   f"an edge; each pixel pools its neighbours' too), n_b, 1 to {N_B_MAX} (default 16, 002 Sec. 2.6)")
    add_adaptive_options(r)
    r.add_argument("--filter", choices=_FILTER_METHODS, default=None, metavar="METHOD",
                   help="scenes with planes (shape = \"plane\", cook-torrance materials) always render with the "
                   "reflectance-filtering renderer (004): METHOD is gmm_aligned (default), gmm_unaligned, toksvig, "
                   "lean, fixed, or ground_truth (--spp >= 64 jittered rays per pixel, averaged over those that "
                   "hit the plane); the filtered methods also write the mip "
                   "level map OUT.level.exr/.png. Under an [environment], each filtered pixel takes --spp pairs of "
                   "one BRDF and one environment sample (MIS), each ground-truth ray one pair. A scene with planes "
                   "beside spheres or meshes renders both: the spheres and meshes with --method (and its options), "
                   "then the planes in front of them with --filter (--spp also sets the planes' samples under "
                   "--method adaptive); spheres and meshes behind a plane are not shaded; the mip level map is then "
                   "OUT.mip_level.exr/.png")
    add_anisotropy_option(r, None)
    common(r, DEFAULT_SPP)
    r.set_defaults(func=cmd_render)

    d = sub.add_parser("demo", help="render the embedded default scene (needs no file)",
                       description="Render the embedded default scene (three spheres, analytic materials, "
                       "procedural sky) to DIR/demo.exr, demo.png and demo.json, with the reference estimator and "
                       "multiple importance sampling (as render --mis): --spp BRDF samples per pixel, each paired "
                       "with an environment sample.  The scene itself goes to DIR/scene.toml, to edit and render "
                       "with warpbw render (e.g. --method adaptive --budget 4).")
    d.add_argument("-o", "--output", type=parse_path, default="warpbw_demo", metavar="DIR",
                   help="output directory (default ./warpbw_demo)")
    common(d, DEMO_SPP)
    d.set_defaults(func=cmd_demo)

    i = sub.add_parser("info", help="summarise what a scene needs", description="Summarise a scene: objects, "
                       "materials, light, the files it reads (beside each precomputed file a material names, what its "
                       "header says: its kind and version, a version this warpbw does not read, builder settings "
                       "other than the builder's, a table or GMM mipmap the render refuses, in its reader's words: of "
                       "another kind than its key, another BRDF or normal map, another lookup or fit options than its "
                       "material's, a damaged table), "
                       "the stages a render would run and the memory they would take (a frame; loading the probe "
                       "and, adaptive, building its bandwidth map; the placed meshes, from their files' headers).")
    i.add_argument("scene", type=parse_path, help="scene file (TOML)")
    i.add_argument("--method", choices=METHODS, default=METHODS[0],
                   help="the stages of warpbw render --method METHOD for the spheres and meshes (default reference; "
                        "adaptive adds the bandwidth pass, the pyramid and the up-sampling)")
    i.add_argument("--json", action="store_true",
                   help="print the summary as JSON (strict JSON: a value that is not a finite number as null)")
    i.set_defaults(func=cmd_info)

    from warpbw import bench as _bench

    def bench_common(p, runs_help: str):
        """--runs, --seed, --device, --force and -q of both bench commands."""
        p.add_argument("--runs", type=_positive_int("runs", RUNS_MAX), default=PROTOCOL_RUNS,
                       help=f"{runs_help}; 1 to {RUNS_MAX}")
        p.add_argument("--seed", type=parse_seed, default=0, help="random seed, 0 to 2^32-1 (default 0)")
        p.add_argument("--device", default="cpu", help="Warp device: cpu (default) or cuda / cuda:N")
        p.add_argument("--force", action="store_true", help="overwrite existing output files")
        p.add_argument("-q", "--quiet", action="store_true", help="only the final table")

    bn = sub.add_parser("bench", help="speed against accuracy: adaptive shading vs the reference",
                        description="The measurement protocol on SCENE: a cached ground truth (MIS, "
                        "--gt-spp), the reference at each --spp, adaptive shading at each --budget, each timed as the "
                        "median of --runs frames after a warm-up; PSNR and relative MSE over covered pixels (with two "
                        "runs or more, the PSNR's standard error over the runs); the equal-quality speed-up (reference "
                        "time at the adaptive error, log-log interpolation) and the bandwidth pass's share of the "
                        "frame.  --nb adds the n_b sweep of 002 Fig. 13 (its runs share seeds across n_b, and the "
                        "range's standard error is that of the paired differences).  In a scene "
                        "with planes beside spheres or meshes, the spheres and meshes are measured where no plane "
                        "hides them (the planes are not rendered: bench-filtering measures them).")
    bn.add_argument("scene", type=parse_path, help="scene file (TOML)")
    bn.add_argument("--json", type=parse_path, metavar="OUT.json",
                    help="write the record here (JSON); without it, beside --plot as OUT.json")
    bn.add_argument("--plot", type=parse_path, metavar="OUT.png",
                    help="write the plot here (PNG): PSNR against time, one curve per method; without it, beside "
                    "--json as OUT.png")
    bn.add_argument("--spp", type=_number_list("spp", int, INT32_MAX), default=list(_bench.DEFAULT_SPP),
                    metavar="N,N,...", help="reference sample counts, comma-separated, each 1 to 2^31-1 (default %s)"
                    % ",".join(map(str, _bench.DEFAULT_SPP)))
    bn.add_argument("--budgets", type=_number_list("budgets", float, BUDGET_MAX), default=list(_bench.DEFAULT_BUDGETS),
                    metavar="B,B,...", help="adaptive budgets, mean samples per covered pixel, comma-separated, each "
                    f"positive up to {BUDGET_MAX:.3g} "
                    "(default %s)" % ",".join(f"{b:g}" for b in _bench.DEFAULT_BUDGETS))
    bn.add_argument("--nb", type=_number_list("nb", int, N_B_MAX), default=None, metavar="N,N,...",
                    help=f"n_b sweep, comma-separated, each 1 to {N_B_MAX}, e.g. 16,64,256,1024 (002 Fig. 13), at "
                    "--nb-budget (without it, no sweep)")
    add_adaptive_options(bn)
    bn.add_argument("--nb-budget", type=_positive_float("nb-budget", BUDGET_MAX), default=None,
                    help=f"budget of the n_b sweep, a positive number up to {BUDGET_MAX:.3g} (default "
                    f"{_bench.NB_SWEEP_BUDGET})")
    bn.add_argument("--gt-spp", type=_gt_spp, default=_bench.DEFAULT_GT_SPP,
                    help=f"ground-truth samples per pixel (default {_bench.DEFAULT_GT_SPP}; cached in two or more "
                         f"equal chunks of at most {_bench.GT_CHUNK_SPP} spp: any even count from 2 to "
                         f"{2 * _bench.GT_CHUNK_SPP}, beyond it a multiple of {_bench.GT_CHUNK_SPP})")
    bn.add_argument("--no-mis", action="store_true",
                    help="compare with BRDF importance sampling only (default: MIS for both methods)")
    bn.add_argument("--cache", type=parse_path, metavar="DIR",
                    help="ground-truth cache directory (default $WARPBW_CACHE/ground_truth, or "
                    "~/.cache/warpbw/ground_truth without $WARPBW_CACHE)")
    bench_common(bn, "runs per point, each with its own seed (default 3): the time is their median, the error "
                     "the mean of their MSEs, with its standard error from their spread (the n_b sweep's runs share "
                     "their seeds across n_b); at a few samples per pixel a point's PSNR standard error over 3 "
                     "runs can reach 1 dB (fireflies): use 8 or 16 runs to tell apart points a few tenths of a dB "
                     "apart")
    bn.set_defaults(func=cmd_bench)

    from warpbw import bench_filtering as _bf

    bf = sub.add_parser("bench-filtering",
                        help="reflectance filtering along a zoom-out: error, flicker, temporal error, time",
                        description="Issue 4 / 004 on a scene with planes: for each zoom (camera distance factor) "
                        "and each filtered method (gmm_aligned, gmm_unaligned, toksvig, lean, fixed), the per-pixel "
                        "normalised Euclidean colour error against the ground truth (mean over covered pixels), the "
                        "flicker (frame-to-frame change beyond the ground truth's own, between zoom z and z * "
                        "2^(1/8)), the temporal error (distance of that change to the ground truth's change: "
                        "unlike the flicker, an image that changes less than the truth does not score 0) and the "
                        "frame time (median of --runs after a warm-up); and the precompute time of the aligned GMM "
                        "mipmaps (built afresh unless --cache or the scene's gmm file provides them). "
                        "In a scene with planes beside spheres or meshes, the planes are measured where no sphere or "
                        "mesh hides them (the spheres and meshes are not shaded: warpbw bench measures them). "
                        "See warpbw/bench_filtering.py for the definitions.")
    bf.add_argument("scene", type=parse_path,
                    help="scene file (TOML) with planes (spheres and meshes beside them hide what they cover)")
    bf.add_argument("--zoom", type=_number_list("zoom", float), default=list(_bf.DEFAULT_ZOOMS), metavar="Z,Z,...",
                    help="zoom factors (camera distance factors), comma-separated, each positive (default %s); a zoom "
                    "at which no pixel sees a plane is refused before any work" % ",".join(map(str, _bf.DEFAULT_ZOOMS)))
    bf.add_argument("--json", type=parse_path, metavar="OUT.json",
                    help="write the record here (JSON); without it, beside --plot as OUT.json")
    bf.add_argument("--plot", type=parse_path, metavar="OUT.png",
                    help="write the plot here (PNG): error, flicker and temporal error against zoom; without it, "
                    "beside --json as OUT.png")
    bf.add_argument("--gt-spp", type=_positive_int("gt-spp", INT32_MAX), default=_bf.DEFAULT_GT_SPP,
                    help=f"ground-truth rays per pixel ({MIN_GT_SPP} to 2^31-1; default {_bf.DEFAULT_GT_SPP}), "
                    "jittered over the pixel and averaged over those that hit the plane")
    bf.add_argument("--spp", type=_positive_int("spp", INT32_MAX), default=None,
                    help="under an [environment]: pairs of one BRDF and one environment sample per pixel of the "
                    f"filtered methods, 1 to 2^31-1 (default {DEFAULT_SPP}, as warpbw render; their noise is part of "
                    "the error)")
    bf.add_argument("--cache", type=parse_path, metavar="DIR",
                    help="GMM mipmap cache directory: mipmaps found there are reused, those built are kept there "
                    "(default: build afresh, so that the precompute time is measured)")
    bf.add_argument("--flicker-pairs", type=_positive_int("flicker-pairs", _bf.FLICKER_PAIRS_MAX), default=1,
                    help="consecutive frame pairs per zoom (z * step^j to z * step^(j+1)) the flicker and temporal "
                    f"error are averaged over (default 1; 1 to {_bf.FLICKER_PAIRS_MAX}, one octave): one pair is "
                    "one sample of where the footprints fall on the texels")
    add_anisotropy_option(bf, 1)
    bench_common(bf, "timed runs per point (median; default 3); the images, hence error and flicker, are the "
                     "same in every run")
    bf.set_defaults(func=cmd_bench_filtering)

    c = sub.add_parser("compare", help="PSNR and relative MSE of an image against a reference",
                       description="PSNR and relative MSE (linear radiance, R, G, B, in Rec. 709's primaries; each "
                       "EXR over its display window) over the pixels covered by geometry "
                       "(the reference's A channel, as warpbw render writes it; without one, the test image's, as "
                       "when a render is compared with another renderer's image; else non-black pixels), and the "
                       "share of the "
                       f"relative MSE held by the worst {_WORST_FRACTION:.0%} of those pixels: "
                       f"{_WORST_FRACTION:.0%} if every pixel had the same error, near 100% when a few pixels hold "
                       "it (fireflies and edges smeared by up-sampling alike: --error-map shows which).  PSNR's "
                       "peak is the reference's largest value over those pixels (any channel); the relative MSE is "
                       f"the mean over them and R, G, B of (test - ref)^2 / (ref^2 + {_RELMSE_EPS:g}).  Render the "
                       "reference with another --seed than the image: at one seed a pixel draws the same samples, so "
                       "the image's are the first of the reference's and the error reads low (a warning says so when "
                       "the images' .json records show it).")
    c.add_argument("test", type=parse_path, help="image to judge (EXR)")
    c.add_argument("reference", type=parse_path, help="reference image (EXR)")
    c.add_argument("--json", action="store_true",
                   help="print JSON (psnr_db, relmse, mse, pixels, worst_pixels, worst_share, coverage_from: whose A "
                        "channel chose the pixels, null for the non-black ones; an infinite PSNR is null, with "
                        "psnr_note saying whether the images are identical or the PSNR undefined; with --error-map, "
                        "error_map, its path, and error_range, the PNG's [LO, HI])")
    c.add_argument("--error-map", type=parse_path, metavar="PATH.exr",
                   help="also write the per-pixel relative squared error, (test - ref)^2 / (ref^2 + "
                   f"{_RELMSE_EPS:g}) averaged "
                   "over R, G, B (its mean over the covered pixels is the relMSE), as PATH.exr (Y; A = covered) and "
                   "a log-scaled false-colour PATH.png (black: not covered, or no error)")
    c.add_argument("--error-range", metavar="LO,HI", type=_number_list("--error-range", float),
                   help="the PNG's log colour scale, printed (default: from 10^-%d times the map's largest value, "
                   "or its smallest positive one if larger, to the largest), so that maps of several images can be "
                   "drawn on one scale (0 < LO < HI)" % ERROR_MAP_DECADES)
    c.add_argument("--force", action="store_true", help="overwrite an existing --error-map")
    c.set_defaults(func=cmd_compare)
    return p


def check_command_options(command: str, options: dict[str, str]) -> None:
    """Check option values (``{"--runs": "0"}``) with the parsers ``warpbw COMMAND`` has for the options of
    those names, for a script that passes them on to the command or takes them with the same meaning, so
    that a bad one is refused, naming it, before the script writes or runs anything.  Raises
    :class:`WarpbwError`."""
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    parser = sub.choices[command]
    for option, value in options.items():
        action = next(a for a in parser._actions if option in a.option_strings)
        shown = shlex.quote(value)   # '' for an empty value ("--gt-spp : expected ..." named none)
        if action.choices is not None and value not in action.choices:
            raise WarpbwError(f"{option} {shown}: expected one of {', '.join(map(str, action.choices))}")
        if action.type is None:
            continue
        try:
            action.type(value)
        except (argparse.ArgumentTypeError, ValueError) as exc:
            raise WarpbwError(f"{option} {shown}: {exc}") from None


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    return run_command("warpbw", args.func, args)


if __name__ == "__main__":
    sys.exit(main())
