"""Ground truth from HIL_STATE_QUATERNION (MAVLink message 115).

PX4 SITL with SIH fills HIL_STATE_QUATERNION from its ``*_groundtruth`` topics once a client
asks for the stream (MAV_CMD_SET_MESSAGE_INTERVAL); the bundled emulator does the same.
Recorded facts (``../shared/data/px4_sitl_tlogs/README.md``, "Ground truth"): ``time_usec`` is
always 0 (samples are stamped on receipt), ``lat``/``lon`` degE7 and ``alt`` mm AMSL are the
true position, ``vx``/``vy``/``vz`` cm/s the true NED velocity, ``attitude_quaternion`` the true
attitude (w may be negative). A real aircraft sends none.

With jMAVSim, PX4 passes on what jMAVSim sends: ``alt`` is 1000 x its NED z (0 on the ground,
-3000 at 3 m up), not AMSL, so the driver's ``ground_truth_altitude: ned_z`` reads it as minus
the height; its ``lat``/``lon`` are jMAVSim's simulated GPS position (the true one plus a
random walk of about 1 cm per axis, correlated over about 0.1 s), so the driver's
``ground_truth_horizontal: velocity`` integrates the true velocity instead, held to
``lat``/``lon`` over :data:`ANCHOR_S` (:class:`AnchoredHorizontal`); velocity and attitude are
true.

:class:`HilTruth` turns the samples into NED metres relative to the first sample (the true
start point, where the synthetic world's origin is: the vehicle is on the ground when the
mission connects) and implements :class:`~eaglemission.interfaces.truth.GroundTruth`.
"""

from __future__ import annotations

import bisect
import json
import math
import threading
from array import array
from collections.abc import Callable
from typing import Any

from eaglemission.geometry import geodetic_to_ned
from eaglemission.types import XYZ, FlightMode, GeoPoint, Quat, VehicleState

MSG_ID = 115
MAX_EXTRAPOLATION_NS = 100_000_000
ALTITUDES = ("amsl", "ned_z")
"""What ``alt`` holds: the altitude above mean sea level, or the simulator's NED z (down)."""
HORIZONTALS = ("latlon", "velocity")
"""Where the horizontal position comes from: ``lat``/``lon``, or the velocity integrated and held
to ``lat``/``lon`` (:class:`AnchoredHorizontal`)."""
ANCHOR_S = 1.0
"""Time constant holding the integrated velocity to ``lat``/``lon``: jMAVSim's GPS noise (about
1 cm, correlated over about 0.1 s) passes at about a third, a velocity bias of b m/s becomes a
position bias of b x 1 s."""
VELOCITY_STEP_MPS = 0.01
"""The message's velocity unit (cm/s). PX4 casts its float velocity to it, truncating toward
zero, and so does jMAVSim before it: a reading of k steps (k != 0) stands for k + 1/2 steps on
average."""
MAX_INTEGRATION_GAP_S = 0.5
"""A longer gap between samples restarts the integration at ``lat``/``lon``."""
CHECK_TRAVEL_M = 1.0
"""Vertical travel (integrated from the messages' own vertical velocity) after which the
altitude's sense is judged: a take-off climbs further than this."""
MAX_CHECK_GAP_S = 0.5


def parse_hil_state(fields: dict[str, Any], altitude: str = "amsl"
                    ) -> tuple[GeoPoint, XYZ, Quat]:
    """(true position, NED velocity m/s, attitude (w, x, y, z) with w >= 0) of one message's
    fields; raises ValueError on a missing or non-finite field. With ``altitude="ned_z"`` the
    position's altitude is minus ``alt`` (the height above the simulator's origin)."""
    sense = -1.0 if altitude == "ned_z" else 1.0
    try:
        q = [float(v) for v in fields["attitude_quaternion"]]
        geo = GeoPoint(float(fields["lat"]) * 1e-7, float(fields["lon"]) * 1e-7,
                       sense * float(fields["alt"]) * 1e-3)
        vel = (float(fields["vx"]) * 0.01, float(fields["vy"]) * 0.01, float(fields["vz"]) * 0.01)
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"HIL_STATE_QUATERNION: malformed fields ({exc})") from exc
    if len(q) != 4 or not all(math.isfinite(v) for v in (*q, *vel, geo.latitude_deg,
                                                           geo.longitude_deg,
                                                           geo.altitude_amsl_m)):
        raise ValueError("HIL_STATE_QUATERNION: non-finite or incomplete fields")
    n = math.sqrt(sum(v * v for v in q))
    if n < 1e-6:
        raise ValueError("HIL_STATE_QUATERNION: zero attitude quaternion")
    sign = -1.0 if q[0] < 0 else 1.0
    return geo, vel, (sign * q[0] / n, sign * q[1] / n, sign * q[2] / n, sign * q[3] / n)


