"""The safety envelope: a :class:`Vehicle` wrapper that every command passes through.

``SafeVehicle(inner, safety)`` is itself a Vehicle; the mission runner always wraps its vehicle
in it, so no plugin can bypass it. It enforces, in the autopilot's local NED frame (origin at
home; altitudes relative to home, up):

* **geofence**: a circle around home (``geofence.radius_m``) and/or a polygon
  (``geofence.polygon_ned_m``), both must hold; targets are kept ``margin_m`` inside it so the
  controller's overshoot and the estimate's drift stay inside the fence itself;
* **altitude band** ``[min_altitude_m, max_altitude_m]`` (kept ``vertical_margin_m`` inside);
* **speed limits**: an offboard position setpoint far away would make the autopilot fly at its
  own maximum speed (PX4 ``MPC_XY_VEL_MAX``). Setpoints therefore become *speed-limited steps*:
  a carrot that moves towards the requested point at no more than
  ``max_horizontal_speed_mps`` / ``max_vertical_speed_mps`` between two setpoints and never
  leads the vehicle's current position by more than ``lead_s`` seconds of travel at those
  speeds (with PX4's position gain of ~1/s the velocity it commands stays under the limit).
  Mission waypoints get their ``speed_mps`` capped at the horizontal limit.

What is **clamped** or **refused** (``on_violation``): an offboard setpoint, a goto target, a
takeoff altitude or a mission waypoint outside the envelope is moved to the nearest point
inside it (``clamp``; for a goto or mission leg whose straight path would cross a non-convex
fence, to the furthest safe point along the path) or the command raises
:class:`~eaglemission.errors.SafetyViolation` without reaching the vehicle (``refuse``).
Stepping far setpoints is not a violation: it happens in both modes. Safe actions (hold,
land, return to launch, disarm) always pass. Every intervention is logged and recorded as a
:class:`~eaglemission.types.VehicleEvent` of kind ``"safety"`` (merged into ``events()``).

Not covered (documented in docs/vehicles.md): the speed of autopilot-flown moves other than
mission legs (goto, takeoff, RTL and land fly at the autopilot's configured speeds: set
``MPC_XY_CRUISE`` etc. within the limits), and link-loss / low-battery reactions, which the
mission runner handles from ``SafetyConfig``.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from typing import Any

from eaglemission.clock import Clock, MonotonicClock
from eaglemission.config import SafetyConfig
from eaglemission.errors import SafetyViolation
from eaglemission.geometry import down_axis_cos_tilt, geodetic_to_ned, ned_to_geodetic
from eaglemission.geometry.geofence import inside_geofence, point_in_polygon
from eaglemission.interfaces import Vehicle
from eaglemission.types import (
    GeoPoint,
    MissionProgress,
    Setpoint,
    VehicleEvent,
    VehicleState,
    Waypoint,
)

EVENT_SAFETY = "safety"
MAX_SAMPLES = 10_000
"""Most samples along one path check (0.25 m apart up to 2.5 km, sparser beyond)."""
MAX_POSITION_M = 1e7
"""A reported position farther from home than this (10,000 km) is telemetry gone wrong."""

_Vec2 = tuple[float, float]


# ---------------------------------------------------------------------------------------------
# Pure geometry
# ---------------------------------------------------------------------------------------------
def distance_to_segment(p: _Vec2, a: _Vec2, b: _Vec2) -> tuple[float, _Vec2]:
    """Distance from ``p`` to segment ``ab`` and the nearest point on it."""
    ax, ay = a
    dx, dy = b[0] - ax, b[1] - ay
    L2 = dx * dx + dy * dy
    s = 0.0 if L2 == 0 else max(0.0, min(1.0, ((p[0] - ax) * dx + (p[1] - ay) * dy) / L2))
    q = (ax + s * dx, ay + s * dy)
    return math.hypot(p[0] - q[0], p[1] - q[1]), q


def distance_to_polygon_edge(p: _Vec2, polygon: Sequence[Sequence[float]]) -> tuple[float, _Vec2]:
    """Distance from ``p`` to the nearest edge of ``polygon`` and the nearest boundary point."""
    best = (math.inf, (math.nan, math.nan))
    n = len(polygon)
    for i in range(n):
        a = (float(polygon[i][0]), float(polygon[i][1]))
        b = (float(polygon[(i + 1) % n][0]), float(polygon[(i + 1) % n][1]))
        d = distance_to_segment(p, a, b)
        if d[0] < best[0]:
            best = d
    return best


def position_ok(p: Sequence[float]) -> bool:
    """A position estimate the envelope can step from: finite, within MAX_POSITION_M of home."""
    return all(math.isfinite(v) and abs(v) <= MAX_POSITION_M for v in p)


def braking_distance_m(speed_mps: float, decel_mps2: float) -> float:
    """``v^2 / (2 a)``: how far a vehicle at ``speed_mps`` travels while braking."""
    return speed_mps * speed_mps / (2.0 * decel_mps2)


class Envelope:
    """The horizontal fence and altitude band, shrunk by the margins (pure, no vehicle)."""

    def __init__(self, safety: SafetyConfig, *, margin_m: float, vertical_margin_m: float) -> None:
        self.safety = safety
        self.fence = safety.geofence
        self.margin_m = float(margin_m)
        self.vertical_margin_m = float(vertical_margin_m)
        band = safety.max_altitude_m - safety.min_altitude_m
        vm = min(self.vertical_margin_m, band / 4.0)
        self.min_alt_m = safety.min_altitude_m + vm
        self.max_alt_m = safety.max_altitude_m - vm
        if self.fence.radius_m is not None and self.fence.radius_m <= self.margin_m:
            raise ValueError(f"geofence.radius_m ({self.fence.radius_m}) must exceed the margin "
                             f"({self.margin_m} m): enlarge the fence or reduce the margin")
        poly = self.fence.polygon_ned_m
        self._poly: list[tuple[float, float]] | None = (
            [(float(a), float(b)) for a, b in poly] if poly is not None else None)
        if self._poly is not None:
            cn = sum(v[0] for v in self._poly) / len(self._poly)
            ce = sum(v[1] for v in self._poly) / len(self._poly)
            self._poly_centre = (cn, ce)
            if not (self.safe_h(0.0, 0.0) or self.safe_h(cn, ce)):  # nearest_safe's anchors
                raise ValueError(f"geofence.polygon_ned_m: neither home nor the polygon's "
                                 f"centroid lies {self.margin_m:.2f} m inside it: enlarge the "
                                 "fence or reduce the margin")

    # -- membership ----------------------------------------------------------------------------
    def inside_fence(self, north_m: float, east_m: float) -> bool:
        """Inside the configured fence (no margin)."""
        return inside_geofence(self.fence, north_m, east_m)

    def safe_h(self, north_m: float, east_m: float) -> bool:
        """Inside the fence by at least ``margin_m``."""
        r = self.fence.radius_m
        if r is not None and math.hypot(north_m, east_m) > r - self.margin_m:
            return False
        if self._poly is not None:
            if not point_in_polygon(north_m, east_m, self._poly):
                return False
            if distance_to_polygon_edge((north_m, east_m), self._poly)[0] < self.margin_m:
                return False
        return True

    def alt_ok(self, altitude_m: float) -> bool:
        return self.min_alt_m <= altitude_m <= self.max_alt_m

    def clamp_alt(self, altitude_m: float) -> float:
        return min(self.max_alt_m, max(self.min_alt_m, altitude_m))

    # -- clamping ------------------------------------------------------------------------------
    def furthest_safe_on_segment(self, a: _Vec2, b: _Vec2, *, step_m: float = 0.25) -> _Vec2 | None:
        """The furthest point from ``a`` towards ``b`` such that the path ``a -> point`` stays
        in the safe region (sampled every ``step_m``); None if ``a`` itself is not safe."""
        if not self.safe_h(*a):
            return None
        L = math.hypot(b[0] - a[0], b[1] - a[1])
        if L == 0:
            return a
        if not math.isfinite(L):
            return None
        # at most MAX_SAMPLES samples (a position kilometres off, from telemetry that jumped,
        # must not stall the setpoint loop); the bisection below still finds the crossing
        steps = L / step_m
        n = MAX_SAMPLES if not steps < MAX_SAMPLES else max(1, math.ceil(steps))
        last = a
        for k in range(1, n + 1):
            s = k / n
            q = (a[0] + s * (b[0] - a[0]), a[1] + s * (b[1] - a[1]))
            if not self.safe_h(*q):
                # refine between last and q
                lo, hi = (k - 1) / n, s
                for _ in range(12 if n < MAX_SAMPLES else 40):
                    mid = 0.5 * (lo + hi)
                    m = (a[0] + mid * (b[0] - a[0]), a[1] + mid * (b[1] - a[1]))
                    if self.safe_h(*m):
                        lo = mid
                    else:
                        hi = mid
                return (a[0] + lo * (b[0] - a[0]), a[1] + lo * (b[1] - a[1]))
            last = q
        return last

    def path_safe(self, a: _Vec2, b: _Vec2) -> bool:
        """The straight path ``a -> b`` stays in the safe region (``a`` outside it is allowed
        for a convex-fence approach: only ``b`` and the path beyond the first safe point are
        checked)."""
        if not self.safe_h(*b):
            return False
        if not self.safe_h(*a):
            return True
        end = self.furthest_safe_on_segment(a, b)
        return end is not None and math.hypot(end[0] - b[0], end[1] - b[1]) < 1e-6

    def nearest_safe(self, p: _Vec2) -> _Vec2:
        """A point of the safe region near ``p`` (``p`` itself when it is safe)."""
        if self.safe_h(*p):
            return p
        q = p
        r = self.fence.radius_m
        if r is not None:
            d = math.hypot(*q)
            lim = (r - self.margin_m) * (1.0 - 1e-9)
            if d > lim:
                q = (q[0] * lim / d, q[1] * lim / d)
        if self._poly is not None and not self.safe_h(*q):
            _, b = distance_to_polygon_edge(q, self._poly)
            inside = point_in_polygon(q[0], q[1], self._poly)
            # move from the boundary point inwards by the margin (plus a hair)
            dn, de = (b[0] - q[0], b[1] - q[1]) if not inside else (q[0] - b[0], q[1] - b[1])
            L = math.hypot(dn, de)
            if L < 1e-9:  # on the boundary: head for the centroid
                dn, de = self._poly_centre[0] - b[0], self._poly_centre[1] - b[1]
                L = math.hypot(dn, de) or 1.0
            k = (self.margin_m * 1.01 + 1e-6) / L
            cand = (b[0] + dn * k, b[1] + de * k)
            if self.safe_h(*cand):
                q = cand
            else:  # thin or concave corner: fall back towards the centroid
                end = None
                if self.safe_h(*self._poly_centre):
                    end = self.furthest_safe_on_segment(self._poly_centre, q)
                q = end if end is not None else self._poly_centre
        if not self.safe_h(*q):
            # circle and polygon together: search along the segment to home / centroid
            for anchor in ((0.0, 0.0), getattr(self, "_poly_centre", (0.0, 0.0))):
                end = self.furthest_safe_on_segment(anchor, p)
                if end is not None:
                    return end
            raise ValueError("the geofence leaves no room inside its margin: enlarge it")
        return q


# ---------------------------------------------------------------------------------------------
# The wrapper
# ---------------------------------------------------------------------------------------------
class SafeVehicle:
    """A :class:`~eaglemission.interfaces.Vehicle` that keeps ``inner`` inside the envelope.

    Parameters
    ----------
    inner : Vehicle
        Any vehicle (simulated, MAVSDK, ...).
    safety : SafetyConfig
    clock : Clock, optional
        Time source for the setpoint steps; defaults to ``inner.clock`` or the host clock.
    logger : logging.Logger, optional
        Interventions are logged at WARNING (clamp/refuse) or INFO.
    margin_m : float, optional
        How far inside the fence targets are kept. Default: 1 m plus half the braking
        distance at ``max_horizontal_speed_mps`` with 3 m/s^2.
    vertical_margin_m : float
        How far inside the altitude band targets are kept (at most a quarter of the band).
    lead_s : float
        The step target never leads the current position by more than this many seconds of
        travel at the speed limits. With a position gain ``k`` (PX4 ``MPC_XY_P`` = 0.95/s,
        the simulated vehicle's 1/s) the autopilot then commands at most ``k lead_s`` times
        the limit: keep ``lead_s <= 1 / k``.
    max_step_dt_s : float
        Longest gap between two setpoints that still advances the step fully (slower
        streams move slower, never faster).
    """

    def __init__(self, inner: Vehicle, safety: SafetyConfig, *, clock: Clock | None = None,
                 logger: logging.Logger | None = None, margin_m: float | None = None,
                 vertical_margin_m: float = 0.5, lead_s: float = 1.0,
                 max_step_dt_s: float = 0.2) -> None:
        if isinstance(inner, SafeVehicle):
            raise ValueError("inner: already a SafeVehicle (wrap the driver once)")
        self._inner = inner
        self.safety = safety
        self.clock: Clock = clock or getattr(inner, "clock", None) or MonotonicClock()
        self.logger = logger or logging.getLogger("eaglemission.safety.envelope")
        if margin_m is None:
            margin_m = 1.0 + 0.5 * braking_distance_m(safety.max_horizontal_speed_mps, 3.0)
        if not (margin_m >= 0 and vertical_margin_m >= 0 and lead_s > 0 and max_step_dt_s > 0):
            raise ValueError("margin_m, vertical_margin_m must be >= 0; lead_s, max_step_dt_s > 0")
        self.envelope = Envelope(safety, margin_m=margin_m, vertical_margin_m=vertical_margin_m)
        self.lead_s = float(lead_s)
        self.max_step_dt_s = float(max_step_dt_s)
        self._events: list[VehicleEvent] = []
        self._last_logged: dict[str, tuple[tuple[str, str, str], int]] = {}
        self._last_problem: str | None = None
        self._clamp_cache: tuple[tuple[float, float, float, float], tuple[float, float, float], str | None] | None = None
        self._carrot: tuple[float, float, float] | None = None  # NED of the last step sent
        self._carrot_ns = 0
        self.last_requested: Setpoint | None = None
        self.last_sent: Setpoint | None = None

    # -- plumbing ------------------------------------------------------------------------------
    @property
    def inner(self) -> Vehicle:
        """The wrapped vehicle (for the sim world: true poses, fault injection)."""
        return self._inner

    async def __aenter__(self) -> SafeVehicle:
        await self.connect()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    def _intervene(self, origin: str, text: str, data: dict[str, object], *, refuse: bool,
                   params: Any = None) -> None:
        action = "refused" if refuse else "clamped"
        now = self.clock.now_ns()
        key = (origin, action, repr(data.get("requested")))
        last = self._last_logged.get(origin)
        # a setpoint clamped at 20 Hz is one intervention: record it when the request changes
        # and at most once a second while it lasts
        if refuse or last is None or last[0] != key or now - last[1] >= 1_000_000_000:
            self._last_logged[origin] = (key, now)
            self._events.append(VehicleEvent(now, EVENT_SAFETY, f"{origin}: {action}: {text}",
                                             {"origin": origin, "action": action, **data}))
            self.logger.warning("safety envelope %s %s: %s", action, origin, text)
        if refuse:
            hint = ("safety.on_violation is 'refuse'; use 'clamp' to move targets inside the "
                    "envelope instead") if self._refuse else "this is never clamped"
            raise SafetyViolation("OUTSIDE_ENVELOPE", origin, params, f"{text} ({hint})")

    @property
    def _refuse(self) -> bool:
        return self.safety.on_violation == "refuse"

    def _home(self, origin: str, s: VehicleState | None = None) -> GeoPoint:
        home = (self._inner.state() if s is None else s).home
        if home is None:
            raise SafetyViolation("NO_HOME", origin, None,
                                  "the vehicle reports no home position yet: wait for it before "
                                  "sending geodetic targets")
        return home

    def ground_offset_m(self, s: VehicleState | None = None) -> float:
        """What to add to an estimated altitude (relative to home) to get the height above the
        ground under the vehicle: ``range x cos tilt - estimated altitude`` with
        ``altitude_reference: rangefinder`` and a trusted reading, else 0 (docs/vehicles.md,
        "Altitude band on the rangefinder")."""
        if self.safety.altitude_reference != "rangefinder":
            return 0.0
        if s is None:
            s = self._inner.state()
        d = s.distance_to_ground_m
        if d is None or not math.isfinite(d) or d <= 0:
            return 0.0
        cos_tilt = down_axis_cos_tilt(s.attitude_q)
        if not math.isfinite(cos_tilt) or cos_tilt < math.cos(math.radians(30.0)):
            return 0.0
        offset = d * cos_tilt + s.position_ned_m[2]  # height above ground - (-down)
        if not math.isfinite(offset):
            return 0.0
        if abs(offset) > self.safety.rangefinder_max_correction_m:
            self._intervene("altitude_reference", f"range {d:.2f} m disagrees with the altitude "
                            f"estimate {-s.position_ned_m[2]:.2f} m by {offset:+.2f} m: the band "
                            "uses the estimate", {"requested": None, "range_m": round(d, 2)},
                            refuse=False)
            return 0.0
        return offset

    def _position(self, origin: str, s: VehicleState, params: Any) -> tuple[float, float, float]:
        """The vehicle's reported position; :class:`SafetyViolation` ``NO_POSITION`` when it is
        not finite (a path or a step cannot be checked against an unknown start)."""
        p = s.position_ned_m
        if not position_ok(p):
            raise SafetyViolation("NO_POSITION", origin, params,
                                  f"the vehicle reports a non-finite or absurd position {p}: "
                                  "wait for a valid position estimate")
        return p

    def _check_point(self, origin: str, north_m: float, east_m: float, altitude_m: float,
                     start: tuple[float, float] | None, params: Any, *,
                     ground_offset_m: float = 0.0) -> tuple[float, float, float]:
        """Clamp (or refuse) a target; ``start`` is where the straight path to it begins;
        ``ground_offset_m`` turns its estimated altitude into height above the ground."""
        env = self.envelope
        n, e, alt = north_m, east_m, altitude_m
        problems: list[str] = []
        agl = alt + ground_offset_m
        if not env.alt_ok(agl):
            ref = "" if ground_offset_m == 0.0 else f" above the ground ({ground_offset_m:+.2f} m by the rangefinder)"
            problems.append(f"altitude {agl:.2f} m{ref} outside [{env.min_alt_m:.2f}, {env.max_alt_m:.2f}] m "
                            f"(band {self.safety.min_altitude_m:g}..{self.safety.max_altitude_m:g} m "
                            f"minus margin)")
            alt = env.clamp_alt(agl) - ground_offset_m
        if not env.safe_h(n, e):
            problems.append(f"({n:.2f}, {e:.2f}) m is outside the geofence or within "
                            f"{env.margin_m:.2f} m of it")
            n, e = env.nearest_safe((n, e))
        if start is not None and not env.path_safe(start, (n, e)):
            problems.append(f"the straight path from ({start[0]:.2f}, {start[1]:.2f}) crosses the "
                            "geofence")
            end = env.furthest_safe_on_segment(start, (n, e))
            if end is not None:
                n, e = end
        self._last_problem = "; ".join(problems) if problems else None
        if problems:
            self._intervene(origin, "; ".join(problems),
                            {"requested": (north_m, east_m, altitude_m), "result": (n, e, alt)},
                            refuse=self._refuse, params=params)
        return n, e, alt

    # -- pass-through --------------------------------------------------------------------------
    async def connect(self) -> None:
        await self._inner.connect()

    async def close(self) -> None:
        await self._inner.close()

    def state(self) -> VehicleState:
        return self._inner.state()

    def state_at(self, timestamp_ns: int) -> VehicleState | None:
        return self._inner.state_at(timestamp_ns)

    def events(self) -> Sequence[VehicleEvent]:
        merged = list(self._inner.events()) + self._events
        merged.sort(key=lambda ev: ev.timestamp_ns)
        return tuple(merged)

    def mission_progress(self) -> MissionProgress:
        return self._inner.mission_progress()

    async def arm(self) -> None:
        await self._inner.arm()

    async def disarm(self) -> None:
        await self._inner.disarm()

    async def hold(self) -> None:
        self._carrot = None
        await self._inner.hold()

    async def land(self) -> None:
        self._carrot = None
        await self._inner.land()

    async def return_to_launch(self) -> None:
        self._carrot = None
        await self._inner.return_to_launch()

    async def grab(self) -> None:
        await self._inner.grab()

    async def release(self) -> None:
        await self._inner.release()

    async def stop_offboard(self) -> None:
        self._carrot = None
        await self._inner.stop_offboard()

    # -- checked commands ----------------------------------------------------------------------
    async def takeoff(self, altitude_m: float) -> None:
        env = self.envelope
        if not math.isfinite(altitude_m):
            raise SafetyViolation("INVALID_ARGUMENT", "takeoff()", (altitude_m,),
                                  f"altitude_m must be finite, got {altitude_m}")
        alt = altitude_m
        if not env.alt_ok(altitude_m):
            alt = env.clamp_alt(altitude_m)
            self._intervene("takeoff()", f"altitude {altitude_m:g} m outside "
                            f"[{env.min_alt_m:.2f}, {env.max_alt_m:.2f}] m: {alt:.2f} m",
                            {"requested": altitude_m, "result": alt}, refuse=self._refuse,
                            params=(altitude_m,))
        s = self._inner.state()
        self._position("takeoff()", s, (altitude_m,))
        if not env.safe_h(s.position_ned_m[0], s.position_ned_m[1]):
            self._intervene("takeoff()", "the vehicle is outside the geofence (or its margin)",
                            {"position_ned_m": s.position_ned_m}, refuse=True, params=(altitude_m,))
        self._carrot = None
        await self._inner.takeoff(alt)

    async def goto(self, target: GeoPoint, yaw_deg: float) -> None:
        s = self._inner.state()  # one sample: the home and the position checked together
        home = self._home("goto()", s)
        n, e, d = geodetic_to_ned(home, target)
        p = self._position("goto()", s, (target, yaw_deg))
        start = (p[0], p[1])
        cn, ce, calt = self._check_point("goto()", n, e, -d, start, (target, yaw_deg))
        if (cn, ce, calt) != (n, e, -d):
            target = ned_to_geodetic(home, cn, ce, -calt)
        self._carrot = None
        await self._inner.goto(target, yaw_deg)

    async def upload_mission(self, waypoints: Sequence[Waypoint]) -> None:
        out: list[Waypoint] = []
        p = self._position("upload_mission()", self._inner.state(), None)
        prev: tuple[float, float] | None = (p[0], p[1])
        vmax = self.safety.max_horizontal_speed_mps
        for i, w in enumerate(waypoints):
            origin = f"upload_mission() waypoint {i}"
            n, e, alt = self._check_point(origin, w.north_m, w.east_m, w.altitude_m, prev, (i, w))
            speed = w.speed_mps
            if speed is None or speed > vmax:
                if speed is not None:
                    self._intervene(origin, f"speed {speed:g} m/s above the limit {vmax:g} m/s",
                                    {"requested": speed, "result": vmax}, refuse=self._refuse,
                                    params=(i, w))
                speed = vmax
            out.append(Waypoint(n, e, alt, speed_mps=speed, acceptance_radius_m=w.acceptance_radius_m))
            prev = (n, e)
        await self._inner.upload_mission(out)

    async def start_mission(self) -> None:
        self._carrot = None
        await self._inner.start_mission()

    async def start_offboard(self, initial: Setpoint) -> None:
        s = self._inner.state()
        self._carrot = self._position("start_offboard()", s, (initial,))
        self._carrot_ns = self.clock.now_ns()
        try:
            sp = self._step("start_offboard()", initial, s, first=True)
        except SafetyViolation:
            self._carrot = None  # nothing was sent: there is no step to hold
            raise
        await self._inner.start_offboard(sp)

    async def set_setpoint(self, setpoint: Setpoint) -> None:
        s = self._inner.state()
        sp = self._step("set_setpoint()", setpoint, s)
        await self._inner.set_setpoint(sp)

    # -- the speed-limited step ----------------------------------------------------------------
    def _step(self, origin: str, requested: Setpoint, s: VehicleState, *, first: bool = False) -> Setpoint:
        """Clamp ``requested`` into the envelope, then move the carrot towards it by at most
        the speed limits times the time since the last setpoint, no further than ``lead_s``
        of travel from the current position."""
        env = self.envelope
        self.last_requested = requested
        off = round(self.ground_offset_m(s), 2)  # cm steps: the cache survives range noise
        req = (requested.north_m, requested.east_m, requested.down_m, off)
        cached = self._clamp_cache
        if cached is not None and cached[0] == req:  # the same target streamed at 20 Hz
            n, e, alt = cached[1]
            if cached[2] is not None:
                self._intervene(origin, cached[2], {"requested": (req[0], req[1], -req[2]),
                                                    "result": cached[1]},
                                refuse=self._refuse, params=(requested,))
        else:
            before = len(self._events)
            self._clamp_cache = None
            n, e, alt = self._check_point(origin, req[0], req[1], -req[2], None, (requested,),
                                          ground_offset_m=off)
            text = self._last_problem if len(self._events) > before or (n, e, alt) != (req[0], req[1], -req[2]) else None
            self._clamp_cache = (req, (n, e, alt), text)
        goal = (n, e, -alt)
        now = self.clock.now_ns()
        p = s.position_ned_m
        if not position_ok(p):
            # no position to step from: hold the last step sent (inside the envelope)
            if self._carrot is None:
                self._position(origin, s, (requested,))
            self._intervene(origin, f"the vehicle reports a non-finite or absurd position {p}: holding "
                            "the last setpoint", {"requested": req, "position_ned_m": p},
                            refuse=False)
            self._carrot_ns = now
            c = self._carrot
            assert c is not None
            sp = Setpoint(c[0], c[1], c[2], requested.yaw_deg)
            self.last_sent = sp
            return sp
        if self._carrot is None:  # offboard started without us (or after a mode change)
            self._carrot = p
            self._carrot_ns = now
        dt = 0.0 if first else min(self.max_step_dt_s, max(0.0, (now - self._carrot_ns) * 1e-9))
        self._carrot_ns = now
        vh = self.safety.max_horizontal_speed_mps
        vv = self.safety.max_vertical_speed_mps
        c = self._carrot
        # 1. advance the carrot towards the goal at the speed limits
        dn, de = goal[0] - c[0], goal[1] - c[1]
        dh = math.hypot(dn, de)
        kh = 1.0 if dh <= vh * dt else (vh * dt / dh)
        nn, ne = c[0] + dn * kh, c[1] + de * kh
        dd = goal[2] - c[2]
        nd = c[2] + max(-vv * dt, min(vv * dt, dd))
        # 2. never lead the vehicle by more than lead_s of travel
        ln, le = nn - p[0], ne - p[1]
        lh = math.hypot(ln, le)
        max_lead_h = vh * self.lead_s
        if lh > max_lead_h:
            nn, ne = p[0] + ln * max_lead_h / lh, p[1] + le * max_lead_h / lh
        max_lead_v = vv * self.lead_s
        nd = max(p[2] - max_lead_v, min(p[2] + max_lead_v, nd))
        # ... and never further outside the band than the vehicle itself (a step left from
        # before a jump in the reported altitude must not lead out of the band; the band in
        # estimated altitude, i.e. shifted by the rangefinder's ground offset)
        lo_m, hi_m = env.min_alt_m - off, env.max_alt_m - off
        nd = max(-max(hi_m, -p[2]), min(-min(lo_m, -p[2]), nd))
        # 3. the step itself must stay in the envelope (non-convex fences, vehicle outside);
        #    vertically it lies between the vehicle / previous step and a goal inside the band
        if not env.safe_h(nn, ne):
            base = (c[0], c[1]) if env.safe_h(c[0], c[1]) else None
            end = env.furthest_safe_on_segment(base, (nn, ne)) if base is not None else None
            nn, ne = end if end is not None else env.nearest_safe((nn, ne))
        self._carrot = (nn, ne, nd)
        sp = Setpoint(nn, ne, nd, requested.yaw_deg)
        self.last_sent = sp
        return sp
