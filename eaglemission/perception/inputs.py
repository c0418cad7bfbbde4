"""Frames from disk for ``eaglemission detect`` and ``bench``: image folders, single images,
the example image of the target, and a replayed sequence's timestamps."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from eaglemission.commands.params import UsageError

IMAGE_EXTS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff")
T0_NS = 1_000_000_000  # first frame's timestamp (the virtual clock also starts at 1 s)


def images_in(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_EXTS and p.is_file())


def read_image(path: Path) -> NDArray[np.uint8]:
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise UsageError(f"cannot read image {str(path)!r}: unreadable or not an image")
    return np.asarray(img, dtype=np.uint8)  # IMREAD_COLOR: always 8-bit BGR


def frame_time_ns(index: int, fps: float) -> int:
    return T0_NS + round(index * 1e9 / fps)


def read_target_image(path: Path) -> np.ndarray:
    """``--target-image PATH``: a BGR uint8 image (a tight crop or a photo on a plain
    background)."""
    if not path.is_file():
        raise UsageError(f"--target-image {str(path)!r}: not found; give an image file (a tight "
                         f"crop of the target, or a photo of it on a plain background)")
    return read_image(path)
