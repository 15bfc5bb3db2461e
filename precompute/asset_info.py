"""What an asset file holds: the logic of ``warpbw-precompute info FILE...`` (the command line is
:mod:`precompute.__main__`'s).

Public: ``asset_info(path) -> dict`` (the record ``--json`` prints), ``info_lines(record) -> list`` (the lines
the command prints), ``header_status(path) -> dict`` (the header's part alone: ``warpbw info`` of a scene's files),
``AssetFormat`` and ``formats() -> dict`` (format name -> ``AssetFormat``: the version this warpbw
reads, what the file is in words, the builder's current settings and what older files leave unrecorded, its reader).

A file's header (:mod:`precompute.assetfile`) names its format and version, its source and the source's content hash,
the parameters it was built with and the warpbw that wrote it.  Beside them ``asset_info`` says whether this warpbw
reads the file (its format's own reader is asked: a version, a shape or values it refuses make a "no" with the
reader's words), whether the recorded builder settings are the ones the builder would use now
(``assetfile.settings_mismatch`` with each format's public settings function, as the renderer's cache compares them:
a cache entry of other settings is rebuilt, a file a scene names is read as it is), and each array's shape, dtype,
range of finite values and count of non-finite ones (a damaged table shows itself).  For a probe's nu_a map (an entry
of the renderer's cache, read by ``warpbw.bandwidth.env_bandwidth_map``, which has no reader of its own) "reads" means
its format and version; its values show in its array's line.  A file that is not an asset file, or a damaged one, is
refused in one line (``WarpbwError``).
"""
from __future__ import annotations

import json
import re
from dataclasses import dataclass
from typing import Callable

import numpy as np

from precompute.assetfile import read_any_asset, read_asset, settings_mismatch
from warpbw.errors import WarpbwError, check_path

__all__ = ["AssetFormat", "formats", "asset_info", "info_lines", "header_status"]

HASH_SHOWN = 12        # hex digits of a content hash the text shows (the JSON holds it whole)
PARAM_LIST_SHOWN = 6   # items of a recorded list the text shows (the JSON holds it whole)
SETTINGS_DIFFER = "a cache entry like this is rebuilt; a file a scene names is read as it is"
SETTINGS_DIFFER_CACHE = "a cache entry like this is rebuilt"


@dataclass(frozen=True)
class AssetFormat:
    version: int                      # the version this warpbw reads
    what: str                         # what the file is, in words
    settings: Callable[[dict], dict]  # the file's params -> the builder's current settings for such a file
    unrecorded: dict                  # what a setting an older file does not record was
    read: Callable                    # path -> dict of what the reader tells beyond the header; WarpbwError if refused
    cache_only: bool = False          # only the renderer's cache holds such files (no scene names one)


def _read_sampling(path) -> dict:
    from precompute.brdf_sampling import read_sampling

    read_sampling(path)
    return {}


def _read_bandwidth(path) -> dict:
    from precompute.brdf_bandwidth import read_brdf_bandwidth

    read_brdf_bandwidth(path)
    return {}


def _read_gmm(path) -> dict:
    from precompute.gmm_mipmap import read_gmm_mipmap

    mip = read_gmm_mipmap(path)
    return {"levels": len(mip.levels), "components": int(mip.components)}


def _read_env_bandwidth(path) -> dict:
    from warpbw.bandwidth import ENV_BW_FORMAT, ENV_BW_VERSION

    read_asset(path, ENV_BW_FORMAT, ENV_BW_VERSION, "delete the cache file")
    return {}


def _env_settings(params: dict) -> dict:
    """The settings ``env_bandwidth_map`` builds a map of the file's signal with (its cache is keyed by the signal):
    an unknown signal is compared with the default's settings, and differs."""
    from warpbw.bandwidth import ENV_BW_UNRECORDED, ENV_SIGNAL_DEFAULT, ENV_SIGNALS, env_bandwidth_settings

    signal = params.get("signal", ENV_BW_UNRECORDED["signal"])
    return env_bandwidth_settings(signal if signal in ENV_SIGNALS else ENV_SIGNAL_DEFAULT)


