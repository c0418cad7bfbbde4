"""Offboard setpoints in the MAVLink emulator, taken as PX4 v1.16 takes them: every setpoint
MAVSDK's Offboard plugin sends counts as PX4's offboard signal and is flown by the shared
autopilot model.

Probed on PX4 v1.16 SITL (SIH quad; ``benchmarks/probe_mavsdk_plugins.py``): from Hold at
10 m, ``Offboard.start`` after each of ``set_position_ned``, ``set_velocity_ned``,
``set_velocity_body``, ``set_position_velocity_ned``, ``set_position_velocity_acceleration_ned``,
``set_acceleration_ned``, ``set_position_global``, ``set_attitude`` and ``set_attitude_rate``
is ACCEPTED and the HEARTBEAT shows OFFBOARD; the vehicle flies them (body 1 m/s forward with
15 deg/s yaw speed: 50 deg of yaw in 4 s; -5 deg pitch at hover thrust: 0.5-0.8 m forward in
2 s; 10 deg/s yaw rate: 15 deg).

What PX4 accepts (its MAVLink receiver, v1.16):

* SET_POSITION_TARGET_LOCAL_NED in MAV_FRAME_LOCAL_NED (position, velocity, acceleration, each
  unless its type_mask bits say ignore and not NaN) or MAV_FRAME_BODY_NED (velocity and
  acceleration rotated by the heading; position ignored). Another frame: STATUSTEXT CRITICAL
  "SET_POSITION_TARGET_LOCAL_NED coordinate frame N unsupported", no signal. Nothing usable:
  "SET_POSITION_TARGET_LOCAL_NED invalid". An acceleration with the FORCE bit: "... force not
  supported".
* SET_POSITION_TARGET_GLOBAL_INT in MAV_FRAME_GLOBAL_INT (AMSL) or
  MAV_FRAME_GLOBAL_RELATIVE_ALT_INT (above home); another frame: "SET_POSITION_TARGET_GLOBAL_INT
  invalid coordinate frame N".
* SET_ATTITUDE_TARGET: an attitude (quaternion) unless ATTITUDE_IGNORE, body rates when roll
  and pitch rates are not ignored; the thrust (0..1, unless THROTTLE_IGNORE) is flown relative
  to MPC_THR_HOVER.

Yaw (radians) and yaw rate (rad/s) are taken unless ignored. The position-and-velocity kinds are
flown as positions (the velocity only feeds PX4's trajectory forward: not modelled).
"""

from __future__ import annotations

import math
import time
from typing import TYPE_CHECKING, Any

from eaglemission.lab.vehicles.emulator.dialect import M
from eaglemission.lab.vehicles.multicopter.direct import DirectSetpoint

from eaglemission.geometry import R_to_euler, geodetic_to_ned, quat_to_R
from eaglemission.types import GeoPoint, Setpoint

if TYPE_CHECKING:  # the emulator owns these handlers; imported for the annotations only
    from eaglemission.lab.vehicles.emulator.emulator import Px4Emulator

_POS = (M.POSITION_TARGET_TYPEMASK_X_IGNORE, M.POSITION_TARGET_TYPEMASK_Y_IGNORE,
        M.POSITION_TARGET_TYPEMASK_Z_IGNORE)
_VEL = (M.POSITION_TARGET_TYPEMASK_VX_IGNORE, M.POSITION_TARGET_TYPEMASK_VY_IGNORE,
        M.POSITION_TARGET_TYPEMASK_VZ_IGNORE)
_ACC = (M.POSITION_TARGET_TYPEMASK_AX_IGNORE, M.POSITION_TARGET_TYPEMASK_AY_IGNORE,
        M.POSITION_TARGET_TYPEMASK_AZ_IGNORE)
CRITICAL = M.MAV_SEVERITY_CRITICAL
Vec = tuple[float, float, float]


def _field(mask: int, bits: tuple[int, int, int], values: Vec) -> list[float]:
    """Each component unless its ignore bit is set (NaN then)."""
    return [math.nan if mask & b else float(v) for b, v in zip(bits, values)]


def _present(v: list[float]) -> bool:
    return any(math.isfinite(x) for x in v)


def _zero_nan(v: list[float]) -> Vec:
    return (v[0] if math.isfinite(v[0]) else 0.0, v[1] if math.isfinite(v[1]) else 0.0,
            v[2] if math.isfinite(v[2]) else 0.0)


def _yaw(mask: int, yaw_rad: float, yaw_rate_rad_s: float) -> tuple[float | None, float | None]:
    yaw = (None if mask & M.POSITION_TARGET_TYPEMASK_YAW_IGNORE or not math.isfinite(yaw_rad)
           else math.degrees(yaw_rad))
    rate = (None if mask & M.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
            or not math.isfinite(yaw_rate_rad_s) else math.degrees(yaw_rate_rad_s))
    return yaw, rate


def _fly(e: Px4Emulator, name: str, mask: int, pos: list[float], vel: list[float],
         acc: list[float], yaw: float | None, yaw_rate: float | None) -> None:
    """Position (home-relative NED, NaN components: where the vehicle is), else velocity, else
    acceleration: the offboard signal, flown in OFFBOARD."""
    ap = e.autopilot
    if any(math.isinf(v) for v in (*pos, *vel, *acc)):
        return  # an infinite component: no setpoint (NaN means "not given", as on PX4)
    if _present(acc) and mask & M.POSITION_TARGET_TYPEMASK_FORCE_SET:
        e.statustext(f"{name} force not supported", CRITICAL)
        return
    if _present(pos):
        here = e.dyn.estimated_position()
        n, east, d = (p if math.isfinite(p) else h for p, h in zip(pos, here))
        ap.set_setpoint(Setpoint(n, east, d, e.dyn.yaw_setpoint_deg if yaw is None else yaw))
    elif _present(vel):
        ap.set_velocity_setpoint(_zero_nan(vel), yaw, yaw_rate)
    elif _present(acc):
        ap.set_direct_setpoint(DirectSetpoint("acceleration", _zero_nan(acc), yaw, yaw_rate))
    else:
        e.statustext(f"{name} invalid", CRITICAL)
        return
    e.setpoint_wall = time.monotonic()


