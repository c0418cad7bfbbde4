"""Guidance of the approach mission: pure functions (route carrot, standoff, grasp pose, tool
point) and :class:`Guidance`, which owns the goal, the trim and the tilt compensation. Frames
and units: docs/conventions.md (local NED, body FRD, yaw from north to east).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from eaglemission.geometry import quat_to_R, wrap_deg
from eaglemission.types import XYZ, Quat, Setpoint

if TYPE_CHECKING:
    from eaglemission.missions.approach_config import GuidanceConfig

    from eaglemission.config import MissionFile


def step_towards(current: Sequence[float], goal: Sequence[float], max_step_m: float) -> XYZ:
    """Move ``current`` towards ``goal`` by at most ``max_step_m`` (3-D). Speed-limited
    setpoints are a carrot advanced by ``speed * dt`` per tick."""
    c = np.asarray(current, dtype=np.float64)
    d = np.asarray(goal, dtype=np.float64) - c
    n = float(np.linalg.norm(d))
    if n > max_step_m > 0:
        d *= max_step_m / n
    elif max_step_m <= 0:
        d[:] = 0.0
    p = c + d
    return (float(p[0]), float(p[1]), float(p[2]))


def yaw_towards_deg(from_ne: Sequence[float], to_ne: Sequence[float]) -> float:
    """Yaw (deg, north towards east) of the horizontal direction from one point to another."""
    return wrap_deg(math.degrees(math.atan2(to_ne[1] - from_ne[1], to_ne[0] - from_ne[0])))


def route_length_m(route_ne: Sequence[Sequence[float]]) -> float:
    pts = np.asarray(route_ne, dtype=np.float64).reshape(-1, 2)
    return float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum()) if len(pts) > 1 else 0.0


def route_point(route_ne: Sequence[Sequence[float]], s_m: float) -> tuple[float, float, float]:
    """Point at arc length ``s_m`` along the polyline and the yaw of its leg:
    (north_m, east_m, yaw_deg). Clamped to the ends."""
    pts = np.asarray(route_ne, dtype=np.float64).reshape(-1, 2)
    if len(pts) == 1:
        return float(pts[0, 0]), float(pts[0, 1]), 0.0
    s = max(0.0, s_m)
    yaw = 0.0
    for a, b in zip(pts[:-1], pts[1:]):
        seg = float(np.linalg.norm(b - a))
        if seg <= 1e-9:
            continue
        yaw = yaw_towards_deg(a, b)
        if s <= seg:
            p = a + (b - a) * (s / seg)
            return float(p[0]), float(p[1]), yaw
        s -= seg
    return float(pts[-1, 0]), float(pts[-1, 1]), yaw


def along_route_m(route_ne: Sequence[Sequence[float]], north_m: float, east_m: float) -> float:
    """Arc length of the route point nearest to (north_m, east_m)."""
    pts = np.asarray(route_ne, dtype=np.float64).reshape(-1, 2)
    best_d, best_s, s0 = math.inf, 0.0, 0.0
    q = np.array([north_m, east_m])
    for a, b in zip(pts[:-1], pts[1:]):
        ab = b - a
        seg = float(np.linalg.norm(ab))
        u = 0.0 if seg <= 1e-9 else float(np.clip((q - a) @ ab / seg**2, 0.0, 1.0))
        d = float(np.linalg.norm(a + u * ab - q))
        if d < best_d:
            best_d, best_s = d, s0 + u * seg
        s0 += seg
    return best_s


def standoff_position(
    target_ned_m: Sequence[float], approach_yaw_deg: float, horizontal_m: float, height_m: float
) -> XYZ:
    """Standoff point: ``horizontal_m`` short of the target along the approach direction,
    ``height_m`` above the target's top face (reference point = top-face centre)."""
    yaw = math.radians(approach_yaw_deg)
    return (target_ned_m[0] - horizontal_m * math.cos(yaw),
            target_ned_m[1] - horizontal_m * math.sin(yaw),
            target_ned_m[2] - height_m)


