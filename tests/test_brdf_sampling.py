"""The precomputed tables of a tabulated BRDF (precompute.brdf_sampling): opening a source, reading and caching
tables, the rebuild command a refusal suggests, and the ``brdf-sampling`` / ``brdf`` subcommands' options.

The numeric builders are replaced here by stand-ins that report every step and return a valid table at once
(``warpbw.sampling`` and ``precompute.brdf_bandwidth`` have their own modules); what is tested is what a user is
told and which file is read or written.  Truth: README's documented options, defaults and cache folder, the
precompute parser itself (a rebuild hint must parse as the command that builds that table), sources made by
hand with known names and digests, and the file system.
"""
from __future__ import annotations

import importlib
import io
import re
import shlex
import sys

import numpy as np
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st

from conftest import capture_call, fake_npf_table, killed_writer_temp, outcome, uniform_sampler_table
from precompute.assetfile import write_asset
from precompute.brdf_sampling import BrdfSource, brdf_source, read_sampling, write_sampling
from warpbw.sampling import N_PHI, N_THETA_O, N_U, TABLE_FORMAT, TABLE_VERSION, SamplerTable


def _sampling_table(n_theta_o: int = N_THETA_O) -> SamplerTable:
    """A consistent table of the shapes this warpbw reads."""
    return uniform_sampler_table(n_theta_o)


def _write_raw(path, table: SamplerTable, source) -> None:
    """``table`` as a sampling-table file, whatever its shapes or values (write_sampling would write the same)."""
    write_asset(path, TABLE_FORMAT, TABLE_VERSION, source.name, source.digest,
                {"marginal": table.marginal, "conditional": table.conditional, "density": table.density})


@pytest.fixture
def fast_builders(monkeypatch):
    """The two table builders' numeric cores replaced by stand-ins that report every step to ``progress`` and return
    a valid table at once: the commands, their progress bars and their writers run for real."""
    import precompute.brdf_bandwidth as bb
    import precompute.brdf_sampling as bs
    from precompute.brdf_bandwidth import N_THETA_I, SHAPE

    def sampling(evaluate, progress=None, **kw):
        for k in range(1, N_THETA_O + 1):
            progress(k)
        return _sampling_table()

    def bandwidth(evaluate, resolution=128, progress=None, threads=None):
        for k in range(1, N_THETA_I + 1):
            progress(k)
        return np.full(SHAPE, 2.0, np.float32)

    monkeypatch.setattr(bs, "build_sampler_table", sampling)
    monkeypatch.setattr(bb, "brdf_bandwidth_table", bandwidth)


def _reader(cmd: str):
    from precompute.brdf_bandwidth import read_brdf_bandwidth

    return read_sampling if cmd == "brdf-sampling" else read_brdf_bandwidth


# ------------------------------------------------------------------------------------------ sources and tables


def test_brdf_source_names_an_npf_material_as_the_table_spells_it(tmp_path):
    """read_npf takes " Chrome " for chrome; a table built with ``--material " Chrome "`` is then the chrome table:
    same name and digest, so a scene naming "chrome" reads it (it was refused as "different content", and cached
    under a second key)."""
    npf = fake_npf_table(tmp_path / "npf.bin")
    typed, canonical = brdf_source(npf, " Chrome "), brdf_source(npf, "chrome")
    assert typed.name == canonical.name == "npf.bin:chrome" and typed.material == "chrome"
    write_sampling(tmp_path / "t.npz", _sampling_table(), typed)
    got = outcome(read_sampling, tmp_path / "t.npz", canonical)
    assert got.startswith("returned SamplerTable("), got


