"""Where the real inputs live: the light probes, the bunny and the NPF fits of ``../shared/data``.

Public: ``SHARED_DATA_ENV`` and ``shared_data_dir(repository=None) -> Path``.

That folder is not part of warpbw (its README says where each file comes from).  It lies beside the repository, and
``$WARPBW_SHARED_DATA`` names another place; the tests and every example read it through :func:`shared_data_dir`,
so that one setting serves both (the examples once read ``../shared/data`` whatever the variable said).
"""
from __future__ import annotations

import os
from pathlib import Path

SHARED_DATA_ENV = "WARPBW_SHARED_DATA"


def shared_data_dir(repository=None) -> Path:
    """``$WARPBW_SHARED_DATA`` when set (and not empty), else ``shared/data`` beside ``repository`` (the tests' and
    the examples' own checkout), by default the repository this package was installed from (an editable install,
    as the README's first command makes)."""
    given = os.environ.get(SHARED_DATA_ENV)
    if given:
        return Path(given)
    root = Path(__file__).resolve().parents[2] if repository is None else Path(repository)
    return root.parent / "shared" / "data"
