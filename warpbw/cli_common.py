"""What the two command lines (``warpbw``, ``warpbw-precompute``) share: one-line errors and warnings.

Public: ``EXIT_USER_ERROR``, ``EXIT_BROKEN_PIPE`` (stdout's reader left), ``EXIT_INTERRUPTED`` (Ctrl-C),
``EXIT_TERMINATED`` (SIGTERM), ``OneLineParser``, ``run_command(prog, func, args) -> int`` (a stopped run leaves
its outputs as they were), ``parse_seed`` (the argparse type of every ``--seed``), ``parse_path`` (of every ``-o``:
not empty), ``check_output_file(path, option, force)`` and ``check_output_dir(path, option)`` (an output path
that cannot be written, refused before any work), ``check_overwrite(paths, force, option, inputs)`` (several
outputs at once, and --force; never one of the command's inputs), ``init_warp(device) -> warp`` (Warp initialised
without its banner or its no-CUDA-driver line, the device checked), ``json_text(record) -> str`` (strict JSON, a
non-finite float as null) and ``write_json(path, record, say=True, force=True)`` (that, written where asked, and
said so), ``printable(text)`` (control characters written as escapes, as every error and warning line, and each
path of a summary line, is printed).  A measurement's record and plot (DESIGN.md, measurement protocol: every
benchmark writes both; ``warpbw bench`` and the timing scripts of examples/):
``record_paths(json_path, plot_path)`` (the suffixes checked, the one not given beside the other),
``check_record_outputs(json_path, plot_path, force, inputs)`` (that, and the overwrite check, before any work),
``write_record(json_path, plot_path, record, write_plot, force, say)`` (both or neither), ``PROTOCOL_RUNS``,
``few_runs_warning(runs)`` (the protocol's least number of timed runs) and ``RUNS_MAX`` (every --runs's most).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import re
import shlex
import signal
import sys
import tempfile
import threading
import warnings
from contextlib import contextmanager
from pathlib import Path

from warpbw import entry
from warpbw.entry import STOP_SIGNALS, stop_behind
from warpbw.errors import SEED_MAX, WarpbwError, check_device, check_path
from warpbw.io.staged import (check_existing_output, check_name_length, dangling_link, input_clash, output_exists,
                              staged_outputs)
from warpbw.native_output import init_warp_quietly, kernel_cache_write_error, remove_unfinished_kernel_builds

EXIT_USER_ERROR = 2
EXIT_BROKEN_PIPE = 128 + 13   # killed by SIGPIPE, as a shell reports it for other commands
EXIT_INTERRUPTED = 128 + 2    # SIGINT, likewise
EXIT_TERMINATED = 128 + 15    # SIGTERM, likewise
WARP_LOG_WARNING = 30  # warp._src.logger.LOG_WARNING: hide Warp's banner and module-load lines


# Control characters (C0, DEL, C1) and Unicode's line and paragraph separators: what splits a line or drives
# a terminal.
_CONTROL_CHARACTERS = re.compile("[\x00-\x1f\x7f-\x9f\u2028\u2029]")


def printable(text) -> str:
    """``text`` with its control characters written as escapes (``\\n``, ``\\x1b``).  A scene key, a material name
    or a path holding a newline split the one-line error in two (the second line could pass for another
    ``warpbw:`` message), and one holding ESC coloured the terminal (scene fuzzing, session 63)."""
    return _CONTROL_CHARACTERS.sub(lambda m: m.group(0).encode("unicode_escape").decode("ascii"), str(text))


class OneLineParser(argparse.ArgumentParser):
    """argparse with usage errors in the one-line form ``PROG: error: ...``, status 2, and options spelled out
    (``--for`` ran as ``--force``, and a later option beginning alike would have changed what it meant).  An option
    that stores one value may be given once: ``--spp 2 --spp 8`` is refused, naming both values (argparse kept the
    last one without a word, ``-o a1.exr -o a2.exr`` wrote a2.exr only).  A flag given twice (``--force --force``)
    means what it means once and is accepted; so would be an ``append`` or ``count`` option, of which there is
    none.  Subcommands' options are checked by their own parsers (``add_parser`` makes them of this class)."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)
        self._given = {}

    def parse_known_args(self, args=None, namespace=None):
        self._given = {}   # each parse starts with no option given (a subcommand's parser is called once in it)
        # kept for error(): argparse's parse_args refuses leftover arguments through the parser it was called on
        ns, extra = super().parse_known_args(args, namespace)
        self._parsed = ns
        return ns, extra

    def _get_values(self, action, arg_strings):
        # argparse converts each occurrence's strings here, before the action stores them (replacing the last)
        if isinstance(action, argparse._StoreAction) and action.option_strings:
            first = self._given.setdefault(action, arg_strings)
            if first is not arg_strings:
                shown = [" ".join(shlex.quote(s) for s in v) for v in (first, arg_strings)]
                self.error(f"{'/'.join(action.option_strings)} given twice ({shown[0]}, then {shown[1]}): give it "
                           "once")
        return super()._get_values(action, arg_strings)

    def error(self, message):
        # arguments left over are refused by the subcommand's parser, which points to its own --help (warpbw render
        # a.toml b.toml pointed to 'warpbw --help')
        parsed = getattr(self, "_parsed", None)
        if parsed is not None and message.startswith("unrecognized arguments"):
            chosen = next((a.choices.get(getattr(parsed, a.dest, None)) for a in self._actions
                           if isinstance(a, argparse._SubParsersAction)), None)
            if chosen is not None and chosen is not self:
                chosen.error(message)
        tool = self.prog.split()[0]
        self.exit(EXIT_USER_ERROR, f"{tool}: error: {printable(message)} (see '{self.prog} --help')\n")


