"""Closed-loop simulation: simulated vehicle (+ safety envelope) + synthetic dual camera +
detector + estimators + the approach mission, on the virtual-time loop (faster than real time)
or in real time; and fault injection for the fault tests.

The mission sees only what a real flight would (telemetry, frames); ground truth (the
simulator's true trajectory, the world's target) goes to the evaluator only.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from eaglemission.missions.approach import ApproachConfig, MissionState
from eaglemission.missions.evaluator import Evaluation, evaluate
from eaglemission.missions.log import MissionLog
from eaglemission.missions.runner import BoundLoopClock, MissionResult, MissionRunner

from eaglemission import errors, registry
from eaglemission.clock import run_virtual
from eaglemission.config import MissionFile
from eaglemission.names import CAMERA_NARROW, CAMERA_WIDE
from eaglemission.types import Frame

log = logging.getLogger(__name__)


# ---------------------------------------------------------------------------------------------
# Faults
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Fault:
    """A fault injected when the mission enters ``at_state`` (+ ``delay_s``).

    kind: ``camera_dropout`` | ``occlusion`` | ``link_loss`` | ``gps_loss`` | ``battery_low`` |
    ``pilot_mode``
    """

    kind: str
    at_state: str = "FINE_APPROACH"
    delay_s: float = 0.5
    duration_s: float = 1.0
    value: float = 0.1


class FaultyCamera:
    """Wraps a camera: raises :class:`GrabTimeout` during a dropout, hides the target during an
    occlusion (painted over from the world's truth: this is the test harness, not the
    mission)."""

    def __init__(self, inner: Any, world: Any, clock: Any) -> None:
        self.inner, self.world, self.clock = inner, world, clock
        self.camera_id = inner.camera_id
        self.model = inner.model
        self.dropout_until_ns = 0
        self.occluded_until_ns = 0

    def open(self) -> None:
        self.inner.open()

    def close(self) -> None:
        self.inner.close()

    def grab(self, *, timeout_s: float) -> Frame:
        now = self.clock.now_ns()
        if now < self.dropout_until_ns:
            raise errors.GrabTimeout(self.camera_id, timeout_s)
        frame = self.inner.grab(timeout_s=timeout_s)
        if now < self.occluded_until_ns:
            truth = self.world.truth(self.camera_id, frame.seq)
            if truth.target_visible and len(truth.target_polygon_px) >= 3:
                img = frame.image.copy()
                poly = np.asarray(truth.target_polygon_px, dtype=np.float64)
                c = poly.mean(axis=0)
                big = c + (poly - c) * 1.6  # a grass-coloured cover larger than the target
                mask = np.zeros(img.shape[:2], np.uint8)
                cv2.fillPoly(mask, [np.round(big).astype(np.int32)], 255)
                ring = cv2.dilate(mask, np.ones((15, 15), np.uint8)) & ~mask
                colour = np.median(img[ring > 0], axis=0) if (ring > 0).any() else img.mean((0, 1))
                img[mask > 0] = colour.astype(np.uint8)
                frame = Frame(img, frame.timestamp_ns, frame.camera_id, frame.seq,
                              frame.exposure_s)
        return frame


async def _inject_faults(faults: list[Fault], runner: MissionRunner, vehicle: Any,
                         cameras: dict[str, FaultyCamera], clock: Any, mlog: MissionLog) -> None:
    pending = list(faults)
    armed: dict[int, int] = {}
    while pending and not runner.machine.final:
        now = clock.now_ns()
        for f in list(pending):
            key = id(f)
            if key not in armed and runner.machine.state.value == f.at_state:
                armed[key] = now + int(f.delay_s * 1e9)
            if key in armed and now >= armed[key]:
                pending.remove(f)
                until = now + int(f.duration_s * 1e9)
                mlog.write("event", source="fault", text=f"inject {f.kind}", fault=f)
                if f.kind == "camera_dropout":
                    for c in cameras.values():
                        c.dropout_until_ns = until
                elif f.kind == "occlusion":
                    for c in cameras.values():
                        c.occluded_until_ns = until
                elif f.kind == "link_loss":
                    vehicle.inject_link_loss(f.duration_s)
                elif f.kind == "gps_loss":
                    vehicle.inject_gps_loss(f.duration_s)
                elif f.kind == "battery_low":
                    vehicle.set_battery_fraction(f.value)
                elif f.kind == "pilot_mode":
                    from eaglemission.types import FlightMode

                    vehicle.pilot_take_control(FlightMode.POSCTL)
                else:
                    raise ValueError(f"fault kind: unknown {f.kind!r}")
        await clock.sleep(0.05)


# ---------------------------------------------------------------------------------------------
# Building and flying
# ---------------------------------------------------------------------------------------------
@dataclass
class SimOutcome:
    """A simulated flight: what the mission reported, what the evaluator judged, the truth."""

    result: MissionResult
    evaluation: Evaluation
    trajectory: list[Any]
    target_position_ned_m: tuple[float, float, float]
    log: MissionLog
    wall_s: float
    sim_s: float
    estimated_trajectory: list[tuple[int, tuple[float, float, float]]] = field(default_factory=list)
    world: Any = None
    t0_ns: int = 0

    @property
    def speedup(self) -> float:
        return self.sim_s / self.wall_s if self.wall_s > 0 else math.inf


def build_detector(cfg: MissionFile, params: ApproachConfig, camera_id: str) -> Any:
    """One detector per camera; ``params.detector_downscale`` is applied when the detector
    offers ``downscale`` and the config does not set it."""
    cls = registry.get("detectors", cfg.detector.type)
    p = dict(cfg.detector.params)
    if "downscale" in getattr(cls.Config, "model_fields", {}) and "downscale" not in p:
        p["downscale"] = params.detector_downscale
    if (camera_id == "narrow" and params.narrow_threshold != "config"
            and "regions" in getattr(cls.Config, "model_fields", {})):
        regions = dict(p.get("regions", {}))
        regions.setdefault("threshold", params.narrow_threshold)  # paper: adaptive threshold
        p["regions"] = regions
    return registry.load("detectors", cfg.detector.type, p, camera_id=camera_id)


def vehicle_params(cfg: MissionFile) -> dict[str, Any]:
    """The simulated vehicle's params with the autopilot's own speeds set inside the safety
    envelope, as a field team sets PX4's MPC_XY_CRUISE / MPC_Z_VEL_MAX_UP / MPC_Z_VEL_MAX_DN /
    RTL_RETURN_ALT: the envelope only shapes *our* setpoints, and autopilot-flown moves (RTL,
    land, takeoff) fly at the autopilot's speeds. Values the config sets are kept."""
    params = dict(cfg.vehicle.params)
    if cfg.vehicle.type != "simulated":
        return params
    s = cfg.safety
    dyn = dict(params.get("dynamics", {}))
    dyn.setdefault("cruise_speed_mps", min(5.0, 0.9 * s.max_horizontal_speed_mps))
    dyn.setdefault("max_horizontal_speed_mps", min(10.0, s.max_horizontal_speed_mps))
    dyn.setdefault("max_up_speed_mps", min(3.0, 0.9 * s.max_vertical_speed_mps))
    dyn.setdefault("max_down_speed_mps", min(1.5, 0.9 * s.max_vertical_speed_mps))
    params["dynamics"] = dyn
    params.setdefault("rtl_return_altitude_m",
                      max(s.min_altitude_m + 1.0, min(cfg.mission.cruise_altitude_m,
                                                      s.max_altitude_m - 1.0)))
    return params


