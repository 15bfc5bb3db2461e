"""``warpbw-precompute info FILE...`` (precompute.asset_info): what an asset file holds.

Truths used here come from outside the code under test: the arrays and parameters the tests write (real files of
each format, made by warpbw-precompute's own writers from tables made by hand), the source's content hash computed
here with hashlib, NumPy's reading of the archive's arrays, and headers rewritten here with NumPy to another version,
another format or other settings.  Bad input (missing, damaged, non-asset files) is in test_bad_input.py.
"""
from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path

import numpy as np
import pytest
from conftest import fake_npf_table, uniform_sampler_table
from conftest import rewrite_asset as rewrite

from precompute.__main__ import main

HEADER = "__header__"


def numpy_arrays(path: Path) -> dict:
    with np.load(path) as z:
        return {k: z[k] for k in z.files if k != HEADER}


def info(capsys, *argv) -> tuple[int, str, str]:
    code = main(["info", *map(str, argv)])
    out, err = capsys.readouterr()
    return code, out, err


def info_json(capsys, *argv) -> tuple[int, list]:
    code, out, err = info(capsys, "--json", *argv)

    def no_constants(name):   # strict JSON: a NaN or Infinity here is a bug
        raise AssertionError(f"non-strict JSON constant {name} in {out}")
    return code, json.loads(out, parse_constant=no_constants)


def block(out: str, path) -> str:
    """The block of ``out`` that starts with the line ``path``."""
    blocks = {b.splitlines()[0]: b for b in out.strip().split("\n\n")}
    return blocks[str(path)]


@pytest.fixture(scope="module")
def assets(tmp_path_factory):
    """One real file of each format: sampling tables and a nu_rho table of an NPF material (tables made by hand, the
    writers' own files), a GMM mipmap written by ``warpbw-precompute gmm`` and a probe's nu_a cache entry."""
    from precompute.brdf_bandwidth import write_brdf_bandwidth
    from precompute.brdf_sampling import brdf_source, write_sampling
    from precompute.surfaces import dunes
    from warpbw.bandwidth import env_bandwidth_map

    d = tmp_path_factory.mktemp("assets")
    npf = fake_npf_table(d / "npf.bin")
    source = brdf_source(npf, "chrome")
    nu_rho = (np.arange(16 ** 3, dtype=np.float32).reshape(16, 16, 16) % 29) * 0.5 + 0.25   # 0.25 .. 14.25
    out = {
        "npf": npf, "nu_rho": nu_rho,
        "npf_digest": hashlib.blake2b(npf.read_bytes(), digest_size=16).hexdigest(),
        "sampling": write_sampling(d / "chrome.sampling.npz", uniform_sampler_table(), source),
        "bandwidth": write_brdf_bandwidth(d / "chrome.bandwidth.npz", nu_rho, source),
        "gmm": d / "dunes.gmm.npz",
        "dunes_digest": hashlib.blake2b(np.ascontiguousarray(dunes(16)).tobytes(), digest_size=16).hexdigest(),
    }
    assert main(["gmm", "surface:dunes:16", "-o", str(out["gmm"]), "--components", "2", "--prior", "0.5", "-q"]) == 0
    cache = d / "cache"
    rng = np.random.default_rng(1)
    env_bandwidth_map(rng.random((8, 16, 3)).astype(np.float32), name="probe.exr", cache=cache)
    (out["env"],) = cache.glob("env-bandwidth-*.npz")
    return out


