"""The top-plane fit of a target partly hidden by something nearer (the arm's tool at the
grasp): estimators/top_plane.py, ``occluder_px``."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from eaglemission.estimators._occlusion_kernel import visible_points
from eaglemission.estimators.top_plane import (
    box_points_ned,
    clip_to_image,
    fit_on_top_plane,
    fit_on_top_plane_reference,
    rect_fields,
    visible_mbr,
    visible_points_numpy,
)

from eaglemission.geometry import camera_pose_ned, euler_to_quat

SQUARE = np.array([[0, 0], [100, 0], [100, 100], [0, 100]], dtype=np.float32)


def test_what_the_occluder_leaves_is_measured() -> None:
    strip = np.array([[-10, -10], [110, -10], [110, 30], [-10, 30]], dtype=np.float32)
    centre, dims, _ = rect_fields(visible_mbr(SQUARE, strip))
    assert centre == pytest.approx((50, 65), abs=1.5)
    assert dims == pytest.approx((70, 100), abs=2.5)


def test_an_occluder_elsewhere_changes_nothing_and_one_over_all_leaves_nothing() -> None:
    aside = np.array([[200, 0], [300, 0], [300, 100]], dtype=np.float32)
    assert visible_mbr(SQUARE, aside) == cv2.minAreaRect(SQUARE)
    over = np.array([[-5, -5], [105, -5], [105, 105], [-5, 105]], dtype=np.float32)
    assert visible_mbr(SQUARE, over) is None


def _grasp_view(sitl_config, yaw_deg: float):
    """The wide camera near the grasp pose (the target cut by the bottom border) and a tool
    in front of the target's far corner."""
    model = sitl_config.cameras.wide.to_model("wide")
    target = sitl_config.target
    top = np.array([0.0, 0.0, -target.height_m])
    veh = (top[0] - 0.45, top[1], top[2] - 0.175 - 0.35)
    cam = camera_pose_ned(model, veh, euler_to_quat(0.0, 0.0, 0.0))
    px = model.project(cam.inverse().apply(box_points_ned(
        top, yaw_deg, target.length_m, target.width_m, target.height_m, "box")))
    seen = clip_to_image(px, model.width_px, model.height_px).astype(np.float32)
    far = px[np.argmin(px[:, 1])]  # the far corner: highest in the image
    u, v = float(far[0]), float(far[1])
    tool = np.array([[u - 45, v - 60], [u + 45, v - 60], [u + 45, v + 50], [u - 45, v + 50]],
                    dtype=np.float32)
    return model, cam, top, target, seen, tool


@pytest.mark.parametrize("yaw_deg", [35.0, 60.0, 120.0, 150.0])
def test_the_fit_leaves_out_what_the_tool_hides(sitl_config, yaw_deg) -> None:
    """Measured on the simulated gusts campaign's misses: the gripper over the far corner
    shortens the detection, and a model that does not know it puts the target nearer."""
    model, cam, top, target, seen, tool = _grasp_view(sitl_config, yaw_deg)
    rect = visible_mbr(seen, tool)
    assert rect is not None and rect != cv2.minAreaRect(seen)  # the tool really hides some
    centre, corners = np.asarray(rect[0]), cv2.boxPoints(rect).astype(np.float64)
    kwargs = {"yaw_hint_deg": yaw_deg + 5.0, "region_hint": "box", "iterations": 8}
    blind = fit_on_top_plane(model, cam, centre, corners, target, **kwargs)
    aware = fit_on_top_plane(model, cam, centre, corners, target, occluder_px=tool, **kwargs)
    assert blind is not None and aware is not None
    err_blind = math.dist(blind.position_ned_m[:2], top[:2])
    err_aware = math.dist(aware.position_ned_m[:2], top[:2])
    assert err_aware < 0.005
    assert err_blind > 0.01
    ref = fit_on_top_plane_reference(model, cam, centre, corners, target, occluder_px=tool,
                                     **kwargs)
    assert ref is not None and ref.region == aware.region
    assert np.allclose(ref.position_ned_m, aware.position_ned_m, rtol=0.0, atol=1e-6)
    assert ref.cost == pytest.approx(aware.cost, abs=1e-9)


def test_the_compiled_corners_equal_the_reference() -> None:
    rng = np.random.RandomState(5)
    for _ in range(300):
        region = cv2.convexHull(rng.uniform(0, 200, (rng.randint(3, 9), 2)).astype(np.float32))
        occ = cv2.convexHull(rng.uniform(50, 250, (rng.randint(3, 9), 2)).astype(np.float32))
        a = np.asarray(region, np.float64).reshape(-1, 2)
        b = np.asarray(occ, np.float64).reshape(-1, 2)
        ref, fast = visible_points_numpy(a, b), visible_points(a, b)
        assert ref.shape == fast.shape
        assert np.allclose(np.sort(ref, axis=0), np.sort(fast, axis=0), atol=1e-9)
