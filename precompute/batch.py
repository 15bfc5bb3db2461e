"""Tables of many tabulated BRDFs at once, as independent Dask tasks (DESIGN.md, "Scaling past one machine").

Public:
    ``TABLES`` (``"sampling"``, ``"bandwidth"``: what ``warpbw-precompute brdf-sampling`` and ``brdf`` write),
    ``BATCH_FORMAT`` (the record's format name), ``SCHEDULERS``, ``PR_SET_PDEATHSIG`` (the processes scheduler's
        workers are killed when the batch's process dies: ``run_batch``)
    ``BatchItem``   one BRDF: a MERL ``.binary`` file, or one material of an NPF table, and the name its outputs take
    ``batch_items(sources, materials=None) -> list[BatchItem]``   NPF tables (every material, or ``materials``), MERL
        files and folders of them, in the order given; refused before any work when a source is neither, when a
        material is unknown, or when two BRDFs would write the same file
    ``check_tables(tables) -> tuple``   some of ``TABLES``, each once
    ``output_paths(item, out_dir, tables) -> dict``   ``{table: out_dir / f"{item.name}.{table}.npz"}``
    ``check_outputs(items, out_dir, tables, force=False, resume=False)``   the refusals before any work
    ``build_item(item, outputs, threads=1, force=False, resume=False, lookup=None) -> dict``   one task: open the
        BRDF, build and write its tables (with ``resume``, keep each that reads back as this BRDF's and records the
        builder settings it would be built with now); never raises for a bad BRDF, its record says what went wrong
    ``run_batch(items, out_dir, tables=TABLES, scheduler="processes", workers=None, force=False, resume=False,
        progress=True, lookup=None) -> dict``   every item as one task on Dask's ``scheduler`` (``"processes"``,
        ``"threads"``, ``"sync"``, or anything ``dask.compute(scheduler=...)`` takes, such as a
        ``dask.distributed.Client``); the batch's record, one entry per item in the items' order

Each BRDF is one task: its tables are the ones the single-material commands write, bit for bit (the builders take
no seed and a table does not depend on how many threads built it), so a batch on a cluster and a loop on a laptop
give the same files.  The bandwidth tables are those of ``lookup`` (``"nearest"`` or ``"linear"``, what the
scenes' materials will shade with: ``brdf --lookup``), by default each kind's own (``brdf`` without ``--lookup``;
``precompute.brdf_sampling.TABLE_LOOKUP``: an NPF material's is then the table of ``lookup = "linear"``); the
sampling tables do not depend on it.  A BRDF that cannot be read does not stop the others: its record holds the error,
and the command exits 1 after the batch.  Dask is an optional dependency (``pip install -e ".[batch]"``).
"""
from __future__ import annotations

import contextlib
import os
import sys
import threading
import time
import warnings
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from functools import partial
from pathlib import Path

from precompute.assetfile import read_header, settings_mismatch
from warpbw.errors import WarpbwError, check_flag, check_instance, check_path

TABLES = ("sampling", "bandwidth")
BATCH_FORMAT = "warpbw-precompute-batch"
SCHEDULERS = ("processes", "threads", "sync")
MERL_SUFFIX = ".binary"
TABLE_SUFFIX = ".npz"


@dataclass(frozen=True)
class BatchItem:
    path: str                   # the MERL file or the NPF table
    material: str | None        # the NPF material; None for a MERL file
    name: str                   # what its outputs are named after: the material, or the MERL file's stem


def _folder_items(folder: Path) -> list:
    # hidden files are no BRDFs: a writer's temporary (npf-to-merl's .NAME.HOST-PID.RANDOM.part.binary, one a kill
    # left or one still being written) failed the batch, as would macOS's ._NAME.binary
    files = sorted(p for p in folder.iterdir()
                   if p.suffix.lower() == MERL_SUFFIX and not p.name.startswith(".") and p.is_file())
    if not files:
        raise WarpbwError(f"{folder}: a folder without MERL files (expected files ending in {MERL_SUFFIX})")
    return [BatchItem(str(p), None, p.stem) for p in files]


