"""Telemetry of the MAVSDK driver: one long-lived task per MAVSDK stream owns its subscription
and updates a cache; position and attitude samples build :class:`~eaglemission.types.VehicleState`
s for a ~2 s history (samples are stamped on receipt, in MAVSDK's thread)."""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from eaglemission.drivers.vehicles.events import (
    EVENT_FAILSAFE,
    EVENT_LINK,
    EVENT_MISSION,
    EVENT_MODE,
    EVENT_STATUS,
    EVENT_TIME_BASE,
)
from eaglemission.drivers.vehicles.mavsdk.support import MavsdkVehicleConfig, downward_range_m

from eaglemission.errors import VehicleError
from eaglemission.geometry import geodetic_to_ned
from eaglemission.telemetry.history import TelemetryHistory
from eaglemission.telemetry.time_checks import CLOCK_JUMP, TelemetryTimeCheck, Verdict
from eaglemission.types import XYZ, FlightMode, GeoPoint, MissionProgress, Quat, VehicleState

log = logging.getLogger(__name__)

MISSION_STREAMS = frozenset({"mission_progress"})
"""The streams of the MAVSDK mission plugin; the others are the telemetry plugin's."""

EventSink = Callable[[str, str, "dict[str, object] | None"], None]
"""``(kind, text, data)``: the vehicle's event log."""
ModeHook = Callable[[FlightMode, str], None]
"""``(new mode, source)`` after a mode change (the offboard session follows it)."""


@dataclass
class TelemetryCache:
    """Latest telemetry, updated by the stream tasks (event loop thread only)."""

    local_ned: XYZ | None = None
    local_vel: XYZ = (0.0, 0.0, 0.0)
    local_t_ns: int = 0
    attitude_q: Quat = (1.0, 0.0, 0.0, 0.0)
    attitude_t_ns: int = 0
    attitude_autopilot_ns: int | None = None  # ATTITUDE_QUATERNION.time_boot_ms (MAVSDK's stamp)
    stamp_floor: tuple[int, int] | None = None  # (receipt, autopilot) of the newest state served
    rates: XYZ = (0.0, 0.0, 0.0)
    geodetic: GeoPoint | None = None
    relative_alt_m: float = math.nan
    home: GeoPoint | None = None
    home_local: XYZ | None = None
    armed: bool = False
    in_air: bool = False
    mode: FlightMode = FlightMode.UNKNOWN
    mode_changes: int = 0  # flight-mode changes seen so far (a command's effect is a change)
    battery: float = math.nan
    voltage_v: float = math.nan
    local_ok: bool = False
    global_ok: bool = False
    armable: bool = False
    progress: MissionProgress = MissionProgress(0, 0)
    last_sample_ns: int = 0
    distance_m: float | None = None  # last downward reading inside the sensor's range
    distance_t_ns: int = 0


