"""The kinematic multicopter: determinism, limits, attitude from acceleration, wind, estimate."""

from __future__ import annotations

import math

import numpy as np
import pytest
from eaglemission.lab.vehicles.multicopter.dynamics import (
    GRAVITY_MPS2,
    DynamicsParams,
    EstimateModel,
    MulticopterDynamics,
    attitude_from_acceleration,
    stopping_point,
)

from eaglemission.geometry import R_to_euler, quat_to_R
from eaglemission.types import Setpoint


def _airborne(seed: int = 3, **kw: object) -> MulticopterDynamics:
    dyn = MulticopterDynamics(seed=seed, **kw)  # type: ignore[arg-type]
    dyn.set_motors(True)
    dyn.command_position(Setpoint(0.0, 0.0, -5.0, 0.0), immediate=True)
    dyn.step(8.0)
    return dyn


def test_repeat_runs_bit_identical_and_seed_matters() -> None:
    rng = np.random.RandomState(11)
    cmds = [Setpoint(*rng.uniform(-10, 10, 2), -rng.uniform(2, 8), rng.uniform(-180, 180))
            for _ in range(6)]

    def run(seed: int) -> tuple[float, ...]:
        dyn = MulticopterDynamics(seed=seed, wind_ne_mps=(1.0, -2.0))
        dyn.set_motors(True)
        for sp in cmds:
            dyn.command_position(sp)
            dyn.step(2.0)
        s = dyn.truth()
        return (*s.position_ned_m, *s.velocity_ned_mps, s.yaw_deg, *dyn.estimate().position_ned_m)

    assert run(5) == run(5)
    assert run(5) != run(6)


def test_same_commands_same_times_bit_identical_across_chunkings() -> None:
    def run(chunk_s: float) -> tuple[float, ...]:
        dyn = MulticopterDynamics(seed=9, wind_ne_mps=(2.0, 0.0))
        dyn.set_motors(True)
        dyn.command_position(Setpoint(3.0, -4.0, -6.0, 120.0))
        n = int(round(4.0 / chunk_s))
        for _ in range(n):
            dyn.step(chunk_s)
        dyn.command_velocity((1.0, 1.0, 0.0), 45.0)
        for _ in range(n):
            dyn.step(chunk_s)
        s = dyn.truth()
        return (*s.position_ned_m, *s.velocity_ned_mps, s.yaw_deg)

    assert run(0.01) == run(0.1) == run(0.5) == run(2.0)


def test_takeoff_climbs_within_vertical_speed_limit() -> None:
    dyn = MulticopterDynamics(seed=1)
    dyn.set_motors(True)
    dyn.command_position(Setpoint(0.0, 0.0, -10.0, 0.0), max_up_speed_mps=1.5, immediate=True)
    max_up = 0.0

    def watch(d: MulticopterDynamics) -> None:
        nonlocal max_up
        max_up = max(max_up, -d.vd)

    dyn.step(12.0, watch)
    assert -dyn.pd == pytest.approx(10.0, abs=0.4)
    assert 1.3 < max_up <= 1.5 + 0.05
    assert not dyn.on_ground


def test_speed_and_acceleration_limits_and_small_overshoot() -> None:
    p = DynamicsParams(max_horizontal_speed_mps=6.0, cruise_speed_mps=6.0, max_horizontal_accel_mps2=2.5)
    dyn = MulticopterDynamics(p, seed=2)
    dyn.set_motors(True)
    dyn.command_position(Setpoint(0.0, 0.0, -5.0, 0.0), immediate=True)
    dyn.step(6.0)
    dyn.command_position(Setpoint(40.0, 0.0, -5.0, 0.0), immediate=True)
    stats = {"v": 0.0, "a": 0.0, "n": -1e9}
    prev = [dyn.vn]

    def watch(d: MulticopterDynamics) -> None:
        stats["v"] = max(stats["v"], math.hypot(d.vn, d.ve))
        stats["a"] = max(stats["a"], abs(d.an))
        stats["n"] = max(stats["n"], d.pn)
        prev[0] = d.vn

    dyn.step(20.0, watch)
    assert 5.5 < stats["v"] <= 6.0 + 0.1
    assert stats["a"] <= 2.5 + 1e-9
    assert stats["n"] - 40.0 < 0.5  # overshoot below half a metre
    assert dyn.pn == pytest.approx(40.0 - dyn.estimate_model.error_ned_m[0], abs=0.15)


