"""Fuzz target: hostile telemetry into the safety envelope (:class:`SafeVehicle`).

A real :class:`SimulatedVehicle` takes the commands; what the envelope reads as its state is
the simulated vehicle's telemetry corrupted per step by a script: NaN or infinite
coordinates, jumps of kilometres, stamps going backwards, a stale state repeated, an old
state replayed (out of order), the link or the position flagged invalid.

Property: every command that leaves the envelope (setpoint, goto target, takeoff altitude,
mission waypoint) is finite and inside it: horizontally inside the fence by its margin, in
the altitude band (a setpoint may lie between the vehicle's own altitude and the band while
the vehicle is outside the band); no exception escapes except
:class:`~eaglemission.errors.DriverError` (``SafetyViolation`` and the vehicle's refusals).
"""

from __future__ import annotations

import asyncio
import math
import random
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

from eaglemission.lab.vehicles.simulated.vehicle import SimulatedVehicle
from fuzz_common import FuzzCrash

from eaglemission.clock import ManualClock
from eaglemission.config import GeofenceConfig, SafetyConfig
from eaglemission.errors import DriverError
from eaglemission.geometry import geodetic_to_ned, ned_to_geodetic
from eaglemission.safety.envelope import SafeVehicle, position_ok
from eaglemission.types import GeoPoint, Setpoint, VehicleState, Waypoint

TARGET = "telemetry"
CORRUPTIONS = ("none", "nan", "inf", "jump", "backwards", "stale", "replay", "invalid",
               "nan_velocity", "nan_attitude", "no_home")
COMMANDS = ("setpoint", "setpoint", "setpoint", "setpoint", "same_setpoint", "goto",
            "upload_mission", "takeoff", "hold", "start_offboard")


@dataclass(frozen=True)
class Step:
    command: str
    corruption: str
    target_ned_m: tuple[float, float, float]
    dt_s: float
    drift_ned_m: tuple[float, float, float]


@dataclass(frozen=True)
class Sequence_:
    safety: SafetyConfig
    steps: tuple[Step, ...]


def random_safety(rng: random.Random) -> SafetyConfig:
    """A random envelope a SafeVehicle accepts: a circle, a polygon (possibly concave) or
    both, with room inside its margin."""
    while True:
        safety = _random_safety(rng)
        try:
            SafeVehicle(SimulatedVehicle(clock=ManualClock()), safety)
        except ValueError:  # no room inside the margin: refused before any flight
            continue
        return safety


def _random_safety(rng: random.Random) -> SafetyConfig:
    radius = rng.choice((None, rng.uniform(15.0, 200.0)))
    poly = None
    if radius is None or rng.random() < 0.3:
        n = rng.randint(3, 8)
        r = rng.uniform(20.0, 150.0)
        poly = [(r * rng.uniform(0.4, 1.0) * math.cos(2 * math.pi * k / n),
                 r * rng.uniform(0.4, 1.0) * math.sin(2 * math.pi * k / n)) for k in range(n)]
    lo = rng.choice((0.0, rng.uniform(0.0, 10.0)))
    return SafetyConfig(geofence=GeofenceConfig(radius_m=radius, polygon_ned_m=poly),
                        min_altitude_m=lo, max_altitude_m=lo + rng.uniform(3.0, 60.0),
                        max_horizontal_speed_mps=rng.uniform(0.5, 12.0),
                        max_vertical_speed_mps=rng.uniform(0.3, 4.0),
                        on_violation=rng.choice(("clamp", "clamp", "refuse")))


def random_sequence(rng: random.Random, n_steps: int | None = None) -> Sequence_:
    """An envelope and a script of commands, each with the telemetry corruption it sees."""
    safety = random_safety(rng)
    reach = 3.0 * (safety.geofence.radius_m or 150.0)
    steps = []
    for _ in range(n_steps if n_steps is not None else rng.randint(1, 30)):
        steps.append(Step(
            command=rng.choice(COMMANDS),
            corruption=rng.choice(CORRUPTIONS) if rng.random() < 0.7 else "none",
            target_ned_m=(rng.uniform(-reach, reach), rng.uniform(-reach, reach),
                          -rng.uniform(-10.0, 2.0 * safety.max_altitude_m)),
            dt_s=rng.choice((0.0, 1e-9, 0.01, 0.05, 0.05, 0.2, 1.0, 30.0)),
            drift_ned_m=(rng.gauss(0, 2.0), rng.gauss(0, 2.0), rng.gauss(0, 0.5))))
    return Sequence_(safety, tuple(steps))