def grasp_position(
    target_ned_m: Sequence[float], yaw_deg: float, tool_point_m: Sequence[float],
    grasp_distance_m: float,
) -> XYZ:
    """Vehicle position (level attitude, yaw ``yaw_deg``) that puts the body-FRD tool point
    ``grasp_distance_m`` straight above the target's top-face centre."""
    yaw = math.radians(yaw_deg)
    c, s = math.cos(yaw), math.sin(yaw)
    tx, ty, tz = tool_point_m
    tool_n, tool_e = c * tx - s * ty, s * tx + c * ty
    return (target_ned_m[0] - tool_n, target_ned_m[1] - tool_e,
            target_ned_m[2] - grasp_distance_m - tz)


def tool_point_ned(position_ned_m: Sequence[float], attitude_q: Sequence[float],
                   tool_point_m: Sequence[float]) -> XYZ:
    """The body-FRD tool point in local NED for a vehicle pose."""
    p = np.asarray(position_ned_m, dtype=np.float64) + quat_to_R(attitude_q) @ np.asarray(
        tool_point_m, dtype=np.float64)
    return (float(p[0]), float(p[1]), float(p[2]))


def tool_errors(tool_ned_m: Sequence[float], target_ned_m: Sequence[float]) -> tuple[float, float]:
    """(horizontal distance, grasp distance = height of the tool point above the target's top
    face) in metres."""
    return (math.hypot(tool_ned_m[0] - target_ned_m[0], tool_ned_m[1] - target_ned_m[1]),
            float(target_ned_m[2] - tool_ned_m[2]))


def setpoint_at(p: Sequence[float], yaw_deg: float) -> Setpoint:
    return Setpoint(float(p[0]), float(p[1]), float(p[2]), wrap_deg(float(yaw_deg)))


def yaw_step_deg(current_deg: float, goal_deg: float, max_step_deg: float) -> float:
    """Turn from ``current_deg`` towards ``goal_deg`` by at most ``max_step_deg`` (wrapped)."""
    d = wrap_deg(goal_deg - current_deg)
    return wrap_deg(current_deg + max(-max_step_deg, min(max_step_deg, d)))


# ---------------------------------------------------------------------------------------------
# The approach's guidance: goals per state policy, carrot, trim, tilt compensation
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class Plan:
    """What guidance follows of the mission file besides its ``guidance`` params: the route,
    the cruise, the tool point and the grasp distance (plain values)."""

    route_ne_m: tuple[tuple[float, float], ...]
    cruise_altitude_m: float
    cruise_speed_mps: float
    tool_point_m: XYZ
    grasp_distance_m: float

    @classmethod
    def of(cls, cfg: MissionFile, grasp_distance_m: float) -> Plan:
        """From a mission file and the approach's ``grasp.distance_m``."""
        m = cfg.mission
        return cls(route_ne_m=tuple((w.north_m, w.east_m) for w in m.route),
                   cruise_altitude_m=m.cruise_altitude_m, cruise_speed_mps=m.cruise_speed_mps,
                   tool_point_m=(float(cfg.tool_point_m[0]), float(cfg.tool_point_m[1]),
                                 float(cfg.tool_point_m[2])),
                   grasp_distance_m=grasp_distance_m)


@dataclass(frozen=True, slots=True)
class GoalStep:
    """One setpoint tick: the setpoint to send and whether the vehicle is at the standoff."""

    setpoint: Setpoint
    goal_ned_m: XYZ
    at_standoff: bool