def batch_items(sources, materials=None) -> list:
    """The BRDFs of ``sources`` (NPF tables, MERL files, folders of MERL files: their hidden files skipped), in
    order; ``materials`` (names, or None for all 100) picks an NPF table's."""
    from warpbw.io.merl import MERL_FILE_SIZE
    from warpbw.io.npf import NPF_FILE_SIZE, NPF_MATERIAL_NAMES, read_npf

    sources = [sources] if isinstance(sources, (str, os.PathLike)) else list(sources)
    if not sources:
        raise WarpbwError("sources: expected at least one NPF table, MERL file or folder of MERL files")
    items, tables = [], 0
    for s in sources:
        p = check_path(s, "batch_items: sources")   # None or a number: pathlib's TypeError
        if p.is_dir():
            items += _folder_items(p)
        elif p.is_file() and p.stat().st_size == NPF_FILE_SIZE:
            tables += 1
            for m in NPF_MATERIAL_NAMES if materials is None else materials:
                name = read_npf(p, m).name    # refuses an unknown name (with close matches) or a damaged row
                items.append(BatchItem(str(p), name, name))
        elif p.is_file() and (p.suffix.lower() == MERL_SUFFIX or p.stat().st_size == MERL_FILE_SIZE):
            items.append(BatchItem(str(p), None, p.stem))
        elif not p.exists():
            raise WarpbwError(f"{p}: no such file or folder (expected an NPF table, a MERL {MERL_SUFFIX} file or "
                              "a folder of them)")
        else:
            raise WarpbwError(f"{p}: not an NPF table ({NPF_FILE_SIZE} bytes), a MERL file (a name ending in "
                              f"{MERL_SUFFIX}) or a folder of MERL files")
    if materials is not None and tables == 0:
        raise WarpbwError("materials: apply to NPF tables, and no source is one")
    seen = {}
    for it in items:
        other = seen.setdefault(it.name.lower(), it)   # case: one file on a case-insensitive file system
        if other is not it:
            what = (lambda i: f"{i.path}:{i.material}" if i.material else i.path)
            raise WarpbwError(f"{what(other)} and {what(it)} would both write the tables named {it.name!r} (a "
                              "material or file given twice, or two files of one name: batch them separately)")
    return items


def output_paths(item: BatchItem, out_dir, tables=TABLES) -> dict:
    check_instance(item, BatchItem, "output_paths: item", "a BatchItem (batch_items')")   # a path: AttributeError
    out_dir = check_path(out_dir, "output_paths: out_dir")
    return {t: out_dir / f"{item.name}.{t}{TABLE_SUFFIX}" for t in tables}


def check_tables(tables) -> tuple:
    """``tables`` as a tuple, each one of ``TABLES`` once; else a one-line error."""
    tables = tuple(tables)
    bad = [t for t in tables if t not in TABLES]
    if not tables or bad or len(set(tables)) != len(tables):
        raise WarpbwError(f"tables: expected some of {', '.join(TABLES)}, each once, got {', '.join(tables) or 'none'}")
    return tables


def check_outputs(items, out_dir, tables=TABLES, force: bool = False, resume: bool = False) -> None:
    """Before any work: the folder can hold the outputs, none of them is a source, and none exists unless ``force``
    (replace it) or ``resume`` (keep it if it is this BRDF's table, checked by its task)."""
    from warpbw.cli_common import check_output_dir, check_overwrite
    from warpbw.io.staged import output_exists

    force, resume = check_flag(force, "force"), check_flag(resume, "resume")   # force="no" replaced every table
    out_dir = check_path(out_dir, "out_dir")   # None or a number: pathlib's TypeError
    check_output_dir(out_dir, "-o")
    paths = [p for it in items for p in output_paths(it, out_dir, check_tables(tables)).values()]
    check_overwrite(paths, True, inputs=sorted({it.path for it in items}), inputs_are="a BRDF file of the batch")
    existing = [p for p in paths if output_exists(p)]
    if existing and not (force or resume):
        more = f" and {len(existing) - 1} more outputs" if len(existing) > 1 else ""
        raise WarpbwError(f"{existing[0]}{more}: already exist{'s' if not more else ''} (pass --resume to keep the "
                          "tables an earlier batch wrote and build the rest, or --force to replace them)")


