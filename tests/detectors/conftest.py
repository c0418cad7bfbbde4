"""Fixtures for the real-footage tests: ../shared's UAV sequences and aerial ground photos."""

from __future__ import annotations

from pathlib import Path

import pytest


@pytest.fixture
def uav_tracking(shared: Path) -> Path:
    p = shared / "data" / "uav_tracking"
    if not p.is_dir():
        pytest.skip("uav_tracking data absent from ../shared")
    return p


@pytest.fixture
def aerial_ground(shared: Path) -> Path:
    p = shared / "data" / "aerial_ground"
    if not p.is_dir():
        pytest.skip("aerial_ground photos absent from ../shared")
    return p
