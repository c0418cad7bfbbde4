"""The target state: the position and plane filters, and the pure functions (vertical
reference, confirmation, size range, grasp stability)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from eaglemission.missions.target_state import FilterConfig, TargetFilter


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
    from eaglemission.missions.target_state import PlaneOffsetFilter

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


# -- pure functions of the target state -------------------------------------------------------
def _count(samples, slow=True, **kw):
    from eaglemission.missions.target_state import grasp_progress

    args = dict(grasp_distance_m=0.175, tolerance_m=0.025, hold_factor=1.6, accept_fraction=0.5,
                required=5)
    args.update(kw)
    win, n = [], 0
    for h, d in samples:
        win, n = grasp_progress(win, h, d, slow=slow, **args)
    return n


def test_grasp_stability_needs_a_slow_settled_vehicle() -> None:
    """Passing through the grasp band, or hovering just outside it, never counts; a jittery
    hover inside it does."""
    # frames up to 1.6 x the tolerance off, the running mean within half of it
    jitter = [(0.03, 0.17), (0.005, 0.18), (0.01, 0.17), (0.012, 0.175), (0.004, 0.18)]
    assert _count(jitter) >= 5
    # every frame inside the tolerance, but the mean leaves no margin for the estimate's error
    assert _count([(0.02, 0.175)] * 6) < 5
    assert _count([(0.005, 0.194)] * 6) < 5
    assert _count(jitter, slow=False) == 0  # still moving
    descending = [(0.01, d) for d in (0.21, 0.19, 0.175, 0.16, 0.14)]
    assert _count(descending) < 5  # mean inside, the latest frame already below the band
    assert _count([(0.03, 0.17)] * 6) < 5  # every frame near, the mean outside
    # one frame out of the band resets the run
    assert _count([*jitter, (0.2, 0.175), *jitter[:3]]) == 3


def test_vertical_reference_keeps_the_direction_and_takes_the_range_from_the_plane() -> None:
    from eaglemission.missions.target_state import vertical_reference

    cam = (0.0, 0.0, -5.0)
    p = (4.0, 2.0, -0.5)  # a PnP estimate 0.35 m above the plane at -0.15
    hit = vertical_reference(p, cam, -0.15, "ground")
    # same direction from the camera, on the plane
    d_est = np.subtract(p, cam)
    d_hit = np.subtract(hit, cam)
    assert hit[2] == -0.15
    assert np.allclose(np.cross(d_est, d_hit), 0.0, atol=1e-9)
    assert vertical_reference(p, cam, -0.15, "estimate") == p
    close = (0.5, 0.2, -4.0)  # within full_3d_range_m of the camera: hybrid keeps 3-D
    assert vertical_reference(close, cam, -0.15, "hybrid", full_3d=True) == close
    assert vertical_reference(close, cam, -0.15, "hybrid", full_3d=False)[2] == -0.15
    assert vertical_reference(p, None, -0.15, "ground") == (4.0, 2.0, -0.15)


def test_confirmation_needs_agreeing_consecutive_frames() -> None:
    from eaglemission.missions.target_state import confirmation

    h: list = []
    for p in [(10.0, 0.0, 0.0), (10.5, 0.2, 0.0), (10.2, -0.1, 0.0)]:
        h = confirmation(h, p, radius_m=3.0)
    assert len(h) == 3
    assert confirmation(h, None, radius_m=3.0) == []
    assert confirmation(h, (20.0, 0.0, 0.0), radius_m=3.0) == [(20.0, 0.0, 0.0)]
    assert confirmation(h, (10.0, 0.0, 0.0), radius_m=3.0, accept=False) == h


def test_size_range_scale_weights_the_two_ranges() -> None:
    from eaglemission.missions.target_state import size_range_scale

    # a perfect plane: keep the plane's range; an unknown plane: take the size's range
    assert size_range_scale(1.25, 1e-9, 0.7, 2.0, 0.02) == pytest.approx(1.0)
    assert size_range_scale(1.25, 1e3, 0.7, 2.0, 0.02) == pytest.approx(0.8, rel=1e-6)
