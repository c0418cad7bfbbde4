"""The same campaign on the local pool and on the Ray executor: wall time of each and whether
their summaries are equal apart from wall-time fields (``speedup``, ``latency_p90_ms``).

Usage (the full figure is ``--runs 200``, about 50 CPU-minutes per executor)::

    python benchmarks/bench_campaign_executors.py configs/sitl_synthetic.yaml --runs 20 --seed 7 \\
        --workers 2 [--address ADDR] [--out DIR]

``--out DIR`` keeps both campaigns' folders (``DIR/local``, ``DIR/ray``); an interrupted benchmark
resumes each from there (a resumed campaign's time covers only the runs it flew).
Exit 0 when the summaries are equal, 1 when not (the differing runs are printed).
"""

from __future__ import annotations

import argparse
import json
import logging
import tempfile
import time
from pathlib import Path
from typing import Any

from eaglemission.lab.campaign.campaign import run_campaign
from eaglemission.lab.campaign.executors import flight_fields


def _normal(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    out: list[dict[str, Any]] = json.loads(json.dumps(flight_fields(runs), default=str))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("config")
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--address", help="Ray cluster for the ray executor (default: local Ray)")
    ap.add_argument("--out", help="keep the campaigns' folders here (default: a temp folder)")
    a = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    root = Path(a.out) if a.out else Path(tempfile.mkdtemp(prefix="bench-executors-"))
    summaries, walls = {}, {}
    for name in ("local", "ray"):
        t0 = time.perf_counter()
        summaries[name] = run_campaign(a.config, runs=a.runs, seed=a.seed, workers=a.workers,
                                       executor=name, out_dir=str(root / name), progress=True,
                                       address=a.address if name == "ray" else None)
        walls[name] = time.perf_counter() - t0
    loc, ray = summaries["local"], summaries["ray"]
    print(f"config {a.config}  runs {a.runs}  seed {a.seed}  workers {a.workers}  "
          f"ray address {a.address or 'local'}  folders {root}")
    for name, s in summaries.items():
        print(f"  {name:5s}: wall {walls[name]:7.1f} s  success {s.success_rate:.0%}  "
              f"violations {s.violations}")
    diff = [(x["run"], x, y) for x, y in zip(_normal(loc.runs), _normal(ray.runs)) if x != y]
    equal = not diff and loc.n == ray.n
    print(f"summaries equal apart from wall-time fields: {equal} "
          f"({loc.n - len(diff)}/{loc.n} runs identical)")
    for run, x, y in diff:
        keys = sorted(k for k in x if x.get(k) != y.get(k))
        print(f"  run {run} differs in {keys}")
    return 0 if equal else 1


if __name__ == "__main__":
    raise SystemExit(main())
