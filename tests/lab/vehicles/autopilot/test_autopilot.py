"""The shared autopilot model on its own (no vehicle driver around it): mode logic stepped on a
ManualClock, reports through a recording listener."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import pytest
from eaglemission.lab.vehicles.autopilot.model import (
    Autopilot,
    AutopilotParams,
    FailsafeAction,
    LandedState,
    MissionItem,
)
from eaglemission.lab.vehicles.multicopter.dynamics import DynamicsParams, MulticopterDynamics

from eaglemission.clock import ManualClock
from eaglemission.types import FlightMode, Setpoint

STEP_S = 0.01


@dataclass
class Recorder:
    """An AutopilotListener that keeps everything, stamped with the model time."""

    dyn: MulticopterDynamics | None = None
    log: list[tuple[float, str, object]] = field(default_factory=list)

    def _t(self) -> float:
        assert self.dyn is not None
        return self.dyn.time_ns * 1e-9

    def on_status(self, text: str, severity: str) -> None:
        self.log.append((self._t(), "status", text))

    def on_mode(self, old: FlightMode, new: FlightMode, source: str) -> None:
        self.log.append((self._t(), "mode", (old, new, source)))

    def on_failsafe(self, reason: str, action: FailsafeAction) -> None:
        self.log.append((self._t(), "failsafe", (reason, action)))

    def on_armed(self, armed: bool) -> None:
        self.log.append((self._t(), "armed", armed))

    def on_mission_item(self, index: int, total: int) -> None:
        self.log.append((self._t(), "mission", (index, total)))

    def on_gps(self, ok: bool) -> None:
        self.log.append((self._t(), "gps", ok))

    def texts(self) -> list[str]:
        return [str(v) for _, k, v in self.log if k == "status"]

    def first(self, kind: str, pred: Callable[[Any], bool] | None = None) -> float:
        for t, k, v in self.log:
            if k == kind and (pred is None or pred(v)):
                return t
        raise AssertionError(f"no {kind} report matching in {self.log}")


class Bench:
    """Dynamics + autopilot on a ManualClock (the way the simulated vehicle steps them)."""

    def __init__(self, **params: Any) -> None:
        self.clock = ManualClock(start_ns=0)
        self.dyn = MulticopterDynamics(DynamicsParams(estimate_max_error_m=0.0), seed=1)
        self.rec = Recorder(self.dyn)
        self.ap = Autopilot(self.dyn, replace(AutopilotParams(), **params), self.rec)
        self.trace: list[tuple[float, tuple[float, float, float], FlightMode, LandedState]] = []

    def hover(self, north_m: float, east_m: float, alt_m: float) -> None:
        self.dyn.reset((north_m, east_m, -alt_m), 0.0)
        self.ap.start_airborne()

    def run(self, seconds: float, until: Callable[[], bool] | None = None) -> None:
        """Advance ``seconds`` (stop early when ``until()``), recording the true trajectory."""
        end = self.clock.now_ns() + int(round(seconds * 1e9))
        while self.clock.now_ns() < end:
            self.clock.advance(STEP_S)
            self.dyn.advance_to(self.clock.now_ns(), self.ap.on_step)
            s = self.dyn.truth()
            self.trace.append((self.dyn.time_ns * 1e-9, s.position_ned_m, self.ap.mode,
                               self.ap.landed_state))
            if until is not None and until():
                return

    def now_s(self) -> float:
        return self.dyn.time_ns * 1e-9


# ---------------------------------------------------------------------------------------------
# RTL
# ---------------------------------------------------------------------------------------------
def test_rtl_climbs_first_then_returns_then_lands_at_home_and_disarms() -> None:
    b = Bench(rtl_return_altitude_m=10.0)
    b.hover(20.0, 5.0, 3.0)
    b.run(1.0)
    b.ap.start_rtl("command")
    assert b.ap.mode == FlightMode.RETURN_TO_LAUNCH and b.ap.rtl_phase == "climb"
    b.run(120.0, until=lambda: not b.ap.armed)
    assert not b.ap.armed, "RTL did not land and disarm within 120 s"
    after = [(t, p) for t, p, m, _ in b.trace if t >= b.rec.first("mode")]
    # climb in place first: until 9.5 m the vehicle stays within 1 m of where RTL started
    climbed = next(t for t, p in after if -p[2] >= 9.5)
    for t, p in after:
        if t > climbed:
            break
        assert math.hypot(p[0] - 20.0, p[1] - 5.0) < 1.0, (t, p)
    # then returns at that height, then lands near home
    near_home = next(t for t, p in after if math.hypot(p[0], p[1]) < 2.0)
    assert near_home > climbed
    alt_at_home = next(-p[2] for t, p in after if t >= near_home)
    assert alt_at_home > 9.0
    final = b.trace[-1][1]
    assert math.hypot(final[0], final[1]) < 1.0 and final[2] == 0.0
    texts = b.rec.texts()
    i = texts.index("RTL: start return at 499 m (10 m above destination)")
    assert texts[i + 1:] == ["RTL: land at destination", "Landing detected", "Disarmed by landing"]
    assert b.ap.mode == FlightMode.HOLD


def test_rtl_from_above_the_return_altitude_returns_at_its_height() -> None:
    b = Bench(rtl_return_altitude_m=5.0)
    b.hover(15.0, 0.0, 8.0)
    b.ap.start_rtl("command")
    b.run(2.0)
    assert b.ap.rtl_phase == "return"  # no climb needed
    b.run(60.0, until=lambda: b.ap.rtl_phase == "land")
    assert min(-p[2] for _, p, _, _ in b.trace) > 7.0  # never below its height before landing


# ---------------------------------------------------------------------------------------------
# Offboard loss
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("timeout_s", [0.5, 1.0])
def test_offboard_loss_failsafe_fires_com_of_loss_t_after_the_last_setpoint(timeout_s: float) -> None:
    b = Bench(offboard_loss_timeout_s=timeout_s, offboard_loss_action=FailsafeAction.HOLD)
    b.hover(0.0, 0.0, 5.0)
    sp = Setpoint(2.0, 0.0, -5.0, 0.0)
    b.ap.start_offboard(sp)
    for _ in range(40):  # 20 Hz for 2 s: no failsafe while fed
        b.run(0.05)
        b.ap.set_setpoint(sp)
    assert b.ap.mode == FlightMode.OFFBOARD and not b.ap.failsafe_active
    t_last = b.now_s()
    b.run(timeout_s + 1.0)
    t_fs = b.rec.first("failsafe")
    assert timeout_s < t_fs - t_last <= timeout_s + 2 * STEP_S
    assert b.rec.first("mode", lambda v: v[1] == FlightMode.HOLD and v[2] == "failsafe") == t_fs
    assert "Failsafe activated" in b.rec.texts()


def test_offboard_loss_without_rc_descends_lands_and_restores_the_intended_mode() -> None:
    """PX4's default (COM_OBL_RC_ACT = 0, no RC, recorded b): Position mode sinks at ~0.65 m/s,
    lands, disarms; with the emulator's disarm rule the mode goes back to OFFBOARD."""
    b = Bench(offboard_loss_timeout_s=1.0, offboard_loss_action=FailsafeAction.POSITION,
              disarm_restores_intended_mode=True)
    b.hover(0.0, 0.0, 4.0)
    b.ap.start_offboard(Setpoint(0.0, 0.0, -4.0, 0.0))
    b.run(3.0)
    assert b.ap.mode == FlightMode.POSCTL and b.ap.failsafe_active
    t0 = b.now_s()
    b.run(2.0)
    z0 = next(p[2] for t, p, _, _ in b.trace if t >= t0)
    assert (b.trace[-1][1][2] - z0) / 2.0 == pytest.approx(0.65, abs=0.05)  # sinking
    b.run(30.0, until=lambda: not b.ap.armed)
    assert not b.ap.armed and b.ap.mode == FlightMode.OFFBOARD and not b.ap.failsafe_active


