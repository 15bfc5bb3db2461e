"""G-buffer example: cast one ray per pixel at a sphere and the Stanford bunny, save the buffers.

    python examples/gbuffer.py [--mesh ../shared/data/meshes/bunny.obj] [--out gbuffer_out] [--device cpu]
        [--force]

Writes normal.png, depth.png, curvature.png, material.png and gbuffer.exr (all buffers as channels),
and prints the ray-cast time (after a warm-up launch that compiles the kernel).
"""
import argparse
import sys
import time
from pathlib import Path

import numpy as np
import warp as wp

from warpbw.cli_common import OneLineParser, check_overwrite, init_warp, run_command
from warpbw.gbuffer import MeshSpec, SphereSpec, build_geometry, make_camera, render_gbuffer
from warpbw.io.exr import write_exr, write_false_colour_png, write_png
from warpbw.io.mesh import load_mesh
from warpbw.io.shared_data import shared_data_dir
from warpbw.io.staged import staged_outputs
from warpbw.scene import MAX_RESOLUTION

OUTPUTS = ("normal.png", "depth.png", "curvature.png", "material.png", "gbuffer.exr")


def main():
    here = Path(__file__).resolve().parent
    ap = OneLineParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mesh", help="mesh file (default: the shared bunny; the sphere alone when it is absent)")
    ap.add_argument("--out", default="gbuffer_out", help="output folder (default gbuffer_out)")
    ap.add_argument("--resolution", type=int, nargs=2, default=[512, 512], metavar=("W", "H"),
                    help="image width and height in pixels (default 512 512)")
    ap.add_argument("--device", default="cpu", help="Warp device (default cpu)")
    ap.add_argument("--force", action="store_true", help="overwrite existing outputs in --out")
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
    check_overwrite([out / n for n in OUTPUTS], args.force)
    init_warp(args.device)     # --device checked; Warp's no-CUDA-driver line kept off stderr
    if Path(args.mesh).exists():
        md = load_mesh(args.mesh, translate=(-0.2, 0.0, 0.0))
        meshes.append(MeshSpec(md.vertices, md.faces, md.normals, md.mean_curvature, md.uv, 0))
        print(f"mesh {args.mesh}: {len(md.vertices)} vertices, {len(md.faces)} triangles")
    else:
        print(f"{args.mesh} not found: rendering the sphere alone")
    geo = build_geometry(spheres, meshes, device=args.device)
    gb = render_gbuffer(cam, geo, device=args.device)       # warm-up: compiles the kernel
    wp.synchronize_device(args.device)
    times = []
    for _ in range(5):
        t0 = time.perf_counter()
        render_gbuffer(cam, geo, device=args.device, out=gb)
        wp.synchronize_device(args.device)
        times.append(time.perf_counter() - t0)
    print(f"G-buffer {w}x{h}: {np.median(times) * 1e3:.1f} ms (median of 5), coverage {gb.coverage.mean():.1%}")
    # all five, or none: an error leaves the old set
    with staged_outputs([out / n for n in OUTPUTS], force=args.force) as at:
        cov = gb.coverage
        write_png(at[out / "normal.png"], np.where(cov[..., None], 0.5 * gb.numpy("normal") + 0.5, 0.0) ** 2.2)
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


if __name__ == "__main__":
    sys.exit(run_command("gbuffer", lambda _: main(), None))
