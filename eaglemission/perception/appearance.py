"""The target's appearance, modelled once from the mission file's ``target`` section and handed
to every stage that needs it (not in the paper; docs/architecture.md, "Perception").

Two descriptions of one appearance, each from what the target section gives:

- **colour model** of ``target.appearance_image`` (an example photo: a tight crop, or the target
  on a plain background): a 4096-bin colour histogram over a span of exposure gains
  (:mod:`.histogram`). The appearance prior stage (:mod:`.prior`) back-projects it on each frame
  and re-ranks regions by their colour histogram's likeness to it.
- **chromaticity** of ``target.color_bgr`` (the target's colour, when known): which detections
  have the target's colour (:meth:`TargetAppearance.colour_matches`, the target choice), the
  connected region of that colour near a pixel (:meth:`TargetAppearance.colour_region`: the
  whole silhouette at close range) and its outline (the shape check) (:mod:`.colour`).

Either may be absent; :class:`TargetAppearance` says what it can do (``has_model``,
``has_colour``) and the stages use what is there.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from eaglemission.errors import ConfigError
from eaglemission.perception.colour import colour_blob, colour_matches, warm_up_colour_kernel
from eaglemission.perception.histogram import AppearanceModel, validate_example_image
from eaglemission.perception.prior import AppearancePrior, PriorConfig
from eaglemission.types import Detection, Frame


class ColourConfig(BaseModel):
    """The target's colour region and colour check (need ``target.color_bgr``)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    tolerance: float = Field(0.25, gt=0, le=2, description=(
        "largest L1 distance between a pixel's chromaticity (b, g, r) / (b + g + r) and the "
        "target's"))
    min_area_px: float = Field(200.0, gt=0, description="smallest colour region (frame px)")
    step: int = Field(2, ge=1, le=8, description="the colour region tests every step-th pixel")
    min_brightness: float = Field(60.0, ge=0, description=(
        "darker pixels (B + G + R) have no reliable colour and never belong to the region"))


class ExampleModelConfig(BaseModel):
    """The colour model of the example image and its match as a template (need
    ``target.appearance_image``)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    match_min_ncc: float | None = Field(0.6, gt=0, le=1, description=(
        "choosing among the detector's regions with no prediction of where the target is: "
        "the region where the example image itself matches best (normalised cross-"
        "correlation at its own scale, near the region's centre) when it matches at least "
        "this well; null: the detector's order"))

    target_fraction: float = Field(0.1, gt=0, le=1, description=(
        "fraction of the frame the target is expected to cover (the back-projection's prior)"))
    pool: bool = Field(False, description=(
        "pool every colour bin with its 26 neighbours (tolerance to shading; false: the 4096 "
        "bins as they are, finer colour discrimination)"))
    exposure_span: float = Field(1.5, ge=1, le=4, description=(
        "the model holds the example's histograms at exposure gains from 1/this to this; each "
        "frame uses the gain at which the example's colours are most present in it (1: the "
        "example's colours as they are)"))


class AppearanceConfig(BaseModel):
    """``appearance``: how the target's appearance (``target.color_bgr``,
    ``target.appearance_image``) is modelled, and the appearance prior stage after the
    detector."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    colour: ColourConfig = Field(default_factory=ColourConfig)
    example: ExampleModelConfig = Field(default_factory=ExampleModelConfig)
    prior: PriorConfig | None = Field(default_factory=PriorConfig, description=(
        "the appearance prior after the detector, when the target has an example image; "
        "null: the detector's map alone"))


MATCH_SIDE_PX = 48
"""The example's long side when matched as a template (larger examples are reduced, the frame
with them)."""


