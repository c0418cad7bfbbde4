"""Simulated vehicle (plugin ``simulated``): an in-process, deterministic, PX4-like multicopter.

No MAVLink: the :class:`~eaglemission.drivers.vehicles.dynamics.MulticopterDynamics` model is
integrated *lazily* up to ``clock.now_ns()`` at every call (in whole internal steps, so the
result does not depend on how tasks are scheduled), and an autopilot layer on top of it
reproduces what matters of PX4 v1.16 (recorded traffic in ``../shared/data/px4_sitl_tlogs``):

* modes named as MAVSDK names PX4's (:class:`~eaglemission.types.FlightMode`); HOLD on the
  ground after boot; TAKEOFF climbs (after a spool-up) to the altitude then switches to HOLD;
  MISSION climbs to the first waypoint's altitude, flies the legs, counts progress and loiters
  at the end; RETURN_TO_LAUNCH climbs to ``rtl_return_altitude_m``, returns and lands; LAND
  descends, "Landing detected", auto-disarm after ``auto_disarm_after_land_s``;
* arming refused when not armable (no GPS, battery low); takeoff refused while disarmed;
  disarm refused in the air; auto-disarm 10 s after arming without takeoff (COM_DISARM_PRFLT);
* offboard needs a setpoint: :meth:`start_offboard` takes the first one; when fresh setpoints
  stop for ``offboard_loss_timeout_s`` the failsafe switches to HOLD (or LAND, or PX4's
  default "Position mode without RC" descent; configurable), "Failsafe activated";
* commands return when accepted, like MAVSDK; the motion starts ``command_latency_s`` later;
* telemetry is the drifting *estimate* (what PX4 reports), sampled at ``telemetry_rate_hz``
  into a :class:`~eaglemission.telemetry.TelemetryHistory`; the *truth* (what the synthetic
  cameras and the evaluator use) is logged at every internal step.

Fault injection for tests and the sim world: :meth:`inject_link_loss`,
:meth:`inject_gps_loss`, :meth:`set_battery_fraction`, :meth:`pilot_take_control`,
:meth:`deny_next_command`.
"""

from __future__ import annotations

import bisect
import math
import threading
from array import array
from collections.abc import Sequence
from dataclasses import replace
from typing import Annotated, Any, Literal

import numpy as np
from eaglemission.drivers.vehicles.dynamics import (
    DynamicsParams,
    MulticopterDynamics,
    RangefinderParams,
    _Normals,
    attitude_from_acceleration,
    rangefinder_reading_m,
    speeds_within_envelope,
    wrap_deg,
)
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from eaglemission.clock import Clock, MonotonicClock
from eaglemission.config import SimulationConfig
from eaglemission.errors import ModeChangedExternally, VehicleError
from eaglemission.geometry import down_axis_cos_tilt, geodetic_to_ned, ned_to_geodetic
from eaglemission.telemetry import TelemetryHistory
from eaglemission.types import (
    XYZ,
    FlightMode,
    GeoPoint,
    MissionProgress,
    Quat,
    Setpoint,
    VehicleEvent,
    VehicleState,
    Waypoint,
)

_Pos = Annotated[float, Field(gt=0, allow_inf_nan=False)]
_NonNeg = Annotated[float, Field(ge=0, allow_inf_nan=False)]
_Frac = Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)]

COMMANDS = frozenset({
    "arm", "disarm", "takeoff", "goto", "upload_mission", "start_mission", "start_offboard",
    "set_setpoint", "stop_offboard", "hold", "land", "return_to_launch", "grab", "release",
})
"""Names accepted by :meth:`SimulatedVehicle.deny_next_command`."""

# Event kinds (VehicleEvent.kind) used by the vehicles.
EVENT_MODE = "mode"  # flight mode changed; data: from, to, source (command/autopilot/failsafe/pilot)
EVENT_STATUS = "status"  # autopilot status text (PX4 STATUSTEXT)
EVENT_FAILSAFE = "failsafe"  # a failsafe fired; data: reason, action
EVENT_REFUSED = "refused"  # a command was refused; data: command, result
EVENT_MISSION = "mission"  # a mission item was reached; data: index, total
EVENT_GRIPPER = "gripper"  # grab / release; data: action
EVENT_LINK = "link"  # link lost / regained; data: ok
EVENT_FAULT = "fault"  # a fault was injected (sim only); data: fault, duration_s

_MODES: tuple[FlightMode, ...] = tuple(FlightMode)
_MODE_INDEX = {m: i for i, m in enumerate(_MODES)}
_POSITION_MODES = frozenset({FlightMode.TAKEOFF, FlightMode.HOLD, FlightMode.MISSION,
                             FlightMode.RETURN_TO_LAUNCH, FlightMode.OFFBOARD, FlightMode.POSCTL})


