"""Core geometry: rotations, quaternions, the mount, projection, frame chains, geodetic."""

from __future__ import annotations

import math

import numpy as np
import pytest

from eaglemission.geometry import (
    R_FRD_FROM_OPTICAL,
    CameraModel,
    CameraMount,
    Pose,
    R_to_euler,
    R_to_quat,
    angle_between_rotations_deg,
    body_pose_ned,
    camera_pose_ned,
    down_axis_cos_tilt,
    euler_to_quat,
    euler_to_R,
    geodetic_to_ned,
    intersect_ray_with_horizontal_plane,
    intrinsics_from_lens,
    ned_to_geodetic,
    quat_slerp,
    quat_to_R,
    wrap_deg,
)
from eaglemission.types import GeoPoint


def _is_rotation(R):
    return np.allclose(R @ R.T, np.eye(3), atol=1e-12) and abs(np.linalg.det(R) - 1) < 1e-12


def test_euler_round_trip():
    rs = np.random.RandomState(11)
    for _ in range(200):
        roll, pitch, yaw = rs.uniform(-179, 179), rs.uniform(-89, 89), rs.uniform(-179, 179)
        R = euler_to_R(roll, pitch, yaw)
        assert _is_rotation(R)
        np.testing.assert_allclose(R_to_euler(R), (roll, pitch, yaw), atol=1e-9)


def test_quaternion_round_trip_and_euler_agreement():
    rs = np.random.RandomState(12)
    for _ in range(200):
        q = rs.normal(size=4)
        q /= np.linalg.norm(q)
        R = quat_to_R(q)
        assert _is_rotation(R)
        q2 = np.array(R_to_quat(R))
        assert np.allclose(q2, q, atol=1e-12) or np.allclose(q2, -q, atol=1e-12)
        e = R_to_euler(R)
        np.testing.assert_allclose(quat_to_R(euler_to_quat(*e)), R, atol=1e-12)


