"""Tracker role (entry-point group ``eaglemission.trackers``)."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from eaglemission.types import Detection, Frame


@runtime_checkable
class Tracker(Protocol):
    """Finds the target by its appearance (e.g. its colour) rather than its saliency.

    Construction: ``cls(config=<cls.Config instance>, target=TargetConfig, **context)``.
    ``available`` is False when the target's appearance is unknown (then the mission uses
    neither method). ``track`` returns the target-like region nearest ``near_px`` (None if
    there is none); ``matches`` says whether a detector's region looks like the target.
    Synchronous and I/O-free.
    """

    available: bool

    def track(self, frame: Frame, near_px: tuple[float, float]) -> Detection | None: ...

    def matches(self, frame: Frame, detection: Detection) -> bool: ...
