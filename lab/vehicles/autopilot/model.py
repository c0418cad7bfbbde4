"""One PX4-like autopilot model, driven by the simulated vehicle and by the MAVLink emulator.

It sits on :class:`~eaglemission.lab.vehicles.multicopter.dynamics.MulticopterDynamics` and decides what
PX4 v1.16 decides (recorded in ``../shared/data/px4_sitl_tlogs``): flight modes and their entry
actions, arming, the land detector and auto-disarm, takeoff (spool-up, climb-rate ramp),
hold / goto, land, RTL (climb, return, land), missions (:mod:`.autopilot_mission`), offboard
setpoints and the offboard-loss failsafe, the GPS and battery failsafes, and one
:meth:`Autopilot.failsafe` for every cause (the drivers detect a lost data link their own way
and call it).

Time is the model's: :meth:`Autopilot.on_step` runs after every internal step of the dynamics
(``dyn.advance_to(t, autopilot.on_step)``), so the simulated vehicle steps it lazily on its
injected clock (virtual time: deterministic) and the emulator in its own thread. What the
autopilot says (status texts, mode changes, failsafes, mission items) goes to an
:class:`AutopilotListener`: the simulated vehicle makes :class:`~eaglemission.types.VehicleEvent`
s of it, the emulator STATUSTEXT, HEARTBEAT and MISSION_* messages.

The two vehicles differ in details; :class:`AutopilotParams` keeps each one's behaviour where
it is observable (its fields say what each vehicle sets;
reports/px4_emulator.md has the table next to the recorded PX4), so that aligning both with the
recordings is a change of parameters.

Commands from the client (``source="command"``) take effect after the model's command latency;
the autopilot's own decisions (mode logic, failsafes, a pilot) are immediate and drop the
commands still in flight (the newest command wins, docs/simulation.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Literal

from eaglemission.drivers.vehicles.px4 import MANUAL_MODES
from eaglemission.lab.vehicles.autopilot.mission import MissionExecutor, MissionItem
from eaglemission.lab.vehicles.autopilot.monitors import (
    BatteryMonitor,
    GpsMonitor,
    LandDetector,
)
from eaglemission.lab.vehicles.autopilot.orbit import Orbit, orbit_command
from eaglemission.lab.vehicles.autopilot.params import (
    MANUAL_ACTION_MODES,
    AutopilotListener,
    AutopilotParams,
    FailsafeAction,
    LandedState,
    ModeSource,
    rtl_altitude_m,
)
from eaglemission.lab.vehicles.multicopter.direct import DirectSetpoint
from eaglemission.lab.vehicles.multicopter.dynamics import MulticopterDynamics

from eaglemission.types import XYZ, FlightMode, Setpoint

__all__ = ["Autopilot", "AutopilotListener", "AutopilotParams", "DirectSetpoint", "FailsafeAction",
           "LandedState", "MissionItem", "ModeSource", "Orbit"]


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
        self.failsafe_active = False
        self.manual_input = False  # a pilot with centred sticks holds Position/Altitude mode
        self.offboard_active = False  # a client's offboard session (ended by other commands)
        self.gripper: Literal["unknown", "grab", "release"] = "unknown"
        self.mission = MissionExecutor(self)
        self.setpoint: Setpoint | None = None  # latest offboard position setpoint...
        self.setpoint_velocity: tuple[XYZ, float | None] | None = None  # ...or velocity + yaw
        self.setpoint_yaw_rate: float | None = None  # ... turning at this rate (no yaw given)
        self.setpoint_direct: DirectSetpoint | None = None  # ...or acceleration / attitude
        self.setpoint_ns = 0
        self.orbit: Orbit | None = None  # an orbit under way (PX4: Position mode, ORBIT)
        self.offboard_signal_grace: Callable[[], bool] | None = None  # emulator: wall-time guard
        self.offboard_failover = False  # in an offboard-loss failsafe the signal's return clears
        self._taking_off = False  # a climb from the ground (MAV_LANDED_STATE_TAKEOFF)
        self._takeoff_alt_m = 0.0
        self._takeoff_go_ns = 0
        self._takeoff_climbing = False
        self._takeoff_origin: tuple[float, float] = (0.0, 0.0)
        self.rtl_phase: Literal["climb", "return", "land"] = "climb"
        self._rtl_alt_m = 0.0
        self._goto: tuple[Setpoint, float | None] | None = None
        self._failsafe_hold_until_ns: int | None = None
        self.land_detector = LandDetector(self)
        self.gps = GpsMonitor(self)
        self.power = BatteryMonitor(self)

    @property
    def in_air(self) -> bool:
        """The land detector's verdict."""
        return self.land_detector.in_air

    @property
    def battery(self) -> float:
        """Remaining battery, 0..1."""
        return self.power.fraction

    @property
    def gps_ok(self) -> bool:
        return self.gps.ok

    @property
    def position_valid(self) -> bool:
        """False once GPS has been lost for ``gps_loss_failsafe_delay_s``."""
        return self.gps.position_valid()

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
        if self.setpoint is None and self.setpoint_velocity is None and self.setpoint_direct is None:
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
        self.land_detector.on_arm(self.dyn.time_ns)
        self.dyn.set_motors(True)
        self.status("Armed by external command")
        self.listener.on_armed(True)
        if self.mode == FlightMode.TAKEOFF:  # takeoff selected while disarmed: it flies now
            self.takeoff(self._takeoff_alt_m)

    def start_airborne(self) -> None:
        """Armed and hovering (a simulation starting in the air)."""
        dyn = self.dyn
        self.armed = True
        self.land_detector.airborne()
        dyn.set_motors(True)
        dyn.an = dyn.ae = dyn.ad = 0.0
        dyn.on_ground = False

    def disarm(self, text: str) -> None:
        self.armed = False
        self.land_detector.in_air = False
        self._taking_off = False
        self.orbit = None
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
        # the motors spool up once after arming (COM_SPOOLUP_TIME): armed on the ground for
        # longer already (re-armed right after a landing, recorded e), the climb starts at once
        spool_end_ns = self.land_detector.armed_ns + int(round(self.params.takeoff_spoolup_s * 1e9))
        self._takeoff_go_ns = max(dyn.time_ns, spool_end_ns) if dyn.on_ground else dyn.time_ns
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
        if self.mode == FlightMode.MISSION and items:
            self.mission.start_logic()

    def store_setpoint(self, setpoint: Setpoint) -> None:
        """An offboard position setpoint arrived (flown only in OFFBOARD)."""
        self.setpoint = setpoint
        self.setpoint_velocity = None
        self.setpoint_direct = None
        self.setpoint_ns = self.dyn.time_ns

    def set_setpoint(self, setpoint: Setpoint) -> None:
        self.store_setpoint(setpoint)
        if self.mode == FlightMode.OFFBOARD:
            self._command_offboard()

    def set_velocity_setpoint(self, velocity_ned_mps: XYZ, yaw_deg: float | None,
                              yaw_rate_degps: float | None = None) -> None:
        self.setpoint = None
        self.setpoint_direct = None
        self.setpoint_velocity = (velocity_ned_mps, yaw_deg)
        self.setpoint_yaw_rate = yaw_rate_degps if yaw_deg is None else None
        self.setpoint_ns = self.dyn.time_ns
        if self.mode == FlightMode.OFFBOARD:
            self._command_offboard()

    def set_direct_setpoint(self, setpoint: DirectSetpoint) -> None:
        """An offboard acceleration, attitude or body-rate setpoint (flown only in OFFBOARD)."""
        self.setpoint = None
        self.setpoint_velocity = None
        self.setpoint_direct = setpoint
        self.setpoint_ns = self.dyn.time_ns
        if self.mode == FlightMode.OFFBOARD:
            self._command_offboard()

    def start_orbit(self, orbit: Orbit) -> None:
        """DO_ORBIT: Position mode flying ``orbit`` (PX4's ORBIT sub mode of Position)."""
        self._by_command()
        self.set_mode(FlightMode.POSCTL, "command")
        self.orbit = orbit

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
        self.offboard_failover = self.failsafe_active = False  # the user's intent: a takeover
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
        self.offboard_failover = self.failsafe_active = False  # a user takeover
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
        """RTL: climb to ``rtl_altitude_m`` at MPC_Z_V_AUTO_UP, return at cruise speed, land."""
        dyn = self.dyn
        e = dyn.estimated_position()
        self._rtl_alt_m = rtl_altitude_m(self.params, -e[2], math.hypot(e[0], e[1]))
        self.rtl_phase = "climb"
        self.set_mode(FlightMode.RETURN_TO_LAUNCH, source)
        self.status(f"RTL: start return at {self.params.home_altitude_amsl_m + self._rtl_alt_m:.0f} m "
                    f"({self._rtl_alt_m:.0f} m above destination)")
        dyn.command_position(Setpoint(e[0], e[1], -self._rtl_alt_m, dyn.yaw_deg), immediate=True,
                             **self.params.auto_vertical_speeds())

    def failsafe(self, reason: str, action: FailsafeAction) -> None:
        apply_failsafe(self, reason, action)

    def gps_loss(self, duration_s: float) -> bool:
        """No GPS for ``duration_s`` (extends a loss under way); True when it starts now."""
        return self.gps.loss(duration_s)

    def set_battery(self, fraction: float) -> None:
        """The remaining battery (0..1); the levels already handled above it are forgotten."""
        self.power.set(fraction)

    def climbing_from_ground(self) -> None:
        if not self.in_air:
            self._taking_off = True

    def climb_done(self) -> None:
        self._taking_off = False

    def set_mode(self, mode: FlightMode, source: ModeSource) -> None:
        old = self.mode
        self._failsafe_hold_until_ns = None
        self._taking_off = False
        if self.orbit is not None:
            self.orbit = None  # any mode change ends an orbit (the change to Position starts it)
            if mode == old:
                self.listener.on_mode(old, mode, source)  # Position's sub mode changed
        if not self.failsafe_active:
            self.intended_mode = mode
        if mode == old:
            return
        self.mode = mode
        self.listener.on_mode(old, mode, source)

    def _by_command(self) -> None:
        """A commanded mode, the new intent; in a failsafe a takeover (PX4's FailsafeBase)."""
        self.offboard_active = False
        self.offboard_failover = False
        self.manual_input = False
        self.failsafe_active = False

    def _offboard_signal_back(self) -> None:
        """PX4 (recorded i): setpoints arriving again clear the offboard-loss failsafe and it
        goes straight back to OFFBOARD (the user's mode), with no report a client would see
        other than the next HEARTBEAT."""
        self.offboard_failover = False
        self.failsafe_active = False
        self.set_mode(FlightMode.OFFBOARD, "autopilot")
        self.manual_input = False
        self._command_offboard()

    def _command_offboard(self) -> None:
        """PX4 flies an offboard position setpoint at its own maximum speed."""
        dyn = self.dyn
        if self.setpoint is not None:
            dyn.command_position(self.setpoint, max_speed_mps=self.params.offboard_max_speed_mps)
        elif self.setpoint_velocity is not None:
            v, yaw = self.setpoint_velocity
            dyn.command_velocity(v, yaw, yaw_rate_degps=self.setpoint_yaw_rate)
        elif self.setpoint_direct is not None:
            dyn.command_direct(self.setpoint_direct)

    # ------------------------------------------------------------------------------------------
    # the model, after every internal step of the dynamics
    # ------------------------------------------------------------------------------------------
    def on_step(self, dyn: MulticopterDynamics) -> None:
        t = dyn.time_ns
        if not self.gps.ok:
            self.gps.step(t)
        self.power.step()
        if self.armed:
            self.land_detector.step(t)
        if self.armed and self.offboard_failover and self.offboard_signal():
            self._offboard_signal_back()
        if self.armed:
            mode = self.mode
            if mode == FlightMode.TAKEOFF:
                step_takeoff(self, t)
            elif mode == FlightMode.MISSION:
                self.mission.step()
            elif mode == FlightMode.RETURN_TO_LAUNCH:
                step_rtl(self)
            elif mode == FlightMode.OFFBOARD:
                if not self.offboard_signal():
                    p = self.params
                    self.failsafe("Offboard setpoints lost", p.offboard_loss_action)
                    self.offboard_failover = self.mode != FlightMode.OFFBOARD
                    if (p.offboard_loss_action == FailsafeAction.HOLD
                            and p.offboard_loss_land_after_s is not None):
                        self._failsafe_hold_until_ns = t + int(round(p.offboard_loss_land_after_s * 1e9))
            elif mode == FlightMode.POSCTL and self.orbit is not None:
                v, yaw = orbit_command(self.orbit, dyn.estimated_position(), t)
                dyn.command_velocity(v, yaw, immediate=True)
            elif mode == FlightMode.HOLD and self._failsafe_hold_until_ns is not None:
                if t >= self._failsafe_hold_until_ns and self.in_air:
                    self._failsafe_hold_until_ns = None
                    self.set_mode(FlightMode.LAND, "failsafe")
                    dyn.command_land(immediate=True)

    def climbing(self) -> bool:
        """What PX4 must not auto-disarm in (the emulator's rule)."""
        if self.mode == FlightMode.TAKEOFF:
            return True
        if self.mode == FlightMode.MISSION:
            return self.mission.climbing()
        return (self.mode == FlightMode.OFFBOARD and self.setpoint is not None
                and self.setpoint.down_m < -0.3)


