"""Versioned asset files written by ``warpbw-precompute`` and read by the renderer.

Public: ``write_asset(path, fmt, version, source, source_hash, arrays, params, force, inputs=())``,
``read_asset(path, fmt, version, rebuild) -> Asset`` (``rebuild``: the command to suggest, or a function of the
file's header that gives it), ``Asset``, ``check_float_arrays(arrays, what, hint)`` (what the readers of
floating-point tables refuse).

An asset is a NumPy ``.npz`` archive (no pickles) holding named arrays and a JSON ``header`` with the
format name, its version, the source asset's name, the source's content hash (blake2b of its bytes),
the parameters it was built with and the warpbw version that wrote it.  The renderer refuses a file of
another format or version with a message that says how to rebuild it.
"""
from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from warpbw.errors import WarpbwError, check_input_file
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


def read_asset(path, fmt: str, version: int, rebuild) -> Asset:
    """Read an asset of format ``fmt`` and version ``version``; ``rebuild`` is the command to suggest, or a function
    of the file's header (a dict) that gives it, so that a file of another version is told how to rebuild it from
    its own source and parameters."""
    def how(header) -> str:   # a file of another format gets the header-less command: its header is not ours
        return rebuild(header if isinstance(header, dict) else {}) if callable(rebuild) else rebuild

    p = check_input_file(path)
    try:
        header = None
        if _members_hold_what_they_declare(p):
            with np.load(p, allow_pickle=False) as z:
                header = json.loads(str(z[HEADER_KEY]))
                arrays = {k: z[k] for k in z.files if k != HEADER_KEY}
    except Exception:   # noqa: BLE001 -- whatever numpy, zipfile or json raise reading these bytes is their damage:
        # EOFError for a zero-byte file, zlib.error, zipfile's "compression method is not supported" for an unknown
        # method, RuntimeError for the encrypted flag, RecursionError for a deeply nested header.  Refused below; a
        # cache entry is rebuilt (load_or_build rebuilds on the WarpbwError)
        header = None
    if not isinstance(header, dict):  # also a JSON header that is not an object (a list, a string)
        raise WarpbwError(f"{p}: not a warpbw asset file, or a damaged one (expected a {fmt} file written by "
                          f"warpbw-precompute; rebuild it with: {how(None)})")
    if header.get("format") != fmt:
        raise WarpbwError(f"{p}: is a {header.get('format')!r} file, expected {fmt!r} "
                          f"(rebuild it with: {how(None)})")
    if header.get("version") != version:
        raise WarpbwError(f"{p}: {fmt} version {header.get('version')!r}, this warpbw reads version {version} "
                          f"(rebuild it with: {how(header)})")
    return Asset(header, arrays)


def check_float_arrays(arrays, what: str, hint: str) -> None:
    """Refuse, in one line starting ``what``, ``arrays`` of which one holds numbers that are not floating point:
    the writers store float32, and a damaged dtype field read as integers rendered another image, exit 0.  Strings
    and objects pass here (each reader refuses them in its own words); ``hint`` ends the message."""
    kinds = sorted({np.asarray(a).dtype.name for a in arrays if np.asarray(a).dtype.kind not in "fUSO"})
    if kinds:
        raise WarpbwError(f"{what} of type {', '.join(kinds)}, expected floating-point numbers{hint}")
