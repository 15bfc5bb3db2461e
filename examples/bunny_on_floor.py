"""Write the README's mixed scene, the Stanford bunny sunk into a dunes floor (a plane with a normal map beside a
mesh): OUT/bunny_on_floor.toml and the floor's height field OUT/dunes.exr.

    python examples/bunny_on_floor.py --out mixed
    warpbw render mixed/bunny_on_floor.toml -o out.exr --method adaptive --budget 8 --filter gmm_aligned
    warpbw bench mixed/bunny_on_floor.toml --json b.json      # the bunny where the floor does not hide it
    warpbw bench-filtering mixed/bunny_on_floor.toml --zoom 1,2,4,8 --gt-spp 256 --json f.json
                                                              # the floor where the bunny does not hide it

The scene (256x192 pixels, ``RESOLUTION``, lit by forest.exr):

* the bunny (meshes/bunny.obj, y in [-0.99, 0.99]) raised by 0.85 (``BUNNY_LIFT``), so that its lowest 0.14
  sinks into the floor, in the NPF fit gold-metallic-paint (brdf/npf.bin), shaded by the environment renderer;
* the floor: a plane of side 6 (``FLOOR_SIZE``) at y = 0 with examples/filtering_scenes.py's dunes (its
  Cook-Torrance material, normal-map scale and tiling; dunes.exr is precompute.surfaces' ``dunes`` at ``--size``
  texels square), rendered with reflectance filtering (004);
* the camera (``CAMERA``) above the floor in front of the bunny, looking down at it: the floor fills the frame
  below its far edge, a quarter of the way down, and the bunny hides part of it.

The bunny, the probe and the NPF table are read from the shared data folder (../shared/data beside the repository,
or $WARPBW_SHARED_DATA) and written into the scene by their absolute paths; without them nothing is written.
A file in OUT with other contents (a scene edited by hand, say) is refused without --force, before anything is
written; one with the same contents is rewritten.  The scene and its height field are written together, or
neither.
"""
from __future__ import annotations

from warpbw.entry import interrupt_in_one_line

interrupt_in_one_line(__name__)   # first: a Ctrl-C while the imports below load says one line, no traceback

import argparse
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:   # the dunes of filtering_scenes.py, its sibling (also when imported from elsewhere)
    sys.path.insert(0, str(HERE))

from filtering_scenes import SCENES, height_field, holds_other  # noqa: E402
from precompute.surfaces import MAX_SURFACE_SIZE, MIN_SURFACE_SIZE  # noqa: E402
from warpbw.cli_common import OneLineParser, check_output_dir, check_overwrite, run_command  # noqa: E402
from warpbw.errors import WarpbwError  # noqa: E402
from warpbw.io.shared_data import shared_data_dir  # noqa: E402
from warpbw.scene import toml_escape  # noqa: E402

DATA = shared_data_dir(HERE.parent)
# the shared files the scene names (../shared/data's README says where each comes from)
MESH, PROBE, NPF_TABLE = "meshes/bunny.obj", "envmaps/forest.exr", "brdf/npf.bin"
NPF_MATERIAL = "gold-metallic-paint"
FLOOR = "dunes"            # filtering_scenes.SCENES' surface under the bunny
RESOLUTION = (256, 192)
BUNNY_LIFT = 0.85          # bunny.obj's lowest vertex is at y = -0.99: 0.14 of it below the floor (y = 0)
FLOOR_SIZE = 6.0           # the plane's side (the bunny is 2 wide)
# above the floor in front of the bunny, looking down at it (the floor's far edge a quarter down the frame)
CAMERA = "position = [0.0, 3.0, 4.6]\nlook_at = [0.0, 0.5, 0.0]\nfov = 40.0"
SCENE_NAME = "bunny_on_floor.toml"

