"""The simulated vehicle's ``link_delay`` (lab/vehicles/simulated/link.py) on what the mission
sends and looks up: streamed setpoints reach the dynamics ``delay_s`` late, in order, and
``state_at`` (the frames' poses) only sees the samples the ground has received."""

from __future__ import annotations

import pytest
from eaglemission.drivers.vehicles.wait import wait_until
from eaglemission.lab.vehicles.simulated.vehicle import SimulatedVehicle

from eaglemission.clock import ManualClock
from eaglemission.types import FlightMode, Setpoint, VehicleState

DELAY_S = 0.3
STEP_S = 0.005


async def _offboard() -> tuple[SimulatedVehicle, ManualClock, Setpoint]:
    """Airborne in OFFBOARD at its position, streaming its first setpoint for 1 s."""
    clock = ManualClock()
    v = SimulatedVehicle(clock=clock)
    await v.connect()
    await v.arm()
    await v.takeoff(5.0)
    await wait_until(lambda: v.state().flight_mode == FlightMode.HOLD, 30.0, clock=clock,
                     what="hold")
    s = v.state()
    hover = Setpoint(*s.position_ned_m, s.yaw_deg)
    await v.start_offboard(hover)
    for _ in range(20):
        await v.set_setpoint(hover)
        await clock.sleep(0.05)
    return v, clock, hover


def _north_speed_mps(v: SimulatedVehicle) -> float:
    return v.true_state().velocity_ned_mps[0]


def _ahead(hover: Setpoint, north_m: float) -> Setpoint:
    return Setpoint(hover.north_m + north_m, hover.east_m, hover.down_m, hover.yaw_deg)


async def test_a_delayed_setpoint_moves_the_vehicle_only_delay_s_later() -> None:
    v, clock, hover = await _offboard()
    v.inject_link_delay(DELAY_S, 3.0)
    target = _ahead(hover, 20.0)
    sent_ns = clock.now_ns()
    await v.set_setpoint(target)
    while clock.now_ns() - sent_ns < (DELAY_S - 0.01) * 1e9:
        clock.advance(STEP_S)
        assert v.autopilot.setpoint == hover
        assert abs(_north_speed_mps(v)) < 0.05
    clock.advance(0.02)
    v.true_state()  # steps the model
    assert v.autopilot.setpoint == target
    assert v.autopilot.setpoint_ns >= sent_ns + DELAY_S * 1e9  # arrived (offboard timer) late
    await clock.sleep(0.5)
    assert _north_speed_mps(v) > 0.5


async def test_delayed_setpoints_arrive_in_order_each_delay_s_after_it_was_sent() -> None:
    v, clock, hover = await _offboard()
    v.inject_link_delay(DELAY_S, 3.0)
    sent = [_ahead(hover, float(i)) for i in range(1, 6)]
    for sp in sent:
        await v.set_setpoint(sp)
        await clock.sleep(0.05)
    seen: list[tuple[float, Setpoint]] = []
    start_ns = clock.now_ns() - 5 * 50_000_000  # when the first was sent
    for _ in range(int(0.4 / STEP_S)):
        clock.advance(STEP_S)
        v.true_state()  # steps the model
        sp = v.autopilot.setpoint
        assert sp is not None
        if not seen or seen[-1][1] != sp:
            seen.append(((clock.now_ns() - start_ns) * 1e-9, sp))
    assert [sp for _, sp in seen] == [hover, *sent]
    for i, (t_s, _) in enumerate(seen[1:]):
        assert t_s == pytest.approx(DELAY_S + 0.05 * i, abs=STEP_S + 0.002)


async def _stream(v: SimulatedVehicle, clock: ManualClock, sp: Setpoint, seconds: float) -> None:
    for _ in range(round(seconds / 0.05)):
        await v.set_setpoint(sp)
        await clock.sleep(0.05)


async def test_after_the_window_a_setpoint_goes_through_and_overtakes_the_queue() -> None:
    v, clock, hover = await _offboard()
    v.inject_link_delay(DELAY_S, 0.5)
    queued = _ahead(hover, 3.0)
    await _stream(v, clock, queued, 0.55)  # sent 0-0.5 s, due 0.3-0.8 s after the injection
    assert v.autopilot.setpoint == queued
    fresh = _ahead(hover, 6.0)
    await v.set_setpoint(fresh)  # the window over: straight through again
    assert v.autopilot.setpoint == fresh
    for _ in range(int(0.4 / STEP_S)):
        clock.advance(STEP_S)
        v.true_state()
        assert v.autopilot.setpoint == fresh  # never an older one after it


