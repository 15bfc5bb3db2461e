"""The ``warpbw-precompute`` command: turn raw assets into the tables the renderer reads.

Public: ``main(argv=None) -> int``.  The command line's own parts, not an API: ``build_parser()`` and the
subcommands' handlers ``cmd_npf_to_merl``, ``cmd_brdf_sampling``, ``cmd_brdf``, ``cmd_batch``, ``cmd_gmm`` and
``cmd_info``.

Subcommands:
    npf-to-merl    write a MERL ``.binary`` file from one material of an NPF table
    brdf-sampling  build importance-sampling tables of a tabulated BRDF (002 Sec. 3.3)
    brdf           angular bandwidth table nu_rho of a tabulated BRDF (002 Sec. 2.3)
    batch          both tables of many tabulated BRDFs (every NPF material, a folder of MERL files), on Dask
    gmm            EM-aligned GMM normal mipmap of a height field or normal map (004 Sec. 4.1)
    info           what asset files hold: format, version, source, settings, arrays (``precompute.asset_info``)
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

from warpbw.cli_common import (EXIT_USER_ERROR, OneLineParser, check_output_file, check_overwrite, parse_path,
                               parse_seed, printable, run_command)
from precompute.gmm_mipmap import DEFAULT_PRIOR, MAX_COMPONENTS, MAX_PRIOR
from precompute.surfaces import MAX_SURFACE_SIZE, MIN_SURFACE_SIZE
from warpbw import __version__
from warpbw.errors import WarpbwError
from warpbw.io.staged import check_still_free
from warpbw.scene import LOOKUP_MODES


# what each subcommand writes: the output's name must end in one of these (a habitual --force after a typo in -o
# would otherwise replace an image or a BRDF file)
MERL_SUFFIXES = (".binary",)
TABLE_SUFFIXES = (".npz",)
GMM_SUFFIXES = (".npz", ".gmm")     # a scene's gmm = "scales.gmm" (issue 4's scene syntax)


class _Default(float):
    """A float option's default that the command can tell from the same number given (``is``): gmm's --prior with
    --unaligned and --scale with --kind normal are refused even at their default values, which the run would drop."""


PRIOR_DEFAULT, SCALE_DEFAULT = _Default(DEFAULT_PRIOR), _Default(1.0)   # --scale 1: heights in map widths


def _check_output(args, source, suffixes) -> Path:
    """-o: a name ending in one of ``suffixes``, not the source it is made from (whatever --force says), and not an
    existing file without --force; refused before any work."""
    out = Path(args.output)
    check_output_file(out, "-o", force=True)      # a directory, or a path under a file: refused first
    if out.suffix.lower() not in suffixes:
        raise WarpbwError(f"-o {out}: expected a path ending in {' or '.join(suffixes)}")
    check_overwrite([out], args.force, inputs=[source] if source is not None else [],
                    inputs_are="the file it is made from")
    return out


def cmd_npf_to_merl(args) -> int:
    from precompute.npf_to_merl import npf_to_merl
    from warpbw.io.npf import read_npf

    _check_output(args, args.table, MERL_SUFFIXES)
    t0 = time.perf_counter()
    name = read_npf(args.table, args.material).name   # as the table spells it (" Gold-Metallic-Paint " was echoed)
    out = npf_to_merl(args.table, args.material, args.output, force=args.force)
    print(printable(f"{out}  (MERL .binary from {args.table}:{name}, {time.perf_counter() - t0:.1f} s)"))
    return 0


def _table_command(args, build, write, describe) -> int:
    """The table subcommands: refuse an existing output, open the source, build, write, report."""
    from precompute.brdf_sampling import brdf_source

    from warpbw.io.merl import MERL_FILE_SIZE
    from warpbw.io.npf import NPF_FILE_SIZE

    out = _check_output(args, args.file, TABLE_SUFFIXES)
    f = Path(args.file)
    # read as MERL, the table's error said only how a scene reads one, not this command's own option
    if args.material is None and f.is_file() and f.stat().st_size == NPF_FILE_SIZE:
        raise WarpbwError(f"{f}: the size of an NPF table: name one of its materials with --material NAME")
    if args.material is not None and f.is_file() and f.stat().st_size == MERL_FILE_SIZE:   # read as an NPF table
        raise WarpbwError(f"--material {args.material}: applies to NPF tables, and {f} is the size of a MERL file "
                          f"({MERL_FILE_SIZE} bytes): leave --material out")
    t0 = time.perf_counter()
    source = brdf_source(args.file, args.material, getattr(args, "lookup", None))
    table = build(source, progress=not args.quiet)
    check_still_free(out, args.force)   # another run's, finished first: said so, not "pass --force"
    write(out, table, source, force=args.force)
    print(printable(f"{out}  ({describe(source, table)}, {time.perf_counter() - t0:.1f} s)"))
    return 0


def cmd_brdf_sampling(args) -> int:
    from precompute.brdf_sampling import build_brdf_sampling, write_sampling

    return _table_command(args, build_brdf_sampling, write_sampling, lambda source, t: (
        f"sampling tables for {source.name}: {t.shape[0]} view elevations x {t.shape[1]} x {t.shape[2]} "
        "half-vector cells"))


def cmd_brdf(args) -> int:
    from precompute.brdf_bandwidth import build_brdf_bandwidth, write_brdf_bandwidth

    return _table_command(args, build_brdf_bandwidth, write_brdf_bandwidth, lambda source, t: (
        f"angular bandwidth of {source.name}: {t.shape[0]} incident elevations x {t.shape[1]}x{t.shape[2]} "
        f"outgoing cells, max {float(t.max()):.2f} cycles/radian"))


def _csv(option: str):
    """argparse type: comma-separated names, none empty."""
    def parse(s):
        names = [n.strip() for n in s.split(",")]
        if not all(names):
            raise argparse.ArgumentTypeError(f"expected comma-separated names, got {s!r}")
        return names
    parse.__name__ = option
    return parse


# The most of an existing file at a batch record's path read to tell whether it is one: a record holds about 1 kB per
# BRDF (all 100 NPF materials: about 100 kB); a larger file is no record (cut off, it is no JSON either)
BATCH_RECORD_READ_MAX = 16 << 20


def _check_batch_record(path: Path) -> None:
    """Refuse, before any work, a file at the record's path that is not a batch record: ``--resume`` keeps or replaces
    an earlier batch's outputs and record, and refuses other files in their place unless ``--force`` is given too (a
    table's place was checked so, the record's was replaced whatever it held: a JSON of the user's, text)."""
    from precompute.batch import BATCH_FORMAT

    if not path.is_file():
        return
    try:
        with open(path, "rb") as f:
            record = json.loads(f.read(BATCH_RECORD_READ_MAX).decode("utf-8"))   # cut: no JSON, refused
    except (OSError, ValueError):   # UnicodeDecodeError and JSONDecodeError are ValueErrors
        record = None
    if not (isinstance(record, dict) and record.get("format") == BATCH_FORMAT):
        raise WarpbwError(f"--json {path}: exists and is not the record of a batch (expected JSON of format "
                          f"{BATCH_FORMAT!r}; --resume replaces an earlier batch's record only; pass --force as well "
                          "to replace it)")


