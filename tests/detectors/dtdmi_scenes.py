"""Small synthetic scenes for the DTDMI tests (textured background, moving target)."""

from __future__ import annotations

import cv2
import numpy as np

from eaglemission.types import Frame

FPS = 30.0


def texture(rng: np.random.RandomState, h: int, w: int) -> np.ndarray:
    """Smooth random BGR texture, uint8."""
    t = rng.rand(h, w, 3).astype(np.float32)
    t = cv2.GaussianBlur(t, (0, 0), 1.5)
    t = (t - t.min()) / (t.max() - t.min())
    return (40 + 120 * t).astype(np.uint8)


def frame(img: np.ndarray, i: int, fps: float = FPS, seq: int | None = None) -> Frame:
    return Frame(np.ascontiguousarray(img), int(1e9 + i * 1e9 / fps), "wide",
                 i if seq is None else seq)


def moving_scene(rng: np.random.RandomState, n: int = 10, h: int = 96, w: int = 128,
                 cam_px: tuple[int, int] = (2, 1), target_px: tuple[int, int] = (-3, 2),
                 size: int = 12):
    """Frames of a background translating by ``cam_px`` per frame (camera motion) and a
    red-ish textured target square moving by ``target_px`` per frame; yields (frame, (u, v))."""
    bg = texture(rng, h + 4 * n + 40, w + 4 * n + 40)
    tgt = texture(rng, size, size)
    tgt[:, :, 2] = np.clip(tgt[:, :, 2].astype(int) + 90, 0, 255)
    out = []
    for i in range(n):
        oy, ox = 20 + cam_px[1] * i, 20 + cam_px[0] * i
        img = bg[oy:oy + h, ox:ox + w].copy()
        u0 = w // 2 + target_px[0] * i - size // 2 + 8
        v0 = h // 2 + target_px[1] * i - size // 2 - 8
        img[v0:v0 + size, u0:u0 + size] = tgt
        out.append((frame(img, i), (u0 + size / 2 - 0.5, v0 + size / 2 - 0.5)))
    return out