def _kept(path: Path, kind: str, read, source, settings: dict, unrecorded: dict) -> tuple:
    """``(table, None)``: the ``kind`` table ``path`` holds, if ``read`` accepts it as ``source``'s and it records the
    builder settings the batch builds with now (``settings``; ``unrecorded`` for what older files leave out,
    ``precompute.assetfile.settings_mismatch``), an earlier batch's kept by ``--resume``; else ``(None, why)``, why
    being None where ``path`` does not exist."""
    if not path.exists():
        return None, None
    try:
        table = read(path, source)
    except WarpbwError:
        return None, _other_lookup(path, kind, source) or f"is not a {kind} table of {source.name}"
    other = settings_mismatch((read_header(path) or {}).get("params"), settings, unrecorded)
    if other is not None:   # a table of this BRDF, but not the one the batch builds now (another warpbw's constants)
        return None, f"is a {kind} table of {source.name} built with other settings ({other})"
    return table, None


def _other_lookup(path: Path, kind: str, source) -> str | None:
    """Why ``path``, refused as ``source``'s ``kind`` table, is kept by another ``--lookup``: it records one other than
    ``source``'s, and the content hash of ``source`` read with it (a batch run before with ``--lookup nearest``, resumed
    without it, was told the table "is not a bandwidth table" of its own BRDF); else None."""
    from precompute.brdf_sampling import digest_at, source_lookup
    from warpbw.scene import LOOKUP_MODES

    header = read_header(path) or {}
    params = header.get("params")
    got, want = params.get("lookup") if isinstance(params, dict) else None, source_lookup(source)
    if got not in LOOKUP_MODES or want is None or got == want or header.get("source_hash") != digest_at(source, got):
        return None
    return (f"is {source.name}'s {kind} table for the {got} lookup, not the {want} one this batch builds "
            f"(--lookup {got} keeps it)")


def build_item(item: BatchItem, outputs: dict, threads: int = 1, force: bool = False, resume: bool = False,
               lookup: str | None = None) -> dict:
    """One BRDF's task: its record ``{"name", "source", "outputs", "time_s", "kept", "nu_rho_max", "warnings",
    "error"}``; the tables not ``kept`` are built and written (``force``: over an existing file), the bandwidth
    table of the BRDF read with ``lookup`` (None: its kind's default)."""
    from precompute.brdf_bandwidth import (BANDWIDTH_UNRECORDED, bandwidth_settings, build_brdf_bandwidth,
                                           read_brdf_bandwidth, write_brdf_bandwidth)
    from precompute.brdf_sampling import (SAMPLING_UNRECORDED, brdf_source, build_brdf_sampling, read_sampling,
                                          sampling_settings, write_sampling)

    force, resume = check_flag(force, "force"), check_flag(resume, "resume")
    steps = {"sampling": (read_sampling, lambda s: build_brdf_sampling(s, progress=False), write_sampling,
                          sampling_settings(), SAMPLING_UNRECORDED),
             "bandwidth": (read_brdf_bandwidth, lambda s: build_brdf_bandwidth(s, progress=False, threads=threads),
                           write_brdf_bandwidth, bandwidth_settings(), BANDWIDTH_UNRECORDED)}
    record = {"name": item.name, "source": item.path, "material": item.material,
              "outputs": {t: str(p) for t, p in outputs.items()}, "time_s": {}, "kept": [], "nu_rho_max": None,
              "warnings": [], "error": None}
    with _task_warnings() as said:
        try:
            t0 = time.perf_counter()
            source = brdf_source(item.path, item.material, lookup)
            record["time_s"]["open"] = time.perf_counter() - t0
            for t, path in outputs.items():
                read, build, write, settings, unrecorded = steps[t]
                path = Path(path)
                t0 = time.perf_counter()
                table, why = _kept(path, t, read, source, settings, unrecorded) if resume else (None, None)
                if table is not None:
                    record["kept"].append(t)
                elif resume and path.exists() and not force:
                    raise WarpbwError(f"{path}: exists and {why} (pass --force as well to replace it)")
                else:
                    table = build(source)
                    write(path, table, source, force=force or resume)
                record["time_s"][t] = time.perf_counter() - t0
                if t == "bandwidth":
                    record["nu_rho_max"] = float(table.max())
        except WarpbwError as exc:
            record["error"] = str(exc)
    record["warnings"] = [str(w.message) for w in said]
    return record


