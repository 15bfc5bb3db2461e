"""warpbw-precompute batch (precompute.batch): many BRDFs' tables as Dask tasks.

Truth: the single-material commands' files (a batch must write the same bytes), the tables' own readers (a kept or
written table reads back as its BRDF's), and the record against what is on disk."""
from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import fake_npf_table, outcome, shared_file

pytest.importorskip("dask", reason="the batch runs on Dask: pip install -e '.[batch]'")


def _merl(path, value=0.3):
    """A Lambertian MERL file (every entry ``value``)."""
    from warpbw.io.merl import MERL_SHAPE, write_merl

    write_merl(path, np.full(MERL_SHAPE, value))
    return path


def _batch(*args):
    from precompute.__main__ import main

    return outcome(main, ["batch", *args, "-q"])


def _single(cmd, src, material, out, *more):
    from precompute.__main__ import main

    extra = (["--material", material] if material else []) + list(more)
    assert outcome(main, [cmd, str(src), *extra, "-o", str(out), "-q"]) == "returned 0"
    return out.read_bytes()


def test_a_batch_writes_the_single_commands_files_byte_for_byte(tmp_path, monkeypatch):
    """Two BRDFs (a real NPF material and a MERL file) on the processes scheduler, two workers: each table is the
    file warpbw-precompute brdf-sampling / brdf writes for it, byte for byte, and the record says so."""
    npf = shared_file("brdf/npf.bin")
    monkeypatch.chdir(tmp_path)
    merl = _merl(tmp_path / "grey.binary")
    assert _batch(str(npf), str(merl), "--materials", "pink-felt", "-o", "out", "--workers", "2") == "returned 0"
    for name, src, material in (("pink-felt", npf, "pink-felt"), ("grey", merl, None)):
        assert (tmp_path / f"out/{name}.sampling.npz").read_bytes() == \
            _single("brdf-sampling", src, material, tmp_path / f"{name}.s.npz"), name
        assert (tmp_path / f"out/{name}.bandwidth.npz").read_bytes() == \
            _single("brdf", src, material, tmp_path / f"{name}.b.npz"), name
    record = json.loads((tmp_path / "out/batch.json").read_text())
    assert [r["name"] for r in record["items"]] == ["pink-felt", "grey"]
    assert record["scheduler"] == "processes" and record["workers"] == 2 and record["failed"] == 0
    from precompute.brdf_bandwidth import read_brdf_bandwidth

    for r in record["items"]:
        assert r["error"] is None and r["kept"] == [] and set(r["time_s"]) == {"open", "sampling", "bandwidth"}
        assert r["nu_rho_max"] == float(read_brdf_bandwidth(r["outputs"]["bandwidth"]).max())


def test_every_npf_material_by_default_and_the_threads_scheduler_agrees(tmp_path, monkeypatch):
    """Without --materials an NPF table gives its 100 materials, named as the table names them, in its order; the
    threads scheduler writes the bytes the one-material command writes (sampling tables of a stand-in table whose
    rows are all alike: the files still differ by their material's name and digest; the sync scheduler's are held
    to the same bytes in the test of a caller's own scheduler)."""
    scheduler = "threads"
    from precompute.batch import batch_items
    from warpbw.io.npf import NPF_MATERIAL_NAMES

    monkeypatch.chdir(tmp_path)
    npf = fake_npf_table(tmp_path / "npf.bin")
    items = batch_items([npf])
    assert [i.name for i in items] == list(NPF_MATERIAL_NAMES)
    assert {i.material for i in items} == set(NPF_MATERIAL_NAMES)
    assert _batch("npf.bin", "--materials", "Chrome,nickel.binary", "--tables", "sampling", "-o", "out",
                  "--scheduler", scheduler) == "returned 0"
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["batch.json", "chrome.sampling.npz",
                                                                     "nickel.sampling.npz"]
    for m in ("chrome", "nickel"):
        assert (tmp_path / f"out/{m}.sampling.npz").read_bytes() == \
            _single("brdf-sampling", npf, m, tmp_path / f"{m}.npz")


