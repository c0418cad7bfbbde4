"""Narrow-camera footprint in the wide image and the camera-switch predicate, against the
synthetic world."""

from __future__ import annotations

import math

import numpy as np
import pytest
from eaglemission.lab.world.synthetic import SyntheticWorldConfig, world_config
from world_helpers import detection_from_polygon

from eaglemission.geometry import camera_pose_ned, euler_to_quat
from eaglemission.geometry.fov import (
    map_points,
    narrow_fov_in_wide,
    pixel_homography,
    plane_homography_normalized,
    refine_homography,
    relative_pose,
    target_in_narrow_view,
)


@pytest.fixture(scope="module")
def mission():
    from eaglemission.config import load_config

    return load_config(check_plugins=False)


@pytest.fixture(scope="module")
def world(mission):
    world_mod = pytest.importorskip("eaglemission.lab.world.render")
    return world_mod.SyntheticWorld(world_config(mission), mission.target, seed=1, extent_m=80.0)


@pytest.fixture(scope="module")
def cams(mission):
    return mission.cameras.wide.to_model("wide"), mission.cameras.narrow.to_model("narrow")


def test_plane_homography_matches_ray_casting(cams):
    wide, narrow = cams
    rs = np.random.RandomState(41)
    for _ in range(10):
        pos = np.array([0.0, 0.0, -rs.uniform(0.4, 8.0)])
        q = euler_to_quat(rs.uniform(-8, 8), rs.uniform(-8, 8), rs.uniform(-180, 180))
        height = -pos[2]
        H = plane_homography_normalized(wide, narrow, height, q)
        pn = np.column_stack((rs.uniform(0, 1279, 20), rs.uniform(0, 959, 20)))
        cam_n = camera_pose_ned(narrow, pos, q)
        cam_w = camera_pose_ned(wide, pos, q)
        rays = narrow.rays_optical(pn) @ cam_n.R.T
        s = (0.0 - cam_n.t[2]) / rays[:, 2]
        ground = cam_n.t + s[:, None] * rays
        expect = wide.project(cam_w.inverse().apply(ground))
        np.testing.assert_allclose(map_points(H, narrow, wide, pn), expect, atol=1e-7)


def test_tends_to_infinite_homography_and_baseline_matters_close(cams):
    wide, narrow = cams
    R_wn, t_wn = relative_pose(wide, narrow)
    assert np.linalg.norm(t_wn) == pytest.approx(0.06)  # the configs' lever arms differ by 6 cm
    far = narrow_fov_in_wide(wide, narrow, 1e6)
    inf = narrow_fov_in_wide(wide, narrow, math.inf)
    near = narrow_fov_in_wide(wide, narrow, 0.6)
    assert np.abs(far - inf).max() < 1e-3
    # ~ f_w * baseline / distance: 747 px * 0.06 m / ~1.1 m ~ 40 px at 0.6 m height
    assert np.abs(near - inf).max() > 20
    H = pixel_homography(wide, narrow, plane_homography_normalized(wide, narrow, 5.0))
    c = np.array([[-0.5, -0.5, 1.0]]) @ H.T
    np.testing.assert_allclose(c[0, :2] / c[0, 2], narrow_fov_in_wide(wide, narrow, 5.0)[0], atol=1e-6)


def _poses(rs, tgt, n):
    for _ in range(n):
        alt = rs.uniform(1.5, 6.0)
        dep = rs.uniform(22.0, 40.0)
        hd = (alt - 0.15) / math.tan(math.radians(dep))
        az = rs.uniform(-180, 180)
        pos = np.asarray(tgt) + np.array([-hd * math.cos(math.radians(az)),
                                          -hd * math.sin(math.radians(az)), -(alt - 0.15)])
        yield pos, euler_to_quat(rs.uniform(-4, 4), rs.uniform(-4, 4), az + rs.uniform(-12, 12))


