"""The assembly: every part comes from the registry by its configured type.

Third-party plugins are installed as a real distribution on ``sys.path`` (dist-info with entry
points, as in test_registry.py), so the registry finds them exactly as it finds ours."""

from __future__ import annotations

import os
import signal
import sys
import textwrap
from pathlib import Path

import pytest

from eaglemission import registry
from eaglemission.clock import ManualClock
from eaglemission.config import MissionFile, load_config
from eaglemission.flight import assembly, run
from eaglemission.flight.assembly import assemble
from eaglemission.flight.run import FlightOptions, exit_code_for, fly_sync
from eaglemission.interfaces import MissionHooks

THIRD_PARTY = '''
from pydantic import BaseModel
from eaglemission.lab.vehicles.simulated.vehicle import SimulatedVehicle


class LoggedMission:
    """A mission that only records what it was given and ends at once."""
    description = "test mission"

    class Config(BaseModel):
        tag: str = "x"

    seen = []

    def __init__(self, config=None, *, parts, hooks=None, **context):
        self.config, self.parts = config, parts
        LoggedMission.seen.append(self)

    async def run(self):
        class Outcome:
            final_state, reason, truth_success = "DONE", "nothing to do", None

            def report_lines(self):
                return ["done"]
        return Outcome()

    def interrupt(self, reason, action):
        pass


class RealLookingVehicle(SimulatedVehicle):
    """The simulated model, declared as a real aircraft (arming must be confirmed)."""
    description = "a vehicle that is not simulated"
    simulated = False
'''