def formats() -> dict:
    """Format name -> ``AssetFormat``, from each format's own module (its constants and settings functions)."""
    from precompute.brdf_bandwidth import BANDWIDTH_UNRECORDED, FORMAT, VERSION, bandwidth_settings
    from precompute.brdf_sampling import SAMPLING_UNRECORDED, sampling_settings
    from precompute.gmm_mipmap import GMM_FORMAT, GMM_UNRECORDED, GMM_VERSION, fit_settings
    from warpbw.bandwidth import ENV_BW_FORMAT, ENV_BW_UNRECORDED, ENV_BW_VERSION
    from warpbw.sampling import TABLE_FORMAT, TABLE_VERSION

    return {
        TABLE_FORMAT: AssetFormat(TABLE_VERSION, "importance-sampling tables of a tabulated BRDF (002 Sec. 3.3)",
                                  lambda params: sampling_settings(), SAMPLING_UNRECORDED, _read_sampling),
        FORMAT: AssetFormat(VERSION, "angular bandwidth table nu_rho of a tabulated BRDF (002 Sec. 2.3)",
                            lambda params: bandwidth_settings(), BANDWIDTH_UNRECORDED, _read_bandwidth),
        GMM_FORMAT: AssetFormat(GMM_VERSION, "GMM normal mipmap (004 Sec. 4.1)",
                                lambda params: fit_settings(), GMM_UNRECORDED, _read_gmm),
        ENV_BW_FORMAT: AssetFormat(ENV_BW_VERSION, "a probe's angular bandwidth map nu_a (002 Sec. 2.3, Eq. 7), an "
                                   "entry of the renderer's cache", _env_settings, ENV_BW_UNRECORDED,
                                   _read_env_bandwidth, cache_only=True),
    }


def _number(x):
    """A numpy scalar as the Python number JSON writes (a non-finite one stays a float: json_text makes it null)."""
    return x.item() if isinstance(x, np.generic) else x


def _array_info(name: str, a: np.ndarray) -> dict:
    """Name, shape, dtype; for numbers the least and greatest finite values (None when there are none) and how many
    are NaN or infinite."""
    rec = {"name": name, "shape": [int(s) for s in a.shape], "dtype": a.dtype.name, "min": None, "max": None,
           "non_finite": None}
    if a.dtype.kind in "biuf":
        finite = np.isfinite(a) if a.dtype.kind == "f" else np.ones(a.shape, bool)
        rec["non_finite"] = int(a.size - np.count_nonzero(finite))
        if finite.any():
            values = a[finite]
            rec["min"], rec["max"] = _number(values.min()), _number(values.max())
    return rec


def asset_info(path) -> dict:
    """What the asset file ``path`` holds (module docstring), as a dict of JSON values: ``path``, ``format``,
    ``version``, ``what`` (None for a format this warpbw does not know), ``reads`` and ``not_read`` (why not, or None),
    ``source``, ``source_hash``, ``writer``, ``params``, ``settings`` ("current", "differ" or None where not checked:
    another format or version), ``settings_differ`` (``settings_mismatch``'s text) and ``settings_note`` (what a
    difference means), ``arrays`` (``name``, ``shape``, ``dtype``, ``min``, ``max``, ``non_finite``); a GMM mipmap
    this warpbw reads adds ``levels`` and ``components``.  A file that is no asset file, or a damaged one: a one-line
    ``WarpbwError``."""
    path = check_path(path, "asset_info: path")   # a Path, as the readers name it in their errors
    asset = read_any_asset(path)
    h = asset.header
    fmt_name = h.get("format")
    if not isinstance(fmt_name, str):
        raise WarpbwError(f"{path}: not a warpbw asset file, or a damaged one (its header names no format; expected "
                          "one of " + ", ".join(formats()) + ")")
    fmt = formats().get(fmt_name)
    params = h.get("params")
    rec = {"path": str(path), "format": fmt_name, "version": h.get("version"),
           "what": None if fmt is None else fmt.what, "reads": False, "not_read": None,
           "source": h.get("source"), "source_hash": h.get("source_hash"), "writer": h.get("writer"),
           "params": params, "settings": None, "settings_differ": None, "settings_note": None}
    extra = {}
    rec.update(_header_checks(h, fmt))
    if rec["not_read"] is None:
        try:
            extra = fmt.read(path)
            rec["reads"] = True
        except WarpbwError as exc:
            msg = str(exc)
            rec["not_read"] = msg[len(f"{path}: "):] if msg.startswith(f"{path}: ") else msg
    rec.update(extra)
    rec["arrays"] = [_array_info(k, np.asarray(v)) for k, v in asset.arrays.items()]
    return rec


def _header_checks(h: dict, fmt: AssetFormat | None) -> dict:
    """What the header ``h`` of a file of format ``fmt`` (None: one warpbw does not know) tells without its arrays:
    ``not_read`` (another format or version; None when this warpbw reads both) and the builder settings' check
    (``settings``, ``settings_differ``, ``settings_note``: ``asset_info``'s)."""
    params = h.get("params")
    out = {"not_read": None, "settings": None, "settings_differ": None, "settings_note": None}
    if fmt is None:
        out["not_read"] = f"{h.get('format')!r} is not a format warpbw reads"
        return out
    if h.get("version") != fmt.version:
        out["not_read"] = f"version {h.get('version')!r}, this warpbw reads {fmt.version}"
        return out
    if "params" in h and not isinstance(params, dict):   # read_asset refuses it (warpbw info said "read as it is")
        out["not_read"] = "its header's params are no JSON object (a damaged or hand-edited header)"
        return out
    differ = settings_mismatch(params, fmt.settings(params if isinstance(params, dict) else {}), fmt.unrecorded)
    out["settings"] = "current" if differ is None else "differ"
    if differ is not None:
        out["settings_differ"] = differ
        out["settings_note"] = SETTINGS_DIFFER_CACHE if fmt.cache_only else SETTINGS_DIFFER
    return out