def expected_action(cfg: MissionFile, params: ApproachConfig, faults: list[Fault]) -> str | None:
    """The safe action the configuration prescribes for the first fault (for the evaluator)."""
    s = cfg.safety
    for f in faults:
        return {"link_loss": s.link_loss_action, "gps_loss": s.gps_loss_action,
                "battery_low": s.low_battery_action, "pilot_mode": "release",
                "camera_dropout": None, "occlusion": None}.get(f.kind)
    return None


async def fly_simulation(cfg: MissionFile, *, params: ApproachConfig | None = None,
                         log_path: str | Path | None = None, record_dir: str | Path | None = None,
                         faults: list[Fault] | None = None,
                         grasp_callback: Callable[[], Awaitable[None]] | None = None,
                         on_state: Callable[[float, str, str, str], None] | None = None,
                         keep_log: bool = True, **_context: Any) -> SimOutcome:
    """Build the simulated setup of ``cfg`` and fly the mission (inside a running loop)."""
    from eaglemission.drivers.cameras.synthetic import make_synthetic_rig

    from eaglemission.safety import SafeVehicle

    if cfg.simulation is None:
        raise errors.ConfigError("simulation: a simulated flight needs the `simulation` section")
    if params is None:
        params = ApproachConfig.model_validate(dict(cfg.mission.params))
    faults = list(faults or [])
    loop = asyncio.get_running_loop()
    clock = BoundLoopClock(loop)
    mlog = MissionLog(log_path, now_ns=clock.now_ns, keep=keep_log)
    inner = registry.load("vehicles", cfg.vehicle.type, vehicle_params(cfg), clock=clock,
                          simulation=cfg.simulation, safety=cfg.safety)
    vehicle = SafeVehicle(inner, cfg.safety, clock=clock,
                          logger=logging.getLogger("eaglemission.safety"))
    true_pose = inner.true_pose_at  # the simulated vehicle is thread-safe (RLock)
    rig = make_synthetic_rig(cfg, true_pose, clock)
    world = rig.world
    cams = {CAMERA_WIDE: FaultyCamera(rig.wide, world, clock),
            CAMERA_NARROW: FaultyCamera(rig.narrow, world, clock)}
    models = {c: cam.model for c, cam in cams.items()}
    detectors = {c: build_detector(cfg, params, c) for c in cams}
    coarse = registry.load("estimators", cfg.estimators.coarse.type, cfg.estimators.coarse.params,
                           target=cfg.target)
    fine = registry.load("estimators", cfg.estimators.fine.type, cfg.estimators.fine.params,
                         target=cfg.target)
    recorder = None
    if record_dir is not None:
        recorder = _make_recorder(record_dir, models)
    est_traj: list[tuple[int, tuple[float, float, float]]] = []

    def on_telemetry(vs: Any) -> None:
        if not est_traj or vs.timestamp_ns - est_traj[-1][0] >= 100_000_000:
            est_traj.append((vs.timestamp_ns, vs.position_ned_m))
        if recorder is not None:
            recorder.telemetry(vs)

    wall0 = time.perf_counter()
    t0_ns = clock.now_ns()
    await vehicle.connect()
    for c in cams.values():
        c.open()
    try:
        runner = MissionRunner(cfg, params, vehicle=vehicle, cameras=cams, models=models,
                               detectors=detectors, coarse=coarse, fine=fine, clock=clock,
                               mission_log=mlog, grasp_callback=grasp_callback,
                               on_frame=None if recorder is None else recorder.frame,
                               on_telemetry=on_telemetry, record_all=recorder is not None)
        if on_state is not None:
            report_state_changes(runner, on_state, clock, t0_ns)
        fault_task = asyncio.create_task(_inject_faults(faults, runner, inner, cams, clock, mlog))
        try:
            result = await runner.run()
        finally:
            fault_task.cancel()
            try:
                await fault_task
            except (asyncio.CancelledError, Exception):  # noqa: BLE001
                pass
    finally:
        for c in cams.values():
            c.close()
        await vehicle.close()
        if recorder is not None:
            recorder.close()
    wall = time.perf_counter() - wall0
    traj = list(inner.trajectory())
    target = tuple(float(v) for v in world.target_position_ned_m)
    ev = evaluate(result, traj, cfg, target, t0_ns=t0_ns,
                  expected_action=expected_action(cfg, params, faults))
    mlog.write("evaluation", **ev.as_dict())
    mlog.close()
    return SimOutcome(result, ev, traj, target, mlog, wall, (clock.now_ns() - t0_ns) * 1e-9,
                      est_traj, world, t0_ns)


