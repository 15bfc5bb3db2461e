"""Shared fixtures: where the real test data lives, and a skip when it is absent."""
from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
# ../shared/data beside the repository; WARPBW_SHARED_DATA overrides it.
SHARED_DATA = Path(os.environ.get("WARPBW_SHARED_DATA", ROOT.parent / "shared" / "data"))


def shared_file(rel: str) -> Path:
    """Path of a file under ../shared/data, or skip the test saying why."""
    p = SHARED_DATA / rel
    if not p.exists():
        pytest.skip(f"real test data {p} is absent (clone ../shared beside the repository)")
    return p


def numpy_camera_rays(position, look_at, fov_deg, w, h, jitter=(0.5, 0.5)):
    """The origin and the unit rays (h, w, 3) through the point ``jitter`` (in [0, 1)^2) of every pixel."""
    o = np.asarray(position, float)
    fwd = np.asarray(look_at, float) - o
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    tx = math.tan(math.radians(fov_deg) / 2)
    ty = tx * h / w
    x, y = np.meshgrid(np.arange(w) + jitter[0], np.arange(h) + jitter[1])
    d = fwd + ((2 * x / w - 1) * tx)[..., None] * right + ((1 - 2 * y / h) * ty)[..., None] * up
    return o, d / np.linalg.norm(d, axis=-1, keepdims=True)


@pytest.fixture(scope="session")
def shared():
    return shared_file


# Warp: hide the banner and module-load lines in test output (warp._src.logger.LOG_WARNING).
def pytest_configure(config):
    import warp as wp

    wp.config.log_level = 30
