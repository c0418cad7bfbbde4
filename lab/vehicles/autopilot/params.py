"""The shared autopilot model's parameters, vocabulary and listener (:mod:`.autopilot`)."""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Literal, Protocol

from eaglemission.types import FlightMode

ModeSource = Literal["command", "autopilot", "failsafe", "pilot"]


class FailsafeAction(enum.StrEnum):
    """What a failsafe does (PX4's COM_OBL_RC_ACT / NAV_DLL_ACT / COM_LOW_BAT_ACT choices)."""

    HOLD = "hold"
    LAND = "land"
    RETURN = "return"
    POSITION = "position_no_rc"  # Position mode without RC input: PX4 descends (recorded b)
    ALTITUDE = "altitude_no_rc"
    MANUAL = "manual_no_rc"
    DISARM = "disarm"  # also Terminate

    @classmethod
    def from_com_obl_rc_act(cls, code: int) -> FailsafeAction:
        """COM_OBL_RC_ACT: 0 Position, 1 Altitude, 2 Manual, 3 Return, 4 Land, 5 Hold,
        6 Terminate, 7 Disarm."""
        return {0: cls.POSITION, 1: cls.ALTITUDE, 2: cls.MANUAL, 3: cls.RETURN, 4: cls.LAND,
                5: cls.HOLD}.get(code, cls.DISARM)


MANUAL_ACTION_MODES = {FailsafeAction.POSITION: FlightMode.POSCTL,
                       FailsafeAction.ALTITUDE: FlightMode.ALTCTL,
                       FailsafeAction.MANUAL: FlightMode.MANUAL}


class LandedState(enum.IntEnum):
    """MAV_LANDED_STATE as PX4 reports it in EXTENDED_SYS_STATE."""

    UNDEFINED = 0
    ON_GROUND = 1
    IN_AIR = 2
    TAKEOFF = 3
    LANDING = 4


POSITION_MODES = frozenset({FlightMode.TAKEOFF, FlightMode.HOLD, FlightMode.MISSION,
                            FlightMode.RETURN_TO_LAUNCH, FlightMode.OFFBOARD, FlightMode.POSCTL})
"""Modes that need a position estimate (the GPS-loss failsafe fires in them)."""
PREFLIGHT_EXEMPT = frozenset({FlightMode.TAKEOFF, FlightMode.MISSION, FlightMode.OFFBOARD})
BATTERY_NAMES = {1: "Low", 2: "Critical", 3: "Emergency"}


