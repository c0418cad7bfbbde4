"""Fixtures for the estimator tests: the mission's cameras and target, and the synthetic
world (built once per module: ~3 s)."""

from __future__ import annotations

import pytest
from eaglemission.lab.world.synthetic import world_config

from eaglemission.config import load_config


@pytest.fixture(scope="module")
def mission():
    return load_config(check_plugins=False)


@pytest.fixture(scope="module")
def world(mission):
    world_mod = pytest.importorskip("eaglemission.lab.world.render")
    return world_mod.SyntheticWorld(world_config(mission), mission.target, seed=1, extent_m=80.0)
