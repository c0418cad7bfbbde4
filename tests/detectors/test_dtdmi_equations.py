"""Eqs. (1)-(15) of the DTDMI paper, each against hand-computed values."""

from __future__ import annotations

import numpy as np
import pytest
from eaglemission.detectors.dtdmi import equations as eq


def test_eq1_rgb_to_lms_rows_of_matrix():
    # Pure red, green, blue pick out the matrix columns; white gives the row sums.
    np.testing.assert_allclose(eq.rgb_to_lms([1.0, 0.0, 0.0]), [0.3811, 0.1967, 0.0241])
    np.testing.assert_allclose(eq.rgb_to_lms([0.0, 0.0, 2.0]), [0.0804, 0.1564, 1.6888])
    np.testing.assert_allclose(eq.rgb_to_lms(np.ones((2, 2, 3)))[1, 1],
                               [0.3811 + 0.5783 + 0.0402, 0.1967 + 0.7244 + 0.0782,
                                0.0241 + 0.1288 + 0.8444])


def test_eq2_contrast_cue_by_hand():
    centres = np.array([[0.0, 0.0, 0.0], [3.0, 4.0, 0.0], [0.0, 0.0, 1.0]])
    counts = np.array([2.0, 1.0, 1.0])  # N = 4
    # k=0: 1/4*5 + 1/4*1 = 1.5; k=1: 2/4*5 + 1/4*sqrt(9+16+1) ; k=2: 2/4*1 + 1/4*sqrt(26)
    expect = [1.5, 2.5 + np.sqrt(26) / 4, 0.5 + np.sqrt(26) / 4]
    np.testing.assert_allclose(eq.contrast_cue(centres, counts), expect)
    assert np.all(eq.contrast_cue(centres, np.zeros(3)) == 0)


def test_eq3_inverse_square_distance_and_singularity():
    # 4x4 image: centre (1.5, 1.5); pixel (0, 0) at d^2 = 4.5.
    np.testing.assert_allclose(eq.inverse_square_distance(0, 0, (1.5, 1.5)), 1 / 4.5)
    # 3x3 image: the centre pixel is at d = 0 -> clamped to 1 / 0.25 = 4.
    assert eq.inverse_square_distance(1, 1, (1.0, 1.0)) == pytest.approx(4.0)
    assert eq.inverse_square_distance(1, 1, (1.0, 1.0), min_d2_px2=1.0) == pytest.approx(1.0)


def test_gaussian_centre_weight():
    shape = (5, 9)
    assert eq.gaussian_centre_weight(2, 4, shape) == pytest.approx(1.0)
    # one sigma (0.25 * 9 = 2.25 columns) away -> exp(-1/2)
    assert eq.gaussian_centre_weight(2, 4 + 2.25, shape) == pytest.approx(np.exp(-0.5))


def test_eq4_spatial_cue_mean_weight_with_empty_cluster():
    np.testing.assert_allclose(eq.spatial_cue([6.0, 1.0, 0.0], [3.0, 4.0, 0.0]), [2.0, 0.25, 0.0])


def test_eq5_spatial_cue_over_sequence():
    sums = np.array([[4.0, 1.0], [2.0, 0.0]])  # frames x clusters
    counts = np.array([[2.0, 1.0], [1.0, 3.0]])
    np.testing.assert_allclose(eq.spatial_cue_sequence(sums, counts), [6.0 / 3.0, 1.0 / 4.0])


def test_normalize_cue_and_eq6():
    np.testing.assert_allclose(eq.normalize_cue([1.0, 4.0, 2.0]), [0.25, 1.0, 0.5])
    assert np.all(eq.normalize_cue(np.zeros(3)) == 0)
    np.testing.assert_allclose(eq.static_saliency([0.5, 1.0], [0.2, 0.3]), [0.1, 0.3])


def test_eq7_derivative_and_response_by_hand():
    img = np.array([[0, 1, 4], [1, 2, 9], [0, 0, 0]], np.float32)
    gx, gy = eq.derivative_xy(img)
    # mask [-1, 0, 1], no 1/2, replicated border
    np.testing.assert_allclose(gx, [[1, 4, 3], [1, 8, 7], [0, 0, 0]])
    np.testing.assert_allclose(gy, [[1, 1, 5], [0, -1, -4], [-1, -2, -9]])
    g = eq.gradient_response(gx, gy)
    assert g[1, 1] == pytest.approx(np.sqrt(64 + 1))
    assert g[0, 2] == pytest.approx(np.sqrt(9 + 25))


def test_eq8_eq9_delay_unit_converges_to_input():
    g = np.array([2.0])
    gd = np.zeros(1)  # G_d(0) = 0
    g_tau = eq.inhibition_output(g, gd, 4.0)
    assert g_tau[0] == pytest.approx(0.5)
    gd = eq.delay_update(gd, g_tau)
    assert gd[0] == pytest.approx(0.5)  # 2 * (1 - 3/4)
    for _ in range(200):
        gd = eq.delay_update(gd, eq.inhibition_output(g, gd, 4.0))
    assert gd[0] == pytest.approx(2.0)