async def test_a_setpoint_queued_when_the_window_ends_is_still_delivered() -> None:
    v, clock, hover = await _offboard()
    v.inject_link_delay(DELAY_S, 0.5)
    await _stream(v, clock, hover, 0.45)  # sent 0-0.4 s
    queued = _ahead(hover, 3.0)
    await v.set_setpoint(queued)  # sent at 0.45 s, due at 0.75 s
    await clock.sleep(0.27)
    v.true_state()
    assert v.autopilot.setpoint == hover
    await clock.sleep(0.05)
    v.true_state()
    assert v.autopilot.setpoint == queued
    assert v.autopilot.mode == FlightMode.OFFBOARD


async def _flying_north() -> tuple[SimulatedVehicle, ManualClock]:
    v, clock, hover = await _offboard()
    await v.set_setpoint(_ahead(hover, 40.0))
    for _ in range(20):
        await clock.sleep(0.05)
        await v.set_setpoint(_ahead(hover, 40.0))
    assert v.state().velocity_ned_mps[0] > 2.0
    return v, clock


def _same_sample(a: VehicleState, b: VehicleState) -> bool:
    return a.autopilot_time_ns == b.autopilot_time_ns and a.position_ned_m == b.position_ned_m


async def test_state_at_returns_no_sample_the_ground_has_not_received() -> None:
    v, clock = await _flying_north()
    v.inject_link_delay(DELAY_S, 2.0)
    for _ in range(int(1.0 / STEP_S)):  # read like the mission does
        clock.advance(STEP_S)
        v.state()
    now_ns = clock.now_ns()
    delivered = v.state()
    fresh = v.true_state()
    assert fresh.position_ned_m[0] - delivered.position_ned_m[0] > 0.5  # it is late
    at = v.state_at(delivered.timestamp_ns)
    assert at is not None and _same_sample(at, delivered)
    assert delivered.autopilot_time_ns is not None
    for back_ms in range(0, 900, 5):  # nothing newer than the delivered sample, at any time
        t_ns = now_ns - back_ms * 1_000_000
        st = v.state_at(t_ns)
        assert st is not None and st.autopilot_time_ns is not None
        assert st.autopilot_time_ns <= delivered.autopilot_time_ns
        assert st.position_ned_m[0] <= delivered.position_ned_m[0] + 1e-9
    ahead = v.state_at(now_ns + 40_000_000)  # extrapolated from the delivered sample only
    assert ahead is not None
    assert ahead.position_ned_m[0] < delivered.position_ned_m[0] + 0.5


async def test_state_at_sees_fresh_samples_again_after_the_window() -> None:
    v, clock = await _flying_north()
    v.inject_link_delay(DELAY_S, 0.5)
    for _ in range(int(1.0 / STEP_S)):
        clock.advance(STEP_S)
        v.state()
    s = v.state()
    at = v.state_at(s.timestamp_ns)
    assert at is not None and _same_sample(at, s)
    assert clock.now_ns() - s.timestamp_ns < 25_000_000  # fresh: one 50 Hz period at most


@pytest.mark.parametrize("fault", ["reorder", "duplicate"])
async def test_a_late_or_repeated_message_enters_the_history_stamped_on_receipt(
        fault: str) -> None:
    """The mavsdk driver's history takes every message MAVSDK hands it, stamped on receipt:
    a late (reordered) message stands there for a position already left, a copy repeats its
    position at a later stamp. ``state_at`` of the simulated vehicle must see the same."""
    v, clock = await _flying_north()
    getattr(v, f"inject_link_{fault}")(1.0)
    seen: list[VehicleState] = []
    for _ in range(int(0.8 / STEP_S)):
        clock.advance(STEP_S)
        s = v.state()
        if not seen or s.timestamp_ns != seen[-1].timestamp_ns:
            seen.append(s)
    again = [(a, b) for a, b in zip(seen, seen[1:])
             if b.autopilot_time_ns is not None and a.autopilot_time_ns is not None
             and b.autopilot_time_ns <= a.autopilot_time_ns]
    assert again, f"no {fault}d message delivered"
    for _, late in again:
        at = v.state_at(late.timestamp_ns)
        assert at is not None and _same_sample(at, late)
