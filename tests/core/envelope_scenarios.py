"""Random setpoint sequences flown through SafeVehicle(SimulatedVehicle) on a ManualClock, and
the measurement of how far the TRUE trajectory gets outside the envelope (shared by the
property test and benchmarks/bench_envelope.py)."""

from __future__ import annotations

import asyncio
import math
from dataclasses import dataclass, field

import numpy as np
from eaglemission.lab.vehicles.multicopter.dynamics import DynamicsParams
from eaglemission.lab.vehicles.simulated.vehicle import SimulatedVehicle
from eaglemission.lab.world.synthetic import SyntheticWorldConfig

from eaglemission.clock import ManualClock
from eaglemission.config import GeofenceConfig, SafetyConfig
from eaglemission.safety.envelope import SafeVehicle
from eaglemission.types import Setpoint


@dataclass(frozen=True)
class Leg:
    north_m: float
    east_m: float
    altitude_m: float
    yaw_deg: float
    duration_s: float
    rate_hz: float


@dataclass(frozen=True)
class Scenario:
    fence: GeofenceConfig
    min_altitude_m: float
    max_altitude_m: float
    max_horizontal_speed_mps: float
    max_vertical_speed_mps: float
    wind_ne_mps: tuple[float, float]
    gust_std_mps: float
    seed: int
    legs: tuple[Leg, ...]
    settle_s: float = 2.0  # setpoints stop at the end: the failsafe hold must stay inside too

    def safety(self) -> SafetyConfig:
        return SafetyConfig(geofence=self.fence, min_altitude_m=self.min_altitude_m,
                            max_altitude_m=self.max_altitude_m,
                            max_horizontal_speed_mps=self.max_horizontal_speed_mps,
                            max_vertical_speed_mps=self.max_vertical_speed_mps,
                            on_violation="clamp")


@dataclass
class Excursion:
    """Worst excursions of the TRUE trajectory beyond the configured envelope (>0 = outside)."""

    fence_m: float = -math.inf
    above_max_altitude_m: float = -math.inf
    below_min_altitude_m: float = -math.inf
    horizontal_speed_excess_mps: float = -math.inf
    vertical_speed_excess_mps: float = -math.inf
    samples: int = 0
    sent_outside: int = 0  # setpoints sent to the vehicle outside the (shrunk) envelope
    notes: list[str] = field(default_factory=list)


def fence_excess_m(fence: GeofenceConfig, n: np.ndarray, e: np.ndarray) -> np.ndarray:
    """Per sample, the signed distance outside the fence (negative inside), exact for the
    circle and for the polygon (distance to the nearest edge), vectorised."""
    out = np.full(n.shape, -np.inf)
    if fence.radius_m is not None:
        out = np.maximum(out, np.hypot(n, e) - fence.radius_m)
    if fence.polygon_ned_m is not None:
        poly = np.asarray(fence.polygon_ned_m, dtype=np.float64)
        a = poly
        b = np.roll(poly, -1, axis=0)
        d = b - a  # (m, 2)
        px = np.stack([n, e], axis=1)[:, None, :] - a[None, :, :]  # (k, m, 2)
        L2 = np.maximum((d * d).sum(axis=1), 1e-12)
        s = np.clip((px * d[None]).sum(axis=2) / L2[None], 0.0, 1.0)
        dist = np.linalg.norm(px - s[..., None] * d[None], axis=2).min(axis=1)
        # even-odd rule, vectorised like safety_geometry.point_in_polygon
        e1, e2 = a[:, 1][None], b[:, 1][None]
        n1, n2 = a[:, 0][None], b[:, 0][None]
        crosses = (e1 > e[:, None]) != (e2 > e[:, None])
        with np.errstate(divide="ignore", invalid="ignore"):
            n_cross = n1 + (e[:, None] - e1) * (n2 - n1) / (e2 - e1)
        inside = ((crosses & (n[:, None] < n_cross)).sum(axis=1) % 2) == 1
        out = np.maximum(out, np.where(inside, -dist, dist))
    return out


async def fly(sc: Scenario) -> tuple[Excursion, SimulatedVehicle, SafeVehicle]:
    clock = ManualClock()
    sim = SimulatedVehicle(
        SimulatedVehicle.Config(  # starts hovering mid-band: the takeoff is not tested here
            dynamics=DynamicsParams(wind_gust_std_mps=sc.gust_std_mps),
            telemetry_rate_hz=25.0,
            initial_altitude_m=0.5 * (sc.min_altitude_m + sc.max_altitude_m)),
        clock=clock, simulation=SyntheticWorldConfig(seed=sc.seed, wind_ne_mps=sc.wind_ne_mps))
    safe = SafeVehicle(sim, sc.safety(), clock=clock)
    await safe.connect()
    await clock.sleep(0.3)  # the wind starts pushing the hovering vehicle
    t_offboard = clock.now_ns()
    s = safe.state()
    await safe.start_offboard(Setpoint(*s.position_ned_m, s.yaw_deg))
    env = safe.envelope
    ex = Excursion()
    for leg in sc.legs:
        sp = Setpoint(leg.north_m, leg.east_m, -leg.altitude_m, leg.yaw_deg)
        period = 1.0 / leg.rate_hz
        t_end = clock.now_ns() + int(leg.duration_s * 1e9)
        while clock.now_ns() < t_end:
            await safe.set_setpoint(sp)
            sent = safe.last_sent
            assert sent is not None
            if not (env.safe_h(sent.north_m, sent.east_m) or env.inside_fence(sent.north_m, sent.east_m)):
                ex.sent_outside += 1
            await clock.sleep(period)
    await clock.sleep(sc.settle_s)
    safe.state()
    tr = sim.trajectory_array()
    air = tr[tr[:, 0] >= t_offboard]
    ex.samples = len(air)
    ex.fence_m = float(fence_excess_m(sc.fence, tr[:, 1], tr[:, 2]).max())
    alt = -air[:, 3]
    ex.above_max_altitude_m = float((-tr[:, 3]).max() - sc.max_altitude_m)
    ex.below_min_altitude_m = float(sc.min_altitude_m - alt.min())
    ex.horizontal_speed_excess_mps = float(np.hypot(air[:, 4], air[:, 5]).max() - sc.max_horizontal_speed_mps)
    ex.vertical_speed_excess_mps = float(np.abs(air[:, 6]).max() - sc.max_vertical_speed_mps)
    return ex, sim, safe


def run(sc: Scenario) -> Excursion:
    return asyncio.run(fly(sc))[0]
