"""Deterministic kinematic multicopter: the TRUE motion of a simulated vehicle.

Pure (no asyncio, no clock): time advances only through :meth:`MulticopterDynamics.step` /
:meth:`MulticopterDynamics.advance_to`, in whole internal steps of ``1 / params.rate_hz``, so the
trajectory depends only on the commands and the times they were issued, never on how often the
caller advances the model. The simulated vehicle (plugin ``simulated``) and the MAVLink
emulator both step this model.

Model (NED, metres, seconds), in the spirit of PX4's multicopter position controller:

* **Position loop** (on the *estimated* position, as a real autopilot does): the desired
  velocity points at the setpoint with magnitude ``min(v_max, k_p d, sqrt(2 a_brake d))`` (a
  braking profile, so the vehicle does not overshoot by more than the velocity loop's lag).
* **Velocity loop**: ``a_cmd = (v_des - v) / tau_v + drag v - d_hat`` where ``d_hat`` is a
  disturbance observer (the acceleration the thrust does not explain, low-pass filtered with
  ``wind_observer_time_s``): it learns the wind and rejects it with that lag, without the
  velocity overshoot an integrator would add.
  ``a_cmd`` is limited in magnitude (acceleration limit and ``g tan(max_tilt)``).
* **Attitude**: the thrust acceleration follows ``a_cmd`` with a first-order lag
  (``attitude_time_constant_s``); the body's z axis is aligned with the thrust, so the
  attitude follows the commanded acceleration: braking at ``a`` tilts the body (and a camera
  fixed to it) by ``atan(a / g)``. Yaw follows its setpoint at a limited rate.
* **Physics**: ``a = a_thrust + drag (wind - v)`` (air drag on the airspeed); the ground
  (``down = 0``) stops a descent and holds a landed vehicle in place.
* **Command latency**: a command takes effect ``command_latency_s`` after it was issued
  (link + autopilot reaction); internal commands (autopilot's own mode logic) can be immediate,
  and an immediate command drops the commands still in flight (the newest command wins).
* **Estimate**: :class:`EstimateModel` adds a slowly drifting, bounded error (an
  Ornstein-Uhlenbeck random walk of a few cm to dm, seeded) to the true position: that is what
  the autopilot reports and controls on; GPS loss makes it drift away linearly.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Annotated, Any, Literal

import numpy as np
from eaglemission.lab.vehicles.multicopter.direct import DirectSetpoint, DirectThrust
from eaglemission.lab.vehicles.multicopter.kinematics import (
    GRAVITY_MPS2,
    attitude_from_acceleration,
    stopping_point,
    wrap_deg,
)
from eaglemission.lab.vehicles.multicopter.sensors import (
    EstimateModel,
    Normals,
    RangefinderParams,
    rangefinder_reading_m,
)
from pydantic import BaseModel, ConfigDict, Field

from eaglemission.types import XYZ, Quat, Setpoint

__all__ = ["GRAVITY_MPS2", "DynamicsParams", "EstimateModel", "KinematicState",
           "MulticopterDynamics", "Normals", "RangefinderParams", "attitude_from_acceleration",
           "rangefinder_reading_m", "speeds_within_envelope", "stopping_point", "wrap_deg"]

LIFTOFF_ACCEL_MPS2 = 0.5  # upward thrust excess needed to leave the ground
ESTIMATE_DECIMATION = 4  # the estimate error is updated every 4th internal step

_Pos = Annotated[float, Field(gt=0, allow_inf_nan=False)]
_NonNeg = Annotated[float, Field(ge=0, allow_inf_nan=False)]


class DynamicsParams(BaseModel):
    """Limits and time constants of the kinematic multicopter (PX4 parameter names in
    brackets where one exists; defaults close to PX4 v1.16's, a little slower where that keeps
    tests short)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    rate_hz: Annotated[float, Field(ge=20, le=2000)] = 100.0
    max_horizontal_speed_mps: _Pos = 10.0  # [MPC_XY_VEL_MAX]
    cruise_speed_mps: _Pos = 5.0  # [MPC_XY_CRUISE] default for goto/mission/RTL legs
    max_up_speed_mps: _Pos = 3.0  # [MPC_Z_VEL_MAX_UP]
    max_down_speed_mps: _Pos = 1.5  # [MPC_Z_VEL_MAX_DN]
    max_horizontal_accel_mps2: _Pos = 3.0  # [MPC_ACC_HOR]
    max_vertical_accel_mps2: _Pos = 3.0  # [MPC_ACC_UP_MAX]
    max_tilt_deg: Annotated[float, Field(gt=0, le=60)] = 35.0  # [MPC_TILTMAX_AIR]
    max_yaw_rate_degps: _Pos = 60.0  # [MPC_YAWRAUTO_MAX]
    yaw_gain_per_s: _Pos = 2.5
    position_gain_per_s: _Pos = 1.0  # [MPC_XY_P]
    brake_accel_fraction: Annotated[float, Field(gt=0, le=1)] = 0.6
    velocity_time_constant_s: _Pos = 0.3
    wind_observer_time_s: _Pos = 1.0
    attitude_time_constant_s: _Pos = 0.08
    drag_per_s: _NonNeg = 0.3
    command_latency_s: _NonNeg = 0.03
    takeoff_speed_mps: _Pos = 1.5  # [MPC_TKO_SPEED]
    land_speed_mps: _Pos = 0.7  # [MPC_LAND_SPEED]
    estimate_horizontal_std_m: _NonNeg = 0.08
    estimate_vertical_std_m: _NonNeg = 0.04
    estimate_correlation_time_s: _Pos = 30.0
    estimate_max_error_m: _NonNeg = 0.3
    gps_loss_drift_mps: _NonNeg = 0.3
    wind_gust_std_mps: _NonNeg = 0.0
    wind_gust_time_s: _Pos = 2.0


