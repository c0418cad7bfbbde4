"""Ground from a real aerial photograph (docs/simulation.md, "Real ground").

The photo (``m_per_px`` metres per pixel, north up) is centred on home and mirrored beyond its
edge (``cv2.BORDER_REFLECT`` in the band warps), so the ground never ends. Its mip levels are
the base texture; the detail layer is periodic luminance noise band-limited from 2 detail
texels (2.5 mm) up to the photo's Nyquist wavelength (2 photo pixels): the structure the
photo cannot hold, added at the camera's scale instead of an upsampled blur.
"""

from __future__ import annotations

import functools
from pathlib import Path

import cv2
import numpy as np
from eaglemission.lab.world.ground_images import read_photo
from eaglemission.lab.world.textures import (
    GroundTextures,
    _rng,
    mip_pyramid,
    periodic_bandpass_noise,
    tiled_detail_levels,
)
from numpy.typing import NDArray

DETAIL_TEXEL_M = 0.0025
DETAIL_CONTRAST = 0.08  # std of the detail modulation (x1.0 +- this)
def photo_detail(size_px: int, max_wavelength_px: float, seed: int) -> NDArray[np.uint8]:
    """Periodic luminance modulation (128 = x1.0), wavelengths 2 px .. ``max_wavelength_px``."""
    rng = _rng(seed, "detail", "photo")
    n = periodic_bandpass_noise(size_px, 2.0, max(4.0, max_wavelength_px), rng)
    m = 1.0 + DETAIL_CONTRAST * n
    return np.ascontiguousarray(np.clip(m * 128.0, 0, 255), dtype=np.uint8)


@functools.lru_cache(maxsize=3)
def photo_ground_textures(path: str, m_per_px: float, seed: int, fade_extent_m: float,
                          offset_ne_m: tuple[float, float] = (0.0, 0.0),
                          detail: bool = True, detail_size_px: int = 2048,
                          tiled_size_px: int = 4096) -> GroundTextures:
    """The textures of a world whose ground is the photo at ``path``, its centre at
    ``offset_ne_m`` from home, mirrored beyond its edge; the edge fade acts on a square of
    ``fade_extent_m``. ``detail=False``: the photo alone (for the detail-ratio benchmark)."""
    photo = read_photo(Path(path))
    h, w = photo.shape[:2]
    # a multiple of 8 px a side: the first mip levels stay exact 2x2 averages of the mirror
    photo = np.ascontiguousarray(photo[: h - h % 8, : w - w % 8])
    levels = mip_pyramid(photo, 16)
    for a in levels:
        a.flags.writeable = False
    tiled: list[NDArray[np.uint8]] = []
    if detail:
        tiled = tiled_detail_levels(
            photo_detail(detail_size_px, 2.0 * m_per_px / DETAIL_TEXEL_M, seed),
            DETAIL_TEXEL_M, m_per_px, tiled_size_px)
    mean = tuple(float(v) for v in levels[-1].reshape(-1, 3).mean(axis=0))
    hh, ww = levels[0].shape[:2]
    return GroundTextures("photo", tuple(levels), float(m_per_px),
                          offset_ne_m[0] + hh * m_per_px / 2.0,
                          offset_ne_m[1] - ww * m_per_px / 2.0,
                          (mean[0], mean[1], mean[2]), tuple(tiled), DETAIL_TEXEL_M,
                          detail_size_px, border_mode=cv2.BORDER_REFLECT,
                          fade_extent_m=float(fade_extent_m))


def gradient_energy(img: NDArray[np.uint8]) -> float:
    """Mean gradient magnitude of the luminance relative to its mean (scale-free contrast per
    pixel): the detail-ratio figure compares rendered frames with the photo at native scale."""
    g = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY).astype(np.float32)
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    return float(np.mean(np.hypot(gx, gy)) / max(1.0, float(g.mean())))
