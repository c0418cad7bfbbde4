"""A PX4-like multicopter that speaks MAVLink 2, for testing the MAVSDK driver without PX4.

It answers the way PX4 v1.16 answered MAVSDK 4.1 in the recorded SITL traffic
(``../shared/data/px4_sitl_tlogs``): HEARTBEAT with PX4 custom modes at 1 Hz (and, by default,
again on every change), COMMAND_ACK for every command (DO_SET_MODE acknowledged twice),
SYS_STATUS with sensor and pre-arm bits, HOME_POSITION, GLOBAL_POSITION_INT,
LOCAL_POSITION_NED (relative to an EKF origin a few decimetres from home, as on PX4),
ATTITUDE(+_QUATERNION), EXTENDED_SYS_STATE, BATTERY_STATUS, GPS_RAW_INT, CURRENT_MODE,
DISTANCE_SENSOR (a downward rangefinder, when ``rangefinder.enabled``; encoded as PX4 SIH's), the
mission protocol (upload, download, MISSION_CURRENT, MISSION_ITEM_REACHED re-sent at 1 Hz),
DO_SET_MODE, DO_REPOSITION, takeoff/land/RTL, offboard SET_POSITION_TARGET_LOCAL_NED with
PX4's offboard-loss failsafe (COM_OF_LOSS_T, COM_OBL_RC_ACT), DO_GRIPPER, the parameter protocol
and SET_MESSAGE_INTERVAL / REQUEST_MESSAGE.

The vehicle is :class:`eaglemission.drivers.vehicles.dynamics.MulticopterDynamics` (the same
model as the ``simulated`` plugin), stepped in the emulator's own thread, so the emulator keeps
flying while the client's event loop is blocked.

Time: ``speedup`` scales the emulator's simulated time (dynamics and its own timers: offboard
loss, landing detection, auto-disarm, failsafes). Stream rates and HEARTBEAT stay in wall time
because MAVSDK's timers do (it declares a link dead after 3 s without HEARTBEAT). Offboard
setpoints arrive every 50 ms wall, i.e. every ``0.05 * speedup`` s of emulator time: keep that
below COM_OF_LOSS_T (``speedup <= 10`` with the default 1 s).

Transports: ``udpin://host:port`` (bind, answer the last sender), ``udpout://host:port`` (send
first), or none: then bytes go out through :meth:`Px4Emulator.set_output` and come in through
:meth:`Px4Emulator.feed` (MAVSDK's ``raw://`` connection, one process, no sockets).
"""

from __future__ import annotations

import heapq
import logging
import math
import os
import queue
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Annotated, Any

os.environ.setdefault("MAVLINK20", "1")
import numpy as np  # noqa: E402
from eaglemission.drivers.vehicles import px4  # noqa: E402
from eaglemission.drivers.vehicles.dynamics import (  # noqa: E402
    DynamicsParams,
    KinematicState,
    MulticopterDynamics,
    RangefinderParams,
    _Normals,
    rangefinder_reading_m,
)
from pydantic import BaseModel, ConfigDict, Field  # noqa: E402
from pymavlink import mavutil  # noqa: E402,F401  (mavutil reads MAVLINK20 at import)
from pymavlink.dialects.v20 import development as mavlink  # noqa: E402

from eaglemission.errors import ConfigError  # noqa: E402
from eaglemission.geometry import (  # noqa: E402
    R_to_euler,
    down_axis_cos_tilt,
    geodetic_to_ned,
    ned_to_geodetic,
    quat_to_R,
)
from eaglemission.types import FlightMode, GeoPoint, Setpoint  # noqa: E402

log = logging.getLogger(__name__)

M = mavlink
SENSORS = (M.MAV_SYS_STATUS_SENSOR_3D_GYRO | M.MAV_SYS_STATUS_SENSOR_3D_ACCEL
           | M.MAV_SYS_STATUS_SENSOR_3D_MAG | M.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE)
GPS_BIT = M.MAV_SYS_STATUS_SENSOR_GPS
PREARM_BIT = M.MAV_SYS_STATUS_PREARM_CHECK

# PX4 "Onboard" MAVLink profile rates, as recorded (README of px4_sitl_tlogs, item 1).
PX4_ONBOARD_RATES_HZ: dict[str, float] = {
    "HEARTBEAT": 1.0,
    "ATTITUDE": 100.0,
    "ATTITUDE_QUATERNION": 50.0,
    "GLOBAL_POSITION_INT": 50.0,
    "LOCAL_POSITION_NED": 30.0,
    "GPS_RAW_INT": 8.0,
    "SYS_STATUS": 5.0,
    "EXTENDED_SYS_STATE": 5.0,
    "MISSION_CURRENT": 1.0,
    "HOME_POSITION": 0.5,
    "BATTERY_STATUS": 0.5,
    "CURRENT_MODE": 0.5,
    "DISTANCE_SENSOR": 10.0,  # recorded 9.85 Hz; sent only with a rangefinder (config)
    "HIL_STATE_QUATERNION": 0.0,  # ground truth: not streamed until requested (as PX4 SIH)
}
HIL_STATE_DEFAULT_HZ = 50.0
"""Rate of HIL_STATE_QUATERNION when requested with interval 0 ("default")."""
MSG_IDS: dict[str, int] = {name: getattr(M, f"MAVLINK_MSG_ID_{name}") for name in
                           [*PX4_ONBOARD_RATES_HZ, "AUTOPILOT_VERSION", "GPS_GLOBAL_ORIGIN"]}
MSG_NAMES: dict[int, str] = {v: k for k, v in MSG_IDS.items()}

LANDED_UNDEFINED = M.MAV_LANDED_STATE_UNDEFINED
ON_GROUND = M.MAV_LANDED_STATE_ON_GROUND
IN_AIR = M.MAV_LANDED_STATE_IN_AIR
TAKING_OFF = M.MAV_LANDED_STATE_TAKEOFF
LANDING = M.MAV_LANDED_STATE_LANDING

DISTANCE_NO_RETURN_CM = 65535
"""UINT16_MAX: what PX4 SIH sends beyond the maximum range ("lightware lw20 behaviour"; also
recorded after the landing of scenario a)."""
DISTANCE_SENSOR_MAX_HZ = 50.0
"""PX4 SIH publishes its distance sensor at 50 Hz: a faster stream request sends no more."""

FENCE_COMMANDS = frozenset({M.MAV_CMD_NAV_FENCE_RETURN_POINT,
                            M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
                            M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION,
                            M.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION,
                            M.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION})
NAV_COMMANDS = frozenset({M.MAV_CMD_NAV_WAYPOINT, M.MAV_CMD_NAV_TAKEOFF, M.MAV_CMD_NAV_LAND,
                          M.MAV_CMD_NAV_RETURN_TO_LAUNCH, M.MAV_CMD_NAV_LOITER_UNLIM,
                          M.MAV_CMD_NAV_LOITER_TIME})


def distance_sensor_cm(true_down_m: float, cos_tilt: float, params: RangefinderParams,
                       noise: float) -> tuple[int, int, int]:
    """``(current_distance, min_distance, max_distance)`` of a DISTANCE_SENSOR message, in cm,
    as PX4 v1.16 with SIH sends them (recorded in ``px4_sitl_tlogs``): the reading of
    :func:`~eaglemission.drivers.vehicles.dynamics.rangefinder_reading_m` truncated to whole cm
    (PX4 assigns ``metres * 1e2f`` to a uint16); beyond the maximum range or with the beam at
    the horizon, :data:`DISTANCE_NO_RETURN_CM`; below the minimum (on the ground) the geometric
    range, which is outside ``[min, max]`` -- PX4 never withholds a reading, the receiver checks
    the range."""
    min_cm = int(round(params.min_range_m * 100.0))
    max_cm = int(round(params.max_range_m * 100.0))
    r = rangefinder_reading_m(true_down_m, cos_tilt, params, noise)
    if r is not None:
        return min(DISTANCE_NO_RETURN_CM - 1, max(0, int(r * 100.0))), min_cm, max_cm
    if cos_tilt <= 0.1 or -true_down_m / cos_tilt > params.max_range_m:
        return DISTANCE_NO_RETURN_CM, min_cm, max_cm
    return max(0, min(min_cm - 1, int(-true_down_m / cos_tilt * 100.0))), min_cm, max_cm


def _int(value: float, default: int = 0) -> int:
    """A MAVLink float param as an int (NaN means "not given")."""
    return int(value) if math.isfinite(value) else default


