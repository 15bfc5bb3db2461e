"""Outputs that appear whole or not at all (``warpbw.io.staged``), and the writers built on it.

Truth here is the file system's: bytes before and after, inode links, modes, and what a planted link points at.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import kill_when_written, lambert_sphere_scene

from warpbw.errors import WarpbwError
from warpbw.io.staged import check_replaceable, staged_outputs


def _leftovers(d) -> list:
    """Hidden temporaries left in ``d``."""
    return sorted(p.name for p in d.iterdir() if p.name.startswith("."))


def test_a_failure_in_the_block_leaves_every_output_as_it_was(tmp_path):
    """Two outputs, the second writer fails: neither output changes, no temporary stays, and the message names
    the output, not the temporary."""
    a, b = tmp_path / "out.exr", tmp_path / "out.json"
    a.write_bytes(b"old image")
    b.write_text("old record")
    with pytest.raises(WarpbwError) as e:
        with staged_outputs([a, b]) as at:
            at[a].write_bytes(b"new image")
            raise WarpbwError(f"{at[b]}: cannot write PNG (No space left on device)")
    assert str(e.value) == f"{b}: cannot write PNG (No space left on device)"
    assert a.read_bytes() == b"old image" and b.read_text() == "old record"
    assert _leftovers(tmp_path) == []


def test_an_os_error_names_the_output(tmp_path):
    out = tmp_path / "sub" / "out.png"
    with pytest.raises(WarpbwError, match=r"out\.png: cannot write \(No space left on device\)$") as e:
        with staged_outputs([out]) as at:
            raise OSError(28, "No space left on device", str(at[out]))
    assert ".part" not in str(e.value) and not out.exists() and not out.parent.exists()   # the folder it made: gone


def test_all_outputs_appear_together_with_the_mode_of_a_new_file(tmp_path):
    outs = [tmp_path / "a.exr", tmp_path / "deeper" / "b.png"]
    with staged_outputs(outs) as at:
        for p in outs:
            assert at[p].parent == p.parent and at[p].suffix == p.suffix   # writers that go by the suffix
            at[p].write_text(p.name)
        assert not any(p.exists() for p in outs)                            # nothing until the block ends
    assert [p.read_text() for p in outs] == ["a.exr", "b.png"]
    umask = os.umask(0)
    os.umask(umask)
    assert all((p.stat().st_mode & 0o777) == (0o666 & ~umask) for p in outs)   # mkstemp alone gives 0600


def test_the_mode_of_a_new_output_never_sets_the_umask(tmp_path, monkeypatch):
    """To give an output the mode of a new file, the writer set the process's umask to 0 and back to read it: a file
    another thread created meanwhile got mode 0666, and a second writer in that window (two threads writing outputs:
    the batch's threads scheduler) read 0, wrote its output world-writable and could leave the umask at 0 for the
    rest of the process.  Here the second writer's call lands inside the first's (os.umask stood in for): both give
    0666 less the umask (read before, with no other thread running), and the umask is as it was."""
    import warpbw.io.staged as staged

    real = os.umask
    truth = real(0o022)
    real(truth)
    inner, landed = [], []

    def umask(mask):
        old = real(mask)
        if mask == 0 and not landed:   # another thread's writer, while the umask is 0
            landed.append(True)
            inner.append(staged._new_file_mode())
        return old

    monkeypatch.setattr(os, "umask", umask)
    try:
        outer = staged._new_file_mode()
        assert [outer, *inner] == [0o666 & ~truth] * (1 + len(inner))
    finally:
        now = real(truth)
    assert now == truth
    out = tmp_path / "o.txt"
    with staged_outputs([out]) as at:
        at[out].write_text("x")
    assert out.stat().st_mode & 0o777 == 0o666 & ~truth


def test_an_existing_output_is_replaced_not_written_through(tmp_path):
    """A hard link to the output and a symlink at its place keep the file they pointed at."""
    probe = tmp_path / "probe.exr"
    probe.write_bytes(b"the light probe")
    (tmp_path / "hard.exr").hardlink_to(probe)
    (tmp_path / "soft.exr").symlink_to(probe)
    for name in ("hard.exr", "soft.exr"):
        out = tmp_path / name
        with staged_outputs([out]) as at:
            at[out].write_bytes(b"a render")
        assert out.read_bytes() == b"a render" and not out.is_symlink()
    assert probe.read_bytes() == b"the light probe"


def _read_only(p):
    """chmod 444 ``p``; returns its bytes and mode, to compare after."""
    p.chmod(0o444)
    return p.read_bytes(), p.stat().st_mode


@pytest.mark.parametrize("link", ["same", "relative", "symlink", "hardlink"])
def test_check_replaceable_refuses_an_input_whatever_force_says(tmp_path, monkeypatch, link):
    """A library writer given its own input as output (``npf_to_merl(T, m, T, force=True)``) replaced it; now the
    input is refused, named, and said to be a link where it is one."""
    src = tmp_path / "src.bin"
    src.write_bytes(b"the input")
    monkeypatch.chdir(tmp_path)
    out = {"same": src, "relative": Path("src.bin"), "symlink": tmp_path / "soft.bin",
           "hardlink": tmp_path / "hard.bin"}[link]
    if link == "symlink":
        out.symlink_to(src)
    elif link == "hardlink":
        out.hardlink_to(src)
    for force in (False, True):
        with pytest.raises(WarpbwError) as e:
            check_replaceable(out, force, inputs=[src])
        msg = str(e.value)
        assert msg.startswith(f"{out}: would overwrite {src}, the file it is made from")
        assert msg.endswith("is a link to it)") == (link in ("symlink", "hardlink"))
    assert check_replaceable(tmp_path / "other.bin", False, inputs=[src]) == tmp_path / "other.bin"


def test_check_replaceable_refuses_a_read_only_output_even_with_force(tmp_path):
    out = tmp_path / "kept.npz"
    out.write_bytes(b"keep me")
    _read_only(out)
    with pytest.raises(WarpbwError, match=r"kept\.npz: already exists \(pass --force to overwrite it\)$"):
        check_replaceable(out, False)
    with pytest.raises(WarpbwError, match=r"kept\.npz: cannot be overwritten \(.*; make it writable, or write "
                                          r"elsewhere\)$"):
        check_replaceable(out, True)
    out.chmod(0o644)
    assert check_replaceable(out, True) == out


def test_an_output_that_is_no_regular_file_or_a_dangling_link_is_not_taken_for_a_free_name(tmp_path):
    import signal

    # a FIFO with force blocked for ever, opened for writing to see whether it was read-only; an alarm ends the test
    # if it blocks again
    fifo = tmp_path / "out.exr"
    os.mkfifo(fifo)
    previous = signal.signal(signal.SIGALRM, lambda *a: pytest.fail("check_replaceable blocked on a FIFO"))
    signal.alarm(20)
    try:
        with pytest.raises(WarpbwError, match=r"out\.exr: is a FIFO, not a regular file \(expected a file to write "
                                              r"or replace\)$"):
            check_replaceable(fifo, True)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    with pytest.raises(WarpbwError, match=r"null: is a device, not a regular file"):
        check_replaceable("/dev/null", True)
    # a dangling link is the user's file too: replaced without --force, it is now refused as any output is
    link = tmp_path / "link.exr"
    link.symlink_to(tmp_path / "nowhere.exr")
    with pytest.raises(WarpbwError, match=r"link\.exr: already exists \(pass --force to overwrite it\)$"):
        check_replaceable(link, False)
    assert check_replaceable(link, True) == link


def test_a_long_output_name_is_written_and_one_too_long_refused_before_the_work(tmp_path):
    from warpbw.cli_common import check_output_file

    # 240 bytes: the output fits the file system's 255, but its temporary, 30 bytes longer, did not (after the work)
    out = tmp_path / ("d" * 236 + ".exr")
    with staged_outputs([out]) as at:
        at[out].write_bytes(b"image")
    assert out.read_bytes() == b"image" and [p.name for p in tmp_path.iterdir()] == [out.name]
    # 264 bytes: refused by name first (a raw "[Errno 36] File name too long" after the work, or from is_dir)
    too_long = tmp_path / ("e" * 260 + ".exr")
    with pytest.raises(WarpbwError, match=r"e\.exr: a file name of 264 bytes, longer than the file system takes "
                                          r"\(255\); expected a shorter name$"):
        check_replaceable(too_long, True)
    with pytest.raises(WarpbwError, match=r"^-o .*e\.exr: a file name of 264 bytes"):
        check_output_file(too_long, "-o", force=False)
    # a folder on the way, too (made by the run, it failed there with a raw OSError)
    with pytest.raises(WarpbwError, match=r"out\.exr: a folder name fffffffffffffffff?\.\.\. of 300 bytes"):
        check_output_file(tmp_path / ("f" * 300) / "out.exr", "-o", force=False)


def test_check_replaceable_refuses_a_directory_and_what_is_no_file_name(tmp_path):
    with pytest.raises(WarpbwError, match="is a directory"):
        check_replaceable(tmp_path, True)
    # write_merl(None, ...) and the asset writers gave a TypeError from pathlib
    for bad in (None, 3):
        with pytest.raises(WarpbwError, match=rf"^output path: expected a file name \(str or Path\), got {bad!r}$"):
            check_replaceable(bad, True)
    with pytest.raises(WarpbwError, match=r"^output path: expected a file name, got an empty one$"):
        check_replaceable("", True)


def test_write_merl_refuses_a_read_only_file_and_its_inputs_even_with_force(tmp_path):
    """write_merl(ro_file, data, force=True) replaced a chmod 444 file (and left it 644); and a MERL file written
    from another may not replace it."""
    from warpbw.io.merl import MERL_SHAPE, write_merl

    ro = tmp_path / "ro.binary"
    ro.write_bytes(b"a read-only MERL file")
    before = _read_only(ro)
    with pytest.raises(WarpbwError, match=r"ro\.binary: cannot be overwritten"):
        write_merl(ro, np.full(MERL_SHAPE, 0.1), force=True)
    assert (ro.read_bytes(), ro.stat().st_mode) == before
    src = tmp_path / "src.binary"
    src.write_bytes(b"the MERL file it is made from")
    (tmp_path / "hard.binary").hardlink_to(src)
    with pytest.raises(WarpbwError, match=r"hard\.binary: would overwrite .*src\.binary"):
        write_merl(tmp_path / "hard.binary", np.full(MERL_SHAPE, 0.1), force=True, inputs=[src])
    assert src.read_bytes() == b"the MERL file it is made from" and _leftovers(tmp_path) == []


def test_two_forced_writers_of_one_set_move_it_one_after_the_other(tmp_path, monkeypatch):
    """Two ``--force`` runs of one output set (image and record) that finished together moved their files in turns:
    the first moved its image, the second both its files, the first its record, and the set was the second's image
    beside the first's record (processes audit, session 79: each file whole, the set mixed).  Now each run moves its
    set holding a lock on the set's folders, so the last to finish wins whole.  Truth: the second run starts its
    moves once the first has moved its image, and the first waits there until the second has moved a file (at most
    a second: with the lock the second cannot before the first is done, and the set is the second's whatever the
    wait)."""
    import threading

    outs = [tmp_path / "image.exr", tmp_path / "image.json"]
    real = os.replace
    first_moved_image, second_moved = threading.Event(), threading.Event()

    def replace(src, dst, *args, **kwargs):
        real(src, dst, *args, **kwargs)
        if threading.current_thread().name == "second":
            second_moved.set()
        elif Path(dst).name == "image.exr":
            first_moved_image.set()
            second_moved.wait(timeout=1.0)

    def write(name, before_moves=None):
        with staged_outputs(outs, force=True) as at:
            for p in outs:
                at[p].write_text(name)
            if before_moves is not None:
                before_moves.wait(timeout=60)

    monkeypatch.setattr(os, "replace", replace)
    runs = [threading.Thread(target=write, args=("first",), name="first"),
            threading.Thread(target=write, args=("second", first_moved_image), name="second")]
    for t in runs:
        t.start()
    for t in runs:
        t.join(timeout=60)
    assert [p.read_text() for p in outs] == ["second", "second"] and _leftovers(tmp_path) == []


def test_two_writers_of_one_output_get_temporaries_of_their_own(tmp_path):
    """Each writer has its own temporary.  Of two runs writing one new output without --force, the first to finish
    writes it and the second is refused, naming it (both had passed the check before their work; the second
    replaced the first's file); with force (--force, a cache's writers) both write it, the last to finish winning
    whole."""
    out = tmp_path / "same.npz"
    with pytest.raises(WarpbwError, match="same.npz: already exists: it appeared while this run worked"):
        with staged_outputs([out], force=False) as first, staged_outputs([out], force=False) as second:
            assert first[out] != second[out]
            first[out].write_text("chrome")
            second[out].write_text("gold")
    assert out.read_text() == "gold" and _leftovers(tmp_path) == []
    cache = tmp_path / "cache.npz"
    with staged_outputs([cache]) as first, staged_outputs([cache]) as second:
        first[cache].write_text("chrome")
        second[cache].write_text("gold")
    assert cache.read_text() == "chrome" and _leftovers(tmp_path) == []


def test_an_output_that_appears_during_the_run_is_kept_and_no_output_moved(tmp_path):
    """The user writes out.json while a render runs (no --force): it was replaced by the render's record.  Now it is
    kept, and the run's other outputs are not moved either (all or none); with --force it is replaced, and a
    dangling link that appears counts as taken."""
    img, rec = tmp_path / "out.exr", tmp_path / "out.json"
    with pytest.raises(WarpbwError, match=r"out\.json: already exists: .*\(pass --force to overwrite it\)$"):
        with staged_outputs([img, rec], force=False) as at:
            at[img].write_text("image")
            at[rec].write_text("record")
            rec.write_text("USER NOTES")
    assert rec.read_text() == "USER NOTES" and not img.exists() and _leftovers(tmp_path) == []
    with staged_outputs([img, rec], force=True) as at:
        at[img].write_text("image")
        at[rec].write_text("record")
    assert rec.read_text() == "record" and img.read_text() == "image"
    link = tmp_path / "link.exr"
    with pytest.raises(WarpbwError, match="link.exr: already exists"):
        with staged_outputs([link], force=False) as at:
            at[link].write_text("image")
            link.symlink_to(tmp_path / "nowhere")
    assert link.is_symlink() and not link.exists()


def test_a_failed_run_removes_the_folders_it_made_and_no_other(tmp_path):
    """``-o new/sub/a.exr`` on a full disk left new/ and new/sub/ behind, empty.  A folder that was there stays, and
    so does one the run made in which someone else put a file meanwhile."""
    (tmp_path / "had").mkdir()
    outs = [tmp_path / "new" / "sub" / "a.exr", tmp_path / "had" / "b.png", tmp_path / "other" / "c.json"]
    with pytest.raises(WarpbwError, match="a.exr: cannot write"):
        with staged_outputs(outs) as at:
            (tmp_path / "other" / "theirs.txt").write_text("not ours")
            raise OSError(28, "No space left on device", str(at[outs[0]]))
    assert sorted(q.name for q in tmp_path.iterdir()) == ["had", "other"]
    assert [q.name for q in (tmp_path / "other").iterdir()] == ["theirs.txt"] and not any((tmp_path / "had").iterdir())


def test_write_asset_does_not_follow_a_link_planted_at_a_temporary_name(tmp_path):
    """write_asset wrote OUT.tmp, a fixed name opened without O_EXCL: a link planted there (a shared
    WARPBW_CACHE) had a plain render overwrite the file it pointed at, outside the cache."""
    from precompute.assetfile import read_asset, write_asset

    victim = tmp_path / "victim.txt"
    victim.write_text("keep me")
    out = tmp_path / "cache" / "sampling-key-v2.npz"
    out.parent.mkdir()
    (out.parent / f"{out.name}.tmp").symlink_to(victim)
    write_asset(out, "fmt", 1, "src", "hash", {"a": np.arange(3.0)})
    assert victim.read_text() == "keep me"
    assert np.array_equal(read_asset(out, "fmt", 1, "rebuild").arrays["a"], np.arange(3.0))


def test_write_merl_leaves_the_old_file_when_it_fails(tmp_path, monkeypatch):
    """write_merl: a failed write (a full disk) leaves the existing file as it was and no temporary."""
    from warpbw.io import merl

    out = tmp_path / "m.binary"
    out.write_bytes(b"an earlier MERL file")

    class FullDisk:
        def __init__(self, path, mode):
            self.f = open(path, mode)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.f.close()

        def write(self, data):
            self.f.write(data[: len(data) // 2])
            raise OSError(28, "No space left on device", self.f.name)

    monkeypatch.setattr(merl, "open", FullDisk, raising=False)
    with pytest.raises(WarpbwError, match=r"m\.binary: cannot write \(No space left on device\)"):
        merl.write_merl(out, np.full(merl.MERL_SHAPE, 0.1), force=True)
    assert out.read_bytes() == b"an earlier MERL file" and _leftovers(tmp_path) == []


def test_an_output_that_cannot_be_made_is_named(tmp_path):
    """A folder under a file: the message names the output (not a random temporary) and the file in the way (a
    cache folder that is a file gave "cannot write (File exists)"), and nothing is left."""
    (tmp_path / "afile").write_text("keep")
    in_the_way = rf"cannot write \({tmp_path / 'afile'} is not a directory\)"
    with pytest.raises(WarpbwError, match=rf"afile/sub/out\.exr: {in_the_way}"):
        with staged_outputs([tmp_path / "ok.png", tmp_path / "afile" / "sub" / "out.exr"]):
            pass
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]
    with pytest.raises(WarpbwError, match=rf"afile/out\.exr: {in_the_way}"):
        with staged_outputs([tmp_path / "afile" / "out.exr"]):
            pass


def test_an_example_whose_last_writer_fails_leaves_its_earlier_outputs(tmp_path, monkeypatch):
    """examples/gbuffer.py writes four PNGs, then gbuffer.exr: a full disk in that last write left four new
    PNGs beside the old EXR (and a cut-off EXR).  Now every earlier output stays byte for byte, and no temporary."""
    import trimesh
    from conftest import load_example

    ex = load_example("gbuffer")
    mesh = tmp_path / "sphere.obj"
    trimesh.creation.icosphere(subdivisions=1, radius=0.5).export(mesh)
    out = tmp_path / "gb"
    out.mkdir()
    for name in ex.OUTPUTS:
        (out / name).write_bytes(f"an earlier {name}".encode())

    def full_disk(path, *args, **kwargs):   # half an EXR, then ENOSPC
        with open(path, "wb") as f:
            f.write(b"\x76\x2f\x31\x01 half an EXR")
        raise OSError(28, "No space left on device", str(path))

    monkeypatch.setattr(ex, "write_exr", full_disk)
    monkeypatch.setattr(sys, "argv", ["gbuffer.py", "--mesh", str(mesh), "--out", str(out), "--resolution", "8", "8",
                                      "--force"])
    with pytest.raises(WarpbwError) as e:
        ex.main()
    assert {n: (out / n).read_bytes() for n in ex.OUTPUTS} == {n: f"an earlier {n}".encode() for n in ex.OUTPUTS}
    assert sorted(p.name for p in out.iterdir()) == sorted(ex.OUTPUTS)   # no .part temporary left
    assert str(e.value) == f"{out / 'gbuffer.exr'}: cannot write (No space left on device)"


# A command stopped in the middle of its writes: the child writes half of each output to its temporary, says so on
# stdout, then waits to be stopped.
_STOPPED_WRITER = """
import sys, time
from pathlib import Path
from warpbw.cli_common import run_command
from warpbw.io.staged import check_replaceable, staged_outputs

def write_then_wait(args):
    out = Path(sys.argv[1])
    with staged_outputs([out / "image.exr", out / "stats.json"]) as temps:
        for tmp in temps.values():
            tmp.write_bytes(b"half of it")
        print("written", flush=True)
        time.sleep(60)
    return 0

sys.exit(run_command("warpbw", write_then_wait, None))
"""


@pytest.mark.parametrize("sig, status, said", [("SIGTERM", 143, "warpbw: terminated"),
                                               ("SIGINT", 130, "warpbw: interrupted"),
                                               ("SIGHUP", 129, "warpbw: hung up")])
def test_a_command_stopped_by_a_signal_leaves_its_outputs_and_no_temporary(tmp_path, sig, status, said):
    """SIGTERM (kill, timeout, a batch scheduler) and SIGHUP (a closed terminal, a dropped ssh session) ended the
    process where it stood and left every output's hidden .part temporary behind; now they unwind as Ctrl-C does: the
    old outputs stay, the temporaries go, and the status is the shell's for the signal."""
    import signal
    import subprocess

    out = tmp_path / "out"
    out.mkdir()
    (out / "image.exr").write_bytes(b"an earlier image")
    # a shell without job control starts background jobs with SIGINT ignored, and Python then leaves it ignored:
    # the child gets the default back, as a terminal's Ctrl-C would find it (a CI run under nohup read status 0)
    child = subprocess.Popen([sys.executable, "-c", _STOPPED_WRITER, str(out)], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True,
                             preexec_fn=lambda: [signal.signal(signal.SIGINT, signal.SIG_DFL),
                                                 signal.signal(signal.SIGHUP, signal.SIG_DFL)])   # nohup: ignored
    try:
        assert child.stdout.readline() == "written\n"
        assert len(_leftovers(out)) == 2                      # the temporaries are there while it writes
        child.send_signal(getattr(signal, sig))
        _, err = child.communicate(timeout=120)   # well under a second; 30 s ran out once on a loaded machine
    finally:
        child.kill()
    assert child.returncode == status
    assert err.strip() == said
    assert sorted(p.name for p in out.iterdir()) == ["image.exr"]
    assert (out / "image.exr").read_bytes() == b"an earlier image"


_STOPPED_COMPILE = """
import os, signal, sys
import warp._src.build as build

real = build.build_cpu

def stopped_build(*args, **kwargs):   # the stop arrives while Warp compiles a module (C++ source written)
    os.kill(os.getpid(), getattr(signal, sys.argv[1]))
    return real(*args, **kwargs)

build.build_cpu = stopped_build
from warpbw.cli import main
sys.exit(main(["render", "scene.toml", "-o", "out.exr", "--spp", "1"]))
"""


@pytest.mark.parametrize("sig, status, said", [("SIGTERM", 143, "warpbw: terminated"),
                                               ("SIGINT", 130, "warpbw: interrupted")])
def test_a_command_stopped_while_warp_compiles_leaves_no_build_folder_in_its_kernel_cache(tmp_path, sig, status,
                                                                                          said):
    """Warp compiles a module in a build folder beside its kernel cache entry (MODULE_pPID_tTHREAD) and removes it
    once the module is in place: a Ctrl-C or SIGTERM during a compile (the first run's minute) left the folder, and
    its C++ source, in the kernel cache for good.  Truth: a real process whose stop arrives while Warp compiles (the
    compiler forced to send it), with an empty kernel cache."""
    import signal
    import subprocess

    (tmp_path / "scene.toml").write_text(lambert_sphere_scene(8, 8))
    kernels = tmp_path / "kernels"
    env = dict(os.environ, WARPBW_CACHE=str(tmp_path / "_cache"), WARP_CACHE_PATH=str(kernels))
    r = subprocess.run([sys.executable, "-c", _STOPPED_COMPILE, sig], cwd=tmp_path, env=env, capture_output=True,
                       text=True, timeout=300, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    assert (r.returncode, r.stderr.strip()) == (status, said)
    assert [p.name for p in kernels.glob("*/*") if "_p" in p.name and "_t" in p.name] == []
    assert kernels.is_dir() and sorted(p.name for p in tmp_path.iterdir()) == ["kernels", "scene.toml"]   # no output


class _Stopped(BaseException):
    """What the test's SIGTERM handler raises (as run_command's does)."""


@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM"])
def test_a_stop_while_the_outputs_are_moved_comes_after_the_last_one(tmp_path, monkeypatch, sig):
    """A Ctrl-C or SIGTERM that arrived between two moves into place stopped the run there: a new image beside the
    old record.  Now the stop is held until every output is moved, then raised as it would have been; the handler
    the run had is back afterwards.  Truth: the signal is sent from inside the first move."""
    import signal

    import warpbw.io.staged as staged

    outs = [tmp_path / "image.exr", tmp_path / "stats.json"]
    for p in outs:
        p.write_text("old")
    real_replace, moves = os.replace, []

    def replace_then_stop(src, dst):
        real_replace(src, dst)
        moves.append(dst)
        if len(moves) == 1:
            os.kill(os.getpid(), getattr(signal, sig))

    def stopped(signum, frame):
        raise _Stopped(signum)

    previous = signal.signal(signal.SIGTERM, stopped)
    # Python's own Ctrl-C handler, whatever the suite was started with: a shell without job control starts background
    # jobs with SIGINT ignored, and the signal sent below then did nothing (a failure of the test, not of the code)
    previous_int = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        monkeypatch.setattr(staged.os, "replace", replace_then_stop)
        with pytest.raises(KeyboardInterrupt if sig == "SIGINT" else _Stopped):
            with staged_outputs(outs) as temps:
                for tmp in temps.values():
                    tmp.write_text("new")
        assert signal.getsignal(signal.SIGTERM) is stopped
    finally:
        signal.signal(signal.SIGTERM, previous)
        signal.signal(signal.SIGINT, previous_int)
    assert [p.read_text() for p in outs] == ["new", "new"] and len(moves) == 2
    assert _leftovers(tmp_path) == []


def test_the_next_run_removes_what_a_killed_run_left_and_nothing_else(tmp_path):
    """SIGKILL (the OOM killer, kill -9) cannot be caught: the writer's hidden temporaries stayed beside its outputs
    for good, unseen.  The next run that writes an output removes that output's temporaries whose process is gone
    from this machine; it keeps a live writer's, another machine's, another output's, and a file of the user's that
    only looks like one.  Truth: a real child killed with SIGKILL while it writes."""
    out = tmp_path / "out"
    out.mkdir()
    pid = kill_when_written(_STOPPED_WRITER, str(out), timeout=120.0)
    killed = _leftovers(out)
    assert len(killed) == 2 and all(f"-{pid}." in n for n in killed), killed
    host = killed[0].split(".")[2].split("-")[0]
    kept = [f".image.{host}-{os.getpid()}.abc123.part.exr",        # a live writer (this test)
            ".image.0000beef-1.abc123.part.exr",                   # another machine's
            f".image.{host}-{pid}.abc123.part.png",          # another output's (image.png)
            ".image.mine.part.exr"]                                 # the user's
    for n in kept:
        (out / n).write_text("keep")
    with staged_outputs([out / "image.exr"]) as temps:
        temps[out / "image.exr"].write_bytes(b"whole")
    assert (out / "image.exr").read_bytes() == b"whole"
    # stats.json's temporary stays until a run writes stats.json
    assert _leftovers(out) == sorted(kept + [n for n in killed if n.startswith(".stats.")])


def test_run_command_leaves_the_sigterm_handler_as_it_found_it():
    """run_command's SIGTERM handler holds while the command runs: after it returns, the caller's handler is back (a
    Python caller of cli.main() got the command's termination raised anywhere later)."""
    import signal

    from warpbw.cli_common import run_command

    def mine(signum, frame):
        pass

    previous = signal.signal(signal.SIGTERM, mine)
    try:
        assert run_command("warpbw", lambda args: 0, None) == 0
        assert signal.getsignal(signal.SIGTERM) is mine
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_run_command_keeps_sigterm_ignored_where_the_caller_ignores_it():
    """A caller that ignores SIGTERM (its choice, as nohup's for SIGHUP) keeps it ignored: the command, sent SIGTERM
    while it runs, finishes with status 0 instead of stopping with 143."""
    import signal

    from warpbw.cli_common import EXIT_TERMINATED, run_command

    assert EXIT_TERMINATED == 128 + signal.SIGTERM

    def terminated_midway(args):
        os.kill(os.getpid(), signal.SIGTERM)
        return 0

    previous = signal.signal(signal.SIGTERM, signal.SIG_IGN)
    try:
        assert run_command("warpbw", terminated_midway, None) == 0
        assert signal.getsignal(signal.SIGTERM) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_a_stop_that_lands_in_a_destructor_is_not_reported_as_an_exception(monkeypatch):
    """Ctrl-C right after the outputs were moved into place landed in a Warp array's destructor as the command's
    locals went: "Exception ignored in ... KeyboardInterrupt" and a traceback, after a run that succeeded.  Such
    reports are left out while a command runs; another exception in a destructor is still reported."""
    from warpbw.cli_common import run_command

    class Freed:
        def __init__(self, exc):
            self.exc = exc

        def __del__(self):
            raise self.exc

    def command(args):
        Freed(KeyboardInterrupt())   # dropped at once: its destructor raises
        Freed(ValueError("a real defect"))
        return 0

    reported = []
    monkeypatch.setattr(sys, "unraisablehook", lambda u: reported.append(type(u.exc_value).__name__))
    assert run_command("warpbw", command, None) == 0
    assert reported == ["ValueError"]
    Freed(KeyboardInterrupt())   # outside a command: reported as Python does
    assert reported == ["ValueError", "KeyboardInterrupt"]


def test_the_console_scripts_answer_a_ctrl_c_during_their_imports_with_one_line(monkeypatch, capsys):
    """Ctrl-C in the first tenth of a second (numpy and Warp importing) printed a traceback of the import it
    stopped.  The entry points answer it with one line and status 130, and once the command returns ignore the stops
    while the interpreter shuts down (a late Ctrl-C printed a traceback from the thread pool's exit)."""
    import importlib
    import signal

    from warpbw import entry

    def stopped(name):
        raise KeyboardInterrupt

    saved = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    try:
        monkeypatch.setattr(importlib, "import_module", stopped)
        assert entry.warpbw() == 130 and entry.warpbw_precompute() == 130
        assert capsys.readouterr().err.splitlines() == ["warpbw: interrupted", "warpbw-precompute: interrupted"]
        assert all(signal.getsignal(sig) is signal.SIG_IGN for sig in saved)
    finally:
        for sig, handler in saved.items():
            signal.signal(sig, handler)


_STOPPED_WHILE_LOADING = """
import importlib, os, signal, sys
from warpbw import entry

def loading(name):   # the stop arrives while the command line's modules (numpy, Warp) load
    os.kill(os.getpid(), getattr(signal, sys.argv[1]))
    return real(name)

real, importlib.import_module = importlib.import_module, loading
sys.exit(entry.warpbw())
"""


@pytest.mark.parametrize("sig, status, said", [("SIGTERM", 143, "warpbw: terminated"),
                                               ("SIGHUP", 129, "warpbw: hung up")])
def test_the_console_scripts_answer_a_sigterm_during_their_imports_with_one_line(tmp_path, sig, status, said):
    """A SIGTERM or SIGHUP while ``warpbw`` loaded numpy and Warp (its first seconds, before run_command) ended the
    process where it stood, without the line the README promises (processes audit, session 79); a Ctrl-C there
    already said one.  Truth: a real process whose stop arrives as it imports its command line."""
    import signal
    import subprocess

    r = subprocess.run([sys.executable, "-c", _STOPPED_WHILE_LOADING, sig], cwd=tmp_path, capture_output=True,
                       text=True, timeout=300, preexec_fn=lambda: signal.signal(signal.SIGHUP, signal.SIG_DFL))
    assert (r.returncode, r.stderr.strip(), r.stdout) == (status, said, "")


def test_a_console_script_under_nohup_ignores_a_hangup_while_it_loads(tmp_path):
    """Mutation round 12: a stop the process was started ignoring (``nohup`` ignores SIGHUP) stays ignored while the
    command line loads: the run goes on (here to argparse's refusal of the argument it is given) instead of ending
    "hung up".
    Truth: a real process started with SIGHUP ignored and sent one as it imports its command line."""
    import signal
    import subprocess

    r = subprocess.run([sys.executable, "-c", _STOPPED_WHILE_LOADING, "SIGHUP"], cwd=tmp_path, capture_output=True,
                       text=True, timeout=300, preexec_fn=lambda: signal.signal(signal.SIGHUP, signal.SIG_IGN))
    assert r.returncode == 2 and r.stderr.startswith("warpbw: error: argument COMMAND: invalid choice: 'SIGHUP'"), \
        (r.returncode, r.stderr)


_STOPPED_AS_A_SCRIPT_EXITS = """
import os, signal, sys, time
from warpbw.entry import interrupt_in_one_line

interrupt_in_one_line("__main__")   # as every script under examples/ calls it first
from warpbw.cli_common import run_command

status = run_command("script.py", lambda args: 0, None)
for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):   # stops while the interpreter shuts down, after the run
    os.kill(os.getpid(), sig)
    time.sleep(0.1)
sys.exit(status)
"""


def test_a_script_ignores_a_stop_once_its_run_is_done(tmp_path):
    """The console scripts ignore the stops once their command has returned (a late Ctrl-C printed "Exception ignored
    in ..." from a Warp array's destructor or the thread pool's exit, after a run that had succeeded); the examples,
    which call run_command themselves, did not (processes audit, session 79).  A script that called
    ``interrupt_in_one_line`` now ignores them once its run_command returns.  Truth: a real process sent SIGINT
    after its run."""
    import signal
    import subprocess

    r = subprocess.run([sys.executable, "-c", _STOPPED_AS_A_SCRIPT_EXITS], cwd=tmp_path, capture_output=True,
                       text=True, timeout=300, preexec_fn=lambda: [signal.signal(signal.SIGINT, signal.SIG_DFL),
                                                                   signal.signal(signal.SIGHUP, signal.SIG_DFL)])
    assert (r.returncode, r.stderr, r.stdout) == (0, "", "")


def _initialisation_failed(stop: BaseException):
    """What a stop that lands in a pybind11 extension's initialisation (matplotlib's ft2font, imported at a command's
    first PNG) reaches Python as: "ImportError: initialization failed", raised from the stop."""
    def stand_in(*args, **kwargs):
        raise ImportError("initialization failed") from stop
    return stand_in


@pytest.mark.parametrize("stop, status, said", [("SIGINT", 130, "warpbw: interrupted"),
                                                ("SIGTERM", 143, "warpbw: terminated")])
def test_a_stop_inside_an_extensions_initialisation_ends_a_command_in_one_line(monkeypatch, capsys, stop, status,
                                                                               said):
    """A Ctrl-C at 3.3 s of an adaptive render (processes audit, session 79) landed while matplotlib's ft2font
    initialised, for the first false-colour PNG: Python raised "ImportError: initialization failed" from the
    KeyboardInterrupt, which no handler took, and the run ended with both tracebacks and status 1.  A stop behind the
    error (its cause or context) now ends the command as the stop does, in one line with the stop's status; the
    console scripts' imports, and the examples' (whose excepthook says it), likewise."""
    import importlib
    import signal

    from warpbw import entry
    from warpbw.cli_common import _Terminated, run_command

    the_stop = KeyboardInterrupt() if stop == "SIGINT" else _Terminated(signal.SIGTERM)
    assert run_command("warpbw", _initialisation_failed(the_stop), None) == status
    assert capsys.readouterr().err.splitlines() == [said]
    with pytest.raises(ImportError):   # one that no stop caused is no stop: its traceback is shown
        run_command("warpbw", _initialisation_failed(ValueError("a real defect")), None)
    if stop != "SIGINT":
        return
    saved = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    try:   # the console scripts, stopped while they import numpy and Warp
        monkeypatch.setattr(importlib, "import_module", _initialisation_failed(KeyboardInterrupt()))
        assert entry.warpbw() == 130
        assert capsys.readouterr().err.splitlines() == ["warpbw: interrupted"]
    finally:
        for sig, handler in saved.items():
            signal.signal(sig, handler)
    monkeypatch.setattr(sys, "argv", ["examples/gbuffer.py"])   # an example, stopped while it imports
    monkeypatch.setattr(sys, "excepthook", lambda *exc: print("a traceback", file=sys.stderr))
    entry.interrupt_in_one_line("__main__")
    try:
        _initialisation_failed(KeyboardInterrupt())()
    except ImportError as exc:
        sys.excepthook(type(exc), exc, exc.__traceback__)
    assert capsys.readouterr().err.splitlines() == ["gbuffer.py: interrupted"]


def test_an_output_named_twice_is_written_once_and_leaves_no_temporary(tmp_path):
    """staged_outputs([p, p]): one temporary for p, moved into place once; none left beside it (there were two
    temporaries, one forgotten, and a KeyError at the commit)."""
    out = tmp_path / "out.json"
    with staged_outputs([out, tmp_path / "out.json"]) as at:
        at[out].write_text("{}")
        named = list(at)
    assert named == [out] and out.read_text() == "{}"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.json"]


def test_missing_folders_at_any_depth_are_made(tmp_path):
    """staged_outputs: missing folders are made, however deep."""
    out = tmp_path / "a" / "b" / "c" / "out.exr"
    with staged_outputs([out]) as at:
        at[out].write_bytes(b"image")
    assert out.read_bytes() == b"image"


def test_a_lock_another_program_keeps_on_the_output_folder_delays_the_moves_at_most_folder_lock_wait_s(
        tmp_path, monkeypatch):
    """The moves into place take an exclusive ``flock`` on the outputs' folder, waiting for it at most
    ``FOLDER_LOCK_WAIT_S``: a lock some other program keeps on the folder (here a shared one on an open descriptor
    of the test's, never released while the run works) delays the moves by about that long, then they are made
    without it, whole (mutation round 12: no lock, a shared one, no wait or no end to it passed every test).  Truth:
    the clock, and the files written."""
    import fcntl
    import threading
    import time

    import warpbw.io.staged as staged

    monkeypatch.setattr(staged, "FOLDER_LOCK_WAIT_S", 0.3)
    fd = os.open(tmp_path, os.O_RDONLY)
    fcntl.flock(fd, fcntl.LOCK_SH)   # an exclusive lock waits for it; another shared one would not
    outs = [tmp_path / "image.exr", tmp_path / "image.json"]
    took = []

    def run():
        t0 = time.monotonic()
        with staged_outputs(outs) as at:
            for p in outs:
                at[p].write_text("new")
        took.append(time.monotonic() - t0)

    try:
        t = threading.Thread(target=run, daemon=True)
        t.start()
        t.join(timeout=60)
        assert took and 0.3 <= took[0] < 30, took   # waited for the lock, then moved without it
    finally:
        os.close(fd)
    assert [p.read_text() for p in outs] == ["new", "new"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["image.exr", "image.json"]


def test_an_output_folder_that_cannot_be_opened_for_its_lock_is_moved_into_without_one(tmp_path, monkeypatch):
    """Mutation round 12: a folder the moves cannot open to lock (a file system that refuses it, a folder readable by
    no one but writable) is moved into without the lock, as ``_folders_locked`` documents, not refused after the
    work.  Truth: the files written, and nothing else left."""
    real_open = os.open

    def no_folder(path, flags, *args, **kwargs):
        if flags == os.O_RDONLY and os.path.isdir(path):
            raise PermissionError(13, "Permission denied", str(path))
        return real_open(path, flags, *args, **kwargs)

    monkeypatch.setattr(os, "open", no_folder)
    outs = [tmp_path / "image.exr", tmp_path / "image.json"]
    with staged_outputs(outs) as at:
        for p in outs:
            at[p].write_text("new")
    assert [p.read_text() for p in outs] == ["new", "new"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["image.exr", "image.json"]


def test_stop_behind_follows_an_errors_cause_and_its_context():
    """Mutation round 12: ``stop_behind`` finds the stop an error was raised from (``raise ... from``) and the one it
    was raised while handling (an extension's "initialization failed" raised inside the KeyboardInterrupt's
    handling), through several links, and None where there is none, a chain that loops included.  Truth: chains
    built here."""
    from warpbw.entry import stop_behind

    def chained(link: str):
        try:
            try:
                raise KeyboardInterrupt
            except KeyboardInterrupt as stop:
                if link == "cause":
                    raise ImportError("initialization failed") from stop
                raise ImportError("initialization failed")
        except ImportError as exc:
            try:
                raise RuntimeError("while importing") from exc
            except RuntimeError as outer:
                return outer

    for link in ("cause", "context"):
        outer = chained(link)
        assert isinstance(stop_behind(outer), KeyboardInterrupt), link
        assert stop_behind(outer, (SystemExit,)) is None
    a, b = ValueError("a"), ValueError("b")
    a.__context__, b.__context__ = b, a
    assert stop_behind(a) is None


def test_dangling_link_names_a_link_to_nothing_alone(tmp_path):
    """Mutation round 12: ``dangling_link`` speaks of a symbolic link whose target does not exist, and of nothing
    else: a link to a folder or a file that exists (an output folder reached through a link), a plain file or
    folder, and a name that is not there are None.  Truth: the links made here."""
    from warpbw.io.staged import dangling_link

    (tmp_path / "folder").mkdir()
    (tmp_path / "file").write_text("x")
    (tmp_path / "to_folder").symlink_to(tmp_path / "folder")
    (tmp_path / "to_file").symlink_to(tmp_path / "file")
    (tmp_path / "to_nothing").symlink_to(tmp_path / "gone")
    assert dangling_link(tmp_path / "to_nothing") == f"a link to {tmp_path / 'gone'}, which does not exist"
    for name in ("to_folder", "to_file", "folder", "file", "absent"):
        assert dangling_link(tmp_path / name) is None, name


def test_an_output_under_a_link_to_nothing_names_the_link(tmp_path):
    """Mutation round 12: ``staged_outputs`` given an output whose folder is a symbolic link to nothing (no folder can
    be made in its place) says so, naming the link and its target, not only "File exists".  Truth: the link made
    here."""
    (tmp_path / "out").symlink_to(tmp_path / "gone")
    with pytest.raises(WarpbwError, match=r"x\.json: cannot write \(.*out is a link to .*gone, which does not "
                                          r"exist\)"):
        with staged_outputs([tmp_path / "out" / "x.json"]) as at:
            at[tmp_path / "out" / "x.json"].write_text("{}")
    assert not (tmp_path / "gone").exists()


def test_the_mode_of_a_new_output_where_proc_gives_no_umask(monkeypatch):
    """Where /proc/self/status does not open (no /proc, a kernel before 4.7 lacks its Umask line too), the umask is
    read by setting it (os.umask), not taken for 0: a new output gets 0666 less the umask (truth: os.umask's own)."""
    import builtins

    import warpbw.io.staged as staged

    real_open = builtins.open

    def no_proc(path, *a, **kw):
        if str(path).startswith("/proc/"):
            raise FileNotFoundError(2, "No such file or directory", str(path))
        return real_open(path, *a, **kw)

    previous = os.umask(0o027)
    try:
        monkeypatch.setattr(builtins, "open", no_proc)
        assert staged._umask_from_proc() is None
        assert staged._new_file_mode() == 0o640
    finally:
        monkeypatch.undo()
        os.umask(previous)
