"""Where the grasp point was from the arm's tool home while a flight sat in FINE_DESCENT.

For each accepted target estimate of a flight's JSON-lines log (``eaglemission run --log``):
the grasp point (``grasp.distance_m`` above the estimated top-face centre) against the
telemetry's position, turned into body axes by the telemetry's heading (the tilt is left out:
a few degrees move the answer by millimetres at these offsets), minus ``tool_point_m``. Both
come from the cameras and the autopilot, as the mission sees them; the relative position is
what an arm would have to reach. Prints the distribution and the share of views inside the
arm's workspace shrunk by its margin (the readiness check), e.g.

    python benchmarks/grasp_offsets.py flight.jsonl --skip-s 30

(on PX4 SIH, where the vehicle never reaches GRASP_READY: reports/px4_sitl.md).
"""

from __future__ import annotations

import argparse
import bisect
import math
from pathlib import Path

import numpy as np
from eaglemission.missions.approach_config import ApproachConfig
from eaglemission.missions.log import read_log

from eaglemission.config import MissionFile


def offsets(log: Path, skip_s: float, state: str) -> tuple[MissionFile, np.ndarray]:
    """The grasp point's offsets from the tool home (n x 3, body FRD) in ``state``, from
    ``skip_s`` after its first entry."""
    recs = list(read_log(log))
    cfg = MissionFile.model_validate(next(r for r in recs if r["kind"] == "config")["config"])
    grasp_m = ApproachConfig.of(cfg).grasp.distance_m
    home = np.asarray(cfg.tool_point_m, dtype=np.float64)
    changes = [(r["t_ns"], r["new"]) for r in recs if r["kind"] == "state"]
    entered = [t for t, s in changes if s == state]
    if not entered:
        raise SystemExit(f"{log}: the flight never entered {state}")
    start_ns = entered[0] + int(skip_s * 1e9)
    tel = [r for r in recs if r["kind"] == "telemetry"]
    tel_ns = [r["t_ns"] for r in tel]
    out = []
    for r in recs:
        if r["kind"] != "estimate" or not r.get("ok") or "position_ned_m" not in r:
            continue
        t = r["t_ns"]
        now = [s for ts, s in changes if ts <= t]
        if t < start_ns or not now or now[-1] != state or not tel:
            continue
        v = tel[min(len(tel) - 1, bisect.bisect_left(tel_ns, t))]
        g = np.asarray(r["position_ned_m"]) - np.asarray(v["position_ned_m"])
        g[2] -= grasp_m
        yaw = math.radians(v["yaw_deg"])
        c, s = math.cos(yaw), math.sin(yaw)
        out.append(np.array([c * g[0] + s * g[1], -s * g[0] + c * g[1], g[2]]) - home)
    return cfg, np.array(out).reshape(-1, 3)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("logs", nargs="+", type=Path, help="flight logs (eaglemission run --log)")
    ap.add_argument("--state", default="FINE_DESCENT", help="the mission state to look at")
    ap.add_argument("--skip-s", type=float, default=30.0,
                    help="leave out this long after the state's first entry (the descent)")
    args = ap.parse_args(argv)
    for log in args.logs:
        cfg, o = offsets(log, args.skip_s, args.state)
        if not len(o):
            print(f"{log}: no accepted estimate in {args.state} after {args.skip_s:g} s")
            continue
        ws = cfg.manipulator.params.get("workspace", {})
        half = np.asarray(ws.get("half_extent_m", (0.10, 0.10, 0.08)), dtype=np.float64)
        reach = half - float(ws.get("margin_m", 0.02))
        h = np.hypot(o[:, 0], o[:, 1])
        inside = np.mean(np.all(np.abs(o) <= reach, axis=1))
        print(f"{log}: {len(o)} views; horizontal offset median {np.median(h) * 100:.1f} cm, "
              f"p90 {np.percentile(h, 90) * 100:.1f}, max {h.max() * 100:.1f}; vertical median "
              f"{np.median(o[:, 2]) * 100:+.1f} cm; inside the workspace (box +-"
              f"{', '.join(f'{x * 100:.0f}' for x in reach)} cm): {inside * 100:.0f} %")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
