"""What the shared autopilot model (:mod:`.autopilot`) watches after every step: the land
detector (takeoff / landing detected, auto-disarm), GPS and the battery."""

from __future__ import annotations

from typing import TYPE_CHECKING

from eaglemission.lab.vehicles.autopilot.params import (
    BATTERY_NAMES,
    POSITION_MODES,
    PREFLIGHT_EXEMPT,
)

if TYPE_CHECKING:  # the autopilot owns its monitors; imported for the annotations only
    from eaglemission.lab.vehicles.autopilot.model import Autopilot


class LandDetector:
    """PX4's land detector as the vehicles report it: "Takeoff detected" above
    ``in_air_altitude_m`` off the ground, "Landing detected" after ``land_detect_s`` on it;
    auto-disarm COM_DISARM_LAND after a landing, COM_DISARM_PRFLT after arming without a takeoff.

    As on PX4 v1.16 (Commander's ``_auto_disarm_landed`` hysteresis, recorded e): the
    COM_DISARM_LAND timer starts at "Landing detected" and only "Takeoff detected" stops it;
    an ARM command while armed changes nothing. A takeoff commanded in that window that is
    not detected before the timer runs out is disarmed mid-takeoff (unless
    ``auto_disarm_spares_climb``)."""

    def __init__(self, autopilot: Autopilot) -> None:
        self._ap = autopilot
        self.in_air = False
        self._ground_since_ns: int | None = None
        self._landed_ns: int | None = None
        self._flew_since_arm = False
        self._armed_ns = 0

    @property
    def armed_ns(self) -> int:
        """When the vehicle was last armed (its motors spool up from then)."""
        return self._armed_ns

    def on_arm(self, t: int) -> None:
        self._armed_ns = t
        self._flew_since_arm = False
        self._landed_ns = None

    def airborne(self) -> None:
        self.in_air = True
        self._flew_since_arm = True

    def step(self, t: int) -> None:
        ap = self._ap
        dyn, p = ap.dyn, ap.params
        if not dyn.on_ground and -dyn.pd >= p.in_air_altitude_m and not self.in_air:
            self.in_air = True
            self._flew_since_arm = True
            self._ground_since_ns = None
            self._landed_ns = None  # PX4: the COM_DISARM_LAND timer runs while "landed" only
            ap.status("Takeoff detected")
        if dyn.on_ground:
            if self._ground_since_ns is None:
                self._ground_since_ns = t
            if self.in_air and t - self._ground_since_ns >= p.land_detect_s * 1e9:
                self.in_air = False
                self._landed_ns = t
                ap.status("Landing detected")
        else:
            self._ground_since_ns = None
        spared = p.auto_disarm_spares_climb and ap.climbing()
        if (self._landed_ns is not None and not self.in_air and not spared
                and t - self._landed_ns >= p.auto_disarm_after_land_s * 1e9):
            self._landed_ns = None
            ap.disarm("Disarmed by landing")
        elif (p.auto_disarm_preflight_s is not None and not self._flew_since_arm and dyn.on_ground
              and not (spared if p.auto_disarm_spares_climb else ap.mode in PREFLIGHT_EXEMPT)
              and t - self._armed_ns >= p.auto_disarm_preflight_s * 1e9):
            ap.disarm(p.preflight_disarm_text)


class GpsMonitor:
    """GPS lost for a while: the estimate drifts (the dynamics' estimate model), the position
    is invalid after ``gps_loss_failsafe_delay_s`` and the GPS-loss failsafe fires (once)."""

    def __init__(self, autopilot: Autopilot) -> None:
        self._ap = autopilot
        self._down_until_ns: int | None = None
        self._down_since_ns = 0
        self._failsafe_done = False

    @property
    def ok(self) -> bool:
        return self._down_until_ns is None

    def position_valid(self) -> bool:
        if self._down_until_ns is None:
            return True
        ap = self._ap
        return (ap.dyn.time_ns - self._down_since_ns) < ap.params.gps_loss_failsafe_delay_s * 1e9

    def loss(self, duration_s: float) -> bool:
        """No GPS for ``duration_s`` (extends a loss under way); True when it starts now."""
        dyn = self._ap.dyn
        t = dyn.time_ns
        started = self._down_until_ns is None
        if started:
            self._down_since_ns = t
            self._failsafe_done = False
            dyn.estimate_model.set_gps(False)
        self._down_until_ns = t + int(round(duration_s * 1e9))
        return started

    def step(self, t: int) -> None:
        if self._down_until_ns is None:
            return
        ap = self._ap
        if t >= self._down_until_ns:
            self._down_until_ns = None
            ap.dyn.estimate_model.set_gps(True)
            ap.listener.on_gps(True)
        elif (not self._failsafe_done
              and t - self._down_since_ns >= ap.params.gps_loss_failsafe_delay_s * 1e9):
            self._failsafe_done = True
            if ap.armed and ap.in_air and ap.mode in POSITION_MODES:
                if ap.params.gps_failsafe_text:
                    ap.status(ap.params.gps_failsafe_text, "critical")
                ap.failsafe("No valid position estimate (GPS lost)", ap.params.gps_loss_action)


class BatteryMonitor:
    """The battery drains while flying; each level crossed (low, critical, emergency) is
    reported / acted on once (BAT_*_THR, COM_LOW_BAT_ACT)."""

    def __init__(self, autopilot: Autopilot) -> None:
        self._ap = autopilot
        self.fraction = 1.0
        self._level = 0  # 0 ok, 1 low, 2 critical, 3 emergency (handled)

    def level_of(self, fraction: float) -> int:
        p = self._ap.params
        if fraction <= p.battery_emergency_fraction:
            return 3
        if fraction <= p.battery_critical_fraction:
            return 2
        return int(p.battery_low_fraction is not None and fraction <= p.battery_low_fraction)

    def set(self, fraction: float) -> None:
        """The remaining battery (0..1); the levels already handled above it are forgotten."""
        self.fraction = float(fraction)
        self._level = min(self._level, self.level_of(self.fraction))

    def step(self) -> None:
        ap = self._ap
        dyn, p = ap.dyn, ap.params
        if dyn.motors_on and (p.battery_drain_on_ground or ap.in_air):
            self.fraction = max(0.0, self.fraction - p.battery_drain_per_s * dyn.dt_s)
        flying = ap.armed and ap.in_air
        if p.battery_check_in_flight_only and not flying:
            return
        level = self.level_of(self.fraction)
        if level <= self._level:
            return
        self._level = level
        if p.battery_warnings:
            ap.status(f"{BATTERY_NAMES[level]} battery level", "warning")
        if not flying:
            return
        if level == 3 and p.battery_emergency_action is not None:
            ap.failsafe("Battery level emergency", p.battery_emergency_action)
        elif level >= 2 and p.battery_critical_action is not None:
            ap.failsafe("Battery level critical", p.battery_critical_action)