def parse_path(s: str) -> str:
    """argparse type of a path option: any name but an empty one (``-o ""`` was shown as ``-o .``, pathlib's reading
    of it)."""
    if not s:
        raise argparse.ArgumentTypeError("expected a file name, got an empty one")
    return s


def parse_seed(s: str) -> int:
    """argparse type of ``--seed``: an integer from 0 to SEED_MAX (uint32 seeds wrap or fail outside it)."""
    try:
        v = int(s)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer from 0 to {SEED_MAX}, got {s!r}") from None
    if not 0 <= v <= SEED_MAX:
        raise argparse.ArgumentTypeError(f"expected an integer from 0 to {SEED_MAX} (a uint32 seed), got {v}")
    return v


def _check_parents(path: Path, option: str) -> None:
    """The nearest existing ancestor of ``path`` must be a directory in which a file can be made (else mkdir or the
    write fails after the work): a temporary file is made there and removed.  None on the way may be a link to
    nothing (``warpbw.io.staged.dangling_link``): no folder can be made in its place."""
    for parent in path.parents:
        link = dangling_link(parent)
        if link is not None:
            raise WarpbwError(f"{option} {path}: {parent} is {link}")
        if parent.exists():
            if not parent.is_dir():
                raise WarpbwError(f"{option} {path}: {parent} is not a directory")
            _check_writable(parent, path, option)
            return


def _check_writable(folder: Path, path: Path, option: str) -> None:
    try:
        with tempfile.TemporaryFile(dir=folder, prefix=".warpbw-write-check-"):
            pass
    except OSError as exc:
        raise WarpbwError(f"{option} {path}: cannot write in {folder} ({exc.strerror or exc})") from None


def check_output_file(path, option: str, force: bool) -> None:
    """Refuse, before any work, an output file that is a directory, lies under a file, or exists without --force."""
    p = Path(path)
    check_name_length(p, f"{option} {p}")   # first: Python 3.11's is_dir raises on a name too long
    if p.is_dir():
        raise WarpbwError(f"{option} {p}: is a directory (expected a file name)")
    _check_parents(p, option)
    # a read-only file (chmod a-w, chattr +i) is the user's "keep this", a FIFO no file: say so before any work
    check_existing_output(p, force, f"{option} {p}")


def check_output_dir(path, option: str) -> None:
    """Refuse, before any work, an output directory that is an existing file or lies under one, or whose name is
    too long."""
    p = Path(path)
    check_name_length(p, f"{option} {p}")   # first: Python 3.11's exists raises on a name too long
    link = dangling_link(p)
    if link is not None:
        raise WarpbwError(f"{option} {p}: {link} (expected a directory, made if absent)")
    if p.exists() and not p.is_dir():
        raise WarpbwError(f"{option} {p}: not a directory (expected a directory, made if absent)")
    if p.is_dir():
        _check_writable(p, p, option)
    else:
        _check_parents(p, option)


# How Warp words a failed allocation, on the CPU or a GPU (warp/_src/context.py, allocators: RuntimeError)
WARP_ALLOCATION_FAILED = "Failed to allocate"


# STOP_SIGNALS (warpbw.entry's): the stops that end a run as Ctrl-C does, with their one line (SIGHUP ended the
# process where it stood and left its temporaries)


