"""The MAVLink emulator's configuration, PX4's stream profile and what it reports to tests."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Annotated, Any

from eaglemission.drivers.vehicles.px4 import PX4_SITL_CLOCK_RATE
from eaglemission.lab.vehicles.autopilot.params import AutopilotParams, FailsafeAction
from eaglemission.lab.vehicles.emulator.dialect import M
from eaglemission.lab.vehicles.multicopter.dynamics import (
    DynamicsParams,
    RangefinderParams,
    rangefinder_reading_m,
)
from pydantic import BaseModel, ConfigDict, Field

from eaglemission.types import FlightMode

# PX4 "Onboard" MAVLink profile rates, as recorded (README of px4_sitl_tlogs, item 1).
PX4_ONBOARD_RATES_HZ: dict[str, float] = {
    "HEARTBEAT": 1.0,
    "ATTITUDE": 100.0,
    "ATTITUDE_QUATERNION": 50.0,
    "GLOBAL_POSITION_INT": 50.0,
    "LOCAL_POSITION_NED": 30.0,
    "GPS_RAW_INT": 8.0,
    "SYS_STATUS": 5.0,
    "EXTENDED_SYS_STATE": 5.0,
    "MISSION_CURRENT": 1.0,
    "HOME_POSITION": 0.5,
    "BATTERY_STATUS": 0.5,
    "CURRENT_MODE": 0.5,
    "DISTANCE_SENSOR": 10.0,  # recorded 9.85 Hz; sent only with a rangefinder (config)
    "HIL_STATE_QUATERNION": 0.0,  # ground truth: not streamed until requested (as PX4 SIH)
    # MAVSDK's Telemetry imu, odometry, altitude, fixedwing_metrics, scaled_pressure and
    # unix_epoch_time streams (recorded rates)
    "HIGHRES_IMU": 50.0,
    "ODOMETRY": 30.0,
    "ALTITUDE": 10.0,
    "VFR_HUD": 10.0,
    "SCALED_PRESSURE": 1.0,
    "SYSTEM_TIME": 1.0,
}
HIL_STATE_DEFAULT_HZ = 50.0
"""Rate of HIL_STATE_QUATERNION when requested with interval 0 ("default")."""
MSG_IDS: dict[str, int] = {name: getattr(M, f"MAVLINK_MSG_ID_{name}") for name in
                           [*PX4_ONBOARD_RATES_HZ, "AUTOPILOT_VERSION", "GPS_GLOBAL_ORIGIN"]}
MSG_NAMES: dict[int, str] = {v: k for k, v in MSG_IDS.items()}

DISTANCE_NO_RETURN_CM = 65535
"""UINT16_MAX: what PX4 SIH sends beyond the maximum range ("lightware lw20 behaviour"; also
recorded after the landing of scenario a)."""
PX4_SIH_RANGEFINDER = RangefinderParams(enabled=True, noise_std_m=0.0, min_range_m=0.0,
                                        max_range_m=100.0)
"""PX4 SIH's downward distance sensor as recorded (g): min_distance 0, max_distance 10000 cm,
no noise (it matches the truth ``height / cos(tilt)`` within 0.7 cm RMS)."""
DISTANCE_SENSOR_MAX_HZ = 50.0
AUTO_APPROACH_GAIN_PER_S = 0.45
"""RTL's climb / return gain fitted to recorded f1 / f2 (AutopilotParams.auto_approach_gain_per_s)."""
"""PX4 SIH publishes its distance sensor at 50 Hz: a faster stream request sends no more."""
GPS_LOSS_FAILSAFE_DELAY_S = 1.0
"""How long after the GPS fix is lost the position counts as invalid (PX4 v1.16 has no
COM_POS_FS_DELAY parameter: the emulator reports none)."""


