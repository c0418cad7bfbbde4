"""The mission's perception on box-annotated footage (``eaglemission bench --mission``): acquire
and keep, acquisition alone, keeping from the confirmation on, and OpenCV's CSRT and KCF
trackers started on the first box, scored on the same frames in one run.

Protocol (docs/detectors.md, "Acquire and keep"): each sequence's first frame with a box gives
the example image (its box's crop); every later frame with the target is scored: **on target**
when the method's box centre lies inside the target's box grown by 25 % on each side; a frame
where the method gives nothing (a mission that has not confirmed the target yet, a tracker
that lost it) is a miss. **False**: detections per frame off the grown box (acquisition: all
of the detector's regions; the mission and the trackers: their one box). **CPU**: process time
per frame, median over the frames, and its ratio to OpenCV's spectral residual + regions
measured in the same run.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np
from eaglemission.lab.bench.boxes import box_valid, grow_box, point_in_box
from eaglemission.lab.bench.data import BenchSequence, first_frame_crop
from eaglemission.missions.footage import FootageOptions, FootagePerception

from eaglemission import registry
from eaglemission.config import MissionFile
from eaglemission.perception.inputs import frame_time_ns, read_image
from eaglemission.types import Detection, Frame

OPENCV_DEFAULTS: dict[str, dict[str, Any]] = {
    "csrt": {"scale": 1.0, "template_size": 200, "number_of_scales": 33, "admm_iterations": 4,
             "use_segmentation": True},
    "kcf": {"scale": 1.0},
}
"""The reference trackers as a user would start them: OpenCV's own settings, full resolution
(not the mission's cheaper ones)."""


@dataclass
class MethodScore:
    """One method on one sequence."""

    frames: int = 0
    """Scored frames with the target."""
    hits: int = 0
    false: int = 0
    """Boxes off the target, over every scored frame."""
    scored: int = 0
    """Every scored frame (with the target or not)."""
    cpu_ms: list[float] = field(default_factory=list)

    @property
    def rate(self) -> float:
        return self.hits / self.frames if self.frames else float("nan")

    @property
    def false_per_frame(self) -> float:
        return self.false / self.scored if self.scored else float("nan")

    def merge(self, other: MethodScore) -> None:
        self.frames += other.frames
        self.hits += other.hits
        self.false += other.false
        self.scored += other.scored
        self.cpu_ms += other.cpu_ms


def score(boxes: np.ndarray, i: int, centres: Sequence[tuple[float, float]],
          into: MethodScore) -> None:
    """Frame ``i``'s boxes (``centres``, best first) against its annotation."""
    box = boxes[i]
    into.scored += 1
    if not box_valid(box):
        into.false += len(centres)
        return
    grown = grow_box(box, 0.25)
    on = [point_in_box(c[0], c[1], grown) for c in centres]
    into.frames += 1
    into.hits += bool(on and on[0])
    into.false += sum(not x for x in on)


T = TypeVar("T")


def _timed(fn: Callable[[Frame], T], frame: Frame) -> tuple[T, float]:
    """(``fn(frame)``, its process time in ms)."""
    t0 = time.process_time()
    out = fn(frame)
    return out, (time.process_time() - t0) * 1e3


def _boxes(seq: BenchSequence) -> np.ndarray:
    if seq.boxes is None:
        raise ValueError(f"{seq.name}: no boxes.txt; the perception bench needs a box per frame")
    return seq.boxes


def run_mission(seq: BenchSequence, cfg: MissionFile, options: FootageOptions, first: int,
                fps: float) -> tuple[MethodScore, MethodScore, int | None]:
    """(the mission's perception, the same from its confirmation on, the confirmation frame)."""
    fp = FootagePerception(cfg, options)
    boxes = _boxes(seq)
    mission, keeping = MethodScore(), MethodScore()
    confirmed: int | None = None
    for i in range(first, len(seq.frames)):
        frame = Frame(read_image(seq.frames[i]), frame_time_ns(i, fps), "wide", i)
        meas, ms = _timed(fp.process, frame)
        det = meas.detection
        target = det is not None and (meas.kept or fp.keeper is None)
        if target and confirmed is None:
            confirmed = i
        if i == first:
            continue  # the example's frame
        centres = [det.center_px] if target and det is not None else []
        score(boxes, i, centres, mission)
        mission.cpu_ms.append(ms)
        if confirmed is not None and i > confirmed:
            score(boxes, i, centres, keeping)
    return mission, keeping, confirmed


def run_acquisition(seq: BenchSequence, detector: Any, first: int, fps: float) -> MethodScore:
    """The detector (+ prior) on every frame alone, all its regions (best first)."""
    out = MethodScore()
    boxes = _boxes(seq)
    for i in range(first, len(seq.frames)):
        frame = Frame(read_image(seq.frames[i]), frame_time_ns(i, fps), "wide", i)
        res, ms = _timed(detector.detect, frame)
        if i == first:
            continue
        score(boxes, i, [d.center_px for d in res.detections], out)
        out.cpu_ms.append(ms)
    return out


def run_tracker(seq: BenchSequence, kind: str, first: int, fps: float,
                params: dict[str, Any] | None = None) -> MethodScore:
    """A tracker started on the first box (the example's frame); ``params`` None: OpenCV's own
    settings at full resolution."""
    tracker = registry.load("trackers", kind, OPENCV_DEFAULTS[kind] if params is None else params)
    out = MethodScore()
    boxes = _boxes(seq)
    for i in range(first, len(seq.frames)):
        frame = Frame(read_image(seq.frames[i]), frame_time_ns(i, fps), "wide", i)
        if i == first:
            u0, v0, u1, v1 = (float(x) for x in boxes[i])
            tracker.start(frame, (u0, v0, u1, v1))
            continue
        box, ms = _timed(tracker.update, frame)
        centres = [] if box is None else [((box[0] + box[2]) / 2, (box[1] + box[3]) / 2)]
        score(boxes, i, centres, out)
        out.cpu_ms.append(ms)
    return out


def example_of(seq: BenchSequence) -> tuple[int, np.ndarray]:
    """(the first boxed frame, its box's crop: the example image)."""
    return first_frame_crop(seq)


def detection_centres(dets: Sequence[Detection]) -> list[tuple[float, float]]:
    return [d.center_px for d in dets]


ROWS = ("mission: acquire + keep", "  keeping, from the confirmation on",
        "acquisition: detector + prior, every frame", "mission without the image",
        "acquisition without the image", "sr + regions", "csrt from the first box",
        "kcf from the first box")


def bench_sequence(seq: BenchSequence, cfg: MissionFile, fps: float,
                   trackers: Sequence[str] = tuple(OPENCV_DEFAULTS)) -> dict[str, MethodScore]:
    """Every row of :data:`ROWS` on one sequence (the same frames)."""
    first, crop = example_of(seq)
    out: dict[str, MethodScore] = {}
    # the footage's target is not the mission file's: only the example image describes it
    with_image = FootageOptions(example_image=crop, mission_colour=False)
    out[ROWS[0]], out[ROWS[1]], _ = run_mission(seq, cfg, with_image, first, fps)
    acq = FootagePerception(cfg, FootageOptions(example_image=crop, keep=False,
                                                mission_colour=False))
    out[ROWS[2]] = run_acquisition(seq, acq.detector, first, fps)
    no_image = FootageOptions(without_image=True, mission_colour=False)
    out[ROWS[3]], _, _ = run_mission(seq, cfg, no_image, first, fps)
    plain = FootagePerception(cfg, FootageOptions(without_image=True, keep=False,
                                                  mission_colour=False))
    out[ROWS[4]] = run_acquisition(seq, plain.detector, first, fps)
    out[ROWS[5]] = run_acquisition(seq, registry.load("detectors", "sr", {}), first, fps)
    for kind in trackers:
        out[f"{kind} from the first box"] = run_tracker(seq, kind, first, fps)
    return out


def _pct(x: float) -> str:
    return "-" if x != x else f"{100 * x:.1f} %"


def _spread(per: list[float]) -> str:
    if not per:
        return "-"
    return (f"{_pct(float(np.mean(per)))} +- {_pct(float(np.std(per)))} "
            f"({_pct(min(per))}-{_pct(max(per))})")


def report(per_seq: dict[str, dict[str, MethodScore]]) -> str:
    """Markdown: each row pooled over the frames with its spread over the scenes and CPU, then
    one table per scene."""
    rows = list(next(iter(per_seq.values())))
    pooled = {r: MethodScore() for r in rows}
    for scores in per_seq.values():
        for r in rows:
            pooled[r].merge(scores[r])
    sr_ms = float(np.median(pooled["sr + regions"].cpu_ms)) if pooled["sr + regions"].cpu_ms \
        else float("nan")
    lines = ["| method | on target (pooled) | per scene: mean +- std (min-max) | false / frame "
             "| CPU ms / frame (median) | x SR |", "|---|---|---|---|---|---|"]
    for r in rows:
        per = [s[r].rate for s in per_seq.values() if s[r].frames]
        ms = float(np.median(pooled[r].cpu_ms)) if pooled[r].cpu_ms else float("nan")
        lines.append(f"| {r} | {_pct(pooled[r].rate)} | {_spread(per)} | "
                     f"{pooled[r].false_per_frame:.2f} | {ms:.1f} | {ms / sr_ms:.1f} |")
    lines += ["", "| scene | " + " | ".join(rows) + " |", "|---|" + "---|" * len(rows)]
    for name, scores in per_seq.items():
        lines.append(f"| {name} | " + " | ".join(
            f"{_pct(scores[r].rate)} ({scores[r].hits}/{scores[r].frames})" for r in rows) + " |")
    return "\n".join(lines)
