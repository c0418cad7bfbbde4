"""The messages the MAVLink emulator streams, built as PX4 v1.16 fills them (recorded in
``../shared/data/px4_sitl_tlogs``): one builder per message name."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from eaglemission.drivers.vehicles import px4
from eaglemission.lab.vehicles.emulator.config import distance_sensor_cm
from eaglemission.lab.vehicles.emulator.dialect import GPS_BIT, PREARM_BIT, SENSORS, M
from eaglemission.lab.vehicles.multicopter.kinematics import GRAVITY_MPS2

from eaglemission.geometry import R_to_euler, down_axis_cos_tilt, ned_to_geodetic, quat_to_R
from eaglemission.types import FlightMode

if TYPE_CHECKING:  # the emulator calls these builders; imported for the annotations only
    from eaglemission.lab.vehicles.emulator.emulator import Px4Emulator

Builder = Callable[["Px4Emulator"], Any]


def system_status(e: Px4Emulator) -> int:
    ap = e.autopilot
    if ap.failsafe_active:
        return int(M.MAV_STATE_CRITICAL)
    if ap.armed:
        return int(M.MAV_STATE_ACTIVE)
    # Recorded: STANDBY only when the pre-flight checks pass; UNINIT after the failsafe
    # landing of scenario b (mode OFFBOARD without an offboard signal).
    ready = e.armable() and (ap.mode != FlightMode.OFFBOARD or ap.offboard_signal())
    return int(M.MAV_STATE_STANDBY if ready else M.MAV_STATE_UNINIT)


def _heartbeat(e: Px4Emulator) -> Any:
    ap = e.autopilot
    mode = ap.mode
    base, custom = px4.base_mode(mode, ap.armed), px4.custom_mode(mode)
    if ap.orbit is not None and mode == FlightMode.POSCTL:
        # probed: PX4's ORBIT is Position's sub mode 1, without the manual-input flag (0x91)
        base, custom = base & ~px4.FLAG_MANUAL_INPUT, custom | (px4.POSCTL_ORBIT << 24)
    return M.MAVLink_heartbeat_message(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4, base, custom,
                                       system_status(e), 3)


def _attitude(e: Px4Emulator) -> Any:
    est = e.dyn.estimate()
    r, p, y = (math.radians(a) for a in R_to_euler(quat_to_R(est.attitude_q)))
    return M.MAVLink_attitude_message(e.boot_ms(), r, p, y, 0.0, 0.0,
                                      math.radians(est.yaw_rate_degps))


def _attitude_quaternion(e: Px4Emulator) -> Any:
    est = e.dyn.estimate()
    return M.MAVLink_attitude_quaternion_message(e.boot_ms(), *est.attitude_q, 0.0, 0.0,
                                                 math.radians(est.yaw_rate_degps),
                                                 [0.0, 0.0, 0.0, 0.0])


def _global_position_int(e: Px4Emulator) -> Any:
    est = e.dyn.estimate()
    n, east, d = est.position_ned_m
    vn, ve, vd = est.velocity_ned_mps
    geo = ned_to_geodetic(e.home, n, east, d)
    hdg = int(round((est.yaw_deg % 360.0) * 100)) % 36000
    return M.MAVLink_global_position_int_message(
        e.boot_ms(), int(round(geo.latitude_deg * 1e7)), int(round(geo.longitude_deg * 1e7)),
        int(round(geo.altitude_amsl_m * 1000)), int(round(-d * 1000)),
        int(round(vn * 100)), int(round(ve * 100)), int(round(vd * 100)), hdg)


def _local_position_ned(e: Px4Emulator) -> Any:
    est = e.dyn.estimate()
    n, east, d = est.position_ned_m
    vn, ve, vd = est.velocity_ned_mps
    hl = e.home_local
    return M.MAVLink_local_position_ned_message(e.boot_ms(), n + hl[0], east + hl[1], d + hl[2],
                                                vn, ve, vd)


def _gps_raw_int(e: Px4Emulator) -> Any:
    vn, ve, _ = e.dyn.estimate().velocity_ned_mps
    tg = ned_to_geodetic(e.home, *e.dyn.truth().position_ned_m)
    ok = e.autopilot.gps_ok
    speed = math.hypot(vn, ve)
    cog = int(round((math.degrees(math.atan2(ve, vn)) % 360) * 100)) if speed > 0.1 else 65535
    return M.MAVLink_gps_raw_int_message(
        int(e.sim_time_s * 1e6), 3 if ok else 1, int(round(tg.latitude_deg * 1e7)),
        int(round(tg.longitude_deg * 1e7)), int(round(tg.altitude_amsl_m * 1000)),
        80 if ok else 9999, 120 if ok else 9999, int(round(speed * 100)), cog, 12 if ok else 3)


def _sys_status(e: Px4Emulator) -> Any:
    health = SENSORS | (GPS_BIT if e.autopilot.gps_ok else 0) | (PREARM_BIT if e.armable() else 0)
    return M.MAVLink_sys_status_message(
        SENSORS | GPS_BIT | PREARM_BIT, SENSORS | GPS_BIT | PREARM_BIT, health, 250,
        int(e.voltage() * 1000), -1, int(round(e.autopilot.battery * 100)), 0, 0, 0, 0, 0, 0)


def _extended_sys_state(e: Px4Emulator) -> Any:
    return M.MAVLink_extended_sys_state_message(M.MAV_VTOL_STATE_UNDEFINED,
                                                int(e.autopilot.landed_state))


def _battery_status(e: Px4Emulator) -> Any:
    volts = [int(e.voltage() * 1000)] + [65535] * 9
    return M.MAVLink_battery_status_message(
        0, M.MAV_BATTERY_FUNCTION_ALL, M.MAV_BATTERY_TYPE_LIPO, 2500, volts,
        1000 if e.autopilot.armed else 50, -1, -1, int(round(e.autopilot.battery * 100)))


def _home_position(e: Px4Emulator) -> Any:
    hl = e.home_local
    return M.MAVLink_home_position_message(
        int(round(e.home.latitude_deg * 1e7)), int(round(e.home.longitude_deg * 1e7)),
        int(round(e.home.altitude_amsl_m * 1000)), hl[0], hl[1], hl[2],
        [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, int(e.sim_time_s * 1e6))


def _gps_global_origin(e: Px4Emulator) -> Any:
    o = e.origin
    return M.MAVLink_gps_global_origin_message(
        int(round(o.latitude_deg * 1e7)), int(round(o.longitude_deg * 1e7)),
        int(round(o.altitude_amsl_m * 1000)), int(e.sim_time_s * 1e6))


def mission_current(e: Px4Emulator) -> Any:
    m = e.autopilot.mission
    total = len(m.items) if m.items else 65535
    seq = min(m.current, len(m.items) - 1) if m.items else m.current
    return M.MAVLink_mission_current_message(seq, total, 0, 0)


def _current_mode(e: Px4Emulator) -> Any:
    ap = e.autopilot
    orbit = (px4.POSCTL_ORBIT << 24) if ap.orbit is not None and ap.mode == FlightMode.POSCTL else 0
    return M.MAVLink_current_mode_message(0, px4.custom_mode(ap.mode) | orbit,
                                          px4.custom_mode(ap.intended_mode) | orbit)


def _distance_sensor(e: Px4Emulator) -> Any:
    rf = e.config.rangefinder
    if not rf.enabled or e.rangefinder_lost():
        return None  # PX4 streams DISTANCE_SENSOR only while a sensor publishes
    tr = e.dyn.truth()
    cur, lo, hi = distance_sensor_cm(tr.position_ned_m[2], down_axis_cos_tilt(tr.attitude_q), rf,
                                     e.rangefinder_noise())
    # Recorded PX4 v1.16 SIH: type LASER (0), id 0, orientation PITCH_270 (downward),
    # covariance 0 (SIH's variance is 0: unknown), signal_quality 0 (SIH's -1: unknown),
    # no FOV, quaternion zeros.
    return M.MAVLink_distance_sensor_message(
        e.boot_ms(), lo, hi, cur, M.MAV_DISTANCE_SENSOR_LASER, 0,
        M.MAV_SENSOR_ROTATION_PITCH_270, 0, 0.0, 0.0, [0.0, 0.0, 0.0, 0.0], 0)


def _hil_state_quaternion(e: Px4Emulator) -> Any:
    # The simulator's ground truth as PX4 SIH fills it (README of the tlogs, "Ground
    # truth"): time_usec 0, true attitude, body rates, position (degE7, mm AMSL),
    # NED velocity (cm/s), airspeeds 0, true NED acceleration truncated to m/s^2.
    tr = e.dyn.truth()
    tg = ned_to_geodetic(e.home, *tr.position_ned_m)
    tv = tr.velocity_ned_mps
    acc = tr.acceleration_ned_mps2
    return M.MAVLink_hil_state_quaternion_message(
        0, list(tr.attitude_q), 0.0, 0.0, math.radians(tr.yaw_rate_degps),
        int(round(tg.latitude_deg * 1e7)), int(round(tg.longitude_deg * 1e7)),
        int(round(tg.altitude_amsl_m * 1000)), int(round(tv[0] * 100)),
        int(round(tv[1] * 100)), int(round(tv[2] * 100)), 0, 0,
        int(acc[0]), int(acc[1]), int(acc[2]))


def _autopilot_version(e: Px4Emulator) -> Any:
    caps = (M.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT | M.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
            | M.MAV_PROTOCOL_CAPABILITY_MISSION_INT | M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
            | M.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
            | M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
            | M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT
            | M.MAV_PROTOCOL_CAPABILITY_MAVLINK2)
    return M.MAVLink_autopilot_version_message(
        caps, px4.flight_sw_version(), px4.flight_sw_version(), 0, 1,
        px4.custom_version_bytes(), px4.custom_version_bytes(), [0] * 8,
        0, 0, 0x4541474C45, [0] * 18)


def _pressure_pa(altitude_amsl_m: float) -> float:
    """ISA static pressure at an altitude (what SIH's barometer reads without noise)."""
    return float(101325.0 * (1.0 - 2.25577e-5 * altitude_amsl_m) ** 5.25588)


def _highres_imu(e: Px4Emulator) -> Any:
    # The IMU's specific force and rates in the body frame (FRD), as PX4 SIH fills it
    # (recorded: hovering, zacc ~ -9.8, fields_updated 63 = accel + gyro).
    tr = e.dyn.truth()
    an, ae, ad = tr.acceleration_ned_mps2
    R = quat_to_R(tr.attitude_q)
    f_body = R.T @ [an, ae, ad - GRAVITY_MPS2]
    amsl = e.home.altitude_amsl_m - tr.position_ned_m[2]
    return M.MAVLink_highres_imu_message(
        int(e.sim_time_s * 1e6), float(f_body[0]), float(f_body[1]), float(f_body[2]), 0.0, 0.0,
        math.radians(tr.yaw_rate_degps), 0.22, 0.017, 0.41, _pressure_pa(amsl), 0.0, amsl, 15.0,
        63, 0)


def _odometry(e: Px4Emulator) -> Any:
    # The estimate as PX4 sends it (recorded): frame_id and child_frame_id MAV_FRAME_LOCAL_NED,
    # position in the EKF-origin frame, velocity NED, estimator type 8 (autopilot).
    est = e.dyn.estimate()
    n, east, d = est.position_ned_m
    hl = e.home_local
    nan21 = [math.nan] * 21
    return M.MAVLink_odometry_message(
        int(e.sim_time_s * 1e6), M.MAV_FRAME_LOCAL_NED, M.MAV_FRAME_LOCAL_NED, n + hl[0],
        east + hl[1], d + hl[2], list(est.attitude_q), *est.velocity_ned_mps, 0.0, 0.0,
        math.radians(est.yaw_rate_degps), nan21, nan21, 0, M.MAV_ESTIMATOR_TYPE_AUTOPILOT, 0)


def _altitude(e: Px4Emulator) -> Any:
    est = e.dyn.estimate()
    rel = -est.position_ned_m[2]
    amsl = e.home.altitude_amsl_m + rel
    local = rel - e.home_local[2]
    return M.MAVLink_altitude_message(int(e.sim_time_s * 1e6), amsl, amsl, local, rel, math.nan,
                                      math.nan)


def _vfr_hud(e: Px4Emulator) -> Any:
    est = e.dyn.estimate()
    vn, ve, vd = est.velocity_ned_mps
    throttle = int(round(50.0 * (1.0 - est.acceleration_ned_mps2[2] / GRAVITY_MPS2))) if e.autopilot.armed else 0
    return M.MAVLink_vfr_hud_message(0.0, math.hypot(vn, ve), int(round(est.yaw_deg)) % 360,
                                     max(0, min(100, throttle)),
                                     e.home.altitude_amsl_m - est.position_ned_m[2], -vd)


def _scaled_pressure(e: Px4Emulator) -> Any:
    amsl = e.home.altitude_amsl_m - e.dyn.truth().position_ned_m[2]
    return M.MAVLink_scaled_pressure_message(e.boot_ms(), _pressure_pa(amsl) / 100.0, 0.0, 1179, 0)


def _system_time(e: Px4Emulator) -> Any:
    return M.MAVLink_system_time_message(int(time.time() * 1e6), e.boot_ms())


BUILDERS: dict[str, Builder] = {
    "HEARTBEAT": _heartbeat,
    "ATTITUDE": _attitude,
    "ATTITUDE_QUATERNION": _attitude_quaternion,
    "GLOBAL_POSITION_INT": _global_position_int,
    "LOCAL_POSITION_NED": _local_position_ned,
    "GPS_RAW_INT": _gps_raw_int,
    "SYS_STATUS": _sys_status,
    "EXTENDED_SYS_STATE": _extended_sys_state,
    "BATTERY_STATUS": _battery_status,
    "HOME_POSITION": _home_position,
    "GPS_GLOBAL_ORIGIN": _gps_global_origin,
    "MISSION_CURRENT": mission_current,
    "CURRENT_MODE": _current_mode,
    "DISTANCE_SENSOR": _distance_sensor,
    "HIL_STATE_QUATERNION": _hil_state_quaternion,
    "AUTOPILOT_VERSION": _autopilot_version,
    "HIGHRES_IMU": _highres_imu,
    "ODOMETRY": _odometry,
    "ALTITUDE": _altitude,
    "VFR_HUD": _vfr_hud,
    "SCALED_PRESSURE": _scaled_pressure,
    "SYSTEM_TIME": _system_time,
}
"""Message name -> builder (None from a builder: nothing to send now)."""

SAMPLED = frozenset({"ATTITUDE", "ATTITUDE_QUATERNION", "GLOBAL_POSITION_INT",
                     "LOCAL_POSITION_NED", "DISTANCE_SENSOR", "HIGHRES_IMU", "ODOMETRY"})
"""Streams of an estimator / sensor sample stamped ``time_boot_ms``: PX4 sends one only when a
new sample exists, so never two with the same stamp (0 of 43,803 ATTITUDE_QUATERNION in the
recorded v1.16 tlogs); the emulator skips a due one whose stamp has not moved (its simulation
may lag the wall-time schedule on a loaded machine)."""


class Streams:
    """Which message is due when: PX4's stream rates, changed by SET_MESSAGE_INTERVAL (wall
    time: MAVSDK's timers are)."""

    def __init__(self, rates_hz: dict[str, float]) -> None:
        self.intervals: dict[str, float] = {
            name: (1.0 / hz if hz > 0 else math.inf) for name, hz in rates_hz.items()}
        self._next_due: dict[str, float] = {}
        self._last_sent: dict[str, float] = {}
        self._sampled_ms: dict[str, int] = {}  # the stamp each SAMPLED stream last went out with

    def due(self, wall: float, boot_ms: int | None = None) -> list[str]:
        """The messages to send now (the schedule moves on); with ``boot_ms``, a SAMPLED one
        whose stamp has not moved since it last went out is skipped (PX4 sends none)."""
        out = []
        for name, interval in self.intervals.items():
            if not math.isfinite(interval):
                continue
            due = self._next_due.get(name)
            if due is None:
                self._next_due[name] = wall + (interval if name != "HEARTBEAT" else 0.0)
                continue
            if wall >= due:
                if name in SAMPLED and boot_ms is not None:
                    if self._sampled_ms.get(name) == boot_ms:
                        continue  # still due: it goes out once a new sample exists
                    self._sampled_ms[name] = boot_ms
                out.append(name)
                self._last_sent[name] = wall
                nxt = due + interval
                self._next_due[name] = nxt if nxt > wall else wall + interval
        return out

    def sent_now(self, name: str, wall: float) -> None:
        """``name`` went out out of schedule (a HEARTBEAT on change): the next one a period later."""
        self._next_due[name] = wall + self.intervals[name]

    def set_interval(self, name: str, interval_us: float, default_hz: float, max_hz: float | None,
                     wall: float) -> bool:
        """SET_MESSAGE_INTERVAL: -1 stops the stream, 0 restores ``default_hz``; False when the
        interval is not valid."""
        if not math.isfinite(interval_us):
            return False
        if interval_us == -1:
            self.intervals[name] = math.inf
        elif interval_us == 0:
            self.intervals[name] = 1.0 / default_hz
        elif interval_us > 0:
            self.intervals[name] = max(interval_us * 1e-6, 1.0 / 250.0)
        else:
            return False
        if max_hz is not None:  # PX4 streams a sensor sample once: no faster than it
            self.intervals[name] = max(self.intervals[name], 1.0 / max_hz)
        # PX4 sends a stream once the new interval has elapsed since its last message, so a
        # faster rate takes effect at once.
        if math.isfinite(self.intervals[name]):
            last = self._last_sent.get(name)
            self._next_due[name] = wall if last is None else last + self.intervals[name]
        return True
