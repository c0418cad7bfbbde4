"""The synthetic world: ground truth agrees with the pixels, realism knobs, determinism."""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np
import pytest
from _camera_helpers import StaticPose, looking_at_target
from eaglemission.lab.cameras.synthetic import SyntheticCamera
from eaglemission.lab.world.render import SyntheticWorld, clip_polygon, polygon_area
from eaglemission.lab.world.synthetic import DistractorConfig, SyntheticWorldConfig

from eaglemission.clock import ManualClock
from eaglemission.geometry import angle_between_rotations_deg, euler_to_quat
from eaglemission.types import Frame


def _top_mask(img: np.ndarray, world: SyntheticWorld) -> np.ndarray:
    return np.all(img == np.asarray(world.target_top_colour_bgr, np.uint8), axis=2)


@pytest.mark.parametrize("camera", ["wide", "narrow"])
def test_ground_truth_corners_match_rendered_target_within_1px(
        camera, sim_config, target_config, wide_model, narrow_model):
    rng = np.random.RandomState(101)
    world = SyntheticWorld(sim_config, target_config, extent_m=60.0)
    model = wide_model if camera == "wide" else narrow_model
    checked = 0
    for _ in range(8):
        d = rng.uniform(1.5, 8.0 if camera == "wide" else 4.0)
        pos, q = looking_at_target(d, rng.uniform(-180, 180), roll_deg=rng.uniform(-5, 5),
                                   pitch_deg=rng.uniform(-5, 5), yaw_err_deg=rng.uniform(-4, 4))
        img, gt = world.render(model, pos, q, 1_000_000_000)
        if not gt.top_face_visible:
            continue
        mask = _top_mask(img, world)
        ys, xs = np.nonzero(mask)
        assert len(xs) > 20
        poly = gt.top_corners_px.astype(np.float32)
        # 1) every rendered top-face pixel lies within 1 px of the ground-truth quadrilateral
        sd = np.array([cv2.pointPolygonTest(poly, (float(x), float(y)), True)
                       for x, y in zip(xs[::7], ys[::7])])
        assert sd.min() >= -1.0, f"rendered pixel {-sd.min():.2f} px outside the GT corners"
        # 2) every pixel more than 1 px inside the quadrilateral is rendered as top face
        x0, y0 = np.floor(poly.min(axis=0)).astype(int)
        x1, y1 = np.ceil(poly.max(axis=0)).astype(int)
        for y in range(max(0, y0), min(img.shape[0], y1 + 1), 3):
            for x in range(max(0, x0), min(img.shape[1], x1 + 1), 3):
                if cv2.pointPolygonTest(poly, (float(x), float(y)), True) > 1.0:
                    assert mask[y, x], f"pixel ({x}, {y}) inside the GT corners not rendered"
        # 3) each GT corner has a rendered pixel nearby (acute corners: within 2 px)
        pts = np.column_stack((xs, ys)).astype(np.float64)
        for c in gt.top_corners_px:
            assert np.min(np.hypot(*(pts - c).T)) <= 2.0
        checked += 1
    assert checked >= 5


def test_ground_truth_uses_the_true_camera_not_the_nominal_one(
        sim_config, target_config, wide_model):
    world = SyntheticWorld(sim_config, target_config, extent_m=60.0)
    true = world.true_camera(wide_model)
    # mount error bounded by the knob and present; focal error bounded by the knob
    ang = angle_between_rotations_deg(true.mount.R_body_optical, wide_model.mount.R_body_optical)
    assert 0.0 < ang <= sim_config.mount_error_deg + 1e-9
    e = true.fx / wide_model.fx - 1.0
    assert 0.0 < abs(e) <= sim_config.focal_error_fraction
    assert true.cx == wide_model.cx and true.cy == wide_model.cy
    # the same camera id gets the same error every time (a fixed miscalibration)
    other = SyntheticWorld(sim_config, target_config, extent_m=60.0)
    assert np.allclose(other.true_camera(wide_model).K, true.K)
    # projecting the target with the NOMINAL camera misses the GT corners by pixels
    pos, q = looking_at_target(5.0, 10.0)
    _, gt = world.render(wide_model, pos, q, 1_000_000_000)
    from eaglemission.geometry import camera_pose_ned

    nominal = camera_pose_ned(wide_model, pos, q).inverse().apply(world.target_top_corners_ned())
    miss = np.hypot(*(wide_model.project(nominal) - gt.top_corners_px).T)
    assert miss.max() > 3.0


def test_no_realism_knobs_means_nominal_camera(sim_config, target_config, wide_model):
    sim = sim_config.model_copy(update={"mount_error_deg": 0.0, "focal_error_fraction": 0.0})
    world = SyntheticWorld(sim, target_config, extent_m=60.0)
    pos, q = looking_at_target(5.0, -40.0)
    _, gt = world.render(wide_model, pos, q, 1_000_000_000)
    from eaglemission.geometry import camera_pose_ned

    cam = camera_pose_ned(wide_model, pos, q).inverse()
    expected = wide_model.project(cam.apply(world.target_top_corners_ned()))
    assert np.allclose(expected, gt.top_corners_px, atol=1e-6)
    # the pose in the camera frame reprojects to the same corners
    obj = np.array([[0.2, -0.125, 0], [0.2, 0.125, 0], [-0.2, 0.125, 0], [-0.2, -0.125, 0]])
    assert np.allclose(wide_model.project(gt.target_pose_cam.apply(obj)), gt.top_corners_px,
                       atol=1e-6)


