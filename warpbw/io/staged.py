"""Output files that appear whole, or not at all.

Public: ``staged_outputs(paths)``.

Every writer of warpbw (images, records, plots, asset and cache files) writes to a temporary file beside its
output, and the outputs of one command are moved into place together once all of them are written.  So

* an interrupted or failed run (a full disk, a killed process, an error in a later writer) leaves every output
  as it was: no cut-off file, no new image beside an old record;
* an existing output is replaced, never written through: a hard link to it, or a symlink at its place, keeps
  the file it pointed at (``--force`` once rewrote a light probe hard-linked to ``-o``);
* two runs that write the same output at once do not write into one temporary file: each has its own
  (``mkstemp``, created exclusively, never through a link), and the last to finish wins whole.
"""
from __future__ import annotations

import os
import tempfile
from contextlib import contextmanager
from pathlib import Path

from warpbw.errors import WarpbwError

TEMP_PREFIX = "."   # hidden, so that a listing or a glob of the outputs does not show the temporaries


def _new_file_mode() -> int:
    """The mode a newly created file gets (0666 less the umask): mkstemp makes its file 0600."""
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


def _temp_beside(path: Path, mode: int) -> Path:
    """An empty temporary file in ``path``'s folder, with its suffix (writers that go by it still do)."""
    fd, name = tempfile.mkstemp(dir=path.parent, prefix=f"{TEMP_PREFIX}{path.stem}.", suffix=f".part{path.suffix}")
    os.close(fd)
    os.chmod(name, mode)
    return Path(name)


def _named(exc: BaseException, temps: dict) -> str:
    """``exc``'s message with each temporary file's name replaced by its output's."""
    msg = str(exc)
    for out, tmp in temps.items():
        msg = msg.replace(str(tmp), str(out))
    return msg


@contextmanager
def staged_outputs(paths):
    """Yield ``{output: temporary}`` for ``paths``; write each output to its temporary.  When the block ends
    without an error every temporary is moved onto its output (``os.replace``); on an error they are removed,
    no output is touched, and a ``WarpbwError`` or ``OSError`` raised in the block names the outputs, not the
    temporaries.  Missing folders are made."""
    outs = list(dict.fromkeys(Path(p) for p in paths))
    temps: dict = {}
    try:
        mode = _new_file_mode()
        for p in outs:
            try:
                p.parent.mkdir(parents=True, exist_ok=True)
                temps[p] = _temp_beside(p, mode)
            except OSError as exc:   # its folder under a file, or not writable: name the output
                raise WarpbwError(f"{p}: cannot write ({exc.strerror or exc})") from None
        yield dict(temps)
        for p in outs:
            os.replace(temps[p], p)
            del temps[p]
    except WarpbwError as exc:
        raise WarpbwError(_named(exc, temps)) from None
    except OSError as exc:   # a full disk, a folder that went read-only: name the output, not the temporary
        name = next((p for p, t in temps.items() if exc.filename in (str(t), t)),
                    exc.filename or ", ".join(map(str, outs)))
        raise WarpbwError(f"{name}: cannot write ({exc.strerror or exc})") from None
    finally:
        for tmp in temps.values():   # those not moved into place
            tmp.unlink(missing_ok=True)
