"""Plane-fitter role (entry-point group ``eaglemission.fitters``)."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy.typing as npt

from eaglemission.interfaces.estimator import CameraView
from eaglemission.types import Detection, PlaneFit


@runtime_checkable
class PlaneFitter(Protocol):
    """Refines a detection into a target position on the plane of the target's top face.

    Construction: ``cls(config=<cls.Config instance>, target=TargetConfig, **context)``.
    ``fit`` is synchronous and I/O-free. ``plane_down_m`` is the down coordinate (NED, the
    vehicle's estimated frame) of the ground the target stands on; ``yaw_hint_deg`` and
    ``region_hint`` (from an earlier complete view) restrict the hypotheses of a view cut by
    the image border, the headings to +-``yaw_hint_span_deg`` around the hint (None: the
    fitter's own step). With ``silhouette``, a fit of a whole view of a detection that carries
    its outline (``hull_px``) also measures ``PlaneFit.silhouette_iou``. ``occluder_px``, a
    convex image polygon of something nearer than the target (the arm's tool), hides part of
    the target: the detection stops at it, so the fitted models must too. Returns None when no
    hypothesis projects (misuse raises ``ValueError``).
    """

    def fit(self, detection: Detection, view: CameraView, *, plane_down_m: float,
            yaw_hint_deg: float | None = None, region_hint: str | None = None,
            iterations: int = 4, silhouette: bool = False,
            yaw_hint_span_deg: float | None = None,
            occluder_px: npt.ArrayLike | None = None) -> PlaneFit | None: ...
