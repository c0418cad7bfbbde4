from __future__ import annotations

import math

import numpy as np
import pytest
from eaglemission.missions.filter import FilterConfig, TargetFilter


def test_converges_and_missed_frames_only_grow_uncertainty() -> None:
    rng = np.random.RandomState(7)
    f = TargetFilter(FilterConfig(process_noise_mps=0.02))
    truth = np.array([20.0, 1.5, -0.15])
    t = 1_000_000_000
    for _ in range(50):
        t += 100_000_000
        assert f.update(tuple(truth + rng.normal(0, 0.1, 3)), 0.1, t)
    s = f.state(t)
    assert s is not None and np.linalg.norm(np.array(s.position_ned_m) - truth) < 0.05
    later = f.state(t + 2_000_000_000)  # 2 s without measurements
    assert later.age_s == 2.0 and later.position_ned_m == s.position_ned_m
    assert all(a > b for a, b in zip(later.std_m, s.std_m))


def test_outlier_gated_and_consistent_outliers_reset() -> None:
    f = TargetFilter(FilterConfig(reset_after_rejections=3))
    t = 1_000_000_000
    for _ in range(10):
        t += 100_000_000
        f.update((10.0, 0.0, 0.0), 0.05, t)
    assert not f.update((15.0, 0.0, 0.0), 0.05, t + 1)  # isolated jump: rejected
    assert f.state(t).position_ned_m == (10.0, 0.0, 0.0)
    t += 100_000_000
    assert not f.update((15.0, 0.0, 0.0), 0.05, t, allow_reset=False)
    assert not f.update((15.0, 0.0, 0.0), 0.05, t + 1, allow_reset=False)
    assert f.state(t).position_ned_m[0] == 10.0  # never reset in the final approach
    assert f.update((15.0, 0.0, 0.0), 0.05, t + 2)  # third consistent one: restart there
    assert abs(f.state(t).position_ned_m[0] - 15.0) < 1e-9


def test_empty_filter_and_bad_input() -> None:
    f = TargetFilter()
    assert f.state(0) is None and not f.initialised
    import pytest

    with pytest.raises(ValueError):
        f.update((1.0, float("nan"), 0.0), 0.1, 0)


def test_plane_offset_filter_tracks_a_drifting_plane_and_gates_outliers() -> None:
    from eaglemission.missions.filter import PlaneOffsetFilter

    rng = np.random.RandomState(11)
    f = PlaneOffsetFilter(prior_std_m=0.04, process_noise_mps=0.01)
    assert f.offset_m == 0.0 and f.std_m() == pytest.approx(0.04)
    truth = 0.09  # the altitude estimate is 9 cm off
    t_ns = 0
    for _ in range(200):  # 20 Hz rangefinder-like readings for 10 s
        t_ns += 50_000_000
        assert f.update(truth + rng.normal(0, 0.01), 0.01, t_ns)
    assert f.offset_m == pytest.approx(truth, abs=0.005)
    settled = f.std_m(t_ns)
    assert settled < 0.005
    # the uncertainty grows while no reading arrives (random walk)
    assert f.std_m(t_ns + 10_000_000_000) == pytest.approx(math.hypot(settled, 0.01 * 10**0.5))
    # a reading of the target's top (15 cm above the ground) is an outlier: gated out
    assert not f.update(truth - 0.15, 0.01, t_ns + 50_000_000)
    assert f.offset_m == pytest.approx(truth, abs=0.005)
    # the plane drifts: followed
    for _ in range(200):
        t_ns += 50_000_000
        truth += 0.0002
        f.update(truth + rng.normal(0, 0.01), 0.01, t_ns)
    assert f.offset_m == pytest.approx(truth, abs=0.01)
    with pytest.raises(ValueError, match="offset_m"):
        f.update(math.nan, 0.01, t_ns)
    with pytest.raises(ValueError, match="prior_std_m"):
        PlaneOffsetFilter(prior_std_m=0.0, process_noise_mps=0.01)
