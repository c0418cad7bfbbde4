"""PX4's orbit (MAV_CMD_DO_ORBIT) in the shared autopilot model: fly a circle around a centre at
a tangential speed, the nose to the centre by default.

Probed on PX4 v1.16 SITL (SIH quad; ``benchmarks/probe_mavsdk_plugins.py``): MAVSDK's
``Action.do_orbit(5 m, 2 m/s, HOLD_FRONT_TO_CIRCLE_CENTER, centre 5 m ahead, NaN altitude)``
is ACCEPTED, the HEARTBEAT shows Position mode with PX4's ORBIT sub mode (custom mode main 3,
sub 1, base_mode 0x91: no manual-input flag; MAVSDK reports POSCTL), the vehicle flies round
the centre at up to 1.75 m/s, turning its nose to the centre (yaw -174 deg over half a circle),
at its altitude. The MAVLink command: param1 radius (its sign is the direction: positive
clockwise seen from above), param2 tangential speed, param3 yaw behaviour, x / y the centre,
z its altitude (NaN: the current one). A radius outside [1 m, MC_ORBIT_RAD_MAX] is refused with
"Orbit radius limit exceeded"; the speed is kept within 10 m/s and a centripetal acceleration
of 2 m/s^2 (PX4's orbit task limits).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from eaglemission.types import XYZ

RADIUS_MIN_M = 1.0
SPEED_MAX_MPS = 10.0
CENTRIPETAL_MAX_MPS2 = 2.0
RADIAL_GAIN_PER_S = 1.0  # how fast the circle is regained (back onto the radius)
SPEED_RAMP_MPS2 = 0.3
"""The tangential speed ramps up at this rate from the start (PX4's orbit is jerk-limited:
probed, 2 m/s asked on a 5 m circle, at most 1.75 m/s and half a circle in 12 s)."""
VERTICAL_GAIN_PER_S = 1.0
FRONT_TO_CENTRE, HOLD_INITIAL_HEADING, UNCONTROLLED, FRONT_TANGENT, RC_CONTROLLED = 0, 1, 2, 3, 4


@dataclass(frozen=True, slots=True)
class Orbit:
    """An orbit under way (NED metres relative to home, estimate frame)."""

    centre_ne_m: tuple[float, float]
    down_m: float
    radius_m: float
    speed_mps: float  # tangential; positive clockwise seen from above
    yaw_behaviour: int = FRONT_TO_CENTRE
    initial_yaw_deg: float = 0.0
    start_ns: int = 0  # model time of the command (the speed ramps up from it)


def sanitized_speed(radius_m: float, speed_mps: float) -> float:
    """The tangential speed within PX4's limits (10 m/s, v^2 / r <= 2 m/s^2), sign kept."""
    limit = min(SPEED_MAX_MPS, math.sqrt(CENTRIPETAL_MAX_MPS2 * radius_m))
    return math.copysign(min(abs(speed_mps), limit), speed_mps)


def orbit_command(orbit: Orbit, position_ned_m: XYZ, time_ns: int) -> tuple[XYZ, float | None]:
    """The NED velocity and yaw (None: keep) that fly ``orbit`` from here at ``time_ns``: the
    tangential speed (ramped up) along the circle plus a radial and a vertical correction."""
    cn, ce = orbit.centre_ne_m
    dn, de = position_ned_m[0] - cn, position_ned_m[1] - ce
    r = math.hypot(dn, de)
    if r < 1e-6:
        un, ue = 1.0, 0.0
    else:
        un, ue = dn / r, de / r
    # clockwise seen from above (north towards east): the bearing from the centre increases
    tn, te = -ue, un
    v_r = RADIAL_GAIN_PER_S * (orbit.radius_m - r)
    ramp = SPEED_RAMP_MPS2 * max(0.0, (time_ns - orbit.start_ns) * 1e-9)
    v_t = math.copysign(min(abs(orbit.speed_mps), ramp), orbit.speed_mps)
    vn = v_t * tn + v_r * un
    ve = v_t * te + v_r * ue
    vd = VERTICAL_GAIN_PER_S * (orbit.down_m - position_ned_m[2])
    yaw: float | None
    if orbit.yaw_behaviour == FRONT_TO_CENTRE:
        yaw = math.degrees(math.atan2(-ue, -un))
    elif orbit.yaw_behaviour == FRONT_TANGENT:
        s = 1.0 if orbit.speed_mps >= 0 else -1.0
        yaw = math.degrees(math.atan2(s * te, s * tn))
    elif orbit.yaw_behaviour == HOLD_INITIAL_HEADING:
        yaw = orbit.initial_yaw_deg
    else:
        yaw = None
    return (vn, ve, vd), yaw
