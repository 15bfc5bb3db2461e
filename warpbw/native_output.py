"""Output that native libraries write straight to the process's file descriptors, captured.

Public:
    ``captured_native_output(fds=(1, 2))``  context manager: what C/C++ code wrote to those descriptors
    inside the block, as a list of lines (filled when the block ends), instead of the terminal
    ``init_warp_quietly()``  ``wp.init()`` without Warp's no-CUDA-driver line nor its notice that it will drop
                             Python 3.10 (every other line passed on);
                             a kernel cache folder Warp cannot make is a ``WarpbwError`` naming it
    ``kernel_cache_write_error(exc)``  the ``WarpbwError`` naming Warp's kernel cache for an error Warp raised
                             writing a compiled module there; ``exc`` itself for any other
    ``remove_unfinished_kernel_builds()``  the build folders this process left in Warp's kernel cache (a stop or
                             an error during a compile), removed

Warp prints a line at initialisation on a machine without an NVIDIA driver, and OpenEXR prints warnings
and errors about a damaged file before raising its own exception: neither goes through Python's
``sys.stdout`` / ``sys.stderr``, so only redirecting the descriptors themselves keeps them off the user's
terminal, where warpbw promises one line per error.  The caller decides what to pass on.  The descriptors are the
process's, so one capture runs at a time (``_CAPTURE_LOCK``): two threads reading EXR files at once each saved the
other's redirection as the descriptor to put back, and the last to finish left stdout and stderr pointing at a deleted
temporary file for the rest of the process (everything printed after it was lost).  What another thread writes to the
descriptors during a capture is captured with it.
"""
from __future__ import annotations

import contextlib
import os
import shutil
import sys
import tempfile
import threading
import traceback
import warnings


_CAPTURE_LOCK = threading.RLock()   # one capture of the process's descriptors at a time (module docstring)


@contextlib.contextmanager
def captured_native_output(fds=(1, 2)):
    with _CAPTURE_LOCK:
        with _captured(fds) as lines:
            yield lines


@contextlib.contextmanager
def _captured(fds):
    lines: list[str] = []
    streams = {1: sys.stdout, 2: sys.stderr}
    saved = {}
    try:
        for fd in fds:
            streams[fd].flush()
            saved[fd] = os.dup(fd)
    except (OSError, ValueError, AttributeError):   # no usable descriptor (an embedded interpreter): capture nothing
        for s in saved.values():
            os.close(s)
        yield lines
        return
    with tempfile.TemporaryFile() as tmp:
        for fd in fds:
            os.dup2(tmp.fileno(), fd)
        try:
            yield lines
        finally:
            for fd in fds:
                try:
                    streams[fd].flush()
                finally:
                    os.dup2(saved[fd], fd)
                    os.close(saved[fd])
            tmp.seek(0)
            lines.extend(tmp.read().decode("utf-8", "replace").splitlines())


# The one line Warp's native library prints at init on a machine without an NVIDIA driver
# (warp/native/cuda_util.cpp, init_cuda_driver(), fprintf to stderr).  Warp has no setting that skips the
# driver probe, so init_warp_quietly captures file descriptor 2 around wp.init() and passes on every other line.
WARP_NO_DRIVER_LINE = "Could not find or load the NVIDIA CUDA driver"

# Warp 1.19's notice at init on Python 3.10 (warp/_src/context.py, Runtime.__init__: a FutureWarning through Python's
# warnings, printed "Warp FutureWarning: ..." before every command).  It is about Warps to come: warpbw declares Python
# >= 3.10, and the Warps it runs on (1.15-1.19) support 3.10, so init_warp_quietly ignores that notice, and only it.
WARP_PYTHON_310_NOTICE = r"Support for Python 3\.10 is deprecated and will be removed in Warp "

_warp_initialised = False   # by init_warp_quietly: later calls are free (wp.init() is a no-op then too)