def distance_sensor_cm(true_down_m: float, cos_tilt: float, params: RangefinderParams,
                       noise: float) -> tuple[int, int, int]:
    """``(current_distance, min_distance, max_distance)`` of a DISTANCE_SENSOR message, in cm,
    as PX4 v1.16 with SIH sends them (recorded in ``px4_sitl_tlogs``): the reading of
    :func:`~eaglemission.lab.vehicles.multicopter.dynamics.rangefinder_reading_m` truncated to whole cm
    (PX4 assigns ``metres * 1e2f`` to a uint16); beyond the maximum range or with the beam at
    the horizon, :data:`DISTANCE_NO_RETURN_CM`; below the minimum (on the ground) the geometric
    range, which is outside ``[min, max]`` -- PX4 never withholds a reading, the receiver checks
    the range. A body origin below the ground plane gives a negative range, which wraps around
    in the uint16 (recorded g, fact 29: 0 at the contact, then 65523-65535 cm while SIH let the
    vehicle sink 0.01-0.14 m)."""
    min_cm = int(round(params.min_range_m * 100.0))
    max_cm = int(round(params.max_range_m * 100.0))
    r = rangefinder_reading_m(true_down_m, cos_tilt, params, noise)
    if r is not None:
        return min(DISTANCE_NO_RETURN_CM - 1, max(0, int(r * 100.0))), min_cm, max_cm
    if cos_tilt <= 0.1 or -true_down_m / cos_tilt > params.max_range_m:
        return DISTANCE_NO_RETURN_CM, min_cm, max_cm
    below_cm = int(-true_down_m / cos_tilt * 100.0)  # truncated toward 0, as C's float -> int
    if below_cm < 0:
        return below_cm % (DISTANCE_NO_RETURN_CM + 1), min_cm, max_cm
    return max(0, min(min_cm - 1, below_cm)), min_cm, max_cm


class EmulatorConfig(BaseModel):
    """Parameters of the emulated PX4 multicopter (defaults: PX4 v1.16 SITL, SIH quad)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    home_latitude_deg: Annotated[float, Field(ge=-90, le=90)] = 47.397742
    home_longitude_deg: Annotated[float, Field(ge=-180, le=180)] = 8.545594
    home_altitude_amsl_m: float = 489.4
    home_in_origin_ned_m: tuple[float, float, float] = (-0.35, 0.45, 0.0)
    """Home in the EKF-origin frame of LOCAL_POSITION_NED (PX4: decimetres apart)."""
    initial_yaw_deg: Annotated[float, Field(ge=-180, le=180)] = 0.0
    speedup: Annotated[float, Field(gt=0, le=50)] = 1.0
    clock_rate: Annotated[float, Field(ge=0.9, le=1.1)] = PX4_SITL_CLOCK_RATE
    """PX4's clock against the host's (before ``speedup``): SITL's runs slow, recorded 0.65-1.6 %
    (fact 22: HIGHRES_IMU.time_usec against the recording host), so its stamps fall behind the
    host's by ~8 ms a second and its durations (HEARTBEAT period, COM_DISARM_LAND) look ~0.8 %
    longer. 1.0 = a hardware autopilot's crystal (ppm)."""
    heartbeat_on_change: bool = False
    """Also send HEARTBEAT (and CURRENT_MODE) at once when mode/armed change. PX4 v1.16 does
    not (recorded d: 681 HEARTBEATs 1.005-1.048 s apart, none on change, so a mode change shows
    0.08-0.95 s after its ACCEPTED ack): off by default; on only makes a client's waits shorter
    than they can be on PX4."""
    double_set_mode_ack: bool = True
    stream_rates_hz: dict[str, float] = Field(default_factory=lambda: dict(PX4_ONBOARD_RATES_HZ))
    tick_hz: Annotated[float, Field(ge=20, le=1000)] = 200.0
    seed: int = 0
    wind_ne_mps: tuple[float, float] = (0.0, 0.0)
    battery_drain_per_s: Annotated[float, Field(ge=0, le=1)] = 0.0005
    """Battery fraction used per second of flight (emulator time)."""
    battery_full_v: Annotated[float, Field(gt=0)] = 16.8
    battery_empty_v: Annotated[float, Field(gt=0)] = 14.0
    takeoff_spool_s: Annotated[float, Field(ge=0, le=10)] = 1.0
    """Emulator seconds between the takeoff command and lift-off (PX4 SIH: about 1.8 s)."""
    landed_detect_s: Annotated[float, Field(ge=0, le=10)] = 3.9
    """Emulator seconds from touchdown to "Landing detected" (recorded e: 3.16-6.89 s, median
    3.88 s, n = 5; f1/f2: 2.2 / 3.1 s); auto-disarm follows COM_DISARM_LAND later."""
    dynamics: DynamicsParams = Field(default_factory=DynamicsParams)
    """The vehicle model (the ``simulated`` plugin's); MPC_* parameters report its limits."""
    rangefinder: RangefinderParams = Field(default_factory=RangefinderParams)
    """A downward distance sensor (the ``simulated`` plugin's): DISTANCE_SENSOR from the TRUE
    pose, seeded noise; disabled by default (then no DISTANCE_SENSOR, as PX4 without one)."""
    params: dict[str, float] = Field(default_factory=dict)
    """Overrides of PX4 parameters (names from PX4 v1.16's set: ``px4.default_params()``)."""
    sysid: Annotated[int, Field(ge=1, le=255)] = 1
    compid: Annotated[int, Field(ge=1, le=255)] = 1