# ---------------------------------------------------------------------------------------------
# Landing detection and auto-disarm
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("detect_s", "disarm_s"), [(1.0, 2.0), (2.5, 4.0)])
def test_landing_detected_then_auto_disarm_after_com_disarm_land(detect_s: float,
                                                                 disarm_s: float) -> None:
    b = Bench(land_detect_s=detect_s, auto_disarm_after_land_s=disarm_s)
    b.hover(0.0, 0.0, 2.0)
    b.ap.land("command")
    b.run(30.0, until=lambda: not b.ap.armed)
    touchdown = next(t for t, p, _, _ in b.trace if p[2] >= 0.0)
    landed = b.rec.first("status", lambda v: v == "Landing detected")
    disarmed = b.rec.first("status", lambda v: v == "Disarmed by landing")
    assert landed - touchdown == pytest.approx(detect_s, abs=2 * STEP_S)
    assert disarmed - landed == pytest.approx(disarm_s, abs=2 * STEP_S)
    assert not b.ap.in_air and b.ap.landed_state == LandedState.ON_GROUND


def test_takeoff_late_in_the_auto_disarm_window_is_disarmed_unless_climbs_are_spared() -> None:
    """COM_DISARM_LAND counts from "Landing detected" until "Takeoff detected" (PX4's
    ``_auto_disarm_landed``): a takeoff commanded 0.5 s into that window is detected in time and
    flies (recorded e, re-arm tests 1 and 2), one commanded 1.9 s in is cut by the auto-disarm
    (the vehicle contract suite on PX4 SITL: ``mode=TAKEOFF armed=False``) unless the profile
    spares climbs."""
    for spared, after_s, flies in ((False, 0.5, True), (False, 1.9, False), (True, 1.9, True)):
        b = Bench(auto_disarm_spares_climb=spared)
        b.hover(0.0, 0.0, 1.0)
        b.ap.land("command")
        b.run(30.0, until=lambda: not b.ap.in_air)  # noqa: B023 - runs now
        b.run(after_s)
        b.ap.takeoff(3.0)
        b.run(10.0)
        assert b.ap.armed is flies, (spared, after_s)
        if flies:
            assert b.ap.mode == FlightMode.HOLD and b.ap.in_air


