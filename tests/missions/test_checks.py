from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import yaml
from eaglemission.missions.checks import check_mission_geometry
from mission_helpers import variant

from eaglemission.commands.checks import run_checks
from eaglemission.config import load_config


def test_default_geometry_is_valid() -> None:
    assert check_mission_geometry(load_config(check_plugins=False)) == []


def test_standoff_outside_the_narrow_view_is_rejected() -> None:
    cfg = load_config(check_plugins=False)
    bad = variant(cfg, mission={"params": {**cfg.mission.params, "guidance": {
        "standoff": {"horizontal_m": 0.5, "height_m": 3.0}}}})
    problems = check_mission_geometry(bad)
    assert any(p.startswith("mission.params.guidance.standoff") and "narrow" in p for p in problems)


def test_altitude_band_and_geofence() -> None:
    cfg = load_config(check_plugins=False)
    low = variant(cfg, safety={"max_altitude_m": 1.0, "min_altitude_m": 0.0})
    assert any("altitude" in p for p in check_mission_geometry(low))
    fence = variant(cfg, safety={"geofence": {"radius_m": 21.0}},
                    world_params={"target_north_m": 20.5, "target_east_m": 0.0})
    assert any(p.startswith("safety.geofence") for p in check_mission_geometry(fence))
    high = variant(cfg, mission={"cruise_altitude_m": 19.0})
    assert any("cruise_altitude_m" in p for p in check_mission_geometry(high))


def test_registered_for_validate(tmp_path: Path) -> None:
    cfg = load_config(check_plugins=False)
    bad = variant(cfg, mission={"params": {**cfg.mission.params, "guidance": {
        "standoff": {"horizontal_m": 0.5, "height_m": 3.0}}}})
    assert any(p.startswith("mission.params.guidance.standoff") for p in run_checks(bad))
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(bad.model_dump(mode="json")))
    proc = subprocess.run([sys.executable, "-m", "eaglemission.cli", "validate", str(path)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "mission.params.guidance.standoff" in proc.stderr


def test_the_approach_defaults_pass_the_geometry_check() -> None:
    """A mission file that leaves ``mission.params`` out flies the plugin's defaults: they must
    be a valid standoff for the shipped cameras."""
    cfg = load_config(check_plugins=False)
    assert check_mission_geometry(variant(cfg, mission={"params": {}})) == []