class SimulatedVehicleConfig(BaseModel):
    """Params of the ``simulated`` vehicle (PX4 parameter names in brackets)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    dynamics: DynamicsParams = Field(default_factory=DynamicsParams)
    rangefinder: RangefinderParams = Field(default_factory=RangefinderParams)
    seed: int | None = None  # None: simulation.seed (or 0)
    home_latitude_deg: Annotated[float, Field(ge=-90, le=90)] = 47.397742
    home_longitude_deg: Annotated[float, Field(ge=-180, le=180)] = 8.545594
    home_altitude_amsl_m: Annotated[float, Field(allow_inf_nan=False)] = 489.4
    initial_yaw_deg: Annotated[float, Field(ge=-180, le=180)] = 0.0
    initial_altitude_m: _NonNeg = 0.0  # > 0: start armed, hovering in HOLD (test convenience)
    telemetry_rate_hz: Annotated[float, Field(ge=1, le=1000)] = 50.0
    history_span_s: _Pos = 2.0
    takeoff_spoolup_s: _NonNeg = 1.5  # recorded PX4: "Takeoff detected" ~1.8 s after the command
    takeoff_ramp_s: _NonNeg = 3.0  # [MPC_TKO_RAMP_T]
    takeoff_altitude_tolerance_m: _Pos = 0.3
    in_air_altitude_m: _Pos = 0.3  # "Takeoff detected" above this height
    land_detect_s: _NonNeg = 1.0
    auto_disarm_after_land_s: _NonNeg = 2.0  # [COM_DISARM_LAND]
    auto_disarm_preflight_s: _Pos = 10.0  # [COM_DISARM_PRFLT]
    offboard_loss_timeout_s: _Pos = 0.5  # [COM_OF_LOSS_T] (PX4 default 1.0 s)
    offboard_loss_action: Literal["hold", "land", "position_no_rc"] = "hold"  # [COM_OBL_RC_ACT]
    offboard_loss_land_after_s: _Pos | None = None  # hold, then land after this long
    position_no_rc_descent_mps: _Pos = 0.65  # recorded PX4: POSCTL without RC descends
    rtl_return_altitude_m: _Pos = 10.0  # [RTL_RETURN_ALT] (PX4 default 60 m)
    mission_vertical_acceptance_m: _Pos = 0.8  # [NAV_MC_ALT_RAD]
    link_loss_timeout_s: _Pos = 10.0  # [COM_DL_LOSS_T]
    link_loss_action: Literal["none", "hold", "return", "land"] = "none"  # [NAV_DLL_ACT]
    gps_loss_failsafe_delay_s: _NonNeg = 1.0
    gps_loss_action: Literal["land", "hold"] = "land"
    command_timeout_s: _Pos = 2.0  # no ACK while the link is down (MAVSDK: 2 s)
    battery_drain_per_s: _NonNeg = 1.0 / 1200.0  # a full battery lasts 20 min of flight
    min_arm_battery_fraction: _Frac = 0.15
    battery_critical_fraction: _Frac = 0.07  # -> RETURN_TO_LAUNCH [BAT_CRIT_THR]
    battery_emergency_fraction: _Frac = 0.05  # -> LAND [BAT_EMERGEN_THR]
    trajectory_max_s: _Pos = 7200.0


class SimulatedVehicle:
    """Deterministic in-process PX4-like multicopter. See the module docstring.

    Parameters (context)
    --------------------
    config : SimulatedVehicle.Config or None
    clock : any eaglemission Clock (``LoopClock`` under ``VirtualTimeLoop``, ``ManualClock``
        in unit tests); defaults to the host monotonic clock.
    simulation : SimulationConfig or None (wind, seed)
    """

    Config = SimulatedVehicleConfig
    description = "In-process deterministic PX4-like multicopter (truth + drifting estimate), no MAVLink"

    simulated = True  # no aircraft behind it: the assembly asks no arming confirmation

    def __init__(self, config: SimulatedVehicleConfig | None = None, *, clock: Clock | None = None,
                 simulation: SimulationConfig | None = None, safety: Any = None,
                 **_context: Any) -> None:
        cfg = config or SimulatedVehicleConfig()
        if safety is not None:  # the autopilot's own speeds inside the envelope (unless given)
            cfg = cfg.model_copy(update={"dynamics": speeds_within_envelope(cfg.dynamics, safety)})
        self.config = cfg
        self.clock: Clock = clock or MonotonicClock()
        self.simulation = simulation
        seed = cfg.seed if cfg.seed is not None else (simulation.seed if simulation else 0)
        self.seed = int(seed)
        self.wind_ne_mps = tuple(simulation.wind_ne_mps) if simulation else (0.0, 0.0)
        self.home = GeoPoint(cfg.home_latitude_deg, cfg.home_longitude_deg, cfg.home_altitude_amsl_m)
        self._lock = threading.RLock()
        self._dyn: MulticopterDynamics | None = None
        self._connected = False
        self._closed = False
        self._history = TelemetryHistory(span_s=cfg.history_span_s)
        self._rangefinder_noise = _Normals(np.random.default_rng(
            np.random.SeedSequence([self.seed, 0x52F])))
        self._events: list[VehicleEvent] = []
        # autopilot state
        self._mode = FlightMode.HOLD
        self._armed = False
        self._in_air = False
        self._ground_since_ns: int | None = None
        self._landed_ns: int | None = None
        self._flew_since_arm = False
        self._armed_ns = 0
        self._battery = 1.0
        self._battery_stage = 0  # 0 ok, 1 critical handled, 2 emergency handled
        self._gripper_closed = False
        # mode-specific
        self._takeoff_alt_m = 0.0
        self._takeoff_go_ns = 0
        self._takeoff_climbing = False
        self._takeoff_origin: tuple[float, float] = (0.0, 0.0)
        self._mission: tuple[Waypoint, ...] = ()
        self._mission_reached = 0
        self._mission_phase: Literal["idle", "climb", "legs", "done"] = "idle"
        self._mission_leg_started = False
        self._rtl_phase: Literal["climb", "return", "land"] = "climb"
        self._rtl_alt_m = 0.0
        self._setpoint: Setpoint | None = None
        self._setpoint_ns = 0
        self._offboard_active = False
        self._failsafe_hold_until_ns: int | None = None
        self._posctl_descending = False
        # faults
        self._link_down_until_ns: int | None = None
        self._link_down_since_ns = 0
        self._link_failsafe_done = False
        self._gps_down_until_ns: int | None = None
        self._gps_down_since_ns = 0
        self._gps_failsafe_done = False
        self._deny: set[str] = set()
        self._frozen_state: VehicleState | None = None
        # logs
        self._tel_period_ns = int(round(1e9 / cfg.telemetry_rate_hz))
        self._next_tel_ns = 0
        self._tr_t = array("q")
        self._tr = [array("d") for _ in range(10)]  # pn pe pd vn ve vd an ae ad yaw
        self._tr_flags = array("B")  # bit 0 armed, bit 1 in air
        self._tr_mode = array("B")  # index into _MODES

    # ------------------------------------------------------------------------------------------
    # lifetime
    # ------------------------------------------------------------------------------------------
    async def __aenter__(self) -> SimulatedVehicle:
        await self.connect()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    async def connect(self) -> None:
        with self._lock:
            if self._connected:
                return
            if self._closed:
                raise VehicleError("CONNECTION_ERROR", "connect()", None,
                                   "the vehicle was closed: create a new one")
            now = self.clock.now_ns()
            if self._dyn is None:
                self._dyn = MulticopterDynamics(self.config.dynamics, seed=self.seed,
                                                wind_ne_mps=self.wind_ne_mps, start_time_ns=now)
                self._dyn.reset((0.0, 0.0, -self.config.initial_altitude_m), self.config.initial_yaw_deg)
                if self.config.initial_altitude_m > 0:
                    self._start_airborne()
                self._next_tel_ns = now
                self._log_truth(self._dyn)
                self._sample_telemetry(self._dyn)
                self._status("Ready for takeoff")
            self._connected = True

    def _start_airborne(self) -> None:
        dyn = self._dyn
        assert dyn is not None
        self._armed = True
        self._in_air = True
        self._flew_since_arm = True
        dyn.set_motors(True)
        dyn.an = dyn.ae = dyn.ad = 0.0
        dyn.on_ground = False
        self._status(f"Simulation starts airborne at {self.config.initial_altitude_m:g} m (armed, HOLD)")

    async def close(self) -> None:
        with self._lock:
            self._connected = False
            self._closed = True

    # ------------------------------------------------------------------------------------------
    # telemetry
    # ------------------------------------------------------------------------------------------
    def state(self) -> VehicleState:
        self._require("state()")
        with self._lock:
            self._sync()
            if self._link_down():
                assert self._frozen_state is not None
                return self._frozen_state
            latest = self._history.latest()
            assert latest is not None
            return latest

    def state_at(self, timestamp_ns: int) -> VehicleState | None:
        self._require("state_at()")
        with self._lock:
            self._sync()
        return self._history.state_at(timestamp_ns)

    def events(self) -> Sequence[VehicleEvent]:
        with self._lock:
            self._sync_if_connected()
            return tuple(self._events)

    def mission_progress(self) -> MissionProgress:
        self._require("mission_progress()")
        with self._lock:
            self._sync()
            return MissionProgress(self._mission_reached, len(self._mission))

    # ------------------------------------------------------------------------------------------
    # commands
    # ------------------------------------------------------------------------------------------
    async def arm(self) -> None:
        dyn = await self._command("arm")
        with self._lock:
            if self._armed:
                return
            reason = self._not_armable_reason()
            if reason:
                self._refuse("arm", "COMMAND_DENIED", f"Arming denied: {reason}")
            self._armed = True
            self._armed_ns = dyn.time_ns
            self._flew_since_arm = False
            self._landed_ns = None
            dyn.set_motors(True)
            self._status("Armed by external command")
            self._refresh_telemetry()

    async def disarm(self) -> None:
        dyn = await self._command("disarm")
        with self._lock:
            if not self._armed:
                return
            if self._in_air or not dyn.on_ground:
                self._refuse("disarm", "COMMAND_DENIED",
                             "Disarming denied: vehicle in air (land first)")
            self._do_disarm("Disarmed by external command")

    async def takeoff(self, altitude_m: float) -> None:
        dyn = await self._command("takeoff", altitude_m)
        with self._lock:
            if not (math.isfinite(altitude_m) and altitude_m > 0):
                self._refuse("takeoff", "INVALID_ARGUMENT",
                             f"altitude_m must be a finite height above home > 0, got {altitude_m}",
                             params=(altitude_m,))
            if not self._armed:
                self._refuse("takeoff", "COMMAND_DENIED", "Takeoff denied: vehicle not armed (arm first)",
                             params=(altitude_m,))
            if not self._position_valid():
                self._refuse("takeoff", "COMMAND_DENIED", "Takeoff denied: no valid position estimate",
                             params=(altitude_m,))
            est = dyn.estimated_position()
            self._takeoff_alt_m = float(altitude_m)
            self._takeoff_origin = (est[0], est[1])
            spool = self.config.takeoff_spoolup_s if dyn.on_ground else 0.0
            self._takeoff_go_ns = dyn.time_ns + int(round(spool * 1e9))
            self._takeoff_climbing = False
            self._leave_offboard()
            self._set_mode(FlightMode.TAKEOFF, "command")
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
            self._leave_offboard()
            self._set_mode(FlightMode.HOLD, "command")  # PX4: DO_REPOSITION -> AUTO.LOITER
            dyn.command_position(Setpoint(n, e, d, yaw))

    async def upload_mission(self, waypoints: Sequence[Waypoint]) -> None:
        await self._command("upload_mission", len(waypoints))
        with self._lock:
            wps = tuple(waypoints)
            if not wps:
                self._refuse("upload_mission", "INVALID_ARGUMENT", "the mission has no waypoint")
            for i, w in enumerate(wps):
                vals = (w.north_m, w.east_m, w.altitude_m, w.acceptance_radius_m)
                if not all(math.isfinite(v) for v in vals) or w.acceptance_radius_m <= 0:
                    self._refuse("upload_mission", "INVALID_ARGUMENT",
                                 f"waypoint {i} is not finite or has acceptance_radius_m <= 0: {w}")
                if w.speed_mps is not None and not (math.isfinite(w.speed_mps) and w.speed_mps > 0):
                    self._refuse("upload_mission", "INVALID_ARGUMENT",
                                 f"waypoint {i}: speed_mps must be > 0, got {w.speed_mps}")
            self._mission = wps
            self._mission_reached = 0
            self._mission_phase = "idle"
            if self._mode == FlightMode.MISSION:
                self._start_mission_logic()

    async def start_mission(self) -> None:
        await self._command("start_mission")
        with self._lock:
            if not self._mission:
                self._refuse("start_mission", "NO_MISSION_AVAILABLE", "upload a mission first")
            if not self._armed:
                self._refuse("start_mission", "COMMAND_DENIED", "Mission denied: vehicle not armed")
            if not self._position_valid():
                self._refuse("start_mission", "COMMAND_DENIED", "Mission denied: no valid position")
            if self._mission_reached >= len(self._mission):
                self._mission_reached = 0
            self._leave_offboard()
            self._set_mode(FlightMode.MISSION, "command")
            self._status("Executing Mission")
            self._start_mission_logic()

    async def start_offboard(self, initial: Setpoint) -> None:
        dyn = await self._command("start_offboard", initial)
        with self._lock:
            if not isinstance(initial, Setpoint):
                self._refuse("start_offboard", "NO_SETPOINT_SET",
                             "give the first setpoint (the current position and yaw)")
            if not self._armed:
                self._refuse("start_offboard", "COMMAND_DENIED", "Offboard denied: vehicle not armed",
                             params=(initial,))
            if not self._position_valid():
                self._refuse("start_offboard", "COMMAND_DENIED",
                             "Offboard denied: no valid local position", params=(initial,))
            self._setpoint = initial
            self._setpoint_ns = dyn.time_ns
            self._offboard_active = True
            self._set_mode(FlightMode.OFFBOARD, "command")
            self._command_offboard(initial)

    async def set_setpoint(self, setpoint: Setpoint) -> None:
        self._require("set_setpoint()")
        with self._lock:
            dyn = self._sync()
            if self._link_down():
                return  # streamed setpoints are not acknowledged: lost silently, like MAVSDK
            self._check_deny("set_setpoint", setpoint)
            if self._offboard_active and self._mode != FlightMode.OFFBOARD:
                raise ModeChangedExternally(
                    "MODE_CHANGED", "set_setpoint()", (setpoint,),
                    f"the flight mode is now {self._mode.value} (changed by the pilot or a "
                    "failsafe): our offboard control has ended; call start_offboard() to take it back")
            self._setpoint = setpoint
            self._setpoint_ns = dyn.time_ns
            if self._mode == FlightMode.OFFBOARD:
                self._command_offboard(setpoint)

    async def stop_offboard(self) -> None:
        dyn = await self._command("stop_offboard")
        with self._lock:  # idempotent: outside OFFBOARD it only ends our offboard session
            self._offboard_active = False
            if self._mode == FlightMode.OFFBOARD:
                self._set_mode(FlightMode.HOLD, "command")
                if self._armed:
                    dyn.command_hold()

    async def hold(self) -> None:
        dyn = await self._command("hold")
        with self._lock:
            self._leave_offboard()
            self._set_mode(FlightMode.HOLD, "command")
            if self._armed and not dyn.on_ground:
                dyn.command_hold()

    async def land(self) -> None:
        dyn = await self._command("land")
        with self._lock:
            if not self._armed:
                self._refuse("land", "COMMAND_DENIED", "Land denied: vehicle not armed")
            self._leave_offboard()
            self._set_mode(FlightMode.LAND, "command")
            self._status("Landing at current position")
            dyn.command_land()

    async def return_to_launch(self) -> None:
        await self._command("return_to_launch")
        with self._lock:
            self._require_flying("return_to_launch", None)
            self._leave_offboard()
            self._start_rtl("command")

    async def grab(self) -> None:
        dyn = await self._command("grab")
        with self._lock:
            self._gripper_closed = True
            self._event(EVENT_GRIPPER, "Gripper grab", {"action": "grab",
                                                        "position_ned_m": dyn.truth().position_ned_m})

    async def release(self) -> None:
        dyn = await self._command("release")
        with self._lock:
            self._gripper_closed = False
            self._event(EVENT_GRIPPER, "Gripper release", {"action": "release",
                                                           "position_ned_m": dyn.truth().position_ned_m})

    # ------------------------------------------------------------------------------------------
    # parameters (PX4 names) and ground truth
    # ------------------------------------------------------------------------------------------
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

    def ground_truth(self) -> _SimulatedTruth:
        """The model's true state (for the synthetic cameras and the evaluator)."""
        return _SimulatedTruth(self)

    def summary(self) -> str:
        rf = "rangefinder" if self.config.rangefinder.enabled else "no rangefinder"
        return f"in-process PX4-like model, seed {self.seed}, {rf}"

    # ------------------------------------------------------------------------------------------
    # sim world & tests
    # ------------------------------------------------------------------------------------------
    @property
    def dynamics(self) -> MulticopterDynamics:
        """The underlying model (for tests and the sim world)."""
        self._require("dynamics")
        assert self._dyn is not None
        return self._dyn

    @property
    def gripper_closed(self) -> bool:
        return self._gripper_closed

    def true_state(self) -> VehicleState:
        """The TRUE state now (what the synthetic cameras and the evaluator use)."""
        self._require("true_state()")
        with self._lock:
            dyn = self._sync()
            return self._truth_vehicle_state(dyn.time_ns, dyn.truth().position_ned_m,
                                             (dyn.vn, dyn.ve, dyn.vd),
                                             attitude_q=dyn.truth().attitude_q)

    def true_pose_at(self, timestamp_ns: int) -> tuple[XYZ, Quat] | None:
        """True position and attitude at a host time, interpolated from the truth log; None
        outside it (before the first sample, or later than now)."""
        with self._lock:
            if self._dyn is None:
                return None
            self._sync_if_connected()
            times = self._tr_t
            if not times or timestamp_ns < times[0] or timestamp_ns > times[-1] + self._dyn.step_ns:
                return None
            i = bisect.bisect_right(times, timestamp_ns)
            if i >= len(times):
                i = len(times) - 1
                j = i
                s = 0.0
            else:
                j = i
                i = j - 1
                span = times[j] - times[i]
                s = (timestamp_ns - times[i]) / span if span > 0 else 0.0
            c = self._tr
            vals = [c[k][i] + s * (c[k][j] - c[k][i]) for k in range(9)]
            yaw = c[9][i] + s * wrap_deg(c[9][j] - c[9][i])
        pos = (vals[0], vals[1], vals[2])
        return pos, self._attitude(vals[6], vals[7], vals[8], yaw, on_ground=pos[2] >= 0.0)

    def trajectory(self, *, since_ns: int | None = None, every_s: float | None = None) -> list[VehicleState]:
        """TRUE states (with the armed / in-air / mode of that moment) at every internal step,
        or every ``every_s`` seconds, oldest first."""
        with self._lock:
            self._sync_if_connected()
            times = list(self._tr_t)
            cols = [list(c) for c in self._tr]
            flags = list(self._tr_flags)
            modes = list(self._tr_mode)
        out: list[VehicleState] = []
        last = -math.inf
        for k, t in enumerate(times):
            if since_ns is not None and t < since_ns:
                continue
            if every_s is not None and (t - last) < every_s * 1e9 - 1:
                continue
            last = t
            pn, pe, pd, vn, ve, vd, an, ae, ad, yaw = (c[k] for c in cols)
            q = self._attitude(an, ae, ad, yaw, on_ground=pd >= 0.0)
            out.append(self._truth_vehicle_state(
                t, (pn, pe, pd), (vn, ve, vd), attitude_q=q, armed=bool(flags[k] & 1),
                in_air=bool(flags[k] & 2), mode=_MODES[modes[k]]))
        return out

    def trajectory_array(self, *, since_ns: int | None = None) -> NDArray[np.float64]:
        """Truth log as an (N, 11) array: t_ns, north, east, down, vn, ve, vd, an, ae, ad, yaw_deg."""
        with self._lock:
            self._sync_if_connected()
            t = np.frombuffer(self._tr_t, dtype=np.int64).astype(np.float64)
            cols = [np.frombuffer(c, dtype=np.float64) for c in self._tr]
            arr = np.column_stack([t, *cols]) if len(t) else np.zeros((0, 11))
        if since_ns is not None:
            arr = arr[arr[:, 0] >= since_ns]
        return arr.copy()

    def inject_link_loss(self, duration_s: float) -> None:
        """Drop the link for ``duration_s``: telemetry freezes (``link_ok`` False), commands
        time out after ``command_timeout_s``, streamed setpoints are lost."""
        self._check_duration(duration_s, "inject_link_loss")
        with self._lock:
            dyn = self._sync()
            if not self._link_down():
                latest = self._history.latest()
                assert latest is not None
                self._frozen_state = replace(latest, link_ok=False)
                self._link_down_since_ns = dyn.time_ns
                self._link_failsafe_done = False
                self._event(EVENT_LINK, "Link lost", {"ok": False})
            self._link_down_until_ns = dyn.time_ns + int(round(duration_s * 1e9))
            dyn.clear_pending()
            self._event(EVENT_FAULT, f"link loss for {duration_s:g} s",
                        {"fault": "link_loss", "duration_s": duration_s})

    def inject_gps_loss(self, duration_s: float) -> None:
        """Lose GPS for ``duration_s``: the estimate drifts away; after
        ``gps_loss_failsafe_delay_s`` the position is invalid and the failsafe fires."""
        self._check_duration(duration_s, "inject_gps_loss")
        with self._lock:
            dyn = self._sync()
            if self._gps_down_until_ns is None:
                self._gps_down_since_ns = dyn.time_ns
                self._gps_failsafe_done = False
                dyn.estimate_model.set_gps(False)
                self._status("GPS lost", severity="critical")
            self._gps_down_until_ns = dyn.time_ns + int(round(duration_s * 1e9))
            self._refresh_telemetry()
            self._event(EVENT_FAULT, f"GPS loss for {duration_s:g} s",
                        {"fault": "gps_loss", "duration_s": duration_s})

    def set_battery_fraction(self, fraction: float) -> None:
        """Set the remaining battery (0..1); the low-battery failsafes follow."""
        if not (math.isfinite(fraction) and 0.0 <= fraction <= 1.0):
            raise ValueError(f"fraction: must be in [0, 1], got {fraction}")
        with self._lock:
            self._sync_if_connected()
            self._battery = float(fraction)
            if fraction > self.config.battery_critical_fraction:
                self._battery_stage = 0
            self._event(EVENT_FAULT, f"battery set to {fraction:.2f}",
                        {"fault": "battery", "fraction": fraction})
            self._refresh_telemetry()

    def pilot_take_control(self, mode: FlightMode = FlightMode.POSCTL) -> None:
        """A pilot (or ground station) switches the flight mode. Manual modes hold position
        (sticks centred); HOLD/LAND/RETURN_TO_LAUNCH behave as commanded."""
        mode = FlightMode(mode)
        with self._lock:
            dyn = self._sync()
            self._event(EVENT_FAULT, f"pilot switches to {mode.value}", {"fault": "pilot", "mode": mode.value})
            if mode == FlightMode.RETURN_TO_LAUNCH and self._armed and self._in_air:
                self._start_rtl("pilot")
                return
            self._set_mode(mode, "pilot")
            if not self._armed or dyn.on_ground:
                return
            if mode == FlightMode.LAND:
                dyn.command_land(immediate=True)
            elif mode == FlightMode.MISSION and self._mission:
                self._start_mission_logic()
            elif mode != FlightMode.OFFBOARD:
                dyn.command_hold(immediate=True)

    def deny_next_command(self, name: str) -> None:
        """The next call of command ``name`` (e.g. ``"arm"``) is refused with COMMAND_DENIED."""
        if name not in COMMANDS:
            raise ValueError(f"name: must be one of {sorted(COMMANDS)}, got {name!r}")
        with self._lock:
            self._deny.add(name)

    # ------------------------------------------------------------------------------------------
    # internals: plumbing
    # ------------------------------------------------------------------------------------------
    def _require(self, origin: str) -> None:
        if not self._connected:
            raise VehicleError("NO_SYSTEM", origin, None,
                               "not connected: call `await vehicle.connect()` (or use `async with`)")

    def _sync(self) -> MulticopterDynamics:
        dyn = self._dyn
        assert dyn is not None
        dyn.advance_to(self.clock.now_ns(), self._on_step)
        return dyn

    def _sync_if_connected(self) -> None:
        if self._dyn is not None and not self._closed:
            self._sync()

    async def _command(self, name: str, *params: Any) -> MulticopterDynamics:
        """Common prologue of a command: connected, link up (else TIMEOUT after the command
        timeout, like an unanswered MAVLink command), fault-injected denial."""
        origin = f"{name}()"
        self._require(origin)
        with self._lock:
            dyn = self._sync()
            link_down = self._link_down()
        if link_down:
            await self.clock.sleep(self.config.command_timeout_s)
            with self._lock:
                self._sync()
                self._event(EVENT_REFUSED, f"{origin}: no answer (link down)",
                            {"command": name, "result": "TIMEOUT"})
            raise VehicleError("TIMEOUT", origin, params or None,
                               f"no answer within {self.config.command_timeout_s:g} s: the link "
                               "to the vehicle is down")
        with self._lock:
            self._check_deny(name, *params)
        return dyn

    def _check_deny(self, name: str, *params: Any) -> None:
        if name in self._deny:
            self._deny.discard(name)
            self._refuse(name, "COMMAND_DENIED", "denied by the autopilot (injected fault)",
                         params=params or None)

    def _refuse(self, name: str, result: str, detail: str, *, params: Any = None) -> None:
        self._event(EVENT_REFUSED, f"{name}(): {result}: {detail}", {"command": name, "result": result})
        raise VehicleError(result, f"{name}()", params, detail)

    def _require_flying(self, name: str, params: Any) -> None:
        if not self._armed:
            self._refuse(name, "COMMAND_DENIED", "vehicle not armed: arm and take off first", params=params)
        if not self._in_air:
            self._refuse(name, "COMMAND_DENIED", "vehicle on the ground: take off first", params=params)

    @staticmethod
    def _check_duration(duration_s: float, origin: str) -> None:
        if not (math.isfinite(duration_s) and duration_s > 0):
            raise ValueError(f"{origin}: duration_s must be > 0, got {duration_s}")

    def _event(self, kind: str, text: str, data: dict[str, object] | None = None) -> None:
        t = self._dyn.time_ns if self._dyn is not None else self.clock.now_ns()
        self._events.append(VehicleEvent(t, kind, text, dict(data or {})))

    def _status(self, text: str, severity: str = "info") -> None:
        self._event(EVENT_STATUS, text, {"severity": severity})

    def _set_mode(self, mode: FlightMode, source: str) -> None:
        old = self._mode
        self._posctl_descending = False
        self._failsafe_hold_until_ns = None
        if mode == old:
            return
        self._mode = mode
        self._event(EVENT_MODE, f"{old.value} -> {mode.value}",
                    {"from": old.value, "to": mode.value, "source": source})
        self._refresh_telemetry()

    def _refresh_telemetry(self) -> None:
        """A state change (mode, armed) shows in telemetry at once (a fresh sample now)."""
        if self._dyn is not None and self._link_down_until_ns is None:
            self._sample_telemetry(self._dyn)

    def _leave_offboard(self) -> None:
        self._offboard_active = False

    def _link_down(self) -> bool:
        return self._link_down_until_ns is not None

    def _gps_down(self) -> bool:
        return self._gps_down_until_ns is not None

    def _position_valid(self) -> bool:
        if self._gps_down_until_ns is None or self._dyn is None:
            return True
        return (self._dyn.time_ns - self._gps_down_since_ns) < self.config.gps_loss_failsafe_delay_s * 1e9

    def _not_armable_reason(self) -> str:
        if self._gps_down():
            return "no GPS fix"
        if self._battery < self.config.min_arm_battery_fraction:
            return f"battery low ({self._battery:.0%})"
        if self._dyn is not None and not self._dyn.on_ground:
            return "not landed"
        return ""

    def _command_offboard(self, sp: Setpoint) -> None:
        """PX4 flies an offboard position setpoint at its own maximum speed."""
        assert self._dyn is not None
        p = self.config.dynamics
        self._dyn.command_position(sp, max_speed_mps=p.max_horizontal_speed_mps)

    def _do_disarm(self, text: str) -> None:
        assert self._dyn is not None
        self._armed = False
        self._dyn.set_motors(False)
        self._offboard_active = False
        self._status(text)
        self._refresh_telemetry()
        if self._mode != FlightMode.HOLD:
            self._set_mode(FlightMode.HOLD, "autopilot")

    def _start_rtl(self, source: str) -> None:
        dyn = self._dyn
        assert dyn is not None
        alt = -dyn.estimated_position()[2]
        self._rtl_alt_m = max(alt, self.config.rtl_return_altitude_m)
        self._rtl_phase = "climb"
        self._set_mode(FlightMode.RETURN_TO_LAUNCH, source)
        self._status(f"RTL: start return at {self.home.altitude_amsl_m + self._rtl_alt_m:.0f} m "
                     f"({self._rtl_alt_m:.0f} m above destination)")
        e = dyn.estimated_position()
        dyn.command_position(Setpoint(e[0], e[1], -self._rtl_alt_m, dyn.yaw_deg), immediate=True)

    def _start_mission_logic(self) -> None:
        dyn = self._dyn
        assert dyn is not None
        first = self._mission[min(self._mission_reached, len(self._mission) - 1)]
        alt = -dyn.estimated_position()[2]
        if dyn.on_ground or alt < first.altitude_m - self.config.mission_vertical_acceptance_m:
            self._mission_phase = "climb"
            self._status(f"Climb to {first.altitude_m:.1f} meters above home")
            e = dyn.estimated_position()
            dyn.command_position(Setpoint(e[0], e[1], -first.altitude_m, dyn.yaw_deg),
                                 max_up_speed_mps=self.config.dynamics.takeoff_speed_mps, immediate=True)
        else:
            self._mission_phase = "legs"
            self._mission_leg_started = False

    # ------------------------------------------------------------------------------------------
    # internals: the autopilot, run after every internal step of the model
    # ------------------------------------------------------------------------------------------
    def _on_step(self, dyn: MulticopterDynamics) -> None:
        t = dyn.time_ns
        cfg = self.config
        # faults ending
        if self._link_down_until_ns is not None:
            if t >= self._link_down_until_ns:
                self._link_down_until_ns = None
                self._frozen_state = None
                self._event(EVENT_LINK, "Link regained", {"ok": True})
            elif (not self._link_failsafe_done and cfg.link_loss_action != "none"
                  and t - self._link_down_since_ns >= cfg.link_loss_timeout_s * 1e9):
                self._link_failsafe_done = True
                if self._armed and self._in_air:
                    self._failsafe("Connection to ground control station lost", cfg.link_loss_action)
        if self._gps_down_until_ns is not None:
            if t >= self._gps_down_until_ns:
                self._gps_down_until_ns = None
                dyn.estimate_model.set_gps(True)
                self._status("GPS regained")
            elif (not self._gps_failsafe_done
                  and t - self._gps_down_since_ns >= cfg.gps_loss_failsafe_delay_s * 1e9):
                self._gps_failsafe_done = True
                if self._armed and self._in_air and self._mode in _POSITION_MODES:
                    self._failsafe("No valid position estimate (GPS lost)", cfg.gps_loss_action)
        # battery
        if dyn.motors_on:
            self._battery = max(0.0, self._battery - cfg.battery_drain_per_s * dyn.dt_s)
            if self._armed and self._in_air:
                if self._battery_stage < 2 and self._battery <= cfg.battery_emergency_fraction:
                    self._battery_stage = 2
                    self._failsafe("Battery level emergency", "land")
                elif self._battery_stage < 1 and self._battery <= cfg.battery_critical_fraction:
                    self._battery_stage = 1
                    self._failsafe("Battery level critical", "return")
        # landed state
        if self._armed:
            if not dyn.on_ground and -dyn.pd >= cfg.in_air_altitude_m and not self._in_air:
                self._in_air = True
                self._flew_since_arm = True
                self._ground_since_ns = None
                self._status("Takeoff detected")
            if dyn.on_ground:
                if self._ground_since_ns is None:
                    self._ground_since_ns = t
                if self._in_air and t - self._ground_since_ns >= cfg.land_detect_s * 1e9:
                    self._in_air = False
                    self._landed_ns = t
                    self._status("Landing detected")
            else:
                self._ground_since_ns = None
            if (self._landed_ns is not None and not self._in_air
                    and t - self._landed_ns >= cfg.auto_disarm_after_land_s * 1e9):
                self._landed_ns = None
                self._do_disarm("Disarmed by landing")
            elif (not self._flew_since_arm and dyn.on_ground and self._mode != FlightMode.TAKEOFF
                  and self._mode != FlightMode.MISSION and self._mode != FlightMode.OFFBOARD
                  and t - self._armed_ns >= cfg.auto_disarm_preflight_s * 1e9):
                self._do_disarm("Disarmed by auto preflight disarming")
        # mode logic
        if self._armed:
            mode = self._mode
            if mode == FlightMode.TAKEOFF:
                self._step_takeoff(dyn, t)
            elif mode == FlightMode.MISSION:
                self._step_mission(dyn)
            elif mode == FlightMode.RETURN_TO_LAUNCH:
                self._step_rtl(dyn)
            elif mode == FlightMode.OFFBOARD:
                if t - self._setpoint_ns > cfg.offboard_loss_timeout_s * 1e9:
                    action = cfg.offboard_loss_action
                    self._failsafe("Offboard setpoints lost",
                                   "position_no_rc" if action == "position_no_rc" else action)
                    if action == "hold" and cfg.offboard_loss_land_after_s is not None:
                        self._failsafe_hold_until_ns = t + int(round(cfg.offboard_loss_land_after_s * 1e9))
            elif mode == FlightMode.HOLD and self._failsafe_hold_until_ns is not None:
                if t >= self._failsafe_hold_until_ns and self._in_air:
                    self._failsafe_hold_until_ns = None
                    self._set_mode(FlightMode.LAND, "failsafe")
                    dyn.command_land(immediate=True)
        # logs
        self._log_truth(dyn)
        if t >= self._next_tel_ns:
            self._next_tel_ns = t + self._tel_period_ns
            if self._link_down_until_ns is None:
                self._sample_telemetry(dyn)

    def _failsafe(self, reason: str, action: str) -> None:
        dyn = self._dyn
        assert dyn is not None
        self._status("Failsafe activated", severity="critical")
        self._event(EVENT_FAILSAFE, f"{reason}: {action}", {"reason": reason, "action": action})
        if action == "hold":
            self._set_mode(FlightMode.HOLD, "failsafe")
            dyn.command_hold(immediate=True)
        elif action == "land":
            self._set_mode(FlightMode.LAND, "failsafe")
            dyn.command_land(immediate=True)
        elif action == "return":
            self._start_rtl("failsafe")
        elif action == "position_no_rc":
            # PX4 default (COM_OBL_RC_ACT=0) without RC: Position mode cannot run and the
            # vehicle descends (recorded: ~0.65 m/s) until it lands and disarms.
            self._set_mode(FlightMode.POSCTL, "failsafe")
            self._posctl_descending = True
            dyn.command_velocity((0.0, 0.0, self.config.position_no_rc_descent_mps), immediate=True)

    def _step_takeoff(self, dyn: MulticopterDynamics, t: int) -> None:
        if t < self._takeoff_go_ns:
            return  # motors spooling up
        n, e = self._takeoff_origin
        ramp_s = self.config.takeoff_ramp_s
        elapsed_s = (t - self._takeoff_go_ns) * 1e-9
        if not self._takeoff_climbing or elapsed_s <= ramp_s:
            # PX4 ramps the climb-rate limit up to MPC_TKO_SPEED over MPC_TKO_RAMP_T
            self._takeoff_climbing = True
            k = 1.0 if ramp_s <= 0 else max(0.05, min(1.0, elapsed_s / ramp_s))
            dyn.command_position(Setpoint(n, e, -self._takeoff_alt_m, dyn.yaw_deg),
                                 max_up_speed_mps=k * self.config.dynamics.takeoff_speed_mps,
                                 immediate=True)
            return
        alt = -dyn.estimated_position()[2]
        if abs(alt - self._takeoff_alt_m) <= self.config.takeoff_altitude_tolerance_m:
            self._set_mode(FlightMode.HOLD, "autopilot")  # PX4: TAKEOFF -> AUTO.LOITER

    def _step_mission(self, dyn: MulticopterDynamics) -> None:
        phase = self._mission_phase
        if phase == "done" or phase == "idle":
            return
        wps = self._mission
        e = dyn.estimated_position()
        if phase == "climb":
            target = wps[min(self._mission_reached, len(wps) - 1)].altitude_m
            if -e[2] >= target - self.config.mission_vertical_acceptance_m:
                self._mission_phase = "legs"
                self._mission_leg_started = False
            return
        i = self._mission_reached
        if i >= len(wps):
            return
        wp = wps[i]
        if not self._mission_leg_started:
            self._mission_leg_started = True
            dn, de = wp.north_m - e[0], wp.east_m - e[1]
            yaw = math.degrees(math.atan2(de, dn)) if math.hypot(dn, de) > 1.0 else dyn.yaw_deg
            dyn.command_position(Setpoint(wp.north_m, wp.east_m, -wp.altitude_m, yaw),
                                 max_speed_mps=wp.speed_mps, immediate=True)
            return
        if (math.hypot(wp.north_m - e[0], wp.east_m - e[1]) <= wp.acceptance_radius_m
                and abs(-e[2] - wp.altitude_m) <= self.config.mission_vertical_acceptance_m):
            self._mission_reached = i + 1
            self._event(EVENT_MISSION, f"Mission item {i} reached",
                        {"index": i, "total": len(wps)})
            self._mission_leg_started = False
            if self._mission_reached >= len(wps):
                self._mission_phase = "done"
                self._status("Mission finished, loitering")

    def _step_rtl(self, dyn: MulticopterDynamics) -> None:
        e = dyn.estimated_position()
        p = self.config.dynamics
        if self._rtl_phase == "climb":
            if -e[2] >= self._rtl_alt_m - 0.5:
                self._rtl_phase = "return"
                yaw = math.degrees(math.atan2(-e[1], -e[0])) if math.hypot(e[0], e[1]) > 1.0 else dyn.yaw_deg
                dyn.command_position(Setpoint(0.0, 0.0, -self._rtl_alt_m, yaw),
                                     max_speed_mps=p.cruise_speed_mps, immediate=True)
        elif self._rtl_phase == "return":
            if math.hypot(e[0], e[1]) <= 1.0 and math.hypot(dyn.vn, dyn.ve) < 0.5:
                self._rtl_phase = "land"
                self._status("RTL: land at destination")
                dyn.command_land(immediate=True)

    # ------------------------------------------------------------------------------------------
    # internals: logs and state construction
    # ------------------------------------------------------------------------------------------
    def _log_truth(self, dyn: MulticopterDynamics) -> None:
        self._tr_t.append(dyn.time_ns)
        c = self._tr
        c[0].append(dyn.pn)
        c[1].append(dyn.pe)
        c[2].append(dyn.pd)
        c[3].append(dyn.vn)
        c[4].append(dyn.ve)
        c[5].append(dyn.vd)
        c[6].append(dyn.an)
        c[7].append(dyn.ae)
        c[8].append(dyn.ad)
        c[9].append(dyn.yaw_deg)
        self._tr_flags.append(int(self._armed) | (int(self._in_air) << 1))
        self._tr_mode.append(_MODE_INDEX[self._mode])
        max_n = int(self.config.trajectory_max_s * self.config.dynamics.rate_hz)
        if len(self._tr_t) > max_n:
            drop = len(self._tr_t) - max_n // 2
            del self._tr_t[:drop]
            del self._tr_flags[:drop]
            del self._tr_mode[:drop]
            for col in c:
                del col[:drop]

    @staticmethod
    def _attitude(an: float, ae: float, ad: float, yaw_deg: float, *, on_ground: bool) -> Quat:
        if on_ground and ad > 9.0:  # motors off on the ground: level
            return attitude_from_acceleration((0.0, 0.0, 0.0), yaw_deg)
        return attitude_from_acceleration((an, ae, ad), yaw_deg)

    def _battery_voltage(self) -> float:
        return 4.0 * (3.5 + 0.7 * self._battery)  # 4S LiPo

    def _sample_telemetry(self, dyn: MulticopterDynamics) -> None:
        en, ee, ed = dyn.estimated_position()
        q = self._attitude(dyn.an, dyn.ae, dyn.ad, dyn.yaw_deg, on_ground=dyn.on_ground)
        gps = not self._gps_down()
        rf = self.config.rangefinder
        distance = None
        if rf.enabled:  # the beam follows the TRUE pose
            distance = rangefinder_reading_m(dyn.pd, down_axis_cos_tilt(q), rf,
                                             self._rangefinder_noise.next())
        state = VehicleState(
            timestamp_ns=dyn.time_ns,
            position_ned_m=(en, ee, ed),
            velocity_ned_mps=(dyn.vn, dyn.ve, dyn.vd),
            attitude_q=q,
            angular_velocity_frd_radps=(0.0, 0.0, math.radians(dyn.yaw_rate_degps)),
            geodetic=ned_to_geodetic(self.home, en, ee, ed),
            relative_altitude_m=-ed,
            home=self.home,
            armed=self._armed,
            in_air=self._in_air,
            flight_mode=self._mode,
            battery_remaining=self._battery,
            battery_voltage_v=self._battery_voltage(),
            position_valid=self._position_valid(),
            gps_fix=gps,
            link_ok=True,
            armable=not self._armed and not self._not_armable_reason(),
            distance_to_ground_m=distance,
        )
        self._history.append(state)

    def _truth_vehicle_state(self, t: int, pos: XYZ, vel: XYZ, *, attitude_q: Quat,
                             armed: bool | None = None, in_air: bool | None = None,
                             mode: FlightMode | None = None) -> VehicleState:
        armed = self._armed if armed is None else armed
        return VehicleState(
            timestamp_ns=t, position_ned_m=pos, velocity_ned_mps=vel, attitude_q=attitude_q,
            geodetic=ned_to_geodetic(self.home, *pos), relative_altitude_m=-pos[2], home=self.home,
            armed=armed, in_air=self._in_air if in_air is None else in_air,
            flight_mode=self._mode if mode is None else mode,
            battery_remaining=self._battery, battery_voltage_v=self._battery_voltage(),
            position_valid=True, gps_fix=True, link_ok=True, armable=not armed)


