"""The multicopter model's direct modes: an offboard acceleration, attitude or body-rate setpoint
flown without the position and velocity loops (what PX4 v1.16 does with MAVSDK's
``set_acceleration_ned``, ``set_attitude`` and ``set_attitude_rate``; probed, see
:mod:`.emulator_offboard`). Pure: :class:`DirectThrust` keeps the setpoint and gives the thrust
acceleration to command at each step."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from eaglemission.lab.vehicles.multicopter.kinematics import GRAVITY_MPS2

from eaglemission.types import XYZ

MAX_TILT_SETPOINT_DEG = 60.0  # integrated body rates stop here


@dataclass(frozen=True, slots=True)
class DirectSetpoint:
    """An offboard setpoint that is neither a position nor a velocity (PX4 flies it without its
    position and velocity loops): ``acceleration`` (``values``: NED thrust acceleration,
    m/s^2, gravity compensated), ``attitude`` (roll, pitch in degrees, thrust / hover thrust)
    or ``rates`` (roll and pitch body rates in deg/s, thrust / hover thrust); with a yaw or a
    yaw rate (None: keep)."""

    kind: Literal["acceleration", "attitude", "rates"]
    values: tuple[float, float, float]
    yaw_deg: float | None = None
    yaw_rate_degps: float | None = None


def acceleration_from_attitude(roll_deg: float, pitch_deg: float, yaw_deg: float,
                               specific_thrust_mps2: float) -> XYZ:
    """The gravity-compensated thrust acceleration (the model's ``an, ae, ad``) of a body at
    these Euler angles (ZYX) whose thrust gives ``specific_thrust_mps2`` along its -z axis
    (g at hover thrust). Pitching the nose down (negative pitch) accelerates forward.

    >>> [round(v, 3) for v in acceleration_from_attitude(0.0, 0.0, 0.0, GRAVITY_MPS2)]
    [-0.0, -0.0, 0.0]
    >>> round(acceleration_from_attitude(0.0, -5.0, 0.0, GRAVITY_MPS2)[0], 3)
    0.855
    """
    r, p, y = math.radians(roll_deg), math.radians(pitch_deg), math.radians(yaw_deg)
    cr, sr, cp, sp = math.cos(r), math.sin(r), math.cos(p), math.sin(p)
    cy, sy = math.cos(y), math.sin(y)
    zn, ze, zd = cy * sp * cr + sy * sr, sy * sp * cr - cy * sr, cp * cr  # body z axis in NED
    f = specific_thrust_mps2
    return (-f * zn, -f * ze, GRAVITY_MPS2 - f * zd)


def roll_pitch_of_acceleration(accel_ned_mps2: XYZ, yaw_deg: float) -> tuple[float, float]:
    """Roll and pitch (degrees) of a body producing this thrust acceleration at this heading
    (the inverse of :func:`acceleration_from_attitude` for its angles)."""
    y = math.radians(yaw_deg)
    an, ae, ad = accel_ned_mps2
    fwd = math.cos(y) * an + math.sin(y) * ae
    right = -math.sin(y) * an + math.cos(y) * ae
    up = GRAVITY_MPS2 - ad
    return math.degrees(math.atan2(right, math.hypot(fwd, up))), -math.degrees(math.atan2(fwd, up))


class DirectThrust:
    """The setpoint of the direct modes: ``acceleration`` (NED thrust acceleration) or
    ``attitude`` (roll, pitch in degrees and thrust / hover thrust, optionally integrated at
    roll / pitch body rates)."""

    def __init__(self) -> None:
        self.acceleration: XYZ = (0.0, 0.0, 0.0)
        self.attitude: tuple[float, float, float] = (0.0, 0.0, 1.0)
        self.rates: tuple[float, float] | None = None

    def set(self, kind: str, target: XYZ, rates: tuple[float, float] | None, mode: str,
            current_accel: XYZ, yaw_deg: float) -> None:
        """A new setpoint of ``kind`` (``acceleration`` or ``attitude``) while the model is in
        ``mode``; an attitude with body ``rates`` integrates from the current attitude (or from
        the angles reached, when it was already integrating)."""
        if kind == "acceleration":
            self.acceleration = target
            return
        continuing = mode == "attitude"
        if rates is None:
            self.attitude = target
        elif continuing and self.rates is not None:
            self.attitude = (self.attitude[0], self.attitude[1], target[2])
        else:
            roll, pitch = roll_pitch_of_acceleration(current_accel, yaw_deg)
            self.attitude = (roll, pitch, target[2])
        self.rates = rates

    def command(self, mode: str, yaw_deg: float, dt: float) -> XYZ:
        """The thrust acceleration to command now (attitude mode: after ``dt`` of rates)."""
        if mode == "acceleration":
            return self.acceleration
        roll, pitch, thrust = self.attitude
        if self.rates is not None:
            lim = MAX_TILT_SETPOINT_DEG
            roll = max(-lim, min(lim, roll + self.rates[0] * dt))
            pitch = max(-lim, min(lim, pitch + self.rates[1] * dt))
            self.attitude = (roll, pitch, thrust)
        return acceleration_from_attitude(roll, pitch, yaw_deg, GRAVITY_MPS2 * max(0.0, thrust))
