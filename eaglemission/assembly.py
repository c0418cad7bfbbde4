"""The one assembly path: a validated :class:`~eaglemission.config.MissionFile` -> plugins ->
a flight.

Every flight goes through here (``eaglemission run``, ``campaign``, the tests and the library
API): the vehicle by its ``type`` and params, both cameras by their ``type``, one detector per
camera, the coarse and fine estimators and the mission, all through
:mod:`eaglemission.registry`. A deployment is a config, not a code path (docs/deployments.md):

* simulation: ``synthetic`` cameras + the ``simulated`` vehicle, virtual time;
* emulator / autopilot SITL: the ``mavsdk`` vehicle at a URL, ``synthetic`` cameras rendering
  from the autopilot's ground truth (HIL_STATE_QUATERNION) when it streams it;
* replay: ``replay`` cameras + the ``replay`` vehicle, a recording played open loop;
* field: ``genicam`` cameras + the ``mavsdk`` vehicle, nothing simulated.

Plugin classes may declare (all optional): ``wall_clock = True`` (needs host time: MAVSDK,
GenICam), ``simulated = True`` (no real aircraft behind it: no arming confirmation),
``start_time_ns(config) -> int | None`` (a recording's first stamp: a virtual-time replay
starts its clock there), ``config_problems(mission_file, path) -> list[str]`` (cross-section
checks for ``validate``), and on instances ``summary() -> str`` (the run header) and, for
vehicles, ``ground_truth() -> GroundTruth | None``.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from eaglemission import autopilot_guard, fault_injection, live, mcap_options, mcap_record, registry
from eaglemission.autopilot_guard import AutopilotGuard
from eaglemission.clock import BoundLoopClock, Clock, run_blocking, run_virtual
from eaglemission.config import MissionFile, merge_params
from eaglemission.context import SharedContext
from eaglemission.errors import (
    CameraError,
    ConfigError,
    DriverError,
    EagleMissionError,
    PluginError,
)
from eaglemission.gc_pauses import frozen_heap
from eaglemission.interfaces import (
    FlightParts,
    GroundTruth,
    MissionHooks,
    MissionOutcome,
    PlaneFitter,
    Tracker,
    World,
)
from eaglemission.interrupts import EXIT_INTERRUPTED, FlightInterrupts
from eaglemission.names import CAMERA_NARROW, CAMERA_WIDE
from eaglemission.safety import SafeVehicle
from eaglemission.types import XYZ, Quat
from eaglemission.vehicle_tap import VehicleTap

log = logging.getLogger(__name__)

CAMERAS = (CAMERA_WIDE, CAMERA_NARROW)

# Exit codes of `eaglemission run` (README, "Exit codes").
EXIT_DONE = 0
EXIT_ERROR = 1
EXIT_CONFIG = 2
EXIT_FAILSAFE = 3
EXIT_CONNECTION = 4
EXIT_PREFLIGHT = 5
EXIT_TRUTH_FAILED = 6
EXIT_REPLAY_DIVERGED = 7
# EXIT_INTERRUPTED = 130 (eaglemission.interrupts)
"""``eaglemission replay``: the replay's setpoints or state changes differ from the recording."""


# ---------------------------------------------------------------------------------------------
# What a mission file flies (no construction)
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class FlightPlan:
    """Facts about a mission file's parts, from their classes alone."""

    wall_clock: bool
    """Some part needs host time (a real or SITL autopilot, GenICam cameras)."""
    simulated_vehicle: bool
    """The vehicle plugin flies nothing real (no arming confirmation)."""
    start_ns: int | None
    """Where a virtual-time clock starts (a replayed recording's first stamp), None: 1 s."""


def _plugin_classes(cfg: MissionFile) -> dict[str, type]:
    out = {"vehicle": registry.get("vehicles", cfg.vehicle.type)}
    for cid in CAMERAS:
        out[f"cameras.{cid}"] = registry.get("cameras", getattr(cfg.cameras, cid).type)
    return out