def test_predicate_agrees_with_the_narrow_camera_render(world, cams):
    """The switch predicate on the wide detection vs what the synthetic narrow camera renders
    (ground truth): no false positive with the default margin, and agreement in most cases."""
    wide, narrow = cams
    rs = np.random.RandomState(42)
    tgt = np.array(world.target_position_ned_m)
    agree = total = false_pos = 0
    for pos, q in _poses(rs, tgt, 40):
        _, gw = world.render(wide, pos, q, 10**9)
        if not gw.target_visible or not wide.in_image(gw.target_polygon_px, 1.0).all():
            continue
        _, gn = world.render(narrow, pos, q, 10**9)
        truth = bool(gn.top_face_visible)  # all 4 top corners inside the narrow image
        det = detection_from_polygon(gw.target_polygon_px, "wide")
        height = tgt[2] - pos[2]  # vehicle height above the target's top (down difference)
        pred = target_in_narrow_view(wide, narrow, det.corners_px, height_above_ground_m=height,
                                     attitude_q=q)
        total += 1
        agree += pred == truth
        false_pos += pred and not truth
    assert total >= 20
    assert false_pos == 0
    print(f'agree {agree}/{total}, false positives {false_pos}')
    assert agree / total >= 0.8


def test_predicate_rejects_garbage(cams):
    wide, narrow = cams
    assert not target_in_narrow_view(wide, narrow, np.full((4, 2), np.nan), height_above_ground_m=5)
    with pytest.raises(ValueError, match="height_above_ground_m"):
        target_in_narrow_view(wide, narrow, [[640, 480]], height_above_ground_m=-1)
    assert target_in_narrow_view(wide, narrow, [[640, 480]], height_above_ground_m=1e6,
                                 require="centre")


def test_feature_refinement_recovers_a_mount_error(mission, cams):
    """With a 1.5 deg mount error in the rendering cameras, the calibrated footprint is off by
    ~15 wide px; SIFT + RANSAC on the textured ground brings it back to a few px."""
    from eaglemission.lab.world.render import SyntheticWorld

    wide, narrow = cams
    sim = SyntheticWorldConfig(**{**world_config(mission).model_dump(), "mount_error_deg": 1.5,
                              "noise_sigma": 1.0})
    w = SyntheticWorld(sim, mission.target, seed=3, extent_m=60.0)
    pos = np.array([10.0, 1.5, -4.0])
    q = euler_to_quat(0.0, 0.0, 0.0)
    img_w, gw = w.render(wide, pos, q, 10**9)
    img_n, gn = w.render(narrow, pos, q, 10**9)
    height = -pos[2]
    H_cal = pixel_homography(wide, narrow, plane_homography_normalized(wide, narrow, height, q))
    # The truth with the TRUE (mis-mounted) cameras.
    tw, tn = gw.true_model, gn.true_model
    H_true = pixel_homography(tw, tn, plane_homography_normalized(tw, tn, height, q))
    corners = np.array([[0, 0, 1], [1279, 0, 1], [1279, 959, 1], [0, 959, 1]], dtype=float)

    def footprint(H):
        p = corners @ H.T
        return p[:, :2] / p[:, 2:]

    err_cal = np.abs(footprint(H_cal) - footprint(H_true)).max()
    res = refine_homography(img_w, img_n, H_cal)
    err_ref = np.abs(footprint(res.H_px) - footprint(H_true)).max()
    assert err_cal > 5.0
    assert res.refined, res.reason
    assert err_ref < 0.5 * err_cal and err_ref < 5.0


def test_refinement_falls_back_without_texture(cams):
    wide, narrow = cams
    H = pixel_homography(wide, narrow, plane_homography_normalized(wide, narrow, 5.0))
    flat_w = np.full((960, 1280, 3), 128, np.uint8)
    flat_n = np.full((960, 1280, 3), 128, np.uint8)
    res = refine_homography(flat_w, flat_n, H)
    assert not res.refined and "feature" in res.reason
    np.testing.assert_array_equal(res.H_px, H)
