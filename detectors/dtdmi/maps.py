"""Map plumbing of the DTDMI engine (:mod:`.engine`): the large-sigma smoothing done on a
reduced copy, the CIE L*a*b* features and the fast version of the block contrast cue
(:func:`.equations_static.block_contrast_cue`), and the bilinear upsampling plan the numba
kernels read the coarse scales through.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import cv2
import numpy as np


def smooth_mapped(s: np.ndarray, sigma_px: float, out_hw: tuple[int, int],
                  to_unit: Callable[[np.ndarray, float | None, np.ndarray], None]) -> np.ndarray:
    """Gaussian smoothing (large sigma), mapped to [0, 1] by ``to_unit``, resized to ``out_hw``.

    Done on a copy reduced by ~sigma / 4 (fast); mapped there, so the bilinear upsampling
    (a convex combination) stays in [0, 1]. A map that is zero everywhere stays zero.
    """
    f = smoothing_factor(sigma_px)
    h, w = s.shape
    if f > 1:
        small = cv2.resize(s, (max(1, w // f), max(1, h // f)), interpolation=cv2.INTER_AREA)
    else:
        small = s  # small sigma (field preset): blur in place at full resolution
    return smooth_reduced(small, sigma_px / f, f == 1, out_hw, to_unit)


def smoothing_factor(sigma_px: float) -> int:
    """The reduction factor :func:`smooth_mapped` blurs at (~sigma / 4, at least 1)."""
    return max(1, int(sigma_px / 4))


def smooth_reduced(small: np.ndarray, sigma_px: float, in_place: bool, out_hw: tuple[int, int],
                   to_unit: Callable[[np.ndarray, float | None, np.ndarray], None]) -> np.ndarray:
    """The second half of :func:`smooth_mapped`: blur the reduced map ``small`` (by ``sigma_px``
    at its own resolution; in place if ``in_place``), map it, resize it to ``out_hw``."""
    small = cv2.GaussianBlur(small, (0, 0), sigma_px, dst=small if in_place else None)
    mapped = np.empty_like(small)
    to_unit(small, None, mapped)
    if mapped.shape == (out_hw[0], out_hw[1]):
        return mapped
    return cv2.resize(mapped, (out_hw[1], out_hw[0]), interpolation=cv2.INTER_LINEAR)


def lab_features(bgr: np.ndarray, luminance_weight: float) -> np.ndarray:
    """(H, W, 3) float32 CIE L*a*b* (L* in 0..100, a*, b* about -128..127; OpenCV's 8-bit
    conversion) with L* scaled by ``luminance_weight``: the block contrast cue's features."""
    lab8 = cv2.cvtColor(bgr, cv2.COLOR_BGR2Lab)
    scale = np.array([luminance_weight * 100.0 / 255.0, 1.0, 1.0], np.float32)
    offset = np.array([0.0, -128.0, -128.0], np.float32)
    return lab8.astype(np.float32) * scale + offset


def block_contrast_into(bgr: np.ndarray, luminance_weight: float, radius_px: int,
                        surround: float, scale: float, out: np.ndarray,
                        accumulate: bool) -> None:
    """``out (+)= scale x`` :func:`.equations_static.block_contrast_cue` of
    :func:`lab_features` in one numba pass (:func:`.kernels_general.block_contrast`: both box
    means from one integral image of the reflect-padded 8-bit L*a*b* frame, the weighted
    distance in the same pass); the same map within float rounding (tested)."""
    from eaglemission.detectors.dtdmi.kernels_general import block_contrast

    lab8 = cv2.cvtColor(bgr, cv2.COLOR_BGR2Lab)
    r = max(1, int(radius_px))
    big = max(r + 1, int(round(surround * r)))
    padded = cv2.copyMakeBorder(lab8, big, big, big, big, cv2.BORDER_REFLECT)
    ii = np.asarray(cv2.integral(padded, sdepth=cv2.CV_32S), dtype=np.int32)
    wl = luminance_weight * 100.0 / 255.0
    block_contrast(ii.reshape(ii.shape[0], -1), big, r, big, wl * wl, scale, out, accumulate)


