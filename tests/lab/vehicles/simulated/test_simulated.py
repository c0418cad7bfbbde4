"""The simulated vehicle beyond the contract: PX4-like details, faults, truth vs estimate,
determinism under any task schedule."""

from __future__ import annotations

import asyncio
import contextlib
import math

import pytest
from eaglemission.drivers.vehicles.wait import wait_until
from eaglemission.lab.vehicles.multicopter.dynamics import DynamicsParams
from eaglemission.lab.vehicles.simulated.vehicle import SimulatedVehicle, SimulatedVehicleConfig
from eaglemission.lab.world.synthetic import SyntheticWorldConfig
from pydantic import ValidationError
from test_contract_simulated import SimulatedBackend
from vehicle_contract import VehicleContract

from eaglemission import registry
from eaglemission.clock import LoopClock, ManualClock, run_virtual
from eaglemission.errors import ModeChangedExternally, TimeoutError_, VehicleError
from eaglemission.geometry import R_to_euler, quat_to_R
from eaglemission.types import FlightMode, Setpoint, VehicleState, Waypoint


def make(clock: ManualClock | None = None, **cfg: object) -> tuple[SimulatedVehicle, ManualClock]:
    clock = clock or ManualClock()
    sim_cfg = cfg.pop("simulation", None)
    v = SimulatedVehicle(SimulatedVehicleConfig(**cfg), clock=clock,  # type: ignore[arg-type]
                         simulation=sim_cfg)  # type: ignore[arg-type]
    return v, clock


async def offboard_hover(v: SimulatedVehicle, clock: ManualClock) -> tuple[VehicleState, Setpoint]:
    """Airborne, then 1 s of offboard setpoints at the current position: (state, setpoint)."""
    await airborne(v, clock)
    s = v.state()
    sp = Setpoint(*s.position_ned_m, s.yaw_deg)
    await v.start_offboard(sp)
    for _ in range(20):
        await v.set_setpoint(sp)
        await clock.sleep(0.05)
    return s, sp


async def airborne(v: SimulatedVehicle, clock: ManualClock, alt: float = 5.0) -> None:
    await v.connect()
    await v.arm()
    await v.takeoff(alt)
    await wait_until(lambda: v.state().flight_mode == FlightMode.HOLD, 30.0, clock=clock, what="hold")


def modes(v: SimulatedVehicle) -> list[str]:
    return [str(e.data["to"]) for e in v.events() if e.kind == "mode"]


def test_plugin_conforms_and_validates_params() -> None:
    cls = registry.get("vehicles", "simulated")
    assert cls is SimulatedVehicle
    assert registry.conformance_problems("vehicles", cls) == []
    v = registry.load("vehicles", "simulated", {"seed": 4, "dynamics": {"rate_hz": 200}},
                      clock=ManualClock(), simulation=None, safety=None, unused_context=1)
    assert v.seed == 4 and v.config.dynamics.rate_hz == 200
    with pytest.raises(ValidationError):
        SimulatedVehicleConfig(sed=1)  # type: ignore[call-arg]


async def test_calls_before_connect_say_how_to_fix() -> None:
    v, _ = make()
    with pytest.raises(VehicleError, match="connect") as info:
        await v.arm()
    assert info.value.result == "NO_SYSTEM"
    with pytest.raises(VehicleError):
        v.state()
    assert v.true_pose_at(0) is None


def _timeline(clock_now_s: float) -> list[tuple[float, str, object]]:
    """Commands at fixed times (seconds after start)."""
    return [(0.0, "arm", None), (0.1, "takeoff", 4.0), (8.0, "offboard", None),
            (8.0, "sp", Setpoint(6.0, -2.0, -5.0, 30.0)), (16.0, "hold", None)]


async def _run_timeline(v: SimulatedVehicle, sleep: object, now_s: object, poll_s: float) -> tuple[float, ...]:
    await v.connect()
    t0 = now_s()  # type: ignore[operator]
    streaming = False
    for t_cmd, name, arg in _timeline(0.0):
        while now_s() - t0 < t_cmd - 1e-9:  # type: ignore[operator]
            if streaming:
                await v.set_setpoint(Setpoint(6.0, -2.0, -5.0, 30.0))
            v.state()  # poll telemetry at this caller's own rate
            await sleep(min(poll_s, t_cmd - (now_s() - t0)))  # type: ignore[operator]
        if name == "arm":
            await v.arm()
        elif name == "takeoff":
            await v.takeoff(float(arg))  # type: ignore[arg-type]
        elif name == "offboard":
            s = v.state()
            await v.start_offboard(Setpoint(*s.position_ned_m, s.yaw_deg))
        elif name == "sp":
            streaming = True
        elif name == "hold":
            streaming = False
            await v.hold()
    await sleep(2.0)  # type: ignore[operator]
    s = v.true_state()
    return (*s.position_ned_m, *s.velocity_ned_mps, s.yaw_deg)


