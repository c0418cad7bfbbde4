"""Acquire, then keep (eaglemission/perception/keep.py): the keeper's state machine with a
scripted tracker, and with OpenCV's CSRT on moving frames."""

from __future__ import annotations

import numpy as np
import pytest

from eaglemission import registry
from eaglemission.perception.keep import (
    KeepConfig,
    TargetKeeper,
    box_detection,
    box_iou,
    box_of,
    on_box,
)
from eaglemission.types import Frame

Box = tuple[float, float, float, float]


class ScriptedTracker:
    """A tracker that reports the boxes it is given, one per update (None: lost)."""

    def __init__(self, boxes: list[Box | None]) -> None:
        self.boxes = list(boxes)
        self.starts: list[Box] = []

    def start(self, frame: Frame, box_px: Box) -> None:
        self.starts.append(box_px)

    def update(self, frame: Frame) -> Box | None:
        return self.boxes.pop(0) if self.boxes else None


FRAME = Frame(np.zeros((100, 200, 3), np.uint8), 1, "wide", 0)


def det_at(u: float, v: float, half: float = 5.0):
    return box_detection((u - half, v - half, u + half, v + half), "wide", score=1.0)


def test_box_helpers():
    d = det_at(50, 40)
    assert box_of(d) == (45.0, 35.0, 55.0, 45.0)
    assert on_box((56, 40), box_of(d)) and not on_box((60, 40), box_of(d))
    assert box_iou((0, 0, 10, 10), (5, 0, 15, 10)) == pytest.approx(1 / 3)
    assert box_iou((0, 0, 1, 1), (2, 2, 3, 3)) == 0.0


def test_the_target_is_confirmed_after_confirm_frames_on_one_object():
    tr = ScriptedTracker([])
    k = TargetKeeper(tr, KeepConfig(confirm_frames=2))
    assert k.detector_due() and not k.keeping
    assert k.step(FRAME, det_at(50, 40), True) is None  # a candidate, not yet the target
    assert k.step(FRAME, det_at(120, 40), True) is None  # elsewhere: counting starts again
    kept = k.step(FRAME, det_at(121, 41), True)
    assert kept is not None and not kept.from_tracker and k.keeping
    assert tr.starts == [box_of(det_at(121, 41))]


def test_the_candidate_awaiting_confirmation_is_offered_while_searching_only():
    k = TargetKeeper(ScriptedTracker([(60, 40, 70, 50)]), KeepConfig(confirm_frames=2))
    assert k.candidate is None
    k.step(FRAME, det_at(50, 40), True)
    assert k.candidate == box_of(det_at(50, 40))
    k.step(FRAME, None, True)
    assert k.candidate is None  # nothing chosen: searching anew
    k.step(FRAME, det_at(50, 40), True)
    k.step(FRAME, det_at(51, 40), True)
    assert k.keeping and k.candidate is None  # keeping: the kept box, not a candidate
    k.reset()
    assert k.candidate is None


def test_keeping_between_re_checks_uses_the_trackers_box():
    tr = ScriptedTracker([(51, 36, 61, 46), (52, 36, 62, 46), (53, 36, 63, 46)])
    k = TargetKeeper(tr, KeepConfig(confirm_frames=1, detect_every_frames=3))
    k.step(FRAME, det_at(50, 40), True)
    assert not k.detector_due()
    kept = k.step(FRAME, None, False)
    assert kept is not None and kept.from_tracker and kept.detection.center_px == (56.0, 41.0)
    assert not k.detector_due()
    k.step(FRAME, None, False)
    assert k.detector_due()  # the third frame: the detector re-checks
    assert k.detector_due(close_range=False) and TargetKeeper(tr).detector_due(True)


def test_a_re_check_on_the_kept_box_keeps_the_detection_and_restarts_a_drifted_tracker():
    tr = ScriptedTracker([(50, 35, 60, 45), (40, 35, 60, 55)])
    k = TargetKeeper(tr, KeepConfig(confirm_frames=1, detect_every_frames=1, restart_iou=0.3))
    k.step(FRAME, det_at(55, 40), True)
    kept = k.step(FRAME, det_at(55, 40), True)  # overlaps the tracked box well: no restart
    assert kept is not None and not kept.from_tracker and len(tr.starts) == 1
    kept = k.step(FRAME, det_at(51, 45), True)  # on the box, but the boxes overlap little
    assert kept is not None and len(tr.starts) == 2 and tr.starts[-1] == box_of(det_at(51, 45))


