"""Synthetic PnP problems after the protocol of Li, Xu, Xie (TPAMI 2012), used by the tests and
``benchmarks/bench_pnp.py``: point families in the camera frame, the mission's top-face case,
and the protocol's error measures (test code: imported by name, ``from pnp_synthetic import
...``; pytest puts this folder on ``sys.path``, the benchmark adds it itself)."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from eaglemission.geometry import euler_to_R

Case = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]


def random_rotation(rs: np.random.RandomState) -> NDArray[np.float64]:
    q = rs.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def make_case(family: str, n: int, rs: np.random.RandomState, *,
              rect: tuple[float, float] = (0.40, 0.25)) -> Case:
    """(object_points (n,3), camera points (n,3), R, t) with X_c = R X_o + t.

    families: ``ordinary`` ([-2,2]x[-2,2]x[4,8] in the camera frame), ``quasi_singular``
    ([1,2]x[1,2]x[4,8]), ``planar`` (object z = 0, camera points as ordinary), ``rectangle``
    (the 4 corners of a ``rect`` top face seen from 0.2-10 m with 40-80 deg between the optical
    axis and the face normal; n is ignored)."""
    if family in ("ordinary", "quasi_singular"):
        lo = (-2.0, -2.0) if family == "ordinary" else (1.0, 1.0)
        hi = (2.0, 2.0)
        Xc = np.column_stack((rs.uniform(lo[0], hi[0], n), rs.uniform(lo[1], hi[1], n),
                              rs.uniform(4, 8, n)))
        R = random_rotation(rs)
        t = Xc.mean(axis=0)
        Xo = (Xc - t) @ R  # R^T (Xc - t)
        return Xo, Xc, R, t
    if family == "planar":
        Xc = np.column_stack((rs.uniform(-2, 2, n), rs.uniform(-2, 2, n), rs.uniform(4, 8, n)))
        t = Xc.mean(axis=0)
        # A random plane through t, facing the camera within 70 deg.
        while True:
            R = random_rotation(rs)
            if -R[:, 2] @ t < 0 and abs(R[:, 2] @ t) / np.linalg.norm(t) > math.cos(math.radians(70)):
                break
        Xo = np.column_stack((rs.uniform(-2, 2, n), rs.uniform(-2, 2, n), np.zeros(n)))
        Xc = Xo @ R.T + t
        return Xo, Xc, R, t
    if family == "rectangle":
        L, W = rect
        Xo = np.array([[L / 2, -W / 2, 0], [L / 2, W / 2, 0], [-L / 2, W / 2, 0], [-L / 2, -W / 2, 0]])
        dist = rs.uniform(0.2, 10.0)
        tilt = rs.uniform(40.0, 80.0)  # angle between the optical axis and the face normal
        # The target's z (into the box) makes ``tilt`` with the optical axis, so the top face's
        # outward normal (-z) faces the camera.
        R = euler_to_R(0.0, 0.0, rs.uniform(-180, 180))  # yaw of the target about its normal
        tilt_R = euler_to_R(tilt, 0.0, 0.0)
        spin = euler_to_R(0.0, 0.0, rs.uniform(-180, 180))
        R = spin @ tilt_R @ R
        off = rs.uniform(-0.1, 0.1, 2) * dist  # target near the image centre
        t = np.array([off[0], off[1], dist])
        return Xo, Xo @ R.T + t, R, t
    raise ValueError(family)


def normalized(Xc: NDArray[np.float64]) -> NDArray[np.float64]:
    uv: NDArray[np.float64] = Xc[:, :2] / Xc[:, 2:3]
    return uv


def rotation_error_deg(R: NDArray[np.float64], R_true: NDArray[np.float64]) -> float:
    """The protocol's rotation error: largest angle between corresponding columns (deg)."""
    c = np.clip(np.sum(R * R_true, axis=0), -1.0, 1.0)
    return float(np.degrees(np.arccos(c)).max())


def translation_error_pct(t: NDArray[np.float64], t_true: NDArray[np.float64]) -> float:
    return float(np.linalg.norm(t - t_true) / np.linalg.norm(t_true) * 100.0)
