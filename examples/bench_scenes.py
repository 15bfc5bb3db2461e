"""Write the benchmark scenes of issue 3 (and their NPF-derived MERL files), then optionally bench them.

    python examples/bench_scenes.py --out bench_scenes            # write the scenes only
    python examples/bench_scenes.py --out bench_scenes --run      # and run `warpbw bench` on each
    python examples/bench_scenes.py --out bench_scenes --run --no-mis --results nomis   # 002's baseline
    python examples/bench_scenes.py --out bench_scenes --run --runs 8   # 8 runs per point (the README's table)
    python examples/bench_scenes.py --out bench_scenes --run --env-signal radiance --results radiance   # nu_a as 002
    python examples/bench_scenes.py --out bench_scenes --run --only sphere_ccp3_forest_sun   # a sun added exactly

Four scenes, two shapes, four NPF-derived MERL materials (one very specular, chrome) and two light
probes, from ../shared/data:

=====================  ==========  =========================  ===========  =========
scene                  object      material (NPF -> MERL)     probe        size
=====================  ==========  =========================  ===========  =========
bunny_gold_forest      bunny       gold-metallic-paint        forest.exr   512x512
sphere_chrome_studio   sphere      chrome                     studio.exr   256x256
sphere_ccp3_forest     sphere      color-changing-paint3      forest.exr   256x256
bunny_acrylic_studio   bunny       blue-acrylic               studio.exr   256x256
=====================  ==========  =========================  ===========  =========

A fifth scene is written beside them and run only when ``--only`` names it: ``sphere_ccp3_forest_sun``, the
ccp3 sphere under forest.exr plus a directional sun (``SUN``), whose exact term the adaptive method adds at every
pixel after the up-sampling (README, "Directional lights").

Each bench writes SCENE.json and SCENE.png beside the scene (``warpbw bench --help``). The first scene, the gold
bunny, also runs the n_b sweep of 002 Fig. 13 (``--nb``, by default 16,64,256,1024; ``--nb ''`` for none); a run
whose ``--only`` leaves the gold bunny out runs no sweep.
"""
from __future__ import annotations

from warpbw.entry import interrupt_in_one_line

interrupt_in_one_line(__name__)   # first: a Ctrl-C while the imports below load says one line, no traceback

import argparse
import subprocess
import sys
from pathlib import Path

from precompute.npf_to_merl import tabulation_is_current, write_tabulation_stamp
from warpbw.cli import check_command_options
from warpbw.cli_common import OneLineParser, check_output_dir, check_overwrite, run_command
from warpbw.errors import WarpbwError
from warpbw.io.shared_data import shared_data_dir
from warpbw.io.staged import staged_outputs
from warpbw.scene import toml_escape

HERE = Path(__file__).resolve().parent
DATA = shared_data_dir(HERE.parent)
NPF_TABLE = DATA / "brdf" / "npf.bin"   # the NPF fits the MERL files are converted from

CAMERAS = {
    "bunny": 'position = [0.0, 0.35, 4.6]\nlook_at = [0.0, 0.0, 0.0]\nfov = 35.0',
    "sphere": 'position = [0.0, 0.0, 4.0]\nlook_at = [0.0, 0.0, 0.0]\nfov = 30.0',
}
OBJECTS = {
    "bunny": 'mesh = "{mesh}"\nmaterial = "m"',
    "sphere": 'shape = "sphere"\ncenter = [0.0, 0.0, 0.0]\nradius = 1.0\nmaterial = "m"',
}
SCENES = {  # name: (object, NPF material, probe, size)
    "bunny_gold_forest": ("bunny", "gold-metallic-paint", "forest.exr", 512),
    "sphere_chrome_studio": ("sphere", "chrome", "studio.exr", 256),
    "sphere_ccp3_forest": ("sphere", "color-changing-paint3", "forest.exr", 256),
    "bunny_acrylic_studio": ("bunny", "blue-acrylic", "studio.exr", 256),
}
# A sun about three times the sky's irradiance on a surface facing up (forest.exr's mean radiance is 0.55, so
# pi * 0.55 = 1.7), from the upper right in front of the sphere: its highlight is in view.
SUN = '\n[[light]]\ntype = "directional"\ndirection = [0.4, 0.7, 0.6]\nradiance = [5.0, 4.8, 4.4]\n'
EXTRA_SCENES = {  # written with SCENES, run only when --only names them: name: (..., [[light]] block)
    "sphere_ccp3_forest_sun": ("sphere", "color-changing-paint3", "forest.exr", 256, SUN),
}
TEMPLATE = """# warpbw benchmark scene (examples/bench_scenes.py)
[camera]
{camera}
resolution = [{size}, {size}]

[environment]
file = "{probe}"
{lights}
[[object]]
{obj}

[material.m]
type = "merl"
file = "{merl}"
"""


def scene_texts(out: Path) -> dict[Path, str]:
    """The TOML of each benchmark scene (SCENES, then EXTRA_SCENES), by the path it is written to in ``out``."""
    rows = {**{name: row + ("",) for name, row in SCENES.items()}, **EXTRA_SCENES}
    data = toml_escape(str(DATA), str(DATA))   # the shared folder's path, written into every scene
    return {out / f"{name}.toml": TEMPLATE.format(camera=CAMERAS[obj], size=size, probe=f"{data}/envmaps/{probe}",
                                                 lights=lights,
                                                 obj=OBJECTS[obj].format(mesh=f"{data}/meshes/bunny.obj"),
                                                 merl=f"{material}.binary")
            for name, (obj, material, probe, size, lights) in rows.items()}