def test_the_detector_moves_the_keeper_after_switch_after_re_checks_elsewhere():
    tr = ScriptedTracker([(50, 35, 60, 45)] * 4)
    k = TargetKeeper(tr, KeepConfig(confirm_frames=1, detect_every_frames=1, switch_after=2))
    k.step(FRAME, det_at(55, 40), True)
    kept = k.step(FRAME, det_at(150, 40), True)  # elsewhere once: the tracker's box stays
    assert kept is not None and kept.from_tracker and kept.detection.center_px == (55.0, 40.0)
    kept = k.step(FRAME, det_at(150, 40), True)  # twice: the keeper moves
    assert kept is not None and not kept.from_tracker and kept.detection.center_px == (150, 40)
    assert tr.starts[-1] == box_of(det_at(150, 40))


def test_with_an_example_a_detection_elsewhere_must_look_more_like_it_to_move_the_keeper():
    tr = ScriptedTracker([(50, 35, 60, 45)] * 4)
    k = TargetKeeper(tr, KeepConfig(confirm_frames=1, detect_every_frames=1, switch_after=1))
    k.step(FRAME, det_at(55, 40), True)

    def likeness(centre_px: tuple[float, float]) -> float:
        return 0.9 if centre_px[0] < 100 else 0.5  # the kept target looks like the example

    kept = k.step(FRAME, det_at(150, 40), True, likeness)
    assert kept is not None and kept.from_tracker and kept.detection.center_px == (55.0, 40.0)
    kept = k.step(FRAME, det_at(150, 40), True, lambda c: 1.0 - likeness(c))
    assert kept is not None and not kept.from_tracker  # now the other looks more like it


def test_a_lost_target_hands_over_to_the_detector_then_searching():
    tr = ScriptedTracker([None, None])
    k = TargetKeeper(tr, KeepConfig(confirm_frames=1, detect_every_frames=5))
    k.step(FRAME, det_at(55, 40), True)
    assert k.step(FRAME, None, False) is None  # lost between re-checks
    assert k.detector_due() and k.keeping
    assert k.step(FRAME, None, True) is None and not k.keeping  # nothing there: search again
    k.reset()
    assert k.box is None and k.detector_due()


def _frames(n: int, step_px: int = 3) -> list[Frame]:
    rng = np.random.RandomState(5)
    out = []
    for i in range(n):
        img = np.clip(rng.randn(240, 320, 3) * 8 + 90, 0, 255).astype(np.uint8)
        u = 60 + step_px * i
        img[100:124, u:u + 30] = (30, 40, 210)
        img[106:118, u + 8:u + 22] = (200, 220, 240)  # texture for the tracker
        out.append(Frame(img, 1_000_000_000 + i * 100_000_000, "wide", i))
    return out


@pytest.mark.parametrize("kind", ["csrt", "kcf"])
def test_opencvs_trackers_follow_a_moving_box(kind):
    tracker = registry.load("trackers", kind, {"scale": 0.5})
    frames = _frames(12)
    tracker.start(frames[0], (59.5, 99.5, 89.5, 123.5))
    for i, f in enumerate(frames[1:], start=1):
        box = tracker.update(f)
        assert box is not None, i
        cu = (box[0] + box[2]) / 2
        assert abs(cu - (74.5 + 3 * i)) < 6, (i, box)


def test_a_tracker_that_cannot_start_reports_the_target_lost():
    tracker = registry.load("trackers", "csrt", {"scale": 0.1})
    f = _frames(2)[0]
    tracker.start(f, (10.0, 10.0, 11.0, 11.0))  # below a pixel once reduced
    assert tracker.update(f) is None


def test_a_measured_region_of_the_target_corrects_the_kept_box():
    tr = ScriptedTracker([])
    k = TargetKeeper(tr, KeepConfig(confirm_frames=1, restart_iou=0.3))
    k.correct(FRAME, (0, 0, 10, 10))
    assert not k.keeping and tr.starts == []  # nothing kept: nothing to correct
    k.step(FRAME, det_at(50, 40), True)
    k.correct(FRAME, (46, 35, 56, 45))  # overlaps the kept box well: the tracker goes on
    assert k.box == (46, 35, 56, 45) and len(tr.starts) == 1
    k.correct(FRAME, (80, 35, 90, 45))  # elsewhere: the tracker restarts on it
    assert k.box == (80, 35, 90, 45) and tr.starts[-1] == (80, 35, 90, 45)