def on_set_position_target_local_ned(e: Px4Emulator, msg: Any) -> None:
    """Local NED (relative to the EKF origin) or body-frame setpoints."""
    name = "SET_POSITION_TARGET_LOCAL_NED"
    mask = int(msg.type_mask)
    frame = int(msg.coordinate_frame)
    yaw, yaw_rate = _yaw(mask, msg.yaw, msg.yaw_rate)
    vel = _field(mask, _VEL, (msg.vx, msg.vy, msg.vz))
    acc = _field(mask, _ACC, (msg.afx, msg.afy, msg.afz))
    if frame == M.MAV_FRAME_LOCAL_NED:
        hl = e.home_local
        pos = _field(mask, _POS, (msg.x - hl[0], msg.y - hl[1], msg.z - hl[2]))
    elif frame == M.MAV_FRAME_BODY_NED:
        pos = [math.nan] * 3  # PX4 ignores a position in the body frame
        vel = _rotate_body(e, vel) if not any(mask & b for b in _VEL) else [math.nan] * 3
        acc = _rotate_body(e, acc) if not any(mask & b for b in _ACC) else [math.nan] * 3
    else:
        e.statustext(f"{name} coordinate frame {frame} unsupported", CRITICAL)
        return
    _fly(e, name, mask, pos, vel, acc, yaw, yaw_rate)


def _rotate_body(e: Px4Emulator, v: list[float]) -> list[float]:
    """A forward / right / down vector in NED, by the current heading (components ignored in
    the body frame count as 0, as on PX4)."""
    x, y, z = (c if math.isfinite(c) else 0.0 for c in v)
    yaw = math.radians(e.dyn.yaw_deg)
    return [math.cos(yaw) * x - math.sin(yaw) * y, math.sin(yaw) * x + math.cos(yaw) * y, z]


def on_set_position_target_global_int(e: Px4Emulator, msg: Any) -> None:
    """A global position (lat / lon 1e7, AMSL or above home) and / or a NED velocity."""
    name = "SET_POSITION_TARGET_GLOBAL_INT"
    mask = int(msg.type_mask)
    frame = int(msg.coordinate_frame)
    yaw, yaw_rate = _yaw(mask, msg.yaw, msg.yaw_rate)
    pos = [math.nan] * 3
    if not any(mask & b for b in _POS):
        if frame == M.MAV_FRAME_GLOBAL_INT:
            amsl = float(msg.alt)
        elif frame == M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT:
            amsl = e.home.altitude_amsl_m + float(msg.alt)
        elif frame == M.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT:
            return  # PX4 needs a terrain altitude, which SIH has not: ignored silently
        else:
            e.statustext(f"{name} invalid coordinate frame {frame}", CRITICAL)
            return
        n, east, d = geodetic_to_ned(e.home, GeoPoint(msg.lat_int / 1e7, msg.lon_int / 1e7, amsl))
        pos = [n, east, d]
    _fly(e, name, mask, pos, _field(mask, _VEL, (msg.vx, msg.vy, msg.vz)),
         _field(mask, _ACC, (msg.afx, msg.afy, msg.afz)), yaw, yaw_rate)


def on_set_attitude_target(e: Px4Emulator, msg: Any) -> None:
    """An attitude (quaternion) or body rates, with a thrust (0..1) flown relative to the hover
    thrust MPC_THR_HOVER."""
    mask = int(msg.type_mask)
    attitude = not mask & M.ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE
    rates = not mask & (M.ATTITUDE_TARGET_TYPEMASK_BODY_ROLL_RATE_IGNORE
                        | M.ATTITUDE_TARGET_TYPEMASK_BODY_PITCH_RATE_IGNORE)
    if not (attitude or rates):
        return
    thrust = 0.0 if mask & M.ATTITUDE_TARGET_TYPEMASK_THROTTLE_IGNORE else float(msg.thrust)
    ratio = thrust / max(1e-3, e.param("MPC_THR_HOVER")) if math.isfinite(thrust) else 0.0
    yaw_rate = (None if mask & M.ATTITUDE_TARGET_TYPEMASK_BODY_YAW_RATE_IGNORE
                or not math.isfinite(msg.body_yaw_rate) else math.degrees(msg.body_yaw_rate))
    ap = e.autopilot
    if attitude:
        q = tuple(float(x) for x in msg.q)
        if not all(math.isfinite(x) for x in q) or abs(sum(x * x for x in q) - 1.0) > 0.1:
            return
        roll, pitch, yaw = R_to_euler(quat_to_R(q))
        ap.set_direct_setpoint(DirectSetpoint("attitude", (roll, pitch, ratio), yaw, None))
    else:
        p = math.degrees(msg.body_roll_rate) if math.isfinite(msg.body_roll_rate) else 0.0
        q_rate = math.degrees(msg.body_pitch_rate) if math.isfinite(msg.body_pitch_rate) else 0.0
        ap.set_direct_setpoint(DirectSetpoint("rates", (p, q_rate, ratio), None,
                                              yaw_rate if yaw_rate is not None else 0.0))
    e.setpoint_wall = time.monotonic()
