"""Ground image folders: ``NAME.jpg|png`` photos, each with ``NAME.yaml`` holding its
``m_per_px`` (as ``../shared/data/aerial_ground``), checked with errors naming the file. The
synthetic world renders them (``lab/world/photo_ground.py``); ``campaign
--ground-images`` draws from a folder of them."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import yaml
from numpy.typing import NDArray

from eaglemission.errors import EagleMissionError

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png")


class GroundImageError(EagleMissionError, ValueError):
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
