"""``correspondence._lm_fit`` (MINPACK through ``leastsq``) gives the same iterates as the
``least_squares(method="lm")`` call it replaced in the box fit (a scipy upgrade that changes
least_squares' defaults makes this fail)."""

from __future__ import annotations

import numpy as np
import pytest
from eaglemission.estimators.correspondence import (
    _lm_fit,
    _region_residual,
    box_corners,
    project_box_mbr,
    target_pose_in_camera,
)
from scipy.optimize import least_squares

from eaglemission.geometry import CameraModel, CameraMount, camera_pose_ned


def _residual(rng: np.random.RandomState):
    model = CameraModel.from_lens("narrow", focal_length_mm=12.0,
                                  mount=CameraMount(0.0, -30.0, 0.0, (0.1, 0.03, 0.05)))
    cam = camera_pose_ned(model, (0.0, 0.0, -2.0), (1.0, 0.0, 0.0, 0.0))
    true = np.array([3.2, 0.1, -0.15, 20.0])
    R_ct, t_ct = target_pose_in_camera(cam, true[:3], true[3])
    observed = project_box_mbr(model, R_ct, t_ct, 0.4, 0.25, 0.15)
    assert observed is not None
    observed = observed + rng.normal(0.0, 0.3, observed.shape)
    res = _region_residual(model, box_corners(0.4, 0.25, 0.15), np.ascontiguousarray(cam.R.T),
                           np.ascontiguousarray(cam.t), observed)
    return res, true


@pytest.mark.parametrize("nfev", [10, 40])
def test_lm_fit_equals_least_squares_lm(nfev):
    rng = np.random.RandomState(21)
    res, true = _residual(rng)
    for _ in range(6):
        x0 = true + rng.normal(0.0, [0.1, 0.1, 0.0, 10.0])
        ref = least_squares(res, x0, jac=res.jac, method="lm", diff_step=1e-6, xtol=1e-7,
                            ftol=1e-6, max_nfev=nfev)
        out = _lm_fit(res, res.jac, x0, nfev, xtol=1e-7, ftol=1e-6)
        assert out is not None
        np.testing.assert_array_equal(out.x, ref.x)
        np.testing.assert_array_equal(out.fun, ref.fun)
        assert out.cost == pytest.approx(ref.cost, rel=1e-12, abs=1e-15)


def test_lm_fit_returns_none_where_least_squares_raises():
    def fun(x):
        return np.array([np.nan, x[0], x[1]])

    def jac(x):
        return np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])

    with pytest.raises(ValueError):
        least_squares(fun, np.zeros(2), jac=jac, method="lm")
    assert _lm_fit(fun, jac, np.zeros(2), 10, xtol=1e-7, ftol=1e-6) is None
