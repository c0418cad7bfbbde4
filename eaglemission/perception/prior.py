"""The appearance prior (not in the paper): any detector's saliency map combined with the colour
model of the target's example image, a stage of its own after the detector.

Per frame, at the stage's processing resolution (the frame reduced by ``downscale``):

1. ``A``: the example's colour model back-projected on the frame at the frame's exposure
   (:meth:`~eaglemission.perception.histogram.AppearanceModel.lut`): the probability that a
   pixel of that colour is the target's, in [0, 1], lightly smoothed (:data:`A_SMOOTH_FRAC`).
2. ``M = (A + w S) / (1 + w)``: ``S`` the detector's map in [0, 1], ``w`` =
   ``saliency_weight``. The detector finds what stands out; the model says which of it has
   the target's colours.
3. Following: ``M`` attenuated away from the previous frame's best detection,
   ``M x ((1 - a) + a G)`` with ``G`` a Gaussian of ``follow_sigma_frac`` of the diagonal
   (:func:`spotlit_saliency`; ``a`` = ``follow_weight``, 0: off).
4. Regions (:func:`~eaglemission.perception.regions.find_regions`, ``regions``), the
   ``candidates`` best re-ranked by ``score x BC^rank_exponent`` (BC: the Bhattacharyya
   coefficient of a region's colour histogram and the example's), ``regions.max_detections``
   kept, in frame pixels.

Without an example image the stage is not built and the detector runs alone.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from eaglemission.errors import InputError
from eaglemission.perception.colour_bins import NBINS, quantize_bgr
from eaglemission.perception.histogram import AppearanceModel, region_histogram
from eaglemission.perception.regions import (
    RegionsConfig,
    find_regions,
    reduced_prior,
    to_frame_pixels,
)
from eaglemission.types import Detection, DetectionResult, Frame, Saliency, TargetPrior

A_SMOOTH_FRAC = 0.003
"""Sigma of the Gaussian smoothing of the back-projection, fraction of the image diagonal
(per-pixel colour is noisy; a region's pixels should agree)."""
HIST_STEP = 4
"""The frame's colour histogram counts every HIST_STEP-th pixel in both directions."""


def _default_regions() -> RegionsConfig:
    return RegionsConfig(threshold="adaptive", adaptive_floor=40, peak_fraction=0.7,
                         max_aspect=5.0)


class PriorConfig(BaseModel):
    """``appearance.prior``: the appearance prior stage after the detector."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    saliency_weight: float = Field(2.0, ge=0, le=100, description=(
        "w in M = (A + w S) / (1 + w): the detector's map against the back-projection"))
    rank_exponent: float = Field(8.0, ge=0, le=32, description=(
        "regions re-ranked by score x BC^this (BC: Bhattacharyya coefficient of the region's "
        "colour histogram and the example's); 0: not re-ranked"))
    candidates: int = Field(12, ge=1, le=100, description="regions re-ranked before keeping "
                                                          "regions.max_detections")
    follow_weight: float = Field(0.0, ge=0, le=1, description=(
        "the map attenuated away from the previous frame's best detection by this much "
        "(0: off)"))
    follow_sigma_frac: float = Field(0.1, gt=0, le=1, description=(
        "sigma of the following Gaussian, fraction of the image diagonal"))
    downscale: int = Field(2, ge=1, le=8, description="processed at 1/downscale resolution")
    regions: RegionsConfig = Field(default_factory=_default_regions)


def combined_map(a: NDArray[np.float32], s: NDArray[np.float32], weight: float
                 ) -> NDArray[np.float32]:
    """``M = (A + w S) / (1 + w)``, in [0, 1] when both maps are."""
    out = np.multiply(s, np.float32(weight), dtype=np.float32)
    out += a
    out *= np.float32(1.0 / (1.0 + weight))
    return out


def spotlight_factors(shape: tuple[int, ...], centre_px: tuple[float, float], sigma_px: float,
                      strength: float) -> tuple[NDArray[np.float32], NDArray[np.float32],
                                                np.float32]:
    """The separable factors of :func:`spotlit_saliency`'s weight ``(1 - a) + a G``:
    ``(a x G_rows, G_cols, 1 - a)`` (float32), so that weight[v, u] = ``a G_rows[v] G_cols[u] +
    (1 - a)``."""
    _check_spotlight(sigma_px, strength)
    h, w = shape[0], shape[1]
    u0, v0 = centre_px
    k = -0.5 / (sigma_px * sigma_px)
    g_cols = np.exp(k * (np.arange(w) - u0) ** 2).astype(np.float32)
    g_rows = np.exp(k * (np.arange(h) - v0) ** 2).astype(np.float32)
    return g_rows * np.float32(strength), g_cols, np.float32(1.0 - strength)


def spotlit_saliency(sal: NDArray[np.floating], centre_px: tuple[float, float],
                     sigma_px: float, strength: float) -> NDArray[np.float32]:
    """The map attenuated away from ``centre_px``: ``sal x ((1 - a) + a G)``.

    ``G(u, v) = exp(-((u - u0)^2 + (v - v0)^2) / (2 sigma^2))``, 1 at the centre; ``a`` =
    ``strength`` in [0, 1] (0 returns ``sal`` unchanged, 1 keeps only the Gaussian window).

    Parameters
    ----------
    sal : ndarray of shape (H, W)
    centre_px : (u, v)
        Pixel coordinates (docs/conventions.md: u = column, v = row, pixel centres at integers).
    sigma_px : float
        > 0.
    strength : float
        In [0, 1].
    """
    _check_spotlight(sigma_px, strength)
    s = np.asarray(sal, np.float32)
    if strength == 0.0:
        return s.copy()
    g_rows, g_cols, keep = spotlight_factors(s.shape, centre_px, sigma_px, strength)
    weight = np.outer(g_rows, g_cols)
    weight += keep
    out: NDArray[np.float32] = s * weight
    return out


def _check_spotlight(sigma_px: float, strength: float) -> None:
    if not 0.0 <= strength <= 1.0:
        raise ValueError(f"strength: must be in [0, 1], got {strength}")
    if not sigma_px > 0:
        raise ValueError(f"sigma_px: must be > 0, got {sigma_px}")


def rerank(dets: tuple[Detection, ...], image: NDArray[np.uint8], model: AppearanceModel,
           exponent: float, keep: int, exposure: int | None = None) -> tuple[Detection, ...]:
    """Detections re-ranked by ``score x BC^exponent`` (BC of the region's colour histogram,
    pooled as the model's, and the example's at ``exposure``), the best ``keep``, that product
    as their score; ``image`` at the detections' resolution."""
    def bc(d: Detection) -> float:
        return model.match(region_histogram(image, d.corners_px, pool=model.pool), exposure)

    ranked = sorted(((d.score * bc(d) ** exponent, k) for k, d in enumerate(dets)), reverse=True)
    return tuple(replace(dets[k], score=float(s)) for s, k in ranked[:keep])


def sampled_colour_counts(bgr: NDArray[np.uint8], step: int = HIST_STEP) -> NDArray[np.int64]:
    """(4096,) colour-bin counts of every ``step``-th pixel in both directions."""
    counts: NDArray[np.int64] = np.bincount(quantize_bgr(bgr[::step, ::step]).ravel(),
                                            minlength=NBINS)
    return counts


def detector_map(detector: Any, frame: Frame, shape: tuple[int, int]) -> Saliency:
    """The detector's saliency map at ``shape`` (H, W): ``saliency_map(frame)`` when the detector
    offers it (its map alone, at its own processing resolution), else ``detect(frame)``'s map;
    resized (area average down, bilinear up)."""
    fn = getattr(detector, "saliency_map", None)
    sal = fn(frame) if callable(fn) else detector.detect(frame).saliency
    s = np.asarray(sal, dtype=np.float32)
    if s.ndim != 2:
        raise InputError(f"detector map: must be (H, W), got shape {s.shape}")
    if s.shape != shape:
        shrink = s.shape[0] > shape[0]
        s = np.asarray(cv2.resize(s, (shape[1], shape[0]), interpolation=cv2.INTER_AREA
                                  if shrink else cv2.INTER_LINEAR), dtype=np.float32)
    return s


class AppearancePrior:
    """A :class:`~eaglemission.interfaces.Detector` made of any detector and the target's colour
    model (the module docstring has the steps). Stateful per camera: the previous best
    detection."""

    def __init__(self, detector: Any, model: AppearanceModel, config: PriorConfig | None = None
                 ) -> None:
        self.detector = detector
        self.model = model
        self.config = config or PriorConfig()
        self.follow_px: tuple[float, float] | None = None
        """The previous frame's best detection's centre (processing-resolution pixels)."""

    @property
    def inner(self) -> Any:
        """The detector the prior wraps."""
        return self.detector

    def reset(self) -> None:
        self.detector.reset()
        self.follow_px = None

    def processing_image(self, image: NDArray[np.uint8]) -> NDArray[np.uint8]:
        k = self.config.downscale
        if k <= 1:
            return image
        h, w = image.shape[:2]
        small = cv2.resize(image, (max(8, w // k), max(8, h // k)), interpolation=cv2.INTER_AREA)
        out: NDArray[np.uint8] = np.ascontiguousarray(small)
        return out

    def back_projection(self, work: NDArray[np.uint8]) -> tuple[NDArray[np.float32], int]:
        """``A`` on the processing-resolution image, smoothed, and the exposure it used."""
        counts = sampled_colour_counts(work)
        exposure = self.model.select(counts)
        lut = self.model.lut(counts, exposure)
        a: NDArray[np.float32] = np.take(lut, quantize_bgr(work))
        sigma = A_SMOOTH_FRAC * math.hypot(*work.shape[:2])
        if sigma >= 0.3:
            a = np.asarray(cv2.GaussianBlur(a, (0, 0), sigma), np.float32)
        return a, exposure

    def detect(self, frame: Frame, prior: TargetPrior | None = None) -> DetectionResult:
        image = np.asarray(frame.image)
        if image.ndim != 3 or image.dtype != np.uint8:
            raise InputError(f"image: the appearance prior needs 8-bit BGR frames, got "
                             f"{image.dtype} {image.shape}")
        work = self.processing_image(image)
        s = detector_map(self.detector, frame, work.shape[:2])
        a, exposure = self.back_projection(work)
        return self.combine(frame, work, s, a, exposure, prior)

    def combine(self, frame: Frame, work: NDArray[np.uint8], s: Saliency,
                a: NDArray[np.float32], exposure: int, prior: TargetPrior | None = None
                ) -> DetectionResult:
        """Steps 2-4 of the module docstring on the processing-resolution image ``work``, the
        detector's map ``s`` and the back-projection ``a`` (both at ``work``'s resolution)."""
        cfg = self.config
        h, w = np.asarray(frame.image).shape[:2]
        hh, ww = work.shape[:2]
        m = combined_map(a, s, cfg.saliency_weight)
        if self.follow_px is not None and cfg.follow_weight > 0:
            m = spotlit_saliency(m, self.follow_px, cfg.follow_sigma_frac * math.hypot(hh, ww),
                                 cfg.follow_weight)
        sx, sy = w / ww, h / hh
        regions = cfg.regions
        update: dict[str, Any] = {"min_area_px": regions.min_area_px / (sx * sy)}
        if cfg.rank_exponent > 0:
            update["max_detections"] = max(regions.max_detections, cfg.candidates)
        dets, threshold = find_regions(m, regions.model_copy(update=update),
                                       reduced_prior(prior, sx, sy), camera_id=frame.camera_id)
        if cfg.rank_exponent > 0:
            dets = rerank(dets, work, self.model, cfg.rank_exponent, regions.max_detections,
                          exposure)
        self.follow_px = dets[0].center_px if dets else None
        kept = tuple(to_frame_pixels(d, sx, sy) for d in dets)
        full = m if (hh, ww) == (h, w) else np.asarray(
            cv2.resize(m, (w, h), interpolation=cv2.INTER_LINEAR), dtype=np.float32)
        return DetectionResult(full, kept, frame.timestamp_ns, frame.camera_id, frame.seq,
                               threshold)
