"""MAVSDK driver (plugin ``mavsdk``): PX4 (or any MAVLink autopilot) through MAVSDK 4.1.

The only module that imports ``mavsdk`` (lazily, with a remedy when it is missing). It uses
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
:class:`~eaglemission.telemetry.TelemetryHistory` for :meth:`MavsdkVehicle.state_at`.

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
import concurrent.futures
import contextlib
import functools
import json
import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Annotated, Any, Literal, Protocol

from eaglemission.drivers.vehicles.events import (
    EVENT_FAILSAFE,
    EVENT_GRIPPER,
    EVENT_LINK,
    EVENT_MISSION,
    EVENT_MODE,
    EVENT_REFUSED,
    EVENT_STATUS,
    EVENT_WATCHDOG,
)
from eaglemission.drivers.vehicles.hil_truth import MSG_ID as HIL_MSG_ID
from eaglemission.drivers.vehicles.hil_truth import HilTruth
from eaglemission.drivers.vehicles.watchdog import OffboardWatchdog
from pydantic import BaseModel, ConfigDict, Field

from eaglemission.clock import Clock, LoopClock, MonotonicClock, VirtualTimeLoop
from eaglemission.errors import (
    ModeChangedExternally,
    PluginError,
    TimeoutError_,
    VehicleError,
)
from eaglemission.geometry import geodetic_to_ned, ned_to_geodetic, wrap_deg
from eaglemission.telemetry import TelemetryHistory
from eaglemission.types import (
    XYZ,
    FlightMode,
    GeoPoint,
    MissionProgress,
    Quat,
    Setpoint,
    VehicleEvent,
    VehicleState,
    Waypoint,
)

log = logging.getLogger(__name__)

MAVSDK_REMEDY = 'the MAVSDK driver needs mavsdk 4.1: pip install "mavsdk>=4.1,<4.2"'

_REMEDIES = {
    "TIMEOUT": "no answer from the autopilot: is the link up (telemetry flowing)?",
    "COMMAND_DENIED": "the autopilot refused: see its status texts in events() "
                      "(pre-arm checks, landed state, mode)",
    "BUSY": "the autopilot is busy or temporarily rejected the command: retry",
    "NO_SYSTEM": "no autopilot: call connect() first",
    "CONNECTION_ERROR": "the link is broken: check the URL, cable and autopilot",
    "NO_SETPOINT_SET": "send a setpoint before starting offboard",
    "COMMAND_DENIED_NOT_LANDED": "the vehicle is not landed: land first",
    "COMMAND_DENIED_LANDED_STATE_UNKNOWN": "the landed state is unknown: wait for telemetry",
}


class MavsdkVehicleConfig(BaseModel):
    """Params of the ``mavsdk`` vehicle (all times in seconds, wall clock)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    url: str = "udpin://0.0.0.0:14540"
    """MAVSDK connection URL: ``udpin://0.0.0.0:14540`` (PX4 SITL), ``udpout://HOST:PORT``,
    ``serial:///dev/ttyACM0:921600``, ``tcpout://HOST:PORT``, or ``raw://`` (in-process
    bytes; needs the ``mavlink_peer`` context, e.g. the MAVLink emulator)."""
    connect_timeout_s: Annotated[float, Field(gt=0, le=600)] = 10.0
    command_timeout_s: Annotated[float, Field(gt=0, le=120)] = 5.0
    mission_upload_timeout_s: Annotated[float, Field(gt=0, le=600)] = 15.0
    component: Literal["companion_computer", "ground_station"] = "ground_station"
    """MAVSDK identity. PX4 sends STATUSTEXT on a link only while it hears a GCS heartbeat
    there (recorded), so the default is a ground station (sysid 245, compid 190)."""
    telemetry_rate_hz: Annotated[float, Field(ge=1, le=250)] = 50.0
    """Requested rate of position, local position and attitude (estimators need >= 50 Hz)."""
    state_rate_hz: Annotated[float, Field(ge=0.5, le=50)] = 5.0
    """Requested rate of the landed state (in_air)."""
    history_s: Annotated[float, Field(gt=0, le=60)] = 2.0
    link_timeout_s: Annotated[float, Field(gt=0, le=60)] = 1.5
    """No telemetry for this long: ``link_ok`` False and a link event."""
    offboard_rate_hz: Annotated[float, Field(ge=10, le=100)] = 20.0
    offboard_max_speed_mps: Annotated[float, Field(gt=0, le=20)] = 5.0
    offboard_max_vertical_speed_mps: Annotated[float, Field(gt=0, le=10)] = 1.5
    offboard_max_yaw_rate_degps: Annotated[float, Field(gt=0, le=360)] = 60.0
    watchdog_timeout_s: Annotated[float | None, Field(gt=0, le=10)] = None
    """Fresh-setpoint watchdog; None: ``safety.offboard_watchdog_s`` from the context, else 0.5."""
    position_max_age_s: Annotated[float, Field(gt=0, le=10)] = 0.5
    """Offboard needs a local position sample at most this old."""
    gripper_instance: Annotated[int, Field(ge=0, le=255)] = 1
    distance_sensor_rate_hz: Annotated[float, Field(ge=0, le=100)] = 20.0
    """Requested DISTANCE_SENSOR rate (PX4: 10 Hz on an Onboard link, 0.5 Hz on a Normal one;
    it never sends a sample twice); 0: do not ask."""
    distance_sensor_max_age_s: Annotated[float, Field(gt=0, le=10)] = 0.5
    """An older downward-range reading is not reported (``distance_to_ground_m`` None)."""
    ground_truth: Literal["auto", "off"] = "auto"
    """auto: ask for HIL_STATE_QUATERNION (simulator ground truth: PX4 SITL/SIH and the
    emulator fill it, a real aircraft sends none) and offer it as ``ground_truth()`` once
    samples arrive; it only feeds fake sensors and the evaluator."""
    ground_truth_rate_hz: Annotated[float, Field(gt=0, le=250)] = 50.0
    confirm_modes: bool = True
    """After an accepted command, wait (bounded) until telemetry shows its mode/armed state
    (PX4 sends HEARTBEAT at 1 Hz, so up to ~1 s)."""


class MavlinkPeer(Protocol):
    """The other end of a ``raw://`` connection (e.g. :class:`.mavlink_emulator.Px4Emulator`)."""

    def feed(self, data: bytes) -> None: ...

    def set_output(self, fn: Callable[[bytes], None] | None) -> None: ...


