"""The target as the mission tracks it, fed with perception's measurements (loop thread).

:class:`TargetTracking` owns the position filter, the plane filter, the wide camera's
confirmation, the fine approach's counters, the grasp-stability window and the camera choice.
:meth:`TargetTracking.apply` takes one :class:`~eaglemission.missions.perception.Measurement`
and the current state's policy; what it may do in that state is the policy's data.
"""

from __future__ import annotations

import collections
import math
import statistics
from dataclasses import dataclass

import numpy as np
from eaglemission.missions import guidance as gd
from eaglemission.missions.approach import StatePolicy
from eaglemission.missions.approach_config import (
    GraspConfig,
    PerceptionConfig,
    PlaneConfig,
    TrackingConfig,
)
from eaglemission.missions.arm import ArmTracking
from eaglemission.missions.log import MissionLog
from eaglemission.missions.perception import FitHint, Measurement
from eaglemission.missions.target_state import (
    PlaneOffsetFilter,
    PlaneState,
    TargetFilter,
    confirmation,
    grasp_progress,
    plane_down_m,
    vertical_reference,
)
from eaglemission.missions.views import CameraChoice, ChoiceParams, project_target

from eaglemission.config import MissionFile
from eaglemission.geometry import CameraModel, camera_pose_ned, down_axis_cos_tilt
from eaglemission.names import CAMERA_NARROW, CAMERA_WIDE
from eaglemission.types import XYZ, VehicleState

ARM_FIX_MAX_AGE_S = 0.3
"""An arm aims at the latest fine estimates while the newest is at most this old (two or three
frames at the default processing rate), else at the filter's position."""
FIX_WINDOW_S = 0.6
"""The arm's aim is the median of the fine estimates of this last stretch (a cut view's range
swings by centimetres from frame to frame; the target does not move)."""
GRIPPER_MIN_FIXES = 3
"""The gripper's measured error needs this many fine estimates in the window."""
ARM_FIX_MAX_FIT_COST = 0.25
"""A fine estimate whose plane fit explains its detection worse than this (the fit's ``cost``;
refused above ``perception.plane_fit_max_cost``) still feeds the filter but not the arm: at the
grasp pose such fits were 3.9 cm off (median) against 1.6-1.9 cm for the others, in the gusts
campaign's misses (docs/manipulators.md)."""


@dataclass(frozen=True, slots=True)
class Applied:
    """What one measurement changed, for the runner: a fresh estimate reached the filter
    (wake the setpoints), the fine camera switched."""

    fresh: bool
    switched_to: str | None


