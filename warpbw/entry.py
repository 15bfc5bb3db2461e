"""The console scripts' entry points: what ``warpbw`` and ``warpbw-precompute`` run.

Public: ``warpbw()``, ``warpbw_precompute()``; ``interrupt_in_one_line(module_name)``, what each script under
``examples/`` calls first.

Each imports its command line only inside the handling of Ctrl-C: the imports (numpy, Warp) take a fraction of a
second, and a Ctrl-C then printed a traceback of whichever import it stopped.  And once the command has returned
(its outputs in place, its status known), the stops are ignored while the interpreter shuts down: one that arrived
then printed "Exception ignored in ... KeyboardInterrupt" from a Warp array's destructor or the thread pool's exit,
after a run that had succeeded.

A script under ``examples/`` imports numpy, Warp and warpbw at its top, before its ``run_command`` (1 to 18 s on a
busy machine): :func:`interrupt_in_one_line`, called before those imports, makes a Ctrl-C there one line too.
"""
from __future__ import annotations

import importlib
import os
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


def interrupt_in_one_line(module_name: str) -> None:
    """Called first thing by a script (``interrupt_in_one_line(__name__)``, before its heavy imports): when it runs as
    ``__main__``, a Ctrl-C that no code handles (one while it imports numpy, Warp and warpbw, before its
    ``run_command``) prints ``SCRIPT: interrupted``, as ``run_command`` does, instead of the traceback of the import
    it stopped; the interpreter still ends by SIGINT (status 130 in a shell).  Imported as a module (by the tests),
    nothing changes."""
    if module_name != "__main__":
        return
    prog = os.path.basename(sys.argv[0])   # the script's file name, as its run_command's
    shown = sys.excepthook

    def hook(kind, value, traceback):
        if issubclass(kind, KeyboardInterrupt):
            print(f"{prog}: interrupted", file=sys.stderr)
        else:
            shown(kind, value, traceback)

    sys.excepthook = hook