def test_quaternion_yaw_is_about_down():
    # Hamilton (w, x, y, z): 90 deg about z (NED down) turns north into east.
    q = (math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4))
    np.testing.assert_allclose(quat_to_R(q) @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(euler_to_quat(0, 0, 90), q, atol=1e-15)


def test_quat_rejects_zero():
    with pytest.raises(ValueError, match="quaternion"):
        quat_to_R((0, 0, 0, 0))


def test_slerp_midpoint_and_shortest_arc():
    q0 = euler_to_quat(0, 0, 170)
    q1 = euler_to_quat(0, 0, -170)
    mid = quat_slerp(q0, q1, 0.5)
    assert abs(wrap_deg(R_to_euler(quat_to_R(mid))[2]) - (-180.0)) < 1e-9
    q = quat_slerp(euler_to_quat(0, 0, 0), euler_to_quat(0, 0, 60), 0.25)
    assert R_to_euler(quat_to_R(q))[2] == pytest.approx(15.0, abs=1e-9)


def test_wrap_and_rotation_angle():
    assert wrap_deg(350) == -10 and wrap_deg(180) == -180 and wrap_deg(-190) == 170
    assert angle_between_rotations_deg(euler_to_R(0, 0, 10), euler_to_R(0, 0, -25)) == pytest.approx(35)


def test_mount_pitch_minus_30_looks_30_below_horizon():
    model = CameraModel.from_lens("wide", focal_length_mm=2.8, mount=CameraMount(0, -30, 0))
    level = euler_to_quat(0, 0, 0)
    pose = camera_pose_ned(model, (0, 0, -5), level)
    axis_ned = pose.R @ [0, 0, 1]
    assert math.degrees(math.asin(axis_ned[2])) == pytest.approx(30.0, abs=1e-12)  # down
    assert axis_ned[0] > 0.86 and abs(axis_ned[1]) < 1e-12  # forward = north
    # Optical x (image right) is body right = east when level and facing north.
    np.testing.assert_allclose(pose.R @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    # Yawed 90 deg: the axis points east, still 30 deg down.
    pose_e = camera_pose_ned(model, (0, 0, -5), euler_to_quat(0, 0, 90))
    np.testing.assert_allclose(pose_e.R @ [0, 0, 1], [0, math.cos(math.radians(30)), 0.5], atol=1e-12)


def test_frd_from_optical_permutation():
    np.testing.assert_array_equal(R_FRD_FROM_OPTICAL @ [0, 0, 1], [1, 0, 0])
    np.testing.assert_array_equal(R_FRD_FROM_OPTICAL @ [1, 0, 0], [0, 1, 0])
    np.testing.assert_array_equal(R_FRD_FROM_OPTICAL @ [0, 1, 0], [0, 0, 1])


def test_intrinsics_from_lens_basler():
    K = intrinsics_from_lens(12.0, 3.75, 1280, 960)
    assert K[0, 0] == pytest.approx(3200.0) and K[0, 2] == 639.5 and K[1, 2] == 479.5
    wide = CameraModel.from_lens("wide", focal_length_mm=2.8)
    assert wide.fov_deg[0] == pytest.approx(2 * math.degrees(math.atan(640 / (2800 / 3.75))), rel=1e-12)
    with pytest.raises(ValueError):
        intrinsics_from_lens(0, 3.75, 1280, 960)


@pytest.mark.parametrize("dist", [(), (-0.25, 0.09, 0.001, -0.0005, -0.015)])
def test_project_normalize_round_trip(dist):
    rs = np.random.RandomState(13)
    model = CameraModel.from_lens("narrow", focal_length_mm=12.0, distortion=dist)
    # Points that land inside the image.
    nrm = np.column_stack((rs.uniform(-0.18, 0.18, 200), rs.uniform(-0.14, 0.14, 200)))
    z = rs.uniform(0.5, 20, 200)
    pts = np.column_stack((nrm * z[:, None], z))
    px = model.project(pts)
    assert model.in_image(px).all()
    back = model.normalize(px)
    np.testing.assert_allclose(back, nrm, atol=1e-7 if dist else 1e-14)
    rays = model.rays_optical(px)
    np.testing.assert_allclose(rays, pts / np.linalg.norm(pts, axis=1, keepdims=True), atol=1e-7)
    if dist:  # distortion really moves the pixels
        plain = CameraModel.from_lens("narrow", focal_length_mm=12.0).project(pts)
        assert np.abs(plain - px).max() > 1.0


def test_normalize_converges_at_wide_lens_corners():
    """OpenCV's default 5 undistortion iterations leave 1.25 px at the corners of the 2.8 mm
    camera with k1 = -0.3; normalize() iterates to convergence."""
    model = CameraModel.from_lens("wide", focal_length_mm=2.8,
                                  distortion=(-0.30, 0.09, 0.001, -0.0005, -0.012))
    rs = np.random.RandomState(16)
    nrm = np.column_stack((rs.uniform(-0.8, 0.8, 2000), rs.uniform(-0.6, 0.6, 2000)))
    px = model.project(np.column_stack((nrm, np.ones(len(nrm)))))
    ok = model.in_image(px)
    assert ok.sum() > 1000
    err_px = np.abs(model.normalize(px[ok]) - nrm[ok]).max() * model.fx
    assert err_px < 1e-6


def test_project_behind_camera_is_nan():
    model = CameraModel.from_lens("narrow", focal_length_mm=12.0)
    px = model.project([[0, 0, -1], [0.1, 0, 2]])
    assert np.isnan(px[0]).all() and np.isfinite(px[1]).all()


def test_camera_body_ned_chain():
    rs = np.random.RandomState(14)
    mount = CameraMount(2.0, -30.0, 5.0, (0.10, -0.03, 0.05))
    model = CameraModel.from_lens("wide", focal_length_mm=2.8, mount=mount)
    pos = np.array([3.0, -2.0, -6.0])
    q = euler_to_quat(4.0, -3.0, 123.0)
    cam = camera_pose_ned(model, pos, q)
    body = body_pose_ned(pos, q)
    # The camera centre is the lever arm carried by the body attitude.
    np.testing.assert_allclose(cam.t, pos + quat_to_R(q) @ mount.lever_arm_m, atol=1e-12)
    p_opt = rs.normal(size=(10, 3))
    p_body = p_opt @ mount.R_body_optical.T + mount.lever_arm_m
    np.testing.assert_allclose(cam.apply(p_opt), body.apply(p_body), atol=1e-12)
    # Inverse and composition.
    np.testing.assert_allclose(cam.inverse().apply(cam.apply(p_opt)), p_opt, atol=1e-12)
    comp = cam.inverse() @ cam
    np.testing.assert_allclose(comp.R, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(comp.t, 0, atol=1e-12)


def test_projection_of_ned_point_through_chain():
    model = CameraModel.from_lens("narrow", focal_length_mm=12.0, mount=CameraMount(0, -30, 0))
    cam = camera_pose_ned(model, (0, 0, -5), euler_to_quat(0, 0, 0))
    # A ground point straight along the optical axis projects to the principal point.
    d = 5.0 / math.tan(math.radians(30))
    px = model.project(cam.inverse().apply(np.array([[d, 0, 0.0]])))
    np.testing.assert_allclose(px[0], (model.cx, model.cy), atol=1e-9)


def test_ray_plane_intersection():
    hit = intersect_ray_with_horizontal_plane((0, 0, -5), (1, 0, 1), 0.0)
    np.testing.assert_allclose(hit, (5, 0, 0))
    assert intersect_ray_with_horizontal_plane((0, 0, -5), (1, 0, 0), 0.0) is None
    assert intersect_ray_with_horizontal_plane((0, 0, -5), (1, 0, -0.1), 0.0) is None
    assert intersect_ray_with_horizontal_plane((0, 0, 1), (0, 0, 1), 0.0) is None


def test_geodetic_round_trip():
    home = GeoPoint(47.397742, 8.545594, 488.0)
    rs = np.random.RandomState(15)
    for n, e, d in rs.uniform(-500, 500, size=(50, 3)):
        g = ned_to_geodetic(home, n, e, d)
        np.testing.assert_allclose(geodetic_to_ned(home, g), (n, e, d), atol=1e-6)
    # 1 arc-second of latitude is about 30.9 m.
    n, _, _ = geodetic_to_ned(home, GeoPoint(home.latitude_deg + 1 / 3600, home.longitude_deg, 488.0))
    assert n == pytest.approx(30.87, abs=0.05)


def test_pose_apply_shapes():
    p = Pose(euler_to_R(0, 0, 90), np.array([1.0, 2.0, 3.0]))
    np.testing.assert_allclose(p.apply([1.0, 0.0, 0.0]), [1.0, 3.0, 3.0], atol=1e-12)


def test_down_axis_cos_tilt_is_the_down_component_of_body_z() -> None:
    rng = np.random.RandomState(23)
    for _ in range(50):
        q = euler_to_quat(*rng.uniform(-60, 60, 2), rng.uniform(-180, 180))
        body_z_ned = quat_to_R(q) @ np.array([0.0, 0.0, 1.0])
        assert down_axis_cos_tilt(q) == pytest.approx(body_z_ned[2], abs=1e-12)
    # a 10-deg roll or pitch tilts the down axis by 10 deg; yaw does not
    assert down_axis_cos_tilt(euler_to_quat(10, 0, 75)) == pytest.approx(math.cos(math.radians(10)))
    assert down_axis_cos_tilt(euler_to_quat(0, -10, -30)) == pytest.approx(math.cos(math.radians(10)))
