"""The mission runner: the tasks of one approach mission and their wiring.

Tasks (all on the mission clock, real or virtual -- :mod:`eaglemission.clock`):

* one **camera loop** per camera, paced at ``process_rate_hz``, grabbing only while the state's
  policy needs the camera (cruise: wide only, as the paper does);
* **perception**: one frame at a time in a worker thread (:mod:`.perception`); the immutable
  :class:`~eaglemission.missions.perception.Measurement` it returns is applied on the loop
  thread to the target state (:mod:`.target_state`) and the camera choice (:mod:`.views`);
* the **machine**: a frozen :class:`~eaglemission.missions.approach.Snapshot`, the failsafes,
  one step of the transition table;
* the **setpoint stream** (:mod:`.guidance`), woken early by a fresh estimate;
* the **actuator** (:mod:`.actuator`): every vehicle command, bounded;
* **telemetry**: rate, link, rangefinder, log.

What a state does is data (``approach.POLICIES``): no code here branches on the mission state.
Values cross threads only as arguments and return values of the worker calls.
"""

from __future__ import annotations

import asyncio
import functools
import logging
import math
import time
from collections.abc import Awaitable, Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from eaglemission.missions import guidance as gd
from eaglemission.missions.actuator import Actuator
from eaglemission.missions.approach import (
    POLICIES,
    ApproachConfig,
    ApproachMachine,
    Cameras,
    Goal,
    MissionState,
    Snapshot,
    failsafe,
)
from eaglemission.missions.log import MissionLog
from eaglemission.missions.perception import (
    FitHint,
    Measurement,
    Perception,
    Request,
    Tools,
)
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

from eaglemission import errors
from eaglemission.clock import Clock, VirtualTimeLoop, run_blocking
from eaglemission.config import MissionFile
from eaglemission.geometry import CameraModel, camera_pose_ned, down_axis_cos_tilt
from eaglemission.interfaces import Camera, Detector, Estimator, PlaneFitter, Tracker, Vehicle
from eaglemission.names import CAMERA_NARROW, CAMERA_WIDE
from eaglemission.safety import SafeVehicle
from eaglemission.safety_geometry import inside_geofence
from eaglemission.types import XYZ, FlightMode, Frame, VehicleState

log = logging.getLogger(__name__)