def speeds_within_envelope(params: DynamicsParams, safety: Any) -> DynamicsParams:
    """The autopilot's own speeds (PX4 MPC_XY_CRUISE / MPC_XY_VEL_MAX / MPC_Z_VEL_MAX_UP /
    MPC_Z_VEL_MAX_DN) set inside the mission's safety envelope, as a field team sets PX4's:
    the envelope shapes only *our* setpoints, while autopilot-flown moves (RTL, land, takeoff)
    fly at these. Fields given explicitly in ``params`` are kept."""
    given = params.model_fields_set
    h, v = float(safety.max_horizontal_speed_mps), float(safety.max_vertical_speed_mps)
    derived = {"cruise_speed_mps": min(5.0, 0.9 * h), "max_horizontal_speed_mps": min(10.0, h),
               "max_up_speed_mps": min(3.0, 0.9 * v), "max_down_speed_mps": min(1.5, 0.9 * v)}
    update = {k: val for k, val in derived.items() if k not in given}
    return params.model_copy(update=update) if update else params


# ---------------------------------------------------------------------------------------------
# State and commands
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class KinematicState:
    """A snapshot of the model: truth, or the estimate (position + estimate error)."""

    time_ns: int
    position_ned_m: XYZ
    velocity_ned_mps: XYZ
    acceleration_ned_mps2: XYZ  # thrust acceleration, gravity compensated (what tilts the body)
    yaw_deg: float
    yaw_rate_degps: float
    on_ground: bool
    motors_on: bool

    @property
    def attitude_q(self) -> Quat:
        if self.on_ground and not self.motors_on:
            return attitude_from_acceleration((0.0, 0.0, 0.0), self.yaw_deg)
        return attitude_from_acceleration(self.acceleration_ned_mps2, self.yaw_deg)

    @property
    def tilt_deg(self) -> float:
        a = self.acceleration_ned_mps2
        return math.degrees(math.atan2(math.hypot(a[0], a[1]), GRAVITY_MPS2 - a[2]))

    @property
    def speed_mps(self) -> float:
        v = self.velocity_ned_mps
        return math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])


ControlMode = Literal["idle", "position", "velocity", "land", "acceleration", "attitude"]