def write_scenes(out: Path, force: bool = False) -> list[Path]:
    """Write the scenes and their MERL files into ``out``.  A scene file already there with other
    contents (edited by hand, say) is refused without ``force``, before anything is written."""
    texts = scene_texts(out)
    check_overwrite([p for p, text in texts.items() if p.exists() and p.read_text() != text], force, "--out")
    out.mkdir(parents=True, exist_ok=True)
    for material in sorted({row[1] for row in (*SCENES.values(), *EXTRA_SCENES.values())}):
        merl = out / f"{material}.binary"
        # which tabulation of which table wrote it (a MERL file cannot say): its stamp beside it
        if not tabulation_is_current(merl, NPF_TABLE, material):   # missing, or stale (another tabulation or table)
            # --force: OUT holds these files as a cache (--help), and a second bench_scenes into the same OUT (two
            # --only runs at once) converts the same material to the same bytes; without it the later to finish
            # was refused ("appeared while this run worked") and this script ended in a traceback
            status = subprocess.run([sys.executable, "-m", "precompute", "npf-to-merl", "--table",
                                     str(NPF_TABLE), "--material", material, "-o", str(merl),
                                     "--force"]).returncode
            if status:   # npf-to-merl has said why (check=True printed a traceback under it)
                raise WarpbwError(f"{merl}: converting {material} from the NPF table failed (status {status})")
            write_tabulation_stamp(merl, NPF_TABLE, material)
    with staged_outputs(texts) as at:   # every scene, or none: an error leaves the old ones
        for p, text in texts.items():
            at[p].write_text(text)
    return list(texts)


def main(argv=None) -> int:
    ap = OneLineParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="bench_scenes", help="directory for scenes, MERL files and results (default "
                    "%(default)s; an "
                    "OUT/MATERIAL.binary already there is used as it is, a cache: delete it to convert the NPF fit "
                    "again; one whose stamp OUT/MATERIAL.binary.tabulation names another tabulation or NPF table, "
                    "or is missing, is converted again)")
    ap.add_argument("--run", action="store_true", help="run warpbw bench on every scene")
    ap.add_argument("--only", help="comma-separated scene names to run (default: the four of the table; "
                    f"{', '.join(EXTRA_SCENES)} only when named)")
    ap.add_argument("--nb", default="16,64,256,1024", help="n_b sweep on the first scene, the gold bunny (default "
                    "%(default)s; '' for none)")
    ap.add_argument("--gt-spp", default="8192", help="ground-truth samples per pixel (default 8192; cached)")
    ap.add_argument("--runs", help="runs per point (warpbw bench --runs; default 3): the table's standard errors "
                    "shrink as 1/sqrt(runs)")
    ap.add_argument("--cache", help="ground-truth cache directory (warpbw bench --cache)")
    ap.add_argument("--no-mis", action="store_true", help="BRDF importance sampling only (002's baseline)")
    ap.add_argument("--env-signal", help="what the analysis of the probe's bandwidth reads (warpbw bench --env-signal)")
    ap.add_argument("--results", help="directory for the JSON and PNG records (default: --out)")
    ap.add_argument("--force", action="store_true", help="rewrite changed scene files and overwrite existing "
                    "results (passed on to warpbw bench)")
    args = ap.parse_args(argv)
    unknown = sorted(set(args.only.split(",") if args.only else ()) - set(SCENES) - set(EXTRA_SCENES))
    if unknown:
        ap.error(f"--only {','.join(unknown)}: expected scene names among {', '.join([*SCENES, *EXTRA_SCENES])}")
    # the values passed on to warpbw bench, checked by its own parsers before anything is written
    # (an empty --nb means no sweep; any other value given, empty too, is checked: --gt-spp '' ran at 8192)
    check_command_options("bench", {k: v for k, v in (("--gt-spp", args.gt_spp), ("--runs", args.runs),
                                                         ("--nb", args.nb), ("--env-signal", args.env_signal))
                                    if v or (v is not None and k != "--nb")})
    check_output_dir(args.out, "--out")   # before the MERL files are converted and the scenes written
    if args.run and args.results:
        check_output_dir(args.results, "--results")
    if not DATA.is_dir():
        raise WarpbwError(f"{DATA}: not found (the scenes need the shared data folder's probes, bunny and NPF table: "
                          "clone ../shared beside the repository or set $WARPBW_SHARED_DATA)")
    paths = write_scenes(Path(args.out), args.force)
    print("scenes: " + ", ".join(str(p) for p in paths))
    if not args.run:
        return 0
    only = set(args.only.split(",")) if args.only else set(SCENES)
    for i, p in enumerate(paths):
        if p.stem not in only:
            continue
        res = Path(args.results or args.out) / p.stem
        res.parent.mkdir(parents=True, exist_ok=True)
        # this interpreter's warpbw, as npf-to-merl above: not the `warpbw` on $PATH, absent where the virtual
        # environment is not activated, and another install's where one comes first
        cmd = [sys.executable, "-m", "warpbw.cli", "bench", str(p), "--json", f"{res}.json", "--plot", f"{res}.png",
               "--gt-spp", args.gt_spp, "-q"]
        if args.cache:
            cmd += ["--cache", args.cache]
        if args.no_mis:
            cmd.append("--no-mis")
        if args.runs:
            cmd += ["--runs", args.runs]
        if args.env_signal:
            cmd += ["--env-signal", args.env_signal]
        if i == 0 and args.nb:
            cmd += ["--nb", args.nb]
        if args.force:
            cmd.append("--force")
        print("$ " + " ".join(cmd), flush=True)
        status = subprocess.run(cmd).returncode
        if status:
            return status   # warpbw bench has said why
    return 0


if __name__ == "__main__":
    sys.exit(run_command("bench_scenes.py", lambda _: main(), None))