def add_block_cue(work: np.ndarray, r: Any, s: np.ndarray | None,
                  plane: np.ndarray | None) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The block contrast cue of ``work`` times ``block_weight / block_unit`` (``r``: the
    engine's resolved preset values): added to ``s`` (S_s, ``block_fusion: static``) or
    returned as its own plane (``add``). ``plane``: a preallocated (H, W) float32 plane for
    the fused kernel (:func:`block_contrast_into`); None: the plain numpy functions. With
    ``block_downscale`` d > 1 the cue is computed on ``work`` reduced by d (area average; the
    block radius is a fraction of that frame's diagonal) and upsampled bilinearly. Returns
    (s, block plane or None)."""
    scale = r.block_weight / r.block_unit
    h, w = work.shape[:2]
    d = int(r.block_downscale)
    src = work
    if d > 1:
        src = cv2.resize(work, (max(1, w // d), max(1, h // d)), interpolation=cv2.INTER_AREA)
    into = r.block_fusion == "static" and s is not None
    radius = round(r.block_radius_frac * float(np.hypot(src.shape[0], src.shape[1])))
    reduced = src is not work
    if plane is not None:  # one fused pass
        target = np.zeros(src.shape[:2], np.float32) if reduced else (
            s if into and s is not None else plane)
        block_contrast_into(src, r.block_luminance_weight, radius, r.block_surround, scale,
                            target, accumulate=into and not reduced)
    else:
        from eaglemission.detectors.dtdmi.equations_static import block_contrast_cue

        target = block_contrast_cue(lab_features(src, r.block_luminance_weight), radius,
                                    r.block_surround)
        target *= np.float32(scale)
    if reduced:
        up = plane if plane is not None and not into else np.empty((h, w), np.float32)
        target = cv2.resize(target, (w, h), dst=up, interpolation=cv2.INTER_LINEAR)
    if into and s is not None and target is not s:
        target = np.add(s, target, out=s)
    if r.block_fusion == "static":
        return target, None
    return s, target


class BilinearUpsampling:
    """Per (source, target) resolution: how the numba kernels upsample a coarse plane on the fly
    (:meth:`plan`); cached until the engine reallocates."""

    def __init__(self) -> None:
        self.cache: dict[tuple[tuple[int, int], tuple[int, int]],
                       tuple[tuple[np.ndarray, ...], np.ndarray | None]] = {}

    def plan(self, base: np.ndarray, target_hw: tuple[int, int]
             ) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
        """The plane and :func:`.kernels.linear_coeffs` (rows, columns) the numba kernels
        upsample the coarse scales' sum from, on the fly.

        OpenCV's bilinear float resize matches the plain formula for power-of-two factors
        (weights 1/4, 3/4, ...) but not for every ratio (it quantises the weights). This is
        checked once per resolution on a random plane; where it does not match within 1e-6,
        ``base`` is resized by OpenCV to a full-resolution plane first, read with identity
        coefficients (the previous, slower way).
        """
        hw = (base.shape[0], base.shape[1])
        key = (hw, target_hw)
        if key not in self.cache:
            import eaglemission.detectors.dtdmi.kernels as kernels  # numba: loaded on use

            h, w = target_hw
            ys, yw = kernels.linear_coeffs(h, max(1, hw[0]))
            xs, xw = kernels.linear_coeffs(w, max(1, hw[1]))
            exact = True
            if hw[0] > 0:
                probe = np.random.RandomState(0).rand(*hw).astype(np.float32)
                ref = cv2.resize(probe, (w, h), interpolation=cv2.INTER_LINEAR)
                rows = probe[ys] * (1 - yw[:, None]) + probe[np.minimum(ys + 1, hw[0] - 1)] \
                    * yw[:, None]
                mine = rows[:, xs] * (1 - xw) + rows[:, np.minimum(xs + 1, hw[1] - 1)] * xw
                exact = float(np.abs(mine - ref).max()) <= 1e-6
            if exact:
                self.cache[key] = ((ys, yw, xs, xw), None)
            else:
                ident_y = kernels.linear_coeffs(h, h)
                ident_x = kernels.linear_coeffs(w, w)
                self.cache[key] = ((*ident_y, *ident_x), np.zeros((h, w), np.float32))
        coeffs, full = self.cache[key]
        if full is None:
            return base, coeffs
        h, w = target_hw
        cv2.resize(base, (w, h), dst=full, interpolation=cv2.INTER_LINEAR)
        return full, coeffs