def cmd_batch(args) -> int:
    from precompute.batch import TABLES, batch_items, check_outputs, check_tables, run_batch
    from warpbw.cli_common import check_output_file, write_json
    from warpbw.io.staged import output_exists

    tables = TABLES if args.tables is None else tuple(args.tables)
    try:    # the library names its parameters; here they are options
        items = batch_items(args.sources, args.materials)
        check_tables(tables)
    except WarpbwError as exc:
        msg = str(exc)
        raise WarpbwError(f"--{msg}" if msg.split(":", 1)[0] in ("materials", "tables") else msg) from None
    if args.lookup is not None and "bandwidth" not in tables:   # accepted, recorded, and dropped
        raise WarpbwError(f"--lookup {args.lookup}: applies to the bandwidth tables (brdf --lookup), and --tables "
                          f"{','.join(tables)} builds none (the sampling tables do not depend on the lookup)")
    out = Path(args.output)
    record_path = out / "batch.json" if args.json is None else Path(args.json)
    if record_path.suffix.lower() != ".json":
        raise WarpbwError(f"--json {record_path}: expected a path ending in .json")
    check_outputs(items, out, tables, force=args.force, resume=args.resume)
    check_output_file(record_path, "--json", force=args.force or args.resume)
    if args.resume and not args.force:
        _check_batch_record(record_path)
    # the record is replaced only where it may be: --force, or --resume's earlier record, there before the work; one
    # that appears while the batch works (another batch writing this folder) is kept, as every command keeps it
    replace_record = args.force or (args.resume and output_exists(record_path))
    workers = min(args.workers or os.cpu_count() or 1, len(items))
    how = "one after the other" if args.scheduler == "sync" else f"{workers} at once"
    print(printable(f"{len(items)} BRDFs, {' and '.join(tables)} tables into {out}/ (Dask's {args.scheduler} "
                    f"scheduler, {how})"), flush=True)
    record = run_batch(items, out, tables, scheduler=args.scheduler, workers=workers, force=args.force,
                       resume=args.resume, progress=not args.quiet, lookup=args.lookup)
    for r in record["items"]:
        for w in r["warnings"]:
            print(printable(f"warpbw-precompute: warning: {w}"), file=sys.stderr)
        if r["error"] is not None:
            print(printable(f"warpbw-precompute: error: {r['name']}: {r['error']}"), file=sys.stderr)
    try:
        write_json(record_path, record, say=False, force=replace_record)
    except WarpbwError:
        if not output_exists(record_path):   # not the record that appeared meanwhile: a full disk, a lost folder
            raise
        raise WarpbwError(f"{record_path}: already exists: it appeared while this batch worked (another batch writing "
                          "this folder, or you), and is kept; its tables are written, its record is not (pass "
                          "--resume and another --json to write it without building them again)") from None
    kept = sum(len(r["kept"]) for r in record["items"])
    built = sum(len(r["outputs"]) - len(r["kept"]) for r in record["items"] if r["error"] is None)
    print(printable(f"{out}/  ({built} tables built{f', {kept} kept' if kept else ''}, {record['failed']} BRDFs "
                    f"failed; {record['wall_s']:.1f} s wall, {record['work_s']:.1f} s of work; record in "
                    f"{record_path})"))
    return 1 if record["failed"] else 0