def test_lookup_gives_the_bandwidth_table_brdf_writes_with_it_and_leaves_the_sampling_table(tmp_path, monkeypatch):
    """--lookup nearest: an NPF material's bandwidth file is the one ``brdf --lookup nearest`` writes, byte for byte
    (the table of the BRDF a scene's default lookup shades, which the renderer asks for), its sampling file the one
    ``brdf-sampling`` writes (no lookup), and the record names the lookup; an unknown lookup is refused."""
    from precompute.batch import batch_items, run_batch
    from precompute.brdf_bandwidth import read_brdf_bandwidth
    from precompute.brdf_sampling import brdf_source
    from warpbw.errors import WarpbwError

    monkeypatch.chdir(tmp_path)
    fake_npf_table(tmp_path / "npf.bin")
    assert _batch("npf.bin", "--materials", "chrome", "--lookup", "nearest", "-o", "out", "--scheduler",
                  "sync") == "returned 0"
    assert (tmp_path / "out/chrome.bandwidth.npz").read_bytes() == \
        _single("brdf", "npf.bin", "chrome", tmp_path / "b.npz", "--lookup", "nearest")
    assert (tmp_path / "out/chrome.sampling.npz").read_bytes() == \
        _single("brdf-sampling", "npf.bin", "chrome", tmp_path / "s.npz")
    read_brdf_bandwidth(tmp_path / "out/chrome.bandwidth.npz", brdf_source("npf.bin", "chrome", "nearest"))
    assert json.loads((tmp_path / "out/batch.json").read_text())["lookup"] == "nearest"
    with pytest.raises(WarpbwError, match="lookup: expected one of nearest, linear"):
        run_batch(batch_items("npf.bin", ["chrome"]), tmp_path / "out2", scheduler="sync", lookup="cubic")
    assert not (tmp_path / "out2").exists()


def test_a_brdf_that_cannot_be_read_fails_alone(tmp_path, monkeypatch, capsys):
    """A damaged MERL file among good BRDFs: its error is printed and recorded, naming the file, the others' tables
    are written, and the command exits 1 after the batch (a traceback used to end a loop over materials)."""
    monkeypatch.chdir(tmp_path)
    fake_npf_table(tmp_path / "npf.bin")
    _merl(tmp_path / "fine.binary")
    with open(tmp_path / "black.binary", "wb") as f:      # the right size, no positive entry: read_merl refuses it
        f.write(np.array([90, 90, 180], "<i4").tobytes())
        np.zeros(90 * 90 * 180 * 3, "<f8").tofile(f)
    r = _batch("npf.bin", "black.binary", "fine.binary", "--materials", "chrome", "--tables", "sampling", "-o", "out",
               "--scheduler", "sync")
    assert r == "returned 1", r
    err = capsys.readouterr().err
    assert "error: black: " in err and "black.binary: no positive MERL entry" in err, err
    assert (tmp_path / "out/chrome.sampling.npz").exists() and (tmp_path / "out/fine.sampling.npz").exists()
    assert not (tmp_path / "out/black.sampling.npz").exists()
    record = json.loads((tmp_path / "out/batch.json").read_text())
    assert record["failed"] == 1
    assert [r["error"] is None for r in record["items"]] == [True, False, True]


def test_a_folders_hidden_files_are_no_brdfs(tmp_path):
    """A folder of MERL files held the hidden temporary of an ``npf-to-merl`` killed while it wrote there (or still
    writing: ``.chrome.HOST-PID.RANDOM.part.binary``): ``batch FOLDER`` took it for a BRDF, failed it ("expected
    34992012 bytes") and exited 1 (processes audit, session 79); a macOS "._grey.binary" would have too.  A folder's
    hidden files are skipped; one named on the command line is read as any file."""
    from precompute.batch import batch_items

    merls = tmp_path / "merls"
    merls.mkdir()
    _merl(merls / "grey.binary")
    (merls / ".grey.1a2b3c4d-4242.abcdefgh.part.binary").write_bytes(b"cut off")
    (merls / "._grey.binary").write_bytes(b"AppleDouble")
    assert [(it.name, it.path) for it in batch_items([merls])] == [("grey", str(merls / "grey.binary"))]
    hidden = merls / ".hidden.binary"
    _merl(hidden)
    assert [it.name for it in batch_items([hidden])] == [".hidden"]