@dataclass(frozen=True)
class EmulatorSnapshot:
    """What the emulator is doing, for tests (truth and what it reports)."""

    sim_time_s: float
    mode: FlightMode
    armed: bool
    landed_state: int
    true_position_ned_m: tuple[float, float, float]
    estimate_position_ned_m: tuple[float, float, float]
    velocity_ned_mps: tuple[float, float, float]
    yaw_deg: float
    battery_remaining: float
    gps_ok: bool
    failsafe: bool
    gripper: str
    mission_current: int
    mission_count: int
    offboard_setpoint: tuple[float, float, float, float] | None
    true_attitude_q: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Traffic:
    """One recorded message: wall time, direction ('out' = emulator -> client), message, and
    the emulator's time (PX4's clock): for a message sent, that of the vehicle step that sent
    it (a land detector's STATUSTEXT carries its step's time, whatever the tick's length)."""

    wall_s: float
    direction: str
    msg: Any
    sim_s: float = 0.0


def emulator_autopilot_params(cfg: EmulatorConfig, p: Callable[[str], float],
                              drain_per_s: float) -> AutopilotParams:
    """The shared autopilot model configured from the emulator's PX4 parameters (``p(name)``)
    and config. Where the emulator behaves differently from the simulated vehicle, the values
    keep the emulator's behaviour (see AutopilotParams)."""
    low_bat = int(p("COM_LOW_BAT_ACT"))
    return AutopilotParams(
        home_altitude_amsl_m=cfg.home_altitude_amsl_m, cruise_speed_mps=p("MPC_XY_CRUISE"),
        takeoff_speed_mps=p("MPC_TKO_SPEED"), offboard_max_speed_mps=p("MPC_XY_VEL_MAX"),
        takeoff_spoolup_s=cfg.takeoff_spool_s, takeoff_ramp_s=0.0,
        takeoff_accept_below_m=p("NAV_MC_ALT_RAD"), takeoff_accept_above_m=math.inf,
        land_detect_s=cfg.landed_detect_s, auto_disarm_after_land_s=p("COM_DISARM_LAND"),
        auto_disarm_preflight_s=cfg.landed_detect_s + p("COM_DISARM_LAND"),
        preflight_disarm_text="Disarmed by landing", auto_disarm_spares_climb=False,
        disarm_restores_intended_mode=True, offboard_loss_timeout_s=p("COM_OF_LOSS_T"),
        offboard_loss_action=FailsafeAction.from_com_obl_rc_act(int(p("COM_OBL_RC_ACT"))),
        rtl_return_altitude_m=p("RTL_RETURN_ALT"), rtl_land_max_speed_mps=math.inf,
        rtl_land_radius_m=p("NAV_ACC_RAD"),
        rtl_descend_altitude_m=p("RTL_DESCEND_ALT"), rtl_cone_half_angle_deg=p("RTL_CONE_ANG"),
        auto_up_speed_mps=p("MPC_Z_V_AUTO_UP"), auto_down_speed_mps=p("MPC_Z_V_AUTO_DN"),
        auto_approach_gain_per_s=AUTO_APPROACH_GAIN_PER_S,
        mission_vertical_acceptance_m=p("NAV_MC_ALT_RAD"),
        mission_acceptance_radius_m=p("NAV_ACC_RAD"), mission_end_brake=True,
        gps_loss_failsafe_delay_s=GPS_LOSS_FAILSAFE_DELAY_S, gps_loss_action=FailsafeAction.LAND,
        gps_failsafe_text="Failsafe activated: no position estimate, landing",
        battery_drain_per_s=drain_per_s, battery_drain_on_ground=False,
        min_arm_battery_fraction=p("BAT_CRIT_THR"), battery_low_fraction=p("BAT_LOW_THR"),
        battery_critical_fraction=p("BAT_CRIT_THR"),
        battery_emergency_fraction=p("BAT_EMERGEN_THR"),
        battery_critical_action={2: FailsafeAction.LAND, 3: FailsafeAction.RETURN}.get(low_bat),
        battery_emergency_action=FailsafeAction.LAND if low_bat in (2, 3) else None,
        battery_warnings=True, battery_check_in_flight_only=False)
