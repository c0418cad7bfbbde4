"""Pure geometry of the safety envelope (geofence membership), shared by config checks and
the runtime envelope in :mod:`eaglemission.safety.envelope`."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any


def point_in_polygon(north_m: float, east_m: float, polygon: Sequence[Sequence[float]]) -> bool:
    """Even-odd rule; vertices are (north_m, east_m)."""
    inside = False
    n = len(polygon)
    for i in range(n):
        n1, e1 = polygon[i]
        n2, e2 = polygon[(i + 1) % n]
        if (e1 > east_m) != (e2 > east_m):
            n_cross = n1 + (east_m - e1) * (n2 - n1) / (e2 - e1)
            if north_m < n_cross:
                inside = not inside
    return inside


def inside_geofence(fence: Any, north_m: float, east_m: float) -> bool:
    """``fence`` has ``radius_m`` and/or ``polygon_ned_m``; both must hold when both are set."""
    ok = True
    if getattr(fence, "radius_m", None) is not None:
        ok &= math.hypot(north_m, east_m) <= fence.radius_m
    if getattr(fence, "polygon_ned_m", None) is not None:
        ok &= point_in_polygon(north_m, east_m, fence.polygon_ned_m)
    return bool(ok)