def test_resume_keeps_this_brdfs_tables_builds_the_rest_and_refuses_a_stranger(tmp_path, monkeypatch, capsys):
    """A stopped batch goes on with --resume: a table that reads back as its BRDF's is kept (its bytes and time
    untouched), a missing one is built; a file in its place that is another BRDF's table is refused, and replaced
    only with --force as well.  Without either, the existing outputs are refused before any work."""
    from precompute.batch import BatchItem, output_paths

    monkeypatch.chdir(tmp_path)
    fake_npf_table(tmp_path / "npf.bin")
    args = ["npf.bin", "--materials", "chrome,nickel", "--tables", "sampling", "-o", "out", "--scheduler", "sync"]
    assert _batch(*args) == "returned 0"
    chrome, nickel = (tmp_path / "out/chrome.sampling.npz"), (tmp_path / "out/nickel.sampling.npz")
    assert chrome == tmp_path / output_paths(BatchItem("npf.bin", "chrome", "chrome"), "out", ("sampling",))["sampling"]
    before = chrome.read_bytes(), chrome.stat().st_mtime_ns
    nickel_bytes = nickel.read_bytes()
    nickel.unlink()
    capsys.readouterr()
    assert _batch(*args) == "returned 2"
    assert "error: out/chrome.sampling.npz: already exists (pass --resume to keep the tables an earlier batch " \
        "wrote and build the rest, or --force to replace them)" in capsys.readouterr().err
    assert _batch(*args, "--resume") == "returned 0"
    record = json.loads((tmp_path / "out/batch.json").read_text())
    assert [r["kept"] for r in record["items"]] == [["sampling"], []]
    assert (chrome.read_bytes(), chrome.stat().st_mtime_ns) == before and nickel.read_bytes() == nickel_bytes

    nickel.write_bytes(chrome.read_bytes())          # chrome's table in nickel's place
    assert _batch(*args, "--resume") == "returned 1"
    assert "out/nickel.sampling.npz: exists and is not a sampling table of npf.bin:nickel" in capsys.readouterr().err
    assert nickel.read_bytes() == chrome.read_bytes()
    assert _batch(*args, "--resume", "--force") == "returned 0"
    assert nickel.read_bytes() == nickel_bytes


def test_resume_refuses_this_brdfs_table_of_other_builder_settings(tmp_path, monkeypatch, capsys):
    """--resume kept any file that read back as its BRDF's table, also one built with other builder settings (an
    older warpbw whose constants changed without a version bump), so a resumed batch mixed two builders' tables.
    Such a file is refused, naming the setting, and replaced with --force as well; one whose header records the
    same settings is kept."""
    from precompute.assetfile import read_asset, read_header, write_asset

    monkeypatch.chdir(tmp_path)
    fake_npf_table(tmp_path / "npf.bin")
    args = ["npf.bin", "--materials", "chrome", "--tables", "sampling", "-o", "out", "--scheduler", "sync"]
    assert _batch(*args) == "returned 0"
    chrome = tmp_path / "out/chrome.sampling.npz"
    fresh = chrome.read_bytes()
    h = read_header(chrome)
    a = read_asset(chrome, h["format"], h["version"], "rebuild")
    write_asset(chrome, h["format"], h["version"], h["source"], h["source_hash"], a.arrays,
                params={**h["params"], "view_subsamples": h["params"]["view_subsamples"] + 1}, force=True)
    other = chrome.read_bytes()
    capsys.readouterr()
    assert _batch(*args, "--resume") == "returned 1"
    err = capsys.readouterr().err
    assert "out/chrome.sampling.npz: exists and is a sampling table of npf.bin:chrome built with other settings " \
        f"(view_subsamples {h['params']['view_subsamples'] + 1}, the builder's {h['params']['view_subsamples']}) " \
        "(pass --force as well to replace it)" in err, err
    assert chrome.read_bytes() == other
    assert _batch(*args, "--resume", "--force") == "returned 0"
    assert chrome.read_bytes() == fresh
    assert _batch(*args, "--resume") == "returned 0"
    record = json.loads((tmp_path / "out/batch.json").read_text())
    assert record["items"][0]["kept"] == ["sampling"] and chrome.read_bytes() == fresh


