"""Refinements of the final DTDMI map beyond the paper (docs/paper_choices.md, "Beyond Eq. (15)").

Pure functions; the engine (:mod:`.engine`) and the plugin (:mod:`.detector`) apply them.

- **Colour propagation** (``colour_propagation``, the ``default`` preset): every pixel also gets
  the mean saliency of the pixels of its colour bin in the same frame,
  ``S' = (1 - w) S + w Sbar(bin(p))``. DTDMI's map is smooth (the motion energy sits on edges
  and is blurred over the object); the colour mean spreads it over the whole object and down to
  its outline when the object's colours are its own, and takes it off background pixels whose
  colours are mostly elsewhere. A soft one-step version of colour-based saliency propagation
  (e.g. Perazzi et al.'s element uniqueness / distribution filtering; Cheng et al.'s
  histogram-based smoothing). ``Sbar`` is a mean of S, so ``S'`` stays in [0, 1] and keeps
  DTDMI's absolute scale: a dark map stays dark.
- **Following the target** (``appearance_track_weight``, with an example image of the target):
  the map is attenuated away from the previous frame's best detection,
  ``S' = S x ((1 - a) + a G)`` with ``G`` a Gaussian of ``sigma`` around that detection's
  centre. It uses past frames only (the detector's state); far from the previous detection a
  region needs ``1 / (1 - a)`` times the saliency to win.

References
----------
F. Perazzi, P. Kraehenbuehl, Y. Pritch, A. Hornung, "Saliency filters: contrast based filtering
for salient region detection", CVPR 2012, DOI 10.1109/CVPR.2012.6247743.
M.-M. Cheng, N. J. Mitra, X. Huang, P. H. S. Torr, S.-M. Hu, "Global contrast based salient
region detection", IEEE TPAMI 37(3), 2015, DOI 10.1109/TPAMI.2014.2345401.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray


def colour_mean_saliency(counts: ArrayLike, weighted: ArrayLike) -> NDArray[np.float32]:
    """Mean saliency of each colour bin: ``weighted / counts``, 0 for a bin without pixels.

    Parameters
    ----------
    counts : ndarray of shape (B,)
        Pixels per colour bin (over the sampled pixels).
    weighted : ndarray of shape (B,)
        Sum of the map over the same pixels, per bin.

    Returns
    -------
    ndarray of shape (B,), float32
    """
    n = np.asarray(counts, np.float64)
    s = np.asarray(weighted, np.float64)
    if n.shape != s.shape:
        raise ValueError(f"counts and weighted: must have the same shape, got {n.shape} and "
                         f"{s.shape}")
    mean = np.divide(s, n, out=np.zeros_like(s), where=n > 0)
    out: NDArray[np.float32] = mean.astype(np.float32)
    return out


def propagated_saliency(sal: NDArray[np.floating], painted: NDArray[np.floating],
                        weight: float) -> NDArray[np.float32]:
    """``(1 - weight) x sal + weight x painted``: the map blended with its colour-bin means.

    Parameters
    ----------
    sal : ndarray of shape (H, W)
        The map, in [0, 1].
    painted : ndarray of shape (H, W)
        :func:`colour_mean_saliency` painted at every pixel's colour bin.
    weight : float
        In [0, 1]; 0 returns ``sal``.
    """
    if not 0.0 <= weight <= 1.0:
        raise ValueError(f"weight: must be in [0, 1], got {weight}")
    s = np.asarray(sal, np.float32)
    p = np.asarray(painted, np.float32)
    if s.shape != p.shape:
        raise ValueError(f"sal and painted: must have the same shape, got {s.shape} and "
                         f"{p.shape}")
    out: NDArray[np.float32] = s * np.float32(1.0 - weight) + p * np.float32(weight)
    return out


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


def _check_spotlight(sigma_px: float, strength: float) -> None:
    if not 0.0 <= strength <= 1.0:
        raise ValueError(f"strength: must be in [0, 1], got {strength}")
    if not sigma_px > 0:
        raise ValueError(f"sigma_px: must be > 0, got {sigma_px}")
