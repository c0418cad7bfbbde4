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
(``colour_propagation``, :mod:`.refine`).

Every preset-dependent knob is a config field whose ``None`` means "as the preset says".

References
----------
.. [1] Eagle-eye inspired target detection (DTDMI), Sec. 2. DOI unknown.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from eaglemission.detectors.base import SaliencyDetector
from eaglemission.detectors.dtdmi.config import DTDMIConfig
from eaglemission.detectors.dtdmi.engine import DTDMIEngine

from eaglemission.types import Frame, Saliency


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

    def saliency_map(self, frame: Frame) -> Saliency:
        """The map alone at the processing resolution (1/``downscale`` of the frame's; the
        frame's with colour propagation, which reads it): for a stage that combines maps
        (the appearance prior)."""
        image = self._frame_image(frame)
        native = self.config.downscale > 1 and self.engine.r.colour_propagation == 0
        return self.engine.saliency(image, frame.timestamp_ns, native)

    def _warm_up(self) -> None:
        """Compile (or load from numba's cache) every kernel now, not on the first real frame."""
        rng = np.random.RandomState(0)
        for k in range(2):
            img = rng.randint(0, 256, (32, 32, 3)).astype(np.uint8)
            self.engine.saliency(img, 1_000_000_000 + k * 33_000_000)
        self.engine.reset()

    def _reset(self) -> None:
        self.engine.reset()

    def _saliency(self, image: np.ndarray, frame: Frame) -> Saliency:
        return self.engine.saliency(image, frame.timestamp_ns)
