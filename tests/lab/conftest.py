"""Fixtures of the synthetic world and camera tests: a small world, its target, two camera
models."""

from __future__ import annotations

import pytest
from _camera_helpers import TARGET_NE
from eaglemission.lab.world.synthetic import SyntheticWorldConfig

from eaglemission.config import TargetConfig
from eaglemission.geometry import CameraModel, CameraMount


@pytest.fixture
def sim_config() -> SyntheticWorldConfig:
    return SyntheticWorldConfig(seed=3, target_north_m=TARGET_NE[0], target_east_m=TARGET_NE[1],
                            target_yaw_deg=35.0, ground_texture="snow", noise_sigma=0.0,
                            mount_error_deg=2.0, focal_error_fraction=0.03)


@pytest.fixture
def target_config() -> TargetConfig:
    return TargetConfig(length_m=0.4, width_m=0.25, height_m=0.15, color_bgr=(200, 30, 200))


@pytest.fixture
def wide_model() -> CameraModel:
    return CameraModel.from_lens("wide", focal_length_mm=2.8,
                                 mount=CameraMount(0.0, -30.0, 0.0, (0.1, -0.03, 0.05)))


@pytest.fixture
def narrow_model() -> CameraModel:
    return CameraModel.from_lens("narrow", focal_length_mm=12.0,
                                 mount=CameraMount(0.0, -30.0, 0.0, (0.1, 0.03, 0.05)))
