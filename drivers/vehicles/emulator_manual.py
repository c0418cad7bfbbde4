"""MANUAL_CONTROL in the MAVLink emulator: a ground station's virtual sticks, as PX4 v1.16 uses
them with COM_RC_IN_MODE = 1 (stick input from MAVLink only; recorded h1-h3 of
``px4_sitl_tlogs``).

* Without a fresh MANUAL_CONTROL a manual mode (Position, Altitude, Manual...) is refused:
  "Switching to Position is currently not available", ACKs ACCEPTED then TEMPORARILY_REJECTED,
  the vehicle stays in its mode (recorded h1).
* With centred sticks Position mode holds where it is (recorded h3: truth height 3.48 -> 3.47 m
  over 12 s) instead of sinking as it does in a failsafe without sticks (recorded b, i).
* Deflected sticks fly a velocity: pitch / roll (x, y) horizontally in the body frame up to
  MPC_VEL_MANUAL, throttle (z, 500 = centred) up / down at MPC_Z_VEL_MAX_UP / _DN; inside
  PX4's MPC_HOLD_DZ (0.1) deadzone the vehicle brakes and holds.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

from eaglemission.types import FlightMode

if TYPE_CHECKING:  # annotations only
    from eaglemission.drivers.vehicles.autopilot import Autopilot

MANUAL_MODE_NAMES = {FlightMode.POSCTL: "Position", FlightMode.ALTCTL: "Altitude",
                     FlightMode.MANUAL: "Manual", FlightMode.STABILIZED: "Stabilized",
                     FlightMode.ACRO: "Acro"}
"""PX4's names in "Switching to <name> is currently not available"."""
MANUAL_CONTROL_LOSS_S = 0.5
"""[COM_RC_LOSS_T] MANUAL_CONTROL older than this is no manual input."""
HOLD_DEADZONE = 0.1
"""[MPC_HOLD_DZ] stick fraction below which Position mode holds."""


class ManualControlInput:
    """The last MANUAL_CONTROL sticks (fractions: forward, right, up, yaw) and when they came."""

    def __init__(self) -> None:
        self.sticks = (0.0, 0.0, 0.0, 0.0)
        self.time_s = -math.inf
        self._centred_applied = False

    def on_message(self, msg: Any, t_s: float) -> None:
        self.sticks = (float(msg.x) / 1000.0, float(msg.y) / 1000.0,
                       (float(msg.z) - 500.0) / 500.0, float(msg.r) / 1000.0)
        self.time_s = t_s

    def present(self, t_s: float) -> bool:
        return t_s - self.time_s <= MANUAL_CONTROL_LOSS_S

    def apply(self, ap: Autopilot, max_speed_mps: float, up_mps: float, down_mps: float, *,
              force: bool = False) -> None:
        """Fly the sticks (a manual mode with manual input): hold when centred, else a
        velocity; ``force`` re-commands a hold (on entering the mode)."""
        dyn = ap.dyn
        if not ap.armed or dyn.on_ground:
            return
        fwd, right, up, _ = (0.0 if abs(v) < HOLD_DEADZONE else v for v in self.sticks)
        if fwd == right == up == 0.0:
            if force or not self._centred_applied:
                dyn.command_hold(immediate=True)
            self._centred_applied = True
            return
        self._centred_applied = False
        yaw = math.radians(dyn.yaw_deg)
        vn = (fwd * math.cos(yaw) - right * math.sin(yaw)) * max_speed_mps
        ve = (fwd * math.sin(yaw) + right * math.cos(yaw)) * max_speed_mps
        vd = -up * (up_mps if up > 0 else down_mps)
        dyn.command_velocity((vn, ve, vd), immediate=True)
