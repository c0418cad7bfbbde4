"""The stateful DTDMI computation (:class:`DTDMIEngine`, no plugin plumbing): Eqs. (1)-(15)
of [1] over preallocated planes, with the fused numba kernels of :mod:`.kernels` or plain numpy.

References
----------
.. [1] Eagle-eye inspired target detection (DTDMI), Sec. 2. DOI unknown.
"""

from __future__ import annotations

from typing import Any

import cv2
import eaglemission.detectors.dtdmi.equations_fusion as fusion
import eaglemission.detectors.dtdmi.refine as refine
import numpy as np
from eaglemission.detectors.dtdmi.config import DTDMIConfig, resolve
from eaglemission.detectors.dtdmi.dynamic import DynamicParams, MidbrainDynamic, scale_shape
from eaglemission.detectors.dtdmi.equations_static import gaussian_centre_weight
from eaglemission.detectors.dtdmi.maps import (
    BilinearUpsampling,
    add_block_cue,
    smooth_mapped,
    smooth_reduced,
    smoothing_factor,
)
from eaglemission.detectors.dtdmi.static import ClusterStatic, StaticParams

from eaglemission.perception.colour_bins import NBINS, quantize_bgr


class DTDMIEngine:
    """The stateful computation (no plugin plumbing): ``saliency(bgr, timestamp_ns)``.

    Full-frame planes are preallocated per resolution (fresh arrays every frame cost thousands
    of page faults at 1280x960); with ``backend="numba"`` the per-pixel passes are the fused
    kernels of :mod:`.kernels`, otherwise plain numpy with the same results (tested, 1e-5).
    """

    def __init__(self, cfg: DTDMIConfig) -> None:
        self.cfg = cfg
        self.r = resolve(cfg)
        self.numba = cfg.backend == "numba"
        if self.numba:
            import eaglemission.detectors.dtdmi.kernels as kernels

            self._k = kernels
            import eaglemission.detectors.dtdmi.kernels_general as kernels_general

            self._kg = kernels_general
        self.static = ClusterStatic(StaticParams(
            clusters=cfg.clusters, colour_space=self.r.colour_space,
            spatial_weight=self.r.spatial_weight, window_s=cfg.window_s,
            kmeans_weight=cfg.kmeans_weight, backend=cfg.backend,
            luminance_weight=self.r.luminance_weight, spread_sigma_frac=self.r.spread_sigma_frac,
            contrast_level=self.r.contrast_level, spread_pool=self.r.spread_pool))
        self.dynamic = MidbrainDynamic(DynamicParams(
            scales=tuple(cfg.scales), tau_s=cfg.tau_s, tensor_radius_px=cfg.tensor_radius_px,
            ego_motion=self.r.ego_motion, ego_motion_width_px=cfg.ego_motion_width_px,
            backend=cfg.backend, floor=cfg.dynamic_floor))
        self._shape: tuple[int, int] | None = None
        # S_s as a weighted sum of cues or the max fusion: the general (unstreamed) path of
        # _general_saliency
        self.general = (self.r.block_weight > 0 or self.r.fusion == "max"
                        or self.r.colour_weight != 1.0)

    @property
    def use_dynamic(self) -> bool:
        """Whether the dynamic part runs (``use_dynamic``)."""
        return self.cfg.use_dynamic

    def reset(self) -> None:
        self.static.reset()
        self.dynamic.reset()

    def _allocate(self, shape: tuple[int, int]) -> None:
        h, w = shape
        self._has_full = self.cfg.scales[0] == 1.0
        n_up = min(1, len(self.cfg.scales) - (1 if self._has_full else 0))
        # colour bin per pixel: the numba kernels compute it on the fly where they paint
        self._idx = np.zeros((1, 1) if self.numba else shape, np.uint16)
        self._out = np.zeros(shape, np.float32)
        # the general path's S_s and block cue planes
        self._s = np.zeros(shape if self.general else (1, 1), np.float32)
        self._blk = np.zeros(shape if self.general else (1, 1), np.float32)
        # numpy backend: the coarse scales upsampled to full resolution (numba: on the fly)
        self._ups = np.zeros((n_up, h, w) if not self.numba else (n_up, 1, 1), np.float32)
        self._no_base = np.zeros((0, 1), np.float32)
        self._no_lut = np.zeros(1, np.float32)
        # numba and no per-scale normalisation (that needs each scale's maximum first): every
        # scale is streamed into Eqs. (14)-(15) (_streamed) when the scales are the full
        # resolution plus at most two coarser ones of different sizes (the plain version sums
        # the coarse scales at the larger one's resolution; with two, that is a chain).
        coarse_hw = [scale_shape(shape, s) for s in self.cfg.scales[1:]]
        self._chain = (self.numba and not self.r.normalize_scales and self._has_full
                       and len(coarse_hw) <= 2 and len(set(coarse_hw)) == len(coarse_hw)
                       and shape not in coarse_hw)
        # streamed, no ego-motion (it aligns on the float grey), second scale exactly half:
        # its grey comes from kernels.grey_half
        # (and every further one exactly half the one before, so that dynamic.step reduces
        # it from that one, never from the 8-bit frame)
        self._half = None
        if self._chain and self.r.ego_motion == "none" and coarse_hw:
            ok, prev = True, (h, w)
            for hw in coarse_hw:
                ok = ok and prev[0] % 2 == 0 and prev[1] % 2 == 0 and \
                    hw == (prev[0] // 2, prev[1] // 2)
                prev = hw
            if ok:
                self._half = np.zeros(coarse_hw[0], np.float32)
        self._up = BilinearUpsampling()
        self._grey8 = np.zeros(shape, np.uint8)
        self._grey = np.zeros(shape, np.float32)
        self._hist = np.zeros(NBINS, np.float64)
        self._whist = np.zeros(NBINS, np.float64)
        self._mom = np.zeros((NBINS, 4), np.float64)
        self._dummy = np.zeros((1, 1), np.float32)
        rows = np.arange(h)[:, None]
        cols = np.arange(w)[None, :]
        c = self.r.centre_sigma_frac
        self._centre = (gaussian_centre_weight(rows, cols, shape, c).astype(np.float32)
                        if c > 0 else self._dummy)
        # the same Gaussian as a separable product (centre = row weight x column weight)
        self._centre_row = (gaussian_centre_weight(rows[:, 0], (w - 1) / 2.0, shape, c)
                            .astype(np.float32) if c > 0 else np.ones(h, np.float32))
        self._centre_col = (gaussian_centre_weight((h - 1) / 2.0, cols[0], shape, c)
                            .astype(np.float32) if c > 0 else np.ones(w, np.float32))
        # Default preset (numba): Eqs. (14)-(15) go straight into the f x f block means that
        # the smoothing starts from (kernels.combine / midbrain_combine with f > 1: what
        # smooth_mapped's INTER_AREA reduction gives), so no full-resolution S plane is written.
        self._pool_f = 0
        if (self.numba and self.r.blur_sigma_frac > 0 and self.r.fusion != "boost"
                and not self.general):
            f = smoothing_factor(self.r.blur_sigma_frac * float(np.hypot(h, w)))
            if f > 1 and h % f == 0 and w % f == 0:
                self._pool_f = f
                self._pooled = np.zeros((h // f, w // f), np.float32)
        self._shape = shape
        self._hw = shape  # the allocated resolution (self._shape: None forces a reallocation)

    # -- parts ----------------------------------------------------------------------------------
    def _static_lut(self, work: np.ndarray, timestamp_ns: int) -> np.ndarray:
        if self.static.field:  # field preset: compactness x per-bin contrast, absolute
            if self.numba:
                self._k.sampled_moments(work, self.static.p.sample_step_px, self._hist, self._mom)
                hist, mom = self._hist, self._mom
            else:
                self._idx[...] = quantize_bgr(work)
                hist, mom = self.static.moments(self._idx)
            lut = self.static.bin_saliency_field(hist, mom, self._hw)
        else:
            if self.numba:
                wgrid = self.static.weight_grid(self._hw)
                self._k.sampled_hist(work, self.static.p.sample_step_px, wgrid, self._hist,
                                     self._whist)
                hist, whist = self._hist, self._whist
            else:
                self._idx[...] = quantize_bgr(work)
                hist, whist = self.static.histograms(self._idx)
            lut = self.static.bin_saliency_from_hist(hist, whist, timestamp_ns)  # Eqs. (2)-(6)
        if self.r.static_exponent != 1.0:
            lut = np.power(lut, np.float32(self.r.static_exponent))
        return lut

    def _dynamic_and_product(self, work: np.ndarray, lut: np.ndarray | None,
                             timestamp_ns: int, centre: bool = True) -> float:
        """Eqs. (7)-(15) into ``self._out``; returns its maximum. ``lut`` None: S_M alone
        (Eq. (14)); ``centre`` False: no pixel-level centre weight."""
        cv2.cvtColor(work, cv2.COLOR_BGR2GRAY, dst=self._grey8)
        if self._half is not None:
            # the full scale reads the 8-bit image (kernels._response_row), the half scale is
            # its 2 x 2 block means: no full-resolution float grey plane
            self._k.grey_half(self._grey8, self._half)
            self.dynamic.step(self._grey8, timestamp_ns, defer=True, given={1: self._half})
            return self._streamed(work, lut, centre)
        np.multiply(self._grey8, np.float32(1.0 / 255.0), out=self._grey)
        if self._chain:
            self.dynamic.step(self._grey, timestamp_ns, defer=True)
            return self._streamed(work, lut, centre)
        maps = self.dynamic.step(self._grey, timestamp_ns)
        gamma = np.float32(self.r.dynamic_exponent)
        tops = self.dynamic.tops
        full = maps[0] if self._has_full else None
        coarse = maps[1:] if self._has_full else maps
        coarse_tops = tops[1:] if self._has_full else tops
        h, w = self._hw
        for k, m in enumerate(coarse):
            f = scale_compression(self.r.normalize_scales, coarse_tops[k])
            if f != 1.0:
                m *= np.float32(f)
            if gamma == 0.25:
                np.sqrt(m, out=m)
                np.sqrt(m, out=m)
            elif gamma != 1.0:
                np.power(m, gamma, out=m)
        base = self._no_base
        if coarse:
            # The coarser scales are summed at the largest coarse scale's resolution, so only
            # one plane is upsampled to full resolution (numba: on the fly, row by row).
            b = max(range(len(coarse)), key=lambda i: coarse[i].size)
            base = coarse[b]
            for k, m in enumerate(coarse):
                if k != b:
                    base += cv2.resize(m, (base.shape[1], base.shape[0]),
                                       interpolation=cv2.INTER_LINEAR)
            if not self.numba:
                cv2.resize(base, (w, h), dst=self._ups[0], interpolation=cv2.INTER_LINEAR)
        inv0 = scale_compression(self.r.normalize_scales, tops[0]) if full is not None else 1.0
        boost = self.r.fusion == "boost" and lut is not None
        use_static = lut is not None and not boost
        # with boost, the centre weight multiplies the whole S (after the boost), not S_M alone
        use_centre = self.r.centre_sigma_frac > 0 and not boost and centre
        n = len(maps)
        if self.numba:
            # self._pool_f > 1: S only as the block means the smoothing starts from
            lut_k = lut if use_static and lut is not None else np.zeros(1, np.float32)
            pooled = self._pooled if self._pool_f else self._dummy
            base, up = self._up.plan(base, self._hw)
            top = float(self._k.combine(
                full if full is not None else self._dummy, np.float32(inv0), float(gamma),
                full is not None, base, up, n, lut_k, work, use_static, self._centre_row,
                self._centre_col, use_centre, self._pool_f, pooled, self._out))
            if self._pool_f:
                return -1.0  # the maximum is taken after the smoothing
            return self._boost(work, lut, top) if boost and lut is not None else top
        acc = self._out
        acc[...] = 0.0
        if full is not None:
            x = full * np.float32(inv0)
            acc += np.sqrt(np.sqrt(x)) if gamma == 0.25 else x ** gamma
        if coarse:
            acc += self._ups[0]
        acc *= np.float32(1.0 / n)  # Eq. (14)
        if use_static and lut is not None:
            acc *= lut[self._idx]  # Eq. (15)
        if use_centre:
            acc *= self._centre
        if boost and lut is not None:
            acc[...] = fusion.boosted_saliency(lut[self._idx], acc, self.r.dynamic_gain)
            if self.r.centre_sigma_frac > 0 and centre:
                acc *= self._centre
        return float(acc.max())

    def _boost(self, work: np.ndarray, lut: np.ndarray, top: float) -> float:
        """Field preset's Eq. (15), ``S_s x (1 + gain x S_M)``, on ``self._out`` (numba)."""
        top = float(self._k.boost(work, lut, float(self.r.dynamic_gain), self._out))
        if self.r.centre_sigma_frac > 0:
            np.multiply(self._out, self._centre, out=self._out)
            top = float(self._out.max())
        return top

    def _streamed(self, work: np.ndarray, lut: np.ndarray | None, centre: bool = True) -> float:
        """Eqs. (7)-(15) (numba, ``self._chain``): every scale streamed by
        :func:`.kernels.midbrain_combine`, coarsest first, each Eq. (13) row consumed as made.

        A coarse scale's kernel writes ``S_M^gamma`` plus the (already compressed) coarser
        scale upsampled to it into its ``sm`` plane -- the sum the plain version builds at the
        largest coarse scale's resolution -- and the full-resolution scale adds that sum
        upsampled, divides by the number of scales (Eq. (14)) and applies Eq. (15). Returns
        the maximum of ``self._out`` (-1 when only the block means of the smoothing are made).
        """
        gamma = float(np.float32(self.r.dynamic_exponent))
        radius = int(self.cfg.tensor_radius_px)
        floor = float(self.cfg.dynamic_floor)
        deferred = self.dynamic.deferred
        boost = self.r.fusion == "boost" and lut is not None
        use_static = lut is not None and not boost
        use_centre = self.r.centre_sigma_frac > 0 and not boost and centre
        no_lut = self._no_lut
        base = self._no_base
        for sc, grey_s, gain in sorted(deferred[1:], key=lambda d: d[0].sm.size):
            b, up = self._up.plan(base, sc.shape)
            self._k.midbrain_combine(
                grey_s, sc.g_delayed, sc.g_prev, np.float32(gain), radius, floor, sc.o, gamma, b,
                up, 1, no_lut, work, False, self._centre_row, self._centre_col, False, 0,
                self._dummy, sc.sm)
            base = sc.sm
        sc, grey_s, gain = deferred[0]
        grey_scale = 1.0 / 255.0 if grey_s.dtype == np.uint8 else 1.0
        b, up = self._up.plan(base, self._hw)
        pooled = self._pooled if self._pool_f else self._dummy
        # boost in the same pass unless a centre weight follows it (then a pass of its own)
        boost_in = boost and self.r.centre_sigma_frac == 0
        top = float(self._k.midbrain_combine(
            grey_s, sc.g_delayed, sc.g_prev, np.float32(gain), radius, floor, sc.o, gamma, b, up,
            len(deferred), lut if (use_static or boost_in) and lut is not None else no_lut, work,
            use_static,
            self._centre_row, self._centre_col, use_centre, self._pool_f, pooled, self._out,
            float(self.r.dynamic_gain) if boost_in else -1.0, grey_scale))
        if self._pool_f:
            return -1.0  # the maximum is taken after the smoothing
        return self._boost(work, lut, top) if boost and not boost_in and lut is not None else top

    def _general_saliency(self, work: np.ndarray, timestamp_ns: int) -> np.ndarray:
        """S of the general path into ``self._out`` (no per-pixel fusion kernel): S_s as
        ``colour_weight x`` the colour cue ``+ block_weight x`` the block contrast cue (or the
        block cue added after Eq. (15), ``block_fusion: add``), Eq. (15) as the preset's fusion
        with S_M (Eqs. (7)-(14)), then the centre weight."""
        r = self.r
        out = self._out
        s: np.ndarray | None = None
        blk: np.ndarray | None = None
        if self.cfg.use_static:
            if r.colour_weight > 0:
                lut = self._static_lut(work, timestamp_ns)
                if r.colour_weight != 1.0:  # on the look-up: the same products as on the plane
                    lut = lut * np.float32(r.colour_weight)
                s = self._s
                self._paint(work, lut, s)
            if r.block_weight > 0:
                s, blk = add_block_cue(work, r, s, self._blk if self.numba else None)
        if self.use_dynamic:
            self._dynamic_and_product(work, None, timestamp_ns, centre=False)  # S_M in out
            if s is None:
                s = out.copy()
            elif r.fusion == "max":
                s = fusion.fused_saliency_max(s, out, r.dynamic_gain).astype(np.float32)
            elif r.fusion == "boost":
                s = fusion.boosted_saliency(s, out, r.dynamic_gain).astype(np.float32)
            else:
                s = fusion.final_saliency(s, out).astype(np.float32)
        if blk is not None:  # block_fusion "add": after Eq. (15)
            s = blk if s is None else np.add(s, blk, out=s)
        if s is None:
            out[...] = 0.0
        elif s is not out:
            out[...] = s
        if r.centre_sigma_frac > 0:
            out *= self._centre
        return out

    def _paint(self, work: np.ndarray, lut: np.ndarray, out: np.ndarray) -> None:
        """``out = lut[bin(work)]`` (colour bins of :func:`.static.quantize_bgr`)."""
        if self.numba:
            self._k.paint_static(work, lut, self._dummy, False, out)
        else:
            np.take(lut, quantize_bgr(work), out=out)

    # -- whole frame ----------------------------------------------------------------------------
    def saliency(self, bgr: np.ndarray, timestamp_ns: int, native: bool = False) -> np.ndarray:
        """float32 (H, W) map in [0, 1] at the resolution of ``bgr`` (``native``: at the
        processing resolution, not resized back; not with colour propagation)."""
        if native and self.r.colour_propagation > 0:
            raise ValueError("native: the colour propagation reads the frame's resolution")
        sal = self._map(bgr, timestamp_ns, native)
        if self.r.colour_propagation > 0:
            sal = propagate_by_colour(sal, bgr, self.r.colour_propagation,
                                      self._k if self.numba else None, self._paint)
        return sal

    def _map(self, bgr: np.ndarray, timestamp_ns: int, native: bool = False) -> np.ndarray:
        """The map before the refinements of :mod:`.refine`."""
        cfg = self.cfg
        work = bgr
        if cfg.downscale > 1:
            h, w = bgr.shape[:2]
            work = cv2.resize(bgr, (max(8, w // cfg.downscale), max(8, h // cfg.downscale)),
                              interpolation=cv2.INTER_AREA)
        work = np.ascontiguousarray(work)
        shape = (work.shape[0], work.shape[1])
        out_hw = shape if native else (bgr.shape[0], bgr.shape[1])
        if shape != self._shape:
            self._allocate(shape)
        if self.general:
            return self._finish(self._general_saliency(work, timestamp_ns), -1.0, shape, out_hw)
        lut = self._static_lut(work, timestamp_ns) if cfg.use_static else None
        out = self._out
        if self.use_dynamic:
            top = self._dynamic_and_product(work, lut, timestamp_ns)
        else:
            assert lut is not None
            use_centre = self.r.centre_sigma_frac > 0
            if self.numba:
                top = float(self._k.paint_static(work, lut, self._centre, use_centre, out))
            else:
                np.take(lut, self._idx, out=out)
                if use_centre:
                    out *= self._centre
                top = float(out.max())
        if self.use_dynamic and self._pool_f:
            sigma_px = self.r.blur_sigma_frac * float(np.hypot(*shape))
            return smooth_reduced(self._pooled, sigma_px / self._pool_f, True, out_hw,
                                  self._to_unit)
        return self._finish(out, top, shape, out_hw)

    def _finish(self, out: np.ndarray, top: float, shape: tuple[int, int],
                full_shape: tuple[int, int]) -> np.ndarray:
        """Smoothing, the output scale and the resize from ``shape`` to ``full_shape``."""
        if self.r.blur_sigma_frac > 0:
            return smooth_mapped(out, self.r.blur_sigma_frac * float(np.hypot(*shape)),
                                 full_shape, self._to_unit)
        result = np.empty(shape, np.float32)
        self._to_unit(out, top if top >= 0 else None, result)
        if shape != full_shape:
            return cv2.resize(result, (full_shape[1], full_shape[0]),
                              interpolation=cv2.INTER_LINEAR)
        return result

    def _to_unit(self, s: np.ndarray, top: float | None, result: np.ndarray) -> None:
        """Map S >= 0 to [0, 1] into ``result``: per-frame max or absolute saturation."""
        if self.r.output_scale == "absolute":
            np.add(s, np.float32(self.r.saturation), out=result)
            np.divide(s, result, out=result)
            return
        top = float(s.max()) if top is None else top
        if top > 1e-30:
            np.multiply(s, np.float32(1.0 / top), out=result)
            np.minimum(result, np.float32(1.0), out=result)
        else:
            result[...] = 0.0


def scale_compression(normalize: bool, top: float) -> float:
    """Per-scale factor ``1 / max`` (``normalize``: default preset) or 1 (literal)."""
    if not normalize:
        return 1.0
    return 1.0 / top if top > 0 else 1.0


def propagate_by_colour(sal: np.ndarray, bgr: np.ndarray, weight: float, kernels: Any,
                        paint: Any) -> np.ndarray:
    """:func:`.refine.propagated_saliency`: the map blended with the mean of the map over each
    colour bin's pixels (every 2nd row and column of the frame sampled); ``kernels``: the
    engine's numba kernels (one fused pass), None for numpy (``paint`` fills the bins' means)."""
    step = 2
    img = np.ascontiguousarray(bgr)
    if kernels is not None:
        counts = np.zeros(NBINS, np.float64)
        weighted = np.zeros(NBINS, np.float64)
        wgrid = np.ascontiguousarray(sal[::step, ::step], dtype=np.float64)
        kernels.sampled_hist(img, step, wgrid, counts, weighted)
    else:
        idx = quantize_bgr(img[::step, ::step]).ravel()
        counts = np.bincount(idx, minlength=NBINS).astype(np.float64)
        weighted = np.bincount(idx, weights=sal[::step, ::step].ravel().astype(np.float64),
                               minlength=NBINS).astype(np.float64)
    lut = refine.colour_mean_saliency(counts, weighted)
    if kernels is not None:  # the same blend in one pass, in place
        out = np.ascontiguousarray(sal, dtype=np.float32)
        if out is sal and not out.flags.writeable:
            out = out.copy()
        kernels.blend_lut(img, lut, float(weight), out)
        return out
    painted = np.empty(sal.shape, np.float32)
    paint(img, lut, painted)
    return refine.propagated_saliency(sal, painted, weight)