def step_takeoff(ap: Autopilot, t: int) -> None:
    """TAKEOFF: spool-up, the climb (its rate ramped up), then HOLD at the altitude."""
    if t < ap._takeoff_go_ns:
        return  # motors spooling up
    dyn, p = ap.dyn, ap.params
    n, e = ap._takeoff_origin
    ramp_s = p.takeoff_ramp_s
    elapsed_s = (t - ap._takeoff_go_ns) * 1e-9
    if not ap._takeoff_climbing or elapsed_s <= ramp_s:
        # PX4 ramps the climb-rate limit up to MPC_TKO_SPEED over MPC_TKO_RAMP_T
        ap._takeoff_climbing = True
        ap.climbing_from_ground()
        k = 1.0 if ramp_s <= 0 else max(0.05, min(1.0, elapsed_s / ramp_s))
        dyn.command_position(Setpoint(n, e, -ap._takeoff_alt_m, dyn.yaw_deg),
                             max_up_speed_mps=k * p.takeoff_speed_mps, immediate=True)
        return
    off = -dyn.estimated_position()[2] - ap._takeoff_alt_m
    if -p.takeoff_accept_below_m <= off <= p.takeoff_accept_above_m:
        ap.set_mode(FlightMode.HOLD, "autopilot")  # PX4: TAKEOFF -> AUTO.LOITER


