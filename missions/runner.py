"""The mission runner: an asyncio TaskGroup around the approach state machine.

Tasks (all on the mission clock, real or virtual -- :mod:`eaglemission.clock`):

* one **camera loop** per camera, paced on the clock at ``process_rate_hz``; a camera is grabbed
  only while the current state needs it (cruise: wide only, as the paper does; the narrow one
  while warming up and in the fine approach), so a synthetic camera renders lazily;
* **perception**: detection and estimation of each frame in a worker thread through
  :func:`eaglemission.clock.run_blocking` (the event loop never blocks; virtual time stays frozen
  while it runs), with the vehicle pose at the frame's mid-exposure time (``state_at``);
* the **machine** task: builds a :class:`~eaglemission.missions.approach.Snapshot`, checks the
  failsafes, steps the machine;
* the **setpoint stream**: its own timer at ``mission.setpoint_rate_hz``, woken early by a fresh
  estimate so the frame-to-setpoint latency stays one perception time;
* the **actuator**: every vehicle command (arm, takeoff, offboard, grab, land, return) with a
  timeout, never inside a machine callback;
* **telemetry**: rate, link/GPS/battery monitoring, log.

The vehicle is always wrapped in :class:`eaglemission.safety.SafeVehicle` by the builders here.
"""

from __future__ import annotations

import asyncio
import functools
import logging
import math
import time
from collections import deque
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from eaglemission.missions import guidance as gd
from eaglemission.missions.approach import (
    AIRBORNE_STATES,
    OFFBOARD_STATES,
    TIMEOUT_FIELD,
    ApproachConfig,
    ApproachMachine,
    MissionState,
    Snapshot,
    failsafe,
)
from eaglemission.missions.filter import PlaneOffsetFilter, TargetFilter
from eaglemission.missions.log import MissionLog
from eaglemission.missions.silhouette import PlaneFit, colour_blob, fit_on_top_plane

from eaglemission import errors
from eaglemission.config import MissionFile
from eaglemission.geometry import CameraModel, camera_pose_ned, down_axis_cos_tilt
from eaglemission.interfaces.estimator import CameraView
from eaglemission.names import CAMERA_NARROW, CAMERA_WIDE, PX4_FAILSAFE_PARAMS
from eaglemission.safety import SafeVehicle
from eaglemission.safety_geometry import inside_geofence
from eaglemission.types import (
    Detection,
    DetectionResult,
    EstimationFailed,
    FlightMode,
    Frame,
    TargetEstimate,
    TargetPrior,
    VehicleState,
)

log = logging.getLogger(__name__)
S = MissionState

COM_OBL_RC_ACT_NAMES = {0: "Position mode", 1: "Altitude mode", 2: "Manual", 3: "Return",
                        4: "Land", 5: "Hold", 6: "Terminate", 7: "Disarm"}


def failsafe_param_warnings(values: dict[str, float], safety: Any) -> list[str]:
    """What a field team must know about PX4's own failsafes with this envelope (pure).

    PX4 flies RTL/land/takeoff at its own speeds and RTL climbs to RTL_RETURN_ALT: values
    outside the mission's envelope are reported, as is the offboard-loss action (in the recorded
    PX4 traffic, offboard loss switched to Position mode and, without RC, the vehicle descended
    and landed)."""
    out: list[str] = []
    rtl = values.get("RTL_RETURN_ALT")
    if rtl is not None and rtl > safety.max_altitude_m:
        out.append(f"RTL_RETURN_ALT={rtl:g} m is above safety.max_altitude_m="
                   f"{safety.max_altitude_m:g}: a PX4 return would leave the altitude band; "
                   "set RTL_RETURN_ALT inside it")
    for name, limit in (("MPC_XY_CRUISE", safety.max_horizontal_speed_mps),
                        ("MPC_XY_VEL_MAX", safety.max_horizontal_speed_mps),
                        ("MPC_Z_VEL_MAX_UP", safety.max_vertical_speed_mps),
                        ("MPC_Z_VEL_MAX_DN", safety.max_vertical_speed_mps)):
        v = values.get(name)
        if v is not None and v > limit + 1e-6:
            out.append(f"{name}={v:g} m/s exceeds the envelope's {limit:g} m/s: autopilot-flown "
                       "moves (RTL, land, takeoff) would be faster than the envelope allows")
    act = values.get("COM_OBL_RC_ACT")
    if act is not None:
        out.append(f"offboard loss (COM_OF_LOSS_T={values.get('COM_OF_LOSS_T', float('nan')):g} "
                   f"s) -> COM_OBL_RC_ACT={int(act)} "
                   f"({COM_OBL_RC_ACT_NAMES.get(int(act), 'unknown')})"
                   + ("; without RC PX4 then descends and lands" if int(act) in (0, 1) else ""))
    return out


# ---------------------------------------------------------------------------------------------
# Pure helpers
# ---------------------------------------------------------------------------------------------
def project_target(model: CameraModel, state: VehicleState, target_ned_m: Any) -> np.ndarray:
    """Pixel of a NED point in a camera on a vehicle (NaN when behind the camera)."""
    pose = camera_pose_ned(model, state.position_ned_m, state.attitude_q).inverse()
    return model.project(pose.apply(np.asarray(target_ned_m, dtype=np.float64)))[0]


def target_corners_ned(target_ned_m: Any, length_m: float, width_m: float,
                       yaw_deg: float = 0.0, pad_m: float = 0.0) -> np.ndarray:
    """The 4 top-face corners (plus ``pad_m``) of a target centred at ``target_ned_m``."""
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    hl, hw = length_m / 2 + pad_m, width_m / 2 + pad_m
    out = []
    for x, y in ((hl, -hw), (hl, hw), (-hl, hw), (-hl, -hw)):
        out.append((target_ned_m[0] + c * x - s * y, target_ned_m[1] + s * x + c * y,
                    target_ned_m[2]))
    return np.asarray(out)


def footprint_px(model: CameraModel, state: VehicleState, target_ned_m: Any, length_m: float,
                 width_m: float) -> np.ndarray:
    """Projected footprint (a square of the target's diagonal, any heading) in pixels (4, 2)."""
    d = math.hypot(length_m, width_m)
    pts = target_corners_ned(target_ned_m, d, d)
    pose = camera_pose_ned(model, state.position_ned_m, state.attitude_q).inverse()
    return model.project(pose.apply(pts))


def fully_in_image(model: CameraModel, px: np.ndarray, margin_px: float) -> bool:
    return bool(np.isfinite(px).all() and model.in_image(px, margin_px).all())


def fill_fraction(model: CameraModel, px: np.ndarray) -> float:
    """Largest extent of projected points relative to the image size (inf when behind)."""
    if not np.isfinite(px).all():
        return math.inf
    span = px.max(axis=0) - px.min(axis=0)
    return float(max(span[0] / model.width_px, span[1] / model.height_px))


def touches_border(det: Detection, width_px: int, height_px: int, border_px: float) -> bool:
    c = det.corners_px
    return bool((c[:, 0] < border_px).any() or (c[:, 1] < border_px).any()
                or (c[:, 0] > width_px - 1 - border_px).any()
                or (c[:, 1] > height_px - 1 - border_px).any())


