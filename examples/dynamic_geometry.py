"""Dynamic geometry (002 Sec. 4.3, "Dynamic geometry", Fig. 18): deform a mesh every frame and render
each frame with bandwidth prediction and hierarchical adaptive shading.

    python examples/dynamic_geometry.py [--mesh ../shared/data/meshes/bunny.obj] [--frames 10]
        [--size 256] [--budget 8] [--material red-metallic-paint | ggx] [--host-normals]
        [--out dynamic_out] [--force]

Every frame, from the rest pose and the frame number alone (nothing is precomputed from geometry):
  1. deform: a travelling sine ripple along +Y (the mesh swells and narrows about its vertical axis)
     and a twist about that axis that swings back and forth; amplitudes relative to the mesh's size;
  2. copy the positions to the device, recompute smooth vertex normals and cotangent mean curvature there
     and refit the BVH (``update_mesh`` -> ``warpbw.mesh_normals``, ``wp.Mesh.refit``); with
     --host-normals, normals and curvature are computed on the host instead (numpy on one core,
     ``warpbw.io.mesh.normals_and_curvature``, the same formulas in float64) and copied; either way the
     copies of a vertex a texture seam split are one vertex (the seam map ``load_mesh`` computed once);
  3. ``render_adaptive``: G-buffer, bandwidth pass (from the G-buffer only: normals, depth, curvature),
     hierarchical shading and up-sampling.
The material and environment tables (sampling, nu_rho, nu_a) do not depend on the geometry and are
loaded or built once.  A warm-up frame (kernel compilation, tables) is rendered first and not recorded.

Writes, under --out:
  dynamic_geometry.png   top row: rendered frames; bottom row: the pixels shading was computed for
                         (white), covered pixels filled by up-sampling (grey), as in Fig. 18;
  dynamic_geometry.json  one record per frame: time of each stage (deform, host normals + curvature
                         (null on the device: they are part of the next), update + refit, G-buffer,
                         bandwidth, shading, up-sampling), total, fps, shaded fraction, samples; the means;
                         the settings, device and threads;
  dynamic_geometry_times.png  the measurement's plot (DESIGN.md, measurement protocol): each frame's stage
                         times (stacked) and fps, and its shaded fraction;
and prints the table and the mean frames per second.  The paper's Fig. 18: 66 ms per frame (15 fps)
on a 2009 GPU; here the same kernels run on the CPU.  The default probe is city.exr: under the
high-frequency forest.exr the bandwidth pass asks for nearly every pixel at 256x256 (about 99.6% shaded).
"""
from __future__ import annotations

from warpbw.entry import interrupt_in_one_line

interrupt_in_one_line(__name__)   # first: a Ctrl-C while the imports below load says one line, no traceback

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
import warp as wp

from warpbw.cli import BUDGET_MAX
from warpbw.cli_common import (OneLineParser, check_output_dir, check_overwrite, few_runs_warning, init_warp,
                               json_text, parse_seed, run_command)
from warpbw.errors import SEED_MAX, WarpbwError
from warpbw.io.exr import REC709_LUMINANCE
from warpbw.io.shared_data import shared_data_dir
from warpbw.scene import MAX_RESOLUTION

HERE = Path(__file__).resolve().parent
DATA = shared_data_dir(HERE.parent)
DEFAULT_MESH = DATA / "meshes" / "bunny.obj"
DEFAULT_ENV = DATA / "envmaps" / "city.exr"     # procedural sky when absent
NPF_TABLE = DATA / "brdf" / "npf.bin"
DEFAULT_MATERIAL = "red-metallic-paint"          # Fig. 18's material

# Deformation (amplitudes relative to the mesh: the ripple scales the distance to the vertical axis).
RIPPLE_AMPLITUDE = 0.08        # peak relative change of the distance to the axis
RIPPLE_CYCLES = 2.5            # ripple wavelengths over the mesh's height
RIPPLE_CYCLES_PER_FRAME = 0.1  # phase speed of the travelling wave (one wavelength every 10 frames)
TWIST_MAX_DEG = 30.0           # peak twist of the top against the bottom of the mesh
TWIST_PERIOD_FRAMES = 16       # the twist swings back and forth with this period

