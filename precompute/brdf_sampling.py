"""Importance-sampling tables for tabulated BRDFs (002 Sec. 3.3): build, write, read, cache.

Public:
    ``brdf_source(file, material=None, lookup=None) -> BrdfSource``  a MERL ``.binary`` or an NPF table + material
        name, read with ``lookup`` (warns when ``albedo_excess`` finds it reflects more than ``ALBEDO_WARN`` times
        the light it receives)
    ``TABLE_LOOKUP`` (``{"merl": "nearest", "npf": "linear"}``), ``default_lookup(source) -> str``,
        ``source_lookup(source) -> str | None``, ``with_lookup(source, lookup) -> BrdfSource``,
        ``digest_at(source, lookup) -> str``   the lookup a source's ``evaluate`` reads its tables with (below);
        ``check_lookup(lookup) -> str | None``, one of ``warpbw.scene.LOOKUP_MODES`` or None, else a one-line error
    ``albedo_excess(evaluate) -> str | None``  what says a BRDF is far from conserving energy
    ``build_brdf_sampling(source, progress=True) -> SamplerTable``
    ``write_sampling(path, table, source, force=False)`` / ``read_sampling(path, source=None)``   (never over the
        source's own file, nor a read-only file, whatever ``force`` says); ``sampling_problem(table)``, what both
        refuse
    ``brdf_source_unread(file, material=None, lookup=None) -> BrdfSource``   the name, digest and lookup
        ``brdf_source`` gives, the BRDF not read: what a table's reader checks a file against (``warpbw info``)
    ``check_brdf_source(source, caller, needs) -> source``   a path passed where a source is expected, refused
    ``source_files(source) -> list``   the file a source was read from (what a table written from it may not replace)
    ``rebuild_command(subcommand, source) -> str``   the ``warpbw-precompute`` line that rebuilds a table of a source
    ``load_or_build_sampling(source, explicit=None, cache=None, progress=True) -> (SamplerTable, origin)``
    ``load_or_build(source, explicit, cache, prefix, version, read, build, write, progress, settings, unrecorded)``
        the shared cache logic (a cache entry of other recorded builder settings is rebuilt, below)
    ``sampling_settings() -> dict``, ``SAMPLING_UNRECORDED``   the builder settings a sampling table records
    ``cache_dir()``
    ``BrdfSource``: what ``brdf_source`` returns (name, path, digest, a numpy evaluator, the loaded BRDF)

The tables are those of :mod:`warpbw.sampling` (per view elevation, over sqrt-warped half vectors),
stored in the versioned asset format of :mod:`precompute.assetfile`.  The renderer builds them itself,
once, when the scene does not name a precomputed file, and caches them under ``cache_dir()``
(``$WARPBW_CACHE`` or ``~/.cache/warpbw``) keyed by the source file's content hash.

Lookup.  A material shades its tables with ``lookup = "nearest"`` (the bin a direction pair falls in) or ``"linear"``
(between bin centres; ``warpbw.scene.LOOKUP_MODES``), and a source's ``evaluate`` reads them with its ``lookup``.
``lookup=None`` is the kind's ``TABLE_LOOKUP`` (MERL nearest, NPF linear): the scene's default for that kind
(``warpbw.scene.LOOKUP_DEFAULT``) and the one every table was built with before session 70.  Such a source's name and
digest are the file's (and the material's), so existing cache entries and files stay valid.  Another lookup adds
``" (LOOKUP lookup)"`` to the name and ``":lookup-LOOKUP"`` to the digest, so a table built from it is cached under its
own key and is refused for the other lookup.  The angular bandwidth table
(:mod:`precompute.brdf_bandwidth`) follows the lookup: the nearest-bin steps of an NPF fit read up to 1.9x faster than
its interpolated curves.  The sampling tables do not: their density is tabulated from the BRDF and sampled exactly
whatever BRDF it came from (the estimator divides by the table's own pdf), so they are lookup-free, built from the
source read at its kind's default lookup whatever source they are given: one table, and one cache key, per BRDF.
The two tables' cache entries cannot be confused either: their prefixes (``sampling-``, ``bandwidth-``) and formats
differ.

Builder settings.  A table records the settings it was built with (``sampling_settings()``: the cells, the view
elevations averaged per bin, the midpoint samples per cell side).  A cache entry is read only when they equal the
builder's current ones (``precompute.assetfile.settings_mismatch``), else it is rebuilt and replaced as a damaged or
older entry is, without a word: ``warpbw.sampling.VIEW_SUBSAMPLES`` changed without a version bump no longer serves
the old tables.  A file written before session 71 records no ``subcells``; it was built with 3
(``SAMPLING_UNRECORDED``).  A file the scene names (``sampling =``) is read whatever settings it records.
"""
from __future__ import annotations

