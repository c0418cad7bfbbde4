"""MANUAL_CONTROL in the MAVLink emulator: a ground station's virtual sticks, as PX4 v1.16 uses
them with COM_RC_IN_MODE = 1 (stick input from MAVLink only; recorded h1-h3 of
``px4_sitl_tlogs``).

* Without a fresh MANUAL_CONTROL a manual mode (Position, Altitude, Manual...) is refused:
  "Switching to Position is currently not available", ACKs ACCEPTED then TEMPORARILY_REJECTED,
  the vehicle stays in its mode (recorded h1).
* With centred sticks Position mode holds where it is (recorded h3: truth height 3.48 -> 3.47 m
  over 12 s) instead of sinking as it does in a failsafe without sticks (recorded b, i).
* Deflected sticks fly as PX4's default acceleration-based Position mode (MPC_POS_MODE 4):
  pitch / roll (x, y, body frame) through the MPC_XY_MAN_EXPO expo demand an acceleration of
  up to MPC_ACC_HOR against a drag that limits the speed to MPC_VEL_MANUAL; throttle (z, 500 =
  centred) through MPC_Z_MAN_EXPO a climb / sink rate up to MPC_Z_VEL_MAX_UP / _DN; inside
  PX4's MPC_HOLD_DZ (0.1) deadzone the vehicle brakes and holds. Probed (MAVSDK's
  ManualControl, x = 0.5 for 3 s at 10 m): PX4 flew 1.5-2.3 m at up to 1.2 m/s (a stick flown
  straight as a velocity would give 5 m/s, 9.1 m).
* A stream of MANUAL_CONTROL counts as manual input once it has been arriving for
  :data:`MANUAL_CONTROL_SETTLE_S` (probed: Position requested 3 ms after MAVSDK's first
  MANUAL_CONTROL was refused, TEMPORARILY_REJECTED).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from eaglemission.types import FlightMode

if TYPE_CHECKING:  # annotations only
    from eaglemission.lab.vehicles.autopilot.model import Autopilot

MANUAL_MODE_NAMES = {FlightMode.POSCTL: "Position", FlightMode.ALTCTL: "Altitude",
                     FlightMode.MANUAL: "Manual", FlightMode.STABILIZED: "Stabilized",
                     FlightMode.ACRO: "Acro"}
"""PX4's names in "Switching to <name> is currently not available"."""
MANUAL_CONTROL_LOSS_S = 0.5
"""[COM_RC_LOSS_T] MANUAL_CONTROL older than this is no manual input."""
HOLD_DEADZONE = 0.1
"""[MPC_HOLD_DZ] stick fraction below which Position mode holds."""
MANUAL_CONTROL_SETTLE_S = 0.05
"""A new MANUAL_CONTROL stream counts as manual input after this long (PX4's manual-control
selector and Commander take their cycles; probed: 3 ms was not enough)."""


@dataclass(frozen=True, slots=True)
class StickLimits:
    """PX4's parameters of the stick response (names in brackets)."""

    max_speed_mps: float = 10.0  # [MPC_VEL_MANUAL]
    accel_mps2: float = 3.0  # [MPC_ACC_HOR]
    expo: float = 0.6  # [MPC_XY_MAN_EXPO]
    up_mps: float = 3.0  # [MPC_Z_VEL_MAX_UP]
    down_mps: float = 1.5  # [MPC_Z_VEL_MAX_DN]
    z_expo: float = 0.6  # [MPC_Z_MAN_EXPO]


def expo(x: float, e: float) -> float:
    """PX4's stick expo: ``(1 - e) x + e x^3``."""
    return (1.0 - e) * x + e * x * x * x


class ManualControlInput:
    """The last MANUAL_CONTROL sticks (fractions: forward, right, up, yaw) and when they came."""

    def __init__(self) -> None:
        self.sticks = (0.0, 0.0, 0.0, 0.0)
        self.time_s = -math.inf
        self.since_s = math.inf  # when the current stream started
        self._centred_applied = False
        self._v_ne = (0.0, 0.0)  # the acceleration-based mode's velocity setpoint
        self._applied_s = -math.inf

    def on_message(self, msg: Any, t_s: float) -> None:
        if not self.present(t_s, settle_s=0.0):
            self.since_s = t_s
        self.sticks = (float(msg.x) / 1000.0, float(msg.y) / 1000.0,
                       (float(msg.z) - 500.0) / 500.0, float(msg.r) / 1000.0)
        self.time_s = t_s

    def present(self, t_s: float, *, settle_s: float = MANUAL_CONTROL_SETTLE_S) -> bool:
        """Fresh input (within COM_RC_LOSS_T) from a stream older than ``settle_s``."""
        return t_s - self.time_s <= MANUAL_CONTROL_LOSS_S and t_s - self.since_s >= settle_s

    def apply(self, ap: Autopilot, limits: StickLimits, t_s: float, *, force: bool = False) -> None:
        """Fly the sticks (a manual mode with manual input): hold when centred, else PX4's
        acceleration-based response; ``force`` re-commands a hold (on entering the mode)."""
        dyn = ap.dyn
        if not ap.armed or dyn.on_ground:
            return
        fwd, right, up, _ = (0.0 if abs(v) < HOLD_DEADZONE else v for v in self.sticks)
        dt = min(0.2, max(0.0, t_s - self._applied_s))
        self._applied_s = t_s
        if fwd == right == up == 0.0:
            if force or not self._centred_applied:
                dyn.command_hold(immediate=True)
            self._centred_applied = True
            self._v_ne = (0.0, 0.0)
            return
        if self._centred_applied or force:
            self._v_ne = (dyn.vn, dyn.ve)  # from the current motion
        self._centred_applied = False
        yaw = math.radians(dyn.yaw_deg)
        f, r = expo(fwd, limits.expo), expo(right, limits.expo)
        an = (f * math.cos(yaw) - r * math.sin(yaw)) * limits.accel_mps2
        ae = (f * math.sin(yaw) + r * math.cos(yaw)) * limits.accel_mps2
        drag = limits.accel_mps2 / max(0.1, limits.max_speed_mps)  # top speed MPC_VEL_MANUAL
        vn, ve = self._v_ne
        vn += (an - drag * vn) * dt
        ve += (ae - drag * ve) * dt
        self._v_ne = (vn, ve)
        u = expo(up, limits.z_expo)
        vd = -u * (limits.up_mps if u > 0 else limits.down_mps)
        dyn.command_velocity((vn, ve, vd), immediate=True)
