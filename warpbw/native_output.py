"""Output that native libraries write straight to the process's file descriptors, captured.

Public:
    ``captured_native_output(fds=(1, 2))``  context manager: what C/C++ code wrote to those descriptors
    inside the block, as a list of lines (filled when the block ends), instead of the terminal

Warp prints a line at initialisation on a machine without an NVIDIA driver, and OpenEXR prints warnings
and errors about a damaged file before raising its own exception: neither goes through Python's
``sys.stdout`` / ``sys.stderr``, so only redirecting the descriptors themselves keeps them off the user's
terminal, where warpbw promises one line per error.  The caller decides what to pass on.
"""
from __future__ import annotations

import contextlib
import os
import sys
import tempfile


@contextlib.contextmanager
def captured_native_output(fds=(1, 2)):
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