def test_resume_names_the_lookup_that_keeps_a_bandwidth_table_built_for_another(tmp_path, monkeypatch, capsys):
    """A batch run with --lookup nearest and resumed without it (an NPF fit's default lookup is linear) refused each
    bandwidth table as "not a bandwidth table of npf.bin:chrome", its own BRDF's (session 76's audit): the refusal
    names the lookup the table was built for and the option that keeps it, and with that option it is kept.  Another
    material's table in its place is still "not a bandwidth table" of this one, whatever its lookup.  (The tables
    are a stand-in's: the sync scheduler runs the tasks in this process.)"""
    import precompute.brdf_bandwidth as bb

    monkeypatch.setattr(bb, "build_brdf_bandwidth",
                        lambda source, progress=True, threads=1: np.full((16, 16, 16), 1.0, np.float32))
    monkeypatch.chdir(tmp_path)
    fake_npf_table(tmp_path / "npf.bin")
    args = ["npf.bin", "--materials", "chrome,nickel", "--tables", "bandwidth", "-o", "out", "--scheduler", "sync"]
    assert _batch(*args, "--lookup", "nearest") == "returned 0"
    capsys.readouterr()
    assert _batch(*args, "--resume") == "returned 1"
    err = capsys.readouterr().err
    for m in ("chrome", "nickel"):
        assert (f"out/{m}.bandwidth.npz: exists and is npf.bin:{m}'s bandwidth table for the nearest lookup, not the "
                "linear one this batch builds (--lookup nearest keeps it) (pass --force as well to replace it)") in err
    assert _batch(*args, "--resume", "--lookup", "nearest") == "returned 0"
    record = json.loads((tmp_path / "out/batch.json").read_text())
    assert [r["kept"] for r in record["items"]] == [["bandwidth"], ["bandwidth"]]

    chrome, nickel = tmp_path / "out/chrome.bandwidth.npz", tmp_path / "out/nickel.bandwidth.npz"
    chrome.write_bytes(nickel.read_bytes())          # nickel's table (nearest lookup) in chrome's place
    for more in ((), ("--lookup", "nearest")):
        capsys.readouterr()
        assert _batch(*args, "--resume", *more) == "returned 1"
        err = capsys.readouterr().err
        (line,) = [ln for ln in err.splitlines() if "out/chrome." in ln]
        assert "out/chrome.bandwidth.npz: exists and is not a bandwidth table of npf.bin:chrome" in line, line
        assert line.endswith(" (pass --force as well to replace it)") and "keeps it" not in line, line


def test_a_progress_bar_over_the_brdfs(tmp_path, monkeypatch, tqdm_bars):
    """One bar, one step per BRDF (not per Dask task: dask's own final task is not a BRDF); none with -q.  The
    tables are a stand-in's (the sync scheduler runs the tasks in this process), a uniform one."""
    import precompute.brdf_sampling as bs
    from conftest import uniform_sampler_table
    from precompute.__main__ import main

    monkeypatch.setattr(bs, "build_brdf_sampling", lambda source, progress=True: uniform_sampler_table())
    monkeypatch.chdir(tmp_path)
    fake_npf_table(tmp_path / "npf.bin")
    args = ["batch", "npf.bin", "--materials", "chrome,nickel,steel", "--tables", "sampling", "--scheduler", "sync"]
    assert outcome(main, [*args, "-o", "a", "-q"]) == "returned 0" and tqdm_bars == []
    assert outcome(main, [*args, "-o", "b"]) == "returned 0"
    assert [(b.desc, b.total, b.n) for b in tqdm_bars] == [("batch", 3, 3)]


def test_a_scheduler_of_the_callers_own_runs_the_same_tasks(tmp_path, monkeypatch, tqdm_bars):
    """``run_batch(scheduler=...)`` takes what ``dask.compute`` takes (a ``dask.distributed.Client``, here dask's own
    synchronous ``get``): the same files as the sync scheduler (and it as the single command), the record names it
    and claims no worker count of this machine, and the bar is full at the end."""
    import dask

    from precompute.batch import batch_items, run_batch

    monkeypatch.chdir(tmp_path)
    fake_npf_table(tmp_path / "npf.bin")
    items = batch_items(["npf.bin"], ["chrome", "steel"])
    own = run_batch(items, "own", tables=("sampling",), scheduler=dask.get)
    sync = run_batch(items, "sync", tables=("sampling",), scheduler="sync", progress=False)
    assert (own["scheduler"], own["workers"], sync["workers"]) == (dask.get.__qualname__, None, 1)
    for m in ("chrome", "steel"):
        assert (tmp_path / f"own/{m}.sampling.npz").read_bytes() == (tmp_path / f"sync/{m}.sampling.npz").read_bytes()
    assert (tmp_path / "sync/chrome.sampling.npz").read_bytes() == \
        _single("brdf-sampling", "npf.bin", "chrome", tmp_path / "chrome.npz")
    assert [(b.total, b.n) for b in tqdm_bars] == [(2, 2)]