def plan(cfg: MissionFile) -> FlightPlan:
    classes = _plugin_classes(cfg)
    wall = any(bool(getattr(c, "wall_clock", False)) for c in classes.values())
    vcls = classes["vehicle"]
    start = None
    fn = getattr(vcls, "start_time_ns", None)
    if callable(fn):
        start = fn(registry.validate_params("vehicles", cfg.vehicle.type, cfg.vehicle.params,
                                            path="vehicle.params"))
    return FlightPlan(wall_clock=wall, simulated_vehicle=bool(getattr(vcls, "simulated", False)),
                      start_ns=start)


# ---------------------------------------------------------------------------------------------
# Building
# ---------------------------------------------------------------------------------------------
class PoseSource:
    """Where fake sensors see the world from: the vehicle's ground truth when it has one, else
    its own telemetry (a real autopilot that streams no truth; the header says so). Callable
    from any thread."""

    def __init__(self, vehicle: Any) -> None:
        self._vehicle = vehicle
        self.truth: GroundTruth | None = None

    def __call__(self, timestamp_ns: int) -> tuple[XYZ, Quat] | None:
        if self.truth is not None:
            return self.truth.pose_at(timestamp_ns)
        st = self._vehicle.state_at(timestamp_ns)
        return None if st is None else (st.position_ned_m, st.attitude_q)

    def motion_at(self, timestamp_ns: int) -> tuple[XYZ, XYZ] | None:
        """True velocity (NED, m/s) and angular velocity (NED, rad/s) at a time, when the
        truth offers them (the simulated vehicle's does); None otherwise (a synthetic camera
        then differences two poses for its motion blur)."""
        fn = getattr(self.truth, "motion_at", None)
        motion: tuple[XYZ, XYZ] | None = fn(timestamp_ns) if callable(fn) else None
        return motion


@dataclass
class Assembly:
    """The built (not yet connected) plugins of one flight."""

    config: MissionFile
    clock: Clock
    driver: Any
    vehicle: SafeVehicle
    cameras: dict[str, Any]
    detectors: dict[str, Any]
    coarse: Any
    fine: Any
    shared: SharedContext
    pose_source: PoseSource
    truth: GroundTruth | None = None
    fitter: PlaneFitter | None = None
    tracker: Tracker | None = None
    guard: AutopilotGuard | None = None
    faults: fault_injection.FaultInjector | None = None
    """Injects the config's ``faults:`` section (docs/faults.md), None without one."""

    def parts(self, *, realtime: bool) -> FlightParts:
        return FlightParts(config=self.config, clock=self.clock, vehicle=self.vehicle,
                           cameras=self.cameras, detectors=self.detectors, coarse=self.coarse,
                           fine=self.fine, shared=self.shared, fitter=self.fitter,
                           tracker=self.tracker, truth=self.truth, realtime=realtime,
                           autopilot_guard=self.guard)


def load_appearance_image(cfg: MissionFile) -> Any:
    """The mission's ``target.appearance_image`` as a BGR array (None without one)."""
    path = getattr(cfg.target, "appearance_image", None)
    if not path:
        return None
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise ConfigError(f"target.appearance_image: cannot read {str(path)!r} as an image")
    return img


def detector_params(cfg: MissionFile, camera_id: str) -> dict[str, Any]:
    """The detector params of one camera: ``detector.params`` with that camera's
    ``detector.per_camera`` overrides merged in (nested mappings merge key by key)."""
    over = next((v for k, v in cfg.detector.per_camera.items() if k == camera_id), {})
    return merge_params(cfg.detector.params, over)


def build_world(cfg: MissionFile) -> World | None:
    """The simulated world of ``cfg`` (``world.type``), None when nothing is simulated."""
    if cfg.world is None:
        return None
    world: World = registry.load("worlds", cfg.world.type, cfg.world.params)
    return world


def world_config(cfg: MissionFile) -> Any:
    """The validated world params the fake drivers read (``simulation=`` in their context)."""
    world = build_world(cfg)
    return None if world is None else world.config


