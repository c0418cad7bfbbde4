"""The simulated vehicle's engine: the dynamics and the shared autopilot model stepped lazily
on the injected clock, with the telemetry (estimate) and truth logs they produce.

:class:`SimulatedModel` is the base of :class:`~eaglemission.lab.vehicles.simulated.vehicle.SimulatedVehicle`,
which adds the Vehicle commands. Every call first integrates the model up to ``clock.now_ns()``
in whole internal steps; the autopilot runs after every step, then the logs.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import replace
from typing import Any, Self

import numpy as np
from eaglemission.drivers.vehicles.events import (
    EVENT_FAILSAFE,
    EVENT_MISSION,
    EVENT_MODE,
    EVENT_REFUSED,
    EVENT_STATUS,
)
from eaglemission.lab.vehicles.autopilot.model import (
    Autopilot,
    FailsafeAction,
    ModeSource,
)
from eaglemission.lab.vehicles.multicopter.dynamics import (
    MulticopterDynamics,
    Normals,
    speeds_within_envelope,
)
from eaglemission.lab.vehicles.simulated.config import (
    SimulatedVehicleConfig,
    autopilot_params,
)
from eaglemission.lab.vehicles.simulated.faults import SimulatedFaults
from eaglemission.lab.vehicles.simulated.link import LinkTiming
from eaglemission.lab.vehicles.simulated.state import estimated_state, true_state
from eaglemission.lab.vehicles.simulated.truth_log import TruthLog
from eaglemission.lab.world.synthetic import SyntheticWorldConfig
from numpy.typing import NDArray

from eaglemission.clock import Clock, MonotonicClock
from eaglemission.config import SafetyConfig
from eaglemission.errors import VehicleError
from eaglemission.telemetry.history import TelemetryHistory
from eaglemission.types import (
    XYZ,
    FlightMode,
    GeoPoint,
    Quat,
    VehicleEvent,
    VehicleState,
    Waypoint,
)


class _Reports:
    """The autopilot's reports as the simulated vehicle's events (and fresh telemetry)."""

    def __init__(self, vehicle: SimulatedModel) -> None:
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


class SimulatedModel:
    """The lazily stepped model behind a simulated vehicle (see the module docstring).

    Parameters (context)
    --------------------
    config : SimulatedVehicleConfig or None
    clock : any eaglemission Clock (``LoopClock`` under ``VirtualTimeLoop``, ``ManualClock``
        in unit tests); defaults to the host monotonic clock.
    simulation : SyntheticWorldConfig or None (wind, seed)
    safety : SafetyConfig or None: the autopilot's own speeds are set inside it (unless given)
    """

    def __init__(self, config: SimulatedVehicleConfig | None = None, *, clock: Clock | None = None,
                 simulation: SyntheticWorldConfig | None = None, safety: SafetyConfig | None = None,
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
        self._rangefinder_noise = Normals(np.random.default_rng(
            np.random.SeedSequence([self.seed, 0x52F])))
        self._events: list[VehicleEvent] = []
        self._waypoints: tuple[Waypoint, ...] = ()
        self.faults = SimulatedFaults(self)
        self.link = LinkTiming(self._history, TelemetryHistory(span_s=cfg.history_span_s))
        self._boot_ns = 0  # host time of the autopilot's boot (its timestamps count from it)
        self._tel_period_ns = int(round(1e9 / cfg.telemetry_rate_hz))
        self._next_tel_ns = 0
        self._truth = TruthLog(int(cfg.trajectory_max_s * cfg.dynamics.rate_hz))

    async def __aenter__(self) -> Self:
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
                ap.set_battery(self._battery_before_connect)
                if cfg.initial_altitude_m > 0:
                    ap.start_airborne()
                    self._status(f"Simulation starts airborne at {cfg.initial_altitude_m:g} m "
                                 "(armed, HOLD)")
                self._next_tel_ns = now
                self._boot_ns = now
                self._log_truth(dyn)
                self._sample_telemetry(dyn)
                self._status("Ready for takeoff")
            self._connected = True

    async def close(self) -> None:
        with self._lock:
            self._connected = False
            self._closed = True

    def state(self) -> VehicleState:
        self._require("state()")
        with self._lock:
            self._sync()
            frozen = self.faults.frozen_state
            if frozen is not None:
                return frozen
            latest = self._history.latest()
            assert latest is not None
            return self.link.deliver(latest, self.clock.now_ns())

    def state_at(self, timestamp_ns: int) -> VehicleState | None:
        """The pose at a host time from the samples received by now (see :mod:`.simulated_link`)."""
        self._require("state_at()")
        with self._lock:
            self._sync()
            self.link.receive_due(self.clock.now_ns())
        return self.link.ground.state_at(timestamp_ns)

    def events(self) -> Sequence[VehicleEvent]:
        with self._lock:
            self._sync_if_connected()
            return tuple(self._events)

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

    def true_motion_at(self, timestamp_ns: int) -> tuple[XYZ, XYZ] | None:
        """True velocity (NED, m/s) and angular velocity (NED, rad/s) at a host time, from the
        truth log's rows around it (what the synthetic cameras blur with); None outside it."""
        with self._lock:
            if self._dyn is None:
                return None
            self._sync_if_connected()
            return self._truth.motion_at(timestamp_ns, self._dyn.step_ns)

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
        faults = self.faults
        if faults.busy:
            faults.on_step(t)
        ap = self._ap
        assert ap is not None  # built with the dynamics
        setpoint = self.link.due_setpoint(t)  # a streamed setpoint arriving late (link_delay)
        if setpoint is not None and not faults.link_down:
            ap.set_setpoint(setpoint)
        ap.on_step(dyn)
        self._truth.append(dyn, armed=ap.armed, in_air=ap.land_detector.in_air, mode=ap.mode)
        if t >= self._next_tel_ns:
            self._next_tel_ns = t + self._tel_period_ns
            if not self.faults.link_down:
                self._sample_telemetry(dyn)

    def _log_truth(self, dyn: MulticopterDynamics) -> None:
        ap = self.autopilot
        self._truth.append(dyn, armed=ap.armed, in_air=ap.in_air, mode=ap.mode)

    def _sample_telemetry(self, dyn: MulticopterDynamics) -> None:
        rf = self.config.rangefinder
        noise = self._rangefinder_noise.next() if rf.enabled else 0.0
        state = estimated_state(dyn, self.autopilot, self.home, rf, noise)
        since_boot_ns = int((dyn.time_ns - self._boot_ns) * self.config.autopilot_clock_rate)
        sample = replace(state, autopilot_time_ns=since_boot_ns + self.link.clock_offset_ns)
        self._history.append(sample)
        self.link.send(sample)

    def _truth_vehicle_state(self, t: int, pos: XYZ, vel: XYZ, *, attitude_q: Quat,
                             armed: bool | None = None, in_air: bool | None = None,
                             mode: FlightMode | None = None) -> VehicleState:
        return true_state(self.autopilot, self.home, t, pos, vel, attitude_q=attitude_q,
                          armed=armed, in_air=in_air, mode=mode)

    def _refuse(self, name: str, result: str, detail: str, *, params: Any = None) -> None:
        self._event(EVENT_REFUSED, f"{name}(): {result}: {detail}", {"command": name, "result": result})
        raise VehicleError(result, f"{name}()", params, detail)


class SimulatedTruth:
    """:class:`~eaglemission.interfaces.truth.GroundTruth` of a :class:`SimulatedModel`."""

    description = "the simulated vehicle's true state"

    def __init__(self, vehicle: SimulatedModel) -> None:
        self._v = vehicle

    def available(self) -> bool:
        return self._v._dyn is not None

    def pose_at(self, timestamp_ns: int) -> tuple[XYZ, Quat] | None:
        return self._v.true_pose_at(timestamp_ns)

    def motion_at(self, timestamp_ns: int) -> tuple[XYZ, XYZ] | None:
        """Optional beyond the protocol: true velocity and angular velocity (NED)."""
        return self._v.true_motion_at(timestamp_ns)

    def trajectory(self) -> list[VehicleState]:
        return self._v.trajectory()
