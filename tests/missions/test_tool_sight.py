"""The cameras see the arm's tool by its marker: where it is, and the correction that cancels
their mount error for points near the tool (``missions/tool_sight.py``)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from eaglemission.lab.world.render import SyntheticWorld
from eaglemission.lab.world.synthetic import SyntheticWorldConfig
from eaglemission.missions.log import MissionLog
from eaglemission.missions.tool_sight import MIN_SIGHTINGS, ToolSight

from eaglemission.config import load_config
from eaglemission.geometry import CameraModel, euler_to_quat
from eaglemission.geometry.tool_marker import ToolMarker
from eaglemission.perception.tool_marker import (
    find_marker,
    marker_centre_cam,
    predicted_box_px,
    tool_body_from_marker,
    tool_footprint_px,
)
from eaglemission.types import XYZ, Frame

HOME = (0.45, 0.0, 0.35)
POSE = ((0.0, 0.0, -0.675), euler_to_quat(0.0, 0.0, 0.0))
T_NS = 1_000_000_000


def _world(**sim: object) -> tuple[SyntheticWorld, CameraModel]:
    cfg = load_config()
    world = SyntheticWorld(SyntheticWorldConfig(seed=1, target_north_m=0.5, **sim), cfg.target)
    return world, cfg.cameras.wide.to_model("wide")


def _frame(world: SyntheticWorld, model: CameraModel, tool: XYZ, t_ns: int = T_NS) -> Frame:
    image, _ = world.render(model, *POSE, t_ns, tool_body_m=tool, tool_marker=ToolMarker())
    return Frame(image, t_ns, "wide", t_ns // 10**6)


def _seen_by(true: CameraModel, believed: CameraModel, point_body: XYZ) -> XYZ:
    """Where a camera with a perfect range but the ``believed`` mount puts a body point."""
    p = np.asarray(point_body) - np.asarray(true.mount.lever_arm_m)
    cam = true.mount.R_body_optical.T @ p
    b = np.asarray(believed.mount.lever_arm_m) + believed.mount.R_body_optical @ cam
    return (float(b[0]), float(b[1]), float(b[2]))


def test_the_marker_in_a_rendered_frame_gives_the_tool_within_millimetres() -> None:
    world, model = _world(noise_sigma=2.0, motion_blur=True, bayer_pattern="BayerRG",
                          jpeg_quality=75)
    marker = ToolMarker()
    tool = (0.50, -0.04, 0.38)
    frame = _frame(world, model, tool)
    corners = find_marker(np.asarray(frame.image), marker,
                          predicted_box_px(marker, model, tool))
    assert corners is not None
    centre = marker_centre_cam(corners, marker, model)
    assert centre is not None
    assert math.dist(tool_body_from_marker(centre, marker, model), tool) < 0.004


def test_the_correction_cancels_a_mount_error_near_the_tool() -> None:
    world, model = _world(noise_sigma=2.0, mount_error_deg=2.0)
    true = world.true_camera(model)
    sight = ToolSight(ToolMarker(), MissionLog(None, now_ns=lambda: 0))
    sight.record(T_NS - 10**8, HOME)
    sight.record(T_NS + 10**8, HOME)
    for k in range(MIN_SIGHTINGS):
        assert sight.correction_m("wide") is None
        assert sight.observe(_frame(world, model, HOME, T_NS + k), model) is not None
    c = sight.correction_m("wide")
    assert c is not None and sight.correction_m("narrow") is None
    # the grasp point, 17.5 cm under the tool at home, as this camera sees it
    grasp = (HOME[0], HOME[1], HOME[2] + 0.175)
    seen = _seen_by(true, model, grasp)
    before = math.dist(seen, grasp)
    corrected = sight.corrected_ned_m("wide", POSE[1], seen)  # level, north: NED = FRD
    after = math.dist(corrected, grasp)
    assert before > 0.012, "the drawn mount error is too small to test"
    # left: the mount error over the 17.5 cm between the tool and the point (2 deg: ~6 mm)
    assert after < 0.45 * before and after < 0.007, (before, after)


def test_a_marker_seen_far_from_the_read_back_is_not_a_sighting() -> None:
    world, model = _world(noise_sigma=0.0)
    sight = ToolSight(ToolMarker(), MissionLog(None, now_ns=lambda: 0),
                      max_correction_m=0.02)
    moved = (HOME[0] + 0.03, HOME[1], HOME[2])  # the arm is 3 cm from where it says it is
    sight.record(T_NS - 10**8, HOME)
    sight.record(T_NS + 10**8, HOME)
    assert sight.observe(_frame(world, model, moved), model) is None
    assert sight.observe(_frame(world, model, HOME), model) is not None


def test_the_read_back_is_interpolated_at_the_frame_time() -> None:
    sight = ToolSight(ToolMarker(), MissionLog(None, now_ns=lambda: 0))
    assert sight.readback_at(T_NS) is None
    sight.record(T_NS, (0.4, 0.0, 0.3))
    sight.record(T_NS + 10**8, (0.5, 0.1, 0.3))
    assert sight.readback_at(T_NS + 5 * 10**7) == pytest.approx((0.45, 0.05, 0.3))
    assert sight.readback_at(T_NS + 2 * 10**8) is None  # newer than the read-back: unknown


@pytest.mark.parametrize("tool", [(0.50, -0.04, 0.38), (0.45, 0.0, 0.35), (0.40, 0.08, 0.30)])
def test_the_tools_footprint_covers_the_arm_the_camera_sees(tool: XYZ) -> None:
    """What the plane fit leaves out (missions/arm.py): the cube around the tool point and the
    marker's plate hold the drawn gripper and plate (all but the top of the slide above)."""
    world, model = _world()
    with_arm, _ = world.render(model, *POSE, T_NS, tool_body_m=tool, tool_marker=ToolMarker())
    without, _ = world.render(model, *POSE, T_NS)
    drawn = np.argwhere(np.abs(with_arm.astype(int) - without.astype(int)).max(axis=2) > 0)
    foot = tool_footprint_px(model, tool, 0.04, ToolMarker())
    assert foot is not None and len(drawn) > 1000
    inside = [cv2.pointPolygonTest(foot, (float(u), float(v)), False) >= 0 for v, u in drawn]
    assert np.mean(inside) > 0.85
    assert cv2.contourArea(foot) < 4 * len(drawn)


def test_a_tool_behind_the_camera_has_no_footprint() -> None:
    _, model = _world()
    behind = tuple(np.asarray(model.mount.lever_arm_m) - 0.05 * model.mount.R_body_optical[:, 2])
    assert tool_footprint_px(model, behind, 0.04) is None
