"""The downward rangefinder end to end: the pure reading model, the simulated vehicle's field,
the emulator's DISTANCE_SENSOR (as PX4 v1.16 SIH sends it) and the MAVSDK driver's
``distance_to_ground_m`` (downward, in range, fresh)."""

from __future__ import annotations

import asyncio
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from eaglemission.drivers.vehicles.mavsdk.vehicle import downward_range_m
from eaglemission.drivers.vehicles.wait import wait_until
from eaglemission.lab.vehicles.emulator.emulator import (
    DISTANCE_NO_RETURN_CM,
    PX4_ONBOARD_RATES_HZ,
    distance_sensor_cm,
    mavlink,
)
from eaglemission.lab.vehicles.multicopter.dynamics import RangefinderParams, rangefinder_reading_m
from eaglemission.lab.vehicles.simulated.vehicle import SimulatedVehicle, SimulatedVehicleConfig
from emulator_support import flying_pair, scenario, wait_for
from mavsdk.plugins.telemetry import DistanceSensor, EulerAngle

from eaglemission.clock import ManualClock
from eaglemission.geometry import down_axis_cos_tilt as cos_tilt
from eaglemission.geometry import ned_to_geodetic
from eaglemission.types import FlightMode, GeoPoint, Setpoint

M = mavlink
RF = RangefinderParams(enabled=True, noise_std_m=0.01, min_range_m=0.1, max_range_m=12.0)


# ---------------------------------------------------------------------------------------------
# pure models
# ---------------------------------------------------------------------------------------------
def test_reading_is_the_slant_range_plus_noise_inside_the_range_only() -> None:
    rng = np.random.RandomState(71)
    assert rangefinder_reading_m(-5.0, 1.0, RF, 0.0) == pytest.approx(5.0)
    # tilted 36.87 deg: the beam is longer by 1 / cos
    assert rangefinder_reading_m(-4.0, 0.8, RF, 0.0) == pytest.approx(5.0)
    n = float(rng.standard_normal())
    assert rangefinder_reading_m(-5.0, 1.0, RF, n) == pytest.approx(5.0 + 0.01 * n)
    assert rangefinder_reading_m(-5.0, 1.0, RF.model_copy(update={"enabled": False}), 0.0) is None
    assert rangefinder_reading_m(0.0, 1.0, RF, 0.0) is None  # on the ground: below min
    assert rangefinder_reading_m(-0.05, 1.0, RF, 0.0) is None
    assert rangefinder_reading_m(-12.5, 1.0, RF, 0.0) is None  # beyond max
    assert rangefinder_reading_m(-11.0, 0.9, RF, 0.0) is None  # 12.2 m slant > max
    assert rangefinder_reading_m(-1.0, 0.05, RF, 0.0) is None  # beam at the horizon
    # noise statistics: unbiased, the configured spread
    draws = rng.standard_normal(4000)
    vals = np.array([rangefinder_reading_m(-3.0, 1.0, RF, float(d)) for d in draws])
    assert abs(vals.mean() - 3.0) < 0.001 and vals.std() == pytest.approx(0.01, rel=0.08)


def test_distance_sensor_encoding_follows_px4_sih() -> None:
    # in range: metres * 100 truncated to a uint16, min/max in cm
    assert distance_sensor_cm(-4.567, 1.0, RF, 0.0) == (456, 10, 1200)
    assert distance_sensor_cm(-4.0, 0.8, RF, 0.3) == (500, 10, 1200)  # 5.003 m -> 500 cm
    # beyond the range or beam at the horizon: UINT16_MAX, as SIH ("lightware lw20 behaviour")
    assert distance_sensor_cm(-20.0, 1.0, RF, 0.0)[0] == DISTANCE_NO_RETURN_CM == 65535
    assert distance_sensor_cm(-1.0, 0.0, RF, 0.0)[0] == DISTANCE_NO_RETURN_CM
    # below min (on the ground): the geometric value, outside [min, max] (recorded: 0 cm)
    assert distance_sensor_cm(0.0, 1.0, RF, 0.0)[0] == 0
    cur, lo, hi = distance_sensor_cm(-0.07, 1.0, RF, 0.0)
    assert cur == 7 and cur < lo
    assert PX4_ONBOARD_RATES_HZ["DISTANCE_SENSOR"] == 10.0


def _sample(current_m: float, pitch_deg: float = 270.0, roll_deg: float = 0.0,
            lo: float = 0.1, hi: float = 12.0) -> DistanceSensor:
    return DistanceSensor(lo, hi, current_m, EulerAngle(roll_deg, pitch_deg, 0.0))


