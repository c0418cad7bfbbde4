"""Simulated vehicle (plugin ``simulated``): an in-process, deterministic, PX4-like multicopter.

No MAVLink: the :class:`~eaglemission.drivers.vehicles.dynamics.MulticopterDynamics` model and
the PX4-like :class:`~eaglemission.drivers.vehicles.autopilot.Autopilot` on top of it (the model
the MAVLink emulator drives too) are stepped *lazily* up to ``clock.now_ns()`` at every call (in
whole internal steps, so the result does not depend on how tasks are scheduled). What the
autopilot does is described in :mod:`~eaglemission.drivers.vehicles.autopilot`; this module adds
what a MAVSDK client sees:

* commands return when accepted, like MAVSDK's, and are refused with MAVSDK's result codes
  (arming when not armable, takeoff while disarmed, disarm in the air...); the motion starts
  ``command_latency_s`` later;
* telemetry is the drifting *estimate* (what PX4 reports), sampled at ``telemetry_rate_hz``
  into a :class:`~eaglemission.telemetry.TelemetryHistory`; the *truth* (what the synthetic
  cameras and the evaluator use) is logged at every internal step (:mod:`.truth_log`).

Fault injection for tests and the sim world (:mod:`.simulated_faults`): ``inject_link_loss``,
``inject_gps_loss``, ``set_battery_fraction``, ``pilot_take_control``, ``deny_next_command``.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Sequence
from typing import Annotated, Any, Literal

import numpy as np
from eaglemission.drivers.vehicles.autopilot import (
    Autopilot,
    AutopilotParams,
    FailsafeAction,
    ModeSource,
)
from eaglemission.drivers.vehicles.autopilot_mission import MissionItem
from eaglemission.drivers.vehicles.dynamics import (
    DynamicsParams,
    MulticopterDynamics,
    RangefinderParams,
    _Normals,
    rangefinder_reading_m,
    speeds_within_envelope,
)
from eaglemission.drivers.vehicles.events import (
    EVENT_FAILSAFE,
    EVENT_GRIPPER,
    EVENT_MISSION,
    EVENT_MODE,
    EVENT_REFUSED,
    EVENT_STATUS,
)
from eaglemission.drivers.vehicles.simulated_faults import COMMANDS, SimulatedFaults
from eaglemission.drivers.vehicles.truth_log import TruthLog, body_attitude
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from eaglemission.clock import Clock, MonotonicClock
from eaglemission.config import SafetyConfig, SimulationConfig
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

__all__ = ["COMMANDS", "PARAMETERS", "SimulatedVehicle", "SimulatedVehicleConfig", "autopilot_params"]

_Pos = Annotated[float, Field(gt=0, allow_inf_nan=False)]
_NonNeg = Annotated[float, Field(ge=0, allow_inf_nan=False)]
_Frac = Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)]


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


def autopilot_params(cfg: SimulatedVehicleConfig) -> AutopilotParams:
    """The shared autopilot model as the simulated vehicle configures it."""
    d = cfg.dynamics
    tol = cfg.takeoff_altitude_tolerance_m
    return AutopilotParams(
        home_altitude_amsl_m=cfg.home_altitude_amsl_m, cruise_speed_mps=d.cruise_speed_mps,
        takeoff_speed_mps=d.takeoff_speed_mps, offboard_max_speed_mps=d.max_horizontal_speed_mps,
        takeoff_spoolup_s=cfg.takeoff_spoolup_s, takeoff_ramp_s=cfg.takeoff_ramp_s,
        takeoff_accept_below_m=tol, takeoff_accept_above_m=tol,
        in_air_altitude_m=cfg.in_air_altitude_m, land_detect_s=cfg.land_detect_s,
        auto_disarm_after_land_s=cfg.auto_disarm_after_land_s,
        auto_disarm_preflight_s=cfg.auto_disarm_preflight_s,
        offboard_loss_timeout_s=cfg.offboard_loss_timeout_s,
        offboard_loss_action=FailsafeAction(cfg.offboard_loss_action),
        offboard_loss_land_after_s=cfg.offboard_loss_land_after_s,
        position_no_rc_descent_mps=cfg.position_no_rc_descent_mps,
        rtl_return_altitude_m=cfg.rtl_return_altitude_m,
        mission_vertical_acceptance_m=cfg.mission_vertical_acceptance_m,
        gps_loss_failsafe_delay_s=cfg.gps_loss_failsafe_delay_s,
        gps_loss_action=FailsafeAction(cfg.gps_loss_action),
        battery_drain_per_s=cfg.battery_drain_per_s,
        min_arm_battery_fraction=cfg.min_arm_battery_fraction,
        battery_critical_fraction=cfg.battery_critical_fraction,
        battery_emergency_fraction=cfg.battery_emergency_fraction)


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


class _Reports:
    """The autopilot's reports as the simulated vehicle's events (and fresh telemetry)."""

    def __init__(self, vehicle: SimulatedVehicle) -> None:
        self._v = vehicle

    def on_status(self, text: str, severity: str) -> None:
        self._v._event(EVENT_STATUS, text, {"severity": severity})

    def on_mode(self, old: FlightMode, new: FlightMode, source: ModeSource) -> None:
        self._v._event(EVENT_MODE, f"{old.value} -> {new.value}",
                       {"from": old.value, "to": new.value, "source": source})
        self._v._refresh_telemetry()

    def on_failsafe(self, reason: str, action: FailsafeAction) -> None:
        self._v._event(EVENT_FAILSAFE, f"{reason}: {action.value}",
                       {"reason": reason, "action": action.value})

    def on_armed(self, armed: bool) -> None:
        self._v._refresh_telemetry()

    def on_mission_item(self, index: int, total: int) -> None:
        self._v._event(EVENT_MISSION, f"Mission item {index} reached",
                       {"index": index, "total": total})

    def on_gps(self, ok: bool) -> None:
        if ok:
            self.on_status("GPS regained", "info")


class SimulatedVehicle:
    """Deterministic in-process PX4-like multicopter. See the module docstring.

    Parameters (context)
    --------------------
    config : SimulatedVehicle.Config or None
    clock : any eaglemission Clock (``LoopClock`` under ``VirtualTimeLoop``, ``ManualClock``
        in unit tests); defaults to the host monotonic clock.
    simulation : SimulationConfig or None (wind, seed)
    safety : SafetyConfig or None: the autopilot's own speeds are set inside it (unless given)
    """

    Config = SimulatedVehicleConfig
    description = "In-process deterministic PX4-like multicopter (truth + drifting estimate), no MAVLink"

    simulated = True  # no aircraft behind it: the assembly asks no arming confirmation

    def __init__(self, config: SimulatedVehicleConfig | None = None, *, clock: Clock | None = None,
                 simulation: SimulationConfig | None = None, safety: SafetyConfig | None = None,
                 **_context: Any) -> None:
        cfg = config or SimulatedVehicleConfig()
        if safety is not None:  # the autopilot's own speeds inside the envelope (unless given)
            cfg = cfg.model_copy(update={"dynamics": speeds_within_envelope(cfg.dynamics, safety)})
        self.config = cfg
        self.clock: Clock = clock or MonotonicClock()
        self.simulation = simulation
        seed = cfg.seed if cfg.seed is not None else (simulation.seed if simulation else 0)
        self.seed = int(seed)
        wind = simulation.wind_ne_mps if simulation else (0.0, 0.0)
        self.wind_ne_mps = (float(wind[0]), float(wind[1]))
        self.home = GeoPoint(cfg.home_latitude_deg, cfg.home_longitude_deg, cfg.home_altitude_amsl_m)
        self._lock = threading.RLock()
        self._dyn: MulticopterDynamics | None = None
        self._ap: Autopilot | None = None
        self._battery_before_connect = 1.0
        self._connected = False
        self._closed = False
        self._history = TelemetryHistory(span_s=cfg.history_span_s)
        self._rangefinder_noise = _Normals(np.random.default_rng(
            np.random.SeedSequence([self.seed, 0x52F])))
        self._events: list[VehicleEvent] = []
        self._waypoints: tuple[Waypoint, ...] = ()
        self.faults = SimulatedFaults(self)
        self._tel_period_ns = int(round(1e9 / cfg.telemetry_rate_hz))
        self._next_tel_ns = 0
        self._truth = TruthLog(int(cfg.trajectory_max_s * cfg.dynamics.rate_hz))

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
                cfg = self.config
                dyn = MulticopterDynamics(cfg.dynamics, seed=self.seed,
                                          wind_ne_mps=self.wind_ne_mps, start_time_ns=now)
                self._dyn = dyn
                dyn.reset((0.0, 0.0, -cfg.initial_altitude_m), cfg.initial_yaw_deg)
                ap = self._ap = Autopilot(dyn, autopilot_params(cfg), _Reports(self))
                ap.battery = self._battery_before_connect
                if cfg.initial_altitude_m > 0:
                    ap.start_airborne()
                    self._status(f"Simulation starts airborne at {cfg.initial_altitude_m:g} m "
                                 "(armed, HOLD)")
                self._next_tel_ns = now
                self._log_truth(dyn)
                self._sample_telemetry(dyn)
                self._status("Ready for takeoff")
            self._connected = True

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
            frozen = self.faults.frozen_state
            if frozen is not None:
                return frozen
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
            m = self.autopilot.mission
            return MissionProgress(m.current, len(m.items))

    @property
    def _mission(self) -> tuple[Waypoint, ...]:
        """The uploaded waypoints (what reached the vehicle; for tests)."""
        return self._waypoints

    # ------------------------------------------------------------------------------------------
    # commands
    # ------------------------------------------------------------------------------------------
    async def arm(self) -> None:
        await self._command("arm")
        with self._lock:
            ap = self.autopilot
            if ap.armed:
                return
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
            ap.set_setpoint(setpoint)

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
            if self._ap is not None:
                self._ap.params = autopilot_params(self.config)

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
    def autopilot(self) -> Autopilot:
        """The autopilot model (after :meth:`connect`)."""
        if self._ap is None:
            raise VehicleError("NO_SYSTEM", "autopilot", None,
                               "not connected: call `await vehicle.connect()` (or use `async with`)")
        return self._ap

    @property
    def gripper_closed(self) -> bool:
        return self._ap is not None and self._ap.gripper == "grab"

    def true_state(self) -> VehicleState:
        """The TRUE state now (what the synthetic cameras and the evaluator use)."""
        self._require("true_state()")
        with self._lock:
            dyn = self._sync()
            truth = dyn.truth()
            return self._truth_vehicle_state(dyn.time_ns, truth.position_ned_m,
                                             (dyn.vn, dyn.ve, dyn.vd), attitude_q=truth.attitude_q)

    def true_pose_at(self, timestamp_ns: int) -> tuple[XYZ, Quat] | None:
        """True position and attitude at a host time, interpolated from the truth log; None
        outside it (before the first sample, or later than now)."""
        with self._lock:
            if self._dyn is None:
                return None
            self._sync_if_connected()
            return self._truth.pose_at(timestamp_ns, self._dyn.step_ns)

    def trajectory(self, *, since_ns: int | None = None, every_s: float | None = None) -> list[VehicleState]:
        """TRUE states (with the armed / in-air / mode of that moment) at every internal step,
        or every ``every_s`` seconds, oldest first."""
        with self._lock:
            self._sync_if_connected()
            return self._truth.states(self._truth_vehicle_state, since_ns=since_ns, every_s=every_s)

    def trajectory_array(self, *, since_ns: int | None = None) -> NDArray[np.float64]:
        """Truth log as an (N, 11) array: t_ns, north, east, down, vn, ve, vd, an, ae, ad, yaw_deg."""
        with self._lock:
            self._sync_if_connected()
            return self._truth.array(since_ns=since_ns)

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

    # ------------------------------------------------------------------------------------------
    # internals
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
        with self._lock:
            self.faults.check_deny(name, *params)
        return dyn

    def _refuse(self, name: str, result: str, detail: str, *, params: Any = None) -> None:
        self._event(EVENT_REFUSED, f"{name}(): {result}: {detail}", {"command": name, "result": result})
        raise VehicleError(result, f"{name}()", params, detail)

    def _require_flying(self, name: str, params: Any) -> None:
        if not self.autopilot.armed:
            self._refuse(name, "COMMAND_DENIED", "vehicle not armed: arm and take off first", params=params)
        if not self.autopilot.in_air:
            self._refuse(name, "COMMAND_DENIED", "vehicle on the ground: take off first", params=params)

    def _event(self, kind: str, text: str, data: dict[str, object] | None = None) -> None:
        t = self._dyn.time_ns if self._dyn is not None else self.clock.now_ns()
        self._events.append(VehicleEvent(t, kind, text, dict(data or {})))

    def _status(self, text: str, severity: str = "info") -> None:
        self._event(EVENT_STATUS, text, {"severity": severity})

    def _refresh_telemetry(self) -> None:
        """A state change (mode, armed) shows in telemetry at once (a fresh sample now)."""
        if self._dyn is not None and not self.faults.link_down:
            self._sample_telemetry(self._dyn)

    def _on_step(self, dyn: MulticopterDynamics) -> None:
        """After every internal step: the injected faults, the autopilot, the logs."""
        t = dyn.time_ns
        self.faults.on_step(t)
        ap = self.autopilot
        ap.on_step(dyn)
        self._log_truth(dyn)
        if t >= self._next_tel_ns:
            self._next_tel_ns = t + self._tel_period_ns
            if not self.faults.link_down:
                self._sample_telemetry(dyn)

    def _log_truth(self, dyn: MulticopterDynamics) -> None:
        ap = self.autopilot
        self._truth.append(dyn, armed=ap.armed, in_air=ap.in_air, mode=ap.mode)

    def _battery_voltage(self) -> float:
        return 4.0 * (3.5 + 0.7 * self.autopilot.battery)  # 4S LiPo

    def _sample_telemetry(self, dyn: MulticopterDynamics) -> None:
        ap = self.autopilot
        en, ee, ed = dyn.estimated_position()
        q = body_attitude(dyn.an, dyn.ae, dyn.ad, dyn.yaw_deg, on_ground=dyn.on_ground)
        rf = self.config.rangefinder
        distance = None
        if rf.enabled:  # the beam follows the TRUE pose
            distance = rangefinder_reading_m(dyn.pd, down_axis_cos_tilt(q), rf,
                                             self._rangefinder_noise.next())
        self._history.append(VehicleState(
            timestamp_ns=dyn.time_ns,
            position_ned_m=(en, ee, ed),
            velocity_ned_mps=(dyn.vn, dyn.ve, dyn.vd),
            attitude_q=q,
            angular_velocity_frd_radps=(0.0, 0.0, math.radians(dyn.yaw_rate_degps)),
            geodetic=ned_to_geodetic(self.home, en, ee, ed),
            relative_altitude_m=-ed,
            home=self.home,
            armed=ap.armed,
            in_air=ap.in_air,
            flight_mode=ap.mode,
            battery_remaining=ap.battery,
            battery_voltage_v=self._battery_voltage(),
            position_valid=ap.position_valid,
            gps_fix=ap.gps_ok,
            link_ok=True,
            armable=not ap.armed and not ap.not_armable_reason(),
            distance_to_ground_m=distance,
        ))

    def _truth_vehicle_state(self, t: int, pos: XYZ, vel: XYZ, *, attitude_q: Quat,
                             armed: bool | None = None, in_air: bool | None = None,
                             mode: FlightMode | None = None) -> VehicleState:
        ap = self.autopilot
        armed = ap.armed if armed is None else armed
        return VehicleState(
            timestamp_ns=t, position_ned_m=pos, velocity_ned_mps=vel, attitude_q=attitude_q,
            geodetic=ned_to_geodetic(self.home, *pos), relative_altitude_m=-pos[2], home=self.home,
            armed=armed, in_air=ap.in_air if in_air is None else in_air,
            flight_mode=ap.mode if mode is None else mode,
            battery_remaining=ap.battery, battery_voltage_v=self._battery_voltage(),
            position_valid=True, gps_fix=True, link_ok=True, armable=not armed)


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
