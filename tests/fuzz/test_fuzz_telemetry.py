"""Fuzzing the safety envelope with hostile telemetry (tests/fuzz/fuzz_telemetry.py): every
command that leaves SafeVehicle is inside the envelope; only DriverErrors escape."""

from __future__ import annotations

import asyncio
import math
import random
from dataclasses import replace

import pytest
from eaglemission.lab.vehicles.simulated.vehicle import SimulatedVehicle
from fuzz_telemetry import HostileTelemetry, check_sent, check_sequence, random_sequence
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from eaglemission.clock import ManualClock
from eaglemission.config import GeofenceConfig, SafetyConfig
from eaglemission.errors import DriverError, SafetyViolation
from eaglemission.geometry import ned_to_geodetic
from eaglemission.safety.envelope import SafeVehicle
from eaglemission.types import Setpoint, VehicleState

FUZZ = settings(derandomize=True, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow])
SQUARE = [(-20.0, -20.0), (20.0, -20.0), (20.0, 20.0), (-20.0, 20.0)]


@settings(FUZZ, max_examples=25)
@given(st.randoms(use_true_random=False))
def test_hostile_telemetry_never_gets_a_command_out_of_the_envelope(rand: random.Random) -> None:
    assert check_sequence(random_sequence(rand, rand.randint(1, 12))) in ("flown", "refused")


class _Scripted(HostileTelemetry):
    """Telemetry from a list of states set by the test (after the real vehicle's first)."""

    def __init__(self, inner: SimulatedVehicle) -> None:
        super().__init__(inner)
        self.override: VehicleState | None = None

    def state(self) -> VehicleState:
        s = self.inner.state() if self.override is None else self.override
        self.seen = s
        return s


async def _rig(safety: SafetyConfig) -> tuple[SafeVehicle, _Scripted, ManualClock]:
    sim = SimulatedVehicle(clock=ManualClock())
    hostile = _Scripted(sim)
    clock = ManualClock()
    safe = SafeVehicle(hostile, safety, clock=clock)  # type: ignore[arg-type]
    await safe.connect()
    await safe.arm()
    return safe, hostile, clock


def _at(hostile: _Scripted, n: float, e: float, d: float) -> VehicleState:
    return replace(hostile.inner.state(), position_ned_m=(n, e, d))


async def test_nan_position_holds_the_last_setpoint() -> None:
    """A fuzzing case: with a NaN position set_setpoint holds, it does not raise ValueError
    (Setpoint.north_m must be finite)."""
    safe, hostile, clock = await _rig(SafetyConfig())
    await safe.start_offboard(Setpoint(0.0, 0.0, -1.0, 0.0))
    await safe.set_setpoint(Setpoint(5.0, 0.0, -5.0, 0.0))
    last = safe.last_sent
    hostile.override = _at(hostile, math.nan, 0.0, math.nan)
    clock.advance(0.05)
    await safe.set_setpoint(Setpoint(50.0, 0.0, -5.0, 0.0))
    assert safe.last_sent == replace(last, yaw_deg=0.0)
    assert any("non-finite or absurd position" in ev.text for ev in safe.events())
    check_sent(safe, hostile.sent, "nan")


async def test_nan_position_refuses_what_needs_a_start() -> None:
    """A fuzzing case: goto / upload_mission with a NaN position are refused, not a ValueError
    ("cannot convert float NaN to integer") from the path check."""
    safe, hostile, _ = await _rig(SafetyConfig(geofence=GeofenceConfig(polygon_ned_m=SQUARE)))
    home = hostile.inner.state().home
    assert home is not None
    hostile.override = _at(hostile, math.nan, math.nan, -3.0)
    for call in (safe.goto(ned_to_geodetic(home, 5.0, 5.0, -5.0), 0.0),
                 safe.start_offboard(Setpoint(0.0, 0.0, -3.0, 0.0)), safe.takeoff(3.0)):
        with pytest.raises(SafetyViolation, match="NO_POSITION"):
            await call
    assert hostile.sent == []


