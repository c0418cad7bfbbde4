"""Flying an assembled mission: connect, open, check, fly, close (:func:`fly`,
:func:`fly_sync`), with the options the CLI's flags set and the result and exit code it
prints. Building the parts is :mod:`.assembly`; the order of a flight, Ctrl-C and the dry run
are in docs/field_bringup.md, the exit codes in docs/troubleshooting.md.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from eaglemission import extras, registry
from eaglemission.clock import BoundLoopClock, run_blocking, run_virtual
from eaglemission.config import MissionFile
from eaglemission.errors import (
    CameraError,
    ConfigError,
    DriverError,
    EagleMissionError,
    PluginError,
)
from eaglemission.flight.assembly import (
    Assembly,
    assemble,
    build_vehicle,
    close_sections,
    describe_part,
    header_lines,
    load_sections,
    part_classes,
    plan,
    prepared,
)
from eaglemission.flight.context import SharedContext
from eaglemission.flight.heap import frozen_heap
from eaglemission.flight.interrupts import EXIT_INTERRUPTED, FlightInterrupts
from eaglemission.flight.preflight import Check, check_line, unconnected_checks, verdict_line
from eaglemission.flight.progress import TICK_S, CompileWatch, compile_progress, waiting
from eaglemission.interfaces import (
    MissionHooks,
    MissionOutcome,
    Section,
)
from eaglemission.recording import live
from eaglemission.recording import mcap_writer as mcap_record
from eaglemission.recording import options as mcap_options
from eaglemission.safety import autopilot_guard
from eaglemission.safety.autopilot_guard import AutopilotGuard
from eaglemission.safety.envelope import SafeVehicle

log = logging.getLogger(__name__)

# Exit codes of `eaglemission run` (README, "Exit codes").
EXIT_DONE = 0
EXIT_ERROR = 1
EXIT_CONFIG = 2
EXIT_FAILSAFE = 3
EXIT_CONNECTION = 4
EXIT_PREFLIGHT = 5
EXIT_TRUTH_FAILED = 6
EXIT_REPLAY_DIVERGED = 7
# EXIT_INTERRUPTED = 130 (eaglemission.flight.interrupts)
"""``eaglemission replay``: the replay's setpoints or state changes differ from the recording."""


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
    """A :class:`~eaglemission.recording.options.RecordOptions`: record the flight as MCAP (None:
    as the config's ``recording`` section says, when ``record_config``)."""
    record_config: bool = True
    live: Any = None
    """A :class:`~eaglemission.recording.live.LiveOptions`: serve the flight live in Foxglove (the CLI
    applies the config's ``live`` section); the server starts before take-off."""
    truth_wait_s: float = 3.0
    """How long to wait, after connecting, for the first ground-truth sample."""
    camera_open_timeout_s: float = 20.0
    progress_every_s: float = TICK_S
    """How often a slow step before take-off (connecting, compiling) says it is still going."""


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
    dry_run: bool = False
    """Checked only: nothing armed, nothing flown (its exit line says so, never DONE)."""


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


async def _close_all(asm: Assembly, opened: list[str], *, close_vehicle: bool = True) -> None:
    for cid in opened:
        try:
            await _bounded(f"camera {cid!r}.close()", run_blocking(asm.cameras[cid].close), 10.0)
        except Exception as exc:  # noqa: BLE001 - closing must go on
            log.warning("camera %s: close failed: %s", cid, exc)
    if close_vehicle:  # one that did not connect was closed then
        await _close_vehicle(asm.vehicle)
    close_sections(asm.sections)  # after the vehicle: a relay outlives the link it carries


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
    with compile_progress(say, opt.progress_every_s) as compiling:
        result = await _fly_parts(cfg, opt, clock, say, interrupts, compiling)
        in_flight = compiling.compiled - compiling.reported
        if in_flight and result.outcome is not None:
            compiling.reported = compiling.compiled
            say(f"compiled {in_flight} numba kernels during the flight: run "
                "`eaglemission warm-up` once after installing, before a real flight")
        return result


def _vehicle_what(driver: Any, cfg: MissionFile) -> str:
    url = getattr(getattr(driver, "config", None), "url", None)
    return f"the autopilot on {url}" if url else f"the {cfg.vehicle.type} vehicle"


def _connection_error(exc: DriverError) -> str:
    """One line: why the vehicle did not connect and the fix (the driver's detail)."""
    return _one_line(exc.detail) if exc.detail else _one_line(exc)


async def _connect(cfg: MissionFile, driver: Any, safe: SafeVehicle,
                   say: Callable[[str], None], every_s: float) -> str:
    """Connect the vehicle, saying how long it has waited; '' or why it did not connect."""
    connect_timeout_s = float(getattr(driver.config, "connect_timeout_s", 30.0))
    what = _vehicle_what(driver, cfg)
    say(f"connecting to {what}")
    try:  # connect first: an unreachable autopilot fails within its connect_timeout_s
        with waiting(say, what, every_s):
            await _bounded("vehicle.connect()", safe.connect(), connect_timeout_s + 5.0)
    except DriverError as exc:
        await _close_vehicle(safe)
        return _connection_error(exc)
    except asyncio.CancelledError:
        await _close_vehicle(safe)
        raise
    return ""


