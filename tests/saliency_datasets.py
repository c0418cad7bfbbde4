"""Tiny generated saliency data sets for the ``bench`` and ``detect`` command tests: frames
with a saturated square, and its masks or its boxes. Not a test module."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np


def make_mask_dataset(root: Path, rng: np.random.RandomState, seqs=("alpha", "beta"), n=4,
                      size=(64, 48)) -> Path:
    """``root/<seq>/frames`` and ``root/<seq>/gt``: a yellow 16 x 12 px square moving right on
    noise, its mask beside each frame (the DAVIS layout)."""
    w, h = size
    for s_i, name in enumerate(seqs):
        (root / name / "frames").mkdir(parents=True)
        (root / name / "gt").mkdir()
        for i in range(n):
            img = np.clip(rng.randn(h, w, 3) * 5 + 100, 0, 255).astype(np.uint8)
            gt = np.zeros((h, w), np.uint8)
            u, v = 10 + 4 * i + 3 * s_i, 15
            img[v:v + 12, u:u + 16] = (40, 200, 240)
            gt[v:v + 12, u:u + 16] = 255
            cv2.imwrite(str(root / name / "frames" / f"{i:05d}.jpg"), img)
            cv2.imwrite(str(root / name / "gt" / f"{i:05d}.png"), gt)
    return root


def make_box_dataset(root: Path, rng: np.random.RandomState, n: int = 10,
                     size=(96, 64)) -> Path:
    """``root/set/seq``: a yellow 16 x 12 px square moving right on faint noise, boxes.txt
    1-based, frame 3 without the target (nan)."""
    w, h = size
    seq = root / "set" / "seq"
    (seq / "frames").mkdir(parents=True)
    lines = []
    for i in range(n):
        img = np.clip(rng.randn(h, w, 3) * 1 + 100, 0, 255).astype(np.uint8)
        u, v = 10 + 4 * i, 20
        if i == 3:
            lines.append("nan,nan,nan,nan")
        else:
            img[v:v + 12, u:u + 16] = (40, 200, 240)
            lines.append(f"{u + 1},{v + 1},16,12")  # 1-based, as the UAV sets
        cv2.imwrite(str(seq / "frames" / f"{i + 1:06d}.png"), img)
    (seq / "boxes.txt").write_text("\n".join(lines) + "\n")
    return root

