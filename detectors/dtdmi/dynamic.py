"""Multi-scale midbrain dynamic perception S_M (Eqs. (7)-(14) of [1]) with its per-scale state.

Holds the delay units of every scale in preallocated float32 planes, advances them with the time
step in seconds (Eqs. (8)-(9) via :func:`.equations.tau_steps`), optionally aligns them to the
current frame with the estimated ego-motion (:mod:`.egomotion`) before Eq. (10), and returns the
per-scale Eq. (13) maps. Eq. (14) (and any per-scale normalisation of the default preset) is the
caller's.

References
----------
.. [1] Eagle-eye inspired target detection (DTDMI), Sec. 2.2. DOI unknown.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import cast

import cv2
import eaglemission.detectors.dtdmi.egomotion as egomotion
import eaglemission.detectors.dtdmi.equations_dynamic as eq
import numpy as np
from eaglemission.detectors.dtdmi.midbrain_step import midbrain_step_numpy
from numpy.typing import NDArray

log = logging.getLogger(__name__)
F32 = NDArray[np.float32]
#: float32 grey in 0..1, or (deferred steps only) the 8-bit grey image
Grey = NDArray[np.float32] | NDArray[np.uint8]


@dataclass(frozen=True)
class DynamicParams:
    scales: tuple[float, ...] = (1.0, 0.5, 0.25)
    tau_s: float = 0.1
    tensor_radius_px: int = 2
    ego_motion: str = "none"  # "none" | "phase" | "homography"
    ego_motion_width_px: int = 320
    backend: str = "numba"  # "numba" | "numpy"
    floor: float = 1e-20  # noise floor subtracted from Eq. (13)


class _Scale:
    def __init__(self, shape: tuple[int, int], s: float) -> None:
        self.s = s
        self.shape = shape
        self.grey = np.zeros(shape, np.float32)
        self.g_delayed = np.zeros(shape, np.float32)
        self.g_prev = np.zeros(shape, np.float32)
        self.tmp = np.zeros(shape, np.float32)
        self.o = np.zeros(shape, np.float32)
        self.sm = np.zeros(shape, np.float32)


def scale_shape(shape: tuple[int, int], s: float) -> tuple[int, int]:
    return max(4, int(round(shape[0] * s))), max(4, int(round(shape[1] * s)))


class MidbrainDynamic:
    """``step(grey01, timestamp_ns) -> list of per-scale S_M planes`` (views of internal buffers)."""

    def __init__(self, params: DynamicParams) -> None:
        self.p = params
        self._fused = None
        if params.backend == "numba":
            from eaglemission.detectors.dtdmi.kernels import midbrain_step_fused

            self._fused = midbrain_step_fused
        self.reset()

    def reset(self) -> None:
        self._scales: list[_Scale] = []
        self._shape: tuple[int, int] | None = None
        self._t_prev_ns: int | None = None
        self._small_prev: F32 | None = None
        self.last_motion = np.eye(3)

    def _allocate(self, shape: tuple[int, int]) -> None:
        self._scales = [_Scale(scale_shape(shape, s), s) for s in self.p.scales]
        self._shape = shape
        self._t_prev_ns = None
        self._small_prev = None

    def _ego_motion(self, grey: F32) -> None:
        h, w = grey.shape
        sw = min(w, self.p.ego_motion_width_px)
        s = sw / w
        small = np.asarray(cv2.resize(grey, (sw, max(8, int(round(h * s)))),
                                      interpolation=cv2.INTER_AREA), np.float32)
        hm = np.eye(3)
        if self._small_prev is not None:
            hm = egomotion.estimate_motion(self.p.ego_motion, self._small_prev, small, s)
        self._small_prev = small
        self.last_motion = hm
        if np.allclose(hm, np.eye(3)):
            return
        for sc in self._scales:
            hs = egomotion.homography_at_scale(hm, sc.shape[1] / w)
            for plane in (sc.g_delayed, sc.g_prev):
                egomotion.warp_state(plane, hs, sc.tmp)
                plane[...] = sc.tmp

    def step(self, grey: Grey, timestamp_ns: int, *, defer: bool = False,
             given: dict[int, F32] | None = None) -> list[F32]:
        """Advance every scale by one frame; the per-scale Eq. (13) maps (``self.tops``: maxima).

        ``defer``: the time step, ego-motion alignment and per-scale grey images are done, but
        Eqs. (7)-(13) are left to a caller that streams them into its own use of the maps
        (:func:`.kernels.midbrain_combine`, numba backend): ``self.deferred`` lists
        ``(scale, grey of the scale, gain)`` in scale order; the returned maps are then stale
        and the tops NaN. ``given``: grey images of some scales (by index) the caller already
        has (with ``defer``, ``grey`` itself may then be the 8-bit image: the caller's kernel
        reads it as such); no ego-motion alignment with it.
        """
        self.deferred: list[tuple[_Scale, Grey, float]] = []
        shape = (grey.shape[0], grey.shape[1])
        if shape != self._shape:
            self._allocate(shape)
        if self._t_prev_ns is not None and timestamp_ns <= self._t_prev_ns:
            log.warning("dtdmi: frame timestamp %d not after the previous one (%d); "
                        "resetting the delay units", timestamp_ns, self._t_prev_ns)
            self._allocate(shape)
        dt_s = (timestamp_ns - self._t_prev_ns) * 1e-9 if self._t_prev_ns is not None else None
        self._t_prev_ns = timestamp_ns
        if self.p.ego_motion != "none":
            self._ego_motion(cast(F32, grey))  # float grey: 8-bit frames come without ego-motion
        # First frame: G_d(0) = 0 and no previous response, so the update is a no-op (gain 0).
        gain = 0.0 if dt_s is None else 1.0 / eq.tau_steps(dt_s, self.p.tau_s)
        out = []
        self.tops: list[float] = []
        prev: Grey | None = None
        for k, sc in enumerate(self._scales):
            g_s: Grey
            if given is not None and k in given:
                g_s = given[k]
            elif sc.shape == shape:
                g_s = grey  # the processing resolution itself: no copy
            else:
                # From the previous scale when that is exactly twice this one and an integer
                # reduction of the frame (nested block means: the same values up to float
                # rounding; OpenCV's 2x area path is ~10x faster than its 4x one), else from
                # the frame.
                use_prev = (prev is not None and prev.shape == (2 * sc.shape[0], 2 * sc.shape[1])
                            and shape[0] % prev.shape[0] == 0 and shape[1] % prev.shape[1] == 0)
                if not use_prev and grey.dtype != np.float32:
                    raise ValueError("dtdmi: an 8-bit grey frame needs every coarse scale given "
                                     "or exactly half the one before (internal error)")
                src = prev if use_prev and prev is not None else grey
                cv2.resize(src, (sc.shape[1], sc.shape[0]), dst=sc.grey,
                           interpolation=cv2.INTER_AREA)
                g_s = sc.grey
            prev = g_s
            if defer:
                self.deferred.append((sc, g_s, gain))
                self.tops.append(float("nan"))
                out.append(sc.sm)
                continue
            g32 = cast(F32, g_s)  # computed here: the float grey (8-bit frames are deferred)
            if self._fused is not None:
                top = self._fused(g32, sc.g_delayed, sc.g_prev, gain, self.p.tensor_radius_px,
                                  sc.o, sc.sm, self.p.floor)
            else:
                tau = np.inf if gain == 0.0 else 1.0 / gain
                sm, gd, gp = midbrain_step_numpy(g32, sc.g_delayed, sc.g_prev, tau,
                                                 self.p.tensor_radius_px, self.p.floor)
                sc.sm[...] = sm
                sc.g_delayed[...] = gd
                sc.g_prev[...] = gp
                top = float(sm.max())
            self.tops.append(top)
            out.append(sc.sm)
        return out