class EmulatorConfig(BaseModel):
    """Parameters of the emulated PX4 multicopter (defaults: PX4 v1.16 SITL, SIH quad)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    home_latitude_deg: Annotated[float, Field(ge=-90, le=90)] = 47.397742
    home_longitude_deg: Annotated[float, Field(ge=-180, le=180)] = 8.545594
    home_altitude_amsl_m: float = 489.4
    home_in_origin_ned_m: tuple[float, float, float] = (-0.35, 0.45, 0.0)
    """Home in the EKF-origin frame of LOCAL_POSITION_NED (PX4: decimetres apart)."""
    initial_yaw_deg: Annotated[float, Field(ge=-180, le=180)] = 0.0
    speedup: Annotated[float, Field(gt=0, le=50)] = 1.0
    heartbeat_on_change: bool = True
    """Also send HEARTBEAT at once when mode/armed change (real PX4 only sends at 1 Hz)."""
    double_set_mode_ack: bool = True
    stream_rates_hz: dict[str, float] = Field(default_factory=lambda: dict(PX4_ONBOARD_RATES_HZ))
    tick_hz: Annotated[float, Field(ge=20, le=1000)] = 200.0
    seed: int = 0
    wind_ne_mps: tuple[float, float] = (0.0, 0.0)
    battery_drain_per_s: Annotated[float, Field(ge=0, le=1)] = 0.0005
    """Battery fraction used per second of flight (emulator time)."""
    battery_full_v: Annotated[float, Field(gt=0)] = 16.8
    battery_empty_v: Annotated[float, Field(gt=0)] = 14.0
    takeoff_spool_s: Annotated[float, Field(ge=0, le=10)] = 1.0
    """Emulator seconds between the takeoff command and lift-off (PX4 SIH: about 1.8 s)."""
    landed_detect_s: Annotated[float, Field(ge=0, le=10)] = 1.0
    dynamics: DynamicsParams = Field(default_factory=DynamicsParams)
    """The vehicle model (the ``simulated`` plugin's); MPC_* parameters report its limits."""
    rangefinder: RangefinderParams = Field(default_factory=RangefinderParams)
    """A downward distance sensor (the ``simulated`` plugin's): DISTANCE_SENSOR from the TRUE
    pose, seeded noise; disabled by default (then no DISTANCE_SENSOR, as PX4 without one)."""
    params: dict[str, float] = Field(default_factory=dict)
    """Overrides of PX4 parameters (names from ``px4.DEFAULT_PARAMS``)."""
    sysid: Annotated[int, Field(ge=1, le=255)] = 1
    compid: Annotated[int, Field(ge=1, le=255)] = 1


@dataclass
class _Mission:
    items: list[Any] = field(default_factory=list)  # MAVLink MISSION_ITEM_INT messages
    current: int = 0
    reached: int = -1
    finished: bool = False
    climbing_first: bool = False


@dataclass
class _Upload:
    count: int
    mission_type: int
    partner: tuple[int, int]
    items: list[Any] = field(default_factory=list)
    last_request_wall: float = 0.0
    retries: int = 0


@dataclass(frozen=True)
class EmulatorSnapshot:
    """What the emulator is doing, for tests (truth and what it reports)."""

    sim_time_s: float
    mode: FlightMode
    armed: bool
    landed_state: int
    true_position_ned_m: tuple[float, float, float]
    estimate_position_ned_m: tuple[float, float, float]
    velocity_ned_mps: tuple[float, float, float]
    yaw_deg: float
    battery_remaining: float
    gps_ok: bool
    failsafe: bool
    gripper: str
    mission_current: int
    mission_count: int
    offboard_setpoint: tuple[float, float, float, float] | None
    true_attitude_q: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Traffic:
    """One recorded message: wall time, direction ('out' = emulator -> client), message."""

    wall_s: float
    direction: str
    msg: Any
    sim_s: float = 0.0


def parse_link(url: str) -> tuple[str, str, int]:
    """``udpin://host:port`` / ``udpout://host:port`` (also pymavlink's ``udpin:host:port``)."""
    for scheme in ("udpin", "udpout"):
        for sep in ("://", ":"):
            prefix = scheme + sep
            if url.startswith(prefix):
                host, _, port = url[len(prefix):].rpartition(":")
                if not host or not port.isdigit():
                    break
                return scheme, host, int(port)
    raise ConfigError(f"emulator link {url!r}: use udpin://HOST:PORT or udpout://HOST:PORT "
                      "(or no link and feed()/set_output() for MAVSDK's raw://)")


class _Udp:
    """One UDP socket: ``udpin`` binds and answers the last sender, ``udpout`` sends first."""

    def __init__(self, url: str) -> None:
        scheme, host, port = parse_link(url)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.settimeout(0.1)
        if scheme == "udpin":
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self.sock.bind((host, port))
            self.peer: tuple[str, int] | None = None
        else:
            self.sock.bind(("0.0.0.0", 0))
            self.peer = (host, port)
        self.fixed_peer = scheme == "udpout"

    def send(self, data: bytes) -> None:
        if self.peer is not None:
            try:
                self.sock.sendto(data, self.peer)
            except OSError as exc:  # nobody listening yet (ICMP refused): keep going
                log.debug("udp send failed: %s", exc)

    def recv(self) -> bytes | None:
        try:
            data, addr = self.sock.recvfrom(65535)
        except TimeoutError:
            return None
        except OSError:
            return None
        if not self.fixed_peer:
            self.peer = addr
        return data

    def close(self) -> None:
        self.sock.close()


class Px4Emulator:
    """PX4-like multicopter over MAVLink 2. Use as a context manager or ``start()``/``stop()``.

    Parameters
    ----------
    config : EmulatorConfig or None
        Vehicle, timing and stream parameters.
    link : str or None
        ``udpin://HOST:PORT`` / ``udpout://HOST:PORT``; None for in-process bytes
        (:meth:`feed` / :meth:`set_output`, MAVSDK ``raw://``).
    record : bool
        Keep every message in :attr:`traffic` (tests compare it with real PX4 traffic).
    """

    def __init__(self, config: EmulatorConfig | None = None, *, link: str | None = None,
                 record: bool = False) -> None:
        self.config = config or EmulatorConfig()
        cfg = self.config
        unknown = sorted(set(cfg.params) - set(px4.DEFAULT_PARAMS))
        if unknown:
            raise ConfigError(f"EmulatorConfig.params: unknown PX4 parameters {unknown}; "
                              f"known: {sorted(px4.DEFAULT_PARAMS)}")
        bad = sorted(set(cfg.stream_rates_hz) - set(PX4_ONBOARD_RATES_HZ))
        if bad:
            raise ConfigError(f"EmulatorConfig.stream_rates_hz: unknown messages {bad}")
        self.home = GeoPoint(cfg.home_latitude_deg, cfg.home_longitude_deg,
                             cfg.home_altitude_amsl_m)
        off = cfg.home_in_origin_ned_m
        self.origin = ned_to_geodetic(self.home, -off[0], -off[1], -off[2])
        self._home_local = off  # home in the EKF-origin frame
        dp = cfg.dynamics
        model_params = {"MPC_XY_CRUISE": dp.cruise_speed_mps,
                         "MPC_XY_VEL_MAX": dp.max_horizontal_speed_mps,
                         "MPC_Z_VEL_MAX_UP": dp.max_up_speed_mps,
                         "MPC_Z_VEL_MAX_DN": dp.max_down_speed_mps,
                         "MPC_Z_V_AUTO_UP": dp.max_up_speed_mps,
                         "MPC_Z_V_AUTO_DN": dp.max_down_speed_mps,
                         "MPC_TKO_SPEED": dp.takeoff_speed_mps,
                         "MPC_LAND_SPEED": dp.land_speed_mps,
                         "MPC_YAWRAUTO_MAX": dp.max_yaw_rate_degps}
        self._params: dict[str, list[float | int]] = {
            k: [cfg.params.get(k, model_params.get(k, v)), t]
            for k, (v, t) in px4.DEFAULT_PARAMS.items()
        }
        self._param_names = list(self._params)
        self._link_url = link
        self._udp: _Udp | None = None
        self._record = record
        self.traffic: list[Traffic] = []

        self._lock = threading.RLock()
        self._out_lock = threading.Lock()
        self._output: Callable[[bytes], None] | None = None
        self._inbox: queue.SimpleQueue[bytes] = queue.SimpleQueue()
        self._mav = M.MAVLink(None, srcSystem=cfg.sysid, srcComponent=cfg.compid)
        self._parser = M.MAVLink(None, srcSystem=cfg.sysid, srcComponent=cfg.compid)
        self._parser.robust_parsing = True
        self._threads: list[threading.Thread] = []
        self._stop = threading.Event()

        # Link faults (wall time).
        self._link_down_until = 0.0  # both directions
        self._uplink_down_until = 0.0  # client -> vehicle only (a client that died)
        self._delay_s = 0.0
        self._delayed_out: list[tuple[float, int, bytes]] = []
        self._delayed_in: list[tuple[float, int, bytes]] = []
        self._delay_seq = 0
        self._delay_seq_out = 0
        # feed() runs on the client's thread (MAVSDK's, for raw://): it must never wait for
        # self._lock, which the emulator thread holds while handing bytes to MAVSDK.
        self._in_lock = threading.Lock()
        self._deny: dict[int, int] = {}  # command id -> MAV_RESULT for the next one

        # Vehicle state (emulator time).
        self.dyn = MulticopterDynamics(cfg.dynamics, seed=cfg.seed, wind_ne_mps=cfg.wind_ne_mps)
        self.dyn.reset((0.0, 0.0, 0.0), cfg.initial_yaw_deg)
        self._last_cmd: tuple[Any, ...] = ()
        self._t = 0.0
        self._wall0 = 0.0
        self._last_wall = 0.0
        self.mode = FlightMode.HOLD
        self.intended_mode = FlightMode.HOLD
        self.armed = False
        self.landed_state = ON_GROUND
        self.failsafe = False
        self.manual_control = False  # a pilot with centred sticks (pilot_take_control)
        self.battery = 1.0
        self._drain_per_s = cfg.battery_drain_per_s
        self._battery_warned = 0
        self._gps_lost_until = -1.0
        self._gps_lost_since: float | None = None
        self.gripper = "unknown"
        self._sp: tuple[float, float, float, float, float, float, int] | None = None
        self._sp_time = -math.inf
        self._sp_wall = -math.inf
        self._last_gcs_hb = -math.inf
        self._gcs_lost = False
        self._mission = _Mission()
        self._upload: _Upload | None = None
        self._target: tuple[float, float, float] | None = None  # hold / reposition target (home NED)
        self._target_yaw: float | None = None
        self._speed_mps: float | None = None
        self._phase_t = 0.0  # emulator time the current phase started
        self._rtl_phase = ""
        self._rtl_alt = 0.0
        self._takeoff_announced = False
        self._climb_ne: tuple[float, float] | None = None
        self._gcs_hb_wall = -math.inf
        self._on_ground_since: float | None = 0.0
        self._statustext_id = 0
        self.fence_items: list[Any] = []  # the uploaded geofence (MISSION_ITEM_INT, FENCE)
        self._intervals: dict[str, float] = {
            name: (1.0 / hz if hz > 0 else math.inf) for name, hz in
            {**PX4_ONBOARD_RATES_HZ, **cfg.stream_rates_hz}.items()
        }
        self._next_due: dict[str, float] = {}
        self._last_sent: dict[str, float] = {}
        self._last_reached_send = -math.inf
        self._hb_dirty = False
        self._rangefinder_noise = _Normals(np.random.default_rng(
            np.random.SeedSequence([cfg.seed, 0x52F])))  # the simulated vehicle's stream
        self._rangefinder_lost_until = -1.0

    # ------------------------------------------------------------------ lifecycle
    def __enter__(self) -> Px4Emulator:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def start(self) -> None:
        """Open the link (if any) and start the emulator thread(s)."""
        if self._threads:
            return
        if self._link_url is not None:
            self._udp = _Udp(self._link_url)
            self.set_output(self._udp.send)
            t = threading.Thread(target=self._udp_reader, name="px4emu-udp", daemon=True)
            self._threads.append(t)
        self._wall0 = self._last_wall = time.monotonic()
        self._threads.append(threading.Thread(target=self._run, name="px4emu", daemon=True))
        for t in self._threads:
            t.start()

    def stop(self, timeout_s: float = 2.0) -> None:
        """Stop the threads and close the link. Idempotent."""
        self._stop.set()
        for t in self._threads:
            t.join(timeout_s)
        self._threads = []
        self.set_output(None)
        if self._udp is not None:
            self._udp.close()
            self._udp = None

    # ------------------------------------------------------------------ raw transport
    def set_output(self, fn: Callable[[bytes], None] | None) -> None:
        """Where outgoing bytes go (raw mode). Once this returns with None, nothing is sent."""
        with self._out_lock:
            self._output = fn
        if fn is not None:
            self._hb_dirty = True  # the link came up: announce ourselves at once

    def feed(self, data: bytes) -> None:
        """Bytes from the client (any thread)."""
        now = time.monotonic()
        if now < self._link_down_until or now < self._uplink_down_until:
            return
        if self._delay_s > 0:
            with self._in_lock:
                self._delay_seq += 1
                heapq.heappush(self._delayed_in, (now + self._delay_s, self._delay_seq, data))
            return
        self._inbox.put(data)

    # ------------------------------------------------------------------ fault injection
    def inject_link_loss(self, duration_s: float, *, direction: str = "both") -> None:
        """Drop packets for ``duration_s`` wall seconds: ``both`` directions, or only the
        ``uplink`` (client -> vehicle: a client process that died, as in recorded scenario b)."""
        until = time.monotonic() + float(duration_s)
        if direction == "both":
            self._link_down_until = until
        elif direction == "uplink":
            self._uplink_down_until = until
        else:
            raise ValueError(f"direction: 'both' or 'uplink', got {direction!r}")

    def set_link_delay(self, delay_s: float) -> None:
        """Delay every packet in both directions by ``delay_s`` wall seconds (0 = off)."""
        self._delay_s = max(0.0, float(delay_s))

    def deny_next_command(self, command: int | str,
                          result: int = M.MAV_RESULT_DENIED) -> None:
        """Answer the next COMMAND_LONG/INT with this id (or MAV_CMD name) with ``result``."""
        cid = command if isinstance(command, int) else getattr(M, command if command.startswith(
            "MAV_CMD_") else "MAV_CMD_" + command.upper())
        with self._lock:
            self._deny[int(cid)] = int(result)

    def inject_gps_loss(self, duration_s: float) -> None:
        """No GPS fix for ``duration_s`` emulator seconds (PX4 then lands if flying)."""
        with self._lock:
            self._gps_lost_until = self._t + float(duration_s)

    def inject_rangefinder_loss(self, duration_s: float) -> None:
        """The distance sensor stops publishing for ``duration_s`` emulator seconds (PX4 then
        sends no DISTANCE_SENSOR: its stream only forwards new samples)."""
        with self._lock:
            self._rangefinder_lost_until = self._t + float(duration_s)

    def set_battery_fraction(self, fraction: float) -> None:
        """Set the remaining battery (0..1); crossing BAT_*_THR warns / acts as PX4 does."""
        with self._lock:
            self.battery = min(1.0, max(0.0, float(fraction)))

    def set_battery_drain(self, per_s: float) -> None:
        """Battery fraction used per emulator second of flight (drain it fast in a test)."""
        if not per_s >= 0:
            raise ValueError(f"per_s: must be >= 0, got {per_s}")
        with self._lock:
            self._drain_per_s = float(per_s)

    def pilot_take_control(self, mode: FlightMode | str = FlightMode.POSCTL) -> None:
        """A pilot (RC sticks centred) or ground station switches the mode."""
        with self._lock:
            m = FlightMode(mode)
            self.manual_control = m in px4.MANUAL_MODES
            self._set_mode(m, reason="pilot")
            if m in (FlightMode.HOLD, FlightMode.POSCTL, FlightMode.ALTCTL):
                self._hold_here()

    def set_param(self, name: str, value: float) -> None:
        with self._lock:
            self._params[name][0] = value

    def param(self, name: str) -> float:
        return float(self._params[name][0])

    # ------------------------------------------------------------------ observation
    def snapshot(self) -> EmulatorSnapshot:
        with self._lock:
            s = self.dyn.truth()
            e = self.dyn.estimate()
            sp = None if self._sp is None else (self._sp[0], self._sp[1], self._sp[2], self._sp[3])
            return EmulatorSnapshot(
                sim_time_s=self._t, mode=self.mode, armed=self.armed,
                landed_state=self.landed_state, true_position_ned_m=s.position_ned_m,
                estimate_position_ned_m=e.position_ned_m, velocity_ned_mps=e.velocity_ned_mps,
                yaw_deg=e.yaw_deg, battery_remaining=self.battery, gps_ok=self._gps_ok(),
                failsafe=self.failsafe, gripper=self.gripper,
                mission_current=self._mission.current, mission_count=len(self._mission.items),
                offboard_setpoint=sp, true_attitude_q=s.attitude_q)

    @property
    def sim_time_s(self) -> float:
        return self._t

    def received(self, msg_type: str) -> list[Any]:
        """Recorded messages of a type from the client (``record=True``)."""
        return [t.msg for t in list(self.traffic) if t.direction == "in"
                and t.msg.get_type() == msg_type]

    def sent(self, msg_type: str) -> list[Traffic]:
        return [t for t in list(self.traffic) if t.direction == "out"
                and t.msg.get_type() == msg_type]

    # ------------------------------------------------------------------ threads
    def _udp_reader(self) -> None:
        assert self._udp is not None
        while not self._stop.is_set():
            data = self._udp.recv() if self._udp is not None else None
            if data:
                self.feed(data)

    def _run(self) -> None:
        period = 1.0 / self.config.tick_hz
        next_tick = time.monotonic()
        while not self._stop.is_set():
            try:
                self._tick()
            except Exception:  # keep the vehicle alive: a bug must not look like a link loss
                log.exception("emulator tick failed")
            next_tick += period
            now = time.monotonic()
            if next_tick < now - 0.1:
                next_tick = now  # we fell behind (busy machine): do not try to catch up
            wait = max(0.0, next_tick - now)
            try:
                data = self._inbox.get(timeout=wait) if wait > 0 else self._inbox.get_nowait()
            except queue.Empty:
                continue
            with self._lock:
                self._handle_bytes(data)

    def _tick(self) -> None:
        wall = time.monotonic()
        with self._lock:
            while not self._inbox.empty():
                self._handle_bytes(self._inbox.get_nowait())
            while True:
                with self._in_lock:
                    if not (self._delayed_in and self._delayed_in[0][0] <= wall):
                        break
                    data = heapq.heappop(self._delayed_in)[2]
                self._handle_bytes(data)
            dt = max(0.0, wall - self._last_wall) * self.config.speedup
            self._last_wall = wall
            self._advance(min(dt, 0.5))
            self._streams(wall)
            self._upload_retry(wall)
        with self._out_lock:
            while self._delayed_out and self._delayed_out[0][0] <= wall:
                data = heapq.heappop(self._delayed_out)[2]
                if self._output is not None and wall >= self._link_down_until:
                    self._output(data)

    # ------------------------------------------------------------------ sending
    def _emit(self, msg: Any) -> None:
        data = msg.pack(self._mav)
        self._mav.seq = (self._mav.seq + 1) % 256
        now = time.monotonic()
        if self._record:
            self.traffic.append(Traffic(now, "out", msg, self._t))
        if now < self._link_down_until:
            return
        with self._out_lock:
            if self._delay_s > 0:
                self._delay_seq_out += 1
                heapq.heappush(self._delayed_out, (now + self._delay_s, self._delay_seq_out, data))
            elif self._output is not None:
                self._output(data)

    def _boot_ms(self) -> int:
        return int(self._t * 1000) & 0xFFFFFFFF

    def _statustext(self, text: str, severity: int = M.MAV_SEVERITY_INFO) -> None:
        """STATUSTEXT as PX4 sends it: tab-terminated, split into 50-character chunks."""
        log.info("emulator: %s", text)
        if time.monotonic() - self._gcs_hb_wall > 2.5:
            return  # PX4 sends STATUSTEXT on a link only while a GCS heartbeat is fresh
        body = (text + "\t").encode()
        self._statustext_id = (self._statustext_id + 1) % 65536
        chunks = [body[i:i + 50] for i in range(0, len(body), 50)] or [b""]
        for n, chunk in enumerate(chunks):
            self._emit(M.MAVLink_statustext_message(severity, chunk, self._statustext_id, n))

    # ------------------------------------------------------------------ streams
    def _streams(self, wall: float) -> None:
        if self._hb_dirty and self.config.heartbeat_on_change:
            self._hb_dirty = False
            self._send("HEARTBEAT")
            self._next_due["HEARTBEAT"] = wall + self._intervals["HEARTBEAT"]
        for name, interval in self._intervals.items():
            if not math.isfinite(interval):
                continue
            due = self._next_due.get(name)
            if due is None:
                self._next_due[name] = wall + (interval if name != "HEARTBEAT" else 0.0)
                continue
            if wall >= due:
                self._send(name)
                self._last_sent[name] = wall
                nxt = due + interval
                self._next_due[name] = nxt if nxt > wall else wall + interval
        if (self.mode == FlightMode.MISSION and self._mission.reached >= 0
                and wall - self._last_reached_send >= 1.0):
            self._last_reached_send = wall
            self._emit(M.MAVLink_mission_item_reached_message(self._mission.reached))

    def _system_status(self) -> int:
        if self.failsafe:
            return M.MAV_STATE_CRITICAL
        if self.armed:
            return M.MAV_STATE_ACTIVE
        # Recorded: STANDBY only when the pre-flight checks pass; UNINIT after the failsafe
        # landing of scenario b (mode OFFBOARD without an offboard signal).
        ready = self._armable() and (self.mode != FlightMode.OFFBOARD or self._offboard_signal())
        return M.MAV_STATE_STANDBY if ready else M.MAV_STATE_UNINIT

    def _send(self, name: str) -> None:  # noqa: C901 - one branch per message, flat is clearer
        est = self.dyn.estimate()
        n, e, d = est.position_ned_m
        vn, ve, vd = est.velocity_ned_mps
        geo = ned_to_geodetic(self.home, n, e, d)
        hl = self._home_local
        t_ms = self._boot_ms()
        if name == "HEARTBEAT":
            msg = M.MAVLink_heartbeat_message(
                M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4, px4.base_mode(self.mode, self.armed),
                px4.custom_mode(self.mode), self._system_status(), 3)
        elif name == "ATTITUDE":
            r, p, y = (math.radians(a) for a in R_to_euler(quat_to_R(est.attitude_q)))
            msg = M.MAVLink_attitude_message(t_ms, r, p, y, 0.0, 0.0,
                                             math.radians(est.yaw_rate_degps))
        elif name == "ATTITUDE_QUATERNION":
            q = est.attitude_q
            msg = M.MAVLink_attitude_quaternion_message(t_ms, *q, 0.0, 0.0,
                                                        math.radians(est.yaw_rate_degps),
                                                        [0.0, 0.0, 0.0, 0.0])
        elif name == "GLOBAL_POSITION_INT":
            hdg = int(round((est.yaw_deg % 360.0) * 100)) % 36000
            msg = M.MAVLink_global_position_int_message(
                t_ms, int(round(geo.latitude_deg * 1e7)), int(round(geo.longitude_deg * 1e7)),
                int(round(geo.altitude_amsl_m * 1000)), int(round(-d * 1000)),
                int(round(vn * 100)), int(round(ve * 100)), int(round(vd * 100)), hdg)
        elif name == "LOCAL_POSITION_NED":
            msg = M.MAVLink_local_position_ned_message(t_ms, n + hl[0], e + hl[1], d + hl[2],
                                                       vn, ve, vd)
        elif name == "GPS_RAW_INT":
            tr = self.dyn.truth()
            tg = ned_to_geodetic(self.home, *tr.position_ned_m)
            ok = self._gps_ok()
            speed = math.hypot(vn, ve)
            cog = int(round((math.degrees(math.atan2(ve, vn)) % 360) * 100)) if speed > 0.1 else 65535
            msg = M.MAVLink_gps_raw_int_message(
                int(self._t * 1e6), 3 if ok else 1, int(round(tg.latitude_deg * 1e7)),
                int(round(tg.longitude_deg * 1e7)), int(round(tg.altitude_amsl_m * 1000)),
                80 if ok else 9999, 120 if ok else 9999, int(round(speed * 100)), cog,
                12 if ok else 3)
        elif name == "SYS_STATUS":
            health = SENSORS | (GPS_BIT if self._gps_ok() else 0) | (
                PREARM_BIT if self._armable() else 0)
            msg = M.MAVLink_sys_status_message(
                SENSORS | GPS_BIT | PREARM_BIT, SENSORS | GPS_BIT | PREARM_BIT, health, 250,
                int(self._voltage() * 1000), -1, int(round(self.battery * 100)), 0, 0, 0, 0, 0, 0)
        elif name == "EXTENDED_SYS_STATE":
            msg = M.MAVLink_extended_sys_state_message(M.MAV_VTOL_STATE_UNDEFINED, self.landed_state)
        elif name == "BATTERY_STATUS":
            volts = [int(self._voltage() * 1000)] + [65535] * 9
            msg = M.MAVLink_battery_status_message(
                0, M.MAV_BATTERY_FUNCTION_ALL, M.MAV_BATTERY_TYPE_LIPO, 2500, volts,
                1000 if self.armed else 50, -1, -1, int(round(self.battery * 100)))
        elif name == "HOME_POSITION":
            msg = M.MAVLink_home_position_message(
                int(round(self.home.latitude_deg * 1e7)), int(round(self.home.longitude_deg * 1e7)),
                int(round(self.home.altitude_amsl_m * 1000)), hl[0], hl[1], hl[2],
                [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, int(self._t * 1e6))
        elif name == "GPS_GLOBAL_ORIGIN":
            msg = M.MAVLink_gps_global_origin_message(
                int(round(self.origin.latitude_deg * 1e7)), int(round(self.origin.longitude_deg * 1e7)),
                int(round(self.origin.altitude_amsl_m * 1000)), int(self._t * 1e6))
        elif name == "MISSION_CURRENT":
            total = len(self._mission.items) if self._mission.items else 65535
            msg = M.MAVLink_mission_current_message(self._mission.current, total, 0, 0)
        elif name == "CURRENT_MODE":
            msg = M.MAVLink_current_mode_message(0, px4.custom_mode(self.mode),
                                                 px4.custom_mode(self.intended_mode))
        elif name == "DISTANCE_SENSOR":
            rf = self.config.rangefinder
            if not rf.enabled or self._t < self._rangefinder_lost_until:
                return  # PX4 streams DISTANCE_SENSOR only while a sensor publishes
            tr = self.dyn.truth()
            cur, lo, hi = distance_sensor_cm(tr.position_ned_m[2],
                                             down_axis_cos_tilt(tr.attitude_q), rf,
                                             self._rangefinder_noise.next())
            # Recorded PX4 v1.16 SIH: type LASER (0), id 0, orientation PITCH_270 (downward),
            # covariance 0 (SIH's variance is 0: unknown), signal_quality 0 (SIH's -1: unknown),
            # no FOV, quaternion zeros.
            msg = M.MAVLink_distance_sensor_message(
                t_ms, lo, hi, cur, M.MAV_DISTANCE_SENSOR_LASER, 0,
                M.MAV_SENSOR_ROTATION_PITCH_270, 0, 0.0, 0.0, [0.0, 0.0, 0.0, 0.0], 0)
        elif name == "HIL_STATE_QUATERNION":
            # The simulator's ground truth as PX4 SIH fills it (README of the tlogs, "Ground
            # truth"): time_usec 0, true attitude, body rates, position (degE7, mm AMSL),
            # NED velocity (cm/s), airspeeds 0, true NED acceleration truncated to m/s^2.
            tr = self.dyn.truth()
            tg = ned_to_geodetic(self.home, *tr.position_ned_m)
            tv = tr.velocity_ned_mps
            acc = tr.acceleration_ned_mps2
            msg = M.MAVLink_hil_state_quaternion_message(
                0, list(tr.attitude_q), 0.0, 0.0, math.radians(tr.yaw_rate_degps),
                int(round(tg.latitude_deg * 1e7)), int(round(tg.longitude_deg * 1e7)),
                int(round(tg.altitude_amsl_m * 1000)), int(round(tv[0] * 100)),
                int(round(tv[1] * 100)), int(round(tv[2] * 100)), 0, 0,
                int(acc[0]), int(acc[1]), int(acc[2]))
        elif name == "AUTOPILOT_VERSION":
            caps = (M.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT | M.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
                    | M.MAV_PROTOCOL_CAPABILITY_MISSION_INT | M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                    | M.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
                    | M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
                    | M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT
                    | M.MAV_PROTOCOL_CAPABILITY_MAVLINK2)
            msg = M.MAVLink_autopilot_version_message(
                caps, 0x011000FF, 0, 0, 0, [0x65, 0x6D, 0x75, 0, 0, 0, 0, 0], [0] * 8, [0] * 8,
                0, 0, 0x4541474C45, [0] * 18)
        else:
            return
        self._emit(msg)

    # ------------------------------------------------------------------ receiving
    def _handle_bytes(self, data: bytes) -> None:
        try:
            msgs = self._parser.parse_buffer(data) or []
        except M.MAVError as exc:
            log.debug("bad packet: %s", exc)
            return
        for msg in msgs:
            if msg.get_type() == "BAD_DATA":
                continue
            if self._record:
                self.traffic.append(Traffic(time.monotonic(), "in", msg, self._t))
            try:
                self._handle(msg)
            except Exception:
                log.exception("emulator: cannot handle %s", msg)

    def _for_me(self, msg: Any) -> bool:
        ts = getattr(msg, "target_system", 0)
        tc = getattr(msg, "target_component", 0)
        return ts in (0, self.config.sysid) and tc in (0, self.config.compid)

    def _handle(self, msg: Any) -> None:
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            if msg.type == M.MAV_TYPE_GCS:  # PX4 counts GCS heartbeats only
                self._gcs_hb_wall = time.monotonic()
                self._last_gcs_hb = self._t
                if self._gcs_lost:
                    self._gcs_lost = False
                    self._statustext("Data link regained")
            return
        if kind == "PING":
            if msg.target_system == 0:
                self._emit(M.MAVLink_ping_message(msg.time_usec, msg.seq, msg.get_srcSystem(),
                                                  msg.get_srcComponent()))
            return
        if not self._for_me(msg):
            return
        handler = getattr(self, "_on_" + kind.lower(), None)
        if handler is not None:
            handler(msg)

    # -- commands
    def _ack(self, msg: Any, command: int, result: int) -> None:
        ack = M.MAVLink_command_ack_message(command, result, 0, 0, msg.get_srcSystem(),
                                            msg.get_srcComponent())
        self._emit(ack)

    def _on_command_long(self, msg: Any) -> None:
        self._command(msg, msg.command, [msg.param1, msg.param2, msg.param3, msg.param4,
                                         msg.param5, msg.param6, msg.param7], frame=None)

    def _on_command_int(self, msg: Any) -> None:
        self._command(msg, msg.command, [msg.param1, msg.param2, msg.param3, msg.param4,
                                         msg.x, msg.y, msg.z], frame=msg.frame)

    def _command(self, msg: Any, cmd: int, p: list[float], frame: int | None) -> None:
        denied = self._deny.pop(cmd, None)
        if denied is not None:
            self._ack(msg, cmd, denied)
            return
        handler = _COMMANDS.get(cmd)
        if handler is None:
            self._ack(msg, cmd, M.MAV_RESULT_UNSUPPORTED)
            return
        try:
            result = handler(self, msg, p, frame)
        except Exception:  # PX4 answers every command: a bug here must not look like a TIMEOUT
            log.exception("emulator: command %d failed", cmd)
            result = M.MAV_RESULT_FAILED
        self._ack(msg, cmd, result)
        if cmd == M.MAV_CMD_DO_SET_MODE and self.config.double_set_mode_ack:
            self._ack(msg, cmd, result)  # PX4 v1.16 acknowledges DO_SET_MODE twice
        if result == M.MAV_RESULT_ACCEPTED and cmd == M.MAV_CMD_REQUEST_MESSAGE:
            self._send(MSG_NAMES.get(_int(p[0], -1), ""))

    def _cmd_arm(self, msg: Any, p: list[float], frame: int | None) -> int:
        force = _int(p[1]) == 21196
        if p[0] >= 0.5:
            if self.armed:
                return M.MAV_RESULT_ACCEPTED
            if not force and not self._armable():
                self._statustext("Arming denied: preflight checks failed", M.MAV_SEVERITY_CRITICAL)
                return M.MAV_RESULT_TEMPORARILY_REJECTED
            self._arm()
            self._statustext("Armed by external command")
            return M.MAV_RESULT_ACCEPTED
        if not self.armed:
            return M.MAV_RESULT_ACCEPTED
        if self.landed_state != ON_GROUND and not force:
            self._statustext("Disarming denied: not landed", M.MAV_SEVERITY_CRITICAL)
            return M.MAV_RESULT_DENIED
        self._disarm("Disarmed by external command")
        return M.MAV_RESULT_ACCEPTED

    def _cmd_takeoff(self, msg: Any, p: list[float], frame: int | None) -> int:
        if not self.armed:
            self._statustext("Takeoff denied! Please arm first", M.MAV_SEVERITY_CRITICAL)
            return M.MAV_RESULT_DENIED
        if not self._gps_ok():
            return M.MAV_RESULT_DENIED
        if math.isfinite(p[6]):
            alt = p[6] - self.home.altitude_amsl_m  # NAV_TAKEOFF param7 is AMSL
        else:
            alt = self.param("MIS_TAKEOFF_ALT")
            self._statustext(f"Using default takeoff altitude: {alt:.1f} m")
        n, e, _ = self.dyn.estimate().position_ned_m
        self._target = (n, e, -max(alt, 0.5))
        self._target_yaw = None
        self._set_mode(FlightMode.TAKEOFF)
        self._phase_t = self._t
        return M.MAV_RESULT_ACCEPTED

    def _cmd_land(self, msg: Any, p: list[float], frame: int | None) -> int:
        if not self.armed:
            return M.MAV_RESULT_DENIED
        self._set_mode(FlightMode.LAND)
        self._statustext("Landing at current position")
        return M.MAV_RESULT_ACCEPTED

    def _cmd_rtl(self, msg: Any, p: list[float], frame: int | None) -> int:
        if not self.armed:
            return M.MAV_RESULT_DENIED
        self._start_rtl()
        return M.MAV_RESULT_ACCEPTED

    def _cmd_set_mode(self, msg: Any, p: list[float], frame: int | None) -> int:
        if not (_int(p[0]) & px4.FLAG_CUSTOM_MODE):
            return M.MAV_RESULT_UNSUPPORTED
        main, sub = _int(p[1]), _int(p[2]) if _int(p[1]) == px4.MAIN_AUTO else 0
        mode = px4.PX4_TO_MODE.get((main, sub))
        if mode is None:
            return M.MAV_RESULT_UNSUPPORTED
        if mode == FlightMode.OFFBOARD and not self._offboard_signal():
            self._statustext("Switching to Offboard is currently not available",
                             M.MAV_SEVERITY_CRITICAL)
            return M.MAV_RESULT_TEMPORARILY_REJECTED
        if mode == FlightMode.MISSION and not self._mission.items:
            self._statustext("Switching to Mission is currently not available",
                             M.MAV_SEVERITY_CRITICAL)
            return M.MAV_RESULT_TEMPORARILY_REJECTED
        if mode in (FlightMode.TAKEOFF, FlightMode.LAND, FlightMode.RETURN_TO_LAUNCH) and not self.armed:
            return M.MAV_RESULT_TEMPORARILY_REJECTED
        if mode in (FlightMode.HOLD, FlightMode.POSCTL, FlightMode.ALTCTL) or mode in px4.MANUAL_MODES:
            self._hold_here()
        if mode == FlightMode.RETURN_TO_LAUNCH:
            self._start_rtl()
            return M.MAV_RESULT_ACCEPTED
        if mode == FlightMode.MISSION:
            self._start_mission()
        if mode == FlightMode.OFFBOARD:
            self.failsafe = False
        self.manual_control = False
        self._set_mode(mode)
        return M.MAV_RESULT_ACCEPTED

    def _cmd_reposition(self, msg: Any, p: list[float], frame: int | None) -> int:
        if not self.armed or self.landed_state == ON_GROUND:
            return M.MAV_RESULT_DENIED
        if frame is None:  # COMMAND_LONG: degrees in params 5/6
            lat, lon, alt = p[4], p[5], p[6]
            frame = M.MAV_FRAME_GLOBAL
        else:
            lat, lon, alt = p[4] / 1e7, p[5] / 1e7, p[6]
        if frame in (M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT):
            alt = self.home.altitude_amsl_m + alt
        if not (math.isfinite(lat) and math.isfinite(lon)):
            n, e, _ = self.dyn.estimate().position_ned_m
        else:
            n, e, _ = geodetic_to_ned(self.home, GeoPoint(lat, lon, alt))
        d = (self.home.altitude_amsl_m - alt if math.isfinite(alt)
             else self.dyn.estimate().position_ned_m[2])
        self._target = (n, e, d)
        self._target_yaw = math.degrees(p[3]) if math.isfinite(p[3]) else None
        self._speed_mps = p[0] if p[0] > 0 else None
        self.manual_control = False
        self._set_mode(FlightMode.HOLD)
        return M.MAV_RESULT_ACCEPTED

    def _cmd_gripper(self, msg: Any, p: list[float], frame: int | None) -> int:
        action = _int(p[1], -1)
        if action not in (M.GRIPPER_ACTION_RELEASE, M.GRIPPER_ACTION_GRAB):
            return M.MAV_RESULT_DENIED
        self.gripper = "grab" if action == M.GRIPPER_ACTION_GRAB else "release"
        self._statustext(f"Gripper {self.gripper}")
        return M.MAV_RESULT_ACCEPTED

    def _cmd_interval(self, msg: Any, p: list[float], frame: int | None) -> int:
        name = MSG_NAMES.get(_int(p[0], -1))
        if name is None or name not in self._intervals:
            return M.MAV_RESULT_DENIED
        interval_us = p[1]
        if not math.isfinite(interval_us):
            return M.MAV_RESULT_DENIED
        if interval_us == -1:
            self._intervals[name] = math.inf
        elif interval_us == 0:
            hz = PX4_ONBOARD_RATES_HZ[name] or HIL_STATE_DEFAULT_HZ
            self._intervals[name] = 1.0 / hz
        elif interval_us > 0:
            self._intervals[name] = max(interval_us * 1e-6, 1.0 / 250.0)
        else:
            return M.MAV_RESULT_DENIED
        if name == "DISTANCE_SENSOR":  # PX4 streams a sensor sample once: no faster than it
            self._intervals[name] = max(self._intervals[name], 1.0 / DISTANCE_SENSOR_MAX_HZ)
        # PX4 sends a stream once the new interval has elapsed since its last message, so a
        # faster rate takes effect at once.
        if math.isfinite(self._intervals[name]):
            last = self._last_sent.get(name)
            self._next_due[name] = (time.monotonic() if last is None
                                    else last + self._intervals[name])
        return M.MAV_RESULT_ACCEPTED

    def _cmd_request(self, msg: Any, p: list[float], frame: int | None) -> int:
        return M.MAV_RESULT_ACCEPTED if _int(p[0], -1) in MSG_NAMES else M.MAV_RESULT_DENIED

    def _cmd_change_speed(self, msg: Any, p: list[float], frame: int | None) -> int:
        self._speed_mps = p[1] if p[1] > 0 else None
        return M.MAV_RESULT_ACCEPTED

    def _cmd_mission_start(self, msg: Any, p: list[float], frame: int | None) -> int:
        if not self._mission.items:
            return M.MAV_RESULT_DENIED
        self._start_mission(first=_int(p[0]))
        self._set_mode(FlightMode.MISSION)
        return M.MAV_RESULT_ACCEPTED

    def _cmd_set_home(self, msg: Any, p: list[float], frame: int | None) -> int:
        return M.MAV_RESULT_ACCEPTED  # home stays where the world is: accepted, ignored

    # -- offboard
    def _on_set_position_target_local_ned(self, msg: Any) -> None:
        if msg.coordinate_frame not in (M.MAV_FRAME_LOCAL_NED,):
            return
        hl = self._home_local
        mask = msg.type_mask
        yaw = None if mask & M.POSITION_TARGET_TYPEMASK_YAW_IGNORE else math.degrees(msg.yaw)
        if not mask & (M.POSITION_TARGET_TYPEMASK_X_IGNORE | M.POSITION_TARGET_TYPEMASK_Y_IGNORE
                       | M.POSITION_TARGET_TYPEMASK_Z_IGNORE):
            self._sp = (msg.x - hl[0], msg.y - hl[1], msg.z - hl[2],
                        math.nan if yaw is None else yaw, 0.0, 0.0, 0)
        elif not mask & (M.POSITION_TARGET_TYPEMASK_VX_IGNORE | M.POSITION_TARGET_TYPEMASK_VY_IGNORE
                         | M.POSITION_TARGET_TYPEMASK_VZ_IGNORE):
            self._sp = (msg.vx, msg.vy, msg.vz, math.nan if yaw is None else yaw, 0.0, 0.0, 1)
        else:
            return
        self._sp_time = self._t
        self._sp_wall = time.monotonic()

    def _offboard_signal(self) -> bool:
        """PX4's offboard signal: a setpoint within COM_OF_LOSS_T (emulator time). With a
        speed-up, MAVSDK's 20 Hz re-sending (wall time) is also given 3 periods of wall time,
        so a high speed-up cannot fake a loss between two setpoints."""
        if self._sp is None:
            return False
        if self._t - self._sp_time <= self.param("COM_OF_LOSS_T"):
            return True
        return time.monotonic() - self._sp_wall <= 0.15

    # -- parameters
    def _param_value(self, name: str) -> Any:
        value, ptype = self._params[name]
        return M.MAVLink_param_value_message(name.encode(), px4.encode_param(float(value), int(ptype)),
                                             int(ptype), len(self._params),
                                             self._param_names.index(name))

    @staticmethod
    def _param_id(raw: Any) -> str:
        s = raw.decode(errors="ignore") if isinstance(raw, bytes) else str(raw)
        return s.split("\x00", 1)[0]

    def _on_param_set(self, msg: Any) -> None:
        name = self._param_id(msg.param_id)
        if name not in self._params:
            log.info("emulator: PARAM_SET of unknown parameter %s ignored", name)
            return
        ptype = int(self._params[name][1])
        self._params[name][0] = px4.decode_param(msg.param_value, ptype)
        self._emit(self._param_value(name))
        self._emit(self._param_value(name))  # PX4 answers PARAM_SET twice

    def _on_param_request_read(self, msg: Any) -> None:
        name = self._param_id(msg.param_id)
        if msg.param_index >= 0 and msg.param_index < len(self._param_names) and not name:
            name = self._param_names[msg.param_index]
        if name in self._params:
            self._emit(self._param_value(name))

    def _on_param_request_list(self, msg: Any) -> None:
        for name in self._param_names:
            self._emit(self._param_value(name))

    # -- mission protocol
    def _mission_ack(self, partner: tuple[int, int], result: int, mission_type: int) -> None:
        self._emit(M.MAVLink_mission_ack_message(partner[0], partner[1], result, mission_type))

    def _on_mission_count(self, msg: Any) -> None:
        partner = (msg.get_srcSystem(), msg.get_srcComponent())
        if msg.mission_type == M.MAV_MISSION_TYPE_FENCE:
            if msg.count == 0:
                self.fence_items = []
                self._mission_ack(partner, M.MAV_MISSION_ACCEPTED, msg.mission_type)
                return
            self._upload = _Upload(msg.count, msg.mission_type, partner)  # item by item, as PX4
            self._request_next(time.monotonic())
            return
        if msg.mission_type != M.MAV_MISSION_TYPE_MISSION:
            self._mission_ack(partner, M.MAV_MISSION_ACCEPTED, msg.mission_type)
            return
        if self.mode == FlightMode.MISSION and self.armed and self.landed_state != ON_GROUND:
            self._mission_ack(partner, M.MAV_MISSION_DENIED, msg.mission_type)
            return
        if msg.count == 0:
            self._mission = _Mission()
            self._mission_ack(partner, M.MAV_MISSION_ACCEPTED, msg.mission_type)
            return
        self._upload = _Upload(msg.count, msg.mission_type, partner)
        self._request_next(time.monotonic())

    def _request_next(self, wall: float) -> None:
        up = self._upload
        assert up is not None
        up.last_request_wall = wall
        self._emit(M.MAVLink_mission_request_int_message(up.partner[0], up.partner[1],
                                                         len(up.items), up.mission_type))

    def _upload_retry(self, wall: float) -> None:
        up = self._upload
        if up is None or wall - up.last_request_wall < 0.25:
            return
        up.retries += 1
        if up.retries > 8:
            self._mission_ack(up.partner, M.MAV_MISSION_OPERATION_CANCELLED, up.mission_type)
            self._upload = None
            return
        self._request_next(wall)

    def _on_mission_item_int(self, msg: Any) -> None:
        up = self._upload
        if up is None or msg.mission_type != up.mission_type:
            return
        if msg.seq != len(up.items):
            return  # duplicate or out of order: the retry timer asks again
        up.items.append(msg)
        up.retries = 0
        if len(up.items) < up.count:
            self._request_next(time.monotonic())
            return
        if up.mission_type == M.MAV_MISSION_TYPE_FENCE:
            ok = all(item.command in FENCE_COMMANDS for item in up.items)
            if ok:
                self.fence_items = list(up.items)
                self._statustext("Geofence uploaded")
            self._upload = None
            self._mission_ack(up.partner, M.MAV_MISSION_ACCEPTED if ok else
                              M.MAV_MISSION_UNSUPPORTED, M.MAV_MISSION_TYPE_FENCE)
            return
        for item in up.items:
            if item.command not in NAV_COMMANDS and item.command not in _MISSION_DO:
                self._mission_ack(up.partner, M.MAV_MISSION_UNSUPPORTED, up.mission_type)
                self._upload = None
                return
        self._mission = _Mission(items=list(up.items))
        self._upload = None
        self._mission_ack(up.partner, M.MAV_MISSION_ACCEPTED, M.MAV_MISSION_TYPE_MISSION)
        self._send("MISSION_CURRENT")

    def _on_mission_request_list(self, msg: Any) -> None:
        count = (len(self._mission.items) if msg.mission_type == M.MAV_MISSION_TYPE_MISSION
                 else len(self.fence_items) if msg.mission_type == M.MAV_MISSION_TYPE_FENCE
                 else 0)
        self._emit(M.MAVLink_mission_count_message(msg.get_srcSystem(), msg.get_srcComponent(),
                                                   count, msg.mission_type))

    def _on_mission_request_int(self, msg: Any) -> None:
        if msg.mission_type == M.MAV_MISSION_TYPE_FENCE and msg.seq < len(self.fence_items):
            it = self.fence_items[msg.seq]
            self._emit(M.MAVLink_mission_item_int_message(
                msg.get_srcSystem(), msg.get_srcComponent(), it.seq, it.frame, it.command, 0,
                it.autocontinue, it.param1, it.param2, it.param3, it.param4, it.x, it.y, it.z,
                it.mission_type))
            return
        if msg.mission_type != M.MAV_MISSION_TYPE_MISSION or msg.seq >= len(self._mission.items):
            self._mission_ack((msg.get_srcSystem(), msg.get_srcComponent()),
                              M.MAV_MISSION_INVALID_SEQUENCE, msg.mission_type)
            return
        it = self._mission.items[msg.seq]
        self._emit(M.MAVLink_mission_item_int_message(
            msg.get_srcSystem(), msg.get_srcComponent(), it.seq, it.frame, it.command,
            int(it.seq == self._mission.current), it.autocontinue, it.param1, it.param2, it.param3,
            it.param4, it.x, it.y, it.z, it.mission_type))

    _on_mission_request = _on_mission_request_int

    def _on_mission_clear_all(self, msg: Any) -> None:
        if msg.mission_type == M.MAV_MISSION_TYPE_MISSION:
            self._mission = _Mission()
        self._mission_ack((msg.get_srcSystem(), msg.get_srcComponent()), M.MAV_MISSION_ACCEPTED,
                          msg.mission_type)

    def _on_mission_set_current(self, msg: Any) -> None:
        if 0 <= msg.seq < len(self._mission.items):
            self._mission.current = msg.seq
            self._mission.finished = False
            self._send("MISSION_CURRENT")

    # ------------------------------------------------------------------ vehicle logic
    def _gps_ok(self) -> bool:
        return self._t >= self._gps_lost_until

    def _armable(self) -> bool:
        return self._gps_ok() and self.battery > self.param("BAT_CRIT_THR")

    def _voltage(self) -> float:
        c = self.config
        return c.battery_empty_v + (c.battery_full_v - c.battery_empty_v) * self.battery

    def _est(self) -> KinematicState:
        return self.dyn.estimate()

    def _set_mode(self, mode: FlightMode, reason: str = "") -> None:
        if mode != self.mode:
            log.debug("emulator mode %s -> %s %s", self.mode, mode, reason)
            self._hb_dirty = True
            if self.config.heartbeat_on_change:
                self._send("CURRENT_MODE")
        self.mode = mode
        if not self.failsafe:
            self.intended_mode = mode

    # -- commands to the dynamics model (issued once per change, not every tick)
    def _issue(self, key: tuple[Any, ...], fn: Callable[[], None]) -> None:
        if key != self._last_cmd:
            self._last_cmd = key
            fn()

    def _goto(self, tgt: tuple[float, float, float], yaw_deg: float | None, speed: float | None,
              up: float | None = None, *, immediate: bool = True) -> None:
        yaw = self.dyn.yaw_setpoint_deg if yaw_deg is None else yaw_deg
        key = ("pos", round(tgt[0], 3), round(tgt[1], 3), round(tgt[2], 3), round(yaw, 2), speed, up)
        self._issue(key, lambda: self.dyn.command_position(
            Setpoint(tgt[0], tgt[1], tgt[2], yaw), max_speed_mps=speed, max_up_speed_mps=up,
            immediate=immediate))

    def _hold_here(self) -> None:
        """Brake and hold (PX4 Hold): the model holds its stopping point."""
        self._target = None
        self._target_yaw = None
        self._speed_mps = None
        self._last_cmd = ("hold", self._t)
        if self.armed and self.landed_state != ON_GROUND:
            self.dyn.command_hold(immediate=True)

    def _start_rtl(self) -> None:
        self._set_mode(FlightMode.RETURN_TO_LAUNCH)
        self._rtl_phase = "climb"
        alt = self.param("RTL_RETURN_ALT")
        self._statustext(f"RTL: start return at {self.home.altitude_amsl_m + alt:.0f} m "
                         f"({alt:.0f} m above destination)")

    def _start_mission(self, first: int | None = None) -> None:
        m = self._mission
        if first is not None:
            m.current = first
        if m.finished or m.current >= len(m.items):
            m.current, m.finished = 0, False
        m.reached = -1
        m.climbing_first = True
        self._statustext("Executing Mission")

    def _arm(self) -> None:
        self.armed = True
        self._hb_dirty = True
        self._on_ground_since = self._t
        self._last_cmd = ()
        self._takeoff_announced = False
        self.dyn.set_motors(True)

    def _disarm(self, text: str) -> None:
        self.armed = False
        self._hb_dirty = True
        self.landed_state = ON_GROUND
        self.dyn.set_motors(False)
        self._last_cmd = ()
        self._statustext(text)
        if self.failsafe:
            # Recorded (scenario b): after the failsafe landing the mode returns to the one the
            # user intended (OFFBOARD), status UNINIT.
            self.failsafe = False
            self._set_mode(self.intended_mode)
        elif self.mode in (FlightMode.LAND, FlightMode.RETURN_TO_LAUNCH, FlightMode.TAKEOFF):
            self._set_mode(FlightMode.HOLD)

    def _advance(self, dt: float) -> None:
        if dt <= 0:
            return
        self._t += dt
        self.dyn.estimate_model.set_gps(self._gps_ok())
        self._check_failsafes()
        self._fly()
        self.dyn.step(dt)
        self._landing_logic()
        if self.armed and self.landed_state != ON_GROUND:
            self.battery = max(0.0, self.battery - self._drain_per_s * dt)

    def _check_failsafes(self) -> None:
        # Offboard loss (COM_OF_LOSS_T then COM_OBL_RC_ACT), scenario b of the recordings.
        if (self.mode == FlightMode.OFFBOARD and self.armed and not self.failsafe
                and not self._offboard_signal()):
            self._failsafe(int(self.param("COM_OBL_RC_ACT")), "offboard")
        # Data link loss (COM_DL_LOSS_T, NAV_DLL_ACT).
        # (The client's 1 Hz heartbeats are wall time: also require 2.5 s of wall silence so a
        # speed-up cannot fake a loss between two heartbeats.)
        if (not self._gcs_lost and math.isfinite(self._last_gcs_hb)
                and self._t - self._last_gcs_hb > self.param("COM_DL_LOSS_T")
                and time.monotonic() - self._gcs_hb_wall > 2.5):
            self._gcs_lost = True
            self._statustext("Connection to ground control station lost", M.MAV_SEVERITY_WARNING)
            act = int(self.param("NAV_DLL_ACT"))
            if self.armed and self.landed_state != ON_GROUND and act:
                self._failsafe({1: 5, 2: 3, 3: 4}.get(act, 5), "datalink")
        # GPS loss while flying: PX4 has no position after COM_POS_FS_DELAY -> descends (Land).
        if self._gps_ok():
            self._gps_lost_since = None
        elif self._gps_lost_since is None:
            self._gps_lost_since = self._t
        elif (self.armed and self.landed_state != ON_GROUND and self.mode != FlightMode.LAND
              and self._t - self._gps_lost_since >= self.param("COM_POS_FS_DELAY")):
            self._statustext("Failsafe activated: no position estimate, landing",
                             M.MAV_SEVERITY_CRITICAL)
            self._failsafe(4, "gps")
        # Battery (BAT_*_THR, COM_LOW_BAT_ACT).
        thr = [self.param("BAT_LOW_THR"), self.param("BAT_CRIT_THR"), self.param("BAT_EMERGEN_THR")]
        level = sum(self.battery <= t for t in thr)
        if level > self._battery_warned:
            self._battery_warned = level
            names = {1: "Low", 2: "Critical", 3: "Emergency"}
            self._statustext(f"{names[level]} battery level", M.MAV_SEVERITY_WARNING)
            act = int(self.param("COM_LOW_BAT_ACT"))
            if self.armed and self.landed_state != ON_GROUND:
                if level >= 3 and act in (2, 3):
                    self._failsafe(4, "battery")
                elif level >= 2 and act == 3:
                    self._failsafe(3, "battery")
                elif level >= 2 and act == 2:
                    self._failsafe(4, "battery")

    def _failsafe(self, action: int, cause: str) -> None:
        """COM_OBL_RC_ACT-style action: 0 Position, 1 Altitude, 2 Manual, 3 Return, 4 Land,
        5 Hold, 6 Terminate, 7 Disarm."""
        names = {0: "Position mode", 1: "Altitude mode", 2: "Manual mode", 3: "Return mode",
                 4: "Land mode", 5: "Hold mode", 6: "Terminate", 7: "Disarm"}
        self._statustext("Failsafe activated", M.MAV_SEVERITY_CRITICAL)
        log.info("emulator failsafe (%s): switching to %s", cause, names.get(action, "?"))
        self.failsafe = True
        self._hb_dirty = True
        if action in (0, 1, 2):
            self.manual_control = False
            self._set_mode({0: FlightMode.POSCTL, 1: FlightMode.ALTCTL, 2: FlightMode.MANUAL}[action])
        elif action == 3:
            self._start_rtl()
        elif action == 4:
            self._set_mode(FlightMode.LAND)
        elif action == 5:
            self._hold_here()
            self._set_mode(FlightMode.HOLD)
        else:
            self._disarm("Disarmed by failsafe")

    def _fly(self) -> None:  # noqa: C901 - the mode table
        if not self.armed:
            return
        est = self._est()
        n, e, d = est.position_ned_m
        mode = self.mode
        speed = self._speed_mps
        if mode == FlightMode.TAKEOFF:
            if self._t - self._phase_t < self.config.takeoff_spool_s:
                return
            tgt = self._target or (n, e, -self.param("MIS_TAKEOFF_ALT"))
            self._goto(tgt, None, speed, self.param("MPC_TKO_SPEED"))
            if self.landed_state == ON_GROUND:
                self.landed_state = TAKING_OFF
            if -d >= -tgt[2] - self.param("NAV_MC_ALT_RAD"):
                self.landed_state = IN_AIR
                self._set_mode(FlightMode.HOLD)
        elif mode == FlightMode.HOLD:
            if self._target is not None and self.landed_state != ON_GROUND:
                self._goto(self._target, self._target_yaw, speed)
        elif mode in px4.MANUAL_MODES:
            if self.landed_state == ON_GROUND or self.manual_control:
                return  # holding (pilot with centred sticks) or idle on the ground
            # Recorded (scenario b): no manual input -> "flight task not able to run", the
            # vehicle sinks at ~0.65 m/s while the mode still says POSCTL.
            self._issue(("sink",), lambda: self.dyn.command_velocity((0.0, 0.0, 0.65)))
        elif mode == FlightMode.LAND:
            if self.landed_state != ON_GROUND:
                self.landed_state = LANDING
            self._issue(("land",), lambda: self.dyn.command_land(immediate=True))
        elif mode == FlightMode.RETURN_TO_LAUNCH:
            self._fly_rtl(n, e, d)
        elif mode == FlightMode.OFFBOARD:
            self._fly_offboard(d)
        elif mode == FlightMode.MISSION:
            self._fly_mission(n, e, d, speed)

    def _fly_offboard(self, d: float) -> None:
        sp = self._sp
        if sp is None:
            return
        yaw = None if math.isnan(sp[3]) else sp[3]
        if sp[6] == 0:
            self._goto((sp[0], sp[1], sp[2]), yaw, self.param("MPC_XY_VEL_MAX"),
                       immediate=False)
        else:
            key = ("vel", sp[0], sp[1], sp[2], yaw)
            self._issue(key, lambda: self.dyn.command_velocity((sp[0], sp[1], sp[2]), yaw))
        if self.landed_state == ON_GROUND and -d > 0.3:
            self.landed_state = IN_AIR

    def _fly_rtl(self, n: float, e: float, d: float) -> None:
        ret_alt = max(self.param("RTL_RETURN_ALT"), self._rtl_alt if self._rtl_phase != "climb" else -d)
        if self._rtl_phase == "climb":
            self._rtl_alt = ret_alt
            self._goto((n, e, -ret_alt), None, None, immediate=True)
            if -d >= ret_alt - 0.5:
                self._rtl_phase = "return"
        elif self._rtl_phase == "return":
            yaw = math.degrees(math.atan2(-e, -n)) if math.hypot(n, e) > 2.0 else None
            self._goto((0.0, 0.0, -self._rtl_alt), yaw, self.param("MPC_XY_CRUISE"))
            if math.hypot(n, e) < 1.0:
                self._rtl_phase = "land"
                self._statustext("RTL: land at destination")
        else:
            if self.landed_state != ON_GROUND:
                self.landed_state = LANDING
            self._issue(("land",), lambda: self.dyn.command_land(immediate=True))

    def _fly_mission(self, n: float, e: float, d: float, speed: float | None) -> None:
        m = self._mission
        if m.finished or not m.items:
            return  # "Mission finished, loitering": the hold command issued at the end stays
        item = m.items[m.current]
        tgt = self._item_ned(item, (n, e, d))
        if m.climbing_first:
            if -d < -tgt[2] - self.param("NAV_MC_ALT_RAD"):
                if self.landed_state == ON_GROUND:
                    self._statustext(f"Climb to {-tgt[2]:.1f} meters above home")
                    self._climb_ne = (n, e)
                    self.landed_state = TAKING_OFF
                cn, ce = self._climb_ne or (n, e)
                self._goto((cn, ce, tgt[2]), None, None, self.param("MPC_TKO_SPEED"))
                return
            m.climbing_first = False
        if self.landed_state in (TAKING_OFF, ON_GROUND) and -d > 1.0:
            self.landed_state = IN_AIR
        if item.command == M.MAV_CMD_NAV_LAND:
            self._set_mode(FlightMode.LAND)
            return
        if item.command == M.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            self._start_rtl()
            return
        dist = math.hypot(tgt[0] - n, tgt[1] - e)
        yaw = (item.param4 if math.isfinite(item.param4) else
               (math.degrees(math.atan2(tgt[1] - e, tgt[0] - n)) if dist > 2.0 else None))
        self._goto(tgt, yaw, speed)
        radius = item.param2 if item.param2 > 0 else self.param("NAV_ACC_RAD")
        if dist <= radius and abs(tgt[2] - d) <= self.param("NAV_MC_ALT_RAD"):
            self._item_reached(m)

    def _item_reached(self, m: _Mission) -> None:
        """PX4: the DO items after a waypoint run at once and MISSION_ITEM_REACHED reports the
        last of them (recorded: reached 1, 3, 5 for WP, SPEED, WP, SPEED, WP, SPEED)."""
        j = m.current + 1
        while j < len(m.items) and m.items[j].command not in NAV_COMMANDS:
            it = m.items[j]
            if it.command == M.MAV_CMD_DO_CHANGE_SPEED and it.param2 > 0:
                self._speed_mps = it.param2
            elif it.command == M.MAV_CMD_DO_GRIPPER:
                self.gripper = "grab" if int(it.param2) == M.GRIPPER_ACTION_GRAB else "release"
            j += 1
        m.reached = j - 1
        self._emit(M.MAVLink_mission_item_reached_message(m.reached))
        self._last_reached_send = time.monotonic()
        if j >= len(m.items):
            m.current = len(m.items) - 1
            m.finished = True
            self._hold_here()
            self._statustext("Mission finished, loitering")
        else:
            m.current = j
        self._send("MISSION_CURRENT")

    def _item_ned(self, item: Any, here: tuple[float, float, float]) -> tuple[float, float, float]:
        if item.frame in (M.MAV_FRAME_GLOBAL_INT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                          M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_FRAME_GLOBAL):
            if item.frame in (M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT):
                amsl = self.home.altitude_amsl_m + item.z
            else:
                amsl = item.z
            if item.x == 0 and item.y == 0:
                return (here[0], here[1], self.home.altitude_amsl_m - amsl)
            return geodetic_to_ned(self.home, GeoPoint(item.x / 1e7, item.y / 1e7, amsl))
        if item.frame == M.MAV_FRAME_LOCAL_NED:
            hl = self._home_local
            return (item.x - hl[0], item.y - hl[1], item.z - hl[2])
        return here

    def _landing_logic(self) -> None:
        """Takeoff detection, landing detection (``landed_detect_s`` on the ground) and
        auto-disarm (COM_DISARM_LAND later), as PX4 reports them."""
        if not self.armed:
            return
        on_ground = self.dyn.truth().on_ground
        if not on_ground and not self._takeoff_announced and -self.dyn.truth().position_ned_m[2] > 0.3:
            self._takeoff_announced = True
            self._statustext("Takeoff detected")
        descending = self.landed_state in (LANDING, IN_AIR)
        if not on_ground:
            self._on_ground_since = None
            return
        if self._on_ground_since is None:
            self._on_ground_since = self._t
        grounded_s = self._t - self._on_ground_since
        if descending and grounded_s >= self.config.landed_detect_s:
            self.landed_state = ON_GROUND
            self._statustext("Landing detected")
        climbing = (self.mode == FlightMode.TAKEOFF
                    or (self.mode == FlightMode.MISSION and self._mission.climbing_first)
                    or (self.mode == FlightMode.OFFBOARD and self._sp is not None
                        and self._sp[6] == 0 and self._sp[2] < -0.3))
        if (self.landed_state == ON_GROUND and not climbing
                and grounded_s >= self.config.landed_detect_s + self.param("COM_DISARM_LAND")):
            self._disarm("Disarmed by landing")


_MISSION_DO = frozenset({M.MAV_CMD_DO_CHANGE_SPEED, M.MAV_CMD_DO_GRIPPER,
                         M.MAV_CMD_DO_SET_CAM_TRIGG_DIST, M.MAV_CMD_DO_MOUNT_CONTROL,
                         M.MAV_CMD_IMAGE_START_CAPTURE, M.MAV_CMD_IMAGE_STOP_CAPTURE,
                         M.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW, M.MAV_CMD_NAV_DELAY})

_COMMANDS: dict[int, Callable[[Px4Emulator, Any, list[float], int | None], int]] = {
    M.MAV_CMD_COMPONENT_ARM_DISARM: Px4Emulator._cmd_arm,
    M.MAV_CMD_NAV_TAKEOFF: Px4Emulator._cmd_takeoff,
    M.MAV_CMD_NAV_LAND: Px4Emulator._cmd_land,
    M.MAV_CMD_NAV_RETURN_TO_LAUNCH: Px4Emulator._cmd_rtl,
    M.MAV_CMD_DO_SET_MODE: Px4Emulator._cmd_set_mode,
    M.MAV_CMD_DO_REPOSITION: Px4Emulator._cmd_reposition,
    M.MAV_CMD_DO_GRIPPER: Px4Emulator._cmd_gripper,
    M.MAV_CMD_SET_MESSAGE_INTERVAL: Px4Emulator._cmd_interval,
    M.MAV_CMD_REQUEST_MESSAGE: Px4Emulator._cmd_request,
    M.MAV_CMD_DO_CHANGE_SPEED: Px4Emulator._cmd_change_speed,
    M.MAV_CMD_MISSION_START: Px4Emulator._cmd_mission_start,
    M.MAV_CMD_DO_SET_HOME: Px4Emulator._cmd_set_home,
}

