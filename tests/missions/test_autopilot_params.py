"""The preflight puts the autopilot's own behaviour inside the envelope: a flight
whose envelope is below RTL_RETURN_ALT gets it set before the flight and restored after (read
back from the vehicle), ``safety.autopilot_params: refuse`` refuses with the parameter and the
envelope key, and the log has the parameters read and set. Simulated vehicle, virtual time."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

from eaglemission.lab.campaign.sim import run_simulation
from eaglemission.missions.log import read_log
from mission_helpers import variant

from eaglemission.config import MissionFile
from eaglemission.flight.run import EXIT_PREFLIGHT, FlightOptions, fly_sync

HIGH_RTL_M = 28.0  # above the envelope's max_altitude_m (20 m), as PX4's 30 m default


def _high_rtl(cfg: MissionFile, **safety: Any) -> MissionFile:
    params = {**cfg.vehicle.params, "rtl_return_altitude_m": HIGH_RTL_M}
    return variant(cfg, vehicle={"type": "simulated", "params": params}, safety=safety)


def test_rtl_return_alt_above_the_envelope_is_set_and_restored(fast_config: MissionFile,
                                                               tmp_path: Path) -> None:
    cfg = _high_rtl(fast_config)
    asm: list[Any] = []
    during: list[float] = []

    def on_state(_t: float, new: str, _reason: str, _action: str) -> None:
        if new == "CRUISE":  # in flight: the vehicle flies the envelope's return height
            during.append(asm[0].driver.config.rtl_return_altitude_m)

    log = tmp_path / "mission.jsonl"
    out = run_simulation(cfg, log_path=log, prepare=asm.append, on_state=on_state)
    assert out.final_state == "DONE", out.reason
    want = cfg.mission.cruise_altitude_m  # cruise altitude, inside the band
    assert during == [want]
    # restored after the flight: read back from the vehicle
    assert asyncio.run(asm[0].driver.get_param("RTL_RETURN_ALT")) == HIGH_RTL_M
    recs = list(read_log(log))
    ap = [r for r in recs if r["kind"] == "autopilot_params"]
    assert len(ap) == 1 and ap[0]["mode"] == "set" and not ap[0]["refused"]
    assert ap[0]["values"]["RTL_RETURN_ALT"] == HIGH_RTL_M  # read, never assumed
    assert ap[0]["values"]["RTL_DESCEND_ALT"] == 10.0  # the airframe's, as PX4 reports it
    assert "COM_RC_IN_MODE" in ap[0]["missing"]  # not on this vehicle: reported once
    [ch] = [c for c in ap[0]["set"] if c["name"] == "RTL_RETURN_ALT"]
    assert (ch["old"], ch["new"], ch["envelope_key"]) == (HIGH_RTL_M, want,
                                                          "safety.max_altitude_m")
    sets = [r for r in recs if r["kind"] == "param_set" and r.get("name") == "RTL_RETURN_ALT"]
    assert sets[0]["was"] == HIGH_RTL_M and sets[0]["now"] == want
    assert sets[-1]["restored"] is True and sets[-1]["now"] == HIGH_RTL_M


def test_refuse_mode_refuses_with_the_parameter_and_the_envelope_key(
        fast_config: MissionFile) -> None:
    cfg = _high_rtl(fast_config, autopilot_params="refuse")
    asm: list[Any] = []
    res = fly_sync(cfg, FlightOptions(prepare=asm.append))
    assert res.exit_code == EXIT_PREFLIGHT and res.outcome is None
    assert "RTL_RETURN_ALT=28 m" in res.error and "safety.max_altitude_m" in res.error, res.error
    assert "autopilot_params=refuse" in res.error
    drv = asm[0].driver
    assert drv.config.rtl_return_altitude_m == HIGH_RTL_M  # nothing written
    assert not any(s.armed for s in drv.trajectory())  # never armed


def test_plan_sets_speeds_and_heights_inside_the_envelope(fast_config: MissionFile) -> None:
    from eaglemission.safety.autopilot_guard import plan

    s = fast_config.safety  # 20 m, 1.5 m/s vertical, 4 m/s horizontal; cruise at 5 m
    px4 = {"RTL_RETURN_ALT": 30.0, "RTL_DESCEND_ALT": 10.0, "RTL_CONE_ANG": 45.0,
           "MPC_Z_V_AUTO_UP": 3.0, "MPC_Z_V_AUTO_DN": 1.5, "MPC_TKO_SPEED": 1.5,
           "MPC_LAND_SPEED": 0.7, "MPC_XY_CRUISE": 5.0, "MPC_XY_VEL_MAX": 12.0,
           "COM_OBL_RC_ACT": 0.0}
    got = {c.name: (c.new, c.envelope_key) for c in plan(px4, s, 5.0)}
    assert got == {"RTL_RETURN_ALT": (5.0, "safety.max_altitude_m"),
                   "RTL_DESCEND_ALT": (5.0, "safety.max_altitude_m"),
                   "MPC_Z_V_AUTO_UP": (1.35, "safety.max_vertical_speed_mps"),
                   "MPC_XY_CRUISE": (round(0.9 * s.max_horizontal_speed_mps, 3),
                                     "safety.max_horizontal_speed_mps"),
                   "MPC_XY_VEL_MAX": (round(0.9 * s.max_horizontal_speed_mps, 3),
                                      "safety.max_horizontal_speed_mps")}
    # inside the envelope, refuse mode (no alignment) has nothing to object to
    assert plan({"RTL_RETURN_ALT": 10.0, "RTL_DESCEND_ALT": 5.0, "MPC_Z_V_AUTO_UP": 1.35},
                s, 5.0, align_return=False) == []