import os
import shlex
import warnings
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np

from precompute.assetfile import read_asset, read_header, settings_mismatch, write_asset
from precompute.progress import progress_callback
from warpbw.errors import WarpbwError, check_input_file, check_instance, check_path
from warpbw.io.staged import check_name_length, remove_stale_temps
from warpbw.sampling import (N_PHI, N_THETA_O, N_U, TABLE_FORMAT, TABLE_VERSION, SamplerTable,
                             build_sampler_table, directional_albedo)
from warpbw.scene import LOOKUP_DEFAULT, LOOKUP_MODES


@dataclass
class BrdfSource:
    name: str                   # "file.binary" or "npf.bin:material"
    path: Path
    digest: str                 # content hash of the source bytes (+ material name)
    evaluate: Callable          # numpy (wi, wo) -> (N, 3)
    brdf: object = None         # the loaded MerlBRDF or NPFMaterial (so callers need not read it again)
    material: str | None = None  # the NPF material's name as the table spells it; None for a MERL file
    lookup: str | None = None   # what ``evaluate`` reads the tables with; None: the kind's TABLE_LOOKUP


# The lookup a tabulated BRDF's tables are built with when none is named: the scene's default for its kind
# (warpbw.scene.LOOKUP_DEFAULT: MERL its own nearest bin, NPF its curves interpolated), and what every table was built
# with before session 70, so that such tables stay valid.
TABLE_LOOKUP = dict(LOOKUP_DEFAULT)


# Views (degrees from the normal) at which a tabulated BRDF's directional albedo is checked, and the albedo above
# which it is called non-physical.  A BRDF that conserves energy reflects at most 1; the NPF fits of the 100 MERL
# materials reach 1.23 at these views (light-red-paint's red channel; orange-paint 1.20, pink-plastic 1.07, every
# other one below 1.05), measurement error included.  Grazing views are left out: there the fits reach 1.24 at 85
# degrees, 1.25 at 89 and 2.34 at 89.9 (polyethylene; 23 of the 100 pass 1 there: the fits' 1 / cos_o), and measured
# tables are least sure (docs/testing.md, session 79: a quadrature of the fits decoded from the data README alone).
ALBEDO_CHECK_VIEWS_DEG = (0.0, 30.0, 60.0)
ALBEDO_WARN = 1.5


def brdf_source(file, material: str | None = None, lookup: str | None = None) -> BrdfSource:
    """Open a tabulated BRDF: a MERL ``.binary`` file, or an NPF table with ``material``, read with ``lookup``
    (``"nearest"`` or ``"linear"``; None: the kind's ``TABLE_LOOKUP``, module docstring).  A table that reflects more
    than ``ALBEDO_WARN`` times the light it receives (``albedo_excess``) is read with a warning."""
    from warpbw.io.merl import read_merl
    from warpbw.io.npf import read_npf
    from warpbw.scene import file_digest

    check_lookup(lookup)   # before the file is read (a MERL file is 35 MB)
    p = check_input_file(file)
    if material is None:
        source = BrdfSource(p.name, p, file_digest(p), None, read_merl(p))
    else:
        mat = read_npf(p, material)
        source = BrdfSource(f"{p.name}:{mat.name}", p, f"{file_digest(p)}:{mat.name}", None, mat, mat.name)
    source = _at_lookup(source, lookup)
    excess = albedo_excess(source.evaluate)
    if excess is not None:
        warnings.warn(f"{source.name}: {excess}; it renders as it is", stacklevel=2)
    return source


def brdf_source_unread(file, material: str | None = None, lookup: str | None = None) -> BrdfSource:
    """The name, path, digest, material and lookup that ``brdf_source(file, material, lookup)`` gives, from the file's
    bytes and the material's stored name (``warpbw.io.npf.canonical_name``), the BRDF itself not read (``evaluate``
    and ``brdf`` None): all ``read_sampling`` and ``precompute.brdf_bandwidth.read_brdf_bandwidth`` check a file
    against (``warpbw info`` asks them so, without reading a 35 MB MERL file)."""
    from warpbw.io.npf import canonical_name
    from warpbw.scene import file_digest

    check_lookup(lookup)
    p = check_input_file(file)
    mat = None if material is None else canonical_name(material)
    tag = "" if mat is None else f":{mat}"
    source = BrdfSource(p.name + tag, p, file_digest(p) + tag, None, None, mat)
    lookup = default_lookup(source) if lookup is None else lookup
    name, digest = _lookup_tags(source, lookup)
    return replace(source, name=source.name + name, digest=source.digest + digest, lookup=lookup)


