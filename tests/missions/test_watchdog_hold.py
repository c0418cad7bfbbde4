"""The mission's event loop stalls and the driver's offboard watchdog commands HOLD (seen on a
local PX4 v1.16 SITL, `eaglemission run configs/px4_sitl.yaml` with both cores loaded: a
0.57 s stall in FINE_DESCENT). That HOLD is the mission's own fault, not a pilot's mode change:
taken for one, the mission would *release* control and leave the vehicle hovering in HOLD with
no one flying it. It is logged once and the mission ends in ``actions.on_timeout`` (return),
landed."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
import yaml
from eaglemission.lab.campaign.sim import run_simulation
from eaglemission.missions.approach import S, Snapshot, failsafe
from eaglemission.missions.approach_config import ApproachConfig
from eaglemission.missions.log import read_log

from eaglemission.commands.run import emulator_process
from eaglemission.config import MissionFile, load_config


def test_the_watchdogs_hold_is_the_missions_fault_not_a_pilots() -> None:
    cfg = load_config(check_plugins=False)
    p = ApproachConfig.of(cfg).actions
    held = Snapshot(watchdog_hold="no fresh setpoint for 0.57 s (watchdog 0.5 s)",
                    pilot_override=True)
    abort = failsafe(S.FINE_DESCENT, held, cfg.safety, p)
    assert abort is not None and abort.action == p.on_timeout == "return"
    assert "offboard watchdog commanded HOLD: no fresh setpoint for 0.57 s" in abort.reason
    pilot = failsafe(S.FINE_DESCENT, Snapshot(pilot_override=True), cfg.safety, p)
    assert pilot is not None and pilot.action == "release"  # a real pilot keeps control
    assert failsafe(S.PREFLIGHT, Snapshot(watchdog_hold="x"), cfg.safety, p) is None


@pytest.mark.slow
def test_a_stalled_mission_loop_returns_instead_of_releasing(fast_config: MissionFile,
                                                             tmp_path: Path) -> None:
    """Through MAVSDK against the emulator in real time: the mission's event loop blocked for
    0.9 s as it enters FINE_APPROACH (the watchdog thread keeps running, as on PX4)."""
    doc = fast_config.model_dump(mode="json")
    stalled: list[float] = []
    states: list[str] = []

    def stall(t_s: float, new: str, reason: str, action: str) -> None:
        states.append(f"{t_s:.2f} s {new} ({reason})")
        if new == "FINE_APPROACH" and not stalled:
            stalled.append(t_s)
            time.sleep(0.9)  # on the loop thread: nothing feeds the watchdog

    log = tmp_path / "run.jsonl"
    with emulator_process(None, mission_yaml=yaml.safe_dump(doc)) as url:
        flown = MissionFile.model_validate({**doc, "vehicle": {
            "type": "mavsdk", "params": {"url": url, "connect_timeout_s": 30}}})
        out = run_simulation(flown, realtime=True, log_path=log, on_state=stall)
    recs = list(read_log(log))
    faults = [f"{r.get('state')}: {r['what']}: {r['text']}" for r in recs
              if r["kind"] == "fault_detected"]
    assert stalled, f"the mission never reached FINE_APPROACH: {states}; faults: {faults}"
    watchdog = [r for r in recs if r["kind"] == "fault_detected"
                and r["what"] == "offboard_watchdog"]
    assert len(watchdog) == 1 and "WATCHDOG_HOLD" in watchdog[0]["text"]
    assert out.result.final_state == "FAILSAFE", out.result.reason
    assert "offboard watchdog commanded HOLD" in out.result.reason
    assert out.result.action == "return"
    assert out.evaluation.landed and out.evaluation.violations == []
    refused = [r for r in recs if r["kind"] == "event" and "WATCHDOG_HOLD" in r.get("text", "")]
    assert refused == []  # logged once as the fault, not once per refused setpoint
