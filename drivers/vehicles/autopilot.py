"""One PX4-like autopilot model, driven by the simulated vehicle and by the MAVLink emulator.

It sits on :class:`~eaglemission.drivers.vehicles.dynamics.MulticopterDynamics` and decides what
PX4 v1.16 decides (recorded in ``../shared/data/px4_sitl_tlogs``): flight modes and their entry
actions, arming, the land detector and auto-disarm, takeoff (spool-up, climb-rate ramp),
hold / goto, land, RTL (climb, return, land), missions (:mod:`.autopilot_mission`), offboard
setpoints and the offboard-loss failsafe, and the GPS, battery and data-link failsafes.

Time is the model's: :meth:`Autopilot.on_step` runs after every internal step of the dynamics
(``dyn.advance_to(t, autopilot.on_step)``), so the simulated vehicle steps it lazily on its
injected clock (virtual time: deterministic) and the emulator in its own thread. What the
autopilot says (status texts, mode changes, failsafes, mission items) goes to an
:class:`AutopilotListener`: the simulated vehicle makes :class:`~eaglemission.types.VehicleEvent`
s of it, the emulator STATUSTEXT, HEARTBEAT and MISSION_* messages.

The two vehicles differed in details before they shared this model; :class:`AutopilotParams`
keeps each one's behaviour where it was observable (``SIMULATED`` / ``EMULATED`` columns of its
docstring), so that aligning both with the recordings is a change of parameters here.

Commands from the client (``source="command"``) take effect after the model's command latency;
the autopilot's own decisions (mode logic, failsafes, a pilot) are immediate and drop the
commands still in flight (the newest command wins, docs/vehicles.md).
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal, Protocol

from eaglemission.drivers.vehicles.autopilot_mission import MissionExecutor, MissionItem
from eaglemission.drivers.vehicles.dynamics import MulticopterDynamics

from eaglemission.types import XYZ, FlightMode, Setpoint

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


_MANUAL_ACTION_MODES = {FailsafeAction.POSITION: FlightMode.POSCTL,
                        FailsafeAction.ALTITUDE: FlightMode.ALTCTL,
                        FailsafeAction.MANUAL: FlightMode.MANUAL}


class LandedState(enum.IntEnum):
    """MAV_LANDED_STATE as PX4 reports it in EXTENDED_SYS_STATE."""

    UNDEFINED = 0
    ON_GROUND = 1
    IN_AIR = 2
    TAKEOFF = 3
    LANDING = 4


MANUAL_MODES = frozenset({FlightMode.MANUAL, FlightMode.ALTCTL, FlightMode.POSCTL,
                          FlightMode.ACRO, FlightMode.STABILIZED})
POSITION_MODES = frozenset({FlightMode.TAKEOFF, FlightMode.HOLD, FlightMode.MISSION,
                            FlightMode.RETURN_TO_LAUNCH, FlightMode.OFFBOARD, FlightMode.POSCTL})
"""Modes that need a position estimate (the GPS-loss failsafe fires in them)."""
_PREFLIGHT_EXEMPT = frozenset({FlightMode.TAKEOFF, FlightMode.MISSION, FlightMode.OFFBOARD})
_BATTERY_NAMES = {1: "Low", 2: "Critical", 3: "Emergency"}


@dataclass(frozen=True, slots=True, kw_only=True)
class AutopilotParams:
    """The autopilot's parameters (PX4 names in brackets).

    Where the simulated vehicle and the emulator behaved differently before they shared this
    model, a parameter keeps each one's behaviour; the value each sets is given as
    ``sim`` / ``emu`` (built by ``simulated.autopilot_params`` and the emulator's
    ``Px4Emulator.autopilot_params``).
    """

    home_altitude_amsl_m: float = 489.4
    cruise_speed_mps: float = 5.0  # [MPC_XY_CRUISE] goto, RTL return, mission legs
    takeoff_speed_mps: float = 1.5  # [MPC_TKO_SPEED] takeoff and the mission's first climb
    offboard_max_speed_mps: float = 10.0  # [MPC_XY_VEL_MAX] offboard position setpoints
    takeoff_spoolup_s: float = 1.5  # on the ground only; sim 1.5 / emu 1.0 (recorded: ~1.8 s)
    takeoff_ramp_s: float = 3.0  # [MPC_TKO_RAMP_T] climb-rate limit ramp; sim 3 / emu 0
    takeoff_accept_below_m: float = 0.3  # TAKEOFF -> HOLD this far below; sim 0.3 / emu NAV_MC_ALT_RAD
    takeoff_accept_above_m: float = 0.3  # ... or above the altitude; sim 0.3 / emu inf
    in_air_altitude_m: float = 0.3  # "Takeoff detected" above this height
    land_detect_s: float = 1.0  # on the ground this long: "Landing detected"
    auto_disarm_after_land_s: float = 2.0  # [COM_DISARM_LAND]
    auto_disarm_preflight_s: float | None = 10.0  # [COM_DISARM_PRFLT]; emu: detect + COM_DISARM_LAND
    preflight_disarm_text: str = "Disarmed by auto preflight disarming"  # emu "Disarmed by landing"
    auto_disarm_spares_climb: bool = False  # emu True: no auto-disarm while climbing
    # (TAKEOFF, a mission's first climb, an offboard setpoint above 0.3 m)
    disarm_restores_intended_mode: bool = False
    """After a disarm: sim False: HOLD; emu True (recorded b): the mode the user intended
    after a failsafe landing, HOLD after LAND / RTL / TAKEOFF, else unchanged."""
    offboard_loss_timeout_s: float = 0.5  # [COM_OF_LOSS_T]
    offboard_loss_action: FailsafeAction = FailsafeAction.HOLD  # [COM_OBL_RC_ACT]
    offboard_loss_land_after_s: float | None = None  # hold, then land after this long
    position_no_rc_descent_mps: float = 0.65  # recorded b: Position mode without RC sinks
    rtl_return_altitude_m: float = 10.0  # [RTL_RETURN_ALT]
    rtl_land_max_speed_mps: float = 0.5  # RTL lands within 1 m of home below this speed; emu inf
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


class AutopilotListener(Protocol):
    """Where the autopilot's reports go (the vehicle driving it)."""

    def on_status(self, text: str, severity: str) -> None: ...

    def on_mode(self, old: FlightMode, new: FlightMode, source: ModeSource) -> None: ...

    def on_failsafe(self, reason: str, action: FailsafeAction) -> None: ...

    def on_armed(self, armed: bool) -> None: ...

    def on_mission_item(self, index: int, total: int) -> None: ...

    def on_gps(self, ok: bool) -> None: ...


