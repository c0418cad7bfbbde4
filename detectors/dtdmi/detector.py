"""The DTDMI detector plugin (``dtdmi``): static cluster saliency x midbrain dynamic map.

``S = S_s x S_M`` (Eq. (15) of [1]) with S_s from :mod:`.static` (Eqs. (1)-(6)) and S_M from
:mod:`.dynamic` (Eqs. (7)-(14)). Four presets:

- ``literal``: the equations as printed (1/d^2 spatial cue, raw Eq. (13) maps averaged over
  scales by Eq. (14), map = S / max S). Reproduces the paper's method; near-binary maps.
- ``default``: measured improvements (docs/paper_choices.md, "DTDMI"): per-scale normalisation
  and dynamic-range compression of S_M, Gaussian centre weight for the spatial cue, smoothing.
- ``field``: a target static on the ground seen from a moving UAV (docs/paper_choices.md,
  "field preset"): S_s in Reinhard's l-alpha-beta (chromatic distances), Eq. (2) per colour
  bin, a spatial-compactness cue instead of the centre weighting of Eqs. (3)-(5), absolute
  scale, and Eq. (15) as ``S_s x (1 + gain x S_M)`` so the dynamic map boosts, not gates.
- ``aerial``: real aerial video (docs/paper_choices.md, "aerial preset; real footage, round
  2"): S_s adds to the field colour cue Eq. (2) read per pixel block
  (:func:`.equations.block_contrast_cue`), S_M aligns the delay units to the camera's motion
  (homography), Eq. (15) is ``max(S_s, gain x S_M)``, and the regions use the adaptive
  threshold.

The ``default`` preset also blends the final map with its mean per colour bin
(``colour_propagation``, :mod:`.refine`). An example image of the target (context
``appearance``, :mod:`eaglemission.detectors.appearance`) adds its colour back-projection ``A``:
``S <- A + appearance_saliency_weight x S``; the regions are then re-ranked by colour histogram
and, with ``appearance_track_weight`` > 0, the map is first attenuated away from the previous
frame's best detection.

Every preset-dependent knob is a config field whose ``None`` means "as the preset says".

References
----------
.. [1] Eagle-eye inspired target detection (DTDMI), Sec. 2. DOI unknown.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, ClassVar

import cv2
import numpy as np
from eaglemission.detectors.base import SaliencyDetector
from eaglemission.detectors.dtdmi.config import DTDMIConfig
from eaglemission.detectors.dtdmi.engine import DTDMIEngine
from eaglemission.detectors.dtdmi.refine import spotlight_factors, spotlit_saliency
from eaglemission.detectors.regions import find_regions, reduced_prior, to_frame_pixels

from eaglemission.types import Detection, DetectionResult, Frame, Saliency, TargetPrior


def appearance_rerank(dets: tuple[Detection, ...], image: np.ndarray, model: Any,
                      gamma: float, keep: int, exposure: int | None = None
                      ) -> tuple[Detection, ...]:
    """Detections re-ranked by ``score x BC^gamma`` (BC: the Bhattacharyya coefficient of the
    region's colour histogram, pooled as the model's, and the example's at the frame's
    ``exposure``, :meth:`..appearance.AppearanceModel.match`), the best ``keep``, that
    product as their score (:mod:`eaglemission.detectors.appearance`); ``image`` at the
    detections' resolution."""
    from eaglemission.detectors.appearance import region_histogram

    def bc(d: Detection) -> float:
        return float(model.match(region_histogram(image, d.corners_px, pool=model.pool),
                                 exposure))

    ranked = sorted(((d.score * bc(d) ** gamma, k) for k, d in enumerate(dets)), reverse=True)
    return tuple(replace(dets[k], score=float(s)) for s, k in ranked[:keep])


