"""Tabulate an NPF fit (``npf.bin``) as a MERL ``.binary`` file.

Public function:

- ``npf_to_merl(table, material, out, force=False) -> Path``: read one material with
  :func:`warpbw.io.npf.read_npf`, evaluate :func:`warpbw.io.npf.npf_eval` (interpolated) at every MERL
  bin centre with :func:`warpbw.io.merl.tabulate_merl`, and write it with :func:`warpbw.io.merl.write_merl`.
  ``out`` is never ``table`` itself (nor a link to it) and never a read-only file, whatever ``force`` says.

The CLI ``warpbw-precompute npf-to-merl --table T --material NAME -o OUT [--force]`` calls it.
"""
from __future__ import annotations

from pathlib import Path

from warpbw.errors import WarpbwError
from warpbw.io.merl import tabulate_merl, write_merl
from warpbw.io.npf import npf_eval, read_npf
from warpbw.io.staged import check_replaceable


def npf_to_merl(table, material: str, out, force: bool = False) -> Path:
    """Write NPF material ``material`` of ``table`` to the MERL file ``out`` (a name ending in .binary, as the
    command line asks: with force, an .exr given by mistake was replaced); returns ``out`` as a Path."""
    out = check_replaceable(out, force, inputs=[table])   # before the tabulation, which takes seconds
    if out.suffix.lower() != ".binary":
        raise WarpbwError(f"{out}: expected a MERL file name ending in .binary")
    mat = read_npf(table, material)
    data = tabulate_merl(lambda wi, wo: npf_eval(mat, wi, wo, interpolate=True), name=f"{table}:{mat.name}")
    return write_merl(out, data, force=force, inputs=[table])
