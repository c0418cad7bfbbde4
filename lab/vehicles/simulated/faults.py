"""Fault injection of the simulated vehicle (tests, the sim world and the ``faults:`` section):
link loss, GPS loss, battery level, a pilot taking control, a refused command, a wind gust."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from eaglemission.drivers.vehicles.events import EVENT_FAILOVER, EVENT_FAULT, EVENT_LINK
from eaglemission.drivers.vehicles.mavsdk.failover_watch import failover_data, failover_text
from eaglemission.lab.vehicles.autopilot.model import FailsafeAction

from eaglemission.types import FlightMode, VehicleState

if TYPE_CHECKING:  # the vehicle owns its faults; imported for the annotations only
    from eaglemission.lab.vehicles.simulated.engine import SimulatedModel

COMMANDS = frozenset({
    "arm", "disarm", "takeoff", "goto", "upload_mission", "start_mission", "start_offboard",
    "set_setpoint", "stop_offboard", "hold", "land", "return_to_launch", "grab", "release",
})
"""Names accepted by ``SimulatedVehicle.deny_next_command``."""


def _check_duration(duration_s: float, origin: str) -> None:
    if not (math.isfinite(duration_s) and duration_s > 0):
        raise ValueError(f"{origin}: duration_s must be > 0, got {duration_s}")


class SimulatedFaults:
    """The faults of one :class:`SimulatedModel` (its methods of the same names call these)."""

    def __init__(self, vehicle: SimulatedModel) -> None:
        self._v = vehicle
        self._link_down_until_ns: int | None = None
        self._link_down_since_ns = 0
        self._link_failsafe_done = False
        self._deny: set[str] = set()
        self.frozen_state: VehicleState | None = None  # what telemetry shows while the link is down
        self._gust_until_ns: int | None = None
        self._wind_before: tuple[float, float] = (0.0, 0.0)

    @property
    def busy(self) -> bool:
        """A timed fault is running: :meth:`on_step` must run after every step."""
        return self._link_down_until_ns is not None or self._gust_until_ns is not None

    @property
    def link_down(self) -> bool:
        return self._link_down_until_ns is not None

    def on_step(self, t: int) -> None:
        """Before the autopilot's step: a gust ending, the link coming back, the data-link
        failsafe."""
        if self._gust_until_ns is not None and t >= self._gust_until_ns:
            self._gust_until_ns = None
            dyn = self._v._dyn
            if dyn is not None:
                dyn.wind_ne_mps = self._wind_before
            self._v._event(EVENT_FAULT, "gust over", {"fault": "wind_gust", "ok": True})
        if self._link_down_until_ns is None:
            return
        v = self._v
        cfg = v.config
        if t >= self._link_down_until_ns:
            self._link_down_until_ns = None
            self.frozen_state = None
            v._event(EVENT_LINK, "Link regained", {"ok": True})
            gap_s = (t - self._link_down_since_ns) * 1e-9
            ap = v.autopilot
            timeout_s = ap.params.offboard_loss_timeout_s
            if ap.offboard_failover and ap.offboard_active and ap.setpoint is not None:
                # the client's stream never stopped (MAVSDK resends, unaware of the failover):
                # its next setpoint reaches PX4 ~10 ms after the outage, before any HEARTBEAT
                # reaches the client, and PX4 goes straight back to OFFBOARD (recorded i)
                ap.store_setpoint(ap.setpoint)
            if ap.offboard_failover:  # reported as the mavsdk driver reports PX4's
                v._event(EVENT_FAILOVER, failover_text(gap_s, timeout_s),
                         failover_data(gap_s, timeout_s))
        elif (not self._link_failsafe_done and cfg.link_loss_action != "none"
              and t - self._link_down_since_ns >= cfg.link_loss_timeout_s * 1e9):
            self._link_failsafe_done = True
            ap = v.autopilot
            if ap.armed and ap.in_air:
                ap.failsafe("Connection to ground control station lost",
                            FailsafeAction(cfg.link_loss_action))

    def check_deny(self, name: str, *params: Any) -> None:
        if name in self._deny:
            self._deny.discard(name)
            self._v._refuse(name, "COMMAND_DENIED", "denied by the autopilot (injected fault)",
                            params=params or None)

    # ------------------------------------------------------------------------------------------
    def inject_link_loss(self, duration_s: float) -> None:
        _check_duration(duration_s, "inject_link_loss")
        v = self._v
        with v._lock:
            dyn = v._sync()
            if not self.link_down:
                latest = v._history.latest()
                assert latest is not None
                self.frozen_state = replace(latest, link_ok=False)
                self._link_down_since_ns = dyn.time_ns
                self._link_failsafe_done = False
                v._event(EVENT_LINK, "Link lost", {"ok": False})
            self._link_down_until_ns = dyn.time_ns + int(round(duration_s * 1e9))
            dyn.clear_pending()
            v._event(EVENT_FAULT, f"link loss for {duration_s:g} s",
                     {"fault": "link_loss", "duration_s": duration_s})

    def inject_gps_loss(self, duration_s: float) -> None:
        _check_duration(duration_s, "inject_gps_loss")
        v = self._v
        with v._lock:
            v._sync()
            if v.autopilot.gps_loss(duration_s):
                v._status("GPS lost", severity="critical")
            v._refresh_telemetry()
            v._event(EVENT_FAULT, f"GPS loss for {duration_s:g} s",
                     {"fault": "gps_loss", "duration_s": duration_s})

    def set_battery_fraction(self, fraction: float) -> None:
        if not (math.isfinite(fraction) and 0.0 <= fraction <= 1.0):
            raise ValueError(f"fraction: must be in [0, 1], got {fraction}")
        v = self._v
        with v._lock:
            v._sync_if_connected()
            if v._ap is None:
                v._battery_before_connect = float(fraction)
            else:
                v._ap.set_battery(fraction)
            v._event(EVENT_FAULT, f"battery set to {fraction:.2f}",
                     {"fault": "battery", "fraction": fraction})
            v._refresh_telemetry()

    def pilot_take_control(self, mode: FlightMode) -> None:
        mode = FlightMode(mode)
        v = self._v
        with v._lock:
            v._sync()
            v._event(EVENT_FAULT, f"pilot switches to {mode.value}", {"fault": "pilot", "mode": mode.value})
            v.autopilot.pilot_take_control(mode)

    def deny_next_command(self, name: str) -> None:
        if name not in COMMANDS:
            raise ValueError(f"name: must be one of {sorted(COMMANDS)}, got {name!r}")
        with self._v._lock:
            self._deny.add(name)

    def inject_wind_gust(self, north_mps: float, east_mps: float, duration_s: float) -> None:
        _check_duration(duration_s, "inject_wind_gust")
        if not (math.isfinite(north_mps) and math.isfinite(east_mps)):
            raise ValueError(f"inject_wind_gust: speeds must be finite, got {north_mps}, "
                             f"{east_mps}")
        v = self._v
        with v._lock:
            dyn = v._sync()
            if self._gust_until_ns is None:
                self._wind_before = dyn.wind_ne_mps
            base = self._wind_before
            dyn.wind_ne_mps = (base[0] + north_mps, base[1] + east_mps)
            self._gust_until_ns = dyn.time_ns + int(round(duration_s * 1e9))
            v._event(EVENT_FAULT, f"wind gust ({north_mps:.1f}, {east_mps:.1f}) m/s for "
                     f"{duration_s:g} s", {"fault": "wind_gust", "north_mps": north_mps,
                                           "east_mps": east_mps, "duration_s": duration_s})