def test_braking_tilts_the_body_by_atan_a_over_g() -> None:
    dyn = _airborne()
    dyn.command_position(Setpoint(30.0, 0.0, -5.0, 0.0), immediate=True)
    dyn.step(3.0)  # accelerating north
    s = dyn.truth()
    roll, pitch, _ = R_to_euler(quat_to_R(s.attitude_q))
    assert s.acceleration_ned_mps2[0] > 1.0
    assert pitch == pytest.approx(-math.degrees(math.atan2(s.acceleration_ned_mps2[0],
                                                           GRAVITY_MPS2 - s.acceleration_ned_mps2[2])), abs=0.5)
    assert pitch < -5.0  # nose down when accelerating forward
    dyn.step(4.0)  # now braking towards 30 m
    s = dyn.truth()
    roll, pitch, _ = R_to_euler(quat_to_R(s.attitude_q))
    assert s.acceleration_ned_mps2[0] < -1.0
    assert pitch > 5.0  # nose up when braking: a body-fixed camera tilts up
    assert s.tilt_deg == pytest.approx(abs(pitch), abs=1.0)


def test_attitude_from_acceleration_level_and_yaw() -> None:
    q = attitude_from_acceleration((0.0, 0.0, 0.0), 90.0)
    roll, pitch, yaw = R_to_euler(quat_to_R(q))
    assert (roll, pitch, yaw) == pytest.approx((0.0, 0.0, 90.0), abs=1e-9)
    a = 3.0
    q = attitude_from_acceleration((0.0, a, 0.0), 0.0)  # accelerate east: roll right
    roll, pitch, yaw = R_to_euler(quat_to_R(q))
    assert roll == pytest.approx(math.degrees(math.atan(a / GRAVITY_MPS2)), abs=1e-6)
    assert pitch == pytest.approx(0.0, abs=1e-9)


def test_command_latency() -> None:
    p = DynamicsParams(command_latency_s=0.2)
    dyn = MulticopterDynamics(p, seed=1)
    dyn.set_motors(True)
    dyn.command_position(Setpoint(0.0, 0.0, -5.0, 0.0))
    dyn.step(0.19)
    assert dyn.on_ground and dyn.pd == 0.0
    dyn.step(0.2)
    assert dyn.vd < 0.0


def test_immediate_command_supersedes_commands_still_in_flight() -> None:
    """The newest command wins: an external hold still in its latency must not be applied
    after the autopilot's own (immediate) climb, which is issued once and never repeated."""
    dyn = _airborne(seed=2)
    dyn.command_hold()  # external, 30 ms latency
    dyn.command_position(Setpoint(0.0, 0.0, -10.0, 0.0), immediate=True)  # e.g. RTL climb
    dyn.step(0.1)
    assert dyn.setpoint_ned_m[2] == -10.0
    dyn.step(6.0)
    assert dyn.pd < -9.0
    # delayed commands keep their order among themselves
    dyn.command_position(Setpoint(3.0, 0.0, -10.0, 0.0))
    dyn.command_hold()
    dyn.step(0.1)
    assert dyn.setpoint_ned_m[0] < 1.0