def test_deterministic_whatever_the_polling_rate_and_the_clock() -> None:
    # the same command timeline, polled at different rates, on a ManualClock and on a
    # virtual-time event loop with a concurrent busy task: same trajectory
    results = []
    for poll in (0.05, 0.05, 0.23):
        v, clock = make(seed=11)
        results.append(asyncio.run(_run_timeline(v, clock.sleep, lambda c=clock: c.now_ns() * 1e-9, poll)))

    async def virtual() -> tuple[float, ...]:
        clock = LoopClock()

        async def noise() -> None:
            while True:
                await asyncio.sleep(0.013)

        task = asyncio.create_task(noise())
        v = SimulatedVehicle(SimulatedVehicleConfig(seed=11), clock=clock)
        try:
            return await _run_timeline(v, asyncio.sleep, lambda: clock.now_ns() * 1e-9, 0.05)
        finally:
            task.cancel()

    results.append(run_virtual(virtual()))
    assert results[0] == results[1]  # bit-identical reruns
    for r in results[2:]:
        # the setpoint stream differs only in how often it is repeated: same target
        assert r == pytest.approx(results[0], abs=2e-3)


async def test_takeoff_like_px4_seconds_then_hold() -> None:
    v, clock = make()
    await v.connect()
    await v.arm()
    t0 = clock.now_ns()
    await v.takeoff(5.0)
    assert v.state().flight_mode == FlightMode.TAKEOFF
    await wait_until(lambda: v.state().relative_altitude_m > 4.5, 30.0, clock=clock)
    assert (clock.now_ns() - t0) / 1e9 > 3.0  # recorded PX4: ~9 s to 4.5 m; here spool-up + 1.5 m/s
    await wait_until(lambda: v.state().flight_mode == FlightMode.HOLD, 5.0, clock=clock)
    assert modes(v) == ["TAKEOFF", "HOLD"]
    texts = [e.text for e in v.events() if e.kind == "status"]
    assert "Armed by external command" in texts and "Takeoff detected" in texts


async def test_offboard_loss_px4_default_position_mode_descends_and_disarms() -> None:
    # Recorded PX4 v1.16 (scenario b): failsafe 1.06 s after the last setpoint -> POSCTL,
    # descent at ~0.6-0.7 m/s without RC, "Disarmed by landing" ~11 s after the last setpoint.
    v, clock = make(offboard_loss_timeout_s=1.0, offboard_loss_action="position_no_rc")
    s, sp = await offboard_hover(v, clock)
    t_last = clock.now_ns()
    await wait_until(lambda: v.state().flight_mode == FlightMode.POSCTL, 3.0, clock=clock)
    dt_failsafe = (clock.now_ns() - t_last) / 1e9
    assert 0.95 <= dt_failsafe <= 1.2
    await clock.sleep(3.0)
    vd = v.state().velocity_ned_mps[2]
    assert 0.55 <= vd <= 0.75
    await wait_until(lambda: not v.state().armed, 20.0, clock=clock)
    assert 7.0 < (clock.now_ns() - t_last) / 1e9 < 16.0
    texts = [e.text for e in v.events()]
    assert "Failsafe activated" in texts and "Disarmed by landing" in texts


async def test_offboard_loss_hold_then_land() -> None:
    v, clock = make(offboard_loss_land_after_s=3.0)
    await airborne(v, clock)
    s = v.state()
    await v.start_offboard(Setpoint(*s.position_ned_m, s.yaw_deg))
    await clock.sleep(1.0)
    assert v.state().flight_mode == FlightMode.HOLD
    await clock.sleep(3.0)
    assert v.state().flight_mode == FlightMode.LAND
    assert [e.data["source"] for e in v.events() if e.kind == "mode"][-2:] == ["failsafe", "failsafe"]


