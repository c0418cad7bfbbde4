"""Metrics against hand-computed cases (tiny arrays)."""

from __future__ import annotations

import numpy as np
import pytest
from eaglemission.lab.bench.metrics import (
    CurveAccumulator,
    auc,
    evaluate_sequence,
    f_measure,
    mae,
    max_f_measure,
    normalize_map,
    pr_roc_curves,
    quantize,
)

# 2 x 2 case worked by hand:
#   sal8 = [[10, 200], [200, 50]], gt = [[T, T], [F, F]]
#   fg values {10, 200}, bg values {200, 50}
#   t in 0..10    : TP 2, FP 2 -> P 1/2, R 1,   FPR 1
#   t in 11..50   : TP 1, FP 2 -> P 1/3, R 1/2, FPR 1
#   t in 51..200  : TP 1, FP 1 -> P 1/2, R 1/2, FPR 1/2
#   t in 201..255 : nothing predicted -> P 0 (convention), R 0, FPR 0
SAL8 = np.array([[10, 200], [200, 50]], np.uint8)
GT = np.array([[True, True], [False, False]])


def test_pr_roc_curves_hand_computed():
    p, r, f = pr_roc_curves(SAL8, GT)
    assert p.shape == r.shape == f.shape == (256,)
    for lo, hi, pp, rr, ff in [(0, 10, 1 / 2, 1, 1), (11, 50, 1 / 3, 1 / 2, 1),
                               (51, 200, 1 / 2, 1 / 2, 1 / 2), (201, 255, 0, 0, 0)]:
        np.testing.assert_allclose(p[lo:hi + 1], pp)
        np.testing.assert_allclose(r[lo:hi + 1], rr)
        np.testing.assert_allclose(f[lo:hi + 1], ff)


def test_max_f_measure_eq17_by_hand():
    p, r, _ = pr_roc_curves(SAL8, GT)
    # F(1/2, 1) = 1.3 * 0.5 / (0.15 + 1) = 13/23; F(1/3, 1/2) = 0.21667/0.6; F(1/2, 1/2) = 0.5
    assert max_f_measure(p, r) == pytest.approx(13 / 23)
    f = f_measure(p, r)
    assert f[30] == pytest.approx((1.3 / 6) / 0.6)
    assert f[100] == pytest.approx(0.5)
    assert f[255] == 0.0  # 0/0 -> 0
    # beta^2 = 1 is the harmonic mean
    assert max_f_measure(np.array([0.5]), np.array([1.0]), beta2=1.0) == pytest.approx(2 / 3)


def test_auc_hand_computed():
    p, r, f = pr_roc_curves(SAL8, GT)
    # ROC points (0,0), (1/2,1/2), (1,1/2), (1,1): 0.125 + 0.25 = 0.375
    assert auc(f, r) == pytest.approx(0.375)
    # order of the points does not matter
    assert auc(f[::-1], r[::-1]) == pytest.approx(0.375)
    assert auc(np.array([0.0, 1.0]), np.array([1.0, 1.0])) == pytest.approx(1.0)
    assert auc(np.array([0.5]), np.array([0.5])) == pytest.approx(0.5)


def test_mae_hand_computed():
    sal = np.array([[0.2, 0.9], [0.4, 0.0]])
    assert mae(sal, GT) == pytest.approx((0.8 + 0.1 + 0.4 + 0.0) / 4)


def test_perfect_inverted_and_random_maps(rng):
    gt = rng.rand(40, 50) < 0.2
    perfect = gt.astype(np.uint8) * 255
    p, r, f = pr_roc_curves(perfect, gt)
    assert max_f_measure(p, r) == pytest.approx(1.0)
    assert auc(f, r) == pytest.approx(1.0)
    p, r, f = pr_roc_curves(255 - perfect, gt)
    assert auc(f, r) == pytest.approx(0.0)
    noise = (rng.rand(40, 50) * 255).astype(np.uint8)
    p, r, f = pr_roc_curves(noise, gt)
    assert abs(auc(f, r) - 0.5) < 0.07


def test_degenerate_gt():
    sal = np.array([[0, 255]], np.uint8)
    p, r, f = pr_roc_curves(sal, np.array([[False, False]]))
    assert not r.any() and f[0] == 1.0 and f[255] == 0.5
    p, r, f = pr_roc_curves(sal, np.array([[True, True]]))
    assert not f.any() and r[255] == 0.5 and p[255] == 1.0


def test_input_checks():
    with pytest.raises(ValueError, match="uint8"):
        pr_roc_curves(SAL8.astype(np.float32), GT)
    with pytest.raises(ValueError, match="same shape"):
        pr_roc_curves(SAL8, GT[:1])
    with pytest.raises(ValueError, match="same shape"):
        mae(np.zeros((2, 3)), GT)


def test_normalize_and_quantize():
    np.testing.assert_allclose(normalize_map(np.array([[2.0, 4.0, 6.0]])), [[0, 0.5, 1]])
    assert not normalize_map(np.full((3, 3), 7.0)).any()
    assert normalize_map(np.array([[np.nan, 1.0, 2.0]]))[0, 0] == 0.0
    np.testing.assert_array_equal(quantize(np.array([[0.0, 0.5, 1.0, 1.5, -1]])),
                                  [[0, 128, 255, 255, 0]])


def test_per_image_mean_protocol():
    """Curves are averaged over images first, max F is taken on the mean curves."""
    a = (np.array([[0.0, 1.0], [1.0, 0.2]]), np.array([[False, True], [False, False]]))
    b = (np.array([[0.9, 0.1], [0.3, 0.6]]), np.array([[True, False], [False, True]]))
    s = evaluate_sequence([a, b], normalize=False)
    pa, ra, fa = pr_roc_curves(quantize(a[0]), a[1])
    pb, rb, fb = pr_roc_curves(quantize(b[0]), b[1])
    np.testing.assert_allclose(s.precision, (pa + pb) / 2)
    np.testing.assert_allclose(s.recall, (ra + rb) / 2)
    np.testing.assert_allclose(s.fpr, (fa + fb) / 2)
    assert s.max_f == pytest.approx(max_f_measure((pa + pb) / 2, (ra + rb) / 2))
    assert s.mae == pytest.approx((mae(a[0], a[1]) + mae(b[0], b[1])) / 2)
    assert s.n_frames == 2 and s.as_dict()["auc"] == pytest.approx(s.auc)


def test_accumulator_merge_and_empty_gt():
    x = np.array([[0.0, 1.0]])
    acc1, acc2 = CurveAccumulator(), CurveAccumulator()
    acc1.add(x, np.array([[False, True]]))
    acc2.add(x, np.array([[False, False]]))  # empty GT: MAE only
    acc1.merge(acc2)
    s = acc1.scores()
    assert s.n_frames == 2 and s.n_empty_gt == 1
    assert s.mae == pytest.approx((0.0 + 0.5) / 2)
    assert s.max_f == pytest.approx(1.0)
    with pytest.raises(ValueError, match="no frames"):
        CurveAccumulator().scores()


def test_evaluate_sequence_normalizes_by_default():
    sal = np.array([[10.0, 30.0]])  # not in [0, 1]: min-max -> [0, 1]
    gt = np.array([[False, True]])
    assert evaluate_sequence([(sal, gt)]).mae == pytest.approx(0.0)
    assert evaluate_sequence([(sal, gt)], normalize=False).mae == pytest.approx(0.5)
