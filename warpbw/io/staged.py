"""Output files that appear whole, or not at all.

Public: ``staged_outputs(paths, force=True)``; ``check_replaceable(path, force, inputs=(), inputs_are=...) -> Path``
(what every writer that takes ``force`` checks before its work), ``input_clash(path, inputs, inputs_are=...) ->
str | None``, ``output_exists(path)``, ``check_existing_output(path, force, label)``, ``check_name_length(path,
label)``, ``check_not_read_only(path, label)`` and ``dangling_link(path)`` (its parts the command lines share);
``check_still_free(path, force)`` (after the work, before a writer that checks again: an output that appeared
meanwhile); ``remove_stale_temps(path)`` (what the readers of a cache entry call: see below);
``temporary_folder(prefix, parent)`` (a work folder, removed at the end, whose name says its process: one a SIGKILL
left is removed by the next run that makes one of that prefix).

Every writer of warpbw (images, records, plots, asset and cache files) writes to a temporary file beside its
output, and the outputs of one command are moved into place together once all of them are written.  So

* an interrupted or failed run (a full disk, a killed process, an error in a later writer) leaves every output
  as it was: no cut-off file, no new image beside an old record.  A stop that arrives while the outputs are moved
  into place (Ctrl-C, SIGTERM, SIGHUP) is held until the last one is moved, then takes effect.  SIGKILL cannot be
  held, and leaves the hidden temporaries (``.NAME.HOST-PID.*.part.EXT`` beside each output); the next run that
  writes that output removes those whose process is gone from this machine, and so does the next run that reads a
  cache entry (:func:`remove_stale_temps`): where a run killed while it wrote an entry shared the cache with one
  that wrote it whole, no run writes that entry again;
* an existing output is replaced, never written through: a hard link to it, or a symlink at its place, keeps
  the file it pointed at (``--force`` once rewrote a light probe hard-linked to ``-o``);
* two runs that write the same output at once do not write into one temporary file: each has its own
  (``mkstemp``, created exclusively, never through a link), and move their sets into place one after the other (a
  ``flock`` on the outputs' folders while the moves run).  Without ``force``, an output that is there when the
  outputs are moved appeared while the run worked (the check before the work found none: another run finished
  first, or the user wrote it meanwhile): it is kept, and the run refused, no output of it moved.  With ``force``
  (``--force``, and caches, which two runs may write at once) the last to finish wins whole;
* a failed run removes the folders it made for its outputs (``-o new/sub/a.exr`` on a full disk left new/sub).

Before any work, :func:`check_replaceable` refuses an output that exists without ``force``, and whatever ``force``
says, one that is a file the writer reads (``npf_to_merl(T, m, T, force=True)`` replaced the NPF table it read) or
an existing read-only file (``chmod a-w`` is the user's "keep this"; a rename would replace it all the same).
"""
from __future__ import annotations

import hashlib
import os
import re
import shutil
import signal
import socket
import stat
import tempfile
import threading
from contextlib import contextmanager
from pathlib import Path

from warpbw.errors import WarpbwError, check_flag, check_path

TEMP_PREFIX = "."   # hidden, so that a listing or a glob of the outputs does not show the temporaries
MADE_FROM = "the file it is made from"   # what a library writer's ``inputs`` are, in its messages


def _same_file(a: Path, b: Path) -> bool:
    """``a`` and ``b`` name one file: the same path once links are resolved, or one inode (a hard link)."""
    if a.resolve() == b.resolve():
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:   # either is missing: not one file
        return False


def input_clash(path, inputs, inputs_are: str = MADE_FROM) -> str | None:
    """``"would overwrite INPUT, INPUTS_ARE"`` (and ``"(PATH is a link to it)"`` where it is one) when ``path`` is
    the same file as one of ``inputs`` (see :func:`_same_file`: a symlink or a hard link to it counts); else None."""
    p = check_path(path, "input_clash: path")
    f = next((q for q in (check_path(f, "input_clash: inputs") for f in inputs) if _same_file(p, q)), None)
    if f is None:
        return None
    # a symlink at the output, or another name for the input's inode (a hard link); the same file named relatively
    # or absolutely is no link
    linked = p.is_symlink() or p.resolve() != f.resolve()
    return f"would overwrite {f}, {inputs_are}" + (f" ({p} is a link to it)" if linked else "")