def test_stripping_ground_truth_gives_identical_frames(sim_config, target_config, wide_model):
    """Frames do not depend on whether anybody records or reads the ground truth."""
    pos, q = looking_at_target(6.0, 20.0)
    sim = sim_config.model_copy(update={"noise_sigma": 3.0})
    w1 = SyntheticWorld(sim, target_config, extent_m=60.0)
    w2 = SyntheticWorld(sim, target_config, extent_m=60.0)
    clock = ManualClock()
    cam = SyntheticCamera(model=wide_model, clock=clock, world=w1, pose_source=StaticPose(pos, q))
    frames = []
    for _ in range(3):
        frames.append(cam.grab(timeout_s=1.0))
        assert w1.truth("wide", frames[-1].seq).target_visible
        clock.advance(1 / 30)
    # Frame carries no ground truth
    assert {f.name for f in dataclasses.fields(Frame)} == {
        "image", "timestamp_ns", "camera_id", "seq", "exposure_s", "device_timestamp_ns"}
    # the same renders without any ground-truth bookkeeping
    for f in frames:
        img, _ = w2.render(wide_model, pos, q, f.timestamp_ns)
        assert np.array_equal(img, f.image)


def test_rendering_is_deterministic_for_a_seed(target_config, wide_model):
    sim = SyntheticWorldConfig(seed=5, target_north_m=10, target_east_m=2, noise_sigma=2.0,
                           ground_texture="grass", mount_error_deg=1.0)
    pos, q = looking_at_target(5.0, 0.0)
    a, _ = SyntheticWorld(sim, target_config, extent_m=60.0).render(wide_model, pos, q, 7)
    b, _ = SyntheticWorld(sim, target_config, extent_m=60.0).render(wide_model, pos, q, 7)
    assert np.array_equal(a, b)
    c, _ = SyntheticWorld(sim.model_copy(update={"seed": 6}), target_config,
                          extent_m=60.0).render(wide_model, pos, q, 7)
    assert np.mean(np.abs(a.astype(int) - c.astype(int))) > 5.0
    # noise changes from frame to frame (different timestamps), the scene does not
    d, _ = SyntheticWorld(sim, target_config, extent_m=60.0).render(wide_model, pos, q, 8)
    diff = np.abs(a.astype(int) - d.astype(int))
    assert 0.5 < diff.mean() < 5.0


def test_sky_above_horizon_only(sim_config, target_config, wide_model):
    world = SyntheticWorld(sim_config.model_copy(update={
        "mount_error_deg": 0.0, "focal_error_fraction": 0.0, "ground_texture": "grass"}),
        target_config, extent_m=60.0)
    sky = np.array([205, 150, 95])
    level = world.render(wide_model, (0, 0, -5), euler_to_quat(0, 30, 0), 1)[0]
    # optical axis on the horizon: top half sky-ish blue, bottom half ground (grass)
    top, bottom = level[:400].reshape(-1, 3), level[560:].reshape(-1, 3)
    is_sky = lambda px: (px[:, 0].astype(int) - px[:, 2] > 15)  # noqa: E731 - blue > red
    assert is_sky(top).mean() > 0.99
    assert is_sky(bottom).mean() < 0.05
    down = world.render(wide_model, (0, 0, -5), euler_to_quat(0, -60, 0), 1)[0]
    assert not np.any(np.all(down == sky, axis=2))


def test_ground_texture_is_sharp_at_close_range(target_config, narrow_model):
    """The narrow camera at 0.6 m sees texture detail, not a blurred blob."""
    sim = SyntheticWorldConfig(seed=1, target_north_m=30, target_east_m=0, noise_sigma=0.0,
                           ground_texture="vegetation")
    world = SyntheticWorld(sim, target_config, extent_m=80.0)
    img, _ = world.render(narrow_model, (0, 0, -0.6), euler_to_quat(0, 0, 0), 1)
    gray = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    sharp = cv2.Laplacian(gray, cv2.CV_32F).var()
    assert sharp > 5.0, f"Laplacian variance {sharp:.2f}: close-range ground is a blur"
    assert gray.std() > 10.0