def test_each_format_is_named_read_and_its_arrays_ranged(assets, capsys):
    """Format, version, what the file is, "read yes", source and hash (abbreviated in text, whole in JSON), writer,
    params, settings current, and each array's shape, dtype and range as NumPy reads the archive."""
    from warpbw import __version__

    files = [assets[k] for k in ("sampling", "bandwidth", "gmm", "env")]
    code, out, err = info(capsys, *files)
    assert code == 0 and err == "", err
    code, records = info_json(capsys, *files)
    assert code == 0 and [r["path"] for r in records] == [str(f) for f in files]
    expected = {
        "sampling": ("warpbw.brdf-sampling", 2, "importance-sampling tables of a tabulated BRDF (002 Sec. 3.3)",
                     "npf.bin:chrome", f"{assets['npf_digest']}:chrome"),
        "bandwidth": ("warpbw.brdf-bandwidth", 4,
                      "angular bandwidth table nu_rho of a tabulated BRDF (002 Sec. 2.3)", "npf.bin:chrome",
                      f"{assets['npf_digest']}:chrome"),
        "gmm": ("warpbw-gmm-mipmap", 2, "GMM normal mipmap (004 Sec. 4.1)", "surface:dunes:16",
                assets["dunes_digest"]),
        "env": ("warpbw.env-bandwidth", 5, "a probe's angular bandwidth map nu_a", "probe.exr",   # named by it
                "blake2b:" + re.search(r"-([0-9a-f]{32})-v5\.npz$", assets["env"].name).group(1)),
    }
    for (key, (fmt, version, what, source, digest)), rec in zip(expected.items(), records):
        text = block(out, assets[key])
        assert (rec["format"], rec["version"], rec["reads"], rec["not_read"]) == (fmt, version, True, None), rec
        assert rec["what"].startswith(what) and rec["source"] == source and rec["writer"] == f"warpbw {__version__}"
        assert f"  format    {fmt} version {version}: {what}" in text, text
        assert "\n  read      yes\n" in text and f"\n  writer    warpbw {__version__}\n" in text, text
        assert rec["settings"] == "current" and "\n  settings  current" in text, text
        assert rec["source_hash"] == digest, rec["source_hash"]
        hex_digits = re.search(r"[0-9a-f]{32}", digest).group(0)
        shown = f"\n  source    {source} ({digest.replace(hex_digits, hex_digits[:12] + '...')})\n"
        assert shown in text and hex_digits not in text.split("\n", 1)[1], (shown, text)
        arrays = numpy_arrays(assets[key])
        assert [a["name"] for a in rec["arrays"]] == list(arrays)
        for a in rec["arrays"]:
            truth = arrays[a["name"]]
            assert (a["shape"], a["dtype"], a["non_finite"]) == (list(truth.shape), str(truth.dtype), 0), a
            assert (a["min"], a["max"]) == (float(truth.min()), float(truth.max())), a
            shown = "x".join(map(str, truth.shape))
            assert re.search(rf"  {a['name']} +{shown} {truth.dtype}  {float(truth.min()):.6g} \.\. "
                             rf"{float(truth.max()):.6g}$", text, re.M), (a, text)
    # the nu_rho table holds what was written
    bw = records[1]["arrays"][0]
    assert (bw["name"], bw["min"], bw["max"]) == ("nu_rho", 0.25, 14.25)
    # the parameters passed to warpbw-precompute gmm, and the mipmap's levels (16, 8, 4, 2, 1 texels a side)
    gmm = records[2]
    assert (gmm["params"]["components"], gmm["params"]["prior"], gmm["levels"], gmm["components"]) == (2, 0.5, 5, 2)
    assert [a["shape"] for a in gmm["arrays"]] == [[s, s, 2, 4] for s in (16, 8, 4, 2, 1)]
    text = block(out, assets["gmm"])
    assert re.search(r"^  params    components +2$", text, re.M) and re.search(r"^ +prior +0\.5$", text, re.M), text
    assert "\n  mipmap    5 levels of 2 components per texel\n" in text, text
    assert records[3]["params"]["signal"] == "log"


def test_another_version_or_format_is_not_read(assets, tmp_path, capsys):
    """A file rewritten to version 1 reads "no: version 1, this warpbw reads 2" (its settings unchecked); a format
    warpbw does not know is said to be one; either is shown whole, exit 0."""
    old = rewrite(assets["sampling"], tmp_path / "old.npz", version=1)
    other = rewrite(assets["bandwidth"], tmp_path / "other.npz", format="someone.elses-table")
    code, out, err = info(capsys, old, other)
    assert code == 0 and err == "", err
    assert "\n  read      no: version 1, this warpbw reads 2\n" in block(out, old)
    assert "\n  settings  not checked" in block(out, old)
    text = block(out, other)
    assert "\n  format    someone.elses-table version 4\n" in text, text   # the bandwidth table it was copied from
    assert "\n  read      no: 'someone.elses-table' is not a format warpbw reads\n" in text, text
    code, (r_old, r_other) = info_json(capsys, old, other)
    assert (r_old["reads"], r_old["version"], r_old["settings"]) == (False, 1, None)
    assert (r_other["reads"], r_other["what"], r_other["settings"]) == (False, None, None)
    assert r_other["arrays"][0]["max"] == 14.25


