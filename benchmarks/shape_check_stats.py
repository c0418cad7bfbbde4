"""The shape check's margins over a campaign's stored run logs (``campaign --out DIR`` or
``fault_campaign.py --out DIR``).

Each run's ``heading`` records (one per complete close view, logged with the check on or
off) are split into candidates (``views`` starts again at 1 for each); a candidate is the true
target when the median of the mission's estimates logged during its views lies within
``--near-m`` of the target's true place (the run's ``sim`` block). Prints, for true targets and
for other candidates, the lowest running median silhouette IoU the check saw (what
``tracking.shape.min_iou`` is compared with), the rejections the check made, and the runs whose
GRASP_READY was not over the target::

    python benchmarks/shape_check_stats.py DIR [--near-m 1.0] [--threshold 0.86]
"""
from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
from dataclasses import dataclass, field
from pathlib import Path

SHAPE_REJECTION = "rejected: its outline"


@dataclass
class Candidate:
    run: int
    ious: list[float] = field(default_factory=list)
    medians: list[float] = field(default_factory=list)
    places: list[tuple[float, float]] = field(default_factory=list)
    rejected: bool = False

    def distance_m(self, target: tuple[float, float]) -> float:
        if not self.places:
            return math.inf
        north = statistics.median(p[0] for p in self.places)
        east = statistics.median(p[1] for p in self.places)
        return math.dist((north, east), target)


def read_run(log: Path, result: dict) -> tuple[list[Candidate], tuple[float, float]]:
    sim = result["result"]["sim"]
    target = (sim["target_north_m"], sim["target_east_m"])
    run = int(result["run"])
    candidates: list[Candidate] = []
    place: tuple[float, float] | None = None
    for line in log.read_text().splitlines():
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            continue  # a run killed mid-write: its last line may be cut
        kind = record.get("kind")
        if kind == "estimate" and record.get("ok") and record.get("position_ned_m"):
            place = (record["position_ned_m"][0], record["position_ned_m"][1])
        elif kind == "heading":
            if record["views"] == 1 or not candidates:
                candidates.append(Candidate(run))
            current = candidates[-1]
            if record.get("silhouette_iou") is not None:
                current.ious.append(record["silhouette_iou"])
            if record.get("median_iou") is not None:
                current.medians.append(record["median_iou"])
            if place is not None:
                current.places.append(place)
        elif kind == "event" and SHAPE_REJECTION in str(record.get("text", "")) and candidates:
            candidates[-1].rejected = True
    return candidates, target


def quantiles(values: list[float]) -> str:
    if not values:
        return "-"
    v = sorted(values)
    pick = lambda q: v[min(len(v) - 1, int(q * (len(v) - 1) + 0.5))]  # noqa: E731
    return f"min {v[0]:.3f}  p1 {pick(0.01):.3f}  p5 {pick(0.05):.3f}  median {pick(0.5):.3f}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("--near-m", type=float, default=1.0)
    ap.add_argument("--threshold", type=float, default=0.86,
                    help="tracking.shape.min_iou to count margins against")
    args = ap.parse_args(argv)
    results = sorted(args.folder.glob("run_*.result.json"))
    if not results:
        print(f"{args.folder}: no run_*.result.json", file=sys.stderr)
        return 2
    true_c: list[Candidate] = []
    other_c: list[Candidate] = []
    elsewhere: list[str] = []
    for path in results:
        result = json.loads(path.read_text())
        log = path.with_name(path.name.replace(".result.json", ".jsonl"))
        if not log.exists():
            continue
        candidates, target = read_run(log, result)
        for c in candidates:
            (true_c if c.distance_m(target) <= args.near_m else other_c).append(c)
        r = result["result"]
        error_m = r.get("horizontal_error_m")
        if r.get("reached_grasp_ready") and error_m is not None and error_m > args.near_m:
            elsewhere.append(f"run {result['run']}: GRASP_READY {error_m:.2f} m from the target")
    print(f"{len(results)} runs in {args.folder}")
    for name, group in (("true targets", true_c), ("other candidates", other_c)):
        measured = [c for c in group if c.medians]
        lowest = [min(c.medians) for c in measured]
        below = [c for c in measured if min(c.medians) < args.threshold]
        rejected = [c for c in group if c.rejected]
        print(f"{name}: {len(group)} candidates, {len(measured)} with a running median "
              f"(enough views); lowest running median: {quantiles(lowest)}")
        print(f"  below {args.threshold:g}: {len(below)} "
              f"{sorted({c.run for c in below})[:20]}; rejected by the shape check: "
              f"{len(rejected)} {sorted({c.run for c in rejected})[:20]}")
        views = [v for c in group for v in c.ious]
        print(f"  per-view IoU over {len(views)} views: {quantiles(views)}")
    print(f"GRASP_READY away from the target: {len(elsewhere)}")
    for line in elsewhere:
        print("  " + line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