def test_a_record_that_appears_while_the_batch_works_is_kept_not_replaced(tmp_path, monkeypatch, capsys):
    """Two batches writing one folder at once (session 78): the one that ended second replaced the first one's
    record without a word (write_json's default force), while README says an output that appears while a command
    works is kept and the command ends with an error.  Now the record that appeared is kept, byte for byte, the
    command says so in one line (its tables are written, its record is not) and exits 2; --force still replaces it,
    and --resume still replaces the record that was there before it started."""
    import precompute.batch as batch

    monkeypatch.chdir(tmp_path)
    fake_npf_table(tmp_path / "npf.bin")
    real = batch.run_batch
    other = b'{"format": "warpbw-precompute-batch", "items": []}\n'   # the other batch's record, written meanwhile

    def meanwhile(items, out_dir, *args, **kwargs):
        record = real(items, out_dir, *args, **kwargs)
        (tmp_path / "out/batch.json").write_bytes(other)
        return record

    monkeypatch.setattr(batch, "run_batch", meanwhile)
    r = _batch("npf.bin", "--materials", "chrome", "--tables", "sampling", "-o", "out", "--scheduler", "sync")
    err = capsys.readouterr().err
    assert r == "returned 2", r
    assert "out/batch.json: already exists: it appeared while this batch worked" in err, err
    assert len(err.strip().splitlines()) == 1 and "its tables are written, its record is not" in err, err
    assert (tmp_path / "out/batch.json").read_bytes() == other
    assert (tmp_path / "out/chrome.sampling.npz").exists()
    # --resume: the record there before it started is its own to replace; one that appears meanwhile is kept
    r = _batch("npf.bin", "--materials", "chrome", "--tables", "sampling", "-o", "out", "--scheduler", "sync",
               "--resume")
    assert r == "returned 0", r
    assert json.loads((tmp_path / "out/batch.json").read_text())["items"][0]["kept"] == ["sampling"]
    # --resume where no record was there before it started (mutation round 12): the one that appears is kept
    (tmp_path / "out/batch.json").unlink()
    r = _batch("npf.bin", "--materials", "chrome", "--tables", "sampling", "-o", "out", "--scheduler", "sync",
               "--resume")
    assert r == "returned 2", r
    assert (tmp_path / "out/batch.json").read_bytes() == other
    r = _batch("npf.bin", "--materials", "nickel", "--tables", "sampling", "-o", "out", "--scheduler", "sync",
               "--force")
    assert r == "returned 0", r
    assert json.loads((tmp_path / "out/batch.json").read_text())["items"][0]["name"] == "nickel"


