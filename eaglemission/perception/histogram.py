"""The colour model of an example image of the target (beyond the paper): the model part of
:class:`~eaglemission.perception.appearance.TargetAppearance`.

An example image (a BGR uint8 array: a tight crop, or a photo on a plain background) becomes a
colour model on 4096 colour bins (4 bits per channel, :mod:`.colour_bins`), back-projected on a
frame as a per-bin look-up table: one table per frame and one look-up per pixel.

1. **Target histogram** ``q``: the example's pixels, each weighted by an Epanechnikov kernel over
   the image (centre 1, edges 0: a tight box holds background at its border) times a background
   weight that removes the colours of the image's border (a photo on a plain background, the
   background around a cropped target): a bin more common in the border than in the
   kernel-weighted centre is weighted by ``centre(b) / border(b)`` (after Comaniciu et al.'s
   background-weighted histogram); a uniform example keeps every weight. Bins may be pooled
   with their 26 neighbours (tolerance to shading and white balance) and ``q`` sums to 1.
   With an exposure span ``s`` > 1, the model holds one such histogram per gain from ``1/s`` to
   ``s`` (the example scaled, saturating at 255 as a camera does): a 4-bit bin is 16 levels
   wide, so a red of 200 leaves its bin at a gain of 0.92 and the example's colours alone miss
   the target under other light. Per frame, :meth:`AppearanceModel.select` picks the gain at
   which the example's colours are most present in the frame (docs/detectors.md, "Exposure").
2. **Back-projection** on a frame with colour histogram ``p`` (sums to 1, pooled the same way):
   ``A(b) = q(b) / (q(b) + p(b) / prior)``, the posterior probability that a pixel of colour
   ``b`` belongs to the target when the target covers a fraction ``prior`` of the frame (Bayes
   with ``p`` standing for the background's colour distribution). Colours absent from the example
   give 0; a colour of the example that is rare in the frame gives nearly 1; one that covers the
   frame (the ground) gives nearly 0 whatever the example says. ``A`` is absolute, in [0, 1], so
   "the target's colours are not in view" stays dark.

References
----------
M. J. Swain, D. H. Ballard, "Color indexing", IJCV 7(1), 1991, DOI 10.1007/BF00130487
(histogram back-projection).
D. Comaniciu, V. Ramesh, P. Meer, "Kernel-based object tracking", IEEE TPAMI 25(5), 2003,
DOI 10.1109/TPAMI.2003.1195991 (kernel-weighted and background-weighted histograms).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from eaglemission.errors import InputError
from eaglemission.perception.colour_bins import NBINS, pool_colour_bins, quantize_bgr

#: Fraction of the example's width (height) on each side whose colours count as background.
BORDER_FRACTION = 0.15
#: Largest ratio between consecutive gains of an exposure span (a bright channel of 240 moves
#: 12 levels, under one 16-level bin, from one gain to the next).
EXPOSURE_STEP = 1.05
#: A frame switches the model away from gain 1 only when another gain finds this many times
#: more of the example's colours in it (:meth:`AppearanceModel.select`).
EXPOSURE_SWITCH = 1.5


def validate_example_image(image: Any) -> NDArray[np.uint8]:
    """An example image as a contiguous BGR uint8 (H, W, 3) copy; grey (H, W) becomes
    3-channel; anything else raises :class:`InputError` naming the problem."""
    if not isinstance(image, np.ndarray):
        raise InputError(f"appearance image: must be a BGR uint8 numpy array, got "
                         f"{type(image).__name__}")
    if image.dtype != np.uint8:
        raise InputError(f"appearance image: must be uint8 (8-bit BGR or grey), got {image.dtype}")
    if image.ndim == 2:
        image = np.repeat(image[:, :, None], 3, axis=2)
    if image.ndim != 3 or image.shape[2] != 3:
        raise InputError(f"appearance image: must be (H, W, 3) BGR or (H, W) grey, got shape "
                         f"{image.shape}")
    if image.shape[0] < 3 or image.shape[1] < 3:
        raise InputError(f"appearance image: must be at least 3x3 pixels, got "
                         f"{image.shape[1]}x{image.shape[0]}")
    out: NDArray[np.uint8] = np.ascontiguousarray(image).copy()
    return out


def kernel_weights(height_px: int, width_px: int) -> NDArray[np.float64]:
    """Epanechnikov profile ``max(0, 1 - r^2)`` with ``r`` the pixel centre's normalised distance
    to the image centre (1 at the middle of each edge)."""
    v = (np.arange(height_px) - (height_px - 1) / 2.0) / (height_px / 2.0)
    u = (np.arange(width_px) - (width_px - 1) / 2.0) / (width_px / 2.0)
    return np.maximum(0.0, 1.0 - (v[:, None] ** 2 + u[None, :] ** 2))


def border_mask(height_px: int, width_px: int,
                fraction: float = BORDER_FRACTION) -> NDArray[np.bool_]:
    """Pixels within ``fraction`` of the width (height) of the image's edges (at least 1 px)."""
    bh = max(1, int(round(fraction * height_px)))
    bw = max(1, int(round(fraction * width_px)))
    m = np.zeros((height_px, width_px), bool)
    m[:bh] = m[-bh:] = True
    m[:, :bw] = m[:, -bw:] = True
    return m


