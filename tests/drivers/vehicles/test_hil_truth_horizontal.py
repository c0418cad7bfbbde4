"""The MAVSDK driver's ``ground_truth_horizontal``: where the true horizontal position comes from.

jMAVSim fills HIL_STATE_QUATERNION's ``lat``/``lon`` from its simulated GPS (SimpleSensors:
a random walk added to the true position at every 4 ms step, ``w += 10 sqrt(dt) N(0,1) dt -
w / 30``: about 1 cm per axis, correlated over about 0.1 s), its velocity from the true state
truncated to cm/s; PX4 SIH sends the true ``lat``/``lon`` (recorded,
``../shared/data/px4_sitl_tlogs``). ``velocity`` integrates the velocity and holds it to
``lat``/``lon`` (:class:`AnchoredHorizontal`).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from eaglemission.drivers.vehicles.mavsdk.hil_truth import (
    AnchoredHorizontal,
    HilTruth,
    untruncated_mps,
)

try:  # tests/ is not a package
    from emulator_support import scenario
except ImportError:  # pragma: no cover
    from .emulator_support import scenario  # type: ignore[no-redef]

LAT0_DEG, LON0_DEG = 47.397742, 8.545594  # jMAVSim's and SIH's default home
M_PER_DEG_LAT = 111_195.0


def _feed(truth: HilTruth, samples: list[tuple[int, dict[str, Any]]]) -> None:
    for stamp_ns, fields in samples:
        truth.on_message(stamp_ns, json.dumps(fields))


def _jmavsim_like_flight(seed: int) -> tuple[np.ndarray, list[tuple[int, dict[str, Any]]]]:
    """60 s at 250 Hz: 10 m north at up to 1.3 m/s and a slow wander of 5-8 cm; every 5th step sent
    at 50 Hz as jMAVSim fills the message. Returns (true north/east per sent sample, samples)."""
    rng = np.random.default_rng(seed)
    dt = 0.004
    t = np.arange(0.0, 60.0, dt)
    ramp = np.clip((t - 10.0) / 12.0, 0.0, 1.0)
    north = 10.0 * (3 * ramp**2 - 2 * ramp**3) + 0.08 * np.sin(0.9 * t)
    east = 0.05 * np.sin(0.6 * t)
    vel = np.gradient(np.stack([north, east], axis=1), dt, axis=0)
    walk = np.zeros(2)
    out_true, samples = [], []
    m_per_deg_lon = M_PER_DEG_LAT * math.cos(math.radians(LAT0_DEG))
    for k in range(len(t)):
        walk += 10.0 * math.sqrt(dt) * rng.standard_normal(2) * dt - walk / 30.0
        if k % 5:
            continue
        gps = np.array([north[k], east[k]]) + walk
        lat = int((LAT0_DEG + gps[0] / M_PER_DEG_LAT) * 1e7)
        lon = int((LON0_DEG + gps[1] / m_per_deg_lon) * 1e7)
        samples.append((int(t[k] * 1e9), {
            "lat": lat, "lon": lon, "alt": -5000, "vx": int(vel[k, 0] * 100),
            "vy": int(vel[k, 1] * 100), "vz": 0, "attitude_quaternion": [1.0, 0.0, 0.0, 0.0]}))
        out_true.append((north[k], east[k]))
    return np.asarray(out_true), samples


def _positions(truth: HilTruth) -> np.ndarray:
    return np.array([s.position_ned_m[:2] for s in truth.trajectory()])


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_velocity_takes_out_jmavsim_gps_noise_on_a_known_path(seed: int) -> None:
    true_ne, samples = _jmavsim_like_flight(seed)
    latlon = HilTruth(altitude="ned_z", horizontal="latlon")
    velocity = HilTruth(altitude="ned_z", horizontal="velocity")
    _feed(latlon, samples)
    _feed(velocity, samples)
    # both are measured from the first sample, whose GPS noise offsets them alike: that
    # offset is the mean of lat/lon's error (the noise averages out over 60 s)
    truth_ne = true_ne - true_ne[0]
    offset = np.mean(_positions(latlon) - truth_ne, axis=0)
    raw = np.hypot(*(_positions(latlon) - truth_ne - offset).T)
    ours = np.hypot(*(_positions(velocity) - truth_ne - offset).T)[250:]  # the anchor settled
    raw_rms, ours_rms = math.sqrt(np.mean(raw**2)), math.sqrt(np.mean(ours**2))
    assert 0.008 < raw_rms < 0.02, raw_rms  # jMAVSim's ~1 cm per axis
    assert ours_rms < 0.5 * raw_rms, (ours_rms, raw_rms)
    assert np.percentile(ours, 99) < 0.5 * np.percentile(raw, 99)


def test_recorded_sih_flight_velocity_agrees_with_its_exact_latlon(px4_tlogs: Path) -> None:
    """On SIH's own messages (true lat/lon, velocity cast to cm/s by PX4, stamped on receipt)
    through a flight 10 m north at up to 4.5 m/s: the integrated velocity stays on the true
    position, within millimetres once the vehicle has been slow (< 0.5 m/s) for 3 s, within
    centimetres at speed (receipt stamps against PX4's sample times)."""
    px4_msgs, _, _ = scenario(px4_tlogs, "f1")
    samples = [(int(t * 1e9), {k: v for k, v in m.to_dict().items() if k != "mavpackettype"})
               for t, m in px4_msgs if m.get_type() == "HIL_STATE_QUATERNION"]
    assert len(samples) > 1000
    exact, ours = HilTruth(horizontal="latlon"), HilTruth(horizontal="velocity")
    _feed(exact, samples)
    _feed(ours, samples)
    a, b = _positions(exact), _positions(ours)
    assert np.ptp(a[:, 0]) > 9.0  # it flew
    gap = np.hypot(*(a - b).T)
    traj = exact.trajectory()
    t_s = np.array([s.timestamp_ns for s in traj]) * 1e-9
    fast_t = t_s[np.hypot(*np.array([s.velocity_ned_mps[:2] for s in traj]).T) >= 0.5]
    settled = np.array([not np.any((fast_t <= t) & (fast_t > t - 3.0)) for t in t_s])
    assert settled.sum() > 1000
    settled_rms = math.sqrt(np.mean(gap[settled] ** 2))  # measured: 0.32 cm, max 0.94 cm
    assert settled_rms < 0.005 and gap[settled].max() < 0.015, (settled_rms, gap[settled].max())
    assert gap.max() < 0.04, gap.max()  # measured: 2.7 cm at 4.5 m/s


def test_a_truncated_reading_stands_for_half_a_step_more() -> None:
    assert untruncated_mps(0.0) == 0.0
    assert untruncated_mps(1.51) == pytest.approx(1.515)
    assert untruncated_mps(-0.02) == pytest.approx(-0.025)


def test_a_gap_restarts_the_integration_at_latlon() -> None:
    f = AnchoredHorizontal(anchor_s=1.0)
    assert f.update(0.0, 1.0, 2.0, 0.0, 0.0) == (1.0, 2.0)
    n, _ = f.update(0.02, 1.5, 2.0, 0.0, 0.0)  # held: moves 2 % of the way
    assert n == pytest.approx(1.0 + 0.5 * 0.02 / 1.02)
    assert f.update(2.0, 5.0, 6.0, 0.0, 0.0) == (5.0, 6.0)  # 2 s without a sample


def test_an_unknown_horizontal_source_is_refused() -> None:
    with pytest.raises(ValueError, match="latlon, velocity"):
        HilTruth(horizontal="gps")
    with pytest.raises(ValueError, match="anchor_s"):
        AnchoredHorizontal(anchor_s=0.0)