def build_vehicle(cfg: MissionFile, clock: Clock, shared: SharedContext, *,
                  tap: bool = False) -> tuple[Any, SafeVehicle]:
    """The vehicle plugin of ``cfg`` and its envelope wrapper (not connected); ``tap``: a
    :class:`~eaglemission.vehicle_tap.VehicleTap` between them (a recorded flight)."""
    driver = registry.load("vehicles", cfg.vehicle.type, cfg.vehicle.params, clock=clock,
                           safety=cfg.safety, simulation=world_config(cfg), shared=shared)
    inner = VehicleTap(driver, clock) if tap else driver
    return driver, SafeVehicle(inner, cfg.safety, clock=clock,
                               logger=logging.getLogger("eaglemission.safety"))


def assemble(cfg: MissionFile, clock: Clock, *,
             vehicle: tuple[Any, SafeVehicle, SharedContext] | None = None) -> Assembly:
    """Build every plugin of ``cfg`` through the registry (no I/O: nothing connects or opens;
    ``vehicle`` passes one already built by :func:`build_vehicle`).

    Raises :class:`ConfigError` / :class:`PluginError` with the YAML path of the part."""
    if vehicle is None:
        shared = SharedContext()
        driver, safe = build_vehicle(cfg, clock, shared)
    else:
        driver, safe, shared = vehicle
    pose = PoseSource(driver)
    simulation = world_config(cfg)
    cameras: dict[str, Any] = {}
    for cid in CAMERAS:
        section = getattr(cfg.cameras, cid)
        cameras[cid] = registry.load(
            "cameras", section.type, section.params, model=section.to_model(cid), clock=clock,
            camera_id=cid, target=cfg.target, simulation=simulation, safety=cfg.safety,
            shared=shared, pose_source=pose)
    appearance = load_appearance_image(cfg)
    detectors = {cid: registry.load("detectors", cfg.detector.type, detector_params(cfg, cid),
                                    camera_id=cid, appearance=appearance)
                 for cid in CAMERAS}
    coarse = registry.load("estimators", cfg.estimators.coarse.type,
                           cfg.estimators.coarse.params, target=cfg.target)
    fine = registry.load("estimators", cfg.estimators.fine.type, cfg.estimators.fine.params,
                         target=cfg.target)
    fs = cfg.estimators.fitter
    fitter = None if fs is None else registry.load("fitters", fs.type, fs.params,
                                                   target=cfg.target)
    ts = cfg.tracker
    tracker = None if ts is None else registry.load("trackers", ts.type, ts.params,
                                                    target=cfg.target)
    asm = Assembly(cfg, clock, driver, safe, cameras, detectors, coarse, fine, shared, pose,
                   fitter=fitter, tracker=tracker)
    asm.faults = fault_injection.attach(asm)  # wraps the parts the faults live in
    return asm


# ---------------------------------------------------------------------------------------------
# Flying
# ---------------------------------------------------------------------------------------------
@dataclass
class FlightOptions:
    """How to fly a mission file (the CLI's flags)."""

    realtime: bool = False
    """Wall-clock time even when every part could run in virtual time."""
    dry_run: bool = False
    """Open, connect and check everything, report, and stop without arming."""
    confirm: Callable[[str], bool] | None = None
    """Asked (with a one-line description) before arming a vehicle that is not simulated;
    None: no confirmation (``--yes``)."""
    handle_signals: bool = False
    """SIGINT / SIGTERM: first = safe stop (``safety.on_interrupt``), second = exit at once."""
    hooks: MissionHooks = field(default_factory=MissionHooks)
    on_header: Callable[[list[str]], None] | None = None
    on_line: Callable[[str], None] | None = None
    """Progress lines (dry-run checks, interrupts)."""
    prepare: Callable[[Assembly], None] | None = None
    """Called with the connected, open parts before the mission is built (test harnesses
    wrap parts here)."""
    record: Any = None
    """A :class:`~eaglemission.mcap_options.RecordOptions`: record the flight as MCAP (None:
    as the config's ``recording`` section says, when ``record_config``)."""
    record_config: bool = True
    live: Any = None
    """A :class:`~eaglemission.live.LiveOptions`: serve the flight live in Foxglove (the CLI
    applies the config's ``live`` section); the server starts before take-off."""
    truth_wait_s: float = 3.0
    """How long to wait, after connecting, for the first ground-truth sample."""
    camera_open_timeout_s: float = 20.0


