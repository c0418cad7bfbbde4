"""The simulated vehicle's :class:`~eaglemission.types.VehicleState` s: telemetry (the drifting
estimate, what PX4 reports) and truth (what the cameras render from)."""

from __future__ import annotations

import math

from eaglemission.lab.vehicles.autopilot.model import Autopilot
from eaglemission.lab.vehicles.multicopter.dynamics import (
    MulticopterDynamics,
    RangefinderParams,
    rangefinder_reading_m,
)
from eaglemission.lab.vehicles.simulated.truth_log import body_attitude

from eaglemission.geometry import down_axis_cos_tilt, ned_to_geodetic
from eaglemission.types import XYZ, FlightMode, GeoPoint, Quat, VehicleState


def battery_voltage_v(fraction: float) -> float:
    """A 4S LiPo's voltage at a remaining fraction."""
    return 4.0 * (3.5 + 0.7 * fraction)


def estimated_state(dyn: MulticopterDynamics, ap: Autopilot, home: GeoPoint,
                    rangefinder: RangefinderParams, noise: float) -> VehicleState:
    """Telemetry now: the estimated position, the autopilot's flags; the downward range from
    the TRUE pose (``noise``: a standard normal draw)."""
    en, ee, ed = dyn.estimated_position()
    q = body_attitude(dyn.an, dyn.ae, dyn.ad, dyn.yaw_deg, on_ground=dyn.on_ground)
    distance = None
    if rangefinder.enabled:  # the beam follows the TRUE pose
        distance = rangefinder_reading_m(dyn.pd, down_axis_cos_tilt(q), rangefinder, noise)
    return VehicleState(
        timestamp_ns=dyn.time_ns,
        position_ned_m=(en, ee, ed),
        velocity_ned_mps=(dyn.vn, dyn.ve, dyn.vd),
        attitude_q=q,
        angular_velocity_frd_radps=(0.0, 0.0, math.radians(dyn.yaw_rate_degps)),
        geodetic=ned_to_geodetic(home, en, ee, ed),
        relative_altitude_m=-ed,
        home=home,
        armed=ap.armed,
        in_air=ap.in_air,
        flight_mode=ap.mode,
        battery_remaining=ap.battery,
        battery_voltage_v=battery_voltage_v(ap.battery),
        position_valid=ap.position_valid,
        gps_fix=ap.gps_ok,
        link_ok=True,
        armable=not ap.armed and not ap.not_armable_reason(),
        distance_to_ground_m=distance,
    )


def true_state(ap: Autopilot, home: GeoPoint, t: int, pos: XYZ, vel: XYZ, *, attitude_q: Quat,
               armed: bool | None = None, in_air: bool | None = None,
               mode: FlightMode | None = None) -> VehicleState:
    """A TRUE state; flags not given are the autopilot's now."""
    armed = ap.armed if armed is None else armed
    return VehicleState(
        timestamp_ns=t, position_ned_m=pos, velocity_ned_mps=vel, attitude_q=attitude_q,
        geodetic=ned_to_geodetic(home, *pos), relative_altitude_m=-pos[2], home=home,
        armed=armed, in_air=ap.in_air if in_air is None else in_air,
        flight_mode=ap.mode if mode is None else mode,
        battery_remaining=ap.battery, battery_voltage_v=battery_voltage_v(ap.battery),
        position_valid=True, gps_fix=True, link_ok=True, armable=not armed)