_WARNINGS_LOCK = threading.Lock()
_TASKS: dict = {}    # thread id -> the warnings list of the task it runs, while tasks run (_task_warnings)
_TAKEN: list = []    # the catch_warnings that holds the process's warnings machinery while they run


@contextlib.contextmanager
def _task_warnings():
    """Yield the list of the warnings this task raises (each one: ``simplefilter("always")``).  Python's warnings
    machinery is the process's: ``catch_warnings(record=True)`` in tasks that ran at once on threads (the threads
    scheduler) each put back another's recorder and filters as it ended, and 35 of 60 two-BRDF batches left the
    process's warnings going to a finished task's list (never shown again) or shown always.  Here the first task to
    start takes the machinery and the last to end puts it back; a warning goes to the task of the thread that raised
    it, or, from a thread that runs none (a thread a task started), to every task running."""
    said: list = []
    me = threading.get_ident()
    with _WARNINGS_LOCK:
        if not _TASKS:
            taken = warnings.catch_warnings()
            taken.__enter__()
            warnings.simplefilter("always")
            warnings.showwarning = _show_to_tasks
            _TAKEN.append(taken)
        _TASKS[me] = said
    try:
        yield said
    finally:
        with _WARNINGS_LOCK:
            del _TASKS[me]
            if not _TASKS:
                _TAKEN.pop().__exit__(None, None, None)


def _show_to_tasks(message, category, filename, lineno, file=None, line=None) -> None:
    msg = warnings.WarningMessage(message, category, filename, lineno, file, line)
    own = _TASKS.get(threading.get_ident())
    for said in [own] if own is not None else list(_TASKS.values()):
        said.append(msg)


def _dask():
    try:
        import dask
    except ImportError:
        raise WarpbwError("the batch runs on Dask, which is not installed: pip install -e \".[batch]\" (or "
                          "pip install dask)") from None
    return dask