def expected_area_px(model: CameraModel, state: VehicleState, center_px: Any, length_m: float,
                     width_m: float, height_m: float) -> float | None:
    """Image area a target of this size would have if it were where the detection's centre ray
    meets the plane of its top face (flat ground); None when the ray does not meet it."""
    pose = camera_pose_ned(model, state.position_ned_m, state.attitude_q)
    ray = pose.R @ model.rays_optical(np.asarray([center_px], dtype=np.float64))[0]
    drop = -height_m - float(pose.t[2])
    if ray[2] <= 1e-3 or drop <= 0:
        return None
    dist = drop / float(ray[2])
    sin_el = float(ray[2])
    cos_el = math.sqrt(max(0.0, 1.0 - sin_el * sin_el))
    f2 = model.fx * model.fy
    return f2 * (length_m * width_m * sin_el + max(length_m, width_m) * height_m * cos_el) / dist**2


def plausible_size(det: Detection, model: CameraModel, state: VehicleState | None, target: Any,
                   lo: float = 0.2, hi: float = 5.0) -> bool:
    """The paper filters the MBR by the target's known size and shape; with the camera's pose
    the expected size is known at every pixel (ray to the target plane)."""
    if state is None:
        return True
    exp = expected_area_px(model, state, det.center_px, target.length_m, target.width_m,
                           target.height_m)
    if exp is None:
        return False
    return lo * exp <= det.area_px <= hi * exp


def chromaticity(bgr: Any) -> np.ndarray:
    """(b, g, r) / (b + g + r): colour without brightness (lighting gain, shading)."""
    c = np.asarray(bgr, dtype=np.float64)
    return c / max(1.0, float(c.sum()))


