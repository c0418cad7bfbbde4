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
    colour_mask_numpy,
    fit_on_top_plane,
    fit_on_top_plane_reference,
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


def _random_fit_case(rng, models, target):
    """A camera pose, a detection (MBR of the top face or the silhouette, perturbed, sometimes
    cut by the border or unrelated to the target) and the fit's keyword arguments."""
    model = models[rng.randint(len(models))]
    top = np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), -target.height_m])
    yaw = rng.uniform(0, 180)
    back, up = rng.uniform(0.3, 12.0), rng.uniform(0.3, 6.0)
    q = euler_to_quat(rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-25, 25))
    cam = camera_pose_ned(model, (top[0] - back, top[1] + rng.uniform(-1, 1), top[2] - up), q)
    px = model.project(cam.inverse().apply(box_points_ned(
        top, yaw, target.length_m, target.width_m, target.height_m,
        "top" if rng.rand() < 0.5 else "box")))
    if rng.rand() < 0.1 or not np.isfinite(px).all():
        px = rng.uniform(-200, 1500, (4, 2))  # a blob that is not the target
    rect = cv2.minAreaRect(px.astype(np.float32))
    scale = rng.uniform(0.8, 1.25, 2)
    rect = ((rect[0][0] + rng.normal(0, 3), rect[0][1] + rng.normal(0, 3)),
            (rect[1][0] * scale[0], rect[1][1] * scale[1]), rect[2] + rng.normal(0, 5))
    kwargs = {"iterations": int(rng.choice([3, 4, 8]))}
    if rng.rand() < 0.3:
        kwargs["yaw_hint_deg"] = float(yaw + rng.normal(0, 10))
    if rng.rand() < 0.3:
        kwargs["region_hint"] = "top" if rng.rand() < 0.5 else "box"
    if rng.rand() < 0.2:
        kwargs["yaw_step_deg"] = float(rng.choice([10.0, 22.5]))
    return model, cam, np.asarray(rect[0]), cv2.boxPoints(rect).astype(np.float64), kwargs


def test_batched_fit_equals_the_reference(sitl_config) -> None:
    """The batched fit gives the one-hypothesis-at-a-time reference's fit (region, heading,
    position, cost, size ratio) on random views, detections and hints, with and without
    lens distortion."""
    rng = np.random.RandomState(20261122)
    target = sitl_config.target
    wide = sitl_config.cameras.wide.to_model("wide")
    narrow = sitl_config.cameras.narrow.to_model("narrow")
    models = [wide, narrow, wide.with_(distortion=(-0.28, 0.09, 0.001, -0.0005, -0.012))]
    outcomes = {"none": 0, "top": 0, "box": 0}
    for _ in range(400):
        model, cam, centre, corners, kwargs = _random_fit_case(rng, models, target)
        fast = fit_on_top_plane(model, cam, centre, corners, target, **kwargs)
        ref = fit_on_top_plane_reference(model, cam, centre, corners, target, **kwargs)
        assert (fast is None) == (ref is None), kwargs
        outcomes["none" if ref is None else ref.region] += 1
        if ref is None:
            continue
        assert fast.region == ref.region and fast.yaw_deg == pytest.approx(ref.yaw_deg, abs=1e-9)
        assert np.allclose(fast.position_ned_m, ref.position_ned_m, rtol=0.0, atol=1e-6)
        assert fast.cost == pytest.approx(ref.cost, rel=0.0, abs=1e-9)
        assert fast.size_ratio == pytest.approx(ref.size_ratio, rel=0.0, abs=1e-9)
    assert min(outcomes.values()) >= 20, outcomes  # every outcome was exercised


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


def _colour_blob_reference(img, target_bgr, tolerance, near_px, min_area_px=200.0, step=2,
                           min_brightness=60.0):
    """The colour region's rectangle from ALL its pixels (colour_blob uses the boundary)."""
    t = np.asarray(target_bgr, dtype=np.float32)
    t = t / max(1.0, float(t.sum()))
    mask = colour_mask_numpy(img, step, t, tolerance, min_brightness)
    mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    n, labels, stats, cents = cv2.connectedComponentsWithStats(mask, connectivity=8)
    near = np.asarray(near_px, dtype=np.float64) / step
    ok = [i for i in range(1, n) if stats[i, cv2.CC_STAT_AREA] * step * step >= min_area_px]
    if not ok:
        return None
    best = min(ok, key=lambda i: float(np.hypot(*(cents[i] - near))))
    ys, xs = np.nonzero(labels == best)
    pts = (np.stack([xs, ys], axis=1).astype(np.float32) + 0.5) * step - 0.5
    return cv2.minAreaRect(pts), float(len(xs) * step * step)


