"""User-facing errors.

Public: ``WarpbwError``; ``is_int(value)`` (an int or numpy integer, not a bool) and
``check_count(value, name, lo) -> int`` (such an integer >= lo, else a ``WarpbwError`` naming ``name``).

Anything the user can cause (a bad file, a bad key in a scene, a bad CLI value) is raised as
``WarpbwError`` with a one-line message that names the file or key and says what was expected.
The CLIs print it as ``warpbw: error: <message>`` and exit with status 2, never a traceback.
"""
from __future__ import annotations

import numbers


class WarpbwError(Exception):
    """A problem with the user's input, reported in one line without a traceback."""


def is_int(value) -> bool:
    """An integer (Python or numpy), not a bool."""
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def check_count(value, name: str, lo: int) -> int:
    """``value`` as an int when it is an integer >= lo; otherwise a one-line error naming ``name``."""
    if not is_int(value) or value < lo:
        raise WarpbwError(f"{name}: expected an integer >= {lo}, got {value!r}")
    return int(value)