async def test_start_offboard_requires_armed_and_position() -> None:
    v, clock = make()
    await v.connect()
    with pytest.raises(VehicleError, match="not armed"):
        await v.start_offboard(Setpoint(0.0, 0.0, 0.0, 0.0))
    await airborne(v, clock)
    v.inject_gps_loss(30.0)
    await clock.sleep(1.5)
    with pytest.raises(VehicleError, match="position"):
        s = v.state()
        await v.start_offboard(Setpoint(*s.position_ned_m, s.yaw_deg))


async def test_rtl_climbs_returns_lands_disarms() -> None:
    v, clock = make(rtl_return_altitude_m=10.0)
    await airborne(v, clock, alt=4.0)
    home = v.state().home
    assert home is not None
    from eaglemission.geometry import ned_to_geodetic

    await v.goto(ned_to_geodetic(home, 15.0, 10.0, -4.0), 0.0)
    await wait_until(lambda: math.dist(v.state().position_ned_m[:2], (15.0, 10.0)) < 0.5, 30.0, clock=clock)
    await v.return_to_launch()
    max_alt = 0.0

    def done() -> bool:
        nonlocal max_alt
        max_alt = max(max_alt, v.state().relative_altitude_m)
        return not v.state().armed

    await wait_until(done, 90.0, clock=clock)
    assert 9.3 < max_alt < 10.6
    t = v.true_state()
    assert math.hypot(*t.position_ned_m[:2]) < 1.5 and t.position_ned_m[2] == 0.0
    assert modes(v)[-2:] == ["RETURN_TO_LAUNCH", "HOLD"]
    assert "RTL: land at destination" in [e.text for e in v.events()]


async def test_mission_from_ground_climbs_first_and_loiters_at_the_end() -> None:
    v, clock = make()
    await v.connect()
    await v.upload_mission([Waypoint(10.0, 0.0, 8.0), Waypoint(10.0, 10.0, 8.0, speed_mps=2.0)])
    with pytest.raises(VehicleError) as info:
        await v.start_mission()
    assert info.value.result == "COMMAND_DENIED"
    await v.arm()
    await v.start_mission()
    await clock.sleep(3.0)
    s = v.true_state()
    assert math.hypot(*s.position_ned_m[:2]) < 0.5 and s.relative_altitude_m > 1.0  # climbs in place
    await wait_until(lambda: v.mission_progress().finished, 60.0, clock=clock)
    await clock.sleep(3.0)
    assert v.state().flight_mode == FlightMode.MISSION  # PX4 loiters in MISSION
    assert math.dist(v.state().position_ned_m[:2], (10.0, 10.0)) < 1.0
    reached = [e.data["index"] for e in v.events() if e.kind == "mission"]
    assert reached == [0, 1]
    empty, c2 = make()
    await empty.connect()
    await empty.arm()
    with pytest.raises(VehicleError) as info:
        await empty.start_mission()
    assert info.value.result == "NO_MISSION_AVAILABLE"


async def test_truth_and_estimate_differ_by_a_bounded_drift() -> None:
    v, clock = make(simulation=SyntheticWorldConfig(seed=5, wind_ne_mps=(2.0, 1.0)))
    await airborne(v, clock)
    diffs = []
    for _ in range(200):
        await clock.sleep(0.25)
        est = v.state().position_ned_m
        true = v.true_pose_at(v.state().timestamp_ns)
        assert true is not None
        diffs.append(math.dist(est, true[0]))
    assert max(diffs) <= math.sqrt(3) * v.config.dynamics.estimate_max_error_m + 1e-6
    assert max(diffs) > 0.02  # not a copy of the truth


