"""RPnP: round trips (pose -> project -> estimate -> compare), candidates, refinement, and
degenerate input."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from eaglemission.estimators.opencv_pnp import opencv_pnp
from eaglemission.estimators.rpnp import (
    cost_derivative_poly7,
    p3p_quartics,
    refine_pose,
    reprojection_errors,
    rpnp,
)
from pnp_synthetic import make_case, normalized, rotation_error_deg

from eaglemission.types import EstimationFailed, PoseEstimate


def _exact(est, R, t):
    assert isinstance(est, PoseEstimate), str(est)
    assert np.linalg.norm(est.R - R) < 1e-9
    assert np.linalg.norm(est.t_m - t) / np.linalg.norm(t) < 1e-9
    assert abs(np.linalg.det(est.R) - 1) < 1e-12


@pytest.mark.parametrize("family", ["ordinary", "quasi_singular", "planar"])
@pytest.mark.parametrize("n", [4, 5, 6, 10, 50])
def test_noise_free_exact(family, n):
    rs = np.random.RandomState(100 + n)
    for _ in range(25):
        Xo, Xc, R, t = make_case(family, n, rs)
        _exact(rpnp(Xo, normalized(Xc)), R, t)


def test_noise_free_exact_rectangle_top_face():
    rs = np.random.RandomState(7)
    for _ in range(200):
        Xo, Xc, R, t = make_case("rectangle", 4, rs)
        _exact(rpnp(Xo, normalized(Xc)), R, t)


def test_fronto_parallel_centred_square_is_a_multiple_root():
    """A centred square seen straight on: every P3P quartic has a double root at the truth, so the
    degree-7 polynomial has a triple root that np.roots finds to ~eps**(1/3): the unrefined pose
    is right to ~1e-6 (documented), the refined one to round-off."""
    s = 0.3
    Xo = np.array([[s, -s, 0], [s, s, 0], [-s, s, 0], [-s, -s, 0]])
    for R, t in [(np.eye(3), np.array([0.0, 0.0, 2.0])), (np.eye(3), np.array([0.0, 0.0, 0.2]))]:
        uv = normalized(Xo @ R.T + t)
        est = rpnp(Xo, uv)
        assert np.linalg.norm(est.R - R) < 1e-5
        _exact(rpnp(Xo, uv, refine=True), R, t)
    # Off-centre (not symmetric): exact without refinement.
    t = np.array([0.05, -0.02, 0.2])
    _exact(rpnp(Xo, normalized(Xo + t)), np.eye(3), t)


def test_random_pair_is_seeded_and_exact():
    rs = np.random.RandomState(8)
    Xo, Xc, R, t = make_case("ordinary", 20, rs)
    uv = normalized(Xc) + rs.normal(scale=2 / 800, size=(20, 2))
    a = rpnp(Xo, uv, pair="random", rng=5)
    b = rpnp(Xo, uv, pair="random", rng=np.random.default_rng(5))
    np.testing.assert_array_equal(a.R, b.R)
    _exact(rpnp(Xo, normalized(Xc), pair="random", rng=1), R, t)
    with pytest.raises(ValueError, match="pair"):
        rpnp(Xo, uv, pair="shortest")


def test_quartics_vanish_at_true_depth_ratio():
    rs = np.random.RandomState(9)
    Xo, Xc, _, _ = make_case("ordinary", 8, rs)
    v = Xc / np.linalg.norm(Xc, axis=1, keepdims=True)
    d = np.linalg.norm(Xc, axis=1)
    i1, i2, rest = 0, 1, np.arange(2, 8)
    t_true = d[i2] / d[i1] - v[i1] @ v[i2]
    q = p3p_quartics(v[i1] @ v[i2], v[rest] @ v[i1], v[rest] @ v[i2],
                     np.linalg.norm(Xo[i1] - Xo[i2]), np.linalg.norm(Xo[rest] - Xo[i1], axis=1),
                     np.linalg.norm(Xo[rest] - Xo[i2], axis=1))
    vals = np.array([np.polyval(c, t_true) for c in q])
    assert np.abs(vals).max() < 1e-12
    p7 = cost_derivative_poly7(q)
    # It is half the derivative of the sum of squares.
    full = np.zeros(9)
    for c in q:
        full = np.polyadd(full, np.polymul(c, c))
    np.testing.assert_allclose(np.polyder(full) / 2, p7[-len(np.polyder(full)):], rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("family", ["ordinary", "quasi_singular", "planar", "rectangle"])
def test_numba_kernel_matches_numpy_reference(family):
    rs = np.random.RandomState(15)
    for n in (4, 7, 30):
        for _ in range(10):
            Xo, Xc, R, t = make_case(family, n, rs)
            uv = normalized(Xc) + rs.normal(scale=2 / 800, size=(Xo.shape[0], 2))
            a = rpnp(Xo, uv, return_all=True)
            b = rpnp(Xo, uv, return_all=True, backend="numpy")
            assert len(a.candidates) == len(b.candidates)
            np.testing.assert_allclose(a.R, b.R, atol=1e-9)
            np.testing.assert_allclose(a.t_m, b.t_m, atol=1e-9)
            assert a.reprojection_error == pytest.approx(b.reprojection_error, rel=1e-9)


def test_return_all_contains_planar_ambiguity():
    """A 4-point planar target far away has a two-fold ambiguity: both candidates returned,
    the truth among them, best first."""
    rs = np.random.RandomState(10)
    found = 0
    for _ in range(50):
        Xo, Xc, R, t = make_case("rectangle", 4, rs)
        est = rpnp(Xo, normalized(Xc), return_all=True)
        assert len(est.candidates) >= 1
        np.testing.assert_array_equal(est.candidates[0][0], est.R)
        assert any(np.linalg.norm(cR - R) < 1e-9 for cR, _ in est.candidates)
        found += len(est.candidates) >= 2
    assert found > 0


def test_refinement_never_increases_error_and_helps_on_average():
    rs = np.random.RandomState(11)
    gains = []
    for _ in range(40):
        Xo, Xc, R, t = make_case("quasi_singular", 30, rs)
        uv = normalized(Xc) + rs.normal(scale=2 / 800, size=(30, 2))
        a = rpnp(Xo, uv)
        b = rpnp(Xo, uv, refine=True)
        # LM minimises the sum of squares (the reported error is the mean distance).
        ssq_a = np.sum(reprojection_errors(a.R, a.t_m, Xo, uv) ** 2)
        ssq_b = np.sum(reprojection_errors(b.R, b.t_m, Xo, uv) ** 2)
        assert ssq_b <= ssq_a * (1 + 1e-12)
        assert abs(np.linalg.det(b.R) - 1) < 1e-9
        gains.append(rotation_error_deg(a.R, R) - rotation_error_deg(b.R, R))
    assert np.mean(gains) > 0


@pytest.mark.parametrize("family", ["ordinary", "planar", "rectangle"])
def test_compiled_refinement_matches_numpy_reference(family):
    """refine_pose's numba loop against its numpy reference from perturbed starts: the same
    minimum (sum of squares to 1e-9 relative, pose to 1e-6; both stop when an LM step gains
    < 1e-12 relative, so round-off can decide one more tiny step) and the same start returned
    when it has a point behind the camera; the full refined rpnp() agrees too."""
    rs = np.random.RandomState(31)
    for n in (4, 6, 12):
        for _ in range(15):
            Xo, Xc, R, t = make_case(family, n, rs)
            uv = normalized(Xc) + rs.normal(scale=1.5 / 800, size=(len(Xo), 2))
            w = rs.normal(scale=0.03, size=3)
            R0 = cv2.Rodrigues(w)[0] @ R
            t0 = t + rs.normal(scale=0.05 * np.linalg.norm(t), size=3)
            a = refine_pose(R0, t0, Xo, uv)
            b = refine_pose(R0, t0, Xo, uv, backend="numpy")
            np.testing.assert_allclose(a[0], b[0], atol=1e-6)
            np.testing.assert_allclose(a[1], b[1], atol=1e-6 * np.linalg.norm(t))
            ssq = [np.sum(reprojection_errors(*p, Xo, uv) ** 2) for p in (a, b)]
            assert ssq[0] == pytest.approx(ssq[1], rel=1e-9)
            assert ssq[0] <= np.sum(reprojection_errors(R0, t0, Xo, uv) ** 2)
            fa = rpnp(Xo, uv, refine=True, return_all=True)
            fb = rpnp(Xo, uv, refine=True, return_all=True, backend="numpy")
            np.testing.assert_allclose(fa.R, fb.R, atol=1e-6)
            assert fa.reprojection_error == pytest.approx(fb.reprojection_error, rel=1e-6)
    behind = -t0  # every point behind the camera: the start comes back unchanged
    for backend in ("numba", "numpy"):
        Rb, tb = refine_pose(R0, behind, Xo, uv, backend=backend)
        assert np.array_equal(Rb, R0) and np.array_equal(tb, behind)


def test_noisy_matches_sqpnp_order_of_magnitude():
    rs = np.random.RandomState(12)
    ours, ref = [], []
    for _ in range(60):
        Xo, Xc, R, t = make_case("ordinary", 10, rs)
        uv = normalized(Xc) + rs.normal(scale=1 / 800, size=(10, 2))
        ours.append(rotation_error_deg(rpnp(Xo, uv, refine=True).R, R))
        ref.append(rotation_error_deg(opencv_pnp(Xo, uv, method="sqpnp").R, R))
    assert np.median(ours) < 1.2 * np.median(ref)


# -- degenerate input: failure values with the reason, never numpy exceptions ------------------
def _square(n=4):
    return np.array([[0.2, -0.1, 0], [0.2, 0.1, 0], [-0.2, 0.1, 0], [-0.2, -0.1, 0]])[:n]


@pytest.mark.parametrize(
    "obj, img, reason",
    [
        (_square(3), np.zeros((3, 2)), "at least 4"),
        (_square(), np.array([[0.1, 0], [0.2, 0], [np.nan, 0], [0, 0.1]]), "NaN"),
        (np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0.0]]),
         np.array([[0, 0], [0.1, 0], [0.2, 0.01], [0.3, 0.05]]), "collinear"),
        (np.zeros((5, 3)), np.random.RandomState(1).rand(5, 2), "coincident"),
        (_square(), np.array([[0.1, 0.1]] * 4), "image points"),
        (_square(), np.array([[0, 0], [0.1, 0.1], [0.2, 0.2], [0.3, 0.3]]), "image points"),
        (_square(), np.array([[0.1, 0], [np.inf, 0], [0, 0], [0, 0.1]]), "NaN or inf"),
    ],
)
def test_degenerate_input_fails_with_reason(obj, img, reason):
    res = rpnp(obj, img)
    assert isinstance(res, EstimationFailed) and not res
    assert reason in res.reason


def test_shape_misuse_raises_value_error():
    with pytest.raises(ValueError, match="object_points"):
        rpnp(np.zeros((4, 2)), np.zeros((4, 2)))
    with pytest.raises(ValueError, match="same n"):
        rpnp(np.zeros((5, 3)), np.zeros((4, 2)))


def test_points_behind_camera_never_give_a_pose_behind():
    """Object points partly behind the camera: no consistent pose exists; the answer is a
    failure value or a pose with every point in front, never an exception."""
    rs = np.random.RandomState(13)
    failures = 0
    for _ in range(100):
        Xo, Xc, R, t = make_case("ordinary", 8, rs)
        Xc = Xc.copy()
        Xc[:3, 2] *= -1
        Xo = (Xc - t) @ R
        res = rpnp(Xo, normalized(Xc))
        if not res:
            failures += 1
            continue
        assert (Xo @ res.R.T + res.t_m)[:, 2].min() > 0
        assert np.isfinite(reprojection_errors(res.R, res.t_m, Xo, normalized(Xc))).all()
    assert failures >= 0


def test_fuzz_never_raises():
    rs = np.random.RandomState(14)
    for _ in range(300):
        n = rs.randint(4, 12)
        obj = rs.normal(size=(n, 3)) * rs.choice([1e-12, 1, 1e6])
        if rs.rand() < 0.3:
            obj[:, 2] = 0
        img = rs.normal(size=(n, 2)) * rs.choice([1e-9, 0.1, 10])
        res = rpnp(obj, img, refine=bool(rs.rand() < 0.5))
        assert isinstance(res, (PoseEstimate, EstimationFailed))
        if res:
            assert np.isfinite(res.R).all() and np.isfinite(res.t_m).all()


@pytest.mark.parametrize("method", ["sqpnp", "ippe", "iterative", "epnp"])
def test_opencv_solvers_exact_and_never_raise(method):
    rs = np.random.RandomState(16)
    family = "planar" if method == "ippe" else "ordinary"
    Xo, Xc, R, t = make_case(family, 8, rs)
    est = opencv_pnp(Xo, normalized(Xc), method=method)
    assert np.linalg.norm(est.R - R) < 1e-6 and np.linalg.norm(est.t_m - t) / np.linalg.norm(t) < 1e-6
    for _ in range(100):
        n = rs.randint(0, 10)
        obj = rs.normal(size=(n, 3)) * rs.choice([0.0, 1e-9, 1.0])
        img = rs.normal(size=(n, 2))
        if n and rs.rand() < 0.2:
            img[0, 0] = np.nan
        res = opencv_pnp(obj, img, method=method)
        assert isinstance(res, (PoseEstimate, EstimationFailed))
    with pytest.raises(ValueError, match="method"):
        opencv_pnp(Xo, normalized(Xc), method="dls")
