"""The colour bins every colour model shares: 4 bits per channel, 4096 bins
(``b >> 4 << 8 | g >> 4 << 4 | r >> 4``), and the pooling of a bin with its 26 neighbours."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

BITS = 4
NBINS = 1 << (3 * BITS)


def quantize_bgr(image: NDArray[np.uint8]) -> NDArray[np.uint16]:
    """(H, W) histogram bin index ``b >> 4 << 8 | g >> 4 << 4 | r >> 4`` of each pixel."""
    q = (image >> (8 - BITS)).astype(np.uint16)
    return np.asarray((q[:, :, 0] << (2 * BITS)) | (q[:, :, 1] << BITS) | q[:, :, 2], np.uint16)


def pool_colour_bins(values: ArrayLike, bits: int = 4) -> NDArray[np.float64]:
    """Sum of each colour bin and its 26 neighbours in the (2^bits)^3 histogram grid (field).

    The distribution cue pools a bin's pixels with those of adjacent colours (a box version of
    Perazzi et al.'s colour-similarity weighting), so a bin that holds a few pixels of a
    widespread colour (noise on the horizon, a shaded edge) is not taken as compact.

    Parameters
    ----------
    values : ndarray of shape (B,) or (B, C), B = 2^(3 bits), bin index ``b << 2 bits | g << bits | r``

    Returns
    -------
    ndarray of the same shape
    """
    n = 1 << bits
    v = np.asarray(values, np.float64)
    grid = v.reshape((n, n, n) + v.shape[1:])
    for axis in range(3):
        out = grid.copy()
        lo = [slice(None)] * grid.ndim
        hi = [slice(None)] * grid.ndim
        lo[axis], hi[axis] = slice(0, n - 1), slice(1, n)
        out[tuple(lo)] += grid[tuple(hi)]
        out[tuple(hi)] += grid[tuple(lo)]
        grid = out
    return grid.reshape(v.shape)
