"""MAVSDK driver (plugin ``mavsdk``): PX4 (or any MAVLink autopilot) through MAVSDK 4.1.

``mavsdk`` is imported lazily, with a remedy when it is missing, in one place
(:mod:`.mavsdk_support`). The driver uses
MAVSDK 4.1's native binding at its synchronous layer (``mavsdk.mavsdk.Mavsdk`` and the
``mavsdk.plugins.*`` classes) and does its own asyncio bridging, because:

* telemetry callbacks run on MAVSDK's I/O thread, where each sample is **stamped on receipt**
  with the host monotonic clock before it is handed to the event loop (stamping in the loop
  would add the loop's latency to every pose);
* every command runs in a small private thread pool and is **bounded** by
  ``command_timeout_s`` (a hung call cannot starve asyncio's default executor);
* the offboard watchdog (:mod:`.watchdog`) needs a synchronous path to HOLD that works while
  the event loop is blocked: it calls MAVSDK's blocking ``Offboard.stop()`` / ``Action.hold()``
  from its own thread.

Telemetry: ONE long-lived task per stream owns the stream's subscription (subscribed when the
task starts, unsubscribed in its ``finally``) and caches the latest values; fast samples
(position, attitude) build a :class:`~eaglemission.types.VehicleState` appended to a ~2 s
:class:`~eaglemission.telemetry.history.TelemetryHistory` for :meth:`MavsdkVehicle.state_at`.

Distance sensor: ``Telemetry.distance_sensor`` (DISTANCE_SENSOR) fills
``VehicleState.distance_to_ground_m`` only for a downward sensor (MAV_SENSOR_ROTATION_PITCH_270,
which MAVSDK 4.1 reports as ``orientation.pitch_deg == 270``) with a reading inside its
``[minimum, maximum]`` (PX4 sends out-of-range readings too: 655.35 m beyond the range, the
geometric value below it) and at most ``distance_sensor_max_age_s`` old; None otherwise.

Frames: PX4's LOCAL_POSITION_NED is relative to the EKF origin, which differs from home by
decimetres. ``VehicleState.position_ned_m`` and :class:`~eaglemission.types.Setpoint` are
relative to **home** (docs/conventions.md); the driver converts both ways with home's position
in the local frame (HOME_POSITION x/y/z).

Offboard (PX4 rules): :meth:`start_offboard` needs a valid local position, sends the
*current* position and yaw as the first setpoint, switches to OFFBOARD, then a timer task
streams speed-limited steps (``offboard_rate_hz`` >= 10) towards the latest goal given to
:meth:`set_setpoint`, yaw included (wrap-around handled). A mode change made by someone else
(pilot, ground station, PX4 failsafe) ends our commanding and is reported as an event; the
next :meth:`set_setpoint` raises :class:`~eaglemission.errors.ModeChangedExternally`.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any

from eaglemission.drivers.vehicles.events import (
    EVENT_LINK,
    EVENT_REFUSED,
    EVENT_TRUTH,
)
from eaglemission.drivers.vehicles.mavsdk import arming as mavsdk_arming
from eaglemission.drivers.vehicles.mavsdk import outputs
from eaglemission.drivers.vehicles.mavsdk import params as mavsdk_params
from eaglemission.drivers.vehicles.mavsdk.failover_watch import (
    PX4_DEFAULT_OFFBOARD_LOSS_S,
    FailoverWatch,
)
from eaglemission.drivers.vehicles.mavsdk.hil_truth import HilTruth
from eaglemission.drivers.vehicles.mavsdk.offboard import OffboardSession
from eaglemission.drivers.vehicles.mavsdk.outputs import (
    GRIPPER_ACTION_GRAB,
    GRIPPER_ACTION_RELEASE,
    ServoOutputLog,
)
from eaglemission.drivers.vehicles.mavsdk.session import MavsdkSession
from eaglemission.drivers.vehicles.mavsdk.support import (
    MavlinkPeer,
    MavsdkVehicleConfig,
    downward_range_m,
    mission_plan,
    parse_url,
    serial_problem,
    step_towards,
    thread_safe_now,
)
from eaglemission.drivers.vehicles.mavsdk.telemetry import MavsdkTelemetry, request_rates

from eaglemission.clock import Clock, MonotonicClock, VirtualTimeLoop
from eaglemission.config import GeofenceConfig, SafetyConfig
from eaglemission.errors import TimeoutError_, VehicleError
from eaglemission.geometry import ned_to_geodetic
from eaglemission.types import (
    FlightMode,
    GeoPoint,
    MissionProgress,
    Setpoint,
    VehicleEvent,
    VehicleState,
    Waypoint,
)

__all__ = ["MavsdkVehicle", "MavsdkVehicleConfig", "downward_range_m", "parse_url", "step_towards"]

log = logging.getLogger(__name__)



class MavsdkVehicle:
    """A MAVLink autopilot through MAVSDK 4.1 (see the module docstring).

    Context: ``clock`` (must read host monotonic time: MAVSDK runs in wall time),
    ``safety`` (its ``offboard_watchdog_s`` is the default watchdog timeout), ``mavlink_peer``
    (for ``raw://``).
    """

    Config = MavsdkVehicleConfig
    description = "PX4 / MAVLink autopilot through MAVSDK 4.1 (telemetry, commands, offboard + watchdog)"
    wall_clock = True  # MAVSDK and the autopilot run in host time
    extra = "mavsdk"  # mavsdk (eaglemission.extras)

    def __init__(self, config: MavsdkVehicleConfig | None = None, *, clock: Clock | None = None,
                 safety: SafetyConfig | None = None, mavlink_peer: MavlinkPeer | None = None,
                 **_context: Any) -> None:
        self.config = cfg = config or MavsdkVehicleConfig()
        self.clock: Clock = clock or MonotonicClock()
        self._peer = mavlink_peer
        wd = cfg.watchdog_timeout_s
        if wd is None:
            wd = float(getattr(safety, "offboard_watchdog_s", 0.5))
        self.watchdog_timeout_s = wd
        self._tasks: list[asyncio.Task[None]] = []
        self._connected = False
        self._closed = False
        self._events: deque[VehicleEvent] = deque(maxlen=2000)
        self._events_lock = threading.Lock()
        self.session = MavsdkSession(cfg, self.event, mavlink_peer)
        self._offboard = OffboardSession(self, wd)
        self.telemetry = MavsdkTelemetry(cfg, self.event, self._offboard.on_mode)
        self._c = self.telemetry.cache
        self._now_ns: Callable[[], int] = time.monotonic_ns
        self._truth = (HilTruth(self.telemetry.truth_flags, altitude=cfg.ground_truth_altitude,
                                horizontal=cfg.ground_truth_horizontal,
                                on_problem=self._truth_problem)
                       if cfg.ground_truth == "auto" else None)
        self._truth_handle: Any = None
        self.servo_outputs = ServoOutputLog()  # SERVO_OUTPUT_RAW: an arm's servos read back
        self.failover = FailoverWatch(lambda: self._offboard.active, self.event,
                                      cfg.offboard_loss_timeout_s or PX4_DEFAULT_OFFBOARD_LOSS_S)
        self.telemetry.on_gap = self.failover.on_gap

    # ------------------------------------------------------------------------------------------
    # lifetime
    # ------------------------------------------------------------------------------------------
    async def __aenter__(self) -> MavsdkVehicle:
        await self.connect()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    async def connect(self) -> None:
        """Open the link, wait for an autopilot (``connect_timeout_s``), start telemetry."""
        if self._connected:
            return
        if self._closed:
            raise VehicleError("CONNECTION_ERROR", "connect()", None,
                               "this vehicle was closed: create a new one")
        cfg = self.config
        scheme = parse_url(cfg.url)
        if isinstance(asyncio.get_running_loop(), VirtualTimeLoop):
            raise VehicleError("UNSUPPORTED_CLOCK", "connect()", None,
                               "MAVSDK runs in wall time: do not run the mavsdk driver on a "
                               "VirtualTimeLoop (use the simulated vehicle there)")
        self._now_ns = thread_safe_now(self.clock)
        a = self._now_ns()
        time.sleep(0.002)
        if self._now_ns() <= a:
            raise VehicleError("UNSUPPORTED_CLOCK", "connect()", None,
                               "the clock does not advance in wall time: MAVSDK runs in wall "
                               "time, use MonotonicClock (not a manual or virtual-time clock)")
        device = serial_problem(cfg.url)
        if device is not None:
            raise VehicleError("CONNECTION_ERROR", "connect()", cfg.url, device)
        if scheme == "raw" and self._peer is None:
            raise VehicleError("CONNECTION_ERROR", "connect()", cfg.url,
                               "raw:// needs a `mavlink_peer` in the context (e.g. the emulator)")
        t0 = time.monotonic()
        try:
            found = await self.session.open(scheme, cfg.connect_timeout_s)
        except BaseException:
            await self._teardown()
            raise
        if not found:
            await self._teardown()
            raise TimeoutError_("connect()", cfg.connect_timeout_s,
                                f"no autopilot heard on {cfg.url} within {cfg.connect_timeout_s:g} s: "
                                "check the URL (PX4 SITL sends to udpin://0.0.0.0:14540), the "
                                "cable / baud rate, and that the autopilot is powered and sending")
        if self._truth is not None:
            truth, now_ns = self._truth, self._now_ns
            self._truth_handle = self.plugins["MavlinkDirect"].subscribe_message(
                "HIL_STATE_QUATERNION", lambda msg, _ud=None: truth.on_message(
                    now_ns(), msg.fields_json))
        self.servo_outputs.subscribe(self.plugins["MavlinkDirect"])
        self._connected = True
        self._tasks = self.telemetry.start(self.plugins["Telemetry"], self.plugins["Mission"],
                                           self._now_ns, self.mavsdk["MavFlightMode"])
        self._offboard.watchdog.start()
        await request_rates(self)
        await mavsdk_arming.request_truth(self)
        if cfg.offboard_loss_timeout_s is None:
            await self.failover.read_timeout(self.get_param)
        await self.telemetry.wait_first(max(0.5, cfg.connect_timeout_s - (time.monotonic() - t0)))
        self.event(EVENT_LINK, f"connected to {cfg.url}", {"ok": True})

    async def close(self) -> None:
        """Stop streams, the watchdog and the link. Idempotent."""
        if self._closed:
            return
        self._closed = True
        self._connected = False
        await self._teardown()

    async def _teardown(self) -> None:
        """Stop everything that may call into MAVSDK, then destroy it. MAVSDK aborts the
        process if it is destroyed while a System or plugin is still in use, so in-flight calls
        (each bounded by MAVSDK's own timeouts) are waited for first; if some never return, the
        instance is leaked rather than destroyed."""
        loop = asyncio.get_running_loop()
        grace_s = self.config.command_timeout_s + 5.0
        await loop.run_in_executor(None, functools.partial(self._offboard.watchdog.stop, grace_s))
        tasks = [t for t in (*self._tasks, self._offboard.task) if t is not None]
        for t in tasks:
            t.cancel()
        for t in tasks:
            with contextlib.suppress(BaseException):
                await t
        self._tasks = []
        self._offboard.task = None
        await self.session.shutdown(grace_s, lambda: self._offboard.watchdog.running)

    @property
    def plugins(self) -> dict[str, Any]:
        """The MAVSDK plugins (after :meth:`connect`)."""
        return self.session.plugins

    @property
    def mavsdk(self) -> dict[str, Any]:
        """The MAVSDK classes (after :meth:`connect`)."""
        return self.session.mavsdk

    async def bounded(self, origin: str, fn: Callable[[], Any], *, timeout_s: float | None = None,
                      params: Any = None) -> Any:
        """A blocking MAVSDK call, bounded (:meth:`.MavsdkSession.bounded`)."""
        return await self.session.bounded(origin, fn, timeout_s=timeout_s, params=params)

    def _require(self, origin: str) -> None:
        if not self._connected:
            raise VehicleError("NO_SYSTEM", origin, None,
                               "not connected: call `await vehicle.connect()` (or use `async with`)")

    def ground_truth(self) -> HilTruth | None:
        """Simulator ground truth (HIL_STATE_QUATERNION), None with ``ground_truth: off``;
        ``available()`` once a sample arrived (never on a real aircraft)."""
        return self._truth

    def _truth_problem(self, text: str) -> None:
        """The ground truth contradicts itself (MAVSDK's thread): say so, once."""
        log.warning("%s", text)
        self.event(EVENT_TRUTH, text, {"problem": "altitude_sense"})

    def summary(self) -> str:
        return f"url {self.config.url}"

    async def upload_geofence(self, geofence: GeofenceConfig) -> None:
        """Upload the envelope's geofence (a circle around home or a NED polygon) as PX4's
        inclusion fence; PX4 then enforces it itself (its GF_ACTION)."""
        await mavsdk_params.upload_geofence(self, geofence)

    # ------------------------------------------------------------------------------------------
    # Vehicle protocol: telemetry
    # ------------------------------------------------------------------------------------------
    def state(self) -> VehicleState:
        self._require("state()")
        return self.telemetry.state()

    def state_at(self, timestamp_ns: int) -> VehicleState | None:
        self._require("state_at()")
        return self.telemetry.history.state_at(timestamp_ns)

    def events(self) -> Sequence[VehicleEvent]:
        with self._events_lock:
            return tuple(self._events)

    def mission_progress(self) -> MissionProgress:
        self._require("mission_progress()")
        return self._c.progress

    def event(self, kind: str, text: str, data: dict[str, object] | None = None) -> None:
        with self._events_lock:
            self._events.append(VehicleEvent(self._now_ns(), kind, text, dict(data or {})))

    # ------------------------------------------------------------------------------------------
    # commands
    # ------------------------------------------------------------------------------------------
    async def _confirm(self, origin: str, predicate: Callable[[], bool], what: str,
                       timeout_s: float | None = None) -> None:
        """Wait (bounded) until telemetry shows the effect of an accepted command. PX4 reports
        mode and arming only in its 1 Hz HEARTBEAT: up to ~1 s after the ACCEPTED ack."""
        if not self.config.confirm_modes:
            return
        limit = self.config.confirm_timeout_s if timeout_s is None else timeout_s
        deadline = time.monotonic() + limit
        while not predicate():
            if time.monotonic() > deadline:
                raise TimeoutError_(origin, limit,
                                    f"accepted, but telemetry never showed {what} within "
                                    f"{limit:g} s (last: mode={self._c.mode.value} "
                                    f"armed={self._c.armed} in_air={self._c.in_air})")
            await asyncio.sleep(0.02)

    async def mode_command(self, origin: str, fn: Callable[[], Any], modes: set[FlightMode],
                            params: Any = None, *, also_ok: frozenset[FlightMode] = frozenset()
                            ) -> None:
        """A command that changes the flight mode to one of ``modes`` (ours, not external);
        ``also_ok`` are modes the autopilot may move on to by itself (TAKEOFF -> HOLD); they
        count only after a mode change reported since the command (PX4 reports modes in its
        1 Hz HEARTBEAT: the HOLD shown before a takeoff is not the HOLD after it)."""
        self.telemetry.expected = set(modes)
        changes0 = self._c.mode_changes
        await self.bounded(origin, fn, params=params)
        ok = modes | also_ok

        def shown() -> bool:
            c = self._c
            return c.mode in modes or (c.mode in also_ok and c.mode_changes > changes0)

        await self._confirm(origin, shown,
                            "the flight mode " + "/".join(sorted(m.value for m in ok)))

    async def arm(self) -> None:
        """Arm, and wait (bounded) until the HEARTBEAT shows it; armed on the ground is not
        ready (PX4's auto-disarm): :func:`.mavsdk_arming.arm`."""
        await mavsdk_arming.arm(self)

    async def disarm(self) -> None:
        self._require("disarm()")
        await self.bounded("disarm()", self.plugins["Action"].disarm)
        await self._confirm("disarm()", lambda: not self._c.armed, "disarmed")

    async def wait_landed_and_disarmed(self, land_timeout_s: float = 60.0) -> None:
        """After :meth:`land` (or RTL): touchdown, then PX4's auto-disarm, else an explicit
        disarm; every stage bounded (:func:`.mavsdk_arming.wait_landed_and_disarmed`)."""
        await mavsdk_arming.wait_landed_and_disarmed(self, land_timeout_s)

    async def takeoff(self, altitude_m: float) -> None:
        """Take off to ``altitude_m`` above home (PX4 MIS_TAKEOFF_ALT); returns when accepted.

        Armed on the ground right after a landing (mode LAND / RTL), the vehicle is disarmed
        and armed again first (:meth:`arm`): PX4's auto-disarm would otherwise cut the motors
        during the climb."""
        self._require("takeoff()")
        if not (math.isfinite(altitude_m) and altitude_m > 0):
            raise VehicleError("INVALID_ARGUMENT", "takeoff()", (altitude_m,),
                               f"altitude_m must be a finite height above home > 0, got {altitude_m}")
        if not self._c.armed:
            self.event(EVENT_REFUSED, "takeoff(): COMMAND_DENIED: not armed",
                        {"command": "takeoff()", "result": "COMMAND_DENIED"})
            raise VehicleError("COMMAND_DENIED", "takeoff()", (altitude_m,),
                               "the vehicle is not armed: arm first")
        if not self._c.in_air and self._c.mode in (FlightMode.LAND, FlightMode.RETURN_TO_LAUNCH):
            await mavsdk_arming.rearm_after_landing(self, "takeoff()")
        act = self.plugins["Action"]
        await mavsdk_arming.set_takeoff_altitude(self, act, float(altitude_m))
        self._offboard.stop_streaming()
        await self.mode_command("takeoff()", act.takeoff, {FlightMode.TAKEOFF},
                                 params=(altitude_m,), also_ok=frozenset({FlightMode.HOLD}))

    async def goto(self, target: GeoPoint, yaw_deg: float) -> None:
        """Fly to a WGS-84 point (``altitude_amsl_m`` AMSL: home's AMSL + height above home)
        with a heading; PX4 DO_REPOSITION, mode HOLD. Returns when accepted."""
        self._require("goto()")
        vals = (target.latitude_deg, target.longitude_deg, target.altitude_amsl_m)
        if not all(math.isfinite(v) for v in vals):
            raise VehicleError("INVALID_ARGUMENT", "goto()", (target, yaw_deg),
                               "latitude, longitude and AMSL altitude must be finite")
        yaw = float(yaw_deg) if math.isfinite(yaw_deg) else math.nan
        act = self.plugins["Action"]
        self._offboard.stop_streaming()
        await self.mode_command("goto()", lambda: act.goto_location(*vals, yaw), {FlightMode.HOLD},
                                 params=(target, yaw_deg))

    def geopoint(self, north_m: float, east_m: float, altitude_m: float) -> GeoPoint:
        """A point given relative to home (NED metres, height above home) as WGS-84 + AMSL."""
        home = self._c.home
        if home is None:
            raise VehicleError("NO_HOME", "geopoint()", (north_m, east_m, altitude_m),
                               "home is not known yet: wait for telemetry (GPS fix)")
        return ned_to_geodetic(home, north_m, east_m, -altitude_m)

    async def upload_mission(self, waypoints: Sequence[Waypoint]) -> None:
        """Upload the cruise route (NED relative to home, heights above home)."""
        self._require("upload_mission()")
        wps = tuple(waypoints)
        if not wps:
            raise VehicleError("INVALID_ARGUMENT", "upload_mission()", None, "the mission has no waypoint")
        home = await self._home("upload_mission()")
        if home is None:
            raise VehicleError("NO_HOME", "upload_mission()", len(wps),
                               "home is not known yet: wait for telemetry (GPS fix)")
        plan = mission_plan(self.mavsdk, home, wps)
        mission = self.plugins["Mission"]
        await self.bounded("upload_mission()", lambda: mission.set_return_to_launch_after_mission(False))
        await self.bounded("upload_mission()", lambda: mission.upload_mission(plan),
                            timeout_s=self.config.mission_upload_timeout_s, params=len(wps))
        self._c.progress = MissionProgress(0, len(wps))

    async def _home(self, origin: str) -> GeoPoint | None:
        deadline = time.monotonic() + self.config.command_timeout_s
        while self._c.home is None and time.monotonic() < deadline:
            await asyncio.sleep(0.05)
        return self._c.home

    async def start_mission(self) -> None:
        self._require("start_mission()")
        self._offboard.stop_streaming()
        await self.mode_command("start_mission()", self.plugins["Mission"].start_mission,
                                 {FlightMode.MISSION})

    async def hold(self) -> None:
        self._require("hold()")
        if self._offboard.active:
            await self.stop_offboard()
            return
        await self.mode_command("hold()", self.plugins["Action"].hold, {FlightMode.HOLD})

    async def land(self) -> None:
        self._require("land()")
        self._offboard.stop_streaming()
        await self.mode_command("land()", self.plugins["Action"].land, {FlightMode.LAND})

    async def return_to_launch(self) -> None:
        self._require("return_to_launch()")
        self._offboard.stop_streaming()
        await self.mode_command("return_to_launch()", self.plugins["Action"].return_to_launch,
                                 {FlightMode.RETURN_TO_LAUNCH})

    async def grab(self) -> None:
        await self._gripper("grab()", "grab", GRIPPER_ACTION_GRAB)

    async def release(self) -> None:
        await self._gripper("release()", "release", GRIPPER_ACTION_RELEASE)

    async def _gripper(self, origin: str, action: str, code: int) -> None:
        await outputs.gripper(self, origin, action, code)

    async def set_actuator(self, index: int, value: float) -> None:
        """MAV_CMD_DO_SET_ACTUATOR (:func:`.outputs.set_actuator`)."""
        await outputs.set_actuator(self, index, value)

    async def get_param(self, name: str) -> float:
        """Read an autopilot parameter (float, else int), e.g. PX4's COM_OF_LOSS_T."""
        return await mavsdk_params.get_param(self, name)

    async def autopilot_version(self) -> dict[str, Any]:
        """The autopilot's software version and git hash (MAVSDK Info: AUTOPILOT_VERSION)."""
        return await mavsdk_params.autopilot_version(self)

    async def set_param(self, name: str, value: float) -> None:
        """Write a float parameter (ints: :meth:`set_param_int`)."""
        self._require("set_param()")
        p = self.plugins["Param"]
        await self.bounded("set_param()", lambda: p.set_param_float(name, float(value)),
                           params=(name, value))

    async def set_param_int(self, name: str, value: int) -> None:
        """Write an integer parameter (:func:`.params.set_param_int`)."""
        await mavsdk_params.set_param_int(self, name, value)

    # ------------------------------------------------------------------------------------------
    # offboard (:mod:`.mavsdk_offboard`)
    # ------------------------------------------------------------------------------------------
    async def start_offboard(self, initial: Setpoint) -> None:
        """Enter OFFBOARD: first setpoint = current position and yaw, then stream steps towards
        ``initial`` (and later goals from :meth:`set_setpoint`)."""
        self._require("start_offboard()")
        await self._offboard.start(initial)

    async def set_setpoint(self, setpoint: Setpoint) -> None:
        """New offboard goal (NED relative to home, yaw); the stream steps towards it."""
        self._require("set_setpoint()")
        self._offboard.set_goal(setpoint)

    async def stop_offboard(self) -> None:
        """Leave OFFBOARD on purpose: MAVSDK ``Offboard.stop()`` (HOLD, setpoints stop)."""
        self._require("stop_offboard()")
        was = self._offboard.active
        self._offboard.stop_streaming()
        if not was and self._c.mode != FlightMode.OFFBOARD:
            return
        await self.mode_command("stop_offboard()", self.plugins["Offboard"].stop, {FlightMode.HOLD})
