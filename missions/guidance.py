"""Pure guidance functions of the approach mission: route carrot, standoff, grasp pose, tool
point. Frames and units: docs/conventions.md (local NED, body FRD, yaw from north to east).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from eaglemission.geometry import quat_to_R, wrap_deg
from eaglemission.types import XYZ, Setpoint


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
