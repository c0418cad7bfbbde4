"""Static cluster saliency S_s (Sec. 2.1 of [1], Eqs. (1)-(6)), stateful over a time window.

Colour clustering after Fu et al. (TIP 2013): pixels are quantised to a 12-bit colour histogram
(4 bits per channel); a weighted k-means on the occupied bins' LMS colours (Eq. (1)) gives K
clusters, warm-started from the previous frame's centres so cluster k stays the same cluster
along the sequence (Eq. (5) sums over it). Each bin gets its nearest cluster (a look-up table),
so painting the per-cluster saliency back is one table look-up per pixel.

References
----------
.. [1] Eagle-eye inspired target detection (DTDMI), Sec. 2.1. DOI unknown.
.. [2] H. Fu, X. Cao, Z. Tu, "Cluster-Based Co-Saliency Detection", IEEE TIP 22(10), 2013.
   DOI: 10.1109/TIP.2013.2260166.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import eaglemission.detectors.dtdmi.equations_static as eq
import numpy as np
from numpy.typing import NDArray

from eaglemission.perception.colour_bins import BITS, NBINS, pool_colour_bins


def _bin_colours_bgr() -> NDArray[np.float64]:
    """BGR colour (0..1) of the centre of each of the 4096 histogram bins."""
    i = np.arange(NBINS)
    levels = (np.arange(1 << BITS) + 0.5) / (1 << BITS)
    b = levels[(i >> (2 * BITS)) & 0xF]
    g = levels[(i >> BITS) & 0xF]
    r = levels[i & 0xF]
    return np.stack([b, g, r], axis=1)


_BIN_BGR = _bin_colours_bgr()


def bin_features(colour_space: str, luminance_weight: float = 1.0) -> NDArray[np.float64]:
    """(4096, 3) clustering features of the bins.

    ``lms``: Eq. (1) on the sRGB values; ``log_lms``: log10 of that (Reinhard);
    ``lalphabeta`` (field preset): sRGB decoded to linear RGB, Eq. (1), then Reinhard's
    l-alpha-beta, with the ``l`` (log luminance) axis scaled by ``luminance_weight`` (0: the
    distances are chromatic only, so shading and shadows do not count as contrast).
    """
    if colour_space == "lalphabeta":
        lab = eq.lms_to_lalphabeta(eq.rgb_to_lms(eq.srgb_to_linear(_BIN_BGR[:, ::-1])))
        lab[:, 0] *= luminance_weight
        return np.asarray(lab, np.float64)
    lms = np.asarray(eq.rgb_to_lms(_BIN_BGR[:, ::-1]), np.float64)  # Eq. (1) wants R, G, B
    if colour_space == "log_lms":
        return np.asarray(np.log10(np.maximum(lms, 1e-3)), np.float64)
    return lms


def weighted_kmeans(
    x: NDArray[np.float64], w: NDArray[np.float64], centres: NDArray[np.float64], iters: int
) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
    """Lloyd iterations on weighted points; empty clusters keep their centre."""
    c = centres.copy()
    lab = np.zeros(len(x), dtype=np.intp)
    for _ in range(iters):
        d2 = ((x[:, None, :] - c[None, :, :]) ** 2).sum(axis=2)
        lab = np.argmin(d2, axis=1)
        sw = np.bincount(lab, weights=w, minlength=len(c))
        for j in range(x.shape[1]):
            sx = np.bincount(lab, weights=w * x[:, j], minlength=len(c))
            np.divide(sx, sw, out=c[:, j], where=sw > 0)
    d2 = ((x[:, None, :] - c[None, :, :]) ** 2).sum(axis=2)
    return c, np.argmin(d2, axis=1)


def kmeanspp_init(x: NDArray[np.float64], w: NDArray[np.float64], k: int) -> NDArray[np.float64]:
    """Deterministic weighted k-means++ seeding (fixed seed: same frames, same clusters)."""
    rs = np.random.RandomState(0)
    p = w / w.sum()
    centres = [x[rs.choice(len(x), p=p)]]
    for _ in range(1, k):
        d2 = np.min(((x[:, None, :] - np.array(centres)[None]) ** 2).sum(axis=2), axis=1)
        q = w * d2
        if q.sum() <= 0:
            centres.append(x[rs.choice(len(x), p=p)])
        else:
            centres.append(x[rs.choice(len(x), p=q / q.sum())])
    return np.array(centres)


@dataclass(frozen=True)
class StaticParams:
    clusters: int = 8
    colour_space: str = "lms"  # "lms" (Eq. (1)) | "log_lms"
    spatial_weight: str = "inverse_square"  # Eq. (3) | "gaussian" (Fu et al.)
    gaussian_sigma_frac: float = 0.25
    window_s: float = 1.0  # Eq. (5) sequence window
    sample_step_px: int = 2  # statistics on every 2nd pixel in each direction
    kmeans_iters_init: int = 15
    kmeans_iters: int = 3
    kmeans_weight: str = "count"  # "count" | "sqrt": weight of a colour bin in the k-means
    backend: str = "numpy"  # "numpy" | "numba" (same results)
    # field preset (docs/paper_choices.md, "field preset"):
    luminance_weight: float = 1.0  # weight of l in "lalphabeta" distances
    spread_sigma_frac: float = 0.0  # > 0: distribution cue instead of Eqs. (3)-(5)
    contrast_level: str = "bin"  # with the distribution cue: "bin" | "cluster" (Eq. (2))
    spread_pool: bool = True  # pool each bin's moments with its 26 neighbouring colours


class ClusterStatic:
    """Per-frame static saliency: ``compute(image, timestamp_ns) -> per-bin S_s look-up table``."""

    def __init__(self, params: StaticParams) -> None:
        self.p = params
        self._features = bin_features(params.colour_space, params.luminance_weight)
        self._lut = np.zeros(NBINS, np.intp)
        self._k = None
        if params.backend == "numba":
            import eaglemission.detectors.dtdmi.kernels as kernels

            self._k = kernels
        self.reset()

    def reset(self) -> None:
        self._centres: NDArray[np.float64] | None = None
        self._window: deque[tuple[int, NDArray[np.float64], NDArray[np.float64]]] = deque()
        self._weights: NDArray[np.float64] | None = None
        self._shape: tuple[int, int] | None = None

    def weight_grid(self, shape: tuple[int, int]) -> NDArray[np.float64]:
        """(ceil(H / step), ceil(W / step)) Eq. (3) weights of the sampled pixels."""
        if self._weights is None or self._shape != shape:
            h, w = shape
            s = self.p.sample_step_px
            rows = np.arange(0, h, s, dtype=np.float64)[:, None]
            cols = np.arange(0, w, s, dtype=np.float64)[None, :]
            if self.p.spatial_weight == "gaussian":
                wt = eq.gaussian_centre_weight(rows, cols, shape, self.p.gaussian_sigma_frac)
            else:
                wt = eq.inverse_square_distance(rows, cols, ((h - 1) / 2, (w - 1) / 2))
            self._weights = np.ascontiguousarray(wt)
            self._shape = shape
            self._window.clear()
        return self._weights

    def histograms(self, idx: NDArray[np.uint16]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Bin counts and Eq. (3) weight sums over the sampled pixels (plain numpy)."""
        s = self.p.sample_step_px
        sub = idx[::s, ::s].ravel()
        wgrid = self.weight_grid((idx.shape[0], idx.shape[1])).ravel()
        hist = np.bincount(sub, minlength=NBINS).astype(np.float64)
        whist = np.asarray(np.bincount(sub, weights=wgrid, minlength=NBINS), np.float64)
        return hist, whist

    def _cluster_bins(self, hist: NDArray[np.float64]) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.float64], int]:
        """Warm-started weighted k-means of the occupied colour bins (the clustering of
        Fu et al.); returns the occupied bins, their cluster labels, each cluster's pixel count and K. A change of K
        restarts the clustering and empties the Eq. (5) window."""
        occ = np.flatnonzero(hist)
        x, n_occ = self._features[occ], hist[occ]
        # sqrt weights let rare colours (a small target) win a cluster of their own.
        w = np.sqrt(n_occ) if self.p.kmeans_weight == "sqrt" else n_occ
        k = min(self.p.clusters, len(occ))
        if self._centres is None or len(self._centres) != k:
            self._centres = kmeanspp_init(x, w, k)
            iters = self.p.kmeans_iters_init
            self._window.clear()
        else:
            iters = self.p.kmeans_iters
        if self._k is not None:
            self._centres = np.ascontiguousarray(self._centres, dtype=np.float64)
            lab = self._k.weighted_kmeans(np.ascontiguousarray(x), w, self._centres, iters)
        else:
            self._centres, lab = weighted_kmeans(x, w, self._centres, iters)
        counts = np.asarray(np.bincount(lab, weights=n_occ, minlength=k), np.float64)
        return occ, lab, counts, k

    def bin_saliency_from_hist(self, hist: NDArray[np.float64], whist: NDArray[np.float64],
                               timestamp_ns: int) -> NDArray[np.float32]:
        """S_s of each bin from the histograms of :meth:`histograms` (or the fused kernel)."""
        occ, lab, counts, k = self._cluster_bins(hist)
        wsums = np.asarray(np.bincount(lab, weights=whist[occ], minlength=k), np.float64)
        centres = self._centres
        assert centres is not None  # set by _cluster_bins
        # Eq. (5): the window of past frames, in seconds.
        self._window.append((timestamp_ns, wsums, counts))
        horizon = timestamp_ns - int(self.p.window_s * 1e9)
        while len(self._window) > 1 and self._window[0][0] <= horizon:
            self._window.popleft()
        lam_s = eq.normalize_cue(eq.spatial_cue_sequence(
            np.array([e[1] for e in self._window]), np.array([e[2] for e in self._window])))
        # Eq. (2) on the cluster colours, normalised the same way.
        lam_c = eq.normalize_cue(eq.contrast_cue(centres, counts))
        s_cluster = eq.static_saliency(lam_s, lam_c)  # Eq. (6)
        # Nearest cluster of every bin (also the unoccupied ones: later frames may use them).
        if self._k is not None:
            self._k.nearest_centre(self._features, centres, self._lut)
            lut = self._lut
        else:
            d2 = ((self._features[:, None, :] - centres[None]) ** 2).sum(axis=2)
            lut = np.argmin(d2, axis=1)
        return s_cluster[lut].astype(np.float32)

    # -- field preset ---------------------------------------------------------------------------
    @property
    def field(self) -> bool:
        """Whether the distribution cue replaces Eqs. (3)-(5) (the ``field`` preset)."""
        return self.p.spread_sigma_frac > 0

    def moments(self, idx: NDArray[np.uint16]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Bin counts (B,) and spatial moments (B, 4) over the sampled pixels (plain numpy)."""
        s = self.p.sample_step_px
        h, w = idx.shape
        sub = idx[::s, ::s].ravel()
        rows, cols = np.mgrid[0:h:s, 0:w:s]
        r = rows.ravel().astype(np.float64)
        c = cols.ravel().astype(np.float64)
        hist = np.bincount(sub, minlength=NBINS).astype(np.float64)
        mom = np.asarray(np.stack([np.bincount(sub, weights=v, minlength=NBINS)
                                   for v in (c, r, c * c, r * r)], axis=1), np.float64)
        return hist, mom

    def bin_saliency_field(self, hist: NDArray[np.float64], mom: NDArray[np.float64],
                           shape: tuple[int, int]) -> NDArray[np.float32]:
        """S_s of each colour bin, field preset: contrast x distribution, absolute scale.

        The clustering is the same warm-started weighted k-means as :meth:`bin_saliency_from_hist`;
        the contrast is Eq. (2) per bin (:func:`.equations.bin_contrast_cue`) or per cluster
        (``contrast_level="cluster"``), not normalised; the spatial cue is the bin's spatial
        compactness (:func:`.equations.distribution_cue`) instead of the centre weighting of
        Eqs. (3)-(5); Eq. (6) is their product.
        """
        occ, lab, counts, k = self._cluster_bins(hist)
        centres = self._centres
        assert centres is not None  # set by _cluster_bins
        if self.p.contrast_level == "cluster":
            d2 = ((self._features[:, None, :] - centres[None]) ** 2).sum(axis=2)
            contrast = eq.contrast_cue(centres, counts)[np.argmin(d2, axis=1)]
        else:
            contrast = eq.bin_contrast_cue(self._features, centres, counts)
        diag = float(np.hypot(*shape))
        pooled_mom: NDArray[np.floating] = mom
        pooled_hist: NDArray[np.floating] = hist
        if self.p.spread_pool:
            pooled_mom, pooled_hist = pool_colour_bins(mom), pool_colour_bins(hist)
        spatial = eq.distribution_cue(pooled_mom, pooled_hist, diag, self.p.spread_sigma_frac)
        return eq.static_saliency(spatial, contrast).astype(np.float32)  # Eq. (6)
