"""The console scripts' entry points: what ``warpbw`` and ``warpbw-precompute`` run.

Public: ``warpbw()``, ``warpbw_precompute()``.

Each imports its command line only inside the handling of Ctrl-C: the imports (numpy, Warp) take a fraction of a
second, and a Ctrl-C then printed a traceback of whichever import it stopped.  And once the command has returned
(its outputs in place, its status known), the stops are ignored while the interpreter shuts down: one that arrived
then printed "Exception ignored in ... KeyboardInterrupt" from a Warp array's destructor or the thread pool's exit,
after a run that had succeeded.
"""
from __future__ import annotations

import importlib
import signal
import sys


def _run(module: str, prog: str) -> int:
    try:
        try:   # a Ctrl-C while importing, or while the arguments are parsed (outside run_command's own handling)
            return importlib.import_module(module).main()
        except KeyboardInterrupt:
            print(f"{prog}: interrupted", file=sys.stderr)
            return 128 + signal.SIGINT   # the shell's status, as run_command's EXIT_INTERRUPTED
    finally:
        for name in ("SIGINT", "SIGTERM", "SIGHUP"):
            if hasattr(signal, name):
                signal.signal(getattr(signal, name), signal.SIG_IGN)


def warpbw() -> int:
    return _run("warpbw.cli", "warpbw")


def warpbw_precompute() -> int:
    return _run("precompute.__main__", "warpbw-precompute")