class DTDMIDetector(SaliencyDetector):
    """DTDMI: static cluster saliency x eagle-midbrain dynamic map (Eqs. (1)-(15) of [1])."""

    Config: ClassVar[type[DTDMIConfig]] = DTDMIConfig
    description: ClassVar[str] = (
        "DTDMI: static cluster saliency x eagle-midbrain dynamic perception (paper Sec. 2)")

    def __init__(self, config: DTDMIConfig | None = None, **context: Any) -> None:
        super().__init__(config, **context)
        self.engine = DTDMIEngine(self.config)
        if self.engine.numba:
            self._warm_up()
        #: centre (u, v) of the previous frame's best detection (with an appearance image)
        self.track_px: tuple[float, float] | None = None
        if self.appearance is not None:
            from eaglemission.detectors.appearance import AppearanceModel

            self.engine.set_appearance(AppearanceModel.from_image(
                self.appearance, prior=self.config.appearance_prior,
                pool=self.engine.r.appearance_pool,
                exposure_span=self.engine.r.appearance_exposure_span))

    def detect(self, frame: Frame, prior: TargetPrior | None = None) -> DetectionResult:
        """Regions of the map. With an appearance image: the map is attenuated away from the
        previous frame's best detection (``appearance_track_weight``,
        :func:`.refine.spotlit_saliency`), and the ``appearance_candidates`` best regions are
        re-ranked by ``score x BC^appearance_rank_exponent`` (their colour histogram against
        the example's, :meth:`..appearance.AppearanceModel.match`) and
        ``regions.max_detections`` kept, with that product as their score. With ``downscale``
        > 1 (and no colour propagation) all of this runs on the map at the processing
        resolution, which has no finer detail than that, and the detections are mapped to the
        frame's pixels (:func:`..regions.to_frame_pixels`); the map is upsampled for the
        result."""
        model = self.engine.appearance
        if model is None:
            return super().detect(frame, prior)
        image = self._frame_image(frame)
        h, w = image.shape[:2]
        # the map, following and regions at the processing resolution (the map has no finer
        # detail: it is upsampled once, for the result); the detections in frame pixels
        native = self.config.downscale > 1 and self.engine.r.colour_propagation == 0
        sal = self.engine.saliency(image, frame.timestamp_ns, native)
        sx, sy = w / sal.shape[1], h / sal.shape[0]
        track = None if self.track_px is None else (
            (self.track_px[0] - (sx - 1) / 2) / sx, (self.track_px[1] - (sy - 1) / 2) / sy)
        sal = self.follow(sal, track)
        cfg = self.config.regions
        r = self.engine.r
        update: dict[str, Any] = {"min_area_px": cfg.min_area_px / (sx * sy)}
        if r.appearance_peak_fraction is not None:
            update["peak_fraction"] = r.appearance_peak_fraction
        if r.appearance_floor is not None:
            update["adaptive_floor"] = r.appearance_floor
        gamma = r.appearance_rank_exponent
        if gamma > 0:
            update["max_detections"] = max(cfg.max_detections, self.config.appearance_candidates)
        wide = cfg.model_copy(update=update)
        dets, threshold = find_regions(sal, wide, reduced_prior(prior, sx, sy),
                                       camera_id=frame.camera_id)
        if gamma > 0:
            colours = self.engine.work if native and self.engine.work is not None else image
            dets = appearance_rerank(dets, colours, model, gamma, cfg.max_detections,
                                     self.engine.exposure)
        kept = tuple(to_frame_pixels(d, sx, sy) for d in dets) if native else dets
        self.track_px = kept[0].center_px if kept else None
        if native:
            sal = np.asarray(cv2.resize(sal, (w, h), interpolation=cv2.INTER_LINEAR),
                             dtype=np.float32)
        return DetectionResult(sal, kept, frame.timestamp_ns, frame.camera_id, frame.seq,
                               threshold)

    def follow(self, sal: Saliency, track_px: tuple[float, float] | None) -> Saliency:
        """``sal`` attenuated away from ``track_px`` (the previous best detection) by
        ``appearance_track_weight`` (:func:`.refine.spotlit_saliency`); unchanged without a
        previous detection or with the weight 0."""
        weight = self.engine.r.appearance_track_weight
        if track_px is None or weight == 0:
            return sal
        h, w = sal.shape
        sigma = self.config.appearance_track_sigma_frac * float(np.hypot(h, w))
        if not self.engine.numba:
            return spotlit_saliency(sal, track_px, sigma, weight)
        from eaglemission.detectors.dtdmi.kernels_general import spotlight

        g_rows, g_cols, keep = spotlight_factors(sal.shape, track_px, sigma, weight)
        # in place: the engine's map is a new array every frame (a fresh full-resolution plane
        # costs ~1 ms of page faults at 1280x960)
        out = sal if sal.flags.writeable and sal.flags.c_contiguous else sal.copy()
        spotlight(out, g_rows, g_cols, float(keep), out)
        return out

    def _warm_up(self) -> None:
        """Compile (or load from numba's cache) every kernel now, not on the first real frame."""
        rng = np.random.RandomState(0)
        for k in range(2):
            img = rng.randint(0, 256, (32, 32, 3)).astype(np.uint8)
            self.engine.saliency(img, 1_000_000_000 + k * 33_000_000)
        self.engine.reset()

    def _reset(self) -> None:
        self.engine.reset()
        self.track_px = None

    def _saliency(self, image: np.ndarray, frame: Frame) -> Saliency:
        return self.engine.saliency(image, frame.timestamp_ns)
