"""The synthetic world's ground and sky: the textured plane warped band by band from the mip
level that matches each band's footprint, aerial haze and the edge fade, the sky gradient
(docs/simulation.md, "Synthetic world")."""

from __future__ import annotations

import math
import threading

import cv2
import numpy as np
from eaglemission.lab.world.objects import clip_polygon, polygon_area
from eaglemission.lab.world.textures import GroundTextures
from numpy.typing import NDArray

SKY_ZENITH_BGR = (205, 150, 95)
SKY_HORIZON_BGR = (235, 215, 200)
HAZE_VISIBILITY_M = 400.0  # aerial perspective: 1/e distance of the haze
HAZE_MAX = 0.9  # haze opacity at infinity (the horizon stays faintly visible)
HAZE_MIN_M = 30.0  # rows whose ground is nearer than this are left untouched
# The ground is warped from 4-channel copies of the base texture levels (OpenCV's 4-channel
# bilinear warp is ~2x faster than its 3-channel one; same values per channel) for levels up to
# this size (level 0 of a 200 m world at 5 cm is 64 MB); larger levels use the 3-channel path.
BGRA_LEVEL_BUDGET_BYTES = 192 * 2**20


def _homography_inv(H: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.asarray(np.linalg.inv(H), dtype=np.float64)


class GroundRenderer:
    """Draws the ground and the sky of one world's textures (thread-safe caches)."""

    def __init__(self, textures: GroundTextures) -> None:
        self.textures = textures
        self._lock = threading.Lock()
        self._const: dict[tuple[object, ...], tuple[NDArray[np.uint8], NDArray[np.uint8]]] = {}
        self.bgra: dict[int, NDArray[np.uint8] | None] = {}  # base levels with 4 channels

    def render_ground(self, img: NDArray[np.uint8], K: NDArray[np.float64],
                       R_on: NDArray[np.float64], C: NDArray[np.float64]) -> None:
        tex = self.textures
        H, W = img.shape[:2]
        t = -R_on @ C
        # ground (north, east, 1) -> pixel
        Hg = K @ np.column_stack((R_on[:, 0], R_on[:, 1], t))
        if abs(np.linalg.det(Hg)) < 1e-12:  # camera on the plane: nothing sensible to show
            img[:] = np.asarray(tex.base_mean_bgr, np.uint8)
            return
        G = _homography_inv(Hg)  # pixel -> ground
        Kinv = np.linalg.inv(K)
        down = (R_on.T @ Kinv)[2]  # ray's down component, linear in (u, v, 1)
        levels = self._band_levels(G, down, W, H)
        for r0, r1, lb, ld in levels:
            self._render_band(img, G, r0, r1, lb, ld, tex)
        self._render_haze(img, G, down, C)

    def _render_haze(self, img: NDArray[np.uint8], G: NDArray[np.float64],
                     down: NDArray[np.float64], C: NDArray[np.float64]) -> None:
        """Aerial perspective on far ground: blend towards the horizon colour with
        ``1 - exp(-distance / HAZE_VISIBILITY_M)`` and fade the texture to its mean colour
        near the edge of the textured square, so neither the edge nor the horizon is a
        hard line. Only rows that reach ``HAZE_MIN_M`` are touched (cheap at close range)."""
        H, W = img.shape[:2]
        half = self.textures.extent_m / 2.0
        step = 8
        rows = np.arange(0, H + step - 1, step, dtype=np.float64).clip(0, H - 1)
        cols = np.array([0.0, (W - 1) / 2.0, W - 1.0])
        uu, vv = np.meshgrid(cols, rows)
        pts = np.stack((uu.ravel(), vv.ravel(), np.ones(uu.size)))
        g = G @ pts
        dn = down @ pts
        with np.errstate(divide="ignore", invalid="ignore"):
            ne = g[:2] / g[2]
        dist = np.where(dn > 1e-9, np.hypot(ne[0] - C[0], ne[1] - C[1]), np.inf)
        far = (dist.reshape(len(rows), 3).max(axis=1) >= min(HAZE_MIN_M, 0.7 * half))
        if not far.any():
            return
        r1 = min(H, int(rows[np.nonzero(far)[0].max()]) + step)  # far rows are at the top
        # The factors are smooth: compute them on a 4x coarser grid, then upsample.
        k = 4
        hs, ws = (r1 + k - 1) // k + 1, (W + k - 1) // k + 1
        vv2, uu2 = np.mgrid[0:hs, 0:ws].astype(np.float64) * k
        gx = G[0, 0] * uu2 + G[0, 1] * vv2 + G[0, 2]
        gy = G[1, 0] * uu2 + G[1, 1] * vv2 + G[1, 2]
        gz = G[2, 0] * uu2 + G[2, 1] * vv2 + G[2, 2]
        dz = down[0] * uu2 + down[1] * vv2 + down[2]
        ground = dz > 0
        gz = np.where(np.abs(gz) < 1e-12, 1e-12, gz)
        n, e = gx / gz, gy / gz
        d = np.where(ground, np.hypot(n - C[0], e - C[1]), 1e9)
        haze = (1.0 - np.exp(-d / HAZE_VISIBILITY_M)) * HAZE_MAX
        edge = np.clip((np.maximum(np.abs(n), np.abs(e)) - 0.7 * half) / (0.3 * half), 0, 1)
        edge = np.where(ground, edge * edge * (3 - 2 * edge), 1.0)
        # grid point (i, j) is pixel (k j, k i): an affine upsampling, then crop
        M = np.array([[1.0 / k, 0.0, 0.0], [0.0, 1.0 / k, 0.0]])
        flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
        edge_full = None
        if edge.max() > 0.0:  # else the fade is 0 everywhere: blending with it is the identity
            edge_full = cv2.warpAffine(edge.astype(np.float32), M, (W, r1), flags=flags,
                                       borderMode=cv2.BORDER_REPLICATE)
        haze_full = cv2.warpAffine(haze.astype(np.float32), M, (W, r1), flags=flags,
                                   borderMode=cv2.BORDER_REPLICATE)
        mean, horizon = self._haze_colours(H, W)
        # the edge fade leaves a row untouched where its weight is 0 everywhere (near ground)
        re = 0
        if edge_full is not None:
            rows_e = np.flatnonzero(edge_full.max(axis=1) > 0.0)
            re = int(rows_e[-1]) + 1 if len(rows_e) else 0
        if re > 0 and edge_full is not None:
            img[:re] = cv2.blendLinear(img[:re], mean[:re], 1.0 - edge_full[:re], edge_full[:re])
        img[:r1] = cv2.blendLinear(img[:r1], horizon[:r1], 1.0 - haze_full, haze_full)

    def _haze_colours(self, H: int, W: int) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
        """Constant images of the ground's mean colour and the horizon colour (cached)."""
        key = ("haze", H, W)
        with self._lock:
            found = self._const.get(key)
        if found is None:
            mean = np.empty((H, W, 3), np.uint8)
            mean[:] = np.asarray(np.round(self.textures.base_mean_bgr), np.uint8)
            horizon = np.empty((H, W, 3), np.uint8)
            horizon[:] = np.asarray(SKY_HORIZON_BGR, np.uint8)
            found = (mean, horizon)
            with self._lock:
                self._const[key] = found
        return found

    def _band_levels(self, G: NDArray[np.float64], down: NDArray[np.float64], W: int, H: int
                     ) -> list[tuple[int, int, int, int]]:
        """Row bands with the same (base level, detail level); detail -1 = none."""
        tex = self.textures
        step = 8
        rows = np.arange(0, H, step, dtype=np.float64) + step / 2.0
        cols = np.array([0.0, (W - 1) / 2.0, W - 1.0])
        uu, vv = np.meshgrid(cols, rows)
        pts = np.stack((uu.ravel(), vv.ravel(), np.ones(uu.size)))
        g = G @ pts
        valid = (down @ pts) > 1e-6
        gz = np.where(np.abs(g[2]) < 1e-12, 1e-12, g[2])
        # |det J| of the pixel -> ground map for a homography: det(G) / g_z^3.
        detJ = np.abs(np.linalg.det(G) / gz ** 3)
        fp = np.sqrt(detJ)
        fp = np.where(valid, fp, np.inf).reshape(len(rows), len(cols))
        fp_row = np.median(fp, axis=1)  # inf where most of the row is sky
        nb = len(tex.base)
        nd = len(tex.detail_tiled)
        bands: list[tuple[int, int, int, int]] = []
        for i, f in enumerate(fp_row.tolist()):
            if not math.isfinite(f):
                lb, ld = nb - 1, -1
            else:
                lb = min(max(math.floor(math.log2(max(f, 1e-9) / tex.base_texel_m) + 0.5), 0),
                         nb - 1)
                ld_f = math.floor(math.log2(max(f, 1e-9) / tex.detail_texel_m) + 0.5)
                ld = int(max(0, ld_f)) if 0 < nd and ld_f < nd else -1
            r0 = i * step
            r1 = min(H, r0 + step)
            if bands and bands[-1][2] == lb and bands[-1][3] == ld:
                bands[-1] = (bands[-1][0], r1, lb, ld)
            else:
                bands.append((r0, r1, lb, ld))
        return bands

    def _render_band(self, img: NDArray[np.uint8], G: NDArray[np.float64], r0: int, r1: int,
                     lb: int, ld: int, tex: GroundTextures) -> None:
        W = img.shape[1]
        h = r1 - r0
        shift = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, float(r0)], [0.0, 0.0, 1.0]])
        s = tex.base_texel_m * 2 ** lb
        # ground (n, e, 1) -> texel (col, row, 1) of base level lb
        ground_to_tex = np.array([[0.0, 1.0 / s, -tex.origin_east_m / s - 0.5],
                                  [-1.0 / s, 0.0, tex.origin_north_m / s - 0.5],
                                  [0.0, 0.0, 1.0]])
        M = ground_to_tex @ G @ shift  # band pixel -> texel
        band = img[r0:r1]
        mean = tex.base_mean_bgr
        src4 = self.base_bgra(lb)
        if src4 is not None:
            # same interpolation per channel; OpenCV's 4-channel path is ~2x faster
            band4 = cv2.warpPerspective(src4, M, (W, h),
                                        flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                        borderMode=tex.border_mode,
                                        borderValue=(*mean, 255.0))
            cv2.cvtColor(band4, cv2.COLOR_BGRA2BGR, dst=band)
        else:
            cv2.warpPerspective(tex.base[lb], M, (W, h), dst=band,
                                flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                borderMode=tex.border_mode, borderValue=mean)
        if ld < 0:
            return
        src = tex.detail_tiled[ld]
        sd = tex.detail_texel_m * 2 ** ld
        period = tex.detail_period_px >> ld
        g2t = np.array([[0.0, 1.0 / sd, 0.0], [-1.0 / sd, 0.0, 0.0], [0.0, 0.0, 1.0]])
        Md = g2t @ G @ shift
        corners = np.array([[0, 0, 1], [W - 1, 0, 1], [0, h - 1, 1], [W - 1, h - 1, 1]], float).T
        q = Md @ corners
        if (q[2] * np.sign(q[2][0]) <= 0).any():
            return
        q = q[:2] / q[2]
        lo = np.floor(q.min(axis=1) / period) * period
        span = q.max(axis=1) - lo
        if (span >= src.shape[0] - 2).any():
            return  # footprint wider than the pre-tiled detail: skip detail in this band
        Md = np.array([[1.0, 0.0, -lo[0]], [0.0, 1.0, -lo[1]], [0.0, 0.0, 1.0]]) @ Md
        d = cv2.warpPerspective(src, Md, (W, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                borderMode=cv2.BORDER_CONSTANT, borderValue=128)
        cv2.multiply(band, cv2.cvtColor(d, cv2.COLOR_GRAY2BGR), dst=band, scale=1.0 / 128.0)

    def warm_up(self) -> None:
        """Build the 4-channel base levels now."""
        for level in range(len(self.textures.base)):
            self.base_bgra(level)

    def base_bgra(self, level: int) -> NDArray[np.uint8] | None:
        """Base level ``level`` with a 4th channel (built on first use, kept per world), or
        None when it would exceed ``BGRA_LEVEL_BUDGET_BYTES`` (then the 3-channel path)."""
        with self._lock:
            found = self.bgra.get(level)
        if found is not None or level in self.bgra:
            return found
        src = self.textures.base[level]
        arr = None
        if src.nbytes * 4 // 3 <= BGRA_LEVEL_BUDGET_BYTES:
            arr = np.asarray(cv2.cvtColor(src, cv2.COLOR_BGR2BGRA), dtype=np.uint8)
            arr.flags.writeable = False
        with self._lock:
            self.bgra[level] = arr
        return arr

    def render_sky(self, img: NDArray[np.uint8], K: NDArray[np.float64],
                    R_no: NDArray[np.float64]) -> None:
        H, W = img.shape[:2]
        Kinv = np.linalg.inv(K)
        down = (R_no @ Kinv)[2]  # d-component of the ray through (u, v, 1), linear
        rect = np.array([[-0.5, -0.5], [W - 0.5, -0.5], [W - 0.5, H - 0.5], [-0.5, H - 0.5]])
        # sky: down(u, v) <= 0  <=>  -down[:2] . (u, v) >= down[2]
        sky = clip_polygon(rect, -down[:2], float(down[2]))
        if polygon_area(sky) < 0.5:
            return
        y0 = max(0, int(math.floor(sky[:, 1].min())))
        y1 = min(H, int(math.ceil(sky[:, 1].max())) + 1)
        # the mask of the sky rows only (an integer shift does not change the rasterisation)
        mask = np.zeros((y1 - y0, W), np.uint8)
        pts = np.round(sky * 16).astype(np.int32) - np.array([0, 16 * y0], np.int32)
        cv2.fillConvexPoly(mask, pts, 255, cv2.LINE_8, 4)
        # elevation ~ -down / |ray|: gradient from horizon colour to zenith colour; each ray
        # component is a linear function of (u, v): three planes, broadcast row x column
        M = (R_no @ Kinv).astype(np.float32)
        uu = np.arange(W, dtype=np.float32)[None, :]
        vv = np.arange(y0, y1, dtype=np.float32)[:, None]
        rx = uu * M[0, 0] + (vv * M[0, 1] + M[0, 2])
        ry = uu * M[1, 0] + (vv * M[1, 1] + M[1, 2])
        rz = uu * M[2, 0] + (vv * M[2, 1] + M[2, 2])
        elev = -rz / np.sqrt(rx * rx + ry * ry + rz * rz)
        t = np.clip(elev * np.float32(2.0), 0.0, 1.0) ** np.float32(0.6)
        hz = np.asarray(SKY_HORIZON_BGR, np.float32)
        zn = np.asarray(SKY_ZENITH_BGR, np.float32)
        sky_img = (hz + (zn - hz) * t[..., None]).astype(np.uint8)
        np.copyto(img[y0:y1], sky_img, where=mask[:, :, None] > 0)