def example_ncc(image: NDArray[np.uint8], example: NDArray[np.uint8],
                centre_px: tuple[float, float]) -> float:
    """See :meth:`TargetAppearance.example_match`."""
    th, tw = example.shape[:2]
    k = min(1.0, MATCH_SIDE_PX / max(th, tw))
    margin = max(th, tw) // 2 + 4
    u0, v0 = int(centre_px[0] - tw / 2 - margin), int(centre_px[1] - th / 2 - margin)
    u1, v1 = u0 + tw + 2 * margin, v0 + th + 2 * margin
    u0, v0 = max(0, u0), max(0, v0)
    u1, v1 = min(image.shape[1], u1), min(image.shape[0], v1)
    if u1 - u0 < tw or v1 - v0 < th or image.ndim != 3:
        return -1.0
    window: NDArray[np.uint8] = image[v0:v1, u0:u1]
    template: NDArray[np.uint8] = example
    if k < 1.0:
        window = np.asarray(cv2.resize(window, None, fx=k, fy=k, interpolation=cv2.INTER_AREA),
                            np.uint8)
        template = np.asarray(cv2.resize(example, None, fx=k, fy=k,
                                         interpolation=cv2.INTER_AREA), np.uint8)
    if template.shape[0] > window.shape[0] or template.shape[1] > window.shape[1]:
        return -1.0
    ncc = cv2.matchTemplate(window, template, cv2.TM_CCOEFF_NORMED)
    return float(cv2.minMaxLoc(ncc)[1])


LOCATE_SIDE_PX = 24
"""The example's long side when looked for over the whole frame: half the local match's, so
the search over a 1280x960 frame costs a few milliseconds, not tens (bench_perception.py)."""

LOCATE_SCALES = (0.8, 1.0, 1.25)
"""The example's scales :func:`locate_example` tries (a target the example was cropped from,
a few frames on)."""


def locate_example(image: NDArray[np.uint8], example: NDArray[np.uint8],
                   side_px: int = LOCATE_SIDE_PX
                   ) -> tuple[tuple[float, float, float, float], float] | None:
    """See :meth:`TargetAppearance.locate_example` (the frame and the example reduced together
    so that the example's long side is at most ``side_px``)."""
    if image.ndim != 3:
        return None
    th, tw = example.shape[:2]
    k = min(1.0, side_px / max(th, tw))
    small: NDArray[np.uint8] = image if k == 1.0 else np.asarray(
        cv2.resize(image, None, fx=k, fy=k, interpolation=cv2.INTER_AREA), np.uint8)
    best: tuple[float, tuple[float, float, float, float]] | None = None
    for s in LOCATE_SCALES:
        w, h = max(3, round(tw * k * s)), max(3, round(th * k * s))
        if h > small.shape[0] or w > small.shape[1]:
            continue
        t = cv2.resize(example, (w, h), interpolation=cv2.INTER_AREA)
        ncc = cv2.matchTemplate(small, t, cv2.TM_CCOEFF_NORMED)
        _, peak, _, (u, v) = cv2.minMaxLoc(ncc)
        if best is None or peak > best[0]:
            # pixel edges: u - 0.5 reduced is u / k - 0.5 in the frame
            box = (u / k - 0.5, v / k - 0.5, (u + w) / k - 0.5, (v + h) / k - 0.5)
            best = (float(peak), box)
    return None if best is None else (best[1], best[0])


def read_example_image(path: str | Path, *, where: str = "target.appearance_image"
                       ) -> NDArray[np.uint8]:
    """The example image at ``path`` (BGR); :class:`ConfigError` naming ``where`` when it
    cannot be read."""
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise ConfigError(f"{where}: cannot read {str(path)!r} as an image")
    return validate_example_image(np.asarray(img, np.uint8))


