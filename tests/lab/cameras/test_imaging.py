"""The synthetic camera's imaging effects: motion blur from the camera's motion during the
exposure, white balance, Bayer demosaicing, JPEG (docs/simulation.md, "Imaging effects")."""

from __future__ import annotations

import math
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from _camera_helpers import TARGET_NE, StaticPose
from eaglemission.drivers.cameras.genicam import to_bgr
from eaglemission.lab.cameras.imaging import (
    MIN_BLUR_PX,
    apply_colour_gains,
    bayer_mosaic,
    bayer_round_trip,
    jpeg_round_trip,
    motion_blur,
    motion_blur_kernel,
)
from eaglemission.lab.cameras.synthetic import SyntheticCamera, pose_moved_back
from eaglemission.lab.vehicles.simulated.truth_log import TruthLog
from eaglemission.lab.world.render import SyntheticWorld

from eaglemission.clock import ManualClock
from eaglemission.geometry import (
    CameraModel,
    CameraMount,
    angle_between_rotations_deg,
    euler_to_quat,
    quat_to_R,
)
from eaglemission.types import FlightMode

EXPOSURE_S = 0.004
HEIGHT_M = 3.0


def _nadir_narrow() -> CameraModel:
    return CameraModel.from_lens("narrow", focal_length_mm=12.0, exposure_s=EXPOSURE_S,
                                 mount=CameraMount(0.0, -90.0, 0.0, (0.0, 0.0, 0.0)))


def _world(sim_config, target_config, **knobs) -> SyntheticWorld:
    sim = sim_config.model_copy(update={"mount_error_deg": 0.0, "focal_error_fraction": 0.0,
                                        "noise_sigma": 0.0, **knobs})
    return SyntheticWorld(sim, target_config, extent_m=60.0)


def _above_target() -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
    # right above the target: its top face is whole around the image centre
    return (TARGET_NE[0], TARGET_NE[1], -HEIGHT_M), euler_to_quat(0.0, 0.0, 0.0)


# ---------------------------------------------------------------------------------------------
# Motion blur
# ---------------------------------------------------------------------------------------------
def _run_length(column: np.ndarray, colour: np.ndarray) -> int:
    """Length of the longest run of pixels of exactly ``colour`` in a column."""
    same = np.all(column == colour, axis=1)
    best = run = 0
    for s in same:
        run = run + 1 if s else 0
        best = max(best, run)
    return best


def test_blur_length_matches_the_analytic_displacement_for_a_known_velocity(
        sim_config, target_config):
    """A nadir 12 mm camera 3 m above the ground, flying north at 3 m/s: the ground point on
    its optical axis moves by f v T / Z = 3200 px x 3 m/s x 4 ms / 3 m = 12.8 px along v
    during the 4 ms exposure; the frame is smeared by that, so the target's uniform top face
    (its core of exactly the top colour) shrinks along v by the blur length."""
    model = _nadir_narrow()
    f = model.K[0, 0]
    speed = 3.0
    pos, q = _above_target()
    start = ((pos[0] - speed * EXPOSURE_S / 2, pos[1], pos[2]), q)
    sharp_world = _world(sim_config, target_config)
    blur_world = _world(sim_config, target_config, motion_blur=True)
    sharp, _ = sharp_world.render(model, pos, q, 10**9)
    blurred, truth = blur_world.render(model, pos, q, 10**9, exposure_start_pose=start)
    expected = f * speed * EXPOSURE_S / HEIGHT_M  # the ground point on the optical axis
    du, dv = truth.motion_blur_px
    assert du == pytest.approx(0.0, abs=1e-6)
    assert dv == pytest.approx(expected, rel=1e-6)  # north = image up: the scene moves down
    top = np.asarray(blur_world.target_top_colour_bgr, np.uint8)
    col = model.width_px // 2
    n_sharp = _run_length(sharp[:, col], top)
    n_blur = _run_length(blurred[:, col], top)
    assert n_sharp > 100
    assert expected - 1.0 <= n_sharp - n_blur <= expected + 2.0


