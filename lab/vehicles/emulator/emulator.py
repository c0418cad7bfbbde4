"""A PX4-like multicopter that speaks MAVLink 2, for testing the MAVSDK driver without PX4.

It answers the way PX4 v1.16 answered MAVSDK 4.1 in the recorded SITL traffic
(``../shared/data/px4_sitl_tlogs``): HEARTBEAT with PX4 custom modes at 1 Hz of emulator time
and never on a change (so a mode change shows at the next HEARTBEAT, as on PX4; the config's
``heartbeat_on_change`` also sends one on every change), COMMAND_ACK for every command
(DO_SET_MODE acknowledged twice),
SYS_STATUS with sensor and pre-arm bits, HOME_POSITION, GLOBAL_POSITION_INT,
LOCAL_POSITION_NED (relative to an EKF origin a few decimetres from home, as on PX4),
ATTITUDE(+_QUATERNION), EXTENDED_SYS_STATE, BATTERY_STATUS, GPS_RAW_INT, CURRENT_MODE,
DISTANCE_SENSOR (a downward rangefinder, when ``rangefinder.enabled``; encoded as PX4 SIH's), the
mission protocol (upload, download, MISSION_CURRENT, MISSION_ITEM_REACHED re-sent at 1 Hz),
DO_SET_MODE, DO_REPOSITION, DO_ORBIT, takeoff/land/RTL, every offboard setpoint MAVSDK sends
(SET_POSITION_TARGET_LOCAL_NED / _GLOBAL_INT, SET_ATTITUDE_TARGET: :mod:`.emulator_offboard`)
with PX4's offboard-loss failsafe (COM_OF_LOSS_T, COM_OBL_RC_ACT), DO_GRIPPER (IN_PROGRESS, then
ACCEPTED), MANUAL_CONTROL, the parameter protocol for PX4 v1.16's whole parameter set and
SET_MESSAGE_INTERVAL / REQUEST_MESSAGE; reports/px4_emulator.md, "MAVSDK plugins as PX4 answers them",
compares each with what PX4 v1.16 SITL answered the same MAVSDK calls.

The vehicle is :class:`eaglemission.lab.vehicles.multicopter.dynamics.MulticopterDynamics` with the
PX4-like :class:`eaglemission.lab.vehicles.autopilot.model.Autopilot` on top (the ``simulated``
plugin's model, configured from this emulator's PX4 parameters: :meth:`Px4Emulator.autopilot_params`),
stepped in the emulator's own thread, so the emulator keeps flying while the client's event
loop is blocked. This module talks MAVLink around it: commands (:mod:`.emulator_commands`),
missions (:mod:`.emulator_missions`), streams (:mod:`.emulator_messages`), the link
(:mod:`.emulator_link`).

Time: ``speedup`` scales the emulator's simulated time (dynamics and its own timers: offboard
loss, landing detection, auto-disarm, failsafes, and the HEARTBEAT period); ``clock_rate`` is
PX4's clock against the host's (SITL's runs ~0.8 % slow, recorded), so the stamps it sends
(``time_boot_ms``) fall behind the host's clock as PX4's do. The other stream
rates stay in wall time because MAVSDK's timers do (it declares a link dead after 3 s without
HEARTBEAT). Offboard
setpoints arrive every 50 ms wall, i.e. every ``0.05 * speedup`` s of emulator time: keep that
below COM_OF_LOSS_T (``speedup <= 10`` with the default 1 s).

Transports: ``udpin://host:port`` (bind, answer the last sender), ``udpout://host:port`` (send
first), or none: then bytes go out through :meth:`Px4Emulator.set_output` and come in through
:meth:`Px4Emulator.feed` (MAVSDK's ``raw://`` connection, one process, no sockets).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from eaglemission.drivers.vehicles import px4
from eaglemission.lab.vehicles.autopilot.model import (
    Autopilot,
    AutopilotParams,
    FailsafeAction,
    LandedState,
    ModeSource,
)
from eaglemission.lab.vehicles.emulator import offboard
from eaglemission.lab.vehicles.emulator.commands import CommandHandlers
from eaglemission.lab.vehicles.emulator.config import (
    DISTANCE_NO_RETURN_CM,
    PX4_ONBOARD_RATES_HZ,
    EmulatorConfig,
    EmulatorSnapshot,
    Traffic,
    distance_sensor_cm,
    emulator_autopilot_params,
)
from eaglemission.lab.vehicles.emulator.dialect import SEVERITY, M, mavlink
from eaglemission.lab.vehicles.emulator.link import Transport, UdpLink, parse_link
from eaglemission.lab.vehicles.emulator.messages import BUILDERS, Streams
from eaglemission.lab.vehicles.emulator.missions import MissionProtocol
from eaglemission.lab.vehicles.multicopter.dynamics import MulticopterDynamics, Normals

from eaglemission.errors import ConfigError
from eaglemission.geometry import ned_to_geodetic
from eaglemission.types import FlightMode, GeoPoint

__all__ = ["DISTANCE_NO_RETURN_CM", "PX4_ONBOARD_RATES_HZ", "EmulatorConfig", "EmulatorSnapshot", "Px4Emulator", "Traffic",
           "distance_sensor_cm", "mavlink", "parse_link"]

log = logging.getLogger(__name__)

_DLL_ACTIONS = {1: FailsafeAction.HOLD, 2: FailsafeAction.RETURN, 3: FailsafeAction.LAND}
"""NAV_DLL_ACT -> failsafe (other non-zero values: hold)."""


class _Reports:
    """The autopilot's reports as MAVLink: STATUSTEXT, HEARTBEAT / CURRENT_MODE on change,
    MISSION_ITEM_REACHED and MISSION_CURRENT."""

    def __init__(self, emulator: Px4Emulator) -> None:
        self._e = emulator

    def on_status(self, text: str, severity: str) -> None:
        self._e.statustext(text, SEVERITY.get(severity, M.MAV_SEVERITY_INFO))

    def on_mode(self, old: FlightMode, new: FlightMode, source: ModeSource) -> None:
        log.debug("emulator mode %s -> %s (%s)", old, new, source)
        self._e.heartbeat_due = True
        if self._e.config.heartbeat_on_change:
            self._e.send("CURRENT_MODE")

    def on_failsafe(self, reason: str, action: FailsafeAction) -> None:
        log.info("emulator failsafe (%s): %s", reason, action.value)
        self._e.heartbeat_due = True

    def on_armed(self, armed: bool) -> None:
        self._e.heartbeat_due = True

    def on_mission_item(self, index: int, total: int) -> None:
        self._e.emit(M.MAVLink_mission_item_reached_message(index))
        self._e.last_reached_send = time.monotonic()
        self._e.send("MISSION_CURRENT")

    def on_gps(self, ok: bool) -> None:
        pass


def stream_rates_hz(cfg: EmulatorConfig) -> dict[str, float]:
    """Wall-time stream rates. PX4's HEARTBEAT period is what delays every mode / arming report
    (recorded d: 1.005-1.048 s): it runs on the emulator's clock, so ``speedup`` times per wall
    second (MAVSDK's link timers only need >= 1 Hz of wall time)."""
    rates = {**PX4_ONBOARD_RATES_HZ, **cfg.stream_rates_hz}
    if not cfg.heartbeat_on_change:
        rates["HEARTBEAT"] *= cfg.speedup * cfg.clock_rate
    return rates


def message_handlers(e: Px4Emulator) -> dict[str, Callable[[Any], None]]:
    """What the emulator does with each message type a client sends (others are ignored)."""
    return {
        "COMMAND_LONG": e.commands.on_command_long,
        "COMMAND_INT": e.commands.on_command_int,
        "PARAM_SET": e.commands.on_param_set,
        "PARAM_REQUEST_READ": e.commands.on_param_request_read,
        "PARAM_REQUEST_LIST": e.commands.on_param_request_list,
        "MISSION_COUNT": e.missions.on_mission_count,
        "MISSION_ITEM_INT": e.missions.on_mission_item_int,
        "MISSION_ITEM": e.missions.on_mission_item,
        "MISSION_ACK": e.missions.on_mission_ack,
        "MISSION_REQUEST_LIST": e.missions.on_mission_request_list,
        "MISSION_REQUEST_INT": e.missions.on_mission_request_int,
        "MISSION_REQUEST": e.missions.on_mission_request,
        "MISSION_CLEAR_ALL": e.missions.on_mission_clear_all,
        "MISSION_SET_CURRENT": e.missions.on_mission_set_current,
        "SET_POSITION_TARGET_LOCAL_NED": lambda m: offboard.on_set_position_target_local_ned(e, m),
        "SET_POSITION_TARGET_GLOBAL_INT": lambda m: offboard.on_set_position_target_global_int(e, m),
        "SET_ATTITUDE_TARGET": lambda m: offboard.on_set_attitude_target(e, m),
        "MANUAL_CONTROL": e.commands.on_manual_control,
    }


def _model_params(cfg: EmulatorConfig) -> dict[str, float]:
    """The PX4 parameters the vehicle model's dynamics set (unless the config sets them)."""
    dp = cfg.dynamics
    return {"MPC_XY_CRUISE": dp.cruise_speed_mps, "MPC_XY_VEL_MAX": dp.max_horizontal_speed_mps,
            "MPC_Z_VEL_MAX_UP": dp.max_up_speed_mps, "MPC_Z_VEL_MAX_DN": dp.max_down_speed_mps,
            "MPC_Z_V_AUTO_UP": dp.max_up_speed_mps, "MPC_Z_V_AUTO_DN": dp.max_down_speed_mps,
            "MPC_TKO_SPEED": dp.takeoff_speed_mps, "MPC_LAND_SPEED": dp.land_speed_mps,
            "MPC_YAWRAUTO_MAX": dp.max_yaw_rate_degps, "MAV_SYS_ID": cfg.sysid}


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
        self.config = cfg = config or EmulatorConfig()
        known = px4.default_params()
        unknown = sorted(set(cfg.params) - set(known))
        if unknown:
            raise ConfigError(f"EmulatorConfig.params: unknown PX4 parameters {unknown}: not in "
                              f"PX4 v1.16's set ({px4.PARAMS_FILE.name}, {len(known)} names)")
        bad = sorted(set(cfg.stream_rates_hz) - set(PX4_ONBOARD_RATES_HZ))
        if bad:
            raise ConfigError(f"EmulatorConfig.stream_rates_hz: unknown messages {bad}")
        self.home = GeoPoint(cfg.home_latitude_deg, cfg.home_longitude_deg,
                             cfg.home_altitude_amsl_m)
        off = cfg.home_in_origin_ned_m
        self.origin = ned_to_geodetic(self.home, -off[0], -off[1], -off[2])
        self.home_local = off  # home in the EKF-origin frame
        model_params = _model_params(cfg)
        self.params: dict[str, list[float]] = {
            k: [float(cfg.params.get(k, model_params.get(k, v))), float(t)]
            for k, (v, t) in known.items()
        }
        self.param_names = list(self.params)
        self.param_index = {name: i for i, name in enumerate(self.param_names)}
        self._link_url = link
        self._udp: UdpLink | None = None
        self._record = record
        self.traffic: list[Traffic] = []
        self._lock = threading.RLock()
        self._link = Transport()
        self._mav = M.MAVLink(None, srcSystem=cfg.sysid, srcComponent=cfg.compid)
        self._parser = M.MAVLink(None, srcSystem=cfg.sysid, srcComponent=cfg.compid)
        self._parser.robust_parsing = True
        self._threads: list[threading.Thread] = []
        self._stop = threading.Event()
        # The vehicle (emulator time).
        self.dyn = MulticopterDynamics(cfg.dynamics, seed=cfg.seed, wind_ne_mps=cfg.wind_ne_mps)
        self.dyn.reset((0.0, 0.0, 0.0), cfg.initial_yaw_deg)
        self._drain_per_s = cfg.battery_drain_per_s
        self.autopilot = Autopilot(self.dyn, self.autopilot_params(), _Reports(self))
        self.autopilot.offboard_signal_grace = self._recent_setpoint
        self.autopilot.gripper = "grab"  # PX4's payload deliverer grabs at boot (probed)
        self.commands = CommandHandlers(self)
        self.missions = MissionProtocol(self)
        self.streams = Streams(stream_rates_hz(cfg))
        self._handlers = message_handlers(self)
        self._t = 0.0
        self._in_step = False  # inside the vehicle's steps (what is sent carries their time)
        self._last_wall = 0.0
        self.setpoint_wall = -math.inf
        self._last_gcs_hb = -math.inf
        self._gcs_hb_wall = -math.inf
        self._gcs_lost = False
        self._statustext_id = 0
        self.last_reached_send = -math.inf
        self.heartbeat_due = False
        self._rf_noise = Normals(np.random.default_rng(
            np.random.SeedSequence([cfg.seed, 0x52F])))  # the simulated vehicle's stream
        self._rangefinder_lost_until = -1.0

    def autopilot_params(self) -> AutopilotParams:
        """The shared autopilot model as configured by the PX4 parameters and the config."""
        return emulator_autopilot_params(self.config, self.param, self._drain_per_s)

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
            self._udp = UdpLink(self._link_url)
            self.set_output(self._udp.send)
            self._threads.append(threading.Thread(target=self._udp_reader, name="px4emu-udp",
                                                  daemon=True))
        self._last_wall = time.monotonic()
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
        self._link.set_output(fn)
        if fn is not None:
            self.heartbeat_due = True  # the link came up: announce ourselves at once

    def feed(self, data: bytes) -> None:
        """Bytes from the client (any thread)."""
        self._link.feed(data)

    # ------------------------------------------------------------------ fault injection
    def inject_link_loss(self, duration_s: float, *, direction: str = "both") -> None:
        """Drop packets for ``duration_s`` wall seconds: ``both`` directions, or only the
        ``uplink`` (client -> vehicle: a client process that died, as in recorded scenario b)."""
        self._link.inject_loss(duration_s, direction)

    def set_link_delay(self, delay_s: float) -> None:
        """Delay every packet in both directions by ``delay_s`` wall seconds (0 = off)."""
        self._link.set_delay(delay_s)

    def deny_next_command(self, command: int | str, result: int = M.MAV_RESULT_DENIED) -> None:
        """Answer the next COMMAND_LONG/INT with this id (or MAV_CMD name) with ``result``."""
        cid = command if isinstance(command, int) else getattr(M, command if command.startswith(
            "MAV_CMD_") else "MAV_CMD_" + command.upper())
        with self._lock:
            self.commands.deny[int(cid)] = int(result)

    def inject_gps_loss(self, duration_s: float) -> None:
        """No GPS fix for ``duration_s`` emulator seconds (PX4 then lands if flying)."""
        with self._lock:
            self.autopilot.gps_loss(float(duration_s))

    def inject_rangefinder_loss(self, duration_s: float) -> None:
        """The distance sensor stops publishing for ``duration_s`` emulator seconds (PX4 then
        sends no DISTANCE_SENSOR: its stream only forwards new samples)."""
        with self._lock:
            self._rangefinder_lost_until = self._t + float(duration_s)

    def set_battery_fraction(self, fraction: float) -> None:
        """Set the remaining battery (0..1); crossing BAT_*_THR warns / acts as PX4 does."""
        with self._lock:
            self.autopilot.set_battery(min(1.0, max(0.0, float(fraction))))

    def set_battery_drain(self, per_s: float) -> None:
        """Battery fraction used per emulator second of flight (drain it fast in a test)."""
        if not per_s >= 0:
            raise ValueError(f"per_s: must be >= 0, got {per_s}")
        with self._lock:
            self._drain_per_s = float(per_s)
            self.autopilot.params = self.autopilot_params()

    def pilot_take_control(self, mode: FlightMode | str = FlightMode.POSCTL) -> None:
        """A pilot (RC sticks centred) or ground station switches the mode."""
        with self._lock:
            self.autopilot.pilot_take_control(FlightMode(mode))

    def set_param(self, name: str, value: float) -> None:
        with self._lock:
            self.params[name][0] = float(value)
            self.autopilot.params = self.autopilot_params()

    def param(self, name: str) -> float:
        return float(self.params[name][0])

    # ------------------------------------------------------------------ observation
    def snapshot(self) -> EmulatorSnapshot:
        with self._lock:
            ap = self.autopilot
            s = self.dyn.truth()
            e = self.dyn.estimate()
            sp: tuple[float, float, float, float] | None = None
            if ap.setpoint is not None:
                sp = (*ap.setpoint.position_ned_m, ap.setpoint.yaw_deg)
            elif ap.setpoint_velocity is not None:
                v, yaw = ap.setpoint_velocity
                sp = (*v, math.nan if yaw is None else yaw)
            return EmulatorSnapshot(
                sim_time_s=self._t, mode=ap.mode, armed=ap.armed,
                landed_state=int(ap.landed_state), true_position_ned_m=s.position_ned_m,
                estimate_position_ned_m=e.position_ned_m, velocity_ned_mps=e.velocity_ned_mps,
                yaw_deg=e.yaw_deg, battery_remaining=ap.battery, gps_ok=ap.gps_ok,
                failsafe=ap.failsafe_active, gripper=ap.gripper,
                mission_current=min(ap.mission.current, max(0, len(ap.mission.items) - 1)),
                mission_count=len(self.missions.items),
                offboard_setpoint=sp, true_attitude_q=s.attitude_q)

    @property
    def sim_time_s(self) -> float:
        return self._t

    @property
    def fence_items(self) -> list[Any]:
        """The uploaded geofence (MISSION_ITEM_INT, FENCE)."""
        return self.missions.fence_items

    def received(self, msg_type: str) -> list[Any]:
        """Recorded messages of a type from the client (``record=True``)."""
        return [t.msg for t in list(self.traffic) if t.direction == "in"
                and t.msg.get_type() == msg_type]

    def sent(self, msg_type: str) -> list[Traffic]:
        return [t for t in list(self.traffic) if t.direction == "out"
                and t.msg.get_type() == msg_type]

    # ------------------------------------------------------------------ for the protocol parts
    def armable(self) -> bool:
        return not self.autopilot.not_armable_reason()

    def voltage(self) -> float:
        c = self.config
        return c.battery_empty_v + (c.battery_full_v - c.battery_empty_v) * self.autopilot.battery

    def boot_ms(self) -> int:
        return int(self._t * 1000) & 0xFFFFFFFF

    def rangefinder_lost(self) -> bool:
        return self._t < self._rangefinder_lost_until

    def rangefinder_noise(self) -> float:
        return self._rf_noise.next()

    def emit(self, msg: Any) -> None:
        """Send one message (recorded with ``record=True``)."""
        data = msg.pack(self._mav)
        self._mav.seq = (self._mav.seq + 1) % 256
        now = time.monotonic()
        if self._record:  # sent from a vehicle step: that step's time, not the tick's end
            sent_s = self.dyn.time_ns * 1e-9 if self._in_step else self._t
            self.traffic.append(Traffic(now, "out", msg, sent_s))
        self._link.send(data, now)

    def send(self, name: str) -> None:
        """Send the message ``name`` as it is now (nothing for an unknown name)."""
        builder = BUILDERS.get(name)
        msg = builder(self) if builder is not None else None
        if msg is not None:
            self.emit(msg)

    def statustext_link_live(self) -> bool:
        """A GCS HEARTBEAT arrived within 2.5 s (wall): STATUSTEXT goes out (PX4's rule)."""
        return time.monotonic() - self._gcs_hb_wall <= 2.5

    def statustext(self, text: str, severity: int = M.MAV_SEVERITY_INFO) -> None:
        """STATUSTEXT as PX4 sends it: tab-terminated, split into 50-character chunks."""
        log.info("emulator: %s", text)
        if not self.statustext_link_live():
            return  # PX4 sends STATUSTEXT on a link only while a GCS heartbeat is fresh
        body = (text + "\t").encode()
        self._statustext_id = (self._statustext_id + 1) % 65536
        chunks = [body[i:i + 50] for i in range(0, len(body), 50)] or [b""]
        for n, chunk in enumerate(chunks):
            self.emit(M.MAVLink_statustext_message(severity, chunk, self._statustext_id, n))

    # ------------------------------------------------------------------ threads
    def _udp_reader(self) -> None:
        while not self._stop.is_set():
            udp = self._udp
            data = udp.recv() if udp is not None else None
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
            data = self._link.get(max(0.0, next_tick - now))
            if data is not None:
                with self._lock:
                    self._handle_bytes(data)

    def _tick(self) -> None:
        wall = time.monotonic()
        dt = max(0.0, wall - self._last_wall) * self.config.speedup * self.config.clock_rate
        self._last_wall = wall  # the emulator thread's own
        self.step(dt, wall=wall)

    def step(self, dt_s: float, *, wall: float | None = None) -> None:
        """One tick of the emulator's own thread, for a caller that drives it without
        :meth:`start`: the bytes :meth:`feed` delivered are handled, the vehicle is advanced by
        ``dt_s`` simulated seconds (at most 0.5), the streams due at ``wall`` (monotonic
        seconds, default now) and the delayed packets that are due are sent."""
        wall = time.monotonic() if wall is None else wall
        with self._lock:
            for data in self._link.inbound(wall):
                self._handle_bytes(data)
            self._advance(min(dt_s, 0.5))
            self._streams(wall)
            self.missions.retry(wall)
            self.commands.tick()
        self._link.flush(wall)

    def _advance(self, dt: float) -> None:
        if dt <= 0:
            return
        self._t += dt
        self._check_datalink()
        self._in_step = True
        self.dyn.step(dt, self.autopilot.on_step)
        self._in_step = False

    def _check_datalink(self) -> None:
        """Data link loss (COM_DL_LOSS_T, NAV_DLL_ACT). The client's 1 Hz heartbeats are wall
        time: 2.5 s of wall silence are also required, so a speed-up cannot fake a loss."""
        if (self._gcs_lost or not math.isfinite(self._last_gcs_hb)
                or self._t - self._last_gcs_hb <= self.param("COM_DL_LOSS_T")
                or time.monotonic() - self._gcs_hb_wall <= 2.5):
            return
        self._gcs_lost = True
        self.statustext("Connection to ground control station lost", M.MAV_SEVERITY_WARNING)
        act = int(self.param("NAV_DLL_ACT"))
        ap = self.autopilot
        if ap.armed and ap.landed_state != LandedState.ON_GROUND and act:
            ap.failsafe("Connection to ground control station lost",
                        _DLL_ACTIONS.get(act, FailsafeAction.HOLD))

    def _streams(self, wall: float) -> None:
        if self.heartbeat_due and self.config.heartbeat_on_change:
            self.heartbeat_due = False
            self.send("HEARTBEAT")
            self.streams.sent_now("HEARTBEAT", wall)
        for name in self.streams.due(wall, self.boot_ms()):
            self.send(name)
        reached = self.autopilot.mission.reached
        if (self.autopilot.mode == FlightMode.MISSION and reached >= 0
                and wall - self.last_reached_send >= 1.0):
            self.last_reached_send = wall
            self.emit(M.MAVLink_mission_item_reached_message(reached))

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

    def _handle(self, msg: Any) -> None:
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            if msg.type == M.MAV_TYPE_GCS:  # PX4 counts GCS heartbeats only
                self._gcs_hb_wall = time.monotonic()
                self._last_gcs_hb = self._t
                if self._gcs_lost:
                    self._gcs_lost = False
                    self.statustext("Data link regained")
            return
        if kind == "PING":
            if msg.target_system == 0:
                self.emit(M.MAVLink_ping_message(msg.time_usec, msg.seq, msg.get_srcSystem(),
                                                 msg.get_srcComponent()))
            return
        ts = getattr(msg, "target_system", 0)
        tc = getattr(msg, "target_component", 0)
        if ts not in (0, self.config.sysid) or tc not in (0, self.config.compid):
            return
        handler = self._handlers.get(kind)
        if handler is not None:
            handler(msg)

    def _recent_setpoint(self) -> bool:
        """With a speed-up, MAVSDK's 20 Hz re-sending (wall time) is also given 3 periods of
        wall time, so a high speed-up cannot fake an offboard loss between two setpoints."""
        return time.monotonic() - self.setpoint_wall <= 0.15