def _import_mavsdk() -> dict[str, Any]:
    """The MAVSDK classes the driver uses (lazy import with a remedy)."""
    try:
        from mavsdk.component_type import ComponentType
        from mavsdk.exceptions import MavsdkError
        from mavsdk.mavsdk import Configuration, Mavsdk
        from mavsdk.plugins.action import Action
        from mavsdk.plugins.geofence import (
            Circle,
            FenceType,
            Geofence,
            GeofenceData,
            Point,
            Polygon,
        )
        from mavsdk.plugins.gripper import Gripper
        from mavsdk.plugins.mavlink_direct import MavlinkDirect, MavlinkMessage
        from mavsdk.plugins.mission import Mission, MissionItem, MissionPlan
        from mavsdk.plugins.offboard import Offboard, PositionNedYaw
        from mavsdk.plugins.param import Param
        from mavsdk.plugins.telemetry import FlightMode as MavFlightMode
        from mavsdk.plugins.telemetry import Telemetry
    except ImportError as exc:  # pragma: no cover - depends on the install
        raise PluginError(f"cannot import mavsdk ({exc}): {MAVSDK_REMEDY}") from exc
    return dict(ComponentType=ComponentType, MavsdkError=MavsdkError, Configuration=Configuration,
                Mavsdk=Mavsdk, Action=Action, Gripper=Gripper, Mission=Mission,
                Geofence=Geofence, GeofenceData=GeofenceData, Circle=Circle, Polygon=Polygon,
                Point=Point, FenceType=FenceType, MavlinkDirect=MavlinkDirect,
                MavlinkMessage=MavlinkMessage,
                MissionItem=MissionItem, MissionPlan=MissionPlan, Offboard=Offboard,
                PositionNedYaw=PositionNedYaw, Param=Param, MavFlightMode=MavFlightMode,
                Telemetry=Telemetry)


# ---------------------------------------------------------------------------------------------
# Pure helpers
# ---------------------------------------------------------------------------------------------
def step_towards(current: Setpoint, goal: Setpoint, dt_s: float, *, max_speed_mps: float,
                 max_vertical_speed_mps: float, max_yaw_rate_degps: float) -> Setpoint:
    """One offboard step: move at most ``max_speed_mps * dt`` horizontally,
    ``max_vertical_speed_mps * dt`` vertically and ``max_yaw_rate_degps * dt`` in yaw (the
    short way round: 170 -> -170 deg is a 20 deg turn) from ``current`` towards ``goal``.

    A far-away position setpoint makes PX4 fly at its own maximum speed; these steps keep the
    commanded motion at the mission's speed.
    """
    dn, de = goal.north_m - current.north_m, goal.east_m - current.east_m
    h = math.hypot(dn, de)
    h_max = max_speed_mps * dt_s
    if h > h_max:
        dn, de = dn * h_max / h, de * h_max / h
    dd = goal.down_m - current.down_m
    v_max = max_vertical_speed_mps * dt_s
    dd = max(-v_max, min(v_max, dd))
    dyaw = wrap_deg(goal.yaw_deg - current.yaw_deg)
    y_max = max_yaw_rate_degps * dt_s
    dyaw = max(-y_max, min(y_max, dyaw))
    return Setpoint(current.north_m + dn, current.east_m + de, current.down_m + dd,
                    wrap_deg(current.yaw_deg + dyaw))


def downward_range_m(sample: Any) -> float | None:
    """The range of a MAVSDK ``Telemetry.DistanceSensor`` sample if the sensor looks down and
    the reading is a valid one, else None.

    MAVSDK 4.1 turns DISTANCE_SENSOR's ``orientation`` enum into Euler angles: PITCH_270
    (downward) -> ``pitch_deg = 270``, roll and yaw 0; unknown orientations -> 0/0/0 (forward),
    so only pitch 270 (or -90) with roll 0 counts. PX4 sends every sample, in range or not
    (SIH: 65535 cm beyond the maximum): a reading outside ``[minimum, maximum]``, not positive
    or not finite is no range.
    """
    o = getattr(sample, "orientation", None)
    pitch, roll = (float(getattr(o, "pitch_deg", math.nan)), float(getattr(o, "roll_deg", math.nan)))
    if not (math.isfinite(pitch) and math.isfinite(roll)):
        return None
    if abs(wrap_deg(pitch + 90.0)) > 1.0 or abs(wrap_deg(roll)) > 1.0:
        return None
    d = float(sample.current_distance_m)
    lo, hi = float(sample.minimum_distance_m), float(sample.maximum_distance_m)
    if not (math.isfinite(d) and d > 0.0):
        return None
    if math.isfinite(lo) and d < lo:
        return None
    if math.isfinite(hi) and d > hi:
        return None
    return d


def parse_url(url: str) -> str:
    """Validate a MAVSDK connection URL and return its scheme (raises VehicleError)."""
    scheme, sep, rest = url.partition("://")
    ok = {"udpin", "udpout", "udp", "tcpin", "tcpout", "tcp", "serial", "raw"}
    if not sep or scheme not in ok:
        raise VehicleError("CONNECTION_ERROR", "connect()", url,
                           "use a MAVSDK URL: udpin://0.0.0.0:14540, udpout://HOST:PORT, "
                           "serial:///dev/ttyACM0:921600, tcpout://HOST:PORT or raw://")
    if scheme in ("udpin", "udpout", "udp", "tcpin", "tcpout", "tcp"):
        host, _, port = rest.rpartition(":")
        if not host or not port.isdigit():
            raise VehicleError("CONNECTION_ERROR", "connect()", url,
                               f"{scheme}:// needs HOST:PORT with an explicit host "
                               "(e.g. udpin://0.0.0.0:14540; MAVSDK rejects udpin://:14540)")
    return scheme


@dataclass
class _Cache:
    """Latest telemetry, updated by the stream tasks (event loop thread only)."""

    local_ned: XYZ | None = None
    local_vel: XYZ = (0.0, 0.0, 0.0)
    local_t_ns: int = 0
    attitude_q: Quat = (1.0, 0.0, 0.0, 0.0)
    attitude_t_ns: int = 0
    rates: XYZ = (0.0, 0.0, 0.0)
    geodetic: GeoPoint | None = None
    relative_alt_m: float = math.nan
    home: GeoPoint | None = None
    home_local: XYZ | None = None
    armed: bool = False
    in_air: bool = False
    mode: FlightMode = FlightMode.UNKNOWN
    battery: float = math.nan
    voltage_v: float = math.nan
    local_ok: bool = False
    global_ok: bool = False
    armable: bool = False
    progress: MissionProgress = MissionProgress(0, 0)
    last_sample_ns: int = 0
    distance_m: float | None = None  # last downward reading inside the sensor's range
    distance_t_ns: int = 0