def test_tau_steps_exact_is_frame_rate_invariant():
    # Two steps of dt give the same decay as one of 2 dt.
    a1 = 1 / eq.tau_steps(0.02, 0.1)
    a2 = 1 / eq.tau_steps(0.04, 0.1)
    assert (1 - a1) ** 2 == pytest.approx(1 - a2)
    assert eq.tau_steps(0.01, 0.1, exact=False) == pytest.approx(10.0)
    assert eq.tau_steps(1.0, 0.1, exact=False) == 1.0
    assert eq.tau_steps(10.0, 0.1) == pytest.approx(1.0)


def test_eq10_competitive_selection_reichardt():
    # A static pattern with G_d proportional to G gives R = 0 (no motion).
    g = np.array([[1.0, 3.0, 2.0]])
    gd = 0.4 * g
    r = eq.competitive_selection(g, eq.shift_neighbour(gd, 1), eq.shift_neighbour(g, 1), gd)
    np.testing.assert_allclose(r, 0.0, atol=1e-12)
    # By hand: G = 2, G_d' = 3, G' = 1, G_d = 5 -> 2*3 - 1*5 = 1
    assert eq.competitive_selection(2.0, 3.0, 1.0, 5.0) == pytest.approx(1.0)
    # A pattern that moved one pixel to the right between the frames: sign tells direction.
    prev = np.array([[0.0, 1.0, 0.0, 0.0]])
    cur = np.array([[0.0, 0.0, 1.0, 0.0]])
    r_right = eq.competitive_selection(cur, eq.shift_neighbour(prev, 1),
                                       eq.shift_neighbour(cur, 1), prev)
    r_left = eq.competitive_selection(prev, eq.shift_neighbour(cur, 1),
                                      eq.shift_neighbour(prev, 1), cur)
    assert r_right.sum() == pytest.approx(-r_left.sum())
    assert np.abs(r_right).sum() > 0


def test_shift_neighbour():
    a = np.array([[1.0, 2.0], [3.0, 4.0]])
    np.testing.assert_array_equal(eq.shift_neighbour(a, 1), [[2, 2], [4, 4]])
    np.testing.assert_array_equal(eq.shift_neighbour(a, 0), [[3, 4], [3, 4]])


def test_eq11_synthesis():
    assert eq.synthesis_2d(np.array(3.0), np.array(-4.0)) == pytest.approx(5.0)


def test_box_sum_by_hand():
    a = np.arange(9, dtype=float).reshape(3, 3)
    b = eq.box_sum(a, 1)
    assert b[1, 1] == pytest.approx(a.sum())
    assert b[0, 0] == pytest.approx(0 + 1 + 3 + 4)
    np.testing.assert_array_equal(eq.box_sum(a, 0), a)


def test_eq12_structure_tensor_of_a_ramp():
    # O = 2 * column: O_x = 4 inside (mask [-1,0,1]), 2 at the replicated borders; O_y = 0.
    o = np.tile(2.0 * np.arange(5.0), (5, 1))
    dxx, dxy, dyy = eq.structure_tensor(o, 1)
    assert dxx[2, 2] == pytest.approx(9 * 16.0)
    assert dxx[2, 0] == pytest.approx(3 * 4.0 + 3 * 16.0)  # zero outside the image
    assert np.all(dxy == 0) and np.all(dyy == 0)


def test_eq13_closed_form_equals_eigvalsh(rng):
    a = rng.randn(200) * 3
    c = rng.randn(200) * 2
    b = rng.randn(200)
    mats = np.stack([np.stack([a, b], -1), np.stack([b, c], -1)], -2)
    lam = np.linalg.eigvalsh(mats)
    np.testing.assert_allclose(eq.eigenvalue_discrepancy(a, b, c),
                               (lam[:, 1] - lam[:, 0]) ** 2, rtol=1e-10, atol=1e-10)
    # By hand: diag(3, 1) -> (3 - 1)^2 = 4; isotropic -> 0.
    assert eq.eigenvalue_discrepancy(3.0, 0.0, 1.0) == pytest.approx(4.0)
    assert eq.eigenvalue_discrepancy(2.0, 0.0, 2.0) == 0.0


def test_eq14_multiscale_mean_and_eq15_product():
    m = eq.multiscale_synthesis([np.ones((2, 2)), 3 * np.ones((2, 2))])
    np.testing.assert_allclose(m, 2.0)
    with pytest.raises(ValueError):
        eq.multiscale_synthesis([])
    np.testing.assert_allclose(eq.final_saliency(np.array([0.5, 2.0]), np.array([4.0, 0.0])),
                               [2.0, 0.0])
