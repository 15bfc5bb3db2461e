"""examples/allocation_ceiling.py: the oracle's noise gains against closed forms on Lambert spheres under a
constant sky, where every pixel of one sphere has the same one-step variance, proportional to albedo^2."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from conftest import ROOT, load_example
from warpbw.pipeline import prepare_scene
from warpbw.scene import parse_scene

SCENE = """
[camera]
position = [0.0, 0.0, 6.0]
look_at = [0.0, 0.0, 0.0]
fov = 30.0
resolution = [48, 24]
[environment]
constant = [1.0, 1.0, 1.0]
{objects}
[material.bright]
type = "lambert"
albedo = [0.8, 0.8, 0.8]
[material.dark]
type = "lambert"
albedo = [0.2, 0.2, 0.2]
"""
SPHERE = '[[object]]\nshape = "sphere"\ncenter = [{x}, 0.0, 0.0]\nradius = 0.7\nmaterial = "{m}"\n'


@pytest.fixture(scope="module")
def ac():
    return load_example("allocation_ceiling")


def scene(*spheres):
    return parse_scene(SCENE.format(objects="".join(SPHERE.format(x=x, m=m) for x, m in spheres)))


def test_one_lambert_sphere_has_nothing_to_allocate(ac):
    """Under a constant sky every pixel of a Lambert sphere sees the same integrand in its own frame: v_p is
    constant, so Neyman's allocation is the uniform one (gain 1, up to sqrt(v)'s estimation bias of about
    1 / (2 x seeds)), and so is the oracle on the shaded pixels."""
    r = ac.allocation_ceiling(prepare_scene(scene((0.0, "bright"))), budget=4.0, seeds=32, spp=8)
    assert r["oracle_all"] < 1.06   # never below 1 (Cauchy-Schwarz): the check is how close it comes
    assert r["oracle_shaded"] == pytest.approx(r["uniform_shaded"], rel=0.06)
    assert 0.0 < r["shaded_fraction"] < 0.2      # nothing varies: a few coarse texels are shaded


def test_two_albedos_give_the_closed_form_neyman_gain(ac):
    """Spheres of albedo 0.8 and 0.2: v_p proportional to albedo^2, so with n_1 and n_2 pixels the oracle gain is
    (n_1 a_1^2 + n_2 a_2^2) (n_1 + n_2) / (n_1 a_1 + n_2 a_2)^2 (1.36 for equal counts)."""
    prep = prepare_scene(scene((-1.0, "bright"), (1.0, "dark")))
    cov, v = ac.per_pixel_variance(prep, seeds=32, spp=8)
    left = np.zeros(cov.shape, bool)
    left[:, : cov.shape[1] // 2] = True
    n1, n2 = int((cov & left).sum()), int((cov & ~left).sum())
    assert n1 == n2 > 50
    np.testing.assert_allclose(np.median(v[cov & left]) / np.median(v[cov & ~left]), 16.0, rtol=0.1)
    expect = (n1 * 0.64 + n2 * 0.04) * (n1 + n2) / (n1 * 0.8 + n2 * 0.2) ** 2
    r = ac.allocation_ceiling(prep, budget=4.0, seeds=32, spp=8)
    assert r["oracle_all"] == pytest.approx(expect, rel=0.05)
    assert r["frame"] <= r["oracle_shaded"] * 1.0001   # nothing beats Neyman's with the same samples on the same pixels


def test_noise_gain_and_neyman_by_hand(ac):
    v = np.array([4.0, 1.0])
    n = ac.neyman(np.sqrt(v), 6.0)                    # 2 : 1
    np.testing.assert_allclose(n, [4.0, 2.0])
    # reference at 3 spp: (4 + 1) / 3; allocation: 4 / 4 + 1 / 2 = 1.5 (sums over pixels: the 1 / n_cov cancels)
    assert ac.noise_gain(v, v, n, 3.0) == pytest.approx((5 / 3) / 1.5)
    # a floor of one sample: weights 9 : 1 : 1 : 1 over 8 samples want 6 and 2/3 each; the floor gives 1 each
    # to the three, 5 to the first
    np.testing.assert_allclose(ac.neyman(np.array([9.0, 1.0, 1.0, 1.0]), 8.0, 1.0), [5.0, 1.0, 1.0, 1.0], rtol=1e-9)
    np.testing.assert_allclose(ac.neyman(np.array([9.0, 1.0, 1.0, 1.0]), 8.0), [6.0, 2 / 3, 2 / 3, 2 / 3])
    # only the first pixel shaded, the second noise-free: 4 / 6 against (4 + 1) / 3
    assert ac.noise_gain(v, v[:1], np.array([6.0]), 3.0) == pytest.approx((5 / 3) / (4 / 6))


def test_command_line_writes_json_and_refuses_to_overwrite(tmp_path):
    p = tmp_path / "s.toml"
    p.write_text(SCENE.format(objects=SPHERE.format(x=0.0, m="bright")))
    out = tmp_path / "c.json"
    cmd = [sys.executable, str(ROOT / "examples" / "allocation_ceiling.py"), str(p), "--budget", "2", "--seeds", "4",
           "--spp", "2", "--json", str(out)]
    r = subprocess.run(cmd, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "oracle, every pixel shaded" in r.stdout
    rec = json.loads(out.read_text())
    assert rec["budget"] == 2.0 and rec["covered_pixels"] > 0
    r = subprocess.run(cmd, capture_output=True, text=True)
    assert r.returncode == 2 and "--force" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    r = subprocess.run(cmd[:3] + ["--seeds", "1"], capture_output=True, text=True)
    assert r.returncode == 2 and "--seeds" in r.stderr
