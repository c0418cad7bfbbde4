"""The mission's side of an arm that moves its tool (a manipulator with a workspace).

Everything here is measured, never true: the target is the camera filter's estimate, the
vehicle's pose the telemetry, the tool's position the arm's own read-back. The grasp point is
``grasp.distance_m`` above the target's top-face centre (as the fixed tool's grasp pose).

* :func:`grasp_point_body` puts the grasp point in body FRD (the arm's frame);
* readiness: the grasp point lies inside the workspace shrunk by its margin
  (:meth:`ArmTracking.reachable`), counted over ``grasp.stable_frames`` frames;
* :meth:`ArmTracking.run` commands the tool to the grasp point whenever it is woken (every
  processed frame and every setpoint tick) while tracking is on;
* :meth:`ArmTracking.error_m`: the measured tool-to-target error the gripper waits for;
* :meth:`ArmTracking.footprint_px`: where the tool covers a camera's view (the plane fit
  leaves it out of its models, as the detector's region leaves it out);
* :meth:`ArmTracking.hides`: the tool covers a view of the target (the shape check skips it);
* ``sight``: with a marker on the tool, the cameras' correction of their target estimates
  relative to the tool (:mod:`.tool_sight`).
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable, Sequence

import cv2
import numpy as np
import numpy.typing as npt
from eaglemission.missions.approach_config import ApproachConfig
from eaglemission.missions.log import MissionLog
from eaglemission.missions.tool_sight import ToolSight

from eaglemission import errors
from eaglemission.geometry import CameraModel, quat_to_R
from eaglemission.geometry.workspace import Workspace, offset_from_home
from eaglemission.interfaces import Manipulator
from eaglemission.perception.tool_marker import tool_footprint_px
from eaglemission.types import XYZ, VehicleState

TOOL_RADIUS_M = 0.04
"""How far around its point an arm's tool (gripper and the slide above it) can cover the view,
unless the manipulator says (its optional ``tool_radius_m``)."""
SETTLED_M = 0.002
"""The arm has settled when its read-back is this close to the point last commanded."""


def grasp_point_body(position_ned_m: Sequence[float], attitude_q: Sequence[float],
                     target_ned_m: Sequence[float], grasp_distance_m: float) -> XYZ:
    """The grasp point (``grasp_distance_m`` above the target's top-face centre) in body FRD
    for a vehicle pose."""
    g = np.array([target_ned_m[0], target_ned_m[1], target_ned_m[2] - grasp_distance_m])
    b = quat_to_R(attitude_q).T @ (g - np.asarray(position_ned_m, dtype=np.float64))
    return (float(b[0]), float(b[1]), float(b[2]))


class ArmTracking:
    """Readiness, tracking and the measured error of an arm (loop thread). Built for every
    flight: ``enabled`` only when the manipulator has a workspace (a fixed tool: nothing
    here runs)."""

    @classmethod
    def of(cls, manipulator: Manipulator | None, log: MissionLog, params: ApproachConfig, *,
           state: Callable[[], tuple[VehicleState, XYZ | None]],
           measured: Callable[[], tuple[VehicleState, XYZ | None]] | None = None
           ) -> ArmTracking:
        """For the approach's params: the grasp distance, the command timeout, the setpoint
        rate as the tracking period."""
        return cls(manipulator, log, grasp_distance_m=params.grasp.distance_m,
                   command_s=params.timeouts.command_s,
                   period_s=1.0 / params.guidance.setpoint_rate_hz, state=state,
                   measured=measured)

    def __init__(self, arm: Manipulator | None, log: MissionLog, *, grasp_distance_m: float,
                 command_s: float, period_s: float,
                 state: Callable[[], tuple[VehicleState, XYZ | None]],
                 measured: Callable[[], tuple[VehicleState, XYZ | None]] | None = None
                 ) -> None:
        """``state``: the vehicle's pose and the target to aim at (the best estimate there
        is); ``measured``: the pose and the target as the cameras measured it just now (None
        when they have not), what the gripper waits for; by default ``state``."""
        self.enabled = arm is not None and arm.workspace is not None
        self._arm, self.log = arm, log
        self._workspace = None if arm is None else arm.workspace
        self.grasp_distance_m = grasp_distance_m
        self.command_s, self.period_s = command_s, period_s
        self._state = state
        self._measured = state if measured is None else measured
        self.tracking = False
        self.stopping = False
        self.wake = asyncio.Event()
        self.commands = 0
        self._failed = ""
        self._goal_body: XYZ | None = None
        marker = None if arm is None or not self.enabled else getattr(arm, "marker", None)
        self.marker = marker
        self.tool_radius_m = float(getattr(arm, "tool_radius_m", TOOL_RADIUS_M))
        self.sight = None if marker is None else ToolSight(marker, log)
        """The cameras' sightings of the tool's marker (None: the tool carries none)."""

    @property
    def arm(self) -> Manipulator:
        assert self._arm is not None and self.enabled, "no arm (a fixed tool)"
        return self._arm

    @property
    def workspace(self) -> Workspace:
        assert self._workspace is not None, "no arm (a fixed tool)"
        return self._workspace

    def follow(self, tracks: bool) -> None:
        """A state change: track while the state's policy says so (woken now)."""
        self.tracking = self.enabled and tracks
        self._goal_body = None
        self.wake.set()

    def hold(self) -> None:
        """The gripper closes: stop tracking (the arm holds what it grasped)."""
        self.tracking = False

    def settled(self) -> bool:
        """The tool (its read-back) is at the point last commanded since tracking started
        (clamped to the workspace): it has stopped moving towards the target."""
        goal = self._goal_body
        if goal is None:
            return False
        tool = self.arm.report().tool_body_m
        return all(math.isfinite(v) for v in tool) and math.dist(tool, goal) <= SETTLED_M

    def measured_error(self) -> float | None:
        """The measured tool-to-target error now (None: no fresh camera measurement of the
        target, or no read-back)."""
        vs, target = self._measured()
        return None if target is None else self.error_m(vs, target)

    def goal_body(self, vs: VehicleState, target_ned_m: XYZ) -> XYZ:
        return grasp_point_body(vs.position_ned_m, vs.attitude_q, target_ned_m,
                                self.grasp_distance_m)

    def reachable(self, vs: VehicleState, target_ned_m: XYZ) -> bool:
        """The grasp point lies inside the workspace shrunk by its margin."""
        off = offset_from_home(self.goal_body(vs, target_ned_m), self.arm.home_m)
        return self.workspace.offset_inside(off, self.workspace.margin_m)

    def footprint_px(self, model: CameraModel, radius_m: float | None = None
                     ) -> npt.NDArray[np.float32] | None:
        """The convex image polygon where the tool covers ``model``'s view: a cube of
        ``radius_m`` (default ``tool_radius_m``) around it and its marker's plate; None: not in
        view, or no read-back. The tool is where the camera sees it: the read-back less the
        camera's marker correction (its calibration error at the tool) when it has one."""
        tool = self.arm.report().tool_body_m
        if not all(math.isfinite(v) for v in tool):
            return None
        c = None if self.sight is None else self.sight.correction_m(model.camera_id)
        if c is not None:
            tool = (tool[0] - c[0], tool[1] - c[1], tool[2] - c[2])
        r = self.tool_radius_m if radius_m is None else radius_m
        return tool_footprint_px(model, tool, r, self.marker)

    def _covering_px(self, model: CameraModel) -> npt.NDArray[np.float32] | None:
        """The footprint :meth:`hides` and :meth:`covers` judge by: at least
        :data:`TOOL_RADIUS_M` around the tool (the slide above the gripper too)."""
        return self.footprint_px(model, max(self.tool_radius_m, TOOL_RADIUS_M))

    def hides(self, model: CameraModel, corners_px: npt.ArrayLike) -> bool:
        """The tool's footprint, at least :data:`TOOL_RADIUS_M` around the tool (the slide
        above the gripper too), overlaps the rectangle around a detection's corners: that view
        of the target is partly the arm's (its outline is not the target's shape)."""
        foot = self._covering_px(model)
        if foot is None:
            return False
        c = np.asarray(corners_px, dtype=np.float64).reshape(-1, 2)
        lo, hi = foot.min(axis=0), foot.max(axis=0)
        return bool(lo[0] <= c[:, 0].max() and c[:, 0].min() <= hi[0]
                    and lo[1] <= c[:, 1].max() and c[:, 1].min() <= hi[1])

    def covers(self, model: CameraModel, point_px: npt.ArrayLike) -> bool:
        """The tool's footprint, at least :data:`TOOL_RADIUS_M` around the tool, covers the
        image point ``point_px``: what lies there beyond the tool is out of ``model``'s sight."""
        p = np.asarray(point_px, dtype=np.float64).reshape(-1)
        foot = self._covering_px(model)
        if foot is None or not np.isfinite(p).all():
            return False
        return bool(cv2.pointPolygonTest(foot.reshape(-1, 1, 2).astype(np.float32),
                                         (float(p[0]), float(p[1])), False) >= 0)

    def error_m(self, vs: VehicleState, target_ned_m: XYZ) -> float | None:
        """Measured distance from the tool (its read-back) to the grasp point; None when the
        read-back or the pose is not finite."""
        tool = self.arm.report().tool_body_m
        goal = self.goal_body(vs, target_ned_m)
        if not all(math.isfinite(v) for v in (*tool, *goal)):
            return None
        return math.dist(tool, goal)

    async def run(self) -> None:
        """Command the tool to the grasp point while ``tracking``: on every wake and at least
        every ``period_s``. A refused or late command is logged (once per kind) and retried
        on the next wake. Returns at once without an arm."""
        while self.enabled and not self.stopping:
            try:
                await asyncio.wait_for(self.wake.wait(), timeout=self.period_s)
            except TimeoutError:
                pass
            self.wake.clear()
            if self.sight is not None:
                report = self.arm.report()
                self.sight.record(report.timestamp_ns, report.tool_body_m)
            if not self.tracking:
                continue
            vs, target = self._state()
            if target is None or not all(math.isfinite(v) for v in (*vs.position_ned_m,
                                                                      *vs.attitude_q)):
                continue
            goal = self.goal_body(vs, target)
            try:
                await self.arm.move_to(goal, timeout_s=self.command_s)
                self.commands += 1
                home = self.arm.home_m
                off = self.workspace.clamp_offset(offset_from_home(goal, home))
                self._goal_body = (home[0] + off[0], home[1] + off[1], home[2] + off[2])
            except (errors.EagleMissionError, TimeoutError) as exc:
                text = f"{type(exc).__name__}: {exc}"
                if text != self._failed:
                    self._failed = text
                    self.log.write("fault_detected", what="arm_command", text=text,
                                   response="retried on the next frame")
