"""Reference estimator example (002 Eq. 2), stage by stage at the kernel level: G-buffer, materials,
environment, then N BRDF-importance samples per pixel, with and without MIS.

    python examples/reference_estimator.py [--probe ../shared/data/envmaps/studio.exr] [--spp 64] [--out ref_out]
        [--force]

Two analytic spheres (Lambert and GGX) and one NPF sphere under a light probe (the procedural sky when
the default probe is absent; the NPF sphere is left out when the default NPF table is).  Prints time
per stage and throughput; writes ref_bis.exr / ref_mis.exr and PNGs.
"""
import argparse
import sys
import time
from pathlib import Path

from warpbw import brdf as B
from warpbw.cli_common import OneLineParser, check_overwrite, init_warp, run_command
from warpbw.envmap import envmap_from_array, load_envmap, procedural_sky
from warpbw.errors import INT32_MAX, check_count
from warpbw.gbuffer import SphereSpec, build_geometry, make_camera, render_gbuffer
from warpbw.io.exr import write_exr, write_png
from warpbw.io.shared_data import shared_data_dir
from warpbw.io.staged import staged_outputs
from warpbw.scene import MAX_RESOLUTION
from warpbw.shading import shade_reference

OUTPUTS = ("ref_bis.exr", "ref_bis.png", "ref_mis.exr", "ref_mis.png")


def main():
    here = Path(__file__).resolve().parent
    data = shared_data_dir(here.parent)
    ap = OneLineParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    default_probe, default_npf = data / "envmaps" / "studio.exr", data / "brdf" / "npf.bin"
    ap.add_argument("--probe", help=f"lat-long EXR light probe (default {default_probe}; the procedural sky "
                                    "when it is absent)")
    ap.add_argument("--npf", help=f"NPF table (default {default_npf}; no NPF sphere when it is absent)")
    ap.add_argument("--material", default="gold-metallic-paint", help="NPF material of the NPF sphere (default "
                    "gold-metallic-paint)")
    ap.add_argument("--spp", type=int, default=64, help="samples per pixel (default 64)")
    ap.add_argument("--resolution", type=int, nargs=2, default=[384, 160], metavar=("W", "H"),
                    help="image size in pixels (default 384 160)")
    ap.add_argument("--device", default="cpu", help="Warp device (default cpu; cuda where there is one)")
    ap.add_argument("--out", default="ref_out", help="output folder (default ref_out)")
    ap.add_argument("--force", action="store_true", help="overwrite existing outputs in --out")
    args = ap.parse_args()
    dev = args.device
    w, h = args.resolution
    if not (1 <= w <= MAX_RESOLUTION and 1 <= h <= MAX_RESOLUTION):
        ap.error(f"--resolution {w} {h}: expected a width and a height of at least 1 pixel and at most "
                 f"{MAX_RESOLUTION}")
    check_count(args.spp, "--spp", 1, INT32_MAX)   # the shading kernel counts samples in int32
    for flag, given in (("--probe", args.probe), ("--npf", args.npf)):
        if given is not None and not Path(given).is_file():
            ap.error(f"{flag} {given}: no such file")
    probe = Path(args.probe) if args.probe is not None else default_probe
    npf = Path(args.npf) if args.npf is not None else default_npf
    out = Path(args.out)
    check_overwrite([out / n for n in OUTPUTS], args.force)
    init_warp(dev)             # --device checked; Warp's no-CUDA-driver line kept off stderr

    t0 = time.perf_counter()
    env = load_envmap(probe, device=dev) if probe.is_file() else \
        envmap_from_array(procedural_sky(512, 256), name="procedural sky", device=dev)
    specs = [B.MaterialSpec("lambert", B.LAMBERT, albedo=(0.7, 0.7, 0.7)),
             B.MaterialSpec("ggx", B.GGX, alpha=0.15, specular=(0.95, 0.95, 0.95))]
    spheres = [SphereSpec((-1.3, 0, 0), 0.6, 0), SphereSpec((0, 0, 0), 0.6, 1)]
    if npf.is_file():
        from warpbw.io.npf import npf_eval, read_npf
        from warpbw.sampling import build_sampler_table

        m = read_npf(npf, args.material)
        specs.append(B.MaterialSpec(m.name, B.NPF, npf=B.pack_npf_curves(m.rho_d, m.rho_s, m.D, m.G1, m.F),
                                    linear=True, sampler=build_sampler_table(lambda a, b: npf_eval(m, a, b))))
        spheres.append(SphereSpec((1.3, 0, 0), 0.6, 2))
    mats = B.build_material_table(specs, device=dev)
    geo = build_geometry(spheres, [], device=dev)
    cam = make_camera((0, 0.4, 4.5), (0, 0, 0), (0, 1, 0), 45.0, w, h)
    print(f"assets: {time.perf_counter() - t0:.2f} s ({env.name}, materials {', '.join(mats.names)})")

    gb = render_gbuffer(cam, geo, device=dev)
    images = {}   # name -> image, written together at the end
    for mis in (False, True):
        shade_reference(gb, mats, env.data, 1, mis=mis, device=dev)      # warm-up (compiles)
        t0 = time.perf_counter()
        res = shade_reference(gb, mats, env.data, args.spp, seed=1, mis=mis, device=dev)
        dt = time.perf_counter() - t0
        evals = res.samples * (2 if mis else 1)
        img = res.radiance.numpy().reshape(h, w, 3)
        name = "ref_mis" if mis else "ref_bis"
        images[name] = img
        print(f"{name}: {args.spp} spp over {res.pixels_shaded} pixels in {dt:.2f} s "
              f"({evals / dt / 1e6:.2f} M evaluations/s), non-finite samples {res.non_finite}; "
              f"mean radiance {img[gb.coverage].mean(0).round(4)}")
    # all four, or none: an error leaves the old set
    with staged_outputs([out / n for n in OUTPUTS], force=args.force) as at:
        for name, img in images.items():
            write_exr(at[out / f"{name}.exr"], img)
            write_png(at[out / f"{name}.png"], img)
    print(f"wrote {out}/ref_bis.exr, ref_mis.exr and PNGs")


if __name__ == "__main__":
    sys.exit(run_command("reference_estimator", lambda _: main(), None))