@dataclass
class FlightResult:
    exit_code: int
    outcome: MissionOutcome | None = None
    header: list[str] = field(default_factory=list)
    error: str = ""
    """One line: why the flight did not happen or ended abnormally."""
    interrupted: bool = False
    checks: list[tuple[str, bool, str]] = field(default_factory=list)
    wall_s: float = 0.0
    sim_s: float = 0.0
    virtual: bool = False
    recording: dict[str, Any] | None = None
    """The MCAP recorder's counts (frames written and dropped, write errors, bytes)."""
    live: dict[str, Any] | None = None


def exit_code_for(outcome: MissionOutcome | None, *, interrupted: bool) -> int:
    if interrupted:
        return EXIT_INTERRUPTED
    if outcome is None:
        return EXIT_ERROR
    if outcome.final_state == "DONE":
        return EXIT_TRUTH_FAILED if outcome.truth_success is False else EXIT_DONE
    if outcome.final_state == "FAILSAFE":
        return EXIT_FAILSAFE
    return EXIT_ERROR


def _describe(obj: Any, name: str) -> str:
    fn = getattr(obj, "summary", None)
    extra = ""
    if callable(fn):
        try:
            extra = str(fn())
        except Exception as exc:  # noqa: BLE001 - a header line must not stop a flight
            extra = f"(summary failed: {exc})"
    return f"{name} ({extra})" if extra else name


def header_lines(asm: Assembly, *, virtual: bool) -> list[str]:
    cfg = asm.config
    lines = [f"vehicle: {_describe(asm.driver, cfg.vehicle.type)}"]
    for cid in CAMERAS:
        cam = asm.cameras[cid]
        m = cam.model
        lines.append(f"camera {cid}: {_describe(cam, getattr(cfg.cameras, cid).type)}, "
                     f"{m.width_px}x{m.height_px} px, fx {m.fx:.0f} px")
    lines.append(f"detector: {cfg.detector.type} {dict(cfg.detector.params) or ''}".rstrip())
    lines.append(f"estimators: coarse {cfg.estimators.coarse.type}, "
                 f"fine {cfg.estimators.fine.type}")
    lines.append(f"mission: {cfg.mission.type}")
    lines.append("clock: " + ("virtual time (faster than real time)" if virtual
                              else "wall clock (real time)"))
    if asm.truth is not None:
        lines.append(f"ground truth: {asm.truth.description} (fake sensors render from it; "
                     "the evaluator judges on it)")
    elif any(getattr(c, "needs_pose", False) for c in asm.cameras.values()):
        lines.append("ground truth: none: the synthetic cameras render from the autopilot's "
                     "own estimate and the evaluator judges on it")
    else:
        lines.append("ground truth: none")
    return lines


async def _bounded(what: str, coro: Any, timeout_s: float) -> Any:
    try:
        async with asyncio.timeout(timeout_s):
            return await coro
    except TimeoutError:
        raise DriverError("TIMEOUT", what, None, f"no answer within {timeout_s:g} s") from None


async def _open_cameras(asm: Assembly, timeout_s: float) -> None:
    for cid, cam in asm.cameras.items():
        try:
            await _bounded(f"camera {cid!r}.open()", run_blocking(cam.open), timeout_s)
        except EagleMissionError as exc:
            raise CameraError("OPEN_FAILED", f"camera {cid!r}.open()", None, str(exc)) from exc
        except Exception as exc:  # a vendor SDK may raise anything
            raise CameraError("OPEN_FAILED", f"camera {cid!r}.open()", None,
                              f"{type(exc).__name__}: {exc}") from exc


async def _close_all(asm: Assembly, opened: list[str]) -> None:
    for cid in opened:
        try:
            await _bounded(f"camera {cid!r}.close()", run_blocking(asm.cameras[cid].close), 10.0)
        except Exception as exc:  # noqa: BLE001 - closing must go on
            log.warning("camera %s: close failed: %s", cid, exc)
    await _close_vehicle(asm.vehicle)