@dataclass(frozen=True, slots=True, kw_only=True)
class AutopilotParams:
    """The autopilot's parameters (PX4 names in brackets).

    Where the simulated vehicle and the emulator behave differently, a parameter keeps each
    one's behaviour; the value each sets is given as
    ``sim`` / ``emu`` (built by ``simulated_config.autopilot_params`` and
    ``emulator_config.emulator_autopilot_params``; reports/px4_emulator.md has the table).
    """

    home_altitude_amsl_m: float = 489.4
    cruise_speed_mps: float = 5.0  # [MPC_XY_CRUISE] goto, RTL return, mission legs
    takeoff_speed_mps: float = 1.5  # [MPC_TKO_SPEED] takeoff and the mission's first climb
    offboard_max_speed_mps: float = 10.0  # [MPC_XY_VEL_MAX] offboard position setpoints
    takeoff_spoolup_s: float = 1.5  # [COM_SPOOLUP_TIME] from arming; sim 1.5 / emu 1.0
    # (recorded e: liftoff 4.2-4.4 s after arm + takeoff, 3.4-3.9 s when re-armed in LAND)
    takeoff_ramp_s: float = 3.0  # [MPC_TKO_RAMP_T] climb-rate limit ramp; sim 3 / emu 0
    takeoff_accept_below_m: float = 0.3  # TAKEOFF -> HOLD this far below; sim 0.3 / emu NAV_MC_ALT_RAD
    takeoff_accept_above_m: float = 0.3  # ... or above the altitude; sim 0.3 / emu inf
    in_air_altitude_m: float = 0.3  # "Takeoff detected" above this height
    land_detect_s: float = 1.0  # on the ground this long: "Landing detected"
    auto_disarm_after_land_s: float = 2.0  # [COM_DISARM_LAND]
    auto_disarm_preflight_s: float | None = 10.0  # [COM_DISARM_PRFLT]; emu: detect + COM_DISARM_LAND
    preflight_disarm_text: str = "Disarmed by auto preflight disarming"  # emu "Disarmed by landing"
    auto_disarm_spares_climb: bool = False  # True: no auto-disarm while climbing (TAKEOFF,
    # a mission's first climb, an offboard setpoint above 0.3 m); PX4 and both vehicles: False
    # (a takeoff not yet detected when COM_DISARM_LAND runs out is disarmed, as on PX4)
    disarm_restores_intended_mode: bool = False
    """After a disarm: sim False: HOLD; emu True (recorded b): the mode the user intended
    after a failsafe landing, HOLD after LAND / RTL / TAKEOFF, else unchanged."""
    offboard_loss_timeout_s: float = 0.5  # [COM_OF_LOSS_T]
    offboard_loss_action: FailsafeAction = FailsafeAction.HOLD  # [COM_OBL_RC_ACT]
    offboard_loss_land_after_s: float | None = None  # hold, then land after this long
    position_no_rc_descent_mps: float = 0.65  # recorded b: Position mode without RC sinks
    rtl_return_altitude_m: float = 10.0  # [RTL_RETURN_ALT]
    rtl_descend_altitude_m: float = 0.0  # [RTL_DESCEND_ALT] PX4 returns at least this high
    rtl_cone_half_angle_deg: float = 0.0  # [RTL_CONE_ANG] 0: no cone (sim); emu 45
    auto_up_speed_mps: float | None = None  # [MPC_Z_V_AUTO_UP] RTL climb; None: the model's
    auto_down_speed_mps: float | None = None  # [MPC_Z_V_AUTO_DN] RTL descent to land
    auto_approach_gain_per_s: float | None = None
    """Position gain of RTL's climb and return legs (None: the dynamics' own, as an offboard
    setpoint). PX4's auto trajectory (jerk- and acceleration-limited, then slowing toward the
    target) is slower than its offboard loop: recorded f1 / f2 climbed 4.3 -> 10 / 8 m at
    1.15 / 0.82 m/s mean (10-90 %, max 2.09 / 1.42 m/s, never MPC_Z_V_AUTO_UP's 3 m/s) and
    returned 10 m at up to 3.1 m/s (not MPC_XY_CRUISE's 5); the estimate's error to the target
    shrank ~0.5-0.7 /s. emu 0.45 (fitted to f1 / f2), sim None."""
    rtl_land_max_speed_mps: float = 0.5  # RTL lands near home below this speed; emu inf
    rtl_land_radius_m: float = 1.0  # ... this close; emu NAV_ACC_RAD (recorded f1 / f2: "RTL:
    # land at destination" 1.89 / 1.92 m before home, still at 1.3 m/s)
    mission_vertical_acceptance_m: float = 0.8  # [NAV_MC_ALT_RAD]
    mission_acceptance_radius_m: float = 2.0  # [NAV_ACC_RAD] items without their own
    mission_end_brake: bool = False  # emu True: brake where the last item was reached
    gps_loss_failsafe_delay_s: float = 1.0  # [COM_POS_FS_DELAY]
    gps_loss_action: FailsafeAction = FailsafeAction.LAND
    gps_failsafe_text: str | None = None  # emu: a status text before the failsafe's own
    battery_drain_per_s: float = 1.0 / 1200.0
    battery_drain_on_ground: bool = True  # sim: while the motors run; emu: in the air only
    min_arm_battery_fraction: float = 0.15  # emu [BAT_CRIT_THR]
    battery_low_fraction: float | None = None  # [BAT_LOW_THR]; sim None (no low level)
    battery_critical_fraction: float = 0.07  # [BAT_CRIT_THR]
    battery_emergency_fraction: float = 0.05  # [BAT_EMERGEN_THR]
    battery_critical_action: FailsafeAction | None = FailsafeAction.RETURN  # [COM_LOW_BAT_ACT]
    battery_emergency_action: FailsafeAction | None = FailsafeAction.LAND
    battery_warnings: bool = False  # emu True: "Low battery level" etc. status texts
    battery_check_in_flight_only: bool = True  # emu False: levels tracked on the ground too

    def auto_vertical_speeds(self, *, rtl_return: bool = False) -> dict[str, float | None]:
        """The climb / descent limits of autopilot-flown moves (RTL) for ``command_position``
        (``rtl_return``: with the cruise speed of the return leg)."""
        out = {"max_up_speed_mps": self.auto_up_speed_mps,
               "max_down_speed_mps": self.auto_down_speed_mps,
               "gain_per_s": self.auto_approach_gain_per_s}
        return out | {"max_speed_mps": self.cruise_speed_mps} if rtl_return else out


def rtl_altitude_m(p: AutopilotParams, altitude_m: float, distance_m: float) -> float:
    """PX4's return height: RTL_RETURN_ALT, lowered inside the RTL_CONE_ANG cone over home
    (``distance / tan(angle)``), never below RTL_DESCEND_ALT nor the current height
    (recorded f1: 30 / 10 m / 45 deg at 9.9 m from home -> 10 m; f2: 8 / 4 m -> 8 m)."""
    alt = p.rtl_return_altitude_m
    if 0.0 < p.rtl_cone_half_angle_deg < 90.0:
        alt = min(alt, distance_m / math.tan(math.radians(p.rtl_cone_half_angle_deg)))
    return max(altitude_m, p.rtl_descend_altitude_m, alt)


class AutopilotListener(Protocol):
    """Where the autopilot's reports go (the vehicle driving it)."""

    def on_status(self, text: str, severity: str) -> None: ...

    def on_mode(self, old: FlightMode, new: FlightMode, source: ModeSource) -> None: ...

    def on_failsafe(self, reason: str, action: FailsafeAction) -> None: ...

    def on_armed(self, armed: bool) -> None: ...

    def on_mission_item(self, index: int, total: int) -> None: ...

    def on_gps(self, ok: bool) -> None: ...
