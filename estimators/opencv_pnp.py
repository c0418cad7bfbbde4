"""OpenCV PnP solvers (SQPnP, IPPE, ITERATIVE, EPnP) behind the same pure-function interface as
:func:`eaglemission.estimators.rpnp.rpnp`, and as estimator plugins for comparison.

The ``SOLVEPNP_*`` flags are looked up by name: their numeric values changed in OpenCV 5
(IPPE 4, IPPE_SQUARE 5, SQPNP 6), so no number is written anywhere.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, ClassVar

import cv2
import numpy as np
from eaglemission.estimators.corner_plugin import CornerPnPConfig, CornerPnPEstimator
from eaglemission.estimators.pnp_refine import refine_pose, reprojection_errors
from numpy.typing import ArrayLike, NDArray

from eaglemission.types import EstimationFailed, Mat3, PoseEstimate, Vec3

if TYPE_CHECKING:
    from eaglemission.config import TargetConfig

SOLVEPNP_SQPNP: int = cv2.SOLVEPNP_SQPNP
SOLVEPNP_IPPE: int = cv2.SOLVEPNP_IPPE
SOLVEPNP_ITERATIVE: int = cv2.SOLVEPNP_ITERATIVE
SOLVEPNP_EPNP: int = cv2.SOLVEPNP_EPNP

METHODS: dict[str, int] = {
    "sqpnp": SOLVEPNP_SQPNP,
    "ippe": SOLVEPNP_IPPE,
    "iterative": SOLVEPNP_ITERATIVE,
    "epnp": SOLVEPNP_EPNP,
}

_EYE = np.eye(3)
_ZERO = np.zeros(5)


def _f64(m: cv2.typing.MatLike) -> NDArray[np.float64]:
    """An OpenCV result as float64 (the solvers return float64 for float64 input: no copy)."""
    return np.asarray(m, dtype=np.float64)


def opencv_pnp(
    object_points: ArrayLike,
    normalized_points: ArrayLike,
    *,
    method: str = "sqpnp",
    refine: bool = False,
    return_all: bool = False,
) -> PoseEstimate | EstimationFailed:
    """Pose from normalised points with an OpenCV solver (``X_c = R X_o + t``).

    Parameters
    ----------
    object_points : (n, 3) ; normalized_points : (n, 2)
    method : {"sqpnp", "ippe", "iterative", "epnp"}
    refine : polish with the same Levenberg-Marquardt as RPnP's option
    return_all : with IPPE (which returns both planar solutions) put both in ``candidates``

    Returns
    -------
    PoseEstimate or EstimationFailed (never an OpenCV exception for bad geometry).
    """
    if method not in METHODS:
        raise ValueError(f"method: must be one of {sorted(METHODS)}, got {method!r}")
    X = np.asarray(object_points, dtype=np.float64)
    uv = np.asarray(normalized_points, dtype=np.float64)
    if X.ndim != 2 or X.shape[1] != 3 or uv.ndim != 2 or uv.shape[1] != 2 or X.shape[0] != uv.shape[0]:
        raise ValueError(f"object_points (n, 3) and normalized_points (n, 2): got {X.shape}, {uv.shape}")
    n = X.shape[0]
    if n < 4:
        return EstimationFailed(f"{method}: needs at least 4 points, got {n}")
    if not (np.isfinite(X).all() and np.isfinite(uv).all()):
        return EstimationFailed(f"{method}: input contains NaN or inf")
    if method == "iterative" and n < 6 and np.ptp(X[:, 2]) > 0:
        return EstimationFailed(f"{method}: needs at least 6 non-planar points, got {n}")
    flag = METHODS[method]
    try:
        if method == "ippe" or return_all:
            nsol, rvecs, tvecs, _ = cv2.solvePnPGeneric(X, uv, _EYE, _ZERO, flags=flag)
            sols = [(_f64(cv2.Rodrigues(rv)[0]), _f64(tv).reshape(3))
                    for rv, tv in zip(rvecs, tvecs)]
        else:
            ok, rvec, tvec = cv2.solvePnP(X, uv, _EYE, _ZERO, flags=flag)
            sols = [(_f64(cv2.Rodrigues(rvec)[0]), _f64(tvec).reshape(3))] if ok else []
    except cv2.error as exc:
        msg = str(exc).strip().splitlines()[-1] if str(exc).strip() else "error"
        return EstimationFailed(f"{method}: OpenCV refused the input ({msg})")
    scored: list[tuple[float, Mat3, Vec3]] = []
    for R, t in sols:
        if not (np.isfinite(R).all() and np.isfinite(t).all()):
            continue
        e = float(reprojection_errors(R, t, X, uv).mean())
        if math.isfinite(e):
            scored.append((e, R, t))
    if not scored:
        return EstimationFailed(f"{method}: no solution in front of the camera")
    scored.sort(key=lambda s: s[0])
    _, R, t = scored[0]
    if refine:
        R, t = refine_pose(R, t, X, uv)
    err = float(reprojection_errors(R, t, X, uv).mean())
    cands = tuple((r, tt) for _, r, tt in scored) if return_all else ()
    return PoseEstimate(R=R, t_m=t, reprojection_error=err, candidates=cands)


class OpenCVPnPConfig(CornerPnPConfig):
    """Params of the OpenCV PnP estimator plugins (same corner handling as ``rpnp``)."""

    refine: bool = False


class _OpenCVPnPEstimator(CornerPnPEstimator):
    Config: ClassVar[type[OpenCVPnPConfig]] = OpenCVPnPConfig
    description: ClassVar[str] = ""
    method: ClassVar[str] = ""

    def __init__(self, config: OpenCVPnPConfig | None = None, *,
                 target: TargetConfig | None = None, **context: object) -> None:
        self.config: OpenCVPnPConfig = config if config is not None else OpenCVPnPConfig()
        cfg = self.config
        method = self.method

        def solver(obj: NDArray[np.float64], nrm: NDArray[np.float64]) -> PoseEstimate | EstimationFailed:
            return opencv_pnp(obj, nrm, method=method, refine=cfg.refine, return_all=True)

        super().__init__(solver, cfg, target=target, source=method)


class SQPnPEstimator(_OpenCVPnPEstimator):
    """Plugin ``sqpnp``."""

    description: ClassVar[str] = "OpenCV SQPnP on the target's top face from the MBR corners"
    method: ClassVar[str] = "sqpnp"


class IPPEEstimator(_OpenCVPnPEstimator):
    """Plugin ``ippe``."""

    description: ClassVar[str] = "OpenCV IPPE (planar) on the target's top face from the MBR corners"
    method: ClassVar[str] = "ippe"


class IterativePnPEstimator(_OpenCVPnPEstimator):
    """Plugin ``iterative``."""

    description: ClassVar[str] = "OpenCV SOLVEPNP_ITERATIVE (LM) on the target's top face from the MBR corners"
    method: ClassVar[str] = "iterative"
