"""Progress bars for the precompute builders.

Public: ``progress_callback(total, desc, unit, enabled) -> context manager yielding step(k, total=None)``.
"""
from __future__ import annotations

import contextlib


@contextlib.contextmanager
def progress_callback(total: int, desc: str, unit: str, enabled: bool = True):
    """Yield ``step(k, total=None)``: report that ``k`` of ``total`` items are done (a tqdm bar when ``enabled``);
    a ``total`` given to ``step`` replaces the bar's (for work whose size its callee decides)."""
    if not enabled:
        yield lambda k, total=None: None
        return
    from tqdm import tqdm

    bar = tqdm(total=total, desc=desc, unit=unit, leave=False)
    done = [0]

    def step(k, total=None):
        if total is not None and total != bar.total:
            bar.total = total
        bar.update(k - done[0])
        done[0] = k

    try:
        yield step
    finally:
        bar.close()
