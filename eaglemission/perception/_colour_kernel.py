"""Compiled (numba) chromaticity mask of :func:`~eaglemission.perception.colour.colour_blob`:
one pass over every ``step``-th pixel of a BGR image, with the numpy path's float32 arithmetic
in the same order (``colour_mask_numpy``; tests compare them bit for bit)."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def colour_mask(img: np.ndarray, step: int, t: np.ndarray, tolerance: np.float32,
                min_brightness: np.float32) -> np.ndarray:
    """uint8 mask (1 = the pixel's chromaticity is within ``tolerance`` (L1) of ``t`` and its
    B + G + R is at least ``min_brightness``) of ``img[::step, ::step]``; ``t``, ``tolerance``
    and ``min_brightness`` are float32."""
    h = (img.shape[0] + step - 1) // step
    w = (img.shape[1] + step - 1) // step
    out = np.zeros((h, w), np.uint8)
    one = np.float32(1.0)
    for i in range(h):
        for j in range(w):
            b = np.float32(img[i * step, j * step, 0])
            g = np.float32(img[i * step, j * step, 1])
            r = np.float32(img[i * step, j * step, 2])
            total = (b + g) + r
            den = total if total > one else one
            dist = abs(b / den - t[0])
            dist = dist + abs(g / den - t[1])
            dist = dist + abs(r / den - t[2])
            if dist <= tolerance and total >= min_brightness:
                out[i, j] = 1
    return out