@dataclass(frozen=True, slots=True)
class _Command:
    kind: Literal["position", "velocity", "hold", "land", "acceleration", "attitude"]
    target: XYZ = (0.0, 0.0, 0.0)
    yaw_deg: float | None = None
    max_speed_mps: float | None = None
    max_up_speed_mps: float | None = None
    max_down_speed_mps: float | None = None
    gain_per_s: float | None = None
    at_ne: tuple[float, float] | None = None  # land: where (None: the stopping point)
    yaw_rate_degps: float | None = None  # velocity / acceleration / attitude: turn at this rate
    rates_degps: tuple[float, float] | None = None  # attitude: roll / pitch rates (body rates)


@dataclass(frozen=True, slots=True)
class _Constants:
    dt: float
    kp: float
    two_a_brake_h: float
    two_a_brake_v: float
    v_h_max: float
    v_up_max: float
    v_down_max: float
    v_land: float
    inv_tau_v: float
    drag: float
    a_v_max: float
    k_yaw: float
    yaw_rate_max: float
    beta_obs: float
    gust_a: float
    gust_b: float


def _constants(p: DynamicsParams, dt: float, a_h_max: float) -> _Constants:
    gust_a = math.exp(-dt / p.wind_gust_time_s)
    return _Constants(
        dt=dt, kp=p.position_gain_per_s,
        two_a_brake_h=2.0 * a_h_max * p.brake_accel_fraction,
        two_a_brake_v=2.0 * p.max_vertical_accel_mps2 * p.brake_accel_fraction,
        v_h_max=p.max_horizontal_speed_mps, v_up_max=p.max_up_speed_mps,
        v_down_max=p.max_down_speed_mps, v_land=min(p.land_speed_mps, p.max_down_speed_mps),
        inv_tau_v=1.0 / p.velocity_time_constant_s, drag=p.drag_per_s,
        a_v_max=p.max_vertical_accel_mps2, k_yaw=p.yaw_gain_per_s,
        yaw_rate_max=p.max_yaw_rate_degps, beta_obs=dt / p.wind_observer_time_s,
        gust_a=gust_a, gust_b=math.sqrt(1.0 - gust_a * gust_a) * p.wind_gust_std_mps)