class _Terminated(BaseException):
    """A stop of ``STOP_SIGNALS``, raised where the run is (a BaseException, as KeyboardInterrupt is: no ``except
    Exception`` takes it); ``signum`` says which."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


@contextmanager
def _sigterm_raises():
    """While the block runs, SIGTERM and SIGHUP (``STOP_SIGNALS``) raise ``_Terminated``, so that the run unwinds as
    on Ctrl-C and its staged outputs' temporary files are removed (by default they end the process where it stands
    and leave them).  Python handles a signal between bytecodes: one that arrives during a kernel launch acts when
    the launch returns.  Not in a thread other than the main one (Python sets handlers there only), nor for a signal
    that is ignored (the caller's choice: ``nohup`` ignores SIGHUP)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def on_stop(signum, frame):
        raise _Terminated(signum)

    sigs = [getattr(signal, n) for n in STOP_SIGNALS]
    previous = {sig: signal.signal(sig, on_stop) for sig in sigs if signal.getsignal(sig) is not signal.SIG_IGN}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


@contextmanager
def _stops_in_destructors_unsaid():
    """A Ctrl-C or stop that lands in a destructor (a Warp array freed as the command's locals go, right after its
    outputs were moved into place) cannot unwind the run: Python reports it as "Exception ignored in ...
    KeyboardInterrupt" with a traceback and goes on.  While the block runs, such a report is left out; any other
    exception in a destructor is reported as before."""
    previous = sys.unraisablehook

    def hook(unraisable):
        if not isinstance(unraisable.exc_value, (KeyboardInterrupt, _Terminated)):
            previous(unraisable)

    sys.unraisablehook = hook
    try:
        yield
    finally:
        sys.unraisablehook = previous


@contextmanager
def _script_ends_ignoring_stops():
    """When the block ends in a script run as ``__main__`` (``warpbw.entry.running_as_script``, set by its
    ``interrupt_in_one_line``), ignore the stops from then on, while the interpreter ends, as the console scripts'
    entry points do (a late Ctrl-C printed "Exception ignored in ..." or "SCRIPT: interrupted" after its run)."""
    try:
        yield
    finally:
        if entry.running_as_script and threading.current_thread() is threading.main_thread():
            entry.ignore_stops()


class _NamedStdout:
    """``sys.stdout`` while a command runs (:func:`_stdout_named`): a write or flush that fails with an OSError other
    than a closed pipe (``> /dev/full``, a full disk or quota, a file-size limit) raises a ``WarpbwError`` naming
    standard output (it said a bare "[Errno 28] No space left on device", naming nothing); anything else is the
    stream's own."""

    def __init__(self, stream):
        self._stream = stream

    def _named(self, exc: OSError) -> WarpbwError:
        try:   # the interpreter's own flush at exit would fail again, and say so
            os.dup2(os.open(os.devnull, os.O_WRONLY), self._stream.fileno())
        except (OSError, ValueError, AttributeError):   # no descriptor of its own (pytest's capture)
            pass
        return WarpbwError(f"standard output: cannot write there ({exc.strerror or exc}); what the command printed "
                           "is lost")

    def write(self, text):
        try:
            return self._stream.write(text)
        except BrokenPipeError:   # the reader left: run_command stops quietly
            raise
        except OSError as exc:
            raise self._named(exc) from None

    def flush(self):
        try:
            return self._stream.flush()
        except BrokenPipeError:
            raise
        except OSError as exc:
            raise self._named(exc) from None

    def __getattr__(self, name):
        return getattr(self._stream, name)


@contextmanager
def _stderr_or_nowhere():
    """While the block runs, a process started with stderr closed (``2>&-``; Python has no ``sys.stderr``) writes its
    progress, warnings and errors nowhere, as a shell's other commands do there: ``print(..., file=sys.stderr)``
    with no sys.stderr prints to stdout, so an error line landed among the results (``--json``'s JSON)."""
    if sys.stderr is not None:
        yield
        return
    with open(os.devnull, "w") as nowhere:
        sys.stderr = nowhere
        try:
            yield
        finally:
            sys.stderr = None


@contextmanager
def _stdout_named():
    """While the block runs, ``sys.stdout`` is a :class:`_NamedStdout` of itself (unless there is none: started with
    stdout closed, ``>&-``, Python has no ``sys.stdout`` and print() writes nothing)."""
    out = sys.stdout
    if out is None:
        yield
        return
    sys.stdout = _NamedStdout(out)
    try:
        yield
    finally:
        if isinstance(sys.stdout, _NamedStdout):   # unless the command set its own
            sys.stdout = out


def run_command(prog: str, func, args) -> int:
    """Run a subcommand; user errors and warnings print as one line each (``PROG: error: ...``).  Ctrl-C, SIGTERM
    and SIGHUP stop it with one line and the shell's status for the signal, its outputs untouched (and no build folder
    of a compile it stopped left in Warp's kernel cache), also where the stop came out as another error raised from it
    (an extension's initialisation it stopped: ``warpbw.entry.stop_behind``)."""

    def show_warning(message, category, filename, lineno, file=None, line=None):
        # warnings (an environment with clamped pixels, unmeasured MERL entries...) as one line each
        print(f"{prog}: warning: {printable(message)}", file=sys.stderr if file is None else file)

    with _script_ends_ignoring_stops(), warnings.catch_warnings(), _sigterm_raises(), _stops_in_destructors_unsaid(), \
            _stdout_named(), _stderr_or_nowhere():
        warnings.showwarning = show_warning
        try:
            try:
                status = func(args)
            except Exception as exc:   # a stop that an extension's initialisation turned into an ImportError
                stop = stop_behind(exc, (KeyboardInterrupt, _Terminated))
                if stop is None:
                    raise
                raise stop from None
            if sys.stdout is not None:   # None: started with stdout closed (``>&-``), where print() writes nothing
                sys.stdout.flush()   # here, where a closed pipe or a full disk is caught, rather than at exit
            return status
        except BrokenPipeError:
            # the reader left (``warpbw compare ... | head -1``): stop quietly, as other Unix tools do, and point
            # stdout at /dev/null so that the interpreter's own flush at exit does not report it again
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            return EXIT_BROKEN_PIPE
        except WarpbwError as exc:
            print(f"{prog}: error: {printable(exc)}", file=sys.stderr)
            return EXIT_USER_ERROR
        except KeyboardInterrupt:
            print(f"{prog}: interrupted", file=sys.stderr)
            return EXIT_INTERRUPTED
        except _Terminated as stop:
            try:   # after a hang-up the terminal may be gone
                print(f"{prog}: {STOP_SIGNALS[signal.Signals(stop.signum).name]}", file=sys.stderr)
            except OSError:
                pass
            return 128 + stop.signum   # the shell's status for the signal: EXIT_TERMINATED for SIGTERM
        except (OSError, MemoryError) as exc:   # Warp's kernel cache on a full disk: named, not a bare "[Errno 28]"
            print(f"{prog}: error: {printable(kernel_cache_write_error(exc))}", file=sys.stderr)
            return EXIT_USER_ERROR
        except RuntimeError as exc:
            if not str(exc).startswith(WARP_ALLOCATION_FAILED):
                raise
            print(f"{prog}: error: out of memory: {exc} (a smaller [camera].resolution, fewer samples or directions "
                  "need less)", file=sys.stderr)
            return EXIT_USER_ERROR
        finally:   # a stop or an error during a compile left Warp's build folder in its kernel cache for good
            remove_unfinished_kernel_builds()


def init_warp(device: str):
    """Initialise Warp quietly (no banner, no no-CUDA-driver line) and check ``--device``; returns ``warp``."""
    import warp as wp

    wp.config.log_level = WARP_LOG_WARNING
    init_warp_quietly()
    check_device(device, "--device")
    return wp


def check_overwrite(paths, force: bool, option: str = "-o", inputs=(), inputs_are: str = "a file this command reads"):
    """Refuse, before any work, output files that cannot be written or exist without --force, and, whatever --force
    says, an output that is one of ``inputs`` (the scene, its probe, a BRDF file, ...: ``--force`` would have
    replaced a light probe by the render of it).  ``option`` names the first path's option, the others being its
    siblings (``-o out.exr``'s .png, .json, ...), or is one option per path (``("--json", "--plot")``)."""
    read = [Path(f) for f in inputs]
    options = [option] * len(paths) if isinstance(option, str) else list(option)
    for p, opt in zip(paths, options):  # a directory, or a path under a file, fails whatever --force says
        clash = input_clash(p, read, inputs_are)   # the rule every library writer keeps (warpbw.io.staged)
        if clash is not None:
            if not isinstance(option, str):   # each path is named by its own option
                raise WarpbwError(f"{opt} {p}: {clash}")
            whose = "" if Path(p) == Path(paths[0]) else f" (its output {p})"
            raise WarpbwError(f"{option} {paths[0]}{whose}: {clash}")
        check_output_file(p, opt, force=True)
    if force:
        return
    existing = [str(p) for p in paths if output_exists(p)]
    if existing:
        more = len(existing) - 1   # "(pass --force to overwrite it and 3 more)" read as --force's doing (session 76)
        others = {0: "", 1: ", as does 1 more output of this command"}.get(
            more, f", as do {more} more outputs of this command")
        them = "them" if more else "it"
        raise WarpbwError(f"{existing[0]}: already exists{others} (pass --force to overwrite {them})")


def json_text(record: dict, **kw) -> str:
    """``record`` as strict JSON: a non-finite float (no value) becomes null, never a bare NaN or Infinity."""
    def clean(x):
        if isinstance(x, float) and not math.isfinite(x):
            return None
        if isinstance(x, dict):
            return {k: clean(v) for k, v in x.items()}
        if isinstance(x, (list, tuple)):
            return [clean(v) for v in x]
        return x
    return json.dumps(clean(record), indent=2, allow_nan=False, **kw) + "\n"


def write_json(path, record: dict, say: bool = True, force: bool = True) -> Path:
    """Write ``record`` to ``path`` as :func:`json_text` (its folder made if needed); with ``say``, print where.
    Without ``force`` (the caller refused an existing ``path`` before its work) a file that appeared there meanwhile
    is kept."""
    p = check_path(path, "write_json: path")
    with staged_outputs([p], force=force) as at:   # whole or not at all (a full disk leaves the old record)
        at[p].write_text(json_text(record))
    if say:
        print(f"wrote {printable(p)}")
    return p


PROTOCOL_RUNS = 3   # DESIGN.md, measurement protocol: the median of at least 3 timed runs
# --runs of every measurement: the timed runs of one point.  The median settles within a few dozen; 1000 runs of even
# a 16x16 frame take minutes per point, and each run's MSE is kept in the record (2^31 ran until killed, its memory
# growing)
RUNS_MAX = 1000


def few_runs_warning(runs: int, option: str = "--runs") -> str | None:
    """The warning for fewer timed runs than the protocol's ``PROTOCOL_RUNS`` (without the ``PROG: warning:``
    prefix), or None."""
    if runs >= PROTOCOL_RUNS:
        return None
    return (f"{option} {runs}: the measurement protocol times the median of at least {PROTOCOL_RUNS} runs "
            "(DESIGN.md); fewer give noisier times")


def record_paths(json_path, plot_path) -> tuple[str | None, str | None]:
    """``--json OUT.json`` / ``--plot OUT.png`` of a measurement, each refused unless it ends in its suffix; the
    one not given goes beside the other, with its suffix (every benchmark writes both, DESIGN.md); neither given:
    ``(None, None)``."""
    if json_path and Path(json_path).suffix.lower() != ".json":
        raise WarpbwError(f"--json {json_path}: expected a path ending in .json")
    if plot_path and Path(plot_path).suffix.lower() != ".png":
        raise WarpbwError(f"--plot {plot_path}: expected a path ending in .png")
    if not (json_path or plot_path):
        return None, None
    return (str(json_path or Path(plot_path).with_suffix(".json")),
            str(plot_path or Path(json_path).with_suffix(".png")))


def check_record_outputs(json_path, plot_path, force: bool, inputs=()) -> tuple[str | None, str | None]:
    """:func:`record_paths`, and both refused, before any work, where they cannot be written, exist without
    --force or are one of ``inputs`` (``check_overwrite``).  Returns the two paths (or two Nones)."""
    json_path, plot_path = record_paths(json_path, plot_path)
    if json_path is not None:
        check_overwrite([Path(json_path), Path(plot_path)], force, option=("--json", "--plot"), inputs=inputs)
    return json_path, plot_path


def write_record(json_path, plot_path, record: dict, write_plot, force: bool, say: bool = True) -> None:
    """``record`` as JSON (:func:`json_text`) and ``write_plot(record, path)``'s PNG, both or neither: a plot that
    fails leaves an earlier record as it was.  With ``say``, print where."""
    j, p = Path(json_path), Path(plot_path)
    with staged_outputs([j, p], force=force) as at:
        at[j].write_text(json_text(record))
        write_plot(record, at[p])
    if say:
        print(f"record {printable(json_path)}, plot {printable(plot_path)}")