def header_status(path) -> dict:
    """What the header of the asset file ``path`` says, its arrays not read and its reader not asked (``warpbw info``
    of a scene lists it beside the file): ``path``, ``format``, ``version``, ``what``, ``not_read`` (another format
    or version, else None), ``settings``, ``settings_differ``; or ``path`` and ``error`` for a file that is missing
    or no asset file (a damaged one: its reader says more)."""
    from precompute.assetfile import read_header

    p = check_path(path, "header_status: path")
    h = read_header(p) if p.is_file() else None
    if not isinstance(h, dict) or not isinstance(h.get("format"), str):
        why = "not a warpbw asset file, or a damaged one" if p.is_file() else "no such file"
        return {"path": str(p), "error": why}
    fmt = formats().get(h["format"])
    checks = _header_checks(h, fmt)
    return {"path": str(p), "format": h["format"], "version": h.get("version"),
            "what": None if fmt is None else fmt.what, "not_read": checks["not_read"],
            "settings": checks["settings"], "settings_differ": checks["settings_differ"]}


def _short_hash(h) -> str:
    """Each run of hex digits longer than HASH_SHOWN cut to its first HASH_SHOWN, "..." after them."""
    return re.sub(rf"([0-9a-f]{{{HASH_SHOWN}}})[0-9a-f]+", r"\1...", str(h))


def _value(v) -> str:
    """A recorded parameter as JSON writes it, a long list cut to its first PARAM_LIST_SHOWN items."""
    if isinstance(v, list) and len(v) > PARAM_LIST_SHOWN:
        shown = ", ".join(json.dumps(x) for x in v[:PARAM_LIST_SHOWN])
        return f"[{shown}, ... ({len(v)} items)]"
    return v if isinstance(v, str) else json.dumps(v)


def _shown(v) -> str:
    """A header's text field; another value (a damaged or hand-written header's) as JSON, none as "not recorded"."""
    return "not recorded" if v is None else v if isinstance(v, str) else json.dumps(v)


def _g(x) -> str:
    return "-" if x is None else f"{x:.6g}" if isinstance(x, float) else str(x)


def info_lines(record: dict) -> list:
    """The lines ``warpbw-precompute info`` prints for ``asset_info``'s record (as the header holds them: the command
    prints each through ``printable``, so a value's newline cannot start a line of its own)."""
    rec = record
    lines = [rec["path"]]
    what = f": {rec['what']}" if rec["what"] else ""
    lines.append(f"  format    {rec['format']} version {rec['version']}{what}")
    lines.append("  read      " + ("yes" if rec["reads"] else f"no: {rec['not_read']}"))
    lines.append(f"  source    {_shown(rec['source'])} ({_short_hash(_shown(rec['source_hash']))})")
    lines.append(f"  writer    {_shown(rec['writer'])}")
    params = rec["params"]
    if isinstance(params, dict) and params:
        width = max(len(str(k)) for k in params)
        for i, (k, v) in enumerate(params.items()):
            lines.append(f"  {'params' if i == 0 else '':<10}{str(k):<{width}}  {_value(v)}")
    else:
        lines.append(f"  params    {'none' if not params else _value(params)}")
    if rec["settings"] is None:
        lines.append("  settings  not checked (a format, version or header this warpbw does not read)")
    elif rec["settings"] == "current":
        lines.append("  settings  current (what the builder would use now)")
    else:
        lines.append(f"  settings  differ: {rec['settings_differ']} ({rec['settings_note']})")
    if "levels" in rec:
        lines.append(f"  mipmap    {rec['levels']} levels of {rec['components']} components per texel")
    arrays = rec["arrays"]
    width = max((len(a["name"]) for a in arrays), default=0)
    for i, a in enumerate(arrays):
        shape = "x".join(str(s) for s in a["shape"]) or "scalar"
        values = ""
        if a["non_finite"] is not None:
            values = f"  {_g(a['min'])} .. {_g(a['max'])}" if a["min"] is not None else "  no finite values"
            if a["non_finite"]:
                values += f", {a['non_finite']} NaN or infinite"
        lines.append(f"  {'arrays' if i == 0 else '':<10}{a['name']:<{width}}  {shape} {a['dtype']}{values}")
    if not arrays:
        lines.append("  arrays    none")
    return lines