def check_lookup(lookup) -> str | None:
    """``lookup`` when it is one of ``LOOKUP_MODES`` or None (its kind's default); else a one-line ``WarpbwError``."""
    if lookup is not None and lookup not in LOOKUP_MODES:
        raise WarpbwError(f"lookup: expected one of {', '.join(LOOKUP_MODES)} (or None: the kind's table default), "
                          f"got {lookup!r}")
    return lookup


def default_lookup(source) -> str:
    """The lookup ``source``'s tables are built with when none is named: ``TABLE_LOOKUP`` of its kind (an NPF
    material when it names one, else a MERL file)."""
    return TABLE_LOOKUP["merl" if getattr(source, "material", None) is None else "npf"]


def source_lookup(source) -> str | None:
    """The lookup ``source``'s ``evaluate`` reads its tables with: its ``lookup``, else its kind's default; None for
    a source that has no ``lookup`` attribute at all (an analytic material, which has no tables to read)."""
    if not hasattr(source, "lookup"):
        return None
    return source.lookup if source.lookup is not None else default_lookup(source)


def _lookup_tags(source, lookup: str) -> tuple[str, str]:
    """What ``lookup`` adds to ``source``'s name and digest: nothing at its kind's default (module docstring)."""
    if lookup == default_lookup(source):
        return "", ""
    return f" ({lookup} lookup)", f":lookup-{lookup}"


def _at_lookup(source: BrdfSource, lookup: str | None) -> BrdfSource:
    """``source`` (read at its kind's default: untagged name and digest) with the evaluator, name and digest of
    ``lookup``."""
    from warpbw.io.merl import merl_eval
    from warpbw.io.npf import npf_eval

    lookup = default_lookup(source) if lookup is None else lookup
    brdf, linear = source.brdf, lookup == "linear"
    if source.material is None:
        def evaluate(wi, wo):
            return merl_eval(brdf, wi, wo, interpolate=linear)
    else:
        def evaluate(wi, wo):
            return npf_eval(brdf, wi, wo, interpolate=linear)
    name, digest = _lookup_tags(source, lookup)
    return replace(source, name=source.name + name, digest=source.digest + digest, evaluate=evaluate, lookup=lookup)


def _untagged(source) -> tuple[str, str]:
    """``source``'s name and digest without what its lookup added to them (those at its kind's default)."""
    name, digest = _lookup_tags(source, source_lookup(source))
    return source.name[:len(source.name) - len(name)], source.digest[:len(source.digest) - len(digest)]


def digest_at(source, lookup: str) -> str:
    """The digest ``source`` has when read with ``lookup`` (its own digest, retagged; module docstring)."""
    return _untagged(source)[1] + _lookup_tags(source, lookup)[1]


def with_lookup(source: BrdfSource, lookup: str | None) -> BrdfSource:
    """The BRDF of ``source`` read with ``lookup`` (None: its kind's default), from the BRDF it already holds: neither
    its file nor its albedo is read again.  ``source`` itself when it already reads with that lookup."""
    check_brdf_source(source, "with_lookup", needs=("name", "digest", "brdf", "material", "lookup"))
    want = default_lookup(source) if check_lookup(lookup) is None else lookup
    have = source_lookup(source)
    if want == have:
        return source
    if source.brdf is None:
        raise WarpbwError(f"with_lookup: source {source.name!r} holds no BRDF to read with the {want} lookup; expected "
                          "what brdf_source(path, material) returns")
    name, digest = _untagged(source)   # back to the source at its kind's default, then on to ``want``
    return _at_lookup(replace(source, name=name, digest=digest, lookup=None), want)


