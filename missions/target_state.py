"""The target state of the approach mission: filters over time and pure functions.

:class:`TargetFilter` (the target's position), :class:`PlaneOffsetFilter` (the plane of its
top, measured by the rangefinder), the vertical reference, the plane-fit and size-range
error models, the wide camera's confirmation and the grasp-stability count.

The position filter: a static target with process noise.

The target is assumed static in the world; its position *in the autopilot's local NED frame*
still wanders slowly because the vehicle's own position estimate drifts, and because coarse
(bearing) and fine (PnP) estimates disagree. A constant-position Kalman filter with a random-walk
process noise captures both: missed frames only grow the covariance, so a few misses never abort
the approach, and an outlier gate (Mahalanobis distance) rejects isolated wrong detections. A run
of rejected measurements that agree with each other resets the filter (the target was
re-acquired somewhere else, e.g. after a large estimate drift).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from eaglemission.geometry import ray_plane_points
from eaglemission.types import XYZ


class FilterConfig(BaseModel):
    """Parameters of :class:`TargetFilter` (``mission.params.filter``)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    process_noise_mps: float = Field(0.05, ge=0, description="random-walk sigma, m per sqrt(s)")
    gate_sigma: float = Field(4.0, gt=0, description="Mahalanobis gate for outliers")
    reset_after_rejections: int = Field(5, ge=1, description="consecutive consistent outliers")
    min_std_m: float = Field(0.01, gt=0, description="floor on a measurement's std")


@dataclass(frozen=True, slots=True)
class FilteredTarget:
    """Filter output at a time: position, 1-sigma per axis, time since the last update."""

    position_ned_m: XYZ
    std_m: XYZ
    age_s: float
    updates: int


def _xyz(values: Iterable[float]) -> XYZ:
    a, b, c = values
    return (a, b, c)


def predict_covariance(P: np.ndarray, dt_s: float, process_noise_mps: float) -> np.ndarray:
    """Random-walk prediction ``P + q^2 dt I`` (the mean of a static target does not move)."""
    return P + (process_noise_mps**2) * max(0.0, dt_s) * np.eye(3)


def kalman_update(
    x: np.ndarray, P: np.ndarray, z: np.ndarray, R: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float]:
    """Kalman update with identity measurement; returns (x, P, squared Mahalanobis distance)."""
    S = P + R
    innov = z - x
    S_inv = np.linalg.inv(S)
    d2 = float(innov @ S_inv @ innov)
    K = P @ S_inv
    x_new = x + K @ innov
    I_K = np.eye(3) - K
    P_new = I_K @ P @ I_K.T + K @ R @ K.T  # Joseph form: stays symmetric positive definite
    return x_new, P_new, d2


class TargetFilter:
    """Constant-position Kalman filter on the target's NED position (thread-compatible: call
    from one task)."""

    def __init__(self, config: FilterConfig | None = None) -> None:
        self.config = config or FilterConfig()
        self.reset()

    def reset(self) -> None:
        self._x: np.ndarray | None = None
        self._P = np.eye(3)
        self._t_ns = 0
        self._t_update_ns = 0
        self.updates = 0
        self._rejected: list[np.ndarray] = []

    @property
    def initialised(self) -> bool:
        return self._x is not None

    def _predict_to(self, t_ns: int) -> None:
        if t_ns > self._t_ns:
            self._P = predict_covariance(self._P, (t_ns - self._t_ns) * 1e-9,
                                         self.config.process_noise_mps)
            self._t_ns = t_ns

    def update(self, position_ned_m: XYZ, std_m: float | XYZ, t_ns: int, *,
               allow_reset: bool = True) -> bool:
        """Fuse one measurement; returns False when it was gated out as an outlier.
        ``allow_reset=False`` never restarts the filter on a run of consistent outliers
        (e.g. in the final approach, where a restart would follow a biased estimator)."""
        z = np.asarray(position_ned_m, dtype=np.float64)
        if z.shape != (3,) or not np.isfinite(z).all():
            raise ValueError(f"position_ned_m: must be 3 finite numbers, got {position_ned_m}")
        std = np.broadcast_to(np.asarray(std_m, dtype=np.float64), (3,))
        std = np.maximum(std, self.config.min_std_m)
        R = np.diag(std**2)
        if self._x is None:
            self._x, self._P = z.copy(), R.copy()
            self._t_ns = self._t_update_ns = t_ns
            self.updates = 1
            return True
        self._predict_to(t_ns)
        x_new, P_new, d2 = kalman_update(self._x, self._P, z, R)
        if d2 > self.config.gate_sigma**2:
            self._rejected.append(z)
            if allow_reset and len(self._rejected) >= self.config.reset_after_rejections:
                pts = np.array(self._rejected)
                spread = float(np.max(np.linalg.norm(pts - pts.mean(axis=0), axis=1)))
                if spread <= self.config.gate_sigma * float(std.max()):
                    # the outliers agree with each other: the target is elsewhere, restart there
                    self._x, self._P = pts.mean(axis=0), R.copy()
                    self._t_ns = self._t_update_ns = t_ns
                    self.updates = 1
                    self._rejected = []
                    return True
                self._rejected = self._rejected[1:]
            elif len(self._rejected) > self.config.reset_after_rejections:
                self._rejected = self._rejected[1:]
            return False
        self._rejected = []
        self._x, self._P = x_new, P_new
        self._t_update_ns = t_ns
        self.updates += 1
        return True

    def state(self, t_ns: int) -> FilteredTarget | None:
        """The estimate at ``t_ns`` (covariance predicted forward), None before any update."""
        if self._x is None:
            return None
        P = predict_covariance(self._P, (t_ns - self._t_ns) * 1e-9, self.config.process_noise_mps)
        x = self._x
        return FilteredTarget(
            (float(x[0]), float(x[1]), float(x[2])),
            _xyz(math.sqrt(max(0.0, float(v))) for v in np.diag(P)),
            max(0.0, (t_ns - self._t_update_ns) * 1e-9),
            self.updates,
        )