def target_histogram(image: NDArray[np.uint8], *, pool: bool = True,
                     border_fraction: float = BORDER_FRACTION) -> NDArray[np.float64]:
    """Kernel- and background-weighted colour histogram of an example image (4096 bins, sums to 1).

    Parameters
    ----------
    image : ndarray of shape (H, W, 3), uint8 BGR
    pool : bool
        Pool every bin with its 26 neighbouring colours.
    border_fraction : float
        Width of the border whose colours are taken as background (0: no background weighting).

    Returns
    -------
    ndarray of shape (4096,), float64, sums to 1 (all zeros if every weight vanished).
    """
    h, w = image.shape[:2]
    idx = quantize_bgr(image).ravel()
    k = kernel_weights(h, w).ravel()
    q = np.asarray(np.bincount(idx, weights=k, minlength=NBINS), np.float64)
    if border_fraction > 0 and min(h, w) >= 3:
        border = border_mask(h, w, border_fraction).ravel()
        bg = np.bincount(idx[border], minlength=NBINS).astype(np.float64)
        centre = q.copy()
        if pool:
            bg, centre = pool_colour_bins(bg), pool_colour_bins(centre)
        if bg.sum() > 0 and centre.sum() > 0:
            bg /= bg.sum()
            centre /= centre.sum()
            # a colour more common at the border than at the (kernel-weighted) centre is
            # background: weight centre / border; a uniform example keeps every weight
            keep = np.ones(NBINS)
            np.divide(centre, bg, out=keep, where=bg > centre)
            q *= keep
    if pool:
        q = pool_colour_bins(q)
    total = q.sum()
    return q / total if total > 0 else q


def exposure_gains(span: float, step: float = EXPOSURE_STEP) -> NDArray[np.float64]:
    """Gains from ``1/span`` to ``span``, geometric, 1 included, consecutive ratios <= ``step``
    (``[1.0]`` for a span of 1)."""
    if not span >= 1:
        raise ValueError(f"exposure span: must be >= 1, got {span}")
    half = int(np.ceil(np.log(span) / np.log(step) - 1e-9)) if span > 1 else 0
    return np.geomspace(1.0 / span, span, 2 * half + 1) if half else np.ones(1)


def exposure_histograms(image: NDArray[np.uint8], span: float, *, pool: bool = True,
                        border_fraction: float = BORDER_FRACTION) -> NDArray[np.float64]:
    """(G, 4096) :func:`target_histogram` of the example scaled by each of
    :func:`exposure_gains` (``span``), saturating at 255 like a camera's pixel values."""
    def scaled(gain: float) -> NDArray[np.uint8]:
        if gain == 1.0:
            return image
        return np.asarray(cv2.convertScaleAbs(image, alpha=gain), dtype=np.uint8)

    return np.stack([target_histogram(scaled(float(g)), pool=pool, border_fraction=border_fraction)
                     for g in exposure_gains(span)])


def frame_histogram(hist: ArrayLike, *, pool: bool = True) -> NDArray[np.float64]:
    """A frame's 4096-bin colour counts (e.g. the static cue's sampled histogram), pooled like
    :func:`target_histogram` and normalised to sum 1."""
    p = np.asarray(hist, np.float64)
    if pool:
        p = pool_colour_bins(p)
    total = p.sum()
    return p / total if total > 0 else p


def appearance_posterior(q: NDArray[np.floating], p: NDArray[np.floating],
                         prior: float) -> NDArray[np.float32]:
    """Per-bin back-projection ``A(b) = q(b) / (q(b) + p(b) / prior)`` in [0, 1].

    Parameters
    ----------
    q : ndarray of shape (B,)
        Target colour distribution (sums to 1).
    p : ndarray of shape (B,)
        The frame's colour distribution (sums to 1).
    prior : float
        Fraction of the frame the target is expected to cover (> 0).

    Returns
    -------
    ndarray of shape (B,), float32; 0 where ``q`` is 0.
    """
    if not prior > 0:
        raise ValueError(f"prior: must be > 0, got {prior}")
    q = np.asarray(q, np.float64)
    den = q + np.asarray(p, np.float64) / prior
    a = np.divide(q, den, out=np.zeros_like(q), where=den > 0)
    posterior: NDArray[np.float32] = a.astype(np.float32)
    return posterior


