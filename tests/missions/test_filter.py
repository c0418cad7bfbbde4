from __future__ import annotations

import numpy as np
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
