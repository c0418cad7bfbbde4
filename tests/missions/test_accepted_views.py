"""What the final approach takes from a view depends on whether the target filter accepted it:
the heading that constrains the cut views to come and the fix an arm's gripper waits for come
only from accepted views (a tracker gone astray, another object: measured in the gusts
campaign, where such a view's heading put every later cut view 10 cm off)."""

from __future__ import annotations

import numpy as np
import pytest
from eaglemission.missions.approach import POLICIES, S
from eaglemission.missions.perception import FitHint, Measurement, Provenance
from eaglemission.missions.tracking import (
    ARM_FIX_MAX_AGE_S,
    ARM_FIX_MAX_FIT_COST,
    GRIPPER_MIN_FIXES,
    TargetTracking,
)
from mission_helpers import target_tracking

from eaglemission.geometry import euler_to_quat
from eaglemission.types import XYZ, Frame, TargetEstimate, VehicleState

TARGET = (20.0, 1.0, -0.15)
VEHICLE = (19.55, 1.0, -0.67)


def _view(t: TargetTracking, t_ns: int, position_ned_m: XYZ, yaw_deg: float, *,
          kept: bool = False, fit_cost: float | None = 0.02) -> None:
    """One complete close view of the narrow camera in FINE_DESCENT: a plane fit at
    ``position_ned_m`` whose outline gives the heading ``yaw_deg``."""
    vs = VehicleState(t_ns, VEHICLE, (0.0, 0.0, 0.0), euler_to_quat(0, 0, 0), in_air=True,
                      armed=True)
    frame = Frame(np.zeros((4, 4, 3), np.uint8), t_ns, "narrow", t_ns // 10**8)
    est = TargetEstimate(position_ned_m, (0.0, 0.0, 0.5), t_ns, "narrow", "rpnp+fit:box",
                         std_m=0.02, fit_cost=fit_cost)
    hint = FitHint(yaw_deg, "box", 0.95, yaw_deg, 3.0)
    meas = Measurement("narrow", frame, vs, "fine", None, 1, False, est, Provenance.FINE,
                       True, None, hint, 1.0, kept=kept)
    t.apply(meas, POLICIES[S.FINE_DESCENT], vs, t_ns, t_ns * 1e-9)


def test_a_heading_and_a_fix_come_only_from_views_the_filter_accepted() -> None:
    t = target_tracking()
    t.filter.update(TARGET, 0.01, 10**9)
    _view(t, 11 * 10**8, TARGET, 27.0)
    assert t.fit_hint is not None and t.fit_hint.yaw_deg == 27.0
    assert t.fresh_fix_ned_m(11 * 10**8) is not None

    far = (TARGET[0], TARGET[1] + 0.45, TARGET[2])  # 45 cm off a target known to 1 cm
    _view(t, 12 * 10**8, far, 100.0)
    assert t.fit_hint.yaw_deg == 27.0, "a refused view changed the heading"
    assert t.latest_fix is not None and t.latest_fix[1] != far


def test_the_gripper_waits_for_a_fresh_fix_while_the_arm_aims_at_the_filter() -> None:
    t = target_tracking()
    t.filter.update(TARGET, 0.01, 10**9)
    _view(t, 11 * 10**8, TARGET, 27.0)
    stale_ns = 11 * 10**8 + int((ARM_FIX_MAX_AGE_S + 0.05) * 1e9)
    assert t.fresh_fix_ned_m(11 * 10**8 + 10**8) is not None
    assert t.fresh_fix_ned_m(stale_ns) is None  # what the gripper's error is measured on
    assert t.arm_target_ned_m(stale_ns) is not None  # the arm still has somewhere to aim


def test_the_arm_aims_at_the_median_of_the_last_fixes_and_the_gripper_needs_three() -> None:
    t = target_tracking()
    t.filter.update(TARGET, 0.05, 10**9)
    swings = (0.0, 0.04, -0.01)  # a cut view's range swings from frame to frame
    for k, dn in enumerate(swings):
        now = 11 * 10**8 + k * 125_000_000
        _view(t, now, (TARGET[0] + dn, TARGET[1], TARGET[2]), 27.0)
        three = t.fresh_fix_ned_m(now, min_fixes=GRIPPER_MIN_FIXES)
        assert (three is None) == (k < 2)
    aim = t.fresh_fix_ned_m(now)
    assert aim is not None and aim[0] == pytest.approx(TARGET[0], abs=1e-9)  # not the 4 cm swing



def test_a_fit_that_explains_its_detection_poorly_feeds_the_filter_not_the_arm() -> None:
    t = target_tracking()
    t.filter.update(TARGET, 0.01, 10**9)
    near = (TARGET[0] + 0.005, TARGET[1], TARGET[2])
    _view(t, 11 * 10**8, near, 27.0, fit_cost=ARM_FIX_MAX_FIT_COST + 0.1)
    assert t.latest_fix is None
    assert t.filter.state(11 * 10**8) is not None
    _view(t, 12 * 10**8, near, 27.0, fit_cost=ARM_FIX_MAX_FIT_COST - 0.1)
    assert t.latest_fix is not None and t.latest_fix[1] == near
    _view(t, 13 * 10**8, near, 27.0, fit_cost=None)  # not a plane fit (fitter off)
    assert t.latest_fix[0] == 13 * 10**8


@pytest.mark.parametrize("behind_tool", [True, False])
def test_a_target_behind_the_tool_is_out_of_sight_not_lost(behind_tool: bool) -> None:
    """In the wide camera the target lies on the line of sight through the arm's tool (as in a
    descent towards it): the mission does not expect to see it, so no loss is declared while
    the tool hides it; a metre aside it is expected in view."""
    from eaglemission.lab.manipulators.simulated_arm import SimulatedArm, SimulatedArmConfig
    from eaglemission.missions.arm import ArmTracking
    from eaglemission.missions.log import MissionLog
    from eaglemission.missions.views import project_target

    from eaglemission.clock import ManualClock
    from eaglemission.geometry import camera_pose_ned

    t = target_tracking()
    home = t.cfg.tool_point_m
    vs = VehicleState(10**9, (10.0, 1.0, -1.6), (0.0, 0.0, 0.0), euler_to_quat(0, 0, 0),
                      in_air=True, armed=True)
    arm = SimulatedArm(SimulatedArmConfig(), clock=ManualClock(), tool_point_m=home)
    t.arm = ArmTracking(arm, MissionLog(None, now_ns=lambda: 0), grasp_distance_m=0.175,
                        command_s=1.0, period_s=0.05, state=lambda: (vs, TARGET))
    wide = t.models["wide"]
    cam = np.asarray(camera_pose_ned(wide, vs.position_ned_m, vs.attitude_q).t)
    tool = np.asarray(vs.position_ned_m) + np.asarray(home)  # level, heading north
    ray = tool - cam
    k = (-0.15 - cam[2]) / ray[2]  # on to the target's top, 0.15 m above the ground
    target = tuple(float(x) for x in cam + k * ray)
    if not behind_tool:
        target = (target[0], target[1] + 1.0, target[2])
    assert np.isfinite(project_target(wide, vs, target)).all()
    t.choice.fine_camera = "wide"
    t.filter.update(target, 0.01, 10**9)
    frame = Frame(np.zeros((4, 4, 3), np.uint8), 10**9, "wide", 10)
    est = TargetEstimate(target, (0.0, 0.0, 2.0), 10**9, "wide", "rpnp", std_m=0.02)
    meas = Measurement("wide", frame, vs, "fine", None, 1, False, est, Provenance.FINE,
                       False, None, None, 1.0)
    t.apply(meas, POLICIES[S.FINE_DESCENT], vs, 10**9, 1.0)
    assert t.choice.expected_visible is not behind_tool