@pytest.mark.parametrize("key,params,drop,differ", [
    ("gmm", {"seed": 3}, (), "seed 3, the builder's 0"),
    ("sampling", {"subcells": 5}, (), "subcells 5, the builder's 3"),
    ("sampling", {}, ("subcells",), None),                    # before session 71: built with 3, unrecorded
    ("bandwidth", {"epsilon": 0.02}, (), "epsilon 0.02, the builder's 0.01"),
    ("bandwidth", {}, ("wavelet", "epsilon"), None),          # db4 and 0.01 unrecorded
    ("bandwidth", {"resolution": 64}, (), "resolution 64, the builder's 128"),
    ("env", {"signal": "radiance"}, (), None),                # a radiance map's settings: the signal is its key
    ("env", {}, ("signal",), None),                           # before session 58: radiance
    ("env", {"energy_fraction": 0.9}, (), "energy_fraction 0.9, the builder's 0.95"),
], ids=["gmm seed", "sampling subcells", "sampling unrecorded", "bandwidth epsilon", "bandwidth unrecorded",
        "bandwidth resolution", "env radiance", "env unrecorded", "env energy"])
def test_the_settings_check_is_the_cache_readers(assets, tmp_path, capsys, key, params, drop, differ):
    """A header rewritten with other builder settings says which differs (settings_mismatch's words) and what that
    means; one that leaves out a setting its builder's older files did not record is current."""
    f = rewrite(assets[key], tmp_path / "edited.npz", params=params, drop=drop)
    code, out, err = info(capsys, f)
    assert code == 0 and err == "", err
    code, (rec,) = info_json(capsys, f)
    if differ is None:
        assert rec["settings"] == "current" and "\n  settings  current" in out, out
        return
    note = ("a cache entry like this is rebuilt" if key == "env" else
            "a cache entry like this is rebuilt; a file a scene names is read as it is")
    assert (rec["settings"], rec["settings_differ"], rec["settings_note"]) == ("differ", differ, note), rec
    assert f"\n  settings  differ: {differ} ({note})\n" in out, out
    assert rec["reads"] is True    # a file a scene names is read whatever its settings


def test_a_damaged_table_shows_its_non_finite_values(assets, tmp_path, capsys):
    """NaN and infinities planted in a nu_rho table: counted, the range of the finite rest given, the reader's refusal
    quoted; the JSON stays strict (a NaN parameter in the header is null)."""
    t = assets["nu_rho"].copy()
    t[0, 0, :3] = np.nan
    t[5, 5, 5] = -np.inf
    t[1, 2, 3] = 99.0     # beyond what an analysis at 128 gives, finite
    f = rewrite(assets["bandwidth"], tmp_path / "damaged.npz", arrays={"nu_rho": t}, params={"epsilon": float("nan")})
    code, out, err = info(capsys, f)
    assert code == 0 and err == "", err
    assert re.search(r"^  arrays    nu_rho  16x16x16 float32  0\.25 \.\. 99, 4 NaN or infinite$", out, re.M), out
    assert "\n  read      no: table has negative or non-finite bandwidths (rebuild it with: " in out, out
    code, (rec,) = info_json(capsys, f)
    a = rec["arrays"][0]
    assert (a["min"], a["max"], a["non_finite"], rec["reads"]) == (0.25, 99.0, 4, False), rec
    assert rec["params"]["epsilon"] is None and rec["settings"] == "differ"


def test_long_lists_are_cut_in_text_and_whole_in_json(assets, tmp_path, capsys):
    f = rewrite(assets["gmm"], tmp_path / "long.npz", params={"weights": list(range(20))})
    code, out, err = info(capsys, f)
    assert re.search(r"^ +weights +\[0, 1, 2, 3, 4, 5, \.\.\. \(20 items\)\]$", out, re.M), out
    code, (rec,) = info_json(capsys, f)
    assert rec["params"]["weights"] == list(range(20))


def test_help_says_what_it_prints(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["info", "--help"])
    assert stop.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    for words in ("format and version", "whether this warpbw reads it", "content hash", "least and greatest finite",
                  "NaN or infinite", "the other files are still shown", "exits 2", "--json"):
        assert words in text, words
