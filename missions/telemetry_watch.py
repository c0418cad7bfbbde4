"""The mission's telemetry task: the telemetry rate, the link, the rangefinder's plane, the
vehicle's events, all logged (a telemetry record every 0.2 s)."""

from __future__ import annotations

from collections.abc import Callable

from eaglemission.missions.approach import StatePolicy
from eaglemission.missions.log import MissionLog
from eaglemission.missions.tracking import TargetTracking

from eaglemission.clock import Clock
from eaglemission.interfaces import Vehicle
from eaglemission.types import VehicleState

PERIOD_S = 0.02
LOG_EVERY_NS = 200_000_000


class TelemetryWatch:
    """Reads ``vehicle.state()`` every 20 ms (see the module docstring)."""

    def __init__(self, vehicle: Vehicle, clock: Clock, log: MissionLog, track: TargetTracking,
                 *, policy: Callable[[], StatePolicy], state_name: Callable[[], str],
                 on_telemetry: Callable[[VehicleState], None] | None = None) -> None:
        self.vehicle, self.clock, self.log, self.track = vehicle, clock, log, track
        self.policy, self.state_name, self.on_telemetry = policy, state_name, on_telemetry
        self.times: list[int] = []
        self.link_lost_since_ns: int | None = None
        self.events_seen = 0
        self.failover = ""  # the vehicle's last ``failover`` event: PX4 acted while we were cut off
        self.stopping = False

    def rate_hz(self) -> float:
        if len(self.times) < 2:
            return 0.0
        span = (self.times[-1] - self.times[0]) * 1e-9
        return (len(self.times) - 1) / span if span > 0 else 0.0

    def link_lost_s(self, now_ns: int) -> float:
        return 0.0 if self.link_lost_since_ns is None else (now_ns - self.link_lost_since_ns) * 1e-9

    async def run(self) -> None:
        last_log = 0
        last_range_ns = -1
        while not self.stopping:
            vs = self.vehicle.state()
            now = self.clock.now_ns()
            if not self.times or vs.timestamp_ns != self.times[-1]:
                self.times = [*self.times[-199:], vs.timestamp_ns]
            if not vs.link_ok:
                if self.link_lost_since_ns is None:
                    self.link_lost_since_ns = now
            else:
                self.link_lost_since_ns = None
            if self.on_telemetry is not None:
                self.on_telemetry(vs)
            if vs.timestamp_ns != last_range_ns:
                last_range_ns = vs.timestamp_ns
                self.track.use_rangefinder(vs, self.policy())
            if now - last_log >= LOG_EVERY_NS:
                last_log = now
                plane = self.track.plane
                self.log.write("telemetry", position_ned_m=vs.position_ned_m,
                               velocity_ned_mps=vs.velocity_ned_mps, yaw_deg=round(vs.yaw_deg, 2),
                               mode=vs.flight_mode, armed=vs.armed, in_air=vs.in_air,
                               battery=vs.battery_remaining, link_ok=vs.link_ok,
                               gps_fix=vs.gps_fix, state=self.state_name(),
                               distance_to_ground_m=vs.distance_to_ground_m,
                               plane_offset_m=round(plane.offset_m, 4),
                               plane_offset_std_m=round(plane.std_m(vs.timestamp_ns), 4))
            events = self.vehicle.events()
            for ev in list(events)[self.events_seen:]:
                if ev.kind == "failover":
                    self.failover = ev.text
                self.log.write("event", source="vehicle", event_kind=ev.kind, text=ev.text,
                               data=ev.data, event_t_ns=ev.timestamp_ns)
            self.events_seen = len(events)
            await self.clock.sleep(PERIOD_S)