def untruncated_mps(reading_mps: float) -> float:
    """The mean velocity behind a reading truncated toward zero to whole
    :data:`VELOCITY_STEP_MPS` (a zero reading stands for anything in (-1, 1) steps: 0)."""
    if abs(reading_mps) < 0.5 * VELOCITY_STEP_MPS:
        return 0.0
    return reading_mps + math.copysign(0.5 * VELOCITY_STEP_MPS, reading_mps)


class AnchoredHorizontal:
    """The horizontal position from the true velocity, held to a noisy position: a
    complementary filter, ``x = x_pred + dt / (anchor_s + dt) * (measured - x_pred)`` with
    ``x_pred`` the last position plus the mean of the two velocities times dt. Velocity
    readings are taken as truncated (:func:`untruncated_mps`)."""

    def __init__(self, anchor_s: float = ANCHOR_S) -> None:
        if not anchor_s > 0:
            raise ValueError(f"anchor_s: must be > 0, got {anchor_s}")
        self.anchor_s = anchor_s
        self._last: tuple[float, float, float, float, float] | None = None  # t n e vn ve

    def update(self, t_s: float, north_m: float, east_m: float, vn_mps: float,
               ve_mps: float) -> tuple[float, float]:
        """One sample (time, measured position, velocity reading); returns the position."""
        vn, ve = untruncated_mps(vn_mps), untruncated_mps(ve_mps)
        last = self._last
        dt = -1.0 if last is None else t_s - last[0]
        if last is None or not 0.0 < dt <= MAX_INTEGRATION_GAP_S:
            n, e = north_m, east_m
        else:
            pn = last[1] + 0.5 * (vn + last[3]) * dt
            pe = last[2] + 0.5 * (ve + last[4]) * dt
            k = dt / (self.anchor_s + dt)
            n, e = pn + k * (north_m - pn), pe + k * (east_m - pe)
        self._last = (t_s, n, e, vn, ve)
        return n, e


class AltitudeSense:
    """Does the altitude read from the messages move with their own vertical velocity?

    Over consecutive samples, the height change is compared with the climb the velocity gives
    (``-vz * dt``); once :data:`CHECK_TRAVEL_M` of vertical travel has accumulated, the sign of
    their sum of products is the verdict (True: they agree). A wrong ``ground_truth_altitude``
    makes them disagree on every step of a take-off.
    """

    def __init__(self, travel_m: float = CHECK_TRAVEL_M) -> None:
        self.travel_m = travel_m
        self.travelled_m = 0.0
        self._dot = 0.0
        self._last: tuple[float, float, float] | None = None
        self.verdict: bool | None = None

    def add(self, t_s: float, height_m: float, climb_mps: float) -> bool | None:
        """One sample; returns the verdict on the sample that decides it, else None."""
        last, self._last = self._last, (t_s, height_m, climb_mps)
        if self.verdict is not None or last is None:
            return None
        dt = t_s - last[0]
        if not 0.0 < dt <= MAX_CHECK_GAP_S:
            return None
        climb_m = 0.5 * (climb_mps + last[2]) * dt
        self._dot += (height_m - last[1]) * climb_m
        self.travelled_m += abs(climb_m)
        if self.travelled_m < self.travel_m:
            return None
        self.verdict = self._dot > 0.0
        return self.verdict


