"""Tracker role (entry-point group ``eaglemission.trackers``): keeps a target the detector found,
from frame to frame, between the detector's frames."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from eaglemission.types import Frame

Box = tuple[float, float, float, float]
"""(u_min, v_min, u_max, v_max): pixel edges in the frame (docs/conventions.md)."""


@runtime_checkable
class Tracker(Protocol):
    """A box tracker of one camera.

    Construction: ``cls(config=<cls.Config instance>, **context)``. ``start`` begins on a box;
    ``update`` returns the target's box in the next frame, or None when it lost it (then it
    needs ``start`` again). Synchronous and I/O-free.
    """

    def start(self, frame: Frame, box_px: Box) -> None: ...

    def update(self, frame: Frame) -> Box | None: ...
