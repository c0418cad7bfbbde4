"""Params of the ``simulated`` vehicle, the autopilot model as it configures it, and the PX4
parameters it answers."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Annotated, Literal

from eaglemission.drivers.vehicles.px4 import PX4_SITL_CLOCK_RATE
from eaglemission.lab.vehicles.autopilot.model import AutopilotParams, FailsafeAction
from eaglemission.lab.vehicles.multicopter.dynamics import DynamicsParams, RangefinderParams
from pydantic import BaseModel, ConfigDict, Field

from eaglemission.types import Waypoint

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
    autopilot_clock_rate: Annotated[float, Field(ge=0.9, le=1.1)] = PX4_SITL_CLOCK_RATE
    """The autopilot's clock (its telemetry stamps) against the host's: PX4 SITL's runs ~0.8 %
    slow (recorded); 1.0 for a hardware autopilot's crystal."""
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
    # RTL heights as PX4 v1.16's multicopter airframes set them (sihsim_quadx, recorded d-i:
    # 30 / 10 m / 45 deg; the parameters' own defaults, 60 / 30 m, are not what a quad flies):
    # near home (within 10 m) the return is at RTL_DESCEND_ALT, further out inside the cone
    rtl_return_altitude_m: _Pos = 30.0  # [RTL_RETURN_ALT]
    rtl_descend_altitude_m: _NonNeg = 10.0  # [RTL_DESCEND_ALT]
    rtl_cone_half_angle_deg: Annotated[float, Field(ge=0, lt=90)] = 45.0  # [RTL_CONE_ANG] 0: none
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
        rtl_descend_altitude_m=cfg.rtl_descend_altitude_m,
        rtl_cone_half_angle_deg=cfg.rtl_cone_half_angle_deg,
        mission_vertical_acceptance_m=cfg.mission_vertical_acceptance_m,
        gps_loss_failsafe_delay_s=cfg.gps_loss_failsafe_delay_s,
        gps_loss_action=FailsafeAction(cfg.gps_loss_action),
        battery_drain_per_s=cfg.battery_drain_per_s,
        min_arm_battery_fraction=cfg.min_arm_battery_fraction,
        battery_critical_fraction=cfg.battery_critical_fraction,
        battery_emergency_fraction=cfg.battery_emergency_fraction)


_OBL = {"position_no_rc": 0.0, "land": 4.0, "hold": 5.0}
_DLL = {"none": 0.0, "hold": 1.0, "return": 2.0, "land": 3.0}
PARAMETERS: dict[str, tuple[Callable[[SimulatedVehicleConfig], float], str | None]] = {
    "RTL_RETURN_ALT": (lambda c: c.rtl_return_altitude_m, "rtl_return_altitude_m"),
    "RTL_DESCEND_ALT": (lambda c: c.rtl_descend_altitude_m, "rtl_descend_altitude_m"),
    "RTL_CONE_ANG": (lambda c: c.rtl_cone_half_angle_deg, None),
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


def waypoint_problem(waypoints: Sequence[Waypoint]) -> str | None:
    """Why the simulated vehicle refuses a mission (None: it accepts it)."""
    if not waypoints:
        return "the mission has no waypoint"
    for i, w in enumerate(waypoints):
        vals = (w.north_m, w.east_m, w.altitude_m, w.acceptance_radius_m)
        if not all(math.isfinite(v) for v in vals) or w.acceptance_radius_m <= 0:
            return f"waypoint {i} is not finite or has acceptance_radius_m <= 0: {w}"
        if w.speed_mps is not None and not (math.isfinite(w.speed_mps) and w.speed_mps > 0):
            return f"waypoint {i}: speed_mps must be > 0, got {w.speed_mps}"
    return None