def test_armed_on_the_ground_without_takeoff_disarms_after_com_disarm_prflt() -> None:
    b = Bench(auto_disarm_preflight_s=4.0)
    b.ap.arm()
    b.run(3.9)
    assert b.ap.armed
    b.run(0.2)
    assert not b.ap.armed and b.rec.texts()[-1] == "Disarmed by auto preflight disarming"


# ---------------------------------------------------------------------------------------------
# Takeoff, landed state, missions, battery
# ---------------------------------------------------------------------------------------------
def test_takeoff_spools_up_then_climbs_and_reports_px4_landed_states() -> None:
    b = Bench(takeoff_spoolup_s=1.5, takeoff_ramp_s=3.0)
    b.ap.arm()
    b.ap.takeoff(5.0)
    b.run(1.4)
    assert b.dyn.on_ground and b.ap.landed_state == LandedState.ON_GROUND  # spooling up
    b.run(20.0, until=lambda: b.ap.mode == FlightMode.HOLD)
    assert b.ap.mode == FlightMode.HOLD and abs(-b.dyn.estimated_position()[2] - 5.0) <= 0.3
    b.ap.land("command")
    b.run(30.0, until=lambda: not b.ap.armed)
    states = [s for *_, s in b.trace]
    distinct = [s for i, s in enumerate(states) if i == 0 or states[i - 1] != s]
    # recorded PX4 (scenario a): ON_GROUND, TAKEOFF, IN_AIR, LANDING, ON_GROUND
    assert distinct == [LandedState.ON_GROUND, LandedState.TAKEOFF, LandedState.IN_AIR,
                        LandedState.LANDING, LandedState.ON_GROUND]