# Camera: looks at the rest pose's bounding-box centre from slightly above, framing every pose (_camera).
FOV_DEG = 35.0
CAMERA_ELEVATION = 0.15        # height of the eye over the distance, along +Y
FRAMING_MARGIN = 1.1           # half extent of the deformed mesh to the half field of view

# A GGX stand-in for Fig. 18's red metallic paint when ``--material ggx`` (or no NPF table).
GGX_MATERIAL = 'type = "ggx"\nalpha = 0.15\nspecular = [0.8, 0.12, 0.1]'

# Shaded-mask row of the strip (linear values; written as sRGB).
LUMINANCE = REC709_LUMINANCE   # Rec. 709's Y weights, for the strip's exposure
MASK_SHADED = 1.0
MASK_UPSAMPLED = 0.04          # covered, filled by up-sampling: dark grey
STRIP_GAP = 2                  # pixels between frames
STRIP_WHITE_PERCENTILE = 99.5  # this percentile of covered pixels' luminance (all frames) is shown white
MAX_STRIP_FRAMES = 10          # evenly spaced frames shown in the strip

SCENE = """
[camera]
position = [0.0, 0.0, 4.0]
look_at = [0.0, 0.0, 0.0]
fov = {fov}
resolution = [{w}, {h}]
[environment]
{env}
[[object]]
mesh = "{mesh}"
material = "m"
[material.m]
{material}
"""

OUTPUTS = ("dynamic_geometry.png", "dynamic_geometry.json", "dynamic_geometry_times.png")
# the stages of a frame's time as the record names them, stacked in the plot (their sum is the frame's total_s:
# the scene has no [[light]])
PLOT_STAGES = ("geometry_s", "gbuffer_s", "bandwidth_s", "shading_s", "hierarchy_s", "upsampling_s")


def deform(rest: np.ndarray, frame: int, axis_xz: np.ndarray, y_range: tuple) -> np.ndarray:
    """The frame's vertex positions (V, 3) from the rest pose: a travelling ripple then a twist,
    both about the vertical axis through ``axis_xz`` (x, z)."""
    y0, y1 = y_range
    s = (rest[:, 1] - y0) / max(y1 - y0, 1e-12)        # 0 at the bottom, 1 at the top
    phase = 2.0 * math.pi * (RIPPLE_CYCLES * s - RIPPLE_CYCLES_PER_FRAME * frame)
    radial = 1.0 + RIPPLE_AMPLITUDE * np.sin(phase)      # scales the distance to the axis
    twist = math.radians(TWIST_MAX_DEG) * math.sin(2.0 * math.pi * frame / TWIST_PERIOD_FRAMES) * (s - 0.5)
    dx = (rest[:, 0] - axis_xz[0]) * radial
    dz = (rest[:, 2] - axis_xz[1]) * radial
    c, sn = np.cos(twist), np.sin(twist)
    out = np.empty_like(rest, dtype=np.float64)
    out[:, 0] = axis_xz[0] + c * dx + sn * dz          # rotation about +Y (right-handed)
    out[:, 1] = rest[:, 1]
    out[:, 2] = axis_xz[1] - sn * dx + c * dz
    return out


def _material_toml(name: str) -> tuple[str, str]:
    if name == "ggx":
        return GGX_MATERIAL, "ggx (alpha 0.15, red specular)"
    from warpbw.io.npf import NPF_MATERIAL_NAMES

    if name not in NPF_MATERIAL_NAMES:
        raise WarpbwError(f"--material {name!r}: expected 'ggx' or an NPF material name "
                          f"(e.g. {DEFAULT_MATERIAL})")
    if not NPF_TABLE.is_file():
        print(f"{NPF_TABLE} not found: using the GGX stand-in instead of {name}")
        return GGX_MATERIAL, "ggx (alpha 0.15, red specular)"
    return f'type = "npf"\ntable = "{NPF_TABLE}"\nname = "{name}"\nlookup = "linear"', f"npf {name}"


