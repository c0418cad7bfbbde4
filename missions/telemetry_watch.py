"""The mission's telemetry task: the telemetry rate, the link, the rangefinder's plane, the
vehicle's events, all logged (a telemetry record every 0.2 s).

Every sample the mission uses passes :meth:`TelemetryWatch.current`: the time-base checks of
:mod:`eaglemission.telemetry.time_checks` refuse duplicated and out-of-order samples (the mission goes
on with the newest good one) and re-anchor on a jump of the autopilot's clock; telemetry older
than ``safety.max_telemetry_age_s`` counts as a lost link. Each is logged as
``fault_detected`` (at most once a second per kind)."""

from __future__ import annotations

from collections.abc import Callable

from eaglemission.missions.approach import StatePolicy
from eaglemission.missions.log import MissionLog
from eaglemission.missions.tracking import TargetTracking

from eaglemission.clock import Clock
from eaglemission.interfaces import Vehicle
from eaglemission.telemetry.time_checks import CLOCK_JUMP, TelemetryTimeCheck
from eaglemission.types import VehicleState

PERIOD_S = 0.02
LOG_EVERY_NS = 200_000_000
LATE_S = 0.1
"""Telemetry older than this is reported late (flown through up to max_age_s)."""
REPORT_EVERY_NS = 1_000_000_000
RESPONSES = {
    "telemetry_duplicate": "ignored: the mission keeps the newest good sample",
    "telemetry_out_of_order": "ignored: the mission keeps the newest good sample",
    CLOCK_JUMP: "re-anchored: the mission's times are the host's receipt stamps",
}


class TelemetryWatch:
    """Reads ``vehicle.state()`` every 20 ms (see the module docstring)."""

    def __init__(self, vehicle: Vehicle, clock: Clock, log: MissionLog, track: TargetTracking,
                 *, policy: Callable[[], StatePolicy], state_name: Callable[[], str],
                 on_telemetry: Callable[[VehicleState], None] | None = None,
                 max_age_s: float = 0.5) -> None:
        self.vehicle, self.clock, self.log, self.track = vehicle, clock, log, track
        self.policy, self.state_name, self.on_telemetry = policy, state_name, on_telemetry
        self.times: list[int] = []
        self.link_lost_since_ns: int | None = None
        self.events_seen = 0
        self.failover = ""  # the vehicle's last ``failover`` event: PX4 acted while we were cut off
        self.stopping = False
        self.max_age_s = max_age_s
        self.time_check = TelemetryTimeCheck()
        self._reported_ns: dict[str, int] = {}

    def _report(self, what: str, text: str, response: str, now_ns: int) -> None:
        last = self._reported_ns.get(what)
        if last is not None and now_ns - last < REPORT_EVERY_NS:
            return
        self._reported_ns[what] = now_ns
        self.log.write("fault_detected", what=what, text=text, response=response,
                       state=self.state_name())

    def current(self) -> VehicleState:
        """The vehicle's newest sample that passes the time-base checks."""
        vs = self.vehicle.state()
        verdict = self.time_check.check(vs)
        if verdict.problem:
            self._report(verdict.problem, verdict.text, RESPONSES[verdict.problem],
                         self.clock.now_ns())
        last = self.time_check.last
        return vs if last is None else last

    def _stale(self, now_ns: int) -> bool:
        """The accepted telemetry's age judged (late: reported; stale: a lost link)."""
        age_s = self.time_check.age_s(now_ns)
        if age_s > self.max_age_s:
            self._report("telemetry_stale", f"telemetry {age_s:.2f} s old (> "
                         f"safety.max_telemetry_age_s={self.max_age_s:g})",
                         "counted as a lost link (failsafe after safety.link_loss_timeout_s)",
                         now_ns)
            return True
        if age_s > LATE_S:
            self._report("telemetry_late", f"telemetry {age_s:.2f} s old", "flown through "
                         f"(below safety.max_telemetry_age_s={self.max_age_s:g})", now_ns)
        return False

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
            vs = self.current()
            now = self.clock.now_ns()
            if not self.times or vs.timestamp_ns != self.times[-1]:
                self.times = [*self.times[-199:], vs.timestamp_ns]
            if self._stale(now) or not vs.link_ok:
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
