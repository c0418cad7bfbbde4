"""Shared by the PnP solvers (:mod:`~eaglemission.estimators.rpnp`,
:mod:`~eaglemission.estimators.opencv_pnp`): the reprojection error of a pose in normalised image
coordinates and its optional Levenberg-Marquardt polish (``refine=True``).

``refine_pose`` runs the compiled loop ``_rpnp_kernel.refine_pose_core`` by default and keeps
the vectorised numpy reference (``backend="numpy"``); tests compare the two.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from eaglemission.kernels import lazy_kernel
from eaglemission.types import Mat3, Vec3

__all__ = ["refine_pose", "reprojection_errors"]

# the compiled refinement (loaded on first use; None: numpy reference)
_refine_kernel = lazy_kernel("eaglemission.estimators._rpnp_kernel", "refine_pose_core")


def reprojection_errors(
    R: Mat3, t: Vec3, object_points: NDArray[np.float64], normalized_points: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Per-point reprojection error in normalised image units (inf behind the camera)."""
    Xc = object_points @ R.T + t
    z = Xc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        proj = Xc[:, :2] / z[:, None]
        e: NDArray[np.float64] = np.linalg.norm(proj - normalized_points, axis=1)
    e[~(z > 0)] = np.inf
    return e


def _skew_batch(v: NDArray[np.float64]) -> NDArray[np.float64]:
    z = np.zeros(v.shape[0])
    skew: NDArray[np.float64] = np.stack((
        np.stack((z, -v[:, 2], v[:, 1]), axis=1),
        np.stack((v[:, 2], z, -v[:, 0]), axis=1),
        np.stack((-v[:, 1], v[:, 0], z), axis=1),
    ), axis=1)
    return skew


def _rodrigues(w: NDArray[np.float64]) -> Mat3:
    theta = float(np.linalg.norm(w))
    if theta < 1e-12:
        K = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
        R_small: Mat3 = np.eye(3) + K
        return R_small
    k = w / theta
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    R: Mat3 = np.eye(3) + math.sin(theta) * K + (1 - math.cos(theta)) * (K @ K)
    return R


def refine_pose(
    R: Mat3, t: Vec3, object_points: NDArray[np.float64], normalized_points: NDArray[np.float64],
    *, max_iterations: int = 10, tol: float = 1e-12,
    backend: Literal["numba", "numpy"] = "numba",
) -> tuple[Mat3, Vec3]:
    """Levenberg-Marquardt on the reprojection error in normalised coordinates.

    Parameterised by a left-multiplied rotation increment ``R <- exp([w]) R`` and ``t <- t + dt``;
    the Jacobian is analytic and vectorised over the points. Returns the input pose unchanged if
    no step lowers the error (e.g. points behind the camera). ``backend="numba"`` (default) runs
    the compiled loop of ``_rpnp_kernel.refine_pose_core`` (the same iterations, ~20x faster
    at n = 4; tests compare it with this numpy reference).
    """
    kern = _refine_kernel() if backend == "numba" else None
    if kern is not None:
        Rr, tr, _ = kern(np.ascontiguousarray(R, dtype=np.float64),
                         np.ascontiguousarray(t, dtype=np.float64),
                         np.ascontiguousarray(object_points, dtype=np.float64),
                         np.ascontiguousarray(normalized_points, dtype=np.float64),
                         int(max_iterations), float(tol))
        return Rr, tr
    X = object_points
    m = normalized_points
    lam = 1e-3

    def residual(Rk: Mat3, tk: Vec3) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        Xc = X @ Rk.T + tk
        if not (Xc[:, 2] > 0).all():
            return None
        return Xc, (Xc[:, :2] / Xc[:, 2:3] - m).reshape(-1)

    cur = residual(R, t)
    if cur is None:
        return R, t
    Xc, r = cur
    cost = float(r @ r)
    for _ in range(max_iterations):
        z = Xc[:, 2]
        iz = 1.0 / z
        # d(proj)/d(Xc): (n, 2, 3)
        Jp = np.zeros((X.shape[0], 2, 3))
        Jp[:, 0, 0] = iz
        Jp[:, 1, 1] = iz
        Jp[:, 0, 2] = -Xc[:, 0] * iz * iz
        Jp[:, 1, 2] = -Xc[:, 1] * iz * iz
        # d(Xc)/dw = -[R X]_x, d(Xc)/dt = I.
        RX = Xc - t
        Jw = -np.einsum("nij,njk->nik", Jp, _skew_batch(RX))
        J = np.concatenate((Jw, Jp), axis=2).reshape(-1, 6)
        H = J.T @ J
        g = J.T @ r
        improved = False
        for _ in range(8):
            try:
                step = -np.linalg.solve(H + lam * np.diag(np.diag(H) + 1e-12), g)
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            R_new = _rodrigues(step[:3]) @ R
            t_new = t + step[3:]
            nxt = residual(R_new, t_new)
            if nxt is not None and float(nxt[1] @ nxt[1]) < cost:
                R, t = R_new, t_new
                Xc, r = nxt
                new_cost = float(r @ r)
                done = cost - new_cost <= tol * max(cost, 1e-300)
                cost = new_cost
                lam = max(lam / 10, 1e-9)
                improved = True
                break
            lam *= 10
        if not improved or done:
            break
    # Re-orthonormalise (the exponential map keeps R orthonormal up to round-off).
    U, _, Vt = np.linalg.svd(R)
    return U @ Vt, t