async def test_true_pose_tilts_when_braking_and_interpolates() -> None:
    v, clock = make()
    await airborne(v, clock)
    s = v.state()
    await v.start_offboard(Setpoint(*s.position_ned_m, 0.0))
    for _ in range(80):  # 4 s north at up to 10 m/s (PX4's own max speed: far setpoint)
        await v.set_setpoint(Setpoint(40.0, 0.0, -5.0, 0.0))
        await clock.sleep(0.05)
    for _ in range(30):  # now stop here: braking
        await v.set_setpoint(Setpoint(v.state().position_ned_m[0], 0.0, -5.0, 0.0))
        await clock.sleep(0.05)
    tr = v.trajectory_array()
    i = int(tr[:, 7].argmin())  # strongest braking (most negative north acceleration)
    t = int(tr[i, 0])
    pose = v.true_pose_at(t)
    assert pose is not None
    _, pitch, _ = R_to_euler(quat_to_R(pose[1]))
    assert tr[i, 7] < -1.0 and pitch > math.degrees(math.atan(1.0 / 9.81))  # nose up
    mid = v.true_pose_at(t + v.dynamics.step_ns // 2)
    after = v.true_pose_at(t + v.dynamics.step_ns)
    assert mid is not None and after is not None
    assert mid[0][0] == pytest.approx(0.5 * (pose[0][0] + after[0][0]), abs=1e-9)
    assert v.true_pose_at(int(tr[0, 0]) - 1) is None
    assert v.true_pose_at(clock.now_ns() + 10**9) is None
    traj = v.trajectory(every_s=1.0)
    assert traj[0].armed is False and traj[-1].in_air is True  # flags of that moment


async def test_gps_loss_drifts_estimate_and_lands() -> None:
    v, clock = make()
    await airborne(v, clock)
    v.inject_gps_loss(60.0)
    assert not v.state().gps_fix
    await clock.sleep(0.5)
    assert v.state().position_valid
    await clock.sleep(1.0)
    assert not v.state().position_valid
    assert v.state().flight_mode == FlightMode.LAND
    await clock.sleep(6.0)
    est = v.state().position_ned_m
    true = v.true_state().position_ned_m
    assert math.dist(est[:2], true[:2]) > 1.0  # dead reckoning runs away
    await wait_until(lambda: not v.state().armed, 30.0, clock=clock, what="landed, disarmed")
    assert not v.state().armable
    with pytest.raises(VehicleError, match="GPS"):
        await v.arm()  # GPS is still lost: not armable


async def test_battery_failsafes() -> None:
    v, clock = make(rtl_return_altitude_m=6.0)
    await airborne(v, clock)
    v.set_battery_fraction(0.06)
    await clock.sleep(0.1)
    assert v.state().flight_mode == FlightMode.RETURN_TO_LAUNCH
    v.set_battery_fraction(0.04)
    await clock.sleep(0.1)
    assert v.state().flight_mode == FlightMode.LAND
    reasons = [e.data["reason"] for e in v.events() if e.kind == "failsafe"]
    assert reasons == ["Battery level critical", "Battery level emergency"]
    low, c2 = make()
    await low.connect()
    low.set_battery_fraction(0.1)
    with pytest.raises(VehicleError, match="battery"):
        await low.arm()
    with pytest.raises(ValueError):
        low.set_battery_fraction(1.5)


async def test_link_loss_freezes_telemetry_times_out_commands_and_can_trigger_rtl() -> None:
    v, clock = make(link_loss_action="return", link_loss_timeout_s=3.0, rtl_return_altitude_m=6.0)
    await airborne(v, clock)
    frozen = v.state()
    v.inject_link_loss(5.0)
    await clock.sleep(1.0)
    s = v.state()
    assert not s.link_ok and s.timestamp_ns == frozen.timestamp_ns
    t0 = clock.now_ns()
    with pytest.raises(VehicleError) as info:
        await v.hold()
    assert info.value.result == "TIMEOUT"
    assert (clock.now_ns() - t0) / 1e9 == pytest.approx(v.config.command_timeout_s)
    await clock.sleep(2.5)
    assert v.true_state().flight_mode == FlightMode.RETURN_TO_LAUNCH  # autopilot acted
    assert v.state().link_ok and v.state().flight_mode == FlightMode.RETURN_TO_LAUNCH
    assert [e.data["ok"] for e in v.events() if e.kind == "link"] == [False, True]


async def test_denied_command_and_disarm_rules() -> None:
    v, clock = make()
    await v.connect()
    v.deny_next_command("arm")
    with pytest.raises(VehicleError, match="denied") as info:
        await v.arm()
    assert info.value.result == "COMMAND_DENIED" and info.value.origin == "arm()"
    await v.arm()  # only the next one
    with pytest.raises(ValueError):
        v.deny_next_command("fly")
    await clock.sleep(11.0)  # COM_DISARM_PRFLT: no takeoff within 10 s
    assert not v.state().armed
    assert "Disarmed by auto preflight disarming" in [e.text for e in v.events()]
    await airborne(v, clock)
    with pytest.raises(VehicleError, match="in air"):
        await v.disarm()
    with pytest.raises(VehicleError):
        await v.takeoff(float("nan"))


async def test_goto_refused_on_ground_and_pilot_takeover_reported() -> None:
    v, clock = make()
    await v.connect()
    await v.arm()
    home = v.state().home
    assert home is not None
    with pytest.raises(VehicleError, match="take off"):
        await v.goto(home, 0.0)
    await airborne(v, clock)
    s = v.state()
    await v.start_offboard(Setpoint(*s.position_ned_m, s.yaw_deg))
    v.pilot_take_control(FlightMode.POSCTL)
    with pytest.raises(ModeChangedExternally, match="POSCTL"):
        await v.set_setpoint(Setpoint(*s.position_ned_m, s.yaw_deg))
    assert [e.data["source"] for e in v.events() if e.kind == "mode"][-1] == "pilot"
    await clock.sleep(3.0)
    assert math.dist(v.state().position_ned_m, s.position_ned_m) < 0.5  # sticks centred: holds


async def test_gripper_events_and_wait_until_timeout() -> None:
    v, clock = make()
    await v.connect()
    await v.grab()
    assert v.gripper_closed
    await v.release()
    assert [e.data["action"] for e in v.events() if e.kind == "gripper"] == ["grab", "release"]
    t0 = clock.now_ns()
    with pytest.raises(TimeoutError_, match="never"):
        await wait_until(lambda: False, 2.0, clock=clock, what="never")
    assert (clock.now_ns() - t0) / 1e9 == pytest.approx(2.0)


async def test_state_at_interpolates_telemetry() -> None:
    v, clock = make()
    await airborne(v, clock)
    await clock.sleep(1.0)
    s = v.state()
    mid = s.timestamp_ns - 10_000_000  # between 50 Hz samples
    at = v.state_at(mid)
    assert at is not None and at.timestamp_ns == mid
    assert v.state_at(s.timestamp_ns - 5 * 10**9) is None  # 2 s history


async def test_contract_catches_a_vehicle_that_does_not_hold() -> None:
    """The contract can fail: PX4's own default offboard-loss reaction (Position mode without
    RC: descend) is exactly what the watchdog must prevent."""
    clock = ManualClock()
    sim = SimulatedVehicle(SimulatedVehicleConfig(offboard_loss_action="position_no_rc",
                                                  dynamics=DynamicsParams()), clock=clock)
    backend = SimulatedBackend("px4-default-no-watchdog", sim, clock, sim)
    await sim.connect()
    with pytest.raises(pytest.fail.Exception, match="HOLD after setpoints stop"):
        await VehicleContract().test_watchdog_hold_when_setpoints_stop(backend)


# ---------------------------------------------------------------------------------------------
# Against the recorded PX4 v1.16 SITL traffic (../shared/data/px4_sitl_tlogs/summary.json)
# ---------------------------------------------------------------------------------------------
def _scenario(px4_tlogs: object, name: str) -> dict:  # type: ignore[type-arg]
    import json
    from pathlib import Path

    data = json.loads((Path(str(px4_tlogs)) / "summary.json").read_text())
    return next(s for s in data if s["scenario"] == name)


def _step_time(sc: dict, prefix: str) -> float:  # type: ignore[type-arg]
    return next(float(s["t"]) for s in sc["client_steps"] if s["step"].startswith(prefix))


async def test_offboard_loss_profile_matches_recorded_px4(px4_tlogs: object) -> None:
    """Scenario (b): the client dies in offboard at ~4.6 m; PX4 (COM_OF_LOSS_T = 1 s, no RC)
    goes to POSCTL and descends. The simulated vehicle configured like PX4 follows the recorded
    altitude profile."""
    rec = _scenario(px4_tlogs, "b")["offboard_loss"]["profile"]
    v, clock = make(offboard_loss_timeout_s=1.0, offboard_loss_action="position_no_rc")
    await airborne(v, clock, alt=4.6)
    s = v.state()
    sp = Setpoint(*s.position_ned_m, s.yaw_deg)
    await v.start_offboard(sp)
    for _ in range(40):
        await v.set_setpoint(sp)
        await clock.sleep(0.05)
    t_last = clock.now_ns()
    ours = []
    for row in rec:
        t = t_last + int(float(row["t_after_last_sp"]) * 1e9)
        await clock.sleep(max(0.0, (t - clock.now_ns()) / 1e9))
        ours.append(v.state())
    descending = [(r, o) for r, o in zip(rec, ours) if 2.5 <= float(r["t_after_last_sp"]) <= 7.5]
    assert descending
    for r, o in descending:
        assert abs(o.relative_altitude_m - float(r["rel_alt_m"])) < 0.6, (r, o.relative_altitude_m)
        assert abs(o.velocity_ned_mps[2] - float(r["vz_down_mps"])) < 0.2, (r, o.velocity_ned_mps)
        assert o.flight_mode == FlightMode.POSCTL
    recorded_disarm = next(float(r["t_after_last_sp"]) for r in rec if r["armed"] is False)
    ours_disarm = next(float(r["t_after_last_sp"]) for r, o in zip(rec, ours) if not o.armed)
    assert abs(ours_disarm - recorded_disarm) <= 3.0


async def test_takeoff_duration_same_order_as_recorded_px4(px4_tlogs: object) -> None:
    """Scenario (a): PX4 took 9.7 s from the takeoff ACK to 4.5 m. The simulated vehicle
    (spool-up 1.5 s, ramp 3 s, MPC_TKO_SPEED 1.5 m/s) is faster: ~6.4 s (ratio ~0.66)."""
    sc = _scenario(px4_tlogs, "a")
    recorded = _step_time(sc, "reached rel alt") - _step_time(sc, "takeoff (ack)")
    v, clock = make()
    await v.connect()
    await v.arm()
    t0 = clock.now_ns()
    await v.takeoff(5.0)
    await wait_until(lambda: v.state().relative_altitude_m >= 4.5, 30.0, clock=clock, poll_s=0.01)
    ours = (clock.now_ns() - t0) / 1e9
    assert 0.5 * recorded <= ours <= 1.2 * recorded, (ours, recorded)


# ---------------------------------------------------------------------------------------------
# RETURN_TO_LAUNCH / LAND right after other commands (a hold or setpoint still in its command
# latency must not be applied *after* the RTL's climb: it would leave the vehicle hovering in
# RTL for ever; the mission's final action sends stop_offboard() then return_to_launch() at the
# same instant)
# ---------------------------------------------------------------------------------------------
RTL_ALT_M = 10.0


def make_safe(**cfg: object) -> tuple[SimulatedVehicle, object, ManualClock]:
    """A simulated vehicle wrapped in the safety envelope, as the mission runner flies it."""
    from eaglemission.config import SafetyConfig
    from eaglemission.safety.envelope import SafeVehicle

    cfg.setdefault("rtl_return_altitude_m", RTL_ALT_M)
    sim, clock = make(**cfg)
    return sim, SafeVehicle(sim, SafetyConfig(), clock=clock), clock


async def _offboard_to(v: object, clock: ManualClock, goal: Setpoint, duration_s: float) -> None:
    s = v.state()  # type: ignore[attr-defined]
    await v.start_offboard(Setpoint(*s.position_ned_m, s.yaw_deg))  # type: ignore[attr-defined]
    t_end = clock.now_ns() + int(duration_s * 1e9)
    while clock.now_ns() < t_end:
        await v.set_setpoint(goal)  # type: ignore[attr-defined]
        await clock.sleep(0.05)
    await v.set_setpoint(goal)  # type: ignore[attr-defined]  # still in flight when RTL comes


async def _fly_rtl_to_the_end(sim: SimulatedVehicle, clock: ManualClock,
                              timeout_s: float) -> tuple[float, float, float]:
    """Wait (bounded) for the return to end disarmed; (duration s, max true altitude m, max true
    horizontal speed m/s)."""
    t0 = clock.now_ns()
    max_alt = max_speed = 0.0

    def disarmed() -> bool:
        nonlocal max_alt, max_speed
        t = sim.true_state()
        max_alt = max(max_alt, -t.position_ned_m[2])
        max_speed = max(max_speed, math.hypot(*t.velocity_ned_mps[:2]))
        return not sim.state().armed

    await wait_until(disarmed, timeout_s, clock=clock, poll_s=0.1, what="RTL landed and disarmed")
    return (clock.now_ns() - t0) / 1e9, max_alt, max_speed


def _assert_landed_at_home(sim: SimulatedVehicle) -> None:
    t = sim.true_state()
    assert t.position_ned_m[2] == 0.0 and not t.in_air and not t.armed
    assert math.hypot(*t.position_ned_m[:2]) < 1.5, t.position_ned_m  # estimate drift < 0.3 m
    assert "RTL: land at destination" in [e.text for e in sim.events()]


@pytest.mark.parametrize("before", ["hold", "stop_offboard", "setpoint", "goto_then_hold"])
@pytest.mark.parametrize("gap_s", [0.0, 0.01])  # both inside the 30 ms command latency
async def test_rtl_right_after_another_command_climbs_returns_lands_disarms(before: str,
                                                                           gap_s: float) -> None:
    sim, v, clock = make_safe()
    await airborne(sim, clock, alt=5.0)
    goal = Setpoint(12.0, -6.0, -5.0, 0.0)
    if before == "goto_then_hold":
        from eaglemission.geometry import ned_to_geodetic

        home = sim.state().home
        assert home is not None
        await v.goto(ned_to_geodetic(home, goal.north_m, goal.east_m, -5.0), 0.0)
        await wait_until(lambda: math.dist(sim.state().position_ned_m[:2], (12.0, -6.0)) < 0.5,
                         30.0, clock=clock)
    else:
        await _offboard_to(v, clock, goal, 8.0)
    far = sim.true_state().position_ned_m
    assert math.hypot(*far[:2]) > 12.0
    if before in ("hold", "goto_then_hold"):
        await v.hold()
    elif before == "stop_offboard":
        await v.stop_offboard()
    if gap_s:
        await clock.sleep(gap_s)
    await v.return_to_launch()
    assert sim.state().flight_mode == FlightMode.RETURN_TO_LAUNCH
    await clock.sleep(3.0)  # it must be on its way at once, not hovering
    assert -sim.true_state().position_ned_m[2] > 5.0 + 2.0
    cfg = sim.config
    dist_m = math.hypot(*far[:2])
    # climb 5 m + return at cruise speed + descend 10 m + land detection and auto-disarm
    bound_s = (5.0 / 1.0 + dist_m / cfg.dynamics.cruise_speed_mps + RTL_ALT_M / cfg.dynamics.land_speed_mps
               + cfg.land_detect_s + cfg.auto_disarm_after_land_s + 5.0)
    duration_s, max_alt, max_speed = await _fly_rtl_to_the_end(sim, clock, bound_s)
    assert 9.3 < max_alt < 10.6  # at the configured RTL altitude
    assert 0.8 * cfg.dynamics.cruise_speed_mps < max_speed < cfg.dynamics.cruise_speed_mps + 0.3
    _assert_landed_at_home(sim)
    assert modes(sim)[-2:] == ["RETURN_TO_LAUNCH", "HOLD"]  # disarmed by landing
    assert duration_s < bound_s


@pytest.mark.parametrize("when", ["mid_mission", "mission_finished"])
async def test_rtl_after_a_mission_returns_and_lands(when: str) -> None:
    sim, v, clock = make_safe()
    await airborne(sim, clock, alt=5.0)
    await v.upload_mission([Waypoint(15.0, 0.0, 6.0, speed_mps=4.0), Waypoint(15.0, 10.0, 6.0)])
    await v.start_mission()
    if when == "mid_mission":
        await wait_until(lambda: v.mission_progress().current >= 1, 30.0, clock=clock)
    else:
        await wait_until(lambda: v.mission_progress().finished, 60.0, clock=clock)
    await v.return_to_launch()
    _, max_alt, _ = await _fly_rtl_to_the_end(sim, clock, 60.0)
    assert 9.3 < max_alt < 10.6
    _assert_landed_at_home(sim)


async def test_rtl_after_offboard_then_mission_first_leg_not_undone_by_a_setpoint_in_flight() -> None:
    """start_mission() right after the offboard stream: the first leg is not overwritten."""
    sim, v, clock = make_safe()
    await airborne(sim, clock, alt=5.0)
    await v.upload_mission([Waypoint(-10.0, 5.0, 6.0, acceptance_radius_m=1.0)])
    await _offboard_to(v, clock, Setpoint(6.0, 0.0, -5.0, 0.0), 6.0)
    await v.stop_offboard()
    await v.start_mission()
    await wait_until(lambda: v.mission_progress().finished, 40.0, clock=clock, what="mission done")
    await v.return_to_launch()
    await _fly_rtl_to_the_end(sim, clock, 60.0)
    _assert_landed_at_home(sim)


@pytest.mark.parametrize("failsafe", ["battery_critical", "battery_emergency", "pilot_rtl"])
async def test_rtl_or_land_failsafe_during_a_setpoint_stream_is_not_undone(failsafe: str) -> None:
    """An autopilot failsafe fires while setpoints are streaming (one still in its latency):
    the failsafe's own command wins, the stream is told it lost control."""
    sim, v, clock = make_safe()
    await airborne(sim, clock, alt=5.0)
    goal = Setpoint(10.0, 4.0, -5.0, 0.0)
    await _offboard_to(v, clock, goal, 6.0)
    if failsafe == "pilot_rtl":
        sim.pilot_take_control(FlightMode.RETURN_TO_LAUNCH)
    else:
        sim.set_battery_fraction(0.06 if failsafe == "battery_critical" else 0.04)
    await clock.sleep(0.05)
    with pytest.raises(ModeChangedExternally):
        await v.set_setpoint(goal)
    p0 = sim.true_state().position_ned_m
    await _fly_rtl_to_the_end(sim, clock, 60.0)
    t = sim.true_state()
    assert t.position_ned_m[2] == 0.0 and not t.armed
    if failsafe == "battery_emergency":  # LAND where it is
        assert math.dist(t.position_ned_m[:2], p0[:2]) < 1.0
    else:
        _assert_landed_at_home(sim)


@pytest.mark.parametrize("mode", ["takeoff", "hold", "offboard", "mission", "rtl", "posctl"])
async def test_land_from_every_mode_lands_in_place_and_disarms(mode: str) -> None:
    sim, v, clock = make_safe()
    await v.connect()
    await v.arm()
    await v.takeoff(5.0)
    if mode == "takeoff":
        await wait_until(lambda: sim.state().relative_altitude_m > 2.0, 20.0, clock=clock)
    else:
        await wait_until(lambda: sim.state().flight_mode == FlightMode.HOLD, 30.0, clock=clock)
    if mode == "offboard":
        await _offboard_to(v, clock, Setpoint(8.0, 0.0, -5.0, 0.0), 3.0)
    elif mode == "mission":
        await v.upload_mission([Waypoint(20.0, 0.0, 5.0)])
        await v.start_mission()
        await clock.sleep(3.0)
    elif mode == "rtl":
        await v.return_to_launch()
        await clock.sleep(1.0)
    elif mode == "posctl":
        sim.pilot_take_control(FlightMode.POSCTL)
        await clock.sleep(1.0)
    expected = {"takeoff": FlightMode.TAKEOFF, "hold": FlightMode.HOLD, "offboard": FlightMode.OFFBOARD,
                "mission": FlightMode.MISSION, "rtl": FlightMode.RETURN_TO_LAUNCH,
                "posctl": FlightMode.POSCTL}[mode]
    assert sim.state().flight_mode == expected
    await v.land()
    assert sim.state().flight_mode == FlightMode.LAND
    t = sim.true_state()
    # where a vehicle moving at speed v comes to rest braking at ~1.8 m/s^2
    stop_m = math.hypot(*t.velocity_ned_mps[:2]) ** 2 / (2 * 1.8) + 0.5
    await wait_until(lambda: not sim.state().armed, 30.0, clock=clock, what="landed, disarmed")
    end = sim.true_state()
    assert end.position_ned_m[2] == 0.0 and not end.in_air
    assert math.dist(end.position_ned_m[:2], t.position_ned_m[:2]) < stop_m + 0.5
    assert "Disarmed by landing" in [e.text for e in sim.events()]


async def test_short_link_loss_in_offboard_fails_over_back_and_is_reported() -> None:
    """PX4 (recorded i): without setpoints for COM_OF_LOSS_T it fails over to Position and
    sinks; setpoints arriving again put it straight back in OFFBOARD. The link came back before
    the mission's own link-loss timeout, so the ``failover`` event is all that tells."""
    v, clock = make(link_loss_action="return", link_loss_timeout_s=3.0,
                    offboard_loss_action="position_no_rc")  # PX4's COM_OBL_RC_ACT=0
    s, sp = await offboard_hover(v, clock)
    v.inject_link_loss(2.0)
    lowest_m = math.inf
    for _ in range(100):  # 5 s of setpoints, 2 of them into the void
        with contextlib.suppress(VehicleError):
            await v.set_setpoint(sp)
        lowest_m = min(lowest_m, -v.true_state().position_ned_m[2])
        await clock.sleep(0.05)
    modes = [e.text for e in v.events() if e.kind == "mode"]
    assert any(m.endswith("-> POSCTL") for m in modes), modes  # the failover (unseen meanwhile)
    assert lowest_m < -s.position_ned_m[2] - 0.5  # it sank without stick input
    assert v.state().flight_mode == FlightMode.OFFBOARD  # and went back when setpoints returned
    ev = [e for e in v.events() if e.kind == "failover"]
    assert len(ev) == 1 and ev[0].data["gap_s"] == pytest.approx(2.0, abs=0.1)
