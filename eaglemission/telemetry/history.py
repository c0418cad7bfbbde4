"""A short telemetry history to look up the vehicle pose at a frame's mid-exposure time."""

from __future__ import annotations

import bisect
import math
import threading
from collections import deque
from dataclasses import replace

from eaglemission.geometry import quat_slerp
from eaglemission.types import VehicleState


def _lerp3(a: tuple[float, float, float], b: tuple[float, float, float], s: float) -> tuple[float, float, float]:
    return (a[0] + s * (b[0] - a[0]), a[1] + s * (b[1] - a[1]), a[2] + s * (b[2] - a[2]))


def rotate_by_body_rates(
    attitude_q: tuple[float, float, float, float], rates_frd_radps: tuple[float, float, float],
    dt_s: float,
) -> tuple[float, float, float, float]:
    """Attitude after ``dt_s`` at constant body rates (FRD, rad/s): ``q * exp(w dt / 2)``.
    Unchanged when the rates are zero (unknown)."""
    wx, wy, wz = (float(r) * dt_s for r in rates_frd_radps)
    angle = math.sqrt(wx * wx + wy * wy + wz * wz)
    if angle < 1e-15:
        return attitude_q
    h = angle / 2.0
    k = math.sin(h) / angle
    dw, dx, dy, dz = math.cos(h), wx * k, wy * k, wz * k
    w, x, y, z = attitude_q
    q = (w * dw - x * dx - y * dy - z * dz,
         w * dx + x * dw + y * dz - z * dy,
         w * dy - x * dz + y * dw + z * dx,
         w * dz + x * dy - y * dx + z * dw)
    n = math.sqrt(sum(c * c for c in q))
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


def interpolate_states(a: VehicleState, b: VehicleState, timestamp_ns: int) -> VehicleState:
    """Linear interpolation of position/velocity and slerp of attitude between two samples."""
    span = b.timestamp_ns - a.timestamp_ns
    s = 0.0 if span <= 0 else (timestamp_ns - a.timestamp_ns) / span
    nearer = a if s < 0.5 else b
    return replace(
        nearer,
        timestamp_ns=timestamp_ns,
        position_ned_m=_lerp3(a.position_ned_m, b.position_ned_m, s),
        velocity_ned_mps=_lerp3(a.velocity_ned_mps, b.velocity_ned_mps, s),
        attitude_q=quat_slerp(a.attitude_q, b.attitude_q, s),
        relative_altitude_m=a.relative_altitude_m + s * (b.relative_altitude_m - a.relative_altitude_m),
    )


class TelemetryHistory:
    """Thread-safe ring buffer of :class:`VehicleState`, ordered by ``timestamp_ns``.

    ``state_at(t)`` interpolates between the bracketing samples. Beyond the newest sample it
    extrapolates position with the velocity and attitude with the body rates (when reported)
    for at most ``max_extrapolation_s``; outside the
    buffer otherwise it returns None (the caller must not guess a pose).
    """

    def __init__(self, *, span_s: float = 2.0, max_extrapolation_s: float = 0.05) -> None:
        if span_s <= 0:
            raise ValueError(f"span_s: must be > 0, got {span_s}")
        self.span_ns = int(span_s * 1e9)
        self.max_extrapolation_ns = int(max_extrapolation_s * 1e9)
        self._states: deque[VehicleState] = deque()
        self._times: deque[int] = deque()
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self._states)

    def append(self, state: VehicleState) -> None:
        with self._lock:
            if self._times and state.timestamp_ns <= self._times[-1]:
                if state.timestamp_ns == self._times[-1]:
                    self._states[-1] = state
                return  # out-of-order sample: keep the history monotonic
            self._states.append(state)
            self._times.append(state.timestamp_ns)
            cutoff = state.timestamp_ns - self.span_ns
            while self._times and self._times[0] < cutoff:
                self._times.popleft()
                self._states.popleft()

    def latest(self) -> VehicleState | None:
        with self._lock:
            return self._states[-1] if self._states else None

    def latest_at_or_before(self, timestamp_ns: int) -> VehicleState | None:
        """The newest sample stamped at or before ``timestamp_ns`` (None: none that old)."""
        with self._lock:
            i = bisect.bisect_right(list(self._times), timestamp_ns)
            return self._states[i - 1] if i > 0 else None

    def state_at(self, timestamp_ns: int) -> VehicleState | None:
        with self._lock:
            if not self._states:
                return None
            times = list(self._times)
            states = list(self._states)
        if timestamp_ns < times[0]:
            return None
        if timestamp_ns >= times[-1]:
            dt_ns = timestamp_ns - times[-1]
            if dt_ns > self.max_extrapolation_ns:
                return None
            last = states[-1]
            dt = dt_ns * 1e-9
            v = last.velocity_ned_mps
            p = last.position_ned_m
            return replace(last, timestamp_ns=timestamp_ns,
                           position_ned_m=(p[0] + v[0] * dt, p[1] + v[1] * dt, p[2] + v[2] * dt),
                           attitude_q=rotate_by_body_rates(last.attitude_q,
                                                           last.angular_velocity_frd_radps, dt))
        i = bisect.bisect_right(times, timestamp_ns)
        return interpolate_states(states[i - 1], states[i], timestamp_ns)
