"""Tracker plugins (role ``trackers``): OpenCV's CSRT and KCF box trackers, on a reduced copy of
the frame (``scale``), behind :class:`~eaglemission.interfaces.Tracker`.

- ``csrt``: the discriminative correlation filter with channel and spatial reliability (Lukezic
  et al.), with scale estimation: it follows a target whose size changes.
- ``kcf``: the kernelised correlation filter (Henriques et al.): a fraction of CSRT's cost, a
  fixed box size.

References
----------
A. Lukezic, T. Vojir, L. Cehovin, J. Matas, M. Kristan, "Discriminative correlation filter with
channel and spatial reliability", CVPR 2017, DOI 10.1109/CVPR.2017.515.
J. F. Henriques, R. Caseiro, P. Martins, J. Batista, "High-speed tracking with kernelized
correlation filters", IEEE TPAMI 37(3), 2015, DOI 10.1109/TPAMI.2014.2345390.
"""

from __future__ import annotations

from typing import Any, ClassVar

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from eaglemission.errors import InputError
from eaglemission.interfaces.tracker import Box
from eaglemission.types import Frame

CV2: Any = cv2
"""OpenCV contrib's tracking module, untyped (its stubs lack the tracker factories)."""


class _TrackerConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    scale: float = Field(0.5, gt=0.05, le=1, description=(
        "the tracker runs on the frame reduced to this fraction (area average)"))


class OpenCVTracker:
    """Template: the frame reduced by ``scale``, the box converted between the conventions'
    pixel edges and OpenCV's (x, y, w, h) integer rectangles."""

    Config: ClassVar[type[BaseModel]] = _TrackerConfig
    description: ClassVar[str] = ""

    def __init__(self, config: Any = None, **_context: Any) -> None:
        self.config: Any = config if config is not None else self.Config()
        self._tracker: Any = None

    def _create(self) -> Any:
        raise NotImplementedError

    def _small(self, frame: Frame) -> np.ndarray:
        image = np.asarray(frame.image)
        if image.dtype != np.uint8 or image.ndim not in (2, 3):
            raise InputError(f"image: a tracker needs an 8-bit frame, got {image.dtype} "
                             f"{image.shape}")
        s = float(self.config.scale)
        if s == 1.0:
            return image
        return np.asarray(cv2.resize(image, None, fx=s, fy=s, interpolation=cv2.INTER_AREA))

    def start(self, frame: Frame, box_px: Box) -> None:
        s = float(self.config.scale)
        u0, v0, u1, v1 = box_px
        rect = (int(round((u0 + 0.5) * s)), int(round((v0 + 0.5) * s)),
                max(1, int(round((u1 - u0) * s))), max(1, int(round((v1 - v0) * s))))
        self._tracker = self._create()
        try:
            self._tracker.init(self._small(frame), rect)
        except cv2.error:  # a box OpenCV cannot model (e.g. too small once reduced): no track
            self._tracker = None

    def update(self, frame: Frame) -> Box | None:
        """The box in ``frame``; None when the target is lost, or when OpenCV's tracker fails
        on the frame (its model collapsed): a lost target the keeper looks for again."""
        if self._tracker is None:
            return None
        try:
            ok, (x, y, w, h) = self._tracker.update(self._small(frame))
        except cv2.error:
            ok, w, h = False, 0, 0
        if not ok or w <= 0 or h <= 0:
            self._tracker = None
            return None
        s = float(self.config.scale)
        return (x / s - 0.5, y / s - 0.5, (x + w) / s - 0.5, (y + h) / s - 0.5)


class CSRTConfig(_TrackerConfig):
    """Defaults chosen for the CPU budget (two cameras at 54 fps on one core): OpenCV's own
    (template 200, 33 scales, 4 iterations, segmentation) cost 30-40 ms per 1280x960 frame,
    these 3.5-6 ms, and kept the target as well on the tuning footage (docs/detectors.md,
    "Acquire and keep")."""

    template_size: int = Field(48, ge=16, le=400, description=(
        "side of the filter's template, pixels (smaller: faster, coarser; OpenCV's default 200)"))
    number_of_scales: int = Field(9, ge=1, le=65, description=(
        "scales searched per frame (OpenCV's default 33)"))
    admm_iterations: int = Field(2, ge=1, le=10, description=(
        "filter optimisation iterations (OpenCV's default 4)"))
    use_segmentation: bool = Field(False, description=(
        "the spatial reliability map (OpenCV's default on: about twice the cost)"))


class CSRTTracker(OpenCVTracker):
    """Plugin ``csrt``: OpenCV's CSRT."""

    Config: ClassVar[type[BaseModel]] = CSRTConfig
    description: ClassVar[str] = ("OpenCV CSRT: correlation filter with channel and spatial "
                                  "reliability, scale-adaptive")

    def _create(self) -> Any:
        c = self.config
        p = CV2.TrackerCSRT_Params()
        p.template_size = float(c.template_size)
        p.number_of_scales = int(c.number_of_scales)
        p.admm_iterations = int(c.admm_iterations)
        p.use_segmentation = bool(c.use_segmentation)
        return CV2.TrackerCSRT_create(p)


class KCFTracker(OpenCVTracker):
    """Plugin ``kcf``: OpenCV's KCF."""

    description: ClassVar[str] = "OpenCV KCF: kernelised correlation filter, fixed box size"

    def _create(self) -> Any:
        return CV2.TrackerKCF_create()