class TargetAppearance:
    """What the target looks like: the example image's colour model and/or the target's
    chromaticity (see the module docstring). Synchronous, I/O-free after construction, safe to
    share between the cameras' perception threads (nothing in it changes after construction)."""

    def __init__(self, *, image: Any = None, colour_bgr: Any = None,
                 colour: ColourConfig | None = None,
                 example: ExampleModelConfig | None = None) -> None:
        self.colour_config = colour or ColourConfig()
        self.example_config = example or ExampleModelConfig()
        self.image = None if image is None else validate_example_image(image)
        self.model: AppearanceModel | None = None
        if self.image is not None:
            e = self.example_config
            self.model = AppearanceModel.from_image(
                self.image, prior=e.target_fraction, pool=e.pool, exposure_span=e.exposure_span)
        self.colour_bgr: tuple[float, float, float] | None = None
        if colour_bgr is not None:
            b, g, r = (float(v) for v in colour_bgr)
            self.colour_bgr = (b, g, r)
            warm_up_colour_kernel()  # compile / load now, not on the first close view

    @classmethod
    def of_target(cls, target: Any, config: AppearanceConfig | None = None) -> TargetAppearance:
        """From a mission file's ``target`` section (its image read from disk) and its
        ``appearance`` section."""
        cfg = config or AppearanceConfig()
        path = getattr(target, "appearance_image", None)
        image = read_example_image(path) if path else None
        return cls(image=image, colour_bgr=getattr(target, "color_bgr", None), colour=cfg.colour,
                   example=cfg.example)

    def example_match(self, image: NDArray[np.uint8], centre_px: tuple[float, float]
                      ) -> float:
        """How well the example image itself matches the frame near ``centre_px``: the best
        normalised cross-correlation (TM_CCOEFF_NORMED) of the example at its own scale (its
        long side reduced to :data:`MATCH_SIDE_PX`, the frame with it) over a window of a
        template's size around the centre; -1 without an example or where it does not fit."""
        if self.image is None:
            return -1.0
        return example_ncc(image, self.image, centre_px)

    def locate_example(self, image: NDArray[np.uint8]
                       ) -> tuple[tuple[float, float, float, float], float] | None:
        """Where the example image itself matches the whole frame best, at its own scale
        (x0.8, 1, 1.25): its box (u_min, v_min, u_max, v_max) and the normalised
        cross-correlation there; None without an example or when it does not fit the frame."""
        if self.image is None:
            return None
        return locate_example(image, self.image)

    def locate_example_near(self, image: NDArray[np.uint8],
                            box: tuple[float, float, float, float]
                            ) -> tuple[tuple[float, float, float, float], float] | None:
        """:meth:`locate_example` within a window around ``box`` (its size again on every
        side): where a candidate seen in an earlier frame is now, scored as
        :meth:`example_match` scores (the example at its own scale, not the box's)."""
        if self.image is None or image.ndim != 3:
            return None
        u0, v0, u1, v1 = box
        w, h = u1 - u0, v1 - v0
        th, tw = self.image.shape[:2]
        pad_u, pad_v = max(w, tw), max(h, th)
        x0, y0 = max(0, int(u0 - pad_u)), max(0, int(v0 - pad_v))
        x1 = min(image.shape[1], int(math.ceil(u1 + pad_u)))
        y1 = min(image.shape[0], int(math.ceil(v1 + pad_v)))
        window = np.ascontiguousarray(image[y0:y1, x0:x1])
        k = min(1.0, MATCH_SIDE_PX / max(th, tw))
        if window.shape[0] < th * k or window.shape[1] < tw * k:
            return None
        found = locate_example(window, self.image, side_px=MATCH_SIDE_PX)
        if found is None:
            return None
        (a, b, c, d), score = found
        return (a + x0, b + y0, c + x0, d + y0), score

    def with_prior(self, detector: Any, prior: PriorConfig | None) -> Any:
        """``detector`` followed by the appearance prior (``prior``; None: the detector alone,
        as without an example image)."""
        if prior is None or self.model is None:
            return detector
        return AppearancePrior(detector, self.model, prior)

    @property
    def has_model(self) -> bool:
        """An example image gave a colour model (the appearance prior can run)."""
        return self.model is not None

    @property
    def has_colour(self) -> bool:
        """The target's colour is known (colour check, colour region, shape check)."""
        return self.colour_bgr is not None

    @property
    def known(self) -> bool:
        return self.has_model or self.has_colour

    def colour_matches(self, frame: Frame, detection: Detection) -> bool:
        """The detection's core has the target's chromaticity (True when the colour is not
        known: nothing to check)."""
        if self.colour_bgr is None:
            return True
        return colour_matches(frame.image, detection, self.colour_bgr,
                              self.colour_config.tolerance)

    def colour_region(self, frame: Frame, near_px: tuple[float, float]) -> Detection | None:
        """The connected region of the target's colour nearest ``near_px`` (None: no colour
        known, or no region large enough)."""
        if self.colour_bgr is None:
            return None
        c = self.colour_config
        det: Detection | None = colour_blob(frame.image, self.colour_bgr, c.tolerance, near_px,
                                            min_area_px=c.min_area_px, step=c.step,
                                            min_brightness=c.min_brightness,
                                            camera_id=frame.camera_id)
        return det

    def summary(self) -> str:
        parts = []
        if self.image is not None:
            h, w = self.image.shape[:2]
            parts.append(f"colour model of a {w}x{h} example image")
        if self.colour_bgr is not None:
            parts.append("colour " + "/".join(f"{v:.0f}" for v in self.colour_bgr) + " (BGR)")
        return ", ".join(parts) or "unknown"
