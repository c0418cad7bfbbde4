"""The synthetic world plugin: its schema, its target placement and the campaign's draws."""

from __future__ import annotations

import math

import numpy as np
import pytest
from eaglemission.lab.world.synthetic import SyntheticWorld, SyntheticWorldConfig

from eaglemission import registry
from eaglemission.config import load_config
from eaglemission.errors import ConfigError
from eaglemission.flight.assembly import build_world
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


def test_campaign_draws_are_fixed_by_the_seed() -> None:
    """Seeds, distractor kinds and colours of the first 5 worlds of `campaign --seed 7`: a
    change of draw order would change every campaign figure the docs quote."""
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


# The world keys drawn from the campaign's RNG (the imaging effects come from the world seed).
KEYS_WITHOUT_IMAGING = {
    "seed", "target_north_m", "target_east_m", "target_yaw_deg", "ground_texture",
    "ground_image", "distractors", "light_gain", "noise_sigma", "wind_ne_mps",
    "mount_error_deg", "focal_error_fraction", "camera_time_offset_s", "frame_rate_hz"}


def _campaign_worlds(seed: int, runs: int, **kw: object) -> list[dict]:
    """The world params of runs 0..runs-1 of ``campaign --seed SEED``, drawn as it draws."""
    from eaglemission.lab.campaign.campaign import randomise

    base = load_config()
    rng = np.random.RandomState(seed)
    out = []
    for _ in range(runs):
        cfg = randomise(base, np.random.RandomState(int(rng.randint(0, 2**31 - 1))), **kw)
        assert cfg.world is not None
        out.append(cfg.world.params)
    return out


def test_imaging_draws_leave_the_other_draws_of_50_runs_unchanged() -> None:
    """The params of runs 0-49 of `campaign --seed 7` and `--seed 3`, apart from the imaging
    keys, hash as they do with `--no-imaging-effects` (sha256 of their sorted JSON), and world
    521 of seed 3 (the square box of tests/missions/test_candidate_rejection.py) is as
    drawn there."""
    import hashlib
    import json

    expected = {7: "f41219c2c236c9776f4de9913493bea984d31797723d06e6cc07ddebda594a52",
                3: "9d1e630b9300c0f534b7fe3dea6e4c23c958c7abbc1d0fae8ae003894fbbd366"}
    for seed, digest in expected.items():
        worlds = _campaign_worlds(seed, 50)
        assert all(set(SyntheticWorld.imaging_keys) <= set(w) for w in worlds)
        old = [{k: v for k, v in w.items() if k in KEYS_WITHOUT_IMAGING} for w in worlds]
        assert all(set(o) == KEYS_WITHOUT_IMAGING for o in old)
        blob = json.dumps(old, sort_keys=True)
        assert hashlib.sha256(blob.encode()).hexdigest() == digest, f"seed {seed}"
    w521 = _campaign_worlds(3, 522)[521]
    assert w521["seed"] == 1505987167 and w521["ground_texture"] == "soil"
    assert w521["target_north_m"] == pytest.approx(28.016978156996938, abs=1e-12)
    assert w521["light_gain"] == pytest.approx(0.7219598757267537, abs=1e-12)
    assert [d["kind"] for d in w521["distractors"]] == ["box", "disc"]


def test_imaging_effects_are_drawn_from_the_world_seed() -> None:
    """Motion blur and BayerRG in every run, white balance within its ranges, JPEG 60-95 in
    about half of the runs; the same seed draws the same effects; --no-imaging-effects keeps
    the mission file's (all off)."""
    from eaglemission.lab.world.synthetic import (
        WB_TEMPERATURE_LOG_GAIN,
        WB_TINT_LOG_GAIN,
        imaging_draws,
    )

    worlds = _campaign_worlds(7, 50)
    assert all(w["motion_blur"] and w["bayer_pattern"] == "BayerRG" for w in worlds)
    for w in worlds:
        b, g, r = w["white_balance_gains_bgr"]
        assert abs(math.log(r)) <= WB_TEMPERATURE_LOG_GAIN and b * r == pytest.approx(1.0)
        assert abs(math.log(g)) <= WB_TINT_LOG_GAIN
        SyntheticWorldConfig.model_validate(w)
    assert len({w["white_balance_gains_bgr"] for w in worlds}) == 50
    qualities = [w["jpeg_quality"] for w in worlds if w["jpeg_quality"] is not None]
    assert 15 <= len(qualities) <= 35 and all(60 <= q <= 95 for q in qualities)
    assert imaging_draws(worlds[3]["seed"]) == {k: worlds[3][k]
                                                for k in SyntheticWorld.imaging_keys}
    plain = _campaign_worlds(7, 5, imaging_effects=False)
    for p, w in zip(plain, worlds):
        assert {k: p[k] for k in KEYS_WITHOUT_IMAGING} == {k: w[k] for k in KEYS_WITHOUT_IMAGING}
        assert (p["white_balance_gains_bgr"], p["motion_blur"], p["bayer_pattern"],
                p["jpeg_quality"]) == ((1.0, 1.0, 1.0), False, None, None)


def test_imaging_keys_are_validated_with_their_path() -> None:
    with pytest.raises(ConfigError, match=r"world.params.jpeg_quality: must be <= 100"):
        registry.validate_params("worlds", "synthetic", {"jpeg_quality": 101},
                                 path="world.params")
    with pytest.raises(ConfigError, match=r"world.params.bayer_pattern"):
        registry.validate_params("worlds", "synthetic", {"bayer_pattern": "RGGB"},
                                 path="world.params")
    with pytest.raises(ConfigError, match=r"world.params.white_balance_gains_bgr"):
        registry.validate_params("worlds", "synthetic",
                                 {"white_balance_gains_bgr": [1.0, 0.0, 1.0]}, path="world.params")