SCENE = """\
# the Stanford bunny sunk into a dunes floor: a plane with a normal map beside a mesh (examples/bunny_on_floor.py)
[camera]
{camera}
resolution = [{w}, {h}]

[environment]
file = "{data}/{probe}"

[[object]]
mesh = "{data}/{mesh}"
translate = [0.0, {lift}, 0.0]
material = "bunny"

[[object]]
shape = "plane"
center = [0.0, 0.0, 0.0]
size = {floor_size}
material = "floor"

[material.bunny]
type = "npf"
table = "{data}/{table}"
name = "{npf_name}"

[material.floor]
type = "cook-torrance"
roughness = {roughness}
f0 = {f0}
diffuse = {diffuse}
normal_map = "{floor}.exr"
normal_map_kind = "height"
normal_map_scale = 1.0
tiling = {tiling}
"""


def scene_text() -> str:
    """The scene file's TOML (the shared files by their absolute paths, the height field beside it)."""
    _, tiling, mat = SCENES[FLOOR]
    data = toml_escape(DATA.as_posix(), f"the shared data folder {DATA}")
    return SCENE.format(camera=CAMERA, w=RESOLUTION[0], h=RESOLUTION[1], data=data, probe=PROBE, mesh=MESH,
                        lift=BUNNY_LIFT, floor_size=FLOOR_SIZE, table=NPF_TABLE, npf_name=NPF_MATERIAL,
                        floor=FLOOR, tiling=tiling, **mat)


def write_scene(out: Path, size: int, force: bool = False) -> Path:
    """Write OUT/bunny_on_floor.toml and OUT/dunes.exr (``size`` texels square); returns the scene's path.  A file
    there with other contents is refused without ``force``, before anything is written."""
    from warpbw.io.exr import write_exr
    from warpbw.io.staged import staged_outputs

    missing = [rel for rel in (MESH, PROBE, NPF_TABLE) if not (DATA / rel).is_file()]
    if missing:
        raise WarpbwError(f"{DATA / missing[0]}: not found (the scene needs the shared data folder's bunny, "
                          "forest.exr and NPF table: clone ../shared beside the repository or set "
                          "$WARPBW_SHARED_DATA)")
    scene, heights = out / SCENE_NAME, out / f"{FLOOR}.exr"
    outputs = {scene: scene_text(), heights: height_field(FLOOR, size)}
    check_overwrite([p for p, contents in outputs.items() if holds_other(p, contents)], force, "--out")
    with staged_outputs(outputs) as at:   # the scene and its height field, or neither
        write_exr(at[heights], outputs[heights], channels=["Y"])
        at[scene].write_text(outputs[scene])
    return scene


def main(argv=None) -> int:
    ap = OneLineParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True, metavar="DIR",
                    help=f"directory for {SCENE_NAME} and the floor's height field {FLOOR}.exr (made if absent)")
    ap.add_argument("--size", type=int, default=256,
                    help=f"height-field size in texels, from {MIN_SURFACE_SIZE} to {MAX_SURFACE_SIZE} (default 256, "
                    "as filtering_scenes.py's)")
    ap.add_argument("--force", action="store_true",
                    help="overwrite a scene or height field in DIR that holds other contents")
    args = ap.parse_args(argv)
    if not MIN_SURFACE_SIZE <= args.size <= MAX_SURFACE_SIZE:
        ap.error(f"--size {args.size}: expected an integer from {MIN_SURFACE_SIZE} to {MAX_SURFACE_SIZE}")
    check_output_dir(args.out, "--out")
    scene = write_scene(Path(args.out), args.size, args.force)
    print(f"wrote {scene} and {FLOOR}.exr ({args.size}x{args.size}); next:\n"
          f"  warpbw render {scene} -o out.exr --method adaptive --budget 8 --filter gmm_aligned\n"
          f"  warpbw bench {scene} --json b.json\n"
          f"  warpbw bench-filtering {scene} --zoom 1,2,4,8 --gt-spp 256 --json f.json")
    return 0


if __name__ == "__main__":
    sys.exit(run_command("bunny_on_floor.py", lambda _: main(), None))
