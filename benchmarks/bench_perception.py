"""CPU per 1280x960 frame of the mission's perception (acquire and keep) against OpenCV's
spectral residual + regions, measured in the same run on the same frames.

    python benchmarks/bench_perception.py                         # a real UAV sequence, 1280x960
    python benchmarks/bench_perception.py --sequence UAVDT/S0601 --rounds 3

Each round runs, on one core (single-threaded OpenCV and numba), the mission file's perception
of one camera (missions/footage.py: the detector + the appearance prior with the sequence's
first box as the example image, the keeper and its tracker) over the sequence's frames resized
to 1280x960, then SR + regions over the same frames; the rounds alternate so both see the same
machine. Printed: process-time per frame (mean, median, p90) of each and their ratio; the budget
is 9.3 ms (two cameras at 54 frames per second on one core).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402
from eaglemission.lab.bench.data import find_sequences, first_frame_crop  # noqa: E402
from eaglemission.missions.footage import FootageOptions, FootagePerception  # noqa: E402

from eaglemission import registry  # noqa: E402
from eaglemission.config import load_config  # noqa: E402
from eaglemission.perception.inputs import frame_time_ns, read_image  # noqa: E402
from eaglemission.types import Frame  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data" / "uav_tracking"
SIZE = (1280, 960)
BUDGET_MS = 9.3


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--sequence", default="UAV123_10fps/car16_2")
    ap.add_argument("--mission", type=Path, default=None, help="mission file (default embedded)")
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--rounds", type=int, default=3)
    a = ap.parse_args(argv)
    cv2.setNumThreads(1)
    seqs = [s for s in find_sequences(a.data) if s.name == a.sequence or
            s.name.endswith("/" + a.sequence)]
    if not seqs:
        print(f"error: no sequence {a.sequence!r} under {a.data}", file=sys.stderr)
        return 2
    seq = seqs[0]
    first, crop = first_frame_crop(seq)
    sx = SIZE[0] / read_image(seq.frames[first]).shape[1]
    sy = SIZE[1] / read_image(seq.frames[first]).shape[0]
    crop = cv2.resize(crop, None, fx=sx, fy=sy, interpolation=cv2.INTER_LINEAR)
    frames = [cv2.resize(read_image(p), SIZE, interpolation=cv2.INTER_LINEAR)
              for p in seq.frames[first:first + a.frames]]
    cfg = load_config(a.mission)
    times: dict[str, list[float]] = {"mission perception": [], "sr + regions": []}
    kept = 0
    for _ in range(a.rounds):
        fp = FootagePerception(cfg, FootageOptions(example_image=crop, mission_colour=False))
        for i, img in enumerate(frames):
            f = Frame(img, frame_time_ns(i, 10.0), "wide", i)
            t0 = time.process_time()
            meas = fp.process(f)
            times["mission perception"].append((time.process_time() - t0) * 1e3)
            kept += meas.kept
        sr = registry.load("detectors", "sr", {})
        for i, img in enumerate(frames):
            f = Frame(img, frame_time_ns(i, 10.0), "wide", i)
            t0 = time.process_time()
            sr.detect(f)
            times["sr + regions"].append((time.process_time() - t0) * 1e3)
    print(f"# {seq.name}: {len(frames)} frames resized to {SIZE[0]}x{SIZE[1]}, {a.rounds} "
          f"rounds alternated; the target kept in {kept}/{len(frames) * a.rounds} frames")
    print("\n| per frame, process time | mean | median | p90 |\n|---|---|---|---|")
    for k, v in times.items():
        print(f"| {k} | {np.mean(v):.1f} ms | {np.median(v):.1f} ms | "
              f"{np.percentile(v, 90):.1f} ms |")
    m, s = np.mean(times["mission perception"]), np.mean(times["sr + regions"])
    print(f"\nmission perception: {m:.1f} ms per frame = {m / s:.2f}x SR + regions "
          f"({'within' if m <= BUDGET_MS else 'over'} the {BUDGET_MS} ms budget)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