def test_a_source_left_unread_is_named_and_digested_as_the_source_read(tmp_path):
    """``brdf_source_unread`` (what ``warpbw info`` hands the tables' readers, without reading the BRDF) gives the name,
    digest, material and lookup of ``brdf_source`` (which reads it), for a MERL file and an NPF material spelt as a
    user may type it, at each lookup and at the kind's default (None); a nu_rho table is then read or refused alike.
    Truth: ``brdf_source`` itself."""
    from precompute.brdf_bandwidth import read_brdf_bandwidth, write_brdf_bandwidth
    from precompute.brdf_sampling import brdf_source_unread
    from warpbw.io.merl import MERL_SHAPE, write_merl

    npf = fake_npf_table(tmp_path / "npf.bin")
    write_merl(tmp_path / "m.binary", np.full(MERL_SHAPE, 0.1))
    write_brdf_bandwidth(tmp_path / "bw.npz", np.full((16, 16, 16), 2.0, np.float32), brdf_source(npf, "chrome"))
    for file, material in ((tmp_path / "m.binary", None), (npf, " Chrome.binary"), (npf, "nylon")):
        for lookup in (None, "nearest", "linear"):
            read, unread = brdf_source(file, material, lookup), brdf_source_unread(file, material, lookup)
            assert (unread.name, unread.digest, unread.material, unread.lookup, unread.path) == \
                   (read.name, read.digest, read.material, read.lookup, read.path), (file, material, lookup)
            assert unread.brdf is None and unread.evaluate is None
            assert outcome(read_brdf_bandwidth, tmp_path / "bw.npz", unread) == \
                   outcome(read_brdf_bandwidth, tmp_path / "bw.npz", read)


def test_tables_of_an_edited_source_of_the_same_name_are_refused(tmp_path):
    """README: the renderer refuses "a table built from different data".  A MERL file edited under the same name has
    another content hash: its old tables are refused, not matched by name."""
    path = tmp_path / "m.binary"
    before = BrdfSource("m.binary", path, "hash-of-the-first-version", None)
    after = BrdfSource("m.binary", path, "hash-of-the-edited-file", None)
    write_sampling(tmp_path / "t.npz", _sampling_table(), before)
    read_sampling(tmp_path / "t.npz", before)
    assert "different content" in outcome(read_sampling, tmp_path / "t.npz", after)