async def _close_vehicle(vehicle: SafeVehicle) -> None:
    try:
        await _bounded("vehicle.close()", vehicle.close(), 30.0)
    except Exception as exc:  # noqa: BLE001 - closing must not raise over the real error
        log.warning("vehicle: close failed: %s", exc)


async def _attach_truth(asm: Assembly, wait_s: float) -> None:
    fn = getattr(asm.driver, "ground_truth", None)
    truth = fn() if callable(fn) else None
    if truth is None:
        return
    deadline = time.monotonic() + wait_s
    while not truth.available() and time.monotonic() < deadline:
        await asyncio.sleep(0.05)
    if truth.available():
        asm.truth = truth
        asm.pose_source.truth = truth


async def fly(cfg: MissionFile, options: FlightOptions | None = None) -> FlightResult:
    """Assemble ``cfg``, connect, check, fly the mission and close (inside a running loop)."""
    opt = options or FlightOptions()
    loop = asyncio.get_running_loop()
    clock = BoundLoopClock(loop)
    virtual = clock.virtual
    wall0 = time.perf_counter()
    t0_ns = clock.now_ns()
    say = opt.on_line or (lambda _line: None)
    interrupts = FlightInterrupts(cfg, say)
    if opt.handle_signals:
        interrupts.install()
    try:
        return await _fly(cfg, opt, clock, say, interrupts)
    except asyncio.CancelledError:
        if interrupts.count == 0:
            raise
        return FlightResult(EXIT_INTERRUPTED, error="interrupted before the flight",
                            interrupted=True, virtual=virtual,
                            wall_s=time.perf_counter() - wall0,
                            sim_s=(clock.now_ns() - t0_ns) * 1e-9)
    finally:
        interrupts.remove()


