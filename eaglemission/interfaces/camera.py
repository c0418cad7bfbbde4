"""Camera role (entry-point group ``eaglemission.cameras``)."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from eaglemission.geometry import CameraModel
from eaglemission.types import Frame


@runtime_checkable
class Camera(Protocol):
    """A source of :class:`Frame` s.

    Construction: ``cls(config=<cls.Config instance>, model=CameraModel, clock=Clock, **context)``;
    plugins ignore context keys they do not use. ``grab`` blocks at most ``timeout_s`` and raises
    :class:`~eaglemission.errors.GrabTimeout`, :class:`~eaglemission.errors.CameraLost`,
    :class:`~eaglemission.errors.EndOfStream` or :class:`~eaglemission.errors.FrameError`;
    it never returns a half-written frame. ``close`` is idempotent. Cameras are context managers.
    """

    camera_id: str
    model: CameraModel

    def open(self) -> None: ...

    def close(self) -> None: ...

    def grab(self, *, timeout_s: float) -> Frame: ...