def albedo_excess(evaluate) -> str | None:
    """What says the BRDF ``evaluate(wi, wo) -> (N, 3)`` reflects more light than it receives: its directional albedo
    (``warpbw.sampling.directional_albedo``) above ``ALBEDO_WARN`` at one of ``ALBEDO_CHECK_VIEWS_DEG``; else None
    (a few milliseconds)."""
    views = np.radians(ALBEDO_CHECK_VIEWS_DEG)
    with np.errstate(over="ignore", invalid="ignore"):   # 1e300s: an infinite albedo, named below
        a = directional_albedo(evaluate, views)
    worst = np.unravel_index(int(np.argmax(np.where(np.isnan(a), -np.inf, a))), a.shape)
    top = float(a[worst])
    if not top > ALBEDO_WARN:
        return None
    return (f"reflects {top:.3g} times the light it receives (directional albedo {top:.3g} in the "
            f"{'RGB'[worst[1]]} channel at {ALBEDO_CHECK_VIEWS_DEG[worst[0]]:g} degrees from the normal; one that "
            f"conserves energy reflects at most 1, the 100 MERL materials at most 1.23): a table scaled wrongly, or "
            "not what its name says?")


def check_brdf_source(source, caller: str, needs=("name", "evaluate")):
    """``source`` when it has the attributes ``needs`` of a :class:`BrdfSource`; a path, or anything else, refused in
    one line naming ``caller`` and saying what to pass (a path gave ``'str' object has no attribute 'name'``)."""
    if isinstance(source, (str, os.PathLike)):
        raise WarpbwError(f"{caller}: source {str(source)!r} is a path; pass brdf_source(path, material) "
                          "(precompute.brdf_sampling), which reads it")
    missing = [a for a in needs if not hasattr(source, a)]
    if missing:
        raise WarpbwError(f"{caller}: source {source!r} has no {' or '.join(missing)}; expected what "
                          "brdf_source(path, material) returns")
    return source


def source_files(source) -> list:
    """The file ``source`` was read from (``[]`` for one with no ``path``, an analytic material)."""
    path = getattr(source, "path", None)
    return [] if path is None else [path]


def _lookup_free(source):
    """The source a sampling table is built from and checked against: ``source`` at its kind's default lookup
    (module docstring: the sampling tables do not follow the lookup)."""
    if isinstance(source, BrdfSource) and source.lookup not in (None, default_lookup(source)):
        return with_lookup(source, None)
    return source


def build_brdf_sampling(source: BrdfSource, progress: bool = True) -> SamplerTable:
    """Tabulate and invert the source's CDF (a few seconds per material), at its kind's default lookup whatever
    ``source`` reads with (module docstring)."""
    source = _lookup_free(check_brdf_source(source, "build_brdf_sampling"))
    k = sampling_settings()   # what the table records, so that its params say what built it
    with progress_callback(k["n_theta_o"], f"sampling tables {source.name}", "view", progress) as step:
        return build_sampler_table(source.evaluate, n_theta_o=k["n_theta_o"], n_u=k["n_u"], n_phi=k["n_phi"],
                                   sub=k["subcells"], progress=step, sub_views=k["view_subsamples"])


def rebuild_command(subcommand: str, source) -> str:
    """The ``warpbw-precompute SUBCOMMAND`` line that rebuilds a table of ``source``, with ``--material`` for an NPF
    table's material and (``brdf``'s bandwidth table) ``--lookup`` for a lookup other than its kind's default, its
    words quoted for a POSIX shell (a MERL file named ``lab:chrome.binary`` was taken for an NPF material, and a path
    with a space split); placeholders where the source or its file is unknown."""
    path = getattr(source, "path", None)
    if path is None:
        return f"warpbw-precompute {subcommand} SOURCE [--material NAME] -o OUT --force"
    material = getattr(source, "material", None)
    mat = "" if material is None else f" --material {shlex.quote(material)}"
    lookup = source_lookup(source)
    if subcommand == "brdf" and lookup is not None and lookup != default_lookup(source):   # the tables that follow it
        mat += f" --lookup {lookup}"
    return f"warpbw-precompute {subcommand} {shlex.quote(str(path))}{mat} -o OUT --force"


# What a sampling table built before session 71 was built with where it records nothing (warpbw.sampling.SUBCELLS
# has been 3 since the first tables, and LUMINANCE, recorded since session 72, Rec. 709's weights)
SAMPLING_UNRECORDED = {"subcells": 3, "luminance": [0.2126, 0.7152, 0.0722]}