async def _open_for_dry_run(asm: Assembly, timeout_s: float, say: Callable[[str], None],
                            every_s: float) -> tuple[dict[str, Any], list[Check]]:
    """Open each camera (a failure is a failed check, the others still open)."""
    opened: dict[str, Any] = {}
    failed: list[Check] = []
    for cid, cam in asm.cameras.items():
        try:
            with waiting(say, f"camera {cid} to open", every_s):
                await _bounded(f"camera {cid!r}.open()", run_blocking(cam.open), timeout_s)
            opened[cid] = cam
        except Exception as exc:  # noqa: BLE001 - a vendor SDK may raise anything
            text = exc.detail if isinstance(exc, DriverError) and exc.detail else str(exc)
            failed.append((f"camera {cid}: open", False, _one_line(text)))
            say(check_line(failed[-1]))
    return opened, failed


async def _fly_parts(cfg: MissionFile, opt: FlightOptions, clock: BoundLoopClock,
                     say: Callable[[str], None], interrupts: FlightInterrupts,
                     compiling: CompileWatch) -> FlightResult:
    virtual = clock.virtual
    wall0 = time.perf_counter()
    t0_ns = clock.now_ns()
    shared = SharedContext()
    sections: list[Section] = []
    try:
        flight_plan = plan(cfg)
        extras.require_for(part_classes(cfg))
        record = mcap_options.planned(cfg, opt.record, use_config=opt.record_config)
        sections = load_sections(cfg)
        cfg = prepared(cfg, sections)
        driver, safe = build_vehicle(cfg, clock, shared, tap=record is not None)
    except (ConfigError, PluginError) as exc:
        close_sections(sections)
        return FlightResult(EXIT_CONFIG, error=str(exc), virtual=virtual,
                            dry_run=opt.dry_run)
    result = FlightResult(EXIT_ERROR, virtual=virtual, dry_run=opt.dry_run)
    checks: list[Check] = []
    not_connected = await _connect(cfg, driver, safe, say, opt.progress_every_s)
    if not_connected and not opt.dry_run:
        close_sections(sections)
        result.exit_code, result.error = EXIT_CONNECTION, f"vehicle: {not_connected}"
        return result
    if not_connected:  # the dry run goes on: every other check is still worth knowing
        checks += unconnected_checks(not_connected)
    try:
        say("building the parts")
        asm = assemble(cfg, clock, vehicle=(driver, safe, shared), sections=sections)
    except (ConfigError, PluginError) as exc:
        await _close_vehicle(safe)
        close_sections(sections)
        return FlightResult(EXIT_CONFIG, error=str(exc), virtual=virtual,
                            dry_run=opt.dry_run)
    except BaseException:
        await _close_vehicle(safe)
        close_sections(sections)
        raise
    opened: list[str] = []
    sink = None
    try:
        if opt.dry_run:
            for c in checks:
                say(check_line(c))
            cams, failed_open = await _open_for_dry_run(asm, opt.camera_open_timeout_s, say,
                                                        opt.progress_every_s)
            opened = list(cams)
            checks += failed_open
        else:
            try:
                await _open_cameras(asm, opt.camera_open_timeout_s)
                opened = list(asm.cameras)
            except (DriverError, ConfigError) as exc:
                result.exit_code, result.error = EXIT_CONNECTION, _one_line(exc)
                return result
        if not not_connected:
            await _attach_truth(asm, opt.truth_wait_s if not virtual else 0.0)
        compiled = compiling.summary()  # the kernels the parts compiled as they were built
        if compiled:
            say(compiled)
        result.header = header_lines(asm, virtual=virtual)
        if opt.on_header is not None:
            opt.on_header(result.header)
        if record is not None:
            say(mcap_options.size_line(cfg, record, asm))
        disk = None if record is None else mcap_options.disk_check(record, say)
        sink, live_check = live.start(opt.live, say)
        sink_checks = [c for c in (disk, live_check) if c is not None]
        failed = [c for c in sink_checks if not c[1]]
        if failed and not opt.dry_run:
            result.exit_code = EXIT_PREFLIGHT
            result.error = "; ".join(f"{n}: {d}" for n, _, d in failed)
            return result
        if opt.dry_run:
            from eaglemission.flight.preflight import dry_run_checks

            cams = {cid: asm.cameras[cid] for cid in opened}
            result.checks = checks + await dry_run_checks(
                asm, say, cameras=cams, connected=not not_connected) + sink_checks
            ok = all(passed for _, passed, _ in result.checks)
            result.exit_code = EXIT_DONE if ok else EXIT_PREFLIGHT
            if not ok:
                result.error = "preflight checks failed: " + "; ".join(
                    f"{n}: {d}" for n, p, d in result.checks if not p)
            say(verdict_line(result.checks))
            return result
        if not flight_plan.simulated_vehicle and opt.confirm is not None:
            what = f"{cfg.vehicle.type} vehicle ({describe_part(asm.driver, cfg.vehicle.type)})"
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
        hooks = opt.hooks
        for section in asm.sections:
            hooks = section.mission_hooks(hooks)
        recorder, hooks = mcap_record.flight_recorder(cfg, record, asm, virtual, hooks)
        hooks = live.attach(sink, hooks, {c: cam.model for c, cam in asm.cameras.items()},
                            asm.clock.now_ns())
        mission = registry.load("missions", cfg.mission.type, cfg.mission.params,
                                parts=asm.parts(realtime=not virtual), hooks=hooks)
        compiled = compiling.summary()  # before take-off; the rest would compile in flight
        if compiled:
            say(compiled)
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
        await _close_all(asm, opened, close_vehicle=not not_connected)
        result.live = live.stop(sink)
        result.wall_s = time.perf_counter() - wall0
        result.sim_s = (clock.now_ns() - t0_ns) * 1e-9


def _one_line(exc: BaseException | str) -> str:
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