def _camera(rest: np.ndarray, width: int, height: int):
    """Looks at the rest pose's bounding-box centre from slightly above (``CAMERA_ELEVATION``), near enough that every
    pose ``deform`` gives fills the image to 1 / ``FRAMING_MARGIN`` of its half size, and no nearer."""
    from warpbw.gbuffer import make_camera

    centre = 0.5 * (rest.min(0) + rest.max(0))
    q = rest - centre
    # every pose keeps a vertex's height, and its distance to the axis within 1 + RIPPLE_AMPLITUDE of the rest pose's
    # (the twist turns it about the axis): each vertex stays on a circle of radius r about the axis at height y
    r = (1.0 + RIPPLE_AMPLITUDE) * np.hypot(q[:, 0], q[:, 2])
    y = q[:, 1]
    e = math.hypot(1.0, CAMERA_ELEVATION)   # the eye at dist (0, CAMERA_ELEVATION, 1) / e from the centre
    tan_x = math.tan(math.radians(FOV_DEG) * 0.5)   # the field of view is the width's
    tan_y = tan_x * height / width
    # a point p (relative to the centre) lies within 1 / FRAMING_MARGIN of the image's half width while its depth
    # dist - p.(0, CAMERA_ELEVATION, 1) / e is at least FRAMING_MARGIN |p.right| / tan_x, right = (1, 0, 0), and of the
    # half height while it is at least FRAMING_MARGIN |p.up| / tan_y, up = (0, 1, -CAMERA_ELEVATION) / e.  Over a
    # circle p = (r cos a, y, r sin a) the first is largest at y CAMERA_ELEVATION / e + r sqrt(1 / e^2 + (M / tan_x)^2);
    # the second, convex in sin a, at sin a = +-1
    along_x = y * CAMERA_ELEVATION / e + r * math.hypot(1.0 / e, FRAMING_MARGIN / tan_x)
    along_y = np.maximum.reduce([(y * CAMERA_ELEVATION + s * r) / e
                                 + FRAMING_MARGIN * np.abs(y - s * CAMERA_ELEVATION * r) / (e * tan_y)
                                 for s in (-1.0, 1.0)])
    dist = float(max(along_x.max(), along_y.max()))
    eye = centre + dist * np.array([0.0, CAMERA_ELEVATION, 1.0]) / e
    return make_camera(eye, centre, (0.0, 1.0, 0.0), FOV_DEG, width, height)


def _strip(images: list, masks: list, coverage: list) -> np.ndarray:
    """Fig. 18's layout: rendered frames on top (one exposure for all), shaded-pixel masks below,
    ``STRIP_GAP`` apart."""
    lum = np.concatenate([(img @ np.array(LUMINANCE))[c] for img, c in zip(images, coverage)])
    white = float(np.percentile(lum, STRIP_WHITE_PERCENTILE)) if lum.size else 1.0
    images = [img / white if white > 0 else img for img in images]
    h, w = images[0].shape[:2]
    n = len(images)
    out = np.zeros((2 * h + STRIP_GAP, n * w + (n - 1) * STRIP_GAP, 3), np.float32)
    for i, (img, m) in enumerate(zip(images, masks)):
        x = i * (w + STRIP_GAP)
        out[:h, x:x + w] = img
        out[h + STRIP_GAP:, x:x + w] = m[..., None]
    return out