def sampling_settings() -> dict:
    """The settings ``build_brdf_sampling`` builds with, as a table's ``params`` records them: its cells
    (``n_theta_o``, ``n_u``, ``n_phi``), the view elevations averaged per bin and the midpoint samples per cell side
    (``warpbw.sampling``'s constants, read now), and the luminance weights of the importance function Y(f) cos_i."""
    from warpbw import sampling

    return {"n_theta_o": sampling.N_THETA_O, "n_u": sampling.N_U, "n_phi": sampling.N_PHI,
            "view_subsamples": sampling.VIEW_SUBSAMPLES, "subcells": sampling.SUBCELLS,
            "luminance": list(sampling.LUMINANCE)}


# How far a view's tabulated density (as cell shares) may lie from the shares its two CDFs give, in L1 over the
# cells (they sum to 1): the builder's float32 tables agree within 2.1e-6 (chrome).  A damaged table whose density
# was zeroed rendered 65,000x too bright, one whose marginal was zeroed 40x too dark, both silently.
TABLE_CONSISTENCY_TOL = 1e-3


def sampling_problem(table: SamplerTable) -> str | None:
    """What makes ``table`` no sampler ``build_sampler_table`` could have built, or None: CDFs that do not rise
    from 0 to 1, or a density that is not the one they sample (what the writer and the reader both refuse)."""
    check_instance(table, SamplerTable, "sampling_problem: table", "a SamplerTable (build_sampler_table's)")
    m, c, d = (np.asarray(x, np.float64) for x in (table.marginal, table.conditional, table.density))
    for name, cdf in (("marginal", m), ("conditional", c)):
        if np.any(cdf[..., 0] != 0.0) or np.any(np.abs(cdf[..., -1] - 1.0) > TABLE_CONSISTENCY_TOL) \
                or np.any(np.diff(cdf, axis=-1) < 0.0):
            return f"the {name} CDF does not rise from 0 to 1"
    cell = (1.0 / d.shape[1]) * (2.0 * np.pi / d.shape[2])     # du dphi (warpbw.sampling: density = share / cell)
    off = np.abs(d * cell - np.diff(m, axis=1)[..., None] * np.diff(c, axis=2)).sum(axis=(1, 2))
    if np.any(off > TABLE_CONSISTENCY_TOL):
        return (f"the density is not the one the CDFs sample (L1 {off.max():.3g} between their cell shares at "
                f"view bin {int(off.argmax())})")
    return None


def write_sampling(path, table: SamplerTable, source: BrdfSource, force: bool = False) -> Path:
    """Write the tables built from ``source``; never over the source's file (a link to it neither), whatever
    ``force`` says.  Tables ``read_sampling`` would refuse are refused here, before anything is written."""
    source = _lookup_free(check_brdf_source(source, "write_sampling", needs=("name", "digest")))
    if not isinstance(table, SamplerTable):
        raise WarpbwError(f"write_sampling: table is {type(table).__name__}, expected a SamplerTable")
    problem = sampling_problem(table)
    if problem is not None:
        raise WarpbwError(f"write_sampling: not a sampling table ({problem}); {path} is not written")
    if table.shape != (N_THETA_O, N_U, N_PHI):   # read_sampling refuses them: the file was written, then unreadable
        raise WarpbwError(f"write_sampling: tables of shape {table.shape}, the renderer reads "
                          f"{(N_THETA_O, N_U, N_PHI)} (build_sampler_table's defaults); {path} is not written")
    return write_asset(path, TABLE_FORMAT, TABLE_VERSION, source.name, source.digest,
                       {"marginal": table.marginal, "conditional": table.conditional, "density": table.density},
                       params=sampling_settings(), force=force, inputs=source_files(source))


