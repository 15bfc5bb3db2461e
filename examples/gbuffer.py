"""G-buffer example: cast one ray per pixel at a sphere and the Stanford bunny, save the buffers.

    python examples/gbuffer.py [--mesh ../shared/data/meshes/bunny.obj] [--out gbuffer_out] [--device cpu]
        [--json OUT.json] [--plot OUT.png] [--force]

Writes normal.png (each component of the world-space normal as the 8-bit code round(255 (n + 1) / 2), as a normal map
encodes it; black off the geometry), depth.png, curvature.png, material.png and gbuffer.exr (all buffers as channels),
and prints the ray-cast time (the median of ``RUNS`` launches after a warm-up launch that compiles the kernel).
``--json`` / ``--plot`` (as ``warpbw bench``'s: the one not given goes beside the other; an existing file is kept
without ``--force``, refused before any work) write the record (the settings, the mesh's size, the device, each
launch's time and their median, the coverage) and the plot of the launches' times and their median.
"""
from warpbw.entry import interrupt_in_one_line

interrupt_in_one_line(__name__)   # first: a Ctrl-C while the imports below load says one line, no traceback

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from PIL import Image
import warp as wp

from warpbw.cli_common import (OneLineParser, check_output_dir, check_overwrite, check_record_outputs, init_warp,
                               run_command, write_record)
from warpbw.gbuffer import MeshSpec, SphereSpec, build_geometry, make_camera, render_gbuffer
from warpbw.io.exr import write_exr, write_false_colour_png
from warpbw.io.mesh import load_mesh
from warpbw.io.shared_data import shared_data_dir
from warpbw.io.staged import staged_outputs
from warpbw.scene import MAX_RESOLUTION

OUTPUTS = ("normal.png", "depth.png", "curvature.png", "material.png", "gbuffer.exr")
RUNS = 5   # timed launches (their median; DESIGN.md's protocol asks for at least 3)


