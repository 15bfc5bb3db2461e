"""Shared fixtures: where the real test data lives, and a skip when it is absent."""
from __future__ import annotations

import os
from pathlib import Path

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


@pytest.fixture(scope="session")
def shared():
    return shared_file


# Warp: hide the banner and module-load lines in test output (warp._src.logger.LOG_WARNING).
def pytest_configure(config):
    import warp as wp

    wp.config.log_level = 30
