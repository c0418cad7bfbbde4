"""Fused numba kernels of the engine's general path (the ``aerial`` preset): the same results
as the plain functions they replace (:func:`.equations_static.block_contrast_cue` of
:func:`.maps.lab_features`), within float rounding (tested).

- :func:`block_contrast` reads both box means of the block contrast cue from one integral
  image of the reflect-padded 8-bit L*a*b* frame and writes the weighted distance in the same
  pass (OpenCV's two float box filters, the subtraction, ``cv2.transform`` and ``cv2.sqrt``
  were five passes over a three-channel float plane.

Serial, ``cache=True`` like :mod:`.kernels`.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

F32 = NDArray[np.float32]
I32 = NDArray[np.int32]
U8 = NDArray[np.uint8]


@njit(cache=True, nogil=True, fastmath=True)
def block_contrast(ii: I32, pad: int, r: int, big: int, wl2: float, scale: float, out: F32,
                   accumulate: bool) -> None:  # pragma: no cover - jitted
    """``out (+)= scale x sqrt(wl2 dL^2 + da^2 + db^2)``, ``d`` the difference of the
    ``(2r+1)^2`` and ``(2big+1)^2`` box means of the 8-bit L*a*b* channels around each pixel.

    ``ii``: ``cv2.integral`` (int32) of the frame padded by ``pad >= big`` pixels with
    ``cv2.BORDER_REFLECT`` (the border the box filters used), its channels interleaved along
    the row: shape (H + 2 pad + 1, 3 (W + 2 pad + 1)); ``out`` has the frame's shape (H, W).
    Box sums are exact integers. A column shift is a shift of 3 along the interleaved row, so
    the per-channel differences run over shifted row views on the bare counter (they
    vectorise: see :mod:`.kernels`); the three channels are summed after.
    """
    h, w = out.shape
    n = 3 * w
    inv_c = np.float32(1.0 / ((2 * r + 1) * (2 * r + 1)))
    inv_s = np.float32(1.0 / ((2 * big + 1) * (2 * big + 1)))
    sc = np.float32(scale)
    d2 = np.empty(n, np.float32)
    weights = np.ones(n, np.float32)
    for j in range(w):
        weights[3 * j] = np.float32(wl2)
    cr, cl = 3 * (pad + r + 1), 3 * (pad - r)
    sr, sl = 3 * (pad + big + 1), 3 * (pad - big)
    for i in range(h):
        y = i + pad
        c0, c1 = ii[y - r], ii[y + r + 1]
        s0, s1 = ii[y - big], ii[y + big + 1]
        c1r, c0r, c1l, c0l = c1[cr:cr + n], c0[cr:cr + n], c1[cl:cl + n], c0[cl:cl + n]
        s1r, s0r, s1l, s0l = s1[sr:sr + n], s0[sr:sr + n], s1[sl:sl + n], s0[sl:sl + n]
        for m in range(n):
            d = (np.float32(c1r[m] - c0r[m] - c1l[m] + c0l[m]) * inv_c
                 - np.float32(s1r[m] - s0r[m] - s1l[m] + s0l[m]) * inv_s)
            d2[m] = weights[m] * d * d
        orow = out[i]
        for j in range(w):
            v = sc * np.sqrt(d2[3 * j] + d2[3 * j + 1] + d2[3 * j + 2])
            if accumulate:
                orow[j] += v
            else:
                orow[j] = v