@dataclass(frozen=True)
class AppearanceModel:
    """The colour model of an example image.

    ``q_exposures`` holds one histogram per exposure gain (:func:`exposure_histograms`; one row
    without an exposure span); ``select(frame_hist)`` picks the gain for a frame,
    ``lut(frame_hist, k)`` back-projects gain ``k``'s histogram and ``match(region_hist, k)``
    scores a region's colours against it. ``q`` is gain 1's histogram."""

    q_exposures: NDArray[np.float64]
    prior: float = 0.01
    pool: bool = True
    unit: int = field(init=False)
    _sqrt_q: NDArray[np.float64] = field(init=False, repr=False)
    _prior_q: NDArray[np.float64] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        qs = np.atleast_2d(np.asarray(self.q_exposures, np.float64))
        object.__setattr__(self, "q_exposures", qs)
        object.__setattr__(self, "unit", len(qs) // 2)  # exposure_gains is symmetric about 1
        object.__setattr__(self, "_sqrt_q", np.sqrt(qs))
        object.__setattr__(self, "_prior_q", self.prior * qs)

    @classmethod
    def from_image(cls, image: Any, *, prior: float = 0.01, pool: bool = True,
                   border_fraction: float = BORDER_FRACTION,
                   exposure_span: float = 1.0) -> AppearanceModel:
        if image is None:
            raise InputError("appearance: no image given")
        img = validate_example_image(image)
        if not 1.0 <= exposure_span <= 4.0:
            raise InputError(f"appearance exposure span: must be in [1, 4], got {exposure_span}")
        return cls(exposure_histograms(img, exposure_span, pool=pool,
                                       border_fraction=border_fraction), prior, pool)

    @property
    def q(self) -> NDArray[np.float64]:
        """(4096,) gain 1's colour model (sums to 1)."""
        q: NDArray[np.float64] = self.q_exposures[self.unit]
        return q

    def select(self, frame_hist: ArrayLike) -> int:
        """The exposure (row of ``q_exposures``) for a frame with these bin counts: the gain
        whose histogram finds most of itself in the frame, ``sum_b min(prior q_g(b), p(b))``
        (the part of a target covering ``prior`` of the frame that the frame's colours can
        hold), gain 1 unless another finds :data:`EXPOSURE_SWITCH` times more."""
        if len(self.q_exposures) == 1:
            return 0
        p = frame_histogram(frame_hist, pool=self.pool)
        found = np.minimum(self._prior_q, p).sum(axis=1)
        best = int(np.argmax(found))
        return best if found[best] > EXPOSURE_SWITCH * found[self.unit] else self.unit

    def lut(self, frame_hist: ArrayLike, exposure: int | None = None) -> NDArray[np.float32]:
        """(4096,) float32 posterior per colour bin for a frame with these bin counts, with the
        model at ``exposure`` (a row of ``q_exposures``; None: gain 1)."""
        q = self.q if exposure is None else self.q_exposures[exposure]
        return appearance_posterior(q, frame_histogram(frame_hist, pool=self.pool), self.prior)

    def match(self, region_hist: NDArray[np.floating], exposure: int | None = None) -> float:
        """Bhattacharyya coefficient of a region's colour distribution (sums to 1, pooled as
        this model) and the example's at ``exposure`` (None: gain 1)."""
        k = self.unit if exposure is None else exposure
        return float(self._sqrt_q[k] @ np.sqrt(np.asarray(region_hist, np.float64)))

    def back_project(self, image: NDArray[np.uint8], frame_hist: ArrayLike | None = None
                     ) -> NDArray[np.float32]:
        """The (H, W) posterior map of a BGR frame at the frame's :meth:`select`-ed exposure
        (plain numpy; the detector uses :meth:`lut` with its own look-up)."""
        idx = quantize_bgr(image)
        counts = np.bincount(idx.ravel(), minlength=NBINS) if frame_hist is None else frame_hist
        return self.lut(counts, self.select(counts))[idx]


def region_histogram(image: NDArray[np.uint8], corners_px: NDArray[np.floating], *,
                     pool: bool = True) -> NDArray[np.float64]:
    """Colour histogram (4096 bins, pooled like :func:`target_histogram`, sums to 1) of the
    pixels inside the axis-aligned bounding box of a region's corners (all zeros if empty)."""
    h, w = image.shape[:2]
    c = np.asarray(corners_px, np.float64)
    u0, v0 = max(0, int(np.ceil(c[:, 0].min()))), max(0, int(np.ceil(c[:, 1].min())))
    u1, v1 = min(w, int(np.floor(c[:, 0].max())) + 1), min(h, int(np.floor(c[:, 1].max())) + 1)
    if u1 <= u0 or v1 <= v0:
        return np.zeros(NBINS)
    hist = np.bincount(quantize_bgr(image[v0:v1, u0:u1]).ravel(), minlength=NBINS)
    return frame_histogram(hist, pool=pool)
