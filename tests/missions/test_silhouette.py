"""The top-plane fit of a detection (top face or box silhouette, cut by the border) and the
close-range colour region (missions/silhouette.py)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from eaglemission.missions.silhouette import (
    box_points_ned,
    clip_to_image,
    colour_blob,
    fit_on_top_plane,
    mbr,
)

from eaglemission.geometry import camera_pose_ned, euler_to_quat


def _detection_corners(model, cam, top, yaw_deg, target, region):
    """What an ideal detector reports: the MBR of the visible (image-clipped) region."""
    px = model.project(cam.inverse().apply(box_points_ned(
        top, yaw_deg, target.length_m, target.width_m, target.height_m, region)))
    seen = clip_to_image(px, model.width_px, model.height_px)
    rect = cv2.minAreaRect(seen.astype(np.float32))
    return np.asarray(rect[0]), cv2.boxPoints(rect).astype(np.float64)


@pytest.mark.parametrize("region", ["top", "box"])
def test_fit_recovers_the_top_centre_of_either_region(sitl_config, region) -> None:
    rng = np.random.RandomState(7)
    model = sitl_config.cameras.wide.to_model("wide")
    target = sitl_config.target
    errors_fit, errors_mid = [], []
    for _ in range(12):
        top = np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), -target.height_m])
        yaw = rng.uniform(0, 180)
        back, up = rng.uniform(1.0, 3.0), rng.uniform(0.8, 2.0)
        q = euler_to_quat(0.0, 0.0, rng.uniform(-10, 10))
        veh = (top[0] - back, top[1], top[2] - up)
        cam = camera_pose_ned(model, veh, q)
        centre, corners = _detection_corners(model, cam, top, yaw, target, region)
        fit = fit_on_top_plane(model, cam, centre, corners, target)
        assert fit is not None
        errors_fit.append(math.dist(fit.position_ned_m[:2], top[:2]))
        # the fixed mid-height plane (bearing default) for comparison
        ray = cam.R @ model.rays_optical(centre[None, :])[0]
        hit = cam.t + ray * ((-target.height_m / 2 - cam.t[2]) / ray[2])
        errors_mid.append(math.dist(hit[:2], top[:2]))
    assert np.median(errors_fit) < 0.01
    assert max(errors_fit) < 0.03
    assert np.median(errors_fit) < np.median(errors_mid)


def test_fit_of_a_view_cut_by_the_border_uses_the_heading_hint(sitl_config) -> None:
    model = sitl_config.cameras.wide.to_model("wide")
    target = sitl_config.target
    top = np.array([0.0, 0.0, -target.height_m])
    yaw = 35.0
    # near the grasp pose: the tool point 0.175 m above the top, the near edge out of view
    veh = (top[0] - 0.45, top[1], top[2] - 0.175 - 0.35)
    cam = camera_pose_ned(model, veh, euler_to_quat(0.0, 0.0, 0.0))
    px = model.project(cam.inverse().apply(box_points_ned(
        top, yaw, target.length_m, target.width_m, target.height_m, "box")))
    assert (px[:, 1] > model.height_px).any()  # really cut
    centre, corners = _detection_corners(model, cam, top, yaw, target, "box")
    fit = fit_on_top_plane(model, cam, centre, corners, target, yaw_hint_deg=30.0,
                           region_hint="box", iterations=8)
    assert fit is not None
    assert math.dist(fit.position_ned_m[:2], top[:2]) < 0.02
    assert fit.size_ratio == pytest.approx(1.0, abs=0.05)


def test_mbr_and_clip() -> None:
    c, dims, long_deg = mbr(np.array([[0, 0], [40, 0], [40, 10], [0, 10]], dtype=float))
    assert np.allclose(c, [20, 5]) and np.allclose(dims, [10, 40])
    assert min(long_deg, 180 - long_deg) < 1e-6
    seen = clip_to_image(np.array([[50, 50], [150, 50], [150, 150], [50, 150]], float), 100, 100)
    assert seen is not None and seen[:, 0].max() <= 99 and seen[:, 1].max() <= 99
    assert clip_to_image(np.array([[200, 200], [300, 200], [250, 300]], float), 100, 100) is None


def test_colour_blob_finds_the_target_colour_near_the_prediction() -> None:
    rng = np.random.RandomState(3)
    img = np.clip(rng.normal((60, 120, 70), 12, (480, 640, 3)), 0, 255).astype(np.uint8)
    red = (30, 40, 210)
    cv2.fillPoly(img, [np.array([[300, 200], [420, 230], [400, 300], [280, 270]])], red)
    cv2.fillPoly(img, [np.array([[30, 30], [80, 30], [80, 60], [30, 60]])],
                 (15, 20, 105))  # same chromaticity, darker, far from the prediction
    det = colour_blob(img, red, 0.25, (350, 250))
    assert det is not None
    assert math.dist(det.center_px, (350, 250)) < 8
    assert det.area_px == pytest.approx(cv2.contourArea(np.array(
        [[300, 200], [420, 230], [400, 300], [280, 270]], np.float32)), rel=0.15)
    assert colour_blob(img, (200, 40, 30), 0.25, (350, 250)) is None  # no blue region


def test_grasp_stability_needs_a_slow_settled_vehicle() -> None:
    """Passing through the grasp band, or hovering just outside it, never counts; a jittery
    hover inside it does (the runner's rule, exercised on a bare object)."""
    from collections import deque
    from types import SimpleNamespace

    from eaglemission.missions.approach import ApproachConfig
    from eaglemission.missions.runner import MissionRunner

    fake = SimpleNamespace(p=ApproachConfig(), m=SimpleNamespace(
        grasp_tolerance_m=0.025, grasp_distance_m=0.175, grasp_stable_frames=5),
        _fine_phase="descend", _grasp_window=deque(maxlen=64))

    def count(samples, slow=True):
        fake._grasp_window.clear()
        n = 0
        for h, d in samples:
            n = MissionRunner._grasp_stability(fake, h, d, slow)
        return n

    # frames up to 1.6 x the tolerance off, the running mean within half of it
    jitter = [(0.03, 0.17), (0.005, 0.18), (0.01, 0.17), (0.012, 0.175), (0.004, 0.18)]
    assert count(jitter) >= 5
    # every frame inside the tolerance, but the mean leaves no margin for the estimate's error
    assert count([(0.02, 0.175)] * 6) < 5
    assert count([(0.005, 0.194)] * 6) < 5
    assert count(jitter, slow=False) == 0  # still moving
    descending = [(0.01, d) for d in (0.21, 0.19, 0.175, 0.16, 0.14)]
    assert count(descending) < 5  # mean inside, the latest frame already below the band
    outside = [(0.03, 0.17)] * 6
    assert count(outside) < 5  # every frame near, the mean outside
    fake._fine_phase = "standoff"
    assert count(jitter) == 0