# ---------------------------------------------------------------------------------------------
# The model
# ---------------------------------------------------------------------------------------------
class MulticopterDynamics:
    """Kinematic multicopter with a PX4-like cascaded controller (see the module docstring).

    Parameters
    ----------
    params : DynamicsParams or None
        Limits and time constants (defaults when None).
    seed : int
        Seeds the estimate drift and the gusts; same seed + same commands = same trajectory.
    wind_ne_mps : (north, east) mean wind in m/s (``SyntheticWorldConfig.wind_ne_mps``).
    start_time_ns : model time of the initial state (the vehicle's clock at creation).
    estimate : EstimateModel or None
        The estimate error model; built from ``params`` when None.

    Examples
    --------
    >>> dyn = MulticopterDynamics(seed=1)
    >>> dyn.set_motors(True)
    >>> dyn.command_position(Setpoint(0.0, 0.0, -5.0, 0.0), immediate=True)
    >>> dyn.step(10.0)
    >>> round(-dyn.truth().position_ned_m[2])
    5
    """

    def __init__(
        self,
        params: DynamicsParams | None = None,
        *,
        seed: int = 0,
        wind_ne_mps: tuple[float, float] = (0.0, 0.0),
        start_time_ns: int = 0,
        estimate: EstimateModel | None = None,
    ) -> None:
        self.params = p = params or DynamicsParams()
        self.step_ns = int(round(1e9 / p.rate_hz))
        self.dt_s = self.step_ns * 1e-9
        self.time_ns = int(start_time_ns)
        self._target_ns = self.time_ns  # time asked for (may lie between steps)
        self.estimate_model = estimate or EstimateModel.from_params(p, seed=seed)
        self.wind_ne_mps = (float(wind_ne_mps[0]), float(wind_ne_mps[1]))
        self._gust_normals = Normals(np.random.default_rng(np.random.SeedSequence([int(seed), 0x61])))
        self._gust = [0.0, 0.0]
        # true state
        self.pn = self.pe = self.pd = 0.0
        self.vn = self.ve = self.vd = 0.0
        self.an = self.ae = self.ad = 0.0  # thrust acceleration (gravity compensated)
        self.yaw_deg = 0.0
        self.yaw_rate_degps = 0.0
        self.motors_on = False
        self.on_ground = True
        # controller
        self.mode: ControlMode = "idle"
        self._sp = (0.0, 0.0, 0.0)
        self._vel_cmd = (0.0, 0.0, 0.0)
        self._direct = DirectThrust()  # acceleration / attitude modes
        self._yaw_rate_cmd: float | None = None  # turn at this rate instead of to _yaw_sp
        self._yaw_sp = 0.0
        self._max_speed = p.cruise_speed_mps
        self._max_up = p.max_up_speed_mps
        self._max_down = p.max_down_speed_mps
        self._kp = p.position_gain_per_s
        self._dn, self._de = 0.0, 0.0  # disturbance (wind) estimate, m/s^2
        self._pending: deque[tuple[int, _Command]] = deque()
        # cached constants
        self._alpha_att = 1.0 - math.exp(-self.dt_s / p.attitude_time_constant_s)
        self._a_h_max = min(p.max_horizontal_accel_mps2,
                            GRAVITY_MPS2 * math.tan(math.radians(p.max_tilt_deg)))
        self._latency_ns = int(round(p.command_latency_s * 1e9))
        self._k = _constants(p, self.dt_s, self._a_h_max)
        self._est_count = 0

    # -- state -----------------------------------------------------------------------------------
    def reset(self, position_ned_m: XYZ = (0.0, 0.0, 0.0), yaw_deg: float = 0.0) -> None:
        """Put the vehicle at rest at a position (on the ground when ``down >= 0``)."""
        self.pn, self.pe, self.pd = (float(v) for v in position_ned_m)
        self.pd = min(self.pd, 0.0)
        self.vn = self.ve = self.vd = 0.0
        self.an = self.ae = self.ad = 0.0
        self.yaw_deg = self._yaw_sp = wrap_deg(float(yaw_deg))
        self.on_ground = self.pd >= 0.0
        self._sp = (self.pn, self.pe, self.pd)
        self._dn = self._de = 0.0
        self._pending.clear()

    def truth(self) -> KinematicState:
        return KinematicState(self.time_ns, (self.pn, self.pe, self.pd), (self.vn, self.ve, self.vd),
                              (self.an, self.ae, self.ad), self.yaw_deg, self.yaw_rate_degps,
                              self.on_ground, self.motors_on)

    def estimate(self) -> KinematicState:
        """What the autopilot believes: true position + estimate error (velocity and attitude
        are reported as true: their errors are small next to the position drift)."""
        en, ee, ed = self.estimate_model.error_ned_m
        return KinematicState(self.time_ns, (self.pn + en, self.pe + ee, self.pd + ed),
                              (self.vn, self.ve, self.vd), (self.an, self.ae, self.ad),
                              self.yaw_deg, self.yaw_rate_degps, self.on_ground, self.motors_on)

    def estimated_position(self) -> XYZ:
        en, ee, ed = self.estimate_model.error_ned_m
        return (self.pn + en, self.pe + ee, self.pd + ed)

    @property
    def setpoint_ned_m(self) -> XYZ:
        """The position the controller currently steers to (estimate frame)."""
        return self._sp

    @property
    def yaw_setpoint_deg(self) -> float:
        return self._yaw_sp

    # -- commands --------------------------------------------------------------------------------
    def _issue(self, cmd: _Command, immediate: bool) -> None:
        if immediate:
            # The newest command wins. Commands still in flight were issued *before* this one
            # (an external hold/setpoint a few ms ago): applying them after it, when their
            # latency elapses, would undo the autopilot's newer decision -- e.g. a
            # RETURN_TO_LAUNCH climb overwritten by the hold sent just before it, leaving the
            # vehicle hovering in RTL forever, since the mode logic commands each phase once.
            self._pending.clear()
            self._apply(cmd)
        else:
            self._pending.append((self._target_ns + self._latency_ns, cmd))

    def command_position(
        self,
        setpoint: Setpoint,
        *,
        max_speed_mps: float | None = None,
        max_up_speed_mps: float | None = None,
        max_down_speed_mps: float | None = None,
        gain_per_s: float | None = None,
        immediate: bool = False,
    ) -> None:
        """Fly to a NED position (estimate frame) and yaw. Speeds default to the cruise speed
        and the vertical limits; they are always capped by the params' limits. ``gain_per_s``
        replaces ``position_gain_per_s`` for this move (an autopilot-flown approach, slower
        than an offboard setpoint: :data:`~.autopilot_params.AutopilotParams`)."""
        self._issue(_Command("position", setpoint.position_ned_m, setpoint.yaw_deg, max_speed_mps,
                             max_up_speed_mps, max_down_speed_mps, gain_per_s), immediate)

    def command_velocity(self, velocity_ned_mps: XYZ, yaw_deg: float | None = None, *,
                         yaw_rate_degps: float | None = None, immediate: bool = False) -> None:
        """Track a NED velocity (limited by the params) and, if given, a yaw (or turn at
        ``yaw_rate_degps`` when no yaw is given)."""
        v = velocity_ned_mps
        self._issue(_Command("velocity", (float(v[0]), float(v[1]), float(v[2])), yaw_deg,
                             yaw_rate_degps=yaw_rate_degps), immediate)

    def command_direct(self, sp: DirectSetpoint, *, immediate: bool = False) -> None:
        """Fly an offboard acceleration, attitude or body-rate setpoint without the position
        and velocity loops."""
        v = (float(sp.values[0]), float(sp.values[1]), float(sp.values[2]))
        rates = (v[0], v[1]) if sp.kind == "rates" else None
        self._issue(_Command("acceleration" if sp.kind == "acceleration" else "attitude", v,
                             sp.yaw_deg, yaw_rate_degps=sp.yaw_rate_degps, rates_degps=rates),
                    immediate)

    def command_hold(self, *, immediate: bool = False) -> None:
        """Brake and hold the stopping point (PX4 Hold/Loiter)."""
        self._issue(_Command("hold"), immediate)

    def command_land(self, *, at_ne_m: tuple[float, float] | None = None,
                     immediate: bool = False) -> None:
        """Hold the horizontal stopping point (or fly to ``at_ne_m``, estimate frame: a
        landing at a destination) and descend at ``land_speed_mps``."""
        self._issue(_Command("land", at_ne=at_ne_m), immediate)

    def set_motors(self, on: bool) -> None:
        """Arm (motors spinning, controller active) or disarm (motors off: idle on the ground,
        free fall in the air). Immediate."""
        self.motors_on = bool(on)
        if on and self.mode == "idle":
            e = self.estimated_position()
            self._sp = e
            self._yaw_sp = self.yaw_deg
            self.mode = "position"
        if not on:
            self.mode = "idle"
            self._pending.clear()

    def clear_pending(self) -> None:
        """Drop commands still in flight (e.g. a link that went down)."""
        self._pending.clear()

    def _apply(self, cmd: _Command) -> None:
        p = self.params
        if not self.motors_on:
            return
        self._yaw_rate_cmd = cmd.yaw_rate_degps if cmd.yaw_deg is None else None
        if cmd.kind == "acceleration" or cmd.kind == "attitude":
            self._direct.set(cmd.kind, cmd.target, cmd.rates_degps, self.mode,
                             (self.an, self.ae, self.ad), self.yaw_deg)
            self.mode = cmd.kind
            if cmd.yaw_deg is not None:
                self._yaw_sp = wrap_deg(cmd.yaw_deg)
            return
        if cmd.kind == "position":
            self.mode = "position"
            self._sp = cmd.target
            if cmd.yaw_deg is not None:
                self._yaw_sp = wrap_deg(cmd.yaw_deg)
            self._max_speed = min(cmd.max_speed_mps or p.cruise_speed_mps, p.max_horizontal_speed_mps)
            self._max_up = min(cmd.max_up_speed_mps or p.max_up_speed_mps, p.max_up_speed_mps)
            self._max_down = min(cmd.max_down_speed_mps or p.max_down_speed_mps, p.max_down_speed_mps)
            self._kp = cmd.gain_per_s or p.position_gain_per_s
        elif cmd.kind == "velocity":
            self.mode = "velocity"
            self._vel_cmd = cmd.target
            if cmd.yaw_deg is not None:
                self._yaw_sp = wrap_deg(cmd.yaw_deg)
        else:
            a = self._a_h_max * p.brake_accel_fraction
            e = self.estimated_position()
            sn, se, _ = stopping_point(e, (self.vn, self.ve, self.vd), a)
            av = p.max_vertical_accel_mps2 * p.brake_accel_fraction
            sd = e[2] + self.vd * abs(self.vd) / (2.0 * av)
            if cmd.at_ne is not None:
                sn, se = cmd.at_ne
            self._sp = (sn, se, min(sd, 0.0) if cmd.kind == "hold" else sd)
            self._yaw_sp = self.yaw_deg
            self._max_speed = p.cruise_speed_mps
            self._max_up = p.max_up_speed_mps
            self._max_down = p.max_down_speed_mps
            self._kp = p.position_gain_per_s
            self.mode = "position" if cmd.kind == "hold" else "land"

    # -- integration -----------------------------------------------------------------------------
    def step(self, dt_s: float, on_step: Callable[[MulticopterDynamics], None] | None = None) -> None:
        """Advance by ``dt_s`` seconds (whole internal steps; a remainder carries over)."""
        if dt_s < 0:
            raise ValueError(f"dt_s: must be >= 0, got {dt_s}")
        self.advance_to(self._target_ns + int(round(dt_s * 1e9)), on_step)

    def advance_to(self, time_ns: int, on_step: Callable[[MulticopterDynamics], None] | None = None) -> None:
        """Integrate up to ``time_ns`` (the model's time becomes the last whole step <= it).
        ``on_step(self)`` runs after every internal step (mode logic, logging); it may issue
        commands."""
        if time_ns <= self._target_ns:
            return
        self._target_ns = time_ns
        step_ns = self.step_ns
        while self.time_ns + step_ns <= time_ns:
            self._step_once()
            if on_step is not None:
                on_step(self)

    def _step_once(self) -> None:
        c = self._k  # constants (see _constants)
        dt = c.dt
        self.time_ns += self.step_ns
        pend = self._pending
        while pend and pend[0][0] <= self.time_ns:
            self._apply(pend.popleft()[1])
        em = self.estimate_model
        self._est_count += 1
        if self._est_count >= ESTIMATE_DECIMATION:  # a slow process: 20-50 Hz is plenty
            self._est_count = 0
            em.step(dt * ESTIMATE_DECIMATION)
        # wind (mean + optional OU gusts)
        wn, we = self.wind_ne_mps
        if c.gust_b > 0.0:
            g = self._gust
            nx = self._gust_normals.next
            g[0] = c.gust_a * g[0] + c.gust_b * nx()
            g[1] = c.gust_a * g[1] + c.gust_b * nx()
            wn += g[0]
            we += g[1]

        if not self.motors_on:
            self._integrate_unpowered(dt)
            return

        # -- position loop -> desired velocity (estimate frame) --------------------------------
        err = em.error_ned_m
        mode = self.mode
        if mode == "acceleration" or mode == "attitude":
            cn, ce, cd = self._direct.command(mode, self.yaw_deg, dt)
            self._thrust(c, cn, ce, cd, wn, we)
            return
        if mode == "velocity":
            vn_d, ve_d, vd_d = self._vel_cmd
            h = math.hypot(vn_d, ve_d)
            vmax = c.v_h_max
            if h > vmax:
                vn_d, ve_d = vn_d * vmax / h, ve_d * vmax / h
            vd_d = max(-c.v_up_max, min(c.v_down_max, vd_d))
        else:
            kp = self._kp
            sp = self._sp
            en = sp[0] - (self.pn + err[0])
            ee = sp[1] - (self.pe + err[1])
            dist = math.hypot(en, ee)
            if dist > 1e-9:
                spd = min(self._max_speed, kp * dist, math.sqrt(c.two_a_brake_h * dist))
                vn_d, ve_d = en / dist * spd, ee / dist * spd
            else:
                vn_d = ve_d = 0.0
            if mode == "land":
                vd_d = c.v_land
            else:
                ed = sp[2] - (self.pd + err[2])
                dz = abs(ed)
                spd = min(kp * dz, math.sqrt(c.two_a_brake_v * dz))
                vd_d = min(spd, self._max_down) if ed > 0 else -min(spd, self._max_up)

        # -- velocity loop -> thrust acceleration ----------------------------------------------
        inv_tau = c.inv_tau_v
        drag = c.drag
        vn, ve, vd = self.vn, self.ve, self.vd
        cn = (vn_d - vn) * inv_tau + drag * vn - self._dn
        ce = (ve_d - ve) * inv_tau + drag * ve - self._de
        cd = (vd_d - vd) * inv_tau + drag * vd
        self._thrust(c, cn, ce, cd, wn, we)

    def _thrust(self, c: _Constants, cn: float, ce: float, cd: float, wn: float, we: float) -> None:
        """The commanded thrust acceleration, limited, through the attitude lag; yaw; physics."""
        dt, drag = c.dt, c.drag
        vn, ve, vd = self.vn, self.ve, self.vd
        h = math.hypot(cn, ce)
        a_h_max = self._a_h_max
        if h > a_h_max:
            cn, ce = cn * a_h_max / h, ce * a_h_max / h
        av_max = c.a_v_max
        cd = -av_max if cd < -av_max else (av_max if cd > av_max else cd)
        # attitude lag: the thrust follows the command
        al = self._alpha_att
        an = self.an + (cn - self.an) * al
        ae = self.ae + (ce - self.ae) * al
        ad = self.ad + (cd - self.ad) * al
        self.an, self.ae, self.ad = an, ae, ad

        # yaw
        on_ground = self.on_ground
        if on_ground:
            rate = 0.0
        else:
            yr = self._yaw_rate_cmd  # a commanded yaw rate, else towards the yaw setpoint
            rate = c.k_yaw * ((self._yaw_sp - self.yaw_deg + 180.0) % 360.0 - 180.0) if yr is None else yr
            rate = -c.yaw_rate_max if rate < -c.yaw_rate_max else (
                c.yaw_rate_max if rate > c.yaw_rate_max else rate)
            self.yaw_deg = (self.yaw_deg + rate * dt + 180.0) % 360.0 - 180.0
            if self._yaw_rate_cmd is not None:
                self._yaw_sp = self.yaw_deg
        self.yaw_rate_degps = rate

        # -- physics ---------------------------------------------------------------------------
        if on_ground and ad >= -LIFTOFF_ACCEL_MPS2:
            # thrust at or below hover (+ a liftoff threshold, so that centimetres of estimate
            # drift do not lift a landed vehicle): it sits on the ground, level
            self.vn = self.ve = self.vd = 0.0
            self.an = self.ae = 0.0
            self._dn = self._de = 0.0
            return
        a_n = an + drag * (wn - vn)
        a_e = ae + drag * (we - ve)
        a_d = ad - drag * vd
        # disturbance observer: what the thrust and the known drag do not explain
        beta = c.beta_obs
        self._dn += (a_n - an + drag * vn - self._dn) * beta
        self._de += (a_e - ae + drag * ve - self._de) * beta
        vn += a_n * dt
        ve += a_e * dt
        vd += a_d * dt
        self.vn, self.ve, self.vd = vn, ve, vd
        self.pn += vn * dt
        self.pe += ve * dt
        self.pd += vd * dt
        self._ground_contact()

    def _integrate_unpowered(self, dt: float) -> None:
        self.an = self.ae = 0.0
        self.ad = GRAVITY_MPS2  # no thrust: the "thrust acceleration" is +g (free fall)
        self.yaw_rate_degps = 0.0
        if self.on_ground:
            self.vn = self.ve = self.vd = 0.0
            self.ad = 0.0
            return
        drag = self.params.drag_per_s
        self.vn += -drag * self.vn * dt
        self.ve += -drag * self.ve * dt
        self.vd += (GRAVITY_MPS2 - drag * self.vd) * dt
        self.pn += self.vn * dt
        self.pe += self.ve * dt
        self.pd += self.vd * dt
        self._ground_contact()

    def _ground_contact(self) -> None:
        if self.pd >= 0.0:
            self.pd = 0.0
            if self.vd > 0.0:
                self.vd = 0.0
            self.on_ground = True
            self.vn = self.ve = 0.0
        else:
            self.on_ground = False