def test_colour_blob_kernel_and_boundary_rectangle_equal_the_references() -> None:
    """The compiled mask equals the numpy one bit for bit, and the rectangle from the region's
    boundary pixels equals the one from all its pixels, on random scenes and parameters."""
    from eaglemission.missions._colour_kernel import colour_mask

    rng = np.random.RandomState(11)
    found = 0
    for _ in range(80):
        h, w = rng.randint(40, 320, 2)
        img = rng.randint(0, 256, (h, w, 3)).astype(np.uint8)
        for _ in range(rng.randint(1, 5)):
            poly = np.column_stack((rng.randint(0, w, 5), rng.randint(0, h, 5)))
            cv2.fillPoly(img, [poly], tuple(int(v) for v in rng.randint(0, 256, 3)))
        target = tuple(int(v) for v in rng.randint(0, 256, 3))
        if rng.rand() < 0.5:  # a region of (a shade of) the target's colour
            poly = np.column_stack((rng.randint(0, w, 4), rng.randint(0, h, 4)))
            k = rng.uniform(0.4, 1.0)
            cv2.fillPoly(img, [poly], tuple(int(v * k) for v in target))
        tol, step = float(rng.uniform(0.02, 0.4)), int(rng.choice([1, 2, 3]))
        t = np.asarray(target, np.float32)
        t = t / max(1.0, float(t.sum()))
        assert np.array_equal(colour_mask(img, step, t, np.float32(tol), np.float32(60.0)),
                              colour_mask_numpy(img, step, t, tol, 60.0))
        near = (float(rng.uniform(0, w)), float(rng.uniform(0, h)))
        det = colour_blob(img, target, tol, near, min_area_px=30.0, step=step)
        ref = _colour_blob_reference(img, target, tol, near, min_area_px=30.0, step=step)
        assert (det is None) == (ref is None)
        if ref is None:
            continue
        found += 1
        (cx, cy), (rw, rh), ang = ref[0]
        assert det.center_px == (cx, cy) and det.angle_deg == ang
        assert det.size_px == (max(rw, rh), min(rw, rh)) and det.area_px == ref[1]
        numpy_det = colour_blob(img, target, tol, near, min_area_px=30.0, step=step,
                                backend="numpy")
        assert np.array_equal(numpy_det.corners_px, det.corners_px)
    assert found >= 30


def test_components_in_the_mask_box_equal_the_full_frame_call() -> None:
    """Stats and centroids (bit for bit) and each component's pixels, against
    cv2.connectedComponentsWithStats on the whole mask."""
    from eaglemission.missions.silhouette import _components

    rng = np.random.RandomState(23)
    for _ in range(60):
        mask = np.zeros((rng.randint(20, 500), rng.randint(20, 700)), np.uint8)
        h, w = mask.shape
        for _ in range(rng.randint(0, 6)):
            poly = np.column_stack((rng.randint(0, w, 4), rng.randint(0, h, 4)))
            cv2.fillPoly(mask, [poly], 1)
        mask |= (rng.rand(h, w) < 0.002).astype(np.uint8)
        n, labels, (bx, by), stats, cents = _components(mask)
        n_ref, labels_ref, stats_ref, cents_ref = cv2.connectedComponentsWithStats(mask, connectivity=8)
        assert n == n_ref
        key = np.lexsort((stats[1:, 1], stats[1:, 0], stats[1:, 4]))
        key_ref = np.lexsort((stats_ref[1:, 1], stats_ref[1:, 0], stats_ref[1:, 4]))
        assert np.array_equal(stats[1:][key], stats_ref[1:][key_ref])
        assert np.array_equal(cents[1:][key], cents_ref[1:][key_ref])
        for i, j in zip(key[:5] + 1, key_ref[:5] + 1):
            full = np.zeros_like(mask, dtype=bool)
            full[by:by + labels.shape[0], bx:bx + labels.shape[1]] = labels == i
            assert np.array_equal(full, labels_ref == j)


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