class HostileTelemetry:
    """A vehicle whose commands reach a real :class:`SimulatedVehicle` and whose telemetry
    is that vehicle's, corrupted as the current step says. It records every command the
    envelope lets through."""

    def __init__(self, inner: SimulatedVehicle) -> None:
        self.inner = inner
        self.clock = inner.clock
        self.corruption = "none"
        self.offset_ned_m = (0.0, 0.0, 0.0)
        self.history: list[VehicleState] = []
        self.sent: list[tuple[str, Any]] = []
        self.seen: VehicleState | None = None

    def __getattr__(self, name: str) -> Any:  # the rest of the Vehicle protocol
        return getattr(self.inner, name)

    def state(self) -> VehicleState:
        s = self.inner.state()
        p = s.position_ned_m
        s = replace(s, position_ned_m=(p[0] + self.offset_ned_m[0], p[1] + self.offset_ned_m[1],
                                       p[2] + self.offset_ned_m[2]))
        c = self.corruption
        nan, inf = math.nan, math.inf
        if c == "nan":
            s = replace(s, position_ned_m=(nan, s.position_ned_m[1], nan))
        elif c == "inf":
            s = replace(s, position_ned_m=(inf, -inf, s.position_ned_m[2]))
        elif c == "jump":
            s = replace(s, position_ned_m=(p[0] + 5e3, p[1] - 1e9, p[2] - 3e2))
        elif c == "backwards":
            s = replace(s, timestamp_ns=s.timestamp_ns - 10**12)
        elif c in ("stale", "replay") and self.history:
            s = self.history[-1] if c == "stale" else self.history[0]
        elif c == "invalid":
            s = replace(s, position_valid=False, link_ok=False, gps_fix=False)
        elif c == "nan_velocity":
            s = replace(s, velocity_ned_mps=(nan, nan, inf))
        elif c == "nan_attitude":
            s = replace(s, attitude_q=(nan, 0.0, 0.0, 0.0))
        elif c == "no_home":
            s = replace(s, home=None)
        self.history = [*self.history[-20:], s]
        self.seen = s
        return s

    async def start_offboard(self, initial: Setpoint) -> None:
        self.sent.append(("setpoint", (initial, self.seen)))
        await self.inner.start_offboard(initial)

    async def set_setpoint(self, setpoint: Setpoint) -> None:
        self.sent.append(("setpoint", (setpoint, self.seen)))
        await self.inner.set_setpoint(setpoint)

    async def goto(self, target: GeoPoint, yaw_deg: float) -> None:
        self.sent.append(("goto", (target, self.seen)))
        await self.inner.goto(target, yaw_deg)

    async def takeoff(self, altitude_m: float) -> None:
        self.sent.append(("takeoff", altitude_m))
        await self.inner.takeoff(altitude_m)

    async def upload_mission(self, waypoints: Sequence[Waypoint]) -> None:
        self.sent.append(("mission", tuple(waypoints)))
        await self.inner.upload_mission(waypoints)


def _alt_ok(safe: SafeVehicle, alt_m: float, vehicle_alt_m: float | None) -> bool:
    env = safe.envelope
    lo, hi = env.min_alt_m, env.max_alt_m
    if vehicle_alt_m is not None and math.isfinite(vehicle_alt_m):
        lo, hi = min(lo, vehicle_alt_m), max(hi, vehicle_alt_m)
    return lo - 1e-6 <= alt_m <= hi + 1e-6