def read_sampling(path, source: BrdfSource | None = None) -> SamplerTable:
    """Read a sampling-table file; with ``source``, refuse one built from different data."""
    if source is not None:
        source = _lookup_free(check_brdf_source(source, "read_sampling", needs=("name", "digest")))
    hint = rebuild_command("brdf-sampling", source)
    a = read_asset(path, TABLE_FORMAT, TABLE_VERSION, hint)
    if source is not None and a.header.get("source_hash") != source.digest:
        raise WarpbwError(f"{path}: built from {a.header.get('source')!r} with different content than "
                          f"{source.name!r} (rebuild it with: {hint})")
    try:
        t = SamplerTable(*(np.asarray(a.arrays[k], np.float32) for k in ("marginal", "conditional", "density")))
    except KeyError as exc:
        raise WarpbwError(f"{path}: sampling-table file lacks array {exc} (rebuild it with: {hint})") from None
    except (TypeError, ValueError):  # an array of strings or objects
        raise WarpbwError(f"{path}: sampling-table arrays are not numeric (rebuild it with: {hint})") from None
    if t.density.ndim != 3:
        raise WarpbwError(f"{path}: inconsistent table shapes (rebuild it with: {hint})")
    nt, nu, nphi = t.density.shape
    if t.marginal.shape != (nt, nu + 1) or t.conditional.shape != (nt, nu, nphi + 1):
        raise WarpbwError(f"{path}: inconsistent table shapes (rebuild it with: {hint})")
    if not all(np.all(np.isfinite(x)) and np.all(x >= 0.0) for x in (t.marginal, t.conditional, t.density)):
        # NaN CDFs sampled nothing: a near-black image, silently
        raise WarpbwError(f"{path}: tables hold negative or non-finite values (rebuild it with: {hint})")
    if (nt, nu, nphi) != (N_THETA_O, N_U, N_PHI):
        raise WarpbwError(f"{path}: tables of shape {(nt, nu, nphi)}, this warpbw uses "
                          f"{(N_THETA_O, N_U, N_PHI)} (rebuild it with: {hint})")
    problem = sampling_problem(t)
    if problem is not None:
        raise WarpbwError(f"{path}: not a sampling table warpbw wrote: {problem} (rebuild it with: {hint})")
    return t


def cache_dir() -> Path:
    """Where tables and ground truths are cached: ``$WARPBW_CACHE``, else ~/.cache/warpbw."""
    env = os.environ.get("WARPBW_CACHE")
    if env:
        check_name_length(Path(env), f"WARPBW_CACHE={env}")   # first: Python 3.11's exists raises on a name too long
    if env and Path(env).exists() and not Path(env).is_dir():
        raise WarpbwError(f"WARPBW_CACHE={env}: not a directory (expected the folder warpbw caches its tables in)")
    return Path(env) if env else Path.home() / ".cache" / "warpbw"


def load_or_build(source, explicit, cache, prefix: str, version: int, read, build, write,
                  progress: bool = True, settings: dict | None = None, unrecorded: dict | None = None) -> tuple:
    """A source's table: from ``explicit`` if given, else the cache (``PREFIX-DIGEST-vVERSION.npz``, the source's
    digest with ``:`` and ``/`` as ``-`` and ``_``), else built and cached.  Returns the table and where it came
    from ("file", "cache" or "built").  ``settings``: the builder's current settings (key -> value) a cache entry's
    ``params`` must record (``precompute.assetfile.settings_mismatch``, with ``unrecorded`` for keys older entries
    lack); an entry that records others is stale, rebuilt and replaced as a damaged one is.  ``explicit`` is read
    whatever settings it records."""
    if explicit is not None:
        return read(explicit, source), "file"
    d = check_path(cache, "cache") if cache is not None else cache_dir()   # None or a number: pathlib's TypeError
    key = source.digest.replace(":", "-").replace("/", "_")
    path = d / f"{prefix}-{key}-v{version}.npz"
    remove_stale_temps(path)   # a killed writer's, where another run wrote the entry whole: none writes it again
    if path.is_file():
        try:
            if settings is None or settings_mismatch((read_header(path) or {}).get("params"), settings,
                                                     unrecorded) is None:
                return read(path, source), "cache"
        except WarpbwError:
            pass  # a stale or damaged cache entry is rebuilt below (so is one of other builder settings, above)
    table = build(source, progress=progress)
    try:
        d.mkdir(parents=True, exist_ok=True)
        write(path, table, source, force=True)
    except (OSError, WarpbwError):
        pass  # a read-only or full cache, an entry's name taken by a folder: it only costs the rebuild next time
    return table, "built"


def load_or_build_sampling(source: BrdfSource, explicit=None, cache: Path | None = None,
                           progress: bool = True) -> tuple[SamplerTable, str]:
    """The source's sampling tables: from ``explicit`` if given, else the cache, else built and cached; those of its
    kind's default lookup whatever ``source`` reads with (module docstring), under one cache key.

    Returns the tables and where they came from ("file", "cache" or "built").
    """
    source = _lookup_free(check_brdf_source(source, "load_or_build_sampling", needs=("name", "digest")))
    return load_or_build(source, explicit, cache, "sampling", TABLE_VERSION, read_sampling, build_brdf_sampling,
                         write_sampling, progress, sampling_settings(), SAMPLING_UNRECORDED)
