"""Ground from a real aerial photograph (docs/cameras.md, "Real ground").

The photo (``m_per_px`` metres per pixel, north up) is centred on home and mirrored beyond its
edge (``cv2.BORDER_REFLECT`` in the band warps), so the ground never ends. Its mip levels are
the base texture; the detail layer is periodic luminance noise band-limited from 2 detail
texels (2.5 mm) up to the photo's Nyquist wavelength (2 photo pixels): the structure the
photo cannot hold, added at the camera's scale instead of an upsampled blur.
"""

from __future__ import annotations

import functools
import math
from pathlib import Path

import cv2
import numpy as np
import yaml
from eaglemission.drivers.cameras.textures import (
    GroundTextures,
    _rng,
    mip_pyramid,
    periodic_bandpass_noise,
)
from numpy.typing import NDArray

DETAIL_TEXEL_M = 0.0025
DETAIL_CONTRAST = 0.08  # std of the detail modulation (x1.0 +- this)
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png")


class GroundImageError(ValueError):
    """A ground image or its sidecar yaml is missing or invalid (the message names the file)."""


def sidecar_m_per_px(image: Path) -> float:
    """``m_per_px`` from ``NAME.yaml`` next to ``NAME.jpg|png``."""
    side = image.with_suffix(".yaml")
    if not side.is_file():
        raise GroundImageError(f"{side}: missing (needs `m_per_px: <metres per pixel>`)")
    try:
        data = yaml.safe_load(side.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise GroundImageError(f"{side}: not readable YAML ({exc})") from exc
    value = data.get("m_per_px") if isinstance(data, dict) else None
    if isinstance(value, bool) or not isinstance(value, int | float) \
            or not math.isfinite(value) or not 0.001 <= value <= 10.0:
        raise GroundImageError(f"{side}: m_per_px must be a number in [0.001, 10] metres per "
                               f"pixel, got {value!r}")
    return float(value)


def read_photo(path: Path) -> NDArray[np.uint8]:
    """The photo as BGR uint8 (a clear error naming the file otherwise)."""
    if not path.is_file():
        raise GroundImageError(f"{path}: ground image not found")
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None or img.ndim != 3 or min(img.shape[:2]) < 64:
        raise GroundImageError(f"{path}: not a readable colour image of at least 64x64 px")
    return np.ascontiguousarray(img, dtype=np.uint8)


def ground_image_files(folder: Path) -> list[Path]:
    """The ``NAME.jpg|png`` of ``folder`` (name order), each checked to have a valid
    ``NAME.yaml``; raises :class:`GroundImageError` naming the first bad file."""
    if not folder.is_dir():
        raise GroundImageError(f"{folder}: not a folder of ground images")
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise GroundImageError(f"{folder}: no NAME.jpg or NAME.png ground images")
    for f in files:
        sidecar_m_per_px(f)
        if cv2.haveImageReader(str(f)) is False:
            raise GroundImageError(f"{f}: not a readable image")
    return files


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
        lvl = photo_detail(detail_size_px, 2.0 * m_per_px / DETAIL_TEXEL_M, seed)
        while DETAIL_TEXEL_M * 2 ** len(tiled) < m_per_px and lvl.shape[0] >= 8:
            reps = max(1, int(math.ceil(tiled_size_px / lvl.shape[0])))
            t = np.tile(lvl, (reps, reps))
            t.flags.writeable = False
            tiled.append(t)
            lvl = np.asarray(cv2.resize(lvl, (lvl.shape[1] // 2, lvl.shape[0] // 2),
                                        interpolation=cv2.INTER_AREA), dtype=np.uint8)
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