def test_camera_blurs_with_a_pitch_rate_from_the_pose_sources_motion(sim_config, target_config):
    """A pose source offering ``motion_at`` (the simulated vehicle's truth does): a pitch rate
    q about the body's y axis moves the principal point by f tan(q T) along v."""
    model = CameraModel.from_lens("narrow", focal_length_mm=12.0, exposure_s=EXPOSURE_S,
                                  mount=CameraMount(0.0, -30.0, 0.0, (0.0, 0.0, 0.0)))
    world = _world(sim_config, target_config, motion_blur=True)
    rate = 0.5  # rad/s, nose up
    source = StaticPose((TARGET_NE[0] - 5.0, TARGET_NE[1], -HEIGHT_M), euler_to_quat(0, 0, 0))
    omega_ned = quat_to_R(source.q) @ np.array([0.0, rate, 0.0])
    asked: list[int] = []

    def motion_at(t_ns: int):
        asked.append(t_ns)
        return (0.0, 0.0, 0.0), tuple(omega_ned)

    source.motion_at = motion_at  # type: ignore[attr-defined]
    cam = SyntheticCamera(model=model, clock=ManualClock(10**9), world=world,
                          pose_source=source)
    frame = cam.grab(timeout_s=1.0)
    du, dv = cam.truth(frame.seq).motion_blur_px
    f = model.K[0, 0]
    assert asked == [10**9]
    assert math.hypot(du, dv) == pytest.approx(f * math.tan(rate * EXPOSURE_S), rel=0.02)
    assert abs(du) < 0.05 * abs(dv)


def test_camera_without_motion_at_differences_two_poses(sim_config, target_config):
    """A pose source with poses only: the camera asks it for the pose half an exposure
    earlier; a vehicle at rest is not blurred."""
    model = _nadir_narrow()
    world = _world(sim_config, target_config, motion_blur=True)
    pos, q = _above_target()
    moving = StaticPose(pos, q, velocity_ned_mps=(0.0, 2.0, 0.0))
    cam = SyntheticCamera(model=model, clock=ManualClock(2 * 10**9), world=world,
                          pose_source=moving)
    frame = cam.grab(timeout_s=1.0)
    assert moving.calls == [2 * 10**9, 2 * 10**9 - 2_000_000]
    du, dv = cam.truth(frame.seq).motion_blur_px
    assert dv == pytest.approx(0.0, abs=1e-6)
    assert -du == pytest.approx(model.K[0, 0] * 2.0 * EXPOSURE_S / HEIGHT_M, rel=1e-6)
    still = SyntheticCamera(model=model, clock=ManualClock(2 * 10**9), world=world,
                            pose_source=StaticPose(pos, q))
    assert math.hypot(*still.truth(still.grab(timeout_s=1.0).seq).motion_blur_px) < 1e-9


def test_blur_off_ignores_the_exposure_start_pose(sim_config, target_config):
    model = _nadir_narrow()
    world = _world(sim_config, target_config)
    pos, q = _above_target()
    a, _ = world.render(model, pos, q, 10**9)
    b, truth = world.render(model, pos, q, 10**9,
                            exposure_start_pose=((pos[0] - 0.1, pos[1], pos[2]), q))
    assert np.array_equal(a, b) and truth.motion_blur_px == (0.0, 0.0)


@pytest.mark.parametrize("motion", [(20.0, -14.0), (40.0, 3.0), (-9.5, 0.0)])
def test_long_blur_in_pieces_equals_the_single_kernel(motion):
    """Segments over 8 px are filtered in pieces (no DFT): the same result as the whole kernel
    applied in float, within rounding."""
    rng = np.random.RandomState(5)
    img = cv2.GaussianBlur(rng.randint(0, 256, (120, 160, 3)).astype(np.uint8), (0, 0), 1.5)
    ref = cv2.filter2D(img.astype(np.float32), -1, motion_blur_kernel(*motion),
                       borderType=cv2.BORDER_REFLECT)
    out = motion_blur(img, *motion)
    m = 25  # the borders are handled alike, but compare the inside
    assert np.abs(out.astype(np.float32) - ref)[m:-m, m:-m].max() <= 1.0