def _threads_per_task(scheduler, workers: int) -> int:
    """The bandwidth tables' threads in each task: the cores left to it by the other workers of this machine."""
    cores = os.cpu_count() or 1
    return max(1, cores // workers) if isinstance(scheduler, str) else 1


# prctl(2)'s option that gives a process a signal when its parent dies (Linux, <linux/prctl.h>)
PR_SET_PDEATHSIG = 1


def _end_with_the_batch(batch_pid: int) -> None:
    """Initialiser of the processes scheduler's workers: each is killed when the batch's process dies.  A batch killed
    with SIGKILL (kill -9, the OOM killer) left its workers running: they finished the BRDFs in flight, writing their
    tables up to a BRDF's build time (about 40 s here) after the command had ended, then stayed, idle, with about 90 MB
    each (session 78).  Killed with it, a worker leaves its temporaries as the batch's own process does, for the next
    run to remove.  Linux only (elsewhere nothing changes)."""
    import ctypes
    import signal

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
    except (OSError, AttributeError):   # no prctl: not Linux
        return
    if os.getppid() != batch_pid:   # the batch died before the signal was asked for
        os._exit(1)


def run_batch(items, out_dir, tables=TABLES, scheduler="processes", workers: int | None = None, force: bool = False,
              resume: bool = False, progress: bool = True, lookup: str | None = None) -> dict:
    """Build every item's tables into ``out_dir``, one Dask task per item, the bandwidth tables of ``lookup`` (module
    docstring); the batch's record."""
    from precompute.brdf_sampling import check_lookup
    from warpbw import __version__

    dask = _dask()
    force, resume = check_flag(force, "force"), check_flag(resume, "resume")
    progress = check_flag(progress, "progress")
    tables = check_tables(tables)
    check_lookup(lookup)   # before any work, as the other arguments (each task would record it as its error)
    if isinstance(scheduler, str) and scheduler not in SCHEDULERS:
        raise WarpbwError(f"scheduler: expected one of {', '.join(SCHEDULERS)} (or a Dask client), got {scheduler!r}")
    items = list(items)
    if not items:
        raise WarpbwError("items: expected at least one BRDF (batch_items gives them)")
    for it in items:   # a file name given for an item was an AttributeError from output_paths
        check_instance(it, BatchItem, "run_batch: items", "BatchItems (batch_items gives them from files)")
    out_dir = check_path(out_dir, "run_batch: out_dir")   # before the check that names it -o
    cores = os.cpu_count() or 1
    workers = min(cores, len(items)) if workers is None else workers
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise WarpbwError(f"workers: expected an integer >= 1, got {workers!r}")
    workers = 1 if scheduler == "sync" else workers if isinstance(scheduler, str) else None   # a client's own
    check_outputs(items, out_dir, tables, force=force, resume=resume)
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    threads = _threads_per_task(scheduler, workers or 1)
    tasks = [dask.delayed(build_item, pure=False)(it, output_paths(it, out_dir, tables), threads, force, resume,
                                                  lookup) for it in items]
    t0 = time.perf_counter()
    with _progress_bar(len(tasks), progress):
        kw = {"num_workers": workers} if isinstance(scheduler, str) else {}
        if scheduler == "processes":
            kw["chunksize"] = 1     # dask sends tasks to a worker process in chunks (of 6): one BRDF is work enough
            kw["initializer"] = partial(_end_with_the_batch, os.getpid())
        try:
            records = list(dask.compute(*tasks, scheduler=scheduler, **kw))
        except BrokenProcessPool:   # a traceback, no record, and the BRDFs in flight and to come abandoned
            raise WarpbwError(f"{out_dir}: a worker process of the batch ended abruptly (killed: the OOM killer, kill "
                              "-9) while it built a BRDF's tables; the batch stopped, the tables written so far are "
                              f"kept: run it again with --resume to build the rest{_script_hint()}") from None
    wall = time.perf_counter() - t0
    work = sum(sum(r["time_s"].values()) for r in records)
    return {"format": BATCH_FORMAT, "writer": f"warpbw {__version__}", "out_dir": str(out_dir),
            "tables": list(tables), "scheduler": scheduler if isinstance(scheduler, str) else
            getattr(scheduler, "__qualname__", None) or type(scheduler).__name__,   # a client: "Client"
            "workers": workers, "threads_per_task": threads, "lookup": lookup, "wall_s": wall, "work_s": work,
            "failed": sum(r["error"] is not None for r in records), "items": records}


def _script_hint() -> str:
    """What a Python script that called run_batch at its top level is told when the batch's worker processes fail:
    each imports the script again as it starts (multiprocessing's spawn), runs its run_batch, and is refused there
    ("An attempt has been made to start a new process before the current process has finished its bootstrapping
    phase"), which the batch then saw as workers that had ended abruptly (it said only "the OOM killer, kill -9").
    Nothing for the commands (``python -m precompute``, the console scripts) or an interactive session."""
    main = sys.modules.get("__main__")
    script = getattr(main, "__file__", None)
    if script is None or getattr(main, "__spec__", None) is not None or Path(script).name.startswith("warpbw"):
        return ""
    return (f" (or, from the Python script {Path(script).name}, the workers never started: each imports the script "
            "again, so call run_batch under `if __name__ == \"__main__\":`)")


class _progress_bar:
    """A tqdm bar over the batch's items, advanced by Dask's local schedulers as each item's task ends (a
    distributed client runs no such callback here: the bar then fills at the end)."""

    def __init__(self, total: int, enabled: bool):
        self.total, self.enabled = total, enabled

    def __enter__(self):
        if not self.enabled:
            return self
        from dask.callbacks import Callback
        from tqdm import tqdm

        from precompute.progress import bar_options

        self.bar = tqdm(total=self.total, desc="batch", unit="BRDF", **bar_options())

        def posttask(key, result, dsk, state, worker_id):
            if isinstance(result, dict) and "outputs" in result:   # an item's task, not dask's final tuple
                self.bar.update(1)

        self.callback = Callback(posttask=posttask)
        self.callback.__enter__()
        return self

    def __exit__(self, *exc):
        if self.enabled:
            self.callback.__exit__(*exc)
            if exc[0] is None:   # every item done (a distributed client's tasks ran no callback here)
                self.bar.update(self.total - self.bar.n)
            self.bar.close()
        return False