def run_simulation(cfg: MissionFile, *, realtime: bool = False, **kwargs: Any) -> SimOutcome:
    """Fly ``cfg`` on a fresh virtual-time loop (or in real time) and return the outcome."""
    if realtime:
        return asyncio.run(fly_simulation(cfg, **kwargs))
    return run_virtual(fly_simulation(cfg, **kwargs))


def _make_recorder(record_dir: str | Path, models: dict[str, Any]) -> Any:
    """The replay-format recorder (both camera streams + telemetry)."""
    from eaglemission.drivers.cameras.recorder import RunRecorder

    return _RecorderAdapter(RunRecorder(Path(record_dir), models=models))


class _RecorderAdapter:
    def __init__(self, rec: Any) -> None:
        self.rec = rec

    def frame(self, frame: Frame) -> None:
        self.rec.write_frame(frame)

    def telemetry(self, state: Any) -> None:
        self.rec.write_state(state)

    def close(self) -> None:
        self.rec.close()


def report_state_changes(runner: MissionRunner, on_state: Callable[..., None], clock: Any,
                         t0_ns: int) -> None:
    """Chain ``on_state(t_s, state, reason, failsafe_action)`` after the machine's own
    state-change callback (the CLI prints the state changes with it)."""
    prev = runner.machine._on_change

    def _cb(old: MissionState, new: MissionState, reason: str) -> None:
        if prev is not None:
            prev(old, new, reason)
        action = runner.machine.action if new is MissionState.FAILSAFE else ""
        on_state((clock.now_ns() - t0_ns) * 1e-9, new.value, reason, action)

    runner.machine._on_change = _cb