class Autopilot:
    """The PX4-like decision layer on top of the dynamics (see the module docstring).

    The drivers check what they refuse (arming when not armable, takeoff while disarmed...) in
    their own words and call the commands here once a command is accepted.
    """

    def __init__(self, dyn: MulticopterDynamics, params: AutopilotParams,
                 listener: AutopilotListener) -> None:
        self.dyn = dyn
        self.params = params
        self.listener = listener
        self.mode = FlightMode.HOLD
        self.intended_mode = FlightMode.HOLD  # what the user chose (failsafes do not change it)
        self.armed = False
        self.in_air = False  # the land detector's verdict
        self.failsafe_active = False
        self.manual_input = False  # a pilot with centred sticks holds Position/Altitude mode
        self.offboard_active = False  # a client's offboard session (ended by other commands)
        self.gripper: Literal["unknown", "grab", "release"] = "unknown"
        self.battery = 1.0
        self.mission = MissionExecutor(self)
        self.setpoint: Setpoint | None = None  # latest offboard position setpoint...
        self.setpoint_velocity: tuple[XYZ, float | None] | None = None  # ...or velocity + yaw
        self.setpoint_ns = 0
        self.offboard_signal_grace: Callable[[], bool] | None = None  # emulator: wall-time guard
        self._battery_level = 0  # 0 ok, 1 low, 2 critical, 3 emergency (handled)
        self._taking_off = False  # a climb from the ground (MAV_LANDED_STATE_TAKEOFF)
        self._ground_since_ns: int | None = None
        self._landed_ns: int | None = None
        self._flew_since_arm = False
        self._armed_ns = 0
        self._takeoff_alt_m = 0.0
        self._takeoff_go_ns = 0
        self._takeoff_climbing = False
        self._takeoff_origin: tuple[float, float] = (0.0, 0.0)
        self.rtl_phase: Literal["climb", "return", "land"] = "climb"
        self._rtl_alt_m = 0.0
        self._goto: tuple[Setpoint, float | None] | None = None
        self._failsafe_hold_until_ns: int | None = None
        self._gps_down_until_ns: int | None = None
        self._gps_down_since_ns = 0
        self._gps_failsafe_done = False

    # ------------------------------------------------------------------------------------------
    # state
    # ------------------------------------------------------------------------------------------
    @property
    def gps_ok(self) -> bool:
        return self._gps_down_until_ns is None

    @property
    def position_valid(self) -> bool:
        """False once GPS has been lost for ``gps_loss_failsafe_delay_s``."""
        if self._gps_down_until_ns is None:
            return True
        return ((self.dyn.time_ns - self._gps_down_since_ns)
                < self.params.gps_loss_failsafe_delay_s * 1e9)

    def not_armable_reason(self) -> str:
        if not self.gps_ok:
            return "no GPS fix"
        if self.battery < self.params.min_arm_battery_fraction:
            return f"battery low ({self.battery:.0%})"
        if not self.dyn.on_ground:
            return "not landed"
        return ""

    @property
    def landed_state(self) -> LandedState:
        """MAV_LANDED_STATE: taking off, in the air, landing (LAND, RTL's descent), on the
        ground."""
        if not self.armed:
            return LandedState.ON_GROUND
        if self._taking_off:
            return LandedState.TAKEOFF
        if not self.in_air:
            return LandedState.ON_GROUND
        if self.mode == FlightMode.LAND or (self.mode == FlightMode.RETURN_TO_LAUNCH
                                            and self.rtl_phase == "land"):
            return LandedState.LANDING
        return LandedState.IN_AIR

    def offboard_signal(self) -> bool:
        """PX4's offboard signal: a setpoint within COM_OF_LOSS_T."""
        if self.setpoint is None and self.setpoint_velocity is None:
            return False
        if self.dyn.time_ns - self.setpoint_ns <= self.params.offboard_loss_timeout_s * 1e9:
            return True
        return self.offboard_signal_grace is not None and self.offboard_signal_grace()

    def status(self, text: str, severity: str = "info") -> None:
        self.listener.on_status(text, severity)

    # ------------------------------------------------------------------------------------------
    # commands (accepted by the driver)
    # ------------------------------------------------------------------------------------------
    def arm(self) -> None:
        self.armed = True
        self._armed_ns = self.dyn.time_ns
        self._flew_since_arm = False
        self._landed_ns = None
        self.dyn.set_motors(True)
        self.status("Armed by external command")
        self.listener.on_armed(True)

    def start_airborne(self) -> None:
        """Armed and hovering (a simulation starting in the air)."""
        dyn = self.dyn
        self.armed = True
        self.in_air = True
        self._flew_since_arm = True
        dyn.set_motors(True)
        dyn.an = dyn.ae = dyn.ad = 0.0
        dyn.on_ground = False

    def disarm(self, text: str) -> None:
        self.armed = False
        self.in_air = False
        self._taking_off = False
        self.dyn.set_motors(False)
        self.offboard_active = False
        self.status(text)
        self.listener.on_armed(False)
        failsafe, self.failsafe_active = self.failsafe_active, False
        if self.params.disarm_restores_intended_mode:
            if failsafe:  # recorded b: back to the mode the user intended
                self.set_mode(self.intended_mode, "autopilot")
            elif self.mode in (FlightMode.LAND, FlightMode.RETURN_TO_LAUNCH, FlightMode.TAKEOFF):
                self.set_mode(FlightMode.HOLD, "autopilot")
        elif self.mode != FlightMode.HOLD:
            self.set_mode(FlightMode.HOLD, "autopilot")

    def takeoff(self, altitude_m: float) -> None:
        dyn = self.dyn
        est = dyn.estimated_position()
        self._takeoff_alt_m = float(altitude_m)
        self._takeoff_origin = (est[0], est[1])
        spool = self.params.takeoff_spoolup_s if dyn.on_ground else 0.0
        self._takeoff_go_ns = dyn.time_ns + int(round(spool * 1e9))
        self._takeoff_climbing = False
        self._by_command()
        self.set_mode(FlightMode.TAKEOFF, "command")

    def goto(self, target: Setpoint, speed_mps: float | None = None) -> None:
        """PX4 DO_REPOSITION: HOLD (AUTO.LOITER) flying to ``target``."""
        self._by_command()
        self.set_mode(FlightMode.HOLD, "command")
        self.dyn.command_position(target, max_speed_mps=speed_mps)
        self._goto = (target, speed_mps)

    def change_speed(self, speed_mps: float | None) -> None:
        """DO_CHANGE_SPEED: the speed of the mission legs from now on, and of a goto under way."""
        self.mission.speed_mps = speed_mps
        if self.mode == FlightMode.HOLD and self._goto is not None:
            self._goto = (self._goto[0], speed_mps)
            self.dyn.command_position(self._goto[0], max_speed_mps=speed_mps, immediate=True)

    def hold(self, source: ModeSource = "command") -> None:
        if source == "command":
            self._by_command()
        self._goto = None
        self.set_mode(FlightMode.HOLD, source)
        if self.armed and not self.dyn.on_ground:
            self.dyn.command_hold(immediate=source != "command")

    def land(self, source: ModeSource = "command") -> None:
        if source == "command":
            self._by_command()
        self.set_mode(FlightMode.LAND, source)
        self.dyn.command_land(immediate=source != "command")

    def return_to_launch(self) -> None:
        self._by_command()
        self.start_rtl("command")

    def start_mission(self, first: int | None = None) -> None:
        self.mission.begin(first)
        self._by_command()
        self.set_mode(FlightMode.MISSION, "command")
        self.status("Executing Mission")
        self.mission.start_logic()

    def upload_mission(self, items: tuple[MissionItem, ...]) -> None:
        self.mission.load(items)
        if self.mode == FlightMode.MISSION:
            self.mission.start_logic()

    def store_setpoint(self, setpoint: Setpoint) -> None:
        """An offboard position setpoint arrived (flown only in OFFBOARD)."""
        self.setpoint = setpoint
        self.setpoint_velocity = None
        self.setpoint_ns = self.dyn.time_ns

    def set_setpoint(self, setpoint: Setpoint) -> None:
        self.store_setpoint(setpoint)
        if self.mode == FlightMode.OFFBOARD:
            self._command_offboard()

    def set_velocity_setpoint(self, velocity_ned_mps: XYZ, yaw_deg: float | None) -> None:
        self.setpoint = None
        self.setpoint_velocity = (velocity_ned_mps, yaw_deg)
        self.setpoint_ns = self.dyn.time_ns
        if self.mode == FlightMode.OFFBOARD:
            self._command_offboard()

    def start_offboard(self, initial: Setpoint) -> None:
        """The client's offboard session starts with its first setpoint."""
        self.store_setpoint(initial)
        self.offboard_active = True
        self.enter_offboard()

    def enter_offboard(self) -> None:
        """DO_SET_MODE OFFBOARD (the driver checked :meth:`offboard_signal`)."""
        self.failsafe_active = False
        self.manual_input = False
        self.set_mode(FlightMode.OFFBOARD, "command")
        self._command_offboard()

    def stop_offboard(self) -> None:
        """Ends the client's session; outside OFFBOARD nothing else changes."""
        self.offboard_active = False
        if self.mode == FlightMode.OFFBOARD:
            self.set_mode(FlightMode.HOLD, "command")
            if self.armed:
                self.dyn.command_hold()

    def enter_manual(self, mode: FlightMode, source: ModeSource) -> None:
        """Position / Altitude / Manual... by a ground station (no RC input: PX4 sinks) or a pilot
        (sticks centred: holds)."""
        self.manual_input = source == "pilot"
        if source == "command":
            self.offboard_active = False
        self.set_mode(mode, source)
        if self.armed and not self.dyn.on_ground:
            if self.manual_input:
                self.dyn.command_hold(immediate=True)
            else:
                self.dyn.command_velocity((0.0, 0.0, self.params.position_no_rc_descent_mps),
                                          immediate=True)

    def pilot_take_control(self, mode: FlightMode) -> None:
        """A pilot or ground station switches the mode (manual modes hold: sticks centred)."""
        dyn = self.dyn
        if mode == FlightMode.RETURN_TO_LAUNCH and self.armed and self.in_air:
            self.start_rtl("pilot")
            return
        self.manual_input = mode in MANUAL_MODES
        self.set_mode(mode, "pilot")
        if not self.armed or dyn.on_ground:
            return
        if mode == FlightMode.LAND:
            dyn.command_land(immediate=True)
        elif mode == FlightMode.MISSION and self.mission.items:
            self.mission.start_logic()
        elif mode != FlightMode.OFFBOARD:
            dyn.command_hold(immediate=True)

    def start_rtl(self, source: ModeSource) -> None:
        """RTL: climb to RTL_RETURN_ALT (or stay higher), return at cruise speed, land."""
        dyn = self.dyn
        alt = -dyn.estimated_position()[2]
        self._rtl_alt_m = max(alt, self.params.rtl_return_altitude_m)
        self.rtl_phase = "climb"
        self.set_mode(FlightMode.RETURN_TO_LAUNCH, source)
        self.status(f"RTL: start return at {self.params.home_altitude_amsl_m + self._rtl_alt_m:.0f} m "
                    f"({self._rtl_alt_m:.0f} m above destination)")
        e = dyn.estimated_position()
        dyn.command_position(Setpoint(e[0], e[1], -self._rtl_alt_m, dyn.yaw_deg), immediate=True)

    def failsafe(self, reason: str, action: FailsafeAction) -> None:
        dyn = self.dyn
        self.failsafe_active = True
        self.status("Failsafe activated", severity="critical")
        self.listener.on_failsafe(reason, action)
        if action == FailsafeAction.HOLD:
            self.set_mode(FlightMode.HOLD, "failsafe")
            dyn.command_hold(immediate=True)
        elif action == FailsafeAction.LAND:
            self.set_mode(FlightMode.LAND, "failsafe")
            dyn.command_land(immediate=True)
        elif action == FailsafeAction.RETURN:
            self.start_rtl("failsafe")
        elif action in _MANUAL_ACTION_MODES:
            # PX4 without RC (COM_OBL_RC_ACT=0, recorded b): the mode cannot run its flight
            # task and the vehicle descends (~0.65 m/s) until it lands and disarms.
            self.manual_input = False
            self.set_mode(_MANUAL_ACTION_MODES[action], "failsafe")
            dyn.command_velocity((0.0, 0.0, self.params.position_no_rc_descent_mps), immediate=True)
        else:
            self.disarm("Disarmed by failsafe")

    def gps_loss(self, duration_s: float) -> bool:
        """No GPS for ``duration_s`` (extends a loss under way); True when it starts now."""
        t = self.dyn.time_ns
        started = self._gps_down_until_ns is None
        if started:
            self._gps_down_since_ns = t
            self._gps_failsafe_done = False
            self.dyn.estimate_model.set_gps(False)
        self._gps_down_until_ns = t + int(round(duration_s * 1e9))
        return started

    def set_battery(self, fraction: float) -> None:
        """The remaining battery (0..1); the levels already handled above it are forgotten."""
        self.battery = float(fraction)
        self._battery_level = min(self._battery_level, self._battery_level_of(self.battery))

    def climbing_from_ground(self) -> None:
        if not self.in_air:
            self._taking_off = True

    def climb_done(self) -> None:
        self._taking_off = False

    def set_mode(self, mode: FlightMode, source: ModeSource) -> None:
        old = self.mode
        self._failsafe_hold_until_ns = None
        self._taking_off = False
        if not self.failsafe_active:
            self.intended_mode = mode
        if mode == old:
            return
        self.mode = mode
        self.listener.on_mode(old, mode, source)

    def _by_command(self) -> None:
        self.offboard_active = False
        self.manual_input = False

    def _command_offboard(self) -> None:
        """PX4 flies an offboard position setpoint at its own maximum speed."""
        if self.setpoint is not None:
            self.dyn.command_position(self.setpoint, max_speed_mps=self.params.offboard_max_speed_mps)
        elif self.setpoint_velocity is not None:
            v, yaw = self.setpoint_velocity
            self.dyn.command_velocity(v, yaw)

    # ------------------------------------------------------------------------------------------
    # the model, after every internal step of the dynamics
    # ------------------------------------------------------------------------------------------
    def on_step(self, dyn: MulticopterDynamics) -> None:
        t = dyn.time_ns
        self._gps_step(t)
        self._battery_step()
        if self.armed:
            self._land_detector(t)
        if self.armed:
            mode = self.mode
            if mode == FlightMode.TAKEOFF:
                self._step_takeoff(t)
            elif mode == FlightMode.MISSION:
                self.mission.step()
            elif mode == FlightMode.RETURN_TO_LAUNCH:
                self._step_rtl()
            elif mode == FlightMode.OFFBOARD:
                if not self.offboard_signal():
                    p = self.params
                    self.failsafe("Offboard setpoints lost", p.offboard_loss_action)
                    if (p.offboard_loss_action == FailsafeAction.HOLD
                            and p.offboard_loss_land_after_s is not None):
                        self._failsafe_hold_until_ns = t + int(round(p.offboard_loss_land_after_s * 1e9))
            elif mode == FlightMode.HOLD and self._failsafe_hold_until_ns is not None:
                if t >= self._failsafe_hold_until_ns and self.in_air:
                    self._failsafe_hold_until_ns = None
                    self.set_mode(FlightMode.LAND, "failsafe")
                    dyn.command_land(immediate=True)

    def _gps_step(self, t: int) -> None:
        if self._gps_down_until_ns is None:
            return
        if t >= self._gps_down_until_ns:
            self._gps_down_until_ns = None
            self.dyn.estimate_model.set_gps(True)
            self.listener.on_gps(True)
        elif (not self._gps_failsafe_done
              and t - self._gps_down_since_ns >= self.params.gps_loss_failsafe_delay_s * 1e9):
            self._gps_failsafe_done = True
            if self.armed and self.in_air and self.mode in POSITION_MODES:
                if self.params.gps_failsafe_text:
                    self.status(self.params.gps_failsafe_text, "critical")
                self.failsafe("No valid position estimate (GPS lost)", self.params.gps_loss_action)

    def _battery_level_of(self, fraction: float) -> int:
        p = self.params
        if fraction <= p.battery_emergency_fraction:
            return 3
        if fraction <= p.battery_critical_fraction:
            return 2
        return int(p.battery_low_fraction is not None and fraction <= p.battery_low_fraction)

    def _battery_step(self) -> None:
        dyn, p = self.dyn, self.params
        if dyn.motors_on and (p.battery_drain_on_ground or self.in_air):
            self.battery = max(0.0, self.battery - p.battery_drain_per_s * dyn.dt_s)
        flying = self.armed and self.in_air
        if p.battery_check_in_flight_only and not flying:
            return
        level = self._battery_level_of(self.battery)
        if level <= self._battery_level:
            return
        self._battery_level = level
        if p.battery_warnings:
            self.status(f"{_BATTERY_NAMES[level]} battery level", "warning")
        if not flying:
            return
        if level == 3 and p.battery_emergency_action is not None:
            self.failsafe("Battery level emergency", p.battery_emergency_action)
        elif level >= 2 and p.battery_critical_action is not None:
            self.failsafe("Battery level critical", p.battery_critical_action)

    def _climbing(self) -> bool:
        """What PX4 must not auto-disarm in (the emulator's rule)."""
        if self.mode == FlightMode.TAKEOFF:
            return True
        if self.mode == FlightMode.MISSION:
            return self.mission.climbing()
        return (self.mode == FlightMode.OFFBOARD and self.setpoint is not None
                and self.setpoint.down_m < -0.3)

    def _land_detector(self, t: int) -> None:
        dyn, p = self.dyn, self.params
        if not dyn.on_ground and -dyn.pd >= p.in_air_altitude_m and not self.in_air:
            self.in_air = True
            self._flew_since_arm = True
            self._ground_since_ns = None
            self.status("Takeoff detected")
        if dyn.on_ground:
            if self._ground_since_ns is None:
                self._ground_since_ns = t
            if self.in_air and t - self._ground_since_ns >= p.land_detect_s * 1e9:
                self.in_air = False
                self._landed_ns = t
                self.status("Landing detected")
        else:
            self._ground_since_ns = None
        spared = p.auto_disarm_spares_climb and self._climbing()
        if (self._landed_ns is not None and not self.in_air and not spared
                and t - self._landed_ns >= p.auto_disarm_after_land_s * 1e9):
            self._landed_ns = None
            self.disarm("Disarmed by landing")
        elif (p.auto_disarm_preflight_s is not None and not self._flew_since_arm and dyn.on_ground
              and not (spared if p.auto_disarm_spares_climb else self.mode in _PREFLIGHT_EXEMPT)
              and t - self._armed_ns >= p.auto_disarm_preflight_s * 1e9):
            self.disarm(p.preflight_disarm_text)

    def _step_takeoff(self, t: int) -> None:
        if t < self._takeoff_go_ns:
            return  # motors spooling up
        dyn, p = self.dyn, self.params
        n, e = self._takeoff_origin
        ramp_s = p.takeoff_ramp_s
        elapsed_s = (t - self._takeoff_go_ns) * 1e-9
        if not self._takeoff_climbing or elapsed_s <= ramp_s:
            # PX4 ramps the climb-rate limit up to MPC_TKO_SPEED over MPC_TKO_RAMP_T
            self._takeoff_climbing = True
            self.climbing_from_ground()
            k = 1.0 if ramp_s <= 0 else max(0.05, min(1.0, elapsed_s / ramp_s))
            dyn.command_position(Setpoint(n, e, -self._takeoff_alt_m, dyn.yaw_deg),
                                 max_up_speed_mps=k * p.takeoff_speed_mps, immediate=True)
            return
        off = -dyn.estimated_position()[2] - self._takeoff_alt_m
        if -p.takeoff_accept_below_m <= off <= p.takeoff_accept_above_m:
            self.set_mode(FlightMode.HOLD, "autopilot")  # PX4: TAKEOFF -> AUTO.LOITER

    def _step_rtl(self) -> None:
        dyn = self.dyn
        e = dyn.estimated_position()
        if self.rtl_phase == "climb":
            if -e[2] >= self._rtl_alt_m - 0.5:
                self.rtl_phase = "return"
                yaw = math.degrees(math.atan2(-e[1], -e[0])) if math.hypot(e[0], e[1]) > 1.0 else dyn.yaw_deg
                dyn.command_position(Setpoint(0.0, 0.0, -self._rtl_alt_m, yaw),
                                     max_speed_mps=self.params.cruise_speed_mps, immediate=True)
        elif self.rtl_phase == "return":
            if (math.hypot(e[0], e[1]) <= 1.0
                    and math.hypot(dyn.vn, dyn.ve) < self.params.rtl_land_max_speed_mps):
                self.rtl_phase = "land"
                self.status("RTL: land at destination")
                dyn.command_land(immediate=True)