def test_consistent_tables_of_another_resolution_are_refused(tmp_path):
    """The kernels index the tables with warpbw.sampling's N_THETA_O x N_U x N_PHI: a self-consistent table of half
    as many view elevations (an older or a hand-made file) is refused with the rebuild hint."""
    src = BrdfSource("m.binary", tmp_path / "m.binary", "d1", None)
    _write_raw(tmp_path / "t.npz", _sampling_table(N_THETA_O // 2), src)
    got = outcome(read_sampling, tmp_path / "t.npz", src)
    assert f"this warpbw uses {(N_THETA_O, N_U, N_PHI)}" in got and "rebuild it with" in got, got


def test_tables_of_another_resolution_are_not_written(tmp_path):
    """write_sampling writes only what read_sampling reads (its docstring): a consistent table of other shapes was
    written, and the file then refused by every reader of it."""
    src = BrdfSource("m.binary", tmp_path / "m.binary", "d1", None)
    got = outcome(write_sampling, tmp_path / "t.npz", _sampling_table(N_THETA_O // 2), src)
    assert f"the renderer reads {(N_THETA_O, N_U, N_PHI)}" in got and "is not written" in got, got
    assert not (tmp_path / "t.npz").exists()


def test_infinite_tables_are_refused(tmp_path):
    """"tables hold negative or non-finite values": +inf passes a ``>= 0`` test (NaN does not), and an infinite
    density samples NaN directions."""
    src = BrdfSource("m.binary", tmp_path / "m.binary", "d1", None)
    t = _sampling_table()
    t.density[3, 5, 7] = np.inf
    _write_raw(tmp_path / "t.npz", t, src)
    assert "negative or non-finite" in outcome(read_sampling, tmp_path / "t.npz", src)


def test_a_source_without_its_attributes_is_refused_in_one_line():
    """check_brdf_source: an object lacking what the call needs is refused naming the caller and what to pass (it was
    an AttributeError traceback)."""
    from types import SimpleNamespace

    from precompute.brdf_sampling import build_brdf_sampling

    got = outcome(build_brdf_sampling, SimpleNamespace(name="x"), progress=False)
    assert got.startswith("WarpbwError: build_brdf_sampling: source") and "has no evaluate" in got, got
    got = outcome(write_sampling, "t.npz", _sampling_table(), SimpleNamespace(name="x"))
    assert got.startswith("WarpbwError: write_sampling: source") and "has no digest" in got, got


# ------------------------------------------------------------------------------------------ the rebuild command


@pytest.mark.parametrize("cmd", ["brdf-sampling", "brdf"])
@pytest.mark.parametrize("kind", ["npf material", "merl named like one", "folder with a space"])
def test_a_refusal_names_the_command_that_rebuilds_that_table(tmp_path, cmd, kind):
    """The hint in a refusal, split as a POSIX shell splits it and parsed by warpbw-precompute's own parser, is the
    subcommand that builds that kind of table, on the source's file, with --material exactly for an NPF material.
    A MERL file named ``lab:chrome.binary`` was taken for an NPF material (``--material chrome.binary``), the
    bandwidth table's hint could name brdf-sampling, and a folder with a space split the path in two."""
    from precompute.__main__ import build_parser, cmd_brdf, cmd_brdf_sampling

    if kind == "npf material":
        src, material = brdf_source(fake_npf_table(tmp_path / "npf.bin"), "chrome"), "chrome"
    else:
        folder = tmp_path / ("my tables" if kind == "folder with a space" else "t")
        src, material = BrdfSource("lab:chrome.binary", folder / "lab:chrome.binary", "d1", None), None
    write_asset(tmp_path / "old.npz", "another-format", 1, src.name, src.digest, {"x": np.zeros(1)})
    got = outcome(_reader(cmd), tmp_path / "old.npz", src)
    assert got.startswith("WarpbwError: ") and "rebuild it with: " in got, got
    prog, *argv = shlex.split(got.split("rebuild it with: ", 1)[1].rstrip(")"))
    args = build_parser().parse_args(argv)
    assert (prog, args.func, args.file, args.material, args.force) == \
        ("warpbw-precompute", cmd_brdf_sampling if cmd == "brdf-sampling" else cmd_brdf, str(src.path), material,
         True), got
    unknown = outcome(_reader(cmd), tmp_path / "old.npz")   # no source: the command, with placeholders
    assert f"rebuild it with: warpbw-precompute {cmd} SOURCE" in unknown, unknown


# ------------------------------------------------------------------------------------------ the cache


def test_the_cache_defaults_to_dot_cache_warpbw_in_the_home_folder(tmp_path, monkeypatch):
    """README: tables are cached under $WARPBW_CACHE (default ~/.cache/warpbw)."""
    from precompute.brdf_sampling import cache_dir

    monkeypatch.delenv("WARPBW_CACHE", raising=False)
    monkeypatch.setenv("HOME", str(tmp_path))
    assert cache_dir() == tmp_path / ".cache" / "warpbw"


def test_a_cache_folder_is_made_with_its_parents_and_used_when_given(tmp_path, monkeypatch):
    """A cache folder that does not exist yet is made, parents and all ($WARPBW_CACHE = ~/.cache/warpbw on a fresh
    account lacks ~/.cache too), and the second call reads the entry.  A folder passed explicitly (bench-filtering's
    --cache, or its private folder that keeps the measured precompute time honest) is where the entry goes, not
    $WARPBW_CACHE."""
    import precompute.brdf_sampling as bs

    built = []

    def build(source, progress=True):
        built.append(source.name)
        return _sampling_table()

    monkeypatch.setattr(bs, "build_brdf_sampling", build)
    monkeypatch.setenv("WARPBW_CACHE", str(tmp_path / "env_cache"))
    src = BrdfSource("m.binary", tmp_path / "m.binary", "d1", None)
    cache = tmp_path / "a" / "b" / "cache"
    origins = [bs.load_or_build_sampling(src, cache=cache, progress=False)[1] for _ in range(2)]
    assert origins == ["built", "cache"] and built == ["m.binary"]
    assert len(list(cache.glob("sampling-*.npz"))) == 1
    assert not (tmp_path / "env_cache").exists()


def test_reading_a_cache_entry_removes_what_a_killed_writer_of_it_left(tmp_path, monkeypatch):
    """Two runs build one cache entry at once and one is killed while it writes (SIGKILL: a scheduler's preemption,
    the OOM killer); the other writes the entry whole, and every later run reads it.  No run wrote the entry again,
    so the killed one's hidden temporary (as large as the entry) stayed in the cache for good; reading the entry now
    removes it, and the entry is read as it was.  Truth: a real process killed while it wrote the entry."""
    import precompute.brdf_sampling as bs

    built = []

    def build(source, progress=True):
        built.append(source.name)
        return _sampling_table()

    monkeypatch.setattr(bs, "build_brdf_sampling", build)
    src = BrdfSource("m.binary", tmp_path / "m.binary", "d1", None)
    cache = tmp_path / "cache"
    assert bs.load_or_build_sampling(src, cache=cache, progress=False)[1] == "built"
    (entry,) = cache.iterdir()
    whole = entry.read_bytes()
    killed_writer_temp(entry)
    table, origin = bs.load_or_build_sampling(src, cache=cache, progress=False)
    assert origin == "cache" and built == ["m.binary"] and np.array_equal(table.density, _sampling_table().density)
    assert list(cache.iterdir()) == [entry] and entry.read_bytes() == whole


def test_a_cache_entry_of_other_builder_settings_is_rebuilt_and_one_of_equal_settings_read(tmp_path, monkeypatch):
    """A sampling table records the settings it was built with.  A cache entry that records others (view_subsamples
    2: warpbw.sampling.VIEW_SUBSAMPLES changed without a version bump served the old tables, session 70) is stale:
    rebuilt, as a fresh build, and replaced.  One of the builder's settings is read without a build, and so is one
    written before session 71, which records no subcells (3 then); the constant itself changed makes it stale.  A
    file the scene names is read whatever settings it records."""
    import precompute.brdf_sampling as bs
    import warpbw.sampling as ws
    from precompute.assetfile import read_header

    assert bs.sampling_settings() == {"n_theta_o": ws.N_THETA_O, "n_u": ws.N_U, "n_phi": ws.N_PHI,
                                      "view_subsamples": ws.VIEW_SUBSAMPLES, "subcells": ws.SUBCELLS,
                                      "luminance": [0.2126, 0.7152, 0.0722]}   # Rec. 709
    src = brdf_source(fake_npf_table(tmp_path / "npf.bin"), "chrome")
    fresh = bs.build_brdf_sampling(src, progress=False)
    builds = []
    real = bs.build_brdf_sampling

    def counting(source, progress=True):
        builds.append(source.name)
        return real(source, progress=progress)

    def same(a, b):
        return all(np.array_equal(getattr(a, k), getattr(b, k)) for k in ("marginal", "conditional", "density"))

    monkeypatch.setattr(bs, "build_brdf_sampling", counting)
    cache = tmp_path / "cache"
    cache.mkdir()
    entry = cache / f"sampling-{src.digest.replace(':', '-').replace('/', '_')}-v{TABLE_VERSION}.npz"
    other = _sampling_table()   # valid tables, not this BRDF's
    arrays = {"marginal": other.marginal, "conditional": other.conditional, "density": other.density}
    before_71 = {"n_theta_o": N_THETA_O, "n_u": N_U, "n_phi": N_PHI, "view_subsamples": ws.VIEW_SUBSAMPLES}
    write_asset(entry, TABLE_FORMAT, TABLE_VERSION, src.name, src.digest, arrays,
                params=dict(before_71, view_subsamples=2))
    table, origin = bs.load_or_build_sampling(src, cache=cache, progress=False)
    assert origin == "built" and builds == [src.name] and same(table, fresh)
    assert read_header(entry)["params"]["view_subsamples"] == ws.VIEW_SUBSAMPLES
    table, origin = bs.load_or_build_sampling(src, cache=cache, progress=False)
    assert origin == "cache" and len(builds) == 1 and same(table, fresh)
    write_asset(entry, TABLE_FORMAT, TABLE_VERSION, src.name, src.digest, arrays, params=before_71, force=True)
    table, origin = bs.load_or_build_sampling(src, cache=cache, progress=False)
    assert origin == "cache" and len(builds) == 1 and same(table, other)
    monkeypatch.setattr(ws, "SUBCELLS", 2)
    table, origin = bs.load_or_build_sampling(src, cache=cache, progress=False)
    assert origin == "built" and len(builds) == 2 and read_header(entry)["params"]["subcells"] == 2
    monkeypatch.setattr(ws, "SUBCELLS", 3)
    # the luminance weights of the importance function, recorded since session 72: an entry from before (Rec. 709's
    # then) is read; other weights make it stale
    write_asset(entry, TABLE_FORMAT, TABLE_VERSION, src.name, src.digest, arrays, params=before_71, force=True)
    assert bs.load_or_build_sampling(src, cache=cache, progress=False)[1] == "cache" and len(builds) == 2
    monkeypatch.setattr(ws, "LUMINANCE", (0.3, 0.6, 0.1))
    assert bs.load_or_build_sampling(src, cache=cache, progress=False)[1] == "built" and len(builds) == 3
    assert read_header(entry)["params"]["luminance"] == [0.3, 0.6, 0.1]
    monkeypatch.undo()
    user = tmp_path / "user.npz"
    write_asset(user, TABLE_FORMAT, TABLE_VERSION, src.name, src.digest, arrays,
                params=dict(before_71, view_subsamples=2, subcells=5))
    table, origin = bs.load_or_build_sampling(src, user, cache=cache, progress=False)
    assert origin == "file" and same(table, other)


def test_progress_reports_k_of_total(tqdm_bars):
    """precompute.progress: the builders call step(k) with the count done, so after step(k) the bar stands at k and
    at the end at total (it stood at 1 + 2 + ... + 16 = 136 of 16)."""
    from precompute.progress import progress_callback

    bars = tqdm_bars
    seen = []
    with progress_callback(16, "x", "item", True) as step:
        for k in range(1, 17):
            step(k)
            seen.append(bars[0].n)
    assert seen == list(range(1, 17)) and bars[0].n == bars[0].total == 16


class _Stream(io.StringIO):
    def __init__(self, tty: bool):
        super().__init__()
        self.tty = tty

    def isatty(self) -> bool:
        return self.tty


@pytest.mark.parametrize("interval, lines", [(0.0, 5), (3600.0, 1)])
def test_off_a_terminal_each_state_of_a_bar_is_a_line_at_most_every_interval(monkeypatch, interval, lines):
    """Off a terminal (a log file, a pipe) tqdm's redraws were carriage returns, ten a second, on one line that never
    ended.  There each state is a line of its own: the first when the bar starts, then at most one per
    ``LOG_INTERVAL_S`` (at 0, one per update; at an hour, none after the first), and nothing when it is erased."""
    from precompute import progress

    stream = _Stream(tty=False)
    monkeypatch.setattr(sys, "stderr", stream)
    monkeypatch.setattr(progress, "LOG_INTERVAL_S", interval)
    with progress.progress_callback(4, "tables", "view", True) as step:
        for k in range(1, 5):
            step(k)
    text = stream.getvalue()
    assert "\r" not in text and text.endswith("\n"), repr(text)
    got = text.splitlines()
    assert len(got) == lines and all(g.startswith("tables:") for g in got), got
    assert got[0].startswith("tables:   0%") and (lines == 1 or got[-1].startswith("tables: 100%")), got


def test_on_a_terminal_a_bar_is_tqdms_own():
    """A terminal keeps the bar redrawn in place (no options), and a stream without isatty counts as no terminal."""
    from precompute.progress import LOG_INTERVAL_S, bar_options

    assert bar_options(_Stream(tty=True)) == {}
    opts = bar_options(object())
    assert opts["mininterval"] == opts["maxinterval"] == LOG_INTERVAL_S > 1


# ------------------------------------------------------------------------------------------ the subcommands


@pytest.mark.parametrize("cmd", ["brdf-sampling", "brdf"])
def test_force_replaces_an_existing_table(tmp_path, monkeypatch, fast_builders, cmd):
    """--force ("overwrite an existing output") reaches the writer: the file is replaced by a table the renderer's
    reader takes as built from that source (it was built, then refused with "already exists")."""
    from precompute.__main__ import main

    monkeypatch.chdir(tmp_path)
    fake_npf_table(tmp_path / "npf.bin")
    (tmp_path / "t.npz").write_bytes(b"an older table")
    assert outcome(main, [cmd, "npf.bin", "--material", "chrome", "-o", "t.npz", "--force", "-q"]) == "returned 0"
    _reader(cmd)(tmp_path / "t.npz", brdf_source(tmp_path / "npf.bin", "chrome"))


@pytest.mark.parametrize("cmd,module,builder", [("brdf-sampling", "precompute.brdf_sampling", "build_brdf_sampling"),
                                                ("brdf", "precompute.brdf_bandwidth", "build_brdf_bandwidth")])
def test_a_table_is_written_to_an_npz_name_only(tmp_path, monkeypatch, capsys, cmd, module, builder):
    """README: the assets warpbw-precompute writes (besides npf-to-merl's .binary) are .npz archives; --help: "a name
    ending in .npz".  A .gmm name is the GMM mipmap's: refused before any work."""
    from precompute.__main__ import main

    monkeypatch.chdir(tmp_path)
    fake_npf_table(tmp_path / "npf.bin")
    got = capture_call(monkeypatch, importlib.import_module(module), builder)
    assert outcome(main, [cmd, "npf.bin", "--material", "chrome", "-o", "t.gmm", "-q"]) == "returned 2"
    assert got == {} and "-o t.gmm: expected a path ending in .npz" in capsys.readouterr().err
    assert not (tmp_path / "t.gmm").exists()


@pytest.mark.parametrize("cmd", ["brdf-sampling", "brdf"])
def test_the_source_as_its_own_output_is_refused_before_it_is_read(tmp_path, monkeypatch, capsys, cmd):
    """A source named like a table (``m.npz``) given as -o with --force is refused up front as the file the table is
    made from, whatever --force says; it is not read as a BRDF first."""
    from precompute.__main__ import main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "m.npz").write_bytes(b"the source, whatever it holds")
    assert outcome(main, [cmd, "m.npz", "-o", "m.npz", "--force", "-q"]) == "returned 2"
    err = capsys.readouterr().err
    assert "-o m.npz: would overwrite m.npz, the file it is made from" in err, err
    assert (tmp_path / "m.npz").read_bytes() == b"the source, whatever it holds"


@pytest.mark.parametrize("cmd,bar", [("brdf-sampling", "sampling tables npf.bin:chrome"),
                                     ("brdf", "bandwidth npf.bin:chrome")])
def test_a_progress_bar_unless_quiet(tmp_path, monkeypatch, capsys, fast_builders, cmd, bar):
    """README: "Long renders and precomputes show a progress bar"; -q: "no progress bar"."""
    from precompute.__main__ import main

    monkeypatch.chdir(tmp_path)
    fake_npf_table(tmp_path / "npf.bin")
    assert outcome(main, [cmd, "npf.bin", "--material", "chrome", "-o", "quiet.npz", "-q"]) == "returned 0"
    quiet = capsys.readouterr().err
    assert bar not in quiet and "%|" not in quiet, quiet
    assert outcome(main, [cmd, "npf.bin", "--material", "chrome", "-o", "loud.npz"]) == "returned 0"
    loud = capsys.readouterr().err
    assert bar in loud and "\r" not in loud, repr(loud)   # off a terminal: lines, not redraws (precompute.progress)


def test_the_test_run_caches_into_a_folder_of_its_own(tmp_path_factory):
    """conftest's ``_run_cache``: the tables the tests build go under this run's temporary folder, not the user's
    cache (this machine's ~/.cache/warpbw held 35 tables that test runs had written)."""
    from precompute.brdf_sampling import cache_dir

    base = tmp_path_factory.getbasetemp().resolve()
    assert base in cache_dir().resolve().parents


# ------------------------------------------------------------------------------------ energy: reflects too much

@pytest.mark.parametrize("factor, warns", [(0.98, False), (1.02, True)])
def test_a_merl_table_that_reflects_more_than_the_bound_is_read_with_a_warning_naming_it(tmp_path, factor, warns):
    """A constant table c reflects pi c at every view (a Lambertian's closed form): on either side of ALBEDO_WARN
    it is read, with a warning above it (a table scaled wrongly read without a word)."""
    import warnings

    from precompute.brdf_sampling import ALBEDO_WARN
    from warpbw.io.merl import MERL_SHAPE, write_merl

    write_merl(tmp_path / "m.binary", np.full(MERL_SHAPE, factor * ALBEDO_WARN / np.pi))
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        source = brdf_source(tmp_path / "m.binary")
    assert source.brdf.data.max() > 0
    texts = [str(w.message) for w in said if "times the light it receives" in str(w.message)]
    assert len(texts) == int(warns), [str(w.message) for w in said]
    if warns:
        assert texts[0].startswith(f"m.binary: reflects {factor * ALBEDO_WARN:.3g} times") and "\n" not in texts[0]



@settings(max_examples=40, deadline=None)
@given(rho=st.lists(st.floats(0.0, 4.0), min_size=3, max_size=3))
@example(rho=[0.0, 3.9999999999999996, 4.0])   # G one float64 ulp below B (session 81, at 100x the examples)
def test_a_lambertian_of_any_colour_is_called_too_bright_exactly_when_a_channel_reflects_more_than_the_bound(rho):
    """A Lambertian of albedo rho_c per channel, f = rho_c / pi, reflects exactly rho_c at every view (the
    hemisphere integral of cos / pi is 1).  albedo_excess says so exactly when the brightest channel exceeds
    ALBEDO_WARN, and names that channel and its albedo; pairs within 1e-3 of the bound are left out (the
    midpoint rule is within 1e-4 of the closed form).  Channels whose rho differ by less than the float64 rounding
    of the quadrature are tied, and either may be named: each channel's albedo is rho_c times the same sum of
    N_U * N_PHI positive cell terms, each term a few roundings, so it is off by at most (N + 8) u relative
    (recursive summation's bound, u = 2^-53), and two channels within twice that may come out in either order
    (hypothesis drew G one ulp below B, equal after the sum; at random rho the ratio a_c / rho_c varies across
    channels by up to 3.9e-14, within the 9.1e-13 bound)."""
    from precompute.brdf_sampling import ALBEDO_WARN, albedo_excess
    from warpbw.sampling import N_PHI, N_U

    rho = np.array(rho)
    assume(abs(rho.max() - ALBEDO_WARN) > 1e-3)
    said = albedo_excess(lambda wi, wo: np.broadcast_to(rho / np.pi, (len(wi), 3)))
    assert (said is not None) == (rho.max() > ALBEDO_WARN)
    if said is not None:
        top = re.match(r"reflects ([0-9.]+) times the light it receives", said)
        assert top and float(top.group(1)) == pytest.approx(rho.max(), rel=4e-3)   # 3 digits
        tie = 2.0 * (N_U * N_PHI + 8) * 2.0 ** -53
        named = re.search(r"in the ([RGB]) channel", said)
        assert named and rho["RGB".index(named.group(1))] >= rho.max() * (1.0 - tie), (said, rho.tolist())

def test_a_merl_table_with_every_seventh_entry_at_1e15_warns(tmp_path):
    """Corrupted-file audit (session 63): a finite but absurd entry in every 7th place rendered an image of mean
    2.8e10, without a word (BRDF_VALUE_MAX, 1e20, is an overflow bound, not a plausibility one)."""
    from warpbw.io.merl import MERL_SHAPE, write_merl

    data = np.full(MERL_SHAPE, 0.05).reshape(-1)
    data[::7] = 1e15
    write_merl(tmp_path / "seventh.binary", data.reshape(MERL_SHAPE))
    with pytest.warns(UserWarning, match=r"^seventh\.binary: reflects [0-9.e+]+ times the light it receives"):
        brdf_source(tmp_path / "seventh.binary")


def test_no_material_of_the_real_npf_table_is_said_to_reflect_too_much(shared):
    """The 100 MERL materials' fits (the data the bound is set from): none beyond ALBEDO_WARN, and the largest
    albedo at the checked views is the 1.23 the constant's comment cites (light-red-paint)."""
    from precompute.brdf_sampling import ALBEDO_CHECK_VIEWS_DEG, albedo_excess
    from warpbw.io.npf import NPF_MATERIAL_NAMES, npf_eval, read_npf
    from warpbw.sampling import directional_albedo

    table = shared("brdf/npf.bin")
    top = {}
    for name in NPF_MATERIAL_NAMES:
        mat = read_npf(table, name)
        f = lambda wi, wo: npf_eval(mat, wi, wo)  # noqa: E731
        assert albedo_excess(f) is None, name
        top[name] = float(directional_albedo(f, np.radians(ALBEDO_CHECK_VIEWS_DEG)).max())
    assert max(top, key=top.get) == "light-red-paint" and round(max(top.values()), 2) == 1.23
    # the 1.23 (ALBEDO_CHECK_VIEWS_DEG's comment, and albedo_excess's message) was a figure of directional_albedo
    # itself; here it is derived without it: a(w_o) = int f(w_i, w_o) cos_i dw_i = pi E[f] over cosine-weighted w_i
    # (u = cos_i^2 uniform: cos_i dw_i = du dphi / 2), by the midpoint rule on a 256 x 512 (u, phi) grid (a 1024 x
    # 2048 grid moves it by under 1e-5; directional_albedo agrees to 1e-4)
    n = 256
    u, phi = np.meshgrid((np.arange(n) + 0.5) / n, (np.arange(2 * n) + 0.5) / (2 * n) * 2 * np.pi, indexing="ij")
    wi = np.stack([np.sqrt(1 - u) * np.cos(phi), np.sqrt(1 - u) * np.sin(phi), np.sqrt(u)], -1).reshape(-1, 3)
    mat = read_npf(table, "light-red-paint")
    by_hand = max(float(np.pi * npf_eval(mat, wi, np.broadcast_to([np.sin(t), 0.0, np.cos(t)], wi.shape)).mean(0).max())
                  for t in np.radians(ALBEDO_CHECK_VIEWS_DEG))
    assert round(by_hand, 2) == 1.23 and by_hand == pytest.approx(top["light-red-paint"], abs=1e-3), by_hand


def test_the_sampling_tables_do_not_follow_the_lookup(shared, tmp_path, monkeypatch):
    """Module docstring, "Lookup": the sampling tables are lookup-free (their density is sampled exactly whatever BRDF
    it was tabulated from), so a source read with another lookup than its kind's default gets the default's tables:
    built from the BRDF read at the default (NPF: linear; the evaluator the builder is handed, compared with npf_eval
    at random pairs), cached once under the default's key, written and read under the default's name and digest, and
    a refusal's command carries no --lookup (brdf-sampling has none).  The bandwidth table's cache entry is apart."""
    import precompute.brdf_sampling as bs
    from precompute.brdf_sampling import load_or_build_sampling, rebuild_command, with_lookup
    from warpbw.io.npf import npf_eval

    handed = []

    def build(evaluate, progress=None, **kw):
        handed.append(evaluate)
        return _sampling_table()

    monkeypatch.setattr(bs, "build_sampler_table", build)
    npf = shared("brdf/npf.bin")
    linear = brdf_source(npf, "gold-metallic-paint")
    nearest = with_lookup(linear, "nearest")
    cache = tmp_path / "cache"
    assert load_or_build_sampling(nearest, cache=cache, progress=False)[1] == "built"
    assert load_or_build_sampling(linear, cache=cache, progress=False)[1] == "cache"
    key = linear.digest.replace(":", "-")
    assert [p.name for p in cache.iterdir()] == [f"sampling-{key}-v{TABLE_VERSION}.npz"]
    rng = np.random.default_rng(2)
    wi, wo = (v / np.linalg.norm(v, axis=1, keepdims=True) for v in np.abs(rng.normal(size=(2, 2000, 3))))
    (evaluate,) = handed
    np.testing.assert_array_equal(evaluate(wi, wo), npf_eval(linear.brdf, wi, wo, interpolate=True))
    p = write_sampling(tmp_path / "s.npz", _sampling_table(), nearest)
    read_sampling(p, linear)
    read_sampling(p, nearest)
    other = brdf_source(npf, "chrome")
    said = outcome(read_sampling, p, with_lookup(other, "nearest"))
    assert "with different content than 'npf.bin:chrome'" in said and "--lookup" not in said, said
    assert "--lookup" not in rebuild_command("brdf-sampling", nearest)
    assert rebuild_command("brdf", nearest).endswith("--material gold-metallic-paint --lookup nearest -o OUT --force")