def colour_matches(image: np.ndarray, det: Detection, target_bgr: Any, tolerance: float) -> bool:
    """The median colour of the detection's core (its MBR shrunk to half size) has the target's
    chromaticity within ``tolerance`` (L1)."""
    if image.ndim != 3:
        return True
    c = np.asarray(det.corners_px, dtype=np.float64)
    core = c.mean(axis=0) + 0.5 * (c - c.mean(axis=0))
    x0, y0 = np.floor(core.min(axis=0)).astype(int)
    x1, y1 = np.ceil(core.max(axis=0)).astype(int) + 1
    h, w = image.shape[:2]
    x0, y0, x1, y1 = max(0, x0), max(0, y0), min(w, x1), min(h, y1)
    if x1 <= x0 or y1 <= y0:
        return False
    patch = image[y0:y1, x0:x1].reshape(-1, 3)
    if len(patch) > 4096:
        patch = patch[:: len(patch) // 4096]
    med = np.median(patch, axis=0)
    return float(np.abs(chromaticity(med) - chromaticity(target_bgr)).sum()) <= tolerance


def select_detection(result: DetectionResult, predicted_px: np.ndarray | None, width_px: int,
                     height_px: int, border_px: float, gate_px: float,
                     plausible: Callable[[Detection], bool] | None = None,
                     allow_cut: bool = False) -> Detection | None:
    """The detection to use: the one nearest the predicted target pixel when there is a
    prediction (within ``gate_px``), else the best-ranked; truncated ones (unless
    ``allow_cut``) and (with ``plausible``) ones of an impossible size are skipped."""
    dets = [d for d in result.detections
            if (allow_cut or not touches_border(d, width_px, height_px, border_px))
            and (plausible is None or plausible(d))]
    if not dets:
        return None
    if predicted_px is not None and np.isfinite(predicted_px).all():
        dist = [math.hypot(d.center_px[0] - predicted_px[0], d.center_px[1] - predicted_px[1])
                for d in dets]
        i = int(np.argmin(dist))
        return dets[i] if dist[i] <= gate_px else None
    return dets[0]


def percentile(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else math.nan


# ---------------------------------------------------------------------------------------------
# Result
# ---------------------------------------------------------------------------------------------
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


# ---------------------------------------------------------------------------------------------
# The runner
# ---------------------------------------------------------------------------------------------
class MissionRunner:
    """Runs one approach mission on already-built components.

    Parameters
    ----------
    cfg : the mission file; params : the mission plugin's params
    vehicle : a connected Vehicle; wrapped in :class:`~eaglemission.safety.SafeVehicle` here
        unless it already is one, so no plugin can bypass the envelope
    cameras : ``{"wide": Camera, "narrow": Camera}``; models : the NOMINAL camera models
    detectors : one detector per camera (their temporal state is per camera)
    coarse, fine : estimators; clock : the mission clock; mission_log : JSON-lines log
    grasp_callback : awaited in GRASP_READY when ``mission.grasp_action == "callback"``
    on_frame : called (loop thread) with every grabbed frame (recording)
    """

    def __init__(self, cfg: MissionFile, params: ApproachConfig, *, vehicle: Any,
                 cameras: dict[str, Any], models: dict[str, CameraModel],
                 detectors: dict[str, Any], coarse: Any, fine: Any, clock: Any,
                 mission_log: MissionLog,
                 grasp_callback: Callable[[], Awaitable[None]] | None = None,
                 on_frame: Callable[[Frame], None] | None = None,
                 on_telemetry: Callable[[VehicleState], None] | None = None,
                 record_all: bool = False,
                 on_state: Callable[[float, str, str, str], None] | None = None) -> None:
        self.cfg, self.p, self.m = cfg, params, cfg.mission
        if not isinstance(vehicle, SafeVehicle):
            vehicle = SafeVehicle(vehicle, cfg.safety, clock=clock)
        self.vehicle, self.cameras, self.models = vehicle, cameras, models
        self.detectors, self.coarse, self.fine = detectors, coarse, fine
        self.clock, self.log = clock, mission_log
        self.grasp_callback, self.on_frame, self.on_telemetry = grasp_callback, on_frame, on_telemetry
        self.record_all = record_all
        self.on_state = on_state
        self._interrupt: tuple[str, str] | None = None
        self._rtl_restore: float | None = None
        self.machine = ApproachMachine(on_change=self._on_state_change)
        if params.colour_track and cfg.target.color_bgr is not None:
            # compile / load the colour mask kernel now, not on the first close-range frame
            colour_blob(np.zeros((8, 8, 3), np.uint8), (1, 1, 1), 0.1, (0, 0))
        self.filter = TargetFilter(params.filter)
        self.plane = PlaneOffsetFilter(params.altitude_std_m, params.plane_offset_drift_mps)
        self._last_range_m: float | None = None
        self._plane_meas: tuple[float, float, int, float, float, str] | None = None
        self._stopping = False
        self._finished = asyncio.Event()
        self._wake_setpoint = asyncio.Event()
        self._wake_machine = asyncio.Event()
        self._commands: asyncio.Queue[tuple[str, Any]] = asyncio.Queue()
        self._frames: asyncio.Queue[tuple[Frame, float, VehicleState | None]] = asyncio.Queue(maxsize=4)
        self._state_entered_ns = clock.now_ns()
        self._t0_ns = clock.now_ns()
        self._wall0 = time.perf_counter()
        self.states: list[tuple[float, str, str]] = [(0.0, S.PREFLIGHT.value, "start")]
        # perception bookkeeping
        self._last_frame_ns: dict[str, int] = {}
        self._processed: dict[str, int] = {c: 0 for c in cameras}
        self._detected: dict[str, int] = {c: 0 for c in cameras}
        self._since_reset: dict[str, int] = {c: 0 for c in cameras}
        self._needed_since_ns: dict[str, int] = {}
        self._confirm: list[tuple[float, float, float]] = []
        self._target_in_narrow = False
        self._near_narrow = False
        self._fine_camera = CAMERA_NARROW
        self._narrow_miss_since_ns: int | None = None
        self._fine_estimates = 0
        self._fine_phase = "standoff"
        self._at_standoff_since_ns: int | None = None
        self._approach_yaw: float | None = None
        self._grasp_count = 0
        self._grasp_window: deque[tuple[float, float]] = deque(maxlen=64)
        self._fit_hint: tuple[float, str] | None = None  # (yaw, region) of the last full view
        self._grasp_done = False
        self._last_target: tuple[float, float, float] | None = None
        self._expected_visible = True
        # control bookkeeping
        self._offboard = False
        self._carrot: tuple[float, float, float] | None = None
        self._carrot_yaw = 0.0
        self._trim: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self._tool_off: tuple[float, float, float] | None = None
        self._route_s = 0.0
        self._route = [(w.north_m, w.east_m) for w in cfg.mission.route]
        self._route_len = gd.route_length_m(self._route)
        # (wall time of the fresh estimate's frame at mid-exposure, extra age s)
        self._fresh: tuple[float, float] | None = None
        self._goal_ok = True
        self._command_failed = ""
        self._offboard_since_ns = 0
        self._mode_bad_since_ns: int | None = None
        self._final_sent = False
        # telemetry bookkeeping
        self._tel_times: deque[int] = deque(maxlen=200)
        self._link_lost_since_ns: int | None = None
        self._events_seen = 0
        # results
        self.latencies_ms: list[float] = []
        self.perception_ms: list[float] = []
        self.detection_frames: list[tuple[float, str, str, int, Any]] = []
        self.failsafe_params: dict[str, float] | None = None
        self.failsafe_warnings: list[str] = []
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
            self._wake_machine.set()

    async def _sleep_until(self, t_ns: int) -> None:
        dt = (t_ns - self.clock.now_ns()) * 1e-9
        await self.clock.sleep(max(0.0, dt))

    # -- machine callbacks (O(1) bookkeeping only) ----------------------------------------------
    def _on_state_change(self, old: MissionState, new: MissionState, reason: str) -> None:
        now = self.clock.now_ns()
        self._state_entered_ns = now
        t = self._t_s()
        self.states.append((t, new.value, reason))
        rec: dict[str, Any] = {"old": old.value, "new": new.value, "reason": reason}
        if new is S.FAILSAFE:
            rec["action"] = self.machine.action
        self.log.write("state", **rec)
        log.info("%.2f s: %s -> %s (%s)", t, old.value, new.value, reason)
        if self.on_state is not None:
            self.on_state(t, new.value, reason, rec.get("action", ""))
        if new is S.TAKEOFF:
            self._commands.put_nowait(("arm_takeoff", None))
        elif new is S.CRUISE:
            self._confirm = []
            if not self._offboard:
                self._commands.put_nowait(("start_offboard", None))
            st = self.vehicle.state()
            self._route_s = max(self._route_s, gd.along_route_m(self._route, *st.position_ned_m[:2]))
            self._report_rangefinder(st)
        elif new is S.COARSE_APPROACH:
            self.filter.reset()
            for p in self._confirm:
                self.filter.update(p, self._coarse_std, now)
            self._approach_yaw = None
            self._near_narrow = False
            self._target_in_narrow = False
        elif new is S.FINE_APPROACH:
            self._fine_camera = CAMERA_NARROW
            self._narrow_miss_since_ns = None
            self._fine_phase = "standoff"
            self._at_standoff_since_ns = None
            self._fine_estimates = 0
            self._grasp_count = 0
            self._grasp_window.clear()
            self._fit_hint = None
        elif new is S.GRASP_READY:
            self.t_grasp_ready_s = t
            self._commands.put_nowait(("grasp", None))
        elif new is S.TARGET_LOST:
            self._confirm = []
            st = self.vehicle.state()
            self._carrot = st.position_ned_m
        elif new is S.DONE:
            self._commands.put_nowait(("final", self.m.on_done))
        elif new is S.FAILSAFE:
            self._commands.put_nowait(("final", self.machine.action))
        self._wake_setpoint.set()

    _coarse_std = 1.0

    # -- camera demand (pure function of the runner's state) -------------------------------------
    def cameras_needed(self) -> set[str]:
        st = self.machine.state
        if st is S.PREFLIGHT:
            return {CAMERA_WIDE, CAMERA_NARROW}
        if st in (S.CRUISE, S.TARGET_LOST):
            return {CAMERA_WIDE}
        if st is S.COARSE_APPROACH:
            return {CAMERA_WIDE, CAMERA_NARROW} if self._near_narrow else {CAMERA_WIDE}
        if st in (S.FINE_APPROACH, S.GRASP_READY):
            return {self._fine_camera}
        return set()

    # -- tasks ---------------------------------------------------------------------------------
    async def _camera_loop(self, cam_id: str) -> None:
        cam = self.cameras[cam_id]
        rate = min(self.p.process_rate_hz, float(getattr(cam, "frame_rate_hz", math.inf)))
        period_ns = int(1e9 / rate)
        next_ns = self.clock.now_ns()
        grab_timeout_s = max(0.5, 3.0 / rate)
        while not self._stopping:
            recording = (self.record_all and self.machine.state in AIRBORNE_STATES)
            if cam_id not in self.cameras_needed() and not recording:
                self._needed_since_ns.pop(cam_id, None)
                await self.clock.sleep(period_ns * 1e-9)
                next_ns = self.clock.now_ns()
                continue
            self._needed_since_ns.setdefault(cam_id, self.clock.now_ns())
            await self._sleep_until(next_ns)
            next_ns = max(next_ns + period_ns, self.clock.now_ns())
            try:
                frame = await asyncio.wait_for(
                    asyncio.shield(_run_blocking(functools.partial(cam.grab,
                                                                   timeout_s=grab_timeout_s))),
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

    async def _perception_loop(self) -> None:
        while not self._stopping:
            try:
                frame, wall, state = await asyncio.wait_for(self._frames.get(), timeout=0.5)
            except TimeoutError:
                continue
            if self.machine.final:
                continue
            await self._process(frame, wall, state)
            self._wake_machine.set()

    def _prior(self, cam_id: str) -> TargetPrior:
        return TargetPrior(min_area_px=12.0 if cam_id == CAMERA_WIDE else 100.0)

    def _estimator_for(self, cam_id: str) -> Any | None:
        st = self.machine.state
        if st in (S.CRUISE, S.TARGET_LOST, S.COARSE_APPROACH):
            return self.coarse if cam_id == CAMERA_WIDE else None
        if st in (S.FINE_APPROACH, S.GRASP_READY):
            return self.fine if cam_id == self._fine_camera else None
        return None

    async def _process(self, frame: Frame, wall: float, state: VehicleState | None) -> None:
        cam_id = frame.camera_id
        model = self.models[cam_id]
        detector = self.detectors[cam_id]
        estimator = self._estimator_for(cam_id)
        predicted = None
        filt = self.filter.state(frame.timestamp_ns)
        if filt is not None and state is not None and self.machine.state not in (S.CRUISE,):
            predicted = project_target(model, state, filt.position_ned_m)
        gate_px = 0.25 * max(model.width_px, model.height_px)
        colour = self.cfg.target.color_bgr if self.p.colour_check else None
        prior = self._prior(cam_id)
        close_phase = self.machine.state in (S.FINE_APPROACH, S.GRASP_READY)
        allow_cut = close_phase and self.p.plane_fit and self._fit_hint is not None
        self._plane_meas = None

        def work() -> tuple[Detection | None, TargetEstimate | Any, float, int, bool]:
            t0 = time.perf_counter()
            result = detector.detect(frame, prior)
            det = select_detection(
                result, predicted, model.width_px, model.height_px, self.p.image_border_px,
                gate_px, lambda d: plausible_size(d, model, state, self.cfg.target,
                                                  *self.p.size_ratio_range)
                and (colour is None or colour_matches(frame.image, d, colour,
                                                      self.p.colour_tolerance)),
                allow_cut=allow_cut)
            track = (close_phase and self.p.colour_track and colour is not None
                     and predicted is not None and np.isfinite(predicted).all())
            tracked = False
            if det is None and track:
                det = colour_blob(frame.image, colour, self.p.colour_tolerance, predicted,
                                  camera_id=cam_id)
                tracked = det is not None
            est = self._estimate(det, estimator, model, state, frame, close_phase, tracked)
            if track and not tracked and det is not None and not est:
                # the detector's region does not fit the target: try its colour region
                alt = colour_blob(frame.image, colour, self.p.colour_tolerance, predicted,
                                  camera_id=cam_id)
                alt_est = self._estimate(alt, estimator, model, state, frame, close_phase, True)
                if alt_est:
                    det, est, tracked = alt, alt_est, True
            return det, est, (time.perf_counter() - t0) * 1e3, len(result.detections), tracked

        det, est, ms, n_raw, tracked = await _run_blocking(work)
        self._use_perception(cam_id, frame, det, est, ms, n_raw, tracked, wall, state,
                             estimator, model)

    def _estimate(self, det: Detection | None, estimator: Any, model: CameraModel,
                  state: VehicleState | None, frame: Frame, close_phase: bool,
                  tracked: bool = False) -> Any:
        """Estimate of one detection (worker thread): the state's estimator, the coarse one
        when the fine one refuses, then the plane fit."""
        est: Any = None
        if det is None or estimator is None or state is None:
            return est
        view = CameraView(model, state, frame.timestamp_ns)
        est = estimator.estimate(det, view)
        if not est and estimator is not self.coarse:
            # the fine estimator refused (e.g. reprojection error): keep tracking with
            # the coarse estimate of the same detection, with less weight
            failed = est
            est = self.coarse.estimate(det, view)
            if est:
                est = replace(est, std_m=est.std_m * self.p.fallback_std_factor,
                              source=f"fallback:{est.source} (fine failed: {failed})")
        if est and self.p.plane_fit:
            est = self._plane_fit(est, det, view, close_phase, tracked)
        return est

    def _use_perception(self, cam_id: str, frame: Frame, det: Detection | None, est: Any,
                        ms: float, n_raw: int, tracked: bool, wall: float,
                        state: VehicleState | None, estimator: Any, model: CameraModel) -> None:
        """Log one processed frame and feed its estimate to the confirmation, the filter,
        the camera choice and the grasp check (loop thread)."""
        self.perception_ms.append(ms)
        if (self._plane_meas is not None and est
                and self._plane_meas[4] <= self.p.plane_max_cost):
            z, std, t_ns, rng_m, cost, region = self._plane_meas
            ok = self.plane.update(z, std, t_ns)
            self.log.write("plane", camera=cam_id, measured_m=z, std_m=std, accepted=ok,
                           frame_t_ns=t_ns, range_m=rng_m, cost=cost, region=region,
                           offset_m=self.plane.offset_m, offset_std_m=self.plane.std_m())
        self._plane_meas = None
        self._processed[cam_id] += 1
        self._since_reset[cam_id] += 1
        t = self._t_s()
        self.detection_frames.append((t, cam_id, self.machine.state.value, frame.seq,
                                      None if det is None else det.center_px))
        if det is not None:
            self._detected[cam_id] += 1
        self.log.write("detection", camera=cam_id, seq=frame.seq, frame_t_ns=frame.timestamp_ns,
                       n=n_raw, used=det is not None,
                       center_px=None if det is None else det.center_px,
                       corners_px=None if det is None else det.corners_px,
                       score=None if det is None else det.score, perception_ms=round(ms, 3),
                       colour_track=tracked)
        st = self.machine.state
        if cam_id == CAMERA_NARROW:
            fine_ok = bool(est) and not str(getattr(est, "source", "")).startswith("fallback")
            if fine_ok or estimator is None:
                self._narrow_miss_since_ns = None
            elif self._narrow_miss_since_ns is None:
                self._narrow_miss_since_ns = self.clock.now_ns()
        if est is not None and not est:
            self.log.write("estimate", camera=cam_id, ok=False, reason=str(est))
            est = None
        if est is not None and math.hypot(*est.position_cam_m) < self.p.min_estimate_range_m:
            self.log.write("estimate", camera=cam_id, ok=False,
                           reason=f"closer than min_estimate_range_m: {est.source}")
            est = None
        if est is not None:
            self.log.write("estimate", camera=cam_id, ok=True, source=est.source,
                           position_ned_m=est.position_ned_m, std_m=est.std_m,
                           position_cam_m=est.position_cam_m)
        # wide camera during search: confirmation over N frames
        if cam_id == CAMERA_WIDE and st in (S.CRUISE, S.TARGET_LOST):
            if est is None:
                self._confirm = []
            else:
                p = self._reference(est.position_ned_m, model, state)
                near_last = (st is not S.TARGET_LOST or self._last_target is None
                             or math.dist(p[:2], self._last_target[:2])
                             <= self.p.search_radius_m + self.p.confirm_radius_m)
                if self._confirm and math.dist(p, self._confirm[-1]) > self.p.confirm_radius_m:
                    self._confirm = []
                if near_last:
                    self._confirm.append(p)
                self._coarse_std = max(est.std_m, 0.2)
        elif est is not None and st in (S.COARSE_APPROACH, S.FINE_APPROACH, S.GRASP_READY):
            pnp_3d = est.full_3d and not est.source.startswith(("fallback", "bearing"))
            accepted = self.filter.update(self._reference(est.position_ned_m, model, state,
                                                          pnp_3d),
                                          est.std_m, frame.timestamp_ns,
                                          allow_reset=st is S.COARSE_APPROACH)
            if accepted and estimator is self.fine and not est.source.startswith("fallback"):
                self._fine_estimates += 1
            if accepted:
                self._fresh = (wall, 0.0)
                self._wake_setpoint.set()
        # switching logic from the wide image (coarse approach) and the predicted footprint
        filt = self.filter.state(frame.timestamp_ns)
        if filt is not None and state is not None:
            self._last_target = filt.position_ned_m
            self._update_camera_choice(state, filt.position_ned_m, cam_id, det)
        # grasp stability: every processed frame in the final phase
        if st in (S.FINE_APPROACH, S.GRASP_READY) and filt is not None:
            now_state = self.vehicle.state()
            tool = gd.tool_point_ned(now_state.position_ned_m, now_state.attitude_q,
                                     self.cfg.tool_point_m)
            h_err, dist = gd.tool_errors(tool, filt.position_ned_m)
            speed = math.sqrt(sum(v * v for v in now_state.velocity_ned_mps))
            self._grasp_count = self._grasp_stability(
                h_err, dist, speed <= self.p.grasp_max_speed_mps)
            self.tool_errors = (h_err, dist)

    def _grasp_stability(self, h_err: float, dist: float, slow: bool = True) -> int:
        """Frames counted towards ``grasp_stable_frames``: consecutive frames with the tool
        point within ``grasp_hold_factor`` x the tolerance (wind makes the hover jitter by a
        few cm) whose latest value is within the tolerance and whose running mean is within
        ``grasp_accept_fraction`` x the tolerance (the rest is the margin for the estimate's
        own error), in the descent phase; 0 resets."""
        tol = self.m.grasp_tolerance_m
        near = (self._fine_phase == "descend" and slow
                and h_err <= self.p.grasp_hold_factor * tol
                and abs(dist - self.m.grasp_distance_m) <= self.p.grasp_hold_factor * tol)
        if not near:
            self._grasp_window.clear()
            return 0
        self._grasp_window.append((h_err, dist))
        n = self.m.grasp_stable_frames
        recent = list(self._grasp_window)[-n:]
        h_mean = float(np.mean([h for h, _ in recent]))
        d_mean = float(np.mean([d for _, d in recent]))
        accept = self.p.grasp_accept_fraction * tol  # margin for the estimate's own error
        inside = (h_mean <= accept and abs(d_mean - self.m.grasp_distance_m) <= accept
                  and h_err <= tol and abs(dist - self.m.grasp_distance_m) <= tol)
        return len(self._grasp_window) if inside else min(len(self._grasp_window), n - 1)

    def _plane_fit(self, est: TargetEstimate, det: Detection, view: CameraView,
                   close_phase: bool, tracked: bool = False) -> TargetEstimate | EstimationFailed:
        """Replace an estimate's position by the top-plane fit of its detection
        (:mod:`~eaglemission.missions.silhouette`: top face or box silhouette, whichever
        explains the MBR). In the final approach a detection no model explains (part of the
        target, a merged blob) is refused; earlier the estimator's value is kept."""
        cam = view.camera_pose_ned
        m = view.model
        cut = touches_border(det, m.width_px, m.height_px, self.p.image_border_px)
        if cut and self._fit_hint is None:
            return EstimationFailed("plane fit: the detection is cut by the image border and "
                                    "no complete view gave the target's heading yet")
        yaw_hint, region_hint = self._fit_hint if cut else (None, None)  # type: ignore[misc]
        if tracked:
            # a colour region is the whole silhouette: the top and the shaded sides share the
            # target's chromaticity (not the detector's region of the earlier views)
            region_hint = "box"
        t_ns = view.timestamp_ns
        offset_m = self.plane.offset_m if self.p.plane_offset else 0.0
        fit = fit_on_top_plane(m, cam, det.center_px, det.corners_px, self.cfg.target,
                               ground_down_m=offset_m, yaw_hint_deg=yaw_hint,
                               region_hint=region_hint, iterations=8 if cut else 4)
        if fit is not None and not cut and fit.cost <= self.p.plane_fit_max_cost and close_phase:
            self._fit_hint = (fit.yaw_deg, fit.region)
        if fit is None or fit.cost > self.p.plane_fit_max_cost:
            if close_phase:
                why = "no fit" if fit is None else f"MBR mismatch {fit.cost:.2f}"
                return EstimationFailed(f"plane fit: {why} (> plane_fit_max_cost="
                                        f"{self.p.plane_fit_max_cost:g})")
            return est
        p = np.asarray(fit.position_ned_m)
        d = p - cam.t
        rng = float(np.linalg.norm(d))
        sin_dep = max(float(d[2]) / max(rng, 1e-9), 1e-3)
        std = rng * math.radians(self.p.plane_fit_angular_std_deg) / sin_dep
        if self.p.size_range and close_phase and fit.size_ratio > 0:
            # range from the apparent size (known target, 1/range) fused with the plane's
            # range (the measured plane, or the vehicle's altitude estimate): same ray. A cut
            # view's size is compared with the model clipped to the image like the detection.
            plane_std = (self.plane.std_m(t_ns) if self.p.plane_offset
                         else self.p.altitude_std_m)
            s_plane = plane_std / sin_dep
            s_size = self.p.size_std_fraction * rng
            if self.p.plane_offset and self.p.plane_from_size and not cut:
                # the plane this view measures: the size-only range along the same ray
                down_m = float(cam.t[2] + d[2] / fit.size_ratio)
                self._plane_meas = (down_m + float(self.cfg.target.height_m),
                                    s_size * sin_dep, t_ns, rng, fit.cost, fit.region)
            w = s_plane**2 / (s_plane**2 + s_size**2)
            k = 1.0 + w * (1.0 / fit.size_ratio - 1.0)
            d = d * k
            p = cam.t + d
            fit = PlaneFit((float(p[0]), float(p[1]), float(p[2])), fit.region, fit.yaw_deg,
                           fit.cost, fit.size_ratio)
        src = "fit" if est.source.startswith("fallback") else f"{est.source.split(' ')[0]}+fit"
        return replace(est, position_ned_m=fit.position_ned_m,
                       position_cam_m=tuple(float(v) for v in cam.R.T @ d),
                       std_m=std, source=f"{src}:{fit.region} yaw {fit.yaw_deg:.0f} "
                                         f"cost {fit.cost:.2f} size {fit.size_ratio:.3f}"
                                         + (" cut" if cut else ""))

    def _reference(self, p: Any, model: CameraModel | None = None,
                   state: VehicleState | None = None,
                   full_3d: bool = False) -> tuple[float, float, float]:
        """Apply ``vertical_reference``. With ``ground`` the target's top lies on the plane
        ``down = -target.height_m`` (flat ground at home's height): the estimate's *direction*
        from the camera (precise) is kept and its *range* (the weak part of a 4-point PnP at a
        few metres) comes from that plane. ``hybrid`` does so beyond ``full_3d_range_m`` and
        uses the full 3-D estimate closer in (where PnP is accurate and cancels the drift of
        the vehicle's own altitude estimate)."""
        if self.p.vertical_reference == "estimate":
            return (float(p[0]), float(p[1]), float(p[2]))
        plane = -float(self.cfg.target.height_m) + (self.plane.offset_m if self.p.plane_offset
                                                    else 0.0)
        if model is not None and state is not None:
            pose = camera_pose_ned(model, state.position_ned_m, state.attitude_q)
            d = np.asarray(p, dtype=np.float64) - pose.t
            if (self.p.vertical_reference == "hybrid" and full_3d
                    and float(np.linalg.norm(d)) <= self.p.full_3d_range_m):
                return (float(p[0]), float(p[1]), float(p[2]))
            if d[2] > 1e-3 and plane - pose.t[2] > 0:
                hit = pose.t + d * ((plane - pose.t[2]) / d[2])
                return (float(hit[0]), float(hit[1]), plane)
        return (float(p[0]), float(p[1]), plane)

    def _update_camera_choice(self, state: VehicleState, target: Any, cam_id: str,
                              det: Detection | None) -> None:
        t = self.cfg.target
        narrow = self.models[CAMERA_NARROW]
        wide = self.models[CAMERA_WIDE]
        px_n = footprint_px(narrow, state, target, t.length_m, t.width_m)
        st = self.machine.state
        if st is S.COARSE_APPROACH:
            in_view = fully_in_image(narrow, px_n, 0.0)
            if cam_id == CAMERA_WIDE and det is not None:
                in_view = in_view and _wide_detection_in_narrow(det, wide, narrow, state, target)
            self._target_in_narrow = in_view
            margin_n = -self.p.warm_margin_px * narrow.fx / wide.fx
            self._near_narrow = self._near_narrow or fully_in_image(narrow, px_n, margin_n)
        if st in (S.FINE_APPROACH, S.GRASP_READY):
            fill_n = fill_fraction(narrow, px_n)
            narrow_ok = fully_in_image(narrow, px_n, 8.0) and fill_n <= self.p.narrow_max_fill
            narrow_silent = (cam_id == CAMERA_NARROW and self._narrow_miss_since_ns is not None
                             and (self.clock.now_ns() - self._narrow_miss_since_ns) * 1e-9
                             > self.p.narrow_miss_switch_s)
            if self._fine_camera == CAMERA_NARROW and (not narrow_ok or narrow_silent):
                self._switch_fine_camera(CAMERA_WIDE)
            px_w = footprint_px(wide, state, target, t.length_m, t.width_m)
            cam = self.models[self._fine_camera]
            px_c = px_n if cam is narrow else px_w
            self._expected_visible = fully_in_image(cam, px_c, self.p.image_border_px)

    def _switch_fine_camera(self, cam_id: str) -> None:
        self._expected_visible = True
        self.log.write("event", source="mission", text=f"fine approach image source -> {cam_id}")
        self._fine_camera = cam_id

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
        vs = self.vehicle.state()
        filt = self.filter.state(now)
        timeout = getattr(self.m.timeouts, TIMEOUT_FIELD[st]) if st in TIMEOUT_FIELD else math.inf
        tel_hz = 0.0
        if len(self._tel_times) >= 2:
            span = (self._tel_times[-1] - self._tel_times[0]) * 1e-9
            tel_hz = (len(self._tel_times) - 1) / span if span > 0 else 0.0
        needed = self.cameras_needed()
        camera_failed = False
        if st is not S.PREFLIGHT:
            for c in needed:
                since = max(self._last_frame_ns.get(c, 0), self._needed_since_ns.get(c, now))
                if (now - since) * 1e-9 > self.p.camera_failure_after_s:
                    camera_failed = True
        streaming = all(c in self._last_frame_ns for c in self.cameras)
        warm = all(self._processed[c] >= max(1, self.p.narrow_warmup_frames)
                   for c in self.cameras)
        link_lost_s = 0.0 if self._link_lost_since_ns is None else (
            now - self._link_lost_since_ns) * 1e-9
        pilot = False
        if self._offboard and vs.link_ok and st in OFFBOARD_STATES:
            if vs.flight_mode is not FlightMode.OFFBOARD:
                if self._mode_bad_since_ns is None:
                    self._mode_bad_since_ns = now
                pilot = (now - self._mode_bad_since_ns) * 1e-9 > 0.3 and (
                    now - self._offboard_since_ns) * 1e-9 > 1.0
            else:
                self._mode_bad_since_ns = None
        return Snapshot(
            t_s=self._t_s(), time_in_state_s=(now - self._state_entered_ns) * 1e-9,
            state_timeout_s=timeout, armable=vs.armable, position_valid=vs.position_valid,
            cameras_streaming=streaming, detector_warm=warm, telemetry_hz=tel_hz,
            min_telemetry_hz=self.p.min_telemetry_hz, in_air=vs.in_air,
            altitude_m=-vs.position_ned_m[2], takeoff_altitude_m=self.m.cruise_altitude_m,
            takeoff_tolerance_m=self.p.takeoff_tolerance_m,
            route_finished=self._route_finished(vs),
            confirmed_frames=len(self._confirm), confirm_frames=self.m.confirm_frames,
            target_in_narrow_view=self._target_in_narrow,
            narrow_warm=self._since_reset.get(CAMERA_NARROW, 0) >= self.p.narrow_warmup_frames,
            has_target=filt is not None, target_age_s=filt.age_s if filt else math.inf,
            target_expected_visible=self._expected_visible,
            target_lost_after_s=self.p.target_lost_after_s,
            grasp_stable_frames=self._grasp_count,
            grasp_required_frames=self.m.grasp_stable_frames, grasp_done=self._grasp_done,
            search_exhausted=(st is S.TARGET_LOST
                              and (now - self._state_entered_ns) * 1e-9 > self.m.timeouts.target_lost_s),
            on_target_lost=self.m.on_target_lost, link_lost_s=link_lost_s,
            link_loss_timeout_s=self.cfg.safety.link_loss_timeout_s,
            gps_ok=vs.gps_fix and (vs.position_valid or not vs.link_ok),
            battery_remaining=vs.battery_remaining,
            low_battery_fraction=self.cfg.safety.low_battery_fraction,
            goal_inside_geofence=self._goal_ok, camera_failed=camera_failed,
            pilot_override=pilot, command_failed=self._command_failed,
            interrupt_reason=self._interrupt[0] if self._interrupt else "",
            interrupt_action=self._interrupt[1] if self._interrupt else "return")

    def _route_finished(self, vs: VehicleState) -> bool:
        if self._route_s < self._route_len - 1e-6:
            return False
        end = self._route[-1]
        return math.dist(vs.position_ned_m[:2], end) < 1.5

    # -- setpoints -----------------------------------------------------------------------------
    def _goal(self, vs: VehicleState, dt_s: float) -> tuple[tuple[float, float, float], float,
                                                              float] | None:
        """(goal position, goal yaw, speed) for the current state, None = no setpoint."""
        st = self.machine.state
        now = self.clock.now_ns()
        filt = self.filter.state(now)
        alt = -self.m.cruise_altitude_m
        if st is S.CRUISE:
            vs_s = gd.along_route_m(self._route, *vs.position_ned_m[:2])
            self._route_s = min(self._route_len, self._route_s + self.m.cruise_speed_mps * dt_s,
                                vs_s + 2.0 * self.m.cruise_speed_mps)
            n, e, yaw = gd.route_point(self._route, self._route_s)
            return (n, e, alt), yaw, self.m.cruise_speed_mps * 1.5
        if st is S.TARGET_LOST:
            assert self._carrot is not None
            base = self._approach_yaw if self._approach_yaw is not None else vs.yaw_deg
            sweep = 40.0 * math.sin(2 * math.pi * (now - self._state_entered_ns) * 1e-9 / 8.0)
            return self._carrot, base + sweep, self.m.approach_speed_mps
        if filt is None:
            return None
        target = filt.position_ned_m
        if st is S.COARSE_APPROACH:
            self._approach_yaw = gd.yaw_towards_deg(vs.position_ned_m, target)
            goal = gd.standoff_position(target, self._approach_yaw, self.m.standoff.horizontal_m,
                                        self.m.standoff.height_m)
            return goal, self._approach_yaw, self.m.approach_speed_mps
        if st in (S.FINE_APPROACH, S.GRASP_READY):
            if self._approach_yaw is None:
                self._approach_yaw = gd.yaw_towards_deg(vs.position_ned_m, target)
            yaw = self._approach_yaw
            standoff = gd.standoff_position(target, yaw, self.m.standoff.horizontal_m,
                                            self.m.standoff.height_m)
            if self._fine_phase == "standoff":
                at = math.dist(vs.position_ned_m, standoff) < self.p.fine_standoff_tolerance_m
                if not at:
                    self._at_standoff_since_ns = None
                elif self._at_standoff_since_ns is None:
                    self._at_standoff_since_ns = now
                dwell_s = 0.0 if self._at_standoff_since_ns is None else (
                    now - self._at_standoff_since_ns) * 1e-9
                if at and (self._fine_estimates >= self.p.fine_min_estimates
                           or dwell_s > self.p.standoff_max_wait_s):
                    self._fine_phase = "descend"
                    self.log.write("event", source="mission",
                                   text="at the standoff: descending to the grasp pose")
                else:
                    return standoff, yaw, self.m.approach_speed_mps
            grasp = gd.grasp_position(target, yaw, self.cfg.tool_point_m, self.m.grasp_distance_m)
            if self.p.tilt_compensation:
                # the vehicle leans into the wind: put the TILTED tool point over the target
                off = self._tool_offset(vs, dt_s)
                grasp = (target[0] - off[0], target[1] - off[1],
                         target[2] - self.m.grasp_distance_m - off[2])
            return grasp, yaw, self.p.final_speed_mps
        return None

    def _tool_offset(self, vs: VehicleState, dt_s: float) -> tuple[float, float, float]:
        """The tool point's NED offset from the vehicle at its current attitude, low-passed
        (time constant 1 s) so the attitude's jitter does not move the goal."""
        off = gd.tool_point_ned((0.0, 0.0, 0.0), vs.attitude_q, self.cfg.tool_point_m)
        if self._tool_off is None:
            self._tool_off = off
        else:
            k = min(1.0, dt_s / 1.0)
            self._tool_off = tuple(a + k * (b - a)  # type: ignore[assignment]
                                   for a, b in zip(self._tool_off, off))
        return self._tool_off

    def _update_trim(self, goal: Any, position: Any, dt_s: float) -> tuple[float, float, float]:
        """Integral trim of the setpoint at the grasp pose: a multicopter's position loop
        holds a steady offset in wind (2-3 cm measured at 2.6 m/s), more than the grasp
        tolerance; the trim integrates the (estimated) position error once the carrot has
        reached the grasp goal, clamped to ``grasp_trim_max_m``."""
        holding = ((self.machine.state is S.FINE_APPROACH and self._fine_phase == "descend")
                   or self.machine.state is S.GRASP_READY)
        if not holding or self.p.grasp_trim_gain_per_s <= 0:
            return (0.0, 0.0, 0.0)
        assert self._carrot is not None
        if math.dist(self._carrot, goal) > 0.05:
            return self._trim
        k = self.p.grasp_trim_gain_per_s * dt_s
        lim = self.p.grasp_trim_max_m
        return tuple(float(np.clip(t + k * (g - p), -lim, lim))  # type: ignore[return-value]
                     for t, g, p in zip(self._trim, goal, position))

    def _inside_envelope(self, pos: Any) -> bool:
        """The goal is inside the geofence, with the safety envelope's margin when the vehicle
        is a SafeVehicle (it would clamp the setpoint short of the goal forever)."""
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
            if not self._offboard or self.machine.state not in OFFBOARD_STATES:
                continue
            vs = self.vehicle.state()
            goal = self._goal(vs, dt)
            if goal is None:
                goal = (self._carrot or vs.position_ned_m, self._carrot_yaw, 0.0)
            pos, yaw, speed = goal
            self._goal_ok = self._inside_envelope(pos)
            if self._carrot is None:
                self._carrot = vs.position_ned_m
            if self.machine.state is S.TARGET_LOST:
                self._carrot = pos
            else:
                self._carrot = gd.step_towards(self._carrot, pos, speed * dt)
                # never let the carrot run away from the vehicle (wind, clamping)
                lead = math.dist(self._carrot, vs.position_ned_m)
                max_lead = max(2.0, 2.0 * speed)
                if lead > max_lead:
                    self._carrot = gd.step_towards(vs.position_ned_m, self._carrot, max_lead)
            self._carrot_yaw = gd.yaw_step_deg(self._carrot_yaw, yaw, self.p.yaw_rate_degps * dt)
            self._trim = self._update_trim(pos, vs.position_ned_m, dt)
            sp = gd.setpoint_at(tuple(c + t for c, t in zip(self._carrot, self._trim)),
                                self._carrot_yaw)
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
            filt = self.filter.state(now)
            self.log.write("setpoint", state=self.machine.state.value, setpoint=sp,
                           goal=pos, latency_ms=None if latency is None else round(latency, 3),
                           target=None if filt is None else filt.position_ned_m)

    # -- actuator ------------------------------------------------------------------------------
    async def _command(self, name: str, coro_fn: Callable[[], Awaitable[Any]]) -> bool:
        timeout = self.m.timeouts.command_s
        try:
            await asyncio.wait_for(coro_fn(), timeout=timeout)
        except (errors.VehicleError, TimeoutError) as exc:
            self.log.write("command", name=name, ok=False, error=str(exc))
            return False
        self.log.write("command", name=name, ok=True)
        return True

    async def _actuator_loop(self) -> None:
        v = self.vehicle
        await self._align_autopilot()
        await self._read_failsafe_params()
        while not self._stopping:
            try:
                name, arg = await asyncio.wait_for(self._commands.get(), timeout=0.5)
            except TimeoutError:
                continue
            if name == "arm_takeoff":
                ok = await self._command("arm", v.arm) and await self._command(
                    "takeoff", lambda: v.takeoff(self.m.cruise_altitude_m))
                if not ok:
                    self._command_failed = "arm/takeoff refused"
            elif name == "start_offboard":
                vs = v.state()
                self._carrot = vs.position_ned_m
                self._carrot_yaw = vs.yaw_deg
                sp = gd.setpoint_at(self._carrot, self._carrot_yaw)
                if await self._command("start_offboard",
                                       functools.partial(v.start_offboard, sp)):
                    self._offboard = True
                    self._offboard_since_ns = self.clock.now_ns()
                else:
                    self._command_failed = "offboard refused"
            elif name == "grasp":
                await self._grasp()
            elif name == "final":
                try:
                    await self._final(arg)
                    if not v.state().in_air:
                        await self._restore_autopilot()
                finally:
                    self._finished.set()
                return

    async def _grasp(self) -> None:
        action = self.m.grasp_action
        if action == "gripper":
            await self._command("grab", self.vehicle.grab)
        elif action == "callback" and self.grasp_callback is not None:
            try:
                await asyncio.wait_for(self.grasp_callback(), timeout=self.m.timeouts.grasp_ready_s)
                self.log.write("command", name="grasp_callback", ok=True)
            except Exception as exc:  # a user callback must not crash the mission
                self.log.write("command", name="grasp_callback", ok=False, error=repr(exc))
        # hold the grasp pose on the live estimate for the stable period before leaving
        await self.clock.sleep(max(0.0, self.m.grasp_stable_frames / self.p.process_rate_hz))
        self._grasp_done = True
        self._wake_machine.set()

    async def _final(self, action: str) -> None:
        v = self.vehicle
        self.log.write("event", source="mission", text=f"final action: {action}")
        if action in ("hold", "land", "return"):
            was_offboard, self._offboard = self._offboard, False
            if was_offboard:  # leave offboard explicitly (MAVSDK: offboard.stop()) first
                await self._command("stop_offboard", v.stop_offboard)
            fn = {"hold": v.hold, "land": v.land, "return": v.return_to_launch}[action]
            deadline = self.clock.now_ns() + int(self._settle_s() * 1e9)
            while not await self._command(action, fn):
                if self.clock.now_ns() > deadline:
                    break
                await self.clock.sleep(1.0)  # e.g. the link is down: retry
        elif action == "release":
            self._offboard = False  # stop commanding: the pilot has the vehicle
        self._final_sent = True
        # let the flight finish (landing / return) so the whole flight is recorded
        if action in ("land", "return"):
            deadline = self.clock.now_ns() + int(self._settle_s() * 1e9)
            while self.clock.now_ns() < deadline:
                vs = v.state()
                if not vs.in_air and not vs.armed:
                    break
                await self.clock.sleep(0.5)
        else:
            await self.clock.sleep(2.0)

    def _settle_s(self) -> float:
        """How long the final action may take (an interrupt has its own bound)."""
        if self._interrupt is not None:
            return min(self.p.settle_timeout_s, self.cfg.safety.interrupt_timeout_s)
        return self.p.settle_timeout_s

    async def _align_autopilot(self) -> None:
        """Put the autopilot's own return height inside the envelope before the flight
        (RTL_RETURN_ALT: PX4 returns at 30 m by default, above most missions' altitude band):
        the cruise altitude, clamped into the band. Restored after the flight. Vehicles
        without parameters are left alone."""
        get = getattr(self.vehicle.inner, "get_param", None)
        put = getattr(self.vehicle.inner, "set_param", None)
        if get is None or put is None:
            return
        s = self.cfg.safety
        want = max(s.min_altitude_m + 1.0, min(self.m.cruise_altitude_m, s.max_altitude_m - 1.0))
        try:
            have = float(await asyncio.wait_for(get("RTL_RETURN_ALT"),
                                                timeout=self.m.timeouts.command_s))
            if abs(have - want) > 1e-3:
                await asyncio.wait_for(put("RTL_RETURN_ALT", want),
                                       timeout=self.m.timeouts.command_s)
                self._rtl_restore = have
            self.log.write("param_set", name="RTL_RETURN_ALT", was=have, now=want)
        except (errors.VehicleError, TimeoutError) as exc:
            self.log.write("param_set", name="RTL_RETURN_ALT", ok=False, error=str(exc))

    async def _restore_autopilot(self) -> None:
        if self._rtl_restore is None:
            return
        put = getattr(self.vehicle.inner, "set_param", None)
        try:
            await asyncio.wait_for(put("RTL_RETURN_ALT", self._rtl_restore),  # type: ignore[misc]
                                   timeout=self.m.timeouts.command_s)
            self.log.write("param_set", name="RTL_RETURN_ALT", now=self._rtl_restore,
                           restored=True)
        except (errors.VehicleError, TimeoutError) as exc:
            self.log.write("param_set", name="RTL_RETURN_ALT", ok=False, restored=False,
                           error=str(exc))
        self._rtl_restore = None

    async def _read_failsafe_params(self) -> None:
        """Read PX4's own failsafe parameters back when the vehicle offers ``get_param``."""
        get = getattr(self.vehicle, "get_param", None)
        if get is None:
            inner = getattr(self.vehicle, "inner", None)
            get = getattr(inner, "get_param", None)
        if get is None:
            self.log.write("failsafe_params", available=False)
            return
        values: dict[str, float] = {}
        for name in PX4_FAILSAFE_PARAMS:
            try:
                res = get(name)
                if asyncio.iscoroutine(res):
                    res = await asyncio.wait_for(res, timeout=self.m.timeouts.command_s)
                values[name] = float(res)
            except Exception as exc:  # noqa: BLE001 - a missing param is reported, not fatal
                log.debug("param %s: %s", name, exc)
        self.failsafe_params = values
        warnings = failsafe_param_warnings(values, self.cfg.safety)
        self.failsafe_warnings = warnings
        self.log.write("failsafe_params", available=True, values=values, warnings=warnings)
        for w in warnings:
            log.warning("PX4 failsafe parameters: %s", w)

    # -- telemetry -----------------------------------------------------------------------------
    async def _telemetry_loop(self) -> None:
        period = 0.02
        last_log = 0
        last_range_ns = -1
        while not self._stopping:
            vs = self.vehicle.state()
            now = self.clock.now_ns()
            if not self._tel_times or vs.timestamp_ns != self._tel_times[-1]:
                self._tel_times.append(vs.timestamp_ns)
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

    def _report_rangefinder(self, vs: VehicleState) -> None:
        """Once airborne: say whether the target's plane will be measured (log + warnings)."""
        if self.p.rangefinder == "off" or not self.p.plane_offset:
            text = "rangefinder not used (mission.params): the grasp height follows the " \
                   "vehicle's altitude estimate"
        elif vs.distance_to_ground_m is None:
            text = "no downward rangefinder reading in the telemetry: the grasp height " \
                   "follows the vehicle's altitude estimate (docs/mission.md)"
            self.failsafe_warnings.append(text)
        else:
            text = f"rangefinder: {vs.distance_to_ground_m:.2f} m to the ground"
        self.log.write("event", source="mission", text=text)

    def _use_rangefinder(self, vs: VehicleState) -> None:
        """A downward distance reading measures where the ground is *in the vehicle's estimated
        frame* (estimated down + range x cos tilt): the plane offset the visual fits need, free
        of the altitude estimate's drift (flat ground between the vehicle and the target)."""
        d = vs.distance_to_ground_m
        if (d is None or not self.p.plane_offset or self.p.rangefinder == "off" or not vs.in_air
                or self.machine.state not in (S.COARSE_APPROACH, S.FINE_APPROACH,
                                              S.GRASP_READY)):
            return
        cos_tilt = down_axis_cos_tilt(vs.attitude_q)
        if not math.isfinite(d) or cos_tilt < 0.5 or d == self._last_range_m:
            return  # a repeated value is the same sample (telemetry outpaces the sensor)
        self._last_range_m = d
        self.plane.update(vs.position_ned_m[2] + d * cos_tilt, self.p.rangefinder_std_m,
                          vs.timestamp_ns)

    def _result(self) -> MissionResult:
        return MissionResult(
            final_state=self.machine.state.value, reason=self.machine.reason,
            action=self.machine.action if self.machine.state is S.FAILSAFE else self.m.on_done,
            states=self.states, t_start_s=0.0, t_end_s=self._t_s(),
            t_grasp_ready_s=self.t_grasp_ready_s, estimated_tool_errors_m=self.tool_errors,
            latencies_ms=self.latencies_ms, frames_processed=dict(self._processed),
            detections=dict(self._detected), detection_frames=self.detection_frames,
            failsafe_params=self.failsafe_params, failsafe_warnings=self.failsafe_warnings,
            perception_ms=self.perception_ms,
            wall_s=time.perf_counter() - self._wall0)

    # -- main ----------------------------------------------------------------------------------
    async def run(self) -> MissionResult:
        self.log.write("start", config_state=self.machine.state.value,
                       params=self.p.model_dump(), cameras=list(self.cameras))

        async def stopper() -> None:
            await self._finished.wait()
            self._stopping = True

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
                tg.create_task(self._actuator_loop())
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


def _is_virtual() -> bool:
    from eaglemission.clock import VirtualTimeLoop

    try:
        return isinstance(asyncio.get_running_loop(), VirtualTimeLoop)
    except RuntimeError:
        return False


async def _run_blocking(fn: Callable[..., Any], *args: Any) -> Any:
    from eaglemission.clock import run_blocking

    return await run_blocking(fn, *args)


def _wide_detection_in_narrow(det: Detection, wide: CameraModel, narrow: CameraModel,
                              state: VehicleState, target: Any) -> bool:
    """Paper Fig. 4(c): the wide-image detection lies inside the narrow camera's view drawn in
    the wide image (the ``estimators.fov`` predicate)."""
    height = float(target[2]) - float(state.position_ned_m[2])  # vehicle height above the top
    if height <= 0:
        return False
    try:
        from eaglemission.estimators.fov import target_in_narrow_view
    except ImportError as exc:  # pragma: no cover - F's module is part of the package
        log.debug("estimators.fov unavailable: %s", exc)
    else:
        return bool(target_in_narrow_view(wide, narrow, det.corners_px,
                                          height_above_ground_m=height,
                                          attitude_q=state.attitude_q))
    # fallback: cast the detection's corners onto the target plane and project into narrow
    pose_w = camera_pose_ned(wide, state.position_ned_m, state.attitude_q)
    rays = wide.rays_optical(det.corners_px) @ pose_w.R.T
    pts = []
    for r in rays:
        if r[2] <= 1e-6:
            return False
        s = (float(target[2]) - pose_w.t[2]) / r[2]
        pts.append(pose_w.t + s * r)
    pose_n = camera_pose_ned(narrow, state.position_ned_m, state.attitude_q).inverse()
    px = narrow.project(pose_n.apply(np.asarray(pts)))
    return fully_in_image(narrow, px, 0.0)
