"""Versioned asset files written by ``warpbw-precompute`` and read by the renderer.

Public: ``write_asset(path, fmt, version, source, source_hash, arrays, params, force, inputs=())``,
``read_asset(path, fmt, version, rebuild) -> Asset`` (``rebuild``: the command to suggest, or a function of the
file's header that gives it), ``Asset``.

An asset is a NumPy ``.npz`` archive (no pickles) holding named arrays and a JSON ``header`` with the
format name, its version, the source asset's name, the source's content hash (blake2b of its bytes),
the parameters it was built with and the warpbw version that wrote it.  The renderer refuses a file of
another format or version with a message that says how to rebuild it.
"""
from __future__ import annotations

import json
import zipfile
import zlib
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


def read_asset(path, fmt: str, version: int, rebuild) -> Asset:
    """Read an asset of format ``fmt`` and version ``version``; ``rebuild`` is the command to suggest, or a function
    of the file's header (a dict) that gives it, so that a file of another version is told how to rebuild it from
    its own source and parameters."""
    def how(header) -> str:   # a file of another format gets the header-less command: its header is not ours
        return rebuild(header if isinstance(header, dict) else {}) if callable(rebuild) else rebuild

    p = check_input_file(path)
    try:
        with np.load(p, allow_pickle=False) as z:
            header = json.loads(str(z[HEADER_KEY]))
            arrays = {k: z[k] for k in z.files if k != HEADER_KEY}
    except (zipfile.BadZipFile, zlib.error, ValueError, KeyError, OSError, EOFError, json.JSONDecodeError):
        header = None  # EOFError: numpy's answer to a zero-byte file; zlib.error: a damaged deflate stream
    if not isinstance(header, dict):  # also a JSON header that is not an object (a list, a string)
        raise WarpbwError(f"{p}: not a warpbw asset file (expected a {fmt} file written by "
                          f"warpbw-precompute; rebuild it with: {how(None)})")
    if header.get("format") != fmt:
        raise WarpbwError(f"{p}: is a {header.get('format')!r} file, expected {fmt!r} "
                          f"(rebuild it with: {how(None)})")
    if header.get("version") != version:
        raise WarpbwError(f"{p}: {fmt} version {header.get('version')!r}, this warpbw reads version {version} "
                          f"(rebuild it with: {how(header)})")
    return Asset(header, arrays)
