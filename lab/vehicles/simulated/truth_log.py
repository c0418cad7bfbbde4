"""The simulated vehicle's truth log: the TRUE state at every internal step of the model (what
the synthetic cameras render from and what the evaluator judges), compact and bounded."""

from __future__ import annotations

import bisect
import math
from array import array
from collections.abc import Callable

import numpy as np
from eaglemission.lab.vehicles.multicopter.dynamics import (
    MulticopterDynamics,
    attitude_from_acceleration,
    wrap_deg,
)
from numpy.typing import NDArray

from eaglemission.geometry import quat_to_R, rotation_vector
from eaglemission.types import XYZ, FlightMode, Quat, VehicleState

MODES: tuple[FlightMode, ...] = tuple(FlightMode)
_MODE_INDEX = {m: i for i, m in enumerate(MODES)}

TruthStateFactory = Callable[..., VehicleState]
"""``(t_ns, position, velocity, *, attitude_q, armed, in_air, mode) -> VehicleState``."""


def body_attitude(an: float, ae: float, ad: float, yaw_deg: float, *, on_ground: bool) -> Quat:
    """The body attitude of a thrust acceleration; level on the ground with the motors off."""
    if on_ground and ad > 9.0:  # motors off on the ground: level
        return attitude_from_acceleration((0.0, 0.0, 0.0), yaw_deg)
    return attitude_from_acceleration((an, ae, ad), yaw_deg)


class TruthLog:
    """Columns t_ns, NED position, velocity, thrust acceleration, yaw, flags and mode, one row
    per internal step; older rows are dropped (half of them at a time) beyond ``max_rows``."""

    def __init__(self, max_rows: int) -> None:
        self.max_rows = max_rows
        self._t = array("q")
        self._cols = [array("d") for _ in range(10)]  # pn pe pd vn ve vd an ae ad yaw
        self._flags = array("B")  # bit 0 armed, bit 1 in air
        self._mode = array("B")  # index into MODES

    def append(self, dyn: MulticopterDynamics, *, armed: bool, in_air: bool, mode: FlightMode) -> None:
        self._t.append(dyn.time_ns)
        c = self._cols
        c[0].append(dyn.pn)
        c[1].append(dyn.pe)
        c[2].append(dyn.pd)
        c[3].append(dyn.vn)
        c[4].append(dyn.ve)
        c[5].append(dyn.vd)
        c[6].append(dyn.an)
        c[7].append(dyn.ae)
        c[8].append(dyn.ad)
        c[9].append(dyn.yaw_deg)
        self._flags.append(int(armed) | (int(in_air) << 1))
        self._mode.append(_MODE_INDEX[mode])
        if len(self._t) > self.max_rows:
            drop = len(self._t) - self.max_rows // 2
            del self._t[:drop]
            del self._flags[:drop]
            del self._mode[:drop]
            for col in c:
                del col[:drop]

    def pose_at(self, timestamp_ns: int, step_ns: int) -> tuple[XYZ, Quat] | None:
        """Position and attitude interpolated at a time; None before the first row or more
        than a step after the last."""
        times = self._t
        if not times or timestamp_ns < times[0] or timestamp_ns > times[-1] + step_ns:
            return None
        i = bisect.bisect_right(times, timestamp_ns)
        if i >= len(times):
            i = len(times) - 1
            j = i
            s = 0.0
        else:
            j = i
            i = j - 1
            span = times[j] - times[i]
            s = (timestamp_ns - times[i]) / span if span > 0 else 0.0
        c = self._cols
        vals = [c[k][i] + s * (c[k][j] - c[k][i]) for k in range(9)]
        yaw = c[9][i] + s * wrap_deg(c[9][j] - c[9][i])
        pos = (vals[0], vals[1], vals[2])
        return pos, body_attitude(vals[6], vals[7], vals[8], yaw, on_ground=pos[2] >= 0.0)

    def motion_at(self, timestamp_ns: int, step_ns: int) -> tuple[XYZ, XYZ] | None:
        """Velocity (NED, m/s) and angular velocity (NED, rad/s: ``R(t + dt) = exp([w]x dt)
        R(t)``) at a time, where :meth:`pose_at` answers: the velocity interpolated between
        the two rows around it (the last row's beyond it), the angular velocity of the
        attitude change between those two rows (the last two beyond the last row)."""
        times = self._t
        if not times or timestamp_ns < times[0] or timestamp_ns > times[-1] + step_ns:
            return None
        c = self._cols
        if len(times) < 2:
            return (c[3][0], c[4][0], c[5][0]), (0.0, 0.0, 0.0)
        j = min(max(bisect.bisect_right(times, timestamp_ns), 1), len(times) - 1)
        i = j - 1
        span = times[j] - times[i]
        s = min(1.0, max(0.0, (timestamp_ns - times[i]) / span)) if span > 0 else 0.0
        vel = tuple(c[k][i] + s * (c[k][j] - c[k][i]) for k in (3, 4, 5))
        Ri, Rj = (quat_to_R(body_attitude(c[6][k], c[7][k], c[8][k], c[9][k],
                                          on_ground=c[2][k] >= 0.0)) for k in (i, j))
        w = rotation_vector(Rj @ Ri.T) / max(span * 1e-9, 1e-9)
        return (vel[0], vel[1], vel[2]), (float(w[0]), float(w[1]), float(w[2]))

    def states(self, make: TruthStateFactory, *, since_ns: int | None = None,
               every_s: float | None = None) -> list[VehicleState]:
        """Rows as states built by ``make``, oldest first, optionally every ``every_s``."""
        times = list(self._t)
        cols = [list(c) for c in self._cols]
        flags = list(self._flags)
        modes = list(self._mode)
        out: list[VehicleState] = []
        last = -math.inf
        for k, t in enumerate(times):
            if since_ns is not None and t < since_ns:
                continue
            if every_s is not None and (t - last) < every_s * 1e9 - 1:
                continue
            last = t
            pn, pe, pd, vn, ve, vd, an, ae, ad, yaw = (c[k] for c in cols)
            q = body_attitude(an, ae, ad, yaw, on_ground=pd >= 0.0)
            out.append(make(t, (pn, pe, pd), (vn, ve, vd), attitude_q=q, armed=bool(flags[k] & 1),
                            in_air=bool(flags[k] & 2), mode=MODES[modes[k]]))
        return out

    def array(self, *, since_ns: int | None = None) -> NDArray[np.float64]:
        """(N, 11): t_ns, north, east, down, vn, ve, vd, an, ae, ad, yaw_deg."""
        t = np.frombuffer(self._t, dtype=np.int64).astype(np.float64)
        cols = [np.frombuffer(c, dtype=np.float64) for c in self._cols]
        arr = np.column_stack([t, *cols]) if len(t) else np.zeros((0, 11))
        if since_ns is not None:
            arr = arr[arr[:, 0] >= since_ns]
        return arr.copy()