class MavsdkVehicle:
    """A MAVLink autopilot through MAVSDK 4.1 (see the module docstring).

    Context: ``clock`` (must read host monotonic time: MAVSDK runs in wall time),
    ``safety`` (its ``offboard_watchdog_s`` is the default watchdog timeout), ``mavlink_peer``
    (for ``raw://``).
    """

    Config = MavsdkVehicleConfig
    description = "PX4 / MAVLink autopilot through MAVSDK 4.1 (telemetry, commands, offboard + watchdog)"
    wall_clock = True  # MAVSDK and the autopilot run in host time

    def __init__(self, config: MavsdkVehicleConfig | None = None, *, clock: Clock | None = None,
                 safety: Any = None, mavlink_peer: MavlinkPeer | None = None,
                 **_context: Any) -> None:
        self.config = cfg = config or MavsdkVehicleConfig()
        self.clock: Clock = clock or MonotonicClock()
        self._peer = mavlink_peer
        wd = cfg.watchdog_timeout_s
        if wd is None:
            wd = float(getattr(safety, "offboard_watchdog_s", 0.5))
        self.watchdog_timeout_s = wd
        self._m: dict[str, Any] = {}
        self._sdk: Any = None
        self._system: Any = None
        self._plugins: dict[str, Any] = {}
        self._raw_handle: Any = None
        self._executor: concurrent.futures.ThreadPoolExecutor | None = None
        self._tasks: list[asyncio.Task[None]] = []
        self._connected = False
        self._closed = False
        self._c = _Cache()
        self._history = TelemetryHistory(span_s=cfg.history_s)
        self._events: deque[VehicleEvent] = deque(maxlen=2000)
        self._events_lock = threading.Lock()
        self._link_ok = True
        # mode bookkeeping
        self._expected: set[FlightMode] = set()
        # offboard
        self._ob_lock = threading.Lock()
        self._ob_active = False
        self._ob_confirmed = False
        self._ob_goal: Setpoint | None = None
        self._ob_cmd: Setpoint | None = None
        self._ob_ended: tuple[str, str] | None = None  # (why, detail)
        self._ob_task: asyncio.Task[None] | None = None
        self._watchdog = OffboardWatchdog(wd, self._watchdog_hold)
        self._leaked: list[Any] = []
        self._now_ns: Callable[[], int] = time.monotonic_ns
        self._truth = HilTruth(self._truth_flags) if cfg.ground_truth == "auto" else None
        self._truth_handle: Any = None

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
        self._now_ns = _thread_safe_now(self.clock)
        a = self._now_ns()
        time.sleep(0.002)
        if self._now_ns() <= a:
            raise VehicleError("UNSUPPORTED_CLOCK", "connect()", None,
                               "the clock does not advance in wall time: MAVSDK runs in wall "
                               "time, use MonotonicClock (not a manual or virtual-time clock)")
        if scheme == "raw" and self._peer is None:
            raise VehicleError("CONNECTION_ERROR", "connect()", cfg.url,
                               "raw:// needs a `mavlink_peer` in the context (e.g. the emulator)")
        m = self._m = _import_mavsdk()
        _route_mavsdk_logs()
        self._executor = concurrent.futures.ThreadPoolExecutor(max_workers=4,
                                                               thread_name_prefix="mavsdk-call")
        ctype = (m["ComponentType"].COMPANION_COMPUTER if cfg.component == "companion_computer"
                 else m["ComponentType"].GROUND_STATION)
        self._sdk = sdk = m["Mavsdk"](m["Configuration"].create_with_component_type(ctype))
        t0 = time.monotonic()
        try:
            await self._bounded("connect()", lambda: sdk.add_any_connection_with_handle(cfg.url),
                                timeout_s=cfg.connect_timeout_s, params=cfg.url)
            if scheme == "raw":
                assert self._peer is not None
                self._raw_handle = sdk.subscribe_raw_bytes_to_be_sent(self._peer.feed)
                self._peer.set_output(sdk.pass_received_raw_bytes)
            remaining = max(0.05, cfg.connect_timeout_s - (time.monotonic() - t0))
            system = await self._first_autopilot(remaining)
        except BaseException:
            await self._teardown()
            raise
        if system is None:
            await self._teardown()
            raise TimeoutError_("connect()", cfg.connect_timeout_s,
                                f"no autopilot heard on {cfg.url} within {cfg.connect_timeout_s:g} s: "
                                "check the URL (PX4 SITL sends to udpin://0.0.0.0:14540), the "
                                "cable / baud rate, and that the autopilot is powered and sending")
        self._system = system
        # Plugins only see messages that arrive after they exist: create them at once.
        for name in ("Telemetry", "Action", "Offboard", "Mission", "Param", "Gripper",
                     "Geofence", "MavlinkDirect"):
            self._plugins[name] = m[name](system)
        if self._truth is not None:
            truth, now_ns = self._truth, self._now_ns
            self._truth_handle = self._plugins["MavlinkDirect"].subscribe_message(
                "HIL_STATE_QUATERNION", lambda msg, _ud=None: truth.on_message(
                    now_ns(), msg.fields_json))
        self._connected = True
        self._start_streams()
        self._watchdog.start()
        await self._request_rates()
        await self._request_truth()
        await self._wait_first_telemetry(max(0.5, cfg.connect_timeout_s - (time.monotonic() - t0)))
        self._event(EVENT_LINK, f"connected to {cfg.url}", {"ok": True})

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
        await loop.run_in_executor(None, functools.partial(self._watchdog.stop, grace_s))
        tasks = [t for t in (*self._tasks, self._ob_task) if t is not None]
        for t in tasks:
            t.cancel()
        for t in tasks:
            with contextlib.suppress(BaseException):
                await t
        self._tasks = []
        self._ob_task = None
        if self._peer is not None:
            self._peer.set_output(None)  # no more bytes into MAVSDK once it is destroyed
        idle = True
        if self._executor is not None:
            ex, self._executor = self._executor, None
            try:
                async with asyncio.timeout(grace_s):
                    await loop.run_in_executor(None, functools.partial(
                        ex.shutdown, wait=True, cancel_futures=True))
            except TimeoutError:
                idle = False
        if self._watchdog.running:
            idle = False
        if self._sdk is not None:
            sdk, self._sdk = self._sdk, None
            plugins = list(self._plugins.values())
            self._plugins.clear()
            self._system = None
            if not idle:
                log.error("mavsdk: calls still running after %.0f s: MAVSDK is not destroyed "
                          "(it would abort the process); it is released at exit", grace_s)
                self._leaked.append(sdk)
                return

            def destroy() -> None:
                for plugin in plugins:  # plugins first: each holds the System
                    plugin.destroy()
                sdk.destroy()

            await loop.run_in_executor(None, destroy)

    async def _first_autopilot(self, timeout_s: float) -> Any:
        loop = asyncio.get_running_loop()
        fut: asyncio.Future[Any] = loop.create_future()

        def settle(system: Any) -> None:
            if not fut.done():
                fut.set_result(system)

        def done(system: Any) -> None:  # MAVSDK's thread
            loop.call_soon_threadsafe(settle, system)

        handle = self._sdk.first_autopilot_async(timeout_s, done)
        try:
            async with asyncio.timeout(timeout_s + 1.0):
                return await fut
        except TimeoutError:
            return None
        finally:
            self._sdk.cancel_first_autopilot(handle)

    # ------------------------------------------------------------------------------------------
    # bounded calls and errors
    # ------------------------------------------------------------------------------------------
    async def _bounded(self, origin: str, fn: Callable[[], Any], *, timeout_s: float | None = None,
                       params: Any = None) -> Any:
        """Run a blocking MAVSDK call in the private pool, bounded; map its errors."""
        if self._executor is None:
            raise VehicleError("NO_SYSTEM", origin, params, _REMEDIES["NO_SYSTEM"])
        timeout = self.config.command_timeout_s if timeout_s is None else timeout_s
        loop = asyncio.get_running_loop()
        try:
            async with asyncio.timeout(timeout):
                return await loop.run_in_executor(self._executor, fn)
        except TimeoutError:
            self._event(EVENT_REFUSED, f"{origin}: no answer within {timeout:g} s",
                        {"command": origin, "result": "TIMEOUT"})
            raise TimeoutError_(origin, timeout, f"no answer within {timeout:g} s: "
                                + _REMEDIES["TIMEOUT"]) from None
        except ConnectionError as exc:  # add_any_connection: bad URL, port in use, no device
            raise VehicleError("CONNECTION_ERROR", origin, params,
                               f"{exc}: check the URL, that the port is free and the device exists") from exc
        except Exception as exc:
            if self._m and isinstance(exc, self._m["MavsdkError"]):
                raise self._error(exc, origin, params) from exc
            raise

    def _error(self, exc: Any, origin: str, params: Any) -> VehicleError:
        result = getattr(exc, "result", None)
        name = getattr(result, "name", str(result))
        self._event(EVENT_REFUSED, f"{origin}: {name}", {"command": origin, "result": name})
        detail = f"MAVSDK {getattr(exc, 'origin', origin)}: {name}"
        if name in _REMEDIES:
            detail += f" ({_REMEDIES[name]})"
        return VehicleError(name, origin, params, detail)

    def _require(self, origin: str) -> None:
        if not self._connected:
            raise VehicleError("NO_SYSTEM", origin, None,
                               "not connected: call `await vehicle.connect()` (or use `async with`)")

    # ------------------------------------------------------------------------------------------
    # telemetry streams: one task per stream, each owning its subscription
    # ------------------------------------------------------------------------------------------
    def _start_streams(self) -> None:
        handlers: dict[str, Callable[[int, Any], None]] = {
            "position_velocity_ned": self._on_local,
            "attitude_quaternion": self._on_attitude,
            "attitude_angular_velocity_body": self._on_rates,
            "position": self._on_position,
            "home": self._on_home,
            "armed": self._on_armed,
            "in_air": self._on_in_air,
            "flight_mode": self._on_mode,
            "battery": self._on_battery,
            "health": self._on_health,
            "status_text": self._on_status,
            "distance_sensor": self._on_distance,
        }
        loop = asyncio.get_running_loop()
        for name, handler in handlers.items():
            self._tasks.append(loop.create_task(self._stream(self._plugins["Telemetry"], name, handler),
                                                name=f"mavsdk-{name}"))
        self._tasks.append(loop.create_task(
            self._stream(self._plugins["Mission"], "mission_progress", self._on_progress),
            name="mavsdk-mission_progress"))
        self._tasks.append(loop.create_task(self._supervise(), name="mavsdk-supervisor"))

    async def _stream(self, plugin: Any, name: str, handler: Callable[[int, Any], None]) -> None:
        loop = asyncio.get_running_loop()
        queue: asyncio.Queue[tuple[int, Any]] = asyncio.Queue()
        now_ns = self._now_ns

        def on_sample(data: Any, _user_data: Any = None) -> None:  # MAVSDK's thread
            stamp = now_ns()  # stamped on receipt, before the loop sees it
            with contextlib.suppress(RuntimeError):  # loop closed during shutdown
                loop.call_soon_threadsafe(queue.put_nowait, (stamp, data))

        handle = getattr(plugin, f"subscribe_{name}")(on_sample)
        try:
            while True:
                stamp, data = await queue.get()
                try:
                    handler(stamp, data)
                except Exception:  # one bad sample must not end the stream
                    log.exception("mavsdk %s: cannot handle %r", name, data)
        finally:
            with contextlib.suppress(Exception):
                getattr(plugin, f"unsubscribe_{name}")(handle)

    def _on_local(self, t: int, d: Any) -> None:
        c = self._c
        p, v = d.position, d.velocity
        c.local_ned = (p.north_m, p.east_m, p.down_m)
        c.local_vel = (v.north_m_s, v.east_m_s, v.down_m_s)
        c.local_t_ns = c.last_sample_ns = t
        self._append_state(t)

    def _on_attitude(self, t: int, q: Any) -> None:
        c = self._c
        c.attitude_q = (q.w, q.x, q.y, q.z)
        c.attitude_t_ns = c.last_sample_ns = t
        self._append_state(t)

    def _on_rates(self, t: int, r: Any) -> None:
        self._c.rates = (r.roll_rad_s, r.pitch_rad_s, r.yaw_rad_s)

    def _on_position(self, t: int, p: Any) -> None:
        c = self._c
        c.geodetic = GeoPoint(p.latitude_deg, p.longitude_deg, p.absolute_altitude_m)
        c.relative_alt_m = p.relative_altitude_m
        c.last_sample_ns = t

    def _on_home(self, t: int, h: Any) -> None:
        c = self._c
        c.home = GeoPoint(h.latitude_deg, h.longitude_deg, h.absolute_altitude_m)
        loc = (getattr(h, "local_north_m", math.nan), getattr(h, "local_east_m", math.nan),
               getattr(h, "local_down_m", math.nan))
        if all(math.isfinite(v) for v in loc):
            c.home_local = loc

    def _on_armed(self, t: int, armed: Any) -> None:
        if bool(armed) != self._c.armed:
            self._event(EVENT_STATUS, "armed" if armed else "disarmed", {"armed": bool(armed)})
        self._c.armed = bool(armed)

    def _on_in_air(self, t: int, in_air: Any) -> None:
        self._c.in_air = bool(in_air)

    def _on_mode(self, t: int, mode: Any) -> None:
        name = getattr(mode, "name", None) or self._m["MavFlightMode"](int(mode)).name
        new = FlightMode(name) if name in FlightMode.__members__ else FlightMode.UNKNOWN
        old = self._c.mode
        if new == old:
            return
        self._c.mode = new
        source = "command" if new in self._expected else "autopilot"
        if source == "command":
            self._expected = set()
        self._event(EVENT_MODE, f"{old.value} -> {new.value}",
                    {"from": old.value, "to": new.value, "source": source})
        if new == FlightMode.OFFBOARD and self._ob_active:
            self._ob_confirmed = True
        elif self._ob_active and self._ob_confirmed and source != "command":
            self._offboard_ended("external",
                                 f"the flight mode is now {new.value} (changed by the pilot, a "
                                 "ground station or a PX4 failsafe)")

    def _on_battery(self, t: int, b: Any) -> None:
        pct = b.remaining_percent
        self._c.battery = pct / 100.0 if math.isfinite(pct) else math.nan
        self._c.voltage_v = b.voltage_v

    def _on_health(self, t: int, h: Any) -> None:
        c = self._c
        c.local_ok, c.global_ok, c.armable = (bool(h.is_local_position_ok),
                                              bool(h.is_global_position_ok), bool(h.is_armable))

    def _on_status(self, t: int, s: Any) -> None:
        text = str(s.text).strip()
        severity = getattr(s.type, "name", str(s.type)).lower()
        self._event(EVENT_STATUS, text, {"severity": severity})
        if "failsafe" in text.lower():
            self._event(EVENT_FAILSAFE, text, {"reason": "autopilot", "action": "see mode events"})

    def _on_distance(self, t: int, d: Any) -> None:
        c = self._c
        c.distance_m = downward_range_m(d)
        c.distance_t_ns = t

    def _distance_at(self, t: int) -> float | None:
        """The last downward reading if it is at most ``distance_sensor_max_age_s`` old at
        ``t`` (and not from after ``t`` by more than that either)."""
        c = self._c
        if c.distance_m is None:
            return None
        age_ns = abs(t - c.distance_t_ns)
        return c.distance_m if age_ns <= self.config.distance_sensor_max_age_s * 1e9 else None

    def _on_progress(self, t: int, p: Any) -> None:
        new = MissionProgress(int(p.current), int(p.total))
        if new != self._c.progress:
            self._event(EVENT_MISSION, f"mission progress {new.current}/{new.total}",
                        {"index": new.current, "total": new.total})
        self._c.progress = new

    async def _supervise(self) -> None:
        """Link watch (no telemetry for ``link_timeout_s``) at 10 Hz."""
        while True:
            await asyncio.sleep(0.1)
            age_s = (self._now_ns() - self._c.last_sample_ns) * 1e-9
            ok = age_s < self.config.link_timeout_s
            if ok != self._link_ok:
                self._link_ok = ok
                self._event(EVENT_LINK, "link regained" if ok else
                            f"link lost: no telemetry for {age_s:.1f} s", {"ok": ok})

    def _home_local(self) -> XYZ | None:
        """Home in the EKF-local frame: HOME_POSITION x/y/z, else derived from the global and
        local positions (which need home)."""
        c = self._c
        if c.home_local is not None:
            return c.home_local
        if c.home is None or c.geodetic is None or c.local_ned is None:
            return None
        g = geodetic_to_ned(c.home, c.geodetic)
        return (c.local_ned[0] - g[0], c.local_ned[1] - g[1], c.local_ned[2] - g[2])

    def _build_state(self, t: int, *, now_ns: int | None = None) -> VehicleState | None:
        """The state at sample time ``t``; the range reading's age is judged at ``now_ns``
        (default ``t``)."""
        c = self._c
        if c.local_ned is None:
            return None
        hl = self._home_local() or (0.0, 0.0, 0.0)
        # Bring the position to the sample time with the velocity (the streams are not in phase).
        dt = (t - c.local_t_ns) * 1e-9 if c.local_t_ns else 0.0
        dt = dt if 0.0 <= dt <= 0.1 else 0.0
        v = c.local_vel
        pos = (c.local_ned[0] + v[0] * dt - hl[0], c.local_ned[1] + v[1] * dt - hl[1],
               c.local_ned[2] + v[2] * dt - hl[2])
        link_ok = (self._now_ns() - c.last_sample_ns) * 1e-9 < self.config.link_timeout_s
        rel = c.relative_alt_m if math.isfinite(c.relative_alt_m) else -pos[2]
        return VehicleState(
            timestamp_ns=t, position_ned_m=pos, velocity_ned_mps=v, attitude_q=c.attitude_q,
            angular_velocity_frd_radps=c.rates, geodetic=c.geodetic, relative_altitude_m=rel,
            home=c.home, armed=c.armed, in_air=c.in_air, flight_mode=c.mode,
            battery_remaining=c.battery if math.isfinite(c.battery) else 1.0,
            battery_voltage_v=c.voltage_v,
            position_valid=c.local_ok and (c.home is not None),
            gps_fix=c.global_ok, link_ok=link_ok, armable=c.armable,
            distance_to_ground_m=self._distance_at(t if now_ns is None else now_ns))

    def _append_state(self, t: int) -> None:
        s = self._build_state(t)
        if s is not None:
            self._history.append(s)

    async def _request_rates(self) -> None:
        tel = self._plugins["Telemetry"]
        fast = self.config.telemetry_rate_hz
        for name, hz in (("position", fast), ("position_velocity_ned", fast),
                         ("attitude_quaternion", fast), ("in_air", self.config.state_rate_hz),
                         ("home", 1.0), ("distance_sensor", self.config.distance_sensor_rate_hz)):
            if hz <= 0:
                continue
            setter = functools.partial(getattr(tel, f"set_rate_{name}"), hz)
            try:
                await self._bounded(f"set_rate_{name}()", setter)
            except VehicleError as exc:  # the autopilot may not honour it: telemetry still flows
                log.warning("telemetry rate not set: %s", exc)

    async def _request_truth(self) -> None:
        """MAV_CMD_SET_MESSAGE_INTERVAL(HIL_STATE_QUATERNION): PX4 SIH streams its ground truth
        only when asked; a refusal (a real aircraft) is not an error."""
        if self._truth is None:
            return
        m = self._m
        fields = {"target_system": 1, "target_component": 1, "command": 511,
                  "confirmation": 0, "param1": float(HIL_MSG_ID),
                  "param2": 1e6 / self.config.ground_truth_rate_hz, "param3": 0.0,
                  "param4": 0.0, "param5": 0.0, "param6": 0.0, "param7": 0.0}
        msg = m["MavlinkMessage"](message_name="COMMAND_LONG", system_id=0, component_id=0,
                                  target_system_id=1, target_component_id=1,
                                  fields_json=json.dumps(fields))
        md = self._plugins["MavlinkDirect"]
        try:
            await self._bounded("request ground truth", lambda: md.send_command(msg))
        except VehicleError as exc:
            log.info("no ground-truth stream requested: %s", exc)

    def _truth_flags(self) -> tuple[bool, bool, FlightMode]:
        c = self._c
        return c.armed, c.in_air, c.mode

    def ground_truth(self) -> HilTruth | None:
        """Simulator ground truth (HIL_STATE_QUATERNION), None with ``ground_truth: off``;
        ``available()`` once a sample arrived (never on a real aircraft)."""
        return self._truth

    def summary(self) -> str:
        return f"url {self.config.url}"

    async def upload_geofence(self, geofence: Any) -> None:
        """Upload the envelope's geofence (a circle around home or a NED polygon) as PX4's
        inclusion fence; PX4 then enforces it itself (its GF_ACTION)."""
        self._require("upload_geofence()")
        home = await self._home("upload_geofence()")
        if home is None:
            raise VehicleError("NO_HOME", "upload_geofence()", None,
                               "home is not known yet: wait for telemetry (GPS fix)")
        m = self._m
        polygons, circles = [], []
        if geofence.polygon_ned_m:
            pts = [ned_to_geodetic(home, n, e, 0.0) for n, e in geofence.polygon_ned_m]
            polygons.append(m["Polygon"]([m["Point"](p.latitude_deg, p.longitude_deg) for p in pts],
                                         m["FenceType"].INCLUSION))
        if geofence.radius_m is not None:
            circles.append(m["Circle"](m["Point"](home.latitude_deg, home.longitude_deg),
                                       float(geofence.radius_m), m["FenceType"].INCLUSION))
        data = m["GeofenceData"](polygons, circles)
        gf = self._plugins["Geofence"]
        await self._bounded("upload_geofence()", lambda: gf.upload_geofence(data),
                            timeout_s=self.config.mission_upload_timeout_s)
        self._event(EVENT_STATUS, "geofence uploaded",
                    {"circles": len(circles), "polygons": len(polygons)})

    async def _wait_first_telemetry(self, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            c = self._c
            if c.local_ned is not None and c.mode != FlightMode.UNKNOWN and c.home is not None:
                return
            await asyncio.sleep(0.02)
        log.warning("mavsdk: connected but no local position, flight mode or home within %.1f s "
                    "(no GPS fix yet?)", timeout_s)

    # ------------------------------------------------------------------------------------------
    # Vehicle protocol: telemetry
    # ------------------------------------------------------------------------------------------
    def state(self) -> VehicleState:
        self._require("state()")
        now = self._now_ns()
        s = self._build_state(self._c.last_sample_ns or now, now_ns=now)
        if s is None:
            return VehicleState(timestamp_ns=self._now_ns(), position_ned_m=(0.0, 0.0, 0.0),
                                velocity_ned_mps=(0.0, 0.0, 0.0), attitude_q=self._c.attitude_q,
                                armed=self._c.armed, flight_mode=self._c.mode,
                                position_valid=False, gps_fix=False,
                                link_ok=self._link_ok, armable=False)
        return s

    def state_at(self, timestamp_ns: int) -> VehicleState | None:
        self._require("state_at()")
        return self._history.state_at(timestamp_ns)

    def events(self) -> Sequence[VehicleEvent]:
        with self._events_lock:
            return tuple(self._events)

    def mission_progress(self) -> MissionProgress:
        self._require("mission_progress()")
        return self._c.progress

    def _event(self, kind: str, text: str, data: dict[str, object] | None = None) -> None:
        with self._events_lock:
            self._events.append(VehicleEvent(self._now_ns(), kind, text, dict(data or {})))

    # ------------------------------------------------------------------------------------------
    # commands
    # ------------------------------------------------------------------------------------------
    async def _confirm(self, origin: str, predicate: Callable[[], bool], what: str) -> None:
        """Wait (bounded) until telemetry shows the effect of an accepted command."""
        if not self.config.confirm_modes:
            return
        deadline = time.monotonic() + self.config.command_timeout_s
        while not predicate():
            if time.monotonic() > deadline:
                raise TimeoutError_(origin, self.config.command_timeout_s,
                                    f"accepted, but telemetry never showed {what}")
            await asyncio.sleep(0.02)

    async def _mode_command(self, origin: str, fn: Callable[[], Any], modes: set[FlightMode],
                            params: Any = None, *, also_ok: frozenset[FlightMode] = frozenset()
                            ) -> None:
        """A command that changes the flight mode to one of ``modes`` (ours, not external);
        ``also_ok`` are modes the autopilot may move on to by itself (TAKEOFF -> HOLD)."""
        self._expected = set(modes)
        await self._bounded(origin, fn, params=params)
        ok = modes | also_ok
        await self._confirm(origin, lambda: self._c.mode in ok,
                            "the flight mode " + "/".join(sorted(m.value for m in ok)))

    async def arm(self) -> None:
        self._require("arm()")
        await self._bounded("arm()", self._plugins["Action"].arm)
        await self._confirm("arm()", lambda: self._c.armed, "armed")

    async def disarm(self) -> None:
        self._require("disarm()")
        await self._bounded("disarm()", self._plugins["Action"].disarm)
        await self._confirm("disarm()", lambda: not self._c.armed, "disarmed")

    async def takeoff(self, altitude_m: float) -> None:
        """Take off to ``altitude_m`` above home (PX4 MIS_TAKEOFF_ALT); returns when accepted."""
        self._require("takeoff()")
        if not (math.isfinite(altitude_m) and altitude_m > 0):
            raise VehicleError("INVALID_ARGUMENT", "takeoff()", (altitude_m,),
                               f"altitude_m must be a finite height above home > 0, got {altitude_m}")
        if not self._c.armed:
            self._event(EVENT_REFUSED, "takeoff(): COMMAND_DENIED: not armed",
                        {"command": "takeoff()", "result": "COMMAND_DENIED"})
            raise VehicleError("COMMAND_DENIED", "takeoff()", (altitude_m,),
                               "the vehicle is not armed: arm first")
        act = self._plugins["Action"]
        await self._bounded("takeoff()", lambda: act.set_takeoff_altitude(float(altitude_m)),
                            params=(altitude_m,))
        self._stop_streaming()
        await self._mode_command("takeoff()", act.takeoff, {FlightMode.TAKEOFF},
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
        act = self._plugins["Action"]
        self._stop_streaming()
        await self._mode_command("goto()", lambda: act.goto_location(*vals, yaw), {FlightMode.HOLD},
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
        m = self._m
        items = []
        for i, w in enumerate(wps):
            vals = (w.north_m, w.east_m, w.altitude_m, w.acceptance_radius_m)
            if not all(math.isfinite(v) for v in vals) or w.acceptance_radius_m <= 0:
                raise VehicleError("INVALID_ARGUMENT", "upload_mission()", i,
                                   f"waypoint {i} is not finite or has acceptance_radius_m <= 0: {w}")
            g = ned_to_geodetic(home, w.north_m, w.east_m, 0.0)
            items.append(m["MissionItem"](
                latitude_deg=g.latitude_deg, longitude_deg=g.longitude_deg,
                relative_altitude_m=float(w.altitude_m),
                speed_m_s=float(w.speed_mps) if w.speed_mps else math.nan,
                is_fly_through=True, acceptance_radius_m=float(w.acceptance_radius_m),
                camera_action=m["MissionItem"].CameraAction.NONE,
                vehicle_action=m["MissionItem"].VehicleAction.NONE))
        plan = m["MissionPlan"](items)
        mission = self._plugins["Mission"]
        await self._bounded("upload_mission()", lambda: mission.set_return_to_launch_after_mission(False))
        await self._bounded("upload_mission()", lambda: mission.upload_mission(plan),
                            timeout_s=self.config.mission_upload_timeout_s, params=len(wps))
        self._c.progress = MissionProgress(0, len(wps))

    async def _home(self, origin: str) -> GeoPoint | None:
        deadline = time.monotonic() + self.config.command_timeout_s
        while self._c.home is None and time.monotonic() < deadline:
            await asyncio.sleep(0.05)
        return self._c.home

    async def start_mission(self) -> None:
        self._require("start_mission()")
        self._stop_streaming()
        await self._mode_command("start_mission()", self._plugins["Mission"].start_mission,
                                 {FlightMode.MISSION})

    async def hold(self) -> None:
        self._require("hold()")
        if self._ob_active:
            await self.stop_offboard()
            return
        await self._mode_command("hold()", self._plugins["Action"].hold, {FlightMode.HOLD})

    async def land(self) -> None:
        self._require("land()")
        self._stop_streaming()
        await self._mode_command("land()", self._plugins["Action"].land, {FlightMode.LAND})

    async def return_to_launch(self) -> None:
        self._require("return_to_launch()")
        self._stop_streaming()
        await self._mode_command("return_to_launch()", self._plugins["Action"].return_to_launch,
                                 {FlightMode.RETURN_TO_LAUNCH})

    async def grab(self) -> None:
        self._require("grab()")
        g = self._plugins["Gripper"]
        await self._bounded("grab()", lambda: g.grab(self.config.gripper_instance))
        self._event(EVENT_GRIPPER, "Gripper grab", {"action": "grab"})

    async def release(self) -> None:
        self._require("release()")
        g = self._plugins["Gripper"]
        await self._bounded("release()", lambda: g.release(self.config.gripper_instance))
        self._event(EVENT_GRIPPER, "Gripper release", {"action": "release"})

    async def get_param(self, name: str) -> float:
        """Read an autopilot parameter (float, else int), e.g. PX4's COM_OF_LOSS_T."""
        self._require("get_param()")
        p = self._plugins["Param"]
        try:
            return float(await self._bounded("get_param()", lambda: p.get_param_float(name),
                                             params=name))
        except VehicleError as exc:
            if exc.result != "WRONG_TYPE":
                raise
        return float(await self._bounded("get_param()", lambda: p.get_param_int(name), params=name))

    async def set_param(self, name: str, value: float) -> None:
        """Write a float parameter (ints: :meth:`set_param_int`)."""
        self._require("set_param()")
        p = self._plugins["Param"]
        await self._bounded("set_param()", lambda: p.set_param_float(name, float(value)),
                            params=(name, value))

    # ------------------------------------------------------------------------------------------
    # offboard
    # ------------------------------------------------------------------------------------------
    def _local_setpoint(self, sp: Setpoint) -> Any:
        hl = self._home_local() or (0.0, 0.0, 0.0)
        return self._m["PositionNedYaw"](sp.north_m + hl[0], sp.east_m + hl[1],
                                         sp.down_m + hl[2], sp.yaw_deg)

    async def start_offboard(self, initial: Setpoint) -> None:
        """Enter OFFBOARD: first setpoint = current position and yaw, then stream steps towards
        ``initial`` (and later goals from :meth:`set_setpoint`)."""
        self._require("start_offboard()")
        c = self._c
        if not isinstance(initial, Setpoint):
            raise VehicleError("NO_SETPOINT_SET", "start_offboard()", None,
                               "give the first goal as a Setpoint")
        if not c.armed:
            raise VehicleError("COMMAND_DENIED", "start_offboard()", (initial,),
                               "the vehicle is not armed: arm (and take off) first")
        age_s = (self._now_ns() - c.local_t_ns) * 1e-9
        if not c.local_ok or c.local_ned is None or age_s > self.config.position_max_age_s:
            raise VehicleError("NO_VALID_POSITION", "start_offboard()", (initial,),
                               "PX4 needs a valid local position for offboard "
                               f"(local_position_ok={c.local_ok}, last sample {age_s:.2f} s ago)")
        s = self.state()
        here = Setpoint(*s.position_ned_m, s.yaw_deg)  # never (0, 0, 0): PX4 would fly there
        ob = self._plugins["Offboard"]
        with self._ob_lock:
            self._ob_goal = initial
            self._ob_cmd = here
            self._ob_ended = None
            self._ob_confirmed = c.mode == FlightMode.OFFBOARD
        await self._bounded("start_offboard()", lambda: ob.set_position_ned(self._local_setpoint(here)),
                            params=(initial,))
        self._ob_active = True
        self._watchdog.arm()
        if self._ob_task is None or self._ob_task.done():
            self._ob_task = asyncio.get_running_loop().create_task(self._offboard_loop(),
                                                                   name="mavsdk-offboard")
        try:
            await self._mode_command("start_offboard()", ob.start, {FlightMode.OFFBOARD},
                                     params=(initial,))
        except BaseException:
            self._stop_streaming()
            raise
        self._ob_confirmed = True

    async def set_setpoint(self, setpoint: Setpoint) -> None:
        """New offboard goal (NED relative to home, yaw); the stream steps towards it."""
        self._require("set_setpoint()")
        ended = self._ob_ended
        if ended is not None:
            why, detail = ended
            raise ModeChangedExternally(
                "MODE_CHANGED" if why == "external" else "WATCHDOG_HOLD", "set_setpoint()",
                (setpoint,), detail + ": our offboard control has ended; call "
                "start_offboard() to take it back")
        if not self._ob_active:
            raise VehicleError("OFFBOARD_NOT_ACTIVE", "set_setpoint()", (setpoint,),
                               "call start_offboard() first")
        self._ob_goal = setpoint
        self._watchdog.feed()

    async def stop_offboard(self) -> None:
        """Leave OFFBOARD on purpose: MAVSDK ``Offboard.stop()`` (HOLD, setpoints stop)."""
        self._require("stop_offboard()")
        was = self._ob_active
        self._stop_streaming()
        if not was and self._c.mode != FlightMode.OFFBOARD:
            return
        await self._mode_command("stop_offboard()", self._plugins["Offboard"].stop,
                                 {FlightMode.HOLD})

    def _stop_streaming(self) -> None:
        """Our offboard control ends (a command changes the mode)."""
        self._watchdog.disarm()
        self._ob_active = False
        self._ob_ended = None

    def _offboard_ended(self, why: str, detail: str) -> None:
        was = self._ob_active
        self._watchdog.disarm()
        self._ob_active = False
        self._ob_ended = (why, detail)
        if was:
            log.warning("offboard ended (%s): %s", why, detail)
            self._event(EVENT_MODE, f"offboard ended: {detail}",
                        {"from": FlightMode.OFFBOARD.value, "to": self._c.mode.value,
                         "source": why})

    async def _offboard_loop(self) -> None:
        """The setpoint timer: independent of perception, ``offboard_rate_hz``."""
        cfg = self.config
        period = 1.0 / cfg.offboard_rate_hz
        ob = self._plugins["Offboard"]
        last = self._now_ns()
        while True:
            await asyncio.sleep(period)
            now = self._now_ns()
            dt, last = min((now - last) * 1e-9, 0.5), now
            if not self._ob_active or self._ob_goal is None or self._ob_cmd is None:
                continue
            cmd = step_towards(self._ob_cmd, self._ob_goal, dt, max_speed_mps=cfg.offboard_max_speed_mps,
                               max_vertical_speed_mps=cfg.offboard_max_vertical_speed_mps,
                               max_yaw_rate_degps=cfg.offboard_max_yaw_rate_degps)
            self._ob_cmd = cmd
            try:
                ob.set_position_ned(self._local_setpoint(cmd))  # non-blocking: queues a message
            except Exception as exc:
                if self._m and isinstance(exc, self._m["MavsdkError"]):
                    log.warning("offboard setpoint not sent: %s", exc)
                else:
                    raise

    def _watchdog_hold(self, age_s: float) -> None:
        """Watchdog thread: fresh setpoints stopped. MAVSDK's blocking calls need nothing from
        the (possibly blocked) event loop."""
        self._ob_active = False
        self._ob_ended = ("watchdog", f"no fresh setpoint for {age_s:.2f} s "
                          f"(watchdog {self.watchdog_timeout_s:g} s): the watchdog commanded HOLD")
        self._expected = {FlightMode.HOLD}
        self._event(EVENT_WATCHDOG, self._ob_ended[1], {"age_s": round(age_s, 3)})
        ob, act = self._plugins.get("Offboard"), self._plugins.get("Action")
        try:
            if ob is not None:
                ob.stop()  # DO_SET_MODE hold + stop re-sending the last setpoint
                return
        except Exception as exc:  # noqa: BLE001 - fall back on a plain hold
            log.warning("watchdog: offboard.stop() failed (%s): trying action.hold()", exc)
        if act is not None:
            act.hold()


def _thread_safe_now(clock: Clock) -> Callable[[], int]:
    """``clock.now_ns`` if it can be called from MAVSDK's thread; a :class:`LoopClock` reads
    the running loop (not available there), and on a normal loop that is host monotonic time."""
    if isinstance(clock, LoopClock):
        return time.monotonic_ns
    return clock.now_ns


def _route_mavsdk_logs() -> None:
    """MAVSDK's C++ log lines into Python logging (once)."""
    global _LOGS_ROUTED
    if _LOGS_ROUTED:
        return
    try:
        from mavsdk.logging import LogLevel, log_subscribe
    except ImportError:  # pragma: no cover
        return
    levels = {LogLevel.DEBUG: logging.DEBUG, LogLevel.INFO: logging.INFO,
              LogLevel.WARN: logging.WARNING, LogLevel.ERROR: logging.ERROR}
    mlog = logging.getLogger("mavsdk")

    def handler(level: Any, message: str, file: str | None, line: int) -> bool:
        mlog.log(levels.get(level, logging.INFO), "%s", message)
        return True

    log_subscribe(handler)
    _LOGS_ROUTED = True


_LOGS_ROUTED = False