class TargetTracking:
    """The mission's knowledge of the target (see the module docstring). Its parameters:
    ``tracking`` (confirmation, filter, loss, candidate rejection), ``perception`` (the camera
    hand-over, the estimates' range), ``plane`` and ``grasp`` (the stability count)."""

    def __init__(self, cfg: MissionFile, models: dict[str, CameraModel], log: MissionLog, *,
                 tracking: TrackingConfig, perception: PerceptionConfig, plane: PlaneConfig,
                 grasp: GraspConfig) -> None:
        self.cfg = cfg
        self.p, self.perception_p, self.plane_p, self.grasp_p = tracking, perception, plane, grasp
        self.models = models
        self.log = log
        self.filter = TargetFilter(tracking.filter)
        self.plane = PlaneOffsetFilter(plane.altitude_std_m, plane.drift_mps)
        self.choice = CameraChoice(models[CAMERA_WIDE], models[CAMERA_NARROW],
                                   cfg.target.length_m, cfg.target.width_m, ChoiceParams(
                                       perception.narrow_warm_margin_px,
                                       perception.narrow_max_fill,
                                       perception.narrow_miss_switch_s,
                                       perception.image_border_px))
        self.confirm: list[XYZ] = []
        self.coarse_std_m = 1.0
        self.fine_estimates = 0
        self.grasp_window: list[tuple[float, float]] = []
        self.grasp_count = 0
        self.fit_hint: FitHint | None = None
        self.last_target: XYZ | None = None
        self.tool_errors: tuple[float, float] | None = None
        self._last_range_m: float | None = None
        self.losses: dict[tuple[float, float], int] = {}
        """Times the target was lost near each place (north, east m of the first loss there)."""
        self.last_place: tuple[float, float] | None = None
        """Where the latest loss was counted (None: the target was never tracked)."""
        self.misshapen: dict[tuple[float, float], str] = {}
        """Places of candidates rejected by the shape check (the reason)."""
        self.headings_deg: list[float] = []
        """Fitted headings of the tracked candidate's complete close-range views."""
        self.silhouettes: list[float] = []
        """Their silhouette IoUs (:func:`~eaglemission.estimators.top_plane.silhouette_iou`)."""
        self.drops = 0
        """How often the mission dropped its target (lost, rejected): perception's keepers let
        it go when this changes."""
        self.fixes: collections.deque[tuple[int, XYZ]] = collections.deque(maxlen=32)
        """(frame stamp, position) of the latest fine estimate the filter accepted (with an arm
        whose tool the camera sees, corrected relative to the tool: :mod:`.tool_sight`)."""
        self.arm: ArmTracking | None = None
        """An arm that moves the tool: readiness is the grasp point inside its workspace
        (:mod:`.arm`); None: the fixed tool's stability count."""

    # -- state entries -------------------------------------------------------------------------
    def seed_filter(self, now_ns: int) -> None:
        """The coarse approach starts from the confirmed wide positions."""
        self.filter.reset()
        for p in self.confirm:
            self.filter.update(p, self.coarse_std_m, now_ns)
        self.choice.reset_coarse()

    def start_fine(self) -> None:
        self.choice.reset_fine()
        self.fine_estimates = 0
        self.grasp_count = 0
        self.grasp_window = []
        self.fit_hint = None
        self.headings_deg = []
        self.silhouettes = []

    def count_loss(self) -> tuple[float, float] | None:
        """The target was lost: count it at the place it was last tracked (losses within
        ``reacquire_radius_m + confirm_radius_m`` count as one place, as reacquisition does),
        and log it. The ``max_losses``-th loss at a place rejects it (``just_rejected``).
        Returns the place, None when the target was never tracked."""
        self.headings_deg = []
        self.silhouettes = []
        self.drops += 1
        if self.last_target is None:
            self.last_place = None
            return None
        place = self._place_of(self.last_target)
        n = self.losses[place] = self.losses.get(place, 0) + 1
        self.last_place = place
        times = "1 time" if n == 1 else f"{n} times"
        self.log.write("event", source="mission",
                       text=f"target lost {times} near north {place[0]:.1f} m east "
                       f"{place[1]:.1f} m" + (": candidate rejected, its estimates are ignored"
                                              if self.just_rejected else ""))
        return place

    @property
    def last_losses(self) -> int:
        """Losses counted at the place of the latest one (0: the target was never tracked)."""
        return 0 if self.last_place is None else self.losses[self.last_place]

    def _place_of(self, position_ned_m: XYZ) -> tuple[float, float]:
        """The counted place within ``reacquire_radius_m + confirm_radius_m`` (as reacquisition
        searches), else the position itself."""
        here = (position_ned_m[0], position_ned_m[1])
        near = self.p.reacquire_radius_m + self.p.confirm_radius_m
        return next((q for q in self.losses if math.dist(q, here) <= near), here)

    def _rejects(self, place: tuple[float, float]) -> bool:
        return self.losses[place] >= self.p.max_losses or place in self.misshapen

    @property
    def just_rejected(self) -> bool:
        """The latest loss was at a rejected place: the ``max_losses``-th there, or at a
        candidate of the wrong shape (:meth:`check_shape`)."""
        return self.last_place is not None and self._rejects(self.last_place)

    @property
    def rejected(self) -> list[tuple[float, float]]:
        """The places of rejected candidates."""
        return [q for q in self.losses if self._rejects(q)]

    def losses_at(self, place: tuple[float, float]) -> int:
        return self.losses[place]

    def is_rejected(self, position_ned_m: XYZ) -> bool:
        """An estimate within ``confirm_radius_m`` of a rejected candidate's place."""
        radius = self.p.confirm_radius_m
        return any(math.dist(q, position_ned_m[:2]) <= radius and self._rejects(q)
                   for q in self.losses)

    def check_shape(self, yaw_deg: float, position_ned_m: XYZ, camera: str = "",
                    silhouette_iou: float | None = None,
                    silhouette_yaw_deg: float | None = None) -> None:
        """One complete close-range view of the candidate tracked in the fine approach: its
        fitted heading and how well the target's shape explains its region's outline
        (``silhouette_iou``). The candidate is rejected at its place, and its track dropped,
        when the median silhouette IoU of its views falls below ``shape.min_iou`` once
        ``shape.min_views`` are in: a box of the target's colour and top area but another
        shape. The loss that follows applies ``on_target_lost`` at once. Each view is logged
        (``heading``), the check on or off."""
        shape = self.p.shape
        self.headings_deg.append(yaw_deg)
        if silhouette_iou is not None:
            self.silhouettes.append(silhouette_iou)
        n = len(self.headings_deg)
        iou = statistics.median(self.silhouettes) \
            if len(self.silhouettes) >= shape.min_views else None
        self.log.write("heading", camera=camera, yaw_deg=round(yaw_deg, 1), views=n,
                       silhouette_iou=None if silhouette_iou is None
                       else round(silhouette_iou, 4),
                       silhouette_yaw_deg=None if silhouette_yaw_deg is None
                       else round(silhouette_yaw_deg, 1),
                       median_iou=None if iou is None else round(iou, 4))
        if iou is None or shape.min_iou is None or iou >= shape.min_iou:
            return
        why = (f"its outline does not fit the target's shape (median silhouette IoU "
               f"{iou:.2f} over {len(self.silhouettes)} views < tracking.shape.min_iou="
               f"{shape.min_iou:g})")
        place = self._place_of(position_ned_m)
        self.losses.setdefault(place, 0)
        self.misshapen[place] = why
        self.headings_deg = []
        self.silhouettes = []
        self.filter.reset()
        self.drops += 1
        self.log.write("event", source="mission",
                       text=f"candidate near north {place[0]:.1f} m east {place[1]:.1f} m "
                       f"rejected: {why}")

    # -- queries -------------------------------------------------------------------------------
    def plane_state(self, t_ns: int | None = None) -> PlaneState:
        return PlaneState(self.plane.offset_m, self.plane.std_m(t_ns))

    def target_ned_m(self, t_ns: int) -> XYZ | None:
        filt = self.filter.state(t_ns)
        return None if filt is None else filt.position_ned_m

    @property
    def latest_fix(self) -> tuple[int, XYZ] | None:
        """(frame stamp, position) of the latest fine estimate the filter accepted (with an arm
        whose tool the camera sees, corrected relative to the tool: :mod:`.tool_sight`)."""
        return max(self.fixes, key=lambda f: f[0]) if self.fixes else None

    def fresh_fix_ned_m(self, t_ns: int, min_fixes: int = 1) -> XYZ | None:
        """While the latest fine estimate the filter accepted is at most
        :data:`ARM_FIX_MAX_AGE_S` old (the vehicle's position estimate drifts little since that
        frame), the median, axis by axis, of those of the last :data:`FIX_WINDOW_S` (at least
        ``min_fixes`` of them); None otherwise: the cameras have not measured the target just
        now."""
        fix = self.latest_fix
        if fix is None or not 0 <= (t_ns - fix[0]) * 1e-9 <= ARM_FIX_MAX_AGE_S:
            return None
        since = fix[0] - int(FIX_WINDOW_S * 1e9)
        recent = [p for t, p in self.fixes if t >= since]
        if len(recent) < min_fixes:
            return None
        m = np.median(np.asarray(recent), axis=0)
        return (float(m[0]), float(m[1]), float(m[2]))

    def arm_target_ned_m(self, t_ns: int) -> XYZ | None:
        """What an arm aims at: the fresh fix (:meth:`fresh_fix_ned_m`), else the filter's
        position (None: no target)."""
        return self.fresh_fix_ned_m(t_ns) or self.target_ned_m(t_ns)

    # -- measurements --------------------------------------------------------------------------
    def apply(self, meas: Measurement, pol: StatePolicy, vehicle_now: VehicleState,
              now_ns: int, t_s: float) -> Applied:
        """One processed frame: log it and feed its estimate to the confirmation, the filter,
        the camera choice and the grasp check."""
        cam_id, frame, state = meas.camera_id, meas.frame, meas.state
        p, pp = self.p, self.perception_p
        det = meas.detection
        self.log.write("detection", camera=cam_id, seq=frame.seq, frame_t_ns=frame.timestamp_ns,
                       n=meas.raw_detections, used=det is not None,
                       center_px=None if det is None else det.center_px,
                       corners_px=None if det is None else det.corners_px,
                       score=None if det is None else det.score,
                       perception_ms=round(meas.perception_ms, 3),
                       colour_track=meas.colour_tracked, detector_ran=meas.detector_ran,
                       kept=meas.kept, from_tracker=meas.from_tracker)
        if cam_id == CAMERA_NARROW:
            self.choice.narrow_result(meas.fine_measurement or meas.role is None, now_ns)
        est = meas.estimate
        if est is None and meas.failure is not None:
            self.log.write("estimate", camera=cam_id, ok=False, reason=meas.failure)
        if est is not None and math.hypot(*est.position_cam_m) < pp.min_estimate_range_m:
            self.log.write("estimate", camera=cam_id, ok=False,
                           reason=f"closer than min_estimate_range_m: {est.source}")
            est = None
        if est is not None:
            self.log.write("estimate", camera=cam_id, ok=True, source=est.source,
                           provenance=None if meas.provenance is None else meas.provenance.value,
                           position_ned_m=est.position_ned_m, std_m=est.std_m,
                           position_cam_m=est.position_cam_m)
        model = self.models[cam_id]
        cam_t = None if state is None else tuple(
            camera_pose_ned(model, state.position_ned_m, state.attitude_q).t)
        plane_m = plane_down_m(self.cfg.target.height_m, self.plane_state())
        fresh = False
        if cam_id == CAMERA_WIDE and pol.confirms:
            pos = None if est is None else vertical_reference(
                est.position_ned_m, cam_t, plane_m, pp.vertical_reference,
                full_3d_range_m=pp.full_3d_range_m)
            near_last = (pos is None or not pol.reacquires or self.last_target is None
                         or math.dist(pos[:2], self.last_target[:2])
                         <= p.reacquire_radius_m + p.confirm_radius_m)
            if pos is not None and self.is_rejected(pos):
                pass  # a rejected candidate neither confirms nor breaks a confirmation
            else:
                self.confirm = confirmation(self.confirm, pos, radius_m=p.confirm_radius_m,
                                            accept=near_last)
            if est is not None:
                self.coarse_std_m = max(est.std_m, 0.2)
        elif est is not None and pol.tracks:
            pos = vertical_reference(est.position_ned_m, cam_t, plane_m, pp.vertical_reference,
                                     full_3d=meas.full_3d, full_3d_range_m=pp.full_3d_range_m)
            if self.is_rejected(pos):
                accepted, why = False, "at a rejected candidate (mission.params.tracking.max_losses)"
            else:
                accepted = self.filter.update(pos, est.std_m, frame.timestamp_ns,
                                              allow_reset=pol.filter_may_reset)
                why = "outside the target filter's gate"
            if not accepted:
                self.log.write("fault_detected", what="estimate_rejected", camera=cam_id,
                               text=why, response="measurement ignored")
            if accepted and meas.role == "fine" and meas.fine_measurement:
                self.fine_estimates += 1
            if accepted and meas.role == "fine" and not (
                    est.fit_cost is not None and est.fit_cost > ARM_FIX_MAX_FIT_COST):
                sight = None if self.arm is None else self.arm.sight
                self.fixes.append((frame.timestamp_ns, pos if sight is None or state is None
                                   else sight.corrected_ned_m(cam_id, state.attitude_q, pos)))
            if accepted and meas.fit_hint is not None:
                # the heading for the cut views to come, from a view of the target: a view
                # the filter refused (another object, a tracker gone astray) teaches nothing
                self.fit_hint = meas.fit_hint
            if (accepted and meas.fit_hint is not None and pol.camera_choice == "fine"
                    and not (self.arm is not None and det is not None
                             and self.arm.hides(model, det.corners_px))):
                self.check_shape(meas.fit_hint.yaw_deg, pos, cam_id,
                                 meas.fit_hint.silhouette_iou, meas.fit_hint.silhouette_yaw_deg)
            fresh = accepted
        filt = self.filter.state(frame.timestamp_ns)
        switched = None
        if filt is not None and state is not None:
            self.last_target = filt.position_ned_m
            if pol.camera_choice == "coarse":
                self.choice.update_coarse(state, filt.position_ned_m, cam_id, det)
            elif pol.camera_choice == "fine":
                switched = self.choice.update_fine(state, filt.position_ned_m, cam_id, now_ns)
                if self.arm is not None and self.choice.expected_visible:
                    # behind the tool the target is out of sight, not lost
                    fine = self.models[self.choice.fine_camera]
                    self.choice.expected_visible = not self.arm.covers(
                        fine, project_target(fine, state, filt.position_ned_m))
                if switched is not None:
                    self.log.write("event", source="mission",
                                   text=f"fine approach image source -> {switched}")
        if pol.tool_errors and filt is not None:
            self._check_grasp(vehicle_now, filt.position_ned_m, counting=pol.grasp_check)
        return Applied(fresh, switched)

    def _check_grasp(self, vs: VehicleState, target_ned_m: XYZ, *, counting: bool) -> None:
        """The mission's own tool-point errors; with ``counting``, the grasp-stability count
        (it stays at 0 at the standoff). A state without a finite pose (telemetry gone
        wrong) is skipped: it neither counts nor breaks the count."""
        if not all(math.isfinite(v) for v in (*vs.position_ned_m, *vs.attitude_q,
                                              *vs.velocity_ned_mps)):
            return
        tool = gd.tool_point_ned(vs.position_ned_m, vs.attitude_q, self.cfg.tool_point_m)
        h_err, dist = gd.tool_errors(tool, target_ned_m)
        speed = math.sqrt(sum(v * v for v in vs.velocity_ned_mps))
        g = self.grasp_p
        if self.arm is not None:  # the arm closes the rest: the grasp point within its reach
            inside = (counting and speed <= g.max_speed_mps
                      and self.arm.reachable(vs, self.arm_target_ned_m(vs.timestamp_ns)
                                             or target_ned_m))
            self.grasp_count = self.grasp_count + 1 if inside else 0
            self.tool_errors = (h_err, dist)
            return
        self.grasp_window, self.grasp_count = grasp_progress(
            self.grasp_window, h_err, dist, slow=counting and speed <= g.max_speed_mps,
            grasp_distance_m=g.distance_m, tolerance_m=g.tolerance_m,
            hold_factor=g.hold_factor, accept_fraction=g.accept_fraction,
            required=g.stable_frames)
        self.tool_errors = (h_err, dist)

    def use_rangefinder(self, vs: VehicleState, pol: StatePolicy) -> None:
        """A downward distance reading measures where the ground is *in the vehicle's estimated
        frame* (estimated down + range x cos tilt): the plane offset the visual fits need, free
        of the altitude estimate's drift (flat ground between the vehicle and the target)."""
        d = vs.distance_to_ground_m
        if d is None or self.plane_p.rangefinder == "off" or not vs.in_air or not pol.rangefinder:
            return
        cos_tilt = down_axis_cos_tilt(vs.attitude_q)
        if (not math.isfinite(d) or not math.isfinite(vs.position_ned_m[2])
                or not cos_tilt >= 0.5 or d == self._last_range_m):  # NaN attitude: not >= 0.5
            return  # a repeated value is the same sample (telemetry outpaces the sensor)
        self._last_range_m = d
        self.plane.update(vs.position_ned_m[2] + d * cos_tilt, self.plane_p.rangefinder_std_m,
                          vs.timestamp_ns)

    def rangefinder_report(self, vs: VehicleState) -> tuple[str, bool]:
        """(what the log says about the rangefinder once airborne, whether it is a warning)."""
        if self.plane_p.rangefinder == "off":
            return ("rangefinder not used (mission.params.plane.rangefinder: off): the grasp "
                    "height follows the vehicle's altitude estimate", False)
        if vs.distance_to_ground_m is None:
            return ("no downward rangefinder reading in the telemetry: the grasp height "
                    "follows the vehicle's altitude estimate (docs/mission.md)", True)
        return f"rangefinder: {vs.distance_to_ground_m:.2f} m to the ground", False
