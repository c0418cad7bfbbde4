"""Fused numba kernels for DTDMI (same results as :mod:`.midbrain_step` and the plain numpy
path of :mod:`.detector`, within 1e-5; tested).

Per scale, row by row over preallocated float32 planes instead of ~20 numpy passes:

1. Eqs. (7)-(9): response ``G`` and delay update, written in place into the state planes;
2. Eqs. (10)-(11): Reichardt correlators and 2-D synthesis into ``o``;
3. Eqs. (12)-(13): box sums of the tensor entries over a ring of rows (re-summed, no running-sum
   drift) and the closed-form eigenvalue discrepancy.

:func:`midbrain_combine` streams 1-3 and Eqs. (14)-(15) for one scale: each Eq. (13) row is
used as soon as it is made (plus the coarser scales' sum upsampled on the fly, the colour
look-up of S_s, the separable centre weight and, for the default preset, the block means the
smoothing starts from), so no full-resolution S_M, S_s, upsampled or S plane is written.
:func:`midbrain_step_fused` (1-3 into an S_M plane) and :func:`combine` (Eqs. (14)-(15) from
planes) serve the configurations that need the maps first (per-scale normalisation).

Speed notes (numba 0.68, AVX-512): a loop vectorises only if its indices are the bare loop
counter -- ``a[c - 1]`` or ``a[k + c]`` makes numba emit a negative-index wrap-around check that
stops LLVM (5x slower), hence the shifted views; a running scalar ``max`` does not vectorise
(per-column maxima do); scattering into one histogram entry sample after sample serialises on
the store (interleaved sub-histograms do not).

``cache=True`` keeps the compiled code on disk; the first call per process compiles (~2 s).
Threads: the kernels are serial (one core per camera, as the speed target is stated).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numba import njit
from numpy.typing import NDArray

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]
I64 = NDArray[np.int64]
#: float32 grey in 0..1, or the 8-bit grey image (read with a scale of 1 / 255)
Grey = NDArray[np.float32] | NDArray[np.uint8]
#: :func:`linear_coeffs` of the rows then of the columns: (index, weight, index, weight)
Coeffs = tuple[NDArray[Any], ...]


@njit(cache=True, nogil=True, inline="always")
def _response_px(grey: Grey, g_delayed: F32, g_prev: F32, gain: np.float32, r: int, rm: int,
                 rp: int, c: int, s: np.float32) -> None:  # pragma: no cover - jitted
    w = grey.shape[1]
    gx = np.float32(grey[r, min(c + 1, w - 1)]) * s - np.float32(grey[r, max(c - 1, 0)]) * s
    gy = np.float32(grey[rp, c]) * s - np.float32(grey[rm, c]) * s
    d = g_delayed[r, c]
    g_delayed[r, c] = d + (g_prev[r, c] - d) * gain
    g_prev[r, c] = np.sqrt(gx * gx + gy * gy)


@njit(cache=True, nogil=True)
def _response_row(grey: Grey, g_delayed: F32, g_prev: F32, gain: np.float32, r: int,
                  s: np.float32) -> None:  # pragma: no cover - jitted
    """Row ``r`` of Eq. (7) into ``g_prev`` and Eqs. (8)-(9) into ``g_delayed``, in place.

    The grey value is ``grey * s``: float32 ``grey`` with ``s = 1``, or the 8-bit grey image
    with ``s = 1 / 255`` (the same float32 values as converting it first, without the plane).
    The interior runs over views indexed by the bare loop counter (see :func:`_tensor_row`).
    """
    h, w = grey.shape
    rm = r - 1 if r > 0 else 0
    rp = r + 1 if r < h - 1 else h - 1
    if w > 2:
        right = grey[r, 2:]
        left = grey[r, : w - 2]
        down = grey[rp, 1 : w - 1]
        up = grey[rm, 1 : w - 1]
        gd = g_delayed[r, 1 : w - 1]
        gp = g_prev[r, 1 : w - 1]
        for c in range(w - 2):
            gx = np.float32(right[c]) * s - np.float32(left[c]) * s
            gy = np.float32(down[c]) * s - np.float32(up[c]) * s
            d = gd[c]
            gd[c] = d + (gp[c] - d) * gain
            gp[c] = np.sqrt(gx * gx + gy * gy)
    _response_px(grey, g_delayed, g_prev, gain, r, rm, rp, 0, s)
    if w > 1:
        _response_px(grey, g_delayed, g_prev, gain, r, rm, rp, w - 1, s)


@njit(cache=True, nogil=True)
def _correlate_row(g: F32, g_delayed: F32, o: F32, r: int) -> None:  # pragma: no cover - jitted
    """Row ``r`` of Eqs. (10)-(11) (needs rows ``r`` and ``r + 1`` of ``g``, ``g_delayed``)."""
    h, w = g.shape
    rp = r + 1 if r < h - 1 else h - 1
    if w > 1:
        g0 = g[r, : w - 1]
        g1 = g[r, 1:]
        d0 = g_delayed[r, : w - 1]
        d1 = g_delayed[r, 1:]
        gdn = g[rp, : w - 1]
        ddn = g_delayed[rp, : w - 1]
        orow = o[r, : w - 1]
        for c in range(w - 1):
            gg = g0[c]
            d = d0[c]
            rx = gg * d1[c] - g1[c] * d
            ry = gg * ddn[c] - gdn[c] * d
            orow[c] = np.sqrt(rx * rx + ry * ry)
    c = w - 1
    rx = g[r, c] * g_delayed[r, c] - g[r, c] * g_delayed[r, c]
    ry = g[r, c] * g_delayed[rp, c] - g[rp, c] * g_delayed[r, c]
    o[r, c] = np.sqrt(rx * rx + ry * ry)


@njit(cache=True, nogil=True)
def response_and_delay(grey: F32, g_delayed: F32, g_prev: F32,
                       gain: np.float32) -> None:  # pragma: no cover
    """Eq. (7) into ``g_prev`` and Eqs. (8)-(9) into ``g_delayed``, in place."""
    for r in range(grey.shape[0]):
        _response_row(grey, g_delayed, g_prev, gain, r, np.float32(1.0))


@njit(cache=True, nogil=True)
def correlate(g: F32, g_delayed: F32, o: F32) -> None:  # pragma: no cover - jitted
    """Eqs. (10)-(11): ``o = |(G Gd' - G' Gd)_x, (G Gd' - G' Gd)_y|``, neighbour = next pixel."""
    for r in range(g.shape[0]):
        _correlate_row(g, g_delayed, o, r)


@njit(cache=True, nogil=True)
def response_and_correlate(grey: F32, g_delayed: F32, g_prev: F32, gain: np.float32,
                           o: F32) -> None:  # pragma: no cover - jitted
    """:func:`response_and_delay` then :func:`correlate` in one sweep over the rows.

    Row ``r`` of Eqs. (10)-(11) needs the updated rows ``r`` and ``r + 1`` only, so the
    response of row ``r + 1`` is computed just before: each plane is streamed once.
    """
    h = grey.shape[0]
    _response_row(grey, g_delayed, g_prev, gain, 0, np.float32(1.0))
    for r in range(h):
        if r + 1 < h:
            _response_row(grey, g_delayed, g_prev, gain, r + 1, np.float32(1.0))
        _correlate_row(g_prev, g_delayed, o, r)


@njit(cache=True, nogil=True, fastmath=True)
def _tensor_row(o: F32, r: int, radius: int, pad: F32, hu: F32,
                hv: F32) -> None:  # pragma: no cover
    """Row ``r`` of ``u = O_x^2 - O_y^2`` and ``v = 2 O_x O_y`` ([-1, 0, 1] derivatives,
    replicated border) into the zero-padded scratch rows ``pad[0]``, ``pad[1]`` (width
    W + 2 radius), then their horizontal (2 radius + 1) box sums into ``hu``, ``hv``
    (``pad[2:4]``: scratch).

    Loops run over views indexed by the bare loop counter: an index such as ``c - 1`` or
    ``radius + c`` makes numba emit a negative-index wrap-around check that stops LLVM from
    vectorising the loop (5x slower).
    """
    h, w = o.shape
    pu = pad[0]
    pv = pad[1]
    rm = r - 1 if r > 0 else 0
    rp = r + 1 if r < h - 1 else h - 1
    two = np.float32(2.0)
    if w > 2:
        right = o[r, 2:]
        left = o[r, : w - 2]
        down = o[rp, 1 : w - 1]
        up = o[rm, 1 : w - 1]
        ou = pu[radius + 1 : radius + w - 1]
        ov = pv[radius + 1 : radius + w - 1]
        for c in range(w - 2):
            ox = right[c] - left[c]
            oy = down[c] - up[c]
            ou[c] = ox * ox - oy * oy
            ov[c] = two * ox * oy
    for c in (0, w - 1):
        ox = o[r, min(c + 1, w - 1)] - o[r, max(c - 1, 0)]
        oy = o[rp, c] - o[rm, c]
        pu[radius + c] = ox * ox - oy * oy
        pv[radius + c] = two * ox * oy
    if radius == 2:  # the default: pair sums, then (p0 + p1) + (p2 + p3) + p4
        su = pad[2]
        sv = pad[3]
        a_u = pu[: w + 3]
        b_u = pu[1 : w + 4]
        a_v = pv[: w + 3]
        b_v = pv[1 : w + 4]
        for c in range(w + 3):
            su[c] = a_u[c] + b_u[c]
            sv[c] = a_v[c] + b_v[c]
        s2u = su[2 : w + 2]
        s2v = sv[2 : w + 2]
        p4u = pu[4 : w + 4]
        p4v = pv[4 : w + 4]
        for c in range(w):
            hu[c] = su[c] + s2u[c] + p4u[c]
            hv[c] = sv[c] + s2v[c] + p4v[c]
        return
    src_u = pu[:w]
    src_v = pv[:w]
    for c in range(w):
        hu[c] = src_u[c]
        hv[c] = src_v[c]
    for d in range(1, 2 * radius + 1):
        src_u = pu[d : d + w]
        src_v = pv[d : d + w]
        for c in range(w):
            hu[c] += src_u[c]
            hv[c] += src_v[c]


@njit(cache=True, nogil=True, fastmath=True)
def _push_row(o: F32, j: int, radius: int, pad: F32, ring: F32,
              pairs: F32) -> None:  # pragma: no cover
    """Row ``j`` of the horizontal sums into ``ring[j % k]`` (zeros for ``j >= H``: the
    zero-padded box sum); with radius 2 also the pair ``pairs[(j - 1) % k] = row j-1 + row j``."""
    h = o.shape[0]
    k = 2 * radius + 1
    s = j % k
    if j < h:
        _tensor_row(o, j, radius, pad, ring[s, 0], ring[s, 1])
    else:
        ring[s, :, :] = 0.0
    if radius == 2:
        sp = (j - 1) % k
        for q in range(2):
            prev = ring[sp, q]
            cur = ring[s, q]
            dst = pairs[sp, q]
            for c in range(prev.shape[0]):
                dst[c] = prev[c] + cur[c]


@njit(cache=True, nogil=True, fastmath=True)
def _vertical_sum(ring: F32, pairs: F32, r: int, radius: int, au: F32,
                  av: F32) -> None:  # pragma: no cover
    """Sum of the ring's rows ``r - radius .. r + radius`` into ``au``, ``av`` (radius 2:
    ``(R0 + R1) + (R2 + R3) + R4`` from the pairs, 3 loads per value instead of 5)."""
    k = 2 * radius + 1
    w = au.shape[0]
    if radius == 2:
        for q in range(2):
            a = pairs[(r - 2) % k, q]
            b = pairs[r % k, q]
            e = ring[(r + 2) % k, q]
            dst = au if q == 0 else av
            for c in range(w):
                dst[c] = a[c] + b[c] + e[c]
        return
    bu = ring[0, 0]
    bv = ring[0, 1]
    for c in range(w):
        au[c] = bu[c]
        av[c] = bv[c]
    for q in range(1, k):
        bu = ring[q, 0]
        bv = ring[q, 1]
        for c in range(w):
            au[c] += bu[c]
            av[c] += bv[c]


@njit(cache=True, nogil=True, fastmath=True)
def _tensor_buffers(w: int, radius: int) -> tuple[F32, F32, F32]:  # pragma: no cover - jitted
    """Zeroed ring, pair ring and padded scratch rows of the Eq. (12) box sums."""
    k = 2 * radius + 1
    return (np.zeros((k, 2, w), np.float32), np.zeros((k, 2, w), np.float32),
            np.zeros((4, w + 2 * radius), np.float32))


@njit(cache=True, nogil=True, fastmath=True)
def tensor_discrepancy(o: F32, radius: int, floor: float,
                       sm: F32) -> np.float32:  # pragma: no cover
    """Eqs. (12)-(13): box-summed structure tensor of ``o``; ``max((l1 - l2)^2 - floor, 0)``.

    ``(l1 - l2)^2 = (D_xx - D_yy)^2 + 4 D_xy^2 = |sum (O_x + i O_y)^2|^2``: only the two box
    sums of ``u = O_x^2 - O_y^2`` and ``v = 2 O_x O_y`` are needed (not three). Each row's
    ``u``, ``v`` are computed and summed horizontally once into a ring of the 2 r + 1 rows of
    the window (zero rows beyond the image: the zero-padded box sum of the reference); the
    vertical sum is re-taken over the ring for every row (no running-sum drift: a flat area
    stays exactly 0). Returns the maximum of ``sm``.
    """
    h, w = o.shape
    ring, pairs, pad = _tensor_buffers(w, radius)
    au = np.empty(w, np.float32)
    av = np.empty(w, np.float32)
    fl = np.float32(floor)
    zero = np.float32(0.0)
    for j in range(radius):
        _push_row(o, j, radius, pad, ring, pairs)
    lanes = np.zeros(w, np.float32)  # per-column maxima: a running scalar max does not vectorise
    for r in range(h):
        _push_row(o, r + radius, radius, pad, ring, pairs)
        _vertical_sum(ring, pairs, r, radius, au, av)
        smr = sm[r]
        for c in range(w):
            v = au[c] * au[c] + av[c] * av[c] - fl
            v = v if v > zero else zero
            smr[c] = v
            t = lanes[c]
            lanes[c] = v if v > t else t
    top: np.float32 = lanes.max()
    return top


@njit(cache=True, nogil=True)
def sampled_hist(bgr: U8, step: int, wgrid: F64, hist: F64, whist: F64) -> None:  # pragma: no cover
    """Counts and spatial-weight sums of the 12-bit colour bins over the pixels on a ``step``
    grid into ``hist`` / ``whist`` (zeroed here); the full-resolution bins are computed on the
    fly where they are painted (:func:`combine`, :func:`paint_static`).

    Consecutive samples go to 4 interleaved sub-histograms, summed at the end: neighbouring
    pixels mostly share a bin, and adding to one entry sample after sample serialises on the
    store (3x slower).
    """
    h, w = bgr.shape[0], bgr.shape[1]
    nb = hist.shape[0]
    counts = np.zeros((4, nb), np.int64)
    wsums = np.zeros((4, nb), np.float64)
    for r in range(0, h, step):
        row = bgr[r]
        wrow = wgrid[r // step]
        j = 0
        for c in range(0, w, step):
            i = ((np.int64(row[c, 0]) >> 4) << 8) | ((np.int64(row[c, 1]) >> 4) << 4) \
                | (np.int64(row[c, 2]) >> 4)
            lane = j & 3
            counts[lane, i] += 1
            wsums[lane, i] += wrow[j]
            j += 1
    for b in range(nb):
        hist[b] = float(counts[0, b] + counts[1, b] + counts[2, b] + counts[3, b])
        whist[b] = (wsums[0, b] + wsums[1, b]) + (wsums[2, b] + wsums[3, b])


@njit(cache=True, nogil=True)
def sampled_moments(bgr: U8, step: int, hist: F64, mom: F64) -> None:  # pragma: no cover - jitted
    """Counts and spatial moments (sum of column, row, column^2, row^2) of the 12-bit colour
    bins over the pixels on a ``step`` grid into ``hist`` (B,) / ``mom`` (B, 4), zeroed here
    (field preset: :func:`.equations.distribution_cue`).

    Integer sums (exact, as the float64 sums were) in 4 interleaved lanes, as
    :func:`sampled_hist`.
    """
    h, w = bgr.shape[0], bgr.shape[1]
    nb = hist.shape[0]
    acc = np.zeros((nb, 4, 5), np.int64)
    for r in range(0, h, step):
        row = bgr[r]
        r2 = np.int64(r) * r
        j = 0
        for c in range(0, w, step):
            i = ((np.int64(row[c, 0]) >> 4) << 8) | ((np.int64(row[c, 1]) >> 4) << 4) \
                | (np.int64(row[c, 2]) >> 4)
            a = acc[i, j & 3]
            a[0] += 1
            a[1] += c
            a[2] += r
            a[3] += np.int64(c) * c
            a[4] += r2
            j += 1
    for b in range(nb):
        t = acc[b]
        hist[b] = float(t[0, 0] + t[1, 0] + t[2, 0] + t[3, 0])
        for q in range(4):
            mom[b, q] = float(t[0, q + 1] + t[1, q + 1] + t[2, q + 1] + t[3, q + 1])


@njit(cache=True, nogil=True, fastmath=True)
def boost(bgr: U8, lut: F32, gain: float, out: F32) -> np.float32:  # pragma: no cover - jitted
    """``out = lut[bin(bgr)] * (1 + gain * out)`` in place (field preset's Eq. (15)); returns
    the maximum of ``out``."""
    h, w = out.shape
    lanes = np.zeros(w, np.float32)
    g = np.float32(gain)
    for r in range(h):
        px = bgr[r]
        orow = out[r]
        for c in range(w):
            i = ((np.uint16(px[c, 0]) >> 4) << 8) | ((np.uint16(px[c, 1]) >> 4) << 4) \
                | (np.uint16(px[c, 2]) >> 4)
            v = lut[i] * (np.float32(1.0) + g * orow[c])
            orow[c] = v
            t = lanes[c]
            lanes[c] = v if v > t else t
    top: np.float32 = lanes.max()
    return top


@njit(cache=True, nogil=True, fastmath=True)
def paint_static(bgr: U8, lut: F32, centre: F32, use_centre: bool,
                 out: F32) -> np.float32:  # pragma: no cover
    """``out = lut[bin(bgr)] (* centre)``: the static map alone; returns its maximum."""
    h, w = out.shape
    lanes = np.zeros(w, np.float32)
    for r in range(h):
        px = bgr[r]
        orow = out[r]
        for c in range(w):
            i = ((np.uint16(px[c, 0]) >> 4) << 8) | ((np.uint16(px[c, 1]) >> 4) << 4) \
                | (np.uint16(px[c, 2]) >> 4)
            v = lut[i]
            if use_centre:
                v *= centre[r, c]
            orow[c] = v
            t = lanes[c]
            lanes[c] = v if v > t else t
    top: np.float32 = lanes.max()
    return top


@njit(cache=True, nogil=True)
def blend_lut(bgr: U8, lut: F32, weight: float, sal: F32) -> None:  # pragma: no cover - jitted
    """``sal = (1 - weight) sal + weight lut[bin(bgr)]`` in place, one pass
    (:func:`.refine.propagated_saliency` of the painted colour means)."""
    h, w = sal.shape
    keep = np.float32(1.0 - weight)
    wt = np.float32(weight)
    for r in range(h):
        px = bgr[r]
        srow = sal[r]
        for c in range(w):
            i = ((np.uint16(px[c, 0]) >> 4) << 8) | ((np.uint16(px[c, 1]) >> 4) << 4) \
                | (np.uint16(px[c, 2]) >> 4)
            srow[c] = keep * srow[c] + wt * lut[i]


@njit(cache=True, nogil=True, fastmath=True)
def _double_row(src: F32, dst: F32) -> None:  # pragma: no cover - jitted
    """``dst`` (2 n) = ``src`` (n) resized x2 bilinearly, as :func:`linear_coeffs` gives it:
    ``dst[2 m] = src[m - 1] / 4 + 3 src[m] / 4``, ``dst[2 m + 1] = 3 src[m] / 4 + src[m + 1] / 4``,
    the end pixels copied."""
    wb = src.shape[0]
    q = np.float32(0.25)
    t = np.float32(0.75)
    a = src[: wb - 1]
    b = src[1:]
    even = dst[2 : 2 * wb - 1 : 2]
    odd = dst[1 : 2 * wb - 2 : 2]
    for m in range(wb - 1):
        even[m] = a[m] * q + b[m] * t
        odd[m] = a[m] * t + b[m] * q
    dst[0] = src[0]
    dst[2 * wb - 1] = src[wb - 1]


@njit(cache=True, nogil=True, fastmath=True)
def _upsampled_row(base: F32, up: Coeffs, r: int, hbuf: F32,
                   tags: I64) -> np.float32:  # pragma: no cover
    """Row ``r`` of ``cv2.resize(base, INTER_LINEAR)`` (``up`` from :func:`linear_coeffs`):
    the two source rows interpolated horizontally (kept in ``hbuf``, their indices in
    ``tags``, as consecutive output rows share them), then vertically, as OpenCV does."""
    yofs, yw, xofs, xw = up
    hb = base.shape[0]
    w = hbuf.shape[1]
    y0 = yofs[r]
    y1 = min(y0 + 1, hb - 1)
    for q in range(2):
        y = y0 if q == 0 else y1
        if tags[q] == y:
            continue
        if tags[1 - q] == y:  # swap rows: the other buffer already holds it
            hbuf[q, :] = hbuf[1 - q, :]
            tags[q] = y
            continue
        src = base[y]
        wb = src.shape[0]
        dst = hbuf[q]
        if w == 2 * wb and wb > 1:  # factor 2 (the default scales): weights 1/4, 3/4, no gather
            _double_row(src, dst)
        else:
            for c in range(w):
                x0 = xofs[c]
                x1 = min(x0 + 1, wb - 1)
                fx = xw[c]
                dst[c] = src[x0] * (np.float32(1.0) - fx) + src[x1] * fx
        tags[q] = y
    fy: np.float32 = yw[r]
    return fy


@njit(cache=True, nogil=True, fastmath=True)
def _combine_row(s0: F32, inv0: np.float32, gamma: float, has_full: bool, base: F32, up: Coeffs,
                 hbuf: F32, tags: I64, r: int, inv_n: np.float32, lut: F32, bgr: U8,
                 use_static: bool, centre_row: F32, centre_col: F32, use_centre: bool, row: F32,
                 boost_gain: float = -1.0) -> None:  # pragma: no cover
    """Row ``r`` of Eqs. (14)-(15) into ``row`` (see :func:`combine`); ``s0`` is row ``r`` of
    the full-resolution Eq. (13) map. ``boost_gain >= 0``: then the field preset's Eq. (15),
    ``lut[bin] * (1 + boost_gain * row)`` (as :func:`boost`)."""
    w = row.shape[0]
    if has_full:
        if gamma == 0.25:
            for c in range(w):
                row[c] = np.sqrt(np.sqrt(s0[c] * inv0))
        elif gamma == 1.0:
            for c in range(w):
                row[c] = s0[c] * inv0
        else:
            for c in range(w):
                row[c] = (s0[c] * inv0) ** gamma
    else:
        row[:] = 0.0
    if base.shape[0] > 0:
        fy = _upsampled_row(base, up, r, hbuf, tags)
        b0 = hbuf[0]
        b1 = hbuf[1]
        gy = np.float32(1.0) - fy
        for c in range(w):
            row[c] += b0[c] * gy + b1[c] * fy
    for c in range(w):
        row[c] *= inv_n
    if use_static:
        px = bgr[r]
        for c in range(w):
            i = ((np.uint16(px[c, 0]) >> 4) << 8) | (
                (np.uint16(px[c, 1]) >> 4) << 4) | (np.uint16(px[c, 2]) >> 4)
            row[c] *= lut[i]
    if use_centre:
        cr = centre_row[r]
        for c in range(w):
            row[c] *= cr * centre_col[c]
    if boost_gain >= 0.0:
        g = np.float32(boost_gain)
        px = bgr[r]
        for c in range(w):
            i = ((np.uint16(px[c, 0]) >> 4) << 8) | (
                (np.uint16(px[c, 1]) >> 4) << 4) | (np.uint16(px[c, 2]) >> 4)
            row[c] = lut[i] * (np.float32(1.0) + g * row[c])


@njit(cache=True, nogil=True, fastmath=True)
def _emit_row(row: F32, r: int, f: int, acc: F32, pooled: F32, out: F32,
              lanes: F32) -> None:  # pragma: no cover
    """Row ``r`` of S into ``out`` (``f == 0``; ``lanes``: running per-column maxima) or into
    the ``f`` x ``f`` block means of ``pooled`` (``acc`` sums the rows of a block)."""
    w = row.shape[0]
    if f == 0:
        orow = out[r]
        for c in range(w):
            v = row[c]
            orow[c] = v
            t = lanes[c]
            lanes[c] = v if v > t else t
        return
    if r % f == 0:
        acc[:] = 0.0
    for c in range(w):
        acc[c] += row[c]
    if r % f == f - 1:
        prow = pooled[r // f]
        area = np.float32(1.0 / (f * f))
        for pc in range(prow.shape[0]):
            blk = acc[pc * f : pc * f + f]
            t = np.float32(0.0)
            for d in range(f):
                t += blk[d]
            prow[pc] = t * area


@njit(cache=True, nogil=True, fastmath=True)
def combine(sm0: F32, inv0: np.float32, gamma: float, has_full: bool, base: F32, up: Coeffs,
            n_scales: int, lut: F32, bgr: U8, use_static: bool, centre_row: F32,
            centre_col: F32, use_centre: bool, f: int, pooled: F32,
            out: F32) -> np.float32:  # pragma: no cover
    """Eq. (14) and Eq. (15) in one pass over rows; returns the maximum of ``out``.

    ``S = lut[bin(bgr)] * centre * (f(sm0 * inv0) + sum_k ups[k]) / n_scales`` where
    ``f(x) = x ** gamma`` (the full-resolution scale, normalised here) and ``ups`` is the sum
    of the other scales (already normalised and compressed) at the resolution of ``base``
    (0 rows: none), upsampled bilinearly on the fly as ``cv2.resize(base, (W, H),
    INTER_LINEAR)`` does (``up``: :func:`linear_coeffs`); the centre weight is separable
    (``centre[r, c] = centre_row[r] * centre_col[c]``, the Gaussian of
    :func:`.equations.gaussian_centre_weight`). ``f == 0``: S into ``out`` (H, W); ``f > 1``:
    only its ``f`` x ``f`` block means into ``pooled`` (H / f, W / f) -- what
    ``cv2.resize(S, INTER_AREA)`` gives for an integer factor -- and 0 is returned.
    """
    h, w = bgr.shape[0], bgr.shape[1]
    inv_n = np.float32(1.0 / n_scales)
    row = np.empty(w, np.float32)
    acc = np.empty(w, np.float32)
    hbuf = np.empty((2, w), np.float32)
    tags = np.full(2, -1, np.int64)
    lanes = np.zeros(w, np.float32)
    for r in range(h):
        _combine_row(sm0[r] if has_full else row, inv0, gamma, has_full, base, up, hbuf, tags,
                     r, inv_n, lut, bgr, use_static, centre_row, centre_col, use_centre, row)
        _emit_row(row, r, f, acc, pooled, out, lanes)
    top: np.float32 = lanes.max()
    return top


@njit(cache=True, nogil=True, fastmath=True)
def midbrain_combine(grey: Grey, g_delayed: F32, g_prev: F32, gain: np.float32, radius: int,
                     floor: float, o: F32, gamma: float, base: F32, up: Coeffs, n_scales: int,
                     lut: F32, bgr: U8, use_static: bool, centre_row: F32, centre_col: F32,
                     use_centre: bool, f: int, pooled: F32, out: F32, boost_gain: float = -1.0,
                     grey_scale: float = 1.0) -> np.float32:  # pragma: no cover - jitted
    """The full-resolution scale's Eqs. (7)-(13) streamed row by row into Eqs. (14)-(15).

    Same results as :func:`midbrain_step_fused` then :func:`combine` (with ``inv0 = 1``), but
    each Eq. (13) row is consumed as soon as it is made: no full-resolution S_M plane, and
    every plane is streamed once while its rows are still in cache. Row ``r`` of Eq. (13)
    needs the ``u``, ``v`` rows up to ``r + radius``, which need the rows of ``o`` up to
    ``r + radius + 1``, which need the responses up to ``r + radius + 2``. ``boost_gain >= 0``:
    the field preset's Eq. (15) last (:func:`boost`, ``lut`` then is S_s). ``grey`` may be the
    8-bit grey image with ``grey_scale = 1 / 255`` (:func:`_response_row`). Returns the maximum
    of ``out`` (``f == 0``), else 0.
    """
    h, w = grey.shape
    ring, pairs, pad = _tensor_buffers(w, radius)
    au = np.empty(w, np.float32)
    av = np.empty(w, np.float32)
    sm_row = np.empty(w, np.float32)
    row = np.empty(w, np.float32)
    acc = np.empty(w, np.float32)
    hbuf = np.empty((2, w), np.float32)
    tags = np.full(2, -1, np.int64)
    fl = np.float32(floor)
    zero = np.float32(0.0)
    inv_n = np.float32(1.0 / n_scales)
    one = np.float32(1.0)
    lanes = np.zeros(w, np.float32)
    gs = np.float32(grey_scale)
    n_resp = 0  # rows of the response done
    n_corr = 0  # rows of o done
    for j in range(-radius, h):  # j < 0: start-up (the first radius rows of the ring)
        jn = j + radius  # the row pushed now; output row j needs rows up to j + radius
        if jn < h:
            need_o = min(jn + 1, h - 1)
            while n_corr <= need_o:
                need_g = min(n_corr + 1, h - 1)
                while n_resp <= need_g:
                    _response_row(grey, g_delayed, g_prev, gain, n_resp, gs)
                    n_resp += 1
                _correlate_row(g_prev, g_delayed, o, n_corr)
                n_corr += 1
        _push_row(o, jn, radius, pad, ring, pairs)
        if j < 0:
            continue
        r = j
        _vertical_sum(ring, pairs, r, radius, au, av)
        for c in range(w):
            v = au[c] * au[c] + av[c] * av[c] - fl
            sm_row[c] = v if v > zero else zero
        _combine_row(sm_row, one, gamma, True, base, up, hbuf, tags, r, inv_n, lut, bgr,
                     use_static, centre_row, centre_col, use_centre, row, boost_gain)
        _emit_row(row, r, f, acc, pooled, out, lanes)
    top: np.float32 = lanes.max()
    return top


@njit(cache=True, nogil=True)
def grey_half(grey8: U8, half: F32) -> None:  # pragma: no cover - jitted
    """``half`` (H / 2, W / 2) = 2 x 2 block means of ``grey8 / 255`` in float32: what
    ``cv2.resize(grey8 * (1 / 255), INTER_AREA)`` gives (up to float rounding), without the
    full-resolution float plane."""
    s = np.float32(1.0 / 255.0)
    q = np.float32(0.25)
    for i in range(half.shape[0]):
        r0 = grey8[2 * i]
        r1 = grey8[2 * i + 1]
        a0 = r0[0::2]
        b0 = r0[1::2]
        a1 = r1[0::2]
        b1 = r1[1::2]
        dst = half[i]
        for j in range(half.shape[1]):
            dst[j] = ((np.float32(a0[j]) * s + np.float32(b0[j]) * s)
                      + (np.float32(a1[j]) * s + np.float32(b1[j]) * s)) * q


@njit(cache=True, nogil=True)
def weighted_kmeans(x: F64, w: F64, centres: F64,
                    iters: int) -> NDArray[np.intp]:  # pragma: no cover
    """Same as :func:`.static.weighted_kmeans` (Lloyd iterations, empty clusters keep their
    centre); updates ``centres`` in place and returns the final labels."""
    n, d = x.shape
    k = centres.shape[0]
    lab = np.zeros(n, np.intp)
    sw = np.zeros(k)
    sx = np.zeros((k, d))
    for it in range(iters + 1):
        for i in range(n):
            best = 0
            bd = np.inf
            for j in range(k):
                s = 0.0
                for q in range(d):
                    t = x[i, q] - centres[j, q]
                    s += t * t
                if s < bd:
                    bd = s
                    best = j
            lab[i] = best
        if it == iters:
            break
        sw[:] = 0.0
        sx[:] = 0.0
        for i in range(n):
            j = lab[i]
            sw[j] += w[i]
            for q in range(d):
                sx[j, q] += w[i] * x[i, q]
        for j in range(k):
            if sw[j] > 0:
                for q in range(d):
                    centres[j, q] = sx[j, q] / sw[j]
    return lab


@njit(cache=True, nogil=True)
def nearest_centre(x: F64, centres: F64, out: NDArray[np.intp]) -> None:  # pragma: no cover
    """Index of the nearest centre of every row of ``x`` into ``out``."""
    for i in range(x.shape[0]):
        best = 0
        bd = np.inf
        for j in range(centres.shape[0]):
            s = 0.0
            for q in range(x.shape[1]):
                t = x[i, q] - centres[j, q]
                s += t * t
            if s < bd:
                bd = s
                best = j
        out[i] = best


def linear_coeffs(n_dst: int, n_src: int) -> tuple[I64, F32]:
    """Source index and weight of each destination pixel of a bilinear resize along one axis,
    as OpenCV computes them (``fx = (d + 0.5) * n_src / n_dst - 0.5``, clamped at the borders)."""
    scale = 1.0 / (n_dst / n_src)
    fx = ((np.arange(n_dst) + 0.5) * scale - 0.5).astype(np.float32)
    sx = np.floor(fx).astype(np.int64)
    fx = (fx - sx).astype(np.float32)
    low = sx < 0
    fx[low], sx[low] = 0.0, 0
    high = sx >= n_src - 1
    fx[high], sx[high] = 0.0, n_src - 1
    return sx, fx


def midbrain_step_fused(grey: F32, g_delayed: F32, g_prev: F32, gain: float, radius_px: int,
                        o_buf: F32, sm_out: F32, floor: float = 0.0) -> float:
    """Fused equivalent of :func:`.midbrain_step.midbrain_step_numpy`, updating state in place.

    Parameters
    ----------
    grey : float32 (H, W)
    g_delayed, g_prev : float32 (H, W), C-contiguous, updated in place
    gain : float
        ``1 / tau`` (Eq. (8)).
    radius_px : int
    o_buf, sm_out : float32 (H, W) work plane and output
    floor : float
        Noise floor subtracted from Eq. (13) (clipped at 0).

    Returns
    -------
    float
        The maximum of ``sm_out``.
    """
    response_and_correlate(grey, g_delayed, g_prev, np.float32(gain), o_buf)
    return float(tensor_discrepancy(o_buf, int(radius_px), float(floor), sm_out))