def test_driver_accepts_only_downward_in_range_readings() -> None:
    assert downward_range_m(_sample(4.2)) == pytest.approx(4.2)
    assert downward_range_m(_sample(4.2, pitch_deg=-90.0)) == pytest.approx(4.2)
    assert downward_range_m(_sample(4.2, pitch_deg=0.0)) is None  # forward (or unknown)
    assert downward_range_m(_sample(4.2, pitch_deg=90.0)) is None  # upward
    assert downward_range_m(_sample(4.2, pitch_deg=270.0, roll_deg=90.0)) is None
    assert downward_range_m(_sample(4.2, pitch_deg=math.nan)) is None
    assert downward_range_m(_sample(655.35)) is None  # PX4's "no return"
    assert downward_range_m(_sample(0.0)) is None  # on the ground, below min
    assert downward_range_m(_sample(0.05)) is None
    assert downward_range_m(_sample(12.0)) == pytest.approx(12.0)
    assert downward_range_m(_sample(math.nan)) is None
    assert downward_range_m(_sample(0.3, lo=math.nan, hi=math.nan)) == pytest.approx(0.3)


def test_recorded_px4_distance_sensor_is_what_the_emulator_imitates(px4_tlogs: Path) -> None:
    """PX4 v1.16 SIH (recorded): ~10 Hz, LASER, id 0, PITCH_270, covariance 0, signal quality 0,
    0 cm on the ground, whole cm in flight, 65535 cm (no return) beyond its range."""
    px4, _, _ = scenario(px4_tlogs, "c")
    ds = [(t, m) for t, m in px4 if m.get_type() == "DISTANCE_SENSOR"]
    span = px4[-1][0] - px4[0][0]
    assert len(ds) / span == pytest.approx(PX4_ONBOARD_RATES_HZ["DISTANCE_SENSOR"], rel=0.1)
    assert {(m.type, m.id, m.orientation, m.covariance, m.signal_quality) for _, m in ds} == {
        (M.MAV_DISTANCE_SENSOR_LASER, 0, M.MAV_SENSOR_ROTATION_PITCH_270, 0, 0)}
    assert ds[0][1].current_distance == 0  # on the ground
    assert max(m.current_distance for _, m in ds) > 900  # the 10 m mission legs


# ---------------------------------------------------------------------------------------------
# simulated vehicle
# ---------------------------------------------------------------------------------------------
async def test_simulated_vehicle_reports_the_slant_range_from_the_true_pose() -> None:
    clock = ManualClock()
    v = SimulatedVehicle(SimulatedVehicleConfig(seed=5, rangefinder=RF), clock=clock,
                         simulation=None)
    await v.connect()
    assert v.state().distance_to_ground_m is None  # on the ground: below min_range_m
    await v.arm()
    await v.takeoff(5.0)
    await wait_until(lambda: v.state().flight_mode == FlightMode.HOLD, 30.0, clock=clock,
                     what="hold")
    await clock.sleep(3.0)
    errs = []
    for _ in range(100):  # hover at a known true height
        await clock.sleep(0.05)
        s = v.state()
        pos, q = v.true_pose_at(s.timestamp_ns)
        assert s.distance_to_ground_m is not None
        errs.append(s.distance_to_ground_m - (-pos[2]) / cos_tilt(q))
    assert -v.true_state().position_ned_m[2] == pytest.approx(5.0, abs=0.5)
    assert abs(float(np.mean(errs))) < 0.004 and float(np.std(errs)) == pytest.approx(0.01, rel=0.3)
    # tilted while accelerating sideways: the beam is longer than the height
    here = v.state()
    await v.start_offboard(Setpoint(*here.position_ned_m, here.yaw_deg))
    goal = Setpoint(here.position_ned_m[0] + 20.0, here.position_ned_m[1], here.position_ned_m[2],
                    here.yaw_deg)
    tilted = []
    for _ in range(40):
        await v.set_setpoint(goal)
        await clock.sleep(0.05)
        s = v.state()
        pos, q = v.true_pose_at(s.timestamp_ns)
        if s.distance_to_ground_m is not None and cos_tilt(q) < 0.995:
            tilted.append((s.distance_to_ground_m, -pos[2], cos_tilt(q)))
    assert len(tilted) > 10
    for d, h, c in tilted:
        assert d == pytest.approx(h / c, abs=0.05)
        assert d > h + 0.01 or c > 0.999  # visibly longer than the height
    await v.close()


# ---------------------------------------------------------------------------------------------
# emulator + MAVSDK driver
# ---------------------------------------------------------------------------------------------
def _truth(emu: Any) -> tuple[float, float, float]:
    """(true slant range, true down, estimate down error) now."""
    snap = emu.snapshot()
    c = cos_tilt(snap.true_attitude_q)
    down = snap.true_position_ned_m[2]
    return -down / c, down, snap.estimate_position_ned_m[2] - down


async def _hover(v: Any, altitude_m: float) -> None:
    await v.arm()
    await v.takeoff(altitude_m)
    await wait_for(lambda: v.state().flight_mode == FlightMode.HOLD and v.state().in_air, 20.0,
                   "hover")


