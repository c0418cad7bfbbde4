"""The manipulator role: the workspace's geometry, the plugins' conformance, the config
section and its errors."""

from __future__ import annotations

import pytest

from eaglemission import registry
from eaglemission.config import load_config
from eaglemission.config.models import validate_mapping
from eaglemission.errors import ConfigError
from eaglemission.geometry.workspace import Workspace


def test_box_workspace_contains_with_margin() -> None:
    ws = Workspace(shape="box", half_extent_m=(0.10, 0.10, 0.08), margin_m=0.02)
    assert ws.offset_inside((0.08, -0.08, 0.06), ws.margin_m)
    assert not ws.offset_inside((0.081, 0.0, 0.0), ws.margin_m)
    assert ws.offset_inside((0.081, 0.0, 0.0))  # inside the whole workspace
    assert not ws.offset_inside((0.0, 0.0, 0.061), ws.margin_m)


def test_cylinder_workspace_contains_and_clamps() -> None:
    ws = Workspace(shape="cylinder", radius_m=0.10, half_height_m=0.05, margin_m=0.0)
    assert ws.offset_inside((0.07, 0.07, 0.0))  # 0.099 m across
    assert not ws.offset_inside((0.08, 0.08, 0.0))  # 0.113 m across
    x, y, z = ws.clamp_offset((0.3, 0.4, -0.2))
    assert (round(x, 9), round(y, 9), z) == (0.06, 0.08, -0.05)


def test_box_clamp_keeps_inside_points() -> None:
    ws = Workspace()
    assert ws.clamp_offset((0.01, -0.02, 0.03)) == (0.01, -0.02, 0.03)
    assert ws.clamp_offset((0.5, -0.5, 0.5)) == (0.10, -0.10, 0.08)


@pytest.mark.parametrize("name", ["fixed", "simulated_arm", "actuator_servos"])
def test_every_built_in_manipulator_conforms(name: str) -> None:
    assert name in registry.available("manipulators")
    cls = registry.get("manipulators", name)
    assert registry.conformance_problems("manipulators", cls) == []


def test_the_default_manipulator_is_fixed() -> None:
    cfg = load_config()
    assert cfg.manipulator.type == "fixed"


def _with(manipulator: object, vehicle_type: str | None = None) -> dict:
    data = load_config().model_dump()
    data["manipulator"] = manipulator
    return data


def test_an_unknown_manipulator_is_named_with_the_available_ones() -> None:
    with pytest.raises(ConfigError) as exc:
        validate_mapping(_with({"type": "robot_arm"}))
    text = str(exc.value)
    assert "manipulator.type" in text and "simulated_arm" in text


def test_an_arm_wider_than_the_simulated_one_is_refused() -> None:
    bad = {"type": "simulated_arm",
           "params": {"workspace": {"half_extent_m": [0.2, 0.1, 0.08]}}}
    with pytest.raises(ConfigError) as exc:
        validate_mapping(_with(bad))
    assert "manipulator.params" in str(exc.value) and "0.10" in str(exc.value)


def test_the_servo_arm_needs_the_mavsdk_vehicle() -> None:
    with pytest.raises(ConfigError) as exc:
        validate_mapping(_with({"type": "actuator_servos"}))
    assert "vehicle.type mavsdk" in str(exc.value)


def test_servo_arm_joints_must_cover_the_workspace() -> None:
    cls = registry.get("manipulators", "actuator_servos")
    with pytest.raises(ValueError, match="widen the joint's travel"):
        cls.Config.model_validate({"joints": [
            {"index": 1, "output": 5, "min_m": -0.05, "max_m": 0.05},
            {"index": 2, "output": 6}, {"index": 3, "output": 7, "min_m": -0.08,
                                        "max_m": 0.08}]})