def write_plot(record: dict, path) -> None:
    """Each timed launch's G-buffer time and their median."""
    from matplotlib.figure import Figure

    runs = [t * 1e3 for t in record["time_runs_s"]]
    fig = Figure(figsize=(6, 3.8))   # not pyplot's: nothing to close, the caller's backend kept
    ax = fig.subplots()
    ax.plot(range(1, len(runs) + 1), runs, "o", label="launch")
    ax.axhline(record["time_s"] * 1e3, color="C3", ls="--", label=f"median {record['time_s'] * 1e3:.1f} ms")
    ax.set_ylim(bottom=0)
    ax.set_xlabel("timed launch (after a warm-up)")
    ax.set_ylabel("G-buffer time (ms)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    w, h = record["resolution"]
    ax.set_title(f"G-buffer {w}x{h}, {record['triangles']} triangles + a sphere, {record['device']}", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main():
    here = Path(__file__).resolve().parent
    ap = OneLineParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mesh", help="mesh file (default: the shared bunny; the sphere alone when it is absent)")
    ap.add_argument("--out", default="gbuffer_out", help="output folder (default gbuffer_out)")
    ap.add_argument("--resolution", type=int, nargs=2, default=[512, 512], metavar=("W", "H"),
                    help="image width and height in pixels (default 512 512)")
    ap.add_argument("--device", default="cpu", help="Warp device (default cpu)")
    ap.add_argument("--json", help="write the record here (JSON); without it, beside --plot as OUT.json")
    ap.add_argument("--plot", help="write the plot here (PNG): each launch's time; without it, beside --json as "
                    "OUT.png")
    ap.add_argument("--force", action="store_true", help="overwrite existing outputs in --out, and --json / --plot")
    args = ap.parse_args()
    w, h = args.resolution
    if not (1 <= w <= MAX_RESOLUTION and 1 <= h <= MAX_RESOLUTION):
        ap.error(f"--resolution {w} {h}: expected a width and a height of at least 1 pixel and at most "
                 f"{MAX_RESOLUTION}")
    cam = make_camera((0.0, 0.3, 3.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 35.0, w, h)
    spheres = [SphereSpec((1.1, -0.55, -0.6), 0.45, 1)]
    meshes = []
    if args.mesh is None:
        args.mesh = str(shared_data_dir(here.parent) / "meshes" / "bunny.obj")
    elif not Path(args.mesh).is_file():
        ap.error(f"--mesh {args.mesh}: no such file (expected a mesh trimesh loads: OBJ, PLY, STL, GLB)")
    out = Path(args.out)
    check_output_dir(out, "--out")   # named by its option (they were refused as "-o OUT/NAME")
    check_overwrite([out / n for n in OUTPUTS], args.force, "--out")
    json_path, plot_path = check_record_outputs(args.json, args.plot, args.force, inputs=[args.mesh])
    init_warp(args.device)     # --device checked; Warp's no-CUDA-driver line kept off stderr
    if Path(args.mesh).exists():
        md = load_mesh(args.mesh, translate=(-0.2, 0.0, 0.0))
        meshes.append(MeshSpec(md.vertices, md.faces, md.normals, md.mean_curvature, md.uv, 0, md.surface))
        print(f"mesh {args.mesh}: {len(md.vertices)} vertices, {len(md.faces)} triangles")
    else:
        print(f"{args.mesh} not found: rendering the sphere alone")
    geo = build_geometry(spheres, meshes, device=args.device)
    gb = render_gbuffer(cam, geo, device=args.device)       # warm-up: compiles the kernel
    wp.synchronize_device(args.device)
    times = []
    for _ in range(RUNS):
        t0 = time.perf_counter()
        render_gbuffer(cam, geo, device=args.device, out=gb)
        wp.synchronize_device(args.device)
        times.append(time.perf_counter() - t0)
    print(f"G-buffer {w}x{h}: {np.median(times) * 1e3:.1f} ms (median of {RUNS}), coverage {gb.coverage.mean():.1%}")
    # all five, or none: an error leaves the old set
    with staged_outputs([out / n for n in OUTPUTS], force=args.force) as at:
        cov = gb.coverage
        # the codes themselves: through write_png, x^2.2 then the sRGB curve put a dark component up to 8 codes off
        codes = np.where(cov[..., None], np.clip(np.round(127.5 * (gb.numpy("normal") + 1.0)), 0.0, 255.0), 0.0)
        Image.fromarray(codes.astype(np.uint8)).save(at[out / "normal.png"], format="PNG")
        write_false_colour_png(at[out / "depth.png"], gb.numpy("depth"), mask=cov)
        curv = gb.numpy("curvature")
        write_false_colour_png(at[out / "curvature.png"], np.log10(np.abs(curv) + 1e-3), mask=cov)
        write_false_colour_png(at[out / "material.png"], gb.numpy("material").astype(float), mask=cov)
        chans, names = [], []
        for name, comps in (("normal", "XYZ"), ("position", "XYZ"), ("depth", None), ("curvature", None),
                            ("material", None)):
            a = gb.numpy(name).astype(np.float32)
            if comps:
                chans += [a[..., i] for i in range(3)]
                names += [f"{name}.{c}" for c in comps]
            else:
                chans.append(a)
                names.append(name)
        write_exr(at[out / "gbuffer.exr"], np.stack(chans, -1), channels=names)
    print(f"wrote {out}/normal.png, depth.png, curvature.png, material.png, gbuffer.exr")
    if json_path is not None:
        record = {"resolution": [w, h], "mesh": args.mesh if meshes else None,
                  "vertices": int(sum(len(m.vertices) for m in meshes)),
                  "triangles": int(sum(len(m.faces) for m in meshes)), "spheres": len(spheres),
                  "device": args.device, "runs": RUNS, "time_s": float(np.median(times)), "time_runs_s": times,
                  "coverage_fraction": float(gb.coverage.mean())}
        write_record(json_path, plot_path, record, write_plot, force=args.force)


if __name__ == "__main__":
    sys.exit(run_command("gbuffer.py", lambda _: main(), None))