def test_wind_is_rejected_with_lag_and_the_body_leans_into_it() -> None:
    dyn = _airborne(wind_ne_mps=(0.0, 5.0))
    worst = 0.0

    def watch(d: MulticopterDynamics) -> None:
        nonlocal worst
        worst = max(worst, abs(d.pe))

    dyn.step(20.0, watch)
    assert 0.1 < worst < 1.5  # the gust-free step of wind pushes it, then the integrator wins
    assert abs(dyn.pe - (-dyn.estimate_model.error_ned_m[1])) < 0.15
    s = dyn.truth()
    roll, _, _ = R_to_euler(quat_to_R(s.attitude_q))
    expected = math.degrees(math.atan(dyn.params.drag_per_s * 5.0 / GRAVITY_MPS2))
    assert roll == pytest.approx(-expected, abs=1.0)  # thrust points west, into the wind


def test_yaw_rate_limited_and_wraps() -> None:
    dyn = _airborne()
    dyn.command_position(Setpoint(0.0, 0.0, -5.0, 170.0), immediate=True)
    dyn.step(5.0)
    dyn.command_position(Setpoint(0.0, 0.0, -5.0, -170.0), immediate=True)  # 20 deg through 180
    rates: list[float] = []
    dyn.step(2.0, lambda d: rates.append(d.yaw_rate_degps))
    assert max(abs(r) for r in rates) <= dyn.params.max_yaw_rate_degps
    assert all(r >= 0 for r in rates)  # short way: increasing through +180
    assert dyn.yaw_deg == pytest.approx(-170.0, abs=0.5)


def test_land_reaches_ground_and_stays() -> None:
    dyn = _airborne()
    dyn.command_land(immediate=True)
    speeds: list[float] = []
    dyn.step(12.0, lambda d: speeds.append(d.vd))
    assert dyn.on_ground and dyn.pd == 0.0
    assert max(speeds) <= dyn.params.land_speed_mps + 0.05
    dyn.set_motors(False)
    dyn.step(1.0)
    assert dyn.on_ground and dyn.truth().speed_mps == 0.0


def test_hold_brakes_to_the_stopping_point() -> None:
    dyn = _airborne()
    dyn.command_velocity((4.0, 0.0, 0.0), immediate=True)
    dyn.step(5.0)
    n0 = dyn.pn
    dyn.command_hold(immediate=True)
    dyn.step(8.0)
    assert abs(dyn.vn) < 0.05
    assert 0.5 < dyn.pn - n0 < 6.0


def test_estimate_drifts_bounded_and_seeded() -> None:
    a = EstimateModel(seed=4, horizontal_std_m=0.1, max_error_m=0.3, correlation_time_s=5.0)
    b = EstimateModel(seed=4, horizontal_std_m=0.1, max_error_m=0.3, correlation_time_s=5.0)
    c = EstimateModel(seed=5, horizontal_std_m=0.1, max_error_m=0.3, correlation_time_s=5.0)
    errs = []
    for _ in range(20000):
        a.step(0.01)
        b.step(0.01)
        c.step(0.01)
        errs.append(a.error_ned_m)
    e = np.array(errs)
    assert a.error_ned_m == b.error_ned_m != c.error_ned_m
    assert np.abs(e).max() <= 0.3 + 1e-12
    assert 0.03 < e[:, 0].std() < 0.2  # a drift of cm to dm, not a constant
    assert np.abs(np.diff(e[:, 0])).max() < 0.01  # slow: no jumps between steps


def test_gps_loss_makes_the_estimate_run_away_then_reset() -> None:
    m = EstimateModel(seed=2, gps_loss_drift_mps=0.5)
    m.set_gps(False)
    for _ in range(1000):
        m.step(0.01)
    assert math.hypot(*m.error_ned_m[:2]) > 3.0
    m.set_gps(True)
    assert math.hypot(*m.error_ned_m[:2]) <= m.max_error_m * math.sqrt(2) + 1e-9


def test_stopping_point() -> None:
    assert stopping_point((0.0, 0.0, 0.0), (2.0, -2.0, 0.0), 2.0) == (1.0, -1.0, 0.0)


def test_unpowered_in_air_falls() -> None:
    dyn = _airborne()
    dyn.set_motors(False)
    dyn.step(3.0)
    assert dyn.on_ground
