"""Fuzz target: images of any shape, dtype and content into the frame checks and the detectors.

* :class:`~eaglemission.types.Frame` (what every camera hands over) and the GenICam buffer
  conversion (:func:`to_bgr`, the camera-side frame check) take arrays of any shape, dtype
  (with NaN) and pixel format: a frame, or a ``ValueError`` / ``FrameError`` naming the problem;
* every detector of the registry, one instance per stream, gets a run of frames whose size,
  channels and content change from frame to frame: a :class:`DetectionResult` (saliency map
  finite float32 in [0, 1] at the frame's size, detections inside the image), or a
  ``ValueError`` (``InputError``) naming the problem.
"""

from __future__ import annotations

import random
from typing import Any

import numpy as np
from eaglemission.drivers.cameras.genicam import to_bgr
from fuzz_common import FuzzCrash

from eaglemission import registry
from eaglemission.errors import FrameError
from eaglemission.types import DetectionResult, Frame

TARGET = "frames"
DTYPES = (np.uint8, np.uint8, np.uint8, np.uint16, np.int8, np.float32, np.float64, np.bool_,
          np.int64)
FORMATS = ("Mono8", "Mono12", "Mono16", "BayerRG8", "BayerGB12", "BayerXY8", "RGB8", "BGR8",
           "RGBa8", "BGRA8", "Mono12Packed", "Mono10p", "YUV422_8", "", "RGB")


def random_array(rng: random.Random, max_side: int = 96) -> np.ndarray:
    """An array of a random shape (0-4 dims, sides 0..max_side), dtype and content
    (constant, noise, extremes, NaN/inf for floats)."""
    ndim = rng.choice((0, 1, 2, 2, 3, 3, 3, 4))
    shape = tuple(rng.choice((0, 1, 2, 3, 4, 7, 8, 9, rng.randint(1, max_side)))
                  for _ in range(ndim))
    if ndim == 3 and rng.random() < 0.6:
        shape = (*shape[:2], 3)
    dtype = rng.choice(DTYPES)
    g = np.random.default_rng(rng.randrange(2**32))
    kind = rng.randrange(4)
    if np.issubdtype(dtype, np.floating):
        a = g.normal(0, 300, shape).astype(dtype)
        if kind and a.size:
            a.flat[g.integers(0, a.size, max(1, a.size // 10))] = rng.choice(
                (np.nan, np.inf, -np.inf))
        return a
    info = np.iinfo(dtype) if dtype is not np.bool_ else None
    if info is None:
        return g.integers(0, 2, shape).astype(np.bool_)
    if kind == 0:
        return np.full(shape, rng.choice((info.min, info.max, 0)), dtype=dtype)
    return g.integers(info.min, int(info.max) + 1, shape, dtype=dtype)


def random_frame_image(rng: random.Random, max_side: int = 120) -> np.ndarray:
    """A uint8 image a camera could deliver, of any size (down to 1x1), grey or BGR,
    constant, noisy, a bright blob or a stripe."""
    h, w = (rng.choice((1, 2, 7, 8, 9, 16, rng.randint(1, max_side))) for _ in range(2))
    g = np.random.default_rng(rng.randrange(2**32))
    shape: tuple[int, ...] = (h, w) if rng.random() < 0.2 else (h, w, 3)
    kind = rng.randrange(4)
    if kind == 0:
        return np.full(shape, rng.choice((0, 255, 128)), np.uint8)
    img = g.integers(0, 256, shape, dtype=np.uint8)
    if kind == 2:
        img[:] = 40
        img[h // 3: h // 3 + max(1, h // 5), w // 3: w // 3 + max(1, w // 5)] = 230
    elif kind == 3:
        img[:, : max(1, w // 4)] = 255
    return img


def check_frame_checks(rng: random.Random) -> str:
    """``Frame(image=random array)`` and ``to_bgr(random buffer, w, h, format)``."""
    a = random_array(rng)
    outcome = []
    try:
        f = Frame(a, 0, "wide", 0)
        if f.image.dtype != np.uint8 or f.image.ndim not in (2, 3):
            raise FuzzCrash(TARGET, f"Frame accepted {a.dtype} {a.shape}", (a.dtype, a.shape))
        outcome.append("frame")
    except ValueError as exc:
        _named(exc, (a.dtype, a.shape))
        outcome.append("refused")
    w, h = rng.choice((0, 1, 4, 8, 16)), rng.choice((0, 1, 4, 8, 16))
    fmt = rng.choice(FORMATS)
    data = a.reshape(-1) if rng.random() < 0.5 else a
    try:
        img = to_bgr(data, w, h, fmt)
        if img.dtype != np.uint8 or img.shape != (h, w, 3):
            raise FuzzCrash(TARGET, f"to_bgr gave {img.dtype} {img.shape} for {w}x{h} {fmt}",
                            (a.dtype, a.shape, w, h, fmt))
        outcome.append("converted")
    except FrameError as exc:
        _named(exc, (a.dtype, a.shape, w, h, fmt))
        outcome.append("refused")
    except Exception as exc:
        raise FuzzCrash(TARGET, f"to_bgr({a.dtype} {a.shape}, {w}, {h}, {fmt!r}) raised "
                        f"{type(exc).__name__}: {exc}", (a.dtype, a.shape, w, h, fmt)) from exc
    return "/".join(outcome)


def _named(exc: Exception, case: Any) -> None:
    if len(str(exc)) < 10:
        raise FuzzCrash(TARGET, f"{type(exc).__name__} without a useful message: {exc!r}",
                        case) from exc


def detector_names() -> list[str]:
    return sorted(registry.available("detectors"))


def new_detector(name: str) -> Any:
    return registry.load("detectors", name, {})


def check_detector(name: str, detector: Any, image: np.ndarray, seq: int) -> str:
    """One frame into a detector that has seen others (any size): a sane result or a
    ``ValueError`` naming the problem."""
    frame = Frame(image, 1_000_000 * (seq + 1), "wide", seq)
    case = (name, image.dtype, image.shape, seq)
    try:
        res = detector.detect(frame)
    except ValueError as exc:
        _named(exc, case)
        return "refused"
    except Exception as exc:
        raise FuzzCrash(TARGET, f"{name}.detect raised {type(exc).__name__}: {exc}", case) from exc
    if not isinstance(res, DetectionResult):
        raise FuzzCrash(TARGET, f"{name}.detect returned {type(res).__name__}", case)
    sal = np.asarray(res.saliency)
    if sal.shape != image.shape[:2] or sal.dtype != np.float32:
        raise FuzzCrash(TARGET, f"{name}: saliency {sal.dtype} {sal.shape} for a "
                        f"{image.shape} frame", case)
    if not np.isfinite(sal).all() or sal.min() < 0.0 or sal.max() > 1.0:
        raise FuzzCrash(TARGET, f"{name}: saliency outside [0, 1] or not finite", case)
    h, w = image.shape[:2]
    for d in res.detections:
        c = np.asarray(d.corners_px)
        if not np.isfinite(c).all() or not (-1.0 <= d.center_px[0] <= w + 1.0
                                            and -1.0 <= d.center_px[1] <= h + 1.0):
            raise FuzzCrash(TARGET, f"{name}: detection outside the image: {d.center_px}", case)
    return "detected" if res.detections else "nothing"