async def test_emulator_streams_distance_sensor_and_the_driver_tracks_the_true_height() -> None:
    rf = {"enabled": True, "noise_std_m": 0.01, "min_range_m": 0.1, "max_range_m": 12.0}
    async with flying_pair(4.0, record=True, emulator={"rangefinder": rf, "seed": 3}) as (emu, v, clock):
        await asyncio.sleep(0.5)
        sent = [t.msg for t in emu.sent("DISTANCE_SENSOR")]
        assert sent, "no DISTANCE_SENSOR with the sensor enabled"
        m = sent[-1]
        assert (m.type, m.id, m.orientation, m.covariance, m.signal_quality) == (
            M.MAV_DISTANCE_SENSOR_LASER, 0, M.MAV_SENSOR_ROTATION_PITCH_270, 0, 0)
        assert (m.min_distance, m.max_distance, m.current_distance) == (10, 1200, 0)  # on ground
        assert v.state().distance_to_ground_m is None  # 0 cm < min: not a range
        # the driver asks for 20 Hz (PX4's Onboard default is 10 Hz)
        n0, t0 = len(emu.sent("DISTANCE_SENSOR")), time.monotonic()
        await asyncio.sleep(1.0)
        hz = (len(emu.sent("DISTANCE_SENSOR")) - n0) / (time.monotonic() - t0)
        assert 14.0 <= hz <= 21.0, hz

        await _hover(v, 4.0)
        await clock.sleep(2.0)
        errs, ground = [], []
        for _ in range(40):
            await asyncio.sleep(0.03)
            s = v.state()
            slant, _, est_err = _truth(emu)
            d = s.distance_to_ground_m
            assert d is not None
            errs.append(d - slant)
            # the ground in the driver's (estimated) frame is where the estimate error puts it
            ground.append(s.position_ned_m[2] + d * cos_tilt(s.attitude_q) - est_err)
        # noise 1 cm, PX4's truncation to whole cm (-0.5 cm), a hover that still breathes
        assert abs(float(np.mean(errs)) + 0.005) < 0.02, np.mean(errs)
        assert max(abs(e) for e in errs) < 0.08
        assert abs(float(np.median(ground))) < 0.05, np.median(ground)

        # climb and fly sideways (tilted): the reading follows, beam-corrected
        s = v.state()
        assert s.home is not None
        g = ned_to_geodetic(s.home, 12.0, 0.0, 0.0)
        target = GeoPoint(g.latitude_deg, g.longitude_deg, s.home.altitude_amsl_m + 7.0)
        truths: list[tuple[float, float]] = []  # (wall s, true slant range)
        for _ in range(10):  # the truth over the first readings' age
            truths.append((time.monotonic(), _truth(emu)[0]))
            await asyncio.sleep(0.03)
        await v.goto(target, s.yaw_deg)
        pairs = []
        deadline = time.monotonic() + 15.0
        while time.monotonic() < deadline:
            await asyncio.sleep(0.03)
            s = v.state()
            slant, down, _ = _truth(emu)
            now = time.monotonic()
            truths.append((now, slant))
            if s.distance_to_ground_m is not None:
                # the truth over the reading's possible age: the 20 Hz stream plus scheduling
                # delay on a loaded machine (up to 0.3 s wall; the emulator runs faster)
                recent = [t for w, t in truths if now - w <= 0.3]
                pairs.append((s.distance_to_ground_m, slant, min(recent), max(recent)))
            if -down > 6.9 and abs(12.0 - s.position_ned_m[0]) < 0.5:
                break
        readings = [p[0] for p in pairs]
        assert min(readings) < 4.5 and max(readings) > 6.5, (min(readings), max(readings))
        for d, slant, lo, hi in pairs:
            # noise 1 cm + whole-cm truncation + the hover's breathing (bound as above)
            assert lo - 0.08 < d < hi + 0.08, (d, slant, lo, hi)

        # the sensor stops: the value goes stale -> None, while telemetry still flows
        emu.inject_rangefinder_loss(4.0)
        await wait_for(lambda: v.state().distance_to_ground_m is None, 2.0, "stale reading")
        await clock.sleep(0.3)  # the history judges age at each sample's time: a little later
        assert v.state().link_ok and v.state().distance_to_ground_m is None
        assert v.state_at(v.state().timestamp_ns).distance_to_ground_m is None
        await wait_for(lambda: v.state().distance_to_ground_m is not None, 3.0, "sensor back")


async def test_no_sensor_or_out_of_range_gives_none() -> None:
    async with flying_pair(4.0, record=True) as (emu, v, clock):
        await _hover(v, 3.0)
        await clock.sleep(1.0)
        assert emu.sent("DISTANCE_SENSOR") == []  # PX4 without a sensor sends none
        assert v.state().distance_to_ground_m is None
        past = [v.state_at(v.state().timestamp_ns - k * 10_000_000) for k in range(5)]
        assert all(h is not None and h.distance_to_ground_m is None for h in past)
    short = {"enabled": True, "min_range_m": 0.1, "max_range_m": 2.0}
    async with flying_pair(4.0, record=True, emulator={"rangefinder": short}) as (emu, v, clock):
        await _hover(v, 3.0)
        await clock.sleep(1.0)
        last = emu.sent("DISTANCE_SENSOR")[-1].msg
        assert last.current_distance == DISTANCE_NO_RETURN_CM and last.max_distance == 200
        assert v.state().distance_to_ground_m is None