def cmd_gmm(args) -> int:
    from precompute.gmm_mipmap import build_gmm_mipmap, load_source, write_gmm_mipmap

    # given at all, even at their defaults: --unaligned --prior 1 was accepted and dropped (options audit, session 64)
    if args.kind == "normal" and args.scale is not SCALE_DEFAULT:
        raise WarpbwError(f"--scale {args.scale:g}: applies to --kind height only (a normal map's normals are used "
                          "as they are)")
    if args.unaligned and args.prior is not PRIOR_DEFAULT:
        raise WarpbwError(f"--prior {args.prior:g}: the unaligned baseline (--unaligned) has no alignment prior")
    prior, scale = float(args.prior), float(args.scale)
    out = _check_output(args, None if args.map.startswith("surface:") else args.map, GMM_SUFFIXES)
    t0 = time.perf_counter()
    data, name, digest = load_source(args.map, args.kind)
    try:
        mip = build_gmm_mipmap(data, kind=args.kind, components=args.components, prior=prior, scale=scale,
                               seed=args.seed, progress=not args.quiet, unaligned=args.unaligned)
    except WarpbwError as exc:    # the builder names its parameters; here they are options
        msg = str(exc)
        raise WarpbwError(f"--{msg}" if msg.split(" ", 1)[0] in ("components", "prior", "scale") else msg) from None
    check_still_free(out, args.force)   # another run's, finished first: said so, not "pass --force"
    write_gmm_mipmap(out, mip, name, digest, force=args.force,
                     inputs=[] if args.map.startswith("surface:") else [args.map])
    h, w = mip.shape
    how = "unaligned (independent EM per texel)" if args.unaligned else f"aligned, prior c={prior:g}"
    print(printable(f"{out}  (GMM mipmap of {name}: {w}x{h}, {len(mip.levels)} levels, {mip.components} "
                    f"components, "
                    f"{how}, {time.perf_counter() - t0:.1f} s)"))
    return 0


def cmd_info(args) -> int:
    from precompute.asset_info import asset_info, info_lines
    from warpbw.cli_common import json_text

    records, bad = [], 0
    for path in args.files:
        try:
            rec = asset_info(path)
        except WarpbwError as exc:   # said at once, in its place among the others; the rest go on
            sys.stdout.flush()
            print(f"warpbw-precompute: error: {printable(exc)}", file=sys.stderr, flush=True)
            records.append({"path": str(path), "error": str(exc)})
            bad += 1
            continue
        records.append(rec)
        if not args.json:
            print("\n".join(([""] if len(records) - bad > 1 else []) + [printable(line) for line in info_lines(rec)]))
    if args.json:
        print(json_text(records), end="")
    return EXIT_USER_ERROR if bad else 0


