"""The console scripts' entry points: what ``warpbw`` and ``warpbw-precompute`` run.

Public: ``warpbw()``, ``warpbw_precompute()``; ``interrupt_in_one_line(module_name)``, what each script under
``examples/`` calls first; ``stop_behind(exc, kinds)`` (the stop an error was raised from); ``ignore_stops()``.

Each imports its command line only inside the handling of Ctrl-C, SIGTERM and SIGHUP: the imports (numpy, Warp) take
a fraction of a second (seconds on a busy machine), and a Ctrl-C then printed a traceback of whichever import it
stopped (a SIGTERM ended the process without a word).  And once the command has returned
(its outputs in place, its status known), the stops are ignored while the interpreter shuts down: one that arrived
then printed "Exception ignored in ... KeyboardInterrupt" from a Warp array's destructor or the thread pool's exit,
after a run that had succeeded.

A script under ``examples/`` imports numpy, Warp and warpbw at its top, before its ``run_command`` (1 to 18 s on a
busy machine): :func:`interrupt_in_one_line`, called before those imports, makes a Ctrl-C, a SIGTERM or a SIGHUP
there one line too.
"""
from __future__ import annotations

import importlib
import os
import signal
import sys


def stop_behind(exc: BaseException, kinds=(KeyboardInterrupt,)) -> BaseException | None:
    """The stop of ``kinds`` that ``exc`` is, or was raised from or while handling (its ``__cause__`` and
    ``__context__``, followed back), else None.  A stop that lands in a pybind11 extension's initialisation
    (matplotlib's ft2font, imported at a command's first PNG) reaches Python as "ImportError: initialization failed",
    raised from the KeyboardInterrupt: a Ctrl-C then ended a render with two tracebacks and status 1 (session 79)."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, kinds):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None


# Set by interrupt_in_one_line in a script run as __main__: its run_command ignores the stops once it returns, as the
# console scripts' _run does (a late Ctrl-C printed "Exception ignored in ..." or "SCRIPT: interrupted" after a run
# that had succeeded)
running_as_script = False

# The stops that end a run as Ctrl-C does, with their one line: ``kill``, ``timeout``, a batch scheduler's stop; a
# closed terminal or a dropped ssh session (warpbw.cli_common.run_command's, and the entry points' while they load)
STOP_SIGNALS = {name: word for name, word in (("SIGTERM", "terminated"), ("SIGHUP", "hung up"))
                if hasattr(signal, name)}


class _StoppedLoading(BaseException):
    """A stop of ``STOP_SIGNALS`` that arrived before the command's run_command (while numpy and Warp load)."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


def _stop_while_loading(signum, frame):
    raise _StoppedLoading(signum)


def _say_stops_while_loading() -> None:
    """SIGTERM and SIGHUP raise ``_StoppedLoading`` from now on, until a ``run_command`` sets its own handlers (and
    puts these back after it): such a stop while a program loads ended it without a word.  An ignored one (nohup)
    stays ignored."""
    for name in STOP_SIGNALS:
        if signal.getsignal(getattr(signal, name)) is not signal.SIG_IGN:
            signal.signal(getattr(signal, name), _stop_while_loading)


def _say_stopped(prog: str, stop: _StoppedLoading) -> int:
    """Print ``PROG: terminated`` (or ``hung up``) for ``stop``; the shell's status for its signal."""
    try:   # after a hang-up the terminal may be gone
        print(f"{prog}: {STOP_SIGNALS[signal.Signals(stop.signum).name]}", file=sys.stderr)
        sys.stderr.flush()
    except OSError:
        pass
    return 128 + stop.signum


def _run(module: str, prog: str) -> int:
    try:
        _say_stops_while_loading()   # a SIGTERM or SIGHUP while the command line loads said nothing
        try:   # a Ctrl-C while importing, or while the arguments are parsed (outside run_command's own handling)
            return importlib.import_module(module).main()
        except Exception as exc:   # an extension's initialisation that a Ctrl-C stopped (stop_behind)
            if stop_behind(exc) is None:
                raise
            print(f"{prog}: interrupted", file=sys.stderr)
            return 128 + signal.SIGINT
        except KeyboardInterrupt:
            print(f"{prog}: interrupted", file=sys.stderr)
            return 128 + signal.SIGINT   # the shell's status, as run_command's EXIT_INTERRUPTED
        except _StoppedLoading as stop:
            return _say_stopped(prog, stop)
    finally:
        ignore_stops()


def ignore_stops() -> None:
    """Ignore Ctrl-C, SIGTERM and SIGHUP from now on: what a run does once its command has returned (its outputs in
    place, its status known), while the interpreter shuts down."""
    for name in ("SIGINT", *STOP_SIGNALS):
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
    it stopped; the interpreter still ends by SIGINT (status 130 in a shell; status 1 where the stop came out as an
    extension's failed initialisation, :func:`stop_behind`).  A SIGTERM or SIGHUP there (``STOP_SIGNALS``), which ended
    the script without a word, prints ``SCRIPT: terminated`` (``hung up``) and exits with the status the commands
    and its own ``run_command`` give (143, 129).  And once its ``run_command`` returns, the stops are ignored while the
    interpreter shuts down (``running_as_script``), as the console scripts ignore them.  Imported as a module (by the
    tests), nothing changes."""
    global running_as_script
    if module_name != "__main__":
        return
    running_as_script = True
    prog = os.path.basename(sys.argv[0])   # the script's file name, as its run_command's
    shown = sys.excepthook

    def hook(kind, value, traceback):
        stopped = stop_behind(value, (_StoppedLoading,))   # a SIGTERM or SIGHUP, or an initialisation it stopped
        if stopped is not None:
            status = _say_stopped(prog, stopped)
            try:
                sys.stdout.flush()
            except (OSError, ValueError):
                pass
            os._exit(status)   # an excepthook cannot set the status; nothing of the run was begun
        if stop_behind(value) is not None:   # a Ctrl-C, or an extension's initialisation it stopped
            print(f"{prog}: interrupted", file=sys.stderr)
        else:
            shown(kind, value, traceback)

    sys.excepthook = hook
    _say_stops_while_loading()
