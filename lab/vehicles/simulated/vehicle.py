"""Simulated vehicle (plugin ``simulated``): an in-process, deterministic, PX4-like multicopter.

No MAVLink: the :class:`~eaglemission.lab.vehicles.multicopter.dynamics.MulticopterDynamics` model and
the PX4-like :class:`~eaglemission.lab.vehicles.autopilot.model.Autopilot` on top of it (the model
the MAVLink emulator drives too) are stepped *lazily* up to ``clock.now_ns()`` at every call (in
whole internal steps, so the result does not depend on how tasks are scheduled). What the
autopilot does is described in :mod:`~eaglemission.lab.vehicles.autopilot.model`; this module adds
what a MAVSDK client sees:

* commands return when accepted, like MAVSDK's, and are refused with MAVSDK's result codes
  (arming when not armable, takeoff while disarmed, disarm in the air...); the motion starts
  ``command_latency_s`` later;
* telemetry is the drifting *estimate* (what PX4 reports), sampled at ``telemetry_rate_hz``
  into a :class:`~eaglemission.telemetry.history.TelemetryHistory`; the *truth* (what the synthetic
  cameras and the evaluator use) is logged at every internal step (:mod:`.truth_log`).

Fault injection for tests and the sim world (:mod:`.simulated_faults`): ``inject_link_loss``,
``inject_gps_loss``, ``set_battery_fraction``, ``pilot_take_control``, ``deny_next_command``,
``inject_wind_gust``; the link's timing (:mod:`.simulated_link`): ``inject_link_delay``,
``inject_link_duplicate``, ``inject_link_reorder``, ``inject_autopilot_clock_jump``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, Literal

from eaglemission.drivers.vehicles.events import (
    EVENT_FAULT,
    EVENT_GRIPPER,
    EVENT_REFUSED,
)
from eaglemission.lab.vehicles.autopilot.mission import MissionItem
from eaglemission.lab.vehicles.multicopter.dynamics import (
    MulticopterDynamics,
)
from eaglemission.lab.vehicles.simulated.config import (
    PARAMETERS,
    SimulatedVehicleConfig,
    autopilot_params,
    waypoint_problem,
)
from eaglemission.lab.vehicles.simulated.engine import SimulatedModel, SimulatedTruth
from eaglemission.lab.vehicles.simulated.faults import COMMANDS

from eaglemission.errors import ModeChangedExternally, VehicleError
from eaglemission.geometry import geodetic_to_ned
from eaglemission.types import (
    FlightMode,
    GeoPoint,
    MissionProgress,
    Setpoint,
    Waypoint,
)

__all__ = ["COMMANDS", "PARAMETERS", "SimulatedVehicle", "SimulatedVehicleConfig", "autopilot_params"]

class SimulatedVehicle(SimulatedModel):
    """Deterministic in-process PX4-like multicopter (plugin ``simulated``). See the module
    docstring; construction: :class:`~.simulated_engine.SimulatedModel`."""

    Config = SimulatedVehicleConfig
    description = "In-process deterministic PX4-like multicopter (truth + drifting estimate), no MAVLink"

    simulated = True  # no aircraft behind it: the assembly asks no arming confirmation

    def mission_progress(self) -> MissionProgress:
        self._require("mission_progress()")
        with self._lock:
            self._sync()
            m = self.autopilot.mission
            return MissionProgress(m.current, len(m.items))

    @property
    def uploaded_waypoints(self) -> tuple[Waypoint, ...]:
        """The waypoints of the last accepted mission upload, as they reached the vehicle."""
        return self._waypoints

    async def arm(self) -> None:
        await self._command("arm")
        with self._lock:
            ap = self.autopilot
            if ap.armed and (ap.in_air or not ap.dyn.on_ground):
                return
            if ap.armed:
                # armed on the ground (after a landing): what the mavsdk driver does on PX4,
                # whose auto-disarm would otherwise hit the next takeoff: disarm, arm again
                ap.disarm("Disarmed by external command")
            reason = ap.not_armable_reason()
            if reason:
                self._refuse("arm", "COMMAND_DENIED", f"Arming denied: {reason}")
            ap.arm()

    async def disarm(self) -> None:
        dyn = await self._command("disarm")
        with self._lock:
            ap = self.autopilot
            if not ap.armed:
                return
            if ap.in_air or not dyn.on_ground:
                self._refuse("disarm", "COMMAND_DENIED",
                             "Disarming denied: vehicle in air (land first)")
            ap.disarm("Disarmed by external command")

    async def takeoff(self, altitude_m: float) -> None:
        await self._command("takeoff", altitude_m)
        with self._lock:
            ap = self.autopilot
            if not (math.isfinite(altitude_m) and altitude_m > 0):
                self._refuse("takeoff", "INVALID_ARGUMENT",
                             f"altitude_m must be a finite height above home > 0, got {altitude_m}",
                             params=(altitude_m,))
            if not ap.armed:
                self._refuse("takeoff", "COMMAND_DENIED", "Takeoff denied: vehicle not armed (arm first)",
                             params=(altitude_m,))
            if not ap.position_valid:
                self._refuse("takeoff", "COMMAND_DENIED", "Takeoff denied: no valid position estimate",
                             params=(altitude_m,))
            ap.takeoff(altitude_m)
            self._status(f"Using takeoff altitude: {altitude_m:.1f} m")

    async def goto(self, target: GeoPoint, yaw_deg: float) -> None:
        dyn = await self._command("goto", target, yaw_deg)
        with self._lock:
            self._require_flying("goto", (target, yaw_deg))
            n, e, d = geodetic_to_ned(self.home, target)
            if not all(math.isfinite(v) for v in (n, e, d)):
                self._refuse("goto", "INVALID_ARGUMENT", f"target must be finite, got {target}",
                             params=(target, yaw_deg))
            yaw = yaw_deg if math.isfinite(yaw_deg) else dyn.yaw_deg
            self.autopilot.goto(Setpoint(n, e, d, yaw))

    async def upload_mission(self, waypoints: Sequence[Waypoint]) -> None:
        await self._command("upload_mission", len(waypoints))
        with self._lock:
            wps = tuple(waypoints)
            problem = waypoint_problem(wps)
            if problem:
                self._refuse("upload_mission", "INVALID_ARGUMENT", problem)
            self._waypoints = wps
            self.autopilot.upload_mission(tuple(MissionItem.from_waypoint(w) for w in wps))

    async def start_mission(self) -> None:
        await self._command("start_mission")
        with self._lock:
            ap = self.autopilot
            if not ap.mission.items:
                self._refuse("start_mission", "NO_MISSION_AVAILABLE", "upload a mission first")
            if not ap.armed:
                self._refuse("start_mission", "COMMAND_DENIED", "Mission denied: vehicle not armed")
            if not ap.position_valid:
                self._refuse("start_mission", "COMMAND_DENIED", "Mission denied: no valid position")
            ap.start_mission()

    async def start_offboard(self, initial: Setpoint) -> None:
        await self._command("start_offboard", initial)
        with self._lock:
            ap = self.autopilot
            if not isinstance(initial, Setpoint):
                self._refuse("start_offboard", "NO_SETPOINT_SET",
                             "give the first setpoint (the current position and yaw)")
            if not ap.armed:
                self._refuse("start_offboard", "COMMAND_DENIED", "Offboard denied: vehicle not armed",
                             params=(initial,))
            if not ap.position_valid:
                self._refuse("start_offboard", "COMMAND_DENIED",
                             "Offboard denied: no valid local position", params=(initial,))
            ap.start_offboard(initial)

    async def set_setpoint(self, setpoint: Setpoint) -> None:
        self._require("set_setpoint()")
        with self._lock:
            self._sync()
            if self.faults.link_down:
                return  # streamed setpoints are not acknowledged: lost silently, like MAVSDK
            self.faults.check_deny("set_setpoint", setpoint)
            ap = self.autopilot
            if ap.offboard_active and ap.mode != FlightMode.OFFBOARD:
                raise ModeChangedExternally(
                    "MODE_CHANGED", "set_setpoint()", (setpoint,),
                    f"the flight mode is now {ap.mode.value} (changed by the pilot or a "
                    "failsafe): our offboard control has ended; call start_offboard() to take it back")
            if not self.link.send_setpoint(setpoint, self.clock.now_ns()):
                ap.set_setpoint(setpoint)  # else it arrives delay_s later (link_delay)

    async def stop_offboard(self) -> None:
        await self._command("stop_offboard")
        with self._lock:  # idempotent: outside OFFBOARD it only ends our offboard session
            self.autopilot.stop_offboard()

    async def hold(self) -> None:
        await self._command("hold")
        with self._lock:
            self.autopilot.hold()

    async def land(self) -> None:
        await self._command("land")
        with self._lock:
            ap = self.autopilot
            if not ap.armed:
                self._refuse("land", "COMMAND_DENIED", "Land denied: vehicle not armed")
            ap.land()
            self._status("Landing at current position")

    async def return_to_launch(self) -> None:
        await self._command("return_to_launch")
        with self._lock:
            self._require_flying("return_to_launch", None)
            self.autopilot.return_to_launch()

    async def grab(self) -> None:
        await self._gripper("grab")

    async def release(self) -> None:
        await self._gripper("release")

    async def _gripper(self, action: Literal["grab", "release"]) -> None:
        dyn = await self._command(action)
        with self._lock:
            self.autopilot.gripper = action
            self._event(EVENT_GRIPPER, f"Gripper {action}",
                        {"action": action, "position_ned_m": dyn.truth().position_ned_m})

    async def get_param(self, name: str) -> float:
        """The PX4 parameter this model has an equivalent of (``PARAMETERS``); an unknown
        name is refused like PX4 refuses one (``PARAM_UNKNOWN``)."""
        entry = PARAMETERS.get(name)
        if entry is None:
            raise VehicleError("PARAM_UNKNOWN", "get_param()", name,
                               f"the simulated vehicle has no parameter {name!r}; it models "
                               f"{', '.join(sorted(PARAMETERS))}")
        return float(entry[0](self.config))

    async def set_param(self, name: str, value: float) -> None:
        """Set one of the settable parameters (``RTL_RETURN_ALT``, ``COM_OF_LOSS_T``,
        ``COM_DISARM_LAND``, ``COM_DL_LOSS_T``)."""
        entry = PARAMETERS.get(name)
        if entry is None or entry[1] is None:
            raise VehicleError("PARAM_UNKNOWN" if entry is None else "PARAM_READ_ONLY",
                               "set_param()", (name, value),
                               f"{name!r} cannot be set on the simulated vehicle")
        if not (math.isfinite(value) and value > 0):
            raise VehicleError("PARAM_VALUE", "set_param()", (name, value),
                               f"{name} must be a finite number > 0, got {value}")
        with self._lock:
            self.config = self.config.model_copy(update={entry[1]: float(value)})
            if self._ap is not None:
                self._ap.params = autopilot_params(self.config)

    def ground_truth(self) -> SimulatedTruth:
        """The model's true state (for the synthetic cameras and the evaluator)."""
        return SimulatedTruth(self)

    def summary(self) -> str:
        rf = "rangefinder" if self.config.rangefinder.enabled else "no rangefinder"
        return f"in-process PX4-like model, seed {self.seed}, {rf}"

    def inject_link_loss(self, duration_s: float) -> None:
        """Drop the link for ``duration_s``: telemetry freezes (``link_ok`` False), commands
        time out after ``command_timeout_s``, streamed setpoints are lost."""
        self.faults.inject_link_loss(duration_s)

    def inject_gps_loss(self, duration_s: float) -> None:
        """Lose GPS for ``duration_s``: the estimate drifts away; after
        ``gps_loss_failsafe_delay_s`` the position is invalid and the failsafe fires."""
        self.faults.inject_gps_loss(duration_s)

    def set_battery_fraction(self, fraction: float) -> None:
        """Set the remaining battery (0..1); the low-battery failsafes follow."""
        self.faults.set_battery_fraction(fraction)

    def pilot_take_control(self, mode: FlightMode = FlightMode.POSCTL) -> None:
        """A pilot (or ground station) switches the flight mode. Manual modes hold position
        (sticks centred); HOLD/LAND/RETURN_TO_LAUNCH behave as commanded."""
        self.faults.pilot_take_control(mode)

    def deny_next_command(self, name: str) -> None:
        """The next call of command ``name`` (e.g. ``"arm"``) is refused with COMMAND_DENIED."""
        self.faults.deny_next_command(name)

    def inject_wind_gust(self, north_mps: float, east_mps: float, duration_s: float) -> None:
        """Add a gust of (north, east) m/s to the world's wind for ``duration_s``."""
        self.faults.inject_wind_gust(north_mps, east_mps, duration_s)

    def inject_link_delay(self, delay_s: float, duration_s: float) -> None:
        """Delay telemetry, command answers and streamed setpoints by ``delay_s`` for
        ``duration_s`` (``state_at`` sees only the samples received)."""
        with self._lock:
            dyn = self._sync()
            self.link.inject_delay(dyn.time_ns, delay_s, duration_s)
            self._event(EVENT_FAULT, f"link delay {delay_s:g} s for {duration_s:g} s",
                        {"fault": "link_delay", "delay_s": delay_s, "duration_s": duration_s})

    def inject_link_duplicate(self, duration_s: float) -> None:
        """Every telemetry message arrives twice for ``duration_s``."""
        with self._lock:
            dyn = self._sync()
            self.link.inject_duplicate(dyn.time_ns, duration_s)
            self._event(EVENT_FAULT, f"duplicated messages for {duration_s:g} s",
                        {"fault": "link_duplicate", "duration_s": duration_s})

    def inject_link_reorder(self, duration_s: float) -> None:
        """Every telemetry message overtakes the one before it for ``duration_s``."""
        with self._lock:
            dyn = self._sync()
            self.link.inject_reorder(dyn.time_ns, duration_s)
            self._event(EVENT_FAULT, f"reordered messages for {duration_s:g} s",
                        {"fault": "link_reorder", "duration_s": duration_s})

    def inject_autopilot_clock_jump(self, jump_s: float) -> None:
        """The autopilot's timestamps jump by ``jump_s`` (to the end of the flight)."""
        with self._lock:
            self._sync()
            self.link.inject_clock_jump(jump_s)
            self._event(EVENT_FAULT, f"autopilot clock jump {jump_s:g} s",
                        {"fault": "autopilot_clock_jump", "jump_s": jump_s})

    async def _command(self, name: str, *params: Any) -> MulticopterDynamics:
        """Common prologue of a command: connected, link up (else TIMEOUT after the command
        timeout, like an unanswered MAVLink command), fault-injected denial."""
        origin = f"{name}()"
        self._require(origin)
        with self._lock:
            dyn = self._sync()
            link_down = self.faults.link_down
        if link_down:
            await self.clock.sleep(self.config.command_timeout_s)
            with self._lock:
                self._sync()
                self._event(EVENT_REFUSED, f"{origin}: no answer (link down)",
                            {"command": name, "result": "TIMEOUT"})
            raise VehicleError("TIMEOUT", origin, params or None,
                               f"no answer within {self.config.command_timeout_s:g} s: the link "
                               "to the vehicle is down")
        delay_s = self.link.command_delay_s(dyn.time_ns)
        if delay_s > 0:  # the answer (and the command's effect) comes later
            await self.clock.sleep(delay_s)
            with self._lock:
                dyn = self._sync()
        with self._lock:
            self.faults.check_deny(name, *params)
        return dyn


    def _require_flying(self, name: str, params: Any) -> None:
        if not self.autopilot.armed:
            self._refuse(name, "COMMAND_DENIED", "vehicle not armed: arm and take off first", params=params)
        if not self.autopilot.in_air:
            self._refuse(name, "COMMAND_DENIED", "vehicle on the ground: take off first", params=params)