def _integer_from(lo: int, hi: int):
    """argparse type: an integer from ``lo`` to ``hi``, said so for any other value (argparse's own words were
    "invalid int value: '2.5'", with no range)."""
    def parse(s):
        try:
            v = int(s)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer from {lo} to {hi}, got {s!r}") from None
        if not lo <= v <= hi:
            raise argparse.ArgumentTypeError(f"expected an integer from {lo} to {hi}, got {v}")
        return v
    parse.__name__ = "integer"
    return parse


def _number_from(lo: float, hi: float | None = None):
    """argparse type: a finite number from ``lo`` to ``hi`` (``hi`` None: any finite number > ``lo``)."""
    expected = f"a number from {lo:g} to {hi:g}" if hi is not None else f"a finite number > {lo:g}"

    def parse(s):
        try:
            v = float(s)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {expected}, got {s!r}") from None
        if not (math.isfinite(v) and (lo <= v <= hi if hi is not None else v > lo)):
            raise argparse.ArgumentTypeError(f"expected {expected}, got {s}")
        return v
    parse.__name__ = "number"
    return parse


def _table_args(p: argparse.ArgumentParser) -> None:
    """The arguments every tabulated-BRDF table command takes: the BRDF, the output, --force, --quiet."""
    p.add_argument("file", type=parse_path, help="MERL .binary file, or NPF table with --material")
    p.add_argument("--material", default=None, help="NPF material name when FILE is an NPF table")
    p.add_argument("-o", "--output", type=parse_path, required=True, help="output table file (a name ending in .npz)")
    p.add_argument("--force", action="store_true", help="overwrite an existing output")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")


def build_parser() -> argparse.ArgumentParser:
    return _build_parsers()[0]