@pytest.fixture
def third_party(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    (tmp_path / "thirdparty_flight.py").write_text(THIRD_PARTY)
    dist = tmp_path / "thirdparty_flight-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: thirdparty-flight\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text(textwrap.dedent("""
        [eaglemission.missions]
        logged = thirdparty_flight:LoggedMission
        [eaglemission.vehicles]
        real_looking = thirdparty_flight:RealLookingVehicle
    """))
    monkeypatch.syspath_prepend(str(tmp_path))
    yield tmp_path
    sys.modules.pop("thirdparty_flight", None)


def variant(cfg: MissionFile, **sections: dict) -> MissionFile:
    data = cfg.model_dump()
    for name, updates in sections.items():
        data[name] = {**data[name], **updates} if isinstance(data.get(name), dict) else updates
    return MissionFile.model_validate(data)


@pytest.fixture
def cfg() -> MissionFile:
    return load_config()


@pytest.fixture
def fast_config(cfg: MissionFile) -> MissionFile:
    return variant(cfg, detector={"type": "mss", "params": {"downscale": 2}})


def test_cameras_are_built_by_their_type(cfg: MissionFile, tmp_path: Path) -> None:
    from eaglemission.drivers.cameras.replay.camera import ReplayCamera
    from eaglemission.lab.cameras.synthetic import SyntheticCamera

    folder = tmp_path / "frames"
    folder.mkdir()
    mixed = variant(cfg, cameras={"wide": cfg.cameras.wide.model_dump(),
                                  "narrow": {**cfg.cameras.narrow.model_dump(), "type": "replay",
                                             "params": {"path": str(folder)}}})
    asm = assemble(mixed, ManualClock())
    assert isinstance(asm.cameras["wide"], SyntheticCamera)
    assert isinstance(asm.cameras["narrow"], ReplayCamera)
    assert asm.cameras["narrow"].config.path == str(folder)
    assert asm.cameras["narrow"].model.fx == pytest.approx(cfg.cameras.narrow.to_model("n").fx)


def test_the_vehicle_gets_its_params_and_the_envelope(cfg: MissionFile) -> None:
    from eaglemission.drivers.vehicles.mavsdk.vehicle import MavsdkVehicle

    from eaglemission.safety.envelope import SafeVehicle

    mav = variant(cfg, vehicle={"type": "mavsdk", "params": {"url": "udpin://127.0.0.1:15999",
                                                             "connect_timeout_s": 2}})
    asm = assemble(mav, ManualClock())
    assert isinstance(asm.driver, MavsdkVehicle)
    assert asm.driver.config.url == "udpin://127.0.0.1:15999"
    assert isinstance(asm.vehicle, SafeVehicle) and asm.vehicle.inner is asm.driver
    assert asm.driver.watchdog_timeout_s == cfg.safety.offboard_watchdog_s
    assert assembly.plan(mav).wall_clock and not assembly.plan(mav).simulated_vehicle
    assert not assembly.plan(cfg).wall_clock and assembly.plan(cfg).simulated_vehicle


def test_one_detector_per_camera_with_per_camera_overrides(cfg: MissionFile) -> None:
    """Without the appearance prior the detector's own regions find the target, and a camera's
    ``per_camera`` overrides reach its detector alone."""
    over = variant(cfg, detector={"type": "dtdmi", "params": {"preset": "field",
                                                              "downscale": 2},
                                  "per_camera": {"narrow": {"regions": {"threshold": "otsu"}}}},
                   appearance={"prior": None})
    asm = assemble(over, ManualClock())
    wide, narrow = asm.detectors["wide"], asm.detectors["narrow"]
    assert wide is not narrow
    assert narrow.config.regions.threshold == "otsu"
    assert wide.config.regions.threshold != "otsu"
    assert wide.config.downscale == narrow.config.downscale == 2


def test_the_mission_is_loaded_by_its_type(cfg: MissionFile, third_party: Path) -> None:
    logged = variant(cfg, mission={"type": "logged", "params": {"tag": "hello"}})
    res = fly_sync(logged)
    mod = sys.modules["thirdparty_flight"]
    assert len(mod.LoggedMission.seen) == 1
    m = mod.LoggedMission.seen[0]
    assert m.config.tag == "hello"
    assert set(m.parts.cameras) == {"wide", "narrow"} and m.parts.judge is None  # no judge for this type
    assert res.exit_code == run.EXIT_DONE and res.outcome.report_lines() == ["done"]


def test_arming_a_real_vehicle_needs_a_yes(cfg: MissionFile, third_party: Path) -> None:
    real = variant(cfg, vehicle={"type": "real_looking",
                                 "params": dict(cfg.vehicle.params)})
    asked: list[str] = []
    res = fly_sync(real, FlightOptions(confirm=lambda q: asked.append(q) or False))
    assert asked and "real_looking" in asked[0]
    assert res.exit_code == run.EXIT_PREFLIGHT and res.outcome is None
    assert "not confirmed" in res.error
    # the simulated vehicle is never asked about
    res2 = fly_sync(variant(cfg, mission={"type": "logged", "params": {}}),
                    FlightOptions(confirm=lambda q: asked.append(q) or False))
    assert len(asked) == 1 and res2.exit_code == 0


def test_dry_run_checks_without_arming(cfg: MissionFile) -> None:
    lines: list[str] = []
    res = fly_sync(cfg, FlightOptions(dry_run=True, on_line=lines.append))
    names = [n for n, _, _ in res.checks]
    assert "camera wide: frame" in names and "camera narrow: frame" in names
    assert "vehicle: home" in names and "autopilot parameters" in names
    assert all(ok for _, ok, _ in res.checks), res.checks
    assert res.exit_code == 0 and res.outcome is None
    assert any(line.startswith("  [ok] camera wide: frame: 1280x960 px") for line in lines)


def test_dry_run_fails_on_a_frame_of_the_wrong_size(cfg: MissionFile, tmp_path: Path) -> None:
    import cv2
    import numpy as np

    folder = tmp_path / "frames"
    folder.mkdir()
    cv2.imwrite(str(folder / "000001.png"), np.zeros((480, 640, 3), np.uint8))
    bad = variant(cfg, cameras={"wide": cfg.cameras.wide.model_dump(),
                                "narrow": {**cfg.cameras.narrow.model_dump(), "type": "replay",
                                           "params": {"path": str(folder),
                                                      "check_size": False}}})
    res = fly_sync(bad, FlightOptions(dry_run=True))
    failed = {n: d for n, ok, d in res.checks if not ok}
    assert failed == {"camera narrow: frame": "640x480 px, calibration 1280x960 px: fix the "
                                              "device's Width/Height or the calibration"}
    assert res.exit_code == run.EXIT_PREFLIGHT


def test_header_says_what_flies(cfg: MissionFile) -> None:
    header: list[str] = []
    fly_sync(cfg, FlightOptions(dry_run=True, on_header=header.extend))
    text = "\n".join(header)
    assert "vehicle: simulated (" in text
    assert "camera wide: synthetic" in text and "camera narrow: synthetic" in text
    assert "clock: virtual time" in text
    assert "ground truth: the simulated vehicle's true state" in text


def test_sigint_in_a_virtual_time_flight_returns_home(fast_config: MissionFile) -> None:
    """The operator's Ctrl-C in CRUISE: the default safe stop (return) through the envelope,
    landed at home on the TRUE trajectory, exit 130, the log ends with its end record."""
    from eaglemission.lab.campaign.sim import run_simulation  # noqa: F401  (plugins importable)

    async def ctrl_c_in_cruise(mission):
        while mission.state is None or mission.state.value != "CRUISE":
            await mission.parts.clock.sleep(0.1)
        await mission.parts.clock.sleep(2.0)
        os.kill(os.getpid(), signal.SIGINT)

    res = fly_sync(fast_config, FlightOptions(handle_signals=True, hooks=MissionHooks(
        side_tasks=(ctrl_c_in_cruise,))))
    out = res.outcome
    assert res.exit_code == run.EXIT_INTERRUPTED and res.interrupted
    assert out.final_state == "FAILSAFE" and out.reason == "interrupted by SIGINT"
    assert out.result.action == "return"
    last = out.trajectory[-1]
    assert not last.in_air and not last.armed and abs(last.position_ned_m[0]) < 1.5
    assert out.log.records[-2]["kind"] == "end" and out.evaluation.violations == []


@pytest.mark.parametrize("final,truth,interrupted,code", [
    ("DONE", True, False, 0), ("DONE", None, False, 0), ("DONE", False, False, 6),
    ("FAILSAFE", None, False, 3), ("FAILSAFE", None, True, 130), ("CRUISE", None, False, 1)])
def test_exit_codes(final: str, truth: bool | None, interrupted: bool, code: int) -> None:
    class Outcome:
        final_state, reason, truth_success = final, "", truth

    assert exit_code_for(Outcome(), interrupted=interrupted) == code  # type: ignore[arg-type]


def test_a_config_error_in_a_part_is_exit_2(cfg: MissionFile) -> None:
    bad = variant(cfg, detector={"type": "no_such_detector", "params": {}})
    res = fly_sync(bad)
    assert res.exit_code == run.EXIT_CONFIG and "no_such_detector" in res.error
    assert registry.available("detectors")