class PlaneOffsetFilter:
    """Height of the target's top plane *in the vehicle's estimated frame*, as an offset (m,
    positive down) from its nominal height ``-target.height_m`` (flat ground at home's height).

    The vehicle's altitude estimate is off by a few centimetres and drifts slowly; every
    position found by intersecting a ray with the nominal plane inherits that error along the
    ray, which at the grasp pose (0.5 m range, 50 deg depression) moves the estimate by ~1.3x
    the altitude error down *and* along the approach. A downward rangefinder measures the plane
    (estimated down + range x cos tilt, flat ground); this scalar random-walk Kalman filter
    fuses its readings, and the plane fits of every view use its value.
    """

    def __init__(self, prior_std_m: float, process_noise_mps: float, gate_sigma: float = 4.0
                 ) -> None:
        if prior_std_m <= 0 or process_noise_mps < 0 or gate_sigma <= 0:
            raise ValueError("PlaneOffsetFilter: prior_std_m and gate_sigma must be > 0, "
                             f"process_noise_mps >= 0; got {prior_std_m}, {process_noise_mps}, "
                             f"{gate_sigma}")
        self.prior_std_m = float(prior_std_m)
        self.process_noise_mps = float(process_noise_mps)
        self.gate_sigma = float(gate_sigma)
        self.reset()

    def reset(self) -> None:
        self.offset_m = 0.0
        self._var = self.prior_std_m**2
        self._t_ns: int | None = None
        self.updates = 0

    def std_m(self, t_ns: int | None = None) -> float:
        var = self._var
        if t_ns is not None and self._t_ns is not None and t_ns > self._t_ns:
            var += self.process_noise_mps**2 * (t_ns - self._t_ns) * 1e-9
        return math.sqrt(var)

    def update(self, offset_m: float, std_m: float, t_ns: int) -> bool:
        """Fuse one measured offset (m, positive down); False when gated out."""
        if not (math.isfinite(offset_m) and math.isfinite(std_m) and std_m > 0):
            raise ValueError(f"offset_m, std_m: must be finite (std > 0), got {offset_m}, {std_m}")
        var = self.std_m(t_ns) ** 2
        if self._t_ns is None or t_ns > self._t_ns:
            self._t_ns = t_ns
        s = var + std_m**2
        innov = offset_m - self.offset_m
        if innov * innov > self.gate_sigma**2 * s:
            self._var = var
            return False
        k = var / s
        self.offset_m += k * innov
        self._var = (1.0 - k) * var
        self.updates += 1
        return True


# ---------------------------------------------------------------------------------------------
# Pure functions of the target state (the runner calls them on the loop thread; the perception
# worker gets the immutable PlaneState)
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class PlaneState:
    """The target plane's offset estimate at one instant (handed to perception by value)."""

    offset_m: float
    std_m: float


