"""Compiled (numba) corners of what a convex occluder leaves of a convex region
(:func:`.top_plane.visible_mbr`): the region's corners not strictly inside the occluder and the
points where the two outlines cross. Same arithmetic as ``top_plane.visible_points_numpy``
(tests compare them)."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def visible_points(region: np.ndarray, occ: np.ndarray) -> np.ndarray:
    n, m = region.shape[0], occ.shape[0]
    out = np.empty((n + n * m, 2))
    k = 0
    for i in range(n):
        pos = 0
        neg = 0
        for j in range(m):
            j1 = (j + 1) % m
            ex, ey = occ[j1, 0] - occ[j, 0], occ[j1, 1] - occ[j, 1]
            c = ex * (region[i, 1] - occ[j, 1]) - ey * (region[i, 0] - occ[j, 0])
            if c > 0:
                pos += 1
            elif c < 0:
                neg += 1
        if not (pos == m or neg == m):
            out[k, 0], out[k, 1] = region[i, 0], region[i, 1]
            k += 1
    for i in range(n):
        i1 = (i + 1) % n
        px, py = region[i, 0], region[i, 1]
        rx, ry = region[i1, 0] - px, region[i1, 1] - py
        for j in range(m):
            j1 = (j + 1) % m
            sx, sy = occ[j1, 0] - occ[j, 0], occ[j1, 1] - occ[j, 1]
            rxs = rx * sy - ry * sx
            if rxs == 0.0:
                continue  # parallel edges
            qx, qy = occ[j, 0] - px, occ[j, 1] - py
            t = (qx * sy - qy * sx) / rxs
            u = (qx * ry - qy * rx) / rxs
            if 0.0 <= t <= 1.0 and 0.0 <= u <= 1.0:
                out[k, 0], out[k, 1] = px + t * rx, py + t * ry
                k += 1
    return out[:k]
