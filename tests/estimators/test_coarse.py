"""Coarse estimators against the synthetic world: Eq. (16) as printed (``pixel_offset``) and
the metric ray/plane variant (``bearing``)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from eaglemission.estimators.bearing import BearingConfig, BearingEstimator, ground_point_from_pixel
from eaglemission.estimators.pixel_offset import (
    PixelOffsetConfig,
    PixelOffsetEstimator,
    eq16_offset,
    linear_fov_m,
)
from world_helpers import detection_from_polygon, view_at

from eaglemission import registry
from eaglemission.geometry import euler_to_quat
from eaglemission.types import Detection, EstimationFailed


def _det_at(u: float, v: float) -> Detection:
    c = np.array([[u - 5, v - 3], [u + 5, v - 3], [u + 5, v + 3], [u - 5, v + 3]])
    return Detection(1.0, (u, v), c, (10, 6), 0.0, 60.0, "wide")


def test_eq16_as_printed():
    # 100 px right of centre, square pixels, 2 m wide scene over 1280 px -> 0.15625 m.
    assert eq16_offset(100.0, 1.0, 2.0, 1280) == pytest.approx(0.15625)
    assert eq16_offset(-100.0, 1.0, 2.0, 1280) == pytest.approx(-0.15625)
    with pytest.raises(ValueError):
        eq16_offset(1.0, 1.0, 1.0, 0)
    # The linear FOV at depth Z makes Eq. (16) the pinhole offset Z * du / f.
    f_px, W, Z = 746.67, 1280, 7.0
    fov_deg = math.degrees(2 * math.atan(W / (2 * f_px)))
    assert eq16_offset(100.0, 1.0, linear_fov_m(fov_deg, Z), W) == pytest.approx(Z * 100 / f_px)


def _cases(mission, world, rs, n=10):
    wide = mission.cameras.wide.to_model("wide")
    tgt = np.array(world.target_position_ned_m)
    out = []
    while len(out) < n:
        # Cruise-like geometry: 3-6 m up, the target anywhere in the lower 2/3 of the image.
        alt = rs.uniform(3.0, 6.0)
        dep = rs.uniform(20.0, 60.0)
        hd = (alt - 0.15) / math.tan(math.radians(dep))
        az = rs.uniform(-180, 180)
        pos = tgt + np.array([-hd * math.cos(math.radians(az)), -hd * math.sin(math.radians(az)),
                              -(alt - 0.15)])
        q = euler_to_quat(rs.uniform(-4, 4), rs.uniform(-4, 4), az + rs.uniform(-25, 25))
        _, gt = world.render(wide, pos, q, 10**9)
        if not gt.target_visible or not wide.in_image(gt.top_corners_px, 2.0).all():
            continue
        out.append((wide, pos, q, gt))
    return out


def test_bearing_exact_at_the_top_face_centre(mission, world):
    rs = np.random.RandomState(31)
    est = registry.load("estimators", "bearing", {"plane_height_fraction": 1.0}, target=mission.target)
    for wide, pos, q, gt in _cases(mission, world, rs):
        centre_px = gt.top_corners_px.mean(axis=0)  # ~ the face centre (affine at this range)
        exact_px = wide.project(gt.target_pose_cam.t[None, :])[0]
        res = est.estimate(_det_at(*exact_px), view_at(wide, pos, q))
        assert res, str(res)
        np.testing.assert_allclose(res.position_ned_m, gt.target_position_ned_m, atol=1e-9)
        np.testing.assert_allclose(res.position_cam_m, gt.target_pose_cam.t, atol=1e-9)
        assert np.linalg.norm(centre_px - exact_px) < 3.0


def test_bearing_and_eq16_against_truth_from_silhouette(mission, world):
    """From the MBR centre of the silhouette (what a detector gives): the default bearing
    (mid-height plane) is within millimetres to a centimetre, the top-plane variant within
    centimetres to decimetres; Eq. (16), which only knows the image plane, is worse."""
    rs = np.random.RandomState(32)
    bearing = BearingEstimator(BearingConfig(), target=mission.target)
    bearing_top = BearingEstimator(BearingConfig(plane_height_fraction=1.0), target=mission.target)
    eq16 = PixelOffsetEstimator(PixelOffsetConfig(), target=mission.target)
    b_err, t_err, p_err = [], [], []
    for wide, pos, q, gt in _cases(mission, world, rs, n=16):
        det = detection_from_polygon(gt.target_polygon_px, "wide")
        view = view_at(wide, pos, q)
        b = bearing.estimate(det, view)
        bt = bearing_top.estimate(det, view)
        p = eq16.estimate(det, view)
        assert b and bt and p
        assert b.position_ned_m[2] == pytest.approx(gt.target_position_ned_m[2])
        assert not p.full_3d and b.full_3d
        horiz = float(np.hypot(*(np.array(gt.target_position_ned_m)[:2] - pos[:2])))
        b_err.append(np.hypot(*(np.array(b.position_ned_m) - gt.target_position_ned_m)[:2]) / horiz)
        t_err.append(np.hypot(*(np.array(bt.position_ned_m) - gt.target_position_ned_m)[:2]) / horiz)
        p_err.append(np.hypot(*(np.array(p.position_ned_m) - gt.target_position_ned_m)[:2]) / horiz)
    # Mid-height plane (default) < top plane < Eq. (16).
    assert np.median(b_err) < 0.005
    assert np.median(b_err) < 0.5 * np.median(t_err) < 0.05
    assert np.median(p_err) > np.median(t_err)


def test_eq16_is_the_pinhole_offset_at_the_axis_depth(mission, world):
    rs = np.random.RandomState(33)
    eq16 = PixelOffsetEstimator(PixelOffsetConfig(), target=mission.target)
    for wide, pos, q, gt in _cases(mission, world, rs, n=5):
        exact_px = wide.project(gt.target_pose_cam.t[None, :])[0]
        res = eq16.estimate(_det_at(*exact_px), view_at(wide, pos, q))
        x, y, z = gt.target_pose_cam.t
        D = res.position_cam_m[2]
        np.testing.assert_allclose(res.position_cam_m[:2], (x * D / z, y * D / z), rtol=1e-9)


def test_ray_above_horizon_is_a_failure(mission):
    wide = mission.cameras.wide.to_model("wide")
    # Level, 30 deg down mount: the top rows of the 2.8 mm camera (vertical FOV ~ 75 deg) look
    # above the horizon.
    pos, q = np.array([0.0, 0.0, -5.0]), euler_to_quat(0, 0, 0)
    view = view_at(wide, pos, q)
    res = BearingEstimator(BearingConfig(), target=mission.target).estimate(_det_at(640, 5), view)
    assert isinstance(res, EstimationFailed) and "horizon" in res.reason
    ok = BearingEstimator(BearingConfig(), target=mission.target).estimate(_det_at(640, 700), view)
    assert ok
    # Eq. (16) with the optical axis at the horizon has no depth.
    up = view_at(wide, pos, euler_to_quat(0, 30, 0))
    res = PixelOffsetEstimator(PixelOffsetConfig(), target=mission.target).estimate(_det_at(640, 480), up)
    assert isinstance(res, EstimationFailed) and "horizon" in res.reason
    fixed = PixelOffsetEstimator(PixelOffsetConfig(depth_source="fixed"), target=mission.target)
    assert fixed.estimate(_det_at(640, 480), up)


def test_ground_point_below_camera_required():
    from eaglemission.geometry import Pose

    cam = Pose(np.eye(3), np.array([0.0, 0.0, 1.0]))  # optical z = NED down, camera under ground
    res = ground_point_from_pixel(cam, np.array([0.0, 0.0, 1.0]), 0.0)
    assert isinstance(res, EstimationFailed)
    cam = Pose(np.eye(3), np.array([0.0, 0.0, -2.0]))
    np.testing.assert_allclose(ground_point_from_pixel(cam, np.array([0.0, 0.0, 1.0]), 0.0), [0, 0, 0])