def _build_parsers() -> tuple[argparse.ArgumentParser, argparse.ArgumentParser]:
    """warpbw-precompute's parser, and npf-to-merl's own: ``main`` says a table given twice or not at all in the
    words of the latter (argparse has no public way back to a subcommand's parser)."""
    p = OneLineParser(prog="warpbw-precompute",
                                description="Offline asset tool of warpbw: MERL files from NPF fits, importance-"
                                "sampling tables and angular bandwidth tables of tabulated BRDFs, GMM normal mipmaps "
                                "of height fields and normal maps.  Tables carry a format name, a version, the "
                                "source's name and its content hash.",
                                epilog="Results (the files a command wrote, what info reads) go to stdout; progress "
                                "bars, warnings and errors to stderr.  Exit status: 0 done; 2 a usage error or bad "
                                "input (one line on stderr; info: a FILE it could not read); 1 batch with a BRDF "
                                "that failed; 130, 143 or 129 stopped by Ctrl-C, SIGTERM or SIGHUP; 141 the reader "
                                "of stdout left (README: Command-line conventions).")
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    a = sub.add_parser("npf-to-merl", help="write a MERL .binary file from an NPF fit",
                       description="Tabulate one material of an NPF table (e.g. ../shared/data/brdf/npf.bin) at "
                       "the 90x90x180 MERL bin centres and write it as a MERL .binary file.")
    # the table as brdf-sampling, brdf and batch take their source, or --table as before (session 81)
    a.add_argument("table", nargs="?", type=parse_path, default=None, metavar="TABLE",
                   help="NPF table (npf.bin); or --table TABLE")
    a.add_argument("--table", dest="table_option", type=parse_path, default=None, metavar="TABLE",
                   help="the NPF table, given as an option")
    a.add_argument("--material", required=True, help="material name, e.g. gold-metallic-paint")
    a.add_argument("-o", "--output", type=parse_path, required=True, help="output MERL file (a name ending in .binary)")
    a.add_argument("--force", action="store_true", help="overwrite an existing output")
    a.set_defaults(func=cmd_npf_to_merl)

    b = sub.add_parser("brdf-sampling", help="importance-sampling tables for a tabulated BRDF",
                       description="Build per-view-elevation tables over half vectors and invert their CDF "
                       "(002 Sec. 3.3).  FILE is a MERL .binary, or an NPF table with --material.  The renderer "
                       "builds and caches these itself when a scene names none (key 'sampling').")
    _table_args(b)
    b.set_defaults(func=cmd_brdf_sampling)

    c = sub.add_parser("brdf", help="angular bandwidth table of a tabulated BRDF",
                       description="For 16 incident elevations, the local angular bandwidth (cycles/radian) "
                       "of the outgoing lobe on a 128x128 equal-area map, reduced to 16x16 cells by a maximum "
                       "(002 Sec. 2.3, 'Reflectance').  FILE is a MERL .binary, or an NPF table with --material.  "
                       "The renderer builds and caches these itself for --method adaptive when a scene names none "
                       "(key 'bandwidth').")
    _table_args(c)
    c.add_argument("--lookup", choices=LOOKUP_MODES, default=None,
                   help="how the material reads its tables, as the scene's lookup says: nearest (the bin a direction "
                   "pair falls in) or linear (between bin centres).  The table is the bandwidth of the BRDF as it is "
                   "shaded, and nearest-bin steps vary faster than interpolated curves (an NPF fit's cells by up to "
                   "1.9x), so the renderer refuses a table of another lookup than its material's.  Default: the "
                   "scene's, MERL nearest, NPF linear")
    c.set_defaults(func=cmd_brdf)

    bt = sub.add_parser("batch", help="both tables of many tabulated BRDFs, on Dask",
                        description="Build the importance-sampling and angular bandwidth tables of many tabulated "
                        "BRDFs, each BRDF one task on Dask (pip install -e \".[batch]\"): every material of an NPF "
                        "table (or --materials), MERL .binary files, folders of them.  Each writes "
                        "OUT/NAME.sampling.npz and OUT/NAME.bandwidth.npz, the files brdf-sampling and brdf (with "
                        "the same --lookup) write, bit for bit; a scene names them with sampling = and bandwidth =.  "
                        "A BRDF that cannot be read is reported and the others go on (exit 1 at the end).  The record "
                        "(OUT/batch.json) holds each BRDF's outputs, times, largest nu_rho, warnings and error.")
    bt.add_argument("sources", nargs="+", type=parse_path, metavar="SOURCE",
                    help="an NPF table (npf.bin), a MERL .binary file, or a folder of MERL files")
    bt.add_argument("-o", "--output", type=parse_path, required=True, metavar="DIR",
                    help="output folder (made if absent)")
    bt.add_argument("--materials", type=_csv("materials"), default=None,
                    help="the NPF tables' materials, comma-separated (without it, all 100)")
    bt.add_argument("--tables", type=_csv("tables"), default=None,
                    help="which tables: sampling, bandwidth or both, comma-separated (default both)")
    bt.add_argument("--scheduler", choices=("processes", "threads", "sync"), default="processes",
                    help="Dask's local scheduler (default processes: the builders hold the GIL; sync runs in this "
                    "process, one BRDF after the other)")
    bt.add_argument("--workers", type=_integer_from(1, 1024), default=None,
                    help="tasks at once, 1 to 1024 (default one per core, at most one per BRDF)")
    bt.add_argument("--json", type=parse_path, default=None, help="the record (default OUT/batch.json)")
    bt.add_argument("--resume", action="store_true",
                    help="keep the outputs that already hold this BRDF's table (an earlier, stopped batch's) and "
                    "build the rest; another file in their place is refused unless --force is given too")
    bt.add_argument("--lookup", choices=LOOKUP_MODES, default=None,
                    help="the lookup the scenes' materials shade with (brdf --lookup): the bandwidth tables are "
                    "those of the BRDFs read with it, and a scene refuses a table of another lookup than its "
                    "material's.  Default: the scene's, MERL nearest, NPF linear")
    bt.add_argument("--force", action="store_true", help="replace existing outputs and record")
    bt.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    bt.set_defaults(func=cmd_batch)

    g = sub.add_parser("gmm", help="GMM normal mipmap of a height field or normal map",
                       description="Build a mipmap whose texels hold an N-component Gaussian mixture of the "
                       "normals (projected (n_x, n_y), isotropic std per component) of their footprint, fitted "
                       "coarse to fine by EM with the neighbour-alignment prior of 004 Sec. 4.1, and stored as "
                       "the linearly filterable (a, a mu_x, a mu_y, a E|n|^2) per component (E|n|^2 = "
                       "2 s^2 + |mu|^2, s the std per axis).  MAP is an OpenEXR or PNG (8/16-bit) image (or another "
                       "image Pillow reads, such as TIFF; JPEG's lossy compression warns), or a "
                       "procedural height field surface:NAME[:SIZE] with NAME one of hemispherical_scales, "
                       f"carved_disk, dunes (e.g. surface:dunes:512; SIZE up to {MAX_SURFACE_SIZE}, default 512; "
                       f"hemispherical_scales needs at least {MIN_SURFACE_SIZE}, and below about 16 texels the "
                       "others' detail is finer than a texel).")
    g.add_argument("map", type=parse_path, metavar="MAP",
                   help="height field / normal map image, or surface:NAME[:SIZE]")
    g.add_argument("-o", "--output", type=parse_path, required=True,
                   help="output mipmap file (a name ending in .npz or .gmm)")
    g.add_argument("--components", type=_integer_from(1, MAX_COMPONENTS), default=4,
                   help=f"Gaussians per texel, 1 to {MAX_COMPONENTS} (default 4)")
    g.add_argument("--prior", type=_number_from(0.0, MAX_PRIOR), default=PRIOR_DEFAULT,
                   help=f"alignment constant c of the MAP prior, 0 to {MAX_PRIOR:g} (default 1; 0 is plain EM; not "
                   "with --unaligned)")
    g.add_argument("--kind", choices=("height", "normal"), default="height",
                   help="MAP is a single-channel height field (default; 16-bit PNG or EXR: 8 bits "
                        "give terraced normals) or an RGB tangent-space normal map (PNG: [0, 1]-encoded; "
                        "EXR: raw unit vectors or [0, 1]-encoded; G points to the image's top row, the OpenGL "
                        "convention: flip G of a DirectX-style map)")
    g.add_argument("--scale", type=_number_from(0.0), default=SCALE_DEFAULT,
                   help="height multiplier, a finite number > 0; heights are in units of the map's width (default 1; "
                   "--kind height only)")
    g.add_argument("--unaligned", action="store_true",
                   help="baseline: independent EM per texel (no prior, no neighbour initialisation)")
    g.add_argument("--seed", type=parse_seed, default=0,
                   help="seed of the clustering and footprint subsampling, 0 to 2^32-1 (default 0)")
    g.add_argument("--force", action="store_true", help="overwrite an existing output")
    g.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    g.set_defaults(func=cmd_gmm)

    i = sub.add_parser("info", help="what asset files hold: format, version, source, settings, arrays",
                       description="Look inside the files warpbw-precompute writes (sampling tables, nu_rho tables, "
                       "GMM mipmaps) and the renderer's cache holds ($WARPBW_CACHE; also a probe's nu_a map).  For "
                       "each FILE: its format and version and what it is; whether this warpbw reads it (yes, or no "
                       "and why: another version, or what its reader refuses); the source it was built from (name, "
                       "content hash) and the warpbw that wrote it; the parameters it records; whether its builder "
                       "settings are the ones the builder would use now (a cache entry of other settings is "
                       "rebuilt, a file a scene names is read as it is); each array's name, shape, dtype, least and "
                       "greatest finite value and count of NaN or infinite values; a GMM mipmap's levels and "
                       "components.  A FILE that is missing, a directory, not an asset file or a damaged one is "
                       "named in one error line where it comes, the other files are still shown, and the command "
                       "exits 2.")
    i.add_argument("files", nargs="+", type=parse_path, metavar="FILE", help="an asset file (.npz or .gmm)")
    i.add_argument("--json", action="store_true",
                   help="print a JSON list, one object per FILE in order (strict JSON: NaN as null; a FILE that "
                   "could not be read is {\"path\": ..., \"error\": ...}); the hash is given whole")
    i.set_defaults(func=cmd_info)
    return p, a


def _npf_table(sub: argparse.ArgumentParser, args) -> None:
    """npf-to-merl's NPF table, TABLE or --table TABLE (one of them, once), into ``args.table``; else the usage error
    of its parser ``sub``."""
    if args.table is not None and args.table_option is not None:
        sub.error(f"the NPF table given twice ({args.table}, then --table {args.table_option}): give it once")
    if args.table is None and args.table_option is None:
        sub.error("the following arguments are required: TABLE (or --table TABLE)")
    args.table = args.table if args.table is not None else args.table_option


def main(argv=None) -> int:
    parser, npf_to_merl = _build_parsers()
    args = parser.parse_args(argv)
    if args.command == "npf-to-merl":
        _npf_table(npf_to_merl, args)
    return run_command("warpbw-precompute", args.func, args)


if __name__ == "__main__":
    sys.exit(main())
