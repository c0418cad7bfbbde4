"""One detector run over the ``eaglemission bench`` sequences: :class:`DetectorRun` holds its
scores (the per-image-mean curves of :mod:`eaglemission.lab.bench.metrics` and the box metrics
of :mod:`eaglemission.lab.bench.boxes`)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
from eaglemission.lab.bench.boxes import (
    BoxScores,
    box_from_mask,
    score_frame,
)
from eaglemission.lab.bench.data import BenchSequence, read_gt
from eaglemission.lab.bench.metrics import CurveAccumulator, SequenceScores, normalize_map, quantize

from eaglemission.commands.params import DetectorSpec
from eaglemission.perception.inputs import frame_time_ns, read_image
from eaglemission.types import DetectionResult, Frame


@dataclass
class DetectorRun:
    spec: DetectorSpec
    sequences: dict[str, SequenceScores] = field(default_factory=dict)
    overall: CurveAccumulator = field(default_factory=CurveAccumulator)
    box_sequences: dict[str, BoxScores] = field(default_factory=dict)
    box: BoxScores = field(default_factory=BoxScores)
    detections: int = 0
    frames: int = 0
    time_s: list[float] = field(default_factory=list)

    @property
    def has_curves(self) -> bool:
        return self.overall.n_frames > 0


def run_detector_on_sequence(detector: Any, seq: BenchSequence, fps: float, run: DetectorRun,
                             save_dir: Path | None, on_frame: Any = None, *,
                             first_scored: int = 0) -> tuple[SequenceScores | None, BoxScores]:
    """Run one detector over a sequence (state reset first) and score it.

    Every frame is run (the detector's state sees the whole sequence); frames before
    ``first_scored`` are not scored. Mask frames feed the curves (max F, AUC, MAE) and the box
    metrics against the mask's bounding box and the mask itself (on the mask); ``boxes.txt``
    frames feed the box metrics.
    """
    detector.reset()
    acc = CurveAccumulator()
    boxes = BoxScores()
    for i, (fpath, gpath) in enumerate(zip(seq.frames, seq.gts)):
        image = read_image(fpath)
        frame = Frame(image, frame_time_ns(i, fps), "bench", i)
        t = time.perf_counter()
        result: DetectionResult = detector.detect(frame)
        run.time_s.append(time.perf_counter() - t)
        run.detections += len(result.detections)
        run.frames += 1
        if i >= first_scored:
            box = gt = None
            if gpath is not None:
                sal01 = normalize_map(result.saliency)
                gt = read_gt(gpath, image.shape[:2])
                acc.add(sal01, gt)
                box = box_from_mask(gt)
                if save_dir is not None:
                    out = save_dir / seq.name / f"{fpath.stem}.png"
                    out.parent.mkdir(parents=True, exist_ok=True)
                    cv2.imwrite(str(out), quantize(sal01))
            if seq.boxes is not None:
                box = seq.boxes[i]
            if box is not None:
                boxes.add(score_frame(result, box, mask=gt))
        if on_frame is not None:
            on_frame()
    run.overall.merge(acc)
    run.box.merge(boxes)
    return (acc.scores() if acc.n_frames else None), boxes

