"""Pure kinematic helpers of the multicopter model: angles, the attitude of a thrust
acceleration, braking. No OpenCV import (the model must stay light)."""

from __future__ import annotations

import math

from eaglemission.types import XYZ, Quat

GRAVITY_MPS2 = 9.80665


def wrap_deg(angle_deg: float) -> float:
    """Wrap to [-180, 180) (same as :func:`eaglemission.geometry.wrap_deg`, kept local so the
    model has no OpenCV import)."""
    return (angle_deg + 180.0) % 360.0 - 180.0


def attitude_from_acceleration(accel_ned_mps2: XYZ, yaw_deg: float) -> Quat:
    """Body FRD -> NED quaternion ``(w, x, y, z)`` of a multicopter whose thrust produces the
    (gravity-compensated) acceleration ``accel_ned_mps2`` with heading ``yaw_deg``.

    The body z axis (down) is opposite to the specific thrust ``a - g``; the body x axis is the
    heading direction projected onto the plane normal to z. Braking while flying north
    (``a_n < 0``) pitches the nose up.
    """
    tn, te, td = accel_ned_mps2[0], accel_ned_mps2[1], accel_ned_mps2[2] - GRAVITY_MPS2
    norm = math.sqrt(tn * tn + te * te + td * td)
    if norm < 1e-6:  # free fall / motors off: report level
        tn, te, td, norm = 0.0, 0.0, -1.0, 1.0
    zx, zy, zz = -tn / norm, -te / norm, -td / norm
    yaw = math.radians(yaw_deg)
    cx, cy = math.cos(yaw), math.sin(yaw)
    # y_b = z_b x x_c, with x_c = (cos yaw, sin yaw, 0)
    yx, yy, yz = -zz * cy, zz * cx, zx * cy - zy * cx
    yn = math.sqrt(yx * yx + yy * yy + yz * yz)
    yx, yy, yz = yx / yn, yy / yn, yz / yn
    # x_b = y_b x z_b
    xx, xy, xz = yy * zz - yz * zy, yz * zx - yx * zz, yx * zy - yy * zx
    # R columns are x_b, y_b, z_b (body -> NED)
    r00, r01, r02 = xx, yx, zx
    r10, r11, r12 = xy, yy, zy
    r20, r21, r22 = xz, yz, zz
    tr = r00 + r11 + r22
    if tr > 0.0:
        s = math.sqrt(tr + 1.0) * 2.0
        w, x, y, z = 0.25 * s, (r21 - r12) / s, (r02 - r20) / s, (r10 - r01) / s
    elif r00 > r11 and r00 > r22:
        s = math.sqrt(1.0 + r00 - r11 - r22) * 2.0
        w, x, y, z = (r21 - r12) / s, 0.25 * s, (r01 + r10) / s, (r02 + r20) / s
    elif r11 > r22:
        s = math.sqrt(1.0 + r11 - r00 - r22) * 2.0
        w, x, y, z = (r02 - r20) / s, (r01 + r10) / s, 0.25 * s, (r12 + r21) / s
    else:
        s = math.sqrt(1.0 + r22 - r00 - r11) * 2.0
        w, x, y, z = (r10 - r01) / s, (r02 + r20) / s, (r12 + r21) / s, 0.25 * s
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if w < 0.0:
        n = -n
    return (w / n, x / n, y / n, z / n)


def stopping_point(position: XYZ, velocity: XYZ, accel_mps2: float) -> XYZ:
    """Where a vehicle braking at ``accel_mps2`` comes to rest: ``p + v |v| / (2 a)``."""
    out = []
    for p, v in zip(position, velocity):
        out.append(p + v * abs(v) / (2.0 * accel_mps2))
    return (out[0], out[1], out[2])