class MavsdkTelemetry:
    """The streams, their cache and the state built from it (see the module docstring)."""

    def __init__(self, config: MavsdkVehicleConfig, event: EventSink, on_mode: ModeHook) -> None:
        self.config = config
        self.cache = TelemetryCache()
        self.history = TelemetryHistory(span_s=config.history_s)
        self.link_ok = True
        self.expected: set[FlightMode] = set()  # modes our pending command asked for
        self.now_ns: Callable[[], int] = lambda: 0
        self.mav_flight_mode: Any = None  # mavsdk.plugins.telemetry.FlightMode
        self._event = event
        self._on_mode_hook = on_mode
        self.on_gap: Callable[[float], None] | None = None  # (seconds between two samples, any stream)
        self._last_rx_ns = 0  # the newest receipt stamp of any stream
        self.stamps = TelemetryTimeCheck()  # every attitude sample's autopilot stamp
        self._stamp_reported: dict[str, int] = {}
        self._handlers: dict[str, Callable[[int, Any], None]] = {
            "position_velocity_ned": self._on_local,
            "attitude_quaternion": self._on_attitude,
            "attitude_angular_velocity_body": self._on_rates,
            "position": self._on_position,
            "home": self._on_home,
            "armed": self._on_armed,
            "in_air": self._on_in_air,
            "flight_mode": self._on_mode,
            "battery": self._on_battery,
            "health": self._on_health,
            "status_text": self._on_status,
            "distance_sensor": self._on_distance,
            "mission_progress": self._on_progress,
        }
        """Each stream's handler, by the name of its MAVSDK subscription."""

    def start(self, telemetry: Any, mission: Any, now_ns: Callable[[], int],
              mav_flight_mode: Any) -> list[asyncio.Task[None]]:
        """Start one task per stream (and the link supervisor); returns the tasks."""
        self.now_ns = now_ns
        self.mav_flight_mode = mav_flight_mode
        loop = asyncio.get_running_loop()
        tasks = [loop.create_task(self._stream(mission if name in MISSION_STREAMS else telemetry,
                                               name), name=f"mavsdk-{name}")
                 for name in self._handlers]
        tasks.append(loop.create_task(self._supervise(), name="mavsdk-supervisor"))
        return tasks

    def receive(self, stream: str, t: int, sample: Any) -> None:
        """One sample of ``stream`` (a MAVSDK subscription's name, e.g. ``attitude_quaternion``)
        received at ``t`` (ns, the vehicle's clock): the link's silence noted, the cache
        updated. The stream tasks call it for every sample."""
        self._note_gap(t)
        self._handlers[stream](t, sample)

    async def _stream(self, plugin: Any, name: str) -> None:
        loop = asyncio.get_running_loop()
        queue: asyncio.Queue[tuple[int, Any]] = asyncio.Queue()
        now_ns = self.now_ns

        def on_sample(data: Any, _user_data: Any = None) -> None:  # MAVSDK's thread
            stamp = now_ns()  # stamped on receipt, before the loop sees it
            with contextlib.suppress(RuntimeError):  # loop closed during shutdown
                loop.call_soon_threadsafe(queue.put_nowait, (stamp, data))

        handle = getattr(plugin, f"subscribe_{name}")(on_sample)
        try:
            while True:
                stamp, data = await queue.get()
                try:
                    self.receive(name, stamp, data)
                except Exception:  # one bad sample must not end the stream
                    log.exception("mavsdk %s: cannot handle %r", name, data)
        finally:
            with contextlib.suppress(Exception):
                getattr(plugin, f"unsubscribe_{name}")(handle)

    def _note_gap(self, t: int) -> None:
        """Every sample of every stream, before its handler: the silence since the previous
        one (any stream) is the link's. The first message after a cut link, a HEARTBEAT's mode
        as much as a position, tells the gap before its own handler runs."""
        last = self._last_rx_ns
        if t > last:
            self._last_rx_ns = t
            if last and self.on_gap is not None:
                self.on_gap((t - last) * 1e-9)

    # ------------------------------------------------------------------------------------------
    def _on_local(self, t: int, d: Any) -> None:
        c = self.cache
        p, v = d.position, d.velocity
        c.local_ned = (p.north_m, p.east_m, p.down_m)
        c.local_vel = (v.north_m_s, v.east_m_s, v.down_m_s)
        c.local_t_ns = c.last_sample_ns = t
        self._append_state(t)

    def _on_attitude(self, t: int, q: Any) -> None:
        c = self.cache
        stamp_ns = int(getattr(q, "timestamp_us", 0) or 0) * 1000 or None
        if stamp_ns is not None:
            verdict = self.stamps.check_stamps(t, stamp_ns)
            if verdict.problem:
                self._report_stamp(t, verdict)
            if not verdict.accepted:  # a copy or an older sample: the cache keeps the newest
                return
            if verdict.problem == CLOCK_JUMP:
                c.stamp_floor = None
        c.attitude_q = (q.w, q.x, q.y, q.z)
        c.attitude_t_ns = c.last_sample_ns = t
        c.attitude_autopilot_ns = stamp_ns
        self._append_state(t)

    def _report_stamp(self, t: int, verdict: Verdict) -> None:
        """A refused or re-anchored attitude stamp as a ``time_base`` event (once a second per
        problem: a duplicating link would log every message)."""
        last = self._stamp_reported.get(verdict.problem)
        if last is not None and t - last < 1_000_000_000:
            return
        self._stamp_reported[verdict.problem] = t
        self._event(EVENT_TIME_BASE, f"{verdict.problem}: {verdict.text}",
                    {"problem": verdict.problem, "stream": "attitude_quaternion"})

    def stamp_at(self, t: int) -> int | None:
        """The autopilot time of a state built at receipt time ``t``
        (:func:`autopilot_time_ns`), never back nor equal from one newer state served to the
        next (the streams' receipt jitter would otherwise read as a reordered link)."""
        c = self.cache
        ap = autopilot_time_ns(c, t)
        if ap is None:
            return None
        floor = c.stamp_floor
        if floor is not None:
            if t == floor[0]:
                return floor[1]
            if t < floor[0]:
                return ap
            ap = max(ap, floor[1] + 1)
        c.stamp_floor = (t, ap)
        return ap

    def _on_rates(self, t: int, r: Any) -> None:
        self.cache.rates = (r.roll_rad_s, r.pitch_rad_s, r.yaw_rad_s)

    def _on_position(self, t: int, p: Any) -> None:
        c = self.cache
        c.geodetic = GeoPoint(p.latitude_deg, p.longitude_deg, p.absolute_altitude_m)
        c.relative_alt_m = p.relative_altitude_m
        c.last_sample_ns = t

    def _on_home(self, t: int, h: Any) -> None:
        c = self.cache
        c.home = GeoPoint(h.latitude_deg, h.longitude_deg, h.absolute_altitude_m)
        loc = (getattr(h, "local_north_m", math.nan), getattr(h, "local_east_m", math.nan),
               getattr(h, "local_down_m", math.nan))
        if all(math.isfinite(v) for v in loc):
            c.home_local = loc

    def _on_armed(self, t: int, armed: Any) -> None:
        if bool(armed) != self.cache.armed:
            self._event(EVENT_STATUS, "armed" if armed else "disarmed", {"armed": bool(armed)})
        self.cache.armed = bool(armed)

    def _on_in_air(self, t: int, in_air: Any) -> None:
        self.cache.in_air = bool(in_air)

    def _on_mode(self, t: int, mode: Any) -> None:
        name = getattr(mode, "name", None) or self.mav_flight_mode(int(mode)).name
        new = FlightMode(name) if name in FlightMode.__members__ else FlightMode.UNKNOWN
        old = self.cache.mode
        if new == old:
            return
        self.cache.mode = new
        self.cache.mode_changes += 1
        source = "command" if new in self.expected else "autopilot"
        if source == "command":
            self.expected = set()
        self._event(EVENT_MODE, f"{old.value} -> {new.value}",
                    {"from": old.value, "to": new.value, "source": source})
        self._on_mode_hook(new, source)

    def _on_battery(self, t: int, b: Any) -> None:
        pct = b.remaining_percent
        self.cache.battery = pct / 100.0 if math.isfinite(pct) else math.nan
        self.cache.voltage_v = b.voltage_v

    def _on_health(self, t: int, h: Any) -> None:
        c = self.cache
        c.local_ok, c.global_ok, c.armable = (bool(h.is_local_position_ok),
                                              bool(h.is_global_position_ok), bool(h.is_armable))

    def _on_status(self, t: int, s: Any) -> None:
        text = str(s.text).strip()
        severity = getattr(s.type, "name", str(s.type)).lower()
        self._event(EVENT_STATUS, text, {"severity": severity})
        if "failsafe" in text.lower():
            self._event(EVENT_FAILSAFE, text, {"reason": "autopilot", "action": "see mode events"})

    def _on_distance(self, t: int, d: Any) -> None:
        c = self.cache
        c.distance_m = downward_range_m(d)
        c.distance_t_ns = t

    def _on_progress(self, t: int, p: Any) -> None:
        new = MissionProgress(int(p.current), int(p.total))
        if new != self.cache.progress:
            self._event(EVENT_MISSION, f"mission progress {new.current}/{new.total}",
                        {"index": new.current, "total": new.total})
        self.cache.progress = new

    async def _supervise(self) -> None:
        """Link watch (no telemetry for ``link_timeout_s``) at 10 Hz."""
        while True:
            await asyncio.sleep(0.1)
            age_s = (self.now_ns() - self.cache.last_sample_ns) * 1e-9
            ok = age_s < self.config.link_timeout_s
            if ok != self.link_ok:
                self.link_ok = ok
                self._event(EVENT_LINK, "link regained" if ok else
                            f"link lost: no telemetry for {age_s:.1f} s", {"ok": ok})

    # ------------------------------------------------------------------------------------------
    def distance_at(self, t: int) -> float | None:
        """The last downward reading if it is at most ``distance_sensor_max_age_s`` old at
        ``t`` (and not from after ``t`` by more than that either)."""
        c = self.cache
        if c.distance_m is None:
            return None
        age_ns = abs(t - c.distance_t_ns)
        return c.distance_m if age_ns <= self.config.distance_sensor_max_age_s * 1e9 else None

    def home_local(self) -> XYZ | None:
        """Home in the EKF-local frame: HOME_POSITION x/y/z, else derived from the global and
        local positions (which need home)."""
        c = self.cache
        if c.home_local is not None:
            return c.home_local
        if c.home is None or c.geodetic is None or c.local_ned is None:
            return None
        g = geodetic_to_ned(c.home, c.geodetic)
        return (c.local_ned[0] - g[0], c.local_ned[1] - g[1], c.local_ned[2] - g[2])

    def build_state(self, t: int, *, now_ns: int | None = None) -> VehicleState | None:
        """The state at sample time ``t``; the range reading's age is judged at ``now_ns``
        (default ``t``)."""
        c = self.cache
        if c.local_ned is None:
            return None
        hl = self.home_local() or (0.0, 0.0, 0.0)
        # Bring the position to the sample time with the velocity (the streams are not in phase).
        dt = (t - c.local_t_ns) * 1e-9 if c.local_t_ns else 0.0
        dt = dt if 0.0 <= dt <= 0.1 else 0.0
        v = c.local_vel
        pos = (c.local_ned[0] + v[0] * dt - hl[0], c.local_ned[1] + v[1] * dt - hl[1],
               c.local_ned[2] + v[2] * dt - hl[2])
        link_ok = (self.now_ns() - c.last_sample_ns) * 1e-9 < self.config.link_timeout_s
        rel = c.relative_alt_m if math.isfinite(c.relative_alt_m) else -pos[2]
        return VehicleState(
            autopilot_time_ns=self.stamp_at(t),
            timestamp_ns=t, position_ned_m=pos, velocity_ned_mps=v, attitude_q=c.attitude_q,
            angular_velocity_frd_radps=c.rates, geodetic=c.geodetic, relative_altitude_m=rel,
            home=c.home, armed=c.armed, in_air=c.in_air, flight_mode=c.mode,
            battery_remaining=c.battery if math.isfinite(c.battery) else 1.0,
            battery_voltage_v=c.voltage_v,
            position_valid=c.local_ok and (c.home is not None),
            gps_fix=c.global_ok, link_ok=link_ok, armable=c.armable,
            distance_to_ground_m=self.distance_at(t if now_ns is None else now_ns))

    def state(self) -> VehicleState:
        """The latest state (a placeholder before the first local position)."""
        c = self.cache
        now = self.now_ns()
        s = self.build_state(c.last_sample_ns or now, now_ns=now)
        if s is None:
            return VehicleState(timestamp_ns=self.now_ns(), position_ned_m=(0.0, 0.0, 0.0),
                                velocity_ned_mps=(0.0, 0.0, 0.0), attitude_q=c.attitude_q,
                                armed=c.armed, flight_mode=c.mode, position_valid=False,
                                gps_fix=False, link_ok=self.link_ok, armable=False)
        return s

    def _append_state(self, t: int) -> None:
        s = self.build_state(t)
        if s is not None:
            self.history.append(s)

    async def wait_first(self, timeout_s: float) -> None:
        """Until local position, flight mode and home arrived (warn after ``timeout_s``)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            c = self.cache
            if c.local_ned is not None and c.mode != FlightMode.UNKNOWN and c.home is not None:
                return
            await asyncio.sleep(0.02)
        log.warning("mavsdk: connected but no local position, flight mode or home within %.1f s "
                    "(no GPS fix yet?)", timeout_s)

    def truth_flags(self) -> tuple[bool, bool, FlightMode]:
        c = self.cache
        return c.armed, c.in_air, c.mode


AUTOPILOT_STAMP_SPAN_NS = 200_000_000
"""How far past the last attitude sample its autopilot stamp is carried (receipt time)."""


def autopilot_time_ns(c: TelemetryCache, t: int) -> int | None:
    """The autopilot's time of a state built at receipt time ``t``: the last attitude sample's
    ``time_boot_ms`` (the only stream MAVSDK stamps) plus the receipt time since it; None
    without one or when it is more than :data:`AUTOPILOT_STAMP_SPAN_NS` old."""
    if c.attitude_autopilot_ns is None or not 0 <= t - c.attitude_t_ns <= AUTOPILOT_STAMP_SPAN_NS:
        return None
    return c.attitude_autopilot_ns + (t - c.attitude_t_ns)


async def request_rates(vehicle: Any) -> None:
    """Ask for the telemetry rates of ``vehicle``'s config (a refused rate is only logged:
    telemetry still flows at the autopilot's own rate)."""
    tel, cfg = vehicle.plugins["Telemetry"], vehicle.config
    fast = cfg.telemetry_rate_hz
    for name, hz in (("position", fast), ("position_velocity_ned", fast),
                     ("attitude_quaternion", fast), ("in_air", cfg.state_rate_hz),
                     ("home", 1.0), ("distance_sensor", cfg.distance_sensor_rate_hz)):
        if hz <= 0:
            continue
        setter = functools.partial(getattr(tel, f"set_rate_{name}"), hz)
        try:
            await vehicle.bounded(f"set_rate_{name}()", setter)
        except VehicleError as exc:
            log.warning("telemetry rate not set: %s", exc)
