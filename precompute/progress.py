"""Progress bars for the precompute builders.

Public: ``progress_callback(total, desc, unit, enabled) -> context manager yielding step(k)``.
"""
from __future__ import annotations

import contextlib


@contextlib.contextmanager
def progress_callback(total: int, desc: str, unit: str, enabled: bool = True):
    """Yield ``step(k)``: report that ``k`` of ``total`` items are done (a tqdm bar when ``enabled``)."""
    if not enabled:
        yield lambda k: None
        return
    from tqdm import tqdm

    bar = tqdm(total=total, desc=desc, unit=unit, leave=False)
    done = [0]

    def step(k):
        bar.update(k - done[0])
        done[0] = k

    try:
        yield step
    finally:
        bar.close()
