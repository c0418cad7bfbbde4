"""Compiled (numba) residual of the region-model fit in :mod:`.correspondence`: project the
region's corners for a target pose (NED position + yaw, face horizontal), take their
minimum-area rectangle, order its corners like ``order_corners`` and return the 8 residuals to
the observed corners, matched up to a cyclic relabelling. Same arithmetic as the numpy path
(``CornerPoseEstimator._residual_numpy``; tests compare them). OpenCV's distortion model with
0, 4, 5 or 8 coefficients.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def _order(c: np.ndarray) -> np.ndarray:
    """order_corners: clockwise on screen (angle about the centre increasing), starting at the
    smallest u + v (ties: smaller v)."""
    cu = (c[0, 0] + c[1, 0] + c[2, 0] + c[3, 0]) / 4.0
    cv = (c[0, 1] + c[1, 1] + c[2, 1] + c[3, 1]) / 4.0
    ang = np.empty(4)
    for i in range(4):
        ang[i] = math.atan2(c[i, 1] - cv, c[i, 0] - cu)
    idx = np.argsort(ang)
    s = np.empty((4, 2))
    for i in range(4):
        s[i, 0] = c[idx[i], 0]
        s[i, 1] = c[idx[i], 1]
    start = 0
    for i in range(1, 4):
        si = s[i, 0] + s[i, 1]
        sb = s[start, 0] + s[start, 1]
        if si < sb or (si == sb and s[i, 1] < s[start, 1]):
            start = i
    out = np.empty((4, 2))
    for i in range(4):
        out[i, 0] = s[(start + i) % 4, 0]
        out[i, 1] = s[(start + i) % 4, 1]
    return out


@njit(cache=True)
def min_area_rect(p: np.ndarray) -> np.ndarray:
    """Ordered corners of the minimum-area rectangle around the points (side along the
    direction of some point pair, which includes every hull edge)."""
    n = p.shape[0]
    best_area = np.inf
    best = np.zeros(6)
    for i in range(n):
        for j in range(i + 1, n):
            dx = p[j, 0] - p[i, 0]
            dy = p[j, 1] - p[i, 1]
            nr = math.sqrt(dx * dx + dy * dy)
            if nr <= 1e-12:
                continue
            ux, uy = dx / nr, dy / nr
            amin = np.inf
            amax = -np.inf
            bmin = np.inf
            bmax = -np.inf
            for k in range(n):
                a = p[k, 0] * ux + p[k, 1] * uy
                b = -p[k, 0] * uy + p[k, 1] * ux
                amin = min(amin, a)
                amax = max(amax, a)
                bmin = min(bmin, b)
                bmax = max(bmax, b)
            area = (amax - amin) * (bmax - bmin)
            if area < best_area:
                best_area = area
                best[0], best[1], best[2], best[3], best[4], best[5] = ux, uy, amin, amax, bmin, bmax
    ux, uy, amin, amax, bmin, bmax = best[0], best[1], best[2], best[3], best[4], best[5]
    # e1 = (ux, uy), e2 = (-uy, ux)
    c = np.empty((4, 2))
    c[0, 0], c[0, 1] = amin * ux - bmin * uy, amin * uy + bmin * ux
    c[1, 0], c[1, 1] = amax * ux - bmin * uy, amax * uy + bmin * ux
    c[2, 0], c[2, 1] = amax * ux - bmax * uy, amax * uy + bmax * ux
    c[3, 0], c[3, 1] = amin * ux - bmax * uy, amin * uy + bmax * ux
    return _order(c)


@njit(cache=True)
def region_residual(x: np.ndarray, corners_t: np.ndarray, R_cn: np.ndarray, cam_t: np.ndarray,
                    K: np.ndarray, dist: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """8 residuals (px). ``x = (north, east, down, yaw_deg)``; ``R_cn`` NED -> optical;
    ``cam_t`` camera centre (NED); ``dist`` OpenCV coefficients (0, 4, 5 or 8)."""
    out = np.full(8, 1e3)
    c = math.cos(math.radians(x[3]))
    s = math.sin(math.radians(x[3]))
    # R_ct = R_cn @ Rz(yaw); t_ct = R_cn @ (p - cam_t)
    Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    R = R_cn @ Rz
    d0, d1, d2 = x[0] - cam_t[0], x[1] - cam_t[1], x[2] - cam_t[2]
    t0 = R_cn[0, 0] * d0 + R_cn[0, 1] * d1 + R_cn[0, 2] * d2
    t1 = R_cn[1, 0] * d0 + R_cn[1, 1] * d1 + R_cn[1, 2] * d2
    t2 = R_cn[2, 0] * d0 + R_cn[2, 1] * d1 + R_cn[2, 2] * d2
    n = corners_t.shape[0]
    px = np.empty((n, 2))
    nd = dist.shape[0]
    k1 = dist[0] if nd > 0 else 0.0
    k2 = dist[1] if nd > 1 else 0.0
    p1 = dist[2] if nd > 2 else 0.0
    p2 = dist[3] if nd > 3 else 0.0
    k3 = dist[4] if nd > 4 else 0.0
    k4 = dist[5] if nd > 7 else 0.0
    k5 = dist[6] if nd > 7 else 0.0
    k6 = dist[7] if nd > 7 else 0.0
    for i in range(n):
        X = R[0, 0] * corners_t[i, 0] + R[0, 1] * corners_t[i, 1] + R[0, 2] * corners_t[i, 2] + t0
        Y = R[1, 0] * corners_t[i, 0] + R[1, 1] * corners_t[i, 1] + R[1, 2] * corners_t[i, 2] + t1
        Z = R[2, 0] * corners_t[i, 0] + R[2, 1] * corners_t[i, 1] + R[2, 2] * corners_t[i, 2] + t2
        if not Z > 1e-6:
            return out
        xn, yn = X / Z, Y / Z
        if nd > 0:
            r2 = xn * xn + yn * yn
            radial = (1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2) / (
                1 + k4 * r2 + k5 * r2 * r2 + k6 * r2 * r2 * r2)
            xd = xn * radial + 2 * p1 * xn * yn + p2 * (r2 + 2 * xn * xn)
            yd = yn * radial + p1 * (r2 + 2 * yn * yn) + 2 * p2 * xn * yn
            xn, yn = xd, yd
        px[i, 0] = K[0, 0] * xn + K[0, 1] * yn + K[0, 2]
        px[i, 1] = K[1, 1] * yn + K[1, 2]
    pred = min_area_rect(px)
    best = np.inf
    for k in range(4):
        e = 0.0
        for i in range(4):
            du = pred[(i - k) % 4, 0] - observed[i, 0]
            dv = pred[(i - k) % 4, 1] - observed[i, 1]
            e += du * du + dv * dv
        if e < best:
            best = e
            for i in range(4):
                out[2 * i] = pred[(i - k) % 4, 0] - observed[i, 0]
                out[2 * i + 1] = pred[(i - k) % 4, 1] - observed[i, 1]
    return out


@njit(cache=True)
def region_jacobian(x: np.ndarray, corners_t: np.ndarray, R_cn: np.ndarray, cam_t: np.ndarray,
                    K: np.ndarray, dist: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """Forward-difference Jacobian (8, 4) of :func:`region_residual` (steps 1e-6 m, 1e-5 deg)."""
    r0 = region_residual(x, corners_t, R_cn, cam_t, K, dist, observed)
    J = np.empty((8, 4))
    for k in range(4):
        h = 1e-6 * max(1.0, abs(x[k])) if k < 3 else 1e-5
        xk = x.copy()
        xk[k] += h
        rk = region_residual(xk, corners_t, R_cn, cam_t, K, dist, observed)
        for i in range(8):
            J[i, k] = (rk[i] - r0[i]) / h
    return J
