"""The dual camera as one object: the wide ("shallow fovea") and narrow ("deep fovea") cameras
with their models, grabbing both streams and pairing frames by timestamp.

``grab_pair`` grabs both cameras concurrently (two worker threads: OpenCV and harvesters
release the GIL), then, while the two mid-exposure stamps differ by more than ``max_skew_s``,
re-grabs the camera whose frame is older (up to ``max_regrabs`` times). The skew of every pair
is reported (``FramePair.skew_s``, ``stats``). ``grab("wide")`` grabs one camera only (the
mission's cruise phase processes only the wide camera).
"""

from __future__ import annotations

import math
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

from eaglemission.errors import GrabTimeout
from eaglemission.geometry import CameraModel
from eaglemission.interfaces.camera import Camera
from eaglemission.types import Frame


@dataclass(frozen=True, slots=True)
class FramePair:
    """Two frames of the rig. ``skew_s = narrow.timestamp - wide.timestamp``; ``synced`` is
    False when the rig could not bring ``|skew_s|`` under ``max_skew_s``."""

    wide: Frame
    narrow: Frame
    skew_s: float
    synced: bool


class CameraRig:
    """Wide + narrow cameras with per-camera models (calibration and mount).

    Parameters
    ----------
    wide, narrow : Camera plugins (any role implementation)
    max_skew_s : pairing tolerance between the two frames' mid-exposure stamps
    max_regrabs : re-grabs of the older camera per pair before giving up (``synced=False``)
    threaded : grab the two cameras concurrently (default) or one after the other
    """

    def __init__(self, wide: Camera, narrow: Camera, *, max_skew_s: float = 0.010,
                 max_regrabs: int = 3, threaded: bool = True) -> None:
        if max_skew_s < 0 or not math.isfinite(max_skew_s):
            raise ValueError(f"max_skew_s: must be a finite number >= 0, got {max_skew_s}")
        self.cameras: dict[str, Camera] = {"wide": wide, "narrow": narrow}
        self.max_skew_s = float(max_skew_s)
        self.max_regrabs = int(max_regrabs)
        self.threaded = threaded
        self.world: Any = None  # the SyntheticWorld when the rig is synthetic
        self._pool: ThreadPoolExecutor | None = None
        self._lock = threading.Lock()
        self.stats: dict[str, float] = {"pairs": 0, "unsynced_pairs": 0, "regrabs": 0,
                                        "max_abs_skew_s": 0.0, "sum_abs_skew_s": 0.0,
                                        "last_skew_s": 0.0}

    @property
    def wide(self) -> Camera:
        return self.cameras["wide"]

    @property
    def narrow(self) -> Camera:
        return self.cameras["narrow"]

    @property
    def models(self) -> dict[str, CameraModel]:
        return {cid: cam.model for cid, cam in self.cameras.items()}

    # -- lifetime --------------------------------------------------------------------------
    def open(self) -> None:
        opened = []
        try:
            for cam in self.cameras.values():
                cam.open()
                opened.append(cam)
        except BaseException:
            for cam in opened:
                cam.close()
            raise
        if self.threaded and self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=2, thread_name_prefix="camera-rig")

    def close(self) -> None:
        for cam in self.cameras.values():
            cam.close()
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None

    def __enter__(self) -> CameraRig:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- grabbing --------------------------------------------------------------------------
    def grab(self, camera_id: str, *, timeout_s: float) -> Frame:
        """Grab one camera only."""
        try:
            cam = self.cameras[camera_id]
        except KeyError:
            raise ValueError(f"camera_id: must be one of {sorted(self.cameras)}, "
                             f"got {camera_id!r}") from None
        return cam.grab(timeout_s=timeout_s)

    def _grab_both(self, timeout_s: float) -> tuple[Frame, Frame]:
        if self._pool is None:
            return (self.wide.grab(timeout_s=timeout_s), self.narrow.grab(timeout_s=timeout_s))
        fw: Future[Frame] = self._pool.submit(self.wide.grab, timeout_s=timeout_s)
        fn: Future[Frame] = self._pool.submit(self.narrow.grab, timeout_s=timeout_s)
        # Each grab is bounded by timeout_s; the margin covers thread start-up.
        wide = fw.result(timeout=timeout_s + 1.0)
        narrow = fn.result(timeout=timeout_s + 1.0)
        return wide, narrow

    def grab_pair(self, *, timeout_s: float, max_skew_s: float | None = None) -> FramePair:
        """Grab both cameras and pair their frames by timestamp (see module docstring).
        The whole call is bounded by about ``timeout_s`` (each grab gets what is left)."""
        tol_ns = int(round((self.max_skew_s if max_skew_s is None else max_skew_s) * 1e9))
        deadline = time.monotonic() + timeout_s
        wide, narrow = self._grab_both(timeout_s)
        regrabs = 0
        while abs(narrow.timestamp_ns - wide.timestamp_ns) > tol_ns and regrabs < self.max_regrabs:
            left = deadline - time.monotonic()
            if left <= 0:
                break
            try:
                if narrow.timestamp_ns < wide.timestamp_ns:
                    narrow = self.narrow.grab(timeout_s=left)
                else:
                    wide = self.wide.grab(timeout_s=left)
            except GrabTimeout:
                break
            regrabs += 1
        skew_ns = narrow.timestamp_ns - wide.timestamp_ns
        synced = abs(skew_ns) <= tol_ns
        skew_s = skew_ns / 1e9
        with self._lock:
            st = self.stats
            st["pairs"] += 1
            st["regrabs"] += regrabs
            st["unsynced_pairs"] += 0 if synced else 1
            st["last_skew_s"] = skew_s
            st["sum_abs_skew_s"] += abs(skew_s)
            st["max_abs_skew_s"] = max(st["max_abs_skew_s"], abs(skew_s))
        return FramePair(wide, narrow, skew_s, synced)

    def health(self) -> dict[str, Any]:
        with self._lock:
            st = dict(self.stats)
        st["mean_abs_skew_s"] = st["sum_abs_skew_s"] / st["pairs"] if st["pairs"] else 0.0
        cams = {}
        for cid, cam in self.cameras.items():
            h = getattr(cam, "health", None)
            cams[cid] = h() if callable(h) else {}
        return {"rig": st, "cameras": cams}
