"""Tabulate an NPF fit (``npf.bin``) as a MERL ``.binary`` file.

Public function:

- ``npf_to_merl(table, material, out, force=False) -> Path``: read one material with
  :func:`warpbw.io.npf.read_npf`, evaluate :func:`warpbw.io.npf.npf_eval` (interpolated) at every MERL
  bin centre with :func:`warpbw.io.merl.tabulate_merl`, and write it with :func:`warpbw.io.merl.write_merl`.
  ``out`` is never ``table`` itself (nor a link to it) and never a read-only file, whatever ``force`` says.
- ``tabulation_stamp(table, material) -> str``, ``tabulation_is_current(merl, table, material) -> bool``,
  ``write_tabulation_stamp(merl, table, material) -> Path``: for scripts that keep such files as a cache
  (``examples/bench_scenes.py``, ``examples/bench_reference.py``).  A MERL file cannot say what wrote it, so its
  stamp ``MERL.tabulation`` beside it does: :data:`warpbw.io.merl.TABULATION_VERSION`, the material and the digest
  of the table's bytes, every input of the tabulation.  A file whose stamp is missing or says otherwise is stale.

The CLI ``warpbw-precompute npf-to-merl --table T --material NAME -o OUT [--force]`` calls it.
"""
from __future__ import annotations

from pathlib import Path

from warpbw.errors import WarpbwError, check_path
from warpbw.io.merl import TABULATION_VERSION, tabulate_merl, write_merl
from warpbw.io.npf import npf_eval, read_npf
from warpbw.io.staged import check_replaceable, check_still_free


def npf_to_merl(table, material: str, out, force: bool = False) -> Path:
    """Write NPF material ``material`` of ``table`` to the MERL file ``out`` (a name ending in .binary, as the
    command line asks: with force, an .exr given by mistake was replaced); returns ``out`` as a Path."""
    table = check_path(table, "npf_to_merl: table")   # None or a number: pathlib's TypeError
    out = check_replaceable(out, force, inputs=[table])   # before the tabulation, which takes seconds
    if out.suffix.lower() != ".binary":
        raise WarpbwError(f"{out}: expected a MERL file name ending in .binary")
    mat = read_npf(table, material)
    data = tabulate_merl(lambda wi, wo: npf_eval(mat, wi, wo, interpolate=True), name=f"{table}:{mat.name}")
    check_still_free(out, force)   # another run's, finished first: said so, not "pass --force"
    return write_merl(out, data, force=force, inputs=[table])


TABULATION_STAMP_SUFFIX = ".tabulation"   # MATERIAL.binary.tabulation: the stamp beside the MERL file it describes


def tabulation_stamp(table, material: str) -> str:
    """What the stamp of a MERL file ``npf_to_merl(table, material, ...)`` writes now says: the tabulation's version,
    the material and the digest of the table's bytes (a stamp of the version alone kept a file converted from another
    table)."""
    from warpbw.scene import file_digest

    return f"{TABULATION_VERSION} {material} {file_digest(check_path(table, 'tabulation_stamp: table'))}"


def _stamp_path(merl) -> Path:
    merl = check_path(merl, "merl")   # None or a number: pathlib's TypeError (write_tabulation_stamp)
    return merl.with_name(merl.name + TABULATION_STAMP_SUFFIX)


def tabulation_is_current(merl, table, material: str) -> bool:
    """True when the MERL file ``merl`` exists and its stamp says ``npf_to_merl(table, material)`` would write it now
    (``tabulation_stamp``); False for a stamp that is missing, unreadable or of another tabulation, table or
    material: such a file is converted again."""
    merl, table = check_path(merl, "tabulation_is_current: merl"), check_path(table, "tabulation_is_current: table")
    try:
        return merl.is_file() and _stamp_path(merl).read_text(errors="replace").strip() == \
            tabulation_stamp(table, material)
    except OSError:
        return False


def write_tabulation_stamp(merl, table, material: str) -> Path:
    """Write the stamp of ``merl``, just converted from ``material`` of ``table``; returns its path."""
    stamp = _stamp_path(merl)
    stamp.write_text(tabulation_stamp(table, material) + "\n")
    return stamp