def percentile(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else math.nan


@dataclass
class MissionResult:
    """What the mission itself knows at the end (no ground truth: see the evaluator)."""

    final_state: str
    reason: str
    action: str
    states: list[tuple[float, str, str]]
    t_start_s: float
    t_end_s: float
    t_grasp_ready_s: float | None = None
    estimated_tool_errors_m: tuple[float, float] | None = None
    latencies_ms: list[float] = field(default_factory=list)
    frames_processed: dict[str, int] = field(default_factory=dict)
    detections: dict[str, int] = field(default_factory=dict)
    detection_frames: list[tuple[float, str, str, int, Any]] = field(default_factory=list)
    failsafe_params: dict[str, float] | None = None
    failsafe_warnings: list[str] = field(default_factory=list)
    perception_ms: list[float] = field(default_factory=list)
    wall_s: float = 0.0

    @property
    def reached_grasp_ready(self) -> bool:
        return self.t_grasp_ready_s is not None

    @property
    def latency_p90_ms(self) -> float:
        return percentile(self.latencies_ms, 90)


def _is_virtual() -> bool:
    try:
        return isinstance(asyncio.get_running_loop(), VirtualTimeLoop)
    except RuntimeError:
        return False


class MissionRunner:
    """Runs one approach mission on already-built parts.

    Parameters
    ----------
    cfg : the mission file; params : the mission plugin's params
    vehicle : a connected Vehicle; wrapped in :class:`~eaglemission.safety.SafeVehicle` here
        unless it already is one, so no plugin can bypass the envelope
    cameras : ``{"wide": Camera, "narrow": Camera}``; models : their (nominal) models
    detectors : one detector per camera (their temporal state is per camera)
    coarse, fine : estimators; fitter : the plane fitter; tracker : the appearance tracker
    clock : the mission clock; mission_log : JSON-lines log
    grasp_callback : awaited in GRASP_READY when ``mission.grasp_action == "callback"``
    on_frame : called (loop thread) with every grabbed frame (recording)
    on_state : called with (t_s, new state, reason, failsafe action) on every state change
    """

    def __init__(self, cfg: MissionFile, params: ApproachConfig, *, vehicle: Vehicle,
                 cameras: Mapping[str, Camera], models: Mapping[str, CameraModel],
                 detectors: Mapping[str, Detector], coarse: Estimator, fine: Estimator,
                 clock: Clock, mission_log: MissionLog, fitter: PlaneFitter | None = None,
                 tracker: Tracker | None = None,
                 grasp_callback: Callable[[], Awaitable[Any]] | None = None,
                 on_frame: Callable[[Frame], None] | None = None,
                 on_telemetry: Callable[[VehicleState], None] | None = None,
                 record_all: bool = False,
                 on_state: Callable[[float, str, str, str], None] | None = None) -> None:
        self.cfg, self.p, self.m = cfg, params, cfg.mission
        self.vehicle: SafeVehicle = (vehicle if isinstance(vehicle, SafeVehicle)
                                     else SafeVehicle(vehicle, cfg.safety, clock=clock))
        self.cameras, self.models = dict(cameras), dict(models)
        self.tools = {c: Tools(detectors[c], coarse, fine, fitter, tracker) for c in cameras}
        self.clock, self.log = clock, mission_log
        self.on_frame, self.on_telemetry, self.on_state = on_frame, on_telemetry, on_state
        self.record_all = record_all
        self.machine = ApproachMachine(on_change=self._on_state_change)
        self.perception = Perception(params, cfg.target)
        self.filter = TargetFilter(params.filter)
        self.plane = PlaneOffsetFilter(params.altitude_std_m, params.plane_offset_drift_mps)
        m = cfg.mission
        self.guidance = gd.Guidance(gd.GuidanceConfig(
            route_ne_m=tuple((w.north_m, w.east_m) for w in m.route),
            cruise_altitude_m=m.cruise_altitude_m, cruise_speed_mps=m.cruise_speed_mps,
            approach_speed_mps=m.approach_speed_mps,
            standoff_horizontal_m=m.standoff.horizontal_m, standoff_height_m=m.standoff.height_m,
            tool_point_m=tuple(cfg.tool_point_m),  # type: ignore[arg-type]
            grasp_distance_m=m.grasp_distance_m, final_speed_mps=params.final_speed_mps,
            yaw_rate_degps=params.yaw_rate_degps,
            fine_standoff_tolerance_m=params.fine_standoff_tolerance_m,
            tilt_compensation=params.tilt_compensation,
            trim_gain_per_s=params.grasp_trim_gain_per_s, trim_max_m=params.grasp_trim_max_m))
        self.actuator = Actuator(cfg, params, self.vehicle, clock, mission_log, self.guidance,
                                 grasp_callback)
        self.actuator.on_grasp_done = self._wake_machine_now
        self.choice = CameraChoice(self.models[CAMERA_WIDE], self.models[CAMERA_NARROW],
                                   cfg.target.length_m, cfg.target.width_m, ChoiceParams(
                                       params.warm_margin_px, params.narrow_max_fill,
                                       params.narrow_miss_switch_s, params.image_border_px))
        self._interrupt: tuple[str, str] | None = None
        self._stopping = False
        self._wake_setpoint = asyncio.Event()
        self._wake_machine = asyncio.Event()
        self._frames: asyncio.Queue[tuple[Frame, float, VehicleState | None]] = asyncio.Queue(maxsize=4)
        self._t0_ns = clock.now_ns()
        self._entered_ns: dict[MissionState, int] = {self.machine.state: self._t0_ns}
        self._wall0 = time.perf_counter()
        self.states: list[tuple[float, str, str]] = [(0.0, self.machine.state.value, "start")]
        # perception bookkeeping
        self._last_frame_ns: dict[str, int] = {}
        self._processed: dict[str, int] = {c: 0 for c in cameras}
        self._detected: dict[str, int] = {c: 0 for c in cameras}
        self._needed_since_ns: dict[str, int] = {}
        self._confirm: list[XYZ] = []
        self._coarse_std = 1.0
        self._fine_estimates = 0
        self._at_standoff_since_ns: int | None = None
        self._at_standoff = False
        self._grasp_window: list[tuple[float, float]] = []
        self._grasp_count = 0
        self._fit_hint: FitHint | None = None
        self._last_target: XYZ | None = None
        self._last_range_m: float | None = None
        # control bookkeeping
        self._fresh: tuple[float, float] | None = None
        self._goal_ok = True
        self._mode_bad_since_ns: int | None = None
        # telemetry bookkeeping
        self._tel_times: list[int] = []
        self._link_lost_since_ns: int | None = None
        self._events_seen = 0
        # results
        self.latencies_ms: list[float] = []
        self.perception_ms: list[float] = []
        self.detection_frames: list[tuple[float, str, str, int, Any]] = []
        self.t_grasp_ready_s: float | None = None
        self.tool_errors: tuple[float, float] | None = None

    # -- time ----------------------------------------------------------------------------------
    def _t_s(self) -> float:
        return (self.clock.now_ns() - self._t0_ns) * 1e-9

    def interrupt(self, reason: str, action: str) -> None:
        """Stop now with ``action`` (the operator's Ctrl-C): the machine aborts at its next
        tick; the actuator carries the action out through the envelope and waits for it."""
        if self._interrupt is None:
            self._interrupt = (reason, action)
            self.actuator.settle_s = min(self.p.settle_timeout_s,
                                         self.cfg.safety.interrupt_timeout_s)
            self._wake_machine.set()

    def _wake_machine_now(self) -> None:
        self._wake_machine.set()

    @property
    def policy(self) -> Any:
        return self.machine.policy

    # -- state entries (the policy's on_enter actions) -----------------------------------------
    def _on_state_change(self, old: MissionState, new: MissionState, reason: str,
                         action: str) -> None:
        now = self.clock.now_ns()
        self._entered_ns[new] = now
        t = self._t_s()
        self.states.append((t, new.value, reason))
        rec: dict[str, Any] = {"old": old.value, "new": new.value, "reason": reason}
        if action:
            rec["action"] = action
        self.log.write("state", **rec)
        log.info("%.2f s: %s -> %s (%s)", t, old.value, new.value, reason)
        if self.on_state is not None:
            self.on_state(t, new.value, reason, action)
        for action in POLICIES[new].on_enter:
            getattr(self, f"_enter_{action}")(now)
        self._wake_setpoint.set()

    def _enter_arm_takeoff(self, now: int) -> None:
        self.actuator.submit("arm_takeoff")

    def _enter_clear_confirmation(self, now: int) -> None:
        self._confirm = []

    def _enter_start_offboard(self, now: int) -> None:
        if not self.actuator.offboard:
            self.actuator.submit("start_offboard")

    def _enter_route_progress(self, now: int) -> None:
        st = self.vehicle.state()
        self.guidance.resume_route_from(*st.position_ned_m[:2])

    def _enter_report_rangefinder(self, now: int) -> None:
        """Once airborne: say whether the target's plane will be measured (log + warnings)."""
        vs = self.vehicle.state()
        if self.p.rangefinder == "off" or not self.p.plane_offset:
            text = "rangefinder not used (mission.params): the grasp height follows the " \
                   "vehicle's altitude estimate"
        elif vs.distance_to_ground_m is None:
            text = "no downward rangefinder reading in the telemetry: the grasp height " \
                   "follows the vehicle's altitude estimate (docs/mission.md)"
            self.actuator.failsafe_warnings.append(text)
        else:
            text = f"rangefinder: {vs.distance_to_ground_m:.2f} m to the ground"
        self.log.write("event", source="mission", text=text)

    def _enter_seed_filter(self, now: int) -> None:
        self.filter.reset()
        for p in self._confirm:
            self.filter.update(p, self._coarse_std, now)
        self.guidance.new_approach()
        self.choice.reset_coarse()

    def _enter_start_fine(self, now: int) -> None:
        self.choice.reset_fine()
        self._at_standoff_since_ns = None
        self._at_standoff = False
        self._fine_estimates = 0
        self._grasp_count = 0
        self._grasp_window = []
        self._fit_hint = None

    def _enter_grasp(self, now: int) -> None:
        self.t_grasp_ready_s = self._t_s()
        self.actuator.submit("grasp")

    def _enter_hold_carrot(self, now: int) -> None:
        self._confirm = []
        self.guidance.start_search(self.vehicle.state().position_ned_m, now)

    def _enter_final_done(self, now: int) -> None:
        self.actuator.submit("final", self.m.on_done)

    def _enter_final_failsafe(self, now: int) -> None:
        self.actuator.submit("final", self.machine.action)

    # -- cameras -------------------------------------------------------------------------------
    def cameras_needed(self) -> set[str]:
        use = self.policy.cameras
        if use is Cameras.BOTH:
            return {CAMERA_WIDE, CAMERA_NARROW}
        if use is Cameras.WIDE:
            return {CAMERA_WIDE}
        if use is Cameras.WIDE_WARMING_NARROW:
            return {CAMERA_WIDE, CAMERA_NARROW} if self.choice.near_narrow else {CAMERA_WIDE}
        if use is Cameras.FINE:
            return {self.choice.fine_camera}
        return set()

    async def _camera_loop(self, cam_id: str) -> None:
        cam = self.cameras[cam_id]
        rate = min(self.p.process_rate_hz, float(getattr(cam, "frame_rate_hz", math.inf)))
        period_ns = int(1e9 / rate)
        next_ns = self.clock.now_ns()
        grab_timeout_s = max(0.5, 3.0 / rate)
        while not self._stopping:
            recording = self.record_all and self.policy.airborne
            if cam_id not in self.cameras_needed() and not recording:
                self._needed_since_ns.pop(cam_id, None)
                await self.clock.sleep(period_ns * 1e-9)
                next_ns = self.clock.now_ns()
                continue
            self._needed_since_ns.setdefault(cam_id, self.clock.now_ns())
            await self.clock.sleep(max(0.0, (next_ns - self.clock.now_ns()) * 1e-9))
            next_ns = max(next_ns + period_ns, self.clock.now_ns())
            try:
                frame = await asyncio.wait_for(asyncio.shield(run_blocking(
                    functools.partial(cam.grab, timeout_s=grab_timeout_s))),
                    timeout=grab_timeout_s + 1.0)
            except errors.EndOfStream:
                self.log.write("event", source=cam_id, text="end of stream")
                return
            except (errors.CameraError, TimeoutError) as exc:
                self.log.write("event", source=cam_id, text=f"grab failed: {exc}")
                continue
            # wall-clock time of the frame's mid-exposure: arrival minus the frame's age then
            # (virtual time stands still while the camera renders: age 0)
            age_s = 0.0 if _is_virtual() else max(
                0.0, (self.clock.now_ns() - frame.timestamp_ns) * 1e-9)
            wall = time.perf_counter() - age_s
            self._last_frame_ns[cam_id] = self.clock.now_ns()
            if self.on_frame is not None:
                self.on_frame(frame)
            if cam_id not in self.cameras_needed():
                continue  # recorded only: perception does not need this camera now
            view_state = self.vehicle.state_at(frame.timestamp_ns)
            try:
                self._frames.put_nowait((frame, wall, view_state))
            except asyncio.QueueFull:
                self._frames.get_nowait()  # drop the oldest: perception is behind
                self._frames.put_nowait((frame, wall, view_state))

    # -- perception ------------------------------------------------------------------------------
    async def _perception_loop(self) -> None:
        while not self._stopping:
            try:
                frame, wall, state = await asyncio.wait_for(self._frames.get(), timeout=0.5)
            except TimeoutError:
                continue
            if self.machine.final:
                continue
            req = self._request(frame, state)
            meas = await run_blocking(self.perception.perceive, req, self.tools[frame.camera_id])
            self._apply(meas, wall)
            self._wake_machine.set()

    def _request(self, frame: Frame, state: VehicleState | None) -> Request:
        cam_id = frame.camera_id
        pol = self.policy
        model = self.models[cam_id]
        predicted = None
        filt = self.filter.state(frame.timestamp_ns)
        if filt is not None and state is not None and pol.predicts:
            px = project_target(model, state, filt.position_ned_m)
            predicted = (float(px[0]), float(px[1]))
        role = None
        if pol.estimator == "coarse" and cam_id == CAMERA_WIDE:
            role = "coarse"
        elif pol.estimator == "fine" and cam_id == self.choice.fine_camera:
            role = "fine"
        plane = PlaneState(self.plane.offset_m, self.plane.std_m(frame.timestamp_ns))
        return Request(frame, model, state, role, predicted, pol.close_range, self._fit_hint,
                       plane)

    def _apply(self, meas: Measurement, wall: float) -> None:
        """One processed frame, on the loop thread: log it and feed its estimate to the
        confirmation, the filter, the camera choice and the grasp check."""
        cam_id, frame, state = meas.camera_id, meas.frame, meas.state
        pol = self.policy
        self.perception_ms.append(meas.perception_ms)
        if meas.fit_hint is not None:
            self._fit_hint = meas.fit_hint
        pm = meas.plane
        if pm is not None and meas.estimate is not None and pm.cost <= self.p.plane_max_cost:
            ok = self.plane.update(pm.offset_m, pm.std_m, pm.frame_t_ns)
            self.log.write("plane", camera=cam_id, measured_m=pm.offset_m, std_m=pm.std_m,
                           accepted=ok, frame_t_ns=pm.frame_t_ns, range_m=pm.range_m,
                           cost=pm.cost, region=pm.region, offset_m=self.plane.offset_m,
                           offset_std_m=self.plane.std_m())
        self._processed[cam_id] += 1
        det = meas.detection
        self.detection_frames.append((self._t_s(), cam_id, self.machine.state.value, frame.seq,
                                      None if det is None else det.center_px))
        if det is not None:
            self._detected[cam_id] += 1
        self.log.write("detection", camera=cam_id, seq=frame.seq, frame_t_ns=frame.timestamp_ns,
                       n=meas.raw_detections, used=det is not None,
                       center_px=None if det is None else det.center_px,
                       corners_px=None if det is None else det.corners_px,
                       score=None if det is None else det.score,
                       perception_ms=round(meas.perception_ms, 3),
                       colour_track=meas.colour_tracked)
        role = meas.role
        if cam_id == CAMERA_NARROW:
            self.choice.narrow_result(meas.fine_measurement or role is None, self.clock.now_ns())
        est = meas.estimate
        if est is None and meas.failure is not None:
            self.log.write("estimate", camera=cam_id, ok=False, reason=meas.failure)
        if est is not None and math.hypot(*est.position_cam_m) < self.p.min_estimate_range_m:
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
        plane_m = plane_down_m(self.cfg.target.height_m, self.plane_state(), self.p.plane_offset)
        if cam_id == CAMERA_WIDE and pol.confirms:
            p = None if est is None else vertical_reference(
                est.position_ned_m, cam_t, plane_m, self.p.vertical_reference,
                full_3d_range_m=self.p.full_3d_range_m)
            near_last = (p is None or not pol.reacquires or self._last_target is None
                         or math.dist(p[:2], self._last_target[:2])
                         <= self.p.search_radius_m + self.p.confirm_radius_m)
            self._confirm = confirmation(self._confirm, p, radius_m=self.p.confirm_radius_m,
                                         accept=near_last)
            if est is not None:
                self._coarse_std = max(est.std_m, 0.2)
        elif est is not None and pol.tracks:
            accepted = self.filter.update(
                vertical_reference(est.position_ned_m, cam_t, plane_m, self.p.vertical_reference,
                                   full_3d=meas.full_3d, full_3d_range_m=self.p.full_3d_range_m),
                est.std_m, frame.timestamp_ns, allow_reset=pol.filter_may_reset)
            if accepted and role == "fine" and meas.fine_measurement:
                self._fine_estimates += 1
            if accepted:
                self._fresh = (wall, 0.0)
                self._wake_setpoint.set()
        filt = self.filter.state(frame.timestamp_ns)
        if filt is not None and state is not None:
            self._last_target = filt.position_ned_m
            if pol.camera_choice == "coarse":
                self.choice.update_coarse(state, filt.position_ned_m, cam_id, det)
            elif pol.camera_choice == "fine":
                switched = self.choice.update_fine(state, filt.position_ned_m, cam_id,
                                                   self.clock.now_ns())
                if switched is not None:
                    self.log.write("event", source="mission",
                                   text=f"fine approach image source -> {switched}")
        if pol.tool_errors and filt is not None:
            self._check_grasp(filt.position_ned_m, counting=pol.grasp_check)

    def plane_state(self) -> PlaneState:
        return PlaneState(self.plane.offset_m, self.plane.std_m())

    def _check_grasp(self, target_ned_m: XYZ, *, counting: bool) -> None:
        """The mission's own tool-point errors; with ``counting``, the grasp-stability count
        (it stays at 0 at the standoff)."""
        vs = self.vehicle.state()
        tool = gd.tool_point_ned(vs.position_ned_m, vs.attitude_q, self.cfg.tool_point_m)
        h_err, dist = gd.tool_errors(tool, target_ned_m)
        speed = math.sqrt(sum(v * v for v in vs.velocity_ned_mps))
        self._grasp_window, self._grasp_count = grasp_progress(
            self._grasp_window, h_err, dist, slow=counting and speed <= self.p.grasp_max_speed_mps,
            grasp_distance_m=self.m.grasp_distance_m, tolerance_m=self.m.grasp_tolerance_m,
            hold_factor=self.p.grasp_hold_factor, accept_fraction=self.p.grasp_accept_fraction,
            required=self.m.grasp_stable_frames)
        self.tool_errors = (h_err, dist)

    # -- machine -------------------------------------------------------------------------------
    async def _machine_loop(self) -> None:
        period = 1.0 / self.m.setpoint_rate_hz
        while not self._stopping and not self.machine.final:
            try:
                await asyncio.wait_for(self._wake_machine.wait(), timeout=period)
            except TimeoutError:
                pass
            self._wake_machine.clear()
            snap = self.snapshot()
            abort = failsafe(self.machine.state, snap, self.m, self.cfg.safety, self.p)
            self.machine.step(snap, abort)

    def snapshot(self) -> Snapshot:
        """The frozen view the guards see."""
        now = self.clock.now_ns()
        st = self.machine.state
        pol = self.policy
        vs = self.vehicle.state()
        filt = self.filter.state(now)
        timeout = (getattr(self.m.timeouts, pol.timeout_field) if pol.timeout_field
                   else math.inf)
        entered = self._entered_ns.get(pol.timeout_from or st, now)
        tel_hz = 0.0
        if len(self._tel_times) >= 2:
            span = (self._tel_times[-1] - self._tel_times[0]) * 1e-9
            tel_hz = (len(self._tel_times) - 1) / span if span > 0 else 0.0
        camera_failed = False
        if pol.camera_watch:
            for c in self.cameras_needed():
                since = max(self._last_frame_ns.get(c, 0), self._needed_since_ns.get(c, now))
                if (now - since) * 1e-9 > self.p.camera_failure_after_s:
                    camera_failed = True
        warm = all(self._processed[c] >= max(1, self.p.narrow_warmup_frames)
                   for c in self.cameras)
        link_lost_s = 0.0 if self._link_lost_since_ns is None else (
            now - self._link_lost_since_ns) * 1e-9
        pilot = False
        act = self.actuator
        if act.offboard and vs.link_ok and pol.offboard:
            if vs.flight_mode is not FlightMode.OFFBOARD:
                if self._mode_bad_since_ns is None:
                    self._mode_bad_since_ns = now
                pilot = (now - self._mode_bad_since_ns) * 1e-9 > 0.3 and (
                    now - act.offboard_since_ns) * 1e-9 > 1.0
            else:
                self._mode_bad_since_ns = None
        dwell = 0.0 if self._at_standoff_since_ns is None else (
            now - self._at_standoff_since_ns) * 1e-9
        in_state_s = (now - self._entered_ns.get(st, now)) * 1e-9
        return Snapshot(
            t_s=self._t_s(), time_in_state_s=(now - entered) * 1e-9, state_timeout_s=timeout,
            armable=vs.armable, position_valid=vs.position_valid,
            cameras_streaming=all(c in self._last_frame_ns for c in self.cameras),
            detector_warm=warm, telemetry_hz=tel_hz, min_telemetry_hz=self.p.min_telemetry_hz,
            in_air=vs.in_air, altitude_m=-vs.position_ned_m[2],
            takeoff_altitude_m=self.m.cruise_altitude_m,
            takeoff_tolerance_m=self.p.takeoff_tolerance_m,
            route_finished=self.guidance.route_finished(vs.position_ned_m),
            confirmed_frames=len(self._confirm), confirm_frames=self.m.confirm_frames,
            target_in_narrow_view=self.choice.target_in_narrow,
            narrow_warm=self._processed.get(CAMERA_NARROW, 0) >= self.p.narrow_warmup_frames,
            has_target=filt is not None, target_age_s=filt.age_s if filt else math.inf,
            target_expected_visible=self.choice.expected_visible,
            target_lost_after_s=self.p.target_lost_after_s,
            at_standoff=self._at_standoff, standoff_dwell_s=dwell,
            standoff_max_wait_s=self.p.standoff_max_wait_s, fine_estimates=self._fine_estimates,
            fine_min_estimates=self.p.fine_min_estimates,
            grasp_stable_frames=self._grasp_count,
            grasp_required_frames=self.m.grasp_stable_frames, grasp_done=act.grasp_done,
            search_exhausted=(pol.goal is Goal.SEARCH
                              and in_state_s > self.m.timeouts.target_lost_s),
            on_target_lost=self.m.on_target_lost, link_lost_s=link_lost_s,
            link_loss_timeout_s=self.cfg.safety.link_loss_timeout_s,
            gps_ok=vs.gps_fix and (vs.position_valid or not vs.link_ok),
            battery_remaining=vs.battery_remaining,
            low_battery_fraction=self.cfg.safety.low_battery_fraction,
            goal_inside_geofence=self._goal_ok, camera_failed=camera_failed,
            pilot_override=pilot, command_failed=act.command_failed,
            interrupt_reason=self._interrupt[0] if self._interrupt else "",
            interrupt_action=self._interrupt[1] if self._interrupt else "return")

    # -- setpoints -----------------------------------------------------------------------------
    def _inside_envelope(self, pos: XYZ) -> bool:
        """The goal is inside the geofence, with the safety envelope's margin (it would clamp
        the setpoint short of the goal forever)."""
        env = getattr(self.vehicle, "envelope", None)
        if env is not None and hasattr(env, "safe_h"):
            return bool(env.safe_h(float(pos[0]), float(pos[1])))
        return inside_geofence(self.cfg.safety.geofence, pos[0], pos[1])

    async def _setpoint_loop(self) -> None:
        period = 1.0 / self.m.setpoint_rate_hz
        last_ns = self.clock.now_ns()
        while not self._stopping:
            try:
                await asyncio.wait_for(self._wake_setpoint.wait(), timeout=period)
            except TimeoutError:
                pass
            self._wake_setpoint.clear()
            now = self.clock.now_ns()
            dt = max(0.0, (now - last_ns) * 1e-9)
            last_ns = now
            pol = self.policy
            if not self.actuator.offboard or not pol.offboard:
                continue
            vs = self.vehicle.state()
            filt = self.filter.state(now)
            step = self.guidance.step(pol.goal.name, vs.position_ned_m, vs.yaw_deg,
                                      vs.attitude_q, None if filt is None else filt.position_ned_m,
                                      now, dt, trim=pol.trim)
            self._goal_ok = self._inside_envelope(step.goal_ned_m)
            self._at_standoff = step.at_standoff
            if not step.at_standoff:
                self._at_standoff_since_ns = None
            elif self._at_standoff_since_ns is None:
                self._at_standoff_since_ns = now
            sp = step.setpoint
            try:
                await asyncio.wait_for(self.vehicle.set_setpoint(sp),
                                       timeout=self.m.timeouts.command_s)
            except (errors.VehicleError, TimeoutError) as exc:
                self.log.write("event", source="setpoint", text=f"setpoint refused: {exc}")
                continue
            latency = None
            if self._fresh is not None:
                wall, age_s = self._fresh
                latency = (time.perf_counter() - wall + age_s) * 1e3
                self.latencies_ms.append(latency)
                self._fresh = None
            self.log.write("setpoint", state=self.machine.state.value, setpoint=sp,
                           goal=step.goal_ned_m,
                           latency_ms=None if latency is None else round(latency, 3),
                           target=None if filt is None else filt.position_ned_m)
            if step.at_standoff:
                self._wake_machine.set()

    # -- telemetry -----------------------------------------------------------------------------
    async def _telemetry_loop(self) -> None:
        period = 0.02
        last_log = 0
        last_range_ns = -1
        while not self._stopping:
            vs = self.vehicle.state()
            now = self.clock.now_ns()
            if not self._tel_times or vs.timestamp_ns != self._tel_times[-1]:
                self._tel_times = [*self._tel_times[-199:], vs.timestamp_ns]
            if not vs.link_ok:
                if self._link_lost_since_ns is None:
                    self._link_lost_since_ns = now
            else:
                self._link_lost_since_ns = None
            if self.on_telemetry is not None:
                self.on_telemetry(vs)
            if vs.timestamp_ns != last_range_ns:
                last_range_ns = vs.timestamp_ns
                self._use_rangefinder(vs)
            if now - last_log >= 200_000_000:
                last_log = now
                self.log.write("telemetry", position_ned_m=vs.position_ned_m,
                               velocity_ned_mps=vs.velocity_ned_mps, yaw_deg=round(vs.yaw_deg, 2),
                               mode=vs.flight_mode, armed=vs.armed, in_air=vs.in_air,
                               battery=vs.battery_remaining, link_ok=vs.link_ok,
                               gps_fix=vs.gps_fix, state=self.machine.state.value,
                               distance_to_ground_m=vs.distance_to_ground_m,
                               plane_offset_m=round(self.plane.offset_m, 4),
                               plane_offset_std_m=round(self.plane.std_m(vs.timestamp_ns), 4))
            events = self.vehicle.events()
            for ev in list(events)[self._events_seen:]:
                self.log.write("event", source="vehicle", event_kind=ev.kind, text=ev.text,
                               data=ev.data, event_t_ns=ev.timestamp_ns)
            self._events_seen = len(events)
            await self.clock.sleep(period)

    def _use_rangefinder(self, vs: VehicleState) -> None:
        """A downward distance reading measures where the ground is *in the vehicle's estimated
        frame* (estimated down + range x cos tilt): the plane offset the visual fits need, free
        of the altitude estimate's drift (flat ground between the vehicle and the target)."""
        d = vs.distance_to_ground_m
        if (d is None or not self.p.plane_offset or self.p.rangefinder == "off" or not vs.in_air
                or not self.policy.rangefinder):
            return
        cos_tilt = down_axis_cos_tilt(vs.attitude_q)
        if not math.isfinite(d) or cos_tilt < 0.5 or d == self._last_range_m:
            return  # a repeated value is the same sample (telemetry outpaces the sensor)
        self._last_range_m = d
        self.plane.update(vs.position_ned_m[2] + d * cos_tilt, self.p.rangefinder_std_m,
                          vs.timestamp_ns)

    # -- main ----------------------------------------------------------------------------------
    def _result(self) -> MissionResult:
        act = self.actuator
        return MissionResult(
            final_state=self.machine.state.value, reason=self.machine.reason,
            action=self.machine.outcome_action(self.m.on_done),
            states=self.states, t_start_s=0.0, t_end_s=self._t_s(),
            t_grasp_ready_s=self.t_grasp_ready_s, estimated_tool_errors_m=self.tool_errors,
            latencies_ms=self.latencies_ms, frames_processed=dict(self._processed),
            detections=dict(self._detected), detection_frames=self.detection_frames,
            failsafe_params=act.failsafe_params, failsafe_warnings=act.failsafe_warnings,
            perception_ms=self.perception_ms, wall_s=time.perf_counter() - self._wall0)

    async def run(self) -> MissionResult:
        self.log.write("start", config_state=self.machine.state.value,
                       params=self.p.model_dump(), cameras=list(self.cameras))

        async def stopper() -> None:
            await self.actuator.finished.wait()
            self._stopping = True
            self.actuator.stopping = True

        async def machine_guard() -> None:
            try:
                await self._machine_loop()
            except Exception as exc:
                self.log.write("event", source="mission", text=f"machine crashed: {exc!r}")
                raise

        completed = False
        try:
            async with asyncio.TaskGroup() as tg:
                tg.create_task(stopper())
                tg.create_task(self._telemetry_loop())
                tg.create_task(self.actuator.run())
                tg.create_task(machine_guard())
                tg.create_task(self._setpoint_loop())
                tg.create_task(self._perception_loop())
                for cam in self.cameras:
                    tg.create_task(self._camera_loop(cam))
            completed = True
        finally:
            result = self._result()
            self.log.write("end", final_state=result.final_state, reason=result.reason,
                           action=result.action, t_grasp_ready_s=result.t_grasp_ready_s,
                           estimated_tool_errors_m=result.estimated_tool_errors_m,
                           latency_p90_ms=result.latency_p90_ms, frames=result.frames_processed,
                           wall_s=round(result.wall_s, 3), completed=completed)
        return result
