"""Saliency metrics: PR and ROC curves over 256 thresholds, max F-measure, MAE, AUC.

Protocol (docs/detectors.md, "Protocol"): the *per-image mean*, the common one in salient-object
benchmarks. Each map is min-max normalised to [0, 1] (``normalize_map``; a constant map becomes
all zeros), quantised to 0..255, and binarised at every threshold ``t = 0..255`` as
``sal8 >= t``. Precision, recall (= TPR) and FPR are computed per image, then averaged over the
images; the max F-measure (Eq. (17) of [1], beta^2 = 0.3) is the maximum over thresholds of
F(mean precision, mean recall), and the AUC is the area under the mean ROC curve with the end
points (0, 0) and (1, 1) added. MAE is the mean over images of the per-image mean absolute
difference between the normalised float map and the binary ground truth.

Conventions for degenerate cases: precision is 0 at a threshold where nothing is predicted
(as PySODMetrics does); a frame whose ground truth is empty has no defined recall and is left
out of the curves (counted in ``SequenceScores.n_empty_gt``), but is included in the MAE.

References
----------
[1] The eagle-eye paper (/work/shared/paper), Eq. (17); beta^2 = 0.3 after Achanta et al.,
    "Frequency-tuned salient region detection", CVPR 2009, DOI 10.1109/CVPR.2009.5206596.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

Curve = NDArray[np.float64]  # (256,), index = threshold on 0..255

N_THRESHOLDS = 256


def _check_pair(sal: NDArray[np.generic], gt: NDArray[np.generic], name: str) -> None:
    if sal.ndim != 2 or gt.shape != sal.shape:
        raise ValueError(f"{name}: map and gt must be 2-D of the same shape, got "
                         f"{sal.shape} and {gt.shape}")


def normalize_map(sal: NDArray[np.floating]) -> NDArray[np.float32]:
    """Per-image min-max normalisation to [0, 1]; a constant map gives zeros; NaN gives 0."""
    s = np.nan_to_num(np.asarray(sal, dtype=np.float32), nan=0.0, posinf=0.0, neginf=0.0)
    lo, hi = float(s.min()), float(s.max())
    if not hi > lo:
        return np.zeros(s.shape, np.float32)
    return ((s - lo) / (hi - lo)).astype(np.float32)


def quantize(sal01: NDArray[np.floating]) -> NDArray[np.uint8]:
    """[0, 1] float map -> 0..255 (round to nearest, saturate)."""
    s = np.asarray(sal01, np.float32)  # float32 first, so float64 inputs round the same way
    q: NDArray[np.uint8] = np.clip(np.rint(s * np.float32(255.0)), 0, 255).astype(np.uint8)
    return q


def pr_roc_curves(sal8: NDArray[np.uint8], gt: NDArray[np.bool_]) -> tuple[Curve, Curve, Curve]:
    """Precision, recall (TPR) and FPR of ``sal8 >= t`` for ``t = 0..255``.

    Parameters
    ----------
    sal8 : ndarray of shape (H, W), uint8
    gt : ndarray of shape (H, W), bool

    Returns
    -------
    precision, recall, fpr : ndarray of shape (256,), float64
        Index ``t`` is the threshold. Precision is 0 where nothing is predicted, recall is 0
        when ``gt`` is empty, FPR is 0 when ``gt`` covers the whole image.
    """
    sal8 = np.asarray(sal8)
    gt = np.asarray(gt, dtype=bool)
    _check_pair(sal8, gt, "pr_roc_curves")
    if sal8.dtype != np.uint8:
        raise ValueError(f"pr_roc_curves: sal8 must be uint8, got {sal8.dtype}")
    fg = np.bincount(sal8[gt], minlength=256).astype(np.float64)
    bg = np.bincount(sal8[~gt], minlength=256).astype(np.float64)
    tp = np.cumsum(fg[::-1])[::-1]  # pixels >= t that are foreground
    fp = np.cumsum(bg[::-1])[::-1]
    n_fg, n_bg = fg.sum(), bg.sum()
    pred = tp + fp
    precision = np.divide(tp, pred, out=np.zeros(256), where=pred > 0)
    recall = tp / n_fg if n_fg > 0 else np.zeros(256)
    fpr = fp / n_bg if n_bg > 0 else np.zeros(256)
    return precision, recall, fpr


def f_measure(precision: Curve, recall: Curve, beta2: float = 0.3) -> Curve:
    """Eq. (17) of [1]: ``(1 + b2) P R / (b2 P + R)``, 0 where the denominator is 0."""
    p = np.asarray(precision, np.float64)
    r = np.asarray(recall, np.float64)
    den = beta2 * p + r
    return np.divide((1.0 + beta2) * p * r, den, out=np.zeros_like(den), where=den > 0)


def max_f_measure(precision: Curve, recall: Curve, beta2: float = 0.3) -> float:
    """Maximum over thresholds of Eq. (17) of [1] (beta^2 = 0.3 as [1] recommends)."""
    return float(f_measure(precision, recall, beta2).max())


def mae(sal_float01: NDArray[np.floating], gt: NDArray[np.bool_]) -> float:
    """Mean absolute error between a [0, 1] map and the binary ground truth."""
    s = np.asarray(sal_float01, np.float64)
    g = np.asarray(gt, dtype=bool)
    _check_pair(s, g, "mae")
    return float(np.abs(s - g).mean())


def auc(fpr: Curve, tpr: Curve) -> float:
    """Area under the ROC curve by the trapezoid rule, with (0, 0) and (1, 1) added.

    Points are sorted by FPR (then TPR), so the thresholds' order does not matter.
    """
    x = np.concatenate([[0.0], np.asarray(fpr, np.float64), [1.0]])
    y = np.concatenate([[0.0], np.asarray(tpr, np.float64), [1.0]])
    order = np.lexsort((y, x))
    return float(np.trapezoid(y[order], x[order]))


@dataclass
class SequenceScores:
    """Per-image-mean curves and figures of one sequence (or of a pooled set of frames)."""

    precision: Curve
    recall: Curve
    fpr: Curve
    mae: float
    n_frames: int
    n_empty_gt: int = 0
    beta2: float = 0.3

    @property
    def max_f(self) -> float:
        return max_f_measure(self.precision, self.recall, self.beta2)

    @property
    def auc(self) -> float:
        return auc(self.fpr, self.recall)

    def as_dict(self) -> dict[str, float | int]:
        return {"max_f": self.max_f, "mae": self.mae, "auc": self.auc,
                "frames": self.n_frames, "empty_gt_frames": self.n_empty_gt}


@dataclass
class CurveAccumulator:
    """Running sums for the per-image mean; ``add`` one frame at a time, then ``scores()``."""

    beta2: float = 0.3
    sum_precision: Curve = field(default_factory=lambda: np.zeros(N_THRESHOLDS))
    sum_recall: Curve = field(default_factory=lambda: np.zeros(N_THRESHOLDS))
    sum_fpr: Curve = field(default_factory=lambda: np.zeros(N_THRESHOLDS))
    n_curves: int = 0
    sum_mae: float = 0.0
    n_frames: int = 0
    n_empty_gt: int = 0

    def add(self, sal01: NDArray[np.floating], gt: NDArray[np.bool_]) -> None:
        """Score one frame: ``sal01`` already in [0, 1] (normalise first if needed)."""
        g = np.asarray(gt, dtype=bool)
        s = np.asarray(sal01, np.float32)
        _check_pair(s, g, "CurveAccumulator.add")
        self.sum_mae += mae(s, g)
        self.n_frames += 1
        if not g.any():
            self.n_empty_gt += 1
            return
        p, r, f = pr_roc_curves(quantize(s), g)
        self.sum_precision += p
        self.sum_recall += r
        self.sum_fpr += f
        self.n_curves += 1

    def merge(self, other: CurveAccumulator) -> None:
        self.sum_precision += other.sum_precision
        self.sum_recall += other.sum_recall
        self.sum_fpr += other.sum_fpr
        self.n_curves += other.n_curves
        self.sum_mae += other.sum_mae
        self.n_frames += other.n_frames
        self.n_empty_gt += other.n_empty_gt

    def scores(self) -> SequenceScores:
        if self.n_frames == 0:
            raise ValueError("no frames were scored")
        k = max(self.n_curves, 1)
        return SequenceScores(self.sum_precision / k, self.sum_recall / k, self.sum_fpr / k,
                              self.sum_mae / self.n_frames, self.n_frames, self.n_empty_gt,
                              self.beta2)


def evaluate_sequence(
    pairs: Iterable[tuple[NDArray[np.floating], NDArray[np.bool_]]],
    *,
    normalize: bool = True,
    beta2: float = 0.3,
) -> SequenceScores:
    """Score (map, gt) pairs with the per-image mean protocol.

    Parameters
    ----------
    pairs : iterable of (map, gt)
        ``map`` float (H, W); ``gt`` bool (H, W) (binarise DAVIS masks as ``gt >= 128``).
    normalize : bool
        Min-max normalise every map first (the protocol); False scores maps as given in [0, 1].
    beta2 : float
        beta^2 of Eq. (17).
    """
    acc = CurveAccumulator(beta2=beta2)
    for sal, gt in pairs:
        acc.add(normalize_map(sal) if normalize else np.clip(sal, 0.0, 1.0), gt)
    return acc.scores()
