"""Helpers of the camera driver tests (imported by name: the tests folder is not a package)."""

from __future__ import annotations

import math

import numpy as np

from eaglemission.geometry import euler_to_quat

TARGET_NE = (10.0, 2.0)


def looking_at_target(distance_m: float, bearing_deg: float, *, tilt_deg: float = 30.0,
                      roll_deg: float = 0.0, pitch_deg: float = 0.0, yaw_err_deg: float = 0.0
                      ) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
    """A vehicle pose at horizontal ``distance_m`` from the target, on ``bearing_deg`` (the
    direction it looks in), at the height that puts the target on a ``tilt_deg`` optical
    axis (the mount's pitch)."""
    b = math.radians(bearing_deg)
    alt = distance_m * math.tan(math.radians(tilt_deg))
    pos = (TARGET_NE[0] - distance_m * math.cos(b), TARGET_NE[1] - distance_m * math.sin(b),
           -alt)
    return pos, euler_to_quat(roll_deg, pitch_deg, bearing_deg + yaw_err_deg)


class StaticPose:
    """A pose source returning a fixed pose (or a pose moving at a constant velocity)."""

    def __init__(self, pos: tuple[float, float, float], q: tuple[float, float, float, float],
                 velocity_ned_mps: tuple[float, float, float] = (0.0, 0.0, 0.0),
                 t0_ns: int = 1_000_000_000) -> None:
        self.pos = np.asarray(pos, dtype=np.float64)
        self.q = q
        self.v = np.asarray(velocity_ned_mps, dtype=np.float64)
        self.t0_ns = t0_ns
        self.calls: list[int] = []

    def __call__(self, t_ns: int) -> tuple[tuple[float, float, float],
                                            tuple[float, float, float, float]] | None:
        self.calls.append(t_ns)
        p = self.pos + self.v * (t_ns - self.t0_ns) / 1e9
        return (float(p[0]), float(p[1]), float(p[2])), self.q
