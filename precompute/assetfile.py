"""Versioned asset files written by ``warpbw-precompute`` and read by the renderer.

Public: ``write_asset(path, fmt, version, source, source_hash, arrays, params, force, inputs=())``,
``read_asset(path, fmt, version, rebuild) -> Asset`` (``rebuild``: the command to suggest, or a function of the
file's header that gives it), ``Asset``, ``check_float_arrays(arrays, what, hint)`` (what the readers of
floating-point tables refuse); ``read_header(path) -> dict | None`` (the header alone) and
``settings_mismatch(params, current, unrecorded=None) -> str | None`` (what a cache reader checks, below);
``read_any_asset(path) -> Asset`` (header and arrays of whatever format and version: ``warpbw-precompute info``).

An asset is a NumPy ``.npz`` archive (no pickles) holding named arrays and a JSON ``header`` with the
format name, its version, the source asset's name, the source's content hash (blake2b of its bytes),
the parameters it was built with and the warpbw version that wrote it.  The renderer refuses a file of
another format or version with a message that says how to rebuild it.

Builder settings.  A file's ``params`` record the settings its builder ran with (the sampling tables' view
subsamples, the nu_rho table's resolution, wavelet and epsilon, ...).  A file the user names in a scene may have been
built with other legitimate settings (a nu_rho table analysed at another resolution) and is read as it is; an entry of
warpbw's own cache (``$WARPBW_CACHE``) stands for what the builder would build now, so its reader compares the
recorded settings with the builder's current ones (``settings_mismatch``) and treats a difference as a stale entry,
rebuilt and replaced as one of another version is (``precompute.brdf_sampling.load_or_build``,
``warpbw.bandwidth.env_bandwidth_map``): a constant changed without a version bump no longer serves the old tables.
A setting an older file does not record is read as the value its builder used then (each reader's ``unrecorded``),
so entries whose settings equal the current ones stay valid.
"""
from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from warpbw.errors import WarpbwError, check_input_file, check_path
from warpbw.io.staged import check_replaceable, staged_outputs

HEADER_KEY = "__header__"


@dataclass
class Asset:
    header: dict
    arrays: dict


def write_asset(path, fmt: str, version: int, source: str, source_hash: str, arrays: dict,
                params: dict | None = None, force: bool = False, inputs=()) -> Path:
    """Write arrays and a header; refuses to overwrite an existing file unless ``force``, and whatever ``force``
    says, a read-only file or one of ``inputs`` (the files the asset is made from)."""
    from warpbw import __version__

    p = check_replaceable(path, force, inputs)
    header = {"format": fmt, "version": int(version), "source": source, "source_hash": source_hash,
              "params": params or {}, "writer": f"warpbw {__version__}"}
    # a temporary of its own, moved into place: never a cut-off or mixed file; with force (caches, which two runs may
    # write at once, and --force) a file that appeared meanwhile is replaced
    with staged_outputs([p], force=force) as tmp:
        with open(tmp[p], "wb") as f:
            np.savez_compressed(f, **{HEADER_KEY: np.array(json.dumps(header))}, **arrays)
    return p


def _members_hold_what_they_declare(p: Path) -> bool:
    """Each .npy member of the archive holds at least the bytes its header declares (shape times item size).
    numpy allocates the declared array before it reads: a damaged header declaring 2**40 floats ended the render
    with "Unable to allocate 4.00 TiB", naming no file, and a cache entry so damaged was not rebuilt.  False also
    for a member whose .npy header cannot be read; raises what zipfile raises for a damaged archive."""
    with zipfile.ZipFile(p) as zf:
        for info in zf.infolist():
            with zf.open(info) as f:
                major_minor = np.lib.format.read_magic(f)
                read_header = {(1, 0): np.lib.format.read_array_header_1_0,
                               (2, 0): np.lib.format.read_array_header_2_0}.get(major_minor)
                if read_header is None:   # version 3 (utf-8 field names) is never written here
                    return False
                shape, _, dtype = read_header(f)
                declared = int(np.prod(shape, dtype=object)) * dtype.itemsize
                if declared > info.file_size - f.tell():
                    return False
    return True


def _load(p: Path, arrays: bool = True) -> tuple:
    """``(header, arrays)`` of the archive ``p``, the header as JSON gives it back (any value; ``arrays=False``: the
    header alone, ``{}`` for the arrays); ``(None, {})`` when its bytes are no asset file's."""
    try:
        if _members_hold_what_they_declare(p):
            with np.load(p, allow_pickle=False) as z:
                header = json.loads(str(z[HEADER_KEY]))
                return header, ({k: z[k] for k in z.files if k != HEADER_KEY} if arrays else {})
    except Exception:   # noqa: BLE001 -- whatever numpy, zipfile or json raise reading these bytes is their damage:
        # EOFError for a zero-byte file, zlib.error, zipfile's "compression method is not supported" for an unknown
        # method, RuntimeError for the encrypted flag, RecursionError for a deeply nested header.  Refused by the
        # callers; a cache entry is rebuilt (load_or_build rebuilds on the WarpbwError)
        pass
    return None, {}