def plane_down_m(target_height_m: float, plane: PlaneState) -> float:
    """Down coordinate of the plane of the target's top face: flat ground at home's height
    (``-height_m``), shifted by the measured offset (0 while nothing measured it)."""
    return -float(target_height_m) + plane.offset_m


def vertical_reference(p: Sequence[float], camera_ned_m: Sequence[float] | None,
                       plane_m: float, mode: str, *, full_3d: bool = False,
                       full_3d_range_m: float = 1.6) -> XYZ:
    """Apply ``vertical_reference`` to an estimated target position ``p``.

    ``estimate``: ``p`` as the estimator gave it. ``ground``: keep the direction of ``p`` from
    the camera (precise) and take its range from the plane ``down = plane_m`` (the weak part of
    a 4-point PnP at a few metres). ``hybrid``: ``ground`` beyond ``full_3d_range_m``, the full
    3-D estimate closer in (when it is one: ``full_3d``). Without a camera position, ``p`` is
    moved vertically onto the plane.
    """
    if mode == "estimate":
        return (float(p[0]), float(p[1]), float(p[2]))
    if camera_ned_m is not None:
        c = np.asarray(camera_ned_m, dtype=np.float64)
        d = np.asarray(p, dtype=np.float64) - c
        if mode == "hybrid" and full_3d and float(np.linalg.norm(d)) <= full_3d_range_m:
            return (float(p[0]), float(p[1]), float(p[2]))
        hit = ray_plane_points(c, d[None, :], plane_m, min_down=1e-3)[0]
        if np.isfinite(hit).all():
            return (float(hit[0]), float(hit[1]), plane_m)
    return (float(p[0]), float(p[1]), plane_m)


def fit_std_m(range_m: float, sin_depression: float, angular_std_deg: float) -> float:
    """1-sigma of a plane-fit position: the angular error spread along the line of sight."""
    return range_m * math.radians(angular_std_deg) / max(sin_depression, 1e-3)


def size_range_scale(size_ratio: float, plane_std_m: float, sin_depression: float,
                     range_m: float, size_std_fraction: float) -> float:
    """Factor on the camera-to-target vector that fuses the plane's range with the range from
    the target's apparent size (1 / ``size_ratio``, a known target), weighted by their errors."""
    s_plane = plane_std_m / max(sin_depression, 1e-3)
    s_size = size_std_fraction * range_m
    w = s_plane**2 / (s_plane**2 + s_size**2)
    return 1.0 + w * (1.0 / size_ratio - 1.0)


def confirmation(history: Sequence[XYZ], p: XYZ | None, *, radius_m: float,
                 accept: bool = True) -> list[XYZ]:
    """The run of consecutive wide-camera positions that agree within ``radius_m``: a miss
    (``p`` None) or a jump clears it; ``accept`` False (too far from where the target was
    lost) leaves it unchanged."""
    if p is None:
        return []
    out = list(history)
    if out and math.dist(p, out[-1]) > radius_m:
        out = []
    if accept:
        out.append(p)
    return out


def grasp_progress(window: Sequence[tuple[float, float]], h_err_m: float, dist_m: float, *,
                   slow: bool, grasp_distance_m: float, tolerance_m: float, hold_factor: float,
                   accept_fraction: float, required: int) -> tuple[list[tuple[float, float]], int]:
    """One frame of the grasp-stability count: (new window, frames counted).

    Frames count while the tool point stays within ``hold_factor`` x the tolerance (a hover in
    wind jitters by a few cm) and the vehicle is slow; the count reaches ``required`` only
    when the latest error is within the tolerance and the running mean of the last
    ``required`` frames within ``accept_fraction`` x the tolerance (the margin for the
    estimate's own error). Anything else resets the window.
    """
    near = (slow and h_err_m <= hold_factor * tolerance_m
            and abs(dist_m - grasp_distance_m) <= hold_factor * tolerance_m)
    if not near:
        return [], 0
    win = [*window, (h_err_m, dist_m)][-64:]
    recent = win[-required:]
    h_mean = float(np.mean([h for h, _ in recent]))
    d_mean = float(np.mean([d for _, d in recent]))
    accept = accept_fraction * tolerance_m
    inside = (h_mean <= accept and abs(d_mean - grasp_distance_m) <= accept
              and h_err_m <= tolerance_m and abs(dist_m - grasp_distance_m) <= tolerance_m)
    return win, len(win) if inside else min(len(win), required - 1)