def test_motion_blur_kernel_is_a_centred_segment():
    k = motion_blur_kernel(6.0, 0.0)
    assert k.sum() == pytest.approx(1.0, abs=1e-6)
    rows = np.nonzero(k.sum(axis=1) > 1e-6)[0]
    cols = np.nonzero(k.sum(axis=0) > 1e-6)[0]
    c = k.shape[0] // 2
    assert list(rows) == [c]
    assert cols.min() == c - 3 and cols.max() == c + 3
    assert np.allclose(k, k[::-1, ::-1])  # symmetric: centred on the mid-exposure image
    img = np.full((20, 20, 3), 77, np.uint8)
    assert motion_blur(img, 0.6 * MIN_BLUR_PX, 0.0) is img  # too short to matter


def test_pose_moved_back_undoes_constant_velocity_and_rate():
    q = euler_to_quat(3.0, -5.0, 40.0)
    w = np.array([0.1, -0.2, 0.8])  # rad/s, NED
    p0, q0 = pose_moved_back((1.0, 2.0, -3.0), q, (2.0, -1.0, 0.5), tuple(w), 0.1)
    assert p0 == pytest.approx((0.8, 2.1, -3.05))
    expected_deg = math.degrees(float(np.linalg.norm(w)) * 0.1)
    assert angle_between_rotations_deg(quat_to_R(q0), quat_to_R(q)) == \
        pytest.approx(expected_deg, rel=1e-6)


def test_truth_log_motion_is_the_velocity_and_yaw_rate_of_its_rows():
    """Rows of a level vehicle flying north at 2 m/s while yawing at 45 deg/s: the motion
    at a time between rows (and past the last one) is that velocity and (0, 0, 45 deg/s)."""
    log = TruthLog(1000)
    step = 10_000_000
    for k in range(5):
        dyn = SimpleNamespace(time_ns=10**9 + k * step, pn=0.02 * k, pe=0.0, pd=-5.0, vn=2.0,
                              ve=0.0, vd=0.0, an=0.0, ae=0.0, ad=-9.81, yaw_deg=0.45 * k)
        log.append(dyn, armed=True, in_air=True, mode=FlightMode.OFFBOARD)  # type: ignore[arg-type]
    for t in (10**9 + 25_000_000, 10**9 + 4 * step + 3_000_000):
        motion = log.motion_at(t, step)
        assert motion is not None
        vel, w = motion
        assert vel == pytest.approx((2.0, 0.0, 0.0))
        assert w == pytest.approx((0.0, 0.0, math.radians(45.0)), abs=1e-6)
    assert log.motion_at(10**9 - 1, step) is None
    assert log.motion_at(10**9 + 4 * step + step + 1, step) is None


# ---------------------------------------------------------------------------------------------
# White balance
# ---------------------------------------------------------------------------------------------
def test_white_balance_gains_change_channel_means_by_the_gains(sim_config, target_config,
                                                                wide_model):
    gains = (0.8, 1.05, 1.25)
    pos, q = (TARGET_NE[0] - 8.0, TARGET_NE[1], -4.0), euler_to_quat(0.0, 0.0, 0.0)
    plain, _ = _world(sim_config, target_config, ground_texture="soil").render(
        wide_model, pos, q, 10**9)
    cast, _ = _world(sim_config, target_config, ground_texture="soil",
                     white_balance_gains_bgr=gains, light_gain=0.9).render(wide_model, pos, q,
                                                                          10**9)
    ok = np.all(plain < 220, axis=2)  # no channel saturates after the gain (x1.125 at most)
    assert ok.mean() > 0.5
    ratio = cast[ok].astype(np.float64).mean(axis=0) / plain[ok].astype(np.float64).mean(axis=0)
    assert ratio == pytest.approx([0.9 * g for g in gains], rel=0.01)


def test_colour_gains_round_and_saturate():
    img = np.array([[[10, 100, 200]]], np.uint8)
    apply_colour_gains(img, (1.26, 0.5, 1.5))
    assert img.tolist() == [[[13, 50, 255]]]


# ---------------------------------------------------------------------------------------------
# Bayer
# ---------------------------------------------------------------------------------------------
def test_bayer_rg_mosaic_puts_red_at_the_top_left():
    img = np.zeros((4, 4, 3), np.uint8)
    img[..., 2] = 200  # red
    img[..., 1] = 100  # green
    img[..., 0] = 50  # blue
    raw = bayer_mosaic(img, "BayerRG")
    assert raw[0::2, 0::2].tolist() == [[200, 200], [200, 200]]
    assert (raw[0::2, 1::2] == 100).all() and (raw[1::2, 0::2] == 100).all()
    assert (raw[1::2, 1::2] == 50).all()
    with pytest.raises(ValueError, match="pattern"):
        bayer_mosaic(img, "BayerXY")