def check_not_read_only(path, label: str) -> None:
    """Refuse an existing file that is read-only: one that cannot be opened for writing (``chmod a-w`` for a user,
    ``chattr +i``), or has no write permission bit at all (``chmod 444``, which root could write all the same).
    ``label`` starts the message (the path, or the option and the path)."""
    p = check_path(path, "check_not_read_only: path")
    try:
        with open(p, "ab"):   # append mode: opened for writing, not one byte changed
            pass
    except OSError as exc:
        raise WarpbwError(f"{label}: cannot be overwritten ({exc.strerror or exc}; make it writable, or write "
                          "elsewhere)") from None
    mode = stat.S_IMODE(p.stat().st_mode)
    if not mode & 0o222:
        raise WarpbwError(f"{label}: cannot be overwritten (read-only, mode {mode:04o}; make it writable, or write "
                          "elsewhere)")


def output_exists(path) -> bool:
    """Whether an output's name is taken: by a file, or by a link, dangling or not (a dangling link is the user's
    too, and was replaced without a word)."""
    p = check_path(path, "output_exists: path")
    return p.exists() or p.is_symlink()


def dangling_link(path) -> str | None:
    """``"a link to TARGET, which does not exist"`` when ``path`` is a symbolic link to nothing, else None.  A folder
    cannot be made in its place (mkdir says "File exists"), nor a file written through it where its target's folder
    is missing: an output under one failed after the work, with "cannot write (File exists)"."""
    p = check_path(path, "dangling_link: path")
    try:
        if not p.is_symlink() or p.exists():
            return None
        target = os.readlink(p)
    except OSError:   # a name too long, a folder that cannot be read: not for this check to say
        return None
    return f"a link to {target}, which does not exist"


def check_existing_output(path, force: bool, label: str) -> None:
    """Refuse an output already there without ``force`` (a dangling link counts: it is the user's too, and was
    replaced without a word), and whatever ``force`` says one that is not a regular file (a FIFO blocked the run for
    ever, opened for writing; a device or a socket would be replaced by a file) or is read-only.  ``label`` starts
    the messages of the latter (the path, or the option and the path)."""
    p = check_path(path, "check_existing_output: path")
    if not output_exists(p):
        return
    if not force:
        raise WarpbwError(f"{p}: already exists (pass --force to overwrite it)")
    if not p.exists():
        return   # a dangling link: replaced by the file, as a link to a file is
    mode = p.stat().st_mode
    if not stat.S_ISREG(mode):
        kind = ("a FIFO" if stat.S_ISFIFO(mode) else "a socket" if stat.S_ISSOCK(mode)
                else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else "not a file")
        raise WarpbwError(f"{label}: is {kind}, not a regular file (expected a file to write or replace)")
    check_not_read_only(p, label)


def check_replaceable(path, force: bool, inputs=(), inputs_are: str = MADE_FROM) -> Path:
    """``path`` as a Path, once it may be written: a name its file system takes, not a directory, not one of
    ``inputs`` (whatever ``force`` says), not an existing file (or link) without ``force``, not an existing
    read-only file or one that is no regular file (:func:`check_existing_output`).  Writers call it before their
    work."""
    p = check_path(path, "output path")
    force = check_flag(force, "force")   # "no" is truthy: write_merl(force="no") replaced the file
    check_name_length(p, str(p))   # first: Python 3.11's is_dir raises on a name too long
    if p.is_dir():   # a temporary file would not replace a directory
        raise WarpbwError(f"{p}: is a directory (expected a file name)")
    clash = input_clash(p, inputs, inputs_are)
    if clash is not None:
        raise WarpbwError(f"{p}: {clash}")
    check_existing_output(p, force, str(p))
    return p


def _new_file_mode() -> int:
    """The mode a newly created file gets (0666 less the umask): mkstemp makes its file 0600.  The umask is read from
    /proc/self/status where Linux gives it (4.7 on): os.umask reads it only by setting another, and while it was 0 a
    file another thread created got mode 0666; two threads writing outputs at once (the batch's threads scheduler)
    could read 0 and leave the process's umask at 0 for good.  Elsewhere our own threads take turns."""
    umask = _umask_from_proc()
    if umask is None:
        with _UMASK_LOCK:
            umask = os.umask(0)
            os.umask(umask)
    return 0o666 & ~umask


_UMASK_LOCK = threading.Lock()


