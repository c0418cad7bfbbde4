"""The top-plane fit of a detection (top face or box silhouette, cut by the border): plugin
``top_plane`` (estimators/top_plane.py)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from eaglemission.estimators.top_plane import (
    TopPlaneFitter,
    box_points_ned,
    clip_to_image,
    fit_on_top_plane,
    fit_on_top_plane_reference,
    mbr,
    polygon_iou,
    silhouette_iou,
)

from eaglemission import registry
from eaglemission.geometry import camera_pose_ned, euler_to_quat
from eaglemission.interfaces.estimator import CameraView
from eaglemission.types import Detection, VehicleState


def test_top_plane_is_the_registered_fitter() -> None:
    assert registry.get("fitters", "top_plane") is TopPlaneFitter


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


def _outline(model, cam, top, yaw_deg, length_m, width_m, height_m, region="box"):
    """The convex hull of a box's projection: what a perfect segmentation outlines."""
    px = model.project(cam.inverse().apply(box_points_ned(top, yaw_deg, length_m, width_m,
                                                          height_m, region)))
    return cv2.convexHull(px.astype(np.float32)).reshape(-1, 2).astype(np.float64)


@pytest.mark.parametrize("camera", ["wide", "narrow"])
def test_the_silhouette_tells_a_square_box_from_the_elongated_target(sitl_config, camera) -> None:
    """A 0.32 m square box, 0.20 m high, of the target's colour and top area (the distractor of
    tests/missions/test_candidate_rejection.py): the MBR fit explains it, its outline does not
    (perfect segmentations, fine-approach views)."""
    model = getattr(sitl_config.cameras, camera).to_model(camera)
    t = sitl_config.target
    rng = np.random.RandomState(521)
    target_iou, square_iou = [], []
    for _ in range(10):
        yaw = rng.uniform(0, 180)
        back, up = rng.uniform(0.8, 2.5), rng.uniform(0.6, 1.8)
        q = euler_to_quat(0.0, 0.0, rng.uniform(-10, 10))
        top = np.array([0.0, 0.0, -t.height_m])
        cam = camera_pose_ned(model, (-back, 0.0, top[2] - up), q)
        hull = _outline(model, cam, top, yaw, t.length_m, t.width_m, t.height_m)
        best = silhouette_iou(model, cam, hull, top[2], t)
        assert best is not None
        target_iou.append(best[0])
        assert min(abs(best[1] - yaw % 180), 180 - abs(best[1] - yaw % 180)) < 6.0
        sq_top = np.array([0.0, 0.0, -0.1996])
        hull = _outline(model, cam, sq_top, yaw, 0.324, 0.324, 0.1996)
        # the fit places the model's top on the target's plane: 5 cm below the square's top
        square = silhouette_iou(model, cam, hull, top[2], t)
        assert square is not None
        square_iou.append(square[0])
    assert min(target_iou) > 0.95, target_iou
    assert max(square_iou) < 0.86, square_iou


def test_the_top_face_alone_is_a_region_model_too(sitl_config) -> None:
    model = sitl_config.cameras.narrow.to_model("narrow")
    t = sitl_config.target
    top = np.array([0.0, 0.0, -t.height_m])
    cam = camera_pose_ned(model, (-1.5, 0.0, top[2] - 1.0), euler_to_quat(0, 0, 0))
    hull = _outline(model, cam, top, 50.0, t.length_m, t.width_m, t.height_m, region="top")
    best = silhouette_iou(model, cam, hull, top[2], t)
    assert best is not None and best[2] == "top" and best[0] > 0.97


def test_silhouette_iou_refuses_a_degenerate_outline(sitl_config) -> None:
    model = sitl_config.cameras.narrow.to_model("narrow")
    cam = camera_pose_ned(model, (-1.5, 0.0, -1.2), euler_to_quat(0, 0, 0))
    line = np.array([[10.0, 10.0], [20.0, 20.0], [30.0, 30.0]])
    assert silhouette_iou(model, cam, line, -0.15, sitl_config.target) is None
    nan = np.full((4, 2), np.nan)
    assert silhouette_iou(model, cam, nan, -0.15, sitl_config.target) is None


def test_polygon_iou() -> None:
    a = np.array([[0, 0], [10, 0], [10, 10], [0, 10]], np.float32)
    b = a + np.float32(5.0)
    assert polygon_iou(a, a) == pytest.approx(1.0)
    assert polygon_iou(a, b) == pytest.approx(25.0 / 175.0)


def _whole_view_at_30_deg(sitl_config):
    """The narrow camera 2.5 m behind and 1.5 m above the target (heading 30 deg), its whole
    outline as the detection: (fitter, detection, view)."""
    model = sitl_config.cameras.narrow.to_model("narrow")
    t = sitl_config.target
    top = np.array([0.0, 0.0, -t.height_m])
    state = VehicleState(timestamp_ns=1, position_ned_m=(-2.5, 0.0, top[2] - 1.5),
                         velocity_ned_mps=(0.0, 0.0, 0.0), attitude_q=euler_to_quat(0, 0, 0))
    view = CameraView(model, state, 1)
    hull = _outline(model, view.camera_pose_ned, top, 30.0, t.length_m, t.width_m, t.height_m)
    rect = cv2.minAreaRect(hull.astype(np.float32))
    det = Detection(1.0, rect[0], cv2.boxPoints(rect), (max(rect[1]), min(rect[1])), rect[2],
                    rect[1][0] * rect[1][1], hull_px=hull)
    fitter = TopPlaneFitter(target=t)
    return fitter, det, view


def test_the_fitter_measures_the_silhouette_of_whole_views_only_when_asked(sitl_config) -> None:
    fitter, det, view = _whole_view_at_30_deg(sitl_config)
    assert fitter.fit(det, view, plane_down_m=0.0).silhouette_iou is None
    whole = fitter.fit(det, view, plane_down_m=0.0, silhouette=True)
    assert whole is not None and whole.silhouette_iou is not None and whole.silhouette_iou > 0.95
    cut = fitter.fit(det, view, plane_down_m=0.0, silhouette=True, yaw_hint_deg=30.0)
    assert cut is not None and cut.silhouette_iou is None


def test_a_hinted_fit_turns_only_within_the_hints_span(sitl_config) -> None:
    """A hint 10 deg off the true heading: the fitter's own band (+-15 deg) reaches the true
    heading, a +-2 deg span keeps the fit's heading within 2 deg of the hint."""
    fitter, det, view = _whole_view_at_30_deg(sitl_config)
    free = fitter.fit(det, view, plane_down_m=0.0, yaw_hint_deg=40.0)
    narrow = fitter.fit(det, view, plane_down_m=0.0, yaw_hint_deg=40.0, yaw_hint_span_deg=2.0)
    assert free is not None and narrow is not None
    assert abs(free.yaw_deg % 180 - 30.0) < 1e-6
    assert abs(narrow.yaw_deg % 180 - 40.0) <= 2.0 + 1e-9
