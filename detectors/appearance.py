"""The target's appearance as a prior (beyond the paper): a colour model of an example image.

A detector may be given an example image of the target (``appearance``: a BGR uint8 array, a
tight crop or a photo on a plain background) through its constructor context. This module turns
it into a colour model on the same 4096 colour bins (4 bits per channel) as the static cue of
DTDMI (:mod:`eaglemission.detectors.dtdmi.static`), and back-projects it on a frame as a per-bin
look-up table, so it costs one table per frame and the look-up the static map already does.

1. **Target histogram** ``q``: the example's pixels, each weighted by an Epanechnikov kernel over
   the image (centre 1, edges 0: a tight box holds background at its border) times a background
   weight that removes the colours of the image's border (a photo on a plain background, the
   background around a cropped target): a bin more common in the border than in the
   kernel-weighted centre is weighted by ``centre(b) / border(b)`` (after Comaniciu et al.'s
   background-weighted histogram); a uniform example keeps every weight. Bins are pooled with their 26 neighbours (tolerance to shading
   and white balance) and ``q`` sums to 1.
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

from dataclasses import dataclass
from typing import Any

import numpy as np
from eaglemission.detectors.base import validate_appearance
from eaglemission.detectors.dtdmi.equations_static import pool_colour_bins
from eaglemission.detectors.dtdmi.static import NBINS, quantize_bgr
from numpy.typing import ArrayLike, NDArray

from eaglemission.errors import InputError

#: Fraction of the example's width (height) on each side whose colours count as background.
BORDER_FRACTION = 0.15


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
    """The colour model of an example image; ``lut(frame_hist)`` back-projects it."""

    q: NDArray[np.float64]
    prior: float = 0.01
    pool: bool = True

    @classmethod
    def from_image(cls, image: Any, *, prior: float = 0.01, pool: bool = True,
                   border_fraction: float = BORDER_FRACTION) -> AppearanceModel:
        img = validate_appearance(image)
        if img is None:
            raise InputError("appearance: no image given")
        return cls(target_histogram(img, pool=pool, border_fraction=border_fraction), prior, pool)

    def lut(self, frame_hist: ArrayLike) -> NDArray[np.float32]:
        """(4096,) float32 posterior per colour bin for a frame with these bin counts."""
        return appearance_posterior(self.q, frame_histogram(frame_hist, pool=self.pool),
                                    self.prior)

    def back_project(self, image: NDArray[np.uint8], frame_hist: ArrayLike | None = None
                     ) -> NDArray[np.float32]:
        """The (H, W) posterior map of a BGR frame (plain numpy; the detector uses :meth:`lut`
        with its own look-up)."""
        idx = quantize_bgr(image)
        counts = np.bincount(idx.ravel(), minlength=NBINS) if frame_hist is None else frame_hist
        return self.lut(counts)[idx]


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


def bhattacharyya(p: NDArray[np.floating], q: NDArray[np.floating]) -> float:
    """Bhattacharyya coefficient ``sum sqrt(p q)`` of two distributions (1: identical, 0:
    disjoint): how well a region's colour mixture matches the example's."""
    return float(np.sqrt(np.asarray(p, np.float64) * np.asarray(q, np.float64)).sum())
