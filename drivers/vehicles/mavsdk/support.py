"""What the MAVSDK driver (:mod:`.mavsdk_vehicle`) is built from: its params, the one place
that imports ``mavsdk``, and pure helpers (URLs, offboard steps, the downward range).

MAVSDK ships no type information: its modules are imported as module objects here, so the
classes the driver uses are typed ``Any``.
"""

from __future__ import annotations

import importlib
import logging
import math
import os
import time
from collections.abc import Callable, Sequence
from typing import Annotated, Any, Literal, Protocol

from pydantic import BaseModel, ConfigDict, Field

from eaglemission.clock import Clock, LoopClock
from eaglemission.config import GeofenceConfig
from eaglemission.errors import PluginError, VehicleError
from eaglemission.geometry import ned_to_geodetic, wrap_deg
from eaglemission.types import GeoPoint, Setpoint, Waypoint

MAVSDK_REMEDY = ('the mavsdk vehicle needs the [mavsdk] extra: pip install "eaglemission[mavsdk]" '
                 '(mavsdk 4.1)')

REMEDIES = {
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
    offboard_loss_timeout_s: Annotated[float | None, Field(gt=0, le=60)] = None
    """The autopilot's offboard-loss timeout (PX4 COM_OF_LOSS_T); None: read at connect (1 s,
    PX4's default, if it cannot be read). Telemetry silent longer than this while offboard
    means the setpoints did not arrive either: a ``failover`` event (docs/vehicles.md)."""
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
    ground_truth_altitude: Literal["amsl", "ned_z"] = "amsl"
    """What HIL_STATE_QUATERNION's ``alt`` (mm) holds: ``amsl``, the true altitude above mean sea
    level (PX4 SIH, the emulator); ``ned_z``, the simulator's NED z, i.e. minus the height above
    its origin (PX4 passes jMAVSim's on unchanged). The truth is measured from its first sample
    either way. A wrong choice shows as an altitude moving against the message's own vertical
    velocity: the driver then warns and records a ``truth`` event naming this param."""
    ground_truth_horizontal: Literal["latlon", "velocity"] = "latlon"
    """Where the true horizontal position comes from: ``latlon``, the message's ``lat``/``lon``
    (PX4 SIH, the emulator: the true position); ``velocity``, its true velocity integrated and
    held to ``lat``/``lon`` with a 1 s time constant (jMAVSim, whose ``lat``/``lon`` are its
    simulated GPS: the true position plus about 1 cm of noise per axis)."""
    confirm_modes: bool = True
    """After an accepted command, wait (bounded by ``confirm_timeout_s``) until telemetry shows
    its mode/armed state (PX4 sends HEARTBEAT at 1 Hz only, never on change: recorded, the new
    mode shows 0.08-0.95 s after the ACCEPTED ack)."""
    confirm_timeout_s: Annotated[float, Field(gt=0, le=60)] = 3.0
    """How long an accepted mode / arming command may take to show in the HEARTBEAT (PX4: at
    its next 1 Hz HEARTBEAT, <= 1.05 s recorded; 3 s leaves a lost HEARTBEAT's margin)."""
    disarm_after_landing_timeout_s: Annotated[float, Field(gt=0, le=60)] = 5.0
    """After touchdown is reported (``in_air`` False), how long to wait for PX4's own
    auto-disarm (recorded: "Disarmed by landing" 2.02 s after "Landing detected"
    (COM_DISARM_LAND 2 s), shown at the next HEARTBEAT) before disarming explicitly."""


class MavlinkPeer(Protocol):
    """The other end of a ``raw://`` connection (e.g. :class:`.mavlink_emulator.Px4Emulator`)."""

    def feed(self, data: bytes) -> None: ...

    def set_output(self, fn: Callable[[bytes], None] | None) -> None: ...


def import_mavsdk() -> dict[str, Any]:
    """The MAVSDK classes the driver uses (lazy import with a remedy)."""
    names = {
        "component_type": ["ComponentType"], "exceptions": ["MavsdkError"],
        "mavsdk": ["Configuration", "Mavsdk"], "plugins.action": ["Action"],
        "plugins.geofence": ["Circle", "FenceType", "Geofence", "GeofenceData", "Point", "Polygon"],
        "plugins.gripper": ["Gripper"], "plugins.info": ["Info"],
        "plugins.mavlink_direct": ["MavlinkDirect", "MavlinkMessage"],
        "plugins.mission": ["Mission", "MissionItem", "MissionPlan"],
        "plugins.offboard": ["Offboard", "PositionNedYaw"], "plugins.param": ["Param"],
        "plugins.telemetry": ["Telemetry"],
    }
    out: dict[str, Any] = {}
    try:
        for module, attrs in names.items():
            mod = importlib.import_module(f"mavsdk.{module}")
            for attr in attrs:
                out[attr] = getattr(mod, attr)
        out["MavFlightMode"] = importlib.import_module("mavsdk.plugins.telemetry").FlightMode
    except (ImportError, AttributeError) as exc:  # pragma: no cover - depends on the install
        raise PluginError(f"cannot import mavsdk ({exc}): {MAVSDK_REMEDY}") from exc
    return out


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


def serial_problem(url: str) -> str | None:
    """Why a ``serial://`` URL's device cannot be opened (None: it can, or not serial): checked
    before MAVSDK tries, whose own error names neither the device nor the fix."""
    scheme, _, rest = url.partition("://")
    if scheme != "serial":
        return None
    device, _, baud = rest.rpartition(":")
    device = device if baud.isdigit() else rest
    if not device.startswith("/"):
        return None  # COM3 and the like: MAVSDK's own check
    if not os.path.exists(device):
        return f"{device} not found: plug in the autopilot (or fix vehicle.params.url)"
    if not os.access(device, os.R_OK | os.W_OK):
        return (f"{device}: no permission to open it: add your user to its group "
                "(ls -l shows it, e.g. dialout) and log in again")
    return None


def mission_plan(m: dict[str, Any], home: GeoPoint, waypoints: Sequence[Waypoint]) -> Any:
    """The MAVSDK ``MissionPlan`` of a route (NED relative to home, heights above home);
    raises VehicleError on an invalid waypoint."""
    items = []
    for i, w in enumerate(waypoints):
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
    return m["MissionPlan"](items)


def geofence_data(m: dict[str, Any], home: GeoPoint, geofence: GeofenceConfig
                  ) -> tuple[Any, int, int]:
    """(MAVSDK ``GeofenceData``, circles, polygons) of the envelope's geofence: a circle around
    home and / or a NED polygon, as PX4 inclusion fences."""
    polygons, circles = [], []
    if geofence.polygon_ned_m:
        pts = [ned_to_geodetic(home, n, e, 0.0) for n, e in geofence.polygon_ned_m]
        polygons.append(m["Polygon"]([m["Point"](p.latitude_deg, p.longitude_deg) for p in pts],
                                     m["FenceType"].INCLUSION))
    if geofence.radius_m is not None:
        circles.append(m["Circle"](m["Point"](home.latitude_deg, home.longitude_deg),
                                   float(geofence.radius_m), m["FenceType"].INCLUSION))
    return m["GeofenceData"](polygons, circles), len(circles), len(polygons)


def thread_safe_now(clock: Clock) -> Callable[[], int]:
    """``clock.now_ns`` if it can be called from MAVSDK's thread; a :class:`LoopClock` reads
    the running loop (not available there), and on a normal loop that is host monotonic time."""
    if isinstance(clock, LoopClock):
        return time.monotonic_ns
    return clock.now_ns


def route_mavsdk_logs() -> None:
    """MAVSDK's C++ log lines into Python logging (once)."""
    global _LOGS_ROUTED
    if _LOGS_ROUTED:
        return
    try:
        mavsdk_logging = importlib.import_module("mavsdk.logging")
    except ImportError:  # pragma: no cover
        return
    lv = mavsdk_logging.LogLevel
    levels = {lv.DEBUG: logging.DEBUG, lv.INFO: logging.INFO, lv.WARN: logging.WARNING,
              lv.ERROR: logging.ERROR}
    mlog = logging.getLogger("mavsdk")

    def handler(level: Any, message: str, file: str | None, line: int) -> bool:
        mlog.log(levels.get(level, logging.INFO), "%s", message)
        return True

    mavsdk_logging.log_subscribe(handler)
    _LOGS_ROUTED = True


_LOGS_ROUTED = False