def step_rtl(ap: Autopilot) -> None:
    """RTL's phases: climb in place, return at cruise speed, land at home."""
    dyn = ap.dyn
    e = dyn.estimated_position()
    if ap.rtl_phase == "climb":
        if -e[2] >= ap._rtl_alt_m - 0.5:
            ap.rtl_phase = "return"
            yaw = math.degrees(math.atan2(-e[1], -e[0])) if math.hypot(e[0], e[1]) > 1.0 else dyn.yaw_deg
            dyn.command_position(Setpoint(0.0, 0.0, -ap._rtl_alt_m, yaw), immediate=True,
                                 **ap.params.auto_vertical_speeds(rtl_return=True))
    elif ap.rtl_phase == "return":
        if (math.hypot(e[0], e[1]) <= ap.params.rtl_land_radius_m
                and math.hypot(dyn.vn, dyn.ve) < ap.params.rtl_land_max_speed_mps):
            ap.rtl_phase = "land"
            ap.status("RTL: land at destination")
            dyn.command_land(at_ne_m=(0.0, 0.0), immediate=True)  # at home (PX4: its
            # land waypoint; recorded f1 / f2: touchdown 0.31 / 0.37 m from it)


def apply_failsafe(ap: Autopilot, reason: str, action: FailsafeAction) -> None:
    """PX4's failsafe ``action`` (its mode, what the vehicle then does)."""
    dyn = ap.dyn
    ap.failsafe_active = True
    ap.status("Failsafe activated", severity="critical")
    ap.listener.on_failsafe(reason, action)
    if action == FailsafeAction.HOLD:
        ap.set_mode(FlightMode.HOLD, "failsafe")
        dyn.command_hold(immediate=True)
    elif action == FailsafeAction.LAND:
        ap.set_mode(FlightMode.LAND, "failsafe")
        dyn.command_land(immediate=True)
    elif action == FailsafeAction.RETURN:
        ap.start_rtl("failsafe")
    elif action in MANUAL_ACTION_MODES:
        # PX4 without RC (COM_OBL_RC_ACT=0, recorded b): the mode cannot run its flight
        # task and the vehicle descends (~0.65 m/s) until it lands and disarms.
        ap.manual_input = False
        ap.set_mode(MANUAL_ACTION_MODES[action], "failsafe")
        dyn.command_velocity((0.0, 0.0, ap.params.position_no_rc_descent_mps), immediate=True)
    else:
        ap.disarm("Disarmed by failsafe")