def test_distractors_are_drawn_and_move(target_config, wide_model):
    sim = SyntheticWorldConfig(seed=2, target_north_m=30, target_east_m=0, noise_sigma=0.0,
                           ground_texture="snow",
                           distractors=[DistractorConfig(kind="moving_box", north_m=8, east_m=0,
                                                         size_m=0.6, height_m=0.3,
                                                         color_bgr=(0, 200, 0),
                                                         velocity_ne_mps=(0.0, 1.0)),
                                        DistractorConfig(kind="disc", north_m=8, east_m=-2,
                                                         size_m=0.8, color_bgr=(200, 0, 0))])
    world = SyntheticWorld(sim, target_config, extent_m=80.0)
    q = euler_to_quat(0, 0, 0)

    def centroid(img: np.ndarray, bgr: tuple[int, int, int]) -> np.ndarray:
        m = np.all(np.abs(img.astype(int) - np.asarray(bgr)) < 60, axis=2)
        m &= img[..., 1] > 100 if bgr[1] else img[..., 0] > 100
        ys, xs = np.nonzero(m)
        assert len(xs) > 50
        return np.array([xs.mean(), ys.mean()])

    a, _ = world.render(wide_model, (0, 0, -4), q, 1_000_000_000)
    b, _ = world.render(wide_model, (0, 0, -4), q, 2_000_000_000)
    ga, gb = centroid(a, (0, 200, 0)), centroid(b, (0, 200, 0))
    assert gb[0] - ga[0] > 20  # moved east = right in the image
    da, db = centroid(a, (200, 0, 0)), centroid(b, (200, 0, 0))
    assert np.allclose(da, db, atol=0.5)


def test_target_behind_camera_is_not_visible(sim_config, target_config, wide_model):
    world = SyntheticWorld(sim_config, target_config, extent_m=60.0)
    pos, q = looking_at_target(5.0, 0.0)
    q_away = euler_to_quat(0, 0, 180)
    _, gt = world.render(wide_model, pos, q_away, 1)
    assert not gt.target_visible and not gt.top_face_visible
    assert gt.target_polygon_px.shape == (0, 2)
    assert not np.isfinite(gt.top_corners_px).all() or not gt.true_model.in_image(
        gt.top_corners_px).any()


def test_clip_polygon_keeps_the_half_plane():
    sq = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])
    out = clip_polygon(sq, np.array([1.0, 0.0]), 1.0)
    assert out[:, 0].min() == pytest.approx(1.0)
    assert len(out) == 4
    assert len(clip_polygon(sq, np.array([1.0, 0.0]), 5.0)) == 0
    assert math.isclose(polygon_area(out), 2.0)


def test_texture_disk_cache_round_trip_and_pruning(tmp_path, monkeypatch):
    from eaglemission.lab.world import textures
    monkeypatch.setenv("EAGLEMISSION_TEXTURE_CACHE", str(tmp_path))
    calls = []

    def make() -> np.ndarray:
        calls.append(1)
        return textures.base_texture("soil", 64, 0.05, 4)

    a = textures.cached_texture("v1_soil_s4_base_64", make)
    b = textures.cached_texture("v1_soil_s4_base_64", make)
    assert len(calls) == 1 and np.array_equal(a, b)
    assert not list(tmp_path.glob("*.tmp*"))
    # pruning keeps the cache under its size limit, newest first
    monkeypatch.setenv("EAGLEMISSION_TEXTURE_CACHE_MB", str(2.5 * a.nbytes / 1e6))
    for k in range(4):
        textures.cached_texture(f"v1_soil_s{k}_base_64x", lambda k=k: textures.base_texture(
            "soil", 64, 0.05, k))
    assert len(list(tmp_path.glob("*.npy"))) == 2
    monkeypatch.setenv("EAGLEMISSION_TEXTURE_CACHE", "off")
    assert textures.cache_dir() is None


def test_box_casts_a_shadow_on_the_ground(sim_config, target_config, wide_model):
    sim = sim_config.model_copy(update={"mount_error_deg": 0.0, "focal_error_fraction": 0.0,
                                        "ground_texture": "grass"})
    world = SyntheticWorld(sim, target_config, extent_m=60.0)
    R, t = world.target_object.pose_ned(1_000_000_000)
    poly = world.shadow_polygon_ned(world.target_object.faces, R, t)
    assert poly is not None
    # look at the shadow from above-ish, then compare with a flat target (no shadow)
    pos, q = looking_at_target(3.0, 60.0)
    img, _ = world.render(wide_model, pos, q, 1_000_000_000)
    flat = SyntheticWorld(sim, target_config.model_copy(update={"height_m": 0.0}), extent_m=60.0)
    ref, _ = flat.render(wide_model, pos, q, 1_000_000_000)
    from eaglemission.geometry import camera_pose_ned

    cam = camera_pose_ned(wide_model, pos, q).inverse()
    uv = wide_model.project(cam.apply(poly))
    shadow = np.zeros(img.shape[:2], np.uint8)
    cv2.fillConvexPoly(shadow, np.round(uv).astype(np.int32), 1)
    shadow = cv2.erode(shadow, np.ones((5, 5), np.uint8)) > 0
    shadow &= np.all(img == ref, axis=2) == False  # noqa: E712 - only changed pixels
    box = np.all(np.abs(img.astype(int) - np.array(world.target_colour_bgr)) < 80, axis=2)
    ground = shadow & ~box
    assert ground.sum() > 50
    ratio = img[ground].astype(float).mean() / ref[ground].astype(float).mean()
    assert 0.45 < ratio < 0.65
