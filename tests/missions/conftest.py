"""Fixtures of the mission tests: small, fast simulated mission files."""

from __future__ import annotations

import pytest
from mission_helpers import variant

from eaglemission.config import MissionFile, load_config


@pytest.fixture
def fast_config() -> MissionFile:
    """The embedded mission with a fast, deterministic detector (MSS at 1/2 resolution) so the
    closed-loop tests exercise the MISSION, not a detector under development."""
    cfg = load_config(check_plugins=False)
    return variant(cfg, detector={"type": "mss", "params": {"downscale": 2}})