def read_asset(path, fmt: str, version: int, rebuild) -> Asset:
    """Read an asset of format ``fmt`` and version ``version``; ``rebuild`` is the command to suggest, or a function
    of the file's header (a dict) that gives it, so that a file of another version is told how to rebuild it from
    its own source and parameters."""
    def how(header) -> str:   # a file of another format gets the header-less command: its header is not ours
        return rebuild(header if isinstance(header, dict) else {}) if callable(rebuild) else rebuild

    p = check_input_file(path)
    header, arrays = _load(p)
    if not isinstance(header, dict):  # also a JSON header that is not an object (a list, a string)
        raise WarpbwError(f"{p}: not a warpbw asset file, or a damaged one (expected a {fmt} file written by "
                          f"warpbw-precompute; rebuild it with: {how(None)})")
    if header.get("format") != fmt:
        raise WarpbwError(f"{p}: is a {header.get('format')!r} file, expected {fmt!r} "
                          f"(rebuild it with: {how(None)})")
    if header.get("version") != version:
        raise WarpbwError(f"{p}: {fmt} version {header.get('version')!r}, this warpbw reads version {version} "
                          f"(rebuild it with: {how(header)})")
    if not isinstance(header.get("params", {}), dict):
        # the readers look their settings up in it (a list or null gave an AttributeError from deep inside)
        raise WarpbwError(f"{p}: a {fmt} file whose header records params {json.dumps(header['params'])[:40]}, "
                          f"expected a JSON object of its builder's settings (a damaged or hand-edited header; "
                          f"rebuild it with: {how(None)})")
    return Asset(header, arrays)


def read_any_asset(path) -> Asset:
    """The header and arrays of the asset file ``path`` whatever its format and version (``warpbw-precompute info``
    says what a file holds); a file that is none, or a damaged one, is refused in one line as ``read_asset`` refuses
    it.  The header is a dict; what it holds is not checked."""
    p = check_input_file(path, "an asset file of warpbw")
    header, arrays = _load(p)
    if not isinstance(header, dict):
        raise WarpbwError(f"{p}: not a warpbw asset file, or a damaged one (expected an .npz archive with a JSON "
                          "header, as warpbw-precompute and the renderer's cache write)")
    return Asset(header, arrays)


def read_header(path) -> dict | None:
    """The JSON header of the asset file ``path`` without its arrays (a cache reader's cheap look at its ``params``),
    or None when ``path`` is no asset file, or a damaged one (``read_asset`` then says what is wrong)."""
    header, _ = _load(check_path(path, "read_header: path"), arrays=False)
    return header if isinstance(header, dict) else None


def _same_setting(recorded, current) -> bool:
    """Whether a recorded setting is ``current``: numbers by value (JSON keeps 4 and 0.01 as written; a bool is no
    number), anything else as JSON gives it back (a tuple recorded is a list)."""
    def number(x):
        return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, (bool, np.bool_))
    if number(recorded) or number(current):
        return number(recorded) and number(current) and float(recorded) == float(current)
    return recorded == json.loads(json.dumps(current))


def settings_mismatch(params, current: dict, unrecorded: dict | None = None) -> str | None:
    """The first of the builder's ``current`` settings (key -> value) that a file's recorded ``params`` (its
    header's) gives otherwise, as "KEY RECORDED, the builder's VALUE"; None when every one agrees.  A key the file
    does not record is read as ``unrecorded``'s value (what the builder used before its files recorded the key, or
    what the writer leaves out at its default), and differs when ``unrecorded`` lacks it; ``params`` that are no
    dict record nothing.  Keys ``params`` holds beyond ``current`` are not compared."""
    params = params if isinstance(params, dict) else {}
    unrecorded = unrecorded or {}
    for key, value in current.items():
        if key in params:
            recorded = params[key]
        elif key in unrecorded:
            recorded = unrecorded[key]
        else:
            return f"{key} not recorded, the builder's {value!r}"
        if not _same_setting(recorded, value):
            return f"{key} {recorded!r}, the builder's {value!r}"
    return None


def check_float_arrays(arrays, what: str, hint: str) -> None:
    """Refuse, in one line starting ``what``, ``arrays`` of which one holds numbers that are not floating point:
    the writers store float32, and a damaged dtype field read as integers rendered another image, exit 0.  Strings
    and objects pass here (each reader refuses them in its own words); ``hint`` ends the message."""
    kinds = sorted({np.asarray(a).dtype.name for a in arrays if np.asarray(a).dtype.kind not in "fUSO"})
    if kinds:
        raise WarpbwError(f"{what} of type {', '.join(kinds)}, expected floating-point numbers{hint}")
