"""Progress bars for the precompute builders and the renderer's long launches.

Public: ``progress_callback(total, desc, unit, enabled) -> context manager yielding step(k, total=None)``;
``bar_options(stream=None) -> dict`` (tqdm's keyword arguments for a bar on ``stream``, stderr by default) and
``LOG_INTERVAL_S``.

On a terminal a bar is tqdm's own, redrawn in place.  Off one (a log file, a pipe, a batch scheduler's output) a
redrawn bar was a carriage return and the whole bar again, up to ten times a second for as long as the work lasted,
all on one line that never ended (a 64-spp render of the demo scene wrote 471 bytes of it); there each state of the
bar is a line of its own, at most one every ``LOG_INTERVAL_S`` seconds after the first, and the bar's erasing at its
end writes nothing.
"""
from __future__ import annotations

import contextlib
import sys

LOG_INTERVAL_S = 30.0   # ours: off a terminal, a bar's state at most every 30 s (a log is read, not watched)


class _LogLines:
    """A stream for tqdm off a terminal: each redraw (``"\\r" + bar + padding``) becomes the bar alone on a line,
    and a redraw that holds only blanks (the bar erased) writes nothing."""

    def __init__(self, stream):
        self.stream = stream

    def write(self, text: str) -> int:
        line = text.replace("\r", "").rstrip()
        if line:
            self.stream.write(line + "\n")
        return len(text)

    def flush(self) -> None:
        self.stream.flush()


def bar_options(stream=None) -> dict:
    """tqdm's keyword arguments for a bar on ``stream`` (None: ``sys.stderr`` as it is now): none on a terminal;
    off one, lines at most every ``LOG_INTERVAL_S`` (module docstring); no bar where there is no stream (a process
    started with stderr closed, ``2>&-``, has no ``sys.stderr``: the bar's first line raised AttributeError, and the
    run ended with status 1 and not a word, its traceback having nowhere to go)."""
    stream = sys.stderr if stream is None else stream
    if stream is None:
        return {"disable": True}
    try:
        tty = stream.isatty()
    except (AttributeError, ValueError):   # no isatty, or a closed stream
        tty = False
    if tty:
        return {}
    return {"file": _LogLines(stream), "mininterval": LOG_INTERVAL_S, "maxinterval": LOG_INTERVAL_S}


@contextlib.contextmanager
def progress_callback(total: int, desc: str, unit: str, enabled: bool = True):
    """Yield ``step(k, total=None)``: report that ``k`` of ``total`` items are done (a tqdm bar with ``bar_options``
    when ``enabled``); a ``total`` given to ``step`` replaces the bar's (for work whose size its callee decides)."""
    if not enabled or sys.stderr is None:   # asked for none, or nowhere to draw one (bar_options)
        yield lambda k, total=None: None
        return
    from tqdm import tqdm

    bar = tqdm(total=total, desc=desc, unit=unit, leave=False, **bar_options())
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
