"""TelemetryHistory: pose at a frame's mid-exposure time."""

from __future__ import annotations

import math
import threading

import numpy as np
import pytest

from eaglemission.geometry import (
    CameraModel,
    CameraMount,
    camera_pose_ned,
    euler_to_quat,
    euler_to_R,
    intersect_ray_with_horizontal_plane,
    quat_to_R,
)
from eaglemission.telemetry.history import TelemetryHistory, interpolate_states
from eaglemission.types import VehicleState

MS = 1_000_000


def _state(t_ms: float, yaw_deg: float, north_m: float = 0.0, vn: float = 0.0,
           down_m: float = -5.0) -> VehicleState:
    return VehicleState(timestamp_ns=int(t_ms * MS), position_ned_m=(north_m, 0.0, down_m),
                        velocity_ned_mps=(vn, 0.0, 0.0), attitude_q=euler_to_quat(0, 0, yaw_deg))


def _yaw(state: VehicleState) -> float:
    R = quat_to_R(state.attitude_q)
    return math.degrees(math.atan2(R[1, 0], R[0, 0]))


def test_30ms_skew_at_60_deg_per_s():
    """Yawing at 60 deg/s, a frame stamped 30 ms before the newest sample
    must get the attitude of its own time (1.8 deg off otherwise, ~0.16 m at 5 m)."""
    hist = TelemetryHistory()
    for k in range(11):  # 100 Hz telemetry, 60 deg/s yaw
        hist.append(_state(10 * k, 0.6 * k, down_m=-5.0 * math.tan(math.radians(30))))
    frame_t = 100 * MS - 30 * MS
    at = hist.state_at(frame_t)
    assert _yaw(at) == pytest.approx(60 * 0.070, abs=1e-9)
    stale = hist.latest()
    err_deg = _yaw(stale) - _yaw(at)
    assert err_deg == pytest.approx(1.8, abs=1e-9)
    # Ground target 5 m ahead (horizontally): the pixel it appears at, back-projected with the
    # stale attitude, lands 5 m x 1.8 deg = 0.157 m away.
    model = CameraModel.from_lens("narrow", focal_length_mm=12.0, mount=CameraMount(0, -30, 0))
    target = np.array([5.0 * math.cos(math.radians(4.2)), 5.0 * math.sin(math.radians(4.2)), 0.0])
    good = camera_pose_ned(model, at.position_ned_m, at.attitude_q)
    bad = camera_pose_ned(model, stale.position_ned_m, stale.attitude_q)
    px = model.project(good.inverse().apply(target[None, :]))
    assert model.in_image(px).all()
    ray = bad.R @ model.rays_optical(px)[0]
    hit = intersect_ray_with_horizontal_plane(bad.t, ray, 0.0)
    miss_m = float(np.linalg.norm(hit - target))
    assert miss_m == pytest.approx(5.0 * math.radians(1.8), rel=0.01)


def test_interpolation_between_samples():
    a = _state(0, 0, north_m=0.0, vn=1.0)
    b = _state(100, 10, north_m=1.0, vn=3.0)
    s = interpolate_states(a, b, 25 * MS)
    assert s.position_ned_m[0] == pytest.approx(0.25)
    assert s.velocity_ned_mps[0] == pytest.approx(1.5)
    assert _yaw(s) == pytest.approx(2.5, abs=1e-9)
    assert s.timestamp_ns == 25 * MS


def test_out_of_range_and_extrapolation():
    hist = TelemetryHistory(span_s=1.0, max_extrapolation_s=0.05)
    assert hist.state_at(0) is None
    hist.append(_state(100, 0, north_m=0.0, vn=2.0))
    hist.append(_state(200, 0, north_m=0.2, vn=2.0))
    assert hist.state_at(50 * MS) is None  # before the buffer
    ext = hist.state_at(240 * MS)
    assert ext.position_ned_m[0] == pytest.approx(0.28)
    assert hist.state_at(260 * MS) is None  # too far ahead: no guessed pose


def test_extrapolation_uses_body_rates():
    """Beyond the newest sample, attitude follows the reported body rates (a 30 ms lag at
    60 deg/s is 1.8 deg); with no rates reported it stays put."""
    hist = TelemetryHistory(max_extrapolation_s=0.05)
    rate = math.radians(60.0)
    for k in range(3):
        s = _state(10 * k, 0.6 * k)
        hist.append(VehicleState(s.timestamp_ns, s.position_ned_m, s.velocity_ned_mps,
                                 s.attitude_q, angular_velocity_frd_radps=(0.0, 0.0, rate)))
    ext = hist.state_at(50 * MS)
    assert _yaw(ext) == pytest.approx(1.2 + 1.8, abs=1e-9)
    # Body rates are in FRD: pitched 20 deg up, a body yaw rate is not a pure NED yaw rate.
    q0 = euler_to_quat(0.0, 20.0, 0.0)
    from eaglemission.telemetry.history import rotate_by_body_rates

    q1 = rotate_by_body_rates(q0, (0.0, 0.0, rate), 0.03)
    R_rel = quat_to_R(q0).T @ quat_to_R(q1)
    np.testing.assert_allclose(R_rel, euler_to_R(0, 0, 1.8), atol=1e-12)
    plain = TelemetryHistory()
    plain.append(_state(0, 10.0))
    assert _yaw(plain.state_at(40 * MS)) == pytest.approx(10.0)


def test_span_and_monotonic():
    hist = TelemetryHistory(span_s=0.5)
    for k in range(100):
        hist.append(_state(10 * k, 0))
    assert len(hist) == 51  # samples within 0.5 s of the newest (inclusive)
    hist.append(_state(500, 0))  # out of order: ignored
    assert hist.latest().timestamp_ns == 990 * MS
    with pytest.raises(ValueError):
        TelemetryHistory(span_s=0)


def test_thread_safe_appends_and_reads():
    hist = TelemetryHistory(span_s=10.0)
    errors = []

    def writer():
        for k in range(2000):
            hist.append(_state(k, 0.01 * k))

    def reader():
        for _ in range(500):
            try:
                latest = hist.latest()
                if latest is not None:
                    hist.state_at(latest.timestamp_ns)
            except Exception as exc:  # pragma: no cover - the failure we look for
                errors.append(exc)

    threads = [threading.Thread(target=writer), threading.Thread(target=reader)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=10)
    assert not errors and len(hist) == 2000