def _umask_from_proc() -> int | None:
    """The process's umask from /proc/self/status ("Umask:\t0022"), or None where it is not there."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    return None


def _host_tag() -> str:
    """This machine, as eight hex digits of a hash of its name (a folder may be shared between machines)."""
    return hashlib.sha1(socket.gethostname().encode()).hexdigest()[:8]


def _gone(pid: int) -> bool:
    """No process ``pid`` runs on this machine (one of another user's answers "not permitted": it runs)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except OSError:
        return False
    return False


# what _temp_beside puts between an output's stem and ".part": HOST-PID (its writer), then mkstemp's random name
_TEMP_WRITER = re.compile(r"(?P<host>[0-9a-f]{8})-(?P<pid>[0-9]+)\.[A-Za-z0-9_]+")
# the longest that part can be: 8 hex digits, "-", a pid (Linux's pid_max is at most 2^22: 7 digits; 10 allow
# any 32-bit one), ".", mkstemp's 8 random characters
_TEMP_WRITER_MAX = 8 + 1 + 10 + 1 + 8
NAME_MAX_DEFAULT = 255   # bytes in a file name on Linux's and macOS's file systems, where pathconf cannot say
PATH_MAX_DEFAULT = 4096   # bytes in a path, its final NUL included, on Linux (limits.h), where pathconf cannot say
# what a temporary's path adds to its output's at most: the prefix, ".", the writer's part and ".part"
_TEMP_PATH_EXTRA = len(TEMP_PREFIX) + 1 + _TEMP_WRITER_MAX + len(".part")


def _name_max(folder: Path) -> int:
    """The longest file name, in bytes, that ``folder``'s file system takes."""
    try:
        return int(os.pathconf(folder, "PC_NAME_MAX"))
    except (OSError, ValueError, AttributeError):   # a folder not made yet, or no pathconf (Windows)
        return NAME_MAX_DEFAULT


def _is_dir(p: Path) -> bool:
    try:
        return p.is_dir()
    except OSError:   # a name too long (Python 3.11 raises where 3.12 answers False)
        return False


def _path_max(folder: Path) -> int:
    """The longest path, in bytes with its final NUL, that the system takes in ``folder``'s file system."""
    try:
        return int(os.pathconf(folder, "PC_PATH_MAX"))
    except (OSError, ValueError, AttributeError):
        return PATH_MAX_DEFAULT


def check_name_length(path, label: str) -> None:
    """Refuse, before any work, a path whose name, or the name of a folder on its way, is longer than its file
    system takes, or that is longer as a whole (with its temporary's additions) than the system takes (the run
    failed at its end, with "File name too long"; an input or a folder, with Python's bare "[Errno 36]")."""
    p = check_path(path, "check_name_length: path")
    folder = next((q for q in (p.parent, *p.parent.parents) if _is_dir(q)), Path("."))
    limit = _name_max(folder)
    for part in p.parts:
        n = len(os.fsencode(part))
        if n > limit:
            what = "file name" if part == p.name else f"folder name {part[:16]}..."
            raise WarpbwError(f"{label}: a {what} of {n} bytes, longer than the file system takes ({limit}); "
                              "expected a shorter name")
    n, room = len(os.fsencode(str(p))), _path_max(folder) - 1 - _TEMP_PATH_EXTRA
    if n > room:
        raise WarpbwError(f"{label}: a path of {n} bytes, longer than the system takes ({room}, with room for a "
                          "temporary file's name); expected a shorter path")


def _temp_stem(path: Path) -> str:
    """``path``'s stem, cut so that a temporary's name ``.STEM.HOST-PID.RANDOM.part.EXT`` fits the file system: an
    output name of 225 bytes and more failed after the work (the temporary is about 30 bytes longer)."""
    room = (_name_max(path.parent) - len(os.fsencode(TEMP_PREFIX + "." + ".part" + path.suffix))
            - _TEMP_WRITER_MAX)
    stem = os.fsencode(path.stem)
    return path.stem if len(stem) <= room else stem[:max(room, 1)].decode("utf-8", "ignore")   # a cut character goes


def remove_stale_temps(path) -> None:
    """Remove the temporaries of ``path`` that a process of this machine, since gone, left (SIGKILL, the OOM killer,
    a power cut).  Another machine's, a live process's and any other file are left alone."""
    path = check_path(path, "remove_stale_temps: path")
    head, tail = f"{TEMP_PREFIX}{_temp_stem(path)}.", f".part{path.suffix}"
    try:
        names = [q for q in path.parent.iterdir() if q.name.startswith(head) and q.name.endswith(tail)]
    except OSError:   # a folder that cannot be listed: nothing to tidy
        return
    host = _host_tag()
    for q in names:
        m = _TEMP_WRITER.fullmatch(q.name[len(head):len(q.name) - len(tail)])
        if m and m["host"] == host and _gone(int(m["pid"])):
            try:
                q.unlink()
            except OSError:   # tidied by another run first, or not ours to delete: no reason to refuse the output
                pass


@contextmanager
def temporary_folder(prefix: str, parent=None):
    """Yield a new folder ``PREFIXHOST-PID.XXXXXXXX`` in ``parent`` (the system's temporary folder when None), and
    remove it with what it holds at the end.  ``tempfile.TemporaryDirectory`` folders that a SIGKILL left stayed for
    good (the filtering benchmark's GMM mipmaps, megabytes each); these are named after their writer, as
    :func:`remove_stale_temps`'s files, and each call first removes the folders of ``prefix`` in ``parent`` whose
    process of this machine is gone.  Another machine's, a live process's and any other entry are left alone."""
    parent = Path(tempfile.gettempdir()) if parent is None else check_path(parent, "temporary_folder: parent")
    host = _host_tag()
    try:
        names = [q for q in parent.iterdir() if q.name.startswith(prefix)]
    except OSError:   # a folder that cannot be listed: nothing to tidy (mkdtemp says why it cannot make one)
        names = []
    for q in names:
        m = _TEMP_WRITER.fullmatch(q.name[len(prefix):])
        if m and m["host"] == host and _gone(int(m["pid"])) and q.is_dir() and not q.is_symlink():
            shutil.rmtree(q, ignore_errors=True)   # not ours to delete, or tidied by another run first: no matter
    folder = Path(tempfile.mkdtemp(prefix=f"{prefix}{host}-{os.getpid()}.", dir=parent))
    try:
        yield folder
    finally:
        shutil.rmtree(folder, ignore_errors=True)   # what is left (a file still open elsewhere) goes with the next run


def _temp_beside(path: Path, mode: int) -> Path:
    """An empty temporary file in ``path``'s folder, with its suffix (writers that go by it still do), named after
    its writer (``HOST-PID``, :data:`_TEMP_WRITER`) so that a later run can tell when it was left behind."""
    prefix = f"{TEMP_PREFIX}{_temp_stem(path)}.{_host_tag()}-{os.getpid()}."
    fd, name = tempfile.mkstemp(dir=path.parent, prefix=prefix, suffix=f".part{path.suffix}")
    os.close(fd)
    os.chmod(name, mode)
    return Path(name)


def _named(exc: BaseException, temps: dict) -> str:
    """``exc``'s message with each temporary file's name replaced by its output's."""
    msg = str(exc)
    for out, tmp in temps.items():
        msg = msg.replace(str(tmp), str(out))
    return msg


# the stops a user or a scheduler sends (Ctrl-C, kill, a closed terminal); SIGKILL cannot be held
HELD_SIGNALS = tuple(getattr(signal, n) for n in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, n))