def init_warp_quietly() -> None:
    """``wp.init()`` without Warp's no-CUDA-driver line on stderr (other native output is passed on): a CPU-only
    machine is warpbw's usual one, where that line is noise; nor Warp's notice that it will drop Python 3.10
    (``WARP_PYTHON_310_NOTICE``; every other warning is passed on).  The command lines and every ``device`` check
    call it, so it is the first initialisation unless the caller initialised Warp itself."""
    global _warp_initialised
    if _warp_initialised:
        return
    import warp as wp

    try:
        with captured_native_output(fds=(2,)) as lines, warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=WARP_PYTHON_310_NOTICE, category=FutureWarning)
            wp.init()
    except OSError as exc:
        raise _kernel_cache_error(exc, wp.config.kernel_cache_dir) from None
    for line in lines:
        if WARP_NO_DRIVER_LINE not in line:
            print(line, file=sys.stderr)
    _warp_initialised = True


def _kernel_cache_error(exc: OSError, cache_dir) -> Exception:
    """The one-line error for Warp's kernel cache folder that ``wp.init()`` could not make (``HOME`` a file gave a
    bare "[Errno 20] Not a directory: 'hf/.cache'"); ``exc`` itself when it is about another file."""
    from warpbw.errors import WarpbwError

    failed = os.fsdecode(exc.filename) if exc.filename is not None else None
    if not cache_dir or failed is None or not (cache_dir == failed or cache_dir.startswith(failed.rstrip("/") + "/")):
        return exc
    return WarpbwError(f"Warp's kernel cache {cache_dir} cannot be made ({exc.strerror or exc} at {failed}): set HOME, "
                       "or WARP_CACHE_PATH, to a folder where it can be")


def kernel_cache_write_error(exc: BaseException) -> BaseException:
    """The one-line error for an ``OSError`` that Warp raised while it wrote a module it compiled into its kernel
    cache: a full disk or quota, a file-size limit (``ulimit -f``) ended the run with a bare "[Errno 28] No space
    left on device", naming no file (a write to an open file names none) nor the kernel cache.  ``exc`` itself for
    any other error, or one about another file."""
    wp = sys.modules.get("warp")   # a Warp imported only in part (a stop during its import) has no config
    cache_dir = getattr(getattr(wp, "config", None), "kernel_cache_dir", None)
    if not isinstance(exc, OSError) or not cache_dir:
        return exc
    from warpbw.errors import WarpbwError

    package = os.path.dirname(os.path.abspath(wp.__file__)) + os.sep
    failed = os.fsdecode(exc.filename) if exc.filename is not None else None
    in_warp = any(os.path.abspath(f.filename).startswith(package) for f in traceback.extract_tb(exc.__traceback__))
    if not in_warp or not (failed is None or os.path.abspath(failed).startswith(os.path.abspath(cache_dir) + os.sep)):
        return exc
    at = f" at {failed}" if failed is not None else ""
    return WarpbwError(f"Warp's kernel cache {cache_dir}: cannot write a compiled module there ({exc.strerror or exc}"
                       f"{at}): make room there, or set WARP_CACHE_PATH to a folder where it can be written")


# Where Warp compiles a module before it moves the result into its kernel cache: ``MODULE_pPID_tTHREAD`` beside the
# module's entry (warp/_src/context.py, Module._compile; warp/_src/build.py for LTO objects)
KERNEL_BUILD_SUFFIX = "_p{pid}_t"


def remove_unfinished_kernel_builds() -> None:
    """Remove the build folders this process left in Warp's kernel cache.  Warp removes one only once its module is
    in place, so a Ctrl-C or SIGTERM during a compile (the first run's minute, when a user is likeliest to stop it),
    or a full disk, left it there for good: 100-200 kB of C++ source each, never read again (a later run builds in
    a folder named after its own process)."""
    wp = sys.modules.get("warp")
    cache_dir = getattr(getattr(wp, "config", None), "kernel_cache_dir", None)
    if not cache_dir:
        return
    mark = KERNEL_BUILD_SUFFIX.format(pid=os.getpid())
    try:
        names = [e.name for e in os.scandir(cache_dir) if mark in e.name and e.is_dir(follow_symlinks=False)]
    except OSError:   # no kernel cache (yet), or one that cannot be listed: nothing to tidy
        return
    for name in names:
        shutil.rmtree(os.path.join(cache_dir, name), ignore_errors=True)