def _start_batch(tmp_path, out: str):
    """``warpbw-precompute batch`` of two stand-in NPF materials on the processes scheduler, two workers, in a process
    of its own; (the process, its two worker processes' ids) once both workers run."""
    import os
    import subprocess
    import sys
    import time

    fake_npf_table(tmp_path / "npf.bin")
    env = dict(os.environ, WARPBW_CACHE=str(tmp_path / "_cache"))
    p = subprocess.Popen([sys.executable, "-m", "precompute", "batch", "npf.bin", "--materials", "chrome,nickel",
                          "-o", out, "--workers", "2", "-q"], cwd=tmp_path, env=env, stdin=subprocess.DEVNULL,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    end = time.monotonic() + 120
    workers = []
    while len(workers) < 2 and time.monotonic() < end and p.poll() is None:
        time.sleep(0.2)
        try:
            kids = open(f"/proc/{p.pid}/task/{p.pid}/children").read().split()
        except OSError:
            kids = []
        workers = [int(k) for k in kids if "spawn_main" in _cmdline(int(k))]
    assert len(workers) == 2, (p.poll(), workers)
    time.sleep(3)   # the workers import warpbw and start on their BRDFs
    return p, workers


def _cmdline(pid: int) -> str:
    try:
        return open(f"/proc/{pid}/cmdline", "rb").read().decode(errors="replace")
    except OSError:
        return ""


def _alive(pid: int) -> bool:
    """``pid`` runs (a zombie left for a parent that does not reap it does not)."""
    try:
        return open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()[0] not in ("Z", "X")
    except OSError:
        return False


def test_tasks_running_at_once_on_threads_leave_the_process_warnings_as_they_were(tmp_path, monkeypatch):
    """Each task recorded its warnings with catch_warnings(record=True), which holds the process's warnings machinery:
    two tasks at once on threads (the threads scheduler) each put back the other's recorder as they ended, and 35 of
    60 two-BRDF batches left every later warning of the process going to a finished task's list, never shown.  The
    order forced here (the BRDF's reading stood in for: it warns, then fails): task a starts, b starts, a ends, then
    b.  Each record holds its own warning, and the machinery (showwarning, the filters) is as it was."""
    import threading
    import warnings

    import precompute.brdf_sampling as bs
    from precompute.batch import BatchItem, build_item
    from warpbw.errors import WarpbwError

    a_in, b_in, a_out = threading.Event(), threading.Event(), threading.Event()

    def brdf_source(path, material=None, lookup=None):
        warnings.warn(f"stand-in {material}", RuntimeWarning)
        if material == "a":
            a_in.set()
            b_in.wait(0.3)   # b's task, when it can start before this one ends
        else:
            b_in.set()
            a_out.wait(5)    # a ends first
        raise WarpbwError(f"stand-in {material} stops")

    monkeypatch.setattr(bs, "brdf_source", brdf_source)
    before = (warnings.showwarning, warnings._showwarnmsg_impl, list(warnings.filters))
    records = {}

    def task(m, after=None):
        if after is not None:
            after.wait(5)
        records[m] = build_item(BatchItem("npf.bin", m, m), {"sampling": tmp_path / f"{m}.npz"})
        if m == "a":
            a_out.set()

    threads = [threading.Thread(target=task, args=("a",)), threading.Thread(target=task, args=("b", a_in))]
    for t in threads:
        t.start()
    for t in threads:
        t.join(10)
    assert (warnings.showwarning, warnings._showwarnmsg_impl, list(warnings.filters)) == before
    assert {m: (r["warnings"], r["error"]) for m, r in records.items()} == {
        m: ([f"stand-in {m}"], f"stand-in {m} stops") for m in "ab"}


def test_a_batch_whose_workers_fail_under_a_python_script_says_to_guard_its_call(tmp_path, monkeypatch):
    """run_batch called at the top level of a Python script (no ``if __name__ == "__main__":``): each worker process
    imports the script again as it starts, runs its run_batch and is refused there by multiprocessing, and the batch
    said its workers had been killed ("the OOM killer, kill -9") and nothing else (seen running a script of two
    lines).  From a script the line now names it and the guard; the commands' line is as before.  The workers'
    failure is dask's BrokenProcessPool, raised here by a stand-in for dask.compute."""
    import sys
    import types
    from concurrent.futures.process import BrokenProcessPool

    import dask

    from precompute.batch import batch_items, run_batch
    from warpbw.errors import WarpbwError

    def broken(*a, **k):
        raise BrokenProcessPool("A process in the process pool was terminated abruptly")

    monkeypatch.setattr(dask, "compute", broken)
    monkeypatch.chdir(tmp_path)
    fake_npf_table(tmp_path / "npf.bin")
    items = batch_items(["npf.bin"], ["chrome"])
    for main, hint in ((str(tmp_path / "my_batch.py"), True), ("/usr/bin/warpbw-precompute", False)):
        module = types.ModuleType("__main__")
        module.__file__ = main
        monkeypatch.setitem(sys.modules, "__main__", module)
        with pytest.raises(WarpbwError) as err:
            run_batch(items, "out", progress=False)
        msg = str(err.value)
        assert msg.startswith("out: a worker process of the batch ended abruptly") and "--resume" in msg, msg
        assert ('from the Python script my_batch.py' in msg and 'if __name__ == "__main__":' in msg) == hint, msg


@pytest.mark.skipif(not __import__("os").path.exists("/proc/self/task"), reason="reads /proc (Linux)")
def test_a_worker_killed_mid_batch_ends_it_in_one_line(tmp_path):
    """A worker process killed with SIGKILL (the OOM killer): the batch ended with concurrent.futures'
    BrokenProcessPool traceback and exit status 1 (session 78).  Now one line naming the out folder, what happened and
    --resume, and the status of a user error."""
    import os
    import signal

    p, workers = _start_batch(tmp_path, "out")
    os.kill(workers[0], signal.SIGKILL)
    out, err = p.communicate(timeout=180)
    assert p.returncode == 2, (p.returncode, err)
    assert err.startswith("warpbw-precompute: error: out: a worker process of the batch ended abruptly"), err
    assert len(err.strip().splitlines()) == 1 and "--resume" in err, err


@pytest.mark.skipif(not __import__("os").path.exists("/proc/self/task"), reason="reads /proc (Linux)")
def test_a_batch_killed_takes_its_workers_with_it(tmp_path):
    """The batch's own process killed with SIGKILL: its Dask workers went on, wrote the tables of the BRDFs in flight
    after the command had ended, and stayed (session 78: idle, about 90 MB each).  Now they end with it and write
    nothing more."""
    import os
    import signal
    import time

    p, workers = _start_batch(tmp_path, "out")
    os.kill(p.pid, signal.SIGKILL)
    p.wait(timeout=60)   # not communicate: workers that outlive it hold its pipes open
    end = time.monotonic() + 10
    while any(_alive(w) for w in workers) and time.monotonic() < end:
        time.sleep(0.1)
    alive = [w for w in workers if _alive(w)]
    for w in alive:   # the test's own processes: not left behind whatever it finds
        os.kill(w, signal.SIGKILL)
    assert alive == [], f"worker processes {alive} outlived the batch"
    written = sorted(f.name for f in (tmp_path / "out").iterdir() if not f.name.startswith("."))
    time.sleep(3)
    assert sorted(f.name for f in (tmp_path / "out").iterdir() if not f.name.startswith(".")) == written
    p.stdout.close()
    p.stderr.close()


def test_task_warnings_go_to_their_task_while_another_runs_and_from_threads_a_task_started():
    """``_task_warnings`` (its docstring): the first task to start takes the process's warnings machinery and the last
    to end puts it back, so a task still running after another ended keeps its own list; a warning from a thread that
    runs no task (one a task started) goes to every task running; each warning is recorded, the same one twice
    included; afterwards the process's warnings are as they were.  Truth: the warnings this test raises."""
    import threading
    import warnings

    from precompute import batch

    before = (warnings.showwarning, list(warnings.filters))
    a_started, a_ended, b_saw = threading.Event(), threading.Event(), {}

    def task_a():
        with batch._task_warnings() as said:
            a_started.set()
            b_saw["a"] = said
        a_ended.set()

    with batch._task_warnings() as said_b:
        t = threading.Thread(target=task_a)
        t.start()
        a_started.wait(10)
        a_ended.wait(10)   # task a ended while this one runs
        t.join(10)
        for _ in range(2):
            warnings.warn("from b", UserWarning)
        helper = threading.Thread(target=lambda: warnings.warn("from a helper thread", UserWarning))
        helper.start()
        helper.join(10)
    assert [str(w.message) for w in said_b] == ["from b", "from b", "from a helper thread"]
    assert b_saw["a"] == []
    assert (warnings.showwarning, list(warnings.filters)) == before


def test_the_script_hint_is_for_a_python_script_alone(monkeypatch):
    """``_script_hint`` says to guard run_batch under ``if __name__ == "__main__":`` to a Python script run as
    ``python make_tables.py`` (no ``__spec__``), and nothing under ``python -m precompute`` (a ``__spec__``) or a
    console script (``warpbw-precompute``).  Truth: the three ways the docstring names."""
    import sys
    from types import SimpleNamespace

    from precompute import batch

    for main, hint in ((SimpleNamespace(__file__="/home/u/make_tables.py", __spec__=None), True),
                       (SimpleNamespace(__file__="/src/precompute/__main__.py", __spec__=object()), False),
                       (SimpleNamespace(__file__="/venv/bin/warpbw-precompute", __spec__=None), False)):
        monkeypatch.setitem(sys.modules, "__main__", main)
        said = batch._script_hint()
        assert ("make_tables.py" in said and "__name__" in said) if hint else said == "", main