class Guidance:
    """Setpoints for the approach: a speed-limited carrot towards the state's goal (route,
    search sweep, standoff, grasp pose), yaw rate limited, with the grasp pose's tilt
    compensation and integral trim. Loop thread only."""

    def __init__(self, plan: Plan, params: GuidanceConfig) -> None:
        self.plan, self.p = plan, params
        self.route_len_m = route_length_m(plan.route_ne_m)
        self.route_s_m = 0.0
        self.carrot: XYZ | None = None
        self.carrot_yaw_deg = 0.0
        self.approach_yaw_deg: float | None = None
        self.trim: XYZ = (0.0, 0.0, 0.0)
        self._tool_off: XYZ | None = None
        self._search_t0_ns = 0
        self._search_centre: XYZ | None = None
        self.passes = 1
        """Route passes begun or granted (``search_route_again``)."""
        self.passes_left = 0
        """Times the route is still to be flown again from its start once it ends."""
        self._to_start = False

    # -- state entries ---------------------------------------------------------------------
    def start_at(self, position_ned_m: XYZ, yaw_deg: float) -> Setpoint:
        """Offboard starts here (never a far-away setpoint PX4 would fly to at full speed)."""
        self.carrot, self.carrot_yaw_deg = position_ned_m, yaw_deg
        return setpoint_at(position_ned_m, yaw_deg)

    def resume_route_from(self, north_m: float, east_m: float) -> None:
        self.route_s_m = max(self.route_s_m, along_route_m(self.plan.route_ne_m, north_m, east_m))

    def search_route_again(self) -> str | None:
        """Fly the route again from its start once it ends (a candidate on it was rejected:
        the target may have been passed unconfirmed), unless ``max_route_passes`` are flown or
        granted; what to log, None when not granted."""
        max_passes = self.p.max_route_passes
        if self.passes >= max_passes:
            return None
        self.passes += 1
        self.passes_left += 1
        return (f"route to be searched again from its start when it ends (pass {self.passes} "
                f"of guidance.max_route_passes={max_passes})")

    def new_approach(self) -> None:
        self.approach_yaw_deg = None

    def start_search(self, position_ned_m: XYZ, now_ns: int) -> None:
        self.carrot = position_ned_m
        self._search_centre = position_ned_m
        self._search_t0_ns = now_ns

    # -- queries -----------------------------------------------------------------------------
    def route_finished(self, position_ned_m: XYZ) -> bool:
        if self.passes_left or self._to_start or self.route_s_m < self.route_len_m - 1e-6:
            return False
        return math.dist(position_ned_m[:2], self.plan.route_ne_m[-1]) < 1.5

    def standoff_ned_m(self, target_ned_m: XYZ) -> XYZ:
        assert self.approach_yaw_deg is not None
        return standoff_position(target_ned_m, self.approach_yaw_deg,
                                 self.p.standoff.horizontal_m, self.p.standoff.height_m)

    # -- goals -------------------------------------------------------------------------------
    def goal(self, kind: str, position_ned_m: XYZ, yaw_deg: float, attitude_q: Quat,
             target_ned_m: XYZ | None, now_ns: int, dt_s: float
             ) -> tuple[XYZ, float, float] | None:
        """(goal position, goal yaw, speed) for a goal kind (``Goal`` names of the state
        policy), None when there is none (no target yet)."""
        c, p = self.plan, self.p
        if kind == "ROUTE":
            start = route_point(c.route_ne_m, 0.0)
            if (self.passes_left and self.route_s_m >= self.route_len_m - 1e-6
                    and math.dist(position_ned_m[:2], c.route_ne_m[-1]) < 1.5):
                self.passes_left -= 1
                self.route_s_m, self._to_start = 0.0, True
            if self._to_start and math.dist(position_ned_m[:2], start[:2]) >= 1.5:
                # straight back to the start at cruise altitude, facing the way it flies
                return ((start[0], start[1], -c.cruise_altitude_m),
                        yaw_towards_deg(position_ned_m[:2], start[:2]), c.cruise_speed_mps * 1.5)
            self._to_start = False
            here_s = along_route_m(c.route_ne_m, *position_ned_m[:2])
            self.route_s_m = min(self.route_len_m, self.route_s_m + c.cruise_speed_mps * dt_s,
                                 here_s + 2.0 * c.cruise_speed_mps)
            n, e, yaw = route_point(c.route_ne_m, self.route_s_m)
            return (n, e, -c.cruise_altitude_m), yaw, c.cruise_speed_mps * 1.5
        if kind == "SEARCH":
            centre = self._search_centre or position_ned_m
            base = self.approach_yaw_deg if self.approach_yaw_deg is not None else yaw_deg
            sweep = 40.0 * math.sin(2 * math.pi * (now_ns - self._search_t0_ns) * 1e-9 / 8.0)
            return centre, base + sweep, p.approach_speed_mps
        if target_ned_m is None:
            return None
        if kind == "APPROACH":  # the heading follows the target
            self.approach_yaw_deg = yaw_towards_deg(position_ned_m, target_ned_m)
            return self.standoff_ned_m(target_ned_m), self.approach_yaw_deg, p.approach_speed_mps
        if kind == "STANDOFF":  # the heading stays as the fine approach found it
            if self.approach_yaw_deg is None:
                self.approach_yaw_deg = yaw_towards_deg(position_ned_m, target_ned_m)
            return self.standoff_ned_m(target_ned_m), self.approach_yaw_deg, p.approach_speed_mps
        if kind == "GRASP":
            if self.approach_yaw_deg is None:
                self.approach_yaw_deg = yaw_towards_deg(position_ned_m, target_ned_m)
            yaw = self.approach_yaw_deg
            # the vehicle leans into the wind: put the TILTED tool point over the target (at
            # level attitude this is grasp_position's goal)
            off = self._tool_offset(attitude_q, dt_s)
            grasp = (target_ned_m[0] - off[0], target_ned_m[1] - off[1],
                     target_ned_m[2] - c.grasp_distance_m - off[2])
            return grasp, yaw, p.final_speed_mps
        return None

    def _tool_offset(self, attitude_q: Quat, dt_s: float) -> XYZ:
        """The tool point's NED offset from the vehicle at its current attitude, low-passed
        (time constant 1 s) so the attitude's jitter does not move the goal."""
        off = tool_point_ned((0.0, 0.0, 0.0), attitude_q, self.plan.tool_point_m)
        if self._tool_off is None:
            self._tool_off = off
        else:
            k = min(1.0, dt_s / 1.0)
            a = self._tool_off
            self._tool_off = (a[0] + k * (off[0] - a[0]), a[1] + k * (off[1] - a[1]),
                              a[2] + k * (off[2] - a[2]))
        return self._tool_off

    def _update_trim(self, goal: XYZ, position: XYZ, dt_s: float, holding: bool) -> XYZ:
        """Integral trim of the setpoint at the grasp pose: a multicopter's position loop
        holds a steady offset in wind (2-3 cm measured at 2.6 m/s), more than the grasp
        tolerance; the trim integrates the (estimated) position error once the carrot has
        reached the grasp goal, clamped to ``grasp_trim_max_m``."""
        if not holding or self.p.grasp_trim_gain_per_s <= 0:
            return (0.0, 0.0, 0.0)
        assert self.carrot is not None
        if math.dist(self.carrot, goal) > 0.05:
            return self.trim
        k = self.p.grasp_trim_gain_per_s * dt_s
        lim = self.p.grasp_trim_max_m
        t = [float(np.clip(t + k * (g - p), -lim, lim))
             for t, g, p in zip(self.trim, goal, position)]
        return (t[0], t[1], t[2])

    def step(self, kind: str, position_ned_m: XYZ, yaw_deg: float, attitude_q: Quat,
             target_ned_m: XYZ | None, now_ns: int, dt_s: float, *, trim: bool) -> GoalStep:
        """Advance the carrot by one tick towards the goal of ``kind``."""
        goal = self.goal(kind, position_ned_m, yaw_deg, attitude_q, target_ned_m, now_ns, dt_s)
        if goal is None:
            goal = (self.carrot or position_ned_m, self.carrot_yaw_deg, 0.0)
        pos, yaw, speed = goal
        if self.carrot is None:
            self.carrot = position_ned_m
        if kind == "SEARCH":
            self.carrot = pos
        else:
            self.carrot = step_towards(self.carrot, pos, speed * dt_s)
            # never let the carrot run away from the vehicle (wind, clamping)
            lead = math.dist(self.carrot, position_ned_m)
            max_lead = max(2.0, 2.0 * speed)
            if lead > max_lead:
                self.carrot = step_towards(position_ned_m, self.carrot, max_lead)
        self.carrot_yaw_deg = yaw_step_deg(self.carrot_yaw_deg, yaw,
                                           self.p.yaw_rate_degps * dt_s)
        self.trim = self._update_trim(pos, position_ned_m, dt_s, trim)
        carrot = self.carrot
        sp = setpoint_at((carrot[0] + self.trim[0], carrot[1] + self.trim[1],
                          carrot[2] + self.trim[2]), self.carrot_yaw_deg)
        at = False
        if kind == "STANDOFF" and target_ned_m is not None and self.approach_yaw_deg is not None:
            at = math.dist(position_ned_m, self.standoff_ned_m(target_ned_m)) \
                < self.p.standoff.tolerance_m
        return GoalStep(sp, pos, at)