class HilTruth:
    """Thread-safe record of true states from HIL_STATE_QUATERNION samples.

    ``flags()`` gives (armed, in_air, mode) from the autopilot's telemetry at the time of a
    sample (the truth message has none; the evaluator needs them). ``altitude`` says what the
    messages' ``alt`` holds (:data:`ALTITUDES`), ``horizontal`` where the horizontal position
    comes from (:data:`HORIZONTALS`); ``on_problem`` is told, once, when the altitude moves
    against the messages' vertical velocity (:class:`AltitudeSense`).
    """

    description = "HIL_STATE_QUATERNION from the autopilot (simulator ground truth)"

    def __init__(self, flags: Callable[[], tuple[bool, bool, FlightMode]] | None = None,
                 max_s: float = 7200.0, rate_hz: float = 50.0, *, altitude: str = "amsl",
                 horizontal: str = "latlon",
                 on_problem: Callable[[str], None] | None = None) -> None:
        if altitude not in ALTITUDES:
            raise ValueError(f"altitude {altitude!r}: use one of {', '.join(ALTITUDES)}")
        if horizontal not in HORIZONTALS:
            raise ValueError(f"horizontal {horizontal!r}: use one of {', '.join(HORIZONTALS)}")
        self.altitude = altitude
        readings = (["alt read as NED z"] if altitude == "ned_z" else []) + (
            ["horizontal from its velocity"] if horizontal == "velocity" else [])
        if readings:
            self.description = ("HIL_STATE_QUATERNION from the autopilot (simulator ground "
                                f"truth; {', '.join(readings)})")
        self._horizontal = AnchoredHorizontal() if horizontal == "velocity" else None
        self._on_problem = on_problem
        self.sense = AltitudeSense()
        self.problem: str | None = None
        self._flags = flags or (lambda: (False, False, FlightMode.UNKNOWN))
        self._lock = threading.Lock()
        self.origin: GeoPoint | None = None
        self._t = array("q")
        self._c = [array("d") for _ in range(10)]  # n e d vn ve vd qw qx qy qz
        self._f = array("B")  # bit 0 armed, bit 1 in air
        self._modes: list[FlightMode] = []
        self._max = int(max_s * rate_hz * 1.5)
        self.errors = 0

    def on_message(self, stamp_ns: int, fields_json: str) -> None:
        """A received message (MAVSDK's thread), stamped on receipt."""
        try:
            geo, vel, q = parse_hil_state(json.loads(fields_json), self.altitude)
        except (ValueError, RecursionError):  # JSONDecodeError is a ValueError
            self.errors += 1
            return
        self.add(stamp_ns, geo, vel, q)

    def add(self, stamp_ns: int, geo: GeoPoint, vel: XYZ, q: Quat) -> None:
        """A parsed sample (altitude already read as ``self.altitude`` says)."""
        armed, in_air, mode = self._flags()
        with self._lock:
            if self._t and stamp_ns <= self._t[-1]:
                return
            verdict = self.sense.add(stamp_ns * 1e-9, geo.altitude_amsl_m, -vel[2])
            if self.origin is None:
                self.origin = geo
            n, e, d = geodetic_to_ned(self.origin, geo)
            if self._horizontal is not None:
                n, e = self._horizontal.update(stamp_ns * 1e-9, n, e, vel[0], vel[1])
            self._t.append(int(stamp_ns))
            for col, v in zip(self._c, (n, e, d, *vel, *q)):
                col.append(float(v))
            self._f.append((1 if armed else 0) | (2 if in_air else 0))
            self._modes.append(mode)
            if len(self._t) > self._max:  # keep the newest (a flight is far shorter)
                k = len(self._t) - self._max
                del self._t[:k]
                for col in self._c:
                    del col[:k]
                del self._f[:k]
                del self._modes[:k]
        if verdict is False:
            self._report_wrong_altitude()

    def _report_wrong_altitude(self) -> None:
        other = "ned_z" if self.altitude == "amsl" else "amsl"
        self.problem = (
            f"ground truth: HIL_STATE_QUATERNION's altitude, read as {self.altitude}, moved "
            f"against the message's own vertical velocity over {self.sense.travelled_m:.1f} m "
            f"of climb or descent: the true heights are wrong; set the mavsdk vehicle's "
            f"`ground_truth_altitude: {other}` (jMAVSim sends its NED z: ned_z)")
        if self._on_problem is not None:
            self._on_problem(self.problem)

    # -- GroundTruth -----------------------------------------------------------------------
    def available(self) -> bool:
        with self._lock:
            return len(self._t) > 0

    def pose_at(self, timestamp_ns: int) -> tuple[XYZ, Quat] | None:
        with self._lock:
            t = self._t
            if not t or timestamp_ns < t[0]:
                return None
            if timestamp_ns >= t[-1]:
                dt_ns = timestamp_ns - t[-1]
                if dt_ns > MAX_EXTRAPOLATION_NS:
                    return None
                c = self._c
                dt = dt_ns * 1e-9
                pos = (c[0][-1] + c[3][-1] * dt, c[1][-1] + c[4][-1] * dt, c[2][-1] + c[5][-1] * dt)
                return pos, (c[6][-1], c[7][-1], c[8][-1], c[9][-1])
            j = bisect.bisect_right(t, timestamp_ns)
            i = j - 1
            span = t[j] - t[i]
            s = (timestamp_ns - t[i]) / span if span > 0 else 0.0
            c = self._c
            pos = (c[0][i] + s * (c[0][j] - c[0][i]), c[1][i] + s * (c[1][j] - c[1][i]),
                   c[2][i] + s * (c[2][j] - c[2][i]))
            qa = [c[k][i] for k in range(6, 10)]
            qb = [c[k][j] for k in range(6, 10)]
        if sum(a * b for a, b in zip(qa, qb)) < 0:
            qb = [-v for v in qb]
        q = [a + s * (b - a) for a, b in zip(qa, qb)]
        n = math.sqrt(sum(v * v for v in q)) or 1.0
        return pos, (q[0] / n, q[1] / n, q[2] / n, q[3] / n)

    def trajectory(self) -> list[VehicleState]:
        with self._lock:
            t = list(self._t)
            cols = [list(c) for c in self._c]
            flags = list(self._f)
            modes = list(self._modes)
        out = []
        for k, ts in enumerate(t):
            n, e, d, vn, ve, vd, qw, qx, qy, qz = (c[k] for c in cols)
            out.append(VehicleState(ts, (n, e, d), (vn, ve, vd), (qw, qx, qy, qz),
                                    armed=bool(flags[k] & 1), in_air=bool(flags[k] & 2),
                                    flight_mode=modes[k]))
        return out
