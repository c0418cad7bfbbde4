"""Soak: back-to-back simulated missions for a wall time, with the process's resources after
each: RSS, open file descriptors, threads, and the peak of asyncio tasks during the flight.

    python benchmarks/soak.py --minutes 60                      # an hour
    python benchmarks/soak.py --minutes 10 --config configs/sitl_synthetic.yaml

Each mission flies through the library API (``fly_sync``, as ``eaglemission run`` does) in
virtual time, with a JSONL log written and deleted each time. At the end: growth of each
figure from the end of the warm-up (the first ``--warmup`` missions, default 2, and at least
``--warmup-min`` minutes, default 5: RSS climbs while caches fill, 741 -> 942 MB over the
first 20 missions of the embedded mission, then settles) to the end, as the change of the median
over the first and the last tenth of the missions after the warm-up (glibc's allocator moves
RSS between a few levels 30 MB apart from one mission to the next, so one sample is noise), and
the largest value after the warm-up; PASS when every median stays under ``--limit`` (default
5 %). RSS is psutil's when installed, else ``VmRSS`` of /proc/self/status. Exit status 1 on FAIL.
"""

from __future__ import annotations

import argparse
import asyncio
import gc
import logging
import os
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from eaglemission.config import load_config
from eaglemission.flight.run import FlightOptions, fly_sync
from eaglemission.interfaces import MissionHooks

FIGURES = ("rss_mb", "fds", "threads", "tasks_peak")


def rss_mb() -> float:
    try:
        import psutil  # type: ignore[import-untyped]

        return float(psutil.Process().memory_info().rss) / 2**20
    except ImportError:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    return float("nan")


def open_fds() -> int:
    return len(os.listdir("/proc/self/fd"))


def fly_one(cfg: Any, log_path: Path) -> tuple[int, float, int]:
    """One mission; (exit code, simulated seconds, peak asyncio tasks during the flight)."""
    peak = [0]

    async def watch_tasks(_mission: Any) -> None:
        while True:
            peak[0] = max(peak[0], len(asyncio.all_tasks()))
            await asyncio.sleep(0.5)

    hooks = MissionHooks(log_path=log_path, side_tasks=(watch_tasks,))
    res = fly_sync(cfg, FlightOptions(hooks=hooks))
    log_path.unlink(missing_ok=True)
    return res.exit_code, res.sim_s, peak[0]


def growth_pct(first: float, last: float) -> float:
    return 0.0 if first == last else 100.0 * (last - first) / max(abs(first), 1e-9)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--minutes", type=float, default=10.0, help="wall time to fly for")
    ap.add_argument("--config", default=None, help="mission file (default: the embedded one)")
    ap.add_argument("--warmup", type=int, default=2, help="missions before the baseline")
    ap.add_argument("--warmup-min", type=float, default=5.0,
                    help="... and minutes before it (RSS settles as caches fill: measured "
                         "741 -> 942 MB over the first 20 missions, flat after)")
    ap.add_argument("--limit", type=float, default=5.0, help="allowed growth in %%")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    cfg = load_config(args.config)
    end = time.monotonic() + 60.0 * args.minutes
    rows: list[dict[str, float]] = []
    print(f"soak: {args.config or '<embedded sitl_synthetic.yaml>'} for {args.minutes:g} min")
    print(f"{'#':>4} {'t_min':>6} {'exit':>4} {'sim_s':>6} {'wall_s':>6} "
          f"{'rss_mb':>8} {'fds':>4} {'threads':>7} {'tasks_peak':>10}")
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory() as tmp:
        while time.monotonic() < end or len(rows) <= args.warmup + 6:
            w0 = time.monotonic()
            code, sim_s, tasks = fly_one(cfg, Path(tmp) / "soak.jsonl")
            gc.collect()
            row = {"t_min": (time.monotonic() - t0) / 60, "exit": code, "sim_s": sim_s, "wall_s": time.monotonic() - w0,
                   "rss_mb": rss_mb(), "fds": open_fds(), "threads": threading.active_count(),
                   "tasks_peak": tasks}
            rows.append(row)
            print(f"{len(rows):4d} {(time.monotonic() - t0) / 60:6.2f} {code:4d} "
                  f"{sim_s:6.1f} {row['wall_s']:6.1f} {row['rss_mb']:8.1f} {row['fds']:4d} "
                  f"{row['threads']:7d} {tasks:10d}", flush=True)
    warm = max(args.warmup, sum(r["t_min"] < args.warmup_min for r in rows))
    warm = min(warm, len(rows) - 6)  # a short run: keep two windows of at least 3 missions
    after = rows[warm:]
    n = max(3, len(after) // 10)
    first, last = after[:n], after[-n:]
    ok = True
    print(f"\n{len(rows)} missions in {(time.monotonic() - t0) / 60:.1f} min; exit codes "
          f"{sorted({int(r['exit']) for r in rows})}; warm-up: {warm} missions "
          f"({rows[warm - 1]['t_min'] if warm else 0.0:.1f} min); growth of the median of "
          f"missions {warm + 1}-{warm + n} to that of the last {n} (the allocator moves RSS "
          f"between a few levels from one mission to the next: one sample is noise):")
    for f in FIGURES:
        a, b = statistics.median(r[f] for r in first), statistics.median(r[f] for r in last)
        g = growth_pct(a, b)
        peak = max(r[f] for r in after)
        ok &= g < args.limit
        print(f"  {f:10s} {a:9.1f} -> {b:9.1f}  ({g:+.1f} %; max after warm-up "
              f"{peak:.1f}: {growth_pct(a, peak):+.1f} %)")
    print(f"{'PASS' if ok else 'FAIL'}: every figure grew less than {args.limit:g} %"
          if ok else f"FAIL: a figure grew {args.limit:g} % or more")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
