"""The synthetic world plugin: its schema, its target placement and the campaign's draws."""

from __future__ import annotations

import numpy as np
import pytest
from eaglemission.drivers.worlds.synthetic import SyntheticWorld, SyntheticWorldConfig

from eaglemission import registry
from eaglemission.assembly import build_world
from eaglemission.config import load_config
from eaglemission.errors import ConfigError
from eaglemission.interfaces import World


def test_the_shipped_world_is_a_world_plugin() -> None:
    cfg = load_config()
    world = build_world(cfg)
    assert isinstance(world, SyntheticWorld) and isinstance(world, World)
    assert world.target_ne_m() == (22.0, 1.5) and world.target_yaw_deg == 20.0
    assert registry.conformance_problems("worlds", SyntheticWorld) == []


def test_bad_world_params_name_their_path() -> None:
    with pytest.raises(ConfigError, match=r"world.params.noise_sigma: must be <= 50"):
        registry.validate_params("worlds", "synthetic", {"noise_sigma": 99}, path="world.params")


def test_campaign_draws_are_the_same_as_in_every_campaign_so_far() -> None:
    """Seeds, distractor kinds and colours of the first 5 worlds of `campaign --seed 7`, as
    drawn since the campaign exists: a change of draw order changes every campaign figure."""
    cfg = load_config()
    assert cfg.world is not None
    world = SyntheticWorld(SyntheticWorldConfig.model_validate(cfg.world.params))
    route = [(w.north_m, w.east_m) for w in cfg.mission.route]
    drawn = [world.randomised_params(np.random.RandomState(7 + i), route) for i in range(5)]
    assert [d["seed"] for d in drawn] == [372560217, 186341519, 869419137, 357864157,
                                          1691805514]
    first = [d["distractors"][0] if d["distractors"] else None for d in drawn]
    assert [f and (f["kind"], list(f["color_bgr"])) for f in first] == [
        None, ("box", [135, 222, 175]), ("disc", [137, 111, 181]), None,
        ("stripe", [180, 65, 145])]
    assert drawn[0]["target_north_m"] == pytest.approx(15.220932629983315, abs=1e-12)
    assert drawn[0]["ground_texture"] == "snow"
    for d in drawn:
        SyntheticWorldConfig.model_validate(d)