def write_plot(record: dict, path) -> None:
    """Per frame: the stage times stacked (ms) with the fps on a second axis, and the shaded fraction."""
    from matplotlib.figure import Figure
    import matplotlib.ticker

    frames = record["frames"]
    f = [r["frame"] for r in frames]
    fig = Figure(figsize=(7, 6))   # not pyplot's: nothing to close, the caller's backend kept
    ax, ax2 = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [2, 1]})
    bottom = np.zeros(len(frames))
    for k in PLOT_STAGES:
        ms = np.array([r[k] * 1e3 for r in frames])
        ax.bar(f, ms, bottom=bottom, label=k[:-2])
        bottom += ms
    ax.set_ylabel("stage time (ms)")
    ax.legend(fontsize=7, loc="upper left")
    fps = ax.twinx()
    fps.plot(f, [r["fps"] for r in frames], "ko-", label="fps (wall)")
    fps.set_ylabel("frames per second (wall)")
    fps.set_ylim(0, 1.15 * max(r["fps"] for r in frames))
    fps.legend(fontsize=7, loc="upper right")
    ax2.plot(f, [r["shaded_fraction"] for r in frames], "s-", color="C3")
    ax2.set_ylim(0, 1.05)
    ax2.set_ylabel("shaded fraction")
    ax2.set_xlabel("frame")
    ax2.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(integer=True))
    ax2.grid(True, alpha=0.3)
    s = record["summary"]
    fig.suptitle(f"dynamic geometry: {record['size'][0]}x{record['size'][1]}, budget {record['budget_spp']:g} spp; "
                 f"mean {s['mean_fps']:.2f} fps, {s['mean_shaded_fraction']:.1%} shaded", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def _print_table(records: list, summary: dict) -> None:
    head = (f"{'frame':>5} {'geom ms':>8} {'update ms':>9} {'gbuf ms':>8} {'bw ms':>7} {'shade ms':>8} "
            f"{'upsmp ms':>8} {'total ms':>8} {'fps':>6} {'shaded':>7} {'samples':>8}")
    print(head)
    for r in records:
        print(f"{r['frame']:>5} {r['geometry_s'] * 1e3:8.1f} {r['update_refit_s'] * 1e3:9.1f} "
              f"{r['gbuffer_s'] * 1e3:8.1f} {r['bandwidth_s'] * 1e3:7.1f} {r['shading_s'] * 1e3:8.1f} "
              f"{r['upsampling_s'] * 1e3:8.1f} {r['total_s'] * 1e3:8.1f} {r['fps']:6.2f} "
              f"{r['shaded_fraction']:7.1%} {r['samples']:>8d}")
    print(f"mean: {summary['mean_total_s'] * 1e3:.1f} ms per frame, {summary['mean_fps']:.2f} fps; "
          f"shaded fraction {summary['mean_shaded_fraction']:.1%} of covered pixels; geometry (deform + "
          f"normals/curvature + refit) {summary['mean_geometry_s'] * 1e3:.1f} ms, "
          f"bandwidth pass {summary['bandwidth_share']:.1%} of the frame")


def main(argv=None):
    ap = OneLineParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mesh", help="mesh file (default: the shared bunny; skipped when it is absent)")
    ap.add_argument("--out", default="dynamic_out", help="output folder (default %(default)s)")
    ap.add_argument("--frames", type=int, default=10, help="frames to render after the warm-up (default %(default)s)")
    ap.add_argument("--budget", type=float, default=8.0, help="mean samples per covered pixel (default %(default)g)")
    ap.add_argument("--size", type=int, default=256,
                    help=f"image width and height in pixels, 8 to {MAX_RESOLUTION} (default %(default)s)")
    ap.add_argument("--material", default=DEFAULT_MATERIAL, help="an NPF material name, or 'ggx' (default %(default)s)")
    ap.add_argument("--env", help="lat-long EXR light probe (default: the shared city.exr; the procedural sky "
                                  "when it is absent)")
    ap.add_argument("--seed", type=parse_seed, default=0,
                    help="frame f uses seed + f (0 to 2^32-1; default %(default)s)")
    ap.add_argument("--threads", type=int, default=None, help="CPU threads for shading (default: cores)")
    ap.add_argument("--device", default="cpu", help="Warp device (default cpu)")
    ap.add_argument("--host-normals", action="store_true",
                    help="compute the normals and curvature with numpy on the host and copy them (the device "
                    "computes them by default)")
    ap.add_argument("--force", action="store_true", help="overwrite existing outputs")
    args = ap.parse_args(argv)
    if args.frames < 1:
        ap.error(f"--frames {args.frames}: expected a positive integer")
    if not 8 <= args.size <= MAX_RESOLUTION:
        ap.error(f"--size {args.size}: expected 8 to {MAX_RESOLUTION} pixels")
    if not 0 < args.budget <= BUDGET_MAX:   # not after loading the mesh and the probe, as the renderer's "budget"
        ap.error(f"--budget {args.budget:g}: expected a positive number of samples per pixel, at most {BUDGET_MAX:g} "
                 "(N_p, up to 256 x budget, is an int32 in the kernels)")
    if args.frames - 1 > SEED_MAX:   # frame f uses seed + f: even --seed 0 cannot give more frames their own seed
        ap.error(f"--frames {args.frames}: expected at most {SEED_MAX + 1} (frame f uses seed + f, a uint32 seed)")
    if args.seed + args.frames - 1 > SEED_MAX:
        ap.error(f"--seed {args.seed}: frame f uses seed + f, which must stay a uint32 (expected at most "
                 f"{SEED_MAX - args.frames + 1} with --frames {args.frames})")
    if args.threads is not None and args.threads < 1:
        ap.error(f"--threads {args.threads}: expected a positive integer")
    if args.mesh is not None and not Path(args.mesh).is_file():
        ap.error(f"--mesh {args.mesh}: no such file (expected a mesh trimesh loads: OBJ, PLY, STL, GLB)")
    if args.env is not None and not Path(args.env).is_file():
        ap.error(f"--env {args.env}: no such file (expected a lat-long EXR light probe)")
    material, material_desc = _material_toml(args.material)
    init_warp(args.device)     # --device checked; Warp's no-CUDA-driver line kept off stderr
    mesh_path = Path(args.mesh or DEFAULT_MESH)
    if not mesh_path.is_file():
        print(f"dynamic_geometry: mesh {mesh_path} not found; skipping (pass --mesh FILE)")
        return None
    out = Path(args.out)
    check_output_dir(out, "--out")
    check_overwrite([out / n for n in OUTPUTS], args.force, "--out")

    from warpbw.gbuffer import update_mesh
    from warpbw.io.exr import write_png
    from warpbw.io.mesh import normals_and_curvature
    from warpbw.io.staged import staged_outputs
    from warpbw.pipeline import prepare_scene, render_adaptive
    from warpbw.scene import parse_scene, toml_escape, toml_string
    from warpbw.launch import default_threads

    env_path = Path(args.env) if args.env is not None else DEFAULT_ENV
    env = f"file = {toml_string(str(env_path), f'--env {env_path}')}" if env_path.is_file() else 'procedural = "sky"'
    mesh = toml_escape(str(mesh_path.resolve()), f"--mesh {mesh_path}")   # a quote in the path broke the scene
    scene = parse_scene(SCENE.format(fov=FOV_DEG, w=args.size, h=args.size, env=env, mesh=mesh, material=material),
                        source="<dynamic_geometry>")
    t0 = time.perf_counter()
    prep = prepare_scene(scene, device=args.device)
    geo = prep.geometry
    start, count = geo.mesh_vertex_ranges[0]
    rest = geo.mesh.points.numpy()[start:start + count].astype(np.float64)   # the animation's input pose
    faces = geo.mesh_attr.indices.numpy().reshape(-1, 3) - start
    surface = geo.mesh_surface[0]   # the seam map load_mesh computed (None without uv seams, as on the bunny)
    prep.camera = _camera(rest, args.size, args.size)
    axis_xz = 0.5 * (rest.min(0) + rest.max(0))[[0, 2]]
    y_range = (float(rest[:, 1].min()), float(rest[:, 1].max()))
    print(f"mesh {mesh_path}: {count} vertices, {len(faces)} triangles; material {material_desc}; "
          f"{args.size}x{args.size}, budget {args.budget:g} spp; loaded in {time.perf_counter() - t0:.1f} s")

    def frame_pose(f):
        t_a = time.perf_counter()
        v = deform(rest, f, axis_xz, y_range)
        t_b = time.perf_counter()
        if args.host_normals:
            n, h = normals_and_curvature(v, faces, surface)
        t_c = time.perf_counter()
        if args.host_normals:
            update_mesh(geo, 0, v, n, h)
        else:
            update_mesh(geo, 0, v)    # normals and curvature on the device
        wp.synchronize_device(args.device)
        t_d = time.perf_counter()
        return t_b - t_a, (t_c - t_b) if args.host_normals else None, t_d - t_c

    t0 = time.perf_counter()
    frame_pose(0)
    render_adaptive(prep, args.budget, seed=args.seed, device=args.device, threads=args.threads)   # warm-up
    print(f"warm-up frame (compile kernels, load or build tables): {time.perf_counter() - t0:.1f} s")

    # only the strip's frames are kept (every frame's image was, whatever --frames asked for); in frame order, as
    # the strip shows them and the closing line names them (a set's order put 33 before 11 from --frames 34 on)
    picked = np.linspace(0, args.frames - 1, min(args.frames, MAX_STRIP_FRAMES)).round().astype(int)
    pick = sorted(set(picked.tolist()))
    records, images, masks, coverage = [], [], [], []
    for f in range(args.frames):
        t_start = time.perf_counter()
        t_deform, t_normals, t_refit = frame_pose(f)
        res = render_adaptive(prep, args.budget, seed=args.seed + f, device=args.device, threads=args.threads)
        wall = time.perf_counter() - t_start
        ts = res.stats["time_s"]
        geometry_s = t_deform + (t_normals or 0.0) + t_refit
        total = geometry_s + ts["frame"]
        records.append({
            "frame": f,
            "deform_s": t_deform,
            "normals_curvature_s": t_normals,
            "update_refit_s": t_refit,
            "geometry_s": geometry_s,
            "gbuffer_s": ts["gbuffer"],
            "bandwidth_s": ts["bandwidth"],
            "shading_s": ts["shading"],
            "upsampling_s": ts["upsampling"],
            "hierarchy_s": ts["hierarchy"],
            "total_s": total,             # sum of the stages
            "wall_s": wall,               # the whole iteration, host-side copies of the AOVs included
            "fps": 1.0 / wall,
            "shaded_fraction": res.stats["shaded_fraction"],
            "pixels_shaded": int(res.stats["pixels_shaded"]),
            "pixels_covered": int(res.stats["pixels_covered"]),
            "samples": int(res.stats["samples"]),
            "samples_per_covered_pixel": res.stats["samples_per_covered_pixel"],
        })
        if f in pick:
            images.append(res.image)
            coverage.append(res.coverage)
            masks.append(np.where(res.aovs["shaded"], MASK_SHADED, np.where(res.coverage, MASK_UPSAMPLED, 0.0)))

    mean = {k: float(np.mean([r[k] for r in records])) for k in records[0]
            if k.endswith("_s") and records[0][k] is not None}
    summary = {f"mean_{k}": v for k, v in mean.items()}
    summary.update({
        "mean_fps": 1.0 / mean["wall_s"],
        "mean_shaded_fraction": float(np.mean([r["shaded_fraction"] for r in records])),
        "mean_samples": float(np.mean([r["samples"] for r in records])),
        "bandwidth_share": mean["bandwidth_s"] / mean["total_s"],
        "geometry_share": mean["geometry_s"] / mean["total_s"],
    })
    result = {
        "mesh": str(mesh_path), "vertices": int(count), "triangles": int(len(faces)),
        "material": material_desc, "environment": env, "size": [args.size, args.size],
        "budget_spp": args.budget, "seed": args.seed, "device": args.device,
        "threads": default_threads(args.device) if args.threads is None else args.threads,
        "normals_and_curvature": "host (numpy)" if args.host_normals else "device (warpbw.mesh_normals)",
        "stages": res.stats["stages"],
        "deformation": {"ripple_amplitude": RIPPLE_AMPLITUDE, "ripple_cycles": RIPPLE_CYCLES,
                        "ripple_cycles_per_frame": RIPPLE_CYCLES_PER_FRAME, "twist_max_deg": TWIST_MAX_DEG,
                        "twist_period_frames": TWIST_PERIOD_FRAMES},
        "frames": records,
        "summary": summary,
    }
    # both, or neither: an error leaves the old pair
    with staged_outputs([out / n for n in OUTPUTS], force=args.force) as at:
        write_png(at[out / OUTPUTS[0]], _strip(images, masks, coverage))
        at[out / OUTPUTS[1]].write_text(json_text(result))
        write_plot(result, at[out / OUTPUTS[2]])
    _print_table(records, summary)
    print(f"wrote {out / OUTPUTS[0]} (frames {', '.join(str(i) for i in pick)}) and {out / OUTPUTS[1]}")
    print(f"plot {out / OUTPUTS[2]} (stage times, fps and shaded fraction per frame)")
    warning = few_runs_warning(args.frames, "--frames")
    if warning is not None:
        print(f"dynamic_geometry.py: warning: {warning}", file=sys.stderr)
    return result


def _cli(_args) -> int:
    main()  # its record (None when the default mesh is absent) is for callers; a finished run exits 0
    return 0


if __name__ == "__main__":
    sys.exit(run_command("dynamic_geometry.py", _cli, None))