@contextmanager
def _signals_held():
    """While the block runs, the signals of ``HELD_SIGNALS`` are recorded instead of handled; when it ends each one
    recorded is raised again, under the handler it found (an ignored one stays ignored).  Outside the main thread,
    where Python sets no handler, nothing is held."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught = []
    # None: a handler not set from Python, which Python cannot put back
    held = {sig: h for sig in HELD_SIGNALS if (h := signal.getsignal(sig)) is not None}
    for sig in held:
        signal.signal(sig, lambda signum, frame: caught.append(signum))
    try:
        yield
    finally:
        for sig, handler in held.items():
            signal.signal(sig, handler)
        for sig in dict.fromkeys(caught):
            signal.raise_signal(sig)


# The longest a run waits for another's lock on an output folder (another run holds it for the microseconds of its
# moves; a lock some other program keeps on the folder must not hold a Ctrl-C, held while the moves run, for ever)
FOLDER_LOCK_WAIT_S = 10.0


def _flock_within(fd: int, wait_s: float) -> bool:
    """An exclusive ``flock`` on ``fd``, waited for at most ``wait_s`` seconds; whether it was taken (never where
    the system has no ``fcntl``)."""
    import time

    try:
        import fcntl
    except ImportError:   # Windows
        return False

    end = time.monotonic() + wait_s
    while True:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return True
        except BlockingIOError:
            if time.monotonic() >= end:
                return False
            time.sleep(0.001)
        except OSError:   # a file system without locks
            return False


@contextmanager
def _folders_locked(folders):
    """While the block runs, hold an exclusive ``flock`` on each of ``folders`` (taken in sorted order: two runs wait
    for each other, never for ever), so that two runs moving outputs into one folder move them one set after the
    other.  A folder that cannot be opened or locked (no ``fcntl``: Windows; a file system without locks; a lock held
    past ``FOLDER_LOCK_WAIT_S``) is moved into without one, as before."""
    fds = []
    try:
        for folder in sorted({str(f) for f in folders}):
            try:
                fd = os.open(folder, os.O_RDONLY)
            except OSError:
                continue
            if _flock_within(fd, FOLDER_LOCK_WAIT_S):
                fds.append(fd)
            else:
                os.close(fd)
        yield
    finally:
        for fd in fds:
            os.close(fd)   # which releases its lock


def _appeared(p: Path) -> WarpbwError:
    return WarpbwError(f"{p}: already exists: it appeared while this run worked (another run writing it, or you), "
                       "and is kept; nothing of this run was written (pass --force to overwrite it)")


def check_still_free(path, force: bool) -> None:
    """Without ``force``, refuse ``path`` if it is there now, once the work is done, where a check before the work
    found none: it appeared meanwhile (:func:`_appeared`).  For a command that hands its output to a writer that
    checks it again (``check_replaceable``, whose "already exists (pass --force ...)" read as if the user had named
    a file of theirs: two ``warpbw-precompute brdf`` of one output at once, session 79)."""
    path = check_path(path, "check_still_free: path")
    if not check_flag(force, "force") and output_exists(path):
        raise _appeared(Path(path))


def _move_new(tmp: Path, p: Path) -> None:
    """Move ``tmp`` to the name ``p``, which must stay free: a hard link made only where no file (or link) is, then
    the temporary's name removed; ``FileExistsError`` when the name was taken.  Where the file system makes no hard
    links, a check and a rename (the race is then back, for microseconds)."""
    try:
        os.link(tmp, p, follow_symlinks=False)
    except FileExistsError:
        raise
    except OSError:   # no hard links here (FAT, some network file systems)
        if output_exists(p):
            raise FileExistsError(p) from None
        os.replace(tmp, p)
        return
    tmp.unlink()


def _missing_folders(folder: Path) -> list:
    """The folders on the way to ``folder`` (itself included) that do not exist, deepest first."""
    missing = []
    for q in (folder, *folder.parents):
        if _is_dir(q) or q.exists():
            break
        missing.append(q)
    return missing


@contextmanager
def staged_outputs(paths, force: bool = True):
    """Yield ``{output: temporary}`` for ``paths``; write each output to its temporary.  When the block ends
    without an error every temporary is moved onto its output (``os.replace``); on an error they are removed,
    no output is touched, and a ``WarpbwError`` or ``OSError`` raised in the block names the outputs, not the
    temporaries.  Missing folders are made, and removed again when nothing was moved into them.  Without ``force``
    (the caller refused existing outputs before its work) an output that is there at the moves appeared meanwhile:
    it is refused (``_appeared``), and nothing moved; each move then takes a name that is free, or fails."""
    outs = list(dict.fromkeys(check_path(p, "staged_outputs: paths") for p in paths))
    move = os.replace if check_flag(force, "force") else _move_new
    temps: dict = {}
    made: list = []
    try:
        mode = _new_file_mode()
        for p in outs:
            try:
                missing = _missing_folders(p.parent)
                p.parent.mkdir(parents=True, exist_ok=True)
                made.extend(q for q in missing if q not in made)
                remove_stale_temps(p)
                temps[p] = _temp_beside(p, mode)
            except OSError as exc:   # its folder under a file, or not writable: name the output (and the file)
                # "File exists" said: a file on the way, or a link to nothing
                under = next((q for q in p.parents if dangling_link(q) or (q.exists() and not q.is_dir())), None)
                why = (exc.strerror or exc if under is None else f"{under} is {dangling_link(under)}"
                       if dangling_link(under) else f"{under} is not a directory")
                raise WarpbwError(f"{p}: cannot write ({why})") from None
        yield dict(temps)
        # a Ctrl-C between two moves left a new image beside an old record; two --force runs of one set that finished
        # together moved their files in turns, the second's image beside the first's record
        with _signals_held(), _folders_locked(p.parent for p in outs):
            moved = []
            for p in outs:
                try:
                    move(temps[p], p)
                except FileExistsError:   # without force: the name was taken meanwhile; the new names made go
                    for q in moved:
                        q.unlink(missing_ok=True)
                    raise _appeared(p) from None
                moved.append(p)
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
        for q in sorted(made, key=lambda q: len(q.parts), reverse=True):   # those left empty: a failed run's
            try:
                q.rmdir()
            except OSError:   # holds an output, or a file someone else put there meanwhile
                pass
