"""What the two command lines (``warpbw``, ``warpbw-precompute``) share: one-line errors and warnings.

Public: ``EXIT_USER_ERROR``, ``OneLineParser``, ``run_command(prog, func, args) -> int``, ``parse_seed`` (the
argparse type of every ``--seed``), ``check_output_file(path, option, force)`` and ``check_output_dir(path,
option)`` (an output path that cannot be written, refused before any work).
"""
from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

from warpbw.errors import SEED_MAX, WarpbwError

EXIT_USER_ERROR = 2


class OneLineParser(argparse.ArgumentParser):
    """argparse with usage errors in the one-line form ``PROG: error: ...``, status 2."""

    def error(self, message):
        tool = self.prog.split()[0]
        self.exit(EXIT_USER_ERROR, f"{tool}: error: {message} (see '{self.prog} --help')\n")


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
    """The nearest existing ancestor of ``path`` must be a directory (else mkdir fails after the work)."""
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise WarpbwError(f"{option} {path}: {parent} is not a directory")
            return


def check_output_file(path, option: str, force: bool) -> None:
    """Refuse, before any work, an output file that is a directory, lies under a file, or exists without --force."""
    p = Path(path)
    if p.is_dir():
        raise WarpbwError(f"{option} {p}: is a directory (expected a file name)")
    _check_parents(p, option)
    if p.exists() and not force:
        raise WarpbwError(f"{p}: already exists (pass --force to overwrite it)")


def check_output_dir(path, option: str) -> None:
    """Refuse, before any work, an output directory that is an existing file or lies under one."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise WarpbwError(f"{option} {p}: not a directory (expected a directory, made if absent)")
    _check_parents(p, option)


def run_command(prog: str, func, args) -> int:
    """Run a subcommand; user errors and warnings print as one line each (``PROG: error: ...``)."""

    def show_warning(message, category, filename, lineno, file=None, line=None):
        # warnings (an environment with clamped pixels, unmeasured MERL entries...) as one line each
        print(f"{prog}: warning: {message}", file=sys.stderr if file is None else file)

    with warnings.catch_warnings():
        warnings.showwarning = show_warning
        try:
            return func(args)
        except WarpbwError as exc:
            print(f"{prog}: error: {exc}", file=sys.stderr)
            return EXIT_USER_ERROR
        except KeyboardInterrupt:
            print(f"{prog}: interrupted", file=sys.stderr)
            return 130
        except (OSError, MemoryError) as exc:
            print(f"{prog}: error: {exc}", file=sys.stderr)
            return EXIT_USER_ERROR
