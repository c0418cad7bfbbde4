"""The mission runner: the tasks of one approach mission and their wiring.

Tasks (all on the mission clock, real or virtual -- :mod:`eaglemission.clock`):

* one **camera loop** per camera, paced at ``perception.process_rate_hz``, grabbing only while
  the state's policy needs the camera (cruise: wide only, as the paper does);
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
import dataclasses
import logging
import math
import time
from collections.abc import Awaitable, Callable, Mapping
from typing import Any

import numpy as np
from eaglemission.missions import guidance as gd
from eaglemission.missions.actuator import Actuator
from eaglemission.missions.approach import (
    POLICIES,
    ApproachMachine,
    Cameras,
    FinalAction,
    Goal,
    MissionState,
    Snapshot,
    StatePolicy,
    failsafe,
    final_action,
)
from eaglemission.missions.approach_config import ApproachConfig
from eaglemission.missions.arm import ArmTracking
from eaglemission.missions.camera_pump import CameraPump
from eaglemission.missions.log import MissionLog
from eaglemission.missions.perception import (
    Measurement,
    Perception,
    Request,
    Tools,
)
from eaglemission.missions.result import MissionResult
from eaglemission.missions.telemetry_watch import TelemetryWatch
from eaglemission.missions.tracking import GRIPPER_MIN_FIXES, TargetTracking
from eaglemission.missions.views import CameraChoice, project_target

from eaglemission import errors
from eaglemission.clock import Clock, run_blocking
from eaglemission.config import MissionFile
from eaglemission.geometry import CameraModel
from eaglemission.geometry.geofence import inside_geofence
from eaglemission.interfaces import Camera, Manipulator, Vehicle
from eaglemission.names import CAMERA_NARROW, CAMERA_WIDE
from eaglemission.recording.provenance import config_record
from eaglemission.safety.autopilot_guard import AutopilotGuard
from eaglemission.safety.envelope import SafeVehicle
from eaglemission.types import XYZ, FlightMode, Frame, VehicleState

log = logging.getLogger(__name__)

SLOW_PERCEPTION_MS = 150.0
"""A frame whose perception took longer is logged as ``fault_detected`` ``slow_perception``."""


def pose_finite(vs: VehicleState) -> bool:
    """The state has a finite position and attitude to steer from (telemetry gone wrong has
    not: the setpoint loop then skips the tick and the autopilot keeps the last setpoint)."""
    return all(math.isfinite(v) for v in (*vs.position_ned_m, *vs.attitude_q))


class MissionRunner:
    """Runs one approach mission on already-built parts.

    Parameters
    ----------
    cfg : the mission file; params : the mission plugin's params
    vehicle : a connected Vehicle; wrapped in :class:`~eaglemission.safety.envelope.SafeVehicle` here
        unless it already is one, so no plugin can bypass the envelope
    cameras : ``{"wide": Camera, "narrow": Camera}``; models : their (nominal) models
    tools : per camera, what its perception uses (:class:`~.perception.Tools`: the camera's
        detector and keeper, whose state is the camera's, the estimators, the plane fitter, the
        target's appearance)
    clock : the mission clock; mission_log : JSON-lines log
    grasp_callback : awaited in GRASP_READY when ``grasp.action == "callback"``
    on_frame, on_processed : called (loop thread) with every grabbed / processed frame (+ its saliency thumbnail)
    on_state : called with (t_s, new state, reason, failsafe action) on every state change
    autopilot_guard : the assembly's (applied) autopilot-parameter guard; None: its own
    manipulator : the tool; None: the fixed tool at ``tool_point_m`` (an arm: :mod:`.arm`)
    """

    def __init__(self, cfg: MissionFile, params: ApproachConfig, *, vehicle: Vehicle,
                 cameras: Mapping[str, Camera], models: Mapping[str, CameraModel],
                 tools: Mapping[str, Tools], clock: Clock, mission_log: MissionLog,
                 grasp_callback: Callable[[], Awaitable[Any]] | None = None,
                 on_frame: Callable[[Frame], None] | None = None,
                 on_telemetry: Callable[[VehicleState], None] | None = None, record_all: bool = False,
                 on_processed: Callable[[Frame, Any], None] | None = None,
                 on_state: Callable[[float, str, str, str], None] | None = None,
                 autopilot_guard: AutopilotGuard | None = None,
                 manipulator: Manipulator | None = None) -> None:
        self.cfg, self.p, self.m = cfg, params, cfg.mission
        self.vehicle: SafeVehicle = (vehicle if isinstance(vehicle, SafeVehicle)
                                     else SafeVehicle(vehicle, cfg.safety, clock=clock))
        self.cameras, self.models = dict(cameras), dict(models)
        self.tools = dict(tools)
        self.clock, self.log = clock, mission_log
        self.on_frame, self.on_telemetry, self.on_state = on_frame, on_telemetry, on_state
        self.record_all, self.on_processed = record_all, on_processed or (lambda _f, _t: None)
        self.machine = ApproachMachine(on_change=self._on_state_change)
        self.perception = Perception(params.perception, cfg.target,
                                     thumbnails=on_processed is not None)
        self._limits = configured_limits(cfg, params)
        self.track = TargetTracking(cfg, self.models, mission_log, tracking=params.tracking,
                                    perception=params.perception, plane=params.plane,
                                    grasp=params.grasp)
        self.guidance = gd.Guidance(gd.Plan.of(cfg, params.grasp.distance_m), params.guidance)
        self.arm = ArmTracking.of(
            manipulator, mission_log, params,
            state=lambda: (self.telemetry.current(),
                           self.track.arm_target_ned_m(self.clock.now_ns())),
            measured=lambda: (self.telemetry.current(), self.track.fresh_fix_ned_m(
                self.clock.now_ns(), min_fixes=GRIPPER_MIN_FIXES)))
        self.track.arm = self.arm if self.arm.enabled else None
        self.actuator = Actuator(  # the grasp pose is held for the stable period before leaving
            cfg, self.vehicle, clock, mission_log, self.guidance, grasp=params.grasp,
            timeouts=params.timeouts, grasp_callback=grasp_callback, guard=autopilot_guard,
            grasp_hold_s=params.grasp.stable_frames / params.perception.process_rate_hz,
            manipulator=manipulator, arm=self.arm)
        self.actuator.on_grasp_done = self._wake_machine_now
        self._interrupt: tuple[str, FinalAction] | None = None
        self._watchdog_hold = ""
        self._stopping = False
        self._wake_setpoint = asyncio.Event()
        self._wake_machine = asyncio.Event()
        self.pump = CameraPump(self.cameras, self.vehicle, clock, mission_log,
                               rate_hz=params.perception.process_rate_hz, needed=self.cameras_needed,
                               recording=lambda: self.record_all and self.policy.airborne,
                               on_frame=on_frame)
        self._t0_ns = clock.now_ns()
        self._entered_ns: dict[MissionState, int] = {self.machine.state: self._t0_ns}
        self._wall0 = time.perf_counter()
        self.states: list[tuple[float, str, str]] = [(0.0, self.machine.state.value, "start")]
        # perception bookkeeping
        self._processed: dict[str, int] = {c: 0 for c in cameras}
        self._detected: dict[str, int] = {c: 0 for c in cameras}
        self._at_standoff_since_ns: int | None = None
        self._at_standoff = False
        # control bookkeeping
        self._fresh: tuple[float, float] | None = None
        self._goal_ok = True
        self._mode_bad_since_ns: int | None = None
        self.telemetry = TelemetryWatch(self.vehicle, clock, mission_log, self.track,
                                        policy=lambda: self.policy,
                                        state_name=lambda: self.machine.state.value,
                                        on_telemetry=on_telemetry,
                                        max_age_s=self.cfg.safety.max_telemetry_age_s)
        # results
        self.latencies_ms: list[float] = []
        self.perception_ms: list[float] = []
        self.detection_frames: list[tuple[float, str, str, int, tuple[float, float] | None]] = []
        self.t_grasp_ready_s: float | None = None

    # -- time ----------------------------------------------------------------------------------
    def _t_s(self) -> float:
        return (self.clock.now_ns() - self._t0_ns) * 1e-9

    def interrupt(self, reason: str, action: str) -> None:
        """Stop now with ``action`` (the operator's Ctrl-C): the machine aborts at its next
        tick; the actuator carries the action out through the envelope and waits for it."""
        if self._interrupt is None:
            self._interrupt = (reason, final_action(action))
            self.actuator.settle_s = min(self.p.timeouts.settle_s,
                                         self.cfg.safety.interrupt_timeout_s)
            self._wake_machine.set()

    def _wake_machine_now(self) -> None:
        self._wake_machine.set()

    @property
    def policy(self) -> StatePolicy:
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
        self.arm.follow(POLICIES[new].arm_tracks and not self.actuator.gripper_closed)
        for action in POLICIES[new].on_enter:
            getattr(self, f"_enter_{action}")(now)
        self._wake_setpoint.set()

    def _enter_arm_takeoff(self, now: int) -> None:
        self.actuator.submit("arm_takeoff")

    def _enter_count_loss(self, now: int) -> None:
        self.track.count_loss()
        again = self.guidance.search_route_again() \
            if self.track.just_rejected else None
        if again is not None:
            self.log.write("event", source="mission", text=again)

    def _enter_clear_confirmation(self, now: int) -> None:
        self.track.confirm = []

    def _enter_start_offboard(self, now: int) -> None:
        if not self.actuator.offboard:
            self.actuator.submit("start_offboard")

    def _enter_route_progress(self, now: int) -> None:
        st = self.vehicle.state()
        self.guidance.resume_route_from(*st.position_ned_m[:2])

    def _enter_report_rangefinder(self, now: int) -> None:
        """Once airborne: say whether the target's plane will be measured (log + warnings)."""
        text, warn = self.track.rangefinder_report(self.vehicle.state())
        if warn:
            self.actuator.failsafe_warnings.append(text)
        self.log.write("event", source="mission", text=text)

    def _enter_seed_filter(self, now: int) -> None:
        self.track.seed_filter(now)
        self.guidance.new_approach()

    def _enter_start_fine(self, now: int) -> None:
        self.track.start_fine()
        self._at_standoff_since_ns = None
        self._at_standoff = False

    def _enter_grasp(self, now: int) -> None:
        self.t_grasp_ready_s = self._t_s()
        self.actuator.submit("grasp")

    def _enter_hold_carrot(self, now: int) -> None:
        self.guidance.start_search(self.vehicle.state().position_ned_m, now)

    def _enter_final_done(self, now: int) -> None:
        self.actuator.submit("final", self.p.actions.on_done)

    def _enter_final_failsafe(self, now: int) -> None:
        self.actuator.submit("final", self.machine.action)

    # -- cameras -------------------------------------------------------------------------------
    def cameras_needed(self) -> set[str]:
        return needed_cameras(self.policy.cameras, self.track.choice)

    # -- perception ------------------------------------------------------------------------------
    async def _perception_loop(self) -> None:
        while not self._stopping:
            item = await self.pump.take(final=lambda: self.machine.final)
            if item is None:
                continue
            frame, wall, state = item
            meas = await perceive_logged(self, self._request(frame, state))
            if meas is not None:
                self._apply(meas, wall)
            self._wake_machine.set()

    def _request(self, frame: Frame, state: VehicleState | None) -> Request:
        cam_id = frame.camera_id
        pol = self.policy
        model = self.models[cam_id]
        predicted = None
        target = self.track.target_ned_m(frame.timestamp_ns)
        if target is not None and state is not None and pol.predicts:
            px = project_target(model, state, target)
            predicted = (float(px[0]), float(px[1]))
        serves = {"coarse": CAMERA_WIDE, "fine": self.track.choice.fine_camera}  # which camera
        role = pol.estimator if pol.estimator and serves[pol.estimator] == cam_id else None
        foot = self.arm.footprint_px(model) if self.arm.enabled and pol.close_range else None
        return Request(frame, model, state, role, predicted, pol.close_range, self.track.fit_hint,
                       self.track.plane_state(frame.timestamp_ns), self.track.drops,
                       occluder_px=foot)

    def _apply(self, meas: Measurement, wall: float) -> None:
        """One processed frame, on the loop thread (:meth:`TargetTracking.apply`)."""
        cam_id = meas.camera_id
        self.perception_ms.append(meas.perception_ms)
        self._processed[cam_id] += 1
        self.on_processed(meas.frame, meas.saliency_thumb)
        det = meas.detection
        self.detection_frames.append((self._t_s(), cam_id, self.machine.state.value,
                                      meas.frame.seq, None if det is None else det.center_px))
        if det is not None:
            self._detected[cam_id] += 1
        if self.policy.close_range and self.arm.sight is not None:
            self.arm.sight.observe(meas.frame, self.models[cam_id])
        applied = self.track.apply(meas, self.policy, self.telemetry.current(), self.clock.now_ns(),
                                   self._t_s())
        if applied.fresh:
            self._fresh = (wall, 0.0)
            self._wake_setpoint.set()
            self.arm.wake.set()

    # -- machine -------------------------------------------------------------------------------
    async def _machine_loop(self) -> None:
        period = 1.0 / self.p.guidance.setpoint_rate_hz
        while not self._stopping and not self.machine.final:
            try:
                await asyncio.wait_for(self._wake_machine.wait(), timeout=period)
            except TimeoutError:
                pass
            self._wake_machine.clear()
            snap = self.snapshot()
            abort = failsafe(self.machine.state, snap, self.cfg.safety, self.p.actions)
            self.machine.step(snap, abort)

    def snapshot(self) -> Snapshot:
        """The frozen view the guards see."""
        now = self.clock.now_ns()
        st = self.machine.state
        pol = self.policy
        vs = self.telemetry.current()
        filt = self.track.filter.state(now)
        timeout = (getattr(self.p.timeouts, pol.timeout_field) if pol.timeout_field
                   else math.inf)
        entered = self._entered_ns.get(pol.timeout_from or st, now)
        p = self.p
        camera_failed = pol.camera_watch and self.pump.failed(now, p.timeouts.camera_failure_s)
        warm = all(self._processed[c] >= max(1, p.perception.narrow_warmup_frames)
                   for c in self.cameras)
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
        return dataclasses.replace(
            self._limits,
            t_s=self._t_s(), time_in_state_s=(now - entered) * 1e-9, state_timeout_s=timeout,
            armable=vs.armable, position_valid=vs.position_valid,
            cameras_streaming=self.pump.streaming(),
            detector_warm=warm, telemetry_hz=self.telemetry.rate_hz(),
            in_air=vs.in_air, altitude_m=-vs.position_ned_m[2],
            route_finished=self.guidance.route_finished(vs.position_ned_m),
            confirmed_frames=len(self.track.confirm),
            target_in_narrow_view=self.track.choice.target_in_narrow,
            narrow_warm=self._processed.get(CAMERA_NARROW, 0) >= p.perception.narrow_warmup_frames,
            has_target=filt is not None, target_age_s=filt.age_s if filt else math.inf,
            target_expected_visible=self.track.choice.expected_visible,
            at_standoff=self._at_standoff, standoff_dwell_s=dwell,
            fine_estimates=self.track.fine_estimates,
            grasp_stable_frames=self.track.grasp_count, grasp_done=act.grasp_done,
            search_exhausted=(pol.goal is Goal.SEARCH
                              and in_state_s > p.timeouts.target_lost_s),
            candidate_rejected=self.track.just_rejected, target_losses=self.track.last_losses,
            link_lost_s=self.telemetry.link_lost_s(now),
            gps_ok=vs.gps_fix and (vs.position_valid or not vs.link_ok),
            battery_remaining=vs.battery_remaining,
            goal_inside_geofence=self._goal_ok, camera_failed=camera_failed,
            pilot_override=pilot, watchdog_hold=self._watchdog_hold,
            autopilot_failover=self.telemetry.failover, command_failed=act.command_failed,
            interrupt_reason=self._interrupt[0] if self._interrupt else "",
            interrupt_action=self._interrupt[1] if self._interrupt else "return")

    # -- setpoints -----------------------------------------------------------------------------
    async def _setpoint_loop(self) -> None:
        period = 1.0 / self.p.guidance.setpoint_rate_hz
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
            vs = self.telemetry.current()
            if not self.actuator.offboard or not pol.offboard or not pose_finite(vs):
                continue
            filt = self.track.filter.state(now)
            step = self.guidance.step(pol.goal.name, vs.position_ned_m, vs.yaw_deg,
                                      vs.attitude_q, None if filt is None else filt.position_ned_m,
                                      now, dt, trim=pol.trim)
            self._goal_ok = inside_envelope(self.vehicle, self.cfg, step.goal_ned_m)
            self._at_standoff = step.at_standoff
            since = self._at_standoff_since_ns
            self._at_standoff_since_ns = (None if not step.at_standoff
                                          else now if since is None else since)
            sp = step.setpoint
            try:
                await asyncio.wait_for(self.vehicle.set_setpoint(sp),
                                       timeout=self.p.timeouts.command_s)
            except (errors.DriverError, TimeoutError) as exc:  # VehicleError, TimeoutError_
                if getattr(exc, "result", "") == "WATCHDOG_HOLD":
                    if not self._watchdog_hold:  # once: every later setpoint is refused too
                        detail = getattr(exc, "detail", "") or str(exc)
                        self._watchdog_hold = detail.split(":")[0]
                        self.log.write("fault_detected", what="offboard_watchdog",
                                       text=str(exc), response=f"{self.p.actions.on_timeout}",
                                       state=self.machine.state.value)
                        self._wake_machine.set()
                    continue
                self.log.write("event", source="setpoint", text=f"setpoint refused: {exc}")
                continue
            latency = None
            if self._fresh is not None:
                wall, age_s = self._fresh
                latency = (time.perf_counter() - wall + age_s) * 1e3
                self.latencies_ms.append(latency)
                self._fresh = None
            self.log.write("setpoint", state=self.machine.state.value, setpoint=sp,
                           sent=self.vehicle.last_sent,
                           goal=step.goal_ned_m,
                           latency_ms=None if latency is None else round(latency, 3),
                           target=None if filt is None else filt.position_ned_m)
            if step.at_standoff:
                self._wake_machine.set()

    # -- main ----------------------------------------------------------------------------------
    async def run(self) -> MissionResult:
        self.log.write("start", t0_ns=self._t0_ns, config_state=self.machine.state.value,
                       params=self.p.model_dump(), cameras=list(self.cameras))
        self.log.write("config", **config_record(self.cfg))

        async def stopper() -> None:
            await self.actuator.finished.wait()
            self._stopping = True
            self.actuator.stopping = self.arm.stopping = True
            self.pump.stopping = True
            self.telemetry.stopping = True

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
                tg.create_task(self.telemetry.run())
                tg.create_task(self.actuator.run())
                tg.create_task(machine_guard())
                tg.create_task(self._setpoint_loop())
                tg.create_task(self._perception_loop())
                if self.arm.enabled:
                    tg.create_task(self.arm.run())
                for cam in self.cameras:
                    tg.create_task(self.pump.run(cam))
            completed = True
        finally:
            result = mission_result(self)
            self.log.write("end", final_state=result.final_state, reason=result.reason,
                           action=result.action, t_grasp_ready_s=result.t_grasp_ready_s,
                           estimated_tool_errors_m=result.estimated_tool_errors_m,
                           latency_p90_ms=result.latency_p90_ms, frames=result.frames_processed,
                           frame_counts=result.frame_counts, wall_s=round(result.wall_s, 3),
                           completed=completed)
        return result


def needed_cameras(use: Cameras, choice: CameraChoice) -> set[str]:
    """The cameras a state's policy grabs (the camera choice says which is the fine one and
    whether the target nears the narrow view)."""
    if use is Cameras.BOTH:
        return {CAMERA_WIDE, CAMERA_NARROW}
    if use is Cameras.WIDE:
        return {CAMERA_WIDE}
    if use is Cameras.WIDE_WARMING_NARROW:
        return {CAMERA_WIDE, CAMERA_NARROW} if choice.near_narrow else {CAMERA_WIDE}
    if use is Cameras.FINE:
        return {choice.fine_camera}
    return set()


def inside_envelope(vehicle: SafeVehicle, cfg: MissionFile, pos: XYZ) -> bool:
    """The goal is inside the geofence, with the safety envelope's margin (it would clamp the
    setpoint short of the goal forever)."""
    env = getattr(vehicle, "envelope", None)
    if env is not None and hasattr(env, "safe_h"):
        return bool(env.safe_h(float(pos[0]), float(pos[1])))
    return inside_geofence(cfg.safety.geofence, pos[0], pos[1])


def configured_limits(cfg: MissionFile, p: ApproachConfig) -> Snapshot:
    """A snapshot holding what the mission file fixes for the guards (thresholds, the loss
    action); :meth:`MissionRunner.snapshot` fills in each tick's measurements."""
    return Snapshot(min_telemetry_hz=p.timeouts.min_telemetry_hz,
                    takeoff_altitude_m=cfg.mission.cruise_altitude_m,
                    takeoff_tolerance_m=p.guidance.takeoff_tolerance_m,
                    confirm_frames=p.tracking.confirm_frames,
                    target_lost_after_s=p.tracking.lost_after_s,
                    standoff_max_wait_s=p.guidance.standoff.max_wait_s,
                    fine_min_estimates=p.guidance.standoff.min_fine_estimates,
                    grasp_required_frames=p.grasp.stable_frames,
                    on_target_lost=p.actions.on_target_lost,
                    link_loss_timeout_s=cfg.safety.link_loss_timeout_s,
                    low_battery_fraction=cfg.safety.low_battery_fraction)


def mission_result(r: MissionRunner) -> MissionResult:
    """What the runner has flown so far, as the mission's result."""
    act = r.actuator
    return MissionResult(
        final_state=r.machine.state.value, reason=r.machine.reason,
        action=r.machine.outcome_action(r.p.actions.on_done),
        states=r.states, t_start_s=0.0, t_end_s=r._t_s(),
        t_grasp_ready_s=r.t_grasp_ready_s,
        estimated_tool_errors_m=r.track.tool_errors,
        t_gripper_closed_s=None if act.gripper_closed_ns is None
        else (act.gripper_closed_ns - r._t0_ns) * 1e-9,
        tool_body_at_close_m=act.tool_body_at_close_m,
        estimated_grasp_error_m=act.grasp_error_at_close_m,
        latencies_ms=r.latencies_ms, frames_processed=dict(r._processed),
        frame_counts=r.pump.final_counts(r._processed, final=r.machine.final),
        detections=dict(r._detected), detection_frames=r.detection_frames,
        failsafe_params=act.failsafe_params, failsafe_warnings=act.failsafe_warnings,
        perception_ms=r.perception_ms, wall_s=time.perf_counter() - r._wall0)


async def perceive_logged(runner: MissionRunner, req: Request) -> Measurement | None:
    """One frame through the runner's perception in a worker thread; what went wrong is
    logged as ``fault_detected``: a plugin that raised (None: the frame is dropped, the flight
    goes on), non-finite detector output, a slow frame (over ``SLOW_PERCEPTION_MS`` and 4x the
    median of the last 50 frames: a loaded machine is not a fault)."""
    cam = req.frame.camera_id
    log, history_ms = runner.log, runner.perception_ms
    try:
        with runner.pump.counts.dropped_on_error(cam):
            meas = await run_blocking(runner.perception.perceive, req, runner.tools[cam])
    except Exception as exc:  # a failing plugin costs the frame, not the flight
        log.write("fault_detected", what="perception_failed", camera=cam,
                  text=f"{type(exc).__name__}: {exc}", response="frame dropped")
        return None
    if meas.anomaly is not None:
        log.write("fault_detected", what=meas.anomaly, camera=cam,
                  text="non-finite detector output", response="detections ignored")
    recent = history_ms[-50:]
    typical_ms = float(np.median(recent)) if recent else 0.0
    if len(recent) >= 10 and meas.perception_ms > max(SLOW_PERCEPTION_MS, 4.0 * typical_ms):
        # judged on the host's wall time (the first frames' JIT warm-up excluded): marked as a
        # wall-clock record, which a virtual-time replay of the same seed need not repeat
        log.write("fault_detected", what="slow_perception", camera=cam,
                  text=f"perception took {meas.perception_ms:.0f} ms",
                  response="frame used; the filter predicts across the gap", wall_clock=True)
    return meas