async def test_a_step_left_from_before_an_altitude_jump_stays_in_the_band() -> None:
    """A fuzzing case: the reported altitude jumps after a step was sent; the next step (dt = 0)
    must not repeat the earlier one, below the band and below the vehicle."""
    safety = SafetyConfig(min_altitude_m=5.0, max_altitude_m=20.0)
    safe, hostile, _ = await _rig(safety)
    hostile.override = _at(hostile, 0.0, 0.0, -0.1)  # on the ground, below the band
    await safe.start_offboard(Setpoint(0.0, 0.0, -10.0, 0.0))
    hostile.override = _at(hostile, 0.0, 0.0, -12.0)  # now reported inside the band
    await safe.set_setpoint(Setpoint(0.0, 0.0, -10.0, 0.0))
    assert safe.last_sent is not None and safe.envelope.alt_ok(-safe.last_sent.down_m)
    check_sent(safe, hostile.sent, "jump")


async def test_a_position_a_million_km_away_is_stepped_without_stalling() -> None:
    """A fuzzing case: a path search sampling every 0.25 m up to the reported position would
    take 4e9 samples inside set_setpoint after a telemetry jump of 1e9 m."""
    safe, hostile, clock = await _rig(SafetyConfig(geofence=GeofenceConfig(polygon_ned_m=SQUARE)))
    await safe.start_offboard(Setpoint(0.0, 0.0, -3.0, 0.0))
    hostile.override = _at(hostile, 1e9, -1e9, -3.0)
    clock.advance(0.05)
    await asyncio.wait_for(safe.set_setpoint(Setpoint(5.0, 5.0, -3.0, 0.0)), timeout=30.0)
    check_sent(safe, hostile.sent, "far")


def test_a_polygon_without_room_inside_its_margin_is_refused_at_construction() -> None:
    """A fuzzing case: such a fence would fail mid-flight ("the geofence leaves no room")."""
    tiny = [(-2.0, -2.0), (2.0, -2.0), (2.0, 2.0), (-2.0, 2.0)]
    with pytest.raises(ValueError, match="polygon_ned_m: neither home nor"):
        SafeVehicle(SimulatedVehicle(clock=ManualClock()),
                    SafetyConfig(geofence=GeofenceConfig(radius_m=None, polygon_ned_m=tiny)))


async def test_an_absurdly_far_but_finite_position_is_no_position() -> None:
    """A fuzzing case (hypothesis drew a drift of 9e307 m): the step must not overflow to NaN
    and make set_setpoint raise ValueError."""
    safe, hostile, clock = await _rig(SafetyConfig(geofence=GeofenceConfig(radius_m=15.0)))
    await safe.start_offboard(Setpoint(0.0, 0.0, -1.0, 0.0))
    hostile.override = _at(hostile, 0.0, 8.98846567431158e307, -1.0)
    clock.advance(0.05)
    await safe.set_setpoint(Setpoint(0.0, 0.0, -1.0, 0.0))
    check_sent(safe, hostile.sent, "9e307")


class _Sequenced(HostileTelemetry):
    """Telemetry that moves on at every read: the given states in turn, then the last (the
    real vehicle's while none are given)."""

    def __init__(self, inner: SimulatedVehicle) -> None:
        super().__init__(inner)
        self.states: list[VehicleState] = []

    def state(self) -> VehicleState:
        if not self.states:
            return self.inner.state()
        s = self.states.pop(0) if len(self.states) > 1 else self.states[0]
        self.seen = s
        return s


async def test_goto_checks_the_home_and_the_position_of_one_sample() -> None:
    """A fuzzing case (`benchmarks/fuzz.py --telemetry 100000 --seed 16`: 49 scripts): goto
    takes the home and the position from one telemetry read; from two reads, with a replayed
    sample without home in between, it would send a target placed by a home the vehicle no
    longer reports."""
    hostile = _Sequenced(SimulatedVehicle(clock=ManualClock()))
    safe = SafeVehicle(hostile, SafetyConfig(), clock=ManualClock())  # type: ignore[arg-type]
    await safe.connect()
    await safe.arm()
    good = hostile.inner.state()
    assert good.home is not None
    target = ned_to_geodetic(good.home, 5.0, 5.0, -5.0)
    moved = replace(good, home=None, position_ned_m=(3.0, 0.0, -2.0))
    hostile.states = [good, moved, good]
    with pytest.raises(DriverError):  # the simulated vehicle refuses a goto on the ground
        await safe.goto(target, 0.0)
    assert [k for k, _ in hostile.sent] == ["goto"]
    check_sent(safe, hostile.sent, "one sample")  # the checker reads the sample goto used
    hostile.states = [moved, good]
    with pytest.raises(SafetyViolation, match="NO_HOME"):
        await safe.goto(target, 0.0)
    assert len(hostile.sent) == 1
    await safe.close()
