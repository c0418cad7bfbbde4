"""Frame faults spoil the frames the camera plugin delivers in their window, and at least one
however short the window (a 0.05 s truncated frame can fall between two 0.1 s grabs: spoiling
only the frames grabbed inside it, such a fault would often spoil none and the run would log no
``frame_rejected``)."""

from __future__ import annotations

import numpy as np
from eaglemission.lab.faults.config import FaultSpec
from eaglemission.lab.faults.faulty_camera import FaultyCamera
from eaglemission.lab.faults.schedule import ActiveFaults

from eaglemission.geometry import CameraModel
from eaglemission.types import Frame

MS = 1_000_000


class _Clock:
    def __init__(self) -> None:
        self.t_ns = 0

    def now_ns(self) -> int:
        return self.t_ns


class _Grey:
    """A camera delivering grey 40x30 frames stamped by ``clock``."""

    camera_id = "wide"

    def __init__(self, clock: _Clock) -> None:
        self.clock, self.seq = clock, 0
        self.model = CameraModel.from_lens("wide", focal_length_mm=2.8, resolution_px=(40, 30))

    def grab(self, *, timeout_s: float) -> Frame:
        self.seq += 1
        return Frame(np.full((30, 40, 3), 128, np.uint8), self.clock.t_ns, "wide", self.seq)


def _spec(kind: str, duration_s: float, camera: str = "both") -> FaultSpec:
    return FaultSpec(kind=kind, at_s=0.0, duration_s=duration_s, camera=camera)


def test_a_window_between_two_grabs_still_spoils_the_next_frame():
    clock, faults = _Clock(), ActiveFaults()
    cam = FaultyCamera(inner=_Grey(clock), faults=faults, clock=clock)
    clock.t_ns = 100 * MS
    assert cam.grab(timeout_s=1.0).image.shape == (30, 40, 3)
    clock.t_ns = 110 * MS
    faults.activate(_spec("truncated_frame", 0.05), clock.t_ns)  # ends at 160 ms
    clock.t_ns = 200 * MS  # the next grab, after the window
    assert cam.grab(timeout_s=1.0).image.shape == (18, 40, 3)
    clock.t_ns = 300 * MS
    assert cam.grab(timeout_s=1.0).image.shape == (30, 40, 3), "one frame, not more"


def test_every_frame_in_the_window_is_spoiled():
    clock, faults = _Clock(), ActiveFaults()
    cam = FaultyCamera(inner=_Grey(clock), faults=faults, clock=clock)
    faults.activate(_spec("corrupted_frame", 0.3), 0)
    noisy = []
    for t_ms in (0, 100, 200, 300, 400):
        clock.t_ns = t_ms * MS
        noisy.append(cam.grab(timeout_s=1.0).image.std() > 10)
    assert noisy == [True, True, True, False, False]


def test_a_fault_on_the_other_camera_waits_for_it():
    faults = ActiveFaults()
    faults.activate(_spec("truncated_frame", 0.05, camera="narrow"), 0)
    assert faults.frame_fault("truncated_frame", 500 * MS, "wide") is None
    assert faults.frame_fault("truncated_frame", 900 * MS, "narrow") is not None
    assert faults.frame_fault("truncated_frame", 1000 * MS, "narrow") is None


def test_nothing_is_spoiled_before_the_fault_starts():
    faults = ActiveFaults()
    faults.activate(_spec("truncated_frame", 0.05), 100 * MS)
    assert faults.frame_fault("truncated_frame", 50 * MS, "wide") is None
    assert faults.frame_fault("truncated_frame", 120 * MS, "wide") is not None
