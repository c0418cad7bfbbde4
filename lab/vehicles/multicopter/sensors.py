"""What the autopilot and its sensors report of the true motion: the position estimate's error
(an EKF's slow drift; dead reckoning without GPS) and a downward rangefinder."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Annotated

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from eaglemission.types import XYZ

if TYPE_CHECKING:  # the model's params build an estimate model; imported for the annotations
    from eaglemission.lab.vehicles.multicopter.dynamics import DynamicsParams

SMOOTHING_TIME_S = 1.0  # low-pass of the estimate error (EKF output is smooth)

_Pos = Annotated[float, Field(gt=0, allow_inf_nan=False)]
_NonNeg = Annotated[float, Field(ge=0, allow_inf_nan=False)]


class Normals:
    """Seeded standard normals drawn in blocks (a numpy call per sample would dominate)."""

    def __init__(self, rng: np.random.Generator, block: int = 4096) -> None:
        self._rng = rng
        self._block = block
        self._buf: list[float] = []
        self._i = 0

    def next(self) -> float:
        if self._i >= len(self._buf):
            self._buf = self._rng.standard_normal(self._block).tolist()
            self._i = 0
        v = self._buf[self._i]
        self._i += 1
        return v


class EstimateModel:
    """The autopilot's position estimate error: ``estimate = truth + error``.

    With GPS the error is an Ornstein-Uhlenbeck process per axis (stationary std
    ``horizontal_std_m`` / ``vertical_std_m``, correlation time ``correlation_time_s``),
    clipped to ``max_error_m`` (EKF innovation gating); it starts at a random draw (home and
    the EKF origin differ by decimetres on real PX4). Without GPS it drifts linearly at
    ``gps_loss_drift_mps`` in a seeded random direction; when GPS returns it resets onto the
    underlying process (an EKF position reset).
    """

    def __init__(
        self,
        *,
        seed: int,
        horizontal_std_m: float = 0.08,
        vertical_std_m: float = 0.04,
        correlation_time_s: float = 30.0,
        max_error_m: float = 0.3,
        gps_loss_drift_mps: float = 0.3,
    ) -> None:
        if correlation_time_s <= 0:
            raise ValueError(f"correlation_time_s: must be > 0, got {correlation_time_s}")
        self.horizontal_std_m = float(horizontal_std_m)
        self.vertical_std_m = float(vertical_std_m)
        self.correlation_time_s = float(correlation_time_s)
        self.max_error_m = float(max_error_m)
        self.gps_loss_drift_mps = float(gps_loss_drift_mps)
        self._normals = Normals(np.random.default_rng(np.random.SeedSequence([int(seed), 0xE5])))
        stds = (self.horizontal_std_m, self.horizontal_std_m, self.vertical_std_m)
        self._ou = [self._clip(s * self._normals.next()) for s in stds]
        self._smooth = list(self._ou)  # low-passed: an EKF estimate does not jitter
        self._drift = [0.0, 0.0, 0.0]
        self._drift_v = (0.0, 0.0, 0.0)
        self.gps_ok = True
        self._cached_dt = -1.0
        self._a = 1.0
        self._b = 0.0

    @classmethod
    def from_params(cls, params: DynamicsParams, *, seed: int) -> EstimateModel:
        return cls(
            seed=seed,
            horizontal_std_m=params.estimate_horizontal_std_m,
            vertical_std_m=params.estimate_vertical_std_m,
            correlation_time_s=params.estimate_correlation_time_s,
            max_error_m=params.estimate_max_error_m,
            gps_loss_drift_mps=params.gps_loss_drift_mps,
        )

    def _clip(self, v: float) -> float:
        m = self.max_error_m
        return -m if v < -m else (m if v > m else v)

    @property
    def error_ned_m(self) -> XYZ:
        o, d = self._smooth, self._drift
        return (o[0] + d[0], o[1] + d[1], o[2] + d[2])

    def set_gps(self, ok: bool) -> None:
        """GPS lost (``False``): start drifting; regained: reset onto the GPS-aided estimate."""
        if ok == self.gps_ok:
            return
        self.gps_ok = ok
        if not ok:
            ang = math.pi * (1.0 + self._normals.next() * 0.5)
            v = self.gps_loss_drift_mps
            self._drift_v = (v * math.cos(ang), v * math.sin(ang), 0.1 * v * self._normals.next())
        else:
            self._drift = [0.0, 0.0, 0.0]
            self._drift_v = (0.0, 0.0, 0.0)
            self._smooth = list(self._ou)

    def step(self, dt_s: float) -> None:
        if dt_s != self._cached_dt:
            self._cached_dt = dt_s
            self._a = math.exp(-dt_s / self.correlation_time_s)
            self._b = math.sqrt(max(0.0, 1.0 - self._a * self._a))
        a, b = self._a, self._b
        o = self._ou
        nx = self._normals.next
        o[0] = self._clip(a * o[0] + b * self.horizontal_std_m * nx())
        o[1] = self._clip(a * o[1] + b * self.horizontal_std_m * nx())
        o[2] = self._clip(a * o[2] + b * self.vertical_std_m * nx())
        f = self._smooth
        k = min(1.0, dt_s / SMOOTHING_TIME_S)
        f[0] += (o[0] - f[0]) * k
        f[1] += (o[1] - f[1]) * k
        f[2] += (o[2] - f[2]) * k
        if not self.gps_ok:
            d, v = self._drift, self._drift_v
            d[0] += v[0] * dt_s
            d[1] += v[1] * dt_s
            d[2] += v[2] * dt_s


class RangefinderParams(BaseModel):
    """A downward distance sensor (lidar such as a LightWare or TFmini, PX4 ``DISTANCE_SENSOR``)
    on the body's down axis at the body origin, over flat ground at home's height (the target
    and distractors are not seen by the beam)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    enabled: bool = False
    noise_std_m: _NonNeg = 0.01
    min_range_m: _NonNeg = 0.1
    max_range_m: _Pos = 12.0


def rangefinder_reading_m(true_down_m: float, cos_tilt: float, params: RangefinderParams,
                          noise: float) -> float | None:
    """Range along the body's down axis to flat ground at ``down = 0`` for a body origin at
    ``true_down_m`` (NED, negative above ground) whose down axis makes ``acos(cos_tilt)`` with
    the vertical; ``noise`` is a standard normal draw. None when disabled, pointing at or
    above the horizon, or outside the sensor's range."""
    if not params.enabled or cos_tilt <= 0.1:
        return None
    r = -true_down_m / cos_tilt
    if not params.min_range_m <= r <= params.max_range_m:
        return None
    return r + params.noise_std_m * noise
