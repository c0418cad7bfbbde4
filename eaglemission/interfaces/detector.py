"""Detector role (entry-point group ``eaglemission.detectors``)."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from eaglemission.types import DetectionResult, Frame, TargetPrior


@runtime_checkable
class Detector(Protocol):
    """Saliency detector, stateful across frames of one camera.

    Construction: ``cls(config=<cls.Config instance>, **context)``. ``detect`` is synchronous and
    I/O-free; it returns a float32 saliency map in [0, 1] at frame resolution plus ranked
    detections filtered by ``prior``. ``reset`` drops all temporal state (delay units,
    sequence windows); a resolution change resets implicitly.
    """

    def detect(self, frame: Frame, prior: TargetPrior | None = None) -> DetectionResult: ...

    def reset(self) -> None: ...
