"""Safety envelope on the simulated vehicle: worst TRUE-trajectory excursions over many random
setpoint sequences, and the simulated vehicle's speed (simulated seconds per wall second).

    python benchmarks/bench_envelope.py --n 500 --seed 1

Excursions are signed: negative = the worst sample stayed that far INSIDE the configured
envelope (fence, altitude band) or below the speed limit.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "core"))

from eaglemission.lab.vehicles.simulated.vehicle import SimulatedVehicle  # noqa: E402
from envelope_scenarios import Leg, Scenario, fly  # noqa: E402

from eaglemission.clock import ManualClock  # noqa: E402
from eaglemission.config import GeofenceConfig  # noqa: E402
from eaglemission.types import Setpoint  # noqa: E402

L_SHAPE = [(-10.0, -10.0), (30.0, -10.0), (30.0, 5.0), (5.0, 5.0), (5.0, 30.0), (-10.0, 30.0)]
FIELDS = ("fence_m", "above_max_altitude_m", "below_min_altitude_m",
          "horizontal_speed_excess_mps", "vertical_speed_excess_mps")


def random_scenario(rng: np.random.RandomState, k: int) -> Scenario:
    kind = k % 4
    if kind == 0:
        fence = GeofenceConfig(radius_m=float(rng.uniform(12, 40)))
    elif kind == 1:
        a, b = rng.uniform(10, 30, 2)
        fence = GeofenceConfig(radius_m=None, polygon_ned_m=[(-a, -b), (a, -b), (a, b), (-a, b)])
    elif kind == 2:
        fence = GeofenceConfig(radius_m=None, polygon_ned_m=L_SHAPE)
    else:
        fence = GeofenceConfig(radius_m=float(rng.uniform(15, 30)), polygon_ned_m=L_SHAPE)
    lo = float(rng.uniform(0, 3))
    legs = tuple(Leg(float(rng.uniform(-80, 80)), float(rng.uniform(-80, 80)),
                     float(rng.uniform(-5, 30)), float(rng.uniform(-180, 180)),
                     float(rng.uniform(0.2, 4.0)), float(rng.choice([5.0, 10.0, 20.0, 50.0])))
                 for _ in range(rng.randint(1, 7)))
    return Scenario(fence, lo, lo + float(rng.uniform(4, 15)), float(rng.uniform(1, 5)),
                    float(rng.uniform(0.5, 2)), (float(rng.uniform(-3, 3)), float(rng.uniform(-3, 3))),
                    float(rng.uniform(0, 0.5)), int(rng.randint(0, 2**16)), legs)


def sim_speed(seconds: float = 60.0) -> float:
    async def run() -> float:
        clock = ManualClock()
        v = SimulatedVehicle(SimulatedVehicle.Config(initial_altitude_m=5.0), clock=clock)
        await v.connect()
        s = v.state()
        await v.start_offboard(Setpoint(*s.position_ned_m, 0.0))
        t0 = time.perf_counter()
        n = int(seconds / 0.05)
        for i in range(n):
            await v.set_setpoint(Setpoint(10.0 * np.sin(i * 0.01), 0.0, -5.0, 0.0))
            await clock.sleep(0.05)
        return seconds / (time.perf_counter() - t0)

    return asyncio.run(run())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=300, help="random scenarios")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    logging.disable(logging.WARNING)
    rng = np.random.RandomState(args.seed)
    worst = {f: -np.inf for f in FIELDS}
    sent_outside = 0
    t0 = time.perf_counter()
    for k in range(args.n):
        ex, _, _ = asyncio.run(fly(random_scenario(rng, k)))
        for f in FIELDS:
            worst[f] = max(worst[f], getattr(ex, f))
        sent_outside += ex.sent_outside
    wall = time.perf_counter() - t0
    print(f"scenarios: {args.n} (seed {args.seed}), {wall / args.n * 1e3:.1f} ms each")
    for f in FIELDS:
        print(f"  worst {f:30s} {worst[f]:+.3f}")
    print(f"  setpoints sent outside the envelope: {sent_outside}")
    print(f"simulated vehicle, offboard at 20 Hz: {sim_speed():.0f} x real time (ManualClock)")


if __name__ == "__main__":
    main()
