"""Full garbage collections during a flight, with and without the flight's frozen heap.

    python benchmarks/bench_gc_pauses.py                  # 800k ballast objects, 3 rounds
    python benchmarks/bench_gc_pauses.py --ballast 0 400000 1600000

A long-lived process (a companion computer's, or the test suite's) holds many tracked objects;
a full collection walks them all and stops every Python thread meanwhile: the setpoint stream,
the telemetry task, the offboard watchdog (0.5 s). ``eaglemission.flight.heap.frozen_heap`` freezes
the heap alive at the flight's start. This script builds about ``--ballast`` objects shaped like a
test process's leftovers (dicts holding lists and tuples), flies the embedded simulated mission
in virtual time, and times one full collection (``gc.collect()``) at FINE_APPROACH: with the
assembly's ``frozen_heap`` and with it replaced by a no-op, alternated per round. It prints the
median pause of each and their ratio (same run, same machine).
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import statistics
import time
from collections.abc import Iterator
from typing import Any


def _ballast(n: int) -> list[Any]:
    return [{"i": i, "l": [i, (i,)], "t": (str(i),)} for i in range(n // 4)]


def _pause_in_flight(frozen: bool) -> float:
    from eaglemission.lab.campaign.sim import run_simulation

    from eaglemission.config import load_config
    from eaglemission.flight import run as assembly
    from eaglemission.flight.heap import frozen_heap

    @contextlib.contextmanager
    def no_freeze() -> Iterator[int]:
        yield 0

    pauses: list[float] = []

    def at_state(t_s: float, new: str, reason: str, action: str) -> None:
        if new == "FINE_APPROACH" and not pauses:
            t0 = time.perf_counter()
            gc.collect()
            pauses.append(time.perf_counter() - t0)

    saved = assembly.frozen_heap
    assembly.frozen_heap = frozen_heap if frozen else no_freeze  # type: ignore[assignment]
    try:
        run_simulation(load_config(), on_state=at_state)
    finally:
        assembly.frozen_heap = saved  # type: ignore[assignment]
    if not pauses:
        raise SystemExit("the mission never reached FINE_APPROACH: nothing measured")
    return pauses[0]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ballast", type=int, nargs="+", default=[800_000],
                    help="objects built before the flight (dicts, lists, tuples; the "
                    "number the collector tracks is printed)")
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    print(f"{'ballast':>9} {'tracked':>9} {'frozen ms':>10} {'unfrozen ms':>12} {'ratio':>7}")
    for n in args.ballast:
        keep = _ballast(n)
        tracked = len(gc.get_objects())
        got: dict[bool, list[float]] = {True: [], False: []}
        for _ in range(args.rounds):
            for frozen in (False, True):
                got[frozen].append(_pause_in_flight(frozen))
        f, u = statistics.median(got[True]) * 1e3, statistics.median(got[False]) * 1e3
        print(f"{n:>9} {tracked:>9} {f:>10.1f} {u:>12.1f} {u / f:>6.1f}x")
        del keep


if __name__ == "__main__":
    main()