async def _fly(cfg: MissionFile, opt: FlightOptions, clock: BoundLoopClock,
               say: Callable[[str], None], interrupts: FlightInterrupts) -> FlightResult:
    virtual = clock.virtual
    wall0 = time.perf_counter()
    t0_ns = clock.now_ns()
    shared = SharedContext()
    try:
        flight_plan = plan(cfg)
        record = mcap_options.planned(cfg, opt.record, use_config=opt.record_config)
        driver, safe = build_vehicle(cfg, clock, shared, tap=record is not None)
    except (ConfigError, PluginError) as exc:
        return FlightResult(EXIT_CONFIG, error=str(exc), virtual=virtual)
    result = FlightResult(EXIT_ERROR, virtual=virtual)
    connect_timeout_s = float(getattr(driver.config, "connect_timeout_s", 30.0))
    try:  # connect first: an unreachable autopilot fails within its connect_timeout_s
        await _bounded("vehicle.connect()", safe.connect(), connect_timeout_s + 5.0)
    except DriverError as exc:
        await _close_vehicle(safe)
        result.exit_code, result.error = EXIT_CONNECTION, _one_line(exc)
        return result
    except asyncio.CancelledError:
        await _close_vehicle(safe)
        raise
    try:
        asm = assemble(cfg, clock, vehicle=(driver, safe, shared))
    except (ConfigError, PluginError) as exc:
        await _close_vehicle(safe)
        return FlightResult(EXIT_CONFIG, error=str(exc), virtual=virtual)
    except BaseException:
        await _close_vehicle(safe)
        raise
    opened: list[str] = []
    sink = None
    try:
        try:
            await _open_cameras(asm, opt.camera_open_timeout_s)
            opened = list(asm.cameras)
        except (DriverError, ConfigError) as exc:
            result.exit_code, result.error = EXIT_CONNECTION, _one_line(exc)
            return result
        await _attach_truth(asm, opt.truth_wait_s if not virtual else 0.0)
        result.header = header_lines(asm, virtual=virtual)
        if opt.on_header is not None:
            opt.on_header(result.header)
        disk = None if record is None else mcap_options.disk_check(record, say)
        sink, live_check = live.start(opt.live, say)
        sink_checks = [c for c in (disk, live_check) if c is not None]
        failed = [c for c in sink_checks if not c[1]]
        if failed and not opt.dry_run:
            result.exit_code, result.error = EXIT_PREFLIGHT, f"{failed[0][0]}: {failed[0][2]}"
            return result
        if opt.dry_run:
            from eaglemission.preflight import dry_run_checks

            result.checks = await dry_run_checks(asm, say) + sink_checks
            ok = all(passed for _, passed, _ in result.checks)
            result.exit_code = EXIT_DONE if ok else EXIT_PREFLIGHT
            if not ok:
                result.error = "preflight checks failed: " + "; ".join(
                    f"{n}: {d}" for n, p, d in result.checks if not p)
            return result
        if not flight_plan.simulated_vehicle and opt.confirm is not None:
            what = f"{cfg.vehicle.type} vehicle ({_describe(asm.driver, cfg.vehicle.type)})"
            if not opt.confirm(f"Arm and fly the {what}?"):
                result.exit_code, result.error = EXIT_PREFLIGHT, "not confirmed: nothing armed"
                return result
        upload = getattr(asm.driver, "upload_geofence", None)
        if callable(upload):
            try:
                await _bounded("upload_geofence()", upload(cfg.safety.geofence), 30.0)
                say("geofence uploaded to the autopilot")
            except (DriverError, NotImplementedError) as exc:
                result.exit_code = EXIT_PREFLIGHT
                result.error = f"geofence upload failed: {_one_line(exc)}"
                return result
        if opt.prepare is not None:
            opt.prepare(asm)
        asm.guard = AutopilotGuard(asm.vehicle.inner, cfg.safety, cfg.mission.cruise_altitude_m)
        refused = await autopilot_guard.before_flight(asm.guard, say)
        if refused:  # nothing armed; what was set already is restored below
            result.exit_code, result.error = EXIT_PREFLIGHT, refused
            return result
        recorder, hooks = mcap_record.flight_recorder(
            cfg, record, asm, virtual, fault_injection.with_hooks(asm.faults, opt.hooks))
        hooks = live.attach(sink, hooks, {c: cam.model for c, cam in asm.cameras.items()},
                            asm.clock.now_ns())
        mission = registry.load("missions", cfg.mission.type, cfg.mission.params,
                                parts=asm.parts(realtime=not virtual), hooks=hooks)
        interrupts.mission = mission
        interrupts.mission_task = task = asyncio.ensure_future(mission.run())
        try:
            with frozen_heap():  # full collections walk only the flight's objects
                result.outcome = await task
        except asyncio.CancelledError:
            if interrupts.count == 0 or not task.cancelled():
                raise
            result.error = "the mission did not end after the interrupt: cancelled"
        finally:
            if recorder is not None:
                result.recording = recorder.close()
        result.interrupted = interrupts.count > 0
        result.exit_code = exit_code_for(result.outcome, interrupted=result.interrupted)
        if result.outcome is not None and result.outcome.final_state not in ("DONE",):
            result.error = result.error or f"{result.outcome.final_state}: {result.outcome.reason}"
        return result
    finally:
        await autopilot_guard.after_flight(asm.guard, asm.vehicle, say)
        await _close_all(asm, opened)
        result.live = live.stop(sink)
        result.wall_s = time.perf_counter() - wall0
        result.sim_s = (clock.now_ns() - t0_ns) * 1e-9


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())


def fly_sync(cfg: MissionFile, options: FlightOptions | None = None) -> FlightResult:
    """Fly ``cfg`` on the right loop: virtual time when every part allows it and
    ``options.realtime`` is off, else the wall clock."""
    opt = options or FlightOptions()
    try:
        flight_plan = plan(cfg)
    except (ConfigError, PluginError) as exc:
        return FlightResult(EXIT_CONFIG, error=str(exc))
    if flight_plan.wall_clock or opt.realtime:
        return asyncio.run(fly(cfg, opt))
    start_s = 1.0 if flight_plan.start_ns is None else flight_plan.start_ns * 1e-9
    return run_virtual(fly(cfg, opt), start_s=start_s)


def speedup(result: FlightResult) -> float:
    return result.sim_s / result.wall_s if result.wall_s > 0 else math.inf
