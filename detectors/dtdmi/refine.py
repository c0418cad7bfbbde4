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