_OBL = {"position_no_rc": 0.0, "land": 4.0, "hold": 5.0}
_DLL = {"none": 0.0, "hold": 1.0, "return": 2.0, "land": 3.0}
PARAMETERS: dict[str, tuple[Any, str | None]] = {
    "RTL_RETURN_ALT": (lambda c: c.rtl_return_altitude_m, "rtl_return_altitude_m"),
    "COM_OF_LOSS_T": (lambda c: c.offboard_loss_timeout_s, "offboard_loss_timeout_s"),
    "COM_DISARM_LAND": (lambda c: c.auto_disarm_after_land_s, "auto_disarm_after_land_s"),
    "COM_DL_LOSS_T": (lambda c: c.link_loss_timeout_s, "link_loss_timeout_s"),
    "COM_OBL_RC_ACT": (lambda c: _OBL[c.offboard_loss_action], None),
    "NAV_DLL_ACT": (lambda c: _DLL[c.link_loss_action], None),
    "MPC_XY_CRUISE": (lambda c: c.dynamics.cruise_speed_mps, None),
    "MPC_XY_VEL_MAX": (lambda c: c.dynamics.max_horizontal_speed_mps, None),
    "MPC_Z_VEL_MAX_UP": (lambda c: c.dynamics.max_up_speed_mps, None),
    "MPC_Z_VEL_MAX_DN": (lambda c: c.dynamics.max_down_speed_mps, None),
    "MPC_Z_V_AUTO_UP": (lambda c: c.dynamics.max_up_speed_mps, None),
    "MPC_Z_V_AUTO_DN": (lambda c: c.dynamics.max_down_speed_mps, None),
    "MPC_TKO_SPEED": (lambda c: c.dynamics.takeoff_speed_mps, None),
    "MPC_LAND_SPEED": (lambda c: c.dynamics.land_speed_mps, None),
}
"""PX4 parameter -> (value from the config, settable config field or None)."""


class _SimulatedTruth:
    """:class:`~eaglemission.interfaces.truth.GroundTruth` of a :class:`SimulatedVehicle`."""

    description = "the simulated vehicle's true state"

    def __init__(self, vehicle: SimulatedVehicle) -> None:
        self._v = vehicle

    def available(self) -> bool:
        return self._v._dyn is not None

    def pose_at(self, timestamp_ns: int) -> tuple[XYZ, Quat] | None:
        return self._v.true_pose_at(timestamp_ns)

    def trajectory(self) -> list[VehicleState]:
        return self._v.trajectory()
