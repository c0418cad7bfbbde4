"""Leave-scenes-out choice of how the mission keeps its target (the ``tracker`` section); prints
out-of-fold figures only.

    python benchmarks/tune_keep.py                                  # ../shared's UAV sequences
    python benchmarks/tune_keep.py --data ../shared/data/uav_tracking --data /path/to/more

Protocol (docs/detectors.md, "Acquire and keep"):

- **Scenes**: sequences of one scene (``group1_1`` and ``group1_3``; a sequence and its longer
  copy) form one scene; scenes, sorted by name, are dealt into ``--folds`` folds. For each fold
  the configuration with the best pooled on-target rate on the other folds' scenes, among those
  whose median CPU per frame is within ``--max-ms`` (when given), is scored on the fold's own
  scenes; the printed figures pool these held-out scores. The configuration that ships is the
  one chosen on all scenes.
- **Frames and scoring** as ``eaglemission bench --mission`` (lab/bench/perception.py): the
  example image is each sequence's first box's crop; every later frame with the target is
  scored; nothing kept yet counts as a miss.
- **Search**: the detector (+ the appearance prior) is run once on every frame of every
  sequence and its regions replayed; only the keeper and its tracker run per configuration
  (the detector's CPU is added for the frames it would run on).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import itertools  # noqa: E402
import json  # noqa: E402
import pickle  # noqa: E402
import re  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402
from eaglemission.lab.bench.data import BenchSequence, find_sequences  # noqa: E402
from eaglemission.lab.bench.perception import MethodScore, example_of, score  # noqa: E402
from eaglemission.missions.footage import FootageOptions, FootagePerception  # noqa: E402

from eaglemission.config import MissionFile, load_config  # noqa: E402
from eaglemission.perception.inputs import frame_time_ns, read_image  # noqa: E402
from eaglemission.types import DetectionResult, Frame  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared" / "data" / "uav_tracking"
FPS = 10.0


def grid() -> list[dict[str, Any]]:
    """The shipped CSRT settings (the CPU budget's: docs/detectors.md, "Acquire and keep") x
    the detector's re-check period x how many re-checks elsewhere move the keeper, and CSRT at
    OpenCV's own settings (three to five times the cost) for reference."""
    cheap = {"template_size": 48, "number_of_scales": 9, "admm_iterations": 2,
             "use_segmentation": False}
    out: list[dict[str, Any]] = []
    for every, switch in itertools.product((2, 4, 8), (2, 3)):
        out.append({"type": "csrt", "params": cheap,
                    "keep": {"detect_every_frames": every, "switch_after": switch}})
    out.append({"type": "csrt", "params": {"template_size": 200, "number_of_scales": 33,
                                           "admm_iterations": 4, "use_segmentation": True},
                "keep": {"detect_every_frames": 4, "switch_after": 2}})
    return out


def scene_of(name: str) -> str:
    """``UAV123_10fps/group1_3`` -> ``group1`` (sub-sequences of one scene go together)."""
    last = name.split("/")[-1]
    return re.sub(r"_\d+$", "", last)


class CachedDetector:
    """The detector's results replayed by frame number (the search runs it once)."""

    def __init__(self, results: list[tuple[DetectionResult, float]]) -> None:
        self.results = results
        self.cpu_ms = 0.0
        self.calls = 0

    def detect(self, frame: Frame, prior: Any = None) -> DetectionResult:
        res, ms = self.results[frame.seq]
        self.cpu_ms += ms
        self.calls += 1
        return res

    def reset(self) -> None:
        pass


def cached_results(seq: BenchSequence, cfg: MissionFile, image: bool,
                   cache: Path) -> list[tuple[DetectionResult, float]]:
    f = cache / f"{seq.name.replace('/', '_')}_{'img' if image else 'noimg'}.pkl"
    if f.is_file():
        out: list[tuple[DetectionResult, float]] = pickle.loads(f.read_bytes())
        return out
    first, crop = example_of(seq)
    opt = FootageOptions(example_image=crop, mission_colour=False) if image else \
        FootageOptions(without_image=True, mission_colour=False)
    det = FootagePerception(cfg, opt).detector
    out = []
    for i, path in enumerate(seq.frames):
        frame = Frame(read_image(path), frame_time_ns(i, FPS), "wide", i)
        t0 = time.process_time()
        res = det.detect(frame)
        ms = (time.process_time() - t0) * 1e3
        out.append((DetectionResult(np.zeros((1, 1), np.float32), res.detections,
                                    res.timestamp_ns, res.camera_id, res.seq, res.threshold),
                    ms))
    f.write_bytes(pickle.dumps(out))
    return out


def run_config(seq: BenchSequence, cfg: MissionFile, point: dict[str, Any],
               results: list[tuple[DetectionResult, float]]) -> MethodScore:
    first, crop = example_of(seq)
    data = cfg.model_dump()
    data["tracker"] = {"type": point["type"], "params": point["params"], "keep": point["keep"]}
    flown = MissionFile.model_validate(data)
    fp = FootagePerception(flown, FootageOptions(example_image=crop, mission_colour=False))
    cached = CachedDetector(results)
    fp.tools = fp.tools.__class__(cached, fp.tools.coarse, fp.tools.fine, None,
                                  fp.tools.appearance, fp.keeper)
    out = MethodScore()
    for i in range(first, len(seq.frames)):
        frame = Frame(read_image(seq.frames[i]), frame_time_ns(i, FPS), "wide", i)
        before = cached.cpu_ms
        t0 = time.process_time()
        meas = fp.process(frame)
        ms = (time.process_time() - t0) * 1e3 + (cached.cpu_ms - before)
        if i == first:
            continue
        det = meas.detection
        score(seq.boxes, i, [det.center_px] if det is not None and meas.kept else [], out)
        out.cpu_ms.append(ms)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--data", type=Path, action="append", default=None,
                    help="a folder of box sequences (repeatable; default ../shared's UAV set)")
    ap.add_argument("--mission", type=Path, default=None, help="mission file (default embedded)")
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--max-ms", type=float, default=None,
                    help="only configurations whose median CPU per frame is within this")
    ap.add_argument("--cache", type=Path, default=Path("/tmp/eaglemission_keep"))
    a = ap.parse_args(argv)
    cv2.setNumThreads(1)
    roots = a.data or [SHARED]
    cfg = load_config(a.mission)
    a.cache.mkdir(parents=True, exist_ok=True)
    seqs: dict[str, BenchSequence] = {}
    for root in roots:
        for s in find_sequences(root):
            if s.boxes is None:
                continue
            key = s.name.split("/")[-1]
            # a longer copy of a sequence stands for it (the same scene, more frames)
            if key not in seqs or len(s.frames) > len(seqs[key].frames):
                seqs[key] = s
    scenes = sorted({scene_of(n) for n in seqs})
    folds = [scenes[i::a.folds] for i in range(a.folds)]
    print(f"# tune_keep: {len(seqs)} sequences, {len(scenes)} scenes, "
          f"{sum(len(s.frames) for s in seqs.values())} frames; folds: "
          + "; ".join(", ".join(f) for f in folds), flush=True)
    points = grid()
    scores: list[dict[str, MethodScore]] = []
    for k, point in enumerate(points):
        t = time.perf_counter()
        per = {n: run_config(s, cfg, point, cached_results(s, cfg, True, a.cache))
               for n, s in seqs.items()}
        scores.append(per)
        pooled = MethodScore()
        for v in per.values():
            pooled.merge(v)
        print(f"#   {k + 1}/{len(points)} {json.dumps(point)}: {100 * pooled.rate:.1f} % "
              f"(median {np.median(pooled.cpu_ms):.1f} ms) [{time.perf_counter() - t:.0f} s]",
              file=sys.stderr, flush=True)

    def pooled_on(k: int, names: list[str]) -> MethodScore:
        m = MethodScore()
        for n in names:
            m.merge(scores[k][n])
        return m

    def best_on(names: list[str]) -> int:
        ok = [k for k in range(len(points)) if a.max_ms is None
              or np.median(pooled_on(k, names).cpu_ms) <= a.max_ms]
        return max(ok or range(len(points)), key=lambda k: pooled_on(k, names).rate)

    names_of = {sc: [n for n in seqs if scene_of(n) == sc] for sc in scenes}
    oof: dict[str, MethodScore] = {}
    chosen = {}
    for i, fold in enumerate(folds):
        train = [n for sc in scenes if sc not in fold for n in names_of[sc]]
        k = chosen[i] = best_on(train)
        for sc in fold:
            for n in names_of[sc]:
                oof[n] = scores[k][n]
    total = MethodScore()
    for v in oof.values():
        total.merge(v)
    per = [v.rate for v in oof.values() if v.frames]
    print(f"\n## Out of fold (scenes held out): {100 * total.rate:.1f} % on target, per sequence "
          f"{100 * np.mean(per):.1f} +- {100 * np.std(per):.1f} % ({100 * min(per):.1f}-"
          f"{100 * max(per):.1f} %), median CPU {np.median(total.cpu_ms):.1f} ms per frame\n")
    print("| sequence | on target | chosen configuration |\n|---|---|---|")
    fold_of = {n: i for i, f in enumerate(folds) for sc in f for n in names_of[sc]}
    for n in sorted(oof):
        v = oof[n]
        print(f"| {n} | {100 * v.rate:.1f} % ({v.hits}/{v.frames}) | "
              f"{json.dumps(points[chosen[fold_of[n]]])} |")
    final = best_on(list(seqs))
    print(f"\nChosen on all scenes (what ships): {json.dumps(points[final])}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