def check_sent(safe: SafeVehicle, sent: list[tuple[str, Any]], case: Any) -> None:
    """Every recorded command lies inside the envelope (see the module docstring)."""
    env = safe.envelope
    vmax = safe.safety.max_horizontal_speed_mps
    prev: Setpoint | None = None
    for kind, what in sent:
        if kind == "setpoint":
            sp, seen = what
            p = (sp.north_m, sp.east_m, sp.down_m)
            if not all(math.isfinite(v) for v in p):
                raise FuzzCrash(TARGET, f"non-finite setpoint {sp}", case)
            held, prev = prev is not None and p == prev.position_ned_m, sp
            if seen is not None and not position_ok(seen.position_ned_m):
                if not held:  # no position: only the last setpoint may be sent again
                    raise FuzzCrash(TARGET, f"setpoint {sp} sent without a position", case)
                continue
            vehicle_alt = None if seen is None else -seen.position_ned_m[2]
            if not env.safe_h(sp.north_m, sp.east_m) or not _alt_ok(safe, -sp.down_m, vehicle_alt):
                raise FuzzCrash(TARGET, f"setpoint outside the envelope: {sp} (vehicle "
                                f"{None if seen is None else seen.position_ned_m})", case)
        elif kind == "goto":
            target, seen = what
            if seen is None or seen.home is None:  # the envelope needs a home to place it
                raise FuzzCrash(TARGET, f"goto {target} sent without a home position", case)
            n, e, d = geodetic_to_ned(seen.home, target)
            if not (env.safe_h(n, e) and _alt_ok(safe, -d, None)):
                raise FuzzCrash(TARGET, f"goto outside the envelope: ({n}, {e}, {-d})", case)
        elif kind == "takeoff":
            if not _alt_ok(safe, what, None):
                raise FuzzCrash(TARGET, f"takeoff to {what} m outside the band", case)
        elif kind == "mission":
            for w in what:
                if not (env.safe_h(w.north_m, w.east_m) and _alt_ok(safe, w.altitude_m, None)
                        and w.speed_mps is not None and w.speed_mps <= vmax + 1e-9):
                    raise FuzzCrash(TARGET, f"waypoint outside the envelope: {w}", case)


async def _fly(seq: Sequence_, sim_clock: ManualClock) -> str:
    sim = SimulatedVehicle(clock=sim_clock)
    hostile = HostileTelemetry(sim)
    clock = ManualClock()  # the envelope's own clock: stepped by the script, not the sim
    safe = SafeVehicle(hostile, seq.safety, clock=clock)  # type: ignore[arg-type]
    await safe.connect()
    await safe.arm()
    refused = 0
    last = Setpoint(0.0, 0.0, -1.0, 0.0)
    try:
        try:
            await safe.start_offboard(last)
        except DriverError:
            refused += 1
        for st in seq.steps:
            clock.advance(st.dt_s)
            hostile.corruption = st.corruption
            o = hostile.offset_ned_m
            hostile.offset_ned_m = (o[0] + st.drift_ned_m[0], o[1] + st.drift_ned_m[1],
                                    o[2] + st.drift_ned_m[2])
            n, e, d = st.target_ned_m
            try:
                if st.command == "setpoint":
                    last = Setpoint(n, e, d, 0.0)
                    await safe.set_setpoint(last)
                elif st.command == "same_setpoint":
                    await safe.set_setpoint(last)
                elif st.command == "start_offboard":
                    await safe.start_offboard(Setpoint(n, e, d, 0.0))
                elif st.command == "goto":
                    home = sim.state().home or GeoPoint(47.0, 8.0, 400.0)
                    await safe.goto(ned_to_geodetic(home, n, e, d), 0.0)
                elif st.command == "upload_mission":
                    await safe.upload_mission([Waypoint(n, e, -d, speed_mps=abs(d)),
                                               Waypoint(e, n, -d / 2.0)])
                elif st.command == "takeoff":
                    await safe.takeoff(-d)
                else:
                    await safe.hold()
            except DriverError:
                refused += 1
    finally:
        hostile.corruption = "none"
        await safe.close()
    check_sent(safe, hostile.sent, seq)
    return "refused" if refused else "flown"


def check_sequence(seq: Sequence_) -> str:
    """Fly one script; ``flown`` or ``refused`` (a documented refusal), or :class:`FuzzCrash`."""
    try:
        return asyncio.run(_fly(seq, ManualClock()))
    except FuzzCrash:
        raise
    except Exception as exc:
        raise FuzzCrash(TARGET, f"{type(exc).__name__}: {exc}", seq) from exc
