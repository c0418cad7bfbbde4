"""Shared fixtures: seeded RNG, the ../shared data folder, fake clocks."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]


def shared_dir() -> Path | None:
    """``../shared`` next to the checkout (or ``$EAGLEMISSION_SHARED``), None when absent."""
    env = os.environ.get("EAGLEMISSION_SHARED")
    p = Path(env) if env else REPO.parent / "shared"
    return p if p.is_dir() else None


@pytest.fixture
def shared() -> Path:
    p = shared_dir()
    if p is None:
        pytest.skip("../shared is absent (set EAGLEMISSION_SHARED)")
    return p


@pytest.fixture
def davis(shared: Path) -> Path:
    p = shared / "data" / "video_saliency" / "DAVIS2016"
    if not p.is_dir():
        pytest.skip("DAVIS2016 data absent from ../shared")
    return p


@pytest.fixture
def px4_tlogs(shared: Path) -> Path:
    p = shared / "data" / "px4_sitl_tlogs"
    if not p.is_dir():
        pytest.skip("px4_sitl_tlogs absent from ../shared")
    return p


@pytest.fixture
def rng() -> np.random.RandomState:
    return np.random.RandomState(12345)


@pytest.fixture
def sitl_config():
    from eaglemission.config import load_config

    return load_config(check_plugins=False)