def test_mission_climbs_flies_the_legs_and_reports_the_do_items_after_each_waypoint() -> None:
    b = Bench(mission_acceptance_radius_m=1.0)
    b.ap.arm()
    b.ap.upload_mission((MissionItem("waypoint", 10.0, 0.0, 6.0), MissionItem("speed", speed_mps=2.0),
                         MissionItem("waypoint", 10.0, 10.0, 6.0), MissionItem("speed", speed_mps=4.0)))
    b.ap.start_mission()
    assert b.rec.texts()[-2:] == ["Executing Mission", "Climb to 6.0 meters above home"]
    b.run(60.0, until=lambda: b.ap.mission.finished)
    assert [v for _, k, v in b.rec.log if k == "mission"] == [(1, 4), (3, 4)]
    assert b.ap.mission.speed_mps == 4.0 and b.rec.texts()[-1] == "Mission finished, loitering"
    # the second leg was flown at the speed of the DO_CHANGE_SPEED after the first waypoint
    leg2 = [p for t, p, *_ in b.trace if t > b.rec.first("mission")]
    speeds = [math.hypot(q[0] - p[0], q[1] - p[1]) / STEP_S for p, q in zip(leg2, leg2[1:])]
    assert 1.7 < max(speeds) < 2.3


@pytest.mark.parametrize(("fraction", "action", "mode"), [
    (0.06, FailsafeAction.RETURN, FlightMode.RETURN_TO_LAUNCH),
    (0.04, FailsafeAction.LAND, FlightMode.LAND)])
def test_battery_levels_trigger_their_failsafe_once(fraction: float, action: FailsafeAction,
                                                    mode: FlightMode) -> None:
    b = Bench()
    b.hover(0.0, 0.0, 5.0)
    b.ap.set_battery(fraction)
    b.run(1.0)
    assert [v[1] for _, k, v in b.rec.log if k == "failsafe"] == [action]
    assert b.ap.mode == mode
    b.ap.hold("command")
    b.run(1.0)
    assert len([1 for _, k, _ in b.rec.log if k == "failsafe"]) == 1


def test_gps_loss_invalidates_the_position_then_lands() -> None:
    b = Bench(gps_loss_failsafe_delay_s=1.0, gps_loss_action=FailsafeAction.LAND)
    b.hover(0.0, 0.0, 5.0)
    assert b.ap.gps_loss(5.0)
    b.run(0.9)
    assert b.ap.position_valid and not b.ap.gps_ok and b.ap.mode == FlightMode.HOLD
    b.run(0.2)
    assert not b.ap.position_valid and b.ap.mode == FlightMode.LAND
    b.run(5.0)
    assert b.ap.gps_ok and [v for _, k, v in b.rec.log if k == "gps"] == [True]


@pytest.mark.parametrize("takeover", ["hold then return (the mission's failsafe)",
                                      "the pilot switches to Hold"])
def test_a_mode_chosen_during_a_failsafe_is_a_takeover_and_what_a_disarm_restores(
        takeover: str) -> None:
    """PX4's FailsafeBase: an updated user-intended mode during a failsafe clears the action,
    so after the landing the mode is what the user chose last, not the mode the failsafe
    interrupted: after an offboard loss (link down, Hold), the mission's stop_offboard + return
    and the RTL's disarm, the mode is not OFFBOARD again (the mode the failsafe interrupted)."""
    b = Bench(offboard_loss_timeout_s=1.0, offboard_loss_action=FailsafeAction.HOLD,
              disarm_restores_intended_mode=True, rtl_return_altitude_m=8.0)
    b.hover(10.0, 0.0, 5.0)
    sp = Setpoint(10.0, 0.0, -5.0, 0.0)
    b.ap.start_offboard(sp)
    for _ in range(20):
        b.run(0.05)
        b.ap.set_setpoint(sp)
    b.run(2.5)  # the link is down: no setpoints
    assert b.ap.mode == FlightMode.HOLD and b.ap.failsafe_active
    assert b.ap.intended_mode == FlightMode.OFFBOARD
    if takeover.startswith("hold"):
        b.ap.stop_offboard()  # outside OFFBOARD: changes nothing
        b.ap.hold()
        b.ap.return_to_launch()
        expected = FlightMode.RETURN_TO_LAUNCH
    else:
        b.ap.pilot_take_control(FlightMode.HOLD)
        expected = FlightMode.HOLD
    assert not b.ap.failsafe_active and b.ap.intended_mode == expected
    if expected == FlightMode.HOLD:
        b.ap.land()
    b.run(120.0, until=lambda: not b.ap.armed)
    assert not b.ap.armed and b.ap.mode == FlightMode.HOLD
