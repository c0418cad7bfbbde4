"""The static saliency equations of DTDMI, Sec. 2.1 of [1] (Eqs. (1)-(6)), and the named
deviations of the field and aerial presets from them, one small pure function each.

Plain numpy, no state and no allocation tricks: with :mod:`.equations_dynamic` and
:mod:`.equations_fusion` this is the reference the fused (numba) kernels of
:mod:`eaglemission.detectors.dtdmi.kernels` are tested against, and what the ``literal`` preset
of :class:`~eaglemission.detectors.dtdmi.DTDMIDetector` follows (:mod:`.equations` gathers the
three). Where the paper leaves a choice open, the choice is a parameter and is documented in
docs/paper_choices.md ("DTDMI").

Shapes: ``(H, W)`` maps are float32 or float64; ``K`` is the number of colour clusters.

References
----------
.. [1] "Biological Eagle-eye Inspired Target Detection for Unmanned Aerial Vehicles Equipped
   with a Manipulator" (eagle-eye multi-camera sensor and the DTDMI saliency method), Sec. 2,
   Eqs. (1)-(15). DOI unknown.
.. [2] H. Fu, X. Cao, Z. Tu, "Cluster-Based Co-Saliency Detection", IEEE Trans. Image
   Processing 22(10), 2013. DOI: 10.1109/TIP.2013.2260166.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.floating]

#: Eq. (1) of [1]: RGB -> LMS (rows L, M, S; columns R, G, B).
RGB_TO_LMS = np.array(
    [[0.3811, 0.5783, 0.0402],
     [0.1967, 0.7244, 0.0782],
     [0.0241, 0.1288, 0.8444]],
    dtype=np.float64,
)


# -- 2.1 static saliency -------------------------------------------------------------------------
def rgb_to_lms(rgb: FloatArray) -> FloatArray:
    """Linear RGB -> LMS cone space, Eq. (1) of [1].

    Parameters
    ----------
    rgb : ndarray of shape (..., 3)
        Colours in R, G, B order (any consistent scale; OpenCV frames are BGR: reverse first).

    Returns
    -------
    lms : ndarray of shape (..., 3)
        L, M, S in the same scale as the input.

    References
    ----------
    .. [1] Eagle-eye inspired target detection (DTDMI), Eq. (1).
    """
    rgb = np.asarray(rgb, dtype=np.float64)
    return rgb @ RGB_TO_LMS.T


def contrast_cue(centres: FloatArray, counts: FloatArray) -> FloatArray:
    """Cluster contrast cue, Eq. (2) of [1] (after Fu et al. [2]).

    ``lambda_c(k) = sum_{i != k} (n_i / N) * ||mu_k - mu_i||_2``.

    Parameters
    ----------
    centres : ndarray of shape (K, C)
        Mean feature (e.g. LMS colour) ``mu`` of each cluster.
    counts : ndarray of shape (K,)
        Pixel count ``n`` of each cluster; ``N`` is their sum.

    Returns
    -------
    ndarray of shape (K,)

    References
    ----------
    .. [1] Eagle-eye inspired target detection (DTDMI), Eq. (2).
    .. [2] Fu, Cao, Tu, TIP 2013, DOI 10.1109/TIP.2013.2260166.
    """
    centres = np.asarray(centres, dtype=np.float64)
    counts = np.asarray(counts, dtype=np.float64)
    total = counts.sum()
    if total <= 0:
        return np.zeros(len(counts))
    dist = np.linalg.norm(centres[:, None, :] - centres[None, :, :], axis=2)  # zero diagonal
    cue: FloatArray = dist @ (counts / total)
    return cue


def inverse_square_distance(
    rows: ArrayLike, cols: ArrayLike, centre_rc: tuple[float, float], min_d2_px2: float = 0.25
) -> FloatArray:
    """Spatial weight ``1 / ||x_p - o||^2`` of a pixel, Eq. (3) of [1].

    The weight is singular at the centre ``o``; the squared distance is clamped from below by
    ``min_d2_px2`` (default a quarter pixel squared: half a pixel along each axis, the nearest a
    pixel centre can be to ``o`` when both image sides are even).

    Parameters
    ----------
    rows, cols : array_like, broadcastable
        Pixel coordinates (row, column).
    centre_rc : (float, float)
        Image centre ``o`` as (row, column), ``((H - 1) / 2, (W - 1) / 2)``.
    min_d2_px2 : float
        Lower clamp of the squared distance, px^2.

    Returns
    -------
    ndarray, broadcast shape of ``rows`` and ``cols``

    References
    ----------
    .. [1] Eagle-eye inspired target detection (DTDMI), Eq. (3).
    """
    d2 = (np.asarray(rows, np.float64) - centre_rc[0]) ** 2 + (
        np.asarray(cols, np.float64) - centre_rc[1]) ** 2
    return 1.0 / np.maximum(d2, min_d2_px2)


def gaussian_centre_weight(
    rows: ArrayLike, cols: ArrayLike, shape_hw: tuple[int, int], sigma_frac: float = 0.25
) -> FloatArray:
    """Gaussian centre weight, the replacement for Eq. (3) of [1] used by Fu et al. [2].

    ``exp(-((r - r0)^2 / (2 (s H)^2) + (c - c0)^2 / (2 (s W)^2)))`` with ``s = sigma_frac``:
    bounded at the centre (no singularity) and scale-free (the same weight at any resolution).

    Parameters
    ----------
    rows, cols : array_like, broadcastable
        Pixel coordinates (row, column).
    shape_hw : (int, int)
        Image height and width.
    sigma_frac : float
        Standard deviation as a fraction of the image height (rows) and width (columns).

    Returns
    -------
    ndarray, broadcast shape of ``rows`` and ``cols``, in (0, 1]

    References
    ----------
    .. [1] Eagle-eye inspired target detection (DTDMI), Eq. (3).
    .. [2] Fu, Cao, Tu, TIP 2013, Eq. (5), DOI 10.1109/TIP.2013.2260166.
    """
    h, w = shape_hw
    r0, c0 = (h - 1) / 2.0, (w - 1) / 2.0
    dr = (np.asarray(rows, np.float64) - r0) / (sigma_frac * h)
    dc = (np.asarray(cols, np.float64) - c0) / (sigma_frac * w)
    return np.exp(-0.5 * (dr * dr + dc * dc))


def spatial_cue(weight_sums: FloatArray, counts: FloatArray) -> FloatArray:
    """Cluster spatial cue of one image, Eq. (4) of [1].

    ``lambda_s(k) = (1 / n_k) * sum_{i in C_k} w_i`` with ``w`` the Eq. (3) weight.

    Parameters
    ----------
    weight_sums : ndarray of shape (K,)
        Sum of the spatial weights of the pixels of each cluster.
    counts : ndarray of shape (K,)
        Pixel count ``n_k`` of each cluster.

    Returns
    -------
    ndarray of shape (K,)
        0 for empty clusters.

    References
    ----------
    .. [1] Eagle-eye inspired target detection (DTDMI), Eq. (4).
    """
    weight_sums = np.asarray(weight_sums, np.float64)
    counts = np.asarray(counts, np.float64)
    return np.divide(weight_sums, counts, out=np.zeros_like(weight_sums), where=counts > 0)


def spatial_cue_sequence(weight_sums: FloatArray, counts: FloatArray) -> FloatArray:
    """Cluster spatial cue over an image sequence, Eq. (5) of [1].

    ``lambda_s(k) = (1 / n_k) * sum_j sum_i w(x_i^j) * delta(c(x_i^j) - C_k)``, the Kronecker
    delta selecting the pixels of cluster k in image j. ``n_k`` is read as the number of pixels
    of cluster k over the whole window (so the cue is a mean weight, comparable between clusters
    of any size; docs/paper_choices.md).

    Parameters
    ----------
    weight_sums : ndarray of shape (M, K)
        Per image j of the window, the sum of the Eq. (3) weights of each cluster's pixels.
    counts : ndarray of shape (M, K)
        Per image, each cluster's pixel count.

    Returns
    -------
    ndarray of shape (K,)

    References
    ----------
    .. [1] Eagle-eye inspired target detection (DTDMI), Eq. (5).
    """
    return spatial_cue(np.sum(weight_sums, axis=0), np.sum(counts, axis=0))


def normalize_cue(cue: FloatArray) -> FloatArray:
    """Normalisation of a cluster cue before Eq. (6) of [1]: divide by the largest value.

    The paper says only that the spatial cue is normalised "after calculating the spatial
    saliency of all clusters"; dividing by the maximum keeps the ratios between clusters (a
    min-max stretch would zero the least central cluster).

    Parameters
    ----------
    cue : ndarray of shape (K,)

    Returns
    -------
    ndarray of shape (K,), in [0, 1] (all zeros if the cue is all zeros)

    References
    ----------
    .. [1] Eagle-eye inspired target detection (DTDMI), text after Eq. (5).
    """
    cue = np.asarray(cue, np.float64)
    top = float(cue.max()) if cue.size else 0.0
    return cue / top if top > 0 else np.zeros_like(cue)


def static_saliency(spatial: FloatArray, contrast: FloatArray) -> FloatArray:
    """Static saliency of each cluster, Eq. (6) of [1]: ``S_s = lambda_s * lambda_c``.

    Every pixel of cluster k gets the value of entry k (paint with ``values[labels]``).

    Parameters
    ----------
    spatial, contrast : ndarray of shape (K,)

    Returns
    -------
    ndarray of shape (K,)

    References
    ----------
    .. [1] Eagle-eye inspired target detection (DTDMI), Eq. (6).
    """
    return np.asarray(spatial, np.float64) * np.asarray(contrast, np.float64)



# -- field and aerial presets: named deviations from [1] (docs/paper_choices.md) ----------------
#: Reinhard et al. [4]: log10 LMS -> l-alpha-beta (rows l, alpha, beta). The rows are
#: orthonormal, so distances in l-alpha-beta equal distances in log10 LMS.
LOG_LMS_TO_LAB = np.diag([1 / np.sqrt(3), 1 / np.sqrt(6), 1 / np.sqrt(2)]) @ np.array(
    [[1.0, 1.0, 1.0], [1.0, 1.0, -2.0], [1.0, -1.0, 0.0]])


def srgb_to_linear(rgb: FloatArray) -> FloatArray:
    """sRGB-encoded values in [0, 1] -> linear RGB (IEC 61966-2-1 decoding).

    Eq. (1) of [1] is Reinhard's RGB -> LMS matrix [4], which expects linear RGB; camera frames
    are gamma-encoded.
    """
    x = np.asarray(rgb, dtype=np.float64)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def lms_to_lalphabeta(lms: FloatArray, floor: float = 1e-4) -> FloatArray:
    """LMS (Eq. (1) of [1]) -> Reinhard's opponent space l-alpha-beta [4] (log10, then rotate).

    ``l`` is log luminance, ``alpha`` yellow-blue, ``beta`` red-green. ``floor`` keeps log10
    finite for black.

    References
    ----------
    .. [4] E. Reinhard, M. Ashikhmin, B. Gooch, P. Shirley, "Color Transfer between Images",
       IEEE CG&A 21(5), 2001. DOI: 10.1109/38.946629.
    """
    lab: FloatArray = np.log10(np.maximum(np.asarray(lms, np.float64), floor)) @ LOG_LMS_TO_LAB.T
    return lab


def bin_contrast_cue(features: FloatArray, centres: FloatArray, counts: FloatArray) -> FloatArray:
    """Eq. (2) of [1] evaluated for each colour bin rather than each cluster (field preset).

    ``lambda_c(b) = sum_k (n_k / N) ||f_b - mu_k||``: the bin's own colour against the K cluster
    means, so a small target whose colour shares a cluster with common colours keeps its own
    contrast (the histogram contrast of Cheng et al., with the clusters as the histogram). For
    a bin at a cluster mean this is Eq. (2) of that cluster. Not normalised: the value is in
    the feature space's units, so a frame without a distinct colour stays low.

    Parameters
    ----------
    features : ndarray of shape (B, C)
    centres : ndarray of shape (K, C)
    counts : ndarray of shape (K,)

    Returns
    -------
    ndarray of shape (B,)
    """
    counts = np.asarray(counts, np.float64)
    total = counts.sum()
    if total <= 0:
        return np.zeros(len(features))
    f = np.asarray(features, np.float64)
    c = np.asarray(centres, np.float64)
    # ||f - c||^2 = ||f||^2 + ||c||^2 - 2 f.c: a (B, C) x (C, K) product instead of a (B, K, C)
    # difference array (float64: the cancellation costs ~1e-8 of a unit near a centre)
    d2 = (f * f).sum(axis=1)[:, None] + (c * c).sum(axis=1)[None, :] - 2.0 * (f @ c.T)
    d = np.sqrt(np.maximum(d2, 0.0))
    cue: FloatArray = d @ (counts / total)
    return cue


def distribution_cue(moments: FloatArray, counts: FloatArray, diag_px: float,
                     sigma_frac: float) -> FloatArray:
    """Spatial compactness of each colour bin (field preset; replaces Eqs. (3)-(5) of [1]).

    ``exp(-(spread_b / (sigma_frac * diag))^2)`` where ``spread_b`` is the RMS distance of the
    bin's pixels to their centroid (Perazzi et al.'s "element distribution"): a colour spread
    over the whole image (ground texture, sky) is background, a compact one (an object) keeps
    its contrast. Bins without pixels get 0 (no evidence of compactness).

    Parameters
    ----------
    moments : ndarray of shape (B, 4)
        Per bin: sums of column, row, column^2, row^2 over its (sampled) pixels.
    counts : ndarray of shape (B,)
        Pixels per bin.
    diag_px : float
        Image diagonal (same pixel units as the moments).
    sigma_frac : float
        Spread (fraction of the diagonal) at which the cue falls to exp(-1).

    Returns
    -------
    ndarray of shape (B,), in [0, 1]
    """
    n = np.asarray(counts, np.float64)
    m = np.asarray(moments, np.float64)
    nn = np.maximum(n, 1.0)
    var = (m[:, 2] / nn - (m[:, 0] / nn) ** 2) + (m[:, 3] / nn - (m[:, 1] / nn) ** 2)
    spread = np.sqrt(np.maximum(var, 0.0)) / (sigma_frac * diag_px)
    return np.where(n > 0, np.exp(-spread * spread), 0.0)




def block_contrast_cue(features: FloatArray, radius_px: int, surround: float) -> FloatArray:
    """Eq. (2) of [1] read as the text describes it, per pixel block (aerial preset).

    Sec. 2.1 says the contrast cue "measures the color difference between the current pixel
    block and the surrounding pixel block"; Eq. (2) as printed sums cluster-mean distances over
    the whole image. This is the block reading: ``||mean_C(p) - mean_S(p)||_2``, with ``C`` the
    ``(2r+1)^2`` block centred on ``p`` and ``S`` the ``(2R+1)^2`` block around it,
    ``R = round(surround * r)`` (a centre-surround difference of box means, as in Itti et al.'s
    centre-surround maps). A uniform area gives 0 and a small object of another colour (or
    brightness) a value in the features' own units, so the cue keeps an absolute scale.

    Parameters
    ----------
    features : ndarray of shape (H, W, C), float32
        Per-pixel colour features (the detector uses CIE L*a*b* with a weighted L*).
    radius_px : int
        ``r``, half-size of the centre block (>= 1).
    surround : float
        ``R / r`` (> 1).

    Returns
    -------
    ndarray of shape (H, W), float32

    References
    ----------
    .. [1] Eagle-eye inspired target detection (DTDMI), Sec. 2.1, Eq. (2).
    .. [5] L. Itti, C. Koch, E. Niebur, "A model of saliency-based visual attention for rapid
       scene analysis", IEEE TPAMI 20(11), 1998. DOI: 10.1109/34.730558.
    """
    import cv2

    f = np.ascontiguousarray(features, dtype=np.float32)
    r = max(1, int(radius_px))
    big = max(r + 1, int(round(surround * r)))
    centre = cv2.blur(f, (2 * r + 1, 2 * r + 1), borderType=cv2.BORDER_REFLECT)
    around = cv2.blur(f, (2 * big + 1, 2 * big + 1), borderType=cv2.BORDER_REFLECT)
    diff: NDArray[np.float32] = centre - around
    if diff.ndim == 2:
        return np.abs(diff)
    d2: NDArray[np.float32] = np.einsum("hwc,hwc->hw", diff, diff, dtype=np.float32)
    return np.sqrt(d2)