@pytest.mark.parametrize("pattern", ["BayerRG", "BayerBG", "BayerGR", "BayerGB"])
def test_demosaic_keeps_a_flat_colour_and_fringes_an_edge(pattern):
    """A flat colour survives the round trip within 2 grey levels (the genicam driver's
    conversion of the pattern); a sharp black/white edge gets false colours along it."""
    flat = np.empty((32, 48, 3), np.uint8)
    flat[:] = (40, 120, 210)
    out = bayer_round_trip(flat, pattern)
    assert np.abs(out[2:-2, 2:-2].astype(int) - flat[2:-2, 2:-2]).max() <= 2
    assert np.array_equal(out, to_bgr(bayer_mosaic(flat, pattern), 48, 32, f"{pattern}8"))
    edge = np.zeros((32, 48, 3), np.uint8)
    edge[:, 23:] = 255
    out = bayer_round_trip(edge, pattern).astype(int)
    chroma = np.abs(out - out.mean(axis=2, keepdims=True)).max(axis=2)
    assert chroma[4:-4, 21:26].max() >= 40  # colour fringes at the edge
    assert chroma[4:-4, 4:18].max() == 0 and chroma[4:-4, 29:-4].max() == 0


def test_world_bayer_frames_are_demosaiced_renders(sim_config, target_config, wide_model):
    pos, q = (TARGET_NE[0] - 8.0, TARGET_NE[1], -4.0), euler_to_quat(0.0, 0.0, 0.0)
    plain, _ = _world(sim_config, target_config).render(wide_model, pos, q, 10**9)
    bayer, _ = _world(sim_config, target_config, bayer_pattern="BayerRG").render(
        wide_model, pos, q, 10**9)
    assert np.array_equal(bayer, bayer_round_trip(plain, "BayerRG"))
    assert not np.array_equal(bayer, plain)


# ---------------------------------------------------------------------------------------------
# JPEG
# ---------------------------------------------------------------------------------------------
def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b) ** 2))
    return 10.0 * math.log10(255.0**2 / mse)


def test_jpeg_quality_lowers_psnr_monotonically(sim_config, target_config, wide_model):
    pos, q = (TARGET_NE[0] - 8.0, TARGET_NE[1], -4.0), euler_to_quat(0.0, 0.0, 0.0)
    world = _world(sim_config, target_config, noise_sigma=2.0)
    plain, _ = world.render(wide_model, pos, q, 10**9)
    psnr = [_psnr(jpeg_round_trip(plain, k), plain) for k in (95, 85, 70, 50, 30, 10)]
    assert all(a > b for a, b in zip(psnr, psnr[1:])), psnr
    assert psnr[0] > 35.0 and psnr[-1] < 33.0
    jpeg_world = _world(sim_config, target_config, noise_sigma=2.0, jpeg_quality=70)
    frame, _ = jpeg_world.render(wide_model, pos, q, 10**9)
    assert np.array_equal(frame, jpeg_round_trip(plain, 70))


def test_all_effects_render_deterministically(sim_config, target_config, narrow_model):
    knobs = {"motion_blur": True, "bayer_pattern": "BayerRG", "jpeg_quality": 80,
             "white_balance_gains_bgr": (0.9, 1.0, 1.1), "noise_sigma": 2.0}
    pos = (TARGET_NE[0] - 3.0, TARGET_NE[1], -1.8)
    q = euler_to_quat(1.0, -2.0, 3.0)
    start = ((pos[0] - 0.004, pos[1], pos[2]), euler_to_quat(1.0, -2.2, 3.1))
    a, ta = _world(sim_config, target_config, **knobs).render(narrow_model, pos, q, 10**9,
                                                              exposure_start_pose=start)
    b, tb = _world(sim_config, target_config, **knobs).render(narrow_model, pos, q, 10**9,
                                                              exposure_start_pose=start)
    assert np.array_equal(a, b) and ta.motion_blur_px == tb.motion_blur_px != (0.0, 0.0)
